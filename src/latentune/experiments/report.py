"""The report of a ``latentune paper`` directory: ``DIR/report.md``, ``DIR/paper_summary.json``,
figures (PNG) and GIFs, every number read from the studies' run stores (``DIR/<study>/run.db``).

Layout (the paper's): Table II (A1) / Table III (Solo12) with the rows Manual Tuned, Phase 1,
Phase 3 even, Phase 3 uneven, Phase 3 cross-task and, per gait, latentune's best path cost beside
the paper's; then A1 → B1 transfer, the VAE stable-preservation rate, the baselines at the
phase-3 budget, the paper's qualitative claims checked one by one, and the figures. The paper's
numbers (``shared/paper/results.json``) are printed beside ours, never instead of them.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from latentune.task import C1  # the fall threshold, defined once with the path cost
ROBOT_NAME = {"a1": "A1", "b1": "B1", "solo12": "Solo12"}
TABLE_NO = {"a1": "II", "solo12": "III"}
METHOD_NAME = {"turbo": "TuRBO-m on θ (full space)", "cma": "CMA-ES on θ",
               "random": "random search on θ"}


def paper_results() -> dict[str, Any] | None:
    """The paper's numbers (``shared/paper/results.json`` above this file), or None."""
    here = Path(__file__).resolve()
    for base in here.parents:
        p = base / "shared" / "paper" / "results.json"
        if p.is_file():
            try:
                return json.loads(p.read_text())
            except (OSError, json.JSONDecodeError):
                return None
    return None


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{float(v):.{nd}f}"


def _reach(costs: np.ndarray, target: float | None) -> int | None:
    if target is None or costs.size == 0:
        return None
    hit = np.flatnonzero(costs < target)
    return int(hit[0]) + 1 if hit.size else None


def study_stats(run_dir: Path) -> dict[str, Any] | None:
    """Numbers of one study from its store (None if it was not run)."""
    from latentune.pipeline.store import RunStore

    if not (run_dir / "run.db").is_file():
        return None
    with RunStore(run_dir) as st:
        out: dict[str, Any] = {"dir": run_dir.name, "config": st.get_meta("config") or {},
                               "wall": st.get_meta("wall", {}) or {}}
        for ph, name in ((0, "manual"), (1, "phase1"), (3, "phase3"), (5, "preservation")):
            y = st.costs(ph)
            b = st.best(ph)
            out[name] = {"n": int(y.size),
                         "best": float(np.min(y)) if y.size else None,
                         "best_idx": None if b is None else int(b.idx),
                         "stable": int(np.sum(y < C1)),
                         "theta": None if b is None else b.theta.tolist(),
                         "costs": y.tolist()}
        out["preservation_meta"] = st.get_meta("preservation")
    man = out["manual"]["best"]
    for name in ("phase1", "phase3"):
        out[name]["evals_to_manual"] = _reach(np.array(out[name]["costs"]), man)
    return out


_WORLDS: dict[tuple, Any] = {}


def _task(cfg: dict[str, Any]):
    """The Task of a stored config. PyBullet worlds are shared between tasks of the same robot,
    terrain and seed (the world does not depend on the gait; building a B1 world takes ~10 s)."""
    from latentune.task import Task

    t = cfg["task"]
    task = Task(robot=t["robot"], gait=t["gait"], terrain=t["terrain"], actor=t["actor"],
                v_des=tuple(t["v_des"]), steps=int(t["steps"]), seed=int(t["seed"]))
    key = (t["robot"], t["terrain"], int(t["seed"]))
    if key in _WORLDS:
        task._world = _WORLDS[key]
    else:
        _WORLDS[key] = task.world
    return task


def _paper_rows(paper: dict[str, Any] | None, robot: str, gait: str) -> dict[str, Any]:
    try:
        return paper["path_cost"][ROBOT_NAME[robot]][gait]  # type: ignore[index]
    except (KeyError, TypeError):
        return {}


def write_paper_report(root: str | Path, simulate: bool = True, gifs: bool = True,
                       log: Callable[[str], None] | None = None) -> str:
    """Write ``DIR/report.md`` (+ figures, ``paper_summary.json``); return the Markdown."""
    log = log or (lambda m: None)
    root = Path(root)
    meta = json.loads((root / "paper.json").read_text())
    robot = meta["robot"]
    R = ROBOT_NAME.get(robot, robot)
    b = meta["budgets"]
    paper = paper_results()
    studies = meta["studies"]
    S = {k: study_stats(root / k) for k in studies}
    gaits = ("trot", "jump")
    other = {"trot": "jump", "jump": "trot"}

    def best(key: str, phase: str) -> float | None:
        s = S.get(key)
        return None if s is None else s[phase]["best"]

    def nev(key: str, phase: str) -> int:
        s = S.get(key)
        return 0 if s is None else s[phase]["n"]

    # ------------------------------------------------------------------ numbers
    table: dict[str, dict[str, Any]] = {}
    for g in gaits:
        pr = _paper_rows(paper, robot, g)
        table[g] = {
            "manual": {"ours": best(f"{robot}-{g}", "manual"), "paper": pr.get("manual"),
                       "evals": nev(f"{robot}-{g}", "manual"), "study": f"{robot}-{g}"},
            "phase1": {"ours": best(f"{robot}-{g}", "phase1"), "paper": pr.get("phase1"),
                       "evals": nev(f"{robot}-{g}", "phase1"), "study": f"{robot}-{g}"},
            "phase3_even": {"ours": best(f"{robot}-{g}", "phase3"), "paper": pr.get("phase3_even"),
                            "evals": nev(f"{robot}-{g}", "phase3"), "study": f"{robot}-{g}"},
            "phase3_uneven": {"ours": best(f"{robot}-{g}-hills", "phase3"),
                              "paper": pr.get("phase3_uneven"),
                              "evals": nev(f"{robot}-{g}-hills", "phase3"),
                              "study": f"{robot}-{g}-hills"},
            "phase3_cross_task": {"ours": best(f"{robot}-{g}-cross", "phase3"),
                                  "paper": pr.get("phase3_cross_task"),
                                  "evals": nev(f"{robot}-{g}-cross", "phase3"),
                                  "study": f"{robot}-{g}-cross", "vae": other[g]},
            "manual_on_hills": {"ours": best(f"{robot}-{g}-hills", "manual"), "paper": None,
                                "evals": nev(f"{robot}-{g}-hills", "manual"),
                                "study": f"{robot}-{g}-hills"},
        }
    transfer: dict[str, Any] = {}
    if robot == "a1":
        ptr = (paper or {}).get("transfer_A1_trot_vae_to_B1", {})
        for g in gaits:
            k = f"b1-{g}-transfer"
            s = S.get(k)
            transfer[g] = {"study": k, "manual": best(k, "manual"), "ours": best(k, "phase3"),
                           "evals": nev(k, "phase3"),
                           "stable": None if s is None else s["phase3"]["stable"],
                           "evals_to_manual": None if s is None else s["phase3"]["evals_to_manual"],
                           "paper": ptr.get(f"B1_{g}_220_evals")}
    pk = f"{robot}-trot-preservation"
    ps = S.get(pk)
    pm = (ps or {}).get("preservation_meta") or {}
    pp = (paper or {}).get("vae_stable_preservation", {})
    preservation = {
        "study": pk, "separate_run_evals": nev(pk, "phase1"),
        "n_stable": pm.get("n_stable"),
        "n_kept": None if ps is None else ps["preservation"]["stable"],
        "n_checked": None if ps is None else ps["preservation"]["n"],
        "paper_stable": pp.get("stable_in_original_space"),
        "paper_kept": pp.get("stable_after_encode_decode"),
    }
    nk, nst = preservation["n_kept"], preservation["n_stable"]
    preservation["rate"] = (nk / nst) if nk is not None and nst else None
    preservation["paper_rate"] = (pp["stable_after_encode_decode"] / pp["stable_in_original_space"]
                                  if pp else None)
    baselines: dict[str, Any] = {}
    for g in gaits:
        main = S.get(f"{robot}-{g}")
        man = best(f"{robot}-{g}", "manual")
        rows = {}
        if main is not None:
            y3 = np.array(main["phase3"]["costs"])
            rows["latent"] = {"label": "phase 3: TuRBO-m in the latent space (ours)",
                              "study": f"{robot}-{g}", "n": int(y3.size),
                              "best": float(y3.min()) if y3.size else None,
                              "stable": int(np.sum(y3 < C1)), "evals_to_manual": _reach(y3, man)}
            y1 = np.array(main["phase1"]["costs"])[: b["baselines"]]
            rows["phase1_prefix"] = {"label": f"phase 1's first {b['baselines']} evaluations "
                                     "(TuRBO-m on θ, phase-1 settings)", "study": f"{robot}-{g}",
                                     "n": int(y1.size), "best": float(y1.min()) if y1.size else None,
                                     "stable": int(np.sum(y1 < C1)),
                                     "evals_to_manual": _reach(y1, man)}
        for m in ("turbo", "cma", "random"):
            s = S.get(f"{robot}-{g}-{m}")
            if s is None:
                rows[m] = {"label": METHOD_NAME[m], "study": f"{robot}-{g}-{m}", "n": 0,
                           "best": None, "stable": None, "evals_to_manual": None}
                continue
            rows[m] = {"label": METHOD_NAME[m], "study": f"{robot}-{g}-{m}",
                       "n": s["phase1"]["n"], "best": s["phase1"]["best"],
                       "stable": s["phase1"]["stable"],
                       "evals_to_manual": s["phase1"]["evals_to_manual"]}
        baselines[g] = {"manual": man, "rows": rows}

    # ------------------------------------------------------------------ claims
    claims: list[tuple[str, bool | None, str]] = []

    def lt(a, c):
        return None if a is None or c is None else bool(a < c)

    for g in gaits:
        t = table[g]
        for ph, name in (("phase1", "phase 1"), ("phase3_even", "phase 3 (flat)")):
            ok = lt(t[ph]["ours"], t["manual"]["ours"])
            claims.append((f"{R} {g}: {name} beats the manual θ", ok,
                           f"{_fmt(t[ph]['ours'])} vs manual {_fmt(t['manual']['ours'])}"))
        for ph, name in (("phase3_uneven", "phase 3 on hills (VAE trained on flat)"),
                         ("phase3_cross_task", f"phase 3 cross-task ({other[g]} VAE)")):
            v = t[ph]["ours"]
            claims.append((f"{R} {g}: {name} finds a stable θ (cost < {C1:g})", lt(v, C1),
                           f"best {_fmt(v)}"))
    for g, tr in transfer.items():
        claims.append((f"A1 → B1 transfer, B1 {g}: phase 3 with the A1 trot VAE finds a stable θ",
                       lt(tr["ours"], C1), f"best {_fmt(tr['ours'])} (B1 manual {_fmt(tr['manual'])})"))
    cj, mj = S.get(f"{robot}-jump-cross"), S.get(f"{robot}-jump")
    if cj is not None and mj is not None:
        e3, e1 = cj["phase3"]["evals_to_manual"], mj["phase1"]["evals_to_manual"]
        tc = (paper or {}).get("text_claims", {})
        claims.append((f"{R} jump with the trot VAE beats the manual θ within its "
                       f"{cj['phase3']['n']}-evaluation budget (paper: "
                       f"{tc.get('jump_with_trot_vae_evals', '< 200')} evaluations, vs "
                       f"~{tc.get('jump_direct_phase1_evals_to_improve', 2000)} for phase 1)",
                       None if cj["phase3"]["n"] == 0 else e3 is not None,
                       f"first strictly better than manual at evaluation {_fmt(e3)} "
                       f"(phase 1 on θ: {_fmt(e1)} of {mj['phase1']['n']})"))
    rate = preservation["rate"]
    claims.append(("VAE stable-preservation rate ≥ 95 %",
                   None if rate is None else bool(rate >= 0.95),
                   "–" if rate is None else f"{nk}/{nst} = {100 * rate:.1f} % "
                   f"(paper {preservation['paper_kept']}/{preservation['paper_stable']})"))
    for g in gaits:
        rows = baselines[g]["rows"]
        lat = rows.get("latent", {}).get("best")
        others = [rows[m]["best"] for m in ("turbo", "cma", "random") if rows.get(m, {}).get("best")
                  is not None]
        ok = None if lat is None or not others else bool(lat < min(others))
        claims.append((f"{R} {g}: phase 3 beats TuRBO-m/CMA-ES/random on θ at the same budget "
                       "(not a numbered claim of the paper; its motivation)", ok,
                       f"{_fmt(lat)} vs best baseline {_fmt(min(others) if others else None)}"))

    # ------------------------------------------------------------------ figures
    from latentune.plots import plot_best_so_far, plot_rollouts

    figs: list[tuple[str, str]] = []
    for g in gaits:
        curves = {}
        main = S.get(f"{robot}-{g}")
        if main is not None:
            curves["phase 1 (TuRBO-m on θ)"] = main["phase1"]["costs"]
            curves["phase 3 flat (latent)"] = main["phase3"]["costs"]
        for key, lab in ((f"{robot}-{g}-hills", "phase 3 hills (latent)"),
                         (f"{robot}-{g}-cross", f"phase 3 cross-task ({other[g]} VAE)"),
                         (f"{robot}-{g}-turbo", "TuRBO-m on θ (phase-3 budget)"),
                         (f"{robot}-{g}-cma", "CMA-ES on θ"),
                         (f"{robot}-{g}-random", "random on θ")):
            s = S.get(key)
            if s is not None:
                curves[lab] = s["phase3" if "phase 3" in lab else "phase1"]["costs"]
        curves = {k: v for k, v in curves.items() if len(v)}
        if curves:
            fn = f"best_so_far_{g}.png"
            plot_best_so_far(curves, str(root / fn), manual=table[g]["manual"]["ours"],
                             title=f"{R} {g}: best path cost so far")
            figs.append((fn, f"{R} {g}: best path cost so far (all studies; manual θ dashed)"))
    if transfer:
        curves = {f"B1 {g} (A1 trot VAE)": S[tr["study"]]["phase3"]["costs"]
                  for g, tr in transfer.items() if S.get(tr["study"])}
        if curves:
            plot_best_so_far(curves, str(root / "best_so_far_transfer.png"),
                             title="A1 → B1 transfer: phase 3 with the A1 trot VAE")
            figs.append(("best_so_far_transfer.png", "A1 → B1 transfer: best cost so far"))
    main_trot = S.get(f"{robot}-trot")
    if main_trot is not None and main_trot["phase1"]["n"] > 1:
        try:
            _plot_transform(np.array(main_trot["phase1"]["costs"]), root / "cost_transform.png",
                            f"{R} trot phase 1")
            figs.append(("cost_transform.png", "what TuRBO-m's GP sees: the rank-based Gaussian "
                         "copula of the path cost (phase 1, A1 trot)"
                         if robot == "a1" else "the GP's copula transform of the path cost"))
        except Exception as exc:  # noqa: BLE001 - a figure must not sink the report
            log(f"cost-transform figure skipped: {exc}")
    resim: dict[str, Any] = {}
    gif_files: list[tuple[str, str]] = []
    if simulate:
        for g in gaits:
            main = S.get(f"{robot}-{g}")
            if main is None:
                continue
            task = _task(main["config"])
            runs = {}
            for ph, lab in (("manual", "manual"), ("phase1", "phase 1"), ("phase3", "phase 3")):
                th = main[ph]["theta"]
                if th is not None:
                    runs[lab] = task.rollout(np.array(th), record=True)
            resim[g] = {k: v.cost for k, v in runs.items()}
            fn = f"com_velocity_{g}.png"
            plot_rollouts(runs, str(root / fn), v_des=float(task.v_des[0]),
                          title=f"{R} {g}: CoM velocity, manual vs phase 1 vs phase 3 (flat)")
            figs.append((fn, f"{R} {g}: CoM forward velocity and base height of the best θ "
                         "(re-simulated; costs in the legend)"))
            log(f"report: re-simulated {R} {g}")
        if gifs:
            targets = [(f"{robot}-{g}", "phase3", f"{robot}_{g}_phase3_best.gif",
                        f"{R} {g}, best phase-3 θ (flat)") for g in gaits]
            targets += [(f"{robot}-{g}-hills", "phase3", f"{robot}_{g}_hills_phase3_best.gif",
                         f"{R} {g} on hills, best phase-3 θ") for g in gaits[:1]]
            targets += [(tr["study"], "phase3", f"b1_{g}_transfer_best.gif",
                         f"B1 {g}, best θ with the A1 trot VAE") for g, tr in transfer.items()]
            for key, ph, fn, cap in targets:
                s = S.get(key)
                if s is None or s[ph]["theta"] is None:
                    continue
                try:
                    _task(s["config"]).rollout(np.array(s[ph]["theta"]), gif=str(root / fn),
                                               gif_fps=6)
                    gif_files.append((fn, cap))
                    log(f"report: GIF {fn}")
                except Exception as exc:  # noqa: BLE001
                    log(f"GIF {fn} skipped: {exc}")

    # ------------------------------------------------------------------ summary + markdown
    walls = {k: (s or {}).get("wall", {}) for k, s in S.items()}
    wall_studies = float(sum(sum(w.values()) for w in walls.values()))
    inv = meta.get("invocations", [])
    summary = {"robot": robot, "actor": meta.get("actor"), "budgets": b,
               "command": meta.get("command"), "report_command":
                   f"latentune paper --robot {robot} --out {root} --report-only",
               "steps": meta.get("steps"), "seed": meta.get("seed"),
               "table": table, "transfer": transfer, "preservation": preservation,
               "baselines": baselines,
               "claims": [{"claim": c, "holds": ok, "detail": d} for c, ok, d in claims],
               "resimulated_costs": resim, "wall_s_invocations": meta.get("wall_s_total"),
               "wall_s_studies": wall_studies, "wall_by_study": walls, "invocations": inv,
               "written": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    (root / "paper_summary.json").write_text(json.dumps(summary, indent=1, default=float))

    pv = lambda v: "–" if v is None else f"{v:g}"  # noqa: E731
    md: list[str] = []
    md.append(f"# latentune paper studies: {R} ({meta.get('actor')} MPC)")
    md.append("")
    md.append(f"Scale S = {b['scale']:g}: phase 1 {b['phase1']} evaluations per gait, phase 3 "
              f"{b['phase3']} per study, baselines {b['baselines']}, separate preservation run "
              f"{b['preservation']} (the paper: {10000} / {220}). Mapping: `{b['mapping']}`"
              + (f"; overridden: {', '.join(k for k, v in b['overridden'].items() if v)}"
                 if any(b.get("overridden", {}).values()) else "") + ".")
    md.append(f"Rollouts: {meta.get('steps')} steps at 1 kHz, v_des = {meta.get('v_des')} m/s, "
              f"seed {meta.get('seed')}, {meta.get('workers')} process workers.")
    md.append("")
    md.append(f"Produced by: `{meta.get('command')}`  ")
    md.append(f"Every number and figure below is regenerated from the stored runs "
              f"(`{root}/<study>/run.db`) by: `latentune paper --robot {robot} --out {root} "
              f"--report-only` (or `latentune report {root}`).")
    wall_total = meta.get("wall_s_total")
    md.append(f"Wall time: {_fmt(wall_total, 0)} s for the `paper` command(s) "
              f"({len(inv)} invocation(s), excluding this report's re-simulations); "
              f"{wall_studies:.0f} s inside the "
              "studies' phases (sum of the stores' wall records).")
    md.append("")
    md.append(f"## Table {TABLE_NO.get(robot, '?')}: path cost of the best θ ({R})")
    md.append("")
    md.append("Best path cost found (lower is better; ≥ 100 = fell). Ours from the run stores, "
              "the paper's beside it (the paper: 10000 phase-1 / 220 phase-3 evaluations).")
    md.append("")
    md.append("| | trot: latentune | trot: paper | jump: latentune | jump: paper |")
    md.append("|---|---:|---:|---:|---:|")
    labels = (("manual", "Manual Tuned"), ("phase1", "Phase 1"),
              ("phase3_even", "Phase 3 even"), ("phase3_uneven", "Phase 3 uneven"),
              ("phase3_cross_task", "Phase 3 cross-task"))
    for key, lab in labels:
        cells = []
        for g in gaits:
            r = table[g][key]
            extra = f" ({r['evals']} evals)" if key != "manual" and r["evals"] else ""
            if key == "phase3_cross_task":
                extra += f", {r['vae']} VAE" if r["evals"] else ""
            cells += [f"{_fmt(r['ours'])}{extra}", pv(r["paper"])]
        md.append(f"| {lab} | " + " | ".join(cells) + " |")
    md.append(f"| (extra) Manual Tuned on hills | {_fmt(table['trot']['manual_on_hills']['ours'])} "
              f"| – | {_fmt(table['jump']['manual_on_hills']['ours'])} | – |")
    md.append("")
    md.append("Phase 3 uneven: Perlin hills (seed "
              f"{meta.get('seed')}), latent space trained on flat-ground phase-1 θ, as in the paper. "
              "Cross-task: trot tuned with the jump VAE and jump with the trot VAE.")
    md.append("")
    if transfer:
        md.append("## A1 → B1 transfer (phase 3 on B1 with the A1 trot VAE)")
        md.append("")
        md.append("| target | B1 manual θ | phase 3, A1 trot VAE: latentune | evals | stable θ "
                  "found | evals to beat B1 manual (first strictly lower) | paper (220 evals) |")
        md.append("|---|---:|---:|---:|---:|---:|---:|")
        for g, tr in transfer.items():
            md.append(f"| B1 {g} | {_fmt(tr['manual'])} | {_fmt(tr['ours'])} | {tr['evals']} | "
                      f"{_fmt(tr['stable'])} | {_fmt(tr['evals_to_manual'])} | {pv(tr['paper'])} |")
        md.append("")
    md.append("## VAE stable-region preservation")
    md.append("")
    md.append(f"A separate TuRBO-m run on θ ({R} trot, seed {meta.get('seed', 0) + 1}, "
              f"{preservation['separate_run_evals']} evaluations, never used for training) gave "
              f"{_fmt(preservation['n_stable'])} stable θ; each was encoded and decoded by the "
              f"{R} trot VAE and rolled out again.")
    md.append("")
    md.append("| | stable θ | stable after encode → decode | rate |")
    md.append("|---|---:|---:|---:|")
    md.append(f"| latentune | {_fmt(preservation['n_stable'])} | {_fmt(preservation['n_kept'])} | "
              f"{'–' if rate is None else f'{100 * rate:.1f} %'} |")
    if preservation["paper_rate"] is not None:
        md.append(f"| paper | {preservation['paper_stable']} | {preservation['paper_kept']} | "
                  f"{100 * preservation['paper_rate']:.1f} % |")
    md.append("")
    md.append(f"## Baselines at the phase-3 budget ({b['baselines']} evaluations, flat, seed "
              f"{meta.get('seed')})")
    md.append("")
    md.append("Same task, seed and batch size; the baselines search the full θ box from the manual "
              "θ (TuRBO-m: first trust region at the manual θ; CMA-ES: mean at the manual θ; "
              "random: the manual θ first). The paper reports no baseline numbers.")
    md.append("")
    for g in gaits:
        bl = baselines[g]
        md.append(f"**{R} {g}** (manual θ: {_fmt(bl['manual'])})")
        md.append("")
        md.append("| method | evaluations | best path cost | stable | evals to beat manual (first strictly lower) |")
        md.append("|---|---:|---:|---:|---:|")
        for key in ("latent", "turbo", "cma", "random", "phase1_prefix"):
            r = bl["rows"].get(key)
            if r is None:
                continue
            md.append(f"| {r['label']} | {r['n']} | {_fmt(r['best'])} | "
                      f"{_fmt(r['stable'])}/{r['n']} | {_fmt(r['evals_to_manual'])} |")
        md.append("")
    md.append("## Does the paper's shape hold here?")
    md.append("")
    for c, ok, d in claims:
        mark = "not run" if ok is None else ("**holds**" if ok else "**does not hold**")
        md.append(f"- {c}: {mark} ({d})")
    md.append("")
    md.append("Caveat: one seed per study and budgets far below the paper's (see the scale "
              "above); differences of a few tenths in path cost are within seed-to-seed noise at "
              "these budgets. The paper's absolute numbers come from another simulator setup and "
              "MPC implementation (its manual θ costs differ from ours), so compare the shape "
              "(which rows beat which), not the values.")
    md.append("")
    md.append("## Figures")
    md.append("")
    for fn, cap in figs:
        md.append(f"![{cap}]({fn})  ")
        md.append(f"*{cap}*")
        md.append("")
    if resim:
        md.append("Re-simulated costs of the plotted θ (the stored costs are the table's): " +
                  "; ".join(f"{g}: " + ", ".join(f"{k} {v:.3f}" for k, v in r.items())
                            for g, r in resim.items()) + ".")
        md.append("")
    for fn, cap in gif_files:
        md.append(f"![{cap}]({fn})  ")
        md.append(f"*{cap}*")
        md.append("")
    md.append("## Studies (run directories)")
    md.append("")
    md.append("| study | what | evaluations (manual / phase 1 / phase 3) | wall [s] |")
    md.append("|---|---|---:|---:|")
    for k, info in studies.items():
        s = S.get(k)
        if s is None:
            md.append(f"| {k} | {info.get('label')} | not run | – |")
            continue
        md.append(f"| {k} | {info.get('label')} | {s['manual']['n']} / {s['phase1']['n']} / "
                  f"{s['phase3']['n']} | {sum(s['wall'].values()):.0f} |")
    md.append("")
    text = "\n".join(md) + "\n"
    (root / "report.md").write_text(text)
    return text


def _plot_transform(y: np.ndarray, path: Path, title: str) -> None:
    from latentune.critic import gaussian_copula
    from latentune.plots import _plt

    plt = _plt()
    z = gaussian_copula(y)
    fig, ax = plt.subplots(figsize=(6, 4))
    st = y < C1
    ax.scatter(y[st], z[st], s=8, label="stable")
    ax.scatter(y[~st], z[~st], s=8, c="tab:red", label="fell (L ≥ 100)")
    ax.set_xscale("log")
    ax.set_xlabel("path cost L (original)")
    ax.set_ylabel("copula score (what the GP models)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
