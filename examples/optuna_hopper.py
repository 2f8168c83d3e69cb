"""An Optuna user's Hopper script, moved to latentune by changing a few lines.

The user tunes the 36 weights of the linear Hopper controller of
:mod:`examples.gym_controller` with Optuna: an objective with ``trial.suggest_float`` for each
weight by name, one study on the simulator (the nominal ``Hopper-v5``) in an SQLite storage, then
a study on the "real" Hopper (masses x1.3, friction x0.6, gear x0.8, noise, a one-step delay).
Going to latentune changes these lines (marked ``# latentune`` below):

* the objective also reports a fall: ``trial.set_constraint("fall", 1.0 if fell else 0.0)``;
* on the simulator: ``TurboSampler(space, seed=...)`` (latentune's TuRBO-m, phase 1) instead of
  ``TPESampler(seed=...)`` (``--sim-sampler tpe`` keeps TPE: the import works on any study);
* the simulator study becomes a latentune run with a latent space, without re-running a trial:
  ``import_optuna_study(storage, "hopper-sim", out / "sim").train_latent(latent_dim=5)``;
* on the real Hopper: ``LatentSampler(out / "sim", seed=...)`` instead of ``TPESampler``.

``--baseline`` also runs the unchanged script (TPE on the real Hopper) for comparison. Every study
is in ``OUT/hopper.db`` and resumes with the same ``--seed``, ``--episode-steps``,
``--sim-sampler`` and ``--latent-dim`` (recorded in ``OUT/example.json``; others are refused).
Run from the repository root::

    python -m examples.optuna_hopper --out runs/examples/optuna_hopper --sim-trials 300 --trials 40

``python -m benchmarks.optuna_hopper`` compares LatentSampler with TPE, CMA-ES with ``source_trials``
and GPSampler over seeds; ``latentune dashboard`` shows the latentune run, and
``optuna-dashboard sqlite:///OUT/hopper.db`` the Optuna studies.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402
import optuna  # noqa: E402

if __package__ in (None, ""):                   # run as a file: python examples/optuna_hopper.py
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from examples.gym_controller import (check_args, hopper_space,  # noqa: E402
                                     make_real_system, make_system)
from latentune.integrations.optuna import (LatentSampler, TurboSampler,  # noqa: E402  # latentune
                                           import_optuna_study, trial_fell)

SPACE = hopper_space()                           # names, bounds and the hand-tuned weights


def make_objective(system: Any) -> Callable[[optuna.Trial], float]:
    """The user's objective: 36 ``suggest_float`` by name, one episode, its cost."""
    def objective(trial: optuna.Trial) -> float:
        w = np.array([trial.suggest_float(n, lo, hi)
                      for n, lo, hi in zip(SPACE.names, SPACE.lower, SPACE.upper)])
        out = system.evaluate(np.clip(SPACE.to_unit(w), 0.0, 1.0))     # one 400-step episode
        trial.set_constraint("fall", 1.0 if out.failed else 0.0)         # latentune: a fall
        return out.cost
    return objective


def results_of(study: optuna.Study) -> tuple[float | None, int, int]:
    """(best cost of the trials that did not fall, or None when every one fell; falls; finished
    trials) of a study: a fall is never its best, whatever cost it was given (a FAIL trial,
    without a value, counts as a fall)."""
    S = optuna.trial.TrialState
    done = study.get_trials(deepcopy=False, states=(S.COMPLETE, S.FAIL))
    stood = [t.value for t in done if not trial_fell(t) and t.value is not None]
    return (min(stood) if stood else None), sum(trial_fell(t) for t in done), len(done)


def _best_text(best: float | None) -> str:
    return "none (every trial fell)" if best is None else f"{best:.2f}"


SETTINGS = ("seed", "episode_steps", "sim_sampler", "latent_dim")
"""The arguments that decide what ``OUT``'s studies hold (the budgets may grow on a re-run)."""


def check_out(out: Path, a: Any) -> None:
    """UsageError unless ``out`` is a new directory or holds the studies of these
    :data:`SETTINGS` (recorded in ``OUT/example.json`` when the directory is new): a re-run
    with another seed, episode length or simulator sampler would resume the stored studies and
    report them as runs of these."""
    from latentune.errors import UsageError

    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory")
    f, given = out / "example.json", {k: getattr(a, k) for k in SETTINGS}
    if f.is_file():
        stored = json.loads(f.read_text())
        diff = [f"--{k.replace('_', '-')} {stored[k]} (not {given[k]})" for k in SETTINGS
                if k in stored and stored[k] != given[k]]
        if diff:
            raise UsageError(f"{out} holds the studies of {', '.join(diff)}: give another --out, "
                             "or the stored values to resume them")
    elif not (out / "hopper.db").exists():        # a new directory (an older one: unrecorded)
        out.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps(given))


def main(argv: list[str] | None = None) -> int:
    """The script (module docstring); a bad argument, or an ``--out`` of other settings
    (:func:`check_out`), is one line on stderr and exit 2."""
    import argparse

    from latentune.errors import LatentuneError

    ap = argparse.ArgumentParser(prog="examples.optuna_hopper",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/examples/optuna_hopper", help="output directory")
    ap.add_argument("--sim-trials", type=int, default=300, help="trials on the simulator")
    ap.add_argument("--trials", type=int, default=40, help="trials on the real Hopper")
    ap.add_argument("--sim-sampler", choices=("turbo", "tpe"), default="turbo")
    ap.add_argument("--latent-dim", type=int, default=5)
    ap.add_argument("--episode-steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--baseline", action="store_true", help="also run TPE on the real Hopper")
    a = ap.parse_args(argv)
    try:
        check_args(a)                   # counts, seed, latent size: before any trial
        check_out(Path(a.out), a)
        return _run(a)
    except LatentuneError as exc:
        print(f"{ap.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


def _run(a: Any) -> int:
    """The script's run for the parsed arguments ``a`` (see :func:`main`)."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    storage = f"sqlite:///{out.resolve() / 'hopper.db'}"
    sim, real = (make_system(seed=a.seed, episode_steps=a.episode_steps),
                 make_real_system(seed=a.seed, episode_steps=a.episode_steps))

    # 1. the simulator study
    if a.sim_sampler == "turbo":
        sampler = TurboSampler(SPACE, seed=a.seed, budget=a.sim_trials, start="manual")  # latentune
    else:
        sampler = optuna.samplers.TPESampler(seed=a.seed)
    study = optuna.create_study(study_name="hopper-sim", storage=storage, sampler=sampler,
                                load_if_exists=True)
    study.optimize(make_objective(sim), n_trials=max(0, a.sim_trials - len(study.trials)))
    best, falls, _ = results_of(study)                  # a fall is never the best
    print(f"simulator: {len(study.trials)} trials ({falls} fell), best cost "
          f"{_best_text(best)}", flush=True)

    # 2. latentune: the simulator study as phase 1, and its latent space (phase 2)
    run = import_optuna_study(storage, "hopper-sim", out / "sim", seed=a.seed)        # latentune
    latent = run.train_latent(latent_dim=a.latent_dim)                                 # latentune
    print(f"latent space: d_low {latent.d_low}, trained on {latent.meta.get('n_train')} θ that "
          "did not fall", flush=True)

    # 3. the real Hopper
    results = {}
    samplers = {"latent": lambda: LatentSampler(out / "sim", seed=a.seed,               # latentune
                                                budget=a.trials)}
    if a.baseline:
        samplers["tpe"] = lambda: optuna.samplers.TPESampler(seed=a.seed)
    for name, make in samplers.items():
        study = optuna.create_study(study_name=f"hopper-real-{name}", storage=storage,
                                    sampler=make(), load_if_exists=True)
        study.optimize(make_objective(real), n_trials=max(0, a.trials - len(study.trials)))
        results[name] = results_of(study)
    print(f"\n| on the real Hopper (seed {a.seed}) | trials | best cost | falls |")
    print("|---|---:|---:|---:|")
    for name, (best, falls, n) in results.items():
        label = "LatentSampler (simulator's latent space)" if name == "latent" else "TPE"
        print(f"| {label} | {n} | {_best_text(best)} | {falls} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
