"""TuRBO-m overhead: the critic's own seconds per suggested point (ask + tell, the cost
function's time excluded) after it was told many points.

latentune's TuRBO-m in ``--dim`` (25) dimensions, batch ``--batch-size`` (10), is told ``--told``
uniform random points (untagged: spread over the regions) of Ackley on [-10, 10]^d (optimum at
-1), then asks and tells ``--asks`` (5) batches. The first ask after the load fits every
region's GP cold; the following asks are the steady state. Cases, for each number of regions of
``--regions`` (1 and 10):

* ``default``: torch at all cores outside the critic (its default) and the critic's default
  ``threads=1``;
* ``torch threads``: ``threads=None`` (the critic uses torch's setting: all cores);
* ``one thread``: ``threads=None`` under one torch thread.

``--busy N`` keeps N other processes busy (one core each) during the measurement (a busy
machine: N = 1 on 2 cores).

    python -m benchmarks.turbo_overhead [--told 10000] [--asks 5] [--regions 1 10] [--busy 1]
        [--out FILE.json]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402


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


def _spin() -> None:
    """A busy process (for ``--busy``): one core's worth of pure-Python work until killed."""
    x = 0
    while True:
        x = (x * 1103515245 + 12345) % 2147483648


def measure(told: int, asks: int, dim: int, batch: int, regions: list[int]) -> list[dict]:
    """One row per (regions, case): load time, first-ask and steady-state seconds per point."""
    import torch

    from latentune.critic import make_critic

    from benchmarks.common import ackley as base

    def fz(u: np.ndarray) -> float:          # Ackley on [-10, 10]^d with the optimum at -1
        return float(base(-10.0 + 20.0 * u - 1.0))

    default_threads = torch.get_num_threads()
    ncpu = os.cpu_count() or 1               # torch's default without OMP_NUM_THREADS
    w = make_critic("turbo", 3, batch_size=4, seed=0, n_regions=1, n_init=4)
    for _ in range(3):                       # warm-up: imports, caches
        U = w.ask()
        w.tell(U, np.array([fz(u) for u in U]), tags=w.last_tags)
    rows = []
    cases = (("default", ncpu, 1), ("torch threads", ncpu, None), ("one thread", 1, None))
    try:
        for nreg in regions:
            for name, torch_threads, critic_threads in cases:
                torch.set_num_threads(torch_threads)
                rng = np.random.default_rng(0)
                X = rng.random((told, dim))
                y = np.array([fz(x) for x in X])
                c = make_critic("turbo", dim, batch_size=batch, seed=0, n_regions=nreg,
                                threads=critic_threads)
                t = time.perf_counter()
                c.tell(X, y)
                load = time.perf_counter() - t
                per = ask_tell_seconds(c, fz, asks)
                rows.append({"regions": nreg, "case": name, "torch_threads_outside": torch_threads,
                             "critic_threads": critic_threads, "tell_load_s": load,
                             "first_ask_s_per_point": per[0],
                             "steady_s_per_point": float(np.mean(per[1:] if len(per) > 1 else per)),
                             "mean_s_per_point": float(np.mean(per)), "s_per_point": per,
                             "loadavg": list(os.getloadavg())})
                print(f"  regions {nreg}, {name}: {rows[-1]['mean_s_per_point']:.3f} s/pt",
                      file=sys.stderr, flush=True)
    finally:
        torch.set_num_threads(default_threads)
    return rows


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.turbo_overhead")
    p = bench_parser("benchmarks.turbo_overhead", description=__doc__,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--told", type=int, default=10_000)
    p.add_argument("--asks", type=int, default=5)
    p.add_argument("--dim", type=int, default=25)
    p.add_argument("--batch-size", type=int, default=10)
    p.add_argument("--regions", type=int, nargs="+", default=[1, 10])
    p.add_argument("--busy", type=int, default=0,
                   help="keep this many other processes busy meanwhile (one core each)")
    add_out_arg(p)
    a = p.parse_args(argv)
    busy = [mp.Process(target=_spin, daemon=True) for _ in range(a.busy)]
    for b in busy:
        b.start()
    try:
        rows = measure(a.told, a.asks, a.dim, a.batch_size, a.regions)
    finally:
        for b in busy:
            b.terminate()
    default = [r for r in rows if r["case"] == "default"]
    slowest = [r for r in rows if r["case"] == "torch threads"]
    results = {"told": a.told, "asks": a.asks, "dim": a.dim, "batch_size": a.batch_size,
               "busy_processes": a.busy,
               # torch's threads inside the critic vs the default one thread (> 1: one thread
               # is faster)
               "ratio": float(np.mean([s["mean_s_per_point"] for s in slowest])
                              / np.mean([d["mean_s_per_point"] for d in default]))}
    finish(a.out, prov, results, rows,
           columns=["regions", "case", "tell_load_s", "first_ask_s_per_point",
                    "steady_s_per_point", "mean_s_per_point"],
           title=f"TuRBO-m, d = {a.dim}, batch {a.batch_size}, told {a.told}: critic seconds per "
                 f"suggested point ({a.busy} busy processes)")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.turbo_overhead"))
