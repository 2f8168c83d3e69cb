"""Convex-MPC actor, world, path cost and the rollout CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest

import latentune as lt
from latentune.actor.base import ActorFailure
from latentune.constants import C1, G, STABLE_CAP
from latentune.space import ParamsError
from latentune.task import path_cost


@pytest.mark.parametrize("robot,gait", [("a1", "trot"), ("a1", "jump"), ("b1", "trot"),
                                        ("b1", "jump"), ("solo12", "trot")])
def test_manual_theta_walks(robot, gait):
    """Manual θ, 5 s at 1 kHz on flat ground: no fall, tracks 0.5 m/s, stands at its height."""
    task = lt.Task(robot=robot, gait=gait, steps=5000)
    res = task.rollout(task.space.manual)
    assert not res.fell, res.reason
    assert res.steps == 5000
    assert 0.4 <= res.mean_vx <= 0.6, res.mean_vx
    # not crawling: the base stays within 20 % of its nominal height
    assert res.mean_height > 0.8 * task.spec.nominal_height
    assert res.cost < C1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a1_trot_hills(seed):
    task = lt.Task(robot="a1", gait="trot", terrain="hills", seed=seed, steps=5000)
    res = task.rollout(task.space.manual)
    assert not res.fell, res.reason
    assert 0.4 <= res.mean_vx <= 0.6


def test_a_hills_rollout_does_not_depend_on_the_rollouts_before_it():
    """PyBullet's restoreState kept the heightfield's broadphase pairs in the order the last
    rollout left them: a θ's cost followed the θ run before it in the world (workers 1 and 2
    stored other costs for the same θ)."""
    th = np.random.default_rng(0).random((3, 25))
    task = lt.Task(terrain="hills", steps=200)
    after_others = [task(x) for x in th]
    alone = [lt.Task(terrain="hills", steps=200)(x) for x in th]
    assert after_others == alone


def test_random_theta_properties():
    """Random θ: never an exception, finite costs, fell ⇔ cost ≥ C1, a share falls, a share stands."""
    steps = 600
    task = lt.Task(robot="a1", gait="trot", steps=steps)
    rng = np.random.default_rng(0)
    results = [task.rollout(rng.random(task.space.dim)) for _ in range(20)]
    costs = np.array([r.cost for r in results])
    fell = np.array([r.fell for r in results])
    assert np.all(np.isfinite(costs))
    assert np.array_equal(fell, costs >= C1)
    assert 0.1 <= fell.mean() <= 0.9, fell.mean()
    for r in results:
        if r.fell:
            assert 1 <= r.fall_step <= steps
            assert r.cost == pytest.approx(C1 * (2 - r.fall_step / steps))


def test_weak_forces_fall():
    """Force weights at their upper bound starve the legs: the robot must fall (cost ≥ C1)."""
    task = lt.Task(robot="a1", gait="trot", steps=2000)
    theta = task.space.manual.copy()
    theta[13:] = 1.0
    theta[:13] = 0.0
    res = task.rollout(theta)
    assert res.fell and res.cost >= C1


def test_path_cost_definition():
    v = np.tile([0.5, 0.0, 0.0], (100, 1))
    assert path_cost(v, np.array([0.5, 0, 0]), None, 100) == 0.0
    v2 = v + np.array([0.1, 0.0, 0.0])
    assert path_cost(v2, np.array([0.5, 0, 0]), None, 100) == pytest.approx(np.sqrt(100 * 0.01))
    assert path_cost(v, np.array([0.5, 0, 0]), 25, 100) == pytest.approx(1.75 * C1)
    assert path_cost(v, np.array([0.5, 0, 0]), 100, 100) == pytest.approx(C1)
    # never fell but 2 m/s off for 5000 steps: sqrt(5000·4) ≈ 1.4·C1 -> capped below C1
    far = np.tile([-1.5, 0.0, 0.0], (5000, 1))
    assert path_cost(far, np.array([0.5, 0, 0]), None, 5000) == STABLE_CAP < C1


def test_actor_failure_is_a_fall(monkeypatch):
    """An infeasible QP (ActorFailure) ends the rollout as a fall at that step, not an exception."""
    task = lt.Task(robot="a1", gait="trot", steps=500)
    cls = task.actor_cls
    orig = cls.control

    def failing(self, step, state):
        if step == 100:
            raise ActorFailure("QP infeasible (test)")
        return orig(self, step, state)

    monkeypatch.setattr(cls, "control", failing)
    res = task.rollout(task.space.manual, record=True)
    assert res.fell and res.fall_step == 101
    assert res.cost == pytest.approx(C1 * (2 - 101 / 500))
    # the step that never ran is not a sample at height 0 (the plot's CoM dropped to the ground)
    assert res.steps == 100 and len(res.trace["height"]) == 100
    assert res.trace["height"].min() > 0.8 * task.spec.nominal_height
    assert res.mean_height > 0.8 * task.spec.nominal_height


def test_a_gif_is_written_when_the_actor_fails_before_a_step(monkeypatch, tmp_path):
    """rollout --gif of an actor failing at its first command wrote no file (no frame yet)
    and exited 0."""
    task = lt.Task(robot="a1", gait="trot", steps=50)

    def failing(self, step, state):
        raise ActorFailure("QP infeasible (test)")

    monkeypatch.setattr(task.actor_cls, "control", failing)
    gif = tmp_path / "x.gif"
    res = task.rollout(task.space.manual, gif=str(gif))
    assert res.fell and res.steps == 0 and gif.stat().st_size > 0


def test_a_non_finite_state_is_a_fall_with_finite_means(monkeypatch):
    """A blow-up to NaN is a fall at its step; its NaN sample made mean_vx and mean_height NaN,
    which rollout --json printed as NaN (no JSON number) and the trial's info stored."""
    from latentune.sim.world import World

    task = lt.Task(robot="a1", gait="trot", steps=100)
    task.world                                     # built and settled before the blow-up
    orig, calls = World.true_state, []

    def blows_up(self):
        s = orig(self)
        calls.append(1)
        if len(calls) > 30:
            s.vel[:] = np.nan
            s.pos[2] = np.nan
            s.finite = False
        return s

    monkeypatch.setattr(World, "true_state", blows_up)
    res = task.rollout(task.space.manual)
    assert res.fell and res.reason == "simulator blow-up (non-finite state)" and res.fall_step == 30
    json.dumps(res.info(100), allow_nan=False)
    assert 0.8 * task.spec.nominal_height < res.mean_height < 1.2 * task.spec.nominal_height


def test_parameter_space_roundtrip():
    space = lt.Task(robot="a1", gait="trot").space
    assert space.dim == 25 and len(space.names) == 25
    u = np.random.default_rng(1).random(25)
    assert np.allclose(space.to_unit(space.to_physical(u)), u)
    assert np.all((space.manual >= 0) & (space.manual <= 1))
    with pytest.raises(ParamsError):
        space.validate_unit(np.full(24, 0.5))
    with pytest.raises(ParamsError):
        space.validate_unit(np.full(25, np.nan))
    with pytest.raises(ParamsError):
        space.validate_unit(np.full(25, 1.5))
    assert np.allclose(space.parse(space.as_dict(u)), u)


def test_normalized_forces_carry_each_robots_weight():
    """A normalized θ means the same on A1 and B1 (transfer needs it): the MPC's forces are
    u = f / (m·g), so with the same θ each robot's stance forces carry its own weight m·g
    (B1 is ~4.5 times heavier than A1)."""
    from latentune.actor.convex_mpc import ConvexMPC

    for robot in ("a1", "b1"):
        task = lt.Task(robot=robot, gait="trot", steps=1000)
        world = task.world
        world.reset()
        actor = ConvexMPC(world, "trot", task.v_des, task.space.to_physical(task.space.manual))
        s, fz = world.state(), []
        for n in range(1000):
            world.apply(actor.control(n, s))
            world.step()
            s = world.state()
            if n % actor.SOLVE_EVERY == 0:
                fz.append(actor.forces[:, 2].sum())
        weight = world.model.mass * G
        assert np.mean(fz) == pytest.approx(weight, rel=0.1), (robot, np.mean(fz) / weight)


def test_cli_rollout_json(tmp_path, run_cli):
    plot = tmp_path / "v.png"
    code, out, err = run_cli("rollout", "--robot", "a1", "--task", "trot", "--steps", "600",
                             "--json", "--plot", plot)
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1              # the JSON is the only stdout line
    obj = json.loads(out)
    for key in ("cost", "fell", "fall_step", "steps", "mean_vx", "wall_s"):
        assert key in obj
    assert obj["steps"] == 600 and not obj["fell"]
    assert plot.stat().st_size > 1000


def test_cli_rollout_json_of_a_fall_gives_the_executed_steps(tmp_path, run_cli):
    """``steps`` is the steps executed (the task's horizon used to overwrite it) and
    ``horizon`` the planned ones; the JSON holds every field of the stored trial's info."""
    params = tmp_path / "p.json"
    params.write_text(json.dumps([0.0] * 13 + [1.0] * 12))    # no state weight: it sags and falls
    code, out, err = run_cli("rollout", "--steps", "400", "--json", "--params", params)
    assert code == 0, err
    obj = json.loads(out)
    assert obj["fell"] and obj["steps"] == obj["fall_step"] < 400 and obj["horizon"] == 400
    assert obj["cost"] == pytest.approx(100.0 * (2 - obj["fall_step"] / 400))
    assert {"rms_vel_error", "mean_height", "reason", "robot", "seed", "dim"} <= obj.keys()


@pytest.mark.parametrize("args,content,expect", [
    (["--robot", "nosuchbot"], None, "unknown robot 'nosuchbot'"),
    (["--task", "moonwalk"], None, "unknown task 'moonwalk'"),
    (["--terrain", "lava"], None, "unknown terrain 'lava'"),
    (["--params", "PARAMS"], "[0.5, 0.5]", "expected 25 normalized parameters, got shape (2,)"),
    (["--params", "PARAMS"], json.dumps([float("nan")] * 25), "contain NaN or inf"),
    (["--params", "PARAMS"], json.dumps([1.5] * 25), "Q_roll = 1.5 is outside [0, 1]"),
    (["--params", "PARAMS"], "{not json", "is not valid JSON"),
    (["--params", "PARAMS"], json.dumps({"Q_roll": 1e9}), "Q_roll = 1e+09 is outside"),
    (["--params", "/nonexistent/params.json"], None, "params file not found"),
    (["--robot", "SPEC"], "name: x\nurdf: nowhere.urdf\n", "missing field(s)"),
    (["--robot", "SPEC"], "name: [unclosed\n", "malformed YAML"),
    (["--steps", "-5"], None, "--steps must be >= 1, got -5"),
])
def test_cli_bad_input(tmp_path, run_cli, error_line, args, content, expect):
    args = list(args)
    if "PARAMS" in args:
        f = tmp_path / "p.json"
        f.write_text(content)
        args[args.index("PARAMS")] = str(f)
    if "SPEC" in args:
        f = tmp_path / "robot.yaml"
        f.write_text(content)
        args[args.index("SPEC")] = str(f)
    code, _, err = (run_cli("rollout", "--steps", "50", *args) if "--steps" not in args
                    else run_cli("rollout", *args))
    assert expect in error_line(code, err)


def test_custom_robot_spec(tmp_path):
    """A YAML spec based on A1 with an overridden gait loads and walks a little."""
    spec = tmp_path / "my_a1.yaml"
    spec.write_text("base: a1\nname: my_a1\ngaits:\n  trot: {period: 0.4, duty: 0.6, step_height: 0.07}\n")
    task = lt.Task(robot=str(spec), gait="trot", steps=800)
    assert task.robot_name == "my_a1"
    assert task.spec.gait("trot").period == 0.4
    res = task.rollout(task.space.manual)
    assert not res.fell


def test_osqp_and_daqp_agree_on_mpc_qp():
    """The MPC's QP solved by DAQP (default) and by OSQP gives the same forces."""
    from latentune.actor.convex_mpc import ConvexMPC

    task = lt.Task(robot="a1", gait="trot", steps=200)
    world = task.world
    world.reset()
    actor = ConvexMPC(world, "trot", task.v_des, task.space.manual_physical)
    captured = []
    orig = actor._qp

    def spy(*args):
        captured.append(args)
        return orig(*args)

    actor._qp = spy
    s = world.state()
    for n in range(60):
        world.apply(actor.control(n, s))
        world.step()
        s = world.state()
    assert len(captured) >= 5
    osqp_actor = ConvexMPC(world, "trot", task.v_des, task.space.manual_physical, solver="osqp")
    for args in captured:
        x_daqp = actor.__class__._qp(actor, *args)
        x_osqp = osqp_actor._qp(*args)
        # forces are in units of m·g: agree within 1 % of the weight
        assert np.allclose(x_daqp, x_osqp, atol=1e-2), np.abs(x_daqp - x_osqp).max()


def test_a_rollout_gif_plays_at_its_frame_rate(tmp_path):
    """rollout --gif passed imageio a frame duration in seconds (0.1), which its GIF writer
    reads as milliseconds: the file held no frame delay at all, played as fast as a viewer
    can (browsers happen to slow such a GIF to 10 fps). Each frame now lasts 1/gif_fps s."""
    from PIL import Image

    task = lt.Task(robot="a1", gait="trot", steps=250)
    gif = tmp_path / "x.gif"
    task.rollout(task.space.manual, gif=str(gif), gif_fps=20)
    with Image.open(gif) as im:
        delays = []
        for i in range(im.n_frames):
            im.seek(i)
            delays.append(im.info.get("duration"))
    assert len(delays) == 5 and delays == [50] * 5, delays
