"""The ask/tell protocol shared by every critic (optimizer) of latentune.

A critic minimizes an unknown cost over the unit box ``[0, 1]^dim``. It never evaluates
anything itself: the caller asks for points, evaluates them (serially, in a process pool, on a
Ray cluster, ...) and tells the costs back::

    critic = make_critic("turbo", dim, batch_size=10, seed=0, x0=manual_theta)
    while budget_left:
        X = critic.ask()            # (n, dim) float64 in [0, 1]^dim
        tags = critic.last_tags     # (n,) int64, one opaque tag per asked point
        y = evaluate(X)             # (n,) raw costs, lower is better; nan/inf allowed
        critic.tell(X, y, tags=tags)

Tags and resume (the contract the run store relies on)
-------------------------------------------------------
* ``ask`` stores in ``critic.last_tags`` one ``int64`` tag per returned point. The caller treats
  tags as opaque integers: it stores each point's tag next to its cost and passes it back to
  ``tell``. A tag tells the critic where the point came from (TuRBO-m: ask generation, trust
  region and design/Thompson kind; CMA-ES: generation; random/Sobol: generation/sequence index).
* ``tell(X, y, tags=None)``: points told without tags (``tags=None`` or tag ``-1``) are
  *external* points (warm data, hand-picked θ). Every critic accepts them; they enter the
  history and the model but do not drive the critic's internal adaptation in the way its own
  points do (see each implementation).
* Resume without a ``state_dict``: a fresh critic built with the same ``dim``, ``batch_size``,
  ``seed``, ``x0`` and options, told the stored history ``(X, y, tags)`` -- in one call, or in
  the original order of the tell calls -- is in an equivalent state to the original critic, and
  its next ``ask`` continues the run (for "random", "sobol" and TuRBO with
  ``warm_start=False`` it returns exactly the batch the original would have returned; see the
  implementations for the precise guarantee). Points within one ``tell`` are grouped by tag,
  so the grouping of tell calls does not matter as long as each ask's points are told
  together or in order.
* What the history does not determine (TuRBO-m's warm-started GP hyperparameters) is
  :meth:`Critic.state_dict`; a fresh critic told the history and then given
  :meth:`Critic.load_state_dict` of the original's state (saved after its last tell) asks the
  original's next batch. The pipeline saves it in the run store after every batch.
* Tags ``<= -2`` are reserved for implementation-specific markers (e.g. ``-2`` = a point of the
  warm start ``x0``); tags are always ``>= -2``.

Screening hooks (a fall model behind the protocol)
--------------------------------------------------
A feasibility model (e.g. :class:`~latentune.critic.fall_aware.FallAware`'s fall model) composes
with any critic through one hook, :meth:`Critic.screen_with`: the critic is given a
:class:`Screen` and from then on every :meth:`Critic.ask` returns only points the screen lets
through (as far as it can), recording what it did in :attr:`Critic.last_screen`. How a critic
screens is its own business, stated by :attr:`Critic.batch_policy`:

* ``"drop"`` (the default): the critic proposes more candidates than it needs
  (:meth:`Critic.propose`, ``oversample·n`` of them, in its order of preference), those the
  screen predicts to fall are dropped and the first ``n`` of the rest are returned. Each
  candidate has a role (:meth:`Critic.screen_roles`): never screened (a warm-start point),
  droppable, or *replace-only* -- a point the critic needs under its tag (e.g. a TuRBO-m initial
  design point), which is replaced by one of :meth:`Critic.replacement_candidates` when predicted
  to fall. The default :meth:`Critic.propose` asks a copy of the critic (kept, and asked again,
  until the next tell), so the critic's state stays a function of its told history.
* ``"complete"``: the critic needs every point it samples told (CMA-ES: a generation), so it
  screens while sampling and accounts for the screened points itself (see its module).

Either way the screen is consulted through :meth:`Screen.predictor` only; the critic says which
told points a prediction may use (``basis``) when its resume needs it.

Costs and falls
---------------
The stored ``y`` are the raw costs as told. Non-finite costs (nan, +inf, -inf: a crashed or
diverged evaluation) are never chosen as best and are treated as the worst finite cost seen so
far wherever a number is needed (:func:`fill_nonfinite`).

``tell(..., fell=)`` flags the trials that failed (default: the non-finite costs); every critic
keeps them (:attr:`Critic.fell`). A failed trial ranks after every trial that stood, whatever
cost it was told: it is never the best (:attr:`Critic.best_index`), and the critics model the
costs of :meth:`Critic.ranked_costs` (:func:`fall_last`), where the falls keep their order among
themselves (Optuna's samplers, run as the stock tools they are, are told the costs as they
are: :mod:`latentune.critic.optuna`). Where every fall already costs more than every standing trial (the path cost's
falls at ``C1·(2 − k/N)``) the ranked costs are the told costs.
"""
from __future__ import annotations

import copy
import logging
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from latentune.checks import is_whole

UNTAGGED: int = -1
"""Tag of a point the critic did not ask for (external / warm data)."""
X0_TAG: int = -2
"""Tag some critics give to the warm-start points ``x0`` they return."""

_BOX_TOL = 1e-9

SCREENED: int = 0
"""Role of a candidate the screen may drop (:meth:`Critic.screen_roles`)."""
EXEMPT: int = 1
"""Role of a candidate that is never screened (a warm-start point)."""
REPLACE: int = 2
"""Role of a candidate the critic needs under its tag: replaced, not dropped, when screened."""


class Screen(Protocol):
    """What a critic consults to screen its candidates (:meth:`Critic.screen_with`).

    ``max_fall_prob``: candidates with a predicted probability above it are screened;
    ``oversample``: candidates proposed per returned point (``"drop"`` policy).
    """

    max_fall_prob: float
    oversample: int

    def predictor(self, basis: np.ndarray | None = None
                  ) -> Callable[[np.ndarray], np.ndarray] | None:
        """The model's prediction ``X (m, dim) -> p (m,)`` in [0, 1] fitted on the told points
        ``basis`` (indices into the critic's history; ``None``: all of them), or ``None`` while
        the model has nothing to predict from (e.g. one class only)."""


@dataclass
class ScreenReport:
    """What the screen did in one ask: ``p`` (n,) the predicted probabilities of the returned
    points (nan where nothing was predicted), ``n_over`` returned points above the threshold
    (too few below it), ``n_screened`` candidates predicted to fall and not returned."""

    p: np.ndarray
    n_over: int = 0
    n_screened: int = 0


class _ScreenLink:
    """Holds a critic's :class:`Screen`; copies of the critic (``copy.deepcopy``) share it."""

    def __init__(self, screen: Screen) -> None:
        self.screen = screen

    def __deepcopy__(self, memo: dict[int, Any]) -> "_ScreenLink":
        return self


def refit_checkpoint(n: int, fraction: float, cap: int) -> int:
    """Largest hyperparameter-refit checkpoint ``<= n``: checkpoints start at 2 and grow as
    ``c_{k+1} = c_k + max(1, ⌈fraction·min(c_k, cap)⌉)``, so a model refitted at checkpoints is
    a deterministic function of its data."""
    c = 2
    while True:
        nxt = c + max(1, math.ceil(fraction * min(c, cap)))
        if nxt > n:
            return c
        c = nxt


def fill_nonfinite(y: np.ndarray) -> np.ndarray:
    """Return a float copy of ``y`` (n,) with non-finite entries set to the worst finite value.

    If no entry is finite, every entry becomes ``0.0`` (all equally bad).
    """
    y = np.array(y, dtype=float, copy=True).reshape(-1)
    bad = ~np.isfinite(y)
    if bad.any():
        y[bad] = y[~bad].max() if (~bad).any() else 0.0
    return y


def fall_last(y: np.ndarray, fell: np.ndarray) -> np.ndarray:
    """Costs (n,) in which every failed trial ranks after every trial that stood.

    ``y`` (n,) finite costs, ``fell`` (n,) bools. When the lowest failed cost is not above the
    highest standing one, every failed cost is raised by the same amount, to just above the
    highest standing cost: the order among the falls and among the standing trials is kept.
    Otherwise (and when either group is empty) ``y`` is returned as it is (a copy).
    """
    y = np.array(y, dtype=float, copy=True).reshape(-1)
    fell = np.asarray(fell, dtype=bool).reshape(-1)
    if not fell.any() or fell.all():
        return y
    top, low = float(y[~fell].max()), float(y[fell].min())
    if low > top:
        return y
    y[fell] += top - low + 1e-9 * max(1.0, abs(top))
    return y


def best_of(y: np.ndarray, fell: np.ndarray) -> int | None:
    """Position of the best of costs ``y`` (n,) with flags ``fell`` (n,) (first one on ties):
    the lowest finite cost of a trial that stood, else the lowest finite cost of a failed one;
    ``None`` if no cost is finite."""
    y = np.asarray(y, dtype=float).reshape(-1)
    fin = np.isfinite(y)
    for ok in (fin & ~np.asarray(fell, dtype=bool).reshape(-1), fin):
        if ok.any():
            return int(np.flatnonzero(ok)[np.argmin(y[ok])])
    return None


def gaussian_copula(y: np.ndarray) -> np.ndarray:
    """Rank-based Gaussian copula warp of costs ``y`` (n,) -> (n,) standard-normal scores.

    ``z_i = Φ⁻¹((rank_i − 0.5) / n)`` with average ranks for ties, after
    :func:`fill_nonfinite`. Monotone (rank preserving), scale free and insensitive to the
    dynamic range of the costs (a fall cost of 200 is just "worse than 150"). ``n = 1 → 0``.
    """
    from scipy.special import ndtri

    y = fill_nonfinite(y)
    n = y.shape[0]
    if n == 0:
        return y
    return ndtri((average_ranks(y) - 0.5) / n)


def average_ranks(y: np.ndarray) -> np.ndarray:
    """1-based ranks of ``y`` (n,), ties sharing their average rank (``scipy.stats.rankdata``'s
    "average", without importing scipy.stats: a large part of a cold ``ask``'s imports)."""
    _, inv, counts = np.unique(y, return_inverse=True, return_counts=True)
    return (np.cumsum(counts) - (counts - 1) / 2.0)[inv.reshape(-1)]


class FitReport:
    """Counts a critic's model fits and the fits that failed, and logs the first failure.

    A failed fit (a numerical error of the optimizer) leaves the model at its starting
    hyperparameters, so the critic keeps working; the failure is logged once through ``logger``
    (a ``WARNING``) and every failure is counted in :attr:`n_failed` (shown in the critic's
    :meth:`Critic.stats`). Copies of a critic made with :func:`copy.deepcopy` (e.g. the
    copies :meth:`Critic.propose` asks) share the report: ``deepcopy`` returns the same object.

    Args:
        what: the model, as shown in the log line (e.g. ``"TuRBO-m GP"``).
        logger: the logger of the module that fits the model.
    """

    def __init__(self, what: str, logger: logging.Logger) -> None:
        self.what = what
        self.logger = logger
        self.n_fits = 0
        self.n_failed = 0
        self.last_failure = ""
        """The error of the last fit that failed ("" before any did)."""

    def record(self, ok: bool, detail: str = "") -> None:
        """Count one fit; on the first failure, log ``detail`` (the error) once."""
        self.n_fits += 1
        if ok:
            return
        self.n_failed += 1
        self.last_failure = detail or "no detail"
        if self.n_failed == 1:
            self.logger.warning("%s: a hyperparameter fit failed (%s); the model keeps its "
                                "starting hyperparameters; later failures are only counted "
                                "(stats()['n_fit_failed'])", self.what, detail or "no detail")

    def as_dict(self) -> dict[str, int]:
        """``{"n_fits": ..., "n_fit_failed": ...}``."""
        return {"n_fits": self.n_fits, "n_fit_failed": self.n_failed}

    def __deepcopy__(self, memo: dict[int, Any]) -> "FitReport":
        return self

    def __copy__(self) -> "FitReport":
        return self


def as_unit_points(X: Any, dim: int, name: str = "X") -> np.ndarray:
    """Validate points ``X`` and return them as a float64 array (n, dim) clipped to [0, 1].

    Accepts a single point (dim,). Raises ``ValueError`` for a wrong shape, non-finite entries
    or entries outside [0, 1] by more than 1e-9.
    """
    try:
        X = np.asarray(X, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be numbers: a point ({dim},) or points (n, {dim})") from None
    if X.ndim == 1 and X.shape[0] == dim:
        X = X[None, :]
    if X.ndim != 2 or X.shape[1] != dim:
        raise ValueError(f"{name} must have shape (n, {dim}), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} contains non-finite values")
    if X.size and (X.min() < -_BOX_TOL or X.max() > 1 + _BOX_TOL):
        raise ValueError(f"{name} must lie in the unit box [0, 1]^{dim}")
    return np.clip(X, 0.0, 1.0)


class Critic(ABC):
    """Abstract ask/tell minimizer on the unit box ``[0, 1]^dim`` (see the module docstring).

    Args:
        dim: number of variables d >= 1.
        batch_size: default number of points per :meth:`ask`.
        seed: integer seed; a critic is a deterministic function of (options, seed, told data).
        x0: optional warm-start point(s) (d,) or (k, d) in [0, 1]^d; every critic returns them
            among its first asked points.
        **opts: implementation options; an unknown option raises ``TypeError``.
    """

    method: str = "abstract"

    def __init__(self, dim: int, *, batch_size: int = 1, seed: int = 0,
                 x0: np.ndarray | None = None, **opts: Any) -> None:
        if opts:
            raise TypeError(f"{type(self).__name__}: unknown option(s) {sorted(opts)}")
        if not is_whole(dim, 1):
            raise ValueError(f"dim must be an integer >= 1, got {dim!r}")
        if not is_whole(batch_size, 1):
            raise ValueError(f"batch_size must be an integer >= 1, got {batch_size!r}")
        if not is_whole(seed, 0):
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.dim = int(dim)
        self.batch_size = int(batch_size)
        self.seed = int(seed)
        self.x0: np.ndarray | None = None if x0 is None else as_unit_points(x0, self.dim, "x0")
        self._X = np.empty((0, self.dim))
        self._y = np.empty(0)
        self._fell = np.zeros(0, dtype=bool)
        self._tags = np.empty(0, dtype=np.int64)
        self.last_tags: np.ndarray = np.empty(0, dtype=np.int64)
        self._screen: _ScreenLink | None = None
        self._proposer: Critic | None = None
        self.last_screen: ScreenReport | None = None
        """What the screen did in the last ask (``None`` without a screen)."""

    # ----------------------------------------------------------------- protocol
    def ask(self, n: int | None = None) -> np.ndarray:
        """Suggest ``n`` (default ``batch_size``) points, float64 (n, dim) in [0, 1]^dim.

        Sets :attr:`last_tags` (n,) int64, the tags to pass back to :meth:`tell`.
        """
        n = self.batch_size if n is None else n
        if not is_whole(n, 1):
            raise ValueError(f"n must be an integer >= 1, got {n!r}")
        if self._screen is None:
            X, tags = self._checked_ask(int(n))
        else:
            X, tags, self.last_screen = self._screened_ask(int(n))
        self.last_tags = np.asarray(tags, dtype=np.int64).reshape(int(n)).copy()
        return X

    def _checked_ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_ask` with its points as float64 (n, dim) clipped to the box."""
        X, tags = self._ask(n)
        X = np.clip(np.asarray(X, dtype=float).reshape(n, self.dim), 0.0, 1.0)
        return X, np.asarray(tags, dtype=np.int64).reshape(n)

    def tell(self, X: np.ndarray, y: np.ndarray, tags: np.ndarray | None = None,
             fell: np.ndarray | None = None) -> None:
        """Report raw costs ``y`` (n,) of points ``X`` (n, dim) in [0, 1]^dim.

        ``tags`` (n,) ints as returned in :attr:`last_tags` (``None`` = all untagged, ``-1``).
        ``fell`` (n,) bools: which trials failed (default: the non-finite costs); a failed
        trial ranks after every trial that stood ("Costs and falls" in the module docstring).
        Non-finite costs are allowed.
        """
        X = as_unit_points(X, self.dim)
        y = np.asarray(y, dtype=float).reshape(-1)
        if y.shape[0] != X.shape[0]:
            raise ValueError(f"y must have shape ({X.shape[0]},), got {np.shape(y)}")
        fa = ~np.isfinite(y) if fell is None else np.asarray(fell, dtype=bool).reshape(-1)
        if fa.shape[0] != X.shape[0]:
            raise ValueError(f"fell must have shape ({X.shape[0]},), got {np.shape(fell)}")
        if tags is None:
            tags_a = np.full(X.shape[0], UNTAGGED, dtype=np.int64)
        else:
            tags_a = np.asarray(tags).reshape(-1)
            if tags_a.shape[0] != X.shape[0]:
                raise ValueError(f"tags must have shape ({X.shape[0]},), got {np.shape(tags)}")
            if tags_a.size and (not np.issubdtype(tags_a.dtype, np.integer)):
                if not np.all(np.equal(np.mod(tags_a, 1), 0)):
                    raise ValueError("tags must be integers")
            tags_a = tags_a.astype(np.int64)
            if tags_a.size and tags_a.min() < X0_TAG:
                raise ValueError("tags must be >= -2")
        if X.shape[0] == 0:
            return
        start = self._X.shape[0]
        self._X = np.vstack([self._X, X])
        self._y = np.concatenate([self._y, y])
        self._fell = np.concatenate([self._fell, fa])
        self._tags = np.concatenate([self._tags, tags_a])
        self._proposer = None
        self._tell(np.arange(start, start + X.shape[0]), tags_a)

    @abstractmethod
    def _ask(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(X (n, dim), tags (n,))``."""

    @abstractmethod
    def _tell(self, idx: np.ndarray, tags: np.ndarray) -> None:
        """Update after the points ``self._X[idx]`` with costs ``self._y[idx]`` were appended."""

    # -------------------------------------------------------------- screening
    batch_policy: str = "drop"
    """How the critic screens (module docstring): ``"drop"`` or ``"complete"``."""

    def screen_with(self, screen: Screen) -> None:
        """From now on, screen every ask with ``screen`` (module docstring, "Screening hooks").
        Only a fresh critic (nothing told) can be given a screen; copies share it."""
        if self.n_told:
            raise ValueError(f"a screen needs a fresh critic, this one was told {self.n_told} "
                             "points")
        self._screen = _ScreenLink(screen)

    def propose(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """``m`` candidates ``(X (m, dim), tags (m,))`` in the critic's order of preference, as
        its next asks would return them, without changing what the critic's next :meth:`ask`
        after a tell depends on: the default asks a copy of the critic, kept (and asked again
        by the next proposal, which continues from it) until the next :meth:`tell`."""
        if self._proposer is None:
            link, self._screen = self._screen, None
            try:
                self._proposer = copy.deepcopy(self)
            finally:
                self._screen = link
        return self._proposer._checked_ask(int(m))

    def screen_roles(self, X: np.ndarray, tags: np.ndarray) -> np.ndarray:
        """Role (m,) int8 of each candidate ``X`` (m, dim) with ``tags`` (m,): :data:`EXEMPT`
        for warm-start points (tag ``-2`` or a row of ``x0``), else :data:`SCREENED`. Critics
        that need some of their points under their tag mark them :data:`REPLACE`."""
        ex = np.asarray(tags) == X0_TAG
        if self.x0 is not None and X.shape[0]:
            ex |= np.any(np.all(X[:, None, :] == self.x0[None, :, :], axis=2), axis=1)
        return np.where(ex, EXEMPT, SCREENED).astype(np.int8)

    def replacement_candidates(self, tag: int, rank: int, m: int) -> np.ndarray:
        """``m`` alternatives (m, dim) for the ``rank``-th :data:`REPLACE` candidate with tag
        ``tag`` of a proposal, in order of preference; a deterministic function of the critic's
        seed, state, ``tag`` and ``rank``. Only critics that mark candidates :data:`REPLACE`
        implement it."""
        raise NotImplementedError(f"{type(self).__name__} marks no candidate REPLACE")

    def _screened_ask(self, n: int) -> tuple[np.ndarray, np.ndarray, ScreenReport]:
        """The ``"drop"`` policy (module docstring): ``(X (n, dim), tags (n,), report)``."""
        screen = self._screen.screen
        thr = float(screen.max_fall_prob)
        pred = screen.predictor()
        if pred is None:                        # nothing to predict from: pass through
            X, T = self.propose(n)
            return X, T, ScreenReport(np.full(n, np.nan))
        C, T = self.propose(n * int(screen.oversample))
        p = np.asarray(pred(C), dtype=float).copy()
        roles = self.screen_roles(C, T)
        ex, repl = roles == EXEMPT, roles == REPLACE
        ok = ex | repl | (p <= thr)
        sel = np.flatnonzero(ok)[:n]
        n_over = 0
        if sel.size < n:                        # too few under the threshold: the least likely
            rest = np.flatnonzero(~ok)
            fill = rest[np.argsort(p[rest], kind="stable")[: n - sel.size]]
            sel = np.sort(np.concatenate([sel, fill]))
            n_over = int(fill.size)
        screened = int(np.count_nonzero(~ok[: sel[-1] + 1])) - n_over
        rank: dict[int, int] = {}
        for i in sel[repl[sel]]:
            j = rank[int(T[i])] = rank.get(int(T[i]), -1) + 1
            if p[i] > thr:
                Z = self.replacement_candidates(int(T[i]), j, 64)
                pz = np.asarray(pred(Z), dtype=float)
                good = np.flatnonzero(pz <= thr)
                k = int(good[0]) if good.size else int(np.argmin(pz))
                C[i], p[i] = Z[k], float(pz[k])
                screened += 1
                n_over += int(p[i] > thr)
        return C[sel], T[sel], ScreenReport(p[sel], n_over, screened)

    # ---------------------------------------------------------------- history
    @property
    def X(self) -> np.ndarray:
        """All told points (n, dim), in tell order."""
        return self._X.copy()

    @property
    def y(self) -> np.ndarray:
        """All told raw costs (n,), in tell order (non-finite values kept as told)."""
        return self._y.copy()

    @property
    def tags(self) -> np.ndarray:
        """Tags (n,) int64 of all told points, in tell order (-1 = untagged)."""
        return self._tags.copy()

    @property
    def fell(self) -> np.ndarray:
        """(n,) bool: the ``fell`` flags of all told points, in tell order."""
        return self._fell.copy()

    @property
    def n_told(self) -> int:
        """Number of told points."""
        return int(self._y.shape[0])

    def ranked_costs(self) -> np.ndarray:
        """The costs (n,) the critic models: :func:`fill_nonfinite`, then :func:`fall_last` with
        the told ``fell`` flags."""
        return fall_last(fill_nonfinite(self._y), self._fell)

    @property
    def best_index(self) -> int | None:
        """Index of the best told point (first one on ties): the lowest finite cost of a trial
        that stood, else the lowest finite cost of a failed one; ``None`` if no cost is
        finite (:func:`best_of`)."""
        return best_of(self._y, self._fell)

    @property
    def best_x(self) -> np.ndarray | None:
        """Point (dim,) of the best finite cost, or ``None``."""
        i = self.best_index
        return None if i is None else self._X[i].copy()

    @property
    def best_y(self) -> float:
        """Best finite cost told, ``inf`` if there is none."""
        i = self.best_index
        return float("inf") if i is None else float(self._y[i])

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """What the told history does not determine and a resume should restore (JSON-ready;
        ``{}`` for critics whose state is a function of the history). See
        :meth:`load_state_dict`."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` after the same history was told (no-op here)."""

    # ------------------------------------------------------------------ report
    def stats(self) -> dict[str, Any]:
        """Counters for logs and run records (``method``, ``n_told``; model-based critics add
        their fit counts, see :class:`FitReport`)."""
        return {"method": self.method, "n_told": self.n_told}

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(dim={self.dim}, batch_size={self.batch_size}, "
                f"seed={self.seed}, n_told={self.n_told}, best_y={self.best_y:.6g})")


class TwoSpaceCritic(Critic):
    """A critic on the full θ box some of whose points come from a latent box of dimension
    :attr:`k`: after each ask :attr:`last_z` (n, k) holds their codes (NaN rows for the others),
    and :meth:`tell` takes the codes back with the fall flags. A subclass sets ``last_z``,
    ``_incoming`` (None) in its constructor and calls :meth:`_incoming_told` first in its
    ``_tell``."""

    last_z: np.ndarray
    _incoming: tuple[np.ndarray, np.ndarray] | None

    @property
    @abstractmethod
    def k(self) -> int:
        """Dimension of the latent box."""

    def tell(self, X: np.ndarray, y: np.ndarray, tags: np.ndarray | None = None,
             fell: np.ndarray | None = None, z: np.ndarray | None = None) -> None:
        """Report costs ``y`` (n,) of θ ``X`` (n, d) with this critic's ``tags``, their fall
        flags ``fell`` (n,) (default: the non-finite costs) and the latent codes ``z`` (n, k) of
        latent points (NaN rows for the others; None: no latent points)."""
        Xa = as_unit_points(X, self.dim)
        ya = np.asarray(y, dtype=float).reshape(-1)
        if ya.shape[0] != Xa.shape[0]:
            raise ValueError(f"y must have shape ({Xa.shape[0]},), got {np.shape(y)}")
        fa = ~np.isfinite(ya) if fell is None else np.asarray(fell, dtype=bool).reshape(-1)
        if fa.shape[0] != Xa.shape[0]:
            raise ValueError(f"fell must have shape ({Xa.shape[0]},), got {np.shape(fell)}")
        za = np.full((Xa.shape[0], self.k), np.nan) if z is None or self.k == 0 else \
            np.asarray(z, dtype=float).reshape(Xa.shape[0], self.k)
        self._incoming = (fa, za)
        super().tell(Xa, ya, tags, fell=fa)

    def _incoming_told(self) -> tuple[np.ndarray, np.ndarray]:
        """The fall flags (n,) and codes (n, k) of the points being told."""
        assert self._incoming is not None
        fa, za = self._incoming
        self._incoming = None
        return fa, za
