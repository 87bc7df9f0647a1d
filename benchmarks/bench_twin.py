#!/usr/bin/env python3
"""Digital-twin benchmark: the Hamlyn stereo frame rebuilt as a scene, rendered with the defaults, and compared
with the real pair by ``rgbd2scene realism`` (every figure as render / real, issue 15's goal bands).

Usage: ``python benchmarks/bench_twin.py [--out MD] [--delight auto|on|off] [--delight-smooth PX]
[--smooth-iterations N] [--work DIR]`` (``--delight*`` and ``--smooth-iterations`` passed to the scene stage;
default: the scene stage's defaults)

Real frames: the Hamlyn silicone heart phantom (``../shared/rgbd_samples/hamlyn_silicone_heart_phantom_stereo``,
one stereo frame, 360x288, calibrated). Measured pixels: the valid area (rows 8-287, columns 8-351: without the
on-screen overlay in the top rows and the black and blue frame columns at the sides; written as a mask PNG and
passed as ``--real-mask``) where the rendered eye sees the twin's surface (``--surface-only``: the mesh covers
only the part of the view where stereo matching found confident depth). The sample's own mask file (a disc of
6 % of the image) is a region of interest, not the valid area, and is not used.

The twin:

1. ``rgbd2scene scene --left L --right R --stereo-calib HAMLYN --path capture`` (the scope is the calibrated
   pair at the capture's own pose, CONVENTIONS 1.2).
2. ``rgbd2scene render --frames 1`` with the defaults, at the capture's own size (360x288).
3. ``rgbd2scene realism`` of frame 0 against the real pair. A rectified dataset's pair is matched as rendered and
   the real pair after rectification with its calibration (``--real-calib``); a raw dataset and the real pair
   are both rectified with the dataset's ``calibration.yaml``.

Protocol (issue 15): defaults are tuned on one eye and reported on the other. The ``TissueDetail`` defaults were
tuned against the real left frame (``bench_realism.py``), so the right eye is the held-out one: the figures are
printed per eye, with a count of the rows within their band for each; the stereo rows describe the pair.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.files.images import write_image  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

HAMLYN = ROOT.parent / "shared" / "rgbd_samples" / "hamlyn_silicone_heart_phantom_stereo"
LEFT, RIGHT = HAMLYN / "f7_dynamic_deint_L_0100.png", HAMLYN / "f7_dynamic_deint_R_0100.png"
SIZE = (360, 288)
#: Valid area of the Hamlyn frames: no overlay (top rows), no frame columns (both sides).
VALID = (slice(8, 288), slice(8, 352))
WORK = ROOT / "bench_out" / "twin"
HELD_OUT_EYE = "right"


def _cli(*args: str) -> str:
    cmd = [sys.executable, "-c", "import sys; from rgbd2scene.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"failed: rgbd2scene {' '.join(args)}\n{proc.stderr[-2000:]}")
    return proc.stdout


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/twin.md; '' to skip)")
    ap.add_argument("--delight", choices=("auto", "on", "off"), default=None,
                    help="the scene stage's --delight (default: its default)")
    ap.add_argument("--delight-smooth", default=None, help="the scene stage's --delight-smooth (texels)")
    ap.add_argument("--smooth-iterations", default=None,
                    help="the scene stage's --smooth-iterations (ray smoothing of the stereo mesh)")
    ap.add_argument("--work", default=str(WORK), help=f"work folder, emptied first (default {WORK})")
    args = ap.parse_args(argv)
    work = Path(args.work)
    scene_args = [arg for flag, value in (("--delight", args.delight), ("--delight-smooth", args.delight_smooth),
                                          ("--smooth-iterations", args.smooth_iterations))
                  if value is not None for arg in (flag, value)]
    if not HAMLYN.is_dir():
        print(f"error: the real frames are absent: {HAMLYN}", file=sys.stderr)
        return 2
    out_md = args.out if args.out is not None else str(ROOT / "benchmarks" / "results" / "twin.md")
    t0 = time.perf_counter()
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    versions = software_versions()
    print(f"settings: --path capture, frame 0, scene {' '.join(scene_args) or 'defaults'}, "
          f"size {SIZE[0]}x{SIZE[1]}, render defaults, "
          f"python {versions['python']}, bpy {versions['bpy']}, "
          f"machine {platform.machine()}", flush=True)

    scene, dataset, out = work / "scene", work / "dataset", work / "realism"
    t = time.perf_counter()
    _cli("scene", "--left", str(LEFT), "--right", str(RIGHT), "--stereo-calib", str(HAMLYN), "--path", "capture",
         "--no-overview", *scene_args, "-o", str(scene))
    t_scene = time.perf_counter() - t
    t = time.perf_counter()
    _cli("render", str(scene), "-o", str(dataset), "--frames", "1", "--quiet", "--no-sheet")
    t_render = time.perf_counter() - t
    meta = json.loads((dataset / "dataset.json").read_text())
    raw = (meta.get("camera") or {}).get("rectified") is False
    mask = np.zeros((SIZE[1], SIZE[0]), np.uint8)
    mask[VALID] = 255
    write_image(work / "valid_area.png", mask)
    t = time.perf_counter()
    real_calib = [] if raw else ["--real-calib", str(HAMLYN)]
    _cli("realism", str(dataset), "--real", str(LEFT), str(RIGHT), "--real-mask", str(work / "valid_area.png"),
         "--surface-only", *real_calib, "-o", str(out))
    t_realism = time.perf_counter() - t
    report = json.loads((out / "realism.json").read_text())
    table = "\n".join(line for line in (out / "realism.md").read_text().splitlines() if line.startswith("|"))

    lines = []
    for eye in ("left", "right", "pair"):
        rows = [r for r in report["rows"] if r["eye"] == eye]
        if not rows:
            continue
        missed = [r for r in rows if not r["within"]]
        role = {"left": "tuned-on eye", "right": "held-out eye", "pair": "stereo difficulty"}[eye]
        ratio = ", ".join(f"{r['measure']} {r['ratio']:.3g}" if r["ratio"] is not None else f"{r['measure']} inf"
                          for r in missed)
        lines.append(f"{eye} ({role}): {len(rows) - len(missed)} of {len(rows)} within the band"
                     + (f"; misses: {ratio}" if missed else ""))
    timing = (f"scene {t_scene:.1f} s, render {t_render:.1f} s, realism {t_realism:.1f} s, wall "
              f"{time.perf_counter() - t0:.1f} s")
    print(f"\n{table}\n", flush=True)
    for line in lines + [f"dataset: {'raw' if raw else 'rectified'}; " + "; ".join(report["notes"]), timing,
                         f"picture: {out / 'realism.png'}"]:
        print(line, flush=True)
    if out_md:
        parts = ["# Digital twin of the Hamlyn frame (`benchmarks/bench_twin.py`)", "",
                 "Twin path: --path capture, frame 0. "
                 f"Render defaults at {SIZE[0]}x{SIZE[1]}; measured pixels: the valid area where "
                 "the rendered eye sees the surface (method: the script's docstring). Goal bands (issue 15): "
                 "image figures 0.8-1.25, stereo difficulty 0.85-1.2. The right eye is held out (the detail "
                 "defaults were tuned on the left frame).", "", table, "", *[f"- {line}" for line in lines], "",
                 f"Notes: {'; '.join(report['notes']) or 'none'}. Software: python {versions['python']}, bpy "
                 f"{versions['bpy']}; {timing}."]
        write_results(out_md, "\n".join(parts) + "\n")
        print(f"report: {out_md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
