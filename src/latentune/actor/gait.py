"""Gait scheduler: which feet are in stance at a time, and the swing progress of the others.

Leg k's phase is φ_k(t) = (t / period + offset_k) mod 1; it is in stance while φ_k < duty.
``trot`` moves diagonal pairs together (offsets 0, ½, ½, 0); ``jump`` is a forward pronk with all
four legs in phase. Times in seconds.
"""
from __future__ import annotations

import numpy as np

from latentune.robots import GaitParams


class GaitScheduler:
    """Periodic contact schedule for four legs (FR, FL, RR, RL)."""

    def __init__(self, params: GaitParams):
        self.params = params
        self.period = params.period
        self.duty = params.duty
        self.offsets = np.asarray(params.offsets, dtype=float)
        self.stance_time = params.duty * params.period           # [s]
        self.swing_time = (1.0 - params.duty) * params.period    # [s]

    def phase(self, t: float) -> np.ndarray:
        """(4,) gait phase in [0, 1) per leg."""
        return np.mod(t / self.period + self.offsets, 1.0)

    def contact(self, t: float) -> np.ndarray:
        """(4,) bool: scheduled stance per leg at time t."""
        return self.phase(t) < self.duty

    def swing_progress(self, t: float) -> np.ndarray:
        """(4,) progress through swing in [0, 1] (0 for stance legs)."""
        ph = self.phase(t)
        return np.where(ph < self.duty, 0.0, (ph - self.duty) / (1.0 - self.duty))

    def contact_table(self, t: float, dt: float, horizon: int) -> np.ndarray:
        """(horizon, 4) bool: predicted stance at t + k·dt, k = 0..horizon−1."""
        ts = t + dt * np.arange(horizon)
        ph = np.mod(ts[:, None] / self.period + self.offsets[None, :], 1.0)
        return ph < self.duty
