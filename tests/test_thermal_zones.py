"""``examples/thermal_zones.py``: the five-room PI system of the transfer ladder's second
held-out family: the manual gains hold the comfort band on every plant, the gap ladder makes θ
that hold it on the model fail more often as the gap grows, failures follow the C1 convention,
bad input is refused."""
from __future__ import annotations

import numpy as np
import pytest

from examples.thermal_zones import N, STEPS, ZonesSystem, make_system


def test_manual_gains_hold_the_band_on_every_plant():
    for g in (0.0, 0.5, 1.0, 2.0):
        s = make_system(g)
        out = s.evaluate(s.space.manual)
        assert not out.failed and 0.3 < out.cost < 2.0, (g, out)
        assert s.config() == {"kind": "thermal_zones", "gap": g, "steps": STEPS}


def test_the_gap_ladder_fails_more_of_the_model_stable_gains():
    X = np.random.default_rng(3).random((40, 4 * N))
    model = make_system(0.0)
    ok = [x for x in X if not model.evaluate(x).failed]
    assert 10 <= len(ok) < len(X)                     # the model itself fails some gains
    share = [np.mean([make_system(g).evaluate(x).failed for x in ok]) for g in (0.5, 1.0, 2.0)]
    assert share[0] < share[1] < share[2] and share[2] > 0.5, share


def test_a_sluggish_controller_fails_when_the_band_starts_to_count():
    s = make_system(0.0)
    theta = np.full(4 * N, 0.5)
    theta[:N] = 0.0                                   # kp at its lowest: 0.05 kW/K
    theta[N:2 * N] = 0.0                              # ki at its lowest
    out = s.evaluate(theta)
    k = out.info["fall_step"]
    assert out.failed and k == 60 and out.cost == pytest.approx(100 * (2 - k / STEPS))


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_bad_gap_is_refused(bad):
    with pytest.raises(ValueError, match="gap must be a finite number"):
        make_system(bad)


def test_gap_ladder_benchmark_counts_what_it_says(capsys):
    """``benchmarks.gap_ladder``: the model-stable θ are those that stand on the model, and
    ``fail_target`` is the share of them that fail at each gap; bad ``--n`` is refused."""
    from benchmarks.gap_ladder import ladder_rows, main

    rows = ladder_rows("zones", 12, 5)
    X = np.random.default_rng(5).random((12, 4 * N))
    stable = [x for x in X if not make_system(0.0).evaluate(x).failed]
    assert [r["gap"] for r in rows] == [0.5, 1.0, 2.0]
    for r in rows:
        assert r["n_model_stable"] == len(stable)
        fails = [make_system(r["gap"]).evaluate(x).failed for x in stable]
        assert r["fail_target"] == pytest.approx(np.mean(fails), abs=1e-3)
    assert main(["--systems", "zones", "--n", "0"]) == 2
    assert "--n must be >= 1" in capsys.readouterr().err


def test_zones_traces_re_runs_the_stored_best_and_draws_it(tmp_path):
    """``benchmarks.zones_traces`` on the committed ladder traces: each method's best θ re-runs
    to its stored cost, the median seed is the default's median, and the figure is written."""
    import json
    from pathlib import Path

    from benchmarks.zones_traces import main, median_seed

    root = Path(__file__).resolve().parents[1] / "results" / "transfer" / "rebuilt" / "runs"
    seed = median_seed(root, 2.0)
    best = sorted(min(json.loads((root / "zones" / "gap2" / f"seed{s}" / "transfer.json")
                          .read_text())["costs"]) for s in range(10))
    ours = min(json.loads((root / "zones" / "gap2" / f"seed{seed}" / "transfer.json")
                          .read_text())["costs"])
    assert ours == best[4]
    png, out = tmp_path / "z.png", tmp_path / "z.json"
    assert main(["--root", str(root), "--gap", "2", "--methods", "transfer", "zero_shot",
                 "--png", str(png), "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["method"] for r in rows] == ["transfer", "zero_shot"] and png.stat().st_size > 10000
    assert rows[1]["failed"] and not rows[0]["failed"]       # the source's best leaves the band
    assert main(["--root", str(tmp_path), "--seed", "0", "--png", str(png)]) == 2  # no run


@pytest.mark.parametrize("rooms", [1, 2, 3])
def test_fewer_rooms_are_the_first_rooms_of_the_row(rooms):
    """``rooms=r``: 4·r gains; room 1 steps to 22 °C, room 2 gets the occupancy gains; the
    manual gains hold the band at every gap; the gap still fails some model-stable gains;
    the five-room system's config is unchanged; bad room counts are refused."""
    s = make_system(0.0, rooms=rooms)
    assert s.space.dim == 4 * rooms and s.config()["rooms"] == rooms
    assert list(s.space.names[:rooms]) == [f"kp_{i + 1}" for i in range(rooms)]
    out, trace = s.simulate(s.space.manual)
    assert not out.failed and trace["temperature"].shape == (STEPS, rooms)
    assert trace["setpoint"][-1, 0] == 22.0 and (rooms < 2 or trace["setpoint"][-1, 1] == 20.0)
    for g in (1.0, 2.0):
        assert not make_system(g, rooms=rooms).evaluate(s.space.manual).failed
    X = np.random.default_rng(0).random((60, 4 * rooms))
    ok = [x for x in X if not s.evaluate(x).failed]
    assert any(make_system(2.0, rooms=rooms).evaluate(x).failed for x in ok)
    assert "rooms" not in make_system(0.0, rooms=N).config()
    for bad in (0, N + 1, 2.5, True):
        with pytest.raises(ValueError, match="rooms must be an integer"):
            ZonesSystem(rooms=bad)


def test_small_theta_benchmark_refuses_bad_sizes(capsys, tmp_path):
    from benchmarks.small_theta import main

    assert main(["--root", str(tmp_path), "--rooms", "5"]) == 2
    assert "--rooms in [1, 4]" in capsys.readouterr().err
    assert main(["--root", str(tmp_path), "--gaps", "0"]) == 2


def test_small_theta_benchmark_pairs_a_run_with_an_earlier_output(capsys, tmp_path):
    """``--against``: this run's ``current`` runs paired with an earlier output's by (rooms,
    gap, seed); the same sources give ties; a different source (first trial's cost) or a file
    that is no output is refused in one line."""
    import json

    from benchmarks.small_theta import main

    args = ["--root", str(tmp_path / "r"), "--rooms", "1", "--gaps", "2", "--seeds", "0",
            "--phase1", "12", "--budget", "3", "--rules", "current"]
    assert main(args + ["--out", str(tmp_path / "a.json")]) == 0
    first = json.loads((tmp_path / "a.json").read_text())
    assert first["rules"] == ["current"] and first["explore_pool"] == "adaptive"
    assert [x["rule"] for x in first["runs"]] == ["current"]
    assert main(args + ["--against", str(tmp_path / "a.json"), "--out",
                        str(tmp_path / "b.json")]) == 0
    ag = json.loads((tmp_path / "b.json").read_text())["against"]
    assert (ag["pairs"], ag["lower"], ag["tie"], ag["higher"]) == (1, 0, 1, 0)
    assert ag["geomean_ratio"] == 1.0 and ag["falls"] == ag["falls_earlier"]
    first["runs"][0]["costs"][0] *= 1.01                    # another source
    (tmp_path / "c.json").write_text(json.dumps(first))
    capsys.readouterr()
    assert main(args + ["--against", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err
    assert "not the same source" in err and err.count("\n") == 1
    assert main(args[:-1] + ["table1", "--against", str(tmp_path / "a.json")]) == 2
    assert "give --rules current" in capsys.readouterr().err
    (tmp_path / "d.json").write_text("[1]")
    assert main(args + ["--against", str(tmp_path / "d.json")]) == 2
    assert "not an output of this benchmark" in capsys.readouterr().err
    # a variant of the default, paired with the default's output, stored beside its runs
    from latentune.constants import Phase
    from latentune.critic.transfer import TRANSFER_DEFAULTS
    from latentune.pipeline.phases import state_key
    from latentune.pipeline.store import RunStore

    kept = dict(TRANSFER_DEFAULTS)
    assert main(args + ["--options", "explore_fall_prob=0.15", "--against",
                        str(tmp_path / "a.json"), "--out", str(tmp_path / "e.json")]) == 0
    out = json.loads((tmp_path / "e.json").read_text())
    assert out["options"] == {"explore_fall_prob": 0.15} and out["against"]["pairs"] == 1
    run = tmp_path / "r" / "r1" / "seed0" / "gap2" / "current+explore_fall_prob=0.15"
    with RunStore(run) as st:         # passed through Study.phase3, recorded, asked with
        assert st.get_meta("config")["phase3"]["transfer_options"] == {"explore_fall_prob": 0.15}
        assert st.get_meta(state_key(Phase.PHASE3))["options"]["explore_fall_prob"] == 0.15
    assert TRANSFER_DEFAULTS == kept                        # nothing patched
    for bad, msg in (("nosuch=1", "unknown option"), ("explore_fall_prob=0.9",
                                                       "explore_fall_prob must be")):
        capsys.readouterr()
        assert main(args + ["--options", bad]) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1


def test_small_theta_pairs_count_lower_ties_and_higher():
    from benchmarks.small_theta import counts, paired

    p = paired([(1.0, 2.0), (2.0, 2.0), (3.0, 1.5), (0.5, 1.0)])
    assert (p["pairs"], p["lower"], p["tie"], p["higher"]) == (4, 2, 1, 1)
    assert p["geomean_ratio"] == pytest.approx((0.5 * 1.0 * 2.0 * 0.5) ** 0.25)
    assert p["sign_p"] == pytest.approx(1.0)
    assert counts([(1.0, 2.0), (2.0, 2.0)]) == "1 / 1 / 0"
    assert paired([])["sign_p"] is None and paired([])["geomean_ratio"] is None
