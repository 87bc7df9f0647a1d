"""A Blender worker never outlives its parent (issue 16 §6): killed with SIGKILL, a caller (the CLI, a thread
of a local pool) takes its ``python -m render.worker`` process with it; SIGTERM still stops a render cleanly.

The watchdog is checked alone; the rest kills real callers of a long render of a one-quad scene (64x32,
thousands of samples, so the worker is mid-frame when its parent dies) and looks for the worker in ``/proc``.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rgbd2scene.stages.blender import watch_parent

#: How long a worker may take to go once its parent is killed.
GONE_WITHIN_S = 5.0


def test_watch_parent_calls_back_once_the_parent_changes():
    orphaned = threading.Event()
    watch_parent(os.getppid() + 1, orphaned.set, interval=0.01)  # "our parent is gone": not our parent
    assert orphaned.wait(2.0)
    kept = threading.Event()
    watch_parent(os.getppid(), kept.set, interval=0.01)
    assert not kept.wait(0.3)


# ================================================================ killing real callers

pytestmark_linux = pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc (Linux)")


def _ppid_and_state(pid: int) -> tuple[int, str] | None:
    """(parent pid, state letter) of a live process, None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    return int(fields[1]), fields[0]


def _workers_of(parent: int) -> list[int]:
    """Live ``render.worker`` processes whose parent is ``parent``."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        info = _ppid_and_state(int(entry.name))
        if b"render.worker" in cmdline and info is not None and info[0] == parent and info[1] != "Z":
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    info = _ppid_and_state(pid)
    return info is not None and info[1] != "Z"  # an unreaped zombie has ended


def _wait_for_worker(proc: subprocess.Popen, dataset: Path, timeout: float = 120.0) -> int:
    """The pid of ``proc``'s worker once it is rendering into ``dataset`` (its scratch folder exists, then a
    second more)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the caller ended (status {proc.returncode}) before it was killed"
        workers = _workers_of(proc.pid)
        if workers and list(dataset.glob(".work/*")):
            time.sleep(1.0)  # into the render
            assert _alive(workers[0])
            return workers[0]
        time.sleep(0.1)
    raise AssertionError("no rendering worker appeared")


def _gone_after_kill(proc: subprocess.Popen, worker: int, sig=signal.SIGKILL) -> float:
    """Send ``sig`` to ``proc`` (not its worker) and return how long the worker took to go."""
    t0 = time.monotonic()
    os.kill(proc.pid, sig)
    proc.wait(timeout=60)
    while _alive(worker) and time.monotonic() - t0 < GONE_WITHIN_S + 5:
        time.sleep(0.05)
    if _alive(worker):
        os.kill(worker, signal.SIGKILL)  # leave nothing running behind a failed test
        raise AssertionError(f"the worker {worker} still runs {GONE_WITHIN_S + 5:.0f} s after its parent died")
    return time.monotonic() - t0


pytest.importorskip("bpy")

from rgbd2scene.geometry.camera import Intrinsics  # noqa: E402
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object  # noqa: E402
from rgbd2scene.scene.paths import CameraPath  # noqa: E402
from rgbd2scene.scene.rig import StereoRig  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, run_task  # noqa: E402
from tests.conftest import write_scene_files  # noqa: E402

#: A render that runs for minutes at 64x32 (no adaptive stop, no denoiser): long enough to be killed in.
LONG_RENDER = ["--size", "64x32", "--samples", "20000", "--no-adaptive", "--denoise", "none", "--gt", "none",
               "--quiet", "--no-sheet"]


@pytest.fixture(scope="module")
def quad_scene(tmp_path_factory) -> Path:
    """A fronto-parallel textured quad filling the view of a 3-frame static path."""
    folder = tmp_path_factory.mktemp("quad")
    poses = np.repeat(np.eye(4)[None], 3, axis=0)
    desc = SceneDescription(StereoRig.parallel(Intrinsics(64, 32, 50.0, 50.0, 32.0, 16.0), 0.005, clip_start=0.001,
                                      clip_end=2.0), CameraPath(poses, fps=25.0, kind="test"), Light(),
                            [tissue_object("as_captured")])
    z = 0.05
    quad = SimpleNamespace(vertices=np.array([(-1, -1, z), (-1, 1, z), (1, 1, z), (1, -1, z)], float),
                           triangles=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                           uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                           vertex_colors=np.full((4, 3), 128, np.uint8), texture=np.full((4, 4, 3), 128, np.uint8))
    write_scene_files(folder, quad, desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict(), "files": {"mesh": "mesh.ply"}}))
    return folder


def _start_cli(scene: Path, out: Path, tmp: Path | None = None) -> subprocess.Popen:
    env = None if tmp is None else {**os.environ, "TMPDIR": str(tmp)}
    return subprocess.Popen([sys.executable, "-m", "rgbd2scene.cli", "render", str(scene), "-o", str(out),
                             *LONG_RENDER], start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=env)


@pytestmark_linux
def test_cli_killed_with_sigkill_takes_its_worker(quad_scene, tmp_path):
    proc = _start_cli(quad_scene, tmp_path / "ds")
    worker = _wait_for_worker(proc, tmp_path / "ds")
    assert _gone_after_kill(proc, worker) < GONE_WITHIN_S


#: A caller like the local pool of a batch build: ``run_task`` in a thread of a thread pool, while the main
#: thread waits (the worker's parent-death signal follows the thread that started it).
POOL_DRIVER = """
import sys, concurrent.futures
from rgbd2scene.stages.render import RenderOptions, prepare_render
job = prepare_render(sys.argv[1], sys.argv[2], RenderOptions(size=(64, 32), samples=20000, adaptive=False,
                                                             denoise="none", gt="none"))
from rgbd2scene.batch.tasks import render_chunk
with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
    print(pool.submit(render_chunk, job, job.todo).result())
"""


@pytestmark_linux
def test_pool_thread_killed_with_sigkill_takes_its_worker(quad_scene, tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", POOL_DRIVER, str(quad_scene), str(tmp_path / "ds")],
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = _wait_for_worker(proc, tmp_path / "ds")
    assert _gone_after_kill(proc, worker) < GONE_WITHIN_S


@pytestmark_linux
def test_sigterm_stops_the_cli_and_its_worker(quad_scene, tmp_path):
    """SIGTERM to the CLI ends its worker too; SIGTERM to the worker stops it, and the CLI reports it. Neither
    leaves temporary folders behind: Blender's session folder of a killed worker goes with its caller's task
    folder, and the task folder of a killed caller is deleted by the next caller."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = _start_cli(quad_scene, tmp_path / "a", tmp)
    worker = _wait_for_worker(proc, tmp_path / "a")
    assert _gone_after_kill(proc, worker, signal.SIGTERM) < GONE_WITHIN_S
    left = [f.name for f in tmp.iterdir()]
    assert len(left) == 1 and left[0].startswith(f"rgbd2scene-task-{proc.pid}@"), left  # the killed CLI's

    proc = subprocess.Popen([sys.executable, "-m", "rgbd2scene.cli", "render", str(quad_scene), "-o",
                             str(tmp_path / "b"), *LONG_RENDER], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp)})
    worker = _wait_for_worker(proc, tmp_path / "b")
    os.kill(worker, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and not _alive(worker)
    assert "render worker failed (exit status -15)" in err
    assert list(tmp.iterdir()) == []


def test_only_the_folders_of_ended_callers_on_this_host_are_removed(tmp_path):
    from rgbd2scene.stages.blender import remove_orphaned_folders

    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait()
    host = socket.gethostname()
    names = {"ended": f"rgbd2scene-task-{ended.pid}@{host}-ab12cd34",
             "running": f"rgbd2scene-task-{os.getpid()}@{host}-ab12cd34",
             "other host": f"rgbd2scene-task-{ended.pid}@not-{host}-ab12cd34",
             "not ours": f"blender-{ended.pid}@{host}-ab12cd34"}
    for name in names.values():
        (tmp_path / name).mkdir()
        (tmp_path / name / "task.json").write_text("{}")
    assert remove_orphaned_folders(tmp_path) == 1
    assert sorted(f.name for f in tmp_path.iterdir()) == sorted(v for k, v in names.items() if k != "ended")


def test_a_finished_worker_leaves_no_blender_temporary_folder(quad_scene, tmp_path):
    """The worker ends without Blender's teardown (render/worker.py ``quick_exit``), which would also have
    deleted Blender's session folder: it must still go."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    done = subprocess.run([sys.executable, "-m", "rgbd2scene.cli", "render", str(quad_scene), "-o",
                           str(tmp_path / "ds"), "--size", "64x32", "--frames", "1", "--gt", "depth", "--quiet",
                           "--no-sheet"],
                          env={**os.environ, "TMPDIR": str(tmp)}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "ds" / "left" / "gt" / "000000.npz").is_file()
    assert not list(tmp.glob("blender_*"))


# ================================================================ the ground-truth child started before bpy

def _children(pid: int) -> list[int]:
    """Live (not zombie) child processes of ``pid``."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            info = _ppid_and_state(int(entry.name))
            if info is not None and info[0] == pid and info[1] != "Z":
                out.append(int(entry.name))
    return out


def test_importing_the_render_package_does_not_import_blender():
    """The worker starts a render's ground-truth child before it imports ``bpy`` (both take about a second)."""
    code = "import sys, render, render.worker; assert 'bpy' not in sys.modules; print(render.build_scene.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "build_scene"


@pytestmark_linux
def test_a_serving_worker_ends_the_ground_truth_child_of_a_task_that_failed_before_using_it(tmp_path):
    """The child is started before the task's scene is opened; when the task fails first, the worker ends the child
    before it reports the task's end (a serving worker lives on: no child may be left waiting beside it)."""
    pytest.importorskip("bpy")
    from rgbd2scene.stages.blender import worker_env
    from rgbd2scene.worker_protocol import Render, Task

    task = Task(Render(str(tmp_path / "no_scene"), str(tmp_path / "out"), {}, {"size": (64, 32)}, frames=2))
    worker = subprocess.Popen([sys.executable, "-m", "render.worker", "--serve"], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=worker_env())
    try:
        worker.stdin.write(task.to_json() + "\n")
        worker.stdin.flush()
        line = worker.stdout.readline()
        assert line.startswith("end 2"), line  # 2: a problem with the task's inputs (no scene.blend)
        assert _children(worker.pid) == []
    finally:
        worker.stdin.close()
        worker.wait(timeout=120)
