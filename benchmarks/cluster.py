"""Phase 1 on a two-node Ray cluster started on this machine, its worker node killed mid-run.

    python -m benchmarks.cluster [--trials 400] [--kill-at 0.4] [--rejoin-at 0.7]
        [--steps 6000] [--seed 0] [--out FILE.json]

Starts a head and a worker node (:class:`LocalCluster`: ``ray start --block``, one CPU each,
their own temp dirs and free ports, on 127.0.0.1), runs ``latentune phase1 --backend ray
--ray-address HEAD --workers 2`` on the chain of ``examples/lqr_chain.py`` (:class:`NodeChain`:
plant gap 0.5, ``--steps`` control steps of 20 ms; each trial records the process group of the
node it ran on), SIGKILLs the worker node's process group once ``--kill-at`` of the trials are
stored, and, with ``--rejoin-at``, starts a fresh worker node once that fraction is stored. If
the run stops, it is run again with ``--resume`` (recorded). Reports the trials, the wall time,
when the kill came, the runs lost with the node and the trials re-run, the rows each node ran
before the kill, between and after the rejoin, the final row count and whether any index or θ
is stored twice.

:class:`LocalCluster` is also the cluster of ``tests/test_ray_cluster.py``.
"""
from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from latentune.threads import one_thread_env, thread_env

one_thread_env()

from examples.lqr_chain import STEPS, ChainSystem  # noqa: E402
from latentune.system import Outcome  # noqa: E402
from latentune.pipeline.store import read_uri  # noqa: E402

from benchmarks.common import ROOT, Provenance, add_out_arg, bench_parser, finish  # noqa: E402

logger = logging.getLogger(__name__)

START_ATTEMPTS = 3
"""How many times :class:`LocalCluster` tries to start a node before it gives up."""

LOST_WARNING = "a Ray worker was lost"
"""The start of the warning the Ray evaluator logs for each run lost with its worker."""


def node_group() -> int:
    """The process group of this process's parent: a Ray worker's parent is its node's raylet,
    in the group of the node's ``ray start`` (Ray workers have groups of their own)."""
    return os.getpgid(os.getppid())


class NodeChain(ChainSystem):
    """:class:`~examples.lqr_chain.ChainSystem` whose Outcome's ``info`` also holds
    ``node_pgid`` (:func:`node_group`: which node ran the trial)."""

    def evaluate(self, theta: Any) -> Outcome:
        out = super().evaluate(theta)
        return Outcome(out.cost, out.failed, {**out.info, "node_pgid": node_group()},
                       out.wall_s)


def make_system(gap: float = 0.5, steps: int = STEPS) -> NodeChain:
    """``--system benchmarks.cluster:make_system [--system-arg steps=N gap=G]``."""
    return NodeChain(gap=gap, steps=steps)


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports free on 127.0.0.1 now."""
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def wait_for(cond: Callable[[], Any], what: str, proc: subprocess.Popen | None = None,
             log: Path | None = None, timeout: float = 300.0) -> None:
    """Poll ``cond()`` every 50 ms until it is true; RuntimeError naming ``what`` (with the tail
    of ``log``) if ``proc`` ends first or after ``timeout`` seconds (a hang guard)."""
    t0 = time.monotonic()
    while not cond():
        tail = log.read_text(errors="replace")[-3000:] if log and log.exists() else ""
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"{what}: the process ended ({proc.returncode}): {tail}")
        if time.monotonic() - t0 > timeout:
            raise RuntimeError(f"{what}: not within {timeout:.0f} s: {tail}")
        time.sleep(0.05)


class LocalCluster:
    """Ray nodes on 127.0.0.1 (one CPU each), each a ``ray start --block`` in a process group
    of its own, with its own temp dir under one short directory (Ray's unix socket paths must
    stay under 107 bytes) and free ports. ``address`` is the head's ``127.0.0.1:PORT``.
    :meth:`kill` SIGKILLs one node's group (its raylet and workers: the node is lost);
    :meth:`stop` ends the nodes it started (SIGINT to each ``ray start``, which then stops its
    node as Ctrl-C does, then SIGKILL to whatever of its group is left) and removes the temp
    dirs, never any other Ray process of the machine (``ray stop`` would end them all)."""

    def __init__(self, env: dict[str, str] | None = None, timeout: float = 300.0) -> None:
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("RAY_AUTH_MODE", "disabled")
        self.timeout = timeout
        self.dir = Path(tempfile.mkdtemp(prefix="ltc", dir="/tmp"))
        self.procs: dict[str, subprocess.Popen] = {}
        self.port = free_ports(1)[0]
        self.address = f"127.0.0.1:{self.port}"

    def _start(self, name: str, args: list[str]) -> subprocess.Popen:
        """``ray start --block`` node ``name`` with ``args``; wait until it reports started.
        Ray gives a new node's raylet a fixed 30 s to register with the GCS; on a loaded
        machine that can run out, and ``ray start`` then ends. Such a start is retried (up to
        ``START_ATTEMPTS`` in all, each in a temp dir of its own after the failed one's group
        is killed); a start that fails every time, or hangs past ``timeout``, raises the
        RuntimeError of :func:`wait_for`."""
        for attempt in range(1, START_ATTEMPTS + 1):
            try:
                return self._start_once(name, args, attempt)
            except RuntimeError as e:
                proc = self.procs.pop(name)
                ended = proc.poll() is not None   # not the hang guard's timeout
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(timeout=60)
                if attempt == START_ATTEMPTS or not ended:
                    raise
                logger.warning("ray start (%s) failed on attempt %d of %d; retrying: %s",
                               name, attempt, START_ATTEMPTS, str(e).splitlines()[0])
        raise AssertionError("unreachable")

    def _start_once(self, name: str, args: list[str], attempt: int) -> subprocess.Popen:
        ray = shutil.which("ray", path=os.path.dirname(sys.executable)) or "ray"
        ports = free_ports(4)
        tag = name if attempt == 1 else f"{name}-{attempt}"
        log = self.dir / f"{tag}.log"
        cmd = [ray, "start", "--block", *args, "--node-ip-address=127.0.0.1", "--num-cpus=1",
               f"--temp-dir={self.dir / tag}", "--disable-usage-stats",
               f"--dashboard-agent-listen-port={ports[0]}",
               f"--dashboard-agent-grpc-port={ports[1]}", f"--metrics-export-port={ports[2]}",
               f"--runtime-env-agent-port={ports[3]}"]
        with open(log, "wb") as f:
            proc = subprocess.Popen(cmd, env=self.env, stdout=f, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        self.procs[name] = proc
        wait_for(lambda: b"Ray runtime started" in log.read_bytes(), f"ray start ({name})",
                 proc, log, self.timeout)
        return proc

    def start_head(self) -> None:
        """The head node (GCS on ``self.port``, no dashboard)."""
        self._start("head", ["--head", f"--port={self.port}", "--include-dashboard=false",
                             f"--dashboard-port={free_ports(1)[0]}"])

    def add_worker(self, name: str) -> None:
        """A worker node joining the head."""
        self._start(name, [f"--address={self.address}"])

    def pgid(self, name: str) -> int:
        """The process group of node ``name`` (the pid of its ``ray start``)."""
        return self.procs[name].pid

    def kill(self, name: str) -> None:
        """SIGKILL node ``name``'s process group and reap its ``ray start``."""
        proc = self.procs[name]
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=60)

    def stop(self) -> None:
        """End every node started (``ray start --block`` ignores SIGTERM: a SIGTERM only ran
        out a 10-s wait before the SIGKILL; SIGINT ends it and its node within seconds)."""
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    pass
            try:
                os.killpg(proc.pid, signal.SIGKILL)   # whatever of the group is left
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> "LocalCluster":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def stored(db: Path) -> int:
    """Phase-1 rows in the store ``db`` (read-only; 0 while it does not exist)."""
    try:
        con = sqlite3.connect(read_uri(db), uri=True, timeout=5)
        try:
            return con.execute("SELECT COUNT(*) FROM evaluations WHERE phase=1").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def main(argv: list[str] | None = None) -> int:
    prov = Provenance(argv, "benchmarks.cluster")
    ap = bench_parser("benchmarks.cluster", description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=400)
    ap.add_argument("--kill-at", type=float, default=0.4,
                    help="kill the worker node when this fraction of the trials is stored")
    ap.add_argument("--rejoin-at", type=float, default=0.7,
                    help="start a fresh worker node at this fraction (<= 0: never)")
    ap.add_argument("--steps", type=int, default=6000, help="control steps of a trial (20 ms)")
    ap.add_argument("--seed", type=int, default=0)
    add_out_arg(ap)
    a = ap.parse_args(argv)
    from latentune.pipeline.store import RunStore

    pypath = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    env = dict(os.environ, **thread_env(), RAY_AUTH_MODE="disabled", PYTHONPATH=pypath)
    work = Path(tempfile.mkdtemp(prefix="lt_cluster_"))
    out = work / "run"
    db = out / "run.db"
    log = work / "cli.log"
    cmd = [sys.executable, "-m", "latentune.cli", "phase1", "--system",
           "benchmarks.cluster:make_system", "--system-arg", f"steps={a.steps}",
           "--out", str(out), "--phase1-evals", str(a.trials), "--backend", "ray",
           "--workers", "2", "--seed", str(a.seed)]
    kill_n = math.ceil(a.kill_at * a.trials)
    rejoin_n = math.ceil(a.rejoin_at * a.trials) if a.rejoin_at > 0 else None
    kill: dict[str, Any] | None = None
    rejoin: dict[str, Any] | None = None
    with LocalCluster(env) as cl:
        t_start = time.monotonic()
        cl.start_head()
        cl.add_worker("worker")
        t_cluster = time.monotonic() - t_start
        cmd += ["--ray-address", cl.address]
        t0, w0 = time.monotonic(), time.time()
        with open(log, "wb") as f:
            proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=f, stderr=subprocess.STDOUT,
                                    start_new_session=True)
            while proc.poll() is None:
                n = stored(db)
                if kill is None and n >= kill_n:
                    cl.kill("worker")
                    kill = {"after_s": time.monotonic() - t0, "rows": n, "epoch": time.time()}
                    print(f"killed the worker node at {n} rows", file=sys.stderr, flush=True)
                elif kill is not None and rejoin is None and rejoin_n is not None \
                        and n >= rejoin_n:
                    cl.add_worker("worker2")
                    rejoin = {"after_s": time.monotonic() - t0, "rows": n,
                              "epoch": time.time()}
                    print(f"a fresh worker node joined at {n} rows", file=sys.stderr,
                          flush=True)
                time.sleep(0.1)
            first_rc = proc.returncode
            resumed = first_rc != 0
            final_rc = first_rc
            if resumed:                           # it stopped: resume once, as a user would
                final_rc = subprocess.run([*cmd, "--resume"], cwd=ROOT, env=env, stdout=f,
                                          stderr=subprocess.STDOUT).returncode
        wall = time.monotonic() - t0
        names = {cl.pgid(n): n for n in cl.procs}
    text = log.read_text(errors="replace")
    store = RunStore(out)
    try:
        rows = store.rows(1)
    finally:
        store.close()
    idx = [r.idx for r in rows]
    thetas = {r.theta.tobytes() for r in rows}
    lost_rows = [r for r in rows if r.info.get("lost_runs")]
    k_epoch = kill["epoch"] if kill else math.inf
    r_epoch = rejoin["epoch"] if rejoin else math.inf
    segments = [("before the kill", w0, k_epoch), ("after the kill", k_epoch, r_epoch),
                ("after the rejoin", r_epoch, math.inf)]
    table = []
    for label, lo, hi in segments:
        seg = [r for r in rows if lo <= r.created < hi]
        if not seg:
            continue
        lo = max(lo, min(r.created for r in seg) if lo == w0 else lo)   # from the first row
        end = min(hi, max(r.created for r in seg))
        per_node: dict[str, int] = {}
        for r in seg:
            node = "driver" if r.info.get("reused") else names.get(r.info.get("node_pgid"),
                                                                    "other")
            per_node[node] = per_node.get(node, 0) + 1
        table.append({"segment": label, "rows": len(seg),
                      "rows_per_s": len(seg) / max(end - lo, 1e-9),
                      **{f"on_{k}": v for k, v in sorted(per_node.items())}})
    results = {
        "system": f"examples.lqr_chain (gap 0.5, {a.steps} steps) as benchmarks.cluster:"
                  "make_system", "trials": a.trials, "seed": a.seed,
        "cli_command": "python " + " ".join(cmd[1:]), "cluster": "head + 1 worker node, 1 CPU each, "
        "127.0.0.1, ray start --block", "cluster_start_s": t_cluster, "wall_s": wall,
        "kill": kill and {k: v for k, v in kill.items() if k != "epoch"},
        "rejoin": rejoin and {k: v for k, v in rejoin.items() if k != "epoch"},
        "lost_warnings": text.count(LOST_WARNING),
        "rerun_trials": [{"idx": r.idx, "lost_runs": r.info["lost_runs"], "fell": r.fell,
                          "stored_s_after_kill": r.created - k_epoch} for r in lost_rows],
        "rows": len(rows), "indices_contiguous": idx == list(range(len(rows))),
        "distinct_theta": len(thetas), "resumed": resumed, "exit_codes": [first_rc] +
        ([final_rc] if resumed else []), "segments": table,
    }
    shutil.rmtree(work, ignore_errors=True)
    columns = ["segment", "rows", "rows_per_s"] + sorted({k for r in table for k in r
                                                         if k.startswith("on_")})
    finish(a.out, prov, results, table, columns, title=f"phase 1, {a.trials} trials on two Ray nodes, "
           f"the worker killed at {kill['rows'] if kill else '–'} rows; {len(rows)} stored, "
           f"{len(lost_rows)} re-run, resumed: {'yes' if resumed else 'no'}")
    return 0 if final_rc == 0 and len(rows) == a.trials else 1


if __name__ == "__main__":
    from benchmarks.common import cli_main

    sys.exit(cli_main(main, "benchmarks.cluster"))
