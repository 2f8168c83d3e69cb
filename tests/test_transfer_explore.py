"""The transfer critic's explore asks (``explore_every``): every k-th ask searches the whole
latent box (or θ box), and the trust region follows the other asks only."""
from __future__ import annotations

from typing import Callable

import numpy as np
import pytest

from latentune.critic.transfer import (ADDED_OPTIONS, FULL, GLOBAL, LATENT, TRANSFER_DEFAULTS,
                                       ExploreRecord, Transfer)
from latentune.critic.transfer_model import TargetGP

from test_transfer import D, _bowl, hypers, source  # noqa: F401 - shared fixtures

# what the critic asked before ``explore_every`` existed (seed 3, the linear latent space below,
# the target bowl centred at 0.5): θ (8, D) and tags (8,)
_BEFORE_X = np.array([
    (0.465157437267, 0.393638670827, 0.363238623288, 0.242355502507, 0.413841243728, 0.503029351282, 0.334052959865, 0.284168965073),
    (0.215966907167, 0.557782272286, 0.392644519346, 0.503156838801, 0.326929271845, 0.241250654353, 0.377331716223, 0.398750967431),
    (0.267014533677, 0.226847575704, 0.369864766428, 0.395688214068, 0.389753783826, 0.261119031622, 0.446856294472, 0.618903873883),
    (0.387254974969, 0.396724641356, 0.453140019828, 0.398688930644, 0.335586908185, 0.389939275625, 0.398891864460, 0.376595438253),
    (0.443052695619, 0.376610905028, 0.442451580281, 0.391246210733, 0.357045842527, 0.395988613770, 0.413744337088, 0.352790181734),
    (0.474448722950, 0.361629070618, 0.419952767960, 0.412215525275, 0.403614193271, 0.414197576030, 0.402438020400, 0.375953883638),
    (0.388363364545, 0.399238251682, 0.383762095557, 0.433042808051, 0.436238705660, 0.416963551175, 0.372285593897, 0.449638213675),
    (0.389710196970, 0.402612024404, 0.376369696067, 0.422595438539, 0.438434770488, 0.413031981757, 0.380689274126, 0.441103286516)])
_BEFORE_TAGS = [0, 4, 8, 14, 18, 22, 26, 30]


class _LinearLatent:
    """A 3-dim linear latent space of the D-dim θ box around 0.4 (codes in [0, 1]^3)."""

    d, d_low = D, 3

    def __init__(self) -> None:
        self.W = np.random.default_rng(4).standard_normal((3, D)) * 0.3

    def to_unit(self, z: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(z), 0, 1)

    def encode(self, th: np.ndarray) -> np.ndarray:
        return np.clip(0.5 + (np.atleast_2d(th) - 0.4) @ self.W.T, 0, 1)[0]

    def decode(self, U: np.ndarray) -> np.ndarray:
        return np.clip(0.4 + (np.atleast_2d(U) - 0.5) @ self.W, 0, 1)


def _critic(source, hypers, latent=True, **kw) -> Transfer:
    X, y, f, _ = source
    cr = Transfer((X, y, f), _LinearLatent() if latent else None, None, batch_size=1, seed=3,
                  **kw)
    cr.load_state_dict({"source_hypers": hypers})
    return cr


def _run(cr: Transfer, n: int) -> None:
    for _ in range(n):
        X = cr.ask(1)
        y, f = _bowl(X, np.full(D, 0.5), 0.6)
        cr.tell(X, y, cr.last_tags, fell=f, z=cr.last_z)


def test_off_asks_what_the_critic_asked_before(source, hypers):
    assert ADDED_OPTIONS["explore_every"] == 0      # stored runs from before resume without
    cr = _critic(source, hypers, explore_every=0, source_order="stored")
    _run(cr, 8)
    assert cr.tags.tolist() == _BEFORE_TAGS
    assert np.allclose(cr.X, _BEFORE_X, atol=1e-8)
    assert not any(d["explore"] for d in cr.decisions)


def test_every_second_ask_decodes_a_code_of_the_whole_latent_box(source, hypers):
    cr = _critic(source, hypers, explore_every=2)
    _run(cr, 8)
    ex = [d["generation"] for d in cr.decisions if d["explore"]]
    assert ex == [3, 5, 7]                  # after the design (0-2), g % 2 == 1
    for g in ex:
        assert cr.tags[g] % 4 == LATENT
        assert np.allclose(cr.X[g], cr.latent.decode(cr._Z[g][None, :])[0])
    # with no latent share the other asks perturb the centre; the explore asks still decode
    cr = _critic(source, hypers, explore_every=2, latent_share_max=0.0)
    _run(cr, 8)
    assert [t % 4 for t in cr.tags[3:]] == [LATENT, FULL, LATENT, FULL, LATENT]
    # whole box: the pool's codes are not confined around the centre's code
    U = cr._pool_latent(256, 1 / 128, cr._centre(), np.random.default_rng(0), whole=True)[1]
    assert U.min(0).max() < 0.05 and U.max(0).min() > 0.95


def test_without_a_latent_space_explore_asks_the_whole_theta_box(source, hypers):
    cr = _critic(source, hypers, latent=False, explore_every=2)
    _run(cr, 6)
    assert [d["explore"] for d in cr.decisions] == [False] * 3 + [True, False, True]
    assert [t % 4 for t in cr.tags[[3, 5]]] == [GLOBAL, GLOBAL]


def _history(cr: Transfer, explore_cost: float) -> None:
    """One good untagged trial, then 12 single-trial generations: the odd ones (explore asks for
    k = 2) from the latent pool at ``explore_cost``, the even ones from the full pool, never
    improving."""
    rng = np.random.default_rng(1)
    cr.tell(np.full((1, D), 0.4), np.array([0.0]), fell=np.array([False]))
    for g in range(12):
        pool, y = (LATENT, explore_cost) if g % 2 else (FULL, 5.0 + g)
        cr.tell(rng.random((1, D)), np.array([y]), np.array([4 * g + pool]),
                fell=np.array([bool(g % 2) and explore_cost > 50]))


@pytest.mark.parametrize("explore_cost", [9.0, -1.0, 99.0])
def test_explore_asks_leave_the_side_and_its_counters_alone(source, hypers, explore_cost):
    """Failing (9), improving (-1) or falling (99) explore trials: the k = 2 critic's side
    follows the 6 full-pool generations (two halvings), the k = 0 critic's all 12."""
    on = _critic(source, hypers, explore_every=2, explore_falls=0)    # no brake: test_brake_*
    off = _critic(source, hypers, explore_every=0)
    for cr in (on, off):
        _history(cr, explore_cost)
    st = on._replay_state()
    assert st["L"] == pytest.approx(0.5 / 4) and st["succ"] == 0
    assert st["latent_told"] == 0
    assert off._replay_state()["L"] != pytest.approx(0.5 / 4)
    if explore_cost < 0:                    # the explore trial is the best: the centre moves
        assert on.best_y == -1.0 and np.allclose(on._centre(), on.X[on.y.argmin()])


def _asks_alike(a: Transfer, b: Transfer, n: int) -> None:
    """``n`` asks of ``a`` and ``b`` in lockstep, each told the target bowl: the same θ, tags and
    explore decisions."""
    for _ in range(n):
        xa, xb = a.ask(1), b.ask(1)
        assert np.array_equal(xa, xb) and np.array_equal(a.last_tags, b.last_tags)
        assert a.decisions[-1]["explore"] == b.decisions[-1]["explore"]
        for cr, x in ((a, xa), (b, xb)):
            y, f = _bowl(x, np.full(D, 0.5), 0.6)
            cr.tell(x, y, cr.last_tags, fell=f, z=cr.last_z)


def test_resume_mid_run_asks_what_the_original_would(source, hypers):
    a = _critic(source, hypers, explore_every=2)
    _run(a, 6)                              # the next ask (generation 6) is not explore
    b = _critic(source, hypers)
    b.tell(a.X, a.y, a.tags, fell=a.fell, z=a._Z)
    b.load_state_dict(a.state_dict())
    assert b.opts["explore_every"] == 2
    _asks_alike(a, b, 2)                    # generations 6 and 7 (explore)
    assert a.decisions[-1]["explore"]
    old = _critic(source, hypers, explore_every=2)
    old.load_state_dict({"options": {k: v for k, v in a.opts.items() if k != "explore_every"}})
    assert old.opts["explore_every"] == 0


@pytest.mark.parametrize("bad", [1, -2, 2.5, True])
def test_explore_every_is_checked(source, hypers, bad):
    with pytest.raises(ValueError):
        _critic(source, hypers, explore_every=bad)


def test_stalled_explores_only_at_the_minimum_side(source, hypers):
    """``explore_when="stalled"``: a due generation explores only while the side it is asked at
    is ``length_min``; before that it is an ordinary ask that moves the side."""
    assert TRANSFER_DEFAULTS["explore_when"] == "always" == ADDED_OPTIONS["explore_when"]
    # a side held at its minimum: every due generation explores, as with "always"
    at_min = _critic(source, hypers, explore_every=2, explore_when="stalled",
                     length_init=1 / 128, length_max=1 / 128)
    _run(at_min, 8)
    assert [d["generation"] for d in at_min.decisions if d["explore"]] == [3, 5, 7]
    # a side far above it (never halved in 8 asks of a 3-batch fail_tol to the minimum):
    # no explore ask, and the asks are those of the critic without explore asks
    wide = _critic(source, hypers, explore_every=2, explore_when="stalled", source_order="stored")
    _run(wide, 8)
    assert not any(d["explore"] for d in wide.decisions)
    assert np.allclose(wide.X, _BEFORE_X, atol=1e-8)
    # the replayed history: due generations count in the side until it reaches the minimum
    on = _critic(source, hypers, explore_every=2, explore_when="stalled", length_init=1 / 32)
    _history(on, 9.0)                       # never improving: halve every 3 counted batches
    st = on._replay_state()
    assert st["L"] == pytest.approx(1 / 128)
    nd = st["explore_next"]
    assert on._explore_generation(13, st["L"], nd) and not on._explore_generation(12, st["L"], nd)
    assert not on._explore_generation(13, 1 / 32, nd)
    with pytest.raises(ValueError):
        _critic(source, hypers, explore_every=2, explore_when="sometimes")


def _fall_history(cr: Transfer, explore_fell: list[bool], start: int = 0) -> None:
    """(``start`` 0: one good untagged trial first,) then generation pairs from 2·start: even
    ones full pool (cost 5 + g), odd ones latent-pool explore trials that fell as
    ``explore_fell`` says (else cost 9)."""
    rng = np.random.default_rng(1 + start)
    if start == 0:
        cr.tell(np.full((1, D), 0.4), np.array([0.0]), fell=np.array([False]))
    for i, f in enumerate(explore_fell, start):
        for g, pool, y, fl in ((2 * i, FULL, 5.0 + 2 * i, False),
                               (2 * i + 1, LATENT, 150.0 if f else 9.0, f)):
            cr.tell(rng.random((1, D)), np.array([y]), np.array([4 * g + pool]),
                    fell=np.array([fl]))


def test_brake_stops_exploring_after_explore_falls_beyond_the_admitted_risk(source, hypers):
    """``explore_falls=3``: 3 of 3 explore trials fell (more than max_fall_prob 0.3 of them):
    the next due generation is an ordinary ask, recorded as braked; a resumed critic agrees."""
    assert TRANSFER_DEFAULTS["explore_falls"] == 3 and ADDED_OPTIONS["explore_falls"] == 0
    cr = _critic(source, hypers, explore_every=2, explore_falls=3, latent_share_max=0.0)
    _fall_history(cr, [True, True])
    assert not cr._replay_state()["explore_braked"]          # 2 falls: fewer than k
    _fall_history(cr, [True], start=2)
    st = cr._replay_state()
    assert st["explore_braked"] and st["explore_told"] == 3 and st["explore_fell"] == 3
    for _ in range(2):                                      # generations 6 (full) and 7 (due)
        x = cr.ask(1)
        y, f = _bowl(x, np.full(D, 0.5), 0.6)
        cr.tell(x, y, cr.last_tags, fell=f, z=cr.last_z)
    assert cr.decisions[-1]["generation"] == 7 and not cr.decisions[-1]["explore"]
    assert cr.decisions[-1]["explore_braked"] and cr.tags[-1] % 4 != LATENT   # not decoded
    b = _critic(source, hypers)
    b.tell(cr.X, cr.y, cr.tags, fell=cr.fell)
    b.load_state_dict(cr.state_dict())
    assert b._replay_state() == cr._replay_state()


def test_no_brake_while_explore_falls_stay_within_the_admitted_risk(source, hypers):
    """3 falls in 12 explore trials (25 % ≤ max_fall_prob 0.3): explore asks go on; with
    ``explore_falls=0`` they go on whatever falls."""
    few = [i % 4 == 3 for i in range(12)]
    cr = _critic(source, hypers, explore_every=2, explore_falls=3)
    _fall_history(cr, few)
    assert not cr._replay_state()["explore_braked"]
    cr = _critic(source, hypers, explore_every=2, explore_falls=0)
    _fall_history(cr, [True] * 6)
    assert not cr._replay_state()["explore_braked"]
    for _ in range(2):                                      # generations 12 and 13 (due)
        x = cr.ask(1)
        y, f = _bowl(x, np.full(D, 0.5), 0.6)
        cr.tell(x, y, cr.last_tags, fell=f, z=cr.last_z)
    assert cr.decisions[-1]["generation"] == 13 and cr.decisions[-1]["explore"]
    with pytest.raises(ValueError, match="explore_falls"):
        _critic(source, hypers, explore_falls=-1)


def test_no_brake_while_every_trial_fell(source, hypers):
    """Every explore trial fell and nothing on the target stands: the explore asks go on (the
    way out); one standing trial later, the brake holds."""
    cr = _critic(source, hypers, explore_every=2, explore_falls=3)
    rng = np.random.default_rng(3)
    for g in range(6):                      # full and explore generations, all fell
        pool = LATENT if g % 2 else FULL
        cr.tell(rng.random((1, D)), np.array([150.0]), np.array([4 * g + pool]),
                fell=np.array([True]))
    assert not cr._replay_state()["explore_braked"]
    cr.tell(rng.random((1, D)), np.array([5.0]), np.array([4 * 6 + FULL]), fell=np.array([False]))
    assert cr._replay_state()["explore_braked"]


@pytest.mark.parametrize("zero_shot_stands", [False, True])
def test_stand_first_keeps_the_side_while_every_trial_fell(source, hypers, zero_shot_stands):
    """``stand_first``: 9 full-pool generations that all fell leave L at length_init (off: three
    halvings), and the first standing trial then counts as a success at that side. With a
    standing (untagged) trial before them, the option changes nothing."""
    assert TRANSFER_DEFAULTS["stand_first"] is False and ADDED_OPTIONS["stand_first"] is False
    states = {}
    for on in (False, True):
        cr = _critic(source, hypers, explore_every=0, stand_first=on)
        rng = np.random.default_rng(5)
        if zero_shot_stands:
            cr.tell(np.full((1, D), 0.4), np.array([3.0]), fell=np.array([False]))
        for g in range(9):
            cr.tell(rng.random((1, D)), np.array([150.0]), np.array([4 * g + FULL]),
                    fell=np.array([True]))
        states[on, "fell"] = cr._replay_state()
        cr.tell(rng.random((1, D)), np.array([2.0]), np.array([4 * 9 + FULL]),
                fell=np.array([False]))
        states[on, "stood"] = cr._replay_state()
        x = cr.ask(1)
        assert cr.decisions[-1]["length"] == states[on, "stood"]["L"]
    L0 = TRANSFER_DEFAULTS["length_init"]
    if zero_shot_stands:
        assert states[True, "fell"] == states[False, "fell"]
        assert states[True, "stood"] == states[False, "stood"]
        return
    assert states[False, "fell"]["L"] == L0 / 8
    assert states[True, "fell"]["L"] == L0 and states[True, "fell"]["fail"] == 0
    assert states[True, "stood"]["L"] == L0 and states[True, "stood"]["succ"] == 1
    with pytest.raises(ValueError, match="stand_first"):
        _critic(source, hypers, stand_first="yes")


def test_explore_pool_source_draws_from_the_source_promising_distribution(source, hypers):
    from cmaes import get_warm_start_mgd

    assert ADDED_OPTIONS["explore_pool"] == "latent"    # stored runs resume as they ran
    cr = _critic(source, hypers, explore_pool="source")
    _run(cr, 8)
    ex = [d["generation"] for d in cr.decisions if d["explore"]]
    assert ex == [3, 5, 7]
    assert all(cr.tags[g] % 4 == GLOBAL and np.isnan(cr._Z[g]).all() for g in ex)
    # the pool is the Gaussian that warm-starts CMA-ES from the source's best tenth
    X, y, f = cr.source_rows()
    mu, sigma, cov = get_warm_start_mgd([(x, v) for x, v in zip(X[~f], y[~f])], 0.1, 0.1)
    P = cr._pool_source(4000, np.random.default_rng(0))
    assert P.shape == (4000, D) and P.min() >= 0 and P.max() <= 1
    inner = np.all(np.abs(P - 0.5) < 0.49, axis=1)      # unclipped draws
    assert np.abs(P[inner].mean(0) - mu).max() < 0.05
    # differs from the latent explore asks of the same seed
    lat = _critic(source, hypers)
    _run(lat, 8)
    assert not np.allclose(lat.X[3], cr.X[3])


def test_explore_pool_both_offers_half_of_each(source, hypers, monkeypatch):
    cr = _critic(source, hypers, explore_pool="both")
    seen = []
    orig = Transfer._pool_source

    def spy(self, m, rng):
        seen.append(m)
        return orig(self, m, rng)

    monkeypatch.setattr(Transfer, "_pool_source", spy)
    _run(cr, 4)
    assert seen == [TRANSFER_DEFAULTS["n_candidates"] // 2]      # the one explore ask (g = 3)
    assert cr.decisions[3]["explore"] and cr.tags[3] % 4 in (LATENT, GLOBAL)


@pytest.mark.parametrize("bad", ["cube", 1, None])
def test_explore_pool_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_pool"):
        _critic(source, hypers, explore_pool=bad)


def test_explore_pool_auto_decodes_while_every_trial_fell_then_draws_from_the_source(source,
                                                                                     hypers):
    cr = _critic(source, hypers, explore_pool="auto")
    rng = np.random.default_rng(2)
    cr.tell(rng.random((1, D)), np.array([9.0]), fell=np.array([True]))   # the zero-shot fell
    for _ in range(4):                           # design (0-2), then the explore ask g = 3
        X = cr.ask(1)
        cr.tell(X, np.full(1, 9.0), cr.last_tags, fell=np.array([True]), z=cr.last_z)
    assert cr.decisions[3]["explore"] and cr.tags[-1] % 4 == LATENT     # all fell: decoded
    X = cr.ask(1)                                                         # g = 4, ordinary
    cr.tell(X, np.array([1.0]), cr.last_tags, fell=np.array([False]), z=cr.last_z)
    X = cr.ask(1)                                                         # g = 5: explore
    assert cr.decisions[5]["explore"] and cr.last_tags[0] % 4 == GLOBAL  # a trial stood: source


def test_explore_pool_auto_brakes_each_pool_on_its_own(source, hypers):
    """Source draws that fall beyond the admitted risk hand the explore asks back to the latent
    box; latent codes that fall too end them."""
    cr = _critic(source, hypers, explore_pool="auto")
    cr.tell(np.full((1, D), 0.4), np.array([0.0]), fell=np.array([False]))     # a trial stands
    rng = np.random.default_rng(1)
    pools = []
    for g in range(16):
        X = cr.ask(1)
        d = cr.decisions[-1]
        pools.append((d["explore"], int(cr.last_tags[0] % 4)))
        explore_fell = d["explore"]                      # every explore trial falls
        cr.tell(X, np.array([50.0 if explore_fell else 1.0 + g]), cr.last_tags,
                fell=np.array([explore_fell]), z=cr.last_z)
    ex = [p for e, p in pools if e]
    # three source draws fall (3 > 0.3 · 3), three latent codes fall, then no explore ask
    assert ex == [GLOBAL] * 3 + [LATENT] * 3
    assert [g for g, (e, _) in enumerate(pools) if e] == [3, 5, 7, 9, 11, 13]
    assert not pools[15][0] and cr.decisions[15]["explore_braked"]          # due, braked


def _adapt_schedule(cr: Transfer, explore_cost: Callable[[int], float], n: int = 20) -> list[int]:
    """One good untagged trial, then ``n`` single-trial generations asked by the replayed
    schedule: a due one is a latent-pool trial at ``explore_cost(g)``, the others full-pool trials
    at 5 + g (never improving). The due generations."""
    rng = np.random.default_rng(2)
    cr.tell(np.full((1, D), 0.4), np.array([0.0]), fell=np.array([False]))
    due = []
    for g in range(n):
        st = cr._replay_state()
        if cr._explore_generation(g, st["L"], st["explore_next"]):
            due.append(g)
            pool, y = LATENT, explore_cost(g)
        else:
            pool, y = FULL, 5.0 + g
        cr.tell(rng.random((1, D)), np.array([y]), np.array([4 * g + pool]),
                fell=np.array([False]))
    return due


def test_adapt_doubles_the_wait_after_explore_asks_that_find_nothing(source, hypers):
    """``explore_adapt``: k = 2; explore asks that never improve come at generations 1, 5, 13
    (waits 4, 8, then the cap 16); improving ones every second generation, as without it; one
    that improves after one that did not brings the wait back to k."""
    assert TRANSFER_DEFAULTS["explore_adapt"] is False and ADDED_OPTIONS["explore_adapt"] is False
    kw = {"explore_every": 2, "explore_adapt": True, "explore_falls": 0}
    assert _adapt_schedule(_critic(source, hypers, **kw), lambda g: 9.0, 31) == [1, 5, 13, 29]
    assert _adapt_schedule(_critic(source, hypers, **kw), lambda g: -1.0 - g) == \
        list(range(1, 20, 2))
    assert _adapt_schedule(_critic(source, hypers, **kw),
                           lambda g: -1.0 - g if g >= 5 else 9.0) == [1, 5, 7, 9, 11, 13, 15, 17,
                                                                      19]
    fixed = _critic(source, hypers, explore_every=2, explore_falls=0)
    assert _adapt_schedule(fixed, lambda g: 9.0) == list(range(1, 20, 2))


def test_adapt_resume_asks_what_the_original_would(source, hypers):
    a = _critic(source, hypers, explore_every=2, explore_adapt=True)
    _run(a, 9)
    b = _critic(source, hypers)
    b.tell(a.X, a.y, a.tags, fell=a.fell, z=a._Z)
    b.load_state_dict(a.state_dict())
    assert b.opts["explore_adapt"] is True
    _asks_alike(a, b, 4)


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_explore_adapt_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_adapt must be true or false"):
        _critic(source, hypers, explore_every=2, explore_adapt=bad)


def test_full_shape_cube_perturbs_every_coordinate_on_the_same_side(source, hypers):
    """``full_shape="cube"``: the full pool's box has side L on every coordinate; by default the
    sides follow the source's lengthscales (short lengthscale, narrow side)."""
    assert TRANSFER_DEFAULTS["full_shape"] == "lengthscales" == ADDED_OPTIONS["full_shape"]
    centre = np.full(D, 0.5)
    spans = {}
    for shape in ("lengthscales", "cube"):
        cr = _critic(source, hypers, full_shape=shape)
        P = cr._pool_full(4000, 0.4, centre, np.random.default_rng(0))
        spans[shape] = P.max(0) - P.min(0)
    assert np.allclose(spans["cube"], 0.4, atol=0.01)
    ls = _critic(source, hypers).source_model().lengthscales
    w = np.clip(ls / np.exp(np.mean(np.log(ls))), 0.25, 4.0)
    assert np.allclose(spans["lengthscales"], np.minimum(0.4 * w, 1.0), atol=0.01)
    with pytest.raises(ValueError, match="full_shape must be one of"):
        _critic(source, hypers, full_shape="sphere")


def test_explore_pool_box_asks_the_whole_theta_box(source, hypers, monkeypatch):
    """``explore_pool="box"``: explore asks choose among Sobol points of the whole θ box (tag
    pool ``global``); the decoded manifold is not drawn for them."""
    whole_calls: list[bool] = []
    orig = Transfer._pool_latent

    def spy(self, m, L, centre, rng, whole=False):
        whole_calls.append(whole)
        return orig(self, m, L, centre, rng, whole=whole)

    monkeypatch.setattr(Transfer, "_pool_latent", spy)
    cr = _critic(source, hypers, explore_pool="box")
    _run(cr, 8)
    ex = [d["generation"] for d in cr.decisions if d["explore"]]
    assert ex == [3, 5, 7]
    assert all(cr.tags[g] % 4 == GLOBAL and np.isnan(cr._Z[g]).all() for g in ex)
    assert whole_calls and not any(whole_calls)     # only the region asks drew latent codes


def test_explore_pool_lines_moves_one_or_two_coordinates_of_the_centre(source, hypers,
                                                                       monkeypatch):
    """``explore_pool="lines"``: explore asks choose among the centre with one or two coordinates
    set anywhere in [0, 1] (tag pool ``global``), which reach the box's faces."""
    cr = _critic(source, hypers, explore_pool="lines", explore_gp=False)
    centre = np.full(D, 0.45)
    P = cr._pool_lines(2000, centre, np.random.default_rng(0))
    moved = (np.abs(P - centre) > 1e-12).sum(1)
    assert moved.max() <= 2 and (moved == 2).mean() > 0.3 and (moved == 1).mean() > 0.3
    assert P.min() < 0.01 and P.max() > 0.99
    centres: list[np.ndarray] = []
    orig = Transfer._pool_lines

    def spy(self, m, c, rng):
        centres.append(c.copy())
        return orig(self, m, c, rng)

    monkeypatch.setattr(Transfer, "_pool_lines", spy)
    _run(cr, 8)
    ex = [d["generation"] for d in cr.decisions if d["explore"]]
    assert ex == [3, 5, 7] and len(centres) == 3
    assert all(d["explore_pool"] == "lines" for d in cr.decisions if d["explore"])
    for g, c in zip(ex, centres):
        assert cr.tags[g] % 4 == GLOBAL
        assert (np.abs(cr.X[g] - c) > 1e-12).sum() <= 2


def test_lines_pick_fall_moves_the_gains_falls_depend_on_least(source, hypers):
    """``lines_pick="fall"``: a coordinate is set with probability ∝ the source fall model's
    lengthscale; by default, and where the source has no fall model, uniformly."""
    assert TRANSFER_DEFAULTS["lines_pick"] == "uniform" == ADDED_OPTIONS["lines_pick"]
    centre = np.full(D, 0.45)
    ls = np.array([0.05, 0.05, 0.05, 0.05, 2.0, 2.0, 2.0, 2.0])[:D]
    share = {}
    for pick in ("uniform", "fall"):
        cr = _critic(source, hypers, explore_pool="lines", lines_pick=pick)
        assert cr.source_model().fall_gp is not None
        cr.source_model().fall_gp.ls = ls.copy()
        P = cr._pool_lines(4000, centre, np.random.default_rng(0))
        moved = (np.abs(P - centre) > 1e-12).sum(0)
        share[pick] = moved[ls < 1].sum() / moved.sum()
    assert 0.4 < share["uniform"] < 0.6
    assert share["fall"] < 0.05                 # 0.05 / 2.05 of the picks, ~2.4 %
    cr = _critic(source, hypers, explore_pool="lines", lines_pick="fall")
    cr.source_model().fall_gp = None
    P = cr._pool_lines(4000, centre, np.random.default_rng(0))
    moved = (np.abs(P - centre) > 1e-12).sum(0)
    assert 0.4 < moved[ls < 1].sum() / moved.sum() < 0.6
    with pytest.raises(ValueError, match="lines_pick must be one of"):
        _critic(source, hypers, lines_pick="cost")


def test_explore_pool_lines_decodes_the_latent_box_while_every_trial_fell(source, hypers):
    """``explore_pool="lines"`` with nothing standing on the target: the explore ask decodes a
    code of the whole latent box (tag pool ``latent``); once a trial stands, lines again."""
    cr = _critic(source, hypers, explore_pool="lines", explore_falls=3, n_design=0)
    rng = np.random.default_rng(3)
    cr.tell(rng.random((1, D)), np.array([150.0]), np.array([4 * 0 + FULL]), fell=np.array([True]))
    assert cr._replay_state()["explore_pool"] == "latent"
    x = cr.ask(1)                                           # generation 1: due
    assert cr.decisions[-1]["explore"] and cr.last_tags[0] % 4 == LATENT
    assert cr.decisions[-1]["explore_pool"] == "latent"
    assert not np.isnan(cr.last_z).any()
    cr.tell(x, np.array([5.0]), cr.last_tags, fell=np.array([False]), z=cr.last_z)
    assert cr._replay_state()["explore_pool"] == "lines"


def test_explore_pool_latent_lines_offers_both_and_the_model_chooses(source, hypers, monkeypatch):
    """``explore_pool="latent_lines"``: each explore ask once a trial stands draws half its
    candidates as decoded codes of the whole latent box and half as lines through the centre;
    the chosen trial is one or the other (tag ``latent`` with its code, or ``global`` with at
    most two coordinates off the centre)."""
    calls: list[tuple[str, int]] = []
    lat, lin = Transfer._pool_latent, Transfer._pool_lines

    def spy_lat(self, m, L, c, rng, whole=False):
        if whole:
            calls.append(("latent", m))
        return lat(self, m, L, c, rng, whole)

    def spy_lin(self, m, c, rng):
        calls.append(("lines", m))
        return lin(self, m, c, rng)

    monkeypatch.setattr(Transfer, "_pool_latent", spy_lat)
    monkeypatch.setattr(Transfer, "_pool_lines", spy_lin)
    cr = _critic(source, hypers, explore_pool="latent_lines")
    _run(cr, 8)
    ex = [d["generation"] for d in cr.decisions if d["explore"]]
    assert ex == [3, 5, 7]
    M = TRANSFER_DEFAULTS["n_candidates"]
    assert calls == [("latent", M // 2), ("lines", M - M // 2)] * 3
    assert all(d["explore_pool"] == "latent_lines" for d in cr.decisions if d["explore"])
    for g in ex:
        assert cr.tags[g] % 4 in (LATENT, GLOBAL)
        if cr.tags[g] % 4 == LATENT:
            assert np.allclose(cr.X[g], cr.latent.decode(cr._Z[g][None, :])[0])


def test_explore_pool_adaptive_follows_each_pools_record(source, hypers):
    """``explore_pool="adaptive"``: the first explore ask decodes the latent box; each later one
    takes the pool with the higher ``(records + 1) / (asks + 2)`` over the told explore
    generations (latent on a tie), whose record the replay rebuilds from the tags and costs."""
    cr = _critic(source, hypers, explore_pool="adaptive", n_design=0)
    cost = iter([5.0, 6.0, 4.0, 3.0, 3.5, 3.2, 2.0, 2.5, 1.9, 4.0])
    pools: list[str] = []
    for _ in range(10):
        x = cr.ask(1)
        d = cr.decisions[-1]
        if d["explore"]:
            pools.append(d["explore_pool"])
            assert cr.last_tags[0] % 4 == (GLOBAL if d["explore_pool"] == "lines" else LATENT)
            lat, lin = d["explore_record"]["latent"], d["explore_record"]["lines"]
            assert (d["explore_pool"] == "lines") == \
                ((lin[1] + 1) / (lin[0] + 2) > (lat[1] + 1) / (lat[0] + 2))
        cr.tell(x, np.array([next(cost)]), cr.last_tags, fell=np.array([False]), z=cr.last_z)
    # generations 1, 3, 5, 7, 9 are explore asks: the latent box at 1 finds nothing (6.0 > 5.0),
    # so 3 tries the lines, which improve (3.0 < 4.0) and keep the asks at 5, 7 and 9 while their
    # record (records + 1) / (asks + 2) stays above the latent box's 1/3; after 9 they tie at 1/3
    assert pools == ["latent", "lines", "lines", "lines", "lines"]
    st = cr._replay_state()
    assert st["explore_record"] == {"latent": [1, 0], "lines": [4, 1]}
    assert st["explore_pool"] == "latent"


@pytest.mark.parametrize("mode, pool_at_9", [("count", "lines"), ("gain", "latent")])
def test_explore_record_gain_weighs_a_record_by_its_drop(source, hypers, mode, pool_at_9):
    """``explore_record="gain"``: the latent box's one record at generation 1 dropped the best
    by 3.0, the lines' one at 7 by 0.01. Counted, the lines' record (1 of 1 ask) outscores the
    latent box's (1 of 3) and takes the ask at 9; weighed by its drop over the mean drop
    (1.505), the latent box's scores (3.0 / 1.505 + 1) / 5 against the lines'
    (0.01 / 1.505 + 1) / 3, and keeps it. The replay rebuilds the drops from the costs."""
    cr = _critic(source, hypers, explore_pool="adaptive", explore_gp=False, n_design=0,
                 explore_record=mode)
    cost = iter([5.0, 2.0, 2.5, 3.0, 2.5, 3.0, 2.4, 1.99, 2.4])
    for _ in range(9):
        x = cr.ask(1)
        cr.tell(x, np.array([next(cost)]), cr.last_tags, fell=np.array([False]), z=cr.last_z)
    assert [d["explore_pool"] for d in cr.decisions if d["explore"]] == \
        ["latent", "latent", "latent", "lines"]
    st = cr._replay_state()
    assert st["explore_pool"] == pool_at_9
    rec = st["explore_record"]
    if mode == "gain":
        assert rec["latent"][:3] == [3, 1, 0] and rec["lines"][:3] == [1, 1, 0]
        assert rec["latent"][3:] == pytest.approx([3.0, 1]) and \
            rec["lines"][3:] == pytest.approx([0.01, 1])
    else:
        assert rec == {"latent": [3, 1], "lines": [1, 1]}
    cr.ask(1)
    assert cr.decisions[-1]["explore_pool"] == pool_at_9


def test_explore_record_gain_scores_records_of_equal_size_as_their_count(source, hypers):
    gain = _critic(source, hypers, explore_record="gain")
    count = _critic(source, hypers)
    own, other = ExploreRecord(4, 2, 1, 0.6, 2), ExploreRecord(3, 1, 0, 0.3, 1)
    assert gain._record_score(own, other) == pytest.approx(count._record_score(own, other))
    small, large = ExploreRecord(4, 2, 0, 0.02, 2), ExploreRecord(3, 1, 0, 3.0, 1)
    assert gain._record_score(small, large) < count._record_score(small, large)
    with pytest.raises(ValueError, match="explore_record"):
        _critic(source, hypers, explore_record="size")


def test_explore_bandit_thompson_gives_a_pool_behind_on_its_record_a_share_of_the_asks(source,
                                                                                      hypers):
    """``explore_bandit="thompson"``: with the latent box 0 records in 2 asks and the lines 6 in
    10, the posterior means (0.25 against 0.58) give every ask to the lines; draws from
    Beta(1, 3) and Beta(7, 5) give the latent box about 1 in 10 (exactly 5/52), each
    generation's draw seeded by (seed, generation), so a replay chooses the same pool."""
    rec = {LATENT: ExploreRecord(2, 0), GLOBAL: ExploreRecord(10, 6)}
    explore = np.zeros(0, dtype=bool)
    mean = _critic(source, hypers, explore_pool="adaptive")
    assert TRANSFER_DEFAULTS["explore_bandit"] == "mean" and \
        ADDED_OPTIONS["explore_bandit"] == "mean"
    assert {mean._explore_pool(explore, True, rec, g) for g in range(400)} == {"lines"}
    ts = _critic(source, hypers, explore_pool="adaptive", explore_bandit="thompson")
    picks = [ts._explore_pool(explore, True, rec, g) for g in range(400)]
    assert 0.06 < picks.count("latent") / 400 < 0.18
    assert picks == [ts._explore_pool(explore, True, rec, g) for g in range(400)]
    for g in range(40):                     # the draw: the run's seed, the generation, 13
        r = np.random.default_rng([ts.seed, g, 13])
        lat, lin = r.beta(1.0, 3.0), r.beta(7.0, 5.0)
        assert picks[g] == ("lines" if lin > lat else "latent")
    # in a run: the same seed draws the same pools; a resumed run's replay chooses alike
    _run(ts, 12)
    twin = _critic(source, hypers, explore_pool="adaptive", explore_bandit="thompson")
    _run(twin, 12)
    assert [d.get("explore_pool") for d in twin.decisions] == \
        [d.get("explore_pool") for d in ts.decisions]
    resumed = _critic(source, hypers)
    resumed.tell(ts.X, ts.y, ts.tags, fell=ts.fell, z=ts._Z)
    resumed.load_state_dict(ts.state_dict())
    assert resumed.opts["explore_bandit"] == "thompson"
    assert resumed._replay_state()["explore_pool"] == ts._replay_state()["explore_pool"]
    with pytest.raises(ValueError, match="explore_bandit"):
        _critic(source, hypers, explore_bandit="ucb")


def test_the_default_explore_pool_is_adaptive_and_a_stored_latent_run_resumes_latent(source,
                                                                                    hypers):
    """The default's explore asks choose their pool by its record (``"adaptive"``); a run stored
    with ``"latent"`` (the default before) resumes with it and asks what it would have asked."""
    assert TRANSFER_DEFAULTS["explore_pool"] == "adaptive"
    cr = _critic(source, hypers, n_design=0)
    cost = iter([5.0, 6.0, 4.0, 3.0, 3.5, 3.2, 2.0, 2.5])     # the latent explore ask finds
    for _ in range(8):                                         # nothing; the lines do
        x = cr.ask(1)
        cr.tell(x, np.array([next(cost)]), cr.last_tags, fell=np.array([False]), z=cr.last_z)
    assert [d["explore_pool"] for d in cr.decisions if d["explore"]] == \
        ["latent", "lines", "lines", "lines"]
    old = _critic(source, hypers, explore_pool="latent", n_design=0)
    _run(old, 5)
    again = _critic(source, hypers, n_design=0)
    again.tell(old.X, old.y, old.tags, fell=old.fell, z=old._Z)
    again.load_state_dict(old.state_dict())
    assert again.opts["explore_pool"] == "latent"
    _asks_alike(old, again, 3)
    assert {d["explore_pool"] for d in old.decisions if d["explore"]} == {"latent"}


def test_explore_pool_adaptive_without_a_latent_space_draws_lines(source, hypers):
    cr = _critic(source, hypers, latent=False, explore_pool="adaptive", n_design=0)
    _run(cr, 6)
    ex = [d for d in cr.decisions if d["explore"]]
    assert ex and all(d["explore_pool"] == "lines" for d in ex)


def _scripted(cr: Transfer, outcomes: list[tuple[float, bool]]) -> list[dict]:
    """Asks one θ per outcome and tells it ``(cost, fell)``; the decisions made."""
    for c, f in outcomes:
        x = cr.ask(1)
        cr.tell(x, np.array([c]), cr.last_tags, fell=np.array([f]), z=cr.last_z)
    return cr.decisions


@pytest.mark.parametrize("region_falls", [True, False])
def test_explore_void_takes_back_a_record_the_region_fell_around(source, hypers, region_falls):
    """``explore_void``: the lines' record at generation 3 (3.0 < 4.0) moves the centre to it; when
    the region ask told after it (generation 4) falls, the record is void: the centre goes back to
    generation 2's θ, the lines' record to none, and the next explore ask (5) decodes the latent
    box on the tie. When generation 4 stands, the record holds and the lines keep the ask."""
    cr = _critic(source, hypers, explore_pool="adaptive", explore_void=True, n_design=0,
                 explore_gp=False, explore_fall_prob=0.0)
    out = [(5.0, False), (6.0, False), (4.0, False), (3.0, False), (2.9 if not region_falls
                                                                   else 9.0, region_falls)]
    dec = _scripted(cr, out)
    assert [d["explore"] for d in dec] == [False, True, False, True, False]
    assert dec[3]["explore_pool"] == "lines" and cr.tags[3] % 4 == GLOBAL
    st = cr._replay_state()
    if region_falls:
        assert st["void"] == [3]
        assert st["explore_record"] == {"latent": [1, 0], "lines": [1, 0]}
        assert np.array_equal(cr._centre(np.arange(5) == 3), cr.X[2])
        assert st["explore_pool"] == "latent"
    else:
        assert st["void"] == []
        assert st["explore_record"] == {"latent": [1, 0], "lines": [1, 1]}
        assert np.array_equal(cr._centre(), cr.X[4])
        assert st["explore_pool"] == "lines"
    x = cr.ask(1)
    assert cr.decisions[-1]["explore_void"] == int(region_falls)
    # a fresh critic told the same history replays the void and asks the same θ
    fresh = _critic(source, hypers, explore_pool="adaptive", explore_void=True, n_design=0,
                    explore_gp=False, explore_fall_prob=0.0)
    fresh.tell(cr.X, cr.y, cr.tags, fell=cr.fell, z=cr._Z)
    assert np.allclose(fresh.ask(1), x)


def test_explore_void_off_keeps_the_record(source, hypers):
    cr = _critic(source, hypers, explore_pool="adaptive", n_design=0)
    _scripted(cr, [(5.0, False), (6.0, False), (4.0, False), (3.0, False), (9.0, True)])
    st = cr._replay_state()
    assert st["explore_record"]["lines"] == [1, 1] and st["void"] == []
    assert np.array_equal(cr._centre(), cr.X[3])


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_explore_void_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_void"):
        _critic(source, hypers, explore_void=bad)


@pytest.mark.parametrize("weight", [0.0, 1.0])
def test_explore_fall_weight_counts_a_fallen_explore_ask_against_its_pool(source, hypers, weight):
    """``explore_fall_weight`` = w: the lines' ask at generation 3 makes a record (3.0 < 4.0) and
    the one at 5 falls. Unweighted the lines score (1 + 1) / (2 + 2) against the latent box's
    1 / 3 and keep generation 7; with w = 1 they score (1 − 1 + 1) / 4 and the latent box takes
    it. The record then holds ``[asks, records, falls]``."""
    cr = _critic(source, hypers, explore_pool="adaptive", n_design=0, explore_fall_weight=weight)
    dec = _scripted(cr, [(5.0, False), (6.0, False), (4.0, False), (3.0, False), (2.9, False),
                         (9.0, True), (2.8, False)])
    assert [d.get("explore_pool") for d in dec if d["explore"]] == ["latent", "lines", "lines"]
    st = cr._replay_state()
    if weight:
        assert st["explore_record"] == {"latent": [1, 0, 0], "lines": [2, 1, 1]}
        assert st["explore_pool"] == "latent"
    else:
        assert st["explore_record"] == {"latent": [1, 0], "lines": [2, 1]}
        assert st["explore_pool"] == "lines"


@pytest.mark.parametrize("bad", [-0.5, 11, "1", True])
def test_explore_fall_weight_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_fall_weight"):
        _critic(source, hypers, explore_fall_weight=bad)


def test_centre_screen_moves_the_centre_off_a_trial_the_falls_around_it_condemn(source, hypers):
    """``centre_screen``: the best standing trial (cost 1.0) has four falls within 0.01 of it, so
    the fall screen rejects its θ; the centre becomes the next best standing trial the screen
    admits (cost 2.0, far from the falls), and the ask records ``centre_screened``. Without the
    option the centre stays at the best standing trial."""
    X, y, f, _ = source
    rng = np.random.default_rng(0)
    a, b = np.full(D, 0.3), np.full(D, 0.7)
    Xt = np.vstack([a, b, a + 0.01 * rng.uniform(-1, 1, (4, D))])
    yt = np.array([1.0, 2.0, 9.0, 9.0, 9.0, 9.0])
    ft = np.array([False, False, True, True, True, True])
    for on in (True, False):
        cr = _critic(source, hypers, n_design=0, centre_screen=on)
        cr.tell(Xt, yt, np.full(len(yt), -1), fell=ft)
        _, fall_m = cr.models()
        pf = cr._fall_prob(Xt[:2], fall_m)
        assert pf[0] > cr.opts["max_fall_prob"] >= pf[1]      # the screen condemns a, admits b
        void = np.zeros(len(yt), dtype=bool)
        c, moved = cr._screened_centre(cr._centre(void), void, fall_m)
        assert np.array_equal(c, b) and moved
        cr.ask(1)
        assert cr.decisions[-1].get("centre_screened", False) is on


def test_centre_screen_keeps_the_best_when_the_screen_admits_no_standing_trial(source, hypers):
    cr = _critic(source, hypers, n_design=0, centre_screen=True)
    a = np.full(D, 0.3)
    rng = np.random.default_rng(1)
    Xt = np.vstack([a, a + 0.01 * rng.uniform(-1, 1, (4, D))])
    cr.tell(Xt, np.array([1.0, 9.0, 9.0, 9.0, 9.0]), np.full(5, -1),
            fell=np.array([False, True, True, True, True]))
    _, fall_m = cr.models()
    c, moved = cr._screened_centre(cr._centre(), np.zeros(5, dtype=bool), fall_m)
    assert np.array_equal(c, a) and not moved


@pytest.mark.parametrize("bad", [1, "yes"])
def test_centre_screen_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="centre_screen"):
        _critic(source, hypers, centre_screen=bad)


class _CollapsedLatent(_LinearLatent):
    """A latent space whose decoder maps every code to one θ (a decoder that collapsed)."""

    def decode(self, U: np.ndarray) -> np.ndarray:
        return np.tile(np.full(D, 0.45), (len(np.atleast_2d(U)), 1))


def _run_batches(cr: Transfer, asks: int, n: int) -> None:
    for _ in range(asks):
        X = cr.ask(n)
        y, f = _bowl(X, np.full(D, 0.5), 0.6)
        cr.tell(X, y, cr.last_tags, fell=f, z=cr.last_z)


@pytest.mark.parametrize("on", [True, False])
def test_distinct_never_asks_a_theta_twice(source, hypers, on):
    """``distinct`` (the default): with a decoder that maps every code to one θ and the latent
    share at its maximum, no θ is asked twice, within a batch or across asks, and the asks that
    dropped candidates record how many. Off (runs stored before it), the same θ comes back."""
    assert TRANSFER_DEFAULTS["distinct"] is True and ADDED_OPTIONS["distinct"] is False
    X, y, f, _ = source
    cr = Transfer((X, y, f), _CollapsedLatent(), None, batch_size=4, seed=3,
                  latent_share_max=1.0, distinct=on)
    cr.load_state_dict({"source_hypers": hypers})
    _run_batches(cr, 5, 4)
    keys = {tuple(r) for r in np.round(cr.X, 9).tolist()}
    if on:
        assert len(keys) == len(cr.X) == 20
        assert sum(d.get("duplicates_dropped", 0) for d in cr.decisions) > 0
    else:
        assert len(keys) < len(cr.X)
        assert not any("duplicates_dropped" in d for d in cr.decisions)


def test_distinct_fills_a_batch_larger_than_the_elites_left(source, hypers):
    """A design ask with fewer elites left than the batch fills it with distinct perturbations
    of the centre (before: the best elite again)."""
    cr = _critic(source, hypers, n_design=3, n_elite=2)
    X = cr.ask(4)
    assert len({tuple(r) for r in np.round(X, 9).tolist()}) == 4
    off = _critic(source, hypers, n_design=3, n_elite=2, distinct=False)
    Xo = off.ask(4)
    assert len({tuple(r) for r in np.round(Xo, 9).tolist()}) < 4


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_distinct_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="distinct"):
        _critic(source, hypers, distinct=bad)


@pytest.mark.parametrize("floor", [0.0, 0.1])
def test_explore_fall_prob_screens_the_explore_asks_at_their_own_bound(source, hypers,
                                                                       monkeypatch, floor):
    """``explore_fall_prob`` = 0.05 with a fall screen that rates a θ by its first gain
    (``floor + 0.25 · θ_0``): with ``floor`` 0 the explore asks pick θ with ``θ_0 ≤ 0.2`` and
    record the bound 0.05, the other asks pick as before; with ``floor`` 0.1 no candidate passes
    0.05 and the explore asks fall back to ``max_fall_prob`` (0.3), as they record."""
    monkeypatch.setattr(Transfer, "_fall_prob",
                        lambda self, C, fall_m, bound=None: floor + 0.25 * np.asarray(C)[:, 0])
    out = [(5.0, False), (6.0, False), (4.0, False), (3.0, False), (2.9, False), (2.8, False),
           (2.7, False)]
    cr = _critic(source, hypers, n_design=0, explore_fall_prob=0.05)
    dec = _scripted(cr, out)
    ex = [i for i, d in enumerate(dec) if d["explore"]]
    assert ex == [1, 3, 5]
    for i in ex:
        assert dec[i]["explore_bound"] == (0.05 if floor == 0.0 else 0.3)
        assert cr.X[i, 0] <= (0.2 + 1e-12 if floor == 0.0 else 0.8 + 1e-12)
    assert not any("explore_bound" in dec[i] for i in range(len(dec)) if i not in ex)
    plain = _critic(source, hypers, n_design=0, explore_fall_prob=0.0)
    dec0 = _scripted(plain, out[:2])
    assert dec0[1]["explore"] and "explore_bound" not in dec0[1]
    if floor == 0.0:        # without the bound the first explore ask picks a θ it now refuses
        assert plain.X[1, 0] > 0.2


@pytest.mark.parametrize("max_fall_prob, resolved", [(None, 0.2), (0.1, 0.066666666667),
                                                     (0.6, 0.4), (1.0, 0.666666666667)])
def test_explore_fall_prob_defaults_to_two_thirds_of_max_fall_prob(source, hypers, max_fall_prob,
                                                                    resolved):
    """The default bound of the explore asks is ⅔ of ``max_fall_prob`` (so a smaller
    ``max_fall_prob`` is not refused), recorded as that number, and a stored run resumes with
    it; an explicit value, 0 included, stands."""
    kw = {} if max_fall_prob is None else {"max_fall_prob": max_fall_prob}
    cr = _critic(source, hypers, **kw)
    assert TRANSFER_DEFAULTS["explore_fall_prob"] is None
    assert cr.opts["explore_fall_prob"] == resolved
    assert cr.state_dict()["options"]["explore_fall_prob"] == resolved
    other = _critic(source, hypers, max_fall_prob=0.9)
    other.load_state_dict(cr.state_dict())
    assert other.opts["explore_fall_prob"] == resolved
    for q in (0.0, 0.05):
        assert _critic(source, hypers, explore_fall_prob=q, **kw).opts["explore_fall_prob"] == q


@pytest.mark.parametrize("bad", [-0.1, 0.5, "0.1", True])
def test_explore_fall_prob_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_fall_prob"):
        _critic(source, hypers, explore_fall_prob=bad)


@pytest.mark.parametrize("skip", [True, False])
def test_explore_skip_asks_the_region_when_the_screen_admits_no_explore_candidate(
        source, hypers, monkeypatch, skip):
    """``explore_skip``: with a fall screen that admits nothing (every θ 0.9), a due explore
    ask becomes a region ask in the full pool (``explore_skipped``; the told history replays it
    as one: a fresh critic told the trials asks the same next θ); without the option it takes
    the explore pool's least falling candidates. While every trial fell, the explore asks are
    made either way."""
    monkeypatch.setattr(Transfer, "_fall_prob",
                        lambda self, C, fall_m, bound=None: np.full(len(np.asarray(C)), 0.9))
    out = [(5.0, False), (6.0, False), (4.0, False), (3.9, False), (3.8, False)]
    cr = _critic(source, hypers, n_design=0, explore_skip=skip)
    dec = _scripted(cr, out)
    due = [1, 3]                                        # g % 2 == 1
    for g in due:
        assert dec[g]["explore"] is (not skip) and dec[g].get("explore_skipped", False) is skip
        assert cr.tags[g] % 4 in ((FULL,) if skip else (LATENT, GLOBAL))
    fresh = _critic(source, hypers, n_design=0, explore_skip=skip)
    fresh.tell(cr.X, cr.y, cr.tags, fell=cr.fell, z=cr._Z)
    assert fresh._replay_state() == cr._replay_state()
    assert np.allclose(fresh.ask(1), cr.ask(1))
    fell = _critic(source, hypers, n_design=0, explore_skip=True)
    dec = _scripted(fell, [(9.0, True)] * 4)
    assert dec[1]["explore"] and dec[3]["explore"] and "explore_skipped" not in dec[1]


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_explore_skip_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_skip"):
        _critic(source, hypers, explore_skip=bad)


def test_log_expected_improvement_is_the_log_of_ei_and_keeps_its_order_where_ei_underflows():
    from scipy.stats import norm

    from latentune.critic.transfer_model import log_expected_improvement

    mu = np.array([-3.0, -1.0, 0.0, 0.5, 2.0, 5.0, 10.0])
    var = np.array([1.0, 4.0, 0.25, 1.0, 1.0, 2.0, 1.0])
    sd = np.sqrt(var)
    u = (0.0 - mu) / sd
    ei = sd * (u * norm.cdf(u) + norm.pdf(u))
    assert np.allclose(log_expected_improvement(mu, var, 0.0), np.log(ei), rtol=1e-9)
    far = log_expected_improvement(np.array([30.0, 40.0, 60.0]), np.ones(3), 0.0)
    assert np.all(np.isfinite(far)) and far[0] > far[1] > far[2]     # EI itself is 0 there


def _spy_explore_gp(monkeypatch) -> list[tuple[np.ndarray, object]]:
    """The (candidates, target GP) of every ``explore_gp`` pool built from now on."""
    seen: list[tuple[np.ndarray, object]] = []
    orig = Transfer._pool_explore_gp

    def spy(self, XI, gp, rng):
        out = orig(self, XI, gp, rng)
        seen.append((out, gp))
        return out

    monkeypatch.setattr(Transfer, "_pool_explore_gp", spy)
    return seen


def test_explore_gp_asks_what_the_targets_own_gp_expects_most_improvement_from(source, hypers,
                                                                             monkeypatch):
    """``explore_gp``: a lines explore ask takes half the lines, Sobol points over the box and
    the local maxima of a target-only GP's log EI, and asks the candidate of highest log EI
    (with the screen admitting every candidate, the highest of them all); other asks and the
    tags are as without it; a resumed run asks the same."""
    from latentune.critic.transfer_model import log_expected_improvement

    assert TRANSFER_DEFAULTS["explore_gp"] is True and ADDED_OPTIONS["explore_gp"] is False
    seen = _spy_explore_gp(monkeypatch)
    cr = _critic(source, hypers, explore_pool="lines", explore_gp=True, max_fall_prob=1.0,
                 explore_fall_prob=0.0)
    _run(cr, 8)
    ex = [d for d in cr.decisions if d["explore"]]
    assert [d["generation"] for d in ex] == [3, 5, 7] and len(seen) == 3
    assert all(d.get("explore_gp") for d in ex)
    assert not any(d.get("explore_gp") for d in cr.decisions if not d["explore"])
    for d, (C, gp) in zip(ex, seen):
        g = d["generation"]
        assert cr.tags[g] % 4 == GLOBAL
        acq = log_expected_improvement(gp.mean_cov(C, False)[0], gp.variance(C),
                                       float(gp.v.min()))
        assert np.allclose(cr.X[g], C[int(np.argmax(acq))])
        assert len(C) > int(cr.opts["n_candidates"])        # the local maxima joined
    # the target GP, not the transfer model, chose: without it the lines ask elsewhere
    plain = _critic(source, hypers, explore_pool="lines", explore_gp=False, max_fall_prob=1.0,
                    explore_fall_prob=0.0)
    _run(plain, 8)
    assert not np.allclose(plain.X[3], cr.X[3])
    # resumed mid-run, it asks what the original would
    a = _critic(source, hypers, explore_pool="lines", explore_gp=True)
    _run(a, 4)
    b = _critic(source, hypers, explore_gp=False)
    b.tell(a.X, a.y, a.tags, fell=a.fell, z=a._Z)
    b.load_state_dict(a.state_dict())
    assert b.opts["explore_gp"] is True         # the stored run's options stand
    _asks_alike(a, b, 2)                    # generations 4 and 5 (explore)
    assert a.decisions[-1].get("explore_gp")


def test_explore_gp_with_latent_lines_weighs_the_decoded_codes_with_the_rest(source, hypers,
                                                                            monkeypatch):
    """``explore_gp`` with ``explore_pool="latent_lines"``: an explore ask once a trial stands
    offers the decoded codes of the whole latent box (half the pool) beside the lines' widened
    pool (lines, Sobol points, log-EI maxima), and asks the highest log EI of the target GP
    among them all, a code included (tag ``latent`` with its code)."""
    codes: list[np.ndarray] = []
    lat = Transfer._pool_latent

    def spy_lat(self, m, L, c, rng, whole=False):
        out = lat(self, m, L, c, rng, whole)
        if whole:
            codes.append(out[0])
        return out

    monkeypatch.setattr(Transfer, "_pool_latent", spy_lat)
    seen = _spy_explore_gp(monkeypatch)
    cr = _critic(source, hypers, explore_pool="latent_lines", explore_gp=True, max_fall_prob=1.0,
                 explore_fall_prob=0.0)
    _run(cr, 8)
    ex = [d for d in cr.decisions if d["explore"]]
    assert [d["generation"] for d in ex] == [3, 5, 7] and len(seen) == len(codes) == 3
    M = int(cr.opts["n_candidates"])
    for d, XL, (C, gp) in zip(ex, codes, seen):
        assert d.get("explore_gp") and d["explore_pool"] == "latent_lines"
        assert len(XL) == M // 2 and d["n_candidates"] == len(XL) + len(C)
        pool = np.vstack([XL, C])
        g = d["generation"]
        assert np.allclose(cr.X[g], pool[int(np.argmax(gp.log_ei(pool)))])
        if cr.tags[g] % 4 == LATENT:
            assert np.allclose(cr.X[g], cr.latent.decode(cr._Z[g][None, :])[0])
    # the codes are weighed, not dropped: where the GP's log EI peaks at the codes, a code is
    # asked (with the codes left out, a line or a Sobol point would be)

    def peaks_at_codes(self, X):
        K = np.vstack(codes)
        return -np.min(((X[:, None, :] - K[None, :, :]) ** 2).sum(-1), axis=1)

    monkeypatch.setattr(TargetGP, "log_ei", peaks_at_codes)
    codes.clear()
    cr2 = _critic(source, hypers, explore_pool="latent_lines", explore_gp=True, max_fall_prob=1.0,
                  explore_fall_prob=0.0)
    _run(cr2, 4)
    assert cr2.tags[3] % 4 == LATENT


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_explore_gp_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="explore_gp"):
        _critic(source, hypers, explore_gp=bad)


def test_explore_gp_with_fall_cost_asks_the_highest_constrained_ei(source, hypers, monkeypatch):
    """``explore_gp`` with ``fall_cost``: the candidate of highest ``log EI + log(1 − p)``, ``p``
    the target fall model's posterior mean (constrained EI), not the highest log EI."""
    seen = _spy_explore_gp(monkeypatch)
    cr = _critic(source, hypers, explore_pool="lines", explore_gp=True, fall_cost=True,
                 max_fall_prob=1.0)
    differs = 0
    for _ in range(8):
        x = cr.ask(1)
        d = cr.decisions[-1]
        if d.get("explore_gp"):
            C, gp = seen[-1]
            p = np.clip(cr.models()[1].mean_cov(C, False)[0], 0.0, 1.0)
            ei = gp.log_ei(C)
            assert np.allclose(x[0], C[int(np.argmax(ei + np.log(np.maximum(1 - p, 1e-300))))])
            differs += int(not np.allclose(x[0], C[int(np.argmax(ei))]))
        y, f = _bowl(x, np.full(D, 0.5), 0.6)
        cr.tell(x, y, cr.last_tags, fell=f, z=cr.last_z)
    assert len(seen) == 3
    assert differs >= 1             # the fall model moved the choice


def test_region_gp_lets_the_targets_own_gp_choose_the_region_asks_while_the_lines_lead(
        source, hypers, monkeypatch):
    """``region_gp``: while the next explore pool is the lines, a trust-region ask adds Sobol
    points and the target GP's log-EI maxima to its pool and asks the highest log EI (with the
    screen admitting all, at least every maximum's); it records ``region_gp``. With the latent
    box next, or without the option, the region asks are the transfer model's; a resumed run
    asks the same."""
    import latentune.critic.transfer as ct
    import latentune.critic.transfer_model as tm

    assert ct.TRANSFER_DEFAULTS["region_gp"] is False and ct.ADDED_OPTIONS["region_gp"] is False
    maxima: list[tuple] = []
    orig = tm._local_max

    def spy(f, X0, maxiter=40):
        out = orig(f, X0, maxiter)
        maxima.append((f, out))
        return out

    monkeypatch.setattr(tm, "_local_max", spy)
    kw = dict(explore_gp=False, explore_fall_prob=0.0, max_fall_prob=1.0)
    cr = _critic(source, hypers, explore_pool="lines", region_gp=True, **kw)
    _run(cr, 8)
    region = [d for d in cr.decisions if not d["explore"] and not d["design"]]
    assert region and all(d.get("region_gp") for d in region) and len(maxima) == len(region)
    assert not any(d.get("region_gp") for d in cr.decisions if d["explore"] or d["design"])
    for d, (f, XM) in zip(region, maxima):
        x = cr.X[d["generation"]][None, :]
        assert f(x)[0] >= f(XM).max() - 1e-12      # the ask is the highest log EI
    for opts in ({"explore_pool": "latent", "region_gp": True}, {"explore_pool": "lines"}):
        maxima.clear()
        other = _critic(source, hypers, **opts, **kw)
        _run(other, 8)
        assert not maxima and not any(d.get("region_gp") for d in other.decisions)
    a = _critic(source, hypers, explore_pool="lines", region_gp=True, **kw)
    _run(a, 4)
    b = _critic(source, hypers, region_gp=False)
    b.tell(a.X, a.y, a.tags, fell=a.fell, z=a._Z)
    b.load_state_dict(a.state_dict())
    assert b.opts["region_gp"] is True
    _asks_alike(a, b, 2)


@pytest.mark.parametrize("floor", [0.0, 0.1])
def test_screened_region_gp_asks_take_the_explore_bound(source, hypers, monkeypatch, floor):
    """``region_gp="screened"`` with a fall screen that rates a θ by its first gain
    (``floor + 0.25 · θ_0``), ``explore_fall_prob`` 0.05 and ``max_fall_prob`` 0.3: with
    ``floor`` 0 every ``region_gp`` ask picks θ with ``θ_0 ≤ 0.2`` and records the bound 0.05;
    with ``floor`` 0.1 none passes 0.05 and they fall back to 0.3, as recorded. With
    ``region_gp=True`` the same asks record no bound and at least one picks ``θ_0 > 0.2``."""
    monkeypatch.setattr(Transfer, "_fall_prob",
                        lambda self, C, fall_m, bound=None: floor + 0.25 * np.asarray(C)[:, 0])
    kw = dict(n_design=0, explore_pool="lines", explore_gp=False, explore_fall_prob=0.05)
    cr = _critic(source, hypers, region_gp="screened", **kw)
    _run(cr, 10)
    region = [d for d in cr.decisions if d.get("region_gp")]
    assert region
    for d in region:
        assert d["explore_bound"] == (0.05 if floor == 0.0 else 0.3)
        assert cr.X[d["generation"], 0] <= (0.2 + 1e-12 if floor == 0.0 else 0.8 + 1e-12)
    plain = _critic(source, hypers, region_gp=True, **kw)
    _run(plain, 10)
    region = [d for d in plain.decisions if d.get("region_gp")]
    assert region and not any("explore_bound" in d for d in region)
    if floor == 0.0:
        assert max(plain.X[d["generation"], 0] for d in region) > 0.2


@pytest.mark.parametrize("bad", [1, "yes", None, "screen"])
def test_region_gp_is_checked(source, hypers, bad):
    with pytest.raises(ValueError, match="region_gp"):
        _critic(source, hypers, region_gp=bad)


def test_explore_pool_cma_asks_a_cma_es_told_every_target_trial(source, hypers):
    """``explore_pool="cma"``: an explore ask runs the first draw of a CMA-ES (started from the
    source's promising distribution, told every target trial a population at a time) that the
    fall screen admits, or the least likely to fall of its draws; a fresh critic told the same
    history asks the same (the CMA-ES is a function of it)."""
    cr = _critic(source, hypers, explore_pool="cma")
    _run(cr, 12)
    ex = [d for d in cr.decisions if d["explore"]]
    assert [d["generation"] for d in ex] == [3, 5, 7, 9, 11]
    assert all(d["explore_pool"] == "cma" and d["pools"] == ["global"] for d in ex)
    lam = 4 + int(np.floor(3 * np.log(D)))
    assert cr.n_told >= lam, "the history holds a whole population: CMA-ES has moved"
    draws = cr._pool_cma(cr.opts["n_candidates"])
    b = _critic(source, hypers, explore_pool="cma")
    b.tell(cr.X, cr.y, cr.tags, fell=cr.fell, z=cr._Z)
    assert np.array_equal(draws, b._pool_cma(cr.opts["n_candidates"]))
    start = _critic(source, hypers, explore_pool="cma")._pool_cma(cr.opts["n_candidates"])
    assert not np.allclose(draws, start), "the told trials must move the CMA-ES"
    # the explore ask of generation 11 ran the first draw its screen admits
    a = _critic(source, hypers, explore_pool="cma")
    a.tell(cr.X[:11], cr.y[:11], cr.tags[:11], fell=cr.fell[:11], z=cr._Z[:11])
    P = a._pool_cma(a.opts["n_candidates"])
    pf = a._fall_prob(P, a.models()[1])
    ok = [pf <= a.opts["explore_fall_prob"], pf <= a.opts["max_fall_prob"]]
    first = next((int(np.flatnonzero(o)[0]) for o in ok if o.any()), int(np.argmin(pf)))
    assert np.allclose(cr.X[11], P[first])
