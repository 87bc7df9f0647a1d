"""Vignetting: the radial fall-off of the image brightness, V(rho) = clip(1 + k1 rho^2 + k2 rho^4, 0, 1).

rho is the distance of a pixel centre from the image centre over the half-diagonal (1 at the corners), the
measure :func:`rgbd2scene.sensor.estimate.radial_falloff` fits on real frames. V is 1 at the centre and
symmetric about both image axes.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rgbd2scene.sensor.estimate import radius_map


@lru_cache(maxsize=4)
def vignetting_map(width: int, height: int, k1: float, k2: float) -> np.ndarray:
    """float32 (H, W) gain of each pixel (read-only: one array per size and coefficients, reused)."""
    rho2 = radius_map(width, height) ** 2
    out = np.clip(1.0 + k1 * rho2 + k2 * rho2 * rho2, 0.0, 1.0).astype(np.float32)
    out.flags.writeable = False
    return out
