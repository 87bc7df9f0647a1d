"""Contact sheet of a capture and its reconstruction (OpenCV drawing only, no display needed).

``write_overview`` writes one PNG with labelled panels: the RGB image, the raw depth, the hole mask,
the filled depth (raw and filled share one turbo colour scale, shown by a labelled colour bar) and,
when given, a rendering of the mesh. ``render_mesh_image`` makes that rendering headlessly in numpy
(z-buffered vertex splats) from a viewpoint orbited a little away from the capture camera, shaded by
the surface normal and the vertex colours so the 3-D shape shows.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from rgbd2scene.conventions import rotate
from rgbd2scene.errors import UserError
from rgbd2scene.files.images import rgb_to_bgr, write_image
from rgbd2scene.geometry.mesh import vertex_normals

FONT = cv2.FONT_HERSHEY_SIMPLEX
BACKGROUND = (28, 28, 28)  # RGB
TEXT = (235, 235, 235)
MESH_LABEL = "mesh (rendered, rotated view)"


# --------------------------------------------------------------------------------------------------
# depth colouring


def depth_range(*depths: np.ndarray) -> tuple[float, float]:
    """A robust shared (min, max) of several depth maps (1st-99th percentile of the finite values)."""
    vals = [d[np.isfinite(d)] for d in depths if d is not None]
    vals = np.concatenate([v.ravel() for v in vals]) if vals else np.zeros(0)
    if vals.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(vals, [1.0, 99.0])
    if not hi > lo:
        lo, hi = float(vals.min()), float(vals.max())
    if not hi > lo:
        pad = max(abs(lo) * 0.01, 1e-3)
        lo, hi = lo - pad, hi + pad
    return float(lo), float(hi)


def colorize_depth(depth: np.ndarray, vmin: float, vmax: float, invalid=(0, 0, 0)) -> np.ndarray:
    """Turbo-coloured RGB uint8 image of a depth map (near = blue, far = red); NaN gets ``invalid``."""
    d = np.asarray(depth, dtype=np.float64)
    finite = np.isfinite(d)
    t = np.clip((np.where(finite, d, vmin) - vmin) / (vmax - vmin), 0.0, 1.0)
    bgr = cv2.applyColorMap(np.round(t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    rgb = rgb_to_bgr(bgr)
    rgb[~finite] = invalid
    return rgb


def _nice_ticks(lo: float, hi: float, n: int = 6) -> np.ndarray:
    span = hi - lo
    raw = span / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = min((s * mag for s in (1, 2, 2.5, 5, 10) if s * mag >= raw), default=10 * mag)
    first = math.ceil(lo / step) * step
    ticks = np.arange(first, hi + step * 1e-6, step)
    return ticks[(ticks >= lo - 1e-12) & (ticks <= hi + 1e-12)]


def _depth_unit(vmax: float) -> tuple[str, float]:
    """Millimetres for close-range scenes (up to 2 m), metres beyond."""
    return ("mm", 1000.0) if vmax <= 2.0 else ("m", 1.0)


def colour_bar(height: int, vmin: float, vmax: float, width: int = 110) -> np.ndarray:
    """A vertical turbo colour bar (near at the top) with tick labels in mm or m, RGB uint8."""
    unit, factor = _depth_unit(vmax)
    img = np.full((height, width, 3), BACKGROUND, np.uint8)
    top, bottom = 40, height - 20
    bar_x0, bar_x1 = 12, 36
    t = np.linspace(0.0, 1.0, max(bottom - top, 2))
    col = cv2.applyColorMap(np.round(t * 255).astype(np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    img[top:bottom, bar_x0:bar_x1] = col[:, None, :]
    cv2.rectangle(img, (bar_x0 - 1, top - 1), (bar_x1, bottom), (200, 200, 200), 1)
    put_text(img, f"depth [{unit}]", (6, 22), 0.45)
    lo, hi = vmin * factor, vmax * factor
    for tick in _nice_ticks(lo, hi):
        y = int(round(top + (tick - lo) / (hi - lo) * (bottom - top - 1)))
        cv2.line(img, (bar_x1, y), (bar_x1 + 6, y), (220, 220, 220), 1)
        label = f"{tick:.0f}" if unit == "mm" and abs(tick) >= 10 else f"{tick:.3g}"
        put_text(img, label, (bar_x1 + 9, y + 5), 0.42)
    return img


# --------------------------------------------------------------------------------------------------
# drawing helpers


def put_text(img, text, org, scale=0.55, color=TEXT, thickness=1):
    cv2.putText(img, text, org, FONT, scale, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, color, thickness, cv2.LINE_AA)


def label_panel(panel: np.ndarray, text: str) -> np.ndarray:
    """Draw ``text`` on a dark band at the panel's top-left corner."""
    (tw, th), base = cv2.getTextSize(text, FONT, 0.55, 1)
    band = panel[: th + base + 10, : tw + 14]
    band[:] = (band * 0.35).astype(np.uint8)
    put_text(panel, text, (7, th + 6), 0.55)
    return panel


def _as_rgb_u8(img: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise UserError(f"overview: {what} must be an (H, W, 3) image, got shape {a.shape}")
    a = a[..., :3]
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a)
    if a.dtype == np.uint16:
        return (a >> 8).astype(np.uint8)
    a = np.nan_to_num(a.astype(np.float64))
    if a.max(initial=0.0) > 1.0:
        a = a / 255.0
    return np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)


def fit_cell(img: np.ndarray, w: int, h: int, interp=cv2.INTER_AREA) -> np.ndarray:
    """Scale ``img`` to fit a w x h cell, centred on the background colour."""
    ih, iw = img.shape[:2]
    s = min(w / iw, h / ih)
    nw, nh = max(1, int(round(iw * s))), max(1, int(round(ih * s)))
    small = cv2.resize(img, (nw, nh), interpolation=interp if s < 1 else cv2.INTER_NEAREST)
    cell = np.full((h, w, 3), BACKGROUND, np.uint8)
    y0, x0 = (h - nh) // 2, (w - nw) // 2
    cell[y0:y0 + nh, x0:x0 + nw] = small
    return cell


# --------------------------------------------------------------------------------------------------

TITLE_H, GAP, BAR_W = 40, 6, 110


def overview_layout(n_panels: int, width: int, height: int, panel_width: int = 480):
    """Sheet size and panel boxes of a contact sheet of ``n_panels`` images of ``width x height``.

    Returns ``(sheet_w, sheet_h, boxes)`` with one ``(x, y, w, h)`` per panel cell (row-major; two
    columns for up to four panels, three for more) plus the spare cell, if any, last.
    """
    pw = int(panel_width)
    ph = int(round(pw * height / width))
    ncols = 3 if n_panels > 4 else 2
    nrows = math.ceil(n_panels / ncols)
    boxes = []
    for i in range(nrows * ncols):
        r, c = divmod(i, ncols)
        boxes.append((GAP + c * (pw + GAP), TITLE_H + GAP + r * (ph + GAP), pw, ph))
    sheet_w = ncols * pw + (ncols + 1) * GAP + BAR_W
    sheet_h = TITLE_H + nrows * ph + (nrows + 1) * GAP
    return sheet_w, sheet_h, boxes


def make_overview(
    rgb: np.ndarray,
    raw_depth: np.ndarray,
    filled_depth: np.ndarray,
    mesh_image: np.ndarray | None = None,
    title: str | None = None,
    panel_width: int = 480,
) -> np.ndarray:
    """The contact sheet as an RGB uint8 array (see ``write_overview``)."""
    sheet, mesh_cell = overview_sheet(rgb, raw_depth, filled_depth, mesh_image is not None, title, panel_width)
    if mesh_image is not None:
        put_mesh_panel(sheet, mesh_cell, mesh_image)
    return sheet


def put_mesh_panel(sheet: np.ndarray, cell: tuple[int, int, int, int], mesh_image: np.ndarray) -> None:
    """Draw the mesh rendering into its ``cell`` ``(x, y, w, h)`` of a sheet from :func:`overview_sheet`."""
    x, y, pw, ph = cell
    sheet[y:y + ph, x:x + pw] = label_panel(fit_cell(_as_rgb_u8(mesh_image, "mesh_image"), pw, ph), MESH_LABEL)


def overview_sheet(
    rgb: np.ndarray,
    raw_depth: np.ndarray,
    filled_depth: np.ndarray,
    mesh_panel: bool,
    title: str | None = None,
    panel_width: int = 480,
) -> tuple[np.ndarray, tuple[int, int, int, int] | None]:
    """The contact sheet without the mesh rendering, and the cell ``(x, y, w, h)`` left for it (None
    without ``mesh_panel``): the mesh stage draws the rest while the mesh is still being built and smoothed.
    No other drawing overlaps that cell, so :func:`put_mesh_panel` completes the same picture."""
    rgb = _as_rgb_u8(rgb, "rgb")
    raw = np.asarray(raw_depth, dtype=np.float32)
    filled = np.asarray(filled_depth, dtype=np.float32)
    if raw.ndim != 2 or filled.ndim != 2:
        raise UserError(f"overview: depth maps must be 2-D, got {raw.shape} and {filled.shape}")
    h, w = raw.shape
    if filled.shape != raw.shape:
        raise UserError(f"overview: filled depth is {filled.shape[1]}x{filled.shape[0]} "
                        f"but raw depth is {w}x{h}")
    vmin, vmax = depth_range(raw, filled)
    unit, factor = _depth_unit(vmax)

    holes = ~np.isfinite(raw)
    hole_pct = 100.0 * float(holes.mean())
    grey = cv2.cvtColor(cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
    mask_img = np.repeat((grey.astype(np.float32) * 0.4).astype(np.uint8)[..., None], 3, axis=2)
    mask_img[holes] = (255, 225, 0)

    still_nan = int((~np.isfinite(filled)).sum())
    filled_label = "filled depth" + (f" ({still_nan} px still NaN)" if still_nan else "")
    panels = [
        (rgb, f"RGB {rgb.shape[1]}x{rgb.shape[0]}"),
        (colorize_depth(raw, vmin, vmax), "raw depth (holes black)"),
        (mask_img, f"hole mask: {hole_pct:.1f} % missing"),
        (colorize_depth(filled, vmin, vmax), filled_label),
    ]
    n_panels = len(panels) + bool(mesh_panel)
    width, height, boxes = overview_layout(n_panels, w, h, panel_width)
    pw, ph = boxes[0][2], boxes[0][3]
    sheet = np.full((height, width, 3), BACKGROUND, np.uint8)
    for (img, label), (x, y, _, _) in zip(panels, boxes, strict=False):
        sheet[y:y + ph, x:x + pw] = label_panel(fit_cell(img, pw, ph), label)
    bar_h = boxes[-1][1] + ph - boxes[0][1]
    bar = colour_bar(bar_h, vmin, vmax, BAR_W)
    if n_panels < len(boxes):  # spare cell: the numbers behind the pictures
        x, y = boxes[n_panels][:2]
        finite = filled[np.isfinite(filled)]
        lines = [f"size {w} x {h} px", f"holes {holes.sum()} px ({hole_pct:.2f} %)",
                 f"colour scale {vmin * factor:.4g} - {vmax * factor:.4g} {unit}"]
        if finite.size:
            lines.append(f"filled depth {finite.min() * factor:.4g} - {finite.max() * factor:.4g} {unit}")
        for k, line in enumerate(lines):
            put_text(sheet, line, (x + 14, y + 34 + 28 * k), 0.55)
    sheet[boxes[0][1]:boxes[0][1] + bar_h, width - BAR_W:] = bar
    put_text(sheet, title or "rgbd2scene overview", (GAP + 4, 28), 0.75, thickness=2)
    return sheet, boxes[len(panels)] if mesh_panel else None


def write_overview(
    path: str | Path,
    rgb: np.ndarray,
    raw_depth: np.ndarray,
    filled_depth: np.ndarray,
    mesh_image: np.ndarray | None = None,
    title: str | None = None,
    panel_width: int = 480,
) -> Path:
    """Write a PNG contact sheet: RGB, raw depth, hole mask, filled depth and (optionally) the mesh.

    Parameters
    ----------
    path : output PNG (written atomically).
    rgb : (H, W, 3) uint8 RGB image (floats in [0, 1] are accepted).
    raw_depth, filled_depth : (H, W) float depth in metres, NaN = hole. Both use one turbo colour
        scale (robust 1-99 % range of their values), shown by a colour bar in mm (or m beyond 2 m).
    mesh_image : optional RGB rendering of the mesh, e.g. from ``render_mesh_image``.
    title : heading line.
    panel_width : width of each panel in pixels.

    Returns the path written.
    """
    return write_sheet(path, make_overview(rgb, raw_depth, filled_depth, mesh_image, title, panel_width))


def write_sheet(path: str | Path, sheet: np.ndarray) -> Path:
    """Write an overview sheet (:func:`make_overview`) as a PNG, atomically; returns the path."""
    path = Path(path)
    try:
        write_image(path, sheet, rle=True)  # flat panels and background: smaller and faster run-length only
    except OSError as exc:
        raise UserError(f"{path}: cannot write the overview image ({exc.strerror or exc})") from None
    return path


# --------------------------------------------------------------------------------------------------
# headless mesh rendering


def _rotation(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def render_mesh_image(
    mesh_vertices: np.ndarray,
    triangles: np.ndarray,
    vertex_colors: np.ndarray | None,
    K: np.ndarray,
    width: int,
    height: int,
    yaw_deg: float = 15.0,
    pitch_deg: float = -15.0,
    distance_scale: float = 1.2,
) -> np.ndarray:
    """Render a mesh headlessly (no display, no OpenGL) to an RGB uint8 image of ``height x width``.

    The mesh is in the capture camera's OpenCV frame (metres). The virtual camera uses the
    intrinsics ``K`` and orbits the mesh's centre by ``yaw_deg`` about the camera y axis and
    ``pitch_deg`` about its x axis, so relief shows, and backs off to ``distance_scale`` times the
    capture camera's distance so the whole surface fits. Each vertex is drawn as a square splat, z-buffered,
    about one and a half projected triangle edges wide (the median edge: a capture's grid mesh is about one
    vertex per pixel), shaded by its colour times (ambient + diffuse) from a light above-left of the virtual
    camera with its area-weighted normal; the background is dark grey. A preview picture, not ground truth:
    splats need no ray caster, whose import (Open3D, about 1 s) would be a third of a ``mesh`` command.
    """
    v = np.asarray(mesh_vertices, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    bg = np.empty((height, width, 3), np.uint8)
    bg[:] = np.linspace(46, 22, height, dtype=np.uint8)[:, None, None]
    if len(v) == 0 or len(t) == 0:
        return bg
    good = np.isfinite(v).all(axis=1)
    if not good.all():  # (a mesh stage's mesh is finite: no (M, 3) gather and reduction for it)
        t = t[good[t].all(axis=1)]
    if len(t) == 0:
        return bg
    v = np.nan_to_num(v)
    if vertex_colors is None:
        colors = np.full((len(v), 3), 0.75)
    else:
        colors = np.asarray(vertex_colors, dtype=np.float64).reshape(-1, 3)
        if colors.max(initial=0.0) > 1.0:
            colors = colors / 255.0
    used = np.zeros(len(v), bool)
    used[t.ravel()] = True
    centre = np.median(v[used], axis=0)
    R = _rotation("y", yaw_deg) @ _rotation("x", pitch_deg)  # virtual camera axes in capture frame
    eye = centre - distance_scale * (R @ centre)
    cam = rotate(R.T, v - eye)
    K = np.asarray(K, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2]
        w = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
    visible = used & (cam[:, 2] > 0) & np.isfinite(u) & np.isfinite(w)
    if not visible.any():
        return bg
    sample = t[:: max(1, len(t) // 20000)]
    edge = np.hypot(u[sample[:, 1]] - u[sample[:, 0]], w[sample[:, 1]] - w[sample[:, 0]])
    size = int(np.clip(np.ceil(1.5 * np.nanmedian(edge)), 1, 8))

    normals = vertex_normals(v, t)
    view = v - eye
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    normals[np.sum(normals * view, axis=1) > 0] *= -1.0  # face the viewer
    light = R @ np.array([-0.45, -0.6, -0.66])  # towards a light above-left of the viewer
    light /= np.linalg.norm(light)
    shade = 0.18 + 0.62 * np.clip(normals @ light, 0.0, None) + 0.25 * np.clip(-(normals * view).sum(axis=1), 0.0, None)
    shaded = np.round(np.clip(colors * shade[:, None], 0, 1) * 255).astype(np.uint8)

    index = np.flatnonzero(visible)
    u0 = np.floor(u[index] - (size - 1) / 2 + 0.5).astype(np.int64)
    w0 = np.floor(w[index] - (size - 1) / 2 + 0.5).astype(np.int64)
    pixels, depths, sources = [], [], []
    for dy in range(size):
        for dx in range(size):
            uu, ww = u0 + dx, w0 + dy
            inside = (uu >= 0) & (uu < width) & (ww >= 0) & (ww < height)
            pixels.append((ww * width + uu)[inside])
            depths.append(cam[index[inside], 2])
            sources.append(index[inside])
    pixel, source, depth = np.concatenate(pixels), np.concatenate(sources), np.concatenate(depths)
    # z-buffer: per pixel the splat of least depth, ties to the first splat: the least depth per pixel, then the
    # first splat at that depth (two unbuffered minimums, a tenth of the time of a stable sort of the depths)
    nearest_depth = np.full(height * width, np.inf)
    np.minimum.at(nearest_depth, pixel, depth)
    front = np.flatnonzero(depth == nearest_depth[pixel])
    first = np.full(height * width, len(depth), np.int64)
    np.minimum.at(first, pixel[front], front)
    hit = np.flatnonzero(first < len(depth))
    out = bg.reshape(-1, 3).copy()
    out[hit] = shaded[source[first[hit]]]
    return out.reshape(height, width, 3)
