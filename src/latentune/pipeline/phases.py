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

The critic of a phase is built from the study's stored options by
:func:`latentune.pipeline.loop.phase_critic`, for this loop and for ask/tell alike.

Failing phases
--------------
When the last :data:`FAIL_STREAK` trials of a phase all failed, one warning is logged
(:func:`failing_message`: what it may mean and what to try), once per streak.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from latentune.constants import Phase
from latentune.critic.handover import HANDOVER_DEFAULTS
from latentune.errors import StoreError, UsageError
from latentune.pipeline.evaluators import Evaluator, TrialError
from latentune.pipeline.store import RunStore
from latentune.system import EvaluationError, Outcome

log = logging.getLogger(__name__)

FAIL_STREAK = 8
"""A phase whose last this many trials all failed says so (:func:`failing_message`)."""

FALL_DESIGN_SIDE = 0.8
"""Side of the box around the warm start that a fall-aware TuRBO-m's first design fills (the
initial trust region's side)."""


def default_batch_size(workers: int) -> int:
    """Critic batch size: the number of workers, at least 4 (TuRBO-m's Thompson batches)."""
    return max(int(workers), 4)


def make_phase_critic(method: str, dim: int, batch_size: int, seed: int, x0: np.ndarray | None,
                      budget: int, regions: int | None = None, max_fall_prob: float | None = None,
                      prior: tuple[np.ndarray, np.ndarray] | None = None,
                      fall_region: bool = True,
                      source: tuple[np.ndarray, np.ndarray] | None = None):
    """The critic of a phase on [0, 1]^dim: ``method`` with its batch size, seed and warm start
    ``x0`` (d,); TuRBO-m gets ``regions`` trust regions (default: by budget).

    ``max_fall_prob``: wrap it in :class:`~latentune.critic.fall_aware.FallAware`, which skips
    candidates whose predicted probability of failing exceeds it; ``prior`` = (X (m, dim),
    fell (m,)) are failed/stable points of a source run in the same box, for its classifier.
    TuRBO-m then also fills its first design around ``x0`` (``design_side`` = its initial
    side) and halves a region whose batch's share of falls exceeds ``max_fall_prob``
    (``fall_shrink``; "Falls" in :mod:`latentune.critic.turbo`), unless ``fall_region`` is
    False (the hand-over's latent stage, which hands over when its search stalls).
    ``optuna-<sampler>``: Optuna's sampler (:class:`~latentune.critic.optuna.OptunaCritic`), ``source`` = (X (m, dim), y (m,)) its CMA-ES's ``source_trials``."""
    if method.startswith("optuna-"):
        if max_fall_prob is not None:
            raise UsageError(f"max_fall_prob is not an option of the method {method}")
        from latentune.critic.optuna import OptunaCritic

        return OptunaCritic(dim, batch_size=batch_size, seed=seed, x0=x0,
                            sampler=method.split("-", 1)[1], source=source)
    from latentune.critic import make_critic
    from latentune.critic.turbo import regions_for_budget

    kw: dict[str, Any] = {"batch_size": batch_size, "seed": seed, "x0": x0}
    if method == "turbo":
        kw["n_regions"] = regions if regions is not None else regions_for_budget(budget)
        if max_fall_prob is not None and fall_region:
            kw.update(design_side=FALL_DESIGN_SIDE, fall_shrink=float(max_fall_prob))
    return _fall_aware(make_critic(method, dim, **kw), max_fall_prob, prior)


def _fall_aware(critic: Any, max_fall_prob: float | None,
                prior: tuple[np.ndarray, np.ndarray] | None) -> Any:
    """``critic`` wrapped in :class:`~latentune.critic.fall_aware.FallAware` with the prior
    (X, fell) (none when empty), or ``critic`` itself when ``max_fall_prob`` is None."""
    if max_fall_prob is None:
        return critic
    from latentune.critic.fall_aware import FallAware

    px, pf = prior if prior is not None and len(prior[0]) else (None, None)
    return FallAware(critic, max_fall_prob=max_fall_prob, prior_X=px, prior_fell=pf)


def handover_options(handover: Any) -> dict[str, Any] | None:
    """The checked hand-over options: ``None``/``False`` (plain phase 3), ``True`` (defaults) or
    a dict overriding some of :data:`HANDOVER_DEFAULTS`. ``ValueError`` for anything else."""
    if handover is None or handover is False:
        return None
    if handover is True:
        return dict(HANDOVER_DEFAULTS)
    if not isinstance(handover, dict) or set(handover) - set(HANDOVER_DEFAULTS):
        raise ValueError("handover must be True, False or a dict with keys "
                         f"{', '.join(HANDOVER_DEFAULTS)}, got {handover!r}")
    out = {**HANDOVER_DEFAULTS, **handover}
    p, t, ln = out["patience"], out["tol"], out["length"]
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(f"handover patience must be an integer >= 1, got {p!r}")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 <= t < 1:
        raise ValueError(f"handover tol must be in [0, 1), got {t!r}")
    if isinstance(ln, bool) or not isinstance(ln, (int, float)) or not 0 < ln <= 1.6:
        raise ValueError(f"handover length must be in (0, 1.6], got {ln!r}")
    return {"patience": int(p), "tol": float(t), "length": float(ln)}


def make_handover_critic(method: str, latent: Any, batch_size: int, seed: int,
                         x0: np.ndarray | None, budget: int, regions: int | None,
                         handover: dict[str, Any], max_fall_prob: float | None = None,
                         latent_prior: tuple[np.ndarray, np.ndarray] | None = None,
                         theta_prior: tuple[np.ndarray, np.ndarray] | None = None):
    """Phase 3 with a hand-over (:class:`~latentune.critic.handover.Handover`): ``method`` on
    the latent box of ``latent`` (a LatentSpace) from the code ``x0`` (k,), then TuRBO-m with
    one trust region on the full θ box. With ``max_fall_prob`` both are fall-aware, with the
    source run's points in each box (``latent_prior``, ``theta_prior``) as priors."""
    from latentune.critic.handover import Handover

    # the trust-region fall rules are left out here: a region shrunk by falls stalls sooner and
    # hands over sooner, to a full-space stage that falls more (measured in session 12: Solo12
    # jump, 10 seeds, 20.5 falls of 100 against 19 without them)
    lat = make_phase_critic(method, latent.d_low, batch_size, seed, x0, budget, regions,
                            max_fall_prob, latent_prior, fall_region=False)

    def make_full(length: float):
        from latentune.critic.turbo import TurboM

        return _fall_aware(TurboM(latent.d, batch_size=batch_size, seed=seed, n_regions=1,
                                  length_init=length), max_fall_prob, theta_prior)

    return Handover(lat, latent.decode, latent.d, make_full, patience=handover["patience"],
                    tol=handover["tol"], handover_length=handover["length"])


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


def failing_message(phase: int, n: int) -> str:
    """The warning of a phase whose last ``n`` trials all failed, with what to try."""
    if int(phase) == 3:
        return (f"phase 3: the last {n} trials all failed: the target may be far from the "
                "latent space's source; try the hand-over (--handover), the fall-aware critic "
                "(--max-fall-prob 0.3), or phase 1 on the target")
    return (f"phase {int(phase)}: the last {n} trials all failed: the search is where the "
            "system fails; try the fall-aware critic (--max-fall-prob 0.3), a start θ that "
            "does not fail, or narrower bounds")


def failure_streak(store: RunStore, phase: int) -> int:
    """How many of the last stored trials of ``phase`` (idx order) failed in a row."""
    fell = store.fell(phase)
    ok = np.flatnonzero(~fell)
    return int(len(fell) - (ok[-1] + 1 if len(ok) else 0))


def warn_if_failing(store: RunStore, phase: int) -> bool:
    """Log :func:`failing_message` when the streak of failed trials of ``phase`` has just
    reached :data:`FAIL_STREAK` (after a trial was stored); return whether it did."""
    if failure_streak(store, phase) == FAIL_STREAK:
        log.warning(failing_message(phase, FAIL_STREAK))
        return True
    return False


def store_outcome(store: RunStore, phase: int, idx: int, theta: np.ndarray, out: Outcome, *,
                  z: np.ndarray | None = None, tag: int = -1, seed: int | None = None) -> None:
    """Commit one Outcome as evaluation ``idx`` of ``phase``."""
    store.add(phase, idx, theta, out.cost, z=z, tag=tag, fell=out.failed,
              fall_step=out.fall_step, wall_s=out.wall_s, seed=seed, info=out.info)


def asked_points(U: np.ndarray, Z: np.ndarray | None, decoder: Callable | None
                 ) -> tuple[np.ndarray, list[np.ndarray | None]]:
    """The θ (n, d) of the points ``U`` (n, k) a critic just asked and the latent code to store
    with each: ``Z`` (n, k) is a two-space critic's ``last_z`` (``U`` is θ already; a finite row
    is the code, a NaN row none); else ``decoder(U)`` with ``U`` as the codes, or ``U`` itself
    without a decoder (no codes)."""
    if Z is not None:
        return U, [z if np.all(np.isfinite(z)) else None for z in Z]
    if decoder is None:
        return U, [None] * len(U)
    return np.atleast_2d(decoder(U)), list(U)


def state_key(phase: int) -> str:
    """The store's meta key of the critic state (:meth:`Critic.state_dict`) of ``phase``."""
    return f"critic_state_{int(phase)}"


def save_state(store: RunStore, phase: int, critic: Any) -> None:
    """Store ``critic.state_dict()`` for ``phase`` (nothing for a critic without state)."""
    state = critic.state_dict() if hasattr(critic, "state_dict") else {}
    if state:
        store.set_meta(state_key(phase), state)


def replay(store: RunStore, phase: int, critic: Any) -> int:
    """Tell ``critic`` the stored rows of ``phase`` (idx order, with their tags) and restore
    its stored state (:func:`save_state`); return n."""
    n = _tell_rows(store, phase, critic)
    state = store.get_meta(state_key(phase))
    if n and state and hasattr(critic, "load_state_dict"):
        critic.load_state_dict(state)
    return n


def _tell_rows(store: RunStore, phase: int, critic: Any) -> int:
    store.check_contiguous(phase)
    if hasattr(critic, "last_z"):                  # a two-space critic: θ, and z where stored
        rows = store.rows(phase)
        if not rows:
            return 0
        k = critic.last_z.shape[1]
        X = np.array([r.theta for r in rows])
        Z = np.array([r.z if r.z is not None and len(r.z) == k else np.full(k, np.nan)
                      for r in rows])
        y = np.array([r.cost for r in rows])
        critic.tell(X, y, np.array([r.tag for r in rows], dtype=np.int64),
                    fell=np.array([r.fell for r in rows], dtype=bool), z=Z)
        return len(rows)
    X, y, tags = store.history(phase)
    if len(y):
        if X.shape[1] != critic.dim:
            raise StoreError(f"stored phase-{phase} points have dimension {X.shape[1]}, "
                             f"the critic {critic.dim}")
        critic.tell(X, y, tags, fell=store.fell(phase))
    return len(y)


def ask_batch(critic: Any, k: int, decoder: Callable | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, list[Any]]:
    """Ask ``critic`` for ``k`` points: (U (k, m) its points, tags (k,), Z (k, m') a
    two-space critic's codes or None, θ (k, d), the code to store with each θ)."""
    U = critic.ask(k)
    T = critic.last_tags.copy()
    Z = getattr(critic, "last_z", None)           # a two-space critic's latent codes
    Z = None if Z is None else Z.copy()
    thetas, codes = asked_points(U, Z, decoder)
    return U, T, Z, thetas, codes


def run_phase(store: RunStore, phase: int, system: Any, critic: Any, budget: int,
              evaluator: Evaluator,
              decoder: Callable[[np.ndarray], np.ndarray] | None = None, seed: int | None = None,
              progress: bool = False, on_row: Callable[[int, float], None] | None = None,
              max_new: int | None = None, known: dict[bytes, Outcome] | None = None
              ) -> PhaseResult:
    """Run (or resume) one tuning phase until ``budget`` evaluations are stored.

    Args:
        store: the run store; rows of ``phase`` already stored are told to ``critic`` first.
        phase: :attr:`Phase.PHASE1` (θ space) or :attr:`Phase.PHASE3` (latent space).
        system: a System (``space`` + ``evaluate``, see :mod:`latentune.system`).
        critic: a fresh critic on [0, 1]^k (k = d in phase 1, d_low in phase 3).
        budget: total evaluations of the phase (stored ones included).
        evaluator: a :class:`~latentune.pipeline.evaluators.Evaluator`.
        decoder: the map D from the critic's box to normalized θ ((n, k) -> (n, d)); ``None`` is
            the identity (phase 1). Rows then store both z (the critic's point) and θ.
            A critic with a ``last_z`` attribute (:class:`~latentune.critic.handover.Handover`)
            works on θ itself and decodes its latent-stage points on its own: rows store its
            ``last_z`` rows as z where they are finite, and it is told them back (``z=``).
        max_new: stop after this many new evaluations (tests; ``None`` = no limit).
        known: outcomes already measured, by ``theta.tobytes()`` of the (d,) float64 θ: an asked
            θ found here is stored with that outcome instead of being run again (the manual θ,
            evaluated once as phase 0, is phase 1's first point).

    Raises:
        EvaluationError: a trial raised or gave no usable cost; the batch's finished trials are
            stored first, the failed one is not (a resume asks again).
    """
    t0 = time.perf_counter()
    n0 = replay(store, phase, critic)
    y = store.costs(phase)
    idx = n0
    bar = _progress(budget, min(n0, budget), f"phase {phase}", progress)
    best = float(np.min(y)) if n0 else math.inf
    streak = failure_streak(store, phase)
    new = 0
    try:
        if bar is not None and n0:
            bar.set_postfix(best=f"{best:.3f}")
        while idx < budget and (max_new is None or new < max_new):
            k = min(critic.batch_size, budget - idx)
            if max_new is not None:
                k = min(k, max_new - new)
            U, T, Z, thetas, codes = ask_batch(critic, k, decoder)
            ib, yb, fb = [], [], []                # ask index, cost and fell of each result
            error: str | None = None
            for i, r in _results(evaluator, system, thetas, known or {}):
                if isinstance(r, TrialError):
                    error = error or r.message
                    continue
                cost = float(r.cost)
                store_outcome(store, phase, idx, thetas[i], r, z=codes[i], tag=int(T[i]),
                              seed=seed)
                idx += 1
                new += 1
                ib.append(i)
                yb.append(cost)
                fb.append(bool(r.failed))
                streak = streak + 1 if r.failed else 0
                if streak == FAIL_STREAK:
                    log.warning(failing_message(phase, FAIL_STREAK))
                if cost < best:
                    best = cost
                if on_row is not None:
                    on_row(idx, cost)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(best=f"{best:.3f}")
            if error is not None:
                raise EvaluationError(f"{error} (phase {int(phase)}; {idx} evaluations are "
                                      "stored; fix the system and resume)")
            # rows are stored as they complete (crash safety); the critic is told the batch in
            # ask order, so a seed gives the same run whatever order the workers finish in
            order = np.argsort(ib, kind="stable")
            ii = np.asarray(ib, dtype=np.int64)[order]
            critic.tell(U[ii], np.asarray(yb, dtype=float)[order], T[ii].astype(np.int64),
                        fell=np.asarray(fb, dtype=bool)[order],
                        **({} if Z is None else {"z": Z[ii]}))
            save_state(store, phase, critic)
    finally:
        if bar is not None:
            bar.close()
    b = store.best(phase)
    wall = time.perf_counter() - t0
    return PhaseResult(phase, store.count(phase), new, b.cost if b else math.inf,
                       None if b is None else b.theta, wall)


def _results(evaluator: Evaluator, system: Any, thetas: np.ndarray,
             known: dict[bytes, Outcome]) -> Any:
    """``(i, Outcome | TrialError)`` for each row of ``thetas``: known ones first (not run)."""
    thetas = np.ascontiguousarray(thetas, dtype=float)
    reuse = [i for i in range(len(thetas)) if thetas[i].tobytes() in known]
    for i in reuse:
        out = known[thetas[i].tobytes()]
        yield i, Outcome(out.cost, out.failed, {**out.info, "reused": True}, out.wall_s)
    todo = [i for i in range(len(thetas)) if i not in reuse]
    if todo:
        for j, r in evaluator.imap(system, thetas[todo]):
            yield todo[j], r


def ensure_manual(store: RunStore, system: Any, seed: int | None = None, idx: int = 0) -> float:
    """Evaluate the system's manual θ once (phase 0, row ``idx``) and return its cost."""
    for r in store.rows(Phase.MANUAL):
        if r.idx == idx:
            return r.cost
    from latentune.system import evaluate

    out = evaluate(system, system.space.manual)
    store_outcome(store, Phase.MANUAL, idx, system.space.manual, out, seed=seed)
    return float(out.cost)


def manual_outcome(store: RunStore, system: Any) -> dict[bytes, Outcome]:
    """The stored manual-θ trial (phase 0, idx 0) of ``system``, keyed by the θ's bytes for
    :func:`run_phase`'s ``known`` (empty if none is stored for this manual θ)."""
    rows = [r for r in store.rows(Phase.MANUAL) if r.idx == 0]
    theta = np.ascontiguousarray(system.space.manual, dtype=float)
    if not rows or not np.array_equal(rows[0].theta, theta):
        return {}
    r = rows[0]
    info = {**r.info, "fall_step": r.fall_step} if r.fall_step is not None else dict(r.info)
    return {theta.tobytes(): Outcome(r.cost, r.fell, info, r.wall_s)}


def training_set(store: RunStore, phase: int = Phase.PHASE1) -> np.ndarray:
    """The θ of ``phase`` whose trial did not fail (for a built-in task: cost < C1, stable):
    phase 2's training set (n, d), in lexicographic order of θ. The store's order is the order
    the workers finished in, which varies from run to run; the VAE's minibatches depend on the
    order, so a fixed one keeps a seed's latent space the same."""
    rows = [r for r in store.rows(phase) if not r.fell]
    if not rows:
        return np.empty((0, 0))
    X = np.array([r.theta for r in rows])
    return X[np.lexsort(X.T[::-1])]
