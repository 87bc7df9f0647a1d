"""How a raw (distorted, unequal-eyed) stereo pair is rendered with a pinhole renderer (no ``bpy``).

Blender renders pinholes only. A raw pair (CONVENTIONS 1.2: the scope's own distortion and eyes, images in
the distorted pixel grid) is rendered as the rectified pair of the same rig (``cv2.stereoRectify``, alpha 0:
both eyes rotated by R1 / R2 to parallel axes, the right eye the baseline along x), with one shared pinhole
K that covers every raw pixel's ray of both eyes (:func:`raw_render_plan`), then each raw pixel takes the
rectified image's value where its own ray lands (``cv2.remap``, bilinear). Only the RGB images go through
this resampling: the ground-truth maps are computed exactly along each raw pixel's ray from the scene model
(:mod:`rgbd2scene.groundtruth.model_maps`). Pixels without a ray (beyond a lens fold) are black.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.geometry.rectification import Rectification
from rgbd2scene.scene.rig import StereoRig

#: Border (pixels of the rectified render) kept around the raw rays, for the bilinear lookup.
BORDER_PX = 2


@dataclass
class RawRender:
    """The rectified render that a raw pair is resampled from.

    ``intrinsics``: the shared pinhole of the render (both eyes); ``R_rect``: per eye, the rotation from
    the raw eye's camera frame to the rectified one (``cv2.stereoRectify``'s R1, R2); ``maps``: per eye,
    (map_x, map_y) float32 (H, W) for ``cv2.remap`` (NaN-free: pixels without a ray point outside).
    """

    intrinsics: Intrinsics
    R_rect: dict[str, np.ndarray]
    maps: dict[str, tuple[np.ndarray, np.ndarray]]
    has_ray: dict[str, np.ndarray]

    def rectified_pose(self, T_world_left: np.ndarray) -> np.ndarray:
        """T_world_cam of the rectified left eye (the render's camera) from the raw left eye's pose."""
        T = np.eye(4)
        T[:3, :3] = self.R_rect["left"].T
        return np.asarray(T_world_left, dtype=np.float64) @ T

    def resample(self, image: np.ndarray, eye: str) -> np.ndarray:
        """A rectified render of ``eye`` (H', W'[, C], any dtype OpenCV remaps: uint8, float32 linear light)
        -> the raw image (H, W[, C]); black where a pixel has no ray."""
        import cv2

        map_x, map_y = self.maps[eye]
        out = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out[~self.has_ray[eye]] = 0
        return out


def raw_render_plan(rig: StereoRig, supersample: float = 1.0) -> RawRender:
    """The rectified render covering every raw pixel's ray of ``rig``'s two eyes.

    Its focal length is ``supersample`` times the largest of the eyes' focal lengths (square pixels); its
    image is the smallest that holds every ray's projection plus :data:`BORDER_PX`.
    """
    rect = rig.calibration.rectification()
    R_rect = {"left": np.asarray(rect.R1, dtype=np.float64), "right": np.asarray(rect.R2, dtype=np.float64)}
    f = float(supersample) * max(rig.left.K[0, 0], rig.left.K[1, 1], rig.right.K[0, 0], rig.right.K[1, 1])
    normalised, has_ray = {}, {}
    for eye in ("left", "right"):
        rays = rig.camera(eye).rays()
        ok = np.isfinite(rays[..., 0])
        r = rays @ R_rect[eye].T
        with np.errstate(invalid="ignore", divide="ignore"):
            normalised[eye] = (r[..., 0] / r[..., 2], r[..., 1] / r[..., 2])
        has_ray[eye] = ok & (r[..., 2] > 0)
    xs = np.concatenate([normalised[e][0][has_ray[e]] for e in normalised])
    ys = np.concatenate([normalised[e][1][has_ray[e]] for e in normalised])
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    cx, cy = BORDER_PX - x0 * f, BORDER_PX - y0 * f
    width = int(math.ceil(x1 * f + cx)) + BORDER_PX + 1
    height = int(math.ceil(y1 * f + cy)) + BORDER_PX + 1
    intrinsics = Intrinsics(width, height, f, f, cx, cy)
    maps = {}
    for eye, (x, y) in normalised.items():
        map_x = np.where(has_ray[eye], f * x + cx, -10.0).astype(np.float32)
        map_y = np.where(has_ray[eye], f * y + cy, -10.0).astype(np.float32)
        maps[eye] = (map_x, map_y)
    return RawRender(intrinsics, R_rect, maps, has_ray)


def rectified_rig(rig: StereoRig) -> tuple[StereoRig, Rectification]:
    """The rectified pair of a raw rig (``render --rectify``): both eyes ``P1[:3, :3]``, no distortion, the
    baseline |T| along x; and the rig's rectification (R1 turns the raw left eye's frame into the rectified
    one: ``T_left_rectified``)."""
    rect = rig.calibration.rectification()
    camera = Intrinsics.from_K(rect.K, rig.left.width, rig.left.height)
    return StereoRig.parallel(camera, rig.baseline, rig.clip_start, rig.clip_end), rect
