"""A cheap user system of a fourth kind: 20 gains of a car's lane-keeping controller, designed on
a vehicle model and driven on a car and road that may differ from it (the model-to-plant gap).

The plant is a single-track ("bicycle") model with saturating tyres, driven along a road of
curves and an S-bend while it accelerates from 12 to 28 m/s over 20 s (steps of 0.02 s,
semi-implicit Euler). The model car: mass 1500 kg, yaw inertia 2500 kg·m², 1.2 m from the
centre of gravity to the front axle and 1.6 m to the rear, cornering stiffness 80 / 90 kN/rad
(front / rear), tyre-road friction 0.9. Tyre forces follow a simplified Pacejka curve,
``F = μ F_z sin(C atan(B α))`` with C = 1.3 and B set so the slope at α = 0 is the cornering
stiffness. The steering actuator is a first-order lag (0.08 s) with at most ±0.5 rad and
0.8 rad/s.

The controller (the tuned θ) measures the lateral error ``e_y`` (m) and heading error ``e_ψ``
(rad) to the lane's centre, the lateral velocity ``v_y`` (m/s), the yaw rate ``r`` (rad/s) and
the road's curvature ``κ`` (1/m), and commands the steering angle

    δ = k_ff (l + K_us v²) κ − k_y e_la − k_ψ e_ψ − k_vy v_y − k_r (r − κ v) − k_i ∫e_y

through a first-order filter of time constant ``tau_f``, where ``e_la = e_y + L_a sin e_ψ``
is the error previewed ``L_a`` metres ahead, ``l`` the wheelbase and ``K_us`` the model's
understeer gradient. The feedback gains and the preview are scheduled on speed: each has a
value at 12, 20 and 28 m/s, interpolated linearly. θ (all log scale, 20): ``k_y@12/20/28``
[0.003, 0.5] rad/m, ``k_psi@…`` [0.03, 5] rad/rad, ``k_vy@…`` [1e-4, 0.1] rad·s/m, ``k_r@…``
[1e-3, 1] rad·s/rad, ``L_a@…`` [0.5, 30] m, ``k_ff@…`` [0.3, 3], ``k_i`` [1e-5, 0.05]
rad/(m·s) and ``tau_f`` [0.01, 0.5] s. Manual: k_y 0.05, k_psi 0.5, k_vy 0.005, k_r 0.05,
L_a 8, k_ff 1, k_i 1e-3, tau_f 0.05.

The car and road differ from the model by ``gap`` g ≥ 0 (g = 0 is the model): tyre-road
friction × (1 − 0.12 g) (a wet road), cornering stiffness × (1 − 0.1 g) front and
(1 − 0.15 g) rear (worn rear tyres: the car turns toward oversteer), mass × (1 + 0.1 g), yaw
inertia × (1 + 0.2 g), and a steering command delay of round(g) steps (20 ms each). Gains
that the dry, understeering model tolerates oscillate or spin the wet, oversteering car: at
gap 2 most of the random θ that stay in lane on the model leave it
(``tests/test_vehicle_lateral.py``; ``benchmarks.transfer`` uses gaps 0.5, 1 and 2).

Cost: the RMS lateral error (m) plus 0.5 · the RMS heading error (rad) plus 0.05 · the RMS
steering rate (rad/s). A trial *fails* when the car leaves the lane (|e_y| > 1.5 m), spins
(sideslip |β| > 0.25 rad) or a value is non-finite, at step k; its cost is then
``100 · (2 − k/steps)`` (the built-in tasks' C1 convention: failing later is better).

    --system examples.vehicle_lateral:make_system [--system-arg gap=1]

Written in session 44 as a fourth held-out family of the transfer ladder (a car: tyre
saturation, speed scheduling, a road preview): no option of phase 3 was chosen on it.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

DT = 0.02                                   # s
STEPS = 1000                                # 20 s
V0, V1 = 12.0, 28.0                         # m/s: speed at the start and the end
SPEEDS = (12.0, 20.0, 28.0)                 # m/s: the schedule's points
MASS, IZ = 1500.0, 2500.0                   # kg, kg·m²
LF, LR = 1.2, 1.6                           # m
CF, CR = 80e3, 90e3                         # N/rad
MU = 0.9
C_SHAPE = 1.3
TAU_ACT, DELTA_MAX, RATE_MAX = 0.08, 0.5, 0.8   # s, rad, rad/s
LANE, SPIN = 1.5, 0.25                      # m, rad
G = 9.81
ROAD = ((40.0, 0.0), (70.0, 1 / 250), (60.0, 0.0), (80.0, -1 / 180), (50.0, 1 / 160),
        (60.0, 0.0), (120.0, 1 / 220))
"""The road as (length m, curvature 1/m) segments, joined by 15 m linear curvature ramps;
straight after the last one."""
RAMP = 15.0
FEEDBACK = ("k_y", "k_psi", "k_vy", "k_r", "L_a", "k_ff")


def vehicle_space() -> lt.ParameterSpace:
    """The 20 gains (module docstring): ``k_y@12`` … ``k_ff@28`` (six scheduled gains at three
    speeds), ``k_i`` and ``tau_f``."""
    rng = {"k_y": (0.003, 0.5, 0.05), "k_psi": (0.03, 5.0, 0.5), "k_vy": (1e-4, 0.1, 0.005),
           "k_r": (1e-3, 1.0, 0.05), "L_a": (0.5, 30.0, 8.0), "k_ff": (0.3, 3.0, 1.0)}
    names, low, high, manual = [], [], [], []
    for g in FEEDBACK:
        for v in SPEEDS:
            names.append(f"{g}@{v:g}")
            lo, hi, m = rng[g]
            low.append(lo)
            high.append(hi)
            manual.append(m)
    names += ["k_i", "tau_f"]
    low += [1e-5, 0.01]
    high += [0.05, 0.5]
    manual += [1e-3, 0.05]
    return lt.ParameterSpace(names=names, low=low, high=high, log=[True] * len(names),
                             manual=manual)


def curvature(s: float) -> float:
    """The road's curvature (1/m) at arc length ``s`` (m): :data:`ROAD`'s segments, each change
    of curvature a linear ramp over the first :data:`RAMP` metres of the new segment."""
    start, prev = 0.0, 0.0
    for length, k in ROAD:
        if s < start + length:
            a = min((s - start) / RAMP, 1.0)
            return prev + a * (k - prev)
        start, prev = start + length, k
    a = min((s - start) / RAMP, 1.0)
    return prev * (1.0 - a)


class VehicleSystem:
    """The lane-keeping gains on a car and road with model-to-plant ``gap`` (module docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        self.space = vehicle_space()
        g = self.gap
        self.mu = MU * max(1.0 - 0.12 * g, 0.2)
        self.cf = CF * max(1.0 - 0.1 * g, 0.2)
        self.cr = CR * max(1.0 - 0.15 * g, 0.2)
        self.m = MASS * (1.0 + 0.1 * g)
        self.iz = IZ * (1.0 + 0.2 * g)
        self.delay = int(round(min(g, self.steps)))  # no longer than the episode
        # the controller's feed-forward uses the model's understeer gradient (s²/m)
        self.k_us = MASS / (LF + LR) * (LR / CF - LF / CR)

    def config(self) -> dict[str, Any]:
        return {"kind": "vehicle_lateral", "gap": self.gap, "steps": self.steps}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        return self.simulate(theta)[0]

    def _tyre(self, alpha: float, fz: float, c_alpha: float) -> float:
        """Lateral force (N) of an axle at slip angle ``alpha`` (rad) under load ``fz`` (N)."""
        d = self.mu * fz
        b = c_alpha / (C_SHAPE * d)
        return d * math.sin(C_SHAPE * math.atan(b * alpha))

    def simulate(self, theta: np.ndarray) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        """The trial of the unit-box θ (d,) and its trace up to the end or the failure:
        ``time_s``, ``speed`` (m/s), ``e_y`` (m), ``e_psi`` (rad), ``delta`` (rad) and
        ``curvature`` (1/m), each (k,)."""
        w = self.space.to_physical(self.space.validate_unit(theta))
        sched = {g: w[3 * i:3 * i + 3] for i, g in enumerate(FEEDBACK)}
        k_i, tau_f = float(w[18]), float(w[19])
        wb = LF + LR
        fzf, fzr = self.m * G * LR / wb, self.m * G * LF / wb
        e_y = e_psi = v_y = r = delta = cmd_f = integ = s = 0.0
        queue = [0.0] * (self.delay + 1)                # steering commands, oldest first
        ey2 = ep2 = rate2 = 0.0
        trace: dict[str, list] = {k: [] for k in ("time_s", "speed", "e_y", "e_psi", "delta",
                                                   "curvature")}

        def done(out: lt.Outcome) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
            return out, {k: np.asarray(v) for k, v in trace.items()}

        for k in range(self.steps):
            t = k * DT
            vx = V0 + (V1 - V0) * t / (self.steps * DT)
            kap = curvature(s)
            gain = {g: float(np.interp(vx, SPEEDS, sched[g])) for g in FEEDBACK}
            e_la = e_y + gain["L_a"] * math.sin(e_psi)
            raw = (gain["k_ff"] * (wb + self.k_us * vx * vx) * kap - gain["k_y"] * e_la
                   - gain["k_psi"] * e_psi - gain["k_vy"] * v_y - gain["k_r"] * (r - kap * vx)
                   - k_i * integ)
            cmd_f += DT / (tau_f + DT) * (raw - cmd_f)
            queue.append(min(max(cmd_f, -DELTA_MAX), DELTA_MAX))
            cmd = queue.pop(0)
            rate = min(max((cmd - delta) / TAU_ACT, -RATE_MAX), RATE_MAX)
            delta += rate * DT
            a_f = delta - math.atan2(v_y + LF * r, vx)
            a_r = -math.atan2(v_y - LR * r, vx)
            fyf = self._tyre(a_f, fzf, self.cf)
            fyr = self._tyre(a_r, fzr, self.cr)
            v_y += DT * ((fyf * math.cos(delta) + fyr) / self.m - vx * r)
            r += DT * (LF * fyf * math.cos(delta) - LR * fyr) / self.iz
            s_dot = (vx * math.cos(e_psi) - v_y * math.sin(e_psi)) / max(1.0 - kap * e_y, 0.1)
            e_y += DT * (v_y * math.cos(e_psi) + vx * math.sin(e_psi))
            e_psi += DT * (r - kap * s_dot)
            s += DT * s_dot
            integ += DT * e_y
            for key, v in (("time_s", t + DT), ("speed", vx), ("e_y", e_y), ("e_psi", e_psi),
                           ("delta", delta), ("curvature", kap)):
                trace[key].append(v)
            beta = math.atan2(v_y, vx)
            if not (math.isfinite(e_y) and math.isfinite(r)) or abs(e_y) > LANE or \
                    abs(beta) > SPIN:
                return done(lt.Outcome(100.0 * (2 - k / self.steps), True, {"fall_step": k}))
            ey2 += e_y * e_y
            ep2 += e_psi * e_psi
            rate2 += rate * rate
        n = self.steps
        cost = math.sqrt(ey2 / n) + 0.5 * math.sqrt(ep2 / n) + 0.05 * math.sqrt(rate2 / n)
        return done(lt.Outcome(cost, False, {"rms_e_y_m": math.sqrt(ey2 / n)}))


def make_system(gap: float = 0.0, steps: int = STEPS) -> VehicleSystem:
    """``--system examples.vehicle_lateral:make_system [--system-arg gap=G]``."""
    return VehicleSystem(gap=gap, steps=steps)
