"""What a study's trials say: the best trial, a status for the person at the robot, trials as
data, and the θ to deploy.

Phases are named as a person reads them (:data:`PHASE_NAMES`): "manual", "phase 1", "phase 3",
"zero-shot" (the source study's best θ as it is, run before phase 3 on another study's latent
space) and "preservation". A trial's θ is given by name in physical units (the study's
:class:`~latentune.space.ParameterSpace`). The best trial is the lowest cost among the trials of
the manual θ, phases 1 and 3 and zero-shot that did not fail; a failed θ is never "best".
"""
from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.constants import PHASE_NAMES, Phase, phase_name
from latentune.checks import is_whole
from latentune.errors import StoreError, UsageError
from latentune.pipeline.manifest import config_space, stored_system, tuned_for
from latentune.pipeline.store import Row, RunStore
from latentune.space import TUNED_FOR, ParameterSpace
from latentune.wording import counted

TUNING = (Phase.MANUAL, Phase.PHASE1, Phase.PHASE3, Phase.ZERO_SHOT)
"""The phases whose trials may give the θ to deploy."""
BUDGET_KEYS = {Phase.PHASE1: "phase1", Phase.PHASE3: "phase3"}
"""The phases with a budget of trials, and the key of their options record in the config."""
BEST_FILE = "best.json"
"""The θ to deploy (physical values by name): ``DIR/best.json``."""


@dataclass
class TrialRecord:
    """One stored trial as data.

    Attributes:
        phase: its phase by name ("phase 1", "zero-shot", ...); ``idx``: its row in the phase.
        params: θ by name in physical units; ``theta``: (d,) the normalized θ.
        cost, failed, info: what the trial gave; ``trial``: its suggestion id (ask/tell), or
        None for a trial a phase ran itself; ``z``: its latent code (phase 3), or None.
    """

    phase: str
    idx: int
    params: dict[str, float]
    cost: float
    failed: bool
    info: dict[str, Any] = field(default_factory=dict)
    trial: int | None = None
    theta: np.ndarray | None = None
    z: np.ndarray | None = None
    created: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (θ and z as lists)."""
        return {"phase": self.phase, "idx": self.idx, "trial": self.trial, "cost": self.cost,
                "failed": self.failed, "params": self.params, "info": self.info,
                "theta": None if self.theta is None else self.theta.tolist(),
                "z": None if self.z is None else self.z.tolist(), "created": self.created}


def _trial_id(r: Row) -> int | None:
    t = r.info.get("trial")
    return int(t) if isinstance(t, (int, np.integer)) else None


def phases_arg(phases: Any) -> tuple[Phase, ...]:
    """``phases`` as the API takes it (one stored phase number, or several: 0 manual, 1, 3,
    4 zero-shot, 5 preservation) as a tuple of :class:`~latentune.constants.Phase`;
    UsageError naming anything else (``1.5``, ``"x"``, 2)."""
    many = not isinstance(phases, (int, np.integer, str, bytes)) and hasattr(phases, "__iter__")
    out = []
    for p in (phases if many else (phases,)):
        if not is_whole(p) or int(p) not in set(Phase):
            raise UsageError(f"a phase is one of {', '.join(str(int(v)) for v in Phase)} "
                             f"({', '.join(PHASE_NAMES.get(v, v.name.lower()) for v in Phase)}), "
                             f"got {p!r}")
        out.append(Phase(int(p)))
    return tuple(out)


def reused_count(rows: list[Row]) -> int:
    """How many of ``rows`` repeat the θ of a stored trial and were stored with its outcome,
    not run again (``info["reused"]``: phase 1's first row, the manual θ's trial; a plain phase
    3's decoded start or a zero-shot θ the study held a trial of). They count in the phase's
    trials and budget; their falls are that trial's."""
    return sum(1 for r in rows if r.info.get("reused"))


def best_row(store: RunStore, phases: tuple[int, ...] = TUNING) -> Row | None:
    """The stored trial of ``phases`` with the lowest cost among those that did not fail (ties:
    earlier phase, then idx); None if every one failed or there is none."""
    rows = [r for ph in phases for r in store.rows(ph) if not r.fell]
    return min(rows, key=lambda r: (r.cost, r.phase, r.idx)) if rows else None


def trials(store: RunStore, space: ParameterSpace | None,
           phases: tuple[int, ...] | None = None) -> list[TrialRecord]:
    """Every stored trial of ``phases`` (default all; see :func:`phases_arg`) in the order the
    trials were stored (:meth:`~latentune.pipeline.store.RunStore.stored_order`), a phase's
    own rows in idx order: the phases as they were made (manual, phase 1, then the zero-shot
    trial and phase 3's as they were told: a zero-shot trial told after some of phase 3's
    comes between them)."""
    wanted = None if phases is None else {int(p) for p in phases_arg(phases)}
    order = [p for p, _ in store.stored_order() if wanted is None or p in wanted]
    rows = {ph: iter(store.rows(ph)) for ph in set(order)}     # each in idx order
    out = []
    for ph in order:                # a phase's place in the order: its next row by idx
        r = next(rows[ph])
        params = space.as_dict(r.theta) if space is not None else \
            {f"theta[{i}]": float(v) for i, v in enumerate(r.theta)}
        out.append(TrialRecord(phase_name(r.phase), r.idx, params, r.cost, r.fell, dict(r.info),
                               _trial_id(r), r.theta, r.z, r.created))
    return out


def trials_dataframe(records: list[TrialRecord], space: ParameterSpace | None = None) -> Any:
    """The trials as a pandas DataFrame, one row per trial: columns phase (its name), idx
    (int), trial (the suggestion id, a nullable integer: missing for a trial a phase ran
    itself), cost (float), failed (bool), one ``params_<name>`` column per θ entry (float,
    physical units), info (a dict per row). Without records the frame is empty with the same
    columns, the ``params_<name>`` ones those of ``space`` (none when it is None). ImportError
    naming the install if pandas is absent."""
    try:
        import pandas as pd
    except ImportError:
        raise ImportError("trials_dataframe needs pandas: pip install pandas (or use "
                          "Study.trials(), a list of records)") from None
    rows = []
    for t in records:
        d = {"phase": t.phase, "idx": t.idx, "trial": t.trial, "cost": t.cost,
             "failed": t.failed}
        d.update({f"params_{k}": v for k, v in t.params.items()})
        d["info"] = t.info
        rows.append(d)
    params = [] if rows or space is None else [f"params_{k}" for k in space.names]
    df = pd.DataFrame(rows, columns=None if rows else
                      ["phase", "idx", "trial", "cost", "failed", *params, "info"])
    return df.astype({"idx": "int64", "trial": "Int64", "cost": "float64", "failed": "bool",
                      **{k: "float64" for k in params}})


def decisions(store: RunStore, phase: int = Phase.PHASE3) -> list[dict[str, Any]]:
    """The decisions the critic of ``phase`` recorded with its state, one per ask in generation
    order (the transfer phase 3: :meth:`~latentune.critic.transfer.Transfer.state_dict`); [] for
    a critic that records none."""
    from latentune.pipeline.phases import state_key

    state = store.get_meta(state_key(phase)) or {}
    got = state.get("decisions") if isinstance(state, dict) else None
    return [d for d in got if isinstance(d, dict)] if isinstance(got, list) else []


def decision_kind(d: dict[str, Any]) -> str:
    """What an ask was, from its decision ``d``: ``"design"`` (the source's elite θ),
    ``"explore (lines)"`` / ``"explore (latent)"`` / … (an explore ask and its pool;
    ``"explore (lines, target GP)"`` when the target's own GP chose it, ``explore_gp``;
    ``"explore (escape)"``: far from every told trial while all fell, ``escape_falls``),
    ``"manual θ"``, ``"converged"`` or ``"record walk"`` (a rule's ask; the last, a θ deeper
    in the source's record after its top fell, ``record_walk``), ``"record CMA-ES"`` (a draw
    of the screened CMA-ES the asks go to once the source's record fell, ``record_cma``), else
    ``"region"`` (the trust region, the latent box around the best θ and the elites, as the
    model chose; ``"region (target GP)"`` when the target's own GP chose, ``region_gp``)."""
    rule = str(d.get("rule") or "")
    if "walk_rank" in d:
        return "record walk"
    if "manual" in rule:
        return "manual θ"
    if "converged" in rule:
        return "converged"
    if d.get("record_cma"):
        return "record CMA-ES"
    if d.get("escape"):
        return "explore (escape)"
    if d.get("explore"):
        return f"explore ({d.get('explore_pool') or 'latent'}" + \
            (", target GP)" if d.get("explore_gp") else ")")
    if d.get("design"):
        return "design"
    return "region (target GP)" if d.get("region_gp") else "region"


def decision_scores(d: dict[str, Any]) -> str | None:
    """What the cost models of the ask with decision ``d`` fitted where ``"auto"`` scores
    chose (``auto_scores``), e.g. ``"warped values (loo ranking loss 0.041 against ranks'
    0.063)"`` for the cost model, then the explore GP's; None where nothing was chosen."""
    got = d.get("auto_scores")
    if not isinstance(got, dict):
        return None
    parts = []
    for model in ("cost", "explore"):
        c = got.get(model)
        if not (isinstance(c, list) and len(c) == 3):
            continue
        pick, loss_r, loss_w = c
        what = "warped values" if pick == "warped" else "ranks"
        who = "" if model == "cost" else "explore GP: "
        if loss_r is None:
            parts.append(f"{who}{what} (too few standing trials to choose)")
        else:
            mine, other = (loss_w, loss_r) if pick == "warped" else (loss_r, loss_w)
            parts.append(f"{who}{what} (loo ranking loss {mine:.3g} against "
                         f"{'ranks' if pick == 'warped' else 'warped values'}' {other:.3g})")
    return "; ".join(parts) or None


def decisions_summary(ds: list[dict[str, Any]]) -> dict[str, Any] | None:
    """``{n, kinds: {kind: asks}, last: {generation, kind, agreement, agreement_unmeasured (why
    the agreement is only its prior, else None), length, pools}}`` of the
    decisions ``ds`` (:func:`decisions`), with ``fit_failed``: how many asks used a model fit
    that raised (its starting hyperparameters kept) when any did, or None without any."""
    if not ds:
        return None
    kinds: dict[str, int] = {}
    for kind in map(decision_kind, ds):
        kinds[kind] = kinds.get(kind, 0) + 1
    last = ds[-1]
    return {"n": len(ds), "kinds": kinds,
            "last": {"generation": last.get("generation"), "kind": decision_kind(last),
                     "agreement": last.get("agreement"),
                     "agreement_unmeasured": last.get("agreement_unmeasured"),
                     "length": last.get("length"),
                     "pools": last.get("pools"), "scores": decision_scores(last)},
            **({"fit_failed": n_failed} if (n_failed := sum("fit_failed" in d for d in ds))
               else {})}


def fall_budget(store: RunStore, config: dict[str, Any] | None) -> dict[str, Any] | None:
    """The transfer phase 3's fall budget (``fall_budget`` > 0; its stored state's options
    win, as a resume restores them): ``{falls_allowed, falls, counts, spent, not_run}``
    (``falls``: as ``fall_budget_counts`` counts them) over the target's
    trials the critic is told (manual, zero-shot and phase 3) out of phase 3's budget and
    those trials; ``not_run``: once spent, the trials asked and never run, ask/tell's queued
    suggestions or the rest of the batch a phase run stopped in (its record,
    :func:`~latentune.pipeline.phases.fall_stop_key`, while no trial was stored after it);
    None for another phase 3, none yet, or no budget."""
    from latentune.critic.transfer import TRANSFER_DEFAULTS, fall_budget_status, stored_options
    from latentune.pipeline.loop import target_budget, told_outside
    from latentune.pipeline.phases import fall_stop_key, state_key

    pc = (config or {}).get("phase3") or {}
    if pc.get("strategy") != "transfer":
        return None
    state = store.get_meta(state_key(Phase.PHASE3))
    opts = (stored_options(state) if isinstance(state, dict) else None) or \
        {**TRANSFER_DEFAULTS, **(pc.get("transfer_options") or {})}
    rows = told_outside(store)
    fell = np.array([bool(r.fell) for r in rows + store.rows(Phase.PHASE3)], dtype=bool)
    fb = fall_budget_status(fell, opts["fall_budget"], target_budget(pc, len(rows)),
                            opts["fall_budget_counts"])
    if fb is not None:
        stop = store.get_meta(fall_stop_key(Phase.PHASE3)) or {}
        queued = sum(1 for t in store.trials() if t.status == "queued"
                     and t.phase in (Phase.ZERO_SHOT, Phase.PHASE3))
        ran = stop.get("n") == store.count(Phase.PHASE3)
        fb["not_run"] = (queued + (int(stop.get("not_run", 0)) if ran else 0)) \
            if fb["spent"] else 0
    return fb


def status(store: RunStore, run_dir: Path, config: dict[str, Any] | None = None
           ) -> dict[str, Any]:
    """The status of a study for the person at the robot (JSON-able).

    ``phases``: by name, each ``{n, budget, failed, pending, reused, best, best_idx,
    best_trial}`` (told trials; the phase's budget of trials, phases 1 and 3, from the study's
    ``config``, else None; how many failed; suggestions handed out and not told; how many of
    the trials repeat a stored trial's θ and were stored with its outcome, not run again,
    :func:`reused_count`; the best cost that did not fail, its row and suggestion id);
    ``pending``: the ids handed out and not told, with ``leases`` (id → asker, seconds left);
    ``queued``: asked from the critic, not handed out; ``told``: suggestions told;
    ``amended``: corrections; ``best``: the best trial over all phases (zero-shot included)
    with ``phase``, ``idx``, ``trial``, ``cost``, ``params_file`` (``DIR/best.json`` when it
    holds this trial's θ, :func:`holds_theta`, else None) and ``params_stale``
    (``DIR/best.json`` holds another θ: a run stopped before writing its best, e.g. by
    Ctrl-C) -- or None; ``decisions``: the phase-3 critic's decisions so far
    (:func:`decisions_summary`), or None; ``fall_budget``: phase 3's (:func:`fall_budget`,
    from the study's ``config``), or None."""
    out: dict[str, Any] = {"dir": str(run_dir), "phases": {}}
    all_trials = store.trials()
    now = time.time()
    pending = [t for t in all_trials if t.status == "pending"]
    for ph in sorted(Phase, key=lambda p: (p == Phase.PHASE3, p)):   # the order they run in
        rows = store.rows(ph)
        n_pending = sum(1 for t in pending if t.phase == ph)
        if not rows and not n_pending:
            continue
        ok = [r for r in rows if not r.fell]
        b = min(ok, key=lambda r: (r.cost, r.idx)) if ok else None
        budget = ((config or {}).get(BUDGET_KEYS.get(ph, "")) or {}).get("budget")
        out["phases"][phase_name(ph)] = {
            "n": len(rows), "budget": None if budget is None else int(budget),
            "failed": sum(r.fell for r in rows), "pending": n_pending,
            "reused": reused_count(rows),
            "best": None if b is None else b.cost, "best_idx": None if b is None else b.idx,
            "best_trial": None if b is None else _trial_id(b)}
    out["pending"] = [t.id for t in pending]
    out["leases"] = {str(t.id): {"asker": t.asker, "phase": phase_name(t.phase),
                                 "seconds_left": None if t.lease_until is None
                                 else max(0.0, round(t.lease_until - now, 1))}
                     for t in pending}
    out["queued"] = sum(1 for t in all_trials if t.status == "queued")
    out["told"] = sum(1 for t in all_trials if t.status == "told")
    out["amended"] = len(store.amendments())
    out["decisions"] = decisions_summary(decisions(store))
    out["fall_budget"] = fall_budget(store, config)
    b = best_row(store)
    f = run_dir / BEST_FILE
    holds = None if b is None else holds_theta(f, b.theta, config_space(config or {}))
    out["best"] = None if b is None else {
        "phase": phase_name(b.phase), "idx": b.idx, "trial": _trial_id(b), "cost": b.cost,
        "params_file": str(f) if holds else None, "params_stale": holds is False}
    return out


def holds_theta(path: Path, theta: np.ndarray, space: ParameterSpace | None) -> bool | None:
    """Whether the θ file ``path`` holds the (d,) unit-box ``theta`` (its values by name, as
    :func:`write_best` writes them): None when there is no such file or no ``space`` to name
    θ by, False for a file of another θ (e.g. ``best.json`` of an earlier best, left by a run
    stopped before it wrote its own)."""
    if space is None or not path.is_file():
        return None
    try:
        got = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    want = space.as_dict(theta)
    return isinstance(got, dict) and all(got.get(k) == v for k, v in want.items())


def write_best(store: RunStore, run_dir: Path, space: ParameterSpace | None,
               phase: int | None = None) -> Path | None:
    """Write the θ to deploy as ``--params`` files (physical values by name): the best trial of
    ``phase`` that did not fail as ``DIR/phase<p>_best.json`` (when ``phase`` is given), and
    the best over all phases as ``DIR/best.json``. A phase whose trials all failed gets no
    file (a stale one is removed, and so is ``best.json`` when no trial of any phase stands).
    Each file records what its θ was tuned for (:func:`study_tuned_for`). Returns the path of
    ``best.json``, or None."""
    if space is None:
        return None
    record = study_tuned_for(store)
    if phase is not None:
        path = run_dir / f"phase{int(phase)}_best.json"
        b = best_row(store, (int(phase),))
        if b is None:
            path.unlink(missing_ok=True)
            store.forget_artifact(f"phase{int(phase)}_best")
        else:
            _write_json(path, space.as_file(b.theta, record))
            store.add_artifact(f"phase{int(phase)}_best", path)
    b = best_row(store)
    path = run_dir / BEST_FILE
    if b is None:
        path.unlink(missing_ok=True)
        store.forget_artifact("best")
        return None
    _write_json(path, space.as_file(b.theta, record))
    store.add_artifact("best", path)
    return path


def best_params(store: RunStore, run_dir: Path, space: ParameterSpace | None,
                out: str | os.PathLike | None = None) -> tuple[Path, Row]:
    """Write the θ to deploy (the best trial over all phases that did not fail, physical
    values by name, and what they are tuned for: :func:`study_tuned_for`) to ``out``
    (default ``DIR/best.json``); return (path, its row).
    StoreError if no trial succeeded or the study has no parameter space (none stored yet, or
    a record without one beside stored trials)."""
    n = sum(store.count(ph) for ph in TUNING)
    if space is None:
        raise StoreError(f"{run_dir}: no parameter space stored" + (
            f", though it holds {counted(n, 'trial')} (a store of another layout?): its θ "
            "cannot be named" if n else " (no trial yet)"))
    b = best_row(store)
    if b is None:
        raise StoreError(f"{run_dir}: no θ to deploy: " + (
            ("its only trial failed" if n == 1 else f"all {n} trials failed") if n
            else "no trial is stored yet"))
    path = run_dir / BEST_FILE if out is None else _deploy_path(out, run_dir, space)
    _write_json(path, space.as_file(b.theta, study_tuned_for(store)))
    return path, b


def study_tuned_for(store: RunStore) -> dict[str, Any] | None:
    """What the θ of the study in ``store`` are tuned for (its recorded system, see
    :func:`~latentune.pipeline.manifest.tuned_for`), as its ``--params`` files record it."""
    return tuned_for(stored_system(store.get_meta("config") or {}))


def _deploy_path(out: str | os.PathLike, run_dir: Path, space: ParameterSpace) -> Path:
    """``out`` as the file for the θ to deploy; UsageError for an empty name, for a file in
    the run's directory that is not a θ file of this space (its store, summary, records):
    writing would destroy it, and for a θ file the run keeps itself (a suggestion's, a
    phase's best: :func:`_own_theta_file`): it would hold another θ than its name says."""
    from latentune.errors import UsageError

    if not str(out).strip():
        raise UsageError("the θ file to write needs a name")
    path = Path(out)
    if path.is_dir():
        raise UsageError(f"{path} is a directory: name the θ file to write "
                         f"(e.g. {path / BEST_FILE})")
    own = _own_theta_file(path, run_dir)
    if own is not None:
        raise UsageError(f"{path} is the file of {own}: write the θ elsewhere (or to "
                         f"{Path(run_dir) / BEST_FILE})")
    if path.is_file() and Path(run_dir).resolve() in path.resolve().parents:
        try:
            theta_file = set(json.loads(path.read_text())) - {TUNED_FOR} == set(space.names)
        except (OSError, UnicodeDecodeError, ValueError, TypeError):
            theta_file = False
        if not theta_file:
            raise UsageError(f"{path} is a file of the run {run_dir}, not a θ file: write the "
                             f"θ elsewhere (or to {Path(run_dir) / BEST_FILE})")
    return path


def _own_theta_file(path: Path, run_dir: Path) -> str | None:
    """What θ file of its own the run keeps at ``path`` ("suggestion 7" for
    ``DIR/suggestions/7.json``, "phase 1's best θ" for ``DIR/phase1_best.json``), or None."""
    where, run = path.resolve(), Path(run_dir).resolve()
    if where.parent == run / "suggestions" and where.suffix == ".json" and where.stem.isdigit():
        return f"suggestion {int(where.stem)}"
    m = re.fullmatch(r"phase(\d+)_best\.json", where.name)
    if where.parent == run and m:
        return f"phase {int(m[1])}'s best θ"
    return None


def _write_json(path: Path, value: Any) -> None:
    """Write ``value`` as JSON to ``path`` whole or not at all (:func:`write_atomic`);
    StoreError naming the file when it cannot be written."""
    try:
        write_atomic(path, json.dumps(value, indent=1))
    except OSError as exc:
        raise StoreError(f"cannot write {path}: {exc.strerror or exc}") from None
