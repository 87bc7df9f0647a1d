"""The reconstruction stage end to end: capture -> filled depth -> mesh -> smoothed mesh -> files.

``reconstruct`` is pure computation; ``write_mesh_folder`` writes the outputs of CONVENTIONS §4
(mesh.ply, depth_filled.npy, a textured OBJ, overview.png) and writes ``scene.json`` last, so a folder
with a scene.json is complete.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import ensure_output_dir, write_json, write_npy
from .capture import Capture
from .conventions import CONVENTIONS_VERSION
from .errors import UserError
from .fill import FillResult, fill_depth
from .mesh import Mesh, grid_mesh
from .meshio import write_ply, write_textured_obj
from .smooth import smooth_mesh
from .versions import software_versions


@dataclass
class MeshOptions:
    """Every setting of the reconstruction stage (recorded in scene.json)."""

    fill: str = "auto"
    max_relative_jump: float = 0.03
    max_grazing_deg: float = 85.0
    smooth: str = "ray"
    smooth_iterations: int = 10
    overview: bool = True

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Reconstruction:
    capture: Capture
    options: MeshOptions
    filled: FillResult
    mesh: Mesh
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def reconstruct(capture: Capture, options: MeshOptions | None = None) -> Reconstruction:
    """Fill holes, back-project into a grid mesh without curtains, and smooth along the viewing rays."""
    options = options or MeshOptions()
    timings = {}
    t0 = time.perf_counter()
    filled = fill_depth(capture.depth, capture.rgb, method=options.fill)
    timings["fill_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mesh, mesh_stats = grid_mesh(filled.depth, capture.intrinsics.K, capture.rgb,
                                 max_relative_jump=options.max_relative_jump,
                                 max_grazing_deg=options.max_grazing_deg)
    timings["mesh_s"] = time.perf_counter() - t0
    if len(mesh.triangles) == 0:
        raise UserError(f"{capture.depth_path}: no triangle survives meshing (depth too sparse or too noisy)")

    t0 = time.perf_counter()
    mesh, smooth_stats = smooth_mesh(mesh, method=options.smooth, iterations=options.smooth_iterations)
    timings["smooth_s"] = time.perf_counter() - t0
    timings["compute_s"] = timings["fill_s"] + timings["mesh_s"] + timings["smooth_s"]
    stats = {"fill": filled.stats, "mesh": mesh_stats, "smooth": smooth_stats}
    return Reconstruction(capture, options, filled, mesh, stats, timings)


def scene_record(recon: Reconstruction) -> dict:
    """The reconstruction part of scene.json: inputs, intrinsics, scale, settings, statistics, timings."""
    fill = recon.filled
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
        "timings": recon.timings,
        "files": {"mesh": "mesh.ply", "depth_filled": "depth_filled.npy", "textured_mesh": "mesh.obj",
                  "texture": "mesh_texture.png", "overview": "overview.png"},
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
    if recon.options.overview:
        from .overview import render_mesh_image, write_overview

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
