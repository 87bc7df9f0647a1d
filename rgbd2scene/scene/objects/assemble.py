"""Objects of a scene from its configuration: ids, geometry files, poses, tracked frames (no ``bpy``).

:func:`add_objects` takes the scene model with its tissue (rig, path, deformation) and a validated
:class:`~rgbd2scene.scene.config.SceneConfig`, writes each part's mesh to ``SCENE/objects/<id>.ply`` (and a
texture next to it) and returns the model with the objects added. Ids not given in the configuration are
assigned in order, skipping the ones given: the tissue 1, then each instrument's four parts (shaft, wrist,
jaw_upper, jaw_lower: consecutive ids), then the meshes, then the tracked frames (each instrument's
``tip``, then the configuration's), which never appear in the segmentation.

Tracked frames on the tissue are anchored to its rest surface (:class:`~rgbd2scene.scene.deformation.
SurfaceAnchor`: the triangle and barycentric weights where the capture camera's ray through the requested
pixel, or towards the requested position, meets the mesh), so they follow a breathing surface; their z axis
is the surface normal (out of the tissue) unless an orientation is given.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rgbd2scene.files.images import write_image
from rgbd2scene.files.meshio import write_ply
from rgbd2scene.scene import folder
from rgbd2scene.scene.config import MESH_PART, TISSUE, ConfigError, FrameSpec, MeshSpec, SceneConfig
from rgbd2scene.scene.deformation import SurfaceAnchor, rest_normals
from rgbd2scene.scene.model import TISSUE_ID, Material, Part, SceneDescription, SceneObject, TrackedFrame
from rgbd2scene.scene.objects.imported import (
    frames_in_view,
    keyframe_poses,
    path_file_poses,
    read_mesh_file,
    read_texture,
)
from rgbd2scene.scene.objects.instrument import PART_CLASSES, PARTS
from rgbd2scene.scene.objects.motion import default_motion

#: How far (metres) a tracked frame's position on the tissue may lie from the surface.
TISSUE_SNAP = 0.005


@dataclass
class Tissue:
    """The tissue's rest mesh (world frame), ready for ray casting, and the capture's K (for pixels)."""

    vertices: np.ndarray
    triangles: np.ndarray
    rc: object  # geometry.raycast.Raycaster
    capture_K: np.ndarray | None = None


class _Ids:
    """Hands out free ids in order, skipping the ones the configuration gives."""

    def __init__(self, reserved):
        self.used = {TISSUE_ID, *reserved}
        self.next = TISSUE_ID + 1

    def take(self, count: int = 1) -> list[int]:
        start = self.next
        while any(i in self.used for i in range(start, start + count)):
            start += 1
        ids = list(range(start, start + count))
        self.used.update(ids)
        self.next = start + count
        return ids


def _reserved(config: SceneConfig) -> set[int]:
    ids = {i for s in config.instruments if s.first_id is not None for i in range(s.first_id, s.first_id + len(PARTS))}
    ids |= {s.id for s in config.meshes if s.id is not None}
    return ids | {s.id for s in config.tracked_frames if s.id is not None}


def add_objects(description: SceneDescription, tissue: Tissue, config: SceneConfig, scene_dir: Path,
                seed: int = 0) -> tuple[SceneDescription, dict]:
    """The scene model with the configuration's objects and tracked frames added, and their record for
    scene.json. Geometry files are written under ``scene_dir``. Raises :class:`ConfigError` (key path first)."""
    objects_dir = Path(scene_dir) / folder.OBJECTS_DIR
    objects_dir.mkdir(parents=True, exist_ok=True)
    for stale in objects_dir.glob("*"):  # a previous build's parts
        if stale.is_file():
            stale.unlink()
    ids = _Ids(_reserved(config))
    tissue_object = replace(description.objects[0], tracked_frames=list(description.objects[0].tracked_frames))
    objects = [tissue_object, *description.objects[1:]]
    record: dict = {"config": None if config.path is None else str(config.path), "instruments": [], "meshes": [],
                    "tracked_frames": []}
    deformation = tissue_object.parts[0].deformation
    rise = 0.0 if deformation is None else deformation.amplitude_m * float(np.abs(deformation.harmonics).sum())

    for spec in config.instruments:
        part_ids = (list(range(spec.first_id, spec.first_id + len(PARTS))) if spec.first_id is not None
                    else ids.take(len(PARTS)))
        try:
            track = default_motion(tissue.rc, description.rig, description.path, spec.instrument, spec.motion,
                                   seed=seed, extra_clearance=rise)
        except ValueError as exc:
            raise ConfigError(f"{spec.key}: {exc}") from None
        meshes, poses, looks = spec.instrument.meshes(), track.part_poses(spec.instrument), spec.instrument.materials()
        parts = []
        for part_id, name in zip(part_ids, PARTS, strict=True):
            write_ply(Path(scene_dir) / folder.object_geometry(part_id), meshes[name])
            parts.append(Part(part_id, name, PART_CLASSES[name], folder.object_geometry(part_id),
                              Material(looks[name]), poses[name]))
        tip = np.eye(4)
        tip[:3, 3] = spec.instrument.tip
        objects.append(SceneObject(spec.name, "instrument", parts, [TrackedFrame(ids.take()[0], "tip", "wrist", tip)]))
        record["instruments"].append({"key": spec.key, "name": spec.name, "ids": part_ids,
                                      "instrument": spec.instrument.to_dict(), "motion": track.settings,
                                      "trocar": track.trocar.tolist(), "in_view_fraction": track.in_view_fraction,
                                      "clearance_min_m": float(track.clearance.min())})

    for spec in config.meshes:
        part_id = spec.id if spec.id is not None else ids.take()[0]
        objects.append(_mesh_object(spec, part_id, description, Path(scene_dir)))
        record["meshes"].append({"key": spec.key, "name": spec.name, "id": part_id, "class": spec.cls,
                                 "file": str(spec.file), "scale": spec.scale,
                                 "motion": "keyframes" if spec.keyframes else "path_file" if spec.path_file
                                 else "static"})

    by_name = {o.name: o for o in objects}
    for spec in config.tracked_frames:
        frame_id = spec.id if spec.id is not None else ids.take()[0]
        if spec.object == TISSUE:
            frame = _tissue_frame(spec, frame_id, tissue, tissue_object.parts[0].name)
        else:
            target = by_name[spec.object]
            part = spec.part or target.parts[0].name
            offset = np.eye(4)
            if spec.rotation is not None:
                offset[:3, :3] = spec.rotation
            if spec.position is not None:
                offset[:3, 3] = spec.position
            frame = TrackedFrame(frame_id, spec.name, part, offset)
        by_name[spec.object].tracked_frames.append(frame)
        record["tracked_frames"].append({"key": spec.key, "name": spec.name, "id": frame_id,
                                         "attached_to": f"{spec.object}/{frame.attached_to}"})
    try:
        return replace(description, objects=objects), record
    except ValueError as exc:
        raise ConfigError(f"objects: {exc}") from None


def _mesh_object(spec: MeshSpec, part_id: int, description: SceneDescription, scene_dir: Path) -> SceneObject:
    try:
        imported = read_mesh_file(spec.file, spec.scale, spec.recenter)
    except ValueError as exc:
        raise ConfigError(f"{spec.key}.file: {exc}") from None
    texture = imported.texture
    if spec.texture is not None:
        if imported.mesh.uvs is None:
            raise ConfigError(f"{spec.key}.texture: {spec.file} has no UVs to map a texture with")
        try:
            texture = read_texture(spec.texture)
        except ValueError as exc:
            raise ConfigError(f"{spec.key}.texture: {exc}") from None
    mesh = imported.mesh
    if texture is None:
        mesh = mesh.copy(uvs=None)
    write_ply(scene_dir / folder.object_geometry(part_id), mesh)
    texture_file = None
    if texture is not None:
        texture_file = folder.object_texture(part_id)
        write_image(scene_dir / texture_file, texture)
    frames, fps = description.path.frames, description.path.fps
    try:
        if spec.keyframes is not None:
            poses = keyframe_poses(spec.keyframes, frames, fps, where=f"{spec.key}.motion.keyframes")
        elif spec.path_file is not None:
            poses = path_file_poses(spec.path_file, frames)
        else:
            poses = spec.pose if spec.pose is not None else np.eye(4)
    except ValueError as exc:
        raise ConfigError(str(exc) if spec.keyframes is not None else f"{spec.key}.motion.path_file: {exc}") from None
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    seen = frames_in_view(mesh.vertices, poses, description.rig, description.path)
    if not seen.any():
        raise ConfigError(f"{spec.key}: {spec.name!r} never enters the view: no vertex projects into either "
                          f"eye's image in any of the {frames} frames (check its pose, motion and scale)")
    material = Material(spec.material, texture_file, spec.color)
    return SceneObject(spec.name, "mesh", [Part(part_id, MESH_PART, spec.cls, folder.object_geometry(part_id),
                                                material, poses)])


def tissue_anchor(tissue: Tissue, direction: np.ndarray, normals: np.ndarray) -> SurfaceAnchor | None:
    """Where the capture camera's ray along ``direction`` (world frame, from the origin) meets the rest
    tissue: its triangle's vertices and barycentric weights (None when it misses)."""
    hit = tissue.rc.cast_rays(np.zeros(3), np.asarray(direction, dtype=np.float64))
    tri = int(hit["triangle_ids"])
    if tri < 0:
        return None
    u, v = hit["uvs"]
    corners = np.asarray(tissue.triangles[tri], dtype=np.int64)
    return SurfaceAnchor(tuple(corners), (1.0 - u - v, u, v), tissue.vertices[corners], normals[corners])


def _tissue_frame(spec: FrameSpec, frame_id: int, tissue: Tissue, part_name: str) -> TrackedFrame:
    if spec.pixel is not None:
        if tissue.capture_K is None:
            raise ConfigError(f"{spec.key}.pixel: the capture's intrinsics are not known for this scene; "
                              "give a position")
        K = tissue.capture_K
        direction = np.array([(spec.pixel[0] - K[0, 2]) / K[0, 0], (spec.pixel[1] - K[1, 2]) / K[1, 1], 1.0])
        where = f"{spec.key}.pixel"
    else:
        direction, where = spec.position, f"{spec.key}.position"
    normals = rest_normals(tissue.vertices, tissue.triangles)
    anchor = tissue_anchor(tissue, direction, normals)
    if anchor is None:
        raise ConfigError(f"{where}: the capture camera's ray there misses the tissue")
    point = anchor.point()
    if spec.position is not None and np.linalg.norm(point - spec.position) > TISSUE_SNAP:
        raise ConfigError(f"{where}: {np.linalg.norm(point - spec.position) * 1e3:.1f} mm from the tissue surface "
                          f"(at most {TISSUE_SNAP * 1e3:.0f} mm)")
    offset = np.eye(4)
    if spec.rotation is not None:
        offset[:3, :3] = spec.rotation
    else:
        z = anchor.normal()
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        if np.linalg.norm(x) < 1e-6:
            x = np.array([0.0, 1.0, 0.0]) - z[1] * z
        x /= np.linalg.norm(x)
        offset[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    offset[:3, 3] = point
    return TrackedFrame(frame_id, spec.name, part_name, offset, anchor)
