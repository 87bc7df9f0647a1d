"""``occlusion``: the ``occluded_forward`` / ``occluded_backward`` flags agree with the geometry.

Each surface point is moved into the next / previous frame of the same eye (with the scene model as oracle:
followed with its moving or deforming surface; otherwise with the camera only, static surface only) and
looked up in that frame's rendered depth at the four pixel centres around it: where one matches and none is
clearly nearer, the point is clearly visible; where every one is clearly nearer, or the point leaves the image,
it is clearly hidden. A flag that contradicts a clear case counts. The cases in between are not judged: the
four centres straddle an occluding edge there, and depth samples alone don't tell on which side of the edge
a point between them falls (judged, they were a one-pixel band of false contradictions along every edge that
moves over the surface).
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.conventions import invert_pose, transform_points
from rgbd2scene.geometry.camera import Camera
from rgbd2scene.verify.framework import Check, EyeFrame

#: flag map -> step to the other frame
DIRECTIONS = {"occluded_forward": 1, "occluded_backward": -1}


class OcclusionCheck(Check):
    names = ("occlusion",)
    maps = tuple(DIRECTIONS)

    def check_eye(self, frame: EyeFrame) -> None:
        for key, step in DIRECTIONS.items():
            flags, other = frame.map(key), frame.index + step
            if flags is None or not 0 <= other <= frame.run.last:
                continue
            T_other, depth_other = frame.pose(other), frame.depth_at(other)
            if T_other is None or depth_other is None:
                continue
            moved = frame.moved_points(other)
            if moved is None:  # the static scene moved with the camera
                moved = transform_points(frame.T_world_cam,
                                         frame.camera.backproject(np.where(frame.surface, frame.depth, np.nan)))
            moved = np.where(frame.surface[..., None], moved, np.nan)
            visible, hidden = occlusion_reference(moved, frame.camera, T_other, depth_other,
                                                  frame.run.tol.occlusion_rel)
            flags = flags.astype(bool)
            wrong = ((flags & visible) | (~flags & hidden)) & frame.static
            if frame.surface.any():
                frame.add("occlusion", f"{key} contradicting geometry (frac)", float(wrong.sum() / frame.surface.sum()),
                          frame.run.tol.occlusion_disagree)


def occlusion_reference(points: np.ndarray, camera: Camera, T_b: np.ndarray, depth_b: np.ndarray,
                        rel: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixels whose surface point (at its position in frame b) is clearly visible / clearly hidden (or
    outside) in camera b.

    Clearly visible: one of camera b's four depth samples around the point's projection matches its depth and
    none is clearly nearer. Clearly hidden: all four are clearly nearer, or the point projects outside.

    Parameters
    ----------
    points : (H, W, 3) world positions in frame b of the points under each pixel, NaN where no surface.
    camera : the eye's camera; T_b : (4, 4) camera b's T_world_cam.
    depth_b : (H, W) planar depth of camera b.
    rel : relative depth difference that separates visible from hidden.

    Returns
    -------
    visible, hidden : bool (H, W) each.
    """
    h, w = points.shape[:2]
    surface = np.all(np.isfinite(points), axis=-1)
    pts = transform_points(invert_pose(T_b), points)
    z = pts[..., 2]
    u, v = camera.project(pts)
    outside = surface & ~camera.in_image(u, v)
    inside = surface & ~outside
    u0 = np.clip(np.floor(np.nan_to_num(u)), 0, w - 2).astype(np.int64) if w > 1 else np.zeros((h, w), int)
    v0 = np.clip(np.floor(np.nan_to_num(v)), 0, h - 2).astype(np.int64) if h > 1 else np.zeros((h, w), int)
    zs = np.stack([depth_b[np.minimum(v0 + dv, h - 1), np.minimum(u0 + du, w - 1)]
                   for dv in (0, 1) for du in (0, 1)], axis=-1).astype(np.float64)
    with np.errstate(invalid="ignore"):
        close = np.any(np.abs(zs - z[..., None]) <= rel * z[..., None], axis=-1)
        nearer = zs < (z * (1 - rel))[..., None]  # NaN compares False: nothing there hides the point
    return inside & close & ~nearer.any(axis=-1), outside | (inside & nearer.all(axis=-1))
