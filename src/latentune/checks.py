"""Checks shared by the API, the command line and the benchmarks, each caller raising its own
error type with its own message naming the argument:

* :func:`is_whole`: the one test of a whole-number argument the API takes (a budget, a count, a
  seed): an ``int`` or NumPy integer — not a bool (``True`` is 1 to Python), not a float
  (``2.5`` would be truncated, ``2.0`` may be a mistake) — within bounds;
* :func:`file_in_the_way`: the file that keeps a path from being created (an output file or
  directory given under a file).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np


def is_whole(v: Any, low: int | None = None, high: int | None = None) -> bool:
    """True when ``v`` is an integer (not a bool) with ``low <= v <= high`` (a bound None is
    open)."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        return False
    return (low is None or v >= low) and (high is None or v <= high)


def file_in_the_way(path: str | os.PathLike) -> Path | None:
    """The nearest of ``path`` and its parents that exists and is not a directory (a file where
    a directory must be for ``path`` to be created under it), or None."""
    p = Path(path)
    return next((q for q in (p, *p.parents) if q.exists() and not q.is_dir()), None)
