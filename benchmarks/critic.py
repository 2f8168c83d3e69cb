"""Critic benchmarks: solution quality on unit-box test functions, and TuRBO-m overhead.

Quality (default): every (function, method, seed) runs ``latentune.minimize`` with the given
budget and batch size; a table gives the median best value and its min/max over seeds.

    python benchmarks/critic.py --functions ackley20 levy25 --methods turbo cma random \
        --budget 1000 --seeds 1 --batch-size 20

Overhead (``--overhead``): TuRBO-m with d = 25, batch 20, 10 regions is told N uniform random
points (untagged: they are spread over the regions), then asks/tells ``--overhead-asks`` batches
on Ackley; prints the critic's seconds per suggested point for the first ask after the load
(all 10 GPs fitted cold) and the mean over the following asks (steady state).

    python benchmarks/critic.py --overhead --overhead-sizes 1000 10000

All test functions are minimized on [0, 1]^d, mapped affinely to their usual domains, and shifted
so that their global minimum is 0.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

import numpy as np

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()


# ---------------------------------------------------------------- test functions (x in [0,1]^d)
def ackley(u: np.ndarray) -> float:
    """Ackley on [-5, 10]^d, minimum 0 at x = 0."""
    x = -5.0 + 15.0 * u
    d = x.shape[0]
    return float(-20.0 * np.exp(-0.2 * np.sqrt(np.sum(x ** 2) / d))
                 - np.exp(np.sum(np.cos(2 * np.pi * x)) / d) + 20.0 + np.e)


def levy(u: np.ndarray) -> float:
    """Levy on [-10, 10]^d, minimum 0 at x = 1."""
    x = -10.0 + 20.0 * u
    w = 1.0 + (x - 1.0) / 4.0
    t1 = np.sin(np.pi * w[0]) ** 2
    t2 = np.sum((w[:-1] - 1) ** 2 * (1 + 10 * np.sin(np.pi * w[:-1] + 1) ** 2))
    t3 = (w[-1] - 1) ** 2 * (1 + np.sin(2 * np.pi * w[-1]) ** 2)
    return float(t1 + t2 + t3)


def rosenbrock(u: np.ndarray) -> float:
    """Rosenbrock on [-5, 10]^d, minimum 0 at x = 1."""
    x = -5.0 + 15.0 * u
    return float(np.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2))


def styblinski_tang(u: np.ndarray) -> float:
    """Styblinski–Tang on [-5, 5]^d, shifted so the minimum (x_i = -2.9035) is 0."""
    x = -5.0 + 10.0 * u
    d = x.shape[0]
    return float(0.5 * np.sum(x ** 4 - 16 * x ** 2 + 5 * x) + 39.16616570377142 * d)


FUNCTIONS: dict[str, tuple[Callable[[np.ndarray], float], int]] = {
    "ackley20": (ackley, 20),
    "levy25": (levy, 25),
    "rosenbrock25": (rosenbrock, 25),
    "styblinski77": (styblinski_tang, 77),
    "ackley77": (ackley, 77),
}


def _run_one(args: tuple[str, str, int, int, int]) -> tuple[str, str, int, float, float, float]:
    fname, method, seed, budget, batch = args
    import torch

    torch.set_num_threads(1)
    from latentune.optimize import minimize

    fun, d = FUNCTIONS[fname]
    t = time.perf_counter()
    res = minimize(fun, [(0.0, 1.0)] * d, method=method, budget=budget, batch_size=batch,
                   seed=seed)
    wall = time.perf_counter() - t
    return fname, method, seed, float(res.fun), wall, float(np.min(res.y[: min(budget, 100)]))


def quality(fnames: list[str], methods: list[str], seeds: int, budget: int, batch: int,
            jobs: int) -> None:
    work = [(f, m, s, budget, batch) for f in fnames for m in methods for s in range(seeds)]
    results: dict[tuple[str, str], list[tuple[float, float]]] = {}
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as ex:
            out = list(ex.map(_run_one, work))
    else:
        out = []
        for w in work:
            out.append(_run_one(w))
            f, m, s, best, wall, _ = out[-1]
            print(f"  {f:14s} {m:7s} seed {s}: best {best:.4g}  ({wall:.0f} s)", flush=True)
    for f, m, s, best, wall, _ in out:
        results.setdefault((f, m), []).append((best, wall))
    print(f"\nbudget {budget}, batch {batch}, seeds {seeds}  (best value found; global min = 0)")
    print(f"{'function':14s} {'method':7s} {'median':>10s} {'min':>10s} {'max':>10s} "
          f"{'wall s/run':>10s}")
    for f in fnames:
        for m in methods:
            r = np.array(results[(f, m)])
            print(f"{f:14s} {m:7s} {np.median(r[:, 0]):10.4g} {r[:, 0].min():10.4g} "
                  f"{r[:, 0].max():10.4g} {np.median(r[:, 1]):10.1f}")


def ask_tell_seconds(critic, fun, n_asks: int) -> list[float]:
    """The critic's own seconds per suggested point of each of ``n_asks`` ask/tell rounds
    (``fun``'s time excluded): (n_asks,) floats."""
    per = []
    for _ in range(n_asks):
        t = time.perf_counter()
        U = critic.ask()
        tags = critic.last_tags
        dt = time.perf_counter() - t
        yy = np.array([fun(u) for u in U])
        t = time.perf_counter()
        critic.tell(U, yy, tags=tags)
        per.append((dt + time.perf_counter() - t) / len(U))
    return per


def overhead(sizes: list[int], n_asks: int, d: int = 25, batch: int = 20,
             n_regions: int = 10) -> None:
    import torch

    torch.set_num_threads(1)
    from latentune.critic import make_critic

    print(f"TuRBO-m overhead: d={d}, batch {batch}, {n_regions} regions "
          f"(critic time only, s per suggested point)")
    for n in sizes:
        rng = np.random.default_rng(0)
        X = rng.random((n, d))
        y = np.array([ackley(x) for x in X])
        critic = make_critic("turbo", d, batch_size=batch, seed=0, n_regions=n_regions)
        t = time.perf_counter()
        critic.tell(X, y)
        t_load = time.perf_counter() - t
        per_pt = np.array(ask_tell_seconds(critic, ackley, n_asks))
        steady = per_pt[1:] if len(per_pt) > 1 else per_pt
        print(f"  told {n:6d}: load (tell) {t_load:.2f} s | first ask {per_pt[0]:.3f} s/pt | "
              f"steady state (asks 2..{n_asks}) mean {steady.mean():.3f} s/pt, "
              f"max {steady.max():.3f} s/pt | over all {n_asks} asks {per_pt.mean():.3f} s/pt",
              flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--functions", nargs="+", default=["ackley20", "levy25", "rosenbrock25",
                                                      "styblinski77"], choices=sorted(FUNCTIONS))
    p.add_argument("--methods", nargs="+", default=["turbo", "cma", "random"],
                   choices=["turbo", "cma", "random", "sobol"])
    p.add_argument("--budget", type=int, default=1000)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=20)
    p.add_argument("--jobs", type=int, default=1, help="parallel runs (processes)")
    p.add_argument("--overhead", action="store_true", help="run the overhead benchmark only")
    p.add_argument("--overhead-sizes", nargs="+", type=int, default=[1000, 10000])
    p.add_argument("--overhead-asks", type=int, default=10)
    a = p.parse_args(argv)
    if a.overhead:
        overhead(a.overhead_sizes, a.overhead_asks)
    else:
        quality(a.functions, a.methods, a.seeds, a.budget, a.batch_size, a.jobs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
