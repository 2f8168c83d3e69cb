"""A pure-numpy user system: state feedback for a chain of masses and springs (24 weights).

Four unit masses on a line, joined to each other and to a wall by springs (stiffness 1) with
light damping, start displaced (``[1, -0.5, 0.5, -1]`` m, at rest). Three actuators push on
masses 0, 1 and 3 with forces ``u = clip(-K x, -5, 5)``, ``x`` = the 4 positions and 4
velocities: K is 3 x 8 = **24 tuned gains**, each in [-0.3, 1] (about half of the
random θ in that box destabilize the chain). A trial simulates 10 s
(200 steps of 0.05 s, semi-implicit Euler).

* cost = ``100 · J / (J + J_open)`` with ``J = Σ (|x|² + 0.1 |u|²) dt`` and ``J_open`` the
  open-loop J: in (0, 100), 50 = no better than no control.
* failed = a position left ±4 m (the chain is unsafe: positive feedback can destabilize it); a
  failed trial returns no cost and gets latentune's convention ``C1 · (2 − k/N)`` (k = the step
  it left the box, N = 200) — between 100 and 200, above every successful cost.
* manual θ: collocated velocity damping ``u_j = −0.5 v_j`` on the three actuated masses.

:func:`make_real_system` perturbs the plant (masses x1.3, stiffness x0.8, damping x0.5,
actuators x0.8): the same controller on a "real" plant. Cheap (a few ms a trial), no dependency
beyond numpy: the tests use it. From the repository root::

    latentune tune --system examples.toy_plant:make_system --out runs/toy \\
        --phase1-evals 100 --phase3-evals 30 --workers 1 --backend serial
"""
from __future__ import annotations

from typing import Any

import numpy as np

import latentune as lt
from examples import checked_scale, checked_steps

N_MASS = 4
ACTUATED = (0, 1, 3)
X0 = np.array([1.0, -0.5, 0.5, -1.0])
DT, STEPS, U_MAX, X_MAX = 0.05, 200, 5.0, 4.0
K_LO, K_HI = -0.3, 1.0


def chain_space() -> lt.ParameterSpace:
    """K (3 x 8) by name ``k_<actuator>_<state>``; manual: damping -0.5 v on own mass."""
    states = [f"x{i}" for i in range(N_MASS)] + [f"v{i}" for i in range(N_MASS)]
    names, manual = [], []
    for j, m in enumerate(ACTUATED):
        for s_i, s in enumerate(states):
            names.append(f"k_u{j}_{s}")
            manual.append(0.5 if s_i == N_MASS + m else 0.0)
    d = len(names)
    return lt.ParameterSpace(names, [K_LO] * d, [K_HI] * d, manual=manual)


class ChainSystem:
    """The mass-spring chain under state feedback (a latentune System; picklable)."""

    def __init__(self, mass_scale: float = 1.0, stiffness_scale: float = 1.0,
                 damping_scale: float = 1.0, gain_scale: float = 1.0, steps: int = STEPS,
                 name: str = "model") -> None:
        self.space = chain_space()
        self.mass_scale = checked_scale(mass_scale, "mass_scale")
        self.stiffness_scale = checked_scale(stiffness_scale, "stiffness_scale")
        self.damping_scale = checked_scale(damping_scale, "damping_scale", zero=True)
        self.gain_scale = checked_scale(gain_scale, "gain_scale")
        self.steps = checked_steps(steps)
        self.name = str(name)
        self._j_open = None

    def _simulate(self, K: np.ndarray) -> tuple[float, int | None]:
        m = np.full(N_MASS, self.mass_scale)
        k, c = 1.0 * self.stiffness_scale, 0.05 * self.damping_scale
        B = np.zeros((N_MASS, len(ACTUATED)))
        for j, i in enumerate(ACTUATED):
            B[i, j] = self.gain_scale
        x, v = X0.copy(), np.zeros(N_MASS)
        J = 0.0
        for t in range(self.steps):
            u = np.clip(-K @ np.r_[x, v], -U_MAX, U_MAX)
            left = np.r_[0.0, x[:-1]]                 # the wall, then the previous mass
            right = np.r_[x[1:], x[-1]]               # the last mass has no right spring
            f = -k * (x - left) - k * (x - right) - c * v + B @ u
            v = v + DT * f / m
            x = x + DT * v
            J += DT * (float(x @ x + v @ v) + 0.1 * float(u @ u))
            if np.any(np.abs(x) > X_MAX):
                return J, t + 1
        return J, None

    def j_open(self) -> float:
        if self._j_open is None:
            self._j_open = self._simulate(np.zeros((len(ACTUATED), 2 * N_MASS)))[0]
        return self._j_open

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        K = self.space.to_physical(self.space.validate_unit(theta)).reshape(len(ACTUATED), -1)
        J, fell = self._simulate(K)
        if fell is not None:
            return lt.Outcome(None, failed=True, info={"fall_step": fell, "horizon": self.steps,
                                                        "reason": "left the safe box"})
        return lt.Outcome(100.0 * J / (J + self.j_open()), info={"J": round(J, 5)})

    def config(self) -> dict[str, Any]:
        return {"name": self.name, "mass_scale": self.mass_scale,
                "stiffness_scale": self.stiffness_scale, "damping_scale": self.damping_scale,
                "gain_scale": self.gain_scale, "steps": self.steps}


def make_system(steps: int = STEPS) -> ChainSystem:
    """The model (``--system examples.toy_plant:make_system``)."""
    return ChainSystem(steps=steps, name="model")


def make_real_system(steps: int = STEPS, mass_scale: float = 1.3, stiffness_scale: float = 0.8,
                     damping_scale: float = 0.5, gain_scale: float = 0.8) -> ChainSystem:
    """The perturbed "real" plant."""
    return ChainSystem(mass_scale, stiffness_scale, damping_scale, gain_scale, steps, "real")
