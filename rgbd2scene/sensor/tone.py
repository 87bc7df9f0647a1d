"""Tone curves: linear sensor signal (0-1) <-> encoded 8-bit values, and white balance.

``srgb`` is the IEC 61966-2-1 curve (what Blender's "Standard" view transform wrote before); ``gamma`` a plain
power law ``x ** (1 / gamma)``, as many analogue-era scope cameras apply (ITU-R BT.709's 0.45 is gamma 2.2).
"""

from __future__ import annotations

import numpy as np

TONE_CURVES = ("srgb", "gamma")


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear (clipped to 0-1) -> sRGB-encoded (0-1)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """sRGB-encoded (0-1) -> linear (0-1)."""
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def encode(x: np.ndarray, curve: str = "srgb", gamma: float = 2.2) -> np.ndarray:
    """Linear sensor signal -> encoded values (0-1) with ``curve`` (:data:`TONE_CURVES`)."""
    if curve == "srgb":
        return srgb_encode(x)
    if curve == "gamma":
        return np.power(np.clip(x, 0.0, 1.0), 1.0 / gamma)
    raise ValueError(f"unknown tone curve {curve!r}; choose one of {', '.join(TONE_CURVES)}")


def decode(v: np.ndarray, curve: str = "srgb", gamma: float = 2.2) -> np.ndarray:
    """Inverse of :func:`encode` on 0-1."""
    if curve == "srgb":
        return srgb_decode(v)
    if curve == "gamma":
        return np.power(np.clip(v, 0.0, 1.0), gamma)
    raise ValueError(f"unknown tone curve {curve!r}; choose one of {', '.join(TONE_CURVES)}")


def to_uint8(v: np.ndarray) -> np.ndarray:
    """Encoded 0-1 -> uint8 (rounded to nearest)."""
    return np.clip(np.rint(np.asarray(v, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 weights (sRGB's primaries) of RGB (..., 3): luminance of linear values, luma of encoded ones.

    The project's one brightness convention: auto exposure, the sensor's brightness statistics and the realism
    report all weigh R, G and B with it.
    """
    rgb = np.asarray(rgb)
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def white_balance(rgb: np.ndarray, gains: tuple[float, float, float]) -> np.ndarray:
    """Per-channel gains on linear RGB (the camera's white balance)."""
    return np.asarray(rgb) * np.asarray(gains, dtype=np.float32)
