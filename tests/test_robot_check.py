"""Robot specs checked against their URDF at load, check_spec, init_spec on Go1/Go2, PyBullet off
stdout, fall reasons that name the link."""
from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from latentune.errors import RobotSpecError, RobotSpecWarning
from latentune.robots import erd_robots_dir, get_robot, load_spec_file, prepared_urdf, spec_from_dict
from latentune.robots.check import CheckReport, check_spec
from latentune.robots.template import init_spec
from latentune.robots.urdf import read_urdf

A1_URDF = Path(get_robot("a1").urdf)
GO1 = erd_robots_dir() / "go1_description" / "urdf" / "go1.urdf"
GO2 = erd_robots_dir() / "go2_description" / "urdf" / "go2.urdf"
A1_JOINTS = [f"{leg}_{j}_joint" for leg in ("FR", "FL", "RR", "RL") for j in ("hip", "upper", "lower")]


def spec_file(tmp_path: Path, text: str, name: str = "robot.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def urdf_file(tmp_path: Path, text: str, name: str = "robot.urdf") -> Path:
    """``text`` written to ``tmp_path/name``, beside A1's meshes/ (a URDF is loaded with the
    mesh files it names)."""
    p = tmp_path / name
    p.write_text(text)
    if not (tmp_path / "meshes").exists():
        (tmp_path / "meshes").symlink_to(A1_URDF.parent / "meshes")
    return p


def load_error(path: Path) -> str:
    with pytest.raises(RobotSpecError) as exc:
        load_spec_file(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"robot spec {path}: ")
    return msg


# ----------------------------------------------------------------------------- the URDF itself
@pytest.mark.parametrize("text, message", [
    ("", "the file is empty"),
    ("this is not XML\n", "not XML"),
    ('<robot name="x"><link name="a"></robot>', "not XML"),
    ('<sdf version="1.6"/>', "top element is <sdf>"),
    ('<robot name="x"/>', "no <link> elements"),
    ('<robot name="x"><link name="a"/></robot>', "no <joint> elements"),
    ('<robot name="x"><link name="a"/><joint name="j" type="fixed"><parent link="a"/>'
     '<child link="b"/></joint></robot>', "undefined link 'b'"),
    ('<robot name="x"><link name="a"/><link name="b"/><link name="c"/><joint name="j" type="fixed">'
     '<parent link="a"/><child link="b"/></joint></robot>', "do not form one tree"),
])
def test_bad_urdf_is_one_line_naming_the_file(tmp_path, text, message):
    urdf = urdf_file(tmp_path, text)
    msg = load_error(spec_file(tmp_path, f"base: a1\nurdf: {urdf}\n"))
    assert f"URDF {urdf}: " in msg and message in msg


def test_cli_reports_a_bad_urdf_in_one_line(tmp_path, run_cli, error_line):
    urdf = urdf_file(tmp_path, "garbage")
    spec = spec_file(tmp_path, f"base: a1\nurdf: {urdf}\n")
    code, out, err = run_cli("rollout", "--robot", spec, "--steps", "5")
    assert out == "" and error_line(code, err) == (
        f"latentune: error: robot spec {spec}: URDF {urdf}: not XML (syntax error: line 1, column 0)")


def test_check_takes_the_robot_names_rollout_takes(tmp_path, monkeypatch, run_cli):
    """`robot check NAME` resolves NAME as `--robot NAME` does: an unknown name is refused
    naming the choices (not "file not found"), and a spec file without .yaml is not OK in
    check while every other command refuses it."""
    unknown = "unknown robot 'go1' (choose from a1, b1, solo12 or a spec .yaml)"
    assert check_spec("go1").errors == [unknown]
    code, out, _ = run_cli("robot", "check", "go1", "--no-sim")
    assert code == 2 and out.splitlines()[1] == f"  error: {unknown}"
    monkeypatch.chdir(tmp_path)
    Path("myrobot").write_text("base: a1\n")
    assert check_spec("myrobot").errors == [unknown.replace("go1", "myrobot")]
    assert check_spec("./myrobot", simulate=False).ok


# ----------------------------------------------------------------------------- names and leg order
def test_wrong_joint_and_foot_names(tmp_path):
    names = list(A1_JOINTS)
    names[4] = "FL_thigh_joint"
    msg = load_error(spec_file(tmp_path, f"base: a1\njoint_names: {names}\n"))
    assert "joint_names: not in the URDF: FL_thigh_joint" in msg and "FR_hip_joint" in msg  # lists real ones
    names = list(A1_JOINTS)
    names[2] = "FR_toe_fixed"
    msg = load_error(spec_file(tmp_path, f"base: a1\njoint_names: {names}\n", "b.yaml"))
    assert "FR_toe_fixed is fixed, not revolute or continuous" in msg
    msg = load_error(spec_file(tmp_path, "base: a1\nfoot_links: [FR_toe, FL_toe, RR_toe, RL_foot]\n", "c.yaml"))
    assert "foot_links: not links of the URDF: RL_foot" in msg and "FR_toe" in msg


def test_swapped_feet_and_legs_are_refused(tmp_path):
    # feet swapped left/right: FL's toe is not below FR's knee
    msg = load_error(spec_file(tmp_path, "base: a1\nfoot_links: [FL_toe, FR_toe, RR_toe, RL_toe]\n"))
    assert "foot_links: FL_toe (leg FR) is not below that leg's knee joint FR_lower_joint" in msg
    # whole legs swapped (joints and feet together): the geometry says FL where FR is expected
    names = A1_JOINTS[3:6] + A1_JOINTS[0:3] + A1_JOINTS[6:]
    msg = load_error(spec_file(tmp_path, f"base: a1\njoint_names: {names}\n"
                                         "foot_links: [FL_toe, FR_toe, RR_toe, RL_toe]\n", "b.yaml"))
    assert re.search(r"leg FR's foot FL_toe is at x=\+0\.183, y=\+0\.132 m .*\(FL\); FR needs x > 0, y < 0", msg)
    assert "leg FL's foot FR_toe" in msg
    # joints of one leg out of order
    names = list(A1_JOINTS)
    names[0], names[1] = names[1], names[0]
    msg = load_error(spec_file(tmp_path, f"base: a1\njoint_names: {names}\n", "c.yaml"))
    assert "leg FR (FR_upper_joint, FR_hip_joint, FR_lower_joint) is not one chain" in msg


def test_feet_must_be_below_the_base_and_at_the_contact_point(tmp_path):
    msg = load_error(spec_file(tmp_path, "base: a1\nnominal_q: [0, 3.1, 0, 0, 3.1, 0, 0, 3.1, 0, 0, 3.1, 0]\n"))
    assert "nominal_q: feet not below the base" in msg
    msg = load_error(spec_file(tmp_path, "base: a1\nfoot_links: [FR_lower, FL_lower, RR_lower, RL_lower]\n", "b.yaml"))
    assert "foot_links: FR_lower, FL_lower, RR_lower, RL_lower at the knee joint, not at the foot" in msg


def test_a_foot_larger_than_the_leg_is_refused_and_a_large_one_warns(tmp_path):
    """A foot_radius beyond the leg length (hip -> knee -> foot) only warned that nominal_height
    was off the forward-kinematics height, and nothing at all with nominal_height omitted (the
    height then follows the foot); it is refused naming the range. A foot over a quarter of the
    leg (a ball foot, a wheel) still loads, with a warning; the built-in robots' are 5-6 %."""
    leg = check_spec("a1", simulate=False).leg_length
    for extra in ("", "nominal_height: 0.8\n"):
        msg = load_error(spec_file(tmp_path, f"base: a1\nfoot_radius: 0.5\n{extra}"))
        assert msg.endswith(f": foot_radius must be in (0, {leg:.3g}) m, below the leg length "
                            "(hip -> knee -> foot at q = 0), got 0.5"), msg
    rep = check_spec(spec_file(tmp_path, "base: a1\nfoot_radius: 0.15\nnominal_height: 0.43\n",
                               "b.yaml"), simulate=False)
    assert rep.ok and rep.warnings == [
        f"foot_radius 0.15 m is {100 * 0.15 / leg:.0f}% of the leg length {leg:.3g} m (more than "
        "25%): a ball foot or a wheel?"]
    for name in ("a1", "b1", "solo12"):
        assert check_spec(name, simulate=False).warnings == [], name


def test_a_joint_limit_whose_lower_is_above_its_upper_is_refused(tmp_path):
    """A spec joint whose URDF <limit> has lower > upper (swapped: PyBullet reads it as no
    limit at all) loaded without a word, and nominal_q was not checked against it; it is
    refused naming the joint, its lower limit and the bound it must be under."""
    text = A1_URDF.read_text()
    bad = text.replace('lower="-1.0471975512" upper="4.18879020479"',
                       'lower="4.18879020479" upper="-1.0471975512"', 1)
    assert bad != text
    urdf = urdf_file(tmp_path, bad)
    msg = load_error(spec_file(tmp_path, f"base: a1\nurdf: {urdf}\n"))
    assert msg.endswith(": joint_names: FR_upper_joint's URDF <limit> lower must be at most its "
                        "upper -1.047 rad, got 4.189"), msg


def test_a_link_with_mass_and_a_zero_moment_of_inertia_warns(tmp_path):
    """A link of mass > 0 with a zero moment of inertia (a point mass or a thin rod: a limit,
    not a body) loaded without a word, while a negative one is refused; it loads with a
    warning naming the link, the moment and the mass."""
    text = A1_URDF.read_text()
    zero = text.replace('ixx="0.005529065"', 'ixx="0"', 1)
    assert zero != text
    rep = check_spec(spec_file(tmp_path, f"base: a1\nurdf: {urdf_file(tmp_path, zero)}\n"),
                     simulate=False)
    assert rep.ok and rep.warnings == [
        "link 'FR_upper' has mass 1.013 kg and the moment of inertia ixx = 0 kg·m² (a point mass "
        "or a thin rod, not a body): give its moments (the engines need them > 0)"]
    neg = urdf_file(tmp_path, text.replace('ixx="0.005529065"', 'ixx="-0.005"', 1), "n.urdf")
    assert "inertia moments ixx, iyy, izz must be >= 0 [kg·m²], got ixx=-0.005" in load_error(
        spec_file(tmp_path, f"base: a1\nurdf: {neg}\n", "n.yaml"))


def test_a_link_welded_by_a_fixed_joint_may_have_zero_moments(tmp_path, run_cli):
    """HyQ's `trunk_imu` (0.018 kg, moments 0, fixed to the trunk) was warned about on every
    load ("the engines need them > 0"), yet a link on a fixed joint is welded into its parent's
    body: its moments add to the parent's, a point mass is no limit there (HyQ's rollouts were
    the same to 8 digits with moments 1e-6, in PyBullet and MuJoCo). Such a link loads
    without a word; a zero moment on a link that moves (FR_upper) still warns."""
    text = A1_URDF.read_text()
    toe = '<mass value="0.06"/>\n      <inertia ixx="9.6e-06" ixy="0.0" ixz="0.0" iyy="9.6e-06"'
    assert toe in text
    zero = text.replace(toe, '<mass value="0.06"/>\n      <inertia ixx="0" ixy="0.0" ixz="0.0" iyy="0"', 1)
    spec = spec_file(tmp_path, f"base: a1\nurdf: {urdf_file(tmp_path, zero)}\n")
    rep = check_spec(spec, simulate=False)
    assert rep.ok and rep.warnings == []
    code, out, err = run_cli("rollout", "--robot", spec, "--steps", "200", "--json")
    code_a1, out_a1, _ = run_cli("rollout", "--robot", "a1", "--steps", "200", "--json")
    assert code == code_a1 == 0 and err == ""
    # the toe loses its own moments (9.6e-6 kg·m²): the cost moves by ~1e-6, relative
    assert json.loads(out)["cost"] == pytest.approx(json.loads(out_a1)["cost"], rel=1e-5)
    moving = zero.replace('ixx="0.005529065"', 'ixx="0"', 1)
    rep = check_spec(spec_file(tmp_path, f"base: a1\nurdf: {urdf_file(tmp_path, moving, 'm.urdf')}\n",
                               "m.yaml"), simulate=False)
    assert [w.split(" has ")[0] for w in rep.warnings] == ["link 'FR_upper'"]


# ----------------------------------------------------------------------------- computed fields
def test_nominal_height_and_torque_limits_from_the_urdf(tmp_path, capsys):
    text = "\n".join(f"{k}: {json.dumps(v)}" for k, v in
                     {**get_robot("a1").to_dict(), "name": "a1_urdf_values"}.items()
                     if k not in ("nominal_height", "torque_limits", "strip_root"))
    spec = load_spec_file(spec_file(tmp_path, text))
    assert spec.nominal_height == pytest.approx(0.2987, abs=1e-4)      # foot_radius − mean foot z
    assert spec.torque_limits == (20.0, 55.0, 55.0)                    # <limit effort>
    assert spec.strip_root is False and spec_from_dict(spec.to_dict()) == spec
    assert capsys.readouterr().err == ""


def test_nominal_height_far_from_forward_kinematics_warns_once(tmp_path, capsys):
    p = spec_file(tmp_path, "base: a1\nname: tall_a1\nnominal_height: 0.40\n")
    with pytest.warns(RobotSpecWarning) as rec:
        spec = load_spec_file(p)
        load_spec_file(p)
    assert spec.nominal_height == 0.40 and len(rec) == 1
    assert str(rec[0].message) == (
        f"robot spec {p}: nominal_height 0.400 m is +34% off the height 0.299 m that nominal_q "
        "gives with the feet on the ground (forward kinematics); omit nominal_height to use that")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotSpecWarning)                        # 4 %: quiet
        load_spec_file(spec_file(tmp_path, "base: a1\nname: a1b\nnominal_height: 0.31\n", "b.yaml"))
    assert capsys.readouterr().err == ""


def test_massless_root_is_stripped_when_strip_root_is_omitted(tmp_path):
    base = {k: v for k, v in get_robot("b1").to_dict().items() if k not in ("strip_root", "torque_limits")}
    spec = spec_from_dict(base)
    assert spec.strip_root is True and spec.torque_limits == (91.0035, 93.33, 140.0)
    assert read_urdf(spec.urdf).massless_root() and read_urdf(prepared_urdf(spec)).root == "trunk"
    with pytest.warns(RobotSpecWarning, match="strip_root is false but the root link 'base' is "
                                              "massless"):
        spec_from_dict({**base, "strip_root": False})


def test_primitive_collisions_without_table_or_foot_shape(tmp_path):
    msg = load_error(spec_file(tmp_path, "base: a1\nprimitive_collisions: true\n"))
    assert "primitive_collisions needs collision_primitives" in msg
    msg = load_error(spec_file(tmp_path, "base: a1\nprimitive_collisions: true\n"
                                         "collision_primitives: {trunk: {box: [0.2, 0.1, 0.1]}}\n", "b.yaml"))
    assert "no key ends the foot link name(s) FR_toe, FL_toe, RR_toe, RL_toe" in msg
    urdf = urdf_file(tmp_path, re.sub(r'(<link name="FR_toe">.*?)<collision>.*?</collision>', r"\1",
                                      A1_URDF.read_text(), count=1, flags=re.S))
    msg = load_error(spec_file(tmp_path, f"base: a1\nurdf: {urdf}\n", "c.yaml"))
    assert "foot link(s) FR_toe have no collision shape PyBullet uses" in msg


def test_continuous_joints_become_revolute(tmp_path):
    import pinocchio as pin

    urdf = urdf_file(tmp_path, A1_URDF.read_text().replace(
        '<joint name="FR_lower_joint" type="revolute">', '<joint name="FR_lower_joint" type="continuous">'))
    spec = load_spec_file(spec_file(tmp_path, f"base: a1\nname: a1c\nurdf: {urdf}\n"))
    text = Path(prepared_urdf(spec)).read_text()
    assert 'type="continuous"' not in text and read_urdf(prepared_urdf(spec)).joints["FR_lower_joint"].type == "revolute"
    assert pin.buildModelFromUrdf(prepared_urdf(spec)).nq == 12


# ----------------------------------------------------------------------------- check_spec
def test_check_spec_reports_measurements_and_all_errors(tmp_path):
    rep = check_spec("a1")
    assert isinstance(rep, CheckReport) and rep.ok and rep.errors == [] and rep.warnings == []
    assert rep.mass == pytest.approx(12.458) and rep.fk_height == pytest.approx(0.2987, abs=1e-4)
    feet = np.array(rep.foot_positions)
    assert (np.sign(feet[:, :2]) == [[1, -1], [1, 1], [-1, -1], [-1, 1]]).all() and (feet[:, 2] < 0).all()
    assert rep.torque_limits == [20.0, 55.0, 55.0] and rep.urdf_torque_limits == [20.0, 55.0, 55.0]
    assert json.loads(json.dumps(rep.to_dict()))["ok"] is True and "OK" in rep.format().splitlines()[0]
    assert rep.settled_height == pytest.approx(0.292, abs=0.005)          # stood up in PyBullet
    assert rep.closest_link.endswith("_lower") and 0.01 < rep.body_clearance < 0.02
    assert check_spec(get_robot("b1"), simulate=False).ok and check_spec(get_robot("solo12").to_dict(), simulate=False).ok

    bad = check_spec(spec_file(tmp_path, "base: a1\nnominal_height: 0.5\nkp: [1, 2]\n"))
    assert not bad.ok and bad.errors == ["kp needs 3 entries, got 2"]
    bad = check_spec(spec_file(tmp_path, "base: a1\nfoot_links: [FL_toe, FR_toe, RR_toe, RL_toe]\n", "b.yaml"))
    assert len(bad.errors) == 2 and "INVALID" in bad.format() and bad.mass == pytest.approx(12.458)
    assert check_spec(tmp_path / "none.yaml").errors == [f"robot spec file not found: {tmp_path / 'none.yaml'}"]
    warn = check_spec(spec_file(tmp_path, "base: a1\nnominal_height: 0.5\ntorque_limits: [20, 55, 99]\n", "c.yaml"))
    assert warn.ok and len(warn.warnings) == 2 and "knee 99 > 55" in warn.warnings[1]


# ----------------------------------------------------------------------------- init_spec
@pytest.fixture(scope="module")
def go_specs(tmp_path_factory):
    d = tmp_path_factory.mktemp("go")
    out = {}
    for name, urdf in (("go1", GO1), ("go2", GO2)):
        p = d / f"{name}.yaml"
        p.write_text(init_spec(urdf))
        out[name] = p
    return out


def test_init_spec_go1_go2(go_specs):
    go1, go2 = load_spec_file(go_specs["go1"]), load_spec_file(go_specs["go2"])
    for spec in (go1, go2):
        assert spec.joint_names == tuple(f"{leg}_{j}_joint" for leg in ("FR", "FL", "RR", "RL")
                                         for j in ("hip", "thigh", "calf"))   # Go2's URDF lists FL first
        assert spec.foot_links == ("FR_foot", "FL_foot", "RR_foot", "RL_foot")  # not the rotor leaves
        assert spec.nominal_q[:3] == pytest.approx((0.0, 0.7227, -1.4455), abs=1e-4)
        rep = check_spec(spec, simulate=False)
        assert spec.gaits["trot"].period == 0.392 and rep.ok and not rep.warnings
    assert go1.strip_root is True and go2.strip_root is False
    assert go1.torque_limits == (23.7, 23.7, 35.55) and go2.torque_limits == (23.7, 23.7, 45.43)
    assert (go1.kp, go1.kd) == ((100.0,) * 3, (1.0, 2.0, 2.0)) and go2.kp == (130.0,) * 3
    assert go1.foot_radius == 0.02 and go2.foot_radius == pytest.approx(0.0206)  # sphere; STL extent
    assert yaml.safe_load(go_specs["go1"].read_text())["urdf"] == {
        "package": "example-robot-data", "path": "go1_description/urdf/go1.urdf"}


def test_init_spec_replaces_collisions_that_reach_the_ground():
    """HyQ's lower-leg collision is 1 mm above the ground at the stance: a base box and foot
    spheres instead (with the URDF's shapes the robot 'falls' at step 10, body contact)."""
    text = init_spec(erd_robots_dir() / "hyq_description" / "robots" / "hyq_no_sensors.urdf")
    d = yaml.safe_load(text)
    assert d["foot_links"] == ["rf_foot", "lf_foot", "rh_foot", "lh_foot"]
    assert d["nominal_q"][6:9] == pytest.approx([0.0, -0.7177, 1.4455], abs=1e-4)  # rear knees forward (limits)
    assert d["primitive_collisions"] is True and d["collision_primitives"]["_foot"] == {"sphere": "foot_radius"}
    assert "lf_lowerleg is 1.0 mm from the ground" in text and set(d["collision_primitives"]) == {"trunk", "_foot"}


def test_primitive_collisions_give_each_matched_link_one_shape():
    """HyQ's trunk collides through a .dae mesh, which PyBullet ignores and the rewrite dropped
    before replacing collisions: the init spec's trunk box was never added (a belly on the
    ground was no fall in either engine), and a link with several collisions (ANYmal's base:
    8, HyQ's feet: 2) got one copy of its shape for each. Each link a key matches now has
    exactly that shape; links no key matches have none."""
    import xml.etree.ElementTree as ET

    from latentune.robots import prepared_urdf, spec_from_dict

    for urdf, box in (("hyq_description/robots/hyq_no_sensors.urdf", "trunk"),
                      ("anymal_b_simple_description/robots/anymal.urdf", "base")):
        d = yaml.safe_load(init_spec(erd_robots_dir() / urdf))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            spec = spec_from_dict(d)
        links = {ln.get("name"): ln for ln in ET.parse(prepared_urdf(spec)).getroot().iter("link")}
        shapes = {n: [g.tag for c in ln.findall("collision") for g in c.find("geometry")]
                  for n, ln in links.items()}
        assert shapes[box] == ["box"], (urdf, shapes[box])
        feet = [n for n in spec.foot_links]
        assert all(shapes[f] == ["sphere"] for f in feet), {f: shapes[f] for f in feet}
        assert all(not v for n, v in shapes.items() if n != box and n not in feet), shapes


def test_a_missing_mesh_file_is_named_at_load(tmp_path, capsys):
    """A collision mesh file that is not there (a URDF copied without its meshes/) passed the
    load; rollout then ended in a traceback ('pybullet.error: Cannot load URDF file.'), robot
    check said 'PyBullet cannot build the robot (error: Cannot load URDF file.)'. The load now
    names the link and the file."""
    from latentune.cli import main

    text = A1_URDF.read_text().replace('<box size="0.267 0.194 0.114"/>',
                                       '<mesh filename="meshes/none.stl"/>', 1)
    urdf_file(tmp_path, text, "a1.urdf")
    spec = spec_file(tmp_path, "base: a1\nurdf: a1.urdf\n")
    msg = load_error(spec)
    assert msg.endswith("link 'trunk': collision mesh meshes/none.stl not found (a path is "
                        "relative to the URDF's directory): add the file, or give "
                        "primitive_collisions"), msg
    assert main(["rollout", "--robot", str(spec), "--steps", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "collision mesh meshes/none.stl not found" in err[0], err
    # PyBullet refuses a missing visual mesh as well, with visual shapes ignored or not (the
    # MuJoCo engine discards visuals), also with primitive_collisions
    text = A1_URDF.read_text().replace('<mesh filename="meshes/trunk.obj"',
                                       '<mesh filename="nowhere/trunk.obj"', 1)
    urdf_file(tmp_path, text, "vis.urdf")
    for extra in ("", "primitive_collisions: true\ncollision_primitives: {trunk: {box: [0.2, "
                      "0.1, 0.1]}, _toe: {sphere: foot_radius}}\n"):
        msg = load_error(spec_file(tmp_path, "base: a1\nurdf: vis.urdf\n" + extra, "vis.yaml"))
        assert "link 'trunk': visual mesh nowhere/trunk.obj not found" in msg, msg


def test_init_spec_refuses_what_is_not_a_quadruped(tmp_path):
    text = A1_URDF.read_text()
    for leg in ("RR", "RL"):  # rear legs of two joints
        text = text.replace(f'<joint name="{leg}_hip_joint" type="revolute">', f'<joint name="{leg}_hip_joint" type="fixed">')
    with pytest.raises(RobotSpecError, match=r"init needs 4 legs of 3 revolute joints .*found chains: "
                                             r"FR_hip_joint…\(3 joints\), FL_hip_joint…\(3 joints\), "
                                             r"RR_upper_joint…\(2 joints\)"):
        init_spec(urdf_file(tmp_path, text))
    with pytest.raises(RobotSpecError, match="not XML"):
        init_spec(urdf_file(tmp_path, "<robot", "b.urdf"))
    # an empty path (an unset shell variable) was the working directory: "cannot read (Is a directory)"
    for empty in ("", "  "):
        with pytest.raises(RobotSpecError, match="the URDF path is empty"):
            init_spec(empty)
    with pytest.raises(RobotSpecError, match=f"URDF {tmp_path}: is a directory, not a URDF file"):
        init_spec(tmp_path)


@pytest.mark.parametrize("name", ["go1", "go2"])
def test_init_spec_robot_trots_with_the_manual_weights(go_specs, name):
    from latentune.task import Task

    task = Task(robot=str(go_specs[name]), gait="trot")
    res = task.rollout(task.space.manual)
    assert not res.fell, res.reason
    assert res.steps == 5000 and res.mean_vx > 0.4 and 0.9 * 0.34 < res.mean_height < 1.05 * 0.34
    assert res.cost < 6.0


# ----------------------------------------------------------------------------- PyBullet off stdout
def test_rollout_json_is_the_only_stdout_line(tmp_path, cli):
    """In a process: PyBullet's C-level output must not reach the file descriptor of stdout."""
    # strip_root false: PyBullet's URDF parser warns about the massless root (on stdout by default)
    spec = spec_file(tmp_path, f"base: b1\nname: go1_raw\nurdf: {GO1}\nstrip_root: false\n"
                               "nominal_height: 0.32\ntorque_limits: [23.7, 23.7, 35.55]\nkp: [100, 100, 100]\n"
                               "kd: [1, 2, 2]\nfoot_radius: 0.02\n")
    out = cli("rollout", "--robot", spec, "--json", "--steps", "200", timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["robot"] == "go1_raw" and json.loads(lines[0])["steps"] > 0
    assert "strip_root is false" in out.stderr and "b3Warning" not in out.stdout


def test_stdout_to_stderr_moves_c_level_output():
    code = ("import ctypes; from latentune.sim.bullet import stdout_to_stderr\n"
            "libc = ctypes.CDLL(None)\n"
            "with stdout_to_stderr():\n    libc.printf(b'from C\\n')\n"
            "print('from python')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout == "from python\n" and out.stderr == "from C\n"


# ----------------------------------------------------------------------------- fall reasons
def test_body_contact_names_the_link(monkeypatch):
    from latentune.sim.bullet import p
    from latentune.task import Task

    task = Task(robot="a1", gait="trot", steps=50)
    world = task.world
    world.reset()
    assert world.body_ground_contact() is None
    p.resetBasePositionAndOrientation(world.robot, [0, 0, 0.03], p.getQuaternionFromEuler([np.pi, 0, 0]),
                                      physicsClientId=world.cid)  # on its back
    p.stepSimulation(physicsClientId=world.cid)
    assert world.body_ground_contact() == "trunk" and world.body_touches_ground()
    world.reset()
    monkeypatch.setattr(type(world), "body_ground_contact", lambda self: "FR_lower")
    res = task.rollout(task.space.manual)
    assert res.fell and res.fall_step == 10 and res.reason == "body touched the ground: link FR_lower"


def test_init_spec_does_not_name_a_robot_like_a_built_in_one(tmp_path):
    """example-robot-data's b1-z1.urdf (a B1 with an arm) is <robot name="b1_description">, and
    A1's URDF gives 'a1': the spec was named like the built-in robot without a word."""
    copy = tmp_path / "b1-z1.urdf"
    copy.write_text(A1_URDF.read_text())          # <robot name="a1_description">
    (tmp_path / "meshes").symlink_to(A1_URDF.parent / "meshes")
    for urdf, expected in ((A1_URDF, "my_a1"), (copy, "b1-z1")):
        with pytest.warns(RobotSpecWarning, match=r"the URDF's robot name 'a1' is the built-in "
                                                   rf"robot's: the spec is named '{expected}' "
                                                   r"\(give name='NAME' for another\)"):
            d = yaml.safe_load(init_spec(urdf))
        assert d["name"] == expected
    with pytest.warns(RobotSpecWarning, match="'a1' is the name of a built-in robot.*choose "
                                              "another name to tell them apart"):
        assert yaml.safe_load(init_spec(A1_URDF, name="a1"))["name"] == "a1"   # as asked


def test_init_spec_names_the_name_option_as_the_reader_gives_it():
    """init_spec's warnings of a built-in robot's name said "give --name for another" and
    "choose another --name" to a Python caller too; they name the option as the reader gives
    it (:func:`latentune.wording.option`: ``name=`` in Python, ``--name`` at the command
    line, where ``robot init`` runs it)."""
    from latentune.wording import command_line_words

    with command_line_words():
        with pytest.warns(RobotSpecWarning, match=r"\(give --name NAME for another\)"):
            init_spec(A1_URDF)
        with pytest.warns(RobotSpecWarning, match="choose another --name to tell them apart"):
            init_spec(A1_URDF, name="a1")


def test_a_root_without_inertial_carrying_the_legs_is_not_warned_about():
    """ANYmal C's root 'base' has no <inertial> and carries the legs: check warned that PyBullet
    zeroes its inertia and a root of mass 0 would be fixed in space, but the prepared URDF gives
    such a link a negligible mass and the robot floats; a root of mass 0 is still refused."""
    urdf = erd_robots_dir() / "anymal_c_simple_description" / "urdf" / "anymal.urdf"
    d = yaml.safe_load(init_spec(urdf))
    rep = check_spec(d, simulate=False)
    assert rep.ok and rep.warnings == []
    assert read_urdf(prepared_urdf(spec_from_dict(d))).links["base"].mass == pytest.approx(1e-6)


def test_init_spec_names_solo12_by_its_file(tmp_path):
    """example-robot-data's solo12.urdf and solo.urdf (Solo8) are both <robot name="solo">:
    robot init named Solo12 'solo', as Solo8, and said nothing of the built-in 'solo12'. A file
    stem that extends the robot name is more specific and names the spec; one that is a
    built-in robot's gives 'my_<stem>' with a warning."""
    solo = erd_robots_dir() / "solo_description" / "robots"
    with pytest.warns(RobotSpecWarning, match=r"the URDF file's name 'solo12' is the built-in "
                                               r"robot's: the spec is named 'my_solo12'"):
        assert yaml.safe_load(init_spec(solo / "solo12.urdf"))["name"] == "my_solo12"
    copy = tmp_path / "solo12_light.urdf"
    copy.write_text((solo / "solo12.urdf").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert yaml.safe_load(init_spec(copy))["name"] == "solo12_light"
