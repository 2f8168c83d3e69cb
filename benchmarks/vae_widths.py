"""Whether the VAE's decoder reaches the training set: Table I's hidden widths against the
current ones (:func:`latentune.latent.vae.hidden_widths`) over θ dimensions and seeds.

    python -m benchmarks.vae_widths [--dims 2 3 5 ...] [--seeds 8] [--n 100] [--epochs E]
        [--out F.json]

Per (training set, d, seed) a :class:`~latentune.latent.vae.LatentSpace` of the default kind,
latent size and epochs (``--epochs`` to change them) is trained on ``--n`` normalized θ with each rule of widths:
``table1`` = (max(⌊d/2⌋, 1), max(⌊d/4⌋, 1)), the rule before session 31, and ``current``.
Two training sets, both drawn with ``numpy.random.default_rng(seed)``:

* ``blob``: clip(0.3 + 0.15·N(0, I), 0, 1);
* ``manifold``: clip(0.5 + 0.25·A·s + 0.02·N(0, I), 0, 1) with s ~ U(−1, 1)², A a random
  (d, 2) matrix with orthonormal columns: a 2-dim stable set, as a phase 1 leaves.

One row per (set, d, rule): ``collapsed`` = seeds whose latent box decodes every code to one θ
(:meth:`LatentSpace.require_spread` refuses them), the median of ``spread`` (the decoded θ's
total variance over the training set's, ``decoded_variance_ratio``) and of ``rec`` (the mean
squared reconstruction error summed over θ, over the same total variance: 1 = every θ
reconstructed as the mean).
"""
from __future__ import annotations

import sys
from typing import Any

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, error_line,  # noqa: E402
                               finish)
from latentune.errors import LatentError  # noqa: E402
from latentune.latent.vae import LatentSpace, hidden_widths  # noqa: E402

RULES = {"table1": lambda d: (max(d // 2, 1), max(d // 4, 1)), "current": hidden_widths}
SETS = ("blob", "manifold")


def training_set(kind: str, d: int, n: int, seed: int) -> np.ndarray:
    """(n, d) normalized θ of the training set ``kind`` (module docstring)."""
    rng = np.random.default_rng(seed)
    if kind == "blob":
        return np.clip(0.3 + 0.15 * rng.standard_normal((n, d)), 0.0, 1.0)
    A = np.linalg.qr(rng.standard_normal((d, 2)))[0] if d > 2 else np.eye(d)[:, :2]
    s = rng.uniform(-1.0, 1.0, (n, 2))
    return np.clip(0.5 + 0.25 * s @ A.T + 0.02 * rng.standard_normal((n, d)), 0.0, 1.0)


def one(kind: str, d: int, seed: int, n: int, rule: str, epochs: int | None = None
        ) -> dict[str, Any]:
    """spread, rec and collapsed of one trained latent space."""
    X = training_set(kind, d, n, seed)
    ls = LatentSpace.train(X, seed=seed, hidden=RULES[rule](d), epochs=epochs)
    var = float(X.var(0).sum())
    rec = float(((ls.reconstruct(X) - X) ** 2).sum(1).mean()) / var
    try:
        ls.require_spread()
        collapsed = False
    except LatentError:
        collapsed = True
    return {"spread": ls.meta["decoded_variance_ratio"], "rec": rec, "collapsed": collapsed}


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.vae_widths")
    ap = bench_parser("benchmarks.vae_widths", description=__doc__.splitlines()[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3, 5, 8, 11, 16, 18])
    ap.add_argument("--seeds", type=int, default=8, help="seeds 0 .. SEEDS-1")
    ap.add_argument("--n", type=int, default=100, help="training θ per set")
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    ap.add_argument("--epochs", type=int, default=None, help="default: the training's own")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    if min(a.dims) < 2 or a.seeds < 1 or a.n < 2 or (a.epochs is not None and a.epochs < 1):
        error_line("benchmarks.vae_widths",
                   "--dims must be >= 2, --seeds >= 1, --n >= 2, --epochs >= 1")
        return 2
    rows, runs = [], []
    for kind in a.sets:
        for d in a.dims:
            for rule in RULES:
                res = [one(kind, d, s, a.n, rule, a.epochs) for s in range(a.seeds)]
                runs += [{"set": kind, "d": d, "rule": rule, "seed": s, **r}
                         for s, r in enumerate(res)]
                rows.append({"set": kind, "d": d, "rule": rule, "hidden": str(RULES[rule](d)),
                             "collapsed": f"{sum(r['collapsed'] for r in res)}/{a.seeds}",
                             "spread": float(np.median([r["spread"] for r in res])),
                             "rec": float(np.median([r["rec"] for r in res]))})
    finish(a.out, prov, {"dims": a.dims, "seeds": a.seeds, "n": a.n, "sets": a.sets,
                         "epochs": a.epochs,
                         "runs": runs}, rows,
           title="the decoder's reach: Table I's widths against the current ones")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.vae_widths"))
