"""``latentune report DIR``: comparison table, best-cost curves and CoM plots of a run.

The run store (``DIR/run.db``) is the single source of truth: every number comes from its rows;
the CoM-velocity figure re-simulates the stored best θ of each phase (and the manual θ) with
``record=True``. Writes ``DIR/report.md``, ``DIR/best_so_far.png``, ``DIR/com_velocity.png`` and
refreshes ``DIR/summary.json``. The paper's reported numbers (``../shared/paper/results.json``
when present) are printed beside latentune's own, never instead of them.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from latentune.task import C1  # the fall threshold, defined once with the path cost
_PHASES = ((0, "manual tuned"), (1, "phase 1 (θ, TuRBO-m)"), (3, "phase 3 (latent, TuRBO-m)"))


def _paper_numbers(cfg: dict[str, Any]) -> dict[str, float] | None:
    here = Path(__file__).resolve()
    for base in here.parents:
        p = base / "shared" / "paper" / "results.json"
        if p.is_file():
            break
    else:
        return None
    try:
        data = json.loads(p.read_text())
        names = {"a1": "A1", "solo12": "Solo12", "b1": "B1"}
        t = cfg.get("task", {})
        robot = names.get(str(t.get("robot", "")).lower())
        row = data["path_cost"][robot][t.get("gait")]
        key = "phase3_even" if t.get("terrain") == "flat" else "phase3_uneven"
        return {"manual": row.get("manual"), "phase1": row.get("phase1"), "phase3": row.get(key)}
    except Exception:  # noqa: BLE001 - reference numbers are optional
        return None


def _phase_stats(store: Any, phase: int) -> dict[str, Any]:
    y = store.costs(phase)
    if y.size == 0:
        return {"n": 0, "best": None, "stable": 0, "first_below": None}
    return {"n": int(y.size), "best": float(np.min(y)), "stable": int(np.sum(y < C1)),
            "best_idx": int(np.argmin(y))}


def evals_to_reach(costs: np.ndarray, target: float) -> int | None:
    """Number of evaluations until the best cost so far is ≤ target (None if never)."""
    hit = np.flatnonzero(np.asarray(costs, dtype=float) <= target)
    return int(hit[0]) + 1 if hit.size else None


def comparison_table(store: Any) -> str:
    """The manual / phase 1 / phase 3 table (Markdown) from the store."""
    cfg = store.get_meta("config") or {}
    t = cfg.get("task", {})
    manual = _phase_stats(store, 0)["best"]
    lines = [f"{t.get('robot', '?')} {t.get('gait', '?')} on {t.get('terrain', '?')} "
             f"[{t.get('actor', '?')}], {t.get('steps', '?')} steps, v_des {t.get('v_des', '?')}",
             "",
             "| | best path cost | evaluations | stable | evals to reach manual |",
             "|---|---:|---:|---:|---:|"]
    paper = _paper_numbers(cfg)
    for phase, label in _PHASES:
        s = _phase_stats(store, phase)
        if s["n"] == 0:
            lines.append(f"| {label} | – | 0 | – | – |")
            continue
        reach = "–"
        if phase != 0 and manual is not None:
            r = evals_to_reach(store.costs(phase), manual)
            reach = str(r) if r is not None else "not reached"
        lines.append(f"| {label} | {s['best']:.3f} | {s['n']} | {s['stable']}/{s['n']} | {reach} |")
    if paper and any(v is not None for v in paper.values()):
        lines.append("")
        lines.append("paper (Sarmadi et al., 10000 phase-1 evaluations): manual "
                     f"{paper['manual']}, phase 1 {paper['phase1']}, phase 3 {paper['phase3']}")
    return "\n".join(lines)


def write_summary(store: Any, wall_this: float | None = None) -> dict[str, Any]:
    """Write ``DIR/summary.json`` from the store and return it."""
    cfg = store.get_meta("config") or {}
    wall = store.get_meta("wall", {}) or {}
    p0, p1, p3 = (_phase_stats(store, ph) for ph in (0, 1, 3))
    arts = store.get_meta("artifacts", {}) or {}
    manual = p0["best"]
    summary = {
        "manual_cost": manual,
        "phase1_best": p1["best"],
        "phase3_best": p3["best"],
        "phase1_evals": p1["n"],
        "phase3_evals": p3["n"],
        "phase1_stable": p1["stable"],
        "phase3_stable": p3["stable"],
        "phase1_evals_to_manual": evals_to_reach(store.costs(1), manual) if manual else None,
        "phase3_evals_to_manual": evals_to_reach(store.costs(3), manual) if manual else None,
        "phase3_vs_phase1": (p3["best"] / p1["best"]) if p1["best"] and p3["best"] else None,
        "wall_s": float(sum(wall.values())),
        "wall_by_phase_s": wall,
        "wall_s_this_command": wall_this,
        "seed": cfg.get("phase1", cfg.get("phase3", {})).get("seed", cfg.get("task", {}).get("seed")),
        "config": cfg,
        "phase1_best_params": arts.get("phase1_best"),
        "phase3_best_params": arts.get("phase3_best"),
        "artifacts": arts,
        "paper": _paper_numbers(cfg),
        "written": time.time(),
    }
    path = store.dir / "summary.json"
    path.write_text(json.dumps(summary, indent=1, default=float))
    return summary


def _task_from_config(cfg: dict[str, Any]):
    from latentune.task import Task

    t = cfg["task"]
    return Task(robot=t["robot"], gait=t["gait"], terrain=t["terrain"], actor=t["actor"],
                v_des=tuple(t["v_des"]), steps=int(t["steps"]), seed=int(t["seed"]))


def make_report(store: Any, simulate: bool = True, quiet: bool = False) -> str:
    """Write the report files of a run directory; return the Markdown text."""
    from latentune.plots import plot_best_so_far, plot_rollouts

    cfg = store.get_meta("config") or {}
    t = cfg.get("task", {})
    title = f"{t.get('robot', '?')} {t.get('gait', '?')} ({t.get('terrain', '?')}, {t.get('actor', '?')})"
    out = store.dir
    manual = _phase_stats(store, 0)["best"]
    curves = {label: store.costs(ph) for ph, label in _PHASES[1:] if store.count(ph)}
    figs = []
    if curves:
        plot_best_so_far(curves, str(out / "best_so_far.png"), title=title, manual=manual)
        store.add_artifact("best_so_far_png", out / "best_so_far.png")
        figs.append("best_so_far.png")
    if simulate and "task" in cfg:
        task = _task_from_config(cfg)
        runs = {}
        for ph, label in _PHASES:
            b = store.best(ph)
            if b is not None:
                runs[f"{label}"] = task.rollout(b.theta, record=True)
        if runs:
            plot_rollouts(runs, str(out / "com_velocity.png"), v_des=float(task.v_des[0]),
                          title=title)
            store.add_artifact("com_velocity_png", out / "com_velocity.png")
            figs.append("com_velocity.png")
    summary = write_summary(store)
    table = comparison_table(store)
    lat = cfg.get("latent") or cfg.get("vae") or {}
    md = [f"# latentune run: {title}", "", table, ""]
    if lat:
        md.append(f"Latent space: kind {lat.get('kind')}, d_low {lat.get('d_low')}, trained on "
                  f"{lat.get('n_train')} stable θ; box: {lat.get('box_rule')}.")
        src = cfg.get("phase3_vae_source")
        if src and src != "self":
            md.append(f"Phase 3 used the VAE of {src} ({lat.get('from')}).")
        md.append("")
    wall = summary.get("wall_by_phase_s") or {}
    if wall:
        md.append("Wall time: " + ", ".join(f"{k} {v:.0f} s" for k, v in wall.items()) + ".")
        md.append("")
    for f in figs:
        md.append(f"![{f}]({f})")
    text = "\n".join(md) + "\n"
    (out / "report.md").write_text(text)
    store.add_artifact("report_md", out / "report.md")
    return table
