"""Centroidal-dynamics planner of the kino-dynamic MPC (after BiConMP, Meduri et al. 2022).

State per knot (9, robot-normalized so one weight vector means the same on every robot):

    X = (c, v, h):  c CoM position [m],  v = l / m  linear momentum per mass [m/s],
                    h = k / m  angular momentum about the CoM per mass [m²/s]

Input per knot: the ground's force on each foot in units of m·g, u (12) = f / (m·g). Knot step
dt (0.05 s), horizon H (10). Discrete dynamics (forces held over a knot):

    v⁺ = v + dt·g·(Σ u_i − e_z)
    c⁺ = c + dt·v + ½·dt²·g·(Σ u_i − e_z)
    h⁺ = h + dt·g·Σ (p_i − c) × u_i                           (bilinear in (c, u))

Cost: Σ_{k=1..H−1} ‖X_k − X^ref_k‖²_{W_X} + ‖X_H − X^ref_H‖²_{W_X_ter} + Σ_k ‖u_k‖²_{W_F}, subject
to the friction pyramid |u_x|, |u_y| ≤ μ u_z, 0 ≤ u_z ≤ u_max on (knot, foot) pairs in stance and
u = 0 in swing.

The problem is bi-convex: with the trajectory fixed the dynamics are linear in the forces, with the
forces fixed they are linear in the trajectory. As in BiConMP it is solved by alternating convex
problems, warm-started from the previous plan:

1. *forces step* — fix the CoM trajectory c̄ in the torque arms (p_i − c̄_k); the dynamics are then
   linear in U and the trajectory is an affine function of U (condensing), which gives a QP in the
   forces alone with the friction cones (solved with DAQP, dense active-set).
2. *trajectory step* — fix the forces; the dynamics are linear in X and, imposed as hard
   constraints, determine X uniquely from the measured X_0: the equality-constrained QP in the
   trajectory reduces to this forward pass, which updates c̄.

The alternation stops when the CoM path moves less than ``tol`` (1 mm) or after ``iters`` (3).
Warm-started with the previous plan shifted by one knot, the torque arms are nearly right from the
first step; from a cold start (the reference path) it converges slowly, but the robot is then
standing still and the next replans fix it. BiConMP instead relaxes the dynamics with an
augmented-Lagrangian penalty ρ and runs up to ~50 FISTA iterations in C++, which would not fit a
Python 20 Hz budget. ``python -m benchmarks.kinodynamic`` times a planner solve.
"""
from __future__ import annotations

import numpy as np

from latentune.actor.base import ActorFailure, friction_pyramid
from latentune.constants import G


def _skew_blocks(r: np.ndarray) -> np.ndarray:
    """(n, 3) vectors -> (n, 3, 3) cross-product matrices [r]×."""
    n = r.shape[0]
    S = np.zeros((n, 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -r[:, 2], r[:, 1]
    S[:, 1, 0], S[:, 1, 2] = r[:, 2], -r[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -r[:, 1], r[:, 0]
    return S


class CentroidalPlanner:
    """Bi-convex centroidal planner over ``horizon`` knots of ``dt`` seconds.

    Args:
        dt: knot duration [s]; horizon: number of knots H; mu: friction coefficient;
        u_max: per-foot normal force bound in units of m·g; iters: max alternations per solve;
        tol: stop when the CoM path moves less than this between alternations [m].
    """

    def __init__(self, dt: float = 0.05, horizon: int = 10, mu: float = 0.6, u_max: float = 2.5,
                 iters: int = 3, tol: float = 1e-3):
        self.dt, self.H, self.mu, self.u_max, self.iters, self.tol = dt, horizon, mu, u_max, iters, tol
        H = horizon
        k = np.arange(1, H + 1)[:, None]
        j = np.arange(H)[None, :]
        lower = (j < k)                                          # knot k depends on u_j, j < k
        self._c_coef = np.where(lower, dt * dt * G * (k - j - 0.5), 0.0)   # (H, H)
        self._v_coef = np.where(lower, dt * G, 0.0)
        self.last_iters = 0
        eye3 = np.eye(3)
        self._B_lin = np.zeros((H, 9, H, 12))
        for leg in range(4):
            sl = slice(3 * leg, 3 * leg + 3)
            self._B_lin[:, 0:3, :, sl] = self._c_coef[:, None, :, None] * eye3[None, :, None, :]
            self._B_lin[:, 3:6, :, sl] = self._v_coef[:, None, :, None] * eye3[None, :, None, :]
        self._mask = (np.arange(H)[None, :] < np.arange(1, H + 1)[:, None]).astype(float)
        self._B = self._B_lin.copy()    # the forces step's B: rows 6:9 rewritten every step
        self._cons: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def plan(self, x0: np.ndarray, contact: np.ndarray, feet: np.ndarray, x_ref: np.ndarray,
             w_x: np.ndarray, w_x_ter: np.ndarray, w_f: np.ndarray,
             c_guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Solve one MPC problem.

        Args:
            x0: (9,) measured normalized centroidal state.
            contact: (H, 4) bool stance per knot and foot.
            feet: (H, 4, 3) world foot positions per knot (used for stance feet) [m].
            x_ref: (H, 9) reference for knots 1..H.
            w_x, w_x_ter: (9,) running and terminal state weights; w_f: (12,) force weights.
            c_guess: (H, 3) CoM positions at knots 0..H−1 for the torque arms (warm start), or None.
        Returns:
            X (H + 1, 9) knots 0..H, U (H, 12) forces in units of m·g.
        Raises:
            ActorFailure: infeasible / non-finite QP.
        """
        H, dt = self.H, self.dt
        x0 = np.asarray(x0, float)
        active = np.repeat(contact.reshape(-1), 3)                 # (12H,) variable is free
        cols = np.flatnonzero(active)
        U = np.zeros((H, 12))
        if cols.size == 0:
            X = self.rollout(x0, U, feet)
            return X, U
        if c_guess is None:  # the reference CoM path
            c_guess = np.vstack([x0[None, :3], x_ref[:H - 1, 0:3]])
        c_bar = np.asarray(c_guess, float).copy()
        W = np.tile(w_x, (H, 1))
        W[-1] = w_x_ter
        Wv = W.reshape(-1)
        # free response (gravity, no contact force)
        kk = np.arange(1, H + 1)[:, None] * dt
        Xf = np.empty((H, 9))
        Xf[:, 0:3] = x0[:3] + kk * x0[3:6]
        Xf[:, 2] -= 0.5 * G * kk[:, 0] ** 2
        Xf[:, 3:6] = x0[3:6]
        Xf[:, 5] -= G * kk[:, 0]
        Xf[:, 6:9] = x0[6:9]
        err0 = (Xf - x_ref).reshape(-1)
        n = cols.size
        nc = n // 3
        if nc not in self._cons:   # DAQP does not write to them: cached per nc
            self._cons[nc] = friction_pyramid(nc, self.mu, self.u_max)
        Acon, lo, hi = self._cons[nc]
        Rvec = np.tile(w_f, H)[cols]
        X = None
        B = self._B
        for it in range(self.iters):
            # ---- forces step: condensed QP with the torque arms fixed at c_bar
            arms = _skew_blocks((feet - c_bar[:, None, :]).reshape(-1, 3)).reshape(H, 4, 3, 3) * (dt * G)
            # h_k depends on u_j (j < k) through the arm at knot j: B[k, 6+a, j, 3 leg + b]
            B[:, 6:9, :, :] = self._mask[:, None, :, None] * \
                arms.transpose(2, 0, 1, 3).reshape(3, H, 12)[None, :, :, :]
            Bm = B.reshape(9 * H, 12 * H)[:, cols]
            WB = Bm * Wv[:, None]
            Hm = Bm.T @ WB
            Hm.flat[::n + 1] += Rvec + 1e-9
            g = WB.T @ err0
            u = self._solve(Hm, g, Acon, lo, hi)
            U = np.zeros(12 * H)
            U[cols] = u
            U = U.reshape(H, 12)
            # ---- trajectory step: dynamics with the forces fixed (unique X from x0)
            X = self.rollout(x0, U, feet)
            c_new = X[:H, 0:3]
            delta = float(np.max(np.abs(c_new - c_bar)))
            c_bar = c_new
            self.last_iters = it + 1
            if delta < self.tol:
                break
        return X, U

    def rollout(self, x0: np.ndarray, U: np.ndarray, feet: np.ndarray) -> np.ndarray:
        """(H + 1, 9) trajectory from x0 under forces U (H, 12) [m·g] with exact bilinear dynamics."""
        H, dt = self.H, self.dt
        u = U.reshape(H, 4, 3)
        a = G * u.sum(axis=1)
        a[:, 2] -= G                                               # (H, 3) CoM acceleration
        X = np.empty((H + 1, 9))
        X[0] = x0
        X[1:, 3:6] = x0[3:6] + dt * np.cumsum(a, axis=0)
        v_prev = X[:H, 3:6]
        X[1:, 0:3] = x0[0:3] + np.cumsum(dt * v_prev + 0.5 * dt * dt * a, axis=0)
        r = feet - X[:H, None, 0:3]                               # (H, 4, 3) arms
        tq = np.empty((H, 4, 3))
        tq[..., 0] = r[..., 1] * u[..., 2] - r[..., 2] * u[..., 1]
        tq[..., 1] = r[..., 2] * u[..., 0] - r[..., 0] * u[..., 2]
        tq[..., 2] = r[..., 0] * u[..., 1] - r[..., 1] * u[..., 0]
        X[1:, 6:9] = x0[6:9] + dt * G * np.cumsum(tq.sum(axis=1), axis=0)
        return X

    @staticmethod
    def _solve(Hm: np.ndarray, g: np.ndarray, A: np.ndarray, lo: np.ndarray,
               hi: np.ndarray) -> np.ndarray:
        if not (np.isfinite(Hm).all() and np.isfinite(g).all()):
            raise ActorFailure("non-finite centroidal QP")
        import daqp

        sense = np.zeros(lo.size, dtype=np.int32)
        x, _, flag, _ = daqp.solve(Hm, g, A, hi, lo, sense)
        if flag < 1 or not np.isfinite(x).all():
            raise ActorFailure(f"centroidal QP failed (daqp exit {flag})")
        return np.asarray(x)
