"""Reality profiles and the MuJoCo engine: bad profiles are one line, presets and the YAML form
load, a Task records and rebuilds its reality and engine, every profile parameter moves the
simulated dynamics in its intended direction (in PyBullet and in MuJoCo), the random parts are
reproducible for a seed and differ across seeds, and the manual θ walks on A1 in MuJoCo."""
from __future__ import annotations

import ctypes.util
import importlib.util
import json
import math

import numpy as np
import pytest

from latentune.errors import LatentuneError, UsageError
from latentune.robots import get_robot
from latentune.sim import ENGINES, PRESETS, Reality, SimWorld, make_world
from latentune.sim.reality import RealityRuntime
from latentune.sim.world import p
from latentune.task import Task

A1 = get_robot("a1")
HAVE_MUJOCO = importlib.util.find_spec("mujoco") is not None
engines = pytest.mark.parametrize("engine", [
    "pybullet", pytest.param("mujoco", marks=pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco"))])
_WORLDS: dict = {}


def world(engine: str, **reality):
    """An A1 world on flat ground (cached per engine and reality), reset."""
    key = (engine, json.dumps(reality, sort_keys=True))
    if key not in _WORLDS:
        _WORLDS[key] = make_world(A1, "flat", 0, reality=reality or None, engine=engine)
    w = _WORLDS[key]
    w.reset()
    return w


def place(w, pos, quat=(0.0, 0.0, 0.0, 1.0)) -> None:
    """Teleport the base (position [m], quaternion x, y, z, w) and zero its velocity."""
    if w.engine == "pybullet":
        p.resetBasePositionAndOrientation(w.robot, list(pos), list(quat), physicsClientId=w.cid)
        p.resetBaseVelocity(w.robot, [0, 0, 0], [0, 0, 0], physicsClientId=w.cid)
    else:
        w._data.qpos[:7] = [*pos, quat[3], quat[0], quat[1], quat[2]]
        w._data.qvel[:6] = 0.0
        w.mj.mj_forward(w.mjmodel, w._data)


def hold(w, s) -> np.ndarray:
    """Joint PD torques [N·m] holding the nominal stance."""
    kp, kd = np.tile(w.spec.kp, 4), np.tile(w.spec.kd, 4)
    return kp * (np.array(w.spec.nominal_q) - s.q) - kd * s.dq


def knee_response(w, cmd: float, n: int = 30, k0: int = 5) -> np.ndarray:
    """FR knee velocity [rad/s] per step in free fall (1 m up): no torque for k0 steps, then
    ``cmd`` [N·m] on the FR knee; minus the same run without the command."""
    out = []
    for c in (cmd, 0.0):
        w.reset()
        place(w, [0.0, 0.0, 1.3])
        dq = []
        for k in range(n):
            tau = np.zeros(12)
            tau[2] = c if k >= k0 else 0.0
            w.apply(tau)
            w.step()
            dq.append(w.true_state().dq[2])
        out.append(np.array(dq))
    return out[0] - out[1]


# ----------------------------------------------------------------------------- profiles
@pytest.mark.parametrize("bad, words", [
    ({"mass_scal": 1.1}, "unknown key 'mass_scal'"),
    ({"latency_steps": -1}, "latency_steps must be finite and >= 0"),
    ({"latency_steps": 2.5}, "whole number"),
    ({"torque_scale": float("nan")}, "torque_scale must be finite"),
    ({"friction_scale": 0.0}, "friction_scale must be finite and > 0"),
    ({"payload_offset": [0.1, 0.0]}, "payload_offset must be 3 numbers"),
    ({"noise_vel": "high"}, "noise_vel must be a number"),
    ({"restitution": 1.5}, "restitution must be finite and in [0, 1]"),
    ({"latency_steps": True}, "latency_steps must be a number"),
    ("no-such-preset", "unknown reality 'no-such-preset': not a preset"),
    (["heavy"], "reality must be a preset name"),
])
def test_bad_profile_is_one_usage_error_line(bad, words):
    with pytest.raises(UsageError) as exc:
        Reality.load(bad)
    msg = str(exc.value)
    assert words in msg and "\n" not in msg
    assert isinstance(exc.value, LatentuneError)
    with pytest.raises(UsageError):  # the Task refuses it the same way
        Task("a1", reality=bad)


def test_bad_yaml_files(tmp_path):
    cases = {"broken.yaml": "mass_scale: [1.1\n", "list.yaml": "- 1\n- 2\n",
             "key.yaml": "torque_scal: 0.8\n", "nan.yaml": "torque_scale: .nan\n",
             "base.yaml": "base: [nope]\n", "cycle.yaml": "base: [cycle.yaml]\n"}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
    for name, words in [("broken.yaml", "malformed YAML"), ("list.yaml", "must be a mapping"),
                        ("key.yaml", "unknown key 'torque_scal'"), ("nan.yaml", "torque_scale"),
                        ("base.yaml", "base 'nope' is neither a preset"), ("cycle.yaml", "include itself")]:
        with pytest.raises(UsageError) as exc:
            Reality.load(str(tmp_path / name))
        assert words in str(exc.value) and "\n" not in str(exc.value), name


def test_an_unknown_key_of_a_file_lists_base_among_the_known_ones(tmp_path):
    """A profile file with a misspelled key listed the keys it may hold without ``base``, the key
    the presets use to build on each other (``bsae: heavy`` read 'unknown key 'bsae' (known:
    friction, …)'); a file's list names base too, a dict's (which takes no base) does not."""
    f = tmp_path / "mine.yaml"
    f.write_text("bsae: heavy\nmass_scale: 1.1\n")
    with pytest.raises(UsageError, match=r"unknown key 'bsae' \(known: base, friction, "):
        Reality.load(str(f))
    with pytest.raises(UsageError, match=r"unknown key 'bsae' \(known: friction, "):
        Reality.load({"bsae": "heavy"})


def test_presets_and_yaml_form(tmp_path):
    assert set(PRESETS) >= {"nominal", "heavy", "worn", "slippery", "laggy", "hard"}
    assert Reality.load("nominal").is_nominal and Reality().is_nominal and Reality.load(None).is_nominal
    heavy, worn, slip, lag = (Reality.load(n) for n in ("heavy", "worn", "slippery", "laggy"))
    assert heavy.mass_scale == 1.15 and heavy.payload_fraction > 0
    assert worn.torque_scale == 0.8 and worn.joint_friction_fraction > 0
    assert slip.foot_friction == 0.5 and lag.latency_steps > 0 and lag.has_noise
    hard = Reality.load("hard")
    assert hard.name == "hard" and hard.push_fraction > 0 and hard.relative
    for part in (heavy, worn, slip, lag):  # hard = heavy + worn + slippery + laggy + pushes
        for k, v in part.changes().items():
            assert hard.changes()[k] == v, k
    for name in PRESETS:
        r = Reality.load(name)
        assert Reality.from_dict(json.loads(json.dumps(r.to_dict()))) == r
    f = tmp_path / "mine.yaml"
    f.write_text("base: [heavy]\ntorque_scale: 0.9\nlatency_steps: 2\npayload_offset: [0, 0.02, 0]\n")
    mine = Reality.load(str(f))
    assert mine.name == "mine" and mine.mass_scale == 1.15 and mine.torque_scale == 0.9
    assert mine.payload_offset == (0.0, 0.02, 0.0) and mine.latency_steps == 2
    assert Reality.load(mine) is mine and Reality.load({"friction": 0.3}).foot_friction == 0.3


def test_a_profile_reads_numbers_in_exponent_form(tmp_path):
    """PyYAML reads 1.0e6, 1e-3 (no dot or no exponent sign) as text: they were refused as
    "must be a number, got '1.0e6'"; text that is no number still is."""
    f = tmp_path / "exp.yaml"
    f.write_text("mass_scale: 1.2e0\nnoise_q: 1e-3\npayload_offset: [1e-2, 0, 0]\n"
                 "latency_steps: 2e0\n")
    r = Reality.load(str(f))
    assert (r.mass_scale, r.noise_q, r.payload_offset, r.latency_steps) == (1.2, 1e-3, (0.01, 0, 0), 2)
    for bad in ("abc", "1e", "-1e3"):
        with pytest.raises(UsageError):
            Reality.load({"mass_scale": bad})


def test_relative_fields_scale_with_the_robot():
    """The presets' payload, pushes and joint friction are fractions of the robot's mass, weight
    and torque limit: the same share of a light Solo12 as of an A1, resolved by the worlds."""
    hard = Reality.load("hard")
    a1, solo = hard.for_robot(12.0, 50.0), hard.for_robot(2.5, 2.7)
    assert not a1.relative and a1.for_robot(1.0, 1.0) is a1
    assert a1.payload_mass == pytest.approx(12.0 * hard.payload_fraction)
    assert a1.push_force == pytest.approx(12.0 * 9.81 * hard.push_fraction)
    assert a1.joint_friction == pytest.approx(50.0 * hard.joint_friction_fraction)
    assert solo.payload_mass / a1.payload_mass == pytest.approx(2.5 / 12.0)
    both = Reality(payload_mass=1.0, payload_fraction=0.1, push_force=5.0).for_robot(10.0, 1.0)
    assert both.payload_mass == pytest.approx(2.0) and both.push_force == 5.0
    assert Reality(push_force=5.0).for_robot(10.0, 1.0) == Reality(push_force=5.0)
    for engine in ENGINES:
        w = world(engine, **hard.to_dict())
        assert w.reality.payload_mass == pytest.approx(hard.payload_fraction * 12.458, rel=1e-3)
        assert w.reality.joint_friction == pytest.approx(hard.joint_friction_fraction * 55.0)
        assert w.reality.push_force == pytest.approx(hard.push_fraction * 12.458 * 9.81, rel=1e-3)
    with pytest.raises(UsageError, match="push_fraction must be finite and >= 0"):
        Reality(push_fraction=-0.1)


def test_task_records_and_rebuilds_reality_and_engine():
    nominal = Task("a1", steps=100)
    assert "reality" not in nominal.config() and "engine" not in nominal.config()
    assert Task("a1", steps=100, reality="nominal").config() == nominal.config()
    t = Task("a1", steps=100, reality="hard", engine="mujoco", seed=3)
    cfg = t.config()
    assert cfg["engine"] == "mujoco" and cfg["reality"] == Reality.load("hard").to_dict()
    back = Task.from_config(json.loads(json.dumps(cfg)))
    assert back.config() == cfg and back.reality == t.reality and back.engine == "mujoco"
    # another reality or engine is another configuration (a resume compares configs)
    assert Task("a1", steps=100, reality="heavy", seed=3).config() != cfg
    assert Task("a1", steps=100, reality="hard", seed=3).config() != cfg
    assert back.cache_key() == t.cache_key() != nominal.cache_key()
    with pytest.raises(UsageError, match="unknown engine 'ode'"):
        Task("a1", engine="ode")
    assert ENGINES == ("pybullet", "mujoco")


# ----------------------------------------------------------------------------- worlds
def test_nominal_reality_keeps_the_default_numbers():
    costs = [Task("a1", steps=2000, reality=r) for r in (None, "nominal")]
    costs = [t.rollout(t.space.manual).cost for t in costs]
    assert costs[0] == costs[1]                     # nominal is no profile, to the last bit
    # the default numbers; the last digits depend on the CPU (BLAS and the QP solver choose
    # their kernels by it), far below this tolerance
    assert costs[0] == pytest.approx(4.3968415056, rel=1e-6)


@engines
def test_world_interface(engine):
    w = world(engine)
    assert isinstance(w, SimWorld) and w.engine == engine and w.dt == 0.001
    s = w.true_state()
    assert s.pos.shape == s.vel.shape == s.omega.shape == (3,) and s.q.shape == s.dq.shape == (12,)
    assert w.state().pos.tolist() == s.pos.tolist()  # no noise: the controller sees the truth
    assert abs(s.pos[2] - A1.nominal_height) < 0.02 and s.up_z > 0.999
    assert w.foot_contacts().all() and w.body_ground_contact() is None
    feet = w.foot_positions()
    assert feet.shape == (4, 3) and np.all(np.abs(feet[:, 2] - A1.foot_radius) < 0.005)
    with pytest.raises(UsageError, match="same engine and reality"):
        Task("a1", reality="heavy", engine=engine).use_world(w)


def test_a_world_without_visual_shapes_moves_and_renders_like_one_with_them():
    """PyBullet worlds skip the URDF's visual meshes (the physics never reads them): the same
    rollout to the last bit, and render() draws a twin with them, posed like the world."""
    from latentune.sim.world import World

    bare, full = World(A1, "hills", seed=3), World(A1, "hills", seed=3, visuals=True)
    assert not bare.visuals and full.visuals
    runs = []
    for w in (bare, full):
        t = Task("a1", gait="jump", terrain="hills", seed=3, steps=250)
        t.use_world(w)
        runs.append(t.rollout(np.linspace(0.2, 0.8, t.space.dim), record=True))
    assert runs[0].cost == runs[1].cost
    assert np.array_equal(runs[0].trace["pos"], runs[1].trace["pos"])
    frames = bare.render(64, 48), full.render(64, 48)
    assert frames[0].shape == (48, 64, 3) and frames[0].std() > 1
    assert np.array_equal(*frames)                  # the robot is drawn in the same pose
    place(full, (0.0, 0.0, 0.6))
    assert not np.array_equal(full.render(64, 48), frames[0])
    bare.close()
    assert bare._twin is None and bare.cid is None


def test_hills_are_computed_once_and_handed_out_as_copies():
    from latentune.sim import perlin_heightfield

    a = perlin_heightfield(40, 7)
    assert a.shape == (40, 40) and a.min() == 0.0 and a.max() == pytest.approx(0.02)
    a[0, 0] = 1.0                                   # the caller's copy, not the cached field
    b = perlin_heightfield(40, 7)
    assert b[0, 0] != 1.0 and b is not perlin_heightfield(40, 7) and b.flags.writeable
    assert not np.array_equal(b, perlin_heightfield(40, 8))


@engines
def test_mass_inertia_payload(engine):
    nom, heavy = world(engine), world(engine, mass_scale=1.3, inertia_scale=2.0, payload_mass=3.0)
    if engine == "pybullet":
        def masses(w):
            info = [p.getDynamicsInfo(w.robot, j, physicsClientId=w.cid)
                    for j in range(-1, p.getNumJoints(w.robot, physicsClientId=w.cid))]
            return sum(i[0] for i in info), np.array(info[0][2])
    else:
        def masses(w):
            return float(w.mjmodel.body_mass.sum()), w.mjmodel.body_inertia[w.base_id].copy()
    (m0, i0), (m1, i1) = masses(nom), masses(heavy)
    assert m1 == pytest.approx(1.3 * m0 + 3.0, rel=1e-6)
    assert np.sort(i1) == pytest.approx(2.6 * np.sort(i0), rel=1e-6)  # × mass_scale · inertia_scale
    # under the same θ a heavier robot sinks: lower mean height; a payload ahead pitches it down
    res = {}
    for name, r in [("nominal", None), ("heavy", {"mass_scale": 1.3}),
                    ("ahead", {"payload_mass": 3.0, "payload_offset": [0.1, 0.0, 0.0]})]:
        t = Task("a1", steps=2000, reality=r, engine=engine)
        res[name] = t.rollout(t.space.manual, record=True)
        assert not res[name].fell
    assert res["heavy"].mean_height < res["nominal"].mean_height - 0.005
    assert res["ahead"].mean_height < res["nominal"].mean_height - 0.005
    pitch = {k: float(np.mean(r.trace["rpy"][-1000:, 1])) for k, r in res.items()}
    assert pitch["ahead"] > pitch["nominal"] + 0.03  # nose down [rad]


@engines
def test_motor_and_joint_parameters(engine):
    ref = knee_response(world(engine), -2.0)
    assert abs(ref[-1]) > 5.0
    ratio = {}
    for name, r in [("scale", {"torque_scale": 0.5}), ("limit", {"torque_limits": [20.0, 55.0, 1.0]}),
                    ("damping", {"joint_damping": 0.05}), ("friction", {"joint_friction": 0.5})]:
        ratio[name] = knee_response(world(engine, **r), -2.0)[-1] / ref[-1]
    assert ratio["scale"] == pytest.approx(0.5, abs=0.03)       # half the torque
    assert ratio["limit"] == pytest.approx(0.5, abs=0.03)       # 2 N·m saturated at 1 N·m
    assert 0.6 < ratio["damping"] < 0.95 and 0.4 < ratio["friction"] < 0.8
    stuck = knee_response(world(engine, joint_friction=0.5), -0.3)  # below the friction torque
    assert np.abs(stuck).max() < 0.05 * np.abs(knee_response(world(engine), -0.3)).max()
    # latency: the response starts exactly latency_steps later
    for lat in (0, 3, 10):
        resp = knee_response(world(engine, latency_steps=lat) if lat else world(engine), -2.0)
        assert int(np.argmax(np.abs(resp) > 1e-9)) == 5 + lat


def test_latency_sends_the_command_of_latency_steps_ago_and_holds_no_copies():
    """The queue held latency_steps copies of the first command: latency_steps 10**12 (a
    legal profile) was a MemoryError traceback. It holds the commands sent only."""
    for lat in (3, 10 ** 12):
        rt = RealityRuntime(Reality(latency_steps=lat), 0, 0.001)
        cmds = [np.full(12, float(k)) for k in range(8)]
        out = [rt.motor(c)[0] for c in cmds]
        assert out == [float(max(0, k - lat)) for k in range(8)] and len(rt.queue) <= 8
        rt.reset()
        assert rt.motor(np.full(12, 9.0))[0] == 9.0


@pytest.mark.skipif(importlib.util.find_spec("mujoco") is None, reason="needs mujoco")
def test_a_restitution_mujoco_cannot_take_is_refused_not_capped():
    """MuJoCo's contacts take a restitution up to 0.85: 0.95 ran as 0.85, unsaid."""
    with pytest.raises(UsageError, match="MuJoCo takes a restitution of at most 0.85.*, got 0.95"):
        Task(steps=10, engine="mujoco", reality={"restitution": 0.95})
    Task(steps=10, engine="mujoco", reality={"restitution": 0.85})
    Task(steps=10, reality={"restitution": 0.95})


def test_a_latency_not_shorter_than_the_rollout_is_refused(tmp_path, run_cli, error_line):
    """latency_steps >= the rollout's steps: no command of the controller ever acted (the
    first one was held throughout), and the rollout was scored as if it were the controller's."""
    with pytest.raises(UsageError, match="latency_steps 200 .* not shorter than the rollout's 200 steps"):
        Task(steps=200, reality={"latency_steps": 200})
    Task(steps=201, reality={"latency_steps": 200})
    prof = tmp_path / "slow.yaml"
    prof.write_text("latency_steps: 100000\n")
    code, out, err = run_cli("rollout", "--steps", "50", "--reality", str(prof), "--json")
    assert code == 2 and out == ""
    assert "latency_steps 100000 " in error_line(code, err) and "50 steps" in error_line(code, err)


@engines
def test_lower_friction_more_foot_slip(engine):
    def slip(w):
        f0 = w.foot_positions()
        for _ in range(300):  # 50 N forward on the base for 0.3 s, stance held
            w.apply(hold(w, w.true_state()))
            w._push(np.array([50.0, 0.0, 0.0]))
            w._raw_step()
        return float(np.linalg.norm((w.foot_positions() - f0)[:, :2], axis=1).mean())
    s1, s05, s02 = slip(world(engine)), slip(world(engine, friction_scale=0.5)), slip(world(engine, friction=0.2))
    assert s1 < s05 < s02 and s02 > 3 * s1


@engines
def test_restitution_bounces(engine):
    def rebound(w):
        place(w, [0.0, 0.0, 0.5], (1.0, 0.0, 0.0, 0.0))  # upside down: the trunk lands first
        vz = []
        for _ in range(500):
            w.apply(hold(w, w.true_state()))
            w.step()
            vz.append(w.true_state().vel[2])
        vz = np.array(vz)
        return float(vz[int(np.argmin(vz)):].max())
    assert rebound(world(engine, restitution=0.8)) > 1.5 * rebound(world(engine))


@engines
def test_sensor_noise_is_the_controllers_view_only(engine):
    sd = {"noise_pos": 0.01, "noise_rpy": 0.02, "noise_vel": 0.1, "noise_omega": 0.2,
          "noise_q": 0.03, "noise_dq": 0.4}
    w = world(engine, **sd)
    s = w.true_state()
    obs = [w.observe(s) for _ in range(2000)]
    assert w.true_state().pos.tolist() == s.pos.tolist()
    for key, get in [("noise_pos", lambda o: o.pos - s.pos), ("noise_vel", lambda o: o.vel - s.vel),
                     ("noise_omega", lambda o: o.omega - s.omega), ("noise_q", lambda o: o.q - s.q),
                     ("noise_dq", lambda o: o.dq - s.dq)]:
        assert np.std([get(o) for o in obs]) == pytest.approx(sd[key], rel=0.1), key
    tilt = [math.acos(min(1.0, (np.trace(o.R.T @ s.R) - 1) / 2)) for o in obs]  # rotation angle
    assert np.sqrt(np.mean(np.square(tilt)) / 3) == pytest.approx(0.02, rel=0.1)
    # the actor sees noisy velocities; the cost uses the true ones: with 0.2 m/s of noise a cost
    # of noisy velocities would be ≥ sqrt(2000 · 3 · 0.2²) = 15.5
    t = Task("a1", steps=2000, reality={"noise_vel": 0.2}, engine=engine)
    nominal = Task("a1", steps=2000, engine=engine)
    r, r0 = t.rollout(t.space.manual), nominal.rollout(nominal.space.manual)
    assert not r.fell and r.cost < 12.0 and r.cost != r0.cost


def test_push_schedule():
    r = Reality(push_force=30.0, push_duration=0.05, push_interval=0.5)
    rt = RealityRuntime(r, seed=0, dt=0.001)
    forces = np.array([f if (f := rt.push()) is not None else np.zeros(3) for _ in range(100_000)])
    on = np.linalg.norm(forces, axis=1)
    assert set(np.round(on, 9)) == {0.0, 30.0} and np.all(forces[:, 2] == 0)
    starts = np.flatnonzero(np.diff((on > 0).astype(int)) == 1)
    assert len(starts) == pytest.approx(100.0 / 0.55, rel=0.15)  # a push per interval + duration
    assert (on > 0).sum() == pytest.approx(50 * len(starts), abs=50)
    rt.reset()
    again = np.array([f if (f := rt.push()) is not None else np.zeros(3) for _ in range(100_000)])
    assert np.array_equal(forces, again)
    other = RealityRuntime(r, seed=1, dt=0.001)
    assert not np.array_equal(forces[:20000], [f if (f := other.push()) is not None else np.zeros(3)
                                               for _ in range(20000)])


@engines
def test_pushes_shake_the_robot(engine):
    runs = {}
    for name, r in [("calm", None), ("pushed", {"push_force": 60.0, "push_interval": 0.5})]:
        t = Task("a1", steps=2000, reality=r, engine=engine)
        runs[name] = t.rollout(t.space.manual, record=True)
    assert not runs["pushed"].fell
    assert runs["pushed"].trace["vel"][:, 1].std() > 2 * runs["calm"].trace["vel"][:, 1].std()


def test_reproducible_for_a_seed_and_different_across_seeds():
    t = Task("a1", steps=1000, reality="hard", seed=0)
    c0 = t.rollout(t.space.manual).cost
    assert t.rollout(t.space.manual).cost == c0
    fresh = Task("a1", steps=1000, reality="hard", seed=0)
    assert fresh.rollout(fresh.space.manual).cost == c0
    t1 = Task("a1", steps=1000, reality="hard", seed=1)
    assert t1.rollout(t1.space.manual).cost != c0
    # a profile without random parts does not depend on the seed (flat ground)
    h0, h1 = (Task("a1", steps=1000, reality="heavy", seed=s) for s in (0, 1))
    assert h0.rollout(h0.space.manual).cost == h1.rollout(h1.space.manual).cost


# ----------------------------------------------------------------------------- MuJoCo
@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_manual_theta_walks_on_a1_in_mujoco():
    t = Task("a1", "trot", steps=5000, engine="mujoco")
    r = t.rollout(t.space.manual, record=True)
    assert not r.fell, r.reason
    assert r.mean_vx > 0.3 and 0.27 < r.mean_height < 0.31      # walks, neither crawls nor sinks
    assert abs(r.trace["pos"][-1, 1]) < 0.1 and r.cost < 10.0
    pb = Task("a1", "trot", steps=5000)
    assert r.cost != pb.rollout(pb.space.manual).cost             # another engine, another contact


@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_a_mujoco_world_that_cannot_render_names_the_engine_as_the_reader_sets_it(monkeypatch):
    """MuJoCo without an OpenGL context said "... or use --engine pybullet" to a Python caller
    too (a GIF of ``Task(engine='mujoco')``); the engine is named as the reader sets it
    (:func:`latentune.wording.option`)."""
    import mujoco

    from latentune.wording import command_line_words

    def no_gl(*a, **k):
        raise RuntimeError("no OpenGL context")

    monkeypatch.setattr(mujoco, "Renderer", no_gl)
    w = make_world(A1, "flat", 0, engine="mujoco")
    with pytest.raises(UsageError) as e:
        w.render()
    assert str(e.value).endswith("or use engine='pybullet'"), e.value
    with command_line_words(), pytest.raises(UsageError) as e:
        w.render()
    assert str(e.value).endswith("or use --engine pybullet"), e.value


@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_mujoco_hills_are_the_pybullet_hills():
    import mujoco

    w = make_world(A1, "hills", 5, engine="mujoco")
    pb = make_world(A1, "hills", 5)
    assert np.array_equal(w.heights, pb.heights) and w.ground_z == pb.ground_z and w.start_x == -1.25
    geom = np.zeros(1, dtype=np.int32)
    rng = np.random.default_rng(0)
    for i, j in rng.integers(40, 95, size=(20, 2)):  # vertices ahead of the robot
        x, y = (i - 49.5) * 0.05, (j - 49.5) * 0.05
        d = mujoco.mj_ray(w.mjmodel, w._data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]),
                          None, 1, -1, geom)
        assert geom[0] == w.ground_geom and 1.0 - d == pytest.approx(w.ground_height(x, y), abs=1e-6)
    t = Task("a1", terrain="hills", steps=1500, engine="mujoco", seed=5)
    t.use_world(w)
    assert not t.rollout(t.space.manual).fell


@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_mujoco_blow_up_is_a_non_finite_state(tmp_path, monkeypatch, capfd, caplog):
    monkeypatch.chdir(tmp_path)
    w = make_world(A1, "flat", 0, engine="mujoco")
    for case in ("ctrl", "qvel"):  # a huge control (MuJoCo zeroes it), a huge velocity (resets)
        w.reset()
        if case == "qvel":
            w._data.qvel[:] = 1e30
        for _ in range(3):
            w.apply(np.full(12, 1e30 if case == "ctrl" else 0.0))
            w.step()
        assert not w.true_state().finite, case  # the fall detector is told: "simulator blow-up"
    out, err = capfd.readouterr()
    assert out == "" and not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert any(r.name == "latentune.sim.mujoco_world" and r.levelname == "WARNING"
               and r.getMessage().startswith("MuJoCo warning") for r in caplog.records)
    w.reset()
    assert w.true_state().finite


@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_an_unusable_mujoco_gl_is_one_line(cli, cli_env):
    """mujoco's import loads MUJOCO_GL's backend: an unknown name (or osmesa without its
    library, which the render error suggested) was a traceback of the import."""
    out = cli("rollout", "--engine", "mujoco", "--steps", "3",
              env=dict(cli_env, MUJOCO_GL="bogus"), timeout=120)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.splitlines() == [
        "latentune: error: mujoco cannot be imported (RuntimeError: invalid value for environment "
        "variable MUJOCO_GL: bogus); MUJOCO_GL=bogus is not usable here: unset it or set it to egl"]


@pytest.mark.skipif(not HAVE_MUJOCO or ctypes.util.find_library("EGL") is None,
                    reason="no mujoco, or no libEGL to draw without a display")
def test_a_mujoco_gif_without_a_display_or_mujoco_gl_is_drawn_headless(cli, cli_env, tmp_path):
    """``rollout --engine mujoco --gif`` on a machine without a display and MUJOCO_GL unset
    (mujoco then loads GLFW, which needs a display) was refused after the rollout: 'MuJoCo
    cannot render here ... set MUJOCO_GL=egl'. Without a display, an unset MUJOCO_GL is egl
    (osmesa without libEGL) before mujoco is imported, and the GIF is drawn."""
    env = {k: v for k, v in cli_env.items()
           if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    gif = tmp_path / "x.gif"
    out = cli("rollout", "--robot", "a1", "--task", "trot", "--engine", "mujoco", "--steps", "20",
              "--gif", gif, env=env, timeout=300)
    assert out.returncode == 0 and out.stderr == "", out.stderr
    assert gif.read_bytes()[:4] == b"GIF8"
    # the robot can be seen: a lit ground, and a robot much darker than it (before the light
    # and the ground's colour: every pixel of the first frame between 34 and 43 of 255)
    import imageio.v3 as iio

    grey = iio.imread(gif)[0][..., :3].astype(float).mean(axis=2)
    assert np.median(grey) > 120 and np.percentile(grey, 2) < np.median(grey) - 60, \
        (np.median(grey), np.percentile(grey, 2))


@pytest.mark.skipif(not HAVE_MUJOCO, reason="no mujoco")
def test_a_mujoco_gl_that_cannot_draw_here_is_named_in_one_line(cli, cli_env, tmp_path):
    """A MUJOCO_GL that imports but cannot draw here (glfw without a display) was told to set
    MUJOCO_GL=egl without being named (the same line as for an unset one); it is named."""
    env = {k: v for k, v in cli_env.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = cli("rollout", "--engine", "mujoco", "--steps", "20", "--gif", tmp_path / "x.gif",
              env=dict(env, MUJOCO_GL="glfw"), timeout=300)
    assert out.returncode == 2 and len(out.stderr.splitlines()) == 1, out.stderr
    assert out.stderr.startswith(
        "latentune: error: MuJoCo cannot render here with MUJOCO_GL=glfw (")
    assert out.stderr.endswith("set MUJOCO_GL=egl (or osmesa), or use --engine pybullet\n")
    assert not (tmp_path / "x.gif").exists()


def test_pybullet_blow_up_at_finite_positions_is_a_fall():
    """A huge joint damping blows PyBullet up with finite positions: the base velocity jumps
    between ±100 m/s (its clamp) at a plausible height. It was a stable rollout at the capped
    cost just below C1; it is a fall at the step it happens."""
    task = Task("a1", steps=50, reality={"joint_damping": 1e9})
    res = task.rollout(task.space.manual)
    assert res.fell and res.fall_step == 1 and res.cost == pytest.approx(200 - 2)
    assert res.reason == "simulator blow-up (base speed 173 m/s)"


def test_a_study_of_one_reality_refuses_another(tmp_path):
    from latentune.errors import StoreError
    from latentune.study import Study

    heavy = Task("a1", steps=100, reality="heavy")
    Study(tmp_path / "run").bind(heavy)
    Study(tmp_path / "run").bind(heavy)                                 # the same: resumes
    with Study(tmp_path / "run") as st:                                 # a trial of it stored
        st.store.add(1, 0, np.full(heavy.space.dim, 0.5), 1.0, fell=False)
    for other in (Task("a1", steps=100, reality="slippery"), Task("a1", steps=100),
                  Task("a1", steps=100, reality="heavy", engine="mujoco")):
        with pytest.raises(StoreError, match="another"):
            Study(tmp_path / "run").bind(other)


@pytest.mark.parametrize("text", ["", "# my robot, to do\n", "{}\n", "name: mine\n"],
                         ids=["empty", "a comment", "an empty mapping", "a name only"])
def test_a_profile_file_without_fields_is_refused(tmp_path, run_cli, error_line, text):
    """``--reality FILE`` of an empty file (or one holding no field) ran the nominal simulator
    without a word, though a user passing a file means a change: it is refused in one line
    naming the file and the keys a profile holds (the nominal preset stays nominal)."""
    f = tmp_path / "mine.yaml"
    f.write_text(text)
    with pytest.raises(UsageError, match=f"reality {f}: the file sets no field") as exc:
        Reality.load(str(f))
    assert "(known: base, friction, " in str(exc.value) and "\n" not in str(exc.value)
    line = error_line(*run_cli("rollout", "--reality", f, "--steps", "10")[::2])
    assert line.startswith(f"latentune: error: reality {f}: the file sets no field"), line
    (tmp_path / "on_it.yaml").write_text(f"base: [{f.name}]\ntorque_scale: 0.9\n")
    with pytest.raises(UsageError, match=f"reality {f}: the file sets no field"):
        Reality.load(str(tmp_path / "on_it.yaml"))
    assert Reality.load("nominal") == Reality(name="nominal")


def test_a_profile_is_its_fields_not_its_file_name(tmp_path, run_cli, error_line):
    """A run made with ``--reality mine.yaml`` was refused on a resume with a copy of the file
    under another name ("another system (task.reality.name: stored 'mine', given 'copy')"),
    and a heavy run with a file holding ``base: [heavy]``: a profile's name is a label, the
    perturbation is its fields. Other fields are still another system."""
    (tmp_path / "mine.yaml").write_text("torque_scale: 0.9\n")
    (tmp_path / "copy.yaml").write_text("torque_scale: 0.9\n")
    (tmp_path / "on_heavy.yaml").write_text("base: [heavy]\n")
    (tmp_path / "other.yaml").write_text("torque_scale: 0.8\n")
    common = ("--steps", "20", "--backend", "serial", "--quiet")
    for reality, again in (("mine.yaml", "copy.yaml"), ("heavy", "on_heavy.yaml")):
        run = tmp_path / f"run_{reality}"
        for n, r, more in ((2, reality, []), (3, again, ["--resume"])):
            code, _, err = run_cli("phase1", *common, "--reality", tmp_path / r if "." in r
                                   else r, "--out", run, "--phase1-evals", n, *more)
            assert code == 0, err
    line = error_line(*run_cli("phase1", *common, "--reality", tmp_path / "other.yaml", "--out",
                               tmp_path / "run_mine.yaml", "--phase1-evals", 4, "--resume")[::2])
    assert "holds a run of another system (task.reality.torque_scale: stored 0.9, given 0.8)" \
        in line, line


def test_a_run_with_a_reality_file_resumed_without_it_names_the_file(tmp_path, run_cli,
                                                                     error_line, monkeypatch):
    """A run made with ``--reality mine.yaml`` and resumed without it said only "another
    system (task.reality: stored {'torque_scale': 0.9}, given None)": the file was not
    recorded. Its path (as given, made absolute) is recorded and suggested; that flag, or the
    path spelled another way, resumes. A file that no longer holds the profile is not
    suggested."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "mine.yaml").write_text("torque_scale: 0.9\n")
    monkeypatch.chdir(work)
    common = ("--steps", "20", "--backend", "serial", "--quiet", "--out", tmp_path / "run")
    code, _, err = run_cli("phase1", *common, "--reality", "mine.yaml", "--phase1-evals", 2)
    assert code == 0, err
    from latentune.study import Study

    assert Study(tmp_path / "run").config()["task"]["reality_file"] == str(work / "mine.yaml")
    line = error_line(*run_cli("phase1", *common, "--phase1-evals", 3, "--resume")[::2])
    assert line.endswith(f"given None): pass --reality {work / 'mine.yaml'} to go on with it"), \
        line
    monkeypatch.chdir(tmp_path)
    for n, path in ((3, str(work / "mine.yaml")), (4, "work/mine.yaml")):
        code, _, err = run_cli("phase1", *common, "--reality", path, "--phase1-evals", n,
                               "--resume")
        assert code == 0, err
    (work / "mine.yaml").write_text("torque_scale: 0.8\n")
    line = error_line(*run_cli("phase1", *common, "--phase1-evals", 5, "--resume")[::2])
    assert "given None)" in line and "pass --reality" not in line, line


def test_a_custom_robot_named_like_a_built_in_one_gets_its_own_world():
    """A spec named 'b1' that is not the built-in B1 (robot init on example-robot-data's
    b1-z1.urdf named it so) had the same world key: the paper report's world cache (and
    use_world) would have run it in the built-in B1's world."""
    import dataclasses
    import types

    from latentune.robots import get_robot

    b1 = get_robot("b1")
    other = dataclasses.replace(b1, kp=tuple(2 * k for k in b1.kp))
    builtin, custom = Task("b1"), Task(robot=other)
    assert custom.robot_name == "b1" and builtin.world_key() != custom.world_key()
    assert Task(robot=dataclasses.replace(other)).world_key() == custom.world_key()
    world = types.SimpleNamespace(spec=b1, terrain="flat", engine="pybullet", reality=builtin.reality)
    with pytest.raises(UsageError, match="same robot"):
        custom.use_world(world)
    builtin.use_world(world)


@engines
def test_a_joint_the_spec_does_not_drive_is_held_as_in_the_model(engine, tmp_path):
    """A URDF joint outside ``joint_names`` (ANYmal's Kinova arm, a spinning lidar) stays at its
    zero position as in the MPC's model: PyBullet's default motors held it, while MuJoCo let it
    swing free (the arm's third joint ended at 4.2 rad of a trot)."""
    import dataclasses
    from pathlib import Path

    src = Path(A1.urdf)
    arm = ('<link name="arm"><inertial><origin xyz="0.15 0 0"/><mass value="0.5"/><inertia '
           'ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>'
           '<joint name="arm_joint" type="revolute"><parent link="trunk"/><child link="arm"/>'
           '<origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit effort="5" lower="-3" upper="3" '
           'velocity="10"/></joint></robot>')
    (tmp_path / "a1_arm.urdf").write_text(src.read_text().replace("</robot>", arm))
    (tmp_path / "meshes").symlink_to(src.parent / "meshes")
    spec = dataclasses.replace(A1, name="a1_arm", urdf=str(tmp_path / "a1_arm.urdf"))
    w = make_world(spec, "flat", 0, engine=engine)
    w.reset()
    for _ in range(200):
        w.apply(np.zeros(12))
        w.step()
    if engine == "mujoco":
        import mujoco
        m, d = w.mjmodel, w._data
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "arm_joint") == -1
        trunk, link = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in ("trunk", "arm"))
        rel = d.xmat[trunk].reshape(3, 3).T @ d.xmat[link].reshape(3, 3)
    else:
        j = next(j for j in range(p.getNumJoints(w.robot, physicsClientId=w.cid))
                 if p.getJointInfo(w.robot, j, physicsClientId=w.cid)[1] == b"arm_joint")
        angle = p.getJointState(w.robot, j, physicsClientId=w.cid)[0]
        rel = np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0],
                        [-math.sin(angle), 0, math.cos(angle)]])
    assert rel == pytest.approx(np.eye(3), abs=1e-3)
