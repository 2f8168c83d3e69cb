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

Corrections
-----------
``tell(..., amend=True)`` replaces a told result; the store keeps the old one in its audit
trail (``amendments``), drops the suggestions queued from the uncorrected rows and the
critic's saved state, so the next ask rebuilds the critic from the corrected rows.

Suggestion files (``DIR/suggestions/<id>.json``, the ``--params`` file of a suggestion) belong
to the command line: :func:`write_suggestion_files` and :func:`remove_suggestion_file`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from latentune.constants import Phase
from latentune.errors import StoreError, UsageError
from latentune.pipeline import manifest as mf
from latentune.pipeline.baselines import queue_zero_shot
from latentune.pipeline.loop import (decoder_of, phase_critic, record_latent, resolve_latent,
                                     resolve_strategy)
from latentune.pipeline.phases import (ask_batch, replay, save_state, state_key,
                                       warn_if_failing)
from latentune.pipeline.results import phase_name, write_best
from latentune.pipeline.store import Row, RunStore
from latentune.space import ParameterSpace
from latentune.system import EvaluationError, as_outcome

LEASE_S = 3600.0
"""How long a suggestion stays leased to its asker when it is not told [s] (one hour)."""
WAIT_S = 60.0
"""How long an ask or a tell waits for another writer of the study [s]."""
DEFAULT_ASKER = "default"


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

    @property
    def phase_name(self) -> str:
        """"phase 1", "phase 3" or "zero-shot"."""
        return phase_name(self.phase)

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "phase": self.phase, "phase_name": self.phase_name,
                "again": self.again, "params": self.params, "theta": self.theta.tolist(),
                "file": self.path, "asker": self.asker, "lease_until": self.lease_until}


def write_suggestion_files(run_dir: str | os.PathLike, suggestions: list[Suggestion]) -> None:
    """Write each suggestion's ``--params`` file ``DIR/suggestions/<id>.json`` (physical values
    by name) and set its ``path``."""
    d = Path(run_dir) / "suggestions"
    d.mkdir(parents=True, exist_ok=True)
    for s in suggestions:
        path = d / f"{s.id}.json"
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(s.params, indent=1))
        os.replace(tmp, path)
        s.path = str(path)


def remove_suggestion_file(run_dir: str | os.PathLike, trial_id: int) -> None:
    """Remove ``DIR/suggestions/<id>.json`` if it exists (after its result was told)."""
    path = Path(run_dir) / "suggestions" / f"{int(trial_id)}.json"
    if path.is_file():
        path.unlink()


def _check_id(trial_id: Any) -> int:
    if isinstance(trial_id, bool) or not isinstance(trial_id, (int, np.integer)):
        raise UsageError(f"a suggestion id is an integer, got {trial_id!r}")
    return int(trial_id)


def _space(study: Any, system: Any, space: ParameterSpace | None) -> ParameterSpace:
    if system is not None:
        study.manifest.bind(system)
        return system.space
    if space is not None:
        study.manifest.bind_space(space)
        return space
    stored = study.manifest.space()
    if stored is None:
        raise StoreError(f"{study.dir}: no parameter space yet: the first ask needs a system "
                         "or a space (--system, --robot or --space FILE)")
    return stored


def _phase(cfg: dict[str, Any], phase: int | None, latent: Any, dir_: Path) -> int:
    stored = (cfg.get("asktell") or {}).get("phase")
    if stored is not None:
        if phase is not None and int(phase) != int(stored):
            raise StoreError(f"{dir_}: ask/tell runs phase {stored} (stored), not {phase}")
        return int(stored)
    if phase is None:
        phase = Phase.PHASE3 if latent is not None else Phase.PHASE1
    if int(phase) not in (Phase.PHASE1, Phase.PHASE3):
        raise UsageError(f"ask/tell runs phase 1 or 3, not {phase}")
    return int(phase)


def _normalized(given: dict[str, Any], space: ParameterSpace) -> dict[str, Any]:
    """The given ask options as their stored records (None stays None: "the stored one")."""
    g = dict(given)
    if g.get("start") is not None:
        g["start"] = mf.start_point(g["start"], space.manual, space.dim)[1]
    if g.get("handover") is not None:
        g["handover"] = mf.handover(g["handover"])
    if g.get("max_fall_prob") is not None:
        g["max_fall_prob"] = mf.fall_options(g["max_fall_prob"], None)["max_fall_prob"]
    if g.get("fall_prior") is not None:
        g["fall_prior"] = str(g["fall_prior"])
    return g


def options(study: Any, phase: int, space: ParameterSpace, latent: Any, given: dict[str, Any]
            ) -> tuple[dict[str, Any], Any]:
    """(the checked options record of ``phase``, its LatentSpace or None) for an ask: options
    not given are the stored ones (or the defaults on the first ask); a given one that differs
    from the stored is refused (:func:`~latentune.pipeline.manifest.ask_options`)."""
    key = mf.PHASE_KEYS[Phase(phase)]
    cfg = study.manifest.config()
    fixed = (cfg.get("asktell") or {}).get("phase") == phase or study.manifest.n_used(phase)
    stored = cfg.get(key) if fixed else None
    if phase == Phase.PHASE1 and given.get("handover"):
        raise UsageError("handover is an option of phase 3")
    strategy = given.get("strategy")
    if phase == Phase.PHASE1 and strategy:
        raise UsageError("strategy is an option of phase 3")
    given = {k: v for k, v in given.items() if k != "strategy"}
    if phase == Phase.PHASE1 and latent is not None:
        raise UsageError(f"{study.dir}: ask/tell runs phase 1 here; a latent space is an option "
                         "of phase 3 (use another directory)")
    g = _normalized(given, space)
    if stored:
        g = mf.ask_options(stored, g, study.dir, phase)
    else:
        g = {**g, "method": g.get("method") or "turbo", "budget": g.get("budget") or mf.ASK_BUDGET,
             "start": "manual" if g.get("start") is None else g["start"]}
    start_rec = g.get("start")
    mfp = g.get("max_fall_prob")
    ls = None
    if phase == Phase.PHASE3:
        ls, source = resolve_latent(study.run, study.manifest, latent, space)
        record_latent(study.run, study.manifest, ls, source)
        extra = {"latent_source": source,
                 "strategy": resolve_strategy(study.manifest, strategy, g.get("handover")),
                 "start": start_rec,
                 **mf.fall_options(mfp, None if mfp is None else "latent source"),
                 "handover": g.get("handover")}
    else:
        extra = {"start": start_rec, **mf.fall_options(mfp, g.get("fall_prior"))}
    pc = study.manifest.phase_options(phase, method=g["method"], budget=g["budget"],
                                      regions=g.get("regions"), seed=study.seed,
                                      batch_size=study.batch_size_of(phase), extra=extra)
    return pc, ls


def ask(study: Any, n: int = 1, *, system: Any = None, space: ParameterSpace | None = None,
        phase: int | None = None, latent: Any = None, asker: str | None = None,
        lease_s: float | None = None, **given: Any) -> list[Suggestion]:
    """Hand out ``n`` suggestions of ``study`` to ``asker`` (see the module docstring).

    ``given``: the phase's options (strategy, method, budget, regions, start, max_fall_prob,
    fall_prior, handover), each None for "the stored one"."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise UsageError(f"n must be an integer >= 1, got {n!r}")
    who = DEFAULT_ASKER if asker is None else str(asker)
    if not who.strip():
        raise UsageError("asker must be a non-empty name")
    lease = LEASE_S if lease_s is None else float(lease_s)
    if not np.isfinite(lease) or lease <= 0:
        raise UsageError(f"lease_s must be a positive number of seconds, got {lease_s!r}")
    with study.run.writing(wait=WAIT_S) as st:
        sp = _space(study, system, space)
        ph = _phase(study.manifest.config(), phase, latent, study.dir)
        pc, ls = options(study, ph, sp, latent, given)
        study.manifest.record_seed(study.seed)
        study.manifest.update(asktell={**pc, "phase": ph}, **{mf.PHASE_KEYS[Phase(ph)]: pc})
        phases: tuple[int, ...] = (ph,)
        if ph == Phase.PHASE3:
            queue_zero_shot(st, pc.get("latent_source"))
            phases = (Phase.ZERO_SHOT, ph)
        got = st.lease(who, phases, int(n), lease)
        if len(got) < n:
            _ask_critic(study, st, ph, pc, sp, ls, int(n) - len(got))
            got += st.lease(who, (ph,), int(n) - len(got), lease, queued_only=True)
        return [Suggestion(t.id, t.phase, t.theta, sp.as_dict(t.theta), t.z, again, None,
                           t.asker, t.lease_until) for t, again in got]


def _ask_critic(study: Any, st: RunStore, phase: int, pc: dict[str, Any], space: ParameterSpace,
                ls: Any, need: int) -> None:
    """Ask the critic the next batch (at least ``need`` points, the batch size by default,
    within the budget) and queue it; points already handed out and not told are not asked
    again (the critic does not know them yet)."""
    open_ = [t for t in st.trials() if t.phase == phase and t.status in ("queued", "pending")]
    left = pc["budget"] - st.count(phase) - len(open_)
    if left <= 0:
        raise StoreError(f"{study.dir}: {phase_name(phase)}'s budget of {pc['budget']} trials is "
                         f"handed out ({st.count(phase)} told, {len(open_)} pending): tell the "
                         "pending ones, or ask with a larger budget")
    k = min(max(pc["batch_size"], need), left)
    critic = phase_critic(phase, pc, space, study.dir, ls)
    replay(st, phase, critic)
    U, T, Z, thetas, codes = ask_batch(critic, len(open_) + k, decoder_of(pc, ls))
    held = {np.ascontiguousarray(t.theta).tobytes() for t in st.trials()
            if t.status in ("queued", "pending") and t.phase in (phase, Phase.ZERO_SHOT)}
    keep = [i for i in range(len(thetas))
            if np.ascontiguousarray(thetas[i]).tobytes() not in held][-k:]
    save_state(st, phase, critic)           # the next ask reuses its GP fits
    st.queue_trials(phase, thetas[keep], [codes[i] for i in keep], T[keep])
    if pc.get("handover") is not None:
        study.manifest.update(phase3_handover=critic.rule())


def tell(study: Any, trial_id: int, cost: float | None = None, *, failed: bool = False,
         note: str | None = None, info: dict[str, Any] | None = None,
         amend: bool = False) -> Row:
    """Store the result of suggestion ``trial_id`` (``amend``: correct a told one, see the
    module docstring); return its evaluation row. A failed trial may omit the cost (the
    convention of :mod:`latentune.system`)."""
    tid = _check_id(trial_id)
    try:
        out = as_outcome({"cost": cost, "failed": bool(failed), "info": dict(info or {})})
    except EvaluationError as exc:
        raise UsageError(f"bad result for suggestion {tid}: {exc}".replace(
            "evaluate returned", "got")) from None
    if note:
        out.info["note"] = str(note)
    with study.run.writing(wait=WAIT_S) as st:
        if amend:
            ph, idx = st.amend_trial(tid, out.cost, fell=out.failed, fall_step=out.fall_step,
                                     info=out.info, note=note)
            st.set_meta(state_key(ph), {})   # rebuilt from the corrected rows alone
        else:
            idx = st.tell_trial(tid, out.cost, fell=out.failed, fall_step=out.fall_step,
                                seed=study.seed, info=out.info)
            ph = st.trials_by_id(tid).phase
            warn_if_failing(st, ph)
        write_best(st, study.dir, study.manifest.space(), ph)
        return next(r for r in st.rows(ph) if r.idx == idx)


def release(study: Any, trial_id: int) -> None:
    """End the lease of pending suggestion ``trial_id`` now: the next ask hands it out again."""
    tid = _check_id(trial_id)
    with study.run.writing(wait=WAIT_S) as st:
        st.release(tid)
