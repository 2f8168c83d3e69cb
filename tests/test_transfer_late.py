"""The transfer critic's late phase (``handoff``): TuRBO-m's side rules and a cost model of the
target's own trials once the target has ``handoff`` own trials."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.critic.transfer import Transfer
from latentune.critic.transfer_model import SourceModel, TargetGP, TargetModel
from latentune.critic.turbo import TurboM

from test_transfer import D, _bowl, hypers, source  # noqa: F401 - shared fixtures


def _critic(source, hypers, **kw) -> Transfer:
    X, y, f, _ = source
    cr = Transfer((X, y, f), None, None, batch_size=1, seed=3, **kw)
    cr.load_state_dict({"source_hypers": hypers})
    return cr


def _run(cr: Transfer, centre: np.ndarray, n: int) -> None:
    for _ in range(n):
        X = cr.ask(1)
        y, f = _bowl(X, centre, 0.6)
        cr.tell(X, y, cr.last_tags, fell=f)


def _stalled_history(cr: Transfer, n: int) -> None:
    """One good untagged trial, then ``n`` own single-trial generations that never improve."""
    rng = np.random.default_rng(1)
    cr.tell(np.full((1, D), 0.4), np.array([0.0]), fell=np.array([False]))
    for g in range(n):
        cr.tell(rng.random((1, D)), np.array([5.0 + g]), np.array([4 * g + 1]),
                fell=np.array([False]))


def test_handoff_follows_turbos_side_rules(source, hypers):
    """On a stalled run the early rules halve the side every ``fail_tol`` generations; after
    the hand-off TuRBO-m halves it only after ``max(5, d)`` failed evaluations."""
    early, late = _critic(source, hypers), _critic(source, hypers, handoff=3)
    for cr in (early, late):
        _stalled_history(cr, 12)
    tm = TurboM(D, n_regions=1)
    # early: 12 failures, halved 4 times from 0.5; late: 1 halving in the 3 early generations,
    # then 9 failed evaluations: one TuRBO halving (failure_tol = 8)
    assert early._replay_state()["L"] == pytest.approx(0.5 / 16)
    assert tm.failure_tol == 8
    assert late._replay_state()["L"] == pytest.approx(0.5 / 4)
    assert late._side_rules(True) == (tm.success_tol, tm.failure_tol, tm.length_min,
                                      tm.length_max)


def test_handoff_models_the_target_alone(source, hypers):
    """After the hand-off the cost model is a GP on the target's trials (its lengthscales are
    its own, not the source's); before it the transfer model."""
    X, y, f, c = source
    cr = _critic(source, hypers, handoff=6)
    _run(cr, np.clip(c + 0.1, 0, 1), 5)
    assert isinstance(cr.models()[0], TargetModel)
    _run(cr, np.clip(c + 0.1, 0, 1), 5)
    m = cr.models()[0]
    assert isinstance(m, TargetGP)
    assert not np.allclose(m.ls, cr.source_model().lengthscales)
    assert "handoff" not in cr.decisions[4] and cr.decisions[-1]["handoff"]
    assert all("ls_ratio" in d for d in cr.decisions[6:])


def test_target_gp_finds_the_coordinate_the_target_varies_on(source, hypers):
    X, y, f, c = source
    sm = SourceModel(X, y, f, seed=0, hypers=hypers)
    rng = np.random.default_rng(5)
    Xt = rng.random((30, D))
    v = np.sin(6.0 * Xt[:, 2])
    base = TargetModel(Xt, v, sm.cost, sm.lengthscales)
    gp = TargetGP(Xt, v, TurboM(D, n_regions=1), base)
    assert int(np.argmin(gp.ls)) == 2
    mu, cov = gp.mean_cov(Xt[:5])
    assert np.allclose(mu, v[:5], atol=0.1)
    assert np.allclose(np.diag(cov), gp.variance(Xt[:5]))


@pytest.mark.parametrize("model", ["target", "prior", "transfer"])
def test_handoff_resume_asks_what_the_original_would(source, hypers, model):
    X, y, f, c = source
    a = _critic(source, hypers, handoff=4, handoff_model=model)
    _run(a, np.clip(c + 0.1, 0, 1), 8)
    b = _critic(source, hypers)
    b.tell(a.X, a.y, a.tags, fell=a.fell)
    b.load_state_dict(a.state_dict())
    assert b.opts["handoff"] == 4 and b.opts["handoff_model"] == model
    assert np.array_equal(a.ask(1), b.ask(1))
    assert np.array_equal(a.last_tags, b.last_tags)


def test_handoff_models_differ(source, hypers):
    """``prior`` fits the transfer model's residual lengthscales; ``transfer`` keeps them."""
    X, y, f, c = source
    ls = {}
    for model in ("prior", "transfer"):
        cr = _critic(source, hypers, handoff=4, handoff_model=model)
        _run(cr, np.clip(c + 0.1, 0, 1), 6)
        m = cr.models()[0]
        assert isinstance(m, TargetModel)
        ls[model] = m.ls
    src = SourceModel(X, y, f, seed=0, hypers=hypers).lengthscales
    assert np.allclose(ls["transfer"], src) and not np.allclose(ls["prior"], src)


def test_handoff_options_are_checked_and_stored_runs_resume_without_them(source, hypers):
    with pytest.raises(ValueError):
        _critic(source, hypers, handoff=-1)
    with pytest.raises(ValueError):
        _critic(source, hypers, handoff_model="source")
    old = _critic(source, hypers, handoff=5)
    opts = {k: v for k, v in old.opts.items() if k not in ("handoff", "handoff_model")}
    old.load_state_dict({"options": opts})
    assert old.opts["handoff"] == 0 and not old._handoff_active()


def test_handoff_fall_shrink_halves_the_side_after_a_late_fall(source, hypers):
    """With ``handoff_fall_shrink`` a late generation that fell halves the side (TuRBO-m's
    ``fall_shrink``); without it a fall is one failed evaluation like any other."""
    side = {}
    for on in (False, True):
        cr = _critic(source, hypers, handoff=3, handoff_fall_shrink=on)
        _stalled_history(cr, 4)
        cr.tell(np.full((1, D), 0.9), np.array([200.0]), np.array([4 * 4 + 1]),
                fell=np.array([True]))
        side[on] = cr._replay_state()["L"]
    assert side[False] == pytest.approx(0.25) and side[True] == pytest.approx(0.125)


def test_fall_shrink_halves_the_side_after_an_early_region_fall(source, hypers):
    """``fall_shrink``: in the early phase a region generation that fell halves the side and
    resets the counters (one generation that did not improve, then one that fell: 0.5 → 0.25;
    without it these are two failures of the three that halve it, and the side stays 0.5); a
    design generation (elite pool) that fell, and a fall while no trial stands, leave it."""
    side = {}
    for on in (False, True):
        cr = _critic(source, hypers, fall_shrink=on)
        _stalled_history(cr, 1)                     # generation 0 fails to improve
        cr.tell(np.full((1, D), 0.9), np.array([200.0]), np.array([4 * 1 + 1]),
                fell=np.array([True]))              # generation 1 falls: 2 failures, or halved
        side[on] = cr._replay_state()["L"]
    assert side[False] == pytest.approx(0.5) and side[True] == pytest.approx(0.25)
    design = _critic(source, hypers, fall_shrink=True)
    _stalled_history(design, 0)
    design.tell(np.full((1, D), 0.9), np.array([200.0]), np.array([4 * 0 + 0]),
                fell=np.array([True]))              # an elite fell: a failure, not a shrink
    assert design._replay_state()["L"] == pytest.approx(0.5)
    fell_only = _critic(source, hypers, fall_shrink=True)
    fell_only.tell(np.full((1, D), 0.9), np.array([200.0]), np.array([1]), fell=np.array([True]))
    assert fell_only._replay_state()["L"] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="fall_shrink"):
        _critic(source, hypers, fall_shrink=1)


def test_handoff_rules_transfer_changes_the_model_only(source, hypers):
    """``handoff_rules="transfer"``: the early side rules go on after the hand-off (the side of
    a stalled run is the default's) while the cost model is the target's GP."""
    early = _critic(source, hypers)
    late = _critic(source, hypers, handoff=3, handoff_rules="transfer")
    for cr in (early, late):
        _stalled_history(cr, 12)
    assert late._replay_state()["L"] == early._replay_state()["L"]
    assert isinstance(late.models()[0], TargetGP)
    with pytest.raises(ValueError):
        _critic(source, hypers, handoff_rules="cma")


def test_centre_falls_leaves_a_centre_whose_neighbours_fell(source, hypers):
    """``centre_falls=2``: the best standing θ (cost 1) with two of its three neighbours (within
    0.05 in every coordinate) fallen is fragile, and the centre is the next best standing θ
    (cost 2); with one neighbour fallen, or a neighbour 0.06 away, or the option off, the centre
    is the best. When every standing θ is fragile, the best. Decisions record the count."""
    best, second = np.full(D, 0.3), np.full(D, 0.7)

    def told(offsets: list[float], fell: list[bool], **kw) -> Transfer:
        cr = _critic(source, hypers, **kw)
        X = np.vstack([best, second] + [best + o for o in offsets])
        cr.tell(X, np.array([1.0, 2.0] + [200.0 if f else 3.0 for f in fell]),
                fell=np.array([False, False] + fell))
        return cr

    near = [0.02, -0.03, 0.04]
    cr = told(near, [True, True, False], centre_falls=2)
    assert np.array_equal(cr._centre(cr._fragile()), second)
    for offsets, fell, k in ((near, [True, False, False], 2), ([0.06, -0.06, 0.06],
                                                               [True, True, False], 2),
                             (near, [True, True, False], 0)):
        cr = told(offsets, fell, centre_falls=k)
        assert np.array_equal(cr._centre(cr._fragile()), best)
    both = _critic(source, hypers, centre_falls=1)
    both.tell(np.vstack([best, best + 0.01, second, second + 0.01]),
              np.array([1.0, 200.0, 2.0, 200.0]), fell=np.array([False, True, False, True]))
    assert both._fragile().tolist() == [True, False, True, False]
    assert np.array_equal(both._centre(both._fragile()), best)
    both.ask(1)
    assert both.decisions[-1]["centre_fragile"] == 2
    with pytest.raises(ValueError, match="centre_falls"):
        _critic(source, hypers, centre_falls=True)


class _Falling:
    """A fall model whose every bound is over 1: mean ``1.5 − θ_0``, standard deviation
    ``2 θ_0``, so the bound (``fall_kappa`` 1) is ``1.5 + θ_0``: lowest where θ_0 is small, the
    mean lowest where it is large."""

    def mean_cov(self, X, with_cov=True):
        return 1.5 - np.asarray(X)[:, 0], None

    def variance(self, X):
        return (2.0 * np.asarray(X)[:, 0]) ** 2


@pytest.mark.parametrize("how", ["clipped", "bound", "mean"])
def test_fall_rank_orders_the_least_likely_to_fall_when_every_bound_is_over_one(
        source, hypers, monkeypatch, how):
    """Every candidate's fall bound over 1 (the target's trials all fell): clipped they tie at
    1 and the screen keeps the first three generated; ``fall_rank="bound"`` keeps the three of
    lowest unclipped bound, ``"mean"`` the three of lowest posterior mean; the ask is among those
    kept, and the decision records the largest value of the order asked."""
    cr = _critic(source, hypers, fall_rank=how)
    for x in (0.35, 0.45, 0.4):
        cr.tell(np.full((1, D), x), np.array([150.0]), fell=np.array([True]))
    cost_m = cr.models()[0]
    monkeypatch.setattr(cr, "models", lambda: (cost_m, _Falling()))
    seen = {}
    chosen = cr._chosen

    def spy(cands, sel, ctx):
        seen.update(cands=cands, sel=sel)
        return chosen(cands, sel, ctx)

    monkeypatch.setattr(cr, "_chosen", spy)
    X = cr.ask(1)
    c, sel = seen["cands"], seen["sel"]
    assert len(c.X) > 3 and np.all(c.pf == 1.0)
    kept = np.flatnonzero(c.ok)
    d = cr.decisions[-1]
    assert d["max_fall_prob_asked"] == 1.0 and set(sel) <= set(kept)
    order = {"clipped": None, "bound": 1.5 + c.X[:, 0], "mean": 1.5 - c.X[:, 0]}[how]
    if order is None:
        np.testing.assert_array_equal(kept, [0, 1, 2])     # the first generated
        assert "max_fall_rank_asked" not in d
    else:
        np.testing.assert_array_equal(kept, np.sort(np.argsort(order, kind="stable")[:3]))
        assert d["max_fall_rank_asked"] == pytest.approx(
            1.5 + X[0, 0] if how == "bound" else 1.5 - X[0, 0])
    with pytest.raises(ValueError, match="fall_rank"):
        _critic(source, hypers, fall_rank=True)
