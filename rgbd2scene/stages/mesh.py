"""The mesh stage (``rgbd2scene mesh``): write a reconstruction as a mesh folder (CONVENTIONS §4).

mesh.ply, depth_filled.npy, a textured OBJ (its ``mesh_texture.png`` is the capture image without specular
highlights; the image as captured is kept as ``texture_original.png`` when they were removed) and
overview.png, then ``scene.json`` last, so a folder with a scene.json is complete.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import CONVENTIONS_VERSION
from rgbd2scene.files.atomic import ensure_output_dir, write_json, write_npy
from rgbd2scene.files.images import write_image
from rgbd2scene.files.meshio import write_ply, write_textured_obj
from rgbd2scene.reconstruct.pipeline import Reconstruction
from rgbd2scene.reconstruct.texture import HighlightSettings
from rgbd2scene.versions import software_versions

#: The capture image as captured, next to the texture without highlights (``mesh_texture.png``).
TEXTURE_ORIGINAL = "texture_original.png"


def scene_record(recon: Reconstruction) -> dict:
    """The reconstruction part of scene.json: inputs, intrinsics, scale, settings, statistics, timings."""
    fill = recon.filled
    removed = recon.options.highlights == "remove"
    return {
        "conventions_version": CONVENTIONS_VERSION,
        "software": software_versions(),
        "capture": recon.capture.describe(),
        "options": recon.options.to_dict(),
        "fill": {"method": fill.method, "settings": fill.settings, "stats": fill.stats},
        "mesh": {"file": "mesh.ply", "textured": "mesh.obj", "stats": recon.stats["mesh"],
                 "max_relative_jump": recon.options.max_relative_jump,
                 "max_grazing_deg": recon.options.max_grazing_deg},
        "smooth": {"method": recon.options.smooth, "iterations": recon.options.smooth_iterations,
                   "stats": recon.stats["smooth"]},
        "texture": {"highlights": recon.options.highlights, "stats": recon.stats["texture"],
                    "settings": asdict(HighlightSettings()) if removed else None},
        "timings": recon.timings,
        "files": {"mesh": "mesh.ply", "depth_filled": "depth_filled.npy", "textured_mesh": "mesh.obj",
                  "texture": "mesh_texture.png", "overview": "overview.png",
                  **({"texture_original": TEXTURE_ORIGINAL} if removed else {})},
    }


def write_mesh_folder(out_dir: str | Path, recon: Reconstruction, finalize: bool = True) -> dict:
    """Write the mesh folder and return the scene.json record.

    ``scene.json`` goes last so that its presence means the folder is complete; with
    ``finalize=False`` the caller adds more (the Blender scene) and writes it itself.
    """
    out = ensure_output_dir(out_dir)
    (out / "scene.json").unlink(missing_ok=True)
    t0 = time.perf_counter()
    write_ply(out / "mesh.ply", recon.mesh)
    depth_filled = recon.filled.depth.astype(np.float32)
    write_npy(out / "depth_filled.npy", depth_filled)
    write_textured_obj(out, recon.mesh, name="mesh")
    if recon.options.highlights == "remove":
        write_image(out / TEXTURE_ORIGINAL, recon.capture.rgb)
    if recon.options.overview:
        from rgbd2scene.pictures.overview import render_mesh_image, write_overview

        K = recon.capture.intrinsics.K
        h, w = depth_filled.shape
        mesh_img = render_mesh_image(recon.mesh.vertices, recon.mesh.triangles, recon.mesh.vertex_colors, K, w, h)
        write_overview(out / "overview.png", recon.capture.rgb, recon.capture.depth, depth_filled, mesh_img,
                       title=Path(recon.capture.rgb_path).name)
    recon.timings["write_s"] = time.perf_counter() - t0
    record = scene_record(recon)
    if finalize:
        write_json(out / "scene.json", record)
    return record
