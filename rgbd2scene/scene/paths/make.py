"""``make_path``: the camera path of a kind, drawn by its generator until both eyes' views stay on the mesh."""

from __future__ import annotations

import inspect

import numpy as np

from rgbd2scene.scene.paths.generators import PATH_GENERATORS, PathContext, require
from rgbd2scene.scene.paths.surface import Surface, path_coverage, view_height
from rgbd2scene.scene.paths.track import CameraPath
from rgbd2scene.scene.paths.waypoints import load_path_file, waypoint_path
from rgbd2scene.scene.rig import StereoRig

DEFAULT_STANDOFF = 0.04
DEFAULT_SPEED = 0.02  # m/s: a slow, steady endoscope motion (a few pixels of flow per frame at 30 fps)
PATH_KINDS = (*PATH_GENERATORS, "waypoints")
#: Depths (in standoffs) down to which both eyes' views are kept on the mesh footprint, tried in turn.
RELIEF_ALLOWANCES = (1.25, 1.6, 2.0, 2.6, 3.4, 4.5)


def _option_names(generator) -> list[str]:
    """The keyword-only parameters of a generator: its kind's options."""
    return [p.name for p in inspect.signature(generator).parameters.values() if p.kind is p.KEYWORD_ONLY]


def make_path(kind: str, vertices=None, triangles=None, rig=None, frames: int = 60, fps: float = 30.0,
              seed: int = 0, standoff: float = DEFAULT_STANDOFF, *, waypoints=None,
              speed: float = DEFAULT_SPEED,
              min_coverage: float = 0.95, check_scale: float = 0.5, smooth: float = 1.5, rc=None,
              **options) -> CameraPath:
    """Camera path of the left eye over the mesh.

    kind
        A key of ``PATH_GENERATORS`` (``static``, ``scan``, ``orbit``, ``random``; ``options`` are the
        generator's keyword-only parameters, see its docstring), or ``waypoints`` (``waypoints``: a list,
        or a path file name; the mesh is not needed).

    Generated paths look along the capture direction (+z, or tilted from it by at most the tilt), keep
    ``standoff`` metres between the left eye and the visible surface at the image centre, and keep
    both eyes' views on the reconstructed surface: the path stays inside the mesh's footprint
    (orthographic along +z) shrunk by the view's footprint at a depth allowing for relief; every frame
    is then ray cast for both eyes at ``check_scale`` of the rig's resolution and, if any frame sees
    less than ``min_coverage`` surface, the footprint allowance grows and the path is drawn again.
    ``settings`` records everything (and the coverage reached) to regenerate it. Bad arguments, or a
    mesh with no room for the path, raise ``ValueError``.
    """
    from rgbd2scene.geometry.raycast import raycaster

    kind = kind.lower()
    generator = PATH_GENERATORS.get(kind)
    if generator is None and kind != "waypoints":
        raise ValueError(f"unknown path kind {kind!r}; choose one of {', '.join([*PATH_GENERATORS, 'waypoints'])}")
    frames = int(frames)
    require((frames >= 1, f"frames must be at least 1, got {frames}"),
            (fps > 0 and np.isfinite(fps), f"fps must be positive, got {fps}"))
    if kind == "waypoints":
        if waypoints is None:
            raise ValueError("path kind 'waypoints' needs waypoints (a list or a path file)")
        if isinstance(waypoints, str) or hasattr(waypoints, "__fspath__"):
            return load_path_file(waypoints)
        return waypoint_path(waypoints, frames, fps)
    unknown = set(options) - set(_option_names(generator))
    if unknown:
        raise ValueError(f"unknown option(s) for kind {kind!r}: {', '.join(sorted(unknown))}")
    if rig is None:
        rig = StereoRig.endoscope()
    require((standoff > 0 and np.isfinite(standoff), f"standoff must be positive, got {standoff}"),
            (rig.clip_start < standoff < rig.clip_end, f"standoff {standoff} m lies outside the rig's clip range "
                                                         f"[{rig.clip_start}, {rig.clip_end}] m"),
            (speed > 0 and np.isfinite(speed), f"speed must be positive, got {speed}"),
            (0.0 < check_scale <= 1.0, f"check_scale must lie in (0, 1], got {check_scale}"),
            (0.0 <= min_coverage <= 1.0, f"min_coverage must lie in [0, 1], got {min_coverage}"))
    rc = rc if rc is not None else raycaster(vertices, triangles)
    require((len(rc.triangles) > 0, "the mesh has no triangles"))
    intr = rig.intrinsics
    surface = Surface(rc, cell=view_height(rig, standoff) / 16.0)
    require((surface.valid.any(), "the mesh has no surface facing the capture direction (+z)"))

    best = None
    for relief in RELIEF_ALLOWANCES:
        context = PathContext(surface, rig, frames, fps, standoff, speed, smooth, relief)
        placement = generator(context, np.random.default_rng(seed), **options)
        if placement is None:
            continue
        candidate = CameraPath(placement.poses, float(fps), kind, {})
        coverage = path_coverage(None, None, rig, candidate, scale=check_scale, rc=rc)
        if best is None or coverage.min() > best[1].min():
            best = (candidate, coverage, relief, placement.settings)
        if coverage.min() >= min_coverage + 0.005:
            break
    if best is None:
        raise ValueError(
            f"the mesh (footprint {np.ptp(rc.vertices[:, 0]):.3f} x {np.ptp(rc.vertices[:, 1]):.3f} m) "
            f"has no room for a {kind} path of the {intr.width}x{intr.height} view at standoff "
            f"{standoff} m; try a smaller standoff or a shorter path")
    candidate, coverage, relief, drawn = best
    if coverage.min() < min_coverage:
        raise ValueError(
            f"no {kind} path keeps {min_coverage:.0%} of both views on the mesh at standoff "
            f"{standoff} m (best frame: {coverage.min():.1%}); try a smaller standoff or a shorter path")
    candidate.settings = {"seed": int(seed), "standoff": float(standoff), "min_coverage": float(min_coverage),
                          **drawn, "relief_allowance": relief, "coverage_min": float(coverage.min()),
                          "coverage_scale": check_scale}
    return candidate
