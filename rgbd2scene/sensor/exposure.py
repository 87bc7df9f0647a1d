"""Auto exposure: a brightness target on the trimmed-mean luma, smoothed over time so it does not flicker.

Metering (:func:`meter`): the exposure E* that would put this frame's trimmed-mean 8-bit luma (2nd-98th
percentile, so highlights and black corners do not steer it) of the clean developed image at the target; found
by bisection on log E (the developed luma grows with E). Smoothing (:func:`smoothed_log_exposure`): the
exposure of frame i is the exponentially weighted mean of log E* over frames max(0, i - W + 1) .. i,

    log E_i = sum_k w_k log E*_{i-k} / sum_k w_k,   w_k = (1 - speed)^k,   k = 0 .. min(i, W - 1),

so it depends on earlier frames only through their metered log E* (recorded per frame in
``DATASET/sensor/NNNNNN.json``): a resumed or parallel chunk recomputes it from those records. Splitting
(:func:`split_exposure`): like a scope's camera control unit, the light source dims first (down to
``light_min`` of the scene's light, never above it) and the sensor gain makes up the rest (1 to ``gain_max``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from rgbd2scene.sensor.estimate import trimmed_mean
from rgbd2scene.sensor.settings import SensorOptions
from rgbd2scene.sensor.tone import luminance
from rgbd2scene.sensor.vignetting import sensor_vignetting

#: Bisection bounds of log E and its step count (precision 2^-22 of the range, 1e-5: below the 1e-4 the
#: records keep).
LOG_E_RANGE = (-16.0, 16.0)
BISECTION_STEPS = 22
#: Metering looks at every METER_STRIDE-th pixel in each direction (the statistic hardly changes; speed).
METER_STRIDE = 4


@dataclass(frozen=True)
class Exposure:
    """How one frame was exposed: ``light`` (share of the scene's light power) times ``gain`` (sensor gain)."""

    light: float
    gain: float

    @property
    def total(self) -> float:
        return self.light * self.gain

    def to_dict(self) -> dict:
        return {**asdict(self), "total": self.total}


def meter(linear: np.ndarray, options: SensorOptions) -> float:
    """log E* of one frame: the exposure that brings its clean developed trimmed-mean luma to ``target``."""
    from rgbd2scene.sensor.pipeline import develop_clean

    sample = np.ascontiguousarray(linear[::METER_STRIDE, ::METER_STRIDE])
    # the meter sees what the sensor sees: after the vignetting (the same map as the image, not a second one)
    vign = sensor_vignetting(options, linear.shape[1], linear.shape[0])
    if vign is not None:
        vign = vign[::METER_STRIDE, ::METER_STRIDE]

    def luma(log_e: float) -> float:
        enc = develop_clean(sample, math.exp(log_e), options, vign)
        return trimmed_mean(luminance(enc) * 255.0)

    lo, hi = LOG_E_RANGE
    if luma(hi) < options.target:  # black frame: as bright as the system goes
        return hi
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if luma(mid) < options.target else (lo, mid)
    return 0.5 * (lo + hi)


def smoothed_log_exposure(metered: Sequence[float], options: SensorOptions) -> float:
    """log E of a frame from the metered log E* of it and the frames before it (``metered[-1]`` is this
    frame's; only the last ``ae_window`` count)."""
    recent = np.asarray(metered[-int(options.ae_window):], dtype=np.float64)[::-1]
    if recent.size == 0:
        raise ValueError("auto exposure needs at least this frame's metering")
    w = (1.0 - options.ae_speed) ** np.arange(recent.size)
    return float((w * recent).sum() / w.sum())


def split_exposure(log_e: float, options: SensorOptions) -> Exposure:
    """Light share and sensor gain of exposure exp(log_e): the light dims first, the gain makes up the rest."""
    e = math.exp(log_e)
    light = min(max(e, options.light_min), 1.0)
    gain = min(max(e / light, 1.0), options.gain_max)
    return Exposure(light, gain)


def frame_exposure(metered: Sequence[float], options: SensorOptions) -> Exposure:
    """The exposure of a frame: fixed (light 1, gain ``exposure_gain``) or auto from the metering history."""
    if options.exposure == "fixed":
        return Exposure(1.0, float(options.exposure_gain))
    return split_exposure(smoothed_log_exposure(metered, options), options)
