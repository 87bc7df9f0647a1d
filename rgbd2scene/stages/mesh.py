"""The mesh stage (``rgbd2scene mesh``): write a reconstruction as a mesh folder (CONVENTIONS §4).

mesh.ply, depth_filled.npy, a textured OBJ (its ``mesh_texture.png`` is the capture image without specular
highlights; the image as captured is kept as ``texture_original.png`` when they were removed) and
overview.png, then ``scene.json`` last, so a folder with a scene.json is complete.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.capture.readers import Capture
from rgbd2scene.conventions import CONVENTIONS_VERSION, invert_pose, transform_points
from rgbd2scene.files.atomic import ensure_output_dir, write_bytes, write_json, write_npy
from rgbd2scene.files.images import encode_png
from rgbd2scene.files.meshio import write_ply, write_textured_obj
from rgbd2scene.reconstruct.fill import FillResult
from rgbd2scene.reconstruct.pipeline import MeshOptions, Reconstruction
from rgbd2scene.reconstruct.texture import HighlightSettings
from rgbd2scene.scene import folder
from rgbd2scene.stages.capture import LoadedCapture, reconstruct_inputs


def _removes_highlights(options: MeshOptions) -> bool:
    """Whether a single frame's texture is its image without its highlights (``texture_original.png`` keeps the
    image as captured)."""
    return options.highlights == "remove"


def _highlights_removed(recon: Reconstruction) -> bool:
    """:func:`_removes_highlights` for a finished reconstruction: a single frame's (fusion averages, no texture
    statistics)."""
    return _removes_highlights(recon.options) and "texture" in recon.stats


def scene_record(recon: Reconstruction) -> dict:
    """The reconstruction part of scene.json: inputs, intrinsics, scale, settings, statistics, timings."""
    from rgbd2scene.versions import software_versions

    fill = recon.filled
    textured = recon.mesh.texture is not None and recon.mesh.uvs is not None
    files = {"mesh": folder.MESH, "depth_filled": folder.DEPTH_FILLED, "textured_mesh": folder.TEXTURED_MESH,
             "texture": folder.TEXTURE, "overview": folder.OVERVIEW}
    if not textured:
        files.pop("texture")
    removed = _highlights_removed(recon)
    if removed:
        files["texture_original"] = folder.TEXTURE_ORIGINAL
    return {
        "conventions_version": CONVENTIONS_VERSION,
        "software": software_versions(),
        "capture": recon.capture.describe(),
        "options": recon.options.to_dict(),
        "fill": {"method": fill.method, "settings": fill.settings, "stats": fill.stats},
        "mesh": {"file": folder.MESH, "textured": folder.TEXTURED_MESH, "stats": recon.stats["mesh"],
                 "max_relative_jump": recon.options.max_relative_jump,
                 "max_grazing_deg": recon.options.max_grazing_deg},
        "smooth": {"method": recon.options.smooth, "iterations": recon.options.smooth_iterations,
                   "stats": recon.stats["smooth"]},
        "texture": {"highlights": recon.options.highlights if "texture" in recon.stats else "not applied (fused "
                    "frames: vertex colours averaged from the frames)", "stats": recon.stats.get("texture"),
                    "settings": asdict(HighlightSettings()) if removed else None},
        "timings": recon.timings,
        "files": files,
        **recon.sections,
    }


def _overview_image(recon: Reconstruction) -> np.ndarray:
    """The mesh seen from near the capture camera, in its frame (the overview's third panel)."""
    from rgbd2scene.pictures.overview import render_mesh_image

    vertices = recon.mesh.vertices
    if recon.capture.posed:
        vertices = transform_points(invert_pose(recon.capture.T_world_capture), vertices)
    h, w = recon.filled.depth.shape
    return render_mesh_image(vertices, recon.mesh.triangles, recon.mesh.vertex_colors, recon.capture.intrinsics.K,
                             w, h)


@dataclass
class _FilledFiles:
    """The folder's files that need only the capture and its filled depth, prepared but not yet written (a
    failed reconstruction writes nothing)."""

    depth: np.ndarray  # float32, depth_filled.npy
    texture_png: bytes | None  # the image as captured (texture_original.png), PNG bytes
    overview: tuple[np.ndarray, tuple[int, int, int, int]] | None  # the overview without the mesh, its cell


def _filled_files(capture: Capture, filled: FillResult, texture: bool, overview: bool) -> _FilledFiles:
    """:class:`_FilledFiles` of a capture and its fill: ``texture_original.png`` with ``texture`` (the texture
    is the image without its highlights), the overview's sheet with ``overview``."""
    from rgbd2scene.pictures.overview import overview_sheet

    depth = filled.depth.astype(np.float32)
    sheet = (overview_sheet(capture.rgb, capture.depth, depth, mesh_panel=True, title=Path(capture.rgb_path).name)
             if overview else None)
    return _FilledFiles(depth, encode_png(capture.rgb) if texture else None, sheet)


def reconstruct_mesh_folder(out_dir: str | Path, loaded: LoadedCapture, options: MeshOptions | None = None,
                            finalize: bool = True) -> tuple[Reconstruction, dict]:
    """Reconstruct a loaded capture into the mesh folder ``out_dir``; returns the reconstruction and the
    scene.json record (:func:`write_mesh_folder`).

    The files that need no mesh (``depth_filled.npy``, ``texture_original.png``, the overview but for its mesh
    panel: 0.1 s of CPU) and the software versions are prepared on other threads once the depth is filled,
    while the mesh is built and smoothed on one core (a single frame's reconstruction; fused frames have no
    fill, their files are all made at the end).
    """
    options = options or MeshOptions()
    out = ensure_output_dir(out_dir)
    with ThreadPoolExecutor(max_workers=2) as pool:
        prepared: list[Future] = []

        def on_filled(capture: Capture, filled: FillResult) -> None:
            prepared.append(pool.submit(_filled_files, capture, filled, _removes_highlights(options),
                                        options.overview))
            pool.submit(_look_up_versions)

        recon = reconstruct_inputs(loaded, options, on_filled=on_filled)
        return recon, _write_folder(out, recon, pool, prepared[0] if prepared else None, finalize)


def _look_up_versions() -> None:
    """The software versions of scene.json looked up ahead, off the main thread (importlib.metadata's import and
    the look-ups: 30 ms; :func:`rgbd2scene.versions.software_versions` keeps them)."""
    from rgbd2scene.versions import software_versions

    software_versions()


def write_mesh_folder(out_dir: str | Path, recon: Reconstruction, finalize: bool = True) -> dict:
    """Write the mesh folder and return the scene.json record.

    ``scene.json`` goes last so that its presence means the folder is complete; with
    ``finalize=False`` the caller adds more (the Blender scene) and writes it itself.
    """
    with ThreadPoolExecutor(max_workers=2) as pool:
        return _write_folder(ensure_output_dir(out_dir), recon, pool, None, finalize)


def _write_folder(out: Path, recon: Reconstruction, pool: ThreadPoolExecutor, prepared: Future | None,
                  finalize: bool) -> dict:
    """:func:`write_mesh_folder` on ``pool`` (two workers), with the :class:`_FilledFiles` made beforehand when
    ``prepared``."""
    from rgbd2scene.pictures.overview import put_mesh_panel, write_sheet

    (out / folder.SCENE_JSON).unlink(missing_ok=True)
    t0 = time.perf_counter()
    removed = _highlights_removed(recon)
    # the overview's splats and the OBJ text (numpy, mostly outside the GIL) run beside the other files
    image = pool.submit(_overview_image, recon) if recon.options.overview else None
    obj = pool.submit(write_textured_obj, out, recon.mesh, name=folder.MESH_NAME)
    write_ply(out / folder.MESH, recon.mesh)
    files = (prepared.result() if prepared is not None
             else _filled_files(recon.capture, recon.filled, removed, recon.options.overview))
    write_npy(out / folder.DEPTH_FILLED, files.depth)
    if removed:
        write_bytes(out / folder.TEXTURE_ORIGINAL, files.texture_png)
    if image is not None:
        sheet, cell = files.overview
        put_mesh_panel(sheet, cell, image.result())
        write_sheet(out / folder.OVERVIEW, sheet)
    obj.result()
    recon.timings["write_s"] = time.perf_counter() - t0
    record = scene_record(recon)
    if finalize:
        write_json(out / folder.SCENE_JSON, record)
    return record
