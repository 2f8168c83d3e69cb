"""Study: the public pipeline of latentune on a run directory (the paper's Algorithm 1).

``Study(DIR)`` opens (or creates) ``DIR/run.db``, the single source of truth of a run. On it:

* :meth:`Study.phase1` — the critic (TuRBO-m by default) tunes the full θ of a System
  (``AC_GEN(f, Id)``), starting from the system's manual θ;
* :meth:`Study.train_latent` — phase 2: a VAE on the θ of phase 1 whose trial did not fail;
* :meth:`Study.phase3` — the critic tunes in the latent box through the decoder
  (``AC_GEN(f, D)``), on the same or another system, with this study's latent space or another
  study's; when the latent space (or the system) comes from elsewhere, the source's best θ is
  first evaluated as it is on the target (the zero-shot baseline, phase 4);
* :meth:`Study.ask` / :meth:`Study.tell` — the same critic for trials run elsewhere (a real
  robot, a person): every call rebuilds the critic from the store, so each can be its own
  short process; suggestions are stored as pending until told;
* :meth:`Study.best`, :meth:`Study.summary`, :meth:`Study.status`, :meth:`Study.report`.

Every phase resumes from the stored rows (no finished trial is lost or run twice) and refuses
to continue with other options or another system than it was started with. A study records
which system it ran (a built-in task's full configuration, a ``--system module:factory``
string with its arguments, or a Python class name) but never imports or calls what it names:
rebuilding a user system takes the user passing it again.

One process writes a study at a time: a second writer gets :class:`~latentune.errors.LockError`
at once (the lock is an ``flock`` on ``DIR/run.lock``, released when its process dies).
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from latentune.constants import Phase
from latentune.errors import LatentError, LockError, StoreError, UsageError
from latentune.pipeline.evaluators import Evaluator, make_evaluator
from latentune.pipeline.phases import (PhaseResult, asked_points, default_batch_size,
                                       ensure_manual, handover_options, make_handover_critic,
                                       make_phase_critic, replay, run_phase, save_state,
                                       store_outcome, training_set)
from latentune.pipeline.store import RunStore, Row
from latentune.space import ParameterSpace
from latentune.system import EvaluationError, as_outcome, check_system, evaluate

METHODS = ("turbo", "cma", "random", "sobol")
ASK_BUDGET = 200
"""The budget ask/tell assumes for its critic's options (TuRBO-m's region count) by default."""


def describe(system: Any) -> dict[str, Any]:
    """The JSON-able record of which system a phase ran (compared on resume).

    A built-in Task: ``{"kind": "task", "task": task.config()}``; a ``--system`` plugin (from
    :func:`latentune.system.load_system`): ``{"kind": "plugin", "target", "args"}``; any other
    object: its class, its ``config()`` if it has one, and its space.
    """
    from latentune.task import Task

    if isinstance(system, Task):
        return {"kind": "task", "task": system.config()}
    plugin = getattr(system, "latentune_plugin", None)
    if isinstance(plugin, dict):
        return {"kind": "plugin", **plugin, "space": system.space.to_dict()}
    d: dict[str, Any] = {"kind": "python",
                         "class": f"{type(system).__module__}.{type(system).__qualname__}",
                         "space": system.space.to_dict()}
    cfg = getattr(system, "config", None)
    if callable(cfg):
        d["config"] = json.loads(json.dumps(cfg(), default=str))
    return d


@dataclass
class Suggestion:
    """A θ handed out by :meth:`Study.ask` for a trial run elsewhere.

    Attributes:
        id: the id to pass to :meth:`Study.tell`.
        phase: 1 (θ space) or 3 (latent space).
        theta: (d,) normalized θ; ``params``: the physical values by name.
        z: (d_low,) the latent unit-box point in phase 3, else None.
        again: True if it was handed out before and is still pending.
        path: the ``--params`` JSON file written for it (``DIR/suggestions/<id>.json``).
    """

    id: int
    phase: int
    theta: np.ndarray
    params: dict[str, float]
    z: np.ndarray | None = None
    again: bool = False
    path: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "phase": self.phase, "again": self.again, "params": self.params,
                "theta": self.theta.tolist(), "file": self.path}


class Study:
    """A resumable run directory and the three phases on it (see the module docstring).

    Args:
        path: the run directory (created when a phase first writes to it).
        seed: seed of every critic, VAE and trial of this study (recorded).
        workers: parallel trials; ``backend``: ``serial``, ``process`` (a local pool) or ``ray``
            (``ray_address`` for a cluster, else a local Ray).
        batch_size: points per critic ask (default ``max(workers, 4)``).
        progress: show a progress bar; ``log``: a callable for one-line messages (default none).
        evaluator: an Evaluator to use instead of starting one (shared by several studies;
            the caller closes it; ``workers`` should be its worker count).
    """

    def __init__(self, path: str | os.PathLike, *, seed: int = 0, workers: int = 1,
                 backend: str = "serial", ray_address: str | None = None,
                 batch_size: int | None = None, progress: bool = False,
                 log: Callable[[str], None] | None = None,
                 evaluator: Evaluator | None = None) -> None:
        for name, v, lo in (("seed", seed, 0), ("workers", workers, 1)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise UsageError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not 0 <= int(seed) < 2 ** 63:
            raise UsageError(f"seed must be below 2**63, got {seed}")
        if batch_size is not None and (isinstance(batch_size, bool) or int(batch_size) < 1):
            raise UsageError(f"batch_size must be an integer >= 1, got {batch_size!r}")
        if backend not in ("serial", "process", "ray"):
            raise UsageError(f"unknown backend {backend!r} (choose from serial, process, ray)")
        if ray_address and backend != "ray":
            raise UsageError("ray_address needs backend='ray'")
        self.dir = Path(path)
        if self.dir.exists() and not self.dir.is_dir():
            raise StoreError(f"{self.dir} exists and is not a directory")
        self.seed = int(seed)
        self.workers = int(workers)
        self.backend = backend
        self.ray_address = ray_address
        self.batch_size = int(batch_size) if batch_size else default_batch_size(self.workers)
        self.progress = bool(progress)
        self._log = log
        self._store: RunStore | None = None
        self._lock_fd: int | None = None
        self._lock_depth = 0
        self._evaluator: Evaluator | None = evaluator
        self._owns_evaluator = evaluator is None

    # ------------------------------------------------------------------ store, lock, evaluator
    @property
    def exists(self) -> bool:
        """Whether the directory holds a run store."""
        return (self.dir / "run.db").is_file()

    @property
    def store(self) -> RunStore:
        """The run store (opened read-write; StoreError if there is none yet)."""
        if self._store is None:
            self._store = RunStore(self.dir)
        return self._store

    def _open(self) -> RunStore:
        if self._store is None:
            self._store = RunStore(self.dir, create=True)
        return self._store

    def log(self, msg: str) -> None:
        if self._log is not None:
            self._log(msg)

    @contextmanager
    def writing(self) -> Iterator[RunStore]:
        """Hold the study's write lock (re-entrant); yields the store (created if needed)."""
        if self._lock_depth == 0:
            self._acquire()
        self._lock_depth += 1
        try:
            st = self._open()
            if self._lock_depth == 1:
                st.check()             # a damaged store is refused before anything is added
            yield st
        finally:
            self._lock_depth -= 1
            if self._lock_depth == 0:
                self._release()

    def _acquire(self) -> None:
        import fcntl

        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.dir / "run.lock", os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise StoreError(f"cannot write to {self.dir}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            try:
                holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            finally:
                os.close(fd)
            raise LockError(f"{self.dir} is being written by {holder}; wait for it or use "
                            "another directory") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} since {time.strftime('%Y-%m-%d %H:%M:%S')}".encode(), 0)
        self._lock_fd = fd

    def _release(self) -> None:
        if self._lock_fd is not None:
            try:
                os.ftruncate(self._lock_fd, 0)
            except OSError:
                pass
            os.close(self._lock_fd)       # closing releases the flock
            self._lock_fd = None

    def evaluator(self) -> Evaluator:
        """The study's evaluator (started on first use; stopped by :meth:`close`)."""
        if self._evaluator is None:
            try:
                self._evaluator = make_evaluator(self.backend, self.workers, self.ray_address)
            except (RuntimeError, ValueError, OSError) as exc:
                raise EvaluationError(f"cannot start the {self.backend} evaluator: {exc}") from None
        return self._evaluator

    def close(self) -> None:
        """Stop the evaluator and close the store."""
        if self._evaluator is not None and self._owns_evaluator:
            self._evaluator.close()
            self._evaluator = None
        if self._store is not None:
            self._store.close()
            self._store = None

    def __enter__(self) -> "Study":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ config
    def config(self) -> dict[str, Any]:
        """The stored configuration (empty for a new study)."""
        return (self.store.get_meta("config") or {}) if self.exists else {}

    def _update_config(self, **kw: Any) -> dict[str, Any]:
        st = self._open()
        cfg = st.get_meta("config") or {}
        cfg.update(kw)
        st.set_meta("config", cfg)
        return cfg

    def _add_wall(self, key: str, seconds: float) -> None:
        w = self.store.get_meta("wall", {}) or {}
        w[key] = float(w.get(key, 0.0)) + float(seconds)
        self.store.set_meta("wall", w)

    def bind(self, system: Any) -> dict[str, Any]:
        """Record ``system`` as the study's system, or check it is the one recorded.

        Raises StoreError naming the differences if the study holds a run of another system."""
        desc = self.bind_check(system)
        if self.config().get("system") is None:
            kw: dict[str, Any] = {"system": desc, "space": system.space.to_dict()}
            if desc["kind"] == "task":
                kw["task"] = desc["task"]
            self._update_config(**kw)
        return desc

    def space(self) -> ParameterSpace | None:
        """The study's parameter space (stored with its first phase), or None."""
        sp = self.config().get("space")
        return None if sp is None else ParameterSpace.from_dict(sp)

    def _phase_config(self, key: str, method: str, budget: int, regions: int | None,
                      extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """The options of a phase: stored ones must match on resume (budget may grow)."""
        from latentune.critic.turbo import regions_for_budget

        if method not in METHODS:
            raise UsageError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
        if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
            raise UsageError(f"budget must be an integer >= 1, got {budget!r}")
        if regions is not None and not 1 <= int(regions) <= 100:
            raise UsageError(f"regions must be in [1, 100], got {regions}")
        stored = self.config().get(key)
        n = self.store.count(_PHASE_OF[key]) if self.exists else 0
        if regions is None and stored and n:
            regions = stored.get("regions")
        if regions is None and method == "turbo":
            regions = regions_for_budget(int(budget))
        pc = {"method": method, "batch_size": self.batch_size, "seed": self.seed,
              "regions": regions if method == "turbo" else None, "budget": int(budget),
              **(extra or {})}
        if stored and n:
            for k in ("method", "batch_size", "seed", "regions", *(extra or {})):
                if k in stored and stored.get(k) != pc.get(k):
                    raise StoreError(f"{self.dir}: {key} was run with {k.replace('_', '-')} = "
                                     f"{stored.get(k)!r}, not {pc.get(k)!r}")
        return pc

    # ------------------------------------------------------------------ phases
    def phase1(self, system: Any, budget: int, *, method: str = "turbo",
               regions: int | None = None, start: Any = "manual",
               max_fall_prob: float | None = None, fall_prior: Any = None,
               max_new: int | None = None) -> PhaseResult:
        """Phase 1: ``method`` tunes the full θ of ``system`` for ``budget`` evaluations in all
        (stored ones included). Resumes a stored phase 1.

        ``start``: ``"manual"`` (the first point is the system's manual θ), ``None`` (from
        scratch: the critic's own initial design) or a (d,) unit-box θ (e.g. another run's best).
        ``max_fall_prob``: skip candidates whose predicted probability of failing exceeds it
        (:class:`~latentune.critic.fall_aware.FallAware`; TuRBO-m also fills its first design
        around ``start`` and halves its trust region when more than that share of a batch
        falls, see :func:`~latentune.pipeline.phases.make_phase_critic`); ``fall_prior``: a run
        directory whose phase-1 trials (θ, failed) seed that prediction.
        """
        check_system(system)
        x0, start_rec = _start_point(start, system.space.manual, system.space.dim)
        extra = {"start": start_rec, **_fall_options(max_fall_prob, fall_prior)}
        pc = self._phase_config("phase1", method, budget, regions, extra)
        prior = _theta_prior(fall_prior, system.space.dim) if max_fall_prob is not None else None
        with self.writing() as st:
            self.bind(system)
            pc = self._phase_config("phase1", method, budget, regions, extra)
            self._update_config(phase1=pc)
            manual = ensure_manual(st, system, seed=self.seed)
            self.log(f"manual θ: cost {manual:.3f}")
            critic = make_phase_critic(method, system.space.dim, self.batch_size, self.seed,
                                       x0, pc["budget"], pc["regions"], max_fall_prob, prior)
            t = time.perf_counter()
            try:
                res = run_phase(st, Phase.PHASE1, system, critic, pc["budget"], self.evaluator(),
                                seed=self.seed, progress=self.progress, max_new=max_new,
                                known=self._manual_outcome(system))
            finally:
                self._add_wall("phase1", time.perf_counter() - t)
            self._write_best(Phase.PHASE1)
            self.log(f"phase 1: {res.n} evaluations, best cost {res.best_cost:.3f}")
            return res

    def _manual_outcome(self, system: Any) -> dict[bytes, Any]:
        """The stored manual-θ trial (phase 0), keyed for :func:`run_phase`'s ``known``."""
        from latentune.system import Outcome

        rows = [r for r in self.store.rows(Phase.MANUAL) if r.idx == 0]
        if not rows:
            return {}
        r = rows[0]
        theta = np.ascontiguousarray(system.space.manual, dtype=float)
        if not np.array_equal(r.theta, theta):
            return {}
        info = {**r.info, "fall_step": r.fall_step} if r.fall_step is not None else dict(r.info)
        return {theta.tobytes(): Outcome(r.cost, r.fell, info, r.wall_s)}

    def train_latent(self, latent_dim: int | None = None, *, kind: str | None = None,
                     epochs: int | None = None, retrain: bool = False) -> Any:
        """Phase 2: train the latent space on the phase-1 θ whose trial did not fail.

        Returns the :class:`~latentune.latent.LatentSpace` (``DIR/vae.pt``, ``DIR/vae.json``). A
        trained one is returned as it is unless ``retrain``; retraining after phase 3 used it
        is refused (it would invalidate the stored phase-3 rows)."""
        from latentune.latent.vae import DEFAULT_KIND, LatentSpace

        with self.writing() as st:
            if st.artifact("vae") is not None:
                if not retrain:
                    return LatentSpace.load(st.artifact("vae"))
                if st.count(Phase.PHASE3) > 0 and self.config().get("phase3_vae_source") == "self":
                    raise LatentError(f"{self.dir}: phase 3 already used the VAE; retraining it "
                                      "would invalidate the stored phase-3 rows (use another dir)")
            X = training_set(st, Phase.PHASE1)
            if len(X) < 2:
                raise LatentError(f"{self.dir}: phase 1 has {len(X)} θ whose trial did not fail; "
                                  "the latent space needs at least 2 (run more phase-1 evaluations)")
            cfg = self.config()
            t = time.perf_counter()
            meta = {"source_run": str(self.dir.resolve()), "n_phase1": st.count(Phase.PHASE1),
                    "system": cfg.get("system"), "space_names": cfg.get("space", {}).get("names")}
            if "task" in cfg:
                meta.update({k: cfg["task"][k] for k in ("robot", "gait", "actor", "terrain")})
            latent = LatentSpace.train(X, d_low=latent_dim, kind=kind or DEFAULT_KIND,
                                       seed=self.seed, epochs=epochs, meta=meta)
            prefix = self.dir / "vae"
            latent.save(prefix)
            self._add_wall("vae", time.perf_counter() - t)
            st.add_artifact("vae", prefix)
            self._update_config(vae={"kind": latent.kind, "d_low": latent.d_low, "n_train": len(X),
                                     "seed": self.seed, "beta": latent.meta.get("beta"),
                                     "box": latent.box.tolist(),
                                     "box_rule": latent.meta.get("box_rule")})
            self.log(f"VAE ({latent.kind}, d_low {latent.d_low}) trained on {len(X)} θ in "
                     f"{latent.meta.get('train_wall_s', 0):.1f} s; final reconstruction error "
                     f"{latent.meta.get('final_rec', float('nan')):.4f}")
            return latent

    def phase3(self, system: Any, budget: int, *, latent: Any = None, method: str = "turbo",
               regions: int | None = None, start: Any = "manual",
               max_fall_prob: float | None = None, handover: Any = None,
               max_new: int | None = None) -> PhaseResult:
        """Phase 3: ``method`` tunes in the latent box through the decoder, on ``system``.

        Args:
            latent: None (this study's latent space), a LatentSpace, or another study (its
                directory or a Study) whose latent space is copied here.
            start: ``"manual"`` (the first point is the code of the manual θ), ``None`` (from
                scratch) or a (d,) unit-box θ whose code starts the search.
            max_fall_prob: skip candidates whose predicted probability of failing exceeds it;
                the prediction starts from the latent space's source run (its phase-1 θ,
                encoded, with their failed flags). TuRBO-m's trust region also starts and
                shrinks as in :meth:`phase1`.
            handover: ``True`` or a dict of options (``patience``, ``tol``, ``length``): when
                the latent search stalls, continue with TuRBO-m on the full θ box from the best
                decoded θ (:mod:`latentune.critic.handover`; the rule and where it fired are
                recorded as ``phase3_handover`` in the run's config; rows of the full-space
                stage have no z).
        If the latent space comes from another study, that study's best θ is evaluated on
        ``system`` as it is first (the zero-shot baseline, phase 4, one evaluation)."""
        check_system(system)
        ls, source = self._resolve_latent(latent, system)              # checks before writing
        theta0, start_rec = _start_point(start, system.space.manual, system.space.dim)
        extra = {"latent_source": source, "start": start_rec,
                 **_fall_options(max_fall_prob, None if max_fall_prob is None else "latent source"),
                 "handover": _handover(handover)}
        pc = self._phase_config("phase3", method, budget, regions, extra)
        if self.exists:
            self.bind_check(system)
        with self.writing() as st:
            self.bind(system)
            pc = self._phase_config("phase3", method, budget, regions, extra)
            self._record_latent(ls, source)
            self._update_config(phase3=pc)
            manual = ensure_manual(st, system, seed=self.seed)
            self.log(f"manual θ: cost {manual:.3f}")
            self._zero_shot(system, source)
            x0 = None if theta0 is None else ls.to_unit(ls.encode(theta0))
            critic = self._phase3_critic(ls, source, pc, x0)
            two = pc["handover"] is not None
            t = time.perf_counter()
            try:
                res = run_phase(st, Phase.PHASE3, system, critic, pc["budget"], self.evaluator(),
                                decoder=None if two else ls.decode, seed=self.seed,
                                progress=self.progress, max_new=max_new)
            finally:
                self._add_wall("phase3", time.perf_counter() - t)
                if two:
                    self._update_config(phase3_handover=critic.rule())
            self._write_best(Phase.PHASE3)
            self.log(f"phase 3: {res.n} evaluations, best cost {res.best_cost:.3f}")
            return res

    def _phase3_critic(self, ls: Any, source: str, pc: dict[str, Any], x0: Any) -> Any:
        """The critic of phase 3 for the phase config ``pc``: on the latent box, or (with a
        hand-over) a :class:`~latentune.critic.handover.Handover` on the θ box."""
        mfp = pc.get("max_fall_prob")
        run = self.dir if source == "self" else Path(source)
        lprior = _latent_prior(run, ls) if mfp is not None else None
        if pc.get("handover") is None:
            return make_phase_critic(pc["method"], ls.d_low, self.batch_size, self.seed, x0,
                                     pc["budget"], pc["regions"], mfp, lprior)
        tprior = _theta_prior(run, ls.d) if mfp is not None else None
        return make_handover_critic(pc["method"], ls, self.batch_size, self.seed, x0,
                                    pc["budget"], pc["regions"], pc["handover"], mfp, lprior,
                                    tprior)

    def latent(self) -> Any:
        """The latent space phase 3 uses here (own or copied), or None."""
        from latentune.latent.vae import LatentSpace

        if not self.exists:
            return None
        src = self.store.artifact("phase3_vae") or self.store.artifact("vae")
        return None if src is None else LatentSpace.load(src)

    def _resolve_latent(self, latent: Any, system: Any) -> tuple[Any, str]:
        """(LatentSpace, source) for phase 3: source is "self" or the source study's path."""
        from latentune.latent.vae import LatentSpace

        space = system.space
        if latent is None:
            cfg = self.config()
            prev = cfg.get("phase3_vae_source")
            if prev not in (None, "self") and self.store.artifact("phase3_vae") is not None:
                ls, source = LatentSpace.load(self.store.artifact("phase3_vae")), prev
            elif self.exists and self.store.artifact("vae") is not None:
                ls, source = LatentSpace.load(self.store.artifact("vae")), "self"
            else:
                raise LatentError(f"no latent space in {self.dir}: train one first "
                                  "(train_latent / train-vae) or pass another study's")
        elif isinstance(latent, LatentSpace):
            src = latent.meta.get("source_run")
            ls = latent
            source = "self" if src is None or Path(src) == self.dir.resolve() else str(src)
        else:
            other = latent.dir if isinstance(latent, Study) else Path(latent)
            if not other.is_dir():
                raise LatentError(f"latent: run directory {other} does not exist")
            src = None
            if (other / "run.db").is_file():
                with RunStore(other) as o:
                    src = o.artifact("vae")
            ls = LatentSpace.load(src if src is not None else other / "vae")
            source = "self" if other.resolve() == self.dir.resolve() else str(other.resolve())
        if ls.d != space.dim:
            raise LatentError(f"the latent space ({source}) maps to {ls.d}-dim θ, but the "
                              f"system has {space.dim}-dim θ")
        names = ls.meta.get("space_names")
        if names is not None and list(names) != list(space.names):
            raise LatentError(f"the latent space ({source}) was trained on θ with other names "
                              "than the system's: normalized θ would not mean the same thing")
        actor = ls.meta.get("actor")
        mine = getattr(system, "actor", None) if isinstance(getattr(system, "actor", None), str) \
            else None
        if actor is not None and mine is not None and actor != mine:
            raise LatentError(f"the latent space ({source}) was trained on θ of the {actor} "
                              f"actor, not {mine}: normalized θ of different actors do not mean "
                              "the same thing")
        return ls, source

    def _record_latent(self, ls: Any, source: str) -> None:
        st = self.store
        cfg = self.config()
        prev = cfg.get("phase3_vae_source")
        if prev is not None and prev != source and st.count(Phase.PHASE3) > 0:
            raise StoreError(f"{self.dir}: phase 3 was run with the latent space of {prev}, "
                             f"not {source}")
        if prev is None or st.count(Phase.PHASE3) == 0:
            if source != "self":
                dst = self.dir / "phase3_vae"
                ls.save(dst)
                st.add_artifact("phase3_vae", dst)
            self._update_config(phase3_vae_source=source,
                                latent={"kind": ls.kind, "d": ls.d, "d_low": ls.d_low,
                                        "box": ls.box.tolist(),
                                        "box_rule": ls.meta.get("box_rule"),
                                        "n_train": ls.meta.get("n_train"),
                                        "from": {k: ls.meta.get(k) for k in
                                                 ("robot", "gait", "actor", "terrain")}})

    def _zero_shot(self, system: Any, source: str) -> None:
        """Evaluate the source study's best θ on ``system`` once (phase 4, idx 0)."""
        st = self.store
        if source == "self" or st.count(Phase.ZERO_SHOT) > 0:
            return
        best = source_best(source)
        if best is None:
            return
        src = Path(source)
        out = evaluate(system, best.theta)
        out.info.update({"source": str(src), "source_phase": int(best.phase),
                         "source_idx": int(best.idx), "source_cost": float(best.cost)})
        store_outcome(st, Phase.ZERO_SHOT, 0, best.theta, out, seed=self.seed)
        self.log(f"zero-shot (the source's best θ as it is): cost {out.cost:.3f}")

    def preservation(self, system: Any, latent: Any) -> dict[str, Any]:
        """Pass each phase-1 θ of this study whose trial did not fail through ``latent``'s
        encoder and decoder and evaluate the result on ``system`` (phase 5, idx = the source
        row's idx). Returns ``{n_stable, n_kept, rate}``; resumes."""
        with self.writing() as st:
            ls, source = self._resolve_latent(latent, system)
            rows = [r for r in st.rows(Phase.PHASE1) if not r.fell]
            done = {r.idx for r in st.rows(Phase.PRESERVATION)}
            todo = [r for r in rows if r.idx not in done]
            t = time.perf_counter()
            if todo:
                rec = np.clip(ls.reconstruct(np.array([r.theta for r in todo])), 0.0, 1.0)
                for i, out in self.evaluator().imap(system, rec):
                    out = _checked(out)
                    store_outcome(st, Phase.PRESERVATION, todo[i].idx, rec[i], out,
                                  z=todo[i].theta, seed=self.seed)
            self._add_wall("preservation_rollouts", time.perf_counter() - t)
            kept = int(sum(not r.fell for r in st.rows(Phase.PRESERVATION)))
            res = {"vae_source": source, "n_phase1": st.count(Phase.PHASE1),
                   "n_stable": len(rows), "n_kept": kept, "complete": True,
                   "rate": kept / len(rows) if rows else math.nan,
                   "rows": "phase 5: theta = decoded θ, z = the original θ, "
                           "idx = the source phase-1 idx"}
            st.set_meta("preservation", res)
            return res

    # ------------------------------------------------------------------ ask / tell
    def ask(self, n: int = 1, *, system: Any = None, space: ParameterSpace | None = None,
            phase: int | None = None, latent: Any = None, method: str = "turbo",
            budget: int = ASK_BUDGET, handover: Any = None) -> list[Suggestion]:
        """Suggest ``n`` θ for trials run elsewhere; pending ones are handed out again first.

        The first ask fixes the study's system (``system``) or parameter space (``space``),
        the phase (1, or 3 with ``latent`` or this study's trained latent space) and the
        critic's options (``handover`` as in :meth:`phase3`); later asks reuse them. Every call
        rebuilds the critic from the store.
        Each suggestion is stored as pending and written as a ``--params`` file."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise UsageError(f"n must be an integer >= 1, got {n!r}")
        with self.writing() as st:
            sp = self._ask_space(system, space)
            at = self._ask_config(phase, method, budget, latent, sp, handover)
            ph = Phase(at["phase"])
            if ph == Phase.PHASE3:
                self._ask_zero_shot(st, at.get("latent_source"))
            waiting = st.trials("pending")
            pending = [t for t in waiting if t.phase == ph]
            first = [t for t in waiting if t.phase == Phase.ZERO_SHOT] + pending
            out = [self._suggestion(t, sp, again=True) for t in first[:n]]
            k = n - len(out)
            if k > 0:
                ls = self.latent() if ph == Phase.PHASE3 else None
                if ls is None:
                    critic = make_phase_critic(at["method"], sp.dim, self.batch_size, self.seed,
                                               sp.manual, at["budget"], at["regions"])
                else:
                    critic = self._phase3_critic(ls, at.get("latent_source", "self"), at,
                                                 ls.to_unit(ls.encode(sp.manual)))
                replay(st, ph, critic)
                U = critic.ask(len(pending) + k)[len(pending):]
                tags = critic.last_tags[len(pending):]
                save_state(st, ph, critic)          # the next ask reuses its GP fits
                Z = getattr(critic, "last_z", None)    # a hand-over critic: U is θ already
                thetas, zs = asked_points(U, None if Z is None else Z[len(pending):],
                                          None if ls is None else ls.decode)
                for i in range(k):
                    tid = st.add_trial(ph, thetas[i], zs[i], int(tags[i]))
                    out.append(self._suggestion(st.trials_by_id(tid), sp, again=False))
            return out

    def _ask_zero_shot(self, st: RunStore, source: str | None) -> None:
        """Phase-3 ask/tell with another study's latent space: the first suggestion is that
        study's best θ as it is (the zero-shot baseline, phase 4), handed out once."""
        if source in (None, "self") or st.count(Phase.ZERO_SHOT) > 0 or \
                any(t.phase == Phase.ZERO_SHOT for t in st.trials()):
            return
        best = source_best(source)
        if best is not None:
            st.add_trial(Phase.ZERO_SHOT, best.theta, None, -1)

    def tell(self, trial_id: int, cost: float | None = None, *, failed: bool = False,
             note: str | None = None, info: dict[str, Any] | None = None) -> Row:
        """Store the result of suggestion ``trial_id``: its cost (None with ``failed`` takes the
        C1 convention, see :mod:`latentune.system`), whether it failed, a free note.
        Raises StoreError for an unknown or already told id, ValueError for a bad cost."""
        if isinstance(trial_id, bool) or not isinstance(trial_id, (int, np.integer)):
            raise UsageError(f"a suggestion id is an integer, got {trial_id!r}")
        try:
            out = as_outcome({"cost": cost, "failed": bool(failed), "info": dict(info or {})})
        except EvaluationError as exc:
            raise UsageError(f"bad result for suggestion {trial_id}: {exc}".replace(
                "evaluate returned", "got")) from None
        if note:
            out.info["note"] = str(note)
        with self.writing() as st:
            idx = st.tell_trial(int(trial_id), out.cost, fell=out.failed, fall_step=out.fall_step,
                                seed=self.seed, info=out.info)
            trial = st.trials_by_id(int(trial_id))
            path = self.dir / "suggestions" / f"{trial_id}.json"
            if path.is_file():
                path.unlink()
            self._write_best(Phase(trial.phase))
            return next(r for r in st.rows(trial.phase) if r.idx == idx)

    def _ask_space(self, system: Any, space: ParameterSpace | None) -> ParameterSpace:
        if system is not None:
            self.bind(system)
            return system.space
        stored = self.space()
        if space is not None:
            if stored is not None and stored != space:
                raise StoreError(f"{self.dir} holds a study of another parameter space")
            if stored is None:
                self._update_config(space=space.to_dict(),
                                    system={"kind": "external", "space": space.to_dict()})
            return space
        if stored is None:
            raise StoreError(f"{self.dir}: no parameter space yet: the first ask needs a system "
                             "or a space (--system, --robot or --space FILE)")
        return stored

    def _ask_config(self, phase: int | None, method: str, budget: int, latent: Any,
                    space: ParameterSpace, handover: Any = None) -> dict[str, Any]:
        cfg = self.config()
        stored = cfg.get("asktell")
        if stored is not None:
            if phase is not None and int(phase) != stored["phase"]:
                raise StoreError(f"{self.dir}: ask/tell runs phase {stored['phase']}, not {phase}")
            return stored
        if phase is None:
            phase = Phase.PHASE3 if latent is not None else Phase.PHASE1
        if int(phase) not in (Phase.PHASE1, Phase.PHASE3):
            raise UsageError(f"ask/tell runs phase 1 or 3, not {phase}")
        key = "phase1" if int(phase) == Phase.PHASE1 else "phase3"
        extra = None
        if int(phase) == Phase.PHASE3:
            ls, source = self._resolve_latent(latent, _SpaceOnly(space))
            self._record_latent(ls, source)
            extra = {"latent_source": source, "handover": _handover(handover)}
        elif handover:
            raise UsageError("handover is an option of phase 3")
        pc = self._phase_config(key, method, budget, None, extra)
        at = {**pc, "phase": int(phase)}
        self._update_config(asktell=at, **{key: pc})
        return at

    def _suggestion(self, t: Any, space: ParameterSpace, again: bool) -> Suggestion:
        params = space.as_dict(t.theta)
        d = self.dir / "suggestions"
        d.mkdir(exist_ok=True)
        path = d / f"{t.id}.json"
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(params, indent=1))
        os.replace(tmp, path)
        return Suggestion(t.id, t.phase, t.theta, params, t.z, again, str(path))

    # ------------------------------------------------------------------ results
    def best(self, phase: int | None = None) -> Row | None:
        """The best stored evaluation of ``phase`` (default: of phases 1 and 3 together)."""
        if not self.exists:
            return None
        phases = (phase,) if phase is not None else (Phase.PHASE1, Phase.PHASE3)
        rows = [b for ph in phases if (b := self.store.best(ph)) is not None]
        return min(rows, key=lambda r: (r.cost, r.phase, r.idx)) if rows else None

    def status(self) -> dict[str, Any]:
        """Counts per phase (told, failed), pending suggestions, best cost and θ file."""
        st = self.store
        out: dict[str, Any] = {"dir": str(self.dir), "phases": {}}
        for ph in Phase:
            rows = st.rows(ph)
            if rows:
                b = min(rows, key=lambda r: (r.cost, r.idx))
                out["phases"][ph.name.lower()] = {"n": len(rows), "failed": sum(r.fell for r in rows),
                                                  "best": b.cost, "best_idx": b.idx}
        out["pending"] = [t.id for t in st.trials("pending")]
        out["told"] = len(st.trials("told"))
        b = self.best()
        out["best"] = None if b is None else {"phase": b.phase, "idx": b.idx, "cost": b.cost}
        return out

    def summary(self) -> dict[str, Any]:
        """Write and return ``DIR/summary.json`` (see :mod:`latentune.reporting.run_report`)."""
        from latentune.reporting.run_report import write_summary

        return write_summary(self.store)

    def report(self, system: Any = None, simulate: bool = True) -> str:
        """Write ``DIR/report.md`` with its figures; return the comparison table (Markdown).

        Re-simulated CoM plots need a system with ``rollout`` (a built-in task is rebuilt from
        the stored configuration; a user system only if passed here)."""
        from latentune.reporting.run_report import make_report

        if system is not None:
            self.bind_check(system)
        return make_report(self.store, system=system, simulate=simulate, quiet=not self.progress)

    def bind_check(self, system: Any) -> dict[str, Any]:
        """Return ``system``'s description; StoreError (naming the differences) unless it is
        the system this study recorded, or no system is recorded yet."""
        desc = describe(check_system(system))
        cfg = self.config()
        stored = cfg.get("system")
        if stored is None and "task" in cfg:        # a run written before systems were recorded
            stored = {"kind": "task", "task": cfg["task"]}
        if stored is not None and stored != desc:
            raise StoreError(f"{self.dir} holds a run of another system ({_diff(stored, desc)})")
        return desc

    def _write_best(self, phase: int) -> None:
        b = self.store.best(phase)
        sp = self.space()
        if b is None or sp is None:
            return
        path = self.dir / f"phase{int(phase)}_best.json"
        path.write_text(json.dumps(sp.as_dict(b.theta), indent=1))
        self.store.add_artifact(f"phase{int(phase)}_best", path)


_PHASE_OF = {"phase1": Phase.PHASE1, "phase3": Phase.PHASE3}


@dataclass
class _SpaceOnly:
    """A stand-in carrying only a space (ask/tell on an external system)."""

    space: ParameterSpace


def source_best(run: str | os.PathLike) -> Row | None:
    """The best trial of a run's phases 1 and 3 among those that did not fail (all trials if
    every one failed); None if the run has no store or no trials. The zero-shot θ."""
    if not (Path(run) / "run.db").is_file():
        return None
    with RunStore(run) as o:
        rows = [r for ph in (Phase.PHASE1, Phase.PHASE3) for r in o.rows(ph)]
    if not rows:
        return None
    ok = [r for r in rows if not r.fell] or rows
    return min(ok, key=lambda r: (r.cost, r.phase, r.idx))


def _fall_options(max_fall_prob: float | None, prior: Any) -> dict[str, Any]:
    """The phase-config record of the fall-aware option (checked, compared on resume)."""
    if max_fall_prob is None:
        return {"max_fall_prob": None}
    if isinstance(max_fall_prob, bool) or not isinstance(max_fall_prob, (int, float)) or \
            not 0.0 < float(max_fall_prob) <= 1.0:
        raise UsageError(f"max_fall_prob must be in (0, 1], got {max_fall_prob!r}")
    return {"max_fall_prob": float(max_fall_prob),
            "fall_prior": None if prior is None else str(prior)}


def _handover(handover: Any) -> dict[str, Any] | None:
    try:
        return handover_options(handover)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _prior_rows(run: Path) -> list[Row]:
    if not (Path(run) / "run.db").is_file():
        raise StoreError(f"fall prior: no run store in {run}")
    with RunStore(run) as o:
        return o.rows(Phase.PHASE1)


def _theta_prior(run: Any, dim: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(θ (m, d), fell (m,)) of another run's phase 1, the prior of a direct fall-aware search."""
    if run is None:
        return None
    rows = _prior_rows(Path(run))
    if not rows:
        return None
    X = np.array([r.theta for r in rows])
    if X.shape[1] != dim:
        raise StoreError(f"fall prior {run}: its θ have {X.shape[1]} entries, not {dim}")
    return X, np.array([r.fell for r in rows], dtype=bool)


def _latent_prior(run: Path, ls: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """The source run's phase-1 θ encoded into the latent unit box (codes outside the box are
    dropped: clipping would pile them on its faces) with their fell flags."""
    rows = _prior_rows(run)
    if not rows:
        return None
    Z = np.atleast_2d(ls.encode(np.array([r.theta for r in rows])))
    inside = np.all((Z >= ls.box[:, 0]) & (Z <= ls.box[:, 1]), axis=1)
    fell = np.array([r.fell for r in rows], dtype=bool)[inside]
    return ls.to_unit(Z[inside]), fell


def _start_point(start: Any, manual: np.ndarray, dim: int) -> tuple[np.ndarray | None, Any]:
    """(θ0 or None, the JSON record of ``start``) for a phase's ``start`` argument."""
    if isinstance(start, str):
        if start != "manual":
            raise UsageError(f"start must be 'manual', None or a θ, got {start!r}")
        return manual, "manual"
    if start is None:
        return None, None
    from latentune.critic.base import as_unit_points

    try:
        x = as_unit_points(start, dim, "start")[0]
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return x, [float(v) for v in x]


def _checked(out: Any) -> Any:
    from latentune.pipeline.evaluators import TrialError

    if isinstance(out, TrialError):
        raise EvaluationError(out.message)
    return out


def _diff(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> str:
    """The differing keys of two descriptions, as ``key: stored X, given Y`` (at most 4)."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if va == vb:
            continue
        if isinstance(va, dict) and isinstance(vb, dict):
            out.append(_diff(va, vb, f"{prefix}{k}."))
        else:
            out.append(f"{prefix}{k}: stored {_short(va)}, given {_short(vb)}")
    return "; ".join(x for x in out[:4] if x)


def _short(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 50 else s[:47] + "..."


def stderr_log(msg: str) -> None:
    """A ``log`` for :class:`Study` that prints to stderr."""
    print(msg, file=sys.stderr, flush=True)


__all__ = ["Study", "Suggestion", "describe", "source_best", "stderr_log"]
