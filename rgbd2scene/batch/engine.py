"""Where the units of work run: a local pool of threads, a local Dask cluster, or an existing Dask scheduler.

The same task functions (:mod:`rgbd2scene.batch.tasks`) are submitted either way. The heavy work happens in
processes the tasks start (Blender workers through ``run_task``), so a thread per concurrent unit is all a
local pool needs, and Dask workers never import ``bpy`` themselves. Each thread keeps its Blender worker for
the next unit; closing an engine ends them (:func:`rgbd2scene.stages.blender.close_workers`).
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from rgbd2scene.errors import UserError

#: How long to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 20
DASHBOARD_ADDRESS = ":8787"
#: Variables Dask sets to 1 in the processes it spawns (``distributed.nanny.pre-spawn-environ``).
THREAD_LIMITS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@dataclass
class EngineInfo:
    kind: str  # "local pool", "local Dask cluster", "Dask scheduler"
    workers: int
    dashboard: str | None = None

    def describe(self) -> str:
        text = f"{self.kind}, {self.workers} worker{'s' if self.workers != 1 else ''}"
        return text + (f", dashboard {self.dashboard}" if self.dashboard else "")


class LocalEngine:
    """A pool of ``workers`` threads (each drives one unit at a time; Blender runs in its own process)."""

    def __init__(self, workers: int = 1):
        self.pool = concurrent.futures.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="rgbd2scene")
        self.info = EngineInfo("local pool", workers)

    def submit(self, fn: Callable, *args, key: str = "", priority: int = 0) -> concurrent.futures.Future:
        return self.pool.submit(fn, *args)

    def wait(self, futures: Iterable, timeout: float) -> None:
        """Return when one of ``futures`` is done, or after ``timeout`` seconds."""
        concurrent.futures.wait(list(futures), timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED)

    def close(self) -> None:
        from rgbd2scene.stages.blender import close_workers

        self.pool.shutdown(wait=True, cancel_futures=True)
        close_workers()


class DaskEngine:
    """A Dask ``Client``: of a local cluster of ``workers`` processes (one thread each), or of the scheduler at
    ``address`` (its workers must see ROOT and the captures at the same paths, e.g. a shared file system)."""

    def __init__(self, workers: int | None = None, address: str | None = None, dashboard: bool = False):
        from distributed import Client, LocalCluster

        self.cluster = None
        self._config = None
        if address is None:
            # A worker runs one unit at a time, which should use the cores: Dask would start its workers with
            # OMP/MKL/OpenBLAS limited to one thread (measured: the mesh stage 1.8x, the scene stage 1.9x slower)
            import dask

            environ = dask.config.get("distributed.nanny.pre-spawn-environ", {})
            self._config = dask.config.set({"distributed.nanny.pre-spawn-environ": {
                k: v for k, v in environ.items() if k not in THREAD_LIMITS}})
            # memory_limit 0: the Blender processes a task starts are not the worker's memory, and Dask's
            # memory monitor would otherwise pause a worker for what its own imports (Open3D) take
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=0,
                                        dashboard_address=DASHBOARD_ADDRESS if dashboard else None,
                                        silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
            kind = "local Dask cluster"
        else:
            try:
                self.client = Client(address, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, ValueError) as exc:
                raise UserError(f"--scheduler: cannot reach a Dask scheduler at {address} ({exc})") from None
            kind = "Dask scheduler"
        count = len(self.client.scheduler_info().get("workers", {}))
        self.info = EngineInfo(kind, count, self.client.dashboard_link if dashboard else None)

    def submit(self, fn: Callable, *args, key: str = "", priority: int = 0):
        # unique keys: Dask would otherwise hand back the result of an earlier identical call
        return self.client.submit(fn, *args, key=f"{key}-{os.urandom(4).hex()}", pure=False, priority=priority)

    def wait(self, futures: Iterable, timeout: float) -> None:
        from distributed import wait

        try:
            wait(list(futures), timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            pass

    def close(self) -> None:
        from rgbd2scene.stages.blender import close_workers

        try:  # the workers' Blender processes (a scheduler's workers live on after this build)
            self.client.run(close_workers)
        except Exception:  # noqa: BLE001 - a worker already gone: the client and cluster must still close
            pass
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        if self._config is not None:
            self._config.__exit__(None, None, None)


def check_engine(workers: int | None = None, scheduler: str | None = None, jobs: int = 1,
                 dashboard: bool = False) -> None:
    """Refuse engine settings that cannot work, before anything starts (one-line :class:`UserError`)."""
    if scheduler is not None and workers is not None:
        raise UserError("--workers and --scheduler: give one (--workers starts a local cluster; --scheduler uses one)")
    if workers is not None and workers < 1:
        raise UserError(f"--workers: must be at least 1, got {workers}")
    if jobs < 1:
        raise UserError(f"--jobs: must be at least 1, got {jobs}")
    if dashboard and scheduler is None and workers is None:
        raise UserError("--dashboard: needs Dask (--workers N or --scheduler ADDRESS)")


def open_engine(workers: int | None = None, scheduler: str | None = None, jobs: int = 1,
                dashboard: bool = False) -> LocalEngine | DaskEngine:
    """The engine the command line asks for: ``--scheduler`` or ``--workers`` (Dask), else a local pool."""
    check_engine(workers, scheduler, jobs, dashboard)
    if scheduler is not None or workers is not None:
        return DaskEngine(workers, scheduler, dashboard)
    return LocalEngine(jobs)
