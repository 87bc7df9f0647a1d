"""Mesh files: binary PLY round trip through Open3D, textured OBJ that Open3D loads with its texture."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from rgbd2scene.errors import UserError
from rgbd2scene.files.meshio import _fixed, _write_digits, obj_text, read_ply, write_ply, write_textured_obj
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.reconstruct.mesh import grid_mesh

H, W = 20, 28
K = np.array([[40.0, 0.0, (W - 1) / 2.0], [0.0, 40.0, (H - 1) / 2.0], [0.0, 0.0, 1.0]])


@pytest.fixture
def mesh() -> Mesh:
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:H, 0:W]
    depth = (0.05 + 0.01 * np.sin(u / 5.0) + 0.002 * v / H).astype(np.float32)
    depth[6:9, 10:15] = np.nan
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return grid_mesh(depth, K, rgb)[0]


def _ply_header(path):
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode(), len(data) - end


def test_ply_round_trip_exact(tmp_path, mesh):
    path = write_ply(tmp_path / "mesh.ply", mesh)
    header, body = _ply_header(path)
    assert "format binary_little_endian 1.0" in header
    for prop in ("float x", "uchar red", "uchar green", "uchar blue", "float s", "float t",
                 "list uchar int vertex_indices"):
        assert f"property {prop}" in header
    assert body == mesh.n_vertices * (12 + 3 + 8) + mesh.n_triangles * 13
    back = read_ply(path)
    assert np.array_equal(back.vertices, mesh.vertices.astype(np.float32).astype(np.float64))
    assert np.array_equal(back.triangles, mesh.triangles)
    assert np.array_equal(back.vertex_colors, mesh.vertex_colors)
    assert np.array_equal(back.uvs, mesh.uvs)
    assert back.pixels is None and back.texture is None
    # Open3D's own reader agrees.
    o = o3d.io.read_triangle_mesh(str(path))
    assert np.array_equal(np.asarray(o.triangles), mesh.triangles)
    assert np.array_equal(np.rint(np.asarray(o.vertex_colors) * 255).astype(np.uint8), mesh.vertex_colors)
    # float64 on request: bit-exact vertices.
    write_ply(tmp_path / "mesh64.ply", mesh, double=True)
    assert np.array_equal(read_ply(tmp_path / "mesh64.ply").vertices, mesh.vertices)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.ply", "mesh64.ply"]  # no temporary left


def test_ply_without_colours_or_uvs(tmp_path, mesh):
    bare = Mesh(mesh.vertices, mesh.triangles)
    write_ply(tmp_path / "bare.ply", bare)
    header, body = _ply_header(tmp_path / "bare.ply")
    assert "red" not in header and "property float s" not in header
    assert body == mesh.n_vertices * 12 + mesh.n_triangles * 13
    back = read_ply(tmp_path / "bare.ply")
    assert back.vertex_colors is None and back.uvs is None
    assert np.array_equal(back.triangles, mesh.triangles)


def test_read_ply_missing_file(tmp_path):
    with pytest.raises(UserError, match="not found"):
        read_ply(tmp_path / "nope.ply")


def test_obj_loads_with_texture(tmp_path, mesh):
    paths = write_textured_obj(tmp_path / "out", mesh)
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["mesh.mtl", "mesh.obj", "mesh_texture.png"]
    assert paths["obj"].name == "mesh.obj"
    assert "map_Kd mesh_texture.png" in paths["mtl"].read_text()
    o = o3d.io.read_triangle_mesh(str(paths["obj"]), True)
    assert o.has_textures() and o.has_triangle_uvs()
    tex = np.asarray(o.textures[0])
    assert np.array_equal(tex, mesh.texture[::-1])  # Open3D keeps OBJ textures bottom row first
    V, T = np.asarray(o.vertices), np.asarray(o.triangles)
    assert len(T) == mesh.n_triangles
    np.testing.assert_allclose(V[T], mesh.vertices[mesh.triangles], atol=1e-7)
    tri_uv = np.asarray(o.triangle_uvs).reshape(-1, 3, 2)
    np.testing.assert_allclose(tri_uv, mesh.uvs[mesh.triangles], atol=1e-6)
    # The texel under each corner's UV (in Open3D's bottom-up image) is that vertex's colour.
    u, v = tri_uv[..., 0], tri_uv[..., 1]
    texel = tex[np.rint(v * H - 0.5).astype(int), np.rint(u * W - 0.5).astype(int)]
    assert np.array_equal(texel, mesh.vertex_colors[mesh.triangles])
    # Mesh.to_open3d(with_texture=True) follows the same convention.
    m3 = mesh.to_open3d(with_texture=True)
    assert np.array_equal(np.asarray(m3.textures[0]), tex)
    np.testing.assert_allclose(np.asarray(m3.triangle_uvs).reshape(-1, 3, 2), tri_uv, atol=1e-6)


def test_obj_text_is_exact_and_parseable(mesh):
    m = mesh.copy()
    m.vertices[0] = [-0.5, 0.0, -3e-9]  # negative, zero and rounding-to-zero values
    m.vertices[1] = [12.25, -0.000001, 7.0]
    text = obj_text(m, mtl_name="x.mtl").decode()
    lines = text.splitlines()
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    vt = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("vt ")])
    f = [ln.split()[1:] for ln in lines if ln.startswith("f ")]
    np.testing.assert_allclose(v, m.vertices, atol=5.1e-9, rtol=0)
    np.testing.assert_allclose(vt, m.uvs, atol=6e-8, rtol=0)
    assert lines[lines.index("mtllib x.mtl")] and "v -0.50000000 0.00000000 0.00000000" in lines
    idx = np.array([[int(c.split("/")[0]) for c in row] for row in f]) - 1
    idx_t = np.array([[int(c.split("/")[1]) for c in row] for row in f]) - 1
    assert np.array_equal(idx, m.triangles) and np.array_equal(idx_t, m.triangles)
    assert "\0" not in text and "  " not in text
    bare = obj_text(Mesh(m.vertices, m.triangles)).decode()
    assert "vt " not in bare and "/" not in bare.split("\nf ", 1)[1]


def test_obj_unwritable_folder(tmp_path, mesh):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(UserError):
        write_textured_obj(blocker / "sub", mesh)


def test_digit_text_matches_python_formatting():
    """The OBJ's number text, four digits per division: right-aligned digits with NULs (or zeros) in front, and
    fixed-point numbers as Python's ``%.Nf`` writes them."""
    values = np.array([0, 7, 10, 99, 1000, 9999, 10000, 123456789, 10**12 + 34])
    for width in (1, 3, 4, 5, 9, 13):
        fits = values[values < 10**width]
        for zeros in (False, True):
            out = np.empty((len(fits), width), np.uint8)
            _write_digits(out, fits, leading_zeros=zeros)
            for value, row in zip(fits, out, strict=True):
                expected = f"{value:0{width}d}" if zeros else f"{value:{width}d}".replace(" ", "\0")
                assert row.tobytes().decode() == expected, (value, width, zeros)
    x = np.array([[0.0, -0.0, 1.5], [-12.345678912, 3e-9, -4e-9], [98765.4321, 0.1, -7.0]])
    for decimals in (0, 3, 8):
        rows = _fixed(x, decimals)
        for value, cell in zip(x.ravel(), rows.reshape(-1, rows.shape[-1]), strict=True):
            text = f"{abs(value):.{decimals}f}"
            sign = "-" if value < 0 and float(text) != 0 else ""
            assert cell.tobytes().replace(b"\0", b"").decode() == f" {sign}{text}", (value, decimals)
