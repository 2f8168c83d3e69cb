"""Sim-to-real over seeds: phase 3 in the model's latent space vs direct TuRBO-m vs zero-shot.

    python -m benchmarks.sim_to_real [--seeds 0 1 2 3 4] [--phase1-evals 300]
        [--phase3-evals 100] [--checkpoints 20 40 60] [--latent-dim 5] [--episode-steps 400]
        [--work runs/sim_to_real] [--workers 1] [--backend serial] [--out FILE.json]

(from the repository root: it imports ``examples``).

The system is example (b), ``examples/sim_to_real.py``: the 36-weight linear controller of
Gymnasium's ``Hopper-v5`` (``examples/gym_controller.py``); the model is the nominal Hopper, the
"real" one has masses x1.3, friction x0.6, gear x0.8, observation noise and a one-step action
delay. For every seed s (one model study per seed, seed s; nothing is shared between seeds):

1. ``WORK/seed<s>/model``: phase 1 (``--phase1-evals`` model evaluations) + the VAE;
2. ``WORK/seed<s>/phase3``: phase 3 on the real Hopper, ``--phase3-evals`` evaluations in the
   model's latent space (``Study.phase3(real, B, latent=model)``; that also runs the model's best
   θ on the real Hopper once: the zero-shot cost);
3. ``WORK/seed<s>/direct``: TuRBO-m on the full θ on the real Hopper from the manual θ
   (``Study.phase1(real, B)``), the same ``--phase3-evals`` budget.

Each tuning budget B counts the tuned trials only; both also evaluate the manual θ once and
phase 3 also the zero-shot θ once. Reported per method, over the seeds: median, min-max and
IQR of the best real cost at B (and at each ``--checkpoints`` budget: TuRBO-m's options depend on
the budget only through the number of trust regions, 1 for every budget below 750, so the best
after k < B evaluations is the result of a k-evaluation run), evaluations until the best so far
beats the zero-shot cost and the manual cost, and failed real trials (falls) during tuning.
Every study directory resumes: rerunning the same command finishes what is missing.
Prints a Markdown table; ``--out FILE.json`` writes every seed's results with the provenance
(:mod:`benchmarks.common`) and the table next to it (``FILE.md``).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from examples.gym_controller import REAL  # noqa: E402
from examples.sim_to_real import run_model, run_real  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, out_dir,  # noqa: E402
                               write_json)

METHODS = ("phase3", "direct")


def spread(values: list[float]) -> dict[str, Any]:
    """median, min, max, IQR (q25, q75) of the finite values; n."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"n": 0, "median": None, "min": None, "max": None, "q25": None, "q75": None}
    q25, med, q75 = np.percentile(v, [25, 50, 75])
    return {"n": int(v.size), "median": float(med), "min": float(v.min()),
            "max": float(v.max()), "q25": float(q25), "q75": float(q75)}


def _lt(a: float | None, b: float | None) -> bool:
    """a < b for best costs where None (every trial fell) is worse than any cost."""
    return a is not None and (b is None or a < b)


def _best(x: float | None) -> str:
    """A best cost as the tables show it ("all fell" for None)."""
    return "all fell" if x is None else f"{x:.2f}"


def aggregate(per_seed: list[dict[str, Any]], budget: int,
              checkpoints: list[int]) -> dict[str, Any]:
    agg: dict[str, Any] = {
        "manual_real": spread([r["manual_real"] for r in per_seed]),
        "zero_shot": spread([r["zero_shot"] for r in per_seed]),
        "zero_shot_fell": int(sum(r["zero_shot_failed"] for r in per_seed)),
        "model_phase1_best": spread([r["model"]["phase1_best"] for r in per_seed]),
    }
    for m in METHODS:
        rs = [r[m] for r in per_seed]
        a: dict[str, Any] = {"best": spread([x["best"] for x in rs]),
                             "all_fell": int(sum(x["all_fell"] for x in rs)),
                             "failed": spread([x["failed"] for x in rs]),
                             "failed_total": int(sum(x["failed"] for x in rs)),
                             "trials_total": int(sum(x["n"] for x in rs))}
        for key in ("evals_to_beat_zero_shot", "evals_to_beat_manual"):
            vals = [x[key] for x in rs]
            a[key] = {**spread(vals), "never": int(sum(v is None for v in vals))}
        a["best_at"] = {str(k): spread([x["best_so_far"][k - 1] for x in rs])
                        for k in checkpoints if k <= budget}
        agg[m] = a
    wins = [_lt(r["phase3"]["best"], r["direct"]["best"]) for r in per_seed]
    agg["phase3_beats_direct"] = {"seeds": int(sum(wins)), "of": len(wins)}
    agg["phase3_beats_direct_at"] = {
        str(k): int(sum(_lt(r["phase3"]["best_so_far"][k - 1], r["direct"]["best_so_far"][k - 1])
                        for r in per_seed)) for k in checkpoints if k <= budget}
    agg["beats_zero_shot"] = {m: int(sum(r[m]["evals_to_beat_zero_shot"] is not None
                                         for r in per_seed)) for m in METHODS}
    agg["beats_manual"] = {m: int(sum(r[m]["evals_to_beat_manual"] is not None
                                      for r in per_seed)) for m in METHODS}
    return agg


def _fmt(s: dict[str, Any], nd: int = 2) -> str:
    if not s or s.get("median") is None:
        return "–"
    return (f"{s['median']:.{nd}f} [{s['min']:.{nd}f}–{s['max']:.{nd}f}] "
            f"(IQR {s['q25']:.{nd}f}–{s['q75']:.{nd}f})")


def _fmt_evals(s: dict[str, Any]) -> str:
    if s["n"] == 0:
        return f"never ({s['never']} seeds)"
    txt = f"{s['median']:g} [{s['min']:g}–{s['max']:g}]"
    return txt + (f", never on {s['never']} seeds" if s["never"] else "")


def markdown(res: dict[str, Any]) -> str:
    agg, b, n = res["aggregate"], res["phase3_evals"], len(res["seeds"])
    label = {"phase3": "phase 3 (latent space of the model)",
             "direct": "direct TuRBO-m on θ (real, from manual)"}
    out = [f"Best real cost at {b} real evaluations, over {n} seeds: median [min–max] (IQR). "
           f"Phase 1 on the model: {res['phase1_evals']} evaluations per seed.", "",
           "| method | best real cost | failed trials (falls) | evals to beat zero-shot | "
           "evals to beat manual |", "|---|---|---|---|---|",
           f"| manual θ (1 eval) | {_fmt(agg['manual_real'])} | 0 | – | – |",
           f"| zero-shot: model's best θ (1 eval) | {_fmt(agg['zero_shot'])} | "
           f"{agg['zero_shot_fell']}/{n} fell | – | – |"]
    for m in METHODS:
        a = agg[m]
        out.append(f"| {label[m]} | {_fmt(a['best'])} | median {a['failed']['median']:g} of {b} "
                   f"(total {a['failed_total']}/{a['trials_total']}) | "
                   f"{_fmt_evals(a['evals_to_beat_zero_shot'])} | "
                   f"{_fmt_evals(a['evals_to_beat_manual'])} |")
    ks = list(agg["phase3"]["best_at"])
    out += ["", "Best real cost so far after k evaluations (median [min–max]); phase 3 better "
            "than direct on how many seeds:", "",
            "| k | phase 3 | direct | phase 3 < direct |", "|---:|---|---|---:|"]
    for k in ks:
        out.append(f"| {k} | {_fmt(agg['phase3']['best_at'][k])} | "
                   f"{_fmt(agg['direct']['best_at'][k])} | "
                   f"{agg['phase3_beats_direct_at'][k]}/{n} |")
    out += ["", "Per seed (real costs; ✗ = the trial fell):", "",
            "| seed | manual | zero-shot | phase 3 best | direct best | phase-3 falls | "
            "direct falls | model phase-1 best |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["per_seed"]:
        out.append(f"| {r['seed']} | {r['manual_real']:.2f} | {r['zero_shot']:.2f}"
                   f"{' ✗' if r['zero_shot_failed'] else ''} | {_best(r['phase3']['best'])} | "
                   f"{_best(r['direct']['best'])} | {r['phase3']['failed']} | "
                   f"{r['direct']['failed']} | {_best(r['model']['phase1_best'])} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.sim_to_real")
    ap = bench_parser("benchmarks.sim_to_real", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--phase1-evals", type=int, default=300)
    ap.add_argument("--phase3-evals", type=int, default=100,
                    help="real evaluations of phase 3 and of direct TuRBO-m each")
    ap.add_argument("--checkpoints", type=int, nargs="*", default=[10, 20, 40, 60])
    ap.add_argument("--latent-dim", type=int, default=5)
    ap.add_argument("--episode-steps", type=int, default=400)
    ap.add_argument("--work", type=out_dir, default="runs/sim_to_real",
                    help="root of the study directories")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--backend", default="serial", choices=("serial", "process", "ray"))
    add_out_arg(ap)
    a = ap.parse_args(argv)
    root = Path(a.work)
    checkpoints = sorted(set(a.checkpoints) | {a.phase3_evals})
    per_seed = []
    for s in a.seeds:
        d = root / f"seed{s}"
        ts = time.perf_counter()
        model = run_model(d / "model", s, a.phase1_evals, a.latent_dim, a.episode_steps,
                          a.workers, a.backend)
        r = run_real(d / "model", d / "phase3", d / "direct", s, a.phase3_evals,
                     a.episode_steps, a.workers, a.backend)
        r["model"] = model
        r["wall_s"] = time.perf_counter() - ts
        per_seed.append(r)
        print(f"seed {s}: manual {r['manual_real']:.2f}, zero-shot {r['zero_shot']:.2f}"
              f"{' (fell)' if r['zero_shot_failed'] else ''}, phase 3 {_best(r['phase3']['best'])} "
              f"({r['phase3']['failed']} falls), direct {_best(r['direct']['best'])} "
              f"({r['direct']['failed']} falls); model phase 1 {_best(model['phase1_best'])}; "
              f"{r['wall_s']:.0f} s", file=sys.stderr, flush=True)
    res = {"benchmark": "sim_to_real",
           "system": {"env": "Hopper-v5", "controller": "linear feedback + bias, 36 weights",
                      "episode_steps": a.episode_steps, "real_perturbation": REAL,
                      "cost": "100·exp(-max(return - 200·fell, 0)/1000), in (0, 100]; "
                              "fell = the episode terminated early (unhealthy)"},
           "seeds": a.seeds, "model_study": "one per seed (seed s), not shared",
           "phase1_evals": a.phase1_evals, "phase3_evals": a.phase3_evals,
           "direct_evals": a.phase3_evals, "latent_dim": a.latent_dim,
           "workers": a.workers, "backend": a.backend, "out": str(root),
           "notes": ("real budgets count tuned trials; both methods also evaluate the manual θ "
                     "once, phase 3 also the zero-shot θ once. Wall times of a resumed run "
                     "cover only what that run computed."),
           "per_seed": per_seed}
    res["aggregate"] = aggregate(per_seed, a.phase3_evals, checkpoints)
    table = markdown(res)
    res["table"] = table
    print(table)
    if a.out is not None:
        p = prov.finish()
        out = write_json(a.out, res, p)
        load = p["loadavg_start"] or [float("nan")], p["loadavg_end"] or [float("nan")]
        out.with_suffix(".md").write_text(
            f"# Sim-to-real on the Hopper-v5 controller\n\n`{p['command']}`\n\n{p['date']}, "
            f"{p['wall_s']:.0f} s wall, load average {load[0][0]:.2f} → {load[1][0]:.2f} on "
            f"{p['machine']['cores']} cores\n\n{table}\n")
        print(f"\nwritten: {out}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.sim_to_real"))
