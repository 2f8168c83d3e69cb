"""The one test of a whole-number argument the API takes (a budget, a count, a seed): an
``int`` or NumPy integer — not a bool (``True`` is 1 to Python), not a float (``2.5`` would be
truncated, ``2.0`` may be a mistake) — within bounds. Each caller raises its own error type
with its own message naming the argument."""
from __future__ import annotations

from typing import Any

import numpy as np


def is_whole(v: Any, low: int | None = None, high: int | None = None) -> bool:
    """True when ``v`` is an integer (not a bool) with ``low <= v <= high`` (a bound None is
    open)."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        return False
    return (low is None or v >= low) and (high is None or v <= high)
