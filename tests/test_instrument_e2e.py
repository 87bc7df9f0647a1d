"""``rgbd2scene scene --instrument`` on the bundled sample, rendered small and verified (CLI in-process).

Rendered at 256x128, not 64x32: verify's stereo check compares each pixel with the other eye's two nearest
samples, and a jaw 3 px wide has a ridge of disparity between them (at 64x32, 0.3 % of the pixels "see further"
by up to 0.45 px, against a 0.2 % tolerance; at 256x128, 0.04 %). The ground truth itself is exact at any
size (tests/test_objects_render.py ray casts every part).
"""

import json

import numpy as np
import pytest

pytest.importorskip("bpy")

from rgbd2scene.cli import main  # noqa: E402
from tests.conftest import BUNDLED_SAMPLE  # noqa: E402

SAMPLE_ARGS = ["--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
               "--camera", str(BUNDLED_SAMPLE / "camera.json")]


def test_instrument_scene_renders_and_verifies(tmp_path, capsys):
    scene, dataset = tmp_path / "scene", tmp_path / "dataset"
    assert main(["scene", *SAMPLE_ARGS, "--frames", "3", "--path", "scan", "--size", "128x64", "--no-overview",
                 "--instrument", "-o", str(scene)]) == 0
    assert "instrument 'instrument' (ids 2-5)" in capsys.readouterr().out
    record = json.loads((scene / "scene.json").read_text())
    assert record["objects"]["instruments"][0]["in_view_fraction"] == 1.0  # 3 frames: no entry phase
    assert sorted(p.name for p in (scene / "objects").iterdir()) == ["2.ply", "3.ply", "4.ply", "5.ply"]
    assert main(["render", str(scene), "-o", str(dataset), "--size", "256x128", "--samples", "1", "--quiet",
                 "--no-sheet"]) == 0
    info = json.loads((dataset / "dataset.json").read_text())
    assert {v["class"] for v in info["objects"].values()} == {"tissue", "instrument_shaft", "instrument_wrist",
                                                               "instrument_jaw"}
    seen = set()
    for f in range(3):
        gt = np.load(dataset / "left" / "gt" / f"{f:06d}.npz")
        seen |= set(np.unique(gt["segmentation"]).tolist())
        assert list(gt["object_ids"]) == [1, 2, 3, 4, 5, 6]
    assert 1 in seen and len(seen & {2, 3, 4, 5}) >= 2, seen
    capsys.readouterr()
    assert main(["verify", str(dataset), "--quiet"]) == 0, capsys.readouterr().out
