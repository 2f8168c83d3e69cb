"""Transfer-critic variants on synthetic source/target pairs that are not in the ladder (a check
of a default before it meets the ladder's targets).

    python -m benchmarks.transfer_variants [--variants default fail_tol=20 ...] [--seeds 0 1 2 3]
        [--problems bowl:0.05 levy:0.2 ...]
        [--out FILE.json]

Problems (d = 16; each seed draws its own source and target): ``bowl`` (cost 10·distance to a
centre, a fall beyond a radius; the target's centre moves by ``gap``·N(0, 1) per coordinate and
its stable radius shrinks by ``gap``) and ``levy`` (the shifted Levy function; the target's shift
moves by 10·``gap``·N(0, 1) and its cost is scaled by 1 + ``gap``), each at two gaps. For each
seed: a 200-trial TuRBO-m source run (batch 10), then 30 target trials of each variant (the
zero-shot θ first) and of TuRBO-m from the source's best. A variant is ``default`` or
``option=value[:option=value]`` of :data:`latentune.critic.transfer.TRANSFER_DEFAULTS`.
"""
from __future__ import annotations

import argparse
import functools
import sys

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, finish  # noqa: E402

D, SOURCE, B = 16, 200, 30


def _levy(x: np.ndarray) -> np.ndarray:
    w = 1 + (x - 1) / 4
    t = np.sin(np.pi * w[:, 0]) ** 2 + (((w[:, :-1] - 1) ** 2)
                                        * (1 + 10 * np.sin(np.pi * w[:, :-1] + 1) ** 2)).sum(1)
    return t + (w[:, -1] - 1) ** 2 * (1 + np.sin(2 * np.pi * w[:, -1]) ** 2)


def problem(name: str, gap: float, rng: np.random.Generator, d: int = D):
    """(source, target): each maps θ (n, d) to (cost (n,), fell (n,))."""
    if name == "bowl":
        c = rng.uniform(0.3, 0.7, d)
        ct = np.clip(c + gap * rng.standard_normal(d), 0, 1)

        def bowl(X, centre, radius):
            r = np.sqrt(((X - centre) ** 2).sum(1))
            return np.where(r > radius, 100 + r, 10 * r), r > radius
        return (lambda X: bowl(X, c, 0.8)), (lambda X: bowl(X, ct, 0.8 - gap))
    s0 = rng.uniform(-2, 2, d)
    st = s0 + gap * 10 * rng.standard_normal(d)
    return (lambda X: (_levy(X * 20 - 10 - s0), np.zeros(len(X), bool))), \
        (lambda X: (_levy(X * 20 - 10 - st) * (1 + gap), np.zeros(len(X), bool)))


@functools.lru_cache(maxsize=None)
def source(name: str, gap: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The source run of (problem, gap, seed): 200 TuRBO-m trials, ``(X, y, fell)``."""
    from latentune.critic.turbo import TurboM

    src, _ = problem(name, gap, np.random.default_rng([seed, 99]))
    s = TurboM(D, batch_size=10, seed=seed, x0=np.full(D, 0.5))
    while s.n_told < SOURCE:
        X = s.ask()
        y, f = src(X)
        s.tell(X, y, s.last_tags, fell=f)
    return s.X, s.y, src(s.X)[1]


def run(variant: str, name: str, gap: float, seed: int) -> tuple[float, int, np.ndarray]:
    from latentune.critic.transfer import Transfer
    from latentune.critic.turbo import TurboM

    _, tgt = problem(name, gap, np.random.default_rng([seed, 99]))
    Xs, ys, fs = source(name, gap, seed)
    best = Xs[np.argmin(np.where(fs, np.inf, ys))]
    costs: list[float] = []
    falls: list[bool] = []
    if variant == "turbo_source":
        cr = TurboM(D, batch_size=1, seed=seed, x0=best, n_regions=1)
    else:
        from benchmarks.transfer import LADDER_BASE, parse_variant

        opts = {**LADDER_BASE, **({} if variant == "default" else parse_variant(variant))}
        cr = Transfer((Xs, ys, fs), None, np.full(D, 0.5), batch_size=1, seed=seed, **opts)
        y0, f0 = tgt(best[None])
        cr.tell(best[None], y0, fell=f0)
        costs.append(float(y0[0]))
        falls.append(bool(f0[0]))
    while len(costs) < B:
        X = cr.ask(1)
        y, f = tgt(X)
        cr.tell(X, y, cr.last_tags, fell=f)
        costs.append(float(y[0]))
        falls.append(bool(f[0]))
    return float(min(costs)), int(sum(falls)), np.minimum.accumulate(costs)


PROBLEMS = (("bowl", 0.05), ("bowl", 0.15), ("levy", 0.05), ("levy", 0.2))


def _problem(text: str) -> tuple[str, float]:
    name, _, gap = text.partition(":")
    try:
        g = float(gap)
    except ValueError:
        g = -1.0
    if name not in ("bowl", "levy") or not 0 <= g < (0.8 if name == "bowl" else 10):
        raise argparse.ArgumentTypeError(f"expected bowl:GAP (0 ≤ GAP < 0.8) or levy:GAP, "
                                         f"got {text!r}")
    return name, g


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.transfer_variants")
    ap = bench_parser("benchmarks.transfer_variants", description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", default=["turbo_source", "default"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--problems", nargs="+", type=_problem, default=list(PROBLEMS),
                    help="NAME:GAP pairs, NAME bowl or levy (default: %(default)s)")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    rows = []
    for name, gap in a.problems:
        for v in a.variants:
            r = [run(v, name, gap, s) for s in a.seeds]
            rows.append({"problem": name, "gap": gap, "variant": v,
                         "median best": float(np.median([x[0] for x in r])),
                         "median falls": float(np.median([x[1] for x in r])),
                         "best at 10": float(np.median([x[2][9] for x in r]))})
            print(rows[-1], flush=True)
    finish(a.out, prov, {"seeds": a.seeds, "budget": B}, rows, title="transfer variants")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer_variants"))
