"""``rgbd2scene dataset --status ROOT``: where a batch build stands, in progress or done.

Reads ``ROOT/manifest.csv`` and, for sequences not done, the frames on disk (a running build rewrites the
manifest every few seconds; the files are the truth in between).
"""

from __future__ import annotations

import datetime
from pathlib import Path

from rgbd2scene.batch.manifest import MANIFEST, counts, read_manifest
from rgbd2scene.batch.run import build_running
from rgbd2scene.dataset import layout as ds
from rgbd2scene.errors import UserError


def _frames_on_disk(folder: Path, frames: int) -> int:
    if not (folder / ds.DATASET_JSON).is_file():
        return 0
    with_gt = bool(ds.read_dataset_json(folder).get("render", {}).get("gt", True))
    return sum(ds.frame_done(folder, i, gt=with_gt) for i in range(frames))


def status_report(root: str | Path) -> str:
    """The summary ``--status`` prints: state, counts by status and split, frames, failures (first error line)."""
    root = Path(root)
    manifest = root / MANIFEST
    if not manifest.is_file():
        raise UserError(f"{root}: not a batch build ({MANIFEST} not found)")
    rows = read_manifest(root)
    for row in rows:
        if row.status != "done":
            row.frames_done = _frames_on_disk(root / row.sequence, row.frames)
    stamp = datetime.datetime.fromtimestamp(manifest.stat().st_mtime).isoformat(sep=" ", timespec="seconds")
    state = "build running" if build_running(root) else "no build running"
    splits, table = counts(rows)
    columns = [*splits, "total"]
    width = max(len(c) for c in columns) + 2
    lines = [f"{root}: {len(rows)} sequences from {len({r.capture for r in rows})} captures; {state} "
             f"(manifest updated {stamp})",
             "status".ljust(9) + "".join(c.rjust(width) for c in columns)]
    lines += [status.ljust(9) + "".join(str(n).rjust(width) for n in by_split.values())
              for status, by_split in table.items()]
    total = sum(r.frames for r in rows)
    done = sum(r.frames_done for r in rows)
    lines.append(f"frames: {done} of {total} done ({100 * done / total if total else 0:.0f} %)")
    failed = [r for r in rows if r.status == "failed"]
    if failed:
        lines.append(f"failed ({len(failed)}; logs in {root / 'logs'}):")
        lines += [f"  {r.sequence} ({r.split}): {r.error}" for r in failed]
    return "\n".join(lines)
