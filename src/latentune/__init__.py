"""latentune: high-dimensional controller tuning through latent representations.

Phase 1 tunes the full weight vector θ of a system (a built-in simulated quadruped, :class:`Task`,
or any :class:`System`) with a critic (TuRBO-m); phase 2 trains a VAE on the θ whose trial did not
fail; phase 3 tunes in the VAE's latent space, on the same or another system. :class:`Study` runs
the phases on a resumable run directory; :func:`minimize` is the critic alone.

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
    "ParameterSpace": "latentune.space",
    "System": "latentune.system",
    "FunctionSystem": "latentune.system",
    "Outcome": "latentune.system",
    "load_system": "latentune.system",
    "Study": "latentune.study",
    "Suggestion": "latentune.study",
    "LatentSpace": "latentune.latent.vae",
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
