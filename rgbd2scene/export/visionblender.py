"""VisionBlender-style export: one npz per eye and frame with the keys of VisionBlender's add-on and loaders.

Layout (``NNNN`` = the dataset's frame number, at least four digits, as VisionBlender names Blender frames;
``_L``/``_R`` are Blender's default stereo view suffixes)::

    OUT/NNNN_L.png  OUT/NNNN_L.npz  OUT/NNNN_R.png  OUT/NNNN_R.npz

Keys (float64 like VisionBlender's, which come from Blender's float pixel arrays) and how they differ from the
dataset's (CONVENTIONS §1-§3):

- ``depth_map`` (H, W): planar z in metres; -1 where there is no surface (VisionBlender's ``INVALID_POINT``;
  the dataset has NaN). Its own depth came from Blender's Depth pass, which before Blender 2.90 was ray length.
- ``disparity_map`` (H, W): fx·B/z in pixels, positive for both eyes; 0 where there is no surface (as VisionBlender).
- ``normal_map`` (H, W, 3): unit normals in the *world* frame (Blender's Normal pass, which VisionBlender saves);
  the dataset's are in the camera frame and are rotated by T_world_cam here. 0 where there is no surface.
- ``optical_flow`` (H, W, 2): the dataset's forward flow (du, dv) in pixels, y down, from this frame to the
  next; 0 where there is none (last frame, no surface). VisionBlender derives its "forward" flow from the
  Vector pass's motion *to the previous* frame with u negated (-X, Y): equal to the forward flow only for
  motion at constant velocity. Here it is the exact forward flow.
- ``segmentation_masks`` (H, W) uint16: instance ids (Blender ``pass_index``), 0 = nothing, as the dataset's.
- ``segmentation_masks_indexes``: structured array (``name``, ``pass_index`` uint16) of every object part.
- ``intrinsic_mat`` (3, 3): K (OpenCV, pixel centres at integers: the same as VisionBlender's cx = (W-1)/2).
- ``extrinsic_mat`` (3, 4): world -> camera [R | t] in OpenCV axes (VisionBlender's ``R_world2cv | T_world2cv``),
  the top rows of inverse(T_world_cam).
- ``object_poses``: structured array (``name``, ``pose`` (4, 4)) of T_world_obj of every tracked object part and
  frame (VisionBlender lists every Blender object's ``matrix_world``, including camera and light; the
  dataset's world frame is the Blender scene's world frame, so poses carry over unchanged).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.conventions import invert_pose
from rgbd2scene.dataset.layout import EYES
from rgbd2scene.dataset.reader import Dataset, ObjectEntry
from rgbd2scene.export.common import ExportSummary, frame_indices, require_keys
from rgbd2scene.files.atomic import atomic_path, write_bytes

SUFFIX = {"left": "_L", "right": "_R"}
INVALID_DEPTH = -1.0
KEYS = ("depth", "disparity", "normals", "flow_forward", "segmentation", "K", "T_world_cam", "object_ids",
        "object_poses")


def object_label(entry: ObjectEntry | None, oid: int) -> str:
    """The object's name as VisionBlender lists it (``name`` or ``name_part``; ``object_<id>`` when unknown)."""
    if entry is None:
        return f"object_{oid}"
    return f"{entry.name}_{entry.part}" if entry.part else entry.name


def visionblender_arrays(gt: dict, objects: dict[int, ObjectEntry]) -> dict[str, np.ndarray]:
    """The npz arrays of one eye and frame (see the module docstring) from the dataset's ground truth."""
    surface = np.isfinite(gt["depth"])
    T = np.asarray(gt["T_world_cam"], np.float64)
    normals_world = np.asarray(gt["normals"], np.float64) @ T[:3, :3].T
    flow = np.asarray(gt["flow_forward"], np.float64)
    ids = [int(i) for i in gt["object_ids"]]
    labels = [object_label(objects.get(i), i) for i in ids]
    parts = sorted((oid, object_label(o, oid)) for oid, o in objects.items() if not o.tracked_frame)
    width = max([len(s) for s in labels] + [len(s) for _, s in parts] + [1])
    indexes = np.array([(name, oid) for oid, name in parts], dtype=[("name", f"U{width}"), ("pass_index", "<u2")])
    poses = np.array(list(zip(labels, np.asarray(gt["object_poses"], np.float64), strict=True)),
                     dtype=[("name", f"U{width}"), ("pose", "<f8", (4, 4))])
    return {
        "optical_flow": np.where(np.isfinite(flow).all(axis=-1, keepdims=True), flow, 0.0),
        "segmentation_masks": np.asarray(gt["segmentation"], np.uint16),
        "segmentation_masks_indexes": indexes,
        "intrinsic_mat": np.asarray(gt["K"], np.float64),
        "extrinsic_mat": invert_pose(T)[:3],
        "normal_map": np.where(surface[..., None], normals_world, 0.0),
        "depth_map": np.where(surface, np.asarray(gt["depth"], np.float64), INVALID_DEPTH),
        "disparity_map": np.where(surface, np.asarray(gt["disparity"], np.float64), 0.0),
        "object_poses": poses,
    }


def export_visionblender(dataset: Dataset, out: str | Path, progress: bool = True) -> ExportSummary:
    """Write the VisionBlender-style folder (see the module docstring) frame by frame."""
    out = Path(out)
    summary = ExportSummary("visionblender", out)
    require_keys(dataset, EYES, KEYS)
    objects = dataset.objects
    for index in frame_indices(dataset, progress, "export visionblender"):
        for eye in EYES:
            stem = f"{index:04d}{SUFFIX[eye]}"
            write_bytes(out / f"{stem}.png", dataset.rgb_file(eye, index).read_bytes())
            arrays = visionblender_arrays(dataset.gt(eye, index, KEYS), objects)
            with atomic_path(out / f"{stem}.npz") as tmp:
                np.savez_compressed(tmp, **arrays)
            summary.files += 2
        summary.frames += 1
    return summary
