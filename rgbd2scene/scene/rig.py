"""The stereo endoscope: its calibrated pair (:class:`~rgbd2scene.geometry.stereo.StereoCalibration`) and the
clip range it renders with.

A rectified rig (:meth:`StereoRig.parallel`, the endoscope default :meth:`StereoRig.endoscope`) is Blender
multiview PARALLEL with pivot LEFT: both eyes share the left camera, R = I, T = (-B, 0, 0), so the right eye sits
+B along the left eye's x axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.stereo import StereoCalibration

#: da Vinci-class stereo endoscope: 5 mm baseline; 512x256 as in the VisionBlender dataset.
DEFAULT_BASELINE = 0.005
DEFAULT_SIZE = (512, 256)
DEFAULT_FOV_X_DEG = 70.0


@dataclass(frozen=True)
class StereoRig:
    """The scope: its ``calibration`` (both eyes, R and T) and what is the rig's own, the clip range
    ``clip_start``/``clip_end`` (metres; suits an endoscope working 1-30 cm from tissue).

    The calibration's eyes, ``baseline`` and ``rectified`` are read through the rig, as every stage asks them.
    """

    calibration: StereoCalibration
    clip_start: float = 0.001
    clip_end: float = 1.0

    @classmethod
    def parallel(cls, camera: Camera | Intrinsics, baseline: float = DEFAULT_BASELINE, clip_start: float = 0.001,
                 clip_end: float = 1.0) -> StereoRig:
        """A rectified rig: ``camera`` twice, ``baseline`` metres apart along x."""
        return cls(StereoCalibration.parallel(camera, baseline), clip_start, clip_end)

    @classmethod
    def endoscope(
        cls, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1], fov_x_deg: float = DEFAULT_FOV_X_DEG,
        baseline: float = DEFAULT_BASELINE,
    ) -> StereoRig:
        return cls.parallel(Intrinsics.from_fov(width, height, fov_x_deg), baseline)

    @property
    def left(self) -> Camera:
        return self.calibration.left

    @property
    def right(self) -> Camera:
        return self.calibration.right

    @property
    def baseline(self) -> float:
        return self.calibration.baseline

    @property
    def rectified(self) -> bool:
        return self.calibration.rectified

    def camera(self, eye: str) -> Camera:
        return self.calibration.camera(eye)

    @property
    def intrinsics(self) -> Intrinsics:
        """The left eye's pinhole part."""
        return self.left.intrinsics

    def right_pose(self, T_world_left: np.ndarray) -> np.ndarray:
        """T_world_cam of the right eye from the left eye's T_world_cam."""
        return np.asarray(T_world_left, dtype=np.float64) @ self.calibration.T_left_right

    def resized(self, width: int, height: int) -> StereoRig:
        """Both eyes sampled at ``width`` x ``height``."""
        return replace(self, calibration=self.calibration.resized(width, height))

    def to_dict(self) -> dict:
        calib = self.calibration
        out = {"intrinsics": self.left.intrinsics.to_dict(), "K": self.left.K.tolist(),
               "baseline": self.baseline, "clip_start": self.clip_start, "clip_end": self.clip_end}
        if not self.rectified:  # the rectified default stays as before (scene.json files of earlier versions)
            out.update({"D": calib.D_left.tolist(), "right": self.right.to_dict(), "R": [list(r) for r in calib.R],
                        "T": list(calib.T)})
        return out

    @classmethod
    def from_dict(cls, d: dict) -> StereoRig:
        left = Camera(Intrinsics.from_dict(d["intrinsics"]), d.get("D", ()))
        if "right" in d:
            calibration = StereoCalibration(left, Camera.from_dict(d["right"]), d["R"], d["T"])
        else:
            calibration = StereoCalibration.parallel(left, float(d["baseline"]))
        return cls(calibration, float(d["clip_start"]), float(d["clip_end"]))


def read_scope_calibration(path, size: tuple[int, int] | None = None) -> StereoRig:
    """The rig of a stereo calibration file (``--scope-calib``): an OpenCV FileStorage file, a calibration
    JSON or a Hamlyn-style folder (:func:`~rgbd2scene.capture.stereo.read_stereo_calibration`; a folder, or a
    FileStorage file without ``image_width``/``image_height``, takes its image size from ``size``).

    One-line :class:`UserError` naming the file and the problem (the key of a bad value, a lens folding near
    the centre); a lens folding inside the image is a printed warning.
    """
    from pathlib import Path

    from rgbd2scene.capture.stereo import read_stereo_calibration
    from rgbd2scene.errors import UserError

    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: calibration file not found")
    try:
        return StereoRig(read_stereo_calibration(path, size))
    except (ValueError, OSError) as exc:
        raise UserError(f"{path}: {exc}") from None
