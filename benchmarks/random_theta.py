"""Share of uniformly random θ (unit box) that fall, per robot × gait × actor.

Usage: python -m benchmarks.random_theta [--robot a1] [--task trot] [--actor convex] [--n 200]
           [--steps 1000] [--widen DECADES] [--target COST] [--workers 1] [--out FILE.json]

Checks the properties the tuning relies on: no exception, every cost finite, fell ⇔ cost ≥ C1,
and a good share falls (the stable set is a proper subset of the box, so there is something for
a latent space to learn).

``--widen K`` samples a box K decades wider on each side of every log-scaled entry (the actor's
box is unchanged; this measures how the stable share and the share below ``--target`` depend on
the box an engineer would choose). ``--target`` (e.g. the manual cost) reports the share p of θ
at or below it: a method whose first points are a space-filling design needs about 1/p
evaluations to reach the target by chance.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from multiprocessing import get_context

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.task import C1  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402

_TASK = None


def widened(space, decades: float):
    """The space with every log-scaled entry's bounds moved out by ``decades`` on each side."""
    f = 10.0 ** (decades * space.log)
    return dataclasses.replace(space, lower=space.lower / f, upper=space.upper * f)


def _init(args) -> None:
    global _TASK
    _TASK = lt.Task(robot=args.robot, gait=args.task, actor=args.actor, steps=args.steps)
    if args.widen:
        _TASK.space = widened(_TASK.space, args.widen)


def _rollout(theta: np.ndarray):
    try:
        r = _TASK.rollout(theta)
        return r.cost, r.fell, None
    except Exception as exc:  # the property under test: this never happens
        return np.nan, True, f"{type(exc).__name__}: {exc}"


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.random_theta")
    ap = bench_parser("benchmarks.random_theta", description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--actor", default="convex")
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--widen", type=float, default=0.0, help="decades added on each side of log bounds")
    ap.add_argument("--target", type=float, default=None, help="report the share of θ with cost ≤ this")
    ap.add_argument("--workers", type=int, default=1)
    add_out_arg(ap)
    args = ap.parse_args(argv)
    _init(args)
    thetas = np.random.default_rng(args.seed).random((args.n, _TASK.space.dim))
    t0 = time.perf_counter()
    if args.workers > 1:
        with get_context("spawn").Pool(args.workers, _init, (args,)) as pool:
            out = pool.map(_rollout, thetas, chunksize=1)
    else:
        out = [_rollout(t) for t in thetas]
    errors = [e for _, _, e in out if e is not None]
    for e in errors[:5]:
        print("EXCEPTION:", e, file=sys.stderr)
    ok = [(c, f) for c, f, e in out if e is None]
    costs = np.array([c for c, _ in ok])
    fell = np.array([f for _, f in ok], dtype=bool)
    stable = costs[costs < C1]
    box = f", box widened by {args.widen:g} decades per side" if args.widen else ""
    wall = time.perf_counter() - t0
    manual = _TASK.rollout(_TASK.space.manual)
    p = float(np.mean(costs <= args.target)) if args.target is not None else None
    row = {"robot": args.robot, "task": args.task, "actor": args.actor, "n": args.n,
           "steps": args.steps, "widen": args.widen, "exceptions": len(errors),
           "all_finite": bool(np.all(np.isfinite(costs))),
           "fell_iff_cost_ge_C1": bool(np.array_equal(fell, costs >= C1)),
           "fell_share": float(fell.mean()) if fell.size else None,
           "stable_min": float(stable.min()) if stable.size else None,
           "stable_median": float(np.median(stable)) if stable.size else None,
           "stable_max": float(stable.max()) if stable.size else None,
           "target": args.target, "p_at_or_below_target": p,
           "manual_cost": manual.cost, "manual_fell": manual.fell}
    finish(args.out, prov, {"seed": args.seed, "wall_s": wall, "errors": errors[:5], **row},
           [row], title=f"{args.n} random θ x {args.steps} steps{box} in {wall:.1f} s")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.random_theta"))
