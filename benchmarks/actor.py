"""Actor speed: a 5000-step rollout vs bare PyBullet stepping of the same robot (same run).

Usage: python benchmarks/actor.py [--robot a1] [--task trot] [--actor convex] [--steps 5000] [--repeat 3]

Baselines (benchmarks/baseline.py): the same World stepped under torque control with a state read
and a stance joint PD every step (the cheapest controller that keeps the robot standing: the
reference), stepSimulation alone with zero torques, and an open-loop replay of the rollout's own
torques (the same motion with no controller). Prints the min over repeats.
"""
from __future__ import annotations

import argparse

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import latentune as lt  # noqa: E402
from baseline import (bare_stepping_only, bare_stepping_pd, record_torques,  # noqa: E402
                      replay_stepping)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--actor", default="convex")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
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
    print(f"{args.robot} {args.task} [{args.actor}] {args.steps} steps: cost {res.cost:.3f}, fell {res.fell}")
    print(f"  rollout                    {r:7.3f} s  ({1e6 * r / args.steps:6.1f} us/step)")
    print(f"  bare stepping + PD         {b:7.3f} s  ({1e6 * b / args.steps:6.1f} us/step)")
    print(f"  stepSimulation alone       {so:7.3f} s  ({1e6 * so / args.steps:6.1f} us/step)")
    print(f"  replay of its torques      {rp:7.3f} s  ({1e6 * rp / len(taus):6.1f} us/step, "
          f"same motion, open loop)")
    print(f"  ratio rollout / bare+PD    {r / b:7.2f}   (the reference; goal <= 2.0)")
    print(f"  ratio rollout / step alone {r / so:7.2f}   (collapsed robot: more contacts, slower steps)")
    print(f"  ratio rollout / replay     {r / rp:7.2f}   (the gait's own physics; the rest is the actor)")


if __name__ == "__main__":
    main()
