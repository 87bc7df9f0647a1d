"""The evaluation's files: ``metrics.csv``, ``metrics.md``, ``per_frame.csv`` and error-map pictures."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rgbd2scene.conventions import depth_from_disparity
from rgbd2scene.evaluate.metrics import METRICS, SCORINGS, FrameScore, valid_disparity
from rgbd2scene.files.atomic import write_text
from rgbd2scene.pictures.overview import BACKGROUND, colorize_depth, depth_range, fit_cell, label_panel

COLUMNS = ("method", "frames", *[c for m in (*METRICS, "density") for c in (m, f"{m}_std")], "scored", "split")
FRAME_COLUMNS = ("split", "sequence", "method", "frame", "scored", *METRICS, "density", "gt_pixels")
#: Where a method gave no disparity (error-map pictures), RGB
NO_PREDICTION = (255, 0, 255)
CELL_W = 400


@dataclass
class SummaryRow:
    """One table row: a method's mean and std of every metric over ``frames`` frames of a split."""

    split: str
    method: str
    scored: str
    frames: int
    values: dict[str, tuple[float, float]]


def _fmt(value: float) -> str:
    return "" if not np.isfinite(value) else f"{value:.6g}"


def metrics_csv(rows: list[SummaryRow]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for r in rows:
        cells = [r.method, r.frames]
        for m in (*METRICS, "density"):
            cells += [_fmt(r.values[m][0]), _fmt(r.values[m][1])]
        writer.writerow([*cells, r.scored, r.split])
    return buf.getvalue()


def per_frame_csv(records: list[tuple[str, str, str, int, FrameScore]]) -> str:
    """Rows of (split, sequence, method, frame, score), both scorings each."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(FRAME_COLUMNS)
    for split, sequence, method, frame, score in records:
        for scoring in SCORINGS:
            writer.writerow([split, sequence, method, frame, scoring,
                             *[_fmt(score.metrics[scoring][m]) for m in METRICS], _fmt(score.density),
                             score.gt_pixels])
    return buf.getvalue()


_MD_HEAD = ("method", "frames", "RMSE mm", "Abs Rel", "Sq Rel (mm)", "RMSE log", "δ<1.25", "δ<1.25²", "δ<1.25³",
            "density")


def markdown_table(rows: list[SummaryRow]) -> str:
    """A Markdown table of mean ± std (one scoring, one split)."""
    lines = ["| " + " | ".join(_MD_HEAD) + " |", "|" + "---|" * len(_MD_HEAD)]
    for r in rows:
        cells = [r.method, str(r.frames)]
        for m in (*METRICS, "density"):
            mean, std = r.values[m]
            digits = 2 if m == "rmse_mm" else 4
            cells.append("n/a" if not np.isfinite(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown_report(rows: list[SummaryRow], title: str, settings: list[str]) -> str:
    """metrics.md: per split, the main table (every ground-truth pixel, invalid predictions filled) and the
    table over valid predictions only."""
    out = [f"# {title}", "", *[f"- {s}" for s in settings], ""]
    for split in dict.fromkeys(r.split for r in rows):
        if split != "all":
            out += [f"## Split: {split}", ""]
        main = [r for r in rows if r.split == split and r.scored == "all"]
        valid = [r for r in rows if r.split == split and r.scored == "valid"]
        out += ["Every valid ground-truth pixel; where a method gave no disparity, the nearest valid prediction "
                "fills in (main score):", "", markdown_table(main), "",
                "Only the pixels where the method gave a disparity (flatters sparse methods: read with density):",
                "", markdown_table(valid), ""]
    return "\n".join(out)


def write_tables(out: Path, rows: list[SummaryRow], records, title: str, settings: list[str]) -> list[Path]:
    paths = [out / "metrics.csv", out / "metrics.md", out / "per_frame.csv"]
    write_text(paths[0], metrics_csv(rows))
    write_text(paths[1], markdown_report(rows, title, settings))
    write_text(paths[2], per_frame_csv(records))
    return paths


def error_map(left_rgb: np.ndarray, gt_depth: np.ndarray, pred_disparity: np.ndarray, fx: float, baseline: float,
              title: str) -> np.ndarray:
    """Picture (RGB uint8) of one scored frame: left image, ground-truth depth, predicted depth (one turbo scale,
    no prediction in magenta) and |depth error| in mm (turbo from 0 to the 99th percentile)."""
    valid = valid_disparity(pred_disparity)
    pred_depth = depth_from_disparity(np.where(valid, pred_disparity, np.nan), fx, baseline)
    gt_valid = np.isfinite(gt_depth)
    lo, hi = depth_range(gt_depth)
    pred_img = colorize_depth(pred_depth, lo, hi)
    pred_img[~valid] = NO_PREDICTION
    err_mm = np.abs(pred_depth.astype(np.float64) - gt_depth) * 1000.0
    err_mm[~(valid & gt_valid)] = np.nan
    top = float(np.nanpercentile(err_mm, 99)) if np.isfinite(err_mm).any() else 1.0
    err_img = colorize_depth(err_mm, 0.0, max(top, 1e-6))
    err_img[gt_valid & ~valid] = NO_PREDICTION
    panels = [(left_rgb, "left image"),
              (colorize_depth(gt_depth, lo, hi), f"ground truth {1e3 * lo:.0f}-{1e3 * hi:.0f} mm"),
              (pred_img, "prediction (magenta: none)"), (err_img, f"|error| 0-{top:.2g} mm (magenta: none)")]
    h, w = gt_depth.shape
    cell_h = max(1, int(round(CELL_W * h / w)))
    title_h = 34
    sheet = np.full((title_h + 2 * (cell_h + 4), 2 * (CELL_W + 4), 3), BACKGROUND, np.uint8)
    cv2.putText(sheet, title, (6, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235), 1, cv2.LINE_AA)
    for i, (img, text) in enumerate(panels):
        r, c = divmod(i, 2)
        y, x = title_h + r * (cell_h + 4), c * (CELL_W + 4)
        sheet[y:y + cell_h, x:x + CELL_W] = label_panel(fit_cell(np.ascontiguousarray(img), CELL_W, cell_h), text)
    return sheet

