"""One loop: the critic of a phase, built from the study's stored options and seed.

A phase is an ask/tell loop on a critic: :func:`~latentune.pipeline.phases.run_phase` runs it
with an evaluator (simulated trials), :mod:`latentune.pipeline.asktell` with a person (trials run
elsewhere). Both build the critic here, with :func:`phase_critic`, from the phase's options
record (:meth:`~latentune.pipeline.manifest.Manifest.phase_options`: method, batch size, seed,
regions, budget, start, max_fall_prob and its prior, hand-over, latent source, the transfer
critic's options) and both replay the stored rows into it, so a seed gives the same rows
whichever drives the loop.

This module also finds the latent space phase 3 searches (the study's own or another study's,
:func:`resolve_latent`) and records it (:func:`record_latent`).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from latentune.constants import Phase
from latentune.errors import LatentError, StoreError
from latentune.pipeline import manifest as mf
from latentune.pipeline.manifest import Manifest
from latentune.pipeline.phases import (make_handover_critic, make_phase_critic, not_run_note,
                                       state_key)
from latentune.pipeline.rundir import RunDir
from latentune.pipeline.store import RunStore, Row
from latentune.space import ParameterSpace
from latentune.wording import FLAGS, counted, option

log = logging.getLogger(__name__)


def start_theta(pc: dict[str, Any], space: ParameterSpace) -> np.ndarray | None:
    """The (d,) unit-box θ a phase starts from, per its stored ``start`` record."""
    start = pc.get("start", "manual")
    if start == "manual":
        return space.manual
    return None if start is None else np.asarray(start, dtype=float)


def phase_critic(phase: int, pc: dict[str, Any], space: ParameterSpace, run_dir: Path,
                 latent: Any = None) -> Any:
    """The critic of ``phase`` for its options record ``pc``, fresh (replay the stored rows
    into it with :func:`~latentune.pipeline.phases.replay`).

    Phase 1: ``pc["method"]`` on the θ box of ``space`` from the ``start`` θ, fall-aware with
    ``max_fall_prob`` (prior: the phase-1 trials of the run ``fall_prior``). Phase 3: on the
    latent box of ``latent`` (a LatentSpace) from the code of the ``start`` θ, its fall prior
    the encoded phase-1 trials of the latent space's source run (``run_dir`` when
    ``latent_source`` is "self"); with ``handover``, a
    :class:`~latentune.critic.handover.Handover` on the θ box. Every phase-3 strategy is one
    branch here. The source run is not checked here: the phase's start did
    (:func:`check_source_run`, in :func:`phase3_setup` and ask/tell's options)."""
    mfp = pc.get("max_fall_prob")
    theta0 = start_theta(pc, space)
    if int(phase) == Phase.PHASE1:
        prior = theta_prior(pc.get("fall_prior"), space, pc.get("prior_counts")) \
            if mfp is not None else None
        return make_phase_critic(pc["method"], space.dim, pc["batch_size"], pc["seed"], theta0,
                                 pc["budget"], pc["regions"], mfp, prior,
                                 source=source_costs(pc.get("source_run"), space,
                                                     pc.get("source_counts")))
    if latent is None:
        raise LatentError("phase 3 needs a latent space")
    source = pc.get("latent_source", "self")
    run = run_dir if source in (None, "self") else Path(source)
    if strategy_of(pc) == "transfer":
        return transfer_critic(pc, space, run_dir, run, latent)
    latent.require_spread()                 # the paper's phase 3 searches the decoded θ only
    x0 = None if theta0 is None else latent.to_unit(latent.encode(theta0))
    counts = pc.get("source_counts")            # the source's trials the phase began with
    lprior = latent_prior(run, latent, counts) if mfp is not None else None
    if pc.get("handover") is None:
        return make_phase_critic(pc["method"], latent.d_low, pc["batch_size"], pc["seed"], x0,
                                 pc["budget"], pc["regions"], mfp, lprior)
    tprior = theta_prior(run, space, counts) if mfp is not None else None
    return make_handover_critic(pc["method"], latent, pc["batch_size"], pc["seed"], x0,
                                pc["budget"], pc["regions"], pc["handover"], mfp, lprior, tprior)


STRATEGIES = ("transfer", "plain")
"""Phase 3's strategies: ``transfer`` (the default, :mod:`latentune.critic.transfer`: everything
the source run tried, the target's own trials, latent and full θ boxes) and ``plain`` (the
paper's phase 3: ``method`` on the latent box only, optionally with a hand-over)."""


def strategy_of(pc: dict[str, Any]) -> str:
    """The phase-3 strategy of an options record; records written before strategies existed
    ran the paper's phase 3 (``plain``)."""
    return str(pc.get("strategy") or "plain")


def reuse_phases(phase: int, pc: dict[str, Any]) -> tuple[int, ...]:
    """The phases whose stored trials a θ the critic of ``phase`` (options record ``pc``) asks
    again is stored from, not run again (:func:`~latentune.pipeline.phases.stored_outcomes`),
    in the phase run and ask/tell alike: for the plain phase 3, the manual θ's trial, the
    zero-shot trial and phase 3's own (its decoded start may be the manual θ, which may be the
    source's best). None for phase 1 (its manual θ is reused by the phase run alone: ask/tell
    has no trial of it before phase 1's) and the transfer phase 3 (it is told those trials
    and never asks a told θ again, option ``distinct``)."""
    if int(phase) != Phase.PHASE3 or strategy_of(pc) != "plain":
        return ()
    return (Phase.MANUAL, Phase.ZERO_SHOT, Phase.PHASE3)


OWN_TOLD = 30
"""Phase 3 on the system of its own phase 1: the best trials of phase 1 told to the transfer
critic as target data (with the phase-1 trials among its elites), so it does not run them again."""


def phase3_setup(run: RunDir, manifest: Manifest, space: ParameterSpace, actor: str | None,
                 latent: Any, strategy: str | None, start: Any, max_fall_prob: float | None,
                 handover: Any, transfer_options: dict[str, Any] | None,
                 method: str | None = None, regions: int | None = None
                 ) -> tuple[Any, dict[str, Any]]:
    """(the LatentSpace, phase 3's own options record) of a phase-3 run with these arguments
    (:meth:`~latentune.study.Study.phase3`), checked (:func:`refuse_plain_options`); writes
    nothing but the new place of a moved source run and the source's amendments reported
    (:func:`check_source_run`), and a retraining of its latent space reported
    (:func:`began_latent`)."""
    ls, source = resolve_latent(run, manifest, latent, space, actor)
    strategy = resolve_strategy(manifest, strategy, handover, ls)
    refuse_transfer_on_stored_plain(manifest, strategy, transfer_options, run.dir)
    refuse_plain_options(strategy, method, regions, start)
    require_source_store(strategy, source, max_fall_prob)
    check_source_run(run, manifest, source, ls,
                     latent is not None or mf.learns_from_source(strategy, max_fall_prob))
    ls = began_latent(run, manifest, ls, source, latent is not None)
    start_rec = mf.start_point(start, space.manual, space.dim)[1]
    return ls, mf.phase3_extra(source, strategy, start_rec, max_fall_prob, handover,
                               transfer_options,
                               *source_pin(run.dir, manifest, source,
                                           mf.pins_source(strategy, max_fall_prob, source)))


def refuse_transfer_on_stored_plain(manifest: Manifest, strategy: str,
                                    transfer_options: dict[str, Any] | None, where: Any) -> None:
    """StoreError, in the words a later ask uses (:func:`~latentune.pipeline.manifest.
    stored_plain_refusal`), when ``transfer_options`` are given to a resume of the stored
    plain phase 3 (``strategy`` resolved plain, the phase fixed by a trial)."""
    if transfer_options and strategy == "plain" and manifest.n_fixing(Phase.PHASE3) \
            and strategy_of(manifest.config().get("phase3") or {}) == "plain":
        raise StoreError(mf.stored_plain_refusal(where))


def refuse_plain_options(strategy: str, method: str | None, regions: int | None,
                         start: Any = "manual") -> None:
    """The plain strategy's own options (``method`` other than TuRBO-m, ``regions``, a
    ``start`` other than the manual θ) refused with the transfer strategy, which has no use for
    them (UsageError naming the option)."""
    from latentune.errors import UsageError

    if strategy != "transfer":
        return
    for name, value, unset in (("method", method, method in (None, "turbo")),
                               ("regions", regions, regions is None),
                               ("start", start, isinstance(start, str) and start == "manual")):
        if not unset:
            raise UsageError(f"{name} is an option of the plain phase 3 "
                             f"({option('strategy', 'plain')}), "
                             f"not of the transfer phase 3 (given {name} = {value!r}): its "
                             "search starts from the source's best trials and the manual "
                             "θ, in the latent and the full θ box")


def require_source_store(strategy: str, source: str, max_fall_prob: float | None = None
                         ) -> None:
    """LatentError (one line, before anything is written) when phase 3 is to learn from the
    trials of a source directory that holds a latent space but no run store (``vae.pt`` and
    ``vae.json`` copied without ``run.db``): the transfer phase 3 always does, the plain one
    with ``max_fall_prob`` (its fall prediction starts from them); the plain one without it
    needs the latent space alone. A source directory that no longer exists (a phase 3 started
    from it, the directory moved since) is named as such."""
    if source == "self" or (Path(source) / "run.db").is_file():
        return
    opt = option("latent")      # as the reader gives the source: --vae DIR, or latent=
    if (strategy == "transfer" or max_fall_prob is not None) and not Path(source).exists():
        raise LatentError(f"{opt}: the source run {source} does not exist (moved or "
                          "deleted?): phase 3 learns from its trials; put the run directory "
                          "back there, or give its new place (latent)")
    if strategy == "transfer":
        raise LatentError(f"{opt}: {source} holds a latent space but no run store (run.db): "
                          "the transfer phase 3 learns from the source run's trials; copy the "
                          "run directory with its run.db, or search the latent space alone "
                          f"({option('strategy', 'plain')})")
    if max_fall_prob is not None:
        raise LatentError(f"{opt}: {source} holds a latent space but no run store (run.db): "
                          "the fall prediction (max_fall_prob) starts from the source run's "
                          "trials; copy the run directory with its run.db, or leave the fall "
                          "prediction out")


def source_mismatch(source: Any, counts: dict[str, int] | None,
                    fingerprint: str | None = None, who: str = "phase 3",
                    uses: str = "the latent space it copied when it began",
                    reported: int = 0, record: Callable[[int], None] | None = None
                    ) -> str | None:
    """Why the run at ``source`` is not the source run a phase 3 (``who``) began with, in
    words that follow "it" ("holds 8 phase-1 trials, fewer than the 16 phase 3 began with");
    None when it is, or when nothing is pinned to know it by. That run is known by the trials
    it held then: their ``counts`` (:func:`source_counts`) and ``fingerprint``
    (:func:`~latentune.pipeline.manifest.run_fingerprint`); a phase 3 recorded before the
    fingerprint existed (None) by the counts alone. A run whose pinned trials were amended
    since (:func:`~latentune.pipeline.manifest.amended_since`: the same θ, a cost or fall flag
    corrected) is that run: one warning names the trials amended since that an amendment
    numbered above ``reported`` (the highest one reported before) changed, and says that
    ``who`` goes on with ``uses`` and the amended results; ``record`` is then called with the
    highest amendment number, to be passed as ``reported`` next time: each amendment is
    reported once. The one identity check of a source run: on a
    resume (:func:`require_pinned_trials`), for a moved one (:func:`check_source_run`) and for
    the Optuna sampler's (:class:`~latentune.integrations.optuna.LatentSampler`)."""
    if not counts:
        return None
    if not (Path(source) / "run.db").is_file():
        return "does not exist" if not Path(source).exists() else "holds no run store (run.db)"
    now = mf.run_counts(source) or {}
    for ph, n in sorted(counts.items()):
        if now.get(ph, 0) < int(n):
            held = counted(now.get(ph, 0), f"phase-{ph} trial")
            return f"holds {held}, fewer than the {n} {who} began with"
    if fingerprint is None:
        return None
    since = mf.amended_since(source, counts, fingerprint, reported)
    if since is None:
        began = " and ".join(counted(int(n), f"phase-{ph} trial")
                             for ph, n in sorted(counts.items()) if int(n))
        return f"holds other trials than the {began} {who} began with"
    amended, latest = since
    if amended:
        log.warning("the source run at %s: trial%s %s amended since %s began (%s: a cost or "
                    "fall flag corrected); %s goes on with %s and the amended results", source,
                    "s" if len(amended) > 1 else "", ", ".join(map(str, amended))
                    + (" were" if len(amended) > 1 else " was"), who, option("amend", True),
                    who, uses)
    if record is not None and latest > reported:
        record(latest)
    return None


def require_pinned_trials(source: str, counts: dict[str, int] | None,
                          fingerprint: str | None = None, reported: int = 0,
                          record: Callable[[int], None] | None = None) -> None:
    """LatentError (one line) when the run at ``source`` is not the source run phase 3 began
    with (:func:`source_mismatch`: fewer trials than ``counts``, or other ones than
    ``fingerprint``, amendments since undone): the directory holds another run now (replaced or
    cut since), whose trials would go on in their place. Nothing to check without ``counts``.
    ``reported``, ``record``: the amendments reported before (:func:`source_mismatch`)."""
    why = source_mismatch(source, counts, fingerprint, reported=reported, record=record)
    if why is not None:
        raise LatentError(f"{option('latent')}: the source run at {source} is not the run "
                          f"phase 3 began with: it {why} (replaced since?); put that run back "
                          "there, or give the directory that holds it now (latent)")


def check_source_run(run: RunDir, manifest: Manifest, source: str, latent: Any,
                     reads: bool = True) -> None:
    """Check, before a phase 3 with trials writes anything, that it goes on from the source
    run it began with, ``source`` (the stored one, or the one given: its ``latent`` space).
    The stored source, where phase 3 ``reads`` it (its trials: :func:`~latentune.pipeline.
    manifest.learns_from_source`; or its latent space, given again: a plain phase 3 without a
    fall prediction otherwise searches the copy it made and needs nothing there): LatentError
    (one line) when it holds another run now (:func:`require_pinned_trials`). Another
    directory: recorded as the new place of the source run when that run was moved there: the
    stored directory no longer holds the run phase 3 began with and ``source`` does
    (:func:`source_mismatch`; for a phase 3 recorded before the fingerprint of those trials
    existed, ``latent`` is also the latent space phase 3 copied: counts alone do not tell two
    runs apart), with one warning "source run moved from A to B"; LatentError (one line) when
    ``source`` holds another run. Nothing otherwise: the stored source still holds that run,
    or nothing is pinned to know it by (a plain phase 3 recorded before it pinned its
    source), and the options check names the stored source. A run whose pinned trials were
    amended since is that run (one warning per amendment, :func:`source_mismatch`; the ones
    reported are recorded, :func:`amendments_reported`). This is a phase 3
    start's one check of its source run (:func:`phase_critic` does not check again)."""
    cfg = manifest.config()
    pc = cfg.get("phase3") or {}
    prev, counts, fp = pc.get("latent_source"), pc.get("source_counts"), \
        pc.get("source_fingerprint")
    if source == "self" or prev in (None, "self") or not counts \
            or not manifest.n_fixing(Phase.PHASE3):
        return
    reported, record = amendments_reported(run, manifest, fp)
    if source == prev:
        if reads:
            require_pinned_trials(source, counts, fp, reported, record)
        return
    gone = source_mismatch(prev, counts, fp, reported=reported, record=record)
    if gone is None:
        return
    why = source_mismatch(source, counts, fp, reported=reported, record=record)
    copied = study_latent(run) if why is None and fp is None else None
    if copied is not None and copied.fingerprint() != latent.fingerprint():
        why = ("holds another latent space than the one phase 3 copied from that run (phase 3 "
               "was recorded before its source's trials were fingerprinted: their counts "
               "alone do not tell two runs apart)")
    if why is not None:
        raise LatentError(f"{option('latent')}: {source} is not the run phase 3 began with "
                          f"({prev}, which now {gone}): it {why}; give the directory that "
                          "holds that run now")
    log.warning("%s: phase 3's source run moved from %s to %s (the same trials): recorded "
                "its new place", run.dir, prev, source)
    with run.writing():
        cfg = manifest.config()
        moved = {k: {**cfg[k], "latent_source": source} for k in ("phase3", "asktell")
                 if (cfg.get(k) or {}).get("latent_source") == prev}
        manifest.update(**moved, phase3_vae_source=source)


def began_latent(run: RunDir, manifest: Manifest, latent: Any, source: str,
                 given: bool = True) -> Any:
    """The latent space phase 3 searches, once it has a trial (its zero-shot trial counts):
    the copy it made of its source run's latent space when it began, whatever that run holds
    now; ``latent`` (the one :func:`resolve_latent` found) on a first start, for a phase 3 on
    its own latent space, or when the source was not ``given`` (``latent`` is the copy then).
    A source named again (``given``, :func:`check_source_run` has checked it is the run phase
    3 began with) whose latent space is another now (trained again since, on the same trials)
    gives one warning per retraining (recorded in :data:`RETRAINED_KEY`): phase 3's stored
    trials carry codes of the copy, so it goes on with that one. Call it after
    :func:`check_source_run` (a moved source is recorded there)."""
    from latentune.latent.vae import LatentSpace

    if not given or source == "self" or not manifest.n_fixing(Phase.PHASE3) \
            or manifest.config().get("phase3_vae_source") != source:
        return latent
    path = run.store.artifact("phase3_vae")
    if path is None:
        return latent
    copy = LatentSpace.load(path)
    now = latent.fingerprint()
    reported = {"latent_fingerprint": now}
    if copy.fingerprint() != now and manifest.config().get(RETRAINED_KEY) != reported:
        log.warning("%s holds another latent space than the one phase 3 began with (retrained "
                    "since?): phase 3 goes on with its copy of that one (%s); to search the "
                    "new one, start a new phase 3 in another directory", source, path)
        with run.writing():
            manifest.update(**{RETRAINED_KEY: reported})
    return copy


RETRAINED_KEY = "phase3_retrained_reported"
"""Manifest entry of the last retrained latent space of phase 3's source run reported
(:func:`began_latent`): ``{"latent_fingerprint": its fingerprint}``; absent until one is."""


REPORTED_KEY = "phase3_amendments_reported"
"""Manifest entry of the amendments of phase 3's source run reported so far
(:func:`source_mismatch`): ``{"source_fingerprint": the pin they are of, "amendment": the
highest amendment number reported}``; absent until one is."""


def amendments_reported(run: RunDir, manifest: Manifest, fingerprint: str | None,
                        key: str = REPORTED_KEY) -> tuple[int, Callable[[int], None]]:
    """(the highest amendment of a pinned run (phase 3's source; phase 1's fall prior or
    source run: :data:`PHASE1_PINS`) reported since it was pinned with ``fingerprint``, 0 if
    none; a function recording a higher one in the manifest entry ``key``, default
    :data:`REPORTED_KEY`) for :func:`source_mismatch`: each amendment is reported once."""
    seen = manifest.config().get(key) or {}
    reported = int(seen.get("amendment") or 0) \
        if seen.get("source_fingerprint") == fingerprint else 0

    def record(latest: int) -> None:
        with run.writing():
            manifest.update(**{key: {"source_fingerprint": fingerprint,
                                     "amendment": int(latest)}})
    return reported, record


PHASE1_PINS = {"fall_prior": ("prior_counts", "prior_fingerprint"),
               "source_run": ("source_counts", "source_fingerprint")}
"""The runs phase 1 learns from (its options ``fall_prior`` and ``source_run``, optuna-cmaes's
``source_trials``) and the pins of each in its options record (counts, fingerprint)."""


def check_phase1_runs(run: RunDir, manifest: Manifest, pc: dict[str, Any]) -> dict[str, Any]:
    """Phase 1's options record ``pc`` (:meth:`~latentune.pipeline.manifest.Manifest.
    phase_options`) with the runs it learns from (:data:`PHASE1_PINS`) pinned or checked, each
    read once. Before the phase's first trial: their fingerprints added
    (:func:`~latentune.pipeline.manifest.run_fingerprint` of the trials counted). After it:
    checked against the stored pins (:func:`source_mismatch`): LatentError (one line) naming
    the option when one holds another run now (replaced or cut since; its trials would seed
    the resumed critic in place of the ones it began with), one warning per amendment of their
    trials since (recorded in ``phase1_<option>_amendments_reported``); a pin recorded before
    the fingerprint existed is checked by its counts alone."""
    first = not manifest.n_fixing(Phase.PHASE1)
    out = dict(pc)
    for name, (n_key, fp_key) in PHASE1_PINS.items():
        where, counts, fp = pc.get(name), pc.get(n_key), pc.get(fp_key)
        if where is None or not counts:
            continue
        if first:
            out[fp_key] = mf.run_fingerprint(where, counts)
            continue
        reported, record = amendments_reported(run, manifest, fp,
                                               f"phase1_{name}_amendments_reported")
        why = source_mismatch(where, counts, fp, "phase 1", "those trials", reported, record)
        if why is not None:
            raise LatentError(f"{option(name) if name in FLAGS else name}: the run at {where} "
                              "is not the run phase 1 began "
                              f"with: it {why} (replaced since?); put that run back there")
    return out


def source_pin(run_dir: Path, manifest: Manifest, source: str, pinned: bool
               ) -> tuple[dict[str, int] | None, str | None]:
    """(``source_counts``, ``source_fingerprint``) for phase 3's options record
    (:func:`~latentune.pipeline.manifest.phase3_extra`) when it pins its ``source``'s trials
    (``pinned``, :func:`~latentune.pipeline.manifest.pins_source`; else (None, None)): once
    phase 3 has a trial, the stored ones, which stand (:meth:`~latentune.pipeline.manifest.
    Manifest.phase_options` takes them; :func:`check_source_run` checked the source against
    them), without reading the source; else the source's now (:func:`source_counts`, and
    :func:`~latentune.pipeline.manifest.run_fingerprint` for another run: the one read of its
    trials at a first start)."""
    if not pinned:
        return None, None
    stored = manifest.config().get("phase3")
    if stored and manifest.n_fixing(Phase.PHASE3):
        return stored.get("source_counts"), stored.get("source_fingerprint")
    counts = source_counts(run_dir, source)
    return counts, None if source == "self" else mf.run_fingerprint(source, counts)


def source_counts(run_dir: Path, source: str) -> dict[str, int] | None:
    """How many trials of phases 1 and 3 a phase 3's source run holds (``{"1": n1, "3": n3}``;
    ``source``: its latent space's source, ``"self"`` for the study at ``run_dir``): what the
    transfer phase 3, or the fall prior of the plain one, starts from (recorded,
    :data:`~latentune.pipeline.manifest.PINNED`). None for a source without a store."""
    return mf.run_counts(Path(run_dir) if source == "self" else Path(source))


def resolve_strategy(manifest: Manifest, strategy: str | None, handover: Any,
                     latent: Any = None, fixed: bool = False) -> str:
    """Phase 3's strategy for a call: ``strategy`` if given (checked), else the stored one once
    phase 3 has trials or is ``fixed`` (ask/tell asked it: its options record stands; ``plain``
    for runs recorded before strategies existed), else
    ``transfer`` — or ``plain`` with a hand-over, which is an option of the paper's phase 3.
    Once it is stored, a given strategy other than the stored one, or a hand-over on a
    stored transfer phase 3, is refused (StoreError naming the stored strategy and what to do).
    With ``latent`` (the LatentSpace), a plain strategy on a latent space whose codes all
    decode to one θ is refused here, before any trial (``LatentSpace.require_spread``)."""
    from latentune.errors import UsageError

    if strategy is not None and strategy not in STRATEGIES:
        raise UsageError(f"unknown phase-3 strategy {strategy!r} (choose from "
                         f"{', '.join(STRATEGIES)})")
    stored = manifest.config().get("phase3")
    stored = strategy_of(stored) if stored and (fixed or manifest.n_fixing(Phase.PHASE3)) \
        else None
    where = manifest.run.dir
    # the stored strategy first: ``handover`` may be the stored one, not the caller's
    if stored is not None and strategy not in (None, stored):
        raise StoreError(f"{where}: phase 3 runs with strategy {stored} (stored), not "
                         f"{strategy}: leave strategy out to go on with the {stored} phase 3, "
                         f"or start a {strategy} phase 3 in another directory")
    if strategy == "transfer" and handover:
        raise UsageError(f"{option('handover')} is an option of the plain phase 3 "
                         f"({option('strategy', 'plain')}); the transfer phase 3 moves to the "
                         "full θ box on its own")
    if stored == "transfer" and handover:
        raise StoreError(f"{where}: {option('handover')} is an option of the plain phase 3, and "
                         f"this phase 3 runs with {option('strategy', 'transfer')} (stored), "
                         "which moves to the full θ box on its own: leave "
                         f"{option('handover')} out to go on with it, or start a plain phase 3 "
                         "in another directory")
    if strategy is None:
        strategy = stored or ("plain" if handover else "transfer")
    if strategy == "plain" and latent is not None:
        latent.require_spread()
    return strategy


def transfer_critic(pc: dict[str, Any], space: ParameterSpace, run_dir: Path, source_run: Path,
                    latent: Any) -> Any:
    """The transfer phase 3's critic (:class:`~latentune.critic.transfer.Transfer`) on the θ box:
    the source run's trials (phases 1 and 3; only phase 1 when the source is this run), the
    latent space, the target's manual θ, and the target trials stored outside phase 3 (the
    zero-shot trial and the manual θ's) told to it as data. Its ``budget`` (for
    ``fall_budget``) is the phase's budget and those trials."""
    from latentune.critic.transfer import Transfer
    from latentune.pipeline.baselines import source_trials

    own = Path(source_run).resolve() == Path(run_dir).resolve()
    X, y, fell = source_trials(source_run, phases=(Phase.PHASE1,) if own else None,
                               counts=pc.get("source_counts"))
    if len(y) < 2:
        raise LatentError(f"transfer phase 3: the source run {source_run} has {len(y)} trials; "
                          f"it needs at least 2 (or use {option('strategy', 'plain')})")
    mfp = pc.get("max_fall_prob")
    rows, state = [], None
    if (Path(run_dir) / "run.db").is_file():
        with RunStore(run_dir) as st:
            rows = told_outside(st)
            state = st.get_meta(state_key(Phase.PHASE3))
    critic = Transfer((X, y, fell), latent, space.manual, batch_size=pc["batch_size"],
                      seed=pc["seed"], budget=target_budget(pc, len(rows)),
                      **({} if mfp is None else {"max_fall_prob": mfp}),
                      **(pc.get("transfer_options") or {}))
    if state:           # a stored run: its options (source order among them) from the start
        critic.load_state_dict(state)
    if rows:
        critic.tell(np.array([r.theta for r in rows]), np.array([r.cost for r in rows]),
                    fell=np.array([r.fell for r in rows], dtype=bool))
    if own:     # the source is this system: its best trials and elites are target data already
        from latentune.critic.transfer_model import rank_scores

        X, y, fell = critic.source_rows()           # the order the critic uses its source in
        z = rank_scores(y, fell)
        E = critic.elites()
        known = set(np.argsort(z, kind="stable")[:OWN_TOLD].tolist())
        known |= {int(i) for i in range(len(X)) if np.min(np.abs(E - X[i]).max(1)) <= 1e-12}
        idx = np.array(sorted(known), dtype=np.int64)
        critic.tell_not_target(X[idx], y[idx], fell[idx])
    return critic


def told_outside(st: RunStore) -> list[Row]:
    """The target's trials stored outside phase 3 that the transfer critic is told before its
    own: the manual θ's and the zero-shot trial."""
    return [r for ph in (Phase.MANUAL, Phase.ZERO_SHOT) for r in st.rows(ph)]


def target_budget(pc: dict[str, Any], n_outside: int) -> int | None:
    """The transfer critic's ``budget`` (for ``fall_budget``): phase 3's budget in ``pc`` and
    the ``n_outside`` trials of :func:`told_outside`; None for options without a budget."""
    return None if pc.get("budget") is None else int(pc["budget"]) + int(n_outside)


def stop_note(critic: Any, n: int, budget: int, not_run: int = 0, asked: int = 0) -> str:
    """Why a phase ended with ``n`` of its ``budget`` trials, to end its log line: the fall
    budget a critic spent (:attr:`~latentune.critic.transfer.Transfer.fall_budget_spent`), with
    the ``not_run`` trials it did not start (``asked`` of them: ask/tell's queued suggestions;
    :func:`~latentune.pipeline.phases.not_run_note`), or nothing."""
    if n >= budget or not getattr(critic, "fall_budget_spent", False):
        return ""
    return (f"; stopped at {n} of {counted(budget, 'trial')}: its fall budget "
            f"({counted(critic.falls_allowed(), 'fall')}) is spent"
            + not_run_note(not_run, asked))


def source_costs(run: Any, space: ParameterSpace, counts: dict[str, int] | None = None
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """The phase-1 and phase-3 trials of the run ``run`` as (X (m, d) unit-box θ, cost (m,)),
    or None without a run (``counts``: only the first that many of each phase, :func:`~latentune.
    pipeline.manifest.run_counts`); StoreError when it holds none, or θ of another dimension
    or box than ``space``'s (:func:`require_same_box`)."""
    if run is None:
        return None
    from latentune.pipeline.baselines import source_trials

    X, y, _ = source_trials(run, counts=counts)
    if X.ndim != 2 or len(X) == 0:
        raise StoreError(f"{run} holds no phase-1 or phase-3 trials")
    if X.shape[1] != space.dim:
        raise StoreError(f"the trials of {run} have {X.shape[1]} parameters, the system "
                         f"{space.dim}")
    require_same_box(run, space, f"the source run {run}", StoreError)
    return X, y


def require_same_box(run: Any, space: ParameterSpace, what: str,
                     error: type[Exception]) -> None:
    """Raise ``error`` naming ``what`` when the run at ``run`` recorded a parameter space whose
    unit-box θ mean other physical values than ``space``'s (other names, bounds or scales,
    :meth:`~latentune.space.ParameterSpace.box_difference`); runs without a recorded space, or
    gone, pass."""
    if run is None or not (Path(run) / "run.db").is_file():
        return
    with RunStore(run) as o:
        other = (o.get_meta("config") or {}).get("space")
    diff = None if other is None else space.box_difference(other)
    if diff is not None:
        raise error(f"{what} holds θ of another box than the system's ({diff}): normalized θ "
                    "would not mean the same thing")


def decoder_of(pc: dict[str, Any], latent: Any) -> Any:
    """The map from the critic's box to θ for :func:`run_phase`: None in phase 1 and for a
    two-space critic (a hand-over or the transfer critic decode on their own), else the latent
    space's decoder."""
    if latent is None or pc.get("handover") is not None or strategy_of(pc) == "transfer":
        return None
    return latent.decode


# ---------------------------------------------------------------------------- priors
def _prior_rows(run: Path, counts: dict[str, int] | None = None) -> list[Row]:
    """The phase-1 rows of the run at ``run`` (``counts``: only the first ``counts["1"]``, the
    ones a phase began with, :func:`~latentune.pipeline.manifest.run_counts`)."""
    if not (Path(run) / "run.db").is_file():
        raise StoreError(f"fall prior: no run store in {run}")
    with RunStore(run) as o:
        rows = o.rows(Phase.PHASE1)
    return rows if counts is None else rows[:int(counts.get(str(int(Phase.PHASE1)), 0))]


def theta_prior(run: Any, space: ParameterSpace, counts: dict[str, int] | None = None
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """(θ (m, d), fell (m,)) of another run's phase 1 (the first ``counts``, :func:`_prior_rows`),
    the prior of a direct fall-aware search; StoreError when its θ are of another dimension or
    box than ``space``'s."""
    if run is None:
        return None
    rows = _prior_rows(Path(run), counts)
    if not rows:
        return None
    X = np.array([r.theta for r in rows])
    if X.shape[1] != space.dim:
        raise StoreError(f"fall prior {run}: its θ have {X.shape[1]} entries, not {space.dim}")
    require_same_box(run, space, f"fall prior {run}", StoreError)
    return X, np.array([r.fell for r in rows], dtype=bool)


def latent_prior(run: Path, ls: Any, counts: dict[str, int] | None = None
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """The source run's phase-1 θ (the first ``counts``, :func:`_prior_rows`) encoded into the
    latent unit box (codes outside the box are dropped: clipping would pile them on its faces)
    with their fell flags."""
    rows = _prior_rows(run, counts)
    if not rows:
        return None
    Z = np.atleast_2d(ls.encode(np.array([r.theta for r in rows])))
    inside = np.all((Z >= ls.box[:, 0]) & (Z <= ls.box[:, 1]), axis=1)
    fell = np.array([r.fell for r in rows], dtype=bool)[inside]
    return ls.to_unit(Z[inside]), fell


# ---------------------------------------------------------------------------- latent space
def study_latent(run: RunDir) -> Any:
    """The latent space phase 3 uses in ``run`` (own or copied), or None."""
    from latentune.latent.vae import LatentSpace

    if not run.exists:
        return None
    src = run.store.artifact("phase3_vae") or run.store.artifact("vae")
    return None if src is None else LatentSpace.load(src)


def resolve_latent(run: RunDir, manifest: Manifest, latent: Any, space: ParameterSpace,
                   actor: str | None = None) -> tuple[Any, str]:
    """(LatentSpace, source) for phase 3 on ``space``: source is "self" or the source study's
    resolved path. ``latent``: None (the study's own, or the one copied before), a
    LatentSpace, or another study (a directory, or an object with ``dir``). LatentError if the
    latent space's θ are not this space's (dimension, names, actor), or ``space`` has one
    parameter (no smaller latent space); with ``latent`` None and no latent space here, the
    LatentError says to train one, or to run phase 1 first where the run holds no phase-1
    trial."""
    from latentune.latent.vae import LatentSpace

    me = run.dir.resolve()
    if space.dim < 2:
        raise LatentError(f"a {space.dim}-dim θ has no smaller latent space for phase 3 to "
                          "search: run phase 1 alone")
    if latent is None:
        prev = manifest.config().get("phase3_vae_source")
        if prev not in (None, "self") and run.store.artifact("phase3_vae") is not None:
            ls, source = LatentSpace.load(run.store.artifact("phase3_vae")), prev
        elif run.exists and run.store.artifact("vae") is not None:
            ls, source = LatentSpace.load(run.store.artifact("vae")), "self"
        elif not run.exists or not run.store.count(Phase.PHASE1):     # nothing to train on
            raise LatentError(f"no latent space in {run.dir} and no phase-1 trial to train one "
                              "on: run phase 1 there first (phase1, then train_latent), or "
                              "name another study's (latent)")
        else:
            raise LatentError(f"no latent space in {run.dir}: train one first "
                              "(train_latent / train-vae), or name another study's (latent)")
    elif isinstance(latent, LatentSpace):
        src = latent.meta.get("source_run")
        ls = latent
        source = "self" if src is None or Path(src) == me else str(src)
    else:
        other = getattr(latent, "dir", latent)
        if not isinstance(other, (str, os.PathLike)):
            raise LatentError(f"latent must be a study, its run directory or a LatentSpace, not "
                              f"{type(latent).__name__} {latent!r:.40}")
        other = Path(other)
        opt = option("latent")      # as the reader gives it: --vae DIR, or latent=
        if other.exists() and not other.is_dir():
            holder = other.parent if (other.parent / "vae.pt").is_file() else None
            raise LatentError(f"{opt}: {other} is a file, not a run directory: give the run "
                              "directory that holds the latent space (vae.pt, vae.json) and "
                              "run.db" + (f" ({holder})" if holder is not None else ""))
        if not other.is_dir():
            raise LatentError(f"{opt}: run directory {other} does not exist")
        src = None
        if (other / "run.db").is_file():
            with RunStore(other) as o:
                src = o.artifact("vae")
                searched = (o.get_meta("config") or {}).get("phase3_vae_source")
            if src is None and not (other / "vae.pt").is_file():
                if searched not in (None, "self"):      # a phase 3 on another's latent space
                    raise LatentError(f"{opt}: {other} holds no latent space of its own: it "
                                      f"is a phase 3 on the latent space of {searched}; give "
                                      f"that run instead ({opt})")
                raise LatentError(f"{opt}: {other} holds no latent space: train one there "
                                  "first (train_latent / train-vae)")
        ls = LatentSpace.load(src if src is not None else other / "vae")
        source = "self" if other.resolve() == me else str(other.resolve())
    if ls.d != space.dim:
        raise LatentError(f"the latent space ({source}) maps to {ls.d}-dim θ, but the "
                          f"system has {space.dim}-dim θ")
    names = ls.meta.get("space_names")
    diff = None if names is None else space.names_difference(list(names))
    if diff is not None:
        raise LatentError(f"the latent space ({source}) was trained on θ named otherwise than "
                          f"the system's, {diff}: normalized θ would not mean the same thing")
    if source != "self":
        require_same_box(source, space, f"the latent space's run ({source})", LatentError)
    trained = ls.meta.get("actor")
    if trained is not None and actor is not None and trained != actor:
        raise LatentError(f"the latent space ({source}) was trained on θ of the {trained} "
                          f"actor, not {actor}: normalized θ of different actors do not mean "
                          "the same thing")
    return ls, source


def latent_to_record(manifest: Manifest) -> bool:
    """Whether :func:`record_latent` writes: no latent space of phase 3 is recorded yet, or
    phase 3 has no trial (its zero-shot trial counts) to fix it."""
    return manifest.config().get("phase3_vae_source") is None \
        or manifest.n_fixing(Phase.PHASE3) == 0


def record_latent(run: RunDir, manifest: Manifest, ls: Any, source: str) -> None:
    """Record the latent space of phase 3 (copied into the run when it is another study's);
    StoreError if phase 3 already ran on another one: a phase-3 trial, or its zero-shot trial
    (the other study's best θ, run, queued or handed out), is stored with it."""
    st = run.store
    prev = manifest.config().get("phase3_vae_source")
    zero_shot = manifest.n_used(Phase.ZERO_SHOT)
    used = manifest.n_used(Phase.PHASE3) + zero_shot
    if prev is not None and prev != source and used > 0:
        raise StoreError(f"{run.dir}: phase 3 was run with the latent space of {prev}, "
                         f"not {source}" + ("" if used > zero_shot else
                                            f" (its zero-shot trial is the best θ of {prev})"))
    if latent_to_record(manifest):
        if source != "self":
            dst = run.dir / "phase3_vae"
            ls.save(dst)
            st.add_artifact("phase3_vae", dst)
        manifest.update(phase3_vae_source=source,
                        latent={"kind": ls.kind, "d": ls.d, "d_low": ls.d_low,
                                "box": ls.box.tolist(), "box_rule": ls.meta.get("box_rule"),
                                "n_train": ls.meta.get("n_train"),
                                "from": {k: ls.meta.get(k) for k in
                                         ("robot", "gait", "actor", "terrain")}})
