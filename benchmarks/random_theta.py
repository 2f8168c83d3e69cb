"""Share of uniformly random θ (unit box) that fall, per robot × gait × actor.

Usage: python benchmarks/random_theta.py [--robot a1] [--task trot] [--actor convex] [--n 200] [--steps 1000]

Checks the properties the tuning relies on: no exception, every cost finite, fell ⇔ cost ≥ C1,
and a good share falls (the stable set is a proper subset of the box, so there is something for
a latent space to learn).
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.task import C1  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--actor", default="convex")
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    task = lt.Task(robot=args.robot, gait=args.task, actor=args.actor, steps=args.steps)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    costs, fell, errors = [], [], 0
    for _ in range(args.n):
        try:
            r = task.rollout(rng.random(task.space.dim))
        except Exception as exc:  # the property under test: this never happens
            errors += 1
            print("EXCEPTION:", type(exc).__name__, exc)
            continue
        costs.append(r.cost)
        fell.append(r.fell)
    costs, fell = np.array(costs), np.array(fell)
    stable = costs[costs < C1]
    print(f"{args.robot} {args.task} [{args.actor}] {args.n} random θ x {args.steps} steps "
          f"in {time.perf_counter() - t0:.1f} s")
    print(f"  exceptions: {errors}; all costs finite: {bool(np.all(np.isfinite(costs)))}; "
          f"fell <=> cost >= C1: {bool(np.array_equal(fell, costs >= C1))}")
    print(f"  fell: {fell.sum()}/{fell.size} = {fell.mean():.1%}")
    if stable.size:
        print(f"  stable costs: min {stable.min():.2f}, median {np.median(stable):.2f}, max {stable.max():.2f}")
    manual = task.rollout(task.space.manual)
    print(f"  manual θ: cost {manual.cost:.2f} (fell {manual.fell})")


if __name__ == "__main__":
    main()
