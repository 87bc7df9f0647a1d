"""Several RGB-D frames fused into one coloured mesh (Open3D tensor TSDF, ``VoxelBlockGrid``).

The world frame is the first frame's camera frame (CONVENTIONS section 1): poses ``T_world_cam`` are
given relative to it (``trajectory.relative_to_first``) or estimated frame to frame by RGB-D odometry
(:func:`estimate_poses`, Open3D's multi-scale hybrid photometric + geometric odometry).

Settings (:class:`FusionOptions`) scale with the capture: the voxel edge is ``voxel_px`` pixel
footprints at the first frame's median depth (1.5 x 1.86 m / 525 px = 5.3 mm for the Redwood room,
about 0.2 mm for an endoscope at 6 cm), the truncation distance ``trunc_voxels`` voxels (Open3D's
default 8). The surface is extracted where at least ``min_frames`` frames observed it (1: everything any
frame saw, so the sides one frame misses are kept); vertex colours are the TSDF's weighted average of
the frames' colours. No per-frame hole filling by default: the other frames see into a frame's holes,
and filled guesses would be fused as if measured (``MeshOptions.fill`` turns it on). No smoothing by
default either: the TSDF averages the frames' noise (``taubin`` or ``corrective`` may be asked for;
``ray`` smoothing needs a single viewpoint).

The result is a :class:`~rgbd2scene.reconstruct.pipeline.Reconstruction` like a single frame's, so the
mesh folder and the scene are built the same way: ``capture`` is the first frame, ``filled.depth`` the
fused surface's depth seen from the first camera (its holes filled by what the other frames saw),
``sections["fusion"]`` the frames, poses, settings, timings and each frame's agreement with the mesh.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from rgbd2scene.capture.readers import Capture
from rgbd2scene.capture.sensors import infer_sensor
from rgbd2scene.conventions import invert_pose
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.geometry.raycast import raycaster
from rgbd2scene.reconstruct.fill import FillResult, fill_depth
from rgbd2scene.reconstruct.pipeline import MeshOptions, Reconstruction
from rgbd2scene.reconstruct.smooth import mesh_edges, smooth_mesh

#: Smoothing methods that work on a mesh seen from several viewpoints.
FUSION_SMOOTHING = ("none", "taubin", "corrective")


@dataclass
class FusionOptions:
    """TSDF fusion settings (recorded in scene.json); see the module docstring.

    voxel_size : metres; None: ``voxel_px`` pixel footprints at the first frame's median depth.
    trunc_voxels : truncation distance in voxels.
    min_frames : least number of frames that must have seen a surface for it to be extracted.
    depth_max : metres, depth beyond is ignored; None: the largest valid depth of any frame.
    block_resolution : voxels per block edge (Open3D's default 16).
    min_odometry_fitness : odometry between two frames fails below this fraction of matched pixels.
    min_component_triangles : connected pieces with fewer triangles are dropped (floating TSDF debris).
    """

    voxel_size: float | None = None
    voxel_px: float = 1.5
    trunc_voxels: float = 8.0
    min_frames: int = 1
    depth_max: float | None = None
    block_resolution: int = 16
    min_odometry_fitness: float = 0.3
    min_component_triangles: int = 100

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _o3d():
    import open3d as o3d  # imported here: the CLI starts faster without it

    return o3d


def _depth_image(depth: np.ndarray):
    """An Open3D float depth image in metres (0 = no depth)."""
    o3d = _o3d()
    return o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(np.nan_to_num(depth, nan=0.0),
                                                                      dtype=np.float32)))


def _color_image(rgb: np.ndarray):
    o3d = _o3d()
    return o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0))


def _max_depth(captures: list[Capture]) -> float:
    return float(max(np.nanmax(c.depth) for c in captures))


def estimate_poses(captures: list[Capture], depth_max: float | None = None,
                   min_fitness: float = 0.3) -> tuple[np.ndarray, list[dict]]:
    """Poses ``T_world_cam`` (F, 4, 4) of the frames (world = the first frame's camera) by chaining
    frame-to-frame RGB-D odometry; and per pair its fitness and inlier RMSE.

    Raises ``ValueError`` naming the frames when the odometry of a pair fails.
    """
    o3d = _o3d()
    odometry = o3d.t.pipelines.odometry
    depth_max = _max_depth(captures) * 1.05 if depth_max is None else float(depth_max)
    criteria = [odometry.OdometryConvergenceCriteria(n) for n in (20, 10, 5)]
    # Open3D's defaults (outliers beyond 7 cm, Huber delta 5 cm) suit rooms at ~2 m: scale them to the depth,
    # or at endoscopic range every pixel is an "inlier" and the fitness says nothing.
    z = float(np.nanmedian(captures[0].depth))
    loss = odometry.OdometryLossParams(depth_outlier_trunc=0.035 * z, depth_huber_delta=0.025 * z)
    images = [o3d.t.geometry.RGBDImage(_color_image(c.rgb), _depth_image(c.depth)) for c in captures]
    poses, pairs = [np.eye(4)], []
    for k in range(1, len(captures)):
        K = o3d.core.Tensor(captures[k].intrinsics.K)
        try:
            result = odometry.rgbd_odometry_multi_scale(images[k], images[k - 1], K, o3d.core.Tensor(np.eye(4)),
                                                        1.0, depth_max, criteria, odometry.Method.Hybrid, loss)
        except RuntimeError as exc:  # Open3D gives up on a singular system ("tracking failed")
            reason = str(exc).strip().splitlines()[-1][-80:]
            raise ValueError(f"RGB-D odometry failed between frames {k - 1} and {k} ({captures[k - 1].rgb_path}, "
                             f"{captures[k].rgb_path}): {reason}; give the poses") from None
        T_prev_this = result.transformation.numpy()  # maps points of frame k into frame k-1
        pairs.append({"frames": [k - 1, k], "fitness": float(result.fitness),
                      "inlier_rmse": float(result.inlier_rmse)})
        if not (result.fitness >= min_fitness and np.isfinite(T_prev_this).all()):
            raise ValueError(f"RGB-D odometry failed between frames {k - 1} and {k} ({captures[k - 1].rgb_path}, "
                             f"{captures[k].rgb_path}): fitness {result.fitness:.2f} < {min_fitness}; give the poses")
        poses.append(poses[-1] @ T_prev_this)
    return np.array(poses), pairs


def open3d_pixel_K(K: np.ndarray) -> np.ndarray:
    """K for Open3D's TSDF kernels, which look up the depth of pixel (int(u), int(v)): shifting the principal
    point by half a pixel makes that the nearest pixel centre of this project's convention (centre of pixel
    (u, v) at (u, v)). Unshifted, surfaces seen obliquely came out 0.3 voxel too near the camera."""
    shifted = np.array(K, dtype=np.float64)
    shifted[:2, 2] += 0.5
    return shifted


def auto_voxel_size(capture: Capture, voxel_px: float) -> float:
    """``voxel_px`` pixel footprints (z / fx) at the capture's median valid depth, metres."""
    return float(voxel_px * np.nanmedian(capture.depth) / capture.intrinsics.fx)


def fuse_tsdf(captures: list[Capture], poses: np.ndarray,
              options: FusionOptions | None = None) -> tuple[Mesh, dict]:
    """Integrate the frames at their poses into a TSDF and extract the coloured surface mesh.

    Returns the mesh (world frame, metres, vertex colours, triangles facing the cameras) and stats
    (settings used, blocks, vertices, triangles, seconds per step).
    """
    o3d = _o3d()
    core = o3d.core
    options = options or FusionOptions()
    voxel = options.voxel_size or auto_voxel_size(captures[0], options.voxel_px)
    depth_max = _max_depth(captures) * 1.05 if options.depth_max is None else float(options.depth_max)
    integrate_args = (1.0, depth_max, options.trunc_voxels)  # depth scale (metres), depth max, truncation

    def grid(blocks: int):
        return o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (core.float32,) * 3, (1, 1, 3), voxel,
                                             options.block_resolution, blocks, core.Device("CPU:0"))

    t0 = time.perf_counter()
    depths = [_depth_image(c.depth) for c in captures]
    intrinsics = [core.Tensor(open3d_pixel_K(c.intrinsics.K)) for c in captures]
    extrinsics = [core.Tensor(invert_pose(T)) for T in poses]
    # The blocks each frame touches, to size the hash map (a full map integrates several times slower).
    probe = grid(1)
    blocks = [probe.compute_unique_block_coordinates(d, K, E, *integrate_args)
              for d, K, E in zip(depths, intrinsics, extrinsics, strict=True)]
    n_blocks = len(np.unique(np.concatenate([b.numpy() for b in blocks]), axis=0))
    vbg = grid(2 * n_blocks)
    t_prepare = time.perf_counter() - t0

    t0 = time.perf_counter()
    for cap, depth, K, E, coords in zip(captures, depths, intrinsics, extrinsics, blocks, strict=True):
        vbg.integrate(coords, depth, _color_image(cap.rgb), K, K, E, *integrate_args)
    t_integrate = time.perf_counter() - t0

    t0 = time.perf_counter()
    # every frame adds 1 to a voxel's weight; Open3D keeps voxels whose weight exceeds the threshold
    surface = vbg.extract_triangle_mesh(weight_threshold=options.min_frames - 0.5)
    vertices = surface.vertex.positions.numpy().astype(np.float64)
    triangles = surface.triangle.indices.numpy().astype(np.int32)
    colors = np.clip(np.rint(surface.vertex.colors.numpy() * 255.0), 0, 255).astype(np.uint8)
    mesh, dropped = drop_small_components(Mesh(vertices, triangles, colors), options.min_component_triangles)
    t_extract = time.perf_counter() - t0
    stats = {"voxel_size_m": voxel, "trunc_m": voxel * options.trunc_voxels, "depth_max_m": depth_max,
             "blocks": n_blocks, "vertices": mesh.n_vertices, "triangles": mesh.n_triangles, **dropped,
             "prepare_s": round(t_prepare, 4), "integrate_s": round(t_integrate, 4), "extract_s": round(t_extract, 4)}
    return mesh, stats


def drop_small_components(mesh: Mesh, min_triangles: int) -> tuple[Mesh, dict]:
    """The mesh without its connected pieces of fewer than ``min_triangles`` triangles (and unused vertices);
    stats: dropped_components, dropped_triangles."""
    if mesh.n_triangles == 0:
        return mesh, {"dropped_components": 0, "dropped_triangles": 0}
    n = mesh.n_vertices
    lo, hi, _ = mesh_edges(mesh.triangles, n)
    _, labels = connected_components(sp.coo_matrix((np.ones(lo.size), (lo, hi)), shape=(n, n)), directed=False)
    tri_label = labels[mesh.triangles[:, 0]]
    sizes = np.bincount(tri_label, minlength=labels.max() + 1)
    keep_tri = sizes[tri_label] >= min_triangles
    used = np.zeros(n, dtype=bool)
    used[mesh.triangles[keep_tri].ravel()] = True
    remap = np.cumsum(used) - 1
    kept = Mesh(mesh.vertices[used], remap[mesh.triangles[keep_tri]].astype(np.int32),
                None if mesh.vertex_colors is None else mesh.vertex_colors[used])
    small = (sizes > 0) & (sizes < min_triangles)
    return kept, {"dropped_components": int(small.sum()), "dropped_triangles": int((~keep_tri).sum())}


def frame_agreement(mesh: Mesh, captures: list[Capture], poses: np.ndarray, rc=None) -> list[dict]:
    """How well the mesh reproduces each frame's own depth where that frame sees it.

    The mesh is ray cast through each frame's pixel centres at its pose (``rc``: a ready ``Raycaster`` of
    the mesh); see :func:`agreement_rows` for the figures.
    """
    rc = rc or raycaster(mesh.vertices, mesh.triangles)
    return agreement_rows(rendered_depths(rc, captures, poses), captures)


def rendered_depths(rc, captures: list[Capture], poses: np.ndarray) -> list[np.ndarray]:
    """The depth maps of a ray-cast mesh seen by each frame's camera at its pose (NaN on a miss)."""
    return [rc.cast(Camera(c.intrinsics), T, normals="none")["depth"]
            for c, T in zip(captures, poses, strict=True)]


def agreement_rows(rendered: list[np.ndarray], captures: list[Capture]) -> list[dict]:
    """Per frame, over its valid pixels: ``coverage`` (the fraction the rendered mesh covers) and the
    ``median_mm``, ``p90_mm`` and ``mean_mm`` absolute difference of the rendered and the frame's depth."""
    rows = []
    for k, (depth, cap) in enumerate(zip(rendered, captures, strict=True)):
        seen = np.isfinite(cap.depth)
        both = seen & np.isfinite(depth)
        err = np.abs(depth[both].astype(np.float64) - cap.depth[both]) * 1e3
        rows.append({"frame": k, "valid_px": int(seen.sum()), "coverage": float(both.sum() / max(seen.sum(), 1)),
                     "median_mm": float(np.median(err)) if err.size else float("nan"),
                     "p90_mm": float(np.percentile(err, 90)) if err.size else float("nan"),
                     "mean_mm": float(err.mean()) if err.size else float("nan")})
    return rows


def reconstruct_fused(captures: list[Capture], poses: np.ndarray | None = None, options: MeshOptions | None = None,
                      fusion: FusionOptions | None = None, poses_record: dict | None = None) -> Reconstruction:
    """Fuse frames into one mesh in the first frame's camera frame (see the module docstring).

    ``poses`` (F, 4, 4) ``T_world_cam`` with the first frame's camera as world (None: estimated by odometry);
    ``poses_record`` describes given poses in scene.json (e.g. the trajectory file and association rule).
    ``options.fill`` fills each frame's holes before fusing ("none" by default here); ``options.smooth``
    one of ``FUSION_SMOOTHING``. Raises ``ValueError`` on unusable input.
    """
    options = options or MeshOptions()
    options = replace(options, fill=options.fill or "none", smooth=options.smooth or "none")
    fusion = fusion or FusionOptions()
    if len(captures) < 2:
        raise ValueError("fusion needs at least two frames")
    if options.smooth not in FUSION_SMOOTHING:
        raise ValueError(f"smoothing {options.smooth!r} does not apply to a fused mesh; choose one of "
                         f"{', '.join(FUSION_SMOOTHING)} (ray smoothing needs a single viewpoint)")
    timings: dict = {}
    t0 = time.perf_counter()
    sensor = infer_sensor(captures[0].depth, captures[0].depth_format, given=options.sensor, fused=True)
    options = replace(options, sensor=sensor.sensor.name)
    fills = [None] * len(captures)
    if options.fill != "none":
        fills = [fill_depth(c.depth, c.rgb, method=options.fill, sensor=sensor.sensor, fx=c.intrinsics.fx)
                 for c in captures]
    fused_input = [c if f is None else Capture(c.rgb, f.depth, c.intrinsics)
                   for c, f in zip(captures, fills, strict=True)]
    timings["fill_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if poses is None:
        poses, odometry = estimate_poses(captures, fusion.depth_max, fusion.min_odometry_fitness)
        poses_record = {"source": "estimated", "method": "RGB-D odometry frame to frame (Open3D "
                        "rgbd_odometry_multi_scale, hybrid photometric + geometric)", "pairs": odometry}
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (len(captures), 4, 4):
        raise ValueError(f"need one 4x4 pose per frame ({len(captures)}), got an array of shape {poses.shape}")
    if not np.allclose(poses[0], np.eye(4), atol=1e-9):
        raise ValueError("the first frame's pose must be the identity (world = first camera frame)")
    timings["poses_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    mesh, fuse_stats = fuse_tsdf(fused_input, poses, fusion)
    if mesh.n_triangles == 0:
        raise ValueError("fusion produced an empty mesh (check the poses and the depth scale)")
    timings["fuse_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    mesh, smooth_stats = smooth_mesh(mesh, method=options.smooth, iterations=options.smooth_iterations)
    timings["smooth_s"] = time.perf_counter() - t0
    timings["compute_s"] = sum(timings[k] for k in ("fill_s", "poses_s", "fuse_s", "smooth_s"))

    t0 = time.perf_counter()
    rendered = rendered_depths(raycaster(mesh.vertices, mesh.triangles), captures, poses)
    agreement = agreement_rows(rendered, captures)
    first, seen_first = captures[0], rendered[0]
    timings["agreement_s"] = time.perf_counter() - t0

    holes = ~np.isfinite(first.depth)
    filled_by_fusion = holes & np.isfinite(seen_first)
    filled = FillResult(seen_first, filled_by_fusion, "fusion",
                        settings={"per_frame_fill": options.fill,
                                  "depth": "the fused surface ray cast from the first frame's camera"},
                        stats={"hole_fraction": float(holes.mean()), "filled_fraction": float(filled_by_fusion.mean()),
                               "left_unfilled_fraction": float((holes & ~filled_by_fusion).mean()),
                               "per_frame": [f.stats for f in fills if f is not None]})
    record = {
        "frames": [{"rgb": c.rgb_path, "depth": c.depth_path, "T_world_cam": T.tolist()}
                   for c, T in zip(captures, poses, strict=True)],
        "poses": poses_record or {"source": "given"},
        "settings": {**fusion.to_dict(), "voxel_size_m": fuse_stats["voxel_size_m"],
                     "trunc_m": fuse_stats["trunc_m"], "depth_max_m": fuse_stats["depth_max_m"],
                     "colour": "TSDF weighted average of the frames", "per_frame_fill": options.fill,
                     "method": "Open3D VoxelBlockGrid (tensor TSDF), marching cubes"},
        "stats": fuse_stats,
        "agreement": agreement,
        "timings": {k: round(v, 4) for k, v in timings.items()},
    }
    stats = {"fill": filled.stats, "mesh": fuse_stats, "smooth": smooth_stats}
    return Reconstruction(first, options, filled, mesh, np.zeros(first.depth.shape, bool), stats, timings,
                          sections={"fusion": record, "depth_sensor": sensor.to_dict()})
