"""How hard each gap of the transfer ladder is: of random θ, the share that fail on the model,
and of those that do not, the share that fail on each target.

    python -m benchmarks.gap_ladder [--systems zones springs ...] [--n 300] [--seed 0]
        [--gaps G ...] [--out F.json]

For every system of :data:`benchmarks.transfer.SYSTEMS`: ``--n`` θ drawn uniformly in the unit
box (``numpy.random.default_rng(--seed)``) are run once on the model (gap 0); per gap, the model
-stable ones (those that did not fail there) are run on the target at that gap. One row per
(system, gap): ``n_model_stable``, ``fail_model`` (the share of the n that fail on the model),
``fail_target`` (the share of the model-stable ones that fail on the target), and the median
cost of those that stand on the target. A ladder is a ladder when ``fail_target`` grows with the
gap; the transfer issue asks for a largest gap where most source-stable θ fail.
"""
from __future__ import annotations

import sys
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)
from benchmarks.transfer import SYSTEMS, ladder_targets  # noqa: E402
from latentune.system import evaluate  # noqa: E402


def ladder_rows(system: str, n: int, seed: int,
                gaps: list[float] | None = None) -> list[dict[str, Any]]:
    """The rows of one system (module docstring); ``gaps``: these instead of its ladder's."""
    targets = ladder_targets([system], gaps)[system]
    model = SYSTEMS[system]["model"]()
    X = np.random.default_rng(seed).random((n, model.space.dim))
    on_model = [evaluate(model, x) for x in X]
    stable = [x for x, o in zip(X, on_model) if not o.failed]
    fail_model = float(np.mean([o.failed for o in on_model]))
    rows = []
    for g, target in targets:
        outs = [evaluate(target, x) for x in stable]
        standing = [o.cost for o in outs if not o.failed]
        rows.append({"system": system, "gap": g, "n": n, "n_model_stable": len(stable),
                     "fail_model": round(fail_model, 3),
                     "fail_target": round(float(np.mean([o.failed for o in outs])), 3)
                     if outs else None,
                     "median_cost_standing": float(np.median(standing)) if standing else None})
    return rows


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.gap_ladder")
    ap = bench_parser("benchmarks.gap_ladder", description=__doc__.splitlines()[0])
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gaps", nargs="+", type=float, default=None,
                    help="these gaps on every system instead of its ladder's")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.n < 1:
        error_line("benchmarks.gap_ladder", f"--n must be >= 1, got {a.n}")
        return 2
    try:
        rows = [r for s in a.systems for r in ladder_rows(s, a.n, a.seed, a.gaps)]
    except ValueError as e:
        error_line("benchmarks.gap_ladder", e)
        return 2
    finish(a.out, prov, {"n": a.n, "seed": a.seed, "systems": a.systems, "gaps": a.gaps}, rows,
           title="random θ on the model and on each target")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.gap_ladder"))
