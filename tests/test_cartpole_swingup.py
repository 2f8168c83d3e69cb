"""``examples/cartpole_swingup.py``: the swing-up and balance system of the transfer ladder's
fifth held-out family. Its gap must do what its docstring says: the manual θ swings the model's
pole up and balances it, and at gap 2 most θ that balance the model fail."""
from __future__ import annotations

import math

import numpy as np
import pytest

from examples.cartpole_swingup import MODEL, STEPS, CartPoleSystem, make_system, wrap


def test_config_gap_and_bad_input():
    for g in (0.0, 1.0):
        assert make_system(gap=g).config() == {"kind": "cartpole_swingup", "gap": g,
                                               "steps": STEPS}
    assert make_system(gap=1.0).delay == 2 and make_system(gap=2.0).motor < 1.0
    assert make_system(gap=2.0).plant.mp > MODEL.mp
    for bad in ({"gap": -1.0}, {"gap": float("inf")}, {"steps": 0}):
        with pytest.raises(ValueError):
            CartPoleSystem(**bad)
    assert make_system().space.dim == 20
    assert wrap(3 * math.pi) == pytest.approx(-math.pi) and wrap(-0.5) == -0.5


def test_upright_is_unstable_and_the_force_pushes_the_cart():
    A, B = MODEL.linearized()
    assert A[3, 2] > 0 and B[1, 0] > 0 and B[3, 0] < 0   # φ̈ grows with φ; F moves the cart
    assert np.linalg.eigvals(A).real.max() > 1.0


def test_manual_theta_swings_up_and_the_gap_makes_most_theta_fail():
    model, far = make_system(0.0), make_system(2.0)
    out, trace = model.simulate(model.space.manual)
    assert not out.failed and 0.0 < out.cost < 1.0
    assert trace["mode"][-100:].all() and np.abs(trace["phi"][-100:]).max() < 0.25
    assert np.abs(trace["x"]).max() < 1.2 and abs(trace["phi"][0]) > 3.0     # starts hanging
    U = np.random.default_rng(1).uniform(size=(200, 20))
    kept = [u for u in U if not model.evaluate(u).failed]
    assert len(kept) >= 20
    assert np.mean([far.evaluate(u).failed for u in kept]) > 0.5
    bad = model.evaluate(np.zeros(20))              # the weakest swing: never up, a fall
    assert bad.failed and 100.0 <= bad.cost <= 200.0
