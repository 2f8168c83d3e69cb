"""Task = robot × gait × terrain × actor × v_des × horizon; a rollout and its path cost.

Path cost (paper Eq. 2 with the running cost of its §IV): over N_H physics steps at 1 kHz,

* the robot never fell:   L = sqrt( Σ_{i=1..N_H} ‖v_i − v_des‖² )   (v_i: base CoM velocity, world),
  capped just below C1 (a robot that never fell but tracks very badly stays "stable")
* it fell at step k:      L = C1 · (2 − k / N_H),  C1 = 100, and the rollout stops there.

So L < C1 ⇔ stable. Fallen: base height above the ground outside [0.5, 2.5]·h_nom, tilt above
``max_tilt_deg``, a non-foot link touching the ground, a non-finite state or a base speed above
:data:`BLOWUP_SPEED` (the simulator blew up: PyBullet clamps velocities at 100 m/s), or an actor
failure (infeasible QP) — never an exception.

A Task may run on another physics engine (``engine="mujoco"``) and in a perturbed reality
(``reality=``: a preset name, a YAML file, a dict or a :class:`~latentune.sim.reality.Reality`):
the actor sees the world's noisy sensor view, the cost and the fall detector the true state.
"""
from __future__ import annotations

import importlib
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from latentune.actor.base import Actor, ActorFailure
from latentune.checks import is_whole
from latentune.constants import C1, GAITS, STABLE_CAP, TERRAINS, fail_cost
from latentune.errors import UsageError
from latentune.robots import RobotSpec, get_robot
from latentune.space import ParameterSpace, task_tuned_for
from latentune.system import Outcome

__all__ = ["Task", "RolloutResult", "path_cost", "actor_class", "ACTORS", "C1", "MAX_STEPS",
           "MAX_V_DES", "BLOWUP_SPEED"]
BLOWUP_SPEED = 50.0
"""A base speed above this [m/s] is a simulator blow-up, counted as a fall (legged robots move
at a few m/s; a blown-up PyBullet world jumps between ±100 m/s at finite positions)."""
MAX_STEPS = 10_000_000
"""The longest rollout horizon (10,000 s at 1 kHz): a rollout holds a few arrays of this length."""
MAX_V_DES = 3.0
"""The largest desired velocity a Task takes [m/s] (the size of its 3-vector)."""
ACTORS = {
    "convex": "latentune.actor.convex_mpc:ConvexMPC",
    "kinodynamic": "latentune.actor.kinodynamic:KinodynamicMPC",
}


def actor_class(name: str) -> type[Actor]:
    """The actor class registered under ``name`` (``convex`` or ``kinodynamic``)."""
    if name not in ACTORS:
        raise UsageError(f"unknown actor {name!r} (choose from {', '.join(ACTORS)})")
    mod, cls = ACTORS[name].split(":")
    try:
        return getattr(importlib.import_module(mod), cls)
    except ImportError as exc:
        raise UsageError(f"actor {name!r} is not available here ({exc})") from None


def path_cost(vel: np.ndarray, v_des: np.ndarray, fall_step: int | None, horizon: int) -> float:
    """Path cost of a rollout.

    Args:
        vel: (n, 3) base CoM velocities [m/s] of the executed steps.
        v_des: (3,) desired velocity [m/s].
        fall_step: step k at which the robot fell (1-based count of executed steps), or None.
        horizon: N_H, the planned number of steps.
    """
    if fall_step is not None:
        return fail_cost(fall_step, horizon)
    err = np.asarray(vel, dtype=float) - np.asarray(v_des, dtype=float)
    # A robot that never fell but tracks terribly (seen: B1 running backwards at 1.1 m/s) could
    # exceed C1; cap it just below so that L < C1 ⇔ stable holds for every rollout.
    return min(float(math.sqrt(float(np.sum(err * err)))), STABLE_CAP)


def _finite_mean(a: np.ndarray) -> float:
    """The mean of ``a``'s finite entries (a blown-up step's NaN is no sample; NaN is no JSON
    number); 0.0 when there are none."""
    m = float(np.mean(a)) if a.size else 0.0
    if math.isfinite(m):
        return m
    a = a[np.isfinite(a)]
    return float(np.mean(a)) if a.size else 0.0


@dataclass
class RolloutResult:
    """Outcome of one rollout.

    Attributes:
        cost: path cost L (see module docstring).
        fell: the robot fell (⇔ cost ≥ C1).
        fall_step: step at which it fell, or None.
        steps: steps executed.
        mean_vx: mean forward base velocity over the last 3 s (or the whole run if shorter) [m/s].
        mean_height: mean base height above the ground over the same window [m].
        wall_s: wall-clock time of the rollout [s].
        reason: why it fell ('' if it did not).
        trace: per-step arrays when recorded: t (n,), pos (n, 3), vel (n, 3), rpy (n, 3).
    """

    cost: float
    fell: bool
    fall_step: int | None
    steps: int
    mean_vx: float
    mean_height: float
    wall_s: float
    reason: str = ""
    trace: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def info(self, horizon: int) -> dict[str, Any]:
        """The JSON-able details stored with a trial (everything but cost, fell and trace)."""
        return {"fall_step": self.fall_step, "horizon": int(horizon), "steps": self.steps,
                "mean_vx": self.mean_vx, "mean_height": self.mean_height,
                "rms_vel_error": self.rms_vel_error, "reason": self.reason}

    @property
    def rms_vel_error(self) -> float | None:
        """RMS of ‖v − v_des‖ over the horizon [m/s] (cost / sqrt(N_H)); None after a fall."""
        return None if self.fell else float(self.cost / math.sqrt(max(self.steps, 1)))

    def summary(self) -> dict[str, Any]:
        return {"cost": self.cost, "fell": self.fell, "fall_step": self.fall_step,
                "steps": self.steps, "mean_vx": self.mean_vx, "mean_height": self.mean_height,
                "wall_s": self.wall_s, "reason": self.reason}


class Task:
    """A tuning task: ``Task(robot="a1", gait="trot", terrain="flat", actor="convex")``.

    ``task.rollout(theta)`` takes θ in the unit box ((d,) array) and returns a
    :class:`RolloutResult`; ``task(theta)`` returns only the cost. The PyBullet world is built
    lazily, once per process, and restored between rollouts; a Task pickles without it, so it can
    be sent to worker processes.

    ``reality`` (a preset name, a YAML file, a dict or a :class:`~latentune.sim.reality.Reality`;
    None: nominal) perturbs the simulated robot; ``engine`` is ``"pybullet"`` (default) or
    ``"mujoco"``. Both are recorded in :meth:`config` when they are not the defaults; the
    reality's random parts are seeded from ``seed``.
    """

    def __init__(self, robot: str | RobotSpec = "a1", gait: str = "trot", terrain: str = "flat",
                 actor: str = "convex", v_des: float | tuple[float, float, float] = 0.5,
                 steps: int = 5000, seed: int = 0, reality: Any = None,
                 engine: str = "pybullet"):
        if not isinstance(robot, (str, os.PathLike, RobotSpec, dict)):
            raise UsageError(f"robot must be a name, a spec file or a RobotSpec, got {robot!r}")
        self.spec = get_robot(robot)
        if not isinstance(gait, str) or gait not in GAITS:
            raise UsageError(f"unknown task {gait!r} (choose from {', '.join(GAITS)})")
        self.spec.gait(gait)
        if not isinstance(terrain, str) or terrain not in TERRAINS:
            raise UsageError(f"unknown terrain {terrain!r} (choose from {', '.join(TERRAINS)})")
        if not isinstance(actor, str):
            raise UsageError(f"unknown actor {actor!r} (choose from {', '.join(ACTORS)})")
        self.actor_cls = actor_class(actor)
        try:
            if isinstance(v_des, (str, bytes, bool, np.bool_)) or any(
                    isinstance(x, (str, bytes, bool, np.bool_)) for x in np.ravel(v_des)):
                raise TypeError
            v = np.array([v_des, 0.0, 0.0] if np.isscalar(v_des) else v_des, dtype=float)
            if v.shape != (3,):
                raise ValueError
        except (TypeError, ValueError):
            raise UsageError(f"v_des must be a number or a 3-vector [m/s], got {v_des!r}") from None
        if not np.all(np.isfinite(v)) or math.hypot(*v) > MAX_V_DES:  # hypot: no overflow
            raise UsageError(f"v_des must be a finite velocity of at most {MAX_V_DES:g} m/s")
        if not is_whole(steps, 1):
            raise UsageError(f"steps must be a positive integer, got {steps!r}")
        if steps > MAX_STEPS:
            raise UsageError(f"steps must be at most {MAX_STEPS:,} (10,000 s at 1 kHz), got {steps}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) \
                or not 0 <= seed < 2 ** 63:
            raise UsageError(f"seed must be an integer in [0, 2**63), got {seed!r}")
        from latentune.sim.reality import Reality, profile_file
        from latentune.sim.world import ENGINES

        if not isinstance(engine, str) or engine not in ENGINES:
            raise UsageError(f"unknown engine {engine!r} (choose from {', '.join(ENGINES)})")
        if engine == "mujoco":
            from latentune.sim.mujoco_world import require_mujoco

            require_mujoco()
        self.reality = Reality.load(reality)
        self.reality_file = profile_file(reality)
        if engine == "mujoco":
            from latentune.sim.mujoco_world import MAX_RESTITUTION

            if self.reality.restitution > MAX_RESTITUTION:   # contact_solref would cap it
                raise UsageError(f"reality {self.reality.name!r}: MuJoCo takes a restitution of at "
                                 f"most {MAX_RESTITUTION:.3g} (its contacts blow up beyond), got "
                                 f"{self.reality.restitution:g}; use the pybullet engine for more")
        if self.reality.latency_steps >= steps:     # the first command would act throughout
            raise UsageError(f"reality {self.reality.name!r}: latency_steps "
                             f"{self.reality.latency_steps} is not shorter than the rollout's "
                             f"{steps} steps: no command of the controller would act (lower "
                             "latency_steps or give more steps)")
        self.engine = engine
        self.robot_name = self.spec.name
        self.gait = gait
        self.terrain = terrain
        self.actor = actor
        self.v_des = v
        self.steps = int(steps)
        self.seed = int(seed)
        self.space: ParameterSpace = self.actor_cls.space(self.spec, gait)
        self.space.tuned_for = task_tuned_for(self.robot_name, gait, actor)
        self._world = None

    # pickling: drop the PyBullet client
    def __getstate__(self) -> dict:
        d = self.__dict__.copy()
        d["_world"] = None
        return d

    def config(self) -> dict[str, Any]:
        """JSON-able description of the task (recorded with every run)."""
        from latentune.robots import is_builtin

        cfg = {"robot": self.robot_name, "gait": self.gait, "terrain": self.terrain,
               "actor": self.actor, "v_des": self.v_des.tolist(), "steps": self.steps,
               "seed": self.seed, "dim": self.space.dim}
        if not is_builtin(self.spec):
            cfg["spec"] = self.spec.to_dict()
        if not self.reality.is_nominal:
            cfg["reality"] = self.reality.to_dict()
            if self.reality_file is not None:       # where it was read: a resume suggests it
                cfg["reality_file"] = self.reality_file
        if self.engine != "pybullet":
            cfg["engine"] = self.engine
        return cfg

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> "Task":
        """Rebuild a Task from :meth:`config`'s dict (a stored run's ``config["task"]``).

        A custom robot is rebuilt from the spec stored with it (``cfg["spec"]``), so a run
        directory can be reported on another machine without the robot's YAML file."""
        robot: Any = cfg["robot"]
        if cfg.get("spec") is not None:
            from latentune.robots import spec_from_dict

            robot = spec_from_dict(cfg["spec"])
        task = cls(robot=robot, gait=cfg["gait"], terrain=cfg["terrain"], actor=cfg["actor"],
                   v_des=tuple(cfg["v_des"]), steps=int(cfg["steps"]), seed=int(cfg["seed"]),
                   reality=cfg.get("reality"), engine=cfg.get("engine", "pybullet"))
        task.reality_file = cfg.get("reality_file")
        return task

    def cache_key(self) -> str:
        """Evaluator workers keep one Task (one simulator client) per key."""
        import json

        return json.dumps(self.config(), sort_keys=True, default=str)

    def evaluate(self, theta: np.ndarray) -> Outcome:
        """The :class:`~latentune.system.System` protocol: one rollout as an Outcome
        (cost = path cost, failed = fell; info: fall_step, horizon, steps, mean_vx, mean_height,
        rms_vel_error [m/s], reason)."""
        res = self.rollout(theta)
        return Outcome(res.cost, res.fell, res.info(self.steps), res.wall_s)

    def world_key(self) -> tuple:
        """What a world depends on: robot (every field of its spec, not only its name: a custom
        robot may be named like a built-in one), terrain, seed, engine and reality (not the
        gait): tasks with equal keys can share one world (:meth:`use_world`)."""
        import json

        return (json.dumps(self.spec.to_dict(), sort_keys=True, default=str), self.terrain,
                self.seed, self.engine, json.dumps(self.reality.to_dict(), sort_keys=True))

    def use_world(self, world: Any) -> None:
        """Run this task's rollouts in ``world``, a World of the same robot, terrain and seed
        built by another task (a world does not depend on the gait; building one takes seconds).
        Raises UsageError for a world of another robot, terrain, engine or reality."""
        if (world.spec, world.terrain) != (self.spec, self.terrain):   # the spec, not its name
            raise UsageError("use_world needs a world of the same robot and terrain")
        if (getattr(world, "engine", "pybullet"), getattr(world, "reality", self.reality)) \
                != (self.engine, self.reality):
            raise UsageError("use_world needs a world of the same engine and reality")
        self._world = world

    @property
    def world(self):
        if self._world is None:
            from latentune.sim import make_world

            self._world = make_world(self.spec, self.terrain, seed=self.seed,
                                     reality=self.reality, engine=self.engine)
        return self._world

    def __call__(self, theta: np.ndarray) -> float:
        return self.rollout(theta).cost

    def rollout(self, theta: np.ndarray, record: bool = False, gif: str | None = None,
                gif_fps: int = 10) -> RolloutResult:
        """Simulate ``steps`` physics steps with unit-box θ; see the module docstring for the cost."""
        from threadpoolctl import threadpool_limits

        theta = self.space.validate_unit(theta)
        t0 = time.perf_counter()
        with threadpool_limits(1):
            res = self._run(theta, record, gif, gif_fps)
        res.wall_s = time.perf_counter() - t0
        return res

    def _run(self, theta: np.ndarray, record: bool, gif: str | None, gif_fps: int) -> RolloutResult:
        world = self.world
        world.reset()
        N = self.steps
        h_nom = self.spec.nominal_height
        cos_tilt = math.cos(math.radians(self.spec.max_tilt_deg))
        vel = np.zeros((N, 3))
        height = np.zeros(N)
        rec = {"pos": np.zeros((N, 3)), "rpy": np.zeros((N, 3))} if record else None
        frames = []
        frame_every = max(1, int(round(1.0 / (gif_fps * world.dt)))) if gif else 0
        fall_step: int | None = None
        reason = ""
        try:
            actor = self.actor_cls(world, self.gait, self.v_des, self.space.to_physical(theta))
        except ActorFailure as exc:
            actor, fall_step, reason = None, 1, f"actor: {exc}"
        n = 0
        s = world.true_state()  # the cost and the fall detector see the true state ...
        flat = world.terrain == "flat"
        h_lo, h_hi = 0.5 * h_nom, 2.5 * h_nom
        v_max2 = BLOWUP_SPEED ** 2
        while actor is not None and n < N:
            try:
                tau = actor.control(n, world.observe(s))  # ... the actor its sensors' view
                if not math.isfinite(tau.sum()):
                    raise ActorFailure("non-finite torque")
            except (ActorFailure, np.linalg.LinAlgError, FloatingPointError) as exc:
                fall_step, reason = n + 1, f"actor: {exc}"
                break
            world.apply(tau)
            world.step()
            s = world.true_state()
            n += 1
            vel[n - 1] = s.vel
            pos = s.pos
            h = pos[2] if flat else pos[2] - world.ground_height(pos[0], pos[1])
            height[n - 1] = h
            if rec is not None:
                rec["pos"][n - 1] = pos
                rec["rpy"][n - 1] = s.rpy
            if frame_every and (n - 1) % frame_every == 0:
                frames.append(world.render())
            v = s.vel
            if not (s.finite and abs(h) < 1e3):
                fall_step, reason = n, "simulator blow-up (non-finite state)"
            elif v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > v_max2:
                fall_step, reason = n, (f"simulator blow-up (base speed "
                                        f"{math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]):.0f} m/s)")
            elif not (h_lo <= h <= h_hi):
                fall_step, reason = n, f"base height {h:.3f} m outside [{h_lo:.3f}, {h_hi:.3f}]"
            elif s.up_z < cos_tilt:
                fall_step, reason = n, f"tilt above {self.spec.max_tilt_deg:g} deg"
            elif n % 10 == 0 and (link := world.body_ground_contact()) is not None:
                fall_step, reason = n, f"body touched the ground: link {link}"
            if fall_step is not None:
                break
        n_exec = n      # steps executed: after an actor failure, one fewer than its fall_step
        vel = vel[:n_exec]
        height = height[:n_exec]
        cost = path_cost(vel, self.v_des, fall_step, N)
        win = max(1, min(n_exec, int(round(3.0 / world.dt))))
        mean_vx = _finite_mean(vel[-win:, 0])
        mean_h = _finite_mean(height[-win:])
        trace: dict[str, np.ndarray] = {}
        if rec is not None:
            trace = {"t": np.arange(1, n_exec + 1) * world.dt, "vel": vel.copy(),
                     "pos": rec["pos"][:n_exec], "rpy": rec["rpy"][:n_exec], "height": height.copy()}
        if gif:
            import imageio.v2 as imageio

            if not frames:             # the actor failed before a step: where it stands
                frames.append(world.render())

            # imageio's GIF writer (pillow) takes each frame's duration in milliseconds
            imageio.mimsave(gif, frames, duration=1000.0 / gif_fps, loop=0)
        return RolloutResult(cost=cost, fell=fall_step is not None, fall_step=fall_step,
                             steps=n_exec, mean_vx=mean_vx, mean_height=mean_h, wall_s=0.0,
                             reason=reason, trace=trace)
