"""Phase 1 on a two-node Ray cluster started on this machine, its worker node killed mid-run.

The cluster (:class:`benchmarks.cluster.LocalCluster`): a head and a worker node (one CPU each,
their own temp dirs and free ports), each started with ``ray start --block`` in its own process
group; the fixture's finalizer ends both nodes (:meth:`~benchmarks.cluster.LocalCluster.stop`)
even when the test fails.
``ray stop`` is not used: it ends every Ray process on the machine, other runs' included.

The system is the chain of ``examples/lqr_chain.py`` with a journal (:class:`JournalChain`):
every trial appends ``start``/``end`` lines (its node's process group, its θ) to a file. Once a
``hold`` file exists, a trial that runs on the worker node (its process group is the worker's)
writes ``held`` and waits until it is killed with the node, so the test knows which trial the
kill loses. The run must go on with the head's actor and store every trial once: the lost one
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


class JournalChain(ChainSystem):
    """:class:`~examples.lqr_chain.ChainSystem` (plant gap 0.5) whose trials append ``start
    PGID THETA`` and ``end PGID THETA`` lines to ``journal`` (PGID:
    :func:`~benchmarks.cluster.node_group`, the node's; θ: the unit-box values as a JSON list).
    While the file ``journal + ".hold"`` exists, a trial on the node of group ``hold_pgid``
    writes ``held PGID THETA`` instead and sleeps (until its process is killed)."""

    def __init__(self, journal: str, hold_pgid: int) -> None:
        super().__init__(gap=0.5)
        self.journal = journal
        self.hold_pgid = int(hold_pgid)

    def _log(self, what: str, theta: np.ndarray) -> None:
        line = f"{what} {node_group()} {json.dumps([float(v) for v in theta])}\n"
        fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)

    def evaluate(self, theta: np.ndarray) -> Any:
        if node_group() == self.hold_pgid and os.path.exists(self.journal + ".hold"):
            self._log("held", theta)
            t0 = time.monotonic()
            while time.monotonic() - t0 < HOLD_S:
                time.sleep(0.05)
        else:
            self._log("start", theta)
        out = super().evaluate(theta)
        self._log("end", theta)
        return out


def make_system(journal: str, hold_pgid: int) -> JournalChain:
    """``--system tests.test_ray_cluster:make_system --system-arg journal=… hold_pgid=…``."""
    return JournalChain(journal, hold_pgid)


def _journal(path: Path) -> list[tuple[str, int, tuple[float, ...]]]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        what, pgid, theta = line.split(" ", 2)
        out.append((what, int(pgid), tuple(json.loads(theta))))
    return out


@pytest.fixture
def cluster(cli_env):
    pytest.importorskip("ray")
    pypath = os.pathsep.join(p for p in (str(ROOT), cli_env.get("PYTHONPATH", "")) if p)
    c = LocalCluster(dict(cli_env, PYTHONPATH=pypath, RAY_AUTH_MODE="disabled"))
    try:
        c.start_head()
        c.add_worker("worker")
        yield c
    finally:
        c.stop()


@pytest.mark.slow
def test_worker_node_killed_mid_run(tmp_path, cluster, dump_store):
    out = tmp_path / "run"
    journal = tmp_path / "journal.txt"
    hold = Path(str(journal) + ".hold")
    worker_pgid = cluster.procs["worker"].pid
    log = tmp_path / "cli.log"
    args = ["phase1", "--system", "tests.test_ray_cluster:make_system",
            "--system-arg", f"journal={journal}", "--system-arg", f"hold_pgid={worker_pgid}",
            "--out", str(out), "--phase1-evals", str(BUDGET), "--backend", "ray",
            "--ray-address", cluster.address, "--workers", "2", "--seed", "3"]
    with open(log, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "latentune.cli", *args], cwd=ROOT,
                                env=cluster.env, stdout=f, stderr=subprocess.STDOUT,
                                start_new_session=True)
    try:
        # both nodes have run trials
        wait_for(lambda: stored(out / "run.db") >= KILL_AFTER and worker_pgid in
                 {g for w, g, _ in _journal(journal) if w == "end"}, "the first rows",
                 proc, log)
        hold.touch()
        wait_for(lambda: any(w == "held" for w, _, _ in _journal(journal)),
                 "a held trial on the worker node", proc, log)
        held = next(t for w, _, t in _journal(journal) if w == "held")
        n_at_kill = stored(out / "run.db")
        cluster.kill("worker")
        hold.unlink()
        proc.wait(timeout=900)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = log.read_text()
    assert proc.returncode == 0, text[-3000:]
    assert "a Ray worker was lost" in text, text[-3000:]
    assert n_at_kill < BUDGET                     # the kill was mid-run

    rows = [r for r in dump_store(out)[0] if r[0] == 1]
    assert [r[1] for r in rows] == list(range(BUDGET))      # contiguous, none twice
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
