"""Depth sensors: where their occlusion shadows fall, for the shadow prior of hole filling.

A sensor that triangulates (structured light, active stereo) measures depth from two viewpoints: the
camera the depth is expressed in and a second one (the projector, or the matching imager) a baseline
b to its side. A surface point the second viewpoint cannot see has no depth: beside a near surface
(depth z_near) in front of a far one (z_far), a *shadow* fx * b * (1/z_near - 1/z_far) px wide lies on
the far surface. With the second viewpoint to the right (+x) of the depth camera the shadow falls
*left* of the near surface; to the left, right of it. Registering depth to a colour camera that sits
to the side of the depth camera hides more far surface beside near surfaces, on the side of that
camera (a colour camera to the right leaves holes right of near surfaces), with its own baseline.

Time-of-flight cameras emit and receive from (nearly) one point: no projector shadows; their holes
are low-signal, multipath and mixed-pixel dropouts, so the shadow prior is off for them.

Which sensor took a capture is a fact about the capture, not a default (:func:`infer_sensor`): the user's
choice wins; otherwise a stereo frame, a fused mesh and metric float depth (EXR, ``.npy``: CT, a renderer)
had no projector; a camera preset names its sensor; 16-bit PNG depth is taken for a Kinect v1 / PrimeSense
unless its depth lies outside that sensor's working range (a Kinect v1 sees nothing nearer than about
0.4 m, so depth at endoscopic range did not come from one). The choice and its reason go to scene.json.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

STRUCTURED_LIGHT = "structured_light"
ACTIVE_STEREO = "active_stereo"
TIME_OF_FLIGHT = "time_of_flight"
NO_MODEL = "none"


@dataclass(frozen=True)
class Sensor:
    """A depth sensor's triangulation geometry.

    Attributes
    ----------
    name : preset name.
    kind : ``"structured_light"``, ``"active_stereo"``, ``"time_of_flight"`` or ``"none"`` (no model:
        depth from CT, a renderer, or an unknown source).
    projector_side : side of the depth camera where the second viewpoint sits (``"right"``: +x,
        ``"left"``), or None when the sensor casts no shadows.
    baseline_m : distance from the depth camera to that second viewpoint, metres.
    colour_offset_m : x position of the colour camera the depth is registered to, relative to the
        depth camera, metres (positive: to the right); 0 where not modelled (time-of-flight: the
        shadow prior is off altogether).
    min_range_m, max_range_m : the depth it measures, metres (its working range).
    """

    name: str
    kind: str
    projector_side: str | None
    baseline_m: float
    colour_offset_m: float = 0.0
    min_range_m: float = 0.0
    max_range_m: float = math.inf

    @property
    def casts_shadows(self) -> bool:
        return self.projector_side is not None and self.baseline_m > 0

    def shadow_baselines(self) -> tuple[float, float]:
        """(b for shadows left of a near surface, b for shadows right of it), metres; 0 = none there."""
        if not self.casts_shadows:
            return 0.0, 0.0
        left = self.baseline_m if self.projector_side == "right" else 0.0
        right = self.baseline_m if self.projector_side == "left" else 0.0
        if self.colour_offset_m > 0:
            right = max(right, self.colour_offset_m)
        elif self.colour_offset_m < 0:
            left = max(left, -self.colour_offset_m)
        return left, right

    def out_of_range_fraction(self, depth: np.ndarray) -> float:
        """Fraction of the valid pixels of ``depth`` (metres, NaN = hole) outside the working range."""
        valid = depth[np.isfinite(depth)]
        if valid.size == 0:
            return 0.0
        return float(np.mean((valid < self.min_range_m) | (valid > self.max_range_m)))

    def to_dict(self) -> dict:
        record = asdict(self)
        record["max_range_m"] = None if math.isinf(self.max_range_m) else self.max_range_m  # JSON has no inf
        return record


#: Kinect v1 / PrimeSense: the IR projector sits 7.5 cm right of the IR camera, the IR camera 2.5 cm
#: left of the RGB camera its depth is registered to. It measures from about 0.4 m (near mode; 0.8 m in
#: the default mode) to its last disparity codes near 10 m (TUM and SUN RGB-D frames reach 9-9.9 m).
KINECT_V1 = Sensor("kinect_v1", STRUCTURED_LIGHT, "right", 0.075, 0.025, 0.4, 10.0)

SENSORS: dict[str, Sensor] = {
    "kinect_v1": KINECT_V1,
    "kinect_v2": Sensor("kinect_v2", TIME_OF_FLIGHT, None, 0.0, 0.0, 0.5, 8.0),
    "azure_kinect": Sensor("azure_kinect", TIME_OF_FLIGHT, None, 0.0, 0.0, 0.25, 5.5),
    # RealSense D4xx: depth is matched from the left and right IR imagers (50 mm apart on the D435) and
    # expressed in the LEFT imager. The right imager looks from +x, so near surfaces shift left relative
    # to the far ones in its image and cover the far surface just left of them: the shadows (and the
    # invalid band at the image's left edge) fall on the left, as Intel's D400 depth documentation
    # shows. The emitter only adds texture and casts no shadow of its own. Aligned to colour, the
    # D435's RGB camera sits about 15 mm right of the left imager.
    # Its minimum depth is about 0.1 m at the lowest resolution (0.28 m at 1280x720), its range about 10 m.
    "realsense": Sensor("realsense", ACTIVE_STEREO, "right", 0.050, 0.015, 0.1, 10.0),
    "none": Sensor("none", NO_MODEL, None, 0.0),
}


def get_sensor(name: str) -> Sensor:
    """The named sensor (case-insensitive); ``OptionError`` on ``sensor`` (a ``ValueError``) naming the
    choices for an unknown name."""
    from rgbd2scene.options import OptionError

    try:
        return SENSORS[name.lower()]
    except KeyError:
        raise OptionError("sensor", f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}") from None


#: The sensor 16-bit depth images are taken from when nothing names one (PrimeSense / Kinect v1 PNGs are the
#: common case: TUM, NYU, Redwood, the presets).
DEFAULT_SENSOR = "kinect_v1"
#: Metric float depth formats: no sensor is assumed for them (CT, a renderer, a processed map).
FLOAT_FORMATS = ("exr", "npy", "float")
#: A capture with more of its valid depth outside a sensor's working range was not taken by that sensor.
MAX_OUT_OF_RANGE = 0.01


@dataclass(frozen=True)
class SensorChoice:
    """The sensor assumed for a capture, where the assumption came from (``given`` by the user, the camera
    ``preset``, ``inferred`` from the capture, or the ``default``) and why (recorded in scene.json)."""

    sensor: Sensor
    source: str
    reason: str

    def to_dict(self) -> dict:
        return {"name": self.sensor.name, "kind": self.sensor.kind, "casts_shadows": self.sensor.casts_shadows,
                "source": self.source, "reason": self.reason}


def _range_text(sensor: Sensor) -> str:
    top = "" if math.isinf(sensor.max_range_m) else f"-{sensor.max_range_m:g}"
    return f"{sensor.min_range_m:g}{top} m"


def infer_sensor(depth: np.ndarray | None, depth_format: str, given: str | None = None, named: str | None = None,
                 fused: bool = False) -> SensorChoice:
    """The depth sensor of a capture (the module docstring's rules, in order).

    Parameters
    ----------
    depth : float32 (H, W) metres, NaN = hole (for the working-range check; None skips it).
    depth_format : the format the depth was read in (``png``, ``nyu``, ``sun``, ``exr``, ``npy``, ``float``,
        ``stereo``).
    given : the user's sensor name, or None.
    named : the sensor the capture's camera preset names, or None.
    fused : the depth is fused from several frames into one mesh.
    """
    if given:
        sensor = get_sensor(given)
        reason = "given by the user"
        out = sensor.out_of_range_fraction(depth) if depth is not None else 0.0
        if sensor.casts_shadows and out > MAX_OUT_OF_RANGE:
            reason += (f" (note: {100 * out:.0f} % of the valid depth lies outside its working range "
                       f"{_range_text(sensor)})")
        return SensorChoice(sensor, "given", reason)
    none = SENSORS["none"]
    if depth_format == "stereo":
        return SensorChoice(none, "inferred", "a stereo frame: depth matched between two images, no projector")
    if fused:
        return SensorChoice(none, "inferred", "fused frames: the mesh merges several viewpoints, so no single "
                            "projector's shadows apply")
    if depth_format in FLOAT_FORMATS:
        return SensorChoice(none, "inferred", f"metric float depth ({depth_format}: CT, a renderer or a processed "
                            "map), not a sensor's raw depth image")
    if depth_format == "nyu":
        sensor, source, reason = KINECT_V1, "inferred", "NYU raw depth holds Kinect v1 disparity codes"
    elif named:
        sensor, source, reason = get_sensor(named), "preset", f"the camera preset names the {named} sensor"
    else:
        sensor, source = get_sensor(DEFAULT_SENSOR), "default"
        reason = f"{depth_format} depth image with no sensor named: taken for a {DEFAULT_SENSOR}"
    if depth is not None and sensor.name != "none":
        out = sensor.out_of_range_fraction(depth)
        if out > MAX_OUT_OF_RANGE:
            median = float(np.nanmedian(depth))
            return SensorChoice(none, "inferred", f"{100 * out:.0f} % of the valid depth (median {median:.3g} m) lies "
                                f"outside the {sensor.name}'s working range {_range_text(sensor)}: it could not "
                                "have measured it")
        reason += f"; the depth lies inside its working range {_range_text(sensor)}"
    return SensorChoice(sensor, source, reason)
