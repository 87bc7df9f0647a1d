"""``rgbd2scene evaluate`` on a raw (distorted, unequal-eyed) pair: methods match in the rectified grid of the rig
and are scored at the raw pixels against exact ground truth.

The dataset is built here in closed form, without Blender: a textured plane seen by a rig with barrel distortion,
unequal eyes and a rotated right eye; every raw pixel's image value and depth come from its own ray
(``Camera.rays``) meeting the plane. The independent check of the scoring is a prediction computed in closed
form in the rectified grid (``cv2.stereoRectify``'s R1 / P1, alpha 0): each rectified pixel's ray meets the
plane, and its disparity is f_r B / z_rect.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from rgbd2scene.cli import main
from rgbd2scene.conventions import CONVENTIONS_VERSION
from rgbd2scene.dataset import Dataset
from rgbd2scene.dataset.layout import EYES, frame_paths, write_dataset_json, write_gt, write_rgb
from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.stereo import StereoCalibration
from rgbd2scene.groundtruth.synthetic import PlaneScene, plane_texture
from rgbd2scene.scene.rig import StereoRig

cv2 = pytest.importorskip("cv2")
W, H, FRAMES = 160, 120, 2
Z0, TILT = 0.05, 0.2  # the plane Z = Z0 + TILT X (left camera frame = world frame)


def _rig() -> StereoRig:
    left = Camera(Intrinsics(W, H, 120.0, 120.0, 81.0, 58.5), (-0.18, 0.04, 0.0005, -0.0004, 0.0))
    right = Camera(Intrinsics(W, H, 123.0, 122.0, 77.5, 61.0), (-0.15, 0.03, -0.0003, 0.0002, 0.0))
    angle = np.deg2rad(1.5)  # the right eye turned about y (and a little about x)
    R = cv2.Rodrigues(np.array([0.004, angle, -0.003]))[0]
    return StereoRig(StereoCalibration(left, right, R, [-0.005, 0.0002, 0.0001]))


def _hit(origin: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Ray parameter t of rays (..., 3) from ``origin`` meeting the plane (NaN: no ray or behind)."""
    t = (Z0 + TILT * origin[0] - origin[2]) / (rays[..., 2] - TILT * rays[..., 0])
    return np.where(t > 0, t, np.nan)


def _write_raw_dataset(root):
    rig = _rig()
    scene = PlaneScene(width=W, height=H, seed=3)
    for index in range(FRAMES):
        for eye in EYES:
            T = np.eye(4) if eye == "left" else rig.calibration.T_left_right.copy()
            T[0, 3] += 0.0005 * index
            rays = rig.camera(eye).rays() @ T[:3, :3].T  # unit camera z: t is the planar depth
            t = _hit(T[:3, 3], rays)
            rgb = plane_texture(scene, T[:3, 3] + t[..., None] * rays)
            rgb[~np.isfinite(t)] = 0
            write_rgb(frame_paths(root, eye, index).rgb, rgb)
            write_gt(frame_paths(root, eye, index).gt, {"depth": t.astype(np.float32), "K": rig.camera(eye).K,
                                                         "T_world_cam": T})
    write_dataset_json(root, {
        "width": W, "height": H, "frames": FRAMES, "fps": 30.0, "baseline": rig.baseline, "K": rig.left.K.tolist(),
        "eyes": list(EYES), "objects": {}, "classes": {},
        "camera": {"rectified": False, "left": rig.left.to_dict(), "right": rig.right.to_dict(),
                   "R": [list(r) for r in rig.calibration.R], "T": list(rig.calibration.T)},
        "render": {"engine": "synthetic", "gt": ["depth"]}, "scene": {"synthetic": "raw plane"},
        "software": {}, "seed": 0, "conventions_version": CONVENTIONS_VERSION,
    })
    return root


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    return Dataset(_write_raw_dataset(tmp_path_factory.mktemp("raw") / "ds"))


def _rectified_disparity(index: int) -> np.ndarray:
    """The plane's left disparity in the rectified grid, in closed form: f_r B / z of each rectified pixel's ray."""
    rig = _rig()
    rect = rig.calibration.rectification()
    P1 = np.asarray(rect.P1)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays_rect = np.stack([(u - P1[0, 2]) / P1[0, 0], (v - P1[1, 2]) / P1[1, 1], np.ones_like(u)], axis=-1)
    rays_raw = rays_rect @ np.asarray(rect.R1)  # rectified -> raw left frame: R1^T r
    origin = np.array([0.0005 * index, 0.0, 0.0])
    t = _hit(origin, rays_raw)  # the rectified ray is rays_rect with z 1: t is the rectified depth too
    return (P1[0, 0] * rig.baseline / t).astype(np.float32)


def _row(folder, method, scored="all"):
    with open(folder / "metrics.csv", newline="") as f:
        return next(r for r in csv.DictReader(f) if r["method"] == method and r["scored"] == scored)


def test_the_exact_rectified_disparity_scores_near_zero_at_the_raw_pixels(raw, tmp_path):
    preds = tmp_path / "exact"
    preds.mkdir()
    for index in range(FRAMES):
        np.save(preds / f"{index:06d}.npy", _rectified_disparity(index))
    out = tmp_path / "eval"
    assert main(["evaluate", str(raw.root), "-o", str(out), "--methods", "none", "--predictions", str(preds),
                 "--quiet", "--no-error-maps"]) == 0
    row = _row(out, "exact", "valid")
    # read at the nearest rectified pixel (at most 0.5 px away: the plane's depth changes 0.1 mm per px there)
    assert float(row["rmse_mm"]) < 0.04 and float(row["a1"]) == 1.0
    # the raw corners beyond the rectified image (alpha 0 crops it to pixels both eyes have) get no prediction:
    # filled from the nearest one, they are the whole error of the main score
    assert 0.8 < float(row["density"]) < 0.9
    assert 0.04 < float(_row(out, "exact")["rmse_mm"]) < 0.3


def test_sgbm_matches_the_rectified_pair(raw, tmp_path):
    out = tmp_path / "eval"
    assert main(["evaluate", str(raw.root), "-o", str(out), "--methods", "sgbm", "--quiet"]) == 0
    row = _row(out, "sgbm")
    # matched on the raw images (rows that are not epipolar lines), SGBM scored RMSE 17 mm, a1 0.27 here
    # (0.95 mm and 1.0 rectified, 0.54 mm on the pixels it matched)
    assert float(row["rmse_mm"]) < 1.5 and float(row["a1"]) > 0.99
    assert float(_row(out, "sgbm", "valid")["rmse_mm"]) < 0.8
    assert "raw pair matched rectified" in (out / "metrics.md").read_text()
    assert len(list((out / "error_maps").glob("*.png"))) == 2
