"""The README's Python example runs as written (from a folder holding the bundled sample)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_readme_python_api_example_runs(tmp_path):
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Python API"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    (tmp_path / "data_samples").symlink_to(REPO / "data_samples")
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "PASS" in result.stdout
    assert (tmp_path / "out" / "dataset" / "geometry" / "000003.npz").is_file()  # the tissue breathes
    assert len(list((tmp_path / "out" / "kitti").rglob("*.png"))) >= 4  # the export ran
