"""Signal-dependent sensor noise (Poisson-Gaussian), in the raw linear domain before white balance and tone.

At sensor gain G a clean raw value y (0-1 full scale, after the gain) becomes

    y_noisy = a G * Poisson(y / (a G)) + Normal(0, G^2 b),    so   Var = a G y + b G^2,

``a`` the shot-noise variance per unit signal and ``b`` the read-noise variance, both at gain 1 (photon noise
scales with the gain, read noise before the amplifier with its square). Seeded per (seed, frame, eye).
"""

from __future__ import annotations

import numpy as np

EYE_INDEX = {"left": 0, "right": 1}


def rng_for(seed: int, frame: int, eye: str, stream: int = 0) -> np.random.Generator:
    """The generator of one eye of one frame: the same (seed, frame, eye, stream) give the same numbers."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), int(frame),
                                                                       EYE_INDEX[eye], int(stream)])))


def poisson_gaussian(raw: np.ndarray, shot: float, read: float, gain: float, rng: np.random.Generator) -> np.ndarray:
    """``raw`` (any shape, >= 0) with Poisson-Gaussian noise of variance shot*gain*raw + read*gain^2 (float32)."""
    raw = np.maximum(np.asarray(raw, dtype=np.float64), 0.0)
    out = raw.copy()
    step = shot * gain
    if step > 0:
        out = step * rng.poisson(raw / step)
    if read > 0:
        out = out + rng.normal(0.0, np.sqrt(read) * gain, size=raw.shape)
    return out.astype(np.float32)
