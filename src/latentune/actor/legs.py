"""Leg kinematics (pinocchio, fixed-base model in the base link frame) and swing-leg control.

Shapes: foot positions (4, 3), Jacobians (4, 3, 3) — leg k's foot position w.r.t. its own three
joints (abduction, hip, knee), expressed in the base link frame. Units: m, rad.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from latentune.constants import G
from latentune.robots import RobotModel

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class LegKinematics:
    """Foot positions and per-leg Jacobians from the 12 joint angles."""

    def __init__(self, model: RobotModel):
        self.model = model.pin_model
        self.data = self.model.createData()
        self.fids = model.foot_frame_ids
        self.q_index = np.asarray(model.q_index)
        self.v_index = self.q_index  # revolute joints only: idx_v == idx_q
        self._q = np.zeros(self.model.nq)
        # per leg: its foot frame and its joints' Jacobian columns (a slice when consecutive)
        self._legs = []
        for k, f in enumerate(self.fids):
            cols = self.v_index[3 * k:3 * k + 3]
            a = int(cols[0])
            consecutive = cols.tolist() == [a, a + 1, a + 2]
            self._legs.append((f, slice(a, a + 3) if consecutive else cols))
        self._gravity_w = np.array([0.0, 0.0, -G])

    def update(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Args: q (12,) joint angles. Returns (feet (4, 3), J (4, 3, 3)) in the base link frame."""
        self._q[self.q_index] = q
        m, d = self.model, self.data
        pin.computeJointJacobians(m, d, self._q)
        pin.updateFramePlacements(m, d)
        feet = np.empty((4, 3))
        J = np.empty((4, 3, 3))
        oMf = d.oMf
        for k, (f, cols) in enumerate(self._legs):
            feet[k] = oMf[f].translation
            J[k] = pin.getFrameJacobian(m, d, f, _LWA)[:3, cols]
        return feet, J

    def gravity(self, q: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(12,) joint torques [N·m] that hold the legs' own weight, base orientation R (3, 3).

        Call after :meth:`update` with the same q.
        """
        self.model.gravity.linear = R.T @ self._gravity_w
        g = pin.computeGeneralizedGravity(self.model, self.data, self._q)
        return g[self.q_index]


def swing_trajectory(p0: np.ndarray, p1: np.ndarray, s: np.ndarray, height: float,
                     duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Foot positions and velocities along swings from p0 to p1 (world frame), for k legs at once.

    Horizontal motion follows a minimum-jerk blend; the vertical offset is a smooth bump
    ``height · sin²(π s)`` above the straight line. Args: p0, p1 (k, 3) [m]; s (k,) swing
    progress in [0, 1]; height [m]; duration [s]. Returns (p (k, 3), v (k, 3)) in m, m/s.
    """
    s = np.clip(s, 0.0, 1.0)[:, None]
    b = s * s * s * (10 - 15 * s + 6 * s * s)
    db = 30 * s * s * (1 - s) ** 2 / duration
    d = p1 - p0
    p = p0 + d * b
    v = d * db
    pi_s = np.pi * s[:, 0]
    sn = np.sin(pi_s)
    p[:, 2] += height * sn * sn
    v[:, 2] += height * 2 * sn * np.cos(pi_s) * np.pi / duration
    return p, v
