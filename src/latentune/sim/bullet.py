"""PyBullet, imported without its 'pybullet build time' banner, and kept off stdout.

PyBullet's C code prints to the process's file descriptors: the banner on fd 2, URDF-parser
warnings (``b3Warning: Bad inertia tensor properties …``) on fd 1, which would break a command's
JSON output. :func:`quiet_stderr` silences fd 2 and :func:`stdout_to_stderr` sends fd 1 to fd 2
(or to nothing) around the calls that print; both flush C's stdio buffers before restoring, so
buffered output cannot reach stdout later.
"""
from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager
from typing import Iterator

try:
    _libc: ctypes.CDLL | None = ctypes.CDLL(None)
except OSError:  # pragma: no cover - no C library to flush (not seen on Linux/macOS)
    _libc = None


def _flush_c() -> None:
    """fflush(NULL): write out every C stdio buffer (PyBullet's printf output)."""
    if _libc is not None:
        try:
            _libc.fflush(None)
        except (AttributeError, OSError):  # pragma: no cover
            pass


@contextmanager
def _redirect(fd: int, target: int | None) -> Iterator[None]:
    """Point file descriptor ``fd`` at ``target`` (a descriptor, or None for /dev/null)."""
    stream = sys.stdout if fd == 1 else sys.stderr
    try:
        stream.flush()
        saved = os.dup(fd)
    except (OSError, ValueError, AttributeError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY) if target is None else None
    try:
        _flush_c()
        os.dup2(devnull if target is None else target, fd)
        yield
    finally:
        _flush_c()
        os.dup2(saved, fd)
        os.close(saved)
        if devnull is not None:
            os.close(devnull)


@contextmanager
def quiet_stderr() -> Iterator[None]:
    """Silence C-level writes to fd 2 (PyBullet's banner and URDF-parser messages)."""
    with _redirect(2, None):
        yield


@contextmanager
def stdout_to_stderr(silent: bool = False) -> Iterator[None]:
    """Send C-level writes to fd 1 to fd 2 (``silent``: to /dev/null) for the duration."""
    with _redirect(1, None if silent else 2):
        yield


@contextmanager
def quiet() -> Iterator[None]:
    """Neither stdout nor stderr: around ``loadURDF``, whose warnings the spec checks report."""
    with _redirect(2, None), _redirect(1, None):
        yield


with quiet():
    import pybullet  # noqa: E402

p = pybullet
