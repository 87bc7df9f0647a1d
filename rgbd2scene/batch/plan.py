"""The deterministic expansion of a configuration into sequences.

Capture ``c`` gets sequences ``c_000``, ``c_001``, ... (``sequences.per_capture``); sequence ``k`` follows path
kind ``paths[k % len(paths)]``. Its seed is a hash of the configuration seed and its name (never the order in
which anything runs), and seeds its camera path, its Cycles noise and each of its variations (one stream per
variation, so adding a variation leaves the others' draws as they were).
"""

from __future__ import annotations

import hashlib
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from rgbd2scene.batch.config import BatchConfig, Capture, check_scene
from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError
from rgbd2scene.stages.render import RenderOptions
from rgbd2scene.stages.scene import SceneOptions

#: Seeds stay below 2**31 (Blender's integer properties, such as the Cycles seed, are signed 32-bit).
SEED_BITS = 31


def sequence_seed(config_seed: int, sequence: str) -> int:
    """The seed of sequence ``sequence``: sha256 of the configuration seed and the name, 31 bits."""
    digest = hashlib.sha256(f"{int(config_seed)}/{sequence}".encode()).digest()
    return int.from_bytes(digest[:8], "little") % (1 << SEED_BITS)


def variation_rng(seed: int, name: str) -> np.random.Generator:
    """The random stream of variation ``name`` in the sequence with ``seed``."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def sequence_name(capture: str, index: int) -> str:
    return f"{capture}_{index:03d}"


@dataclass(frozen=True)
class SequencePlan:
    """One sequence: its folder name, capture, split, path kind, seed, length, scene options as built and
    the values its variations drew (``sampled``, in the manifest)."""

    name: str
    capture: Capture
    index: int
    path: str
    seed: int
    frames: int
    scene: SceneOptions
    sampled: dict = field(default_factory=dict)

    @property
    def split(self) -> str:
        return self.capture.split

    def render_options(self, render: RenderOptions) -> RenderOptions:
        """The render settings of this sequence: its length, and its seed for the RGB noise."""
        return replace(render, frames=self.frames, seed=self.seed)


@dataclass
class Plan:
    config: BatchConfig
    sequences: list[SequencePlan]

    @property
    def frames(self) -> int:
        return sum(s.frames for s in self.sequences)

    def of_capture(self, capture: str) -> list[SequencePlan]:
        return [s for s in self.sequences if s.capture.name == capture]


def make_plan(config: BatchConfig) -> Plan:
    """Every sequence of ``config`` with its options; a sampled value the scene stage would refuse is a
    :class:`UserError` naming the configuration key that produced it."""
    sequences = []
    for capture in config.captures:
        for k in range(config.per_capture):
            name = sequence_name(capture.name, k)
            seed = sequence_seed(config.seed, name)
            sampled = {v.name: v.sample(variation_rng(seed, v.name)) for v in config.variations.values()}
            kind = config.paths[k % len(config.paths)]
            values = {**capture.scene, **sampled, "path": kind, "frames": config.frames, "seed": seed}
            where = {**capture.scene_where, **{k: f"variations.{k}" for k in sampled}}
            try:
                options = check_scene(values, where)
            except OptionError as exc:
                raise UserError(f"{config.path}: {exc.name}: {exc.message} (sequence {name})") from None
            sequences.append(SequencePlan(name, capture, k, "file" if options.path_file else kind, seed,
                                          config.frames, options, sampled))
    return Plan(config, sequences)
