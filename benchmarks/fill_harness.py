#!/usr/bin/env python3
"""Quick scoring of ``auto`` on a split of the fill benchmark, for working on the fill.

Usage: ``python benchmarks/fill_harness.py [--split tune|heldout|report] [--captures a,b] [--families a,b]
[--rows] [--save FILE] [--compare FILE] [--jobs N]``

Scores exactly as ``bench_fill.py`` does (its cases, its all-pixel MAE, auto over the row's best reference
method), but caches the reference methods' scores per case under ``benchmarks/.cache/`` (or
``$FILL_HARNESS_CACHE``; keyed by the case and a checksum of its input), so that a rerun after a change of
the fill runs only ``auto``. Prints the geometric mean of auto / best reference, the rows above 1.10 and the
worst row; ``--save`` writes every row's ratio (one line each), ``--compare`` prints the rows whose ratio moved
by more than 0.5 % against such a file. The results files are written by ``bench_fill.py`` alone.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_fill as bf  # noqa: E402

#: Shared between worktrees with FILL_HARNESS_CACHE=DIR.
CACHE = Path(os.environ.get("FILL_HARNESS_CACHE", Path(__file__).resolve().parent / ".cache"))


def _key(case: dict) -> str:
    h = hashlib.sha256(np.ascontiguousarray(case["depth"]).tobytes())
    for name, m in case["scored"].items():
        h.update(name.encode() + np.packbits(m).tobytes())
    return f"{case['capture'].name}/{case['family']}/{case['seed']}/{h.hexdigest()[:16]}"


def _references(case: dict) -> dict[str, dict[str, float]]:
    """Each scored pixel set's all-pixel MAE per reference method (mm)."""
    cap, depth = case["capture"], case["depth"]
    fallback = float(np.nanmedian(depth))
    out = {}
    for name in bf.REFERENCE:
        est_full = bf.PLAIN[name](depth, cap.rgb)
        if est_full is None:
            continue
        for label, hidden in case["scored"].items():
            est, truth = est_full[hidden].astype(np.float64), cap.truth[hidden].astype(np.float64)
            err = np.abs(np.where(np.isfinite(est), est, fallback) - truth) * 1000.0
            out.setdefault(label, {})[name] = float(err.mean())
    return out


def _auto(case: dict) -> dict[str, float]:
    cap, depth = case["capture"], case["depth"]
    res = bf.fill_depth(depth, cap.rgb, "auto", sensor=bf.SENSORS[cap.sensor], fx=bf.FX)
    fallback = float(np.nanmedian(depth))
    out = {}
    for label, hidden in case["scored"].items():
        est, truth = res.depth[hidden].astype(np.float64), cap.truth[hidden].astype(np.float64)
        out[label] = float((np.abs(np.where(np.isfinite(est), est, fallback) - truth) * 1000.0).mean())
    return out


def _score(case: dict, refs: dict | None) -> tuple[dict, dict]:
    return (refs if refs is not None else _references(case)), _auto(case)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=tuple(bf.SPLITS), default="tune")
    ap.add_argument("--captures", default="", help="comma-separated capture names (default: the split's)")
    ap.add_argument("--families", default=",".join((*bf.FAMILIES, "sensor")))
    ap.add_argument("--rows", action="store_true", help="print every row")
    ap.add_argument("--save", default="", help="write every row's ratio to this file")
    ap.add_argument("--compare", default="", help="print the rows that moved against a --save file")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    split = bf.SPLITS[args.split]
    names = set(args.captures.split(",")) if args.captures else split["captures"]
    everything = bf.load_captures()
    caps = [c for c in everything if names is None or c.name in names]
    cases = bf.build_cases(caps, tuple(args.families.split(",")), split["seeds"], bf.hole_masks(everything),
                           avoid=split["avoid"])
    CACHE.mkdir(exist_ok=True)
    cache_file = CACHE / f"{args.split}.json"
    cache = json.loads(cache_file.read_text()) if cache_file.is_file() else {}
    t0 = time.perf_counter()
    keys = [_key(c) for c in cases]
    rows, unsaved = {}, 0
    with ProcessPoolExecutor(args.jobs) if args.jobs > 1 else _Serial() as pool:
        results = pool.map(_score, cases, [cache.get(k) for k in keys])
        for case, key, (refs, auto) in zip(cases, keys, results, strict=True):
            unsaved += key not in cache
            cache[key] = refs
            if unsaved >= 20:  # as it goes: a long first run that is stopped keeps what it computed
                _save(cache_file, cache)
                unsaved = 0
            for label, ref in refs.items():
                best = min(ref, key=ref.get)
                rows[f"{case['capture'].name} {label} {case['seed']}"] = (auto[label] / ref[best], auto[label],
                                                                         best, ref[best])
    _save(cache_file, cache)
    ratios = np.array([r[0] for r in rows.values()])
    if args.rows:
        for name, (ratio, mae, best, ref) in rows.items():
            print(f"{name:28s} {ratio:6.3f} {'*' if ratio > 1.10 else ' '} auto {mae:8.2f} {best} {ref:8.2f}")
    if args.compare:
        before = dict(line.rsplit(" ", 1) for line in Path(args.compare).read_text().splitlines() if line)
        moved = [(n, float(before[n]), r[0]) for n, r in rows.items() if n in before
                 and abs(np.log(r[0] / float(before[n]))) > 0.005]
        for n, b, a in sorted(moved, key=lambda x: x[2] / x[1]):
            print(f"moved {n:28s} {b:6.3f} -> {a:6.3f}")
        print(f"{len(moved)} rows moved of {len(rows)}")
    if args.save:
        Path(args.save).write_text("".join(f"{n} {r[0]:.6f}\n" for n, r in rows.items()))
    worst = max(rows, key=lambda n: rows[n][0])
    print(f"{args.split}: {len(rows)} rows, geomean {np.exp(np.log(ratios).mean()):.4f}, "
          f"{int((ratios > 1.10).sum())} above 1.10, worst {rows[worst][0]:.2f} ({worst}); "
          f"{time.perf_counter() - t0:.0f} s")
    return 0


def _save(cache_file: Path, cache: dict) -> None:
    """Add this run's entries to the cache file (another run may have written it meanwhile; rename is atomic)."""
    latest = json.loads(cache_file.read_text()) if cache_file.is_file() else {}
    tmp = cache_file.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({**latest, **cache}))
    tmp.replace(cache_file)


class _Serial:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    @staticmethod
    def map(fn, *its):
        return map(fn, *its)


if __name__ == "__main__":
    sys.exit(main())
