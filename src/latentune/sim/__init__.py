"""PyBullet world: ground (flat plane or Perlin hills), a quadruped, stepping at 1 kHz, state reads."""
from latentune.sim.world import RobotState, World, perlin_heightfield

__all__ = ["World", "RobotState", "perlin_heightfield"]
