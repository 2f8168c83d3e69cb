"""Evaluators: run a batch of trials serially, in a local process pool, or on Ray (one protocol).

An evaluator maps ``fun`` over the rows of ``X`` (n, d):

* ``imap(fun, X)`` yields ``(i, result)`` as each trial completes (any order), so the caller
  can store every trial at once; ``map(fun, X)`` returns the (n,) float costs in the order of X.
* ``fun`` is a System (an object with ``evaluate``, see :mod:`latentune.system`): then
  ``result`` is an :class:`~latentune.system.Outcome`; or a plain callable ``(d,) -> float``
  (``lt.minimize``): then ``result`` is an Outcome holding the float as it was returned
  (nan/inf allowed there).
* A trial that raises, or a System that returns no usable cost, yields a :class:`TrialError`
  (the message, one line) in place of the Outcome, the same way on every backend; ``map``
  raises :class:`~latentune.system.EvaluationError` for it. Trials that finished are yielded
  before the error is seen by the caller's next step, so they can be stored.

Workers keep one instance of a System that has ``cache_key()`` (a simulated Task keeps its
PyBullet client) for the rest of their life, and run with one BLAS thread
(:mod:`latentune.threads`). The process pool uses forkserver (spawn where unavailable): a
script that creates one must guard its entry point with ``if __name__ == "__main__":``.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from latentune.system import EvaluationError, Outcome, evaluate
from latentune.threads import one_thread_env, thread_env

BACKENDS = ("serial", "process", "ray")


@dataclass(frozen=True)
class TrialError:
    """A trial that raised or returned no usable cost: ``message`` is one line."""

    message: str


def _key(fun: Any) -> str | None:
    ck = getattr(fun, "cache_key", None)
    return ck() if callable(ck) else None


_WORKER_CACHE: dict[str, Any] = {}


def _init_worker() -> None:
    one_thread_env()
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass


def run_trial(fun: Any, key: str | None, x: np.ndarray) -> Outcome | TrialError:
    """Evaluate one point in this process (the worker side of every backend).

    A System with a ``key`` is cached: the worker keeps the first instance sent with that key.
    """
    if key is not None:
        cached = _WORKER_CACHE.get(key)
        if cached is None:
            _WORKER_CACHE.clear()              # one cached System (one simulator) per worker
            _WORKER_CACHE[key] = cached = fun
        fun = cached
    x = np.asarray(x, dtype=float).copy()
    try:
        if hasattr(fun, "evaluate"):
            return evaluate(fun, x)
        t0 = time.perf_counter()
        return Outcome(float(fun(x)), wall_s=time.perf_counter() - t0)
    except EvaluationError as exc:
        return TrialError(str(exc))
    except Exception as exc:  # noqa: BLE001 - a plain callable that raised
        return TrialError(f"the function raised {type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:300]}")


class Evaluator:
    """Base of every evaluator: ``imap`` (subclasses), ``map``, ``close`` and context use."""

    workers: int = 1

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, Outcome | TrialError]]:
        """Yield ``(i, Outcome or TrialError)`` for every row i of X (n, d), as they complete."""
        raise NotImplementedError

    def map(self, fun: Any, X: np.ndarray) -> np.ndarray:
        """(n,) float64 costs in the order of X (n, d). Raises EvaluationError on a TrialError."""
        X = np.asarray(X, dtype=float)
        y = np.full(X.shape[0], np.nan)
        for i, r in self.imap(fun, X):
            if isinstance(r, TrialError):
                raise EvaluationError(r.message)
            y[i] = r.cost
        return y

    def close(self) -> None:
        """Stop the workers (no-op for the serial evaluator)."""

    def __enter__(self) -> "Evaluator":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SerialEvaluator(Evaluator):
    """In this process, one point after the other."""

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, Outcome | TrialError]]:
        for i, x in enumerate(np.asarray(X, dtype=float)):
            yield i, run_trial(fun, None, x)

    def __repr__(self) -> str:
        return "SerialEvaluator()"


class ProcessEvaluator(Evaluator):
    """A local pool of ``workers`` processes (forkserver on Linux, else spawn)."""

    def __init__(self, workers: int = 2, start_method: str | None = None) -> None:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        if workers < 1:
            raise ValueError("workers must be >= 1")
        one_thread_env()
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self.workers = int(workers)
        self.start_method = start_method
        self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context(start_method),
                                         initializer=_init_worker)

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, Outcome | TrialError]]:
        from concurrent.futures import FIRST_COMPLETED, wait

        X = np.asarray(X, dtype=float)
        key = _key(fun)
        futs = {self._pool.submit(run_trial, fun, key, x): i for i, x in enumerate(X)}
        pending = set(futs)
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in sorted(done, key=lambda f: futs[f]):
                    yield futs[f], f.result()
        finally:
            for f in pending:
                f.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __repr__(self) -> str:
        return f"ProcessEvaluator(workers={self.workers}, start_method={self.start_method!r})"


class _RayWorker:
    """A Ray actor keeping one cached System."""

    def __init__(self) -> None:
        _init_worker()

    def run(self, fun: Any, key: str | None, x: np.ndarray) -> Outcome | TrialError:
        return run_trial(fun, key, x)


class RayEvaluator(Evaluator):
    """``workers`` Ray actors on a cluster (``address``) or on a local Ray started here.

    A local Ray gets ``num_cpus=workers``; its temp dir is ``temp_dir`` or ``$RAY_TMPDIR``.
    Ray is shut down on :meth:`close` only if this evaluator started it.
    """

    def __init__(self, workers: int = 2, address: str | None = None,
                 temp_dir: str | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise RuntimeError("the ray backend needs ray (pip install 'latentune[ray]')") from None
        if workers < 1:
            raise ValueError("workers must be >= 1")
        one_thread_env()
        self.workers = int(workers)
        self.address = address
        self._owns = False
        if not ray.is_initialized():
            kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": False}
            if address:
                ray.init(address=address, **kw)
            else:
                tmp = temp_dir or os.environ.get("RAY_TMPDIR")
                if tmp:
                    kw["_temp_dir"] = os.path.abspath(tmp)
                ray.init(num_cpus=self.workers, **kw)
            self._owns = True
        self._ray = ray
        actor = ray.remote(num_cpus=1, runtime_env={"env_vars": thread_env()})(_RayWorker)
        self._actors = [actor.remote() for _ in range(self.workers)]

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, Outcome | TrialError]]:
        ray = self._ray
        X = np.asarray(X, dtype=float)
        key = _key(fun)
        fun_ref = ray.put(fun)
        todo = list(range(X.shape[0]))
        idle = list(self._actors)
        running: dict[Any, tuple[int, Any]] = {}
        while todo or running:
            while todo and idle:
                i, a = todo.pop(0), idle.pop(0)
                running[a.run.remote(fun_ref, key, X[i])] = (i, a)
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                i, a = running.pop(ref)
                idle.append(a)
                yield i, ray.get(ref)

    def close(self) -> None:
        for a in getattr(self, "_actors", []):
            try:
                self._ray.kill(a)
            except Exception:  # noqa: BLE001 - the actor may already be gone
                pass
        self._actors = []
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
            self._owns = False

    def __repr__(self) -> str:
        return f"RayEvaluator(workers={self.workers}, address={self.address!r})"


def make_evaluator(backend: str = "process", workers: int = 2, address: str | None = None,
                   temp_dir: str | None = None) -> Evaluator:
    """``serial``, ``process`` (a pool of ``workers``; ``workers == 1`` → serial) or ``ray``."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if backend == "serial" or (backend == "process" and workers == 1):
        return SerialEvaluator()
    if backend == "process":
        return ProcessEvaluator(workers)
    return RayEvaluator(workers, address=address, temp_dir=temp_dir)
