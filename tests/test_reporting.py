"""latentune.reporting on synthetic run stores: metrics, the run report, the paper report.

No rollouts: stores are filled with made-up costs; the one re-simulation test uses a fake system.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from latentune.constants import C1, Phase
from latentune.errors import UsageError
from latentune.pipeline.store import RunStore
from latentune.reporting import metrics
from latentune.reporting.metrics import (best_so_far, evals_to_beat, fall_count, paper_row,
                                         phase_stats, rms_velocity_error, stable_count,
                                         stable_share)
from latentune.reporting.paper_report import write_paper_report
from latentune.reporting.plots import CurvePanel, plot_best_so_far
from latentune.reporting.run_report import (comparison_table, handover_stats, make_report,
                                             state_lines, write_summary)

TASK = {"robot": "a1", "gait": "trot", "terrain": "flat", "actor": "convex",
        "v_des": [0.5, 0.0, 0.0], "steps": 2500, "seed": 0, "dim": 3}
MANUAL = 6.0
PHASE1 = [6.0, 150.0, 7.0, 5.5, 120.0, 5.0]      # first = the manual θ; beats manual at 4
PHASE3 = [8.0, 6.5, 5.8, 4.5]                      # beats manual at 3
ZERO_SHOT = 5.9


def _fill(store: RunStore, phase: int, costs, dim: int = 3) -> None:
    for i, c in enumerate(costs):
        store.add(phase, i, np.full(dim, 0.1 * (i % 10)), c, fell=c >= C1, tag=-1)


def _store(path: Path, config: dict, zero_shot: bool = True) -> RunStore:
    st = RunStore(path, create=True)
    st.set_meta("config", config)
    st.set_meta("wall", {"phase1": 12.0, "phase3": 3.0})
    _fill(st, Phase.MANUAL, [MANUAL])
    _fill(st, Phase.PHASE1, PHASE1)
    _fill(st, Phase.PHASE3, PHASE3)
    if zero_shot:
        _fill(st, Phase.ZERO_SHOT, [ZERO_SHOT])
    return st


def _row(md: str, label: str) -> list[str]:
    for line in md.splitlines():
        if line.startswith(f"| {label} |"):
            return [c.strip() for c in line.strip("|").split("|")]
    raise AssertionError(f"no row {label!r} in\n{md}")


# ---------------------------------------------------------------------------- metrics
def test_evals_to_beat_is_strict():
    assert evals_to_beat([5.0, 5.0, 4.9], 5.0) == 3      # equal to the target does not count
    assert evals_to_beat([5.0], 5.0) is None
    assert evals_to_beat([6.0, 4.0, 3.0], 5.0) == 2      # 1-based index of the first hit
    assert evals_to_beat([1.0], 5.0) == 1
    assert evals_to_beat([6.0, 7.0], 5.0) is None
    assert evals_to_beat([], 5.0) is None
    assert evals_to_beat([1.0], None) is None
    assert evals_to_beat(np.array([np.nan, 2.0]), 3.0) == 2


def test_curve_and_counts():
    y = [9.0, 150.0, 7.0, 8.0, 200.0, 6.5]
    assert best_so_far(y).tolist() == [9.0, 9.0, 7.0, 7.0, 7.0, 6.5]
    assert best_so_far([]).shape == (0,)
    assert stable_count(y, fall_cost=C1) == 4 and fall_count(y, fall_cost=C1) == 2
    assert stable_count(y) == 6 and fall_count(y) == 0        # no flags, no fall cost: finite
    assert stable_share(y, fall_cost=C1) == pytest.approx(4 / 6) and stable_share([]) is None
    assert fall_count(y, fell=[True, False, False, False, False, False]) == 1
    assert fall_count([1e300, math.inf, 5.0], fall_cost=C1) == 2
    assert fall_count([1e300, math.inf, math.nan, 5.0]) == 2
    s = phase_stats(y, target=7.5, fall_cost=C1)
    assert (s["n"], s["best"], s["best_idx"], s["stable"], s["falls"], s["evals_to_beat"]) == \
        (6, 6.5, 5, 4, 2, 3)
    assert phase_stats([])["best"] is None


def test_rms_velocity_error():
    # L = sqrt(N_H) · 0.1 m/s for a constant 0.1 m/s error over N_H steps
    assert rms_velocity_error(math.sqrt(2500) * 0.1, 2500) == pytest.approx(0.1)
    assert rms_velocity_error(5.0, 2500) == pytest.approx(0.1)
    assert rms_velocity_error(150.0, 2500, fell=True) is None   # a fall: the cost is a penalty
    assert rms_velocity_error(None, 2500) is None
    assert rms_velocity_error(5.0, 0) is None


def test_paper_numbers_lookup():
    assert paper_row("a1", "trot")["phase1"] == 5.96
    assert paper_row("Solo12", "jump")["manual"] == 12.24
    assert paper_row("b1", "trot") == {} and paper_row("anymal", "trot") == {}
    p = metrics.paper_results()
    p["path_cost"]["A1"]["trot"]["manual"] = -1.0          # callers get a copy
    assert paper_row("a1", "trot")["manual"] == 8.96
    assert "Sarmadi" in p["source"]["paper"]


# ---------------------------------------------------------------------------- run report
def test_summary_keys_and_values(tmp_path: Path):
    with _store(tmp_path / "run", {"task": TASK, "phase1": {"method": "turbo", "seed": 3}}) as st:
        s = write_summary(st)
        on_disk = json.loads((tmp_path / "run" / "summary.json").read_text())
    for k in ("manual_cost", "phase1_best", "phase3_best", "phase1_evals", "phase3_evals",
              "wall_s", "phase1_stable", "phase3_stable", "phase1_evals_to_beat_manual",
              "phase3_evals_to_beat_manual", "zero_shot_cost", "phase3_vs_phase1",
              "wall_by_phase_s", "seed", "config", "artifacts", "paper",
              "rms_velocity_error_m_s", "phase1_falls"):
        assert k in s and k in on_disk, k
    assert not any(k.endswith("_evals_to_manual") for k in s)
    assert (s["manual_cost"], s["phase1_best"], s["phase3_best"]) == (MANUAL, 5.0, 4.5)
    assert (s["phase1_evals"], s["phase3_evals"], s["phase1_stable"], s["phase1_falls"]) == \
        (6, 4, 4, 2)
    # phase 1's first evaluation equals the manual cost: not a "beat"
    assert (s["phase1_evals_to_beat_manual"], s["phase3_evals_to_beat_manual"]) == (4, 3)
    assert s["zero_shot_cost"] == ZERO_SHOT
    assert s["wall_s"] == 15.0 and s["seed"] == 3
    assert s["rms_velocity_error_m_s"]["phase3"] == pytest.approx(4.5 / 50.0)
    assert s["paper"] == {"manual": 8.96, "phase1": 5.96, "phase3": 6.17}


def test_a_failed_trial_is_never_the_best_whatever_cost_it_was_given(tmp_path: Path):
    """A user system may give its failed trials a cost below every standing one: the bests,
    "evals to beat manual", the table, ``RunStore.best`` (the θ re-simulated and imported as
    best) skip them; a phase where nothing stood has no best; the manual and zero-shot costs
    are their trial's own, with whether it fell."""
    y, fell = [3.0, 0.5, 2.0, 0.1], [False, True, False, True]
    s = phase_stats(y, target=2.5, fell=fell)
    assert (s["best"], s["best_idx"], s["stable"], s["evals_to_beat"]) == (2.0, 2, 2, 3)
    assert phase_stats([0.3, 0.2], fell=[True, True])["best"] is None
    np.testing.assert_array_equal(best_so_far(y, fell=fell), [3.0, 3.0, 2.0, 2.0])
    np.testing.assert_array_equal(best_so_far([0.5, 1.0], fell=[True, False]), [np.inf, 1.0])
    with RunStore(tmp_path / "run", create=True) as st:
        st.set_meta("config", {"system": {"kind": "user"}})
        st.add(Phase.MANUAL, 0, np.zeros(3), 2.5, fell=False, tag=-1)
        for i, (c, f) in enumerate(zip(y, fell)):
            st.add(Phase.PHASE3, i, np.full(3, 0.1 * i), c, fell=f, tag=-1)
        st.add(Phase.ZERO_SHOT, 0, np.ones(3), 0.05, fell=True, tag=-1)
        for i in range(2):
            st.add(Phase.PHASE1, i, np.full(3, 0.5), 0.01, fell=True, tag=-1)
        assert st.best(Phase.PHASE3).idx == 2 and st.best(Phase.PHASE1) is None
        summ = write_summary(st)
        md = comparison_table(st)
    assert (summ["phase3_best"], summ["phase3_evals_to_beat_manual"]) == (2.0, 3)
    assert summ["phase1_best"] is None and summ["phase3_vs_phase1"] is None
    assert (summ["zero_shot_cost"], summ["zero_shot_fell"]) == (0.05, True)
    assert (summ["manual_cost"], summ["manual_fell"]) == (2.5, False)
    assert _row(md, "phase 3 (latent, TuRBO-m)")[1:3] == ["2.000", "4"]
    assert _row(md, "phase 1 (θ, TuRBO-m)")[1:4] == ["–", "2", "0/2"]
    with RunStore(tmp_path / "hand", create=True) as st:      # the hand-over's two spaces
        st.set_meta("config", {"phase3_handover": {"rule": "x"}})
        st.add(Phase.PHASE3, 0, np.zeros(3), 0.2, z=np.zeros(2), fell=True, tag=-1)
        st.add(Phase.PHASE3, 1, np.zeros(3), 0.9, z=np.zeros(2), fell=False, tag=-1)
        st.add(Phase.PHASE3, 2, np.zeros(3), 0.1, fell=True, tag=-1)
        h = handover_stats(st)
    assert (h["latent_best"], h["full_best"], h["full_falls"]) == (0.9, None, 1)


def test_summary_beats_a_failed_manual_whatever_the_costs_and_ratio_only_for_positive_bests(
        tmp_path: Path):
    """A trial that stood beats a failed manual θ whatever the costs (a constant offset of the
    costs changes nothing); ``phase3_vs_phase1`` is None unless both bests are positive."""
    for offset in (0.0, 1e9):
        with RunStore(tmp_path / f"run{offset:g}", create=True) as st:
            st.set_meta("config", {"system": {"kind": "user"}})
            st.add(Phase.MANUAL, 0, np.zeros(3), 200.0, fell=True, tag=-1)
            for i, (c, f) in enumerate([(200.0, True), (offset + 3.0, False),
                                        (offset + 1.0, False)]):
                st.add(Phase.PHASE1, i, np.full(3, 0.1 * i), c, fell=f, tag=-1)
            st.add(Phase.PHASE3, 0, np.zeros(3), offset + 0.5, fell=False, tag=-1)
            s = write_summary(st)
            md = comparison_table(st)
        assert (s["phase1_evals_to_beat_manual"], s["phase3_evals_to_beat_manual"]) == (2, 1)
        assert _row(md, "phase 3 (latent, TuRBO-m)")[-1] == "1"
    with RunStore(tmp_path / "neg", create=True) as st:
        _fill(st, Phase.MANUAL, [-400.0])
        _fill(st, Phase.PHASE1, [-400.0, -500.0])
        _fill(st, Phase.PHASE3, [-600.0])
        s = write_summary(st)
    assert s["phase3_vs_phase1"] is None and s["phase1_evals_to_beat_manual"] == 2
    with RunStore(tmp_path / "pos", create=True) as st:
        _fill(st, Phase.PHASE1, [4.0])
        _fill(st, Phase.PHASE3, [2.0])
        assert write_summary(st)["phase3_vs_phase1"] == 0.5


def test_comparison_table(tmp_path: Path):
    with _store(tmp_path / "run", {"task": TASK}) as st:
        md = comparison_table(st)
    assert "| | best path cost | RMS velocity error [m/s] | evaluations | stable | evals to beat " \
        "manual |" in md
    m = _row(md, "manual tuned")
    assert m == ["manual tuned", "6.000", "0.120", "1", "1/1", "–"]
    p1 = _row(md, "phase 1 (θ, TuRBO-m)")
    assert p1 == ["phase 1 (θ, TuRBO-m)", "5.000", "0.100", "6", "4/6", "4"]
    p3 = _row(md, "phase 3 (latent, TuRBO-m)")
    assert p3 == ["phase 3 (latent, TuRBO-m)", "4.500", "0.090", "4", "4/4", "3"]
    z = _row(md, "zero-shot (source best θ)")
    assert z == ["zero-shot (source best θ)", "5.900", "0.118", "1", "1/1", "1"]
    lines = md.splitlines()
    # in the order they run, as status lists them: the zero-shot trial opens phase 3
    assert lines.index(next(l for l in lines if l.startswith("| zero-shot"))) + 1 == \
        lines.index(next(l for l in lines if l.startswith("| phase 3")))
    assert "a1 trot on flat [convex], 2500 steps" in md
    assert "paper (Sarmadi et al." in md and "phase 3 6.17" in md


def test_the_table_and_report_name_the_engine_reality_and_system_args(tmp_path: Path):
    """A run on MuJoCo or on the `hard` robot was titled "a1 trot on flat [convex]", as if it
    had run on the nominal PyBullet A1, and a --system run at gap 1 like one at gap 0."""
    task = dict(TASK, engine="mujoco", reality={"name": "hard", "mass_scale": 1.15})
    with _store(tmp_path / "run", {"task": task}) as st:
        assert "a1 trot on flat [convex, mujoco, reality hard], 2500 steps" in comparison_table(st)
        make_report(st, simulate=False, quiet=True)
    head = (tmp_path / "run" / "report.md").read_text().splitlines()[0]
    assert head == "# latentune run: a1 trot (flat, convex, mujoco, reality hard)"
    plugin = {"kind": "plugin", "target": "examples.lqr_chain:make_system", "args": {"gap": 1}}
    with _store(tmp_path / "user", {"system": plugin}) as st:      # and a --system's arguments
        assert comparison_table(st).startswith("system examples.lqr_chain:make_system (gap=1)\n")


@pytest.mark.parametrize("missing", ["actor", "gait", "v_des"])
def test_a_task_record_of_another_layout_is_one_line_and_reported_without_sim(
        tmp_path: Path, run_cli, error_line, missing: str):
    """``report`` on a built-in robot's run whose stored task lacks a field (a run written by
    another latentune version) ended in a traceback (KeyError: 'actor') when it rebuilt the
    task to re-simulate: it says in one line what the record lacks and to report with
    --no-sim, which writes the tables. Study.report said "--no-sim" too; it says
    simulate=False (:func:`latentune.wording.option`)."""
    import latentune as lt
    from latentune.errors import StoreError

    d = tmp_path / "run"
    task = {k: v for k, v in TASK.items() if k != missing}
    with _store(d, {"task": task, "phase1": {"method": "turbo"}}):
        pass
    with lt.Study(d) as st, pytest.raises(StoreError) as e:
        st.report()
    assert str(e.value).endswith("it cannot be re-simulated; report it with simulate=False"), \
        e.value
    line = error_line(*run_cli("report", d)[::2])
    assert line == (f"latentune: error: {d}: its stored task has no {missing!r} (a run written "
                    "by another latentune version): it cannot be re-simulated; report it with "
                    "--no-sim"), line
    code, out, err = run_cli("report", d, "--no-sim")
    assert code == 0 and "| phase 1 (θ, TuRBO-m) |" in out, err


def test_table_without_zero_shot_and_never_beaten(tmp_path: Path):
    cfg = {"task": dict(TASK, terrain="hills"), "phase1": {"method": "cma"},
           "vae": {"d_low": 2}}                     # phase 3 still to come
    with RunStore(tmp_path / "run", create=True) as st:
        st.set_meta("config", cfg)
        _fill(st, Phase.MANUAL, [4.0])
        _fill(st, Phase.PHASE1, [4.0, 4.0, 130.0])
        md = comparison_table(st)
        s = write_summary(st)
    assert "zero-shot" not in md and s["zero_shot_cost"] is None
    assert _row(md, "phase 1 (θ, CMA-ES)")[-1] == "not beaten"
    assert _row(md, "phase 3") == ["phase 3", "–", "–", "0", "–", "–"]   # not started
    assert s["phase1_evals_to_beat_manual"] is None and s["phase1_falls"] == 1
    assert "phase 3 6.57" in md                                # the paper's uneven number


def test_table_shows_tiny_and_huge_costs(tmp_path: Path):
    """A best cost of 1e-9 was shown as 0.000 (and -1e-4 as -0.000)."""
    for costs, best in (([1e-9, 1e12, 3.0], "1e-09"), ([-1e-4, 2.0], "-0.0001"),
                        ([2e12, 5e12], "2e+12"), ([0.0, 1.0], "0.000"), ([2.5, 7.0], "2.500")):
        with RunStore(tmp_path / f"run{best}", create=True) as st:
            st.set_meta("config", {})
            for i, c in enumerate(costs):       # a user system's cost: no fall threshold
                st.add(Phase.PHASE1, i, np.full(3, 0.1 * i), c, fell=False, tag=-1)
            assert _row(comparison_table(st), "phase 1 (θ, TuRBO-m)")[1] == best, costs


def test_make_report_user_system_without_simulation(tmp_path: Path):
    cfg = {"system": {"kind": "python", "class": "mymod.Arm"}, "phase1": {"method": "turbo"}}
    with _store(tmp_path / "run", cfg, zero_shot=False) as st:
        table = make_report(st, simulate=True, quiet=True)
        arts = st.get_meta("artifacts")
    out = tmp_path / "run"
    assert (out / "best_so_far.png").stat().st_size > 1000
    assert not (out / "com_velocity.png").exists()          # nothing to re-simulate with
    md = (out / "report.md").read_text()
    assert md.startswith("# latentune run: system mymod.Arm")
    assert table in md and "![best_so_far.png](best_so_far.png)" in md
    assert "RMS" not in table and "| best cost |" in table and "paper" not in table
    assert _row(table, "phase 1 (θ, TuRBO-m)")[-1] == "4"
    assert set(arts) >= {"best_so_far_png", "report_md"}
    assert json.loads((out / "summary.json").read_text())["rms_velocity_error_m_s"] is None


@pytest.mark.parametrize("made, line", [
    ({"robot": None, "gait": None, "actor": None, "terrain": None},
     "Phase 3 used the VAE of /src/run."),
    ({"robot": "a1", "gait": "trot", "actor": None, "terrain": "flat"},
     "Phase 3 used the VAE of /src/run (robot a1, gait trot, terrain flat)."),
])
def test_report_names_the_latent_space_source_without_empty_fields(tmp_path: Path, made, line):
    """A user system's latent space came from no robot or gait: the report said
    ``({'robot': None, 'gait': None, 'actor': None, 'terrain': None})``; it names what is
    known, and nothing when nothing is."""
    cfg = {"system": {"kind": "python", "class": "mymod.Arm"}, "phase1": {"method": "turbo"},
           "phase3_vae_source": "/src/run",
           "latent": {"kind": "det", "d": 4, "d_low": 2, "n_train": 9, "box_rule": "b",
                      "from": made}}
    with _store(tmp_path / "run", cfg) as st:
        make_report(st, simulate=False, quiet=True)
    md = (tmp_path / "run" / "report.md").read_text().splitlines()
    assert line in md and not any("None" in ln for ln in md if "used the VAE" in ln)


def test_the_report_says_when_a_phase_s_wall_time_is_not_known(tmp_path: Path):
    """A run whose phases no command timed (told through ask/tell, imported, or killed before
    its time was stored) showed no wall time, and summary.json wall_s 0; the report now says
    the time is not known, and summary.json's wall_s is None."""
    cfg = {"system": {"kind": "python", "class": "mymod.Arm"}, "phase1": {"method": "turbo"}}
    with _store(tmp_path / "run", cfg) as st:
        st.delete_meta("wall")
        make_report(st, simulate=False, quiet=True)
    md = (tmp_path / "run" / "report.md").read_text().splitlines()
    assert any(ln.startswith("Wall time of phase1, phase3 not (all) known: trials told "
                             "through ask/tell or imported") for ln in md), md
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["wall_s"] is None and summary["wall_unknown"] == ["phase1", "phase3"]


def test_a_block_killed_then_run_again_says_which_part_of_its_time_is_known(tmp_path: Path):
    """A VAE training killed before it ended (no trial, so its time is lost), then trained
    again to the end: the report said "Wall time of vae not (all) known: trials told through
    ask/tell or imported, ...", as if nothing of it were timed. The later training's time is
    known and shown; the killed one's is not, and the report says that part is missing and
    why; summary.json keeps vae in wall_unknown (its total is not all known)."""
    import time as _time

    from latentune.pipeline.manifest import Manifest
    from latentune.pipeline.rundir import RunDir
    from latentune.pipeline.walltime import settle_open

    cfg = {"system": {"kind": "python", "class": "mymod.Arm"}, "phase1": {"method": "turbo"},
           "vae": {"latent_dim": 2}}                    # the training that ended stored it
    with _store(tmp_path / "run", cfg) as st:
        st.set_meta("wall_open", {"vae": _time.time()})     # killed in its training
        settle_open(st)
    run = RunDir(tmp_path / "run")
    with Manifest(run).timing("vae"):          # the training run again, to its end
        pass
    run.store.close()
    with RunStore(tmp_path / "run") as st:
        make_report(st, simulate=False, quiet=True)
    md = (tmp_path / "run" / "report.md").read_text().splitlines()
    line = next(ln for ln in md if ln.startswith("Wall time:"))
    assert "phase1 12 s, phase3 3 s, vae 0 s + unknown." in line, line
    assert "The time of vae leaves out a block stopped before it stored its time" in line, line
    assert "told through ask/tell" not in line, line
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["wall_unknown"] == ["vae"] and summary["wall_by_phase_s"]["vae"] >= 0.0


def test_a_paper_study_killed_inside_a_phase_counts_its_time(tmp_path: Path):
    """A study of ``paper`` killed inside phase 3 (its start stored, its end never) counted
    0 s for it in the paper's wall times; it counts up to its last stored trial."""
    import time as _time

    from latentune.reporting.paper_report import study_stats

    with _store(tmp_path / "run", {"task": TASK}) as st:
        st.set_meta("wall", {"phase1": 12.0})
        st.set_meta("wall_open", {"phase3": _time.time() - 60.0})
        st.add(Phase.PHASE3, len(PHASE3), np.full(3, 0.5), 4.0, fell=False, tag=-1)
    wall = study_stats(tmp_path / "run")["wall"]
    assert wall["phase1"] == 12.0 and 59.0 < wall["phase3"] < 120.0


class _FakeResult:
    def __init__(self, cost: float) -> None:
        self.cost = cost
        self.rms_vel_error = cost / 50.0
        t = np.arange(1, 51) * 1e-3
        self.trace = {"t": t, "vel": np.tile([0.45, 0.0, 0.0], (50, 1)), "height": 0.3 + 0 * t}


class _FakeSystem:
    v_des = (0.5, 0.0, 0.0)

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, bool]] = []

    def rollout(self, theta, record: bool = False):
        self.calls.append((np.asarray(theta), record))
        return _FakeResult(5.0 + len(self.calls))


def test_make_report_resimulates_with_given_system(tmp_path: Path):
    sim = _FakeSystem()
    with _store(tmp_path / "run", {"task": TASK}) as st:
        make_report(st, system=sim, simulate=True, quiet=True)
        best3 = st.best(Phase.PHASE3).theta
    assert len(sim.calls) == 4 and all(rec for _, rec in sim.calls)   # manual, 1, zero-shot, 3
    assert np.allclose(sim.calls[3][0], best3)
    out = tmp_path / "run"
    assert (out / "com_velocity.png").stat().st_size > 1000
    assert "![com_velocity.png](com_velocity.png)" in (out / "report.md").read_text()
    # simulate=False: the system is not used, and the earlier report's figure (of the best θ
    # then) is not left behind as an artifact of this one
    sim2 = _FakeSystem()
    with RunStore(out) as st:
        make_report(st, system=sim2, simulate=False, quiet=True)
    assert sim2.calls == []
    assert not (out / "com_velocity.png").exists()
    assert "com_velocity_png" not in json.loads((out / "summary.json").read_text())["artifacts"]


def test_best_so_far_figure(tmp_path: Path):
    with pytest.raises(ValueError):
        plot_best_so_far(CurvePanel("empty", {"a": []}), tmp_path / "x.png")
    p = tmp_path / "f.png"
    plot_best_so_far([CurvePanel("phase 1", {"p1": PHASE1}, {"manual θ": MANUAL}),
                      CurvePanel("phase 3", {"p3": PHASE3, "all fell": [150.0, 190.0]},
                                 {"manual θ": None})], p, title="t")
    assert p.stat().st_size > 5000


def test_report_of_a_run_where_every_trial_failed_without_a_manual_row(tmp_path: Path):
    """An ask/tell --space study (no manual row) or an imported Optuna study whose every trial
    failed: the best-cost axis has nothing to log-scale (matplotlib raised); the report, the
    figure and summary.json are written."""
    from latentune.reporting.plots import _log_axis, pyplot

    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2)
    assert _log_axis(a, []) == "linear" and a.get_yscale() == "linear"
    assert _log_axis(b, [np.nan, np.inf]) == "linear" and b.get_yscale() == "linear"
    plt.close(fig)
    for costs in ([np.nan] * 3, [200.0] * 3):
        out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        with RunStore(out, create=True) as st:
            st.set_meta("config", {"system": {"kind": "user"}})
            for i, c in enumerate(costs):
                st.add(Phase.PHASE1, i, np.full(3, 0.1 * i), c, fell=True, tag=-1)
            table = make_report(st, simulate=False, quiet=True)
        assert (out / "best_so_far.png").stat().st_size > 1000
        assert table in (out / "report.md").read_text()
        summ = json.loads((out / "summary.json").read_text())
        assert summ["phase1_best"] is None and summ["phase1_falls"] == 3
        assert _row(table, "phase 1 (θ, TuRBO-m)")[1:4] == ["–", "3", "0/3"]


def test_the_cost_axis_is_linear_where_a_log_axis_would_drop_costs():
    """A user system's costs may be ≤ 0: the top row's log axis would leave them out."""
    from latentune.reporting.plots import _log_axis, pyplot

    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2)
    assert _log_axis(a, [3.0, 0.5, np.inf]) == "log" and a.get_yscale() == "log"
    assert _log_axis(b, [3.0, -0.5, 2.0]) == "linear" and b.get_yscale() == "linear"
    plt.close(fig)


# ---------------------------------------------------------------------------- paper report
def _paper_dir(root: Path) -> Path:
    studies = {"a1-trot": {"label": "tune trot", "kind": "tune"},
               "a1-trot-hills": {"label": "trot on hills", "kind": "phase3"},
               "a1-trot-cma": {"label": "CMA-ES baseline", "kind": "baseline"},
               "a1-jump": {"label": "tune jump", "kind": "tune"},
               "b1-trot-transfer": {"label": "B1 transfer", "kind": "phase3"}}
    meta = {"robot": "a1", "actor": "convex", "steps": 2500, "v_des": 0.5, "seed": 0,
            "workers": 1, "command": "latentune paper --robot a1 --scale 0.001",
            "wall_s_total": 42.0, "invocations": [{"wall_s": 42.0}], "studies": studies,
            "budgets": {"scale": 0.001, "phase1": 6, "phase3": 4, "baselines": 4,
                        "preservation": 3, "mapping": "phase1 = ...", "overridden": {}}}
    root.mkdir(parents=True)
    (root / "paper.json").write_text(json.dumps(meta))
    with _store(root / "a1-trot", {"task": TASK}, zero_shot=False):
        pass
    for key, phase, costs, manual in (("a1-trot-hills", Phase.PHASE3, [7.0, 6.2], 6.4),
                                      ("a1-trot-cma", Phase.PHASE1, [6.0, 5.9, 190.0, 5.2], MANUAL),
                                      ("b1-trot-transfer", Phase.PHASE3, [9.0, 8.0, 150.0], 8.5)):
        with RunStore(root / key, create=True) as st:
            st.set_meta("config", {"task": TASK})
            st.set_meta("wall", {"phase": 1.0})
            _fill(st, Phase.MANUAL, [manual])
            _fill(st, phase, costs)
    return root


def test_paper_report_names_the_phase_1_prefix_it_has(tmp_path: Path):
    """At a small --scale the baselines' budget (phase 3's, at least 8) exceeds phase 1's
    (at least 12 at S = 0.0001: 22 against 12): the row read "phase 1's first 22 evaluations"
    with 12 in its count. It names the evaluations it holds."""
    root = _paper_dir(tmp_path / "paper")
    meta = json.loads((root / "paper.json").read_text())
    meta["budgets"]["baselines"] = 9                  # phase 1 holds 6
    (root / "paper.json").write_text(json.dumps(meta))
    md = write_paper_report(root, simulate=False, gifs=False)
    assert "phase 1's first 9 evaluations" not in md
    assert _row(md, "phase 1's first 6 evaluations (TuRBO-m on θ, phase-1 settings)")[1] == "6"


def test_paper_report_on_synthetic_directory(tmp_path: Path):
    root = _paper_dir(tmp_path / "paper")
    md = write_paper_report(root, simulate=False, gifs=False)
    assert md == (root / "report.md").read_text()
    summary = json.loads((root / "paper_summary.json").read_text())
    t = _row(md, "Manual Tuned")
    assert t[1:] == ["6.000", "8.96", "–", "13.81"]                  # a1-jump has no rows
    assert _row(md, "Phase 1")[1:3] == ["5.000 (6 evals)", "5.96"]
    assert _row(md, "Phase 3 even")[1] == "4.500 (4 evals)"
    assert _row(md, "Phase 3 uneven")[1] == "6.200 (2 evals)"
    assert _row(md, "Phase 3 cross-task")[1:3] == ["–", "9.61"]       # study not in paper.json
    assert _row(md, "(extra) Manual Tuned on hills")[1] == "6.400"
    # baselines: strict "evals to beat manual" (the CMA-ES and phase-1 prefixes start at 6.0)
    assert _row(md, "CMA-ES on θ") == ["CMA-ES on θ", "4", "5.200", "3/4", "2"]
    assert _row(md, "phase 1's first 4 evaluations (TuRBO-m on θ, phase-1 settings)")[1:] == \
        ["4", "5.500", "3/4", "4"]
    assert _row(md, "phase 3: TuRBO-m in the latent space (ours)")[-1] == "3"
    assert summary["baselines"]["trot"]["rows"]["cma"]["evals_to_beat_manual"] == 2
    # transfer: B1 trot ran, B1 jump did not
    assert _row(md, "B1 trot")[1:] == ["8.500", "8.000", "3", "2", "2", "33.41"]
    assert _row(md, "B1 jump")[1:4] == ["–", "–", "0"]
    assert summary["table"]["trot"]["phase1"]["ours"] == 5.0
    assert "- A1 trot: phase 1 beats the manual θ: **holds** (5.000 vs manual 6.000)" in md
    assert "- A1 jump: phase 1 beats the manual θ: not run" in md
    assert "- VAE stable-preservation rate ≥ 95 %: not run (–)" in md
    assert "| a1-jump | tune jump | not run | – |" in md
    assert "| a1-trot | tune trot | 1 / 6 / 4 | 15 |" in md
    for f in ("best_so_far_trot.png", "best_so_far_transfer.png", "cost_transform.png"):
        assert (root / f).stat().st_size > 1000 and f"]({f})" in md, f
    assert not (root / "best_so_far_jump.png").exists()
    assert not list(root.glob("com_velocity_*.png")) and not list(root.glob("*.gif"))


GOOD_META = ('{"robot": "a1", "budgets": {"scale": 1, "phase1": 1, "phase3": 1, "preservation": 1, '
             '"baselines": 1}}')


@pytest.mark.parametrize("text, expect", [
    ("{}", "is not a latentune paper run's record (no robot)"),
    ("[1]", "is not a latentune paper run's record (not a JSON object)"),
    ('{"robot": "atlas"}', "(robot 'atlas', not a1 or solo12)"),
    ('{"robot": "a1", "budgets": {}}', "(no budgets"),
    ('{"robot": "a1", "budgets": {"scale": 1, "phase1": 1, "phase3": 1, "preservation": 1, '
     '"baselines": 1}}', "(no studies)"),
    ("nope", "is not JSON (Expecting value"),
    # hand-edited records of a run: were a ValueError/TypeError/AttributeError traceback, or
    # a study read outside the directory
    ('{"robot": "a1", "budgets": {"scale": "big", "phase1": 1, "phase3": 1, "preservation": 1, '
     '"baselines": 1}, "studies": {}}', "(no budgets"),
    (GOOD_META[:-1] + ', "studies": {"../../x": {"kind": "tune"}}}', "(study '../../x': not a"),
    (GOOD_META[:-1] + ', "studies": {"a1-trot": {"row": "trot"}}}', "(study 'a1-trot': not a"),
    (GOOD_META[:-1] + ', "studies": {}, "seeds": "x"}', "(seed or seeds not an integer)"),
    (GOOD_META[:-1] + ', "studies": {}, "invocations": "x"}', "(invocations not a list"),
    (GOOD_META[:-1] + ', "studies": {}, "invocations": [null]}', "(invocations not a list"),
    (GOOD_META[:-1] + ', "studies": {}, "wall_s_total": "x"}', "(wall_s_total not a number)"),
])
def test_report_of_a_directory_whose_paper_json_is_not_a_paper_runs(tmp_path: Path, run_cli,
                                                                    error_line, text, expect):
    """``latentune report DIR`` with a DIR/paper.json that is no paper run's record: one line
    naming the file (was a KeyError or JSONDecodeError traceback)."""
    (tmp_path / "paper.json").write_text(text)
    with pytest.raises(UsageError, match=re.escape(f"{tmp_path / 'paper.json'} ")):
        write_paper_report(tmp_path, simulate=False)
    code, _, err = run_cli("report", tmp_path, "--no-sim")
    line = error_line(code, err)
    assert str(tmp_path / "paper.json") in line and expect in line
    assert not (tmp_path / "report.md").exists()


def test_phase3_label_names_the_strategy():
    from latentune.constants import Phase
    from latentune.reporting.run_report import phase_label

    assert phase_label(Phase.PHASE3, {"phase3": {"strategy": "transfer"}}).startswith(
        "phase 3 (transfer")
    assert phase_label(Phase.PHASE3, {"phase3": {"strategy": "plain", "method": "cma"}}) == \
        "phase 3 (latent, CMA-ES)"
    assert phase_label(Phase.PHASE3, {"phase3": {"method": "turbo", "handover": {"tol": 0.01}}}) \
        == "phase 3 (latent, TuRBO-m, hand-over)"


def test_report_and_status_name_the_explore_asks_the_targets_gp_chose(tmp_path: Path):
    """A decision of an explore ask the target's own GP chose (``explore_gp``) reads
    ``explore (lines, target GP)`` in the report's table and status's counts, and the screen's
    bound of an explore ask (``explore_bound``) has its column; other asks leave it empty."""
    from latentune.pipeline.phases import state_key
    from latentune.pipeline.results import decision_kind, decisions_summary
    from latentune.reporting.run_report import decisions_markdown

    ds = [{"generation": 0, "n_told": 1, "design": True, "agreement": 0.5, "length": 0.5},
          {"generation": 1, "n_told": 2, "explore": True, "explore_pool": "latent",
           "explore_bound": 0.2, "agreement": 0.4, "length": 0.5},
          {"generation": 3, "n_told": 4, "explore": True, "explore_pool": "lines",
           "explore_gp": True, "explore_bound": 0.3, "agreement": 0.3, "length": 0.25}]
    assert [decision_kind(d) for d in ds] == ["design", "explore (latent)",
                                              "explore (lines, target GP)"]
    assert [decision_kind({"explore": False, "region_gp": g}) for g in (True, False)] == \
        ["region (target GP)", "region"]
    walk = {"generation": 2, "n_told": 4, "design": True, "walk_rank": 75,
            "rule": "the source's top fell: a θ deeper in its record"}
    assert decision_kind(walk) == "record walk"       # a rule ask, not the design
    assert decision_kind({"explore": False, "record_cma": True, "pools": ["global"]}) == \
        "record CMA-ES", "a CMA-ES draw is not the trust region's ask"
    with RunStore(tmp_path / "w", create=True) as st:
        st.set_meta(state_key(Phase.PHASE3), {"decisions": [ds[0], walk]})
        assert "| 2 | 4 | record walk (rank 75) |" in "\n".join(decisions_markdown(st))
    with RunStore(tmp_path / "r", create=True) as st:
        st.set_meta(state_key(Phase.PHASE3), {"decisions": ds})
        md = decisions_markdown(st)
        assert decisions_summary(ds)["kinds"] == {"design": 1, "explore (latent)": 1,
                                                  "explore (lines, target GP)": 1}
    header, rows = md[4], md[6:9]
    cells = [r.split(" | ") for r in rows]
    col = header.split(" | ").index("explore screen")
    assert [c[col] for c in cells] == ["–", "0.20", "0.30"]
    assert cells[2][2] == "explore (lines, target GP)"


def test_comparison_table_leaves_out_phases_a_phase3_run_never_had(tmp_path: Path):
    """A phase 3 on another study's latent space (a robot run of ask/tell) runs no manual θ and
    no phase 1: its table showed them as rows of zeros; a run still in phase 1 keeps its empty
    phase-3 row (still to come), and a phase 3 asked only its zero-shot trial keeps its own."""
    with RunStore(tmp_path / "robot", create=True) as st:
        st.set_meta("config", {"system": {"kind": "user"}, "phase3": {"strategy": "transfer"}})
        st.add(Phase.ZERO_SHOT, 0, np.ones(3), 3.2, fell=False, tag=-1)
        md = comparison_table(st)
        assert "manual tuned" not in md and "phase 1 (" not in md
        assert _row(md, "phase 3 (transfer: source model, latent and θ boxes)")[2] == "0"
        st.add(Phase.PHASE3, 0, np.zeros(3), 1.0, fell=False, tag=-1)
        md = comparison_table(st)
    assert "manual tuned" not in md and "phase 1 (" not in md
    assert _row(md, "phase 3 (transfer: source model, latent and θ boxes)")[1:3] == ["1.000", "1"]
    with RunStore(tmp_path / "running", create=True) as st:
        st.set_meta("config", {"system": {"kind": "user"}, "vae": {"d_low": 2}})
        st.add(Phase.MANUAL, 0, np.zeros(3), 2.5, fell=False, tag=-1)
        md = comparison_table(st)
    assert _row(md, "phase 1 (θ, TuRBO-m)")[2] == "0" and _row(md, "phase 3")[2] == "0"


def test_a_phase1_run_shows_no_phase3_row(tmp_path: Path, run_cli):
    """``latentune phase1 --out D`` then ``latentune report D`` showed an empty "phase 3 | – |
    0" row, as if phase 3 had failed or were to come, though a phase-1 run is complete: its
    table has the manual and phase-1 rows; the phase-3 row (still to come) appears once the
    run holds a latent space, as in a ``tune`` run that stopped before phase 3."""
    d = tmp_path / "run"
    code, _, err = run_cli("phase1", "--system", "examples.toy_plant:make_system", "--out", d,
                           "--phase1-evals", "4", "--backend", "serial", "--quiet")
    assert code == 0, err
    code, out, err = run_cli("report", d, "--no-sim", "--quiet")
    assert code == 0, err
    assert "| phase 3" not in out and "| phase 3" not in (d / "report.md").read_text(), out
    assert _row(out, "phase 1 (θ, TuRBO-m)")[2] == "4"
    with RunStore(d) as st:
        st.set_meta("config", dict(st.get_meta("config"), vae={"d_low": 2}))
        assert _row(comparison_table(st), "phase 3")[2] == "0"


def test_summary_names_a_phase_s_best_file_only_when_it_holds_the_best_theta(
        stopped_after_a_better_trial):
    """A phase run stopped (Ctrl-C) after a better trial than its earlier best, before it
    wrote phase1_best.json: summary.json gave "phase1_best": 0.0655 beside
    "phase1_best_params": "phase1_best.json", a file of the earlier best θ (0.153). The file
    is named only while it holds the phase's best θ (``latentune best`` writes the θ to
    deploy)."""
    import latentune as lt

    d, _ = stopped_after_a_better_trial
    with lt.Study(d) as s:
        summary = s.summary()
    assert summary["phase1_best"] == 0.0 and summary["phase1_best_params"] is None, summary


def test_the_beat_note_says_where_an_ask_tell_manual_trial_was_told(tmp_path: Path, run_cli):
    """The note under the table said "Phase 1's first evaluation is the manual θ's trial" in
    an ask/tell study whose manual suggestion was told third (evaluations count in the order
    told): it names the evaluation the manual θ's trial is there; a phase run's stays."""
    import latentune as lt

    space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
    d = tmp_path / "at"
    with lt.Study(d, seed=0) as st:
        s1, s2, s3 = st.ask(3, space=space)
        st.tell(s2.id, 0.1)
        st.tell(s3.id, 0.9)
        st.tell(s1.id, 0.36)
        make_report(st.store, simulate=False, quiet=True)
    md = (d / "report.md").read_text()
    assert "Phase 1's first evaluation is the manual θ's trial" not in md, md
    assert "Phase 1's evaluation 3 (in the order told) is the manual θ's trial" in md, md
    run = tmp_path / "run"
    with lt.Study(run, seed=0) as st:
        st.phase1(lt.FunctionSystem(space, lambda x: float(np.sum(x))), 3, method="random")
        make_report(st.store, simulate=False, quiet=True)
    assert "Phase 1's first evaluation is the manual θ's trial" in (run / "report.md").read_text()


def test_the_wall_time_of_a_short_phase_is_not_rounded_to_0_s(tmp_path: Path):
    """A phase of cheap trials that took 0.46 s was reported as "Wall time: phase3 0 s" (whole
    seconds), as if it took no time; under 10 s the report gives a tenth of a second."""
    cfg = {"system": {"kind": "python", "class": "mymod.Arm"}, "phase1": {"method": "turbo"},
           "vae": {"latent_dim": 2}}
    with _store(tmp_path / "run", cfg) as st:
        st.set_meta("wall", {"phase1": 12.4, "phase3": 0.46, "vae": 3.0})
        make_report(st, simulate=False, quiet=True)
    md = (tmp_path / "run" / "report.md").read_text()
    assert "Wall time: phase1 12 s, phase3 0.5 s, vae 3 s." in md, md


def test_a_tune_run_stopped_before_phase3_says_phase3_is_to_come(tmp_path: Path, run_cli):
    """A ``tune`` run stopped (Ctrl-C) while it trained its latent space holds phase 1 and the
    plan of its phase 3, but no latent space and no phase-3 record: ``latentune report``
    showed the table and lines of a finished ``phase1`` run, nothing of the 30 phase-3 trials
    still to come. Its table now has the empty phase-3 row, and a line says phase 3 has not
    started, how many trials it plans and the command that goes on."""
    d = tmp_path / "run"
    code, _, err = run_cli("phase1", "--system", "examples.toy_plant:make_system", "--out", d,
                           "--phase1-evals", "4", "--backend", "serial", "--quiet")
    assert code == 0, err
    with RunStore(d) as st:         # as tune records its plan before phase 1 runs
        st.set_meta("config", dict(st.get_meta("config"), command="tune",
                                   tune={"phase3_evals": 30}))
    code, out, err = run_cli("report", d, "--no-sim", "--quiet")
    assert code == 0, err
    assert _row(out, "phase 3")[1:3] == ["–", "0"], out
    md = (d / "report.md").read_text()
    assert ("Phase 3 has not started: the tune run plans 30 trials. If it stopped, the command "
            f"that ran it goes on: `latentune tune … --out {d} --resume` (it trains the latent "
            "space, then runs phase 3).") in md, md
    with RunStore(d) as st:         # its latent space trained: phase 3 alone is to come
        st.set_meta("config", dict(st.get_meta("config"), vae={"d_low": 2}))
        lines = state_lines(st, st.get_meta("config"))
    assert any("`latentune tune … --out" in ln and "(it runs phase 3)" in ln for ln in lines)
    with RunStore(d) as st:         # every phase-1 trial fell: no latent space can be trained
        cfg = dict(st.get_meta("config"))
        cfg.pop("vae")
        st.con.execute("UPDATE evaluations SET fell=1")
        st.con.commit()
        lines = state_lines(st, cfg)
    assert any("plans 30 trials; its latent space needs at least 2 phase-1 trials that did not "
               "fail and phase 1 holds 0, so more phase-1 trials come first:" in ln and
               "--phase1-evals N` (N above 4)" in ln for ln in lines), lines


def test_a_phase3_not_started_is_not_labelled_with_a_strategy(tmp_path: Path, run_cli):
    """``latentune report`` on a run stopped after phase 2 (a ``tune`` before phase 3) labelled
    its empty phase-3 row "phase 3 (latent, TuRBO-m)", the plain strategy, although a phase 3
    started later runs the transfer one by default: the strategy is chosen when phase 3
    starts, so the row is "phase 3" until then, and names the strategy of the stored record
    after."""
    import latentune as lt
    from examples.toy_plant import make_system

    d = tmp_path / "run"
    with lt.Study(d, seed=0) as st:
        st.phase1(make_system(), 6)
        st.train_latent(latent_dim=2, epochs=2)
    code, _, err = run_cli("report", d, "--quiet")
    assert code == 0, err
    md = (d / "report.md").read_text()
    assert "| phase 3 | – | 0 | – | – |" in md and "phase 3 (" not in md, md
    with RunStore(d) as st:
        st.set_meta("config", dict(st.get_meta("config"), phase3={"strategy": "transfer"}))
        assert _row(comparison_table(st), "phase 3 (transfer: source model, latent and θ "
                                          "boxes)")[2] == "0"
        st.set_meta("config", dict(st.get_meta("config"), phase3={"strategy": "plain"}))
        assert _row(comparison_table(st), "phase 3 (latent, TuRBO-m)")[2] == "0"


def test_an_asktell_store_shows_only_the_phases_it_runs(tmp_path: Path, run_cli):
    """``latentune report`` on an ask/tell phase-1 study with nothing told showed a "manual
    tuned | – | 0" row (and an empty phase-3 row), though ask/tell never stores a separate
    manual trial (the manual θ is phase 1's first suggestion) and runs phase 3 in another
    directory; an ask/tell phase 3 with nothing told showed empty manual and phase-1 rows.
    Now an ask/tell store's table has the rows of the phases it runs, and of any that hold
    trials."""
    import latentune as lt
    from examples.toy_plant import make_system

    d = tmp_path / "asktell"
    lt.Study(d, seed=0).ask(1, system=make_system())
    code, out, err = run_cli("report", d, "--no-sim", "--quiet")
    assert code == 0, err
    assert "manual tuned" not in out and "| phase 3" not in out, out
    assert _row(out, "phase 1 (θ, TuRBO-m)")[2] == "0"
    with RunStore(tmp_path / "robot", create=True) as st:
        st.set_meta("config", {"system": {"kind": "user"}, "asktell": {"phase": 3},
                               "phase3": {"strategy": "transfer"}})
        md = comparison_table(st)
        assert "manual tuned" not in md and "phase 1 (" not in md, md
        assert _row(md, "phase 3 (transfer: source model, latent and θ boxes)")[2] == "0"
        st.add(Phase.MANUAL, 0, np.zeros(3), 2.5, fell=False, tag=-1)  # a phase run's, later
        assert _row(comparison_table(st), "manual tuned")[2] == "1"


def test_an_asktell_reports_manual_theta_is_the_same_in_summary_table_and_figure(
        tmp_path: Path, monkeypatch):
    """The manual θ of an ask/tell phase 1 (its first suggestion, :func:`manual_rows`) is found
    once per report and handed to the summary, the table and the best-cost figure: each shows
    the same manual trial, here one that failed (a trial that stood beats it, whatever the
    costs); a first suggestion that is not the manual θ gives no manual trial anywhere."""
    import latentune as lt
    from latentune.reporting import plots

    space = lt.ParameterSpace(names=["kp", "kd"], low=[0.1, 0.0], high=[10.0, 1.0],
                              manual=[2.0, 0.5])
    refs: list[dict] = []
    draw = plots.plot_best_so_far
    monkeypatch.setattr(plots, "plot_best_so_far", lambda panels, path, title="": (
        refs.extend(p.refs for p in panels), draw(panels, path, title=title)))
    for start in ("manual", "scratch"):
        refs.clear()
        with lt.Study(tmp_path / start, seed=0) as st:
            sugg = st.ask(3, space=space, start=start)
            st.tell(sugg[0].id, None, failed=True)
            st.tell(sugg[1].id, 3.0)
            st.tell(sugg[2].id, 0.5)
            table = make_report(st.store, simulate=False, quiet=True)
            first = st.store.rows(Phase.PHASE1)[0].cost
        s = json.loads((tmp_path / start / "summary.json").read_text())
        md = (tmp_path / start / "report.md").read_text()
        assert table in md
        assert _row(table, "phase 1 (θ, TuRBO-m)") == [
            "phase 1 (θ, TuRBO-m)", "0.500", "3", "2/3", "2" if start == "manual" else "–"]
        if start == "manual":
            assert _row(table, "manual tuned") == ["manual tuned", "–", "1", "0/1", "–"]
            assert (s["manual_cost"], s["manual_fell"]) == (first, True)
            assert s["phase1_evals_to_beat_manual"] == 2
            assert refs == [{"manual θ, fell": first}]
        else:
            assert "manual tuned" not in md
            assert (s["manual_cost"], s["manual_fell"]) == (None, None)
            assert s["phase1_evals_to_beat_manual"] is None
            assert refs == [{"manual θ": None}]


def test_a_phase_stopped_short_of_its_budget_says_what_goes_on(tmp_path: Path, run_cli):
    """A ``tune`` stopped in phase 1 stores what a ``phase1`` does, and its report said only
    "Phase 1 … holds N trials of its budget of B.", not how to go on: the line names the
    commands that run the phase with ``--resume`` on the directory (a tune run's goes on to
    phase 3), the study's method for a system made in Python; a phase 3 whose fall budget is
    spent says it asks no more; an ask/tell run (it goes on with ``ask``) gets no such hint."""
    import shlex

    import latentune as lt
    from examples.toy_plant import make_system
    from latentune.reporting.run_report import state_lines
    from latentune.system import load_system

    d = tmp_path / "run"
    with lt.Study(d, seed=0) as st:      # stopped after 3 of its 10 trials
        st.phase1(load_system("examples.toy_plant:make_system"), 10, max_new=3)
    code, _, err = run_cli("report", d, "--no-sim", "--quiet")
    assert code == 0, err
    where = shlex.quote(str(d))
    assert ("Phase 1 (θ, TuRBO-m) holds 3 trials of its budget of 10. If it stopped, the "
            f"command that ran it goes on: `latentune tune … --out {where} --resume` (a tune "
            "run: it then trains the latent space and runs phase 3) or `latentune phase1 … "
            f"--out {where} --resume`.") in (d / "report.md").read_text()
    with lt.Study(tmp_path / "py", seed=0) as st:
        st.phase1(make_system(), 10, max_new=3)
        assert state_lines(st.store, st.config())[0].endswith(
            f" If it stopped, `Study({str(tmp_path / 'py')!r}).phase1(system, budget)` with the "
            "same system goes on.")
    with RunStore(tmp_path / "falls", create=True) as st:
        cfg = {"system": {"kind": "plugin"}, "phase3": {
            "strategy": "transfer", "budget": 10, "transfer_options": {"fall_budget": 0.2}}}
        st.set_meta("config", cfg)
        for i, fell in enumerate([False, True, True, True]):
            st.add(Phase.PHASE3, i, np.zeros(3), 200.0 if fell else 1.0, fell=fell, tag=-1)
        assert state_lines(st, cfg)[0] == (
            "Phase 3 (transfer: source model, latent and θ boxes) holds 4 trials of its budget "
            "of 10. Its fall budget is spent (3 falls counted, 2 allowed): it asks no more.")
    with RunStore(tmp_path / "p1p3", create=True) as st:     # phase1, then phase3: phase3
        cfg = {"system": {"kind": "plugin"}, "command": "phase1",
               "phase3": {"strategy": "transfer", "budget": 10}}
        st.add(Phase.PHASE3, 0, np.zeros(3), 1.0, fell=False, tag=-1)
        assert state_lines(st, cfg)[0].endswith(
            "If it stopped, the command that ran it goes on: `latentune phase3 … --out "
            f"{shlex.quote(str(tmp_path / 'p1p3'))} --resume`.")
    with RunStore(tmp_path / "asktell", create=True) as st:
        cfg = {"system": {"kind": "plugin"}, "asktell": {"phase": 1}, "phase1": {"budget": 4}}
        st.add(Phase.PHASE1, 0, np.zeros(3), 1.0, fell=False, tag=-1)
        assert state_lines(st, cfg)[0] == "Phase 1 (θ, TuRBO-m) holds 1 trial of its budget of 4."


def _legends(monkeypatch) -> list[list[str]]:
    """Patch Figure.savefig to record, per figure saved, its legends' texts and x labels."""
    from matplotlib.figure import Figure

    seen: list[list[str]] = []
    save = Figure.savefig

    def record(fig, *a, **k):
        seen.append([t.get_text() for ax in fig.axes if ax.get_legend() is not None
                     for t in ax.get_legend().get_texts()] + [ax.get_xlabel() for ax in fig.axes])
        return save(fig, *a, **k)

    monkeypatch.setattr(Figure, "savefig", record)
    return seen


def test_the_best_cost_figure_numbers_evaluations_as_status_does(tmp_path: Path, monkeypatch,
                                                                  run_cli):
    """status, best and tell number a phase's evaluations from 0 (the store's idx); the
    best-cost figure's legend counted from 1 ("evaluation 3" in status, "best … at 4" in the
    figure). The figure numbers them as status does."""
    import latentune as lt

    space = lt.ParameterSpace(names=["kp", "kd"], low=[0.1, 0.0], high=[10.0, 1.0],
                              manual=[2.0, 0.5])
    seen = _legends(monkeypatch)
    d = tmp_path / "run"
    with lt.Study(d, seed=0) as st:
        for s, c in zip(st.ask(5, space=space), [4.0, 3.0, 5.0, 0.5, 2.0]):
            st.tell(s.id, c)
        idx = st.status()["phases"]["phase 1"]["best_idx"]
        make_report(st.store, simulate=False, quiet=True)
    code, out, _ = run_cli("status", d)
    assert code == 0 and f"evaluation {idx}," in out
    assert idx == 3
    texts = seen[-1]
    assert any(t.endswith(f": best 0.500 at {idx}, 0 fell") for t in texts), texts
    assert "evaluation (0–4)" in texts, texts


def test_summary_has_no_wall_time_of_this_command(tmp_path: Path, run_cli):
    """summary.json held ``wall_s_this_command``, always null: no command passed it a time, and
    the summary is rewritten by whichever command ran last (a tell, a report), so it would
    not be the tuning's time anyway; the run's times are ``wall_s`` and ``wall_by_phase_s``."""
    import latentune as lt

    space = lt.ParameterSpace(names=["kp"], low=[0.0], high=[1.0], manual=[0.5])
    d = tmp_path / "run"
    with lt.Study(d, seed=0) as st:
        (s,) = st.ask(1, space=space)
    assert run_cli("tell", d, s.id, "--cost", "2.0")[0] == 0
    told = json.loads((d / "summary.json").read_text())
    assert run_cli("report", d, "--no-sim")[0] == 0
    reported = json.loads((d / "summary.json").read_text())
    for summ in (told, reported):
        assert "wall_s_this_command" not in summ and "wall_s" in summ and "wall_by_phase_s" in summ


def test_the_best_cost_figure_says_the_manual_theta_fell(tmp_path: Path, monkeypatch):
    """A manual θ that fell was drawn as the reference line "manual θ (200.000)", as if 200
    were a cost to beat; its legend entry says it fell. One that stood keeps "manual θ (C)"."""
    seen = _legends(monkeypatch)
    for fell in (True, False):
        with RunStore(tmp_path / f"run{fell}", create=True) as st:
            st.set_meta("config", {"system": {"kind": "user"}})
            st.add(Phase.MANUAL, 0, np.zeros(3), 200.0 if fell else 6.0, fell=fell, tag=-1)
            _fill(st, Phase.PHASE1, [7.0, 5.0])
            make_report(st, simulate=False, quiet=True)
        texts = seen[-1]
        assert ("manual θ, fell (200.000)" in texts) == fell, texts
        assert ("manual θ (6.000)" in texts) == (not fell), texts


def test_the_best_cost_figure_says_the_zero_shot_trial_fell(tmp_path: Path, monkeypatch):
    """A zero-shot trial that fell was drawn in phase 3's panel as the reference line
    "zero-shot (source best θ) (200.000)", as if 200 were a cost to beat (the manual θ's line
    says it fell); its legend entry says it fell too. One that stood keeps its cost."""
    seen = _legends(monkeypatch)
    for fell in (True, False):
        with RunStore(tmp_path / f"run{fell}", create=True) as st:
            st.set_meta("config", {"system": {"kind": "user"}, "phase3": {"strategy": "transfer"}})
            st.add(Phase.ZERO_SHOT, 0, np.zeros(3), 200.0 if fell else 6.0, fell=fell, tag=-1)
            _fill(st, Phase.PHASE3, [7.0, 5.0])
            make_report(st, simulate=False, quiet=True)
        texts = seen[-1]
        assert ("zero-shot (source best θ), fell (200.000)" in texts) == fell, texts
        assert ("zero-shot (source best θ) (6.000)" in texts) == (not fell), texts


def test_the_best_cost_axis_of_a_panel_where_no_trial_stood_names_its_scale(
        tmp_path: Path, monkeypatch):
    """Where no trial of a phase stood, the best-so-far axis shows only the reference lines
    on a log axis (ticks 0.1, 0.2, 0.5, 1), yet its label said "best cost so far (linear,
    zoomed)". The label names the scale drawn: log there, linear and zoomed where a trial
    stood."""
    from matplotlib.figure import Figure

    labels: list[str] = []
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (
        labels.append(fig.axes[1].get_ylabel()), save(fig, *a, **k))[1])
    for stood in (False, True):
        with RunStore(tmp_path / f"run{stood}", create=True) as st:
            st.set_meta("config", {"system": {"kind": "user"}})
            st.add(Phase.MANUAL, 0, np.zeros(3), 0.36, fell=True, tag=-1)
            st.add(Phase.PHASE1, 0, np.zeros(3), 0.36, fell=True, tag=-1)
            st.add(Phase.PHASE1, 1, np.ones(3), 3.0, fell=not stood, tag=-1)
            make_report(st, simulate=False, quiet=True)
        assert labels[-1] == ("best cost so far (linear, zoomed)" if stood
                              else "best cost so far (log)"), labels
    from latentune.reporting.plots import CurvePanel, plot_best_so_far

    shown: list = []                 # two columns: the second's own scale is named too
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: shown.append(
        [ax.get_ylabel() for ax in fig.axes[2:]]))
    plot_best_so_far([CurvePanel("a", {"a": [2.0, 1.0]}, {"m": 3.0}),
                      CurvePanel("b", {"b": [5.0, 4.0]}, {"m": 3.0}, {"b": [True, True]})],
                     tmp_path / "two.png")
    assert shown == [["best cost so far (linear, zoomed)", "best cost so far (log)"]]


@pytest.mark.parametrize("manual_fell", [False, True])
def test_evals_to_beat_manual_counts_the_phases_own_trials_from_1_in_every_report(
        tmp_path: Path, manual_fell: bool):
    """"Evals to beat manual" counts a phase's own evaluations from 1: phase 1's first is the
    manual θ's trial (it never beats itself), phase 3's leaves the manual and zero-shot trials
    out, a failed trial never beats it and any trial that stood beats a failed manual θ. The
    paper report's ``study_stats`` counted a failed trial's cost and had no count against a
    failed manual θ (None: "not beaten"); the summary, the table and it now agree, and the
    report says how it counts."""
    from latentune.reporting.paper_report import study_stats

    man = 200.0 if manual_fell else 6.0
    with RunStore(tmp_path / "run", create=True) as st:
        st.set_meta("config", {"system": {"kind": "user"},
                               "phase3": {"strategy": "plain", "budget": 3}})
        st.add(Phase.MANUAL, 0, np.zeros(3), man, fell=manual_fell, tag=-1)
        for i, (c, f) in enumerate([(man, manual_fell), (1.0, True), (5.0, False)]):
            st.add(Phase.PHASE1, i, np.full(3, 0.1 * i), c, fell=f, tag=-1)
        st.add(Phase.ZERO_SHOT, 0, np.ones(3), 4.0, fell=False, tag=-1)   # not counted below
        for i, (c, f) in enumerate([(0.5, True), (7.0, False), (5.5, False)]):
            st.add(Phase.PHASE3, i, np.full(3, 0.2 * i), c, fell=f, tag=-1)
        summ = write_summary(st)
        md = comparison_table(st)
    paper = study_stats(tmp_path / "run")
    p3 = 2 if manual_fell else 3
    assert (summ["phase1_evals_to_beat_manual"], summ["phase3_evals_to_beat_manual"]) == (3, p3)
    assert (paper["phase1"]["evals_to_beat_manual"],
            paper["phase3"]["evals_to_beat_manual"]) == (3, p3)
    assert _row(md, "phase 1 (θ, TuRBO-m)")[-1] == "3"
    assert _row(md, "phase 3 (latent, TuRBO-m)")[-1] == str(p3)
    assert _row(md, "zero-shot (source best θ)")[-1] == "1"
    with RunStore(tmp_path / "run") as st:
        make_report(st, simulate=False)
    md = (tmp_path / "run" / "report.md").read_text()
    assert "\nEvals to beat manual: the first of the phase's own evaluations, counted from 1, " \
        in md and "phase 3's count leaves out the manual and zero-shot trials." in md


def test_status_and_report_say_the_agreement_is_not_measured_on_constant_costs(tmp_path,
                                                                             run_cli):
    """A constant source and a constant target: ``status`` said "agreement 1.00", the prior,
    which the data cannot move. status and report now say "agreement not measured (the
    target's costs do not vary)"; a bowl's agreement is still a number."""
    import latentune as lt

    sp = lt.ParameterSpace(["a", "b", "c", "d"], [0] * 4, [1] * 4, manual=[0.5] * 4)
    flat = lt.FunctionSystem(sp, lambda x: 1.0)
    bowl = lt.FunctionSystem(sp, lambda x: float(((x - 0.3) ** 2).sum()))
    for name, fs in (("flat", flat), ("bowl", bowl)):
        with lt.Study(tmp_path / name, seed=0) as st:
            st.phase1(fs, 10)
            st.train_latent(latent_dim=2, epochs=5)
            st.phase3(fs, 4)
    code, out, err = run_cli("status", tmp_path / "flat")
    assert code == 0 and "agreement not measured (the target's costs do not vary)" in out, out
    assert "agreement 1.00" not in out
    assert run_cli("report", tmp_path / "flat")[0] == 0
    md = (tmp_path / "flat" / "report.md").read_text()
    assert "| not measured (the target's costs do not vary) |" in md
    code, out, err = run_cli("status", tmp_path / "bowl")
    assert code == 0 and re.search(r"agreement -?\d\.\d\d", out) and "not measured" not in out, out


def test_best_so_far_figure_of_costs_near_1e290_lays_out(tmp_path):
    """Costs near 1e290 (a manual θ's reference among them): the legend wrote them with 3
    decimals, 294-character labels, and matplotlib's "Tight layout not applied" reached the
    user's stderr as a latentune warning, the figure crushed. The labels now give 4 significant
    digits above 1e6 (the best's own cost, not the drawn 1e6), and the layout warns nothing."""
    import warnings

    costs = 1e290 * (1.0 + np.linspace(1.0, 0.1, 8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_best_so_far([CurvePanel("phase 1", {"p1": costs}, {"manual θ": 3e290}),
                          CurvePanel("phase 3", {"p3": costs[:4]})], tmp_path / "h.png")
    assert (tmp_path / "h.png").stat().st_size > 0
