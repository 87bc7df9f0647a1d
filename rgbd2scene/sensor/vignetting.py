"""Vignetting: the radial fall-off of the image brightness, V(rho) = clip(1 + k1 rho^2 + k2 rho^4, 0, 1).

rho is the distance of a pixel centre from the image centre over the half-diagonal (1 at the corners), the
measure :func:`rgbd2scene.sensor.estimate.radial_falloff` fits on real frames. V is 1 at the centre and
symmetric about both image axes. It models the optics only: the fall-off of the scope's light is in the
render already (see :mod:`rgbd2scene.sensor.settings` for how the defaults were measured).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rgbd2scene.sensor.estimate import radius_map
from rgbd2scene.sensor.settings import SensorOptions


@lru_cache(maxsize=4)
def vignetting_map(width: int, height: int, k1: float, k2: float) -> np.ndarray:
    """float32 (H, W) gain of each pixel (read-only: one array per size and coefficients, reused)."""
    rho2 = radius_map(width, height) ** 2
    out = np.clip(1.0 + k1 * rho2 + k2 * rho2 * rho2, 0.0, 1.0).astype(np.float32)
    out.flags.writeable = False
    return out


def sensor_vignetting(options: SensorOptions, width: int, height: int) -> np.ndarray | None:
    """The map the sensor multiplies a (width x height) image by, or None where it changes nothing (switched
    off, or k1 = k2 = 0). The one place that decides, for the image and the auto exposure's metering alike."""
    if not options.vignetting or (options.vignetting_k1 == 0 and options.vignetting_k2 == 0):
        return None
    return vignetting_map(width, height, options.vignetting_k1, options.vignetting_k2)
