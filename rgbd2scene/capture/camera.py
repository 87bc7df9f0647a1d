"""Pinhole intrinsics: the ``Intrinsics`` dataclass, named presets and camera-JSON parsing."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError


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


#: Named cameras. PrimeSense/Kinect v1 default (also TUM's "ROS default") and the three TUM calibrations.
PRESETS: dict[str, Intrinsics] = {
    "primesense": Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5),
    "kinect_v1": Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5),
    "tum_fr1": Intrinsics(640, 480, 517.3, 516.5, 318.6, 255.3),
    "tum_fr2": Intrinsics(640, 480, 520.9, 521.0, 325.1, 249.7),
    "tum_fr3": Intrinsics(640, 480, 535.4, 539.2, 320.1, 247.6),
}
#: Depth scale (units per metre) that goes with a preset's usual depth PNGs.
PRESET_DEPTH_SCALE = {"primesense": 1000.0, "kinect_v1": 1000.0, "tum_fr1": 5000.0, "tum_fr2": 5000.0,
                      "tum_fr3": 5000.0}
#: The depth sensor (``rgbd2scene.capture.sensors``) of each preset: all are Kinect v1 / PrimeSense.
PRESET_SENSOR = {name: "kinect_v1" for name in PRESETS}


def preset(name: str) -> Intrinsics:
    """The named camera (case-insensitive); :class:`OptionError` on ``preset`` for an unknown name."""
    try:
        return PRESETS[name.lower()]
    except KeyError:
        raise OptionError("preset", f"unknown camera preset {name!r}; choose one of {', '.join(PRESETS)}") from None


def load_camera_json(path: str | Path) -> tuple[Intrinsics, float | None]:
    """Read intrinsics (and an optional ``depth_scale``) from a camera JSON file.

    Accepts ``{"width", "height", "fx", "fy", "cx", "cy"}`` and Open3D's
    ``{"width", "height", "intrinsic_matrix": [9 numbers, column-major]}``.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: camera file not found")
    from rgbd2scene.files.atomic import read_json_object  # files/ imports the reconstruction: not at load

    data = read_json_object(path, "JSON camera file")
    try:
        width, height = int(data["width"]), int(data["height"])
        if "intrinsic_matrix" in data:
            m = np.asarray(data["intrinsic_matrix"], dtype=np.float64)
            if m.size != 9:
                raise UserError(f"{path}: intrinsic_matrix must have 9 numbers, got {m.size}")
            K = m.reshape(3, 3).T  # Open3D stores it column-major
            intr = Intrinsics.from_K(K, width, height)
        else:
            intr = Intrinsics(width, height, float(data["fx"]), float(data["fy"]),
                              float(data["cx"]), float(data["cy"]))
    except KeyError as exc:
        raise UserError(f"{path}: camera JSON lacks key {exc.args[0]!r} (need width, height and "
                        "fx/fy/cx/cy or intrinsic_matrix)") from None
    except (TypeError, ValueError) as exc:
        raise UserError(f"{path}: bad number in camera JSON ({exc})") from None
    scale = data.get("depth_scale")
    if scale is not None:
        try:
            scale = float(scale)
        except (TypeError, ValueError):
            raise UserError(f"{path}: depth_scale must be a number, got {scale!r}") from None
        if not (scale > 0 and math.isfinite(scale)):
            raise UserError(f"{path}: depth_scale must be positive, got {scale}")
    intr.check(str(path))
    return intr, scale


def camera_for(camera_json: str | Path | None = None, preset_name: str | None = None,
               depth_scale: float | None = None) -> tuple[Intrinsics, float | None]:
    """Intrinsics and depth scale of a capture: from a camera JSON, else a preset (default ``primesense``).

    An explicit ``depth_scale`` wins over the JSON's ``depth_scale``; a named preset brings its usual scale
    (5000 for the TUM presets) when none is given.
    """
    if camera_json:
        intr, json_scale = load_camera_json(camera_json)
        return intr, depth_scale if depth_scale is not None else json_scale
    name = preset_name or "primesense"
    if depth_scale is None and preset_name:
        depth_scale = PRESET_DEPTH_SCALE.get(name.lower())
    return preset(name), depth_scale
