"""Breathing and beating tissue: one smooth periodic displacement along the rest surface normals.

The one formula, evaluated in numpy here and nowhere else::

    x_i(t) = x_i + n_i * sum_k c_k(t) * B_k(x_i)

with x_i and n_i the rest vertex positions and unit normals (area-weighted), ``B_k`` scalar *basis fields*
(metres) and ``c_k(t)`` scalar *coefficients*. A travelling wave ``A w(x) sin(2 pi f t - phi(x))`` splits
into two terms (``sin 2 pi f t`` and ``cos 2 pi f t`` times fixed fields), and each further harmonic of a
non-sinusoidal waveform (the heartbeat) into two more, so the motion of every frame is a linear
combination of a few fixed fields. Blender is keyed from exactly this: one shape key per basis field
(``rest + n B_k``) whose value is ``c_k(frame / fps)`` keyed on every frame (``render/scene_builder.py``);
the ground-truth oracle, the geometry files of ``DATASET/geometry/`` and tracked frames on the tissue call
:meth:`Deformation.displace` on the same arrays.

``w(x) = exp(-|x - centre|^2 / (2 extent^2))`` confines the motion to a region of the organ (``extent``
0 or None: uniform), and ``phi(x) = 2 pi (x - centre) . direction / wavelength`` makes it travel across the
surface (``wavelength`` None: every point in phase).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

#: name -> (amplitude m, frequency Hz, extent m, wavelength m, harmonic amplitudes relative to the first)
PRESETS = {
    "breathing": dict(amplitude_m=0.002, frequency_hz=0.25, extent_m=0.04, wavelength_m=None,
                      harmonics=(1.0,)),
    # a sharp systole then a slower diastole: the first harmonics of a pulse train
    "heartbeat": dict(amplitude_m=0.0008, frequency_hz=1.2, extent_m=0.02, wavelength_m=0.06,
                      harmonics=(1.0, 0.5, 0.25)),
}
KINDS = ("none", *PRESETS)


@dataclass
class Deformation:
    """A periodic displacement of a surface along its rest normals (see the module docstring)."""

    kind: str = "breathing"
    amplitude_m: float = 0.002
    frequency_hz: float = 0.25
    extent_m: float | None = 0.04
    wavelength_m: float | None = None
    harmonics: tuple[float, ...] = (1.0,)
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    phase: float = 0.0  # radians at t = 0

    def __post_init__(self):
        self.harmonics = tuple(float(h) for h in self.harmonics)
        self.centre = tuple(float(c) for c in self.centre)
        d = np.asarray(self.direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if not (norm > 0 and np.isfinite(norm)):
            raise ValueError(f"deformation direction must be a non-zero vector, got {self.direction}")
        self.direction = tuple(float(c) for c in d / norm)
        for name in ("amplitude_m", "frequency_hz"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"deformation {name} must be a non-negative number, got {value}")
        if not self.harmonics:
            raise ValueError("deformation needs at least one harmonic")

    @classmethod
    def preset(cls, kind: str, **changes) -> Deformation:
        """A named preset (breathing, heartbeat) with fields replaced by ``changes``."""
        if kind not in PRESETS:
            raise ValueError(f"unknown deformation {kind!r}; choose one of {', '.join(KINDS)}")
        return replace(cls(kind=kind, **PRESETS[kind]), **changes)

    # -- the formula --
    @property
    def n_fields(self) -> int:
        return 2 * len(self.harmonics)

    def basis(self, positions: np.ndarray) -> np.ndarray:
        """The scalar fields B_k (K, N) in metres at rest positions (N, 3)."""
        x = np.asarray(positions, dtype=np.float64).reshape(-1, 3) - np.asarray(self.centre)
        if self.extent_m:
            w = np.exp(-np.sum(x * x, axis=1) / (2.0 * float(self.extent_m) ** 2))
        else:
            w = np.ones(len(x))
        phi = (2.0 * np.pi * (x @ np.asarray(self.direction)) / float(self.wavelength_m) if self.wavelength_m
               else np.zeros(len(x)))
        out = []
        for h, a in enumerate(self.harmonics, start=1):
            amp = float(self.amplitude_m) * a * w
            # sin(h(wt) - h phi + phase) = sin(h wt + phase) cos(h phi) - cos(h wt + phase) sin(h phi)
            out += [amp * np.cos(h * phi), -amp * np.sin(h * phi)]
        return np.asarray(out)

    def coefficients(self, t: float | np.ndarray) -> np.ndarray:
        """c_k(t) (K,) or (K, T) for times in seconds."""
        t = np.asarray(t, dtype=np.float64)
        out = []
        for h in range(1, len(self.harmonics) + 1):
            angle = h * 2.0 * np.pi * float(self.frequency_hz) * t + h * float(self.phase)
            out += [np.sin(angle), np.cos(angle)]
        return np.asarray(out)

    def displacement(self, positions: np.ndarray, normals: np.ndarray, t: float) -> np.ndarray:
        """Displacement vectors (N, 3) of rest points with unit rest normals at time ``t`` (seconds)."""
        scale = self.coefficients(t) @ self.basis(positions)
        return np.asarray(normals, dtype=np.float64).reshape(-1, 3) * scale[:, None]

    def displace(self, positions: np.ndarray, normals: np.ndarray, t: float) -> np.ndarray:
        """Deformed positions (N, 3) float64 at time ``t``."""
        return np.asarray(positions, dtype=np.float64).reshape(-1, 3) + self.displacement(positions, normals, t)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "amplitude_m": self.amplitude_m, "frequency_hz": self.frequency_hz,
                "extent_m": self.extent_m, "wavelength_m": self.wavelength_m, "harmonics": list(self.harmonics),
                "centre": list(self.centre), "direction": list(self.direction), "phase": self.phase}

    @classmethod
    def from_dict(cls, d: dict) -> Deformation:
        d = dict(d)
        for key in ("harmonics", "centre", "direction"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)


@dataclass
class SurfaceAnchor:
    """A point of a (possibly deforming) surface: barycentric ``weights`` over the triangle's three
    ``vertices`` (indices), with their rest positions and unit rest normals, so it moves with the surface
    without the mesh file at hand."""

    vertices: tuple[int, int, int]
    weights: tuple[float, float, float]
    rest_positions: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    rest_normals: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self):
        self.vertices = tuple(int(v) for v in self.vertices)
        self.weights = tuple(float(w) for w in self.weights)
        self.rest_positions = np.asarray(self.rest_positions, dtype=np.float64).reshape(3, 3)
        self.rest_normals = np.asarray(self.rest_normals, dtype=np.float64).reshape(3, 3)

    def point(self, deformation: Deformation | None = None, t: float = 0.0) -> np.ndarray:
        """The surface point (3,) at time ``t``: the barycentric mix of its (deformed) triangle corners."""
        corners = self.rest_positions if deformation is None else deformation.displace(
            self.rest_positions, self.rest_normals, t)
        return np.asarray(self.weights) @ corners

    def normal(self, deformation: Deformation | None = None, t: float = 0.0) -> np.ndarray:
        """Unit normal (3,) of the (deformed) triangle, oriented like the rest normals."""
        c = self.rest_positions if deformation is None else deformation.displace(
            self.rest_positions, self.rest_normals, t)
        n = np.cross(c[1] - c[0], c[2] - c[0])
        n /= np.linalg.norm(n)
        return n if n @ self.rest_normals.sum(axis=0) >= 0 else -n

    def to_dict(self) -> dict:
        return {"vertices": list(self.vertices), "weights": list(self.weights),
                "rest_positions": self.rest_positions.tolist(), "rest_normals": self.rest_normals.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> SurfaceAnchor:
        return cls(tuple(d["vertices"]), tuple(d["weights"]), d["rest_positions"], d["rest_normals"])


def rest_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The unit rest normals n_i the displacement follows (area-weighted, as the module docstring says)."""
    from rgbd2scene.geometry.mesh import vertex_normals

    return vertex_normals(vertices, triangles, weighting="area")


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector ``a`` to unit vector ``b``."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)
