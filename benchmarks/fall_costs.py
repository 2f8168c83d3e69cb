"""Phase 1 on user systems whose failed trials are told a *low* cost: does ranking the falls
after every standing trial (the critics' rule since session 48) keep TuRBO-m away from them?

A user system may give a failed trial any cost. A natural one is the cost its rollout had run
up when it failed: a trial that fails at step k of N is told ``(k/N)·c_manual`` (``c_manual``:
the manual θ's cost on the same system, which stands), so the earlier a trial fails, the lower
its cost, and every fall costs less than the manual θ. Three arms per (system, seed), each a
plain ``Study.phase1`` (TuRBO-m, batch 4, the ladder sources' settings) on the model system of
``benchmarks.transfer.SYSTEMS``:

- ``told``: the failed trials flagged (``Outcome.failed``) with their low cost: what latentune
  does now (the critic ranks them after every trial that stood);
- ``hidden``: the same costs, the flag withheld from the loop (kept in the trial's ``info``):
  what the critic did before session 48, when TuRBO-m modelled the costs alone and the flag
  changed nothing in a default phase 1;
- ``convention``: the system as it is, falls at ``100·(2 − k/N)`` or the C1 convention, above
  every standing cost: the reference a user gets by following the README.

Per run: the best cost of a trial that stood within the budget, and the trials that failed.
Per system: medians over seeds, and ``told`` against ``hidden`` paired by seed (wins and a
two-sided sign test on the best standing cost).

    python -m benchmarks.fall_costs run --root runs/fall_costs --seeds 0-9 --evals 300
    python -m benchmarks.fall_costs summary --root runs/fall_costs \\
        --out results/fall_costs/fall_costs.json

``run`` resumes (each run is a study directory). ``summary`` writes the table (``.md``), the
numbers (``.json``) and every run's trace (cost and failed per trial, ``traces.json``). Bad
input is one line on stderr and exit 2."""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import transfer as tr
from latentune.system import Outcome, evaluate

ARMS = ("told", "hidden", "convention")
FELL_KEY = "fell_hidden"
"""``info`` key of a trial that failed while its flag was withheld (arm ``hidden``)."""


def fall_fraction(system: Any, out: Outcome) -> float:
    """k/N of a failed trial (0 = failed at once): from ``info``'s ``fall_step`` and
    ``horizon``, else the system's ``steps``, else the examples' convention
    ``cost = 100·(2 − k/N)``."""
    k = out.info.get("fall_step")
    n = out.info.get("horizon") or getattr(system, "steps", None)
    if k is not None and n:
        return float(np.clip(float(k) / float(n), 0.0, 1.0))
    return float(np.clip(2.0 - float(out.cost) / 100.0, 0.0, 1.0))


class LowFallCost:
    """A system whose failed trials are told ``fall_fraction · c_manual`` (module docstring);
    ``hide=True`` withholds the failed flag (``info[FELL_KEY]`` keeps it)."""

    def __init__(self, inner: Any, c_manual: float, hide: bool) -> None:
        self.inner, self.c_manual, self.hide = inner, float(c_manual), bool(hide)
        self.space = inner.space

    def evaluate(self, theta: np.ndarray) -> Outcome:
        out = evaluate(self.inner, theta)
        if not out.failed:
            return out
        info = {**out.info, "convention_cost": out.cost}
        cost = fall_fraction(self.inner, out) * self.c_manual
        if self.hide:
            return Outcome(cost, False, {**info, FELL_KEY: True})
        return Outcome(cost, True, info)


def manual_cost(system: str) -> float:
    """The manual θ's cost on the model of ``system`` (it must stand)."""
    s = tr.SYSTEMS[system]["model"]()
    out = evaluate(s, s.space.manual)
    if out.failed:
        raise ValueError(f"the manual θ of {system} fails on its model")
    return float(out.cost)


def run_one(root: Path, system: str, arm: str, seed: int, evals: int,
            c_manual: float) -> Path:
    import latentune as lt

    model = tr.SYSTEMS[system]["model"]()
    sysm = model if arm == "convention" else LowFallCost(model, c_manual, hide=arm == "hidden")
    d = root / system / arm / f"seed{seed}"
    with lt.Study(d, seed=seed, batch_size=4) as st:
        st.phase1(sysm, evals)
    return d


def trace(d: Path) -> tuple[list[float], list[bool], list[bool]]:
    """(costs, failed, counted as failed by the loop) of a run's phase 1, in trial order."""
    import latentune as lt
    from latentune.constants import Phase

    rows = lt.Study(d).store.rows(Phase.PHASE1)
    failed = [bool(r.fell or (r.info or {}).get(FELL_KEY)) for r in rows]
    return [float(r.cost) for r in rows], failed, [bool(r.fell) for r in rows]


def best_standing(costs: list[float], failed: list[bool]) -> float:
    ok = [c for c, f in zip(costs, failed) if not f]
    return min(ok) if ok else math.inf


def sign_p(wins: int, losses: int) -> float:
    from scipy.stats import binomtest

    n = wins + losses
    return 1.0 if n == 0 else float(binomtest(wins, n, 0.5).pvalue)


def summary(root: Path, systems: list[str], seeds: list[int], evals: int) -> dict[str, Any]:
    out: dict[str, Any] = {"evals": evals, "seeds": seeds, "systems": {}, "traces": {}}
    for s in systems:
        per: dict[str, dict[str, list[float]]] = {a: {"best": [], "falls": []} for a in ARMS}
        for arm in ARMS:
            for seed in seeds:
                d = root / s / arm / f"seed{seed}"
                costs, failed, _ = trace(d)
                if len(costs) < evals:
                    raise ValueError(f"{d} holds {len(costs)} of {evals} trials (run it "
                                     "first)")
                costs, failed = costs[:evals], failed[:evals]
                per[arm]["best"].append(best_standing(costs, failed))
                per[arm]["falls"].append(int(sum(failed)))
                out["traces"][f"{s}/{arm}/seed{seed}"] = {
                    "cost": [round(c, 6) for c in costs], "failed": failed}
        t, h = np.array(per["told"]["best"]), np.array(per["hidden"]["best"])
        wins, losses = int((t < h).sum()), int((t > h).sum())
        out["systems"][s] = {
            **{arm: {"median_best": float(np.median(per[arm]["best"])),
                     "median_falls": float(np.median(per[arm]["falls"])),
                     "best": per[arm]["best"], "falls": per[arm]["falls"]} for arm in ARMS},
            "told_vs_hidden": {"wins": wins, "losses": losses, "p": sign_p(wins, losses),
                               "median_ratio": float(np.median(t / h))}}
    return out


def table(res: dict[str, Any]) -> str:
    lines = [f"Phase 1 (TuRBO-m, {res['evals']} trials, batch 4) on each model system, seeds "
             f"{res['seeds'][0]}–{res['seeds'][-1]}; failed trials told (k/N)·c_manual "
             "(`python -m benchmarks.fall_costs`). Median over seeds of the best standing cost "
             "and of the failed trials; `told` against `hidden` paired by seed.", "",
             "| system | told: best, falls | hidden: best, falls | convention: best, falls "
             "| told < hidden (wins/losses, sign p) | median told/hidden |",
             "|---|---|---|---|---|---|"]
    for s, r in res["systems"].items():
        cells = [f"{r[a]['median_best']:.4g}, {r[a]['median_falls']:g}" for a in ARMS]
        v = r["told_vs_hidden"]
        lines.append(f"| {s} | " + " | ".join(cells) +
                     f" | {v['wins']}/{v['losses']}, p {v['p']:.3g} | {v['median_ratio']:.3f} |")
    tw = sum(r["told_vs_hidden"]["wins"] for r in res["systems"].values())
    tl = sum(r["told_vs_hidden"]["losses"] for r in res["systems"].values())
    ft = sum(sum(r["told"]["falls"]) for r in res["systems"].values())
    fh = sum(sum(r["hidden"]["falls"]) for r in res["systems"].values())
    fc = sum(sum(r["convention"]["falls"]) for r in res["systems"].values())
    lines += ["", f"All pairs: told lower on {tw}, higher on {tl} (sign p {sign_p(tw, tl):.3g}); "
              f"falls in all runs: told {ft}, hidden {fh}, convention {fc}."]
    return "\n".join(lines) + "\n"


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.common import bench_parser, error_line, out_file
    ap = bench_parser("benchmarks.fall_costs", description=__doc__.split("\n\n")[0])
    ap.add_argument("cmd", choices=("run", "summary"))
    ap.add_argument("--root", type=Path, required=True)
    ap.add_argument("--systems", default=",".join(tr.SYSTEMS))
    ap.add_argument("--arms", default=",".join(ARMS))
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--evals", type=int, default=300)
    ap.add_argument("--out", type=out_file, metavar="FILE.json")
    a = ap.parse_args(argv)
    try:
        systems = [s for s in a.systems.split(",") if s]
        arms = [x for x in a.arms.split(",") if x]
        seeds = _seeds(a.seeds)
    except ValueError:
        error_line("benchmarks.fall_costs", f"--seeds {a.seeds!r}: expected e.g. 0-9 or 0,2,5")
        return 2
    bad = [s for s in systems if s not in tr.SYSTEMS] + [x for x in arms if x not in ARMS]
    if bad or not systems or not arms or a.evals < 1:
        error_line("benchmarks.fall_costs",
                   f"unknown system/arm {bad} or empty list or --evals < 1 (systems: "
                   f"{', '.join(tr.SYSTEMS)}; arms: {', '.join(ARMS)})")
        return 2
    if a.cmd == "summary" and a.out is None:
        error_line("benchmarks.fall_costs", "summary needs --out FILE.json")
        return 2
    try:
        if a.cmd == "run":
            for s in systems:
                c = manual_cost(s)
                for seed in seeds:
                    for arm in arms:
                        run_one(a.root, s, arm, seed, a.evals, c)
                        print(f"{s} {arm} seed {seed} done", flush=True)
            return 0
        res = summary(a.root, systems, seeds, a.evals)
    except (ValueError, OSError) as e:
        error_line("benchmarks.fall_costs", e)
        return 2
    a.out.parent.mkdir(parents=True, exist_ok=True)
    traces = res.pop("traces")
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    a.out.with_name("traces.json").write_text(json.dumps(traces) + "\n")
    md = table(res)
    a.out.with_suffix(".md").write_text(md)
    print(md, end="")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.fall_costs"))
