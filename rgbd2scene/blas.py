"""One BLAS thread while our own threads run solvers side by side.

NumPy and SciPy each load their own OpenBLAS, which starts a thread per core for a large enough vector
operation. Two sparse solves running in two of our threads (the hole fill's base fills) then fight over the
two cores with four BLAS threads: measured on the 640x480 TUM frame, the fill took 0.96 s wall and 1.55 s CPU
that way, 0.70 s and 1.3 s with one BLAS thread each (the same bytes: each reduction runs in the same order).
:func:`single_blas_thread` limits every loaded BLAS to one thread through ``threadpoolctl``; overlapping blocks
(threads of a local pool) share one limit, which the last of them to end lifts.
"""

from __future__ import annotations

import contextlib
import threading

from threadpoolctl import threadpool_limits

_lock = threading.Lock()
_inside = 0  # blocks running in single_blas_thread
_limit: threadpool_limits | None = None


@contextlib.contextmanager
def single_blas_thread():
    """Run the block with every loaded BLAS on one thread; the last overlapping block to end restores them."""
    global _inside, _limit
    with _lock:
        if _inside == 0:
            _limit = threadpool_limits(limits=1, user_api="blas")
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0:
                _limit.restore_original_limits()
                _limit = None
