"""A picture of one dataset frame: both eyes' images and every ground-truth map, side by side."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from rgbd2scene.dataset import layout as ds
from rgbd2scene.files.images import write_image
from rgbd2scene.pictures.overview import BACKGROUND, colorize_depth, depth_range, fit_cell, label_panel

CELL_W = 384


def colorize_flow(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Optical flow (H, W, 2) as RGB uint8: hue = direction, saturation = magnitude; NaN is black."""
    finite = np.isfinite(flow).all(axis=-1)
    f = np.where(finite[..., None], flow, 0.0)
    mag = np.hypot(f[..., 0], f[..., 1])
    scale = max_magnitude or max(float(np.percentile(mag[finite], 99)) if finite.any() else 1.0, 1e-6)
    hsv = np.zeros((*flow.shape[:2], 3), np.uint8)
    hsv[..., 0] = ((np.degrees(np.arctan2(f[..., 1], f[..., 0])) % 360) / 2).astype(np.uint8)
    hsv[..., 1] = np.clip(mag / scale * 255, 0, 255).astype(np.uint8)
    hsv[..., 2] = 255
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    rgb[~finite] = 0
    return rgb


def colorize_normals(normals: np.ndarray) -> np.ndarray:
    """Camera-frame unit normals as RGB uint8 ((n + 1) / 2); NaN is black."""
    finite = np.isfinite(normals).all(axis=-1)
    rgb = np.round((np.nan_to_num(normals) + 1.0) * 127.5).clip(0, 255).astype(np.uint8)
    rgb[~finite] = 0
    return rgb


def colorize_ids(ids: np.ndarray) -> np.ndarray:
    """Instance ids as distinct colours (0 = nothing, black)."""
    rng = np.random.default_rng(7)
    palette = rng.integers(60, 256, (int(ids.max(initial=0)) + 1, 3)).astype(np.uint8)
    palette[0] = 0
    return palette[ids]


class Panel(NamedTuple):
    """One picture of a frame: ``key`` names it (``left_rgb``, ``depth``, ...), ``label`` describes it."""

    key: str
    image: np.ndarray
    label: str


def frame_panels(root: str | Path, frame: int) -> list[Panel]:
    """The pictures of ``frame``: left/right RGB, then the left eye's maps present in its npz."""
    panels = []
    for eye in ds.EYES:
        rgb, _ = ds.read_frame(root, eye, frame, rgb=True)
        panels.append(Panel(f"{eye}_rgb", rgb, f"{eye} rgb"))
    _, gt = ds.read_frame(root, "left", frame, rgb=False)
    if "depth" in gt:
        lo, hi = depth_range(gt["depth"])
        panels.append(Panel("depth", colorize_depth(gt["depth"], lo, hi), f"depth {1000 * lo:.0f}-{1000 * hi:.0f} mm"))
    if "disparity" in gt:
        lo, hi = depth_range(gt["disparity"])
        panels.append(Panel("disparity", colorize_depth(gt["disparity"], lo, hi), f"disparity {lo:.1f}-{hi:.1f} px"))
    if "normals" in gt:
        panels.append(Panel("normals", colorize_normals(gt["normals"]), "normals (camera frame)"))
    for key in ("flow_forward", "flow_backward"):
        if key in gt and np.isfinite(gt[key]).any():
            mag = np.hypot(gt[key][..., 0], gt[key][..., 1])
            panels.append(Panel(key, colorize_flow(gt[key]), f"{key.replace('_', ' ')} max {np.nanmax(mag):.1f} px"))
    if "segmentation" in gt:
        panels.append(Panel("segmentation", colorize_ids(gt["segmentation"]), "segmentation"))
    return panels


def frame_sheet(root: str | Path, frame: int) -> np.ndarray:
    """Contact sheet (RGB uint8) of ``frame``: the :func:`frame_panels` in two columns, labelled."""
    panels = frame_panels(root, frame)
    h, w = panels[0].image.shape[:2]
    cell_h = int(round(CELL_W * h / w))
    cols = 2
    rows = (len(panels) + cols - 1) // cols
    sheet = np.full((rows * (cell_h + 4), cols * (CELL_W + 4), 3), BACKGROUND, np.uint8)
    for i, (_, img, text) in enumerate(panels):
        r, c = divmod(i, cols)
        cell = label_panel(fit_cell(img, CELL_W, cell_h), f"{text} (frame {frame})" if i < 2 else text)
        sheet[r * (cell_h + 4):r * (cell_h + 4) + cell_h, c * (CELL_W + 4):c * (CELL_W + 4) + CELL_W] = cell
    return sheet


def write_frame_sheet(root: str | Path, frame: int, path: str | Path) -> Path:
    """Write :func:`frame_sheet` as PNG (atomically)."""
    sheet = frame_sheet(root, frame)
    return write_image(path, sheet)
