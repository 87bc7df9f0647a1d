"""The one camera model: image size, pinhole intrinsics and OpenCV lens distortion (CONVENTIONS.md 1.2, section 2).

A :class:`Camera` answers the two questions every stage asks: the ray through each pixel centre
(:meth:`Camera.rays`) and the pixel a camera-frame point projects to (:meth:`Camera.project`). Without
distortion both are the pinhole conventions of :mod:`rgbd2scene.conventions` (the same arithmetic, bit for
bit); with distortion, projection is ``cv2.projectPoints`` and a pixel's ray is its exact inverse: the
undistortion of ``cv2.undistortPointsIter`` refined by Newton steps on ``cv2.projectPoints`` until the ray
re-projects onto the pixel centre (the default 5 iterations of ``cv2.undistortPoints`` are 0.1-0.2 px off
at the corners of HD images).

A lens model *folds* where its distorted radius stops growing with the undistorted one (over-fitted real
calibrations do so near the image corners): beyond that radius a point has no single image and a pixel no
single ray, so :meth:`Camera.project` gives NaN there and :meth:`Camera.rays` NaN for pixels beyond the
fold's image.

A camera file becomes a :class:`Camera` in :func:`rgbd2scene.capture.camera.load_camera` (input is the capture
stage's business; this module reads no files).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import cached_property, lru_cache

import numpy as np

from rgbd2scene.conventions import backproject, in_image, pixel_grid, pixel_rays
from rgbd2scene.conventions import project as pinhole_project
from rgbd2scene.errors import UserError


@dataclass(frozen=True)
class Intrinsics:
    """OpenCV pinhole intrinsics of a width x height image (pixel centres at integers)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_K(cls, K, width: int, height: int) -> Intrinsics:
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        return cls(int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    @classmethod
    def from_fov(cls, width: int, height: int, fov_x_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, horizontal field of view in degrees."""
        fx = (width / 2.0) / math.tan(math.radians(fov_x_deg) / 2.0)
        return cls(int(width), int(height), fx, fx, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width / (2.0 * self.fx)))

    def resized(self, width: int, height: int) -> Intrinsics:
        """The same camera sampled at another resolution (pixel-centre aware scaling)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            int(width), int(height), self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5,
        )

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Intrinsics:
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]))

    def check(self, source: str = "intrinsics") -> None:
        """Raise ``UserError`` unless the intrinsics are plausible for their own image size."""
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(x) for x in values):
            raise UserError(f"{source}: intrinsics contain non-finite values {values}")
        if self.width <= 0 or self.height <= 0:
            raise UserError(f"{source}: image size {self.width}x{self.height} is not positive")
        if self.fx <= 0 or self.fy <= 0:
            raise UserError(f"{source}: focal lengths must be positive (fx={self.fx}, fy={self.fy})")
        if not (0 <= self.cx <= self.width - 1 and 0 <= self.cy <= self.height - 1):
            raise UserError(
                f"{source}: principal point ({self.cx}, {self.cy}) lies outside the "
                f"{self.width}x{self.height} image"
            )
        if not (0.2 < self.fx / self.fy < 5.0):
            raise UserError(f"{source}: implausible aspect fx/fy = {self.fx / self.fy:.3g}")
        fov = self.fov_x_deg
        if not (5.0 <= fov <= 170.0):
            raise UserError(f"{source}: implausible horizontal field of view {fov:.1f} deg (fx={self.fx})")


#: Distortion vector lengths OpenCV takes.
DISTORTION_LENGTHS = (0, 4, 5, 8, 12, 14)
#: Largest undistorted normalised radius searched for a fold (tan 87 deg: no endoscope sees wider).
FOLD_SEARCH_RADIUS = 20.0
#: Samples of that search (radius step 1e-4).
FOLD_SEARCH_STEPS = 200_001
#: A pixel's ray must re-project onto its centre within this many pixels, else it has no ray.
RAY_TOLERANCE_PX = 1e-6
#: Newton steps after ``cv2.undistortPointsIter`` (quadratic convergence: 2-3 suffice away from the fold).
NEWTON_STEPS = 6
#: A camera whose lens leaves more than this share of its pixels without a ray is refused.
MIN_RAY_SHARE = 0.5


def _as_distortion(D) -> tuple[float, ...]:
    d = tuple(float(x) for x in np.asarray(D if D is not None else (), dtype=np.float64).ravel())
    return () if not any(d) else d


@dataclass(frozen=True)
class Camera:
    """A camera of ``intrinsics.width`` x ``intrinsics.height`` pixels with OpenCV distortion ``D``.

    ``D`` follows OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]]); an
    all-zero vector is stored as ``()``: an ideal pinhole.
    """

    intrinsics: Intrinsics
    D: tuple[float, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "D", _as_distortion(self.D))

    # -- construction --
    @classmethod
    def pinhole(cls, K, width: int, height: int) -> Camera:
        return cls(Intrinsics.from_K(K, width, height))

    @classmethod
    def from_K(cls, K, width: int, height: int, D=()) -> Camera:
        return cls(Intrinsics.from_K(K, width, height), D)

    # -- the pinhole part --
    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K

    @property
    def is_pinhole(self) -> bool:
        return not self.D

    @property
    def distortion(self) -> np.ndarray:
        """D as OpenCV takes it: float64, zeros (5,) for a pinhole."""
        return np.asarray(self.D, dtype=np.float64) if self.D else np.zeros(5)

    @property
    def distortion_model(self) -> str:
        """ROS CameraInfo's name of the model: plumb_bob (up to 5 coefficients) or rational_polynomial."""
        return "plumb_bob" if len(self.D) <= 5 else "rational_polynomial"

    def resized(self, width: int, height: int) -> Camera:
        """The same lens sampled at another resolution (distortion acts on normalised coordinates)."""
        return Camera(self.intrinsics.resized(width, height), self.D)

    def to_dict(self) -> dict:
        """The intrinsics and ``D`` (5 zeros for an ideal lens, CONVENTIONS section 3)."""
        return {**self.intrinsics.to_dict(), "D": self.distortion.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        D = d.get("D", d.get("distortion", ()))
        return cls(Intrinsics.from_dict(d), D or ())

    # -- the lens --
    def _distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (u, v) of normalised undistorted coordinates (x, y) (``cv2.projectPoints`` at z = 1)."""
        import cv2

        pts = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=-1).reshape(-1, 1, 3)
        if not len(pts):
            return np.empty(x.shape), np.empty(x.shape)
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.distortion)
        uv = uv.reshape(-1, 2)
        return uv[:, 0].reshape(x.shape), uv[:, 1].reshape(x.shape)

    @cached_property
    def fold_radius(self) -> float:
        """Undistorted normalised radius where the radial distortion stops growing (inf: never, up to
        :data:`FOLD_SEARCH_RADIUS`). Points beyond it project to NaN."""
        if self.is_pinhole:
            return math.inf
        d = np.zeros(14)
        d[:len(self.D)] = self.D
        k1, k2, _, _, k3, k4, k5, k6 = d[:8]
        r = np.linspace(0.0, FOLD_SEARCH_RADIUS, FOLD_SEARCH_STEPS)
        r2 = r * r
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        with np.errstate(divide="ignore", invalid="ignore"):
            g = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / den
        bad = ~(np.diff(g) > 0) | (den[1:] <= 0)
        if not bad.any():
            return math.inf
        return float(r[int(np.argmax(bad))])  # the last radius before g stops growing

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (u, v) of camera-frame points (..., 3), float64: ``cv2.projectPoints``; NaN
        behind the camera and beyond the fold."""
        if self.is_pinhole:
            return pinhole_project(points_cam, self.K)
        p = np.asarray(points_cam, dtype=np.float64)
        shape = p.shape[:-1]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(p[..., 2] > 0, p[..., 2], np.nan)
            x, y = p[..., 0] / z, p[..., 1] / z
            ok = np.isfinite(x) & np.isfinite(y) & (x * x + y * y < self.fold_radius ** 2)
        u, v = np.full(shape, np.nan), np.full(shape, np.nan)
        if ok.any():
            u[ok], v[ok] = self._distort(x[ok], y[ok])
        return u, v

    def undistort(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted (x, y) whose projection is the pixel (u, v): the exact inverse of
        :meth:`project` (NaN where there is none within the fold)."""
        u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
        if self.is_pinhole:
            K = self.K
            return (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
        import cv2

        pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        xy = cv2.undistortPointsIter(pts, self.K, self.distortion, None, None, criteria).reshape(-1, 2)
        x, y = xy[:, 0].copy(), xy[:, 1].copy()
        u0, v0 = u.ravel(), v.ravel()
        h = 1e-7
        for _ in range(NEWTON_STEPS):  # Newton on the projection, Jacobian by central differences
            pu, pv = self._distort(x, y)
            eu, ev = pu - u0, pv - v0
            ux1, vx1 = self._distort(x + h, y)
            ux0, vx0 = self._distort(x - h, y)
            uy1, vy1 = self._distort(x, y + h)
            uy0, vy0 = self._distort(x, y - h)
            a, b = (ux1 - ux0) / (2 * h), (uy1 - uy0) / (2 * h)
            c, d = (vx1 - vx0) / (2 * h), (vy1 - vy0) / (2 * h)
            with np.errstate(divide="ignore", invalid="ignore"):
                det = a * d - b * c
                dx, dy = (d * eu - b * ev) / det, (a * ev - c * eu) / det
            step = np.isfinite(dx) & np.isfinite(dy)
            x[step] -= dx[step]
            y[step] -= dy[step]
        pu, pv = self._distort(x, y)
        with np.errstate(invalid="ignore"):
            ok = ((np.abs(pu - u0) < RAY_TOLERANCE_PX) & (np.abs(pv - v0) < RAY_TOLERANCE_PX)
                  & (x * x + y * y < self.fold_radius ** 2))
        x[~ok], y[~ok] = np.nan, np.nan
        return x.reshape(u.shape), y.reshape(u.shape)

    def rays(self) -> np.ndarray:
        """Camera-frame ray directions with unit z through every pixel centre, (H, W, 3) float64; NaN for
        pixels without a ray (beyond the fold)."""
        if self.is_pinhole:
            return pixel_rays(self.height, self.width, self.K)
        return self._rays.copy()

    @property
    def _rays(self) -> np.ndarray:
        return _distorted_rays(self)

    def backproject(self, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (H, W, 3) float64 of a planar depth map of this camera (NaN: no surface or no
        ray); :func:`rgbd2scene.conventions.backproject` for a pinhole."""
        if self.is_pinhole:
            return backproject(depth, self.K)
        return self._rays * np.asarray(depth, dtype=np.float64)[..., None]

    @property
    def ray_share(self) -> float:
        """Share of the pixels that have a ray (1 for a pinhole)."""
        return 1.0 if self.is_pinhole else float(np.isfinite(self._rays[..., 0]).mean())

    def _border_inside_fold(self) -> bool:
        """Whether every pixel has a ray, judged from the image border alone: with the principal point inside
        the image, each pixel lies between it and the border, and the radial model grows monotonically up to
        the fold, so a border whose rays all lie inside the fold encloses pixels whose rays do too. Spares
        :meth:`check` the rays of every pixel (tens of seconds for a 1920x1080 pair) where nothing folds."""
        if self.is_pinhole:
            return True
        cx, cy = self.K[0, 2], self.K[1, 2]
        if not (-0.5 <= cx <= self.width - 0.5 and -0.5 <= cy <= self.height - 0.5):
            return False
        us, vs = np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64)
        bu = np.concatenate([us, us, np.zeros(vs.size), np.full(vs.size, self.width - 1.0)])
        bv = np.concatenate([np.zeros(us.size), np.full(us.size, self.height - 1.0), vs, vs])
        x, y = self.undistort(bu, bv)
        return bool(np.isfinite(x).all() and np.isfinite(y).all())

    def in_image(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bool: projections (u, v) fall in the image (NaN: False)."""
        return in_image(u, v, self.width, self.height)

    def normalised_bounds(self, margin_px: float = 1.0) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the normalised coordinates x = X/Z, y = Y/Z the camera can see:
        a box holding every pixel's ray and the image border ``margin_px`` outside the outer pixel centres
        (for a pinhole exactly the frustum; with a fold, the fold's disc where the border has no ray)."""
        if self.is_pinhole:
            fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
            u0, u1 = -0.5 - margin_px, self.width - 0.5 + margin_px
            v0, v1 = -0.5 - margin_px, self.height - 0.5 + margin_px
            return (u0 - cx) / fx, (u1 - cx) / fx, (v0 - cy) / fy, (v1 - cy) / fy
        w, h = self.width, self.height
        us = np.linspace(-0.5 - margin_px, w - 0.5 + margin_px, 4 * w + 1)
        vs = np.linspace(-0.5 - margin_px, h - 0.5 + margin_px, 4 * h + 1)
        bu = np.concatenate([us, us, np.full(vs.size, us[0]), np.full(vs.size, us[-1])])
        bv = np.concatenate([np.full(us.size, vs[0]), np.full(us.size, vs[-1]), vs, vs])
        x, y = self.undistort(bu, bv)
        rays = self._rays
        xs = np.concatenate([x, rays[..., 0].ravel()])
        ys = np.concatenate([y, rays[..., 1].ravel()])
        if not np.isfinite(x).all():
            r = self.fold_radius
            return -r, r, -r, r
        return float(np.nanmin(xs)), float(np.nanmax(xs)), float(np.nanmin(ys)), float(np.nanmax(ys))

    def check(self, source: str = "camera") -> str | None:
        """Raise ``UserError`` for an implausible camera; return a warning when the lens folds inside the
        image (pixels beyond the fold see nothing), else None."""
        self.intrinsics.check(source)
        if len(self.D) not in DISTORTION_LENGTHS:
            raise UserError(f"{source}: distortion must have 4, 5, 8, 12 or 14 coefficients, got {len(self.D)}")
        if not all(math.isfinite(x) for x in self.D):
            raise UserError(f"{source}: distortion contains non-finite values {self.D}")
        share = 1.0 if self._border_inside_fold() else self.ray_share
        if share < MIN_RAY_SHARE:
            raise UserError(f"{source}: the lens model folds at normalised radius {self.fold_radius:.3g}, so only "
                            f"{100 * share:.0f} % of the {self.width}x{self.height} pixels have a ray")
        if share < 1.0:
            return (f"{source}: the lens model folds at normalised radius {self.fold_radius:.3g}; "
                    f"{100 * (1 - share):.1f} % of the pixels (beyond the fold) see nothing")
        return None


@lru_cache(maxsize=4)
def _distorted_rays(camera: Camera) -> np.ndarray:
    """The rays of a distorted camera (read-only, shared): computed once per camera, which every frame of a
    dataset and every stage shares (equal cameras are one key)."""
    u, v = pixel_grid(camera.height, camera.width)
    x, y = camera.undistort(u, v)
    rays = np.stack([x, y, np.where(np.isfinite(x), 1.0, np.nan)], axis=-1)
    rays.flags.writeable = False
    return rays


_WARNED: set[str] = set()


def warn(message: str | None) -> None:
    """Print a warning line on stderr, once per process (nothing for None): a camera is checked by each stage
    that builds it."""
    if message and message not in _WARNED:
        import sys

        _WARNED.add(message)
        print(f"warning: {message}", file=sys.stderr)
