"""Estimators of a real camera's brightness, noise and radial falloff from its 8-bit frames.

They fix the sensor model's defaults (:mod:`rgbd2scene.sensor.settings`, measured on the LEFT eye of the
Hamlyn phantom frame, the RIGHT eye held out: ``benchmarks/bench_sensor.py`` prints both) and serve the realism
report, which compares rendered frames with real ones by the same measures.

- :func:`brightness_stats`: mean, trimmed mean and percentiles of the 8-bit luma (Rec. 709 weights).
- :func:`noise_curve` + :func:`fit_poisson_gaussian`: the signal-dependent noise level in the *linear* domain
  (the encoded values are decoded through the tone curve first), per intensity bin, from horizontal second
  differences, with the robust MAD scale in each bin so edges and texture count as outliers (the
  difference-based estimator of Immerkaer 1996 / Donoho's MAD, binned by intensity as in Foi et al. 2008,
  "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data"); then the least-squares
  non-negative fit var = a * mean + b. Horizontal only: deinterlaced SD frames repeat or interpolate rows.
- :func:`radial_falloff`: the brightness fall-off from the centre, as a fitted V(rho) = 1 + k1 rho^2 + k2 rho^4
  of the 90th percentile of linear luminance in rings (rho = distance / half-diagonal), relative to the
  brightest ring of the central plateau (rho < 0.5). On a real scope this
  is vignetting and illumination fall-off together; albedo changes are what the upper percentile damps.
- :func:`optical_vignetting` (:func:`radial_profile` of a real frame and of its render without vignetting on
  the same pixels, then :func:`vignetting_from_profiles`): the fall-off the sensor must add to a render whose
  light falls off already, a least-squares fit on the ratio of the two profiles with a free level.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from rgbd2scene.sensor.tone import decode, luminance

#: Robust scale of a Gaussian from its median absolute deviation.
MAD_TO_SIGMA = 1.4826
#: Rings nearer the centre than this (rho) form the plateau that :func:`radial_falloff` takes as 1.
PLATEAU = 0.5
#: Pixels left out at each image border: the Hamlyn frames' on-screen overlay rows and frame columns.
BORDER = 8
#: Linear signal range of the bins :func:`fit_poisson_gaussian` fits by default (encoded about 0.15-0.63).
FIT_RANGE = (0.02, 0.35)


@dataclass
class BrightnessStats:
    """8-bit luma statistics of one frame (0-255)."""

    mean: float
    trimmed_mean: float  # mean of the 2nd-98th percentile range
    p50: float
    p95: float
    clipped_fraction: float  # share of pixels with a channel at 255

    def to_dict(self) -> dict:
        return asdict(self)


def luma8(rgb_uint8: np.ndarray) -> np.ndarray:
    """Rec. 709 luma (0-255, float64) of encoded 8-bit RGB."""
    return luminance(np.asarray(rgb_uint8, dtype=np.float64))


def trimmed_mean(values: np.ndarray, low: float = 2.0, high: float = 98.0) -> float:
    """Mean of the values between the ``low`` and ``high`` percentiles (both kept)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    lo, hi = np.percentile(v, [low, high])
    keep = v[(v >= lo) & (v <= hi)]
    return float(keep.mean()) if keep.size else float(v.mean())


def brightness_stats(rgb_uint8: np.ndarray, mask: np.ndarray | None = None) -> BrightnessStats:
    """Brightness of an 8-bit RGB frame (``mask``: pixels to use, default all)."""
    y = luma8(rgb_uint8)
    rgb = np.asarray(rgb_uint8)
    sel = np.ones(y.shape, bool) if mask is None else np.asarray(mask, bool)
    v = y[sel]
    return BrightnessStats(float(v.mean()), trimmed_mean(v), float(np.percentile(v, 50)),
                           float(np.percentile(v, 95)), float((rgb[sel] >= 255).any(axis=-1).mean()))


@dataclass
class NoiseCurve:
    """Per-bin linear-domain mean and noise variance (``count`` samples each)."""

    mean: np.ndarray
    variance: np.ndarray
    count: np.ndarray


def noise_curve(rgb_uint8: np.ndarray, curve: str = "srgb", bins: int = 16, mask: np.ndarray | None = None,
                min_count: int = 200, border: int = BORDER) -> NoiseCurve:
    """Noise variance against signal in the linear domain, pooled over the three channels.

    Each sample is a horizontal triple (x0, x1, x2) of one channel: its mean is the signal, and
    (x0 - 2 x1 + x2) / sqrt(6) has the noise's variance when the signal is locally linear. Bins are equally
    spaced in the encoded domain; a bin's variance is (1.4826 MAD)^2 of its residuals (texture and edges are
    outliers). ``border`` pixels are left out at each side (overlay text, frame edges).
    """
    lin = decode(np.asarray(rgb_uint8, dtype=np.float64) / 255.0, curve)
    h, w = lin.shape[:2]
    keep = np.zeros((h, w), bool)
    keep[border:h - border, border:w - border] = True
    if mask is not None:
        keep &= np.asarray(mask, bool)
    x0, x1, x2 = lin[:, :-2], lin[:, 1:-1], lin[:, 2:]
    sel = keep[:, :-2] & keep[:, 1:-1] & keep[:, 2:]
    resid = ((x0 - 2 * x1 + x2) / np.sqrt(6.0))[sel].ravel()
    mean = ((x0 + x1 + x2) / 3.0)[sel].ravel()
    # unclipped samples only: a clipped triple has no noise left
    enc = np.asarray(rgb_uint8)
    unclipped = ((enc[:, :-2] < 255) & (enc[:, 1:-1] < 255) & (enc[:, 2:] < 255)
                 & (enc[:, :-2] > 0) & (enc[:, 1:-1] > 0) & (enc[:, 2:] > 0))[sel].ravel()
    resid, mean = resid[unclipped], mean[unclipped]
    edges = decode(np.linspace(0.0, 1.0, bins + 1), curve)
    which = np.clip(np.searchsorted(edges, mean, side="right") - 1, 0, bins - 1)
    out_m, out_v, out_n = [], [], []
    for b in range(bins):
        r = resid[which == b]
        if r.size < min_count:
            continue
        sigma = MAD_TO_SIGMA * np.median(np.abs(r - np.median(r)))
        out_m.append(mean[which == b].mean())
        out_v.append(sigma**2)
        out_n.append(r.size)
    return NoiseCurve(np.array(out_m), np.array(out_v), np.array(out_n))


def fit_poisson_gaussian(curve: NoiseCurve, low: float = FIT_RANGE[0],
                         high: float = FIT_RANGE[1]) -> tuple[float, float]:
    """(a, b) of var = a * mean + b over the bins with ``low`` < mean < ``high`` (linear), non-negative least
    squares weighted by sqrt(count).

    The default range leaves out the darkest bins, where 8-bit quantisation of the encoded values sets the
    residual (one code step near black is below the noise model), and the brightest, where few samples remain
    and they sit on highlights and edges.
    """
    from scipy.optimize import nnls

    sel = (curve.mean > low) & (curve.mean < high)
    curve = NoiseCurve(curve.mean[sel], curve.variance[sel], curve.count[sel])
    if curve.mean.size < 2:
        raise ValueError("need at least two populated intensity bins to fit the noise model")
    w = np.sqrt(curve.count)
    design = np.stack([curve.mean, np.ones_like(curve.mean)], axis=1) * w[:, None]
    (a, b), _ = nnls(design, curve.variance * w)
    return float(a), float(b)


@dataclass
class RadialProfile:
    """Level of linear luminance per ring of rho (distance from the image centre / half-diagonal)."""

    rings: np.ndarray  # ring centres rho
    levels: np.ndarray  # the ring's percentile of linear luminance (absolute, not normalised)
    count: np.ndarray  # pixels in the ring


@dataclass
class RadialFalloff:
    """V(rho) = 1 + k1 rho^2 + k2 rho^4 (rho = distance from the image centre / half-diagonal)."""

    k1: float
    k2: float
    corner: float  # V(1)
    rings: np.ndarray  # ring centres rho
    profile: np.ndarray  # measured relative level per ring

    def to_dict(self) -> dict:
        return {"k1": self.k1, "k2": self.k2, "corner": self.corner}

    def at(self, rho: float | np.ndarray) -> float | np.ndarray:
        """V(rho) of the fit, unclipped."""
        rho2 = np.asarray(rho, dtype=np.float64) ** 2
        return 1.0 + self.k1 * rho2 + self.k2 * rho2 * rho2


def linear_luminance(rgb_uint8: np.ndarray, curve: str = "srgb") -> np.ndarray:
    """Linear-domain luminance (0-1, float64) of encoded 8-bit RGB, decoded through the tone ``curve``."""
    return luminance(decode(np.asarray(rgb_uint8, dtype=np.float64) / 255.0, curve))


def radial_profile(y: np.ndarray, mask: np.ndarray | None = None, rings: int = 10, percentile: float = 90.0,
                   border: int = BORDER, min_count: int = 50) -> RadialProfile:
    """The ``percentile`` of ``y`` (H, W) in ``rings`` equal-width rings of rho, from 0 to the largest rho
    measured; ``border`` pixels left out at each side, and with ``mask`` only its pixels; rings with fewer than
    ``min_count`` pixels are left out. Two images measured with the same mask share their rings."""
    y = np.asarray(y, dtype=np.float64)
    h, w = y.shape
    rho = radius_map(w, h)
    keep = np.zeros((h, w), bool)
    keep[border:h - border, border:w - border] = True
    if mask is not None:
        keep &= np.asarray(mask, bool)
    if not keep.any():
        raise ValueError("no pixel left to measure (mask and border)")
    edges = np.linspace(0.0, float(rho[keep].max()) + 1e-9, rings + 1)
    centres, levels, counts = [], [], []
    for i in range(rings):
        sel = keep & (rho >= edges[i]) & (rho < edges[i + 1])
        if sel.sum() < min_count:
            continue
        centres.append(0.5 * (edges[i] + edges[i + 1]))
        levels.append(np.percentile(y[sel], percentile))
        counts.append(int(sel.sum()))
    return RadialProfile(np.array(centres), np.array(levels), np.array(counts))


def radial_falloff(rgb_uint8: np.ndarray, curve: str = "srgb", rings: int = 10, percentile: float = 90.0,
                   border: int = BORDER, mask: np.ndarray | None = None) -> RadialFalloff:
    """Fit the radial brightness fall-off of a frame (linear luminance, ``percentile`` per ring, the brightest
    ring with rho < :data:`PLATEAU` as 1; ``mask``: the pixels to use, default all but the border)."""
    prof = radial_profile(linear_luminance(rgb_uint8, curve), mask, rings, percentile, border)
    centres = prof.rings
    # the central plateau (rho < 0.5) as 1: its ups and downs are the scene's, not the optics'
    levels = np.minimum(prof.levels / prof.levels[centres < PLATEAU].max(), 1.0)
    # least squares of (V - 1) on rho^2, rho^4 (V(0) = 1 by construction)
    design = np.stack([centres**2, centres**4], axis=1)
    (k1, k2), *_ = np.linalg.lstsq(design, levels - 1.0, rcond=None)
    return RadialFalloff(float(k1), float(k2), float(1.0 + k1 + k2), centres, levels)


def vignetting_from_profiles(real: RadialProfile, render: RadialProfile) -> RadialFalloff:
    """The vignetting V that a render needs on top of its own fall-off to fall off as a real frame does.

    Both profiles must be measured on the same pixels (same mask, same rings). Per ring, the ratio real /
    render is fitted by weighted least squares as s V(rho) = s (1 + k1 rho^2 + k2 rho^4), weights sqrt(pixel
    count): ``s`` is a free level (the exposure sets it, so it says nothing about the fall-off) and V(0) = 1.
    ``profile`` holds the measured ratio over s. A fit with V > 1 somewhere says the render already falls off
    more than the real frame there: passive optics cannot brighten, so the sensor's map clips V at 1
    (:func:`rgbd2scene.sensor.vignetting.vignetting_map`).
    """
    if real.rings.shape != render.rings.shape or not np.allclose(real.rings, render.rings):
        raise ValueError("the two profiles have different rings: measure them with the same mask")
    if real.rings.size < 3:
        raise ValueError("need at least three rings to fit a level and two coefficients")
    ratio = real.levels / np.maximum(render.levels, 1e-12)
    weight = np.sqrt(real.count)
    design = np.stack([np.ones_like(real.rings), real.rings**2, real.rings**4], axis=1)
    (s, a, b), *_ = np.linalg.lstsq(design * weight[:, None], ratio * weight, rcond=None)
    if s <= 0:
        raise ValueError("the fitted level is not positive: the profiles do not describe one scene")
    k1, k2 = a / s, b / s
    return RadialFalloff(float(k1), float(k2), float(1.0 + k1 + k2), real.rings, ratio / s)


def optical_vignetting(real_rgb: np.ndarray, render_rgb: np.ndarray, mask: np.ndarray | None = None,
                       curve: str = "srgb", rings: int = 10, percentile: float = 90.0,
                       border: int = BORDER) -> RadialFalloff:
    """The vignetting to add to a render so that it falls off radially as the real frame does.

    Parameters
    ----------
    real_rgb, render_rgb
        8-bit RGB (H, W, 3) of the same view: the real frame and its render *without* vignetting (e.g. a
        digital twin at the capture's pose), both encoded with ``curve``. The render must not clip where it
        is measured (a clipped ring reads too dark): render it at a low fixed exposure.
    mask
        Pixels where both images show the scene (e.g. where the render sees a surface and the real frame has
        no overlay); default all but the ``border``.
    rings, percentile, border
        As :func:`radial_falloff`: the ``percentile`` of linear luminance per ring damps albedo changes.

    Returns
    -------
    RadialFalloff
        k1, k2 of :func:`vignetting_from_profiles` (the least-squares fit on the ratio real / render with a
        free level), and per ring the measured ratio over the fitted level.
    """
    real = radial_profile(linear_luminance(real_rgb, curve), mask, rings, percentile, border)
    render = radial_profile(linear_luminance(render_rgb, curve), mask, rings, percentile, border)
    return vignetting_from_profiles(real, render)


def radius_map(width: int, height: int) -> np.ndarray:
    """Distance of each pixel centre from the image centre, over the half-diagonal (1 at the corners)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    cu, cv = (width - 1) / 2.0, (height - 1) / 2.0
    return np.hypot(u - cu, v - cv) / np.hypot(cu, cv)
