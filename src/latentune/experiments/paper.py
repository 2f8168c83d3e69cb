"""``latentune paper``: the paper's studies (Sarmadi et al., Tables II/III, transfer, preservation)
plus baselines, as resumable run directories under one ``--out DIR``.

Studies (each one a run directory ``DIR/<key>`` holding its own ``run.db``)
--------------------------------------------------------------------------
For the robot R (a1: convex MPC, solo12: kino-dynamic MPC) and each gait g in (trot, jump):

``R-g``             manual θ (phase 0), phase 1 (TuRBO-m on θ, ``phase1`` evals, flat),
                    phase 2 (VAE on the stable phase-1 θ), phase 3 on flat (``phase3`` evals)
``R-g-hills``       phase 3 on Perlin hills with the VAE of ``R-g`` (trained on flat)
``R-g-cross``       phase 3 on flat with the VAE of the *other* gait (cross-task)
``R-g-turbo|cma|random``  baselines in the full θ space at the phase-3 budget, same seed
``b1-g-transfer``   (a1 only) phase 3 on B1 with the VAE of ``a1-trot`` (A1 → B1 transfer)
``R-trot-preservation``  a separate TuRBO-m run on θ (seed + 1, ``preservation`` evals, never
                    used for training); each of its stable θ is passed through the encoder and
                    decoder of ``R-trot``'s VAE and rolled out again (store phase 5, idx = the
                    source row's idx). Rate = stable after encode→decode / stable before.

Seeds (``--seeds N``, seed indices i = 0..N-1; run directory = seed 0's key + ``-s<i>`` for i > 0)
------------------------------------------------------------------------------------------------
The sources — ``R-g``'s phase 1 and VAE, and the preservation run — are run once (seed 0), as the
paper does; every seed reuses them. Per seed index i, with the study seed ``--seed + i`` and the
same target tasks (task seed ``--seed``, so hills are the same terrain for every seed):

``R-g-flat-s<i>``, ``R-g-hills-s<i>``, ``R-g-cross-s<i>``, ``b1-g-transfer-s<i>``  the paper's
                    plain phase 3 (i > 0; seed 0's are the studies above)
``<same stems>-default[-s<i>]``  latentune's default phase 3 (``strategy="transfer"``) beside it
``R-g-<m>[-s<i>]``  baselines on θ from the manual θ: m = turbo, cma, random (latentune's
                    critics; seed 0's are the studies above), tpe (Optuna's multivariate TPE),
                    cmaes-src (Optuna's CMA-ES with ``R-g``'s trials as ``source_trials``)
``R-g-cross-<m>[-s<i>]``, ``b1-g-transfer-<m>[-s<i>]``  baselines on the cross-task and the
                    cross-robot target from the zero-shot θ (the source run's best θ), m =
                    turbo, cma, tpe, cmaes-src (the source run's trials as ``source_trials``)

The Optuna baselines need the ``optuna`` extra; without it they are skipped with a warning.
Each study records its comparison (``row``) and method (``arm``) in ``paper.json``; the report
gives median and interquartile range over the seeds in every cell, and best-so-far curves with
bands.

Budget scale
------------
``--scale S`` maps to (``budgets``; recorded in ``DIR/paper.json`` and the report)::

    phase1       = max(12, round(10000 · S))             # the paper: 10000 at S = 1
    phase3       = max(8,  round(220 · min(1, S**0.25))) # the paper: 220 at S = 1
    preservation = max(12, round(phase1 / 2))            # the separate TuRBO-m run
    baselines    = phase3

The fourth root keeps phase 3 meaningful at small scales (S = 0.03 → 300 / 92 / 150) while the
phase-1 budget, the expensive one, scales linearly. ``--phase1-evals`` / ``--phase3-evals``
override the mapping (also recorded).

``--sources-only`` runs only the phase-1 runs of ``R-g`` (and of ``R-trot-preservation``): the
long sources of every other study, in the layout a later full ``latentune paper`` resumes.

Order (``_priority``): the sources; phase 3 (plain and default) on flat jump, flat trot and
trot → jump over every seed; the baselines on jump, trot → jump and A1 → B1 jump; the other
phase-3 rows; the preservation run (its encode → decode check answers the paper's
preservation claim; its phase-1 run is a source); the other baselines last (no claim rests on
them).

Resume: every study is a pipeline run; re-running the same command skips finished studies and
resumes unfinished ones from their stored rows (the pipeline's ``run_phase`` resume). All
studies share one evaluator (process pool of ``--workers``).

Parallel: more ``latentune paper`` processes with the same options may run on the same ``--out``
(one machine, or several sharing the directory), or ``--studies KEY …`` to run chosen studies
(e.g. the preservation run beside the rest). A study another process is writing is skipped
with a warning (its store is locked), so the processes share the plan's studies;
``paper.json`` keeps every invocation's record. Run the command once more when they are done:
it finishes any study skipped there.
"""
from __future__ import annotations

import json
import logging
import math
import os
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from latentune.checks import file_in_the_way
from latentune.constants import GAITS, PAPER_PHASE1, PAPER_PHASE3, Phase
from latentune.errors import LockError, UsageError
from latentune.machine import loadavg, machine
from latentune.reporting.paper_report import ARMS, read_paper_meta

logger = logging.getLogger(__name__)

MIN_PHASE1 = 12
MIN_PHASE3 = 8
MIN_PRESERVATION = 12
BASELINES = ("turbo", "cma", "random")
ROBOT_ACTOR = {"a1": "convex", "solo12": "kinodynamic"}
MAPPING_DOC = ("phase1 = max(12, round(10000*S)); phase3 = max(8, round(220*min(1, S**0.25))); "
               "preservation = max(12, round(phase1/2)); baselines = phase3")


def budgets(scale: float, phase1: int | None = None, phase3: int | None = None) -> dict[str, Any]:
    """The evaluation budgets of a scale (see the module docstring)."""
    s = float(scale)
    if not math.isfinite(s) or s <= 0 or not math.isfinite(PAPER_PHASE1 * s):
        raise UsageError(f"--scale must be a finite number > 0 (a finite budget), got {scale}")
    p1 = max(MIN_PHASE1, int(round(PAPER_PHASE1 * s))) if phase1 is None else int(phase1)
    p3 = max(MIN_PHASE3, int(round(PAPER_PHASE3 * min(1.0, s ** 0.25)))) if phase3 is None \
        else int(phase3)
    for flag, v in (("--phase1-evals", p1), ("--phase3-evals", p3)):
        if v < 1:
            raise UsageError(f"{flag} must be >= 1, got {v}")
    pres = max(MIN_PRESERVATION, int(round(p1 / 2)))
    return {"scale": s, "phase1": p1, "phase3": p3, "preservation": pres, "baselines": p3,
            "mapping": MAPPING_DOC, "overridden": {"phase1": phase1 is not None,
                                                   "phase3": phase3 is not None}}


@dataclass
class StudyPlan:
    key: str                  # run directory name under DIR
    kind: str                 # tune | phase3 | baseline | preservation
    robot: str
    gait: str
    terrain: str = "flat"
    vae_from: str | None = None   # key of the study whose VAE phase 3 uses
    method: str = "turbo"     # turbo | cma | random (latentune) | tpe | cmaes-src (Optuna)
    budget: int = 0
    seed_offset: int = 0      # the task's seed: DIR's --seed + seed_offset
    label: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    strategy: str = "plain"   # phase 3: plain (the paper's) | transfer (latentune's default)
    source: str | None = None     # baselines: the run whose trials cmaes-src starts from
    start: str = "manual"     # baselines: manual (the task's manual θ) | source (source's best θ)
    seed_index: int = 0       # the study's seed: DIR's --seed + seed_offset + seed_index
    row: str | None = None    # the seeded comparison this study is one seed of
    arm: str | None = None    # its method in that comparison (paper_report.ARMS)


OPTUNA_METHODS = {"tpe": "optuna-tpe", "cmaes-src": "optuna-cmaes"}
"""Baselines run by Optuna's samplers (their :meth:`Study.phase1 <latentune.study.Study.phase1>`
methods)."""
OWN_BASELINES = ("turbo", "cma", "random", "tpe", "cmaes-src")
"""On a study's own task, from the manual θ (cmaes-src: the task's phase-1 trials)."""
CROSS_BASELINES = ("turbo", "cma", "tpe", "cmaes-src")
"""On a cross-task / cross-robot target, from the zero-shot θ (the source run's best;
cmaes-src: the source run's trials)."""


def _sfx(i: int) -> str:
    return "" if i == 0 else f"-s{i}"


def plan(robot: str, b: dict[str, Any], seeds: int = 1) -> list[StudyPlan]:
    """The studies of ``latentune paper --robot R --seeds N`` in execution order (``_priority``):
    the sources, then the phase-3 rows that answer the paper's claims over every seed, their
    baselines, the other rows, the preservation run, and the other baselines last; seed-major
    within each tier.

    Seed index i > 0 repeats phase 3 (both strategies) and the baselines with the study seed
    ``--seed + i`` on the same source runs (``R-g``, their VAEs) and the same target tasks;
    its run directories are seed 0's key + ``-s<i>``."""
    R = robot
    other = {"trot": "jump", "jump": "trot"}
    st: list[StudyPlan] = []
    for g in GAITS:
        st.append(StudyPlan(f"{R}-{g}", "tune", R, g, budget=b["phase1"],
                            label=f"{R} {g}: manual, phase 1, VAE, phase 3 (flat)",
                            row=g, arm="phase3-plain"))
    for g in GAITS:
        st.append(StudyPlan(f"{R}-{g}-hills", "phase3", R, g, "hills", vae_from=f"{R}-{g}",
                            budget=b["phase3"], label=f"{R} {g}: phase 3 on hills ({g} VAE, flat)",
                            row=f"{g}-hills", arm="phase3-plain"))
    for g in GAITS:
        st.append(StudyPlan(f"{R}-{g}-cross", "phase3", R, g, vae_from=f"{R}-{other[g]}",
                            budget=b["phase3"], label=f"{R} {g}: phase 3 with the {other[g]} VAE",
                            row=f"{g}-cross", arm="phase3-plain"))
    if R == "a1":
        for g in GAITS:
            st.append(StudyPlan(f"b1-{g}-transfer", "phase3", "b1", g, vae_from="a1-trot",
                                budget=b["phase3"], label=f"B1 {g}: phase 3 with the A1 trot VAE",
                                row=f"b1-{g}", arm="phase3-plain"))
    st.append(StudyPlan(f"{R}-trot-preservation", "preservation", R, "trot", vae_from=f"{R}-trot",
                        budget=b["preservation"], seed_offset=1,
                        label=f"{R} trot: separate TuRBO-m run (seed+1) → encode/decode"))
    for g in GAITS:
        for m in BASELINES:
            st.append(StudyPlan(f"{R}-{g}-{m}", "baseline", R, g, method=m, budget=b["baselines"],
                                label=f"{R} {g}: {m} on θ at the phase-3 budget", row=g, arm=m))
    for i in range(seeds):
        st += _seeded(R, b, i)
    return sorted(st, key=_priority)     # stable: seed-major within a tier


CLAIM_ROWS = ("jump", "trot", "jump-cross")
"""The rows that answer the paper's claims (phase 3 at 220 against phase 1 at 10,000; the trot
space finding a jump); their phase-3 arms run over every seed before anything else."""
BASELINE_ROWS = ("jump", "jump-cross", "b1-jump")
"""The rows whose baselines come next (the issue's "baselines on jump, trot → jump, A1 → B1
jump")."""


def _priority(s: StudyPlan) -> int:
    """Execution tier: sources (0), phase 3 on the claim rows (1), their baselines (2), the
    other phase-3 rows (3), the preservation run (4), the other baselines (5)."""
    if s.kind == "tune":
        return 0
    if s.kind == "phase3":
        return 1 if s.row in CLAIM_ROWS else 3
    if s.kind == "baseline":
        return 2 if s.row in BASELINE_ROWS else 5
    return 4


def _seeded(R: str, b: dict[str, Any], i: int) -> list[StudyPlan]:
    """Seed index ``i``'s phase-3 rows (plain for i > 0; the transfer strategy for every i)
    and baselines, jump first (the paper's claims are about jump)."""
    other = {"trot": "jump", "jump": "trot"}
    sx, B = _sfx(i), b["phase3"]
    targets = []        # (row, key stem, robot, gait, terrain, vae/source)
    for g in ("jump", "trot"):
        targets += [(g, f"{R}-{g}-flat", R, g, "flat", f"{R}-{g}"),
                    (f"{g}-hills", f"{R}-{g}-hills", R, g, "hills", f"{R}-{g}"),
                    (f"{g}-cross", f"{R}-{g}-cross", R, g, "flat", f"{R}-{other[g]}")]
        if R == "a1":
            targets.append((f"b1-{g}", f"b1-{g}-transfer", "b1", g, "flat", "a1-trot"))
    st: list[StudyPlan] = []
    seed_txt = f" (seed +{i})" if i else ""
    for row, stem, robot, g, terrain, src in targets:
        if i > 0:
            st.append(StudyPlan(f"{stem}{sx}", "phase3", robot, g, terrain, vae_from=src, budget=B,
                                seed_index=i, row=row, arm="phase3-plain",
                                label=f"{robot} {g} {terrain}: plain phase 3, {src} VAE{seed_txt}"))
        st.append(StudyPlan(f"{stem}-default{sx}", "phase3", robot, g, terrain, vae_from=src,
                            budget=B, seed_index=i, row=row, arm="phase3-transfer",
                            strategy="transfer",
                            label=f"{robot} {g} {terrain}: default phase 3 (transfer), {src} "
                                  f"source{seed_txt}"))
    for row, stem, robot, g, terrain, src in targets:
        if terrain != "flat":
            continue
        own = row == g
        for m in (OWN_BASELINES if own else CROSS_BASELINES):
            if own and i == 0 and m in BASELINES:
                continue                     # seed 0's are the paper layout's R-g-<m>
            key = f"{R}-{g}-{m}{sx}" if own else f"{stem}-{m}{sx}"
            start = "manual θ" if own else f"{src}'s best θ"
            st.append(StudyPlan(key, "baseline", robot, g, method=m, budget=B, seed_index=i,
                                source=src if (m == "cmaes-src" or not own) else None,
                                start="manual" if own else "source", row=row, arm=m,
                                label=f"{robot} {g}: {ARMS[m]} from the {start}{seed_txt}"))
    return st


# ---------------------------------------------------------------------------- running
@dataclass
class PaperOptions:
    """The options of ``latentune paper`` (see the module docstring)."""

    robot: str = "a1"
    actor: str | None = None
    scale: float = 0.03
    phase1: int | None = None
    phase3: int | None = None
    out: str = "paper-a1"
    workers: int = 2
    seed: int = 0
    steps: int = 5000
    v_des: float = 0.5
    quiet: bool = False
    sources_only: bool = False   # only the phase-1 runs (the sources): R-g and R-trot-preservation
    seeds: int = 1               # phase 3, transfer rows and baselines over seed indices 0..N-1
    studies: tuple[str, ...] = ()  # only these studies of the plan (keys; default: all)
    progress: bool = False       # progress bars (never with quiet)
    vae_epochs: int | None = None  # the sources' VAE training epochs (None: ~2000 Adam steps)


def _done(out: Path, plan_: StudyPlan, b: dict[str, Any]) -> bool:
    from latentune.pipeline.store import RunStore

    if not (out / "run.db").is_file():
        return False
    with RunStore(out) as st:
        if plan_.kind == "tune":
            return st.count(Phase.PHASE1) >= b["phase1"] and st.count(Phase.PHASE3) >= b["phase3"] \
                and st.artifact("vae") is not None
        if plan_.kind == "phase3":
            return st.count(Phase.PHASE3) >= plan_.budget
        if plan_.kind == "baseline":
            return st.count(Phase.PHASE1) >= plan_.budget
        pres = st.get_meta("preservation") or {}
        return st.count(Phase.PHASE1) >= plan_.budget and pres.get("complete", False) and \
            pres.get("n_phase1") == st.count(Phase.PHASE1)


def _start(root: Path, plan_: StudyPlan) -> Any:
    """A baseline's first θ: ``"manual"``, or the zero-shot θ of its row: the θ of the zero-shot
    trial stored by the row's phase-3 study (the source's best when that study ran; the source
    may improve later, by its own phase 3), else the source's best now. A resumed baseline
    keeps its stored start."""
    if plan_.start == "manual":
        return "manual"
    from latentune.pipeline.store import RunStore
    from latentune.study import Study, source_best

    if (root / plan_.key / "run.db").is_file():
        with Study(root / plan_.key) as done:
            stored = (done.config().get("phase1") or {}).get("start")
        if isinstance(stored, list):
            return np.asarray(stored, dtype=float)
    stem = root / plan_.key[: plan_.key.rindex(f"-{plan_.method}")]
    if (stem / "run.db").is_file():
        with RunStore(stem) as st:
            zs = st.rows(Phase.ZERO_SHOT)
        if zs:
            return zs[0].theta

    best = source_best(root / str(plan_.source))
    if best is None:
        raise UsageError(f"{root / str(plan_.source)} holds no trial: run its study first")
    return best.theta


def run_study(plan_: StudyPlan, opts: PaperOptions, root: Path, b: dict[str, Any], evaluator: Any,
              log: Any) -> None:
    """Run (or resume) one planned study as a :class:`~latentune.study.Study` under ``root``."""
    from latentune.study import Study
    from latentune.task import Task

    out = root / plan_.key
    if opts.sources_only:
        if plan_.kind not in ("tune", "preservation"):
            return
        with_phase1 = StudyPlan(plan_.key, "baseline", plan_.robot, plan_.gait, plan_.terrain,
                                method=plan_.method, seed_offset=plan_.seed_offset,
                                budget=b["phase1"] if plan_.kind == "tune" else plan_.budget,
                                label=f"{plan_.label} (phase-1 source only)")
        plan_ = with_phase1
    if _done(out, plan_, b):
        log(f"[{plan_.key}] done (skipped)")
        return
    if plan_.method in OPTUNA_METHODS:
        try:
            import optuna  # noqa: F401
        except ImportError:
            logger.warning("[%s] skipped: Optuna is not installed (pip install "
                           "'latentune[optuna]')", plan_.key)
            return
    log(f"[{plan_.key}] {plan_.label}")
    seed = opts.seed + plan_.seed_offset        # the task's: the same target for every seed
    task = Task(robot=plan_.robot, gait=plan_.gait, terrain=plan_.terrain, actor=opts.actor,
                v_des=opts.v_des, steps=opts.steps, seed=seed)
    study = Study(out, seed=seed + plan_.seed_index, workers=opts.workers,
                  progress=opts.progress and not opts.quiet, log=None if opts.quiet else log,
                  evaluator=evaluator)
    try:
        if plan_.kind == "tune":
            study.phase1(task, b["phase1"], method=plan_.method)
            study.train_latent(epochs=opts.vae_epochs)
            study.phase3(task, b["phase3"], method=plan_.method, strategy="plain")
        elif plan_.kind == "phase3":
            study.phase3(task, plan_.budget, latent=root / plan_.vae_from,
                         strategy=plan_.strategy,
                         **({"method": plan_.method} if plan_.strategy == "plain" else {}))
        elif plan_.kind == "baseline":
            start = _start(root, plan_)
            study.phase1(task, plan_.budget, method=OPTUNA_METHODS.get(plan_.method,
                                                                      plan_.method),
                         start=start, source_run=None if plan_.method != "cmaes-src"
                         else root / str(plan_.source))
        elif plan_.kind == "preservation":
            study.phase1(task, plan_.budget, method=plan_.method)
            res = study.preservation(task, root / plan_.vae_from)
            log(f"[{plan_.key}] preservation: {res['n_kept']}/{res['n_stable']} stay stable")
        study.summary()
    finally:
        study.close()


def _config_differences(meta: dict[str, Any], opts: PaperOptions) -> list[str]:
    """What a resume of the paper run recorded in ``meta`` (paper.json) gives otherwise than
    the run: ``"--steps 60 there, 5000 here"`` per differing option (robot, actor, steps,
    seed, v_des, VAE epochs; a record without v_des, from before it was kept, is not
    compared on it)."""
    out = []
    for flag, key, given in (("--robot", "robot", opts.robot), ("--actor", "actor", opts.actor),
                             ("--steps", "steps", opts.steps), ("--seed", "seed", opts.seed),
                             ("--v-des", "v_des", opts.v_des),
                             ("--vae-epochs", "vae_epochs", opts.vae_epochs)):
        stored = meta.get(key)
        if key == "v_des" and stored is None:
            continue
        if stored != given:
            out.append(f"{flag} {'default' if stored is None else stored} there, "
                       f"{'default' if given is None else given} here")
    return out


def _check_out(out: Path) -> None:
    """Create the --out directory; UsageError (one line) where it cannot be: a file there or
    among its parents is named as such."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        blocking = file_in_the_way(out.parent)
        why = f"{blocking} is a file, not a directory" if blocking is not None \
            else exc.strerror or exc
        raise UsageError(f"cannot create --out {out}: {why}") from None
    if not out.is_dir():
        raise UsageError(f"--out {out} is not a directory")
    probe = out / ".latentune-write-test"
    try:
        probe.write_text("x")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"--out {out} is not writable: {exc.strerror or exc}") from None


def validate(opts: PaperOptions) -> dict[str, Any]:
    """Check the options (fills the default actor); return the budgets."""
    if opts.robot not in ROBOT_ACTOR:
        raise UsageError(f"unknown robot {opts.robot!r} for the paper's studies (choose from a1, solo12)")
    if opts.actor is None:
        opts.actor = ROBOT_ACTOR[opts.robot]
    b = budgets(opts.scale, opts.phase1, opts.phase3)
    for name, v in (("workers", opts.workers), ("steps", opts.steps)):
        if v < 1:
            raise UsageError(f"--{name} must be >= 1, got {v}")
    from latentune.pipeline.evaluators import check_workers

    check_workers(opts.workers)
    if opts.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {opts.seed}")
    if opts.vae_epochs is not None and opts.vae_epochs < 1:
        raise UsageError(f"--vae-epochs must be >= 1, got {opts.vae_epochs}")
    if not math.isfinite(opts.v_des):
        raise UsageError(f"--v-des must be finite, got {opts.v_des}")
    if isinstance(opts.seeds, bool) or not isinstance(opts.seeds, int) or opts.seeds < 1:
        raise UsageError(f"--seeds must be an integer >= 1, got {opts.seeds!r}")
    if opts.sources_only and opts.seeds > 1:
        raise UsageError("--seeds does not apply to --sources-only: the sources are run once "
                         "(seed 0) and shared by every seed")
    return b


def command_line(opts: PaperOptions, report_only: bool = False) -> str:
    """The ``latentune paper`` command that reproduces a run (recorded in paper.json); the
    output directory quoted for a shell where it needs it."""
    parts = ["latentune paper", f"--robot {opts.robot}", f"--scale {opts.scale:g}",
             f"--out {shlex.quote(str(opts.out))}", f"--workers {opts.workers}", f"--seed {opts.seed}",
             f"--steps {opts.steps}"]
    if opts.phase1 is not None:
        parts.append(f"--phase1-evals {opts.phase1}")
    if opts.phase3 is not None:
        parts.append(f"--phase3-evals {opts.phase3}")
    if opts.seeds > 1:
        parts.append(f"--seeds {opts.seeds}")
    if opts.vae_epochs is not None:
        parts.append(f"--vae-epochs {opts.vae_epochs}")
    if opts.sources_only:
        parts.append("--sources-only")
    if opts.studies:
        parts.append("--studies " + " ".join(opts.studies))
    if report_only:
        parts.append("--report-only")
    return " ".join(parts)


def _check_tasks(opts: PaperOptions, studies: list[StudyPlan]) -> None:
    """Build the task of every planned study, so that an option a task refuses (``--actor``,
    ``--v-des``, ``--steps``, ``--seed``) stops the command before paper.json is written.

    Raises:
        UsageError: the task's one-line message.
    """
    from latentune.task import Task

    for robot, gait, terrain, seed in sorted({(s.robot, s.gait, s.terrain, opts.seed + s.seed_offset)
                                              for s in studies}):
        Task(robot=robot, gait=gait, terrain=terrain, actor=opts.actor, v_des=opts.v_des,
             steps=opts.steps, seed=seed)


def _check_report_only(opts: PaperOptions) -> None:
    """``--report-only`` reports the runs stored in ``--out``: an option left at its default
    takes the stored value, one given must be the stored one (it cannot change the report).

    Raises:
        UsageError: no paper run in ``--out``, or an option that does not describe it.
    """
    if opts.studies:
        raise UsageError("--studies does not apply to --report-only: the report covers every "
                         "study of the run")
    if opts.sources_only:
        raise UsageError("--sources-only does not apply to --report-only: the report covers "
                         "every study of the run")
    root = Path(opts.out)
    if not (root / "paper.json").is_file():     # checked before anything is made in --out
        raise UsageError(f"{root} holds no paper run (no paper.json): run latentune paper first")
    meta = read_paper_meta(root)
    b, default = meta["budgets"], PaperOptions()
    stored = {"robot": meta["robot"], "actor": meta.get("actor"), "steps": meta.get("steps"),
              "seed": meta.get("seed"), "workers": meta.get("workers"),
              "v_des": meta.get("v_des"), "seeds": meta.get("seeds", 1),
              "vae_epochs": meta.get("vae_epochs"), "scale": b["scale"],
              "phase1": b["phase1"], "phase3": b["phase3"]}
    for name, value in stored.items():
        given = getattr(opts, name)
        if given != getattr(default, name) and given != value:
            flag = {"phase1": "phase1-evals", "phase3": "phase3-evals"}.get(name, name.replace("_", "-"))
            raise UsageError(f"--{flag} {given}: {root} holds a paper run with {value} "
                             "(--report-only reports the stored runs; leave the option out)")


def _record_invocation(meta_path: Path, meta: dict[str, Any], mine: dict[str, Any]) -> None:
    """Write ``paper.json`` with this invocation's record ``mine`` (its wall time) into the
    invocations on disk now: another ``latentune paper`` process on the same directory may have
    added its own since this one started."""
    try:
        disk = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError):
        disk = meta
    inv = [i for i in disk.get("invocations", [])
           if (i.get("started"), i.get("pid")) != (mine["started"], mine["pid"])]
    disk = {**meta, "invocations": sorted(inv + [mine], key=lambda i: str(i.get("started")))}
    disk["wall_s_total"] = sum(float(i.get("wall_s") or 0) for i in disk["invocations"])
    meta_path.write_text(json.dumps(disk, indent=1))


def run_paper(opts: PaperOptions, report_only: bool = False, simulate: bool = True,
              gifs: bool = True) -> str:
    """Run (or resume) every study of the plan under ``opts.out``, then write the paper report;
    return its text."""
    from latentune.pipeline.evaluators import make_evaluator
    from latentune.reporting.paper_report import write_paper_report

    def log(msg: str) -> None:
        if not opts.quiet:
            logger.info("%s", msg)

    if report_only:
        _check_report_only(opts)
        return write_paper_report(opts.out, simulate=simulate, gifs=gifs, log=log)
    b = validate(opts)
    studies = plan(opts.robot, b, opts.seeds)
    unknown = sorted(set(opts.studies) - {s.key for s in studies})
    if unknown:
        raise UsageError(f"--studies: {', '.join(unknown)} not in this plan (see the report's "
                         f"Studies list, or paper.json)")
    _check_tasks(opts, studies)     # before --out is made or paper.json written
    root = Path(opts.out)
    _check_out(root)
    meta_path = root / "paper.json"
    meta: dict[str, Any] = read_paper_meta(root) if meta_path.is_file() else {}
    differ = _config_differences(meta, opts) if meta else []
    if differ:
        raise UsageError(f"{root} holds a paper run of another configuration: "
                         f"{'; '.join(differ)} (give the stored values to resume it, or "
                         "another --out)")
    t0 = time.perf_counter()
    meta.update({"format": "latentune-paper", "robot": opts.robot, "actor": opts.actor,
                 "steps": opts.steps, "seed": opts.seed, "v_des": opts.v_des,
                 "workers": opts.workers, "budgets": b, "command": command_line(opts),
                 "seeds": opts.seeds, "vae_epochs": opts.vae_epochs,
                 "studies": {s.key: {"kind": s.kind, "robot": s.robot, "gait": s.gait,
                                     "terrain": s.terrain, "vae_from": s.vae_from,
                                     "method": s.method, "budget": s.budget,
                                     "seed": opts.seed + s.seed_offset + s.seed_index,
                                     "task_seed": opts.seed + s.seed_offset,
                                     "label": s.label, "strategy": s.strategy,
                                     "start": s.start, "source": s.source,
                                     "seed_index": s.seed_index, "row": s.row,
                                     "arm": s.arm}
                             for s in studies}})
    meta.setdefault("invocations", [])
    mine = {"started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "command": command_line(opts), "pid": os.getpid(), "wall_s": None,
            "machine": machine(), "loadavg_start": loadavg()}
    meta["invocations"].append(mine)
    try:
        ev = make_evaluator("process", opts.workers)
    except (RuntimeError, ValueError, OSError) as exc:
        raise UsageError(f"cannot start the evaluator: {exc}") from None
    try:
        meta_path.write_text(json.dumps(meta, indent=1))   # only once every check passed
        for s in studies:
            if opts.studies and s.key not in opts.studies:
                continue
            try:
                run_study(s, opts, root, b, ev, log)
            except LockError as exc:     # another `paper` process on this --out has it
                logger.warning("[%s] skipped: %s; run the command again once it is done",
                               s.key, exc)
    finally:
        ev.close()
        mine["wall_s"] = time.perf_counter() - t0
        mine["loadavg_end"] = loadavg()
        _record_invocation(meta_path, meta, mine)
    if opts.sources_only:
        return f"sources of {root} done (phase 1 only; run without --sources-only for the rest)"
    return write_paper_report(root, simulate=simulate, gifs=gifs, log=log)
