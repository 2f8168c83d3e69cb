"""The paper's Algorithm 1: phase 1 (AC_GEN(f, Id)), phase 2 (the VAE), phase 3 (AC_GEN(f, D)).

:func:`run_phase` is the one actor–critic loop of both tuning phases: the critic works on a unit
box, the map ``decoder`` takes its points to normalized θ (identity in phase 1, the VAE decoder
on the latent box in phase 3), the evaluator simulates them, and every finished evaluation is
committed to the run store before the critic is told the batch.

Resume and crash safety
-----------------------
Rows get their index when they are *committed* (completion order), so the indices of a phase
are always 0..n−1 without gaps, whatever order the workers finish in, and one index is never
written twice (the store's primary key refuses it). A row stored out of its batch's ask order
records the index it would have had in ask order (``info["asked"]``, :data:`ASKED`). On resume
a fresh critic with the same options and seed is told the stored rows (X, y, tags) in ask
order, the order it was told them (:func:`told_order`: the order of the points in the GP's data
changes what it asks next), and its state is restored (see :mod:`latentune.critic.base`); the
loop then continues at index n.

A process may die in the middle of a batch. So every asked batch is recorded in the store's meta
(:class:`AskedBatch`, key :func:`batch_key`) before its first trial runs, and removed in the
transaction that stores the critic's state after the batch is told. A resume that finds the
record, with the phase's last rows all points of that batch, replays only the rows stored before
the batch (and the state saved then), asks the critic that batch again (:func:`reask`: a critic
fits its models when it asks, and the next fits start from those), runs the batch's points that
have no row yet, and tells the critic the whole batch in ask order: the critic sees the asks and
tells of a run that was never stopped, so a seed gives the same θ whether or not (and wherever)
it was stopped. A record that does not match the rows (the rows grew since, another budget) is
ignored: the stored rows are told and the critic asks again. No finished evaluation is lost and
none is run twice.

The critic of a phase is built from the study's stored options by
:func:`latentune.pipeline.loop.phase_critic`, for this loop and for ask/tell alike.

Failing phases
--------------
When the last :data:`FAIL_STREAK` trials of a phase all failed, one warning is logged
(:func:`failing_message`: what it may mean and what to try; :func:`timeout_message` when the
trial timeout stopped them all), once per streak. When the trials of phase 1 or 3 that stood
reach :data:`FLAT_COUNT`, all at one cost, one warning says the cost does not tell θ apart
(:func:`warn_if_flat`).
"""
from __future__ import annotations

import inspect
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from latentune.checks import is_whole
from latentune.constants import Phase, phase_name
from latentune.critic.handover import HANDOVER_DEFAULTS
from latentune.errors import StoreError, UsageError
from latentune.pipeline.evaluators import ClusterLost, Evaluator, TrialError
from latentune.pipeline.store import ASKED, NOT_REUSED, Row, RunStore
from latentune.system import EvaluationError, Outcome
from latentune.wording import counted

log = logging.getLogger(__name__)

FAIL_STREAK = 8
"""A phase whose last this many trials all failed says so (:func:`failing_message`)."""

FLAT_COUNT = 10
"""A phase whose trials that stood reach this many, all at one cost, says so
(:func:`warn_if_flat`)."""

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
    if not is_whole(p, 1):
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
    not_run: int = 0
    """Trials of the last batch not run: the fall budget was spent before they started."""
    asked: int = 0
    """Of ``not_run``, the suggestions ask/tell asked and had not handed out (queued)."""

    def best_text(self, fmt: str = ".3f") -> str:
        """``"best cost X"``, or ``"no trial stood"`` when every trial of the phase failed (its
        ``best_cost`` is then inf)."""
        if math.isfinite(self.best_cost):
            return f"best cost {self.best_cost:{fmt}}"
        return f"no trial stood (all {self.n} failed)" if self.n else "no trial yet"

    def line(self) -> str:
        """The phase's one-line summary: ``"phase 3: 1 evaluation, best cost X"``."""
        return f"phase {int(self.phase)}: {counted(self.n, 'evaluation')}, {self.best_text()}"


def not_run_note(not_run: int, asked: int = 0) -> str:
    """The trials a spent fall budget left unrun, to end a stop's line: ``" (3 trials of its
    last batch not run)"``, ``" (2 trials asked, not run)"`` (``asked`` of the ``not_run``:
    ask/tell's queued suggestions), ``" (1 trial of its last batch and 2 asked, not run)"``;
    ``""`` when none."""
    batch = not_run - asked
    if not_run <= 0:
        return ""
    if not asked:
        return f" ({counted(batch, 'trial')} of its last batch not run)"
    if not batch:
        return f" ({counted(asked, 'trial')} asked, not run)"
    return f" ({counted(batch, 'trial')} of its last batch and {asked} asked, not run)"


def _progress(total: int, initial: int, desc: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="eval", dynamic_ncols=True,
                leave=True)


def failing_message(phase: int, n: int, strategy: str = "plain",
                    running: dict[str, Any] | None = None, fixed: bool = False) -> str:
    """The warning of a phase whose last ``n`` trials all failed, with what to try; in phase 3
    what the ``strategy`` (``"transfer"`` or ``"plain"``) can take: the hand-over is an option of
    the plain strategy only, and the transfer strategy screens at ``--max-fall-prob`` already.
    ``running``: what the phase's critic does already (:func:`fall_options`), not suggested
    again (None: not known). ``fixed``: the phase's options cannot change here (ask/tell: the
    first ask fixed them), so the options are advised for a new directory. Options are named
    as the reader sets them (:func:`latentune.wording.option`: flags at the command line,
    keywords in Python)."""
    from latentune.wording import option

    run = running or {}
    mfp = run.get("max_fall_prob")
    new = ", in a new directory (the first ask fixed this one's options)," if fixed else ""
    if int(phase) == 3 and strategy == "transfer":
        from latentune.critic.transfer import TRANSFER_DEFAULTS

        p = TRANSFER_DEFAULTS["max_fall_prob"] if mfp is None else mfp
        told = " unless told" if p == TRANSFER_DEFAULTS["max_fall_prob"] else ""
        escape = "" if run.get("escape_falls") else \
            f"{option('escape_falls', 8)} if the target falls wherever the source stood, "
        return (f"phase 3: the last {n} trials all failed: the target may be far from the "
                "source run, or fail wherever it is tuned (run its manual θ by hand); the "
                f"transfer strategy asks the manual θ while every trial failed; try{new} a "
                f"lower {option('max_fall_prob')} (it screens at {p:g}{told}), {escape}or phase 1 "
                "on the target")
    screen = (f"the fall-aware critic ({option('max_fall_prob', 0.3)}), " if mfp is None else
              f"a lower {option('max_fall_prob')} (it screens at {mfp:g}), ")
    if int(phase) == 3:
        handover = "" if run.get("handover") else f"the hand-over ({option('handover')}), "
        return (f"phase 3: the last {n} trials all failed: the target may be far from the "
                f"latent space's source; try{new} {handover}{screen}the transfer strategy (the "
                "default), or phase 1 on the target")
    return (f"phase {int(phase)}: the last {n} trials all failed: the search is where the "
            f"system fails; try{new} {screen}a start θ that does not fail, or narrower bounds")


def timeout_message(phase: int, n: int, seconds: Any) -> str:
    """The warning of a phase whose last ``n`` trials were all stopped at the trial timeout of
    ``seconds`` (in place of :func:`failing_message`: they failed by the clock, not where the
    search went). The timeout is named as the reader sets it (:func:`latentune.wording.option`)."""
    from latentune.wording import option

    limit = f" of {float(seconds):g} s" if isinstance(seconds, (int, float)) else ""
    return (f"phase {int(phase)}: the last {n} trials all ran longer than the trial "
            f"timeout{limit} and were stopped (stored as failed): a trial of the system may "
            f"take longer than that; resume with a longer {option('trial_timeout')}")


def stored_fall_options(pc: dict[str, Any]) -> dict[str, Any]:
    """:func:`fall_options` read from a phase's stored options record ``pc`` (an ask/tell
    phase, whose critic is not built when a result is told)."""
    return {"max_fall_prob": pc.get("max_fall_prob"), "handover": bool(pc.get("handover")),
            "escape_falls": int((pc.get("transfer_options") or {}).get("escape_falls", 0))}


def fall_options(critic: Any) -> dict[str, Any]:
    """What a phase's ``critic`` does against falls already, for :func:`failing_message`:
    ``max_fall_prob`` (its screen; None: none), ``escape_falls`` (the transfer critic's) and
    ``handover`` (a hand-over critic)."""
    from latentune.critic.fall_aware import FallAware
    from latentune.critic.handover import Handover
    from latentune.critic.transfer import Transfer

    if isinstance(critic, Transfer):
        return {"max_fall_prob": critic.opts["max_fall_prob"],
                "escape_falls": int(critic.opts["escape_falls"])}
    out: dict[str, Any] = {"handover": isinstance(critic, Handover)}
    inner = critic.latent if isinstance(critic, Handover) else critic
    if isinstance(inner, FallAware):
        out["max_fall_prob"] = inner.max_fall_prob
    return out


def failure_streak(store: RunStore, phase: int) -> int:
    """How many of the last stored trials of ``phase`` (idx order) failed in a row."""
    fell = store.fell(phase)
    ok = np.flatnonzero(~fell)
    return int(len(fell) - (ok[-1] + 1 if len(ok) else 0))


def warn_if_failing(store: RunStore, phase: int,
                    strategy: str | Callable[[], str] = "plain",
                    running: Callable[[], dict[str, Any]] | None = None,
                    fixed: bool = False) -> bool:
    """Log :func:`failing_message` (of phase 3's ``strategy``, with what the critic runs:
    ``running()``, and ``fixed``) when the streak of failed trials of ``phase`` has just reached
    :data:`FAIL_STREAK` (after a trial was stored); return whether it did. ``strategy`` may be
    a function that reads it; it and ``running`` are called only then (a told trial reads the
    study's config only when there is something to warn about)."""
    if failure_streak(store, phase) == FAIL_STREAK:
        log.warning(failing_message(phase, FAIL_STREAK,
                                    strategy() if callable(strategy) else strategy,
                                    None if running is None else running(), fixed))
        return True
    return False


def warn_if_flat(store: RunStore, phase: int) -> bool:
    """Log one warning when the trials of ``phase`` (1 or 3) that stood number just
    :data:`FLAT_COUNT` (call it after storing a trial that stood) and all cost the same: the
    cost does not tell those θ apart, so the search has nothing to follow. Returns whether it
    warned."""
    if int(phase) not in (Phase.PHASE1, Phase.PHASE3):
        return False
    y = store.costs(phase)[~store.fell(phase)]
    if len(y) != FLAT_COUNT or np.ptp(y) > 0:
        return False
    log.warning("phase %d: its %d trials that stood so far all cost %g: the cost does not tell "
                "these θ apart, so the search has nothing to follow; check what the system "
                "returns (a constant by mistake, a cost that saturates or is rounded)",
                int(phase), FLAT_COUNT, float(y[0]))
    return True


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
    thetas = U if Z is not None or decoder is None else np.atleast_2d(decoder(U))
    return thetas, stored_codes(U, Z, decoder is not None)


def stored_codes(U: np.ndarray, Z: np.ndarray | None, decoded: bool) -> list[np.ndarray | None]:
    """The latent code stored with each asked point (:func:`asked_points`): the finite rows of
    ``Z``, else the rows of ``U`` when they were ``decoded`` to θ, else none."""
    if Z is not None:
        return [z if np.all(np.isfinite(z)) else None for z in Z]
    return list(U) if decoded else [None] * len(U)


def told_order(rows: list[Row]) -> list[Row]:
    """``rows`` of a phase (index order) in the order the critic was told them: each batch in
    ask order (:data:`ASKED`)."""
    return sorted(rows, key=lambda r: (r.info or {}).get(ASKED, r.idx))


def state_key(phase: int) -> str:
    """The store's meta key of the critic state (:meth:`Critic.state_dict`) of ``phase``."""
    return f"critic_state_{int(phase)}"


def batch_key(phase: int) -> str:
    """The store's meta key of the batch of ``phase`` being evaluated (:class:`AskedBatch`)."""
    return f"asked_batch_{int(phase)}"


def fall_stop_key(phase: int) -> str:
    """The store's meta key of the record of a phase run that stopped in the middle of a batch
    because its fall budget was spent: ``{"n": rows of the phase then, "not_run": trials of
    the batch it did not run}`` (:func:`run_phase`, read by
    :func:`~latentune.pipeline.results.fall_budget`)."""
    return f"fall_stop_{int(phase)}"


def save_state(store: RunStore, phase: int, critic: Any,
               extra: dict[str, Any] | None = None) -> None:
    """Store ``critic.state_dict()`` for ``phase`` (nothing for a critic without state) and
    remove the record of the batch just told (:class:`AskedBatch`), in one transaction (with
    the meta entries ``extra``)."""
    state = critic.state_dict() if hasattr(critic, "state_dict") else {}
    store.update_meta({batch_key(phase): None, **({state_key(phase): state} if state else {}),
                       **(extra or {})})


@dataclass
class AskedBatch:
    """A batch the critic asked, recorded in the store until it is told (see "Resume and crash
    safety" above).

    Attributes:
        n0: rows of the phase stored when it was asked (its points get indices from n0 on).
        U: (k, m) the critic's points; ``T`` (k,) their tags; ``Z`` (k, m') a two-space
            critic's codes (``last_z``, NaN rows for none) or None.
        thetas: (k, d) the normalized θ to evaluate; ``codes``: the code stored with each.
        done: ask index -> (cost, fell) of the points evaluated so far.
    """

    n0: int
    U: np.ndarray
    T: np.ndarray
    Z: np.ndarray | None
    thetas: np.ndarray
    codes: list[np.ndarray | None]
    done: dict[int, tuple[float, bool]] = field(default_factory=dict)

    def record(self) -> dict[str, Any]:
        """The JSON record stored under :func:`batch_key` (floats round-trip exactly)."""
        return {"n0": self.n0, "u": self.U.tolist(), "tags": self.T.tolist(),
                "z": None if self.Z is None else self.Z.tolist(), "theta": self.thetas.tolist()}


def pending_batch(store: RunStore, phase: int, budget: int, decoder: Callable | None
                  ) -> AskedBatch | None:
    """The recorded batch of ``phase`` a stopped run did not tell (its evaluated points in
    ``done``), or None: no record, or one the stored rows do not continue (rows stored after
    it that are not its points, a budget it does not fit in)."""
    rec = store.get_meta(batch_key(phase))
    if not rec:
        return None
    try:
        U = np.array(rec["u"], dtype=float)
        Z = None if rec["z"] is None else np.array(rec["z"], dtype=float)
        b = AskedBatch(int(rec["n0"]), U, np.array(rec["tags"], dtype=np.int64), Z,
                       np.array(rec["theta"], dtype=float),
                       stored_codes(U, Z, Z is None and decoder is not None))
    except (KeyError, TypeError, ValueError):
        log.warning("phase %d: the record of the last asked batch is garbled; it is ignored "
                    "(the critic asks again)", int(phase))
        return None
    k, n = len(b.thetas), store.count(phase)
    if not b.n0 <= n <= b.n0 + k or b.n0 + k > budget or len(b.T) != k or len(b.U) != k:
        return None
    for r in store.rows(phase)[b.n0:]:
        i = next((i for i in range(k) if i not in b.done and b.T[i] == r.tag
                  and np.array_equal(b.thetas[i], r.theta)), None)
        if i is None:
            return None
        b.done[i] = (float(r.cost), bool(r.fell))
    return b


def reask(critic: Any, batch: AskedBatch, decoder: Callable | None,
          known: dict[bytes, Outcome] | None = None, twins: bool = False) -> None:
    """Ask ``critic``, told the rows stored before ``batch``, for as many points as ``batch``
    holds, so its state (model fits, random streams, Optuna's trials) is the one the stopped
    run's critic had while the batch was evaluated; the recorded points are the ones evaluated
    and told. A critic that asks other points (not deterministic) is told the recorded ones as
    points of its batch (a warning says so). ``known``: the stored outcomes the batch was
    ordered by when it was asked (:func:`ask_batch`; ``twins`` as there)."""
    U, T = ask_batch(critic, len(batch.thetas), decoder, known, twins)[:2]
    if U.shape != batch.U.shape or not (np.array_equal(U, batch.U)
                                        and np.array_equal(T, batch.T)):
        log.warning("the critic asked again for the batch a stopped run left unfinished gives "
                    "other points (it is not deterministic); the recorded points are evaluated "
                    "and told, and the run may differ from one that was never stopped")


def replay(store: RunStore, phase: int, critic: Any, upto: int | None = None) -> int:
    """Tell ``critic`` the stored rows of ``phase`` (idx order, with their tags; only the first
    ``upto`` when given) and restore its stored state (:func:`save_state`); return how many
    rows it was told."""
    n = _tell_rows(store, phase, critic, upto)
    state = store.get_meta(state_key(phase))
    if n and state and hasattr(critic, "load_state_dict"):
        critic.load_state_dict(state)
    return n


def _tell_rows(store: RunStore, phase: int, critic: Any, upto: int | None = None) -> int:
    store.check_contiguous(phase)
    rows = told_order(store.rows(phase)[:upto])
    if not rows:
        return 0
    y = np.array([r.cost for r in rows])
    tags = np.array([r.tag for r in rows], dtype=np.int64)
    fell = np.array([r.fell for r in rows], dtype=bool)
    if hasattr(critic, "last_z"):                  # a two-space critic: θ, and z where stored
        k = critic.last_z.shape[1]
        Z = np.array([r.z if r.z is not None and len(r.z) == k else np.full(k, np.nan)
                      for r in rows])
        critic.tell(np.array([r.theta for r in rows]), y, tags, fell=fell, z=Z)
        return len(rows)
    X = np.array([r.z if r.z is not None else r.theta for r in rows])      # the critic's box
    if X.shape[1] != critic.dim:
        raise StoreError(f"stored phase-{phase} points have dimension {X.shape[1]}, "
                         f"the critic {critic.dim}")
    critic.tell(X, y, tags, fell=fell)
    return len(rows)


def ask_batch(critic: Any, k: int, decoder: Callable | None,
              known: dict[bytes, Outcome] | None = None, twins: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, list[Any]]:
    """Ask ``critic`` for ``k`` points: (U (k, m) its points, tags (k,), Z (k, m') a
    two-space critic's codes or None, θ (k, d), the code to store with each θ);
    with ``known`` (or ``twins``), in the order they are stored and told
    (:func:`reused_first`), else in ask order."""
    U = critic.ask(k)
    T = critic.last_tags.copy()
    Z = getattr(critic, "last_z", None)           # a two-space critic's latent codes
    Z = None if Z is None else Z.copy()
    thetas, codes = asked_points(U, Z, decoder)
    if not known and not twins:
        return U, T, Z, thetas, codes
    o = reused_first(thetas, known or {}, twins)
    return (U[o], T[o], None if Z is None else Z[o], np.asarray(thetas)[o],
            [codes[i] for i in o])


def run_phase(store: RunStore, phase: int, system: Any, critic: Any, budget: int,
              evaluator: Evaluator,
              decoder: Callable[[np.ndarray], np.ndarray] | None = None, seed: int | None = None,
              progress: bool = False, on_row: Callable[[int, float], None] | None = None,
              max_new: int | None = None, known: dict[bytes, Outcome] | None = None,
              strategy: str = "plain", reuse: tuple[int, ...] = ()) -> PhaseResult:
    """Run (or resume) one tuning phase until ``budget`` evaluations are stored, or until a
    critic with a fall budget (``fall_budget_spent``: the transfer critic's ``fall_budget``)
    has spent it. The budget is checked before each trial starts (its
    ``fall_budget_spent_after`` the batch's finished trials): once spent, the batch's trials
    not started are not run (those running on other workers finish and are stored), the
    critic is told the ones that ran, and the stop is recorded (:func:`fall_stop_key`;
    ``PhaseResult.not_run``). Ask/tell's suggestions not handed out yet are withdrawn (this run
    asks its own), unless the fall budget is spent already: then they count as not run.

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
        strategy: phase 3's strategy (``"transfer"`` or ``"plain"``): what the warning of a
            streak of failed trials suggests (:func:`failing_message`).
        reuse: phases whose stored trials join ``known`` at each batch (the rows stored before
            it, :func:`stored_outcomes`; :func:`~latentune.pipeline.loop.reuse_phases`): a θ
            asked again is stored with the outcome it had (a row of the phase, in its budget),
            as ask/tell stores it, and said at INFO (:func:`say_reused`). A batch is stored
            and told with those first (:func:`reused_first`). With ``reuse``, a θ asked twice
            within a batch is run once: the second is stored with the first's outcome right
            after it (:func:`batch_twins`, :func:`twin_outcome`).

    Raises:
        EvaluationError: a trial raised or gave no usable cost; the batch's finished trials are
            stored first, the failed one is not (a resume runs it again).
        ClusterLost: the Ray cluster's head was lost; its message says how many evaluations
            of the phase are stored (a resume runs the batch's others).
    """
    t0 = time.perf_counter()
    batch = pending_batch(store, phase, budget, decoder)
    replay(store, phase, critic, None if batch is None else batch.n0)
    if batch is not None or not getattr(critic, "fall_budget_spent", False):
        store.drop_queued((phase,))     # ask/tell's, not handed out yet: this run asks its own
    # (else the fall budget is spent: they stay, asked and not run, as status counts them)
    y = store.costs(phase)
    idx = n0 = len(y)

    def known_at(n: int) -> dict[bytes, Outcome]:   # what a batch asked at row n reuses
        return {**(known or {}), **stored_outcomes(store, reuse, {int(phase): n})}
    kn = known_at(n0 if batch is None else batch.n0)
    if batch is not None:
        reask(critic, batch, decoder, kn, bool(reuse))
        log.info("phase %d: finishing the batch of %d points a stopped run asked (%d of them "
                 "stored)", int(phase), len(batch.thetas), len(batch.done))
    bar = _progress(budget, min(n0, budget), f"phase {phase}", progress)
    b = store.best(phase)           # the lowest cost of a trial that stood
    best = math.inf if b is None else float(b.cost)
    streak = failure_streak(store, phase)
    stopped = 0                     # of them, the trials stopped at the trial timeout
    standing = int((~store.fell(phase)).sum())      # the trials that stood (warn_if_flat)
    new = 0
    not_run = asked = 0
    spent_after = getattr(critic, "fall_budget_spent_after", None)
    if spent_after is not None and critic.falls_allowed() is None:
        spent_after = None          # no fall budget: a batch runs whole

    def spent() -> bool:            # the fall budget, with the batch's finished trials
        return spent_after(np.array([batch.done[i][1] for i in sorted(batch.done)],
                                    dtype=bool))

    def put(i: int, r: Outcome) -> None:    # store row i of the batch, as told
        nonlocal idx, new, streak, stopped, best, standing
        cost = float(r.cost)
        say_reused(phase, r)
        if batch.n0 + i != idx:         # out of ask order: where it was asked
            r = Outcome(r.cost, r.failed, {**r.info, ASKED: batch.n0 + i}, r.wall_s)
        store_outcome(store, phase, idx, batch.thetas[i], r, z=batch.codes[i],
                      tag=int(batch.T[i]), seed=seed)
        idx += 1
        new += 1
        batch.done[i] = (cost, bool(r.failed))
        streak = streak + 1 if r.failed else 0
        standing += 0 if r.failed else 1
        if standing == FLAT_COUNT and not r.failed:
            warn_if_flat(store, phase)
        stopped = stopped + 1 if r.failed and r.info.get("timed_out") else 0
        if streak == FAIL_STREAK:
            log.warning(timeout_message(phase, FAIL_STREAK, r.info.get("trial_timeout"))
                        if stopped == streak else
                        failing_message(phase, FAIL_STREAK, strategy, fall_options(critic)))
        if cost < best and not r.failed:
            best = cost
        if on_row is not None:
            on_row(idx, cost)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(best=f"{best:.3f}")
    try:
        if bar is not None and n0:
            bar.set_postfix(best=f"{best:.3f}")
        while idx < budget and (max_new is None or new < max_new):
            if batch is None and getattr(critic, "fall_budget_spent", False):
                rec = store.get_meta(fall_stop_key(phase)) or {}    # a stop in a batch before
                not_run = int(rec.get("not_run", 0)) if rec.get("n") == idx else 0
                asked = sum(1 for t in store.trials("queued")      # ask/tell's
                            if t.phase in (phase, Phase.ZERO_SHOT))
                not_run += asked
                _say_fall_stop(phase, critic.falls_allowed(), idx, budget, not_run, asked)
                break
            if batch is None:
                k = min(critic.batch_size, budget - idx)   # whole: max_new leaves the rest
                kn = known_at(idx)
                batch = AskedBatch(idx, *ask_batch(critic, k, decoder, kn,       # for the resume
                                                   bool(reuse)))
                store.set_meta(batch_key(phase), batch.record())
            U, T, Z, thetas = batch.U, batch.T, batch.Z, batch.thetas
            todo = [i for i in range(len(thetas)) if i not in batch.done]
            if max_new is not None:
                todo = todo[:max_new - new]
            # a θ asked twice in the batch is run once (the plain phase 3): the second is
            # stored with the first's outcome right after it (or now, the first stored before)
            twin_of = batch_twins(thetas, kn) if reuse else {}
            runs = [i for i in todo if i not in twin_of]
            error: str | None = None
            for i in [i for i in todo if twin_of.get(i) in batch.done]:
                put(i, twin_outcome(store, phase, thetas[i]))
            for j, r in _lost_head_says_stored(
                    _results(evaluator, system, thetas[runs], kn,
                             None if spent_after is None else spent), store, phase):
                i = runs[j]
                if isinstance(r, TrialError):
                    error = error or r.message
                    continue
                put(i, r)
                for t in (t for t in todo if twin_of.get(t) == i):
                    put(t, twin_outcome(store, phase, thetas[t]))
            if error is not None:
                raise EvaluationError(f"{error} (phase {int(phase)}; "
                                      f"{counted(idx, 'evaluation')} "
                                      f"{'is' if idx == 1 else 'are'} stored; fix the system "
                                      "and resume)")
            if spent_after is not None and len(batch.done) < len(thetas) and spent():
                keep = sorted(batch.done)           # told in ask order, as a whole batch is
                not_run = len(thetas) - len(keep)
                critic.tell(U[keep], np.array([batch.done[i][0] for i in keep], dtype=float),
                            T[keep].astype(np.int64),
                            fell=np.array([batch.done[i][1] for i in keep], dtype=bool),
                            **({} if Z is None else {"z": Z[keep]}))
                save_state(store, phase, critic,
                           {fall_stop_key(phase): {"n": idx, "not_run": not_run}})
                _say_fall_stop(phase, critic.falls_allowed(), idx, budget, not_run)
                batch = None
                break
            if len(batch.done) < len(thetas):      # max_new stopped it: it stays recorded
                break
            # rows are stored as they complete (crash safety); the critic is told the batch in
            # ask order, so a seed gives the same run whatever order the workers finish in
            yb = np.array([batch.done[i][0] for i in range(len(thetas))], dtype=float)
            fb = np.array([batch.done[i][1] for i in range(len(thetas))], dtype=bool)
            critic.tell(U, yb, T.astype(np.int64), fell=fb, **({} if Z is None else {"z": Z}))
            save_state(store, phase, critic)
            batch = None
    finally:
        if bar is not None:
            bar.close()
    b = store.best(phase)
    wall = time.perf_counter() - t0
    return PhaseResult(phase, store.count(phase), new, b.cost if b else math.inf,
                       None if b is None else b.theta, wall, not_run, asked)


def _say_fall_stop(phase: int, allowed: int, n: int, budget: int, not_run: int,
                   asked: int = 0) -> None:
    """Warn that ``phase`` stopped at ``n`` of its ``budget`` trials because its fall budget
    (``allowed`` falls) is spent, with the ``not_run`` trials it did not start (``asked`` of
    them: ask/tell's queued suggestions; :func:`not_run_note`), as the ask/tell ``tell`` that
    spends it warns."""
    log.warning("phase %d's fall budget is spent (%s allowed): stopped after %d of %d trials%s; "
                "its best θ is the result", int(phase), counted(allowed, "fall"), n, budget,
                not_run_note(not_run, asked))


def _lost_head_says_stored(results: Any, store: RunStore, phase: int) -> Any:
    """``results`` as they come; a :class:`ClusterLost` among them again with the number of
    evaluations of ``phase`` stored."""
    try:
        yield from results
    except ClusterLost as exc:
        raise ClusterLost(f"{exc} ({counted(store.count(phase), 'evaluation')} of phase "
                          f"{int(phase)} stored)") from None


def _results(evaluator: Evaluator, system: Any, thetas: np.ndarray,
             known: dict[bytes, Outcome], stop: Callable[[], bool] | None = None) -> Any:
    """``(i, Outcome | TrialError)`` for each row of ``thetas``: known ones first (not run).
    ``stop``: no further row once it returns True (the evaluator's ``imap(..., stop=)``; an
    evaluator whose ``imap`` takes no ``stop`` is left after the result that made it True)."""
    thetas = np.ascontiguousarray(thetas, dtype=float)
    reuse = [i for i in range(len(thetas)) if thetas[i].tobytes() in known]
    for i in reuse:
        if stop is not None and stop():
            return
        out = known[thetas[i].tobytes()]
        yield i, Outcome(out.cost, out.failed, {**out.info, "reused": True}, out.wall_s)
    todo = [i for i in range(len(thetas)) if i not in reuse]
    if not todo:
        return
    if stop is None:
        results = evaluator.imap(system, thetas[todo])
    elif "stop" in inspect.signature(evaluator.imap).parameters:
        results = evaluator.imap(system, thetas[todo], stop=stop)
    else:
        results = _until(evaluator.imap(system, thetas[todo]), stop)
    for j, r in results:
        yield todo[j], r


def _until(results: Any, stop: Callable[[], bool]) -> Any:
    """``results`` as they come, left (closed) once ``stop()`` is True after one."""
    if stop():
        return
    it = iter(results)
    try:
        for r in it:
            yield r
            if stop():
                return
    finally:
        close = getattr(it, "close", None)
        if close is not None:
            close()


def ensure_manual(store: RunStore, system: Any, seed: int | None = None,
                  evaluator: Evaluator | None = None, idx: int = 0) -> float:
    """Evaluate the system's manual θ once (phase 0, row ``idx``) and return its cost; on
    ``evaluator`` (the phase's: a crash or a timeout of the trial is a failed trial there), else
    in this process. A zero-shot trial of the manual θ stored already (the source's best was
    the manual θ) gives its outcome instead (:func:`reused_outcome`)."""
    for r in store.rows(Phase.MANUAL):
        if r.idx == idx:
            return r.cost
    from latentune.system import evaluate

    out = reused_outcome(store, Phase.MANUAL, system.space.manual, (Phase.ZERO_SHOT,))
    if out is None:
        out = evaluator.one(system, system.space.manual) if evaluator is not None \
            else evaluate(system, system.space.manual)
    store_outcome(store, Phase.MANUAL, idx, system.space.manual, out, seed=seed)
    return float(out.cost)


def theta_key(theta: np.ndarray) -> bytes:
    """The key of a (d,) θ among stored trials: the bytes of its float64 values (equal θ, equal
    keys: :func:`stored_outcomes`, :func:`batch_twins`)."""
    return np.ascontiguousarray(theta, dtype=float).tobytes()


def reused_outcome(store: RunStore, phase: int, theta: np.ndarray,
                   phases: tuple[int, ...]) -> Outcome | None:
    """The outcome of the stored trial of ``phases`` whose θ is ``theta`` (its ``info`` with
    ``"reused": True`` and ``"same_as"``, :func:`stored_outcomes`), said at INFO for a trial
    of ``phase`` that is then not run (:func:`say_reused`); None when there is none."""
    out = stored_outcomes(store, phases).get(theta_key(theta))
    if out is None:
        return None
    say_reused(phase, out)
    return Outcome(out.cost, out.failed, {**out.info, "reused": True}, out.wall_s)


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


def stored_outcomes(store: RunStore, phases: tuple[int, ...],
                    upto: dict[int, int] | None = None) -> dict[bytes, Outcome]:
    """The stored trials of ``phases`` (``upto``: only the first ``upto[p]`` rows of phase
    ``p``) by the bytes of their (d,) float64 θ, the first stored of equal θ, each as the
    Outcome a θ asked again is stored with instead of a new trial (:func:`run_phase`'s
    ``known``; ``info["same_as"]``: [phase, idx] of the trial it repeats)."""
    out: dict[bytes, Outcome] = {}
    for ph in phases:
        rows = store.rows(ph)
        for r in rows if upto is None or ph not in upto else rows[:upto[ph]]:
            key = theta_key(r.theta)
            if key in out:
                continue
            info = {k: v for k, v in (r.info or {}).items() if k not in NOT_REUSED}
            if r.fall_step is not None:
                info["fall_step"] = r.fall_step
            out[key] = Outcome(r.cost, r.fell, {**info, "same_as": [int(ph), int(r.idx)]},
                               r.wall_s)
    return out


def reused_first(thetas: np.ndarray, known: dict[bytes, Outcome], twins: bool = False
                 ) -> np.ndarray:
    """The order in which a batch of asked ``thetas`` (k, d) is stored and told: its θ found in
    ``known`` (stored with that outcome, not run) first, then the others, each part in ask
    order; with ``twins``, a θ asked again within the batch right after the first of its θ
    (:func:`batch_twins`: stored with that one's outcome once it is told). The phase run and
    ask/tell store a batch in this order alike, so the critic is told the same rows in the same
    order whichever drives the loop."""
    keys = [theta_key(t) for t in thetas]
    hit = [i for i in range(len(thetas)) if keys[i] in known]
    rest = [i for i in range(len(thetas)) if i not in hit]
    if twins:
        of = batch_twins(thetas, known)
        order: list[int] = []
        for i in rest:
            if i not in of:
                order += [i, *(t for t in rest if of.get(t) == i)]
        rest = order
    return np.array(hit + rest, dtype=np.int64)


def batch_twins(thetas: np.ndarray, known: dict[bytes, Outcome]) -> dict[int, int]:
    """The θ of a batch (k, d) asked again within it and not in ``known``: ``{i: j}``, row i
    repeats the earlier row j (the first of its θ), which is run; i is not (the plain phase 3,
    :func:`~latentune.pipeline.loop.reuse_phases`)."""
    first: dict[bytes, int] = {}
    out: dict[int, int] = {}
    for i, t in enumerate(thetas):
        key = theta_key(t)
        if key in known:
            continue
        if key in first:
            out[i] = first[key]
        else:
            first[key] = i
    return out


def twin_outcome(store: RunStore, phase: int, theta: np.ndarray) -> Outcome:
    """The outcome a θ asked twice in one batch (:func:`batch_twins`) is stored with: that of
    the first stored trial of ``phase`` with its θ (``info``: ``"reused"``, ``"same_as"``)."""
    out = stored_outcomes(store, (phase,))[theta_key(theta)]
    return Outcome(out.cost, out.failed, {**out.info, "reused": True}, out.wall_s)


def say_reused(phase: int, out: Outcome) -> None:
    """Log at INFO that an asked θ is the θ of a stored trial (``out.info["same_as"]``) and is
    stored with its outcome instead of being run again."""
    same = out.info.get("same_as")
    if same is not None:
        log.info("phase %d: an asked θ is the θ of the stored %s trial %d: stored with its "
                 "outcome, not run again", int(phase), phase_name(same[0]), int(same[1]))


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
