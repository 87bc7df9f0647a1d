"""Grid mesh of a depth map: exact vertices, winding, discontinuity cuts, UVs, reindexing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from rgbd2scene.capture.camera import PRESETS
from rgbd2scene.conventions import project
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.reconstruct.mesh import grid_mesh

H, W = 24, 32
FX, FY = 30.0, 28.0
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0
K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])


def _rgb(h=H, w=W, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _rows_cols(mesh: Mesh, w=W):
    return np.divmod(mesh.pixels, w)


def _tilted_plane(h=H, w=W, K=K, a=0.002, b=-0.003, c=2.0):
    """Planar depth: 1/z is affine in the pixel coordinates."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return (1.0 / (a * (u - K[0, 2]) + b * (v - K[1, 2]) + c)).astype(np.float32)


def test_fronto_parallel_plane_exact_vertices():
    z = 0.5
    mesh, stats = grid_mesh(np.full((H, W), z, np.float32), K, _rgb())
    assert mesh.vertices.dtype == np.float64 and mesh.triangles.dtype == np.int32
    assert mesh.vertex_colors.dtype == np.uint8 and mesh.uvs.dtype == np.float32
    assert mesh.pixels.dtype == np.int64
    assert mesh.n_vertices == H * W
    assert mesh.n_triangles == 2 * (H - 1) * (W - 1) == stats["faces_kept"] == stats["faces_total_possible"]
    rows, cols = _rows_cols(mesh)
    expected = np.stack([(cols - CX) * z / FX, (rows - CY) * z / FY, np.full(len(rows), z)], axis=1)
    np.testing.assert_allclose(mesh.vertices, expected, rtol=0, atol=1e-15)
    # Vertex normals of a fronto-parallel plane face the camera: (0, 0, -1).
    for weighting in ("area", "angle"):
        np.testing.assert_allclose(mesh.vertex_normals(weighting), [[0, 0, -1]] * H * W, atol=1e-12)
    np.testing.assert_allclose(mesh.face_normals(), [[0, 0, -1]] * mesh.n_triangles, atol=1e-12)


def test_backprojection_round_trip():
    depth = _tilted_plane()
    mesh, _ = grid_mesh(depth, K, _rgb())
    u, v = project(mesh.vertices, K)
    rows, cols = _rows_cols(mesh)
    np.testing.assert_allclose(u, cols, atol=1e-9)
    np.testing.assert_allclose(v, rows, atol=1e-9)
    np.testing.assert_allclose(mesh.vertices[:, 2], depth.ravel()[mesh.pixels].astype(np.float64), rtol=1e-12)


def test_triangle_order_and_all_faces_face_the_camera():
    rng = np.random.default_rng(1)
    depth = (0.8 + 0.02 * rng.standard_normal((H, W))).astype(np.float32)
    depth[5:9, 10:14] = np.nan
    mesh, _ = grid_mesh(depth, K, _rgb(), max_relative_jump=None, max_grazing_deg=90.0)
    centroids = mesh.vertices[mesh.triangles].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals(), centroids) < 0)
    # The first quad gives (a, c, b) and (b, c, d) with a=(0,0), b=(0,1), c=(1,0), d=(1,1).
    plane, _ = grid_mesh(np.ones((2, 2), np.float32), K)
    assert plane.pixels[plane.triangles].tolist() == [[0, 2, 1], [1, 2, 3]]


def test_no_triangle_spans_a_step():
    depth = np.full((H, W), 0.5, np.float32)
    depth[:, W // 2:] = 0.6
    mesh, stats = grid_mesh(depth, K, _rgb())
    tz = mesh.vertices[:, 2][mesh.triangles]
    assert np.all((tz.max(axis=1) - tz.min(axis=1)) / tz.min(axis=1) <= 0.03)
    assert not np.any((tz.min(axis=1) < 0.55) & (tz.max(axis=1) > 0.55))
    assert stats["faces_dropped_jump"] == 2 * (H - 1)  # the column of quads across the step
    assert stats["faces_kept"] == stats["faces_total_possible"] - 2 * (H - 1)
    assert mesh.n_vertices == H * W  # both rims keep their triangles
    # With the test off the curtain is built.
    _, loose = grid_mesh(depth, K, _rgb(), max_relative_jump=0.5)
    assert loose["faces_dropped_jump"] == 0


def _plane_at_angle(alpha_deg, h=12, w=16, f=1000.0, dist=1.0):
    """Depth of a plane whose normal makes ``alpha_deg`` with the optical axis (tilted about y)."""
    Kp = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    a = np.radians(alpha_deg)
    u = np.arange(w) - Kp[0, 2]
    z = dist / (np.cos(a) * (1.0 - u * np.tan(a) / f))
    return np.tile(z, (h, 1)).astype(np.float64), Kp


def test_grazing_faces_dropped():
    depth, Kp = _plane_at_angle(88.0)
    _, stats = grid_mesh(depth, Kp, max_relative_jump=None, max_grazing_deg=85.0)
    assert stats["faces_kept"] == 0
    assert stats["faces_dropped_grazing"] == stats["faces_total_possible"]
    _, stats = grid_mesh(depth, Kp, max_relative_jump=None, max_grazing_deg=89.5)
    assert stats["faces_kept"] == stats["faces_total_possible"]
    depth, Kp = _plane_at_angle(80.0)
    mesh, stats = grid_mesh(depth, Kp, max_relative_jump=None, max_grazing_deg=85.0)
    assert stats["faces_dropped_grazing"] == 0
    angles = np.degrees(np.arccos(-mesh.face_normals() @ np.array([0, 0, 1.0])))
    np.testing.assert_allclose(angles, 80.0, atol=0.5)


def test_uvs_sample_the_vertex_pixel():
    rgb = _rgb(seed=3)
    depth = _tilted_plane()
    depth[3:6, 4:20] = np.nan
    mesh, _ = grid_mesh(depth, K, rgb)
    u, v = mesh.uvs[:, 0].astype(np.float64), mesh.uvs[:, 1].astype(np.float64)
    col = u * W - 0.5
    row = (1.0 - v) * H - 0.5
    np.testing.assert_allclose(col, np.rint(col), atol=1e-4)
    np.testing.assert_allclose(row, np.rint(row), atol=1e-4)
    rows, cols = _rows_cols(mesh)
    assert np.array_equal(np.rint(row).astype(int), rows) and np.array_equal(np.rint(col).astype(int), cols)
    looked_up = mesh.texture[np.rint(row).astype(int), np.rint(col).astype(int)]
    assert np.array_equal(looked_up, mesh.vertex_colors)
    assert np.array_equal(mesh.vertex_colors, rgb.reshape(-1, 3)[mesh.pixels])
    assert np.all(np.isfinite(depth.ravel()[mesh.pixels]))


def test_unreferenced_vertices_dropped():
    depth = np.full((H, W), 0.7, np.float32)
    depth[10:15, 10:15] = np.nan
    depth[12, 12] = 0.7  # an isolated valid pixel: no triangle can use it
    depth[0, :] = 2.0  # the top row: every triangle to it is a jump
    mesh, stats = grid_mesh(depth, K, _rgb())
    assert 12 * W + 12 not in set(mesh.pixels.tolist())
    assert not np.any(mesh.pixels < W)  # the top row is gone
    assert stats["vertices_valid"] == H * W - 25 + 1
    assert stats["vertices"] == mesh.n_vertices == H * W - 25 - W
    used = np.zeros(mesh.n_vertices, bool)
    used[mesh.triangles.ravel()] = True
    assert used.all()
    assert mesh.triangles.min() >= 0 and mesh.triangles.max() < mesh.n_vertices
    assert np.all(np.diff(mesh.pixels) > 0)


def test_alternate_diagonal_closes_three_corner_quads():
    depth = np.ones((2, 2), np.float32)
    depth[0, 1] = np.nan  # b missing: only (a, c, d) is possible
    mesh, stats = grid_mesh(depth, K)
    assert mesh.pixels[mesh.triangles].tolist() == [[0, 2, 3]]
    assert stats["faces_alternate_diagonal"] == 1
    depth = np.ones((2, 2), np.float32)
    depth[1, 0] = np.nan  # c missing: (a, d, b)
    mesh, _ = grid_mesh(depth, K)
    assert mesh.pixels[mesh.triangles].tolist() == [[0, 3, 1]]
    assert np.all(mesh.face_normals()[:, 2] < 0)
    mesh, stats = grid_mesh(depth, K, alternate_diagonal=False)
    assert mesh.n_triangles == 0 and mesh.n_vertices == 0


def test_stats_add_up_and_open3d_conversion():
    depth = _tilted_plane()
    depth[4:7, 3:9] = np.nan
    depth[15:, 20:] *= 1.2
    mesh, s = grid_mesh(depth, K, _rgb())
    assert s["faces_candidates"] - s["faces_dropped_jump"] - s["faces_dropped_grazing"] == s["faces_kept"]
    assert s["faces_total_possible"] == 2 * (H - 1) * (W - 1)
    o = mesh.to_open3d()
    assert len(o.vertices) == mesh.n_vertices and len(o.triangles) == mesh.n_triangles
    np.testing.assert_allclose(np.asarray(o.vertex_colors) * 255.0, mesh.vertex_colors, atol=1e-9)
    o = mesh.to_open3d(with_texture=True)
    assert o.has_textures() and len(o.triangle_uvs) == 3 * mesh.n_triangles


def test_bad_inputs():
    with pytest.raises(UserError):
        grid_mesh(np.ones((H, W), np.float32), K, _rgb(H + 1, W))
    with pytest.raises(UserError):
        grid_mesh(np.ones(5, np.float32), K)
    with pytest.raises(UserError):
        grid_mesh(np.ones((H, W), np.float32), np.eye(2))


def test_tum_frame(shared_samples):
    from rgbd2scene.capture.readers import read_depth, read_rgb

    folder = shared_samples / "tum_office_frame_open3d"
    depth, _, _ = read_depth(folder / "TUM_depth.png", 5000.0)
    rgb = read_rgb(folder / "TUM_color.png")
    t0 = time.perf_counter()
    mesh, stats = grid_mesh(depth, PRESETS["primesense"], rgb)
    seconds = time.perf_counter() - t0
    assert seconds < 2.0  # about 0.1 s here; generous for a busy machine
    assert stats["faces_kept"] > 400_000
    centroids = mesh.vertices[mesh.triangles].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals(), centroids) < 0)
    assert np.all(np.isfinite(mesh.vertices))
