"""The three-phase pipeline: run store, VAE, the phase loop, crash safety, Ray, bad CLI input.

Fast: rollouts of a few hundred steps and budgets of tens of evaluations.
"""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from latentune.threads import thread_env
import pytest

from latentune.pipeline.store import RunStore, StoreError

PY = sys.executable
ENV = dict(os.environ, **thread_env(),
           RAY_AUTH_MODE="disabled", PYTHONUNBUFFERED="1")


def cli(*args: str, env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "latentune.cli", *args], capture_output=True, text=True,
                          env=env or ENV, timeout=timeout)


def dump(run_dir: Path) -> tuple:
    """Rows and meta of a store, read-only (to check a store is unchanged)."""
    con = sqlite3.connect(f"file:{run_dir / 'run.db'}?mode=ro", uri=True)
    try:
        rows = con.execute("SELECT phase, idx, theta, z, tag, cost FROM evaluations "
                           "ORDER BY phase, idx").fetchall()
        meta = con.execute("SELECT key, value FROM meta ORDER BY key").fetchall()
    finally:
        con.close()
    return rows, meta


# ---------------------------------------------------------------------------- store
def test_store_round_trip(tmp_path):
    with RunStore(tmp_path / "run", create=True) as st:
        st.set_meta("config", {"a": 1, "b": [1, 2]})
        for i in range(5):
            st.add(1, i, np.full(3, i / 10), cost=10.0 + i, tag=i * 7, fell=False, wall_s=0.5,
                   seed=3)
        st.add(3, 0, np.full(3, 0.5), cost=150.0, z=[0.1, 0.2], tag=2, fall_step=42)
        with pytest.raises(StoreError):
            st.add(1, 2, np.zeros(3), cost=1.0)            # an index is never written twice
        st.add_artifact("vae", tmp_path / "run" / "vae")
    with RunStore(tmp_path / "run") as st:
        assert st.get_meta("config") == {"a": 1, "b": [1, 2]}
        rows = st.rows(1)
        assert [r.idx for r in rows] == list(range(5))
        assert np.allclose(rows[3].theta, 0.3) and rows[3].cost == 13.0 and rows[3].tag == 21
        X, y, t = st.history(3)
        assert np.allclose(X, [[0.1, 0.2]]) and y[0] == 150.0 and t[0] == 2
        r3 = st.rows(3)[0]
        assert r3.fell and r3.fall_step == 42 and np.allclose(r3.theta, 0.5)
        assert st.best(1).idx == 0 and st.next_idx(1) == 5
        assert st.artifact("vae") == tmp_path / "run" / "vae"
        st.check_contiguous(1)
        assert st.con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_store_rejects_corrupt_and_foreign(tmp_path):
    d = tmp_path / "bad"
    d.mkdir()
    (d / "run.db").write_bytes(b"this is not a database at all" * 100)
    before = (d / "run.db").read_bytes()
    with pytest.raises(StoreError, match="not a latentune run store"):
        RunStore(d)
    assert (d / "run.db").read_bytes() == before
    f = tmp_path / "foreign"
    f.mkdir()
    con = sqlite3.connect(f / "run.db")
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="not a latentune run store"):
        RunStore(f)
    with pytest.raises(StoreError, match="does not exist"):
        RunStore(tmp_path / "missing")


# ---------------------------------------------------------------------------- VAE
@pytest.mark.parametrize("kind", ["det", "vae"])
def test_vae_shapes_determinism_training(tmp_path, kind):
    from latentune.latent import LatentSpace

    rng = np.random.default_rng(0)
    # points near a 3-dim manifold in [0, 1]^25
    A = rng.normal(size=(3, 25))
    X = 1 / (1 + np.exp(-(rng.normal(size=(150, 3)) @ A) * 0.5))
    a = LatentSpace.train(X, kind=kind, seed=1, epochs=200)
    b = LatentSpace.train(X, kind=kind, seed=1, epochs=200)
    assert a.d == 25 and a.d_low == 10 and a.kind == kind
    assert a.net.encoder[0].out_features == 12 and a.net.encoder[2].out_features == 6
    u = rng.random((7, 10))
    th = a.decode(u)
    assert th.shape == (7, 25) and th.min() >= 0 and th.max() <= 1
    assert a.decode(u[0]).shape == (25,)
    assert np.array_equal(th, b.decode(u))                  # deterministic for a seed
    assert a.log.rec[-1] < 0.95 * a.log.rec[0]               # training reduces the loss
    assert a.log.loss[-1] < a.log.loss[0]
    assert a.box.shape == (10, 2) and np.all(a.box[:, 0] < a.box[:, 1])
    uz = a.to_unit(a.encode(X))
    assert uz.shape == (150, 10) and uz.min() >= 0 and uz.max() <= 1
    a.meta["robot"] = "a1"
    a.save(tmp_path / "vae")
    c = LatentSpace.load(tmp_path / "vae")
    assert np.allclose(c.decode(u), th) and c.meta["robot"] == "a1" and c.meta["n_train"] == 150
    assert np.allclose(c.box, a.box)


def test_vae_77_dim_default_latent():
    from latentune.latent import LatentSpace

    X = np.random.default_rng(0).random((40, 77))
    ls = LatentSpace.train(X, seed=0, epochs=5)
    assert ls.d_low == 5 and ls.decode(np.full(5, 0.5)).shape == (77,)


# ---------------------------------------------------------------------------- phase loop
def quad(x: np.ndarray) -> float:
    return float(np.sum((np.asarray(x) - 0.3) ** 2) * 100)


def test_phase_identity_and_resume(tmp_path):
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase

    def critic():
        return make_phase_critic("turbo", 6, 4, 0, np.full(6, 0.5), 30, regions=1)

    with RunStore(tmp_path / "r", create=True) as st:
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator(), max_new=14)
        assert r.n == 14 and r.n_new == 14
        np.testing.assert_allclose(st.rows(1)[0].theta, 0.5)      # starts from x0
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator())   # resume
        assert r.n == 30 and r.n_new == 16
        rows = st.rows(1)
        assert [x.idx for x in rows] == list(range(30))
        assert all(x.z is None for x in rows)
        assert r.best_cost == min(x.cost for x in rows) < quad(np.full(6, 0.5))
        r = run_phase(st, 1, quad, critic(), 30, SerialEvaluator())    # nothing left to do
        assert r.n_new == 0


def test_a_resumed_turbo_run_is_the_uninterrupted_run(tmp_path):
    """The store keeps TuRBO-m's warm-started GP hyperparameters (its state_dict) after every
    batch, so a run stopped between batches and resumed asks exactly the points of a run that
    was never stopped; without that state it would not (the hyperparameters are refitted cold)."""
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase, state_key

    def critic():
        return make_phase_critic("turbo", 6, 4, 0, None, 60, regions=2)

    def thetas(st):
        return np.array([r.theta for r in st.rows(1)])

    with RunStore(tmp_path / "whole", create=True) as st:
        run_phase(st, 1, quad, critic(), 60, SerialEvaluator())
        whole = thetas(st)
    with RunStore(tmp_path / "resumed", create=True) as st:
        for stop in (20, 36, 60):
            run_phase(st, 1, quad, critic(), 60, SerialEvaluator(), max_new=stop - st.count(1))
        np.testing.assert_array_equal(thetas(st), whole)
    with RunStore(tmp_path / "stateless", create=True) as st:
        run_phase(st, 1, quad, critic(), 60, SerialEvaluator(), max_new=36)
        st.set_meta(state_key(1), {})
        run_phase(st, 1, quad, critic(), 60, SerialEvaluator())
        assert not np.array_equal(thetas(st), whole)


class _ReversedEvaluator:
    """Yields each batch's results last-first, as workers that finish out of order would."""

    def imap(self, fun, X):
        from latentune.system import Outcome

        return reversed([(i, Outcome(fun(x))) for i, x in enumerate(X)])


def test_phase_same_seed_same_run_whatever_the_completion_order(tmp_path):
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import make_phase_critic, run_phase

    runs = []
    for name, ev in (("in_order", SerialEvaluator()), ("reversed", _ReversedEvaluator())):
        with RunStore(tmp_path / name, create=True) as st:
            run_phase(st, 1, quad, make_phase_critic("turbo", 6, 4, 0, None, 60, regions=2), 60, ev)
            runs.append(sorted(tuple(r.theta) for r in st.rows(1)))
    assert len(runs[0]) == 60 and runs[0] == runs[1]


def test_training_set_does_not_depend_on_completion_order(tmp_path):
    from latentune.pipeline.phases import training_set

    rng = np.random.default_rng(0)
    X, y = rng.random((20, 5)), np.where(rng.random(20) < 0.3, 150.0, 10.0)
    sets = []
    for name, order in (("a", np.arange(20)), ("b", rng.permutation(20))):
        with RunStore(tmp_path / name, create=True) as st:
            for idx, i in enumerate(order):
                st.add(1, idx, X[i], float(y[i]))
            sets.append(training_set(st))
    assert sets[0].shape == (int((y < 100).sum()), 5)
    np.testing.assert_array_equal(sets[0], sets[1])


def test_phase_with_decoder_and_task(tmp_path):
    from latentune.pipeline.evaluators import SerialEvaluator
    from latentune.pipeline.phases import ensure_manual, make_phase_critic, run_phase
    from latentune.task import Task

    task = Task("a1", "trot", steps=150)
    d = task.space.dim
    W = np.random.default_rng(0).normal(size=(3, d))
    man = task.space.manual

    def decoder(U):        # a fixed 3-dim "latent space" around the manual θ
        return np.clip(man + 0.1 * (np.atleast_2d(U) - 0.5) @ W, 0, 1)

    crit = make_phase_critic("random", 3, 3, 0, None, 6)
    with RunStore(tmp_path / "r", create=True) as st:
        assert ensure_manual(st, task) == st.rows(0)[0].cost
        r = run_phase(st, 3, task, crit, 6, SerialEvaluator(), decoder=decoder)
        rows = st.rows(3)
        assert r.n == 6 and len(rows) == 6
        for row in rows:
            assert row.z.shape == (3,) and row.theta.shape == (d,)
            np.testing.assert_allclose(row.theta, decoder(row.z)[0])
            assert row.wall_s > 0 and row.fell == (row.cost >= 100)


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


# ---------------------------------------------------------------------------- CLI end to end
TINY = ["--robot", "a1", "--task", "trot", "--steps", "200", "--quiet"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A tiny `tune` run (serial) shared by the bad-input tests."""
    out = tmp_path_factory.mktemp("runs") / "small"
    p = cli("tune", *TINY, "--out", str(out), "--phase1-evals", "16", "--phase3-evals", "8",
            "--backend", "serial", "--vae-epochs", "30")
    assert p.returncode == 0, p.stderr
    return out


def test_tune_outputs(small_run):
    s = json.loads((small_run / "summary.json").read_text())
    for k in ("manual_cost", "phase1_best", "phase3_best", "phase1_evals", "phase3_evals",
              "wall_s", "seed", "config"):
        assert k in s
    assert s["phase1_evals"] == 16 and s["phase3_evals"] == 8
    from latentune.task import Task

    with RunStore(small_run) as st:                            # phase 1 starts from manual
        np.testing.assert_allclose(st.rows(1)[0].theta, Task(steps=200).space.manual)
        assert st.rows(1)[0].cost == pytest.approx(s["manual_cost"])
    best = json.loads((small_run / "phase3_best.json").read_text())
    assert isinstance(best, dict) and len(best) == 25
    p = cli("rollout", "--robot", "a1", "--task", "trot", "--steps", "200", "--json",
            "--params", str(small_run / "phase1_best.json"))
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["cost"] == pytest.approx(s["phase1_best"], rel=1e-6)
    assert (small_run / "vae.pt").is_file() and (small_run / "vae.json").is_file()


def test_report(small_run):
    before = dump(small_run)[0]
    p = cli("report", str(small_run), "--quiet")
    assert p.returncode == 0, p.stderr
    assert "phase 1" in p.stdout and "phase 3" in p.stdout
    for f in ("report.md", "best_so_far.png", "com_velocity.png"):
        assert (small_run / f).stat().st_size > 0
    assert dump(small_run)[0] == before


def _one_line_error(p: subprocess.CompletedProcess) -> None:
    assert p.returncode != 0
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith("latentune: error:")


def test_bad_input(small_run, tmp_path):
    from latentune.latent import LatentSpace

    before = dump(small_run)
    # missing run directory / store
    _one_line_error(cli("report", str(tmp_path / "nope")))
    _one_line_error(cli("train-vae", *TINY, "--out", str(tmp_path / "nope")))
    _one_line_error(cli("phase3", *TINY, "--out", str(tmp_path / "nope2")))
    assert not (tmp_path / "nope2").exists()
    # corrupt store
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "run.db").write_bytes(os.urandom(4096))
    raw = (bad / "run.db").read_bytes()
    _one_line_error(cli("report", str(bad)))
    _one_line_error(cli("phase1", *TINY, "--out", str(bad), "--resume"))
    assert (bad / "run.db").read_bytes() == raw
    # resume with another configuration
    _one_line_error(cli("tune", "--robot", "a1", "--task", "jump", "--steps", "200", "--quiet",
                        "--out", str(small_run), "--resume"))
    _one_line_error(cli("tune", *TINY, "--seed", "5", "--out", str(small_run), "--resume"))
    # the run exists: no silent re-run without --resume
    _one_line_error(cli("phase1", *TINY, "--out", str(small_run)))
    # a VAE of another θ dimension
    other = tmp_path / "vae12"
    other.mkdir()
    LatentSpace.train(np.random.default_rng(0).random((20, 12)), seed=0, epochs=2).save(other / "vae")
    _one_line_error(cli("phase3", *TINY, "--out", str(small_run), "--vae", str(other), "--resume"))
    _one_line_error(cli("phase3", *TINY, "--out", str(tmp_path / "x"), "--vae", str(other)))
    assert not (tmp_path / "x").exists()
    # budgets < 1
    _one_line_error(cli("tune", *TINY, "--out", str(tmp_path / "b0"), "--phase1-evals", "0"))
    _one_line_error(cli("phase3", *TINY, "--out", str(small_run), "--phase3-evals", "-3",
                        "--resume"))
    assert not (tmp_path / "b0").exists()
    assert dump(small_run) == before


def _count(db: Path) -> int:
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return con.execute("SELECT COUNT(*) FROM evaluations WHERE phase=1").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def test_crash_and_resume(tmp_path):
    out = tmp_path / "crash"
    args = ["phase1", *TINY, "--out", str(out), "--phase1-evals", "40", "--workers", "2"]
    proc = subprocess.Popen([PY, "-m", "latentune.cli", *args], env=ENV, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.time()
    while _count(out / "run.db") < 12:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.time() - t0 < 120
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)                   # the CLI and its workers
    proc.wait()
    kept = dump(out)[0]
    n_kill = len([r for r in kept if r[0] == 1])
    assert 12 <= n_kill < 40
    p = cli(*args, "--resume")
    assert p.returncode == 0, p.stderr
    rows = [r for r in dump(out)[0] if r[0] == 1]
    assert [r[1] for r in rows] == list(range(40))          # contiguous, none duplicated
    assert rows[:n_kill] == [r for r in kept if r[0] == 1]  # everything stored is kept
    assert len({r[2] for r in rows}) == 40                   # no θ evaluated twice


def test_phase1_on_local_ray(tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    ray_tmp = tmp_path / "rt"
    ray_tmp.mkdir()
    # Ray's unix socket paths must stay under 107 bytes: reach the temp dir inside tmp_path
    # through a short symlink
    link_dir = Path(tempfile.mkdtemp(prefix="ltr", dir="/tmp"))
    link = link_dir / "r"
    link.symlink_to(ray_tmp)
    env = dict(ENV, RAY_TMPDIR=str(link))
    p = cli("phase1", *TINY, "--out", str(out), "--phase1-evals", "10", "--backend", "ray",
            "--workers", "2", env=env, timeout=240)
    assert p.returncode == 0, p.stderr
    rows = [r for r in dump(out)[0] if r[0] == 1]
    assert [r[1] for r in rows] == list(range(10))
    assert any(ray_tmp.iterdir())                      # Ray wrote its files inside tmp_path
    shutil.rmtree(link_dir, ignore_errors=True)
