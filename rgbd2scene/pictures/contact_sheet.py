"""A picture of one dataset frame: both eyes' images and every ground-truth map, side by side."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from rgbd2scene.dataset import layout as ds
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.files.images import write_image
from rgbd2scene.pictures.overview import BACKGROUND, colorize_depth, depth_range, fit_cell, label_panel, put_text

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


def id_colour(i: int) -> np.ndarray:
    """A fixed, distinct RGB colour per id (0: black), the same in every picture of every dataset."""
    if i == 0:
        return np.zeros(3, np.uint8)
    hue = (i * 0.618033988749895) % 1.0  # golden-ratio steps around the hue circle
    hsv = np.array([[[int(hue * 180), 200 if i % 2 else 255, 255 if i % 3 else 190]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]


def colorize_ids(ids: np.ndarray) -> np.ndarray:
    """Instance (or class) ids as distinct colours (0 = nothing, black); see :func:`id_colour`."""
    values = np.unique(ids)
    palette = np.zeros((int(values.max(initial=0)) + 1, 3), np.uint8)
    for v in values:
        palette[v] = id_colour(int(v))
    return palette[ids]


def legend_panel(entries: list[tuple[int, str]], width: int, height: int) -> np.ndarray:
    """A panel listing ``(id, text)`` rows with the id's colour swatch (as :func:`colorize_ids` paints it)."""
    panel = np.full((height, width, 3), BACKGROUND, np.uint8)
    row = max(12, min(20, (height - 30) // max(len(entries), 1)))
    widest = max((cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 1.0, 1)[0][0] for _, text in entries), default=1)
    scale = min(row / 36.0, (width - 24 - row) / widest)  # every line fits the panel
    for k, (i, text) in enumerate(entries):
        y = 30 + k * row
        if y + row > height:
            put_text(panel, f"... {len(entries) - k} more", (8, y + row - 4), scale)
            break
        panel[y + 3:y + row - 3, 8:8 + row] = id_colour(i)
        put_text(panel, text, (16 + row, y + row - 6), scale)
    return panel


def _class_map(seg: np.ndarray, table: dict, classes: dict[str, int]) -> np.ndarray:
    """Semantic mask: each instance id replaced by its class id (0 for nothing or unknown ids)."""
    lut = np.zeros(int(seg.max(initial=0)) + 1, np.uint16)
    for i, entry in table.items():
        if i < len(lut) and entry.cls in classes:
            lut[i] = classes[entry.cls]
    return lut[seg]


class Panel(NamedTuple):
    """One picture of a frame: ``key`` names it (``left_rgb``, ``depth``, ...), ``label`` describes it."""

    key: str
    image: np.ndarray
    label: str


def frame_panels(root: str | Path, frame: int) -> list[Panel]:
    """The pictures of ``frame``: left/right RGB, then the left eye's maps present in its npz: depth,
    disparity (or, for a raw pair, the correspondence to the right eye), normals, both flows, the instance and
    class masks with their legends, the flow of moving objects and the occlusion flags."""
    panels = []
    for eye in ds.EYES:
        rgb, _ = ds.read_frame(root, eye, frame, rgb=True)
        panels.append(Panel(f"{eye}_rgb", rgb, f"{eye} rgb"))
    _, gt = ds.read_frame(root, "left", frame, rgb=False)
    h, w = panels[0].image.shape[:2]
    legend_h = int(round(CELL_W * h / w))
    if "depth" in gt:
        lo, hi = depth_range(gt["depth"])
        panels.append(Panel("depth", colorize_depth(gt["depth"], lo, hi), f"depth {1000 * lo:.0f}-{1000 * hi:.0f} mm"))
    if "disparity" in gt:
        lo, hi = depth_range(gt["disparity"])
        panels.append(Panel("disparity", colorize_depth(gt["disparity"], lo, hi), f"disparity {lo:.1f}-{hi:.1f} px"))
    if "correspondence" in gt and np.isfinite(gt["correspondence"]).any():  # a raw pair: to the right eye's pixel
        mag = np.hypot(gt["correspondence"][..., 0], gt["correspondence"][..., 1])
        panels.append(Panel("correspondence", colorize_flow(gt["correspondence"]),
                            f"correspondence to right max {np.nanmax(mag):.1f} px"))
    if "normals" in gt:
        panels.append(Panel("normals", colorize_normals(gt["normals"]), "normals (camera frame)"))
    for key in ("flow_forward", "flow_backward"):
        if key in gt and np.isfinite(gt[key]).any():
            mag = np.hypot(gt[key][..., 0], gt[key][..., 1])
            panels.append(Panel(key, colorize_flow(gt[key]), f"{key.replace('_', ' ')} max {np.nanmax(mag):.1f} px"))
    if "segmentation" in gt:
        seg = gt["segmentation"]
        dataset = Dataset(root)
        table, classes = dataset.objects, dataset.classes
        panels.append(Panel("segmentation", colorize_ids(seg), "segmentation (instances)"))
        present = [int(i) for i in np.unique(seg) if i]
        panels.append(Panel("instance_legend", legend_panel([(i, _describe(i, table)) for i in present], CELL_W,
                                                            legend_h), "instance ids"))
        semantic = _class_map(seg, table, classes)
        panels.append(Panel("classes", colorize_ids(semantic), "classes"))
        names = {v: k for k, v in classes.items()}
        panels.append(Panel("class_legend", legend_panel([(c, f"{c}: {names.get(c, '?')}") for c in np.unique(semantic)
                                                          if c], CELL_W, legend_h), "class ids"))
        moving = [i for i in present if i in table and table[i].moving]
        if moving and "flow_forward" in gt and np.isfinite(gt["flow_forward"]).any():
            flow = np.where(np.isin(seg, moving)[..., None], gt["flow_forward"], np.nan)
            mag = np.hypot(flow[..., 0], flow[..., 1])
            peak = float(np.nanmax(mag)) if np.isfinite(mag).any() else 0.0
            panels.append(Panel("moving_flow", colorize_flow(flow), f"flow of moving objects max {peak:.1f} px"))
    for key in ("occluded_forward", "occluded_backward"):
        if key in gt:
            img = np.where(gt[key][..., None], np.uint8(255), np.uint8(0)).repeat(3, axis=-1)
            panels.append(Panel(key, img, f"{key.replace('_', ' ')} ({100 * gt[key].mean():.1f} %)"))
    return panels


def frame_sheet(root: str | Path, frame: int) -> np.ndarray:
    """Contact sheet (RGB uint8) of ``frame``: the :func:`frame_panels` in three columns, labelled."""
    panels = frame_panels(root, frame)
    h, w = panels[0].image.shape[:2]
    cell_h = int(round(CELL_W * h / w))
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    sheet = np.full((rows * (cell_h + 4), cols * (CELL_W + 4), 3), BACKGROUND, np.uint8)
    for i, (_, img, text) in enumerate(panels):
        r, c = divmod(i, cols)
        cell = label_panel(fit_cell(img, CELL_W, cell_h), f"{text} (frame {frame})" if i < 2 else text)
        sheet[r * (cell_h + 4):r * (cell_h + 4) + cell_h, c * (CELL_W + 4):c * (CELL_W + 4) + CELL_W] = cell
    return sheet


def _describe(i: int, table: dict) -> str:
    entry = table.get(i)
    if entry is None:
        return f"{i}: (not in dataset.json)"
    part = f"/{entry.part}" if entry.part and entry.part != entry.name else ""
    return f"{i}: {entry.name}{part} ({entry.cls}){' moving' if entry.moving else ''}"


def write_frame_sheet(root: str | Path, frame: int, path: str | Path) -> Path:
    """Write :func:`frame_sheet` as PNG (atomically)."""
    sheet = frame_sheet(root, frame)
    return write_image(path, sheet)
