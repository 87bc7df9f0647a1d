"""Signal-dependent sensor noise (Poisson-Gaussian), in the raw linear domain before white balance and tone.

At sensor gain G a clean raw value y (0-1 full scale, after the gain) becomes

    y_noisy = a G * Poisson(y / (a G)) + Normal(0, G^2 b),    so   Var = a G y + b G^2,

``a`` the shot-noise variance per unit signal and ``b`` the read-noise variance, both at gain 1 (photon noise
scales with the gain, read noise before the amplifier with its square). Seeded per (seed, frame, eye).
Above :data:`POISSON_MAX` expected counts the Poisson draw is its normal approximation (same mean and
variance; at that count the two differ far below one 8-bit step), which is 10 times faster.
"""

from __future__ import annotations

import numpy as np

EYE_INDEX = {"left": 0, "right": 1}
POISSON_MAX = 100.0


def rng_for(seed: int, frame: int, eye: str, stream: int = 0) -> np.random.Generator:
    """The generator of one eye of one frame: the same (seed, frame, eye, stream) give the same numbers."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), int(frame),
                                                                       EYE_INDEX[eye], int(stream)])))


def poisson_gaussian(raw: np.ndarray, shot: float, read: float, gain: float, rng: np.random.Generator) -> np.ndarray:
    """``raw`` (any shape, >= 0) with Poisson-Gaussian noise of variance shot*gain*raw + read*gain^2 (float32)."""
    raw = np.maximum(np.asarray(raw, dtype=np.float32), np.float32(0.0))
    out = raw.copy()
    step = np.float32(shot * gain)
    if step > 0:
        counts = raw / step
        low = counts < POISSON_MAX
        out = step * (counts + np.sqrt(counts) * rng.standard_normal(raw.shape, dtype=np.float32))
        out[low] = step * rng.poisson(counts[low]).astype(np.float32)
    if read > 0:
        out += np.float32(np.sqrt(read) * gain) * rng.standard_normal(raw.shape, dtype=np.float32)
    return out
