"""The numbers every report computes from a phase's costs, each defined once here.

``costs`` is always a 1-D sequence of shape (n,): the path costs of one phase in evaluation
order (the run store's ``idx`` order, :meth:`~latentune.pipeline.store.RunStore.costs`).
Which evaluations failed (fell) is data of the trial, not of its cost's scale: the functions
that count falls take the (n,) ``fell`` flags (the run store's), or a ``fall_cost`` from a
caller that knows its task's convention (a cost not below it is a fall; the built-in tasks'
reports pass theirs); given neither, only a non-finite cost counts as a fall.

The paper's reported numbers are packaged with latentune (``latentune/data/paper_results.json``)
and read through :func:`paper_results` / :func:`paper_row`.
"""
from __future__ import annotations

import json
import math
from functools import lru_cache
from importlib import resources
from typing import Any, Sequence

import numpy as np


PAPER_ROBOT = {"a1": "A1", "b1": "B1", "solo12": "Solo12"}
"""latentune robot name → the paper's spelling (the keys of ``paper_results()["path_cost"]``)."""


def _costs(costs: Sequence[float] | np.ndarray) -> np.ndarray:
    return np.asarray(costs, dtype=float).reshape(-1)


def evals_to_beat(costs: Sequence[float] | np.ndarray, target: float | None) -> int | None:
    """Number of evaluations until the first cost strictly below ``target`` (1-based).

    ``costs``: (n,) costs in evaluation order. Returns ``k`` such that ``costs[k - 1] < target``
    and no earlier cost is; ``None`` when no cost is below ``target``, when ``target`` is
    ``None`` or when there are no costs. A cost equal to the target does not count: phase 1's
    first evaluation is the manual θ itself and does not beat it.
    """
    y = _costs(costs)
    if target is None or y.size == 0:
        return None
    hit = np.flatnonzero(y < float(target))
    return int(hit[0]) + 1 if hit.size else None


def best_so_far(costs: Sequence[float] | np.ndarray,
                fell: Sequence[bool] | np.ndarray | None = None) -> np.ndarray:
    """The running minimum of ``costs``: (n,) array, element ``i`` = min(costs[: i + 1]); with
    (n,) ``fell`` flags, over the trials that did not fail only (inf until the first stands)."""
    y = _costs(costs)
    if fell is not None:
        y = np.where(np.asarray(fell, dtype=bool).reshape(-1), np.inf, y)
    return np.minimum.accumulate(y) if y.size else y


def fell_mask(costs: Sequence[float] | np.ndarray,
              fell: Sequence[bool] | np.ndarray | None = None,
              fall_cost: float | None = None) -> np.ndarray:
    """(n,) bool array, True where the evaluation failed: the (n,) ``fell`` flags when given;
    else ``not (cost < fall_cost)`` when ``fall_cost`` is given; else the non-finite costs."""
    if fell is not None:
        return np.asarray(fell, dtype=bool).reshape(-1)
    y = _costs(costs)
    return ~(y < float(fall_cost)) if fall_cost is not None else ~np.isfinite(y)


def stable_count(costs: Sequence[float] | np.ndarray,
                 fell: Sequence[bool] | np.ndarray | None = None,
                 fall_cost: float | None = None) -> int:
    """Number of evaluations that did not fail (see :func:`fell_mask`)."""
    return int(np.count_nonzero(~fell_mask(costs, fell, fall_cost)))


def stable_share(costs: Sequence[float] | np.ndarray,
                 fell: Sequence[bool] | np.ndarray | None = None,
                 fall_cost: float | None = None) -> float | None:
    """Fraction in [0, 1] of evaluations that did not fail (see :func:`fell_mask`); ``None``
    for no evaluations."""
    f = fell_mask(costs, fell, fall_cost)
    return None if f.size == 0 else float(np.mean(~f))


def fall_count(costs: Sequence[float] | np.ndarray,
               fell: Sequence[bool] | np.ndarray | None = None,
               fall_cost: float | None = None) -> int:
    """Number of evaluations that failed (see :func:`fell_mask`)."""
    return int(np.count_nonzero(fell_mask(costs, fell, fall_cost)))


def rms_velocity_error(cost: float | None, steps: int, fell: bool = False) -> float | None:
    """RMS velocity-tracking error [m/s] of a stable rollout of ``steps`` steps.

    The path cost of a stable rollout is ``L = sqrt(Σ_k ‖v_k − v_des‖²)`` over the ``N_H =
    steps`` steps of the horizon, so the RMS of ``‖v − v_des‖`` is ``L / sqrt(N_H)``. Returns
    ``None`` for a missing or non-finite cost, a rollout that ``fell`` (its cost is the fall
    penalty, not a velocity error) or ``steps < 1``.
    """
    if cost is None or not math.isfinite(cost) or fell or steps < 1:
        return None
    return float(cost) / math.sqrt(float(steps))


def phase_stats(costs: Sequence[float] | np.ndarray, target: float | None = None,
                fell: Sequence[bool] | np.ndarray | None = None,
                fall_cost: float | None = None) -> dict[str, Any]:
    """Summary of one phase's (n,) costs.

    Keys: ``n`` (evaluations), ``best`` (the lowest cost of a trial that did not fail, None
    if none stood), ``best_idx`` (0-based index of its first occurrence, None likewise),
    ``stable`` (trials that did not fail: from the (n,) ``fell`` flags or ``fall_cost``, see
    :func:`fell_mask`), ``falls`` (n − stable), ``evals_to_beat`` (:func:`evals_to_beat`
    against ``target``, e.g. the manual θ's cost, counting only trials that did not fail). A
    failed trial is never the best, whatever cost it was given.
    """
    y = _costs(costs)
    n = int(y.size)
    ok = ~fell_mask(y, fell, fall_cost)
    y_ok = np.where(ok, y, np.inf)
    i = int(np.argmin(y_ok)) if ok.any() else None
    return {"n": n, "best": None if i is None else float(y[i]), "best_idx": i,
            "stable": int(ok.sum()), "falls": n - int(ok.sum()),
            "evals_to_beat": evals_to_beat(y_ok, target)}


@lru_cache(maxsize=1)
def _paper_text() -> str:
    return resources.files("latentune").joinpath("data", "paper_results.json").read_text("utf-8")


def paper_results() -> dict[str, Any]:
    """The paper's reported numbers (``latentune/data/paper_results.json``; its ``source``
    entry names the paper and the tables they come from). A fresh dict on every call."""
    return json.loads(_paper_text())


def paper_row(robot: str, gait: str) -> dict[str, Any]:
    """The paper's path-cost row of ``robot`` (latentune name, e.g. ``a1``, or the paper's,
    e.g. ``A1``) and ``gait``: keys ``manual``, ``phase1``, ``phase3_even``, ``phase3_uneven``,
    ``phase3_cross_task``, ``cross_task_vae``. Empty dict when the paper has no such row."""
    name = PAPER_ROBOT.get(str(robot).lower(), str(robot))
    return dict(paper_results().get("path_cost", {}).get(name, {}).get(str(gait), {}))
