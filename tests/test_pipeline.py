"""The three-phase pipeline end to end through the command line: `tune` outputs, `report`, and
bad input refused with one line that names the problem, the store left unchanged.

Fast: rollouts of 200 steps and budgets of tens of evaluations; the commands run in-process
(`latentune.cli.main`); tests/test_evaluators.py covers the runs that need processes.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from latentune.cli import main
from latentune.pipeline.store import RunStore

TINY = ["--robot", "a1", "--task", "trot", "--steps", "200", "--quiet"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A tiny `tune` run (serial) shared by the tests of this file."""
    out = tmp_path_factory.mktemp("runs") / "small"
    code = main(["tune", *TINY, "--out", str(out), "--phase1-evals", "16", "--phase3-evals", "8",
                 "--backend", "serial", "--vae-epochs", "30"])
    assert code == 0
    return out


def test_tune_outputs(small_run, run_cli):
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
    assert isinstance(best, dict) and len(best) == 26        # 25 weights, what they fit
    assert best["tuned_for"] == {"robot": "a1", "gait": "trot", "actor": "convex"}
    code, out, err = run_cli("rollout", "--robot", "a1", "--task", "trot", "--steps", "200",
                             "--json", "--params", small_run / "phase1_best.json")
    assert code == 0, err
    assert json.loads(out)["cost"] == pytest.approx(s["phase1_best"], rel=1e-6)
    assert (small_run / "vae.pt").is_file() and (small_run / "vae.json").is_file()


def test_report(small_run, run_cli, dump_store):
    before = dump_store(small_run)[0]
    code, out, err = run_cli("report", small_run, "--quiet")
    assert code == 0, err
    assert "phase 1" in out and "phase 3" in out
    for f in ("report.md", "best_so_far.png", "com_velocity.png"):
        assert (small_run / f).stat().st_size > 0
    assert dump_store(small_run)[0] == before


def test_bad_input(small_run, tmp_path, run_cli, error_line, dump_store):
    """Each bad input gives one error line naming its problem; no store is created or changed."""
    from latentune.latent import LatentSpace

    def error(*args: object) -> str:
        code, _, err = run_cli(*args)
        return error_line(code, err)

    before = dump_store(small_run)
    # missing run directory / store
    assert f"no run store in {tmp_path / 'nope'}" in error("report", tmp_path / "nope")
    assert "no run store in" in error("train-vae", *TINY, "--out", tmp_path / "nope")
    assert "no run store in" in error("phase3", *TINY, "--out", tmp_path / "nope2")
    assert not (tmp_path / "nope2").exists()
    # corrupt store
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "run.db").write_bytes(os.urandom(4096))
    raw = (bad / "run.db").read_bytes()
    assert "is not a latentune run store" in error("report", bad)
    assert "is not a latentune run store" in error("phase1", *TINY, "--out", bad, "--resume")
    assert (bad / "run.db").read_bytes() == raw
    # resume with another configuration
    msg = error("tune", "--robot", "a1", "--task", "jump", "--steps", "200", "--quiet",
                "--out", small_run, "--resume")
    assert "another system" in msg and "jump" in msg
    assert "--seed 0 (stored), not --seed 5" in error("tune", *TINY, "--seed", "5", "--out",
                                                      small_run, "--resume")
    # the run exists: no silent re-run without --resume
    assert "pass --resume" in error("phase1", *TINY, "--out", small_run)
    # a VAE of another θ dimension
    other = tmp_path / "vae12"
    other.mkdir()
    LatentSpace.train(np.random.default_rng(0).random((20, 12)), seed=0, epochs=2).save(other / "vae")
    for args in (["--out", small_run, "--resume"], ["--out", tmp_path / "x"]):
        assert "maps to 12-dim θ, but the system has 25-dim θ" in error(
            "phase3", *TINY, "--vae", other, *args)
    assert not (tmp_path / "x").exists()
    # budgets < 1
    assert "--phase1-evals must be >= 1, got 0" in error(
        "tune", *TINY, "--out", tmp_path / "b0", "--phase1-evals", "0")
    assert "--phase3-evals must be >= 1, got -3" in error(
        "phase3", *TINY, "--out", small_run, "--phase3-evals", "-3", "--resume")
    assert not (tmp_path / "b0").exists()
    assert dump_store(small_run) == before
