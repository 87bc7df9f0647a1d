"""Hole filling (rgbd2scene.fill) on small analytic scenes with known truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rgbd2scene.errors import UserError
from rgbd2scene.reconstruct.fill import (
    FILL_METHODS,
    FillResult,
    fill_background,
    fill_biharmonic,
    fill_colorization,
    fill_depth,
    fill_harmonic,
    fill_inpaint,
    shadow_pixels,
    step_runs,
)

H, W = 120, 160
FX = 525.0 * W / 640.0  # what fill_depth assumes by default
SHARED = Path(__file__).resolve().parents[2] / "shared" / "rgbd_samples"


def smooth_surface() -> np.ndarray:
    """A curved, tilted, organ-like surface around 1 m (float32 metres)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 1.0 + 0.15 * (u / W) + 0.05 * np.sin(u / 25.0) * np.cos(v / 30.0)
    return z.astype(np.float32)


def step_scene() -> tuple[np.ndarray, np.ndarray, int]:
    """A sloped far wall (about 2 m) with a near box (1 m) in columns 90-129; RGB registered."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 2.0 + 0.002 * u + 0.001 * v
    box = (u >= 90) & (u < 130) & (v >= 20) & (v < 100)
    z[box] = 1.0 + 0.0005 * u[box]
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[..., 0] = 60 + (u * 0.5).astype(np.uint8)
    rgb[..., 2] = 160
    rgb[box] = (220, 180, 40)
    # the projector shadow left of the box: fx * b * (1/z_near - 1/z_far) px
    width = int(FX * 0.075 * (1.0 / 1.045 - 1.0 / 2.2))
    return z.astype(np.float32), rgb, width


def blobs(seed: int = 0, n: int = 6, r: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    m = np.zeros((H, W), bool)
    for _ in range(n):
        cv, cu = rng.integers(20, H - 20), rng.integers(20, W - 20)
        m |= (v - cv) ** 2 + (u - cu) ** 2 <= r * r
    return m


def texture_rgb(z: np.ndarray) -> np.ndarray:
    g = ((z - z.min()) / np.ptp(z) * 200 + 30).astype(np.uint8)
    return np.dstack([g, g // 2, 255 - g])


@pytest.mark.parametrize("filler", ["inpaint", "colorization", "biharmonic", "harmonic", "background"])
def test_each_filler_beats_a_constant_fill(filler):
    truth = smooth_surface()
    mask = blobs()
    depth = truth.copy()
    depth[mask] = np.nan
    rgb = texture_rgb(truth)
    out = {
        "inpaint": lambda: fill_inpaint(depth),
        "colorization": lambda: fill_colorization(depth, rgb),
        "biharmonic": lambda: fill_biharmonic(depth),
        "harmonic": lambda: fill_harmonic(depth),
        "background": lambda: fill_background(depth),
    }[filler]()
    assert out.dtype == np.float32 and out.shape == depth.shape
    assert np.isfinite(out).all()
    err = np.abs(out[mask] - truth[mask]).mean()
    naive = np.abs(np.nanmean(depth) - truth[mask]).mean()
    assert err < 0.1 * naive, (filler, err, naive)
    assert err < 0.01  # metres, on a surface with 5 cm of relief


def test_biharmonic_is_exact_on_a_plane():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = (1.0 / (0.5 + 0.001 * u - 0.0007 * v)).astype(np.float32)  # a plane: affine inverse depth
    mask = blobs(3, n=4, r=8)
    depth = truth.copy()
    depth[mask] = np.nan
    out = fill_biharmonic(depth)
    np.testing.assert_allclose(out[mask], truth[mask], rtol=1e-5)


def test_background_fills_a_shadow_with_the_far_depth():
    truth, rgb, width = step_scene()
    assert width >= 4
    depth = truth.copy()
    shadow = np.zeros((H, W), bool)
    shadow[20:100, 90 - width:90] = True  # left of the near box, on the far wall
    depth[shadow] = np.nan
    far = truth[shadow]
    for out in (fill_background(depth), fill_depth(depth, rgb, "auto").depth):
        assert np.abs(out[shadow] - far).max() < 0.02 * far.max()
    smooth_err = np.abs(fill_biharmonic(depth)[shadow] - far).mean()
    assert smooth_err > 0.2  # a smooth fill would mix in the near box: what the background fill avoids


def test_step_runs_and_shadow_width():
    truth, _, width = step_scene()
    depth = truth.copy()
    mask = np.zeros((H, W), bool)
    mask[20:100, 90 - width:90] = True  # a real shadow's width
    mask[30:40, 50:56] = True  # a hole inside the wall: no step
    depth[mask] = np.nan
    runs = step_runs(depth, mask)
    assert (runs.axis == 0).sum() == 80  # one step run per shadow row
    assert not runs.near_first[runs.axis == 0].any()  # the near end is right of the run
    sh = shadow_pixels(runs, depth, FX)
    assert sh[20:100, 90 - width:90].all() and not sh[30:40, 50:56].any()
    # a run much wider than a shadow there is not taken for one
    wide = mask.copy()
    wide[20:100, 40:90] = True
    depth_w = truth.copy()
    depth_w[wide] = np.nan
    assert not shadow_pixels(step_runs(depth_w, wide), depth_w, FX).any()


def test_a_slanted_surface_is_not_a_step():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = (1.0 / (0.2 + 0.006 * v)).astype(np.float32)  # a floor from 5 m to 1.1 m
    depth = truth.copy()
    mask = np.zeros((H, W), bool)
    mask[40:70, 60:70] = True  # vertical runs span 5 % to 20 % depth change
    depth[mask] = np.nan
    assert step_runs(depth, mask).axis.size == 0


@pytest.mark.parametrize("method", [m for m in FILL_METHODS])
def test_valid_pixels_are_untouched_and_result_is_serialisable(method):
    truth, rgb, width = step_scene()
    depth = truth.copy()
    holes = blobs(1) | np.zeros((H, W), bool)
    holes[20:100, 90 - width:90] = True
    depth[holes] = np.nan
    res = fill_depth(depth, rgb, method)
    assert isinstance(res, FillResult)
    valid = ~holes
    assert np.array_equal(res.depth[valid], depth[valid])
    assert res.depth.dtype == np.float32 and res.filled.dtype == bool
    assert not res.filled[valid].any()
    json.dumps(res.settings)
    json.dumps(res.stats)
    for key in ("hole_fraction", "filled_fraction", "left_unfilled_fraction", "n_holes", "seconds"):
        assert key in res.stats
    if method == "none":
        assert np.isnan(res.depth[holes]).all() and res.method == "none"
    else:
        assert np.isfinite(res.depth).all() and res.filled[holes].all()
        assert res.stats["left_unfilled_fraction"] == 0.0
    if method == "auto":
        assert res.method.startswith("auto: ") and "background" in res.method


def test_huge_hole_is_left_nan():
    truth = smooth_surface()
    depth = truth.copy()
    huge = np.zeros((H, W), bool)
    huge[30:70, 40:100] = True  # 12.5 % of the image
    small = blobs(2, n=2, r=3) & ~ndilate(huge)
    depth[huge | small] = np.nan
    res = fill_depth(depth, None, "auto", max_hole_fraction=0.05)
    assert np.isnan(res.depth[huge]).all() and not res.filled[huge].any()
    assert np.isfinite(res.depth[small]).all()
    assert res.stats["huge_holes"] == 1
    assert res.stats["left_unfilled_fraction"] == pytest.approx(huge.mean())
    assert np.isfinite(fill_depth(depth, None, "auto", max_hole_fraction=0.2).depth).all()


def ndilate(m: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_dilation(m, iterations=2)


def test_border_band_is_extrapolated_when_narrow():
    truth = smooth_surface()
    depth = truth.copy()
    band = np.zeros((H, W), bool)
    band[:, :8] = True  # Kinect-like invalid band on the left
    band[-5:, :] = True  # and at the bottom
    depth[band] = np.nan
    res = fill_depth(depth, None, "biharmonic")
    assert np.isfinite(res.depth).all() and res.filled[band].all()
    assert res.stats["border_band_fraction"] == pytest.approx(band.mean())
    # edge replication: each band pixel takes the nearest valid value (slope 3 mm/px, 8 px band)
    assert np.abs(res.depth[band] - truth[band]).max() < 0.03
    kept = fill_depth(depth, None, "biharmonic", fill_border=False)
    assert np.isnan(kept.depth[band]).all()
    # a 30 px band with border_width 10: its inner 20 px are an interior hole, too big (12.5 %) to
    # fill, and the outer 10 px are then too far from any depth to extrapolate
    wide = truth.copy()
    wide[:, :30] = np.nan
    res = fill_depth(wide, None, "auto", border_width=10)
    assert np.isfinite(res.depth[:, 30:]).all()
    assert np.isnan(res.depth[10:-10, :30]).all() and np.isnan(res.depth[:, :15]).all()
    assert res.stats["huge_holes"] == 1
    res = fill_depth(wide, None, "auto", border_width=10, max_hole_fraction=0.2)
    assert np.isfinite(res.depth).all()


def test_hole_at_the_border_beyond_the_band_is_filled_as_interior():
    truth = smooth_surface()
    depth = truth.copy()
    depth[40:60, :30] = np.nan  # touches the left edge, reaches beyond a 12 px band
    res = fill_depth(depth, None, "auto", border_width=12)
    assert np.isfinite(res.depth).all()
    assert np.abs(res.depth[40:60, 12:30] - truth[40:60, 12:30]).max() < 0.02


def test_bad_arguments():
    depth = smooth_surface()
    with pytest.raises(UserError, match="--fill"):
        fill_depth(depth, None, "magic")
    with pytest.raises(UserError, match="--fill"):
        fill_depth(depth, np.zeros((10, 10, 3), np.uint8), "colorization")
    with pytest.raises(UserError, match="--fill"):
        fill_depth(depth.astype(np.uint16), None)
    with pytest.raises(UserError, match="--fill"):
        fill_depth(depth, None, max_hole_fraction=0.0)


def test_no_valid_depth_and_no_holes():
    empty = np.full((H, W), np.nan, np.float32)
    res = fill_depth(empty, None, "auto")
    assert np.isnan(res.depth).all() and not res.filled.any()
    full = smooth_surface()
    res = fill_depth(full, None, "auto")
    assert np.array_equal(res.depth, full) and res.stats["hole_fraction"] == 0.0


def test_inpaint_telea_runs_on_16_bit_codes():
    truth = smooth_surface()
    mask = blobs(4)
    depth = truth.copy()
    depth[mask] = np.nan
    for algorithm in ("ns", "telea"):
        out = fill_inpaint(depth, algorithm=algorithm)
        assert np.abs(out[mask] - truth[mask]).max() < 0.02


@pytest.mark.skipif(not (SHARED / "tum_office_frame_open3d").is_dir(), reason="../shared/rgbd_samples is absent")
def test_real_tum_frame():
    from rgbd2scene.capture.readers import read_depth, read_rgb

    folder = SHARED / "tum_office_frame_open3d"
    depth, _, _ = read_depth(folder / "TUM_depth.png", 5000)
    res = fill_depth(depth, read_rgb(folder / "TUM_color.png"), "auto")
    valid = np.isfinite(depth)
    assert np.array_equal(res.depth[valid], depth[valid])
    assert res.stats["filled_fraction"] == pytest.approx(res.stats["hole_fraction"] - res.stats[
        "left_unfilled_fraction"])
    assert res.stats["filled_fraction"] > 0.15  # 19 % holes, mostly filled
    lo, hi = np.nanmin(depth), np.nanmax(depth)
    filled = res.depth[res.filled]
    assert filled.min() >= 0.5 * lo and filled.max() <= 2.0 * hi
