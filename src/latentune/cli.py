"""Command line: ``latentune rollout | tune | phase1 | train-vae | phase3 | report | paper | bench``.

Bad input exits with status 2 and one line on stderr (``latentune: error: …``), never a traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Callable, Sequence

# one BLAS/OpenMP thread: rollouts are many small matrix ops (22x slower with default threading)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


class CLIError(Exception):
    """A user error reported as one line on stderr with exit status 2."""


def _die(msg: str, code: int = 2) -> int:
    msg = " ".join(str(msg).split())  # one line
    print(f"latentune: error: {msg}", file=sys.stderr)
    return code


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (argparse prints usage otherwise)
        raise CLIError(message)


def add_task_args(p: argparse.ArgumentParser) -> None:
    """The task flags shared by every command that simulates."""
    p.add_argument("--robot", default="a1", help="a1, b1, solo12 or a robot spec .yaml")
    p.add_argument("--task", default="trot", help="gait: trot or jump")
    p.add_argument("--terrain", default="flat", help="flat or hills")
    p.add_argument("--actor", default="convex", help="convex or kinodynamic")
    p.add_argument("--steps", type=int, default=5000, help="rollout horizon in 1 kHz steps")
    p.add_argument("--v-des", type=float, default=0.5, help="desired forward velocity [m/s]")
    p.add_argument("--seed", type=int, default=0, help="seed (terrain, critic, everything)")


def make_task(args: argparse.Namespace):
    from latentune.robots import RobotSpecError
    from latentune.task import Task

    try:
        return Task(robot=args.robot, gait=args.task, terrain=args.terrain, actor=args.actor,
                    v_des=args.v_des, steps=args.steps, seed=args.seed)
    except RobotSpecError as exc:
        raise CLIError(str(exc)) from None
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def cmd_rollout(args: argparse.Namespace) -> int:
    from latentune.actor.parameter_space import ParamsError

    task = make_task(args)
    try:
        theta = task.space.load(args.params) if args.params else task.space.manual
    except ParamsError as exc:
        raise CLIError(str(exc)) from None
    for path in (args.gif, args.plot):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            raise CLIError(f"output directory does not exist: {os.path.dirname(os.path.abspath(path))}")
    res = task.rollout(theta, record=bool(args.plot), gif=args.gif)
    if args.plot:
        from latentune.plots import plot_rollouts

        plot_rollouts({"rollout": res}, args.plot, v_des=float(task.v_des[0]),
                      title=f"{task.robot_name} {task.gait} ({task.terrain}, {task.actor})")
    out = res.summary()
    out.update(task.config())
    if args.json:
        print(json.dumps(out))
    else:
        state = f"FELL at step {res.fall_step} ({res.reason})" if res.fell else "stable"
        print(f"{task.robot_name} {task.gait} on {task.terrain} [{task.actor}]: cost {res.cost:.3f}, "
              f"{state}, mean vx (last 3 s) {res.mean_vx:.3f} m/s, height {res.mean_height:.3f} m, "
              f"{res.steps} steps in {res.wall_s:.2f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="latentune", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, required=True)
    p = sub.add_parser("rollout", help="simulate one rollout and print its path cost")
    add_task_args(p)
    p.add_argument("--params", help="JSON file: list of normalized θ or object of physical values")
    p.add_argument("--gif", help="write a GIF of the motion here")
    p.add_argument("--plot", help="write a PNG of CoM velocity and height here")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_rollout)
    import importlib

    for mod in ("latentune.pipeline.commands", "latentune.experiments.commands"):
        try:
            add_commands = importlib.import_module(mod).add_commands
        except (ImportError, AttributeError):
            continue
        add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        func: Callable[[argparse.Namespace], int] = args.func
        return func(args)
    except CLIError as exc:
        return _die(str(exc))
    except KeyboardInterrupt:
        return _die("interrupted; stored results are kept", 130)


if __name__ == "__main__":
    sys.exit(main())
