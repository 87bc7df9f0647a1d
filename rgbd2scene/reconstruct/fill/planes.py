"""Piecewise-planar hole filling from colour segments (indoor captures: walls, floors, desks), and quadrics
round single holes (curved surfaces).

The colour image is cut into segments (:func:`colour_segments`: Felzenszwalb's graph segmentation of a
crop round the holes, at reduced resolution); each segment that a hole cuts gets a plane in inverse depth,
affine in pixel coordinates (1/z = a u + b v + c: a plane in space seen by a pinhole camera), fitted
robustly to the segment's valid pixels near the holes (:func:`fit_segment_planes`), and its hole pixels
take the plane where the segment's own valid depth says it is planar (:func:`planar_fill`): most of its
support on the plane within a small relative residual, the residual's scale near the capture's own noise
(:func:`sensor_noise`: a curved surface's shows above it), enough support, the hole pixels within the
support's spread (an interpolation, not an extrapolation far beyond it), the plane's depth at them
within the support's range, and the segment's valid pixel nearest each of them on the plane. Elsewhere
nothing is filled (NaN): the caller keeps its own fill there.

:func:`quadric_fill` applies the same evidence one order up, per hole rather than per segment: a quadric in
inverse depth fitted to the hole's ring of valid pixels, taken where the ring shows it within the noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy import ndimage as ndi

from rgbd2scene.reconstruct.fill.holes import components, valid_depth

#: Relative residual (|1/z_plane - 1/z| * z, about the relative depth error) under which a support pixel
#: counts as on its segment's plane.
PLANE_TOL = 0.01
#: Share of a segment's support that must lie on its plane.
PLANE_INLIERS = 0.8
#: Fewest support pixels a plane is fitted to (of every other row and column: about 4 times as many in all).
PLANE_MIN_SUPPORT = 20
#: A segment is planar only where its residual's robust scale is at most this multiple of the capture's noise.
PLANE_NOISE = 2.0
#: The least relative noise :func:`sensor_noise` returns (noise-free depth, a renderer's: float rounding is not noise).
NOISE_FLOOR = 1e-4
#: :func:`noise_correlation` needs this many adjacent pairs with a residual (1, not white, below it).
MIN_NOISE_PAIRS = 400
#: Support: the segment's valid pixels within this many px of the holes.
PLANE_REACH = 40
#: A hole pixel takes its segment's plane only within this Mahalanobis distance of the support's pixel spread.
PLANE_SPREAD = 2.5
#: The plane's depth at the hole pixels must lie within the support's inverse-depth range widened by this share of it.
PLANE_RANGE = 0.25
#: A hole's quadric (:func:`quadric_fill`) is fitted to its valid pixels within this many px of it.
QUADRIC_REACH = 10
#: Fewest ring pixels a quadric is fitted to (of every other row and column).
QUADRIC_MIN_SUPPORT = 40


@dataclass
class SegmentPlanes:
    """Per segment label (index 0 unused where labels start at 1): plane coefficients of 1/z in the normalised
    pixel coordinates of :func:`fit_segment_planes`, support pixel count, inlier share, robust scale."""

    coef: np.ndarray  # (n, 3)
    support: np.ndarray  # (n,)
    inliers: np.ndarray  # (n,)
    scale: np.ndarray  # (n,) robust scale of the relative residual: 1.4826 times its median absolute value


def colour_segments(rgb: np.ndarray, scale: int = 2, k: float = 150.0, sigma: float = 0.8,
                    min_size: int = 40) -> np.ndarray:
    """Felzenszwalb's graph segmentation of ``rgb`` at 1 / ``scale`` resolution, labels back at full size.

    Parameters
    ----------
    rgb : uint8 (H, W, 3).
    scale : the image is reduced by this factor (area averaging) before segmenting.
    k, sigma, min_size : :func:`skimage.segmentation.felzenszwalb`'s ``scale``, ``sigma`` and ``min_size``
        (the last in reduced pixels).

    Returns
    -------
    int32 (H, W) labels from 0.
    """
    from skimage.segmentation import felzenszwalb

    h, w = rgb.shape[:2]
    small = rgb if scale == 1 else cv2.resize(rgb, (max(w // scale, 1), max(h // scale, 1)),
                                              interpolation=cv2.INTER_AREA)
    lab = felzenszwalb(small, scale=k, sigma=sigma, min_size=min_size).astype(np.int32)
    if scale == 1:
        return lab
    return cv2.resize(lab, (w, h), interpolation=cv2.INTER_NEAREST)


def _irls(basis: np.ndarray, inv: np.ndarray, seg: np.ndarray, n: int, tol: float,
          iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment robust least squares of ``inv`` on the columns of ``basis`` (Cauchy weights of the relative
    residual, scale ``tol``); returns the coefficients (n, k) and each pixel's relative residual."""
    k = basis.shape[1]
    wgt = np.ones_like(inv)
    coef = np.zeros((n, k))
    pairs = [(i, j) for i in range(k) for j in range(i, k)]
    for _ in range(iterations + 1):
        ata = np.zeros((n, k, k))
        atb = np.zeros((n, k))
        for i, j in pairs:
            s = np.bincount(seg, weights=wgt * basis[:, i] * basis[:, j], minlength=n)
            ata[:, i, j] = s
            ata[:, j, i] = s
        for i in range(k):
            atb[:, i] = np.bincount(seg, weights=wgt * basis[:, i] * inv, minlength=n)
        ok = ata[:, 0, 0] > 2 * k
        ata[ok] += (1e-9 * ata[ok, 0, 0])[:, None, None] * np.eye(k)
        coef[ok] = np.linalg.solve(ata[ok], atb[ok][..., None])[..., 0]
        rel = (basis * coef[seg]).sum(axis=1) / inv - 1.0
        wgt = 1.0 / (1.0 + (rel / tol) ** 2)
    return coef, rel


def fit_segment_planes(inv: np.ndarray, u: np.ndarray, v: np.ndarray, seg: np.ndarray, n: int,
                       tol: float = PLANE_TOL, iterations: int = 4) -> SegmentPlanes:
    """Robust plane fits, all segments at once: 1/z = a u + b v + c per segment by iteratively reweighted
    least squares (Cauchy weights of the relative residual with scale ``tol``), normal equations summed
    per segment with :func:`numpy.bincount` and solved as a batch.

    Parameters
    ----------
    inv : float (m,) inverse depth of the support pixels.
    u, v : float (m,) their normalised pixel coordinates (centred and scaled by the caller: conditioning).
    seg : int (m,) their segment, in [0, n).
    n : number of segments.
    tol : scale of the relative residual.
    iterations : reweighting rounds after the plain least-squares fit.

    Returns
    -------
    SegmentPlanes
    """
    coef, rel = _irls(np.stack([np.ones_like(u), u, v], axis=1), inv, seg, n, tol, iterations)
    support = np.bincount(seg, minlength=n).astype(np.float64)
    share = np.bincount(seg, weights=np.abs(rel) < tol, minlength=n) / np.maximum(support, 1)
    return SegmentPlanes(coef, support, share, _robust_scale(rel, seg, n))


def _robust_scale(rel: np.ndarray, seg: np.ndarray, n: int) -> np.ndarray:
    """Per segment, 1.4826 times the median absolute value of ``rel`` over its pixels (inf where it has none)."""
    support = np.bincount(seg, minlength=n)
    order = np.lexsort((np.abs(rel), seg))
    first = np.searchsorted(seg[order], np.arange(n))
    mid = np.minimum(first + support // 2, max(seg.size - 1, 0))
    return np.where(support > 0, 1.4826 * np.abs(rel[order][mid]), np.inf)


def _window_residual(depth: np.ndarray, valid: np.ndarray, win: int, degree: int = 1) -> tuple[np.ndarray, float]:
    """The inverse depth relative to its least-squares polynomial of ``degree`` (1: a plane, whose value at the
    centre is the window's mean; 2: a quadric) over a ``win`` x ``win`` window, minus 1, at the pixels whose
    window is all valid (NaN elsewhere); and the centre pixel's leverage in that fit (white noise's residual
    there has 1 - leverage of its variance)."""
    inv = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0).astype(np.float32)
    full = cv2.blur(valid.astype(np.float32), (win, win), borderType=cv2.BORDER_CONSTANT) > 1 - 1e-6
    if degree == 1:
        fit, leverage = cv2.blur(inv, (win, win), borderType=cv2.BORDER_CONSTANT), 1.0 / win**2
    else:  # the fit's value at the centre is a weighted sum over the window (symmetric: correlation = convolution)
        r = win // 2
        x, y = np.meshgrid(np.arange(-r, r + 1.0), np.arange(-r, r + 1.0))
        basis = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1).reshape(win * win, -1)
        centre = np.linalg.pinv(basis)[0].reshape(win, win)
        fit = cv2.filter2D(inv, -1, centre.astype(np.float32), borderType=cv2.BORDER_CONSTANT)
        leverage = float(centre[r, r])
    return np.where(full, inv / np.where(full, fit, 1.0) - 1.0, np.nan), leverage


def sensor_noise(depth: np.ndarray, valid: np.ndarray, win: int = 7, degree: int = 1) -> float:
    """The capture's relative depth noise: 1.4826 times the median absolute difference between the inverse depth
    and its least-squares polynomial of ``degree`` over a ``win`` x ``win`` window (1: a plane, the window's mean;
    2: a quadric, so that a smooth surface's curvature is not counted), over the pixels whose window is all
    valid, scaled by that difference's standard deviation for white noise, relative to the inverse depth."""
    res, leverage = _window_residual(depth, valid, win, degree)
    res = np.abs(res[np.isfinite(res)])
    if not res.size:
        return np.inf
    return max(float(1.4826 * np.median(res) / np.sqrt(1.0 - leverage)), NOISE_FLOOR)


def noise_free(depth: np.ndarray, valid: np.ndarray, win: int = 7) -> bool:
    """Whether the capture is noise-free (depth from CT, a renderer): a quadric over each ``win`` x ``win`` window
    leaves a residual at the floor (:func:`sensor_noise` of degree 2 at :data:`NOISE_FLOOR`). The plane's residual
    (degree 1) counts a smooth surface's curvature as noise: the tissue sample's organ from CT 2.5e-4 with a plane,
    4.5e-5 with a quadric; the benchmark's captures with a sensor's noise 8.4e-4 (the tissue sample) to 3.3e-3
    with a quadric."""
    return sensor_noise(depth, valid, win, degree=2) <= NOISE_FLOOR


def noise_correlation(depth: np.ndarray, valid: np.ndarray, win: int = 7, min_pairs: int = MIN_NOISE_PAIRS) -> float:
    """How much neighbouring pixels share the capture's depth noise: the correlation of the residuals of
    :func:`sensor_noise` (the inverse depth against its window's mean) of horizontally adjacent pixels, and of
    vertically adjacent ones, whichever is larger (1 where fewer than ``min_pairs`` adjacent pairs have one: a
    small patch of a Kinect's plateaus can read as white, 13 % of the NYU frame's 48 x 48 crops do).

    White noise, each pixel's own, gives about -0.02 (the windows' shared mean); a Kinect's disparity
    quantised in plateaus, a surface's relief finer than the window, or the curvature of noise-free depth give
    0.5-0.8 (the benchmark's captures: TUM 0.61, NYU 0.66, SUN 0.56, Redwood 0.79, the tissue sample's organ
    from CT 0.80); the tissue sample's simulated Kinect noise on a smooth surface 0.26."""
    res = _window_residual(depth, valid, win)[0]
    out = []
    for a, b in ((res[:, :-1], res[:, 1:]), (res[:-1], res[1:])):
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() >= min_pairs:
            x, y = a[ok].astype(np.float64), b[ok].astype(np.float64)
            out.append(float((x * y).mean() / max(np.sqrt((x * x).mean() * (y * y).mean()), 1e-300)))
    return max(out, default=1.0)


class _Crop(NamedTuple):
    box: tuple[slice, slice]  # the crop in the image
    depth: np.ndarray
    mask: np.ndarray
    valid: np.ndarray  # valid depth outside the mask
    noise: float  # sensor_noise on the crop


def _crop_round(depth: np.ndarray, mask: np.ndarray, reach: int) -> _Crop | None:
    """``depth`` and ``mask`` cropped to ``mask``'s bounding box widened by ``reach`` px (within the image), with
    the noise measured on the crop; None where ``mask`` is empty or no window of the crop is all valid (no noise
    to measure: no evidence of a model)."""
    if not mask.any():
        return None
    h, w = mask.shape
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    box = np.s_[max(rows[0] - reach, 0):min(rows[-1] + reach + 1, h),
                max(cols[0] - reach, 0):min(cols[-1] + reach + 1, w)]
    d, m = depth[box], mask[box]
    valid = valid_depth(d) & ~m
    noise = sensor_noise(d, valid)
    return _Crop(box, d, m, valid, noise) if np.isfinite(noise) else None


def planar_fill(depth: np.ndarray, rgb: np.ndarray, mask: np.ndarray, *, tol: float = PLANE_TOL,
                inliers: float = PLANE_INLIERS, min_support: int = PLANE_MIN_SUPPORT, reach: int = PLANE_REACH,
                spread: float = PLANE_SPREAD, margin: float = PLANE_RANGE, noise_ratio: float = PLANE_NOISE,
                seg_scale: int = 2, segments: np.ndarray | None = None) -> np.ndarray:
    """The pixels of ``mask`` filled from their colour segment's plane where the capture shows it planar.

    A crop of ``rgb`` round ``mask`` (``reach`` px beyond it) is segmented (:func:`colour_segments`); each
    segment's support is its valid pixels within ``reach`` px of ``mask``; a plane in inverse depth is fitted
    to it (:func:`fit_segment_planes`; on every other row and column of the support: a quarter of the work).
    A segment's hole pixels take its plane where: at least ``min_support`` support pixels, at least ``inliers``
    of them within ``tol`` relative residual of the plane (a segment across two surfaces fails this), the
    residual's robust scale at most ``noise_ratio`` times the capture's own noise (:func:`sensor_noise`, on the
    crop: a curved surface fails this where its curvature shows above the noise, as on the tissue sample
    against a Kinect's planar walls; where no window of the crop is all valid, so that there is no noise to
    measure, no segment passes), the hole pixel within Mahalanobis distance ``spread`` of the support
    pixels' mean and covariance in the image (no extrapolation far beyond the support), the plane's
    inverse depth there within the support's range widened by ``margin`` of it on either side, and the
    segment's valid pixel nearest the hole pixel on the plane, within three times the robust scale of the
    segment's residual and at least ``tol`` (:func:`_nearest_on_plane`).

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    rgb : uint8 (H, W, 3).
    mask : bool (H, W) the pixels to fill.
    tol, inliers, min_support, reach, noise_ratio, spread, margin : the tests above (defaults: the module's
        ``PLANE_*`` constants).
    seg_scale : the segmentation's reduction (:func:`colour_segments`).
    segments : int (H, W) labels to use instead of segmenting (tests).

    Returns
    -------
    float32 (H, W): the plane's depth on the pixels of ``mask`` it fills, NaN elsewhere.
    """
    out = np.full(depth.shape, np.nan, dtype=np.float32)
    crop = _crop_round(depth, mask, reach)
    if crop is None:
        return out
    box, d, m, valid, noise = crop
    if segments is None:
        seg = colour_segments(rgb[box], scale=seg_scale)
    else:
        seg = segments[box].astype(np.int32)
    n = int(seg.max()) + 1
    near = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 3) <= reach
    cut = np.zeros(n, dtype=bool)
    cut[seg[m]] = True
    sup = valid & near & cut[seg]
    sup[1::2, :] = False  # every other row and column: a quarter of the pixels, the same planes
    sup[:, 1::2] = False
    if not sup.any():
        return out
    hh, ww = d.shape
    norm = max(hh, ww) / 2.0
    vv, uu = np.nonzero(sup)
    su = (uu - ww / 2.0) / norm
    sv = (vv - hh / 2.0) / norm
    ss = seg[sup]
    inv = 1.0 / d[sup].astype(np.float64)
    planes = fit_segment_planes(inv, su, sv, ss, n, tol)
    good = (planes.support >= min_support) & (planes.inliers >= inliers) & (planes.scale <= noise_ratio * noise) & cut
    if not good.any():
        return out
    hv, hu = np.nonzero(m)
    hs = seg[m]
    take = good[hs]
    hv, hu, hs = hv[take], hu[take], hs[take]
    qu = (hu - ww / 2.0) / norm
    qv = (hv - hh / 2.0) / norm
    pred = planes.coef[hs, 0] + planes.coef[hs, 1] * qu + planes.coef[hs, 2] * qv
    ok = _within_support(su, sv, ss, inv, n, qu, qv, hs, pred, spread, margin)
    # the nearest pixel on the plane within its segment's own scatter (3 robust sigmas), at least tol
    ok[ok] = _nearest_on_plane(d, valid & near, seg, planes.coef, norm, hv[ok], hu[ok], hs[ok],
                               np.maximum(tol, 3 * planes.scale))
    out[box][hv[ok], hu[ok]] = (1.0 / pred[ok]).astype(np.float32)
    return out


def _nearest_on_plane(d, valid, seg, coef, norm, hv, hu, hs, bound) -> np.ndarray:
    """Per hole pixel (``hv, hu`` of the crop ``d``, in segment ``hs`` of ``seg``): the segment's ``valid`` pixel
    nearest it lies on the segment's plane (``coef``, in coordinates centred on the crop and divided by
    ``norm``): its relative residual within the segment's ``bound``.

    The inlier test passes a segment with a fifth of its support off its plane; where a hole hides most of a
    surface that the segmentation merged into the segment (a box in front of a wall of its colour, a transplanted
    mask's hole across a depth step), the plane is the other surface's, and the hole's pixels beside what
    is left of that surface took it. The depth measured nearest a hole pixel, in its own segment, is the
    evidence of which surface it lies on."""
    hh, ww = d.shape
    keep = np.zeros(hv.size, dtype=bool)
    boxes = ndi.find_objects(seg + 1)
    for s in np.unique(hs):
        box = boxes[s]
        src = valid[box] & (seg[box] == s)
        if not src.any():
            continue
        _, (iy, ix) = ndi.distance_transform_edt(~src, return_indices=True)
        pick = hs == s
        ny = iy[hv[pick] - box[0].start, hu[pick] - box[1].start] + box[0].start
        nx = ix[hv[pick] - box[0].start, hu[pick] - box[1].start] + box[1].start
        plane = coef[s, 0] + coef[s, 1] * (nx - ww / 2.0) / norm + coef[s, 2] * (ny - hh / 2.0) / norm
        keep[pick] = np.abs(plane * d[ny, nx] - 1.0) < bound[s]
    return keep


def quadric_fill(depth: np.ndarray, mask: np.ndarray, *, reach: int = QUADRIC_REACH, tol: float = PLANE_TOL,
                 inliers: float = PLANE_INLIERS, min_support: int = QUADRIC_MIN_SUPPORT,
                 noise_ratio: float = PLANE_NOISE, spread: float = PLANE_SPREAD,
                 margin: float = PLANE_RANGE) -> np.ndarray:
    """The pixels of ``mask`` filled from a quadric fitted round each of its holes, where the capture shows one.

    Each 8-connected hole of ``mask`` gets a quadric in inverse depth (1/z a polynomial of degree 2 in the
    pixel coordinates: a curved surface seen at close range, to second order), fitted robustly to the valid
    pixels within ``reach`` px of the hole (its ring; on every other row and column) as the planes are
    (:func:`fit_segment_planes`'s reweighting, six columns). Its pixels take the quadric on the tests of
    :func:`planar_fill`: at least ``min_support`` ring pixels, ``inliers`` of them within ``tol`` of it, the
    residual's robust scale at most ``noise_ratio`` times the capture's noise (:func:`sensor_noise`, on the
    crop round the holes: a ring that a fold, a crease or a depth step crosses fails it; no ring passes where
    there is no noise to measure, as for the planes), the pixel within
    the ring's spread and the quadric within its inverse-depth range widened by ``margin``. A narrow ring
    (``reach`` 10 px, not the planes' 40; 8 and 15 px did worse on the benchmark's tuning split): a surface
    is a quadric only locally, and over a large hole none fits (the tissue sample's large holes: a quadric
    from a ring of 20-80 px has 1.1-4.4 times the best plain fill's error there, and the ring test refuses
    them; ``benchmarks/results/fill.md``, session 12).

    Parameters
    ----------
    depth : float (H, W) metres, NaN = invalid.
    mask : bool (H, W) the pixels to fill.
    reach, tol, inliers, min_support, noise_ratio, spread, margin : the tests above.

    Returns
    -------
    float32 (H, W): the quadric's depth on the pixels of ``mask`` it fills, NaN elsewhere.
    """
    out = np.full(depth.shape, np.nan, dtype=np.float32)
    crop = _crop_round(depth, mask, reach)
    if crop is None:
        return out
    box, d, m, valid, noise = crop
    labels, n = components(m)
    n += 1
    # each ring pixel to its nearest hole, within reach (where two rings meet, each keeps its own side)
    distance, (near_v, near_u) = ndi.distance_transform_edt(~m, return_indices=True)
    owner = np.where(distance <= reach, labels[near_v, near_u], 0).astype(np.int64)
    sup = valid & (owner > 0)
    sup[1::2, :] = False  # every other row and column, as the planes
    sup[:, 1::2] = False
    if not sup.any():
        return out
    vv, uu = np.nonzero(sup)
    ss = owner[sup]
    inv = 1.0 / d[sup].astype(np.float64)
    # coordinates centred on each ring and scaled by its extent: the squares stay well conditioned
    cnt = np.maximum(np.bincount(ss, minlength=n), 1)
    cu = np.bincount(ss, weights=uu, minlength=n) / cnt
    cv = np.bincount(ss, weights=vv, minlength=n) / cnt
    ext = np.zeros(n)
    np.maximum.at(ext, ss, np.maximum(np.abs(uu - cu[ss]), np.abs(vv - cv[ss])))
    ext = np.maximum(ext, 1.0)
    su, sv = (uu - cu[ss]) / ext[ss], (vv - cv[ss]) / ext[ss]
    coef, rel = _irls(_quadric_basis(su, sv), inv, ss, n, tol, 4)
    share = np.bincount(ss, weights=np.abs(rel) < tol, minlength=n) / cnt
    scale = _robust_scale(rel, ss, n)
    good = (np.bincount(ss, minlength=n) >= min_support) & (share >= inliers) & (scale <= noise_ratio * noise)
    hv, hu = np.nonzero(m)
    hs = labels[m]
    take = good[hs]
    hv, hu, hs = hv[take], hu[take], hs[take]
    qu, qv = (hu - cu[hs]) / ext[hs], (hv - cv[hs]) / ext[hs]
    pred = (_quadric_basis(qu, qv) * coef[hs]).sum(axis=1)
    ok = _within_support(su, sv, ss, inv, n, qu, qv, hs, pred, spread, margin)
    out[box][hv[ok], hu[ok]] = (1.0 / pred[ok]).astype(np.float32)
    return out


def _quadric_basis(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Columns 1, u, v, u^2, u v, v^2."""
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=1)


def _within_support(su, sv, ss, inv, n, qu, qv, hs, pred, spread: float, margin: float) -> np.ndarray:
    """Which hole pixels (normalised coordinates ``qu, qv``, group ``hs``, predicted inverse depth ``pred``) lie
    within Mahalanobis distance ``spread`` of their group's support pixels (``su, sv``, group ``ss``, inverse
    depth ``inv``) in the image, with ``pred`` positive and within the support's inverse-depth range widened by
    ``margin`` of it on either side."""
    cnt = np.maximum(np.bincount(ss, minlength=n), 1)
    mu = np.bincount(ss, weights=su, minlength=n) / cnt
    mv = np.bincount(ss, weights=sv, minlength=n) / cnt
    cuu = np.bincount(ss, weights=(su - mu[ss]) ** 2, minlength=n) / cnt + 1e-6
    cvv = np.bincount(ss, weights=(sv - mv[ss]) ** 2, minlength=n) / cnt + 1e-6
    cuv = np.bincount(ss, weights=(su - mu[ss]) * (sv - mv[ss]), minlength=n) / cnt
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, ss, inv)
    np.maximum.at(hi, ss, inv)
    du, dv = qu - mu[hs], qv - mv[hs]
    det = cuu[hs] * cvv[hs] - cuv[hs] ** 2
    maha = (cvv[hs] * du**2 - 2 * cuv[hs] * du * dv + cuu[hs] * dv**2) / np.maximum(det, 1e-12)
    span = (hi - lo)[hs]
    sane = (pred > 0) & (pred >= lo[hs] - margin * span) & (pred <= hi[hs] + margin * span)
    return (maha <= spread**2) & sane
