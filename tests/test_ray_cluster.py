"""Phase 1 on a two-node Ray cluster started on this machine, its worker node killed mid-run,
then its head node (one line, exit 2, the store resumed by the command the line names).

The cluster (:class:`benchmarks.cluster.LocalCluster`): a head and a worker node (one CPU each,
their own temp dirs and free ports), each started with ``ray start --block`` in its own process
group. A module fixture starts the head; a test gets a running head and worker node (one an
earlier test killed is started again), and the module's finalizer ends the nodes
(:meth:`~benchmarks.cluster.LocalCluster.stop`) even when a test fails.
``ray stop`` is not used: it ends every Ray process on the machine, other runs' included.

The system is the chain of ``examples/lqr_chain.py`` with a journal (:class:`JournalChain`):
every trial appends ``start``/``end`` lines (its node's process group, its θ) to a file. Once a
``hold`` file names a node's process group, a trial that runs on that node writes ``held`` and
waits until it is killed with the node, so the test knows which trial the kill loses. The run must go on with the head's actor and store every trial once: the lost one
re-run (its row says ``lost_runs``: 1, its cost is the system's own for that θ), none recorded
as a failure, none twice, the phase's indices contiguous.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
import shlex
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:           # ``examples``, ``benchmarks``: from the repository root
    sys.path.insert(0, str(ROOT))

from benchmarks.cluster import LocalCluster, node_group, stored, wait_for  # noqa: E402
from examples.lqr_chain import ChainSystem  # noqa: E402

HOLD_S = 600.0          # a held trial waits at most this long for its node to be killed
BUDGET = 24
KILL_AFTER = 6          # rows stored before the hold starts
RAY_RECONNECT_S = 12    # the head-loss test's Ray ends its driver 12 s after losing the head


class JournalChain(ChainSystem):
    """:class:`~examples.lqr_chain.ChainSystem` (plant gap 0.5) whose trials append ``start
    PGID THETA`` and ``end PGID THETA`` lines to ``journal`` (PGID:
    :func:`~benchmarks.cluster.node_group`, the node's; θ: the unit-box values as a JSON list).
    While the file ``journal + ".hold"`` exists, a trial on the node whose process group the
    file names writes ``held PGID THETA`` instead and sleeps (until its process is killed)."""

    def __init__(self, journal: str) -> None:
        super().__init__(gap=0.5)
        self.journal = journal

    def _held_here(self) -> bool:
        try:
            with open(self.journal + ".hold") as f:
                return f.read().strip() == str(node_group())
        except OSError:
            return False

    def _log(self, what: str, theta: np.ndarray) -> None:
        line = f"{what} {node_group()} {json.dumps([float(v) for v in theta])}\n"
        fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)

    def evaluate(self, theta: np.ndarray) -> Any:
        if self._held_here():
            self._log("held", theta)
            t0 = time.monotonic()
            while time.monotonic() - t0 < HOLD_S:
                time.sleep(0.05)
        else:
            self._log("start", theta)
        out = super().evaluate(theta)
        self._log("end", theta)
        return out


def make_system(journal: str) -> JournalChain:
    """``--system tests.test_ray_cluster:make_system --system-arg journal=…``."""
    return JournalChain(journal)


def _journal(path: Path) -> list[tuple[str, int, tuple[float, ...]]]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        what, pgid, theta = line.split(" ", 2)
        out.append((what, int(pgid), tuple(json.loads(theta))))
    return out


@pytest.fixture(scope="module")
def nodes(cli_env):
    """The module's cluster (its head started once); stopped after the module's tests."""
    pytest.importorskip("ray")
    pypath = os.pathsep.join(p for p in (str(ROOT), cli_env.get("PYTHONPATH", "")) if p)
    c = LocalCluster(dict(cli_env, PYTHONPATH=pypath, RAY_AUTH_MODE="disabled"))
    try:
        c.start_head()
        yield c
    finally:
        c.stop()


@pytest.fixture
def cluster(nodes):
    """The module's cluster with a head and a worker node ``worker`` running: the head started
    again if an earlier test killed it, a new worker node if the earlier one was killed."""
    def down(name: str) -> bool:
        return name not in nodes.procs or nodes.procs[name].poll() is not None

    if down("head"):
        nodes.start_head()
    if down("worker"):
        nodes.add_worker("worker")
    return nodes


def _phase1(tmp_path: Path, cluster: LocalCluster, log: Path, env: dict[str, str] | None = None,
            **popen: Any) -> tuple[subprocess.Popen, Path, Path]:
    """Start ``latentune phase1`` (BUDGET trials of :class:`JournalChain`) on ``cluster`` (its
    environment with ``env`` added), its output to ``log``; return the process, the run
    directory and the journal."""
    out, journal = tmp_path / "run", tmp_path / "journal.txt"
    args = ["phase1", "--system", "tests.test_ray_cluster:make_system",
            "--system-arg", f"journal={journal}",
            "--out", str(out), "--phase1-evals", str(BUDGET), "--backend", "ray",
            "--ray-address", cluster.address, "--workers", "2", "--seed", "3"]
    with open(log, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "latentune.cli", *args], cwd=ROOT,
                                env={**cluster.env, **(env or {})}, stdout=f,
                                start_new_session=True,
                                **{"stderr": subprocess.STDOUT, **popen})
    return proc, out, journal


@pytest.mark.slow
def test_worker_node_then_head_node_killed_mid_run(tmp_path, cluster, dump_store):
    """One phase-1 command loses its worker node, then its head node.

    The worker node is killed while a trial is held on it: the run goes on with the head's
    actor, the held trial is re-run once on the head (its row says ``lost_runs``: 1, its result
    is the system's own). Then the head node (the GCS the run is connected to) is killed while
    a trial is held on it: the command ends with exit status 2 and one line more on stderr
    (what happened, that the stored trials are safe, the command that resumes) before Ray
    would end it silently (exit 1 after 60 s; here RAY_RECONNECT_S, set through Ray's own
    variable, which shortens latentune's head timeout to a quarter of it); the store is intact,
    and that command, once a head is back on the address, completes the phase: every index
    once, no θ twice, the worker's lost trial the only one re-run."""
    from latentune.pipeline.evaluators import RAY_RECONNECT_VAR

    log, err_log = tmp_path / "cli.log", tmp_path / "cli.err"
    worker_pgid, head_pgid = cluster.pgid("worker"), cluster.pgid("head")
    with open(err_log, "wb") as err:
        proc, out, journal = _phase1(tmp_path, cluster, log, stderr=err,
                                     env={RAY_RECONNECT_VAR: str(RAY_RECONNECT_S)})
    hold = Path(str(journal) + ".hold")
    try:
        # both nodes have run trials
        wait_for(lambda: stored(out / "run.db") >= KILL_AFTER and worker_pgid in
                 {g for w, g, _ in _journal(journal) if w == "end"}, "the first rows",
                 proc, err_log)
        hold.write_text(str(worker_pgid))
        wait_for(lambda: any(w == "held" for w, _, _ in _journal(journal)),
                 "a held trial on the worker node", proc, err_log)
        held = next(t for w, _, t in _journal(journal) if w == "held")
        n_at_kill = stored(out / "run.db")
        cluster.kill("worker")
        hold.unlink()
        # the held θ re-run on the head and stored, then a row more
        wait_for(lambda: any(w == "end" and g == head_pgid and t == held
                             for w, g, t in _journal(journal))
                 and stored(out / "run.db") >= n_at_kill + 2, "the lost trial re-run",
                 proc, err_log)
        hold.write_text(str(head_pgid))  # the run cannot finish: a trial waits on the head
        wait_for(lambda: any(w == "held" and g == head_pgid for w, g, _ in _journal(journal)),
                 "a held trial on the head node", proc, err_log)
        before_head_kill = err_log.read_text()
        t0 = time.monotonic()
        cluster.kill("head")
        proc.wait(timeout=120)           # Ray alone: exit 1 after RAY_RECONNECT_S, no line of ours
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        if hold.exists():
            hold.unlink()
    err = err_log.read_text()
    assert proc.returncode == 2, err[-3000:]
    assert "a Ray worker was lost" in before_head_kill, err[-3000:]
    assert "latentune: error" not in before_head_kill, before_head_kill[-3000:]
    assert n_at_kill < BUDGET                     # the worker kill was mid-run
    assert err.startswith(before_head_kill), err[-3000:]
    lines = err[len(before_head_kill):].splitlines()
    assert len(lines) == 1 and lines[0].startswith("latentune: error: the Ray cluster's head "
                                                   f"at {cluster.address} stopped answering"), err
    assert f"the trials stored in {out} are safe" in lines[0], lines[0]
    assert took < RAY_RECONNECT_S, took
    kept = [r for r in dump_store(out)[0] if r[0] == 1]
    n = len(kept)
    assert n_at_kill + 2 <= n < BUDGET and f"({n} evaluations of phase 1 stored)" in lines[0], \
        lines[0]
    assert [r[1] for r in kept] == list(range(n))

    resume = shlex.split(lines[0].split("`")[1])
    assert resume[0] == "latentune" and resume[-1] == "--resume", resume
    cluster.start_head()                 # a head is back on the address (no worker node)
    p = subprocess.run([sys.executable, "-m", "latentune.cli", *resume[1:]], cwd=ROOT,
                       env=cluster.env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    rows = [r for r in dump_store(out)[0] if r[0] == 1]
    assert rows[:n] == kept                                  # everything stored is kept
    assert [r[1] for r in rows] == list(range(BUDGET))       # contiguous, none twice
    assert len({r[2] for r in rows}) == BUDGET               # no θ stored twice

    from latentune.pipeline.store import RunStore

    store = RunStore(out)
    try:
        phase1 = store.rows(1)
    finally:
        store.close()
    system = ChainSystem(gap=0.5)
    rerun = [r for r in phase1 if r.info.get("lost_runs")]
    assert [r.info["lost_runs"] for r in rerun] == [1], rerun     # only the held trial
    held = np.array(held)
    np.testing.assert_array_equal(rerun[0].theta, held)
    again = system.evaluate(held)            # its stored result is the system's own
    assert rerun[0].fell == again.failed
    if again.cost is not None:
        assert rerun[0].cost == pytest.approx(again.cost, rel=1e-9)
    # the journal: the held θ was lost on the worker node, then run once on the head
    entries = [(w, g) for w, g, t in _journal(journal) if np.array_equal(t, held)]
    assert entries.count(("held", worker_pgid)) == 1
    assert [w for w, g in entries if g != worker_pgid] == ["start", "end"]


def _scripted_starts(monkeypatch, cluster: LocalCluster, fails: int) -> list[subprocess.Popen]:
    """Replace ``_start_once`` so that its first ``fails`` attempts start a process that ends
    at once (as ``ray start`` does when its raylet misses the GCS's 30-s window) and the next
    one a process that stays up; return the processes started."""
    started: list[subprocess.Popen] = []

    def start_once(name: str, args: list[str], attempt: int) -> subprocess.Popen:
        cmd = ["sh", "-c", "exit 1"] if attempt <= fails else ["sleep", "60"]
        proc = subprocess.Popen(cmd, start_new_session=True)
        started.append(proc)
        cluster.procs[name] = proc
        wait_for(lambda: False if attempt <= fails else True, f"ray start ({name})", proc)
        return proc

    monkeypatch.setattr(cluster, "_start_once", start_once)
    return started


def test_a_node_whose_start_fails_is_started_again(monkeypatch):
    from benchmarks.cluster import START_ATTEMPTS

    with LocalCluster(env={}) as c:
        started = _scripted_starts(monkeypatch, c, fails=START_ATTEMPTS - 1)
        c.add_worker("worker")
        assert len(started) == START_ATTEMPTS
        assert c.procs["worker"] is started[-1] and started[-1].poll() is None
        assert all(p.returncode == 1 for p in started[:-1])    # the failed ones were reaped
    assert started[-1].poll() is not None                     # stop() ended the last one


def test_a_node_that_never_starts_raises(monkeypatch):
    from benchmarks.cluster import START_ATTEMPTS

    with LocalCluster(env={}) as c:
        started = _scripted_starts(monkeypatch, c, fails=START_ATTEMPTS)
        with pytest.raises(RuntimeError, match=r"ray start \(worker\): the process ended"):
            c.add_worker("worker")
        assert len(started) == START_ATTEMPTS and "worker" not in c.procs
