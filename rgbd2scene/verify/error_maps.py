"""Error-map pictures of ``verify --error-maps DIR``: per eye, the worst frame of the depth and flow checks.

The checks fill a :class:`FrameErrors` per eye and frame (per-pixel :class:`ErrorPanel` maps and a score:
how many times its tolerance the frame's worst metric is); the driver keeps the worst frame per check and
eye (:func:`keep_worst`) and writes it with :func:`write_error_maps` as a PNG of labelled panels
(:func:`render_error_map`): dataset and ray-cast depth, |depth error|, normal angle error, flow endpoint
error and left/right disparity mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path

import numpy as np

from rgbd2scene.dataset.layout import EYES
from rgbd2scene.errors import UserError
from rgbd2scene.files.images import rgb_to_bgr, write_image
from rgbd2scene.verify.framework import Tolerances


class PixelState(IntEnum):
    """What an error map's pixel shows (stored as uint8)."""

    COMPARED = 0  # has an error value
    NO_SURFACE = 1  # no surface in either source
    ONE_SOURCE = 2  # valid in one source only
    NOT_COMPARED = 3  # other or moving objects, depth edges, outside the other view
    OCCLUDED = 4  # occluded in the other eye (stereo only)


#: RGB colour and legend text of the pixels without an error value
STATE_COLOURS = {
    PixelState.ONE_SOURCE: ((255, 0, 255), "valid in one source only"),
    PixelState.OCCLUDED: ((70, 130, 180), "occluded in the other eye"),
    PixelState.NOT_COMPARED: ((110, 110, 110), "not compared"),
    PixelState.NO_SURFACE: ((0, 0, 0), "no surface"),
}
#: error panel -> (unit, low, high) of its log colour scale (viridis; values are clipped to it)
ERROR_SCALES = {"depth": ("um", 1e-2, 1e3), "normals": ("deg", 1e-3, 1e2), "flow": ("px", 1e-4, 1e1),
                "stereo": ("px", 1e-4, 1e1)}
#: the panels of an error-map picture, row-major in three columns (see :func:`error_map_layout`)
ERROR_PANELS = ("depth_dataset", "depth_raycast", "depth", "normals", "flow", "stereo")
#: the checks whose worst frames get a picture
PICTURED = ("depth", "flow")


@dataclass
class ErrorPanel:
    """One per-pixel error map: ``value`` (float32, NaN where there is none) and ``state`` (uint8 PixelState)."""

    value: np.ndarray
    state: np.ndarray
    title: str
    note: str = ""


@dataclass
class FrameErrors:
    """The error maps of one eye and frame, and how far its depth / flow checks are off (``scores``)."""

    eye: str
    frame: int
    depth: np.ndarray
    ref_depth: np.ndarray | None = None
    panels: dict[str, ErrorPanel] = field(default_factory=dict)
    scores: dict[str, float] = field(default_factory=dict)  # "depth", "flow": max over metrics of value / tol


def pixel_states(a: np.ndarray, b: np.ndarray, compared: np.ndarray) -> np.ndarray:
    """PixelState codes from two sources' valid masks, within the ``compared`` pixels."""
    state = np.full(a.shape, PixelState.NO_SURFACE, np.uint8)
    state[a & b] = PixelState.COMPARED
    state[a ^ b] = PixelState.ONE_SOURCE
    state[~compared] = PixelState.NOT_COMPARED
    return state


def ratio(value: float | None, tol: float | None) -> float:
    """``value`` in units of its tolerance (NaN when either is missing)."""
    if value is None or tol is None or not np.isfinite(value):
        return float("nan")
    return float(value) / max(float(tol), 1e-12)


def worst(*ratios: float) -> float:
    """The largest of the ratios that are not NaN (NaN when none is)."""
    vals = [r for r in ratios if not np.isnan(r)]
    return max(vals) if vals else float("nan")


def keep_worst(keep: dict[tuple[str, str], FrameErrors], frame_errors: dict[str, FrameErrors]) -> None:
    """Keep, per (check, eye), the frame whose depth / flow score is the largest so far (ties: the first)."""
    for eye, fe in frame_errors.items():
        for kind in PICTURED:
            score = fe.scores.get(kind, float("nan"))
            cur = keep.get((kind, eye))
            if not np.isnan(score) and (cur is None or score > cur.scores[kind]):
                keep[(kind, eye)] = fe


# ------------------------------------------------------------------------------------------------ drawing

_EM_TITLE_H, _EM_LABEL_H, _EM_BAR_H, _EM_GAP = 60, 40, 34, 8
_FONT_SCALE, _TEXT = 0.5, (235, 235, 235)


def error_map_layout(width: int, height: int) -> tuple[int, int, list[tuple[int, int, int, int]]]:
    """Size of an error-map picture of ``width x height`` frames and the image box of each panel.

    Returns ``(sheet_w, sheet_h, boxes)``: one ``(x, y, w, h)`` per :data:`ERROR_PANELS` entry, three
    panels a row, each with a label strip above and its colour bar below. Panels are 384-640 px wide.
    """
    cw = int(min(max(width, 384), 640))
    ch = max(1, int(round(cw * height / width)))
    cell_h = _EM_LABEL_H + ch + _EM_BAR_H
    boxes = []
    for i in range(len(ERROR_PANELS)):
        r, c = divmod(i, 3)
        boxes.append((_EM_GAP + c * (cw + _EM_GAP), _EM_TITLE_H + _EM_GAP + r * (cell_h + _EM_GAP) + _EM_LABEL_H,
                      cw, ch))
    return 3 * cw + 4 * _EM_GAP, _EM_TITLE_H + 2 * cell_h + 3 * _EM_GAP, boxes


def _colour_map(values_uint8: np.ndarray, colormap: int) -> np.ndarray:
    """RGB of an OpenCV colour map (which returns BGR)."""
    import cv2

    return rgb_to_bgr(cv2.applyColorMap(values_uint8, colormap))


def colorize_error(panel: ErrorPanel, lo: float, hi: float) -> np.ndarray:
    """RGB uint8 image of an error map: viridis on a log scale clipped to [lo, hi], the states in their colours."""
    import cv2

    v = panel.value.astype(np.float64)
    ok = (panel.state == PixelState.COMPARED) & np.isfinite(v)
    t = (np.log10(np.clip(np.where(ok, v, lo), lo, hi)) - np.log10(lo)) / (np.log10(hi) - np.log10(lo))
    rgb = _colour_map(np.round(t * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    for code, (colour, _) in STATE_COLOURS.items():
        rgb[panel.state == code] = colour
    rgb[(panel.state == PixelState.COMPARED) & ~ok] = STATE_COLOURS[PixelState.NO_SURFACE][0]
    return rgb


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = _FONT_SCALE, colour=_TEXT,
          max_width: int | None = None) -> int:
    """Draw ``text`` (shrunk to ``max_width`` if given); returns its width in pixels."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
    if max_width is not None and tw > max_width:
        scale *= max_width / tw
        (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
    cv2.putText(img, text, org, font, scale, colour, 1, cv2.LINE_AA)
    return tw


def _scale_bar(width: int, lo: float, hi: float, log: bool, colormap: int, marks=()) -> np.ndarray:
    """A horizontal colour bar with tick labels (decades when ``log``); white ticks at ``marks``."""
    import cv2

    from rgbd2scene.pictures.overview import BACKGROUND

    img = np.full((_EM_BAR_H, width, 3), BACKGROUND, np.uint8)
    x0, x1, y0, y1 = 10, width - 10, 6, 16
    ramp = np.round(np.linspace(0.0, 1.0, x1 - x0) * 255).astype(np.uint8)[None, :]
    img[y0:y1, x0:x1] = _colour_map(ramp, colormap)[0][None]

    def pos(v: float) -> int:
        fr = (np.log10(v) - np.log10(lo)) / (np.log10(hi) - np.log10(lo)) if log else (v - lo) / (hi - lo)
        return x0 + int(round(float(np.clip(fr, 0.0, 1.0)) * (x1 - x0 - 1)))

    if log:
        ticks = [10.0**k for k in range(int(np.ceil(np.log10(lo) - 1e-9)), int(np.floor(np.log10(hi) + 1e-9)) + 1)]
    else:
        ticks = list(np.linspace(lo, hi, 5))
    for i, v in enumerate(ticks):
        x = pos(v)
        cv2.line(img, (x, y1), (x, y1 + 3), (220, 220, 220), 1)
        label = f"{v:g}" if log else f"{v:.4g}"
        if log and i == len(ticks) - 1:
            label = ">=" + label
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        _text(img, label, (int(np.clip(x - tw // 2, 0, width - tw)), y1 + 15), 0.4)
    for v in marks:
        if lo <= v <= hi:
            x = pos(v)
            cv2.line(img, (x, 0), (x, y1 - 1), (255, 255, 255), 1)
    return img


def render_error_map(fe: FrameErrors, kind: str, tol: Tolerances | None = None, dataset: str = "") -> np.ndarray:
    """The error-map picture (RGB uint8) of one eye and frame; ``kind`` ("depth" or "flow") names the check
    whose worst frame it is. Panels (:func:`error_map_layout`): dataset depth, ray-cast depth (one turbo
    scale, mm), |depth error| (um), normal angle error (deg), flow endpoint error (px) and left/right
    disparity mismatch (px), the errors on clipped log scales with the tolerances marked on their bars.
    """
    import cv2

    from rgbd2scene.pictures.overview import BACKGROUND, colorize_depth, depth_range, fit_cell

    tol = tol or Tolerances()
    H, W = fe.depth.shape
    sheet_w, sheet_h, boxes = error_map_layout(W, H)
    sheet = np.full((sheet_h, sheet_w, 3), BACKGROUND, np.uint8)
    score = fe.scores.get(kind, float("nan"))
    head = f"{dataset + ': ' if dataset else ''}{fe.eye} eye, frame {fe.frame} - worst frame of the {kind} check"
    if np.isfinite(score):
        head += f" (worst metric at {score:.3g} x its tolerance)"
    _text(sheet, head, (_EM_GAP, 24), 0.6, max_width=sheet_w - 2 * _EM_GAP)
    x = _EM_GAP
    for colour, text in list(STATE_COLOURS.values()):
        cv2.rectangle(sheet, (x, 38), (x + 14, 52), colour, -1)
        cv2.rectangle(sheet, (x, 38), (x + 14, 52), (200, 200, 200), 1)
        x += 20 + _text(sheet, text, (x + 20, 50), 0.45) + 16
    _text(sheet, "| on a bar: tolerance (median, p99)", (x, 50), 0.45)

    lo, hi = depth_range(fe.depth, fe.ref_depth)
    depth_bar = _scale_bar(boxes[0][2], 1000 * lo, 1000 * hi, False, cv2.COLORMAP_TURBO)
    valid = float(np.isfinite(fe.depth).mean())
    cells = [(colorize_depth(fe.depth, lo, hi), "dataset depth [mm]", f"{100 * valid:.1f} % with surface",
              depth_bar)]
    if fe.ref_depth is not None:
        hit = float(np.isfinite(fe.ref_depth).mean())
        cells.append((colorize_depth(fe.ref_depth, lo, hi), "ray-cast depth (scene mesh) [mm]",
                      f"{100 * hit:.1f} % hit", depth_bar))
    else:
        cells.append((None, "ray-cast depth", "no scene mesh", None))
    marks = {"depth": (1000 * tol.depth_median_mm, 1000 * tol.depth_p99_mm),
             "normals": (tol.normal_median_deg, tol.normal_p99_deg),
             "flow": (tol.flow_median_px, tol.flow_p99_px), "stereo": (tol.lr_median_px, tol.lr_threshold_px)}
    missing = {"depth": "no scene mesh", "normals": "no normals or no scene mesh", "flow": "no flow to check",
               "stereo": "other eye missing"}
    for key in ERROR_PANELS[2:]:
        panel = fe.panels.get(key)
        unit, elo, ehi = ERROR_SCALES[key]
        if panel is None:
            cells.append((None, key, missing[key], None))
            continue
        n_one = int((panel.state == PixelState.ONE_SOURCE).sum())
        note = panel.note + (f"; {n_one} px in one only" if n_one else "")
        cells.append((colorize_error(panel, elo, ehi), f"{panel.title} [{unit}, log]", note,
                      _scale_bar(boxes[0][2], elo, ehi, True, cv2.COLORMAP_VIRIDIS, marks[key])))
    for (x, y, w, h), (img, title, note, bar) in zip(boxes, cells, strict=True):
        _text(sheet, title, (x + 2, y - _EM_LABEL_H + 16), max_width=w - 4)
        _text(sheet, note, (x + 2, y - 8), 0.42, (200, 200, 200), max_width=w - 4)
        if img is None:
            sheet[y:y + h, x:x + w] = (45, 45, 45)
            _text(sheet, "not available", (x + 10, y + h // 2), 0.55)
        else:
            sheet[y:y + h, x:x + w] = fit_cell(img, w, h)
        if bar is not None:
            sheet[y + h:y + h + _EM_BAR_H, x:x + w] = bar
    return sheet


def write_error_maps(out_dir: Path, keep: dict[tuple[str, str], FrameErrors], tol: Tolerances,
                     dataset: str) -> list[str]:
    """Write the kept worst frames' pictures (atomically): per eye the depth check's worst frame
    (``depth_left_frame000012.png``) and, where it is another frame, the flow check's. Returns their paths."""
    written = []
    for eye in EYES:
        depth_fe, flow_fe = keep.get(("depth", eye)), keep.get(("flow", eye))
        jobs = [("depth", depth_fe)] if depth_fe is not None else []
        if flow_fe is not None and (depth_fe is None or flow_fe.frame != depth_fe.frame):
            jobs.append(("flow", flow_fe))
        for kind, fe in jobs:
            path = out_dir / f"{kind}_{eye}_frame{fe.frame:06d}.png"
            img = render_error_map(fe, kind, tol, dataset)
            try:
                write_image(path, img)
            except OSError:
                raise UserError(f"{path}: could not write the error map") from None
            written.append(str(path))
    return written
