"""The transfer phase 3 (latentune.critic.transfer): its models, its search and its resume."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.critic.transfer import LEGACY_OPTIONS, TRANSFER_DEFAULTS, Transfer, elite_points
from latentune.critic.transfer_model import SourceModel, TargetModel, rank_scores

D = 8


def _bowl(X: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Cost = 10·distance to ``centre``; a trial fails beyond ``radius`` (cost 100 + distance)."""
    r = np.sqrt(((np.atleast_2d(X) - centre) ** 2).sum(1))
    fell = r > radius
    return np.where(fell, 100.0 + r, 10.0 * r), fell


@pytest.fixture(scope="module")
def source() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    c = np.full(D, 0.4)
    X = np.clip(c + 0.25 * rng.standard_normal((160, D)), 0, 1)
    y, f = _bowl(X, c, 0.6)
    return X, y, f, c


@pytest.fixture(scope="module")
def hypers(source):
    X, y, f, _ = source
    return SourceModel(X, y, f, seed=0).hypers


def _critic(source, hypers, manual=None, **kw) -> Transfer:
    X, y, f, _ = source
    cr = Transfer((X, y, f), None, manual, batch_size=1, seed=3, **kw)
    cr.load_state_dict({"source_hypers": hypers})
    return cr


def _run(cr: Transfer, centre: np.ndarray, radius: float, n: int) -> tuple[list, list]:
    costs, falls = [], []
    for _ in range(n):
        X = cr.ask(1)
        y, f = _bowl(X, centre, radius)
        cr.tell(X, y, cr.last_tags, fell=f)
        costs.append(float(y[0]))
        falls.append(bool(f[0]))
    return costs, falls


def test_rank_scores_put_falls_last_and_share_ties():
    z = rank_scores(np.array([5.0, 1.0, 0.5, 1.0, np.nan]), np.array([0, 0, 1, 0, 0], bool))
    assert z[1] == z[3]                                 # tie
    assert z[1] < z[0]                                  # lower cost, better score
    assert z[2] > z[0] and z[4] > z[0]                  # the fall and the nan rank last
    assert np.argmax(z) in (2, 4)


def test_source_model_ranks_like_the_source(source, hypers):
    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    near, far = c + 0.02, np.clip(c + 0.5, 0, 1)
    m = sm.cost(np.stack([near, far]))
    assert m[0] < m[1]
    p = sm.fall_prob(np.stack([near, far]))
    assert p[0] < 0.3 < p[1]


def test_agreement_follows_the_target(source, hypers):
    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(1)
    Xt = np.clip(c + 0.2 * rng.standard_normal((12, D)), 0, 1)
    same, _ = _bowl(Xt, c, 9.0)
    a_same = TargetModel(Xt, rank_scores(same, np.zeros(12, bool)), sm.cost,
                         sm.lengthscales).coefficients()[0][0]
    a_flip = TargetModel(Xt, rank_scores(-same, np.zeros(12, bool)), sm.cost,
                         sm.lengthscales).coefficients()[0][0]
    assert a_same > 0.5 > a_flip


def test_elite_points_are_diverse_and_stable(source):
    X, y, f, _ = source
    idx = elite_points(X, rank_scores(y, f), f, 5, 0.1)
    assert len(idx) == 5 and not f[idx].any()
    assert idx[0] == int(np.argmin(np.where(f, np.inf, y)))
    dist = [np.linalg.norm(X[i] - X[j]) / np.sqrt(D) for i in idx for j in idx if i < j]
    assert min(dist) >= 0.1


def test_small_gap_improves_on_the_zero_shot_with_few_falls(source, hypers):
    X, y, f, c = source
    target_c = np.clip(c + 0.05, 0, 1)
    cr = _critic(source, hypers, manual=np.full(D, 0.5))
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, target_c, 0.5)
    cr.tell(best[None], y0, fell=f0)
    costs, falls = _run(cr, target_c, 0.5, 15)
    assert min(costs) < 0.8 * y0[0]
    assert sum(falls) <= 2
    assert cr.decisions[0]["design"] and not cr.decisions[-1]["design"]


def test_harsh_target_leaves_the_failing_region(source, hypers):
    """Every source-stable θ fails on the target (its stable region moved to the far corner,
    where the manual θ lies): the search must find stable trials after a few falls."""
    X, y, f, _ = source
    corner = np.full(D, 0.9)
    cr = _critic(source, hypers, manual=np.full(D, 0.85))
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.3)
    assert f0[0]
    cr.tell(best[None], y0, fell=f0)
    costs, falls = _run(cr, corner, 0.3, 15)
    assert not all(falls)
    assert falls.index(False) <= 5


def test_every_trial_fell_asks_the_manual_theta_once_per_batch(source, hypers):
    """After the zero-shot θ fell, a batch of 3 is the manual θ and two other θ, never the
    manual θ again (the old rule asked it 3 times); the generation's decision names the rule
    and puts the manual θ's pool first; a batch of 1 is the manual θ alone."""
    X, y, f, _ = source
    corner = np.full(D, 0.9)
    manual = np.full(D, 0.85)
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.3)
    for n in (3, 1):
        cr = _critic(source, hypers, manual=manual)
        cr.tell(best[None], y0, fell=f0)
        B = cr.ask(n)
        assert B.shape == (n, D) and np.array_equal(B[0], manual)
        assert len({tuple(r) for r in B}) == n
        assert cr.last_z.shape[0] == n and cr.last_tags[0] % 4 == 0    # the elite pool
        d = cr.decisions[-1]
        assert "manual" in d["rule"] and d["pools"][0] == "elite" and len(d["pools"]) == n


def test_resume_asks_what_the_original_would(source, hypers):
    X, y, f, c = source
    a = _critic(source, hypers)
    _run(a, c, 0.6, 6)
    b = _critic(source, hypers)
    b.tell(a.X, a.y, a.tags, fell=a.fell)
    assert np.array_equal(a.ask(2), b.ask(2))
    assert np.array_equal(a.last_tags, b.last_tags)


def test_target_model_chooses_the_lengthscale_the_target_needs(source, hypers):
    """A target that varies on a quarter of the source's lengthscale: with a choice of scales,
    maximum likelihood takes a shorter one than the source's."""
    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(4)
    Xt = rng.random((25, D))
    v = np.sin(Xt @ (4.0 / sm.lengthscales))
    one = TargetModel(Xt, v, sm.cost, sm.lengthscales)
    free = TargetModel(Xt, v, sm.cost, sm.lengthscales, ls_scales=(0.25, 0.5, 1.0, 2.0))
    assert one.ls_scale == 1.0 and free.ls_scale < 1.0
    assert np.allclose(free.ls, sm.lengthscales * free.ls_scale)


def test_resume_uses_the_stored_options(source, hypers):
    """A resumed critic asks with the options its run was asked with, whatever today's defaults;
    a state stored before options were recorded resumes with the legacy options."""
    X, y, f, c = source
    a = _critic(source, hypers, length_init=0.6, acquisition="ei")
    _run(a, c, 0.6, 5)
    b = _critic(source, hypers)
    b.tell(a.X, a.y, a.tags, fell=a.fell)
    b.load_state_dict(a.state_dict())
    assert b.opts == a.opts
    assert np.array_equal(a.ask(1), b.ask(1))
    old = _critic(source, hypers)
    old.load_state_dict({"source_hypers": hypers, "last_decision": None})
    assert {k: old.opts[k] for k in LEGACY_OPTIONS if k != "max_fall_prob"} == \
        {k: v for k, v in LEGACY_OPTIONS.items() if k != "max_fall_prob"}


def test_options_are_checked(source):
    X, y, f, _ = source
    with pytest.raises(TypeError, match="unknown option"):
        Transfer((X, y, f), None, None, bogus=1)
    with pytest.raises(ValueError, match="max_fall_prob"):
        Transfer((X, y, f), None, None, max_fall_prob=1.5)
    with pytest.raises(ValueError, match="acquisition"):
        Transfer((X, y, f), None, None, acquisition="ucb")
    assert set(TRANSFER_DEFAULTS) >= {"max_fall_prob", "n_design"}


def test_study_phase3_default_is_transfer(tmp_path):
    """``Study.phase3`` runs the transfer strategy by default: the zero-shot trial is its first
    data, the manual θ is a candidate (not run unless chosen), the options record names it, a
    resume keeps it, and the plain strategy with a hand-over is refused for it."""
    import latentune as lt
    from latentune.constants import Phase
    from latentune.errors import UsageError

    space = lt.ParameterSpace(names=[f"w{i}" for i in range(6)], low=[0.0] * 6, high=[1.0] * 6,
                              manual=[0.5] * 6)

    def plant(shift: float):
        c = np.full(6, 0.3 + shift)

        def fn(w: np.ndarray):
            r = float(np.sqrt(((w - c) ** 2).sum()))
            return (100.0 + r, True) if r > 0.5 else (10.0 * r, False)
        return lt.FunctionSystem(space, fn)

    with lt.Study(tmp_path / "sim", seed=1) as sim:
        sim.phase1(plant(0.0), 40)
        sim.train_latent(latent_dim=2, epochs=30)
    with lt.Study(tmp_path / "real", seed=1) as real:
        r = real.phase3(plant(0.05), 10, latent=tmp_path / "sim")
        cfg = real.manifest.config()["phase3"]
        assert cfg["strategy"] == "transfer" and r.n == 10
        assert real.store.count(Phase.ZERO_SHOT) == 1
        assert real.store.count(Phase.MANUAL) == 0
        zs = real.store.rows(Phase.ZERO_SHOT)[0].cost
        assert r.best_cost <= zs
        with pytest.raises(UsageError,
                           match=r"handover is an option of the plain phase 3 \(strategy=.plain"):
            real.phase3(plant(0.05), 12, latent=tmp_path / "sim", strategy="transfer",
                        handover=True)
    with lt.Study(tmp_path / "real", seed=1) as again:
        again.phase3(plant(0.05), 12, latent=tmp_path / "sim")
        assert again.manifest.config()["phase3"]["strategy"] == "transfer"
        assert again.store.count(Phase.PHASE3) == 12


def test_params_at_a_negative_lower_bound_parse():
    """A physical value exactly at a negative bound is inside the space (the slack used to move
    a negative lower bound inward)."""
    import latentune as lt

    sp = lt.ParameterSpace(names=["a", "b"], low=[-1.0, -5.0], high=[1.0, -2.0], manual=[0.0, -3.0])
    np.testing.assert_allclose(sp.parse({"a": -1.0, "b": -5.0}), [0.0, 0.0])
    np.testing.assert_allclose(sp.parse({"a": 1.0, "b": -2.0}), [1.0, 1.0])
    with pytest.raises(Exception, match="outside"):
        sp.parse({"a": -1.01})


def test_design_screen_skips_elites_the_fall_model_rejects(source, hypers):
    """On a target where the source's best θ falls, the fall model soon rejects the elites near
    it: with ``design_screen`` the design gives way to the search (admissible θ only); without
    it, the design asks an elite over the screen."""
    X, y, f, _ = source
    corner = np.full(D, 0.9)
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.3)
    runs = {}
    for on in (False, True):
        cr = _critic(source, hypers, manual=np.full(D, 0.85), design_screen=on, explore_every=0)
        cr.tell(best[None], y0, fell=f0)
        runs[on] = (cr, _run(cr, corner, 0.3, 6)[1])
    off, on = runs[False][0].decisions, runs[True][0].decisions
    p = TRANSFER_DEFAULTS["max_fall_prob"]
    assert any(d["design"] and d.get("max_fall_prob_asked", 0.0) > p for d in off)
    assert any(d.get("design_screened") for d in on)
    assert all(d.get("max_fall_prob_asked", 0.0) <= p for d in on if d.get("design_screened"))
    assert not any(d.get("design_screened") for d in off)
    assert sum(runs[True][1]) < sum(runs[False][1])


def test_a_stored_run_resumes_without_options_added_later(source, hypers):
    """A state recorded before an option existed resumes with the behaviour it had then."""
    from latentune.critic.transfer import ADDED_OPTIONS

    a = _critic(source, hypers, **ADDED_OPTIONS)
    st = a.state_dict()
    for k in ADDED_OPTIONS:
        st["options"].pop(k)
    b = _critic(source, hypers, **{k: not v if isinstance(v, bool) else v
                                   for k, v in ADDED_OPTIONS.items()})
    b.load_state_dict(st)
    assert {k: b.opts[k] for k in ADDED_OPTIONS} == ADDED_OPTIONS


def test_target_ard_fit_finds_the_coordinates_the_target_needs(source, hypers):
    """A target that varies fast along two coordinates only: the fitted ARD lengthscales are
    short there and stay near the source's elsewhere, and the model predicts the target better
    than with the source's lengthscales."""
    from latentune.critic.transfer_model import fit_residual_kernel

    X, y, f, _ = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(5)
    Xt, Xq = rng.random((25, D)), rng.random((200, D))
    fn = lambda Z: np.sin(6 * Z[:, 0]) + np.cos(5 * Z[:, 1])  # noqa: E731
    base = TargetModel(Xt, fn(Xt), sm.cost, sm.lengthscales)
    ls, s2 = fit_residual_kernel(Xt, fn(Xt), base.hX[:, 0], (1.0, 0.0), base.ls, base.sigma_r2)
    assert ls[:2].max() < 0.5 * ls[2:].min()
    fitted = TargetModel(Xt, fn(Xt), sm.cost, ls, sigma_r2=s2)
    err = [np.sqrt(np.mean((m.mean_cov(Xq, False)[0] - fn(Xq)) ** 2)) for m in (base, fitted)]
    assert err[1] < 0.7 * err[0]


def test_fit_ard_option_fits_once_the_target_has_enough_trials(source, hypers):
    X, y, f, c = source
    cr = _critic(source, hypers, fit_ard=6)
    _run(cr, np.clip(c + 0.1, 0, 1), 0.6, 8)
    src_ls = cr.source_model().lengthscales
    assert "ls_ratio" not in cr.decisions[3] and "ls_ratio" in cr.decisions[-1]
    assert not np.allclose(cr.models()[0].ls, src_ls)
    plain = _critic(source, hypers)
    plain.tell(cr.X, cr.y, cr.tags, fell=cr.fell)
    assert np.allclose(plain.models()[0].ls, src_ls)


def test_safe_fallback_steps_back_instead_of_asking_over_the_screen(source, hypers):
    """Where the fall screen rejects every candidate, ``safe_fallback`` adds steps toward the
    best safe trial and asks one the screen admits; without it the critic asks over the
    screen."""
    X, y, f, _ = source
    corner = np.full(D, 0.6)
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.3)
    p = TRANSFER_DEFAULTS["max_fall_prob"]
    over = {}
    for on in (False, True):
        cr = _critic(source, hypers, manual=np.full(D, 0.6), safe_fallback=on, explore_every=0)
        cr.tell(best[None], y0, fell=f0)
        falls = _run(cr, corner, 0.3, 10)[1]
        over[on] = sum(d.get("max_fall_prob_asked", 0.0) > p for d in cr.decisions)
        used = [d for d in cr.decisions if d.get("safe_fallback")]
        assert bool(used) == on
        assert all(d["max_fall_prob_asked"] <= p for d in used)
        over[on, "falls"] = sum(falls)
    assert over[False] >= 1 and over[True] == 0
    assert over[True, "falls"] < over[False, "falls"]


def test_region_fallback_skips_the_design_and_brakes_where_its_steps_fall(source, hypers):
    """``safe_fallback="region"``: no fallback while the source's elites are the design, and
    where every step from the standing θ falls (only θ within 0.01 of the target's optimum
    stand) it stops after ``explore_falls`` = 3 fallen fallback trials, where
    ``safe_fallback=True`` keeps stepping back on (nearly) every ask."""
    X, y, f, _ = source
    corner = np.full(D, 0.6)
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.01)
    used = {}
    for mode in (True, "region"):
        cr = _critic(source, hypers, manual=corner, safe_fallback=mode)
        cr.tell(best[None], y0, fell=f0)
        _run(cr, corner, 0.01, 25)
        used[mode] = [d for d in cr.decisions if d.get("safe_fallback")]
        told = np.isin(cr.tags // 4, [d["generation"] for d in used[mode]])
        used[mode, "fell"] = int(cr.fell[told].sum())
    assert len(used[True]) >= 10 and any(d["design"] for d in used[True])
    assert not any(d["design"] for d in used["region"])
    assert 1 <= len(used["region"]) <= 3 == used["region", "fell"]
    with pytest.raises(ValueError, match="safe_fallback must be true, false or"):
        _critic(source, hypers, safe_fallback="always")


@pytest.mark.parametrize("counts", ["all", "after_stand"])
def test_fall_budget_asks_the_best_standing_theta_once_spent(source, hypers, counts):
    """``fall_budget`` 0.2 of a 10-trial budget allows 2 falls (every fall, or those after
    the first standing trial): once they are told every ask is the best standing θ, recorded
    as such, and the run falls no more; without a budget the same target keeps falling, and
    that run cut at the budget (``benchmarks.transfer.cut_at_fall_budget``) is the budgeted
    run. Bad values are refused."""
    from benchmarks.transfer import cut_at_fall_budget      # the ladders' derived runs
    from latentune.critic.transfer import counted_falls

    X, y, f, _ = source
    corner = np.full(D, 0.6)
    best = X[np.argmin(np.where(f, np.inf, y))]
    y0, f0 = _bowl(best, corner, 0.05)
    falls, runs = {}, {}
    for q in (0.0, 0.2):
        cr = _critic(source, hypers, manual=corner, fall_budget=q, budget=10,
                     fall_budget_counts=counts)
        cr.tell(best[None], y0, fell=f0)
        _run(cr, corner, 0.05, 9)
        falls[q], runs[q] = int(cr.fell.sum()), (cr.y.tolist(), cr.fell.tolist())
        spent = [i for i, d in enumerate(cr.decisions) if "fall_budget" in d]
        if q:
            assert cr.falls_allowed() == 2 and cr.fall_budget_spent and spent
            t0 = spent[0] + 1           # decision i asked trial i + 1 (trial 0: told above)
            assert counted_falls(cr.fell[:t0], counts) == 2 and not cr.fell[t0:].any()
            ok = ~cr.fell[:t0]
            assert np.allclose(cr.X[t0:], cr.X[:t0][ok][np.argmin(cr.y[:t0][ok])])
        else:
            assert cr.falls_allowed() is None and not spent
    assert falls[0.2] < falls[0.0]
    cut = cut_at_fall_budget({"costs": list(runs[0.0][0]), "failed": list(runs[0.0][1])}, 0.2,
                             counts)
    assert cut["costs"] == list(runs[0.2][0]) and cut["failed"] == list(runs[0.2][1])
    for kw, match in (({"fall_budget": 1.0}, "fall_budget must be"),
                      ({"fall_budget": 0.1, "budget": 0}, "budget must be"),
                      ({"fall_budget_counts": "some"}, "fall_budget_counts must be")):
        with pytest.raises(ValueError, match=match):
            _critic(source, hypers, **kw)


def test_the_fall_budget_counts_every_fall_or_those_after_the_first_stand():
    """Two falls allowed (0.1 of 20 trials): ``"all"`` counts the falls before the first
    standing trial too, ``"after_stand"`` only those after it; while every trial fell the
    budget is never spent (the search has no θ to stop at); the ladders' cut agrees."""
    from benchmarks.transfer import cut_at_fall_budget
    from latentune.critic.transfer import counted_falls, fall_budget_spent, falls_allowed

    assert falls_allowed(0.1, 20) == 2 and falls_allowed(0.01, 20) == 1
    early = np.array([1, 1, 0, 1], bool)          # two falls, a stand, a fall
    assert counted_falls(early, "all") == 3 and counted_falls(early, "after_stand") == 1
    assert fall_budget_spent(early, 0.1, 20, "all")
    assert not fall_budget_spent(early, 0.1, 20, "after_stand")
    assert fall_budget_spent(np.r_[early, True], 0.1, 20, "after_stand")
    assert not fall_budget_spent(np.ones(9, bool), 0.1, 20, "all")
    assert not fall_budget_spent(early, 0.0, 20) and not fall_budget_spent(early, 0.1, None)
    run = {"costs": [9.0, 8.0, 5.0, 7.0, 6.0, 4.0, 3.0] + [2.0] * 13,
           "failed": [True, True, False, True, False, True] + [False] * 14}
    for counts, end in (("all", 3), ("after_stand", 6)):
        cut = cut_at_fall_budget(run, 0.1, counts)
        assert cut["cut_at"] == end and cut["costs"][end:] == [5.0] * (20 - end)
        assert not any(cut["failed"][end:]) and cut["failed"][:end] == run["failed"][:end]


def test_tilt_learns_the_drift_a_gap_adds_and_extrapolates_it(source, hypers):
    """A target whose cost is the source's bowl plus a linear drift along coordinate 0 (the gap
    moved its optimum toward the face): with a tilt grid the model chooses a tilt by marginal
    likelihood and predicts the far side of coordinate 0 better, relative to the centre, than
    the model without a tilt, which leans on the source's prior there; on the source's own
    costs it chooses a smaller tilt."""
    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(2)
    Xt = np.clip(c + 0.15 * rng.standard_normal((20, D)), 0, 1)
    drift = lambda Z: _bowl(Z, c, 9.0)[0] - 12.0 * Z[:, 0]  # noqa: E731
    grid = (0.0, 0.25, 0.5, 1.0)
    v = rank_scores(drift(Xt), np.zeros(20, bool))
    flat, tilted = (TargetModel(Xt, v, sm.cost, sm.lengthscales, tilts=t) for t in ((0.0,), grid))
    assert flat.tilt == 0.0 and flat.hX.shape == (20, 2)
    assert tilted.tilt > 0 and tilted.hX.shape == (20, 2 + D)
    far = c.copy()
    far[0] = 0.95
    q = np.stack([c, far])
    assert np.diff(tilted.mean_cov(q, False)[0])[0] < np.diff(flat.mean_cov(q, False)[0])[0]
    assert tilted.mean_cov(q, False)[0][1] < tilted.mean_cov(q, False)[0][0]
    same = TargetModel(Xt, rank_scores(_bowl(Xt, c, 9.0)[0], np.zeros(20, bool)), sm.cost,
                       sm.lengthscales, tilts=grid)
    assert same.tilt < tilted.tilt


def test_tilt_option_records_and_is_checked(source, hypers):
    X, y, f, c = source
    assert TRANSFER_DEFAULTS["tilt"] == 0.0
    cr = _critic(source, hypers, tilt=1.0)
    _run(cr, np.clip(c + 0.1, 0, 1), 0.6, 5)
    assert all(d["tilt"] in (0.0, 0.25, 0.5, 1.0) for d in cr.decisions[1:])
    assert "tilt" not in _critic(source, hypers).decisions     # off: nothing recorded
    for bad in (-1.0, "1", True, 10.0):
        with pytest.raises(ValueError, match="tilt must be a number"):
            _critic(source, hypers, tilt=bad)


def test_fall_source_sd_screens_where_the_source_tried_nothing(source, hypers):
    """``fall_source_sd``: the source fall model's posterior sd joins the fall screen's bound.
    Its sd is small among the source's trials and near its prior's far from them, so the bound
    rises there and only there; off (the default) the screen is unchanged."""
    assert TRANSFER_DEFAULTS["fall_source_sd"] is False
    X, y, f, c = source
    sm = SourceModel(X, y, f, hypers=hypers)
    near, far = c[None, :], np.ones((1, D))
    assert sm.fall_sd(near)[0] < 0.5 * sm.fall_sd(far)[0]
    assert np.isclose(sm.fall_sd(far)[0] ** 2, sm.fall_gp.outputscale, rtol=0.05)
    # the GP's variance against BoTorch's posterior of the same hyperparameters
    import torch
    from botorch.models import SingleTaskGP
    from gpytorch.kernels import MaternKernel, ScaleKernel
    g, S = sm.fall_gp, sm.fall_gp.S
    k = ScaleKernel(MaternKernel(nu=2.5, ard_num_dims=D))
    k.base_kernel.lengthscale = torch.as_tensor(g.ls).reshape(1, D)
    k.outputscale = torch.tensor(g.outputscale)
    m = SingleTaskGP(torch.as_tensor(S), torch.zeros(len(S), 1, dtype=torch.float64),
                     covar_module=k.double(), outcome_transform=None)
    m.likelihood.noise = torch.tensor([hypers["fall"]["noise"]], dtype=torch.float64)
    m.eval()
    Q = np.random.default_rng(1).random((5, D))
    ref = m.posterior(torch.as_tensor(Q)).variance.detach().numpy().reshape(-1)
    assert np.allclose(g.variance(Q), ref, rtol=1e-4, atol=1e-8)
    # the screen before the target has data: unchanged off; on, the mean plus kappa sd
    P = np.vstack([near, far, Q])
    off = _critic(source, hypers)
    on = _critic(source, hypers, fall_source_sd=True, fall_kappa=1.5)
    sm = on.source_model()
    assert np.allclose(off._fall_prob(P, None), sm.fall_prob(P))
    assert np.allclose(on._fall_prob(P, None),
                       np.clip(sm.fall_prob(P) + 1.5 * sm.fall_sd(P), 0, 1))
    # with target data the two variances add under the root
    x_t = c[None, :] + 0.05
    y_t, f_t = _bowl(x_t, c, 0.6)
    for cr in (off, on):
        cr.tell(x_t, y_t, np.array([1]), fell=f_t)
    _, fm = on.models()
    assert np.allclose(on._fall_prob(P, fm), np.clip(
        fm.mean_cov(P, False)[0] + 1.5 * np.sqrt(fm.variance(P) + sm.fall_sd(P) ** 2), 0, 1))
    _, fm = off.models()
    assert np.allclose(off._fall_prob(P, fm), np.clip(
        fm.mean_cov(P, False)[0] + np.sqrt(fm.variance(P)), 0, 1))
    with pytest.raises(ValueError, match="fall_source_sd must be true or false"):
        _critic(source, hypers, fall_source_sd="yes")


def test_face_snap_puts_full_pool_coordinates_on_the_faces_their_region_reaches(source, hypers):
    """``face_snap``: a coordinate whose region reaches a face is set to it with the given
    probability; a coordinate whose region stays inside the box never is; off, the pool is the
    plain TuRBO draw (no coordinate exactly on a face)."""
    assert TRANSFER_DEFAULTS["face_snap"] == 0.0
    centre = np.full(D, 0.5)
    centre[0], centre[1] = 0.05, 0.97               # regions reach face 0 and face 1
    m = 4000
    for p in (0.0, 0.5, 1.0):
        cr = _critic(source, hypers, face_snap=p, full_shape="cube")
        P = cr._pool_full(m, 0.4, centre, np.random.default_rng(0))
        at0, at1 = P == 0.0, P == 1.0
        assert not at1[:, 0].any() and not at0[:, 1].any()     # only the face it reaches
        assert not (at0 | at1)[:, 2:].any()                     # interior regions: never
        moved = np.abs(P[:, :2] - centre[:2]) > 0               # perturbed by the mask
        share = np.array([at0[:, 0][moved[:, 0]].mean(), at1[:, 1][moved[:, 1]].mean()])
        assert np.allclose(share, p, atol=0.03), (p, share)
    # both faces in reach (a side over 1): the nearer face to the draw
    cr = _critic(source, hypers, face_snap=1.0, full_shape="cube")
    P = cr._pool_full(m, 2.0, centre, np.random.default_rng(1))
    assert np.isin(P[:, 2:][P[:, 2:] != 0.5], (0.0, 1.0)).all()
    for bad in (-0.1, 1.5, "0.5", True):
        with pytest.raises(ValueError, match="face_snap must be a probability"):
            _critic(source, hypers, face_snap=bad)


@pytest.mark.parametrize("scale, shift", [(1e9, 7.0), (1e-6, -3.0)])
def test_the_asks_do_not_depend_on_the_costs_units(source, scale, shift):
    """Costs in other units (every source and target cost mapped by ``scale·y + shift``, scale
    > 0): the critic asks the same θ, bit for bit, over 16 asks with falls among them — its
    models see ranks and relative margins only."""
    X, y, f, c = source

    def asks(a: float, b: float) -> np.ndarray:
        ys = a * y + b
        cr = Transfer((X, ys, f), None, np.full(D, 0.5), batch_size=1, seed=3)
        cr.load_state_dict({"source_hypers": SourceModel(X, ys, f, seed=0).hypers})
        out = []
        for _ in range(16):
            t = cr.ask(1)
            yt, ft = _bowl(t, c + 0.1, 0.5)
            cr.tell(t, a * yt + b, fell=ft)
            out.append(t[0])
        return np.array(out)

    base = asks(1.0, 0.0)
    fell = _bowl(base, c + 0.1, 0.5)[1]
    assert fell.any() and not fell.all()
    assert np.array_equal(asks(scale, shift), base)


def test_fall_fit_learns_that_small_steps_from_a_standing_theta_fall(source, hypers):
    """``fall_fit``: on a target where every other small step from a standing θ falls, the fall
    model chooses a shorter lengthscale and a larger nugget than the source's and screens out the
    small steps the fixed model admits; each decision records the choice; off (the default), the
    source's lengthscales and the fixed nugget, and no record."""
    assert TRANSFER_DEFAULTS["fall_fit"] is False
    rng = np.random.default_rng(5)
    x0 = source[3] + 0.1
    Xt = np.vstack([x0, x0 + 0.04 * rng.standard_normal((14, D))])
    ft = np.arange(len(Xt)) % 2 == 1
    yt = np.where(ft, 100.0, 1.0 + rng.random(len(Xt)))
    steps = x0 + 0.04 * rng.standard_normal((50, D))
    admitted, chosen = {}, {}
    for fit in (False, True):
        cr = _critic(source, hypers, fall_fit=fit)
        cr.tell(Xt, yt, np.ones(len(Xt), dtype=np.int64), fell=ft)
        fm = cr.models()[1]
        chosen[fit] = (fm.ls_scale, fm.noise)
        admitted[fit] = float(np.mean(cr._fall_prob(steps, fm) <= 0.3))
        cr.ask(1)
        assert cr.decisions[-1].get("fall_fit") == (list(chosen[fit]) if fit else None)
    assert chosen[False] == (1.0, 1e-2)
    assert chosen[True][0] < 1.0 and chosen[True][1] > 1e-2
    assert admitted[False] >= 0.2 and admitted[True] < 0.5 * admitted[False]
    with pytest.raises(ValueError, match="fall_fit must be true or false"):
        _critic(source, hypers, fall_fit="yes")


def _hole_target(c: np.ndarray):
    """A target where the source's optimum falls: θ within 0.445 of ``c`` (the source's 16 best
    standing trials) fall, cost 100 more; the cost is 10 × the distance to (0.7, …, 0.7)."""
    def target(T):
        T = np.atleast_2d(T)
        fell = np.sqrt(((T - c) ** 2).sum(1)) < 0.445
        cost = 10.0 * np.sqrt(((T - 0.7) ** 2).sum(1))
        return np.where(fell, 100.0 + cost, cost), fell
    return target


def test_record_walk_walks_down_the_source_record_once_its_top_fell(source, hypers):
    """``record_walk`` 3 on a target where the source's optimum falls (a hole of radius 0.445
    around it: the source's 16 best standing trials) and the rest stands: after the zero-shot θ and the design's elites fell, the
    asks walk down the source's standing trials from the rank quantile 1/4 on, each a source
    trial away from the told falls, and stop once one stood. Off, or where the source's best
    stands, nothing walks."""
    X, y, f, c = source

    target = _hole_target(c)

    ok = np.flatnonzero(~f)
    ranked = X[ok[np.argsort(y[ok], kind="stable")]]
    best = ranked[0]
    walks = {}
    for k in (0, 3):
        cr = _critic(source, hypers, record_walk=k)
        y0, f0 = target(best)
        cr.tell(best[None], y0, fell=f0)
        for _ in range(8):
            T = cr.ask(1)
            yt, ft = target(T)
            cr.tell(T, yt, cr.last_tags, fell=ft)
        walks[k] = [(i, d["walk_rank"]) for i, d in enumerate(cr.decisions) if "walk_rank" in d]
        if k:
            assert walks[k], "the walk never started"
            ranks = [r for _, r in walks[k]]
            assert ranks[0] >= len(ranked) // 4 and ranks == sorted(ranks)
            for i, r in walks[k]:
                t = i + 1                               # decision i asked told trial i + 1
                assert np.allclose(cr.X[t], ranked[r])
                assert not cr.fell[1:t][cr.fell[1:t]].size or \
                    np.abs(cr.X[1:t][cr.fell[1:t]] - ranked[r]).max(1).min() >= 0.15
            assert len(walks[k]) >= 2                         # a walk ask fell, one more
            assert all(cr.fell[i + 1] for i, _ in walks[k][:-1])     # it goes on after falls
            assert not cr.fell[walks[k][-1][0] + 1]            # and stops on a stand
    assert walks[0] == []
    far = np.full(D, 0.9)                               # a source optimum that stands: no walk
    cr = _critic(source, hypers, record_walk=3)
    cr.tell(far[None], *target(far)[:1], fell=target(far)[1])
    _ = [cr.tell((T := cr.ask(1)), target(T)[0], cr.last_tags, fell=target(T)[1])
         for _ in range(3)]
    assert cr.fell[0] or not any("walk_rank" in d for d in cr.decisions)


def test_record_cma_hands_the_asks_to_cma_es_once_the_record_fell(source, hypers):
    """``record_cma`` on the hole target: the same asks as the default until the zero-shot θ
    and the design's elites have fallen, then every ask is a CMA-ES draw (tag pool ``global``,
    recorded ``record_cma``), the first its screen admits. Where the source's best stands it
    never triggers. A value that is not a bool is refused."""
    X, y, f, c = source
    target = _hole_target(c)
    ok = np.flatnonzero(~f)
    best = X[ok[np.argmin(y[ok])]]
    runs = {}
    for on in (False, True):
        cr = _critic(source, hypers, record_cma=on)
        cr.tell(best[None], *target(best)[:1], fell=target(best)[1])
        for _ in range(8):
            T = cr.ask(1)
            yt, ft = target(T)
            cr.tell(T, yt, cr.last_tags, fell=ft)
        runs[on] = cr
    a, b = runs[False], runs[True]
    first = next(i for i, d in enumerate(b.decisions) if d.get("record_cma"))
    told = _critic(source, hypers, record_cma=True)      # the history the trigger saw
    told.tell(b.X[:first + 1], b.y[:first + 1], b.tags[:first + 1], fell=b.fell[:first + 1])
    assert told.record_fell() and b.fell[0], "it triggered before the record fell"
    assert np.array_equal(a.X[:first + 1], b.X[:first + 1]), "before it triggers: the default"
    assert all(d.get("record_cma") and d["pools"] == ["global"] for d in b.decisions[first:]
               if not d.get("rule"))
    P = b._pool_cma(b.opts["n_candidates"])
    assert P.shape == (b.opts["n_candidates"], D)
    far = np.full(D, 0.9)
    cr = _critic(source, hypers, record_cma=True)
    cr.tell(far[None], *target(far)[:1], fell=target(far)[1])
    _ = [cr.tell((T := cr.ask(1)), target(T)[0], cr.last_tags, fell=target(T)[1])
         for _ in range(4)]
    assert not any(d.get("record_cma") for d in cr.decisions)
    with pytest.raises(ValueError, match="record_cma must be true or false"):
        _critic(source, hypers, record_cma="yes")


def test_walk_pick_chooses_each_step_by_the_target_fall_model(source, hypers):
    """``walk_pick`` on the target of the test above: ``"fall"`` asks, among the walk's
    candidates, the one the target fall model (told the record's falls) finds least likely to
    fall, ``"band"`` the same within the step's band of ranks; each records the probability it
    chose by. Bad values of ``record_walk`` and ``walk_pick`` are refused."""
    X, y, f, c = source

    target = _hole_target(c)

    ok = np.flatnonzero(~f)
    ranked = X[ok[np.argsort(y[ok], kind="stable")]]
    first = {}
    for pick in ("rank", "fall", "band"):
        cr = _critic(source, hypers, record_walk=3, walk_pick=pick)
        cr.tell(ranked[:1], *target(ranked[0])[:1], fell=target(ranked[0])[1])
        for _ in range(8):
            before = cr.n_told
            T = cr.ask(1)
            d = cr.decisions[-1]
            if "walk_rank" in d:
                r = d["walk_rank"]
                assert np.allclose(T[0], ranked[r])
                assert ("walk_fall_prob" in d) == (pick != "rank")
                if pick != "rank":
                    free = np.array([np.abs(cr.X - s).max(1).min() > 1e-9 and
                                     (not cr.fell.any() or
                                      np.abs(cr.X[cr.fell] - s).max(1).min() >= 0.15)
                                     for s in ranked])
                    i = sum(1 for e in cr.decisions[:-1] if "walk_rank" in e)
                    lo, hi = ((0, len(ranked)) if pick == "fall" else
                              (len(ranked) * (i + 1) // 4, len(ranked) * (i + 2) // 4))
                    band = np.flatnonzero(free[lo:hi]) + lo
                    p = cr._fall_model(before).mean_cov(ranked[band], with_cov=False)[0]
                    assert lo <= r < hi and round(d["walk_fall_prob"], 3) == round(p.min(), 3)
                    assert d["walk_fall_prob"] == pytest.approx(p[band == r][0])
                first.setdefault(pick, r)
            yt, ft = target(T)
            cr.tell(T, yt, cr.last_tags, fell=ft)
        assert pick in first, f"walk_pick={pick}: the walk never started"
    assert first["fall"] != first["rank"]
    for bad in (-1, 2.5, True, "3"):
        with pytest.raises(ValueError, match="record_walk must be an integer"):
            _critic(source, hypers, record_walk=bad)
    with pytest.raises(ValueError, match="walk_pick must be one of"):
        _critic(source, hypers, walk_pick="cost")


def test_add_source_conditions_the_source_models_on_new_trials_and_keeps_the_rest(source,
                                                                                  hypers):
    """Source trials added while phase 3 runs move the source cost model toward them (the
    hyperparameters kept), leave the elites and the stored hyperparameters alone, reset a kept
    proposal, and a bad shape is refused."""
    X, y, f, c = source
    cr = _critic(source, hypers)
    elites = cr.elites().copy()
    P = c[None, :] + np.linspace(0, 0.05, 3)[:, None]          # where the source stood best
    before = cr.source_model().cost(P)
    cr.propose(2)
    assert cr._proposer is not None
    cr.add_source(P, np.full(3, y.max() * 10), np.ones(3, bool))     # now they fell
    after = cr.source_model().cost(P)
    assert np.all(after > before + 0.1)
    assert cr._proposer is None and np.array_equal(cr.elites(), elites)
    assert cr.source_model().hypers["cost"] == hypers["cost"]
    assert cr.state_dict()["source_hypers"]["cost"] == hypers["cost"]
    with pytest.raises(ValueError):
        cr.add_source(P, np.zeros(2), np.zeros(3, bool))



@pytest.fixture(scope="module")
def default_24(source, hypers) -> Transfer:
    """The default critic after 24 asks on the bowl moved by 0.1 (read only: the run both
    parametrizations of the scores test compare with)."""
    base = _critic(source, hypers)
    _run(base, np.clip(source[3] + 0.1, 0, 1), 0.5, 24)
    return base


@pytest.mark.parametrize("option, value, kind, n", [
    ("refine_scores", "warped", "refinement", 24),
    ("explore_scores", "values", "explore", 12)])     # its asks change from the first explore
def test_scores_of_one_kind_of_ask_change_those_asks_only_and_are_recorded(source, hypers,
                                                                           default_24,
                                                                           option, value,
                                                                           kind, n):
    """``refine_scores``: the refinement asks choose by a model of other scores;
    ``explore_scores``: the explore asks' target GP fits other scores. Each is recorded in the
    decisions of the asks it changed, and only those (never a design or rule ask, and the
    refinement option never an explore ask); the asks before the first such ask are the
    default's; a bad value is refused."""
    X, y, f, c = source
    with pytest.raises(ValueError, match=option):
        Transfer((X, y, f), None, None, **{option: "raw"})
    target_c = np.clip(c + 0.1, 0, 1)
    base, other = default_24, _critic(source, hypers, **{option: value})
    _run(other, target_c, 0.5, n)
    recs = [d for d in other.decisions if option in d]
    assert recs and all(r[option] == value and not r["design"] and r.get("rule") is None
                        and r["explore"] == (kind == "explore") for r in recs)
    assert not any(option in d for d in base.decisions)
    first = min(r["n_told"] for r in recs)
    assert np.array_equal(base.X[:first], other.X[:first])
    assert not np.array_equal(base.X[:n], other.X)


def test_loo_means_are_the_posterior_means_of_each_trial_left_out(source, hypers):
    """``TargetModel.loo_mean`` and ``TargetGP.loo_mean``: the closed form equals refitting
    without trial i (hyperparameters held) and predicting it; ``ranking_loss`` counts the
    wrongly ordered pairs, a fall below every standing trial, two falls not compared."""
    from latentune.critic.transfer_model import TargetGP, loo_means, matern52, ranking_loss
    from latentune.critic.turbo import TurboM

    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(1)
    Xt = rng.uniform(0, 1, (9, D))
    v = rng.standard_normal(9)
    tm = TargetModel(Xt, v, sm.cost, sm.lengthscales)
    for i in range(9):
        keep = np.arange(9) != i
        one = TargetModel(Xt[keep], v[keep], sm.cost, sm.lengthscales, sigma_r2=tm.sigma_r2)
        assert tm.loo_mean()[i] == pytest.approx(one.mean_cov(Xt[i:i + 1], False)[0][0],
                                                 rel=1e-6, abs=1e-8)
    gp = TargetGP(Xt, v, TurboM(D, batch_size=1, seed=0, n_regions=1), tm)
    i = 4
    keep = np.arange(9) != i
    K = gp.sigma_r2 * matern52(Xt, Xt, gp.ls) + gp.noise * np.eye(9)
    zs = (v - gp.med) / gp.s - gp.constant
    pred = gp.med + gp.s * (gp.constant + K[i, keep] @ np.linalg.solve(K[np.ix_(keep, keep)],
                                                                         zs[keep]))
    assert gp.loo_mean()[i] == pytest.approx(pred, rel=1e-6)
    L = np.linalg.cholesky(np.eye(2) * 2.0)
    assert np.allclose(loo_means(L, np.array([2.0, 4.0]), np.array([1.0, 1.0])), [-3.0, -7.0])
    yy = np.array([1.0, 2.0, 3.0, 9.0, 8.0])
    fell = np.array([False, False, False, True, True])
    assert ranking_loss(np.array([0.0, 1, 2, 3, 4]), yy, fell) == 0.0
    assert ranking_loss(np.array([0.0, 1, 2, 4, 3]), yy, fell) == 0.0   # two falls: not compared
    assert ranking_loss(np.array([1.0, 0, 2, 3, 4]), yy, fell) == pytest.approx(1 / 9)
    assert ranking_loss(np.array([0.0, 0, 2, 3, 4]), yy, fell) == pytest.approx(0.5 / 9)
    assert np.isnan(ranking_loss(np.zeros(2), np.ones(2), np.zeros(2, bool)))


def test_auto_scores_choose_by_the_targets_own_trials_and_are_recorded(source, hypers,
                                                                        default_24):
    """``target_scores="auto"``: every ask records its choice and both models' ranking losses;
    ranks while fewer than six target trials stood (so those asks are the default's), warped
    values only where their loss is lower; ``explore_scores="auto"`` records its choice on the
    explore asks alone; a bad value is still refused."""
    from latentune.critic.transfer import AUTO_MIN_STANDING, resolved_options

    X, y, f, c = source
    target_c = np.clip(c + 0.1, 0, 1)
    opts = dict(explore_pool="adaptive", explore_gp=True, explore_fall_prob=0.2)
    assert resolved_options(opts) == resolved_options({})   # the default critic's options:
    base = default_24                                       # its run on this target
    auto = _critic(source, hypers, target_scores="auto", **opts)
    _, falls = _run(auto, target_c, 0.5, 16)
    recs = [d for d in auto.decisions if "auto_scores" in d]
    assert recs and not any("auto_scores" in d for d in base.decisions)
    stood = np.cumsum(~np.asarray(falls))
    for d in recs:
        pick, loss_r, loss_w = d["auto_scores"]["cost"]
        if stood[d["n_told"] - 1] < AUTO_MIN_STANDING:
            assert (pick, loss_r, loss_w) == ("ranks", None, None)
        else:
            assert pick == ("warped" if loss_w < loss_r else "ranks")
    picks = [d["auto_scores"]["cost"][0] for d in recs]
    assert "warped" in picks             # on this smooth bowl the values order better
    first = min(d["n_told"] for d in recs if d["auto_scores"]["cost"][0] == "warped")
    assert np.array_equal(base.X[:first], auto.X[:first])
    assert not np.array_equal(base.X[:len(auto.X)], auto.X)
    ex = _critic(source, hypers, explore_scores="auto", **opts)
    _run(ex, target_c, 0.5, 16)
    recs = [d for d in ex.decisions if "auto_scores" in d]
    assert recs and all(d["explore"] and set(d["auto_scores"]) == {"explore"} for d in recs)
    with pytest.raises(ValueError, match="target_scores"):
        _critic(source, hypers, target_scores="automatic")


def test_a_source_run_replaced_by_a_smaller_one_is_refused(tmp_path):
    """A transfer phase 3 resumed after its source directory was replaced by another run (of
    the same space, with fewer trials than phase 3 began with) went on silently with that
    run's trials; it is refused in one line, as a source that is gone."""
    import shutil

    import latentune as lt
    from latentune.errors import LatentError

    space = lt.ParameterSpace(names=["a", "b", "c"], low=[0.0] * 3, high=[1.0] * 3,
                              manual=[0.5] * 3)
    plant = lt.FunctionSystem(space, lambda w: float(((w - 0.3) ** 2).sum()))
    for name, n in (("src", 16), ("other", 8)):
        with lt.Study(tmp_path / name, seed=0) as s:
            s.phase1(plant, n)
            s.train_latent(latent_dim=2, epochs=5)
    with lt.Study(tmp_path / "t", seed=0) as t:
        t.phase3(plant, 4, latent=tmp_path / "src")
    shutil.rmtree(tmp_path / "src")
    shutil.copytree(tmp_path / "other", tmp_path / "src")
    with lt.Study(tmp_path / "t", seed=0) as t:
        with pytest.raises(LatentError, match=r"holds 8 phase-1 trials, fewer than the 16 "
                                              r"phase 3 began with") as exc:
            t.phase3(plant, 8)
        assert "\n" not in str(exc.value) and t.store.count(3) == 4


def test_a_model_fit_that_failed_is_recorded_in_the_decision_of_its_ask(source, hypers,
                                                                         monkeypatch, caplog):
    """A source-model fit that raises (GPyTorch's NotPSDError is a RuntimeError) leaves the
    model at its starting hyperparameters, which changes what phase 3 asks: the warning is
    logged, and the ask's decision records which fit failed and why (before: the log line
    only, nothing in the record ``status`` and ``report`` read). A fit restored from the state
    is not a new failure."""
    import latentune.critic.transfer_model as tm

    def broken(mll):
        raise RuntimeError("NotPSDError: matrix not positive definite")

    X, y, f, c = source
    monkeypatch.setattr(tm, "_scipy_fit", broken)
    cr = Transfer((X, y, f), None, None, batch_size=1, seed=3, explore_every=0)
    with caplog.at_level("WARNING"):
        P = cr.ask(1)
    assert "source model fit failed" in caplog.text
    failed = cr.decisions[-1]["fit_failed"]
    assert set(failed) == {"source cost model", "source fall model"}
    assert "NotPSDError" in failed["source cost model"]
    cr.tell(P, *_bowl(P, c, 0.6)[:1], cr.last_tags, fell=_bowl(P, c, 0.6)[1])
    cr.ask(1)
    assert "fit_failed" not in cr.decisions[-1]          # said once, in the ask that fitted
    again = _critic(source, cr.state_dict()["source_hypers"], explore_every=0)
    again.ask(1)
    assert "fit_failed" not in again.decisions[-1]
    monkeypatch.undo()
    ok = _critic(source, hypers, explore_every=0)
    ok.ask(1)
    assert "fit_failed" not in ok.decisions[-1]


def test_a_target_gp_fit_that_failed_is_recorded_in_the_decision_of_its_ask(source, hypers,
                                                                            monkeypatch):
    """The explore asks' GP on the target's trials alone (TuRBO-m's fit) that raises keeps its
    starting hyperparameters: the decision of the ask that used it says so."""
    import botorch.optim.fit as bf

    def broken(mll, **kw):
        raise RuntimeError("NotPSDError: matrix not positive definite")

    X, y, f, c = source
    cr = _critic(source, hypers)
    P = cr.ask(1)
    cr.tell(P, _bowl(P, c, 0.6)[0], cr.last_tags, fell=_bowl(P, c, 0.6)[1])
    monkeypatch.setattr(bf, "fit_gpytorch_mll_scipy", broken)
    _run(cr, c, 0.6, 5)
    said = [d["fit_failed"] for d in cr.decisions if "fit_failed" in d]
    assert said and all(set(s) == {"target GP"} and "NotPSDError" in s["target GP"]
                        for s in said)
    assert all(d.get("explore") for d in cr.decisions if "fit_failed" in d)
