"""``examples/buck_converter.py``: the buck converter written in session 51 as a system nobody had
tuned the default phase 3 for. Its docstring's claims: the manual θ regulates the model (and gap
0.5) and falls at gap 1; the model's good θ fall as the gap grows; a violent θ falls (a trip or
over-voltage, never a crash); a non-finite θ or state is a fall with its step."""
from __future__ import annotations

import time

import numpy as np
import pytest

from examples.buck_converter import (NAMES, OVP_GAIN, OVP_OFFSET, STEPS, BuckSystem,
                                     make_system, schedule)


def test_config_bounds_and_bad_input():
    sys0 = make_system()
    assert make_system(gap=0.5).config() == {"kind": "buck_converter", "gap": 0.5,
                                             "steps": STEPS}
    sp = sys0.space
    assert sp.dim == len(NAMES) == 15
    assert np.all(sp.lower < sp.upper) and np.all(sp.lower[sp.log] > 0)
    phys = sp.to_physical(sp.manual)
    assert np.all(phys >= sp.lower) and np.all(phys <= sp.upper)
    assert np.allclose(sp.to_physical(np.zeros(15)), sp.lower)
    assert np.allclose(sp.to_physical(np.ones(15)), sp.upper)
    for bad in ({"gap": -1.0}, {"gap": float("nan")}, {"steps": 0}):
        with pytest.raises(ValueError):
            BuckSystem(**bad)
    with pytest.raises(ValueError):
        sys0.evaluate(np.full(15, 0.5)[:14])


def test_the_gap_changes_the_plant():
    m, far = make_system(0.0), make_system(1.0)
    assert (m.delay, far.delay, make_system(0.5).delay) == (1, 3, 2)
    assert far.L < m.L and far.C < m.C and far.esr < m.esr and far.vin < m.vin
    assert m.bias == m.ripple == m.r_src == 0.0 and far.bias > 0 and far.ripple > 0
    assert far.load.max() == pytest.approx(1 + 3 * 1.5) and m.load.max() == pytest.approx(4.0)
    sp, spec, _ = schedule()
    assert sp[0] == 3.3 and sp[-1] == 5.0 and spec[0] == 0.0 and spec[-1] == pytest.approx(5.0)


def test_manual_regulates_the_model_and_falls_at_gap_one():
    model = make_system(0.0)
    out, tr = model.simulate(model.space.manual)
    assert not out.failed and 5 < out.cost < 50
    assert len(tr["time_s"]) == STEPS
    late = tr["time_s"] > 9e-3                      # settled at 5 V at the end
    assert np.abs(tr["vout"][late] - 5.0).max() < 0.05
    assert tr["vout"].max() < OVP_GAIN * 5.0 + OVP_OFFSET
    assert out.cost == model.evaluate(model.space.manual).cost
    assert not make_system(0.5).evaluate(model.space.manual).failed
    assert make_system(1.0).evaluate(model.space.manual).failed


def test_a_violent_theta_falls_not_crashes():
    for g in (0.0, 1.0):
        out, tr = make_system(g).simulate(np.ones(15))      # the highest gains and limits
        assert out.failed and len(tr["time_s"]) == out.info["fall_step"] + 1
        assert out.cost == pytest.approx(100 * (2 - out.info["fall_step"] / STEPS))
        assert out.info["reason"] in ("over-voltage", "over-current trip", "under-voltage",
                                      "non-finite state")


def test_a_nan_theta_is_refused():
    s = make_system(0.0)
    theta = s.space.manual.copy()
    theta[0] = np.nan
    with pytest.raises(ValueError):                  # the space's ParamsError: never a trial
        s.evaluate(theta)


def test_nonfinite_state_is_a_fall():
    for C in (1e-300, 0.0):                          # the state overflows / divides by zero
        s = make_system(0.0)
        s.C = C
        out, tr = s.simulate(s.space.manual)
        assert out.failed and out.info["reason"] == "non-finite state"
        assert out.cost == pytest.approx(100 * (2 - out.info["fall_step"] / STEPS))


def test_the_gap_makes_the_models_good_theta_fall_and_runs_fast():
    model, far = make_system(0.0), make_system(1.0)
    U = np.random.default_rng(1).uniform(size=(300, 15))
    t0 = time.perf_counter()
    outs = [model.evaluate(u) for u in U]
    assert (time.perf_counter() - t0) / len(U) < 0.05          # ~5 ms a trial
    kept = [u for u, o in zip(U, outs) if not o.failed]
    assert len(kept) >= 20
    assert all(o.cost < 100 for o in outs if not o.failed)
    assert np.mean([far.evaluate(u).failed for u in kept]) > 0.7
