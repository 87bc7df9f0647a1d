"""Speed of the reconstruction stage (issue: fill + mesh + smooth <= 1 s compute, command <= 3 s wall).

Runs ``rgbd2scene mesh`` on the TUM frame (and the bundled sample) several times in fresh processes,
side by side, and prints the stage times reported by the command and the wall time including the
interpreter start. Usage: ``python benchmarks/bench_mesh.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import json
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


def run_once(args: list[str], extra: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([str(RGBD2SCENE), "mesh", *args, *extra, "-o", tmp], check=True, capture_output=True)
        wall = time.perf_counter() - t0
        timings = json.loads((Path(tmp) / "scene.json").read_text())["timings"]
    return {"wall_s": wall, **timings}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    variants = [("default (with overview.png)", []), ("--no-overview", ["--no-overview"])]
    print(f"rgbd2scene mesh, median of {args.repeats} fresh processes, defaults: fill auto, ray smoothing x10")
    header = f"{'case':24s} {'variant':28s} {'fill':>6s} {'mesh':>6s} {'smooth':>6s} {'compute':>8s} " \
             f"{'write':>6s} {'wall':>6s}"
    print(header)
    print("-" * len(header))
    for name, case_args in cases():
        rows = {}
        for label, extra in variants:
            runs = [run_once(case_args, extra) for _ in range(args.repeats)]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            rows[label] = med
            print(f"{name:24s} {label:28s} {med['fill_s']:6.3f} {med['mesh_s']:6.3f} {med['smooth_s']:6.3f} "
                  f"{med['compute_s']:8.3f} {med['write_s']:6.3f} {med['wall_s']:6.2f}")
        a, b = rows[variants[0][0]]["wall_s"], rows[variants[1][0]]["wall_s"]
        print(f"{'':24s} overview costs {a - b:+.2f} s wall ({a / b:.2f}x)")
    print("targets: compute <= 1 s, wall <= 3 s (TUM)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
