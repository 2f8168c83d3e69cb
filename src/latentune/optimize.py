"""``minimize``: a scipy-like front end to the critics, on a box in original coordinates.

>>> import numpy as np, latentune as lt
>>> res = lt.minimize(lambda x: float(np.sum(x ** 2)), [(-1, 1)] * 3, method="random",
...                   budget=20, batch_size=5, seed=0)
>>> res.nfev, res.X.shape
(20, (20, 3))
"""
from __future__ import annotations

import inspect
from typing import Any, Callable

import numpy as np
from scipy.optimize import OptimizeResult as _ScipyResult

from latentune.checks import is_whole
from latentune.critic import critic_class
from latentune.errors import UsageError
from latentune.pipeline.evaluators import Evaluator, SerialEvaluator

_BOUNDS_TOL = 1e-9
MAX_ABS_BOUND = 1e150
"""Largest bound magnitude :func:`minimize` accepts: beyond it the square of a coordinate (any
quadratic cost, any norm) overflows a float64, so every cost would be inf."""


class OptimizeResult(_ScipyResult):
    """Result of :func:`minimize` (a ``scipy.optimize.OptimizeResult``).

    Attributes:
        x: best point (d,) in the original bounds (``None`` if no finite cost was seen).
        fun: its cost (``inf`` if no finite cost was seen).
        nfev: number of evaluations.
        nit: number of ask/tell batches.
        X: all evaluated points (n, d), original bounds, in evaluation order.
        y: their raw costs (n,) (non-finite values kept).
        tags: the critic's tags (n,) int64 (see :mod:`latentune.critic.base`).
        method, seed: as passed.
        success: whether at least one finite cost was seen.
        message: why the run stopped.
        critic: the critic object (can be told more data or asked for more points).
    """


def _check_int(name: str, v: Any, low: int, high: int | None = None) -> int:
    if not is_whole(v, low, high):
        raise UsageError(f"{name} must be an integer >= {low}"
                         f"{'' if high is None else f' and <= {high}'}, got {v!r}")
    return int(v)


def _check_bounds(bounds: Any) -> np.ndarray:
    try:
        b = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError) as e:
        raise UsageError(f"bounds must be a (d, 2) array of numbers: {e}") from None
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
        raise UsageError(f"bounds must have shape (d, 2) with d >= 1, got {b.shape}")
    if not np.all(np.isfinite(b)):
        bad = sorted({int(i) for i in np.argwhere(~np.isfinite(b))[:, 0]})
        raise UsageError(f"bounds must be finite; not in dimension(s) {bad}")
    if np.any(np.abs(b) > MAX_ABS_BOUND):
        bad = sorted({int(i) for i in np.argwhere(np.abs(b) > MAX_ABS_BOUND)[:, 0]})
        raise UsageError(f"bounds must lie within ±{MAX_ABS_BOUND:g} (squares of larger values "
                         f"overflow a float64); rescale dimension(s) {bad}")
    if np.any(b[:, 0] >= b[:, 1]):
        bad = np.flatnonzero(b[:, 0] >= b[:, 1]).tolist()
        raise UsageError(f"bounds need lower < upper; violated in dimension(s) {bad}")
    return b


def minimize_critic(method: str, dim: int, *, budget: int, batch_size: int = 10, seed: int = 0,
                    x0: np.ndarray | None = None, **opts: Any) -> Any:
    """The critic :func:`minimize` runs for ``method`` on ``dim`` variables with these
    arguments (``x0``: unit-box warm-start points or None; TuRBO's ``n_regions`` defaults to
    :func:`~latentune.critic.turbo.regions_for_budget` of ``budget``), built and not asked:
    a caller checks its options with it before a run. UsageError for an unknown method, an
    option the method does not have, or an option value it refuses (``n_regions=0``)."""
    try:
        cls = critic_class(method)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    params = inspect.signature(cls.__init__).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(opts) - set(params))
        if unknown:
            raise UsageError(f"method {method!r} has no option {', '.join(unknown)} (its "
                             f"options: {', '.join(sorted(set(params) - {'self', 'dim'}))})")
    if method.lower() == "turbo" and "n_regions" not in opts:
        from latentune.critic.turbo import regions_for_budget

        opts = {**opts, "n_regions": regions_for_budget(budget)}
    try:
        return cls(dim, batch_size=batch_size, seed=seed, x0=x0, **opts)
    except ValueError as exc:           # an option out of its domain (n_regions=0, sigma0=-1)
        raise UsageError(f"method {method!r}: {exc}") from None


def minimize(fun: Callable[[np.ndarray], float], bounds: Any, method: str = "turbo",
             budget: int = 500, batch_size: int = 10, seed: int = 0,
             x0: Any = None, evaluator: Evaluator | None = None,
             callback: Callable[[OptimizeResult], Any] | None = None,
             **opts: Any) -> OptimizeResult:
    """Minimize ``fun`` over the box ``bounds`` with a critic (TuRBO-m, CMA-ES, random, Sobol).

    Args:
        fun: maps a point (d,) float64 ndarray in the original coordinates to a float cost (a
            real number: a Python or NumPy int/float, or a 0-d array); nan/inf costs are
            allowed (treated as the worst cost seen).
        bounds: (d, 2) array-like of finite ``(lower, upper)`` with lower < upper, each within
            ±:data:`MAX_ABS_BOUND`.
        method: "turbo", "cma", "random" or "sobol".
        budget: number of evaluations (>= 1).
        batch_size: points per ask (>= 1); the last batch is cut to the remaining budget.
        seed: integer seed in [0, 2**63); the run is deterministic for a seed.
        x0: warm-start point(s) (d,) or (k, d) inside ``bounds``; evaluated among the first.
        evaluator: a :class:`~latentune.pipeline.evaluators.Evaluator` (default serial); a
            process or Ray evaluator needs a picklable ``fun``.
        callback: called after every batch with the :class:`OptimizeResult` so far; returning
            ``True`` (or ``numpy.True_``) or raising ``StopIteration`` (as in SciPy) stops the
            run (message "stopped by callback").
        **opts: options of the critic (e.g. ``n_regions`` for TuRBO, default
            :func:`~latentune.critic.turbo.regions_for_budget` of ``budget``; ``sigma0`` for CMA-ES).

    Returns:
        :class:`OptimizeResult` with ``x, fun, nfev, nit, X, y, tags, method, seed, success,
        message, critic``.

    Raises:
        UsageError: (a ``ValueError``) bad bounds, budget, batch_size, seed, x0, method, an
            option the method does not take, or a non-callable ``fun``.
        CostError: ``fun`` returned something that is not a real number (None, a string, a bool,
            an array, a complex number, an int beyond float64); it is a TypeError and a
            ValueError (:class:`latentune.system.CostError`).
        EvaluationError: ``fun`` raised (the message names the exception).
    """
    if not callable(fun):
        raise UsageError("fun must be callable: (d,) ndarray -> float")
    b = _check_bounds(bounds)
    budget = _check_int("budget", budget, 1)
    batch_size = _check_int("batch_size", batch_size, 1)
    seed = _check_int("seed", seed, 0, 2 ** 63 - 1)
    if callback is not None and not callable(callback):
        raise UsageError("callback must be callable or None")
    if evaluator is None:
        evaluator = SerialEvaluator()
    elif not isinstance(evaluator, Evaluator):
        raise UsageError("evaluator must be a latentune.pipeline.evaluators.Evaluator")
    d = b.shape[0]
    lo, hi = b[:, 0], b[:, 1]
    span = hi - lo
    x0_unit = None
    if x0 is not None:
        try:
            x0a = np.asarray(x0, dtype=float)
        except (TypeError, ValueError) as e:
            raise UsageError(f"x0 must be numeric: {e}") from None
        if x0a.ndim == 1:
            x0a = x0a[None, :]
        if x0a.ndim != 2 or x0a.shape[1] != d or x0a.shape[0] < 1:
            raise UsageError(f"x0 must have shape ({d},) or (k, {d}), got {np.shape(x0)}")
        if not np.all(np.isfinite(x0a)):
            raise UsageError("x0 must be finite")
        tol = _BOUNDS_TOL * np.maximum(span, 1.0)
        if np.any(x0a < lo - tol) or np.any(x0a > hi + tol):
            raise UsageError("x0 must lie inside bounds")
        x0_unit = np.clip((x0a - lo) / span, 0.0, 1.0)

    critic = minimize_critic(method, d, budget=budget, batch_size=batch_size, seed=seed,
                             x0=x0_unit, **opts)

    def result(message: str, nit: int) -> OptimizeResult:
        i = critic.best_index
        X = lo + critic.X * span
        return OptimizeResult(
            x=None if i is None else X[i].copy(), fun=critic.best_y, nfev=critic.n_told, nit=nit,
            X=X, y=critic.y, tags=critic.tags, method=method, seed=seed, success=i is not None,
            message=message, critic=critic)

    nit = 0
    message = f"budget of {budget} evaluations used"
    while critic.n_told < budget:
        k = min(batch_size, budget - critic.n_told)
        U = critic.ask(k)
        tags = critic.last_tags
        Xp = lo + U * span
        y = np.asarray(evaluator.map(fun, Xp), dtype=float).reshape(-1)
        if y.shape[0] != k:
            raise UsageError(f"evaluator returned {y.shape[0]} costs for {k} points")
        critic.tell(U, y, tags=tags)
        nit += 1
        try:
            stop = None if callback is None else callback(result("running", nit))
        except StopIteration:           # SciPy's way for a callback to stop a run
            stop = True
        if isinstance(stop, (bool, np.bool_)) and stop:
            message = "stopped by callback"
            break
    res = result(message, nit)
    if not res.success:
        res.message = message + "; no finite cost was seen"
    return res
