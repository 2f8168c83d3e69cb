"""The trials a study compares its phases with: the zero-shot trial and preservation.

* zero-shot (phase 4): the source study's best θ evaluated as it is on the target, before
  phase 3 searches another study's latent space (:func:`zero_shot`);
* preservation (phase 5): each phase-1 θ whose trial did not fail, passed through a latent
  space's encoder and decoder and evaluated again (:func:`preservation`).
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from latentune.constants import Phase
from latentune.pipeline.phases import reused_outcome, store_outcome
from latentune.pipeline.store import Row, RunStore
from latentune.system import EvaluationError, evaluate

def source_best(run: str | os.PathLike) -> Row | None:
    """The best trial of a run's phases 1 and 3 among those that did not fail (all trials if
    every one failed); None if the run has no store or no trials. The zero-shot θ."""
    if not (Path(run) / "run.db").is_file():
        return None
    with RunStore(run) as o:
        rows = [r for ph in (Phase.PHASE1, Phase.PHASE3) for r in o.rows(ph)]
    if not rows:
        return None
    ok = [r for r in rows if not r.fell] or rows
    return min(ok, key=lambda r: (r.cost, r.phase, r.idx))


def source_trials(run: str | Path, phases: tuple[int, ...] | None = None,
                  counts: dict[str, int] | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every trial of a source run's ``phases`` (default phases 1 and 3) as
    ``(X (N, d), y (N,), fell (N,))``, in (phase, idx) order; with ``counts`` (phase number as
    text to a count, :func:`~latentune.pipeline.loop.source_counts`) only the first that many
    of each phase (the trials a phase 3 began with)."""
    with RunStore(run) as st:
        rows = [r for ph in (phases or (Phase.PHASE1, Phase.PHASE3)) for r in st.rows(ph)
                if counts is None or r.idx < int(counts.get(str(int(ph)), 0))]
    if not rows:
        return np.empty((0, 0)), np.empty(0), np.empty(0, dtype=bool)
    X = np.array([r.theta for r in rows], dtype=float)
    y = np.array([r.cost for r in rows], dtype=float)
    f = np.array([bool(r.fell) for r in rows], dtype=bool)
    return X, y, f


REUSED_BY_ZERO_SHOT = (Phase.MANUAL, Phase.PHASE3)
"""The phases whose stored trial of the zero-shot θ gives the zero-shot trial its outcome
instead of a new trial (the source's best is often the manual θ, which the plain phase 3 runs
first)."""


def zero_shot(store: RunStore, system: Any, source: str, seed: int,
              evaluator: Any = None) -> float | None:
    """Evaluate the source study's best θ on ``system`` once (phase 4, idx 0) unless it is
    stored (a zero-shot suggestion of ask/tell not handed out yet is withdrawn: this run asks
    it); return its cost (None when there is nothing to run). On ``evaluator`` (the phase's),
    else in this process; a trial of that θ stored already (:data:`REUSED_BY_ZERO_SHOT`: the
    manual θ's, when the source's best is the manual θ) gives its outcome instead, as
    :func:`queue_zero_shot` does for ask/tell."""
    if source == "self" or store.count(Phase.ZERO_SHOT) > 0:
        return None
    store.drop_queued((Phase.ZERO_SHOT,))
    best = source_best(source)
    if best is None:
        return None
    out = reused_outcome(store, Phase.ZERO_SHOT, best.theta, REUSED_BY_ZERO_SHOT)
    if out is None:
        out = evaluator.one(system, best.theta) if evaluator is not None \
            else evaluate(system, best.theta)
    out.info.update({"source": str(Path(source)), "source_phase": int(best.phase),
                     "source_idx": int(best.idx), "source_cost": float(best.cost)})
    store_outcome(store, Phase.ZERO_SHOT, 0, best.theta, out, seed=seed)
    return float(out.cost)


def zero_shot_to_queue(store: RunStore, source: str | None) -> bool:
    """Whether :func:`queue_zero_shot` looks for a zero-shot suggestion to queue: phase 3
    runs on another study's latent space and has no zero-shot trial (told, queued or
    handed out)."""
    return source not in (None, "self") and store.count(Phase.ZERO_SHOT) == 0 and not any(
        t.phase == Phase.ZERO_SHOT and t.status != "dropped" for t in store.trials())


def queue_zero_shot(store: RunStore, source: str | None, seed: int | None = None) -> None:
    """Ask/tell with another study's latent space: queue that study's best θ as the zero-shot
    suggestion (phase 4), handed out before phase 3's first, once; a trial of that θ stored
    already (:data:`REUSED_BY_ZERO_SHOT`) is stored as the zero-shot trial instead (with
    ``seed``), as :func:`zero_shot` does."""
    if not zero_shot_to_queue(store, source):
        return
    best = source_best(source)
    if best is None:
        return
    out = reused_outcome(store, Phase.ZERO_SHOT, best.theta, REUSED_BY_ZERO_SHOT)
    if out is None:
        store.add_trial(Phase.ZERO_SHOT, best.theta, None, -1)
        return
    out.info.update({"source": str(Path(source)), "source_phase": int(best.phase),
                     "source_idx": int(best.idx), "source_cost": float(best.cost)})
    store_outcome(store, Phase.ZERO_SHOT, 0, best.theta, out, seed=seed)


def preservation(store: RunStore, system: Any, latent: Any, source: str, evaluator: Any,
                 seed: int) -> dict[str, Any]:
    """Pass each phase-1 θ of ``store`` whose trial did not fail through ``latent``'s encoder
    and decoder and evaluate the result on ``system`` (phase 5, idx = the source row's idx).
    Returns ``{n_stable, n_kept, rate, ...}`` (also stored as the ``preservation`` meta entry);
    resumes."""
    from latentune.pipeline.evaluators import TrialError

    rows = [r for r in store.rows(Phase.PHASE1) if not r.fell]
    done = {r.idx for r in store.rows(Phase.PRESERVATION)}
    todo = [r for r in rows if r.idx not in done]
    if todo:
        rec = np.clip(latent.reconstruct(np.array([r.theta for r in todo])), 0.0, 1.0)
        for i, out in evaluator.imap(system, rec):
            if isinstance(out, TrialError):
                raise EvaluationError(out.message)
            store_outcome(store, Phase.PRESERVATION, todo[i].idx, rec[i], out,
                          z=todo[i].theta, seed=seed)
    kept = int(sum(not r.fell for r in store.rows(Phase.PRESERVATION)))
    res = {"vae_source": source, "n_phase1": store.count(Phase.PHASE1),
           "n_stable": len(rows), "n_kept": kept, "complete": True,
           "rate": kept / len(rows) if rows else math.nan,
           "rows": "phase 5: theta = decoded θ, z = the original θ, "
                   "idx = the source phase-1 idx"}
    store.set_meta("preservation", res)
    return res
