"""Stereo difficulty of a rectified pair: how well the project's stereo methods (SGBM, ELAS of
:mod:`rgbd2scene.evaluate.methods`) match it.

Per method: **density** (the share of the measured pixels that get a disparity), **left-right consistency**
(the share of those whose match in the right image, found by matching the mirrored pair, points back within
``LR_TOLERANCE_PX``), and where the pair's own ground-truth disparity is known, the **end-point error**
(mean |d - d_gt|, pixels) and the **bad-2 rate** (share of matched ground-truth pixels off by more than 2 px).

A raw (unrectified) pair is rectified first with :func:`rectify_with`: ``cv2.stereoRectify`` with ``alpha=0``
at the same image size (as CONVENTIONS section 2 defines the rectified pair), the mask carried along.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rgbd2scene.capture.stereo import rectify, rectify_pair
from rgbd2scene.evaluate.methods import DisparityRange, StereoMethod
from rgbd2scene.geometry.stereo import StereoCalibration

#: A left match is consistent when the right view's disparity at its match differs by at most this (pixels).
LR_TOLERANCE_PX = 1.0
#: A ground-truth pixel counts as "bad" when the method's disparity is off by more than this (pixels).
BAD_PX = 2.0


@dataclass(frozen=True)
class StereoScore:
    """One method on one pair; ``epe``/``bad2`` are NaN without ground truth."""

    method: str
    density: float
    lr_consistency: float
    epe: float = math.nan
    bad2: float = math.nan


def right_disparity(method: StereoMethod, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The right view's disparity (positive; a right pixel (u, v) matches the left (u + d, v)): the method run
    on the mirrored pair, whose left image is the mirrored right one."""
    mirrored = method(0, np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]))
    return np.ascontiguousarray(mirrored[:, ::-1])


def lr_consistent(d_left: np.ndarray, d_right: np.ndarray, tolerance: float = LR_TOLERANCE_PX) -> np.ndarray:
    """Left pixels whose disparity agrees with the right view's at the matched pixel (round(u - d), v)."""
    h, w = d_left.shape
    u = np.arange(w)[None, :] - np.nan_to_num(d_left, nan=-1e9)
    ur = np.rint(u).astype(np.int64)
    inside = np.isfinite(d_left) & (ur >= 0) & (ur < w)
    back = np.full(d_left.shape, np.nan)
    rows = np.broadcast_to(np.arange(h)[:, None], d_left.shape)
    back[inside] = d_right[rows[inside], ur[inside]]
    with np.errstate(invalid="ignore"):
        return inside & (np.abs(back - d_left) <= tolerance)


def score_pair(method: StereoMethod, left: np.ndarray, right: np.ndarray, mask: np.ndarray | None = None,
               gt_disparity: np.ndarray | None = None) -> StereoScore:
    """Density, left-right consistency and (with ``gt_disparity``, NaN where unknown) the error of ``method``
    on the pair, over the ``mask`` pixels (all when None)."""
    mask = np.ones(left.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    d = np.asarray(method(0, left, right), np.float64)
    with np.errstate(invalid="ignore"):
        d[~(d > 0)] = np.nan
    matched = np.isfinite(d) & mask
    density = float(matched.sum() / max(mask.sum(), 1))
    consistent = lr_consistent(d, np.asarray(right_disparity(method, left, right), np.float64)) & mask
    lr = float(consistent.sum() / matched.sum()) if matched.any() else 0.0
    epe = bad2 = math.nan
    if gt_disparity is not None:
        gt = np.asarray(gt_disparity, np.float64)
        both = matched & np.isfinite(gt)
        if both.any():
            err = np.abs(d[both] - gt[both])
            epe, bad2 = float(err.mean()), float(np.mean(err > BAD_PX))
    return StereoScore(method.name, density, lr, epe, bad2)


def scaled_range(base: DisparityRange, factor: float) -> DisparityRange:
    """The same depths seen by a rig with ``factor`` times the focal length x baseline."""
    return DisparityRange(base.low * factor, base.high * factor)


@dataclass
class RectifiedView:
    """A pair made ready for matching: rectified images, the mask in the rectified grid, f·B (px·m)."""

    left: np.ndarray
    right: np.ndarray
    mask: np.ndarray
    focal_baseline: float


def rectify_with(calib: StereoCalibration, left: np.ndarray, right: np.ndarray,
                 mask: np.ndarray | None = None) -> RectifiedView:
    """Rectify a raw pair with its calibration (``alpha=0``, same size); the mask keeps the left pixels that hold
    image data in both eyes and lie inside ``mask`` (nearest neighbour)."""
    rect = rectify(calib, alpha=0.0, keep_resolution=False)
    pair = rectify_pair(calib, rect, left, right)
    valid = pair.left_mask & pair.right_mask
    if mask is not None:
        mx, my = rect.maps("left", calib.K_left, calib.D_left)
        valid &= cv2.remap(np.asarray(mask, np.uint8), mx, my, cv2.INTER_NEAREST).astype(bool)
    return RectifiedView(pair.left, pair.right, valid, float(rect.K[0, 0] * rect.baseline))
