#!/usr/bin/env python3
"""Export benchmark: memory and speed of ``export-ros`` (ROS 1 and 2) and ``export`` over a long dataset.

Usage: ``python benchmarks/bench_export.py [--quick] [--frames N] [--out MD]``

A synthetic dataset (:func:`rgbd2scene.groundtruth.synthetic.write_plane_dataset`, 64x32, every ground-truth map)
of ``--frames`` frames (default 2,000; ``--quick`` 300) is written to ``bench_out/export`` once and exported
in this one process to a ROS 1 bag, a ROS 2 (MCAP) bag and each standard format. The process's resident
memory (``VmRSS`` from ``/proc/self/status``) is read every 10 % of the frames (as the exporter reads a frame's
left image) and its peak (``ru_maxrss``) at the end, so growth per frame shows whether streaming keeps memory
flat (the output grows by ~13 kB a frame; holding it would show as that much RSS per frame). Results go to
``benchmarks/results/export.md`` (``--quick``: ``bench_out/export/export.md``).
"""

from __future__ import annotations

import argparse
import platform
import resource
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.dataset import Dataset  # noqa: E402
from rgbd2scene.export import FORMATS, RosOptions, export_ros  # noqa: E402
from rgbd2scene.groundtruth.synthetic import PlaneScene, write_plane_dataset  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

WORK = ROOT / "bench_out" / "export"


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class MeteredDataset(Dataset):
    """A Dataset that records (frame, RSS MB) every ``every`` frames as an exporter reads them."""

    def __init__(self, root: Path, every: int):
        super().__init__(root)
        self.every, self.samples = every, []

    def _sample(self, index: int) -> None:
        if index % self.every == 0 or index == self.frames - 1:
            self.samples.append((index, rss_mb()))

    def rgb(self, eye, index):
        if eye == "left":
            self._sample(index)
        return super().rgb(eye, index)

    def rgb_file(self, eye, index):
        if eye == "left":
            self._sample(index)
        return super().rgb_file(eye, index)


def size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--frames", type=int)
    ap.add_argument("--out")
    args = ap.parse_args()
    frames = args.frames or (300 if args.quick else 2000)
    out_md = Path(args.out) if args.out else (WORK / "export.md" if args.quick else ROOT / "benchmarks" / "results"
                                              / "export.md")
    t0 = time.perf_counter()
    data = WORK / f"plane_{frames}"
    if not (data / "dataset.json").is_file():
        shutil.rmtree(data, ignore_errors=True)
        print(f"writing a {frames}-frame synthetic dataset to {data}", flush=True)
        write_plane_dataset(data, frames, PlaneScene(), progress=True)
    every = max(1, frames // 10)
    rows = []
    jobs = [("export-ros --ros 1", lambda ds, o: export_ros(ds, o, RosOptions(version=1), progress=False), "bag.bag"),
            ("export-ros --ros 2", lambda ds, o: export_ros(ds, o, RosOptions(version=2), progress=False), "bag2")]
    jobs += [(f"export --format {name}", lambda ds, o, f=writer: f(ds, o, progress=False), name)
             for name, writer in FORMATS.items()]
    for label, run, target in jobs:
        out = WORK / "out" / target
        shutil.rmtree(out, ignore_errors=True) if out.is_dir() else out.unlink(missing_ok=True)
        ds = MeteredDataset(data, every)
        start_rss = rss_mb()
        t = time.perf_counter()
        run(ds, out)
        seconds = time.perf_counter() - t
        samples = ds.samples
        first = next(r for i, r in samples if i >= every)  # after the first 10 % (imports and caches settled)
        growth_kb = (samples[-1][1] - first) * 1024 / max(samples[-1][0] - every, 1)
        rows.append((label, seconds / frames * 1000, start_rss, first, samples[-1][1], growth_kb, size_mb(out)))
        print(f"{label}: {seconds:.1f} s, RSS {start_rss:.0f} -> {first:.0f} (frame {every}) -> "
              f"{samples[-1][1]:.0f} MB (frame {samples[-1][0]}), {growth_kb:+.2f} kB/frame, output "
              f"{size_mb(out):.1f} MB", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    versions = software_versions()
    lines = [
        "# Export benchmark (`benchmarks/bench_export.py`)", "",
        f"Synthetic plane dataset, {frames} frames of 64x32 (both eyes, every ground-truth map), exported in one "
        f"process. Settings: machine {platform.machine()}, python {versions['python']}, rosbags "
        f"{_version('rosbags')}, quick: {args.quick}. RSS: resident memory of the process read as the exporter "
        f"reaches frame 0, every {every} frames and the last frame; growth = (RSS at the last frame - RSS at frame "
        f"{every}) / frames in between.", "",
        "| export | ms / frame | RSS before MB | RSS at frame " + str(every) + " MB | RSS at last frame MB | "
        "growth kB / frame | output MB |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, ms, r0, r1, r2, g, mb in rows:
        lines.append(f"| `{label}` | {ms:.2f} | {r0:.0f} | {r1:.0f} | {r2:.0f} | {g:+.2f} | {mb:.1f} |")
    worst = max(rows, key=lambda r: r[5])
    lines += ["", f"Process peak RSS (ru_maxrss) over all exports: {peak:.0f} MB. Largest growth: `{worst[0]}` "
              f"{worst[5]:+.2f} kB/frame against {worst[6] * 1000 / frames:.1f} kB of output per frame.",
              "", f"Benchmark wall time {time.perf_counter() - t0:.0f} s.", ""]
    out_md.parent.mkdir(parents=True, exist_ok=True)
    write_results(out_md, "\n".join(lines))
    print(f"\nreport: {out_md}")
    return 0


def _version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    sys.exit(main())
