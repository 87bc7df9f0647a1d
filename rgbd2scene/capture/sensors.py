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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

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
    """

    name: str
    kind: str
    projector_side: str | None
    baseline_m: float
    colour_offset_m: float = 0.0

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

    def to_dict(self) -> dict:
        return asdict(self)


#: Kinect v1 / PrimeSense: the IR projector sits 7.5 cm right of the IR camera, the IR camera 2.5 cm
#: left of the RGB camera its depth is registered to.
KINECT_V1 = Sensor("kinect_v1", STRUCTURED_LIGHT, "right", 0.075, 0.025)

SENSORS: dict[str, Sensor] = {
    "kinect_v1": KINECT_V1,
    "kinect_v2": Sensor("kinect_v2", TIME_OF_FLIGHT, None, 0.0),
    "azure_kinect": Sensor("azure_kinect", TIME_OF_FLIGHT, None, 0.0),
    # RealSense D4xx: depth is matched from the left and right IR imagers (50 mm apart on the D435) and
    # expressed in the LEFT imager. The right imager looks from +x, so near surfaces shift left relative
    # to the far ones in its image and cover the far surface just left of them: the shadows (and the
    # invalid band at the image's left edge) fall on the left, as Intel's D400 depth documentation
    # shows. The emitter only adds texture and casts no shadow of its own. Aligned to colour, the
    # D435's RGB camera sits about 15 mm right of the left imager.
    "realsense": Sensor("realsense", ACTIVE_STEREO, "right", 0.050, 0.015),
    "none": Sensor("none", NO_MODEL, None, 0.0),
}


def get_sensor(name: str) -> Sensor:
    """The named sensor (case-insensitive); ``ValueError`` naming the choices for an unknown name."""
    try:
        return SENSORS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}") from None
