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
import warnings
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.cli import main
from latentune.errors import LatentuneError, ParamsError, StoreError, UsageError
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


def assert_one_line(capsys, *argv: str, expect: str) -> str:
    """Run the CLI in-process; assert exit 2 and one ``latentune: error:`` line holding
    ``expect`` (which error it is), no traceback; return the line."""
    code, out, err = run_cli(capsys, *argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (argv, code, err)
    assert len(lines) == 1 and lines[0].startswith("latentune: error:"), (argv, err)
    assert "Traceback" not in err
    assert expect in lines[0], (argv, expect, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A tiny finished tune run (serial) and a copy made per test that may damage it."""
    out = tmp_path_factory.mktemp("bad") / "run"
    assert main(["tune", *TINY, "--out", str(out), "--phase1-evals", "10", "--phase3-evals", "4",
                 "--backend", "serial", "--vae-epochs", "20"]) == 0
    return out


def test_a_run_of_another_task_says_which_flags_give_the_stored_one(capsys, copy_run):
    """``train-vae --out RUN`` after ``phase1 --task jump --steps 50 --out RUN`` (the README's
    "phases one at a time", with a flag left out) said "holds a run of another system
    (task.gait: stored 'jump', given 'trot'; task.steps: …)": the store's keys, not what to
    type. The line ends with the flags that give the stored task."""
    line = assert_one_line(capsys, "train-vae", "--out", copy_run, "--task", "jump",
                           expect="holds a run of another system (task.gait: stored 'trot', "
                                  "given 'jump'; task.steps: stored 150, given 5000)")
    assert line.endswith(": pass --task trot --steps 150 to go on with it"), line
    line = assert_one_line(capsys, "phase1", "--robot", "b1", "--terrain", "hills", "--v-des",
                           "0.3", "--out", copy_run, "--resume", expect="another system")
    assert line.endswith(": pass --robot a1 --terrain flat --steps 150 --v-des 0.5 to go on "
                         "with it"), line



def test_the_v_des_a_run_of_another_task_names_gives_the_stored_one(capsys, tmp_path):
    """``phase1 --v-des 0.1234567`` resumed without it said "pass --v-des 0.123457 to go on
    with it" (six digits), and that flag was refused again as another system: the flag
    given now holds the stored velocity as it is."""
    out = tmp_path / "run"
    tiny = ["--steps", "20", "--quiet", "--backend", "serial", "--out", str(out)]
    assert main(["phase1", *tiny, "--v-des", "0.1234567", "--phase1-evals", "2"]) == 0
    line = assert_one_line(capsys, "phase1", *tiny, "--phase1-evals", "3", "--resume",
                           expect="another system")
    assert line.endswith(": pass --v-des 0.1234567 to go on with it"), line
    assert main(["phase1", *tiny, "--v-des", "0.1234567", "--phase1-evals", "3",
                 "--resume"]) == 0


def test_a_run_of_another_reality_says_which_reality_gives_the_stored_one(capsys, copy_run):
    """``phase1 --reality heavy --resume`` on a run made without --reality said "(task.reality:
    stored None, given {'name': 'heavy', 'mass_scale': 1.15, 'payload_...)" and no flag to
    type; it now ends with the --reality preset that gives the stored one (none: a profile
    no preset gives)."""
    from latentune.pipeline.manifest import task_flags
    from latentune.sim.reality import Reality
    from latentune.wording import command_line_words

    line = assert_one_line(capsys, "phase1", *TINY, "--reality", "heavy", "--out", copy_run,
                           "--resume", expect="task.reality: stored None")
    assert line.endswith(": pass --reality nominal to go on with it"), line
    task = {"robot": "a1", "steps": 150}
    heavy = Reality.load("heavy").to_dict()
    stored = {"kind": "task", "task": {**task, "reality": heavy}}
    given = {"kind": "task", "task": {**task, "steps": 20, "reality": heavy}}
    with command_line_words():
        assert task_flags(stored, {"kind": "task", "task": task}) == "--reality heavy"
        assert task_flags(stored, given) == "--steps 150"
    assert task_flags(stored, {"kind": "task", "task": task}) == "reality='heavy'"
    other = {"kind": "task", "task": {**task, "reality": {**heavy, "mass_scale": 1.3}}}
    assert task_flags(other, {"kind": "task", "task": task}) is None



def test_a_system_given_to_a_robot_run_says_to_leave_it_out(capsys, copy_run):
    """``report RUN --system M:F`` (and ``ask RUN --system M:F``) of a built-in robot's run said
    "holds a run of another system (args: stored None, given {}; kind: stored 'task', given
    'plugin'; space: …)", the store's keys; it now names the run's robot and what to do."""
    for argv in (("report", copy_run, "--no-sim"), ("ask", copy_run)):
        line = assert_one_line(capsys, *argv, "--system", "examples.toy_plant:make_system",
                               expect="holds a run of the built-in robot a1 (trot)")
        assert line.endswith("not of a --system: leave --system (and --system-arg) out"), line


@pytest.fixture
def copy_run(run_dir, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(run_dir, dst)
    return dst


# ---------------------------------------------------------------------------- arguments
RUN_CMDS = ("tune", "phase1", "train-vae", "phase3")
BAD_TASK_ARGS = [  # (flags, which error)
    (["--robot", "nosuch"], "unknown robot 'nosuch'"),
    (["--robot", "missing.yaml"], "robot spec file not found: missing.yaml"),
    (["--robot", ""], "--robot is empty"), (["--task", " "], "--task is empty"),
    (["--task", "gallop"], "unknown task 'gallop'"),
    (["--terrain", "ice"], "unknown terrain 'ice'"), (["--actor", "pid"], "unknown actor 'pid'"),
    (["--steps", "0"], "--steps must be >= 1, got 0"),
    (["--steps", "-5"], "--steps must be >= 1, got -5"),
    (["--steps", "x"], "argument --steps: invalid int value: 'x'"),
    (["--steps", "1" + "0" * 12],
     "--steps must be at most 10,000,000 (10,000 s at 1 kHz), got 1" + "0" * 12),
    (["--v-des", "nan"], "--v-des must be finite, got nan"),
    (["--v-des", "inf"], "--v-des must be finite, got inf"),
    (["--v-des", "9"], "--v-des must be a velocity of at most 3 m/s in size, got 9"),
    (["--v-des", "-1e308"], "--v-des must be a velocity of at most 3 m/s in size, got -1e+308"),
    (["--seed", "-1"], "--seed must be in [0, 2**63), got -1"),
    (["--seed", str(2 ** 63)], f"--seed must be in [0, 2**63), got {2 ** 63}"),
    (["--seed", "1.5"], "--seed must be an integer, got '1.5'"),
    (["--reality", "nope"], "unknown reality 'nope'"),
    (["--reality", "missing.yaml"], "unknown reality 'missing.yaml'"),
    (["--engine", "ode"], "argument --engine: invalid choice: 'ode'"),
]
BAD_RUN_ARGS = [
    (["--phase1-evals", "0"], "--phase1-evals must be >= 1, got 0"),
    (["--phase1-eval", "10"], "unrecognized arguments: --phase1-eval 10"),   # no abbreviations
    (["--phase3-evals", "-1"], "--phase3-evals must be >= 1, got -1"),
    (["--workers", "0"], "--workers must be >= 1, got 0"),
    # a typo's pool: a traceback from the semaphore (OverflowError), or thousands of processes
    (["--workers", "99999999999999999999"],
     "--workers must be at most 4096 (one process or Ray actor each), got 99999999999999999999"),
    (["--latent-dim", "0"], "--latent-dim must be >= 1, got 0"),
    (["--latent-dim", "50"], "--latent-dim 50: the latent space of a 25-dim θ needs a size in "
                             "[1, 24]"),
    (["--regions", "0"], "--regions must be in [1, 100], got 0"),
    (["--regions", "101"], "--regions must be in [1, 100], got 101"),
    (["--batch-size", "0"], "--batch-size must be >= 1, got 0"),
    (["--vae-epochs", "0"], "--vae-epochs must be >= 1, got 0"),
    (["--max-fall-prob", "0"], "--max-fall-prob must be in (0, 1], got 0.0"),
    (["--max-fall-prob", "1.5"], "--max-fall-prob must be in (0, 1], got 1.5"),
    (["--max-fall-prob", "nan"], "--max-fall-prob must be in (0, 1], got nan"),
    (["--backend", "gpu"], "argument --backend: invalid choice: 'gpu'"),
    (["--method", "adam"], "argument --method: invalid choice: 'adam'"),
    (["--ray-address", "1.2.3.4:6379"], "--ray-address needs --backend ray"),
    (["--system-arg", "k=v"], "--system-arg needs --system"),
    (["--system", "a:b", "--robot", "a1"], "--system replaces --robot/--task"),
    (["--system", "a:b", "--reality", "heavy"], "--system replaces --robot/--task"),
    (["--system", "nosuchmod:make"], "--system nosuchmod:make: cannot import nosuchmod"),
    (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
    # --out "$OUT" with OUT unset: the run was written into the current directory
    (["--out", ""], "the run directory is empty"),
    (["-v", "--quiet"], "argument --quiet: not allowed with argument -v/--verbose"),
]


def _ids(case: tuple) -> str:
    return " ".join(case[0]) or "nothing"


@pytest.mark.parametrize("cmd", RUN_CMDS)
@pytest.mark.parametrize("bad, expect", BAD_TASK_ARGS + BAD_RUN_ARGS,
                         ids=[_ids(c) for c in BAD_TASK_ARGS + BAD_RUN_ARGS])
def test_run_commands_reject_bad_arguments(capsys, tmp_path, cmd, bad, expect):
    """Every flag is checked before anything is run or stored (the run directory is new)."""
    argv = [cmd, "--out", tmp_path / "r", "--backend", "serial", *bad]
    assert_one_line(capsys, *argv, expect=expect)
    assert not (tmp_path / "r" / "run.db").exists()


def test_phase1_fall_prior_is_checked_before_any_trial(capsys, tmp_path):
    base = ["phase1", "--out", tmp_path / "r", "--backend", "serial"]
    assert_one_line(capsys, *base, "--fall-prior", tmp_path,
                    expect="--fall-prior needs --max-fall-prob")
    assert_one_line(capsys, *base, "--fall-prior", tmp_path / "nope", "--max-fall-prob", "0.5",
                    expect="--fall-prior: no run store in")
    assert not (tmp_path / "r" / "run.db").exists()


@pytest.mark.parametrize("cmd", ["tune", "phase3"])
@pytest.mark.parametrize("bad, expect", [
    (["--handover", "size=3"], "--handover size=3: expected patience=X,tol=X,length=X"),
    (["--handover", "patience=a"], "--handover patience=a: patience must be an integer, got 'a'"),
    (["--handover", "patience=1.5"], "--handover patience=1.5: patience must be an integer, got '1.5'"),
    (["--handover", "tol=x"], "--handover tol=x: tol must be a number, got 'x'"),
    (["--handover", "patience=2,tol=0.1,patience=3"],
     "--handover patience=2,tol=0.1,patience=3: patience given twice (2, 3)"),
    (["--handover", "tol=2"], "--handover tol=2: handover tol must be in [0, 1)"),
    (["--handover", "length=0"], "--handover length=0: handover length must be in (0, 1.6]"),
    (["--handover", "patience"], "--handover patience: expected patience=X,tol=X,length=X"),
], ids=lambda b: " ".join(b) if isinstance(b, list) else "")
def test_bad_handover_options(capsys, tmp_path, cmd, bad, expect):
    argv = [cmd, "--out", tmp_path / "r", "--quiet", "--backend", "serial", *bad]
    assert_one_line(capsys, *argv, expect=expect)
    assert not (tmp_path / "r" / "run.db").exists()


ROLLOUT_ARGS = BAD_TASK_ARGS + [
    (["--params", "missing.json"], "params file not found: missing.json"),
    (["--params", ""], "--params is empty: give a file name, or leave --params out"),
    (["--params", " ", "--system", "x:y"],
     "--params is empty: give a file name, or leave --params out"),
    # each names its flag (with --gif and --plot both given, which one is wrong)
    (["--gif", "/nonexistent/dir/x.gif"],
     "--gif /nonexistent/dir/x.gif: directory /nonexistent/dir does not exist (create it first)"),
    (["--gif", "."], "--gif . is a directory: give a file name in it"),
    (["--gif", "x.png"], "--gif x.png: the file name must end in .gif"),
    (["--plot", "x.txt"], "--plot x.txt: the file name must end in .png or .pdf or .svg"),
    (["--plot", "/nonexistent/x.png"],
     "--plot /nonexistent/x.png: directory /nonexistent does not exist"),
    (["--json", "x"], "unrecognized arguments: x"),
    (["--jso"], "unrecognized arguments: --jso"),
    (["--system", "nosuchmod:make"], "--system nosuchmod:make: cannot import nosuchmod"),
    (["--system", "nosuchmod"], "--system must be module:factory, got 'nosuchmod'"),
]


@pytest.mark.parametrize("bad, expect", ROLLOUT_ARGS, ids=[_ids(c) for c in ROLLOUT_ARGS])
def test_rollout_rejects_bad_arguments(capsys, bad, expect):
    assert_one_line(capsys, "rollout", *bad, expect=expect)


def test_rollout_refuses_a_plot_or_gif_it_could_not_write_before_the_rollout(capsys, tmp_path):
    """A file among the parents was 'output directory does not exist'; a path that cannot be
    written was a traceback after the rollout; an empty --plot/--gif was ignored (no file)."""
    afile = tmp_path / "f"
    afile.write_text("")
    for flag, path, expect in (
            ("--plot", afile / "x.png", f"--plot {afile / 'x.png'}: {afile} is a file, not a directory"),
            ("--gif", "", "--gif is empty: give a file name, or leave --gif out"),
            ("--plot", " ", "--plot is empty: give a file name, or leave --plot out"),
            ("--plot", "/proc/x.png", "--plot /proc/x.png cannot be written"),
            ("--gif", "/proc/x.gif", "--gif /proc/x.gif cannot be written")):
        assert_one_line(capsys, "rollout", "--steps", "5", flag, path, expect=expect)
    ok = tmp_path / "kept.png"          # an existing file passes the check, then is rewritten
    ok.write_bytes(b"old")
    from latentune.cli import main
    assert main(["rollout", "--steps", "5", "--plot", str(ok)]) == 0 and ok.read_bytes() != b"old"


@pytest.mark.parametrize("argv, expect", [
    (["--system", "x:y", "--gif", ""], "--gif is for a built-in robot"),
    (["--gif", "", "--robot", "nosuch"], "unknown robot 'nosuch'"),
    (["--gif", "", "--seed", "3"], "--seed changes nothing here"),
    (["--plot", "", "--gif", "x.txt"], "--gif x.txt: the file name must end in .gif")])
def test_an_empty_plot_or_gif_is_not_the_first_of_several_faults(capsys, argv, expect):
    """rollout checks an empty --gif/--plot with the files it writes, after the robot, the
    system, the seed and --gif's suffix (a twin of argtypes.given, which would refuse it while
    the command line is parsed, before any of these): the first error of a command line with
    several faults is the one it was."""
    assert_one_line(capsys, "rollout", *argv, expect=expect)


def test_rollout_refuses_a_seed_that_changes_nothing(capsys, tmp_path):
    """--seed seeds the hills and a reality's noise and pushes: on flat ground without them
    every seed gave the same rollout, and a sweep over seeds repeated one rollout unawares."""
    assert_one_line(capsys, "rollout", "--steps", "5", "--seed", "3",
                    expect="--seed changes nothing here")
    assert_one_line(capsys, "rollout", "--steps", "5", "--seed", "3", "--reality", "heavy",
                    expect="--seed changes nothing here")
    from latentune.cli import main
    for extra in (["--terrain", "hills"], ["--reality", "laggy"], ["--reality", "hard"], []):
        seed = ["--seed", "3"] if extra else []
        assert main(["rollout", "--steps", "5", *seed, *extra]) == 0, extra


def test_a_params_file_of_another_system_says_how_many_names_and_whose(capsys, tmp_path):
    """A --params file of another system (its best.json, 24 names none of which A1 has) said
    "unknown parameter name(s): k0, k1, k2, k3, k4": five of them, as if that were all, and
    nothing of the names A1 takes. The line counts the rest and starts the system's list."""
    f = tmp_path / "other.json"
    f.write_text(json.dumps({f"k{i}": 0.1 for i in range(24)}))
    line = assert_one_line(capsys, "rollout", "--steps", "10", "--params", f,
                           expect="unknown parameter name(s): k0, k1, k2, k3, k4 and 19 more")
    assert "(this system's: Q_roll, Q_pitch, Q_yaw, " in line and "25 in all)" in line, line


@pytest.mark.parametrize("content, expect", [
    ("not json", "is not valid JSON"),
    ("[0.5]", "expected 25 normalized parameters, got shape (1,)"),
    ("[0.5, 0.5]", "expected 25 normalized parameters, got shape (2,)"),
    (json.dumps([float("nan")] * 25), "parameters contain NaN or inf"),
    (json.dumps([2.0] * 25), "normalized parameter Q_roll = 2 is outside [0, 1]"),
    (json.dumps([True] * 25), "a params list must hold numbers only"),
    (json.dumps({"nosuch": 1.0}), "unknown parameter name(s): nosuch"),
    (json.dumps({"Q_roll ": 1.0}), "unknown parameter name(s): 'Q_roll ' (this"),
    (json.dumps({"Q_\nroll": 1.0}), "unknown parameter name(s): 'Q_\\nroll' (this"),
    (json.dumps({"Q_\troll": 1.0}), "unknown parameter name(s): 'Q_\\troll' (this"),
    ('{"Q_roll": 1.0, "Q_pitch": 1, "Q_roll": 2.0}', "names Q_roll twice (1.0, then 2.0)"),
    (json.dumps({"Q_roll": -1.0}), "parameter Q_roll = -1 is outside"),
    (json.dumps({"Q_roll": "a"}), "parameter Q_roll must be a finite number, got 'a'"),
    ("3", "params must be a JSON list of normalized values or an object of physical values"),
    ("null", "params must be a JSON list of normalized values or an object of physical values"),
    ('{"Q_roll": 1' + "0" * 400 + "}", "parameter Q_roll must be a finite number, got 1000"),
    ("[1" + "0" * 400 + "," + ",".join(["0.5"] * 24) + "]", "numbers a float can hold"),
])
def test_rollout_rejects_bad_params_files(capsys, tmp_path, content, expect):
    """Each names the file (a wrong list said 'expected 25 normalized parameters, got shape
    (2,)' alone, with --params and ask --start's file both in mind)."""
    f = tmp_path / "p.json"
    f.write_text(content)
    line = assert_one_line(capsys, "rollout", "--steps", "10", "--params", f, expect=expect)
    assert f"params file {f}" in line, line


def test_rollout_reads_a_params_file_with_a_byte_order_mark(capsys, tmp_path):
    """A params file saved as UTF-8 with a byte-order mark (Windows Notepad, PowerShell's
    ``Out-File -Encoding utf8``) was 'not valid JSON (Unexpected UTF-8 BOM ...)'; it is read
    as the same file without the mark."""
    from latentune.task import Task

    f = tmp_path / "p.json"
    f.write_bytes(b"\xef\xbb\xbf" + json.dumps({"Q_roll": 1.0}).encode())
    theta = Task(steps=10).space.load(f)
    assert Task(steps=10).space.as_dict(theta)["Q_roll"] == pytest.approx(1.0)
    code, _, err = run_cli(capsys, "rollout", "--steps", "10", "--params", str(f))
    assert code == 0, err


@pytest.mark.parametrize("bad, expect", [
    (["--robot", "go2"], "unknown robot 'go2' for the paper's studies"),
    (["--scale", "0"], "--scale must be a finite number > 0, got 0"),
    (["--scale", "-1"], "--scale must be a finite number > 0, got -1"),
    (["--scale", "nan"], "--scale must be a finite number > 0, got nan"),
    (["--scale", "x"], "--scale must be a number, got 'x'"),
    (["--workers", "0"], "--workers must be >= 1, got 0"),
    (["--steps", "0"], "--steps must be >= 1, got 0"),
    (["--seed", "-3"], "--seed must be in [0, 2**63), got -3"),
    (["--v-des", "nan"], "--v-des must be finite, got nan"),
    (["--phase1-evals", "0"], "--phase1-evals must be >= 1, got 0"),
    (["--phase3-evals", "-1"], "--phase3-evals must be >= 1, got -1"),
    (["--report-only"], "holds no paper run (no paper.json)"),
], ids=lambda b: " ".join(b) if isinstance(b, list) else "")
def test_paper_rejects_bad_arguments(capsys, tmp_path, bad, expect):
    """Each bad flag is one line naming it (``--phase1-evals 0`` said "budgets must be >= 1",
    and ``bench --n 0`` "--steps and --n must be >= 1", naming no flag or both)."""
    assert_one_line(capsys, "paper", "--out", tmp_path / "p", "--quiet", *bad, expect=expect)


@pytest.mark.parametrize("bad, expect", [
    (["--timeout", "-1"], "--timeout must be > 0, got -1.0"),
    (["--timeout", "0"], "--timeout must be > 0, got 0.0"),
    (["--steps", "0"], "--steps must be >= 1, got 0"), (["--n", "0"], "--n must be >= 1, got 0"),
    (["--steps", "1" + "0" * 12], "--steps must be at most 10,000,000, got 1" + "0" * 12),
    (["--n", "x"], "argument --n: invalid int value: 'x'"),
], ids=lambda b: " ".join(b) if isinstance(b, list) else "")
def test_bench_rejects_bad_arguments(capsys, bad, expect):
    assert_one_line(capsys, "bench", *bad, expect=expect)


def test_paper_out_is_a_file(capsys, tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    """--out FILE said "cannot create --out FILE: File exists" (as if a directory were there);
    it says the path is a file (also for a file among its parents)."""
    assert_one_line(capsys, "paper", "--out", f, "--quiet",
                    expect=f"--out {f} is a file, not a directory")
    assert_one_line(capsys, "paper", "--out", f / "p", "--quiet",
                    expect=f"cannot create --out {f / 'p'}: {f} is a file, not a directory")


@pytest.mark.parametrize("argv, expect", [
    ([], "the following arguments are required: command"),
    (["nosuchcommand"], "argument command: invalid choice: 'nosuchcommand'"),
    (["tune"], "the following arguments are required: --out"),
    (["report"], "the following arguments are required: dir"),
    (["ask"], "the following arguments are required: dir"),
    (["tell"], "the following arguments are required: dir, id"),
    (["tell", "d"], "the following arguments are required: id"),
    (["status"], "the following arguments are required: dir"),
    (["rollout", "--steps"], "argument --steps: expected one argument"),
], ids=lambda a: " ".join(a) if isinstance(a, list) else "")
def test_parser_errors(capsys, argv, expect):
    assert_one_line(capsys, *argv, expect=expect)


# ---------------------------------------------------------------------------- run directories
def test_existing_run_is_not_rerun_or_changed(capsys, run_dir, tmp_path):
    before = dump(run_dir)
    cases = [
        (["phase1", *TINY, "--out", run_dir], "already holds 10 phase-1 evaluations; pass "
                                              "--resume"),                   # no --resume
        (["tune", *TINY, "--out", run_dir], "already holds 10 phase-1 evaluations"),
        (["phase3", *TINY, "--out", run_dir], "already holds 4 phase-3 evaluations"),
        (["tune", "--robot", "a1", "--task", "jump", "--steps", "150", "--quiet", "--out",
          run_dir, "--resume"], "gait: stored 'trot', given 'jump'"),         # another task
        (["tune", *TINY[:-1], "--terrain", "hills", "--quiet", "--out", run_dir, "--resume"],
         "terrain: stored 'flat', given 'hills'"),
        (["tune", *TINY, "--seed", "5", "--out", run_dir, "--resume"],
         "--seed 0 (stored), not --seed 5 (leave --seed out"),                 # another seed
        (["tune", *TINY, "--method", "cma", "--out", run_dir, "--resume"],
         "--method turbo (stored), not --method cma"),                          # another method
        (["tune", *TINY, "--batch-size", "7", "--out", run_dir, "--resume"],
         "--batch-size 4 (stored), not --batch-size 7"),
        (["phase1", "--robot", "b1", "--steps", "150", "--quiet", "--out", run_dir, "--resume"],
         "robot: stored 'a1', given 'b1'"),
        (["phase1", "--robot", "a1", "--steps", "151", "--quiet", "--out", run_dir, "--resume"],
         "steps: stored 150, given 151"),
        (["phase3", *TINY, "--out", run_dir, "--resume", "--vae", tmp_path / "nope"],
         f"run directory {tmp_path / 'nope'} does not exist"),
        (["train-vae", "--robot", "b1", "--steps", "150", "--quiet", "--out", run_dir],
         "robot: stored 'a1', given 'b1'"),
        (["phase3", *TINY, "--out", run_dir, "--resume", "--latent-dim", "3"],
         f"--latent-dim 3: the latent space of {run_dir} has size 10"),
        (["tune", *TINY, "--out", run_dir, "--resume", "--system", "x:y"],
         "--system replaces --robot"),
        (["tune", "--system", "x:y", "--out", run_dir, "--resume"],
         f"{run_dir} holds a run of the built-in a1 trot task, not of --system x:y"),
        (["report", run_dir, "--no-sim", "--system-arg", "shift=1"],
         "--system-arg needs --system"),                                  # was ignored
    ]
    for argv, expect in cases:
        assert_one_line(capsys, *argv, expect=expect)
    assert dump(run_dir) == before


@pytest.mark.parametrize("cmd", ["report", "status"])
def test_missing_and_foreign_directories(capsys, tmp_path, cmd):
    nope = tmp_path / "nope"
    line = assert_one_line(capsys, cmd, nope, expect=f"no run store in {nope}")
    assert line == f"latentune: error: no run store in {nope}"   # report: as status, best, tell
    (tmp_path / "empty").mkdir()
    assert_one_line(capsys, cmd, tmp_path / "empty", expect=f"no run store in {tmp_path / 'empty'}")
    f = tmp_path / "file"
    f.write_text("x")
    assert_one_line(capsys, cmd, f, expect=f"{f} exists and is not a directory")
    db = tmp_path / "run" / "run.db"             # the store's file named for its directory
    db.parent.mkdir()
    db.write_bytes(b"")
    assert_one_line(capsys, cmd, db, expect=f"{db} is a file, not a run directory: give the "
                    f"run directory that holds it ({db.parent})")


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
    expect = {"random_bytes": "is not a latentune run store (not an SQLite file)",
              "empty_file": "is not a latentune run store (not an SQLite file)",
              "foreign_sqlite": "is not a latentune run store (missing tables)",
              "truncated": "is corrupt"}[damage]
    argv = {"report": ["report", copy_run], "status": ["status", copy_run],
            "resume": ["tune", *TINY, "--out", copy_run, "--resume", "--backend", "serial"],
            "phase3": ["phase3", *TINY, "--out", copy_run, "--resume", "--backend", "serial"],
            "ask": ["ask", copy_run], "tell": ["tell", copy_run, "1", "--cost", "1"]}[cmd]
    assert_one_line(capsys, *argv, expect=expect)
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
    expect = {"config": "meta entry 'config' is not valid JSON",
              "theta": "evaluation 3 of phase 1 is garbled",
              "deleted_row": "phase 1 indices are not contiguous (9 rows, max idx 9)",
              "duplicate_gap": "phase 3 indices are not contiguous (4 rows, max idx 99)"}[what]
    assert_one_line(capsys, "tune", *TINY, "--out", copy_run, "--resume", "--backend", "serial",
                    "--phase1-evals", "12", "--phase3-evals", "6", expect=expect)
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
    expect = ("no latent space at" if damage == "delete" else
              f"corrupt latent space {copy_run / 'vae'}")
    assert_one_line(capsys, cmd, *TINY, "--out", copy_run, "--resume", "--backend", "serial",
                    *(["--phase1-evals", "10"] if cmd == "tune" else []), "--phase3-evals", "6",
                    expect=expect)
    assert dump(copy_run)[0] == before


def test_phase3_with_a_bad_other_run(capsys, tmp_path, run_dir):
    other = tmp_path / "vae12"
    other.mkdir()
    lt.LatentSpace.train(np.random.default_rng(0).random((20, 12)), seed=0, epochs=2).save(
        other / "vae")
    for vae, expect in ((other, "maps to 12-dim θ, but the system has 25-dim θ"),
                        (tmp_path / "nope", f"run directory {tmp_path / 'nope'} does not exist"),
                        (tmp_path, f"no latent space at {tmp_path}")):
        assert_one_line(capsys, "phase3", *TINY, "--out", tmp_path / "x", "--vae", vae,
                        expect=expect)
        assert not (tmp_path / "x").exists()
    # a kino-dynamic task with the convex VAE
    assert_one_line(capsys, "phase3", "--robot", "solo12", "--actor", "kinodynamic", "--steps",
                    "50", "--quiet", "--out", tmp_path / "y", "--vae", run_dir,
                    expect="maps to 25-dim θ, but the system has 77-dim θ")


def test_a_second_writer_is_refused_with_who_holds_the_lock(capsys, copy_run, monkeypatch):
    try:                                  # ask/tell wait a bounded time for the writer: 1 s here
        import latentune.pipeline.asktell as asktell
        monkeypatch.setattr(asktell, "WAIT_S", 1.0)
    except (ImportError, AttributeError):
        pass
    with lt.Study(copy_run).writing():
        assert_one_line(capsys, "tune", *TINY, "--out", copy_run, "--resume",
                        "--backend", "serial", "--phase1-evals", "12",
                        expect=f"{copy_run} is being written by pid {os.getpid()}")
        assert_one_line(capsys, "tell", copy_run, "1", "--cost", "1",
                        expect=f"{copy_run} is being written by pid {os.getpid()}")


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


ASKTELL_CASES = [
    (["tell", "{d}", "99", "--cost", "1"], "no suggestion with id 99"),
    (["tell", "{d}", "x", "--cost", "1"], "a suggestion id is an integer, got 'x'"),
    (["tell", "{d}", "1"], "tell needs --cost C, or --failed"),
    # a note alone: the same line, which did not say how to amend only the note
    (["tell", "{d}", "1", "--amend", "--note", "slipped"],
     "tell --amend needs the corrected result, --cost C or --failed (to change only the note, "
     "give the told result again with --note)"),
    (["tell", "{d}", "1", "--cost", "nan"], "non-finite cost (nan)"),
    (["tell", "{d}", "1", "--cost", "inf"], "non-finite cost (inf)"),
    (["tell", "{d}", "1", "--cost", "abc"], "argument --cost: invalid float value: 'abc'"),
    (["tell", "{d}", "-1", "--cost", "1"], "no suggestion with id -1"),
    (["tell", "{d}", "1.5", "--cost", "1"], "a suggestion id is an integer, got '1.5'"),
    # beyond SQLite's integers: a traceback (OverflowError)
    (["tell", "{d}", str(2 ** 70), "--cost", "1"], f"no suggestion with id {2 ** 70}"),
    (["tell", "{d}", str(2 ** 63), "--amend", "--cost", "1"], f"no suggestion with id {2 ** 63}"),
    (["release", "{d}", str(-2 ** 70)], f"no suggestion with id {-2 ** 70}"),
    # a budget grown past the store's integers was taken
    (["ask", "{d}", "--budget", str(2 ** 70)],
     f"--budget must be an integer >= 1 and below 2**63, got {2 ** 70}"),
    (["ask", "{d}", "--n", "0"], "--n must be >= 1, got 0"),
    (["ask", "{d}", "--n", "-2"], "--n must be >= 1, got -2"),
    (["ask", "{d}", "--phase", "2"], "argument --phase: invalid choice: 2"),
    (["ask", "{d}", "--phase", "3"], "runs with --phase 1 (stored), not --phase 3"),
    (["ask", "{d}", "--seed", "5"], "runs with --seed 0 (stored), not --seed 5"),
    (["ask", "{d}", "--method", "nope"], "argument --method: invalid choice: 'nope'"),
    (["ask", "{d}", "--robot", "a1"], "holds a run of another system"),
    (["ask", "{d}", "--space", "{d}/missing.yaml"], "--space: file not found:"),
    (["ask", "{d}", "--jso"], "unrecognized arguments: --jso"),
    (["tell", "{d}/nope", "1", "--cost", "1"], "no run store in {d}/nope"),
    (["status", "{d}/nope"], "no run store in {d}/nope"),
    (["ask", " ", "--n", "1"], "the run directory is empty"),
    (["status", ""], "the run directory is empty"),
    (["report", ""], "the run directory is empty"),
]


@pytest.mark.parametrize("argv, expect", ASKTELL_CASES,
                         ids=[" ".join(c[0]).replace("{d}", "D") for c in ASKTELL_CASES])
def test_ask_tell_bad_input(capsys, asktell, argv, expect):
    d, _ = asktell
    before = dump(d)
    assert_one_line(capsys, *[a.replace("{d}", str(d)) for a in argv],
                    expect=expect.replace("{d}", str(d)))
    assert dump(d) == before


def test_a_first_ask_without_a_space_names_the_flags_and_the_api_its_arguments(capsys, tmp_path):
    """A first ask with neither system nor space: the command names its flags and leaves no
    directory; the API's refusal names no command-line flag (it named them to Python users)."""
    import latentune as lt
    from latentune.errors import StoreError

    d = tmp_path / "r"
    assert_one_line(capsys, "ask", str(d),
                    expect="the first ask needs a system or a space (--system, --robot or "
                           "--space FILE)")
    assert not d.exists()
    with pytest.raises(StoreError, match=r"the first ask needs a system or a space$"):
        lt.Study(d).ask(1)


@pytest.mark.parametrize("content, expect", [
    ("names: [a]\nlow: [1]\nhigh: [0]\n", "ParameterSpace needs low < high"),
    ("names: [a, a]\nlow: [0, 0]\nhigh: [1, 1]\n", "ParameterSpace names must be distinct"),
    ("low: [0]\nhigh: [1]\n", "a parameter space needs the keys names, low, high"),
    ("[1, 2]", "a parameter space needs the keys names, low, high"),
    ("names: [a]\nlow: [0]\nhigh: [1]\nlog: [true]\n", "low > 0 on log entries"),
    ("names: [a]\nlow: [0]\nhigh: [1]\nmanual: [5]\n", "manual a = 5 is outside [0, 1]"),
    (": : :", "is not valid YAML/JSON"),
    ("names: [a, b\nlow: [0, 0]\n",
     "is not valid YAML/JSON (expected ',' or ']', but got ':' at line 2, column 4)"),
    ("names: [a]\nlow: [1]\nhigh: [2]\nmanul: [1.5]\n", "not manul"),
    ("names: [a]\nlow: [1]\nhigh: [2]\nlog: ['false']\n", "log entries must be true or false"),
    # true was taken as 1 (and the error spoke of log entries)
    ("names: [a, b]\nlow: [true, 0]\nhigh: [1, 1]\n", "low must be numbers, not true/false"),
])
def test_ask_rejects_bad_space_files(capsys, tmp_path, content, expect):
    f = tmp_path / "s.yaml"
    f.write_text(content)
    assert_one_line(capsys, "ask", tmp_path / "d", "--space", f, expect=expect)
    assert not (tmp_path / "d" / "run.db").exists()


def test_space_file_reads_exponent_numbers(capsys, tmp_path):
    """PyYAML reads 1e-4 and 1.0e6 (no dot, or no exponent sign) as text: a --space file
    with such bounds was refused ('low must be numbers, not text'); they are numbers."""
    f = tmp_path / "s.yaml"
    f.write_text("names: [kp, ki]\nlow: [1e-4, -1E3]\nhigh: [1.0e6, 5e+2]\n"
                 "log: [true, false]\nmanual: [1e-2, 0]\n")
    assert main(["ask", str(tmp_path / "d"), "--space", str(f)]) == 0
    capsys.readouterr()
    with lt.Study(tmp_path / "d") as s:
        sp = s.space()
    assert list(sp.lower) == [1e-4, -1e3] and list(sp.upper) == [1e6, 500.0]
    assert list(sp.manual_physical) == [1e-2, 0.0]
    assert_one_line(capsys, "ask", tmp_path / "e", "--space", f.with_name("x.yaml"),
                    expect="file not found")
    f.write_text("names: [a]\nlow: [1e-4x]\nhigh: [1]\n")     # other text is still refused
    assert_one_line(capsys, "ask", tmp_path / "e", "--space", f, expect="not text")


def test_a_told_suggestion_cannot_be_told_again(capsys, asktell):
    d, _ = asktell
    assert main(["tell", str(d), "1", "--cost", "0.5"]) == 0
    capsys.readouterr()
    before = dump(d)
    assert_one_line(capsys, "tell", d, "1", "--cost", "0.4", expect="suggestion 1 was already told")
    assert_one_line(capsys, "tell", d, "1", "--cost", "0.4",
                    expect="That result stands; to replace it, tell it again with --amend")
    assert dump(d) == before


# ---------------------------------------------------------------------------- the Python API
@pytest.mark.parametrize("kw", [dict(robot=5), dict(robot="nosuch"), dict(gait="gallop"),
                                dict(terrain="mars"), dict(actor="pid"), dict(steps=0),
                                dict(steps=True), dict(steps=2.5), dict(seed=-1), dict(seed=1.7),
                                dict(seed=2 ** 63), dict(v_des=float("nan")), dict(v_des="fast"),
                                dict(v_des=(1, 2)), dict(v_des=True), dict(v_des="0.5")])
def test_task_rejects_bad_arguments(kw):
    with pytest.raises(LatentuneError):
        lt.Task(**kw)


def f(x):
    return float(np.sum(x ** 2))


@pytest.mark.parametrize("kw, expect", [
    (dict(bounds=[[0, 1e308], [-1e308, 1e308]]), r"bounds must lie within ±1e\+150.*\[0, 1\]"),
    (dict(bounds=[[0, 1e308]]), r"bounds must lie within ±1e\+150"),
    (dict(bounds=[[0, 1], [-1e200, 0]]), r"rescale dimension\(s\) \[1\]"),
    (dict(bounds=[[1, 0]]), r"lower < upper; violated in dimension\(s\) \[0\]"),
    (dict(bounds=[[0, 1], [2, 2]]), r"lower < upper; violated in dimension\(s\) \[1\]"),
    (dict(bounds=[[0, np.inf]]), r"bounds must be finite; not in dimension\(s\) \[0\]"),
    (dict(bounds=[[np.nan, 1]]), r"bounds must be finite"),
    (dict(bounds=[]), r"shape \(d, 2\)"), (dict(bounds="abc"), r"array of numbers"),
    (dict(bounds=[[0, 1]], budget=0), "budget must be an integer >= 1"),
    (dict(bounds=[[0, 1]], method="x"), "unknown method 'x'"),
    (dict(bounds=[[0, 1]], batch_size=0), "batch_size must be an integer >= 1"),
    (dict(bounds=[[0, 1]], seed=-1), "seed must be an integer >= 0"),
    (dict(bounds=[[0, 1]], x0=[2.0]), "x0 must lie inside bounds"),
    (dict(bounds=[[0, 1]], x0=[np.nan]), "x0 must be finite"),
])
def test_minimize_rejects_bad_arguments(kw, expect):
    calls = []
    with pytest.raises(ValueError, match=expect):
        lt.minimize(lambda x: calls.append(x) or f(x), **kw)
    assert not calls                                     # f is never evaluated


@pytest.mark.parametrize("value, expect", [
    (None, "returned NoneType None; expected a float cost"),
    ("1.5", "returned str '1.5'; expected a float cost"),
    (True, r"returned a bool \(True\)"),
    (np.array([1.0, 2.0]), r"returned an array of shape \(2,\); expected one float"),
    (np.array([1.0]), r"returned an array of shape \(1,\)"),
    (1 + 2j, "returned a complex number"),
    (10 ** 400, r"returned an integer too large for a float64 \(401 digits\)"),
], ids=["None", "str", "bool", "array", "array1", "complex", "hugeint"])
@pytest.mark.parametrize("method", ["turbo", "random"])
def test_minimize_refuses_a_function_that_returns_no_cost(value, expect, method):
    from latentune.system import CostError

    calls = []

    def fun(x):
        calls.append(x)
        return value

    with pytest.raises(CostError, match=expect) as info:
        lt.minimize(fun, [(0, 1)] * 3, method=method, budget=20, batch_size=4)
    assert isinstance(info.value, TypeError) and isinstance(info.value, ValueError)
    assert len(calls) == 1                              # stops at the first such value


@pytest.mark.parametrize("kw, expect", [
    (dict(method="random", foo=1), "method 'random' has no option foo"),
    (dict(method="turbo", n_regions=0), "method 'turbo': n_regions must be in"),
    (dict(method="cma", sigma0=-1), "sigma0 must be > 0"),
    (dict(method="sobol", seed=2 ** 64), "seed must be an integer >= 0 and <= "),
    (dict(method="x"), "unknown method 'x'"), (dict(budget=0), "budget must be"),
])
def test_minimize_refuses_bad_arguments_with_a_usage_error(kw, expect):
    """An option the method does not take raised the critic's TypeError, an option out of its
    domain and every argument check a bare ValueError, and seed 2**64 scipy's overflow from
    Sobol: each is one UsageError (a ValueError) now."""
    with pytest.raises(UsageError, match=expect):
        lt.minimize(lambda x: float(x.sum()), [(0, 1)] * 2, **{"budget": 4, **kw})


def test_minimize_callback_stops_on_a_numpy_true():
    res = lt.minimize(lambda x: float(x.sum()), [(0, 1)], method="random", budget=6,
                      batch_size=2, callback=lambda r: np.True_)
    assert res.nfev == 2 and res.message == "stopped by callback"
    res = lt.minimize(lambda x: float(x.sum()), [(0, 1)], method="random", budget=6,
                      batch_size=2, callback=lambda r: 1)          # not True: runs on
    assert res.nfev == 6


def test_minimize_callback_raising_stopiteration_stops_the_run():
    """SciPy's way to stop from a callback (``raise StopIteration``) escaped minimize as a bare
    StopIteration, the result lost (inside a generator: a RuntimeError); it stops the run now,
    as returning True does, and the result holds the points evaluated."""
    def stop(r: object) -> None:
        raise StopIteration

    res = lt.minimize(lambda x: float(x.sum()), [(0, 1)], method="random", budget=6,
                      batch_size=2, callback=stop)
    assert res.nfev == 2 and res.message == "stopped by callback" and res.x is not None


@pytest.mark.parametrize("value", [np.float32(0.5), np.int64(3), 7, np.array(0.25), float("nan"),
                                   float("inf")], ids=repr)
def test_minimize_takes_real_numbers(value):
    res = lt.minimize(lambda x: value, [(0, 1)] * 2, method="random", budget=4, batch_size=2)
    assert res.nfev == 4 and res.y.dtype == np.float64


@pytest.mark.parametrize("args", [
    (["a"], [0], [1], [True]), (["a"], [1], [0]), (["a", "a"], [0, 0], [1, 1]), ([], [], []),
    (["a"], [0, 1], [1]), (["a"], [0], [np.nan]), (["a"], [0], [1], None, [3.0]),
])
def test_parameter_space_rejects_bad_arguments(args):
    with pytest.raises(ValueError):
        lt.ParameterSpace(*args)


@pytest.mark.parametrize("args, expect", [
    ((None, [0], [1]), "names must be a list"), (("ab", [0, 0], [1, 1]), "names must be a list"),
    ((["a"], ["x"], [1]), "low must be numbers"),
    ((["a"], [-1.7e308], [1.7e308]), "a's range .* is too wide: its width overflows"),
    ((["a"], [1e-300], [1e300], [True]), "ratio overflows"),
    ((["a", "b", "a"], [0] * 3, [1] * 3), "'a' is given twice"),
    ((["a", "b"], [0, 2], [1, 1]), r"b: \[2, 1\]"),
    ((["", "b"], [0, 0], [1, 1]), "names must be text on one line, not blank .got ''."),
    ((["a", " "], [0, 0], [1, 1]), "not blank .got ' '."),
    ((["a\nb", "c"], [0, 0], [1, 1]), r"not blank .got 'a\\nb'."),
    ((["a\tb"], [0], [1]), "on one line"),
])
def test_parameter_space_errors_are_latentune_errors(args, expect):
    """A names string, None or a number, bounds that are not numbers and a range whose width
    overflows (which gave a space of inf physical values) raise one UsageError naming it. So
    does a blank name or one with a line break (``latentune ask`` printed "=0.5, b=0.5", or
    broke its one-line answer in two)."""
    with pytest.raises(UsageError, match=expect):
        lt.ParameterSpace(*args)


@pytest.mark.parametrize("kw, expect", [
    ({"low": [[0, 0]]}, "low must be a flat list of 2 entries .one per name., not nested"),
    ({"high": np.ones((2, 1))}, "high must be a flat list of 2 entries"),
    ({"low": [[0], [0]]}, "low must be a flat list"),
    ({"low": ["0", 0]}, "low must be numbers, not text: got \\['0', "),
    ({"high": np.array(["1", "1"])}, "high must be numbers, not text"),
    ({"manual": [0.5, "0.5"]}, "manual must be numbers, not text"),
    ({"log": [[0, 0]]}, "log must be a flat list"),
])
def test_parameter_space_refuses_nested_or_text_bounds(kw, expect):
    """``ParameterSpace(names, low=[[0, 0]], ...)`` was flattened and ``low=["0", 0]`` read as
    numbers, quietly. Each is now one UsageError naming the argument (from_dict too)."""
    args = {"names": ["a", "b"], "low": [0, 0], "high": [1, 1], **kw}
    with pytest.raises(UsageError, match=expect):
        lt.ParameterSpace(**args)
    with pytest.raises(UsageError, match=expect):
        lt.ParameterSpace.from_dict({k: np.asarray(v).tolist() for k, v in args.items()})
    assert lt.ParameterSpace(["a"], 0, 1).lower.tolist() == [0.0]     # one entry: a number


def test_a_parameter_space_reads_its_bounds_by_the_names_it_was_given():
    """``ParameterSpace(names, low, high)`` held its bounds as ``lower``/``upper`` only:
    ``space.low`` raised AttributeError. ``low``/``high`` are the same arrays, read-only
    (``lower``/``upper`` remain)."""
    sp = lt.ParameterSpace(["a", "b"], low=[0, 1], high=[2, 3])
    assert sp.low is sp.lower and sp.high is sp.upper
    assert sp.low.tolist() == [0.0, 1.0] and sp.high.tolist() == [2.0, 3.0]
    with pytest.raises(AttributeError):
        sp.low = np.zeros(2)


def test_a_stored_run_with_a_blank_name_still_opens(tmp_path):
    """A run recorded before blank names were refused (its space's names ``""`` and ``"b"``)
    still opens: its status and trials are read, the name as it was recorded."""
    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with lt.Study(tmp_path / "r") as st:
        (s,) = st.ask(space=sp)
        st.tell(s.id, 1.0)
    with RunStore(tmp_path / "r") as store:
        cfg = store.get_meta("config")
        cfg["space"]["names"] = ["", "b"]
        store.set_meta("config", cfg)
    st = lt.Study(tmp_path / "r")
    assert st.status()["phases"]["phase 1"]["n"] == 1
    assert list(st.trials()[0].params) == ["", "b"]
    with pytest.raises(UsageError, match="not blank"):
        lt.ParameterSpace.from_dict({"names": ["", "b"], "low": [0, 0], "high": [1, 1]})


def test_parameter_space_mappings_check_shapes(tmp_path):
    """to_physical broadcast a θ of the wrong length silently ([0.5] -> two values); to_unit
    raised numpy's broadcast error; parse of a non-string key and load of a deeply nested file
    raised TypeError / RecursionError."""
    sp = lt.ParameterSpace(["a", "b"], [1, -1], [100, 1], [True, False])
    for bad in ([0.5], [0.5] * 3, np.zeros((2, 3)), np.zeros((1, 2, 2))):
        with pytest.raises(ParamsError, match=r"shape \(2,\) or \(n, 2\)"):
            sp.to_physical(bad)
        with pytest.raises(ParamsError, match="shape"):
            sp.to_unit(bad)
    for u in ([0, 0], [1, 1], [0, 1], [[0, 1], [1, 0]]):
        assert np.allclose(sp.to_unit(sp.to_physical(u)), u)
    with pytest.raises(ParamsError, match="unknown parameter name"):
        sp.parse({1: 2.0})
    with pytest.raises(ParamsError, match=r"as_dict takes one θ of shape \(2,\)"):
        sp.as_dict([[0.5, 0.5]])                        # was float()'s TypeError
    for other in ({"names": ["a", "b"]}, {"names": ["a", "b"], "low": [1], "high": [2]}):
        assert "cannot be read" in sp.box_difference(other)      # was KeyError / IndexError
    assert sp.box_difference(sp.to_dict()) is None
    neg = lt.ParameterSpace(["a", "b"], [-3, 0.1], [-1, 10], [False, True])
    with warnings.catch_warnings():             # a negative linear upper bound: numpy's
        warnings.simplefilter("error")          # 'invalid value encountered in power'
        assert np.allclose(neg.to_physical([0.5, 0.5]), [-2, 1])
        assert np.allclose(neg.to_unit([-2, 1]), [0.5, 0.5])
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(ParamsError, match="nested too deeply"):
        sp.load(deep)


@pytest.mark.parametrize("kw", [dict(seed=-1), dict(seed=1.5), dict(workers=0), dict(backend="x"),
                                dict(batch_size=0), dict(ray_address="x:1"), dict(batch_size=2.5),
                                dict(batch_size="a"), dict(log="x"), dict(evaluator="x")])
def test_study_rejects_bad_arguments(tmp_path, kw):
    """(batch_size=2.5 was taken as 2, batch_size="a" raised int()'s ValueError; log="x" and
    evaluator="x" were taken and raised TypeError / AttributeError at their first use.)"""
    with pytest.raises(UsageError):
        lt.Study(tmp_path / "s", **kw)
    assert not (tmp_path / "s").exists()


def test_workers_with_the_serial_backend_are_refused(tmp_path, capsys):
    """(They ran one trial at a time without a word.) The command line's --backend serial
    alone takes one worker; a user's own evaluator brings its own workers."""
    with pytest.raises(UsageError, match="workers = 2 needs the process or ray backend"):
        lt.Study(tmp_path / "s", workers=2, backend="serial")
    with pytest.raises(UsageError, match="workers = 3 needs"):
        lt.Study(tmp_path / "s", workers=3)                 # the default backend is serial
    from latentune.pipeline.evaluators import SerialEvaluator

    assert lt.Study(tmp_path / "s", workers=2, evaluator=SerialEvaluator()).workers == 2
    # the command line says it in its flags (it said "workers = 2 needs the process or ray
    # backend", the API's words)
    assert_one_line(capsys, "phase1", "--out", tmp_path / "r", "--workers", "2", "--backend",
                    "serial", expect="--workers 2 needs --backend process or ray: serial runs "
                                     "one trial at a time, in this process")
    assert not (tmp_path / "s").exists() and not (tmp_path / "r" / "run.db").exists()


def test_study_refuses_a_path_that_is_not_one():
    with pytest.raises(UsageError, match="a run directory is a path, got NoneType"):
        lt.Study(None)


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


@pytest.mark.parametrize("method", ["cma", "random", "sobol"])
def test_regions_with_a_method_other_than_turbo_is_refused(capsys, tmp_path, method):
    """--regions is TuRBO-m's: with another method it was dropped without a word. The refusal
    named the API's arguments ("regions (trust regions) is an option of method turbo
    (TuRBO-m), not of cma (given regions = 3)"); it names the flags."""
    said = ("--regions (trust regions) is an option of --method turbo (TuRBO-m), not of "
            f"--method {method} (given --regions = 3)")
    assert_one_line(capsys, "phase1", *TINY, "--out",
                    tmp_path / "p1", "--backend", "serial", "--phase1-evals", "6", "--method",
                    method, "--regions", "3", expect=said)
    assert not (tmp_path / "p1" / "run.db").exists()
    assert_one_line(capsys, "ask", tmp_path / "a", *TINY, "--method", method, "--regions", "3",
                    expect=said)
    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])
    sys_ = lt.FunctionSystem(space, lambda th: float(np.sum((np.asarray(th) - 0.3) ** 2)))
    st = lt.Study(tmp_path / "s")
    st.phase1(sys_, 12)
    st.train_latent(2, epochs=20)
    before = dump(tmp_path / "s")
    with pytest.raises(LatentuneError, match=f"not of {method}"):
        st.phase3(sys_, 4, strategy="plain", method=method, regions=2)
    assert dump(tmp_path / "s") == before


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


@pytest.mark.parametrize("argv, expect", [
    (["robot", "init", "/nonexistent.urdf"], "URDF /nonexistent.urdf: cannot read"),
    # an internal name, robot_command, was named here; now the subcommands are
    (["robot"], "the following arguments are required: {check,init}"),
    (["robot", "chek", "a1"], "argument {check,init}: invalid choice: 'chek'"),
    (["robot", "init"], "the following arguments are required: urdf"),
    (["robot", "init", "x.urdf", "--name", " "], "the robot name must not be empty"),
    (["robot", "check", "a1", "--bogus"], "unrecognized arguments: --bogus"),
], ids=lambda a: " ".join(a) if isinstance(a, list) else "")
def test_robot_commands_reject_bad_input(capsys, argv, expect):
    assert_one_line(capsys, *argv, expect=expect)


def test_robot_init_keeps_an_existing_file(capsys, tmp_path):
    f = tmp_path / "spec.yaml"
    f.write_text("keep me")
    assert_one_line(capsys, "robot", "init", "x.urdf", "--out", f,
                    expect=f"--out {f} exists (not overwritten): delete it or give another --out")
    assert f.read_text() == "keep me"


@pytest.mark.parametrize("out, expect", [
    ("nodir/go1.yaml", "--out nodir/go1.yaml: directory {tmp}/nodir does not exist"),
    (".", "--out . is a directory: give a file name in it"),
    ("go1", "--out go1: the file name must end in .yaml or .yml"),
    ("/proc/go1.yaml", "--out /proc/go1.yaml cannot be written")])
def test_robot_init_refuses_an_out_it_cannot_write_before_reading_the_urdf(
        capsys, tmp_path, monkeypatch, out, expect):
    """``robot init --out`` into a missing directory said 'cannot write nodir/go1.yaml: No such
    file or directory' after reading the URDF, a directory '. exists (not overwritten)', and a
    name without .yaml was written (``--robot go1`` then read it as an unknown built-in name).
    Each is now refused as rollout's --gif/--plot are, before the URDF is read."""
    monkeypatch.chdir(tmp_path)
    assert_one_line(capsys, "robot", "init", "/nonexistent.urdf", "--out", out,
                    expect=expect.format(tmp=tmp_path))


def test_an_interrupt_after_tune_printed_its_table_exits_0(capsys, tmp_path, monkeypatch,
                                                           interrupt_in_close):
    """A Ctrl-C (or SIGTERM) that landed after ``tune`` finished and printed its table, while
    it closed its run, exited 130 ("interrupted") though the run was complete and stored: it
    exits 0. One that lands before the table is still 130, and the work is resumable."""
    import latentune.reporting.run_report as run_report

    hits = interrupt_in_close           # the signal lands while the finished run is closed
    out = tmp_path / "run"
    code, stdout, err = run_cli(capsys, "tune", *TINY, "--out", out, "--phase1-evals", "6",
                                "--phase3-evals", "2", "--backend", "serial",
                                "--vae-epochs", "5")
    assert hits and code == 0, (code, err)
    assert "| best path cost |" in stdout and "interrupted" not in err, (stdout, err)
    hits.append("done")                 # the next closes are not interrupted
    table = run_report.comparison_table

    def interrupted_table(store):       # the signal lands before the table: not done
        raise KeyboardInterrupt

    monkeypatch.setattr(run_report, "comparison_table", interrupted_table)
    code, _, err = run_cli(capsys, "tune", *TINY, "--out", out, "--phase1-evals", "6",
                           "--phase3-evals", "3", "--backend", "serial", "--resume")
    assert code == 130 and err.strip() == "latentune: error: interrupted; stored results are kept"
    monkeypatch.setattr(run_report, "comparison_table", table)


INTERRUPTED = "latentune: error: interrupted; stored results are kept"


def _external_run(tmp_path: Path, n_told: int = 0) -> tuple[Path, Path]:
    """A run of trials run elsewhere in a 4-parameter box (its --space file), ``n_told`` of
    them asked and told."""
    space = tmp_path / "space.json"
    space.write_text(json.dumps({"names": ["a", "b", "c", "d"], "low": [0] * 4,
                                 "high": [1] * 4}))
    d = tmp_path / "run"
    if n_told:
        with lt.Study(d) as st:
            for s in st.ask(n_told, space=lt.ParameterSpace.from_dict(
                    json.loads(space.read_text()))):
                st.tell(s.id, float(np.sum((np.asarray(list(s.params.values())) - 0.3) ** 2)))
    return d, space


def test_an_interrupt_after_ask_tell_or_release_printed_exits_0(run_cli, tmp_path, monkeypatch,
                                                                interrupt_in_close):
    """A Ctrl-C (or SIGTERM) that landed while ``ask``, ``tell`` or ``release`` closed its run,
    the suggestion or result stored, exited 130 ("interrupted") without printing it: ``ask``'s
    ids were never shown, and a ``tell`` told again was refused. Each prints its result, then
    closes its run: an interrupt in the close exits 0. One before the store is written is still
    130, and nothing is stored."""
    from latentune.study import Study

    d, space = _external_run(tmp_path)
    code, out, err = run_cli("ask", d, "--space", space, "--n", "3", "--quiet")
    assert interrupt_in_close == ["close"] and code == 0, (code, err)
    ids = [ln.split("\t")[0] for ln in out.splitlines()]
    assert len(ids) == 3 and "interrupted" not in err, (out, err)
    for argv, said in ((("tell", d, ids[0], "--cost", "1.5"), f"told {ids[0]}: phase 1"),
                       (("release", d, ids[1]), f"released {ids[1]}")):
        interrupt_in_close.clear()
        code, out, err = run_cli(*argv)
        assert interrupt_in_close == ["close"] and code == 0, (argv, code, err)
        assert out.startswith(said) and "interrupted" not in err, (argv, out, err)
    interrupt_in_close.append("done")           # the closes are not interrupted from here

    def interrupted(self, *a, **kw):            # the signal lands before anything is stored
        raise KeyboardInterrupt

    for name, argv in (("ask", ("ask", d, "--quiet")),
                       ("tell", ("tell", d, ids[2], "--cost", "2"))):
        with monkeypatch.context() as m:
            m.setattr(Study, name, interrupted)
            code, out, err = run_cli(*argv)
        assert code == 130 and out == "" and err.strip() == INTERRUPTED, (argv, code, out, err)
    with lt.Study(d) as st:
        assert [r.cost for r in st.store.rows(1)] == [1.5]
    assert run_cli("tell", d, ids[2], "--cost", "2")[0] == 0      # still pending: told now


@pytest.mark.parametrize("delay,sig", [(0.1, "SIGINT"), (0.3, "SIGINT"), (0.1, "SIGTERM")])
def test_a_ctrl_c_while_the_process_exits_after_ask_printed_exits_0(tmp_path, delay, sig):
    """A Ctrl-C in the second or so after ``latentune ask`` printed its suggestions, while the
    interpreter shut down (torch's modules torn down), killed the process with SIGINT: status
    -2 and no word, the suggestions stored. The command's work is done and reported, so the
    process ends with the command's status (0), as an interrupt while the run closes does; a
    SIGTERM there too (Python's finalization runs no Python handler, so both are ignored)."""
    import signal
    import time

    from conftest import CLI_ENV

    d, space = _external_run(tmp_path)
    p = subprocess.Popen(   # Python's own Ctrl-C handler (a pytest-xdist worker ignores SIGINT)
        [sys.executable, "-m", "latentune.cli", "ask", str(d), "--space", str(space), "--n",
         "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=CLI_ENV,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    out = b""
    while out.count(b"\n") < 2:                 # both suggestions printed
        chunk = os.read(p.stdout.fileno(), 4096)
        assert chunk, (out, p.stderr.read())
        out += chunk
    time.sleep(delay)
    p.send_signal(getattr(signal, sig))
    rest, err = p.communicate(timeout=60)
    assert p.returncode == 0 and err == b"" and rest == b"", (p.returncode, err, rest)
    assert [ln.split(b"\t")[0] for ln in out.splitlines()] == [b"1", b"2"]
    with lt.Study(d) as st:
        assert [t.id for t in st.store.trials("pending")] == [1, 2]


def test_an_interrupt_after_train_vae_or_report_printed_exits_0(run_cli, tmp_path, monkeypatch,
                                                                interrupt_in_close):
    """A Ctrl-C (or SIGTERM) that landed after ``train-vae`` stored and named its VAE, or after
    ``report`` wrote and printed its report, while it closed its run, exited 130: it exits 0.
    One before the VAE or report is done is still 130."""
    from latentune.study import Study

    interrupt_in_close.append("done")           # not while the run is made
    d, _ = _external_run(tmp_path, n_told=8)
    for argv, said in ((("train-vae", "--out", d, "--latent-dim", "2", "--vae-epochs", "5"),
                        "VAE ("),
                       (("train-vae", "--out", d, "--resume"), f"{d}: the VAE is already"),
                       (("report", d, "--no-sim", "--quiet"),
                        "space of a, b, c, d (trials run elsewhere)\n\n| ")):
        interrupt_in_close.clear()
        code, out, err = run_cli(*argv)
        assert interrupt_in_close == ["close"] and code == 0, (argv, code, err)
        assert out.startswith(said) and "interrupted" not in err, (argv, out, err)
    interrupt_in_close.append("done")

    def interrupted(self, *a, **kw):
        raise KeyboardInterrupt

    for name, argv in (("train_latent", ("train-vae", "--out", d, "--vae-epochs", "5")),
                       ("report", ("report", d, "--no-sim", "--quiet"))):
        with monkeypatch.context() as m:
            m.setattr(Study, name, interrupted)
            code, out, err = run_cli(*argv)
        assert code == 130 and out == "" and err.strip() == INTERRUPTED, (argv, code, out, err)


def test_a_directory_given_for_a_space_or_params_file_is_named_a_directory(capsys, tmp_path):
    """``ask --space DIR`` and ``rollout --params DIR`` said "file not found: DIR" of a directory
    that is there; they say it is a directory, not a file."""
    d = tmp_path / "conf"
    d.mkdir()
    assert_one_line(capsys, "ask", tmp_path / "r", "--space", d,
                    expect=f"--space: {d} is a directory, not a file")
    assert_one_line(capsys, "rollout", "--steps", "10", "--params", d,
                    expect=f"params file {d} is a directory, not a file")


@pytest.mark.parametrize("argv, flag", [
    (["phase3", "--out", "{d}", "--vae", ""], "--vae"),
    (["phase3", "--out", "{d}", "--vae", " "], "--vae"),
    (["ask", "{d}", "--vae", ""], "--vae"),
    (["phase1", "--out", "{d}", "--max-fall-prob", "0.5", "--fall-prior", ""], "--fall-prior"),
    (["ask", "{d}", "--max-fall-prob", "0.5", "--fall-prior", ""], "--fall-prior"),
])
def test_an_empty_run_directory_flag_says_it_is_empty(capsys, tmp_path, argv, flag):
    """--vae '' (an unset shell variable) said 'no latent space at vae', --vae ' ' '--vae: run
    directory  does not exist' and --fall-prior '' 'fall prior: no run store in .'; each says
    the flag is empty, as --params '' does."""
    argv = [a.format(d=tmp_path / "r") for a in argv] + ["--system", "examples.toy_plant:make_system"]
    assert_one_line(capsys, *argv, expect=f"{flag} is empty: give a run directory, or leave "
                                          f"{flag} out")
    assert not (tmp_path / "r").exists()
