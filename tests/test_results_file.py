"""Results files keep their hand-written notes when a benchmark reruns (``benchmarks/results_file.py``)."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))

from results_file import NOTES_HEADING, kept_notes, write_results  # noqa: E402


def test_a_rerun_replaces_the_figures_and_keeps_the_notes(tmp_path):
    path = tmp_path / "bench.md"
    write_results(path, "# Bench\n\n| a | 1 |\n")
    assert path.read_text() == "# Bench\n\n| a | 1 |\n" and kept_notes(path) == ""
    notes = f"{NOTES_HEADING}\n\nSession 1: tried x, kept y.\n\n### Session 0\n\ntable\n"
    path.write_text(path.read_text() + "\n" + notes)
    write_results(path, "# Bench\n\n| a | 2 |\n")
    assert path.read_text() == "# Bench\n\n| a | 2 |\n\n" + notes
    # placed before a heading of the new text: above the long tables
    write_results(path, "# Bench\n\n| a | 3 |\n\n## Every row\n\n| r |\n", before="## Every row")
    assert path.read_text() == "# Bench\n\n| a | 3 |\n\n" + notes + "\n## Every row\n\n| r |\n"
    assert kept_notes(path) == notes + "\n"


def test_every_results_file_with_history_has_its_notes_under_the_heading():
    """A results file whose benchmark rewrites it must hold its hand-written history under the notes heading,
    or a rerun erases it: the notes run to the end of the file (the fill files: to the table of every row)."""
    for name in ("twin.md", "sensor.md", "vignetting.md", "render.md", "profile.md", "issue16.md", "fill.md",
                 "fill_heldout.md"):
        path = REPO / "benchmarks" / "results" / name
        text = path.read_text()
        assert text.count(NOTES_HEADING) == 1, name
        rest = text[text.index(NOTES_HEADING) + len(kept_notes(path)):]
        assert rest == "" or rest.startswith("## Every row"), name
