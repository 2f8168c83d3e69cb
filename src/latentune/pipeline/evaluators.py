"""Evaluators: run a batch of trials serially, in a local process pool, or on Ray (one protocol).

An evaluator maps ``fun`` over the rows of ``X`` (n, d):

* ``imap(fun, X)`` yields ``(i, result)`` as each trial completes (any order), so the caller
  can store every trial at once; ``map(fun, X)`` returns the (n,) float costs in the order of X.
  ``imap(fun, X, stop=f)`` starts a trial only while ``f()`` is False: once it is True the
  trials not started yet are never run (nor yielded) and those running finish and are yielded
  (the process pool then holds no more trials than it has workers, so that none waits in it;
  a started trial lost with a broken pool, or with its Ray worker, is run again, as without
  ``stop``).
* ``fun`` is a System (an object with ``evaluate``, see :mod:`latentune.system`): then
  ``result`` is an :class:`~latentune.system.Outcome`; or a plain callable ``(d,) -> float``
  (``lt.minimize``): then ``result`` is an Outcome holding the float as it was returned
  (nan/inf allowed there).
* A trial that raises, or a System that returns no usable cost, yields a :class:`TrialError`
  (the message, one line) in place of the Outcome, the same way on every backend; ``map``
  raises :class:`~latentune.system.EvaluationError` for it. Trials that finished are yielded
  before the error is seen by the caller's next step, so they can be stored.
* On Ray, a trial lost with its worker or node (no result) is run again on another worker and
  yielded once (:class:`RayEvaluator`). In the process pool, a trial whose worker dies, or that
  runs longer than ``trial_timeout``, is a failed trial and the others go on
  (:class:`ProcessEvaluator`); on the serial backend it ends, or hangs, this process.

Workers keep one instance of a System that has ``cache_key()`` (a simulated Task keeps its
PyBullet client) for the rest of their life, and run with one BLAS thread: each worker sets the
thread variables of :mod:`latentune.threads` in its own environment when it starts (the
caller's ``os.environ`` is never changed). The process pool uses forkserver (spawn where
unavailable): a script that creates one must guard its entry point with
``if __name__ == "__main__":``.

Shipping a System to workers: a system made by :func:`latentune.system.load_system` (a
``--system module:factory`` plugin; it has a ``plugin_record``) is rebuilt in each process
worker from ``module:factory`` and its arguments (:class:`PluginRef`, built once per worker), so
a factory may return closures. Ray ships systems with its own serializer (cloudpickle) and falls
back to the same rebuild. Any other system is pickled; one that cannot be is refused with
:class:`~latentune.system.EvaluationError` naming ``workers=1`` (``--workers 1``).
"""
from __future__ import annotations

import json
import logging
import os
import math
import pickle
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

import numpy as np

from latentune.checks import is_whole
from latentune.system import CostError, EvaluationError, Outcome, as_cost, as_outcome, evaluate
from latentune.threads import THREAD_VARS, thread_env

BACKENDS = ("serial", "process", "ray")
MAX_LOST = 3
"""How many times a process pool runs a trial again that was lost with workers that died of
something else than a trial (:class:`ProcessEvaluator`) before it ends the trial as failed."""
POLL_S = 0.25
"""How often a process pool reads its trials' start reports and checks their timeouts [s]."""
MAX_WORKERS = 4096
"""The most workers an evaluator starts (one process or Ray actor each): a larger number is a
typo (a pool of more processes than that exhausts the machine's memory or file descriptors)."""
HEAD_PROBE_S = 2.0
"""How often the Ray evaluator checks that the cluster's head accepts a connection while it
waits for trials [s]."""
HEAD_TIMEOUT_S = 15.0
"""How long the head may not answer before the Ray evaluator gives up [s] (:class:`ClusterLost`;
Ray itself ends the process after 60 s without its head): a quarter of Ray's time, by default."""
RAY_RECONNECT_VAR = "RAY_gcs_rpc_server_reconnect_timeout_s"
"""Ray's own setting of how long a process may be without its head before Ray ends it [s]
(60 unless set); a shorter one shortens the Ray evaluator's default head timeout to match."""

RAY_FLUSH_VAR = "RAY_task_events_shutdown_flush_timeout_ms"
"""Ray's setting of how long a process's Ray shutdown waits to send its task events to the
head [ms]; the Ray evaluator connecting to a cluster sets it for its ``ray.init`` (unless the
user did) to :data:`RAY_FLUSH_MS`, so that a command whose head was lost ends soon after its
error line instead of waiting on the lost head."""
RAY_FLUSH_MS = 1000

log = logging.getLogger(__name__)


def default_head_timeout() -> float:
    """:data:`HEAD_TIMEOUT_S`, or a quarter of Ray's reconnect timeout (``$RAY_gcs_rpc_server_
    reconnect_timeout_s``) when that is set below 60 s, so that the Ray evaluator reports a lost
    head before Ray ends the process without a word. An unreadable value is ignored."""
    raw = os.environ.get(RAY_RECONNECT_VAR)
    if raw is None:
        return HEAD_TIMEOUT_S
    try:
        ray_s = float(raw)
    except ValueError:
        ray_s = math.nan
    if not ray_s > 0:
        log.debug("$%s=%r is not a positive number of seconds: ignored", RAY_RECONNECT_VAR, raw)
        return HEAD_TIMEOUT_S
    return min(HEAD_TIMEOUT_S, ray_s / 4)


class ClusterLost(EvaluationError):
    """The Ray cluster's head (its GCS) stopped answering: its node, or the network to it, was
    lost. Raised by :class:`RayEvaluator` before Ray ends the process on its own (it exits
    with status 1 and no message of latentune's a minute after losing its head), so the
    caller can say what happened; the trials yielded before are complete."""


@dataclass(frozen=True)
class TrialError:
    """A trial that raised or returned no usable cost: ``message`` is one line; ``bad_value``:
    the function returned something that is not a cost (:class:`~latentune.system.CostError`)."""

    message: str
    bad_value: bool = False


@dataclass(frozen=True)
class PluginRef:
    """How a worker rebuilds a ``--system module:factory`` system: ``load_system(target, args)``.

    ``path``: the caller's import path (``sys.path``, the current directory first), so a worker
    started elsewhere finds the user's module. The worker builds the system once and keeps it.
    """

    target: str
    args: dict[str, Any] = field(default_factory=dict)
    path: tuple[str, ...] = ()
    space: dict[str, Any] | None = None
    """The caller's system's space (:meth:`~latentune.space.ParameterSpace.to_dict`): a worker's
    build whose unit box means other physical values is refused."""
    command_line: bool = False
    """Whether the caller reads messages at the command line (:func:`~latentune.wording.
    at_command_line` when the reference was made): a worker's build failure names the system as
    the caller gave it (:meth:`name`; ``--system T`` or ``load_system('T')``)."""

    @classmethod
    def of(cls, system: Any) -> "PluginRef | None":
        """The reference of a system made by ``load_system`` (None for any other object)."""
        from latentune.system import plugin_record
        from latentune.wording import at_command_line

        plugin = plugin_record(system)
        if plugin is None or not isinstance(plugin.get("target"), str):
            return None
        path = tuple(os.getcwd() if p == "" else p for p in sys.path)
        return cls(plugin["target"], dict(plugin.get("args") or {}), path,
                   system.space.to_dict(), at_command_line())

    def name(self) -> str:
        """The system as the caller gave it (:func:`~latentune.system.plugin_name`)."""
        from latentune.system import plugin_name

        return plugin_name(self.target, self.command_line)

    def cache_key(self) -> str:
        return "plugin:" + json.dumps([self.target, self.args], sort_keys=True, default=str)

    def build(self) -> Any:
        """Import and call the factory in this process (its import path extended first); its
        errors in the caller's words (:attr:`command_line`)."""
        from contextlib import nullcontext

        from latentune.errors import SystemSpecError
        from latentune.system import load_system
        from latentune.wording import command_line_words

        for p in reversed(self.path):
            if p not in sys.path:
                sys.path.insert(0, p)
        with command_line_words() if self.command_line else nullcontext():
            system = load_system(self.target, self.args)
        diff = None if self.space is None else system.space.box_difference(self.space)
        if diff is not None:        # a factory of random or machine-dependent bounds
            diff = diff.replace(" there", " in the caller").replace(" here", " in the worker")
            raise SystemSpecError(f"its factory built another parameter space in the worker "
                                  f"({diff}): it must build the same system every time it is "
                                  "called")
        return system


def check_workers(workers: Any) -> int:
    """``workers`` as an int; UsageError unless it is a whole number in [1, MAX_WORKERS]."""
    from latentune.errors import UsageError

    if not is_whole(workers, 1, MAX_WORKERS):
        raise UsageError(f"workers must be a whole number in [1, {MAX_WORKERS}] (one process "
                         f"or Ray actor each), got {workers!r}")
    return int(workers)


def check_timeout(seconds: Any) -> float | None:
    """``seconds`` (a trial timeout) as a float; None stays None; UsageError unless it is a
    finite number > 0."""
    from latentune.errors import UsageError

    if seconds is None:
        return None
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(seconds) and seconds > 0):
        raise UsageError(f"trial_timeout must be a finite number of seconds > 0 (or None), got "
                         f"{seconds!r:.40}")
    return float(seconds)


def _key(fun: Any) -> str | None:
    ck = getattr(fun, "cache_key", None)
    return ck() if callable(ck) else None


def _unshippable(fun: Any, exc: BaseException) -> EvaluationError:
    """The refusal of a system that cannot be sent to the workers, in the Python API's words:
    only a Python caller meets it (a ``--system`` system is sent as a :class:`PluginRef`, a
    built-in task pickles)."""
    return EvaluationError(
        f"{type(fun).__name__} cannot be sent to worker processes ({type(exc).__name__}: "
        f"{' '.join(str(exc).split())[:200]}); run it in this process with workers=1 (or "
        "backend='serial'), or build it with latentune.load_system('module:factory')")


def _check_picklable(fun: Any) -> None:
    """Raise EvaluationError (naming workers=1) if ``fun`` cannot be pickled, or refers to
    ``__main__`` of a session without a file (a notebook, ``python -c``, stdin): a worker
    process cannot import what it defines, and the pool broke (BrokenProcessPool)."""
    try:
        data = pickle.dumps(fun)
    except Exception as exc:  # noqa: BLE001 - whatever __reduce__ raises: reported as one line
        raise _unshippable(fun, exc) from None
    main = sys.modules.get("__main__")
    if b"__main__" in data and main is not None \
            and not os.path.isfile(getattr(main, "__file__", None) or ""):
        raise _unshippable(fun, RuntimeError(
            "it is defined in __main__ of an interactive session (a notebook, python -c or "
            "stdin), which worker processes cannot import; define it in a module"))


_WORKER_CACHE: dict[str, Any] = {}
_STARTS: Any = None
"""In a process-pool worker: the queue its trials report their start on (see :func:`_run_sent`)."""


def _exit_with(alive: Any) -> None:
    """End this worker process when ``alive`` (the read end of a pipe whose write end only the
    caller holds) reaches EOF: the caller exited or was killed. A pool's workers would wait for
    work without end (running on, holding the caller's stdout and stderr open)."""
    try:
        alive.poll(None)                       # nothing is ever written: readable means EOF
    except (OSError, EOFError):
        pass
    os._exit(1)


class _QueueLog(logging.Handler):
    """In a process-pool worker: each log record of the ``latentune`` loggers put on the
    pool's start queue as ``("log", logger name, level, message)``, for the caller to log
    (:func:`_read_starts`)."""

    def __init__(self, queue: Any) -> None:
        super().__init__()
        self.queue = queue

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.queue.put(("log", record.name, record.levelno, record.getMessage()))
        except Exception:  # noqa: BLE001 - logging's rule: a failed emit is reported, not raised
            self.handleError(record)


def _init_worker(alive: Any = None, starts: Any = None, log_level: int | None = None) -> None:
    """Start of every worker process: one BLAS/OpenMP thread in this process only; with
    ``alive`` (a process pool's), the worker ends when its caller does; ``starts``: the queue
    its trials report their start on (a process pool's); with ``log_level`` (the caller's
    ``latentune`` logger's) the worker's ``latentune`` log records of that level and above go
    to the caller through ``starts`` (not to the worker's stderr, without the caller's format
    and level)."""
    global _STARTS
    _STARTS = starts
    if starts is not None and log_level is not None:
        logger = logging.getLogger("latentune")
        logger.handlers = [_QueueLog(starts)]
        logger.setLevel(log_level)
        logger.propagate = False
    if alive is not None:
        threading.Thread(target=_exit_with, args=(alive,), daemon=True,
                         name="latentune-exit-with-caller").start()
    for v in THREAD_VARS:                      # libraries loaded from now on
        os.environ[v] = "1"
    try:                                       # libraries already loaded (forkserver preload)
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


def _sendable(r: Outcome | TrialError) -> Outcome | TrialError:
    """``r`` as a worker can send it back: an Outcome whose ``info`` cannot be pickled (a lock,
    a simulator handle) keeps the info as the store would record it (JSON, other values as
    text), as on the serial backend."""
    if not isinstance(r, Outcome) or not r.info:
        return r
    try:
        pickle.dumps(r)
        return r
    except Exception:  # noqa: BLE001 - whatever __reduce__ raises
        pass
    from latentune.pipeline.store import info_json

    try:
        info = json.loads(info_json(r.info))
    except Exception as exc:  # noqa: BLE001 - e.g. a circular reference: one line
        return TrialError(f"the trial's info cannot be sent back from its worker or stored "
                          f"({_one_line(exc, 200)})")
    return Outcome(r.cost, r.failed, info, r.wall_s)


def _run_sent(fun: Any, key: str | None, x: np.ndarray,
              token: Any = None) -> Outcome | TrialError:
    """:func:`run_trial` in a worker process: its result as the worker can send it back. With a
    ``token`` (a process pool's trial), ``(token, pid, time.monotonic())`` is put on the
    worker's start queue once the System is built (a worker's first build of a ``--system``,
    which may load a model, is not part of the trial's time): the pool learns which process
    runs the trial, since when."""
    fun = _cached(fun, key)
    if isinstance(fun, TrialError):
        return fun
    if token is not None and _STARTS is not None:
        _STARTS.put((token, os.getpid(), time.monotonic()))
    return _sendable(run_trial(fun, None, x))


def _cached(fun: Any, key: str | None) -> Any:
    """``fun``, or with a ``key`` the worker's cached instance of it: the first one sent with
    that key (a :class:`PluginRef` built here, once per worker); a TrialError if the build
    failed."""
    if key is not None:
        cached = _WORKER_CACHE.get(key)
        if cached is None:
            if isinstance(fun, PluginRef):
                try:
                    built = fun.build()
                except EvaluationError as exc:
                    return TrialError(str(exc))
                except Exception as exc:  # noqa: BLE001 - e.g. SystemSpecError: one line
                    return TrialError(f"a worker could not rebuild {fun.name()}: "
                                      f"{' '.join(str(exc).split())[:300]}")
            else:
                built = fun
            _WORKER_CACHE.clear()              # one cached System (one simulator) per worker
            _WORKER_CACHE[key] = cached = built
        fun = cached
    return fun


def run_trial(fun: Any, key: str | None, x: np.ndarray) -> Outcome | TrialError:
    """Evaluate one point in this process (the worker side of every backend).

    A System with a ``key`` is cached: the worker keeps the first instance sent with that key.
    A :class:`PluginRef` is built here (once per worker). A plain callable's return value must
    be a real number (nan/inf allowed); anything else is a TrialError naming what it returned.
    """
    fun = _cached(fun, key)
    if isinstance(fun, TrialError):
        return fun
    x = np.asarray(x, dtype=float).copy()
    try:
        if hasattr(fun, "evaluate"):
            return evaluate(fun, x)
        t0 = time.perf_counter()
        value = fun(x)
        wall = time.perf_counter() - t0
        return Outcome(as_cost(value, allow_nonfinite=True), wall_s=wall)
    except CostError as exc:
        return TrialError(str(exc), bad_value=True)
    except EvaluationError as exc:
        return TrialError(str(exc))
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plain callable that raised
        return TrialError(f"the function raised {type(exc).__name__}: "
                          f"{' '.join(str(exc).split())[:300]}")


class Evaluator:
    """Base of every evaluator: ``imap`` (subclasses), ``map``, ``close`` and context use."""

    workers: int = 1

    def imap(self, fun: Any, X: np.ndarray, stop: Callable[[], bool] | None = None
             ) -> Iterator[tuple[int, Outcome | TrialError]]:
        """Yield ``(i, Outcome or TrialError)`` for every row i of X (n, d), as they complete;
        with ``stop``, only the rows started before ``stop()`` turned True (see the module
        docstring)."""
        raise NotImplementedError

    def map(self, fun: Any, X: np.ndarray) -> np.ndarray:
        """(n,) float64 costs in the order of X (n, d). Raises EvaluationError on a TrialError
        (:class:`~latentune.system.CostError` when ``fun`` returned something not a cost)."""
        X = np.asarray(X, dtype=float)
        y = np.full(X.shape[0], np.nan)
        for i, r in self.imap(fun, X):
            if isinstance(r, TrialError):
                raise (CostError if r.bad_value else EvaluationError)(r.message)
            y[i] = r.cost
        return y

    def one(self, fun: Any, x: np.ndarray) -> Outcome:
        """The Outcome of one trial at ``x`` (d,), run as every other (a worker that dies or
        a timeout: a failed Outcome); raises as :meth:`map` does on a TrialError."""
        _, r = next(iter(self.imap(fun, np.asarray(x, dtype=float)[None, :])))
        if isinstance(r, TrialError):
            raise (CostError if r.bad_value else EvaluationError)(r.message)
        return r

    def close(self) -> None:
        """Stop the workers (no-op for the serial evaluator)."""

    def __enter__(self) -> "Evaluator":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SerialEvaluator(Evaluator):
    """In this process, one point after the other. A trial that ends the process (``os._exit``,
    a crash of the interpreter or of a simulator's C code) ends the run with it, and a hung one
    cannot be stopped: the process backend survives both (:class:`ProcessEvaluator`)."""

    def imap(self, fun: Any, X: np.ndarray, stop: Callable[[], bool] | None = None
             ) -> Iterator[tuple[int, Outcome | TrialError]]:
        for i, x in enumerate(np.asarray(X, dtype=float)):
            if stop is not None and stop():
                return
            yield i, run_trial(fun, None, x)

    def __repr__(self) -> str:
        return "SerialEvaluator()"


class ProcessEvaluator(Evaluator):
    """A local pool of ``workers`` processes (forkserver on Linux, else spawn).

    A worker process that dies in a trial (the trial called ``os._exit``, crashed the
    interpreter, was killed by the out-of-memory killer) ends that trial as failed: a System's
    is an Outcome with ``failed=True`` and ``info["worker_died"]`` (the exit code), a plain
    callable's a :class:`TrialError`; the other trials go on. ``trial_timeout`` (seconds, None:
    none): a trial running longer is stopped (its worker is killed) and ends the same way, with
    ``info["timed_out"]`` (a worker's build of a ``--system`` before its first trial is not
    timed). A pool that loses a worker loses all of them (``concurrent.futures``
    stops the others): it is replaced, and the trials the others were running are run again.
    A trial lost :data:`MAX_LOST` times with workers that died of something else (no trial of
    theirs is to blame: a worker killed from outside) ends as failed too. The trials of an
    ``imap`` that was left before its end (Ctrl-C, an error) are not waited for: the next
    ``imap``, or :meth:`close`, terminates the workers still running or queued for them.
    """

    def __init__(self, workers: int = 2, start_method: str | None = None,
                 trial_timeout: float | None = None) -> None:
        import multiprocessing as mp

        workers = check_workers(workers)
        self.trial_timeout = check_timeout(trial_timeout)
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self.workers = int(workers)
        self.start_method = start_method
        self._ctx = mp.get_context(start_method)
        # the workers watch the read end; the write end stays here: a killed caller's workers end
        self._alive_r, self._alive_w = self._ctx.Pipe(duplex=False)
        self._log_level = logging.getLogger("latentune").getEffectiveLevel()
        self._said: set[tuple[str, int, str]] = set()   # worker log lines logged here
        self._pool, self._starts = self._new_pool()
        self._checked: Any = None               # the last system found picklable
        self._abandoned: set[Any] = set()       # running trials of an imap that was left
        self._imaps = 0                         # imap calls so far (the tokens' first part)
        self.replaced = 0                       # pools replaced after a worker died

    def _new_pool(self) -> tuple[Any, Any]:
        """A pool and the queue its trials report their start on (one per pool: the workers of
        a broken pool are killed, maybe while writing to it)."""
        from concurrent.futures import ProcessPoolExecutor

        starts = self._ctx.SimpleQueue()
        pool = ProcessPoolExecutor(self.workers, mp_context=self._ctx, initializer=_init_worker,
                                   initargs=(self._alive_r, starts, self._log_level))
        return pool, starts

    def _replace_pool(self) -> tuple[dict[int, int | None], Any]:
        """Replace a broken pool, or one running trials of a left imap (its workers are
        terminated: a hung one would hold the next trials for ever): ``({pid: exit code}, start
        queue)`` of the old one's workers (every one has ended)."""
        old, starts = self._pool, self._starts
        procs = self._stop_left()
        old.shutdown(wait=True, cancel_futures=True)
        self._pool, self._starts = self._new_pool()
        self.replaced += 1
        return {p.pid: p.exitcode for p in procs}, starts

    def imap(self, fun: Any, X: np.ndarray, stop: Callable[[], bool] | None = None
             ) -> Iterator[tuple[int, Outcome | TrialError]]:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        X = np.asarray(X, dtype=float)
        ref = PluginRef.of(fun)
        if ref is not None:
            fun = ref                           # rebuilt in each worker: closures are fine
        elif self._checked is not fun:
            _check_picklable(fun)
            self._checked = fun
        key = _key(fun)
        system = isinstance(fun, PluginRef) or hasattr(fun, "evaluate")
        self._imaps += 1
        run = self._imaps
        todo = list(range(X.shape[0]))
        futs: dict[Any, int] = {}
        started: dict[int, tuple[int, float]] = {}     # trial -> (worker pid, start)
        stopped: dict[int, int] = {}    # trials to blame for a break (timed out, died) -> pid
        lost = [0] * X.shape[0]
        owed: set[int] = set()          # started, then lost with a pool: run again even after stop
        idle_breaks = 0                                # breaks with no trial running
        if getattr(self._pool, "_broken", False) or self._left():
            self._replace_pool()[1].close()    # a worker died, or trials of a left imap run
        try:
            while todo or futs:
                if stop is not None and todo and stop():
                    todo = [i for i in todo if i in owed]   # the others not started: never run
                    if not futs and not todo:
                        break
                room = len(todo) if stop is None else max(0, self.workers - len(futs))
                for j, i in enumerate(todo[:room]):
                    try:
                        futs[self._pool.submit(_run_sent, fun, key, X[i], (run, i))] = i
                    except BrokenProcessPool:   # a worker died while the batch was submitted
                        room = j                # not run yet: submitted after the break
                        if not futs:            # nothing submitted here to see the break
                            self._replace_pool()[1].close()
                        break
                todo = todo[room:]
                done, _ = wait(futs, timeout=self._wait_s(started, stopped, futs.values()),
                               return_when=FIRST_COMPLETED)
                _read_starts(self._starts, run, started, self._said)
                broken = False
                for f in sorted(done, key=lambda f: futs[f]):
                    if isinstance(f.exception(), BrokenProcessPool):
                        broken = True
                        continue
                    i = futs.pop(f)
                    started.pop(i, None)
                    owed.discard(i)
                    yield i, f.result()
                if not broken:
                    self._stop_late(started, stopped, futs)
                    continue
                codes, starts = self._replace_pool()
                _read_starts(starts, run, started, self._said)
                starts.close()
                ends: dict[int, Outcome | TrialError] = {}
                lost_now = []                          # trials lost with the pool
                for f, i in futs.items():
                    if f.done() and not f.cancelled() and f.exception() is None:
                        ends[i] = f.result()           # it finished before the pool broke
                        continue
                    pid, t0 = started.get(i, (None, 0.0))
                    wall = time.monotonic() - t0 if pid is not None else None
                    if i in stopped:
                        ends[i] = self._failed(system, wall, timed_out=True, info={
                            "timed_out": True, "trial_timeout": self.trial_timeout},
                            msg=f"the trial ran longer than its timeout of "
                                f"{self.trial_timeout:g} s: its worker process was stopped")
                    elif pid is not None and pid not in stopped.values() \
                            and codes.get(pid) not in (None, -signal.SIGTERM):
                        ends[i] = self._failed(system, wall, info={
                            "worker_died": True, "exit_code": codes[pid]},
                            msg=f"the trial's worker process died ({_exit_text(codes[pid])})")
                        stopped[i] = pid                # to blame: the others are not
                    else:
                        lost_now.append(i)
                for i in lost_now:
                    if not stopped and i in started:    # no trial to blame: count the loss
                        lost[i] += 1
                        if lost[i] >= MAX_LOST:
                            ends[i] = self._failed(system, None, info={"worker_died": True},
                                                   msg=f"the trial was lost with its worker "
                                                       f"process {lost[i]} times")
                            continue
                    if i in started or i in owed:
                        owed.add(i)
                    todo.append(i)
                owed.difference_update(ends)
                if not stopped and not any(i in started for i in futs.values()):
                    idle_breaks += 1
                    if idle_breaks >= MAX_LOST:
                        raise EvaluationError(f"the process pool's workers died {idle_breaks} "
                                              "times before running a trial"
                                              + _main_script_hint(self.start_method))
                futs, started, stopped = {}, {}, {}
                for i in sorted(ends):
                    yield i, ends[i]
        finally:
            # not cancelled here: a future cancelled in this thread that the pool has not taken
            # yet makes its manager thread fail (InvalidStateError) when a worker then dies;
            # their results will not be looked at, the next imap or close stops them
            self._abandoned.update(f for f in futs if not f.done())

    def _left(self) -> bool:
        """Whether a trial of an imap that was left has not finished (queued or running)."""
        self._abandoned = {f for f in self._abandoned if not f.done()}
        return bool(self._abandoned)

    def _stop_left(self) -> list[Any]:
        """Terminate the pool's workers if a trial of a left imap has not finished (else the
        pool's shutdown would wait for it); return the worker processes."""
        procs = list((getattr(self._pool, "_processes", None) or {}).values())
        if self._left():
            for p in procs:
                p.terminate()
        self._abandoned.clear()
        return procs

    def _stop_at(self, started: dict[int, tuple[int, float]], stopped: dict[int, int],
                 running: Any) -> float | None:
        """When the next trials past their timeout are to be stopped (``time.monotonic()``;
        None: no running trial has a timeout): the first running trial's deadline or, since a
        worker's death stops every running trial, the last one within :data:`POLL_S` (at most a
        quarter of the timeout) after it: trials that hang together are stopped together, not
        each lost with the other's worker and run again for another timeout."""
        if self.trial_timeout is None:
            return None
        due = [t0 + self.trial_timeout for i, (_, t0) in started.items()
               if i in running and i not in stopped]
        if not due:
            return None
        first = min(due)
        return max(d for d in due if d <= first + min(POLL_S, self.trial_timeout / 4))

    def _wait_s(self, started: dict[int, tuple[int, float]], stopped: dict[int, int],
                running: Any) -> float:
        """How long the next wait may block: until the running trials' next stop, at most
        :data:`POLL_S` (new starts are read between waits)."""
        at = self._stop_at(started, stopped, running)
        if at is None:
            return POLL_S
        return min(POLL_S, max(0.0, at - time.monotonic()))

    def _stop_late(self, started: dict[int, tuple[int, float]], stopped: dict[int, int],
                   futs: dict[Any, int]) -> None:
        """Kill the worker of every running trial past its timeout once it is time to stop
        them (:meth:`_stop_at`; the pool breaks: the next wait sees it)."""
        running = set(futs.values())
        at = self._stop_at(started, stopped, running)
        now = time.monotonic()
        if at is None or now < at:
            return
        for i, (pid, t0) in started.items():
            if i in running and i not in stopped and t0 + self.trial_timeout <= now:
                log.warning("a trial ran longer than its timeout of %g s: its worker process "
                            "%d is stopped", self.trial_timeout, pid)
                stopped[i] = pid
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass

    def _failed(self, system: bool, wall: float | None, info: dict[str, Any], msg: str,
                timed_out: bool = False) -> Outcome | TrialError:
        """A trial ended by its worker's death: a System's failed Outcome (the C1 convention's
        cost, ``info["error"]`` = ``msg``), a plain callable's TrialError."""
        if not system:
            return TrialError(msg)
        if not timed_out:
            log.warning("%s; it is recorded as failed", msg)
        return as_outcome(Outcome(None, True, {**info, "error": msg}, wall))

    def close(self) -> None:
        """Stop the workers; a trial still running for an ``imap`` that was left (Ctrl-C, an
        error) is not waited for: its worker is terminated (a hung or long trial held the
        caller for ever)."""
        self._stop_left()
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._starts.close()
        self._alive_r.close()
        self._alive_w.close()

    def __repr__(self) -> str:
        timeout = "" if self.trial_timeout is None else f", trial_timeout={self.trial_timeout:g}"
        return (f"ProcessEvaluator(workers={self.workers}, start_method={self.start_method!r}"
                f"{timeout})")


def _read_starts(starts: Any, run: int, started: dict[int, tuple[int, float]],
                 said: set[tuple[str, int, str]]) -> None:
    """Move the start reports of ``starts`` (a pool's queue) of the ``imap`` call ``run`` into
    ``started`` (trial -> (pid, start)); others (of an imap that was left) are dropped. The
    workers' log records on it (:class:`_QueueLog`) are logged here by the same loggers, each
    line once (``said``: the lines logged so far; every worker says the same things)."""
    while not starts.empty():
        item = starts.get()
        if item[0] == "log":
            if item[1:] not in said:
                said.add(item[1:])
                logging.getLogger(item[1]).log(item[2], "%s", item[3])
            continue
        (r, i), pid, t0 = item
        if r == run:
            started[i] = (pid, t0)


def _main_script_hint(start_method: str) -> str:
    """What to check when the pool's workers die before any trial and the caller is a script
    run as ``python script.py``: a forkserver or spawn worker imports that script again while
    it starts, and a script without the ``__main__`` guard starts its study there too. "" for
    a fork pool or a ``python -m`` module (the command line guards its entry point)."""
    main = sys.modules.get("__main__")
    if start_method == "fork" or getattr(main, "__spec__", None) is not None \
            or not getattr(main, "__file__", None):
        return ""
    return (f" (each worker runs {os.path.basename(main.__file__)} again as it starts: put the "
            'code that runs the study under `if __name__ == "__main__":`)')


def _exit_text(code: int | None) -> str:
    """A worker process's exit code in words: ``exit code 3``, ``signal 11 (SIGSEGV)``."""
    if code is None or code >= 0:
        return f"exit code {code}"
    try:
        return f"signal {-code} ({signal.Signals(-code).name})"
    except ValueError:
        return f"signal {-code}"


class _RayWorker:
    """A Ray actor keeping one cached System."""

    def __init__(self) -> None:
        _init_worker()

    def run(self, fun: Any, key: str | None, x: np.ndarray) -> Outcome | TrialError:
        return _run_sent(fun, key, x)

    def ping(self) -> bool:
        return True


def _one_line(exc: BaseException, limit: int = 300) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split())[:limit]}"


def _host_port(address: str | None) -> tuple[str, int] | None:
    """``(host, port)`` of a ``HOST:PORT`` address, None for other forms (``auto``,
    ``ray://…``)."""
    if not address:
        return None
    host, sep, port = address.rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def _connect(hp: tuple[str, int], timeout: float) -> None:
    """Open and close a TCP connection to ``hp`` (OSError if none within ``timeout`` s)."""
    import socket

    with socket.create_connection(hp, timeout=timeout):
        pass


def _gcs_address(ray: Any) -> str | None:
    """The ``HOST:PORT`` of the GCS the driver is connected to (None where Ray does not say:
    a ``ray://`` client; the head is then not watched)."""
    try:
        address = ray.get_runtime_context().gcs_address
    except Exception as exc:  # noqa: BLE001 - Ray's client mode raises its own types
        log.debug("no GCS address to watch: %s", _one_line(exc))
        return None
    return address if isinstance(address, str) and _host_port(address) else None


@contextmanager
def _keeps_sigterm(undo: Callable[[], None] | None = None) -> Iterator[None]:
    """Keep the caller's Python SIGTERM handler (the command line's: stop as Ctrl-C does)
    across ``ray.init``, which installs its own (a crash dump, then the process ends). A
    SIGTERM during the block that Ray's start-up handler turned into ``sys.exit(SIGTERM)``
    calls ``undo`` (``ray.shutdown``), then the caller's handler (which raises its stop)."""
    import signal

    prev = signal.getsignal(signal.SIGTERM)
    try:
        yield
    except SystemExit as exc:
        if exc.code != signal.SIGTERM or not callable(prev) \
                or threading.current_thread() is not threading.main_thread():
            raise
        signal.signal(signal.SIGTERM, prev)
        if undo is not None:
            undo()
        prev(signal.SIGTERM, None)
        raise
    finally:
        if callable(prev) and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, prev)


@contextmanager
def _holds_sigint(hold: bool = True) -> Iterator[list[int]]:
    """Inside the block a Ctrl-C (SIGINT) is noted in the yielded list, not raised (if ``hold``;
    main thread, Python's default handler only; restored after): ``ray.init`` starting a local
    Ray, interrupted midway, leaves the agent processes it started running after the command
    ended. Not held while connecting to a cluster (nothing is started; that can hang)."""
    import signal

    noted: list[int] = []
    if not hold or threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield noted
        return
    prev = signal.signal(signal.SIGINT, lambda signum, frame: noted.append(signum))
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, prev)


@contextmanager
def _env_default(var: str, value: str | None) -> Iterator[None]:
    """Inside the block, ``$var`` is ``value`` unless it is set already (or ``value`` is
    None); afterwards the caller's environment is as it was."""
    add = value is not None and var not in os.environ
    if add:
        os.environ[var] = value
    try:
        yield
    finally:
        if add:
            os.environ.pop(var, None)


HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
"""The HTTP/2 client connection preface and an empty SETTINGS frame (RFC 9113 §3.4): what a
gRPC client sends first; a gRPC server (a Ray head's GCS) answers with its SETTINGS frame."""

HANDSHAKE_S = 3.0
"""How long :func:`_check_reachable` waits for a Ray head's gRPC handshake [s]."""


def _check_reachable(address: str, timeout: float = 10.0, handshake: float = HANDSHAKE_S) -> None:
    """Raise ConnectionError if a ``HOST:PORT`` Ray address does not accept a TCP connection
    within ``timeout`` seconds, or accepts one but sends no HTTP/2 SETTINGS frame (the gRPC
    handshake of a Ray head's GCS) within ``handshake`` seconds: another service's port. Ray
    itself retries either without end. Not checked: other forms (``auto``, ``ray://…``), and
    the handshake under ``RAY_USE_TLS`` (it starts with TLS's)."""
    import socket

    hp = _host_port(address)
    if hp is None:
        return
    if not 0 < hp[1] < 65536:           # the resolver takes it modulo 65536: another port
        raise ConnectionError(f"{address}: the port must be 1 to 65535, got {hp[1]}")
    try:
        conn = socket.create_connection(hp, timeout=timeout)
    except OSError as exc:
        raise ConnectionError(f"no Ray cluster answers at {address} ({exc.strerror or exc}); "
                              "start its head (ray start --head) or correct the address"
                              ) from None
    if os.environ.get("RAY_USE_TLS", "").lower() in ("1", "true"):
        conn.close()
        return
    with conn:
        header, why = b"", f"no gRPC handshake within {handshake:g} s"
        try:
            conn.settimeout(handshake)
            conn.sendall(HTTP2_PREFACE)
            deadline = time.monotonic() + handshake
            while len(header) < 9 and time.monotonic() < deadline:
                chunk = conn.recv(9 - len(header))
                if not chunk:
                    why = "it closed the connection"
                    break
                header += chunk
        except OSError as exc:
            if not isinstance(exc, TimeoutError):
                why = f"the connection failed: {exc.strerror or exc}"
    # a frame header: length (3 bytes), type (4: SETTINGS), flags, stream 0
    if len(header) == 9 and header[3] == 4 and header[5:9] == bytes(4):
        return
    if len(header) == 9:
        why = f"it answered {header[:9]!r}, not a gRPC handshake"
    raise ConnectionError(f"{address} answers, but not as a Ray cluster's head ({why}): give "
                          "the port of its head's `ray start --head --port` (6379 by default)")


class RayEvaluator(Evaluator):
    """``workers`` Ray actors (one CPU each) on a cluster (``address``, else ``$RAY_ADDRESS``
    as Ray's own default) or on a local Ray.

    A local Ray gets ``num_cpus=workers``; its temp dir is ``temp_dir`` or ``$RAY_TMPDIR``.
    Ray is shut down on :meth:`close` only if this evaluator started it. A ``HOST:PORT``
    address that accepts no connection, or gives no Ray head's gRPC handshake within
    :data:`HANDSHAKE_S` seconds, raises ConnectionError (Ray would retry it without end).

    Lost workers: a trial whose actor dies before it returns (its node stopped or lost, the
    worker process killed or out of memory, its connection lost) has given no result; it is run
    again on another actor, and yielded once, when a run of it returns. Its Outcome's ``info``
    then holds ``lost_runs`` (how many runs of it were lost). A trial lost ``max_losses`` times
    (a system that crashes its worker process) yields a :class:`TrialError`. Ray restarts a
    lost actor wherever the cluster has a free CPU (a node that comes back, or one that joins);
    until then the remaining actors take every trial. If no actor is alive for
    ``lost_timeout`` seconds while trials wait (all lost, or none placed: more workers than the
    cluster has free CPUs is fine, the actors without one take no trials),
    ``imap`` raises :class:`~latentune.system.EvaluationError` (the trials it yielded before
    are complete). ``lost_trials`` counts the lost runs since the evaluator started.

    Lost head: while it waits, the evaluator checks every :data:`HEAD_PROBE_S` seconds (at most
    half of ``head_timeout``) that the cluster's head (its GCS address) accepts a TCP
    connection; one that has not for ``head_timeout`` seconds (default:
    :func:`default_head_timeout`, 15 s) raises :class:`ClusterLost` (the trials it yielded
    before are complete; runs lost meanwhile are not counted as lost with a worker). Ray would
    end the process on its own a minute after losing the head (``$RAY_gcs_rpc_server_
    reconnect_timeout_s``), without a word. After that, :meth:`close` leaves the cluster alone.
    """

    def __init__(self, workers: int = 2, address: str | None = None,
                 temp_dir: str | None = None, max_losses: int = 3,
                 lost_timeout: float = 300.0, head_timeout: float | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise RuntimeError("the ray backend needs ray (pip install 'latentune[ray]')") from None
        workers = check_workers(workers)
        if max_losses < 1:
            raise ValueError("max_losses must be >= 1")
        if not lost_timeout > 0:
            raise ValueError("lost_timeout must be > 0")
        if head_timeout is None:
            head_timeout = default_head_timeout()
        if not head_timeout > 0:
            raise ValueError("head_timeout must be > 0")
        self.workers = int(workers)
        address = address or os.environ.get("RAY_ADDRESS") or None   # Ray's default address
        self.address = address
        self.max_losses = int(max_losses)
        self.lost_timeout = float(lost_timeout)
        self.head_timeout = float(head_timeout)
        self._probe_s = min(HEAD_PROBE_S, self.head_timeout / 2)
        self.lost_trials = 0
        self.head_lost = False
        self._head_silent: float | None = None  # since when the head has not answered
        self._next_probe = 0.0
        self._owns = False
        if not ray.is_initialized():
            kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": False}
            if address:
                _check_reachable(address)
            else:
                tmp = temp_dir or os.environ.get("RAY_TMPDIR")
                if tmp:
                    kw["_temp_dir"] = os.path.abspath(tmp)
            with _keeps_sigterm(ray.shutdown), _holds_sigint(not address) as interrupted, \
                    _env_default(RAY_FLUSH_VAR, str(RAY_FLUSH_MS) if address else None):
                ray.init(**({"address": address} if address else {"num_cpus": self.workers}),
                         **kw)
            self._owns = True
            if interrupted:                     # Ctrl-C during the start-up: undo it, then stop
                ray.shutdown()
                raise KeyboardInterrupt
        self._ray = ray
        self.head = address if _host_port(address) else _gcs_address(ray)
        from ray import exceptions as rex

        # a run that gave no result because its worker or node went away: run it again
        self._lost_types: tuple[type[BaseException], ...] = (
            rex.RayActorError, rex.WorkerCrashedError, rex.NodeDiedError, rex.ObjectLostError,
            rex.OutOfMemoryError)
        # Ray restarts a lost actor (wherever a CPU is free) and never retries its task: the
        # lost trial is re-run here, on whichever actor is free first
        actor = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=0,
                           runtime_env={"env_vars": thread_env()})(_RayWorker)
        self._actors = [actor.remote() for _ in range(self.workers)]
        self._idle: list[Any] = []              # actors known to be alive and free
        self._back: dict[Any, Any] = {}         # ref -> actor that is idle once ref is done
        self._later: list[tuple[float, Any]] = []   # (when, actor): ping it again then
        for a in self._actors:                  # an actor takes trials once it answers: one
            self._wait_back(a)                  # the cluster has no CPU for yet takes none

    def _lost(self, exc: BaseException) -> bool:
        return isinstance(exc, self._lost_types)

    def _watch_head(self, now: bool = False) -> bool:
        """Check that the head answers (every ``_probe_s`` seconds, or ``now``) and
        return whether it did at the last check; raise :class:`ClusterLost` once it has not
        for ``head_timeout`` seconds."""
        hp = _host_port(self.head)
        t = time.monotonic()
        if hp is None or (not now and t < self._next_probe):
            return self._head_silent is None
        self._next_probe = t + self._probe_s
        try:
            _connect(hp, min(self._probe_s, 1.0))
        except OSError as exc:
            if self._head_silent is None:
                self._head_silent = t
                log.debug("the Ray head at %s does not answer: %s", self.head, exc)
            elif t - self._head_silent >= self.head_timeout:
                self.head_lost = True
                raise ClusterLost(f"the Ray cluster's head at {self.head} stopped answering "
                                  f"(no connection for {self.head_timeout:g} s): its node or "
                                  "the network to it was lost") from None
            return False
        self._head_silent = None
        return True

    def _wait_for_head(self) -> None:
        """Return once the head answers; :class:`ClusterLost` after ``head_timeout`` s."""
        while not self._watch_head(now=True):
            time.sleep(self._probe_s)

    def _wait_back(self, actor: Any) -> None:
        """``actor`` is new or lost a run: it joins the idle actors when a ping returns (once
        Ray has placed it, or restarted it if it died)."""
        self._back[actor.ping.remote()] = actor

    def _timeout(self, running: bool) -> float | None:
        """Ping the actors whose retry time has come; how long the next wait may block."""
        now = time.monotonic()
        due = [a for t, a in self._later if t <= now]
        self._later = [(t, a) for t, a in self._later if t > now]
        for a in due:
            self._wait_back(a)
        waits = [t - now for t, _ in self._later] + ([] if running else [1.0])
        return min(waits) if waits else None

    def imap(self, fun: Any, X: np.ndarray, stop: Callable[[], bool] | None = None
             ) -> Iterator[tuple[int, Outcome | TrialError]]:
        from collections import deque

        ray = self._ray
        X = np.asarray(X, dtype=float)
        self._wait_for_head()                   # Ray's calls block while the head is away
        try:
            fun_ref = ray.put(fun)              # cloudpickle: closures are fine
        except Exception as exc:  # noqa: BLE001 - Ray's serializer raises several types
            ref = PluginRef.of(fun)
            if ref is None:
                raise _unshippable(fun, exc) from None
            fun, fun_ref = ref, ray.put(ref)
        key = _key(fun)
        todo = deque(range(X.shape[0]))
        losses = [0] * X.shape[0]
        running: dict[Any, tuple[int, Any]] = {}
        owed: set[int] = set()          # started, then lost with a worker: run again after stop
        none_alive: float | None = None        # since when no actor is alive (trials waiting)
        try:
            while todo or running:
                if stop is not None and todo and stop():
                    todo = deque(i for i in todo if i in owed)  # the others: never run
                    if not running and not todo:
                        break
                while todo and self._idle:
                    i, a = todo.popleft(), self._idle.pop(0)
                    running[a.run.remote(fun_ref, key, X[i])] = (i, a)
                if running:
                    none_alive = None
                elif none_alive is None:
                    none_alive = time.monotonic()
                elif time.monotonic() - none_alive > self.lost_timeout:
                    raise EvaluationError(
                        f"no Ray worker of {self.workers} was alive for {self.lost_timeout:g} s "
                        "(the cluster's nodes were lost or it has no free CPU; "
                        f"{self.lost_trials} trial runs lost); the trials finished so far are "
                        f"complete, {len(todo)} were not run")
                self._watch_head()
                timeout = min(self._timeout(bool(running)) or self._probe_s, self._probe_s)
                refs = [*running, *self._back]
                if not refs:                    # every actor waits for its next ping
                    time.sleep(timeout)
                    continue
                done, _ = ray.wait(refs, num_returns=1, timeout=timeout)
                for ref in done:
                    if ref in self._back:
                        a = self._back.pop(ref)
                        try:
                            ray.get(ref)
                            self._idle.append(a)
                        except Exception as exc:  # noqa: BLE001 - sorted below
                            if not self._lost(exc):   # it cannot start at all (its runtime env)
                                raise EvaluationError("a Ray worker could not start: "
                                                      f"{_one_line(exc)}") from None
                            log.debug("a Ray worker is not back yet: %s", _one_line(exc))
                            self._later.append((time.monotonic() + 2.0, a))
                        continue
                    i, a = running.pop(ref)
                    try:
                        r = ray.get(ref)
                    except Exception as exc:  # noqa: BLE001 - sorted below
                        if not self._lost(exc):
                            self._idle.append(a)
                            yield i, TrialError(f"a Ray worker could not run the trial: "
                                                f"{_one_line(exc)}")
                            continue
                        self._wait_back(a)
                        if not self._watch_head(now=True):    # not a worker: the head
                            log.debug("a Ray worker's run was lost while the head does not "
                                      "answer (%s)", _one_line(exc, 160))
                            owed.add(i)
                            todo.appendleft(i)
                            continue
                        losses[i] += 1
                        self.lost_trials += 1
                        if losses[i] >= self.max_losses:
                            yield i, TrialError(f"the trial was lost with its Ray worker "
                                                f"{losses[i]} times ({_one_line(exc, 200)})")
                            continue
                        log.warning("a Ray worker was lost (%s); its trial is run again",
                                    _one_line(exc, 160))
                        owed.add(i)
                        todo.appendleft(i)
                        continue
                    owed.discard(i)
                    self._idle.append(a)
                    if losses[i] and isinstance(r, Outcome):
                        r = Outcome(r.cost, r.failed, {**r.info, "lost_runs": losses[i]},
                                    r.wall_s)
                    yield i, r
        finally:
            for ref, (_, a) in running.items():   # abandoned runs: the actor is busy until done
                self._back[ref] = a

    def close(self) -> None:
        if getattr(self, "head_lost", False):   # Ray's calls would wait for the head
            self._actors, self._idle, self._back, self._later = [], [], {}, []
            return
        for a in getattr(self, "_actors", []):
            try:
                self._ray.kill(a, no_restart=True)
            except Exception as exc:  # noqa: BLE001 - the actor may already be gone
                log.debug("killing a Ray actor: %s", _one_line(exc))
        self._actors, self._idle, self._back, self._later = [], [], {}, []
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()
            self._owns = False

    def __repr__(self) -> str:
        return f"RayEvaluator(workers={self.workers}, address={self.address!r})"


def make_evaluator(backend: str = "process", workers: int = 2, address: str | None = None,
                   temp_dir: str | None = None, trial_timeout: float | None = None) -> Evaluator:
    """``serial``, ``process`` (a pool of ``workers``; ``workers == 1`` → serial, unless a
    ``trial_timeout`` asks for a worker that can be stopped) or ``ray``. A ``trial_timeout``
    needs the process backend (ValueError otherwise)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if trial_timeout is not None and backend != "process":
        raise ValueError(f"a trial timeout needs the process backend, not {backend}")
    if backend == "serial" or (backend == "process" and workers == 1 and trial_timeout is None):
        return SerialEvaluator()
    if backend == "process":
        return ProcessEvaluator(workers, trial_timeout=trial_timeout)
    return RayEvaluator(workers, address=address, temp_dir=temp_dir)
