"""One BLAS/OpenMP thread for rollouts and workers.

Rollouts are many small matrix operations, which gain nothing from several BLAS threads and
lose much when the threads compete for the cores with other workers. The command line, the tests
and every evaluator worker call :func:`one_thread_env` before numpy is imported; a library user
who runs rollouts in their own process can call it too, or use :func:`one_thread` as a context.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

THREAD_VARS: tuple[str, ...] = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                "NUMEXPR_NUM_THREADS")


def one_thread_env() -> None:
    """Set every BLAS/OpenMP thread variable to 1 unless the user set it (affects libraries
    loaded after this call)."""
    for v in THREAD_VARS:
        os.environ.setdefault(v, "1")


def thread_env() -> dict[str, str]:
    """The environment variables of :func:`one_thread_env`, for a subprocess or a Ray worker."""
    return {v: "1" for v in THREAD_VARS}


@contextmanager
def one_thread() -> Iterator[None]:
    """Limit the already loaded BLAS/OpenMP libraries (and torch) to one thread inside the block."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield
