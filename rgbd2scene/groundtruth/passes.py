"""Raw render passes -> the ground-truth maps of CONVENTIONS.md section 3 (numpy only, no ``bpy``).

The ground truth comes from the scene model (:mod:`rgbd2scene.groundtruth.model_maps`); Blender's passes are
its independent cross-check (``render --gt-source blender``). The renderer (``render/frames.py``) then reads
the passes of one eye from its data render (1 sample per pixel through the pixel centre, see there) and
hands them to :func:`gt_from_passes`:

- ``Depth`` (planar z, Blender writes 1e10 where no surface) -> ``depth`` with NaN on background;
- ``disparity`` = fx*B/z via :func:`rgbd2scene.conventions.disparity_from_depth`;
- ``Normal`` (world space, Blender axes = the project's world axes) -> camera frame
  (``R_cam_world = R_world_cam.T``, OpenCV axes), unit length, turned to face the camera;
- ``Vector`` (4 channels) -> ``flow_forward`` / ``flow_backward`` via
  :func:`rgbd2scene.conventions.flow_from_blender_vector`, NaN on the last / first frame;
- ``IndexOB`` (object ``pass_index``) -> ``segmentation`` uint16, 0 = nothing.

Every float map is NaN where the depth pass says there is no surface (background, tears in the mesh).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from rgbd2scene.conventions import (
    disparity_from_depth,
    flow_from_blender_vector,
    orient_normals_to_camera,
    pixel_rays,
    rotate,
)
from rgbd2scene.groundtruth.schema import MAPS, surface_mask

#: The per-pixel maps a dataset can hold (the per-frame matrices K, T_world_cam, object_ids and
#: object_poses are always written with them).
#: Short names accepted by :func:`parse_maps` besides the map names themselves.
ALIASES = {"flow": ("flow_forward", "flow_backward"), "seg": ("segmentation",), "normal": ("normals",)}
#: Blender passes each map is computed from (Depth is always needed: it decides where there is surface).
PASSES_FOR = {"depth": ("depth",), "disparity": ("depth",), "normals": ("depth", "normal"),
              "flow_forward": ("depth", "vector"), "flow_backward": ("depth", "vector"),
              "segmentation": ("depth", "index")}


def parse_maps(spec: str | Iterable[str] | None) -> tuple[str, ...]:
    """``"all"``, ``"none"``/``""``/None, or a comma list (``"depth,normals,flow"``) -> map names in
    the canonical order of :data:`MAPS`. Raises ``ValueError`` naming an unknown map."""
    if spec is None:
        return ()
    names = [s.strip().lower() for s in spec.split(",")] if isinstance(spec, str) else [str(s) for s in spec]
    names = [n for n in names if n]
    if not names or names == ["none"]:
        return ()
    if "all" in names:
        return MAPS
    chosen: set[str] = set()
    for name in names:
        if name in MAPS:
            chosen.add(name)
        elif name in ALIASES:
            chosen.update(ALIASES[name])
        else:
            raise ValueError(f"unknown ground-truth map {name!r}; choose all, none or a comma list of "
                             f"{', '.join(MAPS + tuple(ALIASES))}")
    return tuple(m for m in MAPS if m in chosen)


def passes_needed(maps: Iterable[str]) -> set[str]:
    """Blender passes (``depth``, ``normal``, ``vector``, ``index``) needed for ``maps``."""
    out: set[str] = set()
    for m in maps:
        out.update(PASSES_FOR[m])
    return out


def depth_from_pass(depth_pass: np.ndarray) -> np.ndarray:
    """Planar z (float32) with NaN where there is no surface."""
    z = np.asarray(depth_pass, dtype=np.float32)
    return np.where(surface_mask(z), z, np.float32(np.nan)).astype(np.float32)


def normals_to_camera(normal_world: np.ndarray, R_world_cam: np.ndarray, K: np.ndarray,
                      mask: np.ndarray | None = None) -> np.ndarray:
    """World-space normals (H, W, 3) -> unit camera-frame (OpenCV) normals facing the camera, float32.

    NaN outside ``mask`` and where the normal has no length.
    """
    n = np.asarray(normal_world, dtype=np.float64)
    h, w = n.shape[:2]
    R_cam_world = np.asarray(R_world_cam, dtype=np.float64)[:3, :3].T
    n_cam = rotate(R_cam_world, n)
    length = np.linalg.norm(n_cam, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_cam = np.where(length > 1e-12, n_cam / length, np.nan)
    n_cam = orient_normals_to_camera(n_cam, pixel_rays(h, w, K))
    if mask is not None:
        n_cam[~mask] = np.nan
    return n_cam.astype(np.float32)


def flow_from_pass(vector: np.ndarray, mask: np.ndarray | None = None, first: bool = False,
                   last: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Blender's 4-channel Vector pass -> (flow_forward, flow_backward), float32 (H, W, 2).

    NaN outside ``mask``; the whole forward flow is NaN on the ``last`` frame and the backward flow on
    the ``first`` one (Blender reports zero motion there: the path has no frame beyond its ends).
    """
    fwd, bwd = flow_from_blender_vector(vector)
    fwd, bwd = fwd.astype(np.float32, copy=True), bwd.astype(np.float32, copy=True)
    if mask is not None:
        fwd[~mask] = np.nan
        bwd[~mask] = np.nan
    if last:
        fwd[:] = np.nan
    if first:
        bwd[:] = np.nan
    return fwd, bwd


def segmentation_from_pass(index: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Object-index pass (float) -> uint16 instance ids, 0 where there is no surface."""
    idx = np.asarray(index, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        seg = np.where(np.isfinite(idx), np.clip(np.rint(idx), 0, 65535), 0).astype(np.uint16)
    if mask is not None:
        seg[~mask] = 0
    return seg


def gt_from_passes(depth_pass: np.ndarray, normal_world: np.ndarray | None, vector: np.ndarray | None,
                   index: np.ndarray | None, K: np.ndarray, T_world_cam: np.ndarray, baseline: float, *,
                   first: bool = False, last: bool = False, object_ids=None, object_poses=None,
                   maps: Iterable[str] = MAPS, D=None) -> dict[str, np.ndarray]:
    """The section-3 ground truth of one eye and frame from its raw passes.

    Parameters
    ----------
    depth_pass : (H, W)
        Blender's Depth pass (planar z in metres, 1e10 where no surface).
    normal_world : (H, W, 3) or None
        Normal pass (world space). Needed for ``normals``.
    vector : (H, W, 4) or None
        Vector pass (X, Y towards the previous frame, Z, W towards the next; raster pixels, y up).
        Needed for the flows.
    index : (H, W) or None
        Object-index pass (``pass_index`` of the visible object). Needed for ``segmentation``.
    K, T_world_cam
        This eye's intrinsics and pose (OpenCV camera axes).
    baseline
        Stereo baseline in metres (disparity = fx*B/z, the same for both eyes).
    first, last
        Whether this is the dataset's first / last frame (backward / forward flow all NaN).
    object_ids, object_poses
        Tracked objects: ids (N,) and T_world_obj (N, 4, 4); empty when None.
    maps
        The maps to compute (subset of :data:`MAPS`); the matrices are always included.
    D
        This eye's distortion (None: zeros (5,), a pinhole; Blender renders pinholes only).
    """
    maps = tuple(maps)
    unknown = set(maps) - set(MAPS)
    if unknown:
        raise ValueError(f"unknown ground-truth maps {sorted(unknown)}")
    depth_pass = np.asarray(depth_pass)
    if depth_pass.ndim != 2:
        raise ValueError(f"depth pass must be (H, W), got shape {depth_pass.shape}")
    h, w = depth_pass.shape
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    T = np.asarray(T_world_cam, dtype=np.float64).reshape(4, 4)
    mask = surface_mask(depth_pass)

    def need(name, array, channels):
        if array is None:
            raise ValueError(f"map {name!r} needs a pass that was not given")
        a = np.asarray(array)
        shape = (h, w) if channels is None else (h, w, channels)
        if a.shape != shape:
            raise ValueError(f"pass for {name!r} has shape {a.shape}, expected {shape}")
        return a

    out: dict[str, np.ndarray] = {}
    depth = depth_from_pass(depth_pass)
    if "depth" in maps:
        out["depth"] = depth
    if "disparity" in maps:
        out["disparity"] = disparity_from_depth(depth, float(K[0, 0]), float(baseline))
    if "normals" in maps:
        out["normals"] = normals_to_camera(need("normals", normal_world, 3), T[:3, :3], K, mask)
    if "flow_forward" in maps or "flow_backward" in maps:
        fwd, bwd = flow_from_pass(need("flow", vector, 4), mask, first=first, last=last)
        if "flow_forward" in maps:
            out["flow_forward"] = fwd
        if "flow_backward" in maps:
            out["flow_backward"] = bwd
    if "segmentation" in maps:
        out["segmentation"] = segmentation_from_pass(need("segmentation", index, None), mask)
    out["K"] = K.copy()
    out["D"] = np.zeros(5) if D is None else np.asarray(D, dtype=np.float64).ravel()
    out["T_world_cam"] = T.copy()
    ids = np.asarray([] if object_ids is None else object_ids, dtype=np.uint16).reshape(-1)
    poses = (np.zeros((0, 4, 4)) if object_poses is None
             else np.asarray(object_poses, dtype=np.float64).reshape(-1, 4, 4))
    if len(ids) != len(poses):
        raise ValueError(f"{len(ids)} object ids but {len(poses)} object poses")
    out["object_ids"] = ids
    out["object_poses"] = poses
    return out
