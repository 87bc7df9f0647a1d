"""The code blocks of a documentation page that are marked ``<!-- tested -->``, and a runner for them.

tests/test_docs.py runs them at tiny sizes (so a page cannot drift from the program); docs/gen_figures.py runs
them as written to make the page's pictures.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_SAMPLES = "../shared/rgbd_samples"  # as a page writes it: the real captures beside the repository
MARKED = re.compile(r"<!-- tested -->\n```(bash|python)\n(.*?)```", re.S)
TINY = [(re.compile(r"--size \d+x\d+"), "--size 64x32"),
        (re.compile(r"(rgbd2scene render .*)--frames \d+"), r"\1--frames 2"),
        (re.compile(r"\bsize: \d+x\d+"), "size: 64x32"),  # a batch configuration's render size and length
        (re.compile(r"^(\s*frames:) \d+", re.M), r"\1 2")]


def marked_blocks(page: Path, tiny: bool = False) -> list[tuple[str, str]]:
    """(language, code) of each block marked ``<!-- tested -->``; with ``tiny``, renders at 64x32, 2 frames."""
    blocks = []
    for language, code in MARKED.findall(page.read_text(encoding="utf-8")):
        for pattern, small in TINY if tiny else ():
            code = pattern.sub(small, code)
        blocks.append((language, code))
    return blocks


def run_blocks(blocks: list[tuple[str, str]], cwd: Path, shared: Path) -> None:
    """Run the blocks in order in ``cwd`` (which gets the bundled sample as ``data_samples``), with
    ``rgbd2scene`` as this interpreter's command line and ``../shared/rgbd_samples`` meaning ``shared``.
    Raises RuntimeError with the block and the tail of its error output when one fails."""
    if not (cwd / "data_samples").exists():
        (cwd / "data_samples").symlink_to(REPO / "data_samples")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    prelude = f'rgbd2scene() {{ "{sys.executable}" -m rgbd2scene.cli "$@"; }}\nset -euo pipefail\n'
    for language, code in blocks:
        code = code.replace(SHARED_SAMPLES, str(shared))
        command = ["bash", "-c", prelude + code] if language == "bash" else [sys.executable, "-c", code]
        result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError(f"this block failed:\n{code}\n{result.stdout[-1500:]}\n{result.stderr[-3000:]}")
