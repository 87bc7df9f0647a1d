"""The one Blender entry point: ``python -m render.worker TASK.json`` (see :mod:`rgbd2scene.stages.blender`).

Reads the task, runs the handler of its payload (:data:`HANDLERS`: build a scene, render, describe) and
reports on stdout with the progress protocol's lines only: everything else (Blender's C-level prints
included) is sent to stderr, which the caller keeps for its error message. Exit status 0 on success, 2
for a problem with the task's inputs (``error: ...``), 1 for anything else (with a traceback on stderr).

``python -m render.worker --serve`` runs one task per line of stdin in the same process (a batch build's
long-lived worker: Blender starts once) and ends each with an ``end STATUS peak ...MB`` line carrying the
status above. Between tasks Blender is reset to its factory state (:func:`reset_blender`), so a task's output
does not depend on what the process did before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import json
import os
import sys
import time
import traceback
from pathlib import Path

from rgbd2scene.worker_protocol import (
    SERVE_FLAG,
    BuildScene,
    Describe,
    Render,
    Task,
    end_line,
    parse_line,
    peak_rss_mb,
    ready_line,
    tie_to_parent,
)


class TaskError(RuntimeError):
    """A problem with the task's inputs, reported as one ``error:`` line."""


def build(bpy, job: BuildScene, say, t0: float) -> None:
    from render.scene_builder import build_scene
    from rgbd2scene.scene.model import SceneDescription

    say(ready_line(time.perf_counter() - t0, "CPU"))
    build_scene(SceneDescription.from_dict(job.description), Path(job.scene_dir), Path(job.blend))
    say(f"built {job.blend}")


def render(bpy, job: Render, say, t0: float, gt_process=None) -> None:
    from render.frames import WorkerError, render_task
    from render.timing import PhaseClock

    clock = PhaseClock(bpy)

    def say_timed(line: str) -> None:
        """A frame's progress line with the phases Cycles spent on it (``rgb_trace 1.2s``...)."""
        event = parse_line(line)
        if event is not None and event.kind in ("rgb", "done"):
            phases = clock.take("rgb", event.frame)
            if event.kind == "done":
                phases.update(clock.take("gt", event.frame))
            line += "".join(f" {k} {v:.3f}s" for k, v in phases.items())
        say(line)

    try:
        render_task(bpy, job, say_timed, gt_process=gt_process)
    except WorkerError as exc:
        raise TaskError(str(exc)) from None


def describe(bpy, job: Describe, say, t0: float) -> None:
    from render.scene_builder import SCENE_PROPERTY
    from rgbd2scene.scene.folder import SCENE_BLEND
    from rgbd2scene.scene.model import SceneDescription

    blend = Path(job.scene_dir) / SCENE_BLEND
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    stored = bpy.context.scene.get(SCENE_PROPERTY)
    if stored is None:
        raise TaskError(f"{blend}: holds no scene description")
    say("describe " + json.dumps(SceneDescription.from_dict(json.loads(stored)).to_dict()))


#: Payload type -> its handler ``(bpy, payload, say, t0)`` (``t0``: when the worker started the task).
HANDLERS = {BuildScene: build, Render: render, Describe: describe}


def _model_gt_process(payload):
    """For a render whose ground truth comes from the scene model: its ground-truth child, started now, so that
    it imports its libraries (~0.5 CPU s) while this process imports Blender (mostly one core); else None."""
    if not isinstance(payload, Render):
        return None
    from rgbd2scene.rendering import RenderOptions

    try:
        options = RenderOptions(**payload.render).validated()
    except Exception:  # noqa: BLE001 - the render handler reports a bad task
        return None
    if not options.gt_from_model:
        return None
    from rgbd2scene.groundtruth.background import spawn

    return spawn()


def run(task: Task, say) -> None:
    t0 = time.perf_counter()
    gt_process = _model_gt_process(task.payload)
    try:
        import bpy

        extra = {} if gt_process is None else {"gt_process": gt_process}
        HANDLERS[type(task.payload)](bpy, task.payload, say, t0, **extra)
    finally:
        if gt_process is not None and gt_process.poll() is None:  # never handed its job (the task failed first)
            gt_process.kill()
            gt_process.wait()


def run_text(text: str, where: str, say) -> int:
    """Run the task of ``text`` (read from ``where``); its exit status (module docstring)."""
    try:
        try:
            task = Task.from_json(text)
        except (ValueError, TypeError) as exc:
            raise TaskError(f"{where}: not a task file ({exc})") from None
        run(task, say)
        return 0
    except TaskError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - report everything to the parent, which shows the tail
        traceback.print_exc()
        return 1
    finally:
        sys.stderr.flush()


def reset_blender() -> None:
    """Back to the state of a fresh process: factory settings (preferences such as the GPU devices included),
    no data-blocks, images or render engine data left from the task before (with persistent data, the Normal
    pass of a render once depended on what the process had rendered before); the heap's free pages returned."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=False)
    gc.collect()
    _release_free_memory()


def _release_free_memory() -> None:
    """Hand the C heap's free pages back to the system (glibc's ``malloc_trim``): what Blender freed would
    otherwise stay resident while the worker waits for its next task."""
    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def serve(say) -> int:
    """Run the tasks of stdin's lines one after the other until stdin closes (exit status 0), or until Blender
    fails to reset between them (1)."""
    peak_rss_mb(reset=True)
    for number, text in enumerate(sys.stdin, 1):
        status = run_text(text, f"stdin line {number}", say)
        try:
            if "bpy" in sys.modules:
                reset_blender()
        except Exception:  # noqa: BLE001 - the task is done; a worker that cannot reset ends (the next starts fresh)
            traceback.print_exc()
            say(end_line(status, peak_rss_mb()))
            return 1
        say(end_line(status, peak_rss_mb(reset=True)))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # stdout is the progress channel: keep it for our lines and send everything else to stderr
    sys.stdout.flush()
    progress = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)

    def say(line: str) -> None:
        progress.write(line + "\n")
        progress.flush()

    try:
        if argv == [SERVE_FLAG]:
            return serve(say)
        if len(argv) != 1:
            print(f"error: usage: python -m render.worker TASK.json | {SERVE_FLAG}", file=sys.stderr)
            return 2
        try:
            text = Path(argv[0]).read_text()
        except OSError as exc:
            print(f"error: {argv[0]}: not a task file ({exc})", file=sys.stderr)
            return 2
        return run_text(text, argv[0], say)
    finally:
        progress.close()


def quick_exit(status: int) -> None:
    """End the process without Blender's teardown, which frees every data-block one by one (0.2-0.3 s per
    worker, on the caller's critical path: it waits for the exit) where the system frees it all at once.
    Everything the task wrote is closed by then; what the teardown would also do is delete Blender's session
    temporary folder, so that is done here."""
    sys.stdout.flush()
    sys.stderr.flush()
    if "bpy" in sys.modules:
        import shutil

        shutil.rmtree(sys.modules["bpy"].app.tempdir, ignore_errors=True)
    os._exit(status)


if __name__ == "__main__":
    tie_to_parent()  # first, before anything slow (importing bpy): a worker never outlives its caller
    quick_exit(main())
