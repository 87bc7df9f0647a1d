"""The single definition of the project's frames, pixel centres, disparity and flow signs.

Everything else calls these functions; see ``CONVENTIONS.md`` (shared contract), sections 1-3.

- Camera frame: OpenCV (x right, y down, z forward); units are metres.
- Integer pixel (u, v) = (column, row) has its centre at (u, v); a centred principal point is
  cx = (W-1)/2, cy = (H-1)/2.
- Depth is planar z; invalid values are NaN.
- Disparity d = fx*B/z > 0; a left pixel (u, v) matches the right pixel (u - d, v).
- Flow (du, dv) in pixels: p(t+1) = p(t) + flow_forward.

The pinhole functions here (``backproject``, ``pixel_rays``, ``project``) are the distortion-free case of
the camera model, :class:`rgbd2scene.geometry.camera.Camera`, which calls them for a pinhole; stages ask the camera.
"""

from __future__ import annotations

import numpy as np

CONVENTIONS_VERSION = "1.2"

#: T_blendercam_cam: Blender's camera looks down -Z with +Y up; OpenCV's looks down +Z with +Y down.
BLENDER_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u, v) of every pixel, each float64 of shape (H, W)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return u, v


def image_bounds(width: int, height: int) -> tuple[float, float, float, float]:
    """(u_min, u_max, v_min, v_max) of the image area: pixel (u, v) covers [u - 0.5, u + 0.5), so a point
    projecting to (u, v) is in a width x height image when u_min <= u < u_max and v_min <= v < v_max."""
    return -0.5, width - 0.5, -0.5, height - 0.5


def in_image(u: np.ndarray, v: np.ndarray, width: int, height: int) -> np.ndarray:
    """Bool: the projections (u, v) fall in a width x height image (:func:`image_bounds`; NaN: False)."""
    u0, u1, v0, v1 = image_bounds(width, height)
    with np.errstate(invalid="ignore"):
        return (u >= u0) & (u < u1) & (v >= v0) & (v < v1)


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Back-project a planar depth map to camera-frame points.

    Parameters
    ----------
    depth : (H, W) array
        Planar z in metres (NaN where invalid).
    K : (3, 3) array
        OpenCV intrinsics.

    Returns
    -------
    (H, W, 3) float64 array of X = (u-cx) z/fx, Y = (v-cy) z/fy, Z = z.
    """
    h, w = depth.shape
    u, v = pixel_grid(h, w)
    z = depth.astype(np.float64)
    x = (u - K[0, 2]) * z / K[0, 0]
    y = (v - K[1, 2]) * z / K[1, 1]
    return np.stack([x, y, z], axis=-1)


def pixel_rays(height: int, width: int, K: np.ndarray) -> np.ndarray:
    """Camera-frame ray directions with unit z through every pixel centre, (H, W, 3) float64."""
    return backproject(np.ones((height, width)), K)


def project(points_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (..., 3) to pixel coordinates (u, v); NaN behind the camera."""
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        z_safe = np.where(z > 0, z, np.nan)
        u = K[0, 0] * p[..., 0] / z_safe + K[0, 2]
        v = K[1, 1] * p[..., 1] / z_safe + K[1, 2]
    return u, v


def rotate(R: np.ndarray, vectors: np.ndarray, offset: np.ndarray | None = None, planar: bool = False) -> np.ndarray:
    """``vectors @ R.T (+ offset)`` for vectors (..., 3), float64.

    Written out per component: numpy's matmul with an inner dimension of 3 is 3-4 times slower on
    images and meshes (and spends more CPU than it takes wall time). Each row is summed in place in the output
    (``v0 R_i0 + v1 R_i1 + v2 R_i2 (+ offset_i)``, in this order: the same bits as the plain expression) with one
    scratch buffer: a new array per operation costs as much again (4.4 vs 1.1 ms on a 512x256 image).

    ``planar``: the result is a (..., 3) view of three contiguous component planes (3, ...), not interleaved:
    the same values, written (and, given such a view, read) a plane at a time, 2.5 times faster on an image
    (0.46 vs 1.2 ms at 512x256), for callers that go on a component at a time (the ground truth's images).
    """
    v = np.asarray(vectors, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    planes = np.empty((3,) + v.shape[:-1], dtype=np.float64) if planar else None
    out = np.moveaxis(planes, 0, -1) if planar else np.empty(v.shape, dtype=np.float64)
    term = np.empty(v.shape[:-1], dtype=np.float64)
    for i in range(3):
        row = planes[i] if planar else out[..., i]
        np.multiply(v[..., 0], R[i, 0], out=row)
        row += np.multiply(v[..., 1], R[i, 1], out=term)
        row += np.multiply(v[..., 2], R[i, 2], out=term)
        if offset is not None:
            row += offset[i]
    return out


def transform_points(T: np.ndarray, points: np.ndarray, planar: bool = False) -> np.ndarray:
    """Apply a 4x4 rigid transform to points of shape (..., 3) (``planar``: see :func:`rotate`)."""
    T = np.asarray(T, dtype=np.float64)
    return rotate(T[:3, :3], points, T[:3, 3], planar)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def opencv_pose_from_blender(T_world_blendercam: np.ndarray) -> np.ndarray:
    """T_world_cam (OpenCV axes) from a Blender camera's matrix_world."""
    return np.asarray(T_world_blendercam, dtype=np.float64) @ BLENDER_FROM_OPENCV


def blender_pose_from_opencv(T_world_cam: np.ndarray) -> np.ndarray:
    """A Blender camera's matrix_world from T_world_cam (OpenCV axes)."""
    return np.asarray(T_world_cam, dtype=np.float64) @ BLENDER_FROM_OPENCV


def disparity_from_depth(depth: np.ndarray, fx: float, baseline: float, dtype=np.float32) -> np.ndarray:
    """Disparity d = fx*B/z in pixels (``dtype``, float32 as stored; NaN where depth is NaN or not positive)."""
    z = np.asarray(depth, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(z > 0, fx * baseline / z, np.nan)
    return d.astype(dtype, copy=False)


def depth_from_disparity(disparity: np.ndarray, fx: float, baseline: float) -> np.ndarray:
    """Planar depth z = fx*B/d in metres (float32, NaN where disparity is NaN or not positive)."""
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(d > 0, fx * baseline / d, np.nan)
    return z.astype(np.float32)


def flow_from_blender_vector(vector: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward flow (H, W, 2) from Blender's 4-channel Vector pass (rows top first).

    Blender stores (X, Y) = motion towards the previous frame and (Z, W) = motion towards the next
    frame, in raster pixels with y up; the contract fixes forward = (-Z, +W), backward = (+X, -Y).
    """
    vec = np.asarray(vector, dtype=np.float32)
    forward = np.stack([-vec[..., 2], vec[..., 3]], axis=-1)
    backward = np.stack([vec[..., 0], -vec[..., 1]], axis=-1)
    return forward, backward


def flow_between_cameras(
    depth: np.ndarray, K: np.ndarray, T_world_cam_a: np.ndarray, T_world_cam_b: np.ndarray
) -> np.ndarray:
    """Flow (H, W, 2) of a static scene from camera a to camera b, given a's planar depth.

    The surface point under pixel p of a (world-fixed) moves to p + flow in b; NaN where the depth
    is NaN or the point is behind b.
    """
    pts_a = backproject(depth, K)
    T_b_a = invert_pose(T_world_cam_b) @ T_world_cam_a
    u_b, v_b = project(transform_points(T_b_a, pts_a), K)
    u_a, v_a = pixel_grid(*depth.shape)
    return np.stack([u_b - u_a, v_b - v_a], axis=-1).astype(np.float32)


def orient_normals_to_camera(normals_cam: np.ndarray, rays_cam: np.ndarray) -> np.ndarray:
    """Flip camera-frame normals so that n . ray < 0 (facing the camera)."""
    dot = np.sum(normals_cam * rays_cam, axis=-1, keepdims=True)
    return np.where(dot > 0, -normals_cam, normals_cam)
