#!/usr/bin/env python3
"""Batch benchmark: frames per hour of ``rgbd2scene dataset`` on a local pool and a local Dask cluster, against
the same work done by plain stage calls, and the memory of a long sequence.

Usage: ``python benchmarks/bench_batch.py [--quick] [--parallel] [--repeats N] [--sections ...] [--out MD]``

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

   One unit at a time in each. Builds alternate (plain, pool, Dask, then the reverse) and the medians over
   ``--repeats`` rounds are compared; ground-truth checksums must agree between all builds. The scheduler's
   overhead is measured as the time *outside the units* (wall time minus the summed durations of the units, each
   timed where it ran), compared with the same gap of the plain calls: other processes on the machine slow the
   units down (wall times of identical builds varied by a third here) much more than they move that gap.
   With ``--parallel``, one more build each with 2 units at once (``--jobs 2``, ``--workers 2``): the machine
   has 2 cores, and each Blender worker already uses both.
2. **Memory** (one sequence of 60 frames in chunks of 25, on the local cluster ``--workers 1`` starts, but
   submitted through ``--scheduler`` so that this script can ask the worker afterwards): each chunk's Blender
   worker peak RSS (``ru_maxrss`` from ``wait4``) and the Dask worker process's own peak RSS; then the same
   sequence rendered in one chunk of 60 for comparison.
3. **Reused workers** (``4 sequences x 2 chunks of 2 frames`` at 256x128 of the bundled sample, render defaults):
   whole builds (``--jobs 1``) with every Blender task in a fresh process (``reusing_workers`` patched to do
   nothing) and with reused workers, alternating; then the 8 chunks alone, every sequence's first chunk then every
   second one (so each chunk follows another scene), each in a fresh Blender process (``run_task``, as batch builds
   did before) and all in one long-lived worker (``reusing_workers``, as batch builds do now), alternating over
   ``--repeats`` rounds. Wall and CPU seconds (all processes: this one and its Blender workers), the ratio of the
   medians and every chunk's peak memory; every output file must be byte-identical between the two. Then one worker
   renders ``--reuse-tasks`` chunks in turn (the four scenes' first chunks over and over): its peak memory during
   each task and its resident memory after each, which must not grow.

``--quick`` (about 3 minutes): one capture, 2 sequences of 3 frames, one round, 10 memory frames in chunks of 4;
report in ``bench_out/batch/batch.md``. The full run takes about 10 minutes on an idle 2-core machine (``--parallel``
adds about 3) and writes ``benchmarks/results/batch.md``. The load average (other processes) is printed with the
settings: builds alternate so that load changes hit every engine alike, but they do add noise.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import resource
import shutil
import statistics
import sys
import time
import unittest.mock
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.batch.config import load_config  # noqa: E402
from rgbd2scene.batch.engine import DaskEngine  # noqa: E402
from rgbd2scene.batch.manifest import gt_checksum, read_manifest  # noqa: E402
from rgbd2scene.batch.plan import make_plan  # noqa: E402
from rgbd2scene.batch.run import BuildOptions, build_dataset  # noqa: E402
from rgbd2scene.batch.tasks import build_mesh  # noqa: E402
from rgbd2scene.pictures.contact_sheet import write_frame_sheet  # noqa: E402
from rgbd2scene.reconstruct import pipeline  # noqa: E402, F401  (imported before timing, as the driver has it)
from rgbd2scene.rendering import RenderOptions  # noqa: E402
from rgbd2scene.stages import blender  # noqa: E402
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


def plain_build(config_path: Path, root: Path) -> tuple[float, float, dict[str, str]]:
    """The same plan done by the stage functions, one after the other (no scheduler): (wall seconds, seconds
    inside the stage calls that are units in a batch build, ground-truth checksums)."""
    t0 = time.perf_counter()
    units = 0.0
    plan = make_plan(load_config(config_path))
    for capture in plan.config.captures:
        outcome = build_mesh(capture, str(root / "meshes" / capture.name))
        if not outcome.ok:
            raise RuntimeError(outcome.log)
        units += outcome.seconds
    checksums = {}
    for seq in plan.sequences:
        scene_dir = root / "scenes" / seq.name
        scene_dir.mkdir(parents=True)
        t1 = time.perf_counter()
        mesh, record = load_mesh_folder(root / "meshes" / seq.capture.name, scene_dir)
        build_scene_folder(scene_dir, mesh, record, seq.scene)
        out = root / seq.name
        render_dataset(scene_dir, out, seq.render_options(plan.config.render), progress=False)
        units += time.perf_counter() - t1
        write_frame_sheet(out, (seq.frames - 1) // 2, out / "contact_sheet.png")
        checksums[seq.name] = gt_checksum(out, seq.frames)
    return time.perf_counter() - t0, units, checksums


def batch_build(config_path: Path, root: Path, **options):
    """(wall seconds, summed unit seconds, checksums, the BuildSummary) of ``build_dataset``."""
    t0 = time.perf_counter()
    summary = build_dataset(config_path, root, BuildOptions(progress=False, **options))
    seconds = time.perf_counter() - t0
    if summary.failed:
        raise RuntimeError(f"{summary.failed[0].sequence}: {summary.failed[0].error}")
    return seconds, summary.unit_seconds, {r.sequence: r.gt_sha256 for r in read_manifest(root)}, summary


MODES = {
    "plain calls": lambda cfg, root: plain_build(cfg, root),
    "local pool (--jobs 1)": lambda cfg, root: batch_build(cfg, root, jobs=1)[:3],
    "local Dask (--workers 1)": lambda cfg, root: batch_build(cfg, root, workers=1)[:3],
}
PARALLEL = {
    "local pool (--jobs 2)": lambda cfg, root: batch_build(cfg, root, jobs=2)[:3],
    "local Dask (--workers 2)": lambda cfg, root: batch_build(cfg, root, workers=2)[:3],
}


def timed(name: str, fn, config_path: Path, frames: int, results: dict, checksums: dict) -> None:
    root = WORK / "roots" / name.split(" ")[0]
    shutil.rmtree(root, ignore_errors=True)
    seconds, units, sums = fn(config_path, root)
    shutil.rmtree(root, ignore_errors=True)
    results.setdefault(name, []).append((seconds, seconds - units))
    checksums[name] = sums
    print(f"  {name:26s} {seconds:7.1f} s  {3600 * frames / seconds:7.0f} frames/h, {seconds - units:5.1f} s outside "
          "the units", flush=True)


def throughput(args) -> list[str]:
    n_captures, per_capture, frames = (1, 2, 3) if args.quick else (2, 2, 6)
    config_path = write_config(WORK / "throughput.yaml", n_captures, per_capture, frames)
    total = n_captures * per_capture * frames
    print(f"throughput: {n_captures} captures x {per_capture} sequences x {frames} frames at {SIZE} "
          f"({total} stereo frames per build), {args.repeats} rounds", flush=True)
    results: dict[str, list[tuple[float, float]]] = {}
    checksums: dict[str, dict] = {}
    order = list(MODES)
    for r in range(args.repeats):
        for name in (order if r % 2 == 0 else order[::-1]):
            timed(name, MODES[name], config_path, total, results, checksums)
    if args.parallel:
        for name, fn in PARALLEL.items():
            timed(name, fn, config_path, total, results, checksums)
    same = len({tuple(sorted(c.items())) for c in checksums.values()}) == 1
    base = statistics.median(t for t, _ in results["plain calls"])
    base_gap = statistics.median(g for _, g in results["plain calls"])
    lines = [f"## 1. Throughput: {n_captures} capture(s) x {per_capture} sequences x {frames} frames at {SIZE}", "",
             f"{total} stereo frames per build, everything from an empty ROOT (meshes, scenes, frames, checksums, "
             "contact sheets). Wall seconds per build: each run, then the median; frames per hour of the median. "
             "*Outside the units*: wall time minus the summed time of the units (mesh, scene, render chunks: "
             "for plain calls the same stage calls), i.e. planning, checksums, contact sheets, and for the "
             "engines the scheduling, polling and cluster start/stop; it is the scheduler's cost, and less "
             "affected by other load than the wall time, which the units absorb.", "",
             "| engine | units at once | runs (s) | median s | frames / hour | wall vs plain calls "
             "| outside the units, median s | scheduler overhead (% of plain wall) |",
             "|---|---|---|---|---|---|---|---|"]
    losses = []
    for name, runs in results.items():
        med = statistics.median(t for t, _ in runs)
        gap = statistics.median(g for _, g in runs)
        parallel = "2)" in name
        ratio, overhead = med / base - 1, (gap - base_gap) / base
        plain = name == "plain calls"
        lines.append(f"| {name} | {2 if parallel else 1} | {', '.join(f'{t:.1f}' for t, _ in runs)} | {med:.1f} | "
                     f"{3600 * total / med:.0f} | {'' if plain else f'{100 * ratio:+.1f} %'} | "
                     f"{'-' if parallel else f'{gap:.1f}'} | "
                     f"{'' if plain or parallel else f'{100 * overhead:+.1f} %'} |")
        if not plain and ratio > 0:
            losses.append(f"{name}: wall time {100 * ratio:.1f} % above plain calls")
        if not plain and not parallel and overhead > 0:
            losses.append(f"{name}: {gap - base_gap:.1f} s more outside the units ({100 * overhead:.1f} %)")
    lines += ["", f"Target: scheduler overhead under 5 %. Ground-truth checksums {'identical' if same else 'DIFFER'} "
              "across all builds."]
    if losses:
        lines += ["", "Where we lose: " + "; ".join(losses) + "."]
    if not same:
        raise SystemExit("ground truth differs between builds: " + str(checksums))
    return lines


def memory(args) -> list[str]:
    frames, chunk = (10, 4) if args.quick else (60, 25)
    print(f"memory: one sequence of {frames} frames in chunks of {chunk}", flush=True)
    rows = []
    for size in (chunk, frames):
        config_path = write_config(WORK / f"memory_{size}.yaml", 1, 1, frames, chunk=size)
        root = WORK / "roots" / f"memory_{size}"
        shutil.rmtree(root, ignore_errors=True)
        engine = DaskEngine(workers=1)  # the local cluster --workers 1 starts, submitted to through --scheduler
        try:
            seconds, _, _, summary = batch_build(config_path, root, scheduler=engine.cluster.scheduler_address)
            worker_peak = list(engine.client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                                 / 1024).values())
        finally:
            engine.close()
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


def _dataset_bytes(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.suffix in (".png", ".npz")}


def _vm_rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    return next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")) / 1024.0


def _cpu_s() -> float:
    """CPU seconds of this process and of its children waited for."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _render_chunks(scenes: list[Path], out: Path, reuse: bool) -> tuple[float, float, list[float]]:
    """Render every chunk of ``scenes`` into ``out``: (wall s, CPU s, each chunk's peak MB)."""
    from rgbd2scene.stages.render import prepare_render

    shutil.rmtree(out, ignore_errors=True)
    options = RenderOptions(size=tuple(int(v) for v in SIZE.split("x")), chunk=2)
    jobs = [prepare_render(scene, out / scene.name, options) for scene in scenes]
    t0, c0 = time.perf_counter(), _cpu_s()
    peaks = []
    with blender.reusing_workers() if reuse else contextlib.nullcontext():
        for chunk in range(2):
            for job in jobs:
                peaks.append(blender.run_task(job.task(job.chunks()[chunk])).peak_rss_mb)
    blender.close_workers()  # waited for: its CPU time counts
    return time.perf_counter() - t0, _cpu_s() - c0, peaks


def _whole_build(config_path: Path, root: Path, reuse: bool) -> tuple[float, float, dict]:
    """(wall s, CPU s, each sequence's ground-truth and image checksums) of a build from an empty ROOT, its units
    in reused workers or (``reuse`` False: ``reusing_workers`` made a no-op) each in a fresh Blender process."""
    shutil.rmtree(root, ignore_errors=True)
    fresh = unittest.mock.patch.object(blender, "reusing_workers", contextlib.nullcontext)
    with contextlib.nullcontext() if reuse else fresh:
        t0, c0 = time.perf_counter(), _cpu_s()
        batch_build(config_path, root)
        wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    return wall, cpu, {r.sequence: (r.gt_sha256, r.rgb_sha256) for r in read_manifest(root)}


def _build_table(runs: dict[str, list[tuple[float, float]]], base: str) -> list[str]:
    """Markdown rows of ``runs`` (name -> (wall, CPU) per run): the runs, medians and ratios to ``base``."""
    base_wall = statistics.median(w for w, _ in runs[base])
    base_cpu = statistics.median(c for _, c in runs[base])
    lines = ["| workers | runs: wall s | runs: CPU s | median wall s | median CPU s | wall ratio | CPU ratio |",
             "|---|---|---|---|---|---|---|"]
    for name, values in runs.items():
        wall = statistics.median(w for w, _ in values)
        cpu = statistics.median(c for _, c in values)
        lines.append(f"| {name} | {', '.join(f'{w:.1f}' for w, _ in values)} | "
                     f"{', '.join(f'{c:.1f}' for _, c in values)} | {wall:.1f} | {cpu:.1f} | "
                     f"{wall / base_wall:.2f} | {cpu / base_cpu:.2f} |")
    return lines


def reuse(args) -> list[str]:
    sequences, frames = 4, 4
    config_path = write_config(WORK / "reuse.yaml", 1, sequences, frames, chunk=2)
    print(f"reused workers: whole builds of 1 capture x {sequences} sequences x {frames} frames in chunks of 2, "
          f"{args.repeats} rounds", flush=True)
    builds: dict[str, list[tuple[float, float]]] = {"a fresh process per unit": [], "reused workers": []}
    sums = {}
    for r in range(args.repeats):
        for name in (list(builds) if r % 2 == 0 else list(builds)[::-1]):
            wall, cpu, sums[name] = _whole_build(config_path, WORK / "roots" / f"reuse_{name.split()[0]}",
                                                 name == "reused workers")
            builds[name].append((wall, cpu))
            print(f"  {name:24s} wall {wall:6.1f} s  CPU {cpu:6.1f} s  load {os.getloadavg()[0]:.1f}", flush=True)
    same_builds = len({repr(sorted(v.items())) for v in sums.values()}) == 1
    scenes = sorted((WORK / "roots" / "reuse_reused" / "scenes").iterdir())
    print(f"  the chunks alone: {len(scenes)} scenes x 2 chunks of 2 frames at {SIZE}", flush=True)
    runs: dict[str, list[tuple[float, float]]] = {"fresh worker per chunk": [], "one reused worker": []}
    rss: dict[str, list[float]] = {}
    outputs = {}
    for r in range(args.repeats):
        for name in (list(runs) if r % 2 == 0 else list(runs)[::-1]):
            out = WORK / "reuse_out" / name.split()[0]
            wall, cpu, peaks = _render_chunks(scenes, out, name != "fresh worker per chunk")
            runs[name].append((wall, cpu))
            rss[name] = peaks
            outputs[name] = {s.name: _dataset_bytes(out / s.name) for s in scenes}
            print(f"  {name:24s} wall {wall:6.1f} s  CPU {cpu:6.1f} s  load {os.getloadavg()[0]:.1f}", flush=True)
    same = len({repr(sorted((k, hash(v)) for d in o.values() for k, v in d.items())) for o in outputs.values()}) == 1
    files = sum(len(d) for d in next(iter(outputs.values())).values())
    lines = [f"## 3. Reused Blender workers: {len(scenes)} sequences x 2 chunks of 2 frames at {SIZE}", "",
             f"Whole builds (`--jobs 1`, from an empty ROOT: the mesh, {sequences} scene builds and "
             f"{2 * sequences} render chunks, checksums, contact sheets), every unit's Blender task in a fresh "
             "process (as before) or in the thread's reused worker; rounds alternate. Wall and CPU seconds (this "
             "process and its Blender workers), medians and the ratio to fresh processes.", "",
             *_build_table(builds, "a fresh process per unit"), "",
             f"Manifest checksums (ground truth and images) {'identical' if same_builds else 'DIFFER'} between "
             "the builds.", "",
             "The 8 render chunks alone, with the scenes of the last build (every sequence's first chunk, then every "
             "second one: each chunk follows another scene), each in a fresh Blender process or all in one "
             "long-lived worker; rounds alternate.", "",
             *_build_table(runs, "fresh worker per chunk")]
    peaks = rss["one reused worker"]
    lines += ["", f"Output files (PNG, npz of both eyes, {files} in all) "
              f"{'byte-identical' if same else 'DIFFER'} between the two.", "",
              "Peak memory of each chunk (last round, MB): fresh workers "
              f"{', '.join(f'{p:.0f}' for p in rss['fresh worker per chunk'])}; the reused worker "
              f"{', '.join(f'{p:.0f}' for p in peaks)}."]
    lines += ["", *_reused_memory(scenes, args.reuse_tasks)]
    if not (same and same_builds):
        raise SystemExit("outputs differ between fresh and reused workers")
    return lines


def _reused_memory(scenes: list[Path], tasks: int) -> list[str]:
    """One reused worker over ``tasks`` chunks: its peak and resident memory per task (a markdown paragraph)."""
    from rgbd2scene.stages.render import prepare_render

    out = WORK / "reuse_out" / "memory"
    shutil.rmtree(out, ignore_errors=True)
    options = RenderOptions(size=tuple(int(v) for v in SIZE.split("x")), chunk=2, frames=2)
    peaks, resident = [], []
    with blender.reusing_workers():
        for k in range(tasks):
            job = prepare_render(scenes[k % len(scenes)], out / f"{k:03d}", options)
            peaks.append(blender.run_task(job.task(job.chunks()[0])).peak_rss_mb)
            resident.append(_vm_rss_mb(blender._local.worker.proc.pid))
    blender.close_workers()
    print(f"  reused worker over {tasks} tasks: peaks {[round(p) for p in peaks]}, resident "
          f"{[round(m) for m in resident]} MB", flush=True)
    half = tasks // 2
    return [f"Memory of one reused worker over {tasks} chunks of 2 frames (the four scenes in turn), MB. Peak "
            f"during each task: {', '.join(f'{p:.0f}' for p in peaks)}; resident after each task (Blender reset, "
            f"free heap returned): {', '.join(f'{m:.0f}' for m in resident)}. Mean resident, first half "
            f"{statistics.mean(resident[:half]):.0f}, second half {statistics.mean(resident[half:]):.0f}."]


SECTIONS = {"throughput": throughput, "memory": memory, "reuse": reuse}


def merge_report(path: Path, header: list[str], sections: dict[str, list[str]]) -> str:
    """The report: ``header``, then every ``## N.`` section of ``path`` with the ones run now replacing theirs."""
    old: dict[str, list[str]] = {}
    if path.is_file():
        current = None
        for line in path.read_text().splitlines():
            if line.startswith("## "):
                current = line.split(".")[0]
                old[current] = []
            if current is not None and not line.startswith("Benchmark wall time"):
                old[current].append(line)
    for lines in sections.values():
        old[lines[0].split(".")[0]] = lines + [""]
    body = [line for key in sorted(old) for line in old[key]]
    return "\n".join(header + body)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 3 minutes: smaller builds, one round")
    ap.add_argument("--parallel", action="store_true", help="also builds with 2 units at once (--jobs 2, --workers 2)")
    ap.add_argument("--repeats", type=int, default=None, help="rounds of the three engines (default 2, quick 1)")
    ap.add_argument("--reuse-tasks", type=int, default=None, help="tasks of the reused worker's memory series "
                    "(default 16, quick 6)")
    ap.add_argument("--sections", default=",".join(SECTIONS), help="which sections to run (the report keeps the "
                    "others' last figures); default all")
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/batch.md, quick: "
                    "bench_out/batch/batch.md; '' to skip)")
    args = ap.parse_args()
    args.repeats = args.repeats or (1 if args.quick else 2)
    args.reuse_tasks = args.reuse_tasks or (6 if args.quick else 16)
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
    header = [f"# Batch benchmark (`benchmarks/bench_batch.py{' --quick' if args.quick else ''}`)", "",
              "Method: see the script's docstring. Each section names the settings of the run that measured it.", ""]
    run_settings = ["", f"Run {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, settings: " +
                    ", ".join(f"{k}: {v}" for k, v in settings.items()) + "."]
    sections = {}
    for name in args.sections.split(","):
        lines = SECTIONS[name](args)
        sections[name] = lines[:1] + run_settings + lines[1:]
    footer = [f"Benchmark wall time: {time.perf_counter() - t0:.0f} s; load average at the end "
              f"{os.getloadavg()[0]:.1f} (1 minute; other processes on this 2-core machine)."]
    text = merge_report(Path(out) if out else Path("/nonexistent"), header, sections) + "\n" + "\n".join(footer) + "\n"
    print("\n" + text)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        write_results(out, text)
        print(f"report: {out}")


if __name__ == "__main__":
    main()
