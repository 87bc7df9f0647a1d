"""Settings of the tissue's look that the renderer turns into material nodes (no ``bpy`` here).

:class:`TissueDetail` is the procedural micro-structure of the "wet_tissue" material: what a capture
texel of about a millimetre cannot hold but an endoscope at a few centimetres (0.1 mm per pixel) sees:
structure from a few millimetres down to tens of micrometres. Every size is in metres on the tissue
surface, so the detail keeps its physical size whatever the camera distance, and its mean is 1 (it
multiplies the capture's colour), so the capture's colour stays at low spatial frequencies. It is a look,
not geometry: the bump tilts shading normals only, and the ground-truth render replaces every material,
so no ground-truth map depends on it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

#: Standard deviation of the mottling's noise n in [0, 1] (Blender's Perlin noise, Detail 4, Roughness 0.5),
#: measured on rendered planes: the mottling multiplies the colour by 1 + mottle_strength x (n - 0.5) / std.
MOTTLE_NOISE_STD = 0.069
#: Above this the mottling's modulation could go negative (at n = 0).
MAX_MOTTLE_STRENGTH = 2 * MOTTLE_NOISE_STD


@dataclass(frozen=True)
class TissueDetail:
    """Procedural micro-structure of the wet-tissue material (sizes in metres).

    Attributes
    ----------
    enabled
        Off: the capture's colour alone, smooth shading.
    seed
        Offsets the procedural patterns: another seed, another (equally likely) tissue.
    scale_m
        Largest feature of the albedo mottling and of the bumps; both are fractal noise whose finer
        octaves reach sub-millimetre sizes (scale_m / 16 for the mottling, scale_m / 64 for the bumps).
    mottle_strength
        Relative standard deviation of the albedo the mottling adds (colour x modulation of mean 1), at
        most ``MAX_MOTTLE_STRENGTH``.
    vessel_strength
        Darkening towards the vessel colour at the centre of a vessel (0: no vessels).
    vessel_width_m, vessel_spacing_m
        Width of a small vessel (full width at half darkening) and the typical distance between neighbouring
        ones.
    bump_height_m
        Height of the bumps (shading only); vessels are raised by 0.3 of it.
    bake
        Bake the detail into textures when the scene is built (a sample then costs what a textured surface
        costs; the procedural shader doubled it). Off: evaluated per sample (procedural).

    The defaults were tuned with ``benchmarks/bench_realism.py`` (real stereo-endoscope frames of the
    Hamlyn heart phantom): see ``benchmarks/results/realism.md``.
    """

    enabled: bool = True
    seed: int = 0
    scale_m: float = 0.003
    mottle_strength: float = 0.09
    vessel_strength: float = 0.6
    vessel_width_m: float = 0.00013
    vessel_spacing_m: float = 0.003
    bump_height_m: float = 0.0003
    bake: bool = True

    def __post_init__(self):
        for name in ("scale_m", "vessel_width_m", "vessel_spacing_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"tissue detail: {name} must be positive, got {getattr(self, name)}")
        for name, most in (("mottle_strength", MAX_MOTTLE_STRENGTH), ("vessel_strength", 1.0)):
            if not 0 <= getattr(self, name) <= most:
                raise ValueError(f"tissue detail: {name} must be between 0 and {most}, got {getattr(self, name)}")
        if not self.bump_height_m >= 0:
            raise ValueError(f"tissue detail: bump_height_m must be >= 0, got {self.bump_height_m}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TissueDetail:
        """The settings of ``d``; missing keys take their defaults, unknown keys are an error."""
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"tissue detail: unknown setting(s) {', '.join(sorted(unknown))}")
        return cls(**d)
