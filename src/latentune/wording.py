"""Phrases of the text a user reads: counts (``counted(1, "trial")`` is "1 trial",
``counted(2, "trial")`` "2 trials") and options named as the reader sets them (:func:`option`:
a flag at the command line, a keyword in Python)."""
from __future__ import annotations

import os
import shlex
from contextlib import contextmanager
from typing import Any, Iterator


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and ``noun``: the noun as it is when ``n`` is 1, else its plural (``plural``, or
    ``noun`` + "s")."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


_COMMAND_LINE = [False]
"""Whether messages are read at the command line now (:func:`command_line_words`)."""

FLAGS = {
    # the phase options and the run's
    "max_fall_prob": "--max-fall-prob", "handover": "--handover", "escape_falls": "--escape-falls",
    "strategy": "--strategy", "budget": "--budget", "phase": "--phase", "latent": "--vae",
    "trial_timeout": "--trial-timeout", "amend": "--amend", "simulate": "--no-sim",
    "fall_prior": "--fall-prior", "backend": "--backend", "regions": "--regions",
    # a built-in task's (Task's keywords), and robot init's
    "robot": "--robot", "gait": "--task", "terrain": "--terrain", "actor": "--actor",
    "steps": "--steps", "v_des": "--v-des", "engine": "--engine", "seed": "--seed",
    "reality": "--reality", "name": "--name"}
"""The command line's flag of each Python keyword a message may advise (``simulate``: the
flag that sets it False)."""

TRANSFER_KEYS = frozenset({"escape_falls"})
"""The options the Python API takes in ``transfer_options`` rather than as a keyword."""


@contextmanager
def command_line_words() -> Iterator[None]:
    """Inside the block :func:`option` names options by the command line's flags (the command
    line's ``main`` runs every command in it); outside, by the Python API's keywords."""
    before = _COMMAND_LINE[0]
    _COMMAND_LINE[0] = True
    try:
        yield
    finally:
        _COMMAND_LINE[0] = before


def at_command_line() -> bool:
    """Whether messages are read at the command line now (inside :func:`command_line_words`)."""
    return _COMMAND_LINE[0]


def option(name: str, value: Any = None) -> str:
    """How a message names the option ``name`` (a key of :data:`FLAGS`), set to ``value`` if
    given: its flag at the command line (``--max-fall-prob 0.3``; a float with every digit it
    needs, a text or path quoted for a shell; a bool value is the flag alone), else the Python
    API's keyword (``max_fall_prob=0.3``, ``latent='runs/a'``, ``amend=True``; a transfer
    option as ``transfer_options={'escape_falls': 8}``, or ``transfer_options['escape_falls']``
    without a value)."""
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if _COMMAND_LINE[0]:
        if value is None or isinstance(value, bool):
            return FLAGS[name]
        if isinstance(value, float):       # every digit the value needs, no more
            shown = f"{value:g}" if float(f"{value:g}") == value else repr(value)
        else:
            shown = shlex.quote(value) if isinstance(value, str) else str(value)
        return f"{FLAGS[name]} {shown}"
    if name in TRANSFER_KEYS:
        return (f"transfer_options[{name!r}]" if value is None
                else f"transfer_options={{{name!r}: {value!r}}}")
    return name if value is None else f"{name}={value!r}"


def joined(options: list[str]) -> str:
    """Several :func:`option` texts as the reader writes them together: one after the other on
    a command line (``--task jump --steps 50``), a call's arguments in Python (``gait='jump',
    steps=50``)."""
    return (" " if _COMMAND_LINE[0] else ", ").join(options)
