"""Kino-dynamic MPC actor (after BiConMP, Meduri et al. 2022): centroidal planner + whole-body DDP.

Every ``REPLAN_EVERY`` physics steps (50 ms, 20 Hz) from the measured state:

1. :class:`~latentune.actor.centroidal.CentroidalPlanner` — CoM, l/m, k/m and the ground forces
   (in m·g) over 10 knots × 0.05 s under friction pyramids, by alternating convex QPs
   (weights W_X, W_X_ter, W_F);
2. :class:`~latentune.actor.wholebody.WholeBodyDDP` — crocoddyl FDDP on the free-flyer model,
   tracking the plan's CoM/momentum (cent_wt), the stance and swing feet, and regularized toward
   the nominal stance (state_wt); warm-started, ≤ ``DDP_ITERS`` iterations.

At 1 kHz (impedance / inverse-dynamics tracking): joint PD around the DDP's joint trajectory
(linearly interpolated between knots) plus the planned contact forces as feed-forward,
τ = kp (q* − q) + kd (q̇* − q̇) − Jᵀ Rᵀ f for stance legs (f: the ground's force on the foot,
world frame; J: the leg Jacobian in the base frame, refreshed every ``FF_EVERY`` steps and at
contact switches; the forces are the plan's first knot, held for the 50 ms).

θ (77, physical) = W_X (9) ‖ W_X_ter (9) ‖ W_F (12) ‖ state_wt (36) ‖ cent_wt (9) ‖ kp ‖ kd.
The planner works in robot-normalized units (l/m, k/m, f/(m·g)), the DDP's momentum weights are
scaled the same way, and kp, kd are stored per robot as (relative gain) × (the robot's nominal
joint gain ``spec.kp``, ``spec.kd`` divided by Solo12's), so one normalized θ means the same on
Solo12 and A1. Bounds (all log-scaled): each weight ∈ [manual / 100, manual × 100], kp and kd
∈ [manual / 10, manual × 10]. The manual θ is BiConMP's published Solo12 trot configuration, with
the deviations listed in ``MANUAL_NOTES``; the same normalized manual θ trots and pronks Solo12,
A1 and B1.
"""
from __future__ import annotations

import math
import time

import numpy as np

from latentune.actor import wholebody as _wholebody
from latentune.actor.base import Actor, ActorFailure
from latentune.actor.centroidal import CentroidalPlanner
from latentune.actor.gait import GaitScheduler, StepContacts
from latentune.actor.legs import LegKinematics
from latentune.constants import G
from latentune.robots import LEGS, RobotSpec
from latentune.space import ParameterSpace, make_space
from latentune.sim.world import RobotState, World

if _wholebody.crocoddyl is None:  # Task turns this into "actor 'kinodynamic' is not available here"
    raise ImportError("the kino-dynamic MPC actor needs crocoddyl "
                      "(pip install --no-deps crocoddyl==3.2.1 libcrocoddyl==3.2.1)")

X_NAMES = ("cx", "cy", "cz", "lx", "ly", "lz", "kx", "ky", "kz")
_JNAMES = ("haa", "hfe", "kfe")
STATE_NAMES = (tuple(f"base_{a}" for a in "xyz") + tuple(f"base_r{a}" for a in "xyz")
               + tuple(f"q_{leg}_{j}" for leg in LEGS for j in _JNAMES)
               + tuple(f"base_v{a}" for a in "xyz") + tuple(f"base_w{a}" for a in "xyz")
               + tuple(f"dq_{leg}_{j}" for leg in LEGS for j in _JNAMES))
CENT_NAMES = ("com_x", "com_y", "com_z", "lmom_x", "lmom_y", "lmom_z", "amom_x", "amom_y", "amom_z")
F_NAMES = tuple(f"{leg}_f{a}" for leg in LEGS for a in "xyz")

# BiConMP's Solo12 trot configuration (demos/mpc/solo12_gait_params.py, `trot`) as the manual θ.
# Entries that are exactly 0 there get a small positive value (log-scaled bounds need > 0).
W_X_MANUAL = np.array([1e-5, 1e-5, 1e5, 1e1, 1e1, 2e2, 1e4, 1e4, 1e4])
W_X_TER_MANUAL = 10.0 * np.array([1e5, 1e-5, 1e5, 1e1, 1e1, 2e2, 1e5, 1e5, 1e5])
W_F_MANUAL = np.full(12, 1e1)
STATE_WT_MANUAL = np.array([1e-2, 1e-2, 10.0] + [1000.0] * 3 + [1.0] * 12
                           + [1e-2] * 3 + [100.0] * 3 + [0.5] * 12)
CENT_WT_MANUAL = np.array([5e1] * 3 + [5e2] * 3 + [5e2] * 3)
KP_MANUAL, KD_MANUAL = 3.0, 0.05          # Solo12 [N·m/rad], [N·m·s/rad]
SOLO_KP, SOLO_KD = 6.0, 0.15              # Solo12's spec.kp / spec.kd: the gain unit
MANUAL_NOTES = (
    "W_X, W_X_ter (incl. its 1e6 on terminal com x), W_F, kp = 3.0: BiConMP's Solo12 trot values;",
    "kd = 0.05 (BiConMP's current trot file has 0.3; its bound config has 0.05);",
    "state_wt base x/y position and base linear velocity: 0 in BiConMP -> 1e-2 (log bounds need > 0);",
    "cent_wt: BiConMP has 2 weights (com, momentum) = (0·5e1, 5e2); here 9: com 5e1 (BiConMP's "
    "value before its ×0, it keeps the kinematic CoM on the plan), l/m and k/m 5e2;",
    "gait timing, step height (0.05 m) and nominal height (0.24 m) come from the task's RobotSpec "
    "(BiConMP's file: step 0.13 m, height 0.26 m);",
    "fixed, not tuned: reg_wt (5e-2, 1e-5), swing_wt 1e4 (BiConMP values), ctrl_wt (BiConMP's with "
    "the base x/y entries 0 -> 1, around a gravity-compensation reference), orientation correction "
    "gains ORI_GAIN (BiConMP's ori_correction plays this role), DDP ≤ 3 FDDP iterations.",
)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class KinodynamicMPC(Actor):
    """Kino-dynamic MPC actor; θ (77, physical) as in the module docstring."""

    name = "kinodynamic"
    HORIZON = 10
    KNOT_DT = 0.05          # [s]
    REPLAN_EVERY = 50       # physics steps (20 Hz at 1 kHz)
    DDP_ITERS = 3           # FDDP iteration cap per solve (warm-started)
    FF_EVERY = 5            # physics steps between leg-Jacobian refreshes of the feed-forward
    PLANNER_ITERS = 3
    U_MAX = 2.5             # per-foot normal force bound [m·g]
    ORI_GAIN = np.array([3.0, 3.0, 2.0])   # [1/s] angular-momentum reference from orientation error
    DIM = 77

    @classmethod
    def space(cls, spec: RobotSpec, gait: str) -> ParameterSpace:
        s_kp = float(np.mean(spec.kp)) / SOLO_KP
        s_kd = float(np.mean(spec.kd)) / SOLO_KD
        rows = []
        for prefix, names, man in (("WX", X_NAMES, W_X_MANUAL), ("WXter", X_NAMES, W_X_TER_MANUAL),
                                   ("WF", F_NAMES, W_F_MANUAL), ("sw", STATE_NAMES, STATE_WT_MANUAL),
                                   ("cw", CENT_NAMES, CENT_WT_MANUAL)):
            rows += [(f"{prefix}_{n}", m / 100.0, m * 100.0, True, float(m)) for n, m in zip(names, man)]
        rows.append(("kp", KP_MANUAL * s_kp / 10.0, KP_MANUAL * s_kp * 10.0, True, KP_MANUAL * s_kp))
        rows.append(("kd", KD_MANUAL * s_kd / 10.0, KD_MANUAL * s_kd * 10.0, True, KD_MANUAL * s_kd))
        return make_space(rows)

    def __init__(self, world: World, gait: str, v_des: np.ndarray, theta: np.ndarray):
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.DIM,):
            raise ValueError(f"kino-dynamic MPC needs {self.DIM} parameters, got shape {theta.shape}")
        if not np.all(np.isfinite(theta)) or np.any(theta <= 0):
            raise ValueError("kino-dynamic MPC parameters must be finite and positive")
        spec = world.spec
        self.world, self.spec, self.model = world, spec, world.model
        self.legs = LegKinematics(world.model)
        self.gait = GaitScheduler(spec.gait(gait))
        self.v_des = np.asarray(v_des, dtype=float)
        self.w_x, self.w_x_ter, self.w_f = theta[0:9], theta[9:18], theta[18:30]
        self.state_wt, self.cent_wt = theta[30:66], theta[66:75]
        self.kp, self.kd = float(theta[75]), float(theta[76])
        self.mass = float(world.model.mass)
        self.dt = world.dt
        self.planner = CentroidalPlanner(self.KNOT_DT, self.HORIZON, spec.mu, self.U_MAX,
                                         self.PLANNER_ITERS)
        self.ddp = _wholebody.WholeBodyDDP(world.model, self.KNOT_DT, self.HORIZON, self.state_wt, self.cent_wt,
                                self.DDP_ITERS)
        self.tau_lim = np.tile(spec.torque_limits, 4)
        self._tau_lo = -self.tau_lim
        self.qi, self.vi = self.ddp.qi, self.ddp.vi
        self.nq = self.ddp.nq
        self.forces = np.zeros((2, 4, 3))      # world ground forces on the feet at knots 0, 1 [N]
        self.knot_contact = np.zeros((2, 4), dtype=bool)
        self.xs = None
        self.replan_step = 0
        self.start_yaw = None
        self.liftoff = None                     # (4, 3) world position where each foot last stood
        self._offsets = [float(o) for o in self.gait.offsets]
        self._step_contacts = StepContacts(self.gait, self.dt, 1e-6)   # = _contact(step · dt)
        self._yaw_frame: tuple | None = None    # functions of start_yaw (see _start_frame)
        self._ff = np.zeros(12)
        self._ff_contact = None
        self.c_guess = None
        self.timing = {"centroidal": 0.0, "ddp": 0.0, "replan": 0.0, "control": 0.0}
        self.n_replan = 0
        self.n_control = 0

    # ------------------------------------------------------------------ footholds
    def _start_frame(self) -> tuple:
        """Constants of the start yaw (set once, at the first control step): Rz (3, 3), its
        quaternion (4,), Rz·com_offset (3,) and each leg's lateral stance offset Rz·(0, y, 0)
        (4 × (3,)) [m]."""
        if self._yaw_frame is None or self._yaw_frame[0] != self.start_yaw:
            Rz = _rot_z(self.start_yaw)
            lateral = [Rz @ np.array([0.0, self.model.foot_stance[leg, 1]
                                      - self.model.hip_offsets[leg, 1], 0.0]) for leg in range(4)]
            self._yaw_frame = (self.start_yaw, Rz, _quat_from_R(Rz), Rz @ self.model.com_offset,
                               lateral)
        return self._yaw_frame[1:]

    def _foothold(self, leg: int, t_td: float, t: float, base_link: np.ndarray, Rb: np.ndarray,
                  vel: np.ndarray) -> np.ndarray:
        """World foothold of the stance that starts at t_td (Raibert heuristic, hip moving at v_des)."""
        hip = base_link + Rb @ self.model.hip_offsets[leg]
        lateral = self._start_frame()[3][leg]
        dt_ahead = max(0.0, t_td - t)
        p = hip + lateral + self.v_des * dt_ahead + vel * (0.5 * self.gait.stance_time) \
            + self.spec.raibert_gain * (vel - self.v_des)
        p[2] = self.world.ground_height(p[0], p[1]) + self.spec.foot_radius
        return p

    def _feet_plan(self, t: float, feet_now: np.ndarray, contact_now: np.ndarray,
                   base_link: np.ndarray, Rb: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """(H + 1, 4, 3) foot references at knots t + k·dt (stance: contact point; swing: curve)."""
        H, dt = self.HORIZON, self.KNOT_DT
        g = self.gait
        per, duty = g.period, g.duty
        out = np.empty((H + 1, 4, 3))
        eps = 1e-6
        vel_h = np.array([vel[0], vel[1], 0.0])
        for leg in range(4):
            off = g.offsets[leg]
            n_now = math.floor((t + eps) / per + off)
            cache: dict[int, np.ndarray] = {}

            def stance_pos(n: int) -> np.ndarray:
                if n == n_now and contact_now[leg]:
                    return feet_now[leg]
                if n not in cache:
                    cache[n] = self._foothold(leg, (n - off) * per, t, base_link, Rb, vel_h)
                return cache[n]

            for k in range(H + 1):
                tk = t + k * dt + eps
                ph = tk / per + off
                n = math.floor(ph)
                phi = ph - n
                if phi < duty:
                    out[k, leg] = stance_pos(n)
                else:
                    start = self.liftoff[leg] if (n == n_now and not contact_now[leg]) else stance_pos(n)
                    end = stance_pos(n + 1)
                    s = (phi - duty) / (1.0 - duty)
                    out[k, leg] = _swing_point(start, end, s, g.params.step_height)
        return out

    # ------------------------------------------------------------------ replanning
    def _replan(self, t: float, s: RobotState) -> None:
        t0 = time.perf_counter()
        H, dt, m = self.HORIZON, self.KNOT_DT, self.mass
        Rb = s.R
        base_link = s.pos - Rb @ self.world.base_com_local
        x0 = self.ddp.state_vector(base_link, Rb, s.vel + np.cross(s.omega, base_link - s.pos),
                                   s.omega, s.q, s.dq)
        com, lmom, amom = self.ddp.centroidal(x0)
        feet_now = self.ddp.feet()
        contact_now = self.gait.contact(t + 1e-6)
        if self.liftoff is None:
            self.liftoff = feet_now.copy()
        feet = self._feet_plan(t, feet_now, contact_now, base_link, Rb, s.vel)
        # contact per knot interval: stance at the interval's midpoint
        table = self.gait.contact_table(t + 0.5 * dt, dt, H)
        Rz, quat, com_off_w, _ = self._start_frame()
        I_w = Rb @ self.model.inertia @ Rb.T
        # references (knots 1..H)
        tk = np.arange(1, H + 1)[:, None] * dt
        ground = self.world.ground_height(com[0], com[1])
        z_ref = ground + self.spec.nominal_height + self.model.com_offset[2]
        x_ref = np.zeros((H, 9))
        x_ref[:, 0:2] = com[:2] + self.v_des[:2] * tk
        x_ref[:, 2] = z_ref
        x_ref[:, 3:6] = self.v_des
        rpy = s.rpy
        err = np.array([rpy[0], rpy[1], (rpy[2] - self.start_yaw + math.pi) % (2 * math.pi) - math.pi])
        omega_ref = -self.ORI_GAIN * err
        x_ref[:, 6:9] = (I_w @ omega_ref) / m
        xc0 = np.concatenate([com, lmom / m, amom / m])
        t1 = time.perf_counter()
        c_guess = None
        if self.c_guess is not None:
            c_guess = self.c_guess + (com - self.c_guess[0])
        X, U = self.planner.plan(xc0, table, feet[:H], x_ref, self.w_x, self.w_x_ter, self.w_f,
                                 c_guess)
        t2 = time.perf_counter()
        # warm start of the next solve: this plan shifted by one knot
        self.c_guess = np.vstack([X[1:H, 0:3], X[H:H + 1, 0:3] + X[H, 3:6] * dt])
        # whole-body references (knots 0..H)
        I_w_inv = np.linalg.inv(I_w)
        vel_ref = np.zeros((H + 1, 6))
        vel_ref[:, 0:3] = X[:, 3:6]
        vel_ref[:, 3:6] = (X[:, 6:9] * m) @ I_w_inv.T
        xr = np.zeros((H + 1, self.nq + self.ddp.nv))
        xr[:, :self.nq] = self.ddp.q_nom
        xr[:, 0:3] = X[:, 0:3] - com_off_w
        xr[:, 3:7] = quat
        for k in range(H + 1):
            xr[k, self.nq:self.nq + 3] = Rz.T @ X[k, 3:6]
            xr[k, self.nq + 3:self.nq + 6] = Rz.T @ vel_ref[k, 3:6]
        try:
            xs, _ = self.ddp.solve(x0, xr, X[:, 0:3], vel_ref, feet)
        except (RuntimeError, ValueError) as exc:   # crocoddyl/pinocchio errors on a bad state
            raise ActorFailure(f"whole-body DDP failed ({str(exc).splitlines()[0] if str(exc) else exc})") from None
        t3 = time.perf_counter()
        if not np.all(np.isfinite(xs)):
            raise ActorFailure("whole-body DDP diverged")
        self.xs = xs
        self._q_a = xs[0][self.qi].copy()
        self._q_d = xs[1][self.qi] - self._q_a
        self._v_a = xs[0][self.nq + self.vi].copy()
        self._v_d = xs[1][self.nq + self.vi] - self._v_a
        self._ff_contact = None
        for i in range(4):   # a stance foot stays where it is: its next swing starts here
            if contact_now[i]:
                self.liftoff[i] = feet_now[i]
        self.forces[0] = U[0].reshape(4, 3) * (m * G)
        self.forces[1] = U[1].reshape(4, 3) * (m * G)
        self.knot_contact = table[:2].copy()
        self.timing["centroidal"] += t2 - t1
        self.timing["ddp"] += t3 - t2
        self.timing["replan"] += t3 - t0
        self.n_replan += 1

    # ------------------------------------------------------------------ control
    def _contact(self, t: float) -> tuple[bool, bool, bool, bool]:
        """Scheduled stance per leg at t (python floats: cheaper than numpy at 1 kHz). A small
        epsilon puts phase boundaries that coincide with replanning instants on the new phase."""
        g = self.gait
        x = (t + 1e-6) / g.period
        return tuple(((x + o) % 1.0) < g.duty for o in self._offsets)

    def control(self, step: int, s: RobotState) -> np.ndarray:
        t = step * self.dt
        if self.start_yaw is None:
            self.start_yaw = float(s.rpy[2])
        k = step - self.replan_step
        if step % self.REPLAN_EVERY == 0 or self.xs is None:
            self.replan_step, k = step, 0
            self._replan(t, s)
        tc = time.perf_counter()
        contact = self._step_contacts(step)
        if contact != self._ff_contact or k % self.FF_EVERY == 0:
            # feed-forward τ = −Jᵀ Rᵀ f of the stance legs, Jacobians refreshed every FF_EVERY steps
            _, J = self.legs.update(s.q)
            RbT = s.R.T
            ff = np.zeros(12)
            kk = 0 if k * self.dt < self.KNOT_DT else 1
            for i in range(4):
                if not contact[i]:
                    continue
                if self.knot_contact[kk, i]:
                    f = self.forces[kk, i]
                elif self.knot_contact[1, i]:
                    f = self.forces[1, i]
                else:
                    continue
                ff[3 * i:3 * i + 3] = -J[i].T @ (RbT @ f)
            self._ff, self._ff_contact = ff, contact
        a = k * self.dt / self.KNOT_DT
        tau = self.kp * (self._q_a + a * self._q_d - s.q) + self.kd * (self._v_a + a * self._v_d - s.dq) + self._ff
        self.timing["control"] += time.perf_counter() - tc
        self.n_control += 1
        return np.minimum(np.maximum(tau, self._tau_lo), self.tau_lim)


def _swing_point(p0: np.ndarray, p1: np.ndarray, s: float, height: float) -> np.ndarray:
    """Swing foot position at progress s ∈ [0, 1]: minimum-jerk blend p0 → p1 plus a
    ``height · sin²(π s)`` bump (the same curve as :func:`latentune.actor.legs.swing_trajectory`)."""
    s = min(max(s, 0.0), 1.0)
    b = s * s * s * (10 - 15 * s + 6 * s * s)
    (a0, a1, a2), (c0, c1, c2) = p0.tolist(), p1.tolist()   # floats: cheaper than (3,) arrays
    sn = math.sin(math.pi * s)
    return np.array([a0 + (c0 - a0) * b, a1 + (c1 - a1) * b, a2 + (c2 - a2) * b + height * sn * sn])


def _quat_from_R(R: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    return pin.Quaternion(R).coeffs().copy()
