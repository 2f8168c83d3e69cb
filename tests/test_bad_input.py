"""Bad input everywhere: one line on stderr, exit status 2, no traceback, stored rows unchanged.

Most cases run the CLI in this process (``latentune.cli.main``) to stay fast; a few run it as a
subprocess to check what reaches a terminal.
"""
from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.cli import main
from latentune.errors import LatentuneError, StoreError
from latentune.pipeline.store import RunStore

TINY = ["--robot", "a1", "--task", "trot", "--steps", "150", "--quiet"]


def dump(run: Path) -> tuple:
    con = sqlite3.connect(f"file:{run / 'run.db'}?mode=ro", uri=True)
    try:
        return (con.execute("SELECT * FROM evaluations ORDER BY phase, idx").fetchall(),
                con.execute("SELECT key, value FROM meta WHERE key != 'artifacts' "
                            "ORDER BY key").fetchall())
    finally:
        con.close()


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line(capsys, *argv: str) -> str:
    code, out, err = run_cli(capsys, *argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (argv, code, err)
    assert len(lines) == 1 and lines[0].startswith("latentune: error:"), (argv, err)
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny finished tune run (serial) and a copy made per test that may damage it."""
    out = tmp_path_factory.mktemp("bad") / "run"
    assert main(["tune", *TINY, "--out", str(out), "--phase1-evals", "10", "--phase3-evals", "4",
                 "--backend", "serial", "--vae-epochs", "20"]) == 0
    return out


@pytest.fixture
def copy_run(run_dir, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(run_dir, dst)
    return dst


# ---------------------------------------------------------------------------- arguments
RUN_CMDS = ("tune", "phase1", "train-vae", "phase3")
BAD_TASK_ARGS = [
    ["--robot", "nosuch"], ["--robot", "missing.yaml"], ["--task", "gallop"],
    ["--terrain", "ice"], ["--actor", "pid"], ["--steps", "0"], ["--steps", "-5"],
    ["--steps", "x"], ["--v-des", "nan"], ["--v-des", "inf"], ["--v-des", "9"],
    ["--seed", "-1"], ["--seed", str(2 ** 63)], ["--seed", "1.5"], ["--reality", "nope"],
    ["--reality", "missing.yaml"], ["--engine", "ode"],
]
BAD_RUN_ARGS = [
    ["--phase1-evals", "0"], ["--phase3-evals", "-1"], ["--workers", "0"],
    ["--latent-dim", "0"], ["--regions", "0"], ["--regions", "101"], ["--batch-size", "0"],
    ["--vae-epochs", "0"], ["--backend", "gpu"], ["--method", "adam"],
    ["--ray-address", "1.2.3.4:6379"], ["--system-arg", "k=v"],
    ["--system", "a:b", "--robot", "a1"], ["--system", "a:b", "--reality", "heavy"],
    ["--no-such-flag"],
]


@pytest.mark.parametrize("cmd", RUN_CMDS)
@pytest.mark.parametrize("bad", BAD_TASK_ARGS + BAD_RUN_ARGS, ids=lambda b: " ".join(b))
def test_run_commands_reject_bad_arguments(capsys, tmp_path, cmd, bad):
    argv = [cmd, "--out", tmp_path / "r", "--quiet", "--backend", "serial", *bad]
    assert_one_line(capsys, *argv)
    assert not (tmp_path / "r" / "run.db").exists()


@pytest.mark.parametrize("cmd", ["tune", "phase3"])
@pytest.mark.parametrize("bad", [["--handover", "size=3"], ["--handover", "patience=a"],
                                 ["--handover", "tol=2"], ["--handover", "length=0"],
                                 ["--handover", "patience"]], ids=lambda b: " ".join(b))
def test_bad_handover_options(capsys, tmp_path, cmd, bad):
    argv = [cmd, "--out", tmp_path / "r", "--quiet", "--backend", "serial", *bad]
    assert "--handover" in assert_one_line(capsys, *argv)
    assert not (tmp_path / "r" / "run.db").exists()


@pytest.mark.parametrize("bad", BAD_TASK_ARGS + [
    ["--params", "missing.json"], ["--gif", "/nonexistent/dir/x.gif"], ["--gif", "."],
    ["--gif", "x.png"], ["--plot", "x.txt"], ["--plot", "/nonexistent/x.png"], ["--json", "x"],
], ids=lambda b: " ".join(b))
def test_rollout_rejects_bad_arguments(capsys, bad):
    assert_one_line(capsys, "rollout", *bad)


@pytest.mark.parametrize("content", [
    "not json", "[0.5]", "[0.5, 0.5]", json.dumps([float("nan")] * 25), json.dumps([2.0] * 25),
    json.dumps([True] * 25), json.dumps({"nosuch": 1.0}), json.dumps({"Q_roll": -1.0}),
    json.dumps({"Q_roll": "a"}), "3", "null",
])
def test_rollout_rejects_bad_params_files(capsys, tmp_path, content):
    f = tmp_path / "p.json"
    f.write_text(content)
    assert_one_line(capsys, "rollout", "--steps", "10", "--params", f)


@pytest.mark.parametrize("bad", [
    ["--robot", "go2"], ["--scale", "0"], ["--scale", "-1"], ["--scale", "nan"], ["--scale", "x"],
    ["--workers", "0"], ["--steps", "0"], ["--seed", "-3"], ["--v-des", "nan"],
    ["--phase1-evals", "0"], ["--report-only"],
], ids=lambda b: " ".join(b))
def test_paper_rejects_bad_arguments(capsys, tmp_path, bad):
    assert_one_line(capsys, "paper", "--out", tmp_path / "p", "--quiet", *bad)


@pytest.mark.parametrize("bad", [["--timeout", "-1"], ["--timeout", "0"], ["--steps", "0"],
                                 ["--n", "0"], ["--n", "x"]], ids=lambda b: " ".join(b))
def test_bench_rejects_bad_arguments(capsys, bad):
    assert_one_line(capsys, "bench", *bad)


def test_paper_out_is_a_file(capsys, tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    assert_one_line(capsys, "paper", "--out", f, "--quiet")


@pytest.mark.parametrize("argv", [[], ["nosuchcommand"], ["tune"], ["report"], ["ask"], ["tell"],
                                  ["tell", "d"], ["status"], ["rollout", "--steps"]],
                         ids=lambda a: " ".join(a) or "nothing")
def test_parser_errors(capsys, argv):
    assert_one_line(capsys, *argv)


# ---------------------------------------------------------------------------- run directories
def test_existing_run_is_not_rerun_or_changed(capsys, run_dir, tmp_path):
    before = dump(run_dir)
    cases = [
        ["phase1", *TINY, "--out", run_dir],                                  # no --resume
        ["tune", *TINY, "--out", run_dir],
        ["phase3", *TINY, "--out", run_dir],
        ["tune", "--robot", "a1", "--task", "jump", "--steps", "150", "--quiet", "--out", run_dir,
         "--resume"],                                                          # another task
        ["tune", *TINY[:-1], "--terrain", "hills", "--quiet", "--out", run_dir, "--resume"],
        ["tune", *TINY, "--seed", "5", "--out", run_dir, "--resume"],        # another seed
        ["tune", *TINY, "--method", "cma", "--out", run_dir, "--resume"],     # another method
        ["tune", *TINY, "--batch-size", "7", "--out", run_dir, "--resume"],
        ["phase1", "--robot", "b1", "--steps", "150", "--quiet", "--out", run_dir, "--resume"],
        ["phase1", "--robot", "a1", "--steps", "151", "--quiet", "--out", run_dir, "--resume"],
        ["phase3", *TINY, "--out", run_dir, "--resume", "--vae", tmp_path / "nope"],
        ["train-vae", "--robot", "b1", "--steps", "150", "--quiet", "--out", run_dir],
    ]
    for argv in cases:
        assert_one_line(capsys, *argv)
    assert dump(run_dir) == before


@pytest.mark.parametrize("cmd", ["report", "status"])
def test_missing_and_foreign_directories(capsys, tmp_path, cmd):
    assert_one_line(capsys, cmd, tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    assert_one_line(capsys, cmd, tmp_path / "empty")
    f = tmp_path / "file"
    f.write_text("x")
    assert_one_line(capsys, cmd, f)


@pytest.mark.parametrize("damage", ["random_bytes", "empty_file", "foreign_sqlite", "truncated"])
@pytest.mark.parametrize("cmd", ["report", "status", "resume", "phase3", "ask", "tell"])
def test_corrupt_store(capsys, copy_run, damage, cmd):
    db = copy_run / "run.db"
    for side in ("run.db-wal", "run.db-shm"):
        (copy_run / side).unlink(missing_ok=True)
    if damage == "random_bytes":
        db.write_bytes(os.urandom(8192))
    elif damage == "empty_file":
        db.write_bytes(b"")
    elif damage == "foreign_sqlite":
        db.unlink()
        con = sqlite3.connect(db)
        con.execute("CREATE TABLE x (a)")
        con.commit()
        con.close()
    else:
        db.write_bytes(db.read_bytes()[:3000])
    raw = db.read_bytes()
    argv = {"report": ["report", copy_run], "status": ["status", copy_run],
            "resume": ["tune", *TINY, "--out", copy_run, "--resume", "--backend", "serial"],
            "phase3": ["phase3", *TINY, "--out", copy_run, "--resume", "--backend", "serial"],
            "ask": ["ask", copy_run], "tell": ["tell", copy_run, "1", "--cost", "1"]}[cmd]
    assert_one_line(capsys, *argv)
    assert db.read_bytes() == raw


@pytest.mark.parametrize("what", ["config", "theta", "deleted_row", "duplicate_gap"])
def test_damaged_rows_and_meta(capsys, copy_run, what):
    con = sqlite3.connect(copy_run / "run.db")
    if what == "config":
        con.execute("UPDATE meta SET value='{not json' WHERE key='config'")
    elif what == "theta":
        con.execute("UPDATE evaluations SET theta='[0.1, oops' WHERE phase=1 AND idx=3")
    elif what == "deleted_row":
        con.execute("DELETE FROM evaluations WHERE phase=1 AND idx=4")
    else:
        con.execute("UPDATE evaluations SET idx=99 WHERE phase=3 AND idx=1")
    con.commit()
    con.close()
    before = dump(copy_run)[0]
    line = assert_one_line(capsys, "tune", *TINY, "--out", copy_run, "--resume", "--backend",
                           "serial", "--phase1-evals", "12", "--phase3-evals", "6")
    assert "run store" in line or "not contiguous" in line or "garbled" in line
    assert dump(copy_run)[0] == before


@pytest.mark.parametrize("artifact, damage", [("vae.pt", "truncate"), ("vae.pt", "garble"),
                                              ("vae.json", "truncate"), ("vae.json", "garble"),
                                              ("vae.pt", "delete"), ("vae.json", "delete")])
@pytest.mark.parametrize("cmd", ["tune", "phase3"])
def test_damaged_latent_space(capsys, copy_run, artifact, damage, cmd):
    p = copy_run / artifact
    if damage == "truncate":
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 3])
    elif damage == "garble":
        p.write_bytes(b"\x00garbage" * 50)
    else:
        p.unlink()
    before = dump(copy_run)[0]
    assert_one_line(capsys, cmd, *TINY, "--out", copy_run, "--resume", "--backend", "serial",
                    "--phase1-evals", "10", "--phase3-evals", "6")
    assert dump(copy_run)[0] == before


def test_phase3_with_a_bad_other_run(capsys, tmp_path, run_dir):
    other = tmp_path / "vae12"
    other.mkdir()
    lt.LatentSpace.train(np.random.default_rng(0).random((20, 12)), seed=0, epochs=2).save(
        other / "vae")
    for vae in (other, tmp_path / "nope", tmp_path):
        assert_one_line(capsys, "phase3", *TINY, "--out", tmp_path / "x", "--vae", vae)
        assert not (tmp_path / "x").exists()
    # a kino-dynamic task with the convex VAE
    assert_one_line(capsys, "phase3", "--robot", "solo12", "--actor", "kinodynamic", "--steps",
                    "50", "--quiet", "--out", tmp_path / "y", "--vae", run_dir)


def test_a_second_writer_is_refused_with_who_holds_the_lock(capsys, copy_run):
    with lt.Study(copy_run).writing():
        line = assert_one_line(capsys, "tune", *TINY, "--out", copy_run, "--resume",
                               "--backend", "serial", "--phase1-evals", "12")
        assert f"pid {os.getpid()}" in line
        line = assert_one_line(capsys, "tell", copy_run, "1", "--cost", "1")
        assert "being written" in line


def test_full_disk_is_one_line_and_keeps_the_store(tmp_path):
    """SQLite's page limit stands in for a full disk ('database or disk is full')."""
    st = RunStore(tmp_path / "s", create=True)
    n = 0
    st.con.execute(f"PRAGMA max_page_count={st.con.execute('PRAGMA page_count').fetchone()[0] + 2}")
    with pytest.raises(StoreError, match="full"):
        for n in range(100000):
            st.add(1, n, np.random.default_rng(n).random(200), 1.0, info={"pad": "x" * 500})
    st.close()
    with RunStore(tmp_path / "s") as again:
        assert again.count(1) == n                  # every committed row is there
        assert [r.idx for r in again.rows(1)] == list(range(n))


# ---------------------------------------------------------------------------- ask / tell
@pytest.fixture
def asktell(tmp_path):
    d = tmp_path / "at"
    space = tmp_path / "space.yaml"
    space.write_text("names: [a, b, c]\nlow: [0, 0, 0]\nhigh: [1, 2, 3]\n")
    assert main(["ask", str(d), "--space", str(space), "--n", "2"]) == 0
    return d, space


@pytest.mark.parametrize("argv", [
    ["tell", "{d}", "99", "--cost", "1"], ["tell", "{d}", "x", "--cost", "1"],
    ["tell", "{d}", "1"], ["tell", "{d}", "1", "--cost", "nan"], ["tell", "{d}", "1", "--cost", "inf"],
    ["tell", "{d}", "1", "--cost", "abc"], ["tell", "{d}", "-1", "--cost", "1"],
    ["tell", "{d}", "1.5", "--cost", "1"], ["ask", "{d}", "--n", "0"], ["ask", "{d}", "--n", "-2"],
    ["ask", "{d}", "--phase", "2"], ["ask", "{d}", "--phase", "3"], ["ask", "{d}", "--seed", "5"],
    ["ask", "{d}", "--method", "nope"], ["ask", "{d}", "--robot", "a1"],
    ["ask", "{d}", "--space", "{d}/missing.yaml"], ["tell", "{d}/nope", "1", "--cost", "1"],
    ["status", "{d}/nope"],
], ids=lambda a: " ".join(a).replace("{d}", "D"))
def test_ask_tell_bad_input(capsys, asktell, argv):
    d, _ = asktell
    before = dump(d)
    assert_one_line(capsys, *[a.replace("{d}", str(d)) for a in argv])
    assert dump(d) == before


@pytest.mark.parametrize("content", ["names: [a]\nlow: [1]\nhigh: [0]\n", "names: [a, a]\nlow: [0, 0]\nhigh: [1, 1]\n",
                                     "low: [0]\nhigh: [1]\n", "[1, 2]", "names: [a]\nlow: [0]\nhigh: [1]\nlog: [true]\n",
                                     "names: [a]\nlow: [0]\nhigh: [1]\nmanual: [5]\n", ": : :"])
def test_ask_rejects_bad_space_files(capsys, tmp_path, content):
    f = tmp_path / "s.yaml"
    f.write_text(content)
    assert_one_line(capsys, "ask", tmp_path / "d", "--space", f)
    assert not (tmp_path / "d" / "run.db").exists()


def test_a_told_suggestion_cannot_be_told_again(capsys, asktell):
    d, _ = asktell
    assert main(["tell", str(d), "1", "--cost", "0.5"]) == 0
    capsys.readouterr()
    before = dump(d)
    assert "already told" in assert_one_line(capsys, "tell", d, "1", "--cost", "0.4")
    assert dump(d) == before


# ---------------------------------------------------------------------------- the Python API
@pytest.mark.parametrize("kw", [dict(robot=5), dict(robot="nosuch"), dict(gait="gallop"),
                                dict(terrain="mars"), dict(actor="pid"), dict(steps=0),
                                dict(steps=True), dict(steps=2.5), dict(seed=-1), dict(seed=1.7),
                                dict(seed=2 ** 63), dict(v_des=float("nan")), dict(v_des="fast"),
                                dict(v_des=(1, 2))])
def test_task_rejects_bad_arguments(kw):
    with pytest.raises(LatentuneError):
        lt.Task(**kw)


def f(x):
    return float(np.sum(x ** 2))


@pytest.mark.parametrize("kw", [dict(bounds=[[0, 1e308], [-1e308, 1e308]]),
                                dict(bounds=[[1, 0]]), dict(bounds=[[0, np.inf]]), dict(bounds=[]),
                                dict(bounds=[[0, 1]], budget=0), dict(bounds=[[0, 1]], method="x"),
                                dict(bounds=[[0, 1]], batch_size=0), dict(bounds=[[0, 1]], seed=-1),
                                dict(bounds=[[0, 1]], x0=[2.0]), dict(bounds=[[0, 1]], x0=[np.nan]),
                                dict(bounds="abc")])
def test_minimize_rejects_bad_arguments(kw):
    calls = []
    with pytest.raises(ValueError):
        lt.minimize(lambda x: calls.append(x) or f(x), **kw)
    assert not calls                                     # f is never evaluated


@pytest.mark.parametrize("args", [
    (["a"], [0], [1], [True]), (["a"], [1], [0]), (["a", "a"], [0, 0], [1, 1]), ([], [], []),
    (["a"], [0, 1], [1]), (["a"], [0], [np.nan]), (["a"], [0], [1], None, [3.0]),
])
def test_parameter_space_rejects_bad_arguments(args):
    with pytest.raises(ValueError):
        lt.ParameterSpace(*args)


@pytest.mark.parametrize("kw", [dict(seed=-1), dict(seed=1.5), dict(workers=0), dict(backend="x"),
                                dict(batch_size=0), dict(ray_address="x:1")])
def test_study_rejects_bad_arguments(tmp_path, kw):
    with pytest.raises(ValueError):
        lt.Study(tmp_path / "s", **kw)
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("call", ["budget0", "method", "regions", "start", "system", "latent"])
def test_study_phases_reject_bad_arguments(tmp_path, call):
    space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    sys_ = lt.FunctionSystem(space, f)
    st = lt.Study(tmp_path / "s")
    with pytest.raises(LatentuneError):
        if call == "budget0":
            st.phase1(sys_, 0)
        elif call == "method":
            st.phase1(sys_, 5, method="adam")
        elif call == "regions":
            st.phase1(sys_, 5, regions=0)
        elif call == "start":
            st.phase1(sys_, 5, start=[2.0, 0.0])
        elif call == "system":
            st.phase1(object(), 5)
        else:
            st.phase3(sys_, 5)                            # no latent space yet
    assert not (tmp_path / "s" / "run.db").exists()


def test_rollout_json_is_one_line_on_stdout():
    p = subprocess.run([sys.executable, "-m", "latentune.cli", "rollout", "--steps", "20",
                        "--json"], capture_output=True, text=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert p.returncode == 0, p.stderr
    assert len(p.stdout.strip().splitlines()) == 1
    assert json.loads(p.stdout)["steps"] == 20


@pytest.mark.parametrize("spec", ["nosuch", "missing.yaml"])
def test_robot_check_reports_a_bad_spec(capsys, spec):
    code, out, err = run_cli(capsys, "robot", "check", spec, "--no-sim")
    assert code == 2 and "Traceback" not in err + out and spec in out


@pytest.mark.parametrize("argv", [["robot", "init", "/nonexistent.urdf"], ["robot"],
                                  ["robot", "init"], ["robot", "check", "a1", "--bogus"]],
                         ids=lambda a: " ".join(a))
def test_robot_commands_reject_bad_input(capsys, argv):
    assert_one_line(capsys, *argv)


def test_robot_init_keeps_an_existing_file(capsys, tmp_path):
    f = tmp_path / "spec.yaml"
    f.write_text("keep me")
    assert_one_line(capsys, "robot", "init", "x.urdf", "--out", f)
    assert f.read_text() == "keep me"
