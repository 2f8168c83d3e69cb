"""The transfer ladder on the robots: phase 3 against the user's tools, from the paper-budget
sources of A1 and Solo12 to targets at several gaps.

    python -m benchmarks.robot_transfer list
    python -m benchmarks.robot_transfer snapshot [--robots a1 solo12] [--sources a1-trot ...]
        [--paper results/paper10k] [--root runs/robot_transfer]
    python -m benchmarks.robot_transfer run [--robots a1 solo12] [--targets RUNG ...]
        [--methods METHOD ...] [--seeds 0 1 2 3 4] [--budget 100] [--source-trials N]
        [--paper results/paper10k] [--root runs/robot_transfer] [--workers 1]
        [--variants OPTION=VALUE[:OPTION=VALUE] ...]   (transfer variants, stored as transfer+VARIANT)
    python -m benchmarks.robot_transfer import-paper --paper-run results/paper10k/a1
        [--root runs/robot_transfer] [--budget 100]
    python -m benchmarks.robot_transfer summary [--root runs/robot_transfer]
        [--out F.json] [--methods M ...] [--targets RUNG ...]
        [--seeds S ...]
    python -m benchmarks.robot_transfer export --root runs/robot_transfer --out DIR
    python -m benchmarks.robot_transfer restore --traces DIR [--root runs/robot_transfer]
    python -m benchmarks.robot_transfer cut --method METHOD --share Q --as NAME [--counts all]
        [--root runs/robot_transfer] [--seeds S ...]   (METHOD's runs as fall_budget = Q runs them)
    python -m benchmarks.robot_transfer plot [--targets RUNG ...] [--root runs/robot_transfer]
        [--out results/robot_transfer] [--gifs]

Rungs (:func:`rungs`; ``list`` prints them). A source is a phase-1 study of ``latentune paper``
(``PAPER/<robot>/<robot>-<gait>/run.db``, ``scripts/paper_sources.sh``); a target is the
source's task (its stored ``Task.config()``: actor, horizon, v_des and world seed, so the
``hard`` profile's noise and pushes are the same for every method and seed) with a few fields
changed. For each robot R of
``a1`` (convex MPC) and ``solo12`` (kino-dynamic MPC) and each gait g of trot and jump:

* ``R-g-heavy`` / ``R-g-hard``: the source ``R-g`` on the ``heavy`` / ``hard`` reality profile
  (:mod:`latentune.sim.reality`);
* ``R-g-mujoco``: the source ``R-g`` in MuJoCo (the other engine);
* ``R-jump-from-trot``: the source ``R-trot`` on the jump task (cross-task);
* A1 only, ``b1-g-from-a1``: the source ``a1-g`` on B1 (cross-robot), and
  ``b1-jump-from-a1-trot``: the A1 trot source on B1 jump (the paper's A1 → B1 jump row).

Sources are never opened in place: a long ``latentune paper`` run may be writing them.
:func:`snapshot` copies a source's ``run.db`` with SQLite's online-backup API (a read-only
connection, one consistent read) into ``ROOT/sources/<source>/n<N>/`` (N = its phase-1 and
phase-3 trials at that moment) and trains its latent space there (phase 2, the source's recorded
seed) unless the source has one; ``snapshot.json``, written last, marks a finished snapshot.
Sources grow: ``run`` uses the newest snapshot (``--source-trials N``: that one; none yet: it
takes one), ``snapshot`` takes a new one when the source has grown.

``run``: for every seed, rung and method (:data:`benchmarks.transfer.METHODS`, run by
:func:`benchmarks.transfer.run_method`; in that order, so every rung has a seed's runs before
the next seed starts) ``--budget`` B trials on the target, one at a time, every trial counted;
``--variants`` adds the transfer critic with options beyond those of the method ``transfer``
(its defaults with :data:`benchmarks.transfer.LADDER_BASE`; the default phase 3 of sessions
32–38 is ``--variants explore_pool=adaptive``, since session 39
``explore_pool=adaptive:explore_gp=true:explore_fall_prob=0.2``;
:func:`benchmarks.transfer.parse_variant`), stored
as method ``transfer+VARIANT`` and listed
by ``summary`` beside the methods (never a peer); one JSON per run at
``ROOT/targets/<rung>/src<N>/seed<s>/<method>.json``
(cost, failed and θ per trial, the transfer critic's decisions, wall time, load average, the
target's task config, the source and its trial count N), skipped when it exists: the run
resumes. ``summary`` applies the transfer issue's definitions per (rung, source size)
(:func:`benchmarks.transfer.summarize`) and flags rungs where no method beats the zero-shot θ;
``import-paper`` shares rollouts with the evidence issue: the seeded studies of a ``latentune
paper --seeds N`` run whose rows are rungs (trot → jump, A1 trot → B1 trot and jump;
:data:`PAPER_ROWS`) become results of those rungs, cut at ``--budget`` (:func:`import_paper`).
``export`` writes every run's trace (cost and fall per trial, wall time, load, the θ of its
lowest cost) as one JSON per rung, to commit; ``restore`` rebuilds the run files from those
traces on a fresh clone (the run directory is not committed), so ``run`` resumes there and the
other commands read them. ``plot`` re-simulates the best θ of the default phase 3 and of the
best peer (and the zero-shot θ) on a rung's target and draws the base's CoM x/y/z, forward
velocity and height over time into ``OUT/<rung>/``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import logging
import math
import os
import shutil
import sqlite3
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from benchmarks import transfer as tr
from benchmarks.transfer_falls import STEP_EDGES, ask_kind, band, region_steps

import numpy as np  # noqa: E402  (benchmarks.transfer sets one BLAS thread first)

from latentune.pipeline.store import read_uri  # noqa: E402

logger = logging.getLogger(__name__)

ROBOT_GAITS = ("trot", "jump")
ROBOTS = ("a1", "solo12")
SNAPSHOT_FILE = "snapshot.json"


class RobotTransferError(Exception):
    """A request this benchmark cannot honour (unknown rung, missing source, ...)."""


# --------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class Rung:
    """One target of the ladder.

    Attributes:
        name: the rung's name (``a1-trot-heavy``).
        robot: the paper run holding the source (``PAPER/<robot>/``).
        source: the source study's key in that run (``a1-trot``).
        change: the Task fields of the target that differ from the source's task
            (``robot``, ``gait``, ``reality``, ``engine``).
        label: one line for tables and plots.
    """

    name: str
    robot: str
    source: str
    change: dict[str, Any] = field(hash=False)
    label: str = ""

    def target(self, source_task: dict[str, Any]) -> Any:
        """The target Task: ``source_task`` (a stored ``Task.config()``) with :attr:`change`."""
        from latentune.task import Task

        cfg = dict(source_task)
        if "robot" in self.change:
            cfg.pop("spec", None)
        cfg.update(self.change)
        return Task.from_config(cfg)


def rungs(robots: Iterable[str] = ROBOTS) -> dict[str, Rung]:
    """The rungs of ``robots`` by name (module docstring), in run order."""
    out: dict[str, Rung] = {}
    for R in robots:
        if R not in ROBOTS:
            raise RobotTransferError(f"unknown robot {R!r} (choose from {', '.join(ROBOTS)})")
        for g in ROBOT_GAITS:
            for kind, change in (("heavy", {"reality": "heavy"}), ("hard", {"reality": "hard"}),
                                 ("mujoco", {"engine": "mujoco"})):
                out[f"{R}-{g}-{kind}"] = Rung(f"{R}-{g}-{kind}", R, f"{R}-{g}", change,
                                              f"{R} {g} → {kind}")
        out[f"{R}-jump-from-trot"] = Rung(f"{R}-jump-from-trot", R, f"{R}-trot",
                                          {"gait": "jump"}, f"{R} trot source → {R} jump")
        if R == "a1":
            for g in ROBOT_GAITS:
                out[f"b1-{g}-from-a1"] = Rung(f"b1-{g}-from-a1", R, f"a1-{g}", {"robot": "b1"},
                                              f"a1 {g} source → b1 {g}")
            out["b1-jump-from-a1-trot"] = Rung("b1-jump-from-a1-trot", R, "a1-trot",
                                               {"robot": "b1", "gait": "jump"},
                                               "a1 trot source → b1 jump")
    return out


def select(robots: Sequence[str], names: Sequence[str] | None) -> list[Rung]:
    """The rungs named (all of ``robots`` when ``names`` is None); refuses unknown names and
    rungs of other robots."""
    reg = rungs(robots)
    if names is None:
        return list(reg.values())
    every = rungs(ROBOTS)
    for n in names:
        if n not in every:
            raise RobotTransferError(f"unknown target {n!r} (see `list`)")
        if n not in reg:
            raise RobotTransferError(f"target {n!r} is a rung of {every[n].robot}, not of "
                                     f"{', '.join(robots)}")
    return [reg[n] for n in dict.fromkeys(names)]


# --------------------------------------------------------------------------- sources
def _count(run_dir: Path) -> tuple[int, int]:
    from latentune.constants import Phase
    from latentune.pipeline.store import RunStore

    with RunStore(run_dir) as st:
        return st.count(Phase.PHASE1), st.count(Phase.PHASE3)


def snapshots(dest: Path) -> list[Path]:
    """The finished snapshots under ``dest`` (``dest/n<N>/`` with ``snapshot.json``), by N."""
    found = [p for p in dest.glob("n*") if p.is_dir() and p.name[1:].isdigit()
             and (p / SNAPSHOT_FILE).is_file()]
    return sorted(found, key=lambda p: int(p.name[1:]))


def copy_db(src_db: Path, dest_db: Path) -> None:
    """One consistent copy of the SQLite store ``src_db`` at ``dest_db``, read through a
    read-only connection with SQLite's online-backup API (a live run may be writing it)."""
    try:
        con = sqlite3.connect(read_uri(src_db.resolve()), uri=True, timeout=60.0)
        try:
            out = sqlite3.connect(str(dest_db))
            try:
                con.backup(out)
            finally:
                out.close()
        finally:
            con.close()
    except sqlite3.Error as exc:
        raise RobotTransferError(f"cannot copy {src_db}: {exc}") from None


def snapshot(live: Path, dest: Path) -> Path:
    """Snapshot the study ``live`` into ``dest/n<N>/`` and prepare it as a source.

    The copy is made with SQLite's backup API from a read-only connection (``live`` is never
    locked or written); N is its number of phase-1 + phase-3 trials. A snapshot of that size
    that exists is reused. The latent space is copied from ``live`` when it has one
    (``vae.pt`` / ``vae.json``), else trained in the snapshot (``Study.train_latent``, the
    source's recorded seed). Returns the snapshot directory."""
    src_db = live / "run.db"
    if not src_db.is_file():
        raise RobotTransferError(f"no source run at {live} (expected {src_db})")
    dest.mkdir(parents=True, exist_ok=True)
    tmp = dest / f".taking-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    t0 = time.perf_counter()
    try:
        copy_db(src_db, tmp / "run.db")
    except RobotTransferError:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    n1, n3 = _count(tmp)
    final = dest / f"n{n1 + n3}"
    if final.exists():
        shutil.rmtree(tmp)
    else:
        tmp.rename(final)
    if not (final / SNAPSHOT_FILE).is_file():
        _prepare(live, final, n1, n3, time.perf_counter() - t0)
    return final


def _prepare(live: Path, snap: Path, n1: int, n3: int, copy_s: float) -> None:
    """Give the snapshot ``snap`` its latent space, then write ``snapshot.json``."""
    from latentune.study import Study

    copied = all((live / f"vae{ext}").is_file() for ext in (".pt", ".json"))
    if copied:
        for ext in (".pt", ".json"):
            shutil.copy2(live / f"vae{ext}", snap / f"vae{ext}")
    t0 = time.perf_counter()
    with Study(snap) as st:
        if copied and st.store.artifact("vae") is None:
            st.store.add_artifact("vae", snap / "vae")
        latent = st.train_latent()
        cfg = st.config()
        seed = st.seed
    info = {"from": str(live.resolve()), "n_trials": n1 + n3, "n_phase1": n1, "n_phase3": n3,
            "taken": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "copy_s": copy_s, "seed": seed,
            "vae": {"from": "source" if copied else "trained here", "kind": latent.kind,
                    "d_low": latent.d_low, "n_train": (cfg.get("vae") or {}).get("n_train"),
                    "wall_s": time.perf_counter() - t0},
            "task": cfg.get("task"), "system": cfg.get("system"),
            "space_names": (cfg.get("space") or {}).get("names")}
    (snap / SNAPSHOT_FILE).write_text(json.dumps(info, indent=1))
    logger.info("snapshot %s: %d trials, VAE %s", snap, n1 + n3, info["vae"]["from"])


def source_dir(paper: Path, root: Path, robot: str, source: str, trials: int | None = None,
               take: bool = True) -> Path:
    """The snapshot a run uses: of ``trials`` trials if given (it must exist), else the newest
    one; with none yet, a new one (``take``) from ``paper/<robot>/<source>``."""
    dest = root / "sources" / source
    have = snapshots(dest)
    if trials is not None:
        for p in have:
            if int(p.name[1:]) == trials:
                return p
        raise RobotTransferError(f"no snapshot of {source} with {trials} trials under {dest} "
                                 f"(have: {', '.join(p.name for p in have) or 'none'})")
    if have:
        return have[-1]
    if not take:
        raise RobotTransferError(f"no snapshot of {source} under {dest}")
    return snapshot(paper / robot / source, dest)


def snapshot_info(src: Path) -> dict[str, Any]:
    """A snapshot's ``snapshot.json``."""
    return json.loads((src / SNAPSHOT_FILE).read_text())


def build_target(rung: Rung, src: Path) -> Any:
    """The rung's target Task from the snapshot ``src``; refuses a θ space other than the
    source's (the latent space and the source's trials are over the source's θ)."""
    info = snapshot_info(src)
    if not info.get("task"):
        raise RobotTransferError(f"{src} is not a robot task's run (no stored task)")
    target = rung.target(info["task"])
    names = list(target.space.names)
    if info.get("space_names") is not None and names != list(info["space_names"]):
        raise RobotTransferError(f"{rung.name}: the target's θ ({len(names)} entries) are not "
                                 f"the source's ({len(info['space_names'])})")
    return target


# --------------------------------------------------------------------------- runs
class Recorded:
    """A System that forwards to ``system`` and records every θ it evaluates ((d,) lists)."""

    def __init__(self, system: Any) -> None:
        self.system = system
        self.space = system.space
        self.thetas: list[list[float]] = []

    def evaluate(self, theta: np.ndarray) -> Any:
        self.thetas.append([float(v) for v in np.asarray(theta, dtype=float).ravel()])
        return self.system.evaluate(theta)


def result_path(root: Path, target: str, n_source: int, seed: int, method: str) -> Path:
    """Where the run of ``method`` on ``target`` with a source of ``n_source`` trials lives."""
    return root / "targets" / target / f"src{n_source}" / f"seed{seed}" / f"{method}.json"


def run_one(target_name: str, target: Any, src: Path, method: str, seed: int, budget: int,
            root: Path, extra: dict[str, Any] | None = None,
            options: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """``budget`` trials of ``method`` on ``target`` (a System) from the prepared source
    ``src``; writes and returns the result (None when it is stored already). A method
    ``transfer+VARIANT`` is the transfer critic with ``options`` (stored under that name)."""
    info = snapshot_info(src)
    f = result_path(root, target_name, int(info["n_trials"]), seed, method)
    if f.is_file():
        return None
    rec = Recorded(target)
    load0 = list(os.getloadavg())
    t0 = time.perf_counter()
    res = tr.run_method(method.partition("+")[0], rec, src, budget, seed, options)
    res.update(target=target_name, source=Path(info["from"]).name, source_dir=str(src),
               source_trials=int(info["n_trials"]), seed=seed, method=method, budget=budget,
               wall_s=time.perf_counter() - t0, load_start=load0, load_end=list(os.getloadavg()),
               thetas=rec.thetas, **(extra or {}))
    if options:
        res["options"] = options
    cfg = getattr(target, "config", None)
    if callable(cfg):
        res["target_config"] = cfg()
    f.parent.mkdir(parents=True, exist_ok=True)
    tmp = f.with_suffix(".tmp")
    tmp.write_text(json.dumps(res))
    tmp.replace(f)
    return res


def _job(args: tuple) -> str:
    rung, src, method, seed, budget, root, options = args
    target = build_target(rung, src)
    res = run_one(rung.name, target, src, method, seed, budget, root, {"label": rung.label},
                  options)
    if res is None:
        return f"{rung.name} seed {seed} {method}: stored"
    return (f"{rung.name} ({res['source_trials']} source trials) seed {seed} {method}: best "
            f"{min(res['costs']):.4g}, falls {sum(res['failed'])}, {res['wall_s']:.0f} s")


def run(a: argparse.Namespace) -> None:
    root, paper = Path(a.root), Path(a.paper)
    methods = [(m, None) for m in a.methods] + \
        [(f"transfer+{v}", tr.parse_variant(v)) for v in getattr(a, "variants", None) or []]
    from latentune.critic.transfer import TRANSFER_DEFAULTS

    for m, o in methods:
        if o is not None and set(o) - set(TRANSFER_DEFAULTS):
            raise RobotTransferError(f"{m}: unknown transfer option(s) "
                                     f"{', '.join(sorted(set(o) - set(TRANSFER_DEFAULTS)))}")
    prepared = []
    for rung in select(a.robots, a.targets):
        src = source_dir(paper, root, rung.robot, rung.source, a.source_trials)
        build_target(rung, src)                         # refuse a bad rung before any trial
        if any(m.partition("+")[0] == "transfer" and (o or {}).get("source_order") == "stored"
               for m, o in methods):
            # the cache of the runs made before ``source_order`` (fitted with seed 0 for every
            # seed), before the workers share it; a canonical-order critic fits per seed
            tr.source_hypers(src, 0, {"source_order": "stored"})
        prepared.append((rung, src, int(snapshot_info(src)["n_trials"])))
    jobs = [(rung, src, m, s, a.budget, root, o) for s in a.seeds for rung, src, n in prepared
            for m, o in methods if not result_path(root, rung.name, n, s, m).is_file()]
    if getattr(a, "reverse", False):
        jobs.reverse()
    print(f"{len(jobs)} runs to do", flush=True)
    if a.workers == 1:
        for j in jobs:
            print(_job(j), flush=True)
        return
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(a.workers) as ex:
        for line in ex.map(_job, jobs):
            print(line, flush=True)


# --------------------------------------------------------------------------- paper rows
PAPER_ROWS = {"jump-cross": "{R}-jump-from-trot", "b1-trot": "b1-trot-from-a1",
              "b1-jump": "b1-jump-from-a1-trot"}
"""The seeded rows of ``latentune paper --seeds N`` that are rungs of this ladder (row → rung)."""
PAPER_ARMS = {"phase3-transfer": "transfer", "phase3-plain": "plain", "turbo": "turbo_source",
              "cma": "cma_source", "tpe": "tpe", "cmaes-src": "cma_source_trials"}
"""The paper's arms of those rows as this ladder's methods (its ``cma`` is latentune's pycma
critic, not Optuna's ``CmaEsSampler``: the record says so)."""


def _read_copy(study: Path, tmp: Path, read: Callable[[Any], Any]) -> Any:
    """``read(store)`` on a consistent copy (in ``tmp``, removed after) of the study ``study``'s
    run store: a live ``latentune paper`` may be writing it."""
    from latentune.pipeline.store import RunStore

    tmp.mkdir(parents=True, exist_ok=True)
    try:
        copy_db(study / "run.db", tmp / "run.db")
        with RunStore(tmp) as st:
            return read(st)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def import_paper(paper_run: Path, root: Path, budget: int) -> list[str]:
    """Write the first ``budget`` target trials of every finished seeded study of the paper
    run ``paper_run`` (``latentune paper --seeds N --out paper_run``) whose row is a rung
    (:data:`PAPER_ROWS`) as this ladder's results, so the two issues share those rollouts.

    A phase-3 study's trace is its zero-shot trial (the source's best θ, trial 1 as in
    ``run``) then its first ``budget - 1`` phase-3 trials; a baseline's is its first ``budget``
    trials (its first θ is the zero-shot θ); ``zero_shot`` is the zero-shot trial alone. The
    source size is the source study's phase-1 + phase-3 trials. A study's target task must be
    the rung's target built from the source's task (else RobotTransferError); studies with
    fewer than ``budget`` trials are skipped, stored results are kept. Returns one line per
    result written."""
    from latentune.constants import Phase
    from latentune.reporting.paper_report import read_paper_meta

    meta = read_paper_meta(paper_run)       # a missing or hand-edited record: one line
    R = meta["robot"]
    every = rungs(ROBOTS)
    done: list[str] = []
    tmp = root / f".import-{os.getpid()}"
    sources: dict[str, tuple[dict[str, Any], int]] = {}
    for key, info in meta.get("studies", {}).items():
        rung_name = PAPER_ROWS.get(str(info.get("row")), "").format(R=R)
        method = PAPER_ARMS.get(str(info.get("arm")))
        if rung_name not in every or method is None or not (paper_run / key / "run.db").is_file():
            continue
        rung = every[rung_name]
        if rung.source not in sources:          # each source store is copied once
            sources[rung.source] = _read_copy(paper_run / rung.source, tmp, lambda st: (
                st.get_meta("config") or {}, st.count(Phase.PHASE1) + st.count(Phase.PHASE3)))
        src_cfg, n_src = sources[rung.source]
        cfg, zs, rows = _read_copy(paper_run / key, tmp, lambda st: (
            st.get_meta("config") or {}, st.rows(Phase.ZERO_SHOT),
            st.rows(Phase.PHASE3) or st.rows(Phase.PHASE1)))
        want = rung.target(src_cfg["task"]).config()
        if cfg.get("task") != want:
            diff = sorted(k for k in set(want) | set(cfg.get("task") or {})
                          if want.get(k) != (cfg.get("task") or {}).get(k))
            raise RobotTransferError(f"{paper_run / key}: its task is not the target of "
                                     f"{rung_name} (differs in {', '.join(diff)})")
        seed = int(info.get("seed_index", 0))
        phase3 = info["kind"] == "phase3"
        if phase3 and not zs:
            continue
        trace = ([zs[0]] + rows[: budget - 1]) if phase3 else rows[:budget]
        items = [(method, trace)] + ([("zero_shot", [zs[0]])] if phase3 else [])
        for m, tr_rows in items:
            if len(tr_rows) < (1 if m == "zero_shot" else budget):
                continue
            f = result_path(root, rung_name, n_src, seed, m)
            if f.is_file():
                continue
            res = {"costs": [float(r.cost) for r in tr_rows],
                   "failed": [bool(r.fell) for r in tr_rows],
                   "thetas": [[float(v) for v in r.theta] for r in tr_rows],
                   "target": rung_name, "source": rung.source,
                   "source_dir": str(paper_run / rung.source), "source_trials": n_src,
                   "seed": seed, "method": m, "budget": budget if m != "zero_shot" else 1,
                   "label": rung.label, "target_config": cfg["task"],
                   "imported": {"paper_run": str(paper_run), "study": key,
                                "arm": info.get("arm"), "study_seed": info.get("seed"),
                                "note": "latentune paper's study (batch of its critic, "
                                        "process pool)" + ("; CMA-ES is latentune's pycma critic"
                                                           if info.get("arm") == "cma" else "")},
                   "wall_s": float(sum(float(r.wall_s or 0.0) for r in tr_rows))}
            f.parent.mkdir(parents=True, exist_ok=True)
            tmpf = f.with_suffix(".tmp")
            tmpf.write_text(json.dumps(res))
            tmpf.replace(f)
            done.append(f"{rung_name} (src {n_src}) seed {seed} {m}: from {key}, best "
                        f"{min(res['costs']):.4g}, falls {sum(res['failed'])}")
    return done


# --------------------------------------------------------------------------- summary
RESULT_GLOB = "*/src*/seed*/*.json"


def _target_key(r: dict[str, Any]) -> dict[str, Any]:
    return {"target": r["target"], "source": r["source"], "source_trials": int(r["source_trials"])}


def _title(row: dict[str, Any]) -> str:
    return f"{row['target']} (source {row['source']}, {row['source_trials']} trials)"


def min_mannwhitney_p(n: int, two_sided: bool) -> float:
    """The smallest p a Mann–Whitney test of n values against n others can give (exact, no
    ties): every value of one sample below every value of the other."""
    return min(1.0, (2.0 if two_sided else 1.0) / math.comb(2 * n, n))


def summarize(root: Path, methods: list[str] | None = None, targets: list[str] | None = None,
              seeds: list[int] | None = None, default: str = "transfer") -> dict[str, Any]:
    """:func:`benchmarks.transfer.summarize` of ``root``'s runs per (rung, source, source size),
    each row with its rung's label, ``beats_zero_shot``: the methods whose best costs are
    below the zero-shot θ's (one-sided Mann–Whitney p < 0.05; a rung where none does is one to
    drop; None with fewer than 4 seeds, where no p can be below 0.05), and ``cost_check`` (:func:`cost_checks`) of its runs. ``methods``, ``targets``,
    ``seeds``: only these runs (default: all); ``default``: the method judged as latentune's
    default (:func:`benchmarks.transfer.summarize`: it reads as ``transfer``, the stored
    ``transfer`` runs as ``transfer@stored``)."""
    from scipy.stats import mannwhitneyu

    try:
        s = tr.summarize(root / "targets", RESULT_GLOB, _target_key, default=default,
                         methods=methods, seeds=seeds)
    except ValueError as e:                 # e.g. no peer among the methods read
        raise RobotTransferError(str(e)) from e
    if targets is not None:
        s["targets"] = [row for row in s["targets"] if row["target"] in targets]
    if not s["targets"]:          # an empty table and exit 0 read as "nothing went wrong"
        raise RobotTransferError(f"no runs under {root / 'targets'}"
                                 + (f" of {', '.join(targets)}" if targets else "")
                                 + (f" by {', '.join(methods)}" if methods else ""))
    every = rungs(ROBOTS)
    for row in s["targets"]:
        row["label"] = every[row["target"]].label if row["target"] in every else row["target"]
        zs = row["methods"].get("zero_shot")
        if zs is None:
            continue
        n = len(row["seeds"])
        if min_mannwhitney_p(n, two_sided=False) >= 0.05:    # no p < 0.05 possible: unknown
            row["beats_zero_shot"] = None
            continue
        beats = []
        for m, r in row["methods"].items():
            if m == "zero_shot":
                continue
            try:
                p = float(mannwhitneyu(r["best"], zs["best"], alternative="less").pvalue)
            except ValueError:
                p = 1.0
            if p < 0.05:
                beats.append(m)
        row["beats_zero_shot"] = beats
    for row in s["targets"]:
        row["cost_check"] = cost_checks(root, list(row["methods"]), [row["target"]],
                                        row["seeds"]).get((row["target"], row["source_trials"]))
    return s


def cost_checks(root: Path, methods: list[str] | None = None, targets: list[str] | None = None,
                seeds: list[int] | None = None) -> dict[tuple[str, int], dict[str, Any]]:
    """Per (rung, source size), over every stored trial under ``root`` (only of ``methods``,
    ``targets`` and ``seeds`` when given): the number of trials, of non-finite costs and of
    falls, the lowest cost of a fall and the highest of a trial that did not fall (a fall's cost
    carries the fall penalty: the two ranges should not meet)."""
    out: dict[tuple[str, int], dict[str, Any]] = {}
    for f in sorted((root / "targets").glob(RESULT_GLOB)):
        if (targets is not None and f.parts[-4] not in targets) or (
                seeds is not None and f.parts[-2] not in {f"seed{s}" for s in seeds}):
            continue
        r = json.loads(f.read_text())
        if methods is not None and r["method"] not in methods:
            continue
        c = np.asarray(r["costs"], dtype=float)
        fell = np.asarray(r["failed"], dtype=bool)
        o = out.setdefault((r["target"], int(r["source_trials"])),
                           {"trials": 0, "non_finite": 0, "falls": 0, "fall_cost_min": None,
                            "standing_cost_max": None})
        o["trials"] += int(c.size)
        o["non_finite"] += int((~np.isfinite(c)).sum())
        o["falls"] += int(fell.sum())
        for k, sel, agg in (("fall_cost_min", fell, min), ("standing_cost_max", ~fell, max)):
            v = c[sel & np.isfinite(c)]
            if v.size:
                o[k] = float(agg(v)) if o[k] is None else float(agg(o[k], agg(v)))
    return out


def _g(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def _cut(c: dict[str, Any] | None) -> str:
    return "-" if c is None else f"{c['median']:.4g} ({c['method']})"


def overview(s: dict[str, Any]) -> str:
    """One line per rung with a judged default: the best peer's median best and falls, the
    default's (with the two-sided Mann–Whitney p against the best peer), the default's median
    above (+) or below (−) the best peer's in percent, the lowest of the peers' median bests
    with each seed cut before its fall one beyond the default's falls on that seed
    (:func:`benchmarks.transfer.best_within_falls`; the peer named), the default's median
    trials to reach the best peer's median, and the transfer issue's criteria (1) no worse,
    (2) ≤ B/10 and ≤ B/2, (3) falls; then how many rungs hold each."""
    rows = [r for r in s["targets"] if "criteria" in r]
    if not rows:
        return ""
    mark = {True: "✓", False: "✗"}
    lines = ["| rung | seeds | best peer: median / falls | default: median (p) / falls | "
             "default vs best peer | lowest peer at the default's falls | trials to its median "
             "| (1) | (2) B/10, B/2 | (3) |",
             "|---|---:|---|---|---:|---:|---:|:-:|:-:|:-:|"]
    for r in rows:
        bp, t, c = r["methods"][r["best_peer"]], r["methods"]["transfer"], r["criteria"]
        rel = 100.0 * (t["median_best"] - bp["median_best"]) / abs(bp["median_best"])
        lines.append(
            f"| {r['target']} | {len(r['seeds'])} | {r['best_peer']}: {bp['median_best']:.4g} / "
            f"{bp['falls_median']:g} | {t['median_best']:.4g} ({c['mannwhitney_p']:.2f}) / "
            f"{t['falls_median']:g} | {rel:+.1f} % | "
            f"{_cut(r.get('peer_at_default_falls'))} | {t['trials_to_best_peer']:g} | "
            f"{mark[c['no_worse']]} | {mark[c['reach_le_B10']]} {mark[c['reach_le_B2']]} | "
            f"{mark[c['falls_ok']]} |")
    n = len(rows)
    held = {k: sum(r["criteria"][k] for r in rows)
            for k in ("no_worse", "reach_le_B10", "reach_le_B2", "falls_ok")}
    lines.append(f"\nOf {n} rungs: (1) no worse on {held['no_worse']}; (2) ≤ B/10 on "
                 f"{held['reach_le_B10']}, ≤ B/2 on {held['reach_le_B2']}; (3) falls on "
                 f"{held['falls_ok']}.")
    few = min(len(r["seeds"]) for r in rows)
    if min_mannwhitney_p(few, two_sided=True) >= 0.05:
        lines.append(f"With {few} seeds no two-sided p is below 0.05: (1) holds on every rung "
                     "whatever the medians.")
    return "\n".join(lines)


def markdown(s: dict[str, Any]) -> str:
    """The overview (:func:`overview`), the summary's tables
    (:func:`benchmarks.transfer.markdown`) and the rungs to drop."""
    md = overview(s) + "\n" + tr.markdown(s, _title)
    for row in s["targets"]:
        c = row.get("cost_check")
        if c:
            md += (f"\n\n{_title(row)}: {c['trials']} trials, {c['non_finite']} non-finite costs, "
                   f"{c['falls']} falls (fall costs ≥ {_g(c['fall_cost_min'])}, standing costs ≤ "
                   f"{_g(c['standing_cost_max'])})")
    flat = [_title(r) for r in s["targets"] if r.get("beats_zero_shot") == []]
    if flat:
        md += "\n\nNo method beats the zero-shot θ (p < 0.05) on: " + "; ".join(flat)
    return md


def decision_stats(run: dict[str, Any], floor: float = 1 / 64) -> dict[str, Any]:
    """What the default phase 3 did in one run, from its decision records (decision ``i`` asked
    trial ``i + 1``; trial 0 is the zero-shot θ): ``n_asks`` (after the initial design),
    ``floor_share``: the share of its trust-region asks (not explore asks) asked at side
    ``length`` ≤ ``floor``; ``screened_share``: the share of asks whose fall screen admitted
    fewer than 5 % of the candidates; ``explore_asks`` and ``explore_falls``; ``falls_by_pool``
    (the pool of each fallen trial's ask: ``elite``, ``full``, ``latent``, or ``explore``);
    ``distinct_acted``: the asks whose choice ``distinct`` changed (``repeats_avoided`` or
    ``duplicates_dropped`` recorded; 0 = the same asks as without the option); ``by_kind``:
    per kind of ask (``design``, a region ask's pool, or ``explore <pool>``) ``[asks, falls,
    records]``, a record being a trial that stood and cost less than every trial before it
    that stood; ``by_screen``: the same per kind and per band of the fall screen's probability
    of the θ asked (``max_fall_prob_asked``; :data:`SCREEN_BANDS`); ``region_steps``: the
    trust-region asks and their falls per band of the step from the centre
    (:func:`benchmarks.transfer_falls.region_steps`; runs with their θ only)."""
    dec = run.get("decisions") or []
    failed = run["failed"]
    costs = run["costs"]
    by_kind: dict[str, list[int]] = {}
    by_screen: dict[str, dict[str, list[int]]] = {}
    best = math.inf if failed[0] else float(costs[0])
    for i, d in enumerate(dec[:len(failed) - 1]):
        fell = bool(failed[i + 1])
        rec = not fell and float(costs[i + 1]) < best
        best = min(best, math.inf if fell else float(costs[i + 1]))
        kind = ask_kind(d)
        band = screen_band(d.get("max_fall_prob_asked"))
        for acc in (by_kind.setdefault(kind, [0, 0, 0]),
                    by_screen.setdefault(kind, {}).setdefault(band, [0, 0, 0])):
            acc[0] += 1
            acc[1] += fell
            acc[2] += rec
    asks = [d for d in dec if not d.get("design")]
    region = [d for d in asks if not d.get("explore")]
    by_pool: dict[str, int] = {}
    for i, d in enumerate(dec):
        if i + 1 < len(failed) and failed[i + 1]:
            pool = "explore" if d.get("explore") else (d.get("pools") or ["?"])[0]
            by_pool[pool] = by_pool.get(pool, 0) + 1
    ex = [i for i, d in enumerate(dec) if d.get("explore")]
    return {
        "n_asks": len(asks),
        "floor_share": float(np.mean([d["length"] <= floor for d in region])) if region else 0.0,
        "screened_share": float(np.mean([d["n_admissible"] < 0.05 * d["n_candidates"]
                                         for d in asks])) if asks else 0.0,
        "explore_asks": len(ex),
        "explore_falls": int(sum(bool(failed[i + 1]) for i in ex if i + 1 < len(failed))),
        "falls_by_pool": by_pool,
        "distinct_acted": sum(bool(d.get("repeats_avoided") or d.get("duplicates_dropped"))
                              for d in dec),
        "by_kind": by_kind, "by_screen": by_screen,
        **({"region_steps": region_steps(run).tolist()} if "thetas" in run else {})}


SCREEN_BANDS = (0.0, 0.1, 0.15, 0.2, 0.3)
"""Lower edges of the bands of the fall screen's probability :func:`decision_stats` counts the
asks in (the last band reaches 1; the default ``max_fall_prob`` is 0.3)."""


def screen_band(p: float | None) -> str:
    """The band (:data:`SCREEN_BANDS`) of the screen's probability ``p``, e.g. ``"0.15–0.2"``;
    ``"?"`` without one."""
    if p is None or not math.isfinite(float(p)):
        return "?"
    edges = (*SCREEN_BANDS, 1.0)
    k = max(band(edges, float(p)), 0)
    return f"{edges[k]:g}–{edges[k + 1]:g}"


TRACE_DROP = ("thetas", "decisions")
"""Fields of a run file that :func:`export_traces` leaves out (the θ of every trial and the
critic's decision records: large, and rebuilt by rerunning the run); the θ of the run's lowest
cost is kept as ``best_theta``."""


def _with_best_theta(r: dict[str, Any]) -> dict[str, Any]:
    """``r`` without :data:`TRACE_DROP`, with ``best_theta``: the θ ((d,) list) of its lowest
    cost (the first such trial), when ``r`` holds its θ or a ``best_theta`` already."""
    out = {k: v for k, v in r.items() if k not in TRACE_DROP}
    thetas = r.get("thetas")
    if thetas and len(thetas) == len(r["costs"]):
        out["best_theta"] = thetas[int(np.argmin(r["costs"]))]
    return out


def export_traces(root: Path, out: Path) -> list[Path]:
    """One JSON per rung under ``out`` (``<rung>.json``): every run under ``root/targets`` with
    its cost and fall per trial, wall time, load, options, source size and the θ of its lowest
    cost, sorted by (source size, seed, method); the θ of the other trials and the decision
    records are left out (:data:`TRACE_DROP`). Returns the files written."""
    by_rung: dict[str, list[dict[str, Any]]] = {}
    for f in sorted((root / "targets").glob(RESULT_GLOB)):
        by_rung.setdefault(f.parts[-4], []).append(_with_best_theta(json.loads(f.read_text())))
    if by_rung:
        out.mkdir(parents=True, exist_ok=True)
    files = []
    for rung, runs in sorted(by_rung.items()):
        runs.sort(key=lambda r: (int(r.get("source_trials", 0)), int(r["seed"]), r["method"]))
        p = out / f"{rung}.json"
        p.write_text(json.dumps({"target": rung, "runs": runs}, separators=(",", ":")) + "\n")
        files.append(p)
    return files


def restore_traces(traces: Path, root: Path) -> tuple[int, int]:
    """Rebuild ``root``'s run files from exported traces (:func:`export_traces`'s
    ``<rung>.json`` files under ``traces``), each marked ``restored_from`` (the trace file) and
    without the dropped fields: ``run`` then resumes where the exported runs stopped, and
    ``summary``, ``compare``, ``export`` and ``plot`` (from ``best_theta``) read them. A run
    file that exists is kept. Returns (files written, files kept)."""
    files = sorted(f for f in traces.glob("*.json") if f.name != "export.json")
    if not files:
        raise RobotTransferError(f"no traces under {traces}")
    wrote = kept = 0
    for f in files:
        d = json.loads(f.read_text())
        if not isinstance(d, dict) or "runs" not in d or "target" not in d:
            raise RobotTransferError(f"{f} is not a trace file of `robot_transfer export`")
        for r in d["runs"]:
            p = result_path(root, d["target"], int(r["source_trials"]), int(r["seed"]),
                            r["method"])
            if p.is_file():
                kept += 1
                continue
            p.parent.mkdir(parents=True, exist_ok=True)
            tmp = p.with_suffix(".tmp")
            tmp.write_text(json.dumps({**r, "restored_from": str(f)}))
            tmp.replace(p)
            wrote += 1
    return wrote, kept


def decisions(root: Path, method: str = "transfer", seeds: list[int] | None = None
              ) -> dict[str, Any]:
    """:func:`decision_stats` of every stored run of ``method`` under ``root`` (only ``seeds``
    when given), per rung and seed, with the medians over the seeds. Runs without decision
    records (restored from traces: :func:`restore_traces`) are left out and counted in
    ``without_records``."""
    out: dict[str, Any] = {"method": method, "targets": {}, "without_records": 0}
    for f in sorted((root / "targets").glob(RESULT_GLOB)):
        r = json.loads(f.read_text())
        if r["method"] != method or (seeds is not None and int(r["seed"]) not in seeds):
            continue
        if "decisions" not in r:
            out["without_records"] += 1
            continue
        t = out["targets"].setdefault(r["target"], {"seeds": {}})
        t["seeds"][int(r["seed"])] = decision_stats(r)
    for t in out["targets"].values():
        rows = list(t["seeds"].values())
        t["median"] = {k: float(np.median([x[k] for x in rows]))
                       for k in ("floor_share", "screened_share", "explore_asks", "explore_falls")}
        t["distinct_acted"] = sum(x.get("distinct_acted", 0) for x in rows)
        pools = sorted({p for x in rows for p in x["falls_by_pool"]})
        t["median"]["falls_by_pool"] = {p: float(np.median([x["falls_by_pool"].get(p, 0)
                                                            for x in rows])) for p in pools}
        t["by_kind"] = _summed([x.get("by_kind", {}) for x in rows])
        t["region_steps"] = _steps_summed([x["region_steps"] for x in rows
                                           if "region_steps" in x])
    out["region_steps"] = _steps_summed([t["region_steps"] for t in out["targets"].values()])
    out["by_kind"] = _summed([t["by_kind"] for t in out["targets"].values()])
    out["by_screen"] = {k: _summed([x.get("by_screen", {}).get(k, {}) for t in
                                    out["targets"].values() for x in t["seeds"].values()])
                        for k in out["by_kind"]}
    return out


def _steps_summed(counts: list[list[list[int]]]) -> list[list[int]]:
    """The sum of ``region_steps`` tables (each one ``[asks, falls]`` per band of
    :data:`benchmarks.transfer_falls.STEP_EDGES`); zeros for none."""
    zero = np.zeros((len(STEP_EDGES) - 1, 2), dtype=int)
    return (zero + np.sum(counts, axis=0, dtype=int) if counts else zero).tolist()


def _summed(counts: list[dict[str, list[int]]]) -> dict[str, list[int]]:
    """Key-wise sums of ``{key: [asks, falls, records]}`` dicts, keys sorted."""
    out: dict[str, list[int]] = {}
    for c in counts:
        for k, v in c.items():
            acc = out.setdefault(k, [0] * len(v))
            for j, x in enumerate(v):
                acc[j] += x
    return dict(sorted(out.items()))


def decisions_markdown(d: dict[str, Any]) -> str:
    lines = ["| rung | seeds | trust-region asks at side ≤ 1/64 | asks the fall screen "
             "admitted < 5 % of | explore asks / their falls | falls by pool | asks `distinct` "
             "changed (all seeds) |",
             "|---|---:|---:|---:|---:|---|---:|"]
    for name, t in d["targets"].items():
        m = t["median"]
        pools = ", ".join(f"{p} {v:g}" for p, v in m["falls_by_pool"].items()) or "none"
        lines.append(f"| {name} | {len(t['seeds'])} | {100 * m['floor_share']:.0f} % | "
                     f"{100 * m['screened_share']:.0f} % | {m['explore_asks']:g} / "
                     f"{m['explore_falls']:g} | {pools} | {t.get('distinct_acted', 0)} |")
    skipped = (f" {d['without_records']} runs without decision records (restored from traces) "
               "are left out." if d.get("without_records") else "")
    kinds = list(d.get("by_kind", {}))
    lines += ["", "Medians over the seeds." + skipped, "",
              "Falls / asks by kind of ask, summed over the seeds:", "",
              "| rung | " + " | ".join(kinds) + " |", "|---|" + "---:|" * len(kinds)]
    for name, t in d["targets"].items():
        bk = t.get("by_kind", {})
        lines.append(f"| {name} | " + " | ".join(
            f"{bk[k][1]} / {bk[k][0]}" if k in bk else "–" for k in kinds) + " |")
    bands = [screen_band(b) for b in SCREEN_BANDS]
    lines += ["", "Every rung and seed: asks, falls and records (a trial that stood and cost "
              "less than every standing trial before it) by kind of ask and by the fall "
              "screen's probability of the θ asked:", "",
              "| kind | all | " + " | ".join(bands) + " |", "|---|---:|" + "---:|" * len(bands)]
    for k in kinds:
        a = d["by_kind"][k]
        sc = d["by_screen"].get(k, {})
        lines.append(f"| {k} | {a[0]}, {a[1]} fell, {a[2]} rec. | " + " | ".join(
            f"{sc[b][0]}, {sc[b][1]}, {sc[b][2]}" if b in sc else "–" for b in bands) + " |")
    steps = [f"{lo:g}–{hi:g}" for lo, hi in zip(STEP_EDGES, STEP_EDGES[1:])]
    lines += ["", "Trust-region asks (falls / asks) by their largest coordinate step from the "
              "best standing θ before them:", "",
              "| rung | " + " | ".join(steps) + " |", "|---|" + "---:|" * len(steps)]
    for name, t in [*d["targets"].items(), ("all", d)]:
        rs = t.get("region_steps") or []
        lines.append(f"| {name} | " + " | ".join(f"{f} / {n}" for n, f in rs) + " |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- plots
def plot_com(results: dict[str, Any], path: Path, title: str) -> None:
    """The base's CoM x, y, z [m] against time [s] of recorded rollouts (label → a result with
    ``cost`` and ``trace`` holding ``t`` (n,) and ``pos`` (n, 3)), one panel per axis."""
    from latentune.reporting.plots import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for label, res in results.items():
        t, pos = res.trace["t"], res.trace["pos"]
        for k, ax in enumerate(axes):
            ax.plot(t, pos[:, k], lw=0.8, label=f"{label} (L = {res.cost:.2f})" if k == 0 else None)
    for ax, name in zip(axes, "xyz"):
        ax.set_ylabel(f"CoM {name} [m]")
    axes[-1].set_xlabel("time [s]")
    axes[0].legend(fontsize=8)
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _best_theta(runs: dict[int, dict[str, Any]]) -> tuple[list[float], float, int, int]:
    """(θ, cost, seed, trial) of the lowest cost over every seed's run of a method: from the
    run's θ per trial, or from its ``best_theta`` (a run restored from traces). Of equal costs
    (the zero-shot θ on every seed) a run that holds its θ is taken."""
    def no_theta(r: dict[str, Any]) -> bool:
        return "thetas" not in r and "best_theta" not in r

    seed, i = min(((s, i) for s, r in runs.items() for i in range(len(r["costs"]))),
                  key=lambda si: (runs[si[0]]["costs"][si[1]], no_theta(runs[si[0]])))
    r = runs[seed]
    theta = r["thetas"][i] if "thetas" in r else r.get("best_theta")
    if theta is None:
        raise RobotTransferError(f"the {r.get('method')} run of {r.get('target')} seed {seed} "
                                 f"holds no θ (rerun it: delete its file and `run` it again)")
    return theta, float(r["costs"][i]), seed, i + 1


def plot_trials(root: Path, out: Path, target: str, method: str, seed: int,
                trials: list[int], gifs: bool = False) -> Path:
    """CoM plots (and GIFs) of the θ of ``trials`` (0-based; 0 is the zero-shot θ) of one run
    (``target``, ``method``, ``seed``) re-simulated, each labelled with its stored outcome and
    the kind of ask that asked it (:func:`ask_kind`); written to
    ``out/<target>/<method>_seed<seed>/``, with ``plot.json`` (θ, stored and re-simulated cost
    and fall, the fall's reason). The falls of a run, seen."""
    from latentune.reporting.plots import plot_rollouts
    from latentune.task import Task

    files = [f for f in sorted((root / "targets" / target).glob("src*/seed*/*.json"))
             if f.parent.name == f"seed{seed}" and f.stem == method]
    if not files:
        raise RobotTransferError(f"no {method} run of {target} seed {seed} under {root}")
    r = json.loads(files[-1].read_text())
    if "thetas" not in r:
        raise RobotTransferError(f"the {method} run of {target} seed {seed} holds no θ per "
                                 "trial (restored from traces: delete its file and `run` it)")
    bad = [t for t in trials if not 0 <= t < len(r["costs"])]
    if bad:
        raise RobotTransferError(f"trials {bad} are not in the run (0 to {len(r['costs']) - 1})")
    dec = r.get("decisions") or []
    task = Task.from_config(r["target_config"])
    d = out / target / f"{method}_seed{seed}"
    d.mkdir(parents=True, exist_ok=True)
    sims: dict[str, Any] = {}
    record: dict[str, Any] = {"target": target, "method": method, "seed": seed, "trials": {}}
    for t in trials:
        kind = "zero-shot" if t == 0 or t - 1 >= len(dec) else ask_kind(dec[t - 1])
        res = task.rollout(np.array(r["thetas"][t]), record=True,
                           gif=str(d / f"trial{t}.gif") if gifs else None)
        sims[f"trial {t}, {kind}, {'fell' if r['failed'][t] else 'stood'}"] = res
        record["trials"][t] = {"kind": kind, "theta": r["thetas"][t], "cost": r["costs"][t],
                               "fell": bool(r["failed"][t]), "resimulated_cost": res.cost,
                               "resimulated_fell": bool(res.fell), "reason": res.reason}
    title = f"{r.get('label', target)}: {method}, seed {seed}"
    plot_com(sims, d / "com_xyz.png", title)
    plot_rollouts(sims, d / "com_velocity.png", v_des=float(task.v_des[0]), title=title)
    (d / "plot.json").write_text(json.dumps(record, indent=1))
    return d


def plot(a: argparse.Namespace) -> None:
    from latentune.reporting.plots import plot_rollouts
    from latentune.task import Task

    root, out = Path(a.root), Path(a.out)
    if a.trials:
        if a.seed is None or not a.methods or len(a.methods) != 1 or not a.targets or \
                len(a.targets) != 1:
            raise RobotTransferError("--trials plots one run: give one --targets, one "
                                     "--methods and --seed")
        d = plot_trials(root, out, a.targets[0], a.methods[0], a.seed, a.trials, a.gifs)
        print(f"{a.targets[0]}: {d}/com_xyz.png, com_velocity.png", flush=True)
        return
    if a.seed is not None:
        raise RobotTransferError("--seed goes with --trials (the best θ is over every seed)")
    default = getattr(a, "default", "transfer")
    summ = summarize(root, getattr(a, "methods", None), default=default)
    names = a.targets or sorted({r["target"] for r in summ["targets"]})
    for name in names:
        rows = [r for r in summ["targets"] if r["target"] == name]
        if not rows:
            raise RobotTransferError(f"no runs of {name} under {root / 'targets'}")
        row = max(rows, key=lambda r: r["source_trials"])
        methods = [m for m in ("transfer", row["best_peer"], "zero_shot") if m in row["methods"]]
        runs: dict[str, dict[int, dict]] = {}
        stored = {"transfer": default, "transfer@stored": "transfer"}   # judged name → file
        for m in dict.fromkeys(methods):
            runs[m] = {s: json.loads(result_path(root, name, row["source_trials"], s,
                                                 stored.get(m, m)).read_text())
                       for s in row["seeds"]}
        task = Task.from_config(next(iter(runs[methods[0]].values()))["target_config"])
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        sims: dict[str, Any] = {}
        record: dict[str, Any] = {"target": name, "source_trials": row["source_trials"],
                                  "best_peer": row["best_peer"], "theta": {}}
        for m in dict.fromkeys(methods):
            theta, cost, seed, trial = _best_theta(runs[m])
            label = "default phase 3" if m == "transfer" else \
                f"best peer ({m})" if m == row["best_peer"] else m
            gif = str(d / f"{m}.gif") if a.gifs else None
            sims[label] = task.rollout(np.array(theta), record=True, gif=gif)
            record["theta"][m] = {"theta": theta, "cost": cost, "seed": seed, "trial": trial,
                                  "resimulated_cost": sims[label].cost}
        title = f"{row['label']}: best θ"
        plot_com(sims, d / "com_xyz.png", title)
        plot_rollouts(sims, d / "com_velocity.png", v_des=float(task.v_des[0]), title=title)
        (d / "plot.json").write_text(json.dumps(record, indent=1))
        print(f"{name}: {d}/com_xyz.png, com_velocity.png", flush=True)


# --------------------------------------------------------------------------- command line
def _int_at_least(text: str, least: int) -> int:
    """``text`` as an integer >= ``least``; argparse's one-line error naming that bound."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < least:
        raise argparse.ArgumentTypeError(f"must be >= {least}, got {v}")
    return v


def _nonneg_int(text: str) -> int:
    """An integer >= 0 (a seed)."""
    return _int_at_least(text, 0)


def _pos_int(text: str) -> int:
    """An integer >= 1 (a count: budget, workers, trials)."""
    return _int_at_least(text, 1)


def parser() -> argparse.ArgumentParser:
    from benchmarks.common import bench_parser, out_dir, out_file
    ap = bench_parser("benchmarks.robot_transfer", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the rungs")
    sn = sub.add_parser("snapshot", help="snapshot sources (a new one when a source has grown)")
    r = sub.add_parser("run", help="run the ladder (resumes)")
    for p in (sn, r):
        p.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS))
        p.add_argument("--paper", default="results/paper10k",
                       help="the directory holding the paper runs <robot>/<robot>-<gait>/")
        p.add_argument("--root", default="runs/robot_transfer")
    sn.add_argument("--sources", nargs="+", default=None,
                    help="source studies (default: every source of the robots' rungs)")
    r.add_argument("--targets", nargs="+", default=None, help="rungs (default: all of the robots)")
    r.add_argument("--methods", nargs="+", choices=tr.METHODS + tr.SCREENED,
                   default=list(tr.METHODS))
    r.add_argument("--seeds", nargs="+", type=_nonneg_int, default=list(range(5)))
    r.add_argument("--budget", type=_pos_int, default=100)
    r.add_argument("--source-trials", type=_pos_int, default=None,
                   help="use the snapshot of this many trials (default: the newest)")
    r.add_argument("--workers", type=_pos_int, default=1)
    r.add_argument("--variants", nargs="+", default=[],
                   help="transfer variants option=value[:option=value], stored as transfer+VARIANT")
    r.add_argument("--reverse", action="store_true",
                   help="run the jobs last first: a second process on the same root then meets "
                        "the first once instead of running the same jobs in step with it")
    im = sub.add_parser("import-paper", help="the seeded rows of a latentune paper run that "
                        "are rungs, as results (no new trial)")
    im.add_argument("--paper-run", required=True,
                    help="a `latentune paper --seeds N` directory (results/paper10k/a1)")
    im.add_argument("--root", default="runs/robot_transfer")
    im.add_argument("--budget", type=_pos_int, default=100)
    s = sub.add_parser("summary", help="the criteria per rung")
    s.add_argument("--root", default="runs/robot_transfer")
    s.add_argument("--out", type=out_file, default=None,
                   help="write the summary to this JSON and its tables to the .md beside it "
                        "(default: print only)")
    s.add_argument("--methods", nargs="+", default=None, help="only these methods' runs")
    s.add_argument("--targets", nargs="+", default=None, help="only these rungs")
    s.add_argument("--seeds", nargs="+", type=_nonneg_int, default=None, help="only these seeds")
    s.add_argument("--default", default="transfer",
                   help="the method judged as the default (its runs read as transfer; the stored "
                        "transfer runs as transfer@stored)")
    c = sub.add_parser("compare", help="methods against methods over (rung, seed): wins, "
                       "ties, losses, sign test, falls")
    c.add_argument("--root", default="runs/robot_transfer")
    c.add_argument("--a", nargs="+", required=True)
    c.add_argument("--b", nargs="+", required=True)
    c.add_argument("--seeds", nargs="+", type=_nonneg_int, default=None, help="only these seeds")
    c.add_argument("--out", type=out_file, default=None, help="a .json")
    ex = sub.add_parser("export", help="the runs' traces (cost and fall per trial, wall "
                        "time, load) as one JSON per rung, to commit")
    ex.add_argument("--root", default="runs/robot_transfer")
    ex.add_argument("--out", type=out_dir, required=True, help="a directory")
    rs = sub.add_parser("restore", help="rebuild the run files from exported traces (without "
                        "the θ of every trial): run then resumes, summary and plot read them")
    rs.add_argument("--traces", required=True, help="a directory of `export`")
    rs.add_argument("--root", default="runs/robot_transfer")
    ct = sub.add_parser("cut", help="the runs METHOD would have made with the transfer "
                        "critic's fall_budget = SHARE: its stored runs cut where the budget is "
                        "spent (benchmarks.transfer.cut_at_fall_budget), stored as --as")
    ct.add_argument("--root", default="runs/robot_transfer")
    ct.add_argument("--method", required=True)
    ct.add_argument("--share", type=float, required=True)
    ct.add_argument("--counts", default="all",
                    help="the critic's fall_budget_counts: all or after_stand")
    ct.add_argument("--as", dest="name", required=True, help="the method name to store them as")
    ct.add_argument("--seeds", nargs="+", type=_nonneg_int, default=None, help="only these seeds")
    dc = sub.add_parser("decisions", help="what the default phase 3 did, from its decision "
                        "records (trust-region floor, fall screen, explore asks, falls by pool)")
    dc.add_argument("--root", default="runs/robot_transfer")
    dc.add_argument("--out", type=out_file, required=True, help="a .json (and a .md beside it)")
    dc.add_argument("--method", default="transfer")
    dc.add_argument("--seeds", nargs="+", type=_nonneg_int, default=None, help="only these seeds")
    pl = sub.add_parser("plot", help="CoM plots of the best θ per rung")
    pl.add_argument("--targets", nargs="+", default=None)
    pl.add_argument("--root", default="runs/robot_transfer")
    pl.add_argument("--out", type=out_dir, default="results/robot_transfer")
    pl.add_argument("--gifs", action="store_true", help="also a GIF of each re-simulated θ")
    pl.add_argument("--default", default="transfer", help="as summary's --default")
    pl.add_argument("--methods", nargs="+", default=None, help="only these methods' runs")
    pl.add_argument("--trials", nargs="+", type=_nonneg_int, default=None,
                    help="plot these trials (0: the zero-shot θ) of one run (one --targets, "
                    "one --methods, --seed) instead of the best θ")
    pl.add_argument("--seed", type=_nonneg_int, default=None, help="the run of --trials")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    a = parser().parse_args(argv)
    from benchmarks.common import error_line
    from latentune.errors import LatentuneError

    try:
        if a.cmd == "list":
            for rung in rungs().values():
                print(f"{rung.name:22s} source {rung.robot}/{rung.source:10s} change "
                      f"{json.dumps(rung.change)}")
        elif a.cmd == "snapshot":
            reg = rungs(a.robots)
            known = {(g.robot, g.source) for g in reg.values()}
            want = a.sources or sorted({s for _, s in known})
            for name in want:
                robot = next((rb for rb, s in known if s == name), None)
                if robot is None:
                    raise RobotTransferError(f"unknown source {name!r} for {', '.join(a.robots)}"
                                             f" (choose from {', '.join(sorted(s for _, s in known))})")
                p = snapshot(Path(a.paper) / robot / name, Path(a.root) / "sources" / name)
                print(f"{name}: {p} ({snapshot_info(p)['n_trials']} trials)", flush=True)
        elif a.cmd == "run":
            run(a)
        elif a.cmd == "import-paper":
            for line in import_paper(Path(a.paper_run), Path(a.root), a.budget):
                print(line, flush=True)
        elif a.cmd == "summary":
            from benchmarks.common import Provenance, write_json

            prov = Provenance(argv, module="benchmarks.robot_transfer")
            res = summarize(Path(a.root), a.methods, a.targets, a.seeds, a.default)
            p = prov.finish()
            md = markdown(res)
            if a.out:
                out = write_json(a.out, res, p)
                out.with_suffix(".md").write_text(f"`{p['command']}`\n{md}\n")
            print(md)
        elif a.cmd == "compare":
            from benchmarks.common import Provenance, write_json

            prov = Provenance(argv, module="benchmarks.robot_transfer")
            try:
                rows = [tr.compare(Path(a.root) / "targets", x, b, a.seeds, RESULT_GLOB)
                        for x in a.a for b in a.b]
            except ValueError as e:     # a damaged run, or two budgets in one pair
                raise RobotTransferError(str(e)) from None
            if not any(r["pairs"] for r in rows):
                raise RobotTransferError(f"no (rung, seed) under {Path(a.root) / 'targets'} "
                                         f"holds both methods of any pair")
            print(tr.compare_text(rows))
            if a.out:
                write_json(a.out, {"rows": rows}, prov.finish())
        elif a.cmd == "export":
            from benchmarks.common import Provenance, write_json

            prov = Provenance(argv, module="benchmarks.robot_transfer")
            files = export_traces(Path(a.root), Path(a.out))
            if not files:
                raise RobotTransferError(f"no runs under {Path(a.root) / 'targets'}")
            write_json(Path(a.out) / "export.json", {"files": [f.name for f in files]},
                       prov.finish())
            print(f"{len(files)} rungs written to {a.out}")
        elif a.cmd == "restore":
            wrote, kept = restore_traces(Path(a.traces), Path(a.root))
            print(f"{wrote} runs restored under {Path(a.root) / 'targets'}, {kept} kept")
        elif a.cmd == "cut":
            try:
                n = tr.cut_runs(Path(a.root), a.method, a.share, a.name, a.seeds, a.counts,
                                pattern="targets/*/src*/seed*")
            except ValueError as e:
                raise RobotTransferError(str(e)) from None
            print(f"{n} runs of {a.method} cut at fall_budget {a.share:g} ({a.counts}), "
                  f"stored as {a.name}")
        elif a.cmd == "decisions":
            from benchmarks.common import Provenance, write_json

            prov = Provenance(argv, module="benchmarks.robot_transfer")
            res = decisions(Path(a.root), a.method, a.seeds)
            if not res["targets"]:
                raise RobotTransferError(f"no runs of {a.method} under {Path(a.root) / 'targets'}")
            p = prov.finish()
            out = write_json(a.out, res, p)
            md = decisions_markdown(res)
            out.with_suffix(".md").write_text(f"`{p['command']}`\n\n{md}\n")
            print(md)
        else:
            plot(a)
    except (RobotTransferError, LatentuneError, OSError) as exc:
        error_line("benchmarks.robot_transfer", exc)
        return 2
    return 0


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.robot_transfer"))
