"""A probe for phase 3's refinement: a smooth, anisotropic bowl in 8 weights whose optimum the
gap moves, with no falls — the easiest transfer there is, where a user's own choice would be
TuRBO-m started at the source's best θ.

Added in session 51, after a shifted bowl of 2–10 weights (a user's report of a 2-weight system)
showed the default phase 3 ending above TuRBO-m from the source's best at 5 and 10 weights. Its
results check the default; nothing is chosen on them.

θ: 8 weights ``w0 … w7`` in [0, 1] (physical = unit box), manual θ 0.5 each. The model's
optimum ``c0`` is fixed (``default_rng(7)``, uniform in [0.3, 0.7]); the target's is
``c0 + gap · s`` with ``s`` a fixed sign vector (±1 per weight; ``default_rng(8)``), clipped to
[0.02, 0.98]. Cost: ``100 · Σ a_i (w_i − c_i)²`` with curvatures ``a_i`` log-spaced from 1 to 10
(a bowl ten times steeper along ``w7`` than ``w0``). No trial fails.

    --system examples.shifted_bowl:make_system [--system-arg gap=0.2]
"""
from __future__ import annotations

from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap

DIM = 8
CURVATURE = np.logspace(0.0, 1.0, DIM)
"""The bowl's curvature per weight, ``a_i`` (1 … 10)."""
C0 = np.random.default_rng(7).uniform(0.3, 0.7, DIM)
"""The model's optimum (unit box)."""
SIGNS = np.where(np.random.default_rng(8).random(DIM) < 0.5, -1.0, 1.0)
"""The direction the gap moves the optimum in, one sign per weight."""


def optimum(gap: float) -> np.ndarray:
    """The optimum of the system at ``gap`` (DIM,), in the unit box."""
    return np.clip(C0 + gap * SIGNS, 0.02, 0.98)


class BowlSystem:
    """The bowl at ``gap`` (0: the model): a latentune System (``space``, ``evaluate``)."""

    def __init__(self, gap: float = 0.0) -> None:
        self.gap = checked_gap(gap)
        self.space = lt.ParameterSpace([f"w{i}" for i in range(DIM)], np.zeros(DIM),
                                       np.ones(DIM), manual=np.full(DIM, 0.5))
        self.c = optimum(self.gap)

    def evaluate(self, theta: np.ndarray) -> float:
        """The cost of θ (DIM,) in the unit box: ``100 · Σ a_i (θ_i − c_i)²``."""
        x = self.space.to_physical(self.space.validate_unit(theta))
        return float(100.0 * np.sum(CURVATURE * (x - self.c) ** 2))

    def config(self) -> dict[str, Any]:
        return {"kind": "shifted_bowl", "gap": self.gap, "dim": DIM}


def make_system(gap: float = 0.0) -> BowlSystem:
    """``--system examples.shifted_bowl:make_system [--system-arg gap=G]``."""
    return BowlSystem(gap=gap)
