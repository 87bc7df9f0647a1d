"""A calibrated stereo pair: two cameras of the one camera model and the transform between them.

``X_right = R X_left + T`` (metres, as ``cv2.stereoCalibrate`` returns them). Both eyes see images of one
size. A rectified pair (:meth:`StereoCalibration.parallel`) is one distortion-free camera twice, the right eye
the baseline along the left eye's x axis: R = I, T = (-B, 0, 0) (Blender multiview PARALLEL, pivot LEFT).

:meth:`StereoCalibration.from_matrices` is the one validation of a calibration given as matrices (the file
readers of :mod:`rgbd2scene.capture.stereo` all end there): each failure is a ``ValueError`` naming the key.
The camera model has no skew, so a K with skew is refused rather than silently dropped; an ideal lens is
recorded as 5 zeros (CONVENTIONS section 3: "zeros for an ideal pinhole").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.geometry.camera import DISTORTION_LENGTHS, Camera, Intrinsics, warn
from rgbd2scene.geometry.rectification import Rectification, stereo_rectification

#: Numbers of distortion coefficients a calibration may give (OpenCV's models; an ideal lens is 5 zeros).
DISTORTION_SIZES = tuple(n for n in DISTORTION_LENGTHS if n)
#: Names of the matrices in a calibration JSON and :meth:`StereoCalibration.to_dict`, in the order
#: K_left, D_left, K_right, D_right, R, T; a reader of another format names them its own way.
JSON_KEYS = ("K_left", "D_left", "K_right", "D_right", "R", "T")
#: The image size keys of a calibration JSON, and the keys it may hold besides (what OpenCV's calibration and
#: :meth:`StereoCalibration.to_dict` also report: kept in the file, not used).
SIZE_KEYS = ("image_size", "width", "height")
INFO_KEYS = ("baseline_m", "rms", "E", "F", "R1", "R2", "P1", "P2", "Q")
#: R must be a rotation within this (max entry of R^T R - I, with det R > 0).
ROTATION_TOLERANCE = 1e-6
#: A given R off a rotation by more than :data:`ROTATION_TOLERANCE` but at most this (a calibration written as
#: text with 4-6 decimals: Hamlyn's ``calib.l2r.4x4`` files are off by up to 1.5e-6) is replaced by the nearest
#: rotation, so that the right eye's pose stays rigid; beyond it, it is refused.
ROTATION_SNAP = 1e-3
#: Largest skew |K[0, 1]| taken as none, relative to fx (the camera model has no skew).
SKEW_TOLERANCE = 1e-6
#: Plausible baselines |T| (metres): 0.1 mm to 1 m.
BASELINE_RANGE = (1e-4, 1.0)


@dataclass(frozen=True)
class StereoCalibration:
    """The calibrated pair: ``left`` and ``right`` cameras of one image size, ``R`` (3x3, rows) and ``T``
    (metres) with ``X_right = R X_left + T``. An ``Intrinsics`` is taken as a distortion-free camera."""

    left: Camera
    right: Camera
    R: tuple[tuple[float, float, float], ...]
    T: tuple[float, float, float]

    def __post_init__(self):
        for eye in ("left", "right"):
            if isinstance(getattr(self, eye), Intrinsics):
                object.__setattr__(self, eye, Camera(getattr(self, eye)))
        object.__setattr__(self, "R", tuple(map(tuple, np.asarray(self.R, dtype=np.float64).reshape(3, 3).tolist())))
        object.__setattr__(self, "T", tuple(np.asarray(self.T, dtype=np.float64).reshape(3).tolist()))
        if (self.right.width, self.right.height) != (self.left.width, self.left.height):  # resized() keeps one size
            raise ValueError(f"the eyes' images differ in size ({self.left.width}x{self.left.height} and "
                             f"{self.right.width}x{self.right.height})")

    @classmethod
    def parallel(cls, camera: Camera | Intrinsics, baseline: float) -> StereoCalibration:
        """The rectified pair of ``camera``, ``baseline`` metres apart along x."""
        return cls(camera, camera, np.eye(3), (-float(baseline), 0.0, 0.0))

    @classmethod
    def from_matrices(cls, K_left, D_left, K_right, D_right, R, T, width: int, height: int,
                      keys: tuple[str, ...] = JSON_KEYS, source: str | None = None) -> StereoCalibration:
        """The checked calibration of these matrices: a ``ValueError`` names the key (``keys``, in the order of
        :data:`JSON_KEYS`) and the problem (not numbers, wrong size, non-finite, skew, not a rotation,
        implausible cameras, baseline or layout). A lens folding inside the image is a printed warning, prefixed
        with ``source`` (the file)."""
        k_left, d_left, k_right, d_right, r_key, t_key = keys
        width, height = int(width), int(height)
        if width <= 0 or height <= 0:
            raise ValueError(f"image size {width}x{height} is not positive")
        cameras = [Camera(_intrinsics(K, k, width, height), _distortion(D, d))
                   for K, D, k, d in ((K_left, D_left, k_left, d_left), (K_right, D_right, k_right, d_right))]
        R = _matrix(R, (3, 3), r_key)
        off = _rotation_error(R)
        if ROTATION_TOLERANCE < off <= ROTATION_SNAP:
            R = _nearest_rotation(R)
            warn(f"{source + ': ' if source else ''}{r_key} is off a rotation by {off:.2g} (rounded text?); "
                 "the nearest rotation is used")
        calib = cls(*cameras, R, _matrix(T, (3,), t_key))
        for message in calib.check(keys):
            warn(f"{source}: {message}" if source else message)
        return calib

    def check(self, keys: tuple[str, ...] = JSON_KEYS) -> list[str]:
        """Raise ``ValueError`` naming the key (``keys`` as in :meth:`from_matrices`) for an implausible
        calibration; return the warnings (a lens folding inside the image)."""
        k_left, d_left, k_right, d_right, r_key, t_key = keys
        R, T = np.asarray(self.R), np.asarray(self.T)
        for key, value in ((r_key, R), (t_key, T)):
            if not np.isfinite(value).all():
                raise ValueError(f"{key} contains non-finite values")
        if _rotation_error(R) > ROTATION_TOLERANCE:
            raise ValueError(f"{r_key} is not a rotation (R^T R - I up to {np.abs(R.T @ R - np.eye(3)).max():.2g}, "
                             f"det {np.linalg.det(R):.6g})")
        low, high = BASELINE_RANGE
        if not low <= self.baseline <= high:
            hint = " (T must be in metres; millimetres?)" if self.baseline > high else ""
            raise ValueError(f"{t_key}: baseline |T| = {self.baseline:.4g} m is implausible{hint}")
        if abs(T[0]) < abs(T[1]):
            raise ValueError(f"{t_key}: the cameras are stacked vertically (|T_y| > |T_x|); only side-by-side pairs "
                             "are supported")
        if T[0] > 0:
            raise ValueError(f"{t_key}: T_x > 0 puts the right camera left of the left one: are left and right "
                             "swapped?")
        warnings = []
        for camera, k, d in ((self.left, k_left, d_left), (self.right, k_right, d_right)):
            try:
                camera.intrinsics.check(k)
                warnings.append(camera.check(d))
            except UserError as exc:
                raise ValueError(str(exc)) from None
        return [w for w in warnings if w]

    # -- the pair --
    @property
    def width(self) -> int:
        return self.left.width

    @property
    def height(self) -> int:
        return self.left.height

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    @property
    def baseline(self) -> float:
        """|T|, metres."""
        return float(np.linalg.norm(self.T))

    @property
    def K_left(self) -> np.ndarray:
        return self.left.K

    @property
    def D_left(self) -> np.ndarray:
        """As OpenCV takes it: 5 zeros for an ideal lens."""
        return self.left.distortion

    @property
    def K_right(self) -> np.ndarray:
        return self.right.K

    @property
    def D_right(self) -> np.ndarray:
        return self.right.distortion

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

    def rectification(self) -> Rectification:
        """The rectified pair as ``cv2.stereoRectify(alpha=0)`` defines it at this image size (CONVENTIONS 1.2,
        section 2; :func:`~rgbd2scene.geometry.rectification.stereo_rectification`). A rectified pair is its own
        rectification: R1 = R2 = I, P1 = [K | 0], P2 = [K | (-fx B, 0, 0)]
        (:meth:`~rgbd2scene.geometry.rectification.Rectification.identity`)."""
        if self.rectified:
            return Rectification.identity(self.K_left, self.baseline, *self.size)
        return stereo_rectification(self.K_left, self.D_left, self.K_right, self.D_right, self.size, self.R, self.T)

    def resized(self, width: int, height: int) -> StereoCalibration:
        """Both eyes sampled at ``width`` x ``height``."""
        return replace(self, left=self.left.resized(width, height), right=self.right.resized(width, height))

    # -- the record --
    def to_dict(self) -> dict:
        """The calibration JSON (:meth:`from_dict` reads it back), with ``baseline_m`` for the reader's eye."""
        return {"K_left": self.K_left.tolist(), "D_left": self.D_left.tolist(), "K_right": self.K_right.tolist(),
                "D_right": self.D_right.tolist(), "R": [list(r) for r in self.R], "T": list(self.T),
                "image_size": [self.width, self.height], "baseline_m": self.baseline}

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> StereoCalibration:
        """The checked calibration of a JSON object: ``K_left, D_left, K_right, D_right, R, T`` and the image size
        as ``image_size: [w, h]`` or ``width``/``height``; besides these only :data:`INFO_KEYS` are allowed, so
        that a misspelt key does not go unnoticed. ``ValueError`` naming the key; ``source`` as in
        :meth:`from_matrices`."""
        if not isinstance(data, dict):
            raise ValueError("the calibration JSON must be an object")
        missing = [k for k in JSON_KEYS if k not in data]
        if missing:
            raise ValueError(f"missing key(s) {', '.join(missing)} (need {', '.join(JSON_KEYS)} and image_size)")
        unknown = sorted(set(data) - {*JSON_KEYS, *SIZE_KEYS, *INFO_KEYS})
        if unknown:
            raise ValueError(f"unknown key(s) {', '.join(unknown)} (known: {', '.join(JSON_KEYS)}, image_size or "
                             f"width and height, and {', '.join(INFO_KEYS)})")
        if "image_size" in data:
            size = data["image_size"]
            if not isinstance(size, list | tuple) or len(size) != 2:
                raise ValueError(f"image_size must be [width, height], got {size!r}")
        elif "width" in data and "height" in data:
            size = (data["width"], data["height"])
        else:
            raise ValueError("missing the image size (image_size: [width, height], or width and height)")
        try:
            width, height = int(size[0]), int(size[1])
        except (TypeError, ValueError):
            raise ValueError(f"image size must be two integers, got {size!r}") from None
        return cls.from_matrices(*(data[k] for k in JSON_KEYS), width, height, source=source)


def _rotation_error(R: np.ndarray) -> float:
    """How far R is from a rotation: max |R^T R - I| (a scaled R = s I counts s^2 - 1), infinite for a
    reflection (det R <= 0)."""
    return float(np.abs(R.T @ R - np.eye(3)).max()) if np.linalg.det(R) > 0 else math.inf


def _nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to R in the Frobenius norm (its polar factor, U V^T of the SVD)."""
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _matrix(value, shape: tuple[int, ...], key: str) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape``; ``ValueError`` naming ``key``."""
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{key} is not a matrix of numbers") from None
    if m.size != math.prod(shape):
        raise ValueError(f"{key} must have {math.prod(shape)} numbers ({'x'.join(map(str, shape))}), got {m.size}")
    m = m.reshape(shape)
    if not np.isfinite(m).all():
        raise ValueError(f"{key} contains non-finite values")
    return m


def _intrinsics(value, key: str, width: int, height: int) -> Intrinsics:
    """The pinhole intrinsics of the matrix ``value``: refused (naming ``key``) unless it is [[fx, s, cx],
    [0, fy, cy], [0, 0, 1]] with a skew s below :data:`SKEW_TOLERANCE` fx, which is taken as none."""
    K = _matrix(value, (3, 3), key)
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(f"{key} is not a camera matrix (its rows must be [fx s cx], [0 fy cy], [0 0 1])")
    if abs(K[0, 1]) > SKEW_TOLERANCE * abs(K[0, 0]):
        raise ValueError(f"{key} has skew {K[0, 1]:.6g}, which the camera model does not support")
    return Intrinsics.from_K(K, width, height)


def _distortion(value, key: str) -> np.ndarray:
    try:
        d = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{key} is not a list of numbers") from None
    if d.size not in DISTORTION_SIZES:
        sizes = ", ".join(map(str, DISTORTION_SIZES))
        raise ValueError(f"{key} has {d.size} coefficients; OpenCV's models take {sizes}")
    if not np.isfinite(d).all():
        raise ValueError(f"{key} contains non-finite values")
    return d
