"""Convex MPC (Di Carlo et al. 2018): single-rigid-body model, ground-reaction forces by a QP.

State x (13): roll, pitch, yaw, x, y, z, ωx, ωy, ωz (world), vx, vy, vz, g. Input: the ground's
force on each stance foot, expressed as u = f / (m·g) (dimensionless, so the force weights R
mean the same thing on a 12 kg A1 and a 55 kg B1). Dynamics are linearized about the current yaw:

    Θ̇ ≈ Rz(ψ)ᵀ ω,   ṗ = v,   ω̇ = I_w⁻¹ Σ r_i × f_i,   v̇ = Σ f_i / m + g ê_z.

Over a horizon of ``HORIZON`` steps of ``MPC_DT`` seconds the state is condensed into
X = A_qp x0 + B_qp U and the QP

    min_U  ½ (X − X_ref)ᵀ L (X − X_ref) + ½ Uᵀ K U
    s.t.   0 ≤ f_z ≤ f_max,  |f_x|, |f_y| ≤ μ f_z  (only for (step, leg) pairs in stance)

is solved with DAQP (dense active-set; OSQP optional), L = diag(Q, …, Q), K = diag(R, …, R).
θ = (Q (13), R (12)): the paper's 25 weights. Stance torques τ = −Jᵀ Rᵀ f (f acts on the robot,
the leg pushes the ground with −f); swing legs follow a Raibert foothold with joint PD.
"""
from __future__ import annotations

import math

import numpy as np

from latentune.actor.base import Actor, ActorFailure
from latentune.actor.gait import GaitScheduler
from latentune.actor.legs import LegKinematics, swing_trajectory
from latentune.actor.parameter_space import ParameterSpace, make_space
from latentune.robots import LEGS, RobotSpec
from latentune.sim.world import RobotState, World

STATE_NAMES = ("roll", "pitch", "yaw", "x", "y", "z", "wx", "wy", "wz", "vx", "vy", "vz", "g")
FORCE_NAMES = tuple(f"{leg}_f{ax}" for leg in LEGS for ax in "xyz")
G = 9.81

# Manual-tuned weights (found by hand, checked by tests/test_actor.py and benchmarks/actor.py).
_Q_MANUAL = {
    "trot": (20.0, 20.0, 0.2, 1e-3, 1e-3, 10.0, 0.5, 0.5, 0.2, 1.0, 1.0, 0.1, 1e-3),
    "jump": (20.0, 20.0, 0.2, 1e-3, 1e-3, 10.0, 0.5, 0.5, 0.2, 1.0, 1.0, 0.1, 1e-3),
}
_R_MANUAL = {"trot": 1e-2, "jump": 1e-2}


class ConvexMPC(Actor):
    """Convex MPC actor. θ (physical) = Q (13 state weights) ‖ R (12 normalized-force weights)."""

    name = "convex"
    HORIZON = 10
    MPC_DT = 0.025       # [s] horizon step
    SOLVE_EVERY = 10     # physics steps between QP solves (10 ms at 1 kHz)
    KIN_EVERY = 5        # physics steps between kinematics/feed-forward refreshes (5 ms)
    FZ_MAX = 2.5         # per-foot normal force bound, in units of m·g (= 10·m·g/4)

    @classmethod
    def space(cls, spec: RobotSpec, gait: str) -> ParameterSpace:
        q_man = _Q_MANUAL.get(gait, _Q_MANUAL["trot"])
        r_man = _R_MANUAL.get(gait, _R_MANUAL["trot"])
        rows = [(f"Q_{n}", 1e-3, 1e2, True, q) for n, q in zip(STATE_NAMES, q_man)]
        rows += [(f"R_{n}", 1e-4, 1e1, True, r_man) for n in FORCE_NAMES]
        return make_space(rows)

    def __init__(self, world: World, gait: str, v_des: np.ndarray, theta: np.ndarray,
                 solver: str = "daqp"):
        spec = world.spec
        self.world = world
        self.spec = spec
        self.model = world.model
        self.legs = LegKinematics(world.model)
        self.gait = GaitScheduler(spec.gait(gait))
        self.v_des = np.asarray(v_des, dtype=float)
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (25,):
            raise ValueError(f"convex MPC needs 25 weights, got {theta.shape}")
        self.Q = theta[:13].copy()
        self.R = theta[13:].copy()
        self.mass = world.model.mass
        self.inertia_b = world.model.inertia
        self.dt = world.dt
        self.mu = spec.mu
        self.solver = solver
        self.kp = np.tile(spec.kp, 4)
        self.kd = np.tile(spec.kd, 4)
        self.tau_lim = np.tile(spec.torque_limits, 4)
        self.forces = np.zeros((4, 3))            # world-frame ground forces on the feet [N]
        self.swing_start = np.zeros((4, 3))       # world-frame foot position at lift-off
        self.prev_contact = np.ones(4, dtype=bool)
        self.L_diag = np.tile(self.Q, self.HORIZON)
        self.solve_count = 0
        self.solve_fail = 0
        self.start_yaw = None
        self._contact = np.ones(4, dtype=bool)
        self._kk, self._jj = np.tril_indices(self.HORIZON)

    # ------------------------------------------------------------------ MPC
    def _solve_mpc(self, t: float, s: RobotState, com: np.ndarray, feet_w: np.ndarray,
                   ground_z: float) -> np.ndarray:
        """Returns (4, 3) world-frame ground forces for the current step [N]."""
        H, dt, m = self.HORIZON, self.MPC_DT, self.mass
        table = self.gait.contact_table(t, dt, H)            # (H, 4)
        if not table.any():
            return np.zeros((4, 3))
        rpy = s.rpy
        yaw = rpy[2]
        cy, sy = math.cos(yaw), math.sin(yaw)
        Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        I_w_inv = np.linalg.inv(Rz @ self.inertia_b @ Rz.T)
        x0 = np.concatenate([rpy, com, s.omega, s.vel, [-G]])
        A = np.eye(13)
        A[0:3, 6:9] = Rz.T * dt
        A[3:6, 9:12] = np.eye(3) * dt
        A[11, 12] = dt
        Bc = np.zeros((13, 12))
        mg = m * G
        for i in range(4):
            r = feet_w[i] - com
            rx = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
            Bc[6:9, 3 * i:3 * i + 3] = I_w_inv @ rx * mg
            Bc[9:12, 3 * i:3 * i + 3] = np.eye(3) * G
        B = (0.5 * (np.eye(13) + A)) @ Bc * dt  # (I + A_c dt / 2) B_c dt: 2nd-order hold
        # powers
        Apow = [np.eye(13)]
        for _ in range(H):
            Apow.append(A @ Apow[-1])
        P = [Apow[k] @ B for k in range(H)]                   # Ad^k B
        Aqp = np.vstack(Apow[1:])                             # (13H, 13)
        active = table.reshape(-1)                            # (4H,) per (step, leg)
        cols = np.flatnonzero(np.repeat(active, 3))           # force variable columns
        Pst = np.stack(P)                                     # (H, 13, 12)
        blocks = np.zeros((H, H, 13, 12))
        blocks[self._kk, self._jj] = Pst[self._kk - self._jj]  # block (k, j) = Ad^(k−j) B, j ≤ k
        Bqp = blocks.transpose(0, 2, 1, 3).reshape(13 * H, 12 * H)
        Bc_qp = Bqp[:, cols]
        # reference trajectory
        steps = np.arange(1, H + 1) * dt
        Xref = np.zeros((H, 13))
        Xref[:, 2] = self.start_yaw
        Xref[:, 3] = com[0] + self.v_des[0] * steps
        Xref[:, 4] = com[1] + self.v_des[1] * steps
        Xref[:, 5] = ground_z + self.spec.nominal_height + self.model.com_offset[2]
        Xref[:, 9:12] = self.v_des
        Xref[:, 12] = -G
        err0 = Aqp @ x0 - Xref.reshape(-1)
        LB = Bc_qp * self.L_diag[:, None]
        Hm = Bc_qp.T @ LB
        n = cols.size
        Rvec = np.tile(self.R, H)[cols]
        Hm[np.diag_indices(n)] += Rvec + 1e-9
        g = LB.T @ err0
        # constraints: simple bounds then friction pyramid rows
        nc = n // 3
        mu = self.mu
        lb = np.tile([-mu * self.FZ_MAX, -mu * self.FZ_MAX, 0.0], nc)
        ub = np.tile([mu * self.FZ_MAX, mu * self.FZ_MAX, self.FZ_MAX], nc)
        Acon = np.zeros((4 * nc, n))
        r = np.arange(nc)
        for a in range(2):  # x and y
            Acon[4 * r + 2 * a, 3 * r + a] = 1.0
            Acon[4 * r + 2 * a, 3 * r + 2] = -mu
            Acon[4 * r + 2 * a + 1, 3 * r + a] = 1.0
            Acon[4 * r + 2 * a + 1, 3 * r + 2] = mu
        cu = np.tile([0.0, np.inf, 0.0, np.inf], nc)
        cl = np.tile([-np.inf, 0.0, -np.inf, 0.0], nc)
        u = self._qp(Hm, g, Acon, np.concatenate([lb, cl]), np.concatenate([ub, cu]))
        # first horizon step's forces
        first = table[0]
        f = np.zeros((4, 3))
        k = 0
        for i in range(4):
            if first[i]:
                f[i] = u[3 * k:3 * k + 3] * mg
                k += 1
        return f

    def _qp(self, Hm: np.ndarray, g: np.ndarray, A: np.ndarray, lo: np.ndarray,
            hi: np.ndarray) -> np.ndarray:
        if not (np.all(np.isfinite(Hm)) and np.all(np.isfinite(g))):
            raise ActorFailure("non-finite MPC problem")
        n = Hm.shape[0]
        if self.solver == "daqp":
            import daqp

            sense = np.zeros(lo.size, dtype=np.int32)
            hi_c = np.where(np.isinf(hi), 1e30, hi)
            lo_c = np.where(np.isinf(lo), -1e30, lo)
            x, _, flag, _ = daqp.solve(Hm, g, A, hi_c, lo_c, sense)
            if flag < 1 or not np.all(np.isfinite(x)):
                raise ActorFailure(f"MPC QP failed (daqp exit {flag})")
            return np.asarray(x)
        import osqp
        import scipy.sparse as sp

        Afull = sp.csc_matrix(np.vstack([np.eye(n), A]))
        prob = osqp.OSQP()
        prob.setup(sp.csc_matrix(np.triu(Hm)), g, Afull, lo, hi, verbose=False,
                   eps_abs=1e-5, eps_rel=1e-5, polishing=True)
        res = prob.solve()
        if res.info.status_val not in (1, 2) or not np.all(np.isfinite(res.x)):
            raise ActorFailure(f"MPC QP failed (osqp {res.info.status})")
        return res.x

    # ------------------------------------------------------------------ control
    def control(self, step: int, s: RobotState) -> np.ndarray:
        """Two rates: every ``KIN_EVERY`` steps (and whenever the contact pattern changes) the
        kinematics, leg gravity, stance torques and swing joint references are refreshed; every
        step only the swing legs' joint PD runs on the current joint state."""
        t = step * self.dt
        contact = self.gait.contact(t)
        if (step % self.KIN_EVERY == 0 or step % self.SOLVE_EVERY == 0
                or not np.array_equal(contact, self._contact)):
            self._refresh(step, t, s, contact)
        dt_ref = t - self._t_ref
        pd = self.kp * (self._q_ref + self._dq_ref * dt_ref - s.q) + self.kd * (self._dq_ref - s.dq)
        tau = self._tau_ff + self._swing_mask * pd
        return np.clip(tau, -self.tau_lim, self.tau_lim)

    def _refresh(self, step: int, t: float, s: RobotState, contact: np.ndarray) -> None:
        Rb = s.R
        if self.start_yaw is None:
            self.start_yaw = float(s.rpy[2])
            self._lateral_b = np.zeros((4, 3))
            self._lateral_b[:, 1] = self.model.foot_stance[:, 1] - self.model.hip_offsets[:, 1]
        base_link = s.pos - Rb @ self.world.base_com_local
        feet_b, J = self.legs.update(s.q)
        feet_w = base_link + feet_b @ Rb.T
        if step % self.SOLVE_EVERY == 0:
            com = base_link + Rb @ self.model.com_offset
            ground_z = self.world.ground_height(com[0], com[1])
            self.forces = self._solve_mpc(t, s, com, feet_w, ground_z)
            self.solve_count += 1
        tau = self.legs.gravity(s.q, Rb)      # hold the legs' own weight, (12,)
        # stance legs: τ = −Jᵀ Rᵀ f   (f: the ground's force on the robot, world frame)
        f_b = self.forces @ Rb                # rows are Rᵀ f_k
        tau_st = -np.einsum("kji,kj->ki", J, f_b).reshape(-1)
        st = np.repeat(contact, 3)
        tau[st] += tau_st[st]
        self._tau_ff = tau
        self._contact = contact
        self._t_ref = t
        swing = ~contact
        lift = swing & self.prev_contact
        self.swing_start[lift] = feet_w[lift]
        self.prev_contact = contact
        self._swing_mask = (~st).astype(float)
        self._q_ref = s.q.copy()
        self._dq_ref = np.zeros(12)
        if not swing.any():
            return
        sw = np.flatnonzero(swing)
        v_body = s.vel
        # Raibert foothold: under the hip (at the stance width), half a stance ahead,
        # corrected by the velocity error
        hips = base_link + (self.model.hip_offsets[sw] + self._lateral_b[sw]) @ Rb.T
        target = hips + v_body * (0.5 * self.gait.stance_time) \
            + self.spec.raibert_gain * (v_body - self.v_des)
        for j in range(sw.size):
            target[j, 2] = self.world.ground_height(target[j, 0], target[j, 1]) + self.spec.foot_radius
        progress = self.gait.swing_progress(t)[sw]
        p_des, v_des = swing_trajectory(self.swing_start[sw], target, progress,
                                        self.gait.params.step_height, self.gait.swing_time)
        # desired foot position/velocity relative to the base, in the base frame
        w = s.omega
        skew_w = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
        w_x_r = (feet_w[sw] - base_link) @ skew_w.T       # rows ω × r
        rhs = np.empty((sw.size, 3, 2))
        rhs[:, :, 0] = (p_des - base_link) @ Rb - feet_b[sw]     # position error, base frame
        rhs[:, :, 1] = (v_des - v_body - w_x_r) @ Rb              # velocity relative to base
        try:
            sol = np.linalg.solve(J[sw], rhs)                      # J⁻¹ [e_p, v]: one IK step
        except np.linalg.LinAlgError:
            sol = np.linalg.pinv(J[sw]) @ rhs
        idx = (3 * sw[:, None] + np.arange(3)).reshape(-1)
        self._q_ref[idx] += sol[:, :, 0].reshape(-1)
        self._dq_ref[idx] = sol[:, :, 1].reshape(-1)
