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


def test_report_draws_no_source_and_flip_a_tuning_seed_draws_on_a_tuning_capture():
    bench = _bench()
    sources = ["nyu", "sun", "redwood0", "tissue"]
    tuned = {bench.transplant_draw("tum", s, sources) for s in bench.TUNE_SEEDS}
    report = [bench.transplant_draw("tum", s, sources, disjoint=True) for s in bench.SPLITS["report"]["seeds"]]
    assert not tuned & set(report)
    old = [bench.transplant_draw("tum", s, sources) for s in bench.SPLITS["report"]["seeds"]]
    assert tuned & set(old)  # what it is for: unrestricted, report TUM 11 and 12 were tuning TUM 1, 2 and 4
    # a capture outside the tuning split draws as before
    assert [bench.transplant_draw("sun", s, sources, disjoint=True) for s in (10, 11, 12)] == [
        bench.transplant_draw("sun", s, sources) for s in (10, 11, 12)]


def test_no_report_transplant_mask_is_a_tuning_mask(shared_samples):
    bench = _bench()
    everything = bench.load_captures()
    caps = [c for c in everything if c.name in bench.SPLITS["tune"]["captures"]]
    sources = bench.hole_masks(everything)
    tune = bench.build_cases(caps, ("transplant",), bench.TUNE_SEEDS, sources)
    report = bench.build_cases(caps, ("transplant",), bench.SPLITS["report"]["seeds"], sources,
                               disjoint=bench.SPLITS["report"]["disjoint"])
    assert len(report) == 3 * len(caps)
    assert not [(t["capture"].name, t["seed"], r["seed"]) for t in tune for r in report if t["capture"] is r["capture"]
                and np.array_equal(t["scored"]["transplant"], r["scored"]["transplant"])]
