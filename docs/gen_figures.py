"""Regenerate the tutorials' pictures with the real program (`make docs-figures`).

Each tutorial's blocks marked ``<!-- tested -->`` run as written (the sizes the page states) in a scratch folder,
and the pictures the page shows are copied from what they wrote into docs/figures/ (committed, scaled down to
keep the site light). tests/test_docs.py runs the same blocks at tiny sizes and checks that each picture's
source file is written.
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import cv2

DOCS = Path(__file__).resolve().parent
FIGURES = DOCS / "figures"
SHARED = DOCS.parents[1] / "shared" / "rgbd_samples"

#: A picture of docs/figures/ -> the file under the page's ``out/`` folder it is made from (a glob: the first match).
FIGURE_SOURCES = {
    "rgbd-overview.png": "scene/overview.png",
    "rgbd-contact-sheet.png": "dataset/contact_sheet.png",
    "instruments-contact-sheet.png": "dataset/contact_sheet.png",
    "stereo-overview.png": "scene/overview.png",
    "fusion-overview.png": "fused/overview.png",
    "twin-realism.png": "twin_dataset/realism/realism.png",
    "scope-raw-vs-rectified.png": "raw_vs_rectified.png",
    "evaluate-error-map.png": "dataset/evaluation/error_maps/*sgbm*worst*.png",
    "batch-gallery.png": "root/index.html",  # a screenshot of the page in headless Chromium
}


def small_png(source: Path, target: Path, width: int = 900) -> None:
    """Copy a picture, scaled down to at most ``width`` pixels across."""
    image = cv2.imread(str(source), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(source)
    if image.shape[1] > width:
        image = cv2.resize(image, (width, round(image.shape[0] * width / image.shape[1])),
                           interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(target), image, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def source(out: Path, name: str) -> Path | None:
    """The file under ``out`` that picture ``name`` is made from, or None."""
    matches = sorted(out.glob(FIGURE_SOURCES[name]))
    return matches[0] if matches else None


def screenshot(page: Path, target: Path) -> None:
    sys.path.insert(0, str(DOCS.parent))
    from tests.browser import Browser, chromium

    with Browser(chromium(), width=1100, height=700) as browser:
        browser.open(page)
        target.write_bytes(browser.screenshot())
    small_png(target, target)


def page_figures(page: Path) -> list[str]:
    return re.findall(r"\(\.\./figures/([\w-]+\.png)\)", page.read_text(encoding="utf-8"))


def make(page: Path) -> None:
    from blocks import marked_blocks, run_blocks

    with tempfile.TemporaryDirectory() as tmp:
        run_blocks(marked_blocks(page), Path(tmp), SHARED)
        for name in page_figures(page):
            found = source(Path(tmp) / "out", name)
            if found is None:
                raise FileNotFoundError(f"{page.name}: nothing matches {FIGURE_SOURCES[name]} for {name}")
            (screenshot if found.suffix == ".html" else small_png)(found, FIGURES / name)
            print(f"{page.name}: {name}")


if __name__ == "__main__":
    sys.path.insert(0, str(DOCS))
    pages = [Path(p) for p in sys.argv[1:]] or sorted((DOCS / "tutorials").glob("*.md"))
    for page in pages:
        if page_figures(page):
            make(page)
