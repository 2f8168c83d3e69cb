"""Argument types shared by the ``latentune`` command line and the subcommands other modules
register on it (:func:`latentune.integrations.register_cli`): each parses one flag's text or
raises :class:`~latentune.errors.CLIError` with a one-line message naming the flag."""
from __future__ import annotations

from typing import Callable

from latentune.errors import CLIError


def seed(s: str) -> int:
    """``--seed``: an integer in [0, 2**63)."""
    try:
        v = int(s)
    except ValueError:
        raise CLIError(f"--seed must be an integer, got {s!r}") from None
    if not 0 <= v < 2 ** 63:
        raise CLIError(f"--seed must be in [0, 2**63), got {v}")
    return v


def run_dir(s: str) -> str:
    """A run directory (``--out``, ``DIR``): any path but an empty one (an unset shell variable:
    the run was written into the current directory; ``.`` says that)."""
    if not s.strip():
        raise CLIError("the run directory is empty: give a path (. for the current directory)")
    return s


def given(flag: str, what: str) -> Callable[[str], str]:
    """The type of a flag naming a file or a run (``--params``, ``--start``, ``--vae``,
    ``--fall-prior``): any text but an empty one (an unset shell variable, read as the current
    directory, as a file name, or as if the flag were left out), refused naming ``flag`` and
    ``what`` it takes."""
    def parse(s: str) -> str:
        if not s.strip():
            raise CLIError(f"{flag} is empty: give {what}, or leave {flag} out")
        return s

    parse.__name__ = flag.lstrip("-").replace("-", "_")
    return parse


params_file = given("--params", "a file name")
"""``--params``: a θ file's name (an empty one was taken for the manual θ)."""

start = given("--start", "manual, scratch or a file name")
"""ask's ``--start``: manual, scratch or a θ file's name (an empty one was read as the current
directory)."""


def other_run(flag: str) -> Callable[[str], str]:
    """The type of a flag naming another run's directory (``--vae``, ``--fall-prior``)."""
    return given(flag, "a run directory")
