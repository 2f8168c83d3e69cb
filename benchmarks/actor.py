"""Actor speed: a 5000-step rollout vs bare PyBullet stepping of the same robot (same run).

Usage: python -m benchmarks.actor [--robot a1] [--task trot] [--actor convex] [--steps 5000] [--repeat 3]
       [--out FILE.json]

Baselines (:mod:`benchmarks.baseline`): the same World stepped under torque control with a state read
and a stance joint PD every step (the cheapest controller that keeps the robot standing: the
reference), stepSimulation alone with zero torques, and an open-loop replay of the rollout's own
torques (the same motion with no controller). Prints the min over repeats.
"""
from __future__ import annotations

import sys

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import latentune as lt  # noqa: E402
from benchmarks.baseline import (bare_stepping_only, bare_stepping_pd,  # noqa: E402
                                 record_torques, replay_stepping)
from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.actor")
    ap = bench_parser("benchmarks.actor", description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--actor", default="convex")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--repeat", type=int, default=3)
    add_out_arg(ap)
    args = ap.parse_args(argv)
    task = lt.Task(robot=args.robot, gait=args.task, actor=args.actor, steps=args.steps)
    task.rollout(task.space.manual)  # warm up (world build, imports)
    taus = record_torques(task, task.space.manual)
    roll, bare, step_only, replay, res = [], [], [], [], None
    for _ in range(args.repeat):
        res = task.rollout(task.space.manual)
        roll.append(res.wall_s)
        bare.append(bare_stepping_pd(task, args.steps))
        step_only.append(bare_stepping_only(task, args.steps))
        replay.append(replay_stepping(task, taus))
    r, b, so, rp = min(roll), min(bare), min(step_only), min(replay)
    rows = [{"run": "rollout", "s": r, "us_per_step": 1e6 * r / args.steps},
            {"run": "bare stepping + PD", "s": b, "us_per_step": 1e6 * b / args.steps},
            {"run": "stepSimulation alone", "s": so, "us_per_step": 1e6 * so / args.steps},
            {"run": "replay of its torques (open loop)", "s": rp,
             "us_per_step": 1e6 * rp / len(taus)}]
    results = {"robot": args.robot, "task": args.task, "actor": args.actor, "steps": args.steps,
               "repeat": args.repeat, "cost": res.cost, "fell": res.fell,
               # the reference ratio (goal <= 2.0); a collapsed robot steps slower (more
               # contacts); the replay is the gait's own physics, the rest is the actor
               "ratio": r / b, "ratio_step_alone": r / so, "ratio_replay": r / rp}
    finish(args.out, prov, results, rows,
           title=f"{args.robot} {args.task} [{args.actor}] {args.steps} steps: cost "
                 f"{res.cost:.3f}, fell {res.fell}; ratio rollout / bare+PD {r / b:.2f} "
                 f"(goal <= 2.0), / step alone {r / so:.2f}, / replay {r / rp:.2f}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.actor"))
