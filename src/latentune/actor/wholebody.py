"""Whole-body kinematic DDP of the kino-dynamic MPC (crocoddyl FDDP on a free-flyer pinocchio model).

As in BiConMP's inverse-kinematics stage the whole body is modelled as *fully actuated* (free
forward dynamics with ``ActuationModelFull``: the base gets a virtual 6-D wrench), and the DDP
finds joint and base trajectories over the horizon that track

* the centroidal plan — CoM position and momentum (``cent_wt``, 9 weights);
* the feet — stance feet held at their contact points, swing feet along the swing curve;
* a regularization of the state toward the nominal stance moving with the plan (``state_wt``, 36
  weights on the tangent-space state error: base position, base orientation, 12 joints, base
  linear and angular velocity, 12 joint velocities), and of the control toward gravity
  compensation.

Momentum and CoM residuals. crocoddyl's ``ResidualModelCentroidalMomentum`` and
``ResidualModelCoMPosition`` read pinocchio quantities that ``DifferentialActionModelFreeFwdDynamics``
does not compute in ``calc`` (the residuals stay zero there), so the centroidal terms
act on an operational frame fixed to the base at the nominal whole-body CoM: its position tracks
the planned CoM, its spatial velocity (local-world-aligned) tracks the planned l/m and the angular
velocity I⁻¹k of the plan (composite-rigid-body approximation of the momentum; the weights on the
angular part are scaled by (I_ii/m)² so ``cent_wt`` weighs k/m errors as the planner's W_X does).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

try:  # the actor module turns a missing crocoddyl into ImportError at construction
    import crocoddyl
except ImportError:  # pragma: no cover - depends on the environment
    crocoddyl = None

from latentune.robots import RobotModel

# Fixed (not tuned) cost weights, after BiConMP's Solo12 trot configuration.
STATE_REG = 5e-2        # reg_wt[0]: scale of the state regularization cost
CTRL_REG = 1e-5         # reg_wt[1]: scale of the control regularization cost
FOOT_WT = 1e4           # swing_wt: stance and swing foot tracking
CTRL_WT = np.array([1.0, 1.0, 1000.0, 500.0, 500.0, 500.0] + [1.0] * 12)


class WholeBodyDDP:
    """Kinematic whole-body DDP over ``horizon`` knots of ``dt`` seconds.

    Args:
        model: the :class:`RobotModel` (its prepared URDF is reloaded with a free-flyer root).
        dt, horizon: knot duration [s] and count.
        state_wt: (36,) state weights; cent_wt: (9,) centroidal weights (com xyz, l/m xyz, k/m xyz).
        max_iter: FDDP iterations per solve.
    """

    def __init__(self, model: RobotModel, dt: float, horizon: int, state_wt: np.ndarray,
                 cent_wt: np.ndarray, max_iter: int = 5):
        if crocoddyl is None:
            raise ImportError("crocoddyl is required for the kino-dynamic MPC actor")
        spec = model.spec
        self.rmodel = pin.buildModelFromUrdf(model.urdf, pin.JointModelFreeFlyer())
        rm = self.rmodel
        root = rm.getJointId("root_joint")
        self.com_fid = rm.addFrame(pin.Frame("latentune_com", root, 0,
                                             pin.SE3(np.eye(3), np.asarray(model.com_offset, float)),
                                             pin.FrameType.OP_FRAME))
        self.rdata = rm.createData()
        self.foot_fids = [rm.getFrameId(f) for f in spec.foot_links]
        jids = [rm.getJointId(j) for j in spec.joint_names]
        self.qi = np.array([rm.joints[j].idx_q for j in jids])     # our joint order -> q index
        self.vi = np.array([rm.joints[j].idx_v for j in jids])
        self.nq, self.nv = rm.nq, rm.nv
        self.dt, self.H = dt, horizon
        self.max_iter = max_iter
        self.mass = float(model.mass)
        self.q_nom = pin.neutral(rm)
        self.q_nom[self.qi] = spec.nominal_q
        self.state = crocoddyl.StateMultibody(rm)
        self.actuation = crocoddyl.ActuationModelFull(self.state)
        nu = self.actuation.nu
        # control reference: gravity compensation at the nominal stance
        self.u_ref = pin.rnea(rm, self.rdata, self.q_nom, np.zeros(self.nv), np.zeros(self.nv)).copy()
        inertia_ratio = np.diag(model.inertia) / self.mass          # I_ii / m [m²]
        w_state = np.asarray(state_wt, float)
        w_cent = np.asarray(cent_wt, float)
        w_mom = np.concatenate([w_cent[3:6], w_cent[6:9] * inertia_ratio ** 2])
        x_nom = np.concatenate([self.q_nom, np.zeros(self.nv)])
        self.models = []
        for k in range(horizon + 1):
            costs = crocoddyl.CostModelSum(self.state, nu)
            costs.addCost("state", crocoddyl.CostModelResidual(
                self.state, crocoddyl.ActivationModelWeightedQuad(w_state),
                crocoddyl.ResidualModelState(self.state, x_nom, nu)), STATE_REG)
            if k < horizon:
                costs.addCost("ctrl", crocoddyl.CostModelResidual(
                    self.state, crocoddyl.ActivationModelWeightedQuad(CTRL_WT),
                    crocoddyl.ResidualModelControl(self.state, self.u_ref)), CTRL_REG)
            costs.addCost("com", crocoddyl.CostModelResidual(
                self.state, crocoddyl.ActivationModelWeightedQuad(w_cent[0:3]),
                crocoddyl.ResidualModelFrameTranslation(self.state, self.com_fid, np.zeros(3), nu)), 1.0)
            costs.addCost("mom", crocoddyl.CostModelResidual(
                self.state, crocoddyl.ActivationModelWeightedQuad(w_mom),
                crocoddyl.ResidualModelFrameVelocity(self.state, self.com_fid, pin.Motion.Zero(),
                                                     pin.LOCAL_WORLD_ALIGNED, nu)), 1.0)
            for i, fid in enumerate(self.foot_fids):
                costs.addCost(f"foot{i}", crocoddyl.CostModelResidual(
                    self.state, crocoddyl.ResidualModelFrameTranslation(self.state, fid, np.zeros(3), nu)),
                    FOOT_WT)
            dam = crocoddyl.DifferentialActionModelFreeFwdDynamics(self.state, self.actuation, costs)
            self.models.append(crocoddyl.IntegratedActionModelEuler(dam, dt if k < horizon else 0.0))
        self.costs = [m.differential.costs.costs for m in self.models]
        # per knot: the residuals whose references solve() sets (state, com, mom, 4 feet)
        self._residuals = [(c["state"].cost.residual, c["com"].cost.residual,
                            c["mom"].cost.residual, [c[f"foot{i}"].cost.residual for i in range(4)])
                           for c in self.costs]
        x0 = x_nom.copy()
        self.problem = crocoddyl.ShootingProblem(x0, self.models[:-1], self.models[-1])
        try:  # one thread per rollout, as for BLAS (latentune.threads): rollouts run one per core
            self.problem.nthreads = 1
        except AttributeError:  # pragma: no cover - crocoddyl built without multithreading
            pass
        self.solver = crocoddyl.SolverFDDP(self.problem)
        self.solver.th_stop = 1e-4   # stop early once warm-started iterations have converged
        self.xs = None
        self.us = None
        self.last_iter = 0

    # ------------------------------------------------------------------ helpers
    def state_vector(self, base_pos: np.ndarray, R: np.ndarray, vel_w: np.ndarray,
                     omega_w: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Pinocchio state x = (q (nq), v (nv)) from the measured base link pose/twist (world) and
        joints in our order. Free-flyer velocities are expressed in the base frame."""
        x = np.zeros(self.nq + self.nv)
        x[0:3] = base_pos
        x[3:7] = pin.Quaternion(R).coeffs()
        x[self.qi] = q
        x[self.nq:self.nq + 3] = R.T @ vel_w
        x[self.nq + 3:self.nq + 6] = R.T @ omega_w
        x[self.nq + self.vi] = dq
        return x

    def centroidal(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whole-body CoM [m], linear and angular momentum about the CoM (world) of state x."""
        q, v = x[:self.nq], x[self.nq:]
        h = pin.computeCentroidalMomentum(self.rmodel, self.rdata, q, v)
        return self.rdata.com[0].copy(), h.linear.copy(), h.angular.copy()

    def feet(self) -> np.ndarray:
        """(4, 3) world foot positions of the last state given to :meth:`centroidal`/`kinematics`."""
        pin.updateFramePlacements(self.rmodel, self.rdata)
        return np.array([self.rdata.oMf[f].translation for f in self.foot_fids])

    # ------------------------------------------------------------------ solve
    def solve(self, x0: np.ndarray, x_ref: np.ndarray, com_ref: np.ndarray, vel_ref: np.ndarray,
              foot_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Run FDDP from the measured x0.

        Args:
            x0: (nq + nv,) measured state.
            x_ref: (H + 1, nq + nv) state regularization references per knot.
            com_ref: (H + 1, 3) CoM references; vel_ref: (H + 1, 6) planned CoM linear velocity and
                angular velocity (world); foot_ref: (H + 1, 4, 3) foot position references.
        Returns:
            xs (H + 1, nq + nv), us (H, nv).
        """
        H = self.H
        for k, (r_state, r_com, r_mom, r_feet) in enumerate(self._residuals):
            r_state.reference = x_ref[k]
            r_com.reference = com_ref[k]
            r_mom.reference = pin.Motion(vel_ref[k, 0:3], vel_ref[k, 3:6])
            for i in range(4):
                r_feet[i].reference = foot_ref[k, i]
        self.problem.x0 = x0
        if self.xs is None:  # cold start from the references (base moving with the plan)
            xs = [x0.copy()] + [x_ref[k].copy() for k in range(1, H + 1)]
            us = [self.u_ref.copy() for _ in range(H)]
        else:  # shift the previous solution by one knot (replanning period = one knot)
            xs = [x0.copy()] + [self.xs[k] for k in range(2, H + 1)] + [self.xs[H]]
            us = [self.us[k] for k in range(1, H)] + [self.us[H - 1]]
        self.solver.solve(xs, us, self.max_iter, False, 1e-9)
        self.last_iter = self.solver.iter
        self.xs = np.array(self.solver.xs)
        self.us = np.array(self.solver.us)
        return self.xs, self.us
