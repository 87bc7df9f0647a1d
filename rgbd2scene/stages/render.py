"""``rgbd2scene render SCENE -o DATASET``: render a scene folder into a stereo dataset (no ``bpy`` here).

:func:`render_dataset` validates its inputs, writes ``DATASET/dataset.json`` first, then runs the Blender
worker (``python -m render.frames``) in fresh processes over bounded chunks of frames, so memory
stays flat however long the sequence. Finished frames (both eyes' PNG and npz present: every file is
written atomically) are skipped, so re-running the same command resumes. A tqdm bar with ETA follows
the worker's one-line-per-frame progress on its stdout; a failing worker raises :class:`RenderError`
with the tail of its log.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rgbd2scene.capture.camera import Intrinsics
from rgbd2scene.conventions import CONVENTIONS_VERSION
from rgbd2scene.dataset import layout as ds
from rgbd2scene.errors import RenderError, UserError
from rgbd2scene.files.atomic import ensure_output_dir
from rgbd2scene.groundtruth.passes import parse_maps
from rgbd2scene.scene.model import SceneDescription
from rgbd2scene.versions import software_versions

DENOISERS = ("none", "oidn", "optix")
DEVICES = ("CPU", "GPU")
#: RGB defaults: 1 sample per pixel denoised with OpenImageDenoise beats 16 undenoised samples against a
#: 256-sample reference in about 0.3 of the time (benchmarks/results/render.md).
DEFAULT_SAMPLES = 1
DEFAULT_DENOISE = "oidn"
DEFAULT_CHUNK = 25
#: The data render of the ground truth (see render/render_frames.py).
GT_RENDER = {"samples": 1, "filter_width_px": 0.01, "max_bounces": 0, "material_override": "black emission",
             "passes": ["Depth", "Normal", "Vector", "IndexOB"], "exr": "32-bit float, multilayer"}
#: dataset.json entries that must match for a re-run to resume into the same folder.
RESUME_KEYS = ("width", "height", "frames", "baseline", "K", "seed")
RESUME_RENDER_KEYS = ("samples", "adaptive_sampling", "denoiser", "gt")
_PROGRESS = re.compile(r"^frame (\d+) (done|skipped|rgb)\b")
#: Share of a frame's progress-bar step given when its images are written (the data render that
#: completes it takes the rest: about a tenth of the time).
RGB_SHARE = 0.9
_NUMBERS = re.compile(r"(\w+) ([0-9.]+)(s|MB)")
REPO_ROOT = Path(__file__).resolve().parents[2]
#: Temporary files younger than this may belong to a run over other frames of the same folder: kept.
TEMP_MIN_AGE_S = 60.0


def _sha1(path: Path) -> str | None:
    if not path.is_file():
        return None
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _worker_env() -> dict:
    """The worker imports ``render`` and ``rgbd2scene`` from this checkout."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _tail(log, lines: int = 20) -> str:
    log.seek(0)
    text = log.read().decode(errors="replace").splitlines()
    keep = [t for t in text if t.strip() and not t.lstrip().startswith("Fra:") and "| Sample " not in t]
    return "\n".join(keep[-lines:])


def load_scene(scene_dir: str | Path, python: str | None = None) -> tuple[Path, dict, SceneDescription]:
    """Validate a scene folder; (folder, scene.json record, description)."""
    scene_dir = Path(scene_dir)
    if not scene_dir.is_dir():
        raise UserError(f"{scene_dir}: scene folder not found")
    for name in ("scene.blend", "scene.json"):
        if not (scene_dir / name).is_file():
            raise UserError(f"{scene_dir}: not a scene folder made by 'rgbd2scene scene' ({name} is missing)")
    try:
        record = json.loads((scene_dir / "scene.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{scene_dir / 'scene.json'}: not readable JSON ({exc})") from None
    if not isinstance(record, dict):
        raise UserError(f"{scene_dir / 'scene.json'}: must hold a JSON object")
    try:
        if isinstance(record.get("scene"), dict):
            description = SceneDescription.from_dict(record["scene"])
        else:  # fall back to the description stored in the blend (needs Blender: ask the worker)
            description = SceneDescription.from_dict(_describe_from_blend(scene_dir, python))
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{scene_dir / 'scene.json'}: bad scene description ({exc!r})") from None
    return scene_dir, record, description


def _describe_from_blend(scene_dir: Path, python: str | None) -> dict:
    where = str(scene_dir.resolve())
    cmd = [python or sys.executable, "-m", "render.frames", where, where, "--describe"]
    proc = subprocess.run(cmd, capture_output=True, env=_worker_env())
    lines = [t for t in proc.stdout.decode(errors="replace").splitlines() if t.startswith("{")]
    if proc.returncode != 0 or not lines:
        err = proc.stderr.decode(errors="replace").strip().splitlines()
        raise UserError(f"{scene_dir}: scene.json has no 'scene' and scene.blend holds no description "
                        f"({err[-1] if err else 'no output'})")
    return json.loads(lines[-1])


def dataset_info(scene_dir: Path, record: dict, description: SceneDescription, intr: Intrinsics, frames: int,
                 maps: tuple[str, ...], samples: int, adaptive: bool, denoise: str, device: str, seed: int,
                 chunk: int) -> dict:
    """The dataset.json record (CONVENTIONS §4 plus the render settings and provenance)."""
    files = record.get("files") if isinstance(record.get("files"), dict) else {}
    mesh_path = scene_dir / str(files.get("mesh") or description.mesh_file)
    return {
        "width": intr.width, "height": intr.height, "frames": frames, "fps": description.path.fps,
        "baseline": description.rig.baseline, "K": intr.K.tolist(), "eyes": list(ds.EYES),
        "intrinsics": intr.to_dict(),
        "objects": {str(o.id): {"name": o.name, "part": o.part, "class": o.cls, "moving": o.moving}
                    for o in description.objects},
        "scene": {"dir": str(scene_dir.resolve()), "mesh": str(mesh_path.resolve()),
                  "mesh_sha1": _sha1(mesh_path), "scene_json_sha1": _sha1(scene_dir / "scene.json"),
                  "blend_sha1": _sha1(scene_dir / "scene.blend"), "path_kind": description.path.kind,
                  "path_frames": description.path.frames, "material": description.material},
        "software": software_versions(),
        "seed": seed,
        "conventions_version": CONVENTIONS_VERSION,
        "render": {"engine": "CYCLES", "samples": samples, "adaptive_sampling": adaptive, "denoiser": denoise,
                   "size": [intr.width, intr.height], "gt": list(maps), "device": device,
                   "gt_render": GT_RENDER, "chunk": chunk},
        "layout": {"rgb": "{eye}/rgb/{frame:06d}.png", "gt": "{eye}/gt/{frame:06d}.npz"},
    }


def _check_resume(existing: dict, info: dict, path: Path) -> None:
    diffs = [k for k in RESUME_KEYS if existing.get(k) != info[k]]
    old_render = existing.get("render", {})
    diffs += [f"render.{k}" for k in RESUME_RENDER_KEYS if old_render.get(k) != info["render"][k]]
    if existing.get("scene", {}).get("scene_json_sha1") != info["scene"]["scene_json_sha1"]:
        diffs.append("scene (scene.json changed)")
    if diffs:
        raise UserError(f"{path}: this folder holds a dataset rendered with other settings "
                        f"({', '.join(diffs)}); choose another output folder or delete it")


def render_dataset(scene_dir: str | Path, out_dir: str | Path, frames: int | None = None,
                   size: tuple[int, int] | None = None, gt: str = "all", start: int | None = None,
                   end: int | None = None, samples: int = DEFAULT_SAMPLES, adaptive: bool = True,
                   denoise: str = DEFAULT_DENOISE, device: str = "CPU", chunk: int = DEFAULT_CHUNK, seed: int = 0,
                   threads: int = 0, progress: bool = True, python: str | None = None) -> dict:
    """Render SCENE into DATASET (CONVENTIONS §4); returns a summary dict.

    Parameters
    ----------
    frames
        Dataset length: the first ``frames`` frames of the camera path (default: all of it; more than
        the path holds is an error).
    size
        (W, H) of the images; K is rescaled with :meth:`Intrinsics.resized` (default: the scene's).
    gt
        ``"all"``, ``"none"`` or a comma list of maps (``depth,disparity,normals,flow,segmentation``).
    start, end
        Render only frames [start, end) of the dataset (default: all); the rest can follow later.
    samples, adaptive, denoise, seed
        RGB render: samples per pixel, adaptive sampling, denoiser (none, oidn, optix), Cycles seed.
    device, threads
        Cycles device (CPU or GPU) and render threads (0: all cores).
    chunk
        Frames per worker process (Blender's memory grows over long renders).
    """
    t_start = time.perf_counter()
    try:
        maps = parse_maps(gt)
    except ValueError as exc:
        raise UserError(f"--gt: {exc}") from None
    denoise = (denoise or "none").lower()
    if denoise not in DENOISERS:
        raise UserError(f"--denoise: choose one of {', '.join(DENOISERS)}, got {denoise!r}")
    device = str(device).upper()
    if device not in DEVICES:
        raise UserError(f"--device: choose CPU or GPU, got {device!r}")
    if int(samples) < 1:
        raise UserError(f"--samples: must be at least 1, got {samples}")
    if int(chunk) < 1:
        raise UserError(f"--chunk: must be at least 1, got {chunk}")

    scene_dir, record, description = load_scene(scene_dir, python)
    path_frames = description.path.frames
    n = path_frames if frames is None else int(frames)
    if n < 1 or n > path_frames:
        raise UserError(f"--frames: {n} is not between 1 and the {path_frames} frames of the camera path "
                        f"in {scene_dir / 'scene.json'}")
    s = 0 if start is None else int(start)
    e = n if end is None else int(end)
    if not 0 <= s < e <= n:
        raise UserError(f"--start/--end: [{s}, {e}) is not a non-empty range inside the {n} frames")
    intr = description.rig.intrinsics
    if size is not None:
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise UserError(f"--size: must be positive, got {w}x{h}")
        intr = intr.resized(w, h)
    out = ensure_output_dir(out_dir)

    info = dataset_info(scene_dir, record, description, intr, n, maps, int(samples), bool(adaptive), denoise,
                        device, int(seed), int(chunk))
    json_path = out / ds.DATASET_JSON
    if json_path.is_file():
        _check_resume(ds.read_dataset_json(out), info, json_path)
    else:
        ds.write_dataset_json(out, info)
    ds.remove_temp_files(out, min_age_s=TEMP_MIN_AGE_S)

    with_gt = bool(maps)
    todo = [i for i in range(s, e) if not ds.frame_done(out, i, gt=with_gt)]
    skipped = (e - s) - len(todo)
    chunks = [todo[i:i + int(chunk)] for i in range(0, len(todo), int(chunk))]
    base = [python or sys.executable, "-m", "render.frames", str(scene_dir.resolve()),
            str(out.resolve()), "--frames", str(n), "--samples", str(int(samples)),
            "--gt", ",".join(maps) or "none", "--device", device, "--denoise", denoise,
            "--seed", str(int(seed)), "--threads", str(int(threads))]
    if size is not None:
        base += ["--size", f"{intr.width}x{intr.height}"]
    if not adaptive:
        base.append("--no-adaptive")

    stats: dict[int, dict] = {}
    starts: list[float] = []
    bar = _progress_bar(len(todo), progress)
    try:
        for group in chunks:
            cmd = base + ["--start", str(group[0]), "--end", str(group[-1] + 1)]
            _run_worker(cmd, set(group), stats, starts, bar)
            missing = [i for i in group if not ds.frame_done(out, i, gt=with_gt)]
            if missing:
                raise RenderError(f"render worker finished but frames {missing} of {out} are incomplete")
    finally:
        if bar is not None:
            bar.close()
    ds.remove_temp_files(out, min_age_s=TEMP_MIN_AGE_S)

    done = [stats[i] for i in sorted(stats)]
    wall = time.perf_counter() - t_start

    def mean(key):
        vals = [d[key] for d in done if key in d]
        return sum(vals) / len(vals) if vals else None

    return {"dataset": str(out), "frames": n, "range": [s, e], "rendered": len(done), "skipped": skipped,
            "chunks": len(chunks), "seconds": wall,
            "seconds_per_frame": mean("done"), "cpu_seconds_per_frame": mean("cpu"),
            "rgb_seconds_per_frame": mean("rgb"), "gt_seconds_per_frame": mean("gt"),
            "wall_seconds_per_frame": wall / len(done) if done else None,
            "worker_start_seconds": sum(starts) / len(starts) if starts else None,
            "max_rss_mb": max((d.get("rss", 0.0) for d in done), default=None)}


def _progress_bar(total: int, enabled: bool):
    if not enabled or total == 0:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", desc="render", dynamic_ncols=True,
                bar_format="{l_bar}{bar}| {n:.1f}/{total} frames [{elapsed}<{remaining}]")


def _run_worker(cmd: list[str], group: set[int], stats: dict, starts: list, bar) -> None:
    """Run one worker process; parse its progress lines; raise RenderError when it fails."""
    t0 = time.perf_counter()
    half_done: set[int] = set()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=_worker_env(), text=True,
                                bufsize=1)
        try:
            for line in proc.stdout:
                line = line.strip()
                if line.startswith("ready"):
                    starts.append(time.perf_counter() - t0)
                    continue
                m = _PROGRESS.match(line)
                if not m or int(m.group(1)) not in group:
                    continue
                index, what = int(m.group(1)), m.group(2)
                if what == "rgb":
                    half_done.add(index)
                    step = RGB_SHARE
                else:
                    step = 1.0 - RGB_SHARE if index in half_done else 1.0
                    if what == "done":
                        stats[index] = {k: float(v) for k, v, _ in _NUMBERS.findall(line)}
                if bar is not None:
                    bar.update(step)
            rc = proc.wait()
        except BaseException:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            raise
        if rc != 0:
            frames = f"{min(group)}-{max(group)}" if group else "?"
            raise RenderError(f"render worker failed (exit status {rc}) on frames {frames}:\n{_tail(log)}\n"
                              f"command: {' '.join(cmd)}")


__all__ = ["render_dataset", "RenderError", "load_scene", "dataset_info"]
