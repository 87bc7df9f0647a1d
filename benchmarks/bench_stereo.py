#!/usr/bin/env python3
"""Stereo benchmark: the VisionBlender paper's experiment in miniature (SGBM and ELAS on rendered endoscope pairs).

Usage: ``python benchmarks/bench_stereo.py [--quick] [--frames N] [--size WxH] [--out MD]``

1. Scenes from captures (``rgbd2scene scene``, default wet-tissue material, 5 mm baseline, 4 cm standoff): the
   bundled sample ``data_samples/tissue`` and, when ``../shared/rgbd_samples`` is present, real Kinect-style
   captures (TUM office frame, Redwood living-room frame 0, SUN RGB-D frame with the SUN bit rotation).
2. One sequence per scene rendered at ``--size`` (default 256x128, ``--frames`` 8 frames, the render
   defaults) into a batch ROOT with ``manifest.csv`` (CONVENTIONS §8). Captures are split by scene: the test
   split holds captures no other split uses (TUM, SUN), so it is a held-out set for anyone who tunes a method
   (or trains a network, through ``--predictions``) on the train split.
3. ``rgbd2scene evaluate ROOT --methods gt,sgbm,elas``: one table per split, every metric as mean ± std over
   frames, scored on every valid ground-truth pixel with invalid predictions filled by the nearest valid one
   (the main score) and on valid predictions only (with their density). ``gt`` (the ground-truth disparity
   scored as a method) is the sanity row: zero error, density 1.
4. Per-sequence RMSE and density, seconds per frame of each method (measured in this run, on the test
   frames), and the rows where each method loses.

``--quick``: the bundled sample (train) and TUM (test), 4 frames each. Results: ``benchmarks/results/stereo.md``
(``--quick``: ``bench_out/stereo/stereo.md``); the datasets and the evaluation stay in ``bench_out/stereo``.
"""

from __future__ import annotations

import argparse
import csv
import platform
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.cli import main as cli  # noqa: E402
from rgbd2scene.dataset import Dataset  # noqa: E402
from rgbd2scene.evaluate import EvaluationOptions, build_methods, evaluate  # noqa: E402
from rgbd2scene.evaluate.methods import DisparityRange, dataset_depth_range  # noqa: E402
from rgbd2scene.evaluate.report import markdown_table  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

SAMPLE = ROOT / "data_samples" / "tissue"
SHARED = ROOT.parent / "shared" / "rgbd_samples"
WORK = ROOT / "bench_out" / "stereo"
METHODS = ("gt", "sgbm", "elas")


def captures() -> list[dict]:
    """(name, capture arguments, path kind, split) of every scene this machine has captures for."""
    out = [{"name": "tissue_scan", "capture": "tissue (bundled)", "split": "train", "path": "scan",
            "args": ["--rgb", SAMPLE / "rgb.png", "--depth", SAMPLE / "depth.png", "--camera", SAMPLE / "camera.json"]}]
    tum, redwood, nyu = (SHARED / "tum_office_frame_open3d", SHARED / "redwood_livingroom1_5frames_open3d",
                         SHARED / "nyu_sun_raw_frames_open3d")
    if tum.is_dir():
        out.append({"name": "tum_random", "capture": "TUM office (Kinect v1)", "split": "test", "path": "random",
                    "args": ["--rgb", tum / "TUM_color.png", "--depth", tum / "TUM_depth.png",
                             "--camera", tum / "camera_primesense.json", "--depth-scale", "5000"]})
    if redwood.is_dir():
        out.append({"name": "redwood_orbit", "capture": "Redwood living room, frame 0", "split": "train",
                    "path": "orbit", "args": ["--rgb", redwood / "color" / "00000.jpg", "--depth",
                                              redwood / "depth" / "00000.png", "--camera",
                                              redwood / "camera_primesense.json", "--depth-scale", "1000"]})
    if nyu.is_dir():
        out.append({"name": "sun_scan", "capture": "SUN RGB-D frame (primesense intrinsics)", "split": "test",
                    "path": "scan", "args": ["--rgb", nyu / "SUN_color.jpg", "--depth", nyu / "SUN_depth.png",
                                             "--depth-format", "sun", "--preset", "primesense"]})
    return out


def build(seq: dict, frames: int, size: str, root: Path) -> float:
    """Scene and rendered dataset of one sequence (reused when already complete); returns seconds spent."""
    t = time.perf_counter()
    scene, data = WORK / f"scenes_{frames}" / seq["name"], root / seq["name"]
    if not (scene / "scene.blend").is_file():
        args = [str(a) for a in seq["args"]]
        code = cli(["scene", *args, "--path", seq["path"], "--frames", str(frames), "--no-overview", "-o", str(scene)])
        if code:
            raise SystemExit(f"scene {seq['name']} failed ({code})")
    if cli(["render", str(scene), "-o", str(data), "--frames", str(frames), "--size", size, "--quiet",
            "--no-sheet"]):
        raise SystemExit(f"render {seq['name']} failed")
    return time.perf_counter() - t


def write_manifest(root: Path, seqs: list[dict], frames: int) -> None:
    with open(root / "manifest.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["sequence", "capture", "split", "seed", "path", "frames", "status", "error"])
        for s in seqs:
            writer.writerow([s["name"], s["capture"], s["split"], 0, s["path"], frames, "done", ""])


def time_methods(root: Path, seqs: list[dict]) -> dict[str, float]:
    """Seconds per frame of each method over the test sequences' frames (images already in memory)."""
    totals, counts = defaultdict(float), defaultdict(int)
    for s in seqs:
        if s["split"] != "test":
            continue
        ds = Dataset(root / s["name"])
        search = DisparityRange.from_depths(*dataset_depth_range(ds), ds.fx, ds.baseline)
        for method in build_methods(ds, list(METHODS), (), search):
            for index in ds.frame_indices():
                left, right = ds.rgb("left", index), ds.rgb("right", index)
                t = time.perf_counter()
                method(index, left, right)
                totals[method.name] += time.perf_counter() - t
                counts[method.name] += 1
    return {m: totals[m] / counts[m] for m in totals}


def per_sequence(per_frame_csv: Path) -> list[tuple[str, str, str, float, float]]:
    """(sequence, split, method, mean RMSE mm over frames (filled), mean density)."""
    acc = defaultdict(list)
    with open(per_frame_csv, newline="") as f:
        for r in csv.DictReader(f):
            if r["scored"] == "all":
                acc[r["sequence"], r["split"], r["method"]].append((float(r["rmse_mm"]), float(r["density"])))
    return [(s, sp, m, float(np.mean([v[0] for v in vals])), float(np.mean([v[1] for v in vals])))
            for (s, sp, m), vals in acc.items()]


def losses(rows) -> list[str]:
    """Where each real method loses: per split and metric of the main score, the methods behind the best one."""
    lower_better = {"rmse_mm", "abs_rel", "sq_rel", "rmse_log"}
    out = []
    for split in dict.fromkeys(r.split for r in rows):
        main = [r for r in rows if r.split == split and r.scored == "all" and r.method != "gt"]
        for metric in ("rmse_mm", "abs_rel", "sq_rel", "rmse_log", "a1", "a2", "a3", "density"):
            pick = min if metric in lower_better else max
            best = pick(main, key=lambda r: r.values[metric][0])
            for r in main:
                if r is not best and r.values[metric][0] != best.values[metric][0]:
                    out.append(f"- {split}, {metric}: **{r.method}** {r.values[metric][0]:.4g} vs {best.method} "
                               f"{best.values[metric][0]:.4g}")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--frames", type=int)
    ap.add_argument("--size", default="256x128")
    ap.add_argument("--out")
    args = ap.parse_args()
    t0 = time.perf_counter()
    frames = args.frames or (4 if args.quick else 8)
    seqs = captures()
    if args.quick:
        seqs = [s for s in seqs if s["name"] in ("tissue_scan", "tum_random")]
    root = WORK / f"root_{args.size}_{frames}"
    root.mkdir(parents=True, exist_ok=True)
    build_s = {s["name"]: build(s, frames, args.size, root) for s in seqs}
    write_manifest(root, seqs, frames)
    t = time.perf_counter()
    result = evaluate(root, root / "evaluation", EvaluationOptions(methods=METHODS), progress=False)
    eval_s = time.perf_counter() - t
    speed = time_methods(root, seqs)
    seq_rows = per_sequence(root / "evaluation" / "per_frame.csv")
    versions = software_versions()
    settings = (f"machine {platform.machine()}, {__import__('os').cpu_count()} cores, python {versions['python']}, "
                f"bpy {versions['bpy']}, opencv {versions['opencv']}, quick: {args.quick}; {frames} frames per "
                f"sequence at {args.size}, render defaults (1 spp, adaptive, OIDN), scene defaults (wet tissue, "
                "5 mm baseline, 4 cm standoff)")
    lines = ["# Stereo benchmark (`benchmarks/bench_stereo.py`)", "", f"Settings: {settings}.", "",
             "| sequence | capture | split | path | scene + render s |", "|---|---|---|---|---|"]
    lines += [f"| {s['name']} | {s['capture']} | {s['split']} | {s['path']} | {build_s[s['name']]:.0f} |" for s in seqs]
    lines += ["", "Methods: `sgbm` (OpenCV StereoSGBM, 3-way, block 5, P1/P2 = 8/32·3·25, uniqueness 5, speckle "
              "100/2, search = the sequence's ground-truth depth range ±10 %), `elas` (libelas through pyelas, "
              "ROBOTICS preset, search 0 to the range's top), `gt` (the ground-truth disparity: sanity row). Depth "
              "z = fx·B/d; metrics after Eigen et al. over every valid ground-truth pixel.", ""]
    for split in dict.fromkeys(r.split for r in result.rows):
        for scored, text in (("all", "every valid ground-truth pixel, invalid predictions filled by the nearest "
                                     "valid one (main score)"),
                             ("valid", "valid predictions only (flatters sparse methods; read with density)")):
            lines += [f"### {split} split: {text}", "",
                      markdown_table([r for r in result.rows if r.split == split and r.scored == scored]), ""]
    lines += ["### Per sequence (main score)", "", "| sequence | split | method | RMSE mm | density |",
              "|---|---|---|---|---|"]
    lines += [f"| {s} | {sp} | {m} | {r:.2f} | {d:.3f} |" for s, sp, m, r, d in seq_rows]
    lines += ["", "### Speed (test frames, images in memory)", "", "| method | s / frame | vs sgbm |", "|---|---|---|"]
    lines += [f"| {m} | {s:.4f} | {s / speed['sgbm']:.2f} |" for m, s in speed.items()]
    lines += ["", "### Where each method loses (main score)", "", *(losses(result.rows) or ["- nowhere"]), "",
              f"Evaluation {eval_s:.0f} s; benchmark wall time {time.perf_counter() - t0:.0f} s. Tables, per-frame "
              f"CSV and error maps of the best and worst frames: `{root.relative_to(ROOT)}/evaluation/`.", ""]
    out_md = Path(args.out) if args.out else (WORK / "stereo.md" if args.quick else ROOT / "benchmarks" / "results"
                                              / "stereo.md")
    out_md.parent.mkdir(parents=True, exist_ok=True)
    write_results(out_md, "\n".join(lines))
    print("\n".join(lines))
    print(f"report: {out_md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
