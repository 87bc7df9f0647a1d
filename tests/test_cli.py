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
    assert record["options"]["sensor"] == "kinect_v1"  # the default preset's sensor
    assert record["fill"]["settings"]["sensor"]["kind"] == "structured_light"
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
        ("bad_sensor", "--sensor: unknown sensor 'sonar'"),
        ("rgb_as_depth", "depth must be a single-channel image, got 3 channels"),
        ("rgba_depth", "depth must be a single-channel image, got 4 channels"),
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
    elif case == "bad_sensor":
        args += ["--sensor", "sonar"]
    elif case in ("rgb_as_depth", "rgba_depth"):
        # 16-bit colour images with equal channels: they look like depth values, and used to make a mesh
        channels = 3 if case == "rgb_as_depth" else 4
        depth = cv2.imread(str(BUNDLED_SAMPLE / "depth.png"), cv2.IMREAD_UNCHANGED)
        colour = tmp_path / f"depth_{channels}.png"
        cv2.imwrite(str(colour), np.dstack([depth] * channels))
        args[4] = colour
    result = run_cli(*args)
    assert result.returncode == 2, result.stderr
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert message in lines[0]
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out" / "scene.json").exists()


@pytest.mark.parametrize("case", ["path_file", "standoff"])
def test_scene_path_errors_are_one_line_exit_2(mesh_folder, tmp_path, case):
    bad = tmp_path / "path.json"
    bad.write_text(json.dumps({"waypoints": [{"position": [0, 0, 0]}]}))
    extra, message = {
        "path_file": (["--path-file", bad], f"error: {bad}: waypoint 0: waypoint lacks look_at (or give T_world_cam)"),
        "standoff": (["--standoff", "-1"], "error: path: standoff must be positive, got -1.0"),
    }[case]
    result = run_cli("scene", "--mesh-dir", mesh_folder, *extra, "-o", tmp_path / "out")
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip() == message
    assert not (tmp_path / "out" / "scene.json").exists()


@pytest.fixture
def capture_inputs(tmp_path):
    """Files for the input-mode errors: a stereo pair of 64x48 images and calibrations, a trajectory."""
    img = np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    for name in ("left.png", "right.png"):
        cv2.imwrite(str(tmp_path / name), img)
    calib = {"K_left": [[60, 0, 31.5], [0, 60, 23.5], [0, 0, 1]], "D_left": [0, 0, 0, 0, 0],
             "K_right": [[60, 0, 31.5], [0, 60, 23.5], [0, 0, 1]], "D_right": [0, 0, 0, 0, 0],
             "R": np.eye(3).tolist(), "T": [-0.005, 0, 0], "image_size": [64, 48]}
    (tmp_path / "calib.json").write_text(json.dumps(calib))
    (tmp_path / "calib_big.json").write_text(json.dumps({**calib, "image_size": [320, 240],
                                                         "K_left": [[300, 0, 160], [0, 300, 120], [0, 0, 1]],
                                                         "K_right": [[300, 0, 160], [0, 300, 120], [0, 0, 1]]}))
    (tmp_path / "calib_bad.json").write_text(json.dumps({k: v for k, v in calib.items() if k != "R"}))
    (tmp_path / "traj.txt").write_text("0.0 0 0 0 0 0 0 1\n1.0 0 0 0.01 0 0\n")
    (tmp_path / "traj3.txt").write_text("".join(f"{t}.0 0 0 0 0 0 0 1\n" for t in range(3)))
    return tmp_path


RGB, DEPTH = str(BUNDLED_SAMPLE / "rgb.png"), str(BUNDLED_SAMPLE / "depth.png")


@pytest.mark.parametrize("command", ["mesh", "scene"])
@pytest.mark.parametrize("case, message", [
    ("nothing", "--rgb and --depth"),
    ("both_modes", "not both"),
    ("stereo_missing_right", "missing --right"),
    ("stereo_with_camera", "--camera do(es) not apply to a stereo frame"),
    ("counts", "--rgb has 2 files but --depth has 1"),
    ("poses_single_frame", "--poses needs several frames"),
    ("bad_trajectory_line", "traj.txt: line 2: expected 8 numbers"),
    ("missing_trajectory", "nope.txt: trajectory file not found"),
    ("trajectory_count", "traj3.txt: 3 poses for 2 frames"),
    ("bad_calibration", "calib_bad.json: bad stereo calibration: missing key(s) R"),
    ("calibration_size", "the images are 64x48 but the calibration"),
    ("missing_left", "left_nope.png: RGB image not found"),
    ("depth_range", "--depth-range"),
    ("voxel_size", "--voxel-size"),
    ("fusion_option_on_stereo", "--voxel-size do(es) not apply to a stereo frame"),
    ("stereo_option_on_rgbd", "--depth-range do(es) not apply to a single RGB-D frame"),
])
def test_capture_mode_errors_are_one_line_exit_2(capture_inputs, capsys, command, case, message):
    d = capture_inputs
    stereo = ["--left", str(d / "left.png"), "--right", str(d / "right.png"), "--stereo-calib", str(d / "calib.json")]
    two = ["--rgb", RGB, RGB, "--depth", DEPTH, DEPTH, "--camera", str(BUNDLED_SAMPLE / "camera.json")]
    args = {
        "nothing": [],
        "both_modes": [*stereo, "--rgb", RGB, "--depth", DEPTH],
        "stereo_missing_right": stereo[:2] + stereo[4:],
        "stereo_with_camera": [*stereo, "--camera", str(BUNDLED_SAMPLE / "camera.json")],
        "counts": ["--rgb", RGB, RGB, "--depth", DEPTH],
        "poses_single_frame": ["--rgb", RGB, "--depth", DEPTH, "--poses", str(d / "traj.txt")],
        "bad_trajectory_line": [*two, "--poses", str(d / "traj.txt")],
        "missing_trajectory": [*two, "--poses", str(d / "nope.txt")],
        "trajectory_count": [*two, "--poses", str(d / "traj3.txt")],
        "bad_calibration": [*stereo[:5], str(d / "calib_bad.json")],
        "calibration_size": [*stereo[:5], str(d / "calib_big.json")],
        "missing_left": ["--left", str(d / "left_nope.png"), *stereo[2:]],
        "depth_range": [*stereo, "--depth-range", "0.5", "0.1"],
        "voxel_size": [*two, "--voxel-size", "-1"],
        "fusion_option_on_stereo": [*stereo, "--voxel-size", "0.001"],
        "stereo_option_on_rgbd": ["--rgb", RGB, "--depth", DEPTH, "--depth-range", "0.1", "0.5"],
    }[case]
    out = d / "out"
    assert main([command, *args, "-o", str(out)]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert message in lines[0], lines[0]
    assert not (out / "scene.json").exists()


@pytest.mark.parametrize("own_arguments", [True, False])
def test_the_process_command_freezes_the_heap_at_exit_a_call_does_not(own_arguments):
    """Run as the process's command (no ``argv``), the CLI freezes the heap when the interpreter exits, so that
    its last collections skip NumPy's, SciPy's and OpenCV's objects; called with arguments (as here, by a
    program that goes on) it leaves the collector alone."""
    call = "cli.main()" if own_arguments else "cli.main(['mesh', '--help'])"
    code = ("import atexit, gc, sys\n"
            "atexit.register(lambda: print('frozen at exit:', gc.get_freeze_count() > 0))  # runs after the CLI's\n"
            "from rgbd2scene import cli\n"
            "sys.argv = ['rgbd2scene', 'mesh', '--help']\n"
            "try:\n"
            f"    {call}\n"
            "except SystemExit:\n"
            "    pass\n"
            "assert gc.get_freeze_count() == 0\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().endswith(f"frozen at exit: {own_arguments}")
