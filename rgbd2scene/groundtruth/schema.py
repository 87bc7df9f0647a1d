"""The one ground-truth schema (CONVENTIONS.md section 3): keys, dtypes, shapes, NaN rule, optional keys.

The writer (``groundtruth.passes``), ``verify``, the contact sheet, the exporters and ``evaluate`` import
this module instead of spelling keys, dtypes or the background sentinel again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Field:
    """One npz key: dtype, shape (``"H"``, ``"W"``, ``"N"`` are the image size and the object count),
    whether it is a per-pixel map, NaN where there is no surface, and optional."""

    dtype: str
    shape: tuple
    per_pixel: bool = True
    nan_where_no_surface: bool = False
    optional: bool = False
    doc: str = ""

    def expected_shape(self, height: int, width: int, count: int | None = None, d: int | None = None) -> tuple:
        sizes = {"H": height, "W": width, "N": count, "D": d}
        return tuple(sizes.get(s, s) if isinstance(s, str) else s for s in self.shape)


SCHEMA: dict[str, Field] = {
    "depth": Field("float32", ("H", "W"), nan_where_no_surface=True, doc="planar z, metres"),
    "disparity": Field("float32", ("H", "W"), nan_where_no_surface=True, doc="fx*B/z, pixels, positive"),
    "normals": Field("float32", ("H", "W", 3), nan_where_no_surface=True,
                     doc="unit normal, camera frame, facing the camera"),
    "flow_forward": Field("float32", ("H", "W", 2), nan_where_no_surface=True,
                          doc="(du, dv) pixels to the next frame; NaN on the last frame"),
    "flow_backward": Field("float32", ("H", "W", 2), nan_where_no_surface=True,
                           doc="(du, dv) pixels to the previous frame; NaN on the first frame"),
    "segmentation": Field("uint16", ("H", "W"), doc="instance id, 0 = nothing"),
    "occluded_forward": Field("bool", ("H", "W"), optional=True,
                              doc="the surface point is hidden or leaves the image in the next frame"),
    "occluded_backward": Field("bool", ("H", "W"), optional=True, doc="likewise for the previous frame"),
    "correspondence": Field("float32", ("H", "W", 2), nan_where_no_surface=True, optional=True,
                            doc="(du, dv) pixels to the other eye's pixel seeing the same point; NaN where it "
                                "does not (raw pairs, in place of disparity)"),
    "K": Field("float64", (3, 3), per_pixel=False, doc="intrinsics of this eye"),
    "D": Field("float64", ("D",), per_pixel=False, optional=True,
               doc="distortion of this eye, OpenCV order (4, 5, 8, 12 or 14); zeros for a pinhole"),
    "T_world_cam": Field("float64", (4, 4), per_pixel=False, doc="pose of this eye (OpenCV axes)"),
    "object_ids": Field("uint16", ("N",), per_pixel=False, doc="ids of tracked object parts and frames"),
    "object_poses": Field("float64", ("N", 4, 4), per_pixel=False, doc="T_world_obj of each, in that order"),
}
#: The per-pixel maps a renderer produces, in canonical order (optional ones excluded).
MAPS = tuple(k for k, f in SCHEMA.items() if f.per_pixel and not f.optional)
#: Optional per-pixel maps (written once anything but the camera moves).
OPTIONAL_MAPS = tuple(k for k, f in SCHEMA.items() if f.per_pixel and f.optional)
#: Keys written with every frame whatever maps are chosen.
MATRICES = tuple(k for k, f in SCHEMA.items() if not f.per_pixel)
#: Lengths a distortion vector ``D`` may have (OpenCV's).
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
#: Blender's Depth pass writes 1e10 where there is no surface; values at or above this are "no surface".
BACKGROUND_DEPTH = 1e9


def surface_mask(depth: np.ndarray) -> np.ndarray:
    """True where a depth value (map or raw pass) is a surface: finite, positive, below the background."""
    z = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(z) & (z > 0) & (z < BACKGROUND_DEPTH)

