"""The paper's Algorithm 1: phase 1 (AC_GEN(f, Id)), phase 2 (the VAE), phase 3 (AC_GEN(f, D)).

:func:`run_phase` is the one actor–critic loop of both tuning phases: the critic works on a unit
box, the map ``decoder`` takes its points to normalized θ (identity in phase 1, the VAE decoder
on the latent box in phase 3), the evaluator simulates them, and every finished evaluation is
committed to the run store before the critic is told the batch.

Resume and crash safety
-----------------------
Rows get their index when they are *committed* (completion order), so the indices of a phase
are always 0..n−1 without gaps, whatever order the workers finish in, and one index is never
written twice (the store's primary key refuses it). On resume a fresh critic with the same
options and seed is told the stored rows (X, y, tags) in index order. Index order is completion
order, not the ask order each batch was told in, but the tags group the rows by ask, so the
critic replays its batches as they were told and its state is restored (see
:mod:`latentune.critic.base`; only the order of points inside the GP's data may differ); the loop
then continues at index n. If the process died in the middle of a batch, the rows of that batch
that were committed are kept and told with their tags; its unfinished points are lost with the
process and are *re-asked*: the resumed critic's next ask covers the remaining budget. No
finished evaluation is lost and none is run twice.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from latentune.pipeline.store import RunStore
from latentune.task import C1  # the fall threshold, defined once with the path cost

PHASE_MANUAL, PHASE1, PHASE3 = 0, 1, 3


def default_batch_size(workers: int) -> int:
    """Critic batch size: the number of workers, at least 4 (TuRBO-m's Thompson batches)."""
    return max(int(workers), 4)


def make_phase_critic(method: str, dim: int, batch_size: int, seed: int, x0: np.ndarray | None,
                      budget: int, regions: int | None = None):
    from latentune.critic import make_critic
    from latentune.critic.turbo import regions_for_budget

    kw: dict[str, Any] = {"batch_size": batch_size, "seed": seed, "x0": x0}
    if method == "turbo":
        kw["n_regions"] = regions if regions is not None else regions_for_budget(budget)
    return make_critic(method, dim, **kw)


@dataclass
class PhaseResult:
    phase: int
    n: int
    n_new: int
    best_cost: float
    best_theta: np.ndarray | None
    wall_s: float


def _progress(total: int, initial: int, desc: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="eval", dynamic_ncols=True,
                leave=True)


def _restore_inf(y: np.ndarray) -> np.ndarray:
    y = np.asarray(y, dtype=float).copy()
    y[np.abs(y) >= 1e299] = np.inf
    return y


def run_phase(store: RunStore, phase: int, task: Any, critic: Any, budget: int, evaluator: Any,
              decoder: Callable[[np.ndarray], np.ndarray] | None = None, seed: int | None = None,
              progress: bool = False, on_row: Callable[[int, float], None] | None = None,
              max_new: int | None = None) -> PhaseResult:
    """Run (or resume) one tuning phase until ``budget`` evaluations are stored.

    Args:
        store: the run store; rows of ``phase`` already stored are told to ``critic`` first.
        phase: 1 (θ space) or 3 (latent space); any integer works.
        task: a :class:`~latentune.task.Task` (or a picklable callable θ -> cost).
        critic: a fresh critic on [0, 1]^k (k = d in phase 1, d_low in phase 3).
        budget: total evaluations of the phase (stored ones included).
        evaluator: has ``imap(fun, X)`` yielding ``(i, result dict)`` (pipeline evaluators) or
            just ``map(fun, X) -> y``.
        decoder: the map D from the critic's box to normalized θ ((n, k) -> (n, d)); ``None`` is
            the identity (phase 1). Rows then store both z (the critic's point) and θ.
        max_new: stop after this many new evaluations (tests; ``None`` = no limit).
    """
    t0 = time.perf_counter()
    store.check_contiguous(phase)
    X, y, tags = store.history(phase)
    n0 = len(y)
    if n0:
        if X.shape[1] != critic.dim:
            raise ValueError(f"stored phase-{phase} points have dimension {X.shape[1]}, "
                             f"the critic {critic.dim}")
        critic.tell(X, _restore_inf(y), tags)
    idx = n0
    bar = _progress(budget, min(n0, budget), f"phase {phase}", progress)
    best = float(np.min(y)) if n0 else math.inf
    new = 0
    try:
        if bar is not None and n0:
            bar.set_postfix(best=f"{best:.3f}")
        while idx < budget and (max_new is None or new < max_new):
            k = min(critic.batch_size, budget - idx)
            if max_new is not None:
                k = min(k, max_new - new)
            U = critic.ask(k)
            T = critic.last_tags.copy()
            thetas = U if decoder is None else np.atleast_2d(decoder(U))
            ib, yb = [], []                        # ask index and cost of each result
            if hasattr(evaluator, "imap"):
                results = evaluator.imap(task, thetas)
            else:
                ys = np.asarray(evaluator.map(task, thetas), dtype=float).reshape(-1)
                results = ((i, {"cost": float(c)}) for i, c in enumerate(ys))
            for i, r in results:
                cost = float(r["cost"])
                store.add(phase, idx, thetas[i], cost, z=None if decoder is None else U[i],
                          tag=int(T[i]), fell=r.get("fell"), fall_step=r.get("fall_step"),
                          wall_s=r.get("wall_s"), seed=seed)
                idx += 1
                new += 1
                ib.append(i)
                yb.append(cost)
                if cost < best:
                    best = cost
                if on_row is not None:
                    on_row(idx, cost)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(best=f"{best:.3f}")
            # rows are stored as they complete (crash safety); the critic is told the batch in
            # ask order, so a seed gives the same run whatever order the workers finish in
            order = np.argsort(ib, kind="stable")
            ii = np.asarray(ib, dtype=np.int64)[order]
            critic.tell(U[ii], np.asarray(yb, dtype=float)[order], T[ii].astype(np.int64))
    finally:
        if bar is not None:
            bar.close()
    b = store.best(phase)
    wall = time.perf_counter() - t0
    return PhaseResult(phase, store.count(phase), new, b.cost if b else math.inf,
                       None if b is None else b.theta, wall)


def ensure_manual(store: RunStore, task: Any, seed: int | None = None) -> float:
    """Evaluate the task's manual θ once (phase 0, idx 0) and return its cost."""
    rows = store.rows(PHASE_MANUAL)
    if rows:
        return rows[0].cost
    res = task.rollout(task.space.manual)
    store.add(PHASE_MANUAL, 0, task.space.manual, res.cost, tag=-1, fell=res.fell,
              fall_step=res.fall_step, wall_s=res.wall_s, seed=seed)
    return float(res.cost)


def training_set(store: RunStore, phase: int = PHASE1) -> np.ndarray:
    """Phase-1 θ with cost < C1 (the stable ones): phase 2's training set (n, d), in
    lexicographic order of θ. The store's order is the order the workers finished in, which varies
    from run to run; the VAE's minibatches depend on the order, so a fixed one keeps a seed's
    latent space the same."""
    rows = [r for r in store.rows(phase) if r.cost < C1]
    if not rows:
        return np.empty((0, 0))
    X = np.array([r.theta for r in rows])
    return X[np.lexsort(X.T[::-1])]


def preservation_rate(task: Any, latent: Any, thetas: np.ndarray, evaluator: Any) -> float:
    """Fraction of stable θ that stay stable after encode → decode (rollouts of the decoded θ)."""
    if len(thetas) == 0:
        return math.nan
    rec = latent.reconstruct(np.asarray(thetas))
    y = evaluator.map(task, rec)
    return float(np.mean(np.asarray(y) < C1))
