"""The dataset reader: the record, the id table (parts, classes, tracked frames), frames and the scene path."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rgbd2scene.dataset import Dataset, frame_paths
from rgbd2scene.errors import UserError
from rgbd2scene.groundtruth.synthetic import PlaneScene, write_plane_dataset


@pytest.fixture
def plane(tmp_path):
    return write_plane_dataset(tmp_path / "ds", frames=3)


def test_record_and_frames(plane):
    ds = Dataset(plane)
    scene = PlaneScene()
    assert (ds.width, ds.height, ds.frames) == (scene.width, scene.height, 3)
    assert ds.baseline == scene.baseline and ds.fx == scene.fx
    np.testing.assert_array_equal(ds.K, scene.K)
    assert ds.frame_indices() == [0, 1, 2]
    frame_paths(plane, "right", 1).gt.unlink()  # an incomplete frame is not listed
    assert ds.frame_indices() == [0, 2] and ds.frame_indices(complete=False) == [0, 1, 2]
    assert ds.rgb("left", 0).shape == (scene.height, scene.width, 3)
    gt = ds.gt("left", 2, keys=("depth", "T_world_cam"))
    assert set(gt) == {"depth", "T_world_cam"} and gt["depth"].dtype == np.float32
    np.testing.assert_array_equal(ds.pose("right", 2), scene.pose("right", 2))
    seen = [(i, eye) for i, eye, _, _ in ds.iter_frames(keys=("depth",))]
    assert seen == [(0, "left"), (0, "right"), (2, "left"), (2, "right")]


def test_errors_name_the_file(plane, tmp_path):
    with pytest.raises(UserError, match="dataset.json"):
        Dataset(tmp_path / "nothing")
    with pytest.raises(UserError, match="no bogus"):
        Dataset(plane).gt("left", 0, keys=("bogus",))
    frame_paths(plane, "left", 1).gt.write_bytes(b"not a zip")
    with pytest.raises(UserError, match="000001.npz"):
        Dataset(plane).gt("left", 1)


def test_object_table_classes_and_tracked_frames(plane):
    meta = json.loads((plane / "dataset.json").read_text())
    meta["objects"] = {"1": {"name": "tissue", "part": "surface", "class": "tissue", "moving": True},
                       "2": {"name": "forceps", "part": "jaw_left", "class": "instrument_jaw", "moving": True},
                       "3": {"name": "forceps", "part": "jaw_right", "class": "instrument_jaw", "moving": True}}
    meta["classes"] = {"tissue": 1, "instrument_jaw": 2}
    meta["tracked_frames"] = {"500": {"name": "lesion", "attached_to": "tissue/surface"}}
    meta["scene"] = {"dir": "../scene"}
    (plane / "dataset.json").write_text(json.dumps(meta))
    ds = Dataset(plane)
    assert ds.objects[2].cls == ds.objects[3].cls == "instrument_jaw"  # one class, two instances
    assert ds.objects[500].tracked_frame and ds.objects[500].attached_to == "tissue/surface"
    assert not ds.objects[2].tracked_frame
    assert ds.classes == {"tissue": 1, "instrument_jaw": 2}
    assert ds.scene_dir == plane / "../scene"  # relative to the dataset folder, not the working directory
