"""How close the default's explore asks get to the target GP's best log EI.

    python -m benchmarks.transfer_acq_search [--targets arm:1.75 springs:1.75 arm:0.5]
        [--seeds 0 1] [--root runs/transfer] [--every 3] [--out FILE.json]

Each (target, seed) re-runs the default phase 3 of :mod:`benchmarks.transfer` (its source
``ROOT/<system>/seed<s>/source``, made when missing; 40 trials) with the local search of
``explore_gp`` (:func:`latentune.critic.transfer_model._local_max`) watched. At every ``--every``-th
search, the best log EI it returned is compared with a stronger search of the same function:
the 20 best of 1,024 Sobol points of the unit box as starts, L-BFGS-B with 200 iterations
instead of 40 (finite differences, as the critic's). One row per (target, seed): the number of
searches and the 10th, 50th and 90th percentiles of ``strong − found`` (log EI; 0: the
critic's search finds what the strong one finds, > 0: it stops short). The run itself is the
stored default's (the watch changes nothing it asks).
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)


def strong_max(f: Callable[[np.ndarray], np.ndarray], d: int, seed: int) -> float:
    """The highest ``f`` ((m, d) → (m,)) found by L-BFGS-B (200 iterations) from the 20 best of
    1,024 scrambled Sobol points (``seed``) of the unit box [0, 1]^d."""
    from scipy.optimize import minimize
    from scipy.stats import qmc

    S = qmc.Sobol(d, seed=seed).random(1024)
    best = -np.inf
    for x0 in S[np.argsort(-f(S), kind="stable")[:20]]:
        r = minimize(lambda x: -float(f(x[None, :])[0]), x0, method="L-BFGS-B",
                     bounds=[(0.0, 1.0)] * d, options={"maxiter": 200})
        best = max(best, float(f(np.clip(r.x, 0.0, 1.0)[None, :])[0]))
    return best


def search_rows(root: Path, targets: list[tuple[str, float]], seeds: list[int],
                every: int) -> list[dict[str, Any]]:
    """The rows of the module docstring."""
    import benchmarks.transfer as tr
    import latentune.critic.transfer_model as ct

    calls: list[tuple[Callable, np.ndarray]] = []
    orig = ct._local_max

    def watched(f, X0, maxiter=40):
        out = orig(f, X0, maxiter)
        calls.append((f, out))
        return out

    rows = []
    ct._local_max = watched
    try:
        for system, g in targets:
            for seed in seeds:
                calls.clear()
                src = tr.source_run(root, system, seed, tr.SOURCE_EVALS)
                tr.run_method("transfer", tr.SYSTEMS[system]["target"](g), src, 40, seed,
                              tr.default_options())
                gaps = [strong_max(f, XM.shape[1], i) - float(f(XM).max())
                        for i, (f, XM) in enumerate(calls[::every])]
                p = np.percentile(gaps, [10, 50, 90]) if gaps else [np.nan] * 3
                rows.append({"system": system, "gap": g, "seed": seed, "searches": len(calls),
                             "compared": len(gaps), "p10": round(float(p[0]), 3),
                             "median": round(float(p[1]), 3), "p90": round(float(p[2]), 3)})
                print(rows[-1], flush=True)
    finally:
        ct._local_max = orig
    return rows


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.transfer_acq_search")
    ap = bench_parser("benchmarks.transfer_acq_search", description=__doc__.splitlines()[0])
    ap.add_argument("--targets", nargs="+", default=["arm:1.75", "springs:1.75", "arm:0.5"],
                    help="SYSTEM:GAP")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--root", default="runs/transfer")
    ap.add_argument("--every", type=int, default=3)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    from benchmarks.transfer import SYSTEMS

    targets = []
    for t in a.targets:
        name, _, g = t.partition(":")
        try:
            gap = float(g)
        except ValueError:
            gap = -1.0
        if name not in SYSTEMS or not gap > 0:
            error_line("benchmarks.transfer_acq_search",
                       f"a target is SYSTEM:GAP with SYSTEM one of "
                       f"{', '.join(SYSTEMS)} and GAP > 0, got {t!r}")
            return 2
        targets.append((name, gap))
    if a.every < 1:
        error_line("benchmarks.transfer_acq_search", f"--every must be >= 1, got {a.every}")
        return 2
    rows = search_rows(Path(a.root), targets, a.seeds, a.every)
    finish(a.out, prov, {"targets": a.targets, "seeds": a.seeds, "every": a.every}, rows,
           title="the critic's log-EI search against a stronger one")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_acq_search"))
