"""The transfer phase 3 after its trust region converged (``stop_converged``), and the long-budget
synthetic benchmark's cliff problem (benchmarks/transfer_long.py)."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.critic.transfer import ADDED_OPTIONS, Transfer

D = 6
# a target that no trial improves on: the trust region halves 0.5 → 0.25 → 0.125 (one failed
# batch each) and converges at the third failed batch
FAST = {"length_init": 0.5, "length_min": 0.125, "fail_tol": 1, "n_design": 0,
        "n_candidates": 200, "explore_every": 0}


def _cost(X: np.ndarray, best: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance to ``best`` (the zero-shot θ, which nothing beats); nothing falls."""
    return np.sqrt(((np.atleast_2d(X) - best) ** 2).sum(1)), np.zeros(len(np.atleast_2d(X)), bool)


@pytest.fixture(scope="module")
def source() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    best = np.full(D, 0.45)
    X = rng.uniform(0, 1, (60, D))
    y, f = _cost(X, best)
    return X, y, f, best


def _asks(source, n_batches: int, **opts) -> tuple[Transfer, list[np.ndarray]]:
    X, y, f, best = source
    cr = Transfer((X, y, f), None, None, batch_size=4, seed=0, **{**FAST, **opts})
    cr.tell(best[None], *_cost(best, best)[:1], fell=np.zeros(1, bool))
    asked = []
    for _ in range(n_batches):
        A = cr.ask(4)
        yy, ff = _cost(A, best)
        cr.tell(A, yy, cr.last_tags, fell=ff)
        asked.append(A)
    return cr, asked


def test_stop_converged_asks_the_centre_once_the_region_converged(source):
    best = source[3]
    cr, asked = _asks(source, 6, stop_converged=True)
    assert [d["length"] for d in cr.decisions[:3]] == [0.5, 0.25, 0.125]
    assert all(not np.allclose(A, best) for A in asked[:3])       # it searched
    for A in asked[3:]:                                           # then it held the centre
        assert np.allclose(A, best[None, :])
    assert cr.decisions[-1]["rule"].startswith("the trust region converged")
    assert cr.state_dict()["options"]["stop_converged"] is True
    # the default keeps perturbing the centre at the smallest side
    cd, asked_d = _asks(source, 6)
    assert all(not np.allclose(A, best) for A in asked_d[3:])
    assert cd.decisions[-1]["length"] == 0.125


def test_stop_converged_is_resumed_from_the_told_rows(source):
    X, y, f, best = source
    cr, _ = _asks(source, 4, stop_converged=True)
    fresh = Transfer((X, y, f), None, None, batch_size=4, seed=0, **FAST)
    fresh.load_state_dict(cr.state_dict())
    fresh.tell(cr.X, cr.y, cr.tags, fell=np.zeros(cr.n_told, bool))
    assert np.allclose(fresh.ask(4), cr.ask(4))
    assert ADDED_OPTIONS["stop_converged"] is False          # stored runs resume without it


def test_cliff_optimum_sits_at_the_fall_boundary():
    from benchmarks.transfer_long import problem

    src, tgt = problem("cliff", 0.0, 0)
    x0 = np.full((1, 20), 0.5)
    assert not src(x0)[1][0]                                 # the box's centre stands
    rng = np.random.default_rng(0)
    P = np.clip(0.5 + 0.3 * rng.standard_normal((4000, 20)), 0, 1)
    y, fell = src(P)
    assert 0 < fell.mean() < 1
    assert np.array_equal(tgt(P)[1], fell)                   # gap 0: the target is the source
    # the best standing trial of the sample lies next to a point that falls
    b = P[np.argmin(np.where(fell, np.inf, y))]
    steps = b + 0.01 * rng.standard_normal((200, 20))
    assert src(steps)[1].any()


def test_success_scale_spread_counts_gains_small_against_a_cost_offset(source):
    X, y, f, best = source
    goal = np.full(D, 0.7)

    def offset_cost(A: np.ndarray) -> np.ndarray:
        # a constant no θ changes: every gain is below 1e-3·|best|
        return 1000.0 + np.sqrt(((np.atleast_2d(A) - goal) ** 2).sum(1))

    lengths = {}
    for scale in ("best", "spread"):
        cr = Transfer((X, y, f), None, None, batch_size=4, seed=0, success_scale=scale,
                      **{**FAST, "length_min": 1 / 64, "fail_tol": 3})
        cr.tell(best[None], offset_cost(best), fell=np.zeros(1, bool))
        for _ in range(10):
            A = cr.ask(4)
            cr.tell(A, offset_cost(A), cr.last_tags, fell=np.zeros(4, bool))
        lengths[scale] = [d["length"] for d in cr.decisions]
        assert cr.state_dict()["options"]["success_scale"] == scale
    assert lengths["best"] == sorted(lengths["best"], reverse=True)       # it only shrinks
    assert max(lengths["spread"]) > FAST["length_init"]                   # gains counted
    with pytest.raises(ValueError, match="success_scale"):
        Transfer((X, y, f), None, None, success_scale="relative")
