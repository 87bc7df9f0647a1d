"""Environment effects of the scene (numpy, no ``bpy``): what fills the space between scope and surface.

Each effect is a file here with a class built ``from_options(EnvironmentOptions, seed)`` and an
``apply(linear, distance, time_s)`` on one eye's linear RGB and its per-pixel ray length; :data:`EFFECTS` lists
them with the test of whether the options switch them on. A new effect (blood on the lens, fogging) is a new file,
its fields in :class:`EnvironmentOptions` and an entry here. They change only the RGB images, never the ground
truth, and run before the sensor model (:mod:`rgbd2scene.sensor`).
"""

from __future__ import annotations

import numpy as np

from rgbd2scene.environment.settings import EnvironmentOptions
from rgbd2scene.environment.smoke import Smoke, ray_length

#: name -> (effect class, is it on for these options?)
EFFECTS = {"smoke": (Smoke, lambda o: o.smoke > 0)}


def active_effects(options: EnvironmentOptions, seed: int) -> list:
    """The effects the options switch on, built (in :data:`EFFECTS` order)."""
    return [cls.from_options(options, seed) for cls, on in EFFECTS.values() if on(options)]


def apply_environment(linear: np.ndarray, distance: np.ndarray | None, time_s: float, effects: list) -> np.ndarray:
    """``linear`` through every effect in turn."""
    for effect in effects:
        linear = effect.apply(linear, distance, time_s)
    return linear


__all__ = ["EFFECTS", "EnvironmentOptions", "Smoke", "active_effects", "apply_environment", "ray_length"]
