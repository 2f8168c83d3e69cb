"""Study: the public pipeline of latentune on a run directory (the paper's Algorithm 1).

``Study(DIR)`` opens (or creates) ``DIR/run.db``, the single source of truth of a run. On it:

* :meth:`Study.phase1` — the critic (TuRBO-m by default) tunes the full θ of a System
  (``AC_GEN(f, Id)``), starting from the system's manual θ;
* :meth:`Study.train_latent` — phase 2: a VAE on the θ of phase 1 whose trial did not fail;
* :meth:`Study.phase3` — on the same or another system, from this study's source run or
  another's (whose best θ is first run as it is: zero-shot): by default everything the source
  tried (:mod:`latentune.critic.transfer`), or the paper's latent search (``AC_GEN(f, D)``);
* :meth:`Study.ask` / :meth:`Study.tell` — the same loop driven by a person, with leases and
  amendments (:mod:`latentune.pipeline.asktell`);
* :meth:`Study.status`, :meth:`Study.best`, :meth:`Study.best_params`, :meth:`Study.trials`,
  :meth:`Study.trials_dataframe`, :meth:`Study.summary`, :meth:`Study.report`.

A study is a thin façade over its run directory (store, lock, evaluator:
:mod:`latentune.pipeline.rundir`), its manifest (system, options, seed:
:mod:`latentune.pipeline.manifest`) and the one phase loop (:mod:`latentune.pipeline.loop`,
:mod:`latentune.pipeline.phases`). Every phase resumes from the stored rows and refuses other
options, another system or another seed than it was started with; a reopened study takes its
seed and batch size from the store. One process writes a study at a time
(:class:`~latentune.errors.LockError`; an ask or a tell waits a bounded time).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Callable

from latentune.checks import is_whole
from latentune.constants import Phase
from latentune.errors import StoreError, UsageError
from latentune.pipeline import asktell, baselines, phase2, results
from latentune.pipeline import manifest as mf
from latentune.pipeline.asktell import Suggestion
from latentune.pipeline.baselines import source_best
from latentune.pipeline.evaluators import Evaluator
from latentune.pipeline.loop import (check_phase1_runs, decoder_of, phase3_setup, phase_critic,
                                     record_latent, resolve_latent, reuse_phases, stop_note,
                                     study_latent, theta_prior)
from latentune.pipeline.manifest import describe
from latentune.pipeline.phases import (PhaseResult, default_batch_size, ensure_manual,
                                       manual_outcome, run_phase)
from latentune.pipeline.rundir import RunDir
from latentune.pipeline.store import Row, RunStore
from latentune.space import ParameterSpace
from latentune.system import check_system

METHODS = mf.METHODS
ASK_BUDGET = mf.ASK_BUDGET


class Study:
    """A resumable run directory and the three phases on it (see the module docstring).

    Args:
        path: the run directory (created when a phase first writes to it).
        seed: seed of every critic, VAE and trial of this study (recorded). ``None``: the
            stored one for an existing study, else 0; another than the stored one is refused.
        workers: parallel trials; ``backend``: ``serial``, ``process`` (a local pool) or ``ray``
            (``ray_address`` for a cluster, else a local Ray); serial runs one at a time.
        batch_size: points per critic ask (default: the phase's stored one, else
            ``max(workers, 4)``).
        progress: show a progress bar; ``log``: a callable for one-line messages (default none).
        evaluator: an Evaluator to use instead of starting one (shared by several studies;
            the caller closes it; ``workers`` should be its worker count).
        trial_timeout: seconds a trial may run (process backend) before its worker is killed
            and it is stored as failed; None: the stored one (recorded by a phase), else none.
    """

    def __init__(self, path: str | os.PathLike, *, seed: int | None = None, workers: int = 1,
                 backend: str = "serial", ray_address: str | None = None,
                 batch_size: int | None = None, progress: bool = False,
                 log: Callable[[str], None] | None = None,
                 evaluator: Evaluator | None = None, trial_timeout: float | None = None) -> None:
        for name, v, lo in (("seed", seed, 0), ("workers", workers, 1),
                            ("batch_size", batch_size, 1)):
            if (v is not None or name == "workers") and not is_whole(v, lo):
                raise UsageError(f"{name} must be an integer >= {lo}, got {v!r}")
        if seed is not None and not 0 <= int(seed) < 2 ** 63:
            raise UsageError(f"seed must be below 2**63, got {seed}")
        if log is not None and not callable(log):
            raise UsageError(f"log must be a callable taking one line, got {log!r:.40}")
        self.run = RunDir(path, workers=int(workers), backend=backend, ray_address=ray_address,
                          evaluator=evaluator)
        self.manifest = mf.Manifest(self.run)
        self.run.trial_timeout = self.manifest.trial_timeout(trial_timeout)
        self.dir = self.run.dir
        stored = self.manifest.stored_seed()
        if seed is not None and stored is not None and int(seed) != stored:
            raise StoreError(f"{self.dir}: the study was run with seed = {stored}, not {seed} "
                             "(leave the seed out to reopen it)")
        self.seed = int(seed if seed is not None else stored if stored is not None else 0)
        self.workers = int(workers)
        self._batch_size = None if batch_size is None else int(batch_size)
        self.progress = bool(progress)
        self._log = log

    # ------------------------------------------------------------------ run directory
    @property
    def exists(self) -> bool:
        """Whether the directory holds a run store."""
        return self.run.exists

    @property
    def store(self) -> RunStore:
        """The run store (opened read-write; StoreError if there is none yet)."""
        return self.run.store

    @property
    def batch_size(self) -> int:
        """The batch size given, else ``max(workers, 4)`` (a stored phase keeps its own)."""
        return self._batch_size or default_batch_size(self.workers)

    def batch_size_of(self, phase: int) -> int:
        """The batch size of ``phase``: the one given, else the stored one, else the default."""
        stored = self.config().get(mf.PHASE_KEYS[Phase(int(phase))]) or {}
        return self._batch_size or int(stored.get("batch_size") or default_batch_size(self.workers))

    def writing(self, wait: float = 0.0) -> Any:
        """Hold the study's write lock (re-entrant); yields the store (created if needed)."""
        return self.run.writing(wait)

    def evaluator(self) -> Evaluator:
        """The study's evaluator (started on first use; stopped by :meth:`close`)."""
        return self.run.evaluator()

    def close(self) -> None:
        """Stop the evaluator and close the store."""
        self.run.close()

    def __enter__(self) -> "Study":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def log(self, msg: str) -> None:
        """Pass a one-line message to the study's ``log`` callable (if any)."""
        if self._log is not None:
            self._log(msg)

    # ------------------------------------------------------------------ manifest
    def config(self) -> dict[str, Any]:
        """The stored configuration (empty for a new study)."""
        return self.manifest.config()

    def bind(self, system: Any) -> dict[str, Any]:
        """Record ``system`` as the study's system, or check it is the one recorded."""
        return self.manifest.bind(system)

    def bind_check(self, system: Any) -> dict[str, Any]:
        """``system``'s description; StoreError naming the differences unless it is the
        recorded one (or none is recorded yet)."""
        return self.manifest.bind_check(system)

    def space(self) -> ParameterSpace | None:
        """The study's parameter space (stored with its first phase), or None."""
        return self.manifest.space()

    def latent(self) -> Any:
        """The latent space phase 3 uses here (own or copied), or None."""
        return study_latent(self.run)

    def _options(self, phase: int, method: str | None, budget: int, regions: int | None,
                 extra: dict[str, Any], max_new: int | None = None) -> dict[str, Any]:
        return self.manifest.phase_options(phase, method=method, budget=budget, regions=regions,
                                           seed=self.seed, batch_size=self.batch_size_of(phase),
                                           extra=extra, max_new=max_new, phase_run=True)

    # ------------------------------------------------------------------ phases
    def phase1(self, system: Any, budget: int, *, method: str | None = None,
               regions: int | None = None, start: Any = "manual",
               max_fall_prob: float | None = None, fall_prior: Any = None, source_run: Any = None,
               max_new: int | None = None, record: dict[str, Any] | None = None) -> PhaseResult:
        """Phase 1: ``method`` (None: the stored one, else TuRBO-m; ``optuna-*``: Optuna's
        samplers, ``source_run``: a run whose trials are ``optuna-cmaes``'s ``source_trials``)
        tunes the full θ of ``system`` for ``budget`` evaluations in all, stored ones included.

        ``start``: ``"manual"`` (the first point is the system's manual θ), ``None`` (from
        scratch: the critic's own initial design) or a (d,) unit-box θ (e.g. another run's best).
        ``max_fall_prob``: skip candidates whose predicted probability of failing exceeds it
        (TuRBO-m also fills its first design around ``start`` and halves its trust region when
        more than that share of a batch falls, see
        :func:`~latentune.pipeline.phases.make_phase_critic`); ``fall_prior``: a run directory
        whose phase-1 trials (θ, failed) seed that prediction. ``max_new``: stop after this
        many new trials. ``record``: entries stored in the run's configuration with phase 1's
        options once every option is checked, before any trial (e.g. a command's whole plan)."""
        check_system(system)
        extra = {"start": mf.start_point(start, system.space.manual, system.space.dim)[1],
                 **mf.fall_options(max_fall_prob, fall_prior),
                 **mf.source_option(method, source_run)}
        self._options(Phase.PHASE1, method, budget, regions, extra, max_new)   # checked first
        if max_fall_prob is not None:
            theta_prior(fall_prior, system.space)
        with self.run.writing(evaluating=True) as st:
            self.bind(system)
            pc = self._options(Phase.PHASE1, method, budget, regions, extra)
            pc = check_phase1_runs(self.run, self.manifest, pc)
            self.manifest.update(phase1=pc, **(record or {}))
            self.manifest.record_run(self.seed)
            with self.manifest.timing("phase1"):       # its first row is the manual trial
                manual = ensure_manual(st, system, self.seed, self.evaluator())
                self.log(f"manual θ: cost {manual:.3f}")
                critic = phase_critic(Phase.PHASE1, pc, system.space, self.dir)
                res = run_phase(st, Phase.PHASE1, system, critic, pc["budget"], self.evaluator(),
                                seed=self.seed, progress=self.progress, max_new=max_new,
                                known=manual_outcome(st, system))
            results.write_best(st, self.dir, system.space, Phase.PHASE1)
            self.log(res.line())
            return res

    def train_latent(self, latent_dim: int | None = None, *, kind: str | None = None,
                     epochs: int | None = None, retrain: bool = False) -> Any:
        """Phase 2: train the latent space on the phase-1 θ whose trial did not fail.

        Returns the :class:`~latentune.latent.LatentSpace` (``DIR/vae.pt``, ``DIR/vae.json``); a
        trained one as it is unless ``retrain`` (another size, kind or epochs is refused), which
        is refused after phase 3 used it. A refusal leaves the directory as it was."""
        with self.writing(), phase2.wall_kept(self.manifest, "vae"), \
                self.run.as_before_on_error():      # a Ctrl-C keeps the time spent
            latent, msg = phase2.train_latent(self.run, self.manifest, self.seed, latent_dim,
                                              kind, epochs, retrain)
        if msg:
            self.log(msg)
        return latent

    def phase3(self, system: Any, budget: int, *, latent: Any = None, method: str | None = None,
               regions: int | None = None, start: Any = "manual",
               max_fall_prob: float | None = None, handover: Any = None,
               strategy: str | None = None, transfer_options: dict[str, Any] | None = None,
               max_new: int | None = None) -> PhaseResult:
        """Phase 3 on ``system`` with the ``strategy`` (default ``"transfer"``: everything the
        source run tried as a model of the target, latent and full θ boxes,
        :mod:`latentune.critic.transfer`; ``"plain"``: the paper's phase 3, ``method`` in the
        latent box through the decoder; ``method`` (None: the stored one, else TuRBO-m),
        ``regions``, ``start`` and ``handover`` are its options, refused with the transfer).

        Args:
            latent: None (this study's latent space), a LatentSpace, or another study (its
                directory or a Study) whose latent space is copied here.
            start: ``"manual"`` (the first point is the code of the manual θ), ``None`` (from
                scratch) or a (d,) unit-box θ whose code starts the search.
            max_fall_prob: skip candidates whose predicted probability of failing exceeds it
                (a prediction that starts from the source run's falls; transfer default 0.3).
            handover: ``True`` or a dict of options (``patience``, ``tol``, ``length``): when
                the latent search stalls, continue with TuRBO-m on the full θ box from the best
                decoded θ (:mod:`latentune.critic.handover`; recorded as ``phase3_handover``).
            transfer_options: options of the transfer critic (its module's docstring): a dict
                of :data:`~latentune.critic.transfer.TRANSFER_DEFAULTS` keys but max_fall_prob.
            max_new: stop after this many new trials.
        If the latent space comes from another study, its best θ is evaluated on ``system``
        first (the zero-shot trial). The critic: :func:`~latentune.pipeline.loop.phase_critic`."""
        check_system(system)
        ls, extra = phase3_setup(self.run, self.manifest, system.space, _actor(system), latent,
                                 strategy, start, max_fall_prob, handover, transfer_options,
                                 method, regions)
        source, strategy = extra["latent_source"], extra["strategy"]
        self._options(Phase.PHASE3, method, budget, regions, extra, max_new)   # checked first
        if self.exists:
            self.bind_check(system)
        with self.run.writing(evaluating=True) as st:
            self.bind(system)
            pc = self._options(Phase.PHASE3, method, budget, regions, extra)
            record_latent(self.run, self.manifest, ls, source)
            self.manifest.update(phase3=pc)
            self.manifest.record_run(self.seed)
            with self.manifest.timing("phase3"):        # the target's trials, these two too
                if strategy == "plain" or source == "self":  # transfer: the manual θ a candidate
                    manual = ensure_manual(st, system, self.seed, self.evaluator())
                    self.log(f"manual θ: cost {manual:.3f}")
                zs = baselines.zero_shot(st, system, source, self.seed, self.evaluator())
                if zs is not None:
                    self.log(f"zero-shot (the source's best θ as it is): cost {zs:.3f}")
                critic = phase_critic(Phase.PHASE3, pc, system.space, self.dir, ls)
                try:
                    res = run_phase(st, Phase.PHASE3, system, critic, pc["budget"],
                                    self.evaluator(), decoder=decoder_of(pc, ls), seed=self.seed,
                                    progress=self.progress, max_new=max_new, strategy=strategy,
                                    reuse=reuse_phases(Phase.PHASE3, pc))
                finally:
                    if pc["handover"] is not None:
                        self.manifest.update(phase3_handover=critic.rule())
            results.write_best(st, self.dir, system.space, Phase.PHASE3)
            self.log(res.line() + stop_note(critic, res.n, pc["budget"], res.not_run, res.asked))
            return res

    def preservation(self, system: Any, latent: Any) -> dict[str, Any]:
        """Pass each phase-1 θ of this study whose trial did not fail through ``latent``'s
        encoder and decoder and evaluate the result on ``system`` (phase 5, idx = the source
        row's idx). Returns ``{n_stable, n_kept, rate}``; resumes."""
        space = check_system(system).space
        with self.run.writing(evaluating=True) as st:
            ls, source = resolve_latent(self.run, self.manifest, latent, space, _actor(system))
            with self.manifest.timing("preservation_rollouts"):
                return baselines.preservation(st, system, ls, source, self.evaluator(), self.seed)

    # ------------------------------------------------------------------ ask / tell
    def ask(self, n: int = 1, *, system: Any = None, space: ParameterSpace | None = None,
            phase: int | None = None, latent: Any = None, method: str | None = None,
            budget: int | None = None, regions: int | None = None, start: Any = None,
            max_fall_prob: float | None = None, fall_prior: Any = None, handover: Any = None,
            strategy: str | None = None, transfer_options: dict[str, Any] | None = None,
            asker: str | None = None, lease_s: float | None = None) -> list[Suggestion]:
        """Hand out ``n`` suggestions for trials run elsewhere (the asker's pending ones first).

        The first ask fixes the study's system or ``space``, the phase (1; 3 with a latent
        space or in a run holding a phase 3) and its options as :meth:`phase1` /
        :meth:`phase3` take them (``budget`` default 200; ``start``: ``"manual"``, ``"scratch"``
        or a (d,) unit-box θ, not for the transfer phase 3); a later ask takes them from the
        store (None) and refuses another value (a budget may grow); it hands out the batch
        :meth:`tell` prepared when still the critic's (``asker``, ``lease_s``: ``asktell``)."""
        return asktell.ask(self, n, system=system, space=space, phase=phase, latent=latent,
                           asker=asker, lease_s=lease_s, method=method, budget=budget,
                           regions=regions, start=start, max_fall_prob=max_fall_prob,
                           fall_prior=fall_prior, handover=handover, strategy=strategy,
                           transfer_options=transfer_options)

    def tell(self, trial_id: int, cost: float | None = None, *, failed: bool = False,
             note: str | None = None, info: dict[str, Any] | None = None,
             amend: bool = False, asker: str | None = None) -> Row:
        """Store the result of suggestion ``trial_id``: its cost (None with ``failed``: the C1
        convention; or an ``Outcome`` alone), whether it failed, a free note. ``amend``:
        correct a told result (the old one is kept in the store's audit trail). ``asker``: who
        tells it (``info["told_by"]``). StoreError for an unknown id, one told already (without
        ``amend``), never handed out, or leased to another asker than ``asker``. With no
        suggestion left out, it prepares the next ask's batch (:func:`~latentune.pipeline.
        asktell.prepare`)."""
        return asktell.tell(self, trial_id, cost, failed=failed, note=note, info=info,
                            amend=amend, asker=asker)

    def release(self, trial_id: int) -> None:
        """End the lease of a pending suggestion now: the next ask hands it out again."""
        asktell.release(self, trial_id)

    def amendments(self) -> list[dict[str, Any]]:
        """The audit trail of amended results (see :meth:`RunStore.amendments`)."""
        return self.store.amendments() if self.exists else []

    # ------------------------------------------------------------------ results
    def best(self, phase: int | None = None) -> Row | None:
        """The best stored trial that did not fail: of ``phase``, or over the manual θ, phases
        1 and 3 and zero-shot (default); None if there is none."""
        phases = results.TUNING if phase is None else results.phases_arg(phase)
        return results.best_row(self.store, phases) if self.exists else None

    def best_params(self, out: str | os.PathLike | None = None) -> Path:
        """Write the θ to deploy (the best trial over all phases that did not fail, physical
        values by name and what they are tuned for, a ``--params`` file) to ``out`` (default
        ``DIR/best.json``); return the path. StoreError without a store or a trial that stood."""
        return results.best_params(self.store, self.dir, self.space(), out)[0]

    def status(self) -> dict[str, Any]:
        """Per phase and in all, with phase 3's budget: :func:`latentune.pipeline.results.status`."""
        return results.status(self.store, self.dir, self.manifest.config())

    def trials(self, phases: Any = None) -> list[results.TrialRecord]:
        """Every stored trial of ``phases`` (a phase number or several, default all) as a
        record: phase by name, θ by name in physical units, cost, failed, info, suggestion id
        (:class:`~latentune.pipeline.results.TrialRecord`), in the order they were stored."""
        phases = None if phases is None else results.phases_arg(phases)
        return results.trials(self.store, self.space(), phases) if self.exists else []

    def trials_dataframe(self, phases: Any = None) -> Any:
        """:meth:`trials` as a pandas DataFrame (ImportError naming pandas if it is absent)."""
        return results.trials_dataframe(self.trials(phases), self.space() if self.exists else None)

    def summary(self) -> dict[str, Any]:
        """Write and return ``DIR/summary.json`` (see :mod:`latentune.reporting.run_report`)."""
        from latentune.reporting.run_report import write_summary

        return write_summary(self.store)

    def report(self, system: Any = None, simulate: bool = True) -> str:
        """Write ``DIR/report.md`` with its figures; return the comparison table (Markdown).

        Re-simulated CoM plots need a system with ``rollout`` (a built-in task is rebuilt from
        the stored configuration; a user system only if passed here)."""
        from latentune.reporting.run_report import make_report

        if system is not None:
            self.bind_check(system)
        return make_report(self.store, system=system, simulate=simulate, quiet=not self.progress)


def _actor(system: Any) -> str | None:
    actor = getattr(system, "actor", None)
    return actor if isinstance(actor, str) else None


def stderr_log(msg: str) -> None:
    """A ``log`` for :class:`Study` that logs at INFO on the ``latentune.study`` logger (shown
    on stderr by the CLI with -v, or by any logging configuration of the caller)."""
    logging.getLogger(__name__).info(msg)


__all__ = ["Study", "Suggestion", "describe", "source_best", "stderr_log"]
