"""The house rules a reader relies on: bpy only in render/ (a lint rule), no state changed at import."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _ruff(path: str, source: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--stdin-filename", path, "-"],
                          input=source, capture_output=True, text=True, cwd=REPO)


@pytest.mark.parametrize("source", ["import bpy\n", "from mathutils import Matrix\n", "import bpy.ops\n"])
def test_lint_rule_bans_blender_imports_outside_render(source):
    for path in ("rgbd2scene/anything.py", "benchmarks/bench_x.py", "tests/test_x.py"):
        result = _ruff(path, source)
        assert result.returncode != 0 and "TID251" in result.stdout, (path, result.stdout)
    assert "TID251" not in _ruff("render/anything.py", source).stdout


def test_importing_the_package_changes_no_process_state():
    """Importing every module of the numpy core leaves the umask and the environment as they were (the
    third-party libraries, some of which set variables of their own, are imported first)."""
    code = ("import os, pkgutil, importlib, rgbd2scene, cv2, open3d, scipy, skimage, pymeshlab, OpenEXR\n"
            "os.umask(0o027); env = dict(os.environ)\n"
            "for m in pkgutil.walk_packages(rgbd2scene.__path__, 'rgbd2scene.'):\n"
            "    importlib.import_module(m.name)\n"
            "assert os.umask(0o027) == 0o027, 'umask changed'\n"
            "changed = sorted(k for k in set(env) | set(os.environ) if env.get(k) != os.environ.get(k))\n"
            "assert not changed, changed\n"
            "import sys; assert 'bpy' not in sys.modules, 'the numpy core imported bpy'\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr[-2000:]
