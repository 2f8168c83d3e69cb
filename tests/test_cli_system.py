"""``--system module:factory`` on the command line: rollout evaluates the user system, a closure
factory runs under the default process pool (and Ray), a forgotten ``--system`` is one line
saying what to pass, and evaluators leave the caller's environment alone."""
from __future__ import annotations

import json
import math
import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.constants import Phase
from latentune.errors import LatentuneError
from latentune.pipeline.store import RunStore
from latentune.threads import THREAD_VARS

from conftest import one_line_error

PLUGIN = textwrap.dedent('''
    import os
    import threading

    import numpy as np
    import latentune as lt


    def _space(dim):
        return lt.ParameterSpace([f"w{i}" for i in range(dim)], [-1.0] * dim, [1.0] * dim,
                                 manual=[0.5] * dim)


    def make(dim=4, shift=0.0):
        """The natural way to write a factory: fn is a closure (not picklable)."""
        def fn(x):
            omp = {v: os.environ.get(v) for v in %(vars)r}
            try:
                from threadpoolctl import threadpool_info
                blas = max([i["num_threads"] for i in threadpool_info()] or [1])
            except ImportError:
                blas = 1
            return lt.Outcome(float(np.sum((x - shift) ** 2)), failed=bool(x[0] > 0.95),
                              info={"pid": os.getpid(), "omp": omp, "blas_threads": blas})
        return lt.FunctionSystem(_space(dim), fn)


    class Locked:
        """A system holding a lock: no serializer ships it, the factory rebuilds it."""
        def __init__(self, dim=3):
            self.space = _space(dim)
            self.lock = threading.Lock()
        def evaluate(self, u):
            with self.lock:
                return float(np.sum(self.space.to_physical(u) ** 2)), False


    def locked(dim=3):
        return Locked(dim)
''' % {"vars": THREAD_VARS})


def _module_dir(tmp_path, monkeypatch, name: str, text: str):
    """A directory holding the module ``name`` (source ``text``), made the current directory
    and put on sys.path (as a user would run); yields it, then forgets the module."""
    d = tmp_path / f"{name}_dir"
    d.mkdir()
    (d / f"{name}.py").write_text(text)
    monkeypatch.chdir(d)
    monkeypatch.syspath_prepend(str(d))
    yield d
    sys.modules.pop(name, None)


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    """A directory holding ``closplant.py``, made the current directory (as a user would run)."""
    yield from _module_dir(tmp_path, monkeypatch, "closplant", PLUGIN)


# ---------------------------------------------------------------------------- rollout
def test_rollout_evaluates_the_user_system(run_cli, plugin_dir, tmp_path):
    code, out, err = run_cli("rollout", "--system", "closplant:make", "--system-arg", "shift=0.25",
                             "--json")
    assert code == 0, err
    res = json.loads(out)
    # the manual θ is 0.5 in each of 4 entries: cost 4 * 0.25**2, not an A1 path cost
    assert res["cost"] == pytest.approx(4 * 0.25 ** 2)
    assert res["system"] == "closplant:make" and res["system_args"] == {"shift": 0.25}
    assert res["fell"] is False and res["params"] == {f"w{i}": 0.5 for i in range(4)}
    assert "robot" not in res
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"w0": 0.99, "w1": 0.0, "w2": 0.0, "w3": 0.0}))
    code, out, err = run_cli("rollout", "--system", "closplant:make", "--params", params, "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["cost"] == pytest.approx(0.99 ** 2) and res["fell"] is True
    code, out, err = run_cli("rollout", "--system", "closplant:make")
    assert code == 0 and out.startswith("closplant:make: cost 1,"), (out, err)


def test_rollout_refuses_a_theta_file_of_another_system(run_cli, plugin_dir, tmp_path):
    """A θ file that records another system (here the ``locked`` factory's, names in common)
    is one line; the file of this system, or one without the record, runs."""
    params = tmp_path / "p.json"
    theirs = {"w0": 0.1, "w1": 0.2, "tuned_for": {"system": "closplant:locked"}}
    params.write_text(json.dumps(theirs))
    line = one_line_error(*run_cli("rollout", "--system", "closplant:make",
                                   "--params", params)[::2])
    assert line == (f"latentune: error: params file {params} holds θ tuned for the system "
                    "closplant:locked, not the system closplant:make (delete its 'tuned_for' "
                    "entry to use it anyway)")
    params.write_text(json.dumps({**theirs, "tuned_for": {"system": "closplant:make"}}))
    assert run_cli("rollout", "--system", "closplant:make", "--params", params)[0] == 0


def test_rollout_runs_the_best_of_a_python_study_of_the_same_system(run_cli, plugin_dir,
                                                                   tmp_path):
    """A study run from Python on ``closplant.make()`` (a FunctionSystem) recorded its class
    as what its θ were tuned for, and ``rollout --system closplant:make`` refused its
    best.json as another system's; such a file records nothing and runs."""
    import closplant

    with lt.Study(tmp_path / "s") as st:
        s = st.ask(1, system=closplant.make(), method="random")[0]
        st.tell(s.id, 1.0)
        path = st.best_params()
    assert "tuned_for" not in json.loads(path.read_text())
    code, out, err = run_cli("rollout", "--system", "closplant:make", "--params", path)
    assert code == 0, err


@pytest.mark.parametrize("bad, expect", [
    (["--seed", "3"], "--seed is for a built-in robot"),
    (["--gif", "x.gif"], "--gif is for a built-in robot"),
    (["--plot", "x.png"], "--plot is for a built-in robot"),
    (["--steps", "10"], "--system replaces --robot"),
    (["--robot", "a1"], "--system replaces --robot"),
    (["--system-arg", "nosuch=1"], "bad --system-arg"),
    (["--params", "missing.json"], "params file not found"),
], ids=lambda b: " ".join(b) if isinstance(b, list) else None)
def test_rollout_system_refuses_what_it_cannot_honour(run_cli, plugin_dir, bad, expect):
    assert expect in one_line_error(*run_cli("rollout", "--system", "closplant:make", *bad)[::2])


def test_rollout_system_arg_needs_system(run_cli):
    assert "--system-arg needs --system" in one_line_error(
        *run_cli("rollout", "--system-arg", "k=1")[::2])


# ---------------------------------------------------------------------------- closures
def test_a_closure_factory_runs_under_the_default_process_pool(run_cli, plugin_dir, tmp_path):
    out = tmp_path / "run"
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--out", out,
                           "--phase1-evals", "8")             # defaults: 2 workers, process
    assert code == 0, err
    with RunStore(out) as st:
        rows = st.rows(Phase.PHASE1)
    assert len(rows) == 8
    pids = {r.info["pid"] for r in rows if not r.info.get("reused")}
    assert pids and os.getpid() not in pids                  # evaluated in the workers
    assert all(r.info["blas_threads"] == 1 for r in rows if not r.info.get("reused"))
    assert all(set(r.info["omp"].values()) == {"1"} for r in rows if not r.info.get("reused"))


def test_an_unpicklable_api_system_is_one_line_naming_workers_1(tmp_path):
    """An API system that cannot be pickled is one line saying to run it in this process or
    to build it by ``load_system``; it said so in the command line's words ("--workers 1 (API:
    workers=1 or backend='serial'), or pass it as --system module:factory"), though only a
    Python caller meets it (a --system's system is rebuilt in each worker)."""
    space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    system = lt.FunctionSystem(space, lambda x: float(np.sum(x)))
    with pytest.raises(LatentuneError, match="workers=1") as info:
        lt.Study(tmp_path / "s", workers=2, backend="process").phase1(system, 6)
    assert "cannot be sent to worker processes" in str(info.value)
    assert str(info.value).endswith(
        "run it in this process with workers=1 (or backend='serial'), or build it with "
        "latentune.load_system('module:factory')"), info.value
    # the same system runs in this process
    res = lt.Study(tmp_path / "t", workers=1).phase1(system, 6)
    assert res.n == 6


def test_a_closure_factory_runs_on_ray(plugin_dir, ray_local):
    from latentune.pipeline.evaluators import RayEvaluator
    from latentune.system import load_system

    closure = load_system("closplant:make", {"shift": 0.1})
    locked = load_system("closplant:locked", {"dim": 3})       # Ray cannot serialize its lock
    X4, X3 = np.full((3, 4), 0.5), np.full((2, 3), 0.5)
    with RayEvaluator(1) as ev:                               # on conftest's local Ray
        y4 = ev.map(closure, X4)
        y3 = ev.map(locked, X3)
    np.testing.assert_allclose(y4, 4 * 0.1 ** 2)
    np.testing.assert_allclose(y3, 0.0)


# ---------------------------------------------------------------------------- a forgotten --system
@pytest.fixture
def plugin_run(run_cli, plugin_dir, tmp_path):
    out = tmp_path / "prun"
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--system-arg", "shift=0.25",
                           "--system-arg", "dim=3", "--out", out, "--phase1-evals", "6",
                           "--backend", "serial")
    assert code == 0, err
    return out


@pytest.mark.parametrize("cmd", ["tune", "phase1", "train-vae", "phase3"])
def test_forgetting_system_on_a_plugin_run_says_what_to_pass(run_cli, plugin_run, cmd):
    before = _rows(plugin_run)
    line = one_line_error(*run_cli(cmd, "--out", plugin_run, "--resume", "--backend", "serial",
                                   "--phase1-evals", "8")[::2])
    assert line == (f"latentune: error: {plugin_run} holds a run of the user system "
                    "closplant:make: pass --system closplant:make --system-arg shift=0.25 "
                    "--system-arg dim=3")
    assert _rows(plugin_run) == before


def _rows(run: Path) -> list[tuple]:
    with RunStore(run) as st:
        return [(r.phase, r.idx, r.cost, r.theta.tolist()) for ph in (0, 1, 3)
                for r in st.rows(ph)]


def test_passing_system_on_a_task_run_is_refused(run_cli, plugin_dir, tmp_path):
    out = tmp_path / "task"
    code, _, err = run_cli("phase1", "--steps", "100", "--out", out, "--phase1-evals", "2",
                           "--backend", "serial")
    assert code == 0, err
    line = one_line_error(*run_cli("phase1", "--system", "closplant:make", "--out", out,
                                   "--resume", "--backend", "serial", "--phase1-evals", "3")[::2])
    assert "holds a run of the built-in a1 trot task, not of --system closplant:make" in line


def test_a_python_api_run_is_refused_by_the_cli(run_cli, tmp_path):
    space = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])
    lt.Study(tmp_path / "api").phase1(lt.FunctionSystem(space, _sum), 4)
    line = one_line_error(*run_cli("phase1", "--out", tmp_path / "api", "--resume",
                                   "--phase1-evals", "5", "--backend", "serial")[::2])
    assert "holds a run of the Python system latentune.system.FunctionSystem" in line
    assert "continue it with latentune.Study" in line


def _sum(x: np.ndarray) -> float:
    return float(np.sum(x))


# ---------------------------------------------------------------------------- environment
def test_evaluators_leave_the_callers_environment(plugin_dir, monkeypatch):
    from latentune.pipeline.evaluators import make_evaluator
    from latentune.system import load_system

    for v in THREAD_VARS:
        monkeypatch.delenv(v, raising=False)
    before = dict(os.environ)
    system = load_system("closplant:make")
    for backend in ("serial", "process"):
        with make_evaluator(backend, 2) as ev:
            outs = [r for _, r in ev.imap(system, np.full((2, 4), 0.5))]
        assert dict(os.environ) == before, backend
    assert all(set(o.info["omp"].values()) == {"1"} for o in outs)   # the workers' own
    assert all(o.info["pid"] != os.getpid() for o in outs)


# ---------------------------------------------------------------------------- --system-arg values
def _stands_at_the_manual_only(x: np.ndarray) -> float:
    if not np.allclose(x, [0.5, 0.5]):
        raise RuntimeError("solver diverged")
    return 1.0


def test_a_phase_stopped_after_one_stored_evaluation_says_it_in_the_singular(tmp_path):
    """A phase stopped by a trial that raised after one evaluation was stored said "(phase 1;
    1 evaluations are stored; fix the system and resume)"; it now says "1 evaluation is
    stored" (and "2 evaluations are stored" where there are two)."""
    from latentune.system import EvaluationError

    space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1], manual=[0.5, 0.5])
    with pytest.raises(EvaluationError, match=r"\(phase 1; 1 evaluation is stored; fix the "
                                              r"system and resume\)$"):
        lt.Study(tmp_path / "r").phase1(lt.FunctionSystem(space, _stands_at_the_manual_only), 4)


def test_a_system_whose_space_property_raises_is_one_line(run_cli, tmp_path, monkeypatch,
                                                          error_line):
    """``--system mod:Make`` whose ``space`` is a property that raised (a simulator not started)
    ended ``latentune phase1`` and ``ask`` with the property's traceback; it is one line naming
    `space` and the error, exit status 2, and no run directory (the API: a SystemSpecError)."""
    from latentune.errors import SystemSpecError

    made = _module_dir(tmp_path, monkeypatch, "lazyplant", """
class Make:
    @property
    def space(self):
        raise RuntimeError("simulator not started")

    def evaluate(self, theta):
        return 1.0
""")
    next(made)
    for cmd in (["phase1", "--out", tmp_path / "r", "--phase1-evals", "3"],
                ["ask", tmp_path / "r"]):
        line = error_line(*run_cli(*cmd, "--system", "lazyplant:Make", "--quiet")[::2])
        assert "reading its `space` or `evaluate` raised RuntimeError: simulator not started" \
            in line, line
    assert not (tmp_path / "r").exists()
    import lazyplant

    with pytest.raises(SystemSpecError, match="raised RuntimeError: simulator not started"):
        lt.Study(tmp_path / "a").phase1(lazyplant.Make(), 3)
    next(made, None)                    # forget the module


def test_a_frozen_dataclass_or_a_failing_repr_system_runs_and_resumes(run_cli, tmp_path,
                                                                        monkeypatch):
    """``--system mod:Frozen`` (a frozen dataclass) ran, but its resume was refused: "holds a run
    of the Python system mod.Frozen (made through the API); the command line cannot rebuild
    it" (the --system record could not be set on a frozen object); a system whose __repr__
    raised ended the command with its traceback. Both run and resume."""
    made = _module_dir(tmp_path, monkeypatch, "oddplant", """
from dataclasses import dataclass

import numpy as np
import latentune as lt

SPACE = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1], manual=[0.5, 0.5])


@dataclass(frozen=True)
class Frozen:
    scale: float = 1.0

    @property
    def space(self):
        return SPACE

    def evaluate(self, theta):
        return float(np.sum(theta ** 2))


class NoRepr:
    space = SPACE

    def evaluate(self, theta):
        return float(np.sum(theta ** 2))

    def __repr__(self):
        raise RuntimeError("no repr")
""")
    next(made)
    for name in ("Frozen", "NoRepr"):
        run = tmp_path / name
        for n, more in ((3, []), (5, ["--resume"])):
            code, out, err = run_cli("phase1", "--system", f"oddplant:{name}", "--out", run,
                                     "--phase1-evals", n, "--backend", "serial", "--workers", 1,
                                     "--quiet", *more)
            assert code == 0, err
        assert RunStore(run).count(Phase.PHASE1) == 5
        assert lt.Study(run).config()["system"]["target"] == f"oddplant:{name}"
    next(made, None)


def test_system_arg_exponent_values_are_floats():
    from latentune.system import parse_system_args

    got = parse_system_args(["a=1e9", "b=1e-3", "c=1.0e9", "d=-2.5E+3", "e=2.5", "f=10",
                             "g=true", "h=null", "i=abc", "j=", "k=1.0e+9", "l=[1, 2]"])
    assert got == {"a": 1e9, "b": 1e-3, "c": 1e9, "d": -2500.0, "e": 2.5, "f": 10, "g": True,
                   "h": None, "i": "abc", "j": "", "k": 1e9, "l": [1, 2]}
    assert all(type(got[k]) is float for k in "abcdek") and type(got["f"]) is int


def test_a_study_without_trials_takes_another_system(run_cli, plugin_dir, tmp_path):
    """A first run that failed before storing a trial leaves a study bound to its system: the
    corrected run is accepted (and recorded); once a trial is stored, another is refused."""
    out = tmp_path / "r"
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--system-arg", "shift=abc",
                           "--out", out, "--phase1-evals", "4", "--backend", "serial")
    assert code != 0 and _rows(out) == []
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--system-arg", "shift=1e-3",
                           "--system-arg", "dim=3", "--out", out, "--phase1-evals", "4",
                           "--backend", "serial", "--resume")
    assert code == 0, err
    with RunStore(out) as st:
        assert st.get_meta("config")["system"]["args"] == {"shift": 1e-3, "dim": 3}
        assert len(st.rows(Phase.PHASE1)) == 4 and len(st.rows(Phase.PHASE1)[0].theta) == 3
    line = one_line_error(*run_cli("phase1", "--system", "closplant:make", "--system-arg",
                                   "shift=0.5", "--out", out, "--phase1-evals", "5",
                                   "--backend", "serial", "--resume")[::2])
    assert "holds a run of another system (args.dim" in line


def test_a_study_without_trials_forgets_the_old_systems_asked_batch(tmp_path):
    """A batch a failed first run asked (recorded to be evaluated on resume; here written by
    hand, as phase 1 stores the manual θ first) is in the old system's space: binding another
    system drops it."""
    def boom(x):
        raise RuntimeError("not wired yet")

    sp2 = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1])
    sp3 = lt.ParameterSpace(["a", "b", "c"], [0, 0, 0], [1, 1, 1])
    with pytest.raises(LatentuneError, match="not wired yet"):
        lt.Study(tmp_path / "s", workers=1).phase1(lt.FunctionSystem(sp2, boom), 6, start=None)
    with RunStore(tmp_path / "s") as st:
        assert not st.rows(Phase.MANUAL) and not st.rows(Phase.PHASE1)
        st.set_meta("asked_batch_1", {"n0": 0, "u": [[0.1, 0.2]], "tags": [0], "z": None,
                                      "theta": [[0.1, 0.2]]})
    s = lt.Study(tmp_path / "s", workers=1)
    res = s.phase1(lt.FunctionSystem(sp3, _sum), 6, start=None)
    assert res.n == 6 and all(len(r.theta) == 3 for r in s.store.rows(Phase.PHASE1))
    assert s.config()["space"] == sp3.to_dict()


def test_a_plugin_run_recorded_with_a_string_exponent_still_resumes(run_cli, plugin_run):
    """A run stored when ``--system-arg shift=2.5e-1`` reached the factory as a string resumes
    with the same flag (now a float), and its record is kept as it is."""
    with RunStore(plugin_run) as st:
        cfg = st.get_meta("config")
        cfg["system"]["args"]["shift"] = "2.5e-1"
        st.set_meta("config", cfg)
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--system-arg", "shift=2.5e-1",
                           "--system-arg", "dim=3", "--out", plugin_run, "--resume",
                           "--phase1-evals", "8", "--backend", "serial")
    assert code == 0, err
    with RunStore(plugin_run) as st:
        assert st.get_meta("config")["system"]["args"]["shift"] == "2.5e-1"
        assert len(st.rows(Phase.PHASE1)) == 8


SCALED = textwrap.dedent('''
    import closplant

    def make(scales=(), dim=3, strict=True):
        if strict and not all(isinstance(s, float) for s in scales):
            raise TypeError(f"scales={scales!r}: not all numbers")
        return closplant.make(dim)
''')


def test_system_arg_numbers_inside_a_list_are_floats(run_cli, plugin_dir, tmp_path):
    """``--system-arg 'scales=[1e9, 2.5e-1]'`` gave the factory the strings '1e9' and
    '2.5e-1' (YAML 1.1), though ``scales=1e9`` alone is a float: a number with a point or an
    exponent is a float inside a list or mapping too, and is recorded so."""
    from latentune.system import parse_system_args

    assert parse_system_args(["k=[1e9, 2, -.5, 1.0e+3, abc]", "m={a: 1e-3, b: [2E2]}"]) == {
        "k": [1e9, 2, -0.5, 1e3, "abc"], "m": {"a": 1e-3, "b": [200.0]}}
    (plugin_dir / "scaled.py").write_text(SCALED)
    run = tmp_path / "scaled"
    code, _, err = run_cli("phase1", "--system", "scaled:make", "--system-arg",
                           "scales=[1e9, 2.5e-1]", "--out", run, "--phase1-evals", 3,
                           "--backend", "serial", "--quiet")
    assert code == 0, err
    assert lt.Study(run).config()["system"]["args"] == {"scales": [1e9, 0.25]}
    sys.modules.pop("scaled", None)


def test_a_run_recorded_with_string_numbers_in_a_list_still_resumes(run_cli, plugin_dir,
                                                                    tmp_path):
    """A run stored when ``--system-arg 'scales=[1e9, 2.5e-1]'`` reached the factory as
    strings resumes with the same flag (now floats): the record is compared as --system-arg
    reads it now, and kept as it is; other numbers are still another system."""
    (plugin_dir / "scaled.py").write_text(SCALED)
    run = tmp_path / "old"
    flags = ("--system", "scaled:make", "--system-arg", "strict=false", "--system-arg",
             "scales=[1e9, 2.5e-1]", "--out", run, "--backend", "serial", "--quiet")
    assert run_cli("phase1", *flags, "--phase1-evals", 3)[0] == 0
    old = ["1e9", "2.5e-1"]
    with RunStore(run) as st:
        cfg = st.get_meta("config")
        cfg["system"]["args"]["scales"] = old
        st.set_meta("config", cfg)
    code, _, err = run_cli("phase1", *flags, "--phase1-evals", 5, "--resume")
    assert code == 0, err
    with RunStore(run) as st:
        assert st.get_meta("config")["system"]["args"]["scales"] == old
        assert st.count(Phase.PHASE1) == 5
    line = one_line_error(*run_cli("phase1", *flags[:5], "scales=[1e9, 3]", *flags[6:],
                                   "--phase1-evals", 6, "--resume")[::2])
    assert "holds a run of another system (args.scales" in line, line
    sys.modules.pop("scaled", None)


def test_a_resume_keeps_the_stored_method_and_refuses_another(run_cli, plugin_dir, tmp_path):
    """--method is not repeated on --resume: the stored method goes on (phase 1 and the plain
    phase 3); another one given is refused naming both. The parser's default was turbo, so a
    resume without --method of a cma run was refused."""
    out, p3 = tmp_path / "src", tmp_path / "p3"
    common = ("--system", "closplant:make", "--system-arg", "dim=3", "--backend", "serial")
    assert run_cli("phase1", *common, "--out", out, "--phase1-evals", "6", "--method",
                   "random")[0] == 0
    code, _, err = run_cli("phase1", *common, "--out", out, "--phase1-evals", "9", "--resume")
    assert code == 0, err
    with RunStore(out) as st:
        assert st.count(Phase.PHASE1) == 9
    assert lt.Study(out).config()["phase1"]["method"] == "random"
    code, _, err = run_cli("phase1", *common, "--out", out, "--phase1-evals", "10", "--resume",
                           "--method", "turbo")
    line = one_line_error(code, err)
    assert "phase 1 was run with --method random (stored), not --method turbo" in line
    assert run_cli("train-vae", *common[:-2], "--out", out, "--vae-epochs", "5")[0] == 0
    assert run_cli("phase3", *common, "--vae", out, "--out", p3, "--strategy", "plain",
                   "--method", "cma", "--phase3-evals", "3")[0] == 0
    code, _, err = run_cli("phase3", *common, "--vae", out, "--out", p3, "--resume",
                           "--phase3-evals", "5")
    assert code == 0, err
    with RunStore(p3) as st:
        assert st.count(Phase.PHASE3) == 5
    assert lt.Study(p3).config()["phase3"]["method"] == "cma"


def test_load_system_refuses_arguments_that_are_not_a_dict():
    """``load_system(target, [1])`` raised dict()'s TypeError."""
    from latentune.errors import SystemSpecError
    from latentune.system import load_system

    with pytest.raises(SystemSpecError, match="the factory's arguments must be a dict, got \\[1\\]"):
        load_system("examples.toy_plant:make_system", [1])


CLASS_PLUGIN = textwrap.dedent('''
    import numpy as np
    import latentune as lt


    class Plant:
        """A system class: the class itself is the natural factory."""
        def __init__(self, dim=3, shift=0.0):
            self.space = lt.ParameterSpace([f"w{i}" for i in range(dim)], [-1.0] * dim,
                                           [1.0] * dim)
            self.shift = shift
        def evaluate(self, u):
            return float(np.sum((self.space.to_physical(u) - self.shift) ** 2))


    class WithSpace(Plant):
        """A class with a class-level space: a class passes the protocol's attribute test."""
        space = lt.ParameterSpace(["a"], [0.0], [1.0])
        def __init__(self):
            pass


    def returns_int():
        return 42
''')


@pytest.fixture
def class_plugin(tmp_path, monkeypatch):
    """A directory holding ``classplant.py``, made the current directory."""
    yield from _module_dir(tmp_path, monkeypatch, "classplant", CLASS_PLUGIN)


def test_a_system_class_is_a_factory(class_plugin):
    """``--system mod:Plant`` said 'type is not a latentune system', and with ``--system-arg``
    'is not callable; it takes no --system-arg': a class is called like any factory."""
    from latentune.system import load_system

    s = load_system("classplant:Plant")
    assert type(s).__name__ == "Plant" and s.space.dim == 3
    s = load_system("classplant:Plant", {"dim": 2, "shift": 0.5})
    assert s.space.dim == 2 and s.shift == 0.5
    assert type(load_system("classplant:WithSpace")).__name__ == "WithSpace"


def test_a_factory_that_returns_no_system_names_the_factory_and_what_it_gave(class_plugin):
    """A factory returning 42 said only 'int is not a latentune system'."""
    from latentune.errors import SystemSpecError
    from latentune.system import load_system

    with pytest.raises(SystemSpecError) as e:
        load_system("classplant:returns_int")
    msg = str(e.value)
    assert "load_system('classplant:returns_int')" in msg and "returned int 42" in msg
    assert "not a latentune system" in msg and "\n" not in msg


def test_load_system_names_the_system_in_its_callers_words(class_plugin, tmp_path):
    """``lt.load_system`` told Python callers about ``--system`` and ``--system-arg``, flags
    they never gave; a worker rebuilding a system for the command line and for Python alike
    used them. A Python caller reads ``load_system('T')`` and ``args``; the command line
    (``command_line_words``, as ``latentune`` runs every command) ``--system T`` and
    ``--system-arg``; a worker says what its caller would."""
    from latentune.errors import SystemSpecError
    from latentune.pipeline.evaluators import PluginRef
    from latentune.system import load_system
    from latentune.wording import command_line_words

    cases = [(("nocolon",), "load_system: the target must be module:factory, got 'nocolon'",
              "--system must be module:factory, got 'nocolon'"),
             (("classplant:returns_int", {"nope": 1}),
              "load_system('classplant:returns_int'): bad args (",
              "--system classplant:returns_int: bad --system-arg ("),
             (("classplant:nosuch",), "load_system('classplant:nosuch'): classplant has no "
              "attribute 'nosuch'", "--system classplant:nosuch: classplant has no attribute")]
    for args, python, cli in cases:
        with pytest.raises(SystemSpecError) as e:
            load_system(*args)
        assert str(e.value).startswith(python) and "--system" not in str(e.value), str(e.value)
        with command_line_words(), pytest.raises(SystemSpecError) as e:
            load_system(*args)
        assert str(e.value).startswith(cli), str(e.value)
    ref = PluginRef.of(load_system("classplant:Plant"))      # a worker's rebuild, and its
    assert ref.name() == "load_system('classplant:Plant')"    # failure, in Python's words
    with command_line_words():
        ref = PluginRef.of(load_system("classplant:Plant"))
    assert ref.name() == "--system classplant:Plant"         # ... or the command line's
    bad = PluginRef("classplant:nosuch", command_line=ref.command_line)
    with pytest.raises(SystemSpecError, match=r"^--system classplant:nosuch: classplant has no"):
        bad.build()                                           # in a worker: Python's words


def test_a_class_passed_for_a_system_is_refused_before_a_trial(class_plugin, tmp_path):
    """``Study.phase1(WithSpace)`` (the class, not an instance) passed the protocol check and
    stopped at the first trial with 'type.evaluate raised TypeError: … missing 1 required
    positional argument'."""
    import classplant
    from latentune.errors import SystemSpecError
    from latentune.system import check_system

    with pytest.raises(SystemSpecError, match=r"WithSpace is a class, not a system: pass an "
                                              r"instance, WithSpace\(\.\.\.\)"):
        check_system(classplant.WithSpace)
    st = lt.Study(tmp_path / "r")
    with pytest.raises(SystemSpecError, match="is a class, not a system"):
        st.phase1(classplant.WithSpace, budget=2)
    assert not (tmp_path / "r" / "run.db").exists() or st.trials() == []


def test_a_trial_that_raises_or_returns_nan_names_its_theta(tmp_path):
    """'Crashy.evaluate raised RuntimeError: solver diverged (phase 1; 9 evaluations are
    stored; …)' did not say at which θ, the one thing needed to reproduce the crash (the θ is
    not stored): the line now names it in physical units."""
    from latentune.system import EvaluationError, evaluate

    space = lt.ParameterSpace(["kp", "ki"], [1e-3, 0.0], [1e3, 2.0], log=[True, False])

    class Crashy:
        def __init__(self, nan: bool) -> None:
            self.space, self.nan = space, nan

        def evaluate(self, u):
            if self.nan:
                return float("nan")
            raise RuntimeError("solver diverged")

    u = space.to_unit(np.array([10.0, 0.5]))
    with pytest.raises(EvaluationError, match=r"raised RuntimeError: solver diverged at θ "
                                              r"kp=10, ki=0\.5$"):
        evaluate(Crashy(False), u)
    with pytest.raises(EvaluationError, match=r"non-finite cost \(nan\); .*penalty at θ kp=10, ki=0\.5$"):
        evaluate(Crashy(True), u)
    with pytest.raises(EvaluationError, match=r"solver diverged at θ kp=1, ki=1"):  # manual θ
        lt.Study(tmp_path / "r").phase1(Crashy(False), budget=3)


SLOTTED = """
import threading

import numpy as np
import latentune as lt


class Slotted:
    __slots__ = ("space", "scale", "lock")

    def __init__(self, scale=1.0):
        self.space = lt.ParameterSpace(["a", "b"], [0, 0], [1, 1], manual=[0.5, 0.5])
        self.scale = scale
        self.lock = threading.Lock()            # no pickle: the workers rebuild it

    def evaluate(self, theta):
        with self.lock:
            return float(self.scale * np.sum(theta ** 2))
"""


def test_a_slotted_system_class_resumes_from_the_cli(run_cli, tmp_path, monkeypatch):
    """``--system mod:Slotted`` (a class with ``__slots__``, which cannot take the --system
    record) ran, but its resume was refused: "holds a run of the Python system mod.Slotted
    (made through the API); the command line cannot rebuild it". It resumes, on the process
    pool too (its workers rebuild it from the factory: it holds a lock, which no pickle
    ships)."""
    made = _module_dir(tmp_path, monkeypatch, "slotplant", SLOTTED)
    next(made)
    run = tmp_path / "slotted"
    for n, more in ((3, ["--backend", "serial", "--workers", 1]),
                    (5, ["--resume", "--backend", "serial", "--workers", 1]),
                    (7, ["--resume", "--workers", 2])):
        code, out, err = run_cli("phase1", "--system", "slotplant:Slotted", "--out", run,
                                 "--phase1-evals", n, "--quiet", *more)
        assert code == 0, err
    assert RunStore(run).count(Phase.PHASE1) == 7
    assert lt.Study(run).config()["system"]["target"] == "slotplant:Slotted"
    line = one_line_error(*run_cli("phase1", "--system", "slotplant:Slotted", "--system-arg",
                                   "scale=2.0", "--out", run, "--phase1-evals", 8, "--resume",
                                   "--backend", "serial")[::2])
    assert "holds a run of another system (args.scale: stored 1.0, given 2.0)" in line, line
    next(made, None)


def test_a_system_arg_at_its_default_value_is_the_same_system(run_cli, plugin_dir, tmp_path):
    """A run started without ``--system-arg dim=4`` (closplant:make's default) was refused on a
    resume with it ("holds a run of another system (args.dim: stored None, given 4)"), and the
    other way round: a system is its resolved arguments. Another value is refused naming the
    values the factory ran with (its default included)."""
    common = ("--system", "closplant:make", "--backend", "serial", "--quiet")
    runs = tmp_path / "without", tmp_path / "with"
    for run, first, then in ((runs[0], [], ["dim=4", "shift=0.0"]),
                             (runs[1], ["dim=4", "shift=0"], [])):
        for n, pairs, more in ((3, first, []), (5, then, ["--resume"])):
            flags = [x for p in pairs for x in ("--system-arg", p)]
            code, _, err = run_cli("phase1", *common, *flags, "--out", run, "--phase1-evals", n,
                                   *more)
            assert code == 0, err
        assert RunStore(run).count(Phase.PHASE1) == 5
    with RunStore(runs[0]) as st:       # a record written before defaults were recorded
        cfg = st.get_meta("config")
        assert cfg["system"].pop("defaults") == {"dim": 4, "shift": 0.0}
        st.set_meta("config", cfg)
    code, _, err = run_cli("phase1", *common, "--system-arg", "dim=4", "--out", runs[0],
                           "--phase1-evals", 6, "--resume")
    assert code == 0, err
    line = one_line_error(*run_cli("phase1", *common, "--system-arg", "shift=0.5", "--out",
                                   runs[0], "--phase1-evals", 7, "--resume")[::2])
    assert "holds a run of another system (args.shift: stored 0.0, given 0.5)" in line, line
    line = one_line_error(*run_cli("phase1", *common, "--system-arg", "shift=0.5", "--out",
                                   runs[1], "--phase1-evals", 6, "--resume")[::2])
    assert "holds a run of another system (args.shift: stored 0, given 0.5)" in line, line
    # the refusal says what to pass to go on (it named the difference and nothing to do)
    assert line.endswith("given 0.5): pass --system closplant:make --system-arg dim=4 "
                         "--system-arg shift=0 to go on with it, or use another directory"), line
    from latentune.errors import StoreError        # in Python's words from Python
    from latentune.system import load_system

    with pytest.raises(StoreError) as e:
        lt.Study(runs[1]).phase1(load_system("closplant:make", {"shift": 0.5}), 7)
    assert str(e.value).endswith("given 0.5): pass the system of load_system('closplant:make', "
                                 "{'dim': 4, 'shift': 0}) to go on with it, or use another "
                                 "directory"), str(e.value)


def test_resume_refusals_name_the_flag_and_both_values_alike(run_cli, plugin_dir, tmp_path):
    """A resume with another value was refused in several forms: "runs with --budget = 5
    (stored), not 3", "phase1 was run with method = 'random', not 'turbo'", "was run with
    max-fall-prob = None, not 0.2", "ask/tell runs phase 1 (stored), not 3", "runs with seed 0,
    not 5", beside "runs with --fall-budget 0.2 (stored), not --fall-budget 0.3". Each now
    names the flag with the stored and the given value in that one form."""
    system = ("--system", "closplant:make", "--system-arg", "dim=3")
    a, p = tmp_path / "a", tmp_path / "p"
    code, _, err = run_cli("ask", a, *system, "--budget", "5", "--max-fall-prob", "0.4",
                           "--json")
    assert code == 0, err
    code, _, err = run_cli("phase1", *system, "--out", p, "--phase1-evals", "6", "--backend",
                           "serial", "--method", "random", "--batch-size", "2", "--quiet")
    assert code == 0, err
    cases = [
        (("ask", a, "--budget", "3"), "a: phase 1 runs with --budget 5 (stored), not --budget 3"),
        (("ask", a, "--method", "cma"), "runs with --method turbo (stored), not --method cma"),
        (("ask", a, "--max-fall-prob", "0.3"),
         "runs with --max-fall-prob 0.4 (stored), not --max-fall-prob 0.3"),
        (("ask", a, "--start", "scratch"),
         "runs with --start manual (stored), not --start scratch"),
        (("ask", a, "--phase", "3"), "a: ask/tell runs with --phase 1 (stored), not --phase 3; "
                                     f"{a} holds no latent space yet"),
        (("ask", a, "--seed", "5"), "a: ask/tell runs with --seed 0 (stored), not --seed 5"),
        (("phase1", "--out", p, "--method", "turbo"),
         "p: phase 1 was run with --method random (stored), not --method turbo"),
        (("phase1", "--out", p, "--batch-size", "3"),
         "p: phase 1 was run with --batch-size 2 (stored), not --batch-size 3"),
        (("phase1", "--out", p, "--max-fall-prob", "0.2"),
         "p: phase 1 was run with no --max-fall-prob (stored), not --max-fall-prob 0.2"),
        (("phase1", "--out", p, "--seed", "4"),
         "p: the study was run with --seed 0 (stored), not --seed 4 (leave --seed out"),
    ]
    for (cmd, *argv), expect in cases:
        more = ["--json"] if cmd == "ask" else ["--resume", "--phase1-evals", "8", "--backend",
                                                 "serial"]
        line = one_line_error(*run_cli(cmd, *argv, *system, *more)[::2])
        assert expect in line, (argv, line)


def test_a_system_arg_yaml_reads_as_a_date_resumes(run_cli, plugin_dir, tmp_path):
    """``--system-arg when=2020-01-01`` (YAML reads a date) ran, but its resume with the same
    flags was refused: "holds a run of another system (args.when: stored '2020-01-01', given
    datetime.date(2020, 1, 1))": the store keeps the text, the check compared the date. A
    system is compared as the store keeps it."""
    (plugin_dir / "dated.py").write_text(textwrap.dedent('''
        import closplant

        def make(when=None, dim=3):
            return closplant.make(dim)
    '''))
    run = tmp_path / "dated"
    for n, more in ((3, []), (5, ["--resume"])):
        code, _, err = run_cli("phase1", "--system", "dated:make", "--system-arg",
                               "when=2020-01-01", "--out", run, "--phase1-evals", n,
                               "--backend", "serial", "--quiet", *more)
        assert code == 0, err
    assert RunStore(run).count(Phase.PHASE1) == 5
    line = one_line_error(*run_cli("phase1", "--system", "dated:make", "--system-arg",
                                   "when=2020-01-02", "--out", run, "--phase1-evals", 6,
                                   "--backend", "serial", "--resume")[::2])
    assert "(args.when: stored '2020-01-01', given '2020-01-02')" in line, line
    sys.modules.pop("dated", None)


def test_a_system_arg_date_reaches_the_factory_as_its_text(run_cli, plugin_dir, tmp_path):
    """``--system-arg when=2020-01-01`` reached the factory as ``datetime.date(2020, 1, 1)``
    (YAML's timestamp), though a value other than a number, bool, null or list is a string:
    it is the text ``'2020-01-01'`` (also inside a list), stored so, and a resume agrees."""
    from latentune.system import parse_system_args

    assert parse_system_args(["when=2020-01-01", "at=2001-12-14 21:59:43.10 -5",
                              "days=[2020-01-01, 2020-01-02]"]) == {
        "when": "2020-01-01", "at": "2001-12-14 21:59:43.10 -5",
        "days": ["2020-01-01", "2020-01-02"]}
    (plugin_dir / "datetext.py").write_text(textwrap.dedent('''
        import closplant

        def make(when=None, days=(), dim=3):
            if not isinstance(when, str) or not all(isinstance(d, str) for d in days):
                raise TypeError(f"when={when!r}, days={days!r}: not text")
            return closplant.make(dim)
    '''))
    run = tmp_path / "datetext"
    for n, more in ((3, []), (5, ["--resume"])):
        code, _, err = run_cli("phase1", "--system", "datetext:make", "--system-arg",
                               "when=2020-01-01", "--system-arg", "days=[2020-01-01]",
                               "--out", run, "--phase1-evals", n, "--backend", "serial",
                               "--quiet", *more)
        assert code == 0, err
    assert RunStore(run).count(Phase.PHASE1) == 5
    assert lt.Study(run).config()["system"]["args"] == {"when": "2020-01-01",
                                                        "days": ["2020-01-01"]}
    sys.modules.pop("datetext", None)


def test_a_non_finite_float_in_a_list_system_arg_is_shown_so_it_reads_back(run_cli, plugin_dir,
                                                                           tmp_path):
    """A resume without --system of a run made with ``--system-arg 'tags=[.nan, .inf]'`` said
    ``--system-arg 'tags=[NaN, Infinity]'`` (JSON), which reads back as two strings: another
    system. The values inside a list are shown as --system-arg reads them (``.nan``, ``.inf``,
    a float in exponent form with a point), and the line's flags resume the run."""
    import shlex

    from latentune.system import parse_system_args, system_arg_text

    value = [math.nan, math.inf, -math.inf, 1e20, 2.5, "x", [1, math.nan]]
    back = parse_system_args([system_arg_text("tags", value)])["tags"]
    assert json.dumps(back) == json.dumps(value), back          # NaN-aware equality
    (plugin_dir / "nantags.py").write_text(textwrap.dedent('''
        import math

        import closplant

        def make(tags=(), dim=3):
            if not (math.isnan(tags[0]) and tags[1] == math.inf):
                raise TypeError(f"tags={tags!r}")
            return closplant.make(dim)
    '''))
    run = tmp_path / "nantags"
    code, _, err = run_cli("phase1", "--system", "nantags:make", "--system-arg",
                           "tags=[.nan, .inf]", "--out", run, "--phase1-evals", 3,
                           "--backend", "serial", "--quiet")
    assert code == 0, err
    line = one_line_error(*run_cli("phase1", "--out", run, "--phase1-evals", 4, "--backend",
                                   "serial", "--resume")[::2])
    flags = shlex.split(line.split(": pass ", 1)[1])
    assert flags == ["--system", "nantags:make", "--system-arg", "tags=[.nan, .inf]"], line
    code, _, err = run_cli("phase1", *flags, "--out", run, "--phase1-evals", 4, "--backend",
                           "serial", "--quiet", "--resume")
    assert code == 0, err
    sys.modules.pop("nantags", None)


def test_the_system_flags_a_forgotten_system_line_gives_rebuild_it(run_cli, plugin_dir, tmp_path):
    """A resume without --system says what to pass; for ``--system-arg when=.nan`` it said
    ``--system-arg when=NaN`` (YAML reads the text 'NaN': another system), for ``'tags=[1, 2]'``
    an unquoted ``tags=[1, 2]`` (two shell words) and for ``'tag="true"'`` ``tag=true`` (a
    bool). The line's flags, as a shell reads them, now resume the run."""
    import shlex

    (plugin_dir / "tagged.py").write_text(textwrap.dedent('''
        import closplant

        def make(when=None, tags=(), tag="", dim=3):
            return closplant.make(dim)
    '''))
    run = tmp_path / "tagged"
    given = ["when=.nan", "tags=[1, 2]", 'tag="true"']
    code, _, err = run_cli("phase1", "--system", "tagged:make",
                           *[x for g in given for x in ("--system-arg", g)], "--out", run,
                           "--phase1-evals", 3, "--backend", "serial", "--quiet")
    assert code == 0, err
    line = one_line_error(*run_cli("phase1", "--out", run, "--phase1-evals", 4, "--backend",
                                   "serial", "--resume")[::2])
    flags = shlex.split(line.split(": pass ", 1)[1])
    assert flags[:2] == ["--system", "tagged:make"], line
    assert flags[2:] == [x for g in ["when=.nan", "tags=[1, 2]", "tag='true'"]
                         for x in ("--system-arg", g)], line
    code, _, err = run_cli("phase1", *flags, "--out", run, "--phase1-evals", 4, "--backend",
                           "serial", "--quiet", "--resume")
    assert code == 0, err
    assert RunStore(run).count(Phase.PHASE1) == 4
    sys.modules.pop("tagged", None)


def test_a_fall_prior_is_its_directory_not_its_spelling(run_cli, plugin_dir, tmp_path,
                                                        monkeypatch):
    """``--fall-prior src`` resumed with ``--fall-prior ./src`` (or its absolute path) was
    refused: "phase 1 was run with --fall-prior src (stored), not --fall-prior ./src"; and the
    text was recorded as given, so a resume from another directory read another prior. The
    directory is recorded and compared as itself."""
    system = ("--system", "closplant:make", "--system-arg", "dim=3", "--backend", "serial",
              "--quiet")
    src = tmp_path / "src"
    assert run_cli("phase1", *system, "--out", src, "--phase1-evals", 4)[0] == 0
    monkeypatch.chdir(tmp_path)
    run, fall = tmp_path / "run", ("--max-fall-prob", "0.5")
    for n, prior, more in ((3, "src", []), (4, "./src", ["--resume"]),
                           (5, f"{src}/", ["--resume"])):
        code, _, err = run_cli("phase1", *system, "--out", run, "--phase1-evals", n, *fall,
                               "--fall-prior", prior, *more)
        assert code == 0, err
    assert lt.Study(run).config()["phase1"]["fall_prior"] == str(src)
    a = tmp_path / "a"
    assert run_cli("ask", a, *system[:4], *fall, "--fall-prior", "src", "--json")[0] == 0
    code, _, err = run_cli("ask", a, "--fall-prior", f"{src}", "--json")
    assert code == 0, err
    line = one_line_error(*run_cli("phase1", *system, "--out", run, "--phase1-evals", 6, *fall,
                                   "--fall-prior", run, "--resume")[::2])
    assert f"was run with --fall-prior {src} (stored), not --fall-prior {run}" in line, line


@pytest.mark.parametrize("cmd", ["phase1", "tune"])
def test_a_phase1_resume_keeps_its_stored_fall_options(run_cli, plugin_dir, tmp_path, cmd):
    """A phase 1 run with --max-fall-prob (and --fall-prior): ``phase1 --resume`` (or ``tune
    --resume``) without them was refused ("phase 1 was run with --max-fall-prob 0.5 (stored),
    not no --max-fall-prob"), where phase 3 and ask keep the stored ones; it resumes with
    them. Another value is still refused."""
    system = ("--system", "closplant:make", "--system-arg", "dim=3", "--backend", "serial",
              "--quiet")
    src, run = tmp_path / "src", tmp_path / "run"
    assert run_cli("phase1", *system, "--out", src, "--phase1-evals", 4)[0] == 0
    code, _, err = run_cli("phase1", *system, "--out", run, "--phase1-evals", 4,
                           "--max-fall-prob", "0.5", "--fall-prior", src)
    assert code == 0, err
    more = ["--phase3-evals", "2", "--vae-epochs", "5", "--latent-dim", "2"] \
        if cmd == "tune" else []
    code, _, err = run_cli(cmd, *system, "--out", run, "--phase1-evals", 6, "--resume", *more)
    assert code == 0, err
    assert RunStore(run).count(Phase.PHASE1) == 6
    cfg = lt.Study(run).config()["phase1"]
    assert cfg["max_fall_prob"] == 0.5 and cfg["fall_prior"] == str(src)
    line = one_line_error(*run_cli("phase1", *system, "--out", run, "--phase1-evals", 7,
                                   "--resume", "--max-fall-prob", "0.4")[::2])
    assert "--max-fall-prob 0.5 (stored), not --max-fall-prob 0.4" in line, line


def test_a_handover_refusal_shows_the_flags_form(run_cli, plugin_dir, tmp_path):
    """A plain phase 3 run with ``--handover patience=2`` resumed with ``--handover`` was
    refused showing Python dicts ("--handover {'patience': 2, 'tol': 0.01, 'length': 0.2}
    (stored), not --handover {'patience': 20, …}"); it shows the values as --handover takes
    them."""
    system = ("--system", "closplant:make", "--system-arg", "dim=3")
    src, run = tmp_path / "src", tmp_path / "p3"
    assert run_cli("phase1", *system, "--out", src, "--phase1-evals", 6, "--backend", "serial",
                   "--quiet")[0] == 0
    assert run_cli("train-vae", *system, "--out", src, "--vae-epochs", 5, "--latent-dim", 2,
                   "--quiet")[0] == 0
    p3 = ("phase3", *system, "--vae", src, "--out", run, "--strategy", "plain", "--backend",
          "serial", "--quiet")
    assert run_cli(*p3, "--handover", "patience=2", "--phase3-evals", 2)[0] == 0
    line = one_line_error(*run_cli(*p3, "--handover", "--phase3-evals", 3, "--resume")[::2])
    assert line.endswith("phase 3 was run with --handover patience=2,tol=0.01,length=0.2 "
                         "(stored), not --handover patience=20,tol=0.01,length=0.2"), line


def test_a_factory_default_the_record_cannot_hold_is_named_as_the_default(run_cli, plugin_dir,
                                                                           tmp_path):
    """``report DIR --system m:f --system-arg mass=2`` on a run made without --system-arg, of a
    factory whose default JSON cannot hold (NaN: not recorded), said "args.mass: stored None,
    given 2", though the factory's default applied, not None. It says "stored the factory's
    default", and "given the factory's default" the other way round."""
    (plugin_dir / "nanmass.py").write_text(textwrap.dedent('''
        import closplant

        def make(mass=float("nan"), dim=3):
            return closplant.make(dim)
    '''))
    runs = tmp_path / "without", tmp_path / "with"
    for run, pairs in ((runs[0], []), (runs[1], ["--system-arg", "mass=2"])):
        code, _, err = run_cli("phase1", "--system", "nanmass:make", *pairs, "--out", run,
                               "--phase1-evals", 3, "--backend", "serial", "--quiet")
        assert code == 0, err
    line = one_line_error(*run_cli("report", runs[0], "--system", "nanmass:make",
                                   "--system-arg", "mass=2", "--no-sim")[::2])
    assert "(args.mass: stored the factory's default, given 2)" in line, line
    line = one_line_error(*run_cli("report", runs[1], "--system", "nanmass:make",
                                   "--no-sim")[::2])
    assert "(args.mass: stored 2, given the factory's default)" in line, line
    sys.modules.pop("nanmass", None)


def test_a_system_arg_given_twice_is_refused(run_cli, plugin_dir, tmp_path):
    """``--system-arg shift=1 --system-arg shift=2`` ran the system at shift=2 and dropped the
    first without a word: a key given twice is one line naming it and both values, before any
    store is made."""
    from latentune.errors import SystemSpecError
    from latentune.system import parse_system_args

    with pytest.raises(SystemSpecError, match=r"shift is given twice \(1, then 2\)"):
        parse_system_args(["shift=1", "dim=3", "shift=2"])
    out = tmp_path / "r"
    code, _, err = run_cli("phase1", "--system", "closplant:make", "--system-arg", "shift=1",
                           "--system-arg", " shift =2", "--out", out, "--phase1-evals", "4",
                           "--backend", "serial")
    line = one_line_error(code, err)
    assert "--system-arg shift is given twice" in line and not (out / "run.db").exists()


def test_ask_with_system_on_a_run_made_through_the_api_says_to_leave_it_out(run_cli, tmp_path):
    """``ask DIR --system M:F`` on a run made through the API with the same system said "holds
    a run of another system (args: stored None, given {}; class: stored ..., given None; ...)",
    a diff of two descriptions; it names the Python system and says to leave --system out
    (report said the same), and the ask without it goes on."""
    from examples.lqr_chain import make_system

    with lt.Study(tmp_path / "api", seed=0) as st:
        st.phase1(make_system(), 3, method="random")
    line = one_line_error(*run_cli("ask", tmp_path / "api", "--system",
                                   "examples.lqr_chain:make_system", "--budget", "4")[::2])
    assert line == (f"latentune: error: {tmp_path / 'api'} holds a run of the Python system "
                    "examples.lqr_chain.ChainSystem (made through the API), not of --system "
                    "examples.lqr_chain:make_system: leave --system out (ask, tell and report "
                    "read the stored run), or continue it with latentune.Study"), line
    assert run_cli("ask", tmp_path / "api", "--budget", "4")[0] == 0



STOPPING = textwrap.dedent('''
    import os

    import numpy as np
    import latentune as lt


    def make():
        """Unless STOPPLANT_RUNS is set, the first trial of a process runs and the next is a
        Ctrl-C (the file "stop" marks that one has run)."""
        def fn(x):
            if not os.environ.get("STOPPLANT_RUNS"):
                if os.path.exists("stop"):
                    os.remove("stop")
                    raise KeyboardInterrupt
                open("stop", "w").close()
            return float(np.sum((x - 0.2) ** 2))
        return lt.FunctionSystem(lt.ParameterSpace(["a", "b", "c"], [-1.0] * 3, [1.0] * 3,
                                                   manual=[0.5] * 3), fn)
''')


def test_a_phase_run_stopped_after_its_first_trial_is_not_rerun_without_resume(
        run_cli, tmp_path, monkeypatch):
    """A Ctrl-C after the zero-shot θ, the first trial a phase-3 run stores, left a directory
    that the same command without --resume went on with silently, while one with a phase-3
    trial is refused ("already holds N phase-3 evaluations; pass --resume ..."). It is now
    refused the same way, the store unchanged; --resume goes on."""
    from conftest import dump

    made = _module_dir(tmp_path, monkeypatch, "stopplant", STOPPING)
    next(made)
    common = ("--system", "stopplant:make", "--backend", "serial", "--quiet")
    src, tgt = tmp_path / "src", tmp_path / "tgt"
    monkeypatch.setenv("STOPPLANT_RUNS", "1")
    code, _, err = run_cli("tune", *common, "--out", src, "--phase1-evals", 12,
                           "--phase3-evals", 2, "--vae-epochs", 20)
    assert code == 0, err
    monkeypatch.delenv("STOPPLANT_RUNS")
    code, _, err = run_cli("phase3", *common, "--vae", src, "--out", tgt, "--phase3-evals", 4)
    assert code == 130, err
    assert RunStore(tgt).count(Phase.ZERO_SHOT) == 1 and RunStore(tgt).count(Phase.PHASE3) == 0
    before = dump(tgt)
    line = one_line_error(*run_cli("phase3", *common, "--vae", src, "--out", tgt,
                                   "--phase3-evals", 4)[::2])
    assert line.endswith(f"{tgt} already holds the zero-shot trial phase 3 began with; pass "
                         "--resume to continue the run or choose another --out"), line
    assert dump(tgt) == before
    monkeypatch.setenv("STOPPLANT_RUNS", "1")
    code, _, err = run_cli("phase3", *common, "--vae", src, "--out", tgt, "--phase3-evals", 4,
                           "--resume")
    assert code == 0, err
    assert RunStore(tgt).count(Phase.PHASE3) == 4
    next(made, None)


def test_train_vae_reports_the_decoders_spread(run_cli, plugin_dir, tmp_path):
    """README: "train-vae reports the decoder's spread (the variance of the decoded θ over the
    training set's)"; it printed only "VAE (det, d_low 2) trained on N θ: DIR/vae.pt", the
    spread shown with -v alone. The line now ends with it, as recorded in the manifest."""
    import re

    run = tmp_path / "r"
    common = ("--system", "closplant:make", "--out", run)
    assert run_cli("phase1", *common, "--phase1-evals", 10, "--backend", "serial",
                   "--quiet")[0] == 0
    code, out, err = run_cli("train-vae", *common, "--latent-dim", 2, "--vae-epochs", 20)
    assert code == 0, err
    ratio = lt.Study(run).config()["vae"]["decoded_variance_ratio"]
    assert re.fullmatch(rf"VAE \(det, d_low 2\) trained on \d+ θ: {re.escape(str(run))}/vae.pt; "
                        rf"decoded spread {ratio:.3f} of the training variance\n", out), out


def test_a_run_of_one_trial_is_named_in_the_singular(run_cli, error_line, tmp_path):
    """A phase run again without --resume on a run of one phase-1 trial said "already holds 1
    phase-1 evaluations"; one is one evaluation."""
    out = tmp_path / "one"
    flags = ("--system", "examples.toy_plant:make_system", "--out", out, "--backend", "serial",
             "--phase1-evals", "1")
    assert run_cli("phase1", *flags)[0] == 0
    line = error_line(*run_cli("phase1", *flags)[::2])
    assert "already holds 1 phase-1 evaluation; pass --resume" in line, line
