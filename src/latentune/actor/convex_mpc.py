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
The reference moves forward at v_des from the current position; its height starts at the current
height and returns to the standing height with time constant ``TAU_Z``, with v_z,ref its time
derivative (a self-consistent reference, as for x and y); roll and pitch likewise return to level.
θ = (Q (13), R (12)): the paper's 25 weights. Stance torques τ = −Jᵀ Rᵀ f (f acts on the robot,
the leg pushes the ground with −f); swing legs follow a Raibert foothold with joint PD.
"""
from __future__ import annotations

import math

import numpy as np

from latentune.actor.base import Actor, ActorFailure, friction_pyramid
from latentune.actor.gait import GaitScheduler, StepContacts
from latentune.actor.legs import LegKinematics, swing_trajectory
from latentune.constants import G
from latentune.robots import LEGS, RobotSpec
from latentune.space import ParameterSpace, make_space
from latentune.sim.world import RobotState, World

STATE_NAMES = ("roll", "pitch", "yaw", "x", "y", "z", "wx", "wy", "wz", "vx", "vy", "vz", "g")
FORCE_NAMES = tuple(f"{leg}_f{ax}" for leg in LEGS for ax in "xyz")

# Manual-tuned weights (found by hand, checked by tests/test_actor.py and benchmarks.actor).
_Q_MANUAL = {
    "trot": (20.0, 20.0, 0.2, 1e-3, 1e-3, 10.0, 0.5, 0.5, 0.2, 1.0, 1.0, 0.1, 1e-3),
    "jump": (20.0, 20.0, 0.2, 1e-3, 1e-3, 10.0, 0.5, 0.5, 0.2, 1.0, 1.0, 0.1, 1e-3),
}
_R_MANUAL = {"trot": 1e-2, "jump": 1e-2}


_STRUCTURES: dict[tuple, tuple] = {}   # ConvexMPC._horizon_pattern's actor-independent part


class ConvexMPC(Actor):
    """Convex MPC actor. θ (physical) = Q (13 state weights) ‖ R (12 normalized-force weights)."""

    name = "convex"
    HORIZON = 10
    MPC_DT = 0.025       # [s] horizon step
    SOLVE_EVERY = 10     # physics steps between QP solves (10 ms at 1 kHz)
    KIN_EVERY = 10       # physics steps between kinematics/feed-forward refreshes (10 ms)
    FZ_MAX = 2.5         # per-foot normal force bound, in units of m·g (= 10·m·g/4)
    TAU_Z = 0.1          # [s] time constant of the height/attitude reference's return to nominal

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
        self._inertia_inv_b = np.linalg.inv(self.inertia_b)
        self.dt = world.dt
        self.mu = spec.mu
        self.solver = solver
        self.kp = np.tile(spec.kp, 4)
        self.kd = np.tile(spec.kd, 4)
        self.tau_lim = np.tile(spec.torque_limits, 4)
        self.forces = np.zeros((4, 3))            # world-frame ground forces on the feet [N]
        self.swing_start = np.zeros((4, 3))       # world-frame foot position at lift-off
        self.prev_contact = np.ones(4, dtype=bool)
        self._tau_lo = -self.tau_lim
        self._step_contacts = StepContacts(self.gait, self.dt)  # stance per physics step
        self._patterns: dict[tuple[bool, ...], tuple] = {}
        self.L_diag = np.tile(self.Q, self.HORIZON)
        self.solve_count = 0
        self.solve_fail = 0
        self.start_yaw = None
        self._contact: tuple[bool, ...] = ()
        # MPC buffers and constants (reused every solve)
        H, dt = self.HORIZON, self.MPC_DT
        self._eye13 = np.eye(13)
        self._N = np.zeros((13, 13))
        self._N[3:6, 9:12] = np.eye(3) * dt
        self._N[11, 12] = dt
        ks = np.arange(H + 1, dtype=float)
        self._kpow, self._k2pow = ks, 0.5 * ks * (ks - 1.0)
        # N² = dt² at (z, g) whatever the yaw (the yaw block's products all meet zero rows), so
        # A^k = I + k N + k(k−1)/2 N² changes only in its yaw block [0:3, 6:9] from solve to
        # solve: _solve_mpc recomputes that block with the same elementwise expression
        self._N[0:3, 6:9] = np.eye(3) * dt
        self._k2N2 = self._k2pow[:, None, None] * (self._N @ self._N)
        self._Apow = self._eye13 + self._kpow[:, None, None] * self._N + self._k2N2
        self._kpow3 = self._kpow[:, None, None]
        self._x0 = np.empty(13)
        self._x0[12] = -G
        self._Bc = np.zeros((13, 12))
        self._Bc[9:12] = np.tile(np.eye(3), 4) * G
        self._Ppad = np.zeros((H + 1, 13, 12))
        self._pattern_cache: dict[bytes, tuple] = {}
        self._cols3 = np.arange(12 * H).reshape(4 * H, 3)
        self._tsteps = np.arange(1, H + 1) * dt
        self._ref_decay = np.exp(-self._tsteps / self.TAU_Z)  # (H,) height/attitude error decay
        self._Xref = np.zeros((H, 13))
        self._Xref[:, 9:12] = self.v_des
        self._Xref[:, 12] = -G
        self._vx_steps = self.v_des[0] * self._tsteps     # (H,) reference x, y advance [m]
        self._vy_steps = self.v_des[1] * self._tsteps
        self._L_col = self.L_diag[:, None]
        self._Rvec = np.tile(self.R, H) + 1e-9

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
        I_w_inv = Rz @ self._inertia_inv_b @ Rz.T               # world-frame inverse inertia
        x0 = self._x0                                         # (rpy, com, ω, v, −g)
        x0[0:3], x0[3:6], x0[6:9], x0[9:12] = rpy, com, s.omega, s.vel
        # A = I + N with N nilpotent (N³ = 0): A^k = I + k N + k(k−1)/2 N² (only the yaw block
        # of N, and so of A^k, depends on the state; see __init__)
        N = self._N
        N[0:3, 6:9] = Rz.T * dt
        Apow = self._Apow
        Apow[:, 0:3, 6:9] = (self._eye13[0:3, 6:9] + self._kpow3 * N[0:3, 6:9]
                             + self._k2N2[:, 0:3, 6:9])
        Bc = self._Bc
        mg = m * G
        r = feet_w - com                                      # (4, 3) lever arms
        rx = np.zeros((4, 3, 3))
        rx[:, 0, 1], rx[:, 0, 2] = -r[:, 2], r[:, 1]
        rx[:, 1, 0], rx[:, 1, 2] = r[:, 2], -r[:, 0]
        rx[:, 2, 0], rx[:, 2, 1] = -r[:, 1], r[:, 0]
        Bc[6:9] = (I_w_inv @ rx * mg).transpose(1, 0, 2).reshape(3, 12)
        B = (self._eye13 + 0.5 * (Apow[1] - self._eye13)) @ Bc * dt  # (I + A_c dt/2) B_c dt
        Ppad = self._Ppad
        np.matmul(Apow[:H], B, out=Ppad[:H])                  # (H, 13, 12): Ad^k B; Ppad[H] = 0
        Aqp = Apow[1:].reshape(13 * H, 13)
        cols, gather, Rvec, (Acon, lo, hi) = self._horizon_pattern(table)
        Bc_qp = Ppad.ravel().take(gather)                     # (13H, n): block (k, j) = Ad^(k−j) B
        # reference trajectory
        Xref = self._Xref
        Xref[:, 2] = self.start_yaw
        Xref[:, 3] = com[0] + self._vx_steps
        Xref[:, 4] = com[1] + self._vy_steps
        Xref[:, 5] = ground_z + self.spec.nominal_height + self.model.com_offset[2]
        # Height reference from the current height back to the standing height, v_z,ref = its
        # derivative. (A step to the standing height with v_z,ref = 0 contradicts itself: weights
        # with Q_vz >> Q_z, which a trot never penalises, then hold v_z ≈ 0 and never restore the
        # height lost in each flight/landing of a jump: the robot sinks every cycle and falls.)
        dz = (com[2] - Xref[0, 5]) * self._ref_decay
        Xref[:, 5] += dz
        Xref[:, 11] = self.v_des[2] - dz / self.TAU_Z
        # Roll and pitch likewise: from the current attitude back to level, ω_x,y,ref = its
        # derivative (small angles, yaw ≈ start yaw). With a step to level and ω_ref = 0 the
        # steady pitch error under a constant unmodelled moment scales like 1/Q_pitch.
        att = np.outer(self._ref_decay, rpy[:2])
        Xref[:, 0:2] = att
        Xref[:, 6:8] = -att / self.TAU_Z
        err0 = Aqp @ x0 - Xref.reshape(-1)
        LB = Bc_qp * self._L_col
        Hm = Bc_qp.T @ LB
        Hm.flat[::cols.size + 1] += Rvec                       # + K (force weights) on the diagonal
        g = LB.T @ err0
        u = self._qp(Hm, g, Acon, lo, hi)
        # first horizon step's forces
        first = table[0]
        f = np.zeros((4, 3))
        f[first] = u[:3 * int(first.sum())].reshape(-1, 3) * mg
        return f

    def _horizon_pattern(self, table: np.ndarray) -> tuple:
        """Per horizon contact table (H, 4) (cached; a periodic gait has few): the force
        variables' columns (n,), the gather index (13H, n) that builds the condensed input
        matrix from the padded powers Ad^k B, their force weights (n,) and the constraints."""
        key = table.tobytes()
        hit = self._pattern_cache.get(key)
        if hit is None:
            # the structure depends on the table, the horizon, μ and the force bound only: it
            # is shared by every actor of the process (read-only; DAQP does not write to it)
            skey = (key, self.HORIZON, self.mu, self.FZ_MAX)
            shared = _STRUCTURES.get(skey)
            if shared is None:
                H = self.HORIZON
                cols = self._cols3[table.reshape(-1)].reshape(-1)
                j = cols // 12                                # horizon step of each variable
                k = np.arange(H).repeat(13)                   # horizon step of each state row
                rr = np.tile(np.arange(13), H)
                d = k[:, None] - j[None, :]
                d = np.where(d >= 0, d, H)                    # k < j: the zero block Ppad[H]
                gather = (d * 13 + rr[:, None]) * 12 + (cols % 12)[None, :]
                cons = friction_pyramid(cols.size // 3, self.mu, self.FZ_MAX)
                shared = _STRUCTURES[skey] = (cols, gather, cons)
            cols, gather, cons = shared
            hit = self._pattern_cache[key] = (cols, gather, self._Rvec[cols], cons)
        return hit

    def _qp(self, Hm: np.ndarray, g: np.ndarray, A: np.ndarray, lo: np.ndarray,
            hi: np.ndarray) -> np.ndarray:
        if not (np.isfinite(Hm).all() and np.isfinite(g).all()):
            raise ActorFailure("non-finite MPC problem")
        n = Hm.shape[0]
        if self.solver == "daqp":
            import daqp

            sense = np.zeros(lo.size, dtype=np.int32)
            x, _, flag, _ = daqp.solve(Hm, g, A, hi, lo, sense)
            if flag < 1 or not np.isfinite(x).all():
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
        contact = self._step_contacts(step)
        if step % self.KIN_EVERY == 0 or step % self.SOLVE_EVERY == 0 or contact != self._contact:
            self._refresh(step, t, s, contact)
        if self._stance_only:
            return self._tau_ff
        dt_ref = t - self._t_ref
        tau = (self._kp_sw * (self._q_ref + self._dq_ref * dt_ref - s.q)
               + self._kd_sw * (self._dq_ref - s.dq) + self._tau_ff)
        return np.minimum(np.maximum(tau, self._tau_lo, out=tau), self.tau_lim, out=tau)

    def _pattern(self, contact: tuple[bool, ...]) -> tuple:
        """Per contact pattern (cached): stance mask (12,), swing legs, their joint indices and
        the swing-only PD gains."""
        hit = self._patterns.get(contact)
        if hit is None:
            c = np.array(contact, dtype=bool)
            st = np.repeat(c, 3)
            sw = np.flatnonzero(~c)
            idx = (3 * sw[:, None] + np.arange(3)).reshape(-1)
            hit = (c, st.astype(float), sw, idx, self.kp * ~st, self.kd * ~st, {})
            self._patterns[contact] = hit
        return hit

    def _refresh(self, step: int, t: float, s: RobotState, contact_key: tuple[bool, ...]) -> None:
        contact, st_f, sw, idx, self._kp_sw, self._kd_sw, memo = self._pattern(contact_key)
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
        tau -= (J * f_b[:, :, None]).sum(axis=1).reshape(-1) * st_f
        self._contact = contact_key
        self._t_ref = t
        swing = ~contact
        lift = swing & self.prev_contact
        self.swing_start[lift] = feet_w[lift]
        self.prev_contact = contact
        self._stance_only = sw.size == 0
        if self._stance_only:
            self._tau_ff = np.minimum(np.maximum(tau, self._tau_lo), self.tau_lim)
            return
        self._tau_ff = tau
        self._q_ref = s.q.copy()
        self._dq_ref = np.zeros(12)
        v_body = s.vel
        # Raibert foothold: under the hip (at the stance width), half a stance ahead,
        # corrected by the velocity error
        hip_b = memo.get("hip_b")   # the swing hips at the stance width, base frame
        if hip_b is None:
            hip_b = memo["hip_b"] = self.model.hip_offsets[sw] + self._lateral_b[sw]
        hips = base_link + hip_b @ Rb.T
        target = hips + v_body * (0.5 * self.gait.stance_time) \
            + self.spec.raibert_gain * (v_body - self.v_des)
        if self.world.terrain == "flat":
            target[:, 2] = self.spec.foot_radius
        else:
            for j in range(sw.size):
                target[j, 2] = (self.world.ground_height(target[j, 0], target[j, 1])
                                + self.spec.foot_radius)
        progress = self.gait.swing_progress(t)[sw]
        p_des, v_des = swing_trajectory(self.swing_start[sw], target, progress,
                                        self.gait.params.step_height, self.gait.swing_time)
        # desired foot position/velocity relative to the base, in the base frame
        wx, wy, wz = s.omega.tolist()
        skew_w = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
        w_x_r = (feet_w[sw] - base_link) @ skew_w.T       # rows ω × r
        rhs = np.empty((sw.size, 3, 2))
        rhs[:, :, 0] = (p_des - base_link) @ Rb - feet_b[sw]     # position error, base frame
        rhs[:, :, 1] = (v_des - v_body - w_x_r) @ Rb              # velocity relative to base
        try:
            sol = np.linalg.solve(J[sw], rhs)                      # J⁻¹ [e_p, v]: one IK step
        except np.linalg.LinAlgError:
            sol = np.linalg.pinv(J[sw]) @ rhs
        self._q_ref[idx] += sol[:, :, 0].reshape(-1)
        self._dq_ref[idx] = sol[:, :, 1].reshape(-1)
