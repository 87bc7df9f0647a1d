"""The worker's side of the one crossing into Blender: the task a worker runs, its progress lines, its tie to its
parent. Plain Python without ``bpy``: the calling stages (:mod:`rgbd2scene.stages.blender` runs a task) and
the worker (``render/``) both import it.

A :class:`Task` carries one payload, whose type names the action (:data:`PAYLOADS`): :class:`BuildScene`,
:class:`Render` or :class:`Describe`; the worker looks its handler up by that type.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

TASK_VERSION = 2
#: The environment variable that tells a worker which process started it (:func:`tie_to_parent`).
PARENT_PID_ENV = "RGBD2SCENE_PARENT_PID"
#: How often the portable watchdog of :func:`tie_to_parent` looks at the worker's parent (seconds).
PARENT_POLL_S = 0.5
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


# --- tasks: one payload per action -------------------------------------------------------------------------

@dataclass
class BuildScene:
    """Build ``blend`` from the scene model ``description``; geometry and textures are read from ``scene_dir``."""

    scene_dir: str
    description: dict
    blend: str


@dataclass
class Render:
    """Render frames ``[start, end)`` of ``scene_dir`` into ``dataset_dir``; ``description``: the scene model as
    rendered, ``render``: the render options' record, ``frames``: the dataset's length."""

    scene_dir: str
    dataset_dir: str
    description: dict
    render: dict = field(default_factory=dict)
    frames: int | None = None
    start: int = 0
    end: int | None = None


@dataclass
class Describe:
    """Print the scene description stored in ``scene_dir``'s blend."""

    scene_dir: str


#: Action name (in the task file) -> its payload type.
PAYLOADS = {"build_scene": BuildScene, "render": Render, "describe": Describe}
_ACTIONS = {kind: name for name, kind in PAYLOADS.items()}


@dataclass
class Task:
    """What a worker does: one payload (:data:`PAYLOADS`)."""

    payload: BuildScene | Render | Describe

    @property
    def action(self) -> str:
        return _ACTIONS[type(self.payload)]

    def to_json(self) -> str:
        return json.dumps({"version": TASK_VERSION, "action": self.action, "payload": asdict(self.payload)})

    @classmethod
    def from_json(cls, text: str) -> Task:
        d = json.loads(text)
        if d.get("version") != TASK_VERSION:
            raise ValueError(f"task version {d.get('version')} is not {TASK_VERSION}")
        kind = PAYLOADS.get(d.get("action"))
        if kind is None:
            raise ValueError(f"unknown task action {d.get('action')!r}")
        return cls(kind(**d["payload"]))


# --- the progress protocol (worker stdout, one event per line) -------------------------------------------

#: ``ready 0.731s device CPU``; ``frame 3 rgb 1.8s cpu 3.5s``; ``frame 3 done 2.0s cpu 3.9s rgb 1.8s gt 0.2s
#: rss 668MB``; ``frame 3 skipped``; ``built PATH``; ``describe {json}``. The render worker appends to a frame's
#: ``rgb``/``done`` line the seconds Cycles spent on it per phase (``rgb_sync``, ``rgb_bvh``, ``rgb_trace``,
#: ``rgb_save``, likewise ``gt_*`` for the data render: :mod:`render.timing`). A serving worker
#: (:data:`SERVE_FLAG`) ends each task with ``end 0 peak 612MB``: the task's exit status (as a one-task worker's
#: process would have it) and the process's peak resident memory during the task.
PROTOCOL = ("ready", "frame", "built", "describe", "end")
_FRAME = re.compile(r"^frame (\d+) (done|skipped|rgb)\b")
_END = re.compile(r"^end (-?\d+)\b")
#: ``python -m render.worker --serve``: one task per stdin line (:meth:`Task.to_json`), each answered with its
#: progress lines and an ``end`` line, until stdin closes.
SERVE_FLAG = "--serve"
_NUMBERS = re.compile(r"(\w+) ([0-9.]+)(s|MB)")


@dataclass
class Event:
    kind: str  # ready | rgb | done | skipped | built | describe | end
    frame: int | None = None
    stats: dict = field(default_factory=dict)
    text: str = ""


def ready_line(seconds: float, device: str) -> str:
    return f"ready {seconds:.3f}s device {device}"


def resident_mb() -> float:
    """This process's resident memory now (MB; its peak where ``/proc`` is missing)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return _lifetime_peak_mb()


def peak_rss_mb(reset: bool = False) -> float:
    """This process's peak resident memory (MB) since it started or since the last ``reset`` (Linux's
    ``VmHWM``, reset through ``/proc/self/clear_refs``; elsewhere the peak of the whole process)."""
    try:
        with open("/proc/self/status") as f:
            peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024.0
        if reset:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
        return peak
    except (OSError, StopIteration, ValueError):
        return _lifetime_peak_mb()


def _lifetime_peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def frame_line(index: int, what: str, seconds: float | None = None, **stats: float) -> str:
    """``what``: rgb, done or skipped, then its ``seconds``; ``stats`` in seconds except resident memory
    (``rss``, ``gt_rss``: MB)."""
    parts = [f"frame {index} {what}"] + ([] if seconds is None else [f"{seconds:.3f}s"])
    parts += [f"{k} {v:.0f}MB" if k.endswith("rss") else f"{k} {v:.3f}s" for k, v in stats.items()]
    return " ".join(parts)


def end_line(status: int, peak_rss_mb: float) -> str:
    """A serving worker's last line of a task: its exit ``status`` and peak memory (:data:`PROTOCOL`)."""
    return f"end {status} peak {peak_rss_mb:.0f}MB"


def parse_line(line: str) -> Event | None:
    """The event of one worker stdout line, or None for anything else (``end``: ``stats["status"]``,
    ``stats["peak"]``)."""
    line = line.strip()
    m = _END.match(line)
    if m:
        return Event("end", stats={"status": int(m.group(1)), **{k: float(v) for k, v, _ in _NUMBERS.findall(line)}})
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


# --- the worker's tie to its parent ---------------------------------------------------------------------

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


