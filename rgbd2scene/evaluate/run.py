"""``rgbd2scene evaluate``: run stereo methods on every left/right pair of a dataset (or of each ``done``
sequence of a batch ROOT, one table per split) and write the scores (:mod:`rgbd2scene.evaluate.report`)."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rgbd2scene.batch.manifest import MANIFEST
from rgbd2scene.dataset.layout import DATASET_JSON
from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.evaluate.grid import MatchingGrid
from rgbd2scene.evaluate.methods import DisparityRange, build_methods, dataset_depth_range, parse_prediction_arg
from rgbd2scene.evaluate.metrics import FrameScore, score_frame, summarize
from rgbd2scene.evaluate.report import SummaryRow, error_map, write_tables
from rgbd2scene.files.atomic import ensure_output_dir
from rgbd2scene.files.images import write_image

SINGLE_SPLIT = "all"


@dataclass
class Sequence:
    split: str
    name: str
    dataset: Dataset


@dataclass
class EvaluationOptions:
    """``methods`` (of ``sgbm``, ``elas``, ``gt``), prediction folders (``DIR`` or ``NAME=DIR``; for a batch ROOT,
    ``DIR/<sequence>/``), an optional depth range in metres overriding the ground truth's, and error maps."""

    methods: tuple[str, ...] = ("sgbm", "elas")
    predictions: tuple[str, ...] = ()
    depth_range: tuple[float, float] | None = None
    error_maps: bool = True


@dataclass
class EvaluationResult:
    out: Path
    rows: list[SummaryRow]
    files: list[Path] = field(default_factory=list)


def find_sequences(path: str | Path) -> tuple[list[Sequence], bool]:
    """The datasets to score and whether ``path`` is a batch ROOT (``manifest.csv``, CONVENTIONS §8)."""
    path = Path(path)
    if (path / DATASET_JSON).is_file():
        return [Sequence(SINGLE_SPLIT, path.name, Dataset(path))], False
    manifest = path / MANIFEST
    if not manifest.is_file():
        raise UserError(f"{path}: neither a dataset folder ({DATASET_JSON}) nor a batch root ({MANIFEST})")
    try:
        with manifest.open(newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UserError(f"{manifest}: unreadable ({exc})") from None
    missing = [c for c in ("sequence", "split", "status") if rows and c not in rows[0]]
    if missing:
        raise UserError(f"{manifest}: missing column {', '.join(missing)}")
    done = [r for r in rows if (r.get("status") or "").strip() == "done"]
    if not done:
        raise UserError(f"{manifest}: no sequence with status 'done'")
    return [Sequence((r["split"] or "unsplit").strip(), r["sequence"], Dataset(path / r["sequence"]))
            for r in done], True


def _predictions_for(options: EvaluationOptions, sequence: Sequence, batch: bool) -> list[str]:
    if not batch:
        return list(options.predictions)
    return [f"{name}={folder / sequence.name}" for name, folder in map(parse_prediction_arg, options.predictions)]


@dataclass
class _Extreme:
    """The best or worst frame so far of a method in a split (by RMSE, invalid predictions filled)."""

    rmse: float
    sequence: Sequence
    index: int
    prediction: np.ndarray


def evaluate(path: str | Path, out: str | Path | None = None, options: EvaluationOptions | None = None,
             progress: bool = True) -> EvaluationResult:
    """Score every method on every complete frame; write the tables (and error maps) to ``out`` (default
    ``path/evaluation``)."""
    options = options or EvaluationOptions()
    sequences, batch = find_sequences(path)
    out = ensure_output_dir(Path(out) if out is not None else Path(path) / "evaluation")
    records: list[tuple[str, str, str, int, FrameScore]] = []
    extremes: dict[tuple[str, str, str], _Extreme] = {}
    total = sum(len(s.dataset.frame_indices()) for s in sequences)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="evaluate", unit="frame")
    settings: list[str] = []
    for seq in sequences:
        ds = seq.dataset
        try:
            z_range = options.depth_range or dataset_depth_range(ds)
            grid = MatchingGrid.of(ds)
            search = DisparityRange.from_depths(*z_range, grid.focal, grid.baseline)
            methods = build_methods(ds, list(options.methods), _predictions_for(options, seq, batch), search)
        except ValueError as exc:
            raise UserError(f"{ds.root}: {exc}") from None
        settings.append(f"{seq.name} ({seq.split}): {ds.width}x{ds.height}, "
                        + ("raw pair matched rectified (cv2.stereoRectify, alpha 0; predictions in that grid), "
                           "scored at the raw pixels, " if grid.raw else "")
                        + f"fx {grid.focal:.1f} px, baseline {1000 * grid.baseline:.1f} mm, depth "
                        f"{1000 * z_range[0]:.1f}-{1000 * z_range[1]:.1f} mm -> disparities searched "
                        f"{search.low:.1f}-{search.high:.1f} px")
        # a disparity of the matching grid in the dataset's grid (fx of the dataset): what is scored and pictured
        fallback = search.middle * grid.scoring_focal / grid.focal
        for index in ds.frame_indices():
            left, right = grid.pair(ds.rgb("left", index), ds.rgb("right", index))
            depth = ds.gt("left", index, ("depth",))["depth"]
            for method in methods:
                pred = grid.to_scoring(method(index, left, right))
                try:
                    score = score_frame(pred, depth, ds.fx, ds.baseline, fallback)
                except ValueError as exc:
                    raise UserError(f"{ds.root}: method {method.name}, frame {index}: {exc}") from None
                records.append((seq.split, seq.name, method.name, index, score))
                rmse = score.metrics["all"]["rmse_mm"]
                for which, better in (("best", np.less), ("worst", np.greater)):
                    key = (seq.split, method.name, which)
                    if np.isfinite(rmse) and (key not in extremes or better(rmse, extremes[key].rmse)):
                        extremes[key] = _Extreme(rmse, seq, index, pred)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    rows = []
    for split in dict.fromkeys(s.split for s in sequences):
        for name in dict.fromkeys(r[2] for r in records):
            scores = [r[4] for r in records if r[0] == split and r[2] == name]
            summary = summarize(scores)
            rows += [SummaryRow(split, name, scoring, len(scores), summary[scoring]) for scoring in summary]
    rows.sort(key=lambda r: (r.split, r.scored != "all"))
    title = f"Stereo evaluation of {Path(path).resolve().name}" + (" (batch, one table per split)" if batch else "")
    files = write_tables(out, rows, records, title, settings)
    if options.error_maps:
        for (split, name, which), ext in extremes.items():
            ds = ext.sequence.dataset
            label = f"{split}_" if batch else ""
            picture = error_map(ds.rgb("left", ext.index), ds.gt("left", ext.index, ("depth",))["depth"],
                                ext.prediction, ds.fx, ds.baseline,
                                f"{name}: {which} frame {ext.index} of {ext.sequence.name}, RMSE {ext.rmse:.2f} mm")
            files.append(write_image(out / "error_maps" / f"{label}{name}_{which}_{ext.index:06d}.png", picture))
    return EvaluationResult(out, rows, files)
