"""The examples/ user systems through phases 1-3: the Python API and ``latentune tune --system``.

The pure-numpy chain (``examples.toy_plant``) always runs; the Gymnasium Hopper
(``examples.gym_controller``) runs where ``gymnasium[mujoco]`` is installed.
"""
from __future__ import annotations

import json
import os
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.constants import C1, Phase
from latentune.system import as_outcome

ROOT = Path(__file__).resolve().parents[1]
N1, N3 = 16, 6                                   # phase-1 and phase-3 evaluations
FAST = ["--workers", "1", "--backend", "serial", "--quiet", "--vae-epochs", "30",
        "--latent-dim", "3"]

if str(ROOT) not in sys.path:           # ``examples`` is imported from the repository root
    sys.path.insert(0, str(ROOT))


@pytest.fixture
def run(run_cli, monkeypatch):
    """``latentune ARGS`` in-process with cwd = the repository root: ``(code, stdout, stderr)``."""
    monkeypatch.chdir(ROOT)
    return run_cli


@pytest.fixture
def run_process(cli):
    """``latentune ARGS`` in a subprocess with cwd = the repository root (the user module is
    imported from the working directory, as from a user's shell): ``(code, stdout, stderr)``."""
    def go(*args: object) -> tuple[int, str, str]:
        p = cli(*args, cwd=ROOT, timeout=300)
        return p.returncode, p.stdout, p.stderr
    return go


def counts(run: Path) -> dict[int, int]:
    con = sqlite3.connect(f"file:{run / 'run.db'}?mode=ro", uri=True)
    try:
        return dict(con.execute("SELECT phase, COUNT(*) FROM evaluations GROUP BY phase"))
    finally:
        con.close()


def check_report(run_dir: Path, run) -> None:
    code, out, err = run("report", run_dir, "--no-sim", "--quiet")
    assert code == 0, err
    assert "phase 3" in out and (run_dir / "report.md").is_file()


def through_the_api(system, real, tmp_path: Path, run) -> None:
    sim = lt.Study(tmp_path / "api", seed=1)
    assert sim.phase1(system, N1).n == N1
    latent = sim.train_latent(latent_dim=3, epochs=30)
    assert latent.d == system.space.dim and latent.d_low == 3
    assert sim.phase3(system, N3).n == N3
    sim.summary()
    sim.close()
    assert counts(tmp_path / "api") == {Phase.MANUAL: 1, Phase.PHASE1: N1, Phase.PHASE3: N3}
    check_report(tmp_path / "api", run)
    # sim-to-real: phase 3 on the perturbed system in the model's latent space (+ zero-shot row)
    target = lt.Study(tmp_path / "real", seed=1)
    target.phase3(real, 4, latent=tmp_path / "api")
    zs = target.store.rows(Phase.ZERO_SHOT)
    np.testing.assert_allclose(zs[0].theta, lt.Study(tmp_path / "api").best().theta)
    target.close()
    # the default (transfer) phase 3 spends no trial on the manual θ unless its model picks it
    assert counts(tmp_path / "real") == {Phase.ZERO_SHOT: 1, Phase.PHASE3: 4}


def through_the_cli(target: str, args: list[str], tmp_path: Path, run, report=None) -> Path:
    """``latentune tune --system TARGET`` through ``run``, then its report through ``report``
    (default: ``run``)."""
    out = tmp_path / "cli"
    sys_args = ["--system", target] + [x for a in args for x in ("--system-arg", a)]
    code, stdout, err = run("tune", *sys_args, "--out", out, "--phase1-evals", N1,
                            "--phase3-evals", N3, *FAST)
    assert code == 0, err
    assert "phase 3" in stdout
    assert counts(out) == {Phase.MANUAL: 1, Phase.PHASE1: N1, Phase.PHASE3: N3}
    cfg = json.loads((out / "summary.json").read_text())["config"]
    assert cfg["system"]["target"] == target
    check_report(out, report or run)
    return out


# ---------------------------------------------------------------------------- pure numpy
def test_numpy_chain_through_the_api(tmp_path, run):
    from examples import toy_plant

    model, real = toy_plant.make_system(), toy_plant.make_real_system()
    assert model.space.dim == 24
    manual = as_outcome(model.evaluate(model.space.manual))
    assert not manual.failed and 0 < manual.cost < C1
    through_the_api(model, real, tmp_path, run)
    # failed trials (the chain left the safe box) get the C1 convention, above every success
    rows = lt.Study(tmp_path / "api").store.rows(Phase.PHASE1)
    assert all(C1 <= r.cost <= 2 * C1 for r in rows if r.fell)
    assert all(r.cost < C1 for r in rows if not r.fell)


def test_numpy_chain_through_the_cli(tmp_path, run_process, run):
    """tune in a fresh process that imports the user module from its working directory."""
    out = through_the_cli("examples.toy_plant:make_system", ["steps=100"], tmp_path, run_process,
                          report=run)
    assert json.loads((out / "summary.json").read_text())["config"]["system"]["args"] == \
        {"steps": 100}


def test_numpy_chain_ask_tell(tmp_path, run):
    """One round of the ask/tell session (examples/ask_tell_session.sh) on the chain."""
    from examples import toy_plant

    d = tmp_path / "at"
    code, stdout, err = run("ask", d, "--system", "examples.toy_plant:make_real_system")
    assert code == 0, err
    sid, _, path, _ = stdout.strip().split("\t")
    real = toy_plant.make_real_system()
    out = as_outcome(real.evaluate(real.space.parse(json.loads(Path(path).read_text()))))
    code, _, err = run("tell", d, sid, "--cost", f"{out.cost:.6f}",
                       *(["--failed"] if out.failed else []))
    assert code == 0, err
    code, stdout, err = run("status", d, "--json")
    assert code == 0, err
    assert json.loads(stdout)["phases"]["phase 1"]["n"] == 1 and not Path(path).exists()


# ---------------------------------------------------------------------------- Gymnasium
def _hopper():
    pytest.importorskip("gymnasium")
    pytest.importorskip("mujoco")
    from examples import gym_controller

    return gym_controller


def test_hopper_controller_system():
    g = _hopper()
    model, real = g.make_system(episode_steps=400), g.make_real_system(episode_steps=400)
    assert model.space.dim == 36
    for s in (model, real):                       # the manual PD stands for the whole episode
        o = s.evaluate(s.space.manual)
        assert not o.failed and o.info["steps"] == 400 and 0 < o.cost < C1
    assert real.evaluate(real.space.manual).cost != model.evaluate(model.space.manual).cost
    # a fall is a failed trial with a cost below 100 that counts the fall penalty
    theta = model.space.manual.copy()
    theta[-3:] = 1.0                              # full thigh/leg/foot bias: falls
    o = model.evaluate(theta)
    assert o.failed and o.info["fall_step"] < 400 and 0 < o.cost <= C1
    import pickle

    assert pickle.loads(pickle.dumps(model)).evaluate(theta).cost == o.cost


def test_hopper_through_the_api_and_cli(tmp_path, run):
    g = _hopper()
    through_the_api(g.make_system(episode_steps=50), g.make_real_system(episode_steps=50),
                    tmp_path, run)
    through_the_cli("examples.gym_controller:make_system", ["episode_steps=50"], tmp_path, run)


def test_optuna_hopper_benchmark_warm_starts_every_sampler_and_reuses_traces(tmp_path,
                                                                              monkeypatch):
    """``benchmarks.optuna_hopper``: an Optuna sampler's trial 0 is the model's best θ, the θ
    of LatentSampler's zero-shot trial (the same cost on the same real Hopper), and a second
    call with the same settings reads the stored traces instead of running them again."""
    _hopper()
    pytest.importorskip("optuna")
    import json

    from benchmarks import optuna_hopper as oh

    args = ["--seeds", "0", "--trials", "3", "--phase1-evals", "20", "--episode-steps", "50",
            "--models", str(tmp_path / "m"), "--samplers", "latent", "tpe", "--checkpoints",
            "3", "--out", str(tmp_path / "o.json")]
    assert oh.main(args) == 0
    res = json.loads((tmp_path / "o.json").read_text())
    lat, tpe = (res["per_seed"][0]["samplers"][m] for m in ("latent", "tpe"))
    assert lat["costs"][0] == tpe["costs"][0] and len(tpe["costs"]) == 3
    assert (tmp_path / "traces" / "seed0" / "tpe.json").is_file()
    monkeypatch.setattr(oh, "run_sampler", lambda *a, **k: pytest.fail("ran a stored trace"))
    assert oh.main(args) == 0
    assert json.loads((tmp_path / "o.json").read_text())["per_seed"] == res["per_seed"]


LADDER = ["arm_controller", "buck_converter", "cartpole_swingup", "lqr_chain", "quadrotor_mpc",
          "servo_cascade", "thermal_zones", "vehicle_lateral"]


STEPS_ARGS = [{"steps": 2.5}, {"steps": True}, {"steps": -3}, {"steps": 0}]
FACTORY_CASES = [(name, arg) for name in LADDER for arg in [{"gap": True}, *STEPS_ARGS]
                 if name != "arm_controller" or "steps" not in arg]      # the arm has no steps


@pytest.mark.parametrize("name, arg", FACTORY_CASES)
def test_example_factories_refuse_a_bool_or_fractional_steps(name, arg):
    """--system-arg steps=2.5 ran 2 steps, steps=true one, gap=true a gap of 1, and the lqr
    chain ran steps=-3 as no step at all (cost 0): each is a ValueError naming the argument."""
    import importlib

    make = importlib.import_module(f"examples.{name}").make_system
    assert "gap" in arg or "steps" in make.__code__.co_varnames
    with pytest.raises(ValueError, match=f"{next(iter(arg))} must be"):
        make(**arg)
    assert make(**({"steps": 3.0} if "steps" in arg else {"gap": 0.5})) is not None


@pytest.mark.parametrize("name", LADDER)
def test_example_delay_is_no_longer_than_the_episode(name):
    """A huge gap (odd but legal: --system-arg gap=1e9, 1e308) made a delay queue of 1e9
    entries (thermal_zones: killed for memory; others minutes per trial) or raised
    OverflowError; a delay longer than the episode is the same as the episode's length: the
    trial is as it was and takes no longer than at gap 2."""
    import importlib
    import time

    make = importlib.import_module(f"examples.{name}").make_system
    for gap in (1e9, 1e308):
        system = make(gap=gap)
        steps = getattr(system, "steps", 1200)
        assert system.delay <= steps
    short = {"steps": 20} if "steps" in make.__code__.co_varnames else {}
    t0 = time.perf_counter()
    system = make(gap=1e6, **short)
    with np.errstate(all="ignore"):
        out = as_outcome(system.evaluate(system.space.manual))
    assert time.perf_counter() - t0 < 20 and np.isfinite(out.cost)


@pytest.mark.parametrize("target, arg", [
    ("toy_plant:make_real_system", {"mass_scale": -1}),
    ("toy_plant:make_real_system", {"stiffness_scale": float("nan")}),
    ("toy_plant:make_real_system", {"gain_scale": True}),
    ("toy_plant:make_real_system", {"damping_scale": -0.5}),
    ("gym_controller:make_real_system", {"episode_steps": 2.5}),
    ("gym_controller:make_real_system", {"episode_steps": True}),
    ("gym_controller:make_real_system", {"action_delay": 2.5}),
    ("gym_controller:make_system", {"seed": -1}),
    ("gym_controller:make_system", {"seed": 2.5}),
])
def test_toy_and_hopper_factories_refuse_what_they_cannot_run(target, arg):
    """The toy plant ran a negative or NaN mass (a fall or a NaN cost at the first trial),
    the Hopper truncated episode_steps=2.5, action_delay=2.5 and seed=2.5, and seed=-1 raised
    in gymnasium at the first trial: each is a ValueError from the factory, naming it."""
    import importlib

    module, factory = target.split(":")
    if module == "gym_controller":
        pytest.importorskip("gymnasium")
    make = getattr(importlib.import_module(f"examples.{module}"), factory)
    with pytest.raises(ValueError, match=f"{next(iter(arg))} must be"):
        make(**arg)
    assert make(**{k: 1 for k in arg}) is not None


def _fake_real_runs(monkeypatch, rows: dict[int, list[tuple[float, bool]]]):
    """examples.sim_to_real with lt.Study a stand-in whose stores hold ``rows`` (phase ->
    [(cost, fell)] in idx order) and whose phases run nothing."""
    import types

    import examples.sim_to_real as s2r

    def row(i, cost, fell):
        return types.SimpleNamespace(idx=i, cost=cost, fell=fell, info={"return": -cost})

    class Fake:
        def __init__(self, *a, **k):
            self.store = types.SimpleNamespace(
                rows=lambda ph: [row(i, c, f) for i, (c, f) in enumerate(rows[ph])])

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return None

        def phase1(self, *a, **k):
            return None

        phase3 = phase1

    monkeypatch.setattr(s2r, "lt", types.SimpleNamespace(Study=Fake))
    monkeypatch.setattr(s2r, "make_real_system", lambda **k: None)
    return s2r


def test_sim_to_real_never_reports_a_fall_as_the_best(monkeypatch):
    """examples/sim_to_real.py reported a trial that fell as a method's best θ (the Hopper's
    falls keep a finite cost, often the lowest) and counted it as beating the zero-shot θ;
    now the best, the best-so-far curve and the evals to beat count the trials that stood
    only, and a method whose every trial fell says so."""
    s2r = _fake_real_runs(monkeypatch, {
        Phase.MANUAL: [(50.0, False)], Phase.ZERO_SHOT: [(40.0, False)],
        Phase.PHASE3: [(45.0, False), (10.0, True), (30.0, False)],
        Phase.PHASE1: [(5.0, True), (6.0, True)]})
    res = s2r.run_real("m", "p3", "d", 0, 3)
    p3, d = res["phase3"], res["direct"]
    assert (p3["best"], p3["best_idx"], p3["all_fell"]) == (30.0, 2, False)
    assert p3["best_so_far"] == [45.0, 45.0, 30.0]
    assert (p3["evals_to_beat_zero_shot"], p3["evals_to_beat_manual"]) == (3, 1)
    assert d["best"] is None and d["all_fell"] and d["best_so_far"] == [None, None]
    assert d["evals_to_beat_zero_shot"] is None and d["best_return"] is None
    table = s2r.table(res)
    assert "| 30.00 |" in table and "all 2 fell" in table and "10.00" not in table


def test_sim_to_real_a_stood_trial_beats_a_zero_shot_that_fell(monkeypatch):
    """A zero-shot θ that fell is beaten by the first tuned trial that stands (whatever the
    fall's cost), never by another fall."""
    s2r = _fake_real_runs(monkeypatch, {
        Phase.MANUAL: [(50.0, False)], Phase.ZERO_SHOT: [(5.0, True)],
        Phase.PHASE3: [(4.0, True), (60.0, False)], Phase.PHASE1: [(70.0, False)]})
    res = s2r.run_real("m", "p3", "d", 0, 2)
    assert res["phase3"]["evals_to_beat_zero_shot"] == 2
    assert res["direct"]["evals_to_beat_zero_shot"] == 1
    assert res["direct"]["evals_to_beat_manual"] is None


def test_optuna_hopper_never_reports_a_fall_as_the_best():
    """examples/optuna_hopper.py printed the lowest value of any trial as a study's best cost
    (the simulator's and the real Hopper's table), a fall's too (the Hopper's falls keep a
    finite, often the lowest, cost); now the best is over the trials that stood, FAIL trials
    count as falls, and a study whose every trial fell says so."""
    optuna = pytest.importorskip("optuna")
    from examples import optuna_hopper as oh

    FD = optuna.distributions.FloatDistribution
    study = optuna.create_study()
    for x, fell in ((0.1, True), (0.5, False), (0.3, False)):
        study.add_trial(optuna.trial.create_trial(
            params={"x": x}, distributions={"x": FD(0, 1)}, value=x,
            system_attrs={"constraints:fall": 1.0 if fell else 0.0}))
    study.add_trial(optuna.trial.create_trial(params={"x": 0.2}, distributions={"x": FD(0, 1)},
                                              state=optuna.trial.TrialState.FAIL))
    assert oh.results_of(study) == (0.3, 2, 4)
    only_falls = optuna.create_study()
    only_falls.add_trial(optuna.trial.create_trial(
        params={"x": 0.1}, distributions={"x": FD(0, 1)}, value=0.1,
        user_attrs={"latentune_failed": True}))
    assert oh.results_of(only_falls) == (None, 1, 1)
    assert oh._best_text(None) == "none (every trial fell)"


BAD_COUNTS = [(["--episode-steps", "0"], "--episode-steps must be >= 1, got 0"),
              (["--seed", "-1"], "--seed must be >= 0, got -1"),
              (["--latent-dim", "0"], "--latent-dim must be in [1, 35]"),
              (["--latent-dim", "36"], "--latent-dim must be in [1, 35]")]
PHASES = [(["--phase1-evals", "0"], "--phase1-evals must be >= 1, got 0"),
          (["--phase3-evals", "0"], "--phase3-evals must be >= 1, got 0")]


@pytest.mark.parametrize("module, args, says", [
    *[("sim_to_real", *c) for c in BAD_COUNTS + PHASES
      + [(["--workers", "0"], "--workers must be >= 1, got 0")]],
    *[("gym_controller", *c) for c in BAD_COUNTS + PHASES],
    *[("optuna_hopper", *c) for c in BAD_COUNTS
      + [(["--sim-trials", "0"], "--sim-trials must be >= 1, got 0"),
         (["--trials", "0"], "--trials must be >= 1, got 0")]]])
def test_hopper_examples_bad_input_is_one_line_before_any_trial(tmp_path, capsys, module,
                                                                 args, says):
    """python -m examples.sim_to_real --phase1-evals 0 (or --episode-steps 0, --seed -1) ended
    in a traceback, and so did every bad argument of examples.gym_controller and
    examples.optuna_hopper; --phase3-evals 0 or --latent-dim 36 were refused only after phase 1
    ran (300 evaluations by default). Each is one line on stderr and exit status 2, before
    anything is written."""
    pytest.importorskip("gymnasium")
    import importlib

    if module == "optuna_hopper":
        pytest.importorskip("optuna")
    mod = importlib.import_module(f"examples.{module}")
    code = mod.main(["--out", str(tmp_path / "out"), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and says in err and len(err.splitlines()) == 1, err
    assert err.startswith(f"examples.{module}: error: ") and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_optuna_hopper_refuses_an_out_of_other_settings(tmp_path, capsys, monkeypatch):
    """python -m examples.optuna_hopper again into its --out with another --episode-steps (or
    seed, --sim-sampler) resumed the stored studies and printed them as runs of the new
    settings; another --latent-dim or seed was a traceback. The settings are recorded in a new
    --out and a re-run of others is one line, exit 2; the same settings (budgets may grow)
    resume; an --out that is a file is one line."""
    pytest.importorskip("gymnasium")
    pytest.importorskip("optuna")
    from examples import optuna_hopper as oh

    ran = []
    monkeypatch.setattr(oh, "_run", lambda a: ran.append(a) or 0)     # no trial: the checks
    out = tmp_path / "oh"
    base = ["--out", str(out), "--episode-steps", "50"]
    assert oh.main(base) == 0 and len(ran) == 1
    assert json.loads((out / "example.json").read_text()) == {
        "seed": 0, "episode_steps": 50, "sim_sampler": "turbo", "latent_dim": 5}
    assert oh.main([*base, "--trials", "80", "--sim-trials", "400", "--baseline"]) == 0
    for extra, says in ((["--episode-steps", "60"], "--episode-steps 50 (not 60)"),
                        (["--seed", "1"], "--seed 0 (not 1)"),
                        (["--sim-sampler", "tpe"], "--sim-sampler turbo (not tpe)"),
                        (["--latent-dim", "3"], "--latent-dim 5 (not 3)")):
        capsys.readouterr()
        assert oh.main([*base, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("examples.optuna_hopper: error: ") and \
            says in err[0] and str(out) in err[0], err
    assert len(ran) == 2
    (tmp_path / "file").write_text("")
    assert oh.main(["--out", str(tmp_path / "file")]) == 2
    assert "is not a directory" in capsys.readouterr().err


def test_gym_controller_into_an_out_of_another_run_is_one_line(tmp_path, capsys):
    """python -m examples.gym_controller again into its --out with another --episode-steps
    (a study of another system) was a StoreError traceback; it is one line, exit 2."""
    g = _hopper()
    with lt.Study(tmp_path / "h", seed=0) as st:
        st.phase1(g.make_system(episode_steps=5), 2)
    assert g.main(["--out", str(tmp_path / "h"), "--episode-steps", "6",
                   "--phase1-evals", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("examples.gym_controller: error: ") and \
        str(tmp_path / "h") in err[0], err
    # an --out of another seed, or a file: the refusal came after an episode of the manual θ
    # and its "36 tuned weights; manual θ: cost ..." line; it is the one line, nothing run
    (tmp_path / "file").write_text("")
    for argv, says in ((["--out", str(tmp_path / "h"), "--episode-steps", "5", "--seed", "3"],
                        "seed = 0, not 3"),
                       (["--out", str(tmp_path / "file")], "is not a directory")):
        assert g.main([*argv, "--phase1-evals", "2"]) == 2
        out, err = capsys.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1 and says in err, (out, err)


@pytest.mark.parametrize("trials", ["abc", "0", "-3", "2.5"])
def test_ask_tell_session_refuses_a_bad_trial_count(tmp_path, trials):
    """bash examples/ask_tell_session.sh ROOT abc printed seq's "invalid floating point
    argument", ran no trial and ended in "latentune: error: no run store" (0: the same without
    seq's line); a TRIALS that is not a whole number >= 1 is now one line, exit 2, before any
    command runs."""
    import subprocess

    script = Path(__file__).resolve().parents[1] / "examples" / "ask_tell_session.sh"
    p = subprocess.run(["bash", str(script), str(tmp_path / "at"), trials], capture_output=True,
                       text=True, env={**os.environ, "LATENTUNE": "false", "PYTHON": "false"},
                       timeout=60)
    assert p.returncode == 2 and p.stdout == "", p
    assert p.stderr == ("ask_tell_session.sh: error: TRIALS must be a whole number >= 1, got "
                        f"'{trials}'\n")
    assert not (tmp_path / "at").exists()


@pytest.mark.parametrize("module", ["gym_controller", "sim_to_real", "optuna_hopper"])
def test_hopper_examples_run_as_files(tmp_path, module):
    """python examples/gym_controller.py (its ``__main__`` is written for it) stopped at
    ``from examples import …`` with ModuleNotFoundError unless the repository was on the path;
    each Hopper example now runs as a file from anywhere (here: its one-line refusal)."""
    import subprocess

    pytest.importorskip("gymnasium")
    if module == "optuna_hopper":
        pytest.importorskip("optuna")
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, str(root / "examples" / f"{module}.py"), "--seed", "-1"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(root / "src")})
    assert p.returncode == 2 and p.stderr == f"examples.{module}: error: --seed must be >= 0, " \
        "got -1\n", p.stderr
