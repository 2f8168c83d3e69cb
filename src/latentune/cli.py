"""Command line: ``latentune rollout | tune | phase1 | train-vae | phase3 | report | ask | tell |
release | best | status | import-optuna | dashboard | robot check | robot init | paper | bench``.

Every command parses its flags and calls the public API (:class:`latentune.Study`,
:class:`latentune.Task`, :func:`latentune.system.load_system`, the paper studies); no logic
lives here. Bad input exits with status 2 and one line on stderr (``latentune: error: …``).

Diagnostics: the library logs through :mod:`logging` (loggers ``latentune.…``); the command line
shows them on stderr as one line each (``latentune: message``; warnings and Python
:mod:`warnings` as ``latentune: warning: message``): warnings by default, informational lines
with ``-v/--verbose``, errors only with ``--quiet``. Progress bars are drawn only when stderr
is a terminal. Exit status: 0 done, 2 bad input or a failure reported in one line, 130
interrupted, 143 terminated (SIGTERM), 141 stdout closed early (``latentune ask --json | head``).
An interrupt after the command printed its result (while it closes its run, or while the process
exits) leaves the command's status.
"""
from __future__ import annotations

import argparse
import errno
import json
import logging
import math
import os
import re
import shlex
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from latentune import argtypes
from latentune.checks import file_in_the_way
from latentune.errors import CLIError, LatentError, LatentuneError, StoreError, UsageError
from latentune.wording import FLAGS, counted
from latentune.workdone import is_done, work_done

DESCRIPTION = ("Tune the weights of a controller: phase 1 on the full θ of a cheap system, phase 2 "
               "a latent space of its stable θ, phase 3 on the target (see README.md).")
DEFAULT_PHASE1 = 400
DEFAULT_PHASE3 = 220
DEFAULT_WORKERS = 2
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO})
"""OSError numbers reported as one line (a full or read-only disk), not as a bug."""

log = logging.getLogger(__name__)


class _HelpFormatter(argparse.HelpFormatter):
    """Appends ``(default X)`` to an option's help unless it has no default (None, False) or
    its help already names the default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        h = action.help or ""
        d = action.default
        if (d is None or d is False or d is argparse.SUPPRESS or d == [] or "default" in h
                or not action.option_strings):
            return h
        return f"{h} (default %(default)s)" if h else "(default %(default)s)"


_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$",
                              re.IGNORECASE)
"""What argparse takes for a negative number rather than a flag (:class:`_Parser`)."""


class _Parser(argparse.ArgumentParser):
    """No abbreviated flags (``--phase1-eval`` is not ``--phase1-evals``); errors as one line;
    a negative number in any notation (``--cost -1.5e-3``, ``-inf``) is a value, not a flag
    (Python 3.11's argparse takes only ``-2`` and ``-2.5`` for numbers)."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        kw.setdefault("allow_abbrev", False)
        kw.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*a, **kw)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message: str) -> None:  # one line, exit 2 (argparse prints usage otherwise)
        raise CLIError(message)


def _verbosity_parser() -> argparse.ArgumentParser:
    """``-v/--verbose`` and ``--quiet``, shared by every command."""
    p = _Parser(add_help=False)
    g = p.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="store_true",
                   help="also show informational lines (what each phase did)")
    g.add_argument("--quiet", action="store_true",
                   help="errors only: no progress bar, warnings or informational lines")
    return p


def _progress(args: argparse.Namespace) -> bool:
    """Progress bars: only on a terminal, never with --quiet."""
    return not getattr(args, "quiet", False) and _isatty(sys.stderr)


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _positive(name: str, v: Any, low: int = 1) -> None:
    if v is not None and v < low:
        raise CLIError(f"--{name} must be >= {low}, got {v}")


def check_limits(args: argparse.Namespace) -> None:
    """CLIError naming the flag for a --steps or --workers beyond what a Task or an evaluator
    takes (:data:`~latentune.task.MAX_STEPS`, :data:`~latentune.pipeline.evaluators.
    MAX_WORKERS`); either flag absent or None passes."""
    from latentune.pipeline.evaluators import MAX_WORKERS
    from latentune.task import MAX_STEPS

    steps, workers = getattr(args, "steps", None), getattr(args, "workers", None)
    if steps is not None and steps > MAX_STEPS:
        raise CLIError(f"--steps must be at most {MAX_STEPS:,} (10,000 s at 1 kHz), got {steps}")
    if workers is not None and workers > MAX_WORKERS:
        raise CLIError(f"--workers must be at most {MAX_WORKERS} (one process or Ray actor "
                       f"each), got {workers}")


# ---------------------------------------------------------------------------- systems
def add_system_args(p: argparse.ArgumentParser) -> None:
    """The flags that choose the system: a built-in task, or ``--system module:factory``."""
    p.add_argument("--robot", help="a1 (default), b1, solo12 or a robot spec .yaml")
    p.add_argument("--task", help="gait: trot (default) or jump")
    p.add_argument("--terrain", help="flat (default) or hills")
    p.add_argument("--actor", help="convex (default) or kinodynamic")
    p.add_argument("--steps", type=int, help="rollout horizon in 1 kHz steps (default 5000)")
    p.add_argument("--v-des", type=float, help="desired forward velocity [m/s] (default 0.5)")
    p.add_argument("--reality", default=None, metavar="PRESET|FILE",
                   help="perturb the simulated robot: nominal, heavy, worn, slippery, laggy, hard "
                        "or a YAML profile (default none)")
    p.add_argument("--engine", choices=("pybullet", "mujoco"), default=None,
                   help="physics engine (default pybullet)")
    p.add_argument("--system", default=None, metavar="MODULE:FACTORY",
                   help="tune your own system: FACTORY(**system-args) returns it (see README)")
    p.add_argument("--system-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="an argument of the --system factory (repeatable; 1e-3, 2.5: floats; "
                        "other values YAML-typed)")


def _task_given(args: argparse.Namespace) -> bool:
    return any(getattr(args, k, None) is not None
               for k in ("robot", "task", "terrain", "actor", "steps", "v_des", "reality",
                         "engine"))


def check_system_flags(args: argparse.Namespace) -> None:
    """Refuse a built-in task's flags beside ``--system``, and ``--system-arg`` without it."""
    if args.system is not None and _task_given(args):
        raise CLIError("--system replaces --robot/--task/--terrain/--actor/--steps/--v-des/"
                       "--reality/--engine")
    if args.system is None and args.system_arg:
        raise CLIError("--system-arg needs --system")


def make_system(args: argparse.Namespace, seed: int = 0) -> Any:
    """The system of the flags: ``--system`` (a plugin) or the built-in task."""
    from latentune.system import load_system, parse_system_args

    check_system_flags(args)
    if args.system is not None:
        return load_system(args.system, parse_system_args(args.system_arg))
    return make_task(args, seed)


def check_v_des(v_des: float | None) -> None:
    """CLIError naming --v-des unless it is None (the default) or a finite velocity a Task
    takes (:data:`~latentune.task.MAX_V_DES`)."""
    from latentune.task import MAX_V_DES

    if v_des is not None and not math.isfinite(v_des):
        raise CLIError(f"--v-des must be finite, got {v_des}")
    if v_des is not None and abs(v_des) > MAX_V_DES:
        raise CLIError(f"--v-des must be a velocity of at most {MAX_V_DES:g} m/s in size, got "
                       f"{v_des:g}")


def make_task(args: argparse.Namespace, seed: int = 0) -> Any:
    from latentune.task import Task

    for flag in ("robot", "task", "terrain", "actor", "reality"):
        v = getattr(args, flag, None)
        if v is not None and not str(v).strip():
            raise CLIError(f"--{flag} is empty; leave it out for the default")
    _positive("steps", args.steps)
    check_limits(args)
    check_v_des(args.v_des)
    try:
        return Task(robot="a1" if args.robot is None else args.robot,
                    gait="trot" if args.task is None else args.task,
                    terrain="flat" if args.terrain is None else args.terrain,
                    actor="convex" if args.actor is None else args.actor,
                    v_des=0.5 if args.v_des is None else args.v_des,
                    steps=5000 if args.steps is None else args.steps, seed=seed,
                    reality=getattr(args, "reality", None),
                    engine=getattr(args, "engine", None) or "pybullet")
    except (ValueError, TypeError) as exc:
        raise CLIError(str(exc)) from None


# ---------------------------------------------------------------------------- rollout
def _check_output_file(flag: str, path: str, exts: tuple[str, ...]) -> None:
    """CLIError naming ``flag`` unless ``path`` is a file name ending in one of ``exts`` that
    can be written (tried by opening it for appending; a file that was not there is removed)."""
    if not path.strip():
        raise CLIError(f"{flag} is empty: give a file name, or leave {flag} out")
    parent = os.path.dirname(os.path.abspath(path))
    blocker = file_in_the_way(parent)
    if blocker is not None:
        raise CLIError(f"{flag} {path}: {blocker} is a file, not a directory")
    if not os.path.isdir(parent):
        raise CLIError(f"{flag} {path}: directory {parent} does not exist (create it first)")
    if os.path.isdir(path):
        raise CLIError(f"{flag} {path} is a directory: give a file name in it")
    if not path.lower().endswith(exts):
        raise CLIError(f"{flag} {path}: the file name must end in {' or '.join(exts)}")
    existed = os.path.exists(path)
    try:
        with open(path, "ab"):
            pass
        if not existed:
            os.remove(path)
    except OSError as exc:
        raise CLIError(f"{flag} {path} cannot be written ({exc.strerror})") from None


def cmd_rollout(args: argparse.Namespace) -> int:
    if args.system is not None or args.system_arg:
        return _rollout_system(args)
    task = make_task(args, 0 if args.seed is None else args.seed)
    if args.seed is not None and task.terrain != "hills" and not task.reality.is_random:
        raise CLIError("--seed changes nothing here: it seeds the hills (--terrain hills) and a "
                       "--reality's sensor noise and pushes; leave it out")
    theta = task.space.load(args.params) if args.params else task.space.manual
    for flag, path, exts in (("--gif", args.gif, (".gif",)),
                             ("--plot", args.plot, (".png", ".pdf", ".svg"))):
        if path is not None:
            _check_output_file(flag, path, exts)
    res = task.rollout(theta, record=bool(args.plot), gif=args.gif)
    where = ", ".join([task.terrain, task.actor, task.engine]
                      + ([] if task.reality.is_nominal else [f"reality {task.reality.name}"]))
    if args.plot:
        from latentune.reporting.plots import plot_rollouts

        plot_rollouts({"rollout": res}, args.plot, v_des=float(task.v_des[0]),
                      title=f"{task.robot_name} {task.gait} ({where})")
    # the rollout's fields (``steps`` executed, ``horizon`` planned), then the task's others
    cfg = {k: v for k, v in task.config().items() if k not in ("spec", "steps")}
    out = {"cost": res.cost, "fell": res.fell, **res.info(task.steps), "wall_s": res.wall_s,
           **cfg}
    if args.json:
        print(json.dumps(out))
    else:
        state = f"FELL at step {res.fall_step} ({res.reason})" if res.fell else "stable"
        window = min(res.steps, 3000) / 1000      # mean_vx's window: the last 3 s at 1 kHz
        print(f"{task.robot_name} {task.gait} ({where}): cost {res.cost:.3f}, "
              f"{state}, mean vx (last {window:g} s) {res.mean_vx:.3f} m/s, "
              f"height {res.mean_height:.3f} m, "
              f"{counted(res.steps, 'step')} in {res.wall_s:.2f} s")
    return 0


def _rollout_system(args: argparse.Namespace) -> int:
    """``rollout --system``: one trial of the user system at --params (default its manual θ)."""
    from latentune.system import evaluate, plugin_record

    for flag, v in (("--seed", args.seed), ("--gif", args.gif), ("--plot", args.plot)):
        if v is not None:
            raise CLIError(f"{flag} is for a built-in robot; a --system rollout takes --params "
                           "and --json (its options are --system-arg)")
    from latentune.pipeline.manifest import describe, tuned_for

    system = make_system(args)
    theta = system.space.load(args.params, tuned_for(describe(system))) if args.params \
        else system.space.manual
    out = evaluate(system, theta)
    plugin = plugin_record(system) or {}
    res = {"system": args.system, "system_args": plugin.get("args", {}), "cost": out.cost,
           "fell": out.failed, "failed": out.failed, "fall_step": out.fall_step,
           "wall_s": out.wall_s, "params": system.space.as_dict(theta), "info": out.info}
    if args.json:
        print(json.dumps(res, default=str))
    else:
        state = "FAILED" if out.failed else "did not fail"
        print(f"{args.system}: cost {out.cost:.6g}, {state}, {out.wall_s:.2f} s")
    return 0


# ---------------------------------------------------------------------------- the phases
def add_run_args(p: argparse.ArgumentParser, name: str) -> None:
    """The flags of ``tune``, ``phase1``, ``train-vae`` and ``phase3``."""
    from latentune.latent.vae import DEFAULT_KIND, KINDS

    add_system_args(p)
    p.add_argument("--seed", type=argtypes.seed, default=None,
                   help="seed (terrain, critic, VAE); default: the run's stored one, else 0")
    p.add_argument("--out", required=True, type=argtypes.run_dir,
                   help="run directory (holds run.db and artifacts)")
    p.add_argument("--phase1-evals", type=int, default=None,
                   help=f"phase-1 evaluations (default: the run's stored budget, else "
                        f"{DEFAULT_PHASE1}; the paper: 10000)")
    p.add_argument("--phase3-evals", type=int, default=None,
                   help=f"phase-3 evaluations (default: the run's stored budget, else "
                        f"{DEFAULT_PHASE3})")
    p.add_argument("--latent-dim", type=int, default=None,
                   help="latent size d_low (default 10 for 25-dim θ, 5 for 77-dim, else "
                        "d/4 between 2 and 10, below d)")
    p.add_argument("--vae-kind", choices=KINDS, default=DEFAULT_KIND,
                   help="autoencoder kind (see latentune.latent.vae)")
    p.add_argument("--vae-epochs", type=int, default=None,
                   help="VAE training epochs (default: ~2000 Adam steps, at least 100 epochs)")
    p.add_argument("--workers", type=int, default=None,
                   help=f"parallel rollouts (default {DEFAULT_WORKERS}), only 1 with --backend "
                        "serial (its default)")
    p.add_argument("--backend", choices=("serial", "process", "ray"), default="process",
                   help="evaluator: serial, a local process pool or ray")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local Ray)",
                   type=argtypes.given("--ray-address", "the cluster head's HOST:PORT"))
    if name != "train-vae":
        p.add_argument("--trial-timeout", type=float, default=None, metavar="S",
                       help="stop a trial that runs longer than S seconds (its worker process "
                            "is killed) and store it as failed; --backend process only; "
                            "default: the run's stored one, else no limit")
    p.add_argument("--method", choices=("turbo", "cma", "random", "sobol"), default=None,
                   help="critic (turbo = TuRBO-m, the default; a resume keeps the stored one)")
    p.add_argument("--regions", type=int, default=None,
                   help="TuRBO-m trust regions (default: ~1 per 500 evaluations, between 1 and 10, "
                        "of the first budget; a resume keeps the stored regions)")
    p.add_argument("--batch-size", type=int, default=None,
                   help="critic batch size (default max(workers, 4))")
    p.add_argument("--max-fall-prob", type=float, default=None, metavar="P",
                   help="fall-aware critic: skip candidates whose predicted probability of "
                        "failing exceeds P in (0, 1], and (TuRBO-m) start near the warm start "
                        "and shrink the trust region when more than P of a batch falls "
                        "(default off, but 0.3 in the transfer phase 3; phase 3 learns it "
                        "from the latent space's source run)")
    if name in ("tune", "phase3"):
        _handover_arg(p)
        _strategy_arg(p)
        _transfer_args(p)
    if name == "train-vae":
        p.add_argument("--space", default=None, metavar="FILE",
                       help="for a run of trials run elsewhere (ask --space) or an Optuna "
                            "import: its YAML/JSON parameter space (default: the stored one)")
    if name == "phase1":
        p.add_argument("--fall-prior", default=None, metavar="RUN_DIR",
                       type=argtypes.other_run("--fall-prior"),
                       help="with --max-fall-prob: a run whose phase-1 trials seed the prediction")
    p.add_argument("--resume", action="store_true",
                   help="keep the latent space already trained in --out (without it, train-vae "
                        "trains it again)" if name == "train-vae" else
                        "continue the run stored in --out")
    if name == "phase3":
        p.add_argument("--vae", default=None, metavar="RUN_DIR", type=argtypes.other_run("--vae"),
                       help="use the latent space of another run (same θ); its best θ is also "
                            "run as it is here (zero-shot baseline)")


def _handover_arg(p: argparse.ArgumentParser) -> None:
    from latentune.critic.handover import HANDOVER_DEFAULTS

    opts = ",".join(f"{k}={v:g}" for k, v in HANDOVER_DEFAULTS.items())
    p.add_argument("--handover", nargs="?", const="on", default=None, metavar="OPTS",
                   help="phase 3 hands over to TuRBO-m on the full θ once the latent search "
                        f"stalls; OPTS = {opts} (any of them; default these)")


def _handover(args: argparse.Namespace) -> Any:
    """--handover [OPTS] as Study.phase3's ``handover`` argument (None, True or a dict)."""
    v = getattr(args, "handover", None)
    if v is None:
        return None
    if v == "on":
        return True
    from latentune.critic.handover import HANDOVER_DEFAULTS
    from latentune.pipeline.phases import handover_options

    out: dict[str, Any] = {}
    texts: dict[str, str] = {}
    for part in v.split(","):
        key, sep, val = part.partition("=")
        key = key.strip()
        if not sep or key not in HANDOVER_DEFAULTS:
            raise CLIError(f"--handover {v}: expected "
                           + ",".join(f"{k}=X" for k in HANDOVER_DEFAULTS))
        if key in texts:        # the later one would win without a word
            raise CLIError(f"--handover {v}: {key} given twice ({texts[key].strip()}, "
                           f"{val.strip()})")
        texts[key] = val
        try:
            out[key] = type(HANDOVER_DEFAULTS[key])(val)    # int patience, float tol, length
        except ValueError:
            kind = "an integer" if isinstance(HANDOVER_DEFAULTS[key], int) else "a number"
            raise CLIError(f"--handover {v}: {key} must be {kind}, got {val!r}") from None

    try:
        handover_options(out)
    except ValueError as exc:
        raise CLIError(f"--handover {v}: {exc}") from None
    return out


def _study(args: argparse.Namespace):
    """The Study of a run command, its flags checked (nothing is run or written here)."""
    from latentune.study import Study

    check_system_flags(args)
    for flag in ("phase1_evals", "phase3_evals", "workers", "vae_epochs", "latent_dim",
                 "batch_size"):
        _positive(flag.replace("_", "-"), getattr(args, flag, None))
    check_limits(args)
    if args.regions is not None and not 1 <= args.regions <= 100:
        raise CLIError(f"--regions must be in [1, 100], got {args.regions}")
    if args.ray_address and args.backend != "ray":
        raise CLIError("--ray-address needs --backend ray")
    mfp = args.max_fall_prob
    if mfp is not None and not 0.0 < mfp <= 1.0:          # nan fails too
        raise CLIError(f"--max-fall-prob must be in (0, 1], got {mfp}")
    if getattr(args, "fall_prior", None) is not None:
        if mfp is None:
            raise CLIError("--fall-prior needs --max-fall-prob (it seeds the fall prediction)")
        if not (Path(args.fall_prior) / "run.db").is_file():
            raise CLIError(f"--fall-prior: no run store in {args.fall_prior}")
    from latentune.pipeline.evaluators import check_timeout, check_workers

    try:                                # the one check Study makes, with the flag's name
        timeout = check_timeout(getattr(args, "trial_timeout", None))
    except UsageError:
        raise CLIError(f"--trial-timeout must be a number of seconds > 0, got "
                       f"{args.trial_timeout}") from None
    if timeout is not None and args.backend != "process":
        raise CLIError(f"--trial-timeout {timeout:g} needs --backend process: {args.backend} "
                       "cannot stop a trial")
    workers = args.workers if args.workers is not None \
        else 1 if args.backend == "serial" else DEFAULT_WORKERS
    if args.backend == "serial" and check_workers(workers) > 1:
        raise CLIError(f"--workers {workers} needs --backend process or ray: serial runs one "
                       "trial at a time, in this process")
    try:
        return Study(args.out, seed=args.seed, workers=workers, backend=args.backend,
                     ray_address=args.ray_address, batch_size=args.batch_size,
                     progress=_progress(args), log=logging.getLogger("latentune.study").info,
                     trial_timeout=timeout)
    except StoreError as exc:                  # another seed than the stored one
        raise CLIError(stored_flags(str(exc))) from None


def _stored_plugin_flags(run: Any) -> list[str]:
    """:func:`plugin_flags` of the run at ``run`` when it holds a run of a --system plugin,
    else none (read from its stored config; nothing is imported)."""
    from latentune.pipeline.manifest import plugin_flags
    from latentune.study import Study

    try:
        desc = Study(run).config().get("system") or {} if (Path(run) / "run.db").is_file() else {}
    except LatentuneError:
        return []
    return plugin_flags(desc) if desc.get("kind") == "plugin" else []


def _check_stored_system(study: Any, args: argparse.Namespace) -> None:
    """Refuse, in one line saying what to pass, a run directory whose stored system is not the
    kind the flags describe (read from the stored config; nothing is imported). A study that
    holds no trial may take another system (:meth:`Manifest.holds_trials`)."""
    from latentune.pipeline.manifest import plugin_flags

    if not study.exists or not study.manifest.holds_trials():
        return
    desc = study.config().get("system") or {}
    kind = desc.get("kind")
    if kind == "plugin" and args.system is None:
        raise CLIError(f"{study.dir} holds a run of the user system {desc.get('target')}: pass "
                       + " ".join(plugin_flags(desc)))
    if kind == "external":
        raise CLIError(f"{study.dir} holds trials run elsewhere (ask --space): no system here "
                       f"runs its trials; go on with latentune ask {shlex.quote(str(study.dir))}"
                       ", or use it as the source of a phase 3 in another directory (--vae "
                       f"{shlex.quote(str(study.dir))})")
    if kind == "optuna":
        raise CLIError(f"{study.dir} holds an imported Optuna study (import-optuna): no system "
                       "here runs its trials; use it as the source of a phase 3 in another "
                       f"directory (--vae {shlex.quote(str(study.dir))}, or LatentSampler)")
    if kind == "python":
        raise CLIError(f"{study.dir} holds a run of the Python system {desc.get('class')} "
                       "(made through the API); the command line cannot rebuild it: continue "
                       "it with latentune.Study")
    if kind == "task" and args.system is not None:
        t = desc.get("task") or {}
        raise CLIError(f"{study.dir} holds a run of the built-in {t.get('robot')} "
                       f"{t.get('gait')} task, not of --system {args.system}: pass its "
                       "--robot/--task flags instead")


def _check_latent_dim(args: argparse.Namespace, dim: int) -> None:
    """--latent-dim (or its default) against a θ of ``dim`` entries, before any trial."""
    from latentune.latent.vae import default_latent_dim

    ld = getattr(args, "latent_dim", None)
    if dim < 2:
        raise CLIError(f"a {dim}-dim θ has no smaller latent space: run phase1 alone")
    if ld is None:
        ld = default_latent_dim(dim)
        if not 1 <= ld < dim:
            raise CLIError(f"the default latent size {ld} does not fit a {dim}-dim θ: pass "
                           f"--latent-dim in [1, {dim - 1}]")
    elif not 1 <= ld < dim:
        raise CLIError(f"--latent-dim {ld}: the latent space of a {dim}-dim θ needs a size in "
                       f"[1, {dim - 1}]")


UNUSED_FLAGS = {
    "train-vae": {"phase1_evals": None, "phase3_evals": None,
                  "method": None, "regions": None, "batch_size": None,
                  "max_fall_prob": None, "backend": "process", "workers": None,
                  "ray_address": None},
    "phase3": {"phase1_evals": None, "vae_epochs": None},
    "phase1": {"phase3_evals": None, "latent_dim": None, "vae_epochs": None,
               "vae_kind": "(the default kind)"},
}
"""The flags a run command shares with ``tune`` but does not use, with their defaults: another
value is refused (it would be ignored)."""
_UNUSED_WHY = {"train-vae": "train-vae trains the latent space only (it runs no rollout)",
               "phase3": "phase3 uses the trained latent space",
               "phase1": "phase1 tunes θ on the system only (train-vae makes the latent space)"}


def _refuse_unused(args: argparse.Namespace, cmd: str) -> None:
    from latentune.latent.vae import DEFAULT_KIND

    for dest, default in UNUSED_FLAGS[cmd].items():
        default = DEFAULT_KIND if default == "(the default kind)" else default
        if getattr(args, dest, default) != default:
            flag = "--" + dest.replace("_", "-")
            raise CLIError(f"{flag} is not an option of {cmd} (it would be ignored): "
                           f"{_UNUSED_WHY[cmd]}")


def _check_stored_vae(study: Any, args: argparse.Namespace, what: str) -> None:
    """--latent-dim and --vae-kind against the latent space stored in ``study`` (``what``: how
    it is used), refused when they differ."""
    vae = (study.config().get("vae") or {}) if study.exists else {}
    _check_vae_record(vae, args, f"the latent space of {study.dir}", what)


def _check_vae_record(vae: dict[str, Any], args: argparse.Namespace, which: str,
                      what: str) -> None:
    """--latent-dim, --vae-kind and --vae-epochs against ``vae``, the record of a trained
    latent space (``which``: what it is; ``what``: how it is used), refused when they differ."""
    from latentune.pipeline.phase2 import trained_differs

    diff = trained_differs(vae, args.latent_dim, _vae_kind(args), getattr(args, "vae_epochs", None))
    if diff is not None:
        name, given, stored = diff
        flag, has = {"latent_dim": ("--latent-dim", f"has size {stored}"),
                     "kind": ("--vae-kind", f"is {stored}"),
                     "epochs": ("--vae-epochs", f"was trained for {stored} epochs")}[name]
        raise CLIError(f"{flag} {given}: {which} {has} ({what})")


def _check_vae_source(source: str, args: argparse.Namespace) -> None:
    """--latent-dim and --vae-kind against the latent space of the --vae run ``source`` (phase 3
    uses it as it is), refused when they differ; a ``source`` that is no run is left to phase
    3's check."""
    from latentune.study import Study

    if (args.latent_dim is not None or _vae_kind(args) is not None) \
            and (Path(source) / "run.db").is_file():
        with Study(source) as run:
            _check_stored_vae(run, args, "--vae's, used as it is; leave the flag out")


def _vae_kind(args: argparse.Namespace) -> str | None:
    """--vae-kind, or None when it was left at its default (the stored kind is kept)."""
    from latentune.latent.vae import DEFAULT_KIND

    return None if args.vae_kind == DEFAULT_KIND else args.vae_kind


def _refuse_rerun(study: Any, phase: int, resume: bool) -> None:
    """Refuse, without --resume, a run of ``phase`` in a directory where it began: it holds
    trials of the phase, or (phase 3) the zero-shot trial the phase run stores first (a run
    stopped by Ctrl-C right after it)."""
    from latentune.constants import Phase

    if resume or not study.exists:
        return
    n = study.store.count(phase)
    if n > 0:
        held = counted(n, f"phase-{phase} evaluation")
    elif phase == Phase.PHASE3 and study.store.count(Phase.ZERO_SHOT) > 0:
        held = "the zero-shot trial phase 3 began with"
    else:
        return
    raise CLIError(f"{study.dir} already holds {held}; pass --resume to continue the run or "
                   "choose another --out")


def _budget(args: argparse.Namespace, study: Any, phase: int) -> int:
    """--phase1-evals / --phase3-evals of a run command: the value given, else the budget the
    run's phase was started with (a resume goes on to it), else, for phase 3, the one the
    ``tune`` that started the run planned (:func:`_tune_plan`), else the default."""
    given = args.phase1_evals if phase == 1 else args.phase3_evals
    if given is not None:
        return int(given)
    cfg = study.config() if study.exists else {}
    stored = (cfg.get(f"phase{phase}") or {}).get("budget")
    if not stored and phase == 3:
        stored = (cfg.get("tune") or {}).get("phase3_evals")
    return int(stored) if stored else DEFAULT_PHASE1 if phase == 1 else DEFAULT_PHASE3


def _need_store(study: Any, resume: bool) -> None:
    if resume and not study.exists:
        raise CLIError(f"--resume: no run store in {study.dir}")


def _stored_transfer(study: Any) -> dict[str, Any] | None:
    """The transfer options the stored phase 3 of ``study`` was run with (a resume keeps them;
    none stored: None)."""
    if not study.exists:
        return None
    return (study.config().get("phase3") or {}).get("transfer_options")


def _finish(study: Any, args: argparse.Namespace) -> None:
    """Print the run's summary and comparison table; the run is then complete and stored
    (:func:`work_done`: a Ctrl-C or SIGTERM after it exits 0)."""
    from latentune.reporting.run_report import comparison_table

    study.summary()
    print(comparison_table(study.store))
    work_done(args)


def _phase1_study(args: argparse.Namespace, latent: bool,
                  check: Callable[[Any], None] | None = None,
                  record: dict[str, Any] | None = None) -> tuple[Any, Any, Any]:
    """The study, system and phase-1 result of ``tune``/``phase1``, every flag checked first
    (``latent``: the latent-space flags are used afterwards, as in ``tune``; ``check(study)``:
    more checks, before phase 1 runs). ``record``: entries put in the run's config once every
    flag and phase 1's options are checked, before phase 1 runs (the store is created for
    them)."""
    study = _study(args)
    _check_stored_system(study, args)
    if check is not None:
        check(study)
    system = make_system(args, study.seed)
    if latent or args.latent_dim is not None:
        _check_latent_dim(args, system.space.dim)
    if latent and args.resume:
        _check_stored_vae(study, args, "kept with --resume; retrain it with train-vae")
    if not latent:
        _refuse_unused(args, "phase1")
    _need_store(study, args.resume)
    _refuse_rerun(study, 1, args.resume)
    if latent and study.exists:             # tune: after the lock, store and system checks
        with study.writing():
            study.bind_check(system)
            _refuse_phase1_past_latent(study, _budget(args, study, 1))
    mfp, prior = _kept_phase1(study, args)
    try:
        res = study.phase1(system, _budget(args, study, 1), method=args.method,
                           regions=args.regions, max_fall_prob=mfp, fall_prior=prior,
                           record=record)
    except (UsageError, StoreError) as exc:     # in the words of the command's flags
        study.close()
        raise CLIError(_ask_flags(str(exc), args)) from None
    except BaseException:
        study.close()
        raise
    return study, system, res


def _kept_phase1(study: Any, args: argparse.Namespace) -> tuple[Any, Any]:
    """(--max-fall-prob, --fall-prior) of phase 1: a resume of a phase 1 with trials keeps the
    stored ones unless given (the prior only with the stored or a given --max-fall-prob)."""
    mfp, prior = args.max_fall_prob, getattr(args, "fall_prior", None)
    stored = (study.config().get("phase1") or {}) if args.resume and study.exists else {}
    if stored and study.manifest.n_used(1) > 0:
        mfp = stored.get("max_fall_prob") if mfp is None else mfp
        if prior is None and mfp is not None:
            prior = stored.get("fall_prior")
    return mfp, prior


def _phase_line(res: Any, study: Any) -> str:
    best = study.dir / f"phase{res.phase}_best.json"
    return (f"phase {res.phase}: {counted(res.n, 'evaluation')} ({res.n_new} new), "
            f"{res.best_text('.6g')}"
            + (f"; its θ: {best}" if best.is_file() else ""))


def _refuse_phase1_past_latent(study: Any, phase1_evals: int) -> None:
    """tune --resume: refuse, before any trial, a --phase1-evals above the phase-1 trials
    stored once phase 3 ran in the latent space trained on them (neither would use the new
    ones: the latent space is fixed once phase 3 used it, and phase 3 keeps its source
    trials)."""
    from latentune.constants import Phase

    if not study.exists or study.store.artifact("vae") is None \
            or not study.manifest.n_used(Phase.PHASE3):
        return
    n = study.store.count(Phase.PHASE1)
    if phase1_evals > n:
        raise CLIError(f"--phase1-evals {phase1_evals}: phase 3 of {study.dir} runs "
                       f"in the latent space trained on its {n} phase-1 trials, and neither "
                       f"would use more: pass --phase1-evals {n} to go on, or tune again in "
                       "another directory")


def _refuse_tune_in_other_latent(study: Any) -> None:
    """tune on a run whose phase 3 runs in another run's latent space (``phase3 --vae``):
    refused before any trial (tune would run a phase 1 there, train a latent space of its own
    and then find phase 3 bound to the other one); the line names the command that goes on."""
    src = study.config().get("phase3_vae_source") if study.exists else None
    if src not in (None, "self"):
        raise CLIError(f"{study.dir}: its phase 3 runs in the latent space of {src} (phase3 "
                       "--vae), and tune would run a phase 1 here first: go on with "
                       f"`latentune phase3 … --out {shlex.quote(str(study.dir))} --resume`")


def _plan_given(args: argparse.Namespace, key: str) -> Any:
    """The value of ``tune``'s flag ``key`` (of :data:`TUNE_PLAN`) given on the command line,
    else None (--vae-kind: left at its default)."""
    return _vae_kind(args) if key == "vae_kind" else getattr(args, key, None)


def _tune_plan(study: Any, args: argparse.Namespace) -> dict[str, Any]:
    """The plan of ``tune`` (the flags of :data:`TUNE_PLAN`, as its run records them under
    ``tune``): with --resume, each flag not given is set in ``args`` from the run's recorded
    plan, the way a resume keeps phase 1's stored budget (--phase3-evals is read from it by
    :func:`_budget`, after a phase 3's stored budget); a given flag replaces the recorded value
    (a flag the run's latent space or phase 3 already fixed is refused by their checks); a
    transfer flag given at a default every run resumes with is the flag left out where the plan
    has none (:func:`latentune.critic.transfer.same_options`)."""
    from latentune.critic.transfer import same_options

    plan = ((study.config().get("tune") or {}) if study.exists else {}) if args.resume else {}
    out: dict[str, Any] = {}
    for key in TUNE_PLAN:
        given = _plan_given(args, key)
        if given is not None and args.resume and study.exists and key in TRANSFER_DESTS \
                and plan.get(key) is None and same_options(None, {key: given}):
            given = None            # a default every run resumes with: the plan as it began
        out[key] = given if given is not None else plan.get(key)
        if given is None and out[key] is not None and key != "phase3_evals":
            setattr(args, key, out[key])
    return out


def cmd_tune(args: argparse.Namespace) -> int:
    from latentune.constants import Phase
    from latentune.pipeline.loop import refuse_transfer_on_stored_plain, resolve_strategy
    from latentune.pipeline.phase2 import stale_latent

    _strategy(args, _handover(args))                # the flags given: checked before any read
    _transfer_options(args, None, unread=args.resume)
    plan: dict[str, Any] = {}
    chosen: dict[str, Any] = {}         # phase 3's handover and strategy, read with the plan

    def check(study: Any) -> None:
        """The run's plan read (a resume takes the flags it is not given from it), then phase
        3's strategy and transfer options checked, before phase 1 runs."""
        from latentune.pipeline.manifest import transfer_option

        _refuse_tune_in_other_latent(study)
        plan.update(_tune_plan(study, args))
        chosen["handover"] = handover = _handover(args)
        chosen["strategy"] = strategy = _strategy(args, handover)
        try:
            st = resolve_strategy(study.manifest, strategy, handover)
            topts = _transfer_options(args, _stored_transfer(study))
            refuse_transfer_on_stored_plain(study.manifest, st, topts, study.dir)
            transfer_option(topts, st, args.max_fall_prob)
        except (UsageError, StoreError) as exc:
            raise CLIError(_ask_flags(str(exc), args)) from None

    study, system, _ = _phase1_study(args, latent=True, check=check,
                                     record={"tune": plan, "command": "tune"})
    handover, strategy = chosen["handover"], chosen["strategy"]
    with study:
        vae = study.config().get("vae") or {}
        stale = stale_latent(study.store, vae) and not study.manifest.n_used(Phase.PHASE3)
        if stale:           # phase 1 grew since: trained again on every θ, as if never stopped
            study.log(f"phase 1 holds θ the latent space was not trained on "
                      f"({vae['n_train']} of them were): training it again")
        study.train_latent(args.latent_dim or (vae.get("d_low") if stale else None),
                           kind=_vae_kind(args) or (vae.get("kind") if stale else None),
                           epochs=args.vae_epochs, retrain=stale)
        # --method and --regions are phase 1's; phase 3 takes them only when it is plain
        plain = resolve_strategy(study.manifest, strategy, handover) == "plain"
        mfp, handover = _kept_phase3(study, args, handover)     # as phase3 --resume does
        _phase3_flags(study.phase3, system, _budget(args, study, 3),
                      method=args.method if plain else None,
                      regions=args.regions if plain else None,
                      max_fall_prob=mfp, handover=handover, strategy=strategy,
                      transfer_options=_transfer_options(args, _stored_transfer(study)),
                      args=args)
        _finish(study, args)
    return 0


def cmd_phase1(args: argparse.Namespace) -> int:
    study, _, res = _phase1_study(args, latent=False, record={"command": "phase1"})
    with study:
        study.summary()
        print(_phase_line(res, study))
        work_done(args)
    return 0


SPACE_KINDS = {"external": "trials run elsewhere (ask --space)",
               "optuna": "an imported Optuna study (import-optuna)",
               "python": "a Python system (made through the API)"}
"""The stored systems the command line does not rebuild, by what they are: ``train-vae``
trains on their stored parameter space."""


def _train_vae_space(study: Any, args: argparse.Namespace) -> Any:
    """The parameter space ``train-vae`` trains on. A run of :data:`SPACE_KINDS` (trials run
    elsewhere, an Optuna import, a Python system): its stored space, and ``--space FILE``, when
    given, must be that space (one line naming the difference). Any other run: the space of the
    system its flags build, checked against the stored system (``--space`` is refused)."""
    from latentune.space import ParameterSpace

    if args.space is not None and (args.system is not None or _task_given(args)):
        raise CLIError("--space replaces --robot/--task/--terrain/--actor/--steps/--v-des/"
                       "--reality/--engine and --system")
    kind = (study.config().get("system") or {}).get("kind") if study.exists else None
    if kind not in SPACE_KINDS:
        if args.space is not None:
            raise CLIError(f"no run store in {study.dir} (run phase1 or tune first, or ask "
                           "--space)" if not study.exists else
                           f"--space {args.space}: {study.dir} holds a run of a system the "
                           "flags rebuild, not of a parameter space: pass its --robot/--task "
                           "or --system flags instead")
        _check_stored_system(study, args)
        system = make_system(args, study.seed)
        if study.exists:
            study.bind_check(system)
        return system.space
    if args.system is not None or _task_given(args):
        raise CLIError(f"{study.dir} holds {SPACE_KINDS[kind]}: train-vae trains on its stored "
                       "parameter space; leave --robot/--task and --system out")
    stored = study.space()
    if args.space is not None:
        try:
            given = ParameterSpace.from_dict(_read_data(args.space, "--space"))
        except ValueError as exc:
            raise CLIError(f"--space {args.space}: {exc}") from None
        if given != stored:
            why = stored.box_difference(given.to_dict())
            why = f"{why}; there: the file, here: the stored one" if why else "another manual θ"
            raise CLIError(f"--space {args.space}: {study.dir} holds {SPACE_KINDS[kind]} in "
                           f"another parameter space ({why}); leave --space out to use the "
                           "stored one")
    return stored


def cmd_train_vae(args: argparse.Namespace) -> int:
    study = _study(args)
    space = _train_vae_space(study, args)
    _check_latent_dim(args, space.dim)
    if not study.exists:
        raise CLIError(f"no run store in {study.dir} (run phase1 or tune first)")
    _refuse_unused(args, "train-vae")
    with study:
        if study.store.artifact("vae") is not None and args.resume:
            _check_stored_vae(study, args, "kept with --resume; leave --resume out to retrain")
            study.train_latent()            # the kept one (a warning when phase 1 grew since)
            print(f"{study.dir}: the VAE is already trained (kept, --resume)")
            work_done(args)
            return 0
        latent = study.train_latent(args.latent_dim, kind=args.vae_kind, epochs=args.vae_epochs,
                                    retrain=True)
        ratio = latent.meta.get("decoded_variance_ratio")
        spread = "" if ratio is None else f"; decoded spread {ratio:.3f} of the training variance"
        print(f"VAE ({latent.kind}, d_low {latent.d_low}) trained on "
              f"{latent.meta.get('n_train', '?')} θ: {study.dir / 'vae.pt'}{spread}")
        work_done(args)
    return 0


def _kept_phase3(study: Any, args: argparse.Namespace, handover: Any) -> tuple[Any, Any]:
    """(--max-fall-prob, --handover) of phase 3: a resume of a phase 3 with trials keeps the
    stored ones unless given."""
    mfp = args.max_fall_prob
    stored = (study.config().get("phase3") or {}) if args.resume and study.exists else {}
    if stored and study.store.count(3) > 0:
        mfp = stored.get("max_fall_prob") if mfp is None else mfp
        handover = stored.get("handover") if handover is None else handover
    return mfp, handover


def _phase3_flags(phase3: Callable[..., Any], *a: Any, args: argparse.Namespace,
                  **kw: Any) -> Any:
    """``phase3(*a, **kw)`` (:meth:`Study.phase3`), its refusals in the words of the command's
    flags (:func:`_ask_flags`: ``--fall-budget is an option of the transfer phase 3``, not
    ``transfer_options are options …``)."""
    try:
        return phase3(*a, **kw)
    except (UsageError, StoreError, LatentError) as exc:
        raise CLIError(_ask_flags(str(exc), args)) from None


def cmd_phase3(args: argparse.Namespace) -> int:
    handover = _handover(args)
    strategy = _strategy(args, handover)
    _transfer_options(args, None, unread=args.resume)   # checked before anything runs
    study = _study(args)
    _check_stored_system(study, args)
    system = make_system(args, study.seed)
    if args.latent_dim is not None:
        _check_latent_dim(args, system.space.dim)
    _need_store(study, args.resume)
    if args.vae is None and not study.exists:
        raise CLIError(f"no run store in {study.dir} (run phase1 and train-vae first, "
                       "or pass --vae RUN_DIR)")
    _refuse_rerun(study, 3, args.resume)
    _refuse_unused(args, "phase3")
    if study.exists and study.manifest.n_fixing(3) and study.config().get("latent") \
            and study.config().get("phase3_vae_source") not in (None, "self"):
        _check_vae_record(study.config()["latent"], args, "the latent space phase 3 of "
                          f"{study.dir} was run in", "kept with --resume; leave the flag out")
    elif args.vae is not None:
        _check_vae_source(args.vae, args)
    else:
        _check_stored_vae(study, args, "retrain it with train-vae, or leave the flag out")
    mfp, handover = _kept_phase3(study, args, handover)
    with study:
        _phase3_flags(study.phase3, system, _budget(args, study, 3), latent=args.vae,
                      method=args.method, regions=args.regions, max_fall_prob=mfp,
                      handover=handover, strategy=strategy,
                      transfer_options=_transfer_options(args, _stored_transfer(study)),
                      args=args)
        _finish(study, args)
    return 0


# ---------------------------------------------------------------------------- report
def cmd_report(args: argparse.Namespace) -> int:
    from latentune.study import Study

    d = Path(args.dir)
    if args.system is None and args.system_arg:
        raise CLIError("--system-arg needs --system")
    if (d / "paper.json").is_file() and not (d / "run.db").is_file():
        from latentune.reporting.paper_report import write_paper_report

        if args.system is not None:
            raise CLIError(f"--system is for a run directory; {d} is a paper directory, whose "
                           "studies are built-in robots (leave --system out)")

        log = logging.getLogger("latentune.report").info
        print(write_paper_report(d, simulate=not args.no_sim, gifs=True, log=log))
        return 0
    study = Study(d, progress=_progress(args))
    if not study.exists:
        raise CLIError(f"no run store in {d}")      # as status, best, tell and release say
    system = None
    if args.system is not None:
        stored = study.config().get("system") or {}
        if stored.get("kind") in ("external", "optuna"):
            from latentune.pipeline.manifest import no_system_text

            raise CLIError(f"{d} holds {no_system_text(stored)}: it has no system to "
                           "re-simulate; leave --system (and --system-arg) out")
        system = make_system(args)
    with study:
        print(study.report(system=system, simulate=not args.no_sim))
        work_done(args)
    return 0


# ---------------------------------------------------------------------------- ask / tell / status
def _asktell_study(args: argparse.Namespace):
    from latentune.study import Study

    study = Study(args.dir)
    at = study.config().get("asktell") if study.exists else None
    seed = getattr(args, "seed", None)
    if at is not None:
        if seed is not None and seed != at["seed"]:
            raise CLIError(f"{args.dir}: ask/tell runs with --seed {at['seed']} (stored), not "
                           f"--seed {seed}")
        return Study(args.dir, seed=at["seed"], batch_size=at["batch_size"])
    try:
        return Study(args.dir, seed=seed)      # None: the stored seed, else 0
    except StoreError as exc:                  # another seed than the stored one
        raise CLIError(stored_flags(str(exc))) from None


def cmd_ask(args: argparse.Namespace) -> int:
    from latentune.space import ParameterSpace

    _positive("n", args.n)
    study = _asktell_study(args)
    system = None
    if args.system is not None or _task_given(args):
        system = make_system(args, study.seed)
    space = None
    if args.space is not None:
        try:
            space = ParameterSpace.from_dict(_read_data(args.space, "--space"),
                                             name=Path(args.space).name)
        except ValueError as exc:
            raise CLIError(f"--space {args.space}: {exc}") from None
    if system is None and space is None and study.space() is None:
        study.close()
        raise CLIError(f"{study.dir}: no parameter space yet: the first ask needs a system or "
                       "a space (--system, --robot or --space FILE)")
    from latentune.pipeline.asktell import prune_suggestion_files, write_suggestion_files

    handover = _handover(args)
    strategy = _strategy(args, handover)
    if args.max_fall_prob is not None and not 0 < args.max_fall_prob <= 1:
        raise CLIError(f"--max-fall-prob must be in (0, 1], got {args.max_fall_prob}")
    if args.lease is not None and not 0 < args.lease < float("inf"):
        raise CLIError(f"--lease must be a positive number of seconds, got {args.lease}")
    if args.budget is not None:
        _positive("budget", args.budget)
    # the stored transfer options under the flags given; none given: the stored ones (None)
    topts = (_transfer_options(args, _stored_transfer(study))
             if any(getattr(args, k) is not None for k in TRANSFER_DESTS) else None)
    with study:
        with _flag_words(args):     # the ask's warnings in the words of the flags
            start = _ask_start(args.start, system, space, study)
            try:
                sugg = study.ask(
                    args.n, system=system, space=space, phase=args.phase, latent=args.vae,
                    method=args.method, handover=handover, strategy=strategy,
                    budget=args.budget, regions=args.regions, start=start,
                    max_fall_prob=args.max_fall_prob, fall_prior=args.fall_prior,
                    asker=args.asker, lease_s=args.lease,
                    **({} if topts is None else {"transfer_options": topts}))
            except (UsageError, StoreError, LatentError) as exc:
                raise CLIError(_ask_flags(str(exc), args)) from None
            write_suggestion_files(study.dir, sugg)
            prune_suggestion_files(study.dir, _pending_ids(study))
        _print_suggestions(sugg, args)
        work_done(args)
    return 0


def _print_suggestions(sugg: list[Any], args: argparse.Namespace) -> None:
    """Print ask's suggestions (one JSON line with --json, else a line each) and warn of
    those whose θ the fall model rates likely to fall."""
    if args.json:
        print(json.dumps([s.to_dict() for s in sugg]))
    else:
        for s in sugg:
            vals = ", ".join(f"{k}={v:.6g}" for k, v in list(s.params.items())[:6])
            more = " ..." if len(s.params) > 6 else ""
            print(f"{s.id}\t{s.phase_name}{' (again)' if s.again else ''}\t{s.path}\t{vals}{more}")
    for s in sugg:
        if s.fall_risk is not None:
            logging.getLogger("latentune.ask").warning(
                "suggestion %d: the fall model rates θ of the ask that gave it up to %.2f likely "
                "to fall, above its screen of %.2f: be ready to catch the robot, or release it",
                s.id, *s.fall_risk)


class _FlagWords(logging.Filter):
    """A logging filter putting a record's message in the words of the command's flags
    (:func:`_ask_flags`)."""

    def __init__(self, args: argparse.Namespace) -> None:
        super().__init__()
        self.args = args

    def filter(self, record: logging.LogRecord) -> bool:
        record.msg, record.args = _ask_flags(record.getMessage(), self.args), ()
        return True


@contextmanager
def _flag_words(args: argparse.Namespace) -> Iterator[None]:
    """The ask/tell module's log records in the words of the command's flags meanwhile."""
    logger, flt = logging.getLogger("latentune.pipeline.asktell"), _FlagWords(args)
    logger.addFilter(flt)
    try:
        yield
    finally:
        logger.removeFilter(flt)


ASK_FLAGS = {**{k: FLAGS[k] for k in ("budget", "max_fall_prob", "handover", "strategy",
                                       "escape_falls", "latent", "fall_prior")},
             "method": "--method", "regions": "--regions", "start": "--start",
             "max-fall-prob": FLAGS["max_fall_prob"], "fall-prior": FLAGS["fall_prior"], "asker": "--asker", "lease_s": "--lease", "n": "--n",
             "fall_budget": "--fall-budget", "record_walk": "--record-walk",
             "walk_pick": "--walk-pick", "target_scores": "--target-scores",
             "batch_size": "--batch-size", "batch-size": "--batch-size",
             "latent-source": FLAGS["latent"], "latent_source": FLAGS["latent"]}
"""Study.ask's and Study.phase3's keyword arguments (and transfer_options keys) by the flag
that sets them, for :func:`_ask_flags`: those :data:`latentune.wording.FLAGS` names too from
there (one table of their flags), the others here."""
_TRANSFER_STORED = re.compile(r"(?:runs|was run) with transfer-options = (.*?)(?: \(stored\))?, "
                              r"not (.*)$")


def _ask_flags(msg: str, args: argparse.Namespace) -> str:
    """A refusal of :meth:`Study.ask` (or of :meth:`Study.phase1` and :meth:`Study.phase3`, for
    ``phase1``, ``phase3`` and ``tune``) with the command's flags in place of the Python names
    it gives (``transfer_options is an option of phase 3`` → ``--fall-budget is an option of
    phase 3``; ``(strategy plain)`` → ``(--strategy plain)``; ``runs with method = 'a'
    (stored), not 'b'`` → ``runs with --method a (stored), not --method b``)."""
    import ast

    where = getattr(args, "dir", None) or args.out
    given = [ASK_FLAGS[k] for k in TRANSFER_DESTS if getattr(args, k, None) is not None]
    if not given and msg.startswith("transfer_options are options of the transfer phase 3"):
        # the stored options (none given): the stored phase 3 is a transfer one
        return (f"{where}: phase 3 runs with --strategy transfer (stored, with its transfer "
                f"options), not --strategy {args.strategy or 'plain'}")
    msg = re.sub(r"^(.*?: )phase(\d) was run with", r"\1phase \2 was run with", msg)
    topts = " and ".join(given)
    msg = re.sub(r"^transfer_options (is an option|are options) of",
                 lambda m: f"{topts} {'are options' if len(given) > 1 else 'is an option'} of",
                 msg)
    msg = re.sub(r"^(\w+)( is an option of| must be| is not an option of)",
                 lambda m: ASK_FLAGS.get(m[1], m[1]) + m[2], msg)
    msg = re.sub(r"^(\w+) needs (\w+)",
                 lambda m: f"{ASK_FLAGS.get(m[1], m[1])} needs {ASK_FLAGS.get(m[2], m[2])}", msg)
    msg = re.sub(r"^regions \(trust regions\) is an option of method turbo \(TuRBO-m\), not "
                 r"of (\w+)", r"--regions (trust regions) is an option of --method turbo "
                 r"(TuRBO-m), not of --method \1", msg)
    msg = re.sub(r"runs with strategy (\w+) \(stored\), not (\w+): leave strategy out",
                 r"runs with --strategy \1 (stored), not --strategy \2: leave --strategy out", msg)
    msg = re.sub(r"^(.*?)transfer_options are options of(.*?) strategy plain \(stored\): "
                 r"leave them out",
                 lambda m: f"{m[1]}{topts} {'are options' if len(given) > 1 else 'is an option'}"
                           f" of{m[2]} --strategy plain (stored): leave {topts} out", msg)
    msg = re.sub(r"\((\w+)\)", lambda m: f"({ASK_FLAGS.get(m[1], m[1])})", msg)
    msg = re.sub(r"\(given (\w+) = ",
                 lambda m: f"(given {ASK_FLAGS.get(m[1], m[1])} = ", msg)
    m = _TRANSFER_STORED.search(msg)
    if m:
        try:
            old, new = (ast.literal_eval(x) or {} for x in m.groups())
        except (ValueError, SyntaxError):
            return msg
        if not (isinstance(old, dict) and isinstance(new, dict)):
            return msg
        keys = [k for k in {**old, **new} if old.get(k) != new.get(k)]

        def shown(d: dict[str, Any]) -> str:
            return ", ".join(f"{ASK_FLAGS.get(k, k)} {d[k]}" if k in d else
                             f"no {ASK_FLAGS.get(k, k)}" for k in keys)
        verb = "runs" if m[0].startswith("runs") else "was run"
        return msg[:m.start()] + f"{verb} with {shown(old)} (stored), not {shown(new)}"
    if "(train_latent / train-vae)" in msg:      # the command that trains the latent space
        trains = getattr(args, "vae", None) if msg.startswith(f"{ASK_FLAGS['latent']}: ") \
            else where
        msg = msg.replace("(train_latent / train-vae)",
                          f"({shlex.join(['latentune', 'train-vae', '--out', str(trains)])}"
                          + "".join(" " + f for f in _stored_plugin_flags(trains)) + ")")
    if "(phase1, then train_latent)" in msg:     # no phase-1 trial to train one on
        q = shlex.quote(str(where))
        runs = f"latentune ask {q} --phase 1 … and tell its trials" \
            if getattr(args, "command", None) == "ask" else f"latentune phase1 … --out {q}"
        msg = msg.replace("(phase1, then train_latent)",
                          f"({runs}, then "
                          f"{shlex.join(['latentune', 'train-vae', '--out', str(where)])})")
    msg = msg.replace("the result (best_params())",
                      f"the result (latentune best {shlex.quote(str(where))})")
    msg = re.sub(r"was run with latent-source = 'self', not '(.*)'$",  # its own latent space
                 r"was run in its own latent space (without --vae), not with --vae \1", msg)
    return stored_flags(msg)


_STORED_VALUE = re.compile(r"(runs with|was run with) ([a-z][\w-]*) = (.*?)(?: \(stored\))?, "
                           r"not (.*?)(?=; | \(leave |$)")
"""A resume refused for another value, as the study words it (``runs with budget = 5
(stored), not 3``); the given value ends at ``; ``, `` (leave `` or the end."""


def stored_flags(msg: str) -> str:
    """A resume's refusal for another value in the one form of the command line: the flag
    with the stored and the given value as the user types them (``runs with --budget 5
    (stored), not --budget 3``; ``was run with no --max-fall-prob (stored), not
    --max-fall-prob 0.2``; a dict of numbers as ``--handover patience=2,tol=0.01``); any
    other message is returned as it is."""
    import ast

    def typed(text: str) -> str | None:
        try:
            v = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            return text
        if isinstance(v, dict) and all(isinstance(x, (int, float)) for x in v.values()):
            return ",".join(f"{k}={x}" for k, x in v.items())       # --handover's form
        return None if v is None else v if isinstance(v, str) else text

    def form(m: re.Match[str]) -> str:
        flag = ASK_FLAGS.get(m[2], "--" + m[2].replace("_", "-"))
        old, new = (typed(x) for x in (m[3], m[4]))
        return (f"{m[1]} " + (f"no {flag}" if old is None else f"{flag} {old}") + " (stored), not "
                + (f"no {flag}" if new is None else f"{flag} {new}"))

    msg = re.sub(r"^(.*?: )phase(\d) was run with", r"\1phase \2 was run with", msg)
    msg = re.sub(r"ask/tell runs phase (\d) \(stored\), not (\d)",
                 r"ask/tell runs with --phase \1 (stored), not --phase \2", msg)
    msg = msg.replace("(leave the seed out", "(leave --seed out")
    return _STORED_VALUE.sub(form, msg)


def _ask_start(start: str | None, system: Any, space: Any, study: Any) -> Any:
    """ask --start as Study.ask's ``start``: None, "manual", "scratch", or the unit-box θ of
    a --params file (read with the system's, the given or the stored parameter space)."""
    if start is None or start in ("manual", "scratch"):
        return start
    if not Path(start).exists():            # a typo of manual or scratch, or a missing file
        raise CLIError(f"--start {start}: no such file; give manual, scratch or a --params file")
    sp = system.space if system is not None else space if space is not None else study.space()
    from latentune.errors import ParamsError

    try:
        return sp.load(start, _tuned_for(system, space, study))
    except ParamsError as exc:
        raise CLIError(f"--start {start}: {exc}") from None


def _tuned_for(system: Any, space: Any, study: Any) -> dict[str, Any] | None:
    """What θ of an ask are tuned for: those of ``system`` (the one given), none for a
    ``space`` given alone (trials run elsewhere), else the study's recorded system's."""
    from latentune.pipeline.manifest import describe, tuned_for
    from latentune.pipeline.results import study_tuned_for

    if system is not None:
        return tuned_for(describe(system))
    if space is not None or not study.exists:
        return None
    return study_tuned_for(study.store)


def cmd_tell(args: argparse.Namespace) -> int:
    from latentune.study import Study

    study = Study(args.dir)
    if not study.exists:
        raise CLIError(f"no run store in {args.dir}")
    if args.cost is None and not args.failed:
        raise CLIError("tell --amend needs the corrected result, --cost C or --failed (to "
                       "change only the note, give the told result again with --note)"
                       if args.amend else
                       "tell needs --cost C, or --failed (a failed trial may omit the cost)")
    info = _fall_info(args)
    try:
        trial_id = int(args.id)
    except ValueError:
        raise CLIError(f"a suggestion id is an integer, got {args.id!r}") from None
    from latentune.pipeline.asktell import prune_suggestion_files
    from latentune.pipeline.results import phase_name

    with study:
        _check_suggestion_file(study, trial_id, args)
        n_amended = len(study.amendments())
        row = study.tell(trial_id, args.cost, failed=args.failed, note=args.note,
                         amend=args.amend, info=info, asker=args.asker)
        # the rows stored with it (a θ asked again, waiting for its result), or amended with it
        copies = study.store.copies(row.phase, row.idx)
        if args.amend:
            now = {(a["phase"], a["idx"]) for a in study.amendments()[n_amended:]}
            copies = [c for c in copies if (c.phase, c.idx) in now]
        prune_suggestion_files(study.dir, _pending_ids(study))   # an amendment withdraws some
        study.summary()                         # summary.json holds the result told
        if args.json:
            print(json.dumps({"id": trial_id, "amended": bool(args.amend),
                              "phase": int(row.phase), "phase_name": phase_name(row.phase),
                              "idx": row.idx, "cost": row.cost, "failed": row.fell,
                              "copies": [{"id": c.info.get("trial"), "phase": int(c.phase),
                                          "phase_name": phase_name(c.phase), "idx": c.idx}
                                         for c in copies]}))
        else:
            print(f"{'amended' if args.amend else 'told'} {trial_id}: {phase_name(row.phase)} "
                  f"evaluation {row.idx}, cost {row.cost:.6g}{' (failed)' if row.fell else ''}"
                  + _copies_said(copies, args.amend))
        work_done(args)
    return 0


def _copies_said(copies: list[Any], amend: bool) -> str:
    """The end of tell's line naming the rows stored as copies of the told one (a θ asked
    again, stored with its result, not run) or amended with it: ``"; also stored with this
    result: 1 copy: phase 3 evaluation 5 (suggestion 9), its θ asked again"``; "" for none."""
    from latentune.pipeline.results import phase_name

    if not copies:
        return ""
    named = ", ".join(f"{phase_name(c.phase)} evaluation {c.idx}" + (
        f" (suggestion {c.info['trial']})" if c.info.get("trial") is not None else "")
        for c in copies)
    what = f"{counted(len(copies), 'copy', 'copies')}: {named}"
    return (f"; also amended: {what}, stored from it" if amend else
            f"; also stored with this result: {what}, its θ asked again (not run)")


def _fall_info(args: argparse.Namespace) -> dict[str, int] | None:
    """tell's ``--fall-step K --horizon N`` as the trial's info (None without them); CLIError
    unless both are given with --failed and 0 ≤ K ≤ N, N > 0."""
    k, n = args.fall_step, args.horizon
    if k is None and n is None:
        return None
    if k is None or n is None:
        raise CLIError("--fall-step and --horizon go together (when the trial fell, K of N)")
    if not args.failed:
        raise CLIError("--fall-step says when a failed trial fell: add --failed")
    if not (n > 0 and 0 <= k <= n):
        raise CLIError(f"--fall-step must be within 0 … --horizon (> 0), got {k} of {n}")
    return {"fall_step": k, "horizon": n}


def _check_suggestion_file(study: Any, trial_id: int, args: argparse.Namespace) -> None:
    """Refuse to tell a pending suggestion whose file was edited by hand: the store would
    record the result for the suggested θ, which is not the one the robot ran."""
    from latentune.pipeline.asktell import DEFAULT_ASKER, edited_suggestion

    if not -2 ** 63 <= trial_id < 2 ** 63:     # no such id: the tell says so
        return
    trial = study.store.trials(trial_id=trial_id)
    space = study.space()
    if args.amend or not trial or trial[0].status != "pending" or space is None:
        return
    what = edited_suggestion(study.dir, trial_id, trial[0].theta, space)
    if what is not None:
        f = Path(study.dir) / "suggestions" / f"{trial_id}.json"
        asker = trial[0].asker
        again = f"latentune ask {shlex.quote(str(args.dir))}" + (
            "" if asker in (None, DEFAULT_ASKER) else f" --asker {shlex.quote(asker)}")
        raise CLIError(f"{f} is not suggestion {trial_id}'s θ any more ({what}): its result "
                       f"would be stored for the suggested θ. If the robot ran the suggested "
                       f"θ, `{again}` writes the file again, then tell; if it ran the edited "
                       f"one, that is no suggestion: latentune release "
                       f"{shlex.quote(str(args.dir))} {trial_id}")


def _pending_ids(study: Any) -> list[int]:
    """The ids of the suggestions of ``study`` handed out and not told (their files stay)."""
    return [t.id for t in study.store.trials("pending")]


def _stored_study(d: str) -> Any:
    """The Study of an existing run directory ``d``; CLIError when it holds no store."""
    from latentune.study import Study

    study = Study(d)
    if not study.exists:
        raise CLIError(f"no run store in {d}")
    return study


def cmd_release(args: argparse.Namespace) -> int:
    study = _stored_study(args.dir)
    try:
        trial_id = int(args.id)
    except ValueError:
        raise CLIError(f"a suggestion id is an integer, got {args.id!r}") from None
    from latentune.pipeline.asktell import prune_suggestion_files

    with study:
        study.release(trial_id)
        prune_suggestion_files(study.dir, _pending_ids(study))
        print(f"released {trial_id}: the next ask hands it out again (its file is removed)")
        work_done(args)
    return 0


def cmd_best(args: argparse.Namespace) -> int:
    from latentune.pipeline.results import phase_name

    study = _stored_study(args.dir)
    with study:
        if args.out is None and not os.access(study.dir, os.W_OK):
            raise CLIError(f"{args.dir} cannot be written (read-only): write the θ elsewhere "
                           "with --out FILE")
        path = study.best_params(args.out)
        b = study.best()
    print(f"best: cost {b.cost:.6g} ({phase_name(b.phase)}, evaluation {b.idx}); its θ, to "
          f"deploy: {path}")
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    study = _stored_study(args.dir)
    with study:
        s = study.status()
        nameable = study.space() is not None    # else best refuses: no θ to name
    if args.json:
        print(json.dumps(s))
        return 0
    if not s["phases"]:
        print("no trial stored yet")
    for name, p in s["phases"].items():
        best = ("no trial told yet" if p["n"] == 0 else "no trial without a fall") \
            if p["best"] is None else (
            f"best {p['best']:.6g} (evaluation {p['best_idx']}"
            + (f", suggestion {p['best_trial']}" if p.get("best_trial") is not None else "") + ")")
        k = p.get("reused") or 0         # stored with a stored trial's outcome, not run
        again = f" ({k} {'repeat' if k > 1 else 'repeats'} a stored trial, not run again)" \
            if k else ""
        told = counted(p["n"], "trial") if p.get("budget") is None else \
            f"{p['n']} of {counted(p['budget'], 'trial')}"
        print(f"{name}: {told}{again}, {p['failed']} failed, "
              f"{p['pending']} pending; {best}")
    dec = s.get("decisions")
    if dec:
        last = dec["last"]
        agree = f", agreement not measured ({last['agreement_unmeasured']})" \
            if last.get("agreement_unmeasured") else \
            "" if last.get("agreement") is None else f", agreement {last['agreement']:.2f}"
        side = "" if last.get("length") is None else f", side {last['length']:.3g}"
        print(f"phase 3 decisions: {counted(dec['n'], 'ask')} ("
              + ", ".join(f"{k} {v}" for k, v in dec["kinds"].items())
              + f"); last: generation {last['generation']}, {last['kind']}{agree}{side}"
              + (f", pools {'/'.join(sorted(set(last['pools'])))}" if last.get("pools") else "")
              + (f"; scores: {last['scores']}" if last.get("scores") else "")
              + (f"; {counted(dec['fit_failed'], 'ask')} with a model fit that failed "
                 "(latentune report lists them)" if dec.get("fit_failed") else ""))
    fb = s.get("fall_budget")
    if fb:
        which = " (those after the first trial that stood)" \
            if fb.get("counts") == "after_stand" else ""
        print(f"phase 3 fall budget: {counted(fb['falls'], 'fall')} counted{which}, "
              f"{fb['falls_allowed']} "
              "allowed" + ("; spent: phase 3 asks no more" if fb["spent"] else "")
              + (f" ({counted(fb['not_run'], 'trial')} asked not run)"
                 if fb.get("not_run") else ""))
    leases = s.get("leases") or {}
    from latentune.pipeline.asktell import DEFAULT_ASKER

    def held(i: int) -> str:
        """Pending suggestion ``i``: by whom it is held, or that its lease expired (the
        asker of an ask without --asker is not named: its stored name is no flag's value):
        ``"suggestion 1 held by rig2"``, named as a suggestion ("2 (1 held, 2 held)" read as
        counts)."""
        lease = leases.get(str(i), {})
        asker = lease.get("asker")
        unnamed = asker in (None, DEFAULT_ASKER)
        if lease.get("seconds_left") == 0:      # the next ask hands it out again
            whose = "its" if unnamed else f"{asker}'s"
            return f"suggestion {i} free again: {whose} lease expired"
        return f"suggestion {i} held" + ("" if unnamed else f" by {asker}")

    print(f"pending suggestions: {len(s['pending'])}" + (
        " (" + ", ".join(held(i) for i in s["pending"]) + ")" if s["pending"] else ""))
    if s["best"] is not None:
        b = s["best"]
        print(f"best: {b['cost']:.6g} ({b['phase']}, evaluation {b['idx']}"
              + (f", suggestion {b['trial']}" if b.get("trial") is not None else "") + ")"
              + (f"; its θ: {b['params_file']}" if b.get("params_file") else
                 (f"; {Path(args.dir) / 'best.json'} holds an earlier best θ (a run stopped "
                  "before it wrote this one)" if b.get("params_stale") else "")
                 + f"; write it with: latentune best {shlex.quote(str(args.dir))}" if nameable
                 else "; its θ cannot be written: the store records no parameter space (a "
                 "store of another layout?)"))
    return 0


def _read_data(path: str, flag: str) -> Any:
    import yaml

    from latentune import yamltext

    p = Path(path)
    if p.is_dir():
        raise CLIError(f"{flag}: {p} is a directory, not a file")
    if not p.is_file():
        raise CLIError(f"{flag}: file not found: {p}")
    try:
        return yamltext.load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CLIError(f"{flag}: {p} is not valid YAML/JSON ({yamltext.problem(exc)})") from None


# ---------------------------------------------------------------------------- robot specs
def cmd_robot_check(args: argparse.Namespace) -> int:
    from latentune.robots import check_spec

    rep = check_spec(args.spec, simulate=not args.no_sim)
    print(json.dumps(rep.to_dict()) if args.json else rep.format())
    return 0 if rep.ok else 2


def cmd_robot_init(args: argparse.Namespace) -> int:
    from latentune.atomicfile import write_atomic
    from latentune.robots import init_spec

    if args.out is not None:
        if os.path.isfile(args.out):
            raise CLIError(f"--out {args.out} exists (not overwritten): delete it or give "
                           "another --out")
        _check_output_file("--out", args.out, (".yaml", ".yml"))
    text = init_spec(args.urdf, name=args.name)
    if args.out is None:
        print(text, end="")
    else:
        try:
            write_atomic(args.out, text)
        except OSError as exc:
            raise CLIError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    return 0


# ---------------------------------------------------------------------------- paper, bench
def _scale(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise CLIError(f"--scale must be a number, got {s!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise CLIError(f"--scale must be a finite number > 0, got {s}")
    return v


def _seeds(s: str) -> int:
    try:
        v = int(s)
    except ValueError:
        raise CLIError(f"--seeds must be an integer >= 1, got {s!r}") from None
    if v < 1:
        raise CLIError(f"--seeds must be an integer >= 1, got {v}")
    return v


def cmd_paper(args: argparse.Namespace) -> int:
    from latentune.experiments.paper import PaperOptions, run_paper

    for flag, given in (("--no-sim", args.no_sim), ("--no-gif", args.no_gif)):
        if given and args.sources_only:
            raise CLIError(f"{flag} does not apply to --sources-only: it writes no report")
    check_v_des(args.v_des)
    check_limits(args)
    opts = PaperOptions(robot=str(args.robot).lower(), actor=args.actor, scale=args.scale,
                        phase1=args.phase1_evals, phase3=args.phase3_evals,
                        out=args.out or f"paper-{str(args.robot).lower()}", workers=args.workers,
                        seed=args.seed, steps=args.steps, v_des=args.v_des, quiet=args.quiet,
                        sources_only=args.sources_only, seeds=args.seeds,
                        studies=tuple(args.studies or ()), progress=_progress(args),
                        vae_epochs=args.vae_epochs)
    text = run_paper(opts, report_only=args.report_only, simulate=not args.no_sim,
                     gifs=not args.no_gif)
    if not args.quiet:
        print(text)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from latentune.experiments.bench import run_bench

    return run_bench(args.steps, args.n, args.timeout)


def _strategy_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strategy", choices=("transfer", "plain"), default=None,
                   help="phase 3: transfer (default for a new phase 3: everything the source run "
                        "tried, latent and full θ boxes) or plain (the paper's latent search; "
                        "--method, --regions and --handover are its options)")


def _transfer_args(p: argparse.ArgumentParser) -> None:
    """The transfer phase 3's options a person at the robot sets from the shell."""
    from latentune.critic.transfer import TARGET_SCORES, WALK_PICKS

    p.add_argument("--fall-budget", type=float, default=None, metavar="Q",
                   help="transfer phase 3: stop once the target's trials after the first one "
                        "that stood fell Q × its trials times (at least once); default 0: "
                        "never stop")
    p.add_argument("--record-walk", type=int, default=None, metavar="K",
                   help="transfer phase 3: once the zero-shot θ and the design's elites all "
                        "fell, the next K asks walk down the source's own record, one rank "
                        "band each, until one stands; default 0: off")
    p.add_argument("--escape-falls", type=int, default=None, metavar="K",
                   help="transfer phase 3: once K target trials all fell, every explore ask "
                        "(every second ask) takes the θ farthest from them in the whole box, "
                        "for a target that falls wherever the source stood; default 0: off")
    p.add_argument("--walk-pick", choices=WALK_PICKS, default=None,
                   help="how each step of --record-walk is chosen: the best rank past the "
                        "step's quantile (rank, the default), or the least likely to fall "
                        "by the target fall model over the record (fall) or in the step's "
                        "band of ranks (band)")
    p.add_argument("--target-scores", choices=TARGET_SCORES, default=None,
                   help="transfer phase 3: what its model of the target's cost fits: the "
                        "costs' ranks (ranks, the default: robust where trials fall and costs "
                        "jump), their values, or their values under a fitted power warp "
                        "(warped: measured lower on smooth targets where little falls, "
                        "higher on some others; not the default), or at every ask ranks or "
                        "warped, whichever model's leave-one-out predictions order the "
                        "target's own trials better (auto)")


TRANSFER_DESTS = ("fall_budget", "record_walk", "escape_falls", "walk_pick", "target_scores")
"""The flags of :func:`_transfer_args` (their ``args`` attributes)."""

TUNE_PLAN = ("phase3_evals", "latent_dim", "vae_kind", "vae_epochs", "method", "regions",
             "max_fall_prob", "strategy", "handover") + TRANSFER_DESTS
"""The flags of ``tune`` (their ``args`` attributes) its run records, as given (None: not
given), under ``tune`` before phase 1 runs: what its latent space and phase 3 are run with,
which a resume stopped before them would otherwise not know (:func:`_tune_plan`)."""


def _transfer_options(args: argparse.Namespace, stored: dict[str, Any] | None, *,
                      unread: bool = False) -> dict[str, Any] | None:
    """Phase 3's ``transfer_options``: ``stored`` (the stored phase 3's, which a resume or a
    later ask keeps) with --fall-budget, --record-walk, --escape-falls, --walk-pick and
    --target-scores over it
    (each checked; a --walk-pick other than the default without a walk to choose for is
    refused; ``unread``: a resume's stored options not read yet, whose walk that check
    waits for). A flag that changes a stored value is then refused by the study, naming both."""
    q = getattr(args, "fall_budget", None)
    k = getattr(args, "record_walk", None)
    pick = getattr(args, "walk_pick", None)
    esc = getattr(args, "escape_falls", None)
    scores = getattr(args, "target_scores", None)
    if q is None and k is None and pick is None and esc is None and scores is None:
        return stored
    opts = dict(stored or {})
    if q is not None:
        if not 0.0 <= q < 1.0:                      # nan fails too
            raise CLIError(f"--fall-budget must be in [0, 1), got {q}")
        opts["fall_budget"] = q
    if k is not None:
        if k < 0:
            raise CLIError(f"--record-walk must be a number of asks ≥ 0 (0: off), got {k}")
        opts["record_walk"] = k
    if esc is not None:
        if esc < 0:
            raise CLIError(f"--escape-falls must be a number of trials ≥ 0 (0: off), got {esc}")
        opts["escape_falls"] = esc
    if pick is not None:
        from latentune.critic.transfer import TRANSFER_DEFAULTS

        # the default pick without a walk is no choice (as the critic takes it): left out
        if int(opts.get("record_walk", 0)) <= 0 and pick != TRANSFER_DEFAULTS["walk_pick"] \
                and not unread:
            raise CLIError("--walk-pick chooses the steps of a walk: give --record-walk K > 0")
        opts["walk_pick"] = pick
    if scores is not None:
        opts["target_scores"] = scores
    return opts


def _strategy(args: argparse.Namespace, handover: Any) -> Any:
    """The --strategy of phase 3, refused with options only the plain strategy has."""
    st = getattr(args, "strategy", None)
    if st == "transfer" and handover:
        raise CLIError("--handover is an option of --strategy plain")
    return st


# ---------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    from latentune.experiments.paper import MAPPING_DOC

    parser = _Parser(prog="latentune", description=DESCRIPTION)
    common = [_verbosity_parser()]
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, required=True)

    def add(name: str, **kw: Any) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=common, **kw)

    p = add("rollout", help="simulate one rollout and print its path cost (or, with --system, "
                            "run one trial of your system)")
    add_system_args(p)
    p.add_argument("--seed", type=argtypes.seed, default=None, help="terrain seed, and of a --reality's noise and pushes (default 0)")
    p.add_argument("--params", type=argtypes.params_file,
                   help="JSON file: list of normalized θ or object of physical values "
                        "(default: the manual θ)")
    p.add_argument("--gif", help="write a GIF of the motion here")
    p.add_argument("--plot", help="write a PNG of CoM velocity and height here")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_rollout)

    for name, func, hlp in (
            ("tune", cmd_tune, "phases 1-3 on one system: phase1, train-vae, phase3"),
            ("phase1", cmd_phase1, "phase 1: TuRBO-m on the full θ"),
            ("train-vae", cmd_train_vae, "phase 2: train the VAE on the stable phase-1 θ"),
            ("phase3", cmd_phase3, "phase 3 on the target: from the source run's trials "
                                   "(transfer, the default) or TuRBO-m in its latent space "
                                   "(--strategy plain)")):
        p = add(name, help=hlp)
        add_run_args(p, name)
        for a in p._actions:            # accepted only to be refused: not offered in --help
            if a.dest in UNUSED_FLAGS.get(name, {}):
                a.help = argparse.SUPPRESS
        p.set_defaults(func=func)

    p = add("report", help="tables, plots and report.md of a run directory")
    p.add_argument("dir", type=argtypes.run_dir, help="run directory (or a paper directory)")
    p.add_argument("--no-sim", action="store_true",
                   help="skip the re-simulated CoM plots (and a paper directory's GIFs); an "
                        "earlier report's are removed")
    p.add_argument("--system", default=None, metavar="MODULE:FACTORY",
                   help="rebuild the run's user system to re-simulate (must match the stored one)")
    p.add_argument("--system-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="an argument of the --system factory (repeatable)")
    p.set_defaults(func=cmd_report, robot=None, task=None, terrain=None, actor=None, steps=None,
                   v_des=None)  # report rebuilds built-in tasks from the store

    p = add("ask", help="suggest θ for trials run elsewhere (stored as pending)")
    p.add_argument("dir", type=argtypes.run_dir,
                   help="study directory (created on the first ask)")
    p.add_argument("--n", type=int, default=1, help="number of suggestions (default 1)")
    add_system_args(p)
    p.add_argument("--space", default=None, metavar="FILE",
                   help="YAML/JSON parameter space: names, low, high, log, manual")
    p.add_argument("--phase", type=int, choices=(1, 3), default=None,
                   help="1 = the full θ, 3 = the latent space of --vae (default: 3 with "
                        "--vae or in a run holding a phase 3, else 1)")
    p.add_argument("--vae", default=None, metavar="RUN_DIR", type=argtypes.other_run("--vae"),
                   help="the latent space for phase 3")
    p.add_argument("--method", choices=("turbo", "cma", "random", "sobol"), default=None,
                   help="critic (first ask: default turbo; later asks: the stored one)")
    _handover_arg(p)
    _strategy_arg(p)
    _transfer_args(p)
    p.add_argument("--budget", type=int, default=None,
                   help="the trials you plan (first ask: default 200; may grow later)")
    p.add_argument("--regions", type=int, default=None, help="TuRBO-m trust regions")
    p.add_argument("--start", default=None, type=argtypes.start,
                   metavar="manual|scratch|FILE",
                   help="the θ the search starts from: manual (the manual θ, the default), "
                        "scratch (the critic's own initial design) or a --params file "
                        "(physical values by name, or a list of normalized θ); first ask only; "
                        "the transfer phase 3 takes only manual (it starts from the manual θ "
                        "and the source's best trials)")
    p.add_argument("--max-fall-prob", type=float, default=None, metavar="P",
                   help="fall-aware: skip candidates whose predicted fall probability exceeds P "
                        "(first ask: default off, but 0.3 in the transfer phase 3)")
    p.add_argument("--fall-prior", default=None, metavar="RUN_DIR",
                   type=argtypes.other_run("--fall-prior"),
                   help="phase 1 with --max-fall-prob: a run whose trials seed the prediction")
    p.add_argument("--asker", default=None,
                   help="who runs the trials (several askers on one study each get their own)")
    p.add_argument("--lease", type=float, default=None, metavar="SECONDS",
                   help="a suggestion not told within this time is handed out again "
                        "(default 3600)")
    p.add_argument("--seed", type=argtypes.seed, default=None, help="seed (first ask only; default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON list")
    p.set_defaults(func=cmd_ask)

    p = add("tell", help="store the result of a suggestion")
    p.add_argument("dir", type=argtypes.run_dir, help="study directory")
    p.add_argument("id", help="the suggestion's id (from ask)")
    p.add_argument("--cost", type=float, default=None, help="the trial's cost")
    p.add_argument("--failed", action="store_true",
                   help="the trial failed (a fall); without --cost it costs 2·C1 = 200")
    p.add_argument("--fall-step", type=int, default=None, metavar="K",
                   help="with --failed and --horizon: when it fell, K of the trial's N steps "
                        "(any unit: 32 of 100 tenths of a second); without --cost it costs "
                        "C1·(2 − K/N), as a simulated fall (a later fall ranks better)")
    p.add_argument("--horizon", type=int, default=None, metavar="N",
                   help="the trial's length in the unit of --fall-step")
    p.add_argument("--note", default=None, help="free text stored with the trial")
    p.add_argument("--amend", action="store_true",
                   help="correct a result told before (the old one is kept as an audit trail)")
    p.add_argument("--asker", default=None,
                   help="who tells it (recorded with the trial); refused while another "
                        "asker's lease on it lasts")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (with the copies stored or amended with it)")
    p.set_defaults(func=cmd_tell)

    p = add("release", help="hand a pending suggestion out again (its trial will not be run)")
    p.add_argument("dir", type=argtypes.run_dir, help="study directory")
    p.add_argument("id", help="the suggestion's id")
    p.set_defaults(func=cmd_release)

    p = add("best", help="write the θ to deploy: the best trial over all phases that did not fail")
    p.add_argument("dir", type=argtypes.run_dir, help="study directory")
    p.add_argument("--out", default=None, help="the --params file to write (default DIR/best.json)")
    p.set_defaults(func=cmd_best)

    p = add("status", help="evaluations, failures, pending suggestions, best")
    p.add_argument("dir", type=argtypes.run_dir, help="study directory")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_status)

    from latentune.integrations import register_cli

    register_cli(sub, parents=common)            # import-optuna, dashboard (the optuna extra)

    p = sub.add_parser("robot", help="check a robot spec, or write one for a quadruped URDF")
    rsub = p.add_subparsers(dest="robot_command", metavar="{check,init}", parser_class=_Parser,
                            required=True)
    c = rsub.add_parser("check", parents=common,
                        help="check a spec against its URDF (and stand it in PyBullet)")
    c.add_argument("spec", help="a1, b1, solo12 or a robot spec .yaml")
    c.add_argument("--no-sim", action="store_true", help="skip standing the robot in PyBullet")
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.set_defaults(func=cmd_robot_check)
    i = rsub.add_parser("init", parents=common,
                        help="print a starting robot spec (YAML) for a quadruped URDF")
    i.add_argument("urdf", help="the quadruped's URDF file")
    i.add_argument("--name", default=None, help="robot name (default: from the URDF)")
    i.add_argument("--out", default=None, help="write the YAML here (an existing file is kept)")
    i.set_defaults(func=cmd_robot_init)

    p = add("paper", help="the paper's studies end to end, with a budget scale")
    p.add_argument("--robot", default="a1", help="a1 (convex MPC; adds A1→B1 transfer) or solo12")
    p.add_argument("--actor", default=None, help="default: convex for a1, kinodynamic for solo12")
    p.add_argument("--scale", type=_scale, default=0.03,
                   help=f"budget scale, 1.0 = the paper's budgets ({MAPPING_DOC}); default 0.03")
    p.add_argument("--phase1-evals", type=int, default=None, help="override the phase-1 budget")
    p.add_argument("--phase3-evals", type=int, default=None,
                   help="override the phase-3 (and baseline) budget")
    p.add_argument("--out", default=None, help="output directory (default paper-<robot>)")
    p.add_argument("--workers", type=int, default=2, help="parallel rollouts")
    p.add_argument("--seed", type=argtypes.seed, default=0,
                   help="seed of the studies and target tasks (--seeds N: study seed + i at index i)")
    p.add_argument("--steps", type=int, default=5000, help="rollout horizon in 1 kHz steps")
    p.add_argument("--v-des", type=float, default=0.5, help="desired forward velocity [m/s]")
    p.add_argument("--report-only", action="store_true", help="only (re)write DIR/report.md")
    p.add_argument("--sources-only", action="store_true",
                   help="only the phase-1 source runs (resumed later by the full command)")
    p.add_argument("--seeds", type=_seeds, default=1,
                   help="repeat phase 3, the transfer rows and the baselines over N seeds on the "
                        "same sources (median and IQR in the report; default 1)")
    p.add_argument("--studies", nargs="+", default=None, metavar="KEY",
                   help="only these studies of the plan (e.g. a1-trot-preservation); another "
                        "process may run the rest on the same --out")
    p.add_argument("--vae-epochs", type=int, default=None,
                   help="the sources' VAE training epochs (default: ~2000 Adam steps, at least "
                        "100 epochs); recorded, and a resume must give the same")
    p.add_argument("--no-sim", action="store_true",
                   help="report: skip re-simulated CoM plots/GIFs (an earlier report's are removed)")
    p.add_argument("--no-gif", action="store_true",
                   help="report: skip the GIFs (an earlier report's are removed)")
    p.set_defaults(func=cmd_paper)

    p = add("bench", help="the performance-ratio benchmarks at a quick size")
    p.add_argument("--steps", type=int, default=2000, help="rollout steps")
    p.add_argument("--n", type=int, default=8, help="rollouts of the throughput benchmark")
    p.add_argument("--timeout", type=float, default=900, help="per benchmark [s] (inf: none)")
    p.set_defaults(func=cmd_bench)
    return parser


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


class _LineFormatter(logging.Formatter):
    """``latentune: message`` (``latentune: warning: …`` at WARNING and above), one line."""

    def format(self, record: logging.LogRecord) -> str:
        msg = _one_line(record.getMessage())
        if record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            msg += f" ({type(exc).__name__}: {_one_line(exc)[:200]})"
        if record.levelno >= logging.ERROR:
            return f"latentune: error: {msg}"
        if record.levelno >= logging.WARNING:
            return f"latentune: warning: {msg}"
        return f"latentune: {msg}"


@contextmanager
def _cli_logging() -> Iterator[Callable[[int], None]]:
    """Route the ``latentune`` loggers and Python warnings to stderr, one line each, for the
    duration of one command; yields a function setting the level. Restored on exit."""
    logger = logging.getLogger("latentune")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LineFormatter())
    saved = (logger.level, logger.propagate, warnings.showwarning)

    def show(message: Any, category: type, filename: str, lineno: int, file: Any = None,
             line: Any = None) -> None:     # deprecations are for developers: -v only
        dev = issubclass(category, (DeprecationWarning, PendingDeprecationWarning))
        logger.log(logging.INFO if dev else logging.WARNING, "%s", message)

    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False
    warnings.showwarning = show
    try:
        yield logger.setLevel
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]
        warnings.showwarning = saved[2]


def _stdout_closed() -> int:
    """stdout's reader went away (``| head``): no traceback, nothing more written, exit 141."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())      # the interpreter's final flush goes nowhere
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass
    return 141


def _cluster_lost(exc: BaseException, args: argparse.Namespace | None,
                  argv: Sequence[str] | None) -> str:
    """The line of a lost Ray head: what happened, where the stored trials are, the command
    that resumes (this one with ``--resume``)."""
    words = list(sys.argv[1:] if argv is None else argv)
    where = f" in {args.out}" if getattr(args, "out", None) else ""
    if args is not None and hasattr(args, "resume"):
        cmd = shlex.join(["latentune", *words, *([] if "--resume" in words else ["--resume"])])
        again = (f"resume with `{cmd}` once the cluster is back (or with --backend process "
                 "in place of the Ray flags)")
    else:
        again = f"run `{shlex.join(['latentune', *words])}` again once the cluster is back"
    return f"{_one_line(exc)}; the trials stored{where} are safe: {again}"


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``docker stop``, a batch system's time limit) stops a command as
    Ctrl-C does: its workers are stopped and one line says so (it killed the process at once,
    leaving the pool's semaphore warnings or Ray's crash dump on stderr)."""


@contextmanager
def _sigterm_stops() -> Iterator[None]:
    """While a command runs, SIGTERM raises :class:`_Terminated` (the main thread only);
    the previous handler is restored after."""
    import signal

    def stop(signum: int, frame: Any) -> None:
        raise _Terminated

    try:
        prev = signal.signal(signal.SIGTERM, stop)
    except ValueError:                         # not the main thread: left as it is
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, prev)


def _error(msg: str) -> int:
    print(f"latentune: error: {msg}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status. Without ``argv`` (the process's own
    command line: the ``latentune`` script, ``python -m latentune.cli``) it returns with
    SIGINT and SIGTERM ignored, for the process to exit with that status
    (:func:`_exit_uninterrupted`); give ``argv`` to run a command within a program."""
    from latentune.threads import one_thread_env
    from latentune.wording import command_line_words

    one_thread_env()  # before numpy is imported: rollouts are many small matrix operations
    status: dict[str, int] = {}
    try:
        with _cli_logging() as set_level, _sigterm_stops(), command_line_words():
            status["code"] = _command(argv, set_level)
    except KeyboardInterrupt as exc:    # while the handlers were set or restored
        status.setdefault("code", 143 if isinstance(exc, _Terminated) else 130)
    if argv is None:                    # the process's command line: it exits next
        _exit_uninterrupted()
    return status["code"]


def _exit_uninterrupted() -> None:
    """The command has ended and its status is decided: a Ctrl-C or SIGTERM from here on is
    ignored, so the process exits with the command's status. The interpreter's shutdown (a
    second or so tearing down torch's modules) restores the default handlers, and a Ctrl-C
    there killed the process silently (status -2) after ``ask`` had printed and stored its
    suggestions; an ignored signal stays ignored through the shutdown."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, KeyboardInterrupt):   # not the main thread; or it landed now
            pass


def _command(argv: Sequence[str] | None, set_level: Callable[[int], None]) -> int:
    """Parse ``argv`` and run its command; return the exit status. An interrupt (Ctrl-C,
    SIGTERM) is status 130 (143), unless it landed after the command's work was done and
    reported (:func:`work_done`, or the command returned): then the command's status (0)."""
    from concurrent.futures.process import BrokenProcessPool

    args: argparse.Namespace | None = None
    code: int | None = None
    try:
        args = build_parser().parse_args(argv)
        set_level(logging.ERROR if args.quiet else
                  logging.INFO if args.verbose else logging.WARNING)
        func: Callable[[argparse.Namespace], int] = args.func
        code = func(args)
        sys.stdout.flush()                 # a closed pipe is seen here, not at exit
        return code
    except LatentuneError as exc:
        from latentune.pipeline.evaluators import ClusterLost   # numpy: not at import

        if isinstance(exc, ClusterLost):
            return _error(_cluster_lost(exc, args, argv))
        return _error(_one_line(exc))
    except BrokenPipeError:
        return _stdout_closed()
    except OSError as exc:
        if exc.errno not in DISK_ERRNOS:
            raise
        where = f" ({exc.filename})" if exc.filename else ""
        again = ("rerun with --resume" if hasattr(args, "resume") else
                 "run the command again")
        return _error(f"cannot write{where}: {exc.strerror or exc}; the stored evaluations "
                      f"are kept: free space and {again}")
    except Exception as exc:  # noqa: BLE001 - a dead worker is one line; anything else a bug
        if not (isinstance(exc, BrokenProcessPool) or type(exc).__module__.startswith("ray.")):
            raise
        return _error(f"an evaluation worker died ({type(exc).__name__}: "
                      f"{_one_line(exc)[:200]}); the finished evaluations are stored: rerun "
                      "with --resume")
    except KeyboardInterrupt as exc:
        if code is not None or is_done(args):
            logging.getLogger("latentune.cli").info(
                "interrupted after the command finished: its results are complete")
            return 0 if code is None else code
        # what an interrupt leaves: a command may say it (set_defaults(interrupt_note=...))
        note = getattr(args, "interrupt_note", None) or "stored results are kept"
        if isinstance(exc, _Terminated):
            print(f"latentune: error: terminated (SIGTERM); {note}", file=sys.stderr)
            return 143
        print(f"latentune: error: interrupted; {note}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

