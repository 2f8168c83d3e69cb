"""A latentune run shown live in ``optuna-dashboard`` (the ``latentune[optuna]`` extra).

``latentune dashboard DIR`` (or :func:`serve`) exports the run store ``DIR/run.db`` into an
Optuna storage, keeps it in step with a polling thread, and serves it with optuna-dashboard's
WSGI app on ``127.0.0.1`` only.

The export (:class:`RunExport`)
-------------------------------
* one Optuna study per phase present in the store, named ``<DIR name>/<phase>``: ``manual``
  (phase 0), ``phase 1``, ``phase 3``, ``zero-shot`` (phase 4), ``preservation`` (phase 5);
  direction minimize; study user attributes ``latentune_run`` (the directory) and ``phase``;
* one trial per evaluation row, in the phase's idx order: parameters by name in physical units
  (the run's ``ParameterSpace`` as ``FloatDistribution``s), value = the stored cost, user
  attributes ``phase``, ``idx``, ``fell``, ``fall_step``, ``tag``, ``seed``, ``z`` (phase 3's
  latent point) and the row's ``info`` entries as ``info:<key>``; a fall carries the Optuna
  constraint ``fall`` = 1 (else 0), written both as Optuna 4+ names it (``constraints:fall``)
  and in the list optuna-dashboard reads (``constraints``, which Optuna's ``trial.constraints``
  shows as ``"0"``), so the dashboard draws it as infeasible; a row whose cost is non-finite
  (stored as 1e300) is a FAIL trial;
* a suggestion handed out by ``ask`` and not told yet is a RUNNING trial; when it is told, that
  trial is completed with its result (a suggestion released by its asker stays RUNNING until it
  is told; one dropped unseen becomes a FAIL trial with user attribute ``status = dropped``);
* a result corrected after it was exported (``amend``) keeps its first value here: Optuna does
  not change a finished trial; restart the dashboard to show it;
* θ are named by the run's recorded parameter space (a built-in robot's run of the first store
  layout: its task's); a store holding trials without either (another layout's) is refused
  with a StoreError saying so, instead of an export that stays empty;
* the store is read again every ``interval`` seconds (a new SQLite connection each time, read
  only: the run's writer is never blocked for long); a phase whose row count has not grown is
  not read again, and a row is exported once, whatever its idx (preservation rows have gaps).

The exported storage is in memory, or an Optuna journal file with ``journal=`` (a new file).
"""
from __future__ import annotations

import datetime as _dt
import logging
import math
import threading
from pathlib import Path
from typing import Any
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server
from socketserver import ThreadingMixIn

try:
    import optuna
    import optuna_dashboard
except ImportError:  # pragma: no cover - the extra is not installed
    raise ImportError("latentune.integrations.dashboard needs optuna and optuna-dashboard: "
                      "pip install 'latentune[optuna]'") from None

from latentune.constants import Phase
from latentune.errors import StoreError, UsageError
from latentune.integrations.optuna import distributions_of, physical_params
from latentune.pipeline.manifest import config_space
from latentune.pipeline.store import RunStore
from latentune.space import ParameterSpace
from latentune.wording import counted

logger = logging.getLogger(__name__)

PHASE_LABELS = {Phase.MANUAL: "manual", Phase.PHASE1: "phase 1", Phase.PHASE3: "phase 3",
                Phase.ZERO_SHOT: "zero-shot", Phase.PRESERVATION: "preservation"}
"""The Optuna study name suffix of each phase."""
HOST = "127.0.0.1"
"""The dashboard listens on this address only."""


def _time(t: float) -> _dt.datetime:
    return _dt.datetime.fromtimestamp(float(t))


class RunExport:
    """Keep an Optuna storage in step with the run store of ``run_dir`` (see the module
    docstring); call :meth:`sync` to export what is new.

    Args:
        run_dir: a latentune run directory (``run.db`` must exist).
        storage: the Optuna storage to write (default a new ``InMemoryStorage``).
    Raises StoreError for a directory without a run store.
    """

    def __init__(self, run_dir: str | Path, storage: Any = None) -> None:
        self.dir = Path(run_dir)
        if not (self.dir / "run.db").is_file():
            raise StoreError(f"no latentune run in {self.dir} (expected run.db)")
        self.storage = storage if storage is not None else optuna.storages.InMemoryStorage()
        self.name = self.dir.resolve().name
        self._study_ids: dict[int, int] = {}
        self._done: dict[int, set[int]] = {}            # phase -> idx exported (a
        # preservation row's idx is its phase-1 row's: a phase's idx may have gaps)
        self._running: dict[int, int] = {}              # store suggestion id -> Optuna trial id
        self._space: ParameterSpace | None = None
        self._lock = threading.Lock()

    def study_name(self, phase: int) -> str:
        """The Optuna study name of ``phase``."""
        return f"{self.name}/{PHASE_LABELS.get(Phase(phase), f'phase {int(phase)}')}"

    def _study(self, phase: int) -> int:
        if phase not in self._study_ids:
            sid = self.storage.create_new_study([optuna.study.StudyDirection.MINIMIZE],
                                                self.study_name(phase))
            self.storage.set_study_user_attr(sid, "latentune_run", str(self.dir.resolve()))
            self.storage.set_study_user_attr(sid, "phase", int(phase))
            self._study_ids[phase] = sid
        return self._study_ids[phase]

    def sync(self) -> int:
        """Export the rows and suggestions added since the last call; return how many trials
        were added or completed. StoreError if the store cannot be read."""
        with self._lock:
            with RunStore(self.dir) as st:
                if self._space is None:
                    self._space = config_space(st.get_meta("config") or {})
                    if self._space is None:
                        n = sum(st.count(ph) for ph in Phase) + len(st.trials("pending"))
                        if n == 0:
                            return 0                      # nothing run yet
                        raise StoreError(
                            f"{self.dir} holds {counted(n, 'trial')} but records no parameter "
                            "space (a store of another layout?): no trial's parameters can be "
                            "named, so there is nothing to show")
                space = self._space
                dists = distributions_of(space)
                n = 0
                for ph in Phase:
                    done = self._done.setdefault(int(ph), set())
                    if st.count(ph) <= len(done):
                        continue
                    for r in st.rows(ph):
                        if r.idx not in done:
                            n += self._add_row(int(ph), r, space, dists)
                            done.add(r.idx)
                status = {t.id: t.status for t in st.trials()}
                for sid in [i for i in self._running if status.get(i) == "dropped"]:
                    otid = self._running.pop(sid)         # discarded unseen: it will not be told
                    self.storage.set_trial_user_attr(otid, "status", "dropped")
                    self.storage.set_trial_state_values(otid, optuna.trial.TrialState.FAIL)
                    n += 1
                for t in st.trials("pending"):
                    if t.id in self._running:
                        continue
                    params = physical_params(space, t.theta)
                    ft = optuna.trial.FrozenTrial(
                        number=0, state=optuna.trial.TrialState.RUNNING, value=None,
                        datetime_start=_time(t.created), datetime_complete=None, params=params,
                        distributions=dists, user_attrs={"phase": PHASE_LABELS.get(
                            Phase(t.phase), str(t.phase)), "suggestion": t.id}, system_attrs={},
                        intermediate_values={}, trial_id=0)
                    self._running[t.id] = self.storage.create_new_trial(self._study(t.phase), ft)
                    n += 1
        return n

    def _attrs(self, phase: int, r: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        user: dict[str, Any] = {"phase": PHASE_LABELS.get(Phase(phase), str(phase)),
                                "idx": int(r.idx), "fell": bool(r.fell), "tag": int(r.tag)}
        if r.fall_step is not None:
            user["fall_step"] = int(r.fall_step)
        if r.seed is not None:
            user["seed"] = int(r.seed)
        if r.z is not None:
            user["z"] = [round(float(v), 6) for v in r.z]
        for k, v in (r.info or {}).items():
            if isinstance(v, (str, int, float, bool)) or v is None:
                user[f"info:{k}"] = v
        fall = 1.0 if r.fell else 0.0
        return user, {"constraints:fall": fall, "constraints": [fall]}

    def _add_row(self, phase: int, r: Any, space: ParameterSpace, dists: dict[str, Any]) -> int:
        user, system = self._attrs(phase, r)
        failed = not math.isfinite(r.cost) or abs(r.cost) >= 1e299
        state = optuna.trial.TrialState.FAIL if failed else optuna.trial.TrialState.COMPLETE
        tid = (r.info or {}).get("trial")
        if tid is not None and int(tid) in self._running:       # a told suggestion: complete it
            otid = self._running.pop(int(tid))
            for k, v in user.items():
                self.storage.set_trial_user_attr(otid, k, v)
            for k, v in system.items():
                self.storage.set_trial_system_attr(otid, k, v)
            self.storage.set_trial_state_values(otid, state, None if failed else [float(r.cost)])
            return 1
        wall = float(r.wall_s) if r.wall_s is not None and r.wall_s >= 0 else 0.0
        ft = optuna.trial.FrozenTrial(
            number=0, state=state, value=None if failed else float(r.cost),
            datetime_start=_time(r.created - wall), datetime_complete=_time(r.created),
            params=physical_params(space, r.theta), distributions=dists, user_attrs=user,
            system_attrs=system, intermediate_values={}, trial_id=0)
        self.storage.create_new_trial(self._study(phase), ft)
        return 1


class _Server(ThreadingMixIn, WSGIServer):
    daemon_threads = True


class _QuietHandler(WSGIRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base's name
        logger.debug("dashboard: " + format, *args)


class Dashboard:
    """optuna-dashboard on a live export of a run, served from background threads.

    ``Dashboard(run_dir, port=0, interval=2.0, journal=None)``: ``port=0`` picks a free port;
    :attr:`url` is the address (``http://127.0.0.1:PORT/dashboard``); :meth:`close` stops the
    server and the polling thread. Use as a context manager."""

    def __init__(self, run_dir: str | Path, port: int = 0, interval: float = 2.0,
                 journal: str | Path | None = None) -> None:
        if not interval > 0:
            raise UsageError(f"interval must be > 0, got {interval}")
        storage, jp = None, None if journal is None else Path(journal)
        if jp is not None:
            if jp.exists():
                raise UsageError(f"journal file {jp} exists: give a new file")
            from optuna.storages.journal import JournalFileBackend, JournalStorage

            try:
                storage = JournalStorage(JournalFileBackend(str(jp)))
            except OSError as exc:
                raise UsageError(f"cannot create journal file {jp}: "
                                 f"{exc.strerror or exc}") from None
        try:
            self.export = RunExport(run_dir, storage)
            self.export.sync()
            app = optuna_dashboard.wsgi(self.export.storage)
            try:
                self._server = make_server(HOST, int(port), app, server_class=_Server,
                                           handler_class=_QuietHandler)
            except OSError as exc:
                raise UsageError(f"cannot listen on {HOST}:{port}: "
                                 f"{exc.strerror or exc}") from None
        except BaseException:
            if jp is not None:          # a new file left behind would refuse the next attempt
                jp.unlink(missing_ok=True)
            raise
        self.interval = float(interval)
        self._stop = threading.Event()
        self.port = int(self._server.server_address[1])
        self.url = f"http://{HOST}:{self.port}/dashboard"
        self._poller = threading.Thread(target=self._poll, name="latentune-dashboard-poll",
                                        daemon=True)
        self._serving = threading.Thread(target=self._server.serve_forever,
                                         name="latentune-dashboard", daemon=True)

    def start(self) -> "Dashboard":
        """Start the polling thread and the server thread; return self."""
        self._poller.start()
        self._serving.start()
        return self

    def _poll(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                n = self.export.sync()
                if n:
                    logger.info("dashboard: %d trial(s) exported", n)
            except Exception as exc:  # noqa: BLE001 - a busy or damaged store: try again later
                logger.warning("dashboard: cannot read %s (%s); retrying", self.export.dir, exc)

    def close(self) -> None:
        """Stop serving and polling."""
        self._stop.set()
        if self._serving.is_alive():
            self._server.shutdown()
        self._server.server_close()
        if self._poller.is_alive():
            self._poller.join(timeout=5)

    def __enter__(self) -> "Dashboard":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()


def serve(run_dir: str | Path, port: int = 8080, interval: float = 2.0,
          journal: str | Path | None = None, quiet: bool = False) -> None:
    """Serve ``run_dir`` in optuna-dashboard on 127.0.0.1:``port`` until interrupted."""
    dash = Dashboard(run_dir, port=port, interval=interval, journal=journal).start()
    if not quiet:
        print(f"latentune dashboard: {dash.url} (run {dash.export.dir}; Ctrl-C to stop)",
              flush=True)
    try:
        while dash._serving.is_alive():
            dash._serving.join(timeout=0.5)
    except KeyboardInterrupt:
        pass
    finally:
        dash.close()


__all__ = ["RunExport", "Dashboard", "serve", "PHASE_LABELS", "HOST"]
