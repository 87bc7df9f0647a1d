"""The units of work of a batch build, as plain functions any engine runs (a local thread, a Dask worker).

- :func:`build_mesh`: reconstruct one capture into its mesh folder (numpy/Open3D, in the calling process);
- :func:`build_scene`: one sequence's scene folder from a mesh (or scene) folder; Blender runs in its own
  process through :func:`rgbd2scene.stages.blender.run_task`;
- :func:`render_chunk`: one chunk of frames of one sequence, likewise.

The Blender process is the running thread's long-lived worker (:func:`rgbd2scene.stages.blender.reusing_workers`):
started by the first unit a pool thread or Dask worker thread runs, it takes every later scene build and chunk
of that thread, whatever their sequence (the engine ends it when it closes). None of the units imports ``bpy``:
a Dask worker stays a plain Python process. Each returns an :class:`Outcome`
instead of raising, so what went wrong reaches the driver the same way from any engine; only the engine's
own failures (a worker killed) surface as exceptions of the future.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rgbd2scene.errors import RenderError, UserError


@dataclass
class Outcome:
    """How a unit of work ended: ``error`` is the first line of a failure, ``log`` its whole text (the worker
    log's tail, or a traceback); ``peak_rss_mb`` is the Blender worker's peak memory."""

    ok: bool
    seconds: float
    error: str = ""
    log: str = ""
    peak_rss_mb: float = 0.0


def _run(work: Callable[[], float]) -> Outcome:
    """Run ``work`` (returning the worker's peak memory in MB; its Blender tasks in the thread's long-lived
    worker) and report how it ended."""
    from rgbd2scene.stages.blender import reusing_workers

    t0 = time.perf_counter()
    try:
        with reusing_workers():
            peak = work()
    except (UserError, RenderError) as exc:
        text = str(exc).strip() or type(exc).__name__
        return Outcome(False, time.perf_counter() - t0, text.splitlines()[0], text)
    except Exception as exc:  # noqa: BLE001 - a failed unit must not stop the others; the log keeps the traceback
        first = f"{type(exc).__name__}: {exc}".strip().splitlines()[0]
        return Outcome(False, time.perf_counter() - t0, first, traceback.format_exc())
    return Outcome(True, time.perf_counter() - t0, peak_rss_mb=peak)


def build_mesh(capture, out_dir: str) -> Outcome:
    """Reconstruct ``capture`` (a :class:`rgbd2scene.batch.config.Capture`) into the mesh folder ``out_dir``."""

    def work() -> float:
        from rgbd2scene.options import OptionError
        from rgbd2scene.stages.capture import load_inputs, reconstruct_inputs
        from rgbd2scene.stages.mesh import write_mesh_folder

        try:
            recon = reconstruct_inputs(load_inputs(capture.inputs), capture.mesh)
        except OptionError as exc:  # named by the configuration's key
            raise UserError(exc.render(where=capture.where)) from None
        except UserError as exc:  # names the file; the entry too
            raise UserError(f"{capture.where}: {exc}") from None
        write_mesh_folder(out_dir, recon)
        return 0.0

    return _run(work)


def build_scene(source_dir: str, scene_dir: str, options) -> Outcome:
    """Build the scene folder ``scene_dir`` with ``options`` (SceneOptions) over the mesh of ``source_dir``."""

    def work() -> float:
        from rgbd2scene.files.atomic import ensure_output_dir
        from rgbd2scene.stages.scene import build_scene_folder, load_mesh_folder

        out = ensure_output_dir(scene_dir)
        mesh, record = load_mesh_folder(source_dir, out)
        build_scene_folder(out, mesh, record, options)
        return 0.0

    return _run(work)


def render_chunk(job, group: list[int]) -> Outcome:
    """Render frames ``group`` of a prepared :class:`rgbd2scene.stages.render.RenderJob`."""

    def work() -> float:
        from rgbd2scene.stages.blender import run_task

        result = run_task(job.task(group), what="render worker", where=f" on frames {group[0]}-{group[-1]}")
        missing = job.incomplete(group)
        if missing:
            raise RenderError(f"render worker finished but frames {missing} of {Path(job.out)} are incomplete")
        return result.peak_rss_mb

    return _run(work)
