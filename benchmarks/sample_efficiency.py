"""Sample efficiency (default: A1 jump): evaluations needed to reach the manual-tuned cost.

    python -m benchmarks.sample_efficiency --vae RUN_DIR [--budget 220] [--seeds 0 1 2]
        [--methods latent turbo cma random] [--robot a1 --task jump] [--actor A] [--steps 5000]
        [--workers 2] [--target COST] [--more-targets C ...] [--from-stores] [--reconstruct]
        [--out FILE.json]

Methods (same seeds, same budget, all from scratch -- no method gets the manual θ as a start
point, or every one would "reach" it at evaluation 1):

* ``latent``: phase 3 -- TuRBO-m in the latent box of the VAE of ``--vae RUN_DIR`` (e.g. the
  A1 trot run of ``latentune tune``) through its decoder;
* ``turbo``:  TuRBO-m directly on the 25-dim θ;
* ``cma``:    CMA-ES on θ;  ``random``: uniform random θ.

Target: the manual θ's cost on this task; if the manual θ falls (cost ≥ C1), the target is C1
(the first stable θ) unless ``--target`` is given. Every evaluation is stored in a run store per
(method, seed) under ``--work`` so a run can be inspected with ``latentune report``.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.constants import C1  # noqa: E402
from latentune.reporting.metrics import evals_to_beat  # noqa: E402

from benchmarks.common import (Provenance, add_out_arg, bench_parser, finish,  # noqa: E402
                               median_evals, out_dir)


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.sample_efficiency")
    ap = bench_parser("benchmarks.sample_efficiency", description=__doc__.splitlines()[0])
    ap.add_argument("--vae", required=False, help="run directory whose VAE phase 3 uses")
    ap.add_argument("--robot", default="a1")
    ap.add_argument("--task", default="jump")
    ap.add_argument("--actor", default=None, help="convex (default) or kinodynamic (the paper's Solo12 actor)")
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--budget", type=int, default=220)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--methods", nargs="+", default=["latent", "turbo", "cma", "random"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--target", type=float, default=None)
    ap.add_argument("--more-targets", type=float, nargs="*", default=[],
                    help="also report evaluations to reach these costs")
    ap.add_argument("--from-stores", action="store_true",
                    help="run nothing: report from the stores already in --work")
    ap.add_argument("--reconstruct", action="store_true",
                    help="also pass the best θ of each full-space method through the VAE "
                         "(encode -> decode) and simulate it: is it inside the latent space?")
    ap.add_argument("--work", type=out_dir, default=None, help="directory for the per-run stores")
    add_out_arg(ap)
    a = ap.parse_args(argv)
    from latentune.pipeline.evaluators import make_evaluator
    from latentune.pipeline.store import RunStore

    evals_to_reach = evals_to_beat
    task = lt.Task(a.robot, a.task, steps=a.steps, **({"actor": a.actor} if a.actor else {}))
    manual = task.rollout(task.space.manual).cost
    target = a.target if a.target is not None else (manual if manual < C1 else C1)
    latent = None
    if "latent" in a.methods or a.reconstruct:
        if not a.vae:
            ap.error("--vae RUN_DIR is needed for the latent method")
        src = RunStore(a.vae).artifact("vae") if (Path(a.vae) / "run.db").is_file() else Path(a.vae) / "vae"
        latent = lt.LatentSpace.load(src)
    work = Path(a.work or tempfile.mkdtemp(prefix="lt_sampleeff_"))
    print(f"{a.robot} {a.task}: manual cost {manual:.3f}; target {target:.3f}; budget {a.budget}; "
          f"seeds {a.seeds}; stores in {work}", file=sys.stderr, flush=True)
    ev = make_evaluator("serial" if a.from_stores else "process", a.workers)
    results: dict[str, list[dict]] = {}
    try:
        for m in a.methods:
            for s in a.seeds:
                t0 = time.perf_counter()
                phase = 3 if m == "latent" else 1
                if a.from_stores:
                    with RunStore(work / f"{m}_s{s}") as st:
                        y = st.costs(phase)
                    results.setdefault(m, []).append(
                        {"seed": s, "evals_to_target": evals_to_reach(y, target),
                         "more": [evals_to_reach(y, t) for t in a.more_targets],
                         "best": float(y.min()), "stable": int((y < C1).sum()),
                         "hit_rate": float(np.mean(y <= target)), "wall_s": None})
                    continue
                # every method from scratch (start=None): none gets the manual θ as a start
                with lt.Study(work / f"{m}_s{s}", seed=s, workers=a.workers,
                              batch_size=a.batch_size, evaluator=ev) as study:
                    if m == "latent":
                        study.phase3(task, a.budget, latent=a.vae, start=None, strategy="plain")
                    else:
                        study.phase1(task, a.budget, method="turbo" if m == "turbo" else m,
                                     start=None)
                    y = study.store.costs(phase)
                r = {"seed": s, "evals_to_target": evals_to_reach(y, target),
                     "more": [evals_to_reach(y, t) for t in a.more_targets],
                     "best": float(y.min()), "stable": int((y < C1).sum()),
                     "hit_rate": float(np.mean(y <= target)), "wall_s": time.perf_counter() - t0}
                results.setdefault(m, []).append(r)
                print(f"  {m:7s} seed {s}: evals to target {r['evals_to_target']}, best "
                      f"{r['best']:.3f}, stable {r['stable']}/{len(y)} ({r['wall_s']:.0f} s)",
                      file=sys.stderr, flush=True)
    finally:
        ev.close()
    rows, med = [], {}
    for m, rs in results.items():
        e = [r["evals_to_target"] for r in rs]
        med[m] = median_evals(e)
        rows.append({"method": m, "evals to target (per seed)": e, "median": med[m],
                     "best cost (median)": float(np.median([r["best"] for r in rs]))})
    notes = []
    ratio = None
    if "latent" in med and "turbo" in med:
        ratio = med["turbo"] / med["latent"]
        notes.append(f"ratio of medians, direct TuRBO-m / latent: {ratio:.2f}")
    if "random" in results:
        # each random θ reaches the target independently with probability p, so any method whose
        # first points are a space-filling design needs about 1/p evaluations to hit it by chance
        p = float(np.mean([r["hit_rate"] for r in results["random"]]))
        notes.append(f"share of random θ at or below the target: p = {p:.3f}"
                     + (f" -> 1/p = {1 / p:.1f} evaluations by chance" if p > 0 else ""))
    for k, t in enumerate(a.more_targets):
        notes.append(f"target {t:.3f}: evaluations to reach it per seed (None = not within the "
                     "budget): " + "; ".join(
                         f"{m} {[r['more'][k] for r in rs]} median "
                         f"{median_evals([r['more'][k] for r in rs])}"
                         for m, rs in results.items()))
    reconstructed = []
    if a.reconstruct and latent is not None:
        # the latent space's reach: the best θ the full-space methods found, encoded and decoded
        for m in results:
            if m == "latent":
                continue
            for s in a.seeds:
                with RunStore(work / f"{m}_s{s}") as st:
                    b = st.best(1)
                if b is None or b.cost >= C1:
                    continue
                rec = latent.reconstruct(b.theta[None])[0]
                c = task.rollout(rec).cost
                reconstructed.append({"method": m, "seed": s, "best": b.cost,
                                      "after_encode_decode": c,
                                      "delta_theta": float(np.linalg.norm(b.theta - rec))})
    finish(a.out, prov, {"manual": manual, "target": target, "budget": a.budget,
                         "seeds": a.seeds, "vae": a.vae, "work": str(work), "ratio": ratio,
                         "notes": notes, "results": results,
                         "reconstructed": reconstructed}, rows,
           title=f"{a.robot} {a.task}: evaluations to reach the target {target:.3f} (manual "
                 f"{manual:.3f}), budget {a.budget}")
    for line in notes:
        print(f"\n{line}")
    if reconstructed:
        print("\nbest θ of the full-space methods through the VAE (encode -> decode):\n")
        from benchmarks.common import markdown_table
        print(markdown_table(reconstructed))
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.sample_efficiency"))
