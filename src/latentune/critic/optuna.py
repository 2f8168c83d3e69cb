"""Optuna's samplers as latentune critics: :class:`OptunaCritic` runs TPE (multivariate), CMA-ES
(with ``source_trials``, Optuna's transfer mode) or GPSampler behind the critic protocol on the
unit box, so the phase loop, the store and resume treat them as latentune's own methods
(``optuna-tpe``, ``optuna-cmaes``, ``optuna-gp`` of :meth:`Study.phase1
<latentune.study.Study.phase1>`): the baselines a user would pick instead. Needs the ``optuna``
extra; latentune's samplers for Optuna studies are in :mod:`latentune.integrations.optuna`.

As stock tools, the samplers are told each trial's own cost (a non-finite one as the worst
finite cost before it, or as a failed trial when none is finite before it), failed or not, as a user of Optuna would; only :attr:`best_index
<latentune.critic.base.Critic.best_index>` ranks the failed trials last, as every critic's."""
from __future__ import annotations

import logging
import math
import warnings
from typing import Any, Mapping, Sequence

import numpy as np

from latentune.critic.base import Critic
from latentune.errors import UsageError

try:
    import optuna
except ImportError:  # pragma: no cover - the extra is not installed
    raise ImportError("latentune's Optuna critics need Optuna: "
                      "pip install 'latentune[optuna]'") from None

logger = logging.getLogger(__name__)


BASELINE_SAMPLERS = ("tpe", "cmaes", "gp")
"""Optuna samplers :class:`OptunaCritic` runs: ``tpe`` (``TPESampler(multivariate=True)``),
``cmaes`` (``CmaEsSampler``; with source trials its warm-start mode, WS-CMA-ES) and ``gp``
(``GPSampler``)."""

_NUM = 1 << 20
CMAES_SOURCE_MIN = 10
"""The fewest source trials with a finite cost ``cmaes`` takes: its warm start (Optuna's
``source_trials``, ``cmaes.get_warm_start_mgd``) starts from the best 10 % of them."""


def baseline_sampler(name: str, seed: int, *, x0: Mapping[str, float] | None = None,
                     source_trials: Sequence[Any] | None = None) -> Any:
    """The Optuna sampler of a baseline: ``"tpe"`` → ``TPESampler(multivariate=True, seed)``;
    ``"cmaes"`` → ``CmaEsSampler(seed)`` with ``source_trials`` (Optuna's transfer mode: the
    initial mean, step size and covariance from the best of a related task's trials) or else
    with its mean at ``x0`` (params by name); ``"gp"`` → ``GPSampler(seed)``. UsageError for
    another name."""
    if name == "tpe":
        return optuna.samplers.TPESampler(multivariate=True, seed=int(seed))
    if name == "gp":
        return optuna.samplers.GPSampler(seed=int(seed))
    if name == "cmaes":
        if source_trials:
            return optuna.samplers.CmaEsSampler(source_trials=list(source_trials), seed=int(seed))
        return optuna.samplers.CmaEsSampler(x0=None if x0 is None else dict(x0), seed=int(seed))
    raise UsageError(f"unknown Optuna baseline sampler {name!r} (choose from "
                     f"{', '.join(BASELINE_SAMPLERS)})")


class _Quiet:
    """Optuna's per-trial INFO lines, its experimental-feature warnings and the deprecation of
    ``CmaEsSampler(x0=...)`` silenced inside the block (the previous verbosity is restored)."""

    def __enter__(self) -> "_Quiet":
        self._level = optuna.logging.get_verbosity()
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
        # CmaEsSampler's x0 (its initial mean) is deprecated in Optuna 4.9+, still supported in 5
        warnings.filterwarnings("ignore", message=r".*`x0` has been deprecated",
                                category=FutureWarning)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._w.__exit__(*exc)
        optuna.logging.set_verbosity(self._level)


class OptunaCritic(Critic):
    """An Optuna sampler behind latentune's ask/tell protocol on the unit box ``[0, 1]^dim``:
    the baselines users would pick instead of latentune, run by the same phase loop, store and
    resume as latentune's own critics.

    The critic keeps an in-memory Optuna study with one ``FloatDistribution(0, 1)`` per θ entry
    (``x000``, ``x001``, ...). ``x0`` rows are enqueued (its first trials); ``source`` = (X (m,
    dim), y (m,)) unit-box trials of a related task become the sampler's ``source_trials``
    (``cmaes`` only; non-finite costs left out; at least :data:`CMAES_SOURCE_MIN` left).
    ``ask`` asks the study; ``tell`` tells each point's trial its cost (a non-finite cost as the
    worst finite cost told so far, or as failed before any); an untagged point is added as a completed trial.

    Tags: ``told · 2**20 + number`` — the Optuna trial number and how many trials had been told
    when it was asked. Resume: a fresh critic told points it did not ask re-asks its trials in
    number order, telling the stored costs in number order up to each trial's ``told`` count
    first, so the sampler sees the original sequence of asks and tells (its seed then gives
    the same points); a re-asked trial whose point differs from the stored one (a sampler that
    is not deterministic) is failed and the stored point added as a completed trial. Trials
    re-asked but not told (lost in a stop) are served first by the next ``ask``.

    Args:
        dim, batch_size, seed, x0: see :class:`~latentune.critic.base.Critic`.
        sampler: one of :data:`BASELINE_SAMPLERS`.
        source: the source trials of ``cmaes``'s transfer mode.
    """

    method = "optuna"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None, sampler: str = "tpe",
                 source: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        super().__init__(dim, batch_size=batch_size, seed=seed, x0=x0)
        if sampler not in BASELINE_SAMPLERS:
            raise UsageError(f"unknown Optuna baseline sampler {sampler!r} (choose from "
                             f"{', '.join(BASELINE_SAMPLERS)})")
        if source is not None and sampler != "cmaes":
            raise UsageError("source trials are an option of the cmaes sampler")
        self.sampler = sampler
        self.method = f"optuna-{sampler}"
        self.names = [f"x{i:03d}" for i in range(self.dim)]
        self.distributions = {n: optuna.distributions.FloatDistribution(0.0, 1.0)
                              for n in self.names}
        src_trials = None
        if source is not None:
            Xs, ys = np.asarray(source[0], dtype=float), np.asarray(source[1], dtype=float)
            if Xs.ndim != 2 or Xs.shape[1] != self.dim or len(ys) != len(Xs):
                raise UsageError(f"source trials must be (m, {self.dim}) points with m costs, "
                                 f"got {Xs.shape} and {ys.shape}")
            Xs = np.clip(Xs, 0.0, 1.0)
            src_trials = [optuna.trial.create_trial(params=self._params(x),
                                                    distributions=self.distributions,
                                                    value=float(c))
                          for x, c in zip(Xs, ys) if math.isfinite(c)]
            if len(src_trials) < CMAES_SOURCE_MIN:
                raise UsageError(f"the source trials hold {len(src_trials)} finite cost(s): "
                                 "CMA-ES's warm start (Optuna's source_trials) starts from their "
                                 f"best 10 %, so it needs at least {CMAES_SOURCE_MIN}")
        mean = None if self.x0 is None else self._params(self.x0[0])
        with _Quiet():
            self.study = optuna.create_study(
                direction="minimize",
                sampler=baseline_sampler(sampler, self.seed, x0=mean, source_trials=src_trials))
            for row in ([] if self.x0 is None else self.x0):
                self.study.enqueue_trial(self._params(row))
        self._trials: dict[int, Any] = {}      # number -> asked trial not told yet
        self._serve: list[int] = []            # re-asked on resume, not told: served first
        self._n_told = 0                       # trials told to the study
        self._max_asked = -1
        self._warned = False

    def _params(self, x: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, x)}

    def _ask_one(self) -> Any:
        with _Quiet():
            trial = self.study.ask(self.distributions)
        self._trials[trial.number] = trial
        self._max_asked = max(self._max_asked, trial.number)
        trial.set_user_attr("latentune_told_before", self._n_told)
        return trial

    def _point(self, trial: Any) -> np.ndarray:
        return np.array([trial.params[n] for n in self.names], dtype=float)

    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        X, T = [], []
        for _ in range(n):
            trial = self._trials[self._serve.pop(0)] if self._serve else self._ask_one()
            X.append(self._point(trial))
            T.append(int(trial.user_attrs["latentune_told_before"]) * _NUM + trial.number)
        return np.array(X), np.array(T, dtype=np.int64)

    def _value(self, i: int) -> float | None:
        """The value told for point ``i``: its cost; a non-finite cost as the worst finite one
        before it; None (the trial is told as failed, which the samplers leave out) when none
        is finite before it (it was told 0.0, a best value for positive costs)."""
        y = float(self._y[i])
        if math.isfinite(y):
            return y
        prev = self._y[: i][np.isfinite(self._y[: i])]
        return float(prev.max()) if prev.size else None

    def _tell_trial(self, number: int, i: int) -> None:
        trial = self._trials.pop(number)
        with _Quiet():
            if np.allclose(self._point(trial), self._X[i], rtol=0.0, atol=1e-12):
                v = self._value(i)
                if v is None:
                    self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
                else:
                    self.study.tell(trial, v)
            else:                       # a re-asked trial that is not the stored one
                if not self._warned:
                    logger.warning("%s: a re-asked trial differs from the stored one (the "
                                   "sampler is not deterministic); the stored point is added "
                                   "as it is", self.method)
                    self._warned = True
                self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
                self._add(i)
                return
        self._n_told += 1

    def _add(self, i: int) -> None:
        with _Quiet():
            v = self._value(i)
            self.study.add_trial(optuna.trial.create_trial(
                params=self._params(self._X[i]), distributions=self.distributions, value=v,
                state=optuna.trial.TrialState.COMPLETE if v is not None
                else optuna.trial.TrialState.FAIL))
        self._n_told += 1

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        replay: dict[int, tuple[int, int]] = {}       # number -> (told before, index)
        for i, t in zip(idx, tags):
            if t < 0:
                self._add(int(i))
                continue
            told, number = divmod(int(t), _NUM)
            if number in self._trials and number not in self._serve:
                self._tell_trial(number, int(i))
            else:
                replay[number] = (told, int(i))
        if replay:
            self._replay(replay)

    def _replay(self, entries: dict[int, tuple[int, int]]) -> None:
        """Re-ask the trials ``entries`` names (number -> (told before, index of its stored
        point)) and the ones before them, telling stored costs in number order as the
        original did (see the class docstring)."""
        waiting: dict[int, int] = {}                  # re-asked number -> stored index

        def flush(upto: int | None) -> None:
            for num in sorted(waiting):
                if upto is not None and self._n_told >= upto:
                    return
                self._serve = [s for s in self._serve if s != num]
                self._tell_trial(num, waiting.pop(num))

        for number in sorted(entries):
            told, i = entries[number]
            if number in self._trials:                # re-asked earlier (served), not told
                self._serve = [s for s in self._serve if s != number]
                waiting[number] = i
                continue
            while self._max_asked < number:
                flush(told)
                trial = self._ask_one()
                if trial.number != number:
                    self._serve.append(trial.number)
            waiting[number] = i
        flush(None)

