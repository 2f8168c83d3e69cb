"""ParameterSpace: the tuned vector θ, its names, bounds, scales and the unit-box mapping.

The critic always sees θ normalized to [0, 1]^d. Entry i maps to a physical value

* log scale:    x_i = lo_i · (hi_i / lo_i) ** u_i
* linear scale: x_i = lo_i + (hi_i − lo_i) · u_i

A normalized θ means the same thing on every robot and gait of one actor (the actors express
their weights in robot-independent units), which is what makes trot → jump and A1 → B1 transfer
of a latent space possible.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np


class ParamsError(ValueError):
    """A parameter vector or file that cannot be used (wrong length, NaN, out of bounds, …)."""


@dataclass(frozen=True)
class ParameterSpace:
    """Names, bounds and scales of θ; the manual-tuned θ.

    Attributes:
        names: (d,) entry names.
        lower, upper: (d,) physical bounds.
        log: (d,) True where the entry is log-scaled (then lower > 0).
        manual_physical: (d,) the manual-tuned θ in physical units.
    """

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    log: np.ndarray
    manual_physical: np.ndarray

    def __post_init__(self) -> None:
        d = len(self.names)
        for arr in (self.lower, self.upper, self.log, self.manual_physical):
            if np.shape(arr) != (d,):
                raise ValueError("ParameterSpace arrays must all have shape (d,)")
        if np.any(self.lower >= self.upper) or np.any(self.lower[self.log] <= 0):
            raise ValueError("ParameterSpace needs lower < upper and lower > 0 on log entries")

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def manual(self) -> np.ndarray:
        """(d,) manual-tuned θ in the unit box."""
        return self.to_unit(self.manual_physical)

    def to_physical(self, u: np.ndarray) -> np.ndarray:
        """(d,) or (n, d) unit-box θ -> physical values (clipped to the box first)."""
        u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
        lin = self.lower + (self.upper - self.lower) * u
        logv = self.lower * (self.upper / np.where(self.log, self.lower, 1.0)) ** u
        return np.where(self.log, logv, lin)

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        """(d,) or (n, d) physical values -> unit box."""
        x = np.asarray(x, dtype=float)
        lo_l = np.log(np.where(self.log, self.lower, 1.0))
        hi_l = np.log(np.where(self.log, self.upper, 2.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            logu = (np.log(np.maximum(x, 1e-300)) - lo_l) / (hi_l - lo_l)
        linu = (x - self.lower) / (self.upper - self.lower)
        return np.where(self.log, logu, linu)

    def as_dict(self, u: np.ndarray) -> dict[str, float]:
        """Physical values by name, for a ``--params`` JSON file."""
        return {n: float(v) for n, v in zip(self.names, self.to_physical(u))}

    def validate_unit(self, u: Any) -> np.ndarray:
        """Check a normalized θ: length d, finite, inside [0, 1] (1e-9 slack). Returns (d,) floats."""
        try:
            arr = np.asarray(u, dtype=float)
        except (TypeError, ValueError):
            raise ParamsError("parameters must be numbers") from None
        if arr.shape != (self.dim,):
            raise ParamsError(f"expected {self.dim} normalized parameters, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ParamsError("parameters contain NaN or inf")
        bad = np.flatnonzero((arr < -1e-9) | (arr > 1 + 1e-9))
        if bad.size:
            i = int(bad[0])
            raise ParamsError(f"normalized parameter {self.names[i]} = {arr[i]:g} is outside [0, 1]")
        return np.clip(arr, 0.0, 1.0)

    def parse(self, obj: Any) -> np.ndarray:
        """θ from a JSON value: a list of d normalized values, or an object of physical values
        by name (missing names take the manual value). Returns the unit-box θ, validated."""
        if isinstance(obj, dict):
            unknown = [k for k in obj if k not in self.names]
            if unknown:
                raise ParamsError(f"unknown parameter name(s): {', '.join(unknown[:5])}")
            phys = self.manual_physical.copy()
            for k, v in obj.items():
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ParamsError(f"parameter {k} must be a finite number, got {v!r}")
                i = self.names.index(k)
                if not (self.lower[i] * (1 - 1e-9) <= v <= self.upper[i] * (1 + 1e-9)):
                    raise ParamsError(f"parameter {k} = {v:g} is outside [{self.lower[i]:g}, {self.upper[i]:g}]")
                phys[i] = float(v)
            return self.validate_unit(np.clip(self.to_unit(phys), 0.0, 1.0))
        if isinstance(obj, (list, tuple)):
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in obj):
                raise ParamsError("a params list must hold numbers only")
            return self.validate_unit(obj)
        raise ParamsError("params must be a JSON list of normalized values or an object of physical values")

    def load(self, path: str | Path) -> np.ndarray:
        """Read a ``--params`` JSON file (see :meth:`parse`)."""
        p = Path(path)
        if not p.is_file():
            raise ParamsError(f"params file not found: {p}")
        try:
            obj = json.loads(p.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ParamsError(f"params file {p} is not valid JSON ({exc.msg if hasattr(exc, 'msg') else exc})") from None
        return self.parse(obj)


def make_space(entries: Sequence[tuple[str, float, float, bool, float]]) -> ParameterSpace:
    """Build a space from rows (name, lower, upper, log, manual_physical)."""
    names, lo, hi, lg, man = zip(*entries)
    return ParameterSpace(tuple(names), np.array(lo, float), np.array(hi, float),
                          np.array(lg, bool), np.array(man, float))
