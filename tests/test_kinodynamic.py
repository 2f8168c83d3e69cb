"""Kino-dynamic MPC actor (issue 5): centroidal planner, whole-body DDP, rollouts, θ space."""
from __future__ import annotations

import numpy as np
import pytest

# before any import of the actor: latentune.actor.kinodynamic raises ImportError without crocoddyl
pytest.importorskip("crocoddyl")

import latentune as lt  # noqa: E402
from latentune.actor import kinodynamic as kd  # noqa: E402
from latentune.actor.centroidal import CentroidalPlanner  # noqa: E402
from latentune.constants import C1  # noqa: E402
from latentune.space import ParamsError  # noqa: E402


# ----------------------------------------------------------------------------- θ space
def test_space_layout_and_roundtrip():
    from latentune.robots import get_robot

    space = kd.KinodynamicMPC.space(get_robot("solo12"), "trot")
    assert space.dim == 77 and len(set(space.names)) == 77
    assert space.names[0] == "WX_cx" and space.names[9] == "WXter_cx" and space.names[18] == "WF_FR_fx"
    assert space.names[30] == "sw_base_x" and space.names[66] == "cw_com_x"
    assert space.names[-2:] == ("kp", "kd")
    man = space.manual_physical
    # BiConMP's published Solo12 trot values
    np.testing.assert_allclose(man[0:9], [1e-5, 1e-5, 1e5, 10, 10, 200, 1e4, 1e4, 1e4])
    np.testing.assert_allclose(man[18:30], 10.0)
    assert man[75] == pytest.approx(3.0) and man[76] == pytest.approx(0.05)
    assert np.all(space.lower < man) and np.all(man < space.upper)
    assert np.all(space.log)
    u = np.random.default_rng(0).random((5, 77))
    np.testing.assert_allclose(space.to_unit(space.to_physical(u)), u, atol=1e-9)
    np.testing.assert_allclose(space.to_physical(space.manual), man, rtol=1e-9)


def test_normalized_theta_means_the_same_on_a1_and_solo12():
    """One normalized θ on both robots; the physical gains scale with the robot's joint gains."""
    from latentune.robots import get_robot

    solo, a1 = get_robot("solo12"), get_robot("a1")
    s_solo = kd.KinodynamicMPC.space(solo, "trot")
    s_a1 = kd.KinodynamicMPC.space(a1, "trot")
    np.testing.assert_allclose(s_solo.manual, s_a1.manual, atol=1e-12)
    u = np.random.default_rng(0).random(77)
    p_solo, p_a1 = s_solo.to_physical(u), s_a1.to_physical(u)
    np.testing.assert_allclose(p_a1[:75], p_solo[:75], rtol=1e-12)      # weights: no robot unit
    assert p_a1[75] / p_solo[75] == pytest.approx(np.mean(a1.kp) / np.mean(solo.kp))
    assert p_a1[76] / p_solo[76] == pytest.approx(np.mean(a1.kd) / np.mean(solo.kd))


def test_bad_theta_length_raises():
    task = lt.Task(robot="solo12", gait="trot", actor="kinodynamic", steps=10)
    with pytest.raises(ValueError):
        kd.KinodynamicMPC(task.world, "trot", task.v_des, np.ones(76))
    with pytest.raises(ValueError):
        kd.KinodynamicMPC(task.world, "trot", task.v_des, np.ones(78))
    with pytest.raises(ParamsError):
        task.rollout(np.full(25, 0.5))


def test_task_reports_missing_crocoddyl_clearly():
    """Without crocoddyl the actor module does not import and Task says so in one line."""
    import subprocess
    import sys

    code = ("import sys; sys.modules['crocoddyl'] = None\n"
            "import latentune as lt\n"
            "try:\n    lt.Task(robot='solo12', gait='trot', actor='kinodynamic')\n"
            "except ValueError as e:\n    print('ERR', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "ERR" in out.stdout and "crocoddyl" in out.stdout


# ----------------------------------------------------------------------------- planner
def test_centroidal_planner_standing_and_cones():
    """All feet down, stand still: forces carry the weight, respect the cones, momentum stays ~0."""
    H = 10
    P = CentroidalPlanner(0.05, H, mu=0.6, u_max=2.5)
    feet = np.tile(np.array([[0.2, -0.15, 0.0], [0.2, 0.15, 0.0], [-0.2, -0.15, 0.0],
                             [-0.2, 0.15, 0.0]]), (H, 1, 1))
    x0 = np.array([0.01, 0.0, 0.22, 0, 0, 0, 0, 0, 0])
    x_ref = np.zeros((H, 9))
    x_ref[:, 0:2] = x0[0:2]
    x_ref[:, 2] = 0.22
    X, U = P.plan(x0, np.ones((H, 4), bool), feet, x_ref, kd.W_X_MANUAL, kd.W_X_TER_MANUAL,
                  kd.W_F_MANUAL)
    u = U.reshape(H, 4, 3)
    np.testing.assert_allclose(u[..., 2].sum(axis=1), 1.0, atol=0.02)      # Σ f_z = m g
    assert np.all(u[..., 2] >= -1e-9)
    assert np.all(np.abs(u[..., :2]) <= 0.6 * u[..., 2:3] + 1e-7)
    assert np.max(np.abs(X[:, 2] - 0.22)) < 2e-3
    assert np.max(np.abs(X[:, 6:9])) < 1e-3
    # the returned trajectory is the exact (bilinear) rollout of the returned forces
    np.testing.assert_allclose(P.rollout(x0, U, feet), X, atol=1e-12)


def test_centroidal_planner_swing_legs_get_no_force():
    H = 10
    P = CentroidalPlanner(0.05, H, mu=0.6, u_max=2.5)
    contact = np.zeros((H, 4), bool)
    contact[:, [0, 3]] = True
    feet = np.tile(np.array([[0.2, -0.15, 0.0], [0.2, 0.15, 0.0], [-0.2, -0.15, 0.0],
                             [-0.2, 0.15, 0.0]]), (H, 1, 1))
    x0 = np.array([0.0, 0.0, 0.22, 0.3, 0, 0, 0, 0, 0])
    x_ref = np.zeros((H, 9))
    x_ref[:, 0] = 0.5 * 0.05 * np.arange(1, H + 1)
    x_ref[:, 2] = 0.22
    x_ref[:, 3] = 0.5
    _, U = P.plan(x0, contact, feet, x_ref, kd.W_X_MANUAL, kd.W_X_TER_MANUAL, kd.W_F_MANUAL)
    u = U.reshape(H, 4, 3)
    assert np.all(u[:, [1, 2]] == 0.0)
    assert np.all(u[:, [0, 3], 2] > 0.1)


# ----------------------------------------------------------------------------- rollouts
@pytest.mark.parametrize("robot,gait", [("solo12", "trot"), ("solo12", "jump"), ("a1", "trot")])
def test_manual_theta_walks(robot, gait):
    """Manual θ, 5 s at 1 kHz on flat ground: no fall, tracks 0.5 m/s, stands at its height."""
    task = lt.Task(robot=robot, gait=gait, actor="kinodynamic", steps=5000)
    res = task.rollout(task.space.manual, record=True)
    assert not res.fell, res.reason
    assert res.steps == 5000
    assert 0.4 <= res.mean_vx <= 0.6, res.mean_vx
    assert res.mean_height > 0.9 * task.spec.nominal_height    # not crawling on its belly
    assert res.cost < C1
    h = res.trace["height"][-3000:]
    tilt = np.abs(res.trace["rpy"][-3000:, :2])
    assert tilt.max() < 0.35
    if gait == "jump":   # a pronk: the body rises and falls by centimetres every cycle
        assert h.max() - h.min() > 0.03
    else:
        assert h.max() - h.min() < 0.03


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_solo12_trot_hills(seed):
    task = lt.Task(robot="solo12", gait="trot", terrain="hills", seed=seed, actor="kinodynamic",
                   steps=5000)
    res = task.rollout(task.space.manual)
    assert not res.fell, res.reason
    assert 0.4 <= res.mean_vx <= 0.6


def test_random_theta_properties():
    """20 random θ × 700 steps (long enough for these θ: the same ones fall as over 1000
    steps): no exception, finite costs, fell ⇔ cost ≥ C1, a share stable, a share falls (the stable set is
    a proper subset of the box)."""
    task = lt.Task(robot="solo12", gait="trot", actor="kinodynamic", steps=700)
    rng = np.random.default_rng(0)
    fells = []
    for _ in range(20):
        res = task.rollout(rng.random(task.space.dim))
        assert np.isfinite(res.cost)
        assert res.fell == (res.cost >= C1)
        if res.fell:
            assert 1 <= res.fall_step <= 700
        fells.append(res.fell)
    for corner in (np.zeros(task.space.dim), np.ones(task.space.dim)):   # box corners: no exception
        res = task.rollout(corner)
        assert np.isfinite(res.cost) and res.fell == (res.cost >= C1)
    stable = 1.0 - np.mean(fells)
    assert 0.25 <= stable < 1.0, stable
