"""The mesh stage (``rgbd2scene mesh``): write a reconstruction as a mesh folder (CONVENTIONS §4).

mesh.ply, depth_filled.npy, a textured OBJ (its ``mesh_texture.png`` is the capture image without specular
highlights; the image as captured is kept as ``texture_original.png`` when they were removed) and
overview.png, then ``scene.json`` last, so a folder with a scene.json is complete.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import CONVENTIONS_VERSION, invert_pose, transform_points
from rgbd2scene.files.atomic import ensure_output_dir, write_json, write_npy
from rgbd2scene.files.images import write_image
from rgbd2scene.files.meshio import write_ply, write_textured_obj
from rgbd2scene.reconstruct.pipeline import Reconstruction
from rgbd2scene.reconstruct.texture import HighlightSettings
from rgbd2scene.scene import folder
from rgbd2scene.versions import software_versions


def _highlights_removed(recon: Reconstruction) -> bool:
    """Whether the texture is the capture image without its highlights (a single frame; fusion averages)."""
    return recon.options.highlights == "remove" and "texture" in recon.stats


def scene_record(recon: Reconstruction) -> dict:
    """The reconstruction part of scene.json: inputs, intrinsics, scale, settings, statistics, timings."""
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


def write_mesh_folder(out_dir: str | Path, recon: Reconstruction, finalize: bool = True) -> dict:
    """Write the mesh folder and return the scene.json record.

    ``scene.json`` goes last so that its presence means the folder is complete; with
    ``finalize=False`` the caller adds more (the Blender scene) and writes it itself.
    """
    from rgbd2scene.pictures.overview import write_overview

    out = ensure_output_dir(out_dir)
    (out / folder.SCENE_JSON).unlink(missing_ok=True)
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=2) as pool:
        # the overview's splats and the OBJ text (numpy, mostly outside the GIL) run beside the other files
        image = pool.submit(_overview_image, recon) if recon.options.overview else None
        obj = pool.submit(write_textured_obj, out, recon.mesh, name=folder.MESH_NAME)
        write_ply(out / folder.MESH, recon.mesh)
        depth_filled = recon.filled.depth.astype(np.float32)
        write_npy(out / folder.DEPTH_FILLED, depth_filled)
        if _highlights_removed(recon):
            write_image(out / folder.TEXTURE_ORIGINAL, recon.capture.rgb)
        if image is not None:
            write_overview(out / folder.OVERVIEW, recon.capture.rgb, recon.capture.depth, depth_filled,
                           image.result(), title=Path(recon.capture.rgb_path).name)
        obj.result()
    recon.timings["write_s"] = time.perf_counter() - t0
    record = scene_record(recon)
    if finalize:
        write_json(out / folder.SCENE_JSON, record)
    return record
