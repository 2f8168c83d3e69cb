"""A cheap user system: the 20 LQR weights of a chain of seven carts, designed on a model and run
on a plant that may differ from it (the model-to-plant gap).

Seven carts (mass 1 kg each on the model) in a row, joined by springs (10 N/m) and dampers
(0.5 N·s/m), the first one also tied to a wall; six motors push carts 1-6 (the last cart is
moved only through the chain). The controller is the discrete LQR (20 ms steps) of the *model*
with the tuned weights: ``Q = diag(q_pos1..7, q_vel1..7)`` (14 state weights, log scale
[1e-3, 1e3]) and ``R = diag(r1..6)`` (6 input weights, log scale [1e-3, 1e2]), plus the steady
state feedforward for the reference. The task: from rest, bring the last cart to +1 m and hold
it there for 3 s (150 steps). The motor force saturates at ``u_max``.

The plant differs from the model by ``gap`` g ≥ 0 (g = 0 is the model itself): cart masses
× (1 + 0.6 g · s_i) with fixed signs s_i = ±1, spring stiffness × (1 − 0.3 g), damping
× (1 − 0.5 g), an actuation delay of round(3 g) steps and a force limit ``u_max`` = 6 (1 − 0.25 g)
N. Aggressive designs (small R) saturate and, with the delay, go unstable: at large gaps most
designs that are fine on the model fail on the plant.

Cost: ``sqrt(Σ_t (p7_t − 1)² · dt)`` (m·√s) plus 0.002 · the RMS force. A trial *fails* when a
cart leaves ±1.5 m (the chain's end stops) or the state becomes non-finite at step k; its cost is then
``100 · (2 − k/150)`` (the built-in tasks' C1 convention: falling later is better).

    --system examples.lqr_chain:make_system [--system-arg gap=0.5]
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

N_CART = 7
N_MOTOR = 6
DT = 0.02
STEPS = 150
LIMIT = 1.5
_SIGNS = np.array([1, -1, 1, 1, -1, -1, 1], dtype=float)


def chain_space() -> lt.ParameterSpace:
    """The 20 weights: ``q_pos1..7``, ``q_vel1..7`` (Q), ``r1..6`` (R); manual: all 1."""
    names = [f"q_pos{i + 1}" for i in range(N_CART)] + [f"q_vel{i + 1}" for i in range(N_CART)] \
        + [f"r{i + 1}" for i in range(N_MOTOR)]
    low = [1e-3] * 14 + [1e-3] * N_MOTOR
    high = [1e3] * 14 + [1e2] * N_MOTOR
    return lt.ParameterSpace(names=names, low=low, high=high, log=[True] * 20,
                             manual=[1.0] * 20)


def _matrices(masses: np.ndarray, k: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (zero-order hold, DT) A (14, 14), B (14, 6) of the chain."""
    from scipy.linalg import expm

    n = N_CART
    Kmat = np.zeros((n, n))
    for i in range(n):
        Kmat[i, i] += k                              # spring to the left (wall for cart 1)
        if i + 1 < n:
            Kmat[i, i] += k
            Kmat[i, i + 1] -= k
            Kmat[i + 1, i] -= k
    Cmat = Kmat * (c / k)
    Minv = np.diag(1.0 / masses)
    Ac = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ Kmat, -Minv @ Cmat]])
    Bc = np.vstack([np.zeros((n, N_MOTOR)), Minv[:, :N_MOTOR]])
    M = expm(np.block([[Ac, Bc], [np.zeros((N_MOTOR, 2 * n + N_MOTOR))]]) * DT)
    return M[:2 * n, :2 * n], M[:2 * n, 2 * n:]


class ChainSystem:
    """The chain's LQR weights on a plant with model-to-plant ``gap`` (module docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        self.space = chain_space()
        self.A0, self.B0 = _matrices(np.ones(N_CART), 10.0, 0.5)
        g = self.gap
        self.A, self.B = _matrices(1.0 + 0.6 * g * _SIGNS * np.where(_SIGNS > 0, 1.0, 0.5),
                                   10.0 * (1 - 0.3 * g), 0.5 * max(1 - 0.5 * g, 0.05))
        self.delay = int(round(min(3 * g, self.steps)))  # no longer than the episode
        self.u_max = 6.0 * max(1 - 0.25 * g, 0.2)

    def config(self) -> dict[str, Any]:
        return {"kind": "lqr_chain", "gap": self.gap, "steps": self.steps}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        from scipy.linalg import solve_discrete_are

        w = self.space.to_physical(self.space.validate_unit(theta))
        Q, R = np.diag(w[:14]), np.diag(w[14:])
        try:
            P = solve_discrete_are(self.A0, self.B0, Q, R)
            K = np.linalg.solve(R + self.B0.T @ P @ self.B0, self.B0.T @ P @ self.A0)
        except (np.linalg.LinAlgError, ValueError):
            return lt.Outcome(200.0, True, {"fall_step": 0, "reason": "no LQR solution"})
        # steady state for the last cart at +1 m on the model: x* and u* (least squares)
        n = 2 * N_CART
        ref = np.zeros(n)
        ref[N_CART - 1] = 1.0
        Msys = np.block([[self.A0 - np.eye(n), self.B0]])
        sol = np.linalg.lstsq(np.vstack([Msys, np.eye(n, n + N_MOTOR)[N_CART - 1:N_CART]]),
                              np.concatenate([np.zeros(n), [1.0]]), rcond=None)[0]
        xs, us = sol[:n], sol[n:]
        x = np.zeros(n)
        queue = [np.zeros(N_MOTOR)] * self.delay
        err2 = 0.0
        u2 = 0.0
        for t in range(self.steps):
            u = np.clip(us - K @ (x - xs), -self.u_max, self.u_max)
            queue.append(u)
            ua = queue.pop(0)
            x = self.A @ x + self.B @ ua
            if not np.all(np.isfinite(x)) or np.max(np.abs(x[:N_CART])) > LIMIT:
                return lt.Outcome(100.0 * (2 - t / self.steps), True, {"fall_step": t})
            err2 += (x[N_CART - 1] - 1.0) ** 2 * DT
            u2 += float(u @ u)
        cost = math.sqrt(err2) + 0.002 * math.sqrt(u2 / self.steps)
        return lt.Outcome(cost, False, {"rms_force": math.sqrt(u2 / self.steps)})


def make_system(gap: float = 0.0, steps: int = STEPS) -> ChainSystem:
    """``--system examples.lqr_chain:make_system [--system-arg gap=G]``."""
    return ChainSystem(gap=gap, steps=steps)
