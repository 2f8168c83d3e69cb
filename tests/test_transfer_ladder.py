"""The transfer ladder's tables (benchmarks.transfer): a variant judged as the default, and the
per-target, per-seed comparison."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from benchmarks import transfer as tr


def _write(root, m: str, seed: int, costs: list[float], failed: list[bool],
           budget: int | None = None) -> None:
    """A stored run of ``m``; its budget: ``budget``, else its trials (a complete run)."""
    f = root / "arm" / "gap1" / f"seed{seed}" / f"{m}.json"
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps({"system": "arm", "gap": 1.0, "seed": seed, "method": m,
                             "budget": len(costs) if budget is None else budget,
                             "costs": costs, "failed": failed}))


def test_summary_judges_a_variant_as_the_default(tmp_path):
    for s in (0, 1, 2):
        _write(tmp_path, "tpe", s, [4.0, 2.0], [False, False])
        _write(tmp_path, "transfer", s, [2.5, 3.0], [False, True])
        _write(tmp_path, "transfer+x=1", s, [2.5, 1.0], [False, False])
    _write(tmp_path, "transfer+y=1", 0, [9.0, 9.0], [False, False])     # seed 0 only
    (row,) = tr.summarize(tmp_path)["targets"]
    assert row["seeds"] == [0]                  # every method's seeds: the screened one limits
    (row,) = tr.summarize(tmp_path, default="transfer+x=1",
                          methods=["tpe", "transfer", "transfer@stored"])["targets"]
    assert row["seeds"] == [0, 1, 2]
    assert row["methods"]["transfer"]["median_best"] == 1.0
    assert row["methods"]["transfer@stored"]["median_best"] == 2.5
    assert row["criteria"]["falls_ok"] and row["methods"]["transfer"]["trials_to_best_peer"] == 2


def test_a_default_that_names_no_stored_run_is_refused(tmp_path, capsys):
    """``transfer summary --default transfer+typo`` read the stored transfer runs as
    ``transfer@stored`` and judged a table without the default, exit 0; a --default no run
    under the root is stored as is refused in one line naming the stored methods, exit 2."""
    for s in (0, 1):
        _write(tmp_path, "tpe", s, [4.0, 2.0], [False, False])
        _write(tmp_path, "transfer", s, [2.5, 3.0], [False, True])
    with pytest.raises(ValueError, match=r"no run of the default method transfer\+typo under "):
        tr.summarize(tmp_path, default="transfer+typo")
    assert tr.main(["summary", "--root", str(tmp_path), "--default", "transfer+typo"]) == 2
    assert capsys.readouterr().err.strip() == (
        "python -m benchmarks.transfer summary: error: no run of the default method "
        f"transfer+typo under {tmp_path} "
        "(--default; the stored methods: tpe, transfer)")


def test_summary_refuses_a_method_with_no_run_beside_others(tmp_path, capsys):
    """``transfer summary --methods transfr tpe`` (a typo beside a stored method) judged the
    table of tpe alone, exit 0, as if transfr had been read; a --methods name no run under the
    root is stored as (after --default and --machine's renamings) is refused in one line naming
    the methods close to it, exit 2."""
    for s in (0, 1):
        _write(tmp_path, "tpe", s, [4.0, 2.0], [False, False])
        _write(tmp_path, "transfer+x=1", s, [2.5, 3.0], [False, True])
        _write(tmp_path, "gp@m2", s, [2.5, 3.0], [False, True])
    assert tr.main(["summary", "--root", str(tmp_path), "--methods", "transfr", "tpe"]) == 2
    assert capsys.readouterr().err == (
        f"python -m benchmarks.transfer summary: error: no run of transfr under {tmp_path} "
        "(--methods; did you mean transfer+x=1?)\n")
    assert tr.main(["summary", "--root", str(tmp_path), "--default", "transfer+x=1",
                    "--machine", "m2", "--methods", "transfer", "tpe", "gp"]) == 0
    assert tr.main(["summary", "--root", str(tmp_path), "--methods", "tpe", "transfer+x=1",
                    "transfer@stored"]) == 0        # as committed commands name it
    capsys.readouterr()

def test_best_at_the_default_falls_cuts_each_seed_at_its_falls(tmp_path):
    """A peer's best is cut before its (k+1)-th fall, k = the default's falls on that seed."""
    assert tr.best_within_falls([9.0, 5.0, 20.0, 1.0], [False, False, True, False], 0) == 5.0
    assert tr.best_within_falls([9.0, 5.0, 20.0, 1.0], [False, False, True, False], 1) == 1.0
    assert tr.best_within_falls([20.0, 1.0], [True, False], 0) == float("inf")
    _write(tmp_path, "tpe", 0, [9.0, 20.0, 1.0], [False, True, False])
    _write(tmp_path, "transfer", 0, [9.0, 3.0, 4.0], [False, False, False])
    _write(tmp_path, "tpe", 1, [9.0, 20.0, 1.0], [False, True, False])
    _write(tmp_path, "transfer", 1, [30.0, 3.0, 4.0], [True, False, False])
    (row,) = tr.summarize(tmp_path)["targets"]
    assert row["methods"]["tpe"]["median_best"] == 1.0
    assert row["methods"]["tpe"]["median_best_at_default_falls"] == 5.0     # median of 9 and 1
    assert row["methods"]["transfer"]["median_best_at_default_falls"] == 3.0
    assert row["peer_at_default_falls"] == {"method": "tpe", "median": 5.0}
    assert "| tpe | 1 | 1–1 | 3 | 1 | 5 |" in tr.markdown({"targets": [row]})


def test_the_fall_allowance_stops_every_method_at_a_quarter_of_the_best_peers_falls(tmp_path):
    """Criterion (3)'s allowance is ⌊peer falls / 4⌋, and 1 where the peer falls ≤ 4 times;
    each method is stopped at its (allowance + 1)-th fall and listed when no worse than the
    best peer's full run."""
    assert [tr.fall_allowance(f) for f in (0, 4, 4.5, 8, 11.5)] == [1, 1, 1, 2, 2]
    many = [True] * 8 + [False]
    for s in range(6):              # tpe: 8 falls, then 1.0; transfer: 2.0 without a fall
        _write(tmp_path, "tpe", s, [50.0] * 8 + [1.0], many)
        _write(tmp_path, "transfer", s, [2.0] * 9, [False] * 9)
        _write(tmp_path, "gp", s, [3.0, 50.0, 50.0, 50.0, 1.5] + [50.0] * 4,
               [False, True, True, True] + [False] * 5)
    (row,) = tr.summarize(tmp_path)["targets"]
    assert row["best_peer"] == "tpe" and row["fall_allowance"] == 2
    m = row["methods"]
    assert m["tpe"]["median_best_within_allowance"] == 50.0      # stopped at its 3rd fall
    assert m["gp"]["median_best_within_allowance"] == 3.0
    assert m["transfer"]["median_best_within_allowance"] == 2.0
    assert row["within_allowance"] == [], "1.0 on every seed is better than all of them"
    assert "stopped at criterion (3)'s allowance (2 falls): lowest transfer 2" in \
        tr.markdown({"targets": [row]})


def test_compare_counts_per_target_and_keeps_the_seeds_asked(tmp_path):
    for s, (a, b) in enumerate([(1.0, 2.0), (3.0, 2.0), (1.0, 2.0)]):
        _write(tmp_path, "a", s, [a], [s == 0])
        _write(tmp_path, "b", s, [b], [False])
    r = tr.compare(tmp_path, "a", "b")
    assert (r["wins"], r["losses"], r["falls_a"]) == (2, 1, 1)
    assert r["by_target"]["arm gap1"] == {"wins": 2, "ties": 0, "losses": 1, "falls_a": 1,
                                          "falls_b": 0, "median_a": 1.0, "median_b": 2.0,
                                          "ratio": 0.5,
                                          "paired_ratio": pytest.approx(0.375 ** (1 / 3))}
    assert r["falls_paired"] == {"more": 1, "fewer": 0, "same": 2, "sign_test_p": 1.0}
    assert "falls 1 vs 0 (more on 1, fewer on 0 of the pairs, sign test p 1.000)" in \
        tr.compare_text([r])
    r = tr.compare(tmp_path, "a", "b", seeds=[1, 2])
    assert (r["pairs"], r["wins"], r["losses"], r["falls_a"]) == (2, 1, 1, 0)
    assert r["falls_paired"] == {"more": 0, "fewer": 0, "same": 2, "sign_test_p": 1.0}
    assert r["by_target"]["arm gap1"]["ratio"] == 1.0                # medians 2 and 2
    assert tr.compare(tmp_path, "a", "b", systems=["arm"])["pairs"] == 3
    assert tr.compare(tmp_path, "a", "b", systems=["chain"])["pairs"] == 0   # only those systems


def test_compare_pairs_the_falls_seed_by_seed(tmp_path):
    """Falls paired per (target, seed): ``a`` falls more on 6 seeds by one and fewer on none,
    a sign test p of 2 / 2^6; the totals alone (6 against 0) say how many, not how often."""
    for s in range(7):
        _write(tmp_path, "a", s, [1.0, 9.0], [False, s > 0])
        _write(tmp_path, "b", s, [1.0, 9.0], [False, False])
    r = tr.compare(tmp_path, "a", "b")
    assert r["falls_paired"]["more"] == 6 and r["falls_paired"]["fewer"] == 0
    assert r["falls_paired"]["same"] == 1
    assert abs(r["falls_paired"]["sign_test_p"] - 2 / 2 ** 6) < 1e-12


def test_compare_weighs_how_much_not_only_how_often(tmp_path):
    """Wins on many targets by a little and a loss on one by much: the sign test sees mostly
    wins, the median ratios' geometric mean and the worst target see the loss."""
    import numpy as np

    def put(target: str, s: int, a: float, b: float) -> None:
        for m, c in (("a", a), ("b", b)):
            f = tmp_path / target / "gap1" / f"seed{s}" / f"{m}.json"
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(json.dumps({"method": m, "costs": [c], "failed": [False]}))

    for s in range(3):
        for t in ("arm", "chain", "hopper"):
            put(t, s, 0.99, 1.0)                       # 1 % better, 9 wins
        put("springs", s, 2.0, 1.0)                    # twice as bad, 3 losses
    r = tr.compare(tmp_path, "a", "b")
    assert (r["wins"], r["losses"]) == (9, 3)
    assert r["ratio_worst"] == {"target": "springs gap1", "ratio": 2.0}
    assert np.isclose(r["ratio_geo_mean"], (0.99 ** 3 * 2.0) ** 0.25)
    text = tr.compare_text([r])
    assert "geometric mean 1.180, worst 2.000 (springs gap1)" in text
    put("zero", 0, 0.0, 1.0)                           # a cost of 0: no ratio, no geometric mean
    r = tr.compare(tmp_path, "a", "b")
    assert r["by_target"]["zero gap1"]["ratio"] is None and r["ratio_geo_mean"] is None
    assert r["by_target"]["zero gap1"]["paired_ratio"] is None and r["paired_geo_mean"] is None


def test_compare_pairs_the_ratios_seed_by_seed(tmp_path):
    """Costs that interleave across seeds: ``a`` ends lower on 4 of 5 seeds, yet its median is
    the higher (1.5 against 1.4); the paired ratio, the geometric mean over the seeds of
    best_a / best_b, is below 1 where the ratio of the medians is above it."""
    import numpy as np

    a = [1.0, 1.1, 1.5, 1.6, 1.9]
    b = [1.2, 1.2, 1.7, 1.8, 1.4]
    for s in range(5):
        _write(tmp_path, "a", s, [a[s]], [False])
        _write(tmp_path, "b", s, [b[s]], [False])
    r = tr.compare(tmp_path, "a", "b")
    t = r["by_target"]["arm gap1"]
    assert (r["wins"], r["losses"]) == (4, 1)
    assert np.isclose(t["ratio"], 1.5 / 1.4) and t["ratio"] > 1
    paired = float(np.exp(np.mean(np.log(np.array(a) / np.array(b)))))
    assert paired < 1
    assert np.isclose(t["paired_ratio"], paired) and np.isclose(r["paired_geo_mean"], paired)
    assert f"paired ratio: geometric mean {paired:.3f}" in tr.compare_text([r])

def test_compare_applies_a_bar_written_before_the_runs(tmp_path, capsys):
    """``compare --bar-*``: each criterion's verdict; a target fails only when its median ratio
    is above the limit *and* the candidate loses on the share of its seeds asked (4 of 5 at
    0.8, not at 0.9); a share outside (0, 1] is refused in one line."""
    a = [1.3, 1.3, 1.3, 1.3, 0.5]          # loses on 4 of 5 seeds; median 1.3 against 1.0
    b = [1.0, 1.0, 1.0, 1.0, 1.0]
    for s in range(5):
        _write(tmp_path, "a", s, [a[s], 9.0], [False, s == 0])
        _write(tmp_path, "b", s, [b[s], 9.0], [False, False])
    r = tr.compare(tmp_path, "a", "b")
    bar = tr.bar_check(r, paired_max=1.0, falls_max=1.1, target=(1.1, 0.8))
    assert not bar["paired_geo_mean"]["pass"] and bar["paired_geo_mean"]["value"] > 1.0
    assert not bar["falls"]["pass"]                       # one fall against none
    assert bar["targets"]["failing"] == ["arm gap1"] and not bar["pass"]
    assert tr.bar_check(r, target=(1.1, 0.9))["pass"]    # 5 of 5 would be needed
    assert tr.bar_check(r, target=(1.4, 0.8))["pass"]    # 1.3 is not above 1.4
    assert tr.bar_check(r, paired_max=1.2)["pass"]
    assert tr.main(["compare", "--root", str(tmp_path), "--a", "a", "--b", "b",
                    "--bar-paired", "1.0", "--bar-target", "1.1", "0.8"]) == 0
    assert "bar: FAILS" in capsys.readouterr().out
    assert tr.main(["compare", "--root", str(tmp_path), "--a", "a", "--b", "b",
                    "--bar-target", "1.1", "4"]) == 2
    err = capsys.readouterr().err
    assert "SHARE must be in (0, 1]" in err and len(err.strip().splitlines()) == 1


def test_transfer_curves_median_best_so_far_with_provenance(tmp_path) -> None:
    """The curves are medians over seeds of the best standing cost so far (falls never count),
    and the outputs name the command that made them."""
    from benchmarks import transfer_curves

    runs = {0: ([5.0, 3.0, 1.0, 4.0], [False, False, True, False]),
            1: ([7.0, 6.0, 2.0, 2.5], [False, False, False, False]),
            2: ([9.0, 1.5, 8.0, 8.0], [True, False, False, False])}
    for s, (c, f) in runs.items():
        _write(tmp_path, "m", s, c, f)
    out, md = tmp_path / "c.json", tmp_path / "c.md"
    assert transfer_curves.main(["--root", str(tmp_path), "--methods", "m", "--at", "1", "2", "4",
                                 "--out", str(out), "--md", str(md)]) == 0
    row = json.loads(out.read_text())["rows"][0]
    # seed 0: 5, 3, 3, 3 (the fall at 1.0 does not count); seed 1: 7, 6, 2, 2; seed 2: ∞, 1.5, ...
    assert (row["trial 1"], row["trial 2"], row["trial 4"]) == (7.0, 3.0, 2.0)
    assert json.loads(out.read_text())["provenance"]["command"].startswith(
        "python -m benchmarks.transfer_curves")
    assert md.read_text().startswith("`python -m benchmarks.transfer_curves")
    assert transfer_curves.main(["--root", str(tmp_path), "--methods", "m", "--at", "5"]) == 2


def test_explore_stats_split_trials_by_ask(tmp_path) -> None:
    """Trials are counted by the ask that made them (zero-shot by none), records are standing
    trials that beat every earlier standing one, and the final best's ask is named."""
    from benchmarks import transfer_explore_stats as es

    dec = [{"n_told": 1, "design": True, "explore": False, "pools": ["elite"], "agreement": 9.0},
           {"n_told": 2, "design": False, "explore": True, "pools": ["latent"], "agreement": 0.2},
           {"n_told": 3, "design": False, "explore": False, "pools": ["full"], "agreement": 0.4},
           {"n_told": 4, "design": False, "explore": True, "pools": ["global"], "agreement": 1.0,
            "explore_pool": "lines"},
           {"n_told": 5, "design": False, "explore": True, "pools": ["global"], "agreement": 1.0,
            "explore_pool": "lines"}]
    _write(tmp_path, "m", 0, [5.0, 6.0, 2.0, 1.0, 1.5, 1.7],
           [False, False, False, True, False, False])
    f = tmp_path / "arm" / "gap1" / "seed0" / "m.json"
    f.write_text(json.dumps({**json.loads(f.read_text()), "decisions": dec}))
    assert es.ask_kinds(json.loads(f.read_text())) == [None, "design", "explore", "region",
                                                       "explore", "explore"]
    out = tmp_path / "s.json"
    assert es.main(["--root", str(tmp_path), "--methods", "m", "--out", str(out)]) == 0
    (row,) = json.loads(out.read_text())["rows"]
    assert (row["design records"], row["explore trials"], row["explore records"]) == (0, 3, 2)
    # per pool: asks (with a record); an explore decision without a pool is the latent box's
    assert row["explore asks by pool"] == "latent 1 (1), lines 2 (1)"
    assert (row["region falls"], row["region records"], row["final best by explore"]) == (1, 0, 1)
    assert row["agreement"] == 0.7                  # of 0.2, 0.4, 1, 1: not the design ask's 9


def test_transfer_same_tells_equal_traces_from_different_ones(tmp_path, capsys) -> None:
    """A method of ``--b`` with no trace at all (a typo) exited 1 with a table of missing runs
    and no word on stderr; it is now one line naming what was not found, and exit 2."""
    from benchmarks import transfer_same

    for s in (0, 1):
        _write(tmp_path, "a", s, [1.0, 2.0], [False, True])
        _write(tmp_path, "b", s, [1.0, 2.0], [False, True])
        _write(tmp_path, "c", s, [1.0, 2.0 if s == 0 else 2.5], [False, True])
    out = tmp_path / "same.json"
    assert transfer_same.main(["--a", f"{tmp_path}:a", "--b", f"{tmp_path}:b",
                               "--out", str(out)]) == 0
    assert json.loads(out.read_text())["same"] == 2
    assert transfer_same.main(["--a", f"{tmp_path}:a", "--b", f"{tmp_path}:c"]) == 1
    capsys.readouterr()
    assert transfer_same.main(["--a", f"{tmp_path}:a", "--b", f"{tmp_path}:missing"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith(
        f"python -m benchmarks.transfer_same: error: no missing.json under {tmp_path} for any "
        f"of the 2 runs of a"), err
    (tmp_path / "arm" / "gap1" / "seed1" / "b.json").unlink()   # one pair missing: differs
    assert transfer_same.main(["--a", f"{tmp_path}:a", "--b", f"{tmp_path}:b"]) == 1
    assert transfer_same.main(["--a", f"{tmp_path}:nothing", "--b", f"{tmp_path}:a"]) == 2
    assert "no nothing.json under" in capsys.readouterr().err


def test_transfer_same_reads_methods_with_colons(tmp_path) -> None:
    """A variant's name holds ``:`` (option separators): ROOT:METHOD splits at the first one."""
    from benchmarks import transfer_same

    _write(tmp_path, "transfer+a=1:b=2", 0, [1.0], [False])
    _write(tmp_path, "transfer", 0, [1.0], [False])
    assert transfer_same.main(["--a", f"{tmp_path}:transfer+a=1:b=2",
                               "--b", f"{tmp_path}:transfer"]) == 0


def test_transfer_same_with_a_tolerance_on_the_robot_layout(tmp_path, capsys) -> None:
    """``--rtol`` admits last-digit differences of costs and θ, never another fall flag; the
    robot ladder's ``targets/<rung>/src<N>/seed<s>`` layout is read as the cheap ladder's."""
    from benchmarks import transfer_same

    for root, c, th in (("a", 5.805038760, [0.1, 0.2]), ("b", 5.805038765, [0.1, 0.2000000001])):
        f = tmp_path / root / "rung" / "src9" / "seed0" / "transfer.json"
        f.parent.mkdir(parents=True)
        f.write_text(json.dumps({"costs": [6.0, c], "failed": [True, False], "thetas": [th, th]}))
    a, b = f"{tmp_path / 'a'}:transfer", f"{tmp_path / 'b'}:transfer"
    assert transfer_same.main(["--a", a, "--b", b]) == 1
    assert transfer_same.main(["--a", a, "--b", b, "--rtol", "1e-8"]) == 0
    assert transfer_same.main(["--a", a, "--b", b, "--rtol", "1e-12"]) == 1
    g = tmp_path / "b" / "rung" / "src9" / "seed0" / "transfer.json"
    g.write_text(json.dumps({**json.loads(g.read_text()), "failed": [False, False]}))
    assert transfer_same.main(["--a", a, "--b", b, "--rtol", "1e-8"]) == 1
    assert transfer_same.main(["--a", a, "--b", b, "--rtol", "-1"]) == 2
    assert "--rtol must be >= 0" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["bowl:0.8", "bowl:-0.1", "bowl:nan", "levy:x", "ring:0.1",
                                  "bowl"])
def test_transfer_variants_refuses_a_problem_it_cannot_build(text):
    import argparse

    from benchmarks import transfer_variants as tv

    assert tv._problem("bowl:0.25") == ("bowl", 0.25) and tv._problem("levy:2") == ("levy", 2.0)
    with pytest.raises(argparse.ArgumentTypeError, match="expected bowl:GAP"):
        tv._problem(text)


def test_coords_give_where_each_method_looked_and_its_best(tmp_path, capsys) -> None:
    """Per coordinate (by name of the arm's space, or index): the median over the seeds of the
    best standing θ's value and of the highest and lowest value asked; a fall is never the
    best; runs without θ are left out."""
    from benchmarks import transfer_coords as tc

    names = tc.coordinate_names("arm")
    g = names.index("grav_1")
    for s, (hi, best_at) in enumerate([(0.9, 0.7), (0.5, 0.3), (0.7, 0.5)]):
        th = [[0.1] * len(names) for _ in range(3)]
        th[0][g], th[1][g], th[2][g] = 0.2, best_at, hi
        _write(tmp_path, "m", s, [3.0, 1.0, 0.5], [False, False, True])
        f = tmp_path / "arm" / "gap1" / f"seed{s}" / "m.json"
        f.write_text(json.dumps({**json.loads(f.read_text()), "thetas": th}))
    out = tmp_path / "c.json"
    assert tc.main(["--root", str(tmp_path), "--methods", "m", "--coords", "grav_1", str(g + 1),
                    "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    (r,) = [r for r in rows if r["coordinate"] == "grav_1"]
    assert (r["seeds"], r["best"], r["max"], r["min"]) == (3, 0.5, 0.7, 0.2)
    assert [r["coordinate"] for r in rows] == ["grav_1", names[g + 1]]
    capsys.readouterr()
    for bad in ("nope", str(len(names))):
        assert tc.main(["--root", str(tmp_path), "--methods", "m", "--coords", "grav_1", bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"arm has no coordinate {bad} " in err[0]
        assert "grav_1," not in err[0].split("(")[0]        # only the unknown one is named
    assert tc.main(["--root", str(tmp_path), "--methods", "other", "--coords", "grav_1"]) == 2
    assert "that ran every method of other" in capsys.readouterr().err
    assert tc.main(["--root", str(tmp_path), "--methods", "m"]) == 2
    assert "give --coords NAME ... or --faces" in capsys.readouterr().err


def test_faces_give_the_share_of_coordinates_on_the_box_faces(tmp_path) -> None:
    """``--faces``: per seed the share of the best standing θ's coordinates within 0.01 of 0 or
    1 and the highest and lowest share among the trials; medians over the seeds."""
    from benchmarks import transfer_coords as tc

    d = len(tc.coordinate_names("arm"))
    for s, k in enumerate((0, d // 2, d)):              # the best θ has k coordinates on a face
        best = [1.0] * k + [0.5] * (d - k)
        th = [[0.5] * d, best, [0.0] * d]               # the last one fell
        _write(tmp_path, "m", s, [2.0, 1.0, 0.5], [False, False, True])
        f = tmp_path / "arm" / "gap1" / f"seed{s}" / "m.json"
        f.write_text(json.dumps({**json.loads(f.read_text()), "thetas": th}))
    out = tmp_path / "f.json"
    assert tc.main(["--root", str(tmp_path), "--methods", "m", "--faces", "--out", str(out)]) == 0
    (r,) = json.loads(out.read_text())["rows"]
    assert r["coordinate"] == tc.FACES and r["seeds"] == 3
    assert (r["best"], r["max"], r["min"]) == (round((d // 2) / d, 3), 1.0, 0.0)


class _Bowl:
    """A 2-gain system: cost = 10·|θ − c|², a fall when θ₀ > ``edge`` (no cost: C1's rule)."""

    def __init__(self, c: float, edge: float) -> None:
        import latentune as lt

        self.space = lt.ParameterSpace(["a", "b"], [0.0, 0.0], [1.0, 1.0], manual=[0.5, 0.5])
        self.c, self.edge = c, edge

    def evaluate(self, theta):
        import latentune as lt

        if theta[0] > self.edge:
            return lt.Outcome(None, failed=True)
        return float(10 * ((theta - self.c) ** 2).sum())


def test_reach_runs_the_sources_best_standing_theta_on_the_target(tmp_path, monkeypatch, capsys):
    """``transfer_reach``: per seed the source's trials that stood, best model cost first, are
    run on the target; the best of the first k (falls excluded), on how many seeds it reaches
    the best peer's median, and the falls among them."""
    import numpy as np

    import latentune as lt
    from benchmarks import transfer_reach as rr
    from latentune.pipeline.baselines import source_trials

    monkeypatch.setitem(tr.SYSTEMS, "bowl", {"model": lambda: _Bowl(0.3, 0.9),
                                             "target": lambda g: _Bowl(0.3 + 0.2 * g, 0.6),
                                             "gaps": (1.0,)})
    for s in (0, 1):
        with lt.Study(tmp_path / "bowl" / f"seed{s}" / "source", seed=s, batch_size=4) as st:
            st.phase1(tr.SYSTEMS["bowl"]["model"](), 12)
    ladder = tmp_path / "ladder.json"
    ladder.write_text(json.dumps({"targets": [{"system": "bowl", "gap": 1.0, "best_peer": "gp",
                                               "methods": {"gp": {"median_best": 0.5}}}]}))
    out = tmp_path / "r.json"
    assert rr.main(["--sources", str(tmp_path), "--ladder", str(ladder), "--systems", "bowl",
                    "--seeds", "0", "1", "2", "--top", "1", "5", "--out", str(out)]) == 0
    (row,) = json.loads(out.read_text())["rows"]
    target = tr.SYSTEMS["bowl"]["target"](1.0)
    best = {1: [], 5: []}
    falls = {1: [], 5: []}
    for s in (0, 1):                                    # seed 2 has no source: left out
        X, y, f = source_trials(tmp_path / "bowl" / f"seed{s}" / "source")
        order = np.flatnonzero(~f)[np.argsort(y[~f], kind="stable")]
        for k in (1, 5):
            fell = [x[0] > 0.6 for x in X[order[:k]]]
            c = [target.evaluate(x) for x, fl in zip(X[order[:k]], fell) if not fl]
            best[k].append(min(c, default=np.inf))
            falls[k].append(sum(fell))
    assert row["seeds"] == 2 and row["best peer"] == "gp" and row["its median"] == 0.5
    for k in (1, 5):
        assert row[f"best_of_top_{k}"] == pytest.approx(float(np.median(best[k])))
        assert row[f"reach_top_{k}"] == sum(b <= 0.5 for b in best[k])
        assert row[f"falls_top_{k}"] == float(np.median(falls[k]))
    assert row["best_of_top_5"] <= row["best_of_top_1"]
    capsys.readouterr()
    assert rr.main(["--sources", str(tmp_path), "--ladder", str(tmp_path / "none.json")]) == 2
    assert capsys.readouterr().err.startswith(
        "python -m benchmarks.transfer_reach: error: no ladder summary")
    assert rr.main(["--sources", str(tmp_path / "empty"), "--ladder", str(ladder),
                    "--systems", "bowl"]) == 2
    assert "no source run under" in capsys.readouterr().err


def test_summary_without_a_peer_is_one_line_not_a_traceback(tmp_path, capsys):
    """The criteria need a best peer: with only latentune's methods read, ``summary`` says so in
    one line (the target and the methods it read) and exits 2, writing nothing."""
    for s in (0, 1):
        _write(tmp_path, "transfer", s, [2.0, 1.0], [False, False])
        _write(tmp_path, "tpe", s, [3.0, 2.0], [False, False])
    out = tmp_path / "s.json"
    assert tr.main(["summary", "--root", str(tmp_path), "--methods", "transfer",
                    "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "python -m benchmarks.transfer summary: error: no peer among the methods read")
    assert "{'system': 'arm', 'gap': 1.0}" in err[0] and "(read: transfer;" in err[0]
    assert not out.exists()
    assert tr.main(["summary", "--root", str(tmp_path), "--out", str(out)]) == 0   # tpe: a peer


def test_ladder_tables_of_a_root_without_runs_are_one_line_and_exit_2(tmp_path, capsys):
    """``summary``, ``compare``, ``transfer_curves``, ``transfer_explore_stats`` and
    ``transfer_escape summary`` of a root with no matching run (a typo, the wrong directory) said nothing or printed an empty table
    and exited 0; each now says so in one line on stderr and exits 2, writing nothing."""
    from benchmarks import transfer_curves, transfer_escape, transfer_explore_stats

    out = tmp_path / "o.json"
    for m, argv in ((tr.main, ["summary", "--root", str(tmp_path), "--out", str(out)]),
                    (tr.main, ["compare", "--root", str(tmp_path), "--a", "transfer", "--b",
                               "tpe", "--out", str(out)]),
                    (transfer_curves.main, ["--root", str(tmp_path), "--methods", "transfer",
                                            "--out", str(out)]),
                    (transfer_explore_stats.main, ["--root", str(tmp_path), "--methods",
                                                   "transfer", "--out", str(out)]),
                    (transfer_escape.main, ["summary", "--root", str(tmp_path), "--out",
                                            str(out)])):
        assert m(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(tmp_path) in err[0], err
        assert not out.exists()
    _write(tmp_path, "transfer", 0, [2.0, 1.0], [False, False])
    _write(tmp_path, "tpe", 0, [3.0, 2.0], [False, False])
    assert tr.main(["summary", "--root", str(tmp_path), "--methods", "gp"]) == 2
    assert "no run of gp under" in capsys.readouterr().err and tr.main(
        ["compare", "--root", str(tmp_path), "--a", "transfer", "--b", "tpe"]) == 0


def test_summary_prints_and_writes_only_where_told(tmp_path, capsys, monkeypatch):
    """``summary`` without ``--out`` prints the tables and writes no file (a committed summary is
    not overwritten by a look at a root); with ``--out`` it writes the JSON and the .md."""
    for s in (0, 1):
        _write(tmp_path, "transfer", s, [2.0, 1.0], [False, False])
        _write(tmp_path, "tpe", s, [3.0, 2.0], [False, False])
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    assert tr.main(["summary", "--root", str(tmp_path)]) == 0
    assert "criteria:" in capsys.readouterr().out
    assert not any(cwd.rglob("*"))
    out = tmp_path / "s.json"
    assert tr.main(["summary", "--root", str(tmp_path), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["targets"] and out.with_suffix(".md").exists()


def test_summary_reads_one_machines_reruns_in_place_of_the_stored_runs(tmp_path):
    """``machine="m2"``: ``tpe@m2`` reads as ``tpe`` and the ``tpe`` beside it is not read; a
    variant with no twin is read as it is; the default may then be judged on the re-runs."""
    for s in (0, 1):
        _write(tmp_path, "tpe", s, [4.0, 2.0], [False, False])
        _write(tmp_path, "tpe@m2", s, [4.0, 3.0], [False, True])
        _write(tmp_path, "transfer", s, [9.0, 9.0], [False, False])
        _write(tmp_path, "transfer@m2", s, [2.5, 2.5], [False, False])
        _write(tmp_path, "transfer+x=1", s, [2.0, 1.0], [False, False])
    (row,) = tr.summarize(tmp_path, machine="m2")["targets"]
    assert set(row["methods"]) == {"tpe", "transfer", "transfer+x=1"}
    assert row["methods"]["tpe"]["median_best"] == 3.0 and row["methods"]["tpe"]["falls_median"] == 1
    assert row["methods"]["transfer"]["median_best"] == 2.5
    (row,) = tr.summarize(tmp_path, machine="m2", default="transfer+x=1",
                          methods=["tpe", "transfer"])["targets"]
    assert row["methods"]["transfer"]["median_best"] == 1.0
    (row,) = tr.summarize(tmp_path, methods=["tpe", "transfer"])["targets"]     # no machine
    assert row["methods"]["tpe"]["median_best"] == 2.0


@pytest.fixture(scope="module")
def chain_source(tmp_path_factory) -> Path:
    """``tr.source_run`` of the chain (seed 0, 16 evaluations), run once for the module."""
    return tr.source_run(tmp_path_factory.mktemp("chain_source"), "chain", 0, 16)


def _source_copy(src: Path, root: Path) -> Path:
    """A copy of the source run ``src`` where ``tr.source_run(root, "chain", 0, …)`` puts it
    (a run may write its caches beside the source)."""
    return Path(shutil.copytree(src, root / "chain" / "seed0" / "source"))


def test_a_stored_method_name_keeps_its_explore_pool_after_the_default_changed(tmp_path,
                                                                                monkeypatch,
                                                                                chain_source):
    """``transfer`` runs the critic with the explore pool and the explore asks of its stored
    runs (``LADDER_BASE``: the pool of the default before session 32, the explore asks of the
    default before session 39), ``transfer+explore_pool=adaptive`` the default of sessions
    32–38 and ``…:explore_gp=true:explore_fall_prob=0.2`` today's; any other option leaves the
    base."""
    import latentune.critic.transfer as ct

    src = _source_copy(chain_source, tmp_path)
    made: list[dict] = []

    class Stop(Exception):
        pass

    def capture(*args, **kw):
        made.append(kw)
        raise Stop

    monkeypatch.setattr(ct, "Transfer", capture)
    assert tr.DEFAULT_METHOD == \
        "transfer+explore_pool=adaptive:explore_gp=true:explore_fall_prob=0.2"
    today = tr.parse_variant(tr.DEFAULT_METHOD.partition("+")[2])
    for opts in (None, {"explore_pool": "adaptive"}, {"distinct": True}, today):
        with pytest.raises(Stop):
            tr.run_method("transfer", tr.SYSTEMS["chain"]["target"](1.0), src, 4, 0, opts)
    assert [(m["explore_pool"], m["explore_gp"], m["explore_fall_prob"]) for m in made] == [
        ("latent", False, 0.0), ("adaptive", False, 0.0), ("latent", False, 0.0),
        ("adaptive", True, 0.2)]
    assert ct.resolved_options({k: made[-1][k] for k in ("explore_pool", "explore_gp",
                                                         "explore_fall_prob")}) == \
        ct.resolved_options({}), "today's name must be today's default"


def test_check_default_re_runs_stored_runs_with_the_critics_own_defaults(tmp_path, monkeypatch,
                                                                         capsys):
    """``check-default`` runs each stored run of a method with options that give the critic its
    own defaults (the ladder's base keys set back), compares costs and falls trial by trial,
    and exits 1 when one differs, 2 when no stored run is found."""
    import latentune.critic.transfer as ct

    assert ct.resolved_options({**tr.LADDER_BASE, **tr.default_options()}) == \
        ct.resolved_options({})
    stored = tmp_path / "stored"
    runs = {}
    for g in tr.SYSTEMS["arm"]["gaps"]:
        f = stored / "arm" / f"gap{g:g}" / "seed0" / "M.json"
        f.parent.mkdir(parents=True)
        runs[g] = {"costs": [3.0, 2.0 + g], "failed": [False, True], "budget": 2}
        f.write_text(json.dumps(runs[g]))
    seen = []

    def fake(method, target, src, B, seed, options):
        seen.append((method, B, seed, options))
        g = tr.SYSTEMS["arm"]["gaps"][len(seen) - 1]        # the gaps in their order
        return {"costs": list(runs[g]["costs"]), "failed": list(runs[g]["failed"])}

    monkeypatch.setattr(tr, "run_method", fake)
    monkeypatch.setattr(tr, "source_run", lambda root, name, seed, n: root / name)
    args = ["check-default", "--root", str(tmp_path / "src"), "--stored", str(stored),
            "--method", "M", "--systems", "arm"]
    assert tr.main(args) == 0
    assert [s[:3] for s in seen] == [("transfer", 2, 0)] * len(runs)
    assert all(s[3] == tr.default_options() for s in seen)
    assert f"{len(runs)} of {len(runs)} runs the same" in capsys.readouterr().out
    first = min(runs)
    runs[first] = {**runs[first], "failed": [False, False]}      # a fall that is not stored
    seen.clear()
    assert tr.main(args) == 1
    assert "DIFFERS" in capsys.readouterr().out
    assert tr.main(args[:-3] + ["M2", "--systems", "arm"]) == 2
    assert "no stored run of M2" in capsys.readouterr().err


def test_held_out_gaps_replace_the_ladders_and_a_gap_a_system_cannot_take_is_refused(capsys,
                                                                                     tmp_path):
    """``--gaps``: every system gets those gaps instead of its ladder's; a gap its factory
    refuses (the Hopper's friction turns 0 at gap 2.5) or a gap ≤ 0 ends ``run`` and
    ``gap_ladder`` with one line on stderr and exit 2, before any run; so does a ``--variants``
    option the critic does not have or a value it refuses, named."""
    from benchmarks import gap_ladder

    got = tr.ladder_targets(["arm", "chain"], [1.25, 1.75])
    assert [g for g, _ in got["arm"]] == [1.25, 1.75] == [g for g, _ in got["chain"]]
    assert [g for g, _ in tr.ladder_targets(["arm"], None)["arm"]] == \
        list(tr.SYSTEMS["arm"]["gaps"])
    nowhere = str(tmp_path / "nowhere")
    for argv in (["run", "--systems", "hopper", "--gaps", "2.5", "--root", nowhere],
                 ["run", "--systems", "arm", "--gaps", "0", "--root", nowhere]):
        assert tr.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("python -m benchmarks.transfer run: error: ")
    assert gap_ladder.main(["--systems", "hopper", "--gaps", "2.5", "--n", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hopper cannot take gap 2.5" in err[0]
    for variant, expect in (("region_gp=bad", "region_gp must be true, false or"),
                            ("nope=1", "unknown option(s) of the transfer critic: nope"),
                            ("max_fall_prob=2", "max_fall_prob must be in (0, 1]")):
        assert tr.main(["run", "--systems", "arm", "--variants", variant,
                        "--root", str(tmp_path / "nowhere")]) == 2       # before any source run
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expect in err[0]
        assert err[0].startswith("python -m benchmarks.transfer run: error: ")
    for flag in ("--budget", "--source-evals"):     # were run (and stored) with budget 0
        assert tr.main(["run", "--systems", "arm", flag, "0", "--root", nowhere]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"python -m benchmarks.transfer run: error: {flag} must be >= 1, got 0"]


def test_run_refuses_a_budget_below_the_two_first_trials_of_plain_and_handover(capsys, tmp_path):
    """``run --budget 1`` with ``plain`` or ``handover`` (as the default methods hold them) ran
    their manual and zero-shot trials (2) anyway and stored them as a run of budget 1; it is
    now refused in one line (exit 2) before any source run, and ``--only`` without them
    still takes budget 1."""
    for only in ([], ["--only", "plain", "zero_shot"], ["--only", "handover"]):
        assert tr.main(["run", "--systems", "arm", "--budget", "1", *only,
                        "--root", str(tmp_path / "nowhere")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            "python -m benchmarks.transfer run: error: --budget 1 is too small for ")
        assert ("handover" in err[0]) == ("plain" not in only)
    assert tr.main(["run", "--systems", "arm", "--budget", "1", "--only", "zero_shot",
                    "--gaps", "0", "--root", str(tmp_path)]) == 2    # past the budget check
    assert "--budget" not in capsys.readouterr().err


def test_cut_of_a_method_without_runs_is_refused(tmp_path, capsys):
    """``cut`` of a method with no stored run (a typo) said '0 runs ... stored as X' and exited
    0; it now exits 2 with one line naming the method and root."""
    _write(tmp_path, "transfer", 0, [2.0, 1.0], [False, True])
    assert tr.main(["cut", "--root", str(tmp_path), "--method", "transfr", "--share", "0.5",
                    "--as", "x"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"python -m benchmarks.transfer cut: error: no run of transfr under {tmp_path}"]
    assert tr.main(["cut", "--root", str(tmp_path), "--method", "transfer", "--share", "0.5",
                    "--as", "x"]) == 0


def test_cut_stores_a_methods_runs_as_a_fall_budget_would_have_run_them(tmp_path, capsys):
    """``cut`` writes, beside each run of the method, the run cut where ``fall_budget`` is
    spent (named ``--as``, with ``derived_from``), and refuses a share outside (0, 1)."""
    f = tmp_path / "arm" / "gap1" / "seed3" / "M.json"
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"costs": [5.0, 9.0, 4.0, 9.0] + [1.0] * 16, "seed": 3,
                             "failed": [False, True, False, True] + [False] * 16}))
    assert tr.main(["cut", "--root", str(tmp_path), "--method", "M", "--share", "0.1",
                    "--as", "M:fall_budget=0.1"]) == 0
    out = json.loads(f.with_name("M:fall_budget=0.1.json").read_text())
    assert out["cut_at"] == 4 and out["derived_from"] == "M" and out["method"] == "M:fall_budget=0.1"
    assert out["costs"] == [5.0, 9.0, 4.0, 9.0] + [4.0] * 16 and sum(out["failed"]) == 2
    assert tr.main(["cut", "--root", str(tmp_path), "--method", "M", "--share", "1",
                    "--as", "X"]) == 2
    assert "--share must be in (0, 1)" in capsys.readouterr().err


def test_screened_cma_runs_only_what_the_fall_screen_admits(tmp_path, monkeypatch,
                                                           chain_source):
    """``cma_source_screened`` runs the source's best first, then CMA-ES samples the fall screen
    admits (here: first coordinate at most 0.5), the rejected ones told to the study as
    failed; where no draw passes, ``transfer_cma_source`` runs the transfer critic's own ask
    instead."""
    import latentune.critic.transfer as ct

    src = _source_copy(chain_source, tmp_path)
    edge = 0.5
    monkeypatch.setattr(tr, "SCREEN_DRAWS", 400)
    monkeypatch.setattr(ct.Transfer, "_fall_prob",
                        lambda self, C, fall_m, bound=None: (C[:, 0] > edge).astype(float))
    target = tr.SYSTEMS["chain"]["target"](1.0)
    res = tr.run_method("cma_source_screened", target, src, 6, 0)
    assert len(res["costs"]) == 6 and res["draws"][0] == 1
    X = np.array(res["thetas"])
    assert (X[1:, 0] <= edge).all(), "a θ the screen rejects ran"
    assert max(res["draws"][1:]) > 1, "no draw was rejected: the screen was not consulted"
    monkeypatch.setattr(ct.Transfer, "_fall_prob",
                        lambda self, C, fall_m, bound=None: np.ones(len(C)))
    res = tr.run_method("transfer_cma_source", target, src, 4, 0)
    assert res["draws"] == [1, 0, 0, 0], "no draw passes: the critic asks every trial"


def test_screened_cma_bar_sets_each_cma_peer_beside_its_screened_twin(tmp_path, capsys):
    """``transfer_screened`` reads a summary: targets whose best peer is a CMA-ES get the peer's
    screened twin beside it (falls summed per seed, the ratio of medians), then the bar's parts;
    a target with another best peer is left out; bad input is one line and exit 2."""
    from benchmarks import transfer_screened as ts

    for s in range(4):
        _write(tmp_path, "cma_source", s, [5.0, 2.0], [True, False])
        _write(tmp_path, "cma_source_screened", s, [5.0, 2.1 if s % 2 else 1.9], [False, False])
        _write(tmp_path, "transfer", s, [3.0, 3.0], [False, False])
    summary = tr.summarize(tmp_path)
    res = ts.bar(summary, ["arm 1"])
    (row,) = res["rows"]
    assert row["peer"] == "cma_source" and row["peer_falls_sum"] == 4
    assert row["twin_falls_sum"] == 0 and res["falls_ratio"] == 0.0 and res["bar1_falls_half"]
    assert row["ratio"] == 1.0 and res["within_5pct"] == 1
    assert res["bar3"]["arm 1"]["whole_run_quarter_falls"]
    f = tmp_path / "arm" / "gap1" / "seed9" / "cma_source_screened.json"
    f.parent.mkdir()
    f.write_text(json.dumps({"system": "arm", "gap": 1.0, "method": "cma_source_screened",
                             "draws": [1, tr.SCREEN_DRAWS, 3, tr.SCREEN_DRAWS],
                             "failed": [True, True, False, False]}))
    assert ts.forced(tmp_path)["arm 1 cma_source_screened"] == {
        "admitted": 1, "admitted_fell": 0, "forced": 2, "forced_fell": 1}, "the first trial counts"
    summary["targets"][0]["best_peer"] = "tpe"
    with pytest.raises(ValueError, match="no target"):
        ts.bar(summary, [])
    assert ts.main(["--summary", str(tmp_path / "missing.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m benchmarks.transfer_screened: error:") and "missing.json" in err


def test_trace_panels_call_only_the_default_default():
    """A long method name that is not the default keeps its own title (the screened CMA-ES
    was once titled "default")."""
    from benchmarks.zones_traces import method_label

    d = "transfer+explore_pool=adaptive:explore_gp=true:explore_fall_prob=0.2"
    assert method_label(d, d) == "default"
    assert method_label("cma_source_trials_screened", d) == "cma_source_trials_screened"


def test_allowance_sets_the_defaults_early_falls_beside_the_best_peers(tmp_path, capsys):
    """``transfer_allowance``: the default's falls in the first quarter of each run (median
    over seeds) beside the best peer's falls and the allowance; bad input is one line, exit 2."""
    from benchmarks import transfer_allowance as ta

    for s in range(3):
        _write(tmp_path, "tpe", s, [5.0] * 8, [True] * 7 + [False])
        _write(tmp_path, "transfer", s, [4.0] * 8, [True, s > 0, False, False, True, True,
                                                   False, False])
    summary = tr.summarize(tmp_path)
    early = ta.cheap_early(tmp_path, summary, "transfer")
    assert early == {("arm 1", 0): 1, ("arm 1", 1): 2, ("arm 1", 2): 2}
    (row,) = ta.rows_of(summary, early, "{system} {gap:g}")
    assert row["peer_falls"] == 7 and row["allowance"] == 1
    assert row["default_early_falls"] == 2 and row["default_falls"] == 4
    assert ta.main(["--summary", str(tmp_path / "none.json"), "--runs", str(tmp_path)]) == 2
    assert ta.main(["--summary", str(tmp_path / "none.json"), "--runs", str(tmp_path),
                    "--robot-summary", "x"]) == 2
    err = capsys.readouterr().err
    assert err.count("transfer_allowance:") == 2 and "none.json" in err
    assert "--robot-summary and --robot-traces go together" in err


def test_stopping_rules_cut_a_run_where_its_own_falls_say(tmp_path, capsys):
    """``transfer_stop``: the early rule's budget comes from the first quarter's falls, the
    stall rule stops at the m-th fall that bought no better cost; a cut run then holds its
    best standing θ; judging counts criteria (1) and (3) per target; bad input is one line,
    exit 2."""
    from benchmarks import transfer_stop as ts

    y = [5.0, 4.0, 0.0, 3.0, 0.0, 0.0, 2.0, 0.0]
    f = [False, False, True, False, True, True, False, True]
    # first quarter (2 trials) no fall: k = max(1, 0 + 1) = 1, spent at the first fall
    assert ts.early_end(y, f, 1.0, 1) == 3
    g = [True, False, False, True, False, True, False, False]     # E = 1 → k = 2
    assert ts.early_end(y, g, 1.0, 1, "all") == 4
    assert ts.early_end(y, g, 1.0, 1, "after_stand") == 6
    assert ts.early_end(y, [True] * 8, 1.0, 0) == 8                # nothing stood: no stop
    assert ts.stall_end(y, f, 2, 0.0) == 6     # 3 improves (count restarts), then 2 falls
    assert ts.stall_end(y, f, 2, 0.9) == 8     # not before trial 8; 2 restarts it at trial 7
    assert ts.stall_end(y, f, 1, 0.0) == 3
    cut = tr.cut_at({"costs": y, "failed": f}, 4)
    assert cut["costs"] == [5.0, 4.0, 0.0, 3.0] + [3.0] * 4
    assert cut["failed"] == f[:4] + [False] * 4 and cut["cut_at"] == 4
    for s in range(3):                           # the peer falls 7 times: allowance 1
        _write(tmp_path, "tpe", s, [5.0] * 8, [True] * 7 + [False])
        _write(tmp_path, "transfer", s, [4.0, 3.0, 9.0, 9.0, 2.0, 9.0, 9.0, 1.0],
               [False, False, True, True, False, True, True, False])
    (case,) = ts.cheap_cases(tmp_path, ("arm",), "transfer")
    whole = ts.judge([case], None)
    assert (whole["c1"], whole["c3"], whole["falls"]) == (1, 0, 12)
    stopped = ts.judge([case], lambda c, fl: ts.early_end(c, fl, 1.0, 1))
    assert (stopped["c1"], stopped["c3"], stopped["falls"]) == (1, 1, 3)
    assert stopped["paired_cost"] == pytest.approx(3.0)             # 3 against 1 on each seed
    assert ts.main(["--runs", str(tmp_path / "none"), "--heldout-runs", str(tmp_path)]) == 2
    assert ts.main(["--runs", str(tmp_path), "--heldout-runs", str(tmp_path),
                    "--robot-summary", "x"]) == 2
    err = capsys.readouterr().err
    assert err.count("transfer_stop:") == 2 and "no such directory" in err
    assert "--robot-summary and --robot-traces go together" in err
    with pytest.raises(ValueError, match="no rule of the grids"):
        ts.parse_rule("early:a=7", [])


def test_model_comparison_scores_each_model_on_the_trials_it_was_not_given(tmp_path, capsys):
    """``transfer_models``: every model predicts the target's trials after the cut; where the
    target is the source, the source-informed models rank those trials well; the ensemble's
    weight is a share; bad input is one line, exit 2."""
    from benchmarks import transfer_models as tm
    from latentune.critic.transfer import Transfer

    rng = np.random.default_rng(0)
    Xs = rng.random((40, 3))
    ys = ((Xs - 0.4) ** 2).sum(1)
    fs = ys > 0.6
    h = Transfer((Xs, ys, fs), None, None, seed=0).source_model().hypers
    X = rng.random((16, 3))
    y = ((X - 0.4) ** 2).sum(1)                     # the target is the source
    sc = tm.score_cut((Xs, ys, fs), h, 0, X, y, y > 0.6, 6)
    assert set(tm.MODELS) <= set(sc)
    assert sc["source"]["rho"] > 0.8 and sc["transfer"]["rho"] > 0.8 and sc["mtgp"]["rho"] > 0.5
    assert 0.0 <= sc["rgpe_weight_source"]["w"] <= 1.0
    assert all(-1.0 <= sc[m]["rho"] <= 1.0 for m in tm.MODELS)
    assert tm.main(["--sources", str(tmp_path / "none"), "--runs", str(tmp_path)]) == 2
    assert tm.main(["--merge", "x.json", "--runs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("transfer_models:") == 2 and "no such directory" in err
    assert "--merge reads stored rows" in err


def test_a_robot_traces_run_of_a_method_is_its_avx512_twin_where_there_is_one():
    """``runs_by_seed``: the ``@avx512`` run wins whichever comes first in the exported list;
    a seed with only the plain run keeps it; other methods are left out."""
    from benchmarks.transfer_walk import runs_by_seed

    runs = [{"method": "M@avx512", "seed": 0, "tag": "new0"},
            {"method": "M", "seed": 0, "tag": "old0"},
            {"method": "M", "seed": 1, "tag": "old1"},
            {"method": "M2", "seed": 2, "tag": "other"}]
    got = runs_by_seed(runs, "M")
    assert {s: r["tag"] for s, r in got.items()} == {0: "new0", 1: "old1"}
    assert {s: r["tag"] for s, r in runs_by_seed(runs[::-1], "M").items()} == \
        {0: "new0", 1: "old1"}


def test_simrank_scores_the_exact_source_and_a_local_source_gp(tmp_path, monkeypatch, capsys):
    """``transfer_simrank``: a stored trace's θ are run on the model system; where the target
    is the source, the exact source ranks the later trials perfectly; the local GP gets a ρ;
    an unknown system is one line, exit 2."""
    from benchmarks import transfer_simrank as sr
    from latentune.system import Outcome

    class Bowl:                                    # the model system: cost = distance², stands
        space = None

        def evaluate(self, theta):
            return Outcome(float(((np.asarray(theta) - 0.4) ** 2).sum()), False, {})

    monkeypatch.setitem(tr.SYSTEMS, "bowl", {"model": Bowl, "target": None, "gaps": (1.0,)})
    rng = np.random.default_rng(1)
    X = rng.random((16, 3))
    y = ((X - 0.4) ** 2).sum(1)                     # the target is the source
    d = tmp_path / "runs" / "bowl" / "gap1" / "seed0"
    d.mkdir(parents=True)
    (d / f"{tr.DEFAULT_METHOD}.json").write_text(json.dumps(
        {"method": tr.DEFAULT_METHOD, "thetas": X.tolist(), "costs": y.tolist(),
         "failed": [False] * 16}))
    Xs = rng.random((120, 3))
    src = (Xs, ((Xs - 0.4) ** 2).sum(1), np.zeros(120, bool))
    monkeypatch.setattr("latentune.pipeline.baselines.source_trials", lambda d: src)
    (tmp_path / "src" / "bowl" / "seed0" / "source").mkdir(parents=True)
    (tmp_path / "src" / "bowl" / "seed0" / "source" / "run.db").write_text("")
    rows = [{"system": "bowl", "gap": 1.0, "seed": 0, "set": "default", "t": 5,
             "transfer": {"rho": 0.1, "auc": None}, "source": {"rho": 0.2, "auc": None}}]
    (out,) = sr.score(rows, tmp_path / "runs", tmp_path / "src")
    assert out["exact"]["rho"] == pytest.approx(1.0)
    assert -1.0 <= out["local"]["rho"] <= 1.0 and out["local"]["rho"] > 0.5
    assert any("| default | 5 | 1.000 |" in line for line in sr.table([out]))
    mf = tmp_path / "m.json"
    mf.write_text(json.dumps({"rows": rows}))
    assert sr.main(["--runs", str(tmp_path / "runs"), "--sources", str(tmp_path / "src"),
                    "--models", str(mf), "--systems", "nosuch"]) == 2
    assert "transfer_simrank: error: unknown system" in capsys.readouterr().err


def test_transfer_gate_measures_local_agreement_and_labels_wins(tmp_path, monkeypatch, capsys):
    """``transfer_gate``: the θ of ``a``'s run are run on the model system; where the target
    is the source, local and whole-run ρ are 1; the label is ``a`` ending lower than ``b``; a
    missing run and an unknown system are one line, exit 2."""
    from benchmarks import transfer_gate as tg
    from latentune.system import Outcome

    class Bowl:
        space = None

        def evaluate(self, theta):
            return Outcome(float(((np.asarray(theta) - 0.4) ** 2).sum()), False, {})

    monkeypatch.setitem(tr.SYSTEMS, "bowl", {"model": Bowl, "target": None, "gaps": (1.0,)})
    monkeypatch.setattr(tg, "CUTS", (10,))
    rng = np.random.default_rng(2)
    X = rng.random((12, 3))
    y = ((X - 0.4) ** 2).sum(1)
    d = tmp_path / "runs" / "bowl" / "gap1" / "seed0"
    d.mkdir(parents=True)
    for m, c in (("A", y), ("B", y + 1.0)):
        (d / f"{m}.json").write_text(json.dumps({"method": m, "thetas": X.tolist(),
                                                 "costs": c.tolist(), "failed": [False] * 12}))
    (row,) = tg.score(tmp_path / "runs", ["bowl"], [0], "A", "B", 5)
    assert row["local_10"] == pytest.approx(1.0) and row["all_10"] == pytest.approx(1.0)
    assert row["win"] and not row["loss"]
    md = tg.table([row], "A", "B", 5)
    assert any(line.startswith("| bowl | 1 / 0 |") for line in md)
    assert tg.main(["--runs", str(tmp_path / "runs"), "--systems", "bowl", "--seeds", "1",
                    "--a", "A", "--b", "B"]) == 2
    assert "transfer_gate: error: bowl gap 1 seed 1: no stored run of A" in capsys.readouterr().err
    assert tg.main(["--runs", str(tmp_path / "runs"), "--systems", "nosuch"]) == 2
    assert "transfer_gate: error: unknown system" in capsys.readouterr().err


def test_transfer_agreement_reads_the_agreement_at_a_cut_and_labels_gpsampler_wins(tmp_path,
                                                                                     capsys):
    """``transfer_agreement``: the agreement is the decision's at ``n_told`` = the cut; the label
    is GPSampler's best strictly below the method's; a low agreement that goes with GPSampler's
    wins gives AUC 1 and the highest threshold a* below which it wins more than half; a pair without GPSampler's run
    is left out; a missing root is one line, exit 2."""
    from benchmarks import transfer_agreement as ta

    def put(seed: int, agree: float, best: float, peer: float | None) -> None:
        d = tmp_path / "runs" / "bowl" / "gap2" / f"seed{seed}"
        d.mkdir(parents=True)
        decisions = [{"n_told": t, "agreement": agree if t == 10 else 9.0} for t in range(1, 40)]
        (d / "A.json").write_text(json.dumps({"costs": [5.0, best, 0.0], "budget": 2,
                                              "decisions": decisions}))
        if peer is not None:
            (d / "gp.json").write_text(json.dumps({"costs": [5.0, peer], "budget": 2}))

    for seed, agree, best, peer in ((0, 0.1, 2.0, 1.0), (1, 0.2, 2.0, 1.5), (2, 0.8, 1.0, 1.0),
                                    (3, 0.9, 1.0, 3.0), (4, 0.0, 1.0, None)):
        put(seed, agree, best, peer)
    rows = ta.pairs(tmp_path / "runs", "A", (10, 20))
    assert [r["seed"] for r in rows] == [0, 1, 2, 3]          # seed 4 has no GPSampler run
    assert [r["peer_wins"] for r in rows] == [True, True, False, False]   # a tie is no win
    assert rows[0]["agreement"] == {"10": 0.1, "20": 9.0} and rows[0]["best"] == 2.0
    ag = np.array([r["agreement"]["10"] for r in rows])
    won = np.array([r["peer_wins"] for r in rows])
    assert ta.threshold(ag, won) == pytest.approx(0.8)          # wins 2 of the 3 at or below
    assert ta.threshold(ag, ~won) is None                          # nowhere more than half
    st = ta.cut_stats(rows, 10, 0.8)
    assert st["auc"] == pytest.approx(1.0) and st["picked"] == 3 and st["wins_held"] == 1.0
    assert st["picked_win_share"] == pytest.approx(2 / 3)
    assert ta.cut_stats(rows, 20, None)["auc"] == pytest.approx(0.5)   # 9.0 everywhere: ties
    assert ta.main(["--runs", str(tmp_path / "runs"), "--method", "A",
                    "--out", str(tmp_path / "a.json")]) == 0
    assert "| bowl 2 | 4 | 2 | 0.50 / 9.00 |" in (tmp_path / "a.md").read_text()
    capsys.readouterr()
    assert ta.main(["--runs", str(tmp_path / "nosuch")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "transfer_agreement: error: --runs" in err[0], err


def test_fall_costs_tells_a_low_cost_flagged_or_hidden_and_tables_the_arms(tmp_path, capsys):
    """``fall_costs``: a failed trial is told (k/N)·c_manual, its flag kept (``told``) or moved
    to ``info`` (``hidden``); a short run of each arm on the chain is summarized per system;
    bad input is one line, exit 2."""
    from benchmarks import fall_costs as fc
    from latentune.system import Outcome

    class Sys:
        steps = 50
        space = None

        def evaluate(self, theta):
            return Outcome(150.0, True, {"fall_step": 10}) if theta[0] > 0.5 else \
                Outcome(2.0, False, {})

    told, hidden = fc.LowFallCost(Sys(), 4.0, False), fc.LowFallCost(Sys(), 4.0, True)
    o = told.evaluate(np.array([0.9]))
    assert o.failed and o.cost == pytest.approx(0.2 * 4.0) and o.info["convention_cost"] == 150
    h = hidden.evaluate(np.array([0.9]))
    assert not h.failed and h.info[fc.FELL_KEY] and h.cost == o.cost
    assert told.evaluate(np.array([0.1])).cost == 2.0
    assert fc.main(["run", "--root", str(tmp_path), "--systems", "chain", "--seeds", "0",
                    "--evals", "6"]) == 0
    out = tmp_path / "o" / "fc.json"
    assert fc.main(["summary", "--root", str(tmp_path), "--systems", "chain", "--seeds", "0",
                    "--evals", "6", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res["systems"]["chain"]) >= set(fc.ARMS) | {"told_vs_hidden"}
    assert len(json.loads(out.with_name("traces.json").read_text())) == 3
    assert "| chain |" in out.with_suffix(".md").read_text()
    assert fc.main(["run", "--root", str(tmp_path), "--systems", "nosuch"]) == 2
    assert fc.main(["summary", "--root", str(tmp_path), "--systems", "chain", "--seeds", "0",
                    "--evals", "60", "--out", str(out)]) != 0
    assert "error: unknown system/arm" in capsys.readouterr().err


def test_sim_check_options_are_the_benchmarks_and_bad_values_are_refused():
    """``sim_check``/``sim_pick`` are taken by ``benchmarks.transfer`` (not the critic, which
    refuses unknown options); a bad value is one ValueError naming the option."""
    tr.check_variant("explore_gp=true:sim_check=4:sim_pick=true")
    tr.check_variant("sim_check=8:sim_pick=agree")
    for bad, name in (("sim_check=-1", "sim_check"), ("sim_check=true", "sim_check"),
                      ("sim_check=4:sim_pick=3", "sim_pick")):
        with pytest.raises(ValueError, match=name):
            tr.check_variant(bad)


def test_a_run_directory_without_a_store_is_one_line_not_a_traceback(tmp_path, capsys):
    """``python -m benchmarks.rows_digest digest DIR`` (and vae_kind, fall_calibration,
    fall_costs summary, handover, sample_efficiency) of a directory without a run store, or
    transfer_diagnose / rollout_identity of a missing file, ended in a traceback (exit 1); every
    benchmark's entry point (``benchmarks.common.cli_main``) makes a latentune user error or a
    missing input file one line on stderr and exit 2."""
    import os
    import subprocess
    import sys

    from benchmarks import vae_kind
    from benchmarks.common import ROOT, cli_main

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)])}
    p = subprocess.run([sys.executable, "-m", "benchmarks.rows_digest", "digest", str(tmp_path)],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        f"python -m benchmarks.rows_digest: error: no run store in {tmp_path} "
        "(expected run.db)"], p.stderr
    assert cli_main(lambda: vae_kind.main([str(tmp_path / "none")]), "benchmarks.vae_kind") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"python -m benchmarks.vae_kind: error: run directory {tmp_path / 'none'} "
                   "does not exist"]
    from benchmarks import rollout_identity     # a missing input file: one line, not a traceback
    a = tmp_path / "a.json"
    assert cli_main(lambda: rollout_identity.main(["--compare", str(a), str(a)]),
                    "benchmarks.rollout_identity") == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"python -m benchmarks.rollout_identity: error: no such file or directory: {a}"]


@pytest.mark.parametrize("argv", [["--stop", "0"], ["--stop", "100"],
                                  ["--budget", "10", "--stop", "20"], ["--dim", "0"]])
def test_resume_determinism_refuses_a_stop_that_resumes_nothing(argv, capsys):
    """``--stop 0`` or a ``--stop`` at or past ``--budget`` never interrupts the run, so the
    benchmark reported 'no differing evaluation' about a resume that never happened (exit 0);
    it is refused before any run, one argparse line, exit 2."""
    from benchmarks import resume_determinism

    with pytest.raises(SystemExit) as e:
        resume_determinism.main(argv)
    assert e.value.code == 2
    assert "--stop in [1, --budget - 1]" in capsys.readouterr().err


def test_summary_compare_and_cut_refuse_an_incomplete_or_damaged_run(tmp_path, capsys):
    """A run file holding fewer trials than its budget (a cut-short trace) or not JSON at all
    was read as a finished run (its best over 2 of 4 trials in the medians) or was a
    traceback; ``summary``, ``compare`` and ``cut`` now name the file in one line and exit 2,
    writing nothing. The zero-shot θ's one trial is a complete run."""
    for s in (0, 1):
        _write(tmp_path, "tpe", s, [4.0, 3.0, 2.0, 1.0], [False] * 4)
        _write(tmp_path, "zero_shot", s, [4.0], [False], budget=4)
    _write(tmp_path, "transfer", 0, [2.0, 1.0, 1.0, 1.0], [False] * 4)
    _write(tmp_path, "transfer", 1, [2.0, 1.5], [False] * 2, budget=4)       # cut short
    bad = tmp_path / "arm" / "gap1" / "seed1" / "transfer.json"
    out = tmp_path / "o.json"
    for damaged in (None, '{"costs": [2.0, 1'):
        if damaged is not None:
            bad.write_text(damaged)
        for argv in (["summary", "--root", str(tmp_path), "--out", str(out)],
                     ["compare", "--root", str(tmp_path), "--a", "transfer", "--b", "tpe",
                      "--out", str(out)],
                     ["cut", "--root", str(tmp_path), "--method", "transfer", "--share", "0.5",
                      "--as", "cut"]):
            assert tr.main(argv) == 2, argv
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and str(bad) in err[0], err
            assert ("incomplete run" if damaged is None else "is not a stored run") in err[0]
            assert not out.exists() and not bad.with_name("cut.json").exists()
    bad.unlink()
    assert tr.main(["compare", "--root", str(tmp_path), "--a", "zero_shot", "--b", "tpe"]) == 0
    assert tr.main(["summary", "--root", str(tmp_path), "--methods", "zero_shot", "tpe"]) == 0


def test_summary_says_which_seeds_and_targets_it_leaves_out(tmp_path, capsys):
    """A target's medians are over the seeds on which every method read ran: a seed where one
    method is missing was dropped without a word (the table said "2 seeds" of 3), and a target
    without such a seed vanished from the tables; both are now listed, in the JSON
    (``seeds_left_out``, ``targets_left_out``) and the tables, and a root where no target has
    one is refused (exit 2) rather than an empty table."""
    for s in (0, 1, 2):
        _write(tmp_path, "tpe", s, [3.0, 2.0], [False, False])
        if s != 1:
            _write(tmp_path, "transfer", s, [2.0, 1.0], [False, False])
    other = tmp_path / "chain" / "gap2"
    for m, s in (("tpe", 0), ("transfer", 1)):          # chain gap 2: no seed with both
        f = other / f"seed{s}" / f"{m}.json"
        f.parent.mkdir(parents=True)
        f.write_text(json.dumps({"system": "chain", "gap": 2.0, "seed": s, "method": m,
                                 "budget": 1, "costs": [1.0], "failed": [False]}))
    s = tr.summarize(tmp_path)
    (row,) = s["targets"]
    assert row["seeds"] == [0, 2] and row["seeds_left_out"] == [{"seed": 1,
                                                                 "without": ["transfer"]}]
    assert s["targets_left_out"] == [{"system": "chain", "gap": 2.0,
                                      "seeds_of": {"tpe": [0], "transfer": [1]}}]
    md = tr.markdown(s)
    assert "seed 1 left out: no run of transfer" in md
    assert "### chain gap 2: left out, no seed on which every method ran (tpe: seeds 0; " \
           "transfer: seeds 1)" in md
    assert tr.main(["summary", "--root", str(tmp_path), "--systems", "chain"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no target under" in err[0] and "transfer: seeds 1" in err[0]


def test_summary_and_compare_refuse_runs_of_different_budgets(tmp_path, capsys):
    """``run`` at another ``--budget`` on a root adds runs beside those of the first: a
    method's best of 8 trials was set beside another's best of 4 in one table; ``summary``
    and ``compare`` now refuse such a target (one line naming the budgets, exit 2)."""
    for s in (0, 1):
        _write(tmp_path, "tpe", s, [3.0] * 8, [False] * 8)
        _write(tmp_path, "transfer", s, [2.0] * 4, [False] * 4)
    for argv in (["summary", "--root", str(tmp_path)],
                 ["compare", "--root", str(tmp_path), "--a", "transfer", "--b", "tpe"]):
        assert tr.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not comparable" in err[0], err
        assert "4" in err[0] and "8" in err[0]
    # a zero-shot run is one trial whatever budget it records (the paper's robot runs: 1)
    other = tmp_path / "zero"
    for s in (0, 1):
        _write(other, "tpe", s, [3.0] * 4, [False] * 4)
        _write(other, "zero_shot", s, [5.0], [False])
    assert tr.main(["summary", "--root", str(other)]) == 0


def test_run_refuses_to_resume_on_runs_or_sources_of_other_settings(tmp_path, capsys,
                                                                     monkeypatch):
    """``run`` skips a stored run and resumes a stored source: run again with another
    ``--budget`` it kept the stored runs at the old budget beside new ones at this one, with
    another ``--source-evals`` it extended the source's phase 1 under the runs made from it,
    and a damaged run file was skipped for good. Each is now refused before any run (one line,
    exit 2), and the same settings resume."""
    from latentune.pipeline.store import RunStore

    monkeypatch.setattr(tr, "run_method", lambda *a, **k: pytest.fail("ran"))
    root = tmp_path / "root"
    src = root / "bowl" / "seed0" / "source"
    with RunStore(src, create=True) as st:
        st.set_meta("config", {"phase1": {"budget": 16}})
    f = root / "bowl" / "gap0.1" / "seed0" / "zero_shot.json"
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"system": "bowl", "gap": 0.1, "seed": 0, "method": "zero_shot",
                             "budget": 4, "costs": [1.0], "failed": [False]}))
    argv = ["run", "--systems", "bowl", "--seeds", "0", "--gaps", "0.1", "--only", "zero_shot",
            "--root", str(root)]
    for extra, words in ((["--budget", "8", "--source-evals", "16"], "--budget 4, not 8"),
                         (["--budget", "4", "--source-evals", "24"],
                          "--source-evals 16, not 24")):
        assert tr.main(argv + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
    f.write_text('{"costs": [1.0')
    assert tr.main(argv + ["--budget", "4", "--source-evals", "16"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(f) in err[0] and "is not a stored run" in err[0]
    with RunStore(src) as st:
        assert st.count(1) == 0                         # the source was not extended
    f.write_text(json.dumps({"system": "bowl", "gap": 0.1, "seed": 0, "method": "zero_shot",
                             "budget": 4, "costs": [1.0], "failed": [False]}))
    monkeypatch.setattr(tr, "source_run", lambda *a: src)
    assert tr.main(argv + ["--budget", "4", "--source-evals", "16"]) == 0     # resumes: kept


def test_summary_at_a_smaller_budget_reads_each_runs_first_trials(tmp_path, capsys):
    """``summary --budget B`` judges runs made at a larger budget on their first B trials: a
    method whose best came late loses there; a run of fewer than B trials is refused."""
    for s in (0, 1, 2):
        _write(tmp_path, "tpe", s, [4.0, 3.0, 3.0, 3.0], [False] * 4)
        _write(tmp_path, "transfer", s, [5.0, 5.0, 1.0, 1.0], [False, True, False, False])
        _write(tmp_path, "zero_shot", s, [6.0], [False], budget=4)
    (row,) = tr.summarize(tmp_path)["targets"]
    assert row["methods"]["transfer"]["median_best"] == 1.0
    (row,) = tr.summarize(tmp_path, budget=2)["targets"]
    assert row["methods"]["transfer"]["median_best"] == 5.0
    assert row["methods"]["tpe"]["median_best"] == 3.0
    assert row["methods"]["transfer"]["falls"] == [1, 1, 1]       # per seed
    assert row["methods"]["zero_shot"]["median_best"] == 6.0
    assert tr.main(["summary", "--root", str(tmp_path), "--budget", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fewer than --budget 5" in err[0], err


def test_prefix_says_whether_longer_runs_continue_the_stored_ones(tmp_path, capsys):
    """``prefix``: a run made at a larger budget is the same run as its stored twin for the
    twin's trials (exit 0), or it is named (exit 1); a twin of another budget is refused."""
    long, short = tmp_path / "long", tmp_path / "short"
    _write(long, "tpe", 0, [4.0, 3.0, 2.0, 1.0], [False] * 4)
    _write(short, "tpe", 0, [4.0, 3.0], [False] * 2)
    _write(long, "zero_shot", 0, [6.0], [False], budget=4)
    _write(short, "zero_shot", 0, [6.0], [False], budget=2)
    _write(long, "gp", 0, [4.0, 3.0, 2.0, 1.0], [False] * 4)       # no twin: left out
    argv = ["prefix", "--root", str(long), "--stored", str(short), "--budget", "2"]
    assert tr.main(argv) == 0
    assert "2 of 2 runs' first trials equal" in capsys.readouterr().out
    _write(short, "tpe", 0, [4.0, 3.5], [False] * 2)
    assert tr.main(argv) == 1
    out = capsys.readouterr().out
    assert "differs: arm/gap1/seed0/tpe.json" in out and "1 of 2" in out
    assert tr.main(argv[:-1] + ["3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not --budget 3" in err[0], err
