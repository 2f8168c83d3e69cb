"""A best-θ file latentune writes (``best.json``, ``phase<p>_best.json``) names
the robot, gait and controller (or the user system) it was tuned for, and a command that knows
its own refuses a file of another: B1's best θ is not silently run on A1. A file without that
record (written by hand, by an older latentune, or a suggestion's file, which holds the values by
name only) is read as before."""
from __future__ import annotations

import contextlib
import io
import json

import pytest

from latentune.errors import ParamsError


@pytest.fixture(scope="module")
def b1_best(tmp_path_factory):
    """``best.json`` of an ask/tell study of B1 trot (one told trial), made once."""
    from latentune.cli import main

    d = tmp_path_factory.mktemp("b1") / "run"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["ask", str(d), "--robot", "b1", "--task", "trot", "--steps", "20",
                     "--start", "scratch", "--json"]) == 0
        (s,) = json.loads(out.getvalue())
        assert main(["tell", str(d), str(s["id"]), "--cost", "1.5"]) == 0
        assert main(["best", str(d)]) == 0
    return d / "best.json"


def test_best_json_names_what_it_was_tuned_for(b1_best):
    data = json.loads(b1_best.read_text())
    assert data["tuned_for"] == {"robot": "b1", "gait": "trot", "actor": "convex"}
    assert len(data) == 26                              # the 25 weights and the record


def test_rollout_refuses_the_best_of_another_robot_or_gait(b1_best, run_cli, error_line):
    line = error_line(*run_cli("rollout", "--robot", "a1", "--task", "trot", "--steps", "20",
                               "--params", b1_best)[::2])
    assert f"{b1_best} holds θ tuned for b1 trot (convex), not a1 trot (convex)" in line
    line = error_line(*run_cli("rollout", "--robot", "b1", "--task", "jump", "--steps", "20",
                               "--params", b1_best)[::2])
    assert "tuned for b1 trot (convex), not b1 jump (convex)" in line
    code, out, err = run_cli("rollout", "--robot", "b1", "--task", "trot", "--steps", "20",
                             "--params", b1_best, "--terrain", "hills")
    assert code == 0, err                               # its own robot, elsewhere: run


def test_a_file_without_the_record_is_read_as_before(b1_best, tmp_path, run_cli):
    plain = tmp_path / "plain.json"
    data = json.loads(b1_best.read_text())
    del data["tuned_for"]
    plain.write_text(json.dumps(data))
    code, out, err = run_cli("rollout", "--robot", "a1", "--steps", "20", "--params", plain)
    assert code == 0, err


def test_ask_start_refuses_the_best_of_another_robot(b1_best, tmp_path, run_cli, error_line):
    line = error_line(*run_cli("ask", tmp_path / "a1", "--robot", "a1", "--steps", "20",
                               "--start", b1_best)[::2])
    assert "--start" in line and "tuned for b1 trot (convex), not a1 trot (convex)" in line
    assert not (tmp_path / "a1").exists()


def test_the_api_refuses_it_too(b1_best):
    import latentune as lt

    with pytest.raises(ParamsError, match="tuned for b1 trot \\(convex\\), not a1 trot"):
        lt.Task(robot="a1", gait="trot", steps=20).space.load(b1_best)
    b1 = lt.Task(robot="b1", gait="trot", steps=20)
    theta = b1.space.load(b1_best)
    assert b1.space.as_dict(theta) == pytest.approx(
        {k: v for k, v in json.loads(b1_best.read_text()).items() if k != "tuned_for"})


def test_a_studys_stored_space_refuses_another_robots_file(b1_best, tmp_path):
    """``Study(dir).space()`` (the space of the stored run, as a script reads θ files for it)
    took a file tuned for another robot; it knows the study's robot and refuses it."""
    import latentune as lt

    a1 = tmp_path / "a1.json"
    a1.write_text(json.dumps({**json.loads(b1_best.read_text()),
                              "tuned_for": {"robot": "a1", "gait": "trot", "actor": "convex"}}))
    space = lt.Study(b1_best.parent).space()
    with pytest.raises(ParamsError, match="tuned for a1 trot \\(convex\\), not b1 trot"):
        space.load(a1)
    space.load(b1_best)
