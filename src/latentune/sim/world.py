"""The simulated world: one PyBullet DIRECT client with a ground and one robot.

Units: SI (m, s, rad, N, N·m). World frame: x forward, z up. Leg order FR, FL, RR, RL.
PyBullet's own output never reaches stdout (:mod:`latentune.sim.bullet`): building the world,
rendering and closing send it to stderr, ``loadURDF``'s parser warnings go nowhere.
"""
from __future__ import annotations

import math

import numpy as np
from latentune.sim.bullet import p, quiet, stdout_to_stderr

from latentune.constants import G, TERRAINS
from latentune.robots import RobotModel, RobotSpec


class RobotState:
    """Measured state of the robot at one physics step.

    Attributes:
        pos: (3,) base (trunk centre of mass) position, world frame [m].
        quat: (4,) orientation quaternion (x, y, z, w) of the base's inertial frame (PyBullet's
            base frame: it is rotated against the trunk link when the URDF's inertia has a
            rotated origin, as on A1 (0.7 deg) and B1 (2.7 deg)).
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


def perlin_heightfield(n: int, seed: int, octaves: int = 10, amplitude: float = 0.02,
                       base_cells: int = 4) -> np.ndarray:
    """Fractal Perlin noise on an (n, n) grid, rescaled to heights in [0, amplitude] metres.

    Octave k has ``base_cells·2^k`` lattice cells across the field and weight 0.5^k (the paper's
    hills: 10 octaves, 0.02 m). Deterministic for ``seed``.
    """
    rng = np.random.default_rng(seed)
    u = np.linspace(0.0, 1.0, n, endpoint=False)
    total = np.zeros((n, n))
    for k in range(octaves):
        cells = base_cells * 2 ** k
        ang = rng.uniform(0, 2 * np.pi, size=(cells + 1, cells + 1))
        gx, gy = np.cos(ang), np.sin(ang)
        x = u * cells
        i0 = np.minimum(np.floor(x).astype(int), cells - 1)
        f = x - i0
        X0, Y0 = np.meshgrid(i0, i0, indexing="ij")
        FX, FY = np.meshgrid(f, f, indexing="ij")

        def dot(ix, iy, dx, dy):
            return gx[ix, iy] * dx + gy[ix, iy] * dy

        n00 = dot(X0, Y0, FX, FY)
        n10 = dot(X0 + 1, Y0, FX - 1, FY)
        n01 = dot(X0, Y0 + 1, FX, FY - 1)
        n11 = dot(X0 + 1, Y0 + 1, FX - 1, FY - 1)
        sx = FX ** 3 * (FX * (FX * 6 - 15) + 10)
        sy = FY ** 3 * (FY * (FY * 6 - 15) + 10)
        total += 0.5 ** k * ((n00 * (1 - sx) + n10 * sx) * (1 - sy) + (n01 * (1 - sx) + n11 * sx) * sy)
    total -= total.min()
    peak = total.max()
    return total * (amplitude / peak) if peak > 0 else total


class World:
    """A PyBullet DIRECT client with ground and robot, reset cheaply between rollouts.

    Args:
        spec: the robot.
        terrain: one of :data:`latentune.constants.TERRAINS`: ``"flat"`` or ``"hills"`` (5 m × 5 m
            Perlin heightfield, 0.05 m cells, ≤ 0.02 m).
        seed: terrain seed.
        dt: physics step [s] (1 kHz by default).

    Attributes:
        start_x: initial base x [m] (0 on flat ground; hills start near the field's back edge).
        ground_z: highest terrain point [m] (0 on flat ground).
    """

    def __init__(self, spec: RobotSpec, terrain: str = "flat", seed: int = 0, dt: float = 0.001):
        if terrain not in TERRAINS:
            raise ValueError(f"unknown terrain {terrain!r} (choose from {', '.join(TERRAINS)})")
        self.spec = spec
        self.cid = None
        self.model = RobotModel.load(spec)
        self.terrain = terrain
        self.dt = dt
        with stdout_to_stderr():
            self._build(seed)

    def _build(self, seed: int) -> None:
        spec = self.spec
        terrain = self.terrain
        dt = self.dt
        self.cid = p.connect(p.DIRECT)
        c = self.cid
        p.setGravity(0, 0, -G, physicsClientId=c)
        p.setTimeStep(dt, physicsClientId=c)
        p.setPhysicsEngineParameter(enableConeFriction=0, physicsClientId=c)
        self.start_x = 0.0
        self.ground_z = 0.0
        if terrain == "flat":
            col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
            self.ground = p.createMultiBody(0, col, physicsClientId=c)
        else:
            n, cell = 100, 0.05
            self.heights = perlin_heightfield(n, seed)
            col = p.createCollisionShape(p.GEOM_HEIGHTFIELD, meshScale=[cell, cell, 1.0],
                                         heightfieldData=self.heights.T.reshape(-1).tolist(),
                                         numHeightfieldRows=n, numHeightfieldColumns=n,
                                         physicsClientId=c)
            # PyBullet centres the heightfield vertically on (min + max) / 2
            self.ground = p.createMultiBody(0, col, basePosition=[0, 0, 0.5 * self.heights.max()],
                                            physicsClientId=c)
            self.start_x = -1.25
            self.ground_z = float(self.heights.max())
        p.changeDynamics(self.ground, -1, lateralFriction=1.0, physicsClientId=c)
        z0 = spec.nominal_height + self.ground_z + 0.01
        with quiet():
            self.robot = p.loadURDF(self.model.urdf, [self.start_x, 0, z0], [0, 0, 0, 1],
                                    flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        names = {p.getJointInfo(self.robot, j, physicsClientId=c)[1].decode(): j
                 for j in range(p.getNumJoints(self.robot, physicsClientId=c))}
        links = {p.getJointInfo(self.robot, j, physicsClientId=c)[12].decode(): j
                 for j in range(p.getNumJoints(self.robot, physicsClientId=c))}
        # link index -> name (-1: the base), for the fall reason "body touched the ground: link …"
        self.link_names = {j: name for name, j in links.items()}
        self.link_names[-1] = p.getBodyInfo(self.robot, physicsClientId=c)[0].decode()
        self.joint_ids = [names[j] for j in spec.joint_names]
        self.foot_ids = [links[f] for f in spec.foot_links]
        p.setJointMotorControlArray(self.robot, self.joint_ids, p.VELOCITY_CONTROL,
                                    forces=[0.0] * 12, physicsClientId=c)
        for j in range(-1, p.getNumJoints(self.robot, physicsClientId=c)):
            p.changeDynamics(self.robot, j, linearDamping=0, angularDamping=0, physicsClientId=c)
        for f in self.foot_ids:
            p.changeDynamics(self.robot, f, lateralFriction=1.0, physicsClientId=c)
        # base link frame vs. base inertial frame (PyBullet reports the pose of the latter):
        # its origin in the link frame, and its rotation, undone in state()
        info = p.getDynamicsInfo(self.robot, -1, physicsClientId=c)
        self.base_com_local = np.array(info[3])
        R_in = np.array(p.getMatrixFromQuaternion(info[4])).reshape(3, 3)
        self._RT = None if np.allclose(R_in, np.eye(3), atol=1e-12) else R_in.T
        self._RT_col2 = (0.0, 0.0, 1.0) if self._RT is None else tuple(self._RT[:, 2])
        for k, j in enumerate(self.joint_ids):
            p.resetJointState(self.robot, j, spec.nominal_q[k], 0.0, physicsClientId=c)
        self._settle()
        self._saved = p.saveState(physicsClientId=c)

    def _settle(self) -> None:
        """Hold the stance with joint PD for 0.3 s so every rollout starts standing."""
        q0 = np.array(self.spec.nominal_q)
        kp, kd = np.tile(self.spec.kp, 4), np.tile(self.spec.kd, 4)
        lim = np.tile(self.spec.torque_limits, 4)
        for _ in range(300):
            s = self.state()
            self.apply(np.clip(kp * (q0 - s.q) - kd * s.dq, -lim, lim))
            self.step()
        # zero residual velocity
        pos, quat = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        p.resetBaseVelocity(self.robot, [0, 0, 0], [0, 0, 0], physicsClientId=self.cid)

    def reset(self) -> None:
        """Restore the settled standing state (cheap; reuses the loaded world)."""
        p.restoreState(self._saved, physicsClientId=self.cid)

    def state(self) -> RobotState:
        c, r = self.cid, self.robot
        pos, quat = p.getBasePositionAndOrientation(r, physicsClientId=c)
        vel, omega = p.getBaseVelocity(r, physicsClientId=c)
        js = p.getJointStates(r, self.joint_ids, physicsClientId=c)
        q, dq = np.array([(j[0], j[1]) for j in js]).T
        x, y, z, w = quat
        finite = math.isfinite(pos[0] + pos[1] + pos[2] + vel[0] + vel[1] + vel[2])
        # up_z = (R_inertial · RTᵀ)[2, 2]: row 2 of the inertial frame's rotation, times column 2
        # of the inertial -> link correction
        c = self._RT_col2
        up_z = 2.0 * (x * z - w * y) * c[0] + 2.0 * (y * z + w * x) * c[1] \
            + (1.0 - 2.0 * (x * x + y * y)) * c[2]
        return RobotState(np.array(pos), np.array(quat), np.array(vel), np.array(omega), q, dq,
                          up_z, finite, self._RT)

    def apply(self, tau: np.ndarray) -> None:
        """Set the 12 joint torques [N·m] for the next step."""
        self.apply_list(tau.tolist())

    def apply_list(self, tau: list[float]) -> None:
        """:meth:`apply` for a plain list of 12 torques [N·m]."""
        p.setJointMotorControlArray(self.robot, self.joint_ids, p.TORQUE_CONTROL, forces=tau,
                                    physicsClientId=self.cid)

    def step(self) -> None:
        p.stepSimulation(physicsClientId=self.cid)

    def body_touches_ground(self) -> bool:
        """True if any link other than the feet (the trunk included) touches the ground."""
        return self.body_ground_contact() is not None

    def body_ground_contact(self) -> str | None:
        """Name of the first link other than the feet (the trunk included) that touches the
        ground, or None."""
        pts = p.getContactPoints(self.robot, self.ground, physicsClientId=self.cid)
        feet = set(self.foot_ids)
        link = next((pt[3] for pt in pts if pt[3] not in feet), None)
        return None if link is None else self.link_names.get(link, f"#{link}")

    def foot_contacts(self) -> np.ndarray:
        """(4,) bool: which feet touch the ground."""
        pts = p.getContactPoints(self.robot, self.ground, physicsClientId=self.cid)
        links = {pt[3] for pt in pts}
        return np.array([f in links for f in self.foot_ids])

    def ground_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y) [m]."""
        if self.terrain == "flat":
            return 0.0
        n, cell = self.heights.shape[0], 0.05
        i = int(round(x / cell + (n - 1) / 2))
        j = int(round(y / cell + (n - 1) / 2))
        if 0 <= i < n and 0 <= j < n:
            return float(self.heights[i, j])
        return 0.0

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame from a camera following the robot (CPU renderer)."""
        pos, _ = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        view = p.computeViewMatrixFromYawPitchRoll(pos, 1.0 + 1.5 * self.spec.nominal_height,
                                                   50, -25, 0, 2, physicsClientId=self.cid)
        proj = p.computeProjectionMatrixFOV(60, width / height, 0.05, 20, physicsClientId=self.cid)
        with stdout_to_stderr():
            img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                   physicsClientId=self.cid)
        return np.asarray(img[2], dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    def close(self) -> None:
        if self.cid is not None:
            try:
                with stdout_to_stderr():
                    p.disconnect(physicsClientId=self.cid)
            except p.error:
                pass
            self.cid = None

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
