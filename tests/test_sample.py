"""The bundled synthetic Kinect capture (data_samples/tissue) and its generator."""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import numpy as np
import pytest

from rgbd2scene.capture.camera import PRESETS, load_camera_json
from rgbd2scene.capture.readers import load_capture, read_rgb

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data_samples" / "tissue"
GENERATOR = ROOT / "data_samples" / "make_tissue_sample.py"


@pytest.fixture(scope="module")
def sample():
    intr, scale = load_camera_json(SAMPLE / "camera.json")
    cap = load_capture(SAMPLE / "rgb.png", SAMPLE / "depth.png", intr, scale)
    gt = np.load(SAMPLE / "depth_gt.npy")
    return intr, scale, cap, gt


def test_files_present_and_small():
    for name in ("rgb.png", "depth.png", "camera.json", "depth_gt.npy", "hole_cause.png", "README.md"):
        assert (SAMPLE / name).is_file(), name
    total = sum(p.stat().st_size for p in SAMPLE.iterdir())
    assert total < 2.5e6  # float32 depth_gt.npy alone is 1.23 MB


def test_camera_json_is_primesense(sample):
    intr, scale, _, _ = sample
    assert intr == PRESETS["primesense"]
    assert scale == 1000.0
    data = json.loads((SAMPLE / "camera.json").read_text())
    assert {"width", "height", "fx", "fy", "cx", "cy", "depth_scale"} <= set(data)


def test_capture_loads_with_plausible_values(sample):
    _, _, cap, _ = sample
    assert cap.rgb.shape == (480, 640, 3) and cap.rgb.dtype == np.uint8
    assert cap.depth.shape == (480, 640) and cap.depth.dtype == np.float32
    valid = np.isfinite(cap.depth)
    z = cap.depth[valid]
    assert 0.45 <= z.min() and z.max() <= 1.0  # ex-vivo lab bench, 0.5-0.8 m
    assert 0.55 < np.median(z) < 0.75
    holes = 1.0 - valid.mean()
    assert 0.02 < holes < 0.25  # Kinect v1 frames: a few % to ~20 %
    # millimetre depth PNG: values are whole millimetres
    assert np.allclose(z * 1000, np.round(z * 1000), atol=1e-3)


def test_depth_gt_complete_and_close_to_sensor(sample):
    _, _, cap, gt = sample
    assert gt.dtype == np.float32 and gt.shape == (480, 640)
    assert np.isfinite(gt).all()
    assert 0.5 < gt.min() and gt.max() < 0.9
    valid = np.isfinite(cap.depth)
    err_mm = (cap.depth[valid] - gt[valid]) * 1000.0
    assert abs(err_mm.mean()) < 0.3  # unbiased
    assert 0.3 < np.sqrt(np.mean(err_mm**2)) < 2.0  # noisy, like a Kinect at 0.6 m (~1 mm)
    assert np.percentile(np.abs(err_mm), 99) < 6.0


def test_sensor_artefacts_are_where_a_kinect_puts_them(sample):
    _, _, cap, gt = sample
    holes = ~np.isfinite(cap.depth)
    # invalid band on the left border (registration)
    assert holes[:, :7].all()
    assert holes[:2, :].all()
    # saturated specular highlights in RGB have no depth
    saturated = cap.rgb.min(axis=2) >= 250
    assert saturated.sum() > 200
    assert holes[saturated].mean() > 0.95
    # projector shadows lie on the far surface, with a nearer surface (the step) to their right
    cause = read_rgb(SAMPLE / "hole_cause.png")[..., 0]
    rows, cols = np.nonzero(cause == 2)
    assert len(rows) > 100
    nearer = [gt[r, c + 1:c + 12].min() < gt[r, c] - 0.005
              for r, c in zip(rows, cols, strict=True) if c < 620]
    assert np.mean(nearer) > 0.8
    # depth is quantised like Kinect disparity: the code 1092.5 - 351.3/z is (close to) an integer
    z = cap.depth[np.isfinite(cap.depth)].astype(np.float64)
    code = 1092.5 - 351.3 / z
    assert np.median(np.abs(code - np.round(code))) < 0.2


def test_rgb_looks_like_tissue_on_a_drape(sample):
    _, _, cap, _ = sample
    rgb = cap.rgb.astype(np.float64)
    centre = rgb[200:280, 260:380].reshape(-1, 3).mean(axis=0)
    assert centre[0] > centre[1] + 30 and centre[0] > centre[2] + 30  # reddish organ in the middle
    corner = rgb[440:475, 20:80].reshape(-1, 3).mean(axis=0)
    assert corner[2] > corner[0]  # blue drape around it
    assert rgb.std() > 20


def _load_generator():
    spec = importlib.util.spec_from_file_location("make_tissue_sample", GENERATOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_generator_is_deterministic(tmp_path):
    """Regenerating gives byte-identical files (about 4 s of CPU)."""
    gen = _load_generator()
    t0 = time.perf_counter()
    stats = gen.make_sample(tmp_path, verbose=False)
    assert time.perf_counter() - t0 < 60
    for name in ("depth.png", "rgb.png", "depth_gt.npy", "hole_cause.png"):
        assert (tmp_path / name).read_bytes() == (SAMPLE / name).read_bytes(), name
    written = load_capture(tmp_path / "rgb.png", tmp_path / "depth.png", PRESETS["primesense"], 1000.0)
    assert stats["hole_fraction"] == pytest.approx(float(written.hole_mask.mean()))
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind
