"""Ask/tell: a phase driven by a person (trials run elsewhere: a real robot, a lab).

The same loop as a phase run (:mod:`latentune.pipeline.loop`): the critic is built from the
study's stored options and seed and told the stored rows; it is asked a batch of the study's
batch size, queued in the store, and handed out one suggestion at a time. The next batch is
asked once the queue is empty, so a person who asks and tells one trial at a time gets, for a
seed, the rows a phase run gives.

Several askers
--------------
A suggestion is leased to the asker that got it (``asker``, default "default") for ``lease_s``
seconds (default :data:`LEASE_S`, one hour). The same asker asking again gets its pending
suggestions again (``again``); another asker gets other ones. A lease that is never told
expires and its suggestion is handed out again to the next asker; :func:`release` ends a lease
on request. Two askers never hold the same suggestion at once, and every step is one SQLite
transaction under the study's lock (an asker waits up to :data:`WAIT_S` seconds for another's
ask to finish), so a kill loses nothing: an asked batch is queued or not at all, a told
result is stored and its suggestion marked told together.

Prepared suggestions
--------------------
Building the critic (its libraries, the GP fits) takes seconds; leasing a stored suggestion
does not. So :func:`tell` (and :func:`tell` with ``amend``) ends by preparing the next batch
when the next ask would have to ask the critic (no suggestion queued or handed out): the
critic is asked exactly as that ask would ask it and the batch is stored, with the critic's
new state, in the store's meta entry :data:`NEXT_KEY`, under a key made of everything the
batch depends on (the phase's options record, the store's :meth:`~RunStore.data_version`,
the critic's saved state, and the data version of the runs the critic reads: the latent
space's source, the fall prior). An ask whose options are the stored ones then leases from
it without building the critic; a prepared batch whose key differs when it is asked for (a
tell, an amendment, a release or a lease since, a grown budget, other options), or that is
smaller than the ask needs, is dropped unseen and the ask asks the critic itself. So a
study's suggestions, ids and rows are the same with or without the preparation, and a kill
loses nothing: the prepared batch is written in one transaction after the told result's, and
turned into queued suggestions (with the critic's state) in one transaction.

One θ, one trial
----------------
In the plain phase 3 a θ the critic asks that the study holds a trial of already (the manual
θ's, the zero-shot trial's, phase 3's own: :func:`~latentune.pipeline.loop.reuse_phases`) is not
handed out: :func:`_queue` stores it at once with that trial's outcome (``info["reused"]``),
first in its batch, as the phase run stores it (:func:`~latentune.pipeline.phases.run_phase`'s
``reuse``); it counts in the budget in both. A θ the critic asks twice within a batch (or that
another suggestion still out holds) waits, not handed out, and is told the first one's outcome
as soon as that is told (:func:`tell_twins`), as the phase run stores it right after the first.
A zero-shot θ the study holds a trial of is stored from it the same way
(:func:`~latentune.pipeline.baselines.queue_zero_shot`).

Corrections
-----------
``tell(..., amend=True)`` replaces a told result; the store keeps the old one in its audit
trail (``amendments``), and amends the rows stored as copies of it (``info["same_as"]``, by
ask/tell or a phase run alike), each with its own entry (:meth:`RunStore.amend_trial`).
When the cost, fall flag or fall step changed, it drops the suggestions queued from the uncorrected rows and the critic's saved state but what does not depend on the
rows (:data:`ROW_FREE`: the transfer critic's options, source fits and record of decisions), so
the next ask rebuilds the critic from the corrected rows (phase 3's too when the zero-shot
trial is amended: the transfer critic is told it, :func:`~latentune.pipeline.store.critics_told`).

Suggestion files (``DIR/suggestions/<id>.json``, the ``--params`` file of a suggestion) belong
to the command line: :func:`write_suggestion_files` and :func:`prune_suggestion_files`
(the directory holds the files of the suggestions handed out and not told).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.checks import is_whole
from latentune.constants import Phase
from latentune.errors import LatentuneError, StoreError, UsageError
from latentune.pipeline import manifest as mf
from latentune.pipeline.baselines import queue_zero_shot, zero_shot_to_queue
from latentune.pipeline.loop import (began_latent, check_phase1_runs, check_source_run,
                                     decoder_of, latent_to_record, phase_critic, record_latent,
                                     refuse_plain_options, require_source_store,
                                     resolve_latent, resolve_strategy, reuse_phases,
                                     source_pin, strategy_of)
from latentune.pipeline.phases import (ask_batch, replay, reused_first, say_reused, state_key,
                                       stored_fall_options, stored_outcomes, theta_key,
                                       warn_if_failing, warn_if_flat)
from latentune.pipeline.results import best_row, fall_budget, phase_name, write_best
from latentune.pipeline.store import DEFAULT_ASKER, Row, RunStore, critics_told
from latentune.space import ParameterSpace
from latentune.system import EvaluationError, Outcome, as_outcome
from latentune.wording import counted, option

ROW_FREE = ("options", "source_hypers", "decisions", "last_decision")
"""The keys of a critic's saved state an amendment keeps: the transfer critic's
(:meth:`~latentune.critic.transfer.Transfer.state_dict`) options, source models' fits and
record of its asks, none of which depends on the target's told rows."""

RISK_KEY = "asktell_fall_risk"
"""Meta entry: suggestion id -> the highest probability of falling the transfer critic's fall
model gave θ of the ask that queued it (its decision's ``max_fall_prob_asked``), recorded when
queued: after an amendment the rebuilt critic asks that generation again and its decision
replaces the first one in the critic's record."""

LEASE_S = 3600.0
"""How long a suggestion stays leased to its asker when it is not told [s] (one hour)."""
WAIT_S = 60.0
"""How long an ask or a tell waits for another writer of the study [s]."""
OPTIONS = ("strategy", "method", "budget", "regions", "start", "max_fall_prob", "fall_prior",
           "handover", "transfer_options")
"""The phase options an ask takes (each None for "the stored one")."""
NEXT_KEY = "asktell_next"
"""The store's meta entry of the prepared batch (see the module docstring)."""
SCRATCH = "scratch"
"""The ``start`` of an ask that starts from the critic's own initial design (a phase run's
``start=None``; None in an ask means "the stored one")."""

log = logging.getLogger(__name__)


class FallBudgetSpent(StoreError):
    """The ask of a transfer phase 3 whose fall budget is spent: the phase asks no more."""


@dataclass
class Suggestion:
    """A θ handed out by ``ask`` for a trial run elsewhere.

    Attributes:
        id: the suggestion id to pass to ``tell``.
        phase: 1, 3 (phase 3: the latent space) or 4 (zero-shot: the source study's best θ as
            it is, handed out before phase 3's first suggestion).
        theta: (d,) normalized θ; ``params``: the physical values by name.
        z: (d_low,) the latent unit-box point in phase 3, else None.
        again: True if it was handed out before (to this asker, or a lease that expired).
        asker: who holds it; ``lease_until``: unix time its lease ends.
        path: its ``--params`` file once written (:func:`write_suggestion_files`), else None.
        fall_risk: ``(p, bound)`` when the transfer phase 3's ask that gave it rated a θ it
            asked ``p`` likely to fall, above its fall screen's ``bound`` (the critic took θ
            its screen would refuse: run it with care), else None (:func:`fall_risk`).
    """

    id: int
    phase: int
    theta: np.ndarray
    params: dict[str, float]
    z: np.ndarray | None = None
    again: bool = False
    path: str | None = None
    asker: str | None = None
    lease_until: float | None = None
    fall_risk: tuple[float, float] | None = None

    @property
    def phase_name(self) -> str:
        """"phase 1", "phase 3" or "zero-shot"."""
        return phase_name(self.phase)

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "phase": self.phase, "phase_name": self.phase_name,
                "again": self.again, "params": self.params, "theta": self.theta.tolist(),
                "file": self.path, "asker": self.asker, "lease_until": self.lease_until,
                "fall_risk": None if self.fall_risk is None else
                {"max_fall_prob": self.fall_risk[0], "bound": self.fall_risk[1]}}


def write_suggestion_files(run_dir: str | os.PathLike, suggestions: list[Suggestion]) -> None:
    """Write each suggestion's ``--params`` file ``DIR/suggestions/<id>.json`` (physical values
    by name and nothing else: the file a robot program reads, which may pass every entry on to
    its controller; ``best.json`` records what its θ are tuned for, a suggestion does not) and set
    its ``path``."""
    d = Path(run_dir) / "suggestions"
    d.mkdir(parents=True, exist_ok=True)
    for s in suggestions:
        path = d / f"{s.id}.json"
        write_atomic(path, json.dumps(s.params, indent=1))
        s.path = str(path)


def prune_suggestion_files(run_dir: str | os.PathLike, pending: Any) -> list[int]:
    """Remove the suggestion files ``DIR/suggestions/<id>.json`` whose id is not in
    ``pending`` (told, released, or withdrawn unasked after an amendment or a phase run), so
    the directory shows only θ handed out to be run; other files are left. Returns the ids
    removed."""
    d = Path(run_dir) / "suggestions"
    keep = {int(i) for i in pending}
    gone = []
    for path in d.glob("*.json") if d.is_dir() else ():
        if path.stem.isdigit() and int(path.stem) not in keep:
            path.unlink(missing_ok=True)
            gone.append(int(path.stem))
    return sorted(gone)


def edited_suggestion(run_dir: str | os.PathLike, trial_id: int, theta: np.ndarray,
                      space: ParameterSpace) -> str | None:
    """How ``DIR/suggestions/<id>.json`` differs from the θ suggestion ``trial_id`` holds
    (``theta``, unit box): "NAME = V in it, W suggested" for the first changed value, or why
    it no longer reads as a θ; None when it holds that θ or there is no file."""
    from latentune.errors import ParamsError

    path = Path(run_dir) / "suggestions" / f"{int(trial_id)}.json"
    if not path.is_file():
        return None
    try:
        given = space.to_physical(space.load(path))
    except ParamsError as exc:
        return str(exc).replace(f"params file {path} ", "it ")
    stored = space.to_physical(np.asarray(theta, dtype=float))
    diff = [i for i in range(space.dim)
            if not np.isclose(given[i], stored[i], rtol=1e-9, atol=1e-12)]
    if not diff:
        return None
    i = diff[0]
    return (f"{space.names[i]} = {given[i]:.6g} in it, {stored[i]:.6g} suggested"
            + (f", and {len(diff) - 1} more" if len(diff) > 1 else ""))


def _check_asker(who: Any) -> str:
    """``who``, an asker's name (UsageError unless a non-empty name on one line)."""
    if not isinstance(who, str) or not who.strip() or not who.isprintable():
        raise UsageError(f"asker must be a non-empty name on one line, got {who!r:.60}")
    return who


def _check_id(trial_id: Any) -> int:
    if isinstance(trial_id, bool) or not isinstance(trial_id, (int, np.integer)):
        raise UsageError(f"a suggestion id is an integer, got {trial_id!r}")
    return int(trial_id)


def _space(study: Any, system: Any, space: ParameterSpace | None, bind: bool = True
           ) -> ParameterSpace:
    """The space of an ask: the system's, the given one or the stored one, checked; recorded
    in the manifest with ``bind`` (else only checked: nothing is written)."""
    if space is not None and not isinstance(space, ParameterSpace):
        raise UsageError(f"space must be a latentune.ParameterSpace, not "
                         f"{type(space).__name__} (ParameterSpace.from_dict reads a dict)")
    if system is not None and space is not None and space != getattr(system, "space", None):
        raise UsageError("give a system or a space, not both: the system's space is not the "
                         "space given")
    if system is not None:
        study.manifest.bind(system) if bind else study.manifest.bind_check(system)
        return system.space
    if space is not None:
        if bind:
            study.manifest.bind_space(space)
        return space
    stored = study.manifest.space()
    if stored is None:
        raise StoreError(f"{study.dir}: no parameter space yet: the first ask needs a system "
                         "or a space")
    return stored


def _phase(cfg: dict[str, Any], phase: int | None, latent: Any, dir_: Path,
           trained: Any = None) -> int:
    """The phase an ask runs: the one ask/tell stored, else ``phase``, else 3 when a latent
    space is given or the run holds a phase 3 (a phase run's, ``phase3 --vae``), else 1.
    ``trained``: the store of ``dir_`` (whether it holds a latent space, for the refusal of
    phase 3 where ask/tell runs phase 1), or None."""
    stored = (cfg.get("asktell") or {}).get("phase")
    if phase is not None and not is_whole(phase):
        raise UsageError(f"ask/tell runs phase 1 or 3, not {phase!r}")
    if stored is not None:
        if phase is not None and int(phase) != int(stored):
            advice = ""
            if int(stored) == Phase.PHASE1:     # phase 3 goes elsewhere, with a latent space
                vae = _named(dir_ if latent is None else latent)
                advice = f"; ask phase 3 in another directory, with {vae}"
                if latent is None and trained is not None and trained.artifact("vae") is None:
                    advice = (f"; {dir_} holds no latent space yet: train one there first "
                              f"(train_latent / train-vae), then ask phase 3 in another "
                              f"directory, with {_named(dir_)}")
            raise StoreError(f"{dir_}: ask/tell runs phase {stored} (stored), not {phase}{advice}")
        return int(stored)
    if phase is None:
        phase = Phase.PHASE3 if latent is not None or cfg.get(mf.PHASE_KEYS[Phase.PHASE3]) \
            else Phase.PHASE1
    if int(phase) not in (Phase.PHASE1, Phase.PHASE3):
        raise UsageError(f"ask/tell runs phase 1 or 3, not {phase}")
    return int(phase)


def _named(latent: Any) -> str:
    """The latent space an ask was given, as a user gives it again: its directory by the
    option that takes it (:func:`latentune.wording.option`: ``--vae DIR``, quoted for a shell
    where it needs it, at the command line; ``latent='DIR'`` in Python), or "the latent space
    given" for a LatentSpace object."""
    if isinstance(latent, (str, os.PathLike)):
        return option("latent", latent)
    return "the latent space given"


def _start_record(start: Any, space: ParameterSpace) -> Any:
    """The stored record of an ask's (not None) ``start``: "manual", None for
    :data:`SCRATCH`, or the unit-box θ as a list."""
    if isinstance(start, str) and start == SCRATCH:
        return None
    if isinstance(start, str) and start != "manual":
        raise UsageError(f"start must be 'manual', '{SCRATCH}' or a θ, got {start!r}")
    return mf.start_point(start, space.manual, space.dim)[1]


def _start_shown(record: Any) -> str:
    """A start record as the user gives it: 'manual', 'scratch' (stored as None) or a θ."""
    s = repr(SCRATCH if record is None else record)
    return s if len(s) <= 60 else s[:57] + "..."


def _normalized(given: dict[str, Any], space: ParameterSpace) -> dict[str, Any]:
    """The given ask options as their stored records (None stays None: "the stored one");
    ``start`` is left out (:func:`_start_record`)."""
    g = {k: v for k, v in given.items() if k != "start"}
    if g.get("handover") is not None:
        g["handover"] = mf.handover(g["handover"])
    if g.get("max_fall_prob") is not None:
        g["max_fall_prob"] = mf.fall_options(g["max_fall_prob"], None)["max_fall_prob"]
    if g.get("fall_prior") is not None:
        g["fall_prior"] = mf.prior_record(g["fall_prior"])
    if "transfer_options" in g:          # checked with the strategy by :func:`options`
        g["transfer_options"] = mf.transfer_record(g["transfer_options"])
    return g


def options(study: Any, phase: int, space: ParameterSpace, latent: Any, given: dict[str, Any],
            pin: bool = True) -> tuple[dict[str, Any], Any]:
    """(the checked options record of ``phase``, its LatentSpace or None) for an ask: options
    not given are the stored ones (or the defaults on the first ask); a given one that differs
    from the stored is refused (:func:`~latentune.pipeline.manifest.ask_options`). Writes
    nothing (:func:`_context` records the latent space) but the new place of a moved source
    run and the source's amendments reported (:func:`~latentune.pipeline.loop.
    check_source_run`). ``pin`` False: a check whose record is not kept
    (:func:`check_first_ask`), without reading the source's trials to pin them
    (:func:`~latentune.pipeline.loop.source_pin`)."""
    key = mf.PHASE_KEYS[Phase(phase)]
    cfg = study.manifest.config()
    fixed = (cfg.get("asktell") or {}).get("phase") == phase or study.manifest.n_used(phase)
    stored = cfg.get(key) if fixed else None
    for opt in ("handover", "transfer_options"):
        if phase == Phase.PHASE1 and given.get(opt):
            raise UsageError(f"{opt} is an option of phase 3")
    if phase == Phase.PHASE3 and given.get("fall_prior") is not None:
        raise UsageError("fall_prior is an option of phase 1: phase 3's fall prediction starts "
                         "from its latent space's source run")
    strategy = given.get("strategy")
    if phase == Phase.PHASE1 and strategy:
        raise UsageError("strategy is an option of phase 3")
    given = {k: v for k, v in given.items() if k != "strategy"}
    if phase == Phase.PHASE1 and latent is not None:
        if (cfg.get("asktell") or {}).get("phase") is None:     # phase 1 was asked for
            raise UsageError(f"{study.dir}: {option('phase', 1)} with {option('latent')}: a "
                             f"latent space is an option of phase 3: ask {option('phase', 3)} "
                             f"(or leave {option('phase', 1)} out)")
        raise UsageError(f"{study.dir}: ask/tell runs phase 1 here; a latent space is an option "
                         f"of phase 3: ask it in another directory, with {_named(latent)}")
    g = _normalized(given, space)
    strat = None
    if phase == Phase.PHASE3:       # before the stored options: they differ by strategy
        handover = (stored or {}).get("handover") if g.get("handover") is None \
            else g["handover"]
        strat = resolve_strategy(study.manifest, strategy, handover, fixed=bool(stored))
        start = given.get("start")      # "manual" is the option left out, as in Study.phase3
        if strat == "transfer" and start is not None \
                and not (isinstance(start, str) and start == "manual"):
            raise UsageError("start is an option of phase 1 and of the plain phase 3 "
                             f"({option('strategy', 'plain')}); the transfer phase 3 starts "
                             "from the manual θ and the source's best trials")
        refuse_plain_options(strat, given.get("method"), given.get("regions"))
    if stored:
        g = mf.ask_options(stored, g, study.dir, phase)
    else:
        g = {**g, "method": g.get("method") or "turbo",
             "budget": mf.ASK_BUDGET if g.get("budget") is None else g["budget"]}
    old_start = stored.get("start", "manual") if stored else "manual"
    start_rec = old_start
    if given.get("start") is not None:
        start_rec = _start_record(given["start"], space)
        if stored and start_rec != old_start:
            raise StoreError(f"{study.dir}: phase {int(phase)} runs with start = "
                             f"{_start_shown(old_start)} (stored), not {_start_shown(start_rec)}")
    mfp = g.get("max_fall_prob")
    ls = None
    if phase == Phase.PHASE3:
        ls, source = resolve_latent(study.run, study.manifest, latent, space)
        require_source_store(strat, source, mfp)
        check_source_run(study.run, study.manifest, source, ls,
                         latent is not None or mf.learns_from_source(strat, mfp))
        ls = began_latent(study.run, study.manifest, ls, source, latent is not None)
        extra = mf.phase3_extra(source, strat, start_rec, mfp, g.get("handover"),
                                g.get("transfer_options"),
                                *source_pin(study.dir, study.manifest, source,
                                            pin and mf.pins_source(strat, mfp, source)))
    else:
        extra = {"start": start_rec, **mf.fall_options(mfp, g.get("fall_prior"))}
    pc = study.manifest.phase_options(phase, method=g["method"], budget=g["budget"],
                                      regions=g.get("regions"), seed=study.seed,
                                      batch_size=study.batch_size_of(phase), extra=extra)
    if phase == Phase.PHASE1 and pin:
        pc = check_phase1_runs(study.run, study.manifest, pc)
    return pc, ls


def ask(study: Any, n: int = 1, *, system: Any = None, space: ParameterSpace | None = None,
        phase: int | None = None, latent: Any = None, asker: str | None = None,
        lease_s: float | None = None, **given: Any) -> list[Suggestion]:
    """Hand out ``n`` suggestions of ``study`` to ``asker`` (see the module docstring).

    ``given``: the phase's options (strategy, method, budget, regions, start, max_fall_prob,
    fall_prior, handover, transfer_options), each None for "the stored one"; ``start`` is
    "manual", :data:`SCRATCH` or a (d,) unit-box θ."""
    if not is_whole(n, 1):
        raise UsageError(f"n must be an integer >= 1, got {n!r}")
    who = _check_asker(DEFAULT_ASKER if asker is None else asker)
    if lease_s is not None and (isinstance(lease_s, bool) or not isinstance(
            lease_s, (int, float, np.integer, np.floating))):
        raise UsageError(f"lease_s must be a positive number of seconds, got {lease_s!r}")
    lease = LEASE_S if lease_s is None else float(lease_s)
    if not np.isfinite(lease) or lease <= 0:
        raise UsageError(f"lease_s must be a positive number of seconds, got {lease_s!r}")
    if not study.exists:        # the first ask: refused before the directory is written
        check_first_ask(study, system, space, phase, latent, given)
    with study.run.writing(wait=WAIT_S) as st, ExitStack() as undo:
        ctx = _stored_context(study, system, space, phase, latent, given)
        if ctx is None:         # options to record: a failure from here leaves the run as it was
            undo.enter_context(study.run.as_before_on_error())
            ctx = _context(study, st, system, space, phase, latent, given)
        phases = (Phase.ZERO_SHOT, ctx.phase) if ctx.phase == Phase.PHASE3 else (ctx.phase,)
        refuse_if_fall_budget_spent(study, st, ctx.phase, ctx.options)
        waits = reuse_phases(ctx.phase, ctx.options)
        tell_twins(study, st, waits)        # (a kill between a tell and its twins' tells)
        open_ = st.trials("pending") + st.trials("queued")
        undo.push(lambda kind, *_: _undo_leases(st, open_, kind))   # after the undos below
        got = st.lease(who, phases, int(n), lease, waits=waits)
        need = int(n) - len(got)
        if got and _budget_left(st, ctx.phase, ctx.options)[0] <= 0:
            need = 0                    # the budget is handed out: the suggestions there are
        while need > 0:
            told = st.count(ctx.phase)
            if not _take_prepared(study, st, ctx.phase, ctx.options, need):
                if not ctx.built:
                    ctx = _context(study, st, system, space, phase, latent, given, undo)
                _queue(study, st, ctx.phase, ctx.options,
                       _critic_batch(study, st, ctx.phase, ctx.options, ctx.space, ctx.latent,
                                     need))
            new = st.lease(who, (ctx.phase,), need, lease, queued_only=True, waits=waits)
            got, need = got + new, need - len(new)
            if st.count(ctx.phase) == told:
                break       # no θ of the batch was a stored trial's: the critic gave its all
            if got and _budget_left(st, ctx.phase, ctx.options)[0] <= 0:
                break       # (none handed out and the budget told: the next batch says so)
        if not got:             # never an empty answer: the critic asked only θ handed out
            raise StoreError(f"{study.dir}: {phase_name(ctx.phase)}'s critic gave no θ that is "
                             "not handed out already: tell the pending suggestions first")
        if len(got) < int(n):
            warn_fewer(study, st, ctx.phase, ctx.options, len(got), int(n))
        held = {t.id: t.asker for t in open_ if t.status == "pending"}
        for t, _ in got:                    # taken over from another asker's expired lease
            if held.get(t.id) not in (None, who):
                log.warning("suggestion %d was handed out to %s, whose lease expired: if it "
                            "runs there all the same, a tell naming that asker is refused "
                            "while this lease lasts; of tells naming no asker, the first "
                            "stands and the other is refused", t.id, "an asker without a name"
                            if held[t.id] == DEFAULT_ASKER else held[t.id])
        risky = fall_risk(st, ctx.phase, ctx.options)
        return [Suggestion(t.id, t.phase, t.theta, ctx.space.as_dict(t.theta), t.z, again,
                           None, t.asker, t.lease_until, risky(t)) for t, again in got]


def _undo_leases(st: RunStore, before: list[Any], kind: Any) -> bool:
    """The exit of a failed ask (``kind``: its exception's type, else None): the suggestions
    it handed out before it failed go back to how they were (``before``), so a failed ask
    hands out nothing. Returns False: the exception goes on."""
    if kind is not None:
        try:
            st.restore_leases(before)
        except Exception as exc:  # noqa: BLE001 - the ask's own error is the one to see
            log.warning("%s: could not undo the failed ask's leases: %s", st.dir, exc)
    return False


def warn_fewer(study: Any, st: RunStore, phase: int, pc: dict[str, Any], got: int, n: int
               ) -> None:
    """Log one warning that an ask of ``n`` handed out only ``got`` suggestions, and why: the
    phase's budget has no more to hand out, or the critic gave no more θ not handed out."""
    left, n_open = _budget_left(st, phase, pc)
    why = (f"{phase_name(phase)}'s budget of {counted(pc['budget'], 'trial')} has no more "
           f"({st.count(phase)} told, {n_open} handed out); ask with a larger "
           f"{option('budget')} for more"
           if left <= 0 else f"{phase_name(phase)}'s critic gave no more θ that is not handed "
           "out already")
    waiting = sum(1 for t in st.trials("queued") if t.phase == phase)
    if waiting and reuse_phases(phase, pc):     # queued, not handed out: twins (tell_twins)
        verb = "waits" if waiting == 1 else "wait"
        why += (f"; {counted(waiting, 'θ', 'θ')} it asked twice {verb} for the first one's "
                "result and will be told with it")
    log.warning("%s: handed out %d of the %d suggestions asked: %s", study.dir, got, n, why)


def refuse_if_fall_budget_spent(study: Any, st: RunStore, phase: int, pc: dict[str, Any]
                                ) -> None:
    """Raise :class:`FallBudgetSpent` when ``phase`` is a transfer phase 3 whose fall budget
    the told trials spent (:func:`~latentune.pipeline.results.fall_budget`, what ``status``
    reports): the ask then hands out nothing, neither the suggestions a batch asked before the
    budget was spent and still queued nor those handed out and not told (they may still be
    told). The store is left as it is."""
    if phase != Phase.PHASE3:
        return
    fb = fall_budget(st, {"phase3": pc})
    if not fb or not fb["spent"]:
        return
    out = [t.id for t in st.trials() if t.status == "pending"
           and t.phase in (phase, Phase.ZERO_SHOT)]
    raise FallBudgetSpent(
        f"{study.dir}: {phase_name(phase)}'s fall budget is spent "
        f"({counted(fb['falls_allowed'], 'fall')} allowed; "
        f"{counted(st.count(phase), 'trial')} told): its best θ is the result; an ask with a "
        f"larger {option('budget')} allows more falls (the fall budget is a share of it)"
        + (f"; suggestion{'s' if len(out) > 1 else ''} {', '.join(map(str, out))} handed out "
           "before may still be told" if out else ""))


def fall_risk(st: RunStore, phase: int, pc: dict[str, Any]) -> Any:
    """A function of a suggestion (a stored Trial) giving ``(p, bound)`` when the transfer
    phase 3's ask that gave it handed out θ its fall model rates ``p`` likely to fall (as
    recorded when it was queued, :data:`RISK_KEY`; a suggestion queued before that record:
    its decision, by the generation of its tag, ``tag // 4``), above the fall screen's
    ``bound``; else None (phase 1, the plain phase 3, the zero-shot trial)."""
    state = st.get_meta(state_key(phase)) if phase == Phase.PHASE3 else None
    if not isinstance(state, dict) or strategy_of(pc) != "transfer":
        return lambda t: None
    bound = (state.get("options") or {}).get("max_fall_prob")
    by_gen = {d.get("generation"): d for d in state.get("decisions") or ()
              if isinstance(d, dict)}
    recorded = st.get_meta(RISK_KEY) or {}

    def risk(t: Any) -> tuple[float, float] | None:
        if t.phase != phase or t.tag < 0:
            return None
        p = recorded.get(str(t.id))
        if p is None:       # queued by a version that did not record it: its generation's
            p = (by_gen.get(t.tag // 4) or {}).get("max_fall_prob_asked")
        if p is None or bound is None or not float(p) > float(bound):
            return None
        return float(p), float(bound)
    return risk


@dataclass
class _Context:
    """What an ask works with: its phase, the phase's options record, the space, and the
    LatentSpace of phase 3 (None in phase 1, or when ``built`` is False: the options were
    read from the store alone, :func:`_stored_context`)."""

    phase: int
    options: dict[str, Any]
    space: ParameterSpace
    latent: Any = None
    built: bool = True


def _context(study: Any, st: RunStore, system: Any, space: ParameterSpace | None,
             phase: int | None, latent: Any, given: dict[str, Any],
             undo: ExitStack | None = None) -> _Context:
    """The context of an ask with its options checked and recorded in the manifest (the
    zero-shot suggestion queued on phase 3's first ask). ``undo``: the ask's exit stack when
    its context was read from the store (:func:`_stored_context`, its space checked there) and
    the critic is to be built: it records only when that changes the run
    (:func:`_records`), and then enters :meth:`RunDir.as_before_on_error` on ``undo`` first;
    else it writes nothing (and the store is not copied)."""
    sp = _space(study, system, space, bind=undo is None)
    ph = _phase(study.manifest.config(), phase, latent, study.dir, st)
    pc, ls = options(study, ph, sp, latent, given)
    record = {"asktell": {**pc, "phase": ph}, mf.PHASE_KEYS[Phase(ph)]: pc}
    if undo is not None:
        if not _records(study, st, ph, pc, record):
            return _Context(ph, pc, sp, ls)
        undo.enter_context(study.run.as_before_on_error())
    if ph == Phase.PHASE3:
        record_latent(study.run, study.manifest, ls, pc["latent_source"])
    study.manifest.record_seed(study.seed)
    study.manifest.update(**record)
    if ph == Phase.PHASE3:
        queue_zero_shot(st, pc.get("latent_source"), study.seed)
    return _Context(ph, pc, sp, ls)


def _records(study: Any, st: RunStore, phase: int, pc: dict[str, Any],
             record: dict[str, Any]) -> bool:
    """Whether recording the options record ``pc`` of ``phase`` (:func:`_context`) changes
    the run: the study's seed is still to be recorded, the manifest entries ``record`` (the
    ask/tell and phase options records) differ from the stored ones
    (:meth:`~latentune.pipeline.manifest.Manifest.would_change`), or phase 3's latent space
    or zero-shot suggestion is still to be recorded."""
    if study.manifest.config().get("seed") is None or study.manifest.would_change(**record):
        return True
    return phase == Phase.PHASE3 and (latent_to_record(study.manifest)
                                      or zero_shot_to_queue(st, pc.get("latent_source")))


def check_first_ask(study: Any, system: Any, space: ParameterSpace | None, phase: int | None,
                    latent: Any, given: dict[str, Any]) -> None:
    """Check the first ask of ``study`` (no run store yet) as :func:`_context` does, writing
    nothing: its space, phase and options (the latent space, its dimension, the strategy's
    options; the plain phase 3's spread of the latent space), so that a refused first ask
    leaves no run store, lock or copied latent space behind."""
    sp = _space(study, system, space, bind=False)
    ph = _phase({}, phase, latent, study.dir)
    pc, ls = options(study, ph, sp, latent, given, pin=False)
    if ph == Phase.PHASE3 and strategy_of(pc) == "plain":
        ls.require_spread()


def _stored_context(study: Any, system: Any, space: ParameterSpace | None, phase: int | None,
                    latent: Any, given: dict[str, Any]) -> _Context | None:
    """The context of a later ask read from the store alone, without building the critic's
    options (which loads its libraries and the latent space), when everything given is what
    is stored; else None (the ask then checks and records its options, :func:`_context`)."""
    cfg = study.manifest.config()
    at = cfg.get("asktell")
    if not at:
        return None
    ph = int(at["phase"])
    pc = cfg.get(mf.PHASE_KEYS[Phase(ph)])
    if not pc or (phase is not None and phase != ph) or int(pc["seed"]) != study.seed \
            or int(pc["batch_size"]) != study.batch_size_of(ph):
        return None
    if latent is not None:
        if ph != Phase.PHASE3 or not isinstance(latent, (str, os.PathLike)):
            return None
        other = Path(latent).resolve()
        if ("self" if other == study.dir.resolve() else str(other)) != pc.get("latent_source"):
            return None
    sp = _space(study, system, space)
    g = _normalized({k: v for k, v in given.items() if k != "strategy"}, sp)
    for k, v in g.items():
        if v is not None and v != pc.get(k):
            return None
    if given.get("strategy") is not None and (ph != Phase.PHASE3
                                              or given["strategy"] != strategy_of(pc)):
        return None
    if given.get("start") is not None \
            and _start_record(given["start"], sp) != pc.get("start", "manual"):
        return None
    return _Context(ph, pc, sp, None, built=False)


@dataclass
class _Batch:
    """A batch the critic asked: θ (k, d), the code to store with each, tags (k,), the
    critic's state after the ask and its hand-over rule (or None)."""

    thetas: np.ndarray
    codes: list[Any]
    tags: np.ndarray
    state: dict[str, Any]
    rule: dict[str, Any] | None


def _budget_left(st: RunStore, phase: int, pc: dict[str, Any]) -> tuple[int, int]:
    """(trials of ``phase`` the budget leaves to ask, suggestions of it open)."""
    open_ = sum(1 for t in st.trials() if t.phase == phase and t.status in ("queued", "pending"))
    return pc["budget"] - st.count(phase) - open_, open_


def _critic_batch(study: Any, st: RunStore, phase: int, pc: dict[str, Any],
                  space: ParameterSpace, ls: Any, need: int) -> _Batch:
    """Ask the critic (built from the stored rows and state) the next batch: at least
    ``need`` points, the batch size by default, within the budget; points already handed out
    and not told are not asked again (the critic does not know them yet). Writes nothing."""
    left, n_open = _budget_left(st, phase, pc)
    if left <= 0:
        budget = f"{study.dir}: {phase_name(phase)}'s budget of {counted(pc['budget'], 'trial')}"
        if n_open:
            raise StoreError(f"{budget} is handed out ({st.count(phase)} told, {n_open} "
                             f"pending): tell the pending ones, or ask with a larger "
                             f"{option('budget')}")
        if best_row(st) is None:            # every trial of the study failed
            raise StoreError(f"{budget} is told and no trial stood: there is no θ to deploy; "
                             f"ask with a larger {option('budget')}")
        raise StoreError(f"{budget} is told: its best θ is the result (best_params()), or "
                         f"ask with a larger {option('budget')}")
    k = min(max(pc["batch_size"], need), left)
    critic = phase_critic(phase, pc, space, study.dir, ls)
    replay(st, phase, critic)
    if getattr(critic, "fall_budget_spent", False):
        raise FallBudgetSpent(f"{study.dir}: {phase_name(phase)}'s fall budget is spent "
                              f"({counted(critic.falls_allowed(), 'fall')} allowed; "
                              f"{counted(st.count(phase), 'trial')} told): its best θ is the "
                              f"result; an ask with a larger {option('budget')} allows more "
                              "falls (the fall budget is a share of it)")
    out = [t for t in st.trials()
           if t.status in ("queued", "pending") and t.phase in (phase, Phase.ZERO_SHOT)]
    # the critic asks the θ handed out again (the zero-shot θ too for the transfer critic:
    # its first point until it is told; the plain critic never sees it), then the new ones
    again = [t for t in out if t.phase == phase or strategy_of(pc) == "transfer"]
    U, T, Z, thetas, codes = ask_batch(critic, len(again) + k, decoder_of(pc, ls))
    held = {np.ascontiguousarray(t.theta).tobytes() for t in out}
    keep = [i for i in range(len(thetas))
            if np.ascontiguousarray(thetas[i]).tobytes() not in held][-k:]
    state = critic.state_dict() if hasattr(critic, "state_dict") else {}
    rule = critic.rule() if pc.get("handover") is not None else None
    return _Batch(np.asarray(thetas)[keep], [codes[i] for i in keep], np.asarray(T)[keep],
                  state, rule)


def _queue(study: Any, st: RunStore, phase: int, pc: dict[str, Any], batch: _Batch
           ) -> None:
    """Queue ``batch`` as suggestions, with the critic's state (the next ask reuses its GP
    fits) and without any prepared batch, in one transaction (``pc``: the phase's options
    record). Its θ that are a stored trial's (:func:`~latentune.pipeline.loop.reuse_phases`:
    the plain phase 3) are not handed out: they are told that trial's outcome at once, first,
    as the phase run stores them (:func:`~latentune.pipeline.phases.reused_first`), said at
    INFO, and count in the phase's budget."""
    meta: dict[str, Any] = {NEXT_KEY: None}
    if batch.state:
        meta[state_key(phase)] = batch.state
    reuse = reuse_phases(phase, pc)
    known = stored_outcomes(st, reuse)
    o = reused_first(batch.thetas, known, bool(reuse))   # a θ asked twice: after its first
    told = []
    for i in o:
        out = known.get(theta_key(batch.thetas[i]))
        told.append(None if out is None else _reused_result(study, phase, out))
    asked = (batch.state.get("last_decision") or {}).get("max_fall_prob_asked") \
        if batch.state else None
    st.queue_trials(phase, batch.thetas[o], [batch.codes[i] for i in o], batch.tags[o],
                    meta=meta, told=told,
                    each=None if asked is None else (RISK_KEY, float(asked)))
    if any(t is not None for t in told):
        write_best(st, study.dir, study.manifest.space(), phase)
    if batch.rule is not None:
        study.manifest.update(phase3_handover=batch.rule)


def _reused_result(study: Any, phase: int, out: Outcome) -> dict[str, Any]:
    """The result a suggestion of ``phase`` is told at once with, the stored ``out`` of a trial
    with its θ (:func:`~latentune.pipeline.phases.stored_outcomes`), as
    :meth:`RunStore.queue_trials`' ``told`` and :meth:`RunStore.tell_queued` take it (said at
    INFO: :func:`~latentune.pipeline.phases.say_reused`)."""
    say_reused(phase, out)
    return {"cost": out.cost, "fell": out.failed, "fall_step": out.fall_step,
            "wall_s": out.wall_s, "seed": study.seed, "info": {**out.info, "reused": True}}


def tell_twins(study: Any, st: RunStore, reuse: tuple[int, ...]) -> None:
    """Tell each queued suggestion of the phases ``reuse`` (:func:`~latentune.pipeline.loop.
    reuse_phases`: the plain phase 3) whose θ a stored trial of them holds: that trial's
    outcome (``info["reused"]``, ``"same_as"``), as the phase run stores a θ asked twice in one
    batch right after the first (:func:`~latentune.pipeline.phases.batch_twins`). Such a
    suggestion waits, not handed out, while the first of its θ is out (:meth:`RunStore.lease`'s
    ``waits``)."""
    waiting = [t for t in st.trials("queued") if t.phase in reuse] if reuse else []
    if not waiting:
        return
    known = stored_outcomes(st, reuse)
    told = {}
    for t in waiting:
        out = known.get(theta_key(t.theta))
        if out is not None:
            told[t.id] = _reused_result(study, t.phase, out)
    if told:
        st.tell_queued(told)
        write_best(st, study.dir, study.manifest.space(), Phase.PHASE3)


def _prepared_key(study: Any, st: RunStore, phase: int, pc: dict[str, Any]) -> str:
    """The key of a batch prepared for ``phase`` now (see the module docstring)."""
    runs = []
    if phase == Phase.PHASE3 and pc.get("latent_source") not in (None, "self"):
        runs.append(pc["latent_source"])
    if pc.get("max_fall_prob") is not None and pc.get("fall_prior") not in (None, "latent source"):
        runs.append(pc["fall_prior"])
    ext = []
    for r in runs:
        try:
            ext.append(RunStore.data_version_of(r))
        except StoreError:
            ext.append(None)
    body = {"phase": int(phase), "options": pc, "store": st.data_version(),
            "state": st.get_meta(state_key(phase)), "runs": [runs, ext]}
    return hashlib.sha256(json.dumps(body, sort_keys=True, default=str).encode()).hexdigest()


def _take_prepared(study: Any, st: RunStore, phase: int, pc: dict[str, Any], need: int) -> bool:
    """Queue the prepared batch if it is what the critic would be asked now for ``need``
    points (True); else drop it (False)."""
    prep = st.get_meta(NEXT_KEY)
    if not prep:
        return False
    if prep.get("phase") != phase or need > len(prep["thetas"]) \
            or prep.get("key") != _prepared_key(study, st, phase, pc):
        log.debug("%s: the prepared batch is stale; asking the critic", study.dir)
        st.delete_meta(NEXT_KEY)
        return False
    codes = [None if c is None else np.asarray(c, dtype=float) for c in prep["codes"]]
    _queue(study, st, phase, pc, _Batch(np.asarray(prep["thetas"], dtype=float), codes,
                                    np.asarray(prep["tags"], dtype=np.int64), prep["state"],
                                    prep["rule"]))
    return True


def prepare(study: Any) -> bool:
    """Prepare the batch the next ask of ``study`` would ask the critic for, if it would ask
    it (no suggestion queued or handed out, budget left): see the module docstring. Returns
    whether a batch was prepared. An error here (a library's, or the critic's own) is logged,
    not raised: the told result is stored, and the next ask meets the error."""
    if not study.exists:
        return False
    with study.run.writing(wait=WAIT_S) as st:
        at = study.manifest.config().get("asktell")
        if not at or any(t.status in ("queued", "pending") for t in st.trials()):
            return False
        ph = int(at["phase"])
        try:
            sp = _space(study, None, None)
            pc, ls = options(study, ph, sp, None, dict.fromkeys(OPTIONS))
            if _budget_left(st, ph, pc)[0] <= 0:
                return False
            key = _prepared_key(study, st, ph, pc)
            b = _critic_batch(study, st, ph, pc, sp, ls, 1)
        except FallBudgetSpent as exc:      # the phase is over: nothing to prepare
            log.warning("%s", exc)
            st.delete_meta(NEXT_KEY)
            return False
        except Exception as exc:  # noqa: BLE001 - the told result is stored: a warning
            why = str(exc) if isinstance(exc, LatentuneError) else \
                f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
            log.warning("%s: the next suggestion was not prepared (%s); the next ask asks "
                        "the critic", study.dir, why)
            st.delete_meta(NEXT_KEY)
            return False
        st.set_meta(NEXT_KEY, {"phase": ph, "key": key, "thetas": b.thetas, "tags": b.tags,
                               "codes": [None if c is None else np.asarray(c)
                                         for c in b.codes],
                               "state": b.state, "rule": b.rule})
        return True


def tell(study: Any, trial_id: int, cost: float | Outcome | None = None, *,
         failed: bool = False, note: str | None = None, info: dict[str, Any] | None = None,
         amend: bool = False, asker: str | None = None) -> Row:
    """Store the result of suggestion ``trial_id`` (``amend``: correct a told one, see the
    module docstring), then :func:`prepare` the next batch, or warn that phase 3's fall budget
    is spent (:func:`refuse_if_fall_budget_spent`); return its evaluation row. ``asker``: who
    tells it, recorded with the row (``info["told_by"]``); a tell naming another asker than
    the holder of a lease not expired is refused (StoreError); None: no name, as before. A
    failed trial may omit the cost (the convention of :mod:`latentune.system`). ``cost`` may
    also be the :class:`~latentune.system.Outcome` a system's ``evaluate`` returned, given alone
    (without ``failed`` and ``info``)."""
    tid = _check_id(trial_id)
    if asker is not None:
        _check_asker(asker)
    if info is not None and not isinstance(info, dict):
        raise UsageError(f"suggestion {tid}: info must be a dict, got {type(info).__name__}")
    if isinstance(cost, Outcome) and (failed or info):
        raise UsageError(f"suggestion {tid}: give an Outcome alone (its failed and info are "
                         "part of it)")
    try:
        out = as_outcome(cost if isinstance(cost, Outcome) else
                         {"cost": cost, "failed": failed, "info": info}, opening="got")
    except EvaluationError as exc:      # no evaluate ran: "got str 'abc'; expected a float cost"
        raise UsageError(f"bad result for suggestion {tid}: {exc}") from None
    if note:
        out.info["note"] = str(note)
    with study.run.writing(wait=WAIT_S) as st:
        if amend:
            # the rows stored as copies of it (same_as), by ask/tell or a phase run, with it
            ph, idx, changed, copies = st.amend_trial(
                tid, out.cost, fell=out.failed, fall_step=out.fall_step, info=out.info,
                note=note, asker=asker)
            told = {c for p in (ph, *(p for p, _ in copies)) for c in critics_told(p)}
            if changed and Phase.PHASE3 in told and ph != Phase.PHASE3:  # a phase-3 row
                write_best(st, study.dir, study.manifest.space(), Phase.PHASE3)
            for p in sorted(told) if changed else ():       # each critic told the row is
                kept = st.get_meta(state_key(p))             # rebuilt from the corrected rows;
                if kept is not None or p != Phase.MANUAL:    # (the manual θ has no critic)
                    st.set_meta(state_key(p), {k: v for k, v in (kept or {}).items()
                                               if k in ROW_FREE})
        else:
            ph = st.trials_by_id(tid).phase
            idx = st.tell_trial(tid, out.cost, fell=out.failed, fall_step=out.fall_step,
                                seed=study.seed, info=out.info, asker=asker)
            p3 = study.config().get("phase3") if ph in (Phase.ZERO_SHOT, Phase.PHASE3) else None
            tell_twins(study, st, reuse_phases(Phase.PHASE3, p3) if p3 else ())

            def stored() -> dict[str, Any]:
                return study.config().get(mf.PHASE_KEYS.get(Phase(ph), "")) or {}
            warn_if_failing(st, ph, lambda: strategy_of(stored()),
                            lambda: stored_fall_options(stored()), fixed=True)
            if not out.failed:
                warn_if_flat(st, ph)
        # a phase file as the phase runs write them (the zero-shot trial counts in best.json)
        write_best(st, study.dir, study.manifest.space(),
                   ph if ph in (Phase.PHASE1, Phase.PHASE3) else None)
        row = next(r for r in st.rows(ph) if r.idx == idx)
        over = None
        pc = study.config().get("phase3") if ph in (Phase.ZERO_SHOT, Phase.PHASE3) else None
        if pc:
            try:
                refuse_if_fall_budget_spent(study, st, Phase.PHASE3, pc)
            except FallBudgetSpent as exc:      # the phase is over: nothing to prepare
                over = str(exc)
                st.delete_meta(NEXT_KEY)
    if over is not None:
        log.warning("%s", over)
        return row
    prepare(study)
    return row


def release(study: Any, trial_id: int) -> None:
    """End the lease of pending suggestion ``trial_id`` now: the next ask hands it out again."""
    tid = _check_id(trial_id)
    with study.run.writing(wait=WAIT_S) as st:
        st.release(tid)
