"""Interoperability on a real render (bundled sample, 64x32, 3 frames): a ROS 2 bag, a KITTI export and the stereo
evaluation of what ``rgbd2scene render`` writes, object ids and instrument-free tissue included."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from rgbd2scene.cli import main
from rgbd2scene.dataset import Dataset
from tests.conftest import BUNDLED_SAMPLE

pytest.importorskip("bpy")
cv2 = pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("interop")
    scene, dataset = root / "scene", root / "dataset"
    assert main(["scene", "--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
                 "--camera", str(BUNDLED_SAMPLE / "camera.json"), "--frames", "3", "--path", "scan",
                 "--no-overview", "-o", str(scene)]) == 0
    assert main(["render", str(scene), "-o", str(dataset), "--size", "64x32", "--samples", "1", "--quiet",
                 "--no-sheet"]) == 0
    return Dataset(dataset)


def test_ros2_bag_of_a_render(rendered, tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = tmp_path / "bag"
    assert main(["export-ros", str(rendered.root), "-o", str(bag), "--rate", "10", "--quiet"]) == 0
    counts, depth = {}, None
    with (bag / "bag.mcap").open("rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/stereo/depth/image_rect" and depth is None:
                depth = np.frombuffer(bytes(msg.data), "<f4").reshape(msg.height, msg.width)
            if channel.topic == "/tf" and counts["/tf"] == 1:
                children = {t.child_frame_id for t in msg.transforms}
    assert counts["/tf_static"] == 1 and counts["/stereo/left/image_rect_color"] == 3 and counts["/tf"] == 3
    ids = rendered.gt("left", 0, ("object_ids",))["object_ids"]
    assert children == {"endoscope", *(f"object_{int(i)}" for i in ids)}
    np.testing.assert_array_equal(depth, rendered.gt("left", 0, ("depth",))["depth"])


def test_kitti_export_and_evaluation_of_a_render(rendered, tmp_path):
    out = tmp_path / "kitti"
    assert main(["export", str(rendered.root), "--format", "kitti", "-o", str(out), "--quiet"]) == 0
    d = rendered.gt("left", 1, ("disparity",))["disparity"]
    png = cv2.imread(str(out / "disp_occ_0" / "000001_10.png"), cv2.IMREAD_UNCHANGED)
    ok = np.isfinite(d)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(png[ok] / 256.0, d[ok], atol=1 / 512 + 1e-6)
    ev = tmp_path / "eval"
    assert main(["evaluate", str(rendered.root), "--methods", "gt,sgbm", "-o", str(ev), "--quiet"]) == 0
    with open(ev / "metrics.csv", newline="") as f:
        rows = {(r["method"], r["scored"]): r for r in csv.DictReader(f)}
    assert float(rows["gt", "all"]["rmse_mm"]) < 1e-3 and float(rows["gt", "all"]["a1"]) == 1.0
    assert 0 < float(rows["sgbm", "valid"]["density"]) < 1
