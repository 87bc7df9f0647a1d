"""The scene model's ground truth (:class:`~rgbd2scene.groundtruth.model_maps.ModelGroundTruth`) computed and
written in a child process at the lowest CPU priority, beside a render.

Why a process and not a thread of the Blender worker: a thread shares the worker's interpreter lock with
Blender's own Python calls (opening the blend, setting the frame, reading the render back), so loading the
model there slowed Blender's start-up, and it competes with Cycles for the two cores at the same priority.
The child loads the model (open3d, the geometry) while Blender starts up (mostly on one core), then lowers
its priority to ``nice`` 19 and computes frames in what Cycles leaves idle (scene sync, denoising, writes);
what is left when the last image is done runs at full speed.

The child can be started before its job is known (:func:`spawn`, e.g. by the render worker before it imports
``bpy``): it imports its libraries (Python, numpy, open3d's library: about 0.5 CPU s)
while the worker imports Blender, and reads the job when the worker has opened its scene.

Protocol (text lines): the parent writes one JSON line (:class:`Job`; an empty stdin: no job, the child ends),
then one frame index per line and closes stdin when it has no more; the child answers
``done INDEX CPU_SECONDS RSS_MB`` per frame, in the order it finishes them, and ends at once when the last is
written (``os._exit``: no interpreter teardown on the render's critical path). An error ends the child with a
traceback on stderr (inherited: the worker's log).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import traceback
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

#: Frames the child computes at once (numpy and the ray caster release the GIL; the files are each frame's own).
THREADS = 2
#: The child's niceness once the model is loaded: it takes only CPU that the render leaves idle.
NICENESS = 19


@dataclass(frozen=True)
class Job:
    """What the child needs: the scene model as rendered (``SceneDescription.to_dict``), its folder, the
    dataset's length, the maps, the dataset folder and the run's scratch folder (for atomic writes)."""

    description: dict
    scene_dir: str
    frames: int
    maps: list[str]
    out_dir: str
    scratch: str


@dataclass(frozen=True)
class FrameCost:
    """What the child spent on one frame: CPU seconds (its thread), and its resident memory after it (MB)."""

    cpu_s: float
    rss_mb: float


def spawn(python: str | None = None) -> subprocess.Popen:
    """Start a ground-truth child (it imports its libraries at once, then waits for a job): hand it to
    :class:`BackgroundGroundTruth`, or end it (``kill``) when there is no job for it."""
    return subprocess.Popen([python or sys.executable, "-m", __name__, str(os.getpid())],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)


class BackgroundGroundTruth:
    """A child process writing the ground truth of the frames :meth:`submit` names; :meth:`wait` for each.

    Start it before Blender opens the scene, so that the model loads meanwhile; :meth:`close` when done
    (waits for the child; raises if it failed).
    """

    def __init__(self, job: Job, python: str | None = None, process: subprocess.Popen | None = None):
        """``process``: a child started by :func:`spawn` (that has not been given a job yet); default a new one."""
        self._futures: dict[int, Future] = {}
        self._lock = threading.Lock()
        self._proc = process if process is not None else spawn(python)
        self._proc.stdin.write(json.dumps(asdict(job)) + "\n")
        self._proc.stdin.flush()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _future(self, index: int) -> Future:
        with self._lock:
            return self._futures.setdefault(int(index), Future())

    def _read(self) -> None:
        """Resolve each frame's future from the child's lines; when they end, fail whatever is left."""
        for line in self._proc.stdout:
            word, index, cpu, rss = line.split()
            if word == "done":
                self._future(int(index)).set_result(FrameCost(float(cpu), float(rss)))
        code = self._proc.wait()
        with self._lock:
            left = [f for f in self._futures.values() if not f.done()]
        for future in left:
            future.set_exception(RuntimeError(f"the ground-truth process ended (exit status {code}) before "
                                              "writing every frame: see its error above"))

    def submit(self, indices) -> None:
        """Ask for the ground truth of frames ``indices`` (computed in this order)."""
        try:
            for index in indices:
                self._future(index)
                self._proc.stdin.write(f"{int(index)}\n")
            self._proc.stdin.flush()
        except BrokenPipeError:
            pass  # the child has ended: :meth:`wait` reports it

    def done(self, index: int) -> bool:
        """Whether frame ``index``'s files are written (without waiting)."""
        return self._future(index).done()

    def wait(self, index: int) -> FrameCost:
        """Wait for frame ``index``'s files; returns what the child spent on it."""
        return self._future(index).result()

    def close(self) -> None:
        """No more frames: wait for the child to end (it finishes what it was asked first)."""
        if self._proc.stdin and not self._proc.stdin.closed:
            self._proc.stdin.close()
        self._reader.join()
        if self._proc.returncode:
            raise RuntimeError(f"the ground-truth process failed (exit status {self._proc.returncode})")

    def __enter__(self) -> BackgroundGroundTruth:
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.close()
            return
        # an error in the render: it is the one to report; do not wait for frames nobody will use
        self._proc.kill()
        self._reader.join()


def _load_libraries() -> None:
    """What every job needs, imported before the job arrives (while the worker imports Blender)."""
    from rgbd2scene.geometry.raycast import open3d_library

    open3d_library()  # the ray caster's library alone (~0.35 CPU s; the whole open3d package ~0.7)
    import rgbd2scene.groundtruth.model_maps  # noqa: F401 - numpy, the model, the ray caster
    import rgbd2scene.scene.model  # noqa: F401


def _serve(job: Job, say) -> None:
    """Load the model, then compute and write each frame index read from stdin; ``say`` sends a line."""
    from rgbd2scene.geometry.raycast import set_threads
    from rgbd2scene.groundtruth.model_maps import ModelGroundTruth
    from rgbd2scene.scene.model import SceneDescription
    from rgbd2scene.worker_protocol import resident_mb

    model = ModelGroundTruth.of_scene(SceneDescription.from_dict(job.description), job.scene_dir, job.frames,
                                      tuple(job.maps))
    set_threads(1)  # frames are computed THREADS at a time: each cast on its own thread, no pool beside it
    os.nice(NICENESS)  # loaded at the render's priority (beside Blender's start-up, mostly one core); frames after
    lock = threading.Lock()

    def write(index: int) -> None:
        try:
            cpu = time.thread_time()
            model.write(job.out_dir, index, Path(job.scratch))
            with lock:
                say(f"done {index} {time.thread_time() - cpu:.4f} {resident_mb():.1f}")
        except BaseException:  # noqa: BLE001 - end at once: the parent reports it
            traceback.print_exc()
            os._exit(1)

    with ThreadPoolExecutor(max_workers=THREADS) as pool:
        for line in sys.stdin:
            if line.strip():
                pool.submit(write, int(line))


def main(argv: list[str]) -> int:
    from rgbd2scene.worker_protocol import tie_to_parent

    tie_to_parent(int(argv[0]))  # never outlive the render worker
    progress = os.fdopen(os.dup(1), "w", buffering=1)  # stdout carries our lines only (open3d prints)
    os.dup2(2, 1)

    def say(line: str) -> None:
        progress.write(line + "\n")
        progress.flush()

    _load_libraries()
    line = sys.stdin.readline()
    if line.strip():  # else no job: the parent had none for us
        _serve(Job(**json.loads(line)), say)
    # every frame is written and announced: end now, without the interpreter's teardown (open3d's and numpy's
    # modules, ~0.2 s) that the render worker would wait for
    progress.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
