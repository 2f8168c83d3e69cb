"""A cheap user system of another kind: a 21-weight joint controller of a two-link planar arm
that tracks a fast reaching motion, tuned on a model and run on an arm that differs from it.

The arm (vertical plane, gravity on): links of 0.5 m and 1 kg each (point masses at the link
ends), joint torques limited to ±40 N·m, 1 kHz simulation, a 1.2 s motion: both joints follow a
minimum-jerk reach from (−0.6, 0.9) rad to (0.7, −0.5) rad in 0.6 s and hold. Per joint ``j`` the
controller is::

    τ_j = kp_j e + ki_j ∫e (|∫e| ≤ ilim_j) + kd_j ė_f + ffv_j q̇_ref + ffa_j M̂_jj q̈_ref
          + grav_j Ĝ_j(q) + fric_j sign(q̇_ref)

with ``ė_f`` the error rate through a first-order filter of cutoff ``fc_j`` Hz, ``M̂``, ``Ĝ`` the
*model's* inertia and gravity; and one coupling gain ``cpl`` that adds ``cpl · M̂_12 q̈_ref`` of
the other joint: 10 weights per joint + 1 = **21** (log scale, except the feedforward gains
``ffv``, ``ffa``, ``grav``, ``fric`` and ``cpl`` which are linear). Manual θ: a stiff PD with
gravity compensation, a reasonable hand tuning.

``gap`` g ≥ 0 makes the real arm differ from the model (g = 0 is the model): a payload of
1.5 g kg at the tip, viscous friction 0.4 g N·m·s/rad and Coulomb friction 1.5 g N·m in both
joints, and a sensing delay of round(4 g) ms. Cost: the RMS joint tracking error in degrees.
A trial *fails* when a joint leaves ±π, a speed exceeds 25 rad/s or the state is not finite at
step k; its cost is then ``100 · (2 − k/N)``.

    --system examples.arm_controller:make_system [--system-arg gap=1]
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap

DT = 0.001
T_MOTION = 0.6
T_TOTAL = 1.2
Q0 = np.array([-0.6, 0.9])
Q1 = np.array([0.7, -0.5])
TAU_MAX = 40.0
L1 = L2 = 0.5
G = 9.81
_PER_JOINT = (("kp", 1.0, 2000.0, True, 300.0), ("ki", 0.1, 2000.0, True, 10.0),
              ("kd", 0.1, 200.0, True, 20.0), ("fc", 2.0, 200.0, True, 50.0),
              ("ilim", 0.01, 1.0, True, 0.1), ("ffv", 0.0, 10.0, False, 0.0),
              ("ffa", 0.0, 2.0, False, 0.0), ("grav", 0.0, 2.0, False, 1.0),
              ("fric", 0.0, 5.0, False, 0.0), ("dz", 1e-4, 0.1, True, 1e-3))


def arm_space() -> lt.ParameterSpace:
    """The 21 weights ``<gain>_<joint>`` for joints 1, 2, then ``cpl``."""
    names, low, high, log, manual = [], [], [], [], []
    for j in (1, 2):
        for name, lo, hi, lg, man in _PER_JOINT:
            names.append(f"{name}_{j}")
            low.append(lo)
            high.append(hi)
            log.append(lg)
            manual.append(man)
    names.append("cpl")
    low.append(0.0)
    high.append(2.0)
    log.append(False)
    manual.append(0.0)
    return lt.ParameterSpace(names=names, low=low, high=high, log=log, manual=manual)


def _reference(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = min(t / T_MOTION, 1.0)
    p = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
    dp = (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4) / T_MOTION if s < 1 else 0.0
    ddp = (60 * s - 180 * s ** 2 + 120 * s ** 3) / T_MOTION ** 2 if s < 1 else 0.0
    d = Q1 - Q0
    return Q0 + p * d, dp * d, ddp * d


_REF = [tuple(tuple(float(v) for v in a) for a in _reference(k * DT))
        for k in range(int(round(T_TOTAL / DT)))]
"""The reference (q, q̇, q̈) of every control step, as floats."""


class ArmSystem:
    """The arm controller's 21 weights on an arm with model-to-arm ``gap`` (module docstring)."""

    def __init__(self, gap: float = 0.0) -> None:
        self.gap = checked_gap(gap)
        self.space = arm_space()
        g = self.gap
        self.payload = 1.5 * g
        self.visc = 0.4 * g
        self.coulomb = 1.5 * g
        self.delay = int(round(min(4 * g, T_TOTAL / DT)))  # no longer than the episode

    def config(self) -> dict[str, Any]:
        return {"kind": "arm2", "gap": self.gap}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        w = self.space.to_physical(self.space.validate_unit(theta))
        P = w[:20].reshape(2, 10)
        kp, ki, kd, fc, ilim, ffv, ffa, grav, fric, dz = P.T
        cpl = w[20]
        n = int(round(T_TOTAL / DT))
        kp, ki, kd, ilim, ffv, ffa, grav, fric, dz = (
            [float(v) for v in col] for col in (kp, ki, kd, ilim, ffv, ffa, grav, fric, dz))
        alpha = [1.0 - math.exp(-2 * math.pi * float(f) * DT) for f in fc]
        m2 = 1.0 + self.payload
        q1, q2, w1, w2 = float(Q0[0]), float(Q0[1]), 0.0, 0.0
        hist = [(q1, q2)] * (self.delay + 1)      # measured joint angles, oldest first
        ie = [0.0, 0.0]
        df = [0.0, 0.0]
        prev = None
        err2 = 0.0
        vis, cou = self.visc, self.coulomb
        for k in range(n):
            qr, dqr, ddqr = _REF[k]
            qs = hist[0]
            e = [qr[j] - qs[j] for j in (0, 1)]
            e = [0.0 if abs(e[j]) < dz[j] else e[j] for j in (0, 1)]
            if prev is None:
                prev = e
            # the model's inertia diagonal/coupling and gravity at the measured angles
            c2m = math.cos(qs[1])
            Mh11 = 2 * L1 ** 2 + L2 ** 2 + 2 * L1 * L2 * c2m
            Mh12 = L2 ** 2 + L1 * L2 * c2m
            Mh22 = L2 ** 2
            Gh1 = 2 * G * L1 * math.cos(qs[0]) + G * L2 * math.cos(qs[0] + qs[1])
            Gh2 = G * L2 * math.cos(qs[0] + qs[1])
            Mhd, Gh = (Mh11, Mh22), (Gh1, Gh2)
            tau = []
            for j in (0, 1):
                df[j] += alpha[j] * ((e[j] - prev[j]) / DT - df[j])
                ie[j] = min(max(ie[j] + e[j] * DT, -ilim[j]), ilim[j])
                sg = 0.0 if dqr[j] == 0 else math.copysign(1.0, dqr[j])
                t_j = kp[j] * e[j] + ki[j] * ie[j] + kd[j] * df[j] + ffv[j] * dqr[j] \
                    + ffa[j] * Mhd[j] * ddqr[j] + grav[j] * Gh[j] + fric[j] * sg \
                    + cpl * Mh12 * ddqr[1 - j]
                tau.append(min(max(t_j, -TAU_MAX), TAU_MAX))
            prev = e
            # the true arm (payload m2, friction)
            c2, s2 = math.cos(q2), math.sin(q2)
            M11 = (1.0 + m2) * L1 ** 2 + m2 * L2 ** 2 + 2 * m2 * L1 * L2 * c2
            M12 = m2 * L2 ** 2 + m2 * L1 * L2 * c2
            M22 = m2 * L2 ** 2
            h = m2 * L1 * L2 * s2
            g1 = (1.0 + m2) * G * L1 * math.cos(q1) + m2 * G * L2 * math.cos(q1 + q2)
            g2 = m2 * G * L2 * math.cos(q1 + q2)
            b1 = tau[0] + h * (2 * w1 * w2 + w2 * w2) - g1 - vis * w1 - cou * math.tanh(w1 / 0.01)
            b2 = tau[1] - h * w1 * w1 - g2 - vis * w2 - cou * math.tanh(w2 / 0.01)
            det = M11 * M22 - M12 * M12
            a1 = (M22 * b1 - M12 * b2) / det
            a2 = (M11 * b2 - M12 * b1) / det
            w1 += a1 * DT
            w2 += a2 * DT
            q1 += w1 * DT
            q2 += w2 * DT
            hist.append((q1, q2))
            hist.pop(0)
            if not (abs(q1) < math.pi and abs(q2) < math.pi and abs(w1) < 25 and abs(w2) < 25):
                return lt.Outcome(100.0 * (2 - k / n), True, {"fall_step": k})
            err2 += (qr[0] - q1) ** 2 + (qr[1] - q2) ** 2
        return lt.Outcome(math.degrees(math.sqrt(err2 / (2 * n))), False, {})


def make_system(gap: float = 0.0) -> ArmSystem:
    """``--system examples.arm_controller:make_system [--system-arg gap=G]``."""
    return ArmSystem(gap=gap)
