"""The documentation site builds with warnings as errors, and every page loads in a real headless browser with
every internal link and image resolving (the site is built as `make docs` builds it)."""

from __future__ import annotations

import html
import importlib
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from tests.browser import Browser, chromium

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs"))
import hooks  # noqa: E402
from blocks import SHARED_SAMPLES, marked_blocks, run_blocks  # noqa: E402  (docs/blocks.py)
from gen_figures import FIGURE_SOURCES, source  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

LINKS = "Array.from(document.querySelectorAll('a[href]')).map(a => a.href)"


def build_site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-f",
                             str(REPO / "mkdocs.yml"), "-d", str(site)], cwd=REPO, capture_output=True, text=True,
                            env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    return site


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    return build_site(tmp_path_factory)


def broken_links(page: Path, hrefs: list[str], site: Path) -> list[str]:
    """The hrefs of a page that point into the site at a missing file or a missing anchor."""
    broken = []
    for href in hrefs:
        parts = urlsplit(href)
        if parts.scheme != "file":
            continue  # the outside world is not checked (no network in tests)
        target = Path(unquote(parts.path))
        if target.is_dir():
            target = target / "index.html"
        if not target.is_file() or site.resolve() not in target.resolve().parents:
            broken.append(href)
        elif parts.fragment and target.suffix == ".html":
            ids = set(re.findall(r'\bid="([^"]+)"', target.read_text(encoding="utf-8")))
            if unquote(parts.fragment) not in ids:
                broken.append(href)
    return broken


def test_the_api_reference_is_rendered_from_the_docstrings(site):
    api = (site / "reference" / "api.html").read_text()
    for name in ("scene", "render", "verify", "export"):  # one call per command, with its docstring
        assert f'id="rgbd2scene.api.{name}"' in api
    assert "one call per command" in api  # the module docstring itself
    assert ":func:" not in page_text(site / "reference" / "api.html")  # Sphinx roles shown as code (docs/hooks.py)


@pytest.mark.skipif(chromium() is None, reason="chromium is not installed (make test installs Debian's)")
def test_every_page_loads_with_every_link_and_image(site):
    pages = sorted(p for p in site.rglob("*.html") if p.name != "404.html")
    sources = sorted((REPO / "docs").rglob("*.md"))
    assert len(pages) == len(sources)  # every page of docs/ is built (and nothing else)
    with Browser(chromium()) as browser:
        for page in pages:
            browser.open(page)
            name = page.relative_to(site)
            assert browser.evaluate("document.querySelector('article h1') !== null"), f"{name}: no title"
            assert browser.evaluate("document.querySelector('article').innerText.length") > 200, name
            assert [i["src"] for i in browser.images() if not i["loaded"]] == [], name
            assert broken_links(page, browser.evaluate(LINKS), site) == [], name

        # the check fails where an image or a link does not resolve
        page = site / "getting-started.html"
        browser.open(page)
        broken = '<img src="missing.png"><a href="missing.html">x</a><a href="index.html#nowhere">y</a>'
        browser.evaluate(f"document.querySelector('article').insertAdjacentHTML('beforeend', '{broken}')")
        assert [i["src"] for i in browser.images() if not i["loaded"]] == ["missing.png"]
        assert [Path(urlsplit(h).path).name + "#" * bool(urlsplit(h).fragment)
                for h in broken_links(page, browser.evaluate(LINKS), site)] == ["missing.html", "index.html#"]



TUTORIALS = sorted((REPO / "docs" / "tutorials").glob("*.md"))


@pytest.mark.parametrize("page", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_code_runs_as_written(page, tmp_path):
    blocks = marked_blocks(page, tiny=True)
    assert blocks, f"{page.name}: no block marked <!-- tested -->"
    if any(SHARED_SAMPLES in code for _, code in blocks) and not (REPO.parent / "shared").is_dir():
        pytest.skip(f"{page.name} uses the real captures in {SHARED_SAMPLES}, absent here")
    run_blocks(blocks, tmp_path, REPO.parent / "shared" / "rgbd_samples")
    out = tmp_path / "out"
    for picture in re.findall(r"\(\.\./figures/([\w-]+\.png)\)", page.read_text()):  # what the page shows was written
        assert source(out, picture) is not None, f"{page.name}: {picture} is made from {FIGURE_SOURCES[picture]}"
    if page.stem == "rgbd-capture":
        assert len(list((out / "dataset" / "left" / "gt").glob("*.npz"))) == 2
        assert json.loads((out / "verify.json").read_text())["ok"] is True


def test_marked_blocks_get_tiny_sizes():
    page = REPO / "docs" / "tutorials" / "rgbd-capture.md"
    render = [code for _, code in marked_blocks(page, tiny=True) if "rgbd2scene render" in code]
    assert render and all("--size 64x32" in c and "--frames 2" in c for c in render)
    assert all("--size 64x32" not in c for _, c in marked_blocks(page))

def page_text(path: Path) -> str:
    """The text of a built page, tags stripped and whitespace collapsed."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", path.read_text(encoding="utf-8"))).split())


def test_figures_page_is_built_from_every_results_file(site, tmp_path):
    results = sorted(p.name for p in (REPO / "benchmarks" / "results").glob("*.md"))
    assert sorted(hooks.MARKER.findall((REPO / "docs" / "figures.md").read_text())) == results
    text = page_text(site / "figures.html")
    for name in results:  # every results file's table rows are on the page, as the file has them now
        rows = [line for line in (REPO / "benchmarks" / "results" / name).read_text().splitlines()
                if line.startswith("| ") and "---" not in line]
        assert rows, name
        for row in rows[:1] + rows[-1:]:
            cells = [" ".join(re.sub(r"[`*]", "", c).split()) for c in row.strip("|").split("|")]
            assert " ".join(c for c in cells if c) in text, f"{name}: {row}"
    with pytest.raises(FileNotFoundError, match="nowhere.md"):
        hooks.figures_markdown("{{ results nowhere.md }}", tmp_path)


PAGES = sorted((REPO / "docs").rglob("*.md"))


def test_every_python_block_compiles_and_its_imports_of_this_package_resolve():
    untested = re.compile(r"(?<!<!-- tested -->\n)```python\n(.*?)```", re.S)
    blocks = [(page, code) for page in PAGES + [REPO / "README.md"] for code in untested.findall(page.read_text())]
    assert blocks  # e.g. the SLURM script, which needs a cluster to run
    for page, code in blocks:
        compile(code, str(page), "exec")
        for module, names in re.findall(r"^from (rgbd2scene[\w.]*) import ([\w, ]+)$", code, re.M):
            imported = importlib.import_module(module)
            for name in (n.strip() for n in names.split(",")):  # an attribute, or a submodule
                assert hasattr(imported, name) or importlib.util.find_spec(f"{module}.{name}"), (page.name, name)


def test_the_dataset_format_page_lists_every_key_of_the_schema_with_its_dtype():
    from rgbd2scene.groundtruth.schema import SCHEMA

    page = (REPO / "docs" / "dataset-format.md").read_text()
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `(\w+)` \| (\w+) ", page, re.M)}
    assert set(rows) == set(SCHEMA)  # no key missing, none that the program does not write
    assert {key: rows[key] for key in SCHEMA} == {key: field.dtype for key, field in SCHEMA.items()}
