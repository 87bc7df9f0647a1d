"""The stereo endoscope: two cameras and the transform between them.

``X_right = R X_left + T`` (as ``cv2.stereoCalibrate`` returns them). The default, a rectified pair, is
Blender multiview PARALLEL with pivot LEFT: both eyes share the left camera, R = I, T = (-B, 0, 0), so the
right eye sits +B along the left eye's x axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.geometry.camera import Camera, Intrinsics
from rgbd2scene.geometry.rectification import Rectification, stereo_rectification

#: da Vinci-class stereo endoscope: 5 mm baseline; 512x256 as in the VisionBlender dataset.
DEFAULT_BASELINE = 0.005
DEFAULT_SIZE = (512, 256)
DEFAULT_FOV_X_DEG = 70.0
#: R must be a rotation within this (max entry of R^T R - I, and |det R - 1|).
ROTATION_TOLERANCE = 1e-6


@dataclass(frozen=True)
class StereoRig:
    """A stereo pair: the ``left`` camera (an ``Intrinsics`` is taken as a distortion-free camera), the
    ``right`` one (None: the same as the left) and ``R``, ``T`` (None: I and (-baseline, 0, 0)).

    ``baseline`` is |T| (given T, it is derived from it). ``clip_start``/``clip_end`` (metres) suit an
    endoscope working 1-30 cm from tissue.
    """

    left: Camera
    baseline: float = DEFAULT_BASELINE
    clip_start: float = 0.001
    clip_end: float = 1.0
    right: Camera | None = None
    R: tuple | None = None
    T: tuple | None = None

    def __post_init__(self):
        if isinstance(self.left, Intrinsics):
            object.__setattr__(self, "left", Camera(self.left))
        if self.right is None:
            object.__setattr__(self, "right", self.left)
        elif isinstance(self.right, Intrinsics):
            object.__setattr__(self, "right", Camera(self.right))
        R = np.eye(3) if self.R is None else np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        T = (np.array([-float(self.baseline), 0.0, 0.0]) if self.T is None
             else np.asarray(self.T, dtype=np.float64).reshape(3))
        object.__setattr__(self, "R", tuple(map(tuple, R.tolist())))
        object.__setattr__(self, "T", tuple(T.tolist()))
        object.__setattr__(self, "baseline", float(np.linalg.norm(T)))

    @classmethod
    def endoscope(
        cls, width: int = DEFAULT_SIZE[0], height: int = DEFAULT_SIZE[1], fov_x_deg: float = DEFAULT_FOV_X_DEG,
        baseline: float = DEFAULT_BASELINE,
    ) -> StereoRig:
        return cls(Camera(Intrinsics.from_fov(width, height, fov_x_deg)), baseline)

    @property
    def intrinsics(self) -> Intrinsics:
        """The left eye's pinhole part."""
        return self.left.intrinsics

    def camera(self, eye: str) -> Camera:
        return self.left if eye == "left" else self.right

    @property
    def rectified(self) -> bool:
        """Both eyes are one distortion-free camera side by side along x (R = I, T = (-B, 0, 0))."""
        return (self.left.is_pinhole and self.right == self.left and np.array_equal(self.R, np.eye(3))
                and self.T[1] == 0.0 and self.T[2] == 0.0 and self.T[0] < 0)

    @property
    def T_left_right(self) -> np.ndarray:
        """Pose of the right eye in the left eye's (OpenCV) frame: the inverse of [R | T]."""
        R, T = np.asarray(self.R), np.asarray(self.T)
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ T
        return out

    def right_pose(self, T_world_left: np.ndarray) -> np.ndarray:
        """T_world_cam of the right eye from the left eye's T_world_cam."""
        return np.asarray(T_world_left, dtype=np.float64) @ self.T_left_right

    @classmethod
    def from_calibration(cls, values: dict) -> StereoRig:
        """The calibrated pair of a stereo calibration's values (``image_size``, ``K_left``, ``D_left``,
        ``K_right``, ``D_right``, ``R``, ``T``: :meth:`~rgbd2scene.capture.stereo.StereoCalibration.to_dict`, as
        a stereo capture records them). A missing key is a ``KeyError``, a malformed value a ``ValueError``."""
        width, height = (int(v) for v in values["image_size"])
        return cls(Camera(Intrinsics.from_K(values["K_left"], width, height), values["D_left"]), 0.0,
                   right=Camera(Intrinsics.from_K(values["K_right"], width, height), values["D_right"]),
                   R=values["R"], T=values["T"])

    def resized(self, width: int, height: int) -> StereoRig:
        """Both eyes sampled at ``width`` x ``height`` (the right eye scaled as the left)."""
        sx, sy = width / self.left.width, height / self.left.height
        right = self.right.resized(round(self.right.width * sx), round(self.right.height * sy))
        return StereoRig(self.left.resized(width, height), self.baseline, self.clip_start, self.clip_end,
                         right, self.R, self.T)

    def check(self, source: str = "rig") -> list[str]:
        """Raise ``UserError`` for a bad rig (a camera, or an R that is not a rotation); return warnings."""
        from rgbd2scene.errors import UserError

        R, T = np.asarray(self.R), np.asarray(self.T)
        if not (np.isfinite(R).all() and np.isfinite(T).all()):
            raise UserError(f"{source}: R and T must be finite")
        if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or abs(np.linalg.det(R) - 1) > ROTATION_TOLERANCE:
            raise UserError(f"{source}: R is not a rotation (R^T R - I up to {np.abs(R.T @ R - np.eye(3)).max():.2g}, "
                            f"det {np.linalg.det(R):.6g})")
        if not self.baseline > 0:
            raise UserError(f"{source}: the baseline |T| must be positive")
        warnings = [self.left.check(f"{source} (left)")]
        if self.right is not self.left:
            warnings.append(self.right.check(f"{source} (right)"))
        return [w for w in warnings if w]

    def to_dict(self) -> dict:
        out = {"intrinsics": self.left.intrinsics.to_dict(), "K": self.left.K.tolist(),
               "baseline": self.baseline, "clip_start": self.clip_start, "clip_end": self.clip_end}
        if not self.rectified:  # the rectified default stays as before (scene.json files of earlier versions)
            out.update({"D": list(self.left.D), "right": self.right.to_dict(), "R": [list(r) for r in self.R],
                        "T": list(self.T)})
        return out

    @classmethod
    def from_dict(cls, d: dict) -> StereoRig:
        left = Camera(Intrinsics.from_dict(d["intrinsics"]), d.get("D", ()))
        right = Camera.from_dict(d["right"]) if "right" in d else None
        return cls(left, float(d["baseline"]), float(d["clip_start"]), float(d["clip_end"]), right,
                   d.get("R"), d.get("T"))


def rectification(rig: StereoRig) -> Rectification:
    """The rectified pair of ``rig`` as ``cv2.stereoRectify(alpha=0)`` defines it at the rig's image size
    (CONVENTIONS 1.2, section 2; :func:`~rgbd2scene.geometry.rectification.stereo_rectification`).

    A rectified rig is its own rectification: R1 = R2 = I, P1 = [K | 0], P2 = [K | (-fx B, 0, 0)]
    (:meth:`~rgbd2scene.geometry.rectification.Rectification.identity`).
    """
    size = (rig.left.width, rig.left.height)
    if rig.rectified:
        return Rectification.identity(rig.left.K, rig.baseline, *size)
    return stereo_rectification(rig.left.K, rig.left.distortion, rig.right.K, rig.right.distortion, size,
                                np.asarray(rig.R), np.asarray(rig.T))


def read_scope_calibration(path, size: tuple[int, int] | None = None) -> StereoRig:
    """The rig of a stereo calibration file (``--scope-calib``): two eyes with their own K and D, and R, T
    (``X_right = R X_left + T``, metres).

    Accepts an OpenCV FileStorage file (``.yaml``/``.yml``/``.xml``: ``K1 D1 K2 D2 R T`` and ``image_width``,
    ``image_height`` or ``size``), a calibration JSON or a Hamlyn-style folder (as ``--stereo-calib`` reads
    them; a folder takes its image size from ``size``). One-line :class:`UserError` naming the file and
    the problem: missing keys, an R that is not a rotation, non-finite values, a lens folding near the
    centre. A lens folding inside the image is a printed warning.
    """
    from pathlib import Path

    from rgbd2scene.capture.stereo import (
        OPENCV_CALIB_KEYS,
        make_calibration,
        read_opencv_calibration,
        read_stereo_calibration,
    )
    from rgbd2scene.errors import UserError
    from rgbd2scene.geometry.camera import warn

    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: calibration file not found")
    try:
        if path.suffix.lower() in (".yaml", ".yml", ".xml"):
            nodes = read_opencv_calibration(path)
            if nodes is None:
                raise ValueError("not an OpenCV FileStorage file")
            missing = [key for key in OPENCV_CALIB_KEYS if nodes.get(key) is None]
            if missing:
                raise ValueError(f"missing key(s) {', '.join(missing)} (a calibration holds "
                                 f"{' '.join(OPENCV_CALIB_KEYS)} and image_width, image_height)")
            file_size = ((int(nodes["image_width"]), int(nodes["image_height"]))
                         if "image_width" in nodes and "image_height" in nodes else None)
            width, height = file_size or size or (0, 0)
            if not width:
                raise ValueError("no image size (image_width and image_height)")
            calib = make_calibration(*(np.asarray(nodes[key], dtype=np.float64) for key in OPENCV_CALIB_KEYS),
                                     width, height)
        else:
            calib = read_stereo_calibration(path, size)
    except (ValueError, OSError) as exc:
        raise UserError(f"{path}: {exc}") from None
    rig = StereoRig.from_calibration(calib.to_dict())
    for message in rig.check(str(path)):
        warn(message)
    return rig
