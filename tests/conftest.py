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

The README runs the suite with pytest-xdist (``pytest -n auto``): every worker builds the
module-scoped fixtures of the tests it runs, so those tests are moved to the front of the run.
"""
from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest

from latentune.threads import one_thread_env, thread_env

one_thread_env()  # rollouts are many tiny matrix operations: one BLAS thread
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

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


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests that use a module-scoped fixture first (otherwise in collection order):
    under pytest-xdist the expensive shared setups (a paper directory, a phase-1 run) start at
    once on the workers instead of at the end of the run."""
    items.sort(key=lambda item: not _shares_a_module_fixture(item))   # stable


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
