"""The Optuna integration: LatentSampler / TurboSampler under study.optimize and ask/tell (two
worker processes on one journal storage), and an Optuna study imported as a phase-1 run, turned
into a latent space, with the import rules (``latentune.integrations.optuna``)."""
from __future__ import annotations

import argparse
import json
import logging
import math
import multiprocessing
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

optuna = pytest.importorskip("optuna", reason="the optuna extra (CI installs it)")

import latentune as lt  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.errors import LatentuneError, UsageError  # noqa: E402
from latentune.integrations import register_cli  # noqa: E402
from latentune.integrations.optuna import (FAILED_ATTR, POINT_ATTR, LatentSampler,  # noqa: E402
                                           OptunaImportError, TurboSampler, import_optuna_study)

optuna.logging.set_verbosity(optuna.logging.WARNING)
FD = optuna.distributions.FloatDistribution
S = optuna.trial.TrialState
D = 12
NAMES = [f"w{i}" for i in range(D)]
DISTS = {n: FD(-1.0, 1.0) for n in NAMES}
ROOT = Path(__file__).resolve().parents[1]


def cost(x: np.ndarray, shift: float = 0.0) -> tuple[float, bool]:
    """A quadratic bowl; a trial with w0 > 0.8 falls."""
    return float(np.sum((x - 0.2 - shift) ** 2)), bool(x[0] > 0.8)


def manifold(n: int, seed: int = 0) -> np.ndarray:
    """(n, D) θ in [-1, 1]^D near a 3-dim manifold (a VAE can learn it from few points)."""
    rng = np.random.default_rng(seed)
    A = np.random.default_rng(123).normal(size=(D, 3))
    s = rng.uniform(-1, 1, size=(n, 3))
    return -1 + 2 * (0.5 + 0.45 * np.tanh(s @ A.T / 1.5))


def journal_study(path: Path, n: int) -> Path:
    """:func:`simulator_study` "sim" in an Optuna journal file (quicker to create and open than
    an SQLite database, whose schema Optuna sets up); returns the file's path."""
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    simulator_study(JournalStorage(JournalFileBackend(str(path))), n=n)
    return path


def simulator_study(storage, name: str = "sim", n: int = 60, direction: str = "minimize"):
    """An Optuna study "run on a simulator": n COMPLETE trials on the manifold."""
    study = optuna.create_study(storage=storage, study_name=name, direction=direction)
    sign = -1.0 if direction == "maximize" else 1.0
    trials = []
    for x in manifold(n):
        c, f = cost(x)
        trials.append(optuna.trial.create_trial(
            params=dict(zip(NAMES, map(float, x))), distributions=DISTS, value=sign * c,
            system_attrs={"constraints:fall": 1.0 if f else 0.0}))
    study.add_trials(trials)
    return study


@pytest.fixture(scope="module")
def source_run(tmp_path_factory):
    """An Optuna simulator study imported into a latentune run, with its latent space."""
    root = tmp_path_factory.mktemp("optuna_src")
    storage = optuna.storages.InMemoryStorage()
    simulator_study(storage)
    study = import_optuna_study(storage, "sim", root / "sim", seed=0)
    latent = study.train_latent(latent_dim=3, epochs=300)
    assert latent.d == D and latent.d_low == 3
    assert np.all(latent.box[:, 1] - latent.box[:, 0] > 0.05)       # not a collapsed code
    return root / "sim"


def objective_for(sampler, shift: float = 0.1):
    def objective(trial):
        p = sampler.suggest_all(trial)
        c, fell = cost(np.array([p[n] for n in NAMES]), shift)
        trial.set_constraint("fall", 1.0 if fell else 0.0)
        return c
    return objective


def thetas(study) -> list[tuple[float, ...]]:
    return [tuple(t.params[n] for n in NAMES) for t in study.trials]


# ---------------------------------------------------------------------------- import
def test_import_rules(tmp_path):
    storage = optuna.storages.InMemoryStorage()
    study = optuna.create_study(storage=storage, study_name="s", direction="maximize")
    X = manifold(8, seed=1)
    mk = optuna.trial.create_trial
    p = [dict(zip(NAMES, map(float, x))) for x in X]
    study.add_trials([
        mk(params=p[0], distributions=DISTS, value=3.0),                         # plain
        mk(params=p[1], distributions=DISTS, value=5.0,
           system_attrs={"constraints:fall": 0.5}),                             # constraint > 0
        mk(params=p[2], distributions=DISTS, value=1.0, user_attrs={FAILED_ATTR: True}),
        mk(params=p[3], distributions=DISTS, state=S.FAIL, value=None),          # a FAIL trial
        mk(params=p[4], distributions=DISTS, state=S.PRUNED, value=None),        # left out
        mk(params=p[5], distributions=DISTS, state=S.RUNNING, value=None),       # left out
        mk(params=p[6], distributions=DISTS, value=2.0,
           system_attrs={"constraints": [-1.0, 0.0]}),                          # feasible, old form
        mk(params={"w0": 0.1}, distributions={"w0": DISTS["w0"]}, value=9.0),    # lacks parameters
    ])
    study.enqueue_trial(p[7])                                                    # WAITING
    with pytest.warns(UserWarning, match="1 finished trial"):
        lt_study = import_optuna_study(storage, "s", tmp_path / "run", seed=4)
    rows = lt_study.store.rows(Phase.PHASE1)
    assert [r.info["optuna_trial"] for r in rows] == [0, 1, 2, 3, 6]
    assert [r.cost for r in rows] == [-3.0, -5.0, -1.0, math.inf, -2.0]       # maximize negated
    assert [r.fell for r in rows] == [False, True, True, True, False]
    assert all(r.tag == -1 and r.seed == 4 for r in rows)
    np.testing.assert_allclose(rows[0].theta, (X[0] + 1) / 2, atol=1e-12)
    cfg = lt_study.config()
    assert cfg["system"]["kind"] == "optuna" and cfg["system"]["direction"] == "maximize"
    assert cfg["space"]["names"] == NAMES and cfg["phase1"]["method"] == "optuna"
    best = json.loads((tmp_path / "run" / "phase1_best.json").read_text())
    assert best["w0"] == pytest.approx(X[0][0])     # 3.0: the best feasible; 5.0 broke a constraint
    # importing again adds only what is new
    study.add_trial(mk(params=p[7], distributions=DISTS, value=4.0))
    with pytest.warns(UserWarning, match="lack some of the parameters"):
        again = import_optuna_study(storage, "s", tmp_path / "run", seed=4)
    assert [r.info["optuna_trial"] for r in again.store.rows(Phase.PHASE1)][-1] == 9
    assert again.store.count(Phase.PHASE1) == 6
    # another study into the same directory is refused
    other = optuna.create_study(storage=storage, study_name="other")
    other.add_trial(mk(params={"a": 0.5}, distributions={"a": FD(0, 1)}, value=1.0))
    with pytest.raises(LatentuneError, match="holds another run: an import of study 's', "
                                             "not of 'other'$"):
        import_optuna_study(storage, "other", tmp_path / "run")  # seed: the stored one


def test_a_second_import_whose_trials_widen_a_bound_names_it(tmp_path):
    """Importing a study again after a trial suggested a parameter on wider bounds said only
    "holds another run (not an import of study 's' with this space)", naming neither the
    parameter nor the bounds; it names the first that differs, in the run and in the study."""
    storage = optuna.storages.InMemoryStorage()
    study = optuna.create_study(storage=storage, study_name="s")
    mk = optuna.trial.create_trial
    study.add_trial(mk(params={"a": 0.5, "b": 1.0}, value=1.0,
                       distributions={"a": FD(0, 1), "b": FD(0, 3)}))
    import_optuna_study(storage, "s", tmp_path / "run")
    study.add_trial(mk(params={"a": 0.5, "b": 3.5}, value=0.5,
                       distributions={"a": FD(0, 1), "b": FD(0, 4)}))
    with pytest.raises(LatentuneError, match=r"holds another run: an import of study 's' with "
                       r"another space \(b: \[0, 3\] there, \[0, 4\] here; there: the run, "
                       r"here: the study's trials now\); import it into a new directory$"):
        import_optuna_study(storage, "s", tmp_path / "run")
    assert lt.Study(tmp_path / "run").store.count(Phase.PHASE1) == 1


def test_import_log_and_refusals(tmp_path):
    storage = optuna.storages.InMemoryStorage()
    mk = optuna.trial.create_trial

    def one(name, dists, params):
        s = optuna.create_study(storage=storage, study_name=name)
        s.add_trial(mk(params=params, distributions=dists, value=1.0))
        s.add_trial(mk(params=params, distributions=dists, value=2.0))

    one("log", {"kp": FD(0.01, 10.0, log=True), "kd": FD(0.0, 1.0)}, {"kp": 0.1, "kd": 0.5})
    sp = import_optuna_study(storage, "log", tmp_path / "log").space()
    assert list(sp.log) == [True, False] and sp.lower[0] == 0.01 and sp.upper[0] == 10.0
    one("int", {"n": optuna.distributions.IntDistribution(1, 5)}, {"n": 2})
    one("step", {"x": FD(0.0, 1.0, step=0.25)}, {"x": 0.5})
    one("cat", {"c": optuna.distributions.CategoricalDistribution(["a", "b"])}, {"c": "a"})
    for name, msg in (("int", "'n' is an integer distribution"),
                      ("step", "'x' is a stepped float"), ("cat", "'c' is categorical")):
        with pytest.raises(OptunaImportError, match=msg) as ei:
            import_optuna_study(storage, name, tmp_path / name)
        assert "\n" not in str(ei.value)
        assert not (tmp_path / name).exists()                 # nothing written on refusal
    mo = optuna.create_study(storage=storage, study_name="mo", directions=["minimize"] * 2)
    mo.add_trial(mk(params={"x": 0.5}, distributions={"x": FD(0, 1)}, values=[1.0, 2.0]))
    with pytest.raises(OptunaImportError, match="2 objectives"):
        import_optuna_study(storage, "mo", tmp_path / "mo")
    with pytest.raises(OptunaImportError, match="no study 'nope'"):
        import_optuna_study(storage, "nope", tmp_path / "nope")
    with pytest.raises(OptunaImportError, match="not found"):
        import_optuna_study(tmp_path / "missing.log", None, tmp_path / "x")
    narrow = lt.ParameterSpace(["kp", "kd"], [0.01, 0.0], [10.0, 0.4], log=[True, False])
    with pytest.raises(OptunaImportError, match=r"trial 0: kd = 0.5 outside \[0, 0.4\] \(of the "
                                                r"given space\)"):    # was: the first 3 params
        import_optuna_study(storage, "log", tmp_path / "narrow", narrow)


def test_import_of_a_study_with_no_finished_trial_says_so(tmp_path):
    """A study with no trial yet, or only pruned and running ones, is refused as having no
    finished trial to import (was: "no parameters: the study has no trial with float
    parameters", with or without a space naming them, and for a running trial with float
    parameters); a space naming none of the study's parameters names them (was the same)."""
    storage = optuna.storages.InMemoryStorage()
    optuna.create_study(storage=storage, study_name="empty")
    busy = optuna.create_study(storage=storage, study_name="busy")
    busy.ask().suggest_float("a", 0.0, 1.0)                          # RUNNING
    pruned = busy.ask()
    pruned.suggest_float("a", 0.0, 1.0)
    busy.tell(pruned, state=S.PRUNED)
    space = lt.ParameterSpace(["a"], [0.0], [1.0])
    for name, sp, msg in (("empty", None, "study 'empty' has no finished trial .*: it holds none"),
                          ("empty", space, "study 'empty' has no finished trial"),
                          ("busy", None, r"study 'busy' has no finished trial \(COMPLETE or "
                                         r"FAIL\) to import: it holds 2 \(1 pruned, 1 running\)"),
                          ("busy", space, "study 'busy' has no finished trial")):
        with pytest.raises(OptunaImportError, match=msg) as ei:
            import_optuna_study(storage, name, tmp_path / name, sp)
        assert "\n" not in str(ei.value) and not (tmp_path / name).exists()
    done = optuna.create_study(storage=storage, study_name="done")
    done.add_trial(optuna.trial.create_trial(params={"a": 0.5}, distributions={"a": FD(0, 1)},
                                             value=1.0))
    xy = lt.ParameterSpace(["x", "y"], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(OptunaImportError, match="the given space names parameter.s. the study's "
                                                "finished trials do not have: x, y"):
        import_optuna_study(storage, "done", tmp_path / "xy", xy)


def test_import_with_a_space_leaves_out_the_parameters_outside_it(tmp_path):
    """An objective that also suggests an int and a categorical parameter outside the
    controller: a space naming the float parameters imports their values (a warning names the
    others and says their values varied); without a space the refusal says to name them; a
    named parameter that is not a float is still refused."""
    storage = optuna.storages.InMemoryStorage()
    study = optuna.create_study(storage=storage, study_name="mixed",
                                sampler=optuna.samplers.RandomSampler(0))

    def objective(trial):
        a, b = trial.suggest_float("a", 0.0, 1.0), trial.suggest_float("b", 0.0, 1.0)
        n = trial.suggest_int("layers", 1, 3)
        trial.suggest_categorical("solver", ["x", "y"])
        return (a - 0.3) ** 2 + (b - 0.6) ** 2 + 0.01 * n

    study.optimize(objective, n_trials=8)
    with pytest.raises(OptunaImportError, match="'layers' is an integer .* naming them in "
                                                r"space= \(--space FILE\)"):
        import_optuna_study(storage, "mixed", tmp_path / "all")
    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0])
    with pytest.warns(UserWarning, match=r"layers, solver left out \(not in the given space\); "
                                         "the values of layers, solver varied") as rec:
        run = import_optuna_study(storage, "mixed", tmp_path / "ab", space)
    assert len(rec) == 1 and "\n" not in str(rec[0].message)
    rows = run.store.rows(Phase.PHASE1)
    assert [r.info["optuna_trial"] for r in rows] == list(range(8))
    np.testing.assert_allclose([r.theta for r in rows],
                               [[t.params["a"], t.params["b"]] for t in study.trials])
    assert run.config()["phase1"]["import"]["left_out_params"] == ["layers", "solver"]
    three = lt.ParameterSpace(["a", "b", "layers"], [0.0, 0.0, 1.0], [1.0, 1.0, 3.0])
    with pytest.raises(OptunaImportError, match="'layers' is an integer distribution"):
        import_optuna_study(storage, "mixed", tmp_path / "abl", three)
    assert not (tmp_path / "abl").exists()


def test_import_of_a_missing_sqlite_url_creates_no_database(tmp_path):
    """An ``sqlite:///`` URL naming no file (a typo) is refused as a missing file; Optuna's
    RDBStorage would create an empty database there and the import would say it holds no
    study."""
    url = f"sqlite:///{tmp_path / 'typo.db'}"
    with pytest.raises(OptunaImportError, match="storage file not found: .*typo.db"):
        import_optuna_study(url, None, tmp_path / "x")
    assert not (tmp_path / "typo.db").exists() and not (tmp_path / "x").exists()
    simulator_study(f"sqlite:///{tmp_path / 'sim.db'}", n=3)
    assert import_optuna_study(f"sqlite:///{tmp_path / 'sim.db'}", None,
                               tmp_path / "run").store.count(Phase.PHASE1) == 3


def test_import_takes_a_trial_that_stood_with_a_non_finite_value_as_a_fall(tmp_path):
    """A COMPLETE trial's value that is not finite (or 1e300 in size or more) is no cost. A
    trial that stood with one (-inf in a minimize study is Optuna's best) refused the whole
    import, though latentune's samplers tell that same trial as a fall of cost +inf, so the
    study could be tuned on and never imported (Optuna cannot change a COMPLETE trial); it is
    imported as the samplers tell it, a fall of cost +inf, with one warning naming it. A fall's
    value is +inf, as a FAIL's."""
    from latentune.integrations.optuna import trial_cost

    storage = optuna.storages.InMemoryStorage()
    mk = optuna.trial.create_trial
    p = [dict(zip(NAMES, map(float, x))) for x in manifold(3, seed=2)]
    for name, direction, bad in (("min", "minimize", -math.inf), ("max", "maximize", math.inf),
                                 ("big", "minimize", 1e300)):
        s = optuna.create_study(storage=storage, study_name=name, direction=direction)
        s.add_trials([mk(params=p[0], distributions=DISTS, value=1.0),
                      mk(params=p[1], distributions=DISTS, value=bad)])
        with pytest.warns(UserWarning, match=r"trial\(s\) 1 stood with a value that is no cost"):
            st = import_optuna_study(storage, name, tmp_path / name)
        sign = -1.0 if direction == "maximize" else 1.0
        assert [(r.cost, r.fell) for r in st.store.rows(Phase.PHASE1)] == \
            [(sign * 1.0, False), (math.inf, True)]
        assert trial_cost(s.trials[1], sign) == math.inf
    s = optuna.create_study(storage=storage, study_name="fall")
    s.add_trials([mk(params=p[0], distributions=DISTS, value=1.0),
                  mk(params=p[1], distributions=DISTS, value=-math.inf,
                     system_attrs={"constraints:fall": 1.0}),
                  mk(params=p[2], distributions=DISTS, value=math.inf,
                     user_attrs={FAILED_ATTR: True})])
    rows = import_optuna_study(storage, "fall", tmp_path / "fall").store.rows(Phase.PHASE1)
    assert [(r.cost, r.fell) for r in rows] == [(1.0, False), (math.inf, True), (math.inf, True)]


def test_a_no_cost_trial_is_named_only_by_the_import_that_imports_it(tmp_path):
    """Importing a study again named the trial that stood with a value that is no cost once
    more ("imported as falls"), though that import added no trial; so did an import refused
    for a directory holding another run. The warning names the trials this import adds."""
    import warnings as w

    from latentune.errors import StoreError
    storage = optuna.storages.InMemoryStorage()
    mk = optuna.trial.create_trial
    p = [dict(zip(NAMES, map(float, x))) for x in manifold(3, seed=2)]
    s = optuna.create_study(storage=storage, study_name="again")
    s.add_trials([mk(params=p[0], distributions=DISTS, value=1.0),
                  mk(params=p[1], distributions=DISTS, value=-math.inf)])
    with pytest.warns(UserWarning, match=r"trial\(s\) 1 stood"):
        import_optuna_study(storage, "again", tmp_path / "run")
    s.add_trials([mk(params=p[2], distributions=DISTS, value=2.0)])
    with w.catch_warnings(record=True) as got:
        w.simplefilter("always")
        st = import_optuna_study(storage, "again", tmp_path / "run")
    assert st.store.count(Phase.PHASE1) == 3
    assert not [x for x in got if "no cost" in str(x.message)]
    other = optuna.create_study(storage=storage, study_name="other")
    other.add_trials([mk(params=p[1], distributions=DISTS, value=-math.inf)])
    with w.catch_warnings(record=True) as got:
        w.simplefilter("always")
        with pytest.raises(StoreError):
            import_optuna_study(storage, "other", tmp_path / "run")
    assert not [x for x in got if "no cost" in str(x.message)]


def test_import_cli_counts_one_trial_and_one_fall_in_the_singular(tmp_path, capsys):
    """``import-optuna`` of a study with one finished trial, a FAIL, said "holds 1 trials
    (1 falls)"; it says "1 trial (1 fall)"."""
    storage = f"sqlite:///{tmp_path / 'o.db'}"
    s = optuna.create_study(storage=storage, study_name="one")
    t = s.ask()
    t.suggest_float("a", 0.0, 1.0)
    s.tell(t, state=optuna.trial.TrialState.FAIL)
    parser = argparse.ArgumentParser(prog="latentune")
    register_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["import-optuna", storage, "--out", str(tmp_path / "run")])
    assert args.func(args) == 0
    assert "phase 1 holds 1 trial (1 fall), no trial without a fall" in capsys.readouterr().out


def test_import_cli_from_a_journal_file(tmp_path, capsys):
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    path = tmp_path / "sim.log"
    simulator_study(JournalStorage(JournalFileBackend(str(path))), n=20)
    parser = argparse.ArgumentParser(prog="latentune")
    register_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["import-optuna", str(path), "--out", str(tmp_path / "run"),
                              "--train-latent", "--latent-dim", "3", "--vae-epochs", "20"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "phase 1 holds 20 trials (0 falls)" in out and "d_low 3) trained on 20" in out
    run = lt.Study(tmp_path / "run")
    assert run.store.count(Phase.PHASE1) == 20 and run.latent().d_low == 3
    with pytest.raises(LatentuneError, match="--latent-dim needs --train-latent"):
        a = parser.parse_args(["import-optuna", str(path), "--out", "x", "--latent-dim", "2"])
        a.func(a)
    bad = parser.parse_args(["import-optuna", str(tmp_path / "none.db"), "--out",
                             str(tmp_path / "r2")])
    with pytest.raises(LatentuneError, match="storage file not found"):
        bad.func(bad)


def test_import_cli_names_a_latent_dim_too_large_for_the_imported_space(tmp_path, run_cli,
                                                                        error_line):
    """``import-optuna --train-latent --latent-dim D`` with D not below the study's number of
    parameters imported the trials, then said "latent dimension must be in [1, 5], got 6":
    neither the flag nor that the trials are stored and how to train on them. It now names
    --latent-dim and the train-vae command that trains the stored run."""
    db = tmp_path / "opt.db"
    simulator_study(f"sqlite:///{db}", n=20)
    d = len(NAMES)
    line = error_line(*run_cli("import-optuna", db, "--study", "sim", "--out", tmp_path / "O",
                               "--train-latent", "--latent-dim", d)[::2])
    assert line.endswith(f"--latent-dim {d}: the latent space of a {d}-dim θ needs a size in "
                         f"[1, {d - 1}]; the trials are imported: train it with latentune "
                         f"train-vae --out {tmp_path / 'O'} --latent-dim N"), line
    assert lt.Study(tmp_path / "O").store.count(Phase.PHASE1) == 20
    code, out, err = run_cli("train-vae", "--out", tmp_path / "O", "--latent-dim", 2,
                             "--vae-epochs", 20)
    assert code == 0 and "d_low 2) trained on 20" in out, err


def test_train_vae_on_an_imported_study_then_latent_sampler(tmp_path, run_cli, error_line):
    """``latentune import-optuna opt.db --study sim --out O`` then ``latentune train-vae --out
    O`` (the README's two steps without --train-latent) was refused: "O holds a run of another
    system (direction: stored 'minimize', given None; kind: stored 'optuna', given 'task'
    ...)". train-vae now trains on the imported space, and LatentSampler(O) searches in it."""
    db = tmp_path / "opt.db"
    simulator_study(f"sqlite:///{db}", n=20)
    assert run_cli("import-optuna", db, "--study", "sim", "--out", tmp_path / "O")[0] == 0
    line = error_line(*run_cli("train-vae", "--out", tmp_path / "O", "--task", "jump")[::2])
    assert "an imported Optuna study (import-optuna)" in line, line
    code, out, err = run_cli("train-vae", "--out", tmp_path / "O", "--latent-dim", "3",
                             "--vae-epochs", "20")
    assert code == 0 and "d_low 3) trained on 20" in out, err
    sampler = LatentSampler(str(tmp_path / "O"), seed=0, budget=3)
    study = optuna.create_study(sampler=sampler)
    study.optimize(objective_for(sampler), n_trials=3)
    assert len(study.trials) == 3 and all(t.state.name == "COMPLETE" for t in study.trials)


def test_imported_run_feeds_study_phase3(source_run, tmp_path):
    """The imported run is a source like any other: Study.phase3 with its latent space runs its
    best θ as it is (zero-shot), then the latent search."""
    src = lt.Study(source_run)
    system = lt.FunctionSystem(src.space(), lambda x: cost(x, 0.1))
    res = lt.Study(tmp_path / "target", seed=0).phase3(system, 4, latent=source_run)
    assert res.n == 4
    zs = lt.Study(tmp_path / "target").store.rows(Phase.ZERO_SHOT)
    np.testing.assert_allclose(zs[0].theta, src.best(Phase.PHASE1).theta)


# ---------------------------------------------------------------------------- samplers
def test_latent_sampler_default_is_the_transfer_phase3(source_run):
    """The default sampler is latentune's default phase 3: deterministic for a seed with one
    worker, trial 0 the zero-shot θ, the plain strategy's options refused with it."""
    def run(seed: int) -> optuna.Study:
        sampler = LatentSampler(source_run, seed=seed)
        assert sampler.strategy == "transfer"
        study = optuna.create_study(sampler=sampler)
        study.optimize(objective_for(sampler), n_trials=6)
        return study

    a, b = run(0), run(0)
    assert thetas(a) == thetas(b) and len(set(thetas(a))) == len(a.trials)
    assert a.trials[0].system_attrs.get("latentune:zero_shot") is True
    assert all(t.system_attrs[POINT_ATTR]["tag"] >= 0 for t in a.trials[1:])
    with pytest.raises(UsageError, match="strategy='plain'"):
        LatentSampler(source_run, method="cma")


def test_latent_sampler_optimize_and_seed(source_run, tmp_path):
    src = lt.Study(source_run)
    best = src.best(Phase.PHASE1)
    latent = src.latent()

    def run(seed: int) -> optuna.Study:
        sampler = LatentSampler(source_run, seed=seed, budget=40, strategy="plain")
        study = optuna.create_study(sampler=sampler)
        study.optimize(objective_for(sampler), n_trials=7)
        return study

    a, b, c = run(0), run(0), run(1)
    assert thetas(a) == thetas(b)                                  # one worker: deterministic
    assert thetas(a)[1:] != thetas(c)[1:]                          # another seed, another run
    assert {t.system_attrs[POINT_ATTR]["seed"] for s, st in ((0, a), (1, c))
            for t in st.trials[1:] if t.system_attrs[POINT_ATTR]["seed"] != s} == set()
    # trial 0: the source's best θ as it is (zero-shot)
    zs = a.trials[0]
    assert zs.system_attrs.get("latentune:zero_shot") is True and POINT_ATTR not in zs.system_attrs
    np.testing.assert_allclose([zs.params[n] for n in NAMES],
                               src.space().to_physical(best.theta), atol=1e-12)
    # later trials: decoded latent points, every θ distinct, the critic saw the earlier trials
    for t in a.trials[1:]:
        pt = t.system_attrs[POINT_ATTR]
        assert pt["told"] == t.number and pt["pending"] == 0 and pt["tag"] >= 0
        theta = latent.decode(np.array(pt["z"]))
        np.testing.assert_allclose([t.params[n] for n in NAMES],
                                   src.space().to_physical(theta), atol=1e-9)
    assert len(set(thetas(a))) == len(a.trials)
    # the first critic point is the code of the manual θ (start="manual")
    np.testing.assert_allclose(a.trials[1].system_attrs[POINT_ATTR]["u"],
                               latent.to_unit(latent.encode(src.space().manual)), atol=1e-12)


def test_a_study_with_a_latent_sampler_pickles(source_run):
    """An Optuna study is saved with pickle / joblib.dump (Optuna's FAQ): its LatentSampler
    (with the latent network, a class built at run time) pickles, and the loaded study goes on
    with the trials the one kept in memory asks."""
    import pickle

    sampler = LatentSampler(source_run, seed=0, budget=20)
    study = optuna.create_study(sampler=sampler)
    study.optimize(objective_for(sampler), n_trials=2)
    loaded = pickle.loads(pickle.dumps(study))
    for s in (study, loaded):
        s.optimize(objective_for(s.sampler), n_trials=2)
    assert thetas(loaded) == thetas(study) and len(set(thetas(study))) == 4


def test_latent_sampler_falls_and_direction(source_run):
    """Falls reach the critic (constraint > 0, latentune_failed, FAIL); a maximize study is
    negated: the same objective told as -cost in a maximize study gives the same trials."""
    from latentune.integrations.optuna import trial_cost, trial_fell

    sampler = LatentSampler(source_run, seed=2, budget=40, max_fall_prob=0.5)
    study = optuna.create_study(sampler=sampler)
    for i in range(4):
        t = study.ask()
        p = sampler.suggest_all(t)
        c, _ = cost(np.array([p[n] for n in NAMES]))
        if i == 1:
            t.set_user_attr(FAILED_ATTR, True)
            study.tell(t, c)
        elif i == 2:
            study.tell(t, state=S.FAIL)
        else:
            t.set_constraint("fall", 1.0 if i == 3 else -1.0)
            study.tell(t, c)
    fell = [trial_fell(t) for t in study.trials]
    assert fell == [False, True, True, True]
    assert math.isinf(trial_cost(study.trials[2], 1.0))
    nxt = study.ask()
    sampler.suggest_all(nxt)
    assert study.trials[-1].system_attrs[POINT_ATTR]["told"] == 4

    # Optuna's constraints_func, called by the sampler after each trial, marks falls too
    cf = LatentSampler(source_run, seed=2, budget=40,
                       constraints_func=lambda tr: [1.0 if tr.params["w0"] > 0.0 else -1.0])
    st = optuna.create_study(sampler=cf)
    st.optimize(lambda tr: cost(np.array(list(cf.suggest_all(tr).values())))[0], n_trials=3)
    assert [trial_fell(t) for t in st.trials] == [t.params["w0"] > 0.0 for t in st.trials]
    assert all(t.constraints for t in st.trials)

    def run(direction: str) -> list:
        s = LatentSampler(source_run, seed=5, budget=40)
        st = optuna.create_study(sampler=s, direction=direction)
        sign = -1.0 if direction == "maximize" else 1.0
        st.optimize(lambda tr: sign * cost(np.array(list(s.suggest_all(tr).values())))[0],
                    n_trials=5)
        return thetas(st)

    assert run("maximize") == run("minimize")


def test_latent_sampler_transfer_options_and_fall_budget(source_run, caplog):
    """``transfer_options`` reach the critic, checked: a bad one or one with the plain strategy
    is refused naming it. ``fall_budget`` 0.1 of 20 trials allows 2 falls after the first
    trial that stood: ``study.optimize`` stops after the trial that spent them (without the
    option the same objective runs every trial), ``fall_budget(study)`` says so (with the
    ``not_run`` count of ``Study.status()``: it had none, unlike status), and a trial asked
    later re-runs the best θ that stood, with a warning."""
    with pytest.raises(UsageError, match="unknown option.*no_such"):
        LatentSampler(source_run, transfer_options={"no_such": 1})
    with pytest.raises(UsageError, match="fall_budget must be"):
        LatentSampler(source_run, transfer_options={"fall_budget": 1.5})
    with pytest.raises(UsageError, match=re.escape("(strategy='transfer')")):
        LatentSampler(source_run, strategy="plain", transfer_options={"fall_budget": 0.1})

    def falls_from_trial_1(sampler):
        def objective(trial):
            p = sampler.suggest_all(trial)
            trial.set_constraint("fall", 1.0 if trial.number >= 1 else -1.0)
            return cost(np.array([p[n] for n in NAMES]), 0.1)[0]
        return objective

    plain = LatentSampler(source_run, seed=0, budget=20)
    free = optuna.create_study(sampler=plain)
    free.optimize(falls_from_trial_1(plain), n_trials=5)
    assert len(free.trials) == 5 and plain.fall_budget(free) is None

    sampler = LatentSampler(source_run, seed=0, budget=20, transfer_options={"fall_budget": 0.1})
    study = optuna.create_study(sampler=sampler)
    with caplog.at_level(logging.WARNING, logger="latentune.integrations.optuna"):
        study.optimize(falls_from_trial_1(sampler), n_trials=20)
    assert len(study.trials) == 3 and "the study stops here" in caplog.text
    assert sampler.fall_budget(study) == {"falls_allowed": 2, "falls": 2,
                                          "counts": "after_stand", "spent": True, "not_run": 0}
    assert thetas(study)[:3] == thetas(free)[:3]      # the same search until it stops
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="latentune.integrations.optuna"):
        t = study.ask()
        p = sampler.suggest_all(t)
    assert "re-runs the best θ that stood" in caplog.text
    assert study._storage.get_trial(t._trial_id).system_attrs[POINT_ATTR]["fall_budget_spent"]
    np.testing.assert_allclose([p[n] for n in NAMES],
                               [study.trials[0].params[n] for n in NAMES], atol=1e-9)
    # like status, it says how many trials the stop leaves unrun: here the queued ones
    study.enqueue_trial({n: 0.5 for n in NAMES})
    assert sampler.fall_budget(study)["not_run"] == 1


def test_sampler_refuses_other_bounds(source_run):
    sampler = LatentSampler(source_run, seed=0)
    study = optuna.create_study(sampler=sampler)
    study.enqueue_trial({"w0": 0.5})           # trial 0 is fixed; trial 1 comes from the critic
    study.optimize(objective_for(sampler), n_trials=1)
    t = study.ask()
    with pytest.raises(UsageError, match="suggest it with those bounds"):
        t.suggest_float("w1", 5.0, 6.0)
    assert sampler.distributions()["w1"] == FD(-1.0, 1.0)
    assert 0.0 <= t.suggest_float("extra", 0.0, 1.0) <= 1.0          # outside the space: random


def test_sampler_refuses_other_bounds_on_the_first_trial(source_run):
    """Bounds other than the space's are refused on the trial that shows them, whether or not
    the sampler's value lies inside them, with one message naming the parameter and both
    ranges: wider ones when trial 0 finishes (the sampler's value fits), narrower ones at the
    suggest or when the trial finishes. Another scale (log) is refused at the suggest."""
    ranges = {"wider": (-2.0, 1.0), "narrower": (-1.0, 0.999)}
    for sampler in (LatentSampler(source_run, seed=0, budget=20),
                    TurboSampler(DISTS, seed=0, budget=20)):
        for what, (lo, hi) in ranges.items():
            study = optuna.create_study(sampler=sampler)

            def objective(trial):
                x = np.array([trial.suggest_float(n, lo if n == "w3" else -1.0, hi
                                                  if n == "w3" else 1.0) for n in NAMES])
                return cost(x)[0]

            with pytest.raises(UsageError, match=rf"parameter 'w3' is suggested on \[{lo:g}, "
                               rf"{hi:g}\], but the sampler's space has it on \[-1, 1\]"):
                study.optimize(objective, n_trials=5)
            assert len(study.trials) == 1, (type(sampler).__name__, what)
        study = optuna.create_study(sampler=sampler)
        with pytest.raises(ValueError, match="log"):
            study.optimize(lambda t: t.suggest_float("w0", 0.1, 1.0, log=True), n_trials=1)


def test_a_parameter_of_the_space_suggested_as_another_kind_is_refused_by_name(source_run):
    """suggest_int (or a categorical, or a stepped float) on a parameter of the space is the
    sampler's UsageError naming the parameter and saying it is a float weight of the space,
    not Optuna's "Cannot set different distribution kind"; the other parameters still work."""
    for sampler in (LatentSampler(source_run, seed=0, budget=20),
                    TurboSampler(DISTS, seed=0, budget=20)):
        name = type(sampler).__name__
        for suggest, kind in ((lambda t: t.suggest_int("w2", -1, 1), r"an int on \[-1, 1\]"),
                              (lambda t: t.suggest_categorical("w2", [0.0, 1.0]), "a categorical"),
                              (lambda t: t.suggest_float("w2", -1.0, 1.0, step=0.5),
                               r"a stepped float \(step 0.5\)")):
            study = optuna.create_study(sampler=sampler)
            t = study.ask()
            assert -1.0 <= t.suggest_float("w0", -1.0, 1.0) <= 1.0
            with pytest.raises(UsageError, match=rf"{name}: parameter 'w2' is suggested as {kind}"
                                                 r", but it is a float weight of the sampler's "
                                                 r"space on \[-1, 1\]: suggest it with "
                                                 "suggest_float"):
                suggest(t)
            p = sampler.suggest_all(t)
            assert p["w0"] == t.params["w0"] and set(p) == set(NAMES)
            study.tell(t, cost(np.array([p[n] for n in NAMES]))[0])
        study = optuna.create_study(sampler=sampler)
        with pytest.raises(UsageError, match="'w0' is suggested as an int"):
            study.optimize(lambda t: t.suggest_int("w0", -1, 1), n_trials=1)


def test_a_parameter_of_the_space_not_suggested_is_refused():
    """An objective that misspells a parameter of the space ("B" for "b": Optuna draws "B" at
    random) is refused when its first trial finishes, naming the parameter; that trial, which
    did not run at a θ of the space, is left out of what the critic is told."""
    dists = {"a": FD(0.0, 1.0), "b": FD(0.1, 10.0, log=True)}
    sampler = TurboSampler(dists, seed=0, budget=20)
    study = optuna.create_study(sampler=sampler)

    def typo(trial):
        return trial.suggest_float("a", 0.0, 1.0) + trial.suggest_float("B", 0.1, 10.0, log=True)

    with pytest.raises(UsageError, match="trial 0: parameter 'b' of the sampler's space was not "
                                         "suggested \\(it suggested 'B' outside it\\)"):
        study.optimize(typo, n_trials=5)
    assert len(study.trials) == 1
    study.optimize(lambda t: sum(sampler.suggest_all(t).values()), n_trials=2)
    assert [t.system_attrs[POINT_ATTR]["told"] for t in study.trials[1:]] == [0, 1]


@pytest.mark.parametrize("kind", ["turbo", "latent"])
def test_a_partly_enqueued_trial_is_told_at_the_theta_it_ran(source_run, kind):
    """A trial with an enqueued value (the sampler fills the rest) ran at a θ the sampler did
    not propose: the critic is told it as an external point (tag -1) at its own θ; the
    sampler's own trials are told at their critic points."""
    sampler = (TurboSampler(DISTS, seed=0, budget=20) if kind == "turbo"
               else LatentSampler(source_run, seed=0, budget=20))
    study = optuna.create_study(sampler=sampler)
    study.optimize(objective_for(sampler), n_trials=3)
    study.enqueue_trial({"w0": -0.9})
    study.optimize(objective_for(sampler), n_trials=1)
    t = study.trials[3]
    assert t.params["w0"] == -0.9 and t.system_attrs[POINT_ATTR]["theta"][0] != 0.05
    X, y, tags, _, _ = sampler._history(study.get_trials(), 1.0, -1, kind == "latent", D)
    np.testing.assert_allclose(X[3], [(t.params[n] + 1) / 2 for n in NAMES], atol=1e-9)
    assert tags[3] == -1 and y[3] == t.value
    assert tags[1] != -1
    np.testing.assert_allclose(X[1], study.trials[1].system_attrs[POINT_ATTR]["u"])


@pytest.mark.parametrize("enqueued", ["full", "two full", "partial"])
def test_enqueued_trials_run_first_and_the_zero_shot_next(source_run, enqueued):
    """A trial enqueued before the first one (study.enqueue_trial, Optuna's convention: run
    first, as given) took trial 0 and the zero-shot θ was never run (a full one), or was
    marked the zero-shot trial while running the enqueued value (a partial one). Now the
    enqueued trials run first, as given, and are told as external points (tag -1); the
    zero-shot θ is the next trial, then the critic's points."""
    src = lt.Study(source_run)
    zs_params = src.space().as_dict(src.best(Phase.PHASE1).theta)
    sampler = LatentSampler(source_run, seed=0, budget=20)
    study = optuna.create_study(sampler=sampler)
    given = [{n: 0.1 * (k + 1) for n in NAMES} for k in range(2 if enqueued == "two full"
                                                             else 1)]
    if enqueued == "partial":
        given = [{"w0": -0.9}]
    for g in given:
        study.enqueue_trial(g)
    study.optimize(objective_for(sampler), n_trials=len(given) + 2)
    k = len(given)
    for t, g in zip(study.trials, given):
        assert all(t.params[n] == v for n, v in g.items())
        assert not t.system_attrs.get("latentune:zero_shot")
    zs = study.trials[k]
    assert zs.system_attrs.get("latentune:zero_shot") is True and POINT_ATTR not in zs.system_attrs
    np.testing.assert_allclose([zs.params[n] for n in NAMES], [zs_params[n] for n in NAMES],
                               atol=1e-12)
    assert study.trials[k + 1].system_attrs[POINT_ATTR]["told"] == k + 1
    _, y, tags, _, _ = sampler._history(study.get_trials(), 1.0, -1, True, D)
    assert tags[:k + 1] == [-1] * (k + 1) and y[:k + 1] == [t.value for t in study.trials[:k + 1]]


@pytest.mark.parametrize("options", [{}, {"strategy": "plain", "start": "best"}])
def test_a_partly_enqueued_first_trial_takes_the_rest_from_the_manual_theta(source_run, options):
    """study.enqueue_trial({"w0": -0.9}) before the zero-shot trial: its other values came
    from the critic's first point (told nothing: with start="best" the source's best, which
    the zero-shot trial then ran again but for w0). They are the source's manual θ; the
    zero-shot trial comes next, then the critic."""
    src = lt.Study(source_run)
    manual = src.space().as_dict(src.space().manual)
    zs = src.space().as_dict(src.best(Phase.PHASE1).theta)
    sampler = LatentSampler(source_run, seed=0, budget=20, **options)
    study = optuna.create_study(sampler=sampler)
    study.enqueue_trial({"w0": -0.9})
    study.optimize(objective_for(sampler), n_trials=3)
    first, second = study.trials[0], study.trials[1]
    assert first.params["w0"] == -0.9
    np.testing.assert_allclose([first.params[n] for n in NAMES[1:]],
                               [manual[n] for n in NAMES[1:]], atol=1e-12)
    assert second.system_attrs.get("latentune:zero_shot") is True
    np.testing.assert_allclose([second.params[n] for n in NAMES], [zs[n] for n in NAMES],
                               atol=1e-12)
    assert study.trials[2].system_attrs[POINT_ATTR]["told"] == 2


def test_an_enqueued_zero_shot_theta_is_not_run_twice(source_run):
    """An enqueued trial that is the source's best θ runs it: the sampler does not run it
    again as the zero-shot trial; the next trial is the critic's."""
    src = lt.Study(source_run)
    sampler = LatentSampler(source_run, seed=0, budget=20)
    study = optuna.create_study(sampler=sampler)
    study.enqueue_trial(src.space().as_dict(src.best(Phase.PHASE1).theta))
    study.optimize(objective_for(sampler), n_trials=2)
    assert not any(t.system_attrs.get("latentune:zero_shot") for t in study.trials)
    assert study.trials[1].system_attrs[POINT_ATTR]["tag"] >= 0
    assert len(set(thetas(study))) == 2


def test_a_sampler_tells_a_trial_that_stood_with_a_non_finite_value_as_a_fall():
    """A trial that stood with -inf (a minimize study's best for Optuna) or +inf stopped the
    study as it finished, and every later ask raised, leaving a RUNNING trial behind each time:
    Optuna has recorded the trial and cannot drop it, so the study could not go on. The samplers
    tell such a trial as a fall with cost +inf, as a FAIL (one warning names it), and the study
    goes on; a fall's -inf is told as +inf, as before."""
    dists = {"a": FD(0.0, 1.0), "b": FD(-1.0, 1.0)}
    sampler = TurboSampler(dists, seed=0, budget=20)
    study = optuna.create_study(sampler=sampler)

    def objective(trial):
        v = sum(sampler.suggest_all(trial).values())
        if trial.number == 1:
            trial.set_constraint("fall", 1.0)
            return -math.inf
        return {3: -math.inf, 4: math.inf}.get(trial.number, v)

    with pytest.warns(UserWarning, match=r"trial 3 stood with value -inf: .* counts it as a "
                                         r"fall \(cost \+inf\)"):
        study.optimize(objective, n_trials=6)
    S = optuna.trial.TrialState
    assert [t.state for t in study.trials] == [S.COMPLETE] * 6
    _, y, _, fell, _ = sampler._history(study.get_trials(), 1.0, -1, False, 2)
    assert [y[i] for i in (1, 3, 4)] == [math.inf] * 3 and all(fell[i] for i in (1, 3, 4))
    assert not fell[0] and math.isfinite(y[0])
    t = study.ask()
    assert set(sampler.suggest_all(t)) == {"a", "b"}
    study.tell(t, 0.5)
    assert not any(t.state == S.RUNNING for t in study.trials)


def _worker(source: str, journal: str, n: int) -> None:
    """A worker process of one journal storage: n times, two trials asked (both RUNNING), then
    both told."""
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(journal))
    sampler = LatentSampler(source, seed=0, budget=40)
    study = optuna.load_study(study_name="target", storage=storage, sampler=sampler)
    for _ in range(n):
        a, b = study.ask(), study.ask()           # two trials in flight: both RUNNING
        pa, pb = sampler.suggest_all(a), sampler.suggest_all(b)
        for t, p in ((a, pa), (b, pb)):
            x = np.array(list(p.values()))
            study.tell(t, float(np.sum((x - 0.3) ** 2)))


def test_a_theta_given_twice_at_once_is_chosen_again(source_run, monkeypatch):
    """Write, then check: a trial whose θ another RUNNING trial recorded at the same moment (the
    race of two workers on one storage, played here by handing trial 2 trial 1's θ) chooses
    again, and the two run different θ."""
    sampler = LatentSampler(source_run, seed=0, budget=40)
    study = optuna.create_study(sampler=sampler)
    z = study.ask()                               # the zero-shot trial: no critic point
    study.tell(z, float(np.sum(np.array(list(sampler.suggest_all(z).values())) ** 2)))
    a = study.ask()
    pa = sampler.suggest_all(a)
    first = study._storage.get_trial_system_attrs(a._trial_id)[POINT_ATTR]
    real = LatentSampler._next
    calls = []

    def racing(self, st, trial, extra_skip=0):
        calls.append(extra_skip)
        if len(calls) == 1:                       # blind to trial 1: its pick is trial 1's
            return np.asarray(first["theta"], dtype=float), dict(first)
        return real(self, st, trial, extra_skip)

    monkeypatch.setattr(LatentSampler, "_next", racing)
    b = study.ask()
    pb = sampler.suggest_all(b)
    assert len(calls) == 2 and calls[1] == 1      # chose again, leaving trial 1 its θ
    assert tuple(pa.values()) != pytest.approx(tuple(pb.values()))
    assert sampler._clashes(study, b, np.asarray(
        study._storage.get_trial_system_attrs(b._trial_id)[POINT_ATTR]["theta"])) == []


def test_a_theta_that_finished_meanwhile_is_chosen_again(source_run, monkeypatch):
    """The race with a fast objective: trial 1 sampled θ and *finished* before trial 2, blind
    to it, checks; trial 2 sees the finished trial's θ and chooses again (passing over nothing
    more: a finished trial takes no critic point), so no θ runs twice."""
    sampler = LatentSampler(source_run, seed=0, budget=40)
    study = optuna.create_study(sampler=sampler)
    z = study.ask()
    study.tell(z, float(np.sum(np.array(list(sampler.suggest_all(z).values())) ** 2)))
    a = study.ask()
    pa = sampler.suggest_all(a)
    first = study._storage.get_trial_system_attrs(a._trial_id)[POINT_ATTR]
    study.tell(a, float(np.sum(np.array(list(pa.values())) ** 2)))      # finished
    real = LatentSampler._next
    calls = []

    def racing(self, st, trial, extra_skip=0):
        calls.append(extra_skip)
        if len(calls) == 1:
            return np.asarray(first["theta"], dtype=float), dict(first)
        return real(self, st, trial, extra_skip)

    monkeypatch.setattr(LatentSampler, "_next", racing)
    b = study.ask()
    pb = sampler.suggest_all(b)
    assert calls == [0, 0]                        # chose again; nothing left to trial 1
    assert tuple(pa.values()) != pytest.approx(tuple(pb.values()))


class _GrowingSource:
    """A source run imported from an Optuna study "sim" of ``cost`` on ``manifold(50)``: its
    first 40 points, with a latent space, in ``d``; :meth:`grow` adds the other 10 to the
    study and imports them (the source run grows under a study that uses it)."""

    def __init__(self, d) -> None:
        self.d, self.X = d, manifold(50)
        self.storage = optuna.storages.InMemoryStorage()
        self.sim = optuna.create_study(storage=self.storage, study_name="sim")
        self._add(self.X[:40])
        import_optuna_study(self.storage, "sim", d).train_latent(latent_dim=3, epochs=100)

    def _add(self, xs: np.ndarray) -> None:
        self.sim.add_trials([optuna.trial.create_trial(
            params=dict(zip(NAMES, map(float, x))), distributions=DISTS, value=cost(x)[0])
            for x in xs])

    def grow(self) -> None:
        self._add(self.X[40:])
        import_optuna_study(self.storage, "sim", self.d)          # 10 more source trials


def test_a_source_run_that_grows_does_not_change_a_study_under_way(tmp_path):
    """The transfer strategy searches from the source trials there were at the study's first
    sample, as Study.phase3 pins them: a study resumed (a new sampler) after the source run got
    more trials asks what the uninterrupted study asked (it took the new trials in)."""
    src = _GrowingSource(tmp_path / "src")

    def more(study, n):
        study.sampler = LatentSampler(tmp_path / "src", seed=0, budget=20)
        study.optimize(objective_for(study.sampler), n_trials=n)
        return study

    full = more(optuna.create_study(), 5)
    part = more(optuna.create_study(), 3)
    src.grow()
    assert thetas(more(part, 2)) == thetas(full)
    attrs = part._storage.get_study_system_attrs(part._study_id)
    assert attrs["latentune:source_counts:" + part.sampler._key] == {"1": 40, "3": 0}


def _sampled_from_growing_source(src: Path) -> Any:
    """A new in-memory Optuna study of 2 trials sampled by a LatentSampler (seed 0, budget 20)
    of a :class:`_GrowingSource` made at ``src`` (its source trials pinned)."""
    _GrowingSource(src)
    study = optuna.create_study()
    study.sampler = LatentSampler(src, seed=0, budget=20)
    study.optimize(objective_for(study.sampler), n_trials=2)
    return study


def test_a_source_run_holding_other_trials_is_refused_by_a_study_under_way(tmp_path):
    """A study resumed (a new sampler) after its source directory came to hold other trials
    than the ones pinned at its first sample (as many, the same latent space: one cost edited
    here) went on with them; the sampler pins their fingerprint with their counts and refuses
    the source in one line, as Study.phase3 does."""
    import sqlite3

    from latentune.errors import LatentError

    study = _sampled_from_growing_source(tmp_path / "src")
    con = sqlite3.connect(tmp_path / "src" / "run.db")
    with con:
        con.execute("UPDATE evaluations SET cost = cost + 1 WHERE phase = 1 AND idx = 3")
    con.close()
    study.sampler = LatentSampler(tmp_path / "src", seed=0, budget=20)
    with pytest.raises(LatentError, match=r"^LatentSampler: the source run at .* is not the run "
                                          r"the study began with: it holds other trials than the 40 "
                                          r"phase-1 trials the study began with") as exc:
        study.optimize(objective_for(study.sampler), n_trials=1)
    assert "\n" not in str(exc.value)
    assert [t.state for t in study.trials] == [S.COMPLETE, S.COMPLETE, S.FAIL]


def test_a_study_reads_its_source_trials_once_per_sampler(tmp_path, source_reads):
    """The first sample pinned the source trials' fingerprint and then computed it again to
    check it against itself; it reads them once (to pin), a new sampler once (to check)."""
    reads = source_reads
    study = _sampled_from_growing_source(tmp_path / "src")
    assert reads == ["run_fingerprint"]
    reads.clear()
    study.sampler = LatentSampler(tmp_path / "src", seed=0, budget=20)
    study.optimize(objective_for(study.sampler), n_trials=2)
    assert reads == ["amended_since"]


def test_a_source_run_amended_since_goes_on_with_one_warning(tmp_path, caplog):
    """A study resumed after one of its pinned source trials was amended (a cost corrected,
    kept in the store's audit trail as ``tell --amend`` keeps it) was refused as holding other
    trials; the source is the same run: the study goes on, with one warning naming the
    amended trial."""
    import json
    import sqlite3

    study = _sampled_from_growing_source(tmp_path / "src")
    con = sqlite3.connect(tmp_path / "src" / "run.db")
    with con:
        (cost, fell), = con.execute("SELECT cost, fell FROM evaluations WHERE phase = 1 AND "
                                    "idx = 3").fetchall()
        con.execute("UPDATE evaluations SET cost = cost + 1 WHERE phase = 1 AND idx = 3")
        con.execute("INSERT INTO amendments(trial, phase, idx, old, new, note, created) VALUES "
                    "(44, 1, 3, ?, ?, NULL, 0)",
                    (json.dumps({"cost": cost, "fell": bool(fell)}),
                     json.dumps({"cost": cost + 1, "fell": bool(fell)})))
    con.close()
    caplog.set_level(logging.WARNING)
    study.sampler = LatentSampler(tmp_path / "src", seed=0, budget=20)
    study.optimize(objective_for(study.sampler), n_trials=2)
    assert [t.state for t in study.trials] == [S.COMPLETE] * 4
    (line,) = [ln for ln in caplog.text.splitlines() if "amended since" in ln]
    assert "trial 44 was amended since the study began" in line and \
        "the study goes on with the source run's latent space and the amended results" in line


@pytest.mark.parametrize("strategy", ["transfer", "plain"])
def test_a_study_resumed_with_a_larger_budget_goes_on_as_one_run(tmp_path, strategy):
    """A study resumed by a new sampler with a larger budget (more trials planned, as in
    examples/optuna_hopper.py run again with a larger --trials) goes on from the trials it ran:
    its sampler's trials are told as the critic's own points, its critic state and its pinned
    source trials carry on, so it asks what one study with that budget asked (the budget sets
    no point: only the fall budget's base, and TuRBO-m's region count, 1 below 750)."""
    src = _GrowingSource(tmp_path / "src")

    def more(study, n, budget):
        study.sampler = LatentSampler(tmp_path / "src", seed=0, budget=budget, strategy=strategy)
        study.optimize(objective_for(study.sampler), n_trials=n)
        return study

    full = more(optuna.create_study(), 6, 20)
    part = more(optuna.create_study(), 4, 10)
    src.grow()
    assert thetas(more(part, 2, 20)) == thetas(full)
    assert all(t.system_attrs[POINT_ATTR]["tag"] >= 0 for t in part.trials[1:])


def test_keys_written_with_a_budget_name_the_same_configuration():
    """Keys stored before the budget left them (``…:{regions}:{budget}:…``) map to the key a
    sampler of that configuration has now, whatever the budget; other configurations do not."""
    from latentune.integrations.optuna import canonical_key

    s = TurboSampler(DISTS, seed=0, budget=30)
    h, x0 = s._key.split(":")[1], s._key.split(":")[-1]
    assert canonical_key(f"theta:{h}:turbo:None:30:None:{x0}") == s._key
    assert canonical_key(f"theta:{h}:turbo:None:500:None:{x0}") == s._key
    assert canonical_key(f"theta:{h}:turbo:None:5000:None:{x0}") != s._key   # more regions
    assert canonical_key(f"theta:{h}:turbo:None:30:0.3:{x0}") != s._key
    assert canonical_key(s._key) == s._key and canonical_key(None) is None
    t = "latent:abc:transfer:turbo:None:40:None:manual:" + json.dumps({"fall_budget": 0.15})
    assert canonical_key(t) == ("latent:abc:transfer:turbo:regions=None:None:manual:"
                                + json.dumps({"fall_budget": 0.15}))
    assert canonical_key("latent:abc:plain:turbo:None:40:None:best") == \
        "latent:abc:plain:turbo:regions=1:None:best"


@pytest.mark.parametrize("kind", ["transfer", "plain", "turbo"])
def test_a_study_that_prunes_its_trials_goes_on(source_run, kind):
    """PRUNED trials are not told (the critic's history does not change), but their θ are taken:
    a study whose pruner cuts most trials (here every one after the first) goes on, each trial
    at a θ of its own, where the sampler used to stop after a few with "the critic keeps
    proposing θ that are in the study already"."""
    if kind == "turbo":
        sampler = TurboSampler(DISTS, seed=0, budget=40)
    else:
        sampler = LatentSampler(source_run, seed=0, budget=40, strategy=kind)
    study = optuna.create_study(sampler=sampler)

    def objective(trial):
        p = sampler.suggest_all(trial)
        if trial.number >= 1:
            raise optuna.TrialPruned()
        return cost(np.array([p[n] for n in NAMES]))[0]

    study.optimize(objective, n_trials=24)
    assert len(study.trials) == 24 and len(set(thetas(study))) == 24
    assert all(t.state == S.PRUNED for t in study.trials[1:])


def test_the_plain_sampler_never_runs_a_theta_twice_and_says_when_it_has_no_other(
        source_run, monkeypatch):
    """The plain phase 3 through the sampler, in a latent space that decodes to few θ (here
    every θ entry snapped to 0.3 or 0.7): no trial gets a θ the study holds (the phase run
    would store a θ asked again from its trial; an Optuna trial cannot be given a stored
    value). When the critic proposes only taken θ, the trial fails and the study stops with a
    line that said only 'the critic keeps proposing θ that are in the study already'; it says
    what to do."""
    from latentune.latent.vae import LatentSpace

    orig = LatentSpace.decode_code
    monkeypatch.setattr(LatentSpace, "decode_code",
                        lambda self, z: np.where(np.asarray(orig(self, z)) < 0.5, 0.3, 0.7))
    sampler = LatentSampler(source_run, seed=0, strategy="plain", budget=40)
    study = optuna.create_study(sampler=sampler)
    with pytest.raises(LatentuneError, match="keeps proposing") as err:
        study.optimize(objective_for(sampler), n_trials=40)
    ran = [t for t in study.trials if t.params]
    assert 1 < len(ran) < 40 and len({tuple(t.params.values()) for t in ran}) == len(ran)
    assert study.trials[-1].state == S.FAIL and not study.trials[-1].params
    assert "strategy='transfer'" in str(err.value) and f"({len(ran)} θ in all)" in str(err.value)


def test_two_workers_on_one_journal(source_run, tmp_path):
    journal = tmp_path / "target.log"
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    storage = JournalStorage(JournalFileBackend(str(journal)))
    optuna.create_study(study_name="target", storage=storage)
    # two processes from multiprocessing's forkserver, which has torch and latentune loaded
    # (conftest): they start at once, where two fresh interpreters import for seconds first
    ctx = multiprocessing.get_context("forkserver")
    procs = [ctx.Process(target=_worker, args=(str(source_run), str(journal), 2))
             for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=240)
        assert p.exitcode == 0, p.exitcode
    study = optuna.load_study(study_name="target", storage=storage)
    trials = study.trials
    assert len(trials) == 8 and all(t.state == S.COMPLETE for t in trials)    # none lost
    assert sorted(t.number for t in trials) == list(range(8))
    assert len(set(thetas(study))) == 8                                         # none run twice
    pending = [t.system_attrs[POINT_ATTR]["pending"] for t in trials
               if POINT_ATTR in t.system_attrs]
    assert max(pending) >= 1              # RUNNING trials were counted as pending


def test_turbo_sampler(tmp_path):
    dists = {"kp": FD(0.01, 10.0, log=True), "kd": FD(-1.0, 1.0), "ki": FD(0.0, 2.0)}
    start = {"kp": 1.0, "kd": 0.0, "ki": 1.0}

    def objective(trial):
        x = sampler.suggest_all(trial)
        return (math.log10(x["kp"]) - 0.5) ** 2 + (x["kd"] - 0.3) ** 2 + (x["ki"] - 1.5) ** 2

    sampler = TurboSampler(dists, seed=0, budget=20, start=start)
    study = optuna.create_study(sampler=sampler)
    study.optimize(objective, n_trials=14)
    assert study.trials[0].params == pytest.approx(start)
    assert study.best_value < study.trials[0].value
    assert len(set(tuple(t.params.values()) for t in study.trials)) == 14
    again = optuna.create_study(sampler=TurboSampler(dists, seed=0, budget=20, start=start))
    sampler = again.sampler
    again.optimize(objective, n_trials=14)
    assert [t.params for t in again.trials] == [t.params for t in study.trials]
    with pytest.raises(UsageError, match="integer distribution"):
        TurboSampler({"n": optuna.distributions.IntDistribution(0, 3)})
    with pytest.raises(UsageError, match="start"):
        TurboSampler(dists, start="manual")
    with pytest.raises(UsageError, match="independent_sampler must be an Optuna sampler"):
        TurboSampler(dists, independent_sampler="tpe")      # was an AttributeError at a trial
    for regions in (2.5, "3", 0, True):            # 2.5 was taken as 2, "3" as 3
        with pytest.raises(UsageError, match="regions must be"):
            TurboSampler(dists, regions=regions)
    assert TurboSampler(dists, regions=np.int64(3)).regions == 3


def test_optuna_samplers_are_phase1_methods(tmp_path):
    """``Study.phase1(method="optuna-…")`` runs Optuna's sampler through latentune's own loop and
    store: the manual θ first, resumable with the same rows, CMA-ES warm-started from another
    run's trials, and its options checked in one line."""
    space = lt.ParameterSpace(["a", "b", "c"], [-1.0] * 3, [1.0] * 3, manual=[0.5] * 3)
    sys_ = lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.2) ** 2)))
    with lt.Study(tmp_path / "src", seed=1) as st:
        st.phase1(sys_, 12, method="optuna-tpe")
        rows = st.store.rows(Phase.PHASE1)
        assert len(rows) == 12 and st.config()["phase1"]["method"] == "optuna-tpe"
        assert np.allclose(rows[0].theta, space.manual)             # unit box
    with lt.Study(tmp_path / "half", seed=1) as st:
        st.phase1(sys_, 12, method="optuna-tpe", max_new=8)        # a batch boundary
    with lt.Study(tmp_path / "half") as st:                    # resumes: the same 12 rows
        st.phase1(sys_, 12, method="optuna-tpe")
        assert [r.theta.tolist() for r in st.store.rows(Phase.PHASE1)] == \
            [r.theta.tolist() for r in rows]
    with lt.Study(tmp_path / "cma", seed=1) as st:
        st.phase1(sys_, 6, method="optuna-cmaes", source_run=tmp_path / "src", start=None)
        assert st.config()["phase1"]["source_run"] == str((tmp_path / "src").resolve())
    with lt.Study(tmp_path / "few", seed=1) as st:        # CMA-ES starts from the best 10 %
        st.phase1(sys_, 9, method="sobol")
    with pytest.raises(UsageError, match="hold 9 finite cost.*needs at least 10"):
        lt.Study(tmp_path / "cma2", seed=1).phase1(sys_, 6, method="optuna-cmaes",
                                                   source_run=tmp_path / "few")
    with pytest.raises(UsageError, match="source_run is an option of the method optuna-cmaes"):
        lt.Study(tmp_path / "bad", seed=1).phase1(sys_, 6, source_run=tmp_path / "src")
    with pytest.raises(UsageError, match="max_fall_prob is not an option"):
        lt.Study(tmp_path / "bad2", seed=1).phase1(sys_, 6, method="optuna-gp", max_fall_prob=0.3)


def test_optuna_cmaes_resume_uses_the_source_trials_it_started_from(tmp_path):
    """optuna-cmaes's source trials are pinned when phase 1 starts (as the transfer phase 3's
    are): resumed after the source run got more trials, it asks what the uninterrupted run
    asked."""
    space = lt.ParameterSpace(["a", "b", "c"], [0.0] * 3, [1.0] * 3)

    def system(c: float):
        return lt.FunctionSystem(space, lambda x: float(np.sum((x - c) ** 2)))

    def cmaes(name: str, **kw) -> list:
        with lt.Study(tmp_path / name, seed=0) as st:
            st.phase1(system(0.35), 8, method="optuna-cmaes", source_run=tmp_path / "src", **kw)
            return [r.theta.tolist() for r in st.store.rows(Phase.PHASE1)]

    with lt.Study(tmp_path / "src", seed=0) as st:
        st.phase1(system(0.3), 12, method="sobol")
    full = cmaes("full")
    cmaes("part", max_new=4)
    with lt.Study(tmp_path / "src", seed=0) as st:
        st.phase1(system(0.3), 30, method="sobol")                 # the source grows
    assert cmaes("part") == full
    assert lt.Study(tmp_path / "part").config()["phase1"]["source_counts"] == {"1": 12, "3": 0}


def _small_sampler_run(tmp_path, names: str, n: int, **sampler_opts) -> None:
    """A source on a quadratic of len(names) weights (20 trials, a latent space), then ``n``
    trials of ``LatentSampler`` on a shifted quadratic: all complete, every θ distinct."""
    d = len(names)
    space = lt.ParameterSpace(names=list(names), low=[0.0] * d, high=[1.0] * d,
                              manual=[0.5] * d)
    with lt.Study(tmp_path / "src", seed=0) as st:
        st.phase1(lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.3) ** 2)), name="q"),
                  20)
        st.train_latent(epochs=200)
    sampler = LatentSampler(tmp_path / "src", seed=0, **sampler_opts)
    study = optuna.create_study(sampler=sampler)

    def objective(trial):
        p = sampler.suggest_all(trial)
        return float(sum((p[k] - 0.35) ** 2 for k in names))

    study.optimize(objective, n_trials=n)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * n
    assert len({tuple(t.params[k] for k in names) for t in study.trials}) == n


def test_latent_sampler_on_a_three_weight_system_never_repeats_a_theta(tmp_path):
    """A 3-weight system (a 2-dim latent space from 20 source trials): the default sampler runs
    14 trials, every θ distinct (the transfer critic's ``distinct``; before it, trial 6 on
    stopped with "the critic keeps proposing θ that are in the study already")."""
    _small_sampler_run(tmp_path, "abc", 14)


def test_plain_latent_sampler_on_a_two_weight_system(tmp_path):
    """A 2-weight system (a 1-dim latent space): the paper's plain phase 3 through the sampler
    runs 12 distinct trials (before the small-θ widths of the VAE every code decoded to one θ
    and trial 2 stopped); a latent space whose codes all decode to one θ is refused with one
    line before any trial."""
    from latentune.latent.vae import LatentSpace

    _small_sampler_run(tmp_path, "ab", 12, strategy="plain")

    ls = LatentSpace.load(tmp_path / "src" / "vae")         # a constant decoder in its place
    for p in ls.net.decoder[-2].parameters():
        p.data.zero_()
    ls.save(tmp_path / "src" / "vae")
    flat = LatentSampler(tmp_path / "src", seed=0, strategy="plain")
    study = optuna.create_study(sampler=flat)
    with pytest.raises(LatentuneError, match="decodes every code to one θ"):
        study.optimize(lambda t: float(sum(flat.suggest_all(t).values())), n_trials=3)
    assert len(study.trials) == 2 and study.trials[0].state == optuna.trial.TrialState.COMPLETE


@pytest.mark.parametrize("sampler", ["tpe", "cmaes"])
def test_a_first_non_finite_cost_is_a_failed_trial_not_a_best_value(sampler):
    """A first trial whose cost is NaN or inf (a user system's crash) was told as 0.0: for
    positive costs the best value the study had, which the sampler then searched around. It
    is told as failed (the samplers leave it out); a later non-finite cost is still told as
    the worst finite cost before it."""
    from latentune.critic.optuna import OptunaCritic

    c = OptunaCritic(3, batch_size=1, seed=0, sampler=sampler)
    for y in (np.nan, 5.0, np.inf):
        X = c.ask(1)
        c.tell(X, np.array([y]), c.last_tags)
    c.tell(np.full((1, 3), 0.5), np.array([np.inf]), np.array([-1]))   # an untagged point
    trials = c.study.trials
    assert trials[0].state == optuna.trial.TrialState.FAIL and trials[0].value is None
    assert [t.value for t in trials[1:]] == [5.0, 5.0, 5.0]
    c0 = OptunaCritic(3, batch_size=1, seed=0, sampler=sampler)
    c0.tell(np.full((1, 3), 0.5), np.array([np.nan]), np.array([-1]))
    assert c0.study.trials[0].state == optuna.trial.TrialState.FAIL
    assert c0.ask(1).shape == (1, 3)


def test_regions_of_a_method_that_has_none_is_refused(source_run):
    """``LatentSampler(strategy="plain", method="sobol", regions=2)`` was taken and its
    ``regions`` dropped without a word (TuRBO-m's trust regions; Study.phase3 refuses it):
    refused, naming the method."""
    for method in ("cma", "random", "sobol"):
        with pytest.raises(UsageError, match=f"regions .*method turbo.*not of {method}"):
            LatentSampler(source_run, strategy="plain", method=method, regions=2)
    assert LatentSampler(source_run, strategy="plain", method="turbo", regions=2).regions == 2
    assert LatentSampler(source_run, strategy="plain", method="sobol").regions is None


def test_the_report_of_an_import_names_the_study_and_shows_no_empty_phase_row(tmp_path, run_cli):
    """`latentune report` of an `import-optuna` run showed an empty "phase 3 | – | 0 | –" row
    (an ask/tell run's report has none) and titled it "user system": it shows phase 1 alone
    and is titled with the Optuna study's name."""
    db = journal_study(tmp_path / "opt.log", n=12)
    assert run_cli("import-optuna", db, "--study", "sim", "--out", tmp_path / "O")[0] == 0
    code, table, err = run_cli("report", tmp_path / "O", "--no-sim")
    assert code == 0, err
    assert "phase 3" not in table and "user system" not in table
    assert table.startswith("Optuna study 'sim'\n")
    assert (tmp_path / "O" / "report.md").read_text().startswith(
        "# latentune run: Optuna study 'sim'\n")


def test_an_interrupt_after_import_optuna_printed_exits_0(tmp_path, run_cli, monkeypatch,
                                                          interrupt_in_close):
    """A Ctrl-C (or SIGTERM) that landed after ``import-optuna --train-latent`` stored and
    printed the import and the latent space, while it closed the run, exited 130
    ("interrupted"): it exits 0. One before the latent space is trained is still 130."""
    db = journal_study(tmp_path / "opt.log", n=20)
    argv = ("import-optuna", db, "--study", "sim", "--train-latent", "--latent-dim", "3",
            "--vae-epochs", "5")
    code, out, err = run_cli(*argv, "--out", tmp_path / "O")
    assert interrupt_in_close == ["close"] and code == 0, (code, err)
    assert "phase 1 holds 20 trials" in out and "d_low 3) trained on 20" in out, (out, err)
    assert "interrupted" not in err, err

    def interrupted(self, *a, **kw):            # the signal lands before the latent space
        raise KeyboardInterrupt

    monkeypatch.setattr(lt.Study, "train_latent", interrupted)
    code, out, err = run_cli(*argv, "--out", tmp_path / "O2")
    assert code == 130 and "d_low" not in out, (code, out, err)
    assert err.strip() == "latentune: error: interrupted; stored results are kept", err


def _budget_warnings(record: list) -> list[str]:
    return [str(w.message) for w in record if "past its budget" in str(w.message)]


def test_a_study_that_runs_more_trials_than_the_samplers_budget_warns_once(source_run):
    """``LatentSampler(budget=5)`` under ``study.optimize(f, n_trials=7)`` asked trials 6 and 7
    in silence, beyond the trials planned. The first trial past the budget now warns (once
    per study): the search goes on as planned for the budget (its trust regions, its fall
    budget); a sampler with a larger budget plans for more. Within the budget, and for a
    study resumed by a sampler with a larger budget, nothing is said."""
    import warnings

    for sampler, budget, n in ((LatentSampler(source_run, seed=0, budget=5), 5, 7),
                               (TurboSampler(DISTS, seed=0, budget=2), 2, 4)):
        name = type(sampler).__name__
        study = optuna.create_study(sampler=sampler)
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            study.optimize(objective_for(sampler), n_trials=budget)
            assert _budget_warnings(rec) == [], name
            study.optimize(objective_for(sampler), n_trials=n - budget)
        said = _budget_warnings(rec)
        assert len(said) == 1 and said[0].startswith(
            f"{name}: trial {budget} makes {budget + 1} trials in the study, past its budget "
            f"of {budget}: "), said
        assert len(study.trials) == n and all(t.state == S.COMPLETE for t in study.trials)
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            study.sampler = type(sampler)(source_run if name == "LatentSampler" else DISTS,
                                          seed=0, budget=n + 1)
            study.optimize(objective_for(study.sampler), n_trials=1)
        assert _budget_warnings(rec) == [], name


def test_a_sampler_on_a_run_without_phase_1_trials_says_to_run_phase_1_first(tmp_path):
    """``LatentSampler(R)`` where R holds a space but no phase-1 trial (an ask that was never
    told) said "train one first", and training there fails for want of trials; it now says to
    run phase 1 there first. A run with phase-1 trials and no latent space still says to train."""
    from latentune.errors import LatentError

    r = tmp_path / "R"
    with lt.Study(r) as st:
        st.ask(space=lt.ParameterSpace(["a", "b"], [0.0] * 2, [1.0] * 2, manual=[0.5] * 2))
    with pytest.raises(LatentError, match="no phase-1 trial to train one on: run phase 1 there "
                                          "first"):
        LatentSampler(str(r))
    with lt.Study(r) as st:
        (s,) = st.ask()
        st.tell(s.id, 1.0)
    with pytest.raises(LatentError, match=r"no latent space in .*: train one first"):
        LatentSampler(str(r))


def test_import_optuna_with_a_malformed_space_file_says_what_is_wrong(tmp_path, run_cli,
                                                                       error_line):
    """``import-optuna --space FILE`` with a YAML error printed PyYAML's whole report on one
    line ("while parsing a flow sequence in "<unicode string>", line 1, column 8: names: [a
    ^ expected ..."); it is the problem and where, as ``ask --space`` says it."""
    space = tmp_path / "space.yaml"
    space.write_text("names: [a, b\nlow: [0, 0]\n")
    line = error_line(*run_cli("import-optuna", tmp_path / "none.db", "--out", tmp_path / "O",
                               "--space", space)[::2])
    assert line.endswith(f"--space {space}: not valid YAML/JSON (expected ',' or ']', but got "
                         "':' at line 2, column 4)"), line
    space.write_bytes(b"names: [a]\n\xd0\xff\n")
    line = error_line(*run_cli("import-optuna", tmp_path / "none.db", "--out", tmp_path / "O",
                               "--space", space)[::2])
    assert line.endswith("not valid YAML/JSON (not UTF-8 text: invalid continuation byte at "
                         "byte 11)"), line
