"""Camera paths: per-frame poses of the left eye (T_world_cam, OpenCV axes)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class CameraPath:
    """Left-eye poses T_world_cam (F, 4, 4), one per frame, played at ``fps``.

    ``kind`` names the generator (waypoints, scan, orbit, random, static) and ``settings`` holds
    everything needed to regenerate it.
    """

    T_world_cam: np.ndarray
    fps: float = 30.0
    kind: str = "static"
    settings: dict = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.T_world_cam.shape[0])

    def to_dict(self) -> dict:
        return {"kind": self.kind, "fps": self.fps, "frames": self.frames, "settings": self.settings,
                "T_world_cam": self.T_world_cam.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> CameraPath:
        return cls(np.asarray(d["T_world_cam"], dtype=np.float64).reshape(-1, 4, 4), float(d["fps"]),
                   d.get("kind", "static"), d.get("settings", {}))


def look_at(position, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """T_world_cam (OpenCV axes) of a camera at ``position`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (OpenCV y points down, so the
    default (0, -1, 0) keeps the capture camera's orientation).
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
