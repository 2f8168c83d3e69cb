"""``examples/servo_cascade.py``: the servo drive written in session 50 as a system nobody had
tuned the default phase 3 for. Its docstring's claims: the manual θ tracks on the model and
limit-cycles at gap 1; the model's best θ go unstable as the gap grows; a failure is a fall with
its step, and the trace ends there."""
from __future__ import annotations

import numpy as np
import pytest

from examples.servo_cascade import ERR_LIMIT, NAMES, STEPS, ServoSystem, make_system, reference


def test_config_and_bad_input():
    assert make_system(gap=0.5).config() == {"kind": "servo_cascade", "gap": 0.5, "steps": STEPS}
    assert make_system().space.dim == len(NAMES) == 14
    assert make_system(gap=1.0).delay == 3 and make_system(gap=1.0).tau_max < make_system().tau_max
    for bad in ({"gap": -1.0}, {"gap": float("nan")}, {"steps": 0}):
        with pytest.raises(ValueError):
            ServoSystem(**bad)


def test_reference_is_smooth_and_holds_at_the_targets():
    r, v, a = reference()
    assert r[0] == 0.0 and r[-1] == pytest.approx(0.3)
    assert np.abs(np.diff(r)).max() < 0.01                # 1 ms steps of a ≤ 6 rad/s move
    assert np.allclose(np.cumsum(v) * 1e-3, r, atol=0.02)  # the rate integrates to the angle
    assert np.abs(a).max() == pytest.approx(10 / 3 ** 0.5 * 0.8 / 0.25 ** 2, rel=1e-3)  # move 3


def test_manual_tracks_the_model_and_limit_cycles_at_gap_one():
    model = make_system(0.0)
    out, tr = model.simulate(model.space.manual)
    assert not out.failed and 10 < out.cost < 40
    assert len(tr["time_s"]) == STEPS and np.abs(tr["load"] - tr["ref"]).max() < ERR_LIMIT
    assert out.cost == model.evaluate(model.space.manual).cost
    far = make_system(1.0).evaluate(make_system(1.0).space.manual)
    assert far.failed and far.info["reason"] == "limit cycle in the last hold"


def test_the_gap_makes_the_models_stable_theta_fail():
    model, far = make_system(0.0), make_system(1.0)
    U = np.random.default_rng(1).uniform(size=(300, 14))
    kept = [u for u in U if not model.evaluate(u).failed]
    assert len(kept) >= 10
    assert np.mean([far.evaluate(u).failed for u in kept]) > 0.6
    out, tr = far.simulate(np.ones(14))                   # the highest gains: a fall, not a crash
    assert out.failed and len(tr["time_s"]) == out.info["fall_step"] + 1
    assert out.cost == pytest.approx(100 * (2 - out.info["fall_step"] / STEPS))
