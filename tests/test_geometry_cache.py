"""The parts' meshes cached as arrays in the scene folder: used while the mesh file is the same, read again
once it is written again."""

from __future__ import annotations

import numpy as np

from rgbd2scene.files.meshio import write_ply
from rgbd2scene.groundtruth import geometry_cache
from rgbd2scene.groundtruth.geometry_cache import CACHE_DIR, mesh_arrays
from tests.conftest import flat_grid


def test_the_cache_is_used_until_the_mesh_is_written_again(tmp_path, monkeypatch):
    path = tmp_path / "mesh.ply"
    write_ply(path, flat_grid(0.05, 0.04, 11))
    vertices, triangles = mesh_arrays(path)
    assert vertices.dtype == np.float32 and triangles.dtype == np.int32
    np.testing.assert_array_equal(vertices, flat_grid(0.05, 0.04, 11).vertices.astype(np.float32))
    assert len(list((tmp_path / CACHE_DIR).glob("mesh.ply.*.npz"))) == 1

    reads = []
    real_read = geometry_cache.read_ply
    monkeypatch.setattr(geometry_cache, "read_ply", lambda p: reads.append(p) or real_read(p))
    cached_vertices, cached_triangles = mesh_arrays(path)
    assert reads == []  # from the cache
    np.testing.assert_array_equal(cached_vertices, vertices)
    np.testing.assert_array_equal(cached_triangles, triangles)

    write_ply(path, flat_grid(0.07, 0.04, 11))  # the scene changes
    changed, _ = mesh_arrays(path)
    assert reads == [path]
    np.testing.assert_allclose(changed[:, 2], 0.07, rtol=1e-6)
    assert len(list((tmp_path / CACHE_DIR).glob("mesh.ply.*.npz"))) == 1  # the stale one is gone
    mesh_arrays(path)
    assert reads == [path]


def test_an_unreadable_cache_file_is_read_again(tmp_path):
    path = tmp_path / "mesh.ply"
    write_ply(path, flat_grid(0.05, 0.04, 11))
    mesh_arrays(path)
    (cache,) = (tmp_path / CACHE_DIR).glob("mesh.ply.*.npz")
    cache.write_bytes(b"not an npz")
    vertices, _ = mesh_arrays(path)
    np.testing.assert_allclose(vertices[:, 2], 0.05, rtol=1e-6)
