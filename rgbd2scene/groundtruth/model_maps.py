"""Ground truth from the scene model (CONVENTIONS.md section 3), along each pixel's own ray: no Blender.

The scene model (:class:`~rgbd2scene.groundtruth.scene_geometry.SceneGeometry`: every part at its pose of the
frame, deforming tissue deformed) is ray cast through the pixel centres of each eye's camera
(:meth:`rgbd2scene.geometry.camera.Camera.rays`, lens distortion inverted exactly), which gives per pixel:

- ``depth``: the planar z of the hit (the ray has unit z, so the hit distance is z);
- ``normals``: the interpolated angle-weighted vertex normal at the hit (what Blender's Normal pass shows
  of a smooth-shaded mesh), in the camera frame, facing the camera;
- ``segmentation``: the instance id of the hit triangle's part;
- ``flow_forward`` / ``flow_backward``: the hit point followed to the next / previous frame (the same
  triangle and barycentric weights, that frame's vertices), projected by the same eye's camera at that
  frame (``Camera.project``, with its distortion), minus the pixel;
- ``disparity`` (rectified rigs: fx*B/z) and ``correspondence`` (any rig: the hit point projected by the
  other eye at the same frame, minus the pixel; NaN where the other eye does not see it);
- ``occluded_forward`` / ``occluded_backward`` when anything but the camera moves.

Blender's own passes (``groundtruth.passes``, the data render of ``render/frames.py``) stay as the
independent cross-check of these maps (``render --gt-source blender``, ``tests/test_model_gt.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import disparity_from_depth, invert_pose, pixel_grid, transform_points
from rgbd2scene.dataset import layout as ds
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.groundtruth.scene_geometry import SceneGeometry, occlusion_maps
from rgbd2scene.groundtruth.schema import MAPS
from rgbd2scene.scene.model import SceneDescription

EYES = ("left", "right")


@lru_cache(maxsize=4)
def _pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pixel_grid`, made once per image size (read-only)."""
    grid = pixel_grid(height, width)
    for a in grid:
        a.flags.writeable = False
    return grid


def _pixel_offsets(camera: Camera, points_cam: np.ndarray) -> np.ndarray:
    """(H, W, 2) float32: where camera-frame points (H, W, 3) project, minus each pixel's centre."""
    u, v = camera.project(points_cam)
    gu, gv = _pixel_grid(camera.height, camera.width)
    return np.stack([u - gu, v - gv], axis=-1).astype(np.float32)


@dataclass
class ModelGroundTruth:
    """The section-3 maps of every frame and eye of ``description`` (the scene model *as rendered*: its rig
    already at the dataset's image size), read from the scene folder's geometry files.

    ``maps``: the per-pixel maps to compute (a subset of :data:`~rgbd2scene.groundtruth.schema.MAPS`;
    ``disparity`` becomes ``correspondence`` for a raw rig); ``frames``: the dataset's length (flow is NaN
    beyond it).
    """

    geometry: SceneGeometry
    description: SceneDescription
    frames: int
    maps: tuple[str, ...] = MAPS

    @classmethod
    def of_scene(cls, description: SceneDescription, scene_dir: str | Path, frames: int,
                 maps: tuple[str, ...] = MAPS) -> ModelGroundTruth:
        return cls(SceneGeometry(description, scene_dir), description, int(frames), tuple(maps))

    @property
    def moving(self) -> bool:
        return any(part.moving for _, part in self.description.parts())

    def eye(self, index: int, eye: str) -> dict[str, np.ndarray]:
        """The ground-truth dict of one eye at frame ``index`` (the npz's keys)."""
        rig, geometry, maps = self.description.rig, self.geometry, self.maps
        camera = rig.camera(eye)
        T = self.description.camera_pose(index, eye)
        hit = geometry.cast(index, camera, T, normals="smooth" if "normals" in maps else "none", face_normals=False,
                            points=True)
        surface = hit["triangle_ids"] >= 0
        # the surface points under the pixels, at any frame (at this one: the cast's own)
        follow = geometry.follow(hit["triangle_ids"], hit["uvs"], seen=(index, hit["points"]))
        depth = hit["depth"]
        out: dict[str, np.ndarray] = {}
        if "depth" in maps:
            out["depth"] = depth
        if "disparity" in maps:
            if rig.rectified:
                out["disparity"] = disparity_from_depth(depth, float(camera.K[0, 0]), rig.baseline)
            else:
                out["correspondence"] = self._correspondence(index, eye, hit, follow(index))
        if "normals" in maps:
            out["normals"] = hit["normals_cam"]
        if "flow_forward" in maps or "flow_backward" in maps:
            for key, other in (("flow_forward", index + 1), ("flow_backward", index - 1)):
                if key not in maps:
                    continue
                if not 0 <= other < self.frames:
                    out[key] = np.full(depth.shape + (2,), np.nan, np.float32)
                    continue
                T_other = self.description.camera_pose(other, eye)
                flow = _pixel_offsets(camera, transform_points(invert_pose(T_other), follow(other), planar=True))
                flow[~surface] = np.nan
                out[key] = flow
        if "segmentation" in maps:
            out["segmentation"] = hit["instance_ids"]
        if self.moving:
            out.update(occlusion_maps(geometry, index, self.frames, eye, camera, hit=hit, moved_to=follow))
        out["K"] = camera.K
        out["D"] = camera.distortion
        out["T_world_cam"] = T
        ids, poses = self.description.tracked_poses(index)
        out["object_ids"] = np.asarray(ids, dtype=np.uint16).reshape(-1)
        out["object_poses"] = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        return out

    def _correspondence(self, index: int, eye: str, hit: dict, points: np.ndarray) -> np.ndarray:
        """(H, W, 2): the pixel of the other eye that sees the same surface point (``points``: the world points of
        ``hit``) at the same frame, minus this pixel; NaN where no surface, or the other eye does not see the
        point (hidden, or outside)."""
        rig, geometry = self.description.rig, self.geometry
        other = "right" if eye == "left" else "left"
        camera = rig.camera(other)
        T_other = self.description.camera_pose(index, other)
        out = _pixel_offsets(camera, transform_points(invert_pose(T_other), points, planar=True))
        hidden = geometry.hidden(points, camera, T_other, index)
        out[hidden | (hit["triangle_ids"] < 0)] = np.nan
        return out

    def frame(self, index: int) -> dict:
        """Both eyes' dicts by eye name and, for a deforming scene, ``"geometry"`` (``vertices_<id>``)."""
        out: dict = {eye: self.eye(index, eye) for eye in EYES}
        if self.description.deforming:
            out["geometry"] = {f"vertices_{pid}": self.geometry.part_vertices(i, index).astype(np.float32)
                               for pid, i in self.geometry.deformed()}
        return out

    def write(self, out_dir: str | Path, index: int, scratch: Path | None = None) -> None:
        """Compute and write frame ``index``'s npz files (both eyes, and ``geometry/`` when deforming),
        each atomically."""
        write_frame(out_dir, index, self.frame(index), scratch)


def write_frame(out_dir: str | Path, index: int, frame: dict, scratch: Path | None = None) -> None:
    """Write one frame's ground truth (:meth:`ModelGroundTruth.frame`'s layout) into a dataset folder."""
    for eye in EYES:
        ds.write_gt(ds.frame_paths(out_dir, eye, index).gt, frame[eye], scratch=scratch)
    if frame.get("geometry"):
        ds.write_gt(ds.geometry_path(out_dir, index), frame["geometry"], scratch=scratch)
