"""Tracks: per-frame poses of one thing in the world (the camera's left eye, an instrument), and ``look_at``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Self

import numpy as np


@dataclass
class Track:
    """Poses T_world_obj (F, 4, 4) of one object, one per frame, played at ``fps``.

    ``kind`` names how the track was made (waypoints, scan, orbit, random, static) and ``settings`` holds
    everything needed to make it again. ``pose_key`` names the poses in ``to_dict`` and in path files.
    """

    poses: np.ndarray
    fps: float = 30.0
    kind: str = "static"
    settings: dict = field(default_factory=dict)

    pose_key: ClassVar[str] = "T_world_obj"

    @property
    def frames(self) -> int:
        return int(self.poses.shape[0])

    def pose_at(self, frame: int) -> np.ndarray:
        """Pose (4, 4) at ``frame``; before the first frame and after the last the end poses hold."""
        return self.poses[min(max(int(frame), 0), self.frames - 1)]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "fps": self.fps, "frames": self.frames, "settings": self.settings,
                self.pose_key: self.poses.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Self:
        return cls(np.asarray(d[cls.pose_key], dtype=np.float64).reshape(-1, 4, 4), float(d["fps"]),
                   d.get("kind", "static"), d.get("settings", {}))


class CameraPath(Track):
    """The camera's track: left-eye poses T_world_cam (F, 4, 4), OpenCV axes."""

    pose_key: ClassVar[str] = "T_world_cam"

    @property
    def T_world_cam(self) -> np.ndarray:
        return self.poses


def look_at(position, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """T_world_cam (OpenCV axes) of a camera at ``position`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (OpenCV y points down, so the
    default (0, -1, 0) keeps the capture camera's orientation). For an object, its +z points at ``target``.
    """
    position = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - position
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, dtype=np.float64), z)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, position
    return T
