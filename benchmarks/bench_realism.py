#!/usr/bin/env python3
"""Realism benchmark: rendered tissue against real stereo-endoscope frames, old look against the new default.

Usage: ``python benchmarks/bench_realism.py [--quick] [--out MD]``

Real frames: the Hamlyn silicone heart phantom (``../shared/rgbd_samples/hamlyn_silicone_heart_phantom_stereo``,
left and right image of one stereo frame, 360x288), cropped to the valid area (rows 8-287, columns 8-351:
without the on-screen overlay in the top rows and the black and blue frame columns at the sides).

Rendered frames: the bundled sample ``data_samples/tissue`` through ``rgbd2scene scene`` (scan path of
60 frames, default rig 512x256) and ``rgbd2scene render`` (library render defaults, RGB only), frames
spread along the path, both eyes, every pixel. Looks (scene options; everything else the defaults):

* ``old``: ``--highlights keep --tissue-detail off`` (the look before issue 8, part 2);
* ``new``: the defaults (``--highlights remove --tissue-detail on``);
* full run only, to tell the two changes apart: ``highlights removed`` (``--tissue-detail off``) and
  ``detail only`` (``--highlights keep``).

Statistics, per real frame and pooled over a look's images (both eyes, all frames), on the luminance
(Rec. 601 weights of the 8-bit sRGB values) divided by its mean (contrast: exposure does not count):

* **radially averaged power spectrum** (Hann window, power per pixel) in log-spaced bands of spatial
  frequency (cycles per pixel): the band means in dB, the slope of log power against log frequency over
  0.02-0.4 cycles/px, and the distance of the curve to the real frame's (RMS of the dB difference over
  all bands);
* **gradient magnitude** of the contrast image (central differences, per pixel): mean, 50th, 90th and
  99th percentile, and the excess kurtosis of the gradient components (heavy tails: sharp edges and
  small highlights in a smooth image);
* **colour**: mean HSV saturation, and the fraction of near-white pixels (max channel >= 0.94, saturation
  <= 0.15, the highlight cores of ``rgbd2scene.reconstruct.texture``).

For each statistic it prints the real frames' values, each look's, and the distance of the old and the
new look to the real left frame (spectrum: dB RMS; others: |log(look / real)|, the factor apart) and
their ratio new/old (below 1: the new look is closer), then the same against the right frame. The rows
where the new look is farther than the old one are listed at the end.

Caveats: the real frames show another object (a yellow silicone heart phantom, not the pink liver-like
organ of the sample), so the colour statistics compare content as much as look; the luminance-contrast
spectrum and gradients are the measures of fine structure. The two real frames are the two eyes of one
stereo frame, not independent scenes. The ``TissueDetail`` defaults were chosen with this benchmark
(a small grid over ``scale_m``, ``bump_height_m`` and ``mottle_strength``) against the left frame; the
right frame is the check.

``--quick`` renders 2 frames per look at 256x128 (about 1 minute); the full run 6 frames at 512x256 and the
two ablation looks (about 5 minutes on 2 cores) and writes ``benchmarks/results/realism.md``.
"""

from __future__ import annotations

import argparse
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # results_file

from results_file import write_results  # noqa: E402

from rgbd2scene.files.images import read_image  # noqa: E402
from rgbd2scene.realism import measures  # noqa: E402
from rgbd2scene.stages.render import render_dataset  # noqa: E402
from rgbd2scene.versions import software_versions  # noqa: E402

SAMPLE = ROOT / "data_samples" / "tissue"
HAMLYN = ROOT.parent / "shared" / "rgbd_samples" / "hamlyn_silicone_heart_phantom_stereo"
REAL_FRAMES = {"real L": "f7_dynamic_deint_L_0100.png", "real R": "f7_dynamic_deint_R_0100.png"}
#: Valid area of the Hamlyn frames: no overlay (top rows), no frame columns (both sides).
REAL_CROP = (slice(8, 288), slice(8, 352))
WORK = ROOT / "bench_out" / "realism"
PATH_FRAMES = 60
FRAMES = (5, 15, 25, 35, 45, 55)
QUICK_FRAMES = (15, 45)
SIZE = (512, 256)
QUICK_SIZE = (256, 128)
#: look name -> scene options
LOOKS = {"old": ["--highlights", "keep", "--tissue-detail", "off"],
         "new": [],
         "highlights removed": ["--tissue-detail", "off"],
         "detail only": ["--highlights", "keep"]}
QUICK_LOOKS = ("old", "new")
#: Spectrum bands: log-spaced edges in cycles per pixel; the slope is fitted over SLOPE_RANGE.
BAND_EDGES = np.geomspace(0.01, 0.5, 9)
SLOPE_RANGE = (0.02, 0.4)
#: A fraction of zero (no near-white pixel at all) is scored as this many.
FRACTION_FLOOR = 1e-6


# --- statistics (the measures live in rgbd2scene.realism.measures) -----------------------------------------

@dataclass
class Stats:
    """The statistics of one image or of a pool of images (see the module docstring)."""

    band_db: np.ndarray  # mean power per band, dB
    slope: float
    gradient: dict[str, float]
    colour: dict[str, float]

    def scalars(self) -> dict[str, float]:
        return {"spectrum slope": self.slope, **self.gradient, **self.colour}


def image_stats(images: list[np.ndarray]) -> Stats:
    """Statistics pooled over ``images`` (RGB uint8): spectra averaged per band, pixels pooled."""
    band_db = measures.band_power_db([measures.power_spectrum(measures.contrast_image(img)) for img in images],
                                     BAND_EDGES)
    slope = measures.spectral_slope(band_db, BAND_EDGES, SLOPE_RANGE)
    components = [measures.gradients(img) for img in images]
    gradient = measures.gradient_stats(np.concatenate([c[0] for c in components]),
                                       np.concatenate([c[1] for c in components]))
    pooled = np.concatenate([img.reshape(-1, 1, 3) for img in images])
    colour = {"saturation mean": measures.mean_saturation(pooled),
              "near-white fraction": measures.highlight_share(pooled)}
    return Stats(band_db, slope, gradient, colour)


def spectrum_distance(a: Stats, b: Stats) -> float:
    """RMS over the bands of the difference of the two spectra, dB."""
    return float(np.sqrt(np.mean((a.band_db - b.band_db) ** 2)))


def scalar_distance(value: float, real: float) -> float:
    """|log(value / real)|, how many e-folds apart (a zero value counts as ``FRACTION_FLOOR``); negative
    statistics (the slope): |value - real|."""
    if value >= 0 and real > 0:
        return abs(float(np.log(max(value, FRACTION_FLOOR) / real)))
    return abs(value - real)


def mean_scalar_distance(look: Stats, real: Stats) -> float:
    """Mean :func:`scalar_distance` over the gradient and colour statistics."""
    values = {**look.gradient, **look.colour}
    return float(np.mean([scalar_distance(v, {**real.gradient, **real.colour}[k]) for k, v in values.items()]))


# --- renders ----------------------------------------------------------------------------------------------

@dataclass
class Look:
    """A look's rendered images (RGB, both eyes of every frame) and the median CPU seconds per stereo frame."""

    images: list[np.ndarray]
    cpu_s: float


def _cli(*args: str) -> None:
    cmd = [sys.executable, "-c", "import sys; from rgbd2scene.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"failed: rgbd2scene {' '.join(args)}\n{proc.stderr[-2000:]}")


def render_look(name: str, options: list[str], frames: tuple[int, ...], size: tuple[int, int]) -> Look:
    """Build the look's scene from the bundled sample and render ``frames`` (both eyes, one worker each)."""
    folder = WORK / name.replace(" ", "_")
    if folder.exists():
        shutil.rmtree(folder)
    scene = folder / "scene"
    _cli("scene", "--rgb", str(SAMPLE / "rgb.png"), "--depth", str(SAMPLE / "depth.png"),
         "--camera", str(SAMPLE / "camera.json"), "--frames", str(PATH_FRAMES), "--no-overview",
         *options, "-o", str(scene))
    images, cpu = [], []
    for f in frames:
        # one dataset folder per frame: resuming a gt="none" dataset fails its settings check (render.gt: the
        # stored [] reads back as "" against "none")
        dataset = folder / f"dataset_{f:06d}"
        summary = render_dataset(scene, dataset, start=f, end=f + 1, gt="none", size=size, progress=False)
        cpu.append(summary["cpu_seconds_per_frame"])
        images += [read_image(dataset / eye / "rgb" / f"{f:06d}.png") for eye in ("left", "right")]
    return Look(images, float(np.median(cpu)))


def real_frames() -> dict[str, np.ndarray]:
    out = {}
    for name, file in REAL_FRAMES.items():
        img = read_image(HAMLYN / file)
        if img is None:
            raise RuntimeError(f"{HAMLYN / file}: not readable")
        out[name] = img[REAL_CROP]
    return out


# --- report -----------------------------------------------------------------------------------------------

def band_labels() -> list[str]:
    return [f"power {lo:.3f}-{hi:.3f} c/px, dB" for lo, hi in zip(BAND_EDGES[:-1], BAND_EDGES[1:], strict=True)]


def comparison_table(stats: dict[str, Stats], real: str, looks: list[str]) -> tuple[str, list[str]]:
    """Markdown table of every statistic, with the old and new looks' distances to ``real``; rows lost."""
    names = [*REAL_FRAMES, *looks]
    head = f"| statistic | {' | '.join(names)} | old to {real} | new to {real} | new / old |"
    lines = [head, "|---" * (len(names) + 4) + "|"]
    lost = []

    def row(label: str, values: list[float], d_old: float, d_new: float, fmt: str) -> None:
        ratio = d_new / d_old if d_old > 0 else float("inf") if d_new > 0 else 1.0
        mark = " **farther**" if d_new > d_old else ""
        lines.append(f"| {label} | {' | '.join(format(v, fmt) for v in values)} | {d_old:.3f} | {d_new:.3f} | "
                     f"{ratio:.2f}{mark} |")
        if d_new > d_old:
            lost.append(f"{label} (to {real}): old {d_old:.3f}, new {d_new:.3f}")

    ref = stats[real]
    for b, label in enumerate(band_labels()):
        row(label, [stats[n].band_db[b] for n in names], abs(stats["old"].band_db[b] - ref.band_db[b]),
            abs(stats["new"].band_db[b] - ref.band_db[b]), ".1f")
    row("**spectrum distance, dB RMS**", [spectrum_distance(stats[n], ref) for n in names],
        spectrum_distance(stats["old"], ref), spectrum_distance(stats["new"], ref), ".2f")
    for key, value in ref.scalars().items():
        row(key, [stats[n].scalars()[key] for n in names], scalar_distance(stats["old"].scalars()[key], value),
            scalar_distance(stats["new"].scalars()[key], value), ".4g")
    return "\n".join(lines), lost


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 frames at 256x128, old and new looks only")
    ap.add_argument("--out", default=None, help="markdown report (default benchmarks/results/realism.md, quick: "
                    "bench_out/realism/realism.md; '' to skip)")
    args = ap.parse_args(argv)
    if not HAMLYN.is_dir():
        print(f"error: the real frames are absent: {HAMLYN}", file=sys.stderr)
        return 2
    out_md = args.out if args.out is not None else str(
        WORK / "realism.md" if args.quick else ROOT / "benchmarks" / "results" / "realism.md")
    frames, size = (QUICK_FRAMES, QUICK_SIZE) if args.quick else (FRAMES, SIZE)
    looks = list(QUICK_LOOKS if args.quick else LOOKS)
    t0 = time.perf_counter()
    WORK.mkdir(parents=True, exist_ok=True)

    versions = software_versions()
    settings = {"frames": ", ".join(map(str, frames)), "size": f"{size[0]}x{size[1]}", "path": f"scan, "
                f"{PATH_FRAMES} frames", "render": "library defaults, RGB only", "quick": args.quick,
                "python": versions["python"], "bpy": versions["bpy"], "machine": platform.machine()}
    print("settings: " + ", ".join(f"{k} {v}" for k, v in settings.items()), flush=True)
    stats = {name: image_stats([img]) for name, img in real_frames().items()}
    cpu = {}
    for look in looks:
        t = time.perf_counter()
        rendered = render_look(look, LOOKS[look], frames, size)
        stats[look], cpu[look] = image_stats(rendered.images), rendered.cpu_s
        print(f"  {look}: {len(rendered.images)} images, {rendered.cpu_s:.2f} s CPU per stereo frame, "
              f"{time.perf_counter() - t:.0f} s", flush=True)
    cost = ("Render cost (median CPU seconds per stereo frame; one worker per frame, so each includes loading "
            "the scene and building its BVH): " + ", ".join(f"{k} {v:.2f} s" for k, v in cpu.items())
            + f"; new / old = {cpu['new'] / cpu['old']:.2f}.")
    print(cost, flush=True)

    parts = [f"# Realism benchmark (`benchmarks/bench_realism.py{' --quick' if args.quick else ''}`)", "",
             "Rendered frames of the bundled sample against the real Hamlyn phantom frames (left, right), "
             "statistics of the luminance contrast (method and caveats: see the script's docstring; the "
             "real frames show a yellow silicone phantom, the sample a pink organ, so colour statistics compare "
             "content too; the detail defaults were tuned against real L, real R is the check). Settings: "
             + ", ".join(f"{k}: {v}" for k, v in settings.items()) + "."]
    verdicts = []
    for real in REAL_FRAMES:
        table, lost = comparison_table(stats, real, looks)
        d_old, d_new = (spectrum_distance(stats[n], stats[real]) for n in ("old", "new"))
        scalar_old, scalar_new = (mean_scalar_distance(stats[n], stats[real]) for n in ("old", "new"))
        verdict = (f"Against {real}: spectrum distance old {d_old:.2f} dB -> new {d_new:.2f} dB "
                   f"(x{d_new / d_old:.2f}); mean distance of the gradient and colour statistics old "
                   f"{scalar_old:.3f} -> new {scalar_new:.3f} (x{scalar_new / scalar_old:.2f}). Rows where the new "
                   "look is farther: "
                   + ("; ".join(lost) if lost else "none") + ".")
        verdicts.append(verdict)
        print(f"\n{table}\n\n{verdict}", flush=True)
        parts += ["", f"## Against {real}", "", table, "", verdict]
    wall = time.perf_counter() - t0
    parts += ["", "## Summary", "", *[f"- {v}" for v in verdicts], "", cost, "", f"Benchmark wall time {wall:.0f} s."]
    print(f"\nbenchmark wall time {wall:.0f} s", flush=True)
    if out_md:
        write_results(out_md, "\n".join(parts) + "\n")
        print(f"report: {out_md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
