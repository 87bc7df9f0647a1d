"""The scene oracle: what eye E really sees at frame f, by ray casting the scene model (independent of Blender).

The mesh checks (``depth``, ``normals``, ``segmentation``) never open meshes: they ask the run's oracle for
a :class:`RayCast` of the eye's camera (K, D, image size) at its pose and frame, and compare only the pixels
the oracle models (:meth:`SceneOracle.covers`). When the dataset's scene folder holds its scene model
(``scene.json``), the oracle is :class:`ModelOracle`: every part at its pose of frame f, deforming tissue deformed
(:class:`~rgbd2scene.groundtruth.scene_geometry.SceneGeometry`), instance ids per triangle, every pixel
covered, and surface points followed into other frames (:meth:`ModelOracle.moved_points`) for the flow and
occlusion checks of moving surfaces. Otherwise (``--mesh``, or no scene folder) it is one static mesh
(:class:`StaticMeshOracle`), and moving objects are left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from rgbd2scene.dataset.reader import Dataset
from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.geometry.raycast import Raycaster

#: Ways to shade a hit: interpolated angle-weighted vertex normals (a smooth-shaded render) or face normals.
SHADINGS = ("smooth", "face")
#: The scene folder's mesh (CONVENTIONS.md section 4).
SCENE_MESH = "mesh.ply"


@dataclass
class RayCast:
    """What a camera sees of the scene model, per pixel centre (CONVENTIONS.md sections 1 and 3)."""

    depth: np.ndarray  # (H, W) float32 planar z, NaN where the ray misses
    normals: np.ndarray  # (H, W, 3) float32 unit normals, camera frame, facing the camera, as the oracle shades
    face_normals: np.ndarray | None = None  # (H, W, 3) the triangles' own normals when shading is "smooth"
    instance_ids: np.ndarray | None = None  # (H, W) uint16 segmentation ids (0 on a miss); None when unknown

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.depth)


class SceneOracle(Protocol):
    """Answers "ray cast this eye at frame f"."""

    source: str  # what it casts against (the report's "mesh" line)
    shading: str  # one of SHADINGS

    def cast(self, frame: int, camera: Camera, T_world_cam: np.ndarray) -> RayCast:
        """The scene of ``frame`` seen by ``camera`` at T_world_cam (4, 4), along each pixel's ray."""
        ...

    def covers(self, frame: int, segmentation: np.ndarray) -> np.ndarray:
        """Bool (H, W): the pixels (by instance id) whose surface this oracle models at ``frame``."""
        ...


class StaticMeshOracle:
    """The scene as one triangle mesh that never moves.

    Parameters
    ----------
    raycaster : the mesh, ready for ray casting.
    source : where the mesh came from (reported).
    shading : one of :data:`SHADINGS`.
    ids : segmentation ids of the mesh's surface; None: every id (and 0, no object, always).
    moving : ids of objects that move: never covered, whatever ``ids`` says.
    triangle_ids : optional (M,) instance id of each triangle, returned as :attr:`RayCast.instance_ids`.
    """

    def __init__(self, raycaster: Raycaster, source: str, shading: str = "smooth", ids=None,
                 moving=frozenset(), triangle_ids: np.ndarray | None = None):
        if shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, not {shading!r}")
        if triangle_ids is not None and np.shape(triangle_ids) != (len(raycaster.triangles),):
            raise ValueError(f"triangle_ids must have one id per triangle ({len(raycaster.triangles)}), "
                             f"got shape {np.shape(triangle_ids)}")
        self.raycaster, self.source, self.shading = raycaster, source, shading
        self.ids = None if ids is None else frozenset(int(i) for i in ids)
        self.moving = frozenset(moving)
        self.triangle_ids = None if triangle_ids is None else np.asarray(triangle_ids, np.uint16)

    def cast(self, frame: int, camera: Camera, T_world_cam: np.ndarray) -> RayCast:
        hit = self.raycaster.cast(camera, T_world_cam, normals=self.shading)
        ids = None
        if self.triangle_ids is not None:
            tri = hit["triangle_ids"]
            ids = np.where(tri >= 0, self.triangle_ids[np.maximum(tri, 0)], 0).astype(np.uint16)
        return RayCast(hit["depth"], hit["normals_cam"], hit.get("face_normals_cam"), ids)

    def covers(self, frame: int, segmentation: np.ndarray) -> np.ndarray:
        covered = np.ones(segmentation.shape, bool)
        if self.moving:
            covered &= ~np.isin(segmentation, list(self.moving))
        if self.ids is not None:
            covered &= np.isin(segmentation, list(self.ids)) | (segmentation == 0)
        return covered


class ModelOracle:
    """The scene model at every frame: objects at their poses, deforming surfaces deformed.

    ``moved_points(frame, other, ...)`` gives, per pixel, the world position at frame ``other`` of the surface
    point the pixel sees at ``frame`` (the same triangle and barycentric weights): the independent reference
    for the flow and occlusion of moving and deforming surfaces.
    """

    def __init__(self, geometry, source: str, shading: str = "smooth"):
        if shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, not {shading!r}")
        self.geometry, self.source, self.shading = geometry, source, shading
        self._last: tuple | None = None

    def _hit(self, frame: int, camera: Camera, T_world_cam: np.ndarray) -> dict:
        key = (int(frame), camera, np.asarray(T_world_cam).tobytes())
        if self._last is None or self._last[0] != key:
            self._last = (key, self.geometry.cast(frame, camera, T_world_cam, normals=self.shading))
        return self._last[1]

    def cast(self, frame: int, camera: Camera, T_world_cam: np.ndarray) -> RayCast:
        hit = self._hit(frame, camera, T_world_cam)
        return RayCast(hit["depth"], hit["normals_cam"], hit.get("face_normals_cam"), hit["instance_ids"])

    def covers(self, frame: int, segmentation: np.ndarray) -> np.ndarray:
        return np.ones(segmentation.shape, bool)

    def moved_points(self, frame: int, other: int, camera: Camera, T_world_cam: np.ndarray) -> np.ndarray:
        """(H, W, 3) world positions at ``other`` of the points this camera sees at ``frame`` (NaN: none)."""
        hit = self._hit(frame, camera, T_world_cam)
        return self.geometry.moved_points(hit["triangle_ids"], hit["uvs"], other)


def model_oracle(dataset: Dataset, shading: str = "smooth") -> ModelOracle | None:
    """The oracle of the scene model in the dataset's scene folder (None when there is no scene.json)."""
    import json

    from rgbd2scene.groundtruth.scene_geometry import SceneGeometry
    from rgbd2scene.scene.folder import SCENE_JSON
    from rgbd2scene.scene.model import SceneDescription

    scene_dir = dataset.scene_dir
    if scene_dir is None or not (scene_dir / SCENE_JSON).is_file():
        return None
    try:
        record = json.loads((scene_dir / SCENE_JSON).read_text())
        description = SceneDescription.from_dict(record["scene"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if dataset.meta.get("scene", {}).get("scene_json_sha1") not in (None, _sha1(scene_dir / SCENE_JSON)):
        raise UserError(f"{scene_dir / SCENE_JSON}: not the scene this dataset was rendered from (its hash "
                        "differs from dataset.json's); pass --mesh to check against a mesh")
    return ModelOracle(SceneGeometry(description, scene_dir), f"scene model {scene_dir / SCENE_JSON}", shading)


def _sha1(path: Path) -> str:
    import hashlib

    return hashlib.sha1(path.read_bytes()).hexdigest()


def scene_mesh_file(dataset: Dataset, mesh_path: str | Path | None = None) -> tuple[Path | None, str]:
    """The mesh to ray cast and, when there is none, why.

    ``mesh_path`` when given (it must exist), else the scene mesh ``dataset.json`` records (``scene.mesh``,
    else ``mesh.ply`` in the scene folder ``scene.dir``; relative records are relative to the dataset).
    """
    if mesh_path is not None:
        path = Path(mesh_path)
        if not path.is_file():
            raise UserError(f"{path}: mesh file not found")
        return path, ""
    candidates = [dataset.scene_mesh] if dataset.scene_mesh is not None else []
    if dataset.scene_dir is not None:
        candidates.append(dataset.scene_dir / SCENE_MESH)
    for path in candidates:
        if path.is_file():
            return path, ""
    if not candidates:
        return None, "dataset.json names no scene mesh (scene.mesh); pass the mesh path"
    return None, f"scene mesh not found ({', '.join(str(c) for c in candidates)})"


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a mesh file (PLY, or any format Open3D reads), vertices as stored."""
    if path.suffix.lower() == ".ply":
        from rgbd2scene.files.meshio import read_ply

        mesh = read_ply(path)
        return mesh.vertices, mesh.triangles
    import open3d as o3d

    # No post-processing: it splits vertices at texture seams (an OBJ with UVs: one vertex per corner), and
    # smooth normals need the shared vertices.
    mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False)
    if not mesh.has_vertices():
        raise UserError(f"{path}: not a readable mesh (no vertices)")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles)


def scene_oracle(dataset: Dataset, mesh_path: str | Path | None = None, *, shading: str = "smooth", ids=None,
                 moving=frozenset()) -> tuple[SceneOracle | None, str]:
    """The oracle of a dataset's scene, or None and the reason there is none.

    Without ``mesh_path``, the scene model of the dataset's scene folder (:func:`model_oracle`) when it is
    there. Otherwise one static mesh (:func:`scene_mesh_file`) whose surface has the segmentation ids
    ``ids``: by default the objects of class "tissue" in the dataset's object table, else every id; objects
    in ``moving`` are never covered.
    """
    if mesh_path is None:
        oracle = model_oracle(dataset, shading)
        if oracle is not None:
            return oracle, ""
    path, reason = scene_mesh_file(dataset, mesh_path)
    if path is None:
        return None, reason
    vertices, triangles = read_mesh(path)
    if len(triangles) == 0:
        return None, f"{path}: no triangles"
    if ids is None:
        ids = {oid for oid, entry in dataset.objects.items() if entry.cls.lower() == "tissue"} or None
    return StaticMeshOracle(Raycaster(vertices, triangles), str(path), shading, ids, moving), ""
