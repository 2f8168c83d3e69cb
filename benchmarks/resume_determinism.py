"""What a resume reproduces: the same seed run uninterrupted, and stopped then resumed.

    python benchmarks/resume_determinism.py [--seeds 0 1 2 3 4] [--budget 100] [--stop 40]
        [--method turbo] [--dim 10] [--out results/benchmarks/resume_determinism.json]

For each seed: a Study runs phase 1 on a shifted Levy function (d = --dim) for --budget
evaluations; a second Study with the same seed stops after --stop evaluations (between batches)
and is resumed to the budget. Reports the first evaluation where the two runs differ and both
bests.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from sample_efficiency import provenance  # noqa: E402


def levy(x: np.ndarray) -> float:
    """Levy function of x (d,) in [-5, 5]^d shifted by 0.7 (minimum 0)."""
    w = 1 + (x - 0.7 - 1) / 4
    return float(np.sin(np.pi * w[0]) ** 2 + np.sum((w[:-1] - 1) ** 2 * (1 + 10 * np.sin(np.pi * w[:-1] + 1) ** 2))
                 + (w[-1] - 1) ** 2 * (1 + np.sin(2 * np.pi * w[-1]) ** 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--stop", type=int, default=40)
    ap.add_argument("--method", default="turbo")
    ap.add_argument("--dim", type=int, default=10)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    t0 = time.perf_counter()
    space = lt.ParameterSpace([f"x{i}" for i in range(a.dim)], [-5] * a.dim, [5] * a.dim,
                              manual=[2.0] * a.dim)
    system = lt.FunctionSystem(space, levy)
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
              f"uninterrupted vs {rows[-1]['best_resumed']:.4f} resumed", flush=True)
        whole.close()
        part.close()
    bw = np.array([r["best_whole"] for r in rows])
    br = np.array([r["best_resumed"] for r in rows])
    print(f"median best: {np.median(bw):.4f} uninterrupted, {np.median(br):.4f} resumed; "
          f"median |difference| {np.median(np.abs(bw - br)):.4f}")
    if a.out:
        Path(a.out).write_text(json.dumps({"method": a.method, "dim": a.dim, "budget": a.budget,
                                           "stop": a.stop, "seeds": a.seeds, "results": rows,
                                           "provenance": provenance(sys.argv, t0)}, indent=1))


if __name__ == "__main__":
    main()
