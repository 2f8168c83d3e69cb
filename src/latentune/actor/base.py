"""The actor protocol: a controller that maps the measured state to 12 joint torques at 1 kHz."""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from latentune.space import ParameterSpace
from latentune.robots import RobotSpec
from latentune.sim.world import RobotState, World


class ActorFailure(RuntimeError):
    """The controller cannot produce a command (e.g. infeasible QP): the rollout counts it as a fall."""


QP_INF = 1e30
""""No bound" for the QP solvers (DAQP and OSQP both read ±1e30 as infinite)."""


def friction_pyramid(nc: int, mu: float, f_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Friction pyramids and force bounds of ``nc`` contact forces (x, y, z each, any unit).

    Returns (A (4·nc, 3·nc), lower (7·nc,), upper (7·nc,)) in DAQP's layout: simple bounds on
    the 3·nc variables first (|f_x|, |f_y| ≤ μ f_max, 0 ≤ f_z ≤ f_max), then the rows of A,
    f_x − μ f_z ≤ 0 ≤ f_x + μ f_z and the same for f_y.
    """
    n = 3 * nc
    A = np.zeros((4 * nc, n))
    r = np.arange(nc)
    for a in range(2):  # x and y
        A[4 * r + 2 * a, 3 * r + a] = 1.0
        A[4 * r + 2 * a, 3 * r + 2] = -mu
        A[4 * r + 2 * a + 1, 3 * r + a] = 1.0
        A[4 * r + 2 * a + 1, 3 * r + 2] = mu
    lb = np.tile([-mu * f_max, -mu * f_max, 0.0], nc)
    ub = np.tile([mu * f_max, mu * f_max, f_max], nc)
    cl = np.tile([-QP_INF, 0.0, -QP_INF, 0.0], nc)
    cu = np.tile([0.0, QP_INF, 0.0, QP_INF], nc)
    return A, np.concatenate([lb, cl]), np.concatenate([ub, cu])


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
