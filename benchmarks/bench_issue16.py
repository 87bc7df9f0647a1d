#!/usr/bin/env python3
"""The figures of issue 16, side by side in one run (Cycles on CPU, the bundled 300k-triangle sample).

Usage: ``python benchmarks/bench_issue16.py [--sections gt gt_only visionblender] [--long-frames N]
[--vb-repeats N] [--vb-other-quality high] [--out MD]``

The scene is ``bench_render.py``'s (``rgbd2scene scene`` on ``data_samples/tissue``, scan path of 100 frames,
512x256 rig, baked tissue detail), built into ``bench_out/render/scene`` unless it is there already.

1. **Ground truth vs RGB only** (``gt``): ``bench_render.gt_cost`` (one worker per run, RGB only and RGB + all
   ground truth alternating) at 256x128 x 4 frames and at 512x256 x ``--long-frames`` frames, at the library's
   default RGB settings. Reported: the ratio of the runs' whole wall times (worker start included) and of the
   steady-state seconds per frame. Target (issue 16): at most 1.05.
2. **Ground truth without Blender** (``gt_only``): ``render_gt_only`` (``render --gt-only``) of frames
   [0, 1) and then [0, 1 + N) of a 512x256 dataset; the difference over N is the cost per stereo frame, the
   first run the fixed cost (reading the scene and its geometry). Target: at most 0.1 s per stereo frame.
3. **Default vs VisionBlender-style** (``visionblender``): 10 stereo frames at 512x256, the library default
   with all ground truth (``render_dataset``, one worker) against a 16-sample, undenoised Cycles render that
   writes the Depth, Normal, Vector and Object Index passes of the same render beside the image, as
   VisionBlender's add-on does (one multilayer 32-bit EXR per eye and frame, a plain ``bpy`` script on the
   same blend: no exact ground truth, no sensor model). Wall times of the whole runs (process start
   included), alternating, and their CPU seconds (this process and its workers: less dependent on other
   load). ``--vb-other-quality`` adds, in each round, the default with another OpenImageDenoise network (a
   before/after row; rounds alternate which of the two goes first). The quality of each setting against the
   256-sample reference is ``bench_render.py``'s quality sweep on the same scene (``benchmarks/results/render.md``).
4. **Memory of one worker** (``memory``): ``--memory-frames`` frames at 64x32 with all ground truth in one
   worker (one chunk), its resident memory at every progress line: whether one process could render far more
   frames than a chunk (the issue's target: flat over 1,000 frames).
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_render as br  # noqa: E402
from results_file import write_results  # noqa: E402

from rgbd2scene.scene.folder import SCENE_BLEND  # noqa: E402
from rgbd2scene.stages.render import render_dataset, render_gt_only  # noqa: E402

SECTIONS = ("gt", "gt_only", "visionblender", "memory")
WORK = ROOT / "bench_out" / "issue16"
GT_TARGET, GT_ONLY_TARGET_S, SPEEDUP_TARGET = 1.05, 0.1, 6.0
VB_FRAMES, VB_SAMPLES = 10, 16

#: A VisionBlender-style render: one Cycles render per frame with the ground-truth passes of that render.
VB_SCRIPT = """
import sys, time
import bpy
blend, out, frames, samples = sys.argv[-4], sys.argv[-3], int(sys.argv[-2]), int(sys.argv[-1])
bpy.ops.wm.open_mainfile(filepath=blend)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples, scene.cycles.use_adaptive_sampling, scene.cycles.use_denoising = samples, False, False
scene.render.use_motion_blur = False
for view in scene.render.views:
    view.use = view.name in ("left", "right")
layer = scene.view_layers[0]
layer.use_pass_z = layer.use_pass_normal = layer.use_pass_vector = layer.use_pass_object_index = True
s = scene.render.image_settings
s.media_type = "MULTI_LAYER_IMAGE"
s.file_format, s.color_depth, s.exr_codec, s.use_exr_interleave = "OPEN_EXR_MULTILAYER", "32", "NONE", True
s.views_format = "INDIVIDUAL"
for frame in range(frames):
    scene.frame_set(frame)
    scene.render.filepath = f"{out}/{frame:06d}"
    bpy.ops.render.render(write_still=True)
"""


def gt_section(scene: Path, long_frames: int) -> tuple[str, list[dict]]:
    default = br.default_setting()
    rows = []
    for size, frames, repeats in (((256, 128), 4, 2), ((512, 256), long_frames, 1)):
        print(f"  gt: {size[0]}x{size[1]} x {frames} frames, {repeats} alternating run(s) each", flush=True)
        g = br.gt_cost(scene, default, frames, repeats, size)
        rows.append({"size": size, "frames": frames, "repeats": repeats, "steady": g["ratio"],
                     "wall": g["wall_ratio"], "none": g["none"], "all": g["all"],
                     "cpu": g["all"]["cpu"] / g["none"]["cpu"]})
    lines = ["| size x frames | runs each | RGB only: wall s (steady s/frame), CPU s | RGB + all GT: wall s (steady "
             "s/frame), CPU s | wall ratio | steady ratio | CPU ratio | target <= 1.05 |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = "yes" if r["wall"] <= GT_TARGET else "no"
        lines.append(f"| {r['size'][0]}x{r['size'][1]} x {r['frames']} | {r['repeats']} | {r['none']['wall']:.1f} "
                     f"({r['none']['steady']:.2f}), {r['none']['cpu']:.1f} | {r['all']['wall']:.1f} "
                     f"({r['all']['steady']:.2f}), {r['all']['cpu']:.1f} | **{r['wall']:.3f}** | {r['steady']:.3f} "
                     f"| {r['cpu']:.3f} | {ok} |")
    return "\n".join(lines), rows


def gt_only_section(scene: Path, frames: int) -> tuple[str, dict]:
    out = WORK / "gt_only"
    times = {}
    for n in (1, 1 + frames):
        if out.exists():
            shutil.rmtree(out)
        t0 = time.perf_counter()
        render_gt_only(scene, out, size=(512, 256), frames=br.PATH_FRAMES, end=n, progress=False)
        times[n] = time.perf_counter() - t0
    per_frame = (times[1 + frames] - times[1]) / frames
    npz = sorted((out / "left" / "gt").glob("*.npz"))
    mb = 2 * sum(p.stat().st_size for p in npz) / len(npz) / 2**20 if npz else float("nan")
    ok = "meets" if per_frame <= GT_ONLY_TARGET_S else "misses"
    text = (f"`render --gt-only` at 512x256, all maps: fixed cost (scene and geometry, frame 0) {times[1]:.2f} s; "
            f"**{per_frame:.3f} s per stereo frame** over {frames} more frames ({ok} the {GT_ONLY_TARGET_S} s "
            f"target); npz files {mb:.1f} MB per stereo frame.")
    return text, {"fixed_s": times[1], "per_frame_s": per_frame, "mb_per_frame": mb}


def cpu_seconds() -> float:
    """CPU seconds used so far by this process and its finished children (the workers): less load-dependent
    than wall time on a shared machine."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def vb_run(scene: Path, out: Path) -> tuple[float, float]:
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(VB_SCRIPT)
    t0, c0 = time.perf_counter(), cpu_seconds()
    proc = subprocess.run([sys.executable, f.name, str(scene / SCENE_BLEND), str(out), str(VB_FRAMES),
                           str(VB_SAMPLES)], capture_output=True, text=True)
    seconds, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    Path(f.name).unlink()
    if proc.returncode != 0 or len(list(out.glob("*.exr"))) != 2 * VB_FRAMES:
        raise RuntimeError(f"VisionBlender-style render failed:\n{proc.stderr[-2000:]}")
    return seconds, cpu


def vb_section(scene: Path, repeats: int, other_quality: str | None = None) -> tuple[str, dict]:
    """The default against the VisionBlender-style render, ``repeats`` rounds; with ``other_quality`` each round
    also renders the default with that OpenImageDenoise network (``--denoise-quality``), between the two (a
    before/after row in the same run)."""
    default = br.default_setting()
    runs: dict[str, list[tuple[float, float]]] = {"default": [], "other": [], "vb": []}

    def ours(name: str, **more) -> None:
        out = WORK / name
        if out.exists():
            shutil.rmtree(out)
        t0, c0 = time.perf_counter(), cpu_seconds()
        render_dataset(scene, out, size=(512, 256), frames=br.PATH_FRAMES, end=VB_FRAMES, gt="all", progress=False,
                       chunk=VB_FRAMES, **more)
        runs[name].append((time.perf_counter() - t0, cpu_seconds() - c0))

    for r in range(repeats):
        order = ("default", "other") if r % 2 == 0 else ("other", "default")
        for name in order:
            if name == "default":
                ours("default")
            elif other_quality:
                ours("other", denoise_quality=other_quality)
        runs["vb"].append(vb_run(scene, WORK / "visionblender"))
        print(f"  run {r + 1}: " + ", ".join(f"{k} {v[-1][0]:.1f} s ({v[-1][1]:.1f} CPU s)" for k, v in runs.items()
                                             if v), flush=True)
    med = {k: (statistics.median(t for t, _ in v), statistics.median(c for _, c in v)) for k, v in runs.items() if v}
    (a, ac), (b, bc) = med["default"], med["vb"]
    ok = "meets" if b / a >= SPEEDUP_TARGET else "misses"
    ok_cpu = "meets" if bc / ac >= SPEEDUP_TARGET else "misses"
    rows = [f"| default: {default.label}, all ground truth (exact, from the scene model) | {a:.1f} | {ac:.1f} "
            f"| {b / a:.2f}x | {bc / ac:.2f}x |"]
    if "other" in med:
        o, oc = med["other"]
        rows.append(f"| the same with the {other_quality} network (`--denoise-quality {other_quality}`) | {o:.1f} "
                    f"| {oc:.1f} | {b / o:.2f}x | {bc / oc:.2f}x |")
    rows.append(f"| VisionBlender-style: {VB_SAMPLES} spp, fixed, no denoiser, passes of the same render | {b:.1f} "
                f"| {bc:.1f} | 1 | 1 |")
    text = (f"| render (10 stereo frames, 512x256) | wall s (median of {repeats}) | CPU s | VisionBlender-style / "
            "this, wall | CPU |\n|---|---|---|---|---|\n" + "\n".join(rows) +
            f"\n\nVisionBlender-style / default = **{b / a:.2f}x** wall ({ok} the {SPEEDUP_TARGET:.0f}x "
            f"target), **{bc / ac:.2f}x** CPU time ({ok_cpu} it).")
    out = {"default_s": a, "visionblender_s": b, "speedup": b / a, "default_cpu_s": ac,
           "visionblender_cpu_s": bc, "cpu_speedup": bc / ac}
    if "other" in med:
        out.update(other_s=med["other"][0], other_cpu_s=med["other"][1])
    return text, out


def _growth_per_1000(series) -> float:
    """MB per 1,000 frames: the slope of a least-squares line through the second half of ``series``."""
    import numpy as np

    half = len(series) // 2
    if len(series) - half < 2:
        return 0.0
    return float(np.polyfit(np.arange(half, len(series)), series[half:], 1)[0]) * 1000


def memory_section(scene: Path, frames: int) -> tuple[str, dict]:
    """One worker over ``frames`` frames (a scene with a path that long: ``--memory-scene``, built with
    ``--frames N`` when missing)."""
    import numpy as np

    if frames > br.PATH_FRAMES:
        scene = WORK / f"scene{frames}"
        if not (scene / SCENE_BLEND).is_file():
            print(f"  building a {frames}-frame scene -> {scene}", flush=True)
            br.build_scene(scene, ("--frames", str(frames)))
    run = br.run_worker(scene, WORK / "memory", br.default_setting(), 0, frames, frames, "all", (64, 32))
    rss = np.array([run.frames[i]["rss"] for i in sorted(run.frames)])
    gt_rss = np.array([run.frames[i].get("gt_rss", np.nan) for i in sorted(run.frames)])
    half = len(rss) // 2
    text = (f"One worker, {frames} frames at 64x32, RGB + all ground truth ({br.default_setting().label}): the "
            f"worker's RSS {rss[0]:.0f} MB after the first frame, {rss[half]:.0f} MB at frame {half}, "
            f"{rss[-1]:.0f} MB at the end, peak {run.peak_rss_mb:.0f} MB, growth over the second half "
            f"**{_growth_per_1000(rss):+.1f} MB per 1,000 frames**; its ground-truth child process "
            f"{gt_rss[0]:.0f} -> {gt_rss[half]:.0f} -> {gt_rss[-1]:.0f} MB, **{_growth_per_1000(gt_rss):+.1f} MB per "
            f"1,000 frames**; {run.wall_s:.0f} s in all.")
    return text, {"rss_first": float(rss[0]), "rss_last": float(rss[-1]),
                  "mb_per_1000_frames": _growth_per_1000(rss), "gt_mb_per_1000_frames": _growth_per_1000(gt_rss),
                  "peak": run.peak_rss_mb}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--long-frames", type=int, default=20, help="frames of the 512x256 GT comparison (issue: 100)")
    ap.add_argument("--gt-only-frames", type=int, default=20)
    ap.add_argument("--vb-repeats", type=int, default=1)
    ap.add_argument("--vb-other-quality", choices=("fast", "balanced", "high"), default=None,
                    help="also render the default with this OpenImageDenoise network in each round (before/after)")
    ap.add_argument("--memory-frames", type=int, default=br.PATH_FRAMES,
                    help="frames of the memory run (more than the benchmark scene's path: a longer path is built)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "issue16.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    scene = br.WORK / "scene"
    if not (scene / SCENE_BLEND).is_file():
        print(f"building the scene -> {scene}", flush=True)
        br.build_scene(scene)
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").is_file() else []
    parts = ["# Issue 16 figures (`benchmarks/bench_issue16.py`)", "",
             f"Machine: {br._machine()}; load average at the start {' '.join(load)}. Scene: "
             f"{br.mesh_vertices(scene):,}-vertex mesh of `data_samples/tissue` (bench_render's scene). Library "
             f"default RGB: {br.default_setting().label}. Method: see the script's docstring."]
    record = {}
    sections = [  # (key, heading, section function, its argument)
        ("gt", "1. Ground truth vs RGB only", gt_section, args.long_frames),
        ("gt_only", "2. Ground truth without Blender (`render --gt-only`, 512x256)", gt_only_section,
         args.gt_only_frames),
        ("visionblender", "3. Default vs VisionBlender-style (10 stereo frames, 512x256)",
         lambda scene, repeats: vb_section(scene, repeats, args.vb_other_quality), args.vb_repeats),
        ("memory", "4. Memory of one worker (64x32)", memory_section, args.memory_frames),
    ]
    for key, heading, section, arg in sections:
        if key not in args.sections:
            continue
        print(heading, flush=True)
        text, record[key] = section(scene, arg)
        print(text, flush=True)
        parts += ["", f"## {heading}", "", text]
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").is_file() else []
    parts += ["", f"Load average at the end {' '.join(load)}; benchmark wall time {time.perf_counter() - t0:.0f} s."]
    if args.out:
        write_results(args.out, "\n".join(parts) + "\n")
        print(f"report: {args.out}\n{json.dumps(record, default=str)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
