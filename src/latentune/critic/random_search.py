"""Baselines: uniform random search and scrambled Sobol search on the unit box.

Both return the warm-start points ``x0`` (tag ``-2``) first. Tags: ``RandomSearch`` tags a
point with its ask generation, ``SobolSearch`` with its index in the scrambled Sobol sequence.
Resume is exact: after telling a stored history (with tags) a fresh critic of the same seed asks
exactly the batch the original would have asked next.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from latentune.critic.base import X0_TAG, Critic


class _X0First(Critic):
    """Shared handling of ``x0``: returned first, marked with tag -2."""

    def __init__(self, dim: int, **kw: Any) -> None:
        super().__init__(dim, **kw)
        self._x0_left = 0 if self.x0 is None else self.x0.shape[0]

    def _take_x0(self, n: int) -> np.ndarray:
        if self.x0 is None or self._x0_left == 0:
            return np.empty((0, self.dim))
        k0 = self.x0.shape[0] - self._x0_left
        k = min(n, self._x0_left)
        self._x0_left -= k
        return self.x0[k0:k0 + k]

    def _tell_x0(self, tags: np.ndarray) -> None:
        if self.x0 is not None:
            told = int(np.count_nonzero(self._tags == X0_TAG))
            self._x0_left = min(self._x0_left, max(self.x0.shape[0] - told, 0))


class RandomSearch(_X0First):
    """Uniform random search: each ask draws i.i.d. U[0, 1]^dim points.

    The points of ask number ``g`` come from ``numpy.random.default_rng([seed, g])``; their tag
    is ``g``.
    """

    method = "random"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        self._gen = 0

    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        g = self._gen
        self._gen += 1
        X0 = self._take_x0(n)
        rng = np.random.default_rng([self.seed, g])
        Xr = rng.random((n - X0.shape[0], self.dim))
        tags = np.concatenate([np.full(X0.shape[0], X0_TAG), np.full(Xr.shape[0], g)])
        return np.vstack([X0, Xr]), tags

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        if (tags >= 0).any():
            self._gen = max(self._gen, int(tags.max()) + 1)
        self._tell_x0(tags)


class SobolSearch(_X0First):
    """Scrambled Sobol sequence (Owen scrambling, ``torch.quasirandom.SobolEngine``).

    The sequence is fixed by ``seed``; a point's tag is its index in the sequence.
    """

    method = "sobol"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        self._next = 0

    def _sobol(self, start: int, n: int) -> np.ndarray:
        from torch.quasirandom import SobolEngine

        eng = SobolEngine(self.dim, scramble=True, seed=self.seed)
        if start:
            eng.fast_forward(start)
        return eng.draw(n, dtype=_f64()).numpy()

    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        X0 = self._take_x0(n)
        m = n - X0.shape[0]
        Xs = self._sobol(self._next, m) if m else np.empty((0, self.dim))
        tags = np.concatenate([np.full(X0.shape[0], X0_TAG), np.arange(self._next, self._next + m)])
        self._next += m
        return np.vstack([X0, Xs]), tags

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        if (tags >= 0).any():
            self._next = max(self._next, int(tags.max()) + 1)
        self._tell_x0(tags)


def _f64():
    import torch

    return torch.float64
