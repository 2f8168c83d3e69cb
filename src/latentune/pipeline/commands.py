"""``latentune tune | phase1 | train-vae | phase3 | report``: the three-phase pipeline as commands.

``tune`` runs phase 1 (TuRBO-m on θ from the manual θ), phase 2 (the VAE on the stable phase-1 θ)
and phase 3 (TuRBO-m on the latent box through the decoder), then writes ``DIR/summary.json``,
``DIR/phase1_best.json``, ``DIR/phase3_best.json`` (``--params`` files) and prints the comparison
table. The phase commands do one step each on the same ``--out DIR``. Everything a report needs
is in ``DIR/run.db`` (:mod:`latentune.pipeline.store`).

Default budget: 400 phase-1 + 220 phase-3 evaluations, 2 process workers, batch 4. The README's
main job (A1 trot) simulates ~570 full 5-s rollouts (falls stop early) plus ~100 s of critic
work: about 9–10 minutes on 2 free cores (1.3–1.8 s per rollout); measured 35 minutes on 2 cores
shared with other jobs (load average 4–8). ``--phase1-evals 10000`` is the paper's scale.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

DEFAULT_PHASE1 = 400
DEFAULT_PHASE3 = 220
DEFAULT_WORKERS = 2


def _cli():
    """The running ``latentune.cli`` module (``python -m latentune.cli`` runs it as __main__,
    and its ``main`` only catches its own ``CLIError`` class)."""
    m = sys.modules.get("__main__")
    spec = getattr(m, "__spec__", None)
    if spec is not None and spec.name == "latentune.cli":
        return m
    from latentune import cli

    return cli


def _err(msg: str):
    return _cli().CLIError(msg)


# ---------------------------------------------------------------------------- arguments
def _add_run_args(p: argparse.ArgumentParser, name: str) -> None:
    from latentune.latent.vae import DEFAULT_KIND, KINDS

    _cli().add_task_args(p)
    p.add_argument("--out", required=True, help="run directory (holds run.db and artifacts)")
    p.add_argument("--phase1-evals", type=int, default=DEFAULT_PHASE1,
                   help=f"phase-1 evaluations (default {DEFAULT_PHASE1}; the paper: 10000)")
    p.add_argument("--phase3-evals", type=int, default=DEFAULT_PHASE3,
                   help=f"phase-3 evaluations (default {DEFAULT_PHASE3})")
    p.add_argument("--latent-dim", type=int, default=None,
                   help="VAE latent size d_low (default 10 for 25-dim θ, 5 for 77-dim)")
    p.add_argument("--vae-kind", choices=KINDS, default=DEFAULT_KIND,
                   help=f"autoencoder kind (default {DEFAULT_KIND}; see latentune.latent.vae)")
    p.add_argument("--vae-epochs", type=int, default=None,
                   help="VAE training epochs (default: ~2000 Adam steps, at least 100 epochs)")
    p.add_argument("--workers", type=int, default=DEFAULT_WORKERS, help="parallel rollouts")
    p.add_argument("--backend", choices=("serial", "process", "ray"), default="process",
                   help="evaluator: serial, local process pool (default) or ray")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: local Ray)")
    p.add_argument("--method", choices=("turbo", "cma", "random", "sobol"), default="turbo",
                   help="critic (default turbo = TuRBO-m)")
    p.add_argument("--regions", type=int, default=None,
                   help="TuRBO-m trust regions (default: ~1 per 500 evaluations, between 1 and 10)")
    p.add_argument("--batch-size", type=int, default=None,
                   help="critic batch size (default max(workers, 4))")
    p.add_argument("--resume", action="store_true", help="continue the run stored in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar or log lines")
    if name == "phase3":
        p.add_argument("--vae", default=None, metavar="RUN_DIR",
                       help="use the latent space of another run (same actor and θ dimension)")


def add_commands(subparsers: Any) -> None:
    """Register ``tune``, ``phase1``, ``train-vae``, ``phase3`` and ``report``."""
    for name, func, hlp in (
            ("tune", cmd_tune, "phases 1-3: tune θ, learn a latent space, tune in it"),
            ("phase1", cmd_phase1, "phase 1: TuRBO-m on the full θ"),
            ("train-vae", cmd_train_vae, "phase 2: train the VAE on the stable phase-1 θ"),
            ("phase3", cmd_phase3, "phase 3: TuRBO-m in the latent space")):
        p = subparsers.add_parser(name, help=hlp)
        _add_run_args(p, name)
        p.set_defaults(func=func, command_name=name)
    p = subparsers.add_parser("report", help="tables, plots and report.md of a run directory")
    p.add_argument("dir", help="run directory")
    p.add_argument("--no-sim", action="store_true", help="skip the re-simulated CoM plots")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_report)


# ---------------------------------------------------------------------------- helpers
class _Run:
    """Validated arguments, the task, the store and the config of one command."""

    def __init__(self, args: argparse.Namespace, need_store: bool) -> None:
        from latentune.pipeline.phases import default_batch_size
        from latentune.pipeline.store import RunStore, StoreError

        self.args = args
        self.t0 = time.perf_counter()
        for flag in ("phase1_evals", "phase3_evals", "workers"):
            v = getattr(args, flag)
            if v < 1:
                raise _err(f"--{flag.replace('_', '-')} must be >= 1, got {v}")
        if args.vae_epochs is not None and args.vae_epochs < 1:
            raise _err(f"--vae-epochs must be >= 1, got {args.vae_epochs}")
        if args.latent_dim is not None and args.latent_dim < 1:
            raise _err(f"--latent-dim must be >= 1, got {args.latent_dim}")
        if args.regions is not None and not 1 <= args.regions <= 100:
            raise _err(f"--regions must be in [1, 100], got {args.regions}")
        if args.batch_size is not None and args.batch_size < 1:
            raise _err(f"--batch-size must be >= 1, got {args.batch_size}")
        if args.seed < 0:
            raise _err(f"--seed must be >= 0, got {args.seed}")
        if args.ray_address and args.backend != "ray":
            raise _err("--ray-address needs --backend ray")
        self.task = _cli().make_task(args)
        self.out = Path(args.out)
        self.batch_size = args.batch_size or default_batch_size(args.workers)
        if self.out.exists() and not self.out.is_dir():
            raise _err(f"--out {self.out} exists and is not a directory")
        db = self.out / "run.db"
        if need_store and not db.is_file():
            if not self.out.exists():
                raise _err(f"run directory {self.out} does not exist")
            raise _err(f"no run store in {self.out} (run phase1 or tune first)")
        if args.resume and not db.is_file():
            raise _err(f"--resume: no run store in {self.out}")
        self.store = None
        if db.is_file():
            try:
                self.store = RunStore(self.out)
            except StoreError as exc:
                raise _err(str(exc)) from None
            self._check_config()

    # the configuration a run is bound to (a resume must match it)
    def task_config(self) -> dict[str, Any]:
        return self.task.config()

    def _check_config(self) -> None:
        stored = self.store.get_meta("config") or {}
        st = stored.get("task")
        if st is not None and st != self.task_config():
            diff = [f"{k}: stored {st.get(k)!r}, given {v!r}" for k, v in self.task_config().items()
                    if st.get(k) != v]
            raise _err(f"{self.out} holds a run of another configuration ({'; '.join(diff)})")
        for ph in ("phase1", "phase3"):
            sc = stored.get(ph)
            if sc and self.store.count(1 if ph == "phase1" else 3) > 0:
                mine = self.phase_config(ph, sc)
                for k in ("method", "batch_size", "seed", "regions"):
                    if sc.get(k) != mine.get(k):
                        raise _err(f"{self.out}: {ph} was run with {k.replace('_', '-')} = "
                                   f"{sc.get(k)!r}, not {mine.get(k)!r}")

    def phase_config(self, ph: str, stored: dict[str, Any] | None = None) -> dict[str, Any]:
        from latentune.critic.turbo import regions_for_budget

        a = self.args
        budget = a.phase1_evals if ph == "phase1" else a.phase3_evals
        regions = a.regions
        if regions is None:
            # a resumed phase keeps the stored region count even if its budget was extended
            regions = (stored or {}).get("regions") if a.regions is None and stored else None
            if regions is None:
                regions = regions_for_budget(budget) if a.method == "turbo" else None
        return {"method": a.method, "batch_size": self.batch_size, "seed": a.seed,
                "regions": regions if a.method == "turbo" else None, "budget": budget}

    def open_store(self):
        from latentune.pipeline.store import RunStore, StoreError

        if self.store is None:
            try:
                self.store = RunStore(self.out, create=True)
            except (StoreError, OSError) as exc:
                raise _err(str(exc)) from None
            self.store.set_meta("config", {"task": self.task_config()})
        return self.store

    def update_config(self, **kw: Any) -> None:
        cfg = self.store.get_meta("config") or {}
        cfg.setdefault("task", self.task_config())
        cfg.update(kw)
        self.store.set_meta("config", cfg)

    def add_wall(self, key: str, seconds: float) -> None:
        w = self.store.get_meta("wall", {}) or {}
        w[key] = float(w.get(key, 0.0)) + float(seconds)
        self.store.set_meta("wall", w)

    def evaluator(self):
        from latentune.pipeline.evaluators import make_evaluator

        try:
            return make_evaluator(self.args.backend, self.args.workers, self.args.ray_address)
        except (RuntimeError, ValueError, OSError) as exc:
            raise _err(f"cannot start the {self.args.backend} evaluator: {exc}") from None

    def log(self, msg: str) -> None:
        if not self.args.quiet:
            print(msg, file=sys.stderr, flush=True)


def _phase1(run: _Run, ev) -> Any:
    from latentune.pipeline.phases import PHASE1, ensure_manual, make_phase_critic, run_phase

    st = run.open_store()
    stored = (st.get_meta("config") or {}).get("phase1")
    pc = run.phase_config("phase1", stored)
    run.update_config(phase1=pc)
    manual = ensure_manual(st, run.task, seed=run.args.seed)
    run.log(f"manual θ: cost {manual:.3f}")
    critic = make_phase_critic(pc["method"], run.task.space.dim, pc["batch_size"], pc["seed"],
                               run.task.space.manual, pc["budget"], pc["regions"])
    t = time.perf_counter()
    try:
        res = run_phase(st, PHASE1, run.task, critic, pc["budget"], ev, seed=run.args.seed,
                        progress=not run.args.quiet)
    finally:
        run.add_wall("phase1", time.perf_counter() - t)
    _write_best(run, 1)
    run.log(f"phase 1: {res.n} evaluations, best cost {res.best_cost:.3f}")
    return res


def _train_vae(run: _Run, force: bool = True) -> Any:
    from latentune.latent.vae import LatentError, LatentSpace
    from latentune.pipeline.phases import PHASE1, PHASE3, training_set

    st = run.store
    prefix = run.out / "vae"
    if st.artifact("vae") is not None and (not force or st.count(PHASE3) > 0):
        if st.count(PHASE3) > 0 and force:
            raise _err(f"{run.out}: phase 3 already used the VAE; retraining it would invalidate "
                       "the stored phase-3 rows (use another --out)")
        return LatentSpace.load(st.artifact("vae"))
    X = training_set(st, PHASE1)
    if len(X) < 2:
        raise _err(f"{run.out}: phase 1 has {len(X)} stable θ (cost < 100); "
                   "the VAE needs at least 2 (run more phase-1 evaluations)")
    t = time.perf_counter()
    tc = run.task_config()
    meta = {"robot": tc["robot"], "gait": tc["gait"], "actor": tc["actor"],
            "terrain": tc["terrain"], "source_run": str(run.out.resolve()),
            "n_phase1": st.count(PHASE1)}
    try:
        latent = LatentSpace.train(X, d_low=run.args.latent_dim, kind=run.args.vae_kind,
                                   seed=run.args.seed, epochs=run.args.vae_epochs, meta=meta)
    except LatentError as exc:
        raise _err(str(exc)) from None
    latent.save(prefix)
    run.add_wall("vae", time.perf_counter() - t)
    st.add_artifact("vae", prefix)
    run.update_config(vae={"kind": latent.kind, "d_low": latent.d_low, "n_train": len(X),
                           "seed": run.args.seed, "beta": latent.meta.get("beta"),
                           "box": latent.box.tolist(), "box_rule": latent.meta.get("box_rule")})
    run.log(f"VAE ({latent.kind}, d_low {latent.d_low}) trained on {len(X)} stable θ in "
            f"{latent.meta.get('train_wall_s', 0):.1f} s; final reconstruction error "
            f"{latent.meta.get('final_rec', float('nan')):.4f}")
    return latent


def _latent_for_phase3(run: _Run, vae_dir: str | None):
    """The latent space phase 3 uses: DIR's own, or another run's copied into DIR."""
    from latentune.latent.vae import LatentError, LatentSpace
    from latentune.pipeline.store import RunStore, StoreError

    st = run.store
    if vae_dir is None:
        src = st.artifact("phase3_vae") or st.artifact("vae")
        if src is None:
            raise _err(f"no VAE in {run.out}: run train-vae first or pass --vae RUN_DIR")
        source = "self" if st.artifact("phase3_vae") is None else \
            (st.get_meta("config") or {}).get("phase3_vae_source", "self")
    else:
        vd = Path(vae_dir)
        if not vd.is_dir():
            raise _err(f"--vae: run directory {vd} does not exist")
        src = None
        if (vd / "run.db").is_file():
            try:
                with RunStore(vd) as other:
                    src = other.artifact("vae")
            except StoreError as exc:
                raise _err(f"--vae: {exc}") from None
        if src is None:
            src = vd / "vae"
        source = str(vd.resolve())
    try:
        latent = LatentSpace.load(src)
    except LatentError as exc:
        raise _err(str(exc)) from None
    d = run.task.space.dim
    if latent.d != d:
        raise _err(f"the VAE in {src} maps to {latent.d}-dim θ, but {run.task.robot_name} "
                   f"{run.task.gait} ({run.task.actor}) has {d}-dim θ")
    cfg = st.get_meta("config") or {}
    prev = cfg.get("phase3_vae_source")
    if prev is not None and prev != source and st.count(3) > 0:
        raise _err(f"{run.out}: phase 3 was run with the VAE of {prev}, not {source}")
    if prev is None or st.count(3) == 0:
        if source != "self":
            dst = run.out / "phase3_vae"
            shutil.copyfile(Path(src).with_suffix(".pt"), dst.with_suffix(".pt"))
            shutil.copyfile(Path(src).with_suffix(".json"), dst.with_suffix(".json"))
            st.add_artifact("phase3_vae", dst)
        run.update_config(phase3_vae_source=source,
                          latent={"kind": latent.kind, "d": latent.d, "d_low": latent.d_low,
                                  "box": latent.box.tolist(),
                                  "box_rule": latent.meta.get("box_rule"),
                                  "n_train": latent.meta.get("n_train"),
                                  "from": {k: latent.meta.get(k) for k in
                                           ("robot", "gait", "actor", "terrain")}})
    return latent


def _phase3(run: _Run, ev, latent) -> Any:
    from latentune.pipeline.phases import PHASE3, ensure_manual, make_phase_critic, run_phase

    st = run.store
    stored = (st.get_meta("config") or {}).get("phase3")
    pc = run.phase_config("phase3", stored)
    run.update_config(phase3=pc)
    manual = ensure_manual(st, run.task, seed=run.args.seed)
    run.log(f"manual θ: cost {manual:.3f}")
    # the first trust region starts from the manual θ's code (as phase 1 starts from it)
    x0 = latent.to_unit(latent.encode(run.task.space.manual))
    critic = make_phase_critic(pc["method"], latent.d_low, pc["batch_size"], pc["seed"], x0,
                               pc["budget"], pc["regions"])
    t = time.perf_counter()
    try:
        res = run_phase(st, PHASE3, run.task, critic, pc["budget"], ev, decoder=latent.decode,
                        seed=run.args.seed, progress=not run.args.quiet)
    finally:
        run.add_wall("phase3", time.perf_counter() - t)
    _write_best(run, 3)
    run.log(f"phase 3: {res.n} evaluations, best cost {res.best_cost:.3f}")
    return res


def _worker_failure(exc: BaseException) -> bool:
    from concurrent.futures.process import BrokenProcessPool

    return isinstance(exc, BrokenProcessPool) or type(exc).__module__.startswith("ray.")


def _guarded(fn, *a: Any) -> Any:
    """Run a phase; a dead worker pool becomes one error line (the stored rows are kept)."""
    try:
        return fn(*a)
    except Exception as exc:  # noqa: BLE001
        if _worker_failure(exc):
            raise _err(f"an evaluation worker died ({type(exc).__name__}: {exc}); the finished "
                       "evaluations are stored: rerun with --resume") from None
        raise


def _write_best(run: _Run, phase: int) -> None:
    b = run.store.best(phase)
    if b is None:
        return
    path = run.out / f"phase{phase}_best.json"
    path.write_text(json.dumps(run.task.space.as_dict(b.theta), indent=1))
    run.store.add_artifact(f"phase{phase}_best", path)


def _refuse_rerun(run: _Run, phase: int) -> None:
    if run.store is not None and run.store.count(phase) > 0 and not run.args.resume:
        raise _err(f"{run.out} already holds {run.store.count(phase)} phase-{phase} evaluations; "
                   "pass --resume to continue the run or choose another --out")


def _finish(run: _Run) -> dict[str, Any]:
    from latentune.report import comparison_table, write_summary

    summary = write_summary(run.store, wall_this=time.perf_counter() - run.t0)
    print(comparison_table(run.store))
    return summary


# ---------------------------------------------------------------------------- commands
def cmd_tune(args: argparse.Namespace) -> int:
    run = _Run(args, need_store=False)
    _refuse_rerun(run, 1)
    run.open_store()
    ev = run.evaluator()
    try:
        _guarded(_phase1, run, ev)
        _train_vae(run, force=False)        # an existing VAE is kept (resume)
        latent = _latent_for_phase3(run, None)
        _guarded(_phase3, run, ev, latent)
    finally:
        ev.close()
    _finish(run)
    return 0


def cmd_phase1(args: argparse.Namespace) -> int:
    run = _Run(args, need_store=False)
    _refuse_rerun(run, 1)
    run.open_store()
    ev = run.evaluator()
    try:
        _guarded(_phase1, run, ev)
    finally:
        ev.close()
    return 0


def cmd_train_vae(args: argparse.Namespace) -> int:
    run = _Run(args, need_store=True)
    if run.store.artifact("vae") is not None and args.resume:
        run.log(f"{run.out}: VAE already trained (kept, --resume)")
        return 0
    _train_vae(run, force=True)
    return 0


def cmd_phase3(args: argparse.Namespace) -> int:
    run = _Run(args, need_store=args.vae is None)
    _refuse_rerun(run, 3)
    if args.vae is not None:
        # validate the other run's VAE before creating anything here
        _precheck_vae(run, args.vae)
    run.open_store()
    latent = _latent_for_phase3(run, args.vae)
    ev = run.evaluator()
    try:
        _guarded(_phase3, run, ev, latent)
    finally:
        ev.close()
    _finish(run)
    return 0


def _precheck_vae(run: _Run, vae_dir: str) -> None:
    from latentune.latent.vae import LatentError, LatentSpace
    from latentune.pipeline.store import RunStore, StoreError

    vd = Path(vae_dir)
    if not vd.is_dir():
        raise _err(f"--vae: run directory {vd} does not exist")
    src = vd / "vae"
    if (vd / "run.db").is_file():
        try:
            with RunStore(vd) as other:
                src = other.artifact("vae") or src
        except StoreError as exc:
            raise _err(f"--vae: {exc}") from None
    try:
        latent = LatentSpace.load(src)
    except LatentError as exc:
        raise _err(f"--vae: {exc}") from None
    if latent.d != run.task.space.dim:
        raise _err(f"the VAE of {vd} maps to {latent.d}-dim θ, but {run.task.robot_name} "
                   f"{run.task.gait} ({run.task.actor}) has {run.task.space.dim}-dim θ")
    actor = latent.meta.get("actor")
    if actor is not None and actor != run.task.actor:
        raise _err(f"the VAE of {vd} was trained on θ of the {actor} actor, not {run.task.actor}: "
                   "normalized θ of different actors do not mean the same thing")


def cmd_report(args: argparse.Namespace) -> int:
    from latentune.pipeline.store import RunStore, StoreError
    from latentune.report import make_report

    try:
        store = RunStore(args.dir)
    except StoreError as exc:
        raise _err(str(exc)) from None
    with store:
        text = make_report(store, simulate=not args.no_sim, quiet=args.quiet)
    print(text)
    return 0
