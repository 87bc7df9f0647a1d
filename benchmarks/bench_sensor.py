#!/usr/bin/env python3
"""Sensor-model defaults: the figures measured on real frames, and the auto exposure they give a render.

Usage: ``python benchmarks/bench_sensor.py [--quick] [--out MD]``

1. **Real frames** (``../shared/rgbd_samples/hamlyn_silicone_heart_phantom_stereo``, one stereo frame, 360x288):
   the estimators of :mod:`rgbd2scene.sensor.estimate` on the LEFT eye (the defaults of
   :class:`rgbd2scene.sensor.SensorOptions` were set from it) and the RIGHT eye (held out): 8-bit luma mean,
   trimmed mean (the auto-exposure target), median, 95th percentile and clipped share (whole frame); the
   Poisson-Gaussian noise fit var = a x + b in the linear domain and the noise sigma per intensity bin;
   the radial fall-off fit V = 1 + k1 rho^2 + k2 rho^4 and its level at rho = 0.5 (8-pixel border left out:
   light and optics together; the vignetting default comes from ``bench_vignetting.py``). Each with the
   default it set and the ratio right / left.
2. **Auto exposure on a render** (skipped with ``--no-render``): the bundled sample ``data_samples/tissue``
   through ``rgbd2scene scene`` (scan path, standoff 2, 4 and 8 cm, default light) and ``rgbd2scene render``
   with the sensor defaults (1 frame per standoff in ``--quick``, 3 otherwise, 256x128, RGB only): the light
   share and sensor gain the auto exposure chose, and the trimmed-mean luma of the clean image against the
   target. ``stages/scene.py``'s ``DEFAULT_LIGHT_W`` was chosen so that the gain is about 1 at 8 cm.

Writes ``benchmarks/results/sensor.md`` (full run) or ``bench_out/sensor/sensor.md`` (``--quick``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.files.images import read_image  # noqa: E402
from rgbd2scene.sensor import SensorOptions  # noqa: E402
from rgbd2scene.sensor.estimate import (  # noqa: E402
    brightness_stats,
    fit_poisson_gaussian,
    luma8,
    noise_curve,
    radial_falloff,
    trimmed_mean,
)

SAMPLE = ROOT / "data_samples" / "tissue"
HAMLYN = ROOT.parent / "shared" / "rgbd_samples" / "hamlyn_silicone_heart_phantom_stereo"
EYES = {"left (tuned)": "f7_dynamic_deint_L_0100.png", "right (held out)": "f7_dynamic_deint_R_0100.png"}
WORK = ROOT / "bench_out" / "sensor"


def real_figures() -> tuple[list[str], dict]:
    defaults = SensorOptions()
    rows: dict[str, list] = {}
    curves = {}
    for eye, name in EYES.items():
        img = read_image(HAMLYN / name)
        b = brightness_stats(img)
        curve = noise_curve(img)
        a, c = fit_poisson_gaussian(curve)
        fall = radial_falloff(img)
        half = 1 + fall.k1 * 0.25 + fall.k2 * 0.0625
        figures = {"luma mean": b.mean, "luma trimmed mean (target)": b.trimmed_mean, "luma median": b.p50,
                   "luma p95": b.p95, "clipped share": b.clipped_fraction, "noise a (shot)": a, "noise b (read)": c,
                   "fall-off k1": fall.k1, "fall-off k2": fall.k2, "fall-off V(0.5)": half}
        for key, value in figures.items():
            rows.setdefault(key, []).append(value)
        curves[eye] = curve
    default_of = {"luma trimmed mean (target)": defaults.target, "noise a (shot)": defaults.noise_shot,
                  "noise b (read)": defaults.noise_read}
    lines = ["| measure | left (tuned) | right (held out) | right / left | default |", "|---|---|---|---|---|"]
    for key, (left, right) in rows.items():
        ratio = f"{right / left:.2f}" if left else "-"
        default = f"{default_of[key]:.4g}" if key in default_of else ""
        lines.append(f"| {key} | {left:.4g} | {right:.4g} | {ratio} | {default} |")
    lines += ["", "The fall-off rows are the frame's whole radial fall-off, its light and its optics together. "
              "A render has the light's fall-off already, so the sensor's vignetting (default k1 "
              f"{defaults.vignetting_k1:g}, k2 {defaults.vignetting_k2:g}) is fitted on the frame's digital twin "
              "instead: `bench_vignetting.py`, `vignetting.md`."]
    lines += ["", "Noise sigma (linear) per intensity bin:", "",
              "| bin mean (linear) | sigma left | sigma right | samples left |", "|---|---|---|---|"]
    left, right = curves["left (tuned)"], curves["right (held out)"]
    for i, m in enumerate(left.mean):
        j = int(np.argmin(np.abs(right.mean - m)))
        lines.append(f"| {m:.4f} | {np.sqrt(left.variance[i]):.5f} | {np.sqrt(right.variance[j]):.5f} | "
                     f"{left.count[i]} |")
    return lines, rows


def render_figures(quick: bool) -> list[str]:
    from rgbd2scene.cli import main as cli

    frames = 1 if quick else 3
    lines = ["| standoff | frame | light share | sensor gain | clean luma trimmed mean | target |",
             "|---|---|---|---|---|---|"]
    target = SensorOptions().target
    for standoff in (0.02, 0.04, 0.08):
        scene, out = WORK / f"scene_{standoff}", WORK / f"ds_{standoff}"
        if not (scene / "scene.json").is_file():
            assert cli(["scene", "--rgb", str(SAMPLE / "rgb.png"), "--depth", str(SAMPLE / "depth.png"),
                        "--camera", str(SAMPLE / "camera.json"), "--frames", str(frames), "--standoff", str(standoff),
                        "-o", str(scene)]) == 0
        assert cli(["render", str(scene), "-o", str(out), "--size", "256x128", "--gt", "none", "--clean", "--quiet",
                    "--no-sheet"]) == 0
        for f in range(frames):
            rec = json.loads((out / "sensor" / f"{f:06d}.json").read_text())
            clean = read_image(out / "left" / "rgb_clean" / f"{f:06d}.png")
            lines.append(f"| {100 * standoff:.0f} cm | {f} | {rec['light']:.3f} | {rec['gain']:.2f} | "
                         f"{trimmed_mean(luma8(clean)):.1f} | {target:.0f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 frame per standoff")
    ap.add_argument("--no-render", action="store_true", help="real-frame figures only (no Blender)")
    ap.add_argument("--out", default=None, help="markdown report")
    args = ap.parse_args(argv)
    if not HAMLYN.is_dir():
        print(f"skipped: {HAMLYN} is absent")
        return 0
    parts = ["# Sensor model: defaults from real frames", "",
             "Real frame: Hamlyn silicone heart phantom, stereo frame 100 (360x288); defaults tuned on the left eye, "
             "the right eye held out. Produced by `python benchmarks/bench_sensor.py`.", ""]
    lines, _ = real_figures()
    parts += lines
    if not args.no_render:
        parts += ["", "## Auto exposure on the bundled sample (default light, sensor defaults)", ""]
        parts += render_figures(args.quick)
    text = "\n".join(parts) + "\n"
    print(text)
    out = Path(args.out) if args.out else (WORK / "sensor.md" if args.quick or args.no_render
                                           else ROOT / "benchmarks" / "results" / "sensor.md")
    write_results(out, text)
    print(f"-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
