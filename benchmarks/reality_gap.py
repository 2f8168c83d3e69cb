"""Phase 3 on a robot that is not the simulator: reality profiles and MuJoCo as the target.

    python -m benchmarks.reality_gap --source results/a1/a1-trot --realities hard mujoco
        [--robot a1 --task trot --actor convex] [--budget 40] [--seeds 0 1 2 3 4]
        [--methods phase3 direct cma] [--max-fall-prob P] [--workers 2] [--work DIR]
        [--out FILE.json]

The source is a finished run (phase 1 + VAE) on the nominal PyBullet robot. For every target
reality (a preset or profile file run in PyBullet, or ``mujoco``: the nominal robot in MuJoCo)
and seed, at equal budgets on the target:

* ``zero-shot``: the source run's best θ run as it is (one trial; every Study records it);
* ``phase3``:    TuRBO-m in the source's latent space (``Study.phase3(target, latent=source)``);
* ``direct``:    TuRBO-m on θ warm-started at the source's best θ (``Study.phase1(start=best)``);
* ``cma``:       CMA-ES on θ from the same start.

Reports per method the median and spread (min–max) over seeds of the best cost at the budget,
evaluations to beat the zero-shot cost, and falls during tuning. Each (reality, method, seed) is
a Study under ``--work`` and resumes.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.pipeline.evaluators import make_evaluator  # noqa: E402
from latentune.reporting.metrics import evals_to_beat  # noqa: E402
from latentune.study import source_best  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               median_evals, out_dir, refuse_out_of_range, write_json)


METHODS = ("phase3", "direct", "cma")
"""The methods run on each target (module docstring)."""


def spread(v: list[float]) -> dict:
    a = np.asarray(v, dtype=float)
    return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def report(d: Path) -> str:
    """One Markdown table of every ``*.json`` output in ``d``: per (robot, task, reality,
    method) the best cost, falls and evaluations to beat zero-shot without fall avoidance and
    with each ``--max-fall-prob`` P found, and the ratios of the median best cost and of the
    median falls (P / plain). ValueError when ``d`` holds none (an empty table read as done)."""
    rows: dict = {}
    probs: set = set()
    cmds = []
    for f in sorted(d.glob("*.json")):
        o = json.loads(f.read_text())
        if "summary" not in o:            # not a reality_gap.py output (e.g. fall_calibration.py)
            continue
        fa = o.get("max_fall_prob")
        if fa:
            probs.add(fa)
        cmds.append(f"- `{f.name}`: `{o['provenance']['command']}` "
                    f"({o['provenance']['wall_s']:.0f} s)")
        for reality, ms in o["summary"].items():
            for m, v in ms.items():
                rows.setdefault((o["robot"], o["task"], reality, m), {})[fa] = v
    if not rows:
        raise ValueError(f"no reality_gap output (a *.json with a summary) in {d}")
    ps = sorted(probs)

    def cell(v):
        if v is None:
            return ["–", "–", "–"]
        b = v["best"]
        return [f"{b['median']:.3f} [{b['min']:.3f}–{b['max']:.3f}]",
                f"{v['falls']['median']:.0f}", f"{v['evals_to_beat_zero_shot_median']:g}"]

    head = ["robot", "task", "reality", "method", "zero-shot", "best", "falls", "to beat zero-shot"]
    for p in ps:
        head += [f"best, P={p:g}", f"falls, P={p:g}", f"best ratio, P={p:g}",
                 f"falls ratio, P={p:g}"]
    out = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for (robot, task, reality, m), v in sorted(rows.items()):
        z = next(iter(v.values()))["zero_shot"]["median"]
        cells = [robot, task, reality, m, f"{z:.3f}", *cell(v.get(None))]
        for p in ps:
            c = cell(v.get(p))
            ratio = best_ratio = "–"
            if v.get(None) and v.get(p):
                a, b = v[None]["falls"]["median"], v[p]["falls"]["median"]
                ratio = f"{b / a:.2f}" if a else ("1" if b == 0 else "inf")
                best_ratio = f"{v[p]['best']['median'] / v[None]['best']['median']:.3f}"
            cells += [c[0], c[1], best_ratio, ratio]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out + ["", "Commands (wall time):", *cmds])


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.reality_gap")
    ap = bench_parser("benchmarks.reality_gap", description=__doc__.splitlines()[0])
    ap.add_argument("--report", default=None, metavar="DIR",
                    help="print one table of the outputs in DIR (e.g. results/reality_gap)")
    ap.add_argument("--source", help="a finished run directory (phase 1 + VAE)")
    ap.add_argument("--realities", nargs="+", default=["hard", "mujoco"])
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--actor", default="convex")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--budget", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--max-fall-prob", type=float, default=None,
                    help="fall-aware critics: skip candidates above this predicted fall probability")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--work", type=out_dir, default="runs/reality_gap")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.report:
        try:
            print(report(Path(a.report)))
        except ValueError as e:
            error_line("benchmarks.reality_gap", e)
            return 2
        return 0
    if not a.source:
        ap.error("--source is required")
    refuse_out_of_range(ap, a, budget=(1, None), seeds=(0, None), workers=(1, None),
                        steps=(1, None))            # before any target is built
    if a.max_fall_prob is not None and not 0 < a.max_fall_prob <= 1:
        ap.error(f"--max-fall-prob must be in (0, 1], got {a.max_fall_prob}")
    best = source_best(a.source)
    if best is None:                        # refused before any target is built
        ap.error(f"--source {a.source} is not a run with phase-1 trials (no zero-shot θ)")
    if "phase3" in a.methods and not (Path(a.source) / "vae.json").is_file():
        ap.error(f"--source {a.source} has no latent space (train-vae) for the phase3 method")
    best0 = best.theta                      # the zero-shot θ
    work = Path(a.work)
    ev = make_evaluator("process", a.workers)
    res: dict = {}
    try:
        for reality in a.realities:
            for s in a.seeds:
                kw = {"engine": "mujoco"} if reality == "mujoco" else {"reality": reality}
                target = lt.Task(a.robot, a.task, actor=a.actor, steps=a.steps, seed=s, **kw)
                if target.space.dim != best0.shape[0]:      # another robot's or actor's run
                    ap.error(f"--source {a.source} tunes {best0.shape[0]} weights, the target "
                             f"(--robot {a.robot} --actor {a.actor}) {target.space.dim}: give "
                             "a source run of the target's controller")
                zero = target.evaluate(best0).cost    # the source's best θ as it is, on the target
                for m in a.methods:
                    d = work / f"{reality}_{m}{f'_fa{a.max_fall_prob:g}' if a.max_fall_prob else ''}_s{s}"
                    opts = {} if a.max_fall_prob is None else {"max_fall_prob": a.max_fall_prob}
                    with lt.Study(d, seed=s, workers=a.workers, evaluator=ev) as st:
                        if m == "phase3":
                            st.phase3(target, a.budget, latent=a.source, strategy="plain", **opts)
                            ph = Phase.PHASE3
                        else:
                            if opts:
                                opts["fall_prior"] = a.source   # the source run's trials
                            st.phase1(target, a.budget, method="turbo" if m == "direct" else m,
                                      start=best0, **opts)
                            ph = Phase.PHASE1
                        rows = st.store.rows(ph)
                        y = [r.cost for r in rows]
                        r = {"seed": s, "best": float(min(y)), "falls": int(sum(r.fell for r in rows)),
                             "evals_to_beat_zero_shot": evals_to_beat(y, zero), "zero_shot": zero,
                             "manual": st.store.rows(Phase.MANUAL)[0].cost}
                    res.setdefault(reality, {}).setdefault(m, []).append(r)
                    print(f"{reality:9s} {m:7s} seed {s}: best {r['best']:.3f} (zero-shot {zero:.3f}), "
                          f"falls {r['falls']}/{len(y)}, beat zero-shot at {r['evals_to_beat_zero_shot']}",
                          file=sys.stderr, flush=True)
    finally:
        ev.close()
    summary = {}
    print("\n| reality | method | best (median [min–max]) | falls | evals to beat zero-shot | zero-shot |")
    print("|---|---|---|---|---|---|")
    for reality, ms in res.items():
        for m, rs in ms.items():
            b = spread([r["best"] for r in rs])
            f = spread([r["falls"] for r in rs])
            e = median_evals([r["evals_to_beat_zero_shot"] for r in rs])
            z = spread([r["zero_shot"] for r in rs])
            summary.setdefault(reality, {})[m] = {"best": b, "falls": f, "evals_to_beat_zero_shot_median": e,
                                                  "zero_shot": z}
            print(f"| {reality} | {m} | {b['median']:.3f} [{b['min']:.3f}–{b['max']:.3f}] | "
                  f"{f['median']:.0f} [{f['min']:.0f}–{f['max']:.0f}] of {a.budget} | {e} | "
                  f"{z['median']:.3f} |")
    if a.out:
        write_json(a.out, {"source": a.source, "robot": a.robot, "task": a.task,
                           "actor": a.actor, "budget": a.budget, "seeds": a.seeds,
                           "max_fall_prob": a.max_fall_prob, "summary": summary,
                           "results": res}, prov)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.reality_gap"))
