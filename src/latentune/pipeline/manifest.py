"""The run manifest: what a study ran, on which system, with which options and seed.

Stored in the run store's ``config`` meta entry (JSON)::

    seed          the study's seed (every critic, VAE and trial of it)
    trial_timeout seconds a trial may run (process backend; absent: no limit), kept on resume
    system        which system the phases ran (:func:`describe`), and its ``space``
    phase1, phase3  a phase's options (:meth:`Manifest.phase_options`): method, batch_size, seed,
                  regions, budget, start, max_fall_prob (+ fall_prior), and in phase 3
                  latent_source, strategy, handover and transfer_options (only when given)
    asktell       the phase ask/tell drives (``phase``) with the same options
    vae, latent, phase3_vae_source, phase3_handover   phase 2's and phase 3's latent space
    command       the command-line command that last started a phase run here (``tune`` or
                  ``phase1``), which its report names to go on
    tune          a ``tune`` run's plan, recorded before phase 1 runs: the flags it was given
                  for its latent space and phase 3 (None: not given), which its resume keeps

A study reopened reads its seed and options from here; a conflicting one is refused with one
line naming the stored value (:class:`~latentune.errors.StoreError`). A study that holds no
trial (:meth:`Manifest.holds_trials`) takes another system instead (:meth:`Manifest.bind`).
The manifest records a user system's ``--system`` string and arguments, or its class, but
never imports or calls them.
"""
from __future__ import annotations

import hashlib
import json
import shlex
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from latentune.checks import is_whole
from latentune.constants import Phase
from latentune.errors import LatentuneError, StoreError, SystemSpecError, UsageError
from latentune.pipeline.rundir import RunDir
from latentune.pipeline.store import info_json, json_default
from latentune.pipeline.walltime import settle_open
from latentune.space import ParameterSpace, task_tuned_for
from latentune.system import check_system, plugin_record, system_arg_text
from latentune.wording import at_command_line, counted, joined, option

OPTUNA_METHODS = ("optuna-tpe", "optuna-cmaes", "optuna-gp")
"""Optuna's samplers as critics (:class:`latentune.critic.optuna.OptunaCritic`; the
``optuna`` extra): the baselines a user would pick, run by the same loop and store."""
METHODS = ("turbo", "cma", "random", "sobol") + OPTUNA_METHODS
ASK_BUDGET = 200
"""The budget ask/tell assumes for its critic's options (TuRBO-m's region count) by default."""
PHASE_KEYS = {Phase.PHASE1: "phase1", Phase.PHASE3: "phase3"}
COMPARED = ("method", "batch_size", "seed", "regions", "start", "max_fall_prob", "fall_prior",
            "latent_source", "handover", "transfer_options")
"""The options of a phase that must match on resume (budget may grow)."""
RECORDED_IF_GIVEN = ("transfer_options", "source_counts", "source_fingerprint", "prior_counts",
                     "prior_fingerprint")
"""Options recorded only when given: a record without one (a run stored before it existed, or
run without it) compares equal to not giving it."""
PINNED = ("source_counts", "source_fingerprint", "prior_counts", "prior_fingerprint")
"""Options taken as the phase first recorded them once it has a trial, never compared: what
the phase started from (how many trials of each phase its source run or fall prior held:
:func:`run_counts`; which trials those were: :func:`run_fingerprint`), so a resume asks what
the uninterrupted run would have, however much those runs grew since."""


def config_space(cfg: dict[str, Any]) -> ParameterSpace | None:
    """The parameter space a run's stored ``config`` records: its ``space`` entry; for a
    built-in robot's run of the first store layout (its task recorded, no space) the task's
    space; None without either, or when the task record cannot be rebuilt."""
    sp = cfg.get("space")
    if sp is not None:
        return ParameterSpace.from_dict(sp, stored=True)
    if isinstance(cfg.get("task"), dict):
        from latentune.task import Task

        try:
            return Task.from_config(cfg["task"]).space
        except (KeyError, TypeError, ValueError, LatentuneError):
            return None
    return None


def run_counts(run: Any) -> dict[str, int] | None:
    """How many trials of phases 1 and 3 the run at ``run`` holds (``{"1": n1, "3": n3}``),
    None without a run store: what a phase that learns from it starts from (:data:`PINNED`)."""
    from latentune.pipeline.store import RunStore

    if run is None or not (Path(run) / "run.db").is_file():
        return None
    with RunStore(run) as st:
        return {str(int(ph)): st.count(ph) for ph in (Phase.PHASE1, Phase.PHASE3)}


def run_fingerprint(run: Any, counts: dict[str, int] | None) -> str | None:
    """The sha256 (hex) of the trials of the run at ``run`` that ``counts`` pins
    (:func:`run_counts`): of phases 1 and 3 in (phase, idx) order, the first ``counts[phase]``
    of each (idx below it, as :func:`~latentune.pipeline.baselines.source_trials` takes them),
    their θ, cost (float64 bytes) and fell flag; None without ``counts`` or a run store. The
    same run gives the same value wherever its directory is and however many trials it made
    since; another run gives another (and so does an amended result: :func:`amended_since`)."""
    from latentune.pipeline.store import RunStore

    if counts is None or run is None or not (Path(run) / "run.db").is_file():
        return None
    with RunStore(run) as st:
        return _digest(_pinned_rows(st, counts))


PinnedRows = list[tuple[int, int, list[tuple[int, bytes, float, bool]]]]
"""The trials :func:`run_fingerprint` hashes: per phase (phase, its count, [(idx, θ as
float64 bytes, cost, fell)])."""


def _pinned_rows(st: Any, counts: dict[str, int]) -> PinnedRows:
    """The trials of the open run store ``st`` that ``counts`` pins (:data:`PinnedRows`)."""
    out = []
    for ph in (Phase.PHASE1, Phase.PHASE3):
        n = int(counts.get(str(int(ph)), 0))
        out.append((int(ph), n, [(r.idx, np.ascontiguousarray(r.theta, dtype="<f8").tobytes(),
                                  float(r.cost), bool(r.fell)) for r in st.rows(ph) if r.idx < n]))
    return out


def _digest(pinned: PinnedRows, outcomes: dict[tuple[int, int], tuple[float, bool]] | None = None
            ) -> str:
    """:func:`run_fingerprint` of ``pinned``, with the (cost, fell) of ``outcomes`` (by (phase,
    idx)) in place of the stored ones."""
    h = hashlib.sha256()
    for ph, n, rows in pinned:
        h.update(f"phase {ph}: {n} trials\n".encode())
        for idx, theta, cost, fell in rows:
            cost, fell = (outcomes or {}).get((ph, idx), (cost, fell))
            h.update(theta)
            h.update(np.array([cost], dtype="<f8").tobytes())
            h.update(b"\x01" if fell else b"\x00")
    return h.hexdigest()


def amended_since(run: Any, counts: dict[str, int], fingerprint: str, after: int = 0
                  ) -> tuple[list[int], int] | None:
    """Whether the run at ``run`` holds the trials that ``counts`` and ``fingerprint``
    (:func:`run_fingerprint`) pinned, and which of them were amended since: ([], ``after``)
    when they hash to ``fingerprint`` as they are; when undoing the latest amendments of those
    trials (``tell --amend``, :meth:`~latentune.pipeline.store.RunStore.amendments`), newest
    first, gives ``fingerprint`` back (the same run: the same θ, in the same order, results
    corrected since), the ids of the told trials whose cost or fall flag those amendments
    changed and that one numbered above ``after`` amended (the ones not reported yet), with
    the highest number of those amendments (``after`` if higher); None when neither does
    (another run, or no run store). Reads the run once; works for pins taken before this
    existed (the pinned value is the same)."""
    from latentune.pipeline.store import RunStore

    if run is None or not (Path(run) / "run.db").is_file():
        return None
    with RunStore(run) as st:
        pinned = _pinned_rows(st, counts)
        if _digest(pinned) == fingerprint:
            return [], int(after)
        now = {(ph, idx): (cost, fell) for ph, _, rows in pinned for idx, _, cost, fell in rows}
        amends = [a for a in st.amendments() if (a["phase"], a["idx"]) in now]
    undone: dict[tuple[int, int], tuple[float, bool]] = {}
    newest: dict[tuple[int, int], int] = {}         # each trial's newest amendment number
    trial = {(a["phase"], a["idx"]): a["trial"] for a in amends}     # None: a copy's
    for a in reversed(amends):
        k = (a["phase"], a["idx"])
        undone[k] = (float(a["old"]["cost"]), bool(a["old"]["fell"]))
        newest.setdefault(k, int(a["n"]))
        if _digest(pinned, undone) == fingerprint:
            return sorted(int(trial[k]) for k, (cost, fell) in undone.items()
                          if trial[k] is not None and newest[k] > after
                          and (fell != now[k][1] or np.float64(
                              cost).tobytes() != np.float64(now[k][0]).tobytes())), \
                max([int(after), *newest.values()])
    return None


def describe(system: Any) -> dict[str, Any]:
    """The JSON-able record of which system a phase ran (compared on resume).

    A built-in Task: ``{"kind": "task", "task": task.config()}``; a ``--system`` plugin (from
    :func:`latentune.system.load_system`): ``{"kind": "plugin", "target", "args", "defaults",
    "space"}``; any other
    object: its class, its ``config()`` if it has one, and its space.
    """
    from latentune.task import Task

    if isinstance(system, Task):
        return {"kind": "task", "task": system.config()}
    plugin = plugin_record(system)
    if plugin is not None:      # as the store keeps it: a date argument is its text
        return {"kind": "plugin", **json.loads(info_json(plugin)), "space": system.space.to_dict()}
    d: dict[str, Any] = {"kind": "python",
                         "class": f"{type(system).__module__}.{type(system).__qualname__}",
                         "space": system.space.to_dict()}
    cfg = getattr(system, "config", None)
    if callable(cfg):
        try:
            got = cfg()
        except Exception as exc:  # noqa: BLE001 - the system's own code: one line
            raise SystemSpecError(f"{type(system).__name__}.config() raised "
                                  f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]} "
                                  "(a study records it to recognise the system)") from None
        try:
            d["config"] = json.loads(json.dumps(got, default=str))
        except (TypeError, ValueError):     # a key JSON has no type for, a circular reference
            d["config"] = json.loads(info_json(got))
    return d


def tuned_for(desc: Any) -> dict[str, Any] | None:
    """What θ of the system :func:`describe` described as ``desc`` are tuned for, as a
    ``--params`` file records it (:data:`latentune.space.TUNED_FOR`): a built-in task's robot,
    gait and actor (not its terrain, reality or engine: θ tuned for one robot may be tried
    on another ground), a plugin's ``module:factory``; None for another Python object (its
    class, often a wrapper such as FunctionSystem, is no name a command could check: the
    same system given as ``--system module:factory`` must not be refused), for trials run
    elsewhere (only the space is known) and without a description."""
    if not isinstance(desc, dict):
        return None
    task = desc.get("task")
    if desc.get("kind") == "task" and isinstance(task, dict):
        return task_tuned_for(task.get("robot"), task.get("gait"), task.get("actor"))
    if desc.get("kind") == "plugin" and desc.get("target"):
        return {"system": str(desc["target"])}
    return None


def stored_system(cfg: dict[str, Any]) -> dict[str, Any] | None:
    """The system a run's stored ``config`` records (:func:`describe`'s record): its
    ``system`` entry; for a run written before systems were recorded, its task as
    ``{"kind": "task", "task": ...}``; None without either."""
    stored = cfg.get("system")
    if stored is None and "task" in cfg:
        stored = {"kind": "task", "task": cfg["task"]}
    return stored


def plugin_flags(desc: dict[str, Any]) -> list[str]:
    """The --system and --system-arg flags (shell-quoted) that name the --system plugin of a
    stored system description ``desc`` (kind ``plugin``) again."""
    out = ["--system", shlex.quote(str(desc.get("target")))]
    for k, v in (desc.get("args") or {}).items():
        out += ["--system-arg", shlex.quote(system_arg_text(k, v))]
    return out


def no_system_text(stored: dict[str, Any]) -> str:
    """What a run of recorded system ``stored`` of kind ``external`` or ``optuna`` (no system
    to run) holds, as a message says it: trials run elsewhere, or an import of an Optuna
    study (named)."""
    if stored.get("kind") == "external":
        return "trials run elsewhere, in the parameter space its first ask was given"
    return f"an import of the Optuna study {stored.get('study_name')!r}"


def same_system(stored: dict[str, Any] | None, desc: dict[str, Any]) -> bool:
    """Whether the recorded system ``stored`` is the one ``desc`` describes: the same
    :func:`identity` (an argument given at its default value is the same plugin as one left
    out; a reality profile under another name is the same task)."""
    if stored is None or stored == desc:
        return stored is not None
    return identity(stored, desc) == identity(desc)


def identity(desc: dict[str, Any], like: dict[str, Any] | None = None) -> dict[str, Any]:
    """What makes the described system the one it is: a plugin's description with its
    resolved arguments (:func:`plugin_config`; ``like``'s defaults for a record without them),
    a task's without its reality profile's name and the file it was read from (labels: the
    fields are the perturbation); any other description as it is."""
    if desc.get("kind") == "plugin" and isinstance(desc.get("args"), dict):
        return plugin_config(desc, (like or {}).get("defaults"))
    task = desc.get("task")
    if desc.get("kind") == "task" and isinstance(task, dict) \
            and isinstance(task.get("reality"), dict):
        reality = {k: v for k, v in task["reality"].items() if k != "name"}
        return {**desc, "task": {**{k: v for k, v in task.items() if k != "reality_file"},
                                 "reality": reality}}
    return desc


def plugin_config(desc: dict[str, Any], defaults: dict[str, Any] | None = None
                  ) -> dict[str, Any]:
    """A plugin's description with ``args`` resolved (the factory's defaults under the given
    arguments) and no ``defaults`` key; ``defaults``: those of a record that has none (one
    written before they were recorded). The given arguments are compared as --system-arg now
    reads them (:func:`numbers_as_read`): an older record's ``"1e9"`` (also inside a list) is
    the float."""
    d = dict(desc)
    d["args"] = {**(d.pop("defaults", defaults) or {}), **numbers_as_read(d.get("args") or {})}
    return d


def _merged(cfg: dict[str, Any], kw: dict[str, Any]) -> dict[str, Any]:
    """The configuration ``cfg`` with the entries ``kw`` put in (:meth:`Manifest.update`)."""
    return {**cfg, **kw}


def _as_json(cfg: dict[str, Any]) -> str:
    """``cfg`` as the store's JSON with its keys sorted (:meth:`Manifest.would_change`)."""
    return json.dumps(cfg, sort_keys=True, default=json_default)


def numbers_as_read(value: Any) -> Any:
    """``value`` (a recorded JSON value) with every text that ``--system-arg`` reads as a float
    (:func:`latentune.yamltext.decimal_float`: ``"1e9"``, ``"2.5"``) as that float, inside
    lists and mappings too, and such a mapping key as the text JSON gives the float's key
    (``"1000000000.0"``). Older versions gave a factory such text as a string (``1e9`` at the
    top level, then inside a list or mapping): their records are the same system as the
    float."""
    from latentune.yamltext import decimal_float

    def number(text: Any) -> float | None:
        return decimal_float(text) if isinstance(text, str) else None

    if isinstance(value, list):
        return [numbers_as_read(v) for v in value]
    if isinstance(value, dict):
        return {k if number(k) is None else json.dumps(number(k)): numbers_as_read(v)
                for k, v in value.items()}
    num = number(value)
    return value if num is None else num


class Manifest:
    """The ``config`` record of a run directory (see the module docstring)."""

    def __init__(self, run: RunDir) -> None:
        self.run = run

    def config(self) -> dict[str, Any]:
        """The stored configuration (empty for a new study)."""
        return (self.run.store.get_meta("config") or {}) if self.run.exists else {}

    def update(self, **kw: Any) -> dict[str, Any]:
        """Merge ``kw`` into the stored configuration (creates the store)."""
        st = self.run.open()
        cfg = _merged(st.get_meta("config") or {}, kw)
        st.set_meta("config", cfg)
        return cfg

    def would_change(self, **kw: Any) -> bool:
        """Whether :meth:`update` with ``kw`` would change the stored configuration: the
        configuration it would store differs from the stored one as JSON (the store's form:
        NumPy values as numbers, key order ignored). A dry run: writes nothing, creates no
        store."""
        cfg = self.config()
        return _as_json(_merged(cfg, kw)) != _as_json(cfg)

    def add_wall(self, key: str, seconds: float) -> None:
        """Add ``seconds`` of wall time to the ``wall`` meta entry ``key``."""
        st = self.run.store
        w = st.get_meta("wall", {}) or {}
        w[key] = float(w.get(key, 0.0)) + float(seconds)
        st.set_meta("wall", w)

    @contextmanager
    def timing(self, key: str) -> Iterator[None]:
        """Add the block's wall time to the ``wall`` entry ``key`` when it ends. Its start is
        stored first (``wall_open``): a command killed inside the block leaves it behind, and
        its time up to its last stored trial counts (:mod:`latentune.pipeline.walltime`);
        blocks a killed command left open are settled here first."""
        st = self.run.store
        settle_open(st)
        st.set_meta("wall_open", {**(st.get_meta("wall_open", {}) or {}), key: time.time()})
        t = time.perf_counter()
        try:
            yield
        finally:
            self.add_wall(key, time.perf_counter() - t)
            rest = {k: v for k, v in (st.get_meta("wall_open", {}) or {}).items() if k != key}
            st.update_meta({"wall_open": rest or None})

    # ------------------------------------------------------------------ seed
    def stored_seed(self) -> int | None:
        """The study's recorded seed (``seed``, else the seed its phases ran with), or None."""
        cfg = self.config()
        if cfg.get("seed") is not None:
            return int(cfg["seed"])
        for key in ("phase1", "phase3", "asktell", "vae"):
            s = (cfg.get(key) or {}).get("seed")
            if s is not None:
                return int(s)
        return None

    def record_seed(self, seed: int) -> None:
        """Record the study's seed (once)."""
        if self.config().get("seed") is None:
            self.update(seed=int(seed))

    def record_run(self, seed: int) -> None:
        """Before a phase runs trials: record the seed (once) and the run's trial timeout
        (when there is one: a resume uses it, see :meth:`trial_timeout`)."""
        self.record_seed(seed)
        t = self.run.trial_timeout
        if t is not None and self.config().get("trial_timeout") != t:
            self.update(trial_timeout=t)

    def trial_timeout(self, given: Any) -> float | None:
        """The trial timeout of the run: ``given`` (it replaces the stored one when a phase
        runs), else the stored one; each checked by :meth:`RunDir.check_timeout`."""
        if given is not None:
            return self.run.check_timeout(given)
        return self.run.check_timeout(self.config().get("trial_timeout"), stored=True)

    # ------------------------------------------------------------------ system
    def holds_trials(self) -> bool:
        """Whether the study stored an evaluation of any phase or has an ask/tell suggestion
        (of any status). A study without either may be bound to another system."""
        if not self.run.exists:
            return False
        st = self.run.store
        return any(st.count(int(p)) for p in Phase) or bool(st.trials())

    def bind(self, system: Any) -> dict[str, Any]:
        """Record ``system`` as the study's system, or check it is the one recorded. A study
        that holds no trial (:meth:`holds_trials`; e.g. its first run failed before any
        evaluation was stored) is bound to another system instead of refusing it."""
        desc = self.bind_check(system)
        if not same_system(self.config().get("system"), desc):
            was = self._stored()
            self._record(desc, system.space, was is not None and not same_system(was, desc))
        return desc

    def _stored(self) -> dict[str, Any] | None:
        """The recorded system (:func:`stored_system`)."""
        return stored_system(self.config())

    def _record(self, desc: dict[str, Any], space: ParameterSpace, forget: bool,
                **more: Any) -> None:
        """Record the system ``desc`` and its ``space`` (and ``task`` for a built-in task, and
        the entries ``more``; the space file's name is dropped unless one is given), in one
        transaction. ``forget`` (a study holding no trial bound to another system): also
        drop what a run on the old system left, the record of an asked batch not yet told and
        the critic states (their points are in the old space)."""
        from latentune.pipeline.phases import batch_key, state_key

        st = self.run.open()
        cfg = st.get_meta("config") or {}
        cfg.pop("task", None)
        cfg.pop("space_file", None)
        cfg.update(system=desc, space=space.to_dict(), **more)
        if desc["kind"] == "task":
            cfg["task"] = desc["task"]
        entries: dict[str, Any] = {"config": cfg}
        if forget:
            entries.update({key(p): None for p in PHASE_KEYS for key in (batch_key, state_key)})
        st.update_meta(entries)

    def bind_check(self, system: Any) -> dict[str, Any]:
        """Return ``system``'s description; StoreError (naming the differences) unless it is
        the system this study recorded, or no system is recorded yet, or the study holds no
        trial (:meth:`holds_trials`)."""
        desc = describe(check_system(system))
        stored = self._stored()
        if stored is not None and not same_system(stored, desc) and self.holds_trials():
            if stored.get("kind") == "plugin" and desc.get("kind") != "plugin":
                raise StoreError(f"{self.run.dir} holds a run of the user system "
                                 f"{stored.get('target')}: pass --system {stored.get('target')}"
                                 " (and its --system-arg values) again")
            if stored.get("kind") in ("external", "optuna"):
                raise StoreError(f"{self.run.dir} holds a run of another system "
                                 f"({no_system_text(stored)}): ask "
                                 "it without a system")
            if stored.get("kind") == "python" and desc.get("kind") == "plugin":
                raise StoreError(f"{self.run.dir} holds a run of the Python system "
                                 f"{stored.get('class')} (made through the API), not of "
                                 f"--system {desc.get('target')}: leave --system out (ask, tell "
                                 "and report read the stored run), or continue it with "
                                 "latentune.Study")
            if stored.get("kind") == "task" and desc.get("kind") == "plugin":
                t = stored.get("task") or {}
                raise StoreError(f"{self.run.dir} holds a run of the built-in robot "
                                 f"{t.get('robot')} ({t.get('gait')}), not of a --system: "
                                 "leave --system (and --system-arg) out")
            shown = (identity(stored, desc), identity(desc)) \
                if stored.get("kind") == desc.get("kind") else (stored, desc)
            if stored.get("kind") == "plugin" == desc.get("kind"):
                again = " ".join(plugin_flags(stored)) if at_command_line() else \
                    (f"the system of load_system({stored.get('target')!r}, "
                     f"{dict(stored.get('args') or {})!r})")
                hint = f": pass {again} to go on with it, or use another directory"
            else:
                flags = task_flags(stored, desc)
                hint = (f": pass {flags} to go on with it" if flags else
                        ": go on with the system it was run with, or use another directory")
            raise StoreError(f"{self.run.dir} holds a run of another system "
                             f"({diff(*shown)}){hint}")
        return desc

    def space(self) -> ParameterSpace | None:
        """The study's parameter space (stored with its first phase or ask), or None; its
        ``tuned_for`` is the recorded system's (:func:`tuned_for`), so that it refuses a θ
        file tuned for another. A built-in robot's run of the first store layout records its
        task and no space: its space is the task's (as the report re-simulates it), or None if
        the task record cannot be rebuilt."""
        cfg = self.config()
        space = config_space(cfg)
        if space is not None and cfg.get("space") is not None:
            space.tuned_for = tuned_for(self._stored())
        return space

    def bind_space(self, space: ParameterSpace) -> None:
        """Record the parameter space of trials run elsewhere, or check it is the stored one
        (a study that holds no trial takes the new one, as :meth:`bind`); its ``name`` (the
        report's title, ``space_file``) is recorded with it, or later when none is yet."""
        stored = self.space()
        if stored is not None and stored != space and self.holds_trials():
            why = stored.box_difference(space.to_dict())
            why = f"{why}; there: the space given, here: the stored one" if why else \
                "another manual θ"
            raise StoreError(f"{self.run.dir} holds a study of another parameter space ({why})")
        if stored is None or stored != space:
            self._record({"kind": "external", "space": space.to_dict()}, space,
                         stored is not None, space_file=space.name)
        elif space.name and not self.config().get("space_file"):
            self.update(space_file=space.name)

    # ------------------------------------------------------------------ phase options
    def n_used(self, phase: int) -> int:
        """Trials of ``phase`` stored or handed out (options are fixed once there is one)."""
        if not self.run.exists:
            return 0
        st = self.run.store
        return st.count(phase) + sum(1 for t in st.trials() if t.phase == int(phase)
                                     and t.status in ("queued", "pending"))

    def n_fixing(self, phase: int) -> int:
        """Trials that fix ``phase``'s options: :meth:`n_used`, and for phase 3 its zero-shot
        trial's too (stored or handed out: it is phase 3's first trial)."""
        return self.n_used(phase) + (self.n_used(Phase.ZERO_SHOT)
                                     if int(phase) == Phase.PHASE3 else 0)

    def phase_options(self, phase: int, *, method: str | None, budget: int, regions: int | None,
                      seed: int, batch_size: int, extra: dict[str, Any] | None = None,
                      max_new: int | None = None, phase_run: bool = False) -> dict[str, Any]:
        """The options record of ``phase`` (checked): the one configuration check of phase runs
        and ask/tell. Stored options must match once the phase has a trial (StoreError naming
        the stored value; phase 3's zero-shot trial counts, :meth:`n_fixing`); the budget may
        grow, a smaller one is refused (a phase run's as an ask's: :func:`ask_options`); ``method`` None is the stored one (TuRBO-m for a phase without trials); TuRBO-m's
        region count defaults by budget and then stays as stored. ``max_new`` (a phase run's stop after so many new trials, not
        recorded) is checked too. A ``phase_run`` (the phase run in-process, not by ask/tell)
        is refused while suggestions of the phase (or of phase 3's zero-shot trial) are handed
        out to ask/tell: it would run them again and outgrow the budget (those asked and not
        handed out yet are withdrawn by the run)."""
        from latentune.critic.turbo import regions_for_budget

        key = PHASE_KEYS[Phase(int(phase))]
        stored = self.config().get(key)
        n = self.n_fixing(phase)
        if stored and n and stored.get("method") == "optuna":       # import_optuna_study's
            raise StoreError(f"{self.run.dir}: phase {int(phase)} is an imported Optuna study: "
                             "importing the study again adds its new trials, nothing asks more "
                             "of it; a phase 3 (here or in another directory) can use it as "
                             "its source")
        if method is None:                          # the stored method once the phase has run
            method = (stored or {}).get("method") if stored and n else "turbo"
        if method not in METHODS:
            raise UsageError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
        if not is_whole(budget, 1, 2 ** 63 - 1):         # the store's integers
            raise UsageError(f"budget must be an integer >= 1 and below 2**63, got {budget!r}")
        if max_new is not None and not is_whole(max_new, 0):
            raise UsageError(f"max_new must be a whole number >= 0, got {max_new!r}")
        if regions is not None and not is_whole(regions, 1, 100):
            raise UsageError(f"regions must be an integer in [1, 100], got {regions!r}")
        if regions is not None and method != "turbo":
            raise UsageError(f"regions (trust regions) is an option of method turbo (TuRBO-m), "
                             f"not of {method} (given regions = {regions})")
        if phase_run and self.run.exists:
            held = (int(phase), int(Phase.ZERO_SHOT)) if int(phase) == Phase.PHASE3 \
                else (int(phase),)
            out = [t.id for t in self.run.store.trials()
                   if t.phase in held and t.status == "pending"]
            if out:
                one = len(out) == 1
                raise StoreError(f"{self.run.dir}: {counted(len(out), 'suggestion')} of phase "
                                 f"{int(phase)} {'is' if one else 'are'} handed out to ask/tell "
                                 f"({'id' if one else 'ids'} "
                                 f"{', '.join(map(str, out[:5]))}{', …' if len(out) > 5 else ''}"
                                 "): tell them and go on with ask/tell, or release them "
                                 "(the phase run then withdraws them and asks its own), or "
                                 "run the phase here in a study without them")
        if regions is None and stored and n:
            regions = stored.get("regions")
        if regions is None and method == "turbo":
            regions = regions_for_budget(int(budget))
        pc = {"method": method, "batch_size": int(batch_size), "seed": int(seed),
              "regions": regions if method == "turbo" else None, "budget": int(budget),
              **(extra or {})}
        if stored and n:
            old = stored.get("budget")
            if old is not None and int(budget) < int(old):
                cli = at_command_line()
                name = f"--{key}-evals " if cli else "budget="
                raise StoreError(f"{self.run.dir}: phase {int(phase)} has a budget of {old} "
                                 f"trials (stored), which {name}{int(budget)} would lower; a "
                                 f"budget can only grow: give {name}{old} or more"
                                 + (", or leave it out" if cli else ""))
            pc.update({k: stored.get(k) for k in PINNED if k in pc})
            if stored.get("max_fall_prob") != pc.get("max_fall_prob") and same_fall_prob(
                    phase, stored, stored.get("max_fall_prob"), pc.get("max_fall_prob")):
                # the phase's default screen given or left out: the fall record as it began
                for k in FALL_KEYS:
                    pc.pop(k, None)
                    if k in stored:
                        pc[k] = stored[k]
            for k in ("method", "batch_size", "seed", "regions", *(extra or {})):
                if k in PINNED:
                    continue
                if k in stored and not same_option(k, stored.get(k), pc.get(k)):
                    raise StoreError(f"{self.run.dir}: {key} was run with {k.replace('_', '-')}"
                                     f" = {stored.get(k)!r}, not {pc.get(k)!r}"
                                     + default_fall_note(k, phase, stored)
                                     + kept_regions_note(k, stored))
                if k == "transfer_options" and (k in stored or same_option(k, None, pc[k])):
                    pc[k] = stored.get(k)       # the record as it began (options at defaults)
            if pc.get("transfer_options") and "transfer_options" not in stored:
                self.check_transfer_state(phase, pc["transfer_options"])
        return {k: v for k, v in pc.items() if v is not None or k not in RECORDED_IF_GIVEN}

    def check_transfer_state(self, phase: int, given: dict[str, Any]) -> None:
        """StoreError unless the stored transfer critic of ``phase`` (its saved state, which a
        resume restores and whose options win) was asked with the ``given`` transfer options:
        a run recorded without them (none given, or stored before they existed) resumes only
        with the values it ran with; a phase 3 that holds its zero-shot trial alone (no
        critic state yet) was recorded without them, so it takes none."""
        from latentune.critic.transfer import stored_options
        from latentune.pipeline.phases import state_key

        state = self.run.store.get_meta(state_key(phase)) or {}
        if not state and int(phase) == Phase.PHASE3 and not self.n_used(phase) \
                and self.n_used(Phase.ZERO_SHOT):   # its zero-shot trial alone: the record's
            raise StoreError(f"{self.run.dir}: {PHASE_KEYS[Phase.PHASE3]} was run with "
                             f"transfer-options = None, not {given!r}")
        if "options" not in state:      # no state, or one whose constructor's options stand
            return
        stored = stored_options(state) or {}
        for k, v in given.items():
            if stored.get(k) != v:
                raise StoreError(f"{self.run.dir}: phase {int(phase)}'s transfer critic was run "
                                 f"with {k} = {stored.get(k)!r}, not {v!r}")


def ask_options(stored: dict[str, Any] | None, given: dict[str, Any], dir_: Any,
                phase: int) -> dict[str, Any]:
    """The options of a later ask: each ``None`` in ``given`` is the stored value; an explicit
    one that differs from the stored is refused in one line naming the stored value (a budget
    may grow; a smaller one is refused saying so). ``stored``: the phase's options record (None on the first ask)."""
    if not stored:
        return dict(given)
    defaults = {"start": "manual", "max_fall_prob": None, "handover": None, "regions": None,
                "transfer_options": None}
    out = {}
    for k, v in given.items():
        old = stored.get(k, defaults.get(k))
        if v is None:
            out[k] = old
        elif k == "transfer_options" and int(phase) == Phase.PHASE3 and \
                (stored.get("strategy") or "plain") == "plain":     # not an option of it
            raise StoreError(stored_plain_refusal(dir_))
        elif k == "budget" and old is not None and is_whole(v, old):
            out[k] = v
        elif k == "budget" and old is not None and is_whole(v, 1):
            raise StoreError(f"{dir_}: phase {int(phase)} runs with budget = {old!r} (stored), "
                             f"not {v!r}; a budget can only grow: give {old} or more, or leave "
                             "it out")
        elif k == "max_fall_prob" and same_fall_prob(phase, stored, old, v):
            out[k] = old        # the phase's own default: the record stays as it began
        elif not same_option(k, old, v) \
                and not (k == "fall_prior" and stored.get("max_fall_prob") is None):
            raise StoreError(f"{dir_}: phase {int(phase)} runs with {k.replace('_', '-')} = "
                             f"{old!r} (stored), not {v!r}" + default_fall_note(k, phase, stored))
        else:       # transfer options at their defaults: the record stays as it began
            out[k] = old if k == "transfer_options" else v
    return out


def stored_plain_refusal(dir_: Any) -> str:
    """The refusal of transfer options given to a later ask or a resume of the stored plain
    phase 3 in ``dir_`` (the same words for both)."""
    return (f"{dir_}: transfer_options are options of the transfer phase 3, and this phase 3 "
            "runs with strategy plain (stored): leave them out to go on with it, or start a "
            "transfer phase 3 in another directory")


def diff(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> str:
    """The differing keys of two descriptions, as ``key: stored X, given Y`` (at most 4). A
    plugin's argument one side lacks (left out, and its factory's default is not recorded:
    one JSON cannot hold, or a ``**kwargs`` one) is "the factory's default", not None."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if va == vb and (prefix != "args." or (k in a) == (k in b)):
            continue
        if isinstance(va, dict) and isinstance(vb, dict):
            out.append(diff(va, vb, f"{prefix}{k}."))
        else:
            def shown(d: dict[str, Any], v: Any) -> str:
                return "the factory's default" if prefix == "args." and k not in d else _short(v)
            out.append(f"{prefix}{k}: stored {shown(a, va)}, given {shown(b, vb)}")
    return "; ".join(x for x in out[:4] if x)


_TASK_KEYS = ("robot", "gait", "terrain", "actor", "steps", "v_des", "engine", "seed", "reality")
"""The fields of a built-in task's record that one option gives (:func:`task_flags`): a Task
keyword, and a flag of the command line (:data:`latentune.wording.FLAGS`)."""


def task_flags(stored: dict[str, Any], given: dict[str, Any]) -> str | None:
    """The options that give the stored built-in task where the given one differs, as the
    reader sets them (:func:`latentune.wording.option`): the command line's flags
    (``"--task jump --steps 50"``), or the Task's keywords in Python (``"gait='jump',
    steps=50"``); None: not two built-in tasks, or a difference no option gives alone (a robot
    spec, a reality profile other than a preset or the recorded file it was read from, a
    sideways v_des)."""
    if stored.get("kind") != "task" or given.get("kind") != "task":
        return None
    a, b = stored.get("task") or {}, given.get("task") or {}
    if any(a.get(k) != b.get(k) for k in set(a) | set(b)
           if k not in _TASK_KEYS and k not in ("dim", "reality_file")):
        return None
    out = []
    for key in _TASK_KEYS:
        v = a.get(key)
        if v == b.get(key):
            continue
        if key == "engine":
            v = v or "pybullet"
        elif key == "v_des":
            if not (isinstance(v, list) and len(v) == 3 and v[1:] == [0.0, 0.0]):
                return None
            v = float(v[0])             # every digit: the option gives this very velocity
        elif key == "reality":
            v = _reality_preset(v) or _reality_file(v, a.get("reality_file"))
            if v is None:
                return None
        elif v is None or isinstance(v, (dict, list)):
            return None
        out.append(option(key, v))
    return joined(out) or None


def _reality_preset(stored: Any) -> str | None:
    """The reality preset whose record is ``stored`` (a task's ``reality``; absent: the
    nominal one), or None: a profile no preset gives."""
    from latentune.sim.reality import PRESETS, Reality

    if stored is None:
        return "nominal"
    return next((p for p in PRESETS if Reality.load(p).to_dict() == stored), None)


def _reality_file(stored: Any, path: Any) -> str | None:
    """The recorded reality file ``path`` when it still holds the profile ``stored`` (its
    fields; the name aside), else None."""
    from latentune.errors import LatentuneError
    from latentune.sim.reality import Reality

    if not isinstance(path, str) or not isinstance(stored, dict):
        return None
    try:
        fields = Reality.load(path).changes()
    except (LatentuneError, OSError, ValueError):
        return None
    return path if fields == {k: v for k, v in stored.items() if k != "name"} else None


def _short(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 50 else s[:47] + "..."


def start_point(start: Any, manual: np.ndarray, dim: int) -> tuple[np.ndarray | None, Any]:
    """(θ0 (d,) or None, the JSON record of ``start``) for a phase's ``start`` argument:
    ``"manual"`` (the system's manual θ), None (the critic's own design) or a unit-box θ."""
    if isinstance(start, str):
        if start != "manual":
            raise UsageError(f"start must be 'manual', None or a θ, got {start!r}")
        return manual, "manual"
    if start is None:
        return None, None
    from latentune.critic.base import as_unit_points

    try:
        x = as_unit_points(start, dim, "start")[0]
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return x, [float(v) for v in x]


def prior_record(prior: Any) -> str:
    """A fall prior as recorded: a run directory as its absolute path (a resume from another
    directory reads the same run), a label as it is."""
    return str(Path(prior).resolve()) if (Path(prior) / "run.db").is_file() else str(prior)


def same_option(key: str, old: Any, new: Any) -> bool:
    """Whether a stored option ``old`` is the given ``new``; a fall prior is a directory, so
    two spellings of one (``src``, ``./src``, its absolute path; a record written before it
    was recorded absolute) are the same; transfer options given at the default every run
    resumes with are the same as left out (:func:`latentune.critic.transfer.same_options`)."""
    if key == "fall_prior" and isinstance(old, str) and isinstance(new, str):
        return old == new or Path(old).resolve() == Path(new).resolve()
    if key == "transfer_options" and old != new:    # an option at its default: left out
        from latentune.critic.transfer import same_options

        return same_options(old, new)
    return old == new


FALL_KEYS = ("max_fall_prob", "fall_prior", "prior_counts", "prior_fingerprint")
"""The entries of a phase's options record that the fall-aware option writes
(:func:`fall_options`)."""


def default_fall_prob(phase: int, stored: dict[str, Any]) -> float | None:
    """The screen a phase with the options record ``stored`` runs with when ``max_fall_prob``
    is left out: the transfer phase 3's 0.3 (its critic's default,
    :data:`latentune.critic.transfer.TRANSFER_DEFAULTS`); None (off) in phase 1 and the plain
    phase 3, where giving it adds a fall-aware critic."""
    if int(phase) != Phase.PHASE3 or (stored.get("strategy") or "plain") != "transfer":
        return None
    from latentune.critic.transfer import TRANSFER_DEFAULTS

    return float(TRANSFER_DEFAULTS["max_fall_prob"])


def same_fall_prob(phase: int, stored: dict[str, Any], old: Any, new: Any) -> bool:
    """Whether the stored ``max_fall_prob`` ``old`` and the given ``new`` of a phase whose
    options record is ``stored`` screen alike: equal, or one left out (None) and the other
    the phase's default screen (:func:`default_fall_prob`: 0.3 in the transfer phase 3,
    where ``max_fall_prob=0.3`` is the option left out)."""
    if old == new:
        return True
    d = default_fall_prob(phase, stored)
    return d is not None and {old, new} <= {None, d}


def default_fall_note(key: str, phase: int, stored: dict[str, Any]) -> str:
    """What a refusal of another ``max_fall_prob`` (``key``) adds where the stored phase runs
    without one but screens at its default (:func:`default_fall_prob`): "; without it the
    transfer phase 3 screens at 0.3: …", so that 'no --max-fall-prob' does not read as no
    screen; "" otherwise."""
    d = default_fall_prob(phase, stored)
    if key != "max_fall_prob" or d is None or stored.get("max_fall_prob") is not None:
        return ""
    return (f"; without it the transfer phase 3 screens at {d:g}: leave it out (or give "
            f"{option('max_fall_prob', d)}) to go on with it")


def kept_regions_note(key: str, stored: dict[str, Any]) -> str:
    """What a refusal of other ``regions`` (``key``) on a resume adds: the run keeps its stored
    trust regions (their default follows the first budget, not a grown one) and how to go on
    with them; "" for another key."""
    if key != "regions" or stored.get("regions") is None:
        return ""
    return (f"; a resume keeps the stored regions: leave them out (or give "
            f"{option('regions', stored['regions'])}) to go on with them")


def fall_options(max_fall_prob: float | None, prior: Any) -> dict[str, Any]:
    """The options record of the fall-aware option (checked): ``prior`` a run directory (its
    trials counted, ``prior_counts``, and their ``prior_fingerprint``, None here: the phase
    pins it at its first start and checks it on resume, one read of the run each time,
    :func:`~latentune.pipeline.loop.check_phase1_runs`; :data:`PINNED`), a label, or None."""
    if max_fall_prob is None:
        if prior is not None:
            raise UsageError("fall_prior needs max_fall_prob (it seeds the fall prediction)")
        return {"max_fall_prob": None}
    if isinstance(max_fall_prob, bool) or not isinstance(max_fall_prob, (int, float)) or \
            not 0.0 < float(max_fall_prob) <= 1.0:
        raise UsageError(f"max_fall_prob must be in (0, 1], got {max_fall_prob!r}")
    counts = None if prior is None else run_counts(prior)
    return {"max_fall_prob": float(max_fall_prob),
            "fall_prior": None if prior is None else prior_record(prior),
            "prior_counts": counts, "prior_fingerprint": None}


def learns_from_source(strategy: str, max_fall_prob: float | None) -> bool:
    """Whether phase 3 with this ``strategy`` and ``max_fall_prob`` learns from its source
    run's trials: the transfer strategy and the fall prediction do; the plain phase 3 without
    one searches the latent space alone."""
    return strategy == "transfer" or max_fall_prob is not None


def pins_source(strategy: str, max_fall_prob: float | None, source: str) -> bool:
    """Whether phase 3 pins its ``source`` run's trials (:data:`PINNED`: ``source_counts``,
    and ``source_fingerprint`` for another run's): where it learns from them
    (:func:`learns_from_source`), and for another run's whatever the strategy, which knows
    that run by them (a moved source followed, another run refused)."""
    return learns_from_source(strategy, max_fall_prob) or source != "self"


def phase3_extra(source: str, strategy: str, start: Any, max_fall_prob: float | None,
                 hand_over: Any, transfer_options: dict[str, Any] | None,
                 source_counts: dict[str, int] | None = None,
                 source_fingerprint: str | None = None) -> dict[str, Any]:
    """Phase 3's own options for :meth:`Manifest.phase_options` (checked): the latent space's
    ``source``, the ``strategy``, the ``start`` record (:func:`start_point`), the fall-aware
    option (its prior: the latent space's source), the hand-over (:func:`handover`), the
    transfer critic's options (:func:`transfer_option`) and, where phase 3 pins its source's
    trials (:func:`pins_source`: ``source_counts`` None otherwise), how many of each phase the
    source run holds
    (:func:`run_counts`) and, for another run's, their fingerprint (:func:`run_fingerprint`),
    as the caller read them (:func:`~latentune.pipeline.loop.source_pin`; :data:`PINNED`: a
    resume uses those trials, not ones the source made since, and knows the source run by
    them)."""
    pinned = pins_source(strategy, max_fall_prob, source)
    return {"latent_source": source, "strategy": strategy, "start": start,
            **fall_options(max_fall_prob, None if max_fall_prob is None else "latent source"),
            "handover": handover(hand_over),
            **transfer_option(transfer_options, strategy, max_fall_prob),
            "source_counts": source_counts if pinned else None,
            "source_fingerprint": source_fingerprint if pinned and source != "self" else None}


def transfer_record(options: dict[str, Any] | None) -> dict[str, Any] | None:
    """``transfer_options`` as they are recorded: a plain JSON dict (numpy scalars as numbers),
    None for none; UsageError for anything but a dict of names to numbers, text and flags."""
    if not options:
        return None
    if not isinstance(options, dict) or not all(isinstance(k, str) for k in options):
        raise UsageError(f"transfer_options must be a dict of option names to values, "
                         f"got {options!r}")
    try:
        return json.loads(json.dumps(options, default=lambda v: v.item()))
    except (TypeError, ValueError, AttributeError):
        raise UsageError(f"transfer_options must hold numbers, text and true/false, got "
                         f"{options!r}") from None


def transfer_option(options: dict[str, Any] | None, strategy: str,
                    max_fall_prob: float | None) -> dict[str, Any]:
    """The options record of ``transfer_options`` (checked, before anything is written): options
    of phase 3's transfer critic over its defaults (keys of
    :data:`latentune.critic.transfer.TRANSFER_DEFAULTS`), a plain JSON dict under the key
    ``transfer_options``; None when none are given (not recorded). UsageError naming the
    option for an unknown one or a value the critic refuses (checked with ``max_fall_prob``,
    which is its own argument and refused here), and for any option with a strategy other
    than ``transfer``."""
    rec = transfer_record(options)
    if rec is None:
        return {"transfer_options": None}
    if strategy != "transfer":
        raise UsageError(f"transfer_options are options of the transfer phase 3 "
                         f"({option('strategy', 'transfer')}), not of the {strategy} one (the "
                         "strategy given, or the stored one, or plain where a hand-over is "
                         "given)")
    if "max_fall_prob" in rec:
        raise UsageError("max_fall_prob is an argument of its own (max_fall_prob=...), not one "
                         "of transfer_options")
    from latentune.critic.transfer import TRANSFER_DEFAULTS, Transfer

    unknown = sorted(set(rec) - set(TRANSFER_DEFAULTS))
    if unknown:
        raise UsageError(f"unknown option(s) of the transfer critic: {', '.join(unknown)} (see "
                         "latentune.critic.transfer.TRANSFER_DEFAULTS)")
    mfp = {} if max_fall_prob is None else {"max_fall_prob": max_fall_prob}

    def refusal(opts: dict[str, Any]) -> Exception | None:
        try:            # the critic's own checks, on a two-trial source
            Transfer((np.zeros((2, 1)), np.zeros(2), np.zeros(2, dtype=bool)), **mfp, **opts)
        except (TypeError, ValueError) as exc:
            return exc
        return None

    exc = refusal(rec)
    if exc is not None:
        bad = next((k for k in rec if refusal({k: rec[k]}) is not None), None)
        msg = str(exc if bad is None else refusal({bad: rec[bad]}))
        raise UsageError(msg if bad is not None and bad in msg else
                         f"transfer option {bad or ', '.join(rec)}: {msg}") from None
    return {"transfer_options": rec}


def source_option(method: str, source_run: Any) -> dict[str, Any]:
    """The options record of ``source_run``, a run whose phase-1 and phase-3 trials warm-start
    Optuna's CMA-ES (its ``source_trials`` mode): only with the method ``optuna-cmaes``; with
    the trials it holds now (``source_counts``, and their ``source_fingerprint``, None here
    and pinned at the phase's first start, :func:`~latentune.pipeline.loop.check_phase1_runs`;
    :data:`PINNED`: a resume uses those trials, not ones the source made since, and knows the
    run by them)."""
    if source_run is None:
        return {}
    if method != "optuna-cmaes":
        raise UsageError("source_run is an option of the method optuna-cmaes, not "
                         f"{method or 'turbo'} (pass method='optuna-cmaes')")
    if not (Path(source_run) / "run.db").is_file():
        raise StoreError(f"no latentune run in {source_run} (expected run.db)")
    counts = run_counts(source_run)
    return {"source_run": str(Path(source_run).resolve()), "source_counts": counts,
            "source_fingerprint": None}


def handover(option: Any) -> dict[str, Any] | None:
    """The checked hand-over options record (see :func:`~latentune.pipeline.phases.handover_options`)."""
    from latentune.pipeline.phases import handover_options

    try:
        return handover_options(option)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
