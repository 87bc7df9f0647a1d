"""The rectified pair of a calibrated stereo rig: the one place that calls ``cv2.stereoRectify``.

A rig is two cameras ``K1, D1`` (left) and ``K2, D2`` (right), OpenCV distortion, with ``X_right = R X_left + T``
(as ``cv2.stereoCalibrate`` returns them). Its rectified pair (:func:`stereo_rectification`) is
``cv2.stereoRectify`` with zero disparity at infinity (``CALIB_ZERO_DISPARITY``): both eyes turned by R1 / R2
to parallel axes, one shared K (``P1[:3, :3]``), the right eye the baseline along x. ``alpha=0`` at the rig's
own image size is the rectified pair of CONVENTIONS 1.2 section 2 (``render --rectify``, ``calibration.yaml``,
the raw render, evaluation and ROS export all use it); a stereo capture keeps every source pixel instead
(``alpha=1``) on an image enlarged so that nothing is down-sampled (``keep_resolution``). A pair that is
already rectified is its own rectification (:meth:`Rectification.identity`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rectification:
    """``cv2.stereoRectify``'s outputs and the rectified image size (``width`` x ``height``).

    ``R1``, ``R2`` rotate each raw eye's camera frame into its rectified one (X_rect = R1 X_left); ``P1``,
    ``P2`` (3x4) project the rectified eyes; ``Q`` maps (u, v, disparity, 1) to a point; ``alpha`` as given to
    ``cv2.stereoRectify``.
    """

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    width: int
    height: int
    alpha: float = 0.0

    @classmethod
    def identity(cls, K, baseline: float, width: int, height: int) -> Rectification:
        """The rectification of a pair that is already rectified (one distortion-free K, the right eye
        ``baseline`` along x): R1 = R2 = I, P1 = [K | 0], P2 = [K | (-fx B, 0, 0)] exactly."""
        K = np.asarray(K, dtype=np.float64)
        P1 = np.hstack([K, np.zeros((3, 1))])
        P2 = P1.copy()
        P2[0, 3] = -K[0, 0] * baseline
        fx, cx, cy = K[0, 0], K[0, 2], K[1, 2]
        Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, fx], [0, 0, 1 / baseline, 0]])
        return cls(np.eye(3), np.eye(3), P1, P2, Q, int(width), int(height))

    @property
    def K(self) -> np.ndarray:
        """Intrinsics shared by both rectified images."""
        return self.P1[:3, :3].copy()

    @property
    def baseline(self) -> float:
        """Metres; the right rectified camera sits at +baseline along the left one's x axis."""
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def T_left_rectified(self) -> np.ndarray:
        """4x4 pose of the rectified left camera in the raw left camera's frame (rotation R1^T)."""
        T = np.eye(4)
        T[:3, :3] = self.R1.T
        return T

    def eye(self, eye: str) -> tuple[np.ndarray, np.ndarray]:
        """(R, P) of ``eye``: (R1, P1) for "left", (R2, P2) for "right"."""
        return (self.R1, self.P1) if eye == "left" else (self.R2, self.P2)

    def maps(self, eye: str, K, D) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (map_x, map_y, float32 (height, width)) from the raw image of ``eye`` (camera
        ``K``, distortion ``D``) to its rectified image."""
        import cv2

        R, P = self.eye(eye)
        return cv2.initUndistortRectifyMap(K, D, R, P, (self.width, self.height), cv2.CV_32FC1)

    def to_dict(self) -> dict:
        return {"R1": self.R1.tolist(), "R2": self.R2.tolist(), "P1": self.P1.tolist(), "P2": self.P2.tolist(),
                "K": self.K.tolist(), "baseline_m": self.baseline, "image_size": [self.width, self.height],
                "alpha": self.alpha}


def stereo_rectification(K1, D1, K2, D2, size: tuple[int, int], R, T, alpha: float = 0.0,
                         keep_resolution: bool = False) -> Rectification:
    """The rectified pair of the rig (see the module) whose images are ``size`` (width, height).

    ``alpha`` as in ``cv2.stereoRectify`` (0: only pixels valid in both eyes, the convention's pair; 1: every
    source pixel). The rectified image is ``size``, or with ``keep_resolution`` enlarged until its focal
    length is not below the one ``cv2.stereoRectify`` picks without scaling (``alpha=-1``: the mean fy of the
    two cameras for a horizontal pair), so that no part of the image is down-sampled.
    """
    import cv2

    args = (K1, D1, K2, D2, tuple(size), np.asarray(R, dtype=np.float64), np.asarray(T, dtype=np.float64))
    flags = cv2.CALIB_ZERO_DISPARITY
    width, height = size
    if keep_resolution:
        natural = cv2.stereoRectify(*args, flags=flags, alpha=-1)[2][0, 0]
        scaled = cv2.stereoRectify(*args, flags=flags, alpha=alpha)[2][0, 0]
        grow = max(1.0, natural / scaled)
        width, height = math.ceil(width * grow), math.ceil(height * grow)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(*args, flags=flags, alpha=alpha, newImageSize=(width, height))
    return Rectification(R1, R2, P1, P2, Q, width, height, float(alpha))
