"""Fall-aware critics: a fall model that keeps any critic's suggestions out of regions where
trials are predicted to fail.

:class:`FallAware` wraps a critic (TuRBO-m, CMA-ES, random, Sobol or any other
:class:`~latentune.critic.base.Critic`) and is itself a critic on the same box ``[0, 1]^dim``
with the same ask/tell/tag protocol. It keeps a :class:`~latentune.critic.fall_model.FallModel`
(default :class:`~latentune.critic.fall_model.GPFallModel`, a GP classifier on BoTorch/GPyTorch)
of the ``fell`` flag, fitted on every told point and on optional prior data (e.g. a source run's
stable and fallen θ mapped into this box), and gives it to the inner critic as its *screen*
(:meth:`Critic.screen_with <latentune.critic.base.Critic.screen_with>`): the inner critic
consults the model through the critic protocol's screening hooks and screens its own
candidates, in the way its batch policy states ("Screening hooks" in
:mod:`latentune.critic.base`). The wrapper reads nothing of the inner critic but the protocol.

Asking
------
``ask(n)`` is the inner critic's screened ``ask(n)``:

* until the prior or the told points hold both classes (at least one fell and one not), the
  model predicts nothing and the inner critic's points pass unchanged;
* ``"drop"`` policy (TuRBO-m, random, Sobol, the default): the inner critic proposes
  ``oversample·n`` candidates; those with predicted fall probability ``> max_fall_prob`` are
  dropped and the first ``n`` of the rest are returned in the inner critic's order. If fewer
  than ``n`` survive, the remainder are the candidates with the lowest predicted probability
  (counted in :attr:`FallAware.last_n_over`). Warm-start points are never screened; points the
  critic needs under their tag (TuRBO-m's initial design) are replaced, not dropped;
* ``"complete"`` policy (CMA-ES): generations are sampled whole and screened; screened members
  are told to pycma with a penalty (:mod:`latentune.critic.cmaes`, "Screening").

The model is fitted on the told points the inner critic names (all of them for the ``"drop"``
policy), sorted by (tag, point), so the order of points inside a batch does not matter.

Telling
-------
``tell(X, y, tags=None, fell=None)``: ``fell`` (n,) bool are the trials that failed, data of the
trial like its cost (the pipeline tells the stored flags); when absent, only a non-finite cost
counts as failed (a cost alone cannot say it: each system fails on its own scale). Every told
point goes to the inner critic with its tag and flag, unchanged (a TuRBO-m with ``fall_shrink``
shrinks a region whose batch fell too often: a trust-region rule as a critic hook; the
pipeline's fall-aware TuRBO-m has it, see :func:`latentune.pipeline.phases.make_phase_critic`).

Resume
------
A fresh ``FallAware`` (with a fresh inner critic of the same options and seed, and the same
options and prior) told a stored history ``(X, y, tags, fell)`` -- in one call or in the
original tell calls, in any order within a batch -- asks the same next batch as the original,
whenever the inner critic's own resume is exact (random, Sobol, CMA-ES, TuRBO-m with
``warm_start=False``; TuRBO-m's warm-started hyperparameters are :meth:`state_dict`).
:meth:`state_dict` is ``{"inner": <the inner critic's state_dict>}``, as before the fall model
moved behind the protocol, so stored runs keep resuming.

Asks are synchronous: a second ``ask`` without a ``tell`` in between continues from the first
(new points); after a tell, points asked and not told are dropped (``"drop"``) or asked again
later in the generation's order (CMA-ES, whose generations must be completed).

Diagnostics
-----------
A hyperparameter fit of the fall model that fails keeps the starting hyperparameters; the first
failure is logged by :mod:`latentune.critic.fall_model` and every one is counted in
:meth:`FallAware.stats` (``n_fit_failed``; the inner critic's own counts are under
``inner_stats``). ``python -m benchmarks.fall_avoidance`` measures falls and best costs with and
without the wrapper.
"""
from __future__ import annotations

import logging
from typing import Any, Callable

import numpy as np

from latentune.checks import is_whole
from latentune.critic.base import Critic, as_unit_points
from latentune.critic.fall_model import FallModel, GPFallModel

logger = logging.getLogger(__name__)

_MODE = {"drop": "drop", "complete": "penalise"}


class FallAware(Critic):
    """A critic whose inner critic screens its suggestions with a fall model.

    Args:
        inner: a fresh critic (nothing told yet) on [0, 1]^dim; FallAware takes its ``dim``,
            ``batch_size``, ``seed`` and ``x0``, and gives it itself as its screen.
        max_fall_prob: candidates with predicted fall probability above this are not returned
            (0 < max_fall_prob <= 1; 1 screens nothing).
        prior_X: optional points (m, dim) in [0, 1]^dim with known outcome, e.g. a source run's
            θ mapped into this box; they enter the fall model (:meth:`FallModel.set_prior
            <latentune.critic.fall_model.FallModel.set_prior>`), not the inner critic.
        prior_fell: (m,) bool, whether each prior point's trial failed (required with
            ``prior_X``).
        oversample: candidates the inner critic proposes per returned point (``"drop"``).
        model: the fall model (a fresh :class:`~latentune.critic.fall_model.FallModel` of
            dimension ``dim``); default :class:`~latentune.critic.fall_model.GPFallModel` with
            ``max_points``, ``max_fit_points``, ``refit_fraction`` and ``threads``.
        max_points, max_fit_points, refit_fraction, threads: see
            :class:`~latentune.critic.fall_model.GPFallModel` (only without ``model``).

    Raises ``ValueError`` for bad arguments. See the module docstring for the behaviour.
    """

    method = "fall_aware"

    def __init__(self, inner: Critic, max_fall_prob: float = 0.5,
                 prior_X: np.ndarray | None = None, prior_fell: np.ndarray | None = None,
                 oversample: int = 5, *, model: FallModel | None = None, max_points: int = 1000,
                 max_fit_points: int = 300, refit_fraction: float = 0.2,
                 threads: int | None = 1) -> None:
        if not isinstance(inner, Critic):
            raise ValueError(f"inner must be a Critic, got {type(inner).__name__}")
        if isinstance(inner, FallAware):
            raise ValueError("inner is already a FallAware critic")
        if inner.n_told:
            raise ValueError(f"inner must be a fresh critic, it was told {inner.n_told} points")
        super().__init__(inner.dim, batch_size=inner.batch_size, seed=inner.seed, x0=inner.x0)
        if isinstance(max_fall_prob, bool) or not isinstance(max_fall_prob, (int, float,
                                                                             np.number)):
            raise ValueError(f"max_fall_prob must be a number in (0, 1], got {max_fall_prob!r}")
        if not (0.0 < float(max_fall_prob) <= 1.0):
            raise ValueError(f"max_fall_prob must be in (0, 1], got {max_fall_prob!r}")
        if not is_whole(oversample, 1):
            raise ValueError(f"oversample must be an integer >= 1, got {oversample!r}")
        for name, v, lo in (("max_points", max_points, 4), ("max_fit_points", max_fit_points, 4)):
            if not is_whole(v, lo):
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not (isinstance(refit_fraction, (int, float)) and 0.0 < refit_fraction <= 1.0):
            raise ValueError(f"refit_fraction must be in (0, 1], got {refit_fraction!r}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int)
                                    or threads < 1):
            raise ValueError(f"threads must be None or an integer >= 1, got {threads!r}")
        if model is not None and (not isinstance(model, FallModel) or model.dim != self.dim):
            raise ValueError(f"model must be a FallModel of dimension {self.dim}, got {model!r}")
        if (prior_X is None) != (prior_fell is None):
            raise ValueError("prior_X and prior_fell must be given together")
        if prior_X is None:
            self.prior_X = np.empty((0, self.dim))
            self.prior_fell = np.empty(0, dtype=bool)
        else:
            self.prior_X = as_unit_points(prior_X, self.dim, "prior_X")
            self.prior_fell = _as_flags(prior_fell, self.prior_X.shape[0], "prior_fell")
        self.inner = inner
        self.max_fall_prob = float(max_fall_prob)
        self.oversample = int(oversample)
        self.model: FallModel = model if model is not None else GPFallModel(
            self.dim, max_points=int(max_points), max_fit_points=int(max_fit_points),
            refit_fraction=float(refit_fraction), threads=threads)
        self._prior_set = False
        self.last_fall_prob = np.empty(0)
        """(n,) predicted fall probability of the last asked points (nan: model inactive)."""
        self.last_n_over = 0
        """Points of the last ask returned although over ``max_fall_prob`` (too few below)."""
        self.last_n_screened = 0
        """Candidates of the last ask predicted to fall and not returned."""
        self.n_over = 0
        """Total of :attr:`last_n_over` over all asks."""
        self.n_screened = 0
        """Total of :attr:`last_n_screened` over all asks."""
        inner.screen_with(self)

    # ------------------------------------------------------------------ the screen
    def _canonical(self, idx: np.ndarray) -> np.ndarray:
        """``idx`` sorted by (tag, point): independent of the order inside a batch."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return idx
        keys = [self._X[idx, j] for j in range(self.dim - 1, -1, -1)] + [self._tags[idx]]
        return idx[np.lexsort(keys)]

    def predictor(self, basis: np.ndarray | None = None
                  ) -> Callable[[np.ndarray], np.ndarray] | None:
        """:meth:`Screen.predictor <latentune.critic.base.Screen.predictor>`: the fall model
        fitted on the prior and the told points ``basis`` (all when ``None``), or ``None``
        while they hold one class only."""
        if not self._prior_set:
            self.model.set_prior(self.prior_X, self.prior_fell)
            self._prior_set = True
        idx = self._canonical(np.arange(self.n_told) if basis is None else basis)
        if not self.model.fit(self._X[idx], self._fell[idx]):
            return None
        return self.model.p_fall

    def fall_prob(self, X: np.ndarray) -> np.ndarray | None:
        """Predicted fall probability (n,) at ``X`` (n, dim) from the prior and every told point;
        ``None`` while the data hold only one class."""
        X = as_unit_points(X, self.dim)
        pred = self.predictor()
        return None if pred is None else pred(X)

    # ------------------------------------------------------------------ protocol
    def tell(self, X: np.ndarray, y: np.ndarray, tags: np.ndarray | None = None,
             fell: np.ndarray | None = None) -> None:
        """Report raw costs ``y`` (n,) of ``X`` (n, dim) with the inner critic's ``tags`` and the
        ``fell`` flags (n,) bool (default: the non-finite costs); see the module docstring."""
        Xa = as_unit_points(X, self.dim)
        ya = np.asarray(y, dtype=float).reshape(-1)
        if ya.shape[0] != Xa.shape[0]:
            raise ValueError(f"y must have shape ({Xa.shape[0]},), got {np.shape(y)}")
        fa = ~np.isfinite(ya) if fell is None else _as_flags(fell, Xa.shape[0], "fell")
        if Xa.shape[0] == 0:
            return
        n0 = self.n_told
        super().tell(Xa, ya, tags, fell=fa)      # validates the tags; the screen's data first
        try:
            self.inner.tell(Xa, ya, self._tags[n0:], fell=fa)
        except Exception:
            self._X, self._y = self._X[:n0], self._y[:n0]
            self._tags, self._fell = self._tags[:n0], self._fell[:n0]
            raise

    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        """The told points and flags are the screen's data (kept by :class:`Critic`)."""

    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        X = self.inner.ask(n)
        rep = self.inner.last_screen
        self.last_fall_prob = np.asarray(rep.p, dtype=float)
        self.last_n_over, self.last_n_screened = int(rep.n_over), int(rep.n_screened)
        self.n_over += self.last_n_over
        self.n_screened += self.last_n_screened
        return X, self.inner.last_tags.copy()

    def state_dict(self) -> dict[str, Any]:
        """The inner critic's :meth:`~latentune.critic.base.Critic.state_dict`."""
        return {"inner": self.inner.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state and "inner" in state:
            self.inner.load_state_dict(state["inner"])

    # ------------------------------------------------------------------ report
    def stats(self) -> dict[str, Any]:
        """Counters for logs and run records: asks screened, points over the threshold, the
        fall model's hyperparameter fits (``n_fits``, ``n_fit_failed``) and the inner critic's
        :meth:`~latentune.critic.base.Critic.stats` (``inner_stats``)."""
        return {"method": self.method, "inner": self.inner.method,
                "max_fall_prob": self.max_fall_prob,
                "n_told": self.n_told, "n_fell": int(self._fell.sum()),
                "n_prior": int(self.prior_X.shape[0]),
                "n_over": self.n_over,
                "n_screened": self.n_screened,
                "mode": _MODE.get(self.inner.batch_policy, self.inner.batch_policy),
                **self.model.fit_report.as_dict(),
                "inner_stats": self.inner.stats()}

    def __repr__(self) -> str:
        return (f"FallAware({self.inner!r}, max_fall_prob={self.max_fall_prob}, "
                f"n_prior={self.prior_X.shape[0]}, n_fell={int(self._fell.sum())})")


def _as_flags(v: Any, n: int, name: str) -> np.ndarray:
    """Validate (n,) boolean flags (bool or 0/1 values)."""
    a = np.asarray(v)
    if a.ndim != 1 or a.shape[0] != n:
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if a.dtype != bool:
        if not np.issubdtype(a.dtype, np.number) or not np.all(np.isin(a, (0, 1))):
            raise ValueError(f"{name} must be booleans (or 0/1)")
        a = a.astype(bool)
    return a.copy()
