"""``latentune paper`` and ``latentune bench`` (the CLI hook ``add_commands``).

``latentune report DIR`` on a paper directory (one holding ``paper.json`` and no ``run.db``) is
routed to the paper report: :func:`add_commands` wraps the pipeline's ``report`` handler.
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def _cli_error(msg: str) -> Exception:
    """``CLIError`` of the running CLI module (``python -m latentune.cli`` runs it as __main__)."""
    m = sys.modules.get("__main__")
    spec = getattr(m, "__spec__", None)
    if spec is not None and spec.name == "latentune.cli":
        return m.CLIError(msg)
    from latentune.cli import CLIError

    return CLIError(msg)


def _float(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise _cli_error(f"--scale must be a number, got {s!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise _cli_error(f"--scale must be a finite number > 0, got {s}")
    return v


def add_commands(subparsers: Any) -> None:
    from latentune.experiments.paper import MAPPING_DOC

    p = subparsers.add_parser("paper", help="the paper's studies end to end, with a budget scale")
    p.add_argument("--robot", default="a1", help="a1 (convex MPC; adds A1→B1 transfer) or solo12")
    p.add_argument("--actor", default=None, help="default: convex for a1, kinodynamic for solo12")
    p.add_argument("--scale", type=_float, default=0.03,
                   help=f"budget scale, 1.0 = the paper's budgets ({MAPPING_DOC}); default 0.03")
    p.add_argument("--phase1-evals", type=int, default=None, help="override the phase-1 budget")
    p.add_argument("--phase3-evals", type=int, default=None,
                   help="override the phase-3 (and baseline) budget")
    p.add_argument("--out", default=None, help="output directory (default paper-<robot>)")
    p.add_argument("--workers", type=int, default=2, help="parallel rollouts")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=5000, help="rollout horizon in 1 kHz steps")
    p.add_argument("--v-des", type=float, default=0.5)
    p.add_argument("--report-only", action="store_true", help="only (re)write DIR/report.md")
    p.add_argument("--no-sim", action="store_true", help="report: skip re-simulated CoM plots/GIFs")
    p.add_argument("--no-gif", action="store_true", help="report: skip the GIFs")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_paper)

    b = subparsers.add_parser("bench", help="the performance-ratio benchmarks at a quick size")
    b.add_argument("--steps", type=int, default=2000, help="rollout steps (default 2000)")
    b.add_argument("--n", type=int, default=8, help="rollouts of the throughput benchmark")
    b.add_argument("--timeout", type=float, default=900, help="per benchmark [s]")
    b.set_defaults(func=cmd_bench)

    rep = subparsers.choices.get("report") if hasattr(subparsers, "choices") else None
    if rep is not None:
        orig = rep.get_default("func")
        if orig is not None:
            def report(args: argparse.Namespace, _orig=orig) -> int:
                d = Path(args.dir)
                if (d / "paper.json").is_file() and not (d / "run.db").is_file():
                    from latentune.experiments.report import write_paper_report

                    text = write_paper_report(d, simulate=not args.no_sim, gifs=True,
                                              log=(lambda m: None) if args.quiet else
                                              (lambda m: print(m, file=sys.stderr)))
                    print(text)
                    return 0
                return _orig(args)

            rep.set_defaults(func=report)


def _cmd_paper(args: argparse.Namespace) -> int:
    from latentune.experiments.paper import cmd_paper

    if args.out is None:
        args.out = f"paper-{str(args.robot).lower()}"
    return cmd_paper(args)


BENCHES = (
    ("actor", ["benchmarks/actor.py", "--repeat", "1"], "steps"),
    ("critic --overhead", ["benchmarks/critic.py", "--overhead", "--overhead-sizes", "1000",
                           "--overhead-asks", "3"], None),
    ("throughput", ["benchmarks/throughput.py"], "steps"),
)


def _repo_root() -> Path | None:
    here = Path(__file__).resolve()
    for base in here.parents:
        if (base / "benchmarks").is_dir() and (base / "pyproject.toml").is_file():
            return base
    return None


def cmd_bench(args: argparse.Namespace) -> int:
    """Run the benchmark scripts (subprocesses) at a quick size; print their ratio lines."""
    if args.steps < 1 or args.n < 1:
        raise _cli_error("--steps and --n must be >= 1")
    root = _repo_root()
    if root is None:
        raise _cli_error("benchmarks/ not found (run bench from a source checkout)")
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    status = 0
    for name, cmd, steps_flag in BENCHES:
        script = root / cmd[0]
        if not script.is_file():
            print(f"== {name}: {cmd[0]} missing (skipped)")
            continue
        argv = [sys.executable, str(script), *cmd[1:]]
        if steps_flag:
            argv += ["--steps", str(args.steps)]
        if name == "throughput":
            argv += ["--n", str(args.n)]
        print(f"== {name}: {' '.join(argv[1:])}", flush=True)
        t = time.perf_counter()
        try:
            r = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=root,
                               timeout=args.timeout)
        except subprocess.TimeoutExpired:
            print(f"   timed out after {args.timeout:.0f} s")
            status = 1
            continue
        lines = [ln for ln in r.stdout.splitlines() if ln.strip()]
        ratio = [ln for ln in lines if "ratio" in ln.lower() or "×" in ln or "x " in ln.lower()]
        for ln in (ratio or lines[-10:]):
            print("   " + ln)
        if r.returncode != 0:
            status = 1
            err = r.stderr.strip().splitlines()
            print(f"   exit {r.returncode}: {err[-1] if err else ''}")
        print(f"   ({time.perf_counter() - t:.0f} s)", flush=True)
    return status
