"""Regenerate the tutorials' pictures with the real program at small sizes (`make docs-figures`).

Each picture is what the tutorial's own commands write; this script runs those commands on the bundled sample
and copies the pictures into docs/figures/ (committed, a few hundred kB in all).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import cv2

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
FIGURES = DOCS / "figures"
SAMPLE = REPO / "data_samples" / "tissue"


def rgbd2scene(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "rgbd2scene.cli", *args], cwd=REPO, check=True)


def small_png(source: Path, target: Path, width: int = 900) -> None:
    """Copy a picture, scaled down to at most ``width`` pixels across (keeps the site light)."""
    image = cv2.imread(str(source), cv2.IMREAD_COLOR)
    if image.shape[1] > width:
        image = cv2.resize(image, (width, round(image.shape[0] * width / image.shape[1])),
                           interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(target), image, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def rgbd_capture(work: Path) -> None:
    """tutorials/rgbd-capture.md: scene from the bundled capture, a short breathing dataset, verify's maps."""
    scene, dataset = work / "scene", work / "dataset"
    rgbd2scene("scene", "--rgb", str(SAMPLE / "rgb.png"), "--depth", str(SAMPLE / "depth.png"),
               "--camera", str(SAMPLE / "camera.json"), "--path", "scan", "--frames", "30",
               "--deform", "breathing", "-o", str(scene))
    rgbd2scene("render", str(scene), "-o", str(dataset), "--frames", "6", "--size", "320x160")
    rgbd2scene("verify", str(dataset), "--quiet", "--error-maps", str(work / "error_maps"))
    small_png(scene / "overview.png", FIGURES / "rgbd-overview.png")
    small_png(dataset / "contact_sheet.png", FIGURES / "rgbd-contact-sheet.png")


if __name__ == "__main__":
    FIGURES.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        rgbd_capture(Path(tmp))
        for p in sorted(Path(tmp).rglob("*.png")):
            print(p.relative_to(tmp))
