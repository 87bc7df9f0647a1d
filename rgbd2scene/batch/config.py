"""The batch configuration (CONVENTIONS §8): YAML or TOML, the same keys, validated into :class:`BatchConfig`.

```yaml
seed: 0
captures:
  - name: tissue_a                 # names the capture's sequences (default: the file or folder name)
    rgb: a/rgb.png                 # paths relative to this file; globs (a/*/rgb.png) give one capture per match
    depth: a/depth.png
    camera: a/camera.json          # or preset: tum_fr1; depth_scale: 5000 overrides the JSON's
    split: train                   # train | val | test (default train)
    mesh: {fill: inpaint}          # MeshOptions keys for this capture
    scene: {baseline: 0.004}       # SceneOptions keys for this capture
  - name: room                     # fused frames: lists (a glob in a list: its matches, sorted), one capture
    rgb: [room/color/*.jpg]
    depth: [room/depth/*.png]
    poses: room/trajectory.log     # optional (estimated by odometry without it); voxel_size, min_frames
    camera: room/camera.json
  - left: scope/left.png           # a stereo endoscope frame (globs paired by their wildcards, as rgb/depth)
    right: scope/right.png
    stereo_calib: scope/calib      # JSON file or Hamlyn-style folder; matcher, depth_range: [0.02, 0.2]
  - scene: old/scene               # an existing scene folder (its mesh is reused), or
    split: test                    # scene: {folder: old/scene, baseline: 0.004}
scene: {material: wet_tissue}      # SceneOptions for every capture (a capture's own keys win)
mesh: {smooth: ray}                # MeshOptions for every capture
sequences: {per_capture: 2, frames: 30, paths: [scan, orbit]}   # path kinds cycled over a capture's sequences
render: {size: 256x128, samples: 1, chunk: 25}                  # RenderOptions keys
variations:                        # drawn per sequence, over any SceneOptions field
  light_power_w: [0.02, 0.08]      # two numbers: uniform in [lo, hi] (integers for integer fields)
  material: [wet_tissue, as_captured]       # otherwise a list: one of them
  deform: {choice: [none, breathing]}       # explicit forms: {uniform: [lo, hi]}, {choice: [...]}
```

The file is read and its structure checked by the configuration stack the scene configuration shares
(:mod:`rgbd2scene.config_files`: YAML or TOML, pydantic models refusing unknown keys). A capture's input keys
are the fields of the capture stage's :class:`~rgbd2scene.stages.capture.CaptureOptions` (the CLI's capture
flags), checked by the stage itself (:func:`~rgbd2scene.stages.capture.check_inputs`: the same errors as on
the command line, the trajectory and the stereo calibration read at once); the ``mesh``, ``scene`` and
``render`` mappings and the variations go through the options dataclasses
(:func:`rgbd2scene.options.from_mapping`), so options other stages add are configuration keys at once.
Every problem is one :class:`UserError` line ``CONFIG: key.path: problem``.
"""

from __future__ import annotations

import glob
import json
import os
import re
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, create_model, field_validator, model_validator

from rgbd2scene.config_files import ConfigError, Strict, read_config_file, validation_error
from rgbd2scene.errors import UserError
from rgbd2scene.options import OptionError, from_mapping
from rgbd2scene.reconstruct.pipeline import MeshOptions
from rgbd2scene.scene import folder as scene_files
from rgbd2scene.stages.capture import CaptureOptions, check_inputs
from rgbd2scene.stages.render import RenderOptions
from rgbd2scene.stages.scene import SceneOptions

SPLITS = ("train", "val", "test")
#: SceneOptions fields each sequence gets from the plan, never from the configuration's ``scene`` or variations.
PLANNED_SCENE_KEYS = {"path": "sequences.paths", "frames": "sequences.frames",
                      "seed": "the sequence seed (from seed and the sequence name)"}
#: RenderOptions fields each sequence gets from the plan.
PLANNED_RENDER_KEYS = {"frames": "sequences.frames", "start": "the chunks", "end": "the chunks",
                       "seed": "the sequence seed (from seed and the sequence name)"}
#: Render keys that change how a build runs but not what it writes: they may differ when a build resumes.
EXECUTION_KEYS = frozenset({"render.chunk", "render.threads"})
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
CONFIG_FORMAT = "rgbd2scene-batch-config"


# --- the file's structure (pydantic) ----------------------------------------------------------------------

#: A capture entry's input keys: the capture stage's options (their values are checked by the stage).
CAPTURE_KEYS = tuple(f.name for f in fields(CaptureOptions))
#: Input keys that name files, and those of them that may be globs giving one capture per match.
_FILE_KEYS = tuple(f.name for f in fields(CaptureOptions) if f.metadata.get("file"))
_PER_MATCH = ("rgb", "left")
#: Input keys that take a list (the frames of a fused sequence).
_LIST_KEYS = ("rgb", "depth")


class _CaptureBase(Strict):
    """One ``captures`` entry as written (paths not yet resolved, globs not yet expanded): its name, split,
    scene and mesh settings, and (:data:`CaptureEntry`) the capture stage's input keys."""

    name: str | None = None
    scene: Any = None
    mesh: dict[str, Any] = Field(default_factory=dict)
    split: Literal[SPLITS] = "train"  # type: ignore[valid-type]

    @field_validator("name")
    @classmethod
    def _name(cls, value):
        if value is not None and not NAME.match(value):
            raise ValueError(f"{value!r}: use letters, digits, '_', '-' and '.' (it names folders)")
        return value

    @field_validator("scene")
    @classmethod
    def _scene(cls, value):
        if value is not None and not isinstance(value, (str, dict)):
            raise ValueError("give a scene folder, or a mapping of scene options (with folder: for a scene folder)")
        return value

    @model_validator(mode="after")
    def _source(self):
        folder = self.scene_folder
        given = [key for key in CAPTURE_KEYS if getattr(self, key) is not None]
        if folder is None and not given:
            raise ValueError("give rgb and depth (an RGB-D capture; lists of them to fuse frames), left, right and "
                             "stereo_calib (a stereo frame), or scene: a scene folder")
        if folder is not None and given:
            raise ValueError(f"give either a capture ({', '.join(given)}) or a scene folder, not both")
        if folder is not None and self.mesh:
            raise ValueError("mesh options need a capture: a scene folder's mesh is already built")
        return self

    @property
    def scene_folder(self) -> str | None:
        if isinstance(self.scene, str):
            return self.scene
        if isinstance(self.scene, dict):
            return self.scene.get("folder")
        return None

    @property
    def scene_options(self) -> dict:
        return {k: v for k, v in self.scene.items() if k != "folder"} if isinstance(self.scene, dict) else {}

    @property
    def inputs(self) -> dict:
        """The input keys the entry sets, as written."""
        return {key: getattr(self, key) for key in CAPTURE_KEYS if getattr(self, key) is not None}


CaptureEntry = create_model("CaptureEntry", __base__=_CaptureBase, **{key: (Any, None) for key in CAPTURE_KEYS})


class SequencesEntry(Strict):
    per_capture: int = Field(1, ge=1)
    frames: int = Field(30, ge=1)
    paths: list[str] = Field(default_factory=lambda: ["scan"], min_length=1)


class ConfigFile(Strict):
    seed: int = Field(0, ge=0)
    captures: list[CaptureEntry] = Field(min_length=1)
    sequences: SequencesEntry = Field(default_factory=SequencesEntry)
    scene: dict[str, Any] = Field(default_factory=dict)
    mesh: dict[str, Any] = Field(default_factory=dict)
    render: dict[str, Any] = Field(default_factory=dict)
    variations: dict[str, Any] = Field(default_factory=dict)


# --- the validated configuration ------------------------------------------------------------------------

@dataclass(frozen=True)
class Capture:
    """One capture after glob expansion: its inputs (the capture stage's options, absolute paths), split, mesh
    and scene settings; or an existing scene folder (``scene_dir``).

    ``where`` is its key path (``captures[1]``) for messages; ``scene`` and ``mesh_keys`` hold only the keys the
    configuration sets for it (the top-level ``scene``/``mesh`` merged with its own), already parsed, and
    ``scene_where`` the key path that set each.
    """

    name: str
    split: str
    where: str
    inputs: CaptureOptions | None = None
    scene_dir: str | None = None
    mesh: MeshOptions = field(default_factory=MeshOptions)
    mesh_keys: dict = field(default_factory=dict)
    scene: dict = field(default_factory=dict)
    scene_where: dict = field(default_factory=dict)

    @property
    def rgb(self) -> str | list[str] | None:
        """The colour image (a list of them for fused frames)."""
        return _single(self.inputs.rgb) if self.inputs else None

    @property
    def depth(self) -> str | list[str] | None:
        return _single(self.inputs.depth) if self.inputs else None

    @property
    def camera(self) -> str | None:
        return self.inputs.camera if self.inputs else None

    @property
    def source(self) -> tuple:
        """What identifies the captured scene (two captures with one source must share a split)."""
        if self.scene_dir:
            return (self.scene_dir,)
        i = self.inputs
        return (*(i.rgb or ()), *(i.depth or ()), i.left, i.right)

    def record(self) -> dict:
        out = {"name": self.name, "split": self.split}
        if self.scene_dir:
            out["scene_dir"] = self.scene_dir
        else:
            out.update(_inputs_record(self.inputs), mesh=self.mesh_keys)
        out["scene"] = self.scene
        return out


def _single(paths: list[str] | None) -> str | list[str] | None:
    return paths[0] if paths and len(paths) == 1 else paths


def _inputs_record(inputs: CaptureOptions) -> dict:
    """The input keys of a capture for ROOT/config.json: an RGB-D frame's always (as before fused and stereo
    captures were accepted), the others' where they differ from the defaults."""
    out = {}
    always = ("rgb", "depth", "camera", "preset", "depth_scale", "depth_format") if inputs.rgb else ()
    for f in fields(CaptureOptions):
        value = getattr(inputs, f.name)
        if f.name in always or value != f.default:
            out[f.name] = _single(value) if f.name in ("rgb", "depth") else value
    return out


@dataclass(frozen=True)
class Variation:
    """A per-sequence draw of one SceneOptions field: ``uniform`` over [lo, hi] or a ``choice`` of values."""

    name: str
    kind: Literal["uniform", "choice"]
    values: tuple
    integer: bool = False

    def sample(self, rng) -> Any:
        """One value from ``rng`` (a numpy Generator); floats keep 6 significant digits (the recorded value
        is the rendered one)."""
        if self.kind == "choice":
            return self.values[int(rng.integers(len(self.values)))]
        lo, hi = self.values
        if self.integer:
            return int(rng.integers(lo, hi, endpoint=True))
        return float(f"{rng.uniform(lo, hi):.6g}")

    def record(self) -> dict:
        return {self.kind: list(self.values)}


@dataclass
class BatchConfig:
    """A validated configuration: the file it came from, the seed, the captures (globs expanded), the sequence
    settings, the render options (validated) with the keys the file set, and the variations."""

    path: Path
    seed: int
    captures: list[Capture]
    per_capture: int
    frames: int
    paths: tuple[str, ...]
    render: RenderOptions
    render_keys: dict
    variations: dict[str, Variation]

    def record(self) -> dict:
        """The normalised configuration (absolute paths, parsed values) that ROOT/config.json keeps."""
        out = {"format": CONFIG_FORMAT, "seed": self.seed, "captures": [c.record() for c in self.captures],
               "sequences": {"per_capture": self.per_capture, "frames": self.frames, "paths": list(self.paths)},
               "render": self.render_keys, "variations": {k: v.record() for k, v in self.variations.items()}}
        return json.loads(json.dumps(out))  # tuples -> lists, as read back from the file


# --- loading ---------------------------------------------------------------------------------------------

def read_mapping(path: Path) -> dict:
    """The configuration file's contents (YAML or TOML, by suffix) as a mapping; :class:`UserError` naming the file."""
    try:
        return read_config_file(path)
    except ConfigError as exc:
        raise UserError(f"{path}: {exc}") from None


def load_config(path: str | Path) -> BatchConfig:
    """Read and validate a batch configuration; every problem is a one-line :class:`UserError` naming the
    file and the key path (``captures[1].scene.baseline: ...``)."""
    path = Path(path).expanduser().absolute()
    data = read_mapping(path)
    try:
        raw = ConfigFile.model_validate(data)
    except ValidationError as exc:
        raise UserError(f"{path}: {validation_error(exc, ConfigFile)}") from None
    try:
        return _resolve(path, raw)
    except OptionError as exc:
        raise UserError(f"{path}: {exc.name}: {exc.message}") from None


def _parsed(cls, mapping: dict, where: str, base: Path, planned: dict | None = None) -> dict:
    """The keys of ``mapping`` parsed and checked by ``cls``'s option fields (:func:`from_mapping`)."""
    for key in mapping:
        if planned and key in planned:
            raise OptionError(f"{where}.{key}", f"set per sequence by {planned[key]}")
    options = from_mapping(cls, mapping, where, base_dir=base)
    return {key: getattr(options, key) for key in mapping}


def _resolve(path: Path, raw: ConfigFile) -> BatchConfig:
    base = path.parent
    scene_defaults = _parsed(SceneOptions, raw.scene, "scene", base, PLANNED_SCENE_KEYS)
    mesh_defaults = _parsed(MeshOptions, raw.mesh, "mesh", base)
    for i, kind in enumerate(raw.sequences.paths):
        try:
            from_mapping(SceneOptions, {"path": kind})
        except OptionError as exc:
            raise OptionError(f"sequences.paths[{i}]", exc.message) from None
    render_keys = _parsed(RenderOptions, raw.render, "render", base, PLANNED_RENDER_KEYS)
    try:
        render = RenderOptions(**render_keys).validated()
    except OptionError as exc:
        raise OptionError(f"render.{exc.name}", exc.message) from None
    variations = {name: _variation(name, spec, base) for name, spec in raw.variations.items()}

    captures: list[Capture] = []
    for i, entry in enumerate(raw.captures):
        where = f"captures[{i}]"
        own_scene = _parsed(SceneOptions, entry.scene_options, f"{where}.scene", base, PLANNED_SCENE_KEYS)
        own_mesh = _parsed(MeshOptions, entry.mesh, f"{where}.mesh", base)
        scene_where = {k: f"scene.{k}" for k in scene_defaults} | {k: f"{where}.scene.{k}" for k in own_scene}
        common = dict(split=entry.split, where=where, scene={**scene_defaults, **own_scene}, scene_where=scene_where)
        check_scene(common["scene"], scene_where)
        if entry.scene_folder is not None:
            for name, folder in _expand(entry.scene_folder, base, f"{where}.scene", want="dir").items():
                _check_scene_folder(folder, f"{where}.scene")
                captures.append(Capture(_capture_name(entry.name, name, folder.name), scene_dir=str(folder), **common))
            continue
        mesh_keys = {**mesh_defaults, **own_mesh}
        for key, values in _expand_inputs(entry.inputs, base, where).items():
            try:
                inputs = from_mapping(CaptureOptions, values)
                check_inputs(inputs)
            except OptionError as exc:  # the stage names the field: spelled as the entry's key
                raise UserError(f"{path}: {exc.render(where=where)}") from None
            first = Path(inputs.left or inputs.rgb[0])
            captures.append(Capture(_capture_name(entry.name, key, first.stem), inputs=inputs,
                                    mesh=MeshOptions(**mesh_keys), mesh_keys=mesh_keys, **common))
    _check_unique(captures)
    for name in variations:
        if name in PLANNED_SCENE_KEYS:
            raise OptionError(f"variations.{name}", f"set per sequence by {PLANNED_SCENE_KEYS[name]}")
    return BatchConfig(path, raw.seed, captures, raw.sequences.per_capture, raw.sequences.frames,
                       tuple(raw.sequences.paths), render, render_keys, variations)


def _variation(name: str, spec: Any, base: Path) -> Variation:
    where = f"variations.{name}"
    known = {f.name: f for f in fields(SceneOptions)}
    if name not in known:
        raise OptionError(where, f"not a scene option (known: {', '.join(sorted(known))})")
    if name in PLANNED_SCENE_KEYS:
        raise OptionError(where, f"set per sequence by {PLANNED_SCENE_KEYS[name]}")
    hint = typing.get_type_hints(SceneOptions)[name]
    integer = hint is int
    numeric = hint in (int, float)
    if isinstance(spec, dict):
        if len(spec) != 1 or next(iter(spec)) not in ("uniform", "choice"):
            raise OptionError(where, f"give {{uniform: [lo, hi]}} or {{choice: [...]}}, got {spec!r}")
        kind, values = next(iter(spec.items()))
    elif isinstance(spec, list):
        two_numbers = len(spec) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spec)
        kind, values = ("uniform" if numeric and two_numbers else "choice"), spec
    else:
        raise OptionError(where, f"give [lo, hi], {{uniform: [lo, hi]}} or a list of choices, got {spec!r} "
                          "(a value for every sequence belongs under scene:)")
    if not isinstance(values, list) or not values:
        raise OptionError(where, f"{kind} needs a non-empty list, got {values!r}")
    checked = tuple(getattr(from_mapping(SceneOptions, {name: v}, "variations", base_dir=base), name) for v in values)
    if kind == "uniform":
        if not numeric or len(checked) != 2:
            raise OptionError(where, f"uniform needs [lo, hi] of a numeric option, got {values!r}")
        if checked[0] > checked[1]:
            raise OptionError(where, f"uniform range [{checked[0]}, {checked[1]}] has lo > hi")
    for value in checked:
        check_scene({name: value}, {name: where})
    return Variation(name, kind, checked, integer)


def check_scene(values: dict, where: dict[str, str]) -> SceneOptions:
    """SceneOptions with ``values`` through the scene stage's own checks (the rig's plausibility); an
    :class:`OptionError` names the key path ``where[field]`` that set the offending value."""
    options = SceneOptions(**values)
    try:
        options.rig()
    except OptionError as exc:
        raise OptionError(where.get(exc.name, f"scene.{exc.name}"), exc.message) from None
    return options


def _glob_regex(pattern: str) -> re.Pattern:
    """A regex for a glob pattern whose groups are what each wildcard matched."""
    out, i = "", 0
    while i < len(pattern):
        c = pattern[i]
        if pattern.startswith("**", i):
            out, i = out + "(.*)", i + 2
            continue
        if c == "*":
            out += "([^/]*)"
        elif c == "?":
            out += "([^/])"
        elif c == "[" and "]" in pattern[i + 2:]:
            end = pattern.index("]", i + 2)
            body = pattern[i + 1:end]
            out += "([" + ("^" + body[1:] if body.startswith("!") else body) + "])"
            i = end
        else:
            out += re.escape(c)
        i += 1
    return re.compile(out + r"\Z")


def _expand(pattern: str, base: Path, where: str, want: str = "file") -> dict[tuple, Path]:
    """Files (``want="file"``), folders (``"dir"``) or either (``"any"``) that a path or glob names, keyed by what
    its wildcards matched (``()`` for a plain path)."""
    relative = Path(pattern).expanduser()
    prefix = "" if relative.is_absolute() else str(base) + os.sep
    what = {"file": "file", "dir": "folder", "any": "file or folder"}[want]
    wanted = {"file": Path.is_file, "dir": Path.is_dir, "any": Path.exists}[want]
    if not glob.has_magic(pattern):
        path = Path(prefix + str(relative))
        if not wanted(path):
            raise OptionError(where, f"{path}: {what} not found")
        return {(): path}
    regex = _glob_regex(str(relative))
    found = {}
    for match in sorted(glob.glob(glob.escape(prefix) + str(relative), recursive=True)):
        hit = Path(match)
        if wanted(hit):
            found[regex.match(match[len(prefix):]).groups()] = hit
    if not found:
        raise OptionError(where, f"no {what} matches {prefix}{relative}")
    return found


def _pair(rgbs: dict, others: dict, where: str) -> None:
    """Each rgb match needs the match of ``others`` whose wildcards matched the same text."""
    for key, rgb in rgbs.items():
        if key not in others:
            raise OptionError(where, f"nothing matches {rgb} (its wildcards matched {'/'.join(key) or 'nothing'}; "
                              "rgb, depth and camera globs pair files by what their wildcards match)")
    extra = sorted(set(others) - set(rgbs))
    if extra:
        raise OptionError(where, f"{others[extra[0]]} has no rgb file (wildcards matched {'/'.join(extra[0])})")


def _expand_inputs(inputs: dict, base: Path, where: str) -> dict[tuple, dict]:
    """The input keys of one entry with paths made absolute and globs expanded: one mapping per capture, keyed
    by what the wildcards of ``rgb`` (or ``left``) matched. A list (fused frames) is one capture: each item's
    matches, sorted, in turn. The other file keys pair with those matches by their own wildcards, or are one
    file for all."""
    per_match = next((k for k in _PER_MATCH if isinstance(inputs.get(k), str)), None)
    lead = _expand(inputs[per_match], base, f"{where}.{per_match}") if per_match else {(): None}
    out: dict[tuple, dict] = {key: dict(inputs) for key in lead}
    for name in _FILE_KEYS:
        value = inputs.get(name)
        if value is None:
            continue
        if isinstance(value, list) and name in _LIST_KEYS:
            if not all(isinstance(v, str) for v in value):
                raise OptionError(f"{where}.{name}", f"give a file, or a list of files, got {value!r}")
            files = [str(p) for i, v in enumerate(value)
                     for p in _expand(v, base, f"{where}.{name}[{i}]", want=_want(name)).values()]
            for values in out.values():
                values[name] = files
            continue
        if not isinstance(value, str):
            raise OptionError(f"{where}.{name}", f"give a file path, got {value!r}")
        found = lead if name == per_match else _expand(value, base, f"{where}.{name}", want=_want(name))
        if len(found) > 1 or () not in found:
            _pair(lead, found, f"{where}.{name}")
        for key, values in out.items():
            path = str(found.get(key, found.get(())))
            values[name] = [path] if name in ("rgb", "depth") else path
    return out


def _want(key: str) -> str:
    return "any" if key == "stereo_calib" else "file"  # a calibration is a JSON file or a Hamlyn-style folder


def _capture_name(name: str | None, key: tuple, fallback: str) -> str:
    parts = [p for p in ([name] if name else []) + [re.sub(r"[^A-Za-z0-9_.-]+", "-", k).strip("-.") for k in key]
             if p]
    return "_".join(parts) if parts else re.sub(r"[^A-Za-z0-9_.-]+", "-", fallback).strip("-.") or "capture"


def _check_scene_folder(folder: Path, where: str) -> None:
    for name in (scene_files.SCENE_JSON, scene_files.MESH):
        if not (folder / name).is_file():
            raise OptionError(where, f"{folder}: not a scene or mesh folder made by rgbd2scene ({name} is missing)")


def _check_unique(captures: list[Capture]) -> None:
    seen: dict[str, Capture] = {}
    sources: dict[tuple, Capture] = {}
    for c in captures:
        if c.name in seen:
            raise OptionError(f"{c.where}.name", f"{c.name!r} also names a capture of {seen[c.name].where} "
                              "(names must be unique: they seed and name the sequences)")
        seen[c.name] = c
        other = sources.setdefault(c.source, c)
        if other.split != c.split:
            raise OptionError(f"{c.where}.split", f"{c.name} is the same capture as {other.name} ({other.where}) but "
                              f"in split {c.split!r}, not {other.split!r}: its scenes would leak between splits")
