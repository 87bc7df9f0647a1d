"""The three everyday commands on the bundled sample: scene -> render -> verify (tiny render size).

Also the product promises that are only visible end to end: generated paths keep >= 95 % valid
ground truth on the bundled sample, scene.json records what rebuilds the scene, and ``verify`` fails
(exit 1) on a corrupted copy.
"""

import json
import shutil

import numpy as np
import pytest

from rgbd2scene.capture.camera import load_camera_json
from rgbd2scene.capture.readers import load_capture
from rgbd2scene.cli import main
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.reconstruct.pipeline import reconstruct
from rgbd2scene.scene.model import SceneDescription
from rgbd2scene.scene.paths import make_path, path_coverage
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import BUNDLED_SAMPLE

SAMPLE_ARGS = ["--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
               "--camera", str(BUNDLED_SAMPLE / "camera.json")]


@pytest.fixture(scope="module")
def sample_mesh():
    intr, scale = load_camera_json(BUNDLED_SAMPLE / "camera.json")
    cap = load_capture(BUNDLED_SAMPLE / "rgb.png", BUNDLED_SAMPLE / "depth.png", intr, depth_scale=scale)
    return reconstruct(cap).mesh


@pytest.mark.parametrize("kind", ["scan", "orbit", "random"])
def test_generated_paths_keep_95_percent_valid_pixels_on_bundled_sample(sample_mesh, kind):
    rig = StereoRig.endoscope()  # default 512x256, 70 deg, 5 mm
    rc = raycaster(sample_mesh.vertices, sample_mesh.triangles)
    path = make_path(kind, rig=rig, frames=24, seed=3, rc=rc)
    coverage = path_coverage(None, None, rig, path, rc=rc)  # full resolution, both eyes
    assert coverage.shape == (24, 2)
    assert coverage.min() >= 0.95, coverage.min()


@pytest.fixture(scope="module")
def scene_and_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("e2e")
    scene, dataset = root / "scene", root / "dataset"
    assert main(["scene", *SAMPLE_ARGS, "--frames", "3", "--path", "random", "--no-overview",
                 "-o", str(scene)]) == 0
    assert main(["render", str(scene), "-o", str(dataset), "--size", "64x32", "--samples", "2",
                 "--quiet"]) == 0
    return scene, dataset


def test_scene_folder_records_everything(scene_and_dataset):
    scene, _ = scene_and_dataset
    for name in ("scene.json", "scene.blend", "mesh.ply", "depth_filled.npy", "mesh.obj", "mesh_texture.png"):
        assert (scene / name).is_file(), name
    record = json.loads((scene / "scene.json").read_text())
    desc = SceneDescription.from_dict(record["scene"])
    assert desc.path.frames == 3 and desc.rig.baseline == 0.005
    assert (desc.rig.intrinsics.width, desc.rig.intrinsics.height) == (512, 256)
    assert record["coverage"]["min"] >= 0.95
    assert record["scene_options"]["path"] == "random" and record["scene_options"]["seed"] == 0
    assert record["capture"]["depth_scale"] == 1000.0


def test_render_writes_contract_layout(scene_and_dataset):
    _, dataset = scene_and_dataset
    meta = json.loads((dataset / "dataset.json").read_text())
    assert (meta["width"], meta["height"], meta["frames"], meta["baseline"]) == (64, 32, 3, 0.005)
    assert np.asarray(meta["K"]).shape == (3, 3)
    for eye in ("left", "right"):
        for f in range(3):
            assert (dataset / eye / "rgb" / f"{f:06d}.png").is_file()
            gt = np.load(dataset / eye / "gt" / f"{f:06d}.npz")
            assert gt["depth"].dtype == np.float32 and gt["depth"].shape == (32, 64)
            assert np.isfinite(gt["depth"]).mean() >= 0.95


def test_render_writes_a_contact_sheet_of_every_map(scene_and_dataset):
    import cv2

    _, dataset = scene_and_dataset
    sheet = cv2.imread(str(dataset / "contact_sheet.png"))
    assert sheet is not None
    # 3 columns: both eyes, depth, disparity, normals, both flows, instance and class masks with legends
    assert sheet.shape[1] > sheet.shape[0] * 0.9 and sheet.std() > 10


def test_verify_passes_then_fails_on_corruption(scene_and_dataset, tmp_path, capsys):
    _, dataset = scene_and_dataset
    assert main(["verify", str(dataset), "--quiet"]) == 0
    bad = tmp_path / "bad"
    shutil.copytree(dataset, bad)
    npz = bad / "left" / "gt" / "000001.npz"
    gt = dict(np.load(npz))
    gt["depth"] = gt["depth"] * np.float32(1.01)  # 1 % scale error: a wrong unit or K would do this
    np.savez_compressed(npz, **gt)
    capsys.readouterr()
    assert main(["verify", str(bad), "--quiet"]) == 1
    assert "FAIL" in capsys.readouterr().out


def test_render_resume_skips_finished_frames(scene_and_dataset, capsys):
    scene, dataset = scene_and_dataset
    capsys.readouterr()
    assert main(["render", str(scene), "-o", str(dataset), "--size", "64x32", "--samples", "2", "--quiet"]) == 0
    assert "rendered 0 frames, skipped 3" in capsys.readouterr().out
