"""Settings of the scene's environment effects (one dataclass: CLI flags, batch keys, dataset.json record)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from rgbd2scene.options import OptionError, option
from rgbd2scene.sensor.settings import parse_triple


@dataclass
class EnvironmentOptions:
    """What fills the space between the scope and the surface. It changes only the RGB images: the ground truth
    describes the surface behind it."""

    smoke: float = option(0.0, "surgical smoke: mean extinction coefficient in 1/m; a surface d metres away keeps "
                          "exp(-2 DENSITY d) of its light (0: none; 4: haze, 70 %% left at 5 cm; 25: thick, 8 %%)",
                          flag="--smoke", metavar="DENSITY")
    smoke_color: tuple[float, float, float] = option((0.85, 0.85, 0.85), "smoke albedo, linear R,G,B",
                                                     parse=parse_triple, metavar="R,G,B")
    smoke_variation: float = option(0.6, "smoke: relative amplitude of its density variation (0-1)")
    smoke_scale: float = option(0.35, "smoke: size of its puffs, as a share of the image width")
    smoke_drift: float = option(0.15, "smoke: drift speed, image widths per second")

    def validated(self) -> EnvironmentOptions:
        checks = [("smoke", self.smoke >= 0, "must not be negative"),
                  ("smoke_color", len(self.smoke_color) == 3 and min(self.smoke_color) >= 0,
                   "must be three non-negative values"),
                  ("smoke_variation", 0 <= self.smoke_variation <= 1, "must be between 0 and 1"),
                  ("smoke_scale", self.smoke_scale > 0, "must be positive"),
                  ("smoke_drift", self.smoke_drift >= 0, "must not be negative")]
        for name, ok, message in checks:
            if not ok:
                raise OptionError(name, f"{message}, got {getattr(self, name)!r}")
        return replace(self, smoke=float(self.smoke), smoke_color=tuple(float(v) for v in self.smoke_color))

    def to_dict(self) -> dict:
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> EnvironmentOptions:
        d = dict(d)
        if "smoke_color" in d:
            d["smoke_color"] = tuple(d["smoke_color"])
        return cls(**d)
