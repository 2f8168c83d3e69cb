"""benchmarks.robot_transfer: the rung registry, the source snapshots and the run files (on a
tiny user system, not on a robot)."""
from __future__ import annotations

import math
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from benchmarks import robot_transfer as rt
from benchmarks import transfer as tr
from examples.toy_plant import make_real_system, make_system

A1_TASK = {"robot": "a1", "gait": "trot", "terrain": "flat", "actor": "convex",
           "v_des": [0.5, 0.0, 0.0], "steps": 5000, "seed": 0, "dim": 25}
SOLO_TASK = {**A1_TASK, "robot": "solo12", "actor": "kinodynamic", "dim": 77}


def test_registry_names_sources_and_changes():
    reg = rt.rungs()
    for R in ("a1", "solo12"):
        for g in ("trot", "jump"):
            for kind in ("heavy", "hard", "mujoco"):
                r = reg[f"{R}-{g}-{kind}"]
                assert (r.robot, r.source) == (R, f"{R}-{g}")
        cross = reg[f"{R}-jump-from-trot"]
        assert (cross.source, cross.change) == (f"{R}-trot", {"gait": "jump"})
    assert reg["b1-trot-from-a1"].source == "a1-trot"
    assert reg["b1-jump-from-a1"].source == "a1-jump"
    assert (reg["b1-jump-from-a1-trot"].source, reg["b1-jump-from-a1-trot"].change) == (
        "a1-trot", {"robot": "b1", "gait": "jump"})
    assert not any(n.startswith("b1") for n in rt.rungs(["solo12"]))
    assert len(reg) == 17


def test_rung_targets_are_the_source_task_with_the_change():
    reg = rt.rungs()
    heavy = reg["a1-trot-heavy"].target(A1_TASK)
    assert heavy.reality.name == "heavy" and not heavy.reality.is_nominal
    assert (heavy.robot_name, heavy.gait, heavy.engine, heavy.steps) == ("a1", "trot",
                                                                          "pybullet", 5000)
    hard = reg["a1-trot-hard"].target(A1_TASK)
    assert hard.reality.name == "hard" and hard.reality.to_dict() != heavy.reality.to_dict()
    mj = reg["a1-trot-mujoco"].target(A1_TASK)
    assert mj.engine == "mujoco" and mj.reality.is_nominal
    jump = reg["solo12-jump-from-trot"].target(SOLO_TASK)
    assert (jump.robot_name, jump.gait, jump.actor) == ("solo12", "jump", "kinodynamic")
    b1 = reg["b1-trot-from-a1"].target({**A1_TASK, "spec": {"stale": True}})
    assert b1.robot_name == "b1" and list(b1.space.names) == list(heavy.space.names)


def test_select_refuses_unknown_and_foreign_rungs():
    assert [r.name for r in rt.select(["a1"], ["a1-trot-heavy"])] == ["a1-trot-heavy"]
    assert len(rt.select(["solo12"], None)) == 7
    with pytest.raises(rt.RobotTransferError, match="unknown target"):
        rt.select(["a1"], ["a1-trot-windy"])
    with pytest.raises(rt.RobotTransferError, match="rung of solo12"):
        rt.select(["a1"], ["solo12-trot-hard"])
    with pytest.raises(rt.RobotTransferError, match="unknown robot"):
        rt.rungs(["go1"])


@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Path:
    """A source study of the toy plant, phase 1 only (as the paper's sources-only runs)."""
    d = tmp_path_factory.mktemp("live") / "toy"
    with lt.Study(d, seed=3, batch_size=4) as st:
        st.phase1(make_system(steps=60), 40, max_new=16)
    return d


@pytest.fixture(scope="module")
def live_before(live, dump_store) -> tuple[list[tuple], list[tuple]]:
    """The rows and meta of ``live`` before any snapshot of it was taken."""
    return dump_store(live)


@pytest.fixture(scope="module")
def taken(live, live_before, tmp_path_factory) -> Path:
    """One snapshot of ``live`` (its latent space trained once for the module)."""
    return rt.snapshot(live, tmp_path_factory.mktemp("taken") / "sources" / "toy")


def _copy_of(snap: Path, root: Path) -> Path:
    """A copy of the snapshot ``snap`` under ``root/sources/toy/``, as ``rt.snapshot`` would
    have taken it there."""
    return Path(shutil.copytree(snap, root / "sources" / "toy" / snap.name))


def test_snapshot_copies_without_touching_the_live_store(live, live_before, taken, dump_store):
    before, snap = live_before, taken
    dest = snap.parent
    assert snap == dest / "n16"
    assert dump_store(live) == before                       # the live store is unchanged
    assert not (live / "vae.pt").exists()                   # the latent space lives in the copy
    rows, _ = dump_store(snap)
    assert rows == before[0]
    info = rt.snapshot_info(snap)
    assert (info["n_trials"], info["n_phase1"], info["n_phase3"]) == (16, 16, 0)
    assert info["seed"] == 3 and info["vae"]["from"] == "trained here"
    assert info["from"] == str(live.resolve())
    ls = lt.LatentSpace.load(snap / "vae")
    assert ls.d == make_system().space.dim
    assert rt.snapshot(live, dest) == snap                  # not grown: the same snapshot
    assert rt.snapshots(dest) == [snap]
    assert not list(dest.glob(".taking-*"))


def test_snapshot_of_a_grown_source_is_a_new_one(live, taken, tmp_path):
    live = Path(shutil.copytree(live, tmp_path / "live" / "toy"))
    dest = tmp_path / "sources" / "toy"
    first = _copy_of(taken, tmp_path)               # the snapshot of the source's first 16
    assert rt.snapshot(live, dest) == first         # trials, taken already: reused
    (dest / "n99").mkdir()                                  # unfinished: no snapshot.json
    with lt.Study(live) as st:
        st.phase1(make_system(steps=60), 40, max_new=4)
    second = rt.snapshot(live, dest)
    assert second.name == "n20" and rt.snapshots(dest) == [first, second]
    root = tmp_path
    assert rt.source_dir(Path("unused"), root, "x", "toy") == second
    assert rt.source_dir(Path("unused"), root, "x", "toy", trials=16) == first
    with pytest.raises(rt.RobotTransferError, match="no snapshot of toy with 5 trials"):
        rt.source_dir(Path("unused"), root, "x", "toy", trials=5)
    with pytest.raises(rt.RobotTransferError, match="no source run"):
        rt.snapshot(tmp_path / "nowhere", tmp_path / "sources" / "nowhere")


def test_snapshot_takes_the_source_latent_space_when_it_has_one(tmp_path):
    live = tmp_path / "live"
    with lt.Study(live, seed=1, batch_size=4) as st:
        st.phase1(make_system(steps=60), 12)
        mine = st.train_latent()
    snap = rt.snapshot(live, tmp_path / "sources" / "live")
    assert rt.snapshot_info(snap)["vae"]["from"] == "source"
    z = np.full((1, mine.d), 0.5)
    np.testing.assert_allclose(lt.LatentSpace.load(snap / "vae").encode(z), mine.encode(z))


def test_run_files_record_the_source_size_and_resume(taken, tmp_path, monkeypatch):
    snap = _copy_of(taken, tmp_path)
    n = rt.snapshot_info(snap)["n_trials"]
    target = make_real_system(steps=60)
    for m in ("zero_shot", "turbo_source"):
        for seed in (0, 1):
            res = rt.run_one("toy-real", target, snap, m, seed, 3, tmp_path)
            assert res is not None
    f = rt.result_path(tmp_path, "toy-real", n, 0, "turbo_source")
    r = json.loads(f.read_text())
    assert (r["source"], r["source_trials"], r["budget"], r["method"]) == ("toy", n, 3,
                                                                          "turbo_source")
    assert len(r["costs"]) == len(r["failed"]) == len(r["thetas"]) == 3
    assert r["target_config"]["name"] == "real"
    out = target.evaluate(np.array(r["thetas"][1]))            # the θ recorded is the one run
    assert out.failed == r["failed"][1]
    if not out.failed:
        assert out.cost == pytest.approx(r["costs"][1])
    assert rt.run_one("toy-real", target, snap, "turbo_source", 0, 3, tmp_path) is None
    s = rt.summarize(tmp_path)
    (row,) = s["targets"]
    assert (row["target"], row["source"], row["source_trials"]) == ("toy-real", "toy", n)
    assert row["seeds"] == [0, 1] and set(row["methods"]) == {"zero_shot", "turbo_source"}
    assert row["best_peer"] in ("zero_shot", "turbo_source")
    assert row["beats_zero_shot"] is None           # 2 seeds: no p can be below 0.05
    assert "toy-real (source toy" in rt.markdown(s)
    assert "No method beats" not in rt.markdown(s)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    assert rt.main(["summary", "--root", str(tmp_path)]) == 0       # prints, writes nothing
    assert not any(cwd.rglob("*"))
    out = tmp_path / "out" / "ladder.json"
    assert rt.main(["summary", "--root", str(tmp_path), "--out", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["targets"][0]["source_trials"] == n
    assert "benchmarks.robot_transfer summary" in written["provenance"]["command"]
    assert out.with_suffix(".md").read_text().startswith("`")


def test_plot_com_draws_every_rollout(tmp_path):
    class Res:
        def __init__(self, cost: float, k: float) -> None:
            t = np.linspace(0.001, 1.0, 50)
            self.cost, self.trace = cost, {"t": t, "pos": np.c_[k * t, 0 * t, 0.3 + 0 * t]}

    f = tmp_path / "com.png"
    rt.plot_com({"a": Res(1.0, 0.5), "b": Res(2.0, 0.4)}, f, "toy")
    assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ladder_summary_keeps_its_rows(tmp_path):
    """The generalized benchmarks.transfer.summarize reads the cheap ladder's files as before."""
    for m, costs in (("zero_shot", [3.0]), ("tpe", [4.0, 2.0]), ("transfer", [2.5, 1.0])):
        for s in (0, 1):
            f = tmp_path / "arm" / "gap1" / f"seed{s}" / f"{m}.json"
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(json.dumps({"system": "arm", "gap": 1.0, "seed": s, "method": m,
                                     "budget": 2, "costs": costs,
                                     "failed": [False] * len(costs)}))
    (row,) = tr.summarize(tmp_path)["targets"]
    assert (row["system"], row["gap"], row["best_peer"]) == ("arm", 1.0, "tpe")
    assert row["methods"]["transfer"]["trials_to_best_peer"] == 2
    assert "### arm gap 1 (2 seeds; best peer: tpe)" in tr.markdown({"targets": [row]})


def test_command_line_refuses_bad_input(capsys):
    assert rt.main(["run", "--robots", "solo12", "--targets", "a1-trot-heavy"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m benchmarks.robot_transfer: error: target 'a1-trot-heavy' is a "
                   "rung of a1, not of solo12"]
    assert rt.main(["snapshot", "--sources", "a1-walk", "--robots", "a1"]) == 2
    assert "unknown source 'a1-walk'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        rt.main(["run", "--budget", "0"])


def test_variants_run_as_transfer_with_their_options_seed_by_seed(monkeypatch, tmp_path):
    """``run --variants``: each variant is a job ``transfer+VARIANT`` carrying its options; every
    rung has a seed's jobs before the next seed's."""
    done: list[tuple] = []
    monkeypatch.setattr(rt, "source_dir", lambda *a, **k: tmp_path)
    monkeypatch.setattr(rt, "build_target", lambda rung, src: None)
    monkeypatch.setattr(rt, "snapshot_info", lambda src: {"n_trials": 5})
    monkeypatch.setattr(tr, "source_hypers", lambda src, seed: None)
    monkeypatch.setattr(rt, "_job", lambda j: done.append((j[0].name, j[3], j[2], j[6])) or "")
    a = rt.parser().parse_args(["run", "--robots", "a1", "--targets", "b1-trot-from-a1",
                                "a1-jump-from-trot", "--methods", "tpe", "--seeds", "0", "1",
                                "--variants", "explore_every=2", "--root", str(tmp_path)])
    rt.run(a)
    v = ("transfer+explore_every=2", {"explore_every": 2})
    assert done == [(r, s, *m) for s in (0, 1) for r in ("b1-trot-from-a1", "a1-jump-from-trot")
                    for m in (("tpe", None), v)]
    forward = list(done)
    done.clear()
    rt.run(rt.parser().parse_args(["run", "--robots", "a1", "--targets", "b1-trot-from-a1",
                                   "a1-jump-from-trot", "--methods", "tpe", "--seeds", "0", "1",
                                   "--variants", "explore_every=2", "--root", str(tmp_path),
                                   "--reverse"]))
    assert done == forward[::-1]
    assert rt.main(["run", "--robots", "a1", "--targets", "b1-trot-from-a1", "--root",
                    str(tmp_path), "--variants", "no_such_option=1"]) == 2


def test_a_variant_is_stored_under_its_name_and_summarized_beside_the_peers(taken, tmp_path,
                                                                              monkeypatch):
    snap = _copy_of(taken, tmp_path)
    calls: list[tuple] = []

    def fake(method, target, src, B, seed, options=None):
        calls.append((method, options))
        n = 1 if method == "zero_shot" else B           # the zero-shot θ is tried once
        return {"costs": [3.0 - (method == "transfer")] * n, "failed": [False] * n}

    monkeypatch.setattr(tr, "run_method", fake)
    target = make_real_system(steps=60)
    for seed in (0, 1):
        for m, o in (("zero_shot", None), ("tpe", None),
                     ("transfer+explore_every=2", {"explore_every": 2})):
            rt.run_one("toy-real", target, snap, m, seed, 2, tmp_path, options=o)
    assert calls[2] == ("transfer", {"explore_every": 2})
    n = rt.snapshot_info(snap)["n_trials"]
    r = json.loads(rt.result_path(tmp_path, "toy-real", n, 0, "transfer+explore_every=2")
                   .read_text())
    assert r["method"] == "transfer+explore_every=2" and r["options"] == {"explore_every": 2}
    (row,) = rt.summarize(tmp_path)["targets"]
    assert row["best_peer"] in ("zero_shot", "tpe")
    assert row["methods"]["transfer+explore_every=2"]["median_best"] == 2.0
    assert "| transfer+explore_every=2 | 2 |" in rt.markdown({"targets": [row]})


def test_cost_checks_count_non_finite_costs_and_separate_falls(tmp_path):
    for m, costs, failed in (("tpe", [4.0, 150.0, float("nan")], [False, True, False]),
                             ("transfer", [5.0, 3.0, 3.0], [False, False, False])):
        f = rt.result_path(tmp_path, "b1-trot-from-a1", 7, 0, m)
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps({"target": "b1-trot-from-a1", "source": "a1-trot",
                                 "source_trials": 7, "seed": 0, "method": m, "budget": 3,
                                 "costs": costs, "failed": failed}))
    c = rt.cost_checks(tmp_path)[("b1-trot-from-a1", 7)]
    assert c == {"trials": 6, "non_finite": 1, "falls": 1, "fall_cost_min": 150.0,
                 "standing_cost_max": 5.0}
    (row,) = rt.summarize(tmp_path)["targets"]
    assert row["cost_check"] == c
    assert "1 non-finite costs, 1 falls (fall costs ≥ 150" in rt.markdown({"targets": [row]})


def test_summary_counts_explore_asks_and_bests_they_found(tmp_path):
    """Decision i asks trial i + 2; seed 0's best is trial 3 (an explore ask), seed 1's trial 2."""
    dec = [{"pools": ["full"], "explore": False}, {"pools": ["latent"], "explore": True}]
    for m, runs in (("tpe", [[3.0, 3.0, 3.0]] * 2),
                    ("transfer+explore_every=2", [[4.0, 3.5, 1.0], [4.0, 1.0, 2.0]])):
        for s, costs in enumerate(runs):
            f = tmp_path / "arm" / "gap1" / f"seed{s}" / f"{m}.json"
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(json.dumps({"system": "arm", "gap": 1.0, "seed": s, "method": m,
                                     "budget": 3, "costs": costs, "failed": [False] * 3,
                                     **({"decisions": dec} if m != "tpe" else {})}))
    (row,) = tr.summarize(tmp_path)["targets"]
    assert row["methods"]["transfer+explore_every=2"]["explore_picks"] == {
        "median": 1.0, "max": 1, "seeds_best_from_explore": 1}
    assert "explore_picks" not in row["methods"]["tpe"]


def test_summary_reads_only_the_methods_targets_and_seeds_asked(tmp_path):
    for t in ("b1-trot-from-a1", "a1-trot-hard"):
        for m in ("tpe", "transfer", "transfer+explore_every=2"):
            for s in (0, 1, 2):
                if m == "transfer+explore_every=2" and s > 0:
                    continue            # a partial method would cut every method to seed 0
                f = rt.result_path(tmp_path, t, 7, s, m)
                f.parent.mkdir(parents=True, exist_ok=True)
                f.write_text(json.dumps({"target": t, "source": "a1-trot", "source_trials": 7,
                                         "seed": s, "method": m, "budget": 2,
                                         "costs": [5.0, 4.0 - s], "failed": [False, True]}))
    assert [r["seeds"] for r in rt.summarize(tmp_path)["targets"]] == [[0], [0]]
    (row,) = rt.summarize(tmp_path, ["tpe", "transfer"], ["b1-trot-from-a1"], [1, 2])["targets"]
    assert row["target"] == "b1-trot-from-a1" and row["seeds"] == [1, 2]
    assert set(row["methods"]) == {"tpe", "transfer"}
    assert row["cost_check"]["trials"] == 8 and row["cost_check"]["falls"] == 4


def test_overview_lines_up_the_default_against_the_best_peer():
    def m(med: float, falls: float, reach: float = math.inf) -> dict:
        return {"median_best": med, "falls_median": falls, "trials_to_best_peer": reach}

    crit = {"no_worse": False, "mannwhitney_p": 0.008, "reach_le_B10": False,
            "reach_le_B2": True, "falls_ok": True}
    s = {"targets": [
        {"target": "r1", "seeds": [0, 1, 2, 3, 4], "best_peer": "tpe",
         "methods": {"tpe": m(20.0, 8), "transfer": m(21.0, 1, 40)}, "criteria": crit,
         "peer_at_default_falls": {"method": "tpe", "median": 23.5}},
        {"target": "r2", "seeds": [0], "best_peer": "tpe", "methods": {"tpe": m(1.0, 0)}}]}
    text = rt.overview(s)
    (line,) = [x for x in text.splitlines() if x.startswith("| r1 ")]
    assert "tpe: 20 / 8" in line and "21 (0.01) / 1" in line and "+5.0 %" in line
    assert line.endswith("| +5.0 % | 23.5 (tpe) | 40 | ✗ | ✗ ✓ | ✓ |")
    assert "| r2 " not in text                      # no default judged there
    assert "Of 1 rungs: (1) no worse on 0; (2) ≤ B/10 on 0, ≤ B/2 on 1; (3) falls on 1." in text
    assert "no two-sided p" not in text
    s["targets"][0]["seeds"] = [0, 1, 2]
    assert "With 3 seeds no two-sided p is below 0.05" in rt.overview(s)
    assert rt.overview({"targets": []}) == ""


def test_decisions_reads_what_the_default_did(tmp_path, capsys):
    """``decisions``: per rung and seed, the share of trust-region asks at the floor side, of
    asks the fall screen nearly emptied, the explore asks and their falls, the falls by pool."""
    dec = [{"design": True, "pools": ["elite"], "length": 0.5, "n_admissible": 16,
            "n_candidates": 16},
           {"explore": True, "pools": ["latent"], "length": 0.5, "n_admissible": 10,
            "n_candidates": 1000, "max_fall_prob_asked": 0.25},
           {"pools": ["full"], "length": 1 / 128, "n_admissible": 900, "n_candidates": 1000,
            "max_fall_prob_asked": 0.05},
           {"pools": ["full"], "length": 0.25, "n_admissible": 800, "n_candidates": 1000,
            "max_fall_prob_asked": 0.3}]
    run = {"target": "r", "method": "transfer", "seed": 0, "costs": [9.0, 8.0, 150.0, 7.0, 150.0],
           "failed": [False, False, True, False, True], "decisions": dec}
    f = rt.result_path(tmp_path, "r", 5, 0, "transfer")
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps(run))
    other = rt.result_path(tmp_path, "r", 5, 0, "tpe")
    other.write_text(json.dumps({**run, "method": "tpe", "decisions": []}))
    s = rt.decision_stats(run)
    assert s == {"n_asks": 3, "floor_share": 0.5, "screened_share": 1 / 3, "explore_asks": 1,
                 "explore_falls": 1, "falls_by_pool": {"explore": 1, "full": 1},
                 "distinct_acted": 0,
                 # [asks, falls, records]: trial 1 (8 < 9) and trial 3 (7 < 8) are records
                 "by_kind": {"design": [1, 0, 1], "explore latent": [1, 1, 0],
                             "full": [2, 1, 1]},
                 "by_screen": {"design": {"?": [1, 0, 1]},
                               "explore latent": {"0.2–0.3": [1, 1, 0]},
                               "full": {"0–0.1": [1, 0, 1], "0.3–1": [1, 1, 0]}}}
    # with the θ: the two region asks by step from the best standing θ before them (trial 3:
    # 0.02 from trial 1, stood; trial 4: 0.38 from trial 3, fell)
    th = [[0.1, 0.1], [0.5, 0.5], [0.0, 1.0], [0.52, 0.5], [0.9, 0.5]]
    assert rt.decision_stats({**run, "thetas": th})["region_steps"] == [[1, 0], [0, 0], [1, 1]]
    dec[3]["repeats_avoided"] = 1                       # an ask whose choice distinct changed
    assert rt.decision_stats(run)["distinct_acted"] == 1
    dec[3].pop("repeats_avoided")
    restored = rt.result_path(tmp_path, "r", 5, 1, "transfer")     # no records: left out
    restored.parent.mkdir(parents=True)
    restored.write_text(json.dumps({k: v for k, v in run.items() if k != "decisions"}))
    out = tmp_path / "d.json"
    assert rt.main(["decisions", "--root", str(tmp_path), "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert list(d["targets"]) == ["r"] and d["targets"]["r"]["median"]["floor_share"] == 0.5
    assert list(d["targets"]["r"]["seeds"]) == ["0"] and d["without_records"] == 1
    assert "1 runs without decision records" in out.with_suffix(".md").read_text()
    text = capsys.readouterr().out
    assert "| r | 1 | 50 % | 33 % | 1 / 1 | explore 1, full 1 |" in text
    assert d["by_kind"] == {"design": [1, 0, 1], "explore latent": [1, 1, 0], "full": [2, 1, 1]}
    assert "| r | 0 / 1 | 1 / 1 | 1 / 2 |" in text
    assert "| full | 2, 1 fell, 1 rec. | 1, 0, 1 | – | – | – | 1, 1, 0 |" in text
    assert rt.main(["decisions", "--root", str(tmp_path), "--out", str(out),
                    "--method", "plain"]) == 2


def test_min_mannwhitney_p_matches_scipy_at_its_extreme():
    from scipy.stats import mannwhitneyu

    for n in (2, 3, 4, 5):
        lo, hi = list(range(n)), list(range(10, 10 + n))
        for two in (False, True):
            p = mannwhitneyu(lo, hi, alternative="two-sided" if two else "less",
                             method="exact").pvalue
            assert rt.min_mannwhitney_p(n, two) == pytest.approx(p)
    assert rt.min_mannwhitney_p(3, True) >= 0.05 > rt.min_mannwhitney_p(4, True)


def test_compare_counts_wins_per_rung_and_refuses_an_empty_pair(tmp_path, capsys):
    best = {("r1", 0): (3.0, 5.0), ("r1", 1): (4.0, 4.0), ("r2", 0): (9.0, 2.0)}
    for (t, s), (ca, cb) in best.items():
        for m, c in (("transfer+x=1", ca), ("transfer", cb)):
            f = rt.result_path(tmp_path, t, 5, s, m)
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(json.dumps({"target": t, "seed": s, "method": m, "costs": [10.0, c],
                                     "failed": [m == "transfer", False]}))
    out = tmp_path / "c.json"
    assert rt.main(["compare", "--root", str(tmp_path), "--a", "transfer+x=1", "--b", "transfer",
                    "--out", str(out)]) == 0
    (row,) = json.loads(out.read_text())["rows"]
    assert (row["wins"], row["ties"], row["losses"], row["falls_a"], row["falls_b"]) == \
        (1, 1, 1, 0, 3)
    assert row["by_target"]["r1 src5"] == {"wins": 1, "ties": 1, "losses": 0, "falls_a": 0,
                                           "falls_b": 2, "median_a": 3.5, "median_b": 4.5,
                                           "ratio": 3.5 / 4.5,
                                           "paired_ratio": pytest.approx((3 / 5) ** 0.5)}
    assert row["ratio_worst"] == {"target": "r2 src5", "ratio": 4.5}
    assert "1 wins, 1 ties, 1 losses of 3" in capsys.readouterr().out
    assert rt.main(["compare", "--root", str(tmp_path), "--a", "tpe", "--b", "transfer"]) == 2
    assert "holds both methods" in capsys.readouterr().err


def test_export_keeps_costs_falls_and_best_theta_and_restore_rebuilds_the_runs(tmp_path, capsys):
    for s, m in ((1, "tpe"), (0, "transfer"), (0, "tpe")):
        f = rt.result_path(tmp_path, "r1", 9, s, m)
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps({"target": "r1", "seed": s, "method": m, "source_trials": 9,
                                 "costs": [2.0, 1.0], "failed": [True, False], "wall_s": 3.0,
                                 "load_start": [1.0], "thetas": [[0.1], [0.2]],
                                 "decisions": [{"pools": ["full"]}]}))
    out = tmp_path / "traces"
    assert rt.main(["export", "--root", str(tmp_path), "--out", str(out)]) == 0
    d = json.loads((out / "r1.json").read_text())
    assert [(r["seed"], r["method"]) for r in d["runs"]] == [(0, "tpe"), (0, "transfer"),
                                                             (1, "tpe")]
    assert d["runs"][0] == {"target": "r1", "seed": 0, "method": "tpe", "source_trials": 9,
                            "costs": [2.0, 1.0], "failed": [True, False], "wall_s": 3.0,
                            "load_start": [1.0], "best_theta": [0.2]}
    assert "machine" in json.loads((out / "export.json").read_text())["provenance"]
    assert rt.main(["export", "--root", str(tmp_path / "none"), "--out", str(out)]) == 2
    assert "no runs under" in capsys.readouterr().err

    # restored: the same runs where run resumes, a stored file kept; then exported the same
    new = tmp_path / "restored"
    kept = rt.result_path(new, "r1", 9, 1, "tpe")
    kept.parent.mkdir(parents=True)
    kept.write_text(json.dumps({"target": "r1", "seed": 1, "method": "tpe", "source_trials": 9,
                                "costs": [5.0], "failed": [False], "thetas": [[0.7]]}))
    assert rt.main(["restore", "--traces", str(out), "--root", str(new)]) == 0
    assert "2 runs restored" in capsys.readouterr().out
    r = json.loads(rt.result_path(new, "r1", 9, 0, "tpe").read_text())
    assert r["costs"] == [2.0, 1.0] and r["best_theta"] == [0.2] and "thetas" not in r
    assert r["restored_from"].endswith("r1.json")
    assert json.loads(kept.read_text())["costs"] == [5.0]
    assert rt._best_theta({0: r, 1: json.loads(kept.read_text())}) == ([0.2], 1.0, 0, 2)
    again = tmp_path / "again"
    assert rt.main(["export", "--root", str(new), "--out", str(again)]) == 0
    runs = json.loads((again / "r1.json").read_text())["runs"]
    assert [r.get("best_theta") for r in runs] == [[0.2], [0.2], [0.7]]
    # a run without θ cannot be plotted, unless another seed's run of equal cost holds it
    del r["best_theta"]
    twin = {**r, "best_theta": [0.3]}
    assert rt._best_theta({0: r, 1: twin})[:3] == ([0.3], 1.0, 1)
    # a directory without traces is refused
    with pytest.raises(rt.RobotTransferError, match="holds no θ"):
        rt._best_theta({0: r})
    assert rt.main(["restore", "--traces", str(tmp_path / "none"), "--root", str(new)]) == 2
    assert "no traces under" in capsys.readouterr().err


def test_summary_and_plot_without_a_peer_are_one_line(tmp_path, capsys):
    """Read without any peer (``--methods transfer``), ``summary`` and ``plot`` cannot judge a
    best peer: one line naming the rung and the methods read, exit 2, nothing written."""
    for s in (0, 1):
        f = rt.result_path(tmp_path, "a1-trot-hard", 5, s, "transfer")
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps({"target": "a1-trot-hard", "source": "a1-trot", "source_trials": 5,
                                 "seed": s, "method": "transfer", "costs": [6.0, 5.0],
                                 "failed": [False, False]}))
    for cmd in (["summary", "--out", str(tmp_path / "s.json")],
                ["plot", "--out", str(tmp_path / "plots")]):
        assert rt.main([*cmd, "--root", str(tmp_path), "--methods", "transfer"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no peer among the methods read" in err[0], err
        assert "'target': 'a1-trot-hard'" in err[0] and "(read: transfer;" in err[0]
    assert not (tmp_path / "s.json").exists() and not (tmp_path / "plots").exists()


def test_summary_and_plot_of_no_runs_are_one_line(tmp_path, capsys):
    """``summary``/``plot`` of a root with no runs (a typo in --root or --targets) printed an
    empty table and exited 0."""
    for cmd in (["summary"], ["plot", "--out", str(tmp_path / "plots")],
                ["summary", "--targets", "a1-trot-hard"]):
        assert rt.main([*cmd, "--root", str(tmp_path / "nowhere")]) == 2, cmd
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no runs under" in err[0], err


def test_import_paper_of_no_paper_run_is_one_line(tmp_path, capsys):
    """import-paper of a directory without paper.json ('[Errno 2] …'), or with a record that
    is no paper run's (imported nothing and exited 0, or a traceback), names the file."""
    (tmp_path / "p").mkdir()
    for text, expect in ((None, "is unreadable"), ('{"robot": "a1", "studies": []}',
                                                  "not a latentune paper run's record")):
        if text is not None:
            (tmp_path / "p" / "paper.json").write_text(text)
        assert rt.main(["import-paper", "--paper-run", str(tmp_path / "p"),
                        "--root", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(tmp_path / "p" / "paper.json") in err[0] and expect in err[0]
    assert not (tmp_path / "r").exists()


def test_plot_trials_resimulates_the_trials_of_one_run(tmp_path, capsys, monkeypatch):
    """``plot --trials``: the θ of the given trials of one run re-simulated, each labelled with
    the kind of ask that asked it and its stored outcome, beside the re-simulated one; a run
    without θ, a trial outside the run and a half-given run are refused in one line."""
    from latentune.task import Task

    class Res:
        def __init__(self, theta: np.ndarray) -> None:
            t = np.linspace(0.001, 1.0, 20)
            self.cost, self.fell = float(10 * theta[0]), bool(theta[0] > 0.5)
            self.reason = "tilt above 60 deg" if self.fell else ""
            self.trace = {"t": t, "pos": np.c_[t, 0 * t, 0.3 + 0 * t],
                          "vel": np.c_[0 * t + 0.4, 0 * t, 0 * t], "height": 0.3 + 0 * t}

    class FakeTask:
        v_des = np.array([0.5])

        def rollout(self, theta, record=False, gif=None):
            assert record
            return Res(np.asarray(theta))

    monkeypatch.setattr(Task, "from_config", staticmethod(lambda cfg: FakeTask()))
    dec = [{"design": True, "pools": ["elite"]},
           {"explore": True, "explore_pool": "lines", "pools": ["global"]}]
    run = {"target": "r", "method": "transfer+x=1", "seed": 3, "costs": [2.0, 1.0, 8.0],
           "failed": [False, False, True], "thetas": [[0.2], [0.1], [0.8]], "decisions": dec,
           "target_config": {}, "label": "toy rung"}
    f = rt.result_path(tmp_path, "r", 5, 3, "transfer+x=1")
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps(run))
    args = ["plot", "--root", str(tmp_path), "--out", str(tmp_path / "p"), "--targets", "r",
            "--methods", "transfer+x=1", "--seed", "3"]
    assert rt.main(args + ["--trials", "1", "2"]) == 0
    d = tmp_path / "p" / "r" / "transfer+x=1_seed3"
    rec = json.loads((d / "plot.json").read_text())
    assert rec["trials"]["1"]["kind"] == "design" and rec["trials"]["2"]["kind"] == "explore lines"
    assert rec["trials"]["2"]["fell"] and rec["trials"]["2"]["resimulated_fell"]
    assert rec["trials"]["2"]["reason"] == "tilt above 60 deg"
    assert rec["trials"]["2"]["resimulated_cost"] == 8.0
    assert (d / "com_xyz.png").read_bytes()[:4] == b"\x89PNG"
    for bad, msg in ((["--trials", "3"], "not in the run"),
                     (["--trials", "1", "--seed", "4"], "no transfer+x=1 run of r seed 4"),
                     (args[:-2] + ["--trials", "1"], "give one --targets")):
        capsys.readouterr()
        assert rt.main((args if bad[0] == "--trials" else []) + bad) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], err
    del run["thetas"]
    f.write_text(json.dumps(run))
    assert rt.main(args + ["--trials", "1"]) == 2
    assert "holds no θ per trial" in capsys.readouterr().err
