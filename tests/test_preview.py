"""Headless preview screenshots (Open3D legacy visualizer, EGL without a display) and bad inputs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rgbd2scene.errors import UserError
from rgbd2scene.pictures.mesh_preview import preview

o3d = pytest.importorskip("open3d")

H, W = 30, 40
FX = 35.0


def write_grid_ply(path, quadrant_colours=True):
    """A 4x3 cm bulging grid mesh 8 cm in front of the camera, coloured by image quadrant:
    red where y < 0 (top of the image), blue where y > 0, plus green where x > 0 (right)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 0.08 - 0.01 * np.exp(-(((u - W / 2) / 10) ** 2 + ((v - H / 2) / 8) ** 2))
    x, y = (u - (W - 1) / 2) * z / FX, (v - (H - 1) / 2) * z / FX
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    idx = np.arange(H * W).reshape(H, W)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    cols = np.zeros_like(pts)
    cols[:, 0] = (pts[:, 1] < 0) * 0.9
    cols[:, 2] = (pts[:, 1] >= 0) * 0.9
    cols[:, 1] = (pts[:, 0] > 0) * 0.9
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(pts), o3d.utility.Vector3iVector(tris))
    mesh.vertex_colors = o3d.utility.Vector3dVector(cols)
    assert o3d.io.write_triangle_mesh(str(path), mesh)
    return path


def _shot(src, out, **kw):
    try:
        return preview(src, screenshot=out, **kw)
    except RuntimeError as exc:  # machine without any OpenGL/EGL driver
        if "offscreen OpenGL context" in str(exc):
            pytest.skip(f"no offscreen OpenGL here: {exc}")
        raise


def test_screenshot_written_not_blank_and_upright(tmp_path):
    mesh = write_grid_ply(tmp_path / "grid.ply")
    out = _shot(mesh, tmp_path / "shot.png", width=200, height=150)
    assert out == tmp_path / "shot.png"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.ply", "shot.png"]  # atomic, no temp left
    img = cv2.imread(str(out))[..., ::-1].astype(np.float64)
    assert img.shape == (150, 200, 3)
    assert img.std() > 10  # not uniform
    rows, cols = np.mgrid[0:150, 0:200]
    red = (img[..., 0] > img[..., 2] + 30) & (img[..., 0] > 60)
    blue = (img[..., 2] > img[..., 0] + 30) & (img[..., 2] > 60)
    green = img[..., 1] > 60
    assert red.sum() > 300 and blue.sum() > 300 and green.sum() > 300
    # OpenCV frame seen from the capture camera: y < 0 is up, x > 0 is right (not flipped, not mirrored)
    assert rows[red].mean() < rows[blue].mean()
    assert cols[green].mean() > cols[~green & (red | blue)].mean()


def test_scene_folder_without_display_goes_to_preview_png(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    scene = tmp_path / "scene"
    scene.mkdir()
    write_grid_ply(scene / "mesh.ply")
    out = _shot(scene, None, width=120, height=90)
    assert out == scene / "preview.png"
    assert cv2.imread(str(out)).std() > 10


def test_missing_file_raises_user_error(tmp_path):
    with pytest.raises(UserError, match="nothere.ply"):
        preview(tmp_path / "nothere.ply", screenshot=tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("name, content", [
    ("garbage.ply", b"this is not a ply file"),
    ("empty.obj", b""),
    ("points.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   b"property float z\nend_header\n0 0 1\n1 0 1\n0 1 1\n"),
    ("image.png", b"\x89PNG\r\n"),
])
def test_bad_mesh_raises_user_error(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(UserError, match=name):
        preview(path, screenshot=tmp_path / "x.png")


def test_scene_folder_without_mesh_raises_user_error(tmp_path):
    with pytest.raises(UserError, match="no mesh"):
        preview(tmp_path, screenshot=tmp_path / "x.png")
