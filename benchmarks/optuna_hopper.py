"""LatentSampler against Optuna's own samplers on the Hopper sim-to-real, at equal budgets.

    python -m benchmarks.optuna_hopper [--seeds 0 1 2 3 4] [--trials 40] [--phase1-evals 300]
        [--latent-dim 5] [--episode-steps 400] [--models runs/sim_to_real]
        [--samplers latent tpe cmaes_source gp] [--checkpoints 5 10 20 40]
        [--warm-start best|none] [--traces DIR]
        [--out results/optuna_hopper/optuna_hopper.json]

The system of ``examples/sim_to_real.py``: the 36-weight linear controller of Gymnasium's
``Hopper-v5`` (``examples/gym_controller.py``); the model is the nominal Hopper, the "real" one
has masses x1.3, friction x0.6, gear x0.8, observation noise and a one-step action delay. For
every seed s:

1. the model run ``MODELS/seed<s>/model``: latentune's phase 1 on the model
   (``--phase1-evals`` evaluations, TuRBO-m from the manual θ) + the latent space (d_low
   ``--latent-dim``) — the same directories as ``benchmarks/sim_to_real.py --out MODELS``,
   reused when they exist (resumed when shorter);
2. on the real Hopper, one Optuna study per sampler, ``--trials`` trials each, with the same
   objective (an Optuna user's: ``trial.suggest_float`` for the 36 weights by name, one episode,
   the cost, ``trial.set_constraint("fall", 1 if the hopper fell else 0)``):

   * ``latent`` — ``LatentSampler(model run, seed=s, budget=B)`` (its trial 0 is the model's
     best θ as it is: the zero-shot trial counts in B);
   * ``tpe`` — ``optuna.samplers.TPESampler(seed=s)``;
   * ``cmaes_source`` — ``CmaEsSampler(seed=s, source_trials=...)``: warm-started CMA-ES
     (WS-CMA-ES, Nomura et al. 2021) from the model run's phase-1 trials (the same source data
     as the latent space), as Optuna trials by name;
   * ``gp`` — ``optuna.samplers.GPSampler(seed=s)``;
   * opt-in: ``turbo`` (latentune's ``TurboSampler`` from the manual θ), ``cmaes`` (plain),
     ``latent_fb`` (``latent`` with a fall budget of 0.15: its study stops once the budget is
     spent; its best-so-far curve stays at its last value for the trials it did not run).

   Optuna's samplers run as a user would run them: defaults, no ``constraints_func``, and
   the same warm start as ``latent``: the model run's best θ is their trial 0
   (``study.enqueue_trial``; ``--warm-start none`` leaves it out).

   Each (seed, sampler) trace is kept in ``--traces`` (default ``traces/`` beside ``--out``) as
   ``seed<s>/<sampler>.json`` and reused by a later call with the same settings, so an
   interrupted run resumes and seeds can run in separate processes; a last call over every
   seed aggregates them.

Reported over the seeds: the best real cost within B (median, min–max), falls within B
(median), the best-so-far at ``--checkpoints``, and, against the best peer (the Optuna sampler
with the lowest median best), the trials each sampler needs to reach that median (per seed the
first trial at or below it, ∞ if never; then the median) and a two-sided Mann–Whitney U test of
latent's bests against the best peer's. Every trial's cost and fall flag is kept in the JSON.
Writes the JSON (with the command, date, load average, wall time, versions) and a Markdown
table next to it.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]

from latentune.threads import one_thread_env  # noqa: E402

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import Provenance, bench_parser, out_dir, out_file, write_json  # noqa: E402

PEERS = ("tpe", "cmaes_source", "gp", "cmaes", "turbo")
"""Samplers that are peers (stock tools); ``latent`` is reported beside them."""
SAMPLERS = ("latent", "tpe", "cmaes_source", "gp")
LABELS = {"latent": "LatentSampler (model's latent space)", "tpe": "TPE",
          "cmaes_source": "CMA-ES with source_trials (model run)", "gp": "GPSampler",
          "cmaes": "CMA-ES", "turbo": "TurboSampler (θ, from manual)",
          "latent_fb": "LatentSampler, fall_budget 0.15 (stops when spent)"}
FALL_BUDGET = 0.15
"""``latent_fb``'s ``transfer_options={"fall_budget": FALL_BUDGET}``: the share measured on the
transfer ladders (README, "A fall budget")."""


def source_trials(model_dir: Path) -> list[Any]:
    """The model run's phase-1 trials as finished Optuna trials (physical params by name,
    value = cost, the fall as constraint ``fall``)."""
    import optuna

    import latentune as lt
    from latentune.constants import Phase
    from latentune.integrations.optuna import distributions_of, physical_params

    with lt.Study(model_dir) as s:
        space = s.space()
        rows = s.store.rows(Phase.PHASE1)
    dists = distributions_of(space)
    return [optuna.trial.create_trial(params=physical_params(space, r.theta),
                                      distributions=dists, value=float(r.cost),
                                      system_attrs={"constraints:fall": float(r.fell)})
            for r in rows if math.isfinite(r.cost)]


def make_sampler(name: str, seed: int, model_dir: Path, budget: int) -> Any:
    import optuna

    from examples.gym_controller import hopper_space
    from latentune.integrations.optuna import LatentSampler, TurboSampler

    if name == "latent":
        return LatentSampler(model_dir, seed=seed, budget=budget)
    if name == "latent_fb":
        return LatentSampler(model_dir, seed=seed, budget=budget,
                             transfer_options={"fall_budget": FALL_BUDGET})
    if name == "tpe":
        return optuna.samplers.TPESampler(seed=seed)
    if name == "cmaes_source":
        return optuna.samplers.CmaEsSampler(seed=seed, source_trials=source_trials(model_dir))
    if name == "cmaes":
        return optuna.samplers.CmaEsSampler(seed=seed)
    if name == "gp":
        return optuna.samplers.GPSampler(seed=seed)
    if name == "turbo":
        return TurboSampler(hopper_space(), seed=seed, budget=budget, start="manual")
    raise ValueError(f"unknown sampler {name!r}")


def hopper_objective(real: Any) -> Callable[[Any], float]:
    """The Optuna user's objective on the real Hopper: 36 ``suggest_float`` by name."""
    space = real.space

    def objective(trial: Any) -> float:
        x = np.array([trial.suggest_float(n, lo, hi, log=bool(lg))
                      for n, lo, hi, lg in zip(space.names, space.lower, space.upper, space.log)])
        out = real.evaluate(np.clip(space.to_unit(x), 0.0, 1.0))
        trial.set_constraint("fall", 1.0 if out.failed else 0.0)
        trial.set_user_attr("return", out.info.get("return"))
        return float(out.cost)

    return objective


def run_sampler(name: str, seed: int, model_dir: Path, budget: int, episode_steps: int,
                warm_start: str = "best") -> dict[str, Any]:
    """One Optuna study of ``budget`` trials on the real Hopper; its trace. With
    ``warm_start="best"`` an Optuna sampler's trial 0 is the model run's best θ (enqueued),
    the θ of LatentSampler's zero-shot trial."""
    import optuna

    from examples.gym_controller import make_real_system
    from latentune.integrations.optuna import physical_params
    from latentune.study import source_best

    real = make_real_system(seed=seed, episode_steps=episode_steps)
    study = optuna.create_study(sampler=make_sampler(name, seed, model_dir, budget))
    best = source_best(model_dir)
    if warm_start == "best" and name != "latent" and best is not None:
        study.enqueue_trial(physical_params(real.space, best.theta))
    t = time.perf_counter()
    study.optimize(hopper_objective(real), n_trials=budget)
    wall = time.perf_counter() - t
    trials = sorted(study.trials, key=lambda tr: tr.number)
    costs = [float(tr.value) for tr in trials]
    fell = [bool(tr.constraints.get("fall", 0.0) > 0) for tr in trials]
    curve = np.minimum.accumulate(costs).tolist()
    curve += [curve[-1]] * (budget - len(curve))           # a study that stopped early
    return {"costs": [round(c, 6) for c in costs], "fell": fell,
            "best": float(min(costs)), "falls": int(sum(fell)),
            "best_so_far": [round(c, 6) for c in curve], "trials_run": len(costs),
            "wall_s": round(wall, 2)}


def spread(values: list[float]) -> dict[str, Any]:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"n": 0, "median": None, "min": None, "max": None}
    return {"n": int(v.size), "median": float(np.median(v)), "min": float(v.min()),
            "max": float(v.max())}


def first_at_or_below(curve: list[float], level: float) -> float:
    for i, c in enumerate(curve, 1):
        if c <= level:
            return float(i)
    return math.inf


def aggregate(per_seed: list[dict[str, Any]], samplers: list[str], budget: int,
              checkpoints: list[int]) -> dict[str, Any]:
    agg: dict[str, Any] = {}
    for m in samplers:
        runs = [r["samplers"][m] for r in per_seed]
        agg[m] = {"best": spread([x["best"] for x in runs]),
                  "falls": spread([x["falls"] for x in runs]),
                  "best_at": {str(k): spread([x["best_so_far"][k - 1] for x in runs])
                              for k in checkpoints if k <= budget},
                  "wall_s": spread([x["wall_s"] for x in runs])}
    peers = [m for m in samplers if m in PEERS]
    if peers:
        best_peer = min(peers, key=lambda m: agg[m]["best"]["median"])
        level = agg[best_peer]["best"]["median"]
        agg["best_peer"] = {"name": best_peer, "median_best": level}
        for m in samplers:
            reach = [first_at_or_below(r["samplers"][m]["best_so_far"], level) for r in per_seed]
            agg[m]["trials_to_best_peer_median"] = {
                "median": float(np.median(reach)), "per_seed": reach}
        if "latent" in samplers and len(per_seed) >= 2:
            from scipy.stats import mannwhitneyu

            a = [r["samplers"]["latent"]["best"] for r in per_seed]
            b = [r["samplers"][best_peer]["best"] for r in per_seed]
            res = mannwhitneyu(a, b, alternative="two-sided")
            agg["latent_vs_best_peer"] = {"U": float(res.statistic), "p": float(res.pvalue),
                                          "latent_better_seeds": int(sum(x < y for x, y in
                                                                         zip(a, b)))}
    return agg


def _f(s: dict[str, Any], nd: int = 2) -> str:
    if s.get("median") is None:
        return "–"
    return f"{s['median']:.{nd}f} [{s['min']:.{nd}f}–{s['max']:.{nd}f}]"


def markdown(res: dict[str, Any]) -> str:
    agg, b, n = res["aggregate"], res["trials"], len(res["seeds"])
    ks = [k for k in res["checkpoints"] if k <= b]
    out = [f"Real Hopper, {b} trials per study (the zero-shot trial of LatentSampler included), "
           f"{n} seeds; phase 1 on the model: {res['phase1_evals']} evaluations, latent d_low "
           f"{res['latent_dim']}. Median [min–max] over seeds.", "",
           "| sampler | best cost | falls | trials to the best peer's median | "
           + " | ".join(f"best after {k}" for k in ks) + " |",
           "|---|---|---|---|" + "---|" * len(ks)]
    for m in res["samplers"]:
        a = agg[m]
        reach = a.get("trials_to_best_peer_median", {}).get("median")
        out.append(f"| {LABELS.get(m, m)} | {_f(a['best'])} | {_f(a['falls'], 0)} | "
                   f"{'–' if reach is None else ('never' if math.isinf(reach) else f'{reach:g}')}"
                   f" | " + " | ".join(_f(a['best_at'][str(k)]) for k in ks) + " |")
    if "best_peer" in agg:
        bp = agg["best_peer"]
        out += ["", f"Best peer: {LABELS.get(bp['name'], bp['name'])} (median best "
                f"{bp['median_best']:.2f})."]
    if "latent_vs_best_peer" in agg:
        t = agg["latent_vs_best_peer"]
        out.append(f"LatentSampler vs the best peer: better on {t['latent_better_seeds']}/{n} "
                   f"seeds, two-sided Mann–Whitney p = {t['p']:.3g}.")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    import optuna

    from examples.sim_to_real import run_model

    ap = bench_parser("benchmarks.optuna_hopper", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--trials", type=int, default=40, help="trials per study on the real Hopper")
    ap.add_argument("--phase1-evals", type=int, default=300, help="model evaluations (phase 1)")
    ap.add_argument("--latent-dim", type=int, default=5)
    ap.add_argument("--episode-steps", type=int, default=400)
    ap.add_argument("--models", default="runs/sim_to_real",
                    help="root of the model runs (MODELS/seed<s>/model; shared with "
                         "benchmarks/sim_to_real.py)")
    ap.add_argument("--samplers", nargs="+", default=list(SAMPLERS),
                    choices=("latent", "latent_fb") + PEERS)
    ap.add_argument("--checkpoints", type=int, nargs="+", default=[5, 10, 20, 40])
    ap.add_argument("--warm-start", choices=("best", "none"), default="best",
                    help="the Optuna samplers' trial 0: the model run's best θ (as latent's) "
                         "or nothing")
    ap.add_argument("--traces", type=out_dir, default=None,
                    help="per (seed, sampler) traces, reused (default: traces/ beside --out)")
    ap.add_argument("--out", type=out_file, default="results/optuna_hopper/optuna_hopper.json",
                    help="the JSON to write (a .md with the table next to it)")
    a = ap.parse_args(argv)
    for flag, v in (("trials", a.trials), ("phase1-evals", a.phase1_evals)):
        if v < 1:
            ap.error(f"--{flag} must be >= 1")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    import warnings

    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    # the objective records falls as a constraint for every sampler; CMA-ES says it ignores them
    warnings.filterwarnings("ignore", message="Constraints have been set, but CmaEsSampler")
    prov = Provenance(argv, module="benchmarks.optuna_hopper")
    traces = Path(a.traces) if a.traces else Path(a.out).parent / "traces"
    per_seed = []
    for s in a.seeds:
        model_dir = Path(a.models) / f"seed{s}" / "model"
        m = run_model(model_dir, s, a.phase1_evals, a.latent_dim, a.episode_steps)
        rec: dict[str, Any] = {"seed": s, "model": {k: m[k] for k in
                                                    ("phase1_evals", "phase1_best",
                                                     "phase1_failed", "vae_n_train")},
                               "samplers": {}}
        for name in a.samplers:
            key = {"trials": a.trials, "episode_steps": a.episode_steps,
                   "phase1_evals": a.phase1_evals, "latent_dim": a.latent_dim,
                   "warm_start": a.warm_start}
            cache = traces / f"seed{s}" / f"{name}.json"
            r = None
            if cache.is_file():
                kept = json.loads(cache.read_text())
                r = kept["trace"] if kept.get("settings") == key else None
            if r is None:
                r = run_sampler(name, s, model_dir, a.trials, a.episode_steps, a.warm_start)
                cache.parent.mkdir(parents=True, exist_ok=True)
                cache.write_text(json.dumps({"settings": key, "trace": r}) + "\n")
            rec["samplers"][name] = r
            print(f"seed {s} {name:>13}: best {r['best']:.2f}, falls {r['falls']}/{a.trials}, "
                  f"{r['wall_s']:.0f} s", flush=True)
        per_seed.append(rec)
    res: dict[str, Any] = {
        "benchmark": "optuna_hopper", "seeds": a.seeds, "trials": a.trials,
        "phase1_evals": a.phase1_evals, "latent_dim": a.latent_dim,
        "episode_steps": a.episode_steps, "samplers": a.samplers,
        "checkpoints": a.checkpoints, "models": a.models, "warm_start": a.warm_start,
        "aggregate": aggregate(per_seed, a.samplers, a.trials, a.checkpoints),
        "per_seed": per_seed}
    text = markdown(res)
    print(text)
    out = write_json(a.out, res, prov.finish())
    out.with_suffix(".md").write_text(text + "\n")
    print(f"written: {out} and {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.optuna_hopper"))
