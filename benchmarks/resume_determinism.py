"""What a resume reproduces: the same seed run uninterrupted, and stopped then resumed.

    python -m benchmarks.resume_determinism [--seeds 0 1 2 3 4] [--budget 100] [--stop 40]
        [--kill] [--method turbo] [--dim 10] [--out FILE.json]

For each seed: a Study runs phase 1 on :func:`benchmarks.common.shifted_levy` (d = --dim) for --budget
evaluations; a second Study with the same seed stops after --stop evaluations and is resumed to
the budget. Reports the first evaluation where the two runs differ and both bests.

The stop: ``max_new`` (between batches) by default; with ``--kill`` the stopped run is a child
process that sends itself SIGKILL while it evaluates trial --stop (the study runs its trials
serially, in batches of 4: --stop 42 kills it in the middle of a batch, with two of the batch's
trials stored). ``--method`` takes the Optuna samplers too (``optuna-tpe``, ``optuna-cmaes``,
``optuna-gp``).
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import sys
import tempfile
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, finish,  # noqa: E402
                               shifted_levy)


def _space(dim: int) -> lt.ParameterSpace:
    return lt.ParameterSpace([f"x{i}" for i in range(dim)], [-5] * dim, [5] * dim,
                             manual=[2.0] * dim)


class _DieAt:
    """``shifted_levy`` that SIGKILLs its process at its ``calls``-th call."""

    def __init__(self, calls: int) -> None:
        self.calls = calls

    def __call__(self, x: np.ndarray) -> float:
        self.calls -= 1
        if self.calls == 0:
            os.kill(os.getpid(), signal.SIGKILL)
        return shifted_levy(x)


def _killed_phase1(path: str, seed: int, dim: int, budget: int, method: str, stop: int) -> None:
    """The child of ``--kill``: phase 1 in ``path`` until the process dies evaluating trial
    ``stop`` (the manual θ is evaluated once, as phase 0, and is phase 1's first trial: call
    ``stop + 1`` of the function is trial ``stop``)."""
    system = lt.FunctionSystem(_space(dim), _DieAt(stop + 1), name="shifted_levy")
    lt.Study(path, seed=seed).phase1(system, budget, method=method)


def _stop_by_kill(path: Path, seed: int, a: argparse.Namespace) -> None:
    proc = multiprocessing.get_context("spawn").Process(
        target=_killed_phase1, args=(str(path), seed, a.dim, a.budget, a.method, a.stop))
    proc.start()
    proc.join()
    if proc.exitcode != -signal.SIGKILL:
        raise RuntimeError(f"the run to be killed ended with exit code {proc.exitcode}")
    with lt.Study(path, seed=seed) as st:
        n = st.store.count(1)
    if n != a.stop:
        raise RuntimeError(f"the killed run stored {n} trials, not --stop {a.stop}")


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.resume_determinism")
    ap = bench_parser("benchmarks.resume_determinism", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--stop", type=int, default=40)
    ap.add_argument("--kill", action="store_true",
                    help="stop by SIGKILL while trial --stop runs (else between batches)")
    ap.add_argument("--method", default="turbo")
    ap.add_argument("--dim", type=int, default=10)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.dim < 1 or not 1 <= a.stop < a.budget:     # else nothing is resumed: a vacuous "same"
        ap.error(f"--dim must be >= 1 and --stop in [1, --budget - 1], got --dim {a.dim}, "
                 f"--stop {a.stop}, --budget {a.budget}")
    system = lt.FunctionSystem(_space(a.dim), shifted_levy)
    work = Path(tempfile.mkdtemp(prefix="lt_resume_"))
    rows = []
    for s in a.seeds:
        whole = lt.Study(work / f"whole{s}", seed=s)
        whole.phase1(system, a.budget, method=a.method)
        if a.kill:
            _stop_by_kill(work / f"part{s}", s, a)
        else:
            part = lt.Study(work / f"part{s}", seed=s)
            part.phase1(system, a.budget, method=a.method, max_new=a.stop)
            part.close()
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
                         "stop_kind": "SIGKILL mid-trial" if a.kill else "between batches",
                         "seeds": a.seeds, "median_best_whole": float(np.median(bw)),
                         "median_best_resumed": float(np.median(br)),
                         "median_abs_difference": float(np.median(np.abs(bw - br)))}, rows,
           title=f"{a.method}, d = {a.dim}, budget {a.budget}, "
                 f"{'killed' if a.kill else 'stopped'} at {a.stop} and resumed")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.resume_determinism"))
