"""Look at a mesh or a scene folder in Open3D's viewer, or render it headlessly to a PNG.

``preview(path)`` opens the legacy ``open3d.visualization.Visualizer`` on a PLY/OBJ/GLB mesh (vertex
colours, or the texture of a textured OBJ) or on a scene folder (``SCENE/mesh.obj`` when present,
else ``SCENE/mesh.ply``). With ``screenshot=...``, or when there is no display (neither ``DISPLAY``
nor ``WAYLAND_DISPLAY`` set), it renders offscreen instead (Open3D falls back to EGL) and writes
the image atomically.

The mesh is in the capture camera's OpenCV frame (x right, y down, z forward), so the view looks
from the capture camera's origin towards the mesh with image-up = -y: the picture is the right way
up and not mirrored, like the capture's RGB image.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.files import atomic
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene import folder

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".off", ".stl")
BACKGROUND = (0.12, 0.12, 0.13)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def resolve_mesh_path(path: str | Path) -> Path:
    """The mesh file behind a mesh path or a scene folder; ``UserError`` when there is none."""
    path = Path(path)
    if path.is_dir():
        for name in (folder.TEXTURED_MESH, folder.MESH):
            if (path / name).is_file():
                return path / name
        raise UserError(f"{path}: scene folder has no {folder.TEXTURED_MESH} or {folder.MESH}")
    if not path.exists():
        raise UserError(f"{path}: mesh file or scene folder not found")
    if not path.is_file():
        raise UserError(f"{path}: not a regular file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise UserError(f"{path}: not a mesh file (expected {', '.join(MESH_SUFFIXES)} or a scene folder)")
    return path


@contextlib.contextmanager
def _quiet_stderr():
    """Silence C-level stderr (GLFW/EGL/Mesa chatter such as 'error: XDG_RUNTIME_DIR ...'), keep it.

    Yields a list that holds the captured text once the block ends (for error messages).
    """
    captured: list[str] = []
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # pytest capture or an unusual stderr
        yield captured
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield captured
        finally:
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            captured.append(tmp.read().decode(errors="replace"))


def load_mesh(path: str | Path):
    """Read a triangle mesh with Open3D; bad or empty files raise ``UserError`` naming the file."""
    import open3d as o3d

    path = resolve_mesh_path(path)
    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    try:
        with _quiet_stderr():  # the PLY reader prints "RPly: Wrong magic number" etc. on bad files
            mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=True)
    except (RuntimeError, UnicodeDecodeError, ValueError) as exc:
        raise UserError(f"{path}: not a readable mesh ({exc})") from None
    finally:
        o3d.utility.set_verbosity_level(level)
    if not mesh.has_vertices():
        raise UserError(f"{path}: not a readable mesh, or a mesh without vertices")
    if not mesh.has_triangles():
        raise UserError(f"{path}: mesh has no triangles (a point cloud?)")
    v = np.asarray(mesh.vertices)
    if not np.isfinite(v).all():
        raise UserError(f"{path}: mesh has non-finite vertex coordinates")
    if not mesh.has_vertex_normals():
        mesh.compute_vertex_normals()
    return mesh


def _set_view(vis, mesh, fov_x_deg: float = 60.0, back_off: float = 0.15) -> None:
    """Look through the capture camera (the world frame: OpenCV axes, so the image is upright), backed
    off along -z by ``back_off`` of the median depth so the mesh's edges show."""
    import open3d as o3d

    ctr = vis.get_view_control()
    params = ctr.convert_to_pinhole_camera_parameters()
    intr = Intrinsics.from_fov(params.intrinsic.width, params.intrinsic.height, fov_x_deg)
    params.intrinsic = o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
    extrinsic = np.eye(4)  # world -> camera
    extrinsic[2, 3] = back_off * float(np.median(np.asarray(mesh.vertices)[:, 2]))
    params.extrinsic = extrinsic
    ctr.convert_from_pinhole_camera_parameters(params, allow_arbitrary=True)


def _configure(vis) -> None:
    opt = vis.get_render_option()
    if opt is None:
        return
    opt.background_color = np.asarray(BACKGROUND)
    opt.mesh_show_back_face = True
    opt.light_on = True


def render_screenshot(mesh, out_path: str | Path, width: int = 1024, height: int = 768) -> Path:
    """Render ``mesh`` offscreen (EGL when there is no display) and write the PNG atomically."""
    import open3d as o3d

    out_path = Path(out_path)
    if out_path.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise UserError(f"{out_path}: screenshot must be a .png (or .jpg) file")
    vis = o3d.visualization.Visualizer()
    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    try:
        with _quiet_stderr() as log:
            ok = vis.create_window(window_name="rgbd2scene preview", width=int(width), height=int(height),
                                   visible=False)
        if not ok:
            detail = " ".join("".join(log).split())[-300:]
            raise RuntimeError(f"could not open an offscreen OpenGL context (EGL) for the screenshot: "
                               f"{detail}")
        try:
            vis.add_geometry(mesh)
            _configure(vis)
            _set_view(vis, mesh)
            vis.poll_events()
            vis.update_renderer()
            try:
                with atomic.atomic_path(out_path) as tmp:
                    vis.capture_screen_image(str(tmp), do_render=True)
                    if not tmp.is_file() or tmp.stat().st_size == 0:
                        raise RuntimeError(f"{out_path}: Open3D wrote no screenshot")
                    _check_not_blank(tmp, out_path)
            except OSError as exc:
                raise UserError(f"{out_path}: cannot write the screenshot ({exc.strerror or exc})") from None
        finally:
            vis.destroy_window()
    finally:
        o3d.utility.set_verbosity_level(level)
    return out_path


def _check_not_blank(tmp: Path, out_path: Path) -> None:
    import cv2

    img = cv2.imread(str(tmp), cv2.IMREAD_COLOR)
    if img is None:
        raise RuntimeError(f"{out_path}: Open3D wrote an unreadable screenshot")
    if int(img.max()) == int(img.min()):
        raise RuntimeError(f"{out_path}: the offscreen rendering came out blank (uniform colour); "
                           "the OpenGL/EGL driver may not render in this environment")


def _interactive(mesh, title: str, width: int, height: int) -> None:
    import open3d as o3d

    vis = o3d.visualization.Visualizer()
    if not vis.create_window(window_name=title, width=int(width), height=int(height)):
        raise RuntimeError("could not open an Open3D window (is the display reachable?)")
    try:
        vis.add_geometry(mesh)
        _configure(vis)
        _set_view(vis, mesh)
        vis.run()
    finally:
        vis.destroy_window()


def default_screenshot_path(source: Path, mesh_path: Path) -> Path:
    """Where a display-less preview without ``screenshot`` goes: SCENE/preview.png or MESH_preview.png."""
    if source.is_dir():
        return source / "preview.png"
    return mesh_path.with_name(mesh_path.stem + "_preview.png")


def preview(mesh_or_scene_path: str | Path, screenshot: str | Path | None = None,
            width: int = 1024, height: int = 768) -> Path | None:
    """Show a mesh (PLY/OBJ/...) or a scene folder in Open3D's viewer, or render it to a PNG.

    Parameters
    ----------
    mesh_or_scene_path : mesh file, or a scene folder holding ``mesh.obj`` (preferred, textured)
        or ``mesh.ply`` (vertex colours).
    screenshot : PNG to render headlessly instead of opening a window. Without it and without a
        display, the image goes to ``SCENE/preview.png`` or ``MESH_preview.png`` beside the mesh.
    width, height : window or image size in pixels.

    Returns the screenshot path, or None after an interactive session.
    Raises ``UserError`` (one line, naming the file) for a missing, unreadable or empty mesh.
    """
    source = Path(mesh_or_scene_path)
    mesh_path = resolve_mesh_path(source)
    if not (16 <= int(width) <= 8192 and 16 <= int(height) <= 8192):
        raise UserError(f"preview: image size {width}x{height} out of range (16-8192)")
    mesh = load_mesh(mesh_path)
    if screenshot is None and has_display():
        _interactive(mesh, f"rgbd2scene preview: {mesh_path}", width, height)
        return None
    out = Path(screenshot) if screenshot is not None else default_screenshot_path(source, mesh_path)
    return render_screenshot(mesh, out, width, height)
