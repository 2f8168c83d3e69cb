"""CMA-ES (pycma) behind the ask/tell protocol, bounded to the unit box.

* ``pycma.CMAEvolutionStrategy`` with ``bounds=[0, 1]`` (its BoundTransform),
  ``sigma0 = 1/6`` (from the centre, ``mean ± 3·sigma0`` spans the box: pycma's rule of
  thumb for the initial step, and Optuna's ``CmaEsSampler`` default) and
  ``popsize = max(4 + ⌊3 ln d⌋, batch_size)`` unless given: pycma's default population, enlarged
  to the batch so that one ask does not sample two generations from the same distribution. The
  population is independent of the batch otherwise: an ask serves the current generation's
  points and samples the next generation only when they are used up. The initial mean is
  ``x0[0]`` (else the box centre) and all ``x0`` rows are injected into the first generation.
  ``benchmarks.peers`` compares these defaults with Optuna's CMA-ES and pycma called
  directly (results in ``results/peers/``).
* Randomness: generation ``g`` samples with ``numpy.random.default_rng([seed, g])`` through
  pycma's ``randn`` option; pycma's global-seed path is disabled (``seed=nan``), so the global
  numpy state is neither used nor touched.
* Tags: ``tag = told·2**20 + g`` (:func:`encode_tag`): the point's generation ``g`` and the
  number of generations already passed to pycma when ``g`` was sampled. ``ask(n)`` serves
  points from the current generation and samples a new one when it is used up (so with a
  population that is not a multiple of the batch, a generation can be sampled before the
  previous one is complete). A generation is passed to pycma's ``tell`` once all its
  ``popsize`` points have been told (in any number of tell calls), in generation order.
* Untagged points (``tags=None``) and points of generations the ``es`` never sampled are fed to
  pycma's ``tell`` as foreign solutions (pycma repairs them), in chunks of ``popsize``.
* Resume: when a fresh critic is told generations it did not ask, it re-samples them in order
  with the same generators, each one after passing to pycma as many complete generations as the
  original had when it sampled it (read from the tag), so the sequence of pycma asks and tells
  and hence every re-sampled point is the original's; told points that equal the re-sampled
  ones are recognized by pycma exactly as in the original run. Replaying a history therefore
  restores the same mean, step size and covariance; the last generation's points that were not
  told (not asked yet, or lost) are served first, so the next ``ask`` returns the same batch.
  (Exact for a history whose generations were completed in generation order; untagged points
  are passed to pycma at the end of each ``tell``.)
* When pycma's termination criteria fire, the strategy restarts from a uniformly random mean
  (generator ``[seed, 1, restart]``) with ``sigma0``; the history is kept.
* pycma is given :meth:`~latentune.critic.base.Critic.ranked_costs`: non-finite costs as the
  worst finite cost seen so far, and the failed trials ranked after every trial that stood.

Screening (:meth:`~latentune.critic.base.Critic.screen_with`, e.g. a fall model)
--------------------------------------------------------------------------------
pycma updates only on complete generations of ``popsize`` points, so dropping points would stop
it: the batch policy is ``"complete"``. Each generation is sampled whole and screened when it is
sampled; members predicted to fall (probability ``p > max_fall_prob``; the ``x0`` rows are never
screened) are not asked (not evaluated) but are passed to pycma, once the generation's evaluated
members have all been told, with the cost ``M + 1 + p`` (``M`` = the largest finite cost of the
evaluated members of this and all earlier screened generations), i.e. ranked below every
evaluated member and among themselves by ``p``. Every generation has at least one evaluated
member (the one with the lowest ``p`` if none is under the threshold). A generation is screened
with the model fitted on the untagged told points and the evaluated members of the generations
already passed to pycma when it was sampled (the number its tag records), so a resumed critic
re-samples and re-screens the same generations. (Untagged points told after the first ask enter
a generation's screening from the next generation on in the original run but at once in a
resumed one.)
"""
from __future__ import annotations

import contextlib
import warnings
from typing import Any, Iterator

import numpy as np

from latentune.critic.base import EXEMPT, Critic, ScreenReport


_GEN = 1 << 20


@contextlib.contextmanager
def _cma_warnings_filtered() -> Iterator[None]:
    """Silence pycma's known, handled warnings inside the block (and only those): a sampling
    standard deviation clipped to the box's limits and an initial step size larger than the box
    (the box is [0, 1]^d by construction)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Sampling standard deviation i=",
                                category=UserWarning)
        warnings.filterwarnings("ignore", message=r"\s*Initial standard deviation",
                                category=UserWarning)
        yield


def encode_tag(generation: int, told: int) -> int:
    """CMA-ES tag of a point: its ``generation`` and the number of generations ``told`` to pycma
    before that generation was sampled."""
    return int(told) * _GEN + int(generation)


def decode_tag(tag: int) -> tuple[int, int]:
    """Inverse of :func:`encode_tag`: ``(generation, told)``."""
    return int(tag) % _GEN, int(tag) // _GEN


def default_popsize(dim: int) -> int:
    """pycma's (and Hansen's) default population ``4 + ⌊3 ln dim⌋``."""
    return 4 + int(3.0 * np.log(dim))


class CMAES(Critic):
    """CMA-ES on [0, 1]^dim (see the module docstring).

    Args:
        dim, batch_size, seed, x0: see :class:`~latentune.critic.base.Critic`.
        sigma0: initial step size in unit-box coordinates (default 1/6).
        popsize: population size (default ``max(4 + ⌊3 ln dim⌋, batch_size)``).
        cma_options: extra pycma options (override the defaults set here).
    """

    method = "cma"
    batch_policy = "complete"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None, sigma0: float = 1.0 / 6.0,
                 popsize: int | None = None,
                 cma_options: dict[str, Any] | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        if not (np.isfinite(sigma0) and sigma0 > 0):
            raise ValueError(f"sigma0 must be > 0, got {sigma0!r}")
        self.sigma0 = float(sigma0)
        self.popsize = (int(popsize) if popsize is not None
                        else max(default_popsize(self.dim), self.batch_size))
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
        self._gen_told: dict[int, int] = {}     # generation -> generations told when sampled
        self._tag_told: dict[int, int] = {}     # the same, read from told tags (resume)
        self._n_gen_told = 0                    # generations passed to pycma's tell
        self.n_restarts = 0
        self._n_rearm = 0
        # screening (see "Screening"): generation -> (evaluated mask, p, over mask, active)
        self._screened: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, bool]] = {}
        self._untagged: list[int] = []          # told indices without a tag
        self._passed: list[int] = []            # told members of generations passed to pycma
        self._max_real = -np.inf                # largest finite cost of evaluated members
        self._n_new_screened = 0
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
        with _cma_warnings_filtered():
            return cma.CMAEvolutionStrategy(np.asarray(mean, dtype=float).tolist(),
                                            self.sigma0, opts)

    def _sample_generation(self, g: int) -> np.ndarray:
        """Let the current es sample generation ``g`` with its own generator: (popsize, dim)."""
        if self._es.stop() and self._es.countiter > 0:
            self.n_restarts += 1
            mean = np.random.default_rng([self.seed, 1, self.n_restarts]).random(self.dim)
            self._es = self._new_es(mean)
        self._rng = np.random.default_rng([self.seed, 2, g])
        with _cma_warnings_filtered():
            pop = np.asarray(self._es.ask(), dtype=float)
        self._es_gen = g
        self._gen_es[g] = self.n_restarts
        self._gen_told[g] = self._n_gen_told
        self._sampled[g] = pop
        if self._screen is not None:
            self._screen_generation(g, pop)
        return pop

    def _screen_generation(self, g: int, pop: np.ndarray) -> None:
        """Screen a freshly sampled generation (see "Screening")."""
        screen = self._screen.screen
        basis = np.asarray(self._untagged + self._passed, dtype=np.int64)
        pred = screen.predictor(basis)
        if pred is None:
            p = np.zeros(pop.shape[0])
        else:
            p = np.maximum(np.asarray(pred(pop), dtype=float), 1e-300)
        tags = np.full(pop.shape[0], encode_tag(g, self._gen_told[g]), dtype=np.int64)
        ex = self.screen_roles(pop, tags) == EXEMPT
        thr = float(screen.max_fall_prob)
        real = ex | (p <= thr)
        if not real.any():
            real[int(np.argmin(p))] = True
        self._screened[g] = (real, p, real & ~ex & (p > thr), pred is not None)
        self._n_new_screened += int(np.count_nonzero(~real))

    def _asked_rows(self, g: int) -> np.ndarray:
        """The members of sampled generation ``g`` that asks return (all without a screen)."""
        pop = self._sampled.get(g, np.empty((0, self.dim)))
        return pop[self._screened[g][0]] if g in self._screened and pop.shape[0] else pop

    def _screened_ask(self, n: int) -> tuple[np.ndarray, np.ndarray, ScreenReport]:
        """The ``"complete"`` policy: generations are screened as they are sampled."""
        self._n_new_screened = 0
        X, T = self._checked_ask(n)
        p, n_over = np.full(n, np.nan), 0
        for k, (x, t) in enumerate(zip(X, T)):
            g = decode_tag(int(t))[0]
            if g not in self._screened:
                continue
            real, pg, over, active = self._screened[g]
            j = int(np.flatnonzero(np.all(self._sampled[g] == x, axis=1))[0])
            p[k] = pg[j] if active else np.nan
            n_over += int(over[j])
        return X, T, ScreenReport(p, n_over, self._n_new_screened)

    def _es_tell(self, X: np.ndarray, y: np.ndarray) -> None:
        with _cma_warnings_filtered():
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
                self._sample_generation(g)
                self._queue = [(x, g) for x in self._asked_rows(g)]
            x, g = self._queue.pop(0)
            out.append(x)
            tags.append(encode_tag(g, self._gen_told[g]))
        return np.asarray(out), np.asarray(tags, dtype=np.int64)

    def _tell_complete(self, limit: int | None) -> None:
        """Pass complete sampled generations to pycma in generation order (at most until
        ``limit`` generations have been passed in total)."""
        yfill = self.ranked_costs()
        for g in sorted(self._pending):
            if g >= self._gen or (limit is not None and self._n_gen_told >= limit):
                break
            members = self._pending[g]
            screened = self._screened.pop(g, None) if g in self._screened else None
            if len(members) < (self.popsize if screened is None else int(screened[0].sum())):
                if screened is not None:
                    self._screened[g] = screened
                continue
            del self._pending[g]
            pop = self._sampled.pop(g, None)
            if self._gen_es.get(g) != self.n_restarts:
                self._foreign.extend(members)   # sampled by an es that has since restarted
                continue
            Xg, yg = self._X[members], yfill[members]
            if screened is not None and pop is not None:
                fin = yg[np.isfinite(self._y[members])]
                if fin.size:
                    self._max_real = max(self._max_real, float(fin.max()))
                M = self._max_real if np.isfinite(self._max_real) else 0.0
                virtual = ~screened[0] & ~np.array([np.any(np.all(Xg == x, axis=1))
                                                   for x in pop], dtype=bool)
                Xg = np.vstack([Xg, pop[virtual]])
                yg = np.concatenate([yg, M + 1.0 + screened[1][virtual]])
            self._es_tell(Xg, yg)
            self._passed.extend(members)
            self._n_gen_told += 1

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        self._foreign.extend(int(i) for i, t in zip(idx, tags) if t < 0)
        self._untagged.extend(int(i) for i, t in zip(idx, tags) if t < 0)
        for i, t in zip(idx, tags):
            if t >= 0:
                g, c = decode_tag(int(t))
                self._pending.setdefault(g, []).append(int(i))
                self._tag_told.setdefault(g, c)
        # resume: generations this critic never sampled are re-sampled in order, each after as
        # many generations were passed to pycma as when the original critic sampled it
        top = max(self._pending, default=-1)
        resampled = self._gen <= top
        while self._gen <= top:
            g = self._gen
            self._tell_complete(self._tag_told.get(g, self._n_gen_told))
            self._gen += 1
            self._sample_generation(g)
        self._tell_complete(None)
        if resampled:     # the last generation's points not told yet are asked next
            g = self._gen - 1
            self._queue = [(x, g) for x in self._asked_rows(g)]
        if self._queue:   # a queued point told already (a replay in several tells) is dropped
            told = self._X[idx]
            self._queue = [(x, g) for x, g in self._queue
                           if not np.any(np.all(told == x, axis=1))]
            if resampled:
                told = self._X[self._pending.get(self._gen - 1, [])]
                self._queue = [(x, g) for x, g in self._queue
                               if not (told.shape[0] and np.any(np.all(told == x, axis=1)))]
        yfill = self.ranked_costs()
        while len(self._foreign) >= self.popsize:
            chunk, self._foreign = self._foreign[:self.popsize], self._foreign[self.popsize:]
            self._es_tell(self._X[chunk], yfill[chunk])

    @property
    def n_generations_told(self) -> int:
        """Generations passed to pycma's ``tell`` so far."""
        return self._n_gen_told

    @property
    def sigma(self) -> float:
        """Current pycma step size (unit-box coordinates)."""
        return float(self._es.sigma)

    @property
    def mean(self) -> np.ndarray:
        """Current pycma mean (dim,), genotype coordinates."""
        return np.asarray(self._es.mean, dtype=float).copy()
