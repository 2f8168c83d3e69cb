"""``examples/vehicle_lateral.py``: the lane-keeping system of the transfer ladder's fourth
held-out family. Its gap must do what its docstring says: the manual θ keeps the model car in
lane, and at gap 2 most θ that keep the model in lane leave it."""
from __future__ import annotations

import numpy as np
import pytest

from examples.vehicle_lateral import STEPS, VehicleSystem, curvature, make_system


def test_config_gap_and_bad_input():
    for g in (0.0, 1.0):
        assert make_system(gap=g).config() == {"kind": "vehicle_lateral", "gap": g,
                                               "steps": STEPS}
    assert make_system(gap=1.0).delay == 1 and make_system(gap=2.0).mu < make_system().mu
    for bad in ({"gap": -1.0}, {"gap": float("nan")}, {"steps": 0}):
        with pytest.raises(ValueError):
            VehicleSystem(**bad)
    assert make_system().space.dim == 20


def test_road_is_continuous():
    s = np.linspace(0.0, 700.0, 7001)
    k = np.array([curvature(x) for x in s])
    assert np.abs(np.diff(k)).max() < 1e-3 and k[0] == 0.0 and k[-1] == 0.0
    assert np.abs(k).max() == pytest.approx(1 / 160)


def test_manual_theta_drives_the_model_and_the_gap_makes_most_theta_leave_the_lane():
    model, far = make_system(0.0), make_system(2.0)
    out, trace = model.simulate(model.space.manual)
    assert not out.failed and 0.0 < out.cost < 1.0
    assert np.abs(trace["e_y"]).max() < 1.5 and trace["speed"][-1] == pytest.approx(28.0, abs=0.05)
    U = np.random.default_rng(1).uniform(size=(120, 20))
    kept = [u for u in U if not model.evaluate(u).failed]
    assert len(kept) >= 20
    left = np.mean([far.evaluate(u).failed for u in kept])
    assert left > 0.6
    bad = far.evaluate(np.ones(20))                 # the highest gains: a fall, not a crash
    assert bad.failed and 100.0 <= bad.cost <= 200.0
