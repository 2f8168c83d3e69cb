"""``latentune bench``: the performance-ratio benchmarks of ``benchmarks/`` at a quick size.

Each benchmark script runs in a subprocess with one BLAS thread; its ratio lines are printed.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from latentune.errors import CLIError
from latentune.threads import thread_env

BENCHES = (
    ("actor", ["benchmarks/actor.py", "--repeat", "1"], "steps"),
    ("critic --overhead", ["benchmarks/critic.py", "--overhead", "--overhead-sizes", "1000",
                           "--overhead-asks", "3"], None),
    ("throughput", ["benchmarks/throughput.py"], "steps"),
)


def repo_root() -> Path | None:
    """The source checkout holding ``benchmarks/`` (None for an installed package)."""
    here = Path(__file__).resolve()
    for base in here.parents:
        if (base / "benchmarks").is_dir() and (base / "pyproject.toml").is_file():
            return base
    return None


def run_bench(steps: int = 2000, n: int = 8, timeout: float = 900.0) -> int:
    """Run the benchmark scripts; print their ratio lines. Returns 0 if all succeeded, else 1."""
    if steps < 1 or n < 1:
        raise CLIError("--steps and --n must be >= 1")
    if not timeout > 0:
        raise CLIError(f"--timeout must be > 0, got {timeout}")
    root = repo_root()
    if root is None:
        raise CLIError("benchmarks/ not found (run bench from a source checkout)")
    env = dict(os.environ, **thread_env())
    status = 0
    for name, cmd, steps_flag in BENCHES:
        script = root / cmd[0]
        if not script.is_file():
            print(f"== {name}: {cmd[0]} missing (skipped)")
            continue
        argv = [sys.executable, str(script), *cmd[1:]]
        if steps_flag:
            argv += ["--steps", str(steps)]
        if name == "throughput":
            argv += ["--n", str(n)]
        print(f"== {name}: {' '.join(argv[1:])}", flush=True)
        t = time.perf_counter()
        try:
            r = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=root,
                               timeout=timeout)
        except subprocess.TimeoutExpired:
            print(f"   timed out after {timeout:.0f} s")
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
