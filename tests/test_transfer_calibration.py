"""The transfer critic's fall screen calibrated on the target's own outcomes
(``fall_calibrate``): prequential scores, the Platt map, and the screen that uses it."""
from __future__ import annotations

import json
import numpy as np
import pytest
from scipy.optimize import approx_fprime

from latentune.critic.transfer import ADDED_OPTIONS, TRANSFER_DEFAULTS, Transfer
from latentune.critic.transfer_model import TargetModel, calibrated, fit_calibration

from test_transfer import D, _bowl, hypers, source  # noqa: F401 - shared fixtures
from test_transfer_explore import _critic, _run


def test_the_map_stays_the_identity_without_evidence_and_follows_the_outcomes():
    """No outcomes: the prior's mean, ``(0, 1)``, so a score is its probability. Scores of 0.3
    that never fell pull the map below the identity; scores of 0.05 that fell half the time pull
    it above; scores that say nothing of the outcomes (the same falls at every score) flatten it
    (``b`` well below 1)."""
    assert np.allclose(fit_calibration(np.empty(0), np.empty(0, bool)), [0.0, 1.0], atol=1e-6)
    s = np.array([0.05, 0.3, 0.6])
    assert np.allclose(calibrated(s, np.array([0.0, 1.0])), s)
    over = fit_calibration(np.full(30, 0.3), np.zeros(30, bool))
    assert calibrated(np.array([0.3]), over)[0] < 0.1
    under = fit_calibration(np.full(30, 0.05), np.arange(30) % 2 == 0)
    assert calibrated(np.array([0.05]), under)[0] > 0.3
    rng = np.random.default_rng(1)
    flat = fit_calibration(rng.uniform(0.01, 0.6, 200), rng.uniform(size=200) < 0.2)
    assert flat[1] < 0.5


def test_the_map_is_the_posterior_mode():
    """The fitted ``(a, b)`` is a stationary point of the negative log posterior written out
    here (logistic likelihood on ``logit s``, Gaussian prior ``N((0, 1), diag(1, 0.25))``)."""
    from scipy.special import logit

    rng = np.random.default_rng(2)
    s = rng.uniform(0.0, 0.7, 40)
    fell = rng.uniform(size=40) < s
    x = logit(np.clip(s, 0.01, 0.99))

    def nlp(ab):
        f = ab[0] + ab[1] * x
        return np.logaddexp(0, f).sum() - fell @ f + 0.5 * ab[0] ** 2 + 2.0 * (ab[1] - 1) ** 2

    ab = fit_calibration(s, fell)
    assert np.abs(approx_fprime(ab, nlp, 1e-7)).max() < 1e-3
    assert nlp(ab) < nlp(np.array([0.0, 1.0]))


def test_prequential_scores_are_out_of_sample(source, hypers):
    """Row t's score is the screen of the fall model fitted on rows 0 … t−1 alone (the source's
    fall model for row 0), whatever was told after it."""
    cr = _critic(source, hypers, fall_calibrate=True)
    _run(cr, 6)
    pre = cr.prequential_scores()
    assert pre.shape == (6,)
    sm = cr.source_model()
    assert np.isclose(pre[0], cr._fall_score(cr.X[:1], None)[0])
    for t in (1, 3, 5):
        fm = TargetModel(cr.X[:t], cr.fell[:t].astype(float), sm.fall_prob,
                         sm.fall_lengthscales, prior_mean=(1.0, 0.0))
        assert np.isclose(pre[t], cr._fall_score(cr.X[t:t + 1], fm)[0])


def test_the_screen_takes_the_calibrated_probability(source, hypers):
    """With ``fall_calibrate`` each decision records the map fitted on the trials told before
    it, and the probability the screen compares with ``max_fall_prob`` is the map of the score;
    without it the score itself. A fresh critic told the same trials asks the same θ."""
    cr = _critic(source, hypers, fall_calibrate=True)
    _run(cr, 5)
    ab = np.array(cr.decisions[-1]["fall_calibration"])
    assert np.allclose(ab, fit_calibration(cr.prequential_scores()[:4], cr.fell[:4]))
    _, fall_m = cr.models()
    C = np.random.default_rng(0).uniform(size=(7, D))
    assert np.allclose(cr._fall_prob(C, fall_m),
                       calibrated(cr._fall_score(C, fall_m), cr.calibration()))
    plain = _critic(source, hypers)
    _run(plain, 5)
    assert "fall_calibration" not in plain.decisions[-1]
    assert np.allclose(plain._fall_prob(C, fall_m), plain._fall_score(C, fall_m))
    fresh = _critic(source, hypers, fall_calibrate=True)
    fresh.tell(cr.X, cr.y, cr.tags, fell=cr.fell, z=cr._Z)
    assert np.allclose(fresh.ask(1), cr.ask(1))


def test_calibration_is_off_by_default_and_checked(source, hypers):
    assert TRANSFER_DEFAULTS["fall_calibrate"] is False and ADDED_OPTIONS["fall_calibrate"] is False
    for bad in (1, "yes", None):
        with pytest.raises(ValueError, match="fall_calibrate"):
            _critic(source, hypers, fall_calibrate=bad)


def test_screen_bands_count_each_ask_in_the_band_of_its_probability():
    """``benchmarks.transfer_falls.screen_bands``: the zero-shot trial (no decision) and the
    manual θ (no probability) are not counted; each other ask counts in the band of its
    ``max_fall_prob_asked`` (bands closed below), with its fall."""
    from benchmarks.transfer_falls import PF_EDGES, screen_bands

    trace = {"failed": [True, True, False, True, False, False],
             "decisions": [{"pools": ["elite"]},
                           {"max_fall_prob_asked": 0.0, "pools": ["elite"]},
                           {"max_fall_prob_asked": 0.25, "pools": ["full"]},
                           {"max_fall_prob_asked": 0.1, "pools": ["full"]},
                           {"max_fall_prob_asked": 1.0, "pools": ["latent"]}]}
    assert PF_EDGES == (0.0, 0.1, 0.2, 0.3, 1.0)
    assert screen_bands(trace).tolist() == [[1, 0], [1, 0], [1, 1], [1, 0]]


def test_region_steps_count_trust_region_asks_by_their_step_from_the_best_standing_theta():
    """``benchmarks.transfer_falls.region_steps``: design and explore asks and asks made while
    no trial stood are not counted; a region ask counts in the band of its largest coordinate
    step from the best θ that did not fall before it."""
    from benchmarks.transfer_falls import STEP_EDGES, region_steps

    trace = {"failed": [True, False, False, True, False, True],
             "costs": [100.0, 5.0, 4.0, 100.0, 3.0, 100.0],
             "thetas": [[0.9, 0.9], [0.5, 0.5], [0.6, 0.5], [0.62, 0.5], [0.9, 0.1],
                        [0.3, 0.5]],
             "decisions": [{"design": True, "pools": ["elite"]},
                           {"pools": ["full"]},                     # step 0.1 from (0.5, 0.5)
                           {"pools": ["full"]},                     # 0.02 from (0.6, 0.5)
                           {"explore": True, "pools": ["latent"]},
                           {"pools": ["full"]}]}                    # 0.6 from (0.9, 0.1)
    assert STEP_EDGES == (0.0, 0.05, 0.2, 1.0)
    assert region_steps(trace).tolist() == [[1, 1], [1, 0], [1, 1]]


def test_kinds_sum_asks_and_falls_by_kind_over_the_traces(tmp_path, capsys):
    """``benchmarks.transfer_falls kinds``: trial 0 (the zero-shot θ) has no decision and is not
    counted; each ask counts with its trial's fall under its kind, explore asks whose own GP chose
    warped values apart; traces of other methods and of seeds not asked for are left out; a
    method with no trace is one line on stderr and exit 2, named as argparse's lines of the
    command are (it said ``transfer_falls kinds: no trace of ...``, without ``error:``)."""
    from benchmarks.transfer_falls import kinds, main

    def put(system, gap, seed, method, failed, decisions):
        d = tmp_path / system / f"gap{gap}" / f"seed{seed}"
        d.mkdir(parents=True, exist_ok=True)
        (d / f"{method}.json").write_text(json.dumps({"failed": failed,
                                                      "decisions": decisions}))

    warped = {"explore": True, "explore_pool": "lines", "auto_scores": {"explore": ["warped"]}}
    ranks = {"explore": True, "explore_pool": "lines", "auto_scores": {"explore": ["ranks"]}}
    put("arm", 1, 0, "m", [True, True, False, True, False],
        [{"design": True}, {"pools": ["full"]}, warped, ranks])
    put("hopper", 0.5, 1, "m", [False, False, True], [{"design": True}, warped])
    put("hopper", 0.5, 2, "m", [False, True], [{"design": True}])      # seed left out below
    put("hopper", 0.5, 1, "other", [False, True], [{"design": True}])
    rows = {r["kind"]: (r["asks"], r["falls"], r["runs"])
            for r in kinds(tmp_path, ["m"], seeds=[0, 1])}
    assert rows == {"design": (2, 1, 2), "full": (1, 0, 2), "explore lines (warped)": (2, 2, 2),
                    "explore lines": (1, 0, 2), "all": (6, 3, 2)}
    assert main(["kinds", "--root", str(tmp_path), "--methods", "none"]) == 2
    assert capsys.readouterr().err.strip() == ("python -m benchmarks.transfer_falls kinds: error: "
                                               f"no trace of none under {tmp_path}")
