"""Overview contact sheet and the headless mesh rendering behind its mesh panel."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rgbd2scene.errors import UserError
from rgbd2scene.pictures.overview import (
    BACKGROUND,
    colorize_depth,
    depth_range,
    make_overview,
    overview_layout,
    overview_sheet,
    put_mesh_panel,
    render_mesh_image,
    write_overview,
)

H, W = 60, 80
K = np.array([[70.0, 0.0, (W - 1) / 2], [0.0, 70.0, (H - 1) / 2], [0.0, 0.0, 1.0]])


def bump_depth():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = ((u - W / 2) / (W / 3)) ** 2 + ((v - H / 2) / (H / 3)) ** 2
    return (0.08 - 0.02 * np.exp(-r2)).astype(np.float32)  # a 2 cm bulge 8 cm away


def grid_mesh(depth, rgb):
    """Organised grid mesh of a depth map (NOTES: (a,c,b),(b,c,d) faces the camera)."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = (u - K[0, 2]) * depth / K[0, 0], (v - K[1, 2]) * depth / K[1, 1]
    pts = np.stack([x, y, depth], -1).reshape(-1, 3)
    idx = np.arange(h * w).reshape(h, w)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return pts, tris, rgb.reshape(-1, 3)


@pytest.fixture
def capture():
    v, u = np.mgrid[0:H, 0:W]
    rgb = np.stack([150 + u, 60 + v, 70 + 0 * u], -1).astype(np.uint8)
    filled = bump_depth()
    raw = filled.copy()
    raw[20:30, 10:25] = np.nan  # a hole
    raw[:, :3] = np.nan  # border band
    return rgb, raw, filled


def _cells(sheet, n_panels):
    _, _, boxes = overview_layout(n_panels, W, H, 160)
    return [sheet[y:y + h, x:x + w] for x, y, w, h in boxes[:n_panels]]


def test_write_overview_with_mesh(tmp_path, capture):
    rgb, raw, filled = capture
    pts, tris, cols = grid_mesh(filled, rgb)
    mesh_img = render_mesh_image(pts, tris, cols, K, W, H)
    out = write_overview(tmp_path / "overview.png", rgb, raw, filled, mesh_img, title="test", panel_width=160)
    assert out == tmp_path / "overview.png"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["overview.png"]  # atomic: no temp file left
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    sheet_w, sheet_h, _ = overview_layout(5, W, H, 160)
    assert img.shape == (sheet_h, sheet_w, 3)
    sheet = img[..., ::-1]
    for cell in _cells(sheet, 5):  # every panel has content, not just the background colour
        assert cell.std() > 10
        assert np.mean(np.any(cell != BACKGROUND, axis=-1)) > 0.5
    # the written PNG is exactly the in-memory sheet
    assert np.array_equal(sheet, make_overview(rgb, raw, filled, mesh_img, "test", panel_width=160))


def test_write_overview_without_mesh(tmp_path, capture):
    rgb, raw, filled = capture
    out = write_overview(tmp_path / "sub" / "ov.png", rgb, raw, filled, panel_width=160)
    img = cv2.imread(str(out))
    sheet_w, sheet_h, boxes = overview_layout(4, W, H, 160)
    assert img.shape == (sheet_h, sheet_w, 3) and len(boxes) == 4
    for cell in _cells(img[..., ::-1], 4):
        assert cell.std() > 10


def test_the_mesh_panel_is_drawn_last_into_a_cell_nothing_else_touches(capture):
    """The mesh stage draws the sheet before the mesh exists and the mesh panel at the end: the same picture
    only if no other drawing (panels, spare-cell text, colour bar, title) reaches into the mesh's cell."""
    rgb, raw, filled = capture
    pts, tris, cols = grid_mesh(filled, rgb)
    mesh_img = render_mesh_image(pts, tris, cols, K, W, H)
    long_title = "a capture whose file name is long enough to cross the whole sheet_" * 4
    sheet, cell = overview_sheet(rgb, raw, filled, mesh_panel=True, title=long_title, panel_width=160)
    x, y, w, h = cell
    assert cell == overview_layout(5, W, H, 160)[2][4]  # the fifth panel's cell, left blank
    assert (sheet[y:y + h, x:x + w] == BACKGROUND).all()
    put_mesh_panel(sheet, cell, mesh_img)
    assert np.array_equal(sheet, make_overview(rgb, raw, filled, mesh_img, long_title, panel_width=160))
    assert overview_sheet(rgb, raw, filled, mesh_panel=False, panel_width=160)[1] is None


def test_raw_and_filled_share_one_colour_scale(capture):
    _, raw, filled = capture
    lo, hi = depth_range(raw, filled)
    a, b = colorize_depth(raw, lo, hi), colorize_depth(filled, lo, hi)
    valid = np.isfinite(raw)
    assert np.array_equal(a[valid], b[valid])  # same depth, same colour
    assert (a[~valid] == 0).all()  # holes are black
    near = np.unravel_index(np.argmin(filled), filled.shape)
    far = np.unravel_index(np.argmax(filled), filled.shape)
    assert b[near][2] > b[near][0] and b[far][0] > b[far][2]  # turbo: near blue, far red


def test_render_mesh_image_shows_shape():
    rgb = np.full((H, W, 3), 200, np.uint8)
    pts, tris, cols = grid_mesh(bump_depth(), rgb)
    img = render_mesh_image(pts, tris, cols, K, W, H)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    grey = img.mean(axis=2)
    lit = grey > 60
    assert lit.mean() > 0.4  # the surface fills much of the view
    assert grey[lit].std() > 5  # shading varies with the normal: the bulge is visible
    # float colours in [0, 1] and uint8 colours give the same picture
    img2 = render_mesh_image(pts, tris, cols / 255.0, K, W, H)
    assert np.abs(img.astype(int) - img2).max() <= 1


def test_render_mesh_image_z_buffer_nearest_splat_then_first():
    """Two surfaces over the same pixels: the nearer one is drawn; at equal depth the one listed first."""
    depth = np.full((H, W), 0.08, np.float32)
    pts, tris, _ = grid_mesh(depth, np.zeros((H, W, 3), np.uint8))
    near_pts, _, _ = grid_mesh(depth * 0.75, np.zeros((H, W, 3), np.uint8))
    red, green, blue = (np.array([[255, 0, 0]] * len(pts), np.uint8), np.array([[0, 255, 0]] * len(pts), np.uint8),
                        np.array([[0, 0, 255]] * len(pts), np.uint8))

    def dominant(vertices, colours):
        both_tris = np.concatenate([tris, tris + len(pts)])
        img = render_mesh_image(np.concatenate(vertices), both_tris, np.concatenate(colours), K, W, H)
        drawn = img[img.max(axis=2) > 60]
        assert len(drawn) > 0.3 * H * W
        return np.bincount(drawn.argmax(axis=1), minlength=3)

    assert dominant([pts, near_pts], [red, green]).argmax() == 1  # the nearer (green), though listed second
    counts = dominant([pts, pts], [red, blue])  # the same surface twice: the first listed (red) everywhere
    assert counts[0] > 0 and counts[1] == counts[2] == 0


def test_render_mesh_image_empty_mesh_is_background():
    img = render_mesh_image(np.zeros((0, 3)), np.zeros((0, 3), int), None, K, W, H)
    assert img.shape == (H, W, 3)


def test_bad_inputs_raise_user_error(tmp_path, capture):
    rgb, raw, filled = capture
    with pytest.raises(UserError):
        write_overview(tmp_path / "x.png", rgb, raw[None], filled)
    with pytest.raises(UserError):
        write_overview(tmp_path / "x.png", rgb, raw, filled[:10])
