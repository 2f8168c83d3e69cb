"""Rollout profile: where a warm rollout's CPU time goes (cProfile on process CPU time).

    python -m benchmarks.rollout_profile [--tasks a1:trot,a1:jump,b1:trot,solo12:trot]
        [--steps 5000] [--per-task 3] [--top 20] [--out FILE.json]

For each task (``robot:gait``, the robot's actor as in :mod:`benchmarks.rollout_identity`): one
unprofiled warm-up rollout (world build, imports), then ``--per-task`` rollouts of the θ of
:func:`benchmarks.rollout_identity.thetas` under cProfile with ``time.process_time`` as its clock
(CPU seconds: other processes on a loaded machine do not inflate them). Reports, per task, the
profiled CPU seconds per rollout and the ``--top`` functions by own time (``tottime``) and by
cumulative time, in CPU seconds per rollout. cProfile's own overhead inflates Python-heavy code
more than C calls: the shares are a guide, the rollout timings of :mod:`benchmarks.rollout_speed`
are the measurement. The output records the directory ``latentune`` was imported from (put an
export of older code first on ``PYTHONPATH`` to profile it).
"""
from __future__ import annotations

import cProfile
import pstats
import sys
import time
from pathlib import Path
from typing import Any

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)
from benchmarks.rollout_identity import ROBOT_ACTOR, thetas  # noqa: E402


def _name(func: tuple[str, int, str]) -> str:
    file, line, name = func
    if file == "~":
        return name                                   # a built-in, e.g. <built-in method ...>
    parts = file.replace("\\", "/").split("/")
    short = "/".join(parts[-2:]) if "latentune" in parts else parts[-1]
    return f"{short}:{line}({name})"


def profile_task(robot: str, gait: str, steps: int, per_task: int, top: int) -> dict[str, Any]:
    """Profile of ``per_task`` warm rollouts of one task (see the module docstring)."""
    from latentune.task import Task

    task = Task(robot, gait, actor=ROBOT_ACTOR[robot], steps=steps)
    ths = thetas(task, per_task)
    task.rollout(ths[0])                                  # warm-up: world, imports, caches
    prof = cProfile.Profile(time.process_time)
    costs, cpu = [], 0.0
    for th in ths:
        c = time.process_time()
        prof.enable()
        res = task.rollout(th)
        prof.disable()
        cpu += time.process_time() - c
        costs.append(res.cost)
    task.world.close()
    st = pstats.Stats(prof)
    stats = st.stats  # type: ignore[attr-defined]
    rows = [(_name(f), cc, nc, tt, ct) for f, (cc, nc, tt, ct, _) in stats.items()]
    n = len(ths)

    def table(key: int) -> list[dict[str, Any]]:
        best = sorted(rows, key=lambda r: -r[key])[:top]
        return [{"function": r[0], "calls_per_rollout": r[2] / n,
                 "own_s": r[3] / n, "cum_s": r[4] / n} for r in best]

    return {"robot": robot, "gait": gait, "actor": task.actor, "steps": steps, "rollouts": n,
            "costs": costs, "cpu_s_per_rollout": cpu / n,
            "by_own": table(3), "by_cumulative": table(4)}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.rollout_profile")
    ap = bench_parser("benchmarks.rollout_profile", description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="a1:trot,a1:jump,b1:trot,solo12:trot")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--per-task", type=int, default=3)
    ap.add_argument("--top", type=int, default=20)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    tasks = [tuple(t.split(":")) for t in a.tasks.split(",")]
    if any(len(t) != 2 or t[0] not in ROBOT_ACTOR for t in tasks) or a.steps < 1 \
            or a.per_task < 1 or a.top < 1:
        error_line("benchmarks.rollout_profile",
                   f"--tasks must be robot:gait pairs with robots in "
                   f"{', '.join(ROBOT_ACTOR)}; --steps, --per-task, --top >= 1")
        return 2
    profiles = [profile_task(r, g, a.steps, a.per_task, a.top) for r, g in tasks]
    rows = []
    for p in profiles:
        rows.append({"task": f"{p['robot']} {p['gait']}", "function": "(rollout, profiled)",
                     "own_s": None, "cum_s": p["cpu_s_per_rollout"]})
        rows += [{"task": "", **{k: r[k] for k in ("function", "own_s", "cum_s")}}
                 for r in p["by_own"]]
    import latentune

    src = str(Path(latentune.__file__).resolve().parent)   # which code was profiled
    finish(a.out, prov, {"steps": a.steps, "per_task": a.per_task, "latentune_src": src,
                         "profiles": profiles}, rows,
           columns=["task", "function", "own_s", "cum_s"],
           title=f"CPU seconds per warm {a.steps}-step rollout (cProfile, top {a.top} by own time)")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.rollout_profile"))
