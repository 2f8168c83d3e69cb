"""`latentune dashboard`: a run exported to an Optuna storage, kept live, and served by
optuna-dashboard — checked in headless Chromium (Debian's ``chromium`` + ``chromium-driver``;
``.ci/run`` installs them, and this test fails rather than skips without them)."""
from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path
from urllib.request import urlopen

import numpy as np
import pytest

optuna = pytest.importorskip("optuna", reason="the optuna extra (CI installs it)")

import latentune as lt  # noqa: E402
from latentune.constants import Phase  # noqa: E402
from latentune.errors import LatentuneError  # noqa: E402
from latentune.integrations import register_cli  # noqa: E402

# latentune.integrations.dashboard imports optuna-dashboard (with scikit-learn and BoTorch):
# seconds, paid only by the pytest-xdist worker that runs these tests, not at each collection.


def RunExport(*a, **kw):  # noqa: N802 - stands for the class
    """:class:`latentune.integrations.dashboard.RunExport`, imported on first use."""
    from latentune.integrations.dashboard import RunExport as cls
    return cls(*a, **kw)


def Dashboard(*a, **kw):  # noqa: N802 - stands for the class
    """:class:`latentune.integrations.dashboard.Dashboard`, imported on first use."""
    from latentune.integrations.dashboard import Dashboard as cls
    return cls(*a, **kw)

S = optuna.trial.TrialState
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--disable-dev-shm-usage", "--window-size=1400,1000")


def space() -> lt.ParameterSpace:
    return lt.ParameterSpace(["kp", "kd", "ki"], [0.1, 0.0, 0.0], [10.0, 1.0, 2.0],
                             log=[True, False, False], manual=[1.0, 0.5, 1.0])


def plant(x: np.ndarray) -> tuple[float, bool]:
    """A bowl in (log kp, kd, ki); kd > 0.8 falls."""
    c = (np.log10(x[0]) - 0.3) ** 2 + (x[1] - 0.4) ** 2 + (x[2] - 1.2) ** 2
    return float(c), bool(x[1] > 0.8)


def run_dir(tmp_path: Path, budget: int) -> Path:
    with lt.Study(tmp_path / "run", seed=0) as s:
        s.phase1(lt.FunctionSystem(space(), plant), budget, method="sobol")
    return tmp_path / "run"


def wait_for(cond, timeout: float = 30.0, what: str = "condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def test_export_phases_falls_and_suggestions(tmp_path):
    run = run_dir(tmp_path, 8)
    exp = RunExport(run)
    assert exp.sync() == 9 and exp.sync() == 0          # manual θ + 8 phase-1 rows, once
    studies = {s.study_name: s for s in exp.storage.get_all_studies()}
    assert set(studies) == {"run/manual", "run/phase 1"}
    p1 = optuna.load_study(study_name="run/phase 1", storage=exp.storage)
    rows = lt.Study(run).store.rows(Phase.PHASE1)
    assert len(p1.trials) == len(rows) == 8
    for t, r in zip(p1.trials, rows):
        assert t.state == S.COMPLETE and t.value == pytest.approx(r.cost)
        assert t.user_attrs["idx"] == r.idx and t.user_attrs["fell"] == r.fell
        assert t.constraints == {"fall": 1.0 if r.fell else 0.0, "0": 1.0 if r.fell else 0.0}
        np.testing.assert_allclose(list(t.params.values()), space().to_physical(r.theta))
    assert p1.trials[0].distributions["kp"] == optuna.distributions.FloatDistribution(
        0.1, 10.0, log=True)
    assert any(r.fell for r in rows) and not all(r.fell for r in rows)
    # the same export into a journal file, readable by any Optuna process
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    journal = tmp_path / "run.journal"
    RunExport(run, JournalStorage(JournalFileBackend(str(journal)))).sync()
    again = JournalStorage(JournalFileBackend(str(journal)))
    assert [t.value for t in optuna.load_study(study_name="run/phase 1", storage=again).trials] \
        == [t.value for t in p1.trials]
    # ask/tell: a pending suggestion is RUNNING, then completed in place when told
    tell_run = tmp_path / "asked"
    st = lt.Study(tell_run, seed=1)
    sug = st.ask(2, space=space(), method="sobol")
    exp2 = RunExport(tell_run)
    exp2.sync()
    s2 = optuna.load_study(study_name="asked/phase 1", storage=exp2.storage)
    assert [t.state for t in s2.trials] == [S.RUNNING, S.RUNNING]
    st.tell(sug[1].id, cost=0.7, failed=True)
    assert exp2.sync() == 1
    t1 = optuna.load_study(study_name="asked/phase 1", storage=exp2.storage).trials[1]
    assert t1.state == S.COMPLETE and t1.value == 0.7 and t1.user_attrs["fell"] is True
    assert t1.user_attrs["suggestion"] == sug[1].id and t1.constraints == {"fall": 1.0, "0": 1.0}


def test_preservation_rows_stored_between_two_polls_are_all_exported(tmp_path):
    """The export took a phase's exported rows to be its first ``idx + 1`` (the last row's
    idx), but a preservation row's idx is its phase-1 row's, and a phase-1 trial that fell
    has none: with a poll between two preservation trials, 10 of 27 rows of a run were shown.
    Every stored row is exported once, whatever its idx."""
    run = run_dir(tmp_path, 12)
    with lt.Study(run) as s:
        s.train_latent(latent_dim=2, epochs=20)
    exp = RunExport(run)
    exp.sync()
    system = lt.FunctionSystem(space(), plant)

    class Polled:                       # the dashboard's poll before each preservation trial
        space = system.space

        def evaluate(self, u):
            exp.sync()
            return system.evaluate(u)

    with lt.Study(run) as s:
        s.preservation(Polled(), run)
        stored = [r.idx for r in s.store.rows(Phase.PRESERVATION)]
        p1 = s.store.rows(Phase.PHASE1)
    assert any(r.fell for r in p1[:-1])                 # the premise: a gap in the idx
    exp.sync()
    assert exp.sync() == 0
    shown = optuna.load_study(study_name="run/preservation", storage=exp.storage).trials
    assert sorted(t.user_attrs["idx"] for t in shown) == stored


def test_the_dashboard_serves_a_fall_as_an_infeasible_trial(tmp_path):
    """A fall was exported only as Optuna's named constraint ``constraints:fall``, which
    optuna-dashboard does not read (its pages take the ``constraints`` list): the served trials
    had no constraint and the dashboard drew falls as feasible; each trial now carries its fall
    in that list too (1 for a fall, else 0)."""
    run = run_dir(tmp_path, 8)
    fell = [r.fell for r in lt.Study(run).store.rows(Phase.PHASE1)]
    with Dashboard(run, port=0, interval=0.3) as dash:
        base = dash.url.split("/dashboard")[0]
        names = {s["study_name"]: s["study_id"] for s in json.loads(
            urlopen(f"{base}/api/studies", timeout=10).read())["study_summaries"]}
        trials = json.loads(urlopen(f"{base}/api/studies/{names['run/phase 1']}",
                                    timeout=10).read())["trials"]
    assert [t["constraints"] for t in trials] == [[1.0 if f else 0.0] for f in fell]
    assert any(fell) and not all(fell)


def test_dashboard_cli_refusals(tmp_path):
    parser = argparse.ArgumentParser(prog="latentune")
    register_cli(parser.add_subparsers(dest="command", required=True))
    for argv, msg in ((["dashboard", str(tmp_path / "none")], "no latentune run"),
                      (["dashboard", str(tmp_path), "--port", "0"], "--port must be in"),
                      (["dashboard", str(tmp_path), "--interval", "0"], "--interval must be")):
        args = parser.parse_args(argv)
        with pytest.raises(LatentuneError, match=msg) as ei:
            args.func(args)
        assert "\n" not in str(ei.value)


def test_dashboard_journal_refusals(tmp_path):
    """--journal in a directory that does not exist is one line, not a traceback; a refused
    start (no run there) leaves no journal file behind, which would refuse the next attempt."""
    run = run_dir(tmp_path, 2)
    with pytest.raises(LatentuneError, match="cannot create journal file") as ei:
        Dashboard(run, journal=tmp_path / "no_dir" / "j.log")
    assert "\n" not in str(ei.value)
    journal = tmp_path / "j.log"
    with pytest.raises(LatentuneError, match="no latentune run"):
        Dashboard(tmp_path / "none", journal=journal)
    assert not journal.exists()
    dash = Dashboard(run, journal=journal)
    dash.close()
    assert journal.stat().st_size > 0


def _chromium():
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    binary = next((shutil.which(b) for b in ("chromium", "chromium-browser") if shutil.which(b)),
                  None)
    driver = shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.fail("headless Chromium is needed: apt-get install -y chromium chromium-driver")
    opts = Options()
    for a in CHROMIUM_FLAGS:
        opts.add_argument(a)
    opts.binary_location = binary
    return webdriver.Chrome(service=Service(driver), options=opts)


@pytest.mark.slow
def test_dashboard_live_in_chromium(tmp_path):
    from selenium.webdriver.common.by import By

    run = run_dir(tmp_path, 6)
    with Dashboard(run, port=0, interval=0.3) as dash:
        assert dash.url.startswith("http://127.0.0.1:")
        drv = _chromium()
        try:
            drv.set_page_load_timeout(60)
            drv.get(dash.url)
            link = wait_for(lambda: [a for a in drv.find_elements(By.TAG_NAME, "a")
                                     if "run/phase 1" in a.text], what="the study list")[0]
            study_url = link.get_attribute("href")

            def points() -> int:
                plots = drv.find_elements(By.ID, "plot-history")
                return len(plots[0].find_elements(By.CSS_SELECTOR, "path.point")) if plots else 0

            drv.get(study_url)
            wait_for(lambda: points() == 6, what="6 trials in the history plot")
            drv.get(study_url + "/trials")
            body = wait_for(lambda: "6 Trials" in (t := drv.find_element(By.TAG_NAME, "body").text)
                            and t, what="the trial list")
            assert "Trial 5" in body and "kp" in body and "fell" in body
            # live: the run grows while the dashboard serves it
            with lt.Study(run) as s:
                s.phase1(lt.FunctionSystem(space(), plant), 9, method="sobol")
            wait_for(lambda: len(optuna.load_study(study_name="run/phase 1",
                                                   storage=dash.export.storage).trials) == 9,
                     what="the export to catch up")
            # the page asks the server once when loaded, then every few seconds: load it once the
            # server serves 9 trials (it keeps a study's trials for 2 s), not a page that waits
            api = study_url.replace("/dashboard/studies/", "/api/studies/")
            assert api != study_url, study_url
            wait_for(lambda: len(json.loads(urlopen(api, timeout=10).read())["trials"]) == 9,
                     what="the server to serve 9 trials")
            drv.get(study_url)
            wait_for(lambda: points() == 9, what="9 trials in the history plot")
        finally:
            drv.quit()


def test_a_store_with_trials_and_no_space_says_why_nothing_is_shown(tmp_path: Path):
    """A run store holding trials but no parameter space and no task (another layout's store):
    the export exported nothing, silently, and the dashboard showed an empty page. It says why
    in one line; a store of the first layout (its task recorded, no space) is exported by its
    task's space; an empty store waits for its first trial."""
    from latentune.errors import StoreError
    from latentune.pipeline.store import RunStore

    d = tmp_path / "other"
    with RunStore(d, create=True) as st:
        st.add(1, 0, np.zeros(3), cost=1.0)
        st.add(1, 1, np.zeros(3), cost=2.0)
    with pytest.raises(StoreError) as e:
        RunExport(d).sync()
    assert str(e.value) == (f"{d} holds 2 trials but records no parameter space (a store of "
                            "another layout?): no trial's parameters can be named, so there is "
                            "nothing to show")
    with pytest.raises(StoreError):
        Dashboard(d)
    with RunStore(tmp_path / "empty", create=True):
        pass
    assert RunExport(tmp_path / "empty").sync() == 0
    task = {"robot": "a1", "gait": "trot", "terrain": "flat", "actor": "convex",
            "v_des": [0.5, 0.0, 0.0], "steps": 200, "seed": 0, "dim": 25}
    with RunStore(tmp_path / "first", create=True) as st:
        st.set_meta("config", {"task": task})
        st.add(1, 0, np.full(25, 0.5), cost=3.0)
    exp = RunExport(tmp_path / "first")
    assert exp.sync() == 1


def free_port() -> str:
    """A port on 127.0.0.1 that nothing listens on now (the CLI's --port takes no 0)."""
    import socket

    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        return str(sk.getsockname()[1])


@pytest.mark.parametrize("how, expect", [
    ("term", "latentune: error: terminated (SIGTERM); the run is unchanged (the dashboard "
             "only reads it)"),
    ("int", "latentune: error: interrupted; the run is unchanged (the dashboard only reads it)"),
])
def test_a_dashboard_stopped_while_it_starts_says_the_run_is_unchanged(tmp_path, monkeypatch,
                                                                       run_cli, how, expect):
    """SIGTERM (or Ctrl-C) while ``latentune dashboard`` started said "stored results are
    kept", odd for a command that stores nothing; it says the run is unchanged."""
    import os
    import signal

    from latentune.integrations import dashboard

    def stopped(self):
        if how == "term":
            os.kill(os.getpid(), signal.SIGTERM)
        raise KeyboardInterrupt

    monkeypatch.setattr(dashboard.Dashboard, "start", stopped)
    code, out, err = run_cli("dashboard", run_dir(tmp_path, 2), "--port", free_port())
    assert (code, err.strip()) == (143 if how == "term" else 130, expect), (code, err)
