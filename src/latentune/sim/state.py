"""The measured state of a simulated robot at one physics step (:class:`RobotState`), shared by
the worlds (:mod:`latentune.sim.world`, :mod:`latentune.sim.mujoco_world`) and the reality's
sensor noise (:mod:`latentune.sim.reality`).

Units: SI (m, s, rad). World frame: x forward, z up.
"""
from __future__ import annotations

import math

import numpy as np

from latentune.sim.bullet import p

__all__ = ["RobotState"]


class RobotState:
    """Measured state of the robot at one physics step.

    Attributes:
        pos: (3,) base (trunk centre of mass) position, world frame [m].
        quat: (4,) orientation quaternion (x, y, z, w) of the base's inertial frame (PyBullet's
            base frame: it is rotated against the trunk link when the URDF's inertia has a
            rotated origin, as on A1 (0.7 deg) and B1 (2.7 deg)); in MuJoCo the base link's.
        vel: (3,) base linear velocity, world frame [m/s].
        omega: (3,) base angular velocity, world frame [rad/s].
        q: (12,) joint angles [rad]; dq: (12,) joint velocities [rad/s].
        up_z: z component of the base's up axis (cos of the tilt), R[2, 2].
        finite: base position and velocity are finite.
        R: (3, 3) rotation trunk link -> world (computed on first use).
    """

    __slots__ = ("pos", "quat", "vel", "omega", "q", "dq", "up_z", "finite", "_R", "_RT")

    def __init__(self, pos, quat, vel, omega, q, dq, up_z: float, finite: bool,
                 RT: np.ndarray | None = None):
        self.pos, self.quat, self.vel, self.omega, self.q, self.dq = pos, quat, vel, omega, q, dq
        self.up_z, self.finite, self._RT, self._R = up_z, finite, RT, None

    @property
    def R(self) -> np.ndarray:
        if self._R is None:
            R = np.array(p.getMatrixFromQuaternion(self.quat.tolist())).reshape(3, 3)
            self._R = R if self._RT is None else R @ self._RT
        return self._R

    @property
    def rpy(self) -> np.ndarray:
        """(3,) roll, pitch, yaw [rad] (ZYX convention)."""
        R = self.R
        return np.array([math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1.0, min(1.0, R[2, 0]))),
                         math.atan2(R[1, 0], R[0, 0])])
