"""The scene configuration file (``--scene-config``): objects, their motions, tracked frames and the tissue's
deformation, in TOML (``.toml``) or YAML (``.yaml``/``.yml``) with the same keys.

```toml
[deformation]                # the tissue: a preset (or --deform's) and overrides of its fields
preset = "breathing"
amplitude_m = 0.003

[[objects]]                  # the built-in instrument (--instrument adds one with the defaults)
kind = "instrument"
name = "grasper"
shaft_diameter = 0.005       # metres; also shaft_length, wrist_length, jaw_length, segments
look = "metal"               # the shaft's: metal or dark_plastic (wrist and jaws are metal)
motion = { jaw_open_deg = 30, trocar_azimuth_deg = 90 }

[[objects]]                  # a mesh file (OBJ, PLY, STL, GLB/glTF, OFF)
kind = "mesh"
file = "clip.stl"            # relative to this file
scale = 0.001                # file units -> metres
class = "clip"
material = "color"           # color, metal, dark_plastic, as_captured, wet_tissue
color = [0.1, 0.3, 0.8]      # linear RGB; or texture = "clip.png" (the mesh's UVs)
pose = { position = [0.0, 0.01, 0.62], euler_deg = [0, 30, 0] }
# or a motion: keyframes (frame + pose) or a path file like the camera's
# motion = { keyframes = [{ frame = 0, position = [0, 0, 0.6] }, { frame = 59, position = [0.01, 0, 0.6] }] }

[environment]                # what fills the space in front of the scope (render's --smoke etc. replace it)
smoke = 30                   # extinction coefficient, 1/m; also smoke_color, smoke_variation, smoke_scale, ...

[[tracked_frames]]
name = "lesion"
attached_to = "tissue"       # or "<object>" or "<object>/<part>" (instrument parts: shaft, wrist, jaw_upper,
pixel = [320, 240]           # jaw_lower); on the tissue: a pixel of the capture or a position near the surface
```

The file is read and checked by the configuration stack the batch configuration shares
(:mod:`rgbd2scene.config_files`). Every problem is a :class:`ConfigError` whose message starts with the key
path (``objects[1].file``):
unknown keys, missing keys, wrong types, missing files, poses that are not rigid, ids used twice, tracked
frames attached to unknown objects. What needs the scene (an object that never enters the view, a tissue
point off the surface) is checked when the objects are built (:mod:`rgbd2scene.scene.objects.assemble`).
Ids are optional: the ids not given are assigned in order (tissue 1, instrument parts, meshes, tracked
frames), skipping the ones given.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field, ValidationError, create_model

from rgbd2scene.config_files import ConfigError, Strict, model_of, read_config_file, validation_error
from rgbd2scene.environment.settings import EnvironmentOptions
from rgbd2scene.options import OptionError
from rgbd2scene.scene.deformation import PRESETS, Deformation
from rgbd2scene.scene.model import MATERIALS, MAX_ID, TISSUE_ID
from rgbd2scene.scene.objects.imported import MESH_SUFFIXES, rigid_pose
from rgbd2scene.scene.objects.instrument import PARTS as INSTRUMENT_PARTS
from rgbd2scene.scene.objects.instrument import Instrument
from rgbd2scene.scene.objects.motion import MotionOptions

#: Looks of user meshes (``render.materials`` and the tissue's).
MESH_MATERIALS = ("color", "metal", "dark_plastic", *MATERIALS)
TISSUE = "tissue"
MESH_PART = "body"  # the one part of a mesh object


# --------------------------------------------------------------------------- the schema (pydantic v2)

class _Strict(Strict):
    model_config = ConfigDict(extra="forbid", frozen=True)


Vec3 = tuple[float, float, float]


class OrientationModel(_Strict):
    quaternion: tuple[float, float, float, float] | None = None
    euler_deg: Vec3 | None = None
    euler_order: str = "xyz"
    rotation: tuple[Vec3, Vec3, Vec3] | None = None


class PoseModel(OrientationModel):
    matrix: list[list[float]] | None = None
    position: Vec3 | None = None


class KeyframeModel(PoseModel):
    frame: int


class MeshMotionModel(_Strict):
    keyframes: list[KeyframeModel] | None = None
    path_file: str | None = None


MotionModel = model_of(MotionOptions, "MotionModel", _Strict)
InstrumentModel = model_of(Instrument, "InstrumentModel", _Strict, kind=(Literal["instrument"], ...),
                            name=(str | None, None), id=(int | None, None), motion=(MotionModel | None, None))
MeshModel = create_model(
    "MeshModel", __base__=_Strict, kind=(Literal["mesh"], ...), file=(str, ...), name=(str | None, None),
    id=(int | None, None), cls=(str | None, Field(None, alias="class")), scale=(float, 1.0),
    recenter=(bool, False), material=(str, "color"), color=(Vec3 | None, None), texture=(str | None, None),
    pose=(PoseModel | list[list[float]] | None, None), motion=(MeshMotionModel | None, None))
DeformationModel = model_of(Deformation, "DeformationModel", _Strict, exclude=("kind",), optional=True,
                             preset=(Literal["none", *PRESETS] | None, None))
EnvironmentModel = model_of(EnvironmentOptions, "EnvironmentModel", _Strict, optional=True)


class TrackedFrameModel(OrientationModel):
    name: str
    attached_to: str
    id: int | None = None
    position: Vec3 | None = None
    pixel: tuple[float, float] | None = None


class SceneConfigModel(_Strict):
    objects: list[Annotated[InstrumentModel | MeshModel, Field(discriminator="kind")]] = []
    tracked_frames: list[TrackedFrameModel] = []
    deformation: DeformationModel | None = None
    environment: EnvironmentModel | None = None


_TAGS = {"instrument": InstrumentModel, "mesh": MeshModel}


# --------------------------------------------------------------------------- what the file says, resolved

@dataclass
class InstrumentSpec:
    key: str  # e.g. "objects[0]"; "--instrument" for the flag's
    name: str
    instrument: Instrument
    motion: MotionOptions
    first_id: int | None = None  # its parts take first_id .. first_id + 3


@dataclass
class MeshSpec:
    key: str
    name: str
    cls: str
    file: Path
    scale: float = 1.0
    recenter: bool = False
    material: str = "color"
    color: tuple[float, float, float] | None = None
    texture: Path | None = None
    pose: np.ndarray | None = None  # (4, 4)
    keyframes: list[tuple[int, np.ndarray]] | None = None
    path_file: Path | None = None
    id: int | None = None


@dataclass
class FrameSpec:
    key: str
    name: str
    object: str  # "tissue" or an object's name
    part: str | None  # None: the object's only part (or the tissue surface)
    position: np.ndarray | None = None
    pixel: np.ndarray | None = None
    rotation: np.ndarray | None = None  # (3, 3); None: the default orientation
    id: int | None = None


@dataclass
class SceneConfig:
    """A validated scene configuration (paths resolved against the file's folder)."""

    path: Path | None = None
    instruments: list[InstrumentSpec] = field(default_factory=list)
    meshes: list[MeshSpec] = field(default_factory=list)
    tracked_frames: list[FrameSpec] = field(default_factory=list)
    deformation_preset: str | None = None
    deformation_overrides: dict = field(default_factory=dict)
    environment: dict = field(default_factory=dict)  # EnvironmentOptions fields the file sets

    def deformation(self, default_preset: str = "none", **fixed) -> Deformation | None:
        """The tissue's deformation: the file's preset (else ``default_preset``) with the file's overrides and
        ``fixed`` fields (e.g. the centre); None for "none"."""
        preset = self.deformation_preset or default_preset
        if preset == "none":
            if self.deformation_overrides:
                raise ConfigError("deformation.preset: overrides need a preset (breathing or heartbeat) here or "
                                  "from --deform")
            return None
        try:
            return Deformation.preset(preset, **{**fixed, **self.deformation_overrides})
        except (TypeError, ValueError) as exc:
            raise _field_error("deformation", exc, {f.name for f in dataclasses.fields(Deformation)}) from None


def _field_error(key: str, exc: Exception, names) -> ConfigError:
    """``exc`` of a dataclass's checks as an error at ``key.field`` when its message starts with a field name."""
    message = str(exc).removeprefix("deformation ")
    first, _, rest = message.partition(" ")
    if first in names and rest:
        return ConfigError(f"{key}.{first}: {rest}")
    return ConfigError(f"{key}: {message}")


def parse_scene_config(data: dict, base_dir: Path, default_instrument: bool = False,
                       source: Path | None = None) -> SceneConfig:
    """Validate a configuration mapping (paths relative to ``base_dir``); ``default_instrument``: the
    ``--instrument`` flag's instrument is added too unless the mapping has one."""
    if not isinstance(data, dict):
        raise ConfigError("top level: must be a mapping of keys (objects, tracked_frames, deformation)")
    try:
        model = SceneConfigModel.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, SceneConfigModel, _TAGS) from None
    config = SceneConfig(source)
    names = {TISSUE}
    for i, obj in enumerate(model.objects):
        key = f"objects[{i}]"
        if isinstance(obj, InstrumentModel):
            config.instruments.append(_instrument_spec(obj, key, names))
        else:
            config.meshes.append(_mesh_spec(obj, key, base_dir, names))
    if default_instrument and not config.instruments:
        config.instruments.append(InstrumentSpec("--instrument", _unique("instrument", names), Instrument(),
                                                 MotionOptions()))
    parts = {TISSUE: {"surface"}} | {s.name: set(INSTRUMENT_PARTS) for s in config.instruments} | {
        s.name: {MESH_PART} for s in config.meshes}
    for i, frame in enumerate(model.tracked_frames):
        config.tracked_frames.append(_frame_spec(frame, f"tracked_frames[{i}]", parts))
    if model.deformation is not None:
        overrides = model.deformation.model_dump(exclude_none=True)
        config.deformation_preset = overrides.pop("preset", None)
        config.deformation_overrides = overrides
        config.deformation(default_preset="breathing")  # checks the overrides' values
    if model.environment is not None:
        config.environment = model.environment.model_dump(exclude_none=True)
        try:
            EnvironmentOptions.from_dict(config.environment).validated()
        except OptionError as exc:
            raise ConfigError(f"environment.{exc.name}: {exc.message}") from None
    _check_ids(config)
    return config


def load_scene_config(path: str | Path, default_instrument: bool = False) -> SceneConfig:
    """Read and validate a configuration file; :class:`ConfigError` (message: key path and problem)."""
    path = Path(path)
    return parse_scene_config(read_config_file(path), path.parent, default_instrument, path)


def _unique(name: str, names: set[str]) -> str:
    out, k = name, 2
    while out in names:
        out, k = f"{name}_{k}", k + 1
    names.add(out)
    return out


def _claim_name(name: str | None, default: str, key: str, names: set[str]) -> str:
    if name is None:
        return _unique(default, names)
    if not name or "/" in name:
        raise ConfigError(f"{key}.name: must be a non-empty name without '/', got {name!r}")
    if name in names:
        raise ConfigError(f"{key}.name: {name!r} is already used" + (" (the tissue)" if name == TISSUE else ""))
    names.add(name)
    return name


def _instrument_spec(obj, key: str, names: set[str]) -> InstrumentSpec:
    values = obj.model_dump(include={f.name for f in dataclasses.fields(Instrument)})
    try:
        instrument = Instrument(**values)
    except ValueError as exc:
        raise _field_error(key, exc, values) from None
    try:
        motion = MotionOptions(**obj.motion.model_dump()) if obj.motion is not None else MotionOptions()
    except ValueError as exc:
        raise _field_error(f"{key}.motion", exc, {f.name for f in dataclasses.fields(MotionOptions)}) from None
    return InstrumentSpec(key, _claim_name(obj.name, "instrument", key, names), instrument, motion, obj.id)


def _file(value: str, base_dir: Path, key: str, what: str) -> Path:
    path = (base_dir / value).resolve() if not Path(value).is_absolute() else Path(value)
    if not path.is_file():
        raise ConfigError(f"{key}: {what} not found: {path}")
    return path


def _pose(model, key: str) -> np.ndarray:
    if isinstance(model, list):
        return rigid_pose(matrix=model, where=key)
    return rigid_pose(model.matrix, model.position, model.quaternion, model.euler_deg, model.euler_order,
                      model.rotation, where=key)


def _mesh_spec(obj, key: str, base_dir: Path, names: set[str]) -> MeshSpec:
    file = _file(obj.file, base_dir, f"{key}.file", "mesh file")
    if file.suffix.lower() not in MESH_SUFFIXES:
        raise ConfigError(f"{key}.file: unsupported mesh format {file.suffix!r} (use {', '.join(MESH_SUFFIXES)})")
    name = _claim_name(obj.name, file.stem, key, names)
    if obj.material not in MESH_MATERIALS:
        raise ConfigError(f"{key}.material: must be one of {', '.join(MESH_MATERIALS)}, got {obj.material!r}")
    if not (np.isfinite(obj.scale) and obj.scale > 0):
        raise ConfigError(f"{key}.scale: must be a positive number, got {obj.scale}")
    if obj.color is not None and not all(0.0 <= c <= 1.0 for c in obj.color):
        raise ConfigError(f"{key}.color: must be 3 numbers in 0..1 (linear RGB), got {list(obj.color)}")
    spec = MeshSpec(key, name, obj.cls or name, file, obj.scale, obj.recenter, obj.material,
                    None if obj.color is None else tuple(obj.color), id=obj.id)
    if obj.texture is not None:
        spec.texture = _file(obj.texture, base_dir, f"{key}.texture", "texture file")
    try:
        if obj.pose is not None:
            spec.pose = _pose(obj.pose, f"{key}.pose")
        motion = obj.motion
        if motion is not None:
            if obj.pose is not None:
                raise ConfigError(f"{key}.motion: give a pose or a motion, not both")
            if (motion.keyframes is None) == (motion.path_file is None):
                raise ConfigError(f"{key}.motion: give keyframes or path_file (one of them)")
            if motion.keyframes is not None:
                if not motion.keyframes:
                    raise ConfigError(f"{key}.motion.keyframes: needs at least one keyframe")
                spec.keyframes = [(k.frame, _pose(k, f"{key}.motion.keyframes[{j}]"))
                                  for j, k in enumerate(motion.keyframes)]
            else:
                spec.path_file = _file(motion.path_file, base_dir, f"{key}.motion.path_file", "path file")
    except ConfigError:
        raise
    except ValueError as exc:  # the message starts with the key path
        raise ConfigError(str(exc)) from None
    return spec


def _frame_spec(frame, key: str, parts: dict[str, set[str]]) -> FrameSpec:
    if not frame.name:
        raise ConfigError(f"{key}.name: must not be empty")
    obj, _, part = frame.attached_to.partition("/")
    if obj not in parts:
        raise ConfigError(f"{key}.attached_to: unknown object {obj!r} (known: {', '.join(sorted(parts))})")
    if part and part not in parts[obj]:
        raise ConfigError(f"{key}.attached_to: object {obj!r} has no part {part!r} "
                          f"(parts: {', '.join(sorted(parts[obj]))})")
    if not part and len(parts[obj]) > 1:
        raise ConfigError(f"{key}.attached_to: object {obj!r} has several parts: name one as {obj}/PART "
                          f"(parts: {', '.join(sorted(parts[obj]))})")
    on_tissue = obj == TISSUE
    if frame.pixel is not None and not on_tissue:
        raise ConfigError(f"{key}.pixel: a pixel of the capture places frames on the tissue only; give position")
    if frame.pixel is not None and frame.position is not None:
        raise ConfigError(f"{key}: give position or pixel, not both")
    if on_tissue and frame.pixel is None and frame.position is None:
        raise ConfigError(f"{key}: a frame on the tissue needs a pixel of the capture or a position")
    rotation = None
    if any(v is not None for v in (frame.quaternion, frame.euler_deg, frame.rotation)):
        try:
            rotation = rigid_pose(None, None, frame.quaternion, frame.euler_deg, frame.euler_order, frame.rotation,
                                  where=key)[:3, :3]
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    return FrameSpec(key, frame.name, obj, part or None,
                     None if frame.position is None else np.asarray(frame.position, dtype=np.float64),
                     None if frame.pixel is None else np.asarray(frame.pixel, dtype=np.float64), rotation, frame.id)


def _check_ids(config: SceneConfig) -> None:
    """Ids given in the file: in 1..65535, never the tissue's, never twice."""
    owners: dict[int, str] = {TISSUE_ID: "the tissue"}
    claims = [(s.key, range(s.first_id, s.first_id + len(INSTRUMENT_PARTS))) for s in config.instruments
              if s.first_id is not None]
    claims += [(s.key, [s.id]) for s in config.meshes if s.id is not None]
    claims += [(s.key, [s.id]) for s in config.tracked_frames if s.id is not None]
    for key, ids in claims:
        for i in ids:
            if not 1 <= i <= MAX_ID:
                raise ConfigError(f"{key}.id: {i} is not in 1..{MAX_ID}")
            if i in owners:
                raise ConfigError(f"{key}.id: id {i} is already used by {owners[i]}")
            owners[i] = key
