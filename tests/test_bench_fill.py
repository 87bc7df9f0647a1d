"""The hole-filling benchmark's masks: the report split's transplanted masks are none of the tuning split's."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_fill", REPO / "benchmarks" / "bench_fill.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_fill"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_shifted_moves_a_mask_and_keeps_a_band_on_the_edge():
    bench = _bench()
    mask = np.zeros((40, 60), bool)
    mask[:, :3] = True  # a band along the left edge
    mask[20:25, 30:35] = True
    moved = bench.shifted(mask, 4, 6)
    assert moved[24:29, 36:41].all() and moved.sum() == 40 * 9 + 25
    assert moved[:, :9].all()  # the band moved away from the edge, and the opened strip repeats it
    assert np.array_equal(bench.shifted(mask, 0, 0), mask)


def test_no_report_transplant_mask_is_a_tuning_mask(shared_samples):
    bench = _bench()
    everything = bench.load_captures()
    caps = [c for c in everything if c.name in ("tum", "tissue")]
    sources = bench.hole_masks(everything)
    tune = bench.build_cases(caps, ("transplant",), range(8), sources, shift=bench.SPLITS["tune"]["shift"])
    report = bench.build_cases(caps, ("transplant",), bench.SPLITS["report"]["seeds"], sources,
                               shift=bench.SPLITS["report"]["shift"])
    unshifted = bench.build_cases(caps, ("transplant",), bench.SPLITS["report"]["seeds"], sources)

    def repeats(cases):
        return [(t["capture"].name, t["seed"], r["seed"]) for t in tune for r in cases if t["capture"] is r["capture"]
                and np.array_equal(t["scored"]["transplant"], r["scored"]["transplant"])]

    assert repeats(unshifted)  # what the shift is for: tuning TUM transplant 2 and 4 were report TUM 12
    assert not repeats(report)
    assert all("shifted" in c["note"] for c in report)
