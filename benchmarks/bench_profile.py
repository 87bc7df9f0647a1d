#!/usr/bin/env python3
"""Render profile: where a render's time goes, per phase and per frame (issue 16 §1).

Usage: ``python benchmarks/bench_profile.py [--quick] [--sizes WxH ...] [--scenes NAME ...] [--frames N]
[--out MD]``

Scenes are built from the bundled sample like ``bench_render`` does (``rgbd2scene scene`` on
``data_samples/tissue``, default wet-tissue material, scan path of 100 frames): a static scene, breathing
tissue (``--deform breathing``) and an instrument scene (``--instrument``), plus the static scene with its
tissue detail evaluated per sample (``procedural``, ``--tissue-detail procedural``: the cost of a sample
before the bake, side by side). Each (scene, size) renders the
first frames of the path with the library defaults (RGB + all ground truth) in one worker, through the
project's one Blender entry point (a render task run by ``run_task``). The phases come from the worker:

- **start**: process start to the worker's ``ready`` line (Python, ``bpy``, opening the blend, set-up);
- per frame, what Cycles reports (:mod:`render.timing`: its status steps, both eyes) for the RGB render:
  **sync** (scene export and update), **BVH**, **trace** (first to last sample, denoising included),
  **save** (Blender encoding and writing the PNGs); **rgb python**: the rest of the frame's RGB phase
  (frame change, pose checks, developing and writing the images; pipelined: frame i renders while frame
  i-1 is developed, so a frame's share can be negative, the sum over the frames is not);
- **denoising**: Cycles reports no step of its own, so every size also renders the static scene with
  ``--denoise none`` (same frames, alternating with the default run): denoising = trace with the default
  denoiser - trace without, per frame, taken as the same for every scene of that size (its cost depends on
  the pixel count, not on the scene); **path tracing** = trace - denoising;
- **gt render**: the data render of the ground truth (Cycles' sync, BVH, trace and save of the EXRs), zero
  with the default ``--gt-source model``; **gt python**: with the model's ground truth (computed in a
  low-priority child process beside the render), the wait its maps added after the last image; with
  ``--gt-source blender``, the frame's share of the rest of the ground-truth phase (reading the passes, the
  maps, npz writes; pipelined like the RGB phase);
- **exit**: the task's wall time minus all of the above (the end of the chunk and the process exit).

Shares are of the task's wall time. The machine is shared: compare rows of one run, not runs.
``--quick``: 256x128, 2 frames, the static scene only (report to ``bench_out/profile/profile.md``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_render import PATH_FRAMES, SAMPLE, _machine, build_scene, mesh_vertices  # noqa: E402
from results_file import write_results  # noqa: E402

from rgbd2scene.stages.blender import run_task  # noqa: E402
from rgbd2scene.stages.render import RenderOptions, load_scene, parse_size, render_model, render_task  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

WORK = ROOT / "bench_out" / "profile"
#: ``procedural``: the static scene with its tissue detail evaluated per sample (not baked): the "before" of
#: the bake, side by side with ``static``.
SCENES = {"static": (), "procedural": ("--tissue-detail", "procedural"), "breathing": ("--deform", "breathing"),
          "instrument": ("--instrument",)}
SIZES = ((256, 128), (512, 256), (1280, 1024))
#: Frames per run (the first one builds the BVH and loads the kernels); fewer at the largest size.
FRAMES = {(256, 128): 3, (512, 256): 3, (1280, 1024): 2}
ROWS = ("start", "sync", "BVH", "path tracing", "denoising", "save", "rgb python", "gt render", "gt python", "exit")


@dataclass
class Profile:
    """Seconds per phase of one worker run (``phases``: summed over its frames) and its wall time."""

    wall: float
    frames: int
    phases: dict[str, float] = field(default_factory=dict)
    per_frame: list[dict[str, float]] = field(default_factory=list)


def run_profiled(scene: Path, out: Path, size: tuple[int, int], frames: int, denoise: str | None = None) -> Profile:
    """Render frames [0, ``frames``) of ``scene`` at ``size`` with the defaults (``denoise`` overridden if
    given) in one fresh worker into a fresh ``out``; the phases its progress lines report."""
    if out.exists():
        shutil.rmtree(out)
    options = RenderOptions(size=size, **({"denoise": denoise} if denoise else {})).validated()
    model = render_model(load_scene(scene)[2], options)
    ready, done = [0.0], {}

    def on_event(event) -> None:  # a frame's RGB phases come on its "rgb" line, the rest on its "done" line
        if event.kind == "ready":
            ready[0] = event.stats["start"]
        elif event.kind in ("rgb", "done"):
            done.setdefault(event.frame, {}).update(event.stats)

    result = run_task(render_task(scene, out, model, options, PATH_FRAMES, 0, frames), on_event)
    per_frame = []
    for i in sorted(done):
        s = done[i]
        rgb_cycles = sum(s.get(f"rgb_{p}", 0.0) for p in ("sync", "bvh", "trace", "save"))
        gt_cycles = sum(s.get(f"gt_{p}", 0.0) for p in ("sync", "bvh", "trace", "save"))
        per_frame.append({"sync": s.get("rgb_sync", 0.0), "BVH": s.get("rgb_bvh", 0.0),
                          "trace": s.get("rgb_trace", 0.0), "save": s.get("rgb_save", 0.0),
                          "rgb python": s["rgb"] - rgb_cycles, "gt render": gt_cycles,
                          "gt python": s["gt"] - gt_cycles, "done": s["done"]})
    phases = {k: sum(f[k] for f in per_frame) for k in per_frame[0]}
    phases["start"] = ready[0]
    return Profile(result.seconds, len(per_frame), phases, per_frame)


def split(p: Profile, denoise_per_frame: float) -> dict[str, float]:
    """The rows of :data:`ROWS` for one run: trace split into path tracing and denoising, exit the rest."""
    rows = {k: p.phases[k] for k in ("start", "sync", "BVH", "save", "rgb python", "gt render", "gt python")}
    rows["denoising"] = min(denoise_per_frame * p.frames, p.phases["trace"])
    rows["path tracing"] = p.phases["trace"] - rows["denoising"]
    rows["exit"] = p.wall - p.phases["start"] - p.phases["done"]
    return rows


def table(results: list[tuple[str, tuple[int, int], Profile, dict[str, float]]]) -> str:
    """Seconds (per frame where the phase is per frame) and share of the wall time, one column per run."""
    heads = [f"{name} {w}x{h} ({p.frames} fr)" for name, (w, h), p, _ in results]
    lines = ["| phase | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for row in ROWS:
        cells = []
        for _, _, p, rows in results:
            total = rows[row]
            per = "" if row in ("start", "exit") else f" ({total / p.frames:.2f}/fr)"
            cells.append(f"{total:.2f} s{per}, {100 * total / p.wall:.0f} %")
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    lines.append("| **wall** | " + " | ".join(f"**{p.wall:.1f} s** ({p.wall / p.frames:.2f}/fr)"
                                             for _, _, p, _ in results) + " |")
    return "\n".join(lines)


def frame_table(results) -> str:
    """Per frame: the seconds of the frame (RGB + its ground-truth share) and its Cycles phases."""
    lines = ["| run | frame | frame s | sync | BVH | trace (+denoise) | save | rgb python | gt render | gt python |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, (w, h), p, _ in results:
        for i, f in enumerate(p.per_frame):
            lines.append(f"| {name} {w}x{h} | {i} | {f['done']:.2f} | {f['sync']:.2f} | {f['BVH']:.2f} | "
                         f"{f['trace']:.2f} | {f['save']:.3f} | {f['rgb python']:.2f} | {f['gt render']:.2f} | "
                         f"{f['gt python']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="256x128, 2 frames, the static scene")
    ap.add_argument("--sizes", nargs="+", type=parse_size, default=None, help="image sizes WxH")
    ap.add_argument("--scenes", nargs="+", choices=list(SCENES), default=None, help="scenes to profile")
    ap.add_argument("--frames", type=int, default=None, help="frames per run (default per size: 3, 3, 2)")
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/profile.md, quick: "
                    "bench_out/profile/profile.md; '' to skip)")
    args = ap.parse_args(argv)
    sizes = args.sizes or ([(256, 128)] if args.quick else list(SIZES))
    scenes = args.scenes or (["static"] if args.quick else list(SCENES))
    out_md = args.out if args.out is not None else str(
        WORK / "profile.md" if args.quick else ROOT / "benchmarks" / "results" / "profile.md")

    t0 = time.perf_counter()
    WORK.mkdir(parents=True, exist_ok=True)
    folders = {}
    for name in dict.fromkeys(["static", *scenes]):
        folders[name] = WORK / f"scene_{name}"
        print(f"building the {name} scene -> {folders[name]}", flush=True)
        build_scene(folders[name], SCENES[name])
    versions = software_versions()
    defaults = RenderOptions()
    settings = {"machine": _machine(), "python": versions["python"], "bpy": versions["bpy"], "device": "CPU",
                "threads": "all cores", "samples": defaults.samples, "adaptive": defaults.adaptive,
                "denoise": defaults.denoise, "ground truth": defaults.gt}
    print("settings: " + ", ".join(f"{k} {v}" for k, v in settings.items()), flush=True)

    results = []
    denoise_rows = []
    for size in sizes:
        frames = args.frames or (2 if args.quick else FRAMES.get(size, 2))
        # the denoiser's share: the static scene without it, alternating with the default runs
        plain = run_profiled(folders["static"], WORK / "ds_plain", size, frames, denoise="none")
        runs = {name: run_profiled(folders[name], WORK / f"ds_{name}", size, frames) for name in scenes}
        base = runs.get("static") or run_profiled(folders["static"], WORK / "ds_static", size, frames)
        per_frame = max(0.0, (base.phases["trace"] - plain.phases["trace"]) / frames)
        denoise_rows.append((size, frames, plain.phases["trace"] / frames, base.phases["trace"] / frames, per_frame))
        for name, p in runs.items():
            results.append((name, size, p, split(p, per_frame)))
            print(f"  {name} {size[0]}x{size[1]}: {p.wall:.1f} s, {frames} frames", flush=True)
    report = table(results)
    frames_report = frame_table(results)
    dn = ["| size | frames | trace s/frame without denoiser | with the default (oidn) | denoising s/frame |",
          "|---|---|---|---|---|"] + [f"| {w}x{h} | {n} | {a:.2f} | {b:.2f} | {d:.2f} |"
                                      for (w, h), n, a, b, d in denoise_rows]
    print("\n" + report + "\n\n" + "\n".join(dn) + "\n\n" + frames_report, flush=True)

    wall = time.perf_counter() - t0
    parts = [f"# Render profile (`benchmarks/bench_profile.py{' --quick' if args.quick else ''}`)", "",
             f"Bundled sample `data_samples/tissue` -> `rgbd2scene scene` ({mesh_vertices(folders['static']):,}-vertex "
             f"mesh, {PATH_FRAMES}-frame scan path; {SAMPLE.relative_to(ROOT)}). Settings: "
             + ", ".join(f"{k}: {v}" for k, v in settings.items()) + ". Each column is one worker rendering the "
             "first frames of the path (RGB + all ground truth, both eyes). Cells: seconds summed over the "
             "frames (per frame), share of the run's wall time. Phases: see the script's docstring.", "",
             "## Phases", "", report, "", "## Denoising (static scene, the same frames with `--denoise none`)", "",
             "\n".join(dn), "", "## Per frame", "", frames_report, "", f"Benchmark wall time {wall:.0f} s."]
    print(f"\nbenchmark wall time {wall:.0f} s", flush=True)
    if out_md:
        write_results(out_md, "\n".join(parts) + "\n")
        print(f"report: {out_md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
