"""The error types of latentune.

Every error a user can cause (bad input, a missing or corrupt file, a run of another
configuration) is a :class:`LatentuneError`; the command line prints its message as one line on
stderr and exits with status 2. Anything else is a bug and keeps its traceback.
"""
from __future__ import annotations


class LatentuneError(Exception):
    """A user error: reported as one line (``latentune: error: …``), exit status 2."""


class CLIError(LatentuneError):
    """A bad command-line argument or combination of arguments."""


class UsageError(LatentuneError, ValueError):
    """An argument of the public API out of its domain (a budget < 1, an unknown method, …)."""


class ParamsError(LatentuneError, ValueError):
    """A parameter vector or file that cannot be used (wrong length, NaN, out of bounds, …)."""


class RobotSpecError(LatentuneError, ValueError):
    """A robot name or spec file that cannot be used."""


class StoreError(LatentuneError):
    """A missing, corrupt or foreign run store, or a write that would break its invariants."""


class LatentError(LatentuneError, ValueError):
    """A latent space that cannot be trained, loaded or used."""


class SystemSpecError(LatentuneError, ValueError):
    """A ``--system module:factory`` that cannot be imported or called, or a system that does
    not follow the :class:`~latentune.system.System` protocol."""


class LockError(LatentuneError):
    """Another process is writing the same run directory."""


class RobotSpecWarning(UserWarning):
    """A robot spec that loads but holds a value the user should check (e.g. a nominal height
    far from what the joint angles give)."""
