"""Reconstruction end to end, pure computation: capture -> filled depth -> mesh -> smoothed mesh.

The mesh's texture and vertex colours are the capture image without its specular highlights
(``MeshOptions.highlights``, see ``rgbd2scene.reconstruct.texture``); hole filling sees the image as
captured.

Writing the results is the mesh stage's job (``rgbd2scene.stages.mesh``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from rgbd2scene.capture.readers import Capture
from rgbd2scene.capture.sensors import infer_sensor
from rgbd2scene.capture.stereo import STEREO_SMOOTH_ITERATIONS
from rgbd2scene.conventions import transform_points
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.options import OptionError, option, to_record
from rgbd2scene.reconstruct.fill import FILL_METHODS, FillResult, fill_depth
from rgbd2scene.reconstruct.mesh import grid_mesh
from rgbd2scene.reconstruct.smooth import METHODS as SMOOTH_METHODS
from rgbd2scene.reconstruct.smooth import smooth_mesh
from rgbd2scene.reconstruct.texture import HIGHLIGHT_MODES, highlight_stats, remove_highlights


@dataclass
class MeshOptions:
    """Every setting of the reconstruction stage (CLI flags, batch keys, the record in scene.json)."""

    fill: str | None = option(None, "hole filling: auto, inpaint, colorization, biharmonic, background, none "
                              "(default auto; none when fusing frames, whose holes the other frames fill)",
                              choices=FILL_METHODS)
    sensor: str | None = option(None, "depth sensor, for where occlusion shadows fall: kinect_v1 (structured "
                                "light), kinect_v2, azure_kinect (time of flight: no shadows), realsense (active "
                                "stereo), none (default: inferred from the capture: the preset's sensor, kinect_v1 "
                                "for a depth PNG within its 0.4-10 m range; none for a stereo frame, fused frames, "
                                "EXR/npy depth or depth out of the sensor's range; scene.json says why)")
    max_relative_jump: float = option(0.03, "drop triangles whose relative depth jump exceeds this",
                                      flag="--max-jump")
    max_grazing_deg: float = option(85.0, "drop triangles seen more obliquely than this many degrees",
                                    flag="--max-grazing")
    smooth: str | None = option(None, "smoothing: ray (keeps texture registered), taubin, corrective, none "
                                "(default ray; none when fusing frames)", choices=SMOOTH_METHODS)
    smooth_iterations: int | None = option(None, "smoothing strength (default 10; 100 for a stereo frame, whose "
                                           "depth is rougher)")
    highlights: str = option("remove", "specular highlights of the capture image: remove them from the texture "
                             "(filled from the surrounding colour; the image as captured is kept as "
                             "texture_original.png) or keep them", choices=HIGHLIGHT_MODES)
    overview: bool = option(True, "skip overview.png")

    def to_dict(self) -> dict:
        return to_record(self)


@dataclass
class Reconstruction:
    """A reconstruction and its record; ``sections`` are further scene.json sections (e.g. ``fusion``)."""

    capture: Capture
    options: MeshOptions
    filled: FillResult
    mesh: Mesh
    highlights: np.ndarray  # bool (H, W): capture pixels the texture fills in (specular highlights)
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    sections: dict = field(default_factory=dict)


def restrict_to_image(filled: FillResult, image_mask: np.ndarray) -> FillResult:
    """The fill result with NaN outside ``image_mask`` (pixels without image data are never meshed)."""
    depth = np.where(image_mask, filled.depth, np.nan).astype(np.float32)
    stats = {**filled.stats, "outside_image_fraction": float(np.mean(~image_mask))}
    parts = {name: part & image_mask for name, part in filled.parts.items()}
    return replace(filled, depth=depth, filled=filled.filled & image_mask, stats=stats, parts=parts)


def reconstruct(capture: Capture, options: MeshOptions | None = None,
                on_filled: Callable[[Capture, FillResult], None] | None = None) -> Reconstruction:
    """Fill holes, back-project into a grid mesh without curtains, and smooth along the viewing rays.

    The mesh is built in the capture camera's frame and then placed in the world frame by
    ``capture.T_world_capture``; pixels outside ``capture.image_mask`` stay empty. The depth sensor (for the
    fill's shadow prior) is ``options.sensor``, else inferred from the capture
    (:func:`rgbd2scene.capture.sensors.infer_sensor`); ``sections["depth_sensor"]`` records which and why, and
    under ``"shadows"`` whether the fill took shadows from this capture and why (the fill's statistics).
    ``on_filled(capture, filled)``, when given, is called as soon as the depth is filled: the mesh stage prepares
    its files that need no mesh there, on another core, while this one builds and smooths the mesh.
    """
    options = options or MeshOptions()
    stereo = capture.depth_format == "stereo"
    choice = infer_sensor(capture.depth, capture.depth_format, given=options.sensor, named=capture.sensor)
    options = replace(options, fill=options.fill or "auto", smooth=options.smooth or "ray",
                      sensor=choice.sensor.name,
                      smooth_iterations=options.smooth_iterations if options.smooth_iterations is not None
                      else STEREO_SMOOTH_ITERATIONS if stereo else 10)
    timings = {}
    t0 = time.perf_counter()
    # A rectified image's empty margins are no sensor border band: extrapolating into them would paint a
    # frame of made-up depth along the margins.
    try:
        filled = fill_depth(capture.depth, capture.rgb, method=options.fill, sensor=choice.sensor,
                            fx=capture.intrinsics.fx, fill_border=capture.image_mask is None)
    except ValueError as exc:
        raise OptionError("fill", str(exc)) from None
    if capture.image_mask is not None:
        filled = restrict_to_image(filled, capture.image_mask)
    timings["fill_s"] = time.perf_counter() - t0
    if on_filled is not None:
        on_filled(capture, filled)

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
    if capture.posed:
        mesh.vertices = transform_points(capture.T_world_capture, mesh.vertices)
    timings["smooth_s"] = time.perf_counter() - t0
    timings["compute_s"] = timings["fill_s"] + timings["texture_s"] + timings["mesh_s"] + timings["smooth_s"]
    stats = {"fill": filled.stats, "texture": {"highlights": options.highlights, **highlight_stats(highlights)},
             "mesh": mesh_stats, "smooth": smooth_stats}
    return Reconstruction(capture, options, filled, mesh, highlights, stats, timings,
                          sections={"depth_sensor": {**choice.to_dict(), "shadows": filled.stats["shadows"]}})
