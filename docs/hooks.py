"""mkdocs hook: the figures page is built from benchmarks/results/*.md at every build, so it cannot rot.

docs/figures.md holds one line ``{{ results NAME.md }}`` per results file; the hook puts the file there with its
headings one level down and its source named. A results file that is missing is a build error.
"""

from __future__ import annotations

import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
MARKER = re.compile(r"^\{\{ results ([\w.-]+\.md) \}\}$", re.M)


def results_section(name: str, results: Path = RESULTS) -> str:
    """One results file as a section of the figures page: headings demoted by one level, its path named."""
    path = results / name
    if not path.is_file():
        raise FileNotFoundError(f"docs/figures.md: no {path}")
    text = re.sub(r"^(#+) ", r"#\1 ", path.read_text(encoding="utf-8"), flags=re.M)
    heading, _, body = text.partition("\n")
    return f"{heading}\n\n*From `benchmarks/results/{name}`.*\n{body}"


def figures_markdown(markdown: str, results: Path = RESULTS) -> str:
    """The figures page with every ``{{ results NAME.md }}`` line replaced by that file."""
    return MARKER.sub(lambda m: results_section(m.group(1), results), markdown)


def on_page_markdown(markdown, page, **_):
    return figures_markdown(markdown) if page.file.src_uri == "figures.md" else markdown
