"""latentune inside Optuna (the ``latentune[optuna]`` extra): samplers and study import.

* :class:`LatentSampler` — latentune's phase 3 as an ``optuna.samplers.BaseSampler``: the critic
  searches the latent box of a source run (phases 1 + 2 done on a simulator), decodes each point
  to a normalized θ and maps it to the source's physical parameters by name.
  ``optuna.create_study(sampler=LatentSampler("runs/sim"))``, then ``study.optimize(objective)``
  or ``study.ask()`` / ``study.tell()``.
* :class:`TurboSampler` — latentune's TuRBO-m (phase 1) on the θ box of a given search space.
* :func:`import_optuna_study` — an Optuna study run on a simulator becomes a latentune phase-1
  run, so ``Study(out).train_latent()`` and phase 3 use it without re-running a trial.
* :class:`~latentune.critic.optuna.OptunaCritic` — the other way round: Optuna's TPE
  (multivariate), CMA-ES (with ``source_trials``, its transfer mode) and GPSampler as latentune
  critics, the methods ``optuna-tpe``, ``optuna-cmaes`` and ``optuna-gp`` of
  :meth:`Study.phase1 <latentune.study.Study.phase1>` (same phase loop, store, evaluator and
  resume as latentune's methods): the baselines a user would pick instead.

How the samplers see a study
----------------------------
Every sample rebuilds the critic from the study (it keeps nothing between trials, so any number
of processes may share one RDB or journal storage):

* each COMPLETE trial is told with its value (negated for a ``maximize`` study) and a fall flag;
  each FAIL trial is told as a fall with cost +inf (the critics treat it as the worst cost seen);
  PRUNED and WAITING trials are not told (a PRUNED trial's θ is not asked again); a value
  that is not finite (or of 1e300 in size or more) is no cost: the trial is told as a fall
  with cost +inf, as a FAIL, and one that stood with one gets a ``UserWarning`` naming it as it
  finishes (Optuna has recorded it and keeps it: a refusal would stop every later sample, so
  the study could not go on; :func:`import_optuna_study` imports it the same way);
* a trial *falls* (``failed`` in latentune) when any of its Optuna constraint values is > 0 —
  set by ``trial.set_constraint(name, value)`` in the objective, or by a ``constraints_func``
  given to the sampler (called in ``after_trial``, as Optuna's own samplers do) — or when its
  user attribute ``latentune_failed`` (:data:`FAILED_ATTR`) is true;
* a trial is told at the θ it ran with, its parameters: a trial the sampler proposed carries
  its critic point and tag in the system attribute ``latentune:point`` and, when its parameters
  are that θ, is told exactly; any other trial (enqueued, partly enqueued — a fixed value
  differs from the sampler's —, another sampler, the zero-shot one) with every parameter inside
  the box is an external, untagged point at its own θ (in the latent box: its θ encoded; a code
  outside the latent box is left out); a trial lacking a parameter of the space is left out;
* RUNNING trials are pending: a trial asks the rebuilt critic for ``len(pending) + 2`` points
  (and one per PRUNED trial, which the critic, not told, asks again), passes over those whose
  θ a trial of the study already has (a RUNNING trial's θ is recorded
  the moment it is sampled), leaves one more to each pending trial with a smaller number that is
  sampling at the same moment, and takes the next. It records its θ, then checks: when another
  RUNNING trial recorded the same θ at that moment, it chooses again, leaving the first untaken
  points to those with smaller numbers; so workers on one storage do not run the same θ. With
  one worker a seed gives the same trials every time.
* what the told trials do not determine (TuRBO-m's warm-started GP hyperparameters) is kept in
  the study's system attribute ``latentune:critic_state:<key>`` after every sample;
* the transfer strategy searches from the source run's trials as they were at the study's first
  sample (their counts pinned in ``latentune:source_counts:<key>``, as ``Study.phase3`` pins
  them): a source run that gets more trials later does not change a study under way;
* the latent space too is the one of the study's first sample (``latentune:latent_space``): a
  sampler whose source's latent space was trained again since is refused;
* ``budget`` is the trials planned, every trial of the study that ran or runs counted: a trial
  past it is sampled as any other (by the critic planned for the budget: its trust regions, its
  fall budget), with one ``UserWarning`` per study and sampler; a new sampler with a larger
  budget goes on with the study's trials.

The objective must suggest every parameter of the sampler's space with the same bounds and
scale (``sampler.distributions()`` gives them; ``sampler.suggest_all(trial)`` suggests them all);
a parameter outside that space is sampled by ``independent_sampler`` (default
``optuna.samplers.RandomSampler(seed)``). Other bounds for a parameter of the space, or one
of its parameters not suggested (a misspelled name), raise a ``UsageError`` naming the
parameter (and both ranges): at the suggest when the sampler's value lies outside the
objective's bounds, else in ``after_trial`` when the trial finishes COMPLETE (Optuna records
it; ``study.optimize`` stops, ``study.tell`` raises). Another scale (``log``), or another kind
(``suggest_int``, ``suggest_categorical``, a stepped ``suggest_float``), is refused at the
suggest, a ``UsageError`` naming the parameter as a float weight of the space (the sampler
returns no relative parameters: each of the space reaches ``sample_independent`` with the
suggest's distribution and gets the θ ``sample_relative`` chose). Single-objective studies only.

Import rules (:func:`import_optuna_study`)
------------------------------------------
* float distributions (linear or log) map to the :class:`~latentune.space.ParameterSpace`
  (bounds: the widest seen for the name across trials; the scale must be the same in all);
* int distributions and stepped floats (``step=``) are **refused**: a latent space decodes to
  continuous θ, which the objective's ``suggest_int`` / stepped ``suggest_float`` would not take
  back; categorical distributions are refused too — each with one line naming the parameter;
* with ``space=`` (``--space``) only the parameters it names are imported (each must be a float
  of the study); the trials' other parameters (an int or categorical option of the objective
  outside the controller) are left out, with one warning naming them and saying whether their
  values varied across the imported trials (then the costs depend on them too); the names are
  recorded in the run's ``phase1.import.left_out_params``;
* a ``maximize`` study is negated (latentune minimizes); multi-objective studies are refused;
* COMPLETE trials are phase-1 rows; a COMPLETE trial with a constraint value > 0 or
  ``latentune_failed`` is a fall (a failed row, its value kept as its cost); FAIL trials are
  falls with cost +inf; PRUNED, RUNNING and WAITING trials are left out, and so
  are trials that lack one of the parameters (a warning counts them);
* a value that is not finite (or of 1e300 in size or more) is no cost (:func:`trial_cost`):
  the trial is a fall with cost +inf, as a FAIL, as the samplers tell it; one that stood with
  such a value (``-inf`` in a minimize study is Optuna's best) is named in one warning;
* rows are untagged (tag −1: points the critic did not ask for), in trial-number order, with
  ``info`` = ``optuna_trial``, ``optuna_state``, ``optuna_value``, ``constraints``; importing
  again into the same directory adds the trials not imported yet.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import warnings
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from latentune.checks import is_whole
from latentune.constants import COST_LIMIT, Phase
from latentune.errors import LatentError, LatentuneError, StoreError, UsageError
from latentune.space import ParameterSpace

try:
    import optuna
    from optuna.samplers import BaseSampler
except ImportError:  # pragma: no cover - the extra is not installed
    raise ImportError("latentune.integrations.optuna needs Optuna: "
                      "pip install 'latentune[optuna]'") from None

logger = logging.getLogger(__name__)

POINT_ATTR = "latentune:point"
"""Trial system attribute of a sampled trial: ``{"key", "seed", "u", "z", "tag", "theta",
"told", "pending", "skipped"}``: the sampler configuration's key (its budget not in it: a study
resumed with a larger budget goes on with the trials it ran, as ``Study.phase3`` does; keys
written with the budget map to it by :func:`canonical_key`), the critic's seed, the critic's
unit-box point, the
latent code (or None), the critic's tag, the normalized θ, how many finished and pending trials
the critic saw, and how many free points it left to pending trials not sampled yet."""
STATE_ATTR = "latentune:critic_state:"
"""Prefix of the study system attribute holding the critic state of a sampler configuration."""
SOURCE_ATTR = "latentune:source_counts:"
"""Prefix of the study system attribute pinning, for a LatentSampler configuration with the
transfer strategy, how many phase-1 and phase-3 trials of its source run the study searches
from (``{"1": n1, "3": n3}``, as ``Study.phase3`` pins them): set at the study's first sample."""
SOURCE_PRINT_ATTR = "latentune:source_fingerprint:"
"""Prefix of the study system attribute pinning, beside :data:`SOURCE_ATTR`, the fingerprint of
those source trials (:func:`latentune.pipeline.manifest.run_fingerprint`): a source directory
that holds other trials later is refused (:func:`latentune.pipeline.loop.source_mismatch`);
studies pinned before it existed are checked by the counts alone."""
AMENDED_ATTR = "latentune:source_amendments_reported:"
"""Prefix of the study system attribute holding, beside :data:`SOURCE_PRINT_ATTR`, the highest
amendment of those source trials a sampler reported (a warning per amendment, not per
sampler: :func:`latentune.pipeline.loop.source_mismatch`); absent until one is."""
LATENT_ATTR = "latentune:latent_space"
"""Study system attribute pinning the latent space a study's LatentSampler searches:
``{"fingerprint", "source_run"}`` (:meth:`latentune.latent.LatentSpace.fingerprint`) of the
sampler of its first sample that asks the critic; a later sampler with another latent space
(its source's trained again since, or another run's) is refused. Studies sampled before it
existed are pinned to the latent space in their first sampled trial's key."""
FAILED_ATTR = "latentune_failed"
"""Trial user attribute: true marks a fall (``trial.set_user_attr("latentune_failed", True)``)."""
ZERO_SHOT_ATTR = "latentune:zero_shot"
"""Trial system attribute: the trial got the source run's best θ as it is (LatentSampler)."""
INSTALL_HINT = "install the optuna extra: pip install 'latentune[optuna]'"
THETA_ATOL = 1e-7
"""How far (normalized θ) a trial's parameters may lie from the θ the sampler recorded for it
and still count as that θ (the physical round trip changes the last bits only)."""


class OptunaImportError(LatentuneError, ValueError):
    """An Optuna study (or storage) that cannot become a latentune run, with the reason."""


# ---------------------------------------------------------------------------- spaces
def space_from_distributions(dists: Mapping[str, Any], manual: Mapping[str, float] | None = None
                             ) -> ParameterSpace:
    """A :class:`ParameterSpace` from Optuna distributions by name (the import rules).

    ``FloatDistribution(low, high, log)`` without ``step`` maps to one entry; an
    ``IntDistribution``, a stepped float or a ``CategoricalDistribution`` raises
    :class:`OptunaImportError` naming the parameter. ``manual``: physical values by name (the
    manual θ; default the centre of the unit box)."""
    D = optuna.distributions
    names, low, high, log = [], [], [], []
    for name, d in dists.items():
        if isinstance(d, D.CategoricalDistribution):
            raise OptunaImportError(f"parameter {name!r} is categorical ({len(d.choices)} "
                                    "choices): latentune tunes continuous θ only")
        if isinstance(d, D.IntDistribution):
            raise OptunaImportError(f"parameter {name!r} is an integer distribution: latentune "
                                    "refuses int parameters (a latent space decodes to continuous "
                                    "θ); suggest it with suggest_float")
        if not isinstance(d, D.FloatDistribution):
            raise OptunaImportError(f"parameter {name!r} has an unsupported distribution "
                                    f"{type(d).__name__}")
        if d.step is not None:
            raise OptunaImportError(f"parameter {name!r} is a stepped float (step={d.step:g}): "
                                    "latentune refuses stepped parameters (a latent space decodes "
                                    "to continuous θ)")
        if not d.high > d.low:
            raise OptunaImportError(f"parameter {name!r} has an empty range [{d.low:g}, {d.high:g}]")
        names.append(str(name))
        low.append(float(d.low))
        high.append(float(d.high))
        log.append(bool(d.log))
    if not names:
        raise OptunaImportError("no parameters: the study has no trial with float parameters")
    man = None
    if manual is not None:
        unknown = sorted(set(manual) - set(names))
        if unknown:
            raise OptunaImportError(f"manual values for unknown parameter(s): {', '.join(unknown)}")
        centre = ParameterSpace(names, low, high, log).manual_physical
        man = [float(manual.get(n, c)) for n, c in zip(names, centre)]
    try:
        return ParameterSpace(names, low, high, log, man)
    except ValueError as exc:
        raise OptunaImportError(str(exc)) from None


def distributions_of(space: ParameterSpace) -> dict[str, Any]:
    """``{name: optuna.distributions.FloatDistribution(low, high, log=...)}`` of ``space``."""
    return {n: optuna.distributions.FloatDistribution(float(lo), float(hi), log=bool(lg))
            for n, lo, hi, lg in zip(space.names, space.lower, space.upper, space.log)}


def _unit_of(space: ParameterSpace, params: Mapping[str, Any]) -> np.ndarray | None:
    """The normalized θ (d,) of a trial's ``params`` (physical, by name), or None when a
    parameter is missing, not a finite number, or outside the space's box."""
    try:
        x = np.array([float(params[n]) for n in space.names], dtype=float)
    except (KeyError, TypeError, ValueError):
        return None
    if not np.all(np.isfinite(x)):
        return None
    u = space.to_unit(x)
    if np.any(u < -1e-9) or np.any(u > 1 + 1e-9):
        return None
    return np.clip(u, 0.0, 1.0)


def _range(d: Any) -> str:
    """``[low, high]`` with ``(log)`` / ``step`` of a float or int distribution, else its repr."""
    if isinstance(d, (optuna.distributions.FloatDistribution,
                      optuna.distributions.IntDistribution)):
        fl = isinstance(d, optuna.distributions.FloatDistribution)
        step = "" if d.step is None or (not fl and d.step == 1) else f" (step {d.step:g})"
        return f"[{d.low:g}, {d.high:g}]{'' if fl else ' (int)'}{' (log)' if d.log else ''}{step}"
    return repr(d)


def physical_params(space: ParameterSpace, u: np.ndarray) -> dict[str, float]:
    """Physical values by name of the unit-box θ ``u`` (d,), clipped to the bounds (a log
    entry at u = 1 can round past its upper bound)."""
    x = np.clip(space.to_physical(np.clip(u, 0.0, 1.0)), space.lower, space.upper)
    return {n: float(v) for n, v in zip(space.names, x)}


def trial_fell(trial: Any, state: Any = None) -> bool:
    """Whether a finished Optuna trial is a fall: state FAIL, a constraint value > 0, or the
    user attribute :data:`FAILED_ATTR` set to a true value. ``state``: the state it is being
    finished with (in ``after_trial``, before the storage records it), else its own."""
    if (trial.state if state is None else state) == optuna.trial.TrialState.FAIL:
        return True
    if bool(trial.user_attrs.get(FAILED_ATTR, False)):
        return True
    return any(float(v) > 0 for v in trial.constraints.values())


def trial_cost(trial: Any, sign: float) -> float:
    """The cost latentune minimizes for a finished trial: ``sign · value`` (sign −1 for a
    maximize study); +inf for a FAIL trial (it has no value) and for a value that is no cost:
    not finite, or of :data:`~latentune.constants.COST_LIMIT` (1e300) in size or more, as in
    latentune's own trials (:func:`latentune.system.as_outcome`). Such a trial is told as a
    fall (:func:`_sampled_fell`), even one that stood (Optuna keeps a COMPLETE ``-inf`` in a
    minimize study as its best, which latentune cannot rank)."""
    v = trial.values[0] if trial.values else None
    return float(sign) * float(v) if v is not None and _is_cost(v) else math.inf


def _is_cost(v: float) -> bool:
    """Whether an objective value is a cost latentune takes: finite, below COST_LIMIT in size."""
    return math.isfinite(float(v)) and abs(float(v)) < COST_LIMIT


def _sampled_fell(trial: Any, state: Any = None, values: Sequence[float] | None = None
                  ) -> bool:
    """Whether the samplers tell a finished trial as a fall: :func:`trial_fell`, or a value
    that is no cost (not finite, or of 1e300 in size or more: a blown-up objective).
    ``state``, ``values``: those it is being finished with (in ``after_trial``, before the
    storage records them), else its own."""
    vs = trial.values if values is None else values
    v = vs[0] if vs else None
    return trial_fell(trial, state) or (v is not None and not _is_cost(v))


def _sign(study: Any) -> float:
    if len(study.directions) != 1:
        raise UsageError("latentune's samplers and import take single-objective studies only")
    return -1.0 if study.direction == optuna.study.StudyDirection.MAXIMIZE else 1.0


# ---------------------------------------------------------------------------- samplers
def _phase3_critic(source_run: Path, latent: Any, space: ParameterSpace, *, strategy: str,
                   method: str, batch_size: int, seed: int,
                   x0: np.ndarray | None, budget: int, regions: int | None,
                   max_fall_prob: float | None = None,
                   prior: tuple[np.ndarray, np.ndarray] | None = None,
                   transfer_options: dict[str, Any] | None = None,
                   source_counts: dict[str, int] | None = None
                   ) -> tuple[Any, Callable[[np.ndarray], np.ndarray] | None]:
    """The phase-3 critic of :class:`LatentSampler`: ``(critic, decoder)``, the one place that
    chooses it, as ``Study.phase3`` does (:func:`latentune.pipeline.loop.phase_critic`).

    ``strategy="transfer"`` (the default): :class:`~latentune.critic.transfer.Transfer` on the
    θ box from the trials of ``source_run`` (the first ``source_counts`` of phases 1 and 3; its
    parameter space ``space`` gives the manual θ),
    a two-space critic (it asks θ; decoder None), with ``transfer_options`` (checked by the
    sampler) and the study's ``budget`` (its fall budget's base). ``strategy="plain"``: the
    paper's phase 3,
    :func:`~latentune.pipeline.phases.make_phase_critic` on the latent unit box [0, 1]^d_low
    (``x0``: (d_low,) code of the warm start; ``prior``: (codes (m, d_low), fell (m,)) of the
    source run for the fall-aware option), with the decoder ``latent.decode``."""
    if strategy == "transfer":
        from latentune.critic.transfer import Transfer
        from latentune.pipeline.baselines import source_trials

        X, y, fell = source_trials(source_run, counts=source_counts)
        mfp = {} if max_fall_prob is None else {"max_fall_prob": max_fall_prob}
        return Transfer((X, y, fell), latent, space.manual, batch_size=batch_size, seed=seed,
                        budget=budget, **mfp, **(transfer_options or {})), None
    from latentune.pipeline.phases import make_phase_critic

    latent.require_spread()
    critic = make_phase_critic(method, latent.d_low, batch_size, seed, x0, budget, regions,
                               max_fall_prob, prior)
    return critic, latent.decode


class _CriticSampler:
    """Shared machinery of the samplers (see the module docstring); subclasses set the space,
    the critic and the map from a trial's θ to the critic's box."""

    _space: ParameterSpace
    _key: str

    def _init_common(self, seed: int, budget: int, regions: int | None, method: str,
                     max_fall_prob: float | None, constraints_func: Callable | None,
                     independent_sampler: Any) -> None:
        from latentune.critic import METHODS

        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or \
                not 0 <= int(seed) < 2 ** 63:
            raise UsageError(f"seed must be an integer in [0, 2**63), got {seed!r}")
        if not is_whole(budget, 1, 2 ** 63 - 1):
            raise UsageError(f"budget must be an integer >= 1 and below 2**63, got {budget!r}")
        if method not in METHODS:
            raise UsageError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
        if regions is not None and not is_whole(regions, 1, 100):
            raise UsageError(f"regions must be an integer in [1, 100], got {regions!r}")
        if regions is not None and method != "turbo":
            raise UsageError(f"regions (trust regions) is an option of method turbo (TuRBO-m), "
                             f"not of {method} (given regions = {regions})")
        if max_fall_prob is not None and (isinstance(max_fall_prob, bool) or
                                          not 0.0 < float(max_fall_prob) <= 1.0):
            raise UsageError(f"max_fall_prob must be in (0, 1], got {max_fall_prob!r}")
        if constraints_func is not None and not callable(constraints_func):
            raise UsageError("constraints_func must be callable (trial -> sequence of floats)")
        if independent_sampler is not None and not isinstance(independent_sampler, BaseSampler):
            raise UsageError("independent_sampler must be an Optuna sampler "
                             f"(optuna.samplers.BaseSampler), got {independent_sampler!r}")
        self.seed = int(seed)
        self.budget = int(budget)
        self.method = method
        if regions is None and method == "turbo":
            from latentune.critic.turbo import regions_for_budget

            regions = regions_for_budget(self.budget)
        self.regions = None if method != "turbo" else int(regions)  # type: ignore[arg-type]
        self.max_fall_prob = None if max_fall_prob is None else float(max_fall_prob)
        self.batch_size = 1
        self._constraints_func = constraints_func
        self._independent = independent_sampler or optuna.samplers.RandomSampler(seed=self.seed)
        self._dists = distributions_of(self._space)
        self._given: dict[tuple[int, int], dict[str, float]] = {}
        # (storage, study id) of the studies warned of a trial past the budget
        self._past_budget: set[tuple[int, int]] = set()

    # ------------------------------------------------------------------ subclass hooks
    def _critic(self, study: Any) -> tuple[Any, Callable[[np.ndarray], np.ndarray] | None]:
        """(critic, decoder or None) for a sample of ``study``."""
        raise NotImplementedError

    def _external_point(self, theta: np.ndarray) -> np.ndarray | None:
        """The critic-box point of a θ the critic did not ask for (None: leave it out)."""
        raise NotImplementedError

    def _fixed_theta(self, study: Any, trial: Any) -> np.ndarray | None:
        """A θ decided without the critic (LatentSampler's zero-shot trial), else None."""
        return None

    def _study_attr(self, study: Any, prefix: str, attrs: dict[str, Any] | None = None) -> Any:
        """The study system attribute ``prefix`` + the sampler's key, else one written under a
        key of the same configuration in the form before the budget left keys
        (:func:`canonical_key`; pinned source counts: the fewest, the first pinned), else
        None."""
        if attrs is None:
            attrs = study._storage.get_study_system_attrs(study._study_id)
        if prefix + self._key in attrs:
            return attrs[prefix + self._key]
        old = [v for k, v in attrs.items() if k.startswith(prefix) and
               canonical_key(k[len(prefix):]) == self._key]
        if not old:
            return None
        if prefix == SOURCE_ATTR:
            return min(old, key=lambda c: sum(int(n) for n in c.values()))
        return old[-1]

    # ------------------------------------------------------------------ public helpers
    @property
    def space(self) -> ParameterSpace:
        """The physical parameter space the sampler proposes (names, bounds, scales)."""
        return self._space

    def distributions(self) -> dict[str, Any]:
        """The Optuna distributions to suggest, by name (``FloatDistribution(low, high, log)``)."""
        return dict(self._dists)

    def suggest_all(self, trial: Any) -> dict[str, float]:
        """``trial.suggest_float`` for every parameter of the space; physical values by name."""
        return {n: trial.suggest_float(n, d.low, d.high, log=d.log) for n, d in self._dists.items()}

    # ------------------------------------------------------------------ BaseSampler
    def infer_relative_search_space(self, study: Any, trial: Any) -> dict[str, Any]:
        return dict(self._dists)

    def sample_relative(self, study: Any, trial: Any, search_space: dict[str, Any]
                        ) -> dict[str, Any]:
        if not search_space:
            return {}
        _sign(study)
        self._warn_past_budget(study, trial)
        theta, point = self._next(study, trial)
        for _ in range(4):      # write, then check: of two trials given one θ, one sees it
            if point is None:
                break
            study._storage.set_trial_system_attr(trial._trial_id, POINT_ATTR, point)
            if point.get("fall_budget_spent"):      # the best standing θ again, on purpose
                break
            clash = self._clashes(study, trial, theta)
            if not clash:
                break
            logger.info("trial %d: θ given to trial(s) %s at the same moment; choosing again",
                        trial.number, [n for n, _ in clash])
            theta, point = self._next(study, trial, extra_skip=sum(
                n < trial.number for n, running in clash if running))
        self._given[(study._study_id, trial._trial_id)] = physical_params(self._space, theta)
        return {}

    def _warn_past_budget(self, study: Any, trial: Any) -> None:
        """Warn (``UserWarning``, once per study and sampler) when ``trial`` is past the
        budget: the study's trials that ran or run (WAITING ones not yet), ``trial`` included,
        are more than ``budget``. The trial is sampled as any other: the critic goes on as
        planned for ``budget`` trials (its trust-region count, its fall budget's base)."""
        which = (id(study._storage), study._study_id)
        if which in self._past_budget:
            return
        waiting = optuna.trial.TrialState.WAITING
        n = 1 + sum(t.number != trial.number and t.state != waiting
                    for t in study.get_trials(deepcopy=False))
        if n <= self.budget:
            return
        self._past_budget.add(which)
        name = type(self).__name__
        warnings.warn(f"{name}: trial {trial.number} makes {n} trials in the study, past its "
                      f"budget of {self.budget}: the search goes on as planned for "
                      f"{self.budget} trials; to plan for more, go on with a {name} of a "
                      "larger budget (the study keeps its trials)",
                      UserWarning, stacklevel=2)

    def sample_independent(self, study: Any, trial: Any, param_name: str,
                           param_distribution: Any) -> Any:
        """A parameter outside the space goes to ``independent_sampler``. One of the space gets
        the value of the θ :meth:`sample_relative` chose for the trial (it returns no relative
        parameters, so that the suggest's own distribution reaches the sampler; Optuna would
        refuse another kind, ``suggest_int``, with a message of its own): a parameter of the
        space suggested as another kind (int, stepped, categorical) or on bounds or a scale
        that do not hold the value is refused, :class:`UsageError` naming it; bounds that hold
        it are refused as the trial finishes (:meth:`_check_finished`)."""
        want = self._dists.get(param_name)
        if want is None:
            return self._independent.sample_independent(study, trial, param_name,
                                                        param_distribution)
        D = optuna.distributions
        if not isinstance(param_distribution, D.FloatDistribution) or \
                param_distribution.step is not None:
            d = param_distribution
            kind = ("a categorical" if isinstance(d, D.CategoricalDistribution) else
                    f"an int on [{d.low:g}, {d.high:g}]" if isinstance(d, D.IntDistribution)
                    else f"a stepped float (step {d.step:g})" if isinstance(
                        d, D.FloatDistribution) else type(d).__name__)
            raise UsageError(f"{type(self).__name__}: parameter {param_name!r} is suggested "
                             f"as {kind}, but it is a float weight of the sampler's space on "
                             f"{_range(want)}: suggest it with suggest_float and those bounds "
                             "(sampler.distributions() or sampler.suggest_all(trial))")
        value = self._given.get((study._study_id, trial._trial_id), {}).get(param_name)
        if value is None or param_distribution.log != want.log or \
                not param_distribution.low <= value <= param_distribution.high:
            raise UsageError(self._other_bounds(param_name, param_distribution))
        return value

    def _other_bounds(self, name: str, dist: Any, number: int | None = None) -> str:
        at = "" if number is None else f"trial {number}: "
        return (f"{type(self).__name__}: {at}parameter {name!r} is suggested on "
                f"{_range(dist)}, but the sampler's space has it on {_range(self._dists[name])}: "
                "suggest it with those bounds (sampler.distributions() or "
                "sampler.suggest_all(trial))")

    def _check_finished(self, study: Any, trial: Any, state: Any,
                        values: Sequence[float] | None) -> None:
        """Refuse (:class:`UsageError`) a trial finishing COMPLETE that the critic cannot be
        told truly: a parameter of the space suggested with other bounds, or not
        suggested at all (a misspelled name: the trial did not run at a θ of the space). Optuna
        still records the trial; the refusal stops ``study.optimize`` (``study.tell`` raises
        it). A value that is no cost while the trial stood gets a ``UserWarning``: the trial
        is told as a fall (:func:`_sampled_fell`)."""
        if state != optuna.trial.TrialState.COMPLETE:
            return
        for n, d in self._dists.items():
            got = trial.distributions.get(n)
            if got is None:
                extra = sorted(set(trial.params) - set(self._dists))
                raise UsageError(
                    f"{type(self).__name__}: trial {trial.number}: parameter {n!r} of the "
                    "sampler's space was not suggested"
                    + (f" (it suggested {', '.join(map(repr, extra[:5]))} outside it)"
                       if extra else "")
                    + ": the critic cannot be told the θ it ran at; suggest every parameter "
                      "of the space (sampler.suggest_all(trial))")
            if got != d:
                raise UsageError(self._other_bounds(n, got, trial.number))
        v = values[0] if values else None
        if v is not None and not _is_cost(v) and \
                not trial_fell(study._storage.get_trial(trial._trial_id), state):
            warnings.warn(f"{type(self).__name__}: trial {trial.number} stood with value "
                          f"{float(v):g}: that is no cost, so the sampler counts it as a fall "
                          f"(cost +inf); to say so, mark the trial a fall "
                          f"(trial.set_constraint(...) > 0 or the user attribute "
                          f"{FAILED_ATTR!r}), else return a finite value",
                          UserWarning, stacklevel=2)

    def before_trial(self, study: Any, trial: Any) -> None:
        self._independent.before_trial(study, trial)

    def after_trial(self, study: Any, trial: Any, state: Any, values: Sequence[float] | None
                    ) -> None:
        if self._constraints_func is not None:
            from optuna.samplers._base import _process_constraints_after_trial

            _process_constraints_after_trial(self._constraints_func, study, trial, state)
        self._independent.after_trial(study, trial, state, values)
        self._given.pop((study._study_id, trial._trial_id), None)
        self._check_finished(study, trial, state, values)
        self._after_fall_budget(study, trial, state, values)

    def _after_fall_budget(self, study: Any, trial: Any, state: Any,
                           values: Sequence[float] | None) -> None:
        """Subclass hook called after each trial (LatentSampler: its fall budget)."""

    def reseed_rng(self) -> None:
        self._independent.reseed_rng()

    # ------------------------------------------------------------------ the critic loop
    def _history(self, trials: list[Any], sign: float, exclude: int, two_space: bool, dim: int,
                 extra: tuple[int, bool] | None = None
                 ) -> tuple[list[np.ndarray], list[float], list[int], list[bool], list[Any]]:
        """(points, costs, tags, fell, z) of the finished trials in ``trials`` (number order);
        ``extra`` = (number, fell): a trial being finished now counts as finished with that
        fall flag (its cost is not read)."""
        S = optuna.trial.TrialState
        X, y, tags, fell, Z = [], [], [], [], []
        for t in sorted(trials, key=lambda t: t.number):
            now = extra is not None and t.number == extra[0]
            if t.number == exclude or (t.state not in (S.COMPLETE, S.FAIL) and not now):
                continue
            told = self._told_point(t, two_space, dim)
            if told is None:
                continue
            x, tag, z = told
            X.append(x)
            y.append(math.nan if now else trial_cost(t, sign))
            tags.append(tag)
            fell.append(bool(extra[1]) if now else _sampled_fell(t))
            Z.append(z)
        return X, y, tags, fell, Z

    def _told_point(self, t: Any, two_space: bool, dim: int
                    ) -> tuple[np.ndarray, int, Any] | None:
        """(critic point, tag, code) a finished trial is told at: the θ it ran with.

        A trial that lacks a parameter of the space, or has one outside the box, cannot be
        mapped (None: left out). A trial whose parameters are the θ the sampler recorded for it
        (``POINT_ATTR``) is told at its critic point and tag; any other (an enqueued or fixed
        value, another sampler, the zero-shot trial) is an external point at its own θ
        (:meth:`_external_point`; None when that is outside the critic's box)."""
        theta = _unit_of(self._space, t.params)
        if theta is None:
            return None
        pt = t.system_attrs.get(POINT_ATTR)
        if isinstance(pt, dict) and canonical_key(pt.get("key")) == self._key and \
                len(pt.get("u", ())) == dim and pt.get("theta") is not None and \
                np.allclose(theta, np.clip(np.asarray(pt["theta"], dtype=float), 0.0, 1.0),
                            rtol=0.0, atol=THETA_ATOL):
            return np.asarray(pt["u"], dtype=float), int(pt["tag"]), pt.get("z")
        x = theta if two_space else self._external_point(theta)
        return None if x is None else (x, -1, None)

    def _clashes(self, study: Any, trial: Any, theta: np.ndarray) -> list[tuple[int, bool]]:
        """(number, still RUNNING) of the other trials that have ``theta``: recorded when they
        were sampled (``POINT_ATTR``) or as their parameters. A trial that finished in the
        meantime counts too: a fast objective can complete between one worker's sampling and
        another's check."""
        key = _key_of(theta)
        running = optuna.trial.TrialState.RUNNING
        out = []
        for t in study.get_trials(deepcopy=False):
            if t.number == trial.number:
                continue
            pt = t.system_attrs.get(POINT_ATTR)
            mine = isinstance(pt, dict) and pt.get("theta") is not None and \
                _key_of(np.asarray(pt["theta"], dtype=float)) == key
            u_t = None if mine else _unit_of(self._space, t.params)
            if mine or (u_t is not None and _key_of(u_t) == key):
                out.append((t.number, t.state == running))
        return out

    def _next(self, study: Any, trial: Any, extra_skip: int = 0
              ) -> tuple[np.ndarray, dict[str, Any] | None]:
        """The normalized θ (d,) for ``trial`` and the point record to store with it.

        One snapshot of the study's trials gives the history (finished trials), the pending
        ones (RUNNING, other than ``trial``) and the θ already taken: every trial's parameters,
        and the θ a RUNNING trial was given (``POINT_ATTR``, written as soon as it is sampled,
        before its parameters). The critic is asked for ``len(pending) + 2`` points, and one
        per PRUNED trial (not told, the critic asks its θ again); those whose θ is taken are
        passed over, then one more for each pending trial with a smaller
        number whose θ is not known yet (it is sampling now and takes that one), and the trial
        takes the next (asking again when none is left). ``extra_skip``: pass over that many
        more (a trial that was given the same θ as others with smaller numbers, at the same
        moment, leaves them the first ones)."""
        fixed = self._fixed_theta(study, trial)
        if fixed is not None:
            return fixed, None
        S = optuna.trial.TrialState
        sign = _sign(study)
        trials = study.get_trials(deepcopy=False)              # one snapshot for everything
        critic, decoder = self._critic(study)
        two_space = hasattr(critic, "last_z")
        X, y, tags, fell, Z = self._history(trials, sign, trial.number, two_space, critic.dim)
        if X:
            kw: dict[str, Any] = {}
            if two_space:
                k = critic.last_z.shape[1]
                kw["z"] = np.array([np.full(k, np.nan) if z is None else np.asarray(z, float)
                                    for z in Z])
            critic.tell(np.array(X), np.array(y, dtype=float), np.array(tags, dtype=np.int64),
                        fell=np.array(fell, dtype=bool), **kw)
        skey = STATE_ATTR + self._key
        state = self._study_attr(study, STATE_ATTR)
        if X and state and hasattr(critic, "load_state_dict"):
            critic.load_state_dict(state)
        if getattr(critic, "fall_budget_spent", False):
            U = critic.ask(1)
            logger.warning("trial %d: the fall budget is spent (%d falls allowed): it re-runs "
                           "the best θ that stood; stop the study", trial.number,
                           critic.falls_allowed())
            return np.clip(U[0], 0.0, 1.0), {
                "key": self._key, "seed": self.seed, "u": [float(v) for v in U[0]], "z": None,
                "tag": int(critic.last_tags[0]), "theta": [float(v) for v in U[0]],
                "told": len(X), "pending": 0, "skipped": 0, "fall_budget_spent": True}
        others = [t for t in trials if t.number != trial.number]
        # pending: RUNNING trials that take (or may take) a critic point; an enqueued trial
        # (fixed parameters) and the zero-shot trial do not
        pending = [t for t in others if t.state == S.RUNNING and "fixed_params" not in
                   t.system_attrs and not t.system_attrs.get(ZERO_SHOT_ATTR)]
        pending_numbers = {t.number for t in pending}
        taken: set[tuple[float, ...]] = set()
        unknown = 0                     # pending trials before this one whose θ is not known yet
        for t in others:
            u_t = _unit_of(self._space, t.params)
            if u_t is not None:
                taken.add(_key_of(u_t))
            pt = t.system_attrs.get(POINT_ATTR)
            if t.state == S.RUNNING and isinstance(pt, dict) and pt.get("theta") is not None:
                taken.add(_key_of(np.asarray(pt["theta"], dtype=float)))
            elif t.number in pending_numbers and t.number < trial.number and u_t is None:
                unknown += 1
        # a PRUNED trial is not told, so the rebuilt critic asks its θ again: one more each
        untold = sum(t.state == S.PRUNED for t in others)
        n_ask, skip = len(pending) + 2 + untold + extra_skip, unknown + extra_skip
        chosen = None
        for _ in range(8):
            U = critic.ask(n_ask)
            T = critic.last_tags.copy()
            LZ = critic.last_z.copy() if two_space else None
            for i in range(len(U)):
                theta, z = self._decoded(U[i], None if LZ is None else LZ[i], decoder)
                if _key_of(theta) in taken:
                    continue
                if skip > 0:            # left for a pending trial with a smaller number
                    skip -= 1
                    continue
                chosen = (U[i], theta, z, int(T[i]))
                break
            if chosen is not None:
                break
            logger.info("trial %d: every asked θ is taken already; asking again", trial.number)
            n_ask, skip = 2, 0
        if chosen is None:      # no trial is run twice: this one fails, the study stops
            few = (f" ({len(taken)} θ in all): the latent space decodes the region the plain "
                   "strategy searches to few θ; go on with strategy='transfer' (it searches the "
                   "full θ box as well), or a latent space trained on more source trials"
                   if getattr(self, "strategy", None) == "plain" else "")
            raise LatentuneError(f"{type(self).__name__}: trial {trial.number}: the critic keeps "
                                 f"proposing θ that are in the study already{few}")
        u, theta, z, tag = chosen
        if hasattr(critic, "state_dict"):
            st = critic.state_dict()
            if st:
                study._storage.set_study_system_attr(study._study_id, skey, st)
        point = {"key": self._key, "seed": self.seed, "u": [float(v) for v in u], "z": z,
                 "tag": tag, "theta": [float(v) for v in theta], "told": len(X),
                 "pending": len(pending), "skipped": unknown}
        logger.debug("trial %d: %d told, %d pending (%d before it not sampled yet), tag %d",
                     trial.number, len(X), len(pending), unknown, tag)
        return np.clip(theta, 0.0, 1.0), point

    @staticmethod
    def _decoded(u: np.ndarray, zr: np.ndarray | None, decoder: Callable | None
                 ) -> tuple[np.ndarray, list[float] | None]:
        """(θ (d,), stored code or None) of an asked point ``u``: a two-space critic's point
        is θ with its code ``zr`` (NaN: none); else ``decoder(u)`` with code ``u``, or ``u``
        itself without a decoder."""
        if zr is not None:
            return np.clip(u, 0.0, 1.0), ([float(v) for v in zr] if np.all(np.isfinite(zr))
                                          else None)
        if decoder is None:
            return np.clip(u, 0.0, 1.0), None
        return np.clip(np.asarray(decoder(u[None, :]), dtype=float)[0], 0.0, 1.0), \
            [float(v) for v in u]


def canonical_key(key: Any) -> str | None:
    """A sampler configuration's key (:data:`POINT_ATTR`'s ``key``) in the form written now:
    without the budget, with the trust-region count the critic runs with (``regions=R``; None
    but for TuRBO-m). A key written before (``…:{regions}:{budget}:…``) maps to the same form,
    so a study resumed with another budget knows its trials; any other value is returned as it
    is (None for a non-string)."""
    from latentune.critic.turbo import regions_for_budget

    if not isinstance(key, str):
        return None
    p = key.split(":")
    try:
        if p[0] == "latent" and len(p) >= 8 and not p[4].startswith("regions="):
            turbo = p[2] == "plain" and p[3] == "turbo"
            r = None if not turbo else (int(p[4]) if p[4] != "None" else
                                        regions_for_budget(int(p[5])))
            return ":".join(p[:4] + [f"regions={r}"] + p[6:])
        if p[0] == "theta" and len(p) == 7 and not p[3].startswith("regions="):
            r = int(p[3]) if p[3] != "None" else regions_for_budget(int(p[4]))
            return ":".join(p[:3] + [f"regions={r}"] + p[5:])
    except ValueError:
        pass
    return key


def _key_of(theta: np.ndarray) -> tuple[float, ...]:
    """A hashable key of a normalized θ (rounded to 1e-9: parameters stored in physical units
    and mapped back differ from the proposed θ in the last bits)."""
    return tuple(np.round(np.asarray(theta, dtype=float), 9).tolist())


class LatentSampler(_CriticSampler, BaseSampler):
    """latentune's phase 3 as an Optuna sampler over a source run's parameter names.

    ``LatentSampler(source_run, seed=0, *, strategy="transfer", method="turbo", budget=200,
    regions=None, start="manual", zero_shot=True, max_fall_prob=None, transfer_options=None,
    constraints_func=None, independent_sampler=None)``

    Args:
        source_run: a latentune run directory with phase 1 and a trained latent space
            (``Study.train_latent``, ``latentune train-vae``, or an imported Optuna study).
        seed: the critic's seed (recorded in each sampled trial's ``latentune:point``).
        strategy: ``"transfer"`` (default: latentune's phase 3 from every source trial, on the
            latent and the full θ box, :mod:`latentune.critic.transfer`) or ``"plain"`` (the
            paper's phase 3 on the latent box; ``method``, ``regions`` and ``start`` are its
            options).
        method: the plain strategy's critic on the latent box: ``turbo`` (TuRBO-m), ``cma``, ``random``,
            ``sobol``; ``budget``: the trials you plan (TuRBO-m's trust regions unless
            ``regions`` is given: 1 below 750), the zero-shot and enqueued trials included.
            A trial past it is sampled all the same, as planned for ``budget``, with one
            ``UserWarning`` per study; a new sampler with a larger budget goes on with the
            study's trials.
        start: ``"manual"`` (the first critic point is the code of the source space's manual
            θ), ``"best"`` (the code of the source's best θ) or None (the critic's design).
        zero_shot: the study's first trial is the source's best θ as it is (latentune's
            zero-shot baseline; it counts in the budget and is told to the critic as an
            external point). Trials enqueued before it (``study.enqueue_trial``) run first,
            as given, and are told as ordinary external points (a partly enqueued one takes
            its other values from the source space's manual θ, not from the critic, whose
            first point can be the zero-shot θ); the zero-shot trial is the first one after
            them that is not enqueued (none when one of them ran its θ).
        max_fall_prob: skip candidates whose predicted fall probability exceeds it (the
            source run's phase-1 θ, encoded, with their fall flags, seed the prediction).
        transfer_options: options of the transfer critic over its defaults
            (:data:`latentune.critic.transfer.TRANSFER_DEFAULTS`, as ``Study.phase3``'s
            ``transfer_options``), checked here: UsageError naming a bad one. With
            ``{"fall_budget": q}`` the study may fall ``max(1, ⌊q·budget⌋)`` times
            (:meth:`fall_budget`): once that is spent and a trial stood, ``study.optimize``
            stops after the trial that spent it (``study.stop()``), and a trial asked after
            that (``study.ask()``, another worker) re-runs the best θ that stood, with a
            warning.
        constraints_func: Optuna's ``trial -> sequence of floats``; a value > 0 is a fall.
        independent_sampler: for parameters outside the source's space.

    The sampler never gives a trial a θ the study holds already (a finished, running or pruned
    trial's): the critic's next point is taken instead. When the plain critic proposes only
    such θ (a latent space that decodes to few θ), the trial fails with a LatentuneError that
    says so and what to do, and ``study.optimize`` stops, rather than run one θ twice (the
    phase run stores such a θ from its trial instead, ``info["same_as"]``; an Optuna trial
    cannot be given a stored value).

    Raises :class:`~latentune.errors.LatentError` / ``StoreError`` for a source run without
    a latent space or parameter space.
    """

    def __init__(self, source_run: str | os.PathLike, seed: int = 0, *,
                 strategy: str = "transfer", method: str = "turbo", budget: int = 200,
                 regions: int | None = None, start: str | None = "manual",
                 zero_shot: bool = True, max_fall_prob: float | None = None,
                 transfer_options: dict[str, Any] | None = None,
                 constraints_func: Callable | None = None,
                 independent_sampler: Any = None) -> None:
        from latentune.pipeline.loop import STRATEGIES
        from latentune.pipeline.manifest import transfer_option
        from latentune.study import Study, source_best

        if strategy not in STRATEGIES:
            raise UsageError(f"strategy must be one of {', '.join(STRATEGIES)}, got {strategy!r}")
        if strategy == "transfer" and (method != "turbo" or regions is not None or
                                       start != "manual"):
            raise UsageError("method, regions and start are options of strategy='plain'")
        self.strategy = strategy
        self.transfer_options: dict[str, Any] | None = transfer_option(
            transfer_options, strategy, max_fall_prob)["transfer_options"]

        src = Path(source_run)
        if not (src / "run.db").is_file():
            raise StoreError(f"LatentSampler: no latentune run in {src} (expected run.db)")
        with Study(src) as s:
            space = s.space()
            latent = s.latent()
            trained_on = s.store.count(Phase.PHASE1)
        if space is None:
            raise StoreError(f"LatentSampler: {src} records no parameter space")
        if latent is None and not trained_on:
            raise LatentError(f"LatentSampler: no latent space in {src} and no phase-1 trial to "
                              "train one on: run phase 1 there first (Study.phase1, or an "
                              "Optuna study's trials through latentune import-optuna), then "
                              "train one (Study.train_latent or latentune train-vae)")
        if latent is None:
            raise LatentError(f"LatentSampler: no latent space in {src}: train one first "
                              "(Study.train_latent or latentune train-vae)")
        names = latent.meta.get("space_names")
        if latent.d != space.dim or (names is not None and list(names) != list(space.names)):
            raise LatentError(f"LatentSampler: the latent space of {src} does not map to its "
                              "parameter space")
        if start not in ("manual", "best", None):
            raise UsageError(f"start must be 'manual', 'best' or None, got {start!r}")
        self.source_run = src.resolve()
        self._source_checked = False        # the source run is the one the study pinned
        self._latent_checked: set[tuple[int, int]] = set()   # (storage, study) checked
        self._space = space
        self.latent = latent
        best = source_best(src)
        self._zero_shot_theta = None if best is None or not zero_shot else best.theta.copy()
        self.start = start
        self._init_common(seed, budget, regions, method, max_fall_prob, constraints_func,
                          independent_sampler)
        self._latent_print = latent.fingerprint()
        self._key = (f"latent:{self._latent_print}:{strategy}:{method}:"
                     f"regions={self.regions if strategy == 'plain' else None}:"
                     f"{max_fall_prob}:{start}" + ("" if self.transfer_options is None else
                                                   ":" + json.dumps(self.transfer_options,
                                                                    sort_keys=True)))
        self._x0: np.ndarray | None = None
        if start == "manual":
            self._x0 = latent.to_unit(latent.encode(space.manual))
        elif start == "best" and best is not None:
            self._x0 = latent.to_unit(latent.encode(best.theta))
        self._prior = _latent_prior(self.source_run, latent) if max_fall_prob else None

    def _critic(self, study: Any) -> tuple[Any, Callable | None]:
        self._check_latent(study)
        return _phase3_critic(self.source_run, self.latent, self._space,
                              strategy=self.strategy, method=self.method,
                              batch_size=self.batch_size, seed=self.seed, x0=self._x0,
                              budget=self.budget, regions=self.regions,
                              max_fall_prob=self.max_fall_prob, prior=self._prior,
                              transfer_options=self.transfer_options,
                              source_counts=self._source_counts(study))

    def _check_latent(self, study: Any) -> None:
        """Pin the sampler's latent space in ``study`` (:data:`LATENT_ATTR`) at its first
        sample, or check it against the pinned one (once per sampler and study): LatentError
        (one line) when it is another (the source's latent space trained again since, or
        another run's). The study's trials were sampled in the pinned one and the study holds
        no copy of it, so it cannot go on with it; the same latent space from a moved source
        goes on (its new place recorded)."""
        sid = (id(study._storage), int(study._study_id))
        if sid in self._latent_checked:
            return
        now = {"fingerprint": self._latent_print, "source_run": str(self.source_run)}
        pinned = study._storage.get_study_system_attrs(study._study_id).get(LATENT_ATTR) \
            or _first_latent(study)
        if pinned is not None and pinned.get("fingerprint") != now["fingerprint"]:
            was = pinned.get("source_run")
            if was in (None, now["source_run"]):
                why = (f"{self.source_run} holds another latent space than the one the study "
                       "began with (retrained since?)")
            else:
                why = (f"the study began with the latent space of {was}, and {self.source_run} "
                       "holds another")
            raise LatentError(f"LatentSampler: {why}: the study's trials were sampled in that "
                              "one; give the run directory that holds it (source_run), or "
                              "start a new study")
        if pinned != now:
            study._storage.set_study_system_attr(study._study_id, LATENT_ATTR, now)
        self._latent_checked.add(sid)

    def _source_counts(self, study: Any) -> dict[str, int] | None:
        """The source trials the study searches from (:data:`SOURCE_ATTR`), pinned at its
        first sample with their fingerprint (:data:`SOURCE_PRINT_ATTR`); None for the plain
        strategy. LatentError (one line) when the source run holds other trials than those
        now (replaced or cut since), a warning when some of them were amended since
        (:func:`~latentune.pipeline.loop.source_mismatch`; once per amendment,
        :data:`AMENDED_ATTR`): checked once per sampler, not at
        the study's first sample, which pins them (one read of the source's trials)."""
        from latentune.pipeline.loop import source_mismatch
        from latentune.pipeline.manifest import run_counts, run_fingerprint

        if self.strategy != "transfer":
            return None
        key = SOURCE_ATTR + self._key
        attrs = study._storage.get_study_system_attrs(study._study_id)
        pinned = self._study_attr(study, SOURCE_ATTR, attrs)
        printed = None if pinned is None else self._study_attr(study, SOURCE_PRINT_ATTR, attrs)
        if pinned is None:          # pinned now: the trials it holds, nothing to check
            pinned = run_counts(self.source_run)
            printed = run_fingerprint(self.source_run, pinned)
            study._storage.set_study_system_attr(study._study_id, SOURCE_PRINT_ATTR + self._key,
                                                 printed)
            self._source_checked = True
        if attrs.get(key) != pinned:
            study._storage.set_study_system_attr(study._study_id, key, pinned)
        if not self._source_checked:
            seen = AMENDED_ATTR + self._key

            def record(latest: int) -> None:
                study._storage.set_study_system_attr(study._study_id, seen, int(latest))
            why = source_mismatch(self.source_run, pinned, printed, "the study",
                                  "the source run's latent space",
                                  reported=int(attrs.get(seen) or 0), record=record)
            if why is not None:
                raise LatentError(f"LatentSampler: the source run at {self.source_run} is not "
                                  f"the run the study began with: it {why} (replaced since?); "
                                  "give the directory that holds that run (source_run)")
            self._source_checked = True
        return pinned

    def fall_budget(self, study: Any) -> dict[str, Any] | None:
        """The study's fall budget (``transfer_options={"fall_budget": q}``):
        ``{falls_allowed, falls, counts, spent, not_run}`` over its finished trials in number
        order (the zero-shot one included; ``falls`` as ``fall_budget_counts`` counts them,
        ``spent`` as the critic decides it; ``not_run``: once spent, the trials queued in the
        study (WAITING, ``enqueue_trial``) that its stop leaves unrun, else 0), as
        ``Study.status()["fall_budget"]``; None without one."""
        fb = self._fall_budget_of(self._finished_fell(study))
        if fb is not None:
            waiting = optuna.trial.TrialState.WAITING
            fb["not_run"] = sum(t.state == waiting for t in study.get_trials(
                deepcopy=False)) if fb["spent"] else 0
        return fb

    def _fall_budget_of(self, fell: list[bool]) -> dict[str, Any] | None:
        from latentune.critic.transfer import TRANSFER_DEFAULTS, fall_budget_status

        if self.strategy != "transfer":
            return None
        opts = {**TRANSFER_DEFAULTS, **(self.transfer_options or {})}
        return fall_budget_status(fell, opts["fall_budget"], self.budget,
                                  opts["fall_budget_counts"])

    def _finished_fell(self, study: Any, extra: tuple[int, bool] | None = None) -> list[bool]:
        """Fall flags of the trials the critic is told (finished, θ in the box), in number
        order; ``extra`` = (number, fell) of a trial being finished now."""
        _, _, _, fell, _ = self._history(study.get_trials(deepcopy=False), 1.0, -1, True,
                                         self._space.dim, extra=extra)
        return fell

    def _after_fall_budget(self, study: Any, trial: Any, state: Any,
                           values: Sequence[float] | None) -> None:
        if self.transfer_options is None or not self.transfer_options.get("fall_budget"):
            return
        now = study._storage.get_trial(trial._trial_id)         # constraints set just now
        fb = self._fall_budget_of(self._finished_fell(study, (trial.number,
                                                              _sampled_fell(now, state,
                                                                            values))))
        if fb is None or not fb["spent"]:
            return
        logger.warning("trial %d: the fall budget is spent (%d falls counted, %d allowed); "
                       "the study stops here", trial.number, fb["falls"], fb["falls_allowed"])
        if study._thread_local.in_optimize_loop:
            study.stop()

    def _external_point(self, theta: np.ndarray) -> np.ndarray | None:
        code = np.asarray(self.latent.encode(theta), dtype=float)
        box = self.latent.box
        if np.any(code < box[:, 0]) or np.any(code > box[:, 1]):
            return None
        return self.latent.to_unit(code)

    def _fixed_theta(self, study: Any, trial: Any) -> np.ndarray | None:
        """A θ decided without the critic while the zero-shot trial is still to come (every
        trial before ``trial`` enqueued, none of them at the zero-shot θ):

        * the zero-shot θ for the first trial the sampler chooses in full (no enqueued values,
          ``fixed_params``; Optuna runs enqueued trials first, as given);
        * the source space's manual θ for a partly enqueued trial: its values not enqueued
          are the manual θ's. The critic, told nothing yet, would give its first point, which
          can be the zero-shot θ the next trial runs (all but the enqueued values again).

        None for any other trial (a partly enqueued one after the zero-shot trial gets the
        critic's values), and when an enqueued trial already ran the zero-shot θ."""
        if self._zero_shot_theta is None:
            return None
        before = [t for t in study.get_trials(deepcopy=False) if t.number < trial.number]
        if any(not t.system_attrs.get("fixed_params") for t in before):
            return None
        key = _key_of(self._zero_shot_theta)
        ran = [t.number for t in before if (u := _unit_of(self._space, t.params)) is not None
               and _key_of(u) == key]
        if ran:
            logger.info("trial %d: enqueued trial %d ran the zero-shot θ already; asking the "
                        "critic", trial.number, ran[0])
            return None
        fixed = trial.system_attrs.get("fixed_params")
        if fixed:
            logger.info("trial %d: partly enqueued before the zero-shot trial: its other "
                        "parameters are the source's manual θ", trial.number)
            return np.clip(np.asarray(self._space.manual, dtype=float), 0.0, 1.0)
        study._storage.set_trial_system_attr(trial._trial_id, ZERO_SHOT_ATTR, True)
        return self._zero_shot_theta

def _first_latent(study: Any) -> dict[str, Any] | None:
    """The latent space a study sampled before :data:`LATENT_ATTR` existed was pinned to:
    ``{"fingerprint", "source_run": None}`` from the key of its first trial a LatentSampler
    sampled (:data:`POINT_ATTR`), else None."""
    for t in sorted(study.get_trials(deepcopy=False), key=lambda t: t.number):
        key = (t.system_attrs.get(POINT_ATTR) or {}).get("key")
        if isinstance(key, str) and key.startswith("latent:"):
            return {"fingerprint": key.split(":")[1], "source_run": None}
    return None


class TurboSampler(_CriticSampler, BaseSampler):
    """latentune's TuRBO-m (phase 1) as an Optuna sampler on the θ box of a search space.

    ``TurboSampler(search_space, seed=0, *, budget=200, regions=None, start=None,
    max_fall_prob=None, constraints_func=None, independent_sampler=None)``

    Args:
        search_space: ``{name: FloatDistribution(low, high, log=...)}`` (no ``step``; int,
            stepped and categorical distributions are refused) or a latentune
            :class:`~latentune.space.ParameterSpace`.
        seed: the critic's seed.
        budget: the trials you plan (sets the number of trust regions unless ``regions``); a
            trial past it is sampled all the same, with one ``UserWarning`` per study.
        start: None (TuRBO-m's initial design), ``"manual"`` (a ParameterSpace's manual θ)
            or ``{name: physical value}``: the first point.
        max_fall_prob, constraints_func, independent_sampler: as in :class:`LatentSampler`
            (without a prior: the fall prediction learns from the study's falls).
    """

    def __init__(self, search_space: Mapping[str, Any] | ParameterSpace, seed: int = 0, *,
                 budget: int = 200, regions: int | None = None, start: Any = None,
                 max_fall_prob: float | None = None,
                 constraints_func: Callable | None = None,
                 independent_sampler: Any = None) -> None:
        if isinstance(search_space, ParameterSpace):
            space = search_space
        elif isinstance(search_space, Mapping):
            try:
                space = space_from_distributions(search_space)
            except OptunaImportError as exc:
                raise UsageError(f"TurboSampler: {exc}") from None
        else:
            raise UsageError("TurboSampler: search_space must be a dict of "
                             "FloatDistribution by name or a latentune ParameterSpace")
        self._space = space
        if start is None:
            x0 = None
        elif isinstance(start, str) and start == "manual":
            if not isinstance(search_space, ParameterSpace):
                raise UsageError("TurboSampler: start='manual' needs a ParameterSpace")
            x0 = space.manual
        elif isinstance(start, Mapping):
            from latentune.errors import ParamsError

            try:
                x0 = space.parse(dict(start))
            except ParamsError as exc:
                raise UsageError(f"TurboSampler start: {exc}") from None
        else:
            raise UsageError("TurboSampler: start must be None, 'manual' or a dict of "
                             "physical values by name")
        self._x0 = x0
        self._init_common(seed, budget, regions, "turbo", max_fall_prob, constraints_func,
                          independent_sampler)
        self._key = (f"theta:{_space_hash(space)}:turbo:regions={self.regions}:{max_fall_prob}:"
                     f"{None if x0 is None else _hash(np.asarray(x0).tobytes())}")

    def _critic(self, study: Any) -> tuple[Any, Callable | None]:
        from latentune.pipeline.phases import make_phase_critic

        return make_phase_critic("turbo", self._space.dim, self.batch_size, self.seed,
                                 self._x0, self.budget, self.regions,
                                 self.max_fall_prob, None), None

    def _external_point(self, theta: np.ndarray) -> np.ndarray | None:
        return theta


def _hash(b: bytes) -> str:
    return hashlib.sha1(b).hexdigest()[:12]


def _space_hash(space: ParameterSpace) -> str:
    import json

    d = space.to_dict()
    d.pop("manual", None)
    return _hash(json.dumps(d, sort_keys=True).encode())


def _latent_prior(run: Path, latent: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """The fall-aware option's prior: :func:`latentune.pipeline.loop.latent_prior`."""
    from latentune.pipeline.loop import latent_prior

    return latent_prior(run, latent)


# ---------------------------------------------------------------------------- storages and import
def open_storage(storage: Any) -> Any:
    """An Optuna storage from: a storage object (returned as is), an RDB URL
    (``sqlite:///file.db``, ``postgresql://…``), a path to an SQLite file, or a path to a
    journal file (``JournalStorage(JournalFileBackend(path))``). OptunaImportError for a path,
    or the file of an ``sqlite:`` URL, that does not exist (RDBStorage would create it)."""
    if isinstance(storage, optuna.storages.BaseStorage):
        return storage
    if not isinstance(storage, (str, os.PathLike)):
        raise OptunaImportError(f"storage must be an Optuna storage, an RDB URL or a file path, "
                                f"got {type(storage).__name__}")
    s = os.fspath(storage)
    if "://" in s:
        db = _sqlite_file(s)
        if db is not None and not Path(db).is_file():   # RDBStorage would create an empty one
            raise OptunaImportError(f"storage file not found: {db} (of {s})")
        try:
            return optuna.storages.RDBStorage(s)
        except Exception as exc:  # noqa: BLE001 - SQLAlchemy errors of any kind: one line
            raise OptunaImportError(f"cannot open storage {s}: "
                                    f"{' '.join(str(exc).split())[:200]}") from None
    p = Path(s)
    if not p.is_file():
        raise OptunaImportError(f"storage file not found: {p}")
    with open(p, "rb") as f:
        head = f.read(16)
    if head == b"SQLite format 3\x00":
        return open_storage(f"sqlite:///{p.resolve()}")
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    try:
        return JournalStorage(JournalFileBackend(str(p)))
    except Exception as exc:  # noqa: BLE001
        raise OptunaImportError(f"{p} is neither an SQLite nor an Optuna journal file "
                                f"({' '.join(str(exc).split())[:200]})") from None


def _sqlite_file(url: str) -> str | None:
    """The database file of an ``sqlite:`` URL, else None (another database, or in memory)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        u = make_url(url)
    except ArgumentError:
        return None                                     # RDBStorage says what is wrong
    if u.get_backend_name() != "sqlite" or u.database in (None, "", ":memory:") or \
            "uri" in u.query:                           # a file: URI says its own mode
        return None
    return u.database


def _load_study(storage: Any, study_name: str | None) -> Any:
    st = open_storage(storage)
    names = [s.study_name for s in st.get_all_studies()]
    if study_name is None:
        if len(names) != 1:
            raise OptunaImportError(f"the storage holds {len(names)} studies "
                                    f"({', '.join(names[:5]) or 'none'}); name one")
        study_name = names[0]
    if study_name not in names:
        raise OptunaImportError(f"no study {study_name!r} in the storage (it holds: "
                                f"{', '.join(names[:8]) or 'none'})")
    return optuna.load_study(study_name=study_name, storage=st)


def _unfinished(study: Any) -> str:
    """``none``, or how many trials ``study`` holds with their states (``2 (1 pruned, 1
    running)``): what an import finds when no trial finished."""
    from collections import Counter

    states = Counter(t.state.name.lower() for t in study.get_trials(deepcopy=False))
    if not states:
        return "none"
    return f"{sum(states.values())} ({', '.join(f'{n} {k}' for k, n in sorted(states.items()))})"


def _import_difference(old: dict[str, Any], new: dict[str, Any]) -> str:
    """What differs between the ``system`` record of a run (``old``) and that of an import of a
    study into it (``new``): the study, its direction, or the first parameter whose bounds or
    scale differ (the study's trials now span other bounds: an import of them would move the
    stored trials' θ), in one phrase."""
    if old.get("kind") != "optuna":
        return "a run of another system, not an import of an Optuna study"
    if old.get("study_name") != new["study_name"]:
        return f"an import of study {old.get('study_name')!r}, not of {new['study_name']!r}"
    if old.get("direction") != new["direction"]:
        return (f"an import of a {old.get('direction')} study {new['study_name']!r}; the study "
                f"is now {new['direction']}")
    diff = ParameterSpace.from_dict(new["space"]).box_difference(old.get("space") or {})
    if diff is not None:
        return (f"an import of study {new['study_name']!r} with another space ({diff}; there: "
                "the run, here: the study's trials now); import it into a new directory")
    return f"an import of study {new['study_name']!r} with another space"


def import_optuna_study(storage: Any, study_name: str | None, out: str | os.PathLike,
                        space: ParameterSpace | None = None, *, seed: int | None = None) -> Any:
    """Turn an Optuna study into a latentune phase-1 run in ``out``; return its
    :class:`~latentune.study.Study`.

    Args:
        storage: an Optuna storage object, RDB URL, SQLite file or journal file path.
        study_name: the study (None: the storage's only study).
        out: the run directory (created; importing again adds the trials not imported yet).
        space: the parameter space to use (its names: float parameters of the study; the
            trials' other parameters are left out, with a warning; values outside it are
            refused); default: built from the trials' distributions (every parameter).
        seed: the run's seed (recorded; used by ``train_latent`` and later phases); None: the
            seed stored in ``out``, else 0.

    The rules (distributions, direction, falls, left-out trials) are in the module docstring.
    Raises :class:`OptunaImportError` with one line for a study that cannot be imported,
    ``StoreError`` when ``out`` holds another run.
    """
    from latentune.pipeline.phases import store_outcome
    from latentune.study import Study
    from latentune.system import Outcome

    S = optuna.trial.TrialState
    study = _load_study(storage, study_name)
    if len(study.directions) != 1:
        raise OptunaImportError(f"study {study.study_name!r} has {len(study.directions)} "
                                "objectives: latentune imports single-objective studies only")
    sign = _sign(study)
    trials = sorted(study.get_trials(deepcopy=False, states=(S.COMPLETE, S.FAIL)),
                    key=lambda t: t.number)
    n_left = len(study.get_trials(deepcopy=False)) - len(trials)
    if not trials:
        raise OptunaImportError(f"study {study.study_name!r} has no finished trial (COMPLETE or "
                                f"FAIL) to import: it holds {_unfinished(study)}")
    named = None if space is None else set(space.names)
    dists: dict[str, Any] = {}
    for t in trials:
        for n, d in t.distributions.items():
            if named is not None and n not in named:
                continue                # outside the given space: left out (a warning)
            if n not in dists:
                dists[n] = d
                continue
            old = dists[n]
            if type(old) is not type(d) or getattr(old, "log", None) != getattr(d, "log", None):
                raise OptunaImportError(f"parameter {n!r} changes its distribution across trials "
                                        f"({old} and {d})")
            if isinstance(d, optuna.distributions.FloatDistribution) and d.step is None \
                    and old.step is None:
                dists[n] = optuna.distributions.FloatDistribution(
                    min(old.low, d.low), max(old.high, d.high), log=d.log)
    if space is None:
        try:
            sp = space_from_distributions(dists)
        except OptunaImportError as exc:
            raise OptunaImportError(f"{exc}; or import the float parameters only, naming them "
                                    "in space= (--space FILE)") from None
    else:
        sp = space
        if set(space.names) != set(dists):
            raise OptunaImportError("the given space names parameter(s) the study's finished "
                                    "trials do not have: "
                                    f"{', '.join(sorted(set(space.names) - set(dists))[:5])}")
        space_from_distributions(dists)     # the refusal rules apply to the named parameters
    rows: list[tuple[Any, np.ndarray, float]] = []
    incomplete = 0
    for t in trials:
        if not set(sp.names) <= set(t.params):
            incomplete += 1
            continue
        u = _unit_of(sp, t.params)
        if u is None:
            out = [f"{n} = {float(t.params[n]):g} outside [{lo:g}, {hi:g}]"
                   for n, lo, hi in zip(sp.names, sp.lower, sp.upper)
                   if not lo <= float(t.params[n]) <= hi]
            raise OptunaImportError(f"trial {t.number}: {'; '.join(out[:3]) or 'a parameter'}"
                                    f"{' …' if len(out) > 3 else ''} (of the given space)")
        rows.append((t, u, trial_cost(t, sign)))
    if incomplete:
        warnings.warn(f"import of {study.study_name!r}: {incomplete} finished trial(s) lack some "
                      "of the parameters and are left out", stacklevel=2)
    if not rows:
        raise OptunaImportError(f"study {study.study_name!r} has no finished trial with every "
                                "parameter")
    others: dict[str, set[str]] = {}          # parameters outside the given space: their values
    for t, _, _ in rows:
        for n in set(t.params) - set(sp.names):
            others.setdefault(n, set()).add(repr(t.params[n]))
    if others:
        varied = sorted(n for n, v in others.items() if len(v) > 1)
        same = sorted(n for n, v in others.items() if len(v) == 1)
        warnings.warn(f"import of {study.study_name!r}: {', '.join(sorted(others))} left out "
                      "(not in the given space)"
                      + (f"; the values of {', '.join(varied)} varied across the imported "
                         "trials, so their costs depend on them too" if varied else "")
                      + (f"; {', '.join(same)} held one value" if same else ""), stacklevel=2)
    out = Path(out)
    lt_study = Study(out, seed=seed)
    seed = int(lt_study.seed)
    system = {"kind": "optuna", "study_name": study.study_name,
              "storage": _storage_label(storage), "direction": "maximize" if sign < 0 else "minimize",
              "space": sp.to_dict()}
    with lt_study.writing() as st:
        cfg = st.get_meta("config") or {}
        if cfg.get("system") is not None:
            old = {k: v for k, v in cfg["system"].items() if k != "storage"}
            new = {k: v for k, v in system.items() if k != "storage"}
            if old != new:
                raise StoreError(f"{out} holds another run: {_import_difference(old, new)}")
        done = {r.info.get("optuna_trial") for r in st.rows(Phase.PHASE1)}
        idx = st.next_idx(Phase.PHASE1)
        added = 0
        no_cost = []                        # added trials that stood with a value of no cost
        for t, u, cost in rows:
            if t.number in done:
                continue
            if t.values and math.isinf(cost) and not trial_fell(t):
                no_cost.append(t.number)
            info = {"optuna_trial": int(t.number), "optuna_state": t.state.name,
                    "optuna_value": None if not t.values else float(t.values[0]),
                    "constraints": {k: float(v) for k, v in t.constraints.items()}}
            wall = None
            if t.datetime_start is not None and t.datetime_complete is not None:
                wall = (t.datetime_complete - t.datetime_start).total_seconds()
            store_outcome(st, Phase.PHASE1, idx, u,
                          Outcome(cost, _sampled_fell(t), info, wall), tag=-1, seed=seed)
            idx += 1
            added += 1
        cfg = st.get_meta("config") or {}
        cfg.setdefault("seed", seed)
        cfg.update(system=system, space=sp.to_dict(),
                   phase1={"method": "optuna", "seed": int(seed), "budget": st.count(Phase.PHASE1),
                           "batch_size": None, "regions": None,
                           "import": {"left_out_unfinished": n_left,
                                      "left_out_incomplete": incomplete,
                                      "left_out_params": sorted(others),
                                      "rules": "float -> ParameterSpace; int/step/categorical "
                                               "refused; maximize negated; FAIL and constraint "
                                               "> 0 are falls; pruned/running/waiting left out"}})
        st.set_meta("config", cfg)
        best = st.best(Phase.PHASE1)
        if best is not None:
            path = out / "phase1_best.json"
            import json

            from latentune.atomicfile import write_atomic

            write_atomic(path, json.dumps(sp.as_dict(best.theta), indent=1))
            st.add_artifact("phase1_best", path)
    if no_cost:
        warnings.warn(f"import of {study.study_name!r}: trial(s) {', '.join(map(str, no_cost[:5]))}"
                      f"{' …' if len(no_cost) > 5 else ''} stood with a value that is no cost "
                      f"(not finite, or {COST_LIMIT:g} in size or more): imported as falls of "
                      "cost +inf, as latentune's samplers tell them", stacklevel=2)
    logger.info("imported %d trial(s) of %s into %s (%d left out: pruned/running/waiting; "
                "%d lack parameters)", added, study.study_name, out, n_left, incomplete)
    return lt_study


def _storage_label(storage: Any) -> str:
    if isinstance(storage, (str, os.PathLike)):
        s = os.fspath(storage)
        if "://" in s and "@" in s:                     # never record a password
            scheme, rest = s.split("://", 1)
            return f"{scheme}://…@{rest.split('@', 1)[1]}"
        return s
    return type(storage).__name__


__all__ = ["LatentSampler", "TurboSampler", "import_optuna_study", "open_storage",
           "space_from_distributions", "distributions_of", "physical_params", "trial_fell",
           "trial_cost", "OptunaImportError", "FAILED_ATTR", "POINT_ATTR"]
