"""Integrations with other tools (optional extras).

* :mod:`latentune.integrations.optuna` — ``LatentSampler`` (phase 3) and ``TurboSampler``
  (phase 1) as Optuna samplers, and ``import_optuna_study`` (an Optuna study as a phase-1 run);
* :mod:`latentune.integrations.dashboard` — a latentune run shown live in ``optuna-dashboard``.

Both need ``pip install 'latentune[optuna]'``. :func:`register_cli` adds their commands
(``import-optuna``, ``dashboard``) to the ``latentune`` command line without importing Optuna:
a command run without the extra stops with one line naming the install command.
"""
from __future__ import annotations

import argparse
from typing import Any, Sequence

from latentune import argtypes
from latentune.wording import counted
from latentune.workdone import work_done

INSTALL_HINT = "install the optuna extra: pip install 'latentune[optuna]'"


def _need(module: str) -> Any:
    """Import ``latentune.integrations.<module>``; a CLIError with the install hint if the
    extra is missing."""
    import importlib

    from latentune.errors import CLIError

    try:
        return importlib.import_module(f"latentune.integrations.{module}")
    except ImportError as exc:
        raise CLIError(f"{exc.name or 'a dependency'} is not installed: {INSTALL_HINT}") from None


def cmd_import_optuna(args: argparse.Namespace) -> int:
    """``latentune import-optuna STORAGE [--study NAME] --out DIR [--space FILE] [--seed S]
    [--train-latent [--latent-dim D] [--vae-epochs E]]``."""
    from latentune.errors import CLIError

    for flag, v in (("latent-dim", args.latent_dim), ("vae-epochs", args.vae_epochs)):
        if v is not None and not args.train_latent:
            raise CLIError(f"--{flag} needs --train-latent")
        if v is not None and v < 1:
            raise CLIError(f"--{flag} must be >= 1, got {v}")
    mod = _need("optuna")
    space = None
    if args.space is not None:
        space = _load_space(args.space)
    study = mod.import_optuna_study(args.storage, args.study, args.out, space, seed=args.seed)
    from latentune.constants import Phase

    with study:
        rows = study.store.rows(Phase.PHASE1)
        best = study.store.best(Phase.PHASE1)
        print(f"{args.out}: phase 1 holds {counted(len(rows), 'trial')} "
              f"({counted(sum(r.fell for r in rows), 'fall')}), "
              + ("no trial without a fall" if best is None else f"best cost {best.cost:.6g}"))
        if args.train_latent:
            _check_imported_latent_dim(study, args)
            latent = study.train_latent(args.latent_dim, epochs=args.vae_epochs)
            print(f"latent space ({latent.kind}, d_low {latent.d_low}) trained on "
                  f"{latent.meta.get('n_train', '?')} θ that did not fail: "
                  f"LatentSampler({str(args.out)!r}) can use it")
        work_done(args)             # the work is done and reported: an interrupt exits 0
    return 0


def _check_imported_latent_dim(study: Any, args: argparse.Namespace) -> None:
    """CLIError naming --latent-dim, and the train-vae command that trains the run now
    holding the imported trials, when --latent-dim does not fit the imported space."""
    import shlex

    from latentune.errors import CLIError

    dim, ld = study.space().dim, args.latent_dim
    if ld is not None and not 1 <= ld < dim:
        raise CLIError(f"--latent-dim {ld}: the latent space of a {dim}-dim θ needs a size in "
                       f"[1, {dim - 1}]; the trials are imported: train it with "
                       f"latentune train-vae --out {shlex.quote(str(args.out))} --latent-dim N")


def cmd_dashboard(args: argparse.Namespace) -> int:
    """``latentune dashboard DIR [--port P] [--interval S] [--journal FILE]``."""
    from latentune.errors import CLIError

    mod = _need("dashboard")
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)   # not a line per exported study
    if not 1 <= args.port <= 65535:
        raise CLIError(f"--port must be in [1, 65535], got {args.port}")
    if not args.interval > 0:
        raise CLIError(f"--interval must be > 0, got {args.interval}")
    mod.serve(args.dir, port=args.port, interval=args.interval, journal=args.journal,
              quiet=bool(getattr(args, "quiet", False)))
    return 0


def _load_space(path: str) -> Any:
    """A ParameterSpace from a YAML/JSON file (``names, low, high, log, manual``); CLIError
    with one line for a missing or malformed file."""
    from pathlib import Path

    import yaml

    from latentune import yamltext
    from latentune.errors import CLIError
    from latentune.space import ParameterSpace

    p = Path(path)
    if p.is_dir():
        raise CLIError(f"--space: {p} is a directory, not a file")
    if not p.is_file():
        raise CLIError(f"--space: file not found: {p}")
    try:
        data = yamltext.load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CLIError(f"--space {p}: not valid YAML/JSON ({yamltext.problem(exc)})") from None
    try:
        return ParameterSpace.from_dict(data)
    except (ValueError, TypeError) as exc:
        raise CLIError(f"--space {p}: {exc}") from None


def register_cli(sub: Any, parents: Sequence[argparse.ArgumentParser] = ()) -> None:
    """Add ``import-optuna`` and ``dashboard`` to the ``latentune`` subcommands ``sub`` (the
    object ``ArgumentParser.add_subparsers`` returned); ``parents``: parsers whose flags every
    command shares (the CLI's ``-v/--verbose``, ``--quiet``). Optuna is imported only when one
    of them runs."""
    p = sub.add_parser("import-optuna", parents=list(parents),
                       help="an Optuna study (RDB URL, SQLite or journal file) as a phase-1 run")
    p.add_argument("storage", help="sqlite:///file.db, another RDB URL, a .db or a journal file")
    p.add_argument("--study", default=None, help="the study name (default: the only study)")
    p.add_argument("--out", required=True, type=argtypes.run_dir,
                   help="the latentune run directory to write")
    p.add_argument("--space", default=None, metavar="FILE",
                   help="YAML/JSON parameter space to use (default: from the distributions)")
    p.add_argument("--seed", type=argtypes.seed, default=None,
                   help="the run's seed (default: the stored one, else 0)")
    p.add_argument("--train-latent", action="store_true",
                   help="then train the latent space (phase 2) on the trials that did not fail")
    p.add_argument("--latent-dim", type=int, default=None,
                   help="latent size with --train-latent (default: by the number of parameters)")
    p.add_argument("--vae-epochs", type=int, default=None, help="VAE epochs (default: by size)")
    p.set_defaults(func=cmd_import_optuna)

    p = sub.add_parser("dashboard", parents=list(parents), help="show a run live in optuna-dashboard (localhost)")
    p.add_argument("dir", type=argtypes.run_dir, help="run directory")
    p.add_argument("--port", type=int, default=8080, help="port on 127.0.0.1 (default 8080)")
    p.add_argument("--interval", type=float, default=2.0,
                   help="seconds between reads of the run store (default 2)")
    p.add_argument("--journal", default=None, metavar="FILE",
                   help="also keep the exported trials in this Optuna journal file")
    p.set_defaults(func=cmd_dashboard,      # what an interrupt before it serves leaves
                   interrupt_note="the run is unchanged (the dashboard only reads it)")
