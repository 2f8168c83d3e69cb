"""Bad input to the robot and peer benchmarks' command lines (benchmarks.reality_gap,
benchmarks.handover, benchmarks.peers): refused in one line with exit 2 before any work, never
an empty table with exit 0 or a traceback after the first runs."""
from __future__ import annotations

import json
from pathlib import Path

import pytest


def test_a_report_of_a_directory_without_outputs_is_refused(tmp_path, capsys):
    """``--report DIR`` of a directory without outputs (a typo, the wrong one) printed an empty
    table (reality_gap) or nothing (handover) and exited 0; each now says so, exit 2. JSON
    files of other benchmarks beside them are passed over, not a traceback."""
    from benchmarks import handover, reality_gap

    (tmp_path / "other.json").write_text(json.dumps({"rows": []}))
    for mod, name in ((reality_gap, "reality_gap"), (handover, "handover")):
        assert mod.main(["--report", str(tmp_path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            f"python -m benchmarks.{name}: error: no {name} output"), err
        assert str(tmp_path) in err[0]


def test_reality_gap_refuses_a_source_without_trials_or_latent_space_and_unknown_methods(
        tmp_path, capsys):
    """``--source`` that is not a finished run was an AttributeError traceback; a source without
    a latent space failed at the phase3 method after the targets were built; an unknown
    ``--methods`` name after the zero-shot θ ran on the robot. Each is now an argparse error
    (exit 2) before any target is built."""
    from benchmarks import reality_gap
    from latentune.pipeline.store import RunStore

    for argv, words in ((["--source", str(tmp_path / "none")], "is not a run with phase-1"),
                        (["--source", str(tmp_path), "--methods", "tpe"], "invalid choice")):
        with pytest.raises(SystemExit) as e:
            reality_gap.main(argv)
        assert e.value.code == 2 and words in capsys.readouterr().err
    with RunStore(tmp_path, create=True) as st:        # a phase 1 without a latent space
        st.add(1, 0, [0.5, 0.5], 1.0)
    with pytest.raises(SystemExit) as e:
        reality_gap.main(["--source", str(tmp_path), "--robot", "nosuch"])
    assert e.value.code == 2 and "has no latent space" in capsys.readouterr().err
    # a source of another controller (2 weights against the A1's 25) said "expected 25
    # normalized parameters, got shape (2,)" without naming --source
    with pytest.raises(SystemExit) as e:
        reality_gap.main(["--source", str(tmp_path), "--methods", "direct", "--steps", "10",
                          "--work", str(tmp_path / "w"), "--workers", "1"])
    assert e.value.code == 2 and f"--source {tmp_path} tunes 2 weights, the target (--robot " \
        "a1 --actor convex) 25" in capsys.readouterr().err


def test_handover_refuses_options_that_are_not_json_before_the_rollout(tmp_path, capsys,
                                                                      monkeypatch):
    """``--handover '{bad'`` was a JSONDecodeError traceback after the task was built and the
    manual θ rolled out; it is now an argparse error (exit 2) first."""
    import latentune as lt
    from benchmarks import handover

    monkeypatch.setattr(lt, "Task", lambda *a, **k: pytest.fail("built the task"))
    with pytest.raises(SystemExit) as e:
        handover.main(["--vae", str(tmp_path), "--work", str(tmp_path / "w"),
                       "--handover", "{bad"])
    assert e.value.code == 2 and "--handover is not JSON" in capsys.readouterr().err
    # JSON, but not hand-over options, and a target cost that is not a number: the same
    # (they failed after the task was built)
    for argv, words in ((["--handover", '{"nosuch": 1}'], "--handover: handover must be True"),
                        (["--handover", "[1]"], "--handover: handover must be True"),
                        (["--handover", '{"length": 5}'], "handover length must be in"),
                        (["--targets", "nan"], "--targets must be finite costs")):
        with pytest.raises(SystemExit) as e:
            handover.main(["--vae", str(tmp_path), "--work", str(tmp_path / "w"), *argv])
        assert e.value.code == 2 and words in capsys.readouterr().err, argv


@pytest.mark.parametrize("argv", [["--problems", "nosuch"], ["--methods", "nosuch"],
                                  ["--variant", "fast"], ["--variant", "fast={bad"],
                                  ["--variant", "fast=[1]"]])
def test_peers_refuses_unknown_problems_methods_and_bad_variants(tmp_path, capsys, argv):
    """An unknown problem or method, or a ``--variant`` that is not NAME=JSON object, printed a
    traceback per run ("FAILED …") and exited 0, after logging an invocation; each is now an
    argparse error (exit 2) and nothing is written."""
    from benchmarks import peers

    with pytest.raises(SystemExit) as e:
        peers.main([*argv, "--budget", "4", "--seeds", "0", "--dir", str(tmp_path / "p")])
    assert e.value.code == 2 and "error:" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()


def test_handover_refuses_a_store_of_other_options_instead_of_reporting_it(tmp_path, capsys,
                                                                           monkeypatch):
    """A finished store under ``--work`` was read as "(stored)" whenever it held ``--budget``
    trials: a re-run with another ``--max-fall-prob`` or ``--handover`` (or task) under the same
    ``--handover-name`` silently reported the old run. Such a store is now refused in one line
    (exit 2) before the manual θ's rollout; one of the same options is still read."""
    import types

    import latentune as lt
    from benchmarks import handover
    from benchmarks.common import cli_main
    from examples.shifted_bowl import BowlSystem

    with lt.Study(tmp_path / "src", seed=0, workers=1) as st:
        st.phase1(BowlSystem(0.0), 8)
        st.train_latent(2, epochs=10)

    class Task(BowlSystem):                 # the benchmark's Task, on the bowl
        rollouts = 0

        def __init__(self, robot, task, **kw):
            super().__init__(0.1 if task == "jump" else 0.2)

        def rollout(self, theta):
            Task.rollouts += 1
            return types.SimpleNamespace(cost=self.evaluate(theta))

    monkeypatch.setattr(lt, "Task", Task)
    argv = ["--vae", str(tmp_path / "src"), "--work", str(tmp_path / "w"), "--methods",
            "handover", "--seeds", "0", "--budget", "4", "--workers", "1"]
    assert handover.main(argv) == 0
    capsys.readouterr()
    for extra, words in ((["--max-fall-prob", "0.3"], "max-fall-prob = None (not 0.3)"),
                         (["--handover", '{"patience": 3}'], "handover = {"),
                         (["--task", "trot"], "system")):
        Task.rollouts = 0
        assert cli_main(lambda: handover.main(argv + extra), "benchmarks.handover") == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("python -m benchmarks.handover: error:"), err
        assert "handover_s0" in err[0] and words in err[0], err
        assert Task.rollouts == 0
    assert handover.main(argv) == 0         # the same options: read, not re-run
    assert "(stored)" in capsys.readouterr().err


@pytest.mark.parametrize("variant, words", [
    ('x={"nosuch": 1}', "method 'turbo' has no option nosuch (its options: "),
    ('x={"n_regions": 0}', "method 'turbo': n_regions must be in [1, 65536), got 0")])
def test_peers_refuses_a_variant_option_the_critic_refuses_before_any_run(tmp_path, capsys,
                                                                         variant, words):
    """``--variant 'x={"nosuch": 1}'`` (an option the critic does not have) or a value it
    refuses was caught only when each run started: a traceback per run ("FAILED …") after the
    invocation was logged. It is now refused up front in one line, exit 2, nothing written."""
    from benchmarks import peers

    code = peers.main(["--problems", "lqr16", "--methods", "--variant", variant, "--seeds",
                       "0", "--budget", "4", "--dir", str(tmp_path / "p")])
    out, err = capsys.readouterr()
    assert code == 2 and out == "", out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"python -m benchmarks.peers: error: --variant {variant!r}: ") and words in lines[0], err
    assert not (tmp_path / "p").exists()


def test_peers_exits_non_zero_and_names_the_runs_that_failed(tmp_path, capsys, monkeypatch):
    """A run that raised printed "FAILED …" among the others and the command still exited 0 (a
    script or CI took the suite as done); it now exits 1 and ends with one line naming the
    failed runs, which are not written."""
    from benchmarks import peers

    def broken(*a, **k):
        raise RuntimeError("the critic broke")

    monkeypatch.setattr(peers, "run_lt", broken)
    code = peers.main(["--problems", "lqr16", "--methods", "--variant", 'bad={"n_init": 4}',
                       "--seeds", "0", "--budget", "4", "--batch-size", "2",
                       "--dir", str(tmp_path / "p")])
    out, err = capsys.readouterr()
    assert code == 1 and "FAILED lqr16 lt_turbo@bad 0" in out
    assert err.strip().splitlines()[-1] == (
        "python -m benchmarks.peers: error: 1 of 1 runs failed (their tracebacks above; not "
        "written, a re-run tries them again): lqr16 lt_turbo@bad s0")
    assert not list((tmp_path / "p" / "runs").glob("*.json"))
    end = json.loads((tmp_path / "p" / "invocations.jsonl").read_text().splitlines()[-1])
    assert end["runs_failed"] == ["lqr16 lt_turbo@bad s0"]


def test_a_closed_stdout_ends_a_benchmark_without_a_traceback(tmp_path):
    """``python -m benchmarks.X … | head`` (here ``benchmarks.handover --report``) ended in a
    BrokenPipeError traceback; every benchmark's command line (``cli_main``) now ends quietly
    with exit 141, as ``latentune`` does."""
    import subprocess
    import sys

    from conftest import CLI_ENV, ROOT

    (tmp_path / "a1_jump.json").write_text(json.dumps({
        "robot": "a1", "task": "jump", "manual": 1.0, "table": ["| method |"] * 1000,
        "provenance": {"command": "python -m benchmarks.handover", "wall_s": 1.0}}))
    env = dict(CLI_ENV, PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    p = subprocess.Popen([sys.executable, "-m", "benchmarks.handover", "--report",
                          str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         env=env, text=True, cwd=tmp_path)
    p.stdout.close()                        # the reader is gone before anything is written
    err = p.stderr.read()
    assert p.wait(timeout=120) == 141, err
    assert err == ""


@pytest.mark.parametrize("name", ["buck_traces", "cartpole_traces", "quadrotor_traces",
                                  "servo_traces", "vehicle_traces", "zones_traces"])
def test_traces_of_a_root_or_gap_without_runs_exit_2_in_one_line(tmp_path, capsys, name):
    """``benchmarks.buck_traces --root DIR`` (or ``--gap G``) without runs there exited 1 with
    "buck traces: error: …" (a SystemExit of the seed's choice), not 2 as the other usage
    errors; a gap the system refuses (``--gap -1 --seed 0``) was a ValueError traceback. Each
    is now one ``python -m benchmarks.<name>: error:`` line and exit 2, for every ladder's
    traces."""
    import importlib

    mod = importlib.import_module(f"benchmarks.{name}")
    for argv, words in ((["--root", str(tmp_path)], f"run under {tmp_path}"),
                        (["--root", str(tmp_path), "--gap", "-1", "--seed", "0"], "--gap: gap")):
        assert mod.main([*argv, "--png", str(tmp_path / "t.png")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
        assert err[0].startswith(f"python -m benchmarks.{name}: error:"), err
    assert not (tmp_path / "t.png").exists()


@pytest.mark.parametrize("name,argv,words", [
    ("reality_gap", ["--budget", "0"], "--budget must be >= 1, got 0"),
    ("reality_gap", ["--seeds", "0", "-1"], "--seeds must be >= 0, got -1"),
    ("reality_gap", ["--workers", "0"], "--workers must be >= 1, got 0"),
    ("reality_gap", ["--steps", "0"], "--steps must be >= 1, got 0"),
    ("reality_gap", ["--max-fall-prob", "0"], "--max-fall-prob must be in (0, 1], got 0.0"),
    ("handover", ["--budget", "0"], "--budget must be >= 1, got 0"),
    ("handover", ["--seeds", "-2"], "--seeds must be >= 0, got -2"),
    ("handover", ["--workers", "0"], "--workers must be >= 1, got 0"),
    ("handover", ["--batch-size", "0"], "--batch-size must be >= 1, got 0"),
    ("handover", ["--max-fall-prob", "1.5"], "--max-fall-prob must be in (0, 1], got 1.5")])
def test_robot_benchmarks_refuse_bad_counts_before_building_a_task(tmp_path, capsys, monkeypatch,
                                                                   name, argv, words):
    """``--budget 0``, a negative seed, ``--workers 0`` (and ``--steps``, ``--batch-size``,
    ``--max-fall-prob`` out of range) were refused only inside the Study, after the robot's
    task was built and its first trial (the zero-shot θ, the manual θ) rolled out; each is now
    one argparse error (exit 2) before any task."""
    import importlib

    import latentune as lt

    mod = importlib.import_module(f"benchmarks.{name}")
    monkeypatch.setattr(lt, "Task", lambda *a, **k: pytest.fail("built the task"))
    common = (["--source", str(tmp_path), "--work", str(tmp_path / "w")] if name == "reality_gap"
              else ["--vae", str(tmp_path), "--work", str(tmp_path / "w")])
    with pytest.raises(SystemExit) as e:
        mod.main([*common, *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and err[-1].endswith(f"error: {words}"), err
    assert not (tmp_path / "w").exists()


def test_an_output_path_that_cannot_be_written_is_one_line_not_a_traceback(tmp_path, capsys):
    """``benchmarks.transfer summary --out F`` (or ``compare --out``) where F is a directory, or
    under a file, or in a read-only directory, and ``benchmarks.handover --work FILE``, ended in
    an IsADirectoryError, FileExistsError or PermissionError traceback (exit 1), after the work
    was done. Every benchmark's command line (``cli_main``) now says what it could not write in
    one line, exit 2."""
    import os
    from benchmarks import handover, transfer
    from benchmarks.common import cli_main

    root = tmp_path / "root"
    run = root / "chain" / "gap1" / "seed0"
    run.mkdir(parents=True)
    (run / "zero_shot.json").write_text(json.dumps({
        "costs": [0.9], "failed": [False], "thetas": [[0.5] * 20], "system": "chain",
        "gap": 1.0, "seed": 0, "method": "zero_shot", "budget": 1, "wall_s": 0.01}))
    afile = tmp_path / "afile"
    afile.write_text("")
    cases = [
        (transfer, ["summary", "--root", str(root), "--out", str(afile / "s.json")],
         f"{afile} is not a directory"),
        (transfer, ["summary", "--root", str(root), "--out", str(tmp_path)],
         f"{tmp_path} is a directory, not a file"),
        (transfer, ["compare", "--root", str(root), "--a", "zero_shot", "--b", "zero_shot",
                    "--out", str(afile / "c.json")], f"{afile} is not a directory"),
        (handover, ["--vae", str(root), "--work", str(afile)], f"{afile} is not a directory"),
    ]
    for mod, argv, words in cases:            # transfer's --out: refused as it is read
        prog = mod.__name__
        try:
            code = cli_main(lambda: mod.main(argv), prog)
        except SystemExit as e:
            code = e.code
        assert code == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith(f"python -m {prog}") and err[-1].endswith(f"error: {words}") \
            or err[-1].endswith((f"argument --out: {words}", f"argument --work: {words}")), \
            (argv, err)
    from benchmarks.common import os_error_line

    denied = PermissionError(13, os.strerror(13), str(tmp_path / "ro" / "s.json"))
    assert os_error_line(denied) == f"{tmp_path / 'ro' / 's.json'}: Permission denied"


@pytest.mark.parametrize("module", ["handover", "phase3_order", "reality_gap",
                                    "sample_efficiency", "sim_to_real"])
def test_a_work_directory_under_a_file_is_refused_as_it_is_read(tmp_path, capsys, module):
    """``--work`` of five benchmarks was checked only when first written: after the sources
    were read (handover, reality_gap), after the required options' checks, or at the first
    study. It is refused as the command line is read, as ``--out`` is (argparse's one line,
    exit 2), before any other option is checked."""
    import importlib

    mod = importlib.import_module(f"benchmarks.{module}")
    afile = tmp_path / "afile"
    afile.write_text("")
    with pytest.raises(SystemExit) as e:
        mod.main(["--work", str(afile / "w")])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and err[-1] == (f"python -m benchmarks.{module}: error: argument "
                                             f"--work: {afile} is not a directory"), err


def test_compare_names_a_method_with_no_run_and_the_near_ones(tmp_path, capsys):
    """``transfer compare --a nosuch`` said only that no (target, seed) holds both methods; it
    names the method without a run (and the stored ones close to it), exit 2; two stored
    methods that never ran on one seed keep the pair message."""
    from benchmarks import transfer

    for seed, method in ((0, "zero_shot"), (0, "transfer"), (1, "tpe")):
        run = tmp_path / "chain" / "gap1" / f"seed{seed}"
        run.mkdir(parents=True, exist_ok=True)
        (run / f"{method}.json").write_text(json.dumps({
            "costs": [0.9], "failed": [False], "thetas": [[0.5] * 20], "system": "chain",
            "gap": 1.0, "seed": seed, "method": method, "budget": 1, "wall_s": 0.01}))
    for argv, words in (
            (["--a", "transfr", "--b", "zero_shot"], "no run of transfr under "
                                                      f"{tmp_path} (did you mean transfer?)"),
            (["--a", "tpe", "--b", "zero_shot"], "holds both methods of any pair")):
        assert transfer.main(["compare", "--root", str(tmp_path), *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err


def test_a_long_benchmark_refuses_an_output_it_could_not_write_before_any_work(
        tmp_path, capsys, monkeypatch):
    """reality_gap, handover, peers and optuna_hopper checked ``--out`` only when writing it,
    after hours of work (whose results were then lost). ``--out`` is checked as the command
    line is read: a directory, a file among its parents; one argparse line, exit 2, nothing run."""
    import latentune as lt
    from benchmarks import optuna_hopper, peers, reality_gap

    monkeypatch.setattr(lt, "Task", lambda *a, **k: pytest.fail("built the task"))
    afile = tmp_path / "afile"
    afile.write_text("")
    for mod in (reality_gap, peers, optuna_hopper):
        for out, words in ((afile / "x.json", f"{afile} is not a directory"),
                           (tmp_path, f"{tmp_path} is a directory, not a file")):
            with pytest.raises(SystemExit) as e:
                mod.main(["--out", str(out)])
            err = capsys.readouterr().err.strip().splitlines()
            assert e.value.code == 2 and err[-1].endswith(f"argument --out: {words}"), \
                (mod.__name__, err)
    assert list(tmp_path.iterdir()) == [afile]


@pytest.mark.parametrize("argv,words", [
    (["run", "--budget", "-1"], "argument --budget: must be >= 1, got -1"),
    (["run", "--budget", "0"], "argument --budget: must be >= 1, got 0"),
    (["run", "--workers", "-3"], "argument --workers: must be >= 1, got -3"),
    (["run", "--seeds", "-1"], "argument --seeds: must be >= 0, got -1"),
])
def test_robot_transfer_names_the_bound_a_count_must_meet(argv, words, capsys):
    """``benchmarks.robot_transfer run --budget -1`` said "must be >= 0", a bound 0 itself fails
    ("must be >= 1, got 0"): a count of at least 1 now names 1 for every value below it."""
    from benchmarks import robot_transfer

    with pytest.raises(SystemExit) as exc:
        robot_transfer.parser().parse_args(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(words)


def test_every_benchmark_names_itself_as_it_is_run_in_its_usage_lines(capsys):
    """The less-used benchmarks' usage and error lines named the file (``usage: actor.py``,
    ``vae_kind.py: error: …``), not a command one can run; every benchmark's parser is now
    :func:`benchmarks.common.bench_parser` of its own module: ``python -m benchmarks.X``."""
    import ast
    import re
    from pathlib import Path

    from benchmarks import buck_traces, vae_kind

    for f in sorted((Path(__file__).parents[1] / "benchmarks").glob("*.py")):
        if f.name == "common.py":
            continue
        for node in ast.walk(ast.parse(f.read_text())):
            if not isinstance(node, ast.Call):
                continue
            name = ast.unparse(node.func)
            assert not name.endswith("ArgumentParser"), f"{f.name}: {name}"
            if name == "bench_parser":
                arg = ast.unparse(node.args[0]).strip("f'\"")
                assert re.fullmatch(rf"benchmarks\.({f.stem}|{{name}}_traces)( \w+)?", arg), \
                    f"{f.name}: {arg}"
    for mod, name in ((vae_kind, "vae_kind"), (buck_traces, "buck_traces")):
        with pytest.raises(SystemExit):
            mod.main(["--help"])
        assert capsys.readouterr().out.startswith(f"usage: python -m benchmarks.{name} ")


def test_every_benchmark_error_line_names_the_command_as_it_is_run(capsys):
    """A benchmark's own error lines named it four ways (``gap_ladder: error:``,
    ``benchmarks.vae_kind: error:``, a bare ``error:``, and argparse's
    ``python -m benchmarks.X: error:``); each is now :func:`benchmarks.common.error_line`, the
    one argparse's lines have."""
    import re
    from pathlib import Path

    from benchmarks import gap_ladder

    for f in sorted((Path(__file__).parents[1] / "benchmarks").glob("*.py")):
        if f.name != "common.py":
            assert not re.search(r'print\(f?"[^"]*error: ', f.read_text()), f.name
    assert gap_ladder.main(["--n", "0"]) == 2
    assert capsys.readouterr().err == ("python -m benchmarks.gap_ladder: error: --n must be >= 1, "
                                       "got 0\n")


def test_no_benchmark_prints_its_own_error_line_under_a_bare_name(tmp_path, capsys):
    """``322a25ea`` left about thirty error lines of thirteen benchmarks printed by hand under
    the module's bare name (``transfer summary: …``, ``transfer_coords: …``, ``phase3_order:
    …``); each is now :func:`benchmarks.common.error_line`, ``python -m benchmarks.X: error:``
    (a subcommand's adds its name: ``python -m benchmarks.transfer summary: error:``)."""
    import re
    from pathlib import Path

    from benchmarks import transfer, transfer_coords

    for f in sorted((Path(__file__).parents[1] / "benchmarks").glob("*.py")):
        assert not re.search(rf'print\(\s*f?"{f.stem}( [\w-]+)?: ', f.read_text()), f.name
    assert transfer.main(["summary", "--root", str(tmp_path), "--methods", "transfer"]) == 2
    assert capsys.readouterr().err == ("python -m benchmarks.transfer summary: error: no runs "
                                       f"under {tmp_path} of methods transfer\n")
    assert transfer_coords.main(["--root", str(tmp_path), "--methods", "transfer"]) == 2
    assert capsys.readouterr().err == ("python -m benchmarks.transfer_coords: error: give "
                                       "--coords NAME ... or --faces (or both)\n")


def test_a_missing_file_raised_with_a_message_is_named_by_that_message(tmp_path, capsys):
    """``transfer_falls --root R`` (no run store under R) and ``transfer_diagnose --sources S``
    (no source run under S) said ``no such file or directory: None``: they raise
    FileNotFoundError with a message and no file name; the message is the error line now."""
    from benchmarks import common, transfer_falls

    def missing() -> int:
        raise FileNotFoundError(f"no run store at {tmp_path}")

    assert common.cli_main(missing, "benchmarks.transfer_falls") == 2
    assert capsys.readouterr().err == ("python -m benchmarks.transfer_falls: error: no run "
                                       f"store at {tmp_path}\n")
    assert common.cli_main(lambda: transfer_falls.main(["--root", str(tmp_path)]),
                           "benchmarks.transfer_falls") == 2
    assert capsys.readouterr().err == ("python -m benchmarks.transfer_falls: error: no run "
                                       f"store at {tmp_path / 'a1-jump'}\n")


def test_transfer_falls_ladder_refuses_a_method_without_traces_and_a_bad_out(tmp_path, capsys):
    """``transfer_falls ladder --root R`` with no trace of a --methods name under R (a typo,
    the wrong directory) printed an empty table, or the others' rows alone, and exited 0, and
    its --out was not checked before the work; each is now one line, exit 2."""
    from benchmarks import transfer_falls

    assert transfer_falls.main(["ladder", "--root", str(tmp_path), "--methods", "transfr"]) == 2
    assert capsys.readouterr().err == ("python -m benchmarks.transfer_falls ladder: error: no "
                                       f"trace of transfr under {tmp_path} (systems chain "
                                       "hopper, seeds 0 1 2)\n")
    run = tmp_path / "chain" / "gap1" / "seed0" / "transfer.json"
    run.parent.mkdir(parents=True)
    run.write_text(json.dumps({"costs": [2.0, 1.0], "failed": [False, True],
                               "thetas": [[0.5], [0.6]]}))
    argv = ["ladder", "--root", str(tmp_path), "--methods", "transfer", "transfr"]
    assert transfer_falls.main(argv) == 2             # a row of 0 seeds is no trace
    assert "no trace of transfr under" in capsys.readouterr().err
    assert transfer_falls.main(argv[:-1]) == 0
    capsys.readouterr()
    (tmp_path / "f").write_text("")
    with pytest.raises(SystemExit) as e:
        transfer_falls.main(["ladder", "--root", str(tmp_path), "--out",
                             str(tmp_path / "f" / "o.json")])
    assert e.value.code == 2 and f"{tmp_path / 'f'} is not a directory" in capsys.readouterr().err


@pytest.mark.parametrize("module, argv", [
    ("basin_path", ["--md"]), ("transfer_curves", ["--md"]), ("transfer_falls", ["stores", "--md"]),
    ("transfer_long", ["--md"]), ("transfer_reach", ["--md"]), ("transfer_walk", ["--md"]),
    ("zones_traces", ["--png"]), ("servo_traces", ["--png"]),
    ("fall_costs", ["summary", "--root", "r", "--out"]),
    ("transfer", ["summary", "--out"]), ("transfer", ["compare", "--a", "x", "--b", "y", "--out"]),
    ("transfer", ["prefix", "--root", "r", "--stored", "s", "--budget", "4", "--out"]),
    ("robot_transfer", ["summary", "--out"]),
    ("robot_transfer", ["compare", "--a", "x", "--b", "y", "--out"]),
    ("robot_transfer", ["decisions", "--out"]), ("robot_transfer", ["export", "--out/"]),
    ("robot_transfer", ["plot", "--out/"]), ("transfer_escape", ["summary", "--out"]),
    ("transfer_escape", ["blind", "--out/"]),
    ("transfer_falls", ["kinds", "--methods", "x", "--out"]),
    ("transfer_allowance", ["--summary", "s", "--runs", "r", "--out"]),
    ("transfer_diagnose", ["--out"]), ("transfer_gate", ["--runs", "r", "--out"]),
    ("transfer_agreement", ["--runs", "r", "--out"]),
    ("transfer_models", ["--out"]), ("transfer_screened", ["--summary", "s", "--out"]),
    ("transfer_simrank", ["--runs", "r", "--sources", "s", "--models", "m", "--out"]),
    ("transfer_stop", ["--runs", "r", "--heldout-runs", "h", "--out"]),
    ("optuna_hopper", ["--traces/"]), ("transfer_walk", ["--cache/"]), ("peers", ["--dir/"])])
def test_a_table_or_figure_path_that_cannot_be_written_is_refused_before_the_work(
        tmp_path, capsys, monkeypatch, module, argv):
    """``--md``, the traces' ``--png`` and a dozen benchmarks' ``--out`` (transfer summary,
    robot_transfer decisions, transfer_stop, ...) were plain paths: one under a file, a
    directory given for a file or one in a directory that cannot be written failed only when
    written, after the work (or, for those written with ``Path.write_text``, one in a directory
    not made yet). They are checked as the command line is read, as ``add_out_arg``'s ``--out``
    is (argparse's line, exit 2); an output directory (``--out/`` here: export, plot, blind; the
    traces, caches and runs a benchmark writes as it goes) is refused when it is a file."""
    import importlib
    import os

    from benchmarks import common

    (tmp_path / "f").write_text("")
    ro = tmp_path / "ro"
    ro.mkdir()
    access = os.access       # the tests may run as root, to whom every directory is writable
    monkeypatch.setattr(common.os, "access", lambda p, mode, **kw: (
        Path(p) != ro or not mode & os.W_OK) and access(p, mode, **kw))
    name = "t.png" if argv[-1] == "--png" else "t.md"
    cases = [(tmp_path / "f" / name, f"{tmp_path / 'f'} is not a directory"),
             (ro / name, f"{ro}: Permission denied")]
    if argv[-1].endswith("/"):              # an output directory: a file is not one
        argv = [*argv[:-1], argv[-1][:-1]]
        cases.append((tmp_path / "f", f"{tmp_path / 'f'} is not a directory"))
    else:
        cases.append((tmp_path, f"{tmp_path} is a directory, not a file"))
    mod = importlib.import_module(f"benchmarks.{module}")
    for bad, words in cases:
        with pytest.raises(SystemExit) as e:
            mod.main([*argv, str(bad)])
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and err[-1].endswith(f": {words}"), (bad, err)
        assert err[-1].startswith(f"python -m benchmarks.{module}"), err
    assert sorted(tmp_path.iterdir()) == [tmp_path / "f", ro]


def test_an_output_in_a_directory_not_made_yet_is_written_there(tmp_path, capsys):
    """transfer_screened (as transfer_allowance and transfer_stop) wrote ``--out`` with
    ``Path.write_text``: one in a directory not made yet ended in a FileNotFoundError after
    the work. Its parents are made, as every ``--out``'s are."""
    from benchmarks import transfer_screened

    summary = tmp_path / "s.json"
    m = {"median_best": 1.0, "falls_median": 1, "falls": [1], "median_best_within_allowance": 1.0}
    summary.write_text(json.dumps({"targets": [{
        "system": "chain", "gap": 1, "best_peer": "cma_source", "fall_allowance": 2,
        "within_allowance": [], "methods": {"cma_source": m, "cma_source_screened": m}}]}))
    out = tmp_path / "new" / "dir" / "o.json"
    transfer_screened.main(["--summary", str(summary), "--losses", "--out", str(out)])
    capsys.readouterr()
    assert json.loads(out.read_text())["rows"][0]["target"] == "chain 1"
