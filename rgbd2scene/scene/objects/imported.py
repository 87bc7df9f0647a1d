"""User meshes in the scene: files (OBJ, PLY, STL, GLB/glTF, OFF via trimesh) in metres, poses and motions.

A mesh file is read as it is stored (no axis conversion; ``scale`` turns its units into metres, e.g. 0.001
for millimetres, and ``recenter`` moves its bounding-box centre to its origin) with its vertex colours, or
its UVs and texture image where it has them. Its pose is a rigid 4x4 ``T_world_obj`` (OpenCV world frame)
given as a matrix or as a position with a rotation (quaternion x y z w, Euler angles in degrees in a
SciPy axis order, or a 3x3 matrix). A motion is keyframes (frame -> pose) or a path file like the
camera's, interpolated by :mod:`rgbd2scene.scene.paths.waypoints` (C2 position spline and rotation
spline; linear and slerp between two keys; held before the first key and after the last).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.conventions import invert_pose, transform_points
from rgbd2scene.geometry.mesh import Mesh
from rgbd2scene.scene.paths.track import CameraPath, Track
from rgbd2scene.scene.paths.waypoints import load_path_file, pose_matrix, waypoint_path
from rgbd2scene.scene.rig import StereoRig

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Vertices projected per frame when checking that an object enters the view (a seeded subset of larger meshes).
VIEW_CHECK_VERTICES = 4000


@dataclass
class ImportedMesh:
    """A user's mesh in metres in its own frame, with its texture image (RGB uint8) when it has UVs and one."""

    mesh: Mesh
    texture: np.ndarray | None = None
    source: str = ""


def read_mesh_file(path: str | Path, scale: float = 1.0, recenter: bool = False) -> ImportedMesh:
    """Read a triangle mesh file; ``ValueError`` naming the file when it is missing or unreadable."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: mesh file not found")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh format {path.suffix!r} (use {', '.join(MESH_SUFFIXES)})")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale}")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds for a bad file
        raise ValueError(f"{path}: not a readable mesh ({type(exc).__name__}: {exc})") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"{path}: holds no triangles")
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: has NaN or infinite vertex coordinates")
    vertices = vertices * float(scale)
    if recenter:
        vertices -= 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    colors = uvs = texture = None
    visual = loaded.visual
    if visual.kind in ("vertex", "face"):
        colors = np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)
    elif visual.kind == "texture" and getattr(visual, "uv", None) is not None and len(visual.uv) == len(vertices):
        image = _texture_image(visual.material)
        if image is not None:
            uvs = np.asarray(visual.uv, dtype=np.float32)
            texture = image
    mesh = Mesh(vertices=vertices, triangles=faces.astype(np.int32), vertex_colors=colors, uvs=uvs)
    return ImportedMesh(mesh, texture, str(path))


def _texture_image(material) -> np.ndarray | None:
    """The material's colour texture as RGB uint8 (OBJ/MTL ``map_Kd`` or glTF base colour), or None."""
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    return np.asarray(image.convert("RGB"), dtype=np.uint8)


def read_texture(path: str | Path) -> np.ndarray:
    """An image file as RGB uint8; ``ValueError`` naming the file when it is missing or unreadable."""
    from rgbd2scene.files.images import read_image

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: texture file not found")
    image = read_image(path)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return image


def rigid_pose(matrix=None, position=None, quaternion=None, euler_deg=None, euler_order: str = "xyz",
               rotation=None, where: str = "pose") -> np.ndarray:
    """A 4x4 pose from a matrix, or from a position (default 0) and at most one rotation: ``quaternion``
    (x, y, z, w, unit), ``euler_deg`` (degrees, SciPy ``euler_order``: lower case extrinsic, upper case
    intrinsic) or ``rotation`` (3x3, orthonormal). ``ValueError`` starting with ``where`` when it is not rigid."""
    from scipy.spatial.transform import Rotation

    rotations = [r for r in (quaternion, euler_deg, rotation) if r is not None]
    if matrix is not None:
        if position is not None or rotations:
            raise ValueError(f"{where}: give a matrix or a position and rotation, not both")
        return pose_matrix(matrix, where, "matrix")
    if len(rotations) > 1:
        raise ValueError(f"{where}: give one rotation (quaternion, euler_deg or rotation), not several")
    T = np.eye(4)
    if position is not None:
        p = np.asarray(position, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"{where}: position must be 3 finite numbers, got {position!r}")
        T[:3, 3] = p
    if quaternion is not None:
        q = np.asarray(quaternion, dtype=np.float64)
        if q.shape != (4,) or not np.isfinite(q).all() or abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise ValueError(f"{where}: quaternion must be 4 numbers x, y, z, w of unit length, got {quaternion!r}")
        T[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    elif euler_deg is not None:
        try:
            T[:3, :3] = Rotation.from_euler(euler_order, np.asarray(euler_deg, dtype=np.float64),
                                            degrees=True).as_matrix()
        except ValueError as exc:
            raise ValueError(f"{where}: bad euler_deg {euler_deg!r} / euler_order {euler_order!r} ({exc})") from None
    elif rotation is not None:
        R = np.eye(4)
        try:
            R[:3, :3] = np.asarray(rotation, dtype=np.float64)
        except ValueError:
            raise ValueError(f"{where}: rotation must be a 3x3 matrix") from None
        T[:3, :3] = pose_matrix(R, where, "rotation")[:3, :3]
    return T


def keyframe_poses(keys: list[tuple[int, np.ndarray]], frames: int, fps: float, where: str) -> np.ndarray:
    """(F, 4, 4) poses through keyframes ``(frame, T_world_obj)`` (the waypoint machinery: frames strictly
    increasing inside 0..F-1)."""
    waypoints = [{Track.pose_key: T, "frame": f} for f, T in keys]
    return waypoint_path(waypoints, frames, fps, where=where, track_type=Track).poses


def path_file_poses(path: str | Path, frames: int) -> np.ndarray:
    """(F, 4, 4) poses of an object path file (``T_world_obj`` or position/look_at waypoints), held after
    its last frame and cut at the scene's last."""
    poses = load_path_file(path, track_type=Track).poses
    if len(poses) < frames:
        poses = np.concatenate([poses, np.repeat(poses[-1:], frames - len(poses), axis=0)])
    return poses[:frames]


def frames_in_view(vertices: np.ndarray, poses: np.ndarray, rig: StereoRig, path: CameraPath) -> np.ndarray:
    """(F,) bool: some vertex of the object (in its own frame, posed per frame) projects inside either eye's
    image within the clip range."""
    v = np.asarray(vertices, dtype=np.float64)
    if len(v) > VIEW_CHECK_VERTICES:
        v = v[np.random.default_rng(0).choice(len(v), VIEW_CHECK_VERTICES, replace=False)]
    out = np.zeros(path.frames, bool)
    for f in range(path.frames):
        world = transform_points(poses[min(f, len(poses) - 1)], v)
        left = np.asarray(path.T_world_cam[f], dtype=np.float64)
        for T, camera in ((left, rig.left), (rig.right_pose(left), rig.right)):
            p = transform_points(invert_pose(T), world)
            u, w = camera.project(p)
            with np.errstate(invalid="ignore"):
                ok = (p[:, 2] >= rig.clip_start) & (p[:, 2] <= rig.clip_end) & camera.in_image(u, w)
            out[f] |= bool(ok.any())
    return out
