"""``make bench``: run every benchmark in turn (each prints its figures and settings)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCHMARKS = ["bench_mesh.py", "bench_fill.py", "bench_render.py"]

if __name__ == "__main__":
    status = 0
    for name in BENCHMARKS:
        if not (HERE / name).is_file():
            continue
        print(f"\n=== {name} ===", flush=True)
        status |= subprocess.run([sys.executable, str(HERE / name), *sys.argv[1:]]).returncode
    sys.exit(status)
