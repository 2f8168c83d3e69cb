"""A cheap user system of a fifth kind: 20 weights of a cart-pole's swing-up and balance
controller, designed on a model and run on a cart-pole that may differ from it (the
model-to-plant gap).

The plant: a cart (1.0 kg) on a track of ±1.2 m carrying a pole (a uniform rod, 0.2 kg,
half-length 0.4 m) on a damped pivot (0.002 N·m·s/rad); the cart has viscous (0.1 N·s/m) and
Coulomb (0.3 N, smoothed as ``tanh(ẋ / 0.01)``) friction. Equations of motion after Florian
(2007), "Correct equations for the dynamics of the cart-pole system", φ the pole's angle from
upright; semi-implicit Euler at 5 ms, the controller at 10 ms. The motor pushes the cart with
at most ±20 N. The pole starts hanging (φ = π) and at rest but for 0.1 rad/s, the cart at 0.

The controller (the tuned θ) measures the cart position ``x`` (m) and pole angle ``φ`` (rad)
only; it estimates their rates by differencing through first-order filters (``tau_v``,
``tau_w`` s). It has two modes:

* *swing-up* (energy control, Åström & Furuta 2000): the cart acceleration
  ``a = sat(k_E (E − E₀) sign(ω cos φ), a_max) − k_xs x − k_vs ẋ`` (m/s²), with the
  pole's energy ``E = ½ J ω² + m g l (cos φ − 1)`` (0 upright at rest) and the target
  ``E₀ = e_over · m g l``; the force is ``a`` times the model's total mass;
* *balance* (LQR on the model linearized upright, ``Q = diag(q_x, q_v, q_phi, q_w)``,
  ``R = r``): ``F = −s_K K (x, ẋ, φ, ω)`` on the state predicted ``t_lead`` seconds ahead
  (``x + t_lead ẋ``, ``φ + t_lead ω``), ``− k_i ∫x`` and ``+ k_fc`` times the model's Coulomb
  friction in the direction of ``ẋ``, at most ``u_max`` N.

It switches to balance when ``|φ| < phi_sw`` and ``|ω| < w_sw``, and back to swing-up when
``|φ| > phi_out``. θ (20, all log scale): ``k_E`` [0.05, 50], ``e_over`` [0.01, 0.5],
``k_xs`` [0.01, 20] 1/s², ``k_vs`` [0.01, 20] 1/s, ``a_max`` [1, 30] m/s², ``phi_sw``
[0.05, 1] rad, ``w_sw`` [0.5, 12] rad/s, ``phi_out`` [0.2, 1.5] rad, ``q_x`` [0.01, 100],
``q_v`` [0.01, 100], ``q_phi`` [0.1, 1000], ``q_w`` [0.01, 100], ``r`` [1e-3, 10],
``s_K`` [0.3, 3], ``k_i`` [1e-3, 10] N/(m·s), ``k_fc`` [0.01, 2], ``tau_v`` and ``tau_w``
[0.002, 0.2] s, ``t_lead`` [1e-3, 0.1] s, ``u_max`` [2, 40] N. Manual values:
:data:`MANUAL`.

The cart-pole differs from the model by ``gap`` g ≥ 0 (g = 0 is the model): pole mass ×
(1 + 0.3 g), pole length × (1 + 0.1 g), cart friction (viscous and Coulomb) × (1 + g), motor
force × (1 − 0.12 g) and an actuation delay of round(2 g) controller steps (10 ms each). A
heavier, longer pole on a stickier cart with a weaker, later motor: the balance gains the model
tolerates oscillate, and the swing-up no longer brings the pole up within the track (at gap 2
most θ that balance the model fail: ``tests/test_cartpole_swingup.py``; ``benchmarks.transfer``
uses gaps 0.5, 1 and 2).

Cost (8 s): the mean of ``1 − cos φ`` (the pole's height below upright, in pole lengths: a fast
swing-up costs less) plus 0.2 · the mean of ``x²`` (m²) plus 1e-4 · the mean of ``F²`` (N²).
A trial *fails* when the cart leaves the track (|x| > 1.2 m) or a value is non-finite at
controller step k (cost ``100 · (2 − k/steps)``, the built-in tasks' C1 convention: failing
later is better), or when the pole is not balanced over the last second (some |φ| > 0.25 rad
there; cost 100).

    --system examples.cartpole_swingup:make_system [--system-arg gap=1]

Written in session 45 as a fifth held-out family of the transfer ladder (underactuated, two
modes, energy control, velocity estimation): no option of phase 3 was chosen on it.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

import latentune as lt
from examples import checked_gap, checked_steps

DT = 0.01                           # s, the controller's step
SUB = 2                             # plant steps per controller step
STEPS = 800                         # 8 s
M_CART, M_POLE, HALF_LEN = 1.0, 0.2, 0.4        # kg, kg, m
B_CART, F_COULOMB, B_PIVOT = 0.1, 0.3, 0.002    # N·s/m, N, N·m·s/rad
F_MAX, TRACK = 20.0, 1.2                        # N, m
G = 9.81
BALANCED, LAST_S = 0.25, 1.0                    # rad, s
NAMES = ("k_E", "e_over", "k_xs", "k_vs", "a_max", "phi_sw", "w_sw", "phi_out", "q_x", "q_v",
         "q_phi", "q_w", "r", "s_K", "k_i", "k_fc", "tau_v", "tau_w", "t_lead", "u_max")
RANGES = {"k_E": (2.0, 200.0), "e_over": (0.02, 0.5), "k_xs": (0.3, 10.0),
          "k_vs": (0.3, 10.0), "a_max": (2.0, 15.0), "phi_sw": (0.1, 0.8),
          "w_sw": (1.0, 10.0), "phi_out": (0.3, 1.5), "q_x": (0.1, 30.0),
          "q_v": (0.05, 20.0), "q_phi": (1.0, 300.0), "q_w": (0.05, 20.0),
          "r": (0.005, 0.5), "s_K": (0.5, 2.0), "k_i": (0.005, 2.0), "k_fc": (0.05, 1.5),
          "tau_v": (0.003, 0.1), "tau_w": (0.003, 0.1), "t_lead": (0.002, 0.05),
          "u_max": (5.0, 40.0)}
MANUAL = {"k_E": 20.0, "e_over": 0.2, "k_xs": 2.0, "k_vs": 2.0, "a_max": 5.0,
          "phi_sw": 0.35, "w_sw": 4.0, "phi_out": 0.8, "q_x": 2.0, "q_v": 1.0, "q_phi": 20.0,
          "q_w": 1.0, "r": 0.05, "s_K": 1.0, "k_i": 0.1, "k_fc": 0.5, "tau_v": 0.02,
          "tau_w": 0.02, "t_lead": 0.01, "u_max": 15.0}


def cartpole_space() -> lt.ParameterSpace:
    """The 20 weights (module docstring), log scale, with :data:`MANUAL` as the manual θ."""
    return lt.ParameterSpace(names=list(NAMES), low=[RANGES[n][0] for n in NAMES],
                             high=[RANGES[n][1] for n in NAMES], log=[True] * len(NAMES),
                             manual=[MANUAL[n] for n in NAMES])


def wrap(a: float) -> float:
    """The angle ``a`` (rad) in [−π, π)."""
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


class CartPole:
    """The cart-pole's physics (module docstring) with pole mass ``m_pole`` (kg), half-length
    ``half_len`` (m) and cart friction ``b_cart`` (N·s/m), ``coulomb`` (N)."""

    def __init__(self, m_pole: float, half_len: float, b_cart: float, coulomb: float) -> None:
        self.mp, self.l, self.bc, self.fc = m_pole, half_len, b_cart, coulomb
        self.mt = M_CART + m_pole

    def accel(self, v: float, phi: float, w: float, force: float, coulomb: bool = True
              ) -> tuple[float, float]:
        """(ẍ m/s², φ̈ rad/s²) at cart speed ``v`` (m/s), pole angle ``phi`` and rate ``w``
        (rad, rad/s) under the cart force (N)."""
        sin, cos = math.sin(phi), math.cos(phi)
        fric = self.bc * v + (self.fc * math.tanh(v / 0.01) if coulomb else 0.0)
        tmp = (force + self.mp * self.l * w * w * sin - fric) / self.mt
        alpha = (G * sin - cos * tmp - B_PIVOT * w / (self.mp * self.l)) / (
            self.l * (4.0 / 3.0 - self.mp * cos * cos / self.mt))
        return tmp - self.mp * self.l * alpha * cos / self.mt, alpha

    def linearized(self) -> tuple[np.ndarray, np.ndarray]:
        """(A (4, 4), B (4, 1)) of the dynamics upright at rest (central differences; the
        Coulomb friction left out: its smoothed sign has no useful slope at ẋ = 0)."""
        def f(s: np.ndarray, u: float) -> np.ndarray:
            a, al = self.accel(s[1], s[2], s[3], u, coulomb=False)
            return np.array([s[1], a, s[3], al])
        A, B, h = np.zeros((4, 4)), np.zeros((4, 1)), 1e-6
        for j in range(4):
            e = np.zeros(4)
            e[j] = h
            A[:, j] = (f(e, 0.0) - f(-e, 0.0)) / (2 * h)
        B[:, 0] = (f(np.zeros(4), h) - f(np.zeros(4), -h)) / (2 * h)
        return A, B


MODEL = CartPole(M_POLE, HALF_LEN, B_CART, F_COULOMB)
A_UP, B_UP = MODEL.linearized()
"""The model linearized upright: what every θ's LQR is designed on."""


class CartPoleSystem:
    """The swing-up and balance weights on a cart-pole with model-to-plant ``gap`` (module
    docstring)."""

    def __init__(self, gap: float = 0.0, steps: int = STEPS) -> None:
        self.gap = checked_gap(gap)
        self.steps = checked_steps(steps)
        self.space = cartpole_space()
        g = self.gap
        self.plant = CartPole(M_POLE * (1 + 0.3 * g), HALF_LEN * (1 + 0.1 * g),
                              B_CART * (1 + g), F_COULOMB * (1 + g))
        self.motor = max(1.0 - 0.12 * g, 0.2)
        self.delay = int(round(min(2 * g, self.steps)))  # no longer than the episode

    def config(self) -> dict[str, Any]:
        return {"kind": "cartpole_swingup", "gap": self.gap, "steps": self.steps}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        return self.simulate(theta)[0]

    def simulate(self, theta: np.ndarray) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
        """The trial of the unit-box θ (d,) and its trace up to the end or the failure:
        ``time_s``, ``x`` (m), ``phi`` (rad, wrapped), ``force`` (N) and ``mode`` (1: balance),
        each (k,)."""
        from scipy.linalg import solve_continuous_are

        w = dict(zip(NAMES, self.space.to_physical(self.space.validate_unit(theta))))
        P = solve_continuous_are(A_UP, B_UP, np.diag([w["q_x"], w["q_v"], w["q_phi"], w["q_w"]]),
                                 np.array([[w["r"]]]))
        K = w["s_K"] * (B_UP.T @ P / w["r"]).reshape(4)
        mgl = MODEL.mp * G * MODEL.l
        J = 4.0 / 3.0 * MODEL.mp * MODEL.l ** 2
        e0 = w["e_over"] * mgl
        x, v, phi, om = 0.0, 0.0, math.pi, 0.1      # the plant's state
        k_x, k_v, k_p, k_w = (float(c) for c in K)
        x_prev, phi_prev = x, phi
        v_hat = w_hat = integ = 0.0
        balance = False
        queue = [0.0] * (self.delay + 1)
        cost_phi = cost_x = cost_f = 0.0
        last = max(1, int(round(LAST_S / DT)))
        worst_last = 0.0
        h = DT / SUB
        trace: dict[str, list] = {k: [] for k in ("time_s", "x", "phi", "force", "mode")}

        def done(out: lt.Outcome) -> tuple[lt.Outcome, dict[str, np.ndarray]]:
            return out, {k: np.asarray(v) for k, v in trace.items()}

        for k in range(self.steps):
            # the controller measures x and φ only
            v_hat += DT / (w["tau_v"] + DT) * ((x - x_prev) / DT - v_hat)
            w_hat += DT / (w["tau_w"] + DT) * (wrap(phi - phi_prev) / DT - w_hat)
            x_prev, phi_prev = x, phi
            p = wrap(phi)
            if balance and abs(p) > w["phi_out"]:
                balance = False
            elif not balance and abs(p) < w["phi_sw"] and abs(w_hat) < w["w_sw"]:
                balance, integ = True, 0.0
            if balance:
                integ += DT * x
                force = -(k_x * (x + w["t_lead"] * v_hat) + k_v * v_hat
                          + k_p * (p + w["t_lead"] * w_hat) + k_w * w_hat) \
                    - w["k_i"] * integ + w["k_fc"] * MODEL.fc * math.tanh(v_hat / 0.05)
                force = min(max(force, -w["u_max"]), w["u_max"])
            else:
                energy = 0.5 * J * w_hat ** 2 + mgl * (math.cos(p) - 1.0)
                pump = w["k_E"] * (energy - e0) * math.copysign(1.0, w_hat * math.cos(p))
                a = min(max(pump, -w["a_max"]), w["a_max"]) - w["k_xs"] * x - w["k_vs"] * v_hat
                force = MODEL.mt * a
            queue.append(min(max(force, -F_MAX), F_MAX))
            applied = self.motor * queue.pop(0)
            for _ in range(SUB):
                acc, alpha = self.plant.accel(v, phi, om, applied)
                v += h * acc
                om += h * alpha
                x += h * v
                phi += h * om
            p_new = wrap(phi)
            for key, val in (("time_s", (k + 1) * DT), ("x", x), ("phi", p_new),
                             ("force", applied), ("mode", float(balance))):
                trace[key].append(val)
            if not (math.isfinite(x) and math.isfinite(phi) and math.isfinite(v)
                    and math.isfinite(om)) or abs(x) > TRACK:
                return done(lt.Outcome(100.0 * (2 - k / self.steps), True, {"fall_step": k}))
            cost_phi += 1.0 - math.cos(p_new)
            cost_x += x * x
            cost_f += applied * applied
            if k >= self.steps - last:
                worst_last = max(worst_last, abs(p_new))
        if worst_last > BALANCED:
            return done(lt.Outcome(100.0, True, {"fall_step": self.steps,
                                                 "not_balanced_rad": worst_last}))
        n = self.steps
        cost = cost_phi / n + 0.2 * cost_x / n + 1e-4 * cost_f / n
        return done(lt.Outcome(cost, False, {"balanced_rad": worst_last}))


def make_system(gap: float = 0.0, steps: int = STEPS) -> CartPoleSystem:
    """``--system examples.cartpole_swingup:make_system [--system-arg gap=G]``."""
    return CartPoleSystem(gap=gap, steps=steps)
