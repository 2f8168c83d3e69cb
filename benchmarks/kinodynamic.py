"""Kino-dynamic MPC actor: speed (vs bare stepping, same run), replanning breakdown, random-θ share.

Usage:
    python -m benchmarks.kinodynamic [--robot solo12] [--task trot] [--steps 5000] [--repeat 3]
                                     [--random 100] [--random-steps 5000] [--seed 0]
                                     [--out FILE.json]

1. Speed: wall time of a ``--steps`` rollout with the manual θ next to bare stepping of the same
   World in the same process — (a) stepping with state reads and a one-line stance PD (the cheapest
   controller that keeps the robot up: the reference "bare stepping"; the ratio goal is rollout ≤ 4×
   this) and (b) ``stepSimulation`` alone with zero torques (the robot collapses onto its body, whose
   extra contacts make this *slower* than (a) on Solo12) — min over ``--repeat``.
2. Breakdown per replanning step (every 50 physics steps): centroidal planner, whole-body DDP, the
   rest of the replanning (state conversion, footholds, references), and the 1 kHz tracking
   controller per physics step.
3. ``--random`` uniform random normalized θ (seeded): no exception, every cost finite,
   ``fell`` ⇔ cost ≥ 100, and the stable share.
"""
from __future__ import annotations

import sys
import time

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.actor import kinodynamic as kd  # noqa: E402
from latentune.task import C1  # noqa: E402
from benchmarks.baseline import bare_stepping_only, bare_stepping_pd  # noqa: E402
from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402


class _Recorder:
    """Keeps the last constructed actor so its timing counters can be read after a rollout."""

    def __init__(self) -> None:
        self.actor = None
        self._orig = kd.KinodynamicMPC.__init__
        rec = self

        def init(actor, *a, **k):
            rec._orig(actor, *a, **k)
            rec.actor = actor

        kd.KinodynamicMPC.__init__ = init


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.kinodynamic")
    ap = bench_parser("benchmarks.kinodynamic", description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="solo12")
    ap.add_argument("--task", default="trot")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--random", type=int, default=100)
    ap.add_argument("--random-steps", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    add_out_arg(ap)
    args = ap.parse_args(argv)

    rec = _Recorder()
    task = lt.Task(robot=args.robot, gait=args.task, actor="kinodynamic", steps=args.steps)
    theta = task.space.manual
    task.rollout(theta)  # warm-up (URDF parse, model build)
    roll, only, pd, res, breakdown = [], [], [], None, None
    for _ in range(args.repeat):
        only.append(bare_stepping_only(task, args.steps))
        pd.append(bare_stepping_pd(task, args.steps))
        t0 = time.perf_counter()
        res = task.rollout(theta)
        roll.append(time.perf_counter() - t0)
        a = rec.actor
        n = max(1, a.n_replan)
        breakdown = {
            "centroidal_ms": 1e3 * a.timing["centroidal"] / n,
            "ddp_ms": 1e3 * a.timing["ddp"] / n,
            "replan_rest_ms": 1e3 * (a.timing["replan"] - a.timing["centroidal"] - a.timing["ddp"]) / n,
            "replan_total_ms": 1e3 * a.timing["replan"] / n,
            "tracking_us_per_step": 1e6 * a.timing["control"] / max(1, a.n_control),
            "replans": a.n_replan,
        }
    out = {
        "robot": args.robot, "task": args.task, "steps": args.steps,
        "ddp_iters_cap": kd.KinodynamicMPC.DDP_ITERS,
        "manual": {k: v for k, v in res.summary().items()},
        "rollout_s": min(roll), "bare_step_only_s": min(only), "bare_step_pd_s": min(pd),
        "ratio_vs_step_only": min(roll) / min(only), "ratio_vs_step_pd": min(roll) / min(pd),
        "replan_breakdown": breakdown,
    }
    out["ratio"] = out["ratio_vs_step_pd"]          # the reference ratio (goal <= 4)
    b = breakdown
    rows = [{"run": "rollout (kinodynamic, manual θ)", "s": out["rollout_s"], "ratio": 1.0},
            {"run": "bare stepping + state + PD", "s": out["bare_step_pd_s"],
             "ratio": out["ratio_vs_step_pd"]},
            {"run": "stepSimulation only, zero torque", "s": out["bare_step_only_s"],
             "ratio": out["ratio_vs_step_only"]}]
    notes = [f"per replanning step: centroidal {b['centroidal_ms']:.2f} ms, DDP "
             f"{b['ddp_ms']:.2f} ms, rest {b['replan_rest_ms']:.2f} ms (total "
             f"{b['replan_total_ms']:.2f} ms); tracking {b['tracking_us_per_step']:.1f} µs/step"]

    if args.random > 0:
        rtask = lt.Task(robot=args.robot, gait=args.task, actor="kinodynamic", steps=args.random_steps)
        rng = np.random.default_rng(args.seed)
        costs, fells, reasons = [], [], {}
        t0 = time.perf_counter()
        for i in range(args.random):
            r = rtask.rollout(rng.random(rtask.space.dim))
            if not np.isfinite(r.cost) or r.fell != (r.cost >= C1):
                raise SystemExit(f"random θ #{i}: bad result {r.summary()}")
            costs.append(r.cost)
            fells.append(r.fell)
            key = r.reason.split(" (")[0].split(" ")[0:2]
            key = " ".join(key) if r.reason else "stable"
            reasons[key] = reasons.get(key, 0) + 1
        costs = np.array(costs)
        out["random"] = {"n": args.random, "steps": args.random_steps, "seed": args.seed,
                         "stable_share": float(1.0 - np.mean(fells)),
                         "median_cost_stable": float(np.median(costs[costs < 100])) if np.any(costs < 100) else None,
                         "outcomes": reasons, "wall_s": time.perf_counter() - t0}
        notes.append(f"random θ: {args.random} × {args.random_steps} steps: stable share "
                     f"{out['random']['stable_share']:.2f}; outcomes {reasons}; all costs "
                     "finite, fell ⇔ cost ≥ C1")
    finish(args.out, prov, out, rows,
           title=f"{args.robot} {args.task}, {args.steps} steps (min of {args.repeat}): cost "
                 f"{res.cost:.2f}, fell {res.fell}, mean_vx {res.mean_vx:.3f}; ratio rollout / "
                 f"bare+PD {out['ratio']:.2f} (goal <= 4)")
    for line in notes:
        print(f"\n{line}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.kinodynamic"))
