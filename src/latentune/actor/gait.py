"""Gait scheduler: which feet are in stance at a time, and the swing progress of the others.

Leg k's phase is φ_k(t) = (t / period + offset_k) mod 1; it is in stance while φ_k < duty.
``trot`` moves diagonal pairs together (offsets 0, ½, ½, 0); ``jump`` is a forward pronk with all
four legs in phase. Times in seconds.
"""
from __future__ import annotations

import threading

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
        self._offsets_row = self.offsets[None, :]
        self._steps: dict[tuple[float, int], np.ndarray] = {}   # (dt, horizon) -> (horizon, 1)

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
        steps = self._steps.get((dt, horizon))
        if steps is None:
            steps = self._steps[(dt, horizon)] = (dt * np.arange(horizon))[:, None]
        ph = np.mod((t + steps) / self.period + self._offsets_row, 1.0)
        return ph < self.duty


class StepContacts:
    """Scheduled stance per physics step, memoized per process for every scheduler of the same
    timing: ``contacts(n)`` is the tuple over legs of ``((n·dt + eps) / period + offset_k) mod 1
    < duty`` (Python floats, the exact expression the actors evaluated at every step)."""

    _lists: dict[tuple, list[tuple[bool, ...]]] = {}
    _lock = threading.Lock()

    def __init__(self, gait: GaitScheduler, dt: float, eps: float = 0.0):
        self._period, self._duty, self._dt, self._eps = gait.period, gait.duty, dt, eps
        self._offsets = tuple(float(o) for o in gait.offsets)
        key = (self._period, self._duty, self._offsets, dt, eps)
        self._list = StepContacts._lists.setdefault(key, [])

    def __call__(self, step: int) -> tuple[bool, ...]:
        lst = self._list
        if step < len(lst):
            return lst[step]
        per, duty, dt, eps, offs = self._period, self._duty, self._dt, self._eps, self._offsets
        with StepContacts._lock:  # rollouts in threads share the lists
            for n in range(len(lst), step + 1):
                x = (n * dt + eps) / per
                lst.append(tuple((x + o) % 1.0 < duty for o in offs))
        return lst[step]
