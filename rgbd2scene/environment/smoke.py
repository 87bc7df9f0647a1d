"""Surgical smoke: attenuation and airlight along each pixel's ray, drifting smoothly in space and time.

Light goes from the scope's tip to the surface and back through the smoke, so with the extinction coefficient
sigma (1/m) and the ray length d (m) the surface keeps T = exp(-2 sigma d) of its radiance (Beer-Lambert, both
ways), and the smoke scatters the scope light back as airlight (Koschmieder's model):

    I = J T + A (1 - T),    A = smoke_color * L_ref,

with J the smoke-free linear radiance and L_ref the 90th percentile of J's luminance: the smoke is lit by the
same light as the tissue, and a dense cloud returns about what a bright, well-lit tissue patch does. T falls
and the airlight share rises with density, so contrast falls monotonically with it.

sigma varies over the image as sigma0 * (1 + variation * n(u, v, t)), n a seeded sum of sinusoids (wavelength
about ``smoke_scale`` of the image width, random directions and phases) drifting with ``smoke_drift``; it is
smooth in space and time, the same field in both eyes (the smoke is near the scope), and the same for a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.environment.settings import EnvironmentOptions
from rgbd2scene.sensor.tone import luminance

#: Sinusoids summed in the density field, and the percentile of the lit radiance that sets the airlight.
MODES = 6
AIRLIGHT_PERCENTILE = 90.0
#: Ray length given to pixels that see no surface (Cycles' background depth is 1e10 m).
FAR_M = 0.2
#: Phase change of each sinusoid of the density field, rad/s.
BOIL = 0.5


@dataclass
class Smoke:
    """Smoke of mean extinction ``density`` (1/m); see the module docstring."""

    density: float
    color: tuple[float, float, float]
    variation: float
    scale: float
    drift: float
    seed: int = 0

    @classmethod
    def from_options(cls, options: EnvironmentOptions, seed: int) -> Smoke:
        return cls(options.smoke, options.smoke_color, options.smoke_variation, options.smoke_scale,
                   options.smoke_drift, seed)

    def density_field(self, width: int, height: int, time_s: float) -> np.ndarray:
        """float32 (H, W) extinction coefficient (1/m) at ``time_s`` seconds, >= 0."""
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(self.seed), 0x5340_4B45])))
        angles = rng.uniform(0, 2 * np.pi, MODES)
        phases = rng.uniform(0, 2 * np.pi, MODES)
        wavelengths = self.scale * rng.uniform(0.7, 1.4, MODES)  # image widths
        wind = rng.uniform(0, 2 * np.pi)
        v, u = np.mgrid[0:height, 0:width].astype(np.float64) / max(width, 1)
        # the pattern moves with the wind: evaluate it at the position it came from
        u = u - self.drift * time_s * np.cos(wind)
        v = v - self.drift * time_s * np.sin(wind)
        field = np.zeros((height, width))
        for a, p, lam in zip(angles, phases, wavelengths, strict=True):
            # each sinusoid also changes phase slowly (BOIL rad/s): the smoke churns as it drifts
            field += np.cos(2 * np.pi * (u * np.cos(a) + v * np.sin(a)) / lam + p + BOIL * time_s)
        field /= np.sqrt(MODES / 2.0)  # unit variance
        return (self.density * np.maximum(1.0 + self.variation * np.tanh(field), 0.0)).astype(np.float32)

    def apply(self, linear: np.ndarray, distance: np.ndarray, time_s: float) -> np.ndarray:
        """Linear RGB (H, W, 3) seen through the smoke; ``distance``: ray length per pixel (m, inf/NaN/huge for
        none)."""
        linear = np.asarray(linear, dtype=np.float32)
        if self.density <= 0:
            return linear
        h, w = linear.shape[:2]
        d = np.asarray(distance, dtype=np.float64)
        d = np.where(np.isfinite(d) & (d < FAR_M), d, FAR_M)
        transmission = np.exp(-2.0 * self.density_field(w, h, time_s) * d).astype(np.float32)[..., None]
        level = float(np.percentile(luminance(linear), AIRLIGHT_PERCENTILE))
        airlight = np.asarray(self.color, dtype=np.float32) * np.float32(level)
        return linear * transmission + airlight * (1.0 - transmission)


def ray_length(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Ray length (m) of each pixel of a pinhole camera from its planar depth z (the Depth pass):
    d = z * sqrt(1 + x^2 + y^2) with x = (u - cx) / fx, y = (v - cy) / fy."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    return np.asarray(depth, dtype=np.float64) * np.sqrt(1.0 + x * x + y * y)
