"""A cheap user system of another kind: 20 gains of the PI controllers of five thermal zones,
designed on a model and run on a building that may differ from it (the model-to-plant gap).

Five rooms in a row, each a thermal capacitance ``C_i`` (MJ/K: 2, 3, 2.5, 3, 2) tied to its
neighbours (conductance 0.15 kW/K) and to the outside (0.05 kW/K), each with a heater/cooler of
at most ±3 kW. The outside is 10 °C and drops to 2 °C after 1 h; from 2 h rooms 2 and 4 get
1.5 kW of occupancy gains; every room's set-point starts at 20 °C, and rooms 1, 3 and 5 step to
22 °C at 30 min. Steps of 60 s, 4 h (240 steps), explicit Euler, rooms start at 18 °C.

Each room's controller (the tuned θ, all log scale): a PI on the room's error, ``u = kp·e +
ki·∫e + kff·Σ_j (T_i − T_j)`` with back-calculation anti-windup (``∫e`` is driven back by
``kaw·(u_sat − u)`` when the heater saturates) and a feed-forward of the heat the room loses to
its neighbours: ``kp_1..5`` [0.05, 20] kW/K, ``ki_1..5`` [1e-5, 0.05] kW/(K·s), ``kaw_1..5``
[1e-3, 10] and ``kff_1..5`` [1e-3, 1] (× 0.15 kW/K). Manual: kp 1, ki 1e-3, kaw 0.1, kff 0.1.

The building differs from the model by ``gap`` g ≥ 0 (g = 0 is the model): capacitances ×
(1 − 0.35 g · s_i) with fixed s_i ∈ {1, 0.5} (lighter rooms), the walls between rooms ×
(1 + 0.6 g), the heaters' limit × (1 − 0.2 g) and a sensor delay of round(2 g) steps.
High gains that the model tolerates oscillate on the lighter, delayed plant and go unstable.

Cost: the RMS over rooms and steps of the set-point error (K) plus 0.02 · the RMS heater power
(kW). A trial *fails* when a room leaves [10, 30] °C (or a value is non-finite) at step k; its
cost is then ``100 · (2 − k/240)`` (the built-in tasks' C1 convention: failing later is better).

    --system examples.thermal_zones:make_system [--system-arg gap=0.5]

Written in session 30 as a second held-out family of the transfer ladder: no option of phase 3
was chosen on it.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

N = 5
DT = 60.0                                  # s
STEPS = 240
CAP = np.array([2.0, 3.0, 2.5, 3.0, 2.0]) * 1e3     # kJ/K
K_WALL = 0.15                              # kW/K between neighbours
K_OUT = 0.05                               # kW/K to the outside
U_MAX = 12.0                               # kW
BAND = 3.0                                 # K: the comfort band after the first hour
SETTLE = 3600.0                            # s
_SHARE = np.array([1.0, 0.5, 1.0, 0.5, 1.0])


def zones_space(rooms: int = N) -> lt.ParameterSpace:
    """The 4·rooms gains: ``kp_1..n``, ``ki_1..n``, ``kaw_1..n``, ``kff_1..n`` (module
    docstring; 20 for the five rooms)."""
    n = rooms
    names = [f"{g}_{i + 1}" for g in ("kp", "ki", "kaw", "kff") for i in range(n)]
    low = [0.05] * n + [1e-5] * n + [1e-3] * n + [1e-3] * n
    high = [20.0] * n + [0.05] * n + [10.0] * n + [1.0] * n
    manual = [1.0] * n + [1e-3] * n + [0.1] * n + [0.1] * n
    return lt.ParameterSpace(names=names, low=low, high=high, log=[True] * (4 * n),
                             manual=manual)


class ZonesSystem:
    """The five rooms' PI gains on a building with model-to-plant ``gap`` (module docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS, rooms: int = N) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        if isinstance(rooms, bool) or int(rooms) != rooms or not 1 <= int(rooms) <= N:
            raise ValueError(f"rooms must be an integer in [1, {N}], got {rooms}")
        self.n = int(rooms)
        self.space = zones_space(self.n)
        g = self.gap
        self.cap = CAP[:self.n] * np.maximum(1.0 - 0.35 * g * _SHARE[:self.n], 0.1)
        self.k_wall = K_WALL * (1.0 + 0.6 * g)
        self.u_max = U_MAX * max(1.0 - 0.2 * g, 0.2)
        self.delay = int(round(min(2 * g, self.steps)))  # no longer than the episode

    def config(self) -> dict[str, Any]:
        out = {"kind": "thermal_zones", "gap": self.gap, "steps": self.steps}
        return out if self.n == N else {**out, "rooms": self.n}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        return self.simulate(theta)[0]

    def simulate(self, theta: np.ndarray) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        """The trial of the unit-box θ (d,) and its trace up to the end or the failure:
        ``time_s`` (k,), ``temperature`` (k, n) °C, ``setpoint`` (k, n) °C, ``power_kw``
        (k, n) (the heaters' commands, saturated; n rooms)."""
        w = self.space.to_physical(self.space.validate_unit(theta))
        N = self.n                                      # noqa: N806 - the rooms of this system
        kp, ki, kaw, kff = w[:N], w[N:2 * N], w[2 * N:3 * N], w[3 * N:] * K_WALL
        step_rooms, busy_rooms = [i for i in (0, 2, 4) if i < N], [i for i in (1, 3) if i < N]
        T = np.full(N, 18.0)
        integ = np.zeros(N)
        seen = [T.copy()] * (self.delay + 1)           # the sensor's queue: oldest first
        err2 = pow2 = 0.0
        trace: dict[str, list] = {"time_s": [], "temperature": [], "setpoint": [],
                                  "power_kw": []}

        def done(out: lt.Outcome) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
            return out, {k: np.asarray(v) for k, v in trace.items()}

        for k in range(self.steps):
            t = k * DT
            sp = np.full(N, 20.0)
            if t >= 1800.0:
                sp[step_rooms] = 22.0
            t_out = 10.0 if t < 3600.0 else 2.0
            gains = np.zeros(N)
            if t >= 7200.0:
                gains[busy_rooms] = 1.5
            Tm = seen[0]                                # what the controller measures
            e = sp - Tm
            lap = np.zeros(N)                           # Σ_j (T_i − T_j) over neighbours
            lap[:-1] += Tm[:-1] - Tm[1:]
            lap[1:] += Tm[1:] - Tm[:-1]
            u_raw = kp * e + ki * integ + kff * lap
            u = np.clip(u_raw, -self.u_max, self.u_max)
            integ += (e + kaw * (u - u_raw)) * DT
            flow = np.zeros(N)
            flow[:-1] += self.k_wall * (T[1:] - T[:-1])
            flow[1:] += self.k_wall * (T[:-1] - T[1:])
            T = T + DT / self.cap * (K_OUT * (t_out - T) + flow + u + gains)
            seen = seen[1:] + [T.copy()]
            for key, v in (("time_s", t + DT), ("temperature", T.copy()), ("setpoint", sp),
                           ("power_kw", u)):
                trace[key].append(v)
            if not np.all(np.isfinite(T)) or (t >= SETTLE and np.abs(T - sp).max() > BAND):
                return done(lt.Outcome(100.0 * (2 - k / self.steps), True, {"fall_step": k}))
            err2 += float(np.mean((T - sp) ** 2))
            pow2 += float(np.mean(u ** 2))
        rms_u = math.sqrt(pow2 / self.steps)
        return done(lt.Outcome(math.sqrt(err2 / self.steps) + 0.02 * rms_u, False,
                               {"rms_power_kw": rms_u}))


def make_system(gap: float = 0.0, steps: int = STEPS, rooms: int = N) -> ZonesSystem:
    """``--system examples.thermal_zones:make_system [--system-arg gap=G --system-arg rooms=R]``:
    the first ``rooms`` of the five (4·rooms gains; the set-point steps of rooms 1, 3, 5 and the
    occupancy of rooms 2, 4 among them)."""
    return ZonesSystem(gap=gap, steps=steps, rooms=rooms)
