"""Shared test helpers: the environment of the suite and two ways to run the command line.

* ``cli`` (session fixture): ``cli(*args, cwd=None, env=None, timeout=300)`` runs
  ``python -m latentune.cli ARGS`` in a subprocess with one BLAS thread and returns the
  :class:`subprocess.CompletedProcess` (text mode). Use it when the behaviour needs a process
  (exit codes seen by a shell, what reaches a terminal, a fresh interpreter).
* ``run_cli`` (function fixture, uses ``capsys``): ``run_cli(*args) -> (code, stdout, stderr)``
  calls :func:`latentune.cli.main` in this process; much cheaper than a subprocess.
* ``error_line`` (session fixture): ``error_line(code, err) -> str`` asserts exit code 2 and
  exactly one ``latentune: error:`` line on stderr without a traceback, and returns that line so
  the caller can assert which error it is.
* ``cli_env`` (session fixture): the environment of ``cli`` (for ``subprocess.Popen``).
* ``dump_store`` (session fixture): ``dump_store(run_dir) -> (rows, meta)``, a store's rows
  (phase, idx, theta, z, tag, cost) and meta read-only, to check that a store is unchanged.
* ``interrupt_in_close`` (function fixture): the next :meth:`Study.close` closes the run, then
  raises KeyboardInterrupt (a Ctrl-C landing while a command closes its run); returns a list
  that holds ``"close"`` once it has.
* ``ray_local`` (function fixture): the ``ray`` module with a local Ray running in this process
  (2 CPUs, a short temp dir), started once per test process and shared: a
  :class:`~latentune.pipeline.evaluators.RayEvaluator` made meanwhile uses it and leaves it
  running. Starting and stopping Ray takes seconds. ``no_local_ray`` stops it, for a test that
  needs this process without Ray (an evaluator that starts or reaches its own).

The README runs the suite with pytest-xdist (``pytest -n auto``): every worker builds the
module-scoped fixtures of the tests it runs, so those tests are moved to the front of the run,
after them the tests that use ``ray_local`` (together, so that one worker starts Ray once for
all of them), then the tests marked ``slow`` (tens of seconds in one test: a Ray cluster, a
browser), so that no long test is left for the end of the run while the other worker idles.

New processes started in a test process (the process pools of the ``process`` backend, the
ask/tell tests' concurrent askers) fork from multiprocessing's forkserver, which has torch and
latentune's pipeline loaded once (:data:`FORKSERVER_PRELOAD`) instead of each process importing
them again (about 1.5 s of CPU each).
"""
from __future__ import annotations

import multiprocessing
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from latentune.threads import one_thread_env, thread_env

one_thread_env()  # rollouts are many tiny matrix operations: one BLAS thread
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

FORKSERVER_PRELOAD = ["torch", "latentune.study", "latentune.critic.turbo",
                      "latentune.pipeline.asktell", "latentune.pipeline.evaluators",
                      "latentune.task"]
"""Modules the forkserver imports once; set before any test starts it (a running server keeps
the list it started with)."""
multiprocessing.set_forkserver_preload(FORKSERVER_PRELOAD)

ROOT = Path(__file__).resolve().parents[1]
CLI_ENV: dict[str, str] = dict(os.environ, **thread_env(), RAY_AUTH_MODE="disabled",
                               PYTHONUNBUFFERED="1")

CliRunner = Callable[..., subprocess.CompletedProcess]


def _cli(*args: object, cwd: Path | str | None = None, env: dict[str, str] | None = None,
         timeout: float = 300) -> subprocess.CompletedProcess:
    """``latentune ARGS`` in a subprocess (stdout/stderr captured as text)."""
    return subprocess.run([sys.executable, "-m", "latentune.cli", *map(str, args)],
                          capture_output=True, text=True, env=env or CLI_ENV, cwd=cwd,
                          timeout=timeout)


def _shares_a_module_fixture(item: pytest.Item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    return info is not None and any(d.scope == "module" for defs in
                                    info.name2fixturedefs.values() for d in defs)


def _uses_local_ray(item: pytest.Item) -> bool:
    return "ray_local" in getattr(item, "fixturenames", ())


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: one test of tens of seconds (run early under "
                            "pytest-xdist)")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """``-n auto``: one worker more than the cores this process may use (2 cores: 3 workers).
    A fifth of the suite's wall time is spent waiting (on CLI subprocesses, Ray and browser
    start-up, sleeps in kill tests), not computing; the extra worker fills it
    (``farm-bench`` of ``-n 3`` against ``-n 2``, in the README's test-time notes).
    ``PYTEST_XDIST_AUTO_NUM_WORKERS`` and ``-n logical`` keep pytest-xdist's own count."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS") or config.option.numprocesses != "auto":
        return None
    return len(os.sched_getaffinity(0)) + 1


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests that use a module-scoped fixture first, then the ones that use the shared
    local Ray (``ray_local``), then the ``slow`` ones (otherwise in collection order): under
    pytest-xdist the expensive shared setups (a paper directory, a phase-1 run) start at once on
    the workers instead of at the end of the run, the local Ray tests are sent to one worker
    together (one Ray start there instead of one per worker, and another after a
    ``no_local_ray`` test between them), and the long tests do not end the run on one
    worker."""
    def key(item: pytest.Item) -> tuple[bool, bool, bool]:
        ray = _uses_local_ray(item)
        return (not _shares_a_module_fixture(item),        # stable
                item.get_closest_marker("slow") is None and not ray, not ray)

    items.sort(key=key)


@pytest.fixture(scope="session")
def cli() -> CliRunner:
    """``cli(*args, cwd=None, env=None, timeout=300) -> CompletedProcess``: the CLI in a
    subprocess."""
    return _cli


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., tuple[int, str, str]]:
    """``run_cli(*args) -> (exit code, stdout, stderr)``: :func:`latentune.cli.main` in-process."""
    from latentune.cli import main

    def run(*args: object) -> tuple[int, str, str]:
        capsys.readouterr()                     # drop what earlier code printed
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out, err

    return run


@pytest.fixture
def interrupt_in_close(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The next :meth:`Study.close` closes the run, then raises KeyboardInterrupt (once);
    the returned list holds ``"close"`` once it has."""
    from latentune.study import Study

    close = Study.close
    hits: list[str] = []

    def interrupted_close(self: Study) -> None:
        close(self)
        if not hits:
            hits.append("close")
            raise KeyboardInterrupt

    monkeypatch.setattr(Study, "close", interrupted_close)
    return hits


def one_line_error(code: int, err: str) -> str:
    """Assert a bad-input exit (code 2, one ``latentune: error:`` line, no traceback) and return
    the line."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (code, err)
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("latentune: error:"), err
    return lines[0]


@pytest.fixture(scope="session")
def error_line() -> Callable[[int, str], str]:
    """:func:`one_line_error` as a fixture (``error_line(code, err) -> str``)."""
    return one_line_error


@pytest.fixture
def source_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Record each read of a source run's pinned trials: the names of the calls of
    ``manifest.run_fingerprint`` (to pin them) and ``manifest.amended_since`` (to check them),
    in order, in the returned list (the functions still run)."""
    from latentune.pipeline import manifest as mf

    reads: list[str] = []
    for name in ("run_fingerprint", "amended_since"):
        def counting(*a: Any, _f: Callable = getattr(mf, name), _n: str = name, **k: Any) -> Any:
            reads.append(_n)
            return _f(*a, **k)
        monkeypatch.setattr(mf, name, counting)
    return reads


@pytest.fixture
def stopped_after_a_better_trial(tmp_path: Path) -> tuple[Path, Any]:
    """A run of a 2-weight function (costs 1 + Σθ, but 0 at its 6th call) whose phase 1 ran 3
    random trials, then was resumed to 12 and stopped by a Ctrl-C at the 7th call: its best
    trial (cost 0, evaluation 5) came after the last write of its best files, which hold the
    earlier best θ. Returns (run directory, its :class:`~latentune.space.ParameterSpace`)."""
    import latentune as lt

    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
    calls = []

    def fn(x: Any) -> float:
        calls.append(1)
        if len(calls) == 7:
            raise KeyboardInterrupt                 # Ctrl-C in the resumed run
        return 0.0 if len(calls) == 6 else 1.0 + float(sum(x))

    d = tmp_path / "run"
    with lt.Study(d, seed=0) as s:
        s.phase1(lt.FunctionSystem(space, fn), 3, method="random")
        assert s.summary()["phase1_best_params"] == "phase1_best.json"
    with pytest.raises(KeyboardInterrupt), lt.Study(d, seed=0) as s:
        s.phase1(lt.FunctionSystem(space, fn), 12, method="random")
    return d, space


@pytest.fixture(scope="session")
def cli_env() -> dict[str, str]:
    """The environment ``cli`` runs the command line in (one BLAS thread, Ray auth off)."""
    return dict(CLI_ENV)


def dump(run_dir: Path) -> tuple[list[tuple], list[tuple]]:
    """Rows (phase, idx, theta, z, tag, cost) and meta of a run store, read-only."""
    con = sqlite3.connect(f"file:{Path(run_dir) / 'run.db'}?mode=ro", uri=True)
    try:
        rows = con.execute("SELECT phase, idx, theta, z, tag, cost FROM evaluations "
                           "ORDER BY phase, idx").fetchall()
        meta = con.execute("SELECT key, value FROM meta ORDER BY key").fetchall()
    finally:
        con.close()
    return rows, meta


@pytest.fixture(scope="session")
def dump_store() -> Callable[[Path], tuple[list[tuple], list[tuple]]]:
    """:func:`dump` as a fixture: ``dump_store(run_dir) -> (rows, meta)``."""
    return dump


@pytest.fixture(scope="session")
def _ray_dir() -> Iterator[str]:
    """The temp dir of the shared local Ray (under /tmp: Ray's unix socket paths are short);
    Ray is shut down at the end of the session."""
    d = tempfile.mkdtemp(prefix="ltr", dir="/tmp")
    try:
        yield d
    finally:
        if "ray" in sys.modules and sys.modules["ray"].is_initialized():
            sys.modules["ray"].shutdown()
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def ray_local(_ray_dir: str) -> Any:
    """The ``ray`` module, with the shared local Ray of this process running (2 CPUs)."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 configure_logging=False, _temp_dir=_ray_dir)
    return ray


@pytest.fixture
def no_local_ray() -> None:
    """No Ray running in this process (the shared one is stopped; ``ray_local`` restarts it)."""
    if "ray" in sys.modules and sys.modules["ray"].is_initialized():
        sys.modules["ray"].shutdown()


@pytest.fixture
def full_disk(monkeypatch: pytest.MonkeyPatch) -> Callable[[], None]:
    """``full_disk()``: from then on every file opened for writing through ``io.open`` (``open``
    of a path, ``Path.write_text``, ``os.fdopen``) takes half of its first write, then raises
    OSError(ENOSPC), as a full disk does; undone at the test's end (or by
    ``monkeypatch.undo()``)."""
    import errno
    import io

    real_open = io.open

    class Full:
        """A file that takes half of the first write, then the disk is full."""

        def __init__(self, f: Any) -> None:
            self.f = f

        def write(self, data: Any) -> int:
            self.f.write(data[: len(data) // 2])
            self.f.flush()
            raise OSError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name: str) -> Any:
            return getattr(self.f, name)

        def __enter__(self) -> "Full":
            return self

        def __exit__(self, *exc: Any) -> None:
            self.f.close()

    def opened(file: Any, mode: str = "r", *a: Any, **k: Any) -> Any:
        f = real_open(file, mode, *a, **k)
        return Full(f) if "w" in mode else f

    return lambda: monkeypatch.setattr(io, "open", opened)
