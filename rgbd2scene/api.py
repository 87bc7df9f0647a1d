"""The Python API a newcomer meets first: one call per command, with the command's options as keywords.

Example::

    from rgbd2scene import api

    api.scene("out/scene", rgb="rgb.png", depth="depth.png", camera="camera.json", frames=12)
    api.render("out/scene", "out/dataset", size="128x64", frames=4)
    assert api.verify("out/dataset").ok

Each keyword is the field behind the command's flag, as in a batch configuration: the flag with underscores
(``--depth-scale`` is ``depth_scale``, ``--no-overview`` is ``overview=False``) or, where the flag is short, the
field's full name (``--fov`` is ``fov_x_deg``, ``--light-power`` is ``light_power_w``). The keywords of
:func:`mesh`, :func:`scene`, :func:`render` and :func:`dataset` are the fields of the stages' options
dataclasses (``CaptureOptions``, ``MeshOptions``, ``SceneOptions``, ``RenderOptions``, ``BuildOptions``), so an
option added there is a keyword here too; a value may be given as on the command line (``size="128x64"``) or
typed (``size=(128, 64)``), a list of files as one path or several; the fields of a nested record (a field whose
default is an options dataclass) are keywords as they are flags, or the record takes a mapping. ``progress``
stands for ``--quiet``.

An unknown keyword is a :class:`TypeError` naming it. A bad value raises what the command reports as
``error: ...``: an :class:`~rgbd2scene.options.OptionError` (a ValueError) whose message names the keyword, or
a :class:`~rgbd2scene.errors.UserError` naming the file. The command line runs these same functions
(:func:`run_mesh`, :func:`run_scene` and :func:`run_render` take the options as dataclasses, as it has them).

The stage-level functions stay for finer control: :mod:`rgbd2scene.stages` (``load_inputs``,
``reconstruct_inputs``, ``write_mesh_folder``, ``reconstruct_mesh_folder``, ``build_scene_folder``,
``render_dataset``) and the packages named in each function below. Nothing heavy is imported until a call.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rgbd2scene.options import OptionError

__all__ = ["MeshResult", "RenderResult", "SceneResult", "dataset", "evaluate", "export", "export_ros", "mesh",
           "realism", "render", "run_mesh", "run_render", "run_scene", "scene", "verify"]

PathLike = str | os.PathLike


@dataclass
class MeshResult:
    """What :func:`mesh` wrote: the folder, its ``mesh.ply``, the scene.json ``record``; the ``reconstruction``
    itself (arrays and timings) and the wall ``seconds``."""

    folder: Path
    mesh: Path
    record: dict
    reconstruction: Any
    seconds: float


@dataclass
class SceneResult:
    """What :func:`scene` wrote: the folder, its ``scene.blend``, the scene.json ``record``, the wall ``seconds``."""

    folder: Path
    blend: Path
    record: dict
    seconds: float


@dataclass
class RenderResult:
    """What :func:`render` wrote: the dataset folder, frames ``rendered`` and ``skipped`` (already done), the
    contact sheet (None without one) and the render stage's whole ``summary`` (timings, memory)."""

    dataset: Path
    rendered: int
    skipped: int
    sheet: Path | None
    summary: dict


def _keyword_errors(function):
    """An :class:`OptionError` leaving ``function`` names the keyword (the command line names its flag)."""
    @functools.wraps(function)
    def call(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except OptionError as exc:
            exc.args = (exc.render(),)
            raise

    return call


def _plain(value):
    """Paths as strings (the options hold text, as parsed from a command line or a configuration file)."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple)):
        return type(value)(_plain(v) for v in value)
    return value


def _options(command: str, values: dict, *classes):
    """One instance of each options dataclass in ``classes`` from the keywords ``values``, each keyword going to
    the first class with a field of its name; :class:`TypeError` for a keyword no class has.

    The fields of a nested record (a field whose default is an options dataclass, such as the render's sensor
    settings) are keywords too, as they are flags on the command line; the record's own name takes a mapping.
    """
    from rgbd2scene.options import from_mapping

    owner: dict[str, tuple[type, str | None]] = {}
    for cls in classes:
        for name, record in _keywords(cls).items():
            owner.setdefault(name, (cls, record))
    unknown = [name for name in values if name not in owner]
    if unknown:
        raise TypeError(f"{command}() got an unexpected keyword argument {unknown[0]!r} (options: "
                        f"{', '.join(sorted(owner))})")
    out = []
    for cls in classes:
        mine: dict[str, Any] = {}
        nested: dict[str, dict] = {}
        for name, value in values.items():
            target, record = owner[name]
            if target is not cls:
                continue
            value = _plain(value)
            if record is not None:
                nested.setdefault(record, {})[name] = value
                continue
            if isinstance(value, str) and _takes_list(cls, name):
                value = [value]  # one file where several may be given
            mine[name] = value
        for record, flat in nested.items():
            given = mine.get(record)
            mine[record] = (flat if given is None else dataclasses.replace(given, **flat)
                            if dataclasses.is_dataclass(given) else {**given, **flat})
        out.append(from_mapping(cls, mine))
    return tuple(out)


def _keywords(cls) -> dict[str, str | None]:
    """Keyword -> the nested record of ``cls`` that holds it (None: a field of ``cls`` itself)."""
    out: dict[str, str | None] = {f.name: None for f in dataclasses.fields(cls)}
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            for inner in dataclasses.fields(default):
                out.setdefault(inner.name, f.name)
    return out


def _takes_list(cls, name: str) -> bool:
    import typing

    hint = typing.get_type_hints(cls)[name]
    return any(typing.get_origin(a) is list for a in (hint, *typing.get_args(hint)))


def _mesh_classes():
    from rgbd2scene.reconstruct.pipeline import MeshOptions
    from rgbd2scene.stages.capture import CaptureOptions

    return CaptureOptions, MeshOptions


@_keyword_errors
def mesh(output: PathLike, **options) -> MeshResult:
    """``rgbd2scene mesh``: read a capture (an RGB-D frame, several to fuse, or a stereo frame), fill its holes,
    mesh and smooth it; writes ``output/mesh.ply``, the textured OBJ, ``depth_filled.npy``, ``overview.png``
    and ``scene.json``.

    Keywords: the fields of :class:`rgbd2scene.stages.capture.CaptureOptions` (``rgb``, ``depth``, ``camera``,
    ``left``, ``right``, ``stereo_calib``, ...) and :class:`rgbd2scene.reconstruct.MeshOptions` (``fill``,
    ``smooth``, ...).
    """
    capture, recon = _options("mesh", options, *_mesh_classes())
    return run_mesh(output, capture, recon)


def run_mesh(output: PathLike, capture, options) -> MeshResult:
    """:func:`mesh` with its options as dataclasses (the command line's entry)."""
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.scene import folder
    from rgbd2scene.stages.capture import load_inputs
    from rgbd2scene.stages.mesh import reconstruct_mesh_folder

    t0 = time.perf_counter()
    loaded = load_inputs(capture)  # read and checked before anything is written
    out = ensure_output_dir(output)
    recon, record = reconstruct_mesh_folder(out, loaded, options)
    return MeshResult(out, out / folder.MESH, record, recon, time.perf_counter() - t0)


@_keyword_errors
def scene(output: PathLike, *, mesh_dir: PathLike | None = None, **options) -> SceneResult:
    """``rgbd2scene scene``: :func:`mesh`'s work (or the mesh folder ``mesh_dir`` made by it), then the Blender
    scene with the stereo endoscope on its path; writes ``output/scene.blend`` and ``scene.json`` last.

    Keywords: those of :func:`mesh` and the fields of :class:`rgbd2scene.stages.scene.SceneOptions` (``path``,
    ``frames``, ``deform``, ``instrument``, ``baseline``, ...).
    """
    from rgbd2scene.stages.scene import SceneOptions

    capture, recon, options = _options("scene", options, *_mesh_classes(), SceneOptions)
    options.rig()  # a bad scope fails here, naming the keyword
    return run_scene(output, capture, recon, options, mesh_dir)


def run_scene(output: PathLike, capture, mesh_options, options, mesh_dir: PathLike | None = None) -> SceneResult:
    """:func:`scene` with its options as dataclasses (the command line's entry)."""
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.scene import folder
    from rgbd2scene.stages.capture import load_inputs
    from rgbd2scene.stages.mesh import reconstruct_mesh_folder
    from rgbd2scene.stages.scene import build_scene_folder, load_mesh_folder, scene_config

    t0 = time.perf_counter()
    config = scene_config(options)  # a bad configuration or capture fails before anything is written
    if not mesh_dir and not capture.given():
        raise OptionError("rgb", "scene: give a capture ({rgb} and {depth}, or {left}, {right} and {stereo_calib}) "
                          "or {mesh_dir} (a mesh folder)")
    loaded = None if mesh_dir else load_inputs(capture)
    out = ensure_output_dir(output)
    if loaded is None:
        surface, record = load_mesh_folder(mesh_dir, out)
    else:
        # scene.json comes with the scene
        recon, record = reconstruct_mesh_folder(out, loaded, mesh_options, finalize=False)
        surface = recon.mesh
    record = build_scene_folder(out, surface, record, options, config=config)
    return SceneResult(out, out / folder.SCENE_BLEND, record, time.perf_counter() - t0)


@_keyword_errors
def render(scene: PathLike, output: PathLike, *, progress: bool = True, sheet: bool = True,
           **options) -> RenderResult:
    """``rgbd2scene render``: the stereo dataset of the scene folder ``scene`` with its ground truth (resumable:
    finished frames are skipped); ``sheet`` writes ``output/contact_sheet.png`` (the middle frame, all maps).

    Keywords: the fields of :class:`rgbd2scene.stages.render.RenderOptions` (``frames``, ``size``, ``gt``,
    ``samples``, ...).
    """
    from rgbd2scene.stages.render import RenderOptions

    (options,) = _options("render", options, RenderOptions)
    options.validated()  # a bad value fails here, naming the keyword
    return run_render(scene, output, options, progress=progress, sheet=sheet)


def run_render(scene: PathLike, output: PathLike, options, *, progress: bool = True,
               sheet: bool = True) -> RenderResult:
    """:func:`render` with its options as a dataclass (the command line's entry)."""
    from rgbd2scene.stages.render import render_dataset

    summary = render_dataset(scene, output, options, progress=progress)
    picture = None
    if sheet and not options.gt_only:  # --gt-only renders no images to show
        from rgbd2scene.pictures.contact_sheet import write_frame_sheet

        start, end = summary["range"]
        picture = write_frame_sheet(output, (start + end - 1) // 2, Path(output) / "contact_sheet.png")
    return RenderResult(Path(summary["dataset"]), summary["rendered"], summary["skipped"], picture, summary)


@_keyword_errors
def verify(dataset: PathLike, *, mesh: PathLike | None = None, json: PathLike | None = None,
           error_maps: PathLike | None = None, blender_frames: int = 0, progress: bool = True):
    """``rgbd2scene verify``: the self-consistency report of the dataset's ground truth (``.ok`` says whether it
    passes; :func:`rgbd2scene.verify.format_report` prints it). ``mesh`` replaces the mesh dataset.json names,
    ``json`` also writes the report there, ``error_maps`` is a folder for pictures of the worst frames,
    ``blender_frames`` compares the maps of that many sampled frames with Blender's own passes."""
    from rgbd2scene.verify import verify_dataset

    report = verify_dataset(dataset, mesh_path=mesh, progress=progress, error_maps=error_maps,
                            blender_frames=blender_frames)
    if json:
        from rgbd2scene.files.atomic import write_json

        write_json(json, report.to_dict())
    return report


@_keyword_errors
def export(dataset: PathLike, format: str, output: PathLike, *, progress: bool = True):
    """``rgbd2scene export``: the dataset in a standard layout (``format``: a key of
    :data:`rgbd2scene.export.FORMATS`: kitti, sceneflow, visionblender); returns the exporter's summary."""
    from rgbd2scene.dataset import Dataset
    from rgbd2scene.export import FORMATS
    from rgbd2scene.files.atomic import ensure_output_dir

    if format not in FORMATS:
        raise OptionError("format", f"choose one of {', '.join(sorted(FORMATS))}, got {format!r}")
    data = Dataset(dataset)
    return FORMATS[format](data, ensure_output_dir(output), progress=progress)


@_keyword_errors
def export_ros(dataset: PathLike, output: PathLike, *, ros: int = 2, rate: float | None = None,
               start: float | None = None, prefix: str = "/stereo", world_frame: str = "world",
               scope_frame: str = "endoscope", progress: bool = True):
    """``rgbd2scene export-ros``: a ROS 1 ``.bag`` (``ros=1``) or ROS 2 MCAP bag folder of the dataset, stamped
    ``start + i / rate`` (defaults: :data:`rgbd2scene.export.ros.DEFAULT_START_S`, the dataset's fps); returns
    the exporter's summary."""
    from rgbd2scene.dataset import Dataset
    from rgbd2scene.export import RosOptions
    from rgbd2scene.export import export_ros as write_bag

    given = {"start": start} if start is not None else {}
    try:
        options = RosOptions(version=ros, rate=rate, prefix=prefix, world=world_frame, scope=scope_frame, **given)
    except ValueError as exc:
        raise OptionError("ros", f"export-ros: {exc} ({{ros}}, {{rate}}, {{start}})") from None
    return write_bag(Dataset(dataset), output, options, progress=progress)


def _methods(text: str | Sequence[str]) -> tuple[str, ...]:
    """A comma list (or a sequence) of method names; ``none`` is no method."""
    names = text.split(",") if isinstance(text, str) else text
    return tuple(m.strip() for m in names if m.strip() and m.strip() != "none")


@_keyword_errors
def evaluate(dataset: PathLike, output: PathLike | None = None, *, methods: str | Sequence[str] = "sgbm,elas",
             predictions: Sequence[PathLike] = (), min_depth: float | None = None, max_depth: float | None = None,
             error_maps: bool = True, progress: bool = True):
    """``rgbd2scene evaluate``: stereo methods (``methods``: sgbm, elas, gt, or none) and external
    ``predictions`` (``DIR`` or ``NAME=DIR``) scored against the ground truth of a dataset or batch root; writes
    the tables to ``output`` (default ``DATASET/evaluation``) and returns the
    :class:`~rgbd2scene.evaluate.run.EvaluationResult`."""
    from rgbd2scene.evaluate import EvaluationOptions
    from rgbd2scene.evaluate import evaluate as score

    methods = _methods(methods)
    if not methods and not predictions:
        raise OptionError("methods", "evaluate: nothing to score (give {methods} or {predictions})")
    if (min_depth is None) != (max_depth is None):
        raise OptionError("min_depth", "evaluate: give both {min_depth} and {max_depth}, or neither")
    depth_range = None
    if min_depth is not None:
        if not 0 < min_depth < max_depth:
            raise OptionError("min_depth", f"evaluate: {{min_depth}} {min_depth} and {{max_depth}} {max_depth} must "
                              f"satisfy 0 < min < max (metres)")
        depth_range = (min_depth, max_depth)
    if isinstance(predictions, (str, os.PathLike)):
        predictions = [predictions]
    options = EvaluationOptions(methods=methods, predictions=tuple(os.fspath(p) for p in predictions),
                                depth_range=depth_range, error_maps=error_maps)
    return score(dataset, output, options, progress=progress)


@_keyword_errors
def realism(dataset: PathLike, real: PathLike | Sequence[PathLike], output: PathLike | None = None, *,
            real_disparity: PathLike | None = None, real_mask: PathLike | None = None,
            real_calib: PathLike | None = None, surface_only: bool = False, frame: int = 0,
            methods: str | Sequence[str] = "sgbm,elas"):
    """``rgbd2scene realism``: how close frame ``frame`` of the dataset is to the ``real`` LEFT image (or
    [LEFT, RIGHT] pair); writes the table and the side-by-side picture to ``output`` (default
    ``DATASET/realism``) and returns the :class:`~rgbd2scene.realism.RealismOutput`."""
    from rgbd2scene.realism import run_realism

    images = [real] if isinstance(real, (str, os.PathLike)) else list(real)
    if not 1 <= len(images) <= 2:
        raise OptionError("real", f"realism: {{real}} takes the LEFT image and optionally the RIGHT one, got "
                          f"{len(images)}")
    return run_realism(dataset, images[0], images[1] if len(images) > 1 else None, out=output, frame=frame,
                       mask=real_mask, real_disparity=real_disparity, real_calib=real_calib,
                       methods=_methods(methods), surface_only=surface_only)


@_keyword_errors
def dataset(config: PathLike, output: PathLike, **options):
    """``rgbd2scene dataset``: the batch build of the configuration file ``config`` (YAML or TOML) into the root
    folder ``output`` (resumable); returns the :class:`~rgbd2scene.batch.run.BuildSummary` (``failed`` lists
    the sequences that failed).

    Keywords: the fields of :class:`rgbd2scene.batch.run.BuildOptions` (``workers``, ``scheduler``, ``jobs``,
    ``retry_failed``, ``dashboard``, ``progress``).
    """
    from rgbd2scene.batch.run import BuildOptions, build_dataset

    (options,) = _options("dataset", options, BuildOptions)
    return build_dataset(config, output, options)
