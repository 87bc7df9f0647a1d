"""``ROOT/manifest.csv``: one row per sequence (CONVENTIONS §8), readable as it is by ``pandas.read_csv``.

Columns: ``sequence`` (its folder under ROOT), ``capture``, ``split``, ``seed``, ``path``, ``frames``, ``status``
(``done``, ``failed`` or ``pending``), ``error`` (the first line of a failure; the whole story is in
``ROOT/logs/<sequence>.log``), ``frames_done``, ``seconds`` (work time of the sequence's units in the runs that
made it), ``gt_sha256`` (:func:`gt_checksum`), ``rgb_sha256`` (:func:`rgb_checksum`), then one column per
variation with the value drawn.
The file is rewritten atomically, so a reader never sees half a manifest.
"""

from __future__ import annotations

import csv
import hashlib
import io
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from rgbd2scene.dataset.layout import EYES, clean_rgb_path, frame_name, frame_paths
from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import write_text

MANIFEST = "manifest.csv"
#: What CONVENTIONS §8 requires, in its order.
REQUIRED_COLUMNS = ("sequence", "capture", "split", "seed", "path", "frames", "status", "error")
COLUMNS = REQUIRED_COLUMNS + ("frames_done", "seconds", "gt_sha256", "rgb_sha256")
STATUSES = ("done", "failed", "pending")


@dataclass
class Row:
    sequence: str
    capture: str
    split: str
    seed: int
    path: str
    frames: int
    status: str = "pending"
    error: str = ""
    frames_done: int = 0
    seconds: float = 0.0
    gt_sha256: str = ""
    rgb_sha256: str = ""
    settings: dict = field(default_factory=dict)

    def values(self) -> dict:
        out = {c: getattr(self, c) for c in COLUMNS}
        out["seconds"] = round(float(self.seconds), 3)
        out.update(self.settings)
        return out


def write_manifest(root: str | Path, rows: list[Row]) -> Path:
    """Write ``ROOT/manifest.csv`` atomically (the settings columns are the union over the rows, sorted)."""
    extra = sorted({k for r in rows for k in r.settings} - set(COLUMNS))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[*COLUMNS, *extra], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row.values())
    path = Path(root) / MANIFEST
    write_text(path, buffer.getvalue())
    return path


def read_manifest(root: str | Path) -> list[Row]:
    """The rows of ``ROOT/manifest.csv`` ([] when there is none); a damaged file is a :class:`UserError`."""
    path = Path(root) / MANIFEST
    if not path.is_file():
        return []
    try:
        with path.open(newline="") as f:
            records = list(csv.DictReader(f))
        rows = []
        for r in records:
            settings = {k: v for k, v in r.items() if k not in COLUMNS}
            rows.append(Row(r["sequence"], r["capture"], r["split"], int(r["seed"]), r["path"], int(r["frames"]),
                            r["status"], r.get("error") or "", int(r.get("frames_done") or 0),
                            float(r.get("seconds") or 0.0), r.get("gt_sha256") or "", r.get("rgb_sha256") or "",
                            settings))
    except (OSError, UnicodeDecodeError, csv.Error, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: not a manifest written by 'rgbd2scene dataset' ({exc!r})") from None
    return rows


def counts(rows: list[Row]) -> tuple[list[str], dict[str, dict[str, int]]]:
    """(the splits in order of appearance, ``{status: {split: count, ..., "total": count}}``)."""
    splits = list(dict.fromkeys(r.split for r in rows))
    table = {status: {split: sum(r.split == split and r.status == status for r in rows) for split in splits}
             for status in STATUSES}
    for status, by_split in table.items():
        by_split["total"] = sum(r.status == status for r in rows)
    return splits, table


def gt_checksum(dataset: str | Path, frames: int) -> str:
    """sha256 over the sequence's npz files in order (frame by frame, left then right; each file's name, then
    its bytes): equal checksums mean byte-identical ground truth. Empty when the dataset has no npz."""
    return _checksum((f"{eye}/{frame_name(index)}.npz", frame_paths(dataset, eye, index).gt)
                     for index in range(frames) for eye in EYES)


def rgb_checksum(dataset: str | Path, frames: int) -> str:
    """sha256 over the sequence's RGB PNGs as :func:`gt_checksum` over its npz (per frame and eye: ``rgb``, then
    ``rgb_clean`` where the render wrote it; names relative to the dataset): the images are written by numpy
    with no time stamp, so equal configurations give equal checksums. Empty when the dataset has no image."""
    root = Path(dataset)
    paths = (path for index in range(frames) for eye in EYES
             for path in (frame_paths(root, eye, index).rgb, clean_rgb_path(root, eye, index)))
    return _checksum((path.relative_to(root).as_posix(), path) for path in paths)


def _checksum(files: Iterable[tuple[str, Path]]) -> str:
    """sha256 over the (name, path) pairs whose file exists, in order: the name, then the file's bytes ("" when
    none exists)."""
    h = hashlib.sha256()
    found = False
    for name, path in files:
        if not path.is_file():
            continue
        found = True
        h.update(f"{name}\n".encode())
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest() if found else ""
