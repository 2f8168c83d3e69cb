"""examples/shifted_bowl.py: the probe's bowl moves with the gap, is smooth and never fails."""
from __future__ import annotations

import numpy as np
import pytest

from examples.shifted_bowl import C0, CURVATURE, DIM, make_system, optimum


def test_the_gap_moves_the_optimum_and_the_model_optimum_costs_more_on_the_target():
    m, t = make_system(0.0), make_system(0.2)
    assert m.evaluate(C0) == 0.0 and t.evaluate(optimum(0.2)) == 0.0
    c = optimum(0.2)
    inside = (c > 0.02) & (c < 0.98)                   # not clipped: moved by the gap exactly
    assert inside.sum() >= DIM - 2 and np.allclose(np.abs(c - C0)[inside], 0.2)
    assert t.evaluate(C0) == pytest.approx(100 * np.sum(CURVATURE * (C0 - optimum(0.2)) ** 2))
    assert t.evaluate(C0) > 50 and make_system(0.3).evaluate(C0) > t.evaluate(C0)


def test_no_trial_fails_and_bad_input_is_refused():
    s = make_system(0.1)
    rng = np.random.default_rng(0)
    assert all(np.isfinite(s.evaluate(u)) for u in rng.random((20, DIM)))
    with pytest.raises(ValueError):
        make_system(-1.0)
    with pytest.raises(Exception):
        s.evaluate(np.full(DIM, np.nan))
