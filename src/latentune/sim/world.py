"""The simulated world: one PyBullet DIRECT client with a ground and one robot.

Units: SI (m, s, rad, N, N·m). World frame: x forward, z up. Leg order FR, FL, RR, RL.
PyBullet's own output never reaches stdout (:mod:`latentune.sim.bullet`): building the world,
rendering and closing send it to stderr, ``loadURDF``'s parser warnings go nowhere.

:class:`SimWorld` states the interface the actors and :class:`~latentune.task.Task` use; both
engines implement it (:class:`World` here, :class:`~latentune.sim.mujoco_world.MujocoWorld`).
A :class:`~latentune.sim.reality.Reality` perturbs either (body, ground, motors, joints,
sensors, pushes).
"""
from __future__ import annotations

import functools
import logging
import math
from typing import Protocol, runtime_checkable

import numpy as np
from latentune.sim.bullet import p, quiet, stdout_to_stderr

from latentune.constants import G, TERRAINS
from latentune.robots import RobotModel, RobotSpec
from latentune.sim.reality import Reality, RealityRuntime, perturbed_urdf
from latentune.sim.state import RobotState

logger = logging.getLogger(__name__)

ENGINES: tuple[str, ...] = ("pybullet", "mujoco")
"""The physics engines a world can run on (``pybullet`` is the default and the paper's)."""


@runtime_checkable
class SimWorld(Protocol):
    """The world interface both engines implement (units SI, world frame x forward, z up).

    Attributes:
        spec, model: the robot's spec and its nominal measured model (what the controller
            knows; a reality's perturbations are not in it).
        engine: ``"pybullet"`` or ``"mujoco"``.
        reality: the :class:`~latentune.sim.reality.Reality` applied.
        terrain: ``"flat"`` or ``"hills"``; dt: physics step [s] (0.001).
        start_x: initial base x [m]; ground_z: highest terrain point [m].
        base_com_local: (3,) base centre of mass in the base link frame [m] (the offset
            between ``RobotState.pos`` and the base link's origin).
    """

    spec: RobotSpec
    model: RobotModel
    engine: str
    reality: Reality
    terrain: str
    dt: float
    start_x: float
    ground_z: float
    base_com_local: np.ndarray

    def reset(self) -> None:
        """Back to the settled standing state; the reality's generators restart from the seed."""

    def true_state(self) -> "RobotState":
        """The exact state (for the cost and the fall detector)."""

    def observe(self, s: "RobotState") -> "RobotState":
        """The controller's view of the true state ``s`` (with the reality's sensor noise)."""

    def state(self) -> "RobotState":
        """The controller's view of the current state: ``observe(true_state())``."""

    def apply(self, tau: np.ndarray) -> None:
        """Command the 12 joint torques [N·m] (through the reality's motor) for the next step."""

    def step(self) -> None:
        """Advance one physics step of ``dt`` (with the reality's pushes)."""

    def ground_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y) [m]."""

    def body_ground_contact(self) -> str | None:
        """Name of a non-foot link touching the ground, or None."""

    def foot_contacts(self) -> np.ndarray:
        """(4,) bool: which feet touch the ground."""

    def foot_positions(self) -> np.ndarray:
        """(4, 3) world positions of the foot links' frames [m] (true, no noise)."""

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame from a camera following the robot."""

    def close(self) -> None:
        """Release the engine's resources."""


def perlin_heightfield(n: int, seed: int, octaves: int = 10, amplitude: float = 0.02,
                       base_cells: int = 4) -> np.ndarray:
    """Fractal Perlin noise on an (n, n) grid, rescaled to heights in [0, amplitude] metres.

    Octave k has ``base_cells·2^k`` lattice cells across the field and weight 0.5^k (the paper's
    hills: 10 octaves, 0.02 m). Deterministic for ``seed``: a field is computed once per process
    (a tenth of a second or more for the hills) and each call returns a new copy of it.
    """
    return _perlin(int(n), int(seed), int(octaves), float(amplitude), int(base_cells)).copy()


@functools.lru_cache(maxsize=32)
def _perlin(n: int, seed: int, octaves: int, amplitude: float, base_cells: int) -> np.ndarray:
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
    out = total * (amplitude / peak) if peak > 0 else total
    out.flags.writeable = False                # the cached field: callers get copies
    return out


HILLS_CELLS, HILLS_CELL = 100, 0.05
"""The hills heightfield: 100 × 100 vertices, 0.05 m apart (4.95 m across, centred on 0)."""


class WorldBase:
    """What both engines share: the terrain layout and its heights, the reality's runtime
    (motor, sensor noise, pushes), the settling stance, :meth:`state`/:meth:`observe`,
    :meth:`apply` and :meth:`step` around the engine's ``_drive`` (set torques as they are),
    ``_push`` (one step's external force on the base) and ``_raw_step`` (one physics step)."""

    engine = "?"

    def _init_common(self, spec: RobotSpec, terrain: str, seed: int, dt: float,
                     reality: Reality | None) -> None:
        if terrain not in TERRAINS:
            raise ValueError(f"unknown terrain {terrain!r} (choose from {', '.join(TERRAINS)})")
        self.spec = spec
        self.model = RobotModel.load(spec)
        self.terrain = terrain
        self.dt = dt
        self.seed = int(seed)
        self.reality = Reality.load(reality)
        if self.reality.relative:      # fractions of this robot's mass and torque limits
            from latentune.robots.urdf import read_urdf

            self.reality = self.reality.for_robot(read_urdf(self.model.urdf).total_mass(),
                                                  max(spec.torque_limits))
        self._rt = None if self.reality.is_nominal else RealityRuntime(self.reality, seed, dt)
        self._motor = self._rt is not None and not self._rt.passthrough
        self.start_x = 0.0
        self.ground_z = 0.0
        self.heights: np.ndarray | None = None
        if terrain == "hills":
            self.heights = perlin_heightfield(HILLS_CELLS, seed)
            self.start_x = -1.25
            self.ground_z = float(self.heights.max())

    def _settle(self) -> None:
        """Hold the stance with joint PD for 0.3 s so every rollout starts standing (true
        state, torques without the reality's motor, no pushes), then zero the base velocity."""
        q0 = np.array(self.spec.nominal_q)
        kp, kd = np.tile(self.spec.kp, 4), np.tile(self.spec.kd, 4)
        lim = np.tile(self.spec.torque_limits, 4)
        for _ in range(300):
            s = self.true_state()
            self._drive(np.clip(kp * (q0 - s.q) - kd * s.dq, -lim, lim))
            self._raw_step()
        self._zero_base_velocity()

    def reset(self) -> None:
        """Restore the settled standing state (cheap; reuses the loaded world) and restart the
        reality's generators, latency queue and pushes."""
        self._restore()
        if self._rt is not None:
            self._rt.reset()

    def state(self) -> RobotState:
        """The controller's view of the current state (with the reality's sensor noise)."""
        return self.observe(self.true_state())

    def observe(self, s: RobotState) -> RobotState:
        """The controller's view of the true state ``s``: ``s`` itself without sensor noise."""
        return s if self._rt is None else self._rt.observe(s)

    def apply(self, tau: np.ndarray) -> None:
        """Command the 12 joint torques [N·m] for the next step (through the reality's
        latency, torque scale and limits)."""
        if self._motor:
            tau = self._rt.motor(tau)
        self._drive(tau)

    def step(self) -> None:
        """One physics step of ``dt`` [s], with the reality's push (if one is under way) on
        the base's centre of mass."""
        if self._rt is not None:
            f = self._rt.push()
            if f is not None:
                self._push(f)
        self._raw_step()

    def body_touches_ground(self) -> bool:
        """True if any link other than the feet (the trunk included) touches the ground."""
        return self.body_ground_contact() is not None

    def ground_height(self, x: float, y: float) -> float:
        """Terrain height under (x, y) [m] (the nearest heightfield vertex; 0 off the field)."""
        if self.heights is None:
            return 0.0
        n, cell = self.heights.shape[0], HILLS_CELL
        i = int(round(x / cell + (n - 1) / 2))
        j = int(round(y / cell + (n - 1) / 2))
        if 0 <= i < n and 0 <= j < n:
            return float(self.heights[i, j])
        return 0.0

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception as exc:  # noqa: BLE001 - at interpreter exit anything may be gone
            logger.debug("closing a simulator world failed: %s", exc)


class World(WorldBase):
    """A PyBullet DIRECT client with ground and robot, reset cheaply between rollouts
    (implements :class:`SimWorld`).

    Args:
        spec: the robot.
        terrain: one of :data:`latentune.constants.TERRAINS`: ``"flat"`` or ``"hills"`` (5 m × 5 m
            Perlin heightfield, 0.05 m cells, ≤ 0.02 m).
        seed: terrain seed, and the seed of the reality's noise and pushes.
        dt: physics step [s] (1 kHz by default).
        reality: a :class:`~latentune.sim.reality.Reality` (None: the nominal simulator). In
            PyBullet: masses, inertias and the payload through :func:`perturbed_urdf`; ground
            friction (the foot–ground coefficient is the product of the ground's and the
            feet's, 1.0), restitution (the ground's, × 1.0 on every robot link) and joint
            damping through ``changeDynamics``; joint
            friction as each joint's velocity motor (target 0, maximum torque
            ``joint_friction``); latency, torque scale and limits in :meth:`apply`; sensor
            noise in :meth:`state`; pushes through ``applyExternalForce`` in :meth:`step`.
        visuals: load the URDF's visual shapes. Without them (the default) the robot is its
            collision shapes and inertias only, which is all the physics reads; B1's visual
            meshes alone take seconds to load. :meth:`render` then draws a twin world that has
            them, posed like this one.

    Attributes:
        start_x: initial base x [m] (0 on flat ground; hills start near the field's back edge).
        ground_z: highest terrain point [m] (0 on flat ground).
    """

    engine = "pybullet"

    def __init__(self, spec: RobotSpec, terrain: str = "flat", seed: int = 0, dt: float = 0.001,
                 reality: Reality | None = None, visuals: bool = False):
        self.cid = None
        self.visuals = bool(visuals)
        self._twin: World | None = None       # render()'s world with visual shapes
        self._init_common(spec, terrain, seed, dt, reality)
        with stdout_to_stderr():
            self._build()

    def _build(self) -> None:
        spec = self.spec
        dt = self.dt
        self.cid = p.connect(p.DIRECT)
        c = self.cid
        p.setGravity(0, 0, -G, physicsClientId=c)
        p.setTimeStep(dt, physicsClientId=c)
        p.setPhysicsEngineParameter(enableConeFriction=0, physicsClientId=c)
        if self.heights is None:
            col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
            self.ground = p.createMultiBody(0, col, physicsClientId=c)
        else:
            n, cell = HILLS_CELLS, HILLS_CELL
            col = p.createCollisionShape(p.GEOM_HEIGHTFIELD, meshScale=[cell, cell, 1.0],
                                         heightfieldData=self.heights.T.reshape(-1).tolist(),
                                         numHeightfieldRows=n, numHeightfieldColumns=n,
                                         physicsClientId=c)
            # PyBullet centres the heightfield vertically on (min + max) / 2
            self.ground = p.createMultiBody(0, col, basePosition=[0, 0, 0.5 * self.heights.max()],
                                            physicsClientId=c)
        real = self.reality
        p.changeDynamics(self.ground, -1, lateralFriction=real.foot_friction, physicsClientId=c)
        if real.restitution > 0:
            p.changeDynamics(self.ground, -1, restitution=real.restitution, physicsClientId=c)
        z0 = spec.nominal_height + self.ground_z + 0.01
        with quiet():
            self.robot = p.loadURDF(perturbed_urdf(self.model.urdf, real),
                                    [self.start_x, 0, z0], [0, 0, 0, 1],
                                    flags=p.URDF_USE_INERTIA_FROM_FILE
                                    | (0 if self.visuals else p.URDF_IGNORE_VISUAL_SHAPES),
                                    physicsClientId=c)
        names = {p.getJointInfo(self.robot, j, physicsClientId=c)[1].decode(): j
                 for j in range(p.getNumJoints(self.robot, physicsClientId=c))}
        links = {p.getJointInfo(self.robot, j, physicsClientId=c)[12].decode(): j
                 for j in range(p.getNumJoints(self.robot, physicsClientId=c))}
        # link index -> name (-1: the base), for the fall reason "body touched the ground: link …"
        self.link_names = {j: name for name, j in links.items()}
        self.link_names[-1] = p.getBodyInfo(self.robot, physicsClientId=c)[0].decode()
        self.joint_ids = [names[j] for j in spec.joint_names]
        self.foot_ids = [links[f] for f in spec.foot_links]
        # the velocity motors hold at most joint_friction [N·m] (0: off): Coulomb joint friction
        p.setJointMotorControlArray(self.robot, self.joint_ids, p.VELOCITY_CONTROL,
                                    targetVelocities=[0.0] * 12,
                                    forces=[real.joint_friction] * 12, physicsClientId=c)
        for j in range(-1, p.getNumJoints(self.robot, physicsClientId=c)):
            p.changeDynamics(self.robot, j, linearDamping=0, angularDamping=0, physicsClientId=c)
        for f in self.foot_ids:
            p.changeDynamics(self.robot, f, lateralFriction=1.0, physicsClientId=c)
        if real.restitution > 0:  # PyBullet multiplies the two bodies' coefficients
            for j in range(-1, p.getNumJoints(self.robot, physicsClientId=c)):
                p.changeDynamics(self.robot, j, restitution=1.0, physicsClientId=c)
        if real.joint_damping > 0:
            for j in self.joint_ids:
                p.changeDynamics(self.robot, j, jointDamping=real.joint_damping, physicsClientId=c)
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
        self._stepped = False      # no step since the state was saved

    def _zero_base_velocity(self) -> None:
        p.resetBaseVelocity(self.robot, [0, 0, 0], [0, 0, 0], physicsClientId=self.cid)

    def _restore(self) -> None:
        # restoreState keeps the broadphase's overlapping pairs. With the plane (an infinite
        # box) they never change; the heightfield's box is finite, so links leaving and
        # re-entering it reorder them, and a rollout's last bits would follow the rollouts run
        # before it in this world (other costs for --workers 1 and 2). Hills rebuild the
        # client once stepped (a few hundredths of a second): every rollout starts as the
        # first one in a new world.
        if self._stepped and self.heights is not None:
            with stdout_to_stderr():
                p.disconnect(physicsClientId=self.cid)
                self._build()
        p.restoreState(self._saved, physicsClientId=self.cid)
        self._stepped = True

    def true_state(self) -> RobotState:
        """The exact state of the robot (base inertial frame, see :class:`RobotState`)."""
        c, r = self.cid, self.robot
        pos, quat = p.getBasePositionAndOrientation(r, physicsClientId=c)
        vel, omega = p.getBaseVelocity(r, physicsClientId=c)
        js = p.getJointStates(r, self.joint_ids, physicsClientId=c)
        q, dq = np.array([j[0] for j in js]), np.array([j[1] for j in js])
        x, y, z, w = quat
        finite = math.isfinite(pos[0] + pos[1] + pos[2] + vel[0] + vel[1] + vel[2])
        # up_z = (R_inertial · RTᵀ)[2, 2]: row 2 of the inertial frame's rotation, times column 2
        # of the inertial -> link correction
        c = self._RT_col2
        up_z = 2.0 * (x * z - w * y) * c[0] + 2.0 * (y * z + w * x) * c[1] \
            + (1.0 - 2.0 * (x * x + y * y)) * c[2]
        return RobotState(np.array(pos), np.array(quat), np.array(vel), np.array(omega), q, dq,
                          up_z, finite, self._RT)

    def _drive(self, tau: np.ndarray) -> None:
        self.apply_list(tau.tolist())

    def apply_list(self, tau: list[float]) -> None:
        """Set the 12 joint torques [N·m] acting in the next step as they are (no reality)."""
        p.setJointMotorControlArray(self.robot, self.joint_ids, p.TORQUE_CONTROL, forces=tau,
                                    physicsClientId=self.cid)

    def _push(self, f: np.ndarray) -> None:
        pos, _ = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        p.applyExternalForce(self.robot, -1, f.tolist(), pos, p.WORLD_FRAME, physicsClientId=self.cid)

    def _raw_step(self) -> None:
        p.stepSimulation(physicsClientId=self.cid)

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

    def foot_positions(self) -> np.ndarray:
        """(4, 3) world positions of the foot links' frames [m] (true, no noise)."""
        states = p.getLinkStates(self.robot, self.foot_ids, physicsClientId=self.cid)
        return np.array([st[4] for st in states])

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame from a camera following the robot (CPU renderer). A world
        without visual shapes renders its twin (built on the first call) in this pose."""
        if not self.visuals:
            return self._posed_twin().render(width, height)
        pos, _ = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        view = p.computeViewMatrixFromYawPitchRoll(pos, 1.0 + 1.5 * self.spec.nominal_height,
                                                   50, -25, 0, 2, physicsClientId=self.cid)
        proj = p.computeProjectionMatrixFOV(60, width / height, 0.05, 20, physicsClientId=self.cid)
        with stdout_to_stderr():
            img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                   physicsClientId=self.cid)
        return np.asarray(img[2], dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    def _posed_twin(self) -> World:
        """The world with visual shapes, its robot in this robot's base pose and joint angles."""
        if self._twin is None:
            self._twin = World(self.spec, self.terrain, seed=self.seed, dt=self.dt,
                               reality=self.reality, visuals=True)
        t = self._twin
        pos, orn = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
        p.resetBasePositionAndOrientation(t.robot, pos, orn, physicsClientId=t.cid)
        states = p.getJointStates(self.robot, self.joint_ids, physicsClientId=self.cid)
        for j, st in zip(t.joint_ids, states):
            p.resetJointState(t.robot, j, st[0], 0.0, physicsClientId=t.cid)
        return t

    def close(self) -> None:
        if self._twin is not None:
            self._twin.close()
            self._twin = None
        if self.cid is not None:
            try:
                with stdout_to_stderr():
                    p.disconnect(physicsClientId=self.cid)
            except p.error:
                pass
            self.cid = None
