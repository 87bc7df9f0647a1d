"""One BLAS thread while our own threads run solvers side by side.

NumPy and SciPy each load their own OpenBLAS, which starts a thread per core for a large enough vector
operation. Two sparse solves running in two of our threads (the hole fill's base fills) then fight over the
two cores with four BLAS threads: measured on the 640x480 TUM frame, the fill took 0.96 s wall and 1.55 s CPU
that way, 0.70 s and 1.3 s with one BLAS thread each (the same bytes: each reduction runs in the same order).
:func:`single_blas_thread` sets every loaded OpenBLAS to one thread and back, through its own
``openblas_set_num_threads`` (what ``threadpoolctl`` does, without the dependency). Where no OpenBLAS is found
(another BLAS, another system) it changes nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import threading
from collections.abc import Callable
from pathlib import Path

#: The name prefixes and suffixes OpenBLAS builds give ``openblas_{get,set}_num_threads`` (NumPy's 64-bit
#: integer build: ``...64_``; SciPy's: ``scipy_...``).
_PREFIXES = ("", "scipy_")
_SUFFIXES = ("", "64_")


def _openblas_libraries() -> list[tuple[Callable, Callable]]:
    """(get, set) thread-count functions of every OpenBLAS loaded in this process (Linux: /proc/self/maps)."""
    try:
        maps = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return []
    paths = sorted({line.split()[-1] for line in maps if "openblas" in line.rsplit("/", 1)[-1].lower()})
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in _PREFIXES:
            for suffix in _SUFFIXES:
                get = getattr(lib, f"{prefix}openblas_get_num_threads{suffix}", None)
                put = getattr(lib, f"{prefix}openblas_set_num_threads{suffix}", None)
                if get is not None and put is not None:
                    found.append((get, put))
                    break
            else:
                continue
            break
    return found


_lock = threading.Lock()
_inside = 0  # blocks running in single_blas_thread (threads of a local pool may overlap)
_restore: list[tuple[Callable, int]] = []


@contextlib.contextmanager
def single_blas_thread():
    """Run the block with every loaded OpenBLAS on one thread; the last overlapping block to end restores their
    thread counts."""
    global _inside
    with _lock:
        if _inside == 0:
            _restore[:] = [(put, get()) for get, put in _openblas_libraries()]
            for put, _ in _restore:
                put(1)
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0:
                for put, count in _restore:
                    put(count)
