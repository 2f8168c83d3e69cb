"""The transfer ladder: phase 3 against the tools a user would pick, on targets at several gaps.

    python -m benchmarks.transfer run [--systems chain arm hopper] [--seeds 0 1 ... 9]
        [--budget 40] [--source-evals 300] [--root runs/transfer] [--only METHOD ...]
        [--variants OPTION=VALUE[:OPTION=VALUE] ...]   (transfer variants, stored as transfer+VARIANT)
    python -m benchmarks.transfer summary [--root runs/transfer] [--out F.json]
        [--default transfer+VARIANT] [--methods METHOD ...] [--machine M] [--budget B]
        (prints the tables; --out also writes them, F.json and F.md; --machine: read METHOD@M
        runs as METHOD; --budget: read every run as its first B trials)
    python -m benchmarks.transfer prefix --root DIR --stored DIR --budget B [--out F]
        (runs made at a larger budget: exit 0 when each one's first trials equal its stored
        twin's at budget B, 1 when one differs)
    python -m benchmarks.transfer compare --root runs/transfer --a METHOD ... --b METHOD ...
        [--seeds S ...] [--systems SYSTEM ...] [--out F]
    python -m benchmarks.transfer cut --root DIR --method METHOD --share Q --as NAME
        [--counts all|after_stand] [--seeds S ...]   (METHOD's runs as fall_budget = Q runs them)
    python -m benchmarks.transfer check-default --stored DIR --method METHOD [--root runs/transfer]
        [--systems ...] [--seeds S ...]   (re-runs METHOD's stored runs with the critic's own
        defaults: exit 0 when every cost and fall is the same, 1 when one differs)

Systems (``SYSTEMS``; the model is gap 0, each target is the same controller on a plant at a gap):

* ``chain``  — :mod:`examples.lqr_chain`, 20 LQR weights of a seven-cart chain (gaps 0.5, 1, 1.5,
  2: at 2 most θ that were stable on the model fail);
* ``arm``    — :mod:`examples.arm_controller`, 21 joint-controller weights of a two-link arm
  (gaps 0.5, 1, 1.5);
* ``hopper`` — :mod:`examples.gym_controller`, 36 weights of a linear Hopper controller; gap g
  scales the "real" perturbation: masses × (1 + 0.3 g), friction × (1 − 0.4 g), gear × (1 − 0.2 g),
  observation noise 0.01 g, a round(g)-step action delay (gaps 0.5, 1, 1.5).
* ``springs`` — :mod:`examples.toy_plant`, 24 state-feedback gains of four masses on springs;
  gap g: masses × (1 − 0.2 g), stiffness × (1 − 0.2 g), damping × (1 − 0.5 g), actuators ×
  (1 + 0.5 g): a lighter, softer plant with stronger actuators, where the gains that damp the
  model push the target unstable (at gap 2 the springs have no damping of their own and most
  θ that are stable on the model fail; gaps 0.5, 1, 1.5, 2). Added after the default was
  chosen and never used to choose an option: the held-out system.
* ``zones`` — :mod:`examples.thermal_zones`, 20 PI / anti-windup / feed-forward gains of five
  thermal zones; gap g: lighter rooms, stronger walls between them, weaker heaters and a
  round(2 g)-step sensor delay (gaps 0.5, 1, 2: at 2, 90 % of the θ that hold the comfort band
  on the model leave it). Added in session 30, after every option was chosen: a second
  held-out system, of another kind (first-order heat flow, integral control, saturation).
* ``quadrotor`` — :mod:`examples.quadrotor_mpc`, 20 weights of a constrained linear MPC (DAQP)
  flying a planar quadrotor through set-point steps; gap g: mass × (1 + 0.15 g), inertia ×
  (1 + 0.5 g), motor limits × (1 − 0.1 g), drag, side wind and a round(g)-step actuation delay
  (gaps 0.5, 1, 2.5: at 2.5, 72 % of the random θ that fly the model fall). Added in session
  35, after every option was chosen: a third held-out system (an MPC, an underactuated
  nonlinear plant, input saturation).
* ``vehicle`` — :mod:`examples.vehicle_lateral`, 20 speed-scheduled lane-keeping gains of a car
  (a single-track model with saturating tyres on a road of curves, 12 → 28 m/s); gap g: a
  wetter road, worn tyres (rear more: toward oversteer), a heavier car and a round(g)-step
  steering delay (gaps 0.5, 1, 2: at 2 most θ that keep the model in lane leave it). Added in
  session 44, after every option was chosen: a fourth held-out system.
* ``cartpole`` — :mod:`examples.cartpole_swingup`, 20 weights of a cart-pole's energy swing-up
  and LQR balance controller (two modes, rates estimated from positions); gap g: a heavier,
  longer pole, more cart friction, a weaker motor and a round(2 g)-step actuation delay (gaps
  0.5, 1, 2: at 2 most θ that balance the model fail). Added in session 45, after every option
  was chosen: a fifth held-out system.
* ``servo`` — :mod:`examples.servo_cascade`, 14 gains and filters of a cascaded servo drive on a
  flexible shaft (gaps 0.25, 0.5, 1). Added in session 50: a sixth held-out system.
* ``buck`` — :mod:`examples.buck_converter`, 15 gains, limits and filters of a synchronous buck
  converter's digital voltage and current loops; gap g: less inductance and capacitance (and the
  ceramic's DC-bias derating), less ESR, a lower and rippled input, a round(2 g)-cycle longer
  sensing delay and heavier load steps (gaps 0.25, 0.5, 1: at 1 none of the 50 best of 1,500
  random θ that stand on the model stand). Added in session 51: a seventh held-out system.
* ``bowl`` — :mod:`examples.shifted_bowl`, a smooth anisotropic bowl in 8 weights whose optimum
  the gap moves by g along every weight, no falls (gaps 0.1, 0.2, 0.3): a probe of phase 3's
  refinement where the source is nearly right. Added in session 51.

For every (system, seed) one source run: ``Study(ROOT/<system>/seed<s>/source, seed=s)``, phase 1
(TuRBO-m, ``--source-evals`` trials on the model, batch 4) and the latent space. For every target
(system, gap) and seed each method gets ``--budget`` B trials on the target, one at a time, every
trial counted (the zero-shot one included):

* ``transfer``     latentune's transfer phase 3 (:class:`latentune.critic.transfer.Transfer`): the
  zero-shot θ, then the critic on everything the source tried. The name keeps the meaning of
  its stored runs: the critic's defaults with the explore pool of the default before session
  32 and the explore asks of the default before session 39 (:data:`LADDER_BASE`);
  ``transfer+OPTIONS`` is that with OPTIONS, so the default of sessions 32–38 is
  ``transfer+explore_pool=adaptive`` and the default since session 39
  ``transfer+explore_pool=adaptive:explore_gp=true:explore_fall_prob=0.2``;
* ``plain``        the paper's phase 3 as ``Study.phase3`` runs it: the manual θ, the zero-shot θ,
  then TuRBO-m in the latent box from the manual θ's code (not a peer);
* ``handover``     the same with the hand-over to the full θ box (not a peer);
* peers: ``zero_shot`` (the source's best θ, one trial), ``turbo_manual`` / ``turbo_source``
  (TuRBO-m, one trust region, on θ from the manual θ / the source's best), and Optuna 5's
  ``cma_source`` (``CmaEsSampler(x0=source best)``), ``cma_source_trials``
  (``CmaEsSampler(source_trials=<every source trial>)``), ``tpe`` (multivariate) and ``gp``
  (``GPSampler``), each with the source's best θ enqueued as its first trial
  (:class:`latentune.critic.optuna.OptunaCritic`).

Every (system, gap, seed, method) writes ``ROOT/<system>/gap<g>/seed<s>/<method>.json`` (cost,
failed and θ per trial, wall time) and is skipped when it exists: the run resumes (refused before any run where a
stored run or source was made with another ``--budget`` or ``--source-evals``, or a stored run
is damaged). ``summary``
applies the transfer issue's definitions (best peer, trials to reach its median, falls,
Mann-Whitney), cuts every method's runs at the default's falls and at criterion (3)'s allowance
(:func:`fall_allowance`: which methods are then still no worse than the best peer), and writes
JSON + Markdown with provenance. ``--only`` also runs the candidates of :data:`SCREENED`
(CMA-ES behind the default's fall screen, :func:`screened_cma`), which a plain ``run`` leaves
out.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env

one_thread_env()

import numpy as np  # noqa: E402

from benchmarks.common import error_line  # noqa: E402
from latentune.system import evaluate  # noqa: E402

PEERS = ("zero_shot", "turbo_manual", "turbo_source", "cma_source", "cma_source_trials", "tpe",
         "gp")
OURS = ("transfer",)
BESIDE = ("plain", "handover")
METHODS = OURS + BESIDE + PEERS
SCREENED = ("cma_source_screened", "cma_source_trials_screened", "transfer_cma_source",
            "transfer_cma_source_trials")
"""Candidates run on request only (``--only``): a CMA-ES peer whose every sample passes the
default transfer critic's fall screen first, and (``transfer_cma_*``) that CMA-ES's admitted
samples first and the default transfer critic's ask where it has none (:func:`screened_cma`)."""


def _hopper_target(g: float) -> Any:
    from examples.gym_controller import make_real_system

    return make_real_system(seed=0, mass_scale=1 + 0.3 * g, friction_scale=1 - 0.4 * g,
                            gear_scale=1 - 0.2 * g, obs_noise=0.01 * g,
                            action_delay=int(round(g)))


def _hopper_model() -> Any:
    from examples.gym_controller import make_system

    return make_system(seed=0)


def _chain(g: float) -> Any:
    from examples.lqr_chain import make_system

    return make_system(gap=g)


def _arm(g: float) -> Any:
    from examples.arm_controller import make_system

    return make_system(gap=g)


def _zones(g: float) -> Any:
    from examples.thermal_zones import make_system

    return make_system(gap=g)


def _quadrotor(g: float) -> Any:
    from examples.quadrotor_mpc import make_system

    return make_system(gap=g)


def _vehicle(g: float) -> Any:
    from examples.vehicle_lateral import make_system

    return make_system(gap=g)


def _cartpole(g: float) -> Any:
    from examples.cartpole_swingup import make_system

    return make_system(gap=g)


def _servo(g: float) -> Any:
    from examples.servo_cascade import make_system

    return make_system(gap=g)


def _buck(g: float) -> Any:
    from examples.buck_converter import make_system

    return make_system(gap=g)


def _bowl(g: float) -> Any:
    from examples.shifted_bowl import make_system

    return make_system(gap=g)


def _springs(g: float) -> Any:
    from examples.toy_plant import make_real_system

    return make_real_system(mass_scale=1 - 0.2 * g, stiffness_scale=1 - 0.2 * g,
                            damping_scale=1 - 0.5 * g, gain_scale=1 + 0.5 * g)


SYSTEMS: dict[str, dict[str, Any]] = {
    "chain": {"model": lambda: _chain(0.0), "target": _chain, "gaps": (0.5, 1.0, 1.5, 2.0)},
    "arm": {"model": lambda: _arm(0.0), "target": _arm, "gaps": (0.5, 1.0, 1.5)},
    "hopper": {"model": _hopper_model, "target": _hopper_target, "gaps": (0.5, 1.0, 1.5)},
    "springs": {"model": lambda: _springs(0.0), "target": _springs,
                "gaps": (0.5, 1.0, 1.5, 2.0)},
    "zones": {"model": lambda: _zones(0.0), "target": _zones, "gaps": (0.5, 1.0, 2.0)},
    "quadrotor": {"model": lambda: _quadrotor(0.0), "target": _quadrotor,
                  "gaps": (0.5, 1.0, 2.5)},
    "vehicle": {"model": lambda: _vehicle(0.0), "target": _vehicle, "gaps": (0.5, 1.0, 2.0)},
    "cartpole": {"model": lambda: _cartpole(0.0), "target": _cartpole, "gaps": (0.5, 1.0, 2.0)},
    "servo": {"model": lambda: _servo(0.0), "target": _servo, "gaps": (0.25, 0.5, 1.0)},
    "buck": {"model": lambda: _buck(0.0), "target": _buck, "gaps": (0.25, 0.5, 1.0)},
    "bowl": {"model": lambda: _bowl(0.0), "target": _bowl, "gaps": (0.1, 0.2, 0.3)},
}


# --------------------------------------------------------------------------- sources
def check_source(d: Path, evals: int) -> None:
    """ValueError when the source run ``d`` holds a phase 1 asked for another number of trials
    than ``evals``: resuming it would extend (or keep) a phase 1 of another size under the
    latent space and the target runs made from it. Nothing to check where ``d`` has no store."""
    from latentune.pipeline.store import RunStore

    if not (d / "run.db").is_file():
        return
    with RunStore(d) as st:
        stored = (st.get_meta("config") or {}).get("phase1", {}).get("budget")
    if stored is not None and int(stored) != evals:
        raise ValueError(f"the source {d} was made with --source-evals {stored}, not {evals}: "
                         f"use another --root (or, with run, --source-evals {stored})")


def source_run(root: Path, system: str, seed: int, evals: int) -> Path:
    """Phase 1 + the latent space on the model (resumes); the source directory. ValueError
    when a stored source there was asked for another phase-1 size (:func:`check_source`)."""
    import latentune as lt

    d = root / system / f"seed{seed}" / "source"
    check_source(d, evals)
    with lt.Study(d, seed=seed, batch_size=4) as st:
        st.phase1(SYSTEMS[system]["model"](), evals)
        st.train_latent()
    return d


def source_hypers(src: Path, seed: int, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The source models' fitted hyperparameters of the transfer critic with ``options`` and
    ``seed`` on the source ``src``, fitted once and cached as JSON beside it: the fit the critic
    would make itself (its subset depends on the seed and ``source_order``).

    ``source_order="stored"`` with the default ``max_points`` keeps the cache of the runs made
    before the option (``transfer_source_model.json``, fitted with the seed of its first use);
    any other choice has its own file per seed."""
    from latentune.critic.transfer import TRANSFER_DEFAULTS, Transfer
    from latentune.pipeline.baselines import source_trials
    from latentune.critic.transfer_model import SourceModel

    opts = {**TRANSFER_DEFAULTS, **(options or {})}
    legacy = (opts["source_order"] == "stored"
              and opts["max_points"] == TRANSFER_DEFAULTS["max_points"])
    f = src / ("transfer_source_model.json" if legacy else
               f"transfer_source_model.{opts['source_order']}.m{opts['max_points']}.s{seed}.json")
    if f.is_file():
        return json.loads(f.read_text())
    X, y, fell = source_trials(src)
    if legacy:
        h = SourceModel(X, y, fell, seed=seed).hypers
    else:
        h = Transfer((X, y, fell), None, None, seed=seed, source_order=opts["source_order"],
                     max_points=opts["max_points"]).source_model().hypers
    tmp = f.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(h))
    os.replace(tmp, f)                       # workers sharing a source never read half a file
    return h


# --------------------------------------------------------------------------- methods
def _loop(critic: Any, target: Any, n: int, costs: list, failed: list,
          decode: Callable[[np.ndarray], np.ndarray] | None = None,
          thetas: list | None = None) -> None:
    """``n`` trials of ``critic`` on ``target`` one at a time: its points are θ, or latent points
    mapped by ``decode``; two-space critics (``last_z``) get their codes back. The θ tried (unit
    box) are appended to ``thetas`` when given."""
    for _ in range(n):
        U = critic.ask(1)
        tags = critic.last_tags.copy()
        Z = getattr(critic, "last_z", None)
        theta = U[0] if decode is None else decode(U)[0]
        out = evaluate(target, theta)      # a failure without a cost gets C1 · (2 − k/N)
        costs.append(float(out.cost))
        failed.append(bool(out.failed))
        if thetas is not None:
            thetas.append([float(v) for v in np.asarray(theta).reshape(-1)])
        kw = {} if Z is None or Z.shape[1] == 0 else {"z": Z.copy()}
        critic.tell(U, np.array([out.cost]), tags, fell=np.array([out.failed]), **kw)


def _sim_check_loop(critic: Any, target: Any, model: Any, k: int, n: int, costs: list,
                    failed: list, thetas: list, pick: bool | str = False) -> int:
    """``n`` trials of the transfer ``critic`` on ``target``, each after the ``k`` θ the critic
    would ask now (:meth:`~latentune.critic.base.Critic.propose`) ran on the source system
    ``model`` and were added to its source models (:meth:`~latentune.critic.transfer.Transfer.
    add_source`; the option ``sim_check=k`` of a ``transfer+…`` method). The critic then asks;
    with ``pick`` (``sim_pick=true``) the trial is instead the checked θ with the lowest mean of
    the target cost model among those the fall screen admits (all when none is), told under
    its own tag; with ``pick="agree"`` only while the model's agreement is confidently
    positive (the posterior mean of ``a`` minus two standard deviations above 0). Returns the
    source trials made."""
    made = 0
    for _ in range(n):
        P, T = critic.propose(k)
        Zp = critic._proposer.last_z.copy()
        outs = [evaluate(model, p) for p in P]
        critic.add_source(P, np.array([float(o.cost) for o in outs]),
                          np.array([bool(o.failed) for o in outs]))
        made += len(outs)
        cost_m, fall_m = critic.models() if pick else (None, None)
        if cost_m is not None and pick == "agree":
            mean, sd = cost_m.coefficients()
            if not float(mean[0]) - 2.0 * float(sd[0]) > 0.0:
                cost_m = None
        if cost_m is None:
            _loop(critic, target, 1, costs, failed, thetas=thetas)
            continue
        mu = cost_m.mean_cov(P, with_cov=False)[0]
        ok = critic._fall_prob(P, fall_m) <= float(critic.opts["max_fall_prob"]) \
            if fall_m is not None else np.ones(len(P), dtype=bool)
        j = int(np.flatnonzero(ok)[np.argmin(mu[ok])]) if ok.any() else int(np.argmin(mu))
        out = evaluate(target, P[j])
        costs.append(float(out.cost))
        failed.append(bool(out.failed))
        thetas.append([float(v) for v in P[j]])
        kw = {} if Zp.shape[1] == 0 else {"z": Zp[j:j + 1]}
        critic.tell(P[j:j + 1], np.array([out.cost]), T[j:j + 1], fell=np.array([out.failed]),
                    **kw)
    return made


def parse_variant(text: str) -> dict[str, Any]:
    """``"option=value[:option=value]"`` as Transfer options (values read as JSON, else text)."""
    out: dict[str, Any] = {}
    for part in filter(None, text.split(":")):
        k, _, v = part.partition("=")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def check_variant(text: str) -> None:
    """UsageError (a ValueError) naming the option when the variant ``text`` holds an option
    the transfer critic does not have or a value it refuses (the checks phase 3's
    ``max_fall_prob`` and ``transfer_options`` get, :mod:`latentune.pipeline.manifest`)."""
    from latentune.pipeline.manifest import fall_options, transfer_option

    opts = parse_variant(text)
    k = opts.pop("sim_check", 0)
    if isinstance(k, bool) or not isinstance(k, int) or k < 0:
        raise ValueError(f"sim_check must be an integer >= 0, got {k!r}")
    if opts.pop("sim_pick", False) not in (True, False, "agree"):
        raise ValueError("sim_pick must be true, false or agree")
    mfp = opts.pop("max_fall_prob", None)
    fall_options(mfp, None)
    transfer_option(opts or None, "transfer", mfp)


SOURCE_EVALS = 300
"""Phase-1 trials of each seed's source run on the model (``run --source-evals``)."""

LADDER_BASE: dict[str, Any] = {"explore_pool": "latent", "explore_gp": False,
                               "explore_fall_prob": 0.0, "fall_budget_counts": "all"}
"""The transfer critic's options under the method name ``transfer`` beyond its defaults: the
explore pool every stored ``transfer`` and ``transfer+…`` run was made with (the default before
session 32), the explore asks' choice and bound of the runs before session 39, and the fall
budget's count of session 43's ``…:fall_budget=0.15`` runs (every fall), so that a run added
later under a stored name is the same method."""

DEFAULT_METHOD = "transfer+explore_pool=adaptive:explore_gp=true:explore_fall_prob=0.2"
"""Today's default phase 3 (since session 39) in the ladder's method names: ``transfer`` with
the options that give :data:`LADDER_BASE`'s keys back the critic's defaults. The benchmarks that
read the default's stored runs take this name."""


def run_method(method: str, target: Any, src: Path, B: int, seed: int,
               options: dict[str, Any] | None = None) -> dict[str, Any]:
    """B target trials of ``method`` (module docstring; ``options``: the transfer critic's
    options beyond its defaults); returns costs, failed, the θ tried (unit box, one list per
    trial) and extras."""
    from latentune.critic.transfer import Transfer
    from latentune.pipeline.baselines import source_trials
    from latentune.latent.vae import LatentSpace
    from latentune.study import source_best

    best = source_best(src).theta
    manual = target.space.manual
    Xs, ys, fs = source_trials(src)
    costs: list[float] = []
    failed: list[bool] = []
    thetas: list[list[float]] = []
    extra: dict[str, Any] = {}

    def trial(theta: np.ndarray) -> Any:
        out = evaluate(target, theta)      # a failure without a cost gets C1 · (2 − k/N)
        costs.append(float(out.cost))
        failed.append(bool(out.failed))
        thetas.append([float(v) for v in np.asarray(theta).reshape(-1)])
        return out

    if method == "zero_shot":
        trial(best)
    elif method == "transfer":
        ls = LatentSpace.load(src / "vae")
        opts = dict(options or {})
        k = int(opts.pop("sim_check", 0))
        pick = opts.pop("sim_pick", False)
        cr = Transfer((Xs, ys, fs), ls, manual, batch_size=1, seed=seed, budget=B,
                      **{**LADDER_BASE, **opts})
        cr.load_state_dict({"source_hypers": source_hypers(src, seed, opts)})
        o = trial(best)
        cr.tell(best[None], np.array([o.cost]), fell=np.array([o.failed]))
        if k:
            model = SYSTEMS[src.parent.parent.name]["model"]()
            extra["source_checks"] = _sim_check_loop(cr, target, model, k, B - 1, costs,
                                                     failed, thetas, pick)
        else:
            _loop(cr, target, B - 1, costs, failed, thetas=thetas)
        extra["decisions"] = cr.decisions
    elif method in ("plain", "handover"):
        from latentune.pipeline.phases import make_handover_critic, make_phase_critic, \
            handover_options

        ls = LatentSpace.load(src / "vae")
        trial(manual)
        trial(best)
        x0 = ls.to_unit(ls.encode(manual))
        if method == "plain":
            cr = make_phase_critic("turbo", ls.d_low, 1, seed, x0, B - 2)
            _loop(cr, target, B - 2, costs, failed, decode=ls.decode, thetas=thetas)
        else:
            cr = make_handover_critic("turbo", ls, 1, seed, x0, B - 2, None,
                                      handover_options(True))
            _loop(cr, target, B - 2, costs, failed, thetas=thetas)
    elif method in ("turbo_manual", "turbo_source"):
        from latentune.critic.turbo import TurboM

        x0 = manual if method == "turbo_manual" else best
        cr = TurboM(target.space.dim, batch_size=1, seed=seed, x0=x0, n_regions=1)
        _loop(cr, target, B, costs, failed, thetas=thetas)
    elif method in SCREENED:
        extra["draws"] = screened_cma(trial, target, src, (Xs, ys, fs), best, B, seed,
                                      method.endswith("_trials_screened")
                                      or method.endswith("_source_trials"),
                                      fallback=method.startswith("transfer_"))
    else:
        from latentune.critic.optuna import OptunaCritic

        sampler = {"cma_source": "cmaes", "cma_source_trials": "cmaes", "tpe": "tpe",
                   "gp": "gp"}[method]
        cr = OptunaCritic(target.space.dim, batch_size=1, seed=seed, x0=best, sampler=sampler,
                          source=(Xs, ys) if method == "cma_source_trials" else None)
        _loop(cr, target, B, costs, failed, thetas=thetas)
    return {"costs": costs, "failed": failed, "thetas": thetas, **extra}


SCREEN_DRAWS = 200
"""How many CMA-ES samples :func:`screened_cma` draws at most for one target trial."""


def screened_cma(trial: Callable[[np.ndarray], Any], target: Any, src: Path,
                 source: tuple[np.ndarray, np.ndarray, np.ndarray], best: np.ndarray, B: int,
                 seed: int, warm: bool, fallback: bool = False) -> list[int]:
    """``B`` target trials of Optuna's CMA-ES (``warm``: with ``source_trials``, else with its
    mean at the source's best θ ``best`` (d,)), the source's best enqueued first as in the
    peers, whose samples pass the default transfer critic's fall screen first: a sample whose
    fall probability (the critic's screen, on the source and every target trial so far)
    exceeds its ``max_fall_prob`` is told to the study as failed, which CMA-ES leaves out of
    its generation, and the next one is drawn; after :data:`SCREEN_DRAWS` draws the one least
    likely to fall runs (the others told as failed), or with ``fallback`` the default transfer
    critic's own ask, enqueued in the study so CMA-ES counts it in its generation. ``trial``
    runs θ on the target and returns its outcome (``cost``, ``failed``). Returns the samples
    drawn per trial (0: the critic asked)."""
    import optuna

    from latentune.critic.optuna import _Quiet, baseline_sampler
    from latentune.critic.transfer import TRANSFER_DEFAULTS, Transfer
    from latentune.latent.vae import LatentSpace

    Xs, ys, _ = source
    screen = Transfer(source, LatentSpace.load(src / "vae"), target.space.manual,
                      batch_size=1, seed=seed, budget=B)
    screen.load_state_dict({"source_hypers": source_hypers(src, seed, None)})
    names = [f"x{i:03d}" for i in range(len(best))]
    dist = {n: optuna.distributions.FloatDistribution(0.0, 1.0) for n in names}

    def params(x: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(names, x)}

    bound = float(TRANSFER_DEFAULTS["max_fall_prob"])
    draws: list[int] = []
    with _Quiet():
        src_trials = [optuna.trial.create_trial(params=params(x), distributions=dist,
                                                value=float(c))
                      for x, c in zip(np.clip(Xs, 0.0, 1.0), ys) if math.isfinite(c)] \
            if warm else None
        study = optuna.create_study(direction="minimize", sampler=baseline_sampler(
            "cmaes", seed, x0=None if warm else params(best), source_trials=src_trials))
        study.enqueue_trial(params(best))
        for k in range(B):
            fall_m = screen._fall_model(screen.n_told) if screen.n_told else None
            drawn: list[tuple[Any, float]] = []
            while True:
                t = study.ask(dist)
                x = np.array([t.params[n] for n in names])
                pf = 0.0 if k == 0 else float(screen._fall_prob(x[None], fall_m)[0])
                drawn.append((t, pf))
                if pf <= bound or len(drawn) >= SCREEN_DRAWS:
                    break
            admitted = drawn[-1][1] <= bound
            pick = drawn[-1] if admitted else min(drawn, key=lambda d: d[1])
            own = fallback and not admitted
            for t, _ in drawn:
                if own or t is not pick[0]:
                    study.tell(t, state=optuna.trial.TrialState.FAIL)
            tags = None
            if own:                     # the critic asks; CMA-ES gets its point enqueued
                x_own = np.clip(screen.ask(1)[0], 0.0, 1.0)
                tags = screen.last_tags.copy()
                study.enqueue_trial(params(x_own))
                t = study.ask(dist)
            else:
                t = pick[0]
            x = np.array([t.params[n] for n in names])
            o = trial(x)
            c = float(o.cost)
            if not math.isfinite(c):    # the worst finite value told so far, as the peers
                c = max((d.value for d in study.get_trials(
                    deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))), default=0.0)
            study.tell(t, c)
            screen.tell(x[None], np.array([o.cost]), tags, fell=np.array([o.failed]))
            draws.append(0 if own else len(drawn))
    return draws


def default_options() -> dict[str, Any]:
    """Options over :data:`LADDER_BASE` that give the transfer critic its own defaults (each
    base key at :data:`~latentune.critic.transfer.TRANSFER_DEFAULTS`' value): ``run_method``
    with them runs today's default phase 3."""
    from latentune.critic.transfer import TRANSFER_DEFAULTS

    return {k: TRANSFER_DEFAULTS[k] for k in LADDER_BASE}


def check_default(root: Path, stored: Path, method: str, systems: list[str],
                  seeds: list[int]) -> list[dict[str, Any]]:
    """Re-run each stored run ``stored/<system>/gap<g>/seed<s>/<method>.json`` with today's
    default phase 3 (:func:`default_options`) on the source ``root/<system>/seed<s>/source``
    (made when missing) at the stored budget; one row per run: system, gap, seed, ``same``
    (costs and falls equal to the stored ones, trial by trial) and both best costs. Missing
    stored runs are skipped; ValueError when none is found."""
    rows = []
    for name in systems:
        for seed in seeds:
            for g in SYSTEMS[name]["gaps"]:
                f = stored / name / f"gap{g:g}" / f"seed{seed}" / f"{method}.json"
                if not f.is_file():
                    continue
                s = json.loads(f.read_text())
                src = source_run(root, name, seed, SOURCE_EVALS)
                r = run_method("transfer", SYSTEMS[name]["target"](g), src, int(s["budget"]),
                               seed, default_options())
                rows.append({"system": name, "gap": g, "seed": seed,
                             "same": r["costs"] == s["costs"] and r["failed"] == s["failed"],
                             "best": min(r["costs"]), "stored_best": min(s["costs"])})
                print(f"{name} gap {g:g} seed {seed}: {'same' if rows[-1]['same'] else 'DIFFERS'}"
                      f" (best {rows[-1]['best']:.6g}, stored {rows[-1]['stored_best']:.6g})",
                      flush=True)
    if not rows:
        raise ValueError(f"no stored run of {method} under {stored} for these systems and seeds")
    return rows


def compare_text(rows: list[dict[str, Any]]) -> str:
    """:func:`compare` rows as text: one line per pair of methods, one per target below it."""
    out = []
    for r in rows:
        g, w = r.get("ratio_geo_mean"), r.get("ratio_worst")
        out.append(f"{r['a']} vs {r['b']}: {r['wins']} wins, {r['ties']} ties, {r['losses']} "
                   f"losses of {r['pairs']} (sign test p {r['sign_test_p']:.3f}); falls "
                   f"{r['falls_a']} vs {r['falls_b']}"
                   + (f" (more on {fp['more']}, fewer on {fp['fewer']} of the pairs, sign test "
                      f"p {fp['sign_test_p']:.3f})" if (fp := r.get("falls_paired")) else "")
                   + (f"; median ratio: geometric mean {g:.3f}, worst {w['ratio']:.3f} "
                      f"({w['target']})" if g is not None and w is not None else "")
                   + (f"; paired ratio: geometric mean {pg:.3f}"
                      if (pg := r.get("paired_geo_mean")) is not None else ""))
        if (bar := r.get("bar")) is not None:
            said = {"paired_geo_mean": lambda c: f"paired ratio {c['value']:.4f} ≤ {c['limit']:g}",
                    "falls": lambda c: f"falls {c['value'][0]} ≤ {c['limit']:g} × "
                                       f"{c['value'][1]}",
                    "targets": lambda c: f"no target above {c['limit'][0]:g} × while losing "
                                         f"≥ {c['limit'][1]:g} of its seeds "
                                         f"({', '.join(c['failing']) or 'none'})"}
            out.append("  bar: " + ("PASSES" if bar["pass"] else "FAILS") + " — " + "; ".join(
                f"{said[k](c)}: {'holds' if c['pass'] else 'fails'}"
                for k, c in bar.items() if k != "pass"))
        out += [f"  {t}: {c['wins']}/{c['ties']}/{c['losses']} (w/t/l), falls "
                f"{c['falls_a']} vs {c['falls_b']}"
                + (f", medians {c['median_a']:.4g} vs {c['median_b']:.4g}"
                   if "median_a" in c else "")
                + (f", paired ratio {c['paired_ratio']:.3f}"
                   if c.get("paired_ratio") is not None else "")
                for t, c in r["by_target"].items()]
    return "\n".join(out)


# --------------------------------------------------------------------------- run / summary
def ladder_targets(systems: list[str], gaps: list[float] | None) -> dict[str, list[tuple]]:
    """Each system's targets ``[(g, target system)]``: its named ladder gaps
    (``SYSTEMS[name]["gaps"]``), or ``gaps`` (gaps not on the ladder, the same for every
    system). A gap a system cannot take (its factory raises ValueError, e.g. a scale that would
    turn negative) raises ValueError naming the system and the gap, before any run."""
    out: dict[str, list[tuple]] = {}
    for name in systems:
        out[name] = []
        for g in (SYSTEMS[name]["gaps"] if gaps is None else gaps):
            if not (math.isfinite(float(g)) and float(g) > 0):
                raise ValueError(f"a gap must be a finite number > 0, got {g}")
            try:
                out[name].append((float(g), SYSTEMS[name]["target"](float(g))))
            except ValueError as e:
                raise ValueError(f"{name} cannot take gap {g:g}: {e}") from None
    return out


def run_jobs(a: argparse.Namespace) -> list[tuple[str, str, dict[str, Any] | None]]:
    """``run``'s jobs per target: ``(stored name, method, transfer options)``."""
    methods = METHODS if a.only is None else a.only
    return [(m, m, None) for m in methods] + \
        [(f"transfer+{v}", "transfer", parse_variant(v)) for v in a.variants]


def check_resume(a: argparse.Namespace, targets: dict[str, list[tuple]]) -> None:
    """ValueError, before any run, when ``run`` would resume on stored work of other settings:
    a source asked for another ``--source-evals`` (:func:`check_source`), or a stored run of
    one of its jobs that is damaged or incomplete (:func:`load_run`) or ran at another
    ``--budget`` (it would be kept, and read, beside the runs at this one)."""
    root = Path(a.root)
    for seed in a.seeds:
        for name in a.systems:
            check_source(root / name / f"seed{seed}" / "source", a.source_evals)
            for g, _ in targets[name]:
                for m, _, _ in run_jobs(a):
                    f = root / name / f"gap{g:g}" / f"seed{seed}" / f"{m}.json"
                    stored = int(load_run(f)["budget"]) if f.is_file() else a.budget
                    if stored != a.budget:
                        raise ValueError(f"{f} was run with --budget {stored}, not {a.budget}: "
                                         f"run with --budget {stored} or another --root")


def run(a: argparse.Namespace, targets: dict[str, list[tuple]]) -> None:
    """``run``: every method and variant on each system's ``targets`` (:func:`ladder_targets`),
    per seed on its own source run (made when missing; a stored run is kept: call
    :func:`check_resume` first)."""
    root = Path(a.root)
    for seed in a.seeds:
        for name in a.systems:
            src = source_run(root, name, seed, a.source_evals)
            for g, target in targets[name]:
                for m, base, opts in run_jobs(a):
                    f = root / name / f"gap{g:g}" / f"seed{seed}" / f"{m}.json"
                    if f.is_file():
                        continue
                    t0 = time.perf_counter()
                    res = run_method(base, target, src, a.budget, seed, opts)
                    res.update(system=name, gap=g, seed=seed, method=m, budget=a.budget,
                               wall_s=time.perf_counter() - t0)
                    f.parent.mkdir(parents=True, exist_ok=True)
                    tmp = f.with_suffix(".tmp")     # a killed run leaves no half-written trace
                    tmp.write_text(json.dumps(res))
                    tmp.replace(f)
                    print(f"{name} gap {g:g} seed {seed} {m}: best {min(res['costs']):.4g}, "
                          f"falls {sum(res['failed'])}, {res['wall_s']:.1f} s", flush=True)


def _first_reach(costs: list[float], level: float) -> float:
    for i, c in enumerate(costs, 1):
        if c <= level:
            return float(i)
    return math.inf


def best_within_falls(costs: list[float], failed: list[bool], k: int) -> float:
    """The lowest cost among the trials before the (k+1)-th fall (all of them when there are
    at most k falls): a method's best had it stopped once it fell one time more than k."""
    best, n = math.inf, 0
    for c, f in zip(costs, failed):
        if f:
            n += 1
            if n > k:
                break
        best = min(best, c)
    return best


def cut_at_fall_budget(run: dict[str, Any], share: float, counts: str = "all"
                       ) -> dict[str, Any]:
    """The run the transfer critic with ``fall_budget`` = ``share`` (and
    ``fall_budget_counts`` = ``counts``) asks where ``run`` (its stored run without one, budget
    B) was asked: the same trials until the one after which the budget is spent
    (:func:`~latentune.critic.transfer.fall_budget_spent`), then the best standing θ asked
    again for the rest of B (its cost, no fall: a deterministic target repeats it).
    ``cut_at``: the trials kept (B when the budget is never spent)."""
    from latentune.critic.transfer import fall_budget_spent

    failed = [bool(f) for f in run["failed"]]
    B = len(failed)
    end = next((i + 1 for i in range(B)
                if fall_budget_spent(np.array(failed[:i + 1]), share, B, counts)), B)
    return {**cut_at(run, end), "fall_budget": share, "fall_budget_counts": counts}


def cut_at(run: dict[str, Any], end: int) -> dict[str, Any]:
    """``run`` (a stored run of budget B) stopped after its first ``end`` trials at its best
    standing θ: those trials, then that θ asked again for the rest of B (its cost, no fall: a
    deterministic target repeats it); unchanged when no trial among them stood. ``cut_at``:
    the trials kept (B when none stood). The decision records are dropped."""
    costs, failed = list(run["costs"]), [bool(f) for f in run["failed"]]
    B = len(costs)
    ok = [i for i in range(min(end, B)) if not failed[i]]
    j = min(ok, key=lambda i: costs[i]) if ok else None
    end = min(end, B) if j is not None else B
    out = {**run, "costs": costs[:end] + [costs[j]] * (B - end) if j is not None else costs,
           "failed": failed[:end] + [False] * (B - end) if j is not None else failed,
           "cut_at": end}
    if run.get("thetas") and j is not None:
        out["thetas"] = run["thetas"][:end] + [run["thetas"][j]] * (B - end)
    out.pop("decisions", None)
    return out


def cut_runs(root: Path, method: str, share: float, name: str, seeds: list[int] | None = None,
             counts: str = "all", pattern: str = "*/gap*/seed*") -> int:
    """Store each run ``root/PATTERN/METHOD.json`` (only ``seeds`` when given) as the transfer
    critic with ``fall_budget`` = ``share`` and ``fall_budget_counts`` = ``counts`` would have
    run it (:func:`cut_at_fall_budget`), beside it as method ``name`` with ``derived_from``;
    returns how many. ValueError for a share outside (0, 1) or an unknown ``counts``."""
    from latentune.critic.transfer import FALL_BUDGET_COUNTS

    if not 0.0 < share < 1.0:
        raise ValueError(f"--share must be in (0, 1), got {share}")
    if counts not in FALL_BUDGET_COUNTS:
        raise ValueError(f"--counts must be one of {FALL_BUDGET_COUNTS}, got {counts!r}")
    n = 0
    for f in sorted(root.glob(f"{pattern}/{method}.json")):
        r = load_run(f)
        if seeds is not None and int(r["seed"]) not in seeds:
            continue
        out = {**cut_at_fall_budget(r, share, counts), "method": name, "derived_from": method}
        f.with_name(f"{name}.json").write_text(json.dumps(out))
        n += 1
    if not n:                   # "0 runs ... stored" and exit 0 read as done
        raise ValueError(f"no run of {method} under {root}"
                         + (f" of seeds {' '.join(map(str, seeds))}" if seeds is not None else ""))
    return n


def run_trials(method: str, budget: int) -> int:
    """The trials a complete stored run of ``method`` at ``budget`` holds: one for
    ``zero_shot`` (also ``zero_shot@M``: the source's best θ, tried once), else ``budget``."""
    return 1 if method.split("@")[0] == "zero_shot" else int(budget)


def load_run(f: Path) -> dict[str, Any]:
    """The stored run ``f`` (``…/seed<s>/<method>.json``). ValueError naming the file when it
    is not a run (not JSON, no ``costs`` and ``failed`` of one length) or holds another number
    of trials than a complete run of its ``budget`` (:func:`run_trials`): a damaged or cut-short
    trace, which a median would otherwise read as a finished run."""
    try:
        r = json.loads(f.read_text())
        n, n_failed = len(r["costs"]), len(r["failed"])
        want = run_trials(str(r.get("method", f.stem)), r["budget"]) if "budget" in r else n
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{f} is not a stored run ({type(e).__name__}: {e}); delete it "
                         f"(run makes it again)") from None
    if n != n_failed or n != want:
        raise ValueError(f"{f} holds {n} costs and {n_failed} falls where its budget "
                         f"{r['budget']} makes {want} trials: an incomplete run; delete it "
                         f"(run makes it again)")
    return r


def first_trials(run: dict[str, Any], budget: int, f: Path | str = "") -> dict[str, Any]:
    """``run`` as if it had been run at ``budget``: its first ``budget`` trials (costs, falls
    and θ where stored) and ``budget`` recorded; a zero-shot run (one trial) as it is.
    ValueError naming ``f`` when the run holds fewer trials than that (it was run at a smaller
    budget), since its best would then be read as a best within ``budget``."""
    if run["method"].split("@")[0] == "zero_shot":
        return run
    if int(run["budget"]) < budget:
        raise ValueError(f"{f or run['method']} was run with budget {run['budget']}, fewer "
                         f"than --budget {budget}")
    cut = {k: (v[:budget] if k in ("costs", "failed", "thetas") else v) for k, v in run.items()}
    cut["budget"] = budget
    return cut


def _ladder_target(run: dict[str, Any]) -> dict[str, Any]:
    return {"system": run["system"], "gap": float(run["gap"])}


def fall_allowance(peer_falls: float) -> int:
    """The most falls criterion (3) allows beside a best peer that falls ``peer_falls`` times
    (median over seeds): a quarter of them, rounded down, and 1 where the peer falls ≤ 4 times."""
    return 1 if peer_falls <= 4 else int(math.floor(peer_falls / 4))


def _no_worse(a: list[float], b: list[float]) -> tuple[bool, float]:
    """Criterion (1) for best costs ``a`` against ``b`` (one per seed): ``a``'s median is no
    higher, or a two-sided Mann–Whitney test does not tell them apart (p ≥ 0.05); and p."""
    from scipy.stats import mannwhitneyu

    try:
        pv = float(mannwhitneyu(a, b, alternative="two-sided").pvalue)
    except ValueError:
        pv = 1.0
    return bool(np.median(a) <= np.median(b) or pv >= 0.05), pv


def summarize(root: Path, pattern: str = "*/gap*/seed*/*.json",
              target: Callable[[dict[str, Any]], dict[str, Any]] = _ladder_target,
              default: str = "transfer", methods: list[str] | None = None,
              seeds: list[int] | None = None,
              systems: list[str] | None = None, machine: str | None = None,
              budget: int | None = None, known_methods: bool = False) -> dict[str, Any]:
    """The issue's criteria per target from every stored run under ``root`` (the files matching
    ``pattern``); ``target(run)`` gives a run's target fields, the key and head of its row
    (default: ``system`` and ``gap``). ``machine`` = M: a run stored as ``METHOD@M`` (the same
    method re-run on machine M's sources) reads as ``METHOD``, and the ``METHOD`` run beside it
    is not read; methods with no ``@M`` twin are read as they are. ``default`` names the method
    judged as latentune's default (its rows read as ``transfer``; the stored ``transfer`` runs
    then read as ``transfer@stored``; a ``default`` no run under ``root`` is stored as is
    refused, rather than judging a table without it); ``methods``: only these (names after those renamings)
    are read; ``seeds``: only these seeds; ``systems``: only these systems; ``budget`` = B:
    every run is read as its first B trials (:func:`first_trials`; a run of fewer is refused),
    the criteria at budget B of runs made at a larger one. ``known_methods``: a ``methods`` name
    no run under ``root`` reads as (a typo, read as a method without runs otherwise) is refused,
    naming the stored names close to it (``transfer@stored`` passes: it reads nothing without
    a ``default``, as the committed commands that name it expect).

    A target's medians are over the seeds on which every method read ran: each row lists the
    other seeds (``seeds_left_out``: the seed and the methods without a run on it), and a
    target without such a seed is listed in ``targets_left_out`` (its seeds per method).
    ValueError for a damaged or incomplete run file (:func:`load_run`), for a target whose
    runs have different budgets, and when no target is left to judge."""

    runs: dict[tuple, dict[str, dict[int, dict]]] = {}
    stored: set[str] = set()                    # the methods' names as stored
    read: set[str] = set()                      # ... and as read (after the renamings)
    for f in sorted(root.glob(pattern)):
        r = load_run(f)
        stored.add(r["method"])
        if machine:
            if f.with_name(f"{r['method']}@{machine}.json").is_file():
                continue                        # its twin re-run on that machine is read
            if r["method"].endswith(f"@{machine}"):
                r["method"] = r["method"][:-len(machine) - 1]
        if default != "transfer" and r["method"] in (default, "transfer"):
            r["method"] = "transfer" if r["method"] == default else "transfer@stored"
        read.add(r["method"])
        if methods is not None and r["method"] not in methods:
            continue
        if seeds is not None and int(r["seed"]) not in seeds:
            continue
        if systems is not None and r.get("system") not in systems:
            continue
        if budget is not None:
            r = first_trials(r, budget, f)
        runs.setdefault(tuple(target(r).items()), {}).setdefault(r["method"], {})[
            int(r["seed"])] = r
    if default != "transfer" and stored and not any(
            m == default or (machine and m == f"{default}@{machine}") for m in stored):
        raise ValueError(f"no run of the default method {default} under {root} (--default; "
                         f"the stored methods: {', '.join(sorted(stored))})")
    unknown = [m for m in methods or [] if m not in read and m != "transfer@stored"
               ] if known_methods and read else []      # transfer@stored: none without --default
    if unknown:
        import difflib

        near = difflib.get_close_matches(unknown[0], sorted(read), n=3)
        raise ValueError(f"no run of {unknown[0]} under {root} (--methods"
                         + (f"; did you mean {' or '.join(near)}?)" if near else ")"))
    if not runs:                # an empty table and exit 0 read as "nothing went wrong"
        only = [f"{k} {' '.join(map(str, v))}" for k, v in
                (("methods", methods), ("seeds", seeds), ("systems", systems)) if v is not None]
        raise ValueError(f"no runs under {root}" + (f" of {'; '.join(only)}" if only else ""))
    out: dict[str, Any] = {"targets": [], "targets_left_out": []}
    for key, by_m in sorted(runs.items()):
        budgets = {m: sorted({int(r["budget"]) for r in rs.values() if "budget" in r})
                   for m, rs in by_m.items()
                   if m.split("@")[0] != "zero_shot"}    # one trial, whatever it records
        if len({b for v in budgets.values() for b in v}) > 1:
            raise ValueError(f"the runs of {dict(key)} have different budgets ("
                             + ", ".join(f"{m}: {'/'.join(map(str, v))}"
                                         for m, v in sorted(budgets.items()))
                             + "): their best costs are not comparable")
        seeds = sorted(set.intersection(*[set(v) for v in by_m.values()]))
        ran = {m: sorted(v) for m, v in sorted(by_m.items())}
        if not seeds:               # listed, not dropped without a word
            out["targets_left_out"].append({**dict(key), "seeds_of": ran})
            continue
        row: dict[str, Any] = {**dict(key), "seeds": seeds, "methods": {},
                               "seeds_left_out": [
                                   {"seed": s, "without": [m for m in ran if s not in by_m[m]]}
                                   for s in sorted(set().union(*by_m.values())) if s not in seeds]}
        for m, rs in by_m.items():
            best = [min(rs[s]["costs"]) for s in seeds]
            row["methods"][m] = {"median_best": float(np.median(best)),
                                 "iqr": [float(np.percentile(best, 25)),
                                         float(np.percentile(best, 75))],
                                 "falls_median": float(np.median([sum(rs[s]["failed"])
                                                                  for s in seeds])),
                                 "best": best,
                                 "falls": [int(sum(rs[s]["failed"])) for s in seeds]}
            picks, explores, agree, any_dec = [], [], [], False
            best_ex = 0
            for s in seeds:             # the transfer critic's decision records, one pass
                n_lat = n_ex = 0
                dec = rs[s].get("decisions", [])
                j = int(np.argmin(rs[s]["costs"]))      # decision i asks trial i + 2
                best_ex += int(1 <= j <= len(dec) and bool(dec[j - 1].get("explore")))
                for d in dec:
                    any_dec = True
                    n_lat += sum(p == "latent" for p in d["pools"])
                    n_ex += len(d["pools"]) if d.get("explore") else 0
                    if d.get("agreement") is not None and not d.get("design"):
                        agree.append(d["agreement"])
                picks.append(n_lat)
                explores.append(n_ex)
            if any_dec:
                row["methods"][m]["latent_picks"] = {"median": float(np.median(picks)),
                                                     "max": int(max(picks))}
                if any(explores):       # trials of explore asks (``explore_every``)
                    row["methods"][m]["explore_picks"] = {"median": float(np.median(explores)),
                                                          "max": int(max(explores)),
                                                          "seeds_best_from_explore": best_ex}
                if agree:
                    row["methods"][m]["agreement_iqr"] = [float(np.percentile(agree, 25)),
                                                          float(np.percentile(agree, 75))]
        peers = [m for m in PEERS if m in row["methods"]]
        if not peers:
            raise ValueError(f"no peer among the methods read for {dict(key)} "
                             f"(read: {', '.join(sorted(row['methods']))}; the peers: "
                             f"{', '.join(PEERS)}): the criteria need at least one")
        bp = min(peers, key=lambda m: row["methods"][m]["median_best"])
        level = row["methods"][bp]["median_best"]
        row["best_peer"] = bp
        for m in row["methods"]:
            reach = [_first_reach(by_m[m][s]["costs"], level) for s in seeds]
            row["methods"][m]["trials_to_best_peer"] = float(np.median(reach))
        row["fall_allowance"] = k3 = fall_allowance(row["methods"][bp]["falls_median"])
        row["within_allowance"] = within = []
        for m in row["methods"]:            # each seed stopped at its (k3 + 1)-th fall
            cut = [best_within_falls(by_m[m][s]["costs"], by_m[m][s]["failed"], k3)
                   for s in seeds]
            row["methods"][m]["median_best_within_allowance"] = float(np.median(cut))
            if _no_worse(cut, row["methods"][bp]["best"])[0]:
                within.append(m)
        if "transfer" in row["methods"]:
            k = [int(sum(by_m["transfer"][s]["failed"])) for s in seeds]
            for m in row["methods"]:        # each seed cut at the default's falls on it
                row["methods"][m]["median_best_at_default_falls"] = float(np.median(
                    [best_within_falls(by_m[m][s]["costs"], by_m[m][s]["failed"], ks)
                     for s, ks in zip(seeds, k)]))
            m_cut = min(peers, key=lambda m: row["methods"][m]["median_best_at_default_falls"])
            row["peer_at_default_falls"] = {
                "method": m_cut, "median": row["methods"][m_cut]["median_best_at_default_falls"]}
            t, p = row["methods"]["transfer"], row["methods"][bp]
            no_worse, pv = _no_worse(t["best"], p["best"])
            B = by_m["transfer"][seeds[0]]["budget"]
            row["criteria"] = {
                "no_worse": no_worse,
                "mannwhitney_p": pv,
                "reach_le_B10": t["trials_to_best_peer"] <= B / 10,
                "reach_le_B2": t["trials_to_best_peer"] <= B / 2,
                "falls_ok": t["falls_median"] <= (1 if p["falls_median"] <= 4
                                                  else p["falls_median"] / 4)}
        out["targets"].append(row)
    if not out["targets"]:
        raise ValueError(f"no target under {root} has a seed on which every method read ran: "
                         + "; ".join(f"{dict((k, v) for k, v in t.items() if k != 'seeds_of')} "
                                     f"({_seeds_of(t)})" for t in out["targets_left_out"]))
    return out


def _seeds_of(left_out: dict[str, Any]) -> str:
    """A left-out target's seeds per method as text: ``"gp: seeds 1; transfer: seeds 0"``."""
    return "; ".join(f"{m}: seeds {' '.join(map(str, v))}"
                     for m, v in left_out["seeds_of"].items())


def compare(root: Path, a: str, b: str, seeds: list[int] | None = None,
            pattern: str = "*/gap*/seed*/*.json", systems: list[str] | None = None
            ) -> dict[str, Any]:
    """Method ``a`` against ``b`` on every (target, seed) where both ran (only ``seeds`` when
    given): wins (lower best cost within the budget), ties, losses, a two-sided sign test on the
    non-ties, and the falls; the same counts per target (``by_target``, keyed by the two
    directories above the seed's: ``"<system> gap<g>"``), with the medians over its seeds of
    each method's best cost and their ratio ``median_a / median_b``. A sign test counts wins,
    not by how much: ``ratio_geo_mean`` (the geometric mean of the targets' ratios) and
    ``ratio_worst`` (the largest, and its target) say how much (None where a median is not
    positive). The ratio of two medians is not paired: on few seeds ``a`` can end lower on most
    seeds and still have the higher median, when the two methods' costs interleave across the
    seeds. So each target also has ``paired_ratio``, the geometric mean over its seeds of
    ``best_a / best_b`` on the same seed, and the whole ``paired_geo_mean``, the geometric mean
    of those (both None where a best cost is not positive). ``pattern``: the run files under
    ``root``, ``<target>/<sub>/seed<s>/<method>.json``; ``systems``: only those targets
    (``<target>`` is the system's directory). ValueError for a damaged or incomplete run file
    of ``a`` or ``b`` (:func:`load_run`) and for a pair whose two runs have different
    budgets."""
    from scipy.stats import binomtest, gmean

    runs: dict[tuple[str, str, str], dict[str, dict]] = {}
    for f in sorted(root.glob(pattern)):
        if seeds is not None and f.parts[-2] not in {f"seed{s}" for s in seeds}:
            continue
        if systems is not None and f.parts[-4] not in systems:
            continue
        if f.stem not in (a, b):        # a run file is <method>.json
            continue
        r = load_run(f)
        runs.setdefault(f.parts[-4:-1], {})[r["method"]] = r
    pairs = [(k, v[a], v[b]) for k, v in sorted(runs.items()) if a in v and b in v]
    for k, ra, rb in pairs:
        if "budget" in ra and "budget" in rb and ra["budget"] != rb["budget"]:
            raise ValueError(f"{a} ran at budget {ra['budget']} and {b} at budget "
                             f"{rb['budget']} on {' '.join(k)}: their best costs are not "
                             f"comparable")
    best = [(min(ra["costs"]), min(rb["costs"])) for _, ra, rb in pairs]
    d = [ba - bb for ba, bb in best]
    wins, losses = sum(x < 0 for x in d), sum(x > 0 for x in d)
    by_target: dict[str, dict[str, Any]] = {}
    best_of: dict[str, list[tuple[float, float]]] = {}      # per target: (best a, best b)
    for (k, ra, rb), x, ab in zip(pairs, d, best):
        key = f"{k[0]} {k[1]}"
        t = by_target.setdefault(key, {"wins": 0, "ties": 0, "losses": 0,
                                       "falls_a": 0, "falls_b": 0})
        t["wins" if x < 0 else "losses" if x > 0 else "ties"] += 1
        t["falls_a"] += int(sum(ra["failed"]))
        t["falls_b"] += int(sum(rb["failed"]))
        best_of.setdefault(key, []).append(ab)
    for key, t in by_target.items():
        ab = np.asarray(best_of[key])                   # (seeds, 2) best of a, best of b
        ma, mb = (float(v) for v in np.median(ab, axis=0))
        t.update(median_a=ma, median_b=mb, ratio=ma / mb if ma > 0 and mb > 0 else None,
                 paired_ratio=float(gmean(ab[:, 0] / ab[:, 1])) if (ab > 0).all() else None)
    ratios = {k: t["ratio"] for k, t in by_target.items()}
    known = None not in ratios.values() and bool(ratios)
    worst = max(ratios, key=lambda k: ratios[k]) if known else None
    paired = [t["paired_ratio"] for t in by_target.values()]
    return {"a": a, "b": b, "pairs": len(pairs), "wins": wins, "losses": losses,
            "ratio_geo_mean": float(gmean(list(ratios.values()))) if known else None,
            "ratio_worst": {"target": worst, "ratio": ratios[worst]} if known else None,
            "paired_geo_mean": float(gmean(paired)) if paired and None not in paired else None,
            "ties": len(pairs) - wins - losses,
            "sign_test_p": float(binomtest(wins, wins + losses).pvalue) if wins + losses else 1.0,
            "falls_a": int(sum(sum(ra["failed"]) for _, ra, _ in pairs)),
            "falls_b": int(sum(sum(rb["failed"]) for _, _, rb in pairs)),
            "falls_paired": _falls_paired([(int(sum(ra["failed"])), int(sum(rb["failed"])))
                                           for _, ra, rb in pairs]),
            "by_target": by_target}


def bar_check(row: dict[str, Any], paired_max: float | None = None,
              falls_max: float | None = None,
              target: tuple[float, float] | None = None) -> dict[str, Any]:
    """A bar written before a screen's runs, applied to one :func:`compare` row (``a``, the
    candidate, against ``b``): ``paired_max``, the largest ``paired_geo_mean`` allowed;
    ``falls_max``, the largest ratio of total falls ``falls_a / falls_b`` (falls_b 0: none
    allowed); ``target`` = (ratio, share), no target whose median ratio is above ``ratio``
    while ``a`` loses on at least ``share`` of its seeds (⌈share·pairs⌉). Each given criterion's
    value, limit and verdict, the failing targets, and ``pass`` (all given ones hold)."""
    out: dict[str, Any] = {}
    if paired_max is not None:
        v = row["paired_geo_mean"]
        out["paired_geo_mean"] = {"value": v, "limit": paired_max,
                                  "pass": v is not None and v <= paired_max}
    if falls_max is not None:
        fa, fb = row["falls_a"], row["falls_b"]
        out["falls"] = {"value": [fa, fb], "limit": falls_max,
                        "pass": fa <= falls_max * fb}
    if target is not None:
        ratio, share = target
        bad = [k for k, t in row["by_target"].items()
               if t["ratio"] is not None and t["ratio"] > ratio
               and t["losses"] >= int(np.ceil(share * (t["wins"] + t["ties"] + t["losses"])
                                              - 1e-9))]
        out["targets"] = {"failing": bad, "limit": [ratio, share], "pass": not bad}
    out["pass"] = all(c["pass"] for c in out.values())
    return out


def _falls_paired(falls: list[tuple[int, int]]) -> dict[str, Any]:
    """Per (target, seed) pair of fall counts ``(a, b)``: on how many ``a`` fell more, fewer
    and as often, and a two-sided sign test on the pairs that differ (p 1.0 without any)."""
    from scipy.stats import binomtest

    more = sum(fa > fb for fa, fb in falls)
    fewer = sum(fa < fb for fa, fb in falls)
    return {"more": more, "fewer": fewer, "same": len(falls) - more - fewer,
            "sign_test_p": float(binomtest(more, more + fewer).pvalue) if more + fewer else 1.0}


def markdown(s: dict[str, Any],
             title: Callable[[dict[str, Any]], str] = lambda row: f"{row['system']} gap "
                                                              f"{row['gap']:g}") -> str:
    """``summarize``'s rows as Markdown tables, each headed by ``title(row)``."""
    lines = []
    for row in s["targets"]:
        lines.append(f"\n### {title(row)} ({len(row['seeds'])} seeds; "
                     f"best peer: {row['best_peer']})\n")
        for x in row.get("seeds_left_out", []):
            lines.append(f"seed {x['seed']} left out: no run of {', '.join(x['without'])}\n")
        cut = "transfer" in row["methods"]
        lines.append("| method | median best | IQR | trials to best peer's median | falls |"
                     + (" best at the default's falls |" if cut else ""))
        lines.append("|---|---:|---:|---:|---:|" + ("---:|" if cut else ""))
        for m in list(METHODS) + sorted(set(row["methods"]) - set(METHODS)):
            if m not in row["methods"]:
                continue
            r = row["methods"][m]
            lines.append(f"| {m} | {r['median_best']:.4g} | {r['iqr'][0]:.4g}–{r['iqr'][1]:.4g} "
                         f"| {r['trials_to_best_peer']:g} | {r['falls_median']:g} |"
                         + (f" {r['median_best_at_default_falls']:.4g} |" if cut else ""))
        if "within_allowance" in row:
            k3 = row["fall_allowance"]
            low = min(row["methods"], key=lambda m: row["methods"][m][
                "median_best_within_allowance"])
            lines.append(f"\nstopped at criterion (3)'s allowance ({k3} fall"
                         f"{'' if k3 == 1 else 's'}): lowest {low} "
                         f"{row['methods'][low]['median_best_within_allowance']:.4g}; no worse "
                         f"than the best peer's {row['methods'][row['best_peer']]['median_best']:.4g}"
                         f": {', '.join(row['within_allowance']) or 'none'}")
        if "criteria" in row:
            c = row["criteria"]
            lines.append(f"\ncriteria: no worse {c['no_worse']} (p {c['mannwhitney_p']:.3f}), "
                         f"≤ B/10 {c['reach_le_B10']}, ≤ B/2 {c['reach_le_B2']}, "
                         f"falls {c['falls_ok']}")
    for t in s.get("targets_left_out", []):
        lines.append(f"\n### {title(t)}: left out, no seed on which every method ran "
                     f"({_seeds_of(t)})")
    return "\n".join(lines)


def prefix_check(root: Path, stored: Path, budget: int) -> list[dict[str, Any]]:
    """Every run under ``root`` (``<system>/gap<g>/seed<s>/<method>.json``) whose twin at the
    same path under ``stored`` holds ``budget`` trials (a zero-shot run: its one trial), with
    ``same``: its first ``budget`` trials have the twin's costs and falls, trial for trial (a
    run made at a larger budget on the same source and seed continues the stored one rather
    than changing its choices). Runs without a twin are left out. ValueError for a damaged run
    (:func:`load_run`), a twin of another budget, or no pair at all."""
    rows: list[dict[str, Any]] = []
    for f in sorted(root.glob("*/gap*/seed*/*.json")):
        g = stored / f.relative_to(root)
        if not g.is_file():
            continue
        r, t = load_run(f), load_run(g)
        n = len(t["costs"])
        if t["method"].split("@")[0] != "zero_shot" and int(t["budget"]) != budget:
            raise ValueError(f"{g} was run with budget {t['budget']}, not --budget {budget}")
        same = r["costs"][:n] == t["costs"] and r["failed"][:n] == t["failed"]
        rows.append({"run": str(f.relative_to(root)), "same": bool(same),
                     "trials": n, "of": len(r["costs"])})
    if not rows:
        raise ValueError(f"no run under {root} has a twin under {stored}")
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    from benchmarks.common import bench_parser, out_file
    ap = bench_parser("benchmarks.transfer", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    r.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    r.add_argument("--budget", type=int, default=40)
    r.add_argument("--source-evals", type=int, default=SOURCE_EVALS)
    r.add_argument("--root", default="runs/transfer")
    r.add_argument("--only", nargs="*", choices=METHODS + SCREENED, default=None)
    r.add_argument("--variants", nargs="+", default=[],
                   help="transfer variants option=value[:option=value], stored as transfer+VARIANT")
    r.add_argument("--gaps", nargs="+", type=float, default=None,
                   help="these gaps on every system instead of its ladder's (held-out gaps)")
    s = sub.add_parser("summary")
    s.add_argument("--root", default="runs/transfer")
    s.add_argument("--out", type=out_file, default=None,
                   help="write the summary to this JSON and its tables to the .md beside it "
                        "(default: print only)")
    s.add_argument("--default", default="transfer",
                   help="the method judged as the default (e.g. a transfer+VARIANT)")
    s.add_argument("--methods", nargs="+", default=None,
                   help="read only these methods (after --default renames)")
    s.add_argument("--systems", nargs="+", default=None, choices=list(SYSTEMS),
                   help="read only these systems' targets")
    s.add_argument("--machine", default=None, metavar="M",
                   help="read METHOD@M runs (re-run on machine M's sources) as METHOD, in place "
                        "of the METHOD runs beside them")
    s.add_argument("--budget", type=int, default=None, metavar="B",
                   help="read every run as its first B trials (runs made at a larger budget)")
    px = sub.add_parser("prefix", help="runs made at a larger budget against the stored runs "
                        "of --budget: are their first trials the same?")
    px.add_argument("--root", required=True, help="the runs made at the larger budget")
    px.add_argument("--stored", required=True, help="the runs made at --budget")
    px.add_argument("--budget", type=int, required=True)
    px.add_argument("--out", type=out_file, default=None)
    c = sub.add_parser("compare", help="methods against methods over (target, seed)")
    c.add_argument("--root", default="runs/transfer")
    c.add_argument("--a", nargs="+", required=True)
    c.add_argument("--b", nargs="+", required=True)
    c.add_argument("--seeds", nargs="+", type=int, default=None)
    c.add_argument("--systems", nargs="+", default=None, choices=list(SYSTEMS),
                   help="only these systems' targets (default: every one stored)")
    c.add_argument("--out", type=out_file, default=None)
    c.add_argument("--bar-paired", type=float, default=None, metavar="R",
                   help="a bar: the largest paired geometric-mean ratio (a / b) allowed")
    c.add_argument("--bar-falls", type=float, default=None, metavar="R",
                   help="a bar: the largest ratio of total falls (a / b) allowed")
    c.add_argument("--bar-target", type=float, nargs=2, default=None,
                   metavar=("RATIO", "SHARE"),
                   help="a bar: no target whose median ratio is above RATIO while a loses on "
                        "at least SHARE of its seeds")
    ct = sub.add_parser("cut", help="a method's runs as the transfer critic with fall_budget "
                        "= SHARE would have run them (cut_at_fall_budget), stored as --as")
    ct.add_argument("--root", default="runs/transfer")
    ct.add_argument("--method", required=True)
    ct.add_argument("--share", type=float, required=True)
    ct.add_argument("--counts", default="all", help="fall_budget_counts: all or after_stand")
    ct.add_argument("--as", dest="name", required=True, help="the method name to store them as")
    ct.add_argument("--seeds", nargs="+", type=int, default=None)
    k = sub.add_parser("check-default",
                       help="re-run a method's stored runs with the critic's own defaults")
    k.add_argument("--root", default="runs/transfer", help="the sources (made when missing)")
    k.add_argument("--stored", required=True,
                   help="the stored runs (e.g. results/transfer/rebuilt/runs)")
    k.add_argument("--method", required=True, help="the stored name of today's default")
    k.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    k.add_argument("--seeds", nargs="+", type=int, default=[0])
    a = ap.parse_args(argv)
    from benchmarks.common import Provenance, write_json

    if a.cmd == "check-default":
        try:
            rows = check_default(Path(a.root), Path(a.stored), a.method, a.systems, a.seeds)
        except ValueError as e:
            error_line("benchmarks.transfer check-default", e)
            return 2
        n_diff = sum(not r["same"] for r in rows)
        print(f"{len(rows) - n_diff} of {len(rows)} runs the same")
        return 1 if n_diff else 0

    if a.cmd == "prefix":
        prov = Provenance(argv, module="benchmarks.transfer")
        try:
            if a.budget < 1:
                raise ValueError(f"--budget must be >= 1, got {a.budget}")
            rows = prefix_check(Path(a.root), Path(a.stored), a.budget)
        except ValueError as e:
            error_line("benchmarks.transfer prefix", e)
            return 2
        for r in rows:
            if not r["same"]:
                print(f"differs: {r['run']}")
        n_same = sum(r["same"] for r in rows)
        print(f"{n_same} of {len(rows)} runs' first trials equal the stored runs'")
        if a.out:
            write_json(a.out, {"rows": rows}, prov)
        return 0 if n_same == len(rows) else 1
    if a.cmd == "cut":
        try:
            n = cut_runs(Path(a.root), a.method, a.share, a.name, a.seeds, a.counts)
        except ValueError as e:
            error_line("benchmarks.transfer cut", e)
            return 2
        print(f"{n} runs of {a.method} cut at fall_budget {a.share:g} ({a.counts}), stored as "
              f"{a.name}")
        return 0
    if a.cmd == "compare":
        prov = Provenance(argv, module="benchmarks.transfer")
        try:
            rows = [compare(Path(a.root), x, b, a.seeds, systems=a.systems)
                    for x in a.a for b in a.b]
        except ValueError as e:
            error_line("benchmarks.transfer compare", e)
            return 2
        if not any(r["pairs"] for r in rows):
            import difflib

            stored = sorted({f.stem for f in Path(a.root).glob("*/gap*/seed*/*.json")})
            unknown = [m for m in dict.fromkeys([*a.a, *a.b]) if m not in stored]
            if unknown:         # a typo, or a method never run here
                near = difflib.get_close_matches(unknown[0], stored, n=3)
                error_line("benchmarks.transfer compare", f"no run of {unknown[0]} under {a.root}"
                           + (f" (did you mean {' or '.join(near)}?)" if near else ""))
                return 2
            error_line("benchmarks.transfer compare", f"no (target, seed) under {a.root} holds "
                       "both methods of any pair")
            return 2
        if (a.bar_paired, a.bar_falls, a.bar_target) != (None, None, None):
            if a.bar_target is not None and not 0 < a.bar_target[1] <= 1:
                error_line("benchmarks.transfer compare", "--bar-target's SHARE must be in "
                           f"(0, 1], got {a.bar_target[1]:g}")
                return 2
            for r in rows:
                r["bar"] = bar_check(r, a.bar_paired, a.bar_falls,
                                     None if a.bar_target is None else tuple(a.bar_target))
        print(compare_text(rows))
        if a.out:
            write_json(a.out, {"rows": rows}, prov)
        return 0
    if a.cmd == "run":
        try:            # a bad variant or a gap a system cannot take: refused before any run
            for flag, v in (("--budget", a.budget), ("--source-evals", a.source_evals)):
                if v < 1:
                    raise ValueError(f"{flag} must be >= 1, got {v}")
            small = [m for m, base, _ in run_jobs(a) if base in BESIDE]
            if small and a.budget < 2:          # they would run 2 trials, stored as budget 1
                raise ValueError(f"--budget {a.budget} is too small for {', '.join(small)} "
                                 "(its first two trials are the manual θ and the zero-shot "
                                 "θ): give --budget >= 2, or --only without them")
            for v in a.variants:
                check_variant(v)
            targets = ladder_targets(a.systems, a.gaps)
            check_resume(a, targets)
        except ValueError as e:
            error_line("benchmarks.transfer run", e)
            return 2
        run(a, targets)
        return 0
    prov = Provenance(argv, module="benchmarks.transfer")
    try:
        if a.budget is not None and a.budget < 1:
            raise ValueError(f"--budget must be >= 1, got {a.budget}")
        res = summarize(Path(a.root), default=a.default, methods=a.methods, systems=a.systems,
                        machine=a.machine, budget=a.budget, known_methods=True)
    except ValueError as e:
        error_line("benchmarks.transfer summary", e)
        return 2
    p = prov.finish()
    md = markdown(res)
    if a.out:
        out = write_json(a.out, res, p)
        out.with_suffix(".md").write_text(f"`{p['command']}`\n{md}\n")
    print(md)
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.transfer"))
