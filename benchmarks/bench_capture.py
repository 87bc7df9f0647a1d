#!/usr/bin/env python3
"""Capture benchmark: multi-frame fusion (Redwood, 5 frames) and stereo depth (synthetic truth, Hamlyn phantom).

Usage: ``python benchmarks/bench_capture.py [--quick] [--repeats N] [--out benchmarks/results/capture.md]``

1. **Fusion**, Redwood living room 1, frames 0-4 (640x480, given poses from ``trajectory.log``). Every
   variant's mesh is ray cast at each frame's pose and compared with that frame's depth over all of the
   frame's valid pixels: coverage (the fraction the mesh covers) and the median and 90th percentile of the
   absolute depth difference (mm). Variants: the single-frame pipeline on frame 0 (what one frame gives;
   its mesh covers only what frame 0 saw), the fused default (no per-frame fill), per-frame ``auto`` fill
   before fusing, and poses from RGB-D odometry instead of the file. Time: the median over ``--repeats``
   runs of the reconstruction (fusion: poses + integration + extraction + the agreement ray casts), and
   the wall and CPU time of the whole ``rgbd2scene mesh`` command in a fresh process.
2. **Stereo, synthetic truth**: a 640x480 rectified pair of a textured curved surface (disparity
   24-60 px, a smooth bump) made by warping one texture; every pixel whose match lies inside the right
   image is scored: coverage of confident depth, disparity error median and 95th percentile, and the
   share of confident pixels off by more than 1 px. SGBM and ELAS (when ``pyelas`` is installed) side by side.
3. **Stereo, Hamlyn phantom** (360x288 source, 425x340 rectified): coverage of the image data, depth
   percentiles, time; and where SGBM and ELAS are both confident, how far apart their depths are (there
   is no ground truth). The same frame up-sampled to 640x480 (calibration scaled alike) gives the
   640x480 timing (its coverage says little: up-sampled images have no new texture).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.capture.camera import load_camera_json  # noqa: E402
from rgbd2scene.capture.readers import load_capture, read_rgb  # noqa: E402
from rgbd2scene.capture.stereo import (  # noqa: E402
    RectifiedPair,
    StereoOptions,
    elas_available,
    read_stereo_calibration,
    rectify,
    rectify_pair,
    stereo_depth,
)
from rgbd2scene.capture.trajectory import associate, read_trajectory, relative_to_first  # noqa: E402
from rgbd2scene.conventions import pixel_grid  # noqa: E402
from rgbd2scene.reconstruct.fusion import frame_agreement, reconstruct_fused  # noqa: E402
from rgbd2scene.reconstruct.pipeline import MeshOptions, reconstruct  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

SHARED = ROOT.parent / "shared" / "rgbd_samples"
REDWOOD = SHARED / "redwood_livingroom1_5frames_open3d"
HAMLYN = SHARED / "hamlyn_silicone_heart_phantom_stereo"
RGBD2SCENE = Path(sys.executable).with_name("rgbd2scene")


def _timed(fn, repeats: int):
    """(result of the last run, median wall seconds, median CPU seconds of this process over ``repeats`` runs).

    CPU time (all threads) is less affected than wall time by other programs on a shared machine.
    """
    wall, cpu, result = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return result, statistics.median(wall), statistics.median(cpu)


# --------------------------------------------------------------------------------------------- fusion


def bench_fusion(repeats: int, quick: bool) -> tuple[list[dict], dict]:
    intr, _ = load_camera_json(REDWOOD / "camera_primesense.json")
    rgb = [str(REDWOOD / f"color/{i:05d}.jpg") for i in range(5)]
    depth = [str(REDWOOD / f"depth/{i:05d}.png") for i in range(5)]
    frames = [load_capture(r, d, intr, depth_scale=1000) for r, d in zip(rgb, depth, strict=True)]
    poses = relative_to_first(associate(read_trajectory(REDWOOD / "trajectory.log"), rgb).poses)
    plain = MeshOptions(fill="none", smooth="none")
    variants = [
        ("single frame 0 (fill auto, ray smoothing)", lambda: reconstruct(frames[0])),
        ("fused, given poses (default)", lambda: reconstruct_fused(frames, poses, plain)),
        ("fused, per-frame fill auto", lambda: reconstruct_fused(frames, poses, MeshOptions(fill="auto",
                                                                                              smooth="none"))),
        ("fused, odometry poses", lambda: reconstruct_fused(frames, None, plain)),
    ]
    if quick:
        variants = variants[:2]
    rows = []
    for name, run in variants:
        recon, seconds, cpu = _timed(run, repeats if "default" in name else 1)
        agreement = recon.sections["fusion"]["agreement"] if "fusion" in recon.sections else \
            frame_agreement(recon.mesh, frames, poses)
        row = {"variant": name, "seconds": seconds, "cpu_s": cpu, "compute_s": recon.timings["compute_s"],
               "agreement": agreement,
               "triangles": recon.mesh.n_triangles}
        if "fusion" in recon.sections:
            row["fusion_timings"] = recon.sections["fusion"]["timings"]
            row["fusion_stats"] = recon.sections["fusion"]["stats"]
        rows.append(row)
        worst = max(a["median_mm"] for a in agreement)
        print(f"  {name:44s} {seconds:6.2f} s, coverage {min(a['coverage'] for a in agreement) * 100:5.1f}-"
              f"{max(a['coverage'] for a in agreement) * 100:5.1f} %, worst median {worst:.2f} mm", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), _children_cpu()
        subprocess.run([str(RGBD2SCENE), "mesh", "--rgb", *rgb, "--depth", *depth, "--poses",
                        str(REDWOOD / "trajectory.log"), "--camera", str(REDWOOD / "camera_primesense.json"),
                        "--depth-scale", "1000", "-o", tmp], check=True, capture_output=True)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        command_timings = json.loads((Path(tmp) / "scene.json").read_text())["timings"]
    return rows, {"command_wall_s": wall, "command_cpu_s": cpu, "command_write_s": command_timings["write_s"]}


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def fusion_markdown(rows: list[dict], extra: dict, repeats: int) -> list[str]:
    out = ["## 1. Fusion: Redwood living room 1, 5 frames, 640x480", "",
           f"Time: compute s = the reconstruction's own stage times (fusion: poses, fill, fuse, smooth; single "
           f"frame: fill, mesh, smooth), last run; s and CPU s = the whole call, wall and CPU of all threads, "
           f"median of {repeats} runs for the default, one run otherwise (fusion: including the agreement ray "
           "casts it records). Per frame: coverage of its valid "
           "pixels / median / p90 absolute depth difference in mm. Bold: best per column.", ""]
    header = ("| variant | compute s | s | CPU s | triangles | " + " | ".join(f"frame {k}" for k in range(5))
              + " | mean median mm |")
    out += [header, "|" + "---|" * (6 + 5)]
    best_cov = [max(r["agreement"][k]["coverage"] for r in rows) for k in range(5)]
    for r in rows:
        cells = []
        for k, a in enumerate(r["agreement"]):
            cov = f"{100 * a['coverage']:.1f} %"
            cells.append((f"**{cov}**" if a["coverage"] == best_cov[k] else cov)
                         + f" / {a['median_mm']:.2f} / {a['p90_mm']:.1f}")
        mean = np.mean([a["median_mm"] for a in r["agreement"]])
        out.append(f"| {r['variant']} | {r['compute_s']:.2f} | {r['seconds']:.2f} | {r['cpu_s']:.2f} | "
                   f"{r['triangles']:,} | " + " | ".join(cells) + f" | {mean:.2f} |")
    default = next(r for r in rows if "default" in r["variant"])
    t, s = default["fusion_timings"], default["fusion_stats"]
    out += ["", f"Default run: poses {t['poses_s']:.2f} s, TSDF prepare {s['prepare_s']:.2f} s, integrate "
            f"{s['integrate_s']:.2f} s, extract {s['extract_s']:.2f} s (fuse {t['fuse_s']:.2f} s), agreement "
            f"{t['agreement_s']:.2f} s; voxel {s['voxel_size_m'] * 1e3:.2f} mm, {s['blocks']} blocks, "
            f"{s['dropped_components']} debris pieces ({s['dropped_triangles']} triangles) dropped. "
            f"`rgbd2scene mesh` with 5 frames, fresh process (imports, reading, fusion, agreement, files and "
            f"overview.png): {extra['command_wall_s']:.2f} s wall, {extra['command_cpu_s']:.2f} s CPU, of which "
            f"writing the folder {extra['command_write_s']:.2f} s.", ""]
    losses = []
    for r in rows:
        if r is default:
            continue
        pairs = list(enumerate(zip(r["agreement"], default["agreement"], strict=True)))
        closer = [f"{k} ({a['median_mm']:.2f} vs {b['median_mm']:.2f} mm)" for k, (a, b) in pairs
                  if a["median_mm"] < b["median_mm"] - 0.01]
        more = [f"{k} (+{100 * (a['coverage'] - b['coverage']):.1f} points)" for k, (a, b) in pairs
                if a["coverage"] > b["coverage"] + 0.001]
        if closer:
            losses.append(f"{r['variant']} agrees better with frame(s) {', '.join(closer)}")
        if more:
            losses.append(f"{r['variant']} covers more of frame(s) {', '.join(more)}")
    out += ["Where the default loses: " + ("; ".join(losses) if losses else "nowhere in this table") + ".", ""]
    return out


# --------------------------------------------------------------------------------------------- stereo


def curved_pair(width: int = 640, height: int = 480) -> tuple[RectifiedPair, np.ndarray]:
    """A rectified pair of a textured curved surface and its true left disparity (px).

    d(u, v) = 24 + 0.03 u + 0.02 v + 14 exp(-r^2 / 2 (90 px)^2) (a bump in the middle); each right row is
    the left texture resampled at the left position u with u - d(u) = x (d grows slower than u, so the
    map is monotonic and inverted by interpolation).
    """
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (height, width + 200)).astype(np.float32), (0, 0), 1.5)
    texture = cv2.normalize(texture, None, 12, 243, cv2.NORM_MINMAX)
    u, v = pixel_grid(height, width)
    r2 = (u - width / 2) ** 2 + (v - height / 2) ** 2
    truth = 24.0 + 0.03 * u + 0.02 * v + 14.0 * np.exp(-r2 / (2 * 90.0 ** 2))
    fine = np.arange(-100, width + 100, 0.25)
    right_src = np.empty((height, width), np.float32)
    xs = np.arange(width, dtype=np.float64)
    for row in range(height):
        rr = (fine - width / 2) ** 2 + (row - height / 2) ** 2
        d = 24.0 + 0.03 * fine + 0.02 * row + 14.0 * np.exp(-rr / (2 * 90.0 ** 2))
        right_src[row] = np.interp(xs, fine - d, fine)
    left = texture[:, 100:100 + width]
    right = cv2.remap(texture, right_src + 100, v.astype(np.float32), cv2.INTER_CUBIC)
    images = [np.repeat(np.clip(im, 0, 255).astype(np.uint8)[..., None], 3, axis=2) for im in (left, right)]
    mask = np.ones((height, width), bool)
    return RectifiedPair(images[0], images[1], mask, mask.copy()), truth


def matchers() -> list[str]:
    return ["sgbm", "elas"] if elas_available() else ["sgbm"]


def bench_stereo_synthetic(repeats: int) -> list[dict]:
    pair, truth = curved_pair()
    u = pixel_grid(*truth.shape)[0]
    scored = (u - truth) >= 0  # the match lies inside the right image
    f, baseline = 500.0, 0.005  # disparities 24-60 px: depths 42-104 mm
    rows = []
    for matcher in matchers():
        options = StereoOptions(matcher=matcher, min_depth=0.03, max_depth=0.3)
        result, seconds, cpu = _timed(lambda o=options: stereo_depth(pair, f, baseline, o), repeats)
        good = np.isfinite(result.disparity) & scored
        err = np.abs(result.disparity - truth)[good]
        rows.append({"matcher": matcher, "seconds": seconds, "cpu_s": cpu, "coverage": float(good.sum() / scored.sum()),
                     "median_px": float(np.median(err)), "p95_px": float(np.percentile(err, 95)),
                     "bad1": float(np.mean(err > 1.0))})
        print(f"  synthetic 640x480 {matcher}: {seconds:.2f} s, coverage {100 * rows[-1]['coverage']:.1f} %, "
              f"median {rows[-1]['median_px']:.3f} px", flush=True)
    return rows


def _scaled_hamlyn(width: int, height: int):
    """The Hamlyn frame and calibration resampled to width x height (intrinsics scaled pixel-centre aware)."""
    calib = read_stereo_calibration(HAMLYN, image_size=(360, 288))
    scaled = calib.resized(width, height)
    images = [cv2.resize(read_rgb(HAMLYN / name), (width, height), interpolation=cv2.INTER_LINEAR)
              for name in ("f7_dynamic_deint_L_0100.png", "f7_dynamic_deint_R_0100.png")]
    return scaled, images


def bench_stereo_hamlyn(repeats: int, quick: bool) -> list[dict]:
    rows = []
    sizes = [(360, 288)] if quick else [(360, 288), (640, 480)]
    for size in sizes:
        calib, (left, right) = _scaled_hamlyn(*size)
        depths = {}
        for matcher in matchers():
            options = StereoOptions(matcher=matcher)

            def run(c=calib, o=options, lt=left, rt=right):
                rect = rectify(c, alpha=o.alpha, keep_resolution=o.keep_resolution)
                pair = rectify_pair(c, rect, lt, rt)
                return rect, stereo_depth(pair, rect.K[0, 0], rect.baseline, o)

            (rect, result), seconds, cpu = _timed(run, repeats)
            depths[matcher] = result.depth
            pct = result.stats["depth_percentiles_m"]
            rows.append({"size": f"{size[0]}x{size[1]}", "rectified": f"{rect.width}x{rect.height}",
                         "matcher": matcher, "seconds": seconds, "cpu_s": cpu, "coverage": result.stats["coverage"],
                         "p5_mm": pct["5"] * 1e3, "p50_mm": pct["50"] * 1e3, "p95_mm": pct["95"] * 1e3})
            print(f"  hamlyn {size[0]}x{size[1]} {matcher}: {seconds:.2f} s, coverage "
                  f"{100 * result.stats['coverage']:.1f} %", flush=True)
        if len(depths) == 2:
            both = np.isfinite(depths["sgbm"]) & np.isfinite(depths["elas"])
            diff = np.abs(depths["sgbm"] - depths["elas"])[both] * 1e3
            rows[-1]["sgbm_vs_elas"] = {"pixels": int(both.sum()), "median_mm": float(np.median(diff)),
                                        "p95_mm": float(np.percentile(diff, 95))}
    return rows


def stereo_markdown(synthetic: list[dict], hamlyn: list[dict], repeats: int) -> list[str]:
    out = ["## 2. Stereo depth, synthetic truth (640x480, curved textured surface, disparity 24-60 px)", "",
           f"All pixels whose match lies inside the right image are scored; time: median of {repeats} runs of "
           "matching and the confidence filters.", "",
           "| matcher | s | CPU s | coverage | median error px | p95 error px | confident px off by > 1 px |",
           "|---|---|---|---|---|---|---|"]
    for r in synthetic:
        out.append(f"| {r['matcher']} | {r['seconds']:.2f} | {r['cpu_s']:.2f} | {100 * r['coverage']:.1f} % | "
                   f"{r['median_px']:.3f} | "
                   f"{r['p95_px']:.3f} | {100 * r['bad1']:.2f} % |")
    out += ["", "## 3. Stereo depth, Hamlyn heart phantom (no ground truth)", "",
            f"Time: rectification + matching + confidence filters, median of {repeats} runs. Coverage: confident "
            "depth over the rectified image's data pixels. 640x480 is the frame up-sampled (timing only).", "",
            "| input | rectified | matcher | s | CPU s | coverage | depth p5 / p50 / p95 mm |",
            "|---|---|---|---|---|---|---|"]
    for r in hamlyn:
        out.append(f"| {r['size']} | {r['rectified']} | {r['matcher']} | {r['seconds']:.2f} | {r['cpu_s']:.2f} | "
                   f"{100 * r['coverage']:.1f} % | {r['p5_mm']:.1f} / {r['p50_mm']:.1f} / {r['p95_mm']:.1f} |")
    for r in hamlyn:
        if "sgbm_vs_elas" in r:
            c = r["sgbm_vs_elas"]
            out.append(f"\nAt {r['size']}, where both are confident ({c['pixels']:,} px), SGBM and ELAS depths differ "
                       f"by a median {c['median_mm']:.3f} mm (p95 {c['p95_mm']:.3f} mm).")
    if len(matchers()) == 1:
        out.append("\nELAS rows are missing: pyelas is not installed here.")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer variants and sizes, one timing run")
    ap.add_argument("--repeats", type=int, default=None, help="timing runs (median kept; default 3, quick 1)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "capture.md"),
                    help="markdown report (default benchmarks/results/capture.md; '' to skip)")
    args = ap.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    if not SHARED.is_dir():
        print(f"{SHARED} is absent: the capture benchmark needs the Redwood and Hamlyn samples", file=sys.stderr)
        return 0
    t0, load_start = time.perf_counter(), round(os.getloadavg()[0], 2)
    print("fusion (Redwood, 5 frames):", flush=True)
    fusion_rows, extra = bench_fusion(repeats, args.quick)
    print("stereo:", flush=True)
    synthetic = bench_stereo_synthetic(repeats)
    hamlyn = bench_stereo_hamlyn(repeats, args.quick)
    settings = {"quick": args.quick, "repeats": repeats, "python": platform.python_version(),
                "machine": f"{platform.machine()}, {len(os.sched_getaffinity(0))} CPUs",
                "load_average_1min": [load_start, round(os.getloadavg()[0], 2)],
                "software": software_versions(), "elas": elas_available()}
    lines = ["# Capture benchmark (`benchmarks/bench_capture.py`)", "",
             f"Settings: `{json.dumps(settings)}`. The machine is shared (load average at start and end above, "
             "for 2 cores): wall times vary with the load; CPU times less so.", "",
             *fusion_markdown(fusion_rows, extra, repeats), *stereo_markdown(synthetic, hamlyn, repeats), "",
             f"Benchmark wall time {time.perf_counter() - t0:.0f} s."]
    text = "\n".join(lines) + "\n"
    print()
    print(text)
    if args.out:
        write_results(args.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
