"""The hand-over critic (phase 3 without the latent space's floor): rule, tags, z, resume."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from latentune.critic import make_critic
from latentune.critic.handover import FULL, LATENT, Handover, decode_tag, encode_tag
from latentune.critic.turbo import TurboM
from latentune.pipeline.phases import handover_options

torch.set_num_threads(1)

D, K = 6, 2
OPT = np.full(D, 0.3)


def decode(U: np.ndarray) -> np.ndarray:
    """A decoder whose image misses the optimum: θ_0, θ_1 in [0.35, 0.65], the rest at 0.7."""
    U = np.atleast_2d(U)
    th = np.full((U.shape[0], D), 0.7)
    th[:, :K] = 0.5 + 0.3 * (U - 0.5)
    return th


def cost(th: np.ndarray) -> np.ndarray:
    return np.sum((np.atleast_2d(th) - OPT) ** 2, axis=1)


FLOOR = 2 * 0.05 ** 2 + (D - K) * 0.4 ** 2        # the best cost on the decoder's image


def handover(latent="random", full=None, **kw) -> Handover:
    lat = make_critic(latent, K, batch_size=4, seed=1)
    if full is None:
        def full(length):
            return TurboM(D, batch_size=4, seed=1, n_regions=1, n_candidates=300,
                          length_init=length)
    return Handover(lat, decode, D, full, **kw)


def drive(h: Handover, n_batches: int) -> None:
    for _ in range(n_batches):
        X = h.ask()
        h.tell(X, cost(X), h.last_tags, z=h.last_z)


def test_tags_round_trip():
    for inner in (-2, -1, 0, 5, (3 << 20) + 7):
        for stage in (LATENT, FULL):
            t = encode_tag(inner, stage)
            assert t >= 0 and decode_tag(t) == (inner, stage)


def test_hands_over_on_a_stall_and_gets_below_the_latent_floor():
    h = handover(patience=8)
    drive(h, 1)
    assert h.stage == LATENT and not h.stalled()       # 4 < patience evaluations
    drive(h, 19)
    assert h.stage == FULL and h.handover_at is not None and h.handover_at >= 8
    # latent-stage points lie on the decoder's image and carry their codes
    tags = np.array([decode_tag(t)[1] for t in h.tags])
    lat = tags == LATENT
    assert lat.sum() == h.handover_at
    assert np.all(h.y[lat] >= FLOOR - 1e-12)
    # after the hand-over: full-space points, no codes, below the floor
    assert np.all(np.isnan(h.last_z))
    assert h.best_y < 0.5 * FLOOR
    assert h.rule()["handover_at"] == h.handover_at
    st = h.stats()                    # both stages' counters, the full TuRBO-m's GP fits
    assert st["stage"] == FULL and st["latent_stats"]["method"] == "random"
    assert st["full_stats"]["n_fits"] >= 1 and st["full_stats"]["n_fit_failed"] == 0


def test_no_hand_over_while_the_latent_search_improves():
    h = handover(patience=8, tol=0.01)
    for g in range(6):                  # each batch beats the last by 10 %
        X = h.ask()
        h.tell(X, np.full(4, 10.0 * 0.9 ** g) + np.arange(4) * 1e-3, h.last_tags, z=h.last_z)
    assert not h.stalled() and h.stage == LATENT
    X = h.ask()
    h.tell(X, np.full(4, 50.0), h.last_tags, z=h.last_z)
    X = h.ask()
    h.tell(X, np.full(4, 50.0), h.last_tags, z=h.last_z)   # 8 evaluations without a gain
    assert h.stalled()
    h.ask()
    assert h.stage == FULL


@pytest.mark.parametrize("n_batches", [3, 9])      # before and after the hand-over
def test_a_fresh_critic_told_the_history_asks_the_same_batch(n_batches):
    def sobol(length):
        return make_critic("sobol", D, batch_size=4, seed=2)

    h = handover(full=sobol, patience=8)
    drive(h, n_batches)
    assert (h.handover_at is None) == (n_batches == 3)
    nxt = h.ask()
    r = handover(full=sobol, patience=8)
    order = np.random.default_rng(0).permutation(h.n_told)       # any order within the store
    z = np.full((h.n_told, K), np.nan)
    stage = np.array([decode_tag(t)[1] for t in h.tags])
    z[stage == LATENT] = h.latent.X
    r.tell(h.X[order], h.y[order], h.tags[order], z=z[order])
    assert r.handover_at == h.handover_at
    np.testing.assert_array_equal(r.ask(), nxt)
    np.testing.assert_array_equal(r.last_tags, h.last_tags)


def test_latent_points_need_their_codes_and_options_are_checked():
    h = handover()
    X = h.ask()
    with pytest.raises(ValueError, match="latent codes"):
        h.tell(X, cost(X), h.last_tags)
    with pytest.raises(ValueError, match="patience"):
        handover(patience=0)
    with pytest.raises(ValueError, match="handover_length"):
        handover(handover_length=2.0)
    assert handover_options(True) == {"patience": 20, "tol": 0.01, "length": 0.2}
    assert handover_options({"length": 0.4})["length"] == 0.4
    assert handover_options(None) is None
    for bad in ({"size": 1}, {"tol": 1.5}, {"patience": 2.5}, "yes"):
        with pytest.raises(ValueError):
            handover_options(bad)
