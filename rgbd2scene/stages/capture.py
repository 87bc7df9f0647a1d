"""The capture stage: what the user captured, read and checked once for the CLI, batch builds and the API.

A capture is one of three kinds (:attr:`CaptureOptions.mode`):

- ``rgbd``: one RGB-D frame (``rgb``, ``depth``, and ``camera`` or ``preset``);
- ``fusion``: several RGB-D frames fused into one mesh (``rgb: [...]``, ``depth: [...]``, ``poses`` optional:
  estimated by RGB-D odometry without it);
- ``stereo``: a stereo endoscope frame (``left``, ``right``, ``stereo_calib``).

:class:`CaptureOptions` declares every setting once (``rgbd2scene.options``): the CLI flags of ``mesh`` and
``scene`` and the capture keys of a batch configuration derive from it. :func:`check_inputs` finds what is
wrong without reading the images (the kind, options of another kind, values, the trajectory, the stereo
calibration), so a batch build refuses a bad configuration before it starts; :func:`load_inputs` reads
the capture into a :class:`LoadedCapture` and :func:`reconstruct_inputs` turns it into a reconstruction.

Errors are :class:`~rgbd2scene.options.OptionError`\\ s naming the field (each front end spells it: ``--poses``
on the command line, ``captures[0].poses`` in a configuration) or :class:`UserError`\\ s naming the file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rgbd2scene.capture.camera import PRESET_SENSOR, PRESETS, camera_for
from rgbd2scene.capture.readers import DEPTH_FORMATS, Capture, load_capture, read_rgb
from rgbd2scene.capture.stereo import (
    MATCHERS,
    StereoCalibration,
    StereoOptions,
    load_stereo_capture,
    read_stereo_calibration,
)
from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError, option
from rgbd2scene.reconstruct.fill import FillResult
from rgbd2scene.reconstruct.pipeline import MeshOptions, Reconstruction, reconstruct

# Fusion (its ray caster, SciPy's graph routines) and trajectory files serve several frames only: imported where
# a capture has several, not at the start of every command
if TYPE_CHECKING:
    from rgbd2scene.reconstruct.fusion import FusionOptions

INPUT = "capture (an RGB-D frame, several frames to fuse, or a stereo frame)"
FUSION = "fusion of several frames"
STEREO = "stereo"
MODES = ("rgbd", "fusion", "stereo")
_WHAT = {"rgbd": "a single RGB-D frame", "fusion": "fused RGB-D frames", "stereo": "a stereo frame"}
#: The fields that only one kind of capture takes, with that kind.
_FOREIGN = {"voxel_size": "fusion", "min_frames": "fusion", "matcher": "stereo", "depth_range": "stereo"}
_RGBD_ONLY = ("camera", "preset", "depth_scale", "depth_format")
_FILE_KINDS = {"rgb": "RGB image", "depth": "depth file", "camera": "camera file", "left": "RGB image",
               "right": "RGB image"}


def _fields(*names: str) -> str:
    """``{a}, {b} and {c}``: fields named in an OptionError sentence (each front end spells them)."""
    spelled = [f"{{{n}}}" for n in names]
    return spelled[0] if len(spelled) == 1 else f"{', '.join(spelled[:-1])} and {spelled[-1]}"


@dataclass
class CaptureOptions:
    """Every setting of the capture input (CLI flags of ``mesh`` and ``scene``, batch capture keys)."""

    rgb: list[str] | None = option(None, "colour image(s) (PNG, JPEG, PPM, BMP); several frames are fused",
                                   nargs="+", file=True, group=INPUT, metavar="RGB")
    depth: list[str] | None = option(None, "depth: 16-bit PNG, float EXR/.npy (m), NYU raw PGM, SUN PNG; one per "
                                     "--rgb", nargs="+", file=True, group=INPUT, metavar="DEPTH")
    poses: str | None = option(None, "camera trajectory of the frames: TUM (timestamp tx ty tz qx qy qz qw) or "
                               "Redwood/Open3D .log; default: estimated by RGB-D odometry", file=True, group=INPUT)
    camera: str | None = option(None, "camera JSON: {width,height,fx,fy,cx,cy} or Open3D intrinsic_matrix",
                                file=True, group=INPUT)
    preset: str | None = option(None, f"named camera: {', '.join(PRESETS)} (default primesense)", group=INPUT)
    depth_scale: float | None = option(None, "depth units per metre (1000 for mm PNG, 5000 for TUM)", group=INPUT)
    depth_format: str = option("auto", "depth file format", choices=DEPTH_FORMATS, group=INPUT)
    left: str | None = option(None, "left image of a stereo endoscope frame", file=True, group=INPUT)
    right: str | None = option(None, "right image of the stereo frame", file=True, group=INPUT)
    stereo_calib: str | None = option(None, "stereo calibration: JSON (K_left, D_left, K_right, D_right, R, T in "
                                      "metres, image_size) or a Hamlyn-style folder (calib.left.intrinsic.txt, ..., "
                                      "calib.l2r.4x4 in mm)", file=True, group=INPUT)
    voxel_size: float | None = option(None, "TSDF voxel edge in metres (default 1.5 pixel footprints at the first "
                                      "frame's median depth)", group=FUSION)
    min_frames: int | None = option(None, "keep surface seen by at least this many frames (default 1)", group=FUSION)
    matcher: str = option("auto", "stereo matcher (default auto: ELAS when pyelas is installed, else SGBM)",
                          choices=MATCHERS, group=STEREO)
    depth_range: tuple[float, float] | None = option(None, "expected depth range in metres; sets the disparities "
                                                     "searched (default 0.02 0.5)", nargs=2,
                                                     metavar=("MIN", "MAX"), group=STEREO)

    def given(self) -> bool:
        """Whether any capture input is given (the scene stage may build from a mesh folder instead)."""
        return any((self.rgb, self.depth, self.left, self.right, self.stereo_calib))

    @property
    def mode(self) -> str:
        """``rgbd``, ``fusion`` or ``stereo``; :class:`OptionError` when the inputs mix kinds or lack a part."""
        stereo = {"left": self.left, "right": self.right, "stereo_calib": self.stereo_calib}
        if any(stereo.values()):
            if self.rgb or self.depth or self.poses:
                raise OptionError("left", f"give an RGB-D capture ({_fields('rgb', 'depth', 'poses')}) or a stereo "
                                  f"frame ({_fields(*stereo)}), not both")
            missing = [name for name, value in stereo.items() if not value]
            if missing:
                raise OptionError(missing[0], f"a stereo frame needs {_fields(*stereo)} (missing "
                                  f"{_fields(*missing)})")
            return "stereo"
        if not self.rgb or not self.depth:
            raise OptionError("rgb" if not self.rgb else "depth",
                              f"give {_fields('rgb', 'depth')} (an RGB-D capture; several of each to fuse frames) "
                              f"or {_fields('left', 'right', 'stereo_calib')} (a stereo frame)")
        if len(self.rgb) != len(self.depth):
            raise OptionError("depth", f"{{rgb}} has {len(self.rgb)} files but {{depth}} has {len(self.depth)}; "
                              "give one depth per colour image")
        if len(self.rgb) == 1:
            if self.poses:
                raise OptionError("poses", "{poses} needs several frames ({rgb} A B ... {depth} A B ...)")
            return "rgbd"
        return "fusion"

    def check(self) -> str:
        """The capture's mode after checking every value; :class:`OptionError` naming the first bad field
        (options of another kind of capture are refused: they would be ignored)."""
        mode = self.mode
        foreign = [name for name, kind in _FOREIGN.items() if kind != mode and getattr(self, name) != _default(name)]
        if mode == "stereo":
            foreign = [name for name in _RGBD_ONLY if getattr(self, name) != _default(name)] + foreign
        if foreign:
            why = " (the calibration gives the camera, stereo matching the depth)" if foreign[0] in _RGBD_ONLY else ""
            raise OptionError(foreign[0], f"{', '.join(f'{{{n}}}' for n in foreign)} do(es) not apply to "
                              f"{_WHAT[mode]}{why}")
        if self.camera and self.preset:
            raise OptionError("preset", "give {camera} or {preset}, not both")
        if self.preset is not None and self.preset.lower() not in PRESETS:
            raise OptionError("preset", f"unknown camera preset {self.preset!r}; choose one of {', '.join(PRESETS)}")
        if self.depth_scale is not None and not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise OptionError("depth_scale", f"must be a positive number, got {self.depth_scale}")
        if self.voxel_size is not None and not (math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise OptionError("voxel_size", f"must be a positive number of metres, got {self.voxel_size}")
        if self.min_frames is not None and self.min_frames < 1:
            raise OptionError("min_frames", f"must be at least 1, got {self.min_frames}")
        if mode == "stereo":
            try:
                self.stereo_options().check()
            except ValueError as exc:
                raise OptionError("depth_range" if self.depth_range else "matcher", str(exc)) from None
        return mode

    def stereo_options(self) -> StereoOptions:
        stereo = StereoOptions(matcher=self.matcher)
        if self.depth_range is not None:
            stereo.min_depth, stereo.max_depth = (float(v) for v in self.depth_range)
        return stereo

    def fusion_options(self) -> FusionOptions:
        from rgbd2scene.reconstruct.fusion import FusionOptions

        fusion = FusionOptions(voxel_size=self.voxel_size)
        if self.min_frames is not None:
            fusion.min_frames = self.min_frames
        return fusion


def _default(name: str):
    return CaptureOptions.__dataclass_fields__[name].default


@dataclass
class LoadedCapture:
    """A capture as read: its ``mode``, its frames (one, or several to fuse; a stereo frame is its rectified
    left image with the matched depth), and for fusion the frames' poses relative to the first (None:
    estimated by odometry) with their scene.json record and the fusion settings."""

    mode: str
    frames: list[Capture]
    poses: np.ndarray | None = None
    poses_record: dict | None = None
    fusion: FusionOptions | None = None

    @property
    def first(self) -> Capture:
        return self.frames[0]


def read_poses(path: str, frames: list[str]) -> tuple[np.ndarray, dict]:
    """Poses of ``frames`` (file names, in order) from the trajectory ``path``, relative to the first frame,
    and their scene.json record; :class:`OptionError` on ``poses`` naming the file and the problem."""
    from rgbd2scene.capture.trajectory import associate, read_trajectory, relative_to_first

    try:
        trajectory = read_trajectory(path)
        match = associate(trajectory, frames)
    except FileNotFoundError:
        raise OptionError("poses", f"{path}: trajectory file not found") from None
    except (OSError, ValueError) as exc:
        raise OptionError("poses", f"{path}: {exc}") from None
    record = {"source": "given", "file": str(path), "format": trajectory.fmt, "association": match.rule,
              "trajectory_indices": match.indices.tolist(), "max_time_difference_s": match.max_time_difference_s,
              "note": "re-expressed so that the first frame's camera frame is the world frame"}
    return relative_to_first(match.poses), record


def read_calibration(path: str, left: str) -> StereoCalibration:
    """The stereo calibration ``path`` of the images ``left`` (and right), checked against their size;
    :class:`OptionError` on ``stereo_calib`` naming the file and the problem."""
    if not Path(path).exists():
        raise OptionError("stereo_calib", f"{path}: stereo calibration not found")
    image = read_rgb(left)
    size = (image.shape[1], image.shape[0])
    try:
        calib = read_stereo_calibration(path, image_size=size)  # a folder takes the images' size
    except (OSError, ValueError) as exc:
        raise OptionError("stereo_calib", f"{path}: bad stereo calibration: {exc}") from None
    if calib.size != size:
        raise OptionError("stereo_calib", f"{left}: the images are {size[0]}x{size[1]} but the calibration {path} "
                          f"is for {calib.width}x{calib.height}")
    return calib


def check_inputs(options: CaptureOptions) -> str:
    """Check a capture without reading its depth: the kind, the values, that the files exist, the trajectory
    (parsed and matched to the frames) and the stereo calibration (parsed and checked). Returns the mode."""
    mode = options.check()
    files = ("left", "right") if mode == "stereo" else ("rgb", "depth", "camera")
    for name in files:
        for path in _as_list(getattr(options, name)):
            if not Path(path).is_file():
                raise OptionError(name, f"{path}: {_FILE_KINDS[name]} not found")
    if mode == "fusion" and options.poses:
        read_poses(options.poses, options.rgb)
    if mode == "stereo":
        read_calibration(options.stereo_calib, options.left)
    return mode


def _as_list(value) -> list:
    return [] if value is None else [value] if isinstance(value, str) else list(value)


def load_inputs(options: CaptureOptions) -> LoadedCapture:
    """Read and check the capture (:func:`check_inputs`, then the images): a stereo frame is rectified and
    matched, RGB-D frames are read with the camera's intrinsics and depth scale (each frame records the
    depth sensor its preset names)."""
    mode = check_inputs(options)
    if mode == "stereo":
        frame = load_stereo_capture(options.left, options.right, options.stereo_calib, options.stereo_options())
        return LoadedCapture(mode, [frame])
    intr, scale = camera_for(options.camera, options.preset, options.depth_scale)
    sensor = PRESET_SENSOR[options.preset.lower()] if options.preset else None
    frames = [load_capture(rgb, depth, intr, depth_scale=scale, depth_format=options.depth_format, sensor=sensor)
              for rgb, depth in zip(options.rgb, options.depth, strict=True)]
    if mode == "rgbd":
        return LoadedCapture(mode, frames)
    poses, record = read_poses(options.poses, options.rgb) if options.poses else (None, None)
    return LoadedCapture(mode, frames, poses, record, options.fusion_options())


def reconstruct_inputs(loaded: LoadedCapture, mesh: MeshOptions | None = None,
                       on_filled: Callable[[Capture, FillResult], None] | None = None) -> Reconstruction:
    """The reconstruction of a loaded capture: one frame (RGB-D or stereo) filled, meshed and smoothed, or
    several fused (fill and smoothing then default to none). ``on_filled``: see
    :func:`rgbd2scene.reconstruct.pipeline.reconstruct` (fused frames have no fill: not called)."""
    if loaded.mode != "fusion":
        return reconstruct(loaded.first, mesh, on_filled)
    from rgbd2scene.reconstruct.fusion import reconstruct_fused

    try:
        return reconstruct_fused(loaded.frames, loaded.poses, mesh, loaded.fusion, poses_record=loaded.poses_record)
    except OptionError:
        raise
    except ValueError as exc:
        raise UserError(f"fusion: {exc}") from None
