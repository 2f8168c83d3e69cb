"""Choose the autoencoder kind by measurement: reconstruction, stable preservation, phase 3.

    python -m benchmarks.vae_kind RUN_DIR [--kinds det vae] [--n-check 30] [--phase3-evals 0]
        [--workers 2] [--seed 0] [--out FILE.json]

For each kind, trains on RUN_DIR's stable phase-1 θ (cost < C1) and reports: the training time,
the reconstruction error (summed squared error per θ), the stable-preservation rate (fraction of
``--n-check`` stable θ (a seeded random subset) that stay stable
after encode → decode, by rollouts), the fraction of stable θ among decoded points of the latent
box (uniform random u), and optionally the best cost of a phase 3 of ``--phase3-evals``.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, add_out_arg, bench_parser, cli_main, finish  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.vae_kind")
    ap = bench_parser("benchmarks.vae_kind", description=__doc__.splitlines()[0])
    ap.add_argument("run_dir")
    ap.add_argument("--kinds", nargs="+", default=["det", "vae"])
    ap.add_argument("--betas", nargs="+", type=float, default=None,
                    help="KL weights to try (default: each kind's default)")
    ap.add_argument("--n-check", type=int, default=30)
    ap.add_argument("--n-box", type=int, default=0, help="random latent-box points to roll out")
    ap.add_argument("--phase3-evals", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    from latentune.constants import C1
    from latentune.latent import LatentSpace
    from latentune.pipeline.evaluators import make_evaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase, training_set
    from latentune.pipeline.store import RunStore
    from latentune.reporting.run_report import task_from_config as _task_from_config

    st = RunStore(a.run_dir)
    task = _task_from_config(st.get_meta("config"))
    X = training_set(st)
    rng = np.random.default_rng(a.seed)
    check = X[rng.permutation(len(X))[: a.n_check]]
    n_phase1 = st.count(1)
    print(f"{len(X)} stable θ of {n_phase1} phase-1 evaluations; checking {len(check)}",
          file=sys.stderr, flush=True)
    ev = make_evaluator("process", a.workers)
    out = []
    try:
        for kind in a.kinds:
            for beta in (a.betas or [None]):
                t = time.perf_counter()
                ls = LatentSpace.train(X, kind=kind, seed=a.seed, beta=beta)
                tt = time.perf_counter() - t
                rec = float(((ls.reconstruct(X) - X) ** 2).sum(1).mean())
                r = {"kind": kind, "beta": ls.meta["beta"], "train_s": tt, "rec_err": rec}
                if len(check):
                    y = ev.map(task, ls.reconstruct(check))
                    r["preservation"] = float(np.mean(y < C1))
                if a.n_box:
                    y = ev.map(task, ls.decode(rng.random((a.n_box, ls.d_low))))
                    r["box_stable"] = float(np.mean(y < C1))
                    r["box_best"] = float(np.min(y))
                if a.phase3_evals:
                    with RunStore(Path(tempfile.mkdtemp(prefix="ltvk")) / "r", create=True) as s3:
                        crit = make_phase_critic("turbo", ls.d_low, 4, a.seed,
                                                 ls.to_unit(ls.encode(task.space.manual)),
                                                 a.phase3_evals)
                        res = run_phase(s3, 3, task, crit, a.phase3_evals, ev,
                                        decoder=ls.decode, seed=a.seed)
                        r["phase3_best"] = res.best_cost
                        r["phase3_stable"] = float(np.mean(s3.costs(3) < C1))
                out.append(r)
                print(f"{kind} beta {r['beta']}: done", file=sys.stderr, flush=True)
    finally:
        ev.close()
        st.close()
    finish(a.out, prov, {"run_dir": a.run_dir, "n_train": len(X), "n_phase1": n_phase1,
                         "n_check": len(check), "seed": a.seed}, out,
           title=f"autoencoder kinds on {a.run_dir}: {len(X)} stable θ, {len(check)} checked")
    return 0


if __name__ == "__main__":
    sys.exit(cli_main(main, "benchmarks.vae_kind"))
