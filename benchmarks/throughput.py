"""Throughput: 2 process workers vs serial on the same batch of rollouts.

    python -m benchmarks.throughput [--n 16] [--steps 5000] [--workers 2] [--robot a1 --task trot]
        [--out FILE.json]

Both evaluators get the same n θ (the manual θ with small perturbations, so every rollout runs
the full horizon). The pool is warmed up first (its start-up is reported separately): a tuning
run pays it once. Goal: ratio ≥ 1.8 with 2 workers on 2 free cores.
"""
from __future__ import annotations

import sys
import time

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.throughput")
    ap = bench_parser("benchmarks.throughput", description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="trot")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    from latentune.pipeline.evaluators import ProcessEvaluator, SerialEvaluator
    from latentune.task import Task

    task = Task(a.robot, a.task, steps=a.steps)
    rng = np.random.default_rng(0)
    X = np.clip(task.space.manual + 0.02 * rng.standard_normal((a.n, task.space.dim)), 0, 1)
    import resource

    t, c = time.perf_counter(), time.process_time()
    ys = SerialEvaluator().map(task, X)
    t_serial, cpu_serial = time.perf_counter() - t, time.process_time() - c
    def children_cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    warm = Task(a.robot, a.task, steps=10)
    # CPU of starting a pool and warming it up (imports, PyBullet worlds), measured on its own
    c0 = children_cpu()
    with ProcessEvaluator(a.workers, start_method="spawn") as ev0:
        ev0.map(warm, X[: a.workers])
    cpu_startup = children_cpu() - c0
    c0 = children_cpu()
    t = time.perf_counter()
    # spawn: the workers are direct children, so RUSAGE_CHILDREN counts them once they exit
    ev = ProcessEvaluator(a.workers, start_method="spawn")
    ev.map(warm, X[: a.workers])                                   # start the workers
    t_start = time.perf_counter() - t
    t = time.perf_counter()
    yp = ev.map(task, X)
    t_pool = time.perf_counter() - t
    ev.close()
    cpu_pool = children_cpu() - c0 - cpu_startup                   # the rollouts only
    assert np.allclose(ys, yp), "pool and serial costs differ"
    out = {"n": a.n, "steps": a.steps, "workers": a.workers, "serial_s": t_serial,
           "pool_s": t_pool, "pool_startup_s": t_start, "ratio": t_serial / t_pool,
           "ratio_with_startup": t_serial / (t_pool + t_start),
           "stable": int(np.sum(ys < 100)),
           "cpu_serial_s": cpu_serial, "cpu_workers_s": cpu_pool,
           # with `workers` free cores the ratio would be about workers x this efficiency
           "cpu_efficiency": cpu_serial / cpu_pool if cpu_pool > 0 else None}
    rows = [{"evaluator": "serial", "wall_s": t_serial, "cpu_s": cpu_serial},
            {"evaluator": f"{a.workers} process workers", "wall_s": t_pool, "cpu_s": cpu_pool,
             "startup_s": t_start}]
    finish(a.out, prov, out, rows, columns=["evaluator", "wall_s", "cpu_s", "startup_s"],
           title=f"{a.n} x {a.robot} {a.task} {a.steps}-step rollouts: ratio {out['ratio']:.2f}x "
                 f"({out['ratio_with_startup']:.2f}x with start-up), CPU efficiency "
                 f"{out['cpu_efficiency'] or float('nan'):.2f}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.throughput"))
