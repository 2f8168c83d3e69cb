"""Test problems of ``benchmarks/peers.py``: every problem is minimized on the unit box [0, 1]^d.

Synthetic functions are mapped affinely from the unit box to their usual domain, then shifted
(the optimum moves to a point ``o`` drawn in the inner 60 % of the domain) and, where marked,
rotated (``z = z* + R (x − o)``, R a random orthogonal matrix), with shift and rotation drawn
from a generator seeded by the problem's name, so they are the same for every optimizer and
seed. The global minimum of every synthetic problem is 0.

Controller-like problems (global minimum unknown, > 0):

* ``lqr16``: tune the 16 diagonal LQR weights (log10 Q_ii of 12 states, log10 R_jj of 4 inputs,
  each in [-3, 3]) of an unstable discrete linear system; the gain is designed on the nominal
  model and run on a perturbed plant with saturated inputs (|u| <= 1) from 4 fixed initial
  states for 60 steps. Cost: mean quadratic task cost; a run whose state leaves ``|x|_inf <= 20``
  fails with cost ``100 · (2 − t_fail / T)`` (a failure region of costs in [100, 200)).
* ``gains24``: tune the 24 entries of a state-feedback gain K (4 inputs × 6 states) directly,
  ``K = K_lqr + 3 · max(|K_lqr|, 0.3) · (2u − 1)`` around the nominal LQR gain (the box centre,
  like a hand-tuned starting point), on a perturbed plant with saturation and a destabilizing
  cubic term ``+0.01·x³``; same cost and failure rule (about a fifth of the box diverges).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np


def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng(int(hashlib.sha256(name.encode()).hexdigest()[:12], 16))


def _rotation(rng: np.random.Generator, d: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((d, d)))
    return q * np.sign(np.diag(r))


# ------------------------------------------------------------------ base functions (of z)
def ackley(z):
    d = z.shape[0]
    return -20.0 * np.exp(-0.2 * np.sqrt(np.sum(z ** 2) / d)) - np.exp(
        np.sum(np.cos(2 * np.pi * z)) / d) + 20.0 + np.e


def levy(z):
    w = 1.0 + (z - 1.0) / 4.0
    return (np.sin(np.pi * w[0]) ** 2
            + np.sum((w[:-1] - 1) ** 2 * (1 + 10 * np.sin(np.pi * w[:-1] + 1) ** 2))
            + (w[-1] - 1) ** 2 * (1 + np.sin(2 * np.pi * w[-1]) ** 2))


def rastrigin(z):
    return 10.0 * z.shape[0] + np.sum(z ** 2 - 10.0 * np.cos(2 * np.pi * z))


def rosenbrock(z):
    return np.sum(100.0 * (z[1:] - z[:-1] ** 2) ** 2 + (1 - z[:-1]) ** 2)


ST_MIN = -2.903534027771178


def styblinski_tang(z):
    return 0.5 * np.sum(z ** 4 - 16 * z ** 2 + 5 * z) - 0.5 * z.shape[0] * (
        ST_MIN ** 4 - 16 * ST_MIN ** 2 + 5 * ST_MIN)


def griewank(z):
    i = np.arange(1, z.shape[0] + 1)
    return 1.0 + np.sum(z ** 2) / 4000.0 - np.prod(np.cos(z / np.sqrt(i)))


def ellipsoid(z):
    d = z.shape[0]
    return np.sum(10.0 ** (4.0 * np.arange(d) / max(d - 1, 1)) * z ** 2)


def valleys(z):
    """Sum of narrow curved valleys: 100·(z_2k − sin(π z_2k−1))² + |z_2k−1| over pairs."""
    a, b = z[0::2], z[1::2]
    return np.sum(100.0 * (b - np.sin(np.pi * a)) ** 2 + np.abs(a))


@dataclass
class Problem:
    """One benchmark problem: ``f(u)`` for ``u`` in [0, 1]^dim."""

    name: str
    dim: int
    f: Callable[[np.ndarray], float]
    kind: str                      # "synthetic" or "controller"
    f_min: float | None = 0.0      # known global minimum (None: unknown)
    info: dict = field(default_factory=dict)

    def __call__(self, u: np.ndarray) -> float:
        return float(self.f(np.asarray(u, dtype=float)))


def synthetic(name: str, base, d: int, lo: float, hi: float, z_star: float,
              rotate: bool) -> Problem:
    rng = _rng(name)
    span = hi - lo
    o = lo + span * (0.2 + 0.6 * rng.random(d))
    R = _rotation(rng, d) if rotate else None

    def f(u):
        x = lo + span * u
        dz = x - o
        if R is not None:
            dz = R @ dz
        return base(z_star + dz)

    return Problem(name, d, f, "synthetic", 0.0,
                   dict(base=base.__name__, domain=[lo, hi], rotated=rotate))


# ------------------------------------------------------------------ controllers
def _dlqr(A, B, Q, R):
    from scipy.linalg import solve_discrete_are

    P = solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


class _Plant:
    """Unstable discrete linear plant, nominal (A, B) and a perturbed 'true' plant."""

    def __init__(self, name: str, n: int, m: int, cubic: float = 0.0) -> None:
        rng = _rng(name)
        A = rng.standard_normal((n, n)) / np.sqrt(n)
        A *= 1.08 / np.max(np.abs(np.linalg.eigvals(A)))        # spectral radius 1.08
        B = rng.standard_normal((n, m)) / np.sqrt(n)
        self.A, self.B = A, B
        self.A_true = A + 0.03 * rng.standard_normal((n, n)) / np.sqrt(n)
        self.B_true = B * (1.0 + 0.2 * rng.standard_normal((1, m)))
        self.Qc = np.diag(10.0 ** rng.uniform(-1, 1, n))           # the task's true weights
        self.Rc = np.diag(10.0 ** rng.uniform(-1, 1, m))
        self.x0 = rng.standard_normal((4, n)) * 1.5
        self.cubic = cubic
        self.T = 60
        self.n, self.m = n, m

    def cost(self, K: np.ndarray) -> float:
        X = self.x0.copy()                                       # (4, n): 4 runs in parallel
        total = np.zeros(X.shape[0])
        alive = np.ones(X.shape[0], dtype=bool)
        t_fail = np.full(X.shape[0], float(self.T))
        for t in range(self.T):
            U = np.clip(-X @ K.T, -1.0, 1.0)
            total += np.einsum("ij,jk,ik->i", X, self.Qc, X) + np.einsum(
                "ij,jk,ik->i", U, self.Rc, U)
            X = X @ self.A_true.T + U @ self.B_true.T - self.cubic * X ** 3
            bad = alive & ~(np.abs(X).max(1) <= 20.0)
            t_fail[bad] = t + 1
            alive &= ~bad
            X[~alive] = 0.0
        c = np.where(alive, total / self.T, 100.0 * (2.0 - t_fail / self.T))
        return float(np.mean(np.minimum(c, 200.0)))


def lqr16() -> Problem:
    plant = _Plant("lqr16", 12, 4)

    def f(u):
        w = -3.0 + 6.0 * u
        try:
            K = _dlqr(plant.A, plant.B, np.diag(10.0 ** w[:12]), np.diag(10.0 ** w[12:]))
        except (np.linalg.LinAlgError, ValueError):
            return 200.0
        if not np.all(np.isfinite(K)):
            return 200.0
        return plant.cost(K)

    return Problem("lqr16", 16, f, "controller", None, dict(states=12, inputs=4))


def gains24() -> Problem:
    plant = _Plant("gains24", 6, 4, cubic=-0.01)
    K0 = _dlqr(plant.A, plant.B, np.eye(6), np.eye(4))
    scale = 3.0 * np.maximum(np.abs(K0), 0.3)

    def f(u):
        K = K0 + scale * (2.0 * u.reshape(4, 6) - 1.0)
        return plant.cost(K)

    return Problem("gains24", 24, f, "controller", None, dict(states=6, inputs=4))


def problems() -> dict[str, Problem]:
    """All problems of the suite, by name."""
    ps = [
        synthetic("ackley30r", ackley, 30, -10.0, 10.0, 0.0, True),
        synthetic("levy40", levy, 40, -10.0, 10.0, 1.0, False),
        synthetic("rastrigin20r", rastrigin, 20, -5.12, 5.12, 0.0, True),
        synthetic("rosenbrock30", rosenbrock, 30, -5.0, 10.0, 1.0, False),
        synthetic("styblinski50", styblinski_tang, 50, -5.0, 5.0, ST_MIN, False),
        synthetic("griewank60r", griewank, 60, -100.0, 100.0, 0.0, True),
        synthetic("ellipsoid40r", ellipsoid, 40, -5.0, 5.0, 0.0, True),
        synthetic("valleys30r", valleys, 30, -3.0, 3.0, 0.0, True),
        lqr16(),
        gains24(),
    ]
    return {p.name: p for p in ps}
