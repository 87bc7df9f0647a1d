"""``stereo``: left and right depth agree through the disparity (CONVENTIONS.md section 2).

A left pixel (u, v) sees what the right pixel (u - d, v) sees (and a right pixel (u, v) what the left pixel
(u + d, v) sees). The other eye's disparity, sampled there, must equal this eye's where the point is not
occluded in the other eye; it must never be smaller (the other eye would see through the surface) than both
samples around the matching position: between two pixel centres a convex surface (an instrument's shaft near
its silhouette) bulges towards the camera, so the interpolated disparity there lies behind it. Samples that
straddle a depth edge in the other eye, or leave its image, are not compared.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.conventions import disparity_from_depth
from rgbd2scene.verify.error_maps import ErrorPanel, PixelState
from rgbd2scene.verify.framework import Check, PairFrame, Tolerances, VerifyRun
from rgbd2scene.verify.report import fmt

#: report label -> (source eye, other eye, sign of d where the source pixel is found in the other eye)
PAIRS = {"L->R": ("left", "right", -1.0), "R->L": ("right", "left", 1.0)}


@dataclass
class Consistency:
    """How one eye's depth agrees with the other eye's (see :func:`lr_consistency`)."""

    further: float  # fraction of compared pixels where the other eye sees further than this eye's surface
    median: float  # median |disparity difference| over compared pixels not occluded in the other eye (px)
    occluded: float  # fraction of compared pixels occluded in the other eye
    compared: int  # number of compared pixels
    value: np.ndarray | None = None  # per pixel |disparity difference| (px, NaN where not compared or occluded)
    state: np.ndarray | None = None  # per pixel PixelState


class StereoCheck(Check):
    names = ("stereo",)
    maps = ("depth",)

    def applies_to(self, frame) -> bool:
        return frame.run.rectified and super().applies_to(frame)  # a raw pair: the correspondence check

    def declare(self, run: VerifyRun) -> None:
        if not run.rectified:
            return
        for label in PAIRS:
            run.collector.metric("stereo", label, "other eye sees further (frac)", run.tol.lr_inconsistent,
                                 note=run.no_pixels_note)

    def check_pair(self, pair: PairFrame) -> None:
        tol = pair.run.tol
        eyes = {"left": pair.left, "right": pair.right}
        fx = float(pair.left.K[0, 0])
        for label, (src, dst, sign) in PAIRS.items():
            owner = eyes[src]
            c = lr_consistency(owner.gt["depth"], eyes[dst].gt["depth"], fx, pair.run.baseline, sign, tol,
                               maps=owner.errors is not None)
            if c.compared:
                pair.add("stereo", label, "other eye sees further (frac)", c.further, tol.lr_inconsistent)
                pair.add("stereo", label, "median |disparity diff|", c.median, tol.lr_median_px, unit="px")
                pair.add("stereo", label, "occluded in other eye (frac)", c.occluded, None)
            if owner.errors is not None:
                note = (f"further {fmt(100 * c.further, '%')}, median {fmt(c.median, 'px')}, "
                        f"occluded {fmt(100 * c.occluded, '%')}" if c.compared else "no pixels to compare")
                owner.errors.panels["stereo"] = ErrorPanel(c.value, c.state, f"{label} disparity mismatch", note)


def lr_consistency(z_src: np.ndarray, z_dst: np.ndarray, fx: float, baseline: float, sign: float,
                   tol: Tolerances, maps: bool = False) -> Consistency:
    """Compare source depth with the other eye's depth sampled where the disparity sends each pixel.

    ``sign`` = -1 for left -> right (u - d), +1 for right -> left (u + d). With ``maps``, the result also
    holds the per-pixel difference and state maps (for the error-map pictures).
    """
    d_src = disparity_from_depth(z_src, fx, baseline, dtype=np.float64)
    d_dst = disparity_from_depth(z_dst, fx, baseline, dtype=np.float64)
    h, w = z_src.shape
    u = np.arange(w, dtype=np.float64)[None, :] + sign * d_src
    ok = np.isfinite(u) & (u >= 0) & (u <= w - 1)
    u0 = np.clip(np.floor(np.where(ok, u, 0)).astype(np.int64), 0, w - 1)
    u1 = np.minimum(u0 + 1, w - 1)
    a = np.where(ok, u, 0) - u0
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    g0, g1 = d_dst[rows, u0], d_dst[rows, u1]
    inside = ok.copy()
    sampled = np.isfinite(g0) & np.isfinite(g1)
    with np.errstate(invalid="ignore"):
        ok &= sampled & (np.abs(g0 - g1) <= tol.lr_jump_px)
        diff = (1 - a) * g0 + a * g1 - d_src  # > 0: the other eye sees something closer (occlusion)
        behind = np.maximum(g0, g1) - d_src < -tol.lr_threshold_px  # further than both samples
    n = int(ok.sum())
    result = Consistency(float("nan"), float("nan"), float("nan"), 0)
    if n:
        compared = diff[ok]
        occluded = compared > tol.lr_threshold_px
        further = behind[ok]
        visible = np.abs(compared[~occluded])
        result = Consistency(float(further.sum() / n), float(np.median(visible)) if visible.size else float("nan"),
                             float(occluded.sum() / n), n)
    if maps:
        src = np.isfinite(d_src)
        state = np.full((h, w), PixelState.NO_SURFACE, np.uint8)
        state[src] = PixelState.NOT_COMPARED  # leaves the other image, or samples across a depth edge there
        state[src & inside & ~sampled] = PixelState.ONE_SOURCE  # the other eye has no surface where this one points
        state[ok] = PixelState.COMPARED
        with np.errstate(invalid="ignore"):
            state[ok & (diff > tol.lr_threshold_px)] = PixelState.OCCLUDED
        value = np.full((h, w), np.nan, np.float32)
        value[state == PixelState.COMPARED] = np.abs(diff[state == PixelState.COMPARED])
        result.value, result.state = value, state
    return result
