"""The render stage (``rgbd2scene render SCENE -o DATASET``): a scene folder -> a stereo dataset (no ``bpy``).

:func:`render_dataset` validates its inputs, writes ``DATASET/dataset.json`` first, then runs the Blender
worker through the one crossing (:mod:`rgbd2scene.stages.blender`) over bounded chunks of frames, each in
a fresh process, so memory stays flat however long the sequence. The worker takes K, the baseline and
every pose from the scene model sent in the task. Finished frames (both eyes' PNG and npz present: every
file is written atomically) are skipped, so re-running the same command resumes; what a killed run left
is swept first. A tqdm bar with ETA follows the worker's progress lines.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from rgbd2scene.conventions import CONVENTIONS_VERSION
from rgbd2scene.dataset import layout as ds
from rgbd2scene.dataset.calibration import CALIBRATION_YAML, write_calibration
from rgbd2scene.environment import EnvironmentOptions
from rgbd2scene.errors import RenderError, UserError
from rgbd2scene.files.atomic import ensure_output_dir, read_json_object
from rgbd2scene.options import OptionError, flag_of, resume_diff, to_record
from rgbd2scene.rendering import (  # noqa: F401 - the stage's options, re-exported
    BYTES_PER_PIXEL,
    DEFAULT_CHUNK,
    DEFAULT_DENOISE,
    DEFAULT_DENOISE_QUALITY,
    DEFAULT_PREFILTER,
    DEFAULT_SAMPLES,
    ENGINES,
    GT_RENDER,
    GT_SOURCES,
    RGB_SAMPLING_PATTERN,
    RenderOptions,
    machine_memory_bytes,
    parse_size,
    render_memory_bytes,
)
from rgbd2scene.scene.folder import SCENE_BLEND, SCENE_JSON
from rgbd2scene.scene.model import SceneDescription
from rgbd2scene.scene.raw import rectified_rig
from rgbd2scene.scene.rig import StereoRig
from rgbd2scene.stages.blender import Describe, Event, Render, Task, run_task
from rgbd2scene.versions import software_versions

#: How the scene model gives the ground truth (groundtruth/model_maps.py; recorded in dataset.json).
GT_MODEL = {"source": "scene model", "ray_caster": "Open3D RaycastingScene (float32), one ray per pixel centre "
            "of each eye's camera", "normals": "interpolated angle-weighted vertex normals",
            "flow": "hit point followed on its triangle (same barycentrics) to the other frame, projected"}
#: dataset.json entries that must match for a re-run to resume into the same folder (besides the
#: render options marked ``resume`` and the scene's hash).
RESUME_KEYS = ("width", "height", "frames", "baseline", "K")
#: Share of a frame's progress-bar step given when its images are written (the data render that
#: completes it takes the rest: about a tenth of the time).
RGB_SHARE = 0.9
#: Frames ``render --gt-only`` computes at once (threads).
GT_ONLY_THREADS = 2


def _sha1(path: Path) -> str | None:
    if not path.is_file():
        return None
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_scene(scene_dir: str | Path, python: str | None = None) -> tuple[Path, dict, SceneDescription]:
    """Validate a scene folder; (folder, scene.json record, the scene model)."""
    scene_dir = Path(scene_dir)
    if not scene_dir.is_dir():
        raise UserError(f"{scene_dir}: scene folder not found")
    for name in (SCENE_BLEND, SCENE_JSON):
        if not (scene_dir / name).is_file():
            raise UserError(f"{scene_dir}: not a scene folder made by 'rgbd2scene scene' ({name} is missing)")
    record = read_json_object(scene_dir / SCENE_JSON, "scene.json")
    try:
        if isinstance(record.get("scene"), dict):
            description = SceneDescription.from_dict(record["scene"])
        else:  # fall back to the description stored in the blend (needs Blender: ask the worker)
            description = SceneDescription.from_dict(_describe_from_blend(scene_dir, python))
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{scene_dir / SCENE_JSON}: bad scene description ({exc!r})") from None
    return scene_dir, record, description


def _describe_from_blend(scene_dir: Path, python: str | None) -> dict:
    try:
        result = run_task(Task(Describe(str(scene_dir.resolve()))), python=python, what="describe worker")
    except RenderError as exc:
        last = str(exc).strip().splitlines()[-1]
        raise UserError(f"{scene_dir}: scene.json has no 'scene' and scene.blend holds no description "
                        f"({last})") from None
    texts = [e.text for e in result.events if e.kind == "describe"]
    if not texts:
        raise UserError(f"{scene_dir}: scene.json has no 'scene' and scene.blend holds no description")
    return json.loads(texts[-1])


def dataset_info(scene_dir: Path, out_dir: Path, description: SceneDescription, frames: int,
                 options: RenderOptions) -> dict:
    """The dataset.json record (CONVENTIONS §4 plus the render settings and provenance).

    The scene is referred to by its path relative to the dataset folder and the hashes of its files, so
    a dataset folder can be moved (with its scene beside it, or alone: the hashes still identify it).
    """
    intr = description.rig.intrinsics
    tissue = next((p for o, p in description.parts() if o.kind == "tissue"), None)
    rel = Path(os.path.relpath(scene_dir.resolve(), out_dir.resolve()))
    table = description.object_table()
    render = to_record(options)
    render.update(blender_engine=ENGINES[options.engine].blender, sampling_pattern=RGB_SAMPLING_PATTERN,
                  gt=list(options.maps),
                  gt_render=GT_RENDER if options.gt_source == "blender" else GT_MODEL)
    return {
        "width": intr.width, "height": intr.height, "frames": frames, "fps": description.path.fps,
        "baseline": description.rig.baseline, "K": intr.K.tolist(), "eyes": list(ds.EYES),
        "intrinsics": intr.to_dict(), "D": description.rig.left.distortion.tolist(),
        "camera": camera_record(description.rig),
        "objects": table["objects"], "classes": table["classes"], "tracked_frames": table["tracked_frames"],
        "scene": {"dir": rel.as_posix(),
                  "mesh": (rel / tissue.geometry).as_posix() if tissue else None,
                  "mesh_sha1": _sha1(scene_dir / tissue.geometry) if tissue else None,
                  "scene_json_sha1": _sha1(scene_dir / SCENE_JSON),
                  "blend_sha1": _sha1(scene_dir / SCENE_BLEND), "path_kind": description.path.kind,
                  "path_frames": description.path.frames},
        "software": software_versions(),
        "seed": options.seed,
        "conventions_version": CONVENTIONS_VERSION,
        "render": render,
        "sensor": render["sensor"],
        "environment": render["environment"],
        "layout": {"rgb": "{eye}/rgb/{frame:06d}.png", "gt": "{eye}/gt/{frame:06d}.npz",
                   "sensor": f"{ds.SENSOR_DIR}/{{frame:06d}}.json",
                   **({"rgb_clean": f"{{eye}}/{ds.CLEAN_DIR}/{{frame:06d}}.png"} if options.sensor.clean else {})},
    }


def camera_record(rig: StereoRig) -> dict:
    """dataset.json's ``"camera"`` (CONVENTIONS 1.2): rectified or raw, both eyes' cameras, R and T."""
    calib = rig.calibration
    return {"rectified": rig.rectified, "left": rig.left.to_dict(), "right": rig.right.to_dict(),
            "distortion_model": rig.left.distortion_model, "R": [list(r) for r in calib.R], "T": list(calib.T)}


def _check_resume(existing: dict, info: dict, options: RenderOptions, path: Path, only=None) -> None:
    """Refuse to resume into a dataset rendered with other settings (``only``: compare just these render
    options, e.g. those of the ground truth)."""
    diffs = [k for k in RESUME_KEYS if existing.get(k) != info[k]]
    old = existing.get("render", {})
    if old.get("engine") == "CYCLES":  # older datasets recorded Blender's engine name, always Cycles on the CPU
        old = {**old, "engine": "cycles"}
    diffs += [f"render.{k}" for k in resume_diff(options, {**old, "gt": ",".join(old.get("gt", [])) or "none"})
              if only is None or k in only]
    if existing.get("scene", {}).get("scene_json_sha1") != info["scene"]["scene_json_sha1"]:
        diffs.append("scene (scene.json changed)")
    if diffs:
        raise UserError(f"{path}: this folder holds a dataset rendered with other settings "
                        f"({', '.join(diffs)}); choose another output folder or delete it")


def scene_environment(options: RenderOptions, description: SceneDescription) -> RenderOptions:
    """The render's environment: the scene's (its configuration file's ``[environment]``) unless the render
    sets any environment option itself (``--smoke`` ...), which then replaces it whole."""
    if options.environment != EnvironmentOptions().validated() or not description.environment:
        return options
    return replace(options, environment=EnvironmentOptions.from_dict(description.environment).validated())


def render_model(description: SceneDescription, options: RenderOptions) -> SceneDescription:
    """The scene model as rendered: the rig resized to ``options.size`` (K follows ``Intrinsics.resized``),
    then, with ``options.rectify``, a raw rig replaced by its rectified pair (the left eye's poses turned by
    R1: T_world_rect = T_world_left R1^T)."""
    if options.size is not None:
        description = replace(description, rig=description.rig.resized(*options.size))
    if options.rectify and not description.rig.rectified:
        rig, rect = rectified_rig(description.rig)
        path = replace(description.path, poses=description.path.poses @ rect.T_left_rectified)
        description = replace(description, rig=rig, path=path)
    return description


def render_task(scene_dir: Path, out_dir: Path, description: SceneDescription, options: RenderOptions,
                frames: int, start: int, end: int) -> Task:
    """The worker task that renders frames [start, end) of a ``frames``-long dataset (``description`` as
    rendered, see :func:`render_model`)."""
    return Task(Render(str(Path(scene_dir).resolve()), str(Path(out_dir).resolve()), description.to_dict(),
                       render=to_record(options), frames=int(frames), start=int(start), end=int(end)))


@dataclass
class RenderJob:
    """A validated render of frames [start, end) of a ``frames``-long dataset, ready to run chunk by chunk.

    ``description`` is the scene model as rendered (:func:`render_model`); ``todo`` the frames not finished
    when the job was prepared. Each chunk is one worker :class:`Task` (:meth:`task`), which any engine runs
    through :func:`rgbd2scene.stages.blender.run_task`.
    """

    scene_dir: Path
    out: Path
    description: SceneDescription
    options: RenderOptions
    frames: int
    start: int
    end: int
    todo: list[int]

    @property
    def with_gt(self) -> bool:
        return bool(self.options.maps)

    @property
    def with_geometry(self) -> bool:
        """A deforming scene's frames are complete with their ``geometry/`` file too."""
        return self.with_gt and self.description.deforming

    def chunks(self) -> list[list[int]]:
        """The unfinished frames in groups of at most ``options.chunk``."""
        size = self.options.chunk
        return [self.todo[i:i + size] for i in range(0, len(self.todo), size)]

    def task(self, group: list[int]) -> Task:
        """The worker task of one chunk (it renders [first, last] and skips frames already finished)."""
        return render_task(self.scene_dir, self.out, self.description, self.options, self.frames, group[0],
                           group[-1] + 1)

    def incomplete(self, group: list[int]) -> list[int]:
        """Frames of ``group`` still missing a file."""
        return [i for i in group if not ds.frame_done(self.out, i, gt=self.with_gt, geometry=self.with_geometry)]


def frame_range(options: RenderOptions, description: SceneDescription, scene_dir: Path) -> tuple[int, int, int]:
    """(dataset length, first frame, end) of a render: ``--frames`` (default the whole camera path) and the chunk
    ``--start``/``--end`` inside it; one-line :class:`UserError` naming the flag when out of range."""
    path_frames = description.path.frames
    n = path_frames if options.frames is None else int(options.frames)
    if n < 1 or n > path_frames:
        raise UserError(f"--frames: {n} is not between 1 and the {path_frames} frames of the camera path "
                        f"in {scene_dir / SCENE_JSON}")
    s = 0 if options.start is None else int(options.start)
    e = n if options.end is None else int(options.end)
    if not 0 <= s < e <= n:
        raise UserError(f"--start/--end: [{s}, {e}) is not a non-empty range inside the {n} frames")
    return n, s, e


def prepare_render(scene_dir: str | Path, out_dir: str | Path, options: RenderOptions,
                   python: str | None = None) -> RenderJob:
    """Validate a render, write ``DATASET/dataset.json`` (or check that an existing one allows resuming),
    sweep what dead runs left in the folder and list the frames still to render.

    Bad options, scene folders and output folders are one-line :class:`UserError`\\ s naming the flag or file.
    """
    try:
        options = options.validated()
    except OptionError as exc:
        raise UserError(f"{flag_of(RenderOptions, exc.name)}: {exc.message}") from None

    scene_dir, _record, description = load_scene(scene_dir, python)
    options = scene_environment(options, description)
    n, s, e = frame_range(options, description, scene_dir)
    description = render_model(description, options)
    if options.gt_from_model and not all(
            (scene_dir / part.geometry).is_file() for _, part in description.parts()):
        options = replace(options, gt_source="blender")  # a scene folder with its .blend only: Blender's passes
    if options.maps and options.gt_source == "blender" and not description.rig.rectified:
        raise UserError("--gt-source: Blender's passes are those of a pinhole: a raw scope (distortion or unequal "
                        "eyes) takes its ground truth from the scene model, which needs the scene's geometry "
                        f"files in {scene_dir} (or render --rectify)")
    if options.sensor.motion_blur > 0 and (options.rectify or not description.rig.rectified):
        # the worker places the camera of a raw or rectified-from-raw rig itself, frame by frame: no camera
        # motion within the shutter, so the blur would be only the objects'
        raise UserError("--motion-blur: not available for a raw scope or --rectify (the camera is placed per "
                        "frame, so its motion within the shutter is not rendered)")
    out = ensure_output_dir(out_dir)

    info = dataset_info(scene_dir, out, description, n, options)
    json_path = out / ds.DATASET_JSON
    if json_path.is_file():
        _check_resume(ds.read_dataset_json(out), info, options, json_path)
    else:
        ds.write_dataset_json(out, info)
    if not (out / CALIBRATION_YAML).is_file():
        write_calibration(out, description.rig.calibration)
    ds.sweep_dead_runs(out)
    job = RenderJob(scene_dir, out, description, options, n, s, e, [])
    job.todo = [i for i in range(s, e) if not ds.frame_done(out, i, gt=job.with_gt, geometry=job.with_geometry)]
    return job


def render_dataset(scene_dir: str | Path, out_dir: str | Path, options: RenderOptions | None = None, *,
                   progress: bool = True, python: str | None = None, **overrides) -> dict:
    """Render SCENE into DATASET (CONVENTIONS §4); returns a summary dict.

    Parameters
    ----------
    options
        :class:`RenderOptions` (``frames``: dataset length, the first N frames of the camera path;
        ``size``: (W, H), K follows :meth:`Intrinsics.resized`; ``gt``: ``"all"``, ``"none"`` or a comma
        list of maps; ``start``/``end``: render only frames [start, end); ``samples``, ``adaptive``,
        ``denoise``, ``seed``: the RGB render; ``device``, ``threads``; ``chunk``: frames per worker
        process). Keyword ``overrides`` replace single fields (``render_dataset(s, d, samples=4)``).
    progress
        Show a tqdm bar.
    """
    t_start = time.perf_counter()
    options = replace(options or RenderOptions(), **overrides)
    if options.gt_only:
        return render_gt_only(scene_dir, out_dir, options, progress=progress, python=python)
    job = prepare_render(scene_dir, out_dir, options, python)
    chunks = job.chunks()
    stats: dict[int, dict] = {}
    starts: list[float] = []
    bar = _progress_bar(len(job.todo), progress)
    try:
        for group in chunks:
            _run_chunk(job.task(group), set(group), stats, starts, bar, python)
            missing = job.incomplete(group)
            if missing:
                raise RenderError(f"render worker finished but frames {missing} of {job.out} are incomplete")
    finally:
        if bar is not None:
            bar.close()

    done = [stats[i] for i in sorted(stats)]
    wall = time.perf_counter() - t_start

    def mean(key):
        vals = [d[key] for d in done if key in d]
        return sum(vals) / len(vals) if vals else None

    return {"dataset": str(job.out), "frames": job.frames, "range": [job.start, job.end], "rendered": len(done),
            "skipped": (job.end - job.start) - len(job.todo), "chunks": len(chunks), "seconds": wall,
            "seconds_per_frame": mean("done"), "cpu_seconds_per_frame": mean("cpu"),
            "rgb_seconds_per_frame": mean("rgb"), "gt_seconds_per_frame": mean("gt"),
            "wall_seconds_per_frame": wall / len(done) if done else None,
            "worker_start_seconds": sum(starts) / len(starts) if starts else None,
            "max_rss_mb": max((d.get("rss", 0.0) for d in done), default=None),
            "gt_process_max_rss_mb": max((d["gt_rss"] for d in done if "gt_rss" in d), default=None)}


def render_gt_only(scene_dir: str | Path, out_dir: str | Path, options: RenderOptions | None = None, *,
                   progress: bool = True, python: str | None = None, **overrides) -> dict:
    """Write the ground truth of frames [start, end) of DATASET from the scene model, without Blender
    (``render --gt-only``): every npz (and ``geometry/`` file) of those frames is computed again and replaced
    atomically, so a dataset gains a new key, or more frames, without a render. The same settings give the
    same bytes as a full render. Returns a summary dict."""
    from rgbd2scene.groundtruth.model_maps import ModelGroundTruth

    t_start = time.perf_counter()
    options = replace(options or RenderOptions(), **overrides, gt_only=False)
    try:
        options = options.validated()
    except OptionError as exc:
        raise UserError(f"{flag_of(RenderOptions, exc.name)}: {exc.message}") from None
    if not options.maps:
        raise UserError("--gt-only: --gt none leaves nothing to write")
    if options.gt_source != "model":
        raise UserError("--gt-only: the ground truth without Blender comes from the scene model "
                        "(--gt-source model)")
    scene_dir, _record, description = load_scene(scene_dir, python)
    missing = [part.geometry for _, part in description.parts() if not (scene_dir / part.geometry).is_file()]
    if missing:
        raise UserError(f"{scene_dir}: --gt-only needs the scene's geometry files ({', '.join(missing)} missing)")
    options = scene_environment(options, description)  # recorded as a full render records it
    n, s, e = frame_range(options, description, scene_dir)
    out = ensure_output_dir(out_dir)
    json_path = out / ds.DATASET_JSON
    existing = ds.read_dataset_json(out) if json_path.is_file() else None
    if existing is not None and options.size is None:  # the dataset's own size
        options = replace(options, size=(int(existing["width"]), int(existing["height"])))
    description = render_model(description, options)
    info = dataset_info(scene_dir, out, description, n, options)
    if existing is not None:
        # the images' settings (samples, denoiser, seed) do not matter here: only the ground truth's
        _check_resume(existing, info, options, json_path, only=("gt", "gt_source"))
    else:
        ds.write_dataset_json(out, info)
    if not (out / CALIBRATION_YAML).is_file():
        write_calibration(out, description.rig.calibration)
    ds.sweep_dead_runs(out)
    model = ModelGroundTruth.of_scene(description, scene_dir, n, options.maps)
    bar = _progress_bar(e - s, progress)
    try:
        # frames in parallel: the ray caster is thread safe (SceneGeometry locks its caches) and much of a
        # frame's time is numpy and zlib, which release the GIL; each frame's bytes are its own
        with ds.scratch_dir(out) as scratch, ThreadPoolExecutor(max_workers=GT_ONLY_THREADS) as pool:
            pending = deque()
            for index in range(s, e):
                pending.append(pool.submit(model.write, out, index, scratch))
                while len(pending) > GT_ONLY_THREADS or (index == e - 1 and pending):
                    pending.popleft().result()
                    if bar is not None:
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t_start
    return {"dataset": str(out), "frames": n, "range": [s, e], "written": e - s, "rendered": e - s, "skipped": 0,
            "seconds": wall, "seconds_per_frame": wall / (e - s)}


def _progress_bar(total: int, enabled: bool):
    if not enabled or total == 0:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", desc="render", dynamic_ncols=True,
                bar_format="{l_bar}{bar}| {n:.1f}/{total} frames [{elapsed}<{remaining}]")


def _run_chunk(task: Task, group: set[int], stats: dict, starts: list, bar, python: str | None) -> None:
    """Run one worker over a chunk; feed its progress events to the bar and the statistics."""
    half_done: set[int] = set()

    def on_event(event: Event) -> None:
        if event.kind == "ready":
            starts.append(event.stats["start"])
            return
        if event.frame not in group:
            return
        if event.kind == "rgb":
            half_done.add(event.frame)
            step = RGB_SHARE
        else:
            step = 1.0 - RGB_SHARE if event.frame in half_done else 1.0
            if event.kind == "done":
                stats[event.frame] = event.stats
        if bar is not None:
            bar.update(step)

    where = f" on frames {min(group)}-{max(group)}" if group else ""
    run_task(task, on_event, python=python, what="render worker", where=where)


__all__ = ["RenderOptions", "RenderJob", "prepare_render", "render_dataset", "RenderError", "load_scene",
           "dataset_info", "parse_size", "render_model", "render_task"]
