"""Bare-stepping baselines shared by the actor benchmarks (same World, same process).

* :func:`bare_stepping_pd`: a state read, a one-line stance joint PD and a step, per physics step —
  the cheapest controller that keeps the robot standing, i.e. "bare stepping under torque control".
* :func:`bare_stepping_only`: ``stepSimulation`` alone with zero torques (the robot collapses, and
  its body's extra contacts make each step *slower*).
* :func:`replay_stepping`: the torques a rollout applied, replayed open loop from the same start
  (PyBullet is deterministic, so the robot makes the *same* motion): the physics of that very gait
  with no controller and no state reads, i.e. the floor any actor's rollout sits on.
"""
from __future__ import annotations

import time

import numpy as np


def bare_stepping_pd(task, steps: int) -> float:
    """Seconds for ``steps`` torque-controlled steps with a state read and a stance PD each."""
    w = task.world
    w.reset()
    q0 = np.array(w.spec.nominal_q)
    kp, kd = np.tile(w.spec.kp, 4), np.tile(w.spec.kd, 4)
    t0 = time.perf_counter()
    for _ in range(steps):
        s = w.state()
        w.apply(kp * (q0 - s.q) - kd * s.dq)
        w.step()
    return time.perf_counter() - t0


def bare_stepping_only(task, steps: int) -> float:
    """Seconds for ``steps`` calls of stepSimulation alone (zero torques, no state reads)."""
    w = task.world
    w.reset()
    w.apply(np.zeros(12))
    t0 = time.perf_counter()
    for _ in range(steps):
        w.step()
    return time.perf_counter() - t0


def record_torques(task, theta) -> np.ndarray:
    """(n, 12) joint torques [N·m] a rollout of unit-box ``theta`` applied, step by step."""
    w = task.world
    taus: list[np.ndarray] = []
    apply = w.apply

    def recording(tau: np.ndarray) -> None:
        taus.append(np.array(tau))
        apply(tau)

    w.apply = recording
    try:
        task.rollout(theta)
    finally:
        del w.apply
    return np.array(taus)


def replay_stepping(task, taus: np.ndarray) -> float:
    """Seconds to apply the recorded ``taus`` open loop and step, one physics step each."""
    w = task.world
    w.reset()
    rows = [t.tolist() for t in taus]
    t0 = time.perf_counter()
    for tau in rows:
        w.apply_list(tau)
        w.step()
    return time.perf_counter() - t0
