"""A dataset folder with closed-form ground truth, written without Blender (tests, benchmarks, exporters' users).

The scene is a textured plane Z = z0 + tilt·X (world frame) that ends at X = x_edge (background beyond it), seen
by a stereo pair whose left eye translates by ``step`` metres along the world x axis every frame. Depth,
disparity, normals, flow and segmentation follow from ray/plane intersections at pixel centres through
:mod:`rgbd2scene.conventions`; the images are the plane's texture (a sum of sinusoids anchored to the plane)
sampled at the same points, so both eyes and all frames see the same surface and stereo methods can match it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd2scene import __version__
from rgbd2scene.conventions import CONVENTIONS_VERSION, flow_between_cameras, orient_normals_to_camera, pixel_rays
from rgbd2scene.dataset.layout import EYES, frame_paths, write_dataset_json, write_gt, write_rgb
from rgbd2scene.groundtruth.schema import MAPS, OPTIONAL_MAPS

PLANE_ID = 1


@dataclass(frozen=True)
class PlaneScene:
    """The synthetic scene and rig (metres, pixels)."""

    width: int = 64
    height: int = 32
    fx: float = 40.0
    baseline: float = 0.005
    z0: float = 0.05
    tilt: float = 0.2  # dZ/dX of the plane
    x_edge: float = 0.02  # the plane ends here (background beyond)
    step: float = 0.0005  # left-eye translation along world x per frame
    fps: float = 30.0
    seed: int = 0

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, (self.width - 1) / 2], [0.0, self.fx, (self.height - 1) / 2],
                         [0.0, 0.0, 1.0]])

    def pose(self, eye: str, index: int) -> np.ndarray:
        """T_world_cam of one eye: the left eye at (index·step, 0, 0), the right one baseline further along x."""
        T = np.eye(4)
        T[0, 3] = index * self.step + (self.baseline if eye == "right" else 0.0)
        return T


def _plane_points(scene: PlaneScene, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar depth (NaN off the plane) and world points (H, W, 3) of every pixel centre of a camera."""
    rays = pixel_rays(scene.height, scene.width, scene.K)  # unit z, camera frame (axes = world axes here)
    o = T_world_cam[:3, 3]
    # o_z + t r_z = z0 + tilt (o_x + t r_x)  ->  t = (z0 + tilt o_x - o_z) / (r_z - tilt r_x)
    t = (scene.z0 + scene.tilt * o[0] - o[2]) / (rays[..., 2] - scene.tilt * rays[..., 0])
    points = o + t[..., None] * rays
    on_plane = (t > 0) & (points[..., 0] < scene.x_edge)
    return np.where(on_plane, t, np.nan), points


def plane_texture(scene: PlaneScene, points: np.ndarray) -> np.ndarray:
    """RGB uint8 of the plane's texture at world points: sinusoids of 1-4 mm wavelength."""
    rng = np.random.default_rng(scene.seed)
    x, y = points[..., 0], points[..., 1]
    out = np.zeros((*x.shape, 3))
    for _ in range(6):
        k = 2 * np.pi / rng.uniform(0.001, 0.004)
        a = rng.uniform(0, np.pi)
        phase = np.sin(k * (np.cos(a) * x + np.sin(a) * y) + rng.uniform(0, 2 * np.pi))
        out += rng.uniform(10, 25, 3) * phase[..., None]
    return np.clip(128 + out, 0, 255).astype(np.uint8)


def plane_frame(scene: PlaneScene, eye: str, index: int, frames: int) -> tuple[np.ndarray, dict]:
    """(RGB uint8, ground-truth dict with every key of the schema) of one eye and frame."""
    K = scene.K
    T = scene.pose(eye, index)
    depth, points = _plane_points(scene, T)
    surface = np.isfinite(depth)
    rgb = plane_texture(scene, points)
    rgb[~surface] = 0
    normal = np.array([-scene.tilt, 0.0, 1.0]) / np.hypot(scene.tilt, 1.0)
    normals = orient_normals_to_camera(np.broadcast_to(normal, (*depth.shape, 3)),
                                       pixel_rays(scene.height, scene.width, K))
    normals = np.where(surface[..., None], normals, np.nan)
    gt = {"depth": depth.astype(np.float32),
          "disparity": (scene.fx * scene.baseline / depth).astype(np.float32),
          "normals": normals.astype(np.float32),
          "segmentation": np.where(surface, PLANE_ID, 0).astype(np.uint16)}
    for key, other in (("forward", index + 1), ("backward", index - 1)):
        if 0 <= other < frames:
            flow = flow_between_cameras(depth, K, T, scene.pose(eye, other))
            u, v = np.meshgrid(np.arange(scene.width), np.arange(scene.height))
            tu, tv = u + flow[..., 0], v + flow[..., 1]
            # static plane, pure translation: a point is hidden in the other frame only when it leaves the image
            with np.errstate(invalid="ignore"):
                gone = ~((tu > -0.5) & (tu < scene.width - 0.5) & (tv > -0.5) & (tv < scene.height - 0.5))
            occluded = surface & gone
        else:
            flow = np.full((*depth.shape, 2), np.nan, np.float32)
            occluded = np.zeros(depth.shape, bool)
        gt[f"flow_{key}"] = flow.astype(np.float32)
        gt[f"occluded_{key}"] = occluded
    gt.update(K=K, T_world_cam=T, object_ids=np.array([PLANE_ID], np.uint16),
              object_poses=np.eye(4)[None].copy())
    return rgb, gt


def write_plane_dataset(root: str | Path, frames: int = 3, scene: PlaneScene | None = None,
                        progress: bool = False) -> Path:
    """Write a complete dataset folder (CONVENTIONS §4) of the synthetic plane; returns ``root``."""
    scene = scene or PlaneScene()
    root = Path(root)
    indices = range(frames)
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc="synthetic dataset", unit="frame")
    for index in indices:
        for eye in EYES:
            rgb, gt = plane_frame(scene, eye, index, frames)
            paths = frame_paths(root, eye, index)
            write_gt(paths.gt, gt)
            write_rgb(paths.rgb, rgb)
    write_dataset_json(root, {
        "width": scene.width, "height": scene.height, "frames": frames, "fps": scene.fps,
        "baseline": scene.baseline, "K": scene.K.tolist(), "eyes": list(EYES),
        "objects": {str(PLANE_ID): {"name": "plane", "part": "", "class": "tissue", "moving": False}},
        "classes": {"tissue": 1},
        "scene": {"synthetic": "plane", "z0": scene.z0, "tilt": scene.tilt, "x_edge": scene.x_edge,
                  "step": scene.step},
        "software": {"rgbd2scene": __version__}, "seed": scene.seed, "conventions_version": CONVENTIONS_VERSION,
        "render": {"engine": "synthetic", "gt": list(MAPS) + list(OPTIONAL_MAPS)},
    })
    return root
