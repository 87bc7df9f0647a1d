#!/usr/bin/env python3
"""Render benchmark: default quality settings, ground-truth cost and worker memory (Cycles on CPU).

Usage: ``python benchmarks/bench_render.py [--quick] [--frames-memory N] [--sections ...] [--out MD]``

The scene is built once per run from the bundled sample (``rgbd2scene scene`` on
``data_samples/tissue``, default wet-tissue material, scan path of 100 frames, 512x256 rig) into
``bench_out/render/scene``. Every render goes through the project's one Blender entry point (a render
:class:`~rgbd2scene.stages.blender.Task` run by :func:`~rgbd2scene.stages.blender.run_task`, as
:func:`rgbd2scene.stages.render.render_dataset` does per chunk), and the figures come from its progress
events (``frame N done ...s cpu ... rgb ... gt ... rss ...``: the numbers ``render_dataset`` averages
into its summary), so single frames can be told apart.

1. **Quality** (``quality``): a 256-sample, non-adaptive, undenoised reference (another seed, so its
   noise is independent of the candidates') and candidate RGB settings (samples, adaptive sampling,
   denoiser) on frames spread along the path. Each candidate renders frame f-1 then f in one worker;
   f-1 only warms it up (the first render of a worker also builds the BVH and, with OIDN, loads the
   denoiser), f is scored and timed (median over the frames of the wall time and of the worker's CPU
   time, which other load on the machine inflates less; the candidates run in reverse order on every
   other frame). Scores on the 8-bit PNGs of both eyes against the reference:
   PSNR (of the pooled squared error), mean SSIM (``skimage.metrics.structural_similarity``) and
   *detail*, the fine texture a candidate keeps: the correlation of its high-pass luminance (minus a
   Gaussian blur, sigma 1 px) with the reference's, relative to the same correlation of the
   16-sample undenoised render (noise is independent of the reference's and averages out of a
   correlation; blurring lowers it: 1 = as much texture as 16 samples, below 1 = smeared). The images
   are the renderer's before the sensor model (fixed exposure, no vignetting, no sensor noise:
   :data:`QUALITY_SENSOR`). Target: the issue's 40 dB and SSIM 0.97; the pick is the fastest candidate
   that reaches it.
2. **Ground-truth cost** (``gt``): the library defaults (``DEFAULT_SAMPLES`` and ``render_dataset``'s
   adaptive/denoise defaults), the same frames rendered RGB only (``--gt none``) and RGB + all ground
   truth (``--gt all``), alternating, one worker (chunk) per run. First frame (worker start plus frame
   0) and the steady-state mean over the other frames are reported apart.
3. **Memory** (``memory``): ``--frames-memory`` frames, RGB + all ground truth at the defaults, in
   chunks of ``DEFAULT_CHUNK`` frames (one worker each, like ``render_dataset``): the worker's peak
   resident memory (``ru_maxrss`` from ``wait4``) per chunk, and its current RSS read from ``/proc``
   at each of its progress lines (after every RGB render, then after every frame's ground truth).

``--quick`` (about 2 minutes): the quality sweep at 256x128 on one frame with four candidates, the
ground-truth comparison on 4 frames once, 10 memory frames; its report goes to
``bench_out/render/render.md`` unless ``--out`` is given. The full run takes about 15 minutes and
writes ``benchmarks/results/render.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.rendering import DENOISERS  # noqa: E402
from rgbd2scene.sensor import SensorOptions  # noqa: E402
from rgbd2scene.stages.blender import run_task  # noqa: E402
from rgbd2scene.stages.render import (  # noqa: E402
    DEFAULT_CHUNK,
    DEFAULT_DENOISE_QUALITY,
    DEFAULT_PREFILTER,
    RenderOptions,
    load_scene,
    render_model,
    render_task,
)
from rgbd2scene.stages.scene import SceneOptions  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

SAMPLE = ROOT / "data_samples" / "tissue"
WORK = ROOT / "bench_out" / "render"
PATH_FRAMES = 100
SIZE = (512, 256)
QUICK_QUALITY_SIZE = (256, 128)
SECTIONS = ("quality", "gt", "motion", "memory", "bake")
#: The bake section: frames scored and timed (each after a warm-up frame) and the samples of both renders.
BAKE_FRAMES = (10, 50, 90)
QUICK_BAKE_FRAMES = (50,)
#: Scenes of the motion section: the static scene against moving ones (flags of ``rgbd2scene scene``).
MOTION_SCENES = {"static": (), "breathing tissue": ("--deform", "breathing")}
if "instrument" in {f.name for f in dataclasses.fields(SceneOptions)}:
    MOTION_SCENES["instrument + breathing"] = ("--instrument", "--deform", "breathing")
#: Quality frames (scored and timed; each follows a warm-up frame), spread along the 100-frame path.
QUALITY_FRAMES = (10, 50, 90)
QUICK_QUALITY_FRAMES = (50,)
REFERENCE_SEED = 1
CANDIDATE_SEED = 0
#: Cycles' phases of a render (render/timing.py), summed into a candidate's seconds per stereo frame.
RENDER_PHASES = ("sync", "bvh", "trace", "save")
#: The issue's target against the 256-spp reference of the same scene.
TARGET_PSNR_DB, TARGET_SSIM = 40.0, 0.97
DETAIL_SIGMA_PX = 1.0
GT_TARGET = 0.15
#: Figures quoted in the issue for this machine (512x256, 16 samples, 300k-vertex mesh, stereo frame).
ISSUE_PLAIN_CYCLES_S = 3.7
ISSUE_VISIONBLENDER_S = 5.6


@dataclass(frozen=True)
class Setting:
    """RGB render settings of the worker."""

    samples: int
    adaptive: bool
    denoise: str
    prefilter: str = DEFAULT_PREFILTER
    #: OpenImageDenoise's network (``--denoise-quality``); the rows before session 7 were all ``high``.
    quality: str = "high"

    @property
    def label(self) -> str:
        pre = f" ({self.prefilter} prefilter, {self.quality} network)" if DENOISERS[self.denoise].prefilter else ""
        return f"{self.samples} spp, {'adaptive' if self.adaptive else 'fixed'}, {self.denoise}{pre}"

    @property
    def slug(self) -> str:
        pre = f"_{self.prefilter}_{self.quality}" if DENOISERS[self.denoise].prefilter else ""
        return f"s{self.samples}_{'a' if self.adaptive else 'f'}_{self.denoise}{pre}"

    def options(self, **more) -> RenderOptions:
        return RenderOptions(samples=self.samples, adaptive=self.adaptive, denoise=self.denoise,
                             prefilter=self.prefilter, denoise_quality=self.quality, **more)


REFERENCE = Setting(256, False, "none")
BAKE_SETTING = Setting(16, False, "none")
BASELINE = Setting(16, False, "none")
CANDIDATES = (BASELINE, Setting(16, False, "oidn", "fast"), Setting(8, False, "oidn", "accurate"),
              Setting(4, False, "oidn", "accurate"), Setting(4, False, "oidn", "fast"),
              Setting(2, False, "oidn", "fast"), Setting(1, True, "oidn", "fast"), Setting(1, True, "oidn", "accurate"),
              Setting(4, False, "oidn", "fast", "fast"), Setting(2, False, "oidn", "fast", "fast"),
              Setting(1, True, "oidn", "fast", "fast"))
QUICK_CANDIDATES = (BASELINE, Setting(4, False, "oidn", "fast"), Setting(2, False, "oidn", "fast"),
                    Setting(1, True, "oidn", "fast"), Setting(1, True, "oidn", "fast", DEFAULT_DENOISE_QUALITY))
#: The quality sweep scores the renderer's output before the sensor model: fixed exposure, no vignetting and no
#: sensor noise (which would otherwise dominate the error and differ between seeds), only the tone curve.
QUALITY_SENSOR = SensorOptions(exposure="fixed", vignetting=False, noise=False)


@dataclass
class WorkerRun:
    """What one worker process reported.

    Attributes
    ----------
    ready_s
        Seconds from the process start to its ``ready`` line (Python, ``bpy``, the blend).
    frames
        Frame index -> the numbers of its ``done`` line (``done``, ``cpu``, ``rgb``, ``gt`` in seconds,
        ``rss`` in MB).
    rss_trace
        The process's resident memory (MB) at each progress line, in order.
    peak_rss_mb
        The process's peak resident memory (``ru_maxrss``).
    wall_s
        The worker's whole wall time, process start to exit.
    cpu_s
        CPU seconds of the worker and its children (load-independent), process start to exit.
    """

    ready_s: float
    frames: dict[int, dict[str, float]] = field(default_factory=dict)
    rss_trace: list[float] = field(default_factory=list)
    peak_rss_mb: float = 0.0
    wall_s: float = 0.0
    cpu_s: float = 0.0


def default_setting() -> Setting:
    """The library's default RGB settings (``RenderOptions``'s defaults)."""
    d = RenderOptions()
    return Setting(d.samples, d.adaptive, d.denoise, d.prefilter, d.denoise_quality)


def build_scene(folder: Path, extra: tuple[str, ...] = ()) -> None:
    """``rgbd2scene scene`` on the bundled sample: default material, scan path of 100 frames (plus ``extra``
    flags, e.g. ``--deform breathing``)."""
    if folder.exists():
        shutil.rmtree(folder)
    cmd = [sys.executable, "-c", "import sys; from rgbd2scene.cli import main; sys.exit(main(sys.argv[1:]))",
           "scene", "--rgb", str(SAMPLE / "rgb.png"), "--depth", str(SAMPLE / "depth.png"),
           "--camera", str(SAMPLE / "camera.json"), "-o", str(folder), "--frames", str(PATH_FRAMES), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"building the scene failed: {' '.join(cmd)}\n{proc.stderr[-2000:]}")


def mesh_vertices(scene: Path) -> int:
    """Vertex count of a scene's mesh (from its ``scene.json``)."""
    return int(json.loads((scene / "scene.json").read_text())["mesh"]["stats"]["vertices"])


def _children_cpu_s() -> float:
    """CPU seconds of this process's finished children (and theirs)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_worker(scene: Path, out: Path, setting: Setting, start: int, end: int, frames: int, gt: str,
               size: tuple[int, int], seed: int = CANDIDATE_SEED, sensor: SensorOptions | None = None) -> WorkerRun:
    """Render frames [start, end) of a ``frames``-long dataset into a fresh ``out`` in one worker.

    Parameters
    ----------
    scene, out
        Scene folder and dataset folder (removed first: finished frames would be skipped).
    setting
        RGB settings.
    gt
        ``"none"`` or ``"all"``.
    size
        (W, H) of the images.
    seed
        Cycles seed (animated per frame).
    sensor
        The sensor model's settings (default the library's).

    Returns
    -------
    WorkerRun
        Per-frame figures from the worker's progress lines and its peak memory.

    Raises
    ------
    RuntimeError
        The worker failed; the message holds the tail of its log.
    """
    if out.exists():
        shutil.rmtree(out)
    options = setting.options(size=size, gt=gt, seed=seed, engine="cycles",
                              **({} if sensor is None else {"sensor": sensor})).validated()
    model = render_model(load_scene(scene)[2], options)
    run = WorkerRun(ready_s=float("nan"))

    def on_event(event) -> None:
        if event.kind == "ready":
            run.ready_s = event.stats["start"]
        elif event.kind in ("rgb", "done"):
            run.rss_trace.append(event.stats.get("rss", float("nan")))
            if event.kind == "done":
                run.frames[event.frame] = event.stats

    cpu = _children_cpu_s()
    result = run_task(render_task(scene, out, model, options, frames, start, end), on_event)
    run.peak_rss_mb, run.wall_s, run.cpu_s = result.peak_rss_mb, result.seconds, _children_cpu_s() - cpu
    return run


# --- 1. quality ------------------------------------------------------------------------------------------

def read_png(path: Path) -> np.ndarray:
    """An 8-bit PNG as float64 (H, W, 3)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RuntimeError(f"{path}: not readable")
    return img[..., ::-1].astype(np.float64)


def _highpass(img: np.ndarray) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    lum = img.mean(axis=2)
    return lum - gaussian_filter(lum, DETAIL_SIGMA_PX)


def score(items: list[tuple[Path, Path, Path, int]]) -> dict[str, float]:
    """PSNR, SSIM and detail of rendered frames (both eyes) against the reference.

    Parameters
    ----------
    items
        (candidate dataset, reference dataset, baseline dataset, frame) per scored frame.

    Returns
    -------
    dict
        ``psnr`` (dB, of the squared error pooled over all images), ``ssim`` (mean over images),
        ``detail`` (high-pass correlation with the reference relative to the baseline's).
    """
    from skimage.metrics import structural_similarity

    squared, ssims, corr, corr_base = [], [], 0.0, 0.0
    for dataset, reference, baseline, frame in items:
        for eye in ("left", "right"):
            name = Path(eye) / "rgb" / f"{frame:06d}.png"
            img, ref, base = (read_png(d / name) for d in (dataset, reference, baseline))
            squared.append(np.mean((img - ref) ** 2))
            ssims.append(structural_similarity(img, ref, channel_axis=2, data_range=255.0))
            hp_ref = _highpass(ref)
            corr += float(np.sum(_highpass(img) * hp_ref))
            corr_base += float(np.sum(_highpass(base) * hp_ref))
    mse = float(np.mean(squared))
    psnr = float("inf") if mse == 0 else 10.0 * float(np.log10(255.0**2 / mse))
    return {"psnr": psnr, "ssim": float(np.mean(ssims)), "detail": corr / corr_base}


def quality_sweep(scene: Path, candidates: tuple[Setting, ...], frames: tuple[int, ...],
                  size: tuple[int, int], reuse: bool = False) -> dict:
    """Render the reference and the candidates on ``frames``; score, time and pick.

    Returns
    -------
    dict
        ``rows`` (one per candidate: setting, median wall and CPU seconds per stereo frame, scores or an
        error),
        ``pick`` (the fastest row reaching :func:`reaches`, or None), ``reference_s``.
    """
    root = WORK / "quality"
    folder = {s: root / s.slug for s in candidates}
    seconds: dict[Setting, list[float]] = {s: [] for s in candidates}
    cpu: dict[Setting, list[float]] = {s: [] for s in candidates}
    errors: dict[Setting, str] = {}
    reference_s = []
    for k, f in enumerate(frames):
        ref_dir = root / "reference" / f"f{f}"
        kept = ref_dir / f"reference_{size[0]}x{size[1]}.json"
        if reuse and kept.is_file():  # the same scene, size and frame rendered by an earlier run
            reference_s.append(json.loads(kept.read_text())["seconds"])
        else:
            ref = run_worker(scene, ref_dir, REFERENCE, f, f + 1, PATH_FRAMES, "none", size, seed=REFERENCE_SEED,
                             sensor=QUALITY_SENSOR)
            reference_s.append(ref.frames[f]["rgb"])
            kept.write_text(json.dumps({"seconds": reference_s[-1]}))
        print(f"  frame {f}: reference {REFERENCE.label}: {reference_s[-1]:.1f} s", flush=True)
        for s in candidates if k % 2 == 0 else candidates[::-1]:  # a slow spell hits other candidates
            if s in errors:
                continue
            try:
                run = run_worker(scene, folder[s] / f"f{f}", s, f - 1, f + 1, PATH_FRAMES, "none", size,
                                 sensor=QUALITY_SENSOR)
            except RuntimeError as exc:
                errors[s] = str(exc).splitlines()[-1]
                print(f"  frame {f}: {s.label}: FAILED ({errors[s]})", flush=True)
                continue
            # Cycles' own time for frame f's render (both eyes): the worker's lines are pipelined (a frame's
            # share of the wall time holds the next frame's render), so the last frame's share is no measure
            seconds[s].append(sum(run.frames[f].get(f"rgb_{p}", 0.0) for p in RENDER_PHASES))
            cpu[s].append(run.frames[f].get("rgb_trace", float("nan")))
            print(f"  frame {f}: {s.label}: {seconds[s][-1]:.2f} s, trace {cpu[s][-1]:.2f} s", flush=True)
    rows = []
    for s in candidates:
        row = {"setting": s, "error": errors.get(s)}
        if s not in errors:
            row.update(seconds=statistics.median(seconds[s]), cpu=statistics.median(cpu[s]))
            row.update(score([(folder[s] / f"f{f}", root / "reference" / f"f{f}", folder[BASELINE] / f"f{f}", f)
                              for f in frames]))
        rows.append(row)
    passing = [r for r in rows if reaches(r)]
    pick = min(passing, key=lambda r: r["seconds"]) if passing else None
    return {"rows": rows, "pick": pick, "reference_s": statistics.median(reference_s)}


def reaches(row: dict) -> bool:
    """Whether a scored candidate reaches the issue's target (:data:`TARGET_PSNR_DB`, :data:`TARGET_SSIM`)."""
    return row["error"] is None and row["psnr"] >= TARGET_PSNR_DB and row["ssim"] >= TARGET_SSIM


def quality_table(result: dict) -> str:
    base = next(r for r in result["rows"] if r["setting"] == BASELINE)
    lines = [f"| setting | s / stereo frame (RGB) | vs {BASELINE.label} | trace s | PSNR dB | SSIM | detail | "
             "reaches target |", "|---|---|---|---|---|---|---|---|"]
    ok = [r for r in result["rows"] if r["error"] is None]
    for r in sorted(ok, key=lambda r: r["seconds"]):
        reach = "yes" if reaches(r) else "no"
        mark = "**" if r is result["pick"] else ""
        lines.append(f"| {mark}{r['setting'].label}{mark} | {r['seconds']:.2f} | {r['seconds'] / base['seconds']:.2f} "
                     f"| {r['cpu']:.2f} | {r['psnr']:.2f} | {r['ssim']:.4f} | {r['detail']:.2f} | {reach} |")
    lines += [f"| {r['setting'].label} | failed: {r['error']} | | | | | | |" for r in result["rows"] if r["error"]]
    return "\n".join(lines)


def default_note(rows: list[dict], pick: dict | None, default: Setting) -> str:
    """How the library default compares with the pick (same images and time within 10 %: a tie)."""
    if pick is not None and pick["setting"] == default:
        return "the library default"
    row = next((r for r in rows if r["setting"] == default and r["error"] is None), None)
    if row is None:
        return f"the library default ({default.label}) was not measured"
    text = f"the library default ({default.label}): {row['seconds']:.2f} s, {row['psnr']:.2f} dB"
    same_images = pick is not None and all(row[k] == pick[k] for k in ("psnr", "ssim", "detail"))
    if same_images and row["seconds"] <= 1.1 * pick["seconds"]:
        text += ", the same images (identical scores) within 10 % of the time: a tie"
    return text


def detail_note(rows: list[dict]) -> str:
    """One sentence: the fine texture the denoised and the undenoised candidates keep."""
    spans = []
    for denoised, name in ((True, "denoised"), (False, "undenoised")):
        d = [r["detail"] for r in rows if r["error"] is None and (r["setting"].denoise != "none") == denoised]
        if d:
            spans.append(f"{name} {min(d):.2f}-{max(d):.2f}")
    return f"Detail (fine texture kept, 1 = as much as {BASELINE.label}): {', '.join(spans)}."


# --- 2. ground-truth cost -----------------------------------------------------------------------------------

def gt_cost(scene: Path, setting: Setting, frames: int, repeats: int, size: tuple[int, int]) -> dict:
    """RGB only vs RGB + all ground truth on frames [0, frames), alternating, ``repeats`` times each.

    Steady state: medians over frames and runs (robust to the machine's spikes). The worker renders a
    chunk in two phases (every RGB render, then every data render, pipelined: a frame's ``done`` line
    comes after the next frame's data render), so the steady-state ground-truth part is the median
    ``gt`` of frames 1 to ``frames``-2: frame 0's line also carries the switch to the data render and
    frame 1's data render, the last one only the last conversion. First frame: worker start + frame 0's
    RGB part + frame 0's ground-truth part less one steady-state data render (frame 1's), mean over runs.

    Returns
    -------
    dict
        Per mode (``"none"``, ``"all"``): ``start`` (worker start), ``first`` (first frame, including
        the start), ``steady``, ``rgb``, ``gt`` (steady-state seconds per frame and its two parts),
        ``wall`` and ``cpu`` (the worker's whole run, mean; CPU seconds with its children); ``ratio``
        (steady all / steady none), ``wall_ratio`` (wall all / wall none), ``in_run_overhead`` (gt / rgb of
        the GT runs).
    """
    if frames < 3:
        raise ValueError("the ground-truth comparison needs at least 3 frames")
    runs: dict[str, list[WorkerRun]] = {"none": [], "all": []}
    for r in range(repeats):
        for gt in ("none", "all"):
            run = run_worker(scene, WORK / "gt" / f"{gt}{r}", setting, 0, frames, PATH_FRAMES, gt, size)
            runs[gt].append(run)
            print(f"  gt {gt}, run {r + 1}: " + " ".join(f"{run.frames[i]['rgb']:.2f}+{run.frames[i]['gt']:.2f}"
                                                          for i in range(frames)) + " s", flush=True)
    out = {}
    for gt, group in runs.items():
        rgb = statistics.median(run.frames[i]["rgb"] for run in group for i in range(1, frames))
        data = statistics.median(run.frames[i]["gt"] for run in group for i in range(1, frames - 1))
        first = [run.ready_s + run.frames[0]["rgb"] + run.frames[0]["gt"] - data for run in group]
        out[gt] = {"start": statistics.fmean(run.ready_s for run in group), "rgb": rgb, "gt": data,
                   "steady": rgb + data, "first": statistics.fmean(first),
                   "wall": statistics.fmean(run.wall_s for run in group),
                   "cpu": statistics.fmean(run.cpu_s for run in group)}
    out["ratio"] = out["all"]["steady"] / out["none"]["steady"]
    out["wall_ratio"] = out["all"]["wall"] / out["none"]["wall"]
    out["in_run_overhead"] = out["all"]["gt"] / out["all"]["rgb"]
    return out


def gt_table(result: dict, frames: int, repeats: int) -> str:
    lines = ["| run | worker start s | first frame s (incl. start) | steady s / stereo frame | of which RGB | "
             "of which GT |", "|---|---|---|---|---|---|"]
    for gt, name in (("none", "RGB only (`--gt none`)"), ("all", "RGB + all GT (`--gt all`)")):
        d = result[gt]
        lines.append(f"| {name} | {d['start']:.2f} | {d['first']:.2f} | {d['steady']:.2f} | {d['rgb']:.2f} "
                     f"| {d['gt']:.2f} |")
    verdict = "meets" if result["ratio"] - 1.0 <= GT_TARGET else "misses"
    extra, in_run = 100 * (result["ratio"] - 1), 100 * result["in_run_overhead"]
    lines += ["", f"Steady state (medians, frames 1-{frames - 1}, see `gt_cost`), {repeats} alternating run(s) each: "
              f"RGB + GT / RGB only = **{result['ratio']:.3f}** ({extra:+.1f} %); inside the GT runs the "
              f"ground-truth part is {in_run:.1f} % of the RGB part. This {verdict} the target of at most "
              f"+{100 * GT_TARGET:.0f} %."]
    return "\n".join(lines)


# --- 3. memory ---------------------------------------------------------------------------------------------

def memory_run(scene: Path, setting: Setting, frames: int, chunk: int, size: tuple[int, int]) -> list[dict]:
    """Frames [0, frames) with all ground truth in chunks of ``chunk`` frames, one worker each.

    Returns
    -------
    list of dict
        Per chunk: ``range``, ``peak`` (ru_maxrss, MB), ``rss`` (the RSS trace, MB: one value per RGB
        render, then one per finished frame), ``seconds`` (median s per frame).
    """
    out_dir = WORK / "memory"
    if out_dir.exists():
        shutil.rmtree(out_dir)
    chunks = []
    for s in range(0, frames, chunk):
        e = min(s + chunk, frames)
        run = run_worker(scene, out_dir / f"chunk{s:03d}", setting, s, e, frames, "all", size)
        rss = run.rss_trace
        chunks.append({"range": (s, e), "peak": run.peak_rss_mb, "rss": rss,
                       "seconds": statistics.median(run.frames[i]["done"] for i in range(s, e))})
        print(f"  frames {s}-{e - 1}: peak {run.peak_rss_mb:.0f} MB, RSS {rss[0]:.0f} -> {max(rss):.0f} -> "
              f"{rss[-1]:.0f} MB, {chunks[-1]['seconds']:.2f} s/frame", flush=True)
    return chunks


def memory_table(chunks: list[dict]) -> str:
    lines = ["| frames | worker peak RSS MB | RSS after 1st RGB render / last RGB render / last frame MB | "
             "RSS growth MB/frame (RGB phase, data phase) | s / frame |", "|---|---|---|---|---|"]
    for c in chunks:
        n = c["range"][1] - c["range"][0]
        rgb, data = c["rss"][:n], c["rss"][n:]
        slopes = [np.polyfit(np.arange(len(x)), x, 1)[0] if len(x) > 1 else 0.0 for x in (rgb, data)]
        lines.append(f"| {c['range'][0]}-{c['range'][1] - 1} | {c['peak']:.0f} | {rgb[0]:.0f} / {rgb[-1]:.0f} / "
                     f"{data[-1]:.0f} | {slopes[0]:+.2f}, {slopes[1]:+.2f} | {c['seconds']:.2f} |")
    peaks = [c["peak"] for c in chunks]
    lines += ["", f"Peak over all chunks {max(peaks):.0f} MB; spread between chunks {max(peaks) - min(peaks):.0f} MB."]
    return "\n".join(lines)


# --- report ------------------------------------------------------------------------------------------------

def bake_compare(baked: Path, procedural: Path, frames: tuple[int, ...], size: tuple[int, int],
                 setting: Setting = BAKE_SETTING) -> dict:
    """The same scene with its tissue detail baked into textures and evaluated per sample (procedural):
    RGB renders of ``frames`` (each after a warm-up frame, in one worker per frame and scene), alternating
    which goes first; the wall and CPU seconds of the scored frames. Two renders at these samples differ by
    their noise too, so the baked images are scored against the procedural ones next to the *noise floor*:
    the procedural scene rendered again with another seed (``REFERENCE_SEED``), scored the same way (PSNR,
    SSIM; detail = the high-pass correlation with the procedural render relative to the other seed's)."""
    root = WORK / "bake"
    seconds = {"baked": [], "procedural": []}
    cpu = {"baked": [], "procedural": []}
    order = (("baked", baked), ("procedural", procedural))
    for k, f in enumerate(frames):
        for name, scene in order if k % 2 == 0 else order[::-1]:
            run = run_worker(scene, root / name / f"f{f}", setting, f - 1, f + 1, PATH_FRAMES, "none", size)
            seconds[name].append(run.frames[f]["rgb"])
            cpu[name].append(run.frames[f]["cpu"])
            print(f"  frame {f}: {name}: {seconds[name][-1]:.2f} s, cpu {cpu[name][-1]:.2f} s", flush=True)
        run_worker(procedural, root / "floor" / f"f{f}", setting, f, f + 1, PATH_FRAMES, "none", size,
                   seed=REFERENCE_SEED)
    out = {name: {"seconds": statistics.median(seconds[name]), "cpu": statistics.median(cpu[name])}
           for name in seconds}
    out["ratio"] = out["procedural"]["seconds"] / out["baked"]["seconds"]
    out["cpu_ratio"] = out["procedural"]["cpu"] / out["baked"]["cpu"]
    items = {name: [(root / name / f"f{f}", root / "procedural" / f"f{f}", root / "floor" / f"f{f}", f)
                    for f in frames] for name in ("baked", "floor")}
    out["score"], out["floor"] = score(items["baked"]), score(items["floor"])
    return out


def bake_table(result: dict, setting: Setting, blend_mb: dict[str, float]) -> str:
    lines = ["| tissue detail | s / stereo frame (RGB) | CPU s | scene.blend MB |", "|---|---|---|---|"]
    for name in ("procedural", "baked"):
        lines.append(f"| {name} | {result[name]['seconds']:.2f} | {result[name]['cpu']:.2f} | {blend_mb[name]:.0f} |")
    sc, fl = result["score"], result["floor"]
    return "\n".join(lines) + (
        f"\n\nProcedural / baked at {setting.label}: **{result['ratio']:.2f}x** wall, {result['cpu_ratio']:.2f}x CPU. "
        f"Against the procedural render (seed {CANDIDATE_SEED}): baked (same seed) PSNR **{sc['psnr']:.2f} dB**, "
        f"SSIM {sc['ssim']:.4f}, detail {sc['detail']:.2f}; the noise floor, procedural again with seed "
        f"{REFERENCE_SEED}: PSNR {fl['psnr']:.2f} dB, SSIM {fl['ssim']:.4f} (detail 1 by definition: the fine "
        "texture the baked render shares with the procedural one, relative to what another procedural render "
        "shares with it).")


def _machine() -> str:
    model = ""
    try:
        model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                      if line.startswith("model name")), "")
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{platform.machine()}, {cores} cores{', ' + model if model else ''}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 2 minutes: fewer frames and candidates")
    ap.add_argument("--frames-memory", type=int, default=None,
                    help="frames of the memory run (default 100, quick 10)")
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS), help="what to run")
    ap.add_argument("--quality-size", default=None, help="size of the quality sweep (default 512x256, quick 256x128)")
    ap.add_argument("--reuse", action="store_true", help="keep bench_out's scene and the quality sweep's "
                    "reference renders from an earlier run (same size and frames) instead of rendering them again")
    ap.add_argument("--quality-frames", type=int, nargs="+", default=None,
                    help="scored frames of the quality sweep (default 10 50 90, quick 50)")
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/render.md, "
                    "quick: bench_out/render/render.md; '' to skip)")
    args = ap.parse_args(argv)
    frames_memory = args.frames_memory or (10 if args.quick else PATH_FRAMES)
    if not 1 <= frames_memory <= PATH_FRAMES:
        ap.error(f"--frames-memory must be between 1 and {PATH_FRAMES}")
    out_md = args.out if args.out is not None else str(
        WORK / "render.md" if args.quick else ROOT / "benchmarks" / "results" / "render.md")
    gt_frames, gt_repeats = (4, 1) if args.quick else (10, 3)
    motion_frames, motion_repeats = (4, 1) if args.quick else (6, 2)
    candidates = QUICK_CANDIDATES if args.quick else CANDIDATES
    default = default_setting()
    if default not in candidates:
        candidates = (*candidates, default)
    quality_frames = tuple(args.quality_frames or (QUICK_QUALITY_FRAMES if args.quick else QUALITY_FRAMES))
    quality_size = (tuple(int(v) for v in args.quality_size.split("x")) if args.quality_size
                    else QUICK_QUALITY_SIZE if args.quick else SIZE)

    t0 = time.perf_counter()
    WORK.mkdir(parents=True, exist_ok=True)
    scene = WORK / "scene"
    print(f"building the scene ({SAMPLE.relative_to(ROOT)}, {PATH_FRAMES} frames, scan path) -> {scene}", flush=True)
    if not (args.reuse and (scene / "scene.blend").is_file()):
        build_scene(scene)
    versions = software_versions()
    settings = {"machine": _machine(), "python": versions["python"], "bpy": versions["bpy"], "device": "CPU",
                "threads": "all cores", "quick": args.quick, "library default": default.label,
                "chunk": DEFAULT_CHUNK}
    print("settings: " + ", ".join(f"{k} {v}" for k, v in settings.items()), flush=True)
    parts = [f"# Render benchmark (`benchmarks/bench_render.py{' --quick' if args.quick else ''}`)", "",
             "Bundled sample `data_samples/tissue` -> `rgbd2scene scene` (default wet-tissue material, scan path, "
             f"{PATH_FRAMES} frames, {mesh_vertices(scene):,}-vertex mesh), Cycles on CPU. Settings: "
             + ", ".join(f"{k}: {v}" for k, v in settings.items()) + ". Times are seconds per stereo frame "
             "(both eyes) as the worker reports them, medians over frames. Method: see the script's docstring."]

    if "quality" in args.sections:
        w, h = quality_size
        print(f"\n1. quality: {w}x{h}, frames {quality_frames} (each after a warm-up frame), reference "
              f"{REFERENCE.label} (seed {REFERENCE_SEED})", flush=True)
        q = quality_sweep(scene, candidates, quality_frames, quality_size, reuse=args.reuse)
        table = quality_table(q)
        pick = q["pick"]
        pick_text = (f"fastest setting reaching it: **{pick['setting'].label}** ({pick['seconds']:.2f} s per stereo "
                     f"frame)" if pick else "no candidate reaches it")
        same = default_note(q["rows"], pick, default)
        misses = [r["setting"].label for r in q["rows"] if r["error"] is None and not reaches(r)]
        summary = (f"Target: **{TARGET_PSNR_DB:.0f} dB and SSIM {TARGET_SSIM}** against the reference; {pick_text}; "
                   f"{same}. Missing it: {'; '.join(misses) or 'none'}. {detail_note(q['rows'])} Reference "
                   f"render: {q['reference_s']:.1f} s per stereo frame.")
        print(table + "\n" + summary, flush=True)
        parts += ["", f"## 1. Quality settings ({w}x{h}, frames {', '.join(map(str, quality_frames))}, both eyes)",
                  "", f"Against a {REFERENCE.label} reference (seed {REFERENCE_SEED}; candidates seed "
                  f"{CANDIDATE_SEED}). Detail: high-pass correlation with the reference relative to "
                  f"{BASELINE.label} (1 = the same fine texture, below 1 = smeared). Seconds: Cycles' own phases "
                  "of the scored frame's render (sync, BVH, trace with denoising, save; render/timing.py), both "
                  "eyes, without the sensor model's development. Rows by time; bold: the pick.",
                  "", table, "", summary]

    if "gt" in args.sections:
        print(f"\n2. ground-truth cost at {default.label}, {SIZE[0]}x{SIZE[1]}, frames 0-{gt_frames - 1}, "
              f"{gt_repeats} alternating run(s) each", flush=True)
        g = gt_cost(scene, default, gt_frames, gt_repeats, SIZE)
        table = gt_table(g, gt_frames, gt_repeats)
        print(table, flush=True)
        parts += ["", f"## 2. Ground-truth cost ({default.label}, {SIZE[0]}x{SIZE[1]})", "", table, "",
                  f"For reference, the issue quotes on this machine a plain Cycles stereo frame of a 300k-vertex "
                  f"mesh at 512x256 and 16 samples: ~{ISSUE_PLAIN_CYCLES_S} s; VisionBlender's add-on: "
                  f"~{ISSUE_VISIONBLENDER_S} s with inexact ground truth."]

    if "motion" in args.sections:
        print(f"\n3. moving scenes at {default.label}, {SIZE[0]}x{SIZE[1]}, frames 0-{motion_frames - 1}, "
              f"{motion_repeats} alternating run(s) each: {', '.join(MOTION_SCENES)}", flush=True)
        rows = []
        for name, flags in MOTION_SCENES.items():
            folder = scene if not flags else WORK / f"scene_{'_'.join(f.strip('-') for f in flags)}"
            if flags:
                build_scene(folder, flags)
            print(f"  {name}", flush=True)
            rows.append((name, flags, gt_cost(folder, default, motion_frames, motion_repeats, SIZE)))
        static = rows[0][2]["all"]["steady"]
        lines = ["| scene | flags | RGB only s / stereo frame | RGB + GT s | GT overhead | vs static (RGB + GT) |",
                 "|---|---|---|---|---|---|"]
        for name, flags, g in rows:
            lines.append(f"| {name} | `{' '.join(flags) or '-'}` | {g['none']['steady']:.2f} "
                         f"| {g['all']['steady']:.2f} | {100 * (g['ratio'] - 1):+.1f} % "
                         f"| {g['all']['steady'] / static:.2f}x |")
        worst = max(g["ratio"] for _, _, g in rows)
        verdict = "within" if worst - 1.0 <= GT_TARGET else "over"
        table = "\n".join(lines) + (f"\n\nGround truth of moving scenes adds occlusion maps (ray casting the scene "
                                    f"model at this and the neighbouring frames) and, for deforming tissue, the "
                                    f"deformed vertices per frame. Worst GT overhead {100 * (worst - 1):+.1f} %: "
                                    f"{verdict} the +{100 * GT_TARGET:.0f} % target.")
        print(table, flush=True)
        parts += ["", f"## 3. Moving scenes ({default.label}, {SIZE[0]}x{SIZE[1]}, frames 0-{motion_frames - 1}, "
                  f"{motion_repeats} alternating run(s) each)", "", table]

    if "memory" in args.sections:
        print(f"\n4. memory: {frames_memory} frames, RGB + all GT at {default.label}, {SIZE[0]}x{SIZE[1]}, "
              f"chunks of {DEFAULT_CHUNK}", flush=True)
        chunks = memory_run(scene, default, frames_memory, DEFAULT_CHUNK, SIZE)
        table = memory_table(chunks)
        print(table, flush=True)
        parts += ["", f"## 4. Memory ({frames_memory} frames, RGB + all GT, {default.label}, {SIZE[0]}x{SIZE[1]}, "
                  f"chunks of {DEFAULT_CHUNK} frames)", "", "Peak: the worker's `ru_maxrss`; RSS: its resident "
                  "memory read from `/proc` at its progress lines (a chunk renders all its RGB frames, then all "
                  "its ground truth).",
                  "", table]

    if "bake" in args.sections:
        bake_frames = QUICK_BAKE_FRAMES if args.quick else BAKE_FRAMES
        procedural = WORK / "scene_procedural"
        build_scene(procedural, ("--tissue-detail", "procedural"))
        w, h = SIZE
        print(f"\n5. baked tissue detail vs procedural: {BAKE_SETTING.label}, {w}x{h}, frames {bake_frames} (each "
              "after a warm-up frame), alternating", flush=True)
        b = bake_compare(scene, procedural, bake_frames, SIZE)
        blend_mb = {name: (folder / "scene.blend").stat().st_size / 2**20
                    for name, folder in (("baked", scene), ("procedural", procedural))}
        table = bake_table(b, BAKE_SETTING, blend_mb)
        print(table, flush=True)
        parts += ["", f"## 5. Baked tissue detail ({BAKE_SETTING.label}, {w}x{h}, frames "
                  f"{', '.join(map(str, bake_frames))}, both eyes)", "",
                  "The default scene bakes the wet-tissue detail into textures when it is built; "
                  "`--tissue-detail procedural` evaluates it per sample. Medians over the frames.", "", table]

    wall = time.perf_counter() - t0
    parts += ["", f"Benchmark wall time {wall:.0f} s."]
    print(f"\nbenchmark wall time {wall:.0f} s", flush=True)
    if out_md:
        write_results(out_md, "\n".join(parts) + "\n")
        print(f"report: {out_md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
