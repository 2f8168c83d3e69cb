"""Evaluators (latentune.pipeline.evaluators): a process pool gives the serial costs, every
backend stores the same rows when a trial raises, a run killed with its workers resumes without
losing or repeating a trial, phase 1 on a local Ray, a Ray worker lost mid-trial (the trial is
run again, once), an unreachable Ray address (one line). A worker *node* lost mid-run:
tests/test_ray_cluster.py.

The tests of Ray evaluators in this process share one local Ray (conftest's ``ray_local``); the
command line's phase 1 on Ray starts its own, in its process."""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.constants import C1
from latentune.pipeline.store import RunStore
from latentune.system import EvaluationError

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:           # ``benchmarks``: from the repository root
    sys.path.insert(0, str(ROOT))

from benchmarks.cluster import stored  # noqa: E402

TINY = ["--robot", "a1", "--task", "trot", "--steps", "200", "--quiet"]


def quad(x: np.ndarray) -> float:
    return float(np.sum((np.asarray(x) - 0.3) ** 2) * 100)


def test_process_evaluator_matches_serial():
    from latentune.pipeline.evaluators import ProcessEvaluator, SerialEvaluator
    from latentune.task import Task

    task = Task("a1", "trot", steps=100)
    X = np.vstack([task.space.manual, np.random.default_rng(1).random((3, task.space.dim))])
    ys = SerialEvaluator().map(task, X)
    with ProcessEvaluator(2) as ev:
        yp = ev.map(task, X)
        yq = ev.map(quad, X[:, :6])
    np.testing.assert_allclose(ys, yp)
    np.testing.assert_allclose(yq, [quad(x) for x in X[:, :6]])


def _logs(x):
    import logging

    logging.getLogger("latentune.test_worker").warning("said in a worker")
    logging.getLogger("latentune.test_worker").info("an informational line")
    return quad(x)


def test_process_workers_log_through_the_caller_once_at_its_level(capfd, caplog):
    """A worker's log lines reach the caller's ``latentune`` loggers (its CLI format and
    --quiet/-v level), once for all workers, not as bare lines on the workers' stderr."""
    import logging

    from latentune.pipeline.evaluators import ProcessEvaluator

    with caplog.at_level(logging.WARNING, logger="latentune"):
        with ProcessEvaluator(2) as ev:
            ev.map(_logs, np.random.default_rng(0).random((4, 3)))
    said = [r for r in caplog.records if r.name == "latentune.test_worker"]
    assert [(r.levelname, r.getMessage()) for r in said] == [("WARNING", "said in a worker")]
    assert "said in a worker" not in capfd.readouterr().err


class LockInInfo:
    """A system whose Outcome carries a lock in its info (cannot be pickled)."""
    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])

    def evaluate(self, u):
        import threading

        return lt.Outcome(quad(u), info={"lock": threading.Lock(), "k": 1})


def test_process_worker_sends_back_an_outcome_whose_info_cannot_be_pickled():
    """The info is kept as the store records it (as on the serial backend), not a
    pickling traceback from concurrent.futures."""
    from latentune.pipeline.evaluators import ProcessEvaluator

    X = np.random.default_rng(0).random((3, 3))
    with ProcessEvaluator(2) as ev:
        got = dict(ev.imap(LockInInfo(), X))
    assert sorted(got) == [0, 1, 2]
    for i, out in got.items():
        assert isinstance(out, lt.Outcome) and out.cost == pytest.approx(quad(X[i]))
        assert out.info["k"] == 1 and "lock" in out.info["lock"]


def test_a_script_without_the_main_guard_is_told_what_killed_its_workers(tmp_path, cli_env):
    """A script that runs ``Study(..., workers=2, backend="process").phase1`` at its top level
    (the README's Python API needs the ``__main__`` guard for it) ended with "the process
    pool's workers died 3 times before running a trial" and nothing on why: each worker runs
    the script again while it starts. The error now names the guard. Found running the README's
    Python API with the process pool."""
    script = tmp_path / "noguard.py"
    script.write_text(
        "import latentune as lt\n"
        "def f(x):\n    return float(x.sum())\n"
        "space = lt.ParameterSpace(names=['a', 'b'], low=[0, 0], high=[1, 1])\n"
        f"study = lt.Study({str(tmp_path / 'run')!r}, seed=0, workers=2, backend='process')\n"
        "study.phase1(lt.FunctionSystem(space, f), 4)\n")
    env = {**cli_env, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.run([sys.executable, str(script)], env=env, capture_output=True,
                          text=True, timeout=300, cwd=tmp_path)
    line = next((ln for ln in proc.stderr.splitlines()
                 if ln.startswith("latentune.system.EvaluationError")), proc.stderr)
    assert proc.returncode != 0 and "died 3 times before running a trial" in line, proc.stderr
    assert 'if __name__ == "__main__":' in line, line


def test_unreachable_ray_address_is_one_line(tmp_path, run_cli, error_line, no_local_ray):
    """A cluster address nobody answers at: one line at once (Ray alone retries without end),
    and no run directory left behind (it recorded the seed and system of a run that never
    started: the same command with another seed was refused)."""
    pytest.importorskip("ray")
    import socket

    with socket.socket() as s:                       # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "4",
                           "--backend", "ray", "--ray-address", f"127.0.0.1:{port}",
                           "--seed", "1")
    assert f"no Ray cluster answers at 127.0.0.1:{port}" in error_line(code, err)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("greeting", [b"", b"SSH-2.0-OpenSSH_9.6\r\n"])
def test_a_ray_address_that_is_no_ray_head_is_one_line(tmp_path, run_cli, error_line,
                                                      no_local_ray, monkeypatch, greeting):
    """An address where something answers but no Ray head (a port of another service, one
    that says nothing or greets in its own protocol): Ray's connect retried it, without end
    when it bound 127.0.0.1 only (Ray dials the machine's own address instead: 10 minutes of
    'Failed to connect to GCS' lines, and SIGTERM did not end it). A gRPC handshake (HTTP/2
    SETTINGS, which Ray's head sends at once) is now asked for first: none within seconds is
    one line naming the address, before Ray is called."""
    pytest.importorskip("ray")
    import ray

    def no_init(*a: object, **k: object) -> None:
        raise AssertionError("ray.init was called")

    monkeypatch.setattr(ray, "init", no_init)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    held: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                held.append(conn)
                conn.sendall(greeting)

    threading.Thread(target=serve, daemon=True).start()
    t0 = time.monotonic()
    try:
        code, _, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "4",
                               "--backend", "ray", "--ray-address", f"127.0.0.1:{port}")
    finally:
        server.close()
        for c in held:
            c.close()
    assert time.monotonic() - t0 < 10
    assert f": 127.0.0.1:{port} answers, but not as a Ray cluster's head (" in error_line(code, err)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("address", ["", "  "])
def test_an_empty_ray_address_is_refused(tmp_path, run_cli, error_line, address):
    """`--ray-address "$HEAD"` with $HEAD unset ran the phase on a local Ray (an empty address
    read as none given), not the cluster, without a word. It is refused, naming the flag."""
    code, out, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "2",
                             "--backend", "ray", "--ray-address", address)
    assert error_line(code, err).startswith("latentune: error: --ray-address is empty: give ")
    assert out == "" and not (tmp_path / "r").exists()


@pytest.mark.parametrize("port", ["0", "65536", "99999"])
def test_a_ray_address_port_out_of_range_is_refused(tmp_path, run_cli, error_line, port):
    """`--ray-address 127.0.0.1:99999` said 'no Ray cluster answers at 127.0.0.1:99999
    (Connection refused)': the port was taken modulo 65536 (34463 was dialled). A port outside
    1..65535 is refused as such, before anything is dialled."""
    pytest.importorskip("ray")
    code, _, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "2",
                           "--backend", "ray", "--ray-address", f"127.0.0.1:{port}")
    assert error_line(code, err).endswith(
        f"127.0.0.1:{port}: the port must be 1 to 65535, got {port}")
    assert not (tmp_path / "r").exists()


def test_ray_address_from_the_environment_is_the_cluster(tmp_path, run_cli, error_line,
                                                        no_local_ray, monkeypatch):
    """``$RAY_ADDRESS`` (Ray's own default address) without --ray-address: the ray backend
    connects there, checked like --ray-address. It passed num_cpus for a local Ray and Ray
    refused: 'When connecting to an existing cluster, num_cpus and num_gpus must not be
    provided', whether a cluster answered there or not."""
    pytest.importorskip("ray")

    with socket.socket() as s:                       # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    code, _, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "4",
                           "--backend", "ray")
    assert f"no Ray cluster answers at 127.0.0.1:{port} (" in error_line(code, err)
    assert not (tmp_path / "r").exists()


class ExitingSystem:
    """A trial that calls sys.exit (a script's habit): the command ended with its status and
    no word, on every backend (a worker's SystemExit was re-raised in the caller)."""
    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])

    def evaluate(self, u):
        if u[0] > 0.5:
            sys.exit(3)
        return quad(u)


def test_a_trial_that_calls_sys_exit_is_a_trial_error_on_every_backend():
    from latentune.pipeline.evaluators import ProcessEvaluator, SerialEvaluator, TrialError

    X = np.array([[0.1, 0.2, 0.3], [0.9, 0.2, 0.3]])
    with ProcessEvaluator(2) as pool:
        for ev in (SerialEvaluator(), pool):
            got = dict(ev.imap(ExitingSystem(), X))
            assert got[0].cost == pytest.approx(quad(X[0]))
            assert isinstance(got[1], TrialError) and "raised SystemExit: 3" in got[1].message
    got = dict(SerialEvaluator().imap(lambda x: sys.exit("bye") if x[0] > 0.5 else 1.0, X))
    assert isinstance(got[1], TrialError) and "raised SystemExit: bye" in got[1].message


def _raises_sometimes(x):
    if x[0] > 0.6:
        raise RuntimeError("boom")
    return float(np.sum(x))


class RaisingSystem:
    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])

    def evaluate(self, u):
        return _raises_sometimes(u)


def test_every_backend_stores_the_same_rows_when_a_trial_raises(tmp_path, ray_local):
    from latentune.pipeline.evaluators import make_evaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase

    import ray.cloudpickle

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])   # workers lack tests/
    by_backend = {}
    for backend in ("serial", "process", "ray"):
        ev = make_evaluator(backend, 2)
        try:
            with RunStore(tmp_path / backend, create=True) as st:
                with pytest.raises(EvaluationError, match="RuntimeError: boom"):
                    run_phase(st, 1, RaisingSystem(), make_phase_critic("sobol", 3, 4, 0, None, 40),
                              40, ev)
                by_backend[backend] = [(r.idx, tuple(r.theta), r.cost) for r in st.rows(1)]
        finally:
            ev.close()
    assert by_backend["serial"], "the first batch should finish before a trial raises"
    key = lambda rows: sorted(r[1:] for r in rows)  # noqa: E731 - completion order may differ
    assert key(by_backend["serial"]) == key(by_backend["process"]) == key(by_backend["ray"])


def test_crash_and_resume(tmp_path, run_cli, cli_env, dump_store):
    """SIGKILL of the CLI and its worker processes mid-run (needs real processes), then resume
    (in this process)."""
    out = tmp_path / "crash"
    n, n_kill = 12, 4
    args = ["phase1", *TINY, "--out", str(out), "--phase1-evals", str(n), "--workers", "2"]
    proc = subprocess.Popen([sys.executable, "-m", "latentune.cli", *args], env=cli_env,
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    t0 = time.monotonic()
    while stored(out / "run.db") < n_kill:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() - t0 < 600, "no trials stored after 600 s"     # a hang guard
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)                   # the CLI and its workers
    proc.wait()
    kept = dump_store(out)[0]
    n_stored = len([r for r in kept if r[0] == 1])
    assert n_kill <= n_stored < n
    code, _, err = run_cli(*args, "--resume")
    assert code == 0, err
    rows = [r for r in dump_store(out)[0] if r[0] == 1]
    assert [r[1] for r in rows] == list(range(n))           # contiguous, none duplicated
    assert rows[:n_stored] == [r for r in kept if r[0] == 1]  # everything stored is kept
    assert len({r[2] for r in rows}) == n                    # no θ evaluated twice


_SLOW_PLUGIN = """
import time
import latentune as lt


def make():
    def fn(x):
        time.sleep(0.2 if x[0] <= 0.5 else 60)      # trials with x0 > 0.5 hang
        return float(x.sum())
    return lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [1, 1], manual=[0.2, 0.2]),
                             fn, name="slow")
"""


def test_sigterm_stops_a_run_as_ctrl_c_does(tmp_path, cli_env, run_cli):
    """SIGTERM (kill, docker stop, a batch system's limit) while a trial hangs in a worker:
    one line and status 143 at once, no worker left (it ended the process with the pool's
    semaphore warnings on stderr, Ray's crash dump on the Ray backend); a resume goes on."""
    (tmp_path / "slowplug.py").write_text(_SLOW_PLUGIN)
    env = {**cli_env, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(tmp_path)])}
    args = ["phase1", "--system", "slowplug:make", "--out", str(tmp_path / "r"),
            "--phase1-evals", "8", "--workers", "2", "--quiet"]
    proc = subprocess.Popen([sys.executable, "-m", "latentune.cli", *args], env=env,
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    t0 = time.monotonic()
    while stored(tmp_path / "r" / "run.db") < 1 and time.monotonic() - t0 < 120:
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, err
    assert err.strip() == "latentune: error: terminated (SIGTERM); stored results are kept"


def _hangs_above_half(x):
    if x[0] > 0.5:
        time.sleep(30)                      # a trial that hangs (or runs long)
    return float(x[0])


def test_process_pool_close_does_not_wait_for_a_trial_that_was_left():
    """An imap left while a trial runs (Ctrl-C, an error): close terminates its worker
    instead of waiting for it (a SIGINT to the CLI during a hung trial hung it for ever)."""
    from latentune.pipeline.evaluators import ProcessEvaluator

    ev = ProcessEvaluator(2)
    try:
        it = ev.imap(_hangs_above_half, np.array([[0.0], [1.0]]))
        i, out = next(it)                   # the quick trial
        assert i == 0 and out.cost == 0.0
        it.close()
    finally:
        t0 = time.monotonic()
        ev.close()
    assert time.monotonic() - t0 < 10


def _slow_above_half(x):
    if x[0] > 0.5:
        time.sleep(1.0)                     # still running when the quick one has ended
    return float(x[0])


@pytest.mark.parametrize("backend", ["serial", "process"])
def test_imap_with_stop_runs_no_trial_after_it_but_finishes_the_running_ones(backend):
    """``imap(fun, X, stop=f)``: a phase whose fall budget was spent by a batch's first trial
    ran the batch's other trials all the same (the process pool had them all queued). Once
    ``stop()`` is True no further trial starts; one running on another worker finishes and is
    yielded; the others are never run."""
    from latentune.pipeline.evaluators import ProcessEvaluator, SerialEvaluator

    ev = SerialEvaluator() if backend == "serial" else ProcessEvaluator(2)
    X = np.array([[0.0], [1.0], [0.1], [0.2]])
    seen: list[int] = []
    try:
        for i, out in ev.imap(_slow_above_half, X, stop=lambda: 0 in seen):
            seen.append(i)
            assert out.cost == X[i, 0]
        assert seen == ([0] if backend == "serial" else [0, 1])
        assert sorted(i for i, _ in ev.imap(_slow_above_half, X, stop=lambda: False)) == \
            [0, 1, 2, 3]
    finally:
        ev.close()


def test_process_pool_left_imap_then_a_dead_worker_is_clean(monkeypatch):
    """(An imap left while trials were queued (SIGTERM, Ctrl-C, an error) cancelled them in
    this thread; a worker that then died, or close() terminating the workers, made the pool's
    manager thread fail: a traceback 'InvalidStateError: CANCELLED' under the one-line
    'terminated' message, and the other workers were left running.) No thread fails, every
    worker of the old pool ends, and the next imap runs at once."""
    import threading

    from latentune.pipeline.evaluators import ProcessEvaluator

    failed: list[str] = []
    monkeypatch.setattr(threading, "excepthook",
                        lambda a: failed.append(f"{a.exc_type.__name__}: {a.exc_value}"))
    X = np.array([[0.0]] + [[1.0]] * 9)     # the quick trial, then hung ones (queued as well)
    ev = ProcessEvaluator(2)
    try:
        it = ev.imap(_hangs_above_half, X)
        i, out = next(it)
        assert i == 0 and out.cost == 0.0
        it.close()
        time.sleep(0.5)                     # both workers in a hung trial, more queued
        procs = list(ev._pool._processes.values())
        os.kill(procs[0].pid, signal.SIGKILL)       # killed from outside
        t0 = time.monotonic()
        while not getattr(ev._pool, "_broken", False) and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        time.sleep(0.5)
        t0 = time.monotonic()
        got = dict(ev.imap(_hangs_above_half, np.array([[0.1], [0.2]])))
        assert time.monotonic() - t0 < 10 and {i: r.cost for i, r in got.items()} == \
            {0: 0.1, 1: 0.2}
        for p in procs:
            p.join(5)
            assert p.exitcode is not None, "a worker of the broken pool was left running"
        it = ev.imap(_hangs_above_half, X)
        next(it)
        it.close()
    finally:
        ev.close()                          # terminates the left trials' workers
    time.sleep(0.5)
    assert failed == []


def test_process_pool_refuses_a_function_of_an_interactive_main(tmp_path, cli_env):
    """A function or System defined in ``__main__`` of a session without a file (a notebook,
    python -c) cannot be imported by a worker: EvaluationError naming workers=1 (the pool
    broke: BrokenProcessPool, 'terminated abruptly')."""
    code = ("import numpy as np\n"
            "from latentune.pipeline.evaluators import ProcessEvaluator\n"
            "from latentune.system import EvaluationError\n"
            "def f(x):\n    return float(np.sum(x))\n"
            "with ProcessEvaluator(2) as ev:\n"
            "    try:\n        ev.map(f, np.ones((2, 2)))\n"
            "    except EvaluationError as exc:\n        print('refused:', exc)\n")
    env = {**cli_env, "PYTHONPATH": str(ROOT / "src")}
    r = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, text=True,
                       capture_output=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "refused:" in r.stdout and "__main__ of an interactive session" in r.stdout
    assert "workers=1" in r.stdout


_POOL_SCRIPT = """
import os, sys, time
import numpy as np
from latentune.pipeline.evaluators import ProcessEvaluator

def pid(x):
    return float(os.getpid())

if __name__ == "__main__":
    ev = ProcessEvaluator(2)
    pids = set()
    while len(pids) < 2:                    # both workers started
        pids |= {int(p) for p in ev.map(pid, np.zeros((4, 1)))}
    print(*sorted(pids), flush=True)
    time.sleep(600)
"""


def test_process_pool_workers_end_when_their_caller_is_killed(tmp_path, cli_env):
    """A caller killed (SIGKILL, no cleanup) leaves no worker waiting for work without end
    (they held its stdout and stderr open: a pipe reader waited for ever)."""
    (tmp_path / "pool_script.py").write_text(_POOL_SCRIPT)
    env = {**cli_env, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(tmp_path)])}
    proc = subprocess.Popen([sys.executable, str(tmp_path / "pool_script.py")], env=env,
                            cwd=tmp_path, stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert len(pids) == 2 and proc.pid not in pids
    finally:
        proc.kill()
        proc.wait()

    def alive(p):
        try:
            with open(f"/proc/{p}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:         # gone before the open (ENOENT) or between open and read (ESRCH)
            return False

    t0 = time.monotonic()
    while any(map(alive, pids)) and time.monotonic() - t0 < 20:
        time.sleep(0.1)
    left = [p for p in pids if alive(p)]
    for p in left:                          # do not leave them running
        os.kill(p, signal.SIGKILL)
    assert not left, "worker processes outlived their killed caller"


@pytest.mark.slow
def test_phase1_on_local_ray(tmp_path, cli, cli_env, dump_store):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    ray_tmp = tmp_path / "rt"
    ray_tmp.mkdir()
    # Ray's unix socket paths must stay under 107 bytes: reach the temp dir inside tmp_path
    # through a short symlink
    link_dir = Path(tempfile.mkdtemp(prefix="ltr", dir="/tmp"))
    link = link_dir / "r"
    link.symlink_to(ray_tmp)
    env = dict(cli_env, RAY_TMPDIR=str(link))
    try:
        p = cli("phase1", *TINY, "--out", str(out), "--phase1-evals", "10", "--backend", "ray",
                "--workers", "2", env=env, timeout=240)
        assert p.returncode == 0, p.stderr
        rows = [r for r in dump_store(out)[0] if r[0] == 1]
        assert [r[1] for r in rows] == list(range(10))
        assert any(ray_tmp.iterdir())                      # Ray wrote its files inside tmp_path
    finally:
        shutil.rmtree(link_dir, ignore_errors=True)


def test_head_timeout_is_a_quarter_of_rays_own_when_that_is_shorter(monkeypatch):
    """Ray ends a process ``$RAY_gcs_rpc_server_reconnect_timeout_s`` (60) s after it lost the
    head: the Ray evaluator's default head timeout (15 s) is a quarter of a shorter setting, so
    its own line comes first; a longer setting, or one that is not a positive number, keeps it."""
    from latentune.pipeline.evaluators import (HEAD_TIMEOUT_S, RAY_RECONNECT_VAR,
                                               default_head_timeout)

    monkeypatch.delenv(RAY_RECONNECT_VAR, raising=False)
    assert default_head_timeout() == HEAD_TIMEOUT_S == 15.0
    for value, expected in (("16", 4.0), ("10.0", 2.5), ("600", 15.0), ("soon", 15.0),
                            ("0", 15.0), ("nan", 15.0)):
        monkeypatch.setenv(RAY_RECONNECT_VAR, value)
        assert default_head_timeout() == expected, value


def _greets_as_a_head(server: socket.socket) -> None:
    """Answer each connection to ``server`` with an HTTP/2 SETTINGS frame, the start of a Ray
    head's gRPC handshake (the check before ``ray.init``), then hold it."""
    held = []
    with contextlib.suppress(OSError):
        while True:
            conn, _ = server.accept()
            held.append(conn)
            conn.sendall(b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")


def test_ctrl_c_while_ray_starts_stops_the_ray_it_started(monkeypatch):
    """Ctrl-C (SIGINT) while ``ray.init`` starts a local Ray: interrupted midway, Ray's agent
    processes (DashboardAgent, RuntimeEnvAgent) were left running after the command ended (a
    minute or more), and the command sometimes ended in a segfault (status -11, not 130). The interrupt is held until the start-up returns;
    the Ray started is then shut down and KeyboardInterrupt raised."""
    ray = pytest.importorskip("ray")
    from latentune.pipeline.evaluators import RayEvaluator

    calls: list[str] = []

    def init(**kw):                   # Ctrl-C lands while Ray's processes are being started
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(100):          # the handler runs between bytecodes: give it the chance
            time.sleep(0.001)
        calls.append("init done")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: calls.append("shutdown"))
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    # Python's own Ctrl-C handler, as a command has it (a pytest-xdist worker ignores SIGINT)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            RayEvaluator(2)
        assert calls == ["init done", "shutdown"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        calls.clear()           # connecting to a cluster starts nothing, and may hang: not held
        with socket.create_server(("127.0.0.1", 0)) as server:
            threading.Thread(target=_greets_as_a_head, args=(server,), daemon=True).start()
            with pytest.raises(KeyboardInterrupt):
                RayEvaluator(2, address=f"127.0.0.1:{server.getsockname()[1]}")
        assert calls == []
    finally:
        signal.signal(signal.SIGINT, before)


def test_sigterm_while_ray_starts_is_the_callers_stop(monkeypatch):
    """SIGTERM while ``ray.init`` starts: Ray's own start-up handler ended the command with
    ``sys.exit(15)`` (status 15, no line; the command line's is 143 and a line). The caller's
    SIGTERM handler now acts (after Ray's start is shut down), and stays installed."""
    ray = pytest.importorskip("ray")
    from latentune.pipeline.evaluators import RayEvaluator

    class Stop(Exception):
        pass

    def stop(signum, frame):
        raise Stop

    def init(**kw):                   # Ray's handler, as SIGTERM lands during its start-up
        raise SystemExit(signal.SIGTERM)

    calls: list[str] = []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: calls.append("shutdown"))
    prev = signal.signal(signal.SIGTERM, stop)
    try:
        with pytest.raises(Stop):
            RayEvaluator(2)
        assert signal.getsignal(signal.SIGTERM) is stop and calls == ["shutdown"]
    finally:
        signal.signal(signal.SIGTERM, prev)


@pytest.mark.slow
def test_ray_reruns_a_trial_lost_with_its_worker(tmp_path, ray_local):
    """A worker process that dies mid-trial (os._exit) loses that run: Ray restarts the actor,
    the trial is run again and yielded once with ``lost_runs``; a trial that kills every worker
    it runs on is a TrialError after ``max_losses`` runs, the other trials complete; with no
    actor left for ``lost_timeout`` seconds, imap raises EvaluationError."""
    from latentune.pipeline.evaluators import RayEvaluator, TrialError

    marks = str(tmp_path / "crashed")

    def crash_once(x: np.ndarray) -> float:          # shipped by value (cloudpickle)
        mark = f"{marks}{x[0]:.3f}"
        if x[0] > 0.5 and not os.path.exists(mark):
            open(mark, "w").close()
            os._exit(1)
        return float(np.sum(x))

    def always_crash(x: np.ndarray) -> float:
        if x[0] > 0.5:
            os._exit(1)
        return float(np.sum(x))

    X = np.array([[0.1, 0.2], [0.9, 0.1], [0.2, 0.2]])
    with RayEvaluator(1, max_losses=2) as ev:
        res = dict(ev.imap(crash_once, X))
        assert sorted(res) == [0, 1, 2]
        assert [res[i].cost for i in range(3)] == pytest.approx(X.sum(axis=1))
        assert res[1].info == {"lost_runs": 1} and res[0].info == {} == res[2].info
        assert ev.lost_trials == 1
        res = dict(ev.imap(always_crash, X))
        assert isinstance(res[1], TrialError) and "2 times" in res[1].message, res[1]
        assert [res[i].cost for i in (0, 2)] == pytest.approx(X[[0, 2]].sum(axis=1))
        assert ev.lost_trials == 3
        ev.max_losses = 1                         # map: one lost run is enough to fail it
        with pytest.raises(EvaluationError, match="lost with its Ray worker"):
            ev.map(always_crash, X)

        def leave(x: np.ndarray) -> float:        # the actor exits for good: no restart
            if x[0] > 0.5:
                from ray.actor import exit_actor

                exit_actor()
            return float(np.sum(x))

        ev.lost_timeout = 1.0
        with pytest.raises(EvaluationError, match="no Ray worker of 1 was alive"):
            dict(ev.imap(leave, X))


def test_ray_more_workers_than_cpus(ray_local):
    """Actors the cluster has no CPU for take no trials: a batch completes on the placed ones."""
    from latentune.pipeline.evaluators import RayEvaluator

    def sq(x: np.ndarray) -> float:                   # shipped by value (cloudpickle)
        return float(np.sum((x - 0.3) ** 2))

    cpus = int(ray_local.cluster_resources()["CPU"])
    X = np.random.default_rng(0).random((5, 3))
    with RayEvaluator(cpus + 1) as ev:
        np.testing.assert_allclose(ev.map(sq, X), np.sum((X - 0.3) ** 2, axis=1))


class HangsOrDies:
    """A system whose trial hangs (sleeps 60 s) when a > 0.8, ends its process when
    0.5 < a <= 0.8, else costs quad."""
    space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])

    def evaluate(self, u):
        if u[0] > 0.8:
            time.sleep(60)
        elif u[0] > 0.5:
            os._exit(3)
        return quad(u)


def _dies_above_half(x):
    if x[0] > 0.5:
        os._exit(4)
    return float(np.sum(x))


def test_process_pool_survives_a_worker_that_dies_mid_trial():
    """(The pool broke: BrokenProcessPool ended the run.) The dying trial is a fall naming the
    exit code (a plain callable's: a TrialError); the others, run again on a new pool when
    they were lost with it, give their costs."""
    from latentune.pipeline.evaluators import ProcessEvaluator, TrialError

    X = np.array([[0.1, 0.2], [0.6, 0.2], [0.2, 0.3], [0.3, 0.1], [0.7, 0.4], [0.4, 0.4]])
    with ProcessEvaluator(2) as ev:
        got = dict(ev.imap(HangsOrDies(), X))
        plain = dict(ev.imap(_dies_above_half, X))
        assert ev.replaced >= 2
    assert sorted(got) == list(range(6))
    for i in (1, 4):
        assert got[i].failed and got[i].cost == 2 * C1 and got[i].info["exit_code"] == 3
        assert "worker process died (exit code 3)" in got[i].info["error"]
        assert isinstance(plain[i], TrialError) and "exit code 4" in plain[i].message
    for i in (0, 2, 3, 5):
        assert not got[i].failed and got[i].cost == pytest.approx(quad(X[i]))
        assert plain[i].cost == pytest.approx(float(np.sum(X[i])))


def test_process_pool_stops_a_trial_past_its_timeout():
    """(A hung trial hung the run for ever.) It is a fall after trial_timeout seconds, its
    worker killed; the other trials finish."""
    from latentune.pipeline.evaluators import ProcessEvaluator, make_evaluator

    X = np.array([[0.1, 0.2], [0.9, 0.2], [0.2, 0.3], [0.95, 0.1], [0.4, 0.4]])
    t0 = time.monotonic()
    with ProcessEvaluator(2, trial_timeout=1.0) as ev:
        got = dict(ev.imap(HangsOrDies(), X))
    assert time.monotonic() - t0 < 30
    for i in (1, 3):
        assert got[i].failed and got[i].info["timed_out"] and got[i].info["trial_timeout"] == 1
        assert got[i].wall_s >= 1.0 and "timeout of 1 s" in got[i].info["error"]
    for i in (0, 2, 4):
        assert not got[i].failed and got[i].cost == pytest.approx(quad(X[i]))
    with make_evaluator("process", 1, trial_timeout=2) as one:   # not the serial evaluator
        assert type(one) is ProcessEvaluator and one.trial_timeout == 2.0
    with pytest.raises(ValueError, match="needs the process backend"):
        make_evaluator("serial", 1, trial_timeout=2)


SLOW_BUILD = """
import os, time
import numpy as np
import latentune as lt


def make(main_pid, build):
    if os.getpid() != main_pid:         # a worker's build: loads a model, starts a simulator
        time.sleep(build)
    return lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [1, 1]),
                             lambda u: float(np.sum(u)))
"""


def _sleeps(x):
    time.sleep(60 if x[0] > 0.8 else x[0] + 0.1)
    return float(x[0])


def test_trials_that_hang_together_are_stopped_together():
    """(Two trials hanging on 2 workers, started 0.1 s apart, took twice the timeout: stopping
    the first one's worker broke the pool, the second was lost with it and ran again, hanging
    for a second timeout.) Trials whose timeouts fall together are stopped together: one pool
    replaced, one timeout.

    The two hanging trials are among the first three, which the pool queues for its workers
    at once (2 workers + 1 queued call): one starts at once, the other when the 0.1-s trial
    before it ends, 0.1 s later, whatever this process does meanwhile. (With both after two
    quick trials, the second waited for this process's pool thread to queue it after a result:
    a pause of this process, such as a garbage collection of a full suite's heap, started it
    more than the 0.25-s window later and the two were stopped one by one.) Without the
    window the two are stopped one by one here too: two replacements."""
    from latentune.pipeline.evaluators import ProcessEvaluator, TrialError

    with ProcessEvaluator(2, trial_timeout=1.0) as ev:
        ev.map(_sleeps, np.array([[0.0], [0.0]]))        # both workers started and idle
        t0 = time.monotonic()
        got = dict(ev.imap(_sleeps, np.array([[0.0], [0.9], [0.95], [0.2]])))
        took = time.monotonic() - t0
        assert ev.replaced == 1, ev.replaced
    assert got[0].cost == 0.0 and got[3].cost == 0.2 and sorted(got) == [0, 1, 2, 3]
    assert all(isinstance(got[i], TrialError) and "timeout of 1 s" in got[i].message
               for i in (1, 2))
    # one replacement is the proof (stopped one by one: two); the wall time only bounds it
    # from below, since a loaded machine stretches the new pool's start
    assert took >= 1.0, took


def test_a_workers_build_of_a_system_is_not_timed_as_its_trial(tmp_path, monkeypatch):
    """(The first trial of each worker counted the worker's build of a --system: a factory that
    takes longer than --trial-timeout made every trial time out, each stopped worker's
    successor building it again.) Only the trial itself is timed."""
    from latentune.pipeline.evaluators import ProcessEvaluator
    from latentune.system import load_system

    (tmp_path / "slowbuild.py").write_text(SLOW_BUILD)
    monkeypatch.syspath_prepend(str(tmp_path))
    system = load_system("slowbuild:make", {"main_pid": os.getpid(), "build": 1.5})
    X = np.random.default_rng(0).random((4, 2))
    with ProcessEvaluator(2, trial_timeout=1.0) as ev:
        got = dict(ev.imap(system, X))
        assert ev.replaced == 0
    for i in range(4):
        assert not got[i].failed and got[i].cost == pytest.approx(float(np.sum(X[i])))


OTHER_IN_WORKERS = """
import contextlib
import os
import numpy as np
import latentune as lt


def make(main_pid):
    hi = 1.0 if os.getpid() == main_pid else 4.0     # bounds read from the machine, say
    return lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [hi, 1]),
                             lambda x: float(np.sum(x)))
"""


def test_a_factory_building_another_space_in_the_workers_is_refused(tmp_path, monkeypatch):
    """A ``--system`` factory that built other bounds in the worker processes (bounds read
    from the machine, or random ones) ran every trial on other physical values than the
    caller's space says, silently. The worker's build is now checked against the caller's
    space: the phase stops in one line naming the first difference."""
    from latentune.system import load_system

    (tmp_path / "otherspace.py").write_text(OTHER_IN_WORKERS)
    monkeypatch.syspath_prepend(str(tmp_path))
    system = load_system("otherspace:make", {"main_pid": os.getpid()})
    with lt.Study(tmp_path / "r", workers=2, backend="process") as st:
        with pytest.raises(EvaluationError, match=r"could not rebuild load_system\('otherspace:make'\): "
                                                  r"its factory built another parameter space "
                                                  r"in the worker \(a: \[0, 1\] in the caller, "
                                                  r"\[0, 4\] in the worker\)"):
            st.phase1(system, 4)
        assert st.store.count(1) == 0


def test_a_stored_trial_timeout_refused_by_another_backend_names_the_one_to_use(
        tmp_path, run_cli, error_line):
    """A run started with --trial-timeout and resumed with --backend ray (a cluster) or serial
    is refused: the message names the backend that runs it (it said only that the stored
    timeout needs the process backend), as a flag at the command line, a keyword in Python."""
    from latentune.errors import UsageError

    def make_system():
        return lt.load_system("examples.toy_plant:make_system")

    with lt.Study(tmp_path / "r", workers=1, backend="process", trial_timeout=5) as st:
        st.phase1(make_system(), 2)
    for backend in ("ray", "serial"):
        code, _, err = run_cli("phase1", "--system", "examples.toy_plant:make_system", "--out",
                               tmp_path / "r", "--phase1-evals", 4, "--workers", 1,
                               "--backend", backend, "--resume")
        line = error_line(code, err)
        assert "stored trial timeout (5 s) needs the process backend" in line, line
        assert line.endswith("run it with --backend process"), line
        with pytest.raises(UsageError, match=r"run it with backend='process'$"):
            lt.Study(tmp_path / "r", backend=backend).phase1(make_system(), 4)
    assert lt.Study(tmp_path / "r").store.count(1) == 2


def test_study_trial_timeout_is_stored_and_checked(tmp_path, run_cli, error_line):
    """Study(trial_timeout=S) / --trial-timeout S: a hung trial is a fall; S is recorded and a
    reopened study uses it; a value or backend that cannot honour it is refused."""
    from latentune.errors import UsageError

    with lt.Study(tmp_path / "s", workers=2, backend="process", trial_timeout=1.0) as st:
        st.phase1(HangsOrDies(), 6, start=[0.9, 0.5])
        rows = st.store.rows(1)
        assert st.config()["trial_timeout"] == 1.0
    timed_out = [r for r in rows if r.info.get("timed_out")]
    assert len(rows) == 6 and timed_out and all(r.fell for r in timed_out)
    assert lt.Study(tmp_path / "s", workers=2, backend="process").run.trial_timeout == 1.0
    assert lt.Study(tmp_path / "s").status()          # a command that runs no trial opens it
    with pytest.raises(UsageError, match="stored trial timeout .1 s. needs the process"):
        lt.Study(tmp_path / "s").phase1(HangsOrDies(), 8, start=[0.9, 0.5])
    for bad in (0, -1.0, float("nan"), float("inf"), "5", True):
        with pytest.raises(UsageError, match="trial_timeout must be a finite number"):
            lt.Study(tmp_path / "n", workers=2, backend="process", trial_timeout=bad)
    for kw in ({}, {"backend": "ray"}):
        with pytest.raises(UsageError, match=r"a trial timeout \(3 s\) needs the process"):
            lt.Study(tmp_path / "n", trial_timeout=3, **kw)
    assert not (tmp_path / "n").exists()
    for argv, expect in ((["--trial-timeout", "0"], "--trial-timeout must be a number of "
                          "seconds > 0, got 0.0"),
                         (["--trial-timeout", "inf"], "got inf"),
                         (["--trial-timeout", "2", "--backend", "serial"],   # in its flags
                          "--trial-timeout 2 needs --backend process: serial cannot stop a "
                          "trial"),
                         (["--trial-timeout", "2", "--backend", "ray"],
                          "--trial-timeout 2 needs --backend process: ray cannot stop a trial")):
        line = error_line(*run_cli("phase1", "--out", tmp_path / "c", "--quiet", *argv)[::2])
        assert expect in line, line
    assert not (tmp_path / "c").exists()


def _always_hangs(x):
    time.sleep(30)
    return 0.0


def test_a_phase_whose_trials_all_time_out_says_so_not_to_try_the_fall_aware_critic(
        tmp_path, caplog):
    """A system whose every trial ran past ``--trial-timeout`` warned "the last 8 trials all
    failed: the search is where the system fails; try the fall-aware critic (--max-fall-prob
    0.3), a start θ that does not fail, or narrower bounds": no θ would have stood, the clock
    stopped them. The warning now says the trials ran past the timeout and to resume with a
    longer one."""
    import logging

    from latentune.pipeline.phases import FAIL_STREAK

    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with caplog.at_level(logging.WARNING), lt.Study(tmp_path / "s", workers=2, backend="process",
                                                    trial_timeout=0.3) as st:
        st.phase1(lt.FunctionSystem(sp, _always_hangs), FAIL_STREAK)
        assert all(r.fell and r.info.get("timed_out") for r in st.store.rows(1))
    (msg,) = [r.getMessage() for r in caplog.records if "the last" in r.getMessage()]
    assert msg == (f"phase 1: the last {FAIL_STREAK} trials all ran longer than the trial "
                   "timeout of 0.3 s and were stopped (stored as failed): a trial of the system "
                   "may take longer than that; resume with a longer trial_timeout"), msg


def test_the_timeout_warning_names_the_timeout_as_the_reader_sets_it():
    """The warning of a phase whose trials all timed out said "resume with a longer
    --trial-timeout (trial_timeout=)" to everyone; it names the flag at the command line and
    the keyword in Python (:func:`latentune.wording.option`)."""
    from latentune.pipeline.phases import timeout_message
    from latentune.wording import command_line_words

    assert timeout_message(1, 8, 0.3).endswith("resume with a longer trial_timeout")
    with command_line_words():
        assert timeout_message(3, 8, 0.3).endswith("resume with a longer --trial-timeout")


MANUAL_DIES = '''
import os, sys
import numpy as np
import latentune as lt

class ManualDies:
    space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1], manual=[0.9, 0.5])

    def evaluate(self, u):
        if u[0] > 0.8:
            os._exit(3)
        return float(np.sum(u))

if __name__ == "__main__":
    with lt.Study(sys.argv[1], workers=2, backend="process") as st:
        st.phase1(ManualDies(), 5)
        print([r.fell for r in st.store.rows(0)], st.store.count(1))
'''


def test_the_manual_trial_runs_on_the_process_pool(tmp_path, cli_env):
    """(It ran in the caller's process: a manual θ whose trial crashed ended the run, and a
    hung one ignored the trial timeout.) It is a failed trial like any other."""
    (tmp_path / "manual_dies.py").write_text(MANUAL_DIES)
    p = subprocess.run([sys.executable, str(tmp_path / "manual_dies.py"), str(tmp_path / "s")],
                       env=cli_env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split() == ["[True]", "5"], p.stdout


def test_a_pool_that_breaks_while_a_batch_is_submitted_runs_the_rest_after_it(monkeypatch):
    """(A worker that died while imap was still submitting its batch ended the run: the submit
    raised BrokenProcessPool.) The trials not submitted yet are submitted after the break and
    every trial gives its cost."""
    from concurrent.futures.process import BrokenProcessPool

    from latentune.pipeline.evaluators import ProcessEvaluator

    X = np.array([[0.1, 0.2], [0.6, 0.2], [0.2, 0.3], [0.3, 0.1], [0.7, 0.4], [0.4, 0.4]])
    with ProcessEvaluator(2) as ev:
        list(ev.imap(_dies_above_half, X[:1]))          # the pool exists
        real, calls = ev._pool.submit, []

        def submit(*a, **k):
            calls.append(1)
            if len(calls) == 3:
                raise BrokenProcessPool("a child process terminated abruptly")
            return real(*a, **k)

        monkeypatch.setattr(ev._pool, "submit", submit)
        got = dict(ev.imap(_dies_above_half, X[[0, 2, 3, 5]]))   # none above half
    assert sorted(got) == [0, 1, 2, 3] and len(calls) == 5
    for k, i in enumerate((0, 2, 3, 5)):
        assert got[k].cost == pytest.approx(float(np.sum(X[i])))


def _quick_slow_or_dies(x):
    if x[0] == 1.0:
        time.sleep(1.5)                     # running when the other worker dies
    elif x[0] == 2.0:
        time.sleep(0.4)                     # after the quick one has spent the budget
        os._exit(5)
    return float(x[0])


def _until_trial_0_stops(ev, fun, X):
    """``ev.imap(fun, X, stop=)`` whose stop turns True once trial 0 is yielded (a phase's fall
    budget spent by it): ``({i: result}, [i in the order yielded])``."""
    seen: list[int] = []
    got = {}
    for i, out in ev.imap(fun, X, stop=lambda: 0 in seen):
        seen.append(i)
        got[i] = out
    return got, seen


def test_a_trial_lost_with_the_pool_after_stop_is_run_again_not_dropped():
    """``imap(..., stop=)`` on the process pool: a trial running when ``stop()`` turned True
    (a phase's fall budget spent) and then lost with the pool (another worker died) was
    dropped: never yielded, and the phase counted it "not run" though it had started. It is
    run again on the new pool and yielded, as a started trial is; the trials not started by
    then are still never run."""
    from latentune.pipeline.evaluators import ProcessEvaluator, TrialError

    X = np.array([[0.0], [1.0], [2.0], [3.0]])
    with ProcessEvaluator(3) as ev:
        got, seen = _until_trial_0_stops(ev, _quick_slow_or_dies, X)
        assert ev.replaced >= 1
    assert sorted(got) == [0, 1, 2], seen
    assert got[1].cost == 1.0 and isinstance(got[2], TrialError)


@pytest.mark.slow
def test_ray_runs_a_trial_lost_with_its_worker_after_stop_again(tmp_path, ray_local):
    """``RayEvaluator.imap(..., stop=)``: a trial running when ``stop()`` turned True (a phase's
    fall budget spent) and then lost with its worker was dropped (never yielded, counted "not
    run" though it had started). It is run again and yielded, as the process pool does; the
    trials not started by then are never run."""
    from latentune.pipeline.evaluators import RayEvaluator

    crashed, started = str(tmp_path / "crashed"), str(tmp_path / "started")

    def slow_crash_once(x: np.ndarray) -> float:      # shipped by value (cloudpickle)
        if x[0] > 0.5 and not os.path.exists(crashed):
            open(started, "w").close()
            time.sleep(1.0)                           # running when trial 0 spends the budget
            open(crashed, "w").close()
            os._exit(1)
        t0 = time.monotonic()                         # trial 0 ends once trial 1 runs (an
        while not os.path.exists(started) and time.monotonic() - t0 < 60:  # actor may be slow
            time.sleep(0.05)                          # to start)
        return float(x[0])

    X = np.array([[0.1], [0.9], [0.2], [0.3]])
    with RayEvaluator(2) as ev:
        got, seen = _until_trial_0_stops(ev, slow_crash_once, X)
    assert sorted(got) == [0, 1], seen
    assert got[1].cost == pytest.approx(0.9) and got[1].info == {"lost_runs": 1}
