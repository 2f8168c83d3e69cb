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

Resume: every study is a pipeline run; re-running the same command skips finished studies and
resumes unfinished ones from their stored rows (the pipeline's ``run_phase`` resume). All
studies share one evaluator (process pool of ``--workers``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

PAPER_PHASE1 = 10000
PAPER_PHASE3 = 220
MIN_PHASE1 = 12
MIN_PHASE3 = 8
MIN_PRESERVATION = 12
PHASE_PRESERVATION = 5
GAITS = ("trot", "jump")
BASELINES = ("turbo", "cma", "random")
ROBOT_ACTOR = {"a1": "convex", "solo12": "kinodynamic"}
MAPPING_DOC = ("phase1 = max(12, round(10000*S)); phase3 = max(8, round(220*min(1, S**0.25))); "
               "preservation = max(12, round(phase1/2)); baselines = phase3")


def _err(msg: str):
    from latentune.pipeline.commands import _err as perr

    return perr(msg)


def budgets(scale: float, phase1: int | None = None, phase3: int | None = None) -> dict[str, Any]:
    """The evaluation budgets of a scale (see the module docstring)."""
    s = float(scale)
    if not math.isfinite(s) or s <= 0:
        raise ValueError(f"--scale must be a finite number > 0, got {scale}")
    p1 = max(MIN_PHASE1, int(round(PAPER_PHASE1 * s))) if phase1 is None else int(phase1)
    p3 = max(MIN_PHASE3, int(round(PAPER_PHASE3 * min(1.0, s ** 0.25)))) if phase3 is None \
        else int(phase3)
    if p1 < 1 or p3 < 1:
        raise ValueError("budgets must be >= 1")
    pres = max(MIN_PRESERVATION, int(round(p1 / 2)))
    return {"scale": s, "phase1": p1, "phase3": p3, "preservation": pres, "baselines": p3,
            "mapping": MAPPING_DOC, "overridden": {"phase1": phase1 is not None,
                                                   "phase3": phase3 is not None}}


@dataclass
class Study:
    key: str                  # run directory name under DIR
    kind: str                 # tune | phase3 | baseline | preservation
    robot: str
    gait: str
    terrain: str = "flat"
    vae_from: str | None = None   # key of the study whose VAE phase 3 uses
    method: str = "turbo"
    budget: int = 0
    seed_offset: int = 0
    label: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def plan(robot: str, b: dict[str, Any]) -> list[Study]:
    """The studies of ``latentune paper --robot R`` in execution order."""
    R = robot
    other = {"trot": "jump", "jump": "trot"}
    st: list[Study] = []
    for g in GAITS:
        st.append(Study(f"{R}-{g}", "tune", R, g, budget=b["phase1"],
                        label=f"{R} {g}: manual, phase 1, VAE, phase 3 (flat)"))
    for g in GAITS:
        st.append(Study(f"{R}-{g}-hills", "phase3", R, g, "hills", vae_from=f"{R}-{g}",
                        budget=b["phase3"], label=f"{R} {g}: phase 3 on hills ({g} VAE, flat)"))
    for g in GAITS:
        st.append(Study(f"{R}-{g}-cross", "phase3", R, g, vae_from=f"{R}-{other[g]}",
                        budget=b["phase3"], label=f"{R} {g}: phase 3 with the {other[g]} VAE"))
    if R == "a1":
        for g in GAITS:
            st.append(Study(f"b1-{g}-transfer", "phase3", "b1", g, vae_from="a1-trot",
                            budget=b["phase3"], label=f"B1 {g}: phase 3 with the A1 trot VAE"))
    st.append(Study(f"{R}-trot-preservation", "preservation", R, "trot", vae_from=f"{R}-trot",
                    budget=b["preservation"], seed_offset=1,
                    label=f"{R} trot: separate TuRBO-m run (seed+1) → encode/decode"))
    for g in GAITS:
        for m in BASELINES:
            st.append(Study(f"{R}-{g}-{m}", "baseline", R, g, method=m, budget=b["baselines"],
                            label=f"{R} {g}: {m} on θ at the phase-3 budget"))
    return st


# ---------------------------------------------------------------------------- running
def _sub_args(base: argparse.Namespace, study: Study, out: Path, b: dict[str, Any]) -> argparse.Namespace:
    """A Namespace with every flag of the pipeline's run commands (their defaults), set for a study."""
    from latentune.pipeline.commands import _add_run_args

    p = argparse.ArgumentParser(add_help=False)
    _add_run_args(p, "phase3")
    ns = p.parse_args(["--out", str(out)])
    ns.robot = study.robot
    ns.task = study.gait
    ns.terrain = study.terrain
    ns.actor = base.actor
    ns.steps = base.steps
    ns.v_des = base.v_des
    ns.seed = base.seed + study.seed_offset
    ns.workers = base.workers
    ns.backend = "process"
    ns.quiet = base.quiet
    ns.method = study.method
    if study.kind == "tune":
        ns.phase1_evals, ns.phase3_evals = b["phase1"], b["phase3"]
    elif study.kind == "phase3":
        ns.phase1_evals, ns.phase3_evals = 1, study.budget
    else:  # baseline, preservation: a phase-1-style run
        ns.phase1_evals, ns.phase3_evals = study.budget, 1
    ns.resume = (out / "run.db").is_file()
    ns.vae = None
    return ns


def _done(out: Path, study: Study, b: dict[str, Any]) -> bool:
    from latentune.pipeline.store import RunStore

    if not (out / "run.db").is_file():
        return False
    with RunStore(out) as st:
        if study.kind == "tune":
            return st.count(1) >= b["phase1"] and st.count(3) >= b["phase3"] and \
                st.artifact("vae") is not None
        if study.kind == "phase3":
            return st.count(3) >= study.budget
        if study.kind == "baseline":
            return st.count(1) >= study.budget
        pres = st.get_meta("preservation") or {}
        return st.count(1) >= study.budget and pres.get("complete", False) and \
            pres.get("n_phase1") == st.count(1)


def run_study(study: Study, base: argparse.Namespace, root: Path, b: dict[str, Any], ev,
              log) -> None:
    from latentune.pipeline import commands as pc
    from latentune.report import write_summary

    out = root / study.key
    if _done(out, study, b):
        log(f"[{study.key}] done (skipped)")
        return
    log(f"[{study.key}] {study.label}")
    args = _sub_args(base, study, out, b)
    run = pc._Run(args, need_store=False)
    if study.kind == "tune":
        run.open_store()
        pc._guarded(pc._phase1, run, ev)
        pc._train_vae(run, force=False)
        latent = pc._latent_for_phase3(run, None)
        pc._guarded(pc._phase3, run, ev, latent)
    elif study.kind == "phase3":
        vdir = str(root / study.vae_from)
        pc._precheck_vae(run, vdir)
        run.open_store()
        latent = pc._latent_for_phase3(run, vdir)
        pc._guarded(pc._phase3, run, ev, latent)
    elif study.kind == "baseline":
        run.open_store()
        pc._guarded(pc._phase1, run, ev)
    elif study.kind == "preservation":
        run.open_store()
        pc._guarded(pc._phase1, run, ev)
        _preservation(run, root / study.vae_from, ev, log)
    write_summary(run.store)
    run.store.close()


def _preservation(run, vae_run: Path, ev, log) -> None:
    """Encode→decode every stable θ of this run with ``vae_run``'s VAE and roll the result out."""
    from latentune.latent.vae import LatentSpace
    from latentune.pipeline.phases import C1, PHASE1
    from latentune.pipeline.store import RunStore

    st = run.store
    with RunStore(vae_run) as other:
        src = other.artifact("vae")
    if src is None:
        raise _err(f"{vae_run}: no VAE to test the preservation rate with")
    latent = LatentSpace.load(src)
    rows = [r for r in st.rows(PHASE1) if r.cost < C1]
    done = {r.idx for r in st.rows(PHASE_PRESERVATION)}
    todo = [r for r in rows if r.idx not in done]
    t = time.perf_counter()
    if todo:
        rec = latent.reconstruct(np.array([r.theta for r in todo]))
        rec = np.clip(rec, 0.0, 1.0)
        for i, res in ev.imap(run.task, rec):
            st.add(PHASE_PRESERVATION, todo[i].idx, rec[i], float(res["cost"]),
                   z=todo[i].theta, tag=-1, fell=res.get("fell"),
                   fall_step=res.get("fall_step"), wall_s=res.get("wall_s"), seed=run.args.seed)
    run.add_wall("preservation_rollouts", time.perf_counter() - t)
    after = st.costs(PHASE_PRESERVATION)
    st.set_meta("preservation", {"vae_source": str(Path(vae_run).resolve()),
                                 "vae_file": str(src), "n_phase1": st.count(PHASE1),
                                 "n_stable": len(rows), "n_kept": int(np.sum(after < C1)),
                                 "complete": True,
                                 "rows": "phase 5: theta = decoded θ, z = the original θ, "
                                         "idx = the source phase-1 idx"})
    log(f"[{run.out.name}] preservation: {int(np.sum(after < C1))}/{len(rows)} stay stable")


def _check_out(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _err(f"cannot create --out {out}: {exc.strerror or exc}") from None
    if not out.is_dir():
        raise _err(f"--out {out} is not a directory")
    probe = out / ".latentune-write-test"
    try:
        probe.write_text("x")
        probe.unlink()
    except OSError as exc:
        raise _err(f"--out {out} is not writable: {exc.strerror or exc}") from None


def validate(args: argparse.Namespace) -> dict[str, Any]:
    robot = str(args.robot).lower()
    if robot not in ROBOT_ACTOR:
        raise _err(f"unknown robot {args.robot!r} for the paper's studies (choose from a1, solo12)")
    args.robot = robot
    if args.actor is None:
        args.actor = ROBOT_ACTOR[robot]
    try:
        b = budgets(args.scale, args.phase1_evals, args.phase3_evals)
    except (ValueError, TypeError) as exc:
        raise _err(str(exc)) from None
    if args.workers < 1:
        raise _err(f"--workers must be >= 1, got {args.workers}")
    if args.steps < 1:
        raise _err(f"--steps must be >= 1, got {args.steps}")
    if args.seed < 0:
        raise _err(f"--seed must be >= 0, got {args.seed}")
    if not math.isfinite(args.v_des):
        raise _err(f"--v-des must be finite, got {args.v_des}")
    return b


def command_line(args: argparse.Namespace, report_only: bool = False) -> str:
    parts = ["latentune paper", f"--robot {args.robot}", f"--scale {args.scale:g}",
             f"--out {args.out}", f"--workers {args.workers}", f"--seed {args.seed}",
             f"--steps {args.steps}"]
    if args.phase1_evals is not None:
        parts.append(f"--phase1-evals {args.phase1_evals}")
    if args.phase3_evals is not None:
        parts.append(f"--phase3-evals {args.phase3_evals}")
    if report_only:
        parts.append("--report-only")
    return " ".join(parts)


def cmd_paper(args: argparse.Namespace) -> int:
    from latentune.pipeline.evaluators import make_evaluator

    b = validate(args)
    root = Path(args.out)
    _check_out(root)
    meta_path = root / "paper.json"
    meta: dict[str, Any] = {}
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise _err(f"{meta_path} is unreadable ({exc})") from None
        if meta.get("robot") != args.robot or meta.get("actor") != args.actor or \
                meta.get("steps") != args.steps or meta.get("seed") != args.seed:
            raise _err(f"{root} holds a paper run of another configuration (robot "
                       f"{meta.get('robot')}, actor {meta.get('actor')}, steps "
                       f"{meta.get('steps')}, seed {meta.get('seed')})")

    def log(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    studies = plan(args.robot, b)
    if not args.report_only:
        t0 = time.perf_counter()
        meta.update({"format": "latentune-paper", "robot": args.robot, "actor": args.actor,
                     "steps": args.steps, "seed": args.seed, "v_des": args.v_des,
                     "workers": args.workers, "budgets": b, "command": command_line(args),
                     "studies": {s.key: {"kind": s.kind, "robot": s.robot, "gait": s.gait,
                                         "terrain": s.terrain, "vae_from": s.vae_from,
                                         "method": s.method, "budget": s.budget,
                                         "seed": args.seed + s.seed_offset, "label": s.label}
                                 for s in studies}})
        meta.setdefault("invocations", [])
        meta["invocations"].append({"started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                                    "command": command_line(args), "wall_s": None})
        meta_path.write_text(json.dumps(meta, indent=1))
        try:
            ev = make_evaluator("process", args.workers)
        except (RuntimeError, ValueError, OSError) as exc:
            raise _err(f"cannot start the evaluator: {exc}") from None
        try:
            for s in studies:
                run_study(s, args, root, b, ev, log)
        finally:
            ev.close()
            meta["invocations"][-1]["wall_s"] = time.perf_counter() - t0
            meta["wall_s_total"] = sum(float(i.get("wall_s") or 0) for i in meta["invocations"])
            meta_path.write_text(json.dumps(meta, indent=1))
    elif not meta_path.is_file():
        raise _err(f"{root} holds no paper run (no paper.json): run latentune paper first")
    from latentune.experiments.report import write_paper_report

    text = write_paper_report(root, simulate=not args.no_sim, gifs=not args.no_gif, log=log)
    if not args.quiet:
        print(text)
    return 0
