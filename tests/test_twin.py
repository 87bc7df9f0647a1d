"""``scene --path capture``: the digital twin's frame 0 re-creates the captured view."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from rgbd2scene.stages.scene import SceneOptions, capture_camera

W, H, FX = 80, 60, 70.0


def test_capture_camera_of_a_stereo_record_is_the_calibrated_pair():
    K1 = [[400.0, 0, 180.0], [0, 401.0, 140.0], [0, 0, 1]]
    K2 = [[402.0, 0, 175.0], [0, 400.0, 142.0], [0, 0, 1]]
    angle = np.radians(1.0)
    R = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    calib = {"K_left": K1, "D_left": [-0.2, 0.05, 0, 0, 0], "K_right": K2, "D_right": [-0.21, 0.04, 0, 0, 0],
             "R": R, "T": [-0.0055, 0.0, 0.0001], "image_size": [360, 288]}
    rig, pose = capture_camera({"capture": {"stereo": {"calibration_values": calib}}}, SceneOptions())
    assert (rig.left.width, rig.left.height) == (360, 288) and not rig.rectified
    np.testing.assert_array_equal(rig.right.K, K2)
    np.testing.assert_array_equal(rig.left.D, calib["D_left"])
    np.testing.assert_allclose(rig.calibration.R, R)
    assert rig.baseline == pytest.approx(np.linalg.norm(calib["T"]))
    np.testing.assert_array_equal(pose, np.eye(4))


def test_twin_frame_0_depth_is_the_captures_filled_depth(tmp_path):
    pytest.importorskip("bpy")
    from rgbd2scene.cli import main
    from rgbd2scene.dataset import layout as ds
    from rgbd2scene.stages.render import render_gt_only

    v, u = np.mgrid[0:H, 0:W]
    depth_mm = (60.0 + 6.0 * np.sin(u / 11.0) * np.cos(v / 8.0) + 0.05 * u).round().astype(np.uint16)
    depth_mm[20:24, 30:36] = 0  # a hole, filled by the mesh stage
    rgb = np.random.default_rng(0).integers(0, 255, (H, W, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "depth.png"), depth_mm)
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb)
    camera = {"width": W, "height": H, "fx": FX, "fy": FX, "cx": (W - 1) / 2, "cy": (H - 1) / 2, "depth_scale": 1000}
    (tmp_path / "camera.json").write_text(json.dumps(camera))
    scene, out = tmp_path / "scene", tmp_path / "ds"
    assert main(["scene", "--rgb", str(tmp_path / "rgb.png"), "--depth", str(tmp_path / "depth.png"), "--camera",
                 str(tmp_path / "camera.json"), "--path", "capture", "--frames", "2", "--smooth", "none",
                 "--no-overview", "-o", str(scene)]) == 0
    record = json.loads((scene / "scene.json").read_text())
    assert record["scene"]["path"]["kind"] == "capture"
    # an RGB-D capture is lit by the room: its texture is left as captured
    assert not record["delight"]["applied"] and not (scene / "texture_lit.png").exists()
    render_gt_only(scene, out, progress=False)
    _, gt = ds.read_frame(out, "left", 0, rgb=False)
    filled = np.load(scene / "depth_filled.npy")
    assert gt["depth"].shape == filled.shape == (H, W)
    np.testing.assert_allclose(gt["K"], [[FX, 0, (W - 1) / 2], [0, FX, (H - 1) / 2], [0, 0, 1]])
    np.testing.assert_array_equal(gt["T_world_cam"], np.eye(4))
    seen = np.isfinite(gt["depth"])
    assert seen.mean() > 0.99  # every pixel of the mesh (the capture pose's rays pass through its vertices)
    np.testing.assert_allclose(gt["depth"][seen], filled[seen], rtol=1e-6)


def test_stereo_twin_is_the_calibrated_pair_at_the_capture(shared_samples, tmp_path):
    """The Hamlyn frame's twin: the raw calibrated pair (its K, D, R, T and image size) at the calibration's
    left camera. Its frame-0 depth, seen from the rectified camera the capture's depth was computed in,
    is that filled depth (where the mesh exists)."""
    pytest.importorskip("bpy")
    from scipy.ndimage import map_coordinates

    from rgbd2scene.cli import main
    from rgbd2scene.conventions import invert_pose, transform_points
    from rgbd2scene.dataset import layout as ds
    from rgbd2scene.geometry.camera import Camera
    from rgbd2scene.stages.render import render_gt_only

    hamlyn = shared_samples / "hamlyn_silicone_heart_phantom_stereo"
    scene, out = tmp_path / "scene", tmp_path / "ds"
    assert main(["scene", "--left", str(hamlyn / "f7_dynamic_deint_L_0100.png"), "--right",
                 str(hamlyn / "f7_dynamic_deint_R_0100.png"), "--stereo-calib", str(hamlyn), "--path", "capture",
                 "--frames", "1", "--smooth", "none", "--no-overview", "-o", str(scene)]) == 0
    render_gt_only(scene, out, progress=False)
    meta = json.loads((out / "dataset.json").read_text())
    assert (meta["width"], meta["height"]) == (360, 288) and meta["camera"]["rectified"] is False
    np.testing.assert_allclose(meta["camera"]["left"]["fx"], np.loadtxt(hamlyn / "calib.left.intrinsic.txt")[0, 0])
    full = json.loads((scene / "scene.json").read_text())
    record = full["capture"]
    # a stereo endoscope capture: --delight auto divides the scope light out of the texture, keeping the lit one
    assert full["delight"]["applied"] and full["files"]["texture_lit"] == "texture_lit.png"
    assert (scene / "texture_lit.png").is_file() and full["delight"]["stats"]["clamped_share"] < 0.01
    _, gt = ds.read_frame(out, "left", 0, rgb=False)
    np.testing.assert_array_equal(gt["T_world_cam"], np.eye(4))
    camera = Camera.from_K(gt["K"], 360, 288, gt["D"])
    points = camera.backproject(gt["depth"])  # world = the calibration's left camera frame
    rect = transform_points(invert_pose(np.asarray(record["T_world_capture"])), points)
    K_rect = np.asarray(record["stereo"]["rectification"]["K"])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = K_rect[0, 0] * rect[..., 0] / rect[..., 2] + K_rect[0, 2]
        v = K_rect[1, 1] * rect[..., 1] / rect[..., 2] + K_rect[1, 2]
    filled = np.load(scene / "depth_filled.npy").astype(np.float64)
    seen = np.isfinite(gt["depth"]) & np.isfinite(u) & np.isfinite(v)
    assert seen.mean() > 0.3
    ref = map_coordinates(np.nan_to_num(filled, nan=-1.0), [v[seen], u[seen]], order=1, mode="constant", cval=-1)
    ok = ref > 0
    rel = np.abs(ref[ok] - rect[..., 2][seen][ok]) / ref[ok]
    # the mesh is flat between its vertices and the lookup bilinear: equal to a small fraction of the depth
    assert np.median(rel) < 2e-4 and np.percentile(rel, 95) < 2e-3, (np.median(rel), np.percentile(rel, 95))
