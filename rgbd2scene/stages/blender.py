"""The one crossing into Blender: a task file, one worker entry point in a fresh process, one progress protocol.

Every stage that needs Blender (building ``scene.blend``, rendering frames) writes a :class:`Task` (JSON:
the action and its payload: the scene model, the options; :mod:`rgbd2scene.worker_protocol`) and runs
``python -m render.worker TASK.json`` through :func:`run_task`. The worker answers on its stdout with the
lines of :data:`PROTOCOL` only (Blender's own output goes to stderr, kept for the error message). A fresh
process per task bounds Blender's memory and keeps ``bpy`` out of the calling process (a CLI, a test, a
benchmark or a Dask worker).

A worker never outlives its parent (:func:`tie_to_parent`): killed with SIGKILL (the out-of-memory killer, a
scheduler), a caller takes its worker with it, instead of leaving it to render on unowned until its next
progress line hits the closed pipe.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rgbd2scene.errors import RenderError
from rgbd2scene.worker_protocol import (  # noqa: F401 - the crossing's names, re-exported
    PARENT_PID_ENV,
    PAYLOADS,
    PROTOCOL,
    BuildScene,
    Describe,
    Event,
    Render,
    Task,
    frame_line,
    parse_line,
    ready_line,
    tie_to_parent,
    watch_parent,
)

REPO_ROOT = Path(__file__).resolve().parents[2]


# --- running a task --------------------------------------------------------------------------------------

def worker_env() -> dict:
    """The worker imports ``render`` and ``rgbd2scene`` from this checkout; its output is unbuffered; it knows
    its parent's process id (:func:`tie_to_parent`)."""
    env = dict(os.environ)
    env[PARENT_PID_ENV] = str(os.getpid())
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _tail(log, lines: int = 20) -> str:
    log.seek(0)
    text = log.read().decode(errors="replace").splitlines()
    keep = [t for t in text if t.strip() and not t.lstrip().startswith("Fra:") and "| Sample " not in t]
    return "\n".join(keep[-lines:])


@dataclass
class TaskResult:
    """Every progress event of a finished task, the worker's wall time and its peak resident memory."""

    events: list[Event]
    seconds: float
    peak_rss_mb: float


def run_task(task: Task, on_event: Callable[[Event], None] | None = None, python: str | None = None,
             what: str = "Blender worker", where: str = "") -> TaskResult:
    """Run ``task`` in a fresh ``python -m render.worker`` process; call ``on_event`` per progress line.

    A worker that fails raises :class:`RenderError` with the tail of its log (``what`` failed ``where``);
    interrupting the caller terminates the worker, killing it takes the worker with it
    (:func:`tie_to_parent`; the worker is waited for in the thread that starts it, which its Linux
    parent-death signal needs).
    """
    events: list[Event] = []
    with tempfile.TemporaryDirectory(prefix="rgbd2scene-task-") as tmp, tempfile.TemporaryFile() as log:
        task_path = Path(tmp) / "task.json"
        task_path.write_text(task.to_json())
        cmd = [python or sys.executable, "-m", "render.worker", str(task_path)]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=worker_env(), text=True, bufsize=1)
        try:
            for line in proc.stdout:
                event = parse_line(line)
                if event is None:
                    continue
                if event.kind == "ready":
                    event.stats["start"] = time.perf_counter() - t0
                events.append(event)
                if on_event is not None:
                    on_event(event)
            _, status, usage = os.wait4(proc.pid, 0)  # the worker's own peak memory, unlike proc.wait()
            proc.returncode = rc = os.waitstatus_to_exitcode(status)
        except BaseException:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            raise
        if rc != 0:
            raise RenderError(f"{what} failed (exit status {rc}){where}:\n{_tail(log)}")
    return TaskResult(events, time.perf_counter() - t0, usage.ru_maxrss / 1024.0)
