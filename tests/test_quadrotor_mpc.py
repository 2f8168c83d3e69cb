"""``examples/quadrotor_mpc.py``: the planar quadrotor MPC of the transfer ladder's third
held-out family: the QP is the condensed form of the horizon's cost, the manual weights fly the
model and every gap, the gap ladder makes θ that fly the model fall more often as the gap grows,
falls follow the C1 convention and say why, bad input is refused."""
from __future__ import annotations

import numpy as np
import pytest

from examples.quadrotor_mpc import (HORIZON, NU, NX, STEPS, QuadrotorMPC, make_system,
                                    model_matrices)


def test_the_qp_is_the_horizon_cost_written_out():
    """Twice DAQP's objective ½ Uᵀ H U + fᵀ U is the MPC's cost of the predicted trajectory
    less its cost at U = 0, for any inputs U: H and f are the condensed form of the stage, rate
    and terminal terms; the first input solved for lies within the model's bounds."""
    rng = np.random.default_rng(0)
    w = np.exp(rng.normal(size=20))
    mpc = QuadrotorMPC(w)
    A, B = model_matrices()
    q, qf, r, rd = w[:NX], w[NX:2 * NX] * w[:NX], w[16:18], w[18:20]
    e0, u_prev = rng.normal(size=NX), rng.normal(size=NU)

    def cost(U: np.ndarray) -> float:
        e, up, c = e0, u_prev, 0.0
        for k in range(HORIZON):
            u = U[k * NU:(k + 1) * NU]
            e = A @ e + B @ u
            c += (e @ ((qf if k == HORIZON - 1 else q) * e) + u @ (r * u)
                  + (u - up) @ (rd * (u - up)))
            up = u
        return c

    f = mpc.F @ e0 - mpc.Fu @ u_prev
    U0 = np.zeros(HORIZON * NU)
    for _ in range(3):
        U = rng.normal(size=HORIZON * NU)
        quad = U @ mpc.H @ U + 2 * f @ U
        assert quad == pytest.approx(cost(U) - cost(U0), rel=1e-9, abs=1e-9)
    u = mpc.solve(e0, u_prev)
    assert u.shape == (NU,) and np.all(u >= mpc.lo[:NU] - 1e-9) and np.all(u <= mpc.hi[:NU] + 1e-9)


def test_manual_weights_fly_the_model_and_the_small_gap_and_rock_over_on_the_delayed_ones():
    for g in (0.0, 0.5, 1.0, 2.5):
        s = make_system(g)
        out = s.evaluate(s.space.manual)
        if g < 1:
            assert not out.failed and 0.3 < out.cost < 2.0, (g, out)
        else:                                        # a step of actuation delay and more
            assert out.failed and out.info["fall"] == "pitch", (g, out)
        assert s.config() == {"kind": "quadrotor_mpc", "gap": g, "steps": STEPS}


def test_the_gap_ladder_fails_more_of_the_weights_that_fly_the_model():
    X = np.random.default_rng(3).random((40, 20))
    model = make_system(0.0)
    ok = [x for x in X if not model.evaluate(x).failed]
    assert 10 <= len(ok) < len(X)                     # the model itself fails some weights
    share = [np.mean([make_system(g).evaluate(x).failed for x in ok]) for g in (0.5, 1.0, 2.5)]
    assert share[0] < share[1] < share[2] and share[2] > 0.5, share


def test_a_fall_says_why_and_when_and_costs_by_the_c1_convention():
    s = make_system(2.5)
    theta = s.space.manual
    out, trace = s.simulate(theta)
    k = out.info["fall_step"]
    assert out.failed and out.info["fall"] in ("pitch", "ground", "far")
    assert out.cost == pytest.approx(100 * (2 - k / STEPS))
    assert len(trace["time_s"]) == k + 1 and trace["position"].shape == (k + 1, 2)
    assert make_system(2.5).evaluate(theta) == out   # deterministic


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_bad_gap_is_refused(bad):
    with pytest.raises(ValueError, match="gap must be a finite number"):
        make_system(bad)


def test_a_theta_outside_the_unit_box_is_refused():
    with pytest.raises(ValueError):
        make_system(0.0).evaluate(np.full(20, 1.5))


def test_quadrotor_traces_re_runs_the_stored_best_and_draws_it(tmp_path):
    """``benchmarks.quadrotor_traces`` on the committed ladder traces: each method's best θ
    re-runs to its stored cost, the seed drawn is the default's median one, the figure is
    written; a method with no stored run is one line and exit 2."""
    import json
    from pathlib import Path

    from benchmarks.quadrotor_traces import DEFAULT, main

    root = Path(__file__).resolve().parents[1] / "results" / "transfer" / "rebuilt" / "runs"
    best = {s: min(json.loads((root / "quadrotor" / "gap2.5" / f"seed{s}" / f"{DEFAULT}.json")
                              .read_text())["costs"]) for s in range(10)}
    png, out = tmp_path / "q.png", tmp_path / "q.json"
    assert main(["--root", str(root), "--methods", DEFAULT, "zero_shot",
                 "--png", str(png), "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["method"] for r in rows] == [DEFAULT, "zero_shot"] and png.stat().st_size > 10000
    assert best[rows[0]["seed"]] == sorted(best.values())[4]          # the lower median
    assert rows[0]["cost"] == best[rows[0]["seed"]] and not rows[0]["failed"]
    assert rows[1]["trial"] == 0 and rows[1]["failed"] == (rows[1]["cost"] >= 100)
    assert main(["--root", str(tmp_path), "--seed", "0", "--png", str(png)]) == 2
