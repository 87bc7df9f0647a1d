"""``depth``: the depth map against the scene oracle's ray cast at the recorded K and pose.

Median / p99 error over pixels with surface in both; the image shift that best explains the differences
(a half-pixel convention slip or a wrong principal point shows here even where the errors are tiny); and
the valid masks, allowing a thin band of mismatch at silhouettes. Only pixels the oracle models count.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from rgbd2scene.dataset.layout import EYES
from rgbd2scene.verify.error_maps import ErrorPanel, pixel_states, ratio, worst
from rgbd2scene.verify.framework import Check, EyeFrame, VerifyRun, median_p99
from rgbd2scene.verify.report import fmt


class DepthCheck(Check):
    names = ("depth",)
    maps = ("depth",)
    needs_oracle = True

    def declare(self, run: VerifyRun) -> None:
        for eye in EYES:
            run.collector.metric("depth", eye, "median abs error", run.tol.depth_median_mm, unit="mm",
                                 note=run.no_pixels_note)

    def check_eye(self, frame: EyeFrame) -> None:
        consider = frame.oracle_pixels
        if not consider.any():
            return
        tol, depth, surface = frame.run.tol, frame.depth, frame.surface
        cast = frame.cast
        ref_depth = cast.depth.astype(np.float64)
        ref_ok = cast.hit
        both = surface & ref_ok & consider
        med = p99 = shift = float("nan")
        if both.any():
            err_mm = np.abs(depth[both] - ref_depth[both]) * 1000.0
            med, p99 = median_p99(err_mm)
            shift = image_shift(depth, ref_depth, both)
            frame.add("depth", "median abs error", med, tol.depth_median_mm, unit="mm")
            frame.add("depth", "p99 abs error", p99, tol.depth_p99_mm, unit="mm")
            frame.add("depth", "image shift explaining the error", shift, tol.depth_shift_px, unit="px")
        mismatch = (surface != ref_ok) & consider
        band = silhouette_band(ref_ok, tol.mask_band_px) | silhouette_band(surface, tol.mask_band_px)
        off = float((mismatch & ~band).sum() / consider.size)
        frame.add("depth", "valid-mask mismatch off silhouettes (frac)", off, tol.mask_mismatch)
        frame.add("depth", "valid-mask mismatch incl. silhouettes (frac)", float(mismatch.sum() / consider.size),
                  None)
        if frame.errors is not None:
            frame.errors.ref_depth = cast.depth.astype(np.float32)
            value = np.full(frame.run.shape, np.nan, np.float32)
            if both.any():
                value[both] = err_mm * 1000.0
            note = f"median {fmt(med * 1000.0, 'um')}, p99 {fmt(p99 * 1000.0, 'um')}"
            frame.errors.panels["depth"] = ErrorPanel(value, pixel_states(surface, ref_ok, consider), "|depth error|",
                                                      note)
            frame.errors.scores["depth"] = worst(ratio(med, tol.depth_median_mm), ratio(p99, tol.depth_p99_mm),
                                                 ratio(shift, tol.depth_shift_px), ratio(off, tol.mask_mismatch))


def silhouette_band(mask: np.ndarray, band: int) -> np.ndarray:
    """Pixels within ``band`` pixels of a boundary of ``mask`` (either side)."""
    if band <= 0:
        return np.zeros_like(mask)
    st = np.ones((2 * band + 1, 2 * band + 1), bool)
    return ndimage.binary_dilation(mask, st) & ~ndimage.binary_erosion(mask, st, border_value=1)


def image_shift(depth: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """Length (px) of the image shift (du, dv) that best explains depth - ref by ref's gradient.

    A half-pixel convention slip or a wrong principal point shows up here even where the depth
    errors themselves are tiny (gentle slopes). NaN when the surface has too little slope to tell.
    """
    gv, gu = np.gradient(ref)
    diff = depth - ref
    ok = mask & np.isfinite(gu) & np.isfinite(gv) & np.isfinite(diff)
    if ok.sum() < 16:
        return float("nan")
    g = np.stack([gu[ok], gv[ok]], axis=-1)
    d = diff[ok]
    mag = np.linalg.norm(g, axis=-1)
    keep = mag <= 10.0 * np.median(mag) + 1e-12  # leave out depth edges
    g, d = g[keep], d[keep]
    A = g.T @ g
    w = np.linalg.eigvalsh(A)
    scale = float(np.median(np.abs(ref[ok]))) * 1e-6  # slope (m/px) too small to resolve a shift
    if w[0] <= (scale**2) * len(d):
        return float("nan")
    # depth(p) = ref(p + shift)  =>  depth - ref = g . shift
    shift = np.linalg.solve(A, g.T @ d)
    return float(np.linalg.norm(shift))
