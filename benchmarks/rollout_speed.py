"""Rollout speed: warm rollout time of this checkout's code against another source tree, paired.

    python -m benchmarks.rollout_speed --base-src DIR [--tasks a1:trot,solo12:trot]
        [--steps 5000] [--rounds 10] [--out FILE.json]

For each task (``robot:gait``, the robot's actor as in :mod:`benchmarks.rollout_identity`) two
worker processes are started, one importing ``latentune`` from ``--base-src`` (e.g. an export of
the code before a change: ``git archive COMMIT src | tar -x -C DIR``), one from this checkout's
``src``; each builds its Task and runs one unrecorded warm-up rollout. Then ``--rounds`` rounds
ask both for the same rollouts of the θ of :func:`benchmarks.rollout_identity.thetas` (round i:
θ number i mod 3), in the order base, new in even rounds and new, base in odd ones, so that both
see the same machine load; only one rollout runs at a time. Each worker reports the rollout's
wall time (``RolloutResult.wall_s``) and its process CPU time. ``ratio`` = median(new) /
median(base) of the wall time (``cpu_ratio``: of the CPU time): below 1 the new code is faster;
``pair_ratio`` (``pair_cpu_ratio``) is the median over rounds of new / base within the round,
which a drift of the machine's speed during the run moves less.
The costs of the two must be bit-identical: any difference is listed (``cost_mismatches``) and
makes the exit status 1.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env, thread_env  # noqa: E402

one_thread_env()

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)

ROOT = Path(__file__).resolve().parents[1]


def worker(robot: str, gait: str, steps: int) -> int:
    """Serve rollouts: read a θ index per stdin line, answer one JSON line (cost as float.hex,
    wall_s, cpu_s); ``ready`` once the warm-up rollout is done."""
    from benchmarks.rollout_identity import ROBOT_ACTOR, thetas
    from latentune.task import Task

    task = Task(robot, gait, actor=ROBOT_ACTOR[robot], steps=steps)
    ths = thetas(task, 3)
    task.rollout(ths[0])
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        i = int(line)
        c = time.process_time()
        res = task.rollout(ths[i % len(ths)])
        cpu = time.process_time() - c
        print(json.dumps({"cost": float(res.cost).hex(), "wall_s": res.wall_s, "cpu_s": cpu}),
              flush=True)
    return 0


class _Worker:
    def __init__(self, src: Path, robot: str, gait: str, steps: int):
        env = dict(os.environ, **thread_env(), PYTHONPATH=os.pathsep.join([str(src), str(ROOT)]))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.rollout_speed", "--worker", f"{robot}:{gait}",
             "--steps", str(steps)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            env=env, cwd=ROOT)
        self._read()

    def _read(self) -> dict[str, Any]:
        line = self.proc.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise RuntimeError(f"rollout worker exited ({self.proc.wait()})")
        return json.loads(line)

    def rollout(self, i: int) -> dict[str, Any]:
        self.proc.stdin.write(f"{i}\n")  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]
        return self._read()

    def close(self) -> None:
        self.proc.stdin.close()  # type: ignore[union-attr]
        self.proc.wait()


def compare_task(base_src: Path, robot: str, gait: str, steps: int, rounds: int
                 ) -> dict[str, Any]:
    """Paired warm-rollout timings of one task (see the module docstring)."""
    new_src = ROOT / "src"
    base, new = _Worker(base_src, robot, gait, steps), _Worker(new_src, robot, gait, steps)
    runs: dict[str, list[dict[str, Any]]] = {"base": [], "new": []}
    mismatches = []
    try:
        for i in range(rounds):
            order = (("base", base), ("new", new)) if i % 2 == 0 else (("new", new), ("base", base))
            got = {name: w.rollout(i) for name, w in order}
            for name in runs:
                runs[name].append(got[name])
            if got["base"]["cost"] != got["new"]["cost"]:
                mismatches.append({"round": i, "base": got["base"]["cost"],
                                   "new": got["new"]["cost"]})
    finally:
        base.close()
        new.close()

    def med(name: str, key: str) -> float:
        return statistics.median(r[key] for r in runs[name])

    return {"robot": robot, "gait": gait, "steps": steps, "rounds": rounds,
            "base_wall_s": med("base", "wall_s"), "new_wall_s": med("new", "wall_s"),
            "base_cpu_s": med("base", "cpu_s"), "new_cpu_s": med("new", "cpu_s"),
            "ratio": med("new", "wall_s") / med("base", "wall_s"),
            "cpu_ratio": med("new", "cpu_s") / med("base", "cpu_s"),
            "pair_ratio": statistics.median(n["wall_s"] / b["wall_s"]
                                            for b, n in zip(runs["base"], runs["new"])),
            "pair_cpu_ratio": statistics.median(n["cpu_s"] / b["cpu_s"]
                                                for b, n in zip(runs["base"], runs["new"])),
            "cost_mismatches": mismatches, "runs": runs}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.rollout_speed")
    ap = bench_parser("benchmarks.rollout_speed", description=__doc__.splitlines()[0])
    ap.add_argument("--base-src", type=Path, help="the src directory of the code to compare to")
    ap.add_argument("--tasks", default="a1:trot,solo12:trot")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--worker", metavar="ROBOT:GAIT", help=argparse.SUPPRESS)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if a.worker:
        robot, gait = a.worker.split(":")
        return worker(robot, gait, a.steps)
    from benchmarks.rollout_identity import ROBOT_ACTOR

    tasks = [tuple(t.split(":")) for t in a.tasks.split(",")]
    if a.base_src is None or not (a.base_src / "latentune" / "task.py").is_file() \
            or any(len(t) != 2 or t[0] not in ROBOT_ACTOR for t in tasks) \
            or a.steps < 1 or a.rounds < 1:
        error_line("benchmarks.rollout_speed",
                   "--base-src must be a src directory holding latentune/; "
                   f"--tasks robot:gait pairs with robots in {', '.join(ROBOT_ACTOR)}; --steps, "
                   "--rounds >= 1")
        return 2
    results = [compare_task(a.base_src.resolve(), r, g, a.steps, a.rounds) for r, g in tasks]
    rows = [{"task": f"{r['robot']} {r['gait']}", "base_wall_s": r["base_wall_s"],
             "new_wall_s": r["new_wall_s"], "ratio": r["ratio"], "base_cpu_s": r["base_cpu_s"],
             "new_cpu_s": r["new_cpu_s"], "cpu_ratio": r["cpu_ratio"],
             "pair_ratio": r["pair_ratio"], "pair_cpu_ratio": r["pair_cpu_ratio"],
             "cost_mismatches": len(r["cost_mismatches"])} for r in results]
    finish(a.out, prov, {"base_src": str(a.base_src), "steps": a.steps, "rounds": a.rounds,
                         "tasks": results}, rows,
           title=f"median warm {a.steps}-step rollout, this checkout (new) / {a.base_src} "
                 f"(base), {a.rounds} paired rounds")
    return 1 if any(r["cost_mismatches"] for r in results) else 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.rollout_speed"))
