"""De-lighting a scope capture's texture (``rgbd2scene.scene.delight``, ``scene --delight``)."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.scene.delight import MAX_GAIN, delight_texture, spot_mask
from rgbd2scene.scene.model import Light
from rgbd2scene.sensor.tone import srgb_decode, srgb_encode
from rgbd2scene.stages.scene import SceneOptions, delight_choice

W, H, F = 120, 90, 100.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])


def _tilted_plane() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth (H, W) of the plane n . X = d seen from the camera at the origin, its points and its unit normal."""
    n = np.array([0.35, -0.15, -1.0])
    n /= np.linalg.norm(n)  # facing the camera (n . z < 0), tilted about 21 degrees
    d = -0.03  # 3 cm from the camera along the normal: near, so 1/r^2 varies a lot over the view
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], axis=-1)
    z = d / (rays @ n)
    return z, rays * z[..., None], n


def _albedo_pattern() -> np.ndarray:
    """Linear albedo (H, W, 3): stripes and a gradient, 0.1-0.5 (no clipping after the level is restored)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    base = 0.3 + 0.12 * np.sin(u / 6.0) * np.cos(v / 9.0)
    return np.stack([base, 0.8 * base, 0.5 * base + 0.05 * u / W], axis=-1)


def test_delight_recovers_the_albedo_of_a_plane_lit_by_a_point_light_at_the_camera():
    z, points, normal = _tilted_plane()
    albedo = _albedo_pattern()
    # the capture: irradiance of a point light at the camera, cos(incidence) / r^2, computed here independently
    to_light = -points
    r2 = np.sum(to_light ** 2, axis=-1)
    cos_in = (to_light @ normal) / np.sqrt(r2)
    shading = cos_in / r2
    shading /= shading.max()
    lit = albedo * shading[..., None] * 1.6  # the capture exposure: bright near the camera, darker far away
    assert lit.max() <= 1.0
    texture = np.rint(srgb_encode(lit) * 255).astype(np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    light = Light(kind="point", offset=(0.0, 0.0, 0.0), outlets=1)
    out, stats = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    recovered = srgb_decode(out / 255.0)
    inner = (slice(2, H - 2), slice(2, W - 2))  # away from the border, whose normals see one side only
    ratio = recovered[inner] / albedo[inner]
    # recovered up to one level: the ratio is constant (8-bit quantisation on both ends: about 1 % at 0.03)
    spread = np.std(ratio) / np.mean(ratio)
    assert spread < 0.01, spread
    # the level: the median texel keeps its value
    gain = recovered / srgb_decode(texture / 255.0)
    assert np.median(gain) == pytest.approx(1.0, abs=0.01)
    assert stats["clamped_share"] < 0.005 and stats["clipped_share"] == 0  # one far corner reaches the clamp
    # the test can fail: without the cosine, or without the inverse square, the spread is far larger
    for wrong in (1.0 / r2, cos_in):
        wrong_ratio = (lit / wrong[..., None])[inner] / albedo[inner]
        assert np.std(wrong_ratio) / np.mean(wrong_ratio) > 5 * 0.01


def test_two_outlets_beside_the_lenses_are_summed():
    """The light of a stereo scope: two outlets, each with its own distance and incidence."""
    z, points, normal = _tilted_plane()
    albedo = _albedo_pattern()
    light = Light(kind="point", offset=(0.0025, 0.0, 0.0), outlets=2, outlet_spacing=0.008)
    shading = np.zeros((H, W))
    for offset in light.outlet_offsets():
        to_light = np.asarray(offset) - points
        r2 = np.sum(to_light ** 2, axis=-1)
        shading += np.maximum(to_light @ normal, 0) / np.sqrt(r2) / r2
    lit = albedo * (shading / shading.max())[..., None] * 1.6
    texture = np.rint(srgb_encode(lit) * 255).astype(np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    out, _ = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    ratio = (srgb_decode(out / 255.0) / albedo)[2:-2, 2:-2]
    assert np.std(ratio) / np.mean(ratio) < 0.01


def test_gain_is_clamped_where_the_light_barely_reaches():
    """A spot whose cone ends inside the view: beyond it the gain stops at MAX_GAIN, the texels stay finite."""
    z, points, _ = _tilted_plane()
    texture = np.full((H, W, 3), 120, np.uint8)
    mesh, _ = grid_mesh(z.astype(np.float32), K, texture, max_relative_jump=None)
    light = Light(kind="spot", spot_size_deg=40.0, offset=(0.0, 0.0, 0.0), outlets=1)
    out, stats = delight_texture(texture, mesh.vertices, mesh.triangles, mesh.uvs, light)
    linear = srgb_decode(out / 255.0)[..., 0]
    before = srgb_decode(120 / 255.0)
    assert stats["clamped_share"] > 0.2
    assert linear.max() == pytest.approx(MAX_GAIN * before, rel=0.02) and linear.min() > 0


def test_spot_mask_is_blenders_cone():
    half = np.radians(50.0)
    edge = np.cos(half)
    full = edge + (1 - edge) * 0.5  # blend 0.5: full strength from here to the axis
    np.testing.assert_allclose(spot_mask(np.array([1.0, full, edge, edge - 0.1]), 100.0), [1, 1, 0, 0])
    assert spot_mask(np.array([(edge + full) / 2]), 100.0)[0] == pytest.approx(0.5)


def test_auto_delights_scope_lit_captures_only():
    stereo = {"capture": {"stereo": {"calibration_values": {}}}}
    rgbd = {"capture": {"intrinsics": {}}}
    assert delight_choice(stereo, SceneOptions(), True)[0]
    assert not delight_choice(rgbd, SceneOptions(), True)[0]
    assert delight_choice(rgbd, SceneOptions(delight="on"), True)[0]
    assert not delight_choice(stereo, SceneOptions(delight="off"), True)[0]
    assert not delight_choice(stereo, SceneOptions(delight="on"), False)[0]
