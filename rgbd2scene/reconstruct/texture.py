"""The capture image as a texture: specular highlights taken out before the renderer lights it again.

A wet surface photographed under a lamp shows the lamp's mirror reflection: bright, nearly white patches
whose place depends on where the lamp and the camera were. Baked into the texture, they stay put while
the endoscope's own light moves and adds highlights of its own (double highlights). The renderer's
glossy material makes the highlights, so the texture should hold the surface colour only.

:func:`remove_highlights` finds them as **bright, low-saturation regions around a saturated core**
(hysteresis: a core pixel is near white, max channel >= ``core_value`` and saturation <= ``core_saturation``;
the region grows over connected pixels that are still bright and pale, max channel >= ``min_value`` and
saturation <= ``max_saturation``), skips regions larger than ``max_region_fraction`` of the image (a
white object, not a highlight), widens the rest by ``dilate_px`` (the glow of the lens and demosaicing
around a clipped patch) and fills them from the surrounding colour with ``cv2.inpaint`` (Telea).
Saturation here is HSV's, ``(max - min) / max`` of the RGB channels; values are fractions of 255.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage as ndi

HIGHLIGHT_MODES = ("remove", "keep")


@dataclass(frozen=True)
class HighlightSettings:
    """Thresholds of :func:`remove_highlights` (fractions of full scale; see the module docstring)."""

    core_value: float = 0.94
    core_saturation: float = 0.15
    min_value: float = 0.70
    max_saturation: float = 0.35
    dilate_px: int = 2
    max_region_fraction: float = 0.01
    inpaint_radius_px: float = 5.0


def highlight_mask(rgb: np.ndarray, settings: HighlightSettings = HighlightSettings()) -> np.ndarray:
    """Specular highlights of an RGB uint8 (H, W, 3) image: bool (H, W), dilated by ``settings.dilate_px``.

    Raises
    ------
    ValueError
        ``rgb`` is not uint8 (H, W, 3).
    """
    rgb = _as_rgb8(rgb)
    value = rgb.max(axis=2).astype(np.float32) / 255.0
    low = rgb.min(axis=2).astype(np.float32) / 255.0
    saturation = np.where(value > 0, (value - low) / np.maximum(value, 1e-6), 0.0)
    core = (value >= settings.core_value) & (saturation <= settings.core_saturation)
    pale = (value >= settings.min_value) & (saturation <= settings.max_saturation)
    labels, count = ndi.label(pale | core, structure=np.ones((3, 3), bool))
    if count == 0:
        return np.zeros(rgb.shape[:2], bool)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    has_core = np.bincount(labels[core], minlength=count + 1) > 0
    keep = has_core & (sizes <= settings.max_region_fraction * labels.size)
    keep[0] = False
    mask = keep[labels]
    if settings.dilate_px > 0:
        mask = ndi.binary_dilation(mask, structure=np.ones((3, 3), bool), iterations=settings.dilate_px)
    return mask


def remove_highlights(rgb: np.ndarray, mode: str = "remove",
                      settings: HighlightSettings = HighlightSettings()) -> tuple[np.ndarray, np.ndarray]:
    """The capture image without its specular highlights, and where they were.

    Parameters
    ----------
    rgb : uint8 (H, W, 3)
        The capture image, RGB.
    mode : "remove" or "keep"
        "keep" returns the image unchanged (a copy) and an empty mask.
    settings : HighlightSettings
        Detection thresholds, dilation and inpainting radius.

    Returns
    -------
    (rgb_clean, mask)
        uint8 (H, W, 3): highlight pixels filled from the surrounding colour, every other pixel unchanged;
        bool (H, W): the filled pixels.

    Raises
    ------
    ValueError
        Unknown ``mode`` or ``rgb`` not uint8 (H, W, 3).
    """
    if mode not in HIGHLIGHT_MODES:
        raise ValueError(f"unknown highlight mode {mode!r}; choose one of {', '.join(HIGHLIGHT_MODES)}")
    rgb = _as_rgb8(rgb)
    if mode == "keep":
        return rgb.copy(), np.zeros(rgb.shape[:2], bool)
    mask = highlight_mask(rgb, settings)
    if not mask.any():
        return np.array(rgb, copy=True), mask
    clean = cv2.inpaint(rgb, mask.astype(np.uint8), settings.inpaint_radius_px,
                        cv2.INPAINT_TELEA)
    clean[~mask] = rgb[~mask]  # inpainting leaves them alone; this makes it a guarantee
    return clean, mask


def _as_rgb8(rgb) -> np.ndarray:
    rgb = np.ascontiguousarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"image must be uint8 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    return rgb


def highlight_stats(mask: np.ndarray) -> dict:
    """Fraction of the image and number of regions that were filled (for scene.json)."""
    _, regions = ndi.label(mask, structure=np.ones((3, 3), bool))
    return {"highlight_fraction": float(np.mean(mask)), "highlight_regions": int(regions)}
