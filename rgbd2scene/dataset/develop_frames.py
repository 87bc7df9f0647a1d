"""A dataset's RGB frames from the linear renders: environment, auto exposure, sensor model, files.

The render worker hands :class:`FrameDeveloper` each frame's linear render of both eyes (and, when an
environment effect needs it, the Depth pass); it writes, in this order, so that a frame whose ``rgb`` PNGs
exist is complete: ``DATASET/sensor/NNNNNN.json`` (the frame's metering and exposure), the ``rgb_clean`` PNGs
(``--clean``), the ``rgb`` PNGs. All through :mod:`rgbd2scene.dataset.layout` (atomic, no time stamps: the same
render gives the same bytes).

Auto exposure meters the left eye (one camera control unit drives both eyes with one exposure). The exposure
of frame i needs the metering of frames i - W + 1 .. i - 1 (:mod:`rgbd2scene.sensor.exposure`): it is read
from their records; a chunk that starts where no record exists yet (a parallel chunk of a batch build)
renders those frames first to meter them (:meth:`FrameDeveloper.missing_history`). The metered log exposure
is rounded to :data:`METER_DECIMALS` so that the tiny float differences of a re-render cannot change it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from rgbd2scene.dataset import layout as ds
from rgbd2scene.environment import EnvironmentOptions, active_effects, apply_environment, ray_length
from rgbd2scene.files.images import write_image
from rgbd2scene.sensor.exposure import frame_exposure, meter
from rgbd2scene.sensor.pipeline import develop
from rgbd2scene.sensor.settings import SensorOptions

METER_DECIMALS = 4


class FrameDeveloper:
    """Environment + sensor model of one dataset (``K``: the intrinsics, for ray lengths; ``fps``: the time
    of each frame for drifting effects).

    ``lens``, when given, maps one eye's linear image (after the environment) to the image the scope's lens
    forms, ``lens(linear, eye) -> linear`` (a lens-distortion resampling); metering and the sensor model see
    its output.
    """

    def __init__(self, out_dir: str | Path, sensor: SensorOptions, environment: EnvironmentOptions, seed: int,
                 fps: float, K: np.ndarray, lens: Callable[[np.ndarray, str], np.ndarray] | None = None):
        self.out_dir = Path(out_dir)
        self.sensor = sensor
        self.seed = int(seed)
        self.fps = float(fps)
        self.K = np.asarray(K, dtype=np.float64)
        self.effects = active_effects(environment, self.seed)
        self.lens = lens
        self.metered: dict[int, float] = {}

    @property
    def needs_depth(self) -> bool:
        """Whether the linear render must come with its Depth pass (an environment effect is on)."""
        return bool(self.effects)

    @property
    def auto(self) -> bool:
        return self.sensor.exposure == "auto"

    def _window(self, index: int) -> range:
        return range(max(0, index - int(self.sensor.ae_window) + 1), index)

    def _known(self, index: int) -> float | None:
        if index not in self.metered:
            record = ds.read_sensor_record(self.out_dir, index)
            if record is not None and record.get("metered_log_exposure") is not None:
                self.metered[index] = float(record["metered_log_exposure"])
        return self.metered.get(index)

    def missing_history(self, index: int, coming=()) -> list[int]:
        """Earlier frames whose metering frame ``index``'s auto exposure needs and nobody has recorded, leaving
        out the frames in ``coming`` (developed, so metered, before ``index``)."""
        if not self.auto:
            return []
        coming = set(coming)
        return [j for j in self._window(index) if j not in coming and self._known(j) is None]

    def scene_linear(self, index: int, eye: str, linear: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """One eye's linear render through the environment effects and the lens."""
        linear = np.asarray(linear, dtype=np.float32)
        if self.effects:
            linear = apply_environment(linear, ray_length(depth, self.K), index / self.fps, self.effects)
        return linear if self.lens is None else self.lens(linear, eye)

    def meter(self, index: int, left_linear: np.ndarray) -> float:
        """Meter frame ``index`` (its left eye, after the environment) and remember it."""
        value = round(meter(left_linear, self.sensor), METER_DECIMALS)
        self.metered[index] = value
        return value

    def develop_frame(self, index: int, linear: dict[str, np.ndarray],
                      depth: dict[str, np.ndarray] | None = None) -> dict:
        """Write frame ``index`` (both eyes) from its linear renders; returns its sensor record."""
        scene = {eye: self.scene_linear(index, eye, linear[eye], None if depth is None else depth[eye])
                 for eye in linear}
        record: dict = {"frame": int(index), "exposure_mode": self.sensor.exposure}
        history: list[float] = []
        if self.auto:
            missing = self.missing_history(index)
            if missing:
                raise RuntimeError(f"frame {index}: auto exposure needs the metering of frames {missing} first")
            history = [self.metered[j] for j in self._window(index)]
            history.append(self.meter(index, scene["left"]))
            record["metered_log_exposure"] = history[-1]
            record["window"] = [self._window(index).start, index]
        exposure = frame_exposure(history, self.sensor)
        record.update(exposure.to_dict())
        ds.write_sensor_record(self.out_dir, index, record)
        developed = {eye: develop(scene[eye], index, eye, self.sensor, exposure, self.seed) for eye in scene}
        if self.sensor.clean:
            for eye, out in developed.items():
                write_image(ds.clean_rgb_path(self.out_dir, eye, index), out.clean)
        for eye, out in developed.items():
            ds.write_rgb(ds.frame_paths(self.out_dir, eye, index).rgb, out.rgb)
        return record
