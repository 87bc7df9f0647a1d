"""A capture's camera from the user's input: named presets and camera-JSON parsing (intrinsics and, for a scope,
its distortion). The model itself (:class:`Intrinsics`, :class:`Camera`) is :mod:`rgbd2scene.geometry.camera`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import read_json_object
from rgbd2scene.geometry.camera import DISTORTION_LENGTHS, Camera, Intrinsics, warn
from rgbd2scene.options import OptionError

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


def load_camera(path) -> Camera:
    """A scope camera from a camera JSON (CONVENTIONS section 7): the intrinsics of
    :func:`~rgbd2scene.capture.camera.load_camera_json` and an optional ``"distortion"`` (OpenCV order);
    checked (:meth:`Camera.check`: its warning, for a lens folding inside the image, is printed)."""
    intrinsics, _ = load_camera_json(path)
    D = read_json_object(path, "JSON camera file").get("distortion", ())
    try:
        D = np.asarray(D if D is not None else (), dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise UserError(f"{path}: distortion must be a list of numbers, got {D!r}") from None
    if len(D) not in DISTORTION_LENGTHS:
        raise UserError(f"{path}: distortion must have 4, 5, 8, 12 or 14 coefficients, got {len(D)}")
    camera = Camera(intrinsics, D)
    warn(camera.check(str(path)))
    return camera
