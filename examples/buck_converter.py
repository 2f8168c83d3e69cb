"""A cheap user system of another kind: the 15 gains, limits and filters of the digital voltage
controller of a synchronous DC-DC buck converter (12 V in, a 3.3 V then 5 V rail out) feeding a
load that steps; tuned on the datasheet model, run on a board that differs from it (the
model-to-plant gap).

Added in session 51 (after the servo drive of session 50) as a system nobody had tuned the
default phase 3 for: its results are an out-of-sample check of the default, not an input to it.

The plant (SI units) is the switching-cycle-averaged converter in continuous conduction (a
synchronous stage conducts both ways): inductor ``L`` 4.7 µH with ``R`` 20 mΩ of winding and
switch resistance, output capacitor ``C`` 94 µF with ``ESR`` 5 mΩ (the LC resonance near
7.6 kHz), input ``Vin`` 12 V. The switch node averages ``d · Vin``; the duty ``d`` saturates at
[0, 0.95] (the PWM's limits). The load is an electronic load (current steps) beside 20 Ω. The
controller runs once per switching cycle, 200 kHz (``DT`` 5 µs), for 10 ms (2,000 cycles);
the plant is integrated with semi-implicit Euler at 4 sub-steps per cycle. Its measurements
(output voltage, inductor current, load current, input voltage) are ``delay`` cycles old (one
on the model: the ADC and the computation).

The task: a soft start to 3.3 V, a 1 → 4 A load step at 2.5 ms and its release at 4 ms, a
step of the set-point to 5 V at 5 ms (a dynamic voltage scaling command), a 1 → 4 A step at
6.5 ms and a release to 0.5 A at 8 ms. The controller is given the set-point as steps; the
specification it is judged against ramps (0 → 3.3 V in 0.5 ms, 3.3 → 5 V in 0.25 ms).

The controller (``buck_space``): the set-point passes a slew-rate limiter (``slew`` V/ms: the
soft start) and a first-order prefilter (``tau_ref``); the output voltage is measured through
a first-order filter (``fc_v``). The voltage loop is PI (``kp_v``, ``ki_v``, back-calculation
anti-windup ``k_aw``) plus a derivative (lead) term on the filtered measurement (``kd_v``,
its own filter ``fc_d``), load-current feed-forward (``kff_load`` × the measured load current)
and the capacitor's charging current for the prefiltered reference's rate (``kff_ref`` × C ×
dr/dt, with the model's C); the inductor-current command is clamped at ±``i_lim``. The current
loop is PI (``kp_i``, ``ki_i``, clamped integrator) plus output-voltage feed-forward
(``kff_vout`` × the measured output voltage: the switch node's steady value); the duty is that
voltage over ``kff_vin`` × the measured input voltage + (1 − ``kff_vin``) × 12 V (input-voltage
feed-forward), clamped to the PWM's range. Manual θ: a voltage loop of 1.5 A/V (crossing near
2.5 kHz) over a current loop of 0.2 V/A (near 7 kHz), 0.8 of the load current fed forward,
full voltage feed-forwards, a 6 V/ms soft start: it regulates the model (cost about 22, with
0.2–0.3 V dips and overshoots at the load steps) and gap 0.5; at gap 1 its current loop
oscillates with the longer delay and the output trips the over-voltage protection at the
first load release.

The board differs from the model by ``gap`` g ≥ 0 (g = 0 is the model itself): ``L`` ×
(1 − 0.25 g) (tolerance and saturation); ``C`` × (1 − 0.3 g) and, for the ceramic's DC-bias
derating, divided by 1 + 0.6 g (v / 5 V)² at output voltage v (at 5 V and g = 1 the
capacitance is 44 % of the datasheet's); ``ESR`` × (1 − 0.6 g) (less damping), ``R`` × (1 +
0.3 g) (hot); the input at 12 (1 − 0.15 g) V with a 1.5 kHz ripple of 0.6 g V and a source
resistance of 0.1 g Ω (the input droops with the input current ``d i``); 1 + round(2 g) cycles
of sensing and computation delay; and load steps × (1 + 0.5 g) (the 1 → 4 A steps become
1 → 5.5 A at g = 1).

Cost: the RMS error of the output voltage against the specification in mV over 10, plus the
overshoot above the set-point's 5 % band (the largest, in mV, over 50), plus 50 × the RMS duty
change per cycle (chatter); above 50 it is squashed to 50 + 50 tanh((c − 50) / 50), so that a
trial that stands costs less than 100, less than any fall. A good controller on the model costs
about 4–20. A trial *fails* (unsafe) when the output voltage exceeds the over-voltage protection
(1.2 × the set-point in force + 0.2 V), the inductor's peak current (its average plus half the
switching ripple ``(Vin − v) d DT / 2L``) exceeds the 12 A trip for 4 cycles in a row (20 µs),
the output stays below 70 % of the set-point for 2 ms (under-voltage: the rail never came up, or
collapsed), or the state becomes non-finite (an overflow of the simulation included) — at cycle
k of ``steps``; its cost is then ``100 · (2 − k/steps)`` (the built-in tasks' C1 convention:
failing later is better).

    --system examples.buck_converter:make_system [--system-arg gap=0.5]
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

DT = 5e-6
STEPS = 2000
SUB = 4
L0, R0, C0, ESR0, VIN0, R_LOAD = 4.7e-6, 0.02, 94e-6, 0.005, 12.0, 20.0
D_MAX = 0.95
I_TRIP = 12.0
TRIP_CYCLES = 4
OVP_GAIN, OVP_OFFSET = 1.2, 0.2
UV_FRACTION, UV_CYCLES = 0.7, 400
_SETPOINTS = ((0.0, 3.3), (5e-3, 5.0))
"""(from s, V): the set-point the controller is given (steps)."""
_SPEC = ((0.0, 0.0, 0.5e-3, 3.3), (5e-3, 3.3, 0.25e-3, 5.0))
"""(start s, from V, ramp s, to V): the specification the output is judged against."""
_LOAD = ((0.0, 1.0), (2.5e-3, 4.0), (4e-3, 1.0), (6.5e-3, 4.0), (8e-3, 0.5))
"""(from s, A) of the electronic load on the model; the steps above 1 A scale with the gap."""

NAMES = ("kp_v", "ki_v", "k_aw", "kd_v", "fc_d", "fc_v", "kff_load", "kff_ref", "i_lim",
         "kp_i", "ki_i", "kff_vout", "kff_vin", "slew", "tau_ref")


def buck_space() -> lt.ParameterSpace:
    """The 15 controller parameters (module docstring), their units and boxes: ``kp_v`` A/V,
    ``ki_v`` A/(V·s), ``k_aw`` 1/s, ``kd_v`` A·s/V, ``fc_d`` and ``fc_v`` Hz, ``kff_load``,
    ``kff_ref``, ``kff_vout`` and ``kff_vin`` fractions, ``i_lim`` A, ``kp_i`` V/A, ``ki_i``
    V/(A·s), ``slew`` V/ms, ``tau_ref`` s."""
    low = [0.05, 10.0, 100.0, 1e-6, 1e3, 1e3, 0.0, 0.0, 2.0, 0.02, 10.0, 0.0, 0.0, 0.5, 1e-6]
    high = [20.0, 1e5, 1e6, 1e-3, 1e5, 1e5, 1.5, 1.5, 14.0, 5.0, 1e5, 1.2, 1.0, 50.0, 1e-3]
    log = [True, True, True, True, True, True, False, False, False, True, True, False, False,
           True, True]
    manual = [1.5, 4000.0, 1e4, 1e-5, 2e4, 3e4, 0.8, 0.5, 8.0, 0.2, 2000.0, 1.0, 1.0, 6.0, 2e-5]
    return lt.ParameterSpace(names=list(NAMES), low=low, high=high, log=log, manual=manual)


def schedule(steps: int = STEPS, load_scale: float = 1.0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The set-point given to the controller, the specification (V) and the load's current
    steps (A, its steps above 1 A × ``load_scale``), each (steps,)."""
    t = np.arange(steps) * DT
    sp = np.zeros(steps)
    for t0, v in _SETPOINTS:
        sp[t >= t0] = v
    spec = np.zeros(steps)
    for t0, v0, ramp, v1 in _SPEC:
        s = np.clip((t - t0) / ramp, 0.0, 1.0)
        spec = np.where(t >= t0, v0 + (v1 - v0) * s, spec)
    load = np.zeros(steps)
    for t0, a in _LOAD:
        load[t >= t0] = a if a <= 1.0 else 1.0 + (a - 1.0) * load_scale
    return sp, spec, load


def _lowpass(fc: float) -> float:
    """The discrete first-order low-pass coefficient of cut-off ``fc`` Hz at DT."""
    w = 2 * math.pi * fc * DT
    return w / (1 + w)


class BuckSystem:
    """The buck converter's controller on a board with model-to-plant ``gap`` (module
    docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        self.space = buck_space()
        g = self.gap
        self.L = L0 * max(1 - 0.25 * g, 0.2)
        self.C = C0 * max(1 - 0.3 * g, 0.2)
        self.bias = 0.6 * g                          # C(v) = C / (1 + bias (v / 5 V)²)
        self.esr = ESR0 * max(1 - 0.6 * g, 0.1)
        self.R = R0 * (1 + 0.3 * g)
        self.vin = VIN0 * max(1 - 0.15 * g, 0.3)
        self.ripple = 0.6 * g
        self.r_src = 0.1 * g
        self.delay = min(1 + int(round(min(2 * g, self.steps))), self.steps)
        self.load_scale = 1 + 0.5 * g
        self.sp, self.spec, self.load = schedule(self.steps, self.load_scale)

    def config(self) -> dict[str, Any]:
        return {"kind": "buck_converter", "gap": self.gap, "steps": self.steps}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        return self._run(theta, False)[0]

    def simulate(self, theta: np.ndarray) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        """The trial of the unit-box θ (d,) and its trace up to the end or the failure:
        ``time_s``, ``setpoint`` and ``spec`` (V), ``vout`` (V), ``il`` (the inductor's average
        current, A), ``il_peak`` (with half the switching ripple, A), ``iload`` (A) and
        ``duty``, each (k,)."""
        return self._run(theta, True)

    def _run(self, theta: np.ndarray, record: bool
             ) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        (kp_v, ki_v, k_aw, kd_v, fc_d, fc_v, kff_load, kff_ref, i_lim, kp_i, ki_i, kff_vout,
         kff_vin, slew, tau_ref) = (
            float(w) for w in self.space.to_physical(self.space.validate_unit(theta)))
        a_v, a_d = _lowpass(fc_v), _lowpass(fc_d)
        a_pre = DT / (tau_ref + DT)
        dv_max = slew * 1e3 * DT                     # V per cycle
        L, R, C, esr, bias = self.L, self.R, self.C, self.esr, self.bias
        h = DT / SUB
        sp, spec, load = self.sp.tolist(), self.spec.tolist(), self.load.tolist()
        w_rip = 2 * math.pi * 1500.0
        u_max = 1.5 * VIN0                           # the current loop's integrator clamp
        il = vc = 0.0
        vout = 0.0
        n = self.delay
        q_v, q_i, q_l, q_in = [0.0] * n, [0.0] * n, [0.0] * n, [self.vin] * n
        r_lim = r_f = r_prev = v_f = d_f = 0.0
        i_v = i_i = 0.0
        d = d_prev = 0.0
        err2 = dd2 = over = 0.0
        trip = low = 0
        keys = ("time_s", "setpoint", "spec", "vout", "il", "il_peak", "iload", "duty")
        trace: dict[str, list] = {k: [] for k in keys}

        def done(cost: float, failed: bool, info: dict[str, Any]
                 ) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
            return lt.Outcome(cost, failed, info), {k: np.asarray(v) for k, v in trace.items()}

        for t in range(self.steps):
            tt = t * DT
            i_ext = load[t]
            # the measurements, ``delay`` cycles old
            q_v.append(vout)
            q_i.append(il)
            q_l.append(i_ext + vout / R_LOAD)
            vin_now = self.vin + self.ripple * math.sin(w_rip * tt) - self.r_src * d * il
            q_in.append(vin_now)
            y_v, y_i, y_l, y_in = q_v.pop(0), q_i.pop(0), q_l.pop(0), q_in.pop(0)
            # the reference: soft-start slew limiter, then the prefilter
            r_lim += min(max(sp[t] - r_lim, -dv_max), dv_max)
            r_f += a_pre * (r_lim - r_f)
            dr = (r_f - r_prev) / DT
            r_prev = r_f
            # the voltage loop
            v_prev = v_f
            v_f += a_v * (y_v - v_f)
            d_f += a_d * ((v_f - v_prev) / DT - d_f)
            e_v = r_f - v_f
            raw = kp_v * e_v + i_v - kd_v * d_f + kff_load * y_l + kff_ref * C0 * dr
            i_cmd = min(max(raw, -i_lim), i_lim)
            i_v += (ki_v * e_v + k_aw * (i_cmd - raw)) * DT
            # the current loop and the PWM
            e_i = i_cmd - y_i
            i_i = min(max(i_i + ki_i * e_i * DT, -u_max), u_max)
            u = kp_i * e_i + i_i + kff_vout * v_f
            den = kff_vin * y_in + (1 - kff_vin) * VIN0
            d = min(max(u / den if den > 1e-6 else 0.0, 0.0), D_MAX)
            # the plant over one switching cycle, semi-implicit Euler
            try:
                for _ in range(SUB):
                    il += h * (d * vin_now - R * il - vout) / L
                    i_c = il - i_ext - vout / R_LOAD
                    vc += h * i_c * (1 + bias * vc * vc / 25.0) / C
                    vout = vc + esr * (il - i_ext - vc / R_LOAD)
            except (OverflowError, ZeroDivisionError):      # a blow-up is a fall, not a crash
                vout = il = math.nan
            peak = abs(il) + max(vin_now - vout, 0.0) * d * DT / (2 * L)
            if record:
                for k, v in zip(keys, (tt, sp[t], spec[t], vout, il, peak, i_ext + vout / R_LOAD,
                                       d)):
                    trace[k].append(v)
            trip = trip + 1 if peak > I_TRIP else 0
            low = low + 1 if vout < UV_FRACTION * sp[t] else 0
            if not (math.isfinite(vout) and math.isfinite(il) and math.isfinite(raw)) \
                    or vout > OVP_GAIN * sp[t] + OVP_OFFSET or trip >= TRIP_CYCLES \
                    or low >= UV_CYCLES:
                reason = ("non-finite state" if not (math.isfinite(vout) and math.isfinite(il)
                                                     and math.isfinite(raw)) else
                          "over-voltage" if vout > OVP_GAIN * sp[t] + OVP_OFFSET else
                          "over-current trip" if trip >= TRIP_CYCLES else "under-voltage")
                return done(100.0 * (2 - t / self.steps), True,
                            {"fall_step": t, "reason": reason})
            e = vout - spec[t]
            err2 += e * e
            if sp[t] > 0:
                over = max(over, vout - 1.05 * sp[t])
            dd2 += (d - d_prev) ** 2
            d_prev = d
        rms_mv = 1e3 * math.sqrt(err2 / self.steps)
        over_mv = 1e3 * max(float(over), 0.0)
        rms_dd = math.sqrt(dd2 / self.steps)
        raw = rms_mv / 10 + over_mv / 50 + 50 * rms_dd
        cost = raw if raw <= 50 else 50 + 50 * math.tanh((raw - 50) / 50)    # < 100: below a fall
        return done(cost, False,
                    {"rms_err_mv": rms_mv, "overshoot_mv": over_mv, "rms_duty_step": rms_dd,
                     "raw_cost": raw})


def make_system(gap: float = 0.0, steps: int = STEPS) -> BuckSystem:
    """``--system examples.buck_converter:make_system [--system-arg gap=G]``."""
    return BuckSystem(gap=gap, steps=steps)
