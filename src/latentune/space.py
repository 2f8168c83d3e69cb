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
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from latentune.errors import ParamsError, UsageError


def _vec(name: str, v: Any, d: int, dtype: type) -> np.ndarray:
    """``v`` as a (d,) array of ``dtype``: a flat list of d entries (a number for d = 1);
    UsageError naming ``name`` for nested lists, text, true/false where numbers are meant, or
    another count."""
    try:
        given = np.asarray(v, dtype=object)
    except (TypeError, ValueError):
        raise UsageError(f"ParameterSpace: {name} must be a flat list of {d} numbers (one per "
                         f"name), got {_short(v)}") from None
    if given.ndim > 1 or any(isinstance(x, (list, tuple, np.ndarray))
                             for x in given.reshape(-1)):
        raise UsageError(f"ParameterSpace: {name} must be a flat list of {d} entries (one per "
                         f"name), not nested: got {_short(v)}")
    if dtype is not bool and any(isinstance(x, (str, bytes)) for x in given.reshape(-1)):
        raise UsageError(f"ParameterSpace: {name} must be numbers, not text: got {_short(v)}")
    if dtype is not bool and any(isinstance(x, (bool, np.bool_)) for x in given.reshape(-1)):
        raise UsageError(f"ParameterSpace: {name} must be numbers, not true/false: got {_short(v)}")
    if dtype is bool and any(not isinstance(x, (bool, np.bool_)) and x not in (0, 1)
                             for x in given.reshape(-1)):
        raise UsageError(f"ParameterSpace: {name} entries must be true or false, got {v!r}")
    try:
        a = np.asarray(v, dtype=dtype).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise UsageError(f"ParameterSpace: {name} must be numbers, got {_short(v)}") from None
    if a.shape != (d,):
        raise UsageError(f"ParameterSpace: {name} must have {d} entries (one per name), got {a.shape[0]}")
    return a


TUNED_FOR = "tuned_for"
"""The entry of a ``--params`` file written by latentune that records what its θ was tuned
for: an object (:func:`tuned_for_text`), where a parameter's value is a number."""


def task_tuned_for(robot: Any, gait: Any, actor: Any) -> dict[str, Any]:
    """The :data:`TUNED_FOR` record of θ of a built-in task: its robot's name, gait and actor
    (not its terrain, reality or engine)."""
    return {"robot": robot, "gait": gait, "actor": actor}


def tuned_for_text(record: Any) -> str:
    """A tuned-for record as a person reads it: "b1 trot (convex)" for a built-in robot's,
    "the system mymodule:make" for a user system's, any other as its JSON."""
    if isinstance(record, dict) and {"robot", "gait", "actor"} <= set(record):
        return f"{record['robot']} {record['gait']} ({record['actor']})"
    if isinstance(record, dict) and set(record) == {"system"}:
        return f"the system {record['system']}"
    return json.dumps(record, sort_keys=True, default=str)


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 40 else r[:37] + "..."


def _shape_error(what: str, shape: tuple[int, ...], d: int) -> ParamsError:
    return ParamsError(f"{what} must have shape ({d},) or (n, {d}), got {shape}")


class ParameterSpace:
    """Names, bounds and scales of θ, and the manual-tuned θ.

    ``ParameterSpace(names, low, high, log=None, manual=None)``:

    Args:
        names: d distinct entry names.
        low, high: (d,) physical bounds, low < high, finite.
        log: (d,) True where the entry is log-scaled (then low > 0); default all linear.
        manual: (d,) the hand-tuned θ in physical units, inside the bounds; default the centre
            of the unit box. Phase 1 starts its first trust region there.

    Attributes ``low``, ``high`` (read-only, the constructor's names), ``log``,
    ``manual_physical`` hold the (d,) arrays; ``lower``, ``upper`` remain, the same arrays as
    ``low``, ``high``.
    Raises :class:`~latentune.errors.UsageError` (a ``ValueError``) for inconsistent arguments,
    for a blank name or one with a line break, and for bounds whose width (log entries: whose
    ratio high / low) a float64 cannot hold. ``stored``: the space of a stored run, read back
    (names taken as they were recorded before blank ones were refused). ``name``: what the
    space is called (e.g. the file it was read from; attribute ``name``, None by default): an
    ask/tell run's report is titled with it; it is not part of the space (:meth:`to_dict`,
    ``==``). Attribute ``tuned_for``: what θ of this space are tuned for (a built-in task
    sets it: robot, gait, actor), or None: :meth:`load` refuses a file that records another
    (:data:`TUNED_FOR`); not part of the space either.
    """

    def __init__(self, names: Sequence[str], low: Any, high: Any, log: Any = None,
                 manual: Any = None, *, stored: bool = False, name: str | None = None) -> None:
        if name is not None and (not isinstance(name, str) or not name.strip()
                                 or not name.isprintable()):
            raise UsageError(f"ParameterSpace: name must be text on one line, got {name!r:.60}")
        self.name = name
        self.tuned_for: dict[str, Any] | None = None
        if isinstance(names, (str, bytes)) or not isinstance(names, Iterable):
            raise UsageError(f"ParameterSpace: names must be a list of d names, got {_short(names)}")
        names_t = tuple(str(n) for n in names)
        d = len(names_t)
        if d < 1:
            raise UsageError("ParameterSpace needs at least one name")
        blank = None if stored else \
            next((n for n in names_t if not n.strip() or not n.isprintable()), None)
        if blank is not None:               # "=0.5" or a line break in ask's one-line answer
            raise UsageError(f"ParameterSpace names must be text on one line, not blank "
                             f"(got {blank!r})")
        if len(set(names_t)) != d:
            dup = next(n for n in names_t if names_t.count(n) > 1)
            raise UsageError(f"ParameterSpace names must be distinct ({dup!r} is given twice)")
        lower = _vec("low", low, d, float)
        upper = _vec("high", high, d, float)
        lg = np.zeros(d, bool) if log is None else _vec("log", log, d, bool)
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
            raise UsageError("ParameterSpace bounds must be finite")
        if np.any(lower >= upper) or np.any(lower[lg] <= 0):
            i = int(np.flatnonzero((lower >= upper) | (lg & (lower <= 0)))[0])
            raise UsageError(f"ParameterSpace needs low < high and low > 0 on log entries "
                             f"({names_t[i]}: [{lower[i]:g}, {upper[i]:g}]{' log' if lg[i] else ''})")
        with np.errstate(over="ignore"):
            span = np.where(lg, upper / np.where(lg, lower, 1.0), upper - lower)
        if not np.all(np.isfinite(span)):
            i = int(np.flatnonzero(~np.isfinite(span))[0])
            raise UsageError(f"ParameterSpace: {names_t[i]}'s range [{lower[i]:g}, {upper[i]:g}] "
                             f"is too wide: its {'ratio' if lg[i] else 'width'} overflows a float64")
        self.names = names_t
        self.lower = lower
        self.upper = upper
        self.log = lg
        if manual is None:
            man = self.to_physical(np.full(d, 0.5))
        else:
            man = _vec("manual", manual, d, float)
            if not np.all(np.isfinite(man)):
                raise UsageError("ParameterSpace manual values must be finite")
            tol = 1e-9 * np.maximum(np.abs(upper - lower), 1.0)
            if np.any(man < lower - tol) or np.any(man > upper + tol):
                i = int(np.flatnonzero((man < lower - tol) | (man > upper + tol))[0])
                raise UsageError(f"ParameterSpace: manual {names_t[i]} = {man[i]:g} is outside "
                                 f"[{lower[i]:g}, {upper[i]:g}]")
        self.manual_physical = man

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ParameterSpace) and self.to_dict() == other.to_dict()

    def __repr__(self) -> str:
        return f"ParameterSpace(dim={self.dim}, names={list(self.names[:3])}{'...' if self.dim > 3 else ''})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (recorded in the run store); :meth:`from_dict` reads it back."""
        return {"names": list(self.names), "low": self.lower.tolist(), "high": self.upper.tolist(),
                "log": self.log.tolist(), "manual": self.manual_physical.tolist()}

    def box_difference(self, other: dict[str, Any]) -> str | None:
        """Why unit-box θ of the space ``other`` (:meth:`to_dict`'s form, e.g. another run's)
        would mean other physical values here: the first name, bound or scale that differs,
        as ``"b: [0, 1] there, [0, 100] here"``; None when they are the same (the manual θ
        aside)."""
        names = list(other.get("names") or [])
        diff = self.names_difference(names)
        if diff is not None:
            return diff
        try:
            lo, hi = np.asarray(other["low"], float), np.asarray(other["high"], float)
            lg = np.zeros(self.dim, bool) if other.get("log") is None else \
                np.asarray(other["log"], bool)
            if not lo.shape == hi.shape == lg.shape == (self.dim,):
                raise ValueError
        except (KeyError, TypeError, ValueError):
            return "bounds that cannot be read (low, high and log of one entry per name)"
        for i, n in enumerate(self.names):
            if lg[i] != self.log[i] or not (np.isclose(lo[i], self.lower[i], rtol=1e-9, atol=0)
                                            and np.isclose(hi[i], self.upper[i], rtol=1e-9,
                                                           atol=0)):
                def box(a: float, b: float, log: bool) -> str:
                    return f"[{a:g}, {b:g}]" + (" log" if log else "")
                return (f"{n}: {box(lo[i], hi[i], bool(lg[i]))} there, "
                        f"{box(self.lower[i], self.upper[i], bool(self.log[i]))} here")
        return None

    def names_difference(self, names: Sequence[str]) -> str | None:
        """How the names ``names`` (another space's, "there") differ from this space's
        ("here"): ``"the same names in another order (b, a there; a, b here)"`` or ``"other
        names (e there, not here; d here, not there)"`` (up to 4 of each, in order); None when
        they are the same, in the same order."""
        there, here = [str(n) for n in names], list(self.names)
        if there == here:
            return None

        def some(v: list[str]) -> str:
            return ", ".join(v[:4]) + (", …" if len(v) > 4 else "")
        if sorted(there) == sorted(here):
            return f"the same names in another order ({some(there)} there; {some(here)} here)"
        only_there = [n for n in there if n not in here]
        only_here = [n for n in here if n not in there]
        parts = ([f"{some(only_there)} there, not here"] if only_there else []) + \
            ([f"{some(only_here)} here, not there"] if only_here else [])
        return f"other names ({'; '.join(parts) or 'a name given twice'})"

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, stored: bool = False,
                  name: str | None = None) -> "ParameterSpace":
        """Build a space from :meth:`to_dict`'s form (also the ``--space`` YAML/JSON file form;
        ``stored``: a stored run's, ``name``: its name, see the class). Raises
        :class:`~latentune.errors.UsageError` (a ``ValueError``) for missing keys or
        inconsistent values."""
        if not isinstance(d, dict) or not {"names", "low", "high"} <= set(d):
            raise UsageError("a parameter space needs the keys names, low, high (log, manual optional)")
        unknown = sorted(set(d) - {"names", "low", "high", "log", "manual"}, key=str)
        if unknown:
            raise UsageError(f"a parameter space has the keys names, low, high, log and manual, "
                             f"not {', '.join(map(str, unknown))}")
        return cls(d["names"], d["low"], d["high"], d.get("log"), d.get("manual"), stored=stored,
                   name=name)

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def low(self) -> np.ndarray:
        """(d,) lower physical bounds, the constructor's ``low``: the array ``lower`` holds."""
        return self.lower

    @property
    def high(self) -> np.ndarray:
        """(d,) upper physical bounds, the constructor's ``high``: the array ``upper`` holds."""
        return self.upper

    @property
    def manual(self) -> np.ndarray:
        """(d,) manual-tuned θ in the unit box."""
        return self.to_unit(self.manual_physical)

    def _points(self, v: Any, what: str) -> np.ndarray:
        """``v`` as a float array of shape (d,) or (n, d); ParamsError otherwise."""
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise ParamsError(f"{what} must be numbers, got {_short(v)}") from None
        if a.ndim not in (1, 2) or a.shape[-1] != self.dim:
            raise _shape_error(what, a.shape, self.dim)
        return a

    def to_physical(self, u: np.ndarray) -> np.ndarray:
        """(d,) or (n, d) unit-box θ -> physical values of the same shape (clipped to the box
        first). ParamsError for another shape."""
        u = np.clip(self._points(u, "a unit-box θ"), 0.0, 1.0)
        lin = self.lower + (self.upper - self.lower) * u
        ratio = np.where(self.log, self.upper, 1.0) / np.where(self.log, self.lower, 1.0)
        logv = self.lower * ratio ** u             # 1 ** u on linear entries: no nan warning
        return np.where(self.log, logv, lin)

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        """(d,) or (n, d) physical values -> unit-box θ of the same shape (not clipped: a value
        outside the bounds maps outside [0, 1]). ParamsError for another shape."""
        x = self._points(x, "a physical θ")
        lo_l = np.log(np.where(self.log, self.lower, 1.0))
        hi_l = np.log(np.where(self.log, self.upper, 2.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            logu = (np.log(np.maximum(x, 1e-300)) - lo_l) / (hi_l - lo_l)
        linu = (x - self.lower) / (self.upper - self.lower)
        return np.where(self.log, logu, linu)

    def as_dict(self, u: np.ndarray) -> dict[str, float]:
        """A (d,) unit-box θ as physical values by name (a ``--params`` JSON file's form)."""
        x = self.to_physical(u)
        if x.ndim != 1:
            raise ParamsError(f"as_dict takes one θ of shape ({self.dim},), got {x.shape}")
        return {n: float(v) for n, v in zip(self.names, x)}

    def as_file(self, u: np.ndarray, tuned_for: dict[str, Any] | None = None) -> dict[str, Any]:
        """A (d,) unit-box θ as the JSON object of a ``--params`` file latentune writes: its
        values by name (:meth:`as_dict`) and, when ``tuned_for`` is given (and no parameter
        has that name), the record of what it was tuned for under :data:`TUNED_FOR`."""
        out: dict[str, Any] = self.as_dict(u)
        if tuned_for is not None and TUNED_FOR not in self.names:
            out[TUNED_FOR] = tuned_for
        return out

    def validate_unit(self, u: Any) -> np.ndarray:
        """Check a normalized θ: length d, finite, inside [0, 1] (1e-9 slack). Returns (d,) floats."""
        try:
            arr = np.asarray(u, dtype=float)
        except (TypeError, ValueError):
            raise ParamsError("parameters must be numbers") from None
        except OverflowError:
            raise ParamsError("parameters must be numbers a float can hold") from None
        if arr.shape != (self.dim,):
            raise ParamsError(f"expected {self.dim} normalized parameters, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ParamsError("parameters contain NaN or inf")
        bad = np.flatnonzero((arr < -1e-9) | (arr > 1 + 1e-9))
        if bad.size:
            i = int(bad[0])
            raise ParamsError(f"normalized parameter {self.names[i]} = {arr[i]:g} is outside [0, 1]")
        return np.clip(arr, 0.0, 1.0)

    def parse(self, obj: Any, tuned_for: dict[str, Any] | None = None,
              source: str = "the params") -> np.ndarray:
        """θ from a JSON value: a list of d normalized values, or an object of physical values
        by name (missing names take the manual value). Returns the unit-box θ, validated.
        An object's :data:`TUNED_FOR` record (an object) is no parameter: ParamsError (naming
        ``source``) when it differs from ``tuned_for`` (default: the space's own
        ``tuned_for``); an object without one is read whatever it was tuned for."""
        if isinstance(obj, dict) and isinstance(obj.get(TUNED_FOR), dict) \
                and TUNED_FOR not in self.names:
            obj = dict(obj)
            record = obj.pop(TUNED_FOR)
            want = self.tuned_for if tuned_for is None else tuned_for
            if want is not None and record != want:
                raise ParamsError(f"{source} holds θ tuned for {tuned_for_text(record)}, not "
                                  f"{tuned_for_text(want)} (delete its {TUNED_FOR!r} entry to "
                                  "use it anyway)")
        if isinstance(obj, dict):
            unknown = [str(k) if str(k).strip() == str(k) and str(k).isprintable()
                       else repr(str(k)) for k in obj if k not in self.names]
            if unknown:                 # a space, tab or line break in a name shown as such
                more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
                mine = ", ".join(self.names[:3]) + (f", …, {self.dim} in all"
                                                     if self.dim > 3 else "")
                raise ParamsError(f"unknown parameter name(s): {', '.join(unknown[:5])}{more} "
                                  f"(this system's: {mine})")
            phys = self.manual_physical.copy()
            for k, v in obj.items():
                try:
                    finite = math.isfinite(v)
                except (TypeError, OverflowError):
                    finite = False
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not finite:
                    shown = repr(v) if len(repr(v)) <= 40 else repr(v)[:37] + "..."
                    raise ParamsError(f"parameter {k} must be a finite number, got {shown}")
                i = self.names.index(k)
                slack = 1e-9 * max(abs(self.lower[i]), abs(self.upper[i]), 1e-300)
                if not (self.lower[i] - slack <= v <= self.upper[i] + slack):
                    raise ParamsError(f"parameter {k} = {v:g} is outside [{self.lower[i]:g}, {self.upper[i]:g}]")
                phys[i] = float(v)
            return self.validate_unit(np.clip(self.to_unit(phys), 0.0, 1.0))
        if isinstance(obj, (list, tuple)):
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in obj):
                raise ParamsError("a params list must hold numbers only")
            return self.validate_unit(obj)
        raise ParamsError("params must be a JSON list of normalized values or an object of physical values")

    def load(self, path: str | Path, tuned_for: dict[str, Any] | None = None) -> np.ndarray:
        """Read a ``--params`` JSON file (see :meth:`parse`; ``tuned_for``: the record a
        file's must equal, default the space's own). A name given twice in one object
        raises :class:`ParamsError` naming it and both values (JSON alone keeps the last); every
        ParamsError names the file. The file is UTF-8, with or without a byte-order mark."""
        p = Path(path)
        if p.is_dir():
            raise ParamsError(f"params file {p} is a directory, not a file")
        if not p.is_file():
            raise ParamsError(f"params file not found: {p}")

        def unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
            out: dict[str, Any] = {}
            for k, v in pairs:
                if k in out:
                    raise ParamsError(f"params file {p} names {k} twice ({_short(out[k])}, "
                                      f"then {_short(v)})")
                out[k] = v
            return out

        try:
            obj = json.loads(p.read_text(encoding="utf-8-sig"), object_pairs_hook=unique)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ParamsError(f"params file {p} is not valid JSON ({exc.msg if hasattr(exc, 'msg') else exc})") from None
        except RecursionError:
            raise ParamsError(f"params file {p} is nested too deeply to be a params file") from None
        source = f"params file {p}"
        try:
            return self.parse(obj, tuned_for, source)
        except ParamsError as exc:      # parse's own messages do not name the file
            msg = str(exc)
            raise ParamsError(msg if msg.startswith(source) else f"{source}: {msg}") from None


def make_space(entries: Sequence[tuple[str, float, float, bool, float]]) -> ParameterSpace:
    """Build a space from rows (name, lower, upper, log, manual_physical)."""
    names, lo, hi, lg, man = zip(*entries)
    return ParameterSpace(names, lo, hi, lg, man)
