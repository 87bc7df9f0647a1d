"""Image statistics that say how an image looks, for comparing rendered frames with real ones.

Every function takes an RGB image (H, W, 3) of 8-bit values (uint8, or float on the same 0-255 scale) and an
optional boolean ``mask`` (H, W) of the pixels to measure (a real scope's frame has overlays, black margins or
a circular field stop); None measures every pixel.

- **Brightness** (:func:`brightness`): mean luminance, Rec. 601 weights of the 8-bit values (0-255).
- **Contrast** (:func:`rms_contrast`): standard deviation of the luminance over its mean.
- **Colour** (:func:`chromaticity`, :func:`mean_saturation`): each channel's share of the summed channel means
  (the colour cast, independent of exposure), and the mean HSV saturation.
- **Noise** (:func:`noise_sigma`): standard deviation of additive noise in the luminance (8-bit levels), by
  the median absolute value of the finest diagonal wavelet coefficients (Donoho & Johnstone 1994, as
  ``skimage.restoration.estimate_sigma`` does with Daubechies wavelets; here the orthonormal Haar wavelet,
  so a 2x2 block needs only its own pixels to lie inside the mask). The median ignores most scene texture;
  below about one level it is coarse on 8-bit images (the median falls on one of the few values that integer
  pixels give), so a clean render reads about 0.4 whatever its true noise.
- **Sharpness** (:func:`high_frequency_share`, :func:`gradient_mean`): the share of the spectral power of the
  contrast image (luminance over its mean: exposure does not count) at and above ``HIGH_FREQUENCY`` cycles per
  pixel, and the mean gradient magnitude of the contrast image.
- **Highlights** (:func:`highlight_share`): the fraction of near-white pixels, the saturated specular cores of
  :class:`rgbd2scene.reconstruct.texture.HighlightSettings` (max channel >= 0.94 of full scale, saturation
  <= 0.15).

:func:`power_spectrum`, :func:`band_power_db`, :func:`spectral_slope` and :func:`gradient_stats` are the
building blocks, also used by ``benchmarks/bench_realism.py``.
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.reconstruct.texture import HighlightSettings
from rgbd2scene.sensor import tone

#: Spectral power at and above this spatial frequency (cycles per pixel) counts as fine detail.
HIGH_FREQUENCY = 0.25
#: Median of |N(0, 1)|: turns a median absolute deviation into a standard deviation.
MAD_TO_SIGMA = 0.6744897501960817
#: The texture module's highlight thresholds (its near-white core defines a highlight pixel here).
HIGHLIGHTS = HighlightSettings()


def _mask(image: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    if mask is None:
        return np.ones(image.shape[:2], bool)
    mask = np.asarray(mask, bool)
    if mask.shape != image.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} differs from the image's {image.shape[:2]}")
    if not mask.any():
        raise ValueError("the mask holds no pixel")
    return mask


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Luma of the 8-bit values (Rec. 709 weights, as the sensor's auto exposure meters): float64 (H, W), 0-255."""
    return tone.luminance(np.asarray(rgb, np.float64))


def brightness(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean luminance (0-255) over the mask."""
    return float(luminance(rgb)[_mask(rgb, mask)].mean())


def rms_contrast(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Standard deviation of the luminance over its mean (0 for a flat image)."""
    y = luminance(rgb)[_mask(rgb, mask)]
    return float(y.std() / max(y.mean(), 1e-9))


def chromaticity(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(r, g, b): each channel's mean over the sum of the three means (they add up to 1)."""
    means = np.asarray(rgb, np.float64)[_mask(rgb, mask)].mean(axis=0)
    return means / max(means.sum(), 1e-9)


def _value_saturation(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pixels = np.asarray(rgb, np.float64) / 255.0
    value, low = pixels.max(axis=-1), pixels.min(axis=-1)
    return value, np.where(value > 0, (value - low) / np.maximum(value, 1e-9), 0.0)


def mean_saturation(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean HSV saturation (0-1) over the mask."""
    return float(_value_saturation(rgb)[1][_mask(rgb, mask)].mean())


def highlight_pixels(rgb: np.ndarray, settings: HighlightSettings = HIGHLIGHTS) -> np.ndarray:
    """Near-white pixels (bool (H, W)): the saturated cores of specular highlights."""
    value, saturation = _value_saturation(rgb)
    return (value >= settings.core_value) & (saturation <= settings.core_saturation)


def highlight_share(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Fraction of the mask's pixels that are near-white (:func:`highlight_pixels`)."""
    return float(highlight_pixels(rgb)[_mask(rgb, mask)].mean())


def noise_sigma(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Standard deviation of white noise in the luminance (8-bit levels): median |HH| / 0.6745 over the 2x2
    blocks wholly inside the mask, HH = (a - b - c + d) / 2 the orthonormal Haar diagonal detail.

    Unbiased for additive Gaussian noise on a smooth image; scene detail at the pixel scale (sharp edges,
    fine texture) adds to it, much less than to a mean-based estimator because the median ignores the
    minority of blocks that hold an edge.
    """
    y = luminance(rgb)
    m = _mask(rgb, mask)
    h, w = (y.shape[0] // 2) * 2, (y.shape[1] // 2) * 2
    a, b, c, d = y[0:h:2, 0:w:2], y[0:h:2, 1:w:2], y[1:h:2, 0:w:2], y[1:h:2, 1:w:2]
    inside = m[0:h:2, 0:w:2] & m[0:h:2, 1:w:2] & m[1:h:2, 0:w:2] & m[1:h:2, 1:w:2]
    if not inside.any():
        raise ValueError("the mask holds no whole 2x2 block")
    hh = (a - b - c + d)[inside] / 2.0
    return float(np.median(np.abs(hh)) / MAD_TO_SIGMA)


def contrast_image(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Luminance divided by its mean over the mask: float64 (H, W) (exposure does not count)."""
    y = luminance(rgb)
    return y / max(y[_mask(rgb, mask)].mean(), 1e-9)


def power_spectrum(image: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Spatial frequency (cycles/px) and power per pixel of every FFT coefficient of a Hann-windowed grey image.

    With a mask, the spectrum is taken over the mask's bounding box, with the pixels outside it set to the mean
    inside (so they add no power of their own; the mask's own edge still adds a little)."""
    image = np.asarray(image, np.float64)
    if mask is not None:
        mask = _mask(image, mask)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        image, mask = image[box], mask[box]
        image = np.where(mask, image, image[mask].mean())
    h, w = image.shape
    window = np.outer(np.hanning(h), np.hanning(w))
    centred = (image - image.mean()) * window
    power = np.abs(np.fft.fft2(centred)) ** 2 / np.sum(window**2)
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    return np.hypot(fx, fy).ravel(), power.ravel()


def high_frequency_share(rgb: np.ndarray, mask: np.ndarray | None = None, cutoff: float = HIGH_FREQUENCY) -> float:
    """Share of the contrast image's spectral power (DC excluded) at and above ``cutoff`` cycles per pixel."""
    freq, power = power_spectrum(contrast_image(rgb, mask), mask)
    total = power[freq > 0].sum()
    return float(power[freq >= cutoff].sum() / total) if total > 0 else 0.0


def band_power_db(spectra: list[tuple[np.ndarray, np.ndarray]], edges: np.ndarray) -> np.ndarray:
    """Mean power per band (dB) between consecutive ``edges`` (cycles/px), averaged over several spectra; NaN for
    a band that holds no FFT coefficient (below the lowest frequency of a small image)."""
    out = np.full(len(edges) - 1, np.nan)
    for b, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        means = [p[band].mean() for f, p in spectra if (band := (f >= lo) & (f < hi)).any()]
        if means:
            out[b] = 10 * np.log10(np.mean(means))
    return out


def spectral_slope(band_db: np.ndarray, edges: np.ndarray, fit_range: tuple[float, float]) -> float:
    """Slope of log10 power against log10 frequency over the bands whose centre lies in ``fit_range``."""
    centres = np.sqrt(edges[:-1] * edges[1:])
    fit = (centres >= fit_range[0]) & (centres <= fit_range[1])
    return float(np.polyfit(np.log10(centres[fit]), band_db[fit] / 10, 1)[0])


def gradients(rgb: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """x and y gradients (central differences) of the contrast image at the mask's pixels whose neighbours
    are inside the mask too (a mask edge is no image edge)."""
    m = _mask(rgb, mask)
    dy, dx = np.gradient(contrast_image(rgb, m))
    inner = m.copy()
    inner[1:, :] &= m[:-1, :]
    inner[:-1, :] &= m[1:, :]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    return dx[inner], dy[inner]


def gradient_mean(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean gradient magnitude of the contrast image (per pixel)."""
    gx, gy = gradients(rgb, mask)
    return float(np.hypot(gx, gy).mean()) if gx.size else 0.0


def gradient_stats(gx: np.ndarray, gy: np.ndarray) -> dict[str, float]:
    """Mean, 50th, 90th and 99th percentile of the gradient magnitude, and the excess kurtosis of the
    components (heavy tails: sharp edges and small highlights in a smooth image)."""
    magnitude = np.hypot(gx, gy)
    components = np.concatenate([gx, gy])
    kurtosis = float(np.mean(components**4) / np.mean(components**2) ** 2 - 3.0)
    p50, p90, p99 = np.percentile(magnitude, [50, 90, 99])
    return {"gradient mean": float(magnitude.mean()), "gradient p50": float(p50), "gradient p90": float(p90),
            "gradient p99": float(p99), "gradient kurtosis": kurtosis}
