"""The "work done" mark of a ``latentune`` command: a command that has printed its result
marks its parsed arguments with :func:`work_done`; an interrupt (Ctrl-C, SIGTERM) that lands
after the mark, while the command closes its run or exits, is not a failure and the command
line exits 0 (:func:`is_done`, read by ``latentune.cli``). A module apart so that the commands
other modules register on the command line (:func:`latentune.integrations.register_cli`) mark
their work without importing the CLI."""
from __future__ import annotations

import argparse
import sys


def work_done(args: argparse.Namespace) -> None:
    """Mark the command's work done and reported: stdout is flushed, then ``args`` is marked,
    so an interrupt (Ctrl-C, SIGTERM) that lands after this, while the command closes its run
    or exits, is not a failure (exit 0). A command that writes a store prints its result
    before it closes the store, then calls this."""
    sys.stdout.flush()
    args.work_done = True


def is_done(args: argparse.Namespace | None) -> bool:
    """Whether the command of ``args`` (None: not parsed yet) marked its work done
    (:func:`work_done`)."""
    return bool(getattr(args, "work_done", False))
