"""Critic quality: the best value ``latentune.minimize`` finds on the quick suite's unit-box test
functions (:func:`benchmarks.common.quick_problems`, global minimum 0), per method.

Every (function, method, seed) runs ``minimize`` with the given budget and batch size; the
table gives the median best value over seeds, its min and max, and the median wall time per run.

    python -m benchmarks.critic --functions ackley20 levy25 --methods turbo cma random \
        --budget 1000 --seeds 1 --batch-size 20 [--jobs 2] [--out FILE.json]

The TuRBO-m overhead (seconds per suggested point) is ``benchmarks.turbo_overhead``.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, finish,  # noqa: E402
                               quick_problems)


def _run_one(args: tuple[str, str, int, int, int]) -> dict:
    fname, method, seed, budget, batch = args
    import torch

    torch.set_num_threads(1)
    from latentune.optimize import minimize

    prob = quick_problems()[fname]
    t = time.perf_counter()
    res = minimize(prob, [(0.0, 1.0)] * prob.dim, method=method, budget=budget,
                   batch_size=batch, seed=seed)
    return {"function": fname, "method": method, "seed": seed, "best": float(res.fun),
            "wall_s": time.perf_counter() - t}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.critic")
    p = bench_parser("benchmarks.critic", description=__doc__,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--functions", nargs="+", default=["ackley20", "levy25", "rosenbrock25",
                                                      "styblinski77"],
                   choices=sorted(quick_problems()))
    p.add_argument("--methods", nargs="+", default=["turbo", "cma", "random"],
                   choices=["turbo", "cma", "random", "sobol"])
    p.add_argument("--budget", type=int, default=1000)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=20)
    p.add_argument("--jobs", type=int, default=1, help="parallel runs (processes)")
    add_out_arg(p)
    a = p.parse_args(argv)
    work = [(f, m, s, a.budget, a.batch_size) for f in a.functions for m in a.methods
            for s in range(a.seeds)]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            runs = list(ex.map(_run_one, work))
    else:
        runs = [_run_one(w) for w in work]
    rows = []
    for f in a.functions:
        for m in a.methods:
            r = [x for x in runs if x["function"] == f and x["method"] == m]
            best = np.array([x["best"] for x in r])
            rows.append({"function": f, "method": m, "median": float(np.median(best)),
                         "min": float(best.min()), "max": float(best.max()),
                         "wall_s_per_run": float(np.median([x["wall_s"] for x in r]))})
    finish(a.out, prov, {"budget": a.budget, "batch_size": a.batch_size, "seeds": a.seeds,
                         "runs": runs}, rows,
           title=f"best value found (global minimum 0): budget {a.budget}, batch "
                 f"{a.batch_size}, {a.seeds} seeds")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.critic"))
