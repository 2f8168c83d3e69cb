"""Simulated worlds: ground (flat plane or Perlin hills), a quadruped, stepping at 1 kHz, state
reads, on PyBullet (:class:`World`, the default) or MuJoCo
(:class:`~latentune.sim.mujoco_world.MujocoWorld`), both behind :class:`SimWorld`, and the
reality profiles that perturb them (:class:`Reality`)."""
from __future__ import annotations

from latentune.errors import UsageError
from latentune.sim.reality import PRESETS, Reality
from latentune.sim.world import ENGINES, RobotState, SimWorld, World, perlin_heightfield

__all__ = ["World", "RobotState", "SimWorld", "Reality", "PRESETS", "ENGINES", "make_world",
           "perlin_heightfield"]


def make_world(spec, terrain: str = "flat", seed: int = 0, reality: Reality | None = None,
               engine: str = "pybullet", dt: float = 0.001) -> SimWorld:
    """A world of ``engine`` (one of :data:`ENGINES`) with the robot ``spec`` on ``terrain``
    (seed: terrain, noise and pushes), perturbed by ``reality`` (None: nominal), step ``dt`` [s].

    Raises:
        UsageError: unknown engine, or mujoco not installed.
    """
    if engine == "pybullet":
        return World(spec, terrain, seed=seed, dt=dt, reality=reality)
    if engine == "mujoco":
        from latentune.sim.mujoco_world import MujocoWorld

        return MujocoWorld(spec, terrain, seed=seed, dt=dt, reality=reality)
    raise UsageError(f"unknown engine {engine!r} (choose from {', '.join(ENGINES)})")
