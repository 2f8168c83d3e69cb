"""Evaluators (latentune.pipeline.evaluators): a process pool gives the serial costs, a run
killed with its workers resumes without losing or repeating a trial, phase 1 on a local Ray, a
Ray worker lost mid-trial (the trial is run again, once), an unreachable Ray address (one line).
A worker *node* lost mid-run: tests/test_ray_cluster.py."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

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


def test_crash_and_resume(tmp_path, cli, cli_env, dump_store):
    """SIGKILL of the CLI and its worker processes mid-run (needs real processes), then resume."""
    out = tmp_path / "crash"
    n, n_kill = 24, 8
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
    p = cli(*args, "--resume")
    assert p.returncode == 0, p.stderr
    rows = [r for r in dump_store(out)[0] if r[0] == 1]
    assert [r[1] for r in rows] == list(range(n))           # contiguous, none duplicated
    assert rows[:n_stored] == [r for r in kept if r[0] == 1]  # everything stored is kept
    assert len({r[2] for r in rows}) == n                    # no θ evaluated twice


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


def test_ray_reruns_a_trial_lost_with_its_worker(tmp_path):
    """A worker process that dies mid-trial (os._exit) loses that run: Ray restarts the actor,
    the trial is run again and yielded once with ``lost_runs``; a trial that kills every worker
    it runs on is a TrialError after ``max_losses`` runs, the other trials complete; with no
    actor left for ``lost_timeout`` seconds, imap raises EvaluationError."""
    pytest.importorskip("ray")
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
    ray_tmp = Path(tempfile.mkdtemp(prefix="ltr", dir="/tmp"))   # unix sockets: a short path
    try:
        with RayEvaluator(1, temp_dir=str(ray_tmp), max_losses=2) as ev:
            res = dict(ev.imap(crash_once, X))
            assert sorted(res) == [0, 1, 2]
            assert [res[i].cost for i in range(3)] == pytest.approx(X.sum(axis=1))
            assert res[1].info == {"lost_runs": 1} and res[0].info == {} == res[2].info
            assert ev.lost_trials == 1
            res = dict(ev.imap(always_crash, X))
            assert isinstance(res[1], TrialError) and "2 times" in res[1].message, res[1]
            assert [res[i].cost for i in (0, 2)] == pytest.approx(X[[0, 2]].sum(axis=1))
            assert ev.lost_trials == 3
            with pytest.raises(EvaluationError, match="lost with its Ray worker"):
                ev.map(always_crash, X)

            def leave(x: np.ndarray) -> float:        # the actor exits for good: no restart
                if x[0] > 0.5:
                    from ray.actor import exit_actor

                    exit_actor()
                return float(np.sum(x))

            ev.lost_timeout = 3.0
            with pytest.raises(EvaluationError, match="no Ray worker of 1 was alive"):
                dict(ev.imap(leave, X))
    finally:
        shutil.rmtree(ray_tmp, ignore_errors=True)


def test_unreachable_ray_address_is_one_line(tmp_path, run_cli, error_line):
    """A cluster address nobody answers at: one line at once (Ray alone retries without end)."""
    pytest.importorskip("ray")
    import socket

    with socket.socket() as s:                       # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err = run_cli("phase1", *TINY, "--out", tmp_path / "r", "--phase1-evals", "4",
                           "--backend", "ray", "--ray-address", f"127.0.0.1:{port}")
    assert f"no Ray cluster answers at 127.0.0.1:{port}" in error_line(code, err)


def test_ray_more_workers_than_cpus(tmp_path):
    """Actors the cluster has no CPU for take no trials: a batch completes on the placed ones."""
    pytest.importorskip("ray")
    import ray

    from latentune.pipeline.evaluators import RayEvaluator

    ray_tmp = Path(tempfile.mkdtemp(prefix="ltr", dir="/tmp"))   # unix sockets: a short path
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False,
             _temp_dir=str(ray_tmp))
    try:
        def sq(x: np.ndarray) -> float:               # shipped by value (cloudpickle)
            return float(np.sum((x - 0.3) ** 2))

        X = np.random.default_rng(0).random((5, 3))
        with RayEvaluator(3) as ev:
            np.testing.assert_allclose(ev.map(sq, X), np.sum((X - 0.3) ** 2, axis=1))
    finally:
        ray.shutdown()
        shutil.rmtree(ray_tmp, ignore_errors=True)
