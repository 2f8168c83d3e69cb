"""The person at the robot through the CLI: asks by two askers, a mistyped result amended, a
suggestion released, status by phase name, the θ to deploy, --strategy's refusals, --start,
and later asks that lease without loading the critic."""
from __future__ import annotations

import json
import re

import pytest
import yaml


def test_a_person_at_the_robot(tmp_path, run_cli, error_line):
    space = tmp_path / "space.yaml"
    space.write_text(yaml.safe_dump({"names": ["a", "b", "c"], "low": [0, 0, 0],
                                     "high": [1, 1, 1], "manual": [0.5, 0.5, 0.5]}))
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", space, "--asker", "alice", "--json")
    assert code == 0, err
    (a,) = json.loads(out)
    assert a["asker"] == "alice" and a["phase_name"] == "phase 1"
    assert json.loads((d / "suggestions" / f"{a['id']}.json").read_text()).keys() == {"a", "b", "c"}
    code, out, err = run_cli("ask", d, "--asker", "bob", "--json")
    (b,) = json.loads(out)
    assert b["id"] != a["id"] and b["theta"] != a["theta"]          # another θ for bob
    assert run_cli("tell", d, a["id"], "--cost", "-3")[0] == 0       # a typo ...
    code, out, _ = run_cli("tell", d, a["id"], "--cost", "3", "--amend")
    assert code == 0 and out.startswith(f"amended {a['id']}")      # ... corrected
    assert not (d / "suggestions" / f"{a['id']}.json").exists()
    code, out, _ = run_cli("release", d, b["id"])
    assert code == 0 and "again" in out
    code, out, _ = run_cli("status", d, "--json")
    s = json.loads(out)
    assert s["phases"]["phase 1"]["n"] == 1 and s["amended"] == 1
    assert s["best"]["cost"] == 3.0 and s["best"]["trial"] == a["id"]
    code, out, _ = run_cli("best", d, "--out", tmp_path / "deploy.json")
    assert code == 0 and json.loads((tmp_path / "deploy.json").read_text()) == \
        {k: v for k, v in a["params"].items()}
    # a conflicting option on a later ask is refused, naming the stored one
    assert "turbo" in error_line(*run_cli("ask", d, "--method", "cma")[::2])


def test_strategy_flag_is_checked(tmp_path, run_cli, error_line):
    line = error_line(*run_cli("phase3", "--robot", "a1", "--task", "trot", "--out", tmp_path,
                               "--strategy", "transfer", "--handover")[::2])
    assert "--handover is an option of --strategy plain" in line
    assert "invalid choice" in error_line(*run_cli("phase3", "--robot", "a1", "--out", tmp_path,
                                                   "--strategy", "latent")[::2])


def _space_file(tmp_path):
    space = tmp_path / "space.yaml"
    space.write_text(yaml.safe_dump({"names": ["a", "b", "c"], "low": [0, 0, 0],
                                     "high": [1, 2, 4], "manual": [0.5, 0.5, 0.5]}))
    return space


@pytest.mark.parametrize("phase", [1, 3])
def test_later_asks_lease_without_loading_the_critic(tmp_path, cli, cli_env, run_cli, phase):
    """Each ask in its own process, as the person runs them: after the first ask, an ask
    hands out a queued or prepared suggestion without importing torch or BoTorch (phase 3:
    the default strategy, whose first suggestion is the zero-shot trial). The tells (which
    prepare the next batch) run in this process."""
    d = tmp_path / "robot"
    first: tuple = ("--space", _space_file(tmp_path))
    if phase == 3:
        import latentune as lt

        space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 2, 4], manual=[0.5] * 3)
        with lt.Study(tmp_path / "sim", seed=0) as sim:
            sim.phase1(lt.FunctionSystem(space, lambda x: float(sum((x - 0.4) ** 2))), 30)
            sim.train_latent(latent_dim=2, epochs=30)
        first += ("--phase", "3", "--vae", tmp_path / "sim")
    env = dict(cli_env, PYTHONPROFILEIMPORTTIME="1")       # python -X importtime
    seen = []
    for i in range(6):
        r = cli("ask", d, "--json", *(first if i == 0 else ()), env=env)
        assert r.returncode == 0, r.stderr
        (s,) = json.loads(r.stdout)
        seen.append(s["id"])
        imported = {ln.split("|")[-1].strip().split(".")[0] for ln in r.stderr.splitlines()
                    if ln.startswith("import time:")}
        assert "latentune" in imported
        if i == 0:                                     # the first ask builds the critic
            assert "torch" in imported
        else:
            assert not imported & {"torch", "botorch", "gpytorch"}, i
        code, out, err = run_cli("tell", d, s["id"], "--cost", str(sum(v * v for v in s["theta"])))
        assert code == 0 and out.startswith(f"told {s['id']}"), err
        if phase == 3:
            assert s["phase_name"] == ("zero-shot" if i == 0 else "phase 3")
    assert seen == [1, 2, 3, 4, 5, 6]       # batches of 4 after the first ask's (and zero-shot)


def test_ask_start(tmp_path, run_cli, error_line):
    space = _space_file(tmp_path)
    start = tmp_path / "start.json"
    start.write_text(json.dumps({"a": 0.25, "b": 1.5, "c": 3.0}))
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", space, "--start", start, "--json")
    assert code == 0, err
    (s,) = json.loads(out)
    assert s["params"] == {"a": 0.25, "b": 1.5, "c": 3.0}           # the critic starts there
    assert run_cli("ask", d, "--start", start)[0] == 0               # the stored one again
    line = error_line(*run_cli("ask", d, "--start", "manual")[::2])
    assert "runs with --start [0.25, 0.75, 0.75] (stored), not --start manual" in line
    line = error_line(*run_cli("ask", d, "--start", "scratch")[::2])
    assert "(stored), not --start scratch" in line
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"a": 7}))
    assert "--start" in error_line(*run_cli("ask", d, "--start", bad)[::2])
    assert "no such file" in error_line(*run_cli("ask", d, "--start",
                                                  tmp_path / "none.json")[::2])
    assert error_line(*run_cli("ask", d, "--start", "")[::2]) == (  # once "params file . is a
        "latentune: error: --start is empty: give manual, scratch or a file name, or leave "
        "--start out")                                            # directory"
    line = error_line(*run_cli("ask", tmp_path / "new", "--start", start)[::2])
    assert "the first ask needs a system or a space (--system, --robot or --space FILE)" in line
    code, out, err = run_cli("ask", tmp_path / "scratch", "--space", space, "--start", "scratch",
                             "--json", "--n", "4")
    assert code == 0, err
    assert all(s["params"] != {"a": 0.5, "b": 1.0, "c": 2.0} for s in json.loads(out))


def _phase3_asktell(tmp_path):
    """(the robot's study directory, the first phase-3 ask's arguments) over a 3-weight
    source study with its latent space in ``tmp_path / "sim"``."""
    import latentune as lt

    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 2, 4], manual=[0.5] * 3)
    with lt.Study(tmp_path / "sim", seed=0) as sim:
        sim.phase1(lt.FunctionSystem(space, lambda x: float(sum((x - 0.4) ** 2))), 30)
        sim.train_latent(latent_dim=2, epochs=30)
    return tmp_path / "robot", ("--space", _space_file(tmp_path), "--phase", "3",
                                "--vae", tmp_path / "sim")


def test_fall_budget_flag_is_checked_and_kept_by_later_asks(tmp_path, run_cli, error_line):
    """--fall-budget: out of [0, 1) or with the plain strategy, refused in one line, fixing
    nothing; given to the first ask of a transfer phase 3 it is recorded in the
    phase's transfer options, and a later ask with another value is refused naming it."""
    import latentune as lt

    assert "--fall-budget must be in [0, 1), got 1.5" in error_line(*run_cli(
        "phase3", "--robot", "a1", "--out", tmp_path / "r", "--fall-budget", "1.5")[::2])
    d, first = _phase3_asktell(tmp_path)
    line = error_line(*run_cli("ask", d, *first, "--strategy", "plain",
                               "--fall-budget", "0.2")[::2])
    assert "--fall-budget is an option of the transfer phase 3" in line
    assert not (d / "run.db").exists() or "asktell" not in lt.Study(d).config()
    code, _, err = run_cli("ask", d, *first, "--fall-budget", "0.2")
    assert code == 0, err
    assert lt.Study(d).config()["phase3"]["transfer_options"] == {"fall_budget": 0.2}
    assert "0.2" in error_line(*run_cli("ask", d, "--fall-budget", "0.3")[::2])
    assert run_cli("ask", d)[0] == 0


def test_record_walk_flags_are_checked_and_recorded(tmp_path, run_cli, error_line):
    """--record-walk K and --walk-pick P: a negative K, an unknown P, or a P without a walk to
    choose for are refused in one line, fixing nothing; given to the first ask of a transfer
    phase 3 they are recorded in its transfer options (with --fall-budget beside them), and a
    later ask keeps them."""
    import latentune as lt

    assert "--record-walk must be a number of asks ≥ 0" in error_line(*run_cli(
        "phase3", "--robot", "a1", "--out", tmp_path / "r", "--record-walk", "-1")[::2])
    assert "give --record-walk K > 0" in error_line(*run_cli(
        "phase3", "--robot", "a1", "--out", tmp_path / "r", "--walk-pick", "band")[::2])
    assert "invalid choice" in error_line(*run_cli(
        "phase3", "--robot", "a1", "--out", tmp_path / "r", "--record-walk", "3",
        "--walk-pick", "cost")[::2])
    assert "--escape-falls must be a number of trials ≥ 0" in error_line(*run_cli(
        "phase3", "--robot", "a1", "--out", tmp_path / "r", "--escape-falls", "-1")[::2])
    assert not (tmp_path / "r").exists()
    d, first = _phase3_asktell(tmp_path)
    code, _, err = run_cli("ask", d, *first, "--record-walk", "3", "--walk-pick", "band",
                           "--fall-budget", "0.2", "--escape-falls", "8")
    assert code == 0, err
    assert lt.Study(d).config()["phase3"]["transfer_options"] == \
        {"fall_budget": 0.2, "record_walk": 3, "walk_pick": "band", "escape_falls": 8}
    code, _, err = run_cli("ask", d, "--walk-pick", "band")      # the stored walk: K = 3
    assert code == 0, err
    assert "--walk-pick band (stored), not --walk-pick fall" in error_line(
        *run_cli("ask", d, "--walk-pick", "fall")[::2])


API_NAMES = re.compile(r"transfer[_-]options|fall_prior|max_fall_prob|lease_s|walk_pick|"
                       r"record_walk|fall_budget|escape_falls|\(strategy |^\w+ (is|are|must) ")


def test_ask_refusals_name_the_flags_not_the_python_arguments(tmp_path, run_cli, error_line):
    """ask's refusals named Study.ask's arguments: "transfer_options is an option of phase 3"
    for --fall-budget, "fall_prior is an option of phase 1", "(strategy plain)", "runs with
    transfer-options = None (stored), not {'fall_budget': 0.3}"; they now name the flags."""
    space = _space_file(tmp_path)
    d1 = tmp_path / "p1"
    assert run_cli("ask", d1, "--space", space)[0] == 0
    d, first = _phase3_asktell(tmp_path)
    cases = [
        (("ask", d1, "--fall-budget", "0.2"), "--fall-budget is an option of phase 3"),
        (("ask", d1, "--record-walk", "2", "--escape-falls", "3"),
         "--record-walk and --escape-falls are options of phase 3"),
        (("ask", d1, "--handover"), "--handover is an option of phase 3"),
        (("ask", d1, "--strategy", "plain"), "--strategy is an option of phase 3"),
        (("ask", d1, "--asker", ""), "--asker must be a non-empty name"),
        (("ask", tmp_path / "fp", "--space", space, "--fall-prior", d1),
         "--fall-prior needs --max-fall-prob"),
        (("ask", d1, "--method", "cma"), "runs with --method turbo (stored), not --method cma"),
        (("ask", tmp_path / "r0", "--space", space, "--regions", "0"),
         "--regions must be an integer in [1, 100], got 0"),
        (("ask", tmp_path / "n1", *first, "--fall-prior", d1),
         "--fall-prior is an option of phase 1"),
        (("ask", tmp_path / "n2", *first, "--strategy", "transfer", "--method", "cma"),
         "--method is an option of the plain phase 3 (--strategy plain), not of the transfer "
         "phase 3 (given --method = 'cma')"),
        (("ask", tmp_path / "n3", *first, "--strategy", "plain", "--record-walk", "2"),
         "--record-walk is an option of the transfer phase 3 (--strategy transfer)"),
        (("ask", d, *first, "--fall-budget", "0.2"), None),
        (("ask", d, "--fall-budget", "0.3"),
         "runs with --fall-budget 0.2 (stored), not --fall-budget 0.3"),
        (("ask", d, "--escape-falls", "4"), "runs with no --escape-falls (stored), not "
                                            "--escape-falls 4"),
        (("ask", d, "--strategy", "plain"),
         "phase 3 runs with --strategy transfer (stored), not --strategy plain: leave "
         "--strategy out to go on with the transfer phase 3, or start a plain phase 3 in "
         "another directory"),
    ]
    for argv, expect in cases:
        code, _, err = run_cli(*argv)
        if expect is None:
            assert code == 0, err
            continue
        line = error_line(code, err).removeprefix("latentune: error: ")
        assert expect in line and not API_NAMES.search(line), (argv, line)


def test_best_out_never_overwrites_a_file_of_the_run(tmp_path, run_cli, error_line):
    """``best --out DIR/run.db`` wrote the θ over the run store; now a file in the run's
    directory that is not a θ file of its space is refused (a θ file there may be rewritten),
    and an empty name is one line."""
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", _space_file(tmp_path), "--json")
    assert code == 0, err
    (a,) = json.loads(out)
    assert run_cli("tell", d, a["id"], "--cost", "2")[0] == 0
    store = (d / "run.db").read_bytes()
    assert "is a file of the run" in error_line(*run_cli("best", d, "--out", d / "run.db")[::2])
    assert (d / "run.db").read_bytes() == store
    assert "needs a name" in error_line(*run_cli("best", d, "--out", "")[::2])
    for _ in range(2):                                  # a θ file of its own may be rewritten
        assert run_cli("best", d, "--out", d / "deploy.json")[0] == 0
    assert run_cli("status", d)[0] == 0


def test_best_out_never_overwrites_a_suggestion_or_a_phase_file(tmp_path, run_cli, error_line):
    """``best --out DIR/suggestions/2.json`` wrote the best θ over pending suggestion 2's file
    (the robot would have run it, and ``tell 2`` then refused the file as edited), and ``--out
    DIR/phase1_best.json`` put the best over all phases under phase 1's name; both are refused,
    the files unchanged."""
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", _space_file(tmp_path), "--n", "2", "--json")
    assert code == 0, err
    a, b = json.loads(out)
    assert run_cli("tell", d, a["id"], "--cost", "2")[0] == 0
    pending = d / "suggestions" / f"{b['id']}.json"
    before = pending.read_text()
    line = error_line(*run_cli("best", d, "--out", pending)[::2])
    assert line == (f"latentune: error: {pending} is the file of suggestion {b['id']}: write the "
                    f"θ elsewhere (or to {d / 'best.json'})")
    assert pending.read_text() == before
    (d / "phase1_best.json").write_text(json.dumps(a["params"]))
    line = error_line(*run_cli("best", d, "--out", d / "phase1_best.json")[::2])
    assert "phase1_best.json is the file of phase 1's best θ: write the θ elsewhere" in line
    assert run_cli("tell", d, b["id"], "--cost", "3")[0] == 0


def test_best_out_to_a_directory_leaves_no_stray_file(tmp_path, run_cli, error_line):
    """``best --out SOME_DIR`` left ``SOME_DIR.tmp`` beside it (``--out /tmp``: ``/tmp.tmp``);
    now a directory is refused and nothing is left."""
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", _space_file(tmp_path), "--json")
    (a,) = json.loads(out)
    assert run_cli("tell", d, a["id"], "--cost", "2")[0] == 0
    (tmp_path / "outdir").mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    assert "is a directory: name the θ file" in error_line(
        *run_cli("best", d, "--out", tmp_path / "outdir")[::2])
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_rollout_line_names_the_window_of_its_mean_velocity(run_cli):
    """``rollout --steps 20`` printed "mean vx (last 3 s)" for a 0.02 s rollout; the line now
    names the window the mean is taken over: the last 3 s, or the whole rollout if shorter."""
    code, out, _ = run_cli("rollout", "--steps", "20")
    assert code == 0 and "mean vx (last 0.02 s) " in out, out
