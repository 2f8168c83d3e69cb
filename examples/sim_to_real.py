"""Sim-to-real with latentune: phases 1 + 2 on a model, phase 3 on a different "real" system.

The model is Gymnasium's nominal ``Hopper-v5`` with the 36-weight linear controller of
:mod:`examples.gym_controller`; the "real" system is the same controller on a perturbed plant
(body masses x1.3, friction x0.6, actuator gear x0.8, observation noise, a one-step action
delay). Three ways to get a θ for the real system, at equal real-system budgets:

* **phase 3** — the paper's phase 3, TuRBO-m in the latent space learnt on the model
  (``lt.Study(real_dir).phase3(real, budget, latent=model_dir, strategy="plain")``; without
  ``strategy`` it is latentune's default, transfer; that call also runs the model's best θ on
  the real system once: the zero-shot row);
* **zero-shot** — the model's best θ as it is (1 real evaluation);
* **direct** — TuRBO-m on the full θ on the real system from the manual θ
  (``lt.Study(direct_dir).phase1(real, budget)``), no model at all.

Every study directory resumes. Run from the repository root::

    python -m examples.sim_to_real --out runs/examples/s2r --phase1-evals 300 --phase3-evals 60

``benchmarks/sim_to_real.py`` repeats this over seeds.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

import latentune as lt  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.errors import LatentuneError, UsageError  # noqa: E402
from latentune.reporting.metrics import best_so_far, evals_to_beat  # noqa: E402

if __package__ in (None, ""):                     # run as a file: python examples/sim_to_real.py
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from examples.gym_controller import (REAL, check_args, make_real_system,  # noqa: E402
                                     make_system)


def _level(cost: float, fell: bool) -> float:
    """The cost a tuned trial must beat to beat a reference trial: its cost, or +inf when the
    reference fell (any trial that stands beats a fall)."""
    return float("inf") if fell else float(cost)


def method_summary(rows: list[Any], zero_shot: float, manual: float) -> dict[str, Any]:
    """The numbers of one method's real trials ``rows`` (idx order). A trial that fell is never
    the best, never beats a level and never enters the best-so-far curve: ``best`` is the
    lowest cost of the trials that stood (None, with ``all_fell`` True, when every trial fell);
    ``best_so_far[k]`` is None until a trial stands. ``zero_shot`` and ``manual``: the levels
    to beat (:func:`_level`)."""
    costs = [float(r.cost) for r in rows]
    fell = [bool(r.fell) for r in rows]
    stood = [r for r in rows if not r.fell]
    best = min(stood, key=lambda r: (r.cost, r.idx)) if stood else None
    curve = best_so_far(costs, fell)
    y = np.where(np.asarray(fell, dtype=bool), np.inf, np.asarray(costs, dtype=float))
    return {"best": None if best is None else float(best.cost), "all_fell": best is None,
            "best_idx": None if best is None else int(best.idx),
            "best_return": None if best is None else best.info.get("return"),
            "best_distance": None if best is None else best.info.get("distance"),
            "n": len(rows), "failed": int(sum(fell)),
            "evals_to_beat_zero_shot": evals_to_beat(y, zero_shot),
            "evals_to_beat_manual": evals_to_beat(y, manual),
            "best_so_far": [round(float(c), 4) if np.isfinite(c) else None for c in curve]}


def _phase_rows(study: lt.Study, phase: int) -> list[Any]:
    return sorted(study.store.rows(phase), key=lambda r: r.idx)


def run_model(model_dir: str | os.PathLike, seed: int, phase1_evals: int, latent_dim: int,
              episode_steps: int = 400, workers: int = 1, backend: str = "serial",
              log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Phases 1 + 2 on the model (resumes). Returns the model study's numbers."""
    model = make_system(seed=seed, episode_steps=episode_steps)
    t = time.perf_counter()
    with lt.Study(model_dir, seed=seed, workers=workers, backend=backend, log=log) as study:
        study.phase1(model, phase1_evals)
        latent = study.train_latent(latent_dim=latent_dim)
        rows = _phase_rows(study, Phase.PHASE1)
        best = study.best(Phase.PHASE1)          # the best trial that stood (None: all fell)
        return {"dir": str(model_dir), "phase1_evals": len(rows),
                "phase1_failed": int(sum(r.fell for r in rows)),
                "manual_cost": float(study.store.rows(Phase.MANUAL)[0].cost),
                "phase1_best": None if best is None else float(best.cost),
                "vae_n_train": int(latent.meta.get("n_train", 0)), "latent_dim": latent.d_low,
                "wall_s": time.perf_counter() - t}


def run_real(model_dir: str | os.PathLike, phase3_dir: str | os.PathLike,
             direct_dir: str | os.PathLike, seed: int, budget: int, episode_steps: int = 400,
             workers: int = 1, backend: str = "serial",
             log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Phase 3 (model's latent space) and direct TuRBO-m on the real system, ``budget``
    evaluations each, plus the zero-shot θ. Resumes. Returns the numbers of the comparison."""
    real = make_real_system(seed=seed, episode_steps=episode_steps)
    out: dict[str, Any] = {"seed": seed, "budget": budget}
    t = time.perf_counter()
    with lt.Study(phase3_dir, seed=seed, workers=workers, backend=backend, log=log) as s3:
        s3.phase3(real, budget, latent=model_dir, strategy="plain")
        zs = s3.store.rows(Phase.ZERO_SHOT)[0]
        man = s3.store.rows(Phase.MANUAL)[0]
        manual, manual_fell = float(man.cost), bool(man.fell)
        rows3 = _phase_rows(s3, Phase.PHASE3)
    out["phase3_wall_s"] = time.perf_counter() - t
    t = time.perf_counter()
    with lt.Study(direct_dir, seed=seed, workers=workers, backend=backend, log=log) as sd:
        sd.phase1(real, budget)
        rowsd = _phase_rows(sd, Phase.PHASE1)
    out["direct_wall_s"] = time.perf_counter() - t
    out.update(manual_real=manual, zero_shot=float(zs.cost), zero_shot_failed=bool(zs.fell),
               zero_shot_info=dict(zs.info))
    for name, rows in (("phase3", rows3), ("direct", rowsd)):
        out[name] = method_summary(rows, _level(zs.cost, zs.fell), _level(manual, manual_fell))
    return out


def table(res: dict[str, Any]) -> str:
    """The comparison as Markdown."""
    b = res["budget"]
    zs = "fell" if res["zero_shot_failed"] else "stable"
    lines = [f"| on the real Hopper (seed {res['seed']}) | real evals | best cost | failed trials "
             "| evals to beat zero-shot |",
             "|---|---:|---:|---:|---:|",
             f"| manual θ | 1 | {res['manual_real']:.2f} | - | - |",
             f"| zero-shot: the model's best θ as it is | 1 | {res['zero_shot']:.2f} ({zs}) | "
             f"{int(res['zero_shot_failed'])} | - |"]
    for name, label in (("phase3", "phase 3: TuRBO-m in the model's latent space"),
                        ("direct", "direct: TuRBO-m on θ from the manual θ")):
        r = res[name]
        best = f"none: all {r['n']} fell" if r["all_fell"] else f"{r['best']:.2f}"
        lines.append(f"| {label} | {b} | {best} | {r['failed']}/{r['n']} | "
                     f"{r['evals_to_beat_zero_shot'] or 'never'} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="examples.sim_to_real",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/examples/s2r", help="root of the study directories")
    ap.add_argument("--phase1-evals", type=int, default=300, help="model evaluations (phase 1)")
    ap.add_argument("--phase3-evals", type=int, default=60,
                    help="real evaluations of phase 3 and of direct TuRBO-m each")
    ap.add_argument("--latent-dim", type=int, default=5)
    ap.add_argument("--episode-steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--backend", default="serial", choices=("serial", "process", "ray"))
    a = ap.parse_args(argv)
    try:
        check_args(a)               # counts, seed, latent size: before phase 1 runs
        try:                        # the factories' checks (episode steps, seed)
            make_real_system(seed=a.seed, episode_steps=a.episode_steps)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        return _run(a)
    except LatentuneError as exc:   # a bad budget, a run directory of another run, ...
        print(f"{ap.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


def _run(a: Any) -> int:
    """The example's run for the parsed arguments ``a`` (see :func:`main`)."""
    from latentune.study import stderr_log

    root = Path(a.out)
    print(f"real system = model with {REAL}", flush=True)
    m = run_model(root / "model", a.seed, a.phase1_evals, a.latent_dim, a.episode_steps,
                  a.workers, a.backend, stderr_log)
    p1 = "none (every trial fell)" if m["phase1_best"] is None else f"{m['phase1_best']:.2f}"
    print(f"model: manual {m['manual_cost']:.2f}, phase-1 best {p1} after "
          f"{m['phase1_evals']} evaluations ({m['phase1_failed']} failed); VAE on "
          f"{m['vae_n_train']} θ, d_low {m['latent_dim']}", flush=True)
    res = run_real(root / "model", root / "phase3", root / "direct", a.seed, a.phase3_evals,
                   a.episode_steps, a.workers, a.backend, stderr_log)
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
