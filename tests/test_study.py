"""The public pipeline (Study), user systems, --system plugins, ask/tell, a broken module."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

import pytest

import latentune as lt
from latentune.constants import Phase
from latentune.errors import LatentuneError, StoreError
from latentune.pipeline.store import RunStore

PY = sys.executable

PLUGIN = textwrap.dedent('''
    import numpy as np
    import latentune as lt

    def space(dim):
        return lt.ParameterSpace([f"w{i}" for i in range(dim)], [-1.0] * dim, [1.0] * dim,
                                 manual=[0.5] * dim)

    def cost(x, shift=0.0):
        c = float(np.sum((x - 0.2 - shift) ** 2))
        return lt.Outcome(None, failed=True, info={"reason": "x0 too big"}) if x[0] > 0.8 else c

    class Plant:
        def __init__(self, dim=8, shift=0.0):
            self.space = space(dim)
            self.shift = shift
        def evaluate(self, u):
            return cost(self.space.to_physical(u), self.shift)
        def config(self):
            return {"shift": self.shift}

    def make(dim=8, shift=0.0):
        return Plant(dim, shift)

    def raises(dim=8):
        raise RuntimeError("no robot connected")

    class Bad:
        space = space(4)
        def evaluate(self, u):
            if u[1] > 0.5:
                raise ValueError("sensor timeout")
            return float(np.sum(u))

    class Nan(Bad):
        def evaluate(self, u):
            return float("nan")

    class NoneSys(Bad):
        def evaluate(self, u):
            return None

    def bad(): return Bad()
    def nan(): return Nan()
    def none(): return NoneSys()
    not_a_system = 3
''')


@pytest.fixture(scope="session")
def plugin_dir(tmp_path_factory):
    """A directory holding the user module ``myplant`` (also put on ``sys.path``)."""
    d = tmp_path_factory.mktemp("plugin")
    (d / "myplant.py").write_text(PLUGIN)
    sys.path.insert(0, str(d))
    yield d
    sys.path.remove(str(d))


@pytest.fixture
def in_plugin_dir(plugin_dir, run_cli, monkeypatch):
    """``run_cli`` (the CLI in this process) with the plugin's directory as the working
    directory, as a user runs ``latentune --system myplant:make`` next to the module."""
    monkeypatch.chdir(plugin_dir)
    return run_cli


def rows(run: Path) -> list[tuple]:
    con = sqlite3.connect(f"file:{run / 'run.db'}?mode=ro", uri=True)
    try:
        return con.execute("SELECT phase, idx, theta, cost, fell FROM evaluations "
                           "ORDER BY phase, idx").fetchall()
    finally:
        con.close()


# ---------------------------------------------------------------------------- Python API
@pytest.fixture(scope="module")
def user_sim(tmp_path_factory, plugin_dir):
    """The simulator study of the Python API tests: phase 1 (48) and a 3-d latent space on
    ``myplant.make(8)``; ``(run dir, phase-1 result, latent space)``. Tests copy the run."""
    import myplant

    d = tmp_path_factory.mktemp("user_sim") / "sim"
    with lt.Study(d, seed=3) as sim:
        r1 = sim.phase1(myplant.make(8, 0.0), 48)
        latent = sim.train_latent(latent_dim=3, epochs=40)
    return d, r1, latent


def test_study_phases_on_a_user_system(tmp_path, user_sim):
    import myplant

    model, real = myplant.make(8, 0.0), myplant.make(8, 0.15)
    sim_dir, r1, latent = user_sim
    shutil.copytree(sim_dir, tmp_path / "sim")
    sim = lt.Study(tmp_path / "sim", seed=3)
    assert r1.n == 48 and r1.best_cost < model.evaluate(model.space.manual)
    assert latent.d == 8 and latent.d_low == 3
    target = lt.Study(tmp_path / "real", seed=3)
    r3 = target.phase3(real, 12, latent=tmp_path / "sim", strategy="plain")   # the paper's
    assert r3.n == 12
    st = target.store
    assert st.count(Phase.MANUAL) == 1 and st.count(Phase.PHASE3) == 12
    zs = st.rows(Phase.ZERO_SHOT)                       # the source's best θ, as it is
    assert len(zs) == 1
    np.testing.assert_allclose(zs[0].theta, sim.best().theta)
    assert zs[0].cost == pytest.approx(real.evaluate(sim.best().theta))
    # phase 3 rows: θ is the decoded z
    row = st.rows(Phase.PHASE3)[5]
    np.testing.assert_allclose(row.theta, target.latent().decode(row.z[None])[0], atol=1e-9)
    # failed trials keep the C1 convention
    failed = [r for r in sim.store.rows(Phase.PHASE1) if r.fell]
    assert all(r.cost == 200.0 and r.info.get("reason") == "x0 too big" for r in failed)
    s = target.summary()
    assert s["phase3_evals"] == 12 and s["manual_cost"] == pytest.approx(
        real.evaluate(real.space.manual))
    assert "phase 3" in target.report(simulate=False)
    # resume: another system or other options are refused
    with pytest.raises(StoreError, match="another system"):
        lt.Study(tmp_path / "real", seed=3).phase3(myplant.make(8, 0.3), 20,
                                                     latent=tmp_path / "sim")
    with pytest.raises(StoreError, match="seed"):
        lt.Study(tmp_path / "sim", seed=4).phase1(model, 60)
    sim.close()
    target.close()


def test_a_run_of_another_task_names_the_task_keywords_that_give_the_stored_one(tmp_path):
    """``Study.phase1(Task(...))`` on a run of another built-in task said "pass --steps 20
    --v-des 0.1234567 to go on with it", the command line's flags, to a Python caller; it
    names the Task's keywords (every digit of v_des; the command line keeps its flags:
    test_bad_input)."""
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(lt.Task(steps=20, v_des=0.1234567), 1)
    with lt.Study(tmp_path / "r", seed=0) as st, pytest.raises(StoreError) as e:
        st.phase1(lt.Task(steps=30), 2)
    assert str(e.value).endswith(": pass steps=20, v_des=0.1234567 to go on with it"), e.value


def test_a_run_of_another_python_system_says_what_to_do(tmp_path):
    """``Study.phase1`` with a FunctionSystem of another function (renamed, a lambda now) on a
    run holding trials said only "holds a run of another system (config.name: stored 'f',
    given '<lambda>')"; it now says to go on with the system the run holds, or use another
    directory."""
    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])

    def f(x):
        return float(x.sum())

    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(lt.FunctionSystem(sp, f), 2)
    with lt.Study(tmp_path / "r", seed=0) as st, pytest.raises(StoreError) as e:
        st.phase1(lt.FunctionSystem(sp, lambda x: float(x.sum())), 3)
    assert "another system (config.name: stored '" in str(e.value), e.value
    assert str(e.value).endswith("): go on with the system it was run with, or use another "
                                 "directory"), e.value


def test_phase3_hands_over_to_the_full_space_and_records_it(tmp_path, user_sim):
    import myplant

    real = myplant.make(8, 0.15)
    shutil.copytree(user_sim[0], tmp_path / "sim")
    with lt.Study(tmp_path / "plain", seed=3) as plain:
        floor = plain.phase3(real, 40, latent=tmp_path / "sim", strategy="plain").best_cost
    opts = {"patience": 8}
    with lt.Study(tmp_path / "real", seed=3) as target:
        target.phase3(real, 24, latent=tmp_path / "sim", handover=opts, max_new=24)
    with lt.Study(tmp_path / "real", seed=3) as target:        # resumed
        res = target.phase3(real, 40, latent=tmp_path / "sim", handover=opts)
        rec = target.config()["phase3_handover"]
        rows = target.store.rows(Phase.PHASE3)
        ls = target.latent()
        summ = target.summary()["phase3_handover"]
        report = target.report(simulate=False) and (target.dir / "report.md").read_text()
    at = rec["handover_at"]
    assert res.n == 40 and at is not None and 8 <= at < 40
    # the store says which space each evaluation came from: z up to the hand-over, none after
    assert [r.z is not None for r in rows] == [True] * at + [False] * (40 - at)
    np.testing.assert_allclose(rows[0].theta, ls.decode(rows[0].z[None])[0], atol=1e-9)
    assert res.best_cost < floor            # the full-space stage gets below the latent floor
    assert summ["latent_evals"] == at and summ["full_evals"] == 40 - at
    assert summ["full_best"] == pytest.approx(res.best_cost)
    assert f"handed over after {at} latent evaluations" in report
    with pytest.raises(StoreError, match="handover"):
        lt.Study(tmp_path / "real", seed=3).phase3(real, 50, latent=tmp_path / "sim")
    with pytest.raises(LatentuneError, match="handover"):
        lt.Study(tmp_path / "bad", seed=3).phase3(real, 5, latent=tmp_path / "sim",
                                                  handover={"after": 3})
    # ask/tell with a hand-over: suggestions cross into the full space like the phase does
    at_study = lt.Study(tmp_path / "asktell", seed=3)
    n_full = 0
    for _ in range(7):
        for sg in at_study.ask(4, system=real, phase=3, latent=tmp_path / "sim",
                               handover=opts):
            n_full += sg.z is None and sg.phase == Phase.PHASE3
            at_study.tell(sg.id, real.evaluate(sg.theta))
    assert n_full > 0
    zs = [r.z is not None for r in at_study.store.rows(Phase.PHASE3)]
    assert zs == sorted(zs, reverse=True) and zs[0]
    at_study.close()


def test_a_second_writer_is_refused_at_once(tmp_path, plugin_dir):
    import myplant

    a = lt.Study(tmp_path / "s")
    with a.writing():
        t = time.perf_counter()
        with pytest.raises(LatentuneError, match=f"pid {os.getpid()}"):
            lt.Study(tmp_path / "s").phase1(myplant.make(), 10)
        # refused at once, not after ask/tell's 60-s wait for the lock (a loose bound: loaded CI)
        assert time.perf_counter() - t < 30
    lt.Study(tmp_path / "s").phase1(myplant.make(), 6)   # released


# ---------------------------------------------------------------------------- CLI plugins
def test_tune_and_report_with_system_plugin(tmp_path, plugin_dir, cli, in_plugin_dir,
                                           error_line):
    out = tmp_path / "run"
    args = ["--system", "myplant:make", "--system-arg", "dim=6", "--out", str(out),
            "--backend", "serial", "--quiet", "--vae-epochs", "30", "--latent-dim", "2"]
    code, _, err = in_plugin_dir("tune", *args, "--phase1-evals", "24", "--phase3-evals", "8")
    assert code == 0, err
    r = rows(out)
    assert [sum(1 for x in r if x[0] == ph) for ph in (0, 1, 3)] == [1, 24, 8]
    cfg = json.loads((out / "summary.json").read_text())["config"]
    assert cfg["system"]["target"] == "myplant:make" and cfg["system"]["args"] == {"dim": 6}
    best = json.loads((out / "phase1_best.json").read_text())
    assert sorted(best) == ["tuned_for"] + [f"w{i}" for i in range(6)]
    assert best["tuned_for"] == {"system": "myplant:make"}
    before = rows(out)
    elsewhere = tmp_path / "elsewhere"                          # myplant is not importable here
    elsewhere.mkdir()
    p = cli("report", str(out), "--quiet", cwd=elsewhere)      # never imports the plugin
    assert p.returncode == 0, p.stderr
    assert (out / "report.md").is_file() and rows(out) == before
    # resume with other --system-arg values is refused, nothing is written
    code, _, err = in_plugin_dir("tune", *args[:2], "--system-arg", "dim=7", *args[4:],
                                 "--resume")
    assert "dim" in error_line(code, err)
    assert rows(out) == before
    code, _, err = in_plugin_dir("phase3", *args[:-4], "--latent-dim", "2", "--phase3-evals",
                                 "10", "--resume")
    assert code == 0, err
    assert sum(1 for x in rows(out) if x[0] == 3) == 10
    # every ask of the default phase 3, across the resume, is in the store, status and report
    from latentune.pipeline.results import decisions
    from latentune.pipeline.store import RunStore

    with RunStore(out) as st:
        ds = decisions(st)
        gens = sorted({int(r.tag) // 4 for r in st.rows(Phase.PHASE3) if r.tag >= 0})
    assert [d["generation"] for d in ds] == gens and len(gens) >= 3     # asked before and after
    assert all("agreement" in d or "rule" in d for d in ds)
    code, outp, err = in_plugin_dir("status", str(out))
    assert code == 0, err
    assert f"phase 3 decisions: {len(ds)} asks (" in outp
    p = cli("report", str(out), "--quiet", cwd=elsewhere)
    assert p.returncode == 0, p.stderr
    md = (out / "report.md").read_text()
    table = md.split("## Phase 3 decisions")[1].split("\n\n")[2].splitlines()
    assert len(table) == 2 + len(ds) and table[2].startswith("| 0 | ")


def test_report_on_a_custom_robot_run(tmp_path, cli, run_cli):
    spec = tmp_path / "my_a1.yaml"
    spec.write_text("base: a1\nname: my_a1\nnominal_height: 0.29\n")
    out = tmp_path / "robot"
    code, _, err = run_cli("phase1", "--robot", spec, "--steps", "150", "--out", out,
                           "--phase1-evals", "4", "--backend", "serial", "--quiet")
    assert code == 0, err
    spec.unlink()                                   # the run holds the spec itself
    p = cli("report", str(out), "--quiet")          # a fresh process: no spec cached
    assert p.returncode == 0, p.stderr
    assert (out / "com_velocity.png").is_file()


@pytest.mark.parametrize("target, expect", [
    ("nosuchmodule:make", "cannot import"),
    ("myplant:nothing", "no attribute"),
    ("myplant", "module:factory"),
    ("myplant:raises", "factory raised RuntimeError: no robot connected"),
    ("myplant:not_a_system", "not a latentune system"),
])
def test_bad_system_plugins(tmp_path, in_plugin_dir, error_line, target, expect):
    code, _, err = in_plugin_dir("phase1", "--system", target, "--out", tmp_path / "x",
                                 "--phase1-evals", "4", "--backend", "serial")
    line = error_line(code, err)
    assert expect in line
    assert not (tmp_path / "x" / "run.db").exists()


@pytest.mark.parametrize("factory, expect", [
    ("bad", "raised ValueError: sensor timeout"), ("nan", "non-finite cost"),
    ("none", "returned NoneType"),
])
def test_a_system_that_raises_or_returns_no_cost_stops_with_one_line(tmp_path, in_plugin_dir,
                                                                      error_line, factory,
                                                                      expect):
    out = tmp_path / "r"
    code, _, err = in_plugin_dir("phase1", "--system", f"myplant:{factory}", "--out", out,
                                 "--phase1-evals", "20", "--backend", "serial", "--quiet")
    line = error_line(code, err)
    assert expect in line
    if factory == "bad":            # the trials before the failing one are stored, contiguous
        r = [x for x in rows(out) if x[0] == 1]
        assert [x[1] for x in r] == list(range(len(r)))


def test_a_broken_module_fails_loudly(tmp_path, cli_env):
    """A syntax error in a command's module is a traceback, never 'invalid choice'."""
    pkg = tmp_path / "latentune"
    src = Path(lt.__file__).parent
    shutil.copytree(src, pkg)
    (pkg / "study.py").write_text((pkg / "study.py").read_text() + "\n)\n")
    env = dict(cli_env, PYTHONPATH=str(tmp_path))
    p = subprocess.run([PY, "-c", "import latentune.cli"], capture_output=True, text=True,
                       env=env, cwd=tmp_path)
    assert p.returncode == 0, p.stderr          # the CLI imports commands' modules lazily ...
    p = subprocess.run([PY, "-m", "latentune.cli", "tune", "--out", str(tmp_path / "r")],
                       capture_output=True, text=True, env=env, cwd=tmp_path)
    assert p.returncode != 0                    # ... and running one shows the real error
    assert "SyntaxError" in p.stderr and "invalid choice" not in p.stderr
    (pkg / "cli.py").write_text((pkg / "cli.py").read_text() + "\nimport latentune.study\n")
    p = subprocess.run([PY, "-c", "import latentune.cli"], capture_output=True, text=True,
                       env=env, cwd=tmp_path)
    assert p.returncode != 0 and "SyntaxError" in p.stderr


# ---------------------------------------------------------------------------- ask / tell
def robot_program(pfile: str) -> str:
    """The robot's program: reads the suggestion's parameter file, returns the cost to tell
    (``FAILED`` for a failed trial)."""
    import myplant

    params = json.loads(Path(pfile).read_text())
    out = myplant.cost(np.array([params[f"w{i}"] for i in range(6)]), 0.1)
    return "FAILED" if not isinstance(out, float) else str(out)


def test_ask_tell_a_whole_phase3_with_kills(tmp_path, plugin_dir, in_plugin_dir, error_line,
                                            cli_env):
    """A person at a robot: ``latentune ask`` and ``latentune tell`` (the CLI, a new Study from
    the store each time), the robot's program reading the suggestion's file, walking away between
    ask and tell and SIGKILL of a ``tell`` process; every told trial is stored once, none lost or
    handed out twice."""
    sim = tmp_path / "sim"
    code, _, err = in_plugin_dir("tune", "--system", "myplant:make", "--system-arg", "dim=6",
                                 "--out", sim, "--phase1-evals", "30", "--phase3-evals", "4",
                                 "--backend", "serial", "--quiet", "--vae-epochs", "30",
                                 "--latent-dim", "2")
    assert code == 0, err
    real = tmp_path / "real"
    sysargs = ["--system", "myplant:make", "--system-arg", "dim=6", "--system-arg", "shift=0.1"]
    budget, told, handed, kills = 12, [], set(), 0
    rng = np.random.default_rng(0)
    while len(told) < budget + 1:                   # + the zero-shot trial
        code, out, err = in_plugin_dir("ask", real, *sysargs, "--phase", "3", "--vae", sim,
                                       "--json")
        assert code == 0, err
        (s,) = json.loads(out)
        assert s["phase"] == (4 if s["id"] == 1 else 3)   # the source's best θ comes first
        if not s["again"]:
            assert s["id"] not in handed            # a new suggestion is new
        handed.add(s["id"])
        if rng.random() < 0.25:                     # the person walks away: ask again later
            continue
        pfile = s["file"] or str(tmp_path / f"suggestion{s['id']}.json")
        if not s["file"]:                           # the CLI writes it once it is wired
            Path(pfile).write_text(json.dumps(s["params"]))
        assert json.loads(Path(pfile).read_text()) == s["params"]   # values by name only
        res = robot_program(pfile)
        tell = [PY, "-m", "latentune.cli", "tell", str(real), str(s["id"])]
        tell += ["--failed"] if res == "FAILED" else ["--cost", res]
        if rng.random() < 0.25:                     # SIGKILL during tell
            proc = subprocess.Popen(tell, env=cli_env, cwd=plugin_dir, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            time.sleep(rng.uniform(0.0, 0.6))
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            kills += 1
            with RunStore(real) as st:
                done = st.trials_by_id(s["id"]).status == "told"
            if done:
                told.append(s["id"])
            continue                                 # pending: it is handed out again
        code, out, err = in_plugin_dir(*tell[3:])
        assert code == 0 and out.startswith(f"told {s['id']}"), err
        told.append(s["id"])
        code, _, err = in_plugin_dir(*tell[3:])     # told twice: refused
        assert "was already told" in error_line(code, err)
    assert kills > 0
    with RunStore(real) as st:
        r3 = st.rows(Phase.PHASE3)
        assert [r.idx for r in r3] == list(range(budget))
        zs = st.rows(Phase.ZERO_SHOT)
        assert len(zs) == 1 and zs[0].info["trial"] == 1
        assert sorted(r.info["trial"] for r in r3 + zs) == sorted(told)   # each told trial once
        assert len({r.info["trial"] for r in r3}) == budget
        assert {t.id for t in st.trials("told")} == set(told)
        with RunStore(sim) as src:                   # zero-shot = the source's best θ
            ok = [r for ph in (1, 3) for r in src.rows(ph) if not r.fell]
            np.testing.assert_allclose(zs[0].theta, min(ok, key=lambda r: (r.cost, r.phase, r.idx)).theta)
    code, out, err = in_plugin_dir("status", real, "--json")
    assert code == 0 and json.loads(out)["phases"]["phase 3"]["n"] == budget, err
    # bad ids: one line, store untouched
    before = rows(real)
    for bad, expect in ((["999"], "no suggestion with id 999"),
                        (["abc"], "a suggestion id is an integer, got 'abc'"),
                        ([str(told[0])], f"suggestion {told[0]} was already told")):
        code, _, err = in_plugin_dir("tell", real, *bad, "--cost", "1.0")
        assert expect in error_line(code, err)
    code, _, err = in_plugin_dir("tell", real, max(handed) + 50)   # no cost, not failed
    assert "tell needs --cost C, or --failed" in error_line(code, err)
    assert rows(real) == before


def test_ask_answers_quickly_with_many_told_trials(tmp_path):
    """The critic is rebuilt from the store on every ask: with 1000 told trials in 25-d."""
    space = lt.ParameterSpace([f"q{i}" for i in range(25)], [0] * 25, [1] * 25)
    study = lt.Study(tmp_path / "s")
    first = study.ask(1, space=space)[0]
    rng = np.random.default_rng(0)
    with study.writing() as st:
        for i in range(1000):
            st.add(Phase.PHASE1, i, rng.random(25), float(rng.random()), tag=-1)
    again, new = study.ask(2)          # its latency is benchmarks/ask_latency.py's, not a test's
    assert again.id == first.id and again.again and not new.again and new.theta.shape == (25,)


def test_study_is_a_thin_facade():
    """Study delegates to the pipeline's modules (issue 25: study.py <= 400 lines)."""
    src = Path(lt.__file__).parent / "study.py"
    assert len(src.read_text().splitlines()) <= 400


def test_plain_phase3_refuses_a_latent_space_that_decodes_to_one_theta(tmp_path):
    """A latent space whose codes all decode to one θ: the paper's phase 3 is refused with one
    line before any trial, the default transfer phase 3 runs on it."""
    from latentune.errors import LatentError
    from latentune.latent.vae import LatentSpace

    space = lt.ParameterSpace(names=["a", "b", "c"], low=[0.0] * 3, high=[1.0] * 3,
                              manual=[0.5] * 3)
    sys_ = lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.3) ** 2)), name="q")
    with lt.Study(tmp_path / "src", seed=0) as st:
        st.phase1(sys_, 12)
        st.train_latent(epochs=5)
    ls = LatentSpace.load(tmp_path / "src" / "vae")
    for p in ls.net.decoder[-2].parameters():          # the sigmoid's input: 0 for every code
        p.data.zero_()
    ls.save(tmp_path / "src" / "vae")
    with lt.Study(tmp_path / "t", seed=0) as st:
        with pytest.raises(LatentError, match="decodes every code to one θ"):
            st.phase3(sys_, 6, latent=tmp_path / "src", strategy="plain")
        assert not st.exists or st.store.count(Phase.PHASE3) == 0
    with lt.Study(tmp_path / "d", seed=0) as st:
        assert st.phase3(sys_, 6, latent=tmp_path / "src").n == 6


def test_a_fall_step_beyond_its_horizon_and_a_negative_max_new_are_refused(tmp_path):
    """A failed outcome whose ``fall_step`` lies outside ``0 … horizon`` is a defect of the
    system, not a trial (its convention cost ``C1·(2 − k/N)`` would fall below every standing
    trial: −300 for 50 of 10); ``max_new`` below 0 is refused before any trial. A fall step
    with a horizon of 0 steps (no step to fall at; ``tell --horizon 0`` is refused) was taken
    as no horizon: the fall step was dropped and the trial cost 2·C1; it is refused too."""
    from latentune.errors import UsageError
    from latentune.system import EvaluationError, as_outcome

    assert as_outcome(lt.Outcome(None, True, {"fall_step": 5, "horizon": 10})).cost == 150.0
    for k, n in ((50, 10), (-1, 10), ("late", 10), (5, 0), (0, 0), (5, False)):
        with pytest.raises(EvaluationError, match="outside its horizon"):
            as_outcome(lt.Outcome(None, True, {"fall_step": k, "horizon": n}))
    for k in ("late", -1, 2.5):                 # no horizon: was int("late") in the store
        with pytest.raises(EvaluationError, match="expected a whole number of steps"):
            as_outcome(lt.Outcome(None, True, {"fall_step": k}))
    with pytest.raises(EvaluationError, match="info = \\[1\\]; expected a dict"):
        as_outcome(lt.Outcome(1.0, False, [1]))
    for w in ("x", -1.0, float("nan")):         # was float("x") in the store: a traceback
        with pytest.raises(EvaluationError, match="wall_s = .*expected None or a time >= 0"):
            as_outcome(lt.Outcome(1.0, wall_s=w))
    assert as_outcome(lt.Outcome(1.0, wall_s=np.float32(2))).wall_s == 2.0
    with pytest.raises(EvaluationError, match="key\\(s\\) fell; an outcome has cost, failed"):
        as_outcome({"cost": 1.0, "fell": True})  # was a trial that stood: the fall was lost
    assert as_outcome({"cost": 1.0, "failed": True, "info": {}, "wall_s": 1}).failed
    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(UsageError, match="max_new must be a whole number >= 0"):
            st.phase1(lt.FunctionSystem(sp, lambda x: float(x.sum())), 5, max_new=-1)
        assert st.trials() == []


def test_best_params_refusals_name_no_command_line_flag(tmp_path):
    """``Study.best_params(out=...)`` with a directory or an empty name: the refusal named the
    command's flag (``--out names the θ file to write``) to a Python user; it names the file
    to give, for both, now."""
    from latentune.errors import UsageError

    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with lt.Study(tmp_path / "r") as st:
        st.phase1(lt.FunctionSystem(sp, lambda x: float(x.sum())), 2)
        for out, said in ((tmp_path, "is a directory: name the θ file to write"),
                          ("", "the θ file to write needs a name")):
            with pytest.raises(UsageError, match=said) as e:
                st.best_params(out)
            assert "--" not in str(e.value)


def test_preservation_refuses_what_is_not_a_system_in_one_line(tmp_path):
    """``Study.preservation`` given something that is not a system (None, a class, a plain
    function) raised AttributeError: 'NoneType' object has no attribute 'space'; it says what
    a system needs now, as phase1 and phase3 do, before the run is touched."""
    from latentune.errors import SystemSpecError

    st = lt.Study(tmp_path / "r")
    for bad in (None, lambda x: 0.0, lt.FunctionSystem):
        with pytest.raises(SystemSpecError, match="not a system|not a latentune system"):
            st.preservation(bad, None)
    assert not (tmp_path / "r").exists()


def test_train_latent_without_a_run_leaves_the_directory_as_it_was(tmp_path):
    """``train_latent`` on a directory holding no run (a typo, phase 1 not run yet) is refused;
    it left an empty run store behind (run.db, run.lock; a new directory created), which
    ``status`` then showed as a run and a later ``latent=`` named as one without a latent
    space. The directory is as it was now: absent, or empty."""
    from latentune.errors import LatentError

    for d, made in ((tmp_path / "absent", False), (tmp_path / "empty", True)):
        if made:
            d.mkdir()
        with pytest.raises(LatentError, match="phase 1 has 0 θ"):
            lt.Study(d).train_latent(epochs=5)
        assert d.is_dir() == made and (not made or os.listdir(d) == [])


def test_train_latent_refuses_bad_epochs_before_replacing_the_vae(tmp_path):
    """``epochs`` of 0, −1 or 2.5 with ``retrain`` is refused before the trained VAE is
    touched (it was replaced by an untrained one, then a TypeError)."""
    from latentune.errors import UsageError

    sp = lt.ParameterSpace(["a", "b", "c"], [0] * 3, [1] * 3)
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(lt.FunctionSystem(sp, lambda x: float(((x - 0.3) ** 2).sum())), 12)
        st.train_latent(latent_dim=2, epochs=5)
        before = (tmp_path / "r" / "vae.pt").read_bytes()
        for bad in (0, -1, 2.5, True):
            with pytest.raises(UsageError, match="epochs must be a whole number >= 1"):
                st.train_latent(epochs=bad, retrain=True)
        assert (tmp_path / "r" / "vae.pt").read_bytes() == before
        # a trained VAE is kept as it is: another size, kind or epochs was ignored silently
        for kw, said in (({"latent_dim": 1}, "latent_dim = 2, not 1"),
                         ({"kind": "vae"}, "kind = 'det', not 'vae'"),
                         ({"epochs": 7}, "epochs = 5, not 7")):
            with pytest.raises(UsageError, match=said):
                st.train_latent(**kw)
        assert st.train_latent(latent_dim=2, kind="det", epochs=5).d_low == 2
        assert (tmp_path / "r" / "vae.pt").read_bytes() == before


def test_train_latent_names_a_latent_dim_of_the_wrong_type_on_a_trained_run(tmp_path):
    """``train_latent(latent_dim="5")`` on a run trained with latent_dim 5 said "trained already
    with latent_dim = 5, not '5'" (as if the sizes differed); it now says latent_dim must be a
    whole number, as on a run not trained yet, and keeps the trained VAE."""
    from latentune.errors import LatentError

    sp = lt.ParameterSpace(["a", "b", "c"], [0] * 3, [1] * 3)
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(lt.FunctionSystem(sp, lambda x: float(((x - 0.3) ** 2).sum())), 12)
        st.train_latent(latent_dim=2, epochs=5)
        for bad in ("2", 2.0, 0, True):
            with pytest.raises(LatentError, match=r"latent dimension must be a whole number >= 1,"
                                                  r" got"):
                st.train_latent(latent_dim=bad)
        assert st.train_latent(latent_dim=2).d_low == 2


def test_a_cost_the_store_cannot_keep_is_refused_or_a_fall(tmp_path):
    """The store keeps ±1e300 for ±inf: a standing trial's cost of 1e300 or more in size is
    refused by name (it was stored and read back as inf, and best() became inf); a failed
    trial's is no cost, as a NaN is (the fall convention, what was reported kept)."""
    from latentune.system import CostError, as_outcome

    for c in (1e300, -1e300, 1e305):
        with pytest.raises(CostError, match="smaller than 1e.300 in size"):
            as_outcome(c)
    out = as_outcome(lt.Outcome(1e300, True))
    assert out.cost == 200.0 and out.info["reported_cost"] == "1e+300"
    assert as_outcome(9.9e299).cost == 9.9e299
    sp = lt.ParameterSpace(["a"], [0], [1])
    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(CostError):
            st.phase1(lt.FunctionSystem(sp, lambda x: 1e300), 3)


def test_an_evaluate_returning_a_0d_array_or_tensor_is_a_cost(tmp_path):
    """An ``evaluate`` returning a 0-d array or a 0-d torch tensor (``torch.sum(...)``) stopped
    the phase with "evaluate returned Tensor tensor(0.5); expected a cost (float)", though the
    same value inside ``(cost, failed)``, a dict or an Outcome was taken. It is now a cost
    there too; an array of another shape is refused naming its shape."""
    import torch
    from latentune.system import CostError, as_outcome

    for v in (np.array(0.5), torch.tensor(0.5), torch.tensor(0.5, dtype=torch.float64)):
        assert as_outcome(v).cost == 0.5 and as_outcome((v, False)).cost == 0.5
    for v, shape in ((np.array([0.5]), "(1,)"), (torch.tensor([0.5, 1.0]), "(2,)")):
        with pytest.raises(CostError, match=re.escape(f"evaluate returned an array of shape "
                                                      f"{shape}; expected one float")):
            as_outcome(v)
    with pytest.raises(CostError, match="expected a cost .float., .cost, failed. or an Outcome"):
        as_outcome(np.True_)
    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(lt.FunctionSystem(sp, lambda x: torch.as_tensor(x).pow(2).sum()), 4)
        assert len(st.store.costs(1)) == 4


def _info_json_cannot_hold(x):
    loop: dict = {"x": float(x[0])}
    loop["self"] = loop
    return lt.Outcome(float(x.sum()), info={(1, 2): "pair", np.int64(3): [np.float32(0.5)],
                                            "loop": loop})


def test_an_info_with_keys_json_cannot_have_is_stored_not_a_traceback(tmp_path):
    """An ``evaluate`` whose Outcome.info had a tuple or a NumPy integer as a key (or held
    itself) ended ``latentune phase1`` with a traceback ("TypeError: keys must be str, int,
    float, bool or None, not tuple") on the serial backend, and ``Study.tell(info=…)`` alike.
    The store keeps such keys as text, as it keeps other values JSON has no type for."""
    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    with lt.Study(tmp_path / "r", seed=0, workers=1, backend="serial") as st:
        st.phase1(lt.FunctionSystem(sp, _info_json_cannot_hold), 3)
        info = st.trials()[-1].info
        assert info["(1, 2)"] == "pair" and info["3"] == [0.5]
        assert info["loop"]["self"] == "<circular>"
    with lt.Study(tmp_path / "t", seed=0) as st:
        (s,) = st.ask(system=lt.FunctionSystem(sp, _info_json_cannot_hold))
        st.tell(s.id, 1.0, info={np.int64(3): 1})
        st.tell(s.id, 2.0, info={(4, 5): 1}, amend=True)
        assert st.trials()[0].info["(4, 5)"] == 1 and st.amendments()


class _Configured:
    """A system whose ``config()`` raises, or returns a dict with a tuple key."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])

    def evaluate(self, theta):
        return float(np.sum(theta))

    def config(self):
        if self.kind == "raise":
            raise RuntimeError("no config\nyet")
        return {"gains": {(0, 1): 2.0}}


def test_a_system_whose_config_raises_or_has_a_tuple_key_is_one_clear_error(tmp_path):
    """``Study.phase1`` on a system whose ``config()`` raised let the system's RuntimeError out
    unexplained, and one whose config held a tuple key raised json's "TypeError: keys must be
    str, int, float, bool or None"; the first is now one SystemSpecError naming config(), the
    second is recorded (its key as text) and compared on resume."""
    from latentune.errors import SystemSpecError

    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(SystemSpecError, match=r"_Configured.config\(\) raised RuntimeError: "
                                                  "no config yet"):
            st.phase1(_Configured("raise"), 3)
        assert st.trials() == []
    with lt.Study(tmp_path / "k") as st:
        st.phase1(_Configured("tuple"), 3)
        assert st.config()["system"]["config"] == {"gains": {"(0, 1)": 2.0}}
    with lt.Study(tmp_path / "k") as st:
        st.phase1(_Configured("tuple"), 4)
        assert len(st.trials()) == 5


@pytest.mark.parametrize("regions", [2.5, "3", True])
def test_study_regions_must_be_a_whole_number(tmp_path, regions):
    """Study.phase1(regions=2.5) ran 2 trust regions (int(2.5)), as TurboSampler did: a
    UsageError now, before anything is written."""
    from latentune.errors import UsageError

    system = lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [1, 1]),
                               lambda x: float(x.sum()))
    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(UsageError, match="regions must be an integer in"):
            st.phase1(system, 4, regions=regions)
    assert not (tmp_path / "r" / "run.db").exists()


def test_a_phase_where_every_trial_failed_says_so_not_best_cost_inf(tmp_path):
    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
    said: list[str] = []
    with lt.Study(tmp_path / "s", seed=0, log=said.append) as s:
        res = s.phase1(lt.FunctionSystem(space, lambda x: lt.Outcome(None, failed=True)), 3)
    assert res.best_cost == float("inf")
    assert said[-1] == "phase 1: 3 evaluations, no trial stood (all 3 failed)"


def test_a_fall_flag_that_is_not_a_bool_is_refused_not_guessed(tmp_path):
    """``failed="False"`` (read from a file) counted as a fall (``bool("False")``), and an
    array of flags was a ValueError traceback; both are now one line, nothing stored."""
    from latentune.errors import UsageError
    from latentune.system import EvaluationError, as_outcome

    for ok, fell in ((False, False), (np.bool_(True), True), (np.array(True), True), (1, True),
                     (0, False), (None, False)):
        assert as_outcome(lt.Outcome(1.0, ok)).failed is fell
        assert as_outcome((1.0, ok)).failed is fell and as_outcome({"cost": 1.0,
                                                                    "failed": ok}).failed is fell
    for bad in ("False", "no", np.array([True, False]), float("nan"), 2, 0.0):
        with pytest.raises(EvaluationError, match="failed = .*expected True or False"):
            as_outcome(lt.Outcome(1.0, bad))
    sp = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0])
    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(EvaluationError, match="failed = 'False'"):
            st.phase1(lt.FunctionSystem(sp, lambda x: lt.Outcome(1.0, "False")), 3)
        assert st.store.count(Phase.PHASE1) == 0
        (s,) = st.ask(space=sp)
        with pytest.raises(UsageError, match="bad result for suggestion 1: got failed = 'no'"):
            st.tell(s.id, 1.0, failed="no")


def test_a_failed_flag_that_is_not_a_bool_is_refused():
    """``return cost, info`` (or a string, or 0.5) as ``(cost, failed)`` made every trial a
    fall, silently: the flag was read by its truth. A bool, numpy's, or 0 / 1 is a flag."""
    from latentune.system import EvaluationError, as_outcome

    for bad in ((1.0, {"vx": 1.0}), (1.0, "no"), (1.0, 0.5), {"cost": 1.0, "failed": "False"},
                lt.Outcome(1.0, [0])):
        with pytest.raises(EvaluationError, match="failed = .*expected True or False"):
            as_outcome(bad)
    for ok, failed in (((1.0, np.bool_(True)), True), ((1.0, 0), False),
                       ({"cost": 1.0, "failed": 1}, True), (lt.Outcome(1.0, False), False)):
        assert as_outcome(ok).failed is failed


def test_phase3_refuses_a_latent_that_is_not_a_study_or_a_latent_space(tmp_path):
    """``phase3(sys, 3, latent=5)`` raised os.fspath's TypeError; ``FunctionSystem(...,
    by_name="no")`` passed θ by name (bool("no") is True)."""
    from latentune.errors import LatentError

    sp = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    sys_ = lt.FunctionSystem(sp, lambda x: float(x.sum()))
    with lt.Study(tmp_path / "t") as st:
        with pytest.raises(LatentError, match="latent must be a study, its run directory or a "
                                              "LatentSpace, not int 5"):
            st.phase3(sys_, 3, latent=5)
        assert not st.exists or st.trials() == []
    with pytest.raises(TypeError, match="by_name must be True or False, got 'no'"):
        lt.FunctionSystem(sp, lambda d: d["a"], by_name="no")


def test_train_latent_says_when_the_kept_latent_space_misses_phase_1_trials(tmp_path, caplog,
                                                                          run_cli):
    """Phase 1 grown after ``train_latent`` (``Study.phase1`` with a larger budget, or an
    Optuna study imported again): ``train_latent()`` returned the latent space trained on the
    first θ without a word. It is still returned as it is, with one warning naming how many
    θ it was trained on and how to train on all (``retrain=True``, ``train-vae``)."""
    import logging

    sp = lt.ParameterSpace(["a", "b", "c"], [0] * 3, [1] * 3)
    fs = lt.FunctionSystem(sp, lambda x: float(((x - 0.3) ** 2).sum()))
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(fs, 8)
        st.train_latent(latent_dim=2, epochs=5)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            st.train_latent()
        assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
        st.phase1(fs, 12)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            kept = st.train_latent()
        warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert len(warned) == 1 and "trained on 8" in warned[0] and "12" in warned[0] \
            and "retrain" in warned[0], warned
        assert kept.meta["n_phase1"] == 8
    plant = ("--system", "examples.toy_plant:make_system", "--out", tmp_path / "t")
    run = ("--backend", "serial", "--workers", "1")              # and train-vae --resume
    assert run_cli("phase1", *plant, *run, "--phase1-evals", "6")[0] == 0
    assert run_cli("train-vae", *plant, "--latent-dim", "2", "--vae-epochs", "5")[0] == 0
    assert run_cli("phase1", *plant, *run, "--phase1-evals", "9", "--resume")[0] == 0
    code, out, err = run_cli("train-vae", *plant, "--resume")
    assert code == 0 and "kept" in out and "phase 1 holds" in err, (out, err)


def _phase1_killed_after(path: Path, n: int) -> None:
    """In a child process: phase 1 on a bowl whose ``n``-th trial ends the process at once
    (``os._exit``, as SIGKILL: no clean-up runs)."""
    calls = [0]

    def cost(x: np.ndarray) -> float:
        calls[0] += 1
        if calls[0] > n:
            os._exit(9)
        time.sleep(0.02)
        return float(np.sum((x - 0.3) ** 2))

    space = lt.ParameterSpace(names=["a", "b"], low=[0.0] * 2, high=[1.0] * 2, manual=[0.5] * 2)
    lt.Study(path, seed=0).phase1(lt.FunctionSystem(space, cost, name="bowl"), 40,
                                  method="random")


def _killed_in_phase1(path: Path) -> None:
    """Phase 1 at ``path`` in a forked process that dies (exit 9, no clean-up) at its 9th
    trial (:func:`_phase1_killed_after`)."""
    import multiprocessing

    proc = multiprocessing.get_context("fork").Process(target=_phase1_killed_after,
                                                       args=(path, 8))
    proc.start()
    proc.join(60)
    assert proc.exitcode == 9


def test_a_killed_phase_s_wall_time_does_not_take_in_trials_told_later(tmp_path):
    """A run killed inside phase 1 leaves its block open; its time counts up to its last stored
    trial. Trials told later through ask/tell (no command timed them, and asking settles no
    block) counted as that run's own: the killed block's time stretched to the last tell, hours
    later at a robot. It counts the trials its command stored, not the told ones."""
    from latentune.pipeline.walltime import wall_record

    _killed_in_phase1(tmp_path / "k")
    with RunStore(tmp_path / "k") as st:
        before = wall_record(st)[0]["phase1"]
    assert before > 0.05
    space = lt.ParameterSpace(names=["a", "b"], low=[0.0] * 2, high=[1.0] * 2, manual=[0.5] * 2)
    sys_ = lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.3) ** 2)), name="bowl")
    with lt.Study(tmp_path / "k", seed=0) as study:
        time.sleep(1.0)                               # the trial at the robot
        for s in study.ask(2, system=sys_, phase=1):
            study.tell(s.id, float(np.sum((s.theta - 0.3) ** 2)))
    with RunStore(tmp_path / "k") as st:
        assert st.count(Phase.PHASE1) >= 10
        assert wall_record(st)[0]["phase1"] == pytest.approx(before)


def test_a_run_killed_inside_a_phase_reports_its_real_wall_time(tmp_path):
    """A run killed inside phase 1 (no clean-up: its wall time was never added) reports the
    time up to its last stored trial, not 0; the next run of the store adds it for good. A phase
    whose trials no command timed says its time is unknown (wall_s None), never 0."""
    from latentune.reporting.run_report import write_summary

    _killed_in_phase1(tmp_path / "k")
    with RunStore(tmp_path / "k") as st:
        assert st.count(Phase.PHASE1) > 0
        s = write_summary(st)
        assert s["wall_s"] > 0.05 and s["wall_by_phase_s"]["phase1"] > 0.05
        assert s["wall_unknown"] == []
    space = lt.ParameterSpace(names=["a", "b"], low=[0.0] * 2, high=[1.0] * 2, manual=[0.5] * 2)
    sys_ = lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.3) ** 2)), name="bowl")
    lt.Study(tmp_path / "k", seed=0).phase1(sys_, 40, method="random")
    with RunStore(tmp_path / "k") as st:
        assert st.get_meta("wall_open") is None and st.get_meta("wall")["phase1"] > 0.05
    with RunStore(tmp_path / "k") as st:          # trials with no wall record (ask/tell, or
        st.delete_meta("wall")                    # a run killed before this fix)
        s = write_summary(st)
        assert s["wall_s"] is None and s["wall_unknown"] == ["phase1"]


def test_a_phase_s_wall_time_counts_its_manual_and_zero_shot_trials(tmp_path, user_sim):
    """A phase's wall time began after its manual θ's trial (and phase 3's zero-shot trial)
    had run, though phase 1's first row is that trial and phase 3's target budget counts both:
    a phase 1 of a 0.3 s trial reported 0.6 s for 3 trials (0.9 s of trials), and a slow
    manual trial (5 s) left the report's wall time at 2 s for an 8 s run. The phase's time
    now holds them."""
    from latentune.reporting.run_report import write_summary

    def slow(x: np.ndarray) -> float:
        time.sleep(0.3)
        return float(np.sum((x - 0.2) ** 2))

    import myplant

    space = myplant.make(8).space
    with lt.Study(tmp_path / "p1", seed=0) as s:
        s.phase1(lt.FunctionSystem(space, slow), 3, method="random")
        assert write_summary(s.store)["wall_by_phase_s"]["phase1"] >= 0.9
    shutil.copytree(user_sim[0], tmp_path / "sim")
    with lt.Study(tmp_path / "p3", seed=0) as s:      # manual, zero-shot and 2 phase-3 trials
        s.phase3(lt.FunctionSystem(space, slow), 2, latent=tmp_path / "sim", strategy="plain")
        assert s.store.count(Phase.MANUAL) == s.store.count(Phase.ZERO_SHOT) == 1
        assert write_summary(s.store)["wall_by_phase_s"]["phase3"] >= 1.2


def test_status_does_not_point_at_a_best_file_of_an_earlier_best(stopped_after_a_better_trial,
                                                                 run_cli):
    """A phase run stopped (Ctrl-C) after a better trial than its earlier best, before it
    wrote best.json: status said "best: 0 (phase 1, evaluation 5); its θ: DIR/best.json",
    while best.json held the earlier best θ, the one a person would deploy. Status names the
    file only when it holds the best trial's θ, and else says to write it."""
    d, space = stopped_after_a_better_trial
    with lt.Study(d) as s:
        best, st = s.best(), s.status()
        assert best.cost == 0.0
        assert json.loads((d / "best.json").read_text())["a"] != space.as_dict(best.theta)["a"]
    assert st["best"]["params_file"] is None and st["best"]["params_stale"] is True
    code, out, err = run_cli("status", d)
    assert code == 0, err
    assert f"best: 0 (phase 1, evaluation {best.idx}); {d / 'best.json'} holds an earlier " \
        f"best θ (a run stopped before it wrote this one); write it with: latentune best" in out
    assert run_cli("best", d)[0] == 0               # written: status names it again
    assert run_cli("status", d)[1].splitlines()[-1].endswith(f"its θ: {d / 'best.json'}")


def test_a_phase_run_cannot_lower_the_budget_it_stored(tmp_path, run_cli, error_line):
    """``Study.phase1(system, 8)`` (``phase1 --phase1-evals 8 --resume``) on a phase 1 of 20
    trials recorded a budget of 8 with 20 trials stored, silently: a later ask said "phase 1's
    budget of 8 trials is told", and the critic's plan (its trust regions, by budget) was no
    longer the one its trials were asked by. A smaller budget is refused as an ask refuses it;
    the same or a larger one goes on."""
    from latentune.errors import StoreError

    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
    bowl = lt.FunctionSystem(space, lambda x: float(np.sum((x - 0.3) ** 2)), name="bowl")
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(bowl, 20, method="random")
    with lt.Study(tmp_path / "r", seed=0) as st, \
            pytest.raises(StoreError, match=r"phase 1 has a budget of 20 trials \(stored\), "
                                            r"which budget=8 would lower; a budget can only "
                                            r"grow: give budget=20 or more$"):
        st.phase1(bowl, 8, method="random")
    with lt.Study(tmp_path / "r", seed=0) as st:
        assert st.config()["phase1"]["budget"] == 20
        assert st.phase1(bowl, 22, method="random").n == 22
    out = tmp_path / "c"
    flags = ("--system", "examples.toy_plant:make_system", "--out", out, "--backend", "serial")
    assert run_cli("phase1", *flags, "--phase1-evals", "6")[0] == 0
    line = error_line(*run_cli("phase1", *flags, "--phase1-evals", "4", "--resume")[::2])
    assert line.endswith("phase 1 has a budget of 6 trials (stored), which --phase1-evals 4 "
                         "would lower; a budget can only grow: give --phase1-evals 6 or more, "
                         "or leave it out"), line


def test_train_latent_warns_when_few_stable_theta_for_the_latent_dimension(tmp_path, caplog,
                                                                         run_cli):
    """A latent space trained on 2 stable θ with latent_dim 2 (fewer than latent_dim + 1)
    was trained without a word: its codes span at most n − 1 of the box's directions. It now
    warns once, in one line naming the count, the threshold, what it means for phase 3 and what
    to do (more phase-1 trials, a smaller latent dimension); 3 θ for latent_dim 2 do not warn.
    ``train-vae`` says it on stderr."""
    import logging

    sp = lt.ParameterSpace(["a", "b", "c", "d"], [0] * 4, [1] * 4)
    fs = lt.FunctionSystem(sp, lambda x: float(((x - 0.3) ** 2).sum()))

    def warnings_of(st: lt.Study, n: int) -> list[str]:
        st.phase1(fs, n, method="random")
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            st.train_latent(latent_dim=2, epochs=5, retrain=True)
        return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING
                and "stable θ" in r.getMessage()]

    with lt.Study(tmp_path / "r", seed=0) as st:
        warned = warnings_of(st, 2)
        assert len(warned) == 1 and "\n" not in warned[0], warned
        for part in ("2 stable θ", "latent dimension + 1 = 3", "phase 3", "phase-1 trials",
                     "latent dimension of 1 (--latent-dim 1, latent_dim=1)"):
            assert part in warned[0], (part, warned[0])
        assert warnings_of(st, 3) == []
    plant = ("--system", "examples.shifted_bowl:make_system", "--out", tmp_path / "t")
    assert run_cli("phase1", *plant, "--backend", "serial", "--workers", "1",
                   "--phase1-evals", "2", "--method", "random")[0] == 0     # no trial fails
    code, out, err = run_cli("train-vae", *plant, "--latent-dim", "3", "--vae-epochs", "5")
    assert code == 0 and "trained on 2 θ" in out, (out, err)
    assert "2 stable θ" in err and "--latent-dim 1" in err, err


def test_a_resume_keeps_the_stored_regions_and_says_so(tmp_path):
    """phase1 with a budget grown past its first one's default regions (~1 per 500 trials),
    given regions at the new budget's default, was refused with 'was run with regions = 1, not
    2' alone, not saying a resume keeps the stored regions; the refusal now says so and how to
    go on, and the stored value given is accepted."""
    from latentune.critic.turbo import regions_for_budget

    system = lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [1, 1]),
                               lambda x: float(x.sum()))
    assert regions_for_budget(4) == 1 and regions_for_budget(1200) == 2
    with lt.Study(tmp_path / "r") as st:
        st.phase1(system, 4)
        with pytest.raises(StoreError, match=r"regions = 1, not 2; a resume keeps the stored "
                                              r"regions: leave them out \(or give regions=1\)"):
            st.phase1(system, 1200, regions=2)
        st.phase1(system, 5, regions=1)
        assert st.config()["phase1"]["regions"] == 1


def test_a_ctrl_c_in_vae_training_keeps_its_wall_time(tmp_path, monkeypatch):
    """A Ctrl-C during phase 2's training (as inside tune) dropped the block's wall time: the
    rollback of the failed write removed the 'vae' entry with the rest, and the report listed
    phase 1's time alone. The time spent is now kept; the latent space is still not written,
    and the report says the time is that of a training stopped before it stored one."""
    from latentune.latent import LatentSpace

    system = lt.FunctionSystem(lt.ParameterSpace(["a", "b"], [0, 0], [1, 1]),
                               lambda x: float(x.sum()))
    with lt.Study(tmp_path / "r", seed=0) as st:
        st.phase1(system, 8)

    def interrupted(*args, **kwargs):
        time.sleep(0.3)
        raise KeyboardInterrupt

    monkeypatch.setattr(LatentSpace, "train", staticmethod(interrupted))
    with lt.Study(tmp_path / "r") as st:
        with pytest.raises(KeyboardInterrupt):
            st.train_latent(latent_dim=2, epochs=5)
        wall = st.store.get_meta("wall")
        assert wall["vae"] >= 0.3 and wall["phase1"] > 0, wall
        assert not (tmp_path / "r" / "vae.pt").exists() and "vae" not in st.config()
        st.report()
    line = next(ln for ln in (tmp_path / "r" / "report.md").read_text().splitlines()
                if ln.startswith("Wall time:"))
    assert re.search(r"vae [0-9.]+ s \(stopped before it stored a latent space\)", line), line
