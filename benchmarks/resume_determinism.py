"""What a resume reproduces: the same seed run uninterrupted, and stopped then resumed.

    python -m benchmarks.resume_determinism [--seeds 0 1 2 3 4] [--budget 100] [--stop 40]
        [--method turbo] [--dim 10] [--out FILE.json]

For each seed: a Study runs phase 1 on :func:`benchmarks.common.shifted_levy` (d = --dim) for --budget
evaluations; a second Study with the same seed stops after --stop evaluations (between batches)
and is resumed to the budget. Reports the first evaluation where the two runs differ and both
bests.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, finish, shifted_levy  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.resume_determinism")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--stop", type=int, default=40)
    ap.add_argument("--method", default="turbo")
    ap.add_argument("--dim", type=int, default=10)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    space = lt.ParameterSpace([f"x{i}" for i in range(a.dim)], [-5] * a.dim, [5] * a.dim,
                              manual=[2.0] * a.dim)
    system = lt.FunctionSystem(space, shifted_levy)
    work = Path(tempfile.mkdtemp(prefix="lt_resume_"))
    rows = []
    for s in a.seeds:
        whole = lt.Study(work / f"whole{s}", seed=s)
        whole.phase1(system, a.budget, method=a.method)
        part = lt.Study(work / f"part{s}", seed=s)
        part.phase1(system, a.budget, method=a.method, max_new=a.stop)
        part = lt.Study(work / f"part{s}", seed=s)
        part.phase1(system, a.budget, method=a.method)
        tw = [tuple(r.theta) for r in whole.store.rows(1)]
        tp = [tuple(r.theta) for r in part.store.rows(1)]
        first = next((i for i, (x, y) in enumerate(zip(tw, tp)) if x != y), None)
        rows.append({"seed": s, "first_difference": first, "best_whole": whole.best().cost,
                     "best_resumed": part.best().cost})
        print(f"seed {s}: first difference at evaluation {first}, best {rows[-1]['best_whole']:.4f} "
              f"uninterrupted vs {rows[-1]['best_resumed']:.4f} resumed", file=sys.stderr, flush=True)
        whole.close()
        part.close()
    bw = np.array([r["best_whole"] for r in rows])
    br = np.array([r["best_resumed"] for r in rows])
    finish(a.out, prov, {"method": a.method, "dim": a.dim, "budget": a.budget, "stop": a.stop,
                         "seeds": a.seeds, "median_best_whole": float(np.median(bw)),
                         "median_best_resumed": float(np.median(br)),
                         "median_abs_difference": float(np.median(np.abs(bw - br)))}, rows,
           title=f"{a.method}, d = {a.dim}, budget {a.budget}, stopped at {a.stop} and resumed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
