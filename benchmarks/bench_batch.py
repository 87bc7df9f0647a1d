#!/usr/bin/env python3
"""Batch benchmark: frames per hour of ``rgbd2scene dataset`` on a local pool and a local Dask cluster, against
the same work done by plain stage calls, and the memory of a long sequence.

Usage: ``python benchmarks/bench_batch.py [--quick] [--parallel] [--repeats N] [--out MD]``

1. **Throughput** (``2 captures x 2 sequences x 6 frames`` at 256x128, render defaults: 1 spp + OIDN, all
   ground truth): the bundled sample ``data_samples/tissue`` and the TUM office frame from
   ``../shared/rgbd_samples`` (the bundled sample again, under another name, when ../shared is absent), at full
   resolution (640x480 captures, 307k-vertex meshes). Every build starts from an empty ROOT and does everything:
   reconstruct each capture, build each sequence's scene (Blender), render the frames, checksum, contact sheet.

   - *plain calls*: the stage functions the ``mesh``, ``scene`` and ``render`` commands run, called one after
     the other in this process for the same plan (a shell loop around the commands, less their start-up);
   - *local pool*: ``build_dataset`` with the default engine (``--jobs 1``);
   - *local Dask*: ``build_dataset`` with ``--workers 1`` (a ``LocalCluster`` started and stopped per build,
     counted in its time).

   One unit at a time in each, so the difference is the scheduler's overhead. Builds alternate (plain, pool,
   Dask, then the reverse) and the medians over ``--repeats`` rounds are compared; ground-truth checksums must
   agree between all builds. With ``--parallel``, one more build each with 2 units at once (``--jobs 2``,
   ``--workers 2``): the machine has 2 cores, and each Blender worker already uses both.
2. **Memory** (one sequence of 60 frames in chunks of 25, local Dask with one worker, submitted through
   ``--scheduler`` to a cluster this script starts so it can ask the worker afterwards): each chunk's Blender
   worker peak RSS (``ru_maxrss`` from ``wait4``) and the Dask worker process's own peak RSS; then the same
   sequence rendered in one chunk of 60 for comparison.

``--quick`` (about 3 minutes): one capture, 2 sequences of 3 frames, one round, 10 memory frames in chunks of 4;
report in ``bench_out/batch/batch.md``. The full run takes about 10 minutes on an idle 2-core machine (``--parallel``
adds about 3) and writes ``benchmarks/results/batch.md``. The load average (other processes) is printed with the
settings: builds alternate so that load changes hit every engine alike, but they do add noise.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import statistics
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rgbd2scene.batch.config import load_config  # noqa: E402
from rgbd2scene.batch.manifest import gt_checksum, read_manifest  # noqa: E402
from rgbd2scene.batch.plan import make_plan  # noqa: E402
from rgbd2scene.batch.run import BuildOptions, build_dataset  # noqa: E402
from rgbd2scene.batch.tasks import build_mesh  # noqa: E402
from rgbd2scene.pictures.contact_sheet import write_frame_sheet  # noqa: E402
from rgbd2scene.reconstruct import pipeline  # noqa: E402, F401  (imported before timing, as the driver has it)
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from rgbd2scene.stages.scene import build_scene_folder, load_mesh_folder  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

WORK = ROOT / "bench_out" / "batch"
SAMPLE = ROOT / "data_samples" / "tissue"
TUM = ROOT.parent / "shared" / "rgbd_samples" / "tum_office_frame_open3d"
SIZE = "256x128"


def captures(count: int) -> list[dict]:
    tissue = {"name": "tissue", "rgb": str(SAMPLE / "rgb.png"), "depth": str(SAMPLE / "depth.png"),
              "camera": str(SAMPLE / "camera.json"), "split": "train"}
    if TUM.is_dir():
        second = {"name": "tum_office", "rgb": str(TUM / "TUM_color.png"), "depth": str(TUM / "TUM_depth.png"),
                  "preset": "tum_fr1", "split": "test"}
    else:
        second = {**tissue, "name": "tissue_again"}
    return [tissue, second][:count]


def write_config(path: Path, n_captures: int, per_capture: int, frames: int, chunk: int | None = None) -> Path:
    render = {"size": SIZE} | ({"chunk": chunk} if chunk else {})
    config = {"seed": 1, "captures": captures(n_captures),
              "sequences": {"per_capture": per_capture, "frames": frames, "paths": ["scan", "orbit"]},
              "render": render, "variations": {"light_power_w": [0.03, 0.08]}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def plain_build(config_path: Path, root: Path) -> tuple[float, dict[str, str]]:
    """The same plan done by the stage functions, one after the other (no scheduler)."""
    t0 = time.perf_counter()
    plan = make_plan(load_config(config_path))
    for capture in plan.config.captures:
        outcome = build_mesh(capture, str(root / "meshes" / capture.name))
        if not outcome.ok:
            raise RuntimeError(outcome.log)
    checksums = {}
    for seq in plan.sequences:
        scene_dir = root / "scenes" / seq.name
        scene_dir.mkdir(parents=True)
        mesh, record = load_mesh_folder(root / "meshes" / seq.capture.name, scene_dir)
        build_scene_folder(scene_dir, mesh, record, seq.scene)
        out = root / seq.name
        render_dataset(scene_dir, out, seq.render_options(plan.config.render), progress=False)
        write_frame_sheet(out, (seq.frames - 1) // 2, out / "contact_sheet.png")
        checksums[seq.name] = gt_checksum(out, seq.frames)
    return time.perf_counter() - t0, checksums


def batch_build(config_path: Path, root: Path, **options) -> tuple[float, dict[str, str], object]:
    t0 = time.perf_counter()
    summary = build_dataset(config_path, root, BuildOptions(progress=False, **options))
    seconds = time.perf_counter() - t0
    if summary.failed:
        raise RuntimeError(f"{summary.failed[0].sequence}: {summary.failed[0].error}")
    return seconds, {r.sequence: r.gt_sha256 for r in read_manifest(root)}, summary


MODES = {
    "plain calls": lambda cfg, root: plain_build(cfg, root),
    "local pool (--jobs 1)": lambda cfg, root: batch_build(cfg, root, jobs=1)[:2],
    "local Dask (--workers 1)": lambda cfg, root: batch_build(cfg, root, workers=1)[:2],
}
PARALLEL = {
    "local pool (--jobs 2)": lambda cfg, root: batch_build(cfg, root, jobs=2)[:2],
    "local Dask (--workers 2)": lambda cfg, root: batch_build(cfg, root, workers=2)[:2],
}


def timed(name: str, fn, config_path: Path, frames: int, results: dict, checksums: dict) -> None:
    root = WORK / "roots" / name.split(" ")[0]
    shutil.rmtree(root, ignore_errors=True)
    seconds, sums = fn(config_path, root)
    shutil.rmtree(root, ignore_errors=True)
    results.setdefault(name, []).append(seconds)
    checksums[name] = sums
    print(f"  {name:26s} {seconds:7.1f} s  {3600 * frames / seconds:7.0f} frames/h", flush=True)


def throughput(args) -> list[str]:
    n_captures, per_capture, frames = (1, 2, 3) if args.quick else (2, 2, 6)
    config_path = write_config(WORK / "throughput.yaml", n_captures, per_capture, frames)
    total = n_captures * per_capture * frames
    print(f"throughput: {n_captures} captures x {per_capture} sequences x {frames} frames at {SIZE} "
          f"({total} stereo frames per build), {args.repeats} rounds", flush=True)
    results: dict[str, list[float]] = {}
    checksums: dict[str, dict] = {}
    order = list(MODES)
    for r in range(args.repeats):
        for name in (order if r % 2 == 0 else order[::-1]):
            timed(name, MODES[name], config_path, total, results, checksums)
    if args.parallel:
        for name, fn in PARALLEL.items():
            timed(name, fn, config_path, total, results, checksums)
    same = len({tuple(sorted(c.items())) for c in checksums.values()}) == 1
    base = statistics.median(results["plain calls"])
    lines = [f"## 1. Throughput: {n_captures} capture(s) x {per_capture} sequences x {frames} frames at {SIZE}", "",
             f"{total} stereo frames per build, everything from an empty ROOT (meshes, scenes, frames, checksums, "
             "contact sheets). Seconds per build: each run, then the median; frames per hour of the median.", "",
             "| engine | units at once | runs (s) | median s | frames / hour | vs plain calls |",
             "|---|---|---|---|---|---|"]
    losses = []
    for name, times in results.items():
        med = statistics.median(times)
        ratio = med / base - 1
        units = "2" if "2)" in name else "1"
        lines.append(f"| {name} | {units} | {', '.join(f'{t:.1f}' for t in times)} | {med:.1f} | "
                     f"{3600 * total / med:.0f} | {'' if name == 'plain calls' else f'{100 * ratio:+.1f} %'} |")
        if name != "plain calls" and units == "1" and ratio > 0:
            losses.append(f"{name} is {100 * ratio:.1f} % slower than plain calls")
    overheads = {name: statistics.median(t) / base - 1 for name, t in results.items() if name in MODES
                 and name != "plain calls"}
    lines += ["", "Scheduler overhead (one unit at a time, median vs plain calls): "
              + ", ".join(f"{k} {100 * v:+.1f} %" for k, v in overheads.items())
              + f" (target: under 5 %). Ground-truth checksums {'identical' if same else 'DIFFER'} across all builds."]
    if losses:
        lines += ["", "Where we lose: " + "; ".join(losses) + "."]
    if not same:
        raise SystemExit("ground truth differs between builds: " + str(checksums))
    return lines


def memory(args) -> list[str]:
    from distributed import Client, LocalCluster

    frames, chunk = (10, 4) if args.quick else (60, 25)
    print(f"memory: one sequence of {frames} frames in chunks of {chunk}", flush=True)
    rows = []
    for size in (chunk, frames):
        config_path = write_config(WORK / f"memory_{size}.yaml", 1, 1, frames, chunk=size)
        root = WORK / "roots" / f"memory_{size}"
        shutil.rmtree(root, ignore_errors=True)
        with LocalCluster(n_workers=1, threads_per_worker=1, memory_limit=0, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            seconds, _, summary = batch_build(config_path, root, scheduler=cluster.scheduler_address)
            worker_peak = list(client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024).values())
        shutil.rmtree(root, ignore_errors=True)
        peaks = summary.chunk_peak_rss_mb
        rows.append(f"| {size} | {len(peaks)} | {', '.join(f'{p:.0f}' for p in peaks)} | {max(peaks):.0f} | "
                    f"{worker_peak[0]:.0f} | {seconds:.0f} |")
        print(f"  chunks of {size}: Blender peaks {[round(p) for p in peaks]} MB, Dask worker {worker_peak[0]:.0f} MB",
              flush=True)
    return [f"## 2. Memory: one sequence of {frames} frames ({SIZE}, bundled sample, render defaults)", "",
            "Peak resident memory (MB) of each chunk's Blender worker process, and of the Dask worker process that "
            "ran the units (it starts the Blender workers; the Blender processes are not part of it).", "",
            "| frames per chunk | chunks | Blender worker peak per chunk (MB) | max | Dask worker peak (MB) | "
            "build s |", "|---|---|---|---|---|---|", *rows]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 3 minutes: smaller builds, one round")
    ap.add_argument("--parallel", action="store_true", help="also builds with 2 units at once (--jobs 2, --workers 2)")
    ap.add_argument("--repeats", type=int, default=None, help="rounds of the three engines (default 2, quick 1)")
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/batch.md, quick: "
                    "bench_out/batch/batch.md; '' to skip)")
    args = ap.parse_args()
    args.repeats = args.repeats or (1 if args.quick else 2)
    out = args.out if args.out is not None else str(
        WORK / "batch.md" if args.quick else ROOT / "benchmarks" / "results" / "batch.md")
    versions = software_versions()
    settings = {"machine": f"{platform.machine()}, {os.cpu_count()} cores",
                "python": platform.python_version(), "bpy": versions.get("bpy"),
                "dask": __import__("dask").__version__, "render": f"{SIZE}, 1 spp + OIDN, all ground truth",
                "second capture": "TUM office frame" if TUM.is_dir() else "bundled sample again",
                "quick": args.quick, "load average at start": f"{os.getloadavg()[0]:.1f}"}
    print("settings: " + ", ".join(f"{k}: {v}" for k, v in settings.items()), flush=True)
    t0 = time.perf_counter()
    parts = [f"# Batch benchmark (`benchmarks/bench_batch.py{' --quick' if args.quick else ''}`)", "",
             "Settings: " + ", ".join(f"{k}: {v}" for k, v in settings.items()) + ". Method: see the script's "
             "docstring.", ""]
    parts += throughput(args) + [""] + memory(args)
    parts += ["", f"Benchmark wall time: {time.perf_counter() - t0:.0f} s; load average at the end "
              f"{os.getloadavg()[0]:.1f} (1 minute; other processes on this 2-core machine)."]
    text = "\n".join(parts) + "\n"
    print("\n" + text)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(text)
        print(f"report: {out}")


if __name__ == "__main__":
    main()
