"""The built-in laparoscopic / robotic instrument: shaft, wrist and two jaws on a hinge (no ``bpy``).

Every part is a closed triangle mesh (watertight once coincident vertices are welded, outward normals) in
its own frame, in metres:

- **instrument frame** (= the shaft's and the wrist's part frame): origin on the axis at the distal end of
  the shaft, +z along the shaft towards the tip, +x the hinge axis (the jaws open in the y-z plane);
- **shaft**: a cylinder from z = -``shaft_length`` to 0;
- **wrist**: a slimmer cylinder from z = 0 to ``wrist_length``;
- **jaws**: each in its own frame, origin on the hinge (``hinge`` in the instrument frame), +z along the
  closed jaw; a D-shaped cross-section (flat gripping face towards the other jaw) tapering to the tip.
  ``jaw_upper`` lies on the -y side and opens by turning +angle/2 about x, ``jaw_lower`` mirrors it, so
  ``T_world_jaw = T_world_instrument @ hinge @ Rx(+-angle / 2)`` (:meth:`Instrument.jaw_offsets`).

Vertices are duplicated along sharp edges (cylinder rims, the jaw's flat face) so that smooth shading,
which interpolates the angle-weighted vertex normals (as Blender and the ray-casting oracle do), keeps the
round surfaces round and the flat ones flat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd2scene.geometry.mesh import Mesh

LOOKS = ("metal", "dark_plastic")
#: Part name -> class; the two jaws share a class (and never an id).
PART_CLASSES = {"shaft": "instrument_shaft", "wrist": "instrument_wrist", "jaw_upper": "instrument_jaw",
                "jaw_lower": "instrument_jaw"}
PARTS = tuple(PART_CLASSES)
WRIST_RADIUS = 0.85  # of the shaft radius
JAW_BASE_RADIUS = 0.9  # of the wrist radius
JAW_TIP_RADIUS = 0.35  # of the jaw's base radius
JAW_GAP = 0.06  # each jaw's flat face lies this fraction of the jaw base radius off the hinge plane


@dataclass(frozen=True)
class Instrument:
    """Sizes (metres) and look of the built-in instrument. ``look`` is the shaft's (the wrist and jaws are
    metal either way); ``segments`` is the number of sides of the round cross-sections."""

    shaft_diameter: float = 0.008
    shaft_length: float = 0.30
    wrist_length: float = 0.006
    jaw_length: float = 0.010
    look: str = "dark_plastic"
    segments: int = 32

    def __post_init__(self):
        for name in ("shaft_diameter", "shaft_length", "wrist_length", "jaw_length"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive length in metres, got {value}")
        if self.shaft_diameter > 0.03:
            raise ValueError(f"shaft_diameter {self.shaft_diameter} m is not an endoscopic instrument "
                             "(typical: 0.005 or 0.008)")
        if self.look not in LOOKS:
            raise ValueError(f"look must be one of {', '.join(LOOKS)}, got {self.look!r}")
        if int(self.segments) < 8:
            raise ValueError(f"segments must be at least 8, got {self.segments}")

    @property
    def shaft_radius(self) -> float:
        return 0.5 * float(self.shaft_diameter)

    @property
    def wrist_radius(self) -> float:
        return WRIST_RADIUS * self.shaft_radius

    @property
    def jaw_radius(self) -> float:
        """Half-width of a jaw at the hinge (its widest)."""
        return JAW_BASE_RADIUS * self.wrist_radius

    @property
    def hinge(self) -> np.ndarray:
        """Pose (4, 4) of the hinge frame in the instrument frame: on the axis just past the wrist, where
        the jaws' rounded bases clear the wrist when they open."""
        T = np.eye(4)
        T[2, 3] = float(self.wrist_length) + 0.5 * self.jaw_radius
        return T

    @property
    def tip(self) -> np.ndarray:
        """The tip (3,) in the instrument frame: between the closed jaws' ends."""
        return np.array([0.0, 0.0, self.hinge[2, 3] + float(self.jaw_length)])

    def materials(self) -> dict[str, str]:
        """Part name -> material kind (``render.materials``)."""
        return {"shaft": self.look, "wrist": "metal", "jaw_upper": "metal", "jaw_lower": "metal"}

    def jaw_offsets(self, angle_rad: float | np.ndarray) -> dict[str, np.ndarray]:
        """Poses of both jaws in the instrument frame for an opening ``angle_rad`` between them: (4, 4) each,
        or (F, 4, 4) for an array of angles."""
        a = 0.5 * np.asarray(angle_rad, dtype=np.float64)
        return {"jaw_upper": self.hinge @ _rotation_x(a), "jaw_lower": self.hinge @ _rotation_x(-a)}

    def meshes(self) -> dict[str, Mesh]:
        """Part name -> closed triangle mesh in the part's own frame (metres)."""
        n = int(self.segments)
        upper = _jaw_mesh(self.jaw_radius, JAW_TIP_RADIUS * self.jaw_radius, float(self.jaw_length),
                          JAW_GAP * self.jaw_radius, n // 2)
        lower = Mesh(vertices=upper.vertices * [1.0, -1.0, 1.0], triangles=upper.triangles[:, ::-1].copy())
        return {"shaft": _cylinder(self.shaft_radius, -float(self.shaft_length), 0.0, n),
                "wrist": _cylinder(self.wrist_radius, 0.0, float(self.wrist_length), n),
                "jaw_upper": upper, "jaw_lower": lower}

    def to_dict(self) -> dict:
        return {"shaft_diameter": self.shaft_diameter, "shaft_length": self.shaft_length,
                "wrist_length": self.wrist_length, "jaw_length": self.jaw_length, "look": self.look,
                "segments": self.segments}


def _rotation_x(angle: np.ndarray) -> np.ndarray:
    """Rotations (..., 4, 4) about x by ``angle`` radians."""
    angle = np.asarray(angle, dtype=np.float64)
    T = np.zeros(angle.shape + (4, 4))
    c, s = np.cos(angle), np.sin(angle)
    T[..., 0, 0] = T[..., 3, 3] = 1.0
    T[..., 1, 1], T[..., 1, 2], T[..., 2, 1], T[..., 2, 2] = c, -s, s, c
    return T


class _Builder:
    """Collects surface pieces (each with its own vertices, so shading does not blend across sharp edges)."""

    def __init__(self):
        self.vertices: list[np.ndarray] = []
        self.triangles: list[np.ndarray] = []
        self.count = 0

    def add(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        self.vertices.append(np.asarray(vertices, dtype=np.float64))
        self.triangles.append(np.asarray(triangles, dtype=np.int64) + self.count)
        self.count += len(vertices)

    def side(self, rings: list[np.ndarray], closed: bool) -> None:
        """Quads between consecutive rings (each (M, 3), counter-clockwise seen from +z, rings along +z)."""
        m = len(rings[0])
        verts = np.concatenate(rings)
        quads = []
        stop = m if closed else m - 1
        for k in range(len(rings) - 1):
            i = np.arange(stop)
            j = (i + 1) % m
            a, b, c, d = k * m + i, k * m + j, (k + 1) * m + j, (k + 1) * m + i
            quads += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
        self.add(verts, np.concatenate(quads))

    def cap(self, ring: np.ndarray, facing_plus_z: bool) -> None:
        """A fan over a convex ring (counter-clockwise seen from +z), facing +z or -z."""
        m = len(ring)
        verts = np.vstack([ring.mean(axis=0), ring])
        i = np.arange(m)
        tri = np.stack([np.zeros(m, int), 1 + i, 1 + (i + 1) % m], 1)
        self.add(verts, tri if facing_plus_z else tri[:, ::-1])

    def mesh(self) -> Mesh:
        return Mesh(vertices=np.concatenate(self.vertices), triangles=np.concatenate(self.triangles).astype(np.int32))


def _circle(radius: float, z: float, n: int) -> np.ndarray:
    t = 2.0 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(t), radius * np.sin(t), np.full(n, z)], 1)


def _cylinder(radius: float, z0: float, z1: float, n: int) -> Mesh:
    """Rings at most two diameters apart: long thin triangles lose float32 precision in ray casting (a 30 cm
    shaft in one span put Cycles' and Open3D's hits 0.2 um apart; in 2-diameter spans they agree to 1e-6)."""
    b = _Builder()
    rings = max(2, int(np.ceil((z1 - z0) / (4.0 * radius))) + 1)
    b.side([_circle(radius, z, n) for z in np.linspace(z0, z1, rings)], closed=True)
    b.cap(_circle(radius, z0, n), facing_plus_z=False)
    b.cap(_circle(radius, z1, n), facing_plus_z=True)
    return b.mesh()


def _jaw_mesh(r0: float, r1: float, length: float, gap: float, n: int, stations: int = 6) -> Mesh:
    """The upper jaw: at each z a half-ellipse below the flat face y = -gap (half-width r, depth 0.8 r),
    r tapering from r0 at the hinge to r1 at the tip."""
    zs = np.linspace(0.0, length, stations)
    radii = np.interp(zs, [0.0, length], [r0, r1])
    t = np.linspace(np.pi, 2.0 * np.pi, n + 1)  # left -> bottom -> right: counter-clockwise seen from +z

    def curve(r, z):
        return np.stack([r * np.cos(t), -gap + 0.8 * r * np.sin(t), np.full(len(t), z)], 1)

    b = _Builder()
    b.side([curve(r, z) for r, z in zip(radii, zs, strict=True)], closed=False)
    # the flat face, from the right corner back to the left one (closing the counter-clockwise outline)
    b.side([np.array([[r, -gap, z], [-r, -gap, z]]) for r, z in zip(radii, zs, strict=True)], closed=False)
    b.cap(curve(radii[0], 0.0), facing_plus_z=False)
    b.cap(curve(radii[-1], length), facing_plus_z=True)
    return b.mesh()
