"""Evaluators: map a cost function over a batch of points.

Every evaluator implements ``map(fun, X) -> y``: ``fun`` maps one point (d,) to a float, ``X``
is (n, d), ``y`` is (n,) float64 in the order of ``X``. The serial evaluator lives here; the
pipeline adds process-pool and Ray evaluators with the same method.
"""
from __future__ import annotations

from typing import Callable, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Evaluator(Protocol):
    """Anything with ``map(fun, X: (n, d) ndarray) -> (n,) ndarray``."""

    def map(self, fun: Callable[[np.ndarray], float], X: np.ndarray) -> np.ndarray:
        """Evaluate ``fun`` on every row of ``X``; return the (n,) float64 costs in order."""
        ...


class SerialEvaluator:
    """Evaluate the rows of ``X`` one after the other in this process."""

    def map(self, fun: Callable[[np.ndarray], float], X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        return np.array([float(fun(x.copy())) for x in X], dtype=float).reshape(X.shape[0])

    def __repr__(self) -> str:
        return "SerialEvaluator()"
