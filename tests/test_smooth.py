"""Smoothing: along the viewing rays (texture stays registered), Taubin, Blender-corrective, none."""

from __future__ import annotations

import time

import numpy as np
import pytest

from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.reconstruct.smooth import boundary_vertices, mesh_edges, smooth_mesh

H, W = 40, 50
K = np.array([[50.0, 0.0, (W - 1) / 2.0], [0.0, 50.0, (H - 1) / 2.0], [0.0, 0.0, 1.0]])
Z0 = 0.5
SIGMA = 0.002  # 2 mm depth noise


def _noisy_plane(seed=0, hole=True):
    rng = np.random.default_rng(seed)
    depth = (Z0 + SIGMA * rng.standard_normal((H, W))).astype(np.float32)
    if hole:
        depth[12:18, 20:31] = np.nan
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return grid_mesh(depth, K, rgb)[0]


def _tilted_plane_depth(a=0.004, b=-0.006, c=2.0):
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return 1.0 / (a * (u - K[0, 2]) + b * (v - K[1, 2]) + c)


def _rms_z(mesh, z0=Z0):
    return float(np.sqrt(np.mean((mesh.vertices[:, 2] - z0) ** 2)))


def _off_ray(new, old):
    """Distance of each new vertex from the ray through the old one (camera at the origin)."""
    ray = old / np.linalg.norm(old, axis=1, keepdims=True)
    return np.linalg.norm(np.cross(new, ray), axis=1)


def test_ray_smoothing_stays_on_rays_and_reduces_noise():
    mesh = _noisy_plane()
    out, stats = smooth_mesh(mesh)  # default: ray
    assert stats["method"] == "ray"
    assert np.max(_off_ray(out.vertices, mesh.vertices)) < 1e-12
    assert stats["max_off_ray_mm"] < 1e-9
    # Registration is untouched: same pixels, UVs, colours, triangles; the vertex projects to its pixel.
    for name in ("pixels", "uvs", "vertex_colors", "triangles"):
        assert np.array_equal(getattr(out, name), getattr(mesh, name))
    u = K[0, 0] * out.vertices[:, 0] / out.vertices[:, 2] + K[0, 2]
    np.testing.assert_allclose(u, out.pixels % W, atol=1e-9)
    before, after = _rms_z(mesh), _rms_z(out)
    assert after < 0.4 * before
    assert stats["mean_displacement_mm"] > 0.5 and stats["seconds"] >= 0
    # More strength smooths more; the bilateral variant stays on the rays too.
    stronger, _ = smooth_mesh(mesh, "ray", strength=1.0, iterations=30)
    assert _rms_z(stronger) < after
    bil, _ = smooth_mesh(mesh, "ray", edge_sigma=0.02)
    assert np.max(_off_ray(bil.vertices, mesh.vertices)) < 1e-12 and _rms_z(bil) < 0.5 * before


def test_ray_smoothing_keeps_a_tilted_plane():
    depth = _tilted_plane_depth()
    mesh = grid_mesh(depth, K)[0]
    out, _ = smooth_mesh(mesh, "ray", iterations=20)
    rel = np.abs(out.vertices[:, 2] / mesh.vertices[:, 2] - 1.0)
    # 1/z is affine on a plane: the interior and straight borders stay; only the image corners drift
    # (the border turns there), and that spreads a few pixels.
    rows, cols = np.divmod(mesh.pixels, W)
    corner_dist = np.min([np.hypot(rows - r, cols - c) for r in (0, H - 1) for c in (0, W - 1)], axis=0)
    far = corner_dist >= 15
    assert rel[far].max() < 1e-8
    assert rel.max() < 0.01
    pinned, _ = smooth_mesh(mesh, "ray", iterations=20, pin_boundary=True)
    assert np.abs(pinned.vertices[:, 2] / mesh.vertices[:, 2] - 1.0).max() < 1e-12
    # Smoothing z itself bends the plane (kept as an option).
    out_z, _ = smooth_mesh(mesh, "ray", iterations=20, space="z")
    assert np.abs(out_z.vertices[:, 2] / mesh.vertices[:, 2] - 1.0)[far].max() > 1e-6


def test_ray_smoothing_does_not_cross_cut_edges():
    rng = np.random.default_rng(2)
    depth = np.where(np.arange(W) < W // 2, 0.5, 0.6) + SIGMA * rng.standard_normal((H, W))
    mesh, stats = grid_mesh(depth.astype(np.float32), K)
    assert stats["faces_dropped_jump"] > 0
    out, _ = smooth_mesh(mesh, "ray", strength=1.0, iterations=50)
    left = (mesh.pixels % W) < W // 2
    assert np.all(np.abs(out.vertices[left, 2] - 0.5) < 3 * SIGMA)
    assert np.all(np.abs(out.vertices[~left, 2] - 0.6) < 3 * SIGMA)


def test_taubin_moves_sideways_but_reduces_noise():
    mesh = _noisy_plane()
    out, stats = smooth_mesh(mesh, "taubin", iterations=10)
    assert _rms_z(out) < 0.5 * _rms_z(mesh)
    assert stats["max_off_ray_mm"] > 1e-3  # documented: vertices leave their rays
    assert np.max(_off_ray(out.vertices, mesh.vertices)) > 1e-6
    assert np.array_equal(out.uvs, mesh.uvs)


def test_corrective_reduces_noise():
    mesh = _noisy_plane()
    out, stats = smooth_mesh(mesh, "corrective")
    assert stats["iterations"] == 5 and stats["strength"] == 0.5
    assert _rms_z(out) < 0.6 * _rms_z(mesh)
    simple, _ = smooth_mesh(mesh, "corrective", smooth_type="simple")
    assert _rms_z(simple) < 0.6 * _rms_z(mesh)
    pinned, _ = smooth_mesh(mesh, "corrective", pin_boundary=True)
    b = boundary_vertices(mesh.triangles, mesh.n_vertices)
    assert b.sum() > 0
    assert np.array_equal(pinned.vertices[b], mesh.vertices[b])
    assert not np.array_equal(pinned.vertices[~b], mesh.vertices[~b])


def test_corrective_matches_blender_formula_on_one_vertex():
    # A fan: centre 0 with four neighbours; one length-weighted step by hand.
    from rgbd2scene.geometry.mesh import Mesh

    v = np.array([[0, 0, 1.0], [1, 0, 1.2], [0, 1, 1.0], [-2, 0, 1.0], [0, -1, 0.9]])
    t = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]], dtype=np.int32)
    mesh = Mesh(v, t)
    out, _ = smooth_mesh(mesh, "corrective", strength=0.5, iterations=1)
    e = v[1:] - v[0]
    length = np.linalg.norm(e, axis=1)
    expected = v[0] + 2 * 0.5 * (e * length[:, None]).sum(0) / (length.sum() * 4)
    np.testing.assert_allclose(out.vertices[0], expected, atol=1e-12)


def test_none_and_bad_method():
    mesh = _noisy_plane(hole=False)
    out, stats = smooth_mesh(mesh, "none")
    assert np.array_equal(out.vertices, mesh.vertices) and stats["max_displacement_mm"] == 0.0
    assert out.vertices is not mesh.vertices
    with pytest.raises(ValueError):
        smooth_mesh(mesh, "magic")
    with pytest.raises(ValueError):
        smooth_mesh(mesh, "ray", strength=1.5)


def test_edges_and_boundary():
    mesh = grid_mesh(np.ones((3, 4), np.float32), K[:, :])[0]
    lo, hi, count = mesh_edges(mesh.triangles, mesh.n_vertices)
    assert len(lo) == 9 + 8 + 6  # horizontal, vertical, diagonals
    assert np.all(lo < hi) and set(count.tolist()) == {1, 2}
    b = boundary_vertices(mesh.triangles, mesh.n_vertices)
    assert b.sum() == 10  # all but the two inner pixels of a 3x4 grid


def test_ray_smoothing_speed():
    # About 600k faces as a capture gives; the brief's target is well under 0.3 s.
    h, w = 480, 640
    Kb = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    depth = (1.0 + 0.003 * np.random.default_rng(0).standard_normal((h, w))).astype(np.float32)
    mesh = grid_mesh(depth, Kb)[0]
    assert mesh.n_triangles > 600_000
    t0 = time.perf_counter()
    _, stats = smooth_mesh(mesh, "ray")
    assert time.perf_counter() - t0 < 1.5  # about 0.1 s alone; margin for a shared 2-core machine
