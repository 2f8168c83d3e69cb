"""Files written whole or not at all: :func:`write_atomic`; :func:`fsync_path` flushes one to disk.

The text is written to a temporary file of a name no other writer uses, in the target's
directory (so the rename stays on one file system), then renamed over the target with
``os.replace``. A reader sees the old file or the new one, never a truncated one (a kill or a
full disk mid-write leaves the old file), and two processes writing the same file at once each
rename a complete file of their own (the last rename wins). A user's file named like a
temporary file (``DIR/best.json.tmp``) is not touched.
"""
from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()
"""The permissions an ``open(path, "w")`` gives a new file (mkstemp's are 0600)."""


def fsync_path(path: str | os.PathLike) -> None:
    """Flush the file or directory ``path`` to disk (``os.fsync`` of it opened read-only): a
    directory's entries, such as a name just linked or renamed into it, survive a crash. A
    file system that cannot flush a directory (EINVAL, ENOTSUP) is left to its own schedule."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP) or not os.path.isdir(path):
            raise
    finally:
        os.close(fd)


def write_atomic(path: str | os.PathLike, data: str | bytes) -> None:
    """Replace ``path`` by a file holding ``data`` (str: written as UTF-8) in one rename, from a
    unique temporary file ``.<name>.<random>.tmp`` beside it; on any error the temporary file
    is removed, ``path`` is left as it was and the error is raised (an OSError naming ``path``,
    the file the caller writes, not the temporary one). The new file has the permissions of an
    ordinary new file (0666 less the umask)."""
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(path)) from exc
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _MODE)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError) and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
