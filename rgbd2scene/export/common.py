"""What every exporter shares: the frame loop (streamed, with a progress bar) and its summary."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError


@dataclass
class ExportSummary:
    """What an exporter wrote: ``frames`` exported, ``files`` written, and notes (dropped values etc.)."""

    format: str
    out: Path
    frames: int = 0
    files: int = 0
    notes: list[str] = field(default_factory=list)


def complete_frames(dataset: Dataset) -> list[int]:
    """The dataset's complete frames in order; none is an error."""
    indices = dataset.frame_indices()
    if not indices:
        raise UserError(f"{dataset.root}: no complete frame to export (render it first)")
    return indices


def require_keys(dataset: Dataset, eyes: Iterable[str], keys: Iterable[str]) -> None:
    """Fail before anything is written when the dataset's ground truth lacks ``keys`` (e.g. ``disparity`` in a
    raw pair, or a map left out with ``--gt``): checked on the first complete frame of each of ``eyes``, so an
    export never stops after its first files with a folder that looks like a partial dataset."""
    first = complete_frames(dataset)[0]
    for eye in eyes:
        dataset.gt(eye, first, tuple(keys))  # its UserError names the file and the missing key


def frame_indices(dataset: Dataset, progress: bool, desc: str) -> Iterator[int]:
    """The dataset's complete frames in order, behind a tqdm bar when ``progress``; an empty dataset is an error."""
    indices = complete_frames(dataset)
    if progress:
        from tqdm import tqdm

        return iter(tqdm(indices, desc=desc, unit="frame"))
    return iter(indices)
