"""The one crossing into Blender: a task file, one worker entry point in a fresh process, one progress protocol.

Every stage that needs Blender (building ``scene.blend``, rendering frames) writes a :class:`Task` (JSON:
the action and its payload: the scene model, the options; :mod:`rgbd2scene.worker_protocol`) and runs
``python -m render.worker TASK.json`` through :func:`run_task`. The worker answers on its stdout with the
lines of :data:`PROTOCOL` only (Blender's own output goes to stderr, kept for the error message). A fresh
process per task (outside batch builds: below) bounds Blender's memory and keeps ``bpy`` out of the calling
process (a CLI, a test, a benchmark or a Dask worker).

A worker never outlives its parent (:func:`tie_to_parent`): killed with SIGKILL (the out-of-memory killer, a
scheduler), a caller takes its worker with it, instead of leaving it to render on unowned until its next
progress line hits the closed pipe. Nor does its scratch: each worker gets a temporary folder of the caller's
(:func:`worker_folder`) as its ``TMPDIR``, which holds Blender's session folder too, and a folder whose caller
was killed before it could delete it is deleted by the next caller on the machine.

Batch builds reuse workers instead (:func:`reusing_workers`): inside it, :func:`run_task` sends the task to
the calling thread's long-lived :class:`ServingWorker` (``python -m render.worker --serve``), which opens each
task's scene in the same process and resets Blender between tasks, so Blender starts once per pool thread or
Dask worker thread rather than once per chunk. A serving worker that dies is replaced by the next task;
:func:`close_workers` ends them all.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from rgbd2scene.errors import RenderError
from rgbd2scene.worker_protocol import (  # noqa: F401 - the crossing's names, re-exported
    PARENT_PID_ENV,
    PAYLOADS,
    PROTOCOL,
    SERVE_FLAG,
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

def worker_env(tmp: str | Path | None = None) -> dict:
    """The worker imports ``render`` and ``rgbd2scene`` from this checkout; its output is unbuffered; it knows
    its parent's process id (:func:`tie_to_parent`); its temporary files, Blender's session folder among them,
    go to ``tmp`` when given (:func:`worker_folder`)."""
    env = dict(os.environ)
    if tmp is not None:
        env["TMPDIR"] = str(tmp)
    env[PARENT_PID_ENV] = str(os.getpid())
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


#: Workers' temporary folders: ``rgbd2scene-task-<caller pid>@<host>-<random>`` in the system's temporary folder.
WORKER_FOLDER = re.compile(r"rgbd2scene-task-(\d+)@(.+)-[^-]+")


def worker_folder() -> tempfile.TemporaryDirectory:
    """A new temporary folder for a worker (its task file and ``TMPDIR``), named after this process and host.

    Blender deletes its session folder only in its own teardown, which a worker killed mid-render never runs,
    and a caller killed with SIGKILL cannot delete its folders either: so first the folders of this host's
    callers that are gone are deleted (:func:`remove_orphaned_folders`).
    """
    remove_orphaned_folders()
    return tempfile.TemporaryDirectory(prefix=f"rgbd2scene-task-{os.getpid()}@{socket.gethostname()}-")


def remove_orphaned_folders(root: str | Path | None = None) -> int:
    """Delete the workers' temporary folders in ``root`` (default: the system's temporary folder) whose caller,
    a process of this host, has ended; how many. Folders of other hosts (a shared ``TMPDIR``) are left alone."""
    host = socket.gethostname()
    removed = 0
    for folder in Path(root or tempfile.gettempdir()).glob("rgbd2scene-task-*@*"):
        match = WORKER_FOLDER.fullmatch(folder.name)
        if match and match[2] == host and not _running(int(match[1])):
            shutil.rmtree(folder, ignore_errors=True)
            removed += 1
    return removed


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _tail(log, lines: int = 20, start: int = 0) -> str:
    """The last ``lines`` lines of ``log`` from byte ``start`` on, less Cycles' progress chatter."""
    log.seek(start)
    text = log.read().decode(errors="replace").splitlines()
    keep = [t for t in text if t.strip() and not t.lstrip().startswith("Fra:") and "| Sample " not in t]
    return "\n".join(keep[-lines:])


@dataclass
class TaskResult:
    """Every progress event of a finished task, the worker's wall time and its peak resident memory."""

    events: list[Event]
    seconds: float
    peak_rss_mb: float


def _follow(lines: Iterable[str], on_event: Callable[[Event], None] | None,
            t0: float) -> tuple[list[Event], Event | None]:
    """Read a worker's progress ``lines`` until they end or an ``end`` event comes: (the task's events, the
    ``end`` event or None). ``ready`` gets ``stats["start"]``, the seconds since ``t0`` (the task was sent)."""
    events: list[Event] = []
    for line in lines:
        event = parse_line(line)
        if event is None:
            continue
        if event.kind == "end":
            return events, event
        if event.kind == "ready":
            event.stats["start"] = time.perf_counter() - t0
        events.append(event)
        if on_event is not None:
            on_event(event)
    return events, None


def _stop(proc: subprocess.Popen) -> None:
    """Terminate a worker (SIGTERM stops a render cleanly), then kill it if it lingers."""
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _failed(what: str, rc: int, where: str, tail: str) -> RenderError:
    return RenderError(f"{what} failed (exit status {rc}){where}:\n{tail}")


def run_task(task: Task, on_event: Callable[[Event], None] | None = None, python: str | None = None,
             what: str = "Blender worker", where: str = "") -> TaskResult:
    """Run ``task`` in a fresh ``python -m render.worker`` process (inside :func:`reusing_workers`: in the calling
    thread's serving worker instead); call ``on_event`` per progress line.

    A worker that fails raises :class:`RenderError` with the tail of its log (``what`` failed ``where``);
    interrupting the caller terminates the worker, killing it takes the worker with it
    (:func:`tie_to_parent`; the worker is waited for in the thread that starts it, which its Linux
    parent-death signal needs).
    """
    if getattr(_local, "reuse", False):
        return _serving_worker(python).run(task, on_event, what, where)
    with worker_folder() as tmp, tempfile.TemporaryFile() as log:
        task_path = Path(tmp) / "task.json"
        task_path.write_text(task.to_json())
        cmd = [python or sys.executable, "-m", "render.worker", str(task_path)]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=worker_env(tmp), text=True, bufsize=1)
        try:
            events, _ = _follow(proc.stdout, on_event, t0)
            _, status, usage = os.wait4(proc.pid, 0)  # the worker's own peak memory, unlike proc.wait()
            proc.returncode = rc = os.waitstatus_to_exitcode(status)
        except BaseException:
            _stop(proc)
            raise
        if rc != 0:
            raise _failed(what, rc, where, _tail(log))
    return TaskResult(events, time.perf_counter() - t0, usage.ru_maxrss / 1024.0)


# --- long-lived workers (batch builds) -------------------------------------------------------------------

class ServingWorker:
    """One ``python -m render.worker --serve`` process, started by the thread that uses it (its Linux
    parent-death signal follows that thread), running one task at a time; its stderr is kept in a file, and
    each task's error message is the tail of what it wrote there; its temporary files go to a folder of its own
    (:func:`worker_folder`), deleted when it ends."""

    def __init__(self, python: str | None = None):
        self.log = tempfile.TemporaryFile()
        self.tmp = worker_folder()
        cmd = [python or sys.executable, "-m", "render.worker", SERVE_FLAG]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log,
                                     env=worker_env(self.tmp.name), text=True, bufsize=1)
        self.lock = threading.Lock()
        self.tasks = 0

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def run(self, task: Task, on_event: Callable[[Event], None] | None = None, what: str = "Blender worker",
            where: str = "") -> TaskResult:
        """Run ``task`` in this process; like :func:`run_task`. A task that fails with exit status 1 (an
        unexpected error: Blender's state is unknown) or kills the process ends this worker."""
        with self.lock:
            t0 = time.perf_counter()
            start = self.log.seek(0, os.SEEK_END)
            try:
                try:
                    self.proc.stdin.write(task.to_json() + "\n")
                    self.proc.stdin.flush()
                except BrokenPipeError:  # it died since it was last seen alive
                    events, end = [], None
                else:
                    events, end = _follow(self.proc.stdout, on_event, t0)
            except BaseException:  # interrupted: the worker ends, and so do its log and folder
                self.stop()
                raise
            self.tasks += 1
            if end is None:  # the process died during the task
                rc = self.proc.wait()
                raise _failed(what, rc, where, _tail(self.log, start=start))
            rc = int(end.stats["status"])
            if rc != 0:
                if rc != 2:
                    self.close()
                raise _failed(what, rc, where, _tail(self.log, start=start))
            return TaskResult(events, time.perf_counter() - t0, end.stats.get("peak", 0.0))

    def close(self) -> None:
        """End the process: stdin closed, it finishes its loop; killed if it does not within 10 s."""
        with contextlib.suppress(OSError):
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            _stop(self.proc)
        self.log.close()
        self.tmp.cleanup()

    def stop(self) -> None:
        """End the process now (:func:`_stop`), its log and its folder with it."""
        _stop(self.proc)
        self.log.close()
        self.tmp.cleanup()


_local = threading.local()  # .reuse: inside reusing_workers(); .worker: this thread's ServingWorker
_workers: set[ServingWorker] = set()
_workers_lock = threading.Lock()


def _serving_worker(python: str | None) -> ServingWorker:
    """The calling thread's serving worker, started (or replaced, when it died) here."""
    worker = getattr(_local, "worker", None)
    if worker is not None and worker.alive:
        return worker
    if worker is not None:
        worker.close()
        with _workers_lock:
            _workers.discard(worker)
    worker = _local.worker = ServingWorker(python)
    with _workers_lock:
        _workers.add(worker)
    return worker


@contextlib.contextmanager
def reusing_workers():
    """Inside, :func:`run_task` runs its tasks in the calling thread's long-lived worker; the worker stays
    for the thread's next tasks (:func:`close_workers` ends it)."""
    before = getattr(_local, "reuse", False)
    _local.reuse = True
    try:
        yield
    finally:
        _local.reuse = before


def close_workers() -> int:
    """End every serving worker of this process (the engines call it when they close); how many there were. An
    idle one finishes its loop; one still running a task (a build interrupted) is terminated, not waited for."""
    with _workers_lock:
        workers = list(_workers)
        _workers.clear()
    for worker in workers:
        if worker.lock.acquire(blocking=False):
            try:
                worker.close()
            finally:
                worker.lock.release()
        else:  # its thread still reads the log: leave that to it
            _stop(worker.proc)
            worker.tmp.cleanup()
    return len(workers)
