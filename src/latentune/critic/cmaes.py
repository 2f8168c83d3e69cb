"""CMA-ES (pycma) behind the ask/tell protocol, bounded to the unit box.

* ``pycma.CMAEvolutionStrategy`` with ``bounds=[0, 1]`` (its BoundTransform), ``sigma0=0.3``,
  ``popsize = max(batch_size, 2)`` unless given; the initial mean is ``x0[0]`` (else the box
  centre) and all ``x0`` rows are injected into the first generation.
* Randomness: generation ``g`` samples with ``numpy.random.default_rng([seed, g])`` through
  pycma's ``randn`` option; pycma's global-seed path is disabled (``seed=nan``), so the global
  numpy state is neither used nor touched.
* Tags: a point's tag is its generation number ``g``. ``ask(n)`` serves points from the current
  generation and samples a new one when it is used up. A generation is passed to pycma's
  ``tell`` once all its ``popsize`` points have been told (in any number of tell calls).
* Untagged points (``tags=None``) and points of generations the ``es`` never sampled are fed to
  pycma's ``tell`` as foreign solutions (pycma repairs them), in chunks of ``popsize``.
* Resume: when a fresh critic is told a generation it did not ask, it first re-samples that
  generation with the same generator (same ``es`` state by induction, so the same points), then
  tells it; told points that equal the re-sampled ones are recognized by pycma exactly as in the
  original run. Replaying a history therefore restores the same mean, step size and covariance,
  and the next ``ask`` returns the same batch.
* When pycma's termination criteria fire, the strategy restarts from a uniformly random mean
  (generator ``[seed, 1, restart]``) with ``sigma0``; the history is kept.
* Non-finite costs are given to pycma as the worst finite cost seen so far.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from latentune.critic.base import Critic, fill_nonfinite


class CMAES(Critic):
    """CMA-ES on [0, 1]^dim (see the module docstring).

    Args:
        dim, batch_size, seed, x0: see :class:`~latentune.critic.base.Critic`.
        sigma0: initial step size in unit-box coordinates.
        popsize: population size (default ``max(batch_size, 2)``).
        cma_options: extra pycma options (override the defaults set here).
    """

    method = "cma"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None, sigma0: float = 0.3, popsize: int | None = None,
                 cma_options: dict[str, Any] | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        if not (np.isfinite(sigma0) and sigma0 > 0):
            raise ValueError(f"sigma0 must be > 0, got {sigma0!r}")
        self.sigma0 = float(sigma0)
        self.popsize = int(popsize) if popsize is not None else max(self.batch_size, 2)
        if self.popsize < 2:
            raise ValueError(f"popsize must be >= 2, got {popsize!r}")
        self._cma_options = dict(cma_options or {})
        self._rng = np.random.default_rng([self.seed, 0])
        self._gen = 0                       # next generation number to sample
        self._es_gen = -1                   # last generation sampled by the current es
        self._queue: list[tuple[np.ndarray, int]] = []   # asked-not-yet-returned points
        self._pending: dict[int, list[int]] = {}          # generation -> told indices
        self._foreign: list[int] = []                     # untagged / orphan told indices
        self._gen_es: dict[int, int] = {}                 # generation -> restart id
        self._sampled: dict[int, np.ndarray] = {}         # generation -> sampled points
        self.n_restarts = 0
        self._n_rearm = 0
        mean0 = self.x0[0] if self.x0 is not None else np.full(self.dim, 0.5)
        self._es = self._new_es(mean0)
        if self.x0 is not None:
            self._es.inject(list(self.x0), force=True)

    # ------------------------------------------------------------------ internals
    def _randn(self, *shape: int) -> np.ndarray:
        return self._rng.standard_normal(shape)

    def _new_es(self, mean: np.ndarray):
        import cma

        opts = {"bounds": [0.0, 1.0], "popsize": self.popsize, "seed": np.nan,
                "randn": self._randn, "verbose": -9, "tolflatfitness": 10,
                "CMA_diagonal": False}
        opts.update(self._cma_options)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return cma.CMAEvolutionStrategy(np.asarray(mean, dtype=float).tolist(),
                                            self.sigma0, opts)

    def _sample_generation(self, g: int) -> np.ndarray:
        """Let the current es sample generation ``g`` with its own generator: (popsize, dim)."""
        if self._es.stop() and self._es.countiter > 0:
            self.n_restarts += 1
            mean = np.random.default_rng([self.seed, 1, self.n_restarts]).random(self.dim)
            self._es = self._new_es(mean)
        self._rng = np.random.default_rng([self.seed, 2, g])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pop = np.asarray(self._es.ask(), dtype=float)
        self._es_gen = g
        self._gen_es[g] = self.n_restarts
        self._sampled[g] = pop
        return pop

    def _es_tell(self, X: np.ndarray, y: np.ndarray) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if getattr(self._es, "_flgtelldone", False):
                # pycma allows one tell per ask; when two tells follow each other (foreign
                # points, or asynchronous generations) a throw-away ask with its own
                # deterministic generator re-arms it (it samples but changes no state)
                self._n_rearm += 1
                self._rng = np.random.default_rng([self.seed, 5, self._n_rearm])
                self._es.ask()
            self._es.tell(list(X), list(y))

    # ------------------------------------------------------------------ protocol
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        out: list[np.ndarray] = []
        tags: list[int] = []
        while len(out) < n:
            if not self._queue:
                g = self._gen
                self._gen += 1
                self._queue = [(x, g) for x in self._sample_generation(g)]
            x, g = self._queue.pop(0)
            out.append(x)
            tags.append(g)
        return np.asarray(out), np.asarray(tags, dtype=np.int64)

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        yfill = fill_nonfinite(self._y)
        gens = sorted({int(t) for t in tags if t >= 0})
        self._foreign.extend(int(i) for i, t in zip(idx, tags) if t < 0)
        for g in gens:
            self._pending.setdefault(g, []).extend(int(i) for i, t in zip(idx, tags) if t == g)
        # replay: generations this critic never sampled are re-sampled in order first
        for g in sorted(self._pending):
            members = self._pending[g]
            if len(members) < self.popsize:
                continue
            if g >= self._gen:  # never sampled here (resume): reproduce the sampling
                while self._gen <= g:
                    gg = self._gen
                    self._gen += 1
                    self._sample_generation(gg)
                self._queue = []
            del self._pending[g]
            if self._gen_es.get(g) != self.n_restarts:
                self._foreign.extend(members)   # sampled by an es that has since restarted
                continue
            self._es_tell(self._X[members], yfill[members])
            self._sampled.pop(g, None)
        while len(self._foreign) >= self.popsize:
            chunk, self._foreign = self._foreign[:self.popsize], self._foreign[self.popsize:]
            self._es_tell(self._X[chunk], yfill[chunk])

    @property
    def sigma(self) -> float:
        """Current pycma step size (unit-box coordinates)."""
        return float(self._es.sigma)

    @property
    def mean(self) -> np.ndarray:
        """Current pycma mean (dim,), genotype coordinates."""
        return np.asarray(self._es.mean, dtype=float).copy()
