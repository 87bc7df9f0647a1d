"""The scene model's ground truth written by a low-priority child process (what the render worker uses): the
same bytes as written in-process, and a failure of the child reaches the caller."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict

import numpy as np
import pytest

from rgbd2scene.files.meshio import write_ply
from rgbd2scene.geometry.camera import Intrinsics
from rgbd2scene.groundtruth.background import NICENESS, BackgroundGroundTruth, Job, spawn
from rgbd2scene.groundtruth.model_maps import ModelGroundTruth
from rgbd2scene.scene.model import Light, SceneDescription, tissue_object
from rgbd2scene.scene.paths import CameraPath
from rgbd2scene.scene.rig import StereoRig
from tests.conftest import flat_grid

FRAMES = 3


def _scene(folder) -> SceneDescription:
    write_ply(folder / "mesh.ply", flat_grid(0.05, 0.04, 41))
    poses = np.tile(np.eye(4), (FRAMES, 1, 1))
    poses[:, 0, 3] = 0.001 * np.arange(FRAMES)
    rig = StereoRig.parallel(Intrinsics(32, 16, 20.0, 20.0, 15.5, 7.5), 0.004, clip_start=0.001, clip_end=2.0)
    return SceneDescription(rig, CameraPath(poses, fps=10.0, kind="test"), Light(),
                            [tissue_object("as_captured", texture=None)])


def _job(description: SceneDescription, scene_dir, out_dir) -> Job:
    scratch = out_dir / ".scratch"
    scratch.mkdir(parents=True)
    return Job(description.to_dict(), str(scene_dir), FRAMES, ["depth", "normals", "disparity", "flow_forward"],
               str(out_dir), str(scratch))


def test_the_child_writes_the_bytes_written_in_process_at_low_priority(tmp_path):
    description = _scene(tmp_path)
    job = _job(description, tmp_path, tmp_path / "child")
    model = ModelGroundTruth.of_scene(description, tmp_path, FRAMES, tuple(job.maps))
    for index in range(FRAMES):
        model.write(tmp_path / "here", index)
    with BackgroundGroundTruth(job) as child:
        child.submit(range(FRAMES))
        cost = child.wait(0)
        assert cost.cpu_s >= 0.0 and cost.rss_mb > 10.0  # numpy and open3d at least
        assert os.getpriority(os.PRIO_PROCESS, child._proc.pid) >= min(NICENESS, os.nice(0) + NICENESS)
        for index in range(FRAMES):
            child.wait(index)
            assert child.done(index)
    files = sorted(p.relative_to(tmp_path / "here") for p in (tmp_path / "here").rglob("*.npz"))
    assert len(files) == 2 * FRAMES
    for name in files:
        assert (tmp_path / "child" / name).read_bytes() == (tmp_path / "here" / name).read_bytes(), name


def test_a_failing_child_fails_the_frames_it_was_asked_for(tmp_path):
    description = _scene(tmp_path)
    job = _job(description, tmp_path / "no_such_scene", tmp_path / "child")
    child = BackgroundGroundTruth(job)
    child.submit([0])
    with pytest.raises(RuntimeError, match="ground-truth process"):
        child.wait(0)
    with pytest.raises(RuntimeError, match="failed"):
        child.close()


def test_an_error_of_the_render_is_the_one_reported_and_ends_the_child(tmp_path):
    job = _job(_scene(tmp_path), tmp_path, tmp_path / "child")
    with pytest.raises(ValueError, match="the render failed"), BackgroundGroundTruth(job) as child:
        child.submit(range(FRAMES))
        raise ValueError("the render failed")
    assert child._proc.poll() is not None


#: A stand-in for the render worker: gives the child minutes of work (the same frames again and again: it
#: is computing, not waiting for its input, when the worker dies), says its pid, then waits to be killed.
WORKER = """
import json, sys, time
from rgbd2scene.groundtruth.background import BackgroundGroundTruth, Job
child = BackgroundGroundTruth(Job(**json.loads(sys.argv[1])))
child.submit(list(range(3)) * 10000)
child.wait(0)
print(child._proc.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.skipif(not os.path.isfile("/proc/self/stat"), reason="needs /proc (Linux)")
def test_the_child_ends_when_its_worker_is_killed(tmp_path):
    job = _job(_scene(tmp_path), tmp_path, tmp_path / "child")
    worker = subprocess.Popen([sys.executable, "-c", WORKER, json.dumps(asdict(job))], stdout=subprocess.PIPE,
                              text=True, start_new_session=True)
    child = int(worker.stdout.readline())
    assert _alive(child)
    os.kill(worker.pid, signal.SIGKILL)
    worker.wait(timeout=60)
    deadline = time.monotonic() + 10.0
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    if _alive(child):
        os.kill(child, signal.SIGKILL)  # leave nothing running behind a failed test
        raise AssertionError("the ground-truth process outlived its worker")


def _alive(pid: int) -> bool:
    """The process runs (not gone, not a zombie)."""
    try:
        stat = open(f"/proc/{pid}/stat").read()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def test_a_child_started_before_its_job_writes_the_same_bytes_and_ends_at_once(tmp_path):
    """What the render worker does: :func:`spawn` before it imports Blender, the job once the scene is open."""
    description = _scene(tmp_path)
    job = _job(description, tmp_path, tmp_path / "child")
    model = ModelGroundTruth.of_scene(description, tmp_path, FRAMES, tuple(job.maps))
    for index in range(FRAMES):
        model.write(tmp_path / "here", index)
    process = spawn()
    time.sleep(0.2)  # the child is importing its libraries, with no job yet
    assert process.poll() is None
    with BackgroundGroundTruth(job, process=process) as child:
        child.submit(range(FRAMES))
    assert process.returncode == 0  # ended by itself once every frame was written
    for name in sorted(p.relative_to(tmp_path / "here") for p in (tmp_path / "here").rglob("*.npz")):
        assert (tmp_path / "child" / name).read_bytes() == (tmp_path / "here" / name).read_bytes(), name


def test_a_child_given_no_job_ends_quietly():
    process = spawn()
    process.stdin.close()
    assert process.wait(timeout=120) == 0
    assert process.stdout.read() == ""
