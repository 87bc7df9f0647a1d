"""Reconstruction end to end, pure computation: capture -> filled depth -> mesh -> smoothed mesh.

The mesh's texture and vertex colours are the capture image without its specular highlights
(``MeshOptions.highlights``, see ``rgbd2scene.reconstruct.texture``); hole filling sees the image as
captured.

Writing the results is the mesh stage's job (``rgbd2scene.stages.mesh``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from rgbd2scene.capture.readers import Capture
from rgbd2scene.errors import UserError
from rgbd2scene.reconstruct.fill import FillResult, fill_depth
from rgbd2scene.reconstruct.mesh import Mesh, grid_mesh
from rgbd2scene.reconstruct.smooth import smooth_mesh
from rgbd2scene.reconstruct.texture import highlight_stats, remove_highlights


@dataclass
class MeshOptions:
    """Every setting of the reconstruction stage (recorded in scene.json)."""

    fill: str = "auto"
    max_relative_jump: float = 0.03
    max_grazing_deg: float = 85.0
    smooth: str = "ray"
    smooth_iterations: int = 10
    highlights: str = "remove"  # or "keep": the texture as captured
    overview: bool = True

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Reconstruction:
    capture: Capture
    options: MeshOptions
    filled: FillResult
    mesh: Mesh
    highlights: np.ndarray  # bool (H, W): capture pixels the texture fills in (specular highlights)
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
    texture, highlights = remove_highlights(capture.rgb, options.highlights)
    timings["texture_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mesh, mesh_stats = grid_mesh(filled.depth, capture.intrinsics.K, texture,
                                 max_relative_jump=options.max_relative_jump,
                                 max_grazing_deg=options.max_grazing_deg)
    timings["mesh_s"] = time.perf_counter() - t0
    if len(mesh.triangles) == 0:
        raise UserError(f"{capture.depth_path}: no triangle survives meshing (depth too sparse or too noisy)")

    t0 = time.perf_counter()
    mesh, smooth_stats = smooth_mesh(mesh, method=options.smooth, iterations=options.smooth_iterations)
    timings["smooth_s"] = time.perf_counter() - t0
    timings["compute_s"] = timings["fill_s"] + timings["texture_s"] + timings["mesh_s"] + timings["smooth_s"]
    stats = {"fill": filled.stats, "texture": {"highlights": options.highlights, **highlight_stats(highlights)},
             "mesh": mesh_stats, "smooth": smooth_stats}
    return Reconstruction(capture, options, filled, mesh, highlights, stats, timings)
