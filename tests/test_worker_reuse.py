"""Batch builds reuse one Blender worker per thread (issue 16 §2): chunks rendered by a long-lived worker, after
chunks of another scene, are byte for byte those of a fresh worker per chunk; a worker that dies is replaced."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import flat_grid, write_scene_files

pytest.importorskip("bpy")

from rgbd2scene.errors import RenderError  # noqa: E402
from rgbd2scene.rendering import RenderOptions  # noqa: E402
from rgbd2scene.stages import blender  # noqa: E402
from rgbd2scene.stages.blender import BuildScene, Task, close_workers, reusing_workers, run_task  # noqa: E402
from rgbd2scene.stages.render import prepare_render  # noqa: E402

FRAMES = 4
#: Two chunks per sequence; a few samples and no denoiser keep it quick, persistent data stays on (the default).
OPTIONS = {"size": (64, 32), "samples": 2, "denoise": "none", "chunk": 2}


def _scene(folder: Path, z: float, grey: int) -> Path:
    """A grey plane at depth ``z``, the camera backing off over ``FRAMES`` frames."""
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, 2, 3] = -0.001 * np.arange(FRAMES)
    desc = SceneDescription(StereoRig.parallel(Intrinsics(64, 32, 40.0, 40.0, 31.5, 15.5), 0.005, clip_start=0.001,
                                      clip_end=2.0), CameraPath(poses, fps=10.0, kind="test"), Light(),
                            [tissue_object("as_captured", texture=None)])
    write_scene_files(folder, flat_grid(z, 0.06, 31, grey), desc)
    run_task(Task(BuildScene(str(folder), desc.to_dict(), str(folder / "scene.blend"))))
    (folder / "scene.json").write_text(json.dumps({"scene": desc.to_dict(), "files": {"mesh": "mesh.ply"}}))
    return folder


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("reuse_scenes")
    return [_scene(root / "a", 0.05, 150), _scene(root / "b", 0.03, 90)]


def _files(folder: Path) -> dict[str, bytes]:
    """Every frame file of a dataset folder (images, ground truth), by its relative path."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.suffix in (".png", ".npz")}


@pytest.mark.parametrize("gt_source", ["model", "blender"])
def test_a_reused_worker_writes_the_bytes_of_fresh_workers(scenes, tmp_path, gt_source):
    options = RenderOptions(**OPTIONS, gt_source=gt_source)
    fresh = [prepare_render(s, tmp_path / f"fresh_{s.name}", options) for s in scenes]
    reused = [prepare_render(s, tmp_path / f"reused_{s.name}", options) for s in scenes]
    for job in fresh:
        for group in job.chunks():
            run_task(job.task(group))
    with reusing_workers():  # a, b, a, b: every chunk but the first follows another scene
        for chunk in range(2):
            for job in reused:
                run_task(job.task(job.chunks()[chunk]))
    worker = blender._local.worker
    assert worker.alive and worker.tasks == 4
    for a, b in zip(fresh, reused, strict=True):
        expected, found = _files(a.out), _files(b.out)
        assert len(expected) == 4 * FRAMES  # both eyes' PNG and npz
        assert found.keys() == expected.keys()
        assert [k for k in expected if found[k] != expected[k]] == []
    assert close_workers() == 1 and not worker.alive


def test_a_killed_worker_is_reported_and_replaced(scenes, tmp_path):
    job = prepare_render(scenes[0], tmp_path / "ds", RenderOptions(**OPTIONS))
    first, second = job.chunks()

    def kill_when_ready(event) -> None:
        if event.kind == "ready":
            os.kill(blender._local.worker.proc.pid, signal.SIGKILL)

    try:
        with reusing_workers():
            with pytest.raises(RenderError, match="failed \\(exit status -9\\) on frames 0-1"):
                run_task(job.task(first), kill_when_ready, where=" on frames 0-1")
            killed = blender._local.worker
            assert not killed.alive
            run_task(job.task(first))  # a new worker
            replacement = blender._local.worker
            assert replacement is not killed and replacement.alive
            os.kill(replacement.proc.pid, signal.SIGKILL)  # dies while idle: the next task starts another
            replacement.proc.wait()
            run_task(job.task(second))
            assert blender._local.worker.alive and blender._local.worker is not replacement
        assert job.incomplete(first + second) == []
    finally:
        close_workers()


def test_a_bad_task_leaves_the_worker_serving(scenes, tmp_path):
    """An input error (exit status 2) fails its task alone: the worker stays and runs the next task."""
    job = prepare_render(scenes[1], tmp_path / "ds", RenderOptions(**OPTIONS))
    bad = job.task(job.chunks()[0])
    bad.payload.scene_dir = str(tmp_path / "nowhere")
    try:
        with reusing_workers():
            with pytest.raises(RenderError, match="(?s)exit status 2.*no scene.blend"):
                run_task(bad)
            worker = blender._local.worker
            run_task(job.task(job.chunks()[0]))
            assert blender._local.worker is worker and worker.tasks == 2
    finally:
        close_workers()


#: A local pool's thread keeps its worker after a chunk; the driver then waits (the worker idle) to be killed.
IDLE_DRIVER = """
import sys, time, concurrent.futures
from rgbd2scene.rendering import RenderOptions
from rgbd2scene.stages.render import prepare_render
from rgbd2scene.batch.tasks import render_chunk
job = prepare_render(sys.argv[1], sys.argv[2], RenderOptions(size=(64, 32), samples=1, denoise="none", gt="none"))
pool = concurrent.futures.ThreadPoolExecutor(max_workers=1)
print(pool.submit(render_chunk, job, job.todo[:1]).result().ok, flush=True)
time.sleep(600)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc (Linux)")
def test_an_idle_reused_worker_ends_with_its_parent(scenes, tmp_path):
    import subprocess
    import sys
    import time

    from tests.test_worker_lifetime import _alive, _workers_of

    proc = subprocess.Popen([sys.executable, "-c", IDLE_DRIVER, str(scenes[0]), str(tmp_path / "ds")],
                            start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout.readline().strip() == "True"  # the chunk is done; its worker waits for the next
        workers = _workers_of(proc.pid)
        assert len(workers) == 1
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    deadline = time.monotonic() + 5.0
    while _alive(workers[0]) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = _alive(workers[0])
    if alive:
        os.kill(workers[0], signal.SIGKILL)
    assert not alive


def test_closing_terminates_a_busy_worker_without_waiting(scenes, tmp_path):
    """An interrupted build closes its engine while a chunk still renders: the worker is terminated and its
    task fails, instead of the close waiting for the chunk."""
    import threading
    import time

    job = prepare_render(scenes[0], tmp_path / "ds", RenderOptions(size=(64, 32), samples=20000, adaptive=False,
                                                                   denoise="none", gt="none"))
    started, outcome = threading.Event(), {}

    def render() -> None:
        with reusing_workers():
            try:
                run_task(job.task(job.todo), lambda event: started.set() if event.kind == "ready" else None)
            except RenderError as exc:
                outcome["error"] = str(exc)

    thread = threading.Thread(target=render)
    thread.start()
    assert started.wait(120)
    t0 = time.monotonic()
    assert close_workers() == 1
    thread.join(60)
    assert time.monotonic() - t0 < 15 and "exit status -15" in outcome["error"]
