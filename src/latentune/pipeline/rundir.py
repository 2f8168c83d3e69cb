"""A run directory: its store (``DIR/run.db``), its write lock and the evaluator of its trials.

One process writes a run at a time: :meth:`RunDir.writing` holds an ``flock`` on
``DIR/run.lock`` (released when its process dies, so a kill never leaves a stale lock). A phase
run refuses a second writer at once (:class:`~latentune.errors.LockError` naming the holder);
a short writer (an ask or a tell) may wait a bounded time for the lock instead (``wait`` s).
"""
from __future__ import annotations

import logging
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from latentune.errors import LockError, StoreError, UsageError
from latentune.pipeline.evaluators import (BACKENDS, Evaluator, check_timeout, check_workers,
                                           make_evaluator)
from latentune.pipeline.store import RunStore
from latentune.system import EvaluationError
from latentune.wording import option

log = logging.getLogger(__name__)


class RunDir:
    """The store, lock and evaluator of one run directory.

    Args:
        path: the run directory (created when something is first written to it).
        workers, backend, ray_address: the evaluator to start on first use
            (:func:`~latentune.pipeline.evaluators.make_evaluator`).
        evaluator: an Evaluator to use instead (shared; the caller closes it).
    """

    def __init__(self, path: str | os.PathLike, *, workers: int = 1, backend: str = "serial",
                 ray_address: str | None = None, evaluator: Evaluator | None = None) -> None:
        if backend not in BACKENDS:
            raise UsageError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
        if ray_address and backend != "ray":
            raise UsageError("ray_address needs backend='ray'")
        if evaluator is not None and not isinstance(evaluator, Evaluator):
            raise UsageError(f"evaluator must be a latentune.pipeline.evaluators.Evaluator, "
                             f"got {evaluator!r:.40}")
        if not isinstance(path, (str, os.PathLike)):
            raise UsageError(f"a run directory is a path, got {type(path).__name__} {path!r:.40}")
        self.dir = Path(path)
        if self.dir.exists() and not self.dir.is_dir():
            if (self.dir.parent / "run.db").is_file():      # a file of a run (its run.db)
                raise StoreError(f"{self.dir} is a file, not a run directory: give the run "
                                 f"directory that holds it ({self.dir.parent})")
            raise StoreError(f"{self.dir} exists and is not a directory")
        self.workers = check_workers(workers)
        if backend == "serial" and self.workers > 1 and evaluator is None:
            raise UsageError(f"workers = {self.workers} needs the process or ray backend: the "
                             "serial one runs one trial at a time, in this process")
        self.backend = backend
        self.ray_address = ray_address
        self._store: RunStore | None = None
        self._lock_fd: int | None = None
        self._lock_depth = 0
        self._found: tuple[set[str] | None, bool] = (None, False)
        """(the directory's entries, whether it held a store) when the lock was taken."""
        self._remove_lock = False
        self._evaluator = evaluator
        self._owns_evaluator = evaluator is None
        self.trial_timeout: float | None = None
        """Seconds a trial may run before it is stopped and recorded as failed (None: no limit;
        the process backend's, see :meth:`check_timeout`)."""

    def check_timeout(self, seconds: object, stored: bool = False) -> float | None:
        """``seconds`` as the trial timeout of the evaluator this directory starts: None, or a
        finite number > 0 with the process backend (UsageError otherwise: the serial backend
        runs trials in this process, where a hung one cannot be stopped). ``stored``: the
        run's recorded one, checked when the evaluator starts (a command that runs no trial
        opens any run); None with an evaluator of the caller's (it has its own)."""
        t = check_timeout(seconds)
        if t is None or stored:
            return None if not self._owns_evaluator else t
        if not self._owns_evaluator:
            raise UsageError(f"a trial timeout ({t:g} s) is a setting of the evaluator: pass "
                             "ProcessEvaluator(workers, trial_timeout=...) instead")
        self._check_backend(t, "a trial timeout")
        return t

    def _check_backend(self, t: float, what: str, advice: str = "") -> None:
        """UsageError (``what``, then ``advice``) unless this directory's backend is the
        process one, the only one that can stop a trial after ``t`` seconds."""
        if self.backend != "process":
            raise UsageError(f"{what} ({t:g} s) needs the process backend: {self.backend} "
                             f"cannot stop a trial{advice}")

    @property
    def exists(self) -> bool:
        """Whether the directory holds a run store."""
        return (self.dir / "run.db").is_file()

    @property
    def store(self) -> RunStore:
        """The run store (opened read-write; StoreError if there is none yet)."""
        if self._store is None:
            self._store = RunStore(self.dir)
        return self._store

    def open(self) -> RunStore:
        """The run store, created if needed."""
        if self._store is None:
            self._store = RunStore(self.dir, create=True)
        return self._store

    @contextmanager
    def writing(self, wait: float = 0.0, evaluating: bool = False) -> Iterator[RunStore]:
        """Hold the write lock (re-entrant) and yield the store (created if needed); the
        outermost holder checks the store first. ``wait``: seconds to wait for another
        writer's lock before :class:`LockError` (0: refuse at once). ``evaluating``: the
        holder runs trials: the evaluator starts first, so one that cannot (Ray without its
        cluster) leaves the directory as it was (no run store, seed or system recorded)."""
        if self._lock_depth == 0:
            if evaluating:
                self.evaluator()
            had_dir, had_lock = self.dir.is_dir(), (self.dir / "run.lock").exists()
            self._acquire(wait)
            found = set(os.listdir(self.dir))       # after the lock: no writer meanwhile
            if not had_lock:
                found.discard("run.lock")
            self._found = (found if had_dir else None, self.exists)
        self._lock_depth += 1
        try:
            st = self.open()
            if self._lock_depth == 1:
                st.check()             # a damaged store is refused before anything is added
            yield st
        finally:
            self._lock_depth -= 1
            if self._lock_depth == 0:
                self._release()

    @contextmanager
    def as_before_on_error(self) -> Iterator[None]:
        """Inside :meth:`writing`: an exception raised in the block (then re-raised) leaves the
        directory as the outermost :meth:`writing` found it. When it held no run store, the
        store is closed and everything written into the directory since is removed (the lock
        file, and the directory itself when it was created); else the store is put back as it
        was on entering the block (:meth:`RunStore.snapshot`) and the files new in the
        directory (a copied latent space) are removed. Both happen before the lock is
        released, so no other writer sees the half-made run."""
        if self._lock_depth == 0:
            raise RuntimeError("as_before_on_error is used inside writing()")
        found, had_store = self._found
        copy = self.open().snapshot() if had_store else None
        try:
            yield
        except BaseException:
            try:
                self._put_back(found, copy)
            except Exception as exc:  # noqa: BLE001 - the write's own error is the one to see
                log.warning("%s: could not undo the failed write: %s", self.dir, exc)
            copy = None
            raise
        finally:
            if copy is not None:
                copy.close()

    def _put_back(self, found: set[str] | None, copy: Any) -> None:
        """Undo a failed write (see :meth:`as_before_on_error`); what cannot be removed is
        logged."""
        import shutil

        keep = set(found or ())
        if copy is not None:
            self.open().restore(copy)
            keep |= {"run.lock", "run.db", "run.db-wal", "run.db-shm", "run.db-journal"}
        elif self._store is not None:
            self._store.close()
            self._store = None
        for name in sorted(set(os.listdir(self.dir)) - keep - {"run.lock"}):
            path = self.dir / name
            try:
                shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
            except OSError as exc:
                log.warning("%s: could not remove %s after the failed write: %s", self.dir,
                            name, exc.strerror or exc)
        self._remove_lock = "run.lock" not in keep

    def _acquire(self, wait: float) -> None:
        import fcntl

        deadline = time.monotonic() + max(0.0, float(wait))
        while True:
            try:
                self.dir.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.dir / "run.lock", os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise StoreError(f"cannot write to {self.dir}: {exc.strerror or exc}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                if self._same_lock(fd):
                    break
                os.close(fd)        # the holder removed the lock file (a failed first write)
                continue
            except OSError:
                if time.monotonic() < deadline:
                    os.close(fd)
                    time.sleep(0.05)
                    continue
                try:
                    holder = os.pread(fd, 200, 0).decode(errors="replace").strip() \
                        or "another process"
                finally:
                    os.close(fd)
                waited = f" (waited {wait:g} s)" if wait > 0 else ""
                raise LockError(f"{self.dir} is being written by {holder}{waited}; wait for it "
                                "or use another directory") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} since {time.strftime('%Y-%m-%d %H:%M:%S')}".encode(), 0)
        self._lock_fd = fd

    def _same_lock(self, fd: int) -> bool:
        """Whether ``fd`` is still the file ``DIR/run.lock`` (not one removed meanwhile)."""
        try:
            return os.fstat(fd).st_ino == os.stat(self.dir / "run.lock").st_ino
        except OSError:
            return False

    def _release(self) -> None:
        if self._lock_fd is not None:
            try:
                os.ftruncate(self._lock_fd, 0)
                if self._remove_lock:           # removed while held: see _same_lock
                    os.unlink(self.dir / "run.lock")
            except OSError:
                pass
            os.close(self._lock_fd)       # closing releases the flock
            self._lock_fd = None
        if self._remove_lock and self._found[0] is None:
            try:
                self.dir.rmdir()            # created by the failed write, and empty again
            except OSError:
                pass
        self._remove_lock = False

    def evaluator(self) -> Evaluator:
        """The evaluator (started on first use; stopped by :meth:`close`)."""
        if self._evaluator is None:
            if self.trial_timeout is not None:     # recorded: only the process backend runs it
                self._check_backend(self.trial_timeout, "the run's stored trial timeout",
                                    f"; run it with {option('backend', 'process')}")
            try:
                self._evaluator = make_evaluator(self.backend, self.workers, self.ray_address,
                                                 trial_timeout=self.trial_timeout)
            except (RuntimeError, ValueError, OSError) as exc:
                raise EvaluationError(f"cannot start the {self.backend} evaluator: {exc}") from None
        return self._evaluator

    def close(self) -> None:
        """Stop the evaluator (if this run directory started it) and close the store."""
        if self._evaluator is not None and self._owns_evaluator:
            self._evaluator.close()
            self._evaluator = None
        if self._store is not None:
            self._store.close()
            self._store = None
