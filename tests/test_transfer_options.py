"""``Study.phase3(transfer_options=...)``: the transfer critic's options, checked before anything
is stored, recorded with phase 3's options, fixed on resume, and the same through ask/tell."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import latentune as lt
from latentune.constants import Phase
from latentune.critic.transfer import TRANSFER_DEFAULTS, counted_falls
from latentune.errors import StoreError, UsageError
from latentune.pipeline.phases import state_key
from test_asktell import SPACE, plant, src30  # noqa: F401 - shared fixtures

OFF = {"explore_every": 0}


@pytest.fixture
def src(tmp_path: Path, src30: Path) -> Path:  # noqa: F811 - the shared fixture
    shutil.copytree(src30, tmp_path / "src")
    return tmp_path / "src"


def _state(study: lt.Study) -> dict:
    return study.store.get_meta(state_key(Phase.PHASE3))


def test_options_reach_the_critic_and_are_fixed_on_resume(tmp_path, src):
    kept = dict(TRANSFER_DEFAULTS)
    target = plant(0.2)
    with lt.Study(tmp_path / "t", seed=0) as st:
        st.phase3(target, 5, latent=src, transfer_options=OFF)
        assert st.config()["phase3"]["transfer_options"] == OFF
        state = _state(st)
        assert state["options"]["explore_every"] == 0
        assert state["decisions"] and not any(d["explore"] for d in state["decisions"])
        for other, err in (({"explore_every": 4}, StoreError), (None, StoreError)):
            with pytest.raises(err, match="transfer-options"):
                st.phase3(target, 9, latent=src, transfer_options=other)
        assert st.store.count(Phase.PHASE3) == 5
        assert st.phase3(target, 9, latent=src, transfer_options=dict(OFF)).n == 9
        assert not any(d["explore"] for d in _state(st)["decisions"])
    assert TRANSFER_DEFAULTS == kept
    with lt.Study(tmp_path / "plain", seed=0) as st:    # none given: none recorded
        st.phase3(target, 5, latent=src)
        assert "transfer_options" not in st.config()["phase3"]
        with pytest.raises(StoreError, match="explore_every = 2, not 0"):    # its state's
            st.phase3(target, 9, latent=src, transfer_options=OFF)
        assert "transfer_options" not in st.config()["phase3"]


@pytest.mark.parametrize("kw, match", [
    ({"transfer_options": {"nosuch": 1}}, "unknown option.*nosuch"),
    ({"transfer_options": {"explore_every": 1}}, "explore_every must be"),
    ({"transfer_options": {"explore_fall_prob": 0.4}, "max_fall_prob": 0.3}, "explore_fall_prob"),
    ({"transfer_options": {"max_fall_prob": 0.2}}, "max_fall_prob is an argument of its own"),
    ({"transfer_options": OFF, "strategy": "plain"}, "options of the transfer phase 3"),
    ({"transfer_options": OFF, "handover": True}, "options of the transfer phase 3"),
    # numeric options out of their range: before, n_candidates 0 stopped the run at its first
    # model ask with numpy's "argmin of an empty sequence" (options and five trials stored),
    # and the others ran as something else (a side of 0, no fall screen with a NaN kappa)
    ({"transfer_options": {"n_candidates": 0}}, "n_candidates must be"),
    ({"transfer_options": {"n_design": -1}}, "n_design must be"),
    ({"transfer_options": {"n_elite": 2.5}}, "n_elite must be"),
    ({"transfer_options": {"max_points": 1}}, "max_points must be"),
    ({"transfer_options": {"fail_tol": 0}}, "fail_tol must be"),
    ({"transfer_options": {"succ_tol": True}}, "succ_tol must be"),
    ({"transfer_options": {"latent_falls": -1}}, "latent_falls must be"),
    ({"transfer_options": {"fit_ard": -2}}, "fit_ard must be"),
    ({"transfer_options": {"length_init": 0}}, "length_init must be"),
    ({"transfer_options": {"length_min": float("nan")}}, "length_min must be"),
    ({"transfer_options": {"length_max": 1e-3}}, "length_min .* must not exceed length_max"),
    ({"transfer_options": {"elite_spacing": -1}}, "elite_spacing must be"),
    ({"transfer_options": {"fall_kappa": float("nan")}}, "fall_kappa must be"),
    ({"transfer_options": {"latent_share_max": 1.5}}, "latent_share_max must be"),
    # a flag given as text: "false" was truthy, so the option ran switched on
    ({"transfer_options": {"restart": "false"}}, "restart must be true or false"),
    ({"transfer_options": {"stop_converged": "no"}}, "stop_converged must be true or false"),
    ({"transfer_options": {"fall_cost": 1}}, "fall_cost must be true or false"),
    # counts given as fractions: int() made 2.5 a 2 and ran with it
    ({"transfer_options": {"full_scales": 2.5}}, "full_scales must be a whole number"),
    ({"transfer_options": {"handoff": 2.5}}, "handoff must be a whole number"),
])
def test_options_the_critic_cannot_honour_are_refused_before_anything_is_stored(
        tmp_path, src, kw, match):
    d = tmp_path / "t"
    with lt.Study(d, seed=0) as st:
        with pytest.raises(UsageError, match=match) as info:
            st.phase3(plant(0.2), 5, latent=src, **kw)
        assert "\n" not in str(info.value)
        assert "phase3" not in st.config()
    assert not (d / "run.db").exists()


def test_ask_tell_takes_the_same_options(tmp_path, src):
    target = plant(0.2)
    with lt.Study(tmp_path / "p1", seed=0) as st:
        with pytest.raises(UsageError, match="transfer_options is an option of phase 3"):
            st.ask(system=target, transfer_options=OFF)
    with lt.Study(tmp_path / "t", seed=0) as st:
        with pytest.raises(UsageError, match="unknown option.*nosuch"):
            st.ask(system=target, phase=3, latent=src, transfer_options={"nosuch": 1})
        for i in range(3):
            (s,) = st.ask(system=target, phase=3, latent=src, transfer_options=OFF) if i == 0 \
                else st.ask()
            st.tell(s.id, lt.system.evaluate(target, s.theta).cost)
        assert st.config()["phase3"]["transfer_options"] == OFF
        assert _state(st)["options"]["explore_every"] == 0
        with pytest.raises(StoreError, match="transfer-options"):
            st.ask(transfer_options={"explore_every": 4})
        assert st.ask(transfer_options=OFF)[0].phase == Phase.PHASE3


def test_a_small_max_fall_prob_takes_the_default_explore_bound_below_it(tmp_path, src):
    """The default phase 3 at ``max_fall_prob`` 0.1 runs (the explore asks' default bound is ⅔
    of it, not a fixed 0.2 over it) and its state records the bound it used."""
    with lt.Study(tmp_path / "t", seed=0) as st:
        assert st.phase3(plant(0.2), 5, latent=src, max_fall_prob=0.1).n == 5
        opts = _state(st)["options"]
        assert opts["max_fall_prob"] == 0.1 and opts["explore_fall_prob"] == 0.066666666667
        assert opts["explore_gp"] is True


def _harsh(x):
    """The plant's quadratic where a < 0.21 and b < 0.3; a fall elsewhere."""
    if x[0] > 0.21 or x[1] > 0.3:
        return lt.Outcome(None, failed=True)
    return float(((x - 0.2) ** 2).sum())


def test_the_fall_budget_of_a_phase_3_on_its_own_system_counts_only_target_trials(src):
    """Phase 3 on the system of its own phase 1: the phase-1 trials the transfer critic is told
    as data are not the target's trials; their falls spent the budget before any phase-3
    trial (stopped at 0 of 8 while status said 0 falls counted)."""
    with lt.Study(src, seed=0, batch_size=2) as st:
        assert st.store.rows(Phase.PHASE1) and any(r.fell for r in st.store.rows(Phase.PHASE1))
        n = st.phase3(plant(), 8, transfer_options={"fall_budget": 0.1}).n
        fb = st.status()["fall_budget"]
        assert n > 0 and (n == 8 or fb["spent"]), (n, fb)
        assert not fb["spent"] or fb["falls"] >= fb["falls_allowed"]


def test_a_spent_fall_budget_ends_phase_3_and_ask_says_so(tmp_path, src, run_cli):
    """``fall_budget`` 0.1 of 20 phase-3 trials and the zero-shot one allows 2 falls after the
    first standing trial (the default count): the loop stops at the trial that spends it (2
    points a batch: the batch's other one is not run, no fall over), status says so, a resume
    asks nothing more, and ask refuses in one line; without a budget all 20 trials run."""
    target = lt.FunctionSystem(SPACE, _harsh)
    with lt.Study(tmp_path / "all", seed=0) as st:
        assert st.phase3(target, 20, latent=src).n == 20
        assert st.status()["fall_budget"] is None
    said: list[str] = []
    with lt.Study(tmp_path / "t", seed=0, batch_size=2, log=said.append) as st:
        n = st.phase3(target, 20, latent=src, transfer_options={"fall_budget": 0.1}).n
        assert any(f"; stopped at {n} of 20 trials: its fall budget (2 falls)" in m for m in said)
        rows = [r for ph in (Phase.ZERO_SHOT, Phase.PHASE3) for r in st.store.rows(ph)]
        fell = np.array([r.fell for r in rows], dtype=bool)
        assert n < 20 and counted_falls(fell, "after_stand") == 2 and not fell.all()
        assert st.status()["fall_budget"] == {"falls_allowed": 2, "spent": True,
                                              "counts": "after_stand", "falls": 2,
                                              "not_run": 1}
        assert st.phase3(target, 20, latent=src, transfer_options={"fall_budget": 0.1}).n == n
        with pytest.raises(StoreError, match="fall budget is spent") as info:
            st.ask(phase=3, budget=20, latent=src, transfer_options={"fall_budget": 0.1})
        assert "\n" not in str(info.value)
    # status said "N falls counted" of a budget that counts only falls after a standing trial
    out = run_cli("status", tmp_path / "t")[1]
    assert "falls counted (those after the first trial that stood), 2 allowed; spent" in out


def test_transfer_options_under_plain_name_the_strategy_without_claiming_a_hand_over():
    """Transfer options with the plain strategy are refused; the message said "a hand-over
    implies plain" although none was given."""
    from latentune.errors import UsageError
    from latentune.pipeline.manifest import transfer_option

    with pytest.raises(UsageError) as e:
        transfer_option({"fall_budget": 0.2}, "plain", None)
    assert "not of the plain one" in str(e.value) and "implies" not in str(e.value)


def test_target_scores_values_keep_how_much_better_a_trial_is():
    """``target_scores="values"``: standing trials standardized, falls one sd above the worst
    standing one; too few standing trials fall back to the rank scores; an unknown value is
    refused, and the default is the ranks."""
    from latentune.critic.transfer import Transfer
    from latentune.critic.transfer_model import rank_scores, value_scores

    y = np.array([1.0, 2.0, 10.0, 0.5, 7.0])
    fell = np.array([False, False, False, False, True])
    v = value_scores(y, fell)
    ok = ~fell
    assert np.allclose(v[ok], (y[ok] - y[ok].mean()) / y[ok].std())
    assert v[4] == pytest.approx(v[ok].max() + 1.0)
    # 10 is far worse than 2, not just one rank worse
    assert (v[2] - v[1]) > 3 * (v[1] - v[0])
    assert np.array_equal(value_scores(y[:2], fell[:2]), rank_scores(y[:2], fell[:2]))
    assert TRANSFER_DEFAULTS["target_scores"] == "ranks"
    with pytest.raises(ValueError, match="target_scores"):
        Transfer((np.zeros((2, 1)), np.zeros(2), np.zeros(2, dtype=bool)), target_scores="raw")


def test_warped_scores_keep_the_order_and_pull_in_a_tail_of_bad_costs():
    """``warped_scores``: monotone in the standing costs, standardized, falls one sd above the
    worst standing one; a far outlier no longer flattens the differences near the best (as it
    does in the plain values); too few standing trials give the rank scores."""
    from latentune.critic.transfer_model import rank_scores, value_scores, warped_scores

    y = np.array([1.0, 1.1, 1.2, 1.3, 1.5, 100.0, 3.0])
    fell = np.array([False] * 6 + [True])
    w, v = warped_scores(y, fell), value_scores(y, fell)
    ok = ~fell
    assert np.array_equal(np.argsort(w[ok]), np.argsort(y[ok]))
    assert w[ok].mean() == pytest.approx(0.0, abs=1e-9) and w[ok].std() == pytest.approx(1.0)
    assert w[6] == pytest.approx(w[ok].max() + 1.0)
    # the spread of the five good costs relative to the whole spread: the warp keeps more of it
    spread = (lambda s: (s[4] - s[0]) / (s[5] - s[0]))
    assert spread(w) > 3 * spread(v)
    assert np.array_equal(warped_scores(y[:2], fell[:2]), rank_scores(y[:2], fell[:2]))


@pytest.mark.parametrize("scale", [1e155, 1e299, 1e-200])
def test_values_and_warped_scores_of_huge_or_tiny_costs_are_those_of_their_scale(tmp_path, src,
                                                                                  scale):
    """Standing costs some 1e155 apart (a diverged simulation that does not fail: squared
    states) overflowed the standard deviation: ``value_scores`` were all 0 (a flat target
    model, silently), and ``warped_scores`` NaN, so ``--target-scores warped`` and ``auto``
    ended phase 3 with "ValueError: cannot convert float NaN to integer" (costs 1e-200 apart
    underflowed alike). Scores are now those of the same costs at scale 1, and phase 3 runs."""
    from latentune.critic.transfer_model import value_scores, warped_scores

    y = np.array([1.0, 1.1, 1.2, 1.3, 1.5, 100.0, 3.0])
    fell = np.array([False] * 6 + [True])
    for scores in (value_scores, warped_scores):
        assert np.allclose(scores(scale * y, fell), scores(y, fell), atol=1e-9)
    sys_ = lt.FunctionSystem(SPACE, lambda x: scale * float(np.sum((x - 0.3) ** 2)))
    for kind in ("warped", "auto"):
        with lt.Study(tmp_path / kind, seed=0) as st:
            st.phase3(sys_, 8, latent=src, transfer_options={"target_scores": kind})
            assert st.store.count(Phase.PHASE3) == 8


def test_a_model_fit_that_failed_is_said_by_status_and_the_report(tmp_path, src, monkeypatch):
    """A phase 3 whose source model fit raised (kept its starting hyperparameters): its
    decision records it, and the report's "Phase 3 decisions" says which fit, in which ask."""
    import latentune.critic.transfer_model as tm
    from latentune.pipeline.results import decisions

    def broken(mll):
        raise RuntimeError("NotPSDError: not positive definite")

    monkeypatch.setattr(tm, "_scipy_fit", broken)
    with lt.Study(tmp_path / "t", seed=0) as st:
        st.phase3(plant(0.2), 4, latent=src)
        said = [d["fit_failed"] for d in decisions(st.store) if "fit_failed" in d]
        assert said and "NotPSDError" in said[0]["source cost model"]
        st.report(simulate=False)
        summary = st.status()["decisions"]
    assert summary["fit_failed"] == len(said)
    text = (tmp_path / "t" / "report.md").read_text()
    assert "model fit that failed" in text and "source cost model (RuntimeError: NotPSDError" \
        in text
