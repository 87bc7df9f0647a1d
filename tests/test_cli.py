"""The command line as a user meets it: outputs of ``rgbd2scene mesh`` and one-line errors with exit 2."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from rgbd2scene.cli import main
from rgbd2scene.conventions import backproject
from rgbd2scene.files.images import read_image
from rgbd2scene.files.meshio import read_ply
from tests.conftest import BUNDLED_SAMPLE

SAMPLE_ARGS = ["--rgb", str(BUNDLED_SAMPLE / "rgb.png"), "--depth", str(BUNDLED_SAMPLE / "depth.png"),
               "--camera", str(BUNDLED_SAMPLE / "camera.json")]


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "rgbd2scene.cli", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def mesh_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("mesh")
    assert main(["mesh", *SAMPLE_ARGS, "-o", str(out)]) == 0
    return out


def test_mesh_command_writes_the_contract_files(mesh_folder):
    for name in ("mesh.ply", "scene.json", "depth_filled.npy", "mesh.obj", "mesh.mtl", "mesh_texture.png",
                 "overview.png"):
        assert (mesh_folder / name).is_file(), name
    record = json.loads((mesh_folder / "scene.json").read_text())
    assert record["capture"]["intrinsics"]["fx"] == 525.0
    assert record["capture"]["depth_scale"] == 1000.0
    assert 0.02 < record["fill"]["stats"]["hole_fraction"] < 0.2
    assert record["mesh"]["stats"]["faces_kept"] > 0
    for key in ("fill_s", "mesh_s", "smooth_s", "compute_s"):
        assert record["timings"][key] >= 0
    depth = np.load(mesh_folder / "depth_filled.npy")
    assert depth.dtype == np.float32 and depth.shape == (480, 640)


def test_mesh_vertices_lie_on_their_pixel_rays_in_metres(mesh_folder):
    """Smoothing along the ray keeps each vertex on the ray of the pixel whose colour it carries."""
    mesh = read_ply(mesh_folder / "mesh.ply")
    record = json.loads((mesh_folder / "scene.json").read_text())
    intr = record["capture"]["intrinsics"]
    K = np.array([[intr["fx"], 0, intr["cx"]], [0, intr["fy"], intr["cy"]], [0, 0, 1]])
    depth = np.load(mesh_folder / "depth_filled.npy")
    v = mesh.vertices
    u = K[0, 0] * v[:, 0] / v[:, 2] + K[0, 2]
    r = K[1, 1] * v[:, 1] / v[:, 2] + K[1, 2]
    col, row = np.round(u).astype(int), np.round(r).astype(int)
    assert np.abs(u - col).max() < 1e-3 and np.abs(r - row).max() < 1e-3
    texture = read_image(mesh_folder / "mesh_texture.png")  # the capture image without its highlights
    assert np.array_equal(mesh.vertex_colors, texture[row, col])
    # smoothing moves vertices only slightly off the filled depth (metres, not millimetres)
    z_filled = backproject(depth, K)[row, col, 2]
    assert np.median(np.abs(v[:, 2] - z_filled)) < 0.002


@pytest.mark.parametrize(
    "case, message",
    [
        ("missing_rgb", "RGB image not found"),
        ("size_mismatch", "same size"),
        ("bad_scale", "depth scale of 1000"),
        ("unwritable", "output"),
        ("bad_preset", "unknown camera preset"),
        ("bad_fill", "--fill"),
    ],
)
def test_user_errors_are_one_line_exit_2(tmp_path, case, message):
    args = ["mesh", *SAMPLE_ARGS, "-o", tmp_path / "out"]
    if case == "missing_rgb":
        args[2] = tmp_path / "missing.png"
    elif case == "size_mismatch":
        small = tmp_path / "small.png"
        cv2.imwrite(str(small), np.zeros((10, 10, 3), np.uint8))
        args[2] = small
    elif case == "bad_scale":
        args += ["--depth-scale", "1"]
    elif case == "unwritable":
        blocker = tmp_path / "file"
        blocker.write_text("x")
        args[-1] = blocker / "out"
    elif case == "bad_preset":
        args = ["mesh", *SAMPLE_ARGS[:4], "--preset", "nope", "-o", tmp_path / "out"]
    elif case == "bad_fill":
        args += ["--fill", "magic"]
    result = run_cli(*args)
    assert result.returncode == 2, result.stderr
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert message in lines[0]
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out" / "scene.json").exists()
