"""A cheap user system of another kind: the 14 gains and filters of a cascaded servo drive (a
position loop over a velocity loop, feedforward, friction compensation, a notch filter) on a
motor that drives its load through a flexible shaft; tuned on a model, run on a drive that
differs from it (the model-to-plant gap).

Added in session 50 as a system nobody had tuned the default phase 3 for: its results are an
out-of-sample check of the default, not an input to it.

The plant (SI units) is a two-mass system: motor inertia ``Jm`` 1e-4 kg·m², load inertia
``Jl`` 4e-4 kg·m², a shaft of stiffness ``k`` 2 N·m/rad and damping 2e-3 N·m·s/rad (its
resonance near 25 Hz), viscous friction on both sides and Coulomb friction ``Fc`` 0.01 N·m on
the load (smoothed over 0.01 rad/s). The current loop is a first-order lag of ``tau_c`` 2 ms;
the torque saturates at ``tau_max`` 0.5 N·m. Only the motor is measured: a 4096-line encoder
read with ``delay`` samples of latency. It is simulated with semi-implicit Euler at the
controller's rate, 1 kHz, for 1.5 s: three point-to-point moves of the load (smooth S-curves,
0 → 1 → −0.5 → 0.3 rad) with holds between them.

The controller (``servo_space``): the reference passes a first-order prefilter (``tau_ref``);
the position loop is PI (``kp_pos``, ``ki_pos``) on the measured motor angle plus velocity
feedforward (``kff_v`` × the reference's rate); the velocity loop is PI (``kp_vel``,
``ki_vel``, back-calculation anti-windup ``k_aw``) on a filtered finite-difference speed
(cut-off ``fc_vel``), plus acceleration feedforward (``kff_a`` × the model's total inertia ×
the reference's acceleration) and Coulomb friction compensation (``fc_comp`` N·m × the sign of
the reference's rate, smoothed). The torque command passes a notch (``f_notch``, ``zeta_notch``,
``depth_notch``) and a low-pass filter (``fc_tau``). Manual θ: a soft velocity loop (its
bandwidth well below the shaft's resonance) with full feedforward, the notch off: it stands on
the model and up to gap 0.7, where it tracks poorly; at gap 1 it limit-cycles (fails).

The plant differs from the model by ``gap`` g ≥ 0 (g = 0 is the model itself): ``Jl`` ×
(1 + 0.8 g), ``k`` × (1 − 0.3 g), ``Fc`` and the load's viscous friction × (1 + 1.5 g),
``tau_c`` × (1 + g), a latency of 1 + round(2 g) samples, and ``tau_max`` × (1 − 0.2 g).

Cost: the load's RMS tracking error in mrad plus 2 × the RMS torque-command change per sample
in mN·m (chatter). A trial *fails* when the load's tracking error exceeds 0.3 rad, the state
becomes non-finite, or the drive limit-cycles in the last hold (the torque command's standard
deviation there above 0.05 N·m) — at step k of ``steps``; its cost is then
``100 · (2 − k/steps)`` (the built-in tasks' C1 convention: failing later is better).

    --system examples.servo_cascade:make_system [--system-arg gap=0.5]
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

DT = 1e-3
STEPS = 1500
JM, JL, K_SHAFT, C_SHAFT = 1e-4, 4e-4, 2.0, 2e-3
BM, BL, FC = 1e-4, 5e-4, 0.01
TAU_C, TAU_MAX = 2e-3, 0.5
LINES = 4096
ERR_LIMIT = 0.3
HOLD_STD_LIMIT = 0.05
_MOVES = ((0.05, 0.35, 0.0, 1.0), (0.55, 0.9, 1.0, -0.5), (1.05, 1.3, -0.5, 0.3))
"""(start s, end s, from rad, to rad) of the load's moves; it holds between them."""

NAMES = ("kp_pos", "ki_pos", "kff_v", "kp_vel", "ki_vel", "k_aw", "kff_a", "fc_comp",
         "fc_vel", "f_notch", "zeta_notch", "depth_notch", "fc_tau", "tau_ref")


def servo_space() -> lt.ParameterSpace:
    """The 14 controller parameters (module docstring), their units and boxes."""
    low = [1.0, 1e-2, 0.0, 1e-4, 1e-3, 1.0, 0.0, 0.0, 20.0, 5.0, 0.05, 0.0, 50.0, 1e-3]
    high = [300.0, 100.0, 1.5, 0.5, 50.0, 1e4, 1.5, 0.03, 2000.0, 200.0, 1.0, 1.0, 3000.0, 0.1]
    log = [True, True, False, True, True, True, False, False, True, True, True, False, True,
           True]
    manual = [40.0, 1.0, 1.0, 0.01, 0.2, 100.0, 0.9, 0.008, 100.0, 40.0, 0.3, 0.0, 800.0, 0.005]
    return lt.ParameterSpace(names=list(NAMES), low=low, high=high, log=log, manual=manual)


def reference(steps: int = STEPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The load's reference angle (rad), rate (rad/s) and acceleration (rad/s²), each
    (steps,): smooth (quintic) S-curves between holds."""
    t = np.arange(steps) * DT
    r, v, a = np.zeros(steps), np.zeros(steps), np.zeros(steps)
    r[:] = _MOVES[0][2]
    for t0, t1, p0, p1 in _MOVES:
        T = t1 - t0
        s = np.clip((t - t0) / T, 0.0, 1.0)
        inside = (t >= t0) & (t <= t1)
        d = p1 - p0
        after = t > t1
        r[after] = p1
        r[inside] = p0 + d * (10 * s[inside] ** 3 - 15 * s[inside] ** 4 + 6 * s[inside] ** 5)
        v[inside] = d / T * (30 * s[inside] ** 2 - 60 * s[inside] ** 3 + 30 * s[inside] ** 4)
        a[inside] = d / T ** 2 * (60 * s[inside] - 180 * s[inside] ** 2 + 120 * s[inside] ** 3)
    return r, v, a


def _lowpass(fc: float) -> float:
    """The discrete first-order low-pass coefficient of cut-off ``fc`` Hz at DT."""
    w = 2 * math.pi * fc * DT
    return w / (1 + w)


def _notch(f: float, zeta: float, depth: float) -> tuple[float, ...]:
    """A biquad notch at ``f`` Hz (width ``zeta``, ``depth`` 0 = none, 1 = full), bilinear at DT
    with the centre pre-warped: (b0, b1, b2, a1, a2) normalised by a0."""
    w0 = 2 / DT * math.tan(math.pi * f * DT)
    zn = zeta * (1 - depth)                      # the zeros' damping: depth 1 cancels the tone
    c = 2 / DT
    b0, b1, b2 = c * c + 2 * zn * w0 * c + w0 * w0, 2 * (w0 * w0 - c * c), \
        c * c - 2 * zn * w0 * c + w0 * w0
    a0, a1, a2 = c * c + 2 * zeta * w0 * c + w0 * w0, 2 * (w0 * w0 - c * c), \
        c * c - 2 * zeta * w0 * c + w0 * w0
    return b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0


class ServoSystem:
    """The servo drive's controller on a plant with model-to-plant ``gap`` (module docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        self.space = servo_space()
        g = self.gap
        self.jl = JL * (1 + 0.8 * g)
        self.k = K_SHAFT * max(1 - 0.3 * g, 0.2)
        self.fc = FC * (1 + 1.5 * g)
        self.bl = BL * (1 + 1.5 * g)
        self.tau_c = TAU_C * (1 + g)
        self.delay = min(1 + int(round(min(2 * g, self.steps))), self.steps)   # ≤ the episode
        self.tau_max = TAU_MAX * max(1 - 0.2 * g, 0.2)
        self.ref = reference(self.steps)

    def config(self) -> dict[str, Any]:
        return {"kind": "servo_cascade", "gap": self.gap, "steps": self.steps}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        return self.simulate(theta)[0]

    def simulate(self, theta: np.ndarray) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        """The trial of the unit-box θ (d,) and its trace up to the end or the failure:
        ``time_s``, ``ref`` and ``load`` (the load's reference and angle, rad), ``motor``
        (the motor's angle, rad) and ``torque`` (the command after the drive's limit, N·m),
        each (k,)."""
        (kp_pos, ki_pos, kff_v, kp_vel, ki_vel, k_aw, kff_a, fc_comp, fc_vel, f_notch,
         zeta_notch, depth_notch, fc_tau, tau_ref) = (
            float(w) for w in self.space.to_physical(self.space.validate_unit(theta)))
        r_ref, v_ref, a_ref = self.ref
        a_vel, a_tau = _lowpass(fc_vel), _lowpass(fc_tau)
        a_pre = DT / (tau_ref + DT)
        b0, b1, b2, a1, a2 = _notch(f_notch, zeta_notch, depth_notch)
        j_total = JM + JL                            # the model's, as a user would know it
        q = 2 * math.pi / LINES
        lag = DT / (self.tau_c + DT)
        th_m = w_m = th_l = w_l = tau_m = 0.0
        meas = [0.0] * (self.delay + 1)
        pre = prev_meas = w_hat = i_pos = i_vel = tau_f = 0.0
        x1 = x2 = y1 = y2 = 0.0                      # the notch's past inputs and outputs
        err2 = dtau2 = 0.0
        prev_cmd = 0.0
        hold: list[float] = []
        hold_from = int(_MOVES[-1][1] / DT) + 50
        trace: dict[str, list] = {k: [] for k in ("time_s", "ref", "load", "motor", "torque")}

        def done(cost: float, failed: bool, info: dict[str, Any]
                 ) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
            return lt.Outcome(cost, failed, info), {k: np.asarray(v) for k, v in trace.items()}
        for t in range(self.steps):
            # measurement: the motor encoder, quantised, ``delay`` samples old
            meas.append(round(th_m / q) * q)
            y = meas.pop(0)
            pre += a_pre * (r_ref[t] - pre)
            w_hat += a_vel * ((y - prev_meas) / DT - w_hat)
            prev_meas = y
            e_pos = pre - y
            i_pos += ki_pos * e_pos * DT
            w_cmd = kp_pos * e_pos + i_pos + kff_v * v_ref[t]
            e_vel = w_cmd - w_hat
            u = kp_vel * e_vel + i_vel + kff_a * j_total * a_ref[t] \
                + fc_comp * math.tanh(v_ref[t] / 0.05)
            # the notch and the low-pass on the torque command, then the drive's limit
            n = b0 * u + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2
            x2, x1, y2, y1 = x1, u, y1, n
            tau_f += a_tau * (n - tau_f)
            cmd = min(max(tau_f, -self.tau_max), self.tau_max)
            i_vel += (ki_vel * e_vel + k_aw * (cmd - tau_f)) * DT
            # the plant: current lag, then the two masses (semi-implicit Euler)
            tau_m += lag * (cmd - tau_m)
            twist = self.k * (th_m - th_l) + C_SHAFT * (w_m - w_l)
            w_m += DT * (tau_m - twist - BM * w_m) / JM
            w_l += DT * (twist - self.bl * w_l - self.fc * math.tanh(w_l / 0.01)) / self.jl
            th_m += DT * w_m
            th_l += DT * w_l
            e = th_l - r_ref[t]
            for k, v in (("time_s", t * DT), ("ref", r_ref[t]), ("load", th_l),
                         ("motor", th_m), ("torque", cmd)):
                trace[k].append(v)
            if not (math.isfinite(th_l) and math.isfinite(tau_f)) or abs(e) > ERR_LIMIT:
                return done(100.0 * (2 - t / self.steps), True, {"fall_step": t})
            err2 += e * e
            dtau2 += (cmd - prev_cmd) ** 2
            prev_cmd = cmd
            if t >= hold_from:
                hold.append(cmd)
        if len(hold) > 10 and float(np.std(hold)) > HOLD_STD_LIMIT:
            return done(100.0, True, {"fall_step": self.steps - 1,
                                      "reason": "limit cycle in the last hold"})
        rms_err = math.sqrt(err2 / self.steps)
        rms_dtau = math.sqrt(dtau2 / self.steps)
        return done(1e3 * rms_err + 2e3 * rms_dtau, False,
                    {"rms_err_mrad": 1e3 * rms_err, "rms_dtau_mNm": 1e3 * rms_dtau})


def make_system(gap: float = 0.0, steps: int = STEPS) -> ServoSystem:
    """``--system examples.servo_cascade:make_system [--system-arg gap=G]``."""
    return ServoSystem(gap=gap, steps=steps)
