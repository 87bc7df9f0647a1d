#!/usr/bin/env python3
"""The sensor's vignetting default: the real frame's radial fall-off over the fall-off the render already has.

Usage: ``python benchmarks/bench_vignetting.py [--out MD]``

A real scope's frame falls off towards the rim through its light (inverse square of the distance, the angle
of incidence, the beam's profile) and its optics (vignetting, the field stop). A render has the light already:
the scene's lights sit at the scope's tip. The sensor's vignetting map must add only the rest, so it is fitted
on the digital twin of the Hamlyn frame (``bench_twin.py``'s scene, ``--path capture``: the same view):

1. the twin (default scene, ``wet_tissue``) and, for the shading alone, the same twin with ``--material
   as_captured`` (unlit: the texture's colours exactly), each rendered at frame 0 with ``--no-vignetting
   --no-noise --exposure fixed --exposure-gain 0.4`` (no ring clips; the clipped share is printed);
2. per eye, on the valid area (``bench_twin.VALID``) where the rendered eye sees the surface, the linear
   luminance profile in 10 rings of rho (:func:`rgbd2scene.sensor.estimate.radial_profile`, 90th percentile as
   :func:`~rgbd2scene.sensor.estimate.radial_falloff` takes it) of the real frame, the render and the texture
   as the twin shows it; and the median per ring of render / texture, the render's own shading;
3. fits of :func:`~rgbd2scene.sensor.estimate.vignetting_from_profiles` (least squares on the ratio per ring
   with a free level): real / render (what the sensor must add to this render) and real / shading (what the
   optics would be if the texture held the albedo alone).

The LEFT eye sets the default; the RIGHT eye is held out. Writes ``benchmarks/results/vignetting.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import HAMLYN, LEFT, RIGHT, VALID, _cli  # noqa: E402
from results_file import write_results  # noqa: E402

from rgbd2scene.dataset.reader import Dataset  # noqa: E402
from rgbd2scene.files.images import read_image  # noqa: E402
from rgbd2scene.sensor import SensorOptions  # noqa: E402
from rgbd2scene.sensor.estimate import (  # noqa: E402
    RadialFalloff,
    linear_luminance,
    radial_falloff,
    radial_profile,
    vignetting_from_profiles,
)

WORK = ROOT / "bench_out" / "vignetting"
GAIN = 0.4
SENSOR = ["--no-vignetting", "--no-noise", "--exposure", "fixed", "--exposure-gain", str(GAIN)]


def twin(material: str) -> Dataset:
    """The twin with ``material``, rendered without vignetting or noise at the fixed gain (cached)."""
    scene, dataset = WORK / f"scene_{material}", WORK / f"dataset_{material}"
    if not (scene / "scene.json").is_file():
        _cli("scene", "--left", str(LEFT), "--right", str(RIGHT), "--stereo-calib", str(HAMLYN), "--path",
             "capture", "--no-overview", "--material", material, "-o", str(scene))
    if not (dataset / "dataset.json").is_file():
        _cli("render", str(scene), "-o", str(dataset), "--frames", "1", "--quiet", "--no-sheet", *SENSOR)
    return Dataset(dataset)


def _v(fit: RadialFalloff, rho: float) -> float:
    return float(np.clip(fit.at(rho), 0.0, 1.0))


def eye_figures(eye: str, real_rgb: np.ndarray, render: Dataset, flat: Dataset) -> list[str]:
    """The markdown section of one eye: its ring profiles and the fits (module docstring, steps 2-3)."""
    rgb, texture = render.rgb(eye, 0), flat.rgb(eye, 0)
    mask = np.zeros(rgb.shape[:2], bool)
    mask[VALID] = True
    mask &= np.isfinite(render.gt(eye, 0, ("depth",))["depth"])
    y_real, y_render, y_texture = (linear_luminance(x) for x in (real_rgb, rgb, texture))
    mask &= y_texture > 1e-3  # the shading below is a ratio: leave out the texture's black pixels
    shading = y_render / np.maximum(y_texture, 1e-3)
    profiles = {"real": radial_profile(y_real, mask), "render": radial_profile(y_render, mask),
                "texture": radial_profile(y_texture, mask),
                "shading": radial_profile(shading, mask, percentile=50.0)}
    fits = {"real / render": vignetting_from_profiles(profiles["real"], profiles["render"]),
            "real / shading": vignetting_from_profiles(profiles["real"], profiles["shading"]),
            "real alone (radial_falloff)": radial_falloff(real_rgb, mask=mask)}
    rings = profiles["real"].rings
    lines = [f"### {eye} eye: {int(mask.sum())} pixels measured, render clipped share "
             f"{float((rgb[mask] >= 255).any(axis=-1).mean()):.4f}", "",
             "Levels per ring (each over its brightest ring with rho < 0.5):", "",
             "| profile | " + " | ".join(f"rho {r:.2f}" for r in rings) + " |", "|---" * (rings.size + 1) + "|"]
    lines.append("| pixels | " + " | ".join(str(c) for c in profiles["real"].count) + " |")
    for name, prof in profiles.items():
        rel = prof.levels / prof.levels[prof.rings < 0.5].max()
        lines.append(f"| {name} | " + " | ".join(f"{v:.3f}" for v in rel) + " |")
    for name, fit in fits.items():
        if name.startswith("real /"):
            lines.append(f"| ratio {name} / level | " + " | ".join(f"{v:.3f}" for v in fit.profile) + " |")
    lines += ["", "| fit | k1 | k2 | V(0.5) | V(0.7) | V(0.9) | V(1) |", "|---|---|---|---|---|---|---|"]
    for name, fit in fits.items():
        lines.append(f"| {name} | {fit.k1:.3f} | {fit.k2:.3f} | "
                     + " | ".join(f"{_v(fit, r):.3f}" for r in (0.5, 0.7, 0.9, 1.0)) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/vignetting.md)")
    args = ap.parse_args(argv)
    if not HAMLYN.is_dir():
        print(f"skipped: {HAMLYN} is absent")
        return 0
    WORK.mkdir(parents=True, exist_ok=True)
    render, flat = twin("wet_tissue"), twin("as_captured")
    opts = SensorOptions()
    parts = ["# Vignetting: the real frame's fall-off over the render's (`benchmarks/bench_vignetting.py`)", "",
             f"Twin of the Hamlyn frame (--path capture, frame 0, 360x288), rendered with {' '.join(SENSOR)}; "
             "the left eye sets the default, the right eye is held out. V values are clipped to [0, 1] as the "
             f"sensor applies them. Default now: k1 {opts.vignetting_k1:g}, k2 {opts.vignetting_k2:g}"
             f"{'' if opts.vignetting else ' (vignetting off)'}.", ""]
    for eye, path in (("left", LEFT), ("right", RIGHT)):
        parts += eye_figures(eye, read_image(path), render, flat) + [""]
    text = "\n".join(parts)
    print(text)
    out = Path(args.out) if args.out else ROOT / "benchmarks" / "results" / "vignetting.md"
    write_results(out, text)
    print(f"-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
