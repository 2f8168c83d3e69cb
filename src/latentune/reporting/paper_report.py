"""The report of a ``latentune paper`` directory: ``DIR/report.md``, ``DIR/paper_summary.json``,
figures (PNG) and GIFs, every number read from the studies' run stores (``DIR/<study>/run.db``).

Layout (the paper's): Table II (A1) / Table III (Solo12) with the rows Manual Tuned, Phase 1,
Phase 3 even, Phase 3 uneven, Phase 3 cross-task and, per gait, latentune's best path cost beside
the paper's; then A1 → B1 transfer, the VAE stable-preservation rate, the baselines at the
phase-3 budget, the paper's qualitative claims checked one by one, and the figures. The paper's
numbers (:func:`~latentune.reporting.metrics.paper_results`, packaged with latentune) are printed
beside ours, never instead of them.

The work is split in four steps, each a function: :func:`compute` (a dict of numbers from the
stores) → :func:`check_claims` → :func:`make_figures` → :func:`markdown` (and
:func:`summary_json`); :func:`write_paper_report` runs them and writes the files.
"""
from __future__ import annotations

import json
import logging
import math
import os
import shlex
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.constants import C1, PAPER_PHASE1, PAPER_PHASE3, Phase
from latentune.errors import UsageError
from latentune.pipeline.walltime import wall_record
from latentune.reporting.metrics import (PAPER_ROBOT, evals_to_beat, paper_results, paper_row,
                                         phase_stats)
from latentune.reporting.run_report import fmt, task_from_config

logger = logging.getLogger(__name__)

TABLE_NO = {"a1": "II", "solo12": "III"}
METHOD_NAME = {"turbo": "TuRBO-m on θ (full space)", "cma": "CMA-ES on θ",
               "random": "random search on θ"}
GAITS = ("trot", "jump")
OTHER_GAIT = {"trot": "jump", "jump": "trot"}
STUDY_PHASES = ((Phase.MANUAL, "manual"), (Phase.PHASE1, "phase1"), (Phase.PHASE3, "phase3"),
                (Phase.ZERO_SHOT, "zero_shot"), (Phase.PRESERVATION, "preservation"))
ARMS = {"phase3-plain": "phase 3, plain (the paper's)",
        "phase3-transfer": "phase 3, default (transfer)",
        "turbo": "TuRBO-m on θ", "cma": "CMA-ES on θ", "random": "random search on θ",
        "tpe": "Optuna TPE (multivariate) on θ",
        "cmaes-src": "Optuna CMA-ES with source_trials on θ"}
"""The methods of the seeded comparisons (arm key -> label)."""
BASELINE_ARMS = ("turbo", "cma", "random", "tpe", "cmaes-src")

Claim = tuple[str, "bool | None", str]
"""(claim, holds — None when its studies did not run, detail)."""


# ---------------------------------------------------------------------------- numbers
def study_stats(run_dir: Path) -> dict[str, Any] | None:
    """Numbers of one study from its store, None if it was not run.

    Keys ``dir``, ``config``, ``wall`` (seconds per phase, a phase killed inside counted up to
    its last stored trial: :func:`~latentune.pipeline.walltime.wall_record`) and per phase (``manual``, ``phase1``, ``phase3``,
    ``preservation``) a dict: ``n``, ``best``, ``best_idx``, ``stable``, ``falls``, ``theta``
    (the best θ as a list, None without rows), ``costs`` (list, evaluation order) and, for
    phase 1 and phase 3, ``evals_to_beat_manual`` (as the run report counts it,
    :func:`~latentune.reporting.run_report.beats_manual`); ``preservation_meta``.
    """
    from latentune.critic.transfer import stored_options
    from latentune.pipeline.phases import state_key
    from latentune.pipeline.store import RunStore
    from latentune.reporting.run_report import beats_manual

    if not (run_dir / "run.db").is_file():
        return None
    with RunStore(run_dir) as st:
        out: dict[str, Any] = {"dir": run_dir.name, "config": st.get_meta("config") or {},
                               "wall": wall_record(st)[0]}
        for ph, name in STUDY_PHASES:
            y = st.costs(ph)
            b = st.best(ph)
            s = phase_stats(y, fall_cost=C1)
            del s["evals_to_beat"]
            s.update(best_idx=None if b is None else int(b.idx),
                     theta=None if b is None else b.theta.tolist(), costs=y.tolist())
            out[name] = s
        out["preservation_meta"] = st.get_meta("preservation")
        state = st.get_meta(state_key(3))
        out["phase3_options"] = stored_options(state) if isinstance(state, dict) else None
        beat = beats_manual(st)
        for ph, name in ((Phase.PHASE1, "phase1"), (Phase.PHASE3, "phase3")):
            out[name]["evals_to_beat_manual"] = beat[int(ph)]
    return out


def _cell(S: dict[str, Any], key: str, phase: str, paper: Any, **extra: Any) -> dict[str, Any]:
    """One Table II/III cell: our best of ``phase`` in study ``key``, the paper's value."""
    s = S.get(key)
    return {"ours": None if s is None else s[phase]["best"], "paper": paper,
            "evals": 0 if s is None else s[phase]["n"], "study": key, **extra}


def _baseline_row(label: str, study: str, costs: Any, beat: int | None) -> dict[str, Any]:
    """A baseline table row of the (n,) ``costs`` whose ``evals_to_beat_manual`` is ``beat``
    (the study's count, :func:`study_stats`; None when not within ``costs``)."""
    s = phase_stats(costs, fall_cost=C1)
    beat = beat if beat is not None and beat <= s["n"] else None
    return {"label": label, "study": study, "n": s["n"], "best": s["best"],
            "stable": s["stable"], "evals_to_beat_manual": beat}


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def read_paper_meta(root: str | Path) -> dict[str, Any]:
    """``root/paper.json``, the record of a ``latentune paper`` run, checked for what the report
    reads: a JSON object with ``robot`` (a1, solo12), ``budgets`` (scale, phase1, phase3,
    preservation, baselines: numbers), ``studies`` (directory name → object with a ``kind``)
    and, when present, integer ``seed``/``seeds``, a list of ``invocations`` and a number
    ``wall_s_total`` (a hand-edited record fails here in one line, not in the report).

    Raises:
        UsageError: one line naming the file: unreadable, not JSON, or not a paper run's record.
    """
    path = Path(root) / "paper.json"
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path} is unreadable ({getattr(exc, 'strerror', None) or exc})") from None
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path} is not JSON ({exc}): not a latentune paper run's record") from None
    if not isinstance(meta, dict):
        problem = "not a JSON object"
    elif meta.get("robot") not in ("a1", "solo12"):
        problem = "no robot" if "robot" not in meta else f"robot {meta['robot']!r}, not a1 or solo12"
    elif not isinstance(meta.get("budgets"), dict) or not all(
            _is_number(meta["budgets"].get(k))
            for k in ("scale", "phase1", "phase3", "preservation", "baselines")):
        problem = "no budgets (numbers scale, phase1, phase3, preservation, baselines)"
    elif not isinstance(meta.get("studies"), dict) or not all(
            isinstance(v, dict) for v in meta["studies"].values()):
        problem = "no studies"
    elif bad := [k for k, v in meta["studies"].items() if Path(k).name != k or k in ("", ".", "..")
                 or not isinstance(v.get("kind"), str)
                 or not isinstance(v.get("seed_index", 0), int)]:
        problem = f"study {bad[0]!r}: not a directory name with a kind"
    elif not all(isinstance(meta.get(k, 0), int) and not isinstance(meta.get(k, 0), bool)
                 for k in ("seed", "seeds")):
        problem = "seed or seeds not an integer"
    elif not isinstance(meta.get("invocations", []), list) or not all(
            isinstance(i, dict) and isinstance(i.get("machine") or {}, dict)
            for i in meta.get("invocations", [])):
        problem = "invocations not a list of records"
    elif meta.get("wall_s_total") is not None and not _is_number(meta["wall_s_total"]):
        problem = "wall_s_total not a number"
    else:
        return meta
    raise UsageError(f"{path} is not a latentune paper run's record ({problem})")


def compute(root: str | Path) -> dict[str, Any]:
    """Every number of the report from ``root/paper.json`` and the studies' stores.

    Keys: ``root``, ``meta`` (paper.json), ``robot``, ``R`` (the paper's robot name),
    ``budgets``, ``paper`` (the paper's numbers), ``studies`` (study key → :func:`study_stats`),
    ``table`` (gait → Table II/III row → cell), ``transfer`` (A1 only: gait → B1 numbers),
    ``preservation``, ``baselines`` (gait → manual cost and method rows).
    """
    root = Path(root)
    meta = read_paper_meta(root)
    robot = meta["robot"]
    b = meta["budgets"]
    paper = paper_results()
    S = {k: study_stats(root / k) for k in meta["studies"]}
    table: dict[str, dict[str, Any]] = {}
    for g in GAITS:
        pr = paper_row(robot, g)
        main, hills, cross = f"{robot}-{g}", f"{robot}-{g}-hills", f"{robot}-{g}-cross"
        table[g] = {
            "manual": _cell(S, main, "manual", pr.get("manual")),
            "phase1": _cell(S, main, "phase1", pr.get("phase1")),
            "phase3_even": _cell(S, main, "phase3", pr.get("phase3_even")),
            "phase3_uneven": _cell(S, hills, "phase3", pr.get("phase3_uneven")),
            "phase3_cross_task": _cell(S, cross, "phase3", pr.get("phase3_cross_task"),
                                       vae=OTHER_GAIT[g]),
            "manual_on_hills": _cell(S, hills, "manual", None),
        }
    transfer: dict[str, Any] = {}
    if robot == "a1":
        ptr = paper.get("transfer_A1_trot_vae_to_B1", {})
        for g in GAITS:
            k = f"b1-{g}-transfer"
            s = S.get(k)
            c = _cell(S, k, "phase3", ptr.get(f"B1_{g}_220_evals"))
            transfer[g] = {"study": k, "manual": _cell(S, k, "manual", None)["ours"],
                           "ours": c["ours"], "evals": c["evals"],
                           "stable": None if s is None else s["phase3"]["stable"],
                           "evals_to_beat_manual": None if s is None else
                           s["phase3"]["evals_to_beat_manual"],
                           "paper": c["paper"]}
    pk = f"{robot}-trot-preservation"
    ps = S.get(pk)
    pm = (ps or {}).get("preservation_meta") or {}
    pp = paper.get("vae_stable_preservation", {})
    nk = None if ps is None else ps["preservation"]["stable"]
    nst = pm.get("n_stable")
    preservation = {
        "study": pk, "separate_run_evals": 0 if ps is None else ps["phase1"]["n"],
        "n_stable": nst, "n_kept": nk,
        "n_checked": None if ps is None else ps["preservation"]["n"],
        "paper_stable": pp.get("stable_in_original_space"),
        "paper_kept": pp.get("stable_after_encode_decode"),
        "rate": (nk / nst) if nk is not None and nst else None,
        "paper_rate": (pp["stable_after_encode_decode"] / pp["stable_in_original_space"]
                       if pp else None),
    }
    baselines: dict[str, Any] = {}
    for g in GAITS:
        main = S.get(f"{robot}-{g}")
        man = table[g]["manual"]["ours"]
        rows = {}
        if main is not None:
            rows["latent"] = _baseline_row("phase 3: TuRBO-m in the latent space (ours)",
                                           f"{robot}-{g}", main["phase3"]["costs"],
                                           main["phase3"]["evals_to_beat_manual"])
            prefix = main["phase1"]["costs"][: b["baselines"]]    # fewer at a small scale
            rows["phase1_prefix"] = _baseline_row(
                f"phase 1's first {len(prefix)} evaluations (TuRBO-m on θ, phase-1 settings)",
                f"{robot}-{g}", prefix, main["phase1"]["evals_to_beat_manual"])
        for m in ("turbo", "cma", "random"):
            s = S.get(f"{robot}-{g}-{m}")
            rows[m] = {"label": METHOD_NAME[m], "study": f"{robot}-{g}-{m}",
                       "n": 0 if s is None else s["phase1"]["n"],
                       "best": None if s is None else s["phase1"]["best"],
                       "stable": None if s is None else s["phase1"]["stable"],
                       "evals_to_beat_manual": None if s is None else
                       s["phase1"]["evals_to_beat_manual"]}
        baselines[g] = {"manual": man, "rows": rows}
    seeded = seeded_stats(meta, S)
    for g in GAITS:
        for key, row in (("phase3_even", g), ("phase3_uneven", f"{g}-hills"),
                         ("phase3_cross_task", f"{g}-cross")):
            _add_spread(table[g][key], seeded.get(row))
        if g in transfer:
            _add_spread(transfer[g], seeded.get(f"b1-{g}"))
    return {"root": root, "meta": meta, "robot": robot, "R": PAPER_ROBOT.get(robot, robot),
            "budgets": b, "paper": paper, "studies": S, "table": table, "transfer": transfer,
            "preservation": preservation, "baselines": baselines, "seeded": seeded}


# ---------------------------------------------------------------------------- seeds
def spread(values: list[float]) -> dict[str, Any]:
    """Median and interquartile range of per-seed values (``inf`` = never reached):
    ``{"median", "q25", "q75", "n", "reached"}`` (None for no values)."""
    v = np.asarray([np.inf if x is None else float(x) for x in values], dtype=float)
    if v.size == 0:
        return {"median": None, "q25": None, "q75": None, "n": 0, "reached": 0}
    # linear interpolation between seeds; with a seed that never reached (inf) the quantiles
    # are seeds' values (inverted CDF), so a quantile is "never" only if that share never did
    how = "linear" if np.all(np.isfinite(v)) else "inverted_cdf"
    q25, med, q75 = (float(x) for x in np.percentile(v, [25, 50, 75], method=how))
    return {"median": med, "q25": q25, "q75": q75, "n": int(v.size),
            "reached": int(np.isfinite(v).sum())}


def _first_reach(costs: list[float], level: float | None) -> float:
    """1-based evaluation of the first cost <= ``level`` (inf when none; None level: inf)."""
    if level is None:
        return math.inf
    hit = np.flatnonzero(np.asarray(costs, dtype=float) <= float(level))
    return float(hit[0] + 1) if hit.size else math.inf


def seeded_stats(meta: dict[str, Any], S: dict[str, Any]) -> dict[str, Any]:
    """The seeded comparisons: row → ``label``, ``manual`` (the target's manual θ cost),
    ``zero_shot`` (the source's best θ on the target, None on its own task), ``phase1`` (own
    and cross rows: the direct phase-1 run on the target: ``n``, ``best``, ``costs``) and
    ``arms``: arm → ``studies``, ``seeds`` (indices), ``traces`` (each seed's costs on the
    target in evaluation order: phase 3's for phase-3 arms, phase 1's for baselines) and
    spreads over the seeds (:func:`spread`) of ``best``, ``evals``, ``falls_per_100``,
    ``to_manual`` (evaluations to a cost strictly below the manual θ's), ``to_zero_shot``,
    ``to_level`` (to a cost <= ``level``: the lowest median best of the baselines). Empty for a
    directory written before seeds were recorded."""
    robot = meta.get("robot")
    rows: dict[str, Any] = {}
    for key, info in meta.get("studies", {}).items():
        row, arm, s = info.get("row"), info.get("arm"), S.get(key)
        if row is None or arm is None:
            continue
        r = rows.setdefault(row, {"label": _row_label(robot, row), "arms": {}, "manual": None,
                                  "zero_shot": None, "phase1": None})
        a = r["arms"].setdefault(arm, {"label": _arm_label(arm, row), "studies": [], "seeds": [],
                                       "traces": []})
        if s is None:
            continue
        trace = s["phase3" if info["kind"] in ("tune", "phase3") else "phase1"]["costs"]
        if not trace:
            continue
        a["studies"].append(key)
        a["seeds"].append(int(info.get("seed_index", 0)))
        a["traces"].append(trace)
        if arm == "phase3-transfer":
            a.setdefault("options", []).append(s.get("phase3_options"))
        if r["manual"] is None and s["manual"]["best"] is not None:
            r["manual"] = s["manual"]["best"]
        if r["zero_shot"] is None and s["zero_shot"]["best"] is not None and \
                info["kind"] == "phase3" and row != info.get("gait"):
            r["zero_shot"] = s["zero_shot"]["best"]
    for row, r in rows.items():
        g = row.split("-")[-1] if row.startswith("b1-") else row.split("-")[0]
        direct = S.get(f"{robot}-{g}") if not row.startswith("b1-") and \
            not row.endswith("-hills") else None
        if direct is not None and direct["phase1"]["n"]:
            r["phase1"] = {"study": f"{robot}-{g}", "n": direct["phase1"]["n"],
                           "best": direct["phase1"]["best"], "costs": direct["phase1"]["costs"]}
        for a in r["arms"].values():
            tr = a["traces"]
            a["best"] = spread([min(t) for t in tr])
            a["evals"] = spread([len(t) for t in tr])
            a["falls_per_100"] = spread([100.0 * float(np.sum(np.asarray(t) >= C1)) / len(t)
                                         for t in tr])
            a["to_manual"] = spread([evals_to_beat(t, r["manual"]) or math.inf for t in tr])
            a["to_zero_shot"] = spread([evals_to_beat(t, r["zero_shot"]) or math.inf
                                        for t in tr]) if r["zero_shot"] is not None else None
        meds = [a["best"]["median"] for k, a in r["arms"].items()
                if k in BASELINE_ARMS and a["best"]["median"] is not None]
        r["level"] = min(meds) if meds else None
        for a in r["arms"].values():
            a["to_level"] = spread([_first_reach(t, r["level"]) for t in a["traces"]])
        if r["phase1"] is not None:
            p3 = r["arms"].get("phase3-plain", {}).get("best", {}).get("median")
            r["phase1"]["to_phase3_median"] = None if p3 is None else \
                _first_reach(r["phase1"]["costs"], p3)
    return rows


def _row_label(robot: str, row: str) -> str:
    R = PAPER_ROBOT.get(robot, robot)
    if row.startswith("b1-"):
        return f"B1 {row[3:]} from the {R} trot source (cross-robot)"
    g, _, rest = row.partition("-")
    if rest == "hills":
        return f"{R} {g} on hills from the {R} {g} source (flat)"
    if rest == "cross":
        return f"{R} {g} from the {R} {OTHER_GAIT[g]} source (cross-task)"
    return f"{R} {g} (flat) from its own phase 1"


def _arm_label(arm: str, row: str) -> str:
    own = "-" not in row
    if arm in BASELINE_ARMS:
        start = "manual θ" if own else "zero-shot θ"
        if arm == "cmaes-src":
            return f"{ARMS[arm]} (source's trials, from the {start})"
        return f"{ARMS[arm]} from the {start}"
    return ARMS.get(arm, arm)


def _add_spread(cell: dict[str, Any], row: dict[str, Any] | None) -> None:
    """Add the plain phase 3's spread over seeds to a Table II/III or transfer cell (with two or
    more seeds)."""
    arm = (row or {}).get("arms", {}).get("phase3-plain")
    if arm and arm["best"]["n"] >= 2:
        cell["seeds"] = arm["best"]


# ---------------------------------------------------------------------------- claims
def _lt(a: float | None, c: float | None) -> bool | None:
    return None if a is None or c is None else bool(a < c)


def check_claims(nums: dict[str, Any]) -> list[Claim]:
    """The paper's qualitative claims checked against :func:`compute`'s numbers."""
    robot, R, S = nums["robot"], nums["R"], nums["studies"]
    table, preservation = nums["table"], nums["preservation"]
    claims: list[Claim] = []
    for g in GAITS:
        t = table[g]
        for ph, name in (("phase1", "phase 1"), ("phase3_even", "phase 3 (flat)")):
            claims.append((f"{R} {g}: {name} beats the manual θ", _lt(t[ph]["ours"], t["manual"]["ours"]),
                           f"{fmt(t[ph]['ours'])} vs manual {fmt(t['manual']['ours'])}"))
        for ph, name in (("phase3_uneven", "phase 3 on hills (VAE trained on flat)"),
                         ("phase3_cross_task", f"phase 3 cross-task ({OTHER_GAIT[g]} VAE)")):
            v = t[ph]["ours"]
            claims.append((f"{R} {g}: {name} finds a stable θ (cost < {C1:g})", _lt(v, C1),
                           f"best {fmt(v)}"))
    for g, tr in nums["transfer"].items():
        claims.append((f"A1 → B1 transfer, B1 {g}: phase 3 with the A1 trot VAE finds a stable θ",
                       _lt(tr["ours"], C1), f"best {fmt(tr['ours'])} (B1 manual {fmt(tr['manual'])})"))
    cj, mj = S.get(f"{robot}-jump-cross"), S.get(f"{robot}-jump")
    if cj is not None and mj is not None:
        e3, e1 = cj["phase3"]["evals_to_beat_manual"], mj["phase1"]["evals_to_beat_manual"]
        tc = nums["paper"].get("text_claims", {})
        claims.append((f"{R} jump with the trot VAE beats the manual θ within its "
                       f"{cj['phase3']['n']}-evaluation budget (paper: "
                       f"{tc.get('jump_with_trot_vae_evals', '< 200')} evaluations, vs "
                       f"~{tc.get('jump_direct_phase1_evals_to_improve', 2000)} for phase 1)",
                       None if cj["phase3"]["n"] == 0 else e3 is not None,
                       f"first strictly better than manual after {fmt(e3)} evaluations "
                       f"(phase 1 on θ: {fmt(e1)} of {mj['phase1']['n']})"))
    for g in GAITS:
        r = nums.get("seeded", {}).get(g)
        p3 = (r or {}).get("arms", {}).get("phase3-plain", {}).get("best")
        if r is None or r["phase1"] is None or p3 is None or p3["n"] < 2:
            continue
        p1 = r["phase1"]["best"]
        claims.append((f"{R} {g}: phase 3's median best at {nums['budgets']['phase3']} "
                       f"evaluations is within the seeds' spread of phase 1's best at "
                       f"{r['phase1']['n']} (or below it)", bool(p3["median"] <= p1 or
                                                                  p3["q25"] <= p1 <= p3["q75"]),
                       f"phase 3 {_spread_txt(p3)} over {p3['n']} seeds vs phase 1 {fmt(p1)}"))
    rate, nk, nst = preservation["rate"], preservation["n_kept"], preservation["n_stable"]
    claims.append(("VAE stable-preservation rate ≥ 95 %",
                   None if rate is None else bool(rate >= 0.95),
                   "–" if rate is None else f"{nk}/{nst} = {100 * rate:.1f} % "
                   f"(paper {preservation['paper_kept']}/{preservation['paper_stable']})"))
    for g in GAITS:
        rows = nums["baselines"][g]["rows"]
        lat = rows.get("latent", {}).get("best")
        others = [rows[m]["best"] for m in ("turbo", "cma", "random")
                  if rows.get(m, {}).get("best") is not None]
        ok = None if lat is None or not others else bool(lat < min(others))
        claims.append((f"{R} {g}: phase 3 beats TuRBO-m/CMA-ES/random on θ at the same budget "
                       "(not a numbered claim of the paper; its motivation)", ok,
                       f"{fmt(lat)} vs best baseline {fmt(min(others) if others else None)}"))
    return claims


# ---------------------------------------------------------------------------- figures
_WORLDS: dict[tuple, Any] = {}


def _task(cfg: dict[str, Any]):
    """The Task of a stored config. PyBullet worlds are shared between tasks of the same robot,
    terrain, seed, engine and reality (:meth:`Task.world_key`; the world does not depend on the
    gait, and building one takes seconds)."""
    task = task_from_config(cfg)
    key = task.world_key()
    if key in _WORLDS:
        task.use_world(_WORLDS[key])
    else:
        _WORLDS[key] = task.world
    return task


def _best_cost_panels(nums: dict[str, Any], g: str) -> list:
    """Gait ``g``'s best-cost panels: phase 1 on its own axis, the phase-3-budget studies on
    another (both with the flat manual θ's cost as reference)."""
    from latentune.reporting.plots import CurvePanel

    robot, S, b = nums["robot"], nums["studies"], nums["budgets"]
    refs = {"manual θ (flat)": nums["table"][g]["manual"]["ours"]}
    p1: dict[str, Any] = {}
    p3: dict[str, Any] = {}
    main = S.get(f"{robot}-{g}")
    if main is not None:
        p1["phase 1 (TuRBO-m on θ)"] = main["phase1"]["costs"]
        p3["phase 3 flat (latent)"] = main["phase3"]["costs"]
    for key, lab, ph in ((f"{robot}-{g}-hills", "phase 3 hills (latent)", "phase3"),
                         (f"{robot}-{g}-cross", f"phase 3 cross-task ({OTHER_GAIT[g]} VAE)", "phase3"),
                         (f"{robot}-{g}-turbo", "TuRBO-m on θ (phase-3 budget)", "phase1"),
                         (f"{robot}-{g}-cma", "CMA-ES on θ", "phase1"),
                         (f"{robot}-{g}-random", "random on θ", "phase1")):
        s = S.get(key)
        if s is not None:
            p3[lab] = s[ph]["costs"]
    return [CurvePanel(f"phase 1 ({b['phase1']} evaluations)", p1, refs),
            CurvePanel(f"phase-3 budget ({b['phase3']} evaluations)", p3, refs)]


def make_figures(nums: dict[str, Any], simulate: bool = True, gifs: bool = True,
                 log: Callable[[str], None] = lambda m: None) -> dict[str, Any]:
    """Write the report's figures into ``nums["root"]``.

    Always: ``best_so_far_<gait>.png``, ``best_so_far_transfer.png`` (A1), ``cost_transform.png``.
    With ``simulate``: ``com_velocity_<gait>.png`` (the best θ of manual / phase 1 / phase 3
    re-simulated) and, with ``gifs``, GIFs of the best phase-3 θ. A figure or GIF of an earlier
    report that this one does not write (``simulate`` or ``gifs`` off, a study gone) is
    removed. Returns ``figs`` and ``gifs`` (lists of (file name, caption)) and ``resim`` (gait →
    label → re-simulated cost).
    """
    from latentune.reporting.plots import (CurvePanel, plot_best_so_far, plot_cost_transform,
                                           plot_rollouts)

    root, robot, R, S = nums["root"], nums["robot"], nums["R"], nums["studies"]
    transfer = nums["transfer"]
    figs: list[tuple[str, str]] = []
    for g in GAITS:
        panels = _best_cost_panels(nums, g)
        if any(len(v) for p in panels for v in p.curves.values()):
            fn = f"best_so_far_{g}.png"
            plot_best_so_far(panels, root / fn, title=f"{R} {g}: best path cost so far")
            figs.append((fn, f"{R} {g}: best path cost so far (all studies; manual θ dashed)"))
    if transfer:
        panels = [CurvePanel(f"B1 {g} (A1 trot VAE)",
                             {f"B1 {g} (A1 trot VAE)": S[tr["study"]]["phase3"]["costs"]},
                             {"B1 manual θ": tr["manual"]})
                  for g, tr in transfer.items() if S.get(tr["study"])]
        if any(len(v) for p in panels for v in p.curves.values()):
            plot_best_so_far(panels, root / "best_so_far_transfer.png",
                             title="A1 → B1 transfer: phase 3 with the A1 trot VAE")
            figs.append(("best_so_far_transfer.png", "A1 → B1 transfer: best cost so far"))
    main_trot = S.get(f"{robot}-trot")
    if main_trot is not None and main_trot["phase1"]["n"] > 1:
        try:
            plot_cost_transform(main_trot["phase1"]["costs"], root / "cost_transform.png",
                                f"{R} trot phase 1")
            figs.append(("cost_transform.png", "what TuRBO-m's GP sees: the rank-based Gaussian "
                         "copula of the path cost (phase 1, A1 trot)"
                         if robot == "a1" else "the GP's copula transform of the path cost"))
        except Exception as exc:  # noqa: BLE001 - a figure must not sink the report
            logger.warning("cost-transform figure skipped: %s", exc)
    for row, r in nums["seeded"].items():
        if any(a["traces"] for a in r["arms"].values()):
            fn = f"seeds_{row}.png"
            plot_seed_bands(r, root / fn)
            figs.append((fn, f"{r['label']}: best cost so far, median over the seeds with the "
                         "interquartile band"))
    resim: dict[str, Any] = {}
    gif_files: list[tuple[str, str]] = []
    if simulate:
        for g in GAITS:
            main = S.get(f"{robot}-{g}")
            if main is None:
                continue
            task = _task(main["config"])
            runs = {lab: task.rollout(np.array(main[ph]["theta"]), record=True)
                    for ph, lab in (("manual", "manual"), ("phase1", "phase 1"), ("phase3", "phase 3"))
                    if main[ph]["theta"] is not None}
            resim[g] = {k: v.cost for k, v in runs.items()}
            fn = f"com_velocity_{g}.png"
            plot_rollouts(runs, root / fn, v_des=float(task.v_des[0]),
                          title=f"{R} {g}: CoM velocity, manual vs phase 1 vs phase 3 (flat)")
            figs.append((fn, f"{R} {g}: CoM forward velocity and base height of the best θ "
                         "(re-simulated; costs in the legend)"))
            log(f"report: re-simulated {R} {g}")
        if gifs:
            targets = [(f"{robot}-{g}", f"{robot}_{g}_phase3_best.gif",
                        f"{R} {g}, best phase-3 θ (flat)") for g in GAITS]
            targets += [(f"{robot}-{g}-hills", f"{robot}_{g}_hills_phase3_best.gif",
                         f"{R} {g} on hills, best phase-3 θ") for g in GAITS[:1]]
            targets += [(tr["study"], f"b1_{g}_transfer_best.gif",
                         f"B1 {g}, best θ with the A1 trot VAE") for g, tr in transfer.items()]
            for key, fn, cap in targets:
                s = S.get(key)
                if s is None or s["phase3"]["theta"] is None:
                    continue
                try:
                    _task(s["config"]).rollout(np.array(s["phase3"]["theta"]), gif=str(root / fn),
                                               gif_fps=6)
                    gif_files.append((fn, cap))
                    log(f"report: GIF {fn}")
                except Exception as exc:  # noqa: BLE001 - a GIF must not sink the report
                    logger.warning("GIF %s skipped: %s", fn, exc)
    written = {fn for fn, _ in figs + gif_files}
    for fn in sorted(_figure_names(nums) - written):   # an earlier report's: not referred to
        if (root / fn).is_file():
            (root / fn).unlink()
            log(f"report: removed an earlier report's {fn}")
    return {"figs": figs, "gifs": gif_files, "resim": resim}


def _figure_names(nums: dict[str, Any]) -> set[str]:
    """Every figure and GIF file name :func:`make_figures` may write for ``nums``' robot (with
    or without simulation, whichever studies exist)."""
    robot = nums["robot"]
    names = {"best_so_far_transfer.png", "cost_transform.png"}
    names |= {f"seeds_{row}.png" for row in nums["seeded"]}
    for g in GAITS:
        names |= {f"best_so_far_{g}.png", f"com_velocity_{g}.png", f"{robot}_{g}_phase3_best.gif",
                  f"{robot}_{g}_hills_phase3_best.gif", f"b1_{g}_transfer_best.gif"}
    return names


def band(traces: list[list[float]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best-so-far over seeds: ``(x (m,), median, q25, q75)`` at evaluations 1..m (m: the
    longest trace; at each x, over the seeds whose trace reaches x)."""
    from latentune.reporting.metrics import best_so_far

    m = max(len(t) for t in traces)
    B = np.full((len(traces), m), np.nan)
    for i, t in enumerate(traces):
        B[i, : len(t)] = best_so_far(t)
    q25, med, q75 = np.nanpercentile(B, [25, 50, 75], axis=0)
    return np.arange(1, m + 1), med, q25, q75


def plot_seed_bands(r: dict[str, Any], path: Path) -> None:
    """One row of the seeded comparison (:func:`seeded_stats`): per method, the median
    best-so-far cost against the evaluation number with its interquartile band; the manual θ's
    cost (dashed), the zero-shot θ's (dotted) and the direct phase-1 run's best (dash-dot)."""
    from latentune.reporting.plots import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.0, 5.0))
    lo, hi = [], []
    for j, arm in enumerate(ARM_ORDER):
        a = r["arms"].get(arm)
        if a is None or not a["traces"]:
            continue
        x, med, q25, q75 = band(a["traces"])
        c = f"C{j}"
        ax.plot(x, med, color=c, lw=1.5, drawstyle="steps-post",
                label=f"{a['label']} ({len(a['traces'])} seeds)")
        ax.fill_between(x, q25, q75, color=c, alpha=0.18, step="post", linewidth=0)
        lo.append(float(np.nanmin(q25)))
        hi.append(float(np.nanmax(q75[len(q75) // 10:])))
    refs = (("manual θ", r["manual"], "--"), ("zero-shot θ", r["zero_shot"], ":"),
            ("direct phase 1, best", (r["phase1"] or {}).get("best"), "-."))
    for lab, v, ls in refs:
        if v is not None:
            ax.axhline(v, color="k", ls=ls, lw=1, label=f"{lab} ({v:.3f})")
            lo.append(float(v))
    if lo and hi:
        top = max(min(max(hi), C1), max(lo))
        pad = 0.05 * max(top - min(lo), 1e-6)
        ax.set_ylim(min(lo) - pad, top + pad)
    ax.set_xlabel("evaluations on the target")
    ax.set_ylabel("best path cost so far")
    ax.set_title(r["label"], fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------- outputs
def _walls(nums: dict[str, Any]) -> dict[str, dict[str, float]]:
    return {k: (s or {}).get("wall", {}) for k, s in nums["studies"].items()}


def report_command(nums: dict[str, Any]) -> str:
    """The command that regenerates the report of the paper directory ``nums`` describes
    (:func:`compute`) from its stored runs, its directory quoted for a shell where it needs it."""
    return (f"latentune paper --robot {nums['robot']} --out {shlex.quote(str(nums['root']))} "
            "--report-only")


def summary_json(nums: dict[str, Any], claims: list[Claim], fig: dict[str, Any]) -> dict[str, Any]:
    """The content of ``paper_summary.json`` (JSON-able; wall times in s)."""
    meta, walls = nums["meta"], _walls(nums)
    return {"robot": nums["robot"], "actor": meta.get("actor"), "budgets": nums["budgets"],
            "command": meta.get("command"), "report_command": report_command(nums),
            "steps": meta.get("steps"), "seed": meta.get("seed"),
            "table": nums["table"], "transfer": nums["transfer"],
            "preservation": nums["preservation"], "baselines": nums["baselines"],
            "seeds": meta.get("seeds", 1), "seeded": nums["seeded"],
            "claims": [{"claim": c, "holds": ok, "detail": d} for c, ok, d in claims],
            "resimulated_costs": fig["resim"], "wall_s_invocations": meta.get("wall_s_total"),
            "wall_s_studies": float(sum(sum(w.values()) for w in walls.values())),
            "wall_by_study": walls, "invocations": meta.get("invocations", []),
            "written": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def _pv(v: Any) -> str:
    return "–" if v is None else f"{v:g}"


def _md_header(nums: dict[str, Any]) -> list[str]:
    meta, b, root = nums["meta"], nums["budgets"], nums["root"]
    q = shlex.quote(str(root))                  # the directory as a shell command names it
    inv = meta.get("invocations", [])
    wall_studies = float(sum(sum(w.values()) for w in _walls(nums).values()))
    over = [k for k, v in b.get("overridden", {}).items() if v]
    return [
        f"# latentune paper studies: {nums['R']} ({meta.get('actor')} MPC)", "",
        f"Scale S = {b['scale']:g}: phase 1 {b['phase1']} evaluations per gait, phase 3 "
        f"{b['phase3']} per study, baselines {b['baselines']}, separate preservation run "
        f"{b['preservation']} (the paper: {10000} / {220}). Mapping: `{b['mapping']}`"
        + (f"; overridden: {', '.join(over)}" if over else "") + ".",
        f"Rollouts: {meta.get('steps')} steps at 1 kHz, v_des = {meta.get('v_des')} m/s, "
        f"seed {meta.get('seed')}, {meta.get('workers')} process workers.", "",
        f"Produced by: `{meta.get('command')}`  ",
        f"Every number and figure below is regenerated from the stored runs "
        f"(`{root}/<study>/run.db`) by: `{report_command(nums)}` (or `latentune report {q}`).",
        f"Wall time: {fmt(meta.get('wall_s_total'), 0)} s for the `paper` command(s) "
        f"({len(inv)} invocation(s), excluding this report's re-simulations); "
        f"{wall_studies:.0f} s inside the studies' phases (sum of the stores' wall records).",
        *_md_machines(inv), ""]


def _md_machines(inv: list[dict[str, Any]]) -> list[str]:
    """One line per ``paper`` invocation that recorded its machine and load average."""
    lines = []
    for i in inv:
        m = i.get("machine")
        if not m:
            continue
        load = " → ".join(f"{v[0]:.1f}" for v in (i.get("loadavg_start"), i.get("loadavg_end"))
                          if v)
        cores = m.get("cores", m.get("cpus"))     # "cpus": records made before the key was shared
        lines.append(f"- {i.get('started')}: {cores} cores ({m.get('cpu')}"
                     + (f", {m['simd']}" if m.get("simd") else "") + "), 1-min load average "
                     f"{load or '–'}, {fmt(i.get('wall_s'), 0)} s: `{i.get('command')}`")
    if not lines:
        return []
    n = sum(1 for i in inv if not i.get("machine"))
    return ["", "Machine and load per invocation" + (f" ({n} earlier invocation(s) did not record "
                                                     "them)" if n else "") + ":", *lines]


def _md_table(nums: dict[str, Any]) -> list[str]:
    R, table, seed = nums["R"], nums["table"], nums["meta"].get("seed")
    md = [f"## Table {TABLE_NO.get(nums['robot'], '?')}: path cost of the best θ ({R})", "",
          "Best path cost found (lower is better; ≥ 100 = fell). Ours from the run stores, "
          "the paper's beside it (the paper: 10000 phase-1 / 220 phase-3 evaluations).", "",
          "| | trot: latentune | trot: paper | jump: latentune | jump: paper |",
          "|---|---:|---:|---:|---:|"]
    labels = (("manual", "Manual Tuned"), ("phase1", "Phase 1"),
              ("phase3_even", "Phase 3 even"), ("phase3_uneven", "Phase 3 uneven"),
              ("phase3_cross_task", "Phase 3 cross-task"))
    for key, lab in labels:
        cells = []
        for g in GAITS:
            r = table[g][key]
            extra = f" ({r['evals']} evals)" if key != "manual" and r["evals"] else ""
            if key == "phase3_cross_task":
                extra += f", {r['vae']} VAE" if r["evals"] else ""
            ours = fmt(r["ours"])
            if "seeds" in r:
                ours = f"{_spread_txt(r['seeds'])}, {r['seeds']['n']} seeds"
            cells += [f"{ours}{extra}", _pv(r["paper"])]
        md.append(f"| {lab} | " + " | ".join(cells) + " |")
    if any("seeds" in table[g][k] for g in GAITS for k in table[g]):
        md += ["", "Phase 3 cells: median [interquartile range] over the seeds (see \"Over "
               "the seeds\" below); manual and phase 1 are the source runs, run once."]
    md += [f"| (extra) Manual Tuned on hills | {fmt(table['trot']['manual_on_hills']['ours'])} "
           f"| – | {fmt(table['jump']['manual_on_hills']['ours'])} | – |", "",
           f"Phase 3 uneven: Perlin hills (seed {seed}), latent space trained on flat-ground "
           "phase-1 θ, as in the paper. Cross-task: trot tuned with the jump VAE and jump with "
           "the trot VAE.", ""]
    return md


def _md_transfer(nums: dict[str, Any]) -> list[str]:
    if not nums["transfer"]:
        return []
    md = ["## A1 → B1 transfer (phase 3 on B1 with the A1 trot VAE)", "",
          "| target | B1 manual θ | phase 3, A1 trot VAE: latentune | evals | stable θ "
          "found | evals to beat B1 manual (first strictly lower) | paper (220 evals) |",
          "|---|---:|---:|---:|---:|---:|---:|"]
    for g, tr in nums["transfer"].items():
        ours = fmt(tr["ours"]) if "seeds" not in tr else \
            f"{_spread_txt(tr['seeds'])}, {tr['seeds']['n']} seeds"
        md.append(f"| B1 {g} | {fmt(tr['manual'])} | {ours} | {tr['evals']} | "
                  f"{fmt(tr['stable'])} | {fmt(tr['evals_to_beat_manual'])} | {_pv(tr['paper'])} |")
    return md + [""]


def _md_preservation(nums: dict[str, Any]) -> list[str]:
    p, R, meta = nums["preservation"], nums["R"], nums["meta"]
    rate = p["rate"]
    md = ["## VAE stable-region preservation", "",
          f"A separate TuRBO-m run on θ ({R} trot, seed {meta.get('seed', 0) + 1}, "
          f"{p['separate_run_evals']} evaluations, never used for training) gave "
          f"{fmt(p['n_stable'])} stable θ; each was encoded and decoded by the "
          f"{R} trot VAE and rolled out again.", "",
          "| | stable θ | stable after encode → decode | rate |", "|---|---:|---:|---:|",
          f"| latentune | {fmt(p['n_stable'])} | {fmt(p['n_kept'])} | "
          f"{'–' if rate is None else f'{100 * rate:.1f} %'} |"]
    if p["paper_rate"] is not None:
        md.append(f"| paper | {p['paper_stable']} | {p['paper_kept']} | "
                  f"{100 * p['paper_rate']:.1f} % |")
    return md + [""]


def _md_baselines(nums: dict[str, Any]) -> list[str]:
    b, R, seed = nums["budgets"], nums["R"], nums["meta"].get("seed")
    md = [f"## Baselines at the phase-3 budget ({b['baselines']} evaluations, flat, seed {seed})",
          "", "Same task, seed and batch size; the baselines search the full θ box from the manual "
          "θ (TuRBO-m: first trust region at the manual θ; CMA-ES: mean at the manual θ; "
          "random: the manual θ first). The paper reports no baseline numbers.", ""]
    for g in GAITS:
        bl = nums["baselines"][g]
        md += [f"**{R} {g}** (manual θ: {fmt(bl['manual'])})", "",
               "| method | evaluations | best path cost | stable | evals to beat manual (first "
               "strictly lower) |", "|---|---:|---:|---:|---:|"]
        for key in ("latent", "turbo", "cma", "random", "phase1_prefix"):
            r = bl["rows"].get(key)
            if r is not None:
                md.append(f"| {r['label']} | {r['n']} | {fmt(r['best'])} | "
                          f"{fmt(r['stable'])}/{r['n']} | {fmt(r['evals_to_beat_manual'])} |")
        md.append("")
    return md


def _spread_txt(sp: dict[str, Any] | None, digits: int = 3, evals: bool = False) -> str:
    """``median [q25–q75]`` of a :func:`spread`; for evaluation counts, ``never`` for a
    quantile no seed reached and ``(k/n reached)`` when some seed did not."""
    if sp is None or sp["n"] == 0:
        return "–"

    def one(v: float) -> str:
        if not math.isfinite(v):
            return "never"
        return f"{v:.0f}" if evals else fmt(v, digits)

    txt = f"{one(sp['median'])} [{one(sp['q25'])}–{one(sp['q75'])}]"
    if evals and sp["reached"] < sp["n"]:
        txt += f" ({sp['reached']}/{sp['n']} reached)"
    return txt


ARM_ORDER = ("phase3-plain", "phase3-transfer", "turbo", "cma", "random", "tpe", "cmaes-src")


def _md_seeded(nums: dict[str, Any]) -> list[str]:
    rows, meta, b = nums["seeded"], nums["meta"], nums["budgets"]
    if not rows or not any(a["traces"] for r in rows.values() for a in r["arms"].values()):
        return []
    n = meta.get("seeds", 1)
    s0 = meta.get("seed", 0)
    md = [f"## Over the seeds (median [interquartile range], {n} seed(s))", "",
          f"The sources — each gait's phase-1 run ({b['phase1']} evaluations) and its VAE, and "
          "the preservation run — were run once (seed "
          f"{s0}) and are shared by every seed, as the paper trains its VAE once. Phase 3 (the "
          "paper's plain strategy and latentune's default, transfer), and the baselines were "
          f"repeated with the study seeds {s0}..{s0 + n - 1} on the same target tasks, "
          f"{b['phase3']} evaluations each. Every cell is median [25th–75th percentile] over "
          "the seeds. Evaluations to a level: the first evaluation strictly below the manual / "
          "zero-shot θ's cost, or at or below the level L (the lowest median best cost of the "
          "baselines), counted from each method's first evaluation on the target. Phase-3 "
          "studies on another study's latent space also ran the zero-shot θ (one evaluation, "
          "not counted in their trace); the baselines of a cross-task or cross-robot row start "
          "from it (their first evaluation). Falls: cost ≥ "
          f"{C1:g}.", ""]
    for row, r in rows.items():
        if not any(a["traces"] for a in r["arms"].values()):
            continue
        refs = [f"manual θ {fmt(r['manual'])}"]
        if r["zero_shot"] is not None:
            refs.append(f"zero-shot θ {fmt(r['zero_shot'])}")
        if r["phase1"] is not None:
            refs.append(f"direct phase 1 on this target ({r['phase1']['study']}, one run): best "
                        f"{fmt(r['phase1']['best'])} at {r['phase1']['n']} evaluations")
        if r["level"] is not None:
            refs.append(f"L = {fmt(r['level'])}")
        md += [f"### {r['label']}", "", "; ".join(refs) + ".", "",
               "| method | seeds | evaluations | best cost | evals to beat manual | "
               "evals to beat zero-shot | evals to reach L | falls / 100 trials |",
               "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for arm in ARM_ORDER:
            a = r["arms"].get(arm)
            if a is None:
                continue
            if not a["traces"]:
                md.append(f"| {a['label']} | 0 | not run | – | – | – | – | – |")
                continue
            md.append(f"| {a['label']} | {len(a['traces'])} | {_spread_txt(a['evals'], evals=True)}"
                      f" | {_spread_txt(a['best'])} | {_spread_txt(a['to_manual'], evals=True)} | "
                      f"{_spread_txt(a['to_zero_shot'], evals=True)} | "
                      f"{_spread_txt(a['to_level'], evals=True)} | "
                      f"{_spread_txt(a['falls_per_100'], 1)} |")
        note = _options_note(r["arms"].get("phase3-transfer"))
        if note:
            md += ["", note]
        p1 = r["phase1"]
        if p1 is not None and p1.get("to_phase3_median") is not None:
            v = p1["to_phase3_median"]
            p3 = r["arms"]["phase3-plain"]["best"]
            when = f"never reaches the plain phase 3's median best ({fmt(p3['median'])}) in " \
                f"its {p1['n']} evaluations" if not math.isfinite(v) else \
                f"first reaches the plain phase 3's median best ({fmt(p3['median'])}) after " \
                f"{v:.0f} evaluations"
            md += ["", f"The direct phase-1 run on this target {when}; its best at {p1['n']} "
                   f"evaluations is {fmt(p1['best'])}"
                   + (f", {'inside' if p3['q25'] <= p1['best'] <= p3['q75'] else 'outside'} the "
                      f"phase-3 seeds' interquartile range [{fmt(p3['q25'])}–{fmt(p3['q75'])}]"
                      if p3["n"] >= 2 else "") + "."]
        fn = f"seeds_{row}.png"
        if (nums["root"] / fn).is_file():
            md += ["", f"![{r['label']}: best cost so far over the seeds]({fn})"]
        md.append("")
    return md


def _options_note(arm: dict[str, Any] | None) -> str:
    """A line naming the default arm's seeds whose stored options differ from today's default
    (:func:`latentune.critic.transfer.resolved_options`): a row made before an option existed
    resumes as it ran (:func:`latentune.critic.transfer.stored_options`). Empty when every seed
    ran today's default."""
    from latentune.critic.transfer import resolved_options

    if not arm or not arm.get("options"):
        return ""
    today = resolved_options({})
    groups: dict[str, list[int]] = {}
    for seed, o in zip(arm["seeds"], arm["options"]):
        if o is None:
            continue
        default = {**today, "explore_fall_prob": resolved_options(     # at the row's bound
            {"max_fall_prob": o.get("max_fall_prob", today["max_fall_prob"])})["explore_fall_prob"]}
        diff = ", ".join(f"`{k}={o[k]}` (default {v})" for k, v in default.items()
                         if k in o and o[k] != v)
        if diff:
            groups.setdefault(diff, []).append(seed)
    if not groups:
        return ""
    parts = [f"seed{'s' if len(ss) > 1 else ''} {', '.join(map(str, sorted(ss)))}: {d}"
             for d, ss in groups.items()]
    return ("Not today's default: the default phase 3's rows stored before an option existed "
            "resume with the options they ran with, which differ here: " + "; ".join(parts) + ".")


def _md_images(items: list[tuple[str, str]]) -> list[str]:
    md: list[str] = []
    for fn, cap in items:
        md += [f"![{cap}]({fn})  ", f"*{cap}*", ""]
    return md


def markdown(nums: dict[str, Any], claims: list[Claim], fig: dict[str, Any]) -> str:
    """``report.md`` from :func:`compute`'s numbers, the claims and :func:`make_figures`' output."""
    md = _md_header(nums) + _md_table(nums) + _md_transfer(nums) + _md_preservation(nums)
    md += _md_baselines(nums)
    md += _md_seeded(nums)
    md += ["## Does the paper's shape hold here?", ""]
    for c, ok, d in claims:
        mark = "not run" if ok is None else ("**holds**" if ok else "**does not hold**")
        md.append(f"- {c}: {mark} ({d})")
    seeds = nums["meta"].get("seeds", 1)
    md += ["", ("Caveat: one seed per study" if seeds <= 1 else
                f"Caveat: the claims above read seed 0 ({seeds} seeds: see \"Over the seeds\")")
           + (" and budgets far below the paper's (see the scale above); differences of a few "
              "tenths in path cost are within seed-to-seed noise at these budgets."
              if nums["budgets"]["phase1"] < PAPER_PHASE1 or nums["budgets"]["phase3"] <
              PAPER_PHASE3 else " at the paper's budgets.")
           + " The paper's absolute numbers come from another simulator setup and "
           "MPC implementation (its manual θ costs differ from ours), so compare the shape "
           "(which rows beat which), not the values.", "", "## Figures", ""]
    md += _md_images(fig["figs"])
    if fig["resim"]:
        md += ["Re-simulated costs of the plotted θ (the stored costs are the table's): " +
               "; ".join(f"{g}: " + ", ".join(f"{k} {v:.3f}" for k, v in r.items())
                         for g, r in fig["resim"].items()) + ".", ""]
    md += _md_images(fig["gifs"])
    md += ["## Studies (run directories)", "",
           "| study | what | evaluations (manual / phase 1 / phase 3) | wall [s] |",
           "|---|---|---:|---:|"]
    for k, info in nums["meta"]["studies"].items():
        s = nums["studies"].get(k)
        if s is None:
            md.append(f"| {k} | {info.get('label')} | not run | – |")
        else:
            md.append(f"| {k} | {info.get('label')} | {s['manual']['n']} / {s['phase1']['n']} / "
                      f"{s['phase3']['n']} | {sum(s['wall'].values()):.0f} |")
    return "\n".join(md + [""]) + "\n"


def write_paper_report(root: str | Path, simulate: bool = True, gifs: bool = True,
                       log: Callable[[str], None] | None = None) -> str:
    """Write ``root/report.md``, ``root/paper_summary.json`` and the figures (GIFs and CoM
    figures only with ``simulate``; GIFs only with ``gifs`` too); return the Markdown.
    Progress messages go to ``log`` (default: this module's logger at INFO level). A
    directory that cannot be written (read-only media) is a UsageError before anything is
    written."""
    log = log or logger.info
    if os.path.isdir(root) and not os.access(root, os.W_OK):   # a missing one: compute says
        raise UsageError(f"{root} cannot be written (read-only): copy the paper directory to "
                         "a writable directory and report the copy")
    nums = compute(root)
    claims = check_claims(nums)
    fig = make_figures(nums, simulate=simulate, gifs=gifs, log=log)
    root = nums["root"]
    write_atomic(root / "paper_summary.json",
                 json.dumps(summary_json(nums, claims, fig), indent=1, default=float))
    text = markdown(nums, claims, fig)
    write_atomic(root / "report.md", text)
    return text
