"""The run store: ``DIR/run.db``, SQLite in WAL mode, the single source of truth of a run.

Tables
------
``meta(key TEXT PRIMARY KEY, value TEXT)``: JSON values. ``format`` = ``latentune-run-store``,
``version``, ``config`` (task config, budgets, seeds, critic method, batch size, VAE options),
``artifacts`` (paths of the VAE weights, plots, best-θ files, relative to DIR), ``latent``
(phase-3 latent space description) and free entries.

``evaluations``: one row per finished evaluation, committed as it completes::

    phase      a :class:`~latentune.constants.Phase`: 0 manual θ, 1 phase 1 (θ space),
               3 phase 3 (latent space), 4 zero-shot (the source run's best θ on this system),
               5 preservation (encode → decode of stable θ)
    idx        0, 1, 2, ... unique and contiguous within a phase (completion order)
    theta      JSON list, the normalized θ that was evaluated
    z          JSON list, the critic's unit-box latent point (phase 3), else NULL
    tag        the critic's tag of the point (see latentune.critic.base)
    cost, fell (the trial failed), fall_step, wall_s, seed, created (unix time)
    info       JSON object of the trial's details (Outcome.info; ask/tell: trial id, note,
               who told it (:data:`TOLD_BY`, when the tell named an asker); a phase run's
               row stored out of ask order: ``asked``, see latentune.pipeline.phases)

``trials``: suggestions of ask/tell (trials run elsewhere)::

    id         integer, never reused (the suggestion id)
    phase, theta, z, tag   as above
    status     'queued' (asked from the critic, not handed out yet), 'pending' (handed out:
               leased to ``asker`` until ``lease_until``), 'told', or 'dropped' (queued, then
               discarded unseen because a told result was amended)
    idx        the evaluation row it became (NULL until told)
    asker      who holds it (pending) or held it last (told)
    lease_until  unix time the lease ends; an expired pending suggestion is handed out again
    created, told (unix times)

``amendments``: the audit trail of corrected results (:meth:`RunStore.amend_trial`): the
suggestion id (0 for a row a phase run stored: a copy amended with the row it was stored from),
its evaluation (phase, idx), the old and new (cost, fell, info) as JSON, the time and a note.
The evaluation row holds the corrected values.

Costs are stored as given; a non-finite cost is encoded as ±1e300 (NaN as +1e300) and decoded
back to ±inf by every reader here (:meth:`rows`, :meth:`history`, :meth:`costs`). ``fell`` is
data: a row fails only when its writer says so.

The critic's point is ``z`` in phase 3 and ``theta`` otherwise (:meth:`RunStore.history`).
Stores of version 1 (no ``info``, no ``trials``) are read as they are and upgraded in place by
their first write; stores of version 2 (trials without leases) by their first ask/tell write.
"""
from __future__ import annotations

import json
import math
import logging
import os
import sqlite3
import time
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from contextlib import contextmanager
from typing import Any, Iterable, Iterator

import numpy as np

from latentune.atomicfile import fsync_path
from latentune.constants import COST_LIMIT, Phase, phase_name
from latentune.errors import StoreError
from latentune.wording import option

FORMAT = "latentune-run-store"
VERSION = 3
INF_CODE = COST_LIMIT
"""How a non-finite cost is stored (SQLite REAL has no inf): ±INF_CODE."""
DB_NAME = "run.db"
OBJECT_META = ("config", "wall", "wall_open", "artifacts")
"""The meta entries that hold a JSON object (or are absent): opening a store whose entry holds
anything else is a StoreError naming it."""
LIST_META = ("wall_unknown",)
"""The meta entries that hold a JSON list (or are absent), checked as :data:`OBJECT_META`."""
DEFAULT_ASKER = "default"
"""The asker of a suggestion asked without an asker's name."""
TOLD_BY = "told_by"
"""The key of a told row's ``info`` naming who told (or amended) its result: the tell's asker;
absent when the tell named none."""
ASKED = "asked"
"""The key of a row's ``info`` that holds the index the row would have had in its batch's ask
order, for a row stored out of that order (a worker finished before an earlier-asked one)."""
NOT_REUSED = (ASKED, "trial", "reused", "same_as", "source", "source_phase", "source_idx",
              "source_cost", TOLD_BY)
"""The keys of a stored row's ``info`` that say where the row stands, not what the trial gave:
left out of the outcome a θ asked again is stored with (a copy, ``info["same_as"]``:
:func:`~latentune.pipeline.phases.stored_outcomes`), and kept by a copy when the row it was
stored from is amended (:meth:`RunStore.amend_trial`)."""

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS evaluations (
    phase INTEGER NOT NULL,
    idx INTEGER NOT NULL,
    theta TEXT NOT NULL,
    z TEXT,
    tag INTEGER NOT NULL,
    cost REAL NOT NULL,
    fell INTEGER NOT NULL,
    fall_step INTEGER,
    wall_s REAL,
    seed INTEGER,
    created REAL NOT NULL,
    info TEXT,
    PRIMARY KEY (phase, idx)
);
"""
_TRIALS = """
CREATE TABLE IF NOT EXISTS trials (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    phase INTEGER NOT NULL,
    theta TEXT NOT NULL,
    z TEXT,
    tag INTEGER NOT NULL,
    status TEXT NOT NULL,
    idx INTEGER,
    created REAL NOT NULL,
    told REAL,
    asker TEXT,
    lease_until REAL
);
"""
_AMENDMENTS = """
CREATE TABLE IF NOT EXISTS amendments (
    n INTEGER PRIMARY KEY AUTOINCREMENT,
    trial INTEGER NOT NULL,
    phase INTEGER NOT NULL,
    idx INTEGER NOT NULL,
    old TEXT NOT NULL,
    new TEXT NOT NULL,
    note TEXT,
    created REAL NOT NULL
);
"""

log = logging.getLogger(__name__)


@dataclass
class Row:
    """One stored evaluation."""

    phase: int
    idx: int
    theta: np.ndarray
    z: np.ndarray | None
    tag: int
    cost: float
    fell: bool
    fall_step: int | None
    wall_s: float | None
    seed: int | None
    created: float
    info: dict[str, Any] = field(default_factory=dict)


@dataclass
class Trial:
    """A suggestion of ask/tell (``status`` 'queued', 'pending', 'told' or 'dropped')."""

    id: int
    phase: int
    theta: np.ndarray
    z: np.ndarray | None
    tag: int
    status: str
    idx: int | None
    created: float
    asker: str | None = None
    lease_until: float | None = None


def _holder(asker: str, to: str = "") -> str:
    """A lease holder as a message names it: ``"bob"`` (``to``: ``"to bob"``, ``"theirs"``:
    ``"bob's"``), or, for a suggestion asked without an asker's name (:data:`DEFAULT_ASKER`),
    ``"without an asker's name"`` (``"the unnamed asker's"``)."""
    if asker == DEFAULT_ASKER:
        return "the unnamed asker's" if to == "theirs" else "without an asker's name"
    return f"{asker}'s" if to == "theirs" else f"{to} {asker}".strip()


def critics_told(phase: int) -> tuple[int, ...]:
    """The phases whose critic is told the rows of ``phase``: its own, and phase 3's for the
    zero-shot trial (the transfer critic is told it before its own rows)."""
    return (int(phase), int(Phase.PHASE3)) if int(phase) == Phase.ZERO_SHOT else (int(phase),)


def encode_cost(cost: float) -> float:
    """The stored value of a cost: itself, or ±:data:`INF_CODE` for ±inf (NaN: +INF_CODE)."""
    cost = float(cost)
    if math.isfinite(cost):
        return cost
    return INF_CODE if cost > 0 or math.isnan(cost) else -INF_CODE


def decode_cost(value: float) -> float:
    """The cost a stored value stands for (the inverse of :func:`encode_cost`)."""
    v = float(value)
    return math.copysign(math.inf, v) if abs(v) >= INF_CODE else v


def json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer, np.floating, np.bool_)):
        return o.item()
    return str(o)


def info_json(info: Any) -> str:
    """A trial's ``info`` as the JSON text the store keeps: NumPy values as numbers and lists,
    keys JSON cannot have (a tuple, a NumPy integer) and any other value as text
    (:func:`json_default`), a container that holds itself as ``"<circular>"``; never raises."""
    return json.dumps(_jsonable(info, ()), default=json_default)


def _jsonable(o: Any, path: tuple[int, ...]) -> Any:
    """``o`` with every dict's keys JSON keys and no container that holds itself (``path``: the
    ids of the containers ``o`` is inside)."""
    if not isinstance(o, (dict, list, tuple)):
        return o
    if id(o) in path:
        return "<circular>"
    inner = (*path, id(o))
    if isinstance(o, dict):
        return {k if isinstance(k, (str, int, float, bool)) or k is None else
                json_default(k) if isinstance(k, (np.integer, np.floating, np.bool_)) else str(k):
                _jsonable(v, inner) for k, v in o.items()}
    return [_jsonable(v, inner) for v in o]


def _enc(a: Any) -> str | None:
    if a is None:
        return None
    return json.dumps([float(v) for v in np.asarray(a, dtype=float).reshape(-1)])


def read_uri(path: str | Path) -> str:
    """The SQLite URI that opens the store file ``path`` read-only: its name percent-encoded
    (a directory named ``a#b``, ``x?y`` or ``50%`` is not a fragment, a query or an escape),
    and ``immutable`` when its directory cannot be written (read-only media) and it has no
    write-ahead log to read, since SQLite could not create its shared-memory file there."""
    p = Path(path).absolute()
    uri = f"file:{urllib.parse.quote(str(p))}?mode=ro"
    if not os.access(p.parent, os.W_OK) and not Path(f"{p}-wal").exists():
        uri += "&immutable=1"
    return uri


def version_of(con: sqlite3.Connection, amendments: bool, trials: bool) -> list[Any]:
    """:meth:`RunStore.data_version` of an open connection (``amendments``, ``trials``: the
    store has those tables)."""
    out: list[Any] = [list(r) for r in con.execute(
        "SELECT phase, COUNT(*), MAX(created) FROM evaluations GROUP BY phase ORDER BY phase")]
    n_amend = con.execute("SELECT COUNT(*) FROM amendments").fetchone()[0] if amendments else 0
    open_ = [r[0] for r in con.execute(
        "SELECT id FROM trials WHERE status IN ('queued', 'pending') ORDER BY id")] \
        if trials else []
    return [out, int(n_amend), open_]


class RunStore:
    """Open (or create) the store of a run directory.

    ``RunStore(DIR, create=True)`` creates ``DIR`` and ``DIR/run.db`` if needed;
    ``create=False`` requires an existing store. Any file that is not a latentune store raises
    :class:`StoreError` before anything is written to it. A store whose directory cannot be
    written (read-only media, another user's run), or whose file cannot (made read-only), is
    opened read-only (``read_only``): it is read as usual, and a write raises StoreError.
    """

    def __init__(self, run_dir: str | Path, create: bool = False) -> None:
        self.dir = Path(run_dir)
        self.path = self.dir / DB_NAME
        exists = self.path.is_file()
        if not exists and not create:
            if not self.dir.exists():
                raise StoreError(f"run directory {self.dir} does not exist")
            raise StoreError(f"no run store in {self.dir} (expected {DB_NAME})")
        if self.dir.exists() and not self.dir.is_dir():
            raise StoreError(f"{self.dir} is not a directory")
        if exists:
            self._check_foreign()
        else:
            self.dir.mkdir(parents=True, exist_ok=True)
            self._create()
        self.read_only = exists and not (os.access(self.dir, os.W_OK)
                                         and os.access(self.path, os.W_OK))
        try:
            if self.read_only:
                self.con = sqlite3.connect(read_uri(self.path), uri=True, timeout=30.0,
                                           isolation_level=None)
            else:
                self.con = sqlite3.connect(str(self.path), timeout=30.0, isolation_level=None)
                self.con.execute("PRAGMA journal_mode=WAL")
            self.con.execute("PRAGMA synchronous=NORMAL")
            self._current = self._is_current()
        except sqlite3.OperationalError as exc:
            raise StoreError(f"run store {self.path}: {exc}") from None
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"run store {self.path} is corrupt ({exc})") from None

    def _create(self) -> None:
        """Write a new store (tables, format mark, version) to a temporary file and link it in
        as ``DIR/run.db``: another process (a second first ask) never opens a store without
        its tables or format mark. A creator that loses the race opens the other's store."""
        tmp = self.dir / f".{DB_NAME}.{os.getpid()}.{time.monotonic_ns()}.tmp"
        try:
            con = sqlite3.connect(str(tmp), isolation_level=None)
            try:
                # a private file until it is linked in: no rollback journal and no syncs
                # while it is written (a crash leaves a temporary file that is never linked),
                # then one fsync of the file before the link and one of the directory after
                # it (before: a journal and its syncs in each of four transactions)
                con.execute("PRAGMA journal_mode=OFF")
                con.execute("PRAGMA synchronous=OFF")
                con.executescript("BEGIN;" + _SCHEMA + _TRIALS + _AMENDMENTS + "COMMIT;")
                con.executemany("INSERT INTO meta(key, value) VALUES (?, ?)",
                                [(k, json.dumps(v)) for k, v in (
                                    ("format", FORMAT), ("version", VERSION),
                                    ("created", time.time()))])
                # born in WAL mode: its first open never switches modes, which writes the
                # header through a rollback journal (a kill then left a hot journal that a
                # read-only open cannot roll back)
                con.execute("PRAGMA journal_mode=WAL")
            finally:
                con.close()
            fsync_path(tmp)
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                log.debug("%s: created by another process meanwhile", self.path)
            except OSError:                     # no hard links here: move it in if still new
                if not self.path.exists():
                    os.replace(tmp, self.path)
            fsync_path(self.dir)
        except sqlite3.Error as exc:
            raise StoreError(f"run store {self.path}: {exc}") from None
        finally:
            tmp.unlink(missing_ok=True)

    def _is_current(self) -> bool:
        cols = {r[1] for r in self.con.execute("PRAGMA table_info(evaluations)")}
        tables = {r[0] for r in self.con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        self._has_info = "info" in cols
        tcols = {r[1] for r in self.con.execute("PRAGMA table_info(trials)")}
        self._has_leases = "lease_until" in tcols and "amendments" in tables
        return self._has_info and "trials" in tables

    def _upgrade(self) -> None:
        """Bring a version-1 store to this version (adds ``evaluations.info`` and ``trials``);
        runs inside the first write transaction, so reading an old store never changes it."""
        if self._is_current():
            return
        if not self._has_info:
            self.con.execute("ALTER TABLE evaluations ADD COLUMN info TEXT")
        self.con.execute(_TRIALS)
        self.con.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('version', ?)",
                         (json.dumps(2),))
        self._has_info = True
        self._current = True

    def _upgrade_trials(self) -> None:
        """Add the leases (``trials.asker``, ``trials.lease_until``) and ``amendments`` of
        version 3; run inside the first ask/tell write, so phase runs never change the schema."""
        cols = {r[1] for r in self.con.execute("PRAGMA table_info(trials)")}
        for c, t in (("asker", "TEXT"), ("lease_until", "REAL")):
            if c not in cols:
                self.con.execute(f"ALTER TABLE trials ADD COLUMN {c} {t}")
        self.con.execute(_AMENDMENTS)
        self.con.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('version', ?)",
                         (json.dumps(VERSION),))
        self._has_leases = True

    def _check_foreign(self, rolled_back: bool = False) -> None:
        """Validate an existing file read-only (nothing is written to a foreign/corrupt file);
        a hot rollback journal a killed writer left is rolled back first (:meth:`_roll_back`,
        once: ``rolled_back``) where the store can be written."""
        # read through SQLite only: closing a descriptor of the file opened otherwise drops
        # every POSIX lock this process holds on it, an open connection's too, and another
        # process's close then deletes the write-ahead log that connection still writes
        not_sqlite = StoreError(f"{self.path} is not a latentune run store (not an SQLite file)")
        try:
            if os.stat(self.path).st_size == 0:     # SQLite would open it as an empty store
                raise not_sqlite
        except OSError as exc:
            raise StoreError(f"cannot read run store {self.path}: {exc.strerror}") from None
        try:
            con = sqlite3.connect(read_uri(self.path), uri=True, timeout=30.0)
            try:
                tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
                if not {"meta", "evaluations"} <= tables:
                    raise StoreError(f"{self.path} is not a latentune run store (missing tables)")
                row = con.execute("SELECT value FROM meta WHERE key='format'").fetchone()
                if row is None or json.loads(row[0]) != FORMAT:
                    raise StoreError(f"{self.path} is not a latentune run store (no format mark)")
                row = con.execute("SELECT value FROM meta WHERE key='version'").fetchone()
                version = 1 if row is None else json.loads(row[0])
                if isinstance(version, bool) or not isinstance(version, int):
                    raise TypeError(version)            # below: "bad meta"
                if version > VERSION:
                    raise StoreError(f"run store {self.path} is of version {version}, written by "
                                     f"a newer latentune (this one reads versions 1 to "
                                     f"{VERSION}): upgrade latentune to use it")
                for key, kind, what in [*((k, dict, "object") for k in OBJECT_META),
                                        *((k, list, "list") for k in LIST_META)]:
                    row = con.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
                    try:
                        value = None if row is None else json.loads(row[0])
                    except (json.JSONDecodeError, TypeError):
                        raise StoreError(f"run store {self.path}: meta entry {key!r} is not "
                                         "valid JSON") from None
                    if value is not None and not isinstance(value, kind):
                        raise StoreError(f"run store {self.path}: meta entry {key!r} is not a "
                                         f"JSON {what} (got {type(value).__name__})")
                cols = {r[1] for r in con.execute("PRAGMA table_info(evaluations)")}
                need = {"phase", "idx", "theta", "z", "tag", "cost", "fell", "fall_step"}
                if not need <= cols:
                    raise StoreError(f"{self.path} is not a latentune run store (bad schema)")
                ok = con.execute("PRAGMA quick_check").fetchone()
                if not ok or ok[0] != "ok":
                    raise StoreError(f"run store {self.path} is corrupt (integrity check failed)")
            finally:
                con.close()
        except sqlite3.OperationalError as exc:         # cannot open or locked: not corrupt
            if getattr(exc, "sqlite_errorname", "") == "SQLITE_READONLY_ROLLBACK" \
                    and not rolled_back and os.access(self.dir, os.W_OK) \
                    and os.access(self.path, os.W_OK):
                self._roll_back()
                return self._check_foreign(rolled_back=True)
            raise StoreError(f"cannot read run store {self.path}: {exc}") from None
        except sqlite3.DatabaseError as exc:
            if getattr(exc, "sqlite_errorname", "") == "SQLITE_NOTADB":
                raise not_sqlite from None
            raise StoreError(f"run store {self.path} is corrupt ({exc})") from None
        except (json.JSONDecodeError, TypeError):
            raise StoreError(f"{self.path} is not a latentune run store (bad meta)") from None

    def _roll_back(self) -> None:
        """Roll back the transaction a killed writer left in a rollback journal (a hot
        ``run.db-journal``: a store of an earlier version killed while it changed journal
        modes), which a read-only connection cannot do (SQLITE_READONLY_ROLLBACK): a
        read-write connection's first read does it, as any writer's would, and restores the
        store as it was before that transaction."""
        log.warning("%s: rolling back the transaction a killed process left in %s-journal",
                    self.path, DB_NAME)
        try:
            con = sqlite3.connect(str(self.path), timeout=30.0)
            try:
                con.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
            finally:
                con.close()
        except sqlite3.Error as exc:
            raise StoreError(f"cannot read run store {self.path}: {exc}") from None

    def snapshot(self) -> sqlite3.Connection:
        """A copy of the whole store in memory (an SQLite connection), for :meth:`restore`."""
        copy = sqlite3.connect(":memory:")
        try:
            self.con.backup(copy)
        except sqlite3.Error as exc:
            copy.close()
            raise StoreError(f"run store {self.path}: {exc}") from None
        return copy

    def restore(self, copy: sqlite3.Connection) -> None:
        """Put the store back as :meth:`snapshot` copied it (tables, schema and meta, in one
        write) and close the copy."""
        try:
            copy.backup(self.con)
        except sqlite3.Error as exc:
            raise StoreError(f"run store {self.path}: {exc}") from None
        finally:
            copy.close()
        self._current = self._is_current()

    # ------------------------------------------------------------------ meta
    def set_meta(self, key: str, value: Any) -> None:
        """Store a JSON-able value under ``key`` (its own transaction)."""
        with self._write():
            self.con.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                             (key, json.dumps(value, default=json_default)))

    def delete_meta(self, key: str) -> None:
        """Remove the meta entry ``key`` if there is one (its own transaction)."""
        with self._write():
            self.con.execute("DELETE FROM meta WHERE key=?", (key,))

    def update_meta(self, entries: dict[str, Any]) -> None:
        """Write several meta entries in one transaction (a None value removes the entry)."""
        with self._write():
            self._put_meta(entries)

    def _put_meta(self, entries: dict[str, Any]) -> None:
        for key, value in entries.items():
            if value is None:
                self.con.execute("DELETE FROM meta WHERE key=?", (key,))
            else:
                self.con.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                                 (key, json.dumps(value, default=json_default)))

    def get_meta(self, key: str, default: Any = None) -> Any:
        """The JSON value stored under ``key`` (``default`` if absent); StoreError if garbled."""
        row = self.con.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        if row is None:
            return default
        try:
            return json.loads(row[0])
        except (json.JSONDecodeError, TypeError):
            raise StoreError(f"run store {self.path}: meta entry {key!r} is not valid JSON") from None

    def meta(self) -> dict[str, Any]:
        """Every meta entry, decoded."""
        return {k: self.get_meta(k) for (k,) in self.con.execute("SELECT key FROM meta")}

    def add_artifact(self, name: str, path: str | Path) -> None:
        """Record an artifact path (stored relative to the run directory when inside it). The
        record is read and written in one transaction: an entry another process (a report
        beside a phase run) records meanwhile is kept."""
        p = Path(path)
        try:
            rel = str(p.resolve().relative_to(self.dir.resolve()))
        except ValueError:
            rel = str(p)
        with self._write():
            arts = self.get_meta("artifacts", {}) or {}
            arts[name] = rel
            self._put_meta({"artifacts": arts})

    def forget_artifact(self, name: str) -> None:
        """Drop an artifact's record (its file is the caller's to delete: a stored path may
        point anywhere), in one transaction as :meth:`add_artifact`."""
        with self._write():
            arts = self.get_meta("artifacts", {}) or {}
            if arts.pop(name, None) is not None:
                self._put_meta({"artifacts": arts})

    def artifact(self, name: str) -> Path | None:
        rel = (self.get_meta("artifacts", {}) or {}).get(name)
        if rel is None:
            return None
        p = Path(rel)
        return p if p.is_absolute() else self.dir / p

    # ------------------------------------------------------------------ rows
    def count(self, phase: int) -> int:
        return int(self.con.execute("SELECT COUNT(*) FROM evaluations WHERE phase=?",
                                    (phase,)).fetchone()[0])

    def next_idx(self, phase: int) -> int:
        row = self.con.execute("SELECT MAX(idx) FROM evaluations WHERE phase=?", (phase,)).fetchone()
        return 0 if row[0] is None else int(row[0]) + 1

    def add(self, phase: int, idx: int, theta: Any, cost: float, *, z: Any = None, tag: int = -1,
            fell: bool | None = None, fall_step: int | None = None, wall_s: float | None = None,
            seed: int | None = None, info: dict[str, Any] | None = None) -> None:
        """Commit one evaluation (its own transaction). A duplicate (phase, idx) raises StoreError.

        ``fell``: whether the trial failed; ``None`` means "failed if a failure step is given"
        (``fall_step`` not None). Non-finite costs are encoded (:func:`encode_cost`)."""
        with self._write():
            self._insert(phase, idx, theta, cost, z, tag, fell, fall_step, wall_s, seed, info)

    def _insert(self, phase: int, idx: int, theta: Any, cost: float, z: Any, tag: int,
                fell: bool | None, fall_step: int | None, wall_s: float | None,
                seed: int | None, info: dict[str, Any] | None) -> None:
        if fell is None:
            fell = fall_step is not None
        cost = encode_cost(cost)
        try:
            self.con.execute(
                "INSERT INTO evaluations(phase, idx, theta, z, tag, cost, fell, fall_step, "
                "wall_s, seed, created, info) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (int(phase), int(idx), _enc(theta), _enc(z), int(tag), cost, int(bool(fell)),
                 None if fall_step is None else int(fall_step),
                 None if wall_s is None else float(wall_s),
                 None if seed is None else int(seed), time.time(),
                 None if not info else info_json(info)))
        except sqlite3.IntegrityError:
            raise StoreError(f"evaluation {idx} of phase {phase} is already stored") from None

    def check_writable(self) -> None:
        """StoreError, naming what cannot be written and what to do, when the store was opened
        read-only (its directory or its file cannot be written); nothing otherwise."""
        if not self.read_only:
            return
        if not os.access(self.dir, os.W_OK):
            raise StoreError(f"{self.dir} cannot be written (read-only): copy the run to a "
                             "writable directory and use the copy")
        raise StoreError(f"{self.path} cannot be written (read-only): make it writable, or "
                         "copy the run to a writable directory")

    @contextmanager
    def _write(self, trials: bool = False) -> Iterator[None]:
        """One write transaction (BEGIN IMMEDIATE … COMMIT); a full disk or a locked database
        becomes a StoreError with the store untouched. ``trials``: an ask/tell write (upgrades
        the trials table to leases first)."""
        self.check_writable()
        try:
            self.con.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            raise StoreError(f"run store {self.path}: {exc}") from None
        try:
            if not self._current:
                self._upgrade()
            if trials and not self._has_leases:
                self._upgrade_trials()
            yield
            self.con.execute("COMMIT")
        except BaseException as exc:
            try:
                self.con.execute("ROLLBACK")
            except sqlite3.Error:
                pass
            if isinstance(exc, sqlite3.OperationalError):
                raise StoreError(f"run store {self.path}: {exc}") from None
            raise

    # ------------------------------------------------------------------ ask/tell trials
    def queue_trials(self, phase: int, thetas: Any, zs: list[Any], tags: Any,
                     meta: dict[str, Any] | None = None,
                     told: list[dict[str, Any] | None] | None = None,
                     each: tuple[str, Any] | None = None) -> list[int]:
        """Record a batch the critic asked as 'queued' suggestions (one transaction); return
        their ids in ask order. ``thetas`` (n, d), ``zs`` n codes or None, ``tags`` (n,).
        ``meta``: entries written in the same transaction (a None value removes the entry).
        ``each``: ``(key, value)``: the meta entry ``key`` (a map of suggestion ids) gets
        ``value`` under each new suggestion's id, in the same transaction.
        ``told``: per suggestion None, or the result it is told at once (a θ of a stored trial,
        not run again): a dict of ``cost``, ``fell``, ``fall_step``, ``wall_s``, ``seed`` and
        ``info``, stored as the next evaluation of ``phase`` (in the order given)."""
        now = time.time()
        with self._write(trials=True):
            self._put_meta(meta or {})
            ids = []
            for th, z, tag, res in zip(thetas, zs, tags, told or [None] * len(thetas)):
                cur = self.con.execute(
                    "INSERT INTO trials(phase, theta, z, tag, status, idx, created) "
                    "VALUES (?, ?, ?, ?, 'queued', NULL, ?)",
                    (int(phase), _enc(th), _enc(z), int(tag), now))
                ids.append(int(cur.lastrowid))
                if res is not None:
                    self._told_now(ids[-1], int(phase), th, z, int(tag), res, now)
            if each is not None:
                key, value = each
                self._put_meta({key: {**(self.get_meta(key) or {}),
                                      **{str(i): value for i in ids}}})
        return ids

    def _told_now(self, tid: int, phase: int, theta: Any, z: Any, tag: int,
                  res: dict[str, Any], now: float) -> None:
        """Store ``res`` (see :meth:`queue_trials`' ``told``) as the next evaluation of
        ``phase`` for suggestion ``tid`` and mark it told (within the caller's transaction)."""
        idx = self.next_idx(phase)
        self._insert(phase, idx, theta, res["cost"], z, tag, res["fell"], res.get("fall_step"),
                     res.get("wall_s"), res.get("seed"), {**(res.get("info") or {}), "trial": tid})
        self.con.execute("UPDATE trials SET status='told', idx=?, told=? WHERE id=?",
                         (idx, now, tid))

    def tell_queued(self, told: dict[int, dict[str, Any]]) -> None:
        """Tell queued suggestions at once, in one transaction: ``{id: result}`` (a dict as
        :meth:`queue_trials`' ``told``), in the order given; a suggestion no longer queued is
        left as it is."""
        now = time.time()
        with self._write(trials=True):
            for tid, res in told.items():
                t = self._trial(tid)
                if t.status == "queued":
                    self._told_now(t.id, t.phase, t.theta, t.z, t.tag, res, now)

    def add_trial(self, phase: int, theta: Any, z: Any, tag: int) -> int:
        """Record one 'queued' suggestion; return its id."""
        return self.queue_trials(phase, [theta], [z], [tag])[0]

    def lease(self, asker: str, phases: tuple[int, ...], n: int, lease_s: float,
              queued_only: bool = False, waits: tuple[int, ...] = ()
              ) -> list[tuple[Trial, bool]]:
        """Hand out up to ``n`` suggestions of ``phases`` to ``asker`` for ``lease_s`` seconds,
        in one transaction: first those ``asker`` holds already, then those whose lease expired
        (or that were never leased under version 2), then queued ones (``phases`` in the order
        given, oldest first); only queued ones with ``queued_only``. Returns ``(trial, again)``
        pairs; ``again``: it was handed out before. Each suggestion is leased to one asker at a
        time. ``waits``: phases whose queued suggestion is not handed out while an earlier one
        of these phases with its θ is queued or handed out (it is told that one's outcome)."""
        now = time.time()
        ph = tuple(int(p) for p in phases)
        marks = ",".join("?" * len(ph))
        out: list[tuple[Trial, bool]] = []
        with self._write(trials=True):
            picks: list[tuple[int, bool]] = []
            for q, args in (
                    (f"status='pending' AND asker=? AND phase IN ({marks})", (asker, *ph)),
                    (f"status='pending' AND (asker IS NULL OR asker<>?) AND "
                     f"(lease_until IS NULL OR lease_until<?) AND phase IN ({marks})",
                     (asker, now, *ph))):
                if queued_only:
                    break
                for (i,) in self.con.execute(f"SELECT id FROM trials WHERE {q} ORDER BY id", args):
                    picks.append((int(i), True))
            wait = ",".join(str(int(p)) for p in waits)
            twin = (f" AND NOT (phase IN ({wait}) AND EXISTS (SELECT 1 FROM trials o WHERE "
                    f"o.id<q.id AND o.phase IN ({wait}) AND o.theta=q.theta AND "
                    "o.status IN ('queued', 'pending')))") if waits else ""
            for p in ph:
                for (i,) in self.con.execute("SELECT id FROM trials q WHERE status='queued' AND "
                                             f"phase=?{twin} ORDER BY id", (p,)):
                    picks.append((int(i), False))
            for i, again in picks[:int(n)]:
                self.con.execute("UPDATE trials SET status='pending', asker=?, lease_until=? "
                                 "WHERE id=?", (asker, now + float(lease_s), i))
                out.append((self._trial(i), again))
        return out

    def restore_leases(self, before: list[Trial]) -> None:
        """Undo leases, in one transaction: each suggestion of ``before`` (as it was before
        they were given) that is pending now gets back its status, asker and lease end."""
        with self._write(trials=True):
            for t in before:
                self.con.execute("UPDATE trials SET status=?, asker=?, lease_until=? WHERE id=? "
                                 "AND status='pending'",
                                 (t.status, t.asker, t.lease_until, int(t.id)))

    def release(self, trial_id: int) -> None:
        """Give a pending suggestion back (its lease ends now): the next ask hands it out
        again. StoreError unless it is pending."""
        with self._write(trials=True):
            t = self._trial(trial_id)
            if t.status != "pending":
                raise StoreError(f"suggestion {trial_id} is {t.status}, not pending: there is "
                                 "no lease to release")
            self.con.execute("UPDATE trials SET status='queued', asker=NULL, lease_until=NULL "
                             "WHERE id=?", (int(trial_id),))

    def drop_queued(self, phases: tuple[int, ...]) -> int:
        """Withdraw the suggestions of ``phases`` asked but not handed out yet (status 'queued'
        to 'dropped'): a phase run in-process asks its own. Returns how many."""
        if not self._has_leases:                # no suggestion was ever asked here
            return 0
        marks = ", ".join("?" * len(phases))
        with self._write(trials=True):
            return self.con.execute(f"UPDATE trials SET status='dropped' WHERE status='queued' "
                                    f"AND phase IN ({marks})", tuple(map(int, phases))).rowcount

    def _trial(self, trial_id: int) -> Trial:
        tid = int(trial_id)     # ids count from 1; SQLite's integers end below 2**63
        found = self.trials(trial_id=tid) if 0 < tid < 2 ** 63 else []
        if not found:
            raise StoreError(f"no suggestion with id {trial_id} in {self.dir}")
        return found[0]

    def trials(self, status: str | None = None, trial_id: int | None = None) -> list[Trial]:
        """Suggestions (oldest first): all, those with ``status`` ('queued', 'pending', 'told',
        'dropped'), or the one with id ``trial_id``."""
        if not self._current:
            return []
        lease = "asker, lease_until" if self._has_leases else "NULL, NULL"
        q = f"SELECT id, phase, theta, z, tag, status, idx, created, {lease} FROM trials"
        where, args = [], []
        if status:
            where.append("status=?")
            args.append(status)
        if trial_id is not None:
            where.append("id=?")
            args.append(int(trial_id))
        rows = self.con.execute(q + (" WHERE " + " AND ".join(where) if where else "")
                                + " ORDER BY id", args)
        return [Trial(int(r[0]), int(r[1]), np.array(json.loads(r[2]), dtype=float),
                      None if r[3] is None else np.array(json.loads(r[3]), dtype=float),
                      int(r[4]), r[5], r[6], float(r[7]), r[8], r[9]) for r in rows]

    def trials_by_id(self, trial_id: int) -> Trial:
        """The suggestion ``trial_id`` (StoreError if there is none)."""
        return self._trial(trial_id)

    def tell_trial(self, trial_id: int, cost: float, *, fell: bool, fall_step: int | None = None,
                   wall_s: float | None = None, seed: int | None = None,
                   info: dict[str, Any] | None = None, asker: str | None = None) -> int:
        """Store the result of a pending suggestion as the next evaluation of its phase and mark
        it told, in one transaction (a crash leaves it pending, never half-told). Returns idx.
        ``asker``: who tells it, recorded in the row's info (:data:`TOLD_BY`); None: not named.

        Raises StoreError for an unknown id, or one that is told, or is not handed out
        (never asked for, released or withdrawn), or, with ``asker``, one whose lease another
        asker holds and has not expired."""
        with self._write(trials=True):
            t = self._trial(trial_id)
            if t.status == "told":
                raise StoreError(self._told_already(t))
            if t.status != "pending":
                raise StoreError(f"suggestion {trial_id} is not handed out ({t.status}: " + (
                    "never asked for, or released; ask for it)" if t.status == "queued" else
                    "withdrawn unasked after an amendment or a phase run)"))
            if asker is not None and t.asker not in (None, asker) \
                    and t.lease_until is not None and t.lease_until >= time.time():
                until = time.strftime("%H:%M:%S UTC", time.gmtime(t.lease_until))
                raise StoreError(f"suggestion {trial_id} is handed out {_holder(t.asker, 'to')} "
                                 f"until {until}, not to {asker}: {asker}'s result is not "
                                 f"stored (while the lease lasts, its result is "
                                 f"{_holder(t.asker, 'theirs')} to tell)")
            row = self.con.execute("SELECT MAX(idx) FROM evaluations WHERE phase=?",
                                   (t.phase,)).fetchone()
            idx = 0 if row[0] is None else int(row[0]) + 1
            inf = dict(info or {})
            inf["trial"] = int(trial_id)
            if asker is not None:
                inf[TOLD_BY] = str(asker)
            self._insert(t.phase, idx, t.theta, cost, t.z, t.tag, fell, fall_step, wall_s, seed,
                         inf)
            self.con.execute("UPDATE trials SET status='told', idx=?, told=? WHERE id=?",
                             (idx, time.time(), int(trial_id)))
        return idx

    def _told_already(self, t: Trial) -> str:
        """The refusal of a second tell of told suggestion ``t``: the result that stands (cost,
        fall, note), when it was told (or last amended), by whom (:data:`TOLD_BY`) and to whom
        ``t`` was handed out then, so that a teller whose lease had expired and was taken over
        amends knowingly, or not at all."""
        r = self.con.execute("SELECT e.cost, e.fell, e.info, t.told FROM evaluations e JOIN "
                             "trials t ON t.phase=e.phase AND t.idx=e.idx WHERE t.id=?",
                             (int(t.id),)).fetchone()
        info = json.loads(r[2]) if r[2] else {}
        note = f", note {json.dumps(str(info['note']), ensure_ascii=False)}" if info.get("note") \
            else ""
        amended = self.con.execute("SELECT MAX(created) FROM amendments WHERE trial=?",
                                   (int(t.id),)).fetchone()[0] if self._has_leases else None
        at = r[3] if amended is None else amended
        when = (time.strftime(" %Y-%m-%d %H:%M:%S UTC", time.gmtime(at))
                if at is not None else "")
        by = f" by {info[TOLD_BY]}" if info.get(TOLD_BY) else " by a tell that named no asker"
        to = "" if not t.asker else f", while handed out {_holder(t.asker, 'to')}"
        return (f"suggestion {t.id} was already told: cost {decode_cost(r[0]):.6g}"
                f"{' (failed)' if r[1] else ''}{note}, {'told' if amended is None else 'amended'}"
                f"{when}{by}{to} ({phase_name(t.phase)} "
                f"evaluation {t.idx}). That result stands; to replace it, tell it again with "
                f"{option('amend', True)}")

    def amend_trial(self, trial_id: int, cost: float, *, fell: bool,
                    fall_step: int | None = None, info: dict[str, Any] | None = None,
                    note: str | None = None, asker: str | None = None
                    ) -> tuple[int, int, bool, list[tuple[int, int]]]:
        """Correct the told result of suggestion ``trial_id`` in one transaction: its
        evaluation row gets the new cost, fell, fall_step and info (the told note, ``info``'s
        ``"note"``, unless ``info`` gives one; :data:`TOLD_BY` the amending ``asker``, none
        when it names none: the result is no longer the first teller's); the old and new values go
        to ``amendments`` (the audit trail). When the cost, fell or fall_step changed (an
        amendment of the info or the note alone changes nothing the critic saw), the rows
        stored as copies of it (``info["same_as"]``, by ask/tell or a phase run alike), and
        copies of those, are amended to the same outcome, each with its own entry
        (:meth:`_amend_copies`), and the queued suggestions of the phases whose critics were
        told an amended row (:func:`critics_told`), asked from the uncorrected rows, are
        dropped. Returns (phase, idx, whether the outcome changed, the (phase, idx) of the
        copies amended). StoreError unless it was told."""
        with self._write(trials=True):
            t = self._trial(trial_id)
            if t.status != "told":
                raise StoreError(f"suggestion {trial_id} is {t.status}: only a told result can "
                                 "be amended (tell it first)")
            r = self.con.execute("SELECT cost, fell, fall_step, info FROM evaluations "
                                 "WHERE phase=? AND idx=?", (t.phase, t.idx)).fetchone()
            old = {"cost": decode_cost(r[0]), "fell": bool(r[1]), "fall_step": r[2],
                   "info": json.loads(r[3]) if r[3] else {}}
            inf = dict(info or {})
            inf["trial"] = int(trial_id)
            if "note" in old["info"] and "note" not in inf:   # a correction keeps the
                inf["note"] = old["info"]["note"]             # operator's note unless given
            inf.pop(TOLD_BY, None)
            if asker is not None:
                inf[TOLD_BY] = str(asker)
            if fell is None:
                fell = fall_step is not None
            new = {"cost": float(cost), "fell": bool(fell), "fall_step": fall_step, "info": inf}
            self.con.execute("UPDATE evaluations SET cost=?, fell=?, fall_step=?, info=? "
                             "WHERE phase=? AND idx=?",
                             (encode_cost(cost), int(bool(fell)),
                              None if fall_step is None else int(fall_step),
                              info_json(inf), t.phase, t.idx))
            self.con.execute("INSERT INTO amendments(trial, phase, idx, old, new, note, created) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (int(trial_id), t.phase, t.idx,
                              info_json(old), info_json(new), note, time.time()))
            changed = [old[k] for k in ("cost", "fell", "fall_step")] != \
                [new[k] for k in ("cost", "fell", "fall_step")]
            copies = self._amend_copies(t.phase, int(t.idx), new, note) if changed else []
            if changed:
                for ph in {c for p in (t.phase, *(p for p, _ in copies))
                           for c in critics_told(p)}:
                    self.con.execute("UPDATE trials SET status='dropped' WHERE status='queued' "
                                     "AND phase=?", (ph,))
        return t.phase, int(t.idx), changed, copies

    def _amend_copies(self, phase: int, idx: int, new: dict[str, Any], note: str | None
                      ) -> list[tuple[int, int]]:
        """Within the caller's transaction, amend the rows stored as copies of evaluation
        ``idx`` of ``phase`` and the copies of those (:meth:`copies`) to its corrected outcome
        ``new`` (cost, fell, fall_step, info); return their (phase, idx). A copy keeps its own
        :data:`NOT_REUSED` entries (its suggestion id if it has one, ``same_as``, ``asked``)
        and takes the rest of its info from ``new``; each gets its entry in ``amendments``
        (its suggestion id, or 0), noted ``note`` or "<phase> evaluation <idx> amended"."""
        out: list[tuple[int, int]] = []
        for r in self.copies(phase, idx):
            inf = {**{k: v for k, v in new["info"].items() if k not in NOT_REUSED},
                   **{k: v for k, v in r.info.items() if k in NOT_REUSED}, "reused": True}
            if new["fall_step"] is not None:
                inf["fall_step"] = new["fall_step"]
            self.con.execute("UPDATE evaluations SET cost=?, fell=?, fall_step=?, info=? "
                             "WHERE phase=? AND idx=?",
                             (encode_cost(new["cost"]), int(bool(new["fell"])),
                              new["fall_step"], info_json(inf), r.phase, r.idx))
            trial = r.info.get("trial")
            self.con.execute("INSERT INTO amendments(trial, phase, idx, old, new, note, created) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (int(trial) if isinstance(trial, int) else 0, r.phase, r.idx,
                              info_json({"cost": r.cost, "fell": r.fell,
                                         "fall_step": r.fall_step, "info": r.info}),
                              info_json({**new, "info": inf}),
                              note or f"{phase_name(phase)} evaluation {idx} amended",
                              time.time()))
            out.append((int(r.phase), int(r.idx)))
        return out

    def copies(self, phase: int, idx: int) -> list[Row]:
        """The rows stored as copies of evaluation ``idx`` of ``phase`` (``info["same_as"]``:
        a θ asked again, stored with its outcome and not run, by ask/tell or a phase run), and
        the copies of those, in the order they were stored."""
        if not (self._current or self._has_info):
            return []
        rows = {(r.phase, r.idx): r for (p,) in self.con.execute(
                    "SELECT DISTINCT phase FROM evaluations WHERE info LIKE '%same_as%'"
                ).fetchall() for r in self.rows(p) if r.info.get("same_as") is not None}
        found, todo = set(), [(int(phase), int(idx))]
        while todo:
            of = list(todo.pop())
            new = [k for k, r in rows.items() if r.info["same_as"] == of and k not in found]
            found.update(new)
            todo += new
        return [rows[k] for k in self.stored_order() if k in found]

    def amendments(self) -> list[dict[str, Any]]:
        """The audit trail of amended results, oldest first: ``{n, trial, phase, idx, old, new,
        note, created}`` (n: the amendment's number, rising; trial: the suggestion id, None for
        a copy a phase run stored; old/new: cost, fell, fall_step, info)."""
        if not self._has_leases:
            return []
        return [{"n": r[7], "trial": r[0] or None, "phase": r[1], "idx": r[2],
                 "old": json.loads(r[3]),
                 "new": json.loads(r[4]), "note": r[5], "created": r[6]}
                for r in self.con.execute("SELECT trial, phase, idx, old, new, note, created, n "
                                          "FROM amendments ORDER BY n")]

    def data_version(self) -> list[Any]:
        """A JSON-able summary that changes whenever the data a critic is built from change:
        per phase the number of evaluations and the latest one's time, the number of
        amendments (rows change only by a tell or an amendment), and the ids of the open
        (queued or pending) suggestions. Two equal summaries of one store: the same rows."""
        return version_of(self.con, self._has_leases, self._current)

    @staticmethod
    def data_version_of(run_dir: str | Path) -> list[Any]:
        """:meth:`data_version` of the store in ``run_dir``, read-only (StoreError if there is
        none or it cannot be read)."""
        path = Path(run_dir) / DB_NAME
        if not path.is_file():
            raise StoreError(f"no run store in {run_dir} (expected {DB_NAME})")
        try:
            con = sqlite3.connect(read_uri(path), uri=True, timeout=30.0)
            try:
                tables = {r[0] for r in con.execute(
                    "SELECT name FROM sqlite_master WHERE type='table'")}
                cols = {r[1] for r in con.execute("PRAGMA table_info(trials)")}
                return version_of(con, "amendments" in tables and "lease_until" in cols,
                                  "trials" in tables)
            finally:
                con.close()
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"run store {path}: {exc}") from None

    def stored_order(self) -> list[tuple[int, int]]:
        """``(phase, idx)`` of every evaluation, in the order they were stored (SQLite's rowid:
        an insert's, kept by an amendment)."""
        return [(int(p), int(i)) for p, i in
                self.con.execute("SELECT phase, idx FROM evaluations ORDER BY rowid")]

    def rows(self, phase: int) -> list[Row]:
        """The evaluations of ``phase`` in idx order (StoreError for a garbled row)."""
        out = []
        info = "info" if self._current or self._has_info else "NULL"
        for r in self.con.execute(
                "SELECT phase, idx, theta, z, tag, cost, fell, fall_step, wall_s, seed, created, "
                f"{info} FROM evaluations WHERE phase=? ORDER BY idx", (int(phase),)):
            try:
                out.append(Row(r[0], r[1], np.array(json.loads(r[2]), dtype=float),
                               None if r[3] is None else np.array(json.loads(r[3]), dtype=float),
                               int(r[4]), decode_cost(r[5]), bool(r[6]), r[7], r[8], r[9], r[10],
                               json.loads(r[11]) if r[11] else {}))
            except (json.JSONDecodeError, TypeError, ValueError):
                raise StoreError(f"run store {self.path}: evaluation {r[1]} of phase {r[0]} "
                                 "is garbled") from None
        return out

    def history(self, phase: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The critic's view of a phase: (X (n, k), y (n,), tags (n,)) in idx order.

        X holds ``z`` for rows that have one (phase 3), else ``theta``.
        """
        rows = self.rows(phase)
        if not rows:
            return np.empty((0, 0)), np.empty(0), np.empty(0, dtype=np.int64)
        X = np.array([r.z if r.z is not None else r.theta for r in rows])
        y = np.array([r.cost for r in rows])
        t = np.array([r.tag for r in rows], dtype=np.int64)
        return X, y, t

    def costs(self, phase: int) -> np.ndarray:
        """(n,) the decoded costs of ``phase`` in idx order."""
        return np.array([decode_cost(r[0]) for r in self.con.execute(
            "SELECT cost FROM evaluations WHERE phase=? ORDER BY idx", (phase,))], dtype=float)

    def fell(self, phase: int) -> np.ndarray:
        """(n,) bool: which evaluations of ``phase`` failed, in idx order."""
        return np.array([bool(r[0]) for r in self.con.execute(
            "SELECT fell FROM evaluations WHERE phase=? ORDER BY idx", (phase,))], dtype=bool)

    def best(self, phase: int) -> Row | None:
        """The lowest-cost row of ``phase`` that did not fail (the first on ties); None if no
        row stood. A failed trial is never the best, whatever cost it was given."""
        rows = [r for r in self.rows(phase) if not r.fell]
        return min(rows, key=lambda r: (r.cost, r.idx)) if rows else None

    def check_contiguous(self, phase: int) -> None:
        n, mx = self.con.execute("SELECT COUNT(*), MAX(idx) FROM evaluations WHERE phase=?",
                                 (phase,)).fetchone()
        if n and (mx != n - 1):
            raise StoreError(f"phase {phase} indices are not contiguous ({n} rows, max idx {mx})")

    def check(self) -> None:
        """Check every phase: indices contiguous, rows decodable, config readable (StoreError;
        a file SQLite finds malformed too)."""
        try:
            for (ph,) in self.con.execute("SELECT DISTINCT phase FROM evaluations").fetchall():
                self.check_contiguous(ph)
                self.rows(ph)
            self.get_meta("config")
        except sqlite3.OperationalError as exc:         # locked or unreadable: not corrupt
            raise StoreError(f"cannot read run store {self.path}: {exc}") from None
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"run store {self.path} is corrupt ({exc})") from None

    def close(self) -> None:
        try:
            self.con.close()
        except sqlite3.Error as exc:
            log.debug("closing %s: %s", getattr(self, "dir", "the store"), exc)

    def __enter__(self) -> "RunStore":
        return self

    def __exit__(self, *exc: Iterable[Any]) -> None:
        self.close()
