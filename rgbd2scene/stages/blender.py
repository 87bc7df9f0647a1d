"""The one crossing into Blender: a task file, one worker entry point in a fresh process, one progress protocol.

Every stage that needs Blender (building ``scene.blend``, rendering frames) writes a :class:`Task` (JSON:
the action, the scene model and the options) and runs ``python -m render.worker TASK.json`` through
:func:`run_task`. The worker answers on its stdout with the lines of :data:`PROTOCOL` only (Blender's own
output goes to stderr, kept for the error message). A fresh process per task bounds Blender's memory and
keeps ``bpy`` out of the calling process (a CLI, a test, a benchmark or a Dask worker).

A worker never outlives its parent (:func:`tie_to_parent`): killed with SIGKILL (the out-of-memory killer, a
scheduler), a caller takes its worker with it, instead of leaving it to render on unowned until its next
progress line hits the closed pipe.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from rgbd2scene.errors import RenderError

TASK_VERSION = 1
ACTIONS = ("build_scene", "render", "describe")
REPO_ROOT = Path(__file__).resolve().parents[2]
#: The environment variable that tells a worker which process started it (:func:`tie_to_parent`).
PARENT_PID_ENV = "RGBD2SCENE_PARENT_PID"
#: How often the portable watchdog of :func:`tie_to_parent` looks at the worker's parent (seconds).
PARENT_POLL_S = 0.5
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


@dataclass
class Task:
    """What the worker does.

    action
        ``build_scene`` (``description`` -> ``blend``, geometry and textures read from ``scene_dir``),
        ``render`` (frames ``[start, end)`` of ``scene_dir`` into ``dataset_dir`` with ``render`` options;
        ``frames`` is the dataset length) or ``describe`` (print the description stored in the blend).
    """

    action: str
    scene_dir: str
    description: dict | None = None
    blend: str | None = None
    dataset_dir: str | None = None
    render: dict = field(default_factory=dict)
    frames: int | None = None
    start: int = 0
    end: int | None = None
    version: int = TASK_VERSION

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Task:
        d = json.loads(text)
        if d.get("version") != TASK_VERSION:
            raise ValueError(f"task version {d.get('version')} is not {TASK_VERSION}")
        if d.get("action") not in ACTIONS:
            raise ValueError(f"unknown task action {d.get('action')!r}")
        return cls(**d)


# --- the progress protocol (worker stdout, one event per line) -------------------------------------------

#: ``ready 0.731s device CPU``; ``frame 3 rgb 1.8s cpu 3.5s``; ``frame 3 done 2.0s cpu 3.9s rgb 1.8s gt 0.2s
#: rss 668MB``; ``frame 3 skipped``; ``built PATH``; ``describe {json}``. The render worker appends to a frame's
#: ``rgb``/``done`` line the seconds Cycles spent on it per phase (``rgb_sync``, ``rgb_bvh``, ``rgb_trace``,
#: ``rgb_save``, likewise ``gt_*`` for the data render: :mod:`render.timing`).
PROTOCOL = ("ready", "frame", "built", "describe")
_FRAME = re.compile(r"^frame (\d+) (done|skipped|rgb)\b")
_NUMBERS = re.compile(r"(\w+) ([0-9.]+)(s|MB)")


@dataclass
class Event:
    kind: str  # ready | rgb | done | skipped | built | describe
    frame: int | None = None
    stats: dict = field(default_factory=dict)
    text: str = ""


def ready_line(seconds: float, device: str) -> str:
    return f"ready {seconds:.3f}s device {device}"


def frame_line(index: int, what: str, seconds: float | None = None, **stats: float) -> str:
    """``what``: rgb, done or skipped, then its ``seconds``; ``stats`` in seconds except ``rss`` (MB)."""
    parts = [f"frame {index} {what}"] + ([] if seconds is None else [f"{seconds:.3f}s"])
    parts += [f"{k} {v:.0f}MB" if k == "rss" else f"{k} {v:.3f}s" for k, v in stats.items()]
    return " ".join(parts)


def parse_line(line: str) -> Event | None:
    """The event of one worker stdout line, or None for anything else."""
    line = line.strip()
    if line.startswith("ready"):
        return Event("ready", stats={k: float(v) for k, v, _ in _NUMBERS.findall(line)})
    if line.startswith("built "):
        return Event("built", text=line[6:])
    if line.startswith("describe "):
        return Event("describe", text=line[9:])
    m = _FRAME.match(line)
    if m:  # the seconds after "rgb"/"done" are read as stats["rgb"] / stats["done"]
        return Event(m.group(2), int(m.group(1)), {k: float(v) for k, v, _ in _NUMBERS.findall(line)})
    return None


# --- running a task --------------------------------------------------------------------------------------

def worker_env() -> dict:
    """The worker imports ``render`` and ``rgbd2scene`` from this checkout; its output is unbuffered; it knows
    its parent's process id (:func:`tie_to_parent`)."""
    env = dict(os.environ)
    env[PARENT_PID_ENV] = str(os.getpid())
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _set_parent_death_signal() -> bool:
    """Ask Linux to send SIGKILL to this process when its parent dies; False where that is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _end_self() -> None:
    """Die at once, Cycles' render threads included (nothing to report to: the parent is gone)."""
    if hasattr(signal, "SIGKILL"):
        os.kill(os.getpid(), signal.SIGKILL)
    os._exit(1)


def watch_parent(parent: int, on_orphan: Callable[[], None] = _end_self,
                 interval: float = PARENT_POLL_S) -> threading.Thread:
    """Start a daemon thread that calls ``on_orphan`` once this process's parent is no longer ``parent``
    (orphans are re-parented: ``os.getppid()`` changes). Portable; it runs while Blender renders, since
    Blender releases the GIL then."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        on_orphan()

    thread = threading.Thread(target=watch, name="rgbd2scene-parent-watch", daemon=True)
    thread.start()
    return thread


def tie_to_parent(parent: int | None = None) -> None:
    """Make this worker process end when the process that started it dies, however it dies (SIGKILL too).

    ``parent``: the starter's process id (default: :data:`PARENT_PID_ENV`, set by :func:`run_task`, else
    the current parent). On Linux the kernel sends SIGKILL when the parent goes (``PR_SET_PDEATHSIG``; it
    fires when the *thread* that started the worker ends, and :func:`run_task` waits for its worker in
    the thread that started it, so in a local pool's thread or a Dask worker the thread lives as long as
    the worker should); a watchdog thread polling ``os.getppid()`` backs it up (other systems, or a
    parent that died before the signal was set: then the worker ends at once).
    """
    if parent is None:
        parent = int(os.environ.get(PARENT_PID_ENV) or os.getppid())
    _set_parent_death_signal()
    if os.getppid() != parent:  # the parent died before the signal was set
        _end_self()
    watch_parent(parent)


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
