"""``make bench``: run every benchmark in turn (each prints its figures and settings).

``--quick`` is passed to the benchmarks that have a quick mode; other arguments are not forwarded
(each benchmark has its own options: run it directly for those).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCHMARKS = ["bench_mesh.py", "bench_capture.py", "bench_fill.py", "bench_render.py", "bench_profile.py",
              "bench_realism.py", "bench_twin.py", "bench_vignetting.py", "bench_sensor.py", "bench_stereo.py",
              "bench_export.py", "bench_batch.py", "bench_issue16.py"]
HAS_QUICK = {"bench_capture.py", "bench_fill.py", "bench_render.py", "bench_profile.py", "bench_realism.py",
             "bench_sensor.py",
             "bench_stereo.py", "bench_export.py", "bench_batch.py"}

if __name__ == "__main__":
    status = 0
    for name in BENCHMARKS:
        if not (HERE / name).is_file():
            continue
        print(f"\n=== {name} ===", flush=True)
        quick = ["--quick"] if "--quick" in sys.argv[1:] and name in HAS_QUICK else []
        status |= subprocess.run([sys.executable, str(HERE / name), *quick]).returncode
    sys.exit(status)
