"""latentune: high-dimensional controller tuning for legged robots through latent representations.

Phase 1 tunes the full MPC weight vector θ with an actor–critic loop (MPC in PyBullet × TuRBO-m),
phase 2 trains a VAE on the stable θ, phase 3 tunes in the VAE's latent space.

Heavy modules (torch, pybullet) are imported lazily so ``import latentune`` stays cheap.
"""
from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "Task": "latentune.task",
    "RolloutResult": "latentune.task",
    "path_cost": "latentune.task",
    "ParameterSpace": "latentune.actor.parameter_space",
    "RobotSpec": "latentune.robots",
    "get_robot": "latentune.robots",
    "minimize": "latentune.optimize",
    "OptimizeResult": "latentune.optimize",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'latentune' has no attribute {name!r}")


__all__ = list(_LAZY) + ["__version__"]
