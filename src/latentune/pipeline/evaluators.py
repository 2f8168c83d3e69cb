"""Evaluators for the pipeline: serial, a local process pool, and Ray (DESIGN §6).

All implement the :class:`latentune.evaluators.Evaluator` protocol, ``map(fun, X) -> y`` (y: the
(n,) float costs in the order of X), and an incremental form ``imap(fun, X)`` that yields
``(i, result)`` as each evaluation completes, so the caller can commit each row at once.

``fun`` is either a :class:`~latentune.task.Task` -- then ``result`` is a dict with ``cost, fell,
fall_step, wall_s, steps, mean_vx, reason`` and each worker keeps one Task (with its PyBullet
client) per task configuration for the rest of its life -- or any picklable callable
``(d,) ndarray -> float``, then ``result`` is ``{"cost": float}``. An exception inside an
evaluation becomes ``cost = inf`` with the message in ``reason`` (never a crashed run).

The process pool uses forkserver (spawn elsewhere): a script that creates one must guard its
entry point with ``if __name__ == "__main__":`` (the usual multiprocessing rule).

Workers limit BLAS/OpenMP to one thread (the rollouts are many small matrix operations; default
threading made them 22x slower here).
"""
from __future__ import annotations

import json
import os
from typing import Any, Callable, Iterator

import numpy as np

_BLAS_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")
BACKENDS = ("serial", "process", "ray")


def _one_thread_env() -> None:
    for v in _BLAS_VARS:
        os.environ.setdefault(v, "1")


def _is_task(fun: Any) -> bool:
    from latentune.task import Task

    return isinstance(fun, Task)


def task_key(task: Any) -> str:
    """A key identifying a task's configuration (workers cache one Task per key)."""
    cfg = task.config()
    cfg["spec"] = getattr(task.spec, "name", "")
    cfg["actor_cls"] = getattr(task.actor_cls, "__name__", "")
    return json.dumps(cfg, sort_keys=True, default=str)


def _task_result(res: Any) -> dict[str, Any]:
    return {"cost": float(res.cost), "fell": bool(res.fell), "fall_step": res.fall_step,
            "wall_s": float(res.wall_s), "steps": int(res.steps), "mean_vx": float(res.mean_vx),
            "reason": res.reason}


_WORKER_TASKS: dict[str, Any] = {}


def _init_worker() -> None:
    _one_thread_env()
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except Exception:  # noqa: BLE001
        pass


def evaluate_one(fun: Any, key: str | None, x: np.ndarray) -> dict[str, Any]:
    """Evaluate one point in this process (worker side); Tasks are cached by ``key``."""
    import time

    t0 = time.perf_counter()
    try:
        if key is not None:
            task = _WORKER_TASKS.get(key)
            if task is None:
                _WORKER_TASKS.clear()          # one Task (one PyBullet client) per worker
                _WORKER_TASKS[key] = task = fun
            return _task_result(task.rollout(np.asarray(x, dtype=float)))
        return {"cost": float(fun(np.asarray(x, dtype=float).copy())),
                "wall_s": time.perf_counter() - t0}
    except Exception as exc:  # noqa: BLE001 - an evaluation never crashes the run
        return {"cost": float("inf"), "fell": True, "fall_step": None,
                "wall_s": time.perf_counter() - t0,
                "reason": f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"}


class _Base:
    workers: int = 1

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, dict[str, Any]]]:
        raise NotImplementedError

    def map(self, fun: Callable[[np.ndarray], float] | Any, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        y = np.full(X.shape[0], np.nan)
        for i, r in self.imap(fun, X):
            y[i] = r["cost"]
        return y

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SerialEvaluator(_Base):
    """In this process, one point after the other."""

    workers = 1

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, dict[str, Any]]]:
        key = task_key(fun) if _is_task(fun) else None
        for i, x in enumerate(np.asarray(X, dtype=float)):
            if key is not None:
                yield i, _task_result(fun.rollout(x))
            else:
                yield i, evaluate_one(fun, None, x)

    def __repr__(self) -> str:
        return "SerialEvaluator()"


class ProcessEvaluator(_Base):
    """A local pool of ``workers`` processes (forkserver on Linux, else spawn).

    Each worker keeps one Task and its PyBullet client between evaluations. Call :meth:`close`
    (or use it as a context manager) to stop the workers.
    """

    def __init__(self, workers: int = 2, start_method: str | None = None) -> None:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        if workers < 1:
            raise ValueError("workers must be >= 1")
        _one_thread_env()
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self.workers = int(workers)
        self.start_method = start_method
        self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context(start_method),
                                         initializer=_init_worker)

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, dict[str, Any]]]:
        from concurrent.futures import FIRST_COMPLETED, wait

        X = np.asarray(X, dtype=float)
        key = task_key(fun) if _is_task(fun) else None
        futs = {self._pool.submit(evaluate_one, fun, key, x): i for i, x in enumerate(X)}
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
    """A Ray actor keeping one Task (one PyBullet client)."""

    def __init__(self) -> None:
        _init_worker()

    def run(self, fun: Any, key: str | None, x: np.ndarray) -> dict[str, Any]:
        return evaluate_one(fun, key, x)


class RayEvaluator(_Base):
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
        _one_thread_env()
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
        env = {v: "1" for v in _BLAS_VARS}
        actor = ray.remote(num_cpus=1, runtime_env={"env_vars": env})(_RayWorker)
        self._actors = [actor.remote() for _ in range(self.workers)]

    def imap(self, fun: Any, X: np.ndarray) -> Iterator[tuple[int, dict[str, Any]]]:
        ray = self._ray
        X = np.asarray(X, dtype=float)
        key = task_key(fun) if _is_task(fun) else None
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
            except Exception:  # noqa: BLE001
                pass
        self._actors = []
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
            self._owns = False

    def __repr__(self) -> str:
        return f"RayEvaluator(workers={self.workers}, address={self.address!r})"


def make_evaluator(backend: str = "process", workers: int = 2, address: str | None = None,
                   temp_dir: str | None = None) -> _Base:
    """``serial``, ``process`` (a pool of ``workers``; ``workers == 1`` → serial) or ``ray``."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if backend == "serial" or (backend == "process" and workers == 1):
        return SerialEvaluator()
    if backend == "process":
        return ProcessEvaluator(workers)
    return RayEvaluator(workers, address=address, temp_dir=temp_dir)
