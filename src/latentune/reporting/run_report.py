"""The report of one run directory (``latentune report DIR``): every number from ``DIR/run.db``.

* :func:`comparison_table`: Markdown table of the manual θ, phase 1, phase 3 and, when the store
  has phase-4 rows, the zero-shot baseline (the source run's best θ evaluated as it is).
* :func:`write_summary`: ``DIR/summary.json``.
* :func:`make_report`: ``DIR/report.md``, ``DIR/best_so_far.png`` and, when a system that can
  record rollouts is available, ``DIR/com_velocity.png`` (the stored best θ of each phase
  re-simulated with ``record=True``).

A built-in task (the stored config has ``config["task"]``) also gets the RMS velocity error
[m/s] beside each path cost; a user system's run (no ``"task"``) gets the tables and the
best-cost figure, and the CoM figure only when ``make_report`` is given the system.
"""
from __future__ import annotations

import json
import logging
import math
import shlex
import time
from pathlib import Path
from typing import Any

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.constants import Phase
from latentune.errors import StoreError
from latentune.pipeline.walltime import wall_record
from latentune.reporting.metrics import paper_row, phase_stats, rms_velocity_error
from latentune.wording import counted, option

logger = logging.getLogger(__name__)

TABLE_PHASES = (Phase.MANUAL, Phase.PHASE1, Phase.ZERO_SHOT, Phase.PHASE3)
"""The table's rows, in order; a zero-shot row appears only when the store has one."""
ASKTELL_PHASES = {Phase.PHASE1: (Phase.PHASE1,), Phase.PHASE3: (Phase.ZERO_SHOT, Phase.PHASE3)}
"""The table's phases of an ask/tell store by its ask/tell phase: ask/tell stores no separate
manual trial (the manual θ is phase 1's first suggestion; :func:`manual_rows` finds it) and
runs one phase a directory."""

METHOD_LABEL = {"turbo": "TuRBO-m", "cma": "CMA-ES", "random": "random search",
                "sobol": "Sobol search"}


def fmt(v: Any, nd: int = 3) -> str:
    """A table cell: ``–`` for None or a non-finite float, an int as it is, else ``nd`` decimals;
    a non-zero number that ``nd`` decimals would show as 0 (1e-9 was ``0.000``), or one of
    1e9 or more, in ``nd`` significant digits."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    x = float(v)
    if nd > 0 and x != 0 and not 0.5 * 10 ** -nd <= abs(x) < 1e9:
        return f"{x:.{nd}g}"
    return f"{x:.{nd}f}"


TASK_KEYS = ("robot", "gait", "terrain", "actor", "v_des", "steps", "seed")
"""The fields of a stored task record that rebuilding its Task needs."""


def task_from_config(config: dict[str, Any], where: str | Path | None = None):
    """The :class:`~latentune.task.Task` of a stored run config (``config["task"]``), or None
    for a user system's run (no ``"task"``). A record without one of :data:`TASK_KEYS` (a run
    written by another latentune version) is a StoreError naming it (and the run ``where``),
    and to report without simulating (:func:`latentune.wording.option`: ``--no-sim``,
    ``simulate=False``)."""
    if "task" not in config:
        return None
    from latentune.task import Task

    missing = [k for k in TASK_KEYS if k not in (config["task"] or {})]
    if missing:
        raise StoreError(("" if where is None else f"{where}: ") + f"its stored task has no "
                         f"{missing[0]!r} (a run written by another latentune version): it "
                         f"cannot be re-simulated; report it with {option('simulate', False)}")
    return Task.from_config(config["task"])


def phase_label(phase: int, config: dict[str, Any], trials: int | None = None) -> str:
    """The table label of a phase, naming the critic (phase 3: the strategy) of the stored
    config. A phase 3 with no options record and ``trials == 0`` (not started: its strategy is
    chosen when it starts) is labelled ``phase 3`` alone; with trials and no record (stores
    written before the record existed) it is the paper's latent TuRBO-m."""
    def method(key: str) -> str:
        m = str((config.get(key) or {}).get("method", "turbo"))
        return METHOD_LABEL.get(m, m)

    p3 = config.get("phase3") or {}
    if int(phase) == Phase.PHASE3 and not p3 and trials == 0:
        third = "phase 3"
    elif p3.get("strategy") == "transfer":
        third = "phase 3 (transfer: source model, latent and θ boxes)"
    else:
        third = f"phase 3 (latent, {method('phase3')}" + (", hand-over)" if p3.get("handover")
                                                          else ")")
    return {Phase.MANUAL: "manual tuned",
            Phase.PHASE1: f"phase 1 (θ, {method('phase1')})",
            Phase.PHASE3: third,
            Phase.ZERO_SHOT: "zero-shot (source best θ)"}.get(int(phase), f"phase {phase}")


def _steps(config: dict[str, Any]) -> int | None:
    """N_H of a built-in task's rollouts, None for a user system."""
    t = config.get("task")
    return None if not t or t.get("steps") is None else int(t["steps"])


def _where(t: dict[str, Any]) -> str:
    """A built-in task's terrain and actor, and its engine and reality when not the defaults."""
    parts = [str(t.get("terrain", "?")), str(t.get("actor", "?"))]
    if t.get("engine"):
        parts.append(str(t["engine"]))
    if t.get("reality"):
        parts.append(f"reality {t['reality'].get('name', '?')}")
    return ", ".join(parts)


def _title(config: dict[str, Any]) -> str:
    """What the run tuned: a built-in task's robot, gait and terrain; an Optuna import's study
    name; an ask/tell run's space by its name or file (``config["space_file"]``), else by its
    first names; a user system's target, class or name and arguments; else "user system"."""
    t = config.get("task")
    if t:
        return f"{t.get('robot', '?')} {t.get('gait', '?')} ({_where(t)})"
    s = config.get("system")
    kind = s.get("kind") if isinstance(s, dict) else None
    if kind == "optuna" and s.get("study_name"):
        return f"Optuna study {s['study_name']!r}"
    names = list((config.get("space") or {}).get("names") or ())
    if kind == "external" and (config.get("space_file") or names):
        what = config.get("space_file") or \
            f"of {', '.join(map(str, names[:4]))}{', …' if len(names) > 4 else ''}"
        return f"space {what} (trials run elsewhere)"
    name = next((s[k] for k in ("target", "class", "name") if s.get(k)), None) \
        if isinstance(s, dict) else s
    args = (s.get("args") or {}) if isinstance(s, dict) else {}
    given = f" ({', '.join(f'{k}={v}' for k, v in args.items())})" if args else ""
    return f"system {name}{given}" if name else "user system"


def _paper_numbers(config: dict[str, Any]) -> dict[str, Any] | None:
    """The paper's manual / phase 1 / phase 3 costs of a built-in task (phase 3 of its terrain),
    None when the paper has no row for its robot and gait."""
    t = config.get("task") or {}
    row = paper_row(str(t.get("robot", "")), str(t.get("gait", "")))
    if not row:
        return None
    key = "phase3_even" if t.get("terrain") == "flat" else "phase3_uneven"
    return {"manual": row.get("manual"), "phase1": row.get("phase1"), "phase3": row.get(key)}


def manual_rows(store: Any) -> list:
    """The trials of the manual θ: the stored manual rows (phase 0); in an ask/tell phase 1,
    which stores no separate manual trial, the trial of its first suggestion (the lowest
    suggestion id told, wherever its result was stored: suggestions run in parallel are told
    in any order) when it ran exactly the space's manual θ (the first suggestion of
    ``start="manual"``); else []."""
    rows = store.rows(Phase.MANUAL)
    cfg = store.get_meta("config") or {}
    if rows or (cfg.get("asktell") or {}).get("phase") != Phase.PHASE1 or not cfg.get("space"):
        return rows
    from latentune.space import ParameterSpace

    manual = ParameterSpace.from_dict(cfg["space"], stored=True).manual
    rows = store.rows(Phase.PHASE1)
    if not rows:
        return []
    first = min(rows, key=lambda r: (r.info.get("trial", math.inf), r.idx))
    return [first] if np.array_equal(np.asarray(first.theta, dtype=float), manual) else []


def manual_target(rows: list) -> float | None:
    """The cost a trial that stood must be strictly below to beat the manual θ, from its trials
    ``rows`` (:func:`manual_rows`): the manual trial's cost if it stood; +inf if it failed (a
    trial that stood ranks before every failed one, whatever the costs:
    :func:`latentune.critic.base.fall_last`), so the first trial that stood beats it; None
    without a manual trial (``rows`` empty)."""
    stood = [r.cost for r in rows if not r.fell]
    return min(stood) if stood else (math.inf if rows else None)


BEAT_NOTE = ("Evals to beat manual: the first of the phase's own evaluations, counted from 1, "
             "that stood and cost strictly less than the manual θ (the first that stood, when "
             "the manual θ failed). Phase 1's first evaluation is the manual θ's trial; phase "
             "3's count leaves out the manual and zero-shot trials.")
"""The report's line under its table saying how "evals to beat manual" counts
(:func:`beats_manual`); :func:`beat_note` says it for the run at hand."""


def beat_note(manual: list) -> str:
    """:data:`BEAT_NOTE` for the manual θ's trials ``manual`` (:func:`manual_rows`): an
    ask/tell phase 1's manual trial is one of its rows, at the place it was told, which the
    note names when it is not the first."""
    rows = [r for r in manual if r.phase == Phase.PHASE1]
    if not rows or rows[0].idx == 0:
        return BEAT_NOTE
    return BEAT_NOTE.replace("Phase 1's first evaluation is",
                             f"Phase 1's evaluation {rows[0].idx + 1} (in the order told) is")


def beats_manual(store: Any, manual: list | None = None) -> dict[int, int | None]:
    """Phase → its "evals to beat manual": the first of the phase's own evaluations, counted
    from 1 in the store's order, that did not fail and cost strictly less than the manual θ
    (any that did not fail, when the manual θ failed: :func:`manual_target`); None if none
    did, or without a manual trial. Phase 1's first evaluation is the manual θ's trial (never
    a beat); phase 3 leaves the manual and zero-shot trials out (the zero-shot phase has its
    own count, 1 or None). ``manual``: as :func:`run_stats` takes it. The count of
    :func:`run_stats` (:func:`~latentune.reporting.metrics.phase_stats` against
    :func:`manual_target`) from the stored costs and fall flags alone, without reading the
    trials' θ (most of reading a large store)."""
    if manual is None:
        manual = manual_rows(store)
    target = manual_target(manual)
    out = {}
    for ph in TABLE_PHASES:
        if ph == Phase.MANUAL:
            costs, fell = [r.cost for r in manual], [r.fell for r in manual]
        else:
            costs, fell = store.costs(ph).tolist(), store.fell(ph).tolist()
        out[int(ph)] = phase_stats(costs, target, fell=fell)["evals_to_beat"]
    return out


def best_ratio(phase3_best: float | None, phase1_best: float | None) -> float | None:
    """``phase3_best / phase1_best`` when both bests are positive (< 1: phase 3 found a lower
    cost); None otherwise: for a zero or negative cost the ratio of costs does not say which
    phase is better (-10 / -5 = 2 with phase 3 better)."""
    if phase3_best is None or phase1_best is None or phase3_best <= 0 or phase1_best <= 0:
        return None
    return phase3_best / phase1_best


def run_stats(store: Any, manual: list | None = None) -> dict[int, dict[str, Any]]:
    """Phase → :func:`~latentune.reporting.metrics.phase_stats` of the store's costs against the
    manual θ (:func:`manual_target`: a trial that stood beats a failed manual θ whatever the
    costs), plus ``rms`` (RMS velocity error of the best θ [m/s], built-in tasks only) and
    ``falls`` counted from the stored ``fell`` flags. ``manual``: the manual θ's trials
    (:func:`manual_rows`) when the caller has them; None: found in the store."""
    cfg = store.get_meta("config") or {}
    steps = _steps(cfg)
    if manual is None:
        manual = manual_rows(store)
    target = manual_target(manual)
    out = {}
    for ph in TABLE_PHASES:
        rows = manual if ph == Phase.MANUAL else store.rows(ph)
        s = phase_stats([r.cost for r in rows], target, fell=[r.fell for r in rows])
        s["rms"] = rms_velocity_error(s["best"], steps) \
            if steps and s["best"] is not None else None
        out[int(ph)] = s
    return out


def comparison_table(store: Any, manual: list | None = None) -> str:
    """The Markdown table of the run: per phase the best cost, (built-in tasks) its RMS velocity
    error [m/s], the number of evaluations, the stable ones and the evaluations to beat the
    manual θ (:func:`beats_manual`: 1-based, the phase's own); the paper's numbers below it when it
    has the task. A phase without trials has a row of zeros while no later phase holds trials
    (it is still to come), and none after that (it is not part of this run); phase 3 only once
    it can come: the run holds its options record, a latent space or a ``tune`` plan (a
    ``phase1`` run is complete without it; a ``tune`` run that stopped before phase 3 has it
    to come); in an
    ask/tell store, only when it is a phase of its ask/tell phase (:data:`ASKTELL_PHASES`); in
    an Optuna import's, phase 1's only (phase 3's too once a phase 3 is recorded).
    ``manual``: the manual θ's trials, as :func:`run_stats` takes them."""
    cfg = store.get_meta("config") or {}
    t = cfg.get("task")
    stats = run_stats(store, manual)
    rms = t is not None
    asked = (cfg.get("asktell") or {}).get("phase")
    runs = ASKTELL_PHASES.get(int(asked), ()) if asked is not None else TABLE_PHASES
    if asked is None and not (cfg.get("phase3") or cfg.get("vae")) and \
            cfg.get("tune") is None:            # phase 1 alone (a tune run plans phase 3)
        runs = (Phase.MANUAL, Phase.PHASE1)
    if (cfg.get("system") or {}).get("kind") == "optuna":      # an import: phase 1 alone,
        runs = (Phase.PHASE1,) + (ASKTELL_PHASES[Phase.PHASE3] if cfg.get("phase3") else ())
    if t:
        terrain, _, rest = _where(t).partition(", ")
        head = (f"{t.get('robot', '?')} {t.get('gait', '?')} on {terrain} [{rest}], "
                f"{t.get('steps', '?')} steps, v_des {t.get('v_des', '?')}")
    else:
        head = _title(cfg)
    cols = ["best path cost" if rms else "best cost"] + (["RMS velocity error [m/s]"] if rms else [])
    cols += ["evaluations", "stable", "evals to beat manual"]
    lines = [head, "", "| | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
    for k, ph in enumerate(TABLE_PHASES):
        s = stats[int(ph)]
        if s["n"] == 0:
            # the zero-shot row only once it ran; an empty row of manual θ or phase 1 not when
            # a later phase holds trials (a phase 3 on another study's latent space runs none)
            if ph == Phase.ZERO_SHOT or ph not in runs or ph in (
                    Phase.MANUAL, Phase.PHASE1) and any(
                    stats[int(q)]["n"] for q in TABLE_PHASES[k + 1:]):
                continue
            cells = ["–"] * (2 if rms else 1) + ["0", "–", "–"]
        else:
            beat = "–"
            if ph != Phase.MANUAL and stats[Phase.MANUAL]["n"]:
                beat = fmt(s["evals_to_beat"]) if s["evals_to_beat"] is not None else "not beaten"
            cells = [fmt(s["best"])] + ([fmt(s["rms"])] if rms else [])
            cells += [str(s["n"]), f"{s['stable']}/{s['n']}", beat]
        lines.append(f"| {phase_label(ph, cfg, s['n'])} | " + " | ".join(cells) + " |")
    paper = _paper_numbers(cfg) if t else None
    if paper and any(v is not None for v in paper.values()):
        lines.append("")
        lines.append("paper (Sarmadi et al., 10000 phase-1 evaluations): manual "
                     f"{paper['manual']}, phase 1 {paper['phase1']}, phase 3 {paper['phase3']}")
    return "\n".join(lines)


def seconds(v: float) -> str:
    """A wall time [s] as the report writes it: whole seconds from 10 s, else tenths without
    a trailing zero ("12", "0.5", "3"; 0.46 s is not "0")."""
    return f"{v:.0f}" if v >= 9.95 else f"{v:.1f}".rstrip("0").rstrip(".")


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def handover_stats(store: Any) -> dict[str, Any] | None:
    """Phase 3 with a hand-over (:mod:`latentune.critic.handover`): the recorded rule, and the
    evaluations, best cost (of a trial that did not fail; None if none stood) and falls of each
    space (rows with z: latent space; without: θ); None for a plain phase 3."""
    rec = (store.get_meta("config") or {}).get("phase3_handover")
    if rec is None:
        return None
    rows = store.rows(Phase.PHASE3)
    out: dict[str, Any] = dict(rec)
    for name, part in (("latent", [r for r in rows if r.z is not None]),
                       ("full", [r for r in rows if r.z is None])):
        out[f"{name}_evals"] = len(part)
        out[f"{name}_best"] = min((r.cost for r in part if not r.fell), default=None)
        out[f"{name}_falls"] = sum(r.fell for r in part)
    return out


def _best_file(store: Any, cfg: dict[str, Any], arts: dict[str, Any], phase: int) -> str | None:
    """The artifact ``phase{phase}_best`` (the phase's best θ file) while it holds the θ of the
    phase's best trial; None without one, or for a file of an earlier best (a run stopped
    before it wrote its own: :func:`~latentune.pipeline.results.holds_theta`)."""
    from latentune.pipeline.manifest import config_space
    from latentune.pipeline.results import best_row, holds_theta

    name = arts.get(f"phase{int(phase)}_best")
    b = best_row(store, (int(phase),)) if name else None
    if b is None:
        return None
    return name if holds_theta(store.dir / name, b.theta, config_space(cfg)) is not False \
        else None


def write_summary(store: Any, manual: list | None = None) -> dict[str, Any]:
    """Write ``DIR/summary.json`` from the store and return it.

    Costs: ``manual_cost`` and ``zero_shot_cost`` (the trial's own cost, fallen or not, with
    ``manual_fell`` and ``zero_shot_fell``; None without the trial), ``phase1_best`` and
    ``phase3_best`` (the best trial that did not fail; None if none stood),
    ``phase3_vs_phase1`` (``phase3_best / phase1_best`` when both are positive, else None:
    :func:`best_ratio`); counts: ``phase{1,3}_evals``, ``phase{1,3}_stable``,
    ``phase{1,3}_falls``, ``phase{1,3}_reused`` (of the evaluations, those stored with a
    stored trial's outcome, not run again: :func:`~latentune.pipeline.results.reused_count`;
    phase 1's first, the manual θ's trial, is one), ``phase{1,3}_evals_to_beat_manual`` (the
    first evaluation, 1-based,
    that did not fail and beat the manual θ: strictly below its cost, or any that did not fail
    when the manual θ failed; None if never or without a manual trial);
    ``rms_velocity_error_m_s`` (per phase, the best θ's RMS velocity error [m/s]; None for a
    user system); wall times [s]
    ``wall_s`` (sum over phases; None when every phase that ran has an unknown time),
    ``wall_by_phase_s``, ``wall_unknown`` (the phases whose time is not (all) known: a run
    killed inside one before storing a trial, or trials told through ask/tell; one that is in
    ``wall_by_phase_s`` too is partly known: its blocks that ended are counted, the killed
    one is not, and a later block that ends does not make it known:
    :func:`~latentune.pipeline.walltime.wall_record`); ``seed``,
    ``config``, ``artifacts``, ``phase{1,3}_best_params`` (the phase's best θ file, while it
    holds that θ), ``paper`` (the paper's numbers for
    the task or None), ``phase3_handover`` (:func:`handover_stats`), ``written`` (unix time).
    ``manual``: the manual θ's trials, as :func:`run_stats` takes them.
    """
    from latentune.pipeline.results import reused_count

    cfg = store.get_meta("config") or {}
    wall, wall_unknown = wall_record(store)
    arts = store.get_meta("artifacts", {}) or {}
    if manual is None:
        manual = manual_rows(store)
    st = run_stats(store, manual)
    p0, p1, p3, p4 = (st[int(ph)] for ph in (Phase.MANUAL, Phase.PHASE1, Phase.PHASE3,
                                              Phase.ZERO_SHOT))
    names = {"manual": p0, "phase1": p1, "phase3": p3, "zero_shot": p4}
    trial = {Phase.MANUAL: phase_stats([r.cost for r in manual])["best"],
             Phase.ZERO_SHOT: phase_stats(store.costs(Phase.ZERO_SHOT))["best"]}
    summary = {
        "manual_cost": trial[Phase.MANUAL],
        "manual_fell": bool(p0["falls"]) if p0["n"] else None,
        "phase1_best": p1["best"],
        "phase3_best": p3["best"],
        "zero_shot_cost": trial[Phase.ZERO_SHOT],
        "zero_shot_fell": bool(p4["falls"]) if p4["n"] else None,
        "phase1_evals": p1["n"],
        "phase3_evals": p3["n"],
        "phase1_stable": p1["stable"],
        "phase3_stable": p3["stable"],
        "phase1_falls": p1["falls"],
        "phase3_falls": p3["falls"],
        "phase1_reused": reused_count(store.rows(Phase.PHASE1)),
        "phase3_reused": reused_count(store.rows(Phase.PHASE3)),
        "phase1_evals_to_beat_manual": p1["evals_to_beat"],
        "phase3_evals_to_beat_manual": p3["evals_to_beat"],
        "phase3_vs_phase1": best_ratio(p3["best"], p1["best"]),
        "rms_velocity_error_m_s": ({k: v["rms"] for k, v in names.items()}
                                   if _steps(cfg) else None),
        "wall_s": float(sum(wall.values())) if wall or not wall_unknown else None,
        "wall_by_phase_s": wall,
        "wall_unknown": wall_unknown,
        "seed": cfg.get("phase1", cfg.get("phase3", {})).get("seed", cfg.get("task", {}).get("seed")),
        "config": cfg,
        "phase1_best_params": _best_file(store, cfg, arts, Phase.PHASE1),
        "phase3_best_params": _best_file(store, cfg, arts, Phase.PHASE3),
        "artifacts": arts,
        "paper": _paper_numbers(cfg) if "task" in cfg else None,
        "phase3_handover": handover_stats(store),
        "written": time.time(),
    }
    write_atomic(store.dir / "summary.json", json.dumps(summary, indent=1, default=float))
    return summary


def _curve_panels(store: Any, cfg: dict[str, Any], manual_trials: list) -> list:
    """One best-cost panel per tuned phase (phase 1, phase 3), each on its own evaluation axis,
    with the cost of the manual θ's trials ``manual_trials`` as a reference line (phase 3's
    also the zero-shot trial's), labelled "manual θ, fell" ("zero-shot (source best θ), fell")
    when every one of them fell (its cost is no cost to beat: any trial that stands beats it)."""
    from latentune.reporting.plots import CurvePanel

    manual = phase_stats([r.cost for r in manual_trials])["best"]
    fell = bool(manual_trials) and all(r.fell for r in manual_trials)
    zero = phase_stats(store.costs(Phase.ZERO_SHOT))["best"]
    zero_fell = bool(store.count(Phase.ZERO_SHOT)) and bool(store.fell(Phase.ZERO_SHOT).all())
    panels = []
    for ph in (Phase.PHASE1, Phase.PHASE3):
        rows = store.rows(ph)
        if not rows:
            continue
        label = phase_label(ph, cfg)
        refs: dict[str, float | None] = {"manual θ, fell" if fell else "manual θ": manual}
        if ph == Phase.PHASE3 and zero is not None:
            refs["zero-shot (source best θ)" + (", fell" if zero_fell else "")] = zero
        panels.append(CurvePanel(f"{label}: {counted(len(rows), 'evaluation')}",
                                 {label: [r.cost for r in rows]}, refs,
                                 {label: [r.fell for r in rows]}))
    return panels


def _rollout_system(system: Any, cfg: dict[str, Any], where: Path):
    """The system used to re-simulate: ``system`` if given, else the stored built-in task of
    the run in ``where``; None when neither has a ``rollout(theta, record=True)`` method."""
    sim = system if system is not None else task_from_config(cfg, where)
    return sim if callable(getattr(sim, "rollout", None)) else None


def decisions_markdown(store: Any) -> list[str]:
    """The report's lines on the phase-3 critic's decisions (:func:`~latentune.pipeline.results.
    decisions`): how many asks of each kind, then one table row per ask (generation, trials
    told before it, kind (a record walk's with the rank of its θ in the source's standing
    trials; the scores ``"auto"`` chose, :func:`~latentune.pipeline.results.decision_scores`),
    pools of its points, agreement, the trust region's side, admissible
    candidates of all, the fall screen's bound when an explore ask applied its own
    (``explore_bound``), the highest fall probability it asked); [] without any."""
    from latentune.pipeline.results import (decision_kind, decision_scores, decisions,
                                            decisions_summary)

    ds = decisions(store)
    summ = decisions_summary(ds)
    if summ is None:
        return []

    def agreement_cell(d: dict[str, Any]) -> str:
        why = d.get("agreement_unmeasured")
        return f"not measured ({why})" if why else fmt(d.get("agreement"), 2)

    md = ["## Phase 3 decisions", "",
          f"{counted(summ['n'], 'ask')}: " + ", ".join(f"{k} {v}" for k, v in summ["kinds"].items())
          + ". The agreement is the posterior mean of the source model's weight in the target's "
          "cost model (1: the target ranks θ as the source did; 0: the source says nothing).", "",
          "| generation | trials told | ask | pools | agreement | side | admissible | "
          "explore screen | max fall prob asked |", "|---:|---:|---|---|---:|---:|---:|---:|---:|"]
    for d in ds:
        pools = "/".join(sorted(set(d.get("pools") or [])))
        adm = "" if d.get("n_admissible") is None else \
            f"{d['n_admissible']} of {d.get('n_candidates')}"
        scores = decision_scores(d)
        kind = decision_kind(d) + (f" (rank {d['walk_rank']})" if "walk_rank" in d else "") \
            + (f"; {scores}" if scores else "")
        md.append(f"| {d.get('generation')} | {d.get('n_told')} | {kind} | {pools} | "
                  f"{agreement_cell(d)} | {fmt(d.get('length'), 4)} | {adm} | "
                  f"{fmt(d.get('explore_bound'), 2)} | {fmt(d.get('max_fall_prob_asked'), 2)} |")
    md.append("")
    failed = [f"generation {d.get('generation')}: " + ", ".join(
        f"{model} ({why})" for model, why in d["fit_failed"].items())
        for d in ds if d.get("fit_failed")]
    if failed:
        md += ["Asks with a model fit that failed (the model kept its starting hyperparameters, "
               "so the ask differs from a fitted model's): " + "; ".join(failed) + ".", ""]
    return md


RESUMED_BY = {Phase.PHASE1: ("tune", "phase1"), Phase.PHASE3: ("tune", "phase3")}
"""The commands that run a phase of a phase run, and so go on with it given ``--resume``."""


def resume_hint(store: Any, cfg: dict[str, Any], phase: int) -> str:
    """What goes on with a phase run's ``phase`` (1 or 3) stopped short of its budget, as a
    sentence after the line that says so: for a built-in task or a ``--system`` run, the
    command that ran it with ``--resume`` on the run directory: the one recorded (``command``:
    ``tune``, whose run goes on to phase 3 as planned, or ``phase1``, whose phase 3 a ``phase3``
    command ran; a phase 3 in another run's latent space is a ``phase3 --vae`` one), else, for
    a run that
    recorded none (stored before the record existed, or run through the API), the commands that
    run the phase (:data:`RESUMED_BY`); for a system made in Python, the study's method again; a
    phase 3 whose fall budget is spent asks no more, and says so instead. Empty for an ask/tell
    run (it goes on with ``ask``) and an Optuna import."""
    kind = (cfg.get("system") or {}).get("kind")
    if cfg.get("asktell") or kind in ("optuna", "external"):
        return ""
    if phase == Phase.PHASE3:
        from latentune.pipeline.results import fall_budget

        fb = fall_budget(store, cfg)
        if fb and fb.get("spent"):
            return (f" Its fall budget is spent ({counted(fb['falls'], 'fall')} counted, "
                    f"{fb['falls_allowed']} allowed): it asks no more.")
    if kind == "python":
        return (f" If it stopped, `Study({str(store.dir)!r}).phase{int(phase)}(system, budget)` "
                "with the same system goes on.")
    recorded = cfg.get("command")
    other_latent = cfg.get("phase3_vae_source") not in (None, "self")
    if phase == Phase.PHASE3 and (recorded == "phase1" or other_latent):
        ran = "phase3"      # a phase1 run's phase 3, or one in another run's latent space (--vae)
    elif recorded in RESUMED_BY[phase]:
        ran = recorded
    else:
        ran = "tune" if cfg.get("tune") is not None else None
    where = shlex.quote(str(store.dir))
    tune, other = (f"`latentune {c} … --out {where} --resume`" for c in RESUMED_BY[phase])
    p1 = phase == Phase.PHASE1
    if ran == "tune":
        then = " (it then trains the latent space and runs phase 3)" if p1 else ""
        return f" If it stopped, the command that ran it goes on: {tune}{then}."
    if ran is not None:
        return f" If it stopped, the command that ran it goes on: {other}."
    then = " (a tune run: it then trains the latent space and runs phase 3)" if p1 else ""
    return f" If it stopped, the command that ran it goes on: {tune}{then} or {other}."


def state_lines(store: Any, cfg: dict[str, Any]) -> list[str]:
    """What the tables do not show about a run's state: a phase with fewer trials than its
    budget (stopped, still running, or stopped by its fall budget; :func:`resume_hint`), a
    ``tune`` run's phase 3 not started (stopped in or after phase 2), zero-shot and phase-3
    trials stored with a stored trial's outcome, not run again
    (:func:`~latentune.pipeline.results.reused_count`),
    suggestions handed out to ask/tell and not told, and amended results. Empty for a
    finished run."""
    lines = []
    for key, phase in (("phase1", Phase.PHASE1), ("phase3", Phase.PHASE3)):
        budget = (cfg.get(key) or {}).get("budget")
        n = store.count(phase)
        if budget and n < int(budget):
            label = phase_label(phase, cfg)
            lines.append(f"{label[0].upper()}{label[1:]} holds {counted(n, 'trial')} of "
                         f"its budget of {int(budget)}." + resume_hint(store, cfg, phase))
    p1 = (cfg.get("phase1") or {}).get("budget")
    if cfg.get("tune") is not None and not cfg.get("phase3") and not store.count(Phase.PHASE3) \
            and not (p1 and store.count(Phase.PHASE1) < int(p1)):   # else said with phase 1's
        planned = cfg["tune"].get("phase3_evals")
        plan = f": the tune run plans {counted(planned, 'trial')}" if planned else ""
        then = "it runs phase 3" if cfg.get("vae") else \
            "it trains the latent space, then runs phase 3"
        where = shlex.quote(str(store.dir))
        stood = int((~store.fell(Phase.PHASE1)).sum())
        if not cfg.get("vae") and stood < 2:        # phase 2 refuses: the resume would too
            lines.append(f"Phase 3 has not started{plan}; its latent space needs at least 2 "
                         f"phase-1 trials that did not fail and phase 1 holds {stood}, so more "
                         f"phase-1 trials come first: `latentune tune … --out {where} --resume "
                         f"--phase1-evals N` (N above {store.count(Phase.PHASE1)}).")
        else:
            lines.append(f"Phase 3 has not started{plan}. If it stopped, the command that ran "
                         f"it goes on: `latentune tune … --out {where} --resume` ({then}).")
    from latentune.pipeline.results import reused_count

    for phase in (Phase.ZERO_SHOT, Phase.PHASE3):   # phase 1's: its first, the manual θ's
        rows = store.rows(phase) if store.count(phase) else []
        k = reused_count(rows)
        if k:
            fell = sum(1 for r in rows if r.info.get("reused") and r.fell)
            label = phase_label(phase, cfg)
            which = "its trial repeats" if len(rows) == 1 else \
                f"{k} of its {len(rows)} trials {'repeat' if k > 1 else 'repeats'}"
            falls = "" if not fell else " (a fall)" if k == 1 else f" ({counted(fell, 'fall')})"
            lines.append(f"{label[0].upper()}{label[1:]}: {which} the θ of a stored trial, "
                         f"stored with that trial's outcome{falls}, not run again; the table "
                         f"counts {'them' if k > 1 else 'it'}.")
    out = len(store.trials("pending"))
    if out:
        lines.append(f"{out} suggestion{'s are' if out != 1 else ' is'} handed out to ask/tell "
                     "and not told: not in the tables yet.")
    amended = len({a["trial"] for a in store.amendments() if a["trial"] is not None})
    if amended:
        lines.append(f"{amended} told result{'s were' if amended != 1 else ' was'} amended "
                     "(`tell --amend`); the tables use the amended values.")
    return lines + [""] if lines else []


def make_report(store: Any, system: Any = None, simulate: bool = True, quiet: bool = False) -> str:
    """Write ``DIR/report.md``, ``DIR/best_so_far.png``, ``DIR/summary.json`` and (``simulate``
    and a system with ``rollout(theta, record=True)``: ``system``, else the stored config's
    task) ``DIR/com_velocity.png`` (else an earlier report's is removed); return the comparison
    table (Markdown). A run that cannot be written (read-only media) is a StoreError before
    anything is written.

    ``quiet``: no progress messages on stderr.
    """
    from latentune.reporting.plots import plot_best_so_far, plot_rollouts

    store.check_writable()
    cfg = store.get_meta("config") or {}
    title = _title(cfg)
    out = store.dir
    figs = []
    manual = manual_rows(store)             # found once: an ask/tell store's parses its space
    panels = _curve_panels(store, cfg, manual)
    if panels:
        plot_best_so_far(panels, out / "best_so_far.png", title=f"{title}: best cost so far")
        store.add_artifact("best_so_far_png", out / "best_so_far.png")
        figs.append("best_so_far.png")
    sim = _rollout_system(system, cfg, out) if simulate else None
    if sim is not None:
        runs = {}
        for ph in TABLE_PHASES:
            b = store.best(ph)
            if b is not None:
                if not quiet:
                    logger.info("report: re-simulating the best θ of %s", phase_label(ph, cfg))
                runs[phase_label(ph, cfg)] = sim.rollout(b.theta, record=True)
        if runs:
            v_des = getattr(sim, "v_des", None)
            plot_rollouts(runs, out / "com_velocity.png",
                          v_des=None if v_des is None else float(np.ravel(v_des)[0]), title=title)
            store.add_artifact("com_velocity_png", out / "com_velocity.png")
            figs.append("com_velocity.png")
    if "com_velocity.png" not in figs:      # an earlier report's, of another best θ perhaps
        (out / "com_velocity.png").unlink(missing_ok=True)
        store.forget_artifact("com_velocity_png")
    summary = write_summary(store, manual=manual)
    table = comparison_table(store, manual)
    lat = cfg.get("latent") or cfg.get("vae") or {}
    md = [f"# latentune run: {title}", "", table, "", *([beat_note(manual), ""] if manual else []),
          *state_lines(store, cfg)]
    if lat:
        md.append(f"Latent space: kind {lat.get('kind')}, d_low {lat.get('d_low')}, trained on "
                  f"{lat.get('n_train')} stable θ; box: {lat.get('box_rule')}.")
        src = cfg.get("phase3_vae_source")
        if src and src != "self":
            made = ", ".join(f"{k} {v}" for k, v in (lat.get("from") or {}).items()
                             if v is not None)      # a user system's is empty
            md.append(f"Phase 3 used the VAE of {src}" + (f" ({made})." if made else "."))
        ho = summary.get("phase3_handover")
        if ho:
            at = ho.get("handover_at")
            md.append(f"Phase 3 hand-over rule: {ho.get('rule')}; "
                      + (f"it handed over after {counted(at, 'latent evaluation')}"
                         if at is not None
                         else "it did not hand over")
                      + f" (latent space: {counted(ho['latent_evals'], 'evaluation')}, best "
                      f"{_fmt(ho['latent_best'])}, {counted(ho['latent_falls'], 'fall')}; "
                      f"full θ: {counted(ho['full_evals'], 'evaluation')}, best "
                      f"{_fmt(ho['full_best'])}, {counted(ho['full_falls'], 'fall')}).")
        md.append("")
    md += decisions_markdown(store)
    wall = summary.get("wall_by_phase_s") or {}
    unknown = summary.get("wall_unknown") or []
    if wall or unknown:
        partly = [k for k in unknown if k in wall]      # timed, and a block of it lost
        none = [k for k in unknown if k not in wall]
        stopped = {"vae": " (stopped before it stored a latent space)"} \
            if "vae" in wall and not cfg.get("vae") else {}   # a Ctrl-C in its training
        md.append(" ".join(
            ([("Wall time: " + ", ".join(f"{k} {seconds(v)} s" + (" + unknown" if k in partly
                                                               else "") + stopped.get(k, "")
                                         for k, v in wall.items()) + ".")]
             if wall else [])
            + ([f"The time of {', '.join(partly)} leaves out a block stopped before it stored "
                "its time or any trial (a command killed in it, or one running now): the "
                "blocks that ended are counted."] if partly else [])
            + ([f"Wall time of {', '.join(none)} not (all) known: trials told through "
                "ask/tell or imported, or a run stopped before it stored its time or any "
                "trial."]
               if none else [])))
        md.append("")
    for f in figs:
        md.append(f"![{f}]({f})")
    write_atomic(out / "report.md", "\n".join(md) + "\n")
    store.add_artifact("report_md", out / "report.md")
    return table


__all__ = ["comparison_table", "write_summary", "make_report", "run_stats", "task_from_config",
           "manual_rows", "manual_target",
           "phase_label", "fmt", "decisions_markdown", "state_lines", "resume_hint"]
