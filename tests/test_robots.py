"""Robot specs: built-in YAML files, the user loader, dict round-trip, URDF preparation."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import latentune.robots as robots
from latentune.errors import LatentuneError, RobotSpecError
from latentune.robots import (BUILTIN, GaitParams, RobotSpec, get_robot, is_builtin,
                              load_spec_file, prepared_urdf, spec_from_dict)

REPO = Path(__file__).resolve().parent.parent


def write(tmp_path: Path, text: str, name: str = "robot.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ----------------------------------------------------------------------------- built-in robots
def test_builtin_names_and_error_type():
    assert BUILTIN == ("a1", "b1", "solo12")
    assert robots.RobotSpecError is RobotSpecError and issubclass(RobotSpecError, LatentuneError)


def test_builtin_known_values():
    a1, b1, solo = get_robot("a1"), get_robot("b1"), get_robot("solo12")
    assert a1.nominal_height == 0.30 and a1.torque_limits == (20.0, 55.0, 55.0)
    assert a1.gaits["trot"] == GaitParams(0.3833, 0.6, 0.08, (0.0, 0.5, 0.5, 0.0))
    assert a1.gaits["jump"].offsets == (0.0, 0.0, 0.0, 0.0)
    assert a1.nominal_q == (0.0, 0.8, -1.6) * 4 and a1.joint_names[1] == "FR_upper_joint"
    assert (a1.strip_root, a1.primitive_collisions, a1.raibert_gain, a1.mu) == (False, False, 0.03, 0.45)
    assert Path(a1.urdf).parts[-3:] == ("pybullet_data", "a1", "a1.urdf")
    assert b1.strip_root is True and b1.raibert_gain == 0.04 and b1.foot_links[0] == "FR_foot"
    assert Path(b1.urdf) == robots.erd_robots_dir() / "b1_description" / "urdf" / "b1.urdf"
    assert solo.primitive_collisions is True and solo.mu == 0.6 and solo.foot_radius == 0.0175
    assert solo.collision_primitives["UPPER_LEG"].xyz == (0.0, 0.0, -0.08)
    assert solo.collision_primitives["FOOT"].size == ()  # sphere of foot_radius
    for name in BUILTIN:
        spec = get_robot(name)
        assert spec.name == name and Path(spec.urdf).is_absolute() and Path(spec.urdf).is_file()
        assert is_builtin(spec) and len(spec.joint_names) == 12 and spec.max_tilt_deg == 60.0


def test_builtin_specs_are_package_files_read_by_the_user_loader():
    pkg = Path(robots.__file__).resolve().parent
    assert robots.SPECS_DIR.resolve() == pkg / "specs"
    for name in BUILTIN:
        assert load_spec_file(pkg / "specs" / f"{name}.yaml") == get_robot(name)
    # the returned spec is a copy: mutating it does not change the built-in
    spec = get_robot("a1")
    spec.gaits.pop("jump")
    assert "jump" in get_robot("a1").gaits and not is_builtin(spec)


def test_builtin_specs_ship_in_the_wheel_and_load_from_the_installed_package(tmp_path):
    """Build a wheel from a copy of the sources, unpack it, and load the built-ins from there."""
    src = tmp_path / "src"
    shutil.copytree(REPO / "src" / "latentune", src / "src" / "latentune",
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for f in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / f, src / f)
    build = subprocess.run([sys.executable, "-c", "import sys; from setuptools import build_meta; "
                            "print(build_meta.build_wheel(sys.argv[1]))", str(tmp_path / "dist")],
                           cwd=src, capture_output=True, text=True, timeout=120)
    assert build.returncode == 0, build.stderr[-2000:]
    wheel = tmp_path / "dist" / build.stdout.strip().splitlines()[-1]
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as z:
        assert {f"latentune/robots/specs/{n}.yaml" for n in BUILTIN} <= set(z.namelist())
        z.extractall(site)
    code = ("import json, latentune.robots as r; "
            "print(json.dumps([r.__file__, str(r.SPECS_DIR), r.BUILTIN, r.get_robot('b1').to_dict()]))")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    mod_file, specs_dir, names, b1 = json.loads(out.stdout)
    assert Path(mod_file).is_relative_to(site) and Path(specs_dir) == site / "latentune" / "robots" / "specs"
    assert tuple(names) == BUILTIN and b1 == get_robot("b1").to_dict()


# ----------------------------------------------------------------------------- to_dict / spec_from_dict
@pytest.mark.parametrize("name", BUILTIN)
def test_to_dict_round_trip(name):
    spec = get_robot(name)
    d = spec.to_dict()
    assert set(d) == {f for f in RobotSpec.__dataclass_fields__}
    assert d["urdf"] == str(Path(spec.urdf).resolve())
    d2 = json.loads(json.dumps(d))  # JSON-able, and floats survive exactly
    back = spec_from_dict(d2)
    assert back == spec and is_builtin(back)
    assert get_robot(d2) == spec


def test_spec_from_dict_validates_like_the_loader():
    d = get_robot("a1").to_dict()
    d["mu"] = -1.0
    with pytest.raises(RobotSpecError, match="mu must be a positive number"):
        spec_from_dict(d)
    d = get_robot("a1").to_dict()
    del d["kp"]
    with pytest.raises(RobotSpecError, match="missing field"):
        spec_from_dict(d)
    d = get_robot("a1").to_dict()
    d["nominal_q"] = d["nominal_q"][:11]
    with pytest.raises(RobotSpecError, match="nominal_q needs 12 entries, got 11"):
        get_robot(d)
    changed = spec_from_dict({**get_robot("a1").to_dict(), "mu": 0.5})
    assert changed.mu == 0.5 and not is_builtin(changed)


# ----------------------------------------------------------------------------- user YAML files
def test_user_yaml_with_base_overrides_one_field(tmp_path):
    p = write(tmp_path, "base: a1\nname: heavy_a1\nnominal_height: 0.28\n")
    spec = get_robot(str(p))
    assert spec.nominal_height == 0.28 and spec.name == "heavy_a1"
    a1 = get_robot("a1")
    assert spec == RobotSpec(**{**a1.__dict__, "name": "heavy_a1", "nominal_height": 0.28})
    assert not is_builtin(spec) and get_robot(p) == spec  # a Path works as well as a str
    assert spec_from_dict(spec.to_dict()) == spec


def test_base_spec_without_a_name_is_named_by_its_file(tmp_path, run_cli, error_line):
    """A `base: a1` spec without `name:` kept the name `a1`: `rollout --json` said robot "a1"
    and its θ files were "tuned for a1 trot (convex)", as the built-in A1's. It is now named by
    its file's stem; where that is no name of its own (a built-in's, or a dict without a file),
    it is refused in one line asking for one."""
    import latentune as lt

    p = write(tmp_path, "base: a1\nkp: [120, 120, 120]\n", "heavy_a1.yaml")
    spec = load_spec_file(p)
    assert spec.name == "heavy_a1" and spec.kp == (120.0,) * 3 and not is_builtin(spec)
    assert robots.check_spec(p, simulate=False).name == "heavy_a1"
    task = lt.Task(robot=str(p), gait="trot")
    assert task.space.tuned_for == {"robot": "heavy_a1", "gait": "trot", "actor": "convex"}
    assert task.config()["robot"] == "heavy_a1"
    code, out, _ = run_cli("rollout", "--robot", p, "--steps", "5", "--json")
    assert code == 0 and json.loads(out)["robot"] == "heavy_a1"
    own = write(tmp_path, "base: a1\nkp: [120, 120, 120]\n", "a1.yaml")
    code, out, err = run_cli("rollout", "--robot", own, "--steps", "5", "--json")
    assert out == "" and error_line(code, err) == (
        f"latentune: error: robot spec {own}: a spec with base: a1 needs a name of its own "
        "(e.g. name: my_a1); its file's stem 'a1' is a built-in robot's")
    with pytest.raises(RobotSpecError, match=r"base: b1 needs a name of its own \(e.g. name: my_b1\)$"):
        spec_from_dict({"base": "b1"})


def test_a_spec_file_named_as_a_built_in_but_other_warns(tmp_path, run_cli):
    """A spec file that names itself `a1` but is another robot (other gains here) passed as the
    built-in A1 without a word: `rollout --json` said robot "a1" and its θ files were tuned for
    "a1 trot (convex)". It loads with one warning naming the fields that differ; a file equal
    to the built-in loads without one."""
    p = write(tmp_path, "base: a1\nname: a1\nkp: [120, 120, 120]\nmu: 0.5\n", "mine.yaml")
    code, out, err = run_cli("rollout", "--robot", p, "--steps", "5", "--json")
    assert code == 0 and json.loads(out)["robot"] == "a1"
    assert err.splitlines() == [
        f"latentune: warning: robot spec {p}: named a1, as a built-in robot, but not that robot "
        "(kp, mu differ): its θ files and results pass as the built-in a1's; give it a name of "
        "its own"]
    assert robots.check_spec(p, simulate=False).warnings == [err.split(f"{p}: ", 1)[1].strip()]
    assert robots.check_spec("a1", simulate=False).warnings == []
    same = write(tmp_path, "base: a1\nname: a1\n", "same.yaml")
    code, out, err = run_cli("rollout", "--robot", same, "--steps", "5", "--json")
    assert code == 0 and err == ""


def test_user_yaml_with_base_overrides_only_the_gaits_given(tmp_path):
    """`gaits: {trot: {period: 0.4}}` under `base: a1` replaced all of A1's gaits: the spec had
    no jump ('robot has no gait jump') and a trot without duty was refused. The gaits and gait
    fields given now override the base's, the others are kept."""
    a1 = get_robot("a1")
    spec = load_spec_file(write(tmp_path, "base: a1\nname: slow_a1\ngaits:\n  trot: {period: 0.4}\n"))
    assert spec.gaits["jump"] == a1.gaits["jump"]
    assert spec.gaits["trot"] == GaitParams(0.4, 0.6, 0.08, a1.gaits["trot"].offsets)
    spec = load_spec_file(write(tmp_path, "base: a1\ngaits:\n  walk: {period: 0.5, duty: 0.75, "
                                          "step_height: 0.05}\n", "walk.yaml"))
    assert set(spec.gaits) == {"trot", "jump", "walk"} and spec.gaits["trot"] == a1.gaits["trot"]


def test_user_yaml_reads_numbers_in_exponent_form(tmp_path):
    """A spec is read as the other user YAML files are (PyYAML alone reads 1e-2 and 2.8e-1 as
    text): numbers in exponent form are numbers, in a field, a list and a gait."""
    p = write(tmp_path, "base: a1\nname: exp_a1\nnominal_height: 2.8e-1\nkp: [1e2, 1e2, 1e2]\n"
                        "gaits:\n  trot: {period: 3.5e-1, duty: 6e-1, step_height: 8e-2}\n")
    spec = load_spec_file(p)
    assert spec.nominal_height == 0.28 and spec.kp == (100.0, 100.0, 100.0)
    assert spec.gaits["trot"] == GaitParams(0.35, 0.6, 0.08, spec.gaits["trot"].offsets)
    assert robots.check_spec(p, simulate=False).ok


def test_user_yaml_urdf_forms(tmp_path):
    a1_urdf = Path(get_robot("a1").urdf)
    (tmp_path / "urdf").mkdir()
    shutil.copy(a1_urdf, tmp_path / "urdf" / "mine.urdf")
    (tmp_path / "urdf" / "meshes").symlink_to(a1_urdf.parent / "meshes")  # the files it names
    rel = load_spec_file(write(tmp_path, "base: a1\nurdf: urdf/mine.urdf\n"))
    assert rel.urdf == str((tmp_path / "urdf" / "mine.urdf").resolve())
    absolute = load_spec_file(write(tmp_path, f"base: a1\nurdf: {a1_urdf}\n", "abs.yaml"))
    assert absolute.name == "abs" and absolute == RobotSpec(**{**get_robot("a1").__dict__, "name": "abs"})
    pkg = load_spec_file(write(tmp_path, "base: a1\nurdf: {package: pybullet_data, path: a1/a1.urdf}\n", "p.yaml"))
    assert pkg.urdf == str(a1_urdf.resolve())


def test_missing_field_is_a_clear_error(tmp_path):
    d = get_robot("a1").to_dict()
    del d["foot_radius"], d["gaits"]
    p = write(tmp_path, json.dumps(d))  # JSON is YAML
    with pytest.raises(RobotSpecError, match=r"robot\.yaml: missing field\(s\) foot_radius, gaits"):
        load_spec_file(p)


def test_bad_package_name_is_a_clear_error(tmp_path):
    p = write(tmp_path, "base: a1\nurdf: {package: no_such_robot_pkg, path: a1/a1.urdf}\n")
    with pytest.raises(RobotSpecError, match="urdf: package 'no_such_robot_pkg' is not installed"):
        get_robot(str(p))
    p = write(tmp_path, "base: a1\nurdf: {package: pybullet_data, path: a1/none.urdf}\n", "b.yaml")
    with pytest.raises(RobotSpecError, match="URDF not found: .*none.urdf"):
        get_robot(str(p))


@pytest.mark.parametrize("text, message", [
    ("base: a1\nunknown_key: 1\n", r"unknown field\(s\) unknown_key \(the fields: README, "),
    # a typo names the field it was meant to be (it said 'unknown field(s) nominal_heigth')
    ("base: a1\nnominal_heigth: 0.3\nkp: [1, 1, 1]\n",
     r"unknown field\(s\) nominal_heigth \(did you mean nominal_height\?\)"),
    ("base: spot\n", "unknown base robot 'spot'"),
    ("base: a1\nstrip_root: 'yes'\n", "strip_root must be true or false"),
    ("base: a1\ngaits: {trot: {period: 0.4, duty: 1.5, step_height: 0.08}}\n", "0 < duty < 1"),
    ("base: a1\nprimitive_collisions: true\n", "primitive_collisions needs collision_primitives"),
    ("base: solo12\ncollision_primitives: {FOOT: {cone: 1}}\n", "collision primitive 'FOOT'"),
    ("base: a1\nkp: 100\n", "kp must be a list"),
    # a gait's typo and missing fields are named (it said 'gait trot needs period, duty,
    # step_height', under base: a1 too, where the period was there)
    ("base: a1\ngaits: {trot: {perod: 0.4}}\n",
     r"gait 'trot': unknown field\(s\) perod \(did you mean period\?\)"),
    ("base: a1\ngaits: {walk: {period: 0.4}}\n",
     r"gait 'walk' needs period, duty, step_height \(and optional offsets\); missing: duty, "
     "step_height"),
    # impossible values are refused by field and value (they made every rollout a fall, or OK)
    ("base: a1\ngaits: {trot: {period: 0.38, duty: 0.6, step_height: 0.08, offsets: [.nan, 0.5, 0.5, 0]}}\n",
     r"gait 'trot': offsets must be phases in \[0, 1\) cycles, got nan"),
    ("base: a1\ngaits: {trot: {period: 0.38, duty: 0.6, step_height: 0.08, offsets: [0, 0.5, 1.5, 0]}}\n",
     r"offsets must be phases in \[0, 1\) cycles, got 1.5"),
    ("base: a1\ngaits: {trot: {period: 0.38, duty: 0.6, step_height: 0.08, offsets: [0, 0.5]}}\n",
     "offsets needs 4 entries"),
    ("base: a1\ngaits: {trot: {period: 0.38, duty: 0.6, step_height: .inf}}\n",
     "gait 'trot': step_height must be a finite number >= 0 .m., got inf"),
    ("base: a1\ngaits: {trot: {period: .inf, duty: 0.6, step_height: 0.08}}\n",
     "gait 'trot': period must be a positive finite number .s., got inf"),
    ("base: a1\ngaits: {trot: {period: 0, duty: 0.6, step_height: 0.08}}\n", "period must be a positive"),
    ("base: a1\ntorque_limits: [-20, 55, 55]\n", "torque_limits must be positive finite numbers, got -20"),
    ("base: a1\ntorque_limits: [20, 0, 55]\n", "torque_limits must be positive finite numbers, got 0"),
    ("base: a1\nkp: [-100, 100, 100]\n", "kp must be positive finite numbers, got -100"),
    ("base: a1\nkd: [1, -2, 2]\n", "kd must be positive finite numbers, got -2"),
    ("base: a1\nnominal_q: [0, .nan, -1.6, 0, 0.8, -1.6, 0, 0.8, -1.6, 0, 0.8, -1.6]\n",
     "nominal_q must be finite numbers, got nan"),
    # a tilt of 90 deg or more never counts a robot on its side or back as fallen
    ("base: a1\nmax_tilt_deg: 90\n", "max_tilt_deg must be below 90 .*, got 90"),
    ("base: a1\nmax_tilt_deg: 180\n", "max_tilt_deg must be below 90 .*, got 180"),
    ("base: a1\nmu: abc\n", "mu must be a positive number, got 'abc'"),
    ("base: a1\nkd: [1, x, 2]\n", r"kd must be a list of 3 numbers, got \[1, 'x', 2\]"),
    ("base: a1\nfoot_radius: true\n", "foot_radius must be a positive number, got True"),
    ("base: a1\nraibert_gain: -1\n", "raibert_gain must be a positive number, got -1"),
    # a gait value that is no number said only "bad value (could not convert string to float ...)"
    ("base: a1\ngaits: {trot: {period: abc, duty: 0.6, step_height: 0.08}}\n",
     "gait 'trot': period must be a number, got 'abc'"),
    ("base: a1\ngaits: {trot: {period: 0.38, duty: 0.6, step_height: 0.08, offsets: [0, x, 0.5, 0]}}\n",
     r"gait 'trot': offsets must be 4 numbers, got \[0, 'x', 0.5, 0\]"),
    ("[1, 2]\n", "expected a mapping"),
    ("name: [\n", "malformed YAML"),
    # an empty file said "expected a mapping of fields"
    ("", "the file is empty: it needs the spec's fields"),
    ("# only a comment\n", "the file is empty"),
])
def test_invalid_yaml_fields(tmp_path, text, message):
    with pytest.raises(RobotSpecError, match=message):
        load_spec_file(write(tmp_path, text))


@pytest.mark.parametrize("old, new, message", [
    ('<mass value="4.713"/>', '<mass value="-4.713"/>',
     r"link 'trunk': mass must be a finite number >= 0 \[kg\], got -4.713"),
    ('<mass value="4.713"/>', '<mass value="nan"/>', r"link 'trunk': mass must be .*, got nan"),
    ('ixx="0.01683993"', 'ixx="-0.01683993"', "link 'trunk': inertia moments ixx, iyy, izz must be >= 0 .*, got ixx=-0.0168"),
    ('ixx="0.01683993"', 'ixx="inf"', "link 'trunk': inertia must be finite numbers"),
    # a root of mass 0 is fixed in space by PyBullet: every rollout stood still and counted as stable
    ('<mass value="4.713"/>', '<mass value="0"/>', "the root link 'trunk' has mass 0 .* fixed in space"),
    # the URDF format (urdfdom, which pinocchio reads) requires all six: PyBullet took a missing
    # product as 0, MuJoCo stopped ('required attribute missing'), pinocchio printed a parse error
    # per link and the MPC's singular matrix ended the rollout in a traceback
    (' ixy="8.3902e-05" ixz="0.000597679"', '',
     r"link 'trunk': <inertia> lacks ixy, ixz \(the URDF format requires all six of ixx, ixy, ixz, "
     r"iyy, iyz, izz; write 0 for a product of inertia that is zero\)"),
    ('ixx="0.01683993"', 'ixx="heavy"', "link 'trunk': inertia ixx is not a number: 'heavy'"),
    ('<mass value="4.713"/>', '<mass value="4.7 kg"/>', "link 'trunk': mass is not a number: '4.7 kg'"),
])
def test_impossible_urdf_mass_or_inertia_is_refused(tmp_path, old, new, message):
    """Such a URDF loaded: a negative mass made every MPC QP infeasible, a NaN one every MPC
    problem non-finite (both falls), a negative inertia simulated, a massless root stood still."""
    text = Path(get_robot("a1").urdf).read_text()
    assert text.count(old) == 1
    (tmp_path / "a1.urdf").write_text(text.replace(old, new))
    with pytest.raises(RobotSpecError, match=message):
        load_spec_file(write(tmp_path, "base: a1\nurdf: a1.urdf\n"))


def test_unknown_robot_name():
    with pytest.raises(RobotSpecError, match="unknown robot 'spot'.*a1, b1, solo12"):
        get_robot("spot")
    with pytest.raises(RobotSpecError, match="not found"):
        get_robot("nowhere/robot.yaml")


# ----------------------------------------------------------------------------- URDF preparation
def test_prepared_urdf_of_a_copy_elsewhere_refers_to_its_own_meshes(tmp_path):
    # the same URDF text in two places (as in two venvs): each prepared copy names the meshes
    # beside its own source, and removing one place leaves the other loadable
    import dataclasses
    import shutil

    paths = {}
    for place in ("a", "b"):
        (tmp_path / place / "robots").mkdir(parents=True)
        (tmp_path / place / "meshes").mkdir()
        shutil.copy(Path(get_robot("solo12").urdf).parents[1] / "meshes" / "stl" / "solo12"
                    / "solo_12_base.stl", tmp_path / place / "meshes" / "base.stl")
        urdf = tmp_path / place / "robots" / "r.urdf"
        urdf.write_text('<robot name="r"><link name="base"><inertial><mass value="1"/>'
                        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>'
                        '</inertial><visual><geometry><mesh filename="package://r_pkg/meshes/'
                        'base.stl"/></geometry></visual></link></robot>')
        spec = dataclasses.replace(get_robot("solo12"), name="r_copy", urdf=str(urdf),
                                   strip_root=False, primitive_collisions=False)
        paths[place] = Path(prepared_urdf(spec))
    assert paths["a"] != paths["b"]
    for place, path in paths.items():
        assert f'filename="{tmp_path / place / "meshes" / "base.stl"}"' in path.read_text()
    shutil.rmtree(tmp_path / "a")
    import pybullet as pb
    c = pb.connect(pb.DIRECT)
    try:
        assert pb.loadURDF(str(paths["b"]), physicsClientId=c) >= 0
    finally:
        pb.disconnect(c)


def test_prepared_urdf_keeps_mesh_paths_relative_to_its_source(tmp_path):
    """A rewritten URDF lives in the temp directory: its source's relative mesh paths
    (``meshes/trunk.obj``) named nothing there, and PyBullet could not load it (a traceback)."""
    import dataclasses
    import shutil

    shutil.copytree(Path(get_robot("a1").urdf).parent, tmp_path / "a1")
    spec = dataclasses.replace(get_robot("a1"), name="a1_rel", urdf=str(tmp_path / "a1" / "a1.urdf"),
                               strip_root=True)
    text = Path(prepared_urdf(spec)).read_text()
    assert f'filename="{tmp_path / "a1" / "meshes" / "trunk.obj"}"' in text
    assert 'filename="meshes/' not in text
    import pybullet as pb
    c = pb.connect(pb.DIRECT)
    try:
        assert pb.loadURDF(prepared_urdf(spec), physicsClientId=c) >= 0
    finally:
        pb.disconnect(c)


def test_prepared_urdf(tmp_path):
    assert prepared_urdf(get_robot("a1")) == get_robot("a1").urdf  # nothing to rewrite
    b1 = Path(prepared_urdf(get_robot("b1"))).read_text()
    assert re.search(r'<link\s+name="([^"]+)"', b1).group(1) == "trunk"  # massless "base" stripped
    assert '<link name="base"' not in b1 and "package://" not in b1 and 'parent link="base"' not in b1
    solo = Path(prepared_urdf(get_robot("solo12"))).read_text()
    collisions = re.findall(r"<collision>.*?</collision>", solo, flags=re.S)
    assert len(collisions) == 1 + 3 * 4 and not any("<mesh" in c for c in collisions)
    assert solo.count('<sphere radius="0.0175"/>') == 4
    assert solo.count('<origin xyz="0 0 -0.08" rpy="0 0 0"/><geometry><box size="0.03 0.03 0.16"/>') == 4
    bigger = load_spec_file(write(tmp_path, "base: solo12\nname: solo_big_feet\nfoot_radius: 0.02\n"))
    assert Path(prepared_urdf(bigger)).read_text().count('<sphere radius="0.02"/>') == 4


def test_prepared_urdf_of_a_name_that_is_no_file_name(tmp_path):
    """The rewritten URDF's file name was the spec's name as it is: ``name: ../../x`` wrote it
    outside the temp directory, ``name: a b/c`` in a new subdirectory."""
    import tempfile

    cache = Path(tempfile.gettempdir()) / "latentune_urdf"
    for i, name in enumerate(("../../escaped_by_name", "a b/c", "ünï code")):
        spec = load_spec_file(write(tmp_path, f"base: b1\nname: {json.dumps(name)}\n", f"s{i}.yaml"))
        path = Path(prepared_urdf(spec))
        assert path.parent == cache and path.is_file(), (name, path)
    assert not any(cache.parent.parent.glob("escaped_by_name*"))


def test_a_link_without_inertial_is_massless_in_pybullet_too(tmp_path):
    """PyBullet gives a link without ``<inertial>`` 1 kg and 1 kg·m² about each axis (ANYmal C's
    root 'base'): the prepared URDF gives it a negligible one, as pinocchio and MuJoCo read it."""
    import types

    import pybullet as pb
    path = tmp_path / "bare.urdf"
    inertial = ('<inertial><mass value="{m}"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" '
                'iyz="0" izz="0.01"/></inertial>')
    path.write_text(
        '<robot name="bare"><link name="base"><collision><geometry><box size="0.5 0.2 0.2"/>'
        '</geometry></collision></link><link name="frame"/>'
        f'<link name="trunk">{inertial.format(m=3.0)}</link>'
        f'<link name="leg">{inertial.format(m=1.0)}</link>'
        '<joint name="f" type="fixed"><parent link="base"/><child link="trunk"/></joint>'
        '<joint name="g" type="fixed"><parent link="trunk"/><child link="frame"/></joint>'
        '<joint name="j" type="revolute"><parent link="trunk"/><child link="leg"/>'
        '<axis xyz="0 1 0"/><limit effort="1" lower="-1" upper="1" velocity="1"/></joint></robot>')
    spec = types.SimpleNamespace(name="bare", urdf=str(path), strip_root=False,
                                 primitive_collisions=False, collision_primitives={},
                                 foot_radius=0.02)
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(prepared_urdf(spec), physicsClientId=c)
        masses = [pb.getDynamicsInfo(body, j, physicsClientId=c)[0]
                  for j in range(-1, pb.getNumJoints(body, physicsClientId=c))]
        inertia = pb.getDynamicsInfo(body, -1, physicsClientId=c)[2]
    finally:
        pb.disconnect(c)
    assert sum(masses) == pytest.approx(4.0, abs=1e-5)
    assert max(inertia) < 1e-5



@pytest.mark.parametrize("bare", ["<link name='base'><collision/></link>",
                                  "<link name='frame'/>", '<link type="x" name="frame"/>'])
def test_a_link_without_inertial_is_found_however_its_attributes_are_written(tmp_path, bare):
    """A link without ``<inertial>`` written with single quotes (valid XML) or another attribute
    before its name was not found, and kept PyBullet's 1 kg."""
    import types

    from latentune.robots.urdf import NO_INERTIAL
    path = tmp_path / "quoted.urdf"
    path.write_text(f'<robot name="r">{bare}<link name="leg"><inertial/></link></robot>')
    spec = types.SimpleNamespace(name="quoted", urdf=str(path), strip_root=False,
                                 primitive_collisions=False, collision_primitives={},
                                 foot_radius=0.02)
    out = Path(prepared_urdf(spec)).read_text()
    assert out.count(NO_INERTIAL) == 1 and out.count("<inertial") == 2
