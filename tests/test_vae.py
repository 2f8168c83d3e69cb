"""The latent space (latentune.latent.vae): shapes, training, determinism for a seed, save/load,
and the caller's torch random state left untouched."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from latentune.latent import LatentSpace


def manifold_points(n: int = 150, seed: int = 0) -> np.ndarray:
    """Points near a 3-dim manifold in [0, 1]^25 (n, 25)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 25))
    return 1 / (1 + np.exp(-(rng.normal(size=(n, 3)) @ A) * 0.5))


@pytest.mark.parametrize("kind", ["det", "vae"])
def test_vae_shapes_determinism_training(tmp_path, kind):
    X = manifold_points()
    rng = np.random.default_rng(1)
    a = LatentSpace.train(X, kind=kind, seed=1, epochs=60)
    b = LatentSpace.train(X, kind=kind, seed=1, epochs=60)
    assert a.d == 25 and a.d_low == 10 and a.kind == kind
    assert a.net.encoder[0].out_features == 12 and a.net.encoder[2].out_features == 6
    u = rng.random((7, 10))
    th = a.decode(u)
    assert th.shape == (7, 25) and th.min() >= 0 and th.max() <= 1
    assert a.decode(u[0]).shape == (25,)
    assert np.array_equal(th, b.decode(u))                  # deterministic for a seed
    assert a.log.rec[-1] < 0.95 * a.log.rec[0]               # training reduces the loss
    assert a.log.loss[-1] < a.log.loss[0]
    assert a.box.shape == (10, 2) and np.all(a.box[:, 0] < a.box[:, 1])
    uz = a.to_unit(a.encode(X))
    assert uz.shape == (150, 10) and uz.min() >= 0 and uz.max() <= 1
    a.meta["robot"] = "a1"
    a.save(tmp_path / "vae")
    c = LatentSpace.load(tmp_path / "vae")
    assert np.allclose(c.decode(u), th) and c.meta["robot"] == "a1" and c.meta["n_train"] == 150
    assert np.allclose(c.box, a.box)


def test_vae_77_dim_default_latent():
    X = np.random.default_rng(0).random((40, 77))
    ls = LatentSpace.train(X, seed=0, epochs=5)
    assert ls.d_low == 5 and ls.decode(np.full(5, 0.5)).shape == (77,)


@pytest.mark.parametrize("d, d_low", [(2, 1), (3, 2), (8, 2), (12, 3), (60, 10)])
def test_default_latent_dim_is_below_d(d: int, d_low: int):
    """A small θ gets a latent space it can train: d_low < d (1 for a 2-dim θ)."""
    X = np.random.default_rng(0).random((20, d))
    ls = LatentSpace.train(X, seed=0, epochs=2)
    assert ls.d_low == d_low and ls.decode(np.full(d_low, 0.5)).shape == (d,)


def _weights(ls: LatentSpace) -> list[np.ndarray]:
    return [p.detach().numpy().copy() for p in ls.net.parameters()]


def test_vae_seed_fixes_the_weights_and_leaves_the_global_generator_alone(monkeypatch):
    """The initial weights are a function of the seed only, whatever the caller did to torch's
    global generator, and training neither reseeds nor advances that generator."""
    X = manifold_points(60)
    init: list[list[np.ndarray]] = []
    build = __import__("latentune.latent.vae", fromlist=["_build"])._build

    def spy(*args, **kwargs):
        net = build(*args, **kwargs)
        init.append([p.detach().numpy().copy() for p in net.parameters()])
        return net

    monkeypatch.setattr("latentune.latent.vae._build", spy)
    torch.manual_seed(11)
    state = torch.get_rng_state()
    a = LatentSpace.train(X, d_low=3, seed=5, epochs=3)
    assert torch.equal(torch.get_rng_state(), state)        # the caller's generator untouched
    torch.rand(17)                                          # the caller draws in between
    b = LatentSpace.train(X, d_low=3, seed=5, epochs=3)
    LatentSpace.train(X, d_low=3, seed=6, epochs=3)                          # init[2]
    assert len(init) == 3
    assert all(np.array_equal(p, q) for p, q in zip(init[0], init[1]))       # same seed
    assert not all(np.array_equal(p, q) for p, q in zip(init[0], init[2]))   # another seed
    assert all(np.array_equal(p, q) for p, q in zip(_weights(a), _weights(b)))


def test_save_on_a_full_disk_keeps_the_earlier_files(tmp_path, monkeypatch, full_disk):
    """A write that fails (ENOSPC) raises an OSError with its errno and leaves the latent space
    saved before readable and unchanged, with no temporary file behind."""
    import errno

    X = manifold_points(60)
    ls = LatentSpace.train(X, d_low=2, seed=0, epochs=3)
    ls.save(tmp_path / "vae")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    other = LatentSpace.train(X, d_low=2, seed=1, epochs=3)
    full_disk()
    with pytest.raises(OSError) as e:
        other.save(tmp_path / "vae")
    assert e.value.errno == errno.ENOSPC
    monkeypatch.undo()
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    np.testing.assert_allclose(LatentSpace.load(tmp_path / "vae").decode(np.full((1, 2), 0.5)),
                               ls.decode(np.full((1, 2), 0.5)))


@pytest.mark.parametrize("d", [2, 5])
def test_a_small_theta_gets_a_decoder_that_reaches_its_training_set(d: int):
    """Below d = 20 both hidden layers have 16 units: on a 2-dim stable set each seed's decoder
    spreads over more than SPREAD_WARN of the set's variance. With Table I's widths (1 unit in
    the second layer for d < 8) the decoder is constant, which ``require_spread`` refuses."""
    from latentune.errors import LatentError
    from latentune.latent.vae import SPREAD_WARN, hidden_widths

    assert hidden_widths(d) == (16, 16) and hidden_widths(20) == (10, 5)
    assert hidden_widths(25) == (12, 6) and hidden_widths(77) == (38, 19)     # Table I
    rng = np.random.default_rng(d)
    A = np.linalg.qr(rng.standard_normal((d, 2)))[0] if d > 2 else np.eye(2)
    X = np.clip(0.5 + 0.25 * rng.uniform(-1, 1, (60, 2)) @ A.T, 0, 1)
    collapsed = 0
    for seed in range(2):
        ls = LatentSpace.train(X, seed=seed, epochs=400)
        assert ls.meta["hidden"] == [16, 16]
        assert ls.meta["decoded_variance_ratio"] > SPREAD_WARN, (seed, ls.meta)
        ls.require_spread()
        calls = []
        ls.spread = lambda: calls.append(1)          # type: ignore  # checked once: not again
        ls.require_spread()
        assert calls == []
        old = LatentSpace.train(X, seed=seed, epochs=300, hidden=(max(d // 2, 1), 1))
        try:
            old.require_spread()
        except LatentError as e:
            assert "decodes every code to one θ" in str(e) and "\n" not in str(e)
            assert old.meta["decoded_variance_ratio"] < 1e-9
            with pytest.raises(LatentError):                # a refusal is not remembered
                old.require_spread()
            collapsed += 1
    assert collapsed >= 1                           # the defect the widths remove


def test_a_latent_space_saved_before_the_widths_were_recorded_loads(tmp_path):
    """A file without ``hidden`` was built with max(⌊d/2⌋, 1), max(⌊d/4⌋, 1): it loads with
    those widths and decodes as before."""
    import json

    X = np.random.default_rng(0).random((30, 6))
    ls = LatentSpace.train(X, seed=0, epochs=3, hidden=(3, 1))
    ls.save(tmp_path / "vae")
    meta = json.loads((tmp_path / "vae.json").read_text())
    del meta["hidden"]
    (tmp_path / "vae.json").write_text(json.dumps(meta))
    back = LatentSpace.load(tmp_path / "vae")
    u = np.random.default_rng(1).random((5, ls.d_low))
    assert back.net.decoder[0].out_features == 1 and np.array_equal(back.decode(u), ls.decode(u))
    with pytest.raises(Exception, match="hidden widths must be >= 1"):
        LatentSpace.train(X, seed=0, epochs=1, hidden=(0, 4))


def test_vae_widths_benchmark_reports_what_it_trained(tmp_path, capsys):
    """``benchmarks.vae_widths`` at a tiny size: one row per (set, d, rule), the collapsed count
    agrees with ``require_spread`` on the run's own record; bad sizes are refused."""
    import json

    from benchmarks.vae_widths import main

    out = tmp_path / "w.json"
    assert main(["--dims", "2", "--seeds", "1", "--n", "30", "--sets", "manifold",
                 "--epochs", "60", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert [(r["d"], r["rule"], r["hidden"]) for r in res["rows"]] == \
        [(2, "table1", "(1, 1)"), (2, "current", "(16, 16)")]
    for row, run in zip(res["rows"], res["runs"]):
        assert row["collapsed"] == f"{int(run['collapsed'])}/1"
        assert run["collapsed"] == (run["spread"] < 1e-9)
    assert main(["--dims", "1"]) == 2 and "--dims must be >= 2" in capsys.readouterr().err


def test_maps_check_shapes_and_values_and_train_checks_its_integers():
    """``to_unit([0.5])`` / ``from_unit([0.5])`` on a 2-d latent box broadcast to two values
    silently, ``to_unit`` of 3 values raised numpy's broadcast error, ``decode([nan, 0.5])`` and
    ``encode`` of NaN returned NaN, ``decode(["a", "b"])`` raised float()'s ValueError, and
    ``train(d_low=2.5)`` / ``epochs=0`` trained a 2-d / untrained space, ``beta=nan`` a NaN
    network. Each is a LatentError
    now; the maps keep the input's shape."""
    from latentune.errors import LatentError

    X = np.random.default_rng(0).random((20, 4))
    ls = LatentSpace.train(X, 2, epochs=2, seed=0)
    assert ls.to_unit(ls.encode(X[0])).shape == (2,) and ls.to_unit(ls.encode(X)).shape == (20, 2)
    assert ls.from_unit([0.5, 0.5]).shape == (2,) and ls.from_unit(np.zeros((3, 2))).shape == (3, 2)
    assert np.allclose(ls.to_unit(ls.from_unit([0.25, 0.75])), [0.25, 0.75])
    for f in (ls.to_unit, ls.from_unit, ls.decode):
        for bad, expect in (([0.5], r"shape \(2,\) or \(n, 2\)"), ([0.5] * 3, "shape"),
                            ([np.nan, 0.5], "NaN or inf"), (["a", "b"], "must be numbers")):
            with pytest.raises(LatentError, match=expect):
                f(bad)
    with pytest.raises(LatentError, match="NaN or inf"):
        ls.encode([np.nan] * 4)
    for kw in (dict(d_low=2.5), dict(d_low=2, epochs=0), dict(d_low=2, batch_size=0)):
        with pytest.raises(LatentError, match="whole number"):
            LatentSpace.train(X, **kw)
    for kw in (dict(hidden=(0, "a")), dict(hidden=(2.5, 3)), dict(beta=float("nan")),
               dict(lr=-1.0)):           # int()'s ValueError, a 2-unit layer, a NaN network,
        with pytest.raises(LatentError, match="hidden widths must be|must be a finite"):
            LatentSpace.train(X, 2, epochs=1, **kw)     # torch's "Invalid learning rate"
    with pytest.raises(LatentError, match="a latent space's path is a str or Path"):
        LatentSpace.load(5)
