"""The actor protocol: a controller that maps the measured state to 12 joint torques at 1 kHz."""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from latentune.space import ParameterSpace
from latentune.robots import RobotSpec
from latentune.sim.world import RobotState, World


class ActorFailure(RuntimeError):
    """The controller cannot produce a command (e.g. infeasible QP): the rollout counts it as a fall."""


class Actor(ABC):
    """A tunable controller. ``theta`` is given in physical units (see :class:`ParameterSpace`).

    Subclasses define :meth:`space` (the tuned vector for a robot × gait) and :meth:`control`.
    """

    name: str = "actor"

    @classmethod
    @abstractmethod
    def space(cls, spec: RobotSpec, gait: str) -> ParameterSpace:
        """The ParameterSpace of this actor on this robot × gait (bounds, scales, manual θ)."""

    @abstractmethod
    def __init__(self, world: World, gait: str, v_des: np.ndarray, theta: np.ndarray) -> None: ...

    @abstractmethod
    def control(self, step: int, state: RobotState) -> np.ndarray:
        """(12,) joint torques [N·m] for physics step ``step`` given the measured state.

        Raises:
            ActorFailure: no valid command (counted as a fall at this step).
        """
