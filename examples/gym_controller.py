"""A user-defined controller on a system latentune does not ship: Gymnasium's MuJoCo Hopper.

The controller is a linear state feedback with a bias, ``a = clip(K (o - o_ref) + b, -1, 1)``,
on ``Hopper-v5``'s 11 observations (torso height and angle, three joint angles, six velocities)
and 3 actions (thigh, leg, foot torques): 3 x 11 gains + 3 biases = **36 tuned weights**.

* Bounds: gains on the 5 position/angle observations in [-5, 5], gains on the 6 velocities in
  [-1, 1], biases in [-1, 1] (all linear). ``o_ref`` is the initial pose (height 1.25 m, all
  angles 0), so a zero gain matrix is "no feedback".
* Manual θ: a hand-written joint PD that holds the initial pose, ``K[j, angle_j] = -2``,
  ``K[j, velocity_j] = -0.3``, everything else 0. It stands still for the whole episode
  (return ≈ 400 in 400 steps: the healthy reward only) and never hops; nothing better was
  known, and phase 1 has to discover hopping forward.
* A trial is one episode of ``episode_steps`` control steps (default 400 = 3.2 s of simulated
  time, about 0.04 s of wall time) from ``env.reset(seed=seed)``, so a θ always gets the same
  cost. ``failed`` = the episode terminated early (Hopper's "unhealthy" termination: the robot
  fell or its state left the healthy range). ``cost = 100 · exp(-return / 1000)``: in (0, 100)
  for any return ≥ 0, lower is better. A failed trial costs the same with its return less
  ``FALL_PENALTY`` = 200 (a fall also ends the episode early and so loses the healthy reward of
  the remaining steps): the C1 = 100 convention for failed trials is not used.

The "real" Hopper (:func:`make_real_system`) is the same controller on a perturbed plant:
body masses x1.3, friction x0.6, actuator gear x0.8, Gaussian observation noise and a one-step
action delay (see :class:`HopperSystem`).

Use it from the repository root::

    latentune tune --system examples.gym_controller:make_system --out runs/hopper \\
        --phase1-evals 200 --phase3-evals 40 --workers 1 --backend serial
    latentune phase3 --system examples.gym_controller:make_real_system --vae runs/hopper \\
        --out runs/hopper-real --phase3-evals 40 --workers 1 --backend serial
    python -m examples.gym_controller            # phases 1-3 through the Python API

Needs ``pip install "gymnasium[mujoco]"`` (Gymnasium 1.x with the ``mujoco`` wheel; the Hopper
model file ships with Gymnasium, nothing is downloaded at run time).
"""
from __future__ import annotations

import math
import sys
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()  # before numpy: MuJoCo steps and the controller are tiny operations

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402

if __package__ in (None, ""):                   # run as a file: python examples/gym_controller.py
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from examples import checked_steps  # noqa: E402

ENV_ID = "Hopper-v5"
OBS_NAMES = ("z", "torso", "thigh", "leg", "foot",
             "vx", "vz", "w_torso", "w_thigh", "w_leg", "w_foot")
ACT_NAMES = ("thigh", "leg", "foot")
N_POS = 5                                   # observations 0..4 are positions/angles
O_REF = np.array([1.25] + [0.0] * 10)       # Hopper's initial pose: the feedback's set point
KP_MANUAL, KD_MANUAL = 2.0, 0.3             # the manual joint PD
C_SCALE = 1000.0                            # cost = 100 exp(-return / C_SCALE)
FALL_PENALTY = 200.0                        # return lost by a failed episode (a fall)


def hopper_space() -> lt.ParameterSpace:
    """The 36 weights: ``k_<action>_<observation>`` (33 gains) and ``bias_<action>`` (3)."""
    names, low, high, manual = [], [], [], []
    for j, act in enumerate(ACT_NAMES):
        for i, obs in enumerate(OBS_NAMES):
            lim = 5.0 if i < N_POS else 1.0
            names.append(f"k_{act}_{obs}")
            low.append(-lim)
            high.append(lim)
            if i == 2 + j:                     # own joint angle
                manual.append(-KP_MANUAL)
            elif i == N_POS + 3 + j:           # own joint velocity
                manual.append(-KD_MANUAL)
            else:
                manual.append(0.0)
    for act in ACT_NAMES:
        names.append(f"bias_{act}")
        low.append(-1.0)
        high.append(1.0)
        manual.append(0.0)
    return lt.ParameterSpace(names, low, high, manual=manual)


def return_to_cost(ret: float, failed: bool = False) -> float:
    """The cost of an episode: ``100 · exp(-return / 1000)``, lower is better; a failed episode
    (a fall) first loses :data:`FALL_PENALTY` of its return (its cost is at most 100)."""
    r = float(ret) - (FALL_PENALTY if failed else 0.0)
    return float(100.0 * math.exp(-max(r, 0.0) / C_SCALE))


class HopperSystem:
    """The linear controller on ``Hopper-v5``, optionally perturbed (a latentune System).

    Args:
        seed: the episode's reset seed (initial-state noise) and the observation-noise seed:
            a θ always gets the same cost.
        episode_steps: control steps per trial (0.008 s each).
        mass_scale, friction_scale, gear_scale: factors on every body mass, every geom's
            sliding friction and every actuator gear, set on ``env.unwrapped.model`` after
            the environment is made.
        obs_noise: standard deviation of Gaussian noise on the 5 position/angle observations
            [m, rad]; the 6 velocities get 10x that [m/s, rad/s].
        action_delay: control steps between computing an action and applying it (zeros at
            first).

    The MuJoCo environment is made on the first trial of each process (not pickled), so the
    system works with the process and Ray backends too.
    """

    def __init__(self, seed: int = 0, episode_steps: int = 400, mass_scale: float = 1.0,
                 friction_scale: float = 1.0, gear_scale: float = 1.0, obs_noise: float = 0.0,
                 action_delay: int = 0, name: str = "model") -> None:
        checked_steps(episode_steps, "episode_steps")
        checked_steps(action_delay, "action_delay", 0)
        checked_steps(seed, "seed", 0)                  # gymnasium refuses a negative seed
        for k, v in (("mass_scale", mass_scale), ("friction_scale", friction_scale),
                     ("gear_scale", gear_scale)):
            if not (math.isfinite(float(v)) and float(v) > 0):
                raise ValueError(f"{k} must be a finite number > 0, got {v}")
        if not (math.isfinite(float(obs_noise)) and float(obs_noise) >= 0):
            raise ValueError(f"obs_noise must be >= 0, got {obs_noise}")
        self.space = hopper_space()
        self.seed = int(seed)
        self.episode_steps = int(episode_steps)
        self.mass_scale = float(mass_scale)
        self.friction_scale = float(friction_scale)
        self.gear_scale = float(gear_scale)
        self.obs_noise = float(obs_noise)
        self.action_delay = int(action_delay)
        self.name = str(name)
        self._env: Any = None

    # the environment is per process: never pickled
    def __getstate__(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["_env"] = None
        return d

    def env(self) -> Any:
        """The (perturbed) unwrapped MuJoCo environment of this process."""
        if self._env is None:
            import gymnasium as gym

            env = gym.make(ENV_ID).unwrapped
            m = env.model
            m.body_mass[:] *= self.mass_scale
            m.body_inertia[:] *= self.mass_scale       # same density: inertia scales with mass
            m.geom_friction[:, 0] *= self.friction_scale
            m.actuator_gear[:, 0] *= self.gear_scale
            self._env = env
        return self._env

    def gains(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit-box θ -> (K (3, 11), b (3,)) in physical units."""
        x = self.space.to_physical(self.space.validate_unit(theta))
        n = len(OBS_NAMES) * len(ACT_NAMES)
        return x[:n].reshape(len(ACT_NAMES), len(OBS_NAMES)), x[n:]

    def rollout(self, theta: np.ndarray) -> dict[str, Any]:
        """One episode at unit-box θ: return, steps, whether it terminated, distance."""
        K, b = self.gains(theta)
        env = self.env()
        rng = np.random.default_rng(self.seed + 7919)
        sigma = self.obs_noise * np.r_[np.ones(N_POS), 10.0 * np.ones(len(OBS_NAMES) - N_POS)]
        obs, _ = env.reset(seed=self.seed)
        x0 = float(env.data.qpos[0])
        queue = [np.zeros(len(ACT_NAMES))] * self.action_delay
        ret, terminated, steps = 0.0, False, 0
        for steps in range(1, self.episode_steps + 1):
            o = obs + (sigma * rng.standard_normal(obs.shape) if self.obs_noise else 0.0)
            a = np.clip(K @ (o - O_REF) + b, -1.0, 1.0)
            if self.action_delay:
                queue.append(a)
                a = queue.pop(0)
            obs, r, terminated, _, _ = env.step(a)
            ret += float(r)
            if terminated or not np.all(np.isfinite(obs)):
                terminated = True
                break
        dist = float(env.data.qpos[0]) - x0
        return {"return": ret, "steps": steps, "terminated": bool(terminated), "distance": dist,
                "mean_vx": dist / (steps * env.dt)}

    def evaluate(self, theta: np.ndarray) -> lt.Outcome:
        r = self.rollout(theta)
        info = {"return": round(r["return"], 4), "steps": r["steps"],
                "distance": round(r["distance"], 4), "mean_vx": round(r["mean_vx"], 4)}
        if r["terminated"]:
            info.update(fall_step=r["steps"], horizon=self.episode_steps, reason="unhealthy")
        return lt.Outcome(return_to_cost(r["return"], r["terminated"]), failed=r["terminated"],
                          info=info)

    def config(self) -> dict[str, Any]:
        """What a study records of this system (compared on resume)."""
        return {"env": ENV_ID, "name": self.name, "seed": self.seed,
                "episode_steps": self.episode_steps, "mass_scale": self.mass_scale,
                "friction_scale": self.friction_scale, "gear_scale": self.gear_scale,
                "obs_noise": self.obs_noise, "action_delay": self.action_delay}

    def __repr__(self) -> str:
        return f"HopperSystem({self.name}, {self.config()})"


REAL = {"mass_scale": 1.3, "friction_scale": 0.6, "gear_scale": 0.8, "obs_noise": 0.01,
        "action_delay": 1}
"""The "real" Hopper's perturbation of the model."""


def make_system(seed: int = 0, episode_steps: int = 400) -> HopperSystem:
    """The model: the nominal ``Hopper-v5`` (``--system examples.gym_controller:make_system``)."""
    return HopperSystem(seed=seed, episode_steps=episode_steps, name="model")


def make_real_system(seed: int = 0, episode_steps: int = 400, mass_scale: float = 1.3,
                     friction_scale: float = 0.6, gear_scale: float = 0.8,
                     obs_noise: float = 0.01, action_delay: int = 1) -> HopperSystem:
    """The "real" Hopper: the model perturbed as in :data:`REAL` (each factor can be changed)."""
    return HopperSystem(seed=seed, episode_steps=episode_steps, mass_scale=mass_scale,
                        friction_scale=friction_scale, gear_scale=gear_scale,
                        obs_noise=obs_noise, action_delay=action_delay, name="real")


COUNT_ARGS = ("phase1_evals", "phase3_evals", "sim_trials", "trials", "episode_steps",
              "workers")
"""The options of the Hopper examples' command lines that are counts (>= 1)."""


def check_args(a: Any) -> None:
    """UsageError for a Hopper example's argument (``a``: its parsed arguments) that would be
    refused only after trials ran: a count of :data:`COUNT_ARGS` below 1, a negative
    ``--seed``, a ``--latent-dim`` outside [1, 35] (the latent space is smaller than the 36
    weights)."""
    from latentune.errors import UsageError

    for dest in COUNT_ARGS:
        v = getattr(a, dest, None)
        if v is not None and v < 1:
            raise UsageError(f"--{dest.replace('_', '-')} must be >= 1, got {v}")
    if a.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {a.seed}")
    dim = len(hopper_space().names)
    if not 1 <= a.latent_dim < dim:
        raise UsageError(f"--latent-dim must be in [1, {dim - 1}] (smaller than the {dim} "
                         f"weights), got {a.latent_dim}")


def main(argv: list[str] | None = None) -> int:
    """Phases 1-3 through the Python API at a small budget; prints the comparison table. A bad
    argument, or an ``--out`` of another run (another seed, episode length or latent size), is
    one line on stderr and exit 2."""
    import argparse

    from latentune.errors import LatentuneError

    ap = argparse.ArgumentParser(prog="examples.gym_controller",
                                 description="latentune on a 36-weight Hopper-v5 controller")
    ap.add_argument("--out", default="runs/examples/hopper", help="study directory (resumes)")
    ap.add_argument("--phase1-evals", type=int, default=120)
    ap.add_argument("--phase3-evals", type=int, default=40)
    ap.add_argument("--latent-dim", type=int, default=5)
    ap.add_argument("--episode-steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    try:
        check_args(a)
        return _run(a)
    except LatentuneError as exc:   # an --out of another run, a phase 1 without 2 stable θ, ...
        print(f"{ap.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


def _run(a: Any) -> int:
    """The example's run for the parsed arguments ``a`` (see :func:`main`). The study is
    opened first: an ``--out`` it refuses (a file, a run of another seed) stops before any
    episode."""
    from latentune.study import stderr_log

    system = make_system(seed=a.seed, episode_steps=a.episode_steps)
    with lt.Study(a.out, seed=a.seed, log=stderr_log) as study:
        print(f"{system.space.dim} tuned weights; manual θ: cost "
              f"{system.evaluate(system.space.manual).cost:.2f}", flush=True)
        study.phase1(system, a.phase1_evals)
        study.train_latent(latent_dim=a.latent_dim)
        study.phase3(system, a.phase3_evals)
        study.summary()
        print(study.report(simulate=False))
        best = study.best()
        r = system.rollout(best.theta)
        print(f"\nbest θ (phase {best.phase}, evaluation {best.idx}): cost {best.cost:.2f}, "
              f"return {r['return']:.0f}, {r['distance']:.2f} m in {r['steps']} steps"
              f"{' (fell)' if r['terminated'] else ''}; {study.dir}/phase{best.phase}_best.json")
    return 0


if __name__ == "__main__":
    # run the module's own copy (examples.gym_controller.HopperSystem, not __main__.HopperSystem):
    # a study records the system's class and refuses to resume with another one
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from examples.gym_controller import main as _main

    sys.exit(_main())
