"""Speed of the reconstruction stage (issue: fill + mesh + smooth <= 1 s compute, command <= 3 s wall).

Runs ``rgbd2scene mesh`` on the TUM frame (and the bundled sample) several times in fresh processes, the
variants interleaved (run k of every variant before run k+1 of any, so a change of the machine's load hits
them alike), and prints the median stage times reported by the command, the wall time including the
interpreter start and the CPU time of the process (all threads), the fastest run's wall time, and the median
load average seen after the runs (other processes: on a shared machine it decides the wall time). **start s**
is the wall time outside the command's own clock (interpreter start, imports, reading the capture, exit): wall
minus compute and write.
``--against DIR`` runs another checkout of the repository (its ``rgbd2scene`` on ``PYTHONPATH``) as one more
variant, for a ratio measured side by side: the ratio of the medians and the median and range of the ratios
within a round (the two runs of a round saw the same load). ``--realtime`` runs each command under
``chrt -f 10`` (SCHED_FIFO: it takes the CPUs ahead of every ordinary process, which keep the 5 % the kernel's
real-time throttling leaves them), the wall time it would have on an idle machine; it needs root and briefly
slows everything else down.
Usage: ``python benchmarks/bench_mesh.py [--repeats N] [--against DIR] [--realtime]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "rgbd_samples"
RGBD2SCENE = Path(sys.executable).with_name("rgbd2scene")


def cases() -> list[tuple[str, list[str]]]:
    out = []
    tum = SHARED / "tum_office_frame_open3d"
    if tum.is_dir():
        out.append(("tum 640x480", ["--rgb", str(tum / "TUM_color.png"), "--depth", str(tum / "TUM_depth.png"),
                                    "--preset", "tum_fr1"]))
    sample = REPO / "data_samples" / "tissue"
    out.append(("tissue sample 640x480", ["--rgb", str(sample / "rgb.png"), "--depth", str(sample / "depth.png"),
                                          "--camera", str(sample / "camera.json")]))
    return out


def run_once(args: list[str], extra: list[str], code: Path = REPO, prefix: tuple[str, ...] = ()) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code)}
    with tempfile.TemporaryDirectory() as tmp:
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([*prefix, str(RGBD2SCENE), "mesh", *args, *extra, "-o", tmp], check=True,
                       capture_output=True, env=env)
        wall = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        timings = json.loads((Path(tmp) / "scene.json").read_text())["timings"]
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "load": os.getloadavg()[0], **timings,
            "start_s": wall - timings["compute_s"] - timings["write_s"]}


def _ratios(runs: list[dict], against: list[dict], key: str) -> str:
    """The median and range of the per-round ratios ``runs[i][key] / against[i][key]``."""
    ratios = [r[key] / a[key] for r, a in zip(runs, against, strict=True)]
    return f"{statistics.median(ratios):.2f}x ({min(ratios):.2f}-{max(ratios):.2f})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--against", type=Path, help="another checkout, run side by side (default settings)")
    parser.add_argument("--realtime", action="store_true", help="run the commands with real-time priority "
                        "(chrt -f 10): their wall time as on an idle machine")
    args = parser.parse_args(argv)
    prefix = ("chrt", "-f", "10") if args.realtime else ()
    variants = [("default (with overview.png)", [], REPO), ("--no-overview", ["--no-overview"], REPO)]
    if args.against:
        variants.append((f"default, {args.against}", [], args.against.resolve()))
    load = os.getloadavg()[0]
    print(f"rgbd2scene mesh, median of {args.repeats} fresh processes (variants interleaved), defaults: fill auto, "
          f"ray smoothing x10; {os.cpu_count()} CPUs, load average (1 min) at start {load:.2f}"
          f"{'; real-time priority (chrt -f 10)' if args.realtime else ''}")
    header = ("| case | variant | start s | fill s | texture s | mesh s | smooth s | compute s | write s | wall s "
              "| CPU s | fastest wall s | load (1 min) |")
    print(header)
    print("|---" * 13 + "|")
    for name, case_args in cases():
        runs: dict[str, list[dict]] = {label: [] for label, _, _ in variants}
        for _ in range(args.repeats):
            for label, extra, code in variants:
                runs[label].append(run_once(case_args, extra, code, prefix))
        rows = {}
        for label, _, _ in variants:
            med = {k: statistics.median(r[k] for r in runs[label]) for k in runs[label][0]}
            rows[label] = med
            fastest = min(r["wall_s"] for r in runs[label])
            print(f"| {name} | {label} | {med['start_s']:.3f} | {med['fill_s']:.3f} | {med['texture_s']:.3f} | "
                  f"{med['mesh_s']:.3f} | {med['smooth_s']:.3f} | "
                  f"{med['compute_s']:.3f} | {med['write_s']:.3f} | {med['wall_s']:.2f} | {med['cpu_s']:.2f} | "
                  f"{fastest:.2f} | {med['load']:.1f} |")
        a, b = rows[variants[0][0]]["wall_s"], rows[variants[1][0]]["wall_s"]
        print(f"{name}: the overview costs {a - b:+.2f} s wall ({a / b:.2f}x)")
        if args.against:
            c = rows[variants[2][0]]
            print(f"{name}: this checkout / {args.against}: wall {a / c['wall_s']:.2f}x, "
                  f"CPU {rows[variants[0][0]]['cpu_s'] / c['cpu_s']:.2f}x; per round: "
                  + ", ".join(f"{key.removesuffix('_s')} {_ratios(runs[variants[0][0]], runs[variants[2][0]], key)}"
                              for key in ("wall_s", "cpu_s", "start_s", "fill_s", "mesh_s", "write_s")))
    print(f"load average (1 min) at end {os.getloadavg()[0]:.2f}; targets: fill <= 1 s, wall <= 3 s (TUM)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
