"""The one Blender entry point: ``python -m render.worker TASK.json`` (see :mod:`rgbd2scene.stages.blender`).

Reads the task, runs the handler of its payload (:data:`HANDLERS`: build a scene, render, describe) and
reports on stdout with the progress protocol's lines only: everything else (Blender's C-level prints
included) is sent to stderr, which the caller keeps for its error message. Exit status 0 on success, 2
for a problem with the task's inputs (``error: ...``), 1 for anything else (with a traceback on stderr).
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

from rgbd2scene.worker_protocol import BuildScene, Describe, Render, Task, parse_line, ready_line, tie_to_parent


class TaskError(RuntimeError):
    """A problem with the task's inputs, reported as one ``error:`` line."""


def build(bpy, job: BuildScene, say, t0: float) -> None:
    from render.scene_builder import build_scene
    from rgbd2scene.scene.model import SceneDescription

    say(ready_line(time.perf_counter() - t0, "CPU"))
    build_scene(SceneDescription.from_dict(job.description), Path(job.scene_dir), Path(job.blend))
    say(f"built {job.blend}")


def render(bpy, job: Render, say, t0: float) -> None:
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
        render_task(bpy, job, say_timed)
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


def run(task: Task, say) -> None:
    t0 = time.perf_counter()
    import bpy

    HANDLERS[type(task.payload)](bpy, task.payload, say, t0)


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
        if len(argv) != 1:
            raise TaskError("usage: python -m render.worker TASK.json")
        try:
            task = Task.from_json(Path(argv[0]).read_text())
        except (OSError, ValueError, TypeError) as exc:
            raise TaskError(f"{argv[0]}: not a task file ({exc})") from None
        run(task, say)
        return 0
    except TaskError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - report everything to the parent, which shows the tail
        traceback.print_exc()
        return 1
    finally:
        progress.close()


if __name__ == "__main__":
    tie_to_parent()  # first, before anything slow (importing bpy): a worker never outlives its caller
    sys.exit(main())
