"""Critics: optimizers on the unit box behind one ask/tell protocol (see :mod:`.base`).

``make_critic(method, dim, **kw)`` builds one of:

* ``"turbo"``  -- :class:`~latentune.critic.turbo.TurboM` (TuRBO-m, BoTorch/GPyTorch)
* ``"cma"``    -- :class:`~latentune.critic.cmaes.CMAES` (pycma)
* ``"random"`` -- :class:`~latentune.critic.random_search.RandomSearch`
* ``"sobol"``  -- :class:`~latentune.critic.random_search.SobolSearch`

Implementations are imported lazily so ``import latentune.critic`` stays cheap.
"""
from __future__ import annotations

import importlib
from typing import Any

from latentune.critic.base import UNTAGGED, X0_TAG, Critic, fill_nonfinite, gaussian_copula

METHODS: dict[str, tuple[str, str]] = {
    "turbo": ("latentune.critic.turbo", "TurboM"),
    "cma": ("latentune.critic.cmaes", "CMAES"),
    "random": ("latentune.critic.random_search", "RandomSearch"),
    "sobol": ("latentune.critic.random_search", "SobolSearch"),
}


def critic_class(method: str) -> type[Critic]:
    """The critic class of ``method`` (one of :data:`METHODS`); ``ValueError`` otherwise."""
    if not isinstance(method, str) or method.lower() not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {sorted(METHODS)}")
    module, name = METHODS[method.lower()]
    return getattr(importlib.import_module(module), name)


def make_critic(method: str, dim: int, **kw: Any) -> Critic:
    """Build the critic ``method`` for ``dim`` variables.

    ``kw``: ``batch_size``, ``seed``, ``x0`` and the implementation's options. Unknown method →
    ``ValueError``; unknown option → ``TypeError``.
    """
    return critic_class(method)(dim, **kw)


def __getattr__(name: str) -> Any:
    for module, cls in METHODS.values():
        if cls == name:
            return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module 'latentune.critic' has no attribute {name!r}")


__all__ = ["Critic", "make_critic", "critic_class", "METHODS", "UNTAGGED", "X0_TAG",
           "fill_nonfinite", "gaussian_copula", "TurboM", "CMAES", "RandomSearch", "SobolSearch"]
