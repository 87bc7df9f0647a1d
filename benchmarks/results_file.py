"""The results files under ``benchmarks/results``: what a benchmark writes, and the hand-written notes a rerun keeps.

A results file holds the figures of its benchmark's latest run, and, under :data:`NOTES_HEADING`, what people
wrote about them and about earlier runs (the history: what was tried, on what data, with which figures). A
rerun replaces the figures and keeps the notes, so ``make bench`` never erases the history.
"""

from __future__ import annotations

from pathlib import Path

from rgbd2scene.files.atomic import write_text

#: The heading of a results file's hand-written part; it runs to the next ``## `` heading or to the end.
NOTES_HEADING = "## Notes on this run (written by hand)"


def kept_notes(path: str | Path) -> str:
    """The hand-written notes of the results file at ``path`` (from :data:`NOTES_HEADING` to the next ``## ``
    heading or the end), ending in a blank line; empty if the file or its notes are absent."""
    path = Path(path)
    text = path.read_text() if path.is_file() else ""
    start = text.find(NOTES_HEADING)
    if start < 0:
        return ""
    end = text.find("\n## ", start + len(NOTES_HEADING))
    return text[start:end if end >= 0 else len(text)].rstrip() + "\n\n"


def write_results(path: str | Path, text: str, before: str | None = None) -> None:
    """Write a benchmark's ``text`` to the results file ``path`` (atomically), carrying over the notes of the
    file it replaces: inserted before the first line of ``text`` that starts with ``before`` (a heading; the
    notes then sit above the long tables), else appended at the end."""
    notes = kept_notes(path)
    at = text.find("\n" + before) + 1 if notes and before else 0
    if at > 0:
        text = text[:at] + notes + text[at:]
    elif notes:
        text = text.rstrip("\n") + "\n\n" + notes
    write_text(path, text.rstrip("\n") + "\n")
