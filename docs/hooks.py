"""mkdocs hook: the figures page is built from benchmarks/results/*.md at every build, so it cannot rot.

docs/figures.md holds one line ``{{ results NAME.md }}`` per results file; the hook puts the file there with its
headings two levels down and its source named. A results file that is missing is a build error.
"""

from __future__ import annotations

import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
MARKER = re.compile(r"^\{\{ results ([\w.-]+\.md) \}\}$", re.M)


def results_section(name: str, results: Path = RESULTS) -> str:
    """One results file as a section of the figures page: headings demoted by two levels, its path named."""
    path = results / name
    if not path.is_file():
        raise FileNotFoundError(f"docs/figures.md: no {path}")
    text = re.sub(r"^(#+) ", r"##\1 ", path.read_text(encoding="utf-8"), flags=re.M)  # under the page's sections
    heading, _, body = text.partition("\n")
    return f"{heading}\n\n*From `benchmarks/results/{name}`.*\n{body}"


def figures_markdown(markdown: str, results: Path = RESULTS) -> str:
    """The figures page with every ``{{ results NAME.md }}`` line replaced by that file."""
    return MARKER.sub(lambda m: results_section(m.group(1), results), markdown)


def on_page_markdown(markdown, page, **_):
    return figures_markdown(markdown) if page.file.src_uri == "figures.md" else markdown


SPHINX_ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|attr|data|exc|obj|const):<code>(~?)([^<]*?)</code>")


def plain_sphinx_roles(html: str) -> str:
    """The docstrings' Sphinx roles (``:func:`x```, ``:class:`~a.b.C```) as plain code, as Sphinx shows them
    (``~`` keeps the last name), and a paragraph's closing ``::`` as one colon."""
    def code(m):
        return f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>"

    return re.sub(r"::</p>", ":</p>", SPHINX_ROLE.sub(code, html))


def on_page_content(html, page, **_):
    return plain_sphinx_roles(html) if page.file.src_uri.startswith("reference/") else html
