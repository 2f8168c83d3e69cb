"""Phase 3 without a floor (issue 15): phase 3 with a hand-over to the full θ space against plain
phase 3 and direct search on θ, all from scratch, at equal budgets and seeds.

    python -m benchmarks.handover --robot solo12 --task jump --actor kinodynamic \\
        --vae results/solo12/solo12-trot --budget 100 --seeds 0 1 2 3 4 \\
        --methods handover latent turbo optuna_cma optuna_tpe --targets 25.0 23.0 \\
        --work /work/runs/se_solo12 --out results/handover/solo12_jump.json

Methods (every one from scratch: no method gets the manual θ as its first point):

* ``latent``: plain phase 3 (``Study.phase3(start=None)``), TuRBO-m in the VAE's latent box;
* ``handover``: the same with ``handover=True`` (``Study.phase3``'s defaults, or ``--handover``
  options), which continues with TuRBO-m on θ once the latent search stalls;
* ``turbo``: TuRBO-m on θ (``Study.phase1(start=None)``);
* ``optuna_cma``, ``optuna_tpe``: Optuna's ``CmaEsSampler`` / ``TPESampler(multivariate=True)``
  on the unit box of θ, seeded, asked in batches of ``--batch-size`` before any is told, as a
  user would call them; their trials go through the same evaluator and are stored as phase 1 of
  a run store (Optuna is installed for the benchmark only: ``pip install optuna``).

Every (method, seed) is a run store under ``--work`` (``<method>_s<seed>``); a finished store is
read instead of re-run (so stores of ``benchmarks.sample_efficiency`` with the same task,
budget, batch size and seed are reused: the same Study calls), and a store run with other
options or another task is refused before any rollout (``check_stores``). Reported per method:
evaluations to the manual cost and to each ``--targets`` cost (median over seeds; a seed that
never gets there counts as infinite), the best cost after the budget (median, min, max), falls
during tuning (median per run), and the two-sided Mann–Whitney U p-value of the bests against
the handover method's.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.errors import StoreError  # noqa: E402
from latentune.pipeline.phases import handover_options  # noqa: E402
from latentune.reporting.metrics import evals_to_beat  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               median_evals, out_dir, refuse_out_of_range, write_json)

METHODS = ("latent", "handover", "turbo", "optuna_cma", "optuna_tpe")


def report(d: Path) -> str:
    """The tables of every ``*.json`` output in ``d`` with their commands and wall times (other
    JSON files are passed over). ValueError when ``d`` holds none (an empty report read as
    done)."""
    out = []
    for f in sorted(d.glob("*.json")):
        o = json.loads(f.read_text())
        if not (isinstance(o, dict) and "table" in o and "provenance" in o):
            continue                        # not a handover output
        pr = o["provenance"]
        title = f"{o['robot']} {o['task']}" + (f", reality {o['reality']}" if o.get("reality")
                                               else "")
        out += [f"### {title}: `{f.name}`", "", f"`{pr['command']}` ({pr['wall_s']:.0f} s, "
                f"commit {str(pr.get('commit'))[:7]}; manual cost {o['manual']:.3f})", "",
                *o["table"], ""]
    if not out:
        raise ValueError(f"no handover output (a *.json with a table) in {d}")
    return "\n".join(out)


def stored_options(m: str, seed: int, batch_size: int, vae: str, handover: Any,
                   max_fall_prob: float | None) -> dict[str, Any]:
    """The options a store of method ``m`` records for its phase (phase 3 for ``latent`` and
    ``handover``, phase 1 otherwise) when this benchmark runs it with these arguments: what a
    finished store is checked against before it is read instead of re-run."""
    base = {"seed": int(seed), "batch_size": int(batch_size), "start": None}
    if m in ("latent", "handover"):
        ho = m == "handover"
        return {**base, "method": "turbo", "strategy": "plain",
                "latent_source": str(Path(vae).resolve()),
                "handover": handover_options(handover) if ho else None,
                "max_fall_prob": None if not ho or max_fall_prob is None
                else float(max_fall_prob)}
    return {**base, "max_fall_prob": None,
            "method": {"optuna_cma": "optuna-cmaes", "optuna_tpe": "optuna-tpe"}.get(m, "turbo")}


def stored_differences(stored: dict[str, Any], want: dict[str, Any]) -> list[str]:
    """``"key = stored (not wanted)"`` for each option of ``want`` that ``stored`` (a phase's
    options record) holds with another value; options it does not record pass."""
    return [f"{k.replace('_', '-')} = {stored[k]!r} (not {v!r})" for k, v in want.items()
            if k in stored and stored[k] != v]


def check_stores(a: argparse.Namespace, task: Any, handover: Any) -> None:
    """StoreError (one line) unless every store under ``--work`` that holds trials of its
    method's phase was run with the options and the task these arguments ask for: a finished
    store is read instead of re-run, so one of other options (another ``--handover`` or
    ``--max-fall-prob`` under the same ``--handover-name``) would be reported as this run."""
    for m in a.methods:
        name = a.handover_name if m == "handover" else m
        phase = Phase.PHASE3 if m in ("latent", "handover") else Phase.PHASE1
        for s in a.seeds:
            d = Path(a.work) / f"{name}_s{s}"
            if not d.exists():
                continue
            with lt.Study(d, seed=s, workers=1) as study:
                if not (study.exists and study.store.count(phase)):
                    continue
                study.bind_check(task)
                key = "phase3" if phase == Phase.PHASE3 else "phase1"
                diff = stored_differences(study.config().get(key) or {}, stored_options(
                    m, s, a.batch_size, a.vae, handover, a.max_fall_prob))
            if diff:
                raise StoreError(f"{d}: the store of {m} was run with other options "
                                 f"({'; '.join(diff)}): give another --work"
                                 f"{' or --handover-name' if m == 'handover' else ''} for them")


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.handover")
    ap = bench_parser("benchmarks.handover", description=__doc__.splitlines()[0])
    ap.add_argument("--report", default=None, metavar="DIR",
                    help="print the tables of the outputs in DIR (e.g. results/handover)")
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="jump")
    ap.add_argument("--actor", default=None)
    ap.add_argument("--reality", default=None, help="a reality preset or YAML for the target")
    ap.add_argument("--vae", help="run directory whose latent space phase 3 uses")
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--handover", default=None, help='JSON options, e.g. \'{"length": 0.4}\'')
    ap.add_argument("--max-fall-prob", type=float, default=None,
                    help="the handover method's fall-aware option (both of its stages)")
    ap.add_argument("--handover-name", default="handover",
                    help="store name of the handover method (for option variants)")
    ap.add_argument("--targets", type=float, nargs="*", default=[])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--work", type=out_dir)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.report:
        try:
            print(report(Path(a.report)))
        except ValueError as e:
            error_line("benchmarks.handover", e)
            return 2
        return 0
    if not (a.vae and a.work):
        ap.error("--vae and --work are required")
    refuse_out_of_range(ap, a, budget=(1, None), seeds=(0, None), workers=(1, None),
                        batch_size=(1, None))       # before the task is built
    if a.max_fall_prob is not None and not 0 < a.max_fall_prob <= 1:
        ap.error(f"--max-fall-prob must be in (0, 1], got {a.max_fall_prob}")
    try:                                    # refused before the manual θ's rollout
        handover = json.loads(a.handover) if a.handover else True
    except json.JSONDecodeError as e:
        ap.error(f"--handover is not JSON: {e}")
    try:                                    # JSON of the wrong options: before the task too
        handover_options(handover)
    except ValueError as e:
        ap.error(f"--handover: {e}")
    if any(not math.isfinite(t) for t in a.targets):
        ap.error(f"--targets must be finite costs, got {a.targets}")
    from latentune.pipeline.evaluators import make_evaluator

    kw = {"actor": a.actor} if a.actor else {}
    if a.reality:
        kw["reality"] = a.reality
    task = lt.Task(a.robot, a.task, **kw)
    check_stores(a, task, handover)         # before the manual θ's rollout
    manual = task.rollout(task.space.manual).cost
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"{a.robot} {a.task}{' / ' + a.reality if a.reality else ''}: manual {manual:.3f}; "
          f"budget {a.budget}; seeds {a.seeds}; stores in {work}", file=sys.stderr, flush=True)
    ev = make_evaluator("process", a.workers)
    res: dict[str, list[dict]] = {}
    try:
        for m in a.methods:
            name = a.handover_name if m == "handover" else m
            for s in a.seeds:
                d = work / f"{name}_s{s}"
                phase = Phase.PHASE3 if m in ("latent", "handover") else Phase.PHASE1
                t0 = time.perf_counter()
                with lt.Study(d, seed=s, workers=a.workers, batch_size=a.batch_size,
                              evaluator=ev) as study:
                    if study.exists and study.store.count(phase) >= a.budget:
                        ran = False         # checked by check_stores
                    else:
                        ran = True
                        if m == "latent":
                            study.phase3(task, a.budget, latent=a.vae, start=None, strategy="plain")
                        elif m == "handover":
                            study.phase3(task, a.budget, latent=a.vae, start=None,
                                         handover=handover, max_fall_prob=a.max_fall_prob)
                        elif m == "turbo":
                            study.phase1(task, a.budget, start=None)
                        else:       # Optuna's sampler as phase 1 from its own design
                            study.phase1(task, a.budget, start=None,
                                         method={"optuna_cma": "optuna-cmaes",
                                                 "optuna_tpe": "optuna-tpe"}[m])
                    rows = study.store.rows(phase)[: a.budget]
                    cfg = study.config()
                y = np.array([r.cost for r in rows])
                fell = np.array([r.fell for r in rows])
                r = {"seed": s, "to_manual": evals_to_beat(y, manual),
                     "to": [evals_to_beat(y, t) for t in a.targets], "best": float(y.min()),
                     "falls": int(fell.sum()), "n": int(len(y)),
                     "wall_s": time.perf_counter() - t0 if ran else None, "ran": ran}
                if m == "handover":
                    ho = cfg.get("phase3_handover", {})
                    r["handover_at"] = ho.get("handover_at")
                    at = r["handover_at"] if r["handover_at"] is not None else len(y)
                    r["best_at_handover"] = float(y[:at].min()) if at else None
                    r["falls_after_handover"] = int(fell[at:].sum())
                res.setdefault(name, []).append(r)
                print(f"  {name:10s} seed {s}: best {r['best']:.3f}, to manual {r['to_manual']}, "
                      f"to {a.targets} {r['to']}, falls {r['falls']}"
                      + (f", handed over at {r.get('handover_at')}" if m == "handover" else "")
                      + ("" if ran else " (stored)"), file=sys.stderr, flush=True)
    finally:
        ev.close()
    tabs = ["| " + " | ".join(["method", "seeds", "evals to manual",
                               *[f"to {t:g}" for t in a.targets],
                               "best (median [min, max])", "falls (median)",
                               "p (best vs handover)"]) + " |",
            "|---|---:|---:|" + "---:|" * len(a.targets) + "---|---:|---:|"]
    from scipy.stats import mannwhitneyu

    ref = [r["best"] for r in res.get(a.handover_name, [])]
    summary = {}
    for name, rs in res.items():
        b = [r["best"] for r in rs]
        row = {"to_manual": median_evals([r["to_manual"] for r in rs]),
               "to": [median_evals([r["to"][k] for r in rs]) for k in range(len(a.targets))],
               "best_median": float(np.median(b)), "best_min": float(min(b)),
               "best_max": float(max(b)), "falls_median": float(np.median([r["falls"] for r in rs]))}
        p = (float(mannwhitneyu(ref, b).pvalue) if ref and name != a.handover_name
             and len(ref) > 1 and len(b) > 1 else None)
        row["p_best_vs_handover"] = p    # two-sided Mann-Whitney U over seeds
        summary[name] = row
        tabs.append("| " + " | ".join(
            [name, str(len(rs)), f"{row['to_manual']:g}", *[f"{v:g}" for v in row["to"]],
             f"{row['best_median']:.3f} [{row['best_min']:.3f}, {row['best_max']:.3f}]",
             f"{row['falls_median']:g}", "–" if p is None else f"{p:.2f}"]) + " |")
    print("\n" + "\n".join(tabs))
    if a.out:
        write_json(a.out, {"robot": a.robot, "task": a.task, "actor": a.actor,
                           "reality": a.reality, "manual": manual, "budget": a.budget,
                           "seeds": a.seeds, "vae": a.vae, "handover": handover,
                           "max_fall_prob": a.max_fall_prob,
                           "targets": a.targets, "work": str(work),
                           "summary": summary, "table": tabs, "results": res}, prov)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.handover"))
