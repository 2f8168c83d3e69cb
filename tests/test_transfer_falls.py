"""The transfer phase 3's ``fall_cost`` option: the acquisition counts the fall among a
candidate's outcomes, so where the target falls the critic asks θ less likely to fall."""
from __future__ import annotations

import numpy as np
import pytest

from latentune.critic.transfer import Transfer
from latentune.critic.transfer_model import SourceModel

D = 6


def _cost(X: np.ndarray) -> np.ndarray:
    """10·distance to the point ``t`` (0.7, 0.5, …, 0.5), the best θ of source and target."""
    t = np.full(D, 0.5)
    t[0] = 0.7
    return 10.0 * np.sqrt(((np.atleast_2d(X) - t) ** 2).sum(1))


@pytest.fixture(scope="module")
def setting() -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict, tuple]:
    """A source that never fell and a target that falls wherever ``x0 > 0.5``: the source's
    cost model points the target's search into the fall region; 40 target trials told."""
    rng = np.random.default_rng(0)
    Xs = np.clip(0.5 + 0.2 * rng.standard_normal((120, D)), 0, 1)
    ys, fs = _cost(Xs), np.zeros(len(Xs), dtype=bool)
    hypers = SourceModel(Xs, ys, fs, seed=0).hypers
    Xt = np.clip(0.5 + 0.1 * rng.standard_normal((40, D)), 0, 1)
    ft = Xt[:, 0] > 0.5
    return (Xs, ys, fs), hypers, (Xt, np.where(ft, 100.0 + _cost(Xt), _cost(Xt)), ft)


def _critic(setting, **kw) -> Transfer:
    src, hypers, (Xt, yt, ft) = setting
    cr = Transfer(src, None, None, batch_size=16, seed=1, max_fall_prob=1.0, n_design=0, **kw)
    cr.load_state_dict({"source_hypers": hypers})
    cr.tell(Xt, yt, fell=ft)
    return cr


@pytest.mark.parametrize("acquisition", ["thompson", "ei"])
def test_fall_cost_asks_theta_less_likely_to_fall(setting, acquisition):
    """With the screen admitting everything, the acquisition alone chooses: with ``fall_cost``
    the asked θ have a lower predicted fall probability and fewer lie in the fall region."""
    off = _critic(setting, acquisition=acquisition)
    on = _critic(setting, acquisition=acquisition, fall_cost=True)
    X_off, X_on = off.ask(16), on.ask(16)
    fall_m = off.models()[1]
    p_off, p_on = (float(np.clip(fall_m.mean_cov(X, False)[0], 0, 1).mean())
                   for X in (X_off, X_on))
    assert p_on < 0.7 * p_off
    assert (X_on[:, 0] > 0.5).sum() < (X_off[:, 0] > 0.5).sum()


def test_fall_cost_is_recorded_and_resumed(setting):
    cr = _critic(setting, fall_cost=True)
    assert cr.state_dict()["options"]["fall_cost"] is True
    fresh = Transfer(setting[0], None, None, batch_size=16, seed=1)
    fresh.load_state_dict(cr.state_dict())
    assert fresh.opts["fall_cost"] is True


@pytest.fixture(scope="module")
def bowl_source(tmp_path_factory):
    """A source run of ``benchmarks.transfer_escape``'s 2-weight bowl: phase 1 (40) and its
    latent space."""
    import latentune as lt
    from benchmarks.transfer_escape import Bowl

    d = tmp_path_factory.mktemp("bowl") / "src"
    with lt.Study(d, seed=0, batch_size=4) as st:
        st.phase1(Bowl(2), 40)
        st.train_latent(epochs=30)
    return d


@pytest.mark.parametrize("k", [0, 6])
def test_escape_falls_leaves_the_source_region_once_k_trials_all_fell(tmp_path, bowl_source, k):
    """A target that falls wherever the source stood (``anti``): the default phase 3 asks the
    source's region and falls every trial; with ``escape_falls`` = k, once k trials all fell
    an explore ask is the θ farthest from them (recorded as ``escape``), which stands, and the
    rule ends there."""
    import latentune as lt
    from benchmarks.transfer_escape import Bowl
    from latentune.pipeline.phases import state_key

    with lt.Study(tmp_path / "t", seed=0, batch_size=1) as st:
        st.phase3(Bowl(2, "anti"), 16, latent=bowl_source,
                  transfer_options={"escape_falls": k} if k else None)
        fell = st.store.fell(3)
        ds = st.store.get_meta(state_key(3))["decisions"]
    escapes = [i for i, d in enumerate(ds) if d.get("escape")]
    if k == 0:
        assert fell.all() and not escapes
    else:
        assert escapes and all(fell[:escapes[0]]) and escapes[0] + 1 >= k   # + the zero-shot
        assert not fell[escapes[0]] and len(escapes) == 1


def test_escape_falls_is_an_integer_option():
    src = (np.random.default_rng(0).random((10, 3)), np.arange(10.0), np.zeros(10, bool))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="escape_falls"):
            Transfer(src, None, None, escape_falls=bad)
