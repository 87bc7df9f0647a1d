"""The stereo endoscope: a rectified pair sharing K, the right eye +baseline along the left x axis."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.capture.camera import Intrinsics

#: da Vinci-class stereo endoscope: 5 mm baseline; 512x256 as in the VisionBlender dataset.
DEFAULT_BASELINE = 0.005
DEFAULT_SIZE = (512, 256)
DEFAULT_FOV_X_DEG = 70.0


@dataclass(frozen=True)
class StereoRig:
    """Rectified stereo pair (Blender multiview PARALLEL, pivot LEFT): both eyes share ``intrinsics``.

    ``clip_start``/``clip_end`` (metres) suit an endoscope working 1-30 cm from tissue.
    """

    intrinsics: Intrinsics
    baseline: float = DEFAULT_BASELINE
    clip_start: float = 0.001
    clip_end: float = 1.0

    @classmethod
    def endoscope(
        cls, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1], fov_x_deg: float = DEFAULT_FOV_X_DEG,
        baseline: float = DEFAULT_BASELINE,
    ) -> StereoRig:
        return cls(Intrinsics.from_fov(width, height, fov_x_deg), baseline)

    @property
    def T_left_right(self) -> np.ndarray:
        """Pose of the right eye in the left eye's (OpenCV) frame."""
        T = np.eye(4)
        T[0, 3] = self.baseline
        return T

    def right_pose(self, T_world_left: np.ndarray) -> np.ndarray:
        """T_world_cam of the right eye from the left eye's T_world_cam."""
        return np.asarray(T_world_left, dtype=np.float64) @ self.T_left_right

    def resized(self, width: int, height: int) -> StereoRig:
        return StereoRig(self.intrinsics.resized(width, height), self.baseline, self.clip_start, self.clip_end)

    def to_dict(self) -> dict:
        return {"intrinsics": self.intrinsics.to_dict(), "K": self.intrinsics.K.tolist(),
                "baseline": self.baseline, "clip_start": self.clip_start, "clip_end": self.clip_end}

    @classmethod
    def from_dict(cls, d: dict) -> StereoRig:
        return cls(Intrinsics.from_dict(d["intrinsics"]), float(d["baseline"]), float(d["clip_start"]),
                   float(d["clip_end"]))
