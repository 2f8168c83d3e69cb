"""The thing being tuned: a :class:`System` is a parameter space plus ``evaluate``.

``system.space`` is a :class:`~latentune.space.ParameterSpace`; ``system.evaluate(theta)``
takes θ in the unit box ((d,) float array in [0, 1]^d: the critic's coordinates; use
``system.space.to_physical(theta)`` for physical values) and returns an :class:`Outcome`.
The built-in :class:`~latentune.task.Task` (a simulated quadruped) is one System;
:class:`FunctionSystem` wraps a plain function of the physical θ; any object with ``space`` and
``evaluate`` works.

Failed trials
-------------
``Outcome.failed`` marks a trial that was unsafe or unusable (a fall, an e-stop, a diverged
simulation). Phase 2 trains the latent space only on θ whose trial did not fail. A failed
outcome without a cost gets the project's convention: ``C1 · (2 − k/N)`` when the failure step
``k`` of ``N`` is known (``info["fall_step"]``, ``info["horizon"]``), else ``2 · C1``, with
C1 = 100 (see :mod:`latentune.constants`). That convention assumes successful trials cost less
than C1; a system on another scale should give failed trials its own cost.

Errors
------
An ``evaluate`` that raises, or returns something that is not a finite cost (None, NaN, a
string), is a defect of the system, not a failed trial: the phase stops with
:class:`EvaluationError` after storing the trials that finished (resume re-asks the rest).
"""
from __future__ import annotations

import importlib
import inspect
import json
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, runtime_checkable

import numpy as np

from latentune.constants import C1, COST_LIMIT, fail_cost
from latentune.errors import LatentuneError, SystemSpecError
from latentune.space import ParameterSpace
from latentune.wording import at_command_line


class EvaluationError(LatentuneError):
    """A system's ``evaluate`` raised or returned no usable cost."""


class CostError(EvaluationError, TypeError, ValueError):
    """A function or system returned something that is not a cost: None, a string, a bool, an
    array, a complex number, or an integer beyond the float64 range (a TypeError and a
    ValueError, so either ``except`` catches it)."""


def as_cost(value: Any, *, allow_nonfinite: bool = False,
            opening: str = "the function returned") -> float:
    """``value`` as a float cost, or :class:`CostError` naming what was returned instead.

    Accepts a real number (``int``, ``float``, a NumPy real scalar) or a 0-d array of one;
    refuses None, strings, bools, complex numbers, arrays of any other shape, and integers
    that do not fit a float64. Non-finite costs, and finite ones of :data:`~latentune.
    constants.COST_LIMIT` (1e300) in size or more (the store's code for inf), are refused
    unless ``allow_nonfinite``. Each message opens with ``opening`` followed by what was given,
    e.g. "the function returned a bool (True); expected a float cost" (``opening="got"``:
    "got a bool (True); ...").
    """
    v = value
    if isinstance(v, np.ndarray) and v.ndim == 0:
        v = v[()]
    if isinstance(v, (bool, np.bool_)):
        raise CostError(f"{opening} a bool ({v!r}); expected a float cost")
    if isinstance(v, (complex, np.complexfloating)):
        raise CostError(f"{opening} a complex number ({_short(v)}); expected a real cost")
    if isinstance(v, np.ndarray) or (hasattr(v, "shape") and hasattr(v, "ndim")
                                     and getattr(v, "ndim", 0) > 0):
        raise CostError(f"{opening} an array of shape {tuple(v.shape)}; expected one float "
                        "(e.g. float(y[0]) or y.sum())")
    if not isinstance(v, (int, float, np.integer, np.floating)):
        if hasattr(v, "item") and getattr(v, "ndim", None) == 0:     # a 0-d tensor
            return as_cost(v.item(), allow_nonfinite=allow_nonfinite, opening=opening)
        raise CostError(f"{opening} {type(v).__name__} {_short(v)}; expected a float cost")
    try:
        cost = float(v)
    except OverflowError:
        raise CostError(f"{opening} an integer too large for a float64 "
                        f"({len(str(abs(int(v))))} digits)") from None
    if not allow_nonfinite and not math.isfinite(cost):
        raise EvaluationError(_non_finite(opening, cost))
    if not allow_nonfinite and abs(cost) >= COST_LIMIT:
        raise CostError(_too_large(opening, cost))
    return cost


def as_failed(value: Any, *, opening: str = "evaluate returned") -> bool:
    """``value`` as a trial's fall flag, or :class:`EvaluationError` naming what was given.

    Accepts a bool (Python, NumPy, a 0-d array or tensor of one), the integers 0 and 1, and
    None (not failed); refuses anything else: ``bool("False")`` is True, and an array of
    several flags has no truth value. The message opens with ``opening`` (see
    :func:`as_cost`): "evaluate returned failed = 'no'; expected True or False"."""
    v = value
    if v is None:
        return False
    if hasattr(v, "item") and getattr(v, "ndim", None) == 0:   # a 0-d array or tensor
        v = v.item()
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)) and int(v) in (0, 1):
        return bool(v)
    raise EvaluationError(f"{opening} failed = {_short(v)}; expected True or False")


def _non_finite(opening: str, cost: float) -> str:
    """The message for a non-finite cost of a trial that did not fail: what was given, and how
    to record the fall it usually is (the too-large cost's message says the same)."""
    return (f"{opening} a non-finite cost ({cost}); to record a fall, mark the trial failed "
            "(tell --failed, or failed=True), or give a finite penalty")


def _too_large(opening: str, cost: float) -> str:
    """The message for a cost of :data:`~latentune.constants.COST_LIMIT` in size or more."""
    return (f"{opening} {cost:g}: a cost must be smaller than {COST_LIMIT:g} in size (the "
            "store keeps that for inf); mark the trial failed, or return a smaller penalty")


@dataclass
class Outcome:
    """What one trial gave.

    Attributes:
        cost: the cost to minimize (finite; a failed trial may leave it ``None`` to get the
            C1 convention, see the module docstring).
        failed: the trial was unsafe or unusable (a fall).
        info: free-form JSON-able details (stored with the trial), e.g. ``fall_step``,
            ``horizon``, ``reason``, ``mean_vx``.
        wall_s: the trial's wall time [s] (filled in by the evaluator when absent).
    """

    cost: float | None
    failed: bool = False
    info: dict[str, Any] = field(default_factory=dict)
    wall_s: float | None = None

    @property
    def fall_step(self) -> int | None:
        v = self.info.get("fall_step")
        return None if v is None else int(v)


OUTCOME_KEYS = frozenset({"cost", "failed", "info", "wall_s"})
"""The keys of an outcome given as a dict (those of :class:`Outcome`)."""


def as_outcome(value: Any, *, opening: str | None = None) -> Outcome:
    """Normalize what an ``evaluate``/function returned to a checked :class:`Outcome`.

    Accepts an :class:`Outcome`, a number (the cost; not failed; a 0-d array or tensor of one
    too, as :func:`as_cost` takes in the other forms), a ``(cost, failed)`` pair or a
    dict with ``cost`` and optional ``failed``, ``info``, ``wall_s`` (no other key). Raises :class:`EvaluationError` for
    anything else, and for a non-finite cost (or one of 1e300 in size or more) of a trial that
    did not fail. A failed trial's non-finite or so large cost (a simulator that blew up reports
    ``nan``) is no cost: it gets the fall convention, and ``info["reported_cost"]`` keeps what
    was reported (``"nan"``, ``"inf"``, ``"1e+300"``).

    ``opening`` is the phrase each error message opens with, before what was given: None (an
    ``evaluate``'s result) says "evaluate returned", "evaluate (its cost) returned" for the cost
    of an outcome, and "evaluate reported" for its fall step; a result given by hand passes its
    own, e.g. ``opening="got"``: "got str 'abc'; expected a float cost".
    """
    returned = opening or "evaluate returned"
    its_cost = opening or "evaluate (its cost) returned"
    reported = opening or "evaluate reported"
    if isinstance(value, Outcome):
        out = Outcome(value.cost, as_failed(value.failed, opening=returned),
                      _info(value.info, returned), value.wall_s)
    elif isinstance(value, dict):
        unknown = sorted(map(str, set(value) - OUTCOME_KEYS))
        if unknown:                     # {"cost": 1.0, "fell": True} is not a standing trial
            raise EvaluationError(f"{returned} a dict with the key(s) "
                                  f"{', '.join(unknown)}; an outcome has "
                                  f"{', '.join(sorted(OUTCOME_KEYS))} (details go in info)")
        failed = as_failed(value.get("failed"), opening=returned)
        if "cost" not in value and not failed:
            raise EvaluationError(f"{returned} a dict without 'cost': {sorted(value)}")
        out = Outcome(value.get("cost"), failed, _info(value.get("info"), returned),
                      value.get("wall_s"))
    elif isinstance(value, tuple) and len(value) == 2:
        out = Outcome(value[0], as_failed(value[1], opening=returned))
    elif (isinstance(value, (int, float, np.integer, np.floating, np.ndarray))
          or hasattr(value, "ndim")) and not isinstance(value, (bool, np.bool_)):
        # a number, or an array or tensor: as_cost takes a 0-d one and names any other shape
        out = Outcome(as_cost(value, allow_nonfinite=True, opening=returned))
    else:
        raise CostError(f"{returned} {type(value).__name__} {_short(value)}; "
                        "expected a cost (float), (cost, failed) or an Outcome")
    if out.wall_s is not None:
        w = out.wall_s
        if isinstance(w, bool) or not isinstance(w, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(w) and w >= 0):
            raise EvaluationError(f"{returned} wall_s = {_short(w)}; expected None or "
                                  "a time >= 0 in seconds")
        out.wall_s = float(w)
    if out.cost is not None:
        out.cost = as_cost(out.cost, allow_nonfinite=True, opening=its_cost)
        if out.failed and not abs(out.cost) < COST_LIMIT:   # a blown-up simulator: no cost
            out.info["reported_cost"], out.cost = str(out.cost), None
    k, horizon = out.info.get("fall_step"), out.info.get("horizon")
    if k is not None and horizon is not None:   # a horizon of 0 steps has no step to fall at
        try:
            inside = 0 <= float(k) <= float(horizon) and float(horizon) > 0
        except (TypeError, ValueError):
            inside = False
        if not inside:
            raise EvaluationError(f"{reported} fall_step {_short(k)} outside its "
                                  f"horizon of {_short(horizon)} steps (0 … horizon)")
    if k is not None and not _whole_step(k):
        raise EvaluationError(f"{reported} fall_step {_short(k)}; expected a whole "
                              "number of steps >= 0")
    if out.cost is None:
        if not out.failed:
            raise EvaluationError(f"{returned} no cost for a trial that did not fail")
        out.cost = fail_cost(out.info.get("fall_step"), out.info.get("horizon") or 1) \
            if out.info.get("fall_step") is not None and out.info.get("horizon") else 2.0 * C1
    if not math.isfinite(out.cost):
        raise EvaluationError(_non_finite(returned, out.cost))
    if abs(out.cost) >= COST_LIMIT:
        raise CostError(_too_large(returned, out.cost))
    return out


def _whole_step(k: Any) -> bool:
    """``k`` is a step number: an integer (or a float with no fraction, as JSON may give it),
    0 <= k < 2**63 (what the store holds), not a bool."""
    if isinstance(k, bool) or not isinstance(k, (int, float, np.integer, np.floating)):
        return False
    return math.isfinite(k) and float(k).is_integer() and 0 <= k < 2 ** 63


def _info(v: Any, opening: str) -> dict[str, Any]:
    """A trial's ``info`` as a new dict (None: empty); EvaluationError for anything else, its
    message opening with ``opening``."""
    if v is None:
        return {}
    if not isinstance(v, Mapping):
        raise EvaluationError(f"{opening} info = {_short(v)}; expected a dict")
    return dict(v)


def _short(v: Any) -> str:
    """``repr(v)`` cut to 60 characters (a repr that raises: the type's name)."""
    try:
        s = repr(v)
    except Exception:  # noqa: BLE001 - a user object's __repr__: the message must not fail
        s = f"<{type(v).__name__} object>"
    return s if len(s) <= 60 else s[:57] + "..."


@runtime_checkable
class System(Protocol):
    """A parameter space and a trial: ``evaluate((d,) unit-box θ) -> Outcome`` (or a cost)."""

    space: ParameterSpace

    def evaluate(self, theta: np.ndarray) -> Any:
        ...


class FunctionSystem:
    """A System from a plain function of the physical θ.

    ``FunctionSystem(space, fn, by_name=False)``: ``fn`` gets the physical θ, a (d,) float array
    (``by_name=True``: a dict name -> value), and returns a cost, ``(cost, failed)``, a dict or
    an :class:`Outcome`. For the process backend, ``fn`` must be picklable (a module-level
    function), unless the system comes from :func:`load_system` (``--system module:factory``):
    then each worker rebuilds it from the factory, and ``fn`` may be a closure. Ray serializes
    closures itself.
    """

    def __init__(self, space: ParameterSpace, fn: Callable[..., Any], by_name: bool = False,
                 name: str | None = None) -> None:
        if not isinstance(space, ParameterSpace):
            raise TypeError("FunctionSystem: space must be a latentune.ParameterSpace")
        if not callable(fn):
            raise TypeError("FunctionSystem: fn must be callable")
        if not isinstance(by_name, (bool, np.bool_)):
            raise TypeError(f"FunctionSystem: by_name must be True or False, got {by_name!r}")
        self.space = space
        self.fn = fn
        self.by_name = bool(by_name)
        self.name = name or getattr(fn, "__qualname__", type(fn).__name__)

    def evaluate(self, theta: np.ndarray) -> Outcome:
        phys = self.space.to_physical(self.space.validate_unit(theta))
        arg = dict(zip(self.space.names, map(float, phys))) if self.by_name else phys
        return as_outcome(self.fn(arg))

    def config(self) -> dict[str, Any]:
        """JSON-able description (recorded with the run)."""
        return {"kind": "function", "name": self.name, "dim": self.space.dim}

    def __repr__(self) -> str:
        return f"FunctionSystem({self.name}, dim={self.space.dim})"


def check_system(system: Any, what: str | None = None) -> Any:
    """Return ``system`` if it follows the protocol, else raise :class:`SystemSpecError`
    naming ``what`` (default: the object's type) as the thing that is not a system."""
    name = what or type(system).__name__
    if inspect.isclass(system):      # its evaluate would be called without an instance
        raise SystemSpecError(f"{system.__name__} is a class, not a system: pass an instance, "
                              f"{system.__name__}(...)")
    try:
        space = getattr(system, "space", None)
        evaluate_ = getattr(system, "evaluate", None)
    except Exception as exc:  # noqa: BLE001 - a property of the user's: one line
        raise SystemSpecError(f"{name} is not a latentune system as it is: reading its `space` "
                              f"or `evaluate` raised {type(exc).__name__}: "
                              f"{' '.join(str(exc).split())[:200]}") from None
    if not isinstance(space, ParameterSpace):
        raise SystemSpecError(f"{name} is not a latentune system: it needs a "
                              "`space` attribute that is a latentune.ParameterSpace")
    if not callable(evaluate_):
        raise SystemSpecError(f"{name} is not a latentune system: it needs a "
                              "method evaluate(theta) -> Outcome or cost")
    return system


def evaluate(system: Any, theta: np.ndarray) -> Outcome:
    """One trial of ``system`` at unit-box ``theta`` (d,), timed and checked.

    Raises :class:`EvaluationError` if ``evaluate`` raises or returns no usable cost.
    """
    t0 = time.perf_counter()
    try:
        raw = system.evaluate(np.asarray(theta, dtype=float).copy())
        out = as_outcome(raw)
    except EvaluationError as exc:      # CostError stays a CostError
        raise type(exc)(f"{exc}{_at(system, theta)}") from exc
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - one line by the caller; sys.exit too
        raise EvaluationError(f"{type(system).__name__}.evaluate raised "
                              f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
                              f"{_at(system, theta)}") from exc
    if out.wall_s is None:
        out.wall_s = time.perf_counter() - t0
    return out


def _at(system: Any, theta: np.ndarray, most: int = 6) -> str:
    """`` at θ kp=10, ki=0.5`` (physical values, the first ``most`` names): where a trial
    failed to give a cost, for the error line; "" when the θ cannot be shown."""
    try:
        space = system.space
        x = space.to_physical(np.asarray(theta, dtype=float))
        shown = ", ".join(f"{n}={v:.4g}" for n, v in zip(space.names[:most], x[:most]))
    except Exception:  # noqa: BLE001 - the message must not fail
        return ""
    return f" at θ {shown}{', …' if space.dim > most else ''}"


def parse_system_args(pairs: list[str] | None) -> dict[str, Any]:
    """``["k=v", ...]`` -> dict. A value in decimal or exponent form with a point or an
    exponent (``2.5``, ``1e9``, ``1e-3``, ``-2.5E+3``; ``1e999`` is inf) is a float, also
    inside a list or mapping (``[1e9, 2]``); any other value is parsed as YAML (``10`` an int,
    ``true``/``false`` booleans, ``null`` None, ``[1, 2]`` a list), a string when YAML cannot
    parse it; an empty value is ``""``; a date (``2020-01-01``, also inside a list) is its
    text, as the README promises, not a ``datetime.date`` (:func:`latentune.yamltext.load_arg`;
    YAML 1.1 alone reads ``1e9`` and ``1.0e9`` as strings). A key given twice raises
    :class:`SystemSpecError` naming it and both texts (the first would be dropped unseen)."""
    import yaml

    from latentune.yamltext import load_arg

    out: dict[str, Any] = {}
    texts: dict[str, str] = {}          # each key's value as given
    for p in pairs or []:
        if "=" not in p or not p.split("=", 1)[0].strip():
            raise SystemSpecError(f"--system-arg must be key=value, got {p!r}")
        k, v = p.split("=", 1)
        k = k.strip()
        if k in texts:
            raise SystemSpecError(f"--system-arg {k} is given twice ({texts[k].strip()}, then "
                                  f"{v.strip()}): give it once")
        texts[k] = v
        try:
            out[k] = load_arg(v) if v.strip() else ""
        except yaml.YAMLError:
            out[k] = v
    return out


def _flow_text(value: Any) -> str:
    """``value`` (a JSON value) as YAML flow text that ``yaml.safe_load`` reads back as it:
    JSON, but ``.nan``/``.inf``/``-.inf`` for the non-finite floats and a float in exponent
    form with a point (``1.0e+20``: YAML 1.1 reads ``1e+20`` as text), inside lists and
    mappings too."""
    if isinstance(value, float) and not isinstance(value, bool):
        if not math.isfinite(value):
            return ".nan" if math.isnan(value) else ".inf" if value > 0 else "-.inf"
        text = repr(float(value))
        mant, e, exp = text.partition("e")
        return f"{mant}.0e{exp}" if e and "." not in mant else text
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow_text(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{json.dumps(str(k))}: {_flow_text(v)}"
                               for k, v in value.items()) + "}"
    return json.dumps(value, default=str)


def system_arg_text(key: str, value: Any) -> str:
    """The ``key=value`` text :func:`parse_system_args` reads back as ``value`` (a JSON value,
    as a study keeps it): ``.nan``/``.inf`` for the non-finite floats (also inside a list,
    where JSON's ``NaN`` would read back as text), a string YAML would read as something else
    (``'true'``, ``'10'``) in single quotes, any other value as YAML flow text
    (:func:`_flow_text`)."""
    if isinstance(value, float) and not math.isfinite(value):
        text = ".nan" if math.isnan(value) else ".inf" if value > 0 else "-.inf"
    elif isinstance(value, str):
        text = value
        try:
            same = parse_system_args([f"{key}={value}"]).get(key.strip()) == value
        except SystemSpecError:
            same = False
        if not same:
            text = "'" + value.replace("'", "''") + "'"
    else:
        text = _flow_text(value)
    return f"{key}={text}"


def plugin_name(target: Any, cli: bool) -> str:
    """How a message names the system ``module:factory`` its reader gave: ``--system TARGET``
    at the command line (``cli``), ``load_system('TARGET')`` in Python."""
    return f"--system {target}" if cli else f"load_system({target!r})"


def load_system(target: str, args: dict[str, Any] | None = None) -> Any:
    """Import ``module:factory`` and call ``factory(**args)``; return the checked system.

    The current directory is searched for ``module`` (as ``python -m`` does).

    ``factory`` may be a function or a system class (called with ``args``), or a System
    instance (then ``args`` must be empty). Raises
    :class:`SystemSpecError` with one line for a malformed target, a module that cannot be
    imported, a missing attribute, a factory that raises or returns a non-system; the line
    names the system as its reader gave it (:func:`plugin_name`).

    The system carries the record ``{"target", "args", "defaults"}`` (:func:`plugin_record`;
    ``defaults``: :func:`factory_defaults`) that a study keeps and compares on resume.
    """
    cli = at_command_line()
    named = plugin_name(target, cli)
    if args is not None and not isinstance(args, Mapping):
        raise SystemSpecError(f"{named}: the factory's arguments must be a dict, got "
                              f"{_short(args)}")
    args = dict(args or {})
    if not isinstance(target, str) or target.count(":") != 1 or not all(target.split(":")):
        raise SystemSpecError(f"{'--system' if cli else 'load_system: the target'} must be "
                              f"module:factory, got {target!r}")
    mod_name, attr = target.split(":")
    import sys

    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())  # like `python -m`: modules next to the user are found
    try:
        mod = importlib.import_module(mod_name)
    except Exception as exc:  # noqa: BLE001 - any import failure is one line
        raise SystemSpecError(f"{named}: cannot import {mod_name} "
                              f"({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    obj: Any = mod
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise SystemSpecError(f"{named}: {mod_name} has no attribute {attr!r}")
        obj = getattr(obj, part)
    defaults: dict[str, Any] = {}
    if inspect.isclass(obj) or (callable(obj) and not hasattr(obj, "evaluate")):
        # a factory: a function, or a system class (whose ``evaluate`` is not a system's)
        factory = obj
        try:
            if args:
                inspect.signature(obj).bind(**args)
        except TypeError as exc:
            raise SystemSpecError(f"{named}: bad {'--system-arg' if cli else 'args'} ({exc})"
                                  ) from None
        except ValueError:
            pass
        try:
            obj = obj(**args)
        except Exception as exc:  # noqa: BLE001
            raise SystemSpecError(f"{named}: the factory raised {type(exc).__name__}: "
                                  f"{' '.join(str(exc).split())[:200]}") from None
        check_system(obj, f"{named} returned {type(obj).__name__} "
                          f"{' '.join(_short(obj).split())}, which")
        defaults = factory_defaults(factory)
    elif args:
        raise SystemSpecError(f"{named} is not callable; it takes no "
                              f"{'--system-arg' if cli else 'args'}")
    check_system(obj, f"{named} ({type(obj).__name__})")
    record = {"target": target, "args": args, "defaults": defaults}
    try:  # what a study records of a plugin: the string and its arguments, for the user to read
        obj.latentune_plugin = record
    except Exception:  # noqa: BLE001 - a frozen dataclass, a __setattr__ that refuses
        try:
            object.__setattr__(obj, "latentune_plugin", record)
        except Exception:  # noqa: BLE001 - __slots__: kept beside the object instead
            _RECORDS[id(obj)] = (obj, record)
    return obj


def factory_defaults(factory: Callable[..., Any]) -> dict[str, Any]:
    """The default values of ``factory``'s parameters, as JSON reads them back (a tuple is a
    list); a default JSON cannot hold (an object, NaN) is left out, as is every default of a
    factory whose signature cannot be read. Under the given arguments, they are the resolved
    arguments of the system a call builds: what a study compares on resume."""
    try:
        params = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):
        return {}
    out: dict[str, Any] = {}
    for p in params:
        if p.default is p.empty:
            continue
        try:
            out[p.name] = json.loads(json.dumps(p.default, allow_nan=False))
        except (TypeError, ValueError):
            continue
    return out


_RECORDS: dict[int, tuple[Any, dict[str, Any]]] = {}
"""The records of the systems :func:`load_system` made that cannot carry an attribute (a class
with ``__slots__``), by ``id``; each entry keeps its system alive, so its id is not reused."""


def plugin_record(system: Any) -> dict[str, Any] | None:
    """The ``{"target", "args", "defaults"}`` record of a system made by :func:`load_system` (its
    ``latentune_plugin`` attribute, or the record kept beside an object that cannot hold one),
    or None for any other object."""
    try:
        record = getattr(system, "latentune_plugin", None)
    except Exception:  # noqa: BLE001 - a __getattr__ of the user's
        record = None
    if isinstance(record, dict):
        return record
    entry = _RECORDS.get(id(system))
    return entry[1] if entry is not None and entry[0] is system else None
