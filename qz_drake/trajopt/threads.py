"""BLAS threads during a BLC solve.

Our constraint callbacks multiply small matrices (a binding's Jacobian by Drake's AutoDiff
seed) many times per Ipopt iterate. numpy's OpenBLAS runs such products on all cores and its
worker threads then spin between calls, taking the core the solver's own thread needs.
Measured on the 2-core machine shared by several processes (issue 11, interleaved runs): with
OpenBLAS limited to one thread Qingzhui flat 1 m / 2 s took 0.5-0.65x the time. The limit
holds only inside the solve (threadpoolctl), so other work in the process keeps its threads.
"""

from __future__ import annotations

import contextlib


@contextlib.contextmanager
def blas_threads(num_threads: int | None):
    """Within the block numpy's BLAS uses ``num_threads`` threads (None or 0: unchanged)."""
    if not num_threads:
        yield
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # threadpoolctl comes with scikit-learn; without it, no limit
        yield
        return
    with threadpool_limits(limits=int(num_threads), user_api="blas"):
        yield
