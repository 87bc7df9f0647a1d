"""Depth metrics of a predicted disparity map against ground truth (after Eigen et al. 2014), pure functions.

A prediction is a left disparity map in pixels; its depth is z = fx·B/d (:func:`conventions.depth_from_disparity`).
A prediction pixel is *valid* where d is finite and positive. Scores cover the valid ground-truth pixels (finite
depth), two ways, so that a sparse method is never flattered:

- ``valid``: only the pixels where the prediction is valid too; ``density`` says how many of the ground-truth
  pixels that is (a fraction).
- ``all``: every valid ground-truth pixel, invalid predictions filled first with the nearest valid prediction in
  the image (:func:`fill_invalid`), or, when a frame has none, with a constant disparity (the middle of the
  searched range). This is the main score.

Metrics (z = prediction, z* = ground truth, means over the scored pixels):

- ``rmse_mm``: sqrt(mean((z - z*)²)) in millimetres
- ``abs_rel``: mean(|z - z*| / z*)
- ``sq_rel``: mean((z - z*)² / z*) with depths in millimetres (1000 × the value in metres; Eigen et al. used
  metres at tens of metres, millimetres keep endoscopic values readable)
- ``rmse_log``: sqrt(mean((ln z - ln z*)²))
- ``a1``, ``a2``, ``a3``: fraction of pixels with max(z/z*, z*/z) < 1.25, 1.25², 1.25³
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from rgbd2scene.conventions import depth_from_disparity

METRICS = ("rmse_mm", "abs_rel", "sq_rel", "rmse_log", "a1", "a2", "a3")
#: How invalid predictions are treated: "all" fills them (the main score), "valid" leaves them out.
SCORINGS = ("all", "valid")
DELTA = 1.25


def valid_disparity(disparity: np.ndarray) -> np.ndarray:
    """True where a predicted disparity is usable: finite and positive."""
    d = np.asarray(disparity)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 0)


def depth_metrics(pred_depth: np.ndarray, gt_depth: np.ndarray) -> dict[str, float]:
    """The metrics of :data:`METRICS` over paired depths in metres (1-D arrays of the scored pixels, all > 0).

    An empty selection gives NaN for every metric.
    """
    z = np.asarray(pred_depth, np.float64).ravel()
    zt = np.asarray(gt_depth, np.float64).ravel()
    if z.shape != zt.shape:
        raise ValueError(f"prediction and ground truth differ in size: {z.shape} vs {zt.shape}")
    if z.size == 0:
        return dict.fromkeys(METRICS, float("nan"))
    if not ((z > 0).all() and (zt > 0).all()):
        raise ValueError("depths must be positive")
    err = z - zt
    ratio = np.maximum(z / zt, zt / z)
    return {"rmse_mm": float(np.sqrt(np.mean(err**2)) * 1000.0),
            "abs_rel": float(np.mean(np.abs(err) / zt)),
            "sq_rel": float(np.mean((1000.0 * err) ** 2 / (1000.0 * zt))),
            "rmse_log": float(np.sqrt(np.mean((np.log(z) - np.log(zt)) ** 2))),
            "a1": float(np.mean(ratio < DELTA)), "a2": float(np.mean(ratio < DELTA**2)),
            "a3": float(np.mean(ratio < DELTA**3))}


def fill_invalid(disparity: np.ndarray, fallback: float) -> np.ndarray:
    """Disparity with every invalid pixel replaced by the nearest valid one (Euclidean distance in the image);
    all ``fallback`` when no pixel is valid."""
    d = np.asarray(disparity, np.float64)
    valid = valid_disparity(d)
    if valid.all():
        return d
    if not valid.any():
        return np.full(d.shape, float(fallback))
    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return d[rows, cols]


@dataclass(frozen=True)
class FrameScore:
    """The scores of one frame: ``metrics[scoring][name]`` and the density of valid predictions."""

    density: float
    metrics: dict[str, dict[str, float]]
    gt_pixels: int


def score_frame(pred_disparity: np.ndarray, gt_depth: np.ndarray, fx: float, baseline: float,
                fallback_disparity: float) -> FrameScore:
    """Score one predicted left disparity map against the ground-truth depth (see the module docstring)."""
    pred = np.asarray(pred_disparity)
    gt = np.asarray(gt_depth)
    if pred.shape != gt.shape:
        raise ValueError(f"prediction is {pred.shape[::-1]} (W, H), ground truth {gt.shape[::-1]}")
    with np.errstate(invalid="ignore"):
        gt_valid = np.isfinite(gt) & (gt > 0)
    pred_valid = valid_disparity(pred)
    n_gt = int(gt_valid.sum())
    density = float((pred_valid & gt_valid).sum() / n_gt) if n_gt else float("nan")
    filled = depth_from_disparity(fill_invalid(pred, fallback_disparity), fx, baseline)
    both = gt_valid & pred_valid
    return FrameScore(density, {
        "all": depth_metrics(filled[gt_valid], gt[gt_valid]),
        "valid": depth_metrics(depth_from_disparity(pred[both], fx, baseline), gt[both]),
    }, n_gt)


def summarize(scores: list[FrameScore]) -> dict[str, dict[str, tuple[float, float]]]:
    """Mean and standard deviation over frames: ``out[scoring][name] = (mean, std)`` for every metric and
    ``density``; frames with no scored pixel (NaN) are left out of a metric's mean, never counted as zero."""
    out: dict[str, dict[str, tuple[float, float]]] = {}
    density = np.array([s.density for s in scores], np.float64)
    for scoring in SCORINGS:
        row = {}
        for name in METRICS:
            values = np.array([s.metrics[scoring][name] for s in scores], np.float64)
            values = values[np.isfinite(values)]
            row[name] = (float(values.mean()), float(values.std())) if values.size else (float("nan"),) * 2
        d = density[np.isfinite(density)]
        row["density"] = (float(d.mean()), float(d.std())) if d.size else (float("nan"),) * 2
        out[scoring] = row
    return out
