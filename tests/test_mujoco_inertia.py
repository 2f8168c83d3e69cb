"""Inertias MuJoCo rejects (not positive definite, or against the triangle inequality) are
corrected in the URDF MuJoCo loads, with a log line per link; valid ones are left alone."""
from __future__ import annotations

import importlib.util
import logging
import xml.etree.ElementTree as ET

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("mujoco") is None, reason="needs mujoco")

from latentune.sim.mujoco_world import mujoco_urdf_text  # noqa: E402

_LINK = """<link name="{name}"><inertial><origin xyz="0 0 0"/><mass value="{mass}"/>
  <inertia ixx="{i[0]}" ixy="{i[1]}" ixz="{i[2]}" iyy="{i[3]}" iyz="{i[4]}" izz="{i[5]}"/>
  </inertial><collision><geometry><sphere radius="0.05"/></geometry></collision></link>"""


def _urdf(tmp_path, foot_inertia, robot="tiny", foot_mass=1e-6):
    """A two-link robot: a base and a 'foot' on a revolute joint with the given inertia."""
    text = (f'<robot name="{robot}">'
            + _LINK.format(name="base", mass=2.0, i=(0.02, 0, 0, 0.03, 0, 0.04))
            + _LINK.format(name="foot", mass=foot_mass, i=foot_inertia)
            + '<joint name="j" type="revolute"><parent link="base"/><child link="foot"/>'
              '<axis xyz="0 1 0"/><origin xyz="0 0 -0.2"/>'
              '<limit effort="10" lower="-1" upper="1" velocity="10"/></joint></robot>')
    path = tmp_path / f"{robot}.urdf"
    path.write_text(text)
    return str(path)


def _compile(text: str):
    import mujoco
    return mujoco.MjSpec.from_string(text).compile()


def _inertia(text: str, link: str) -> dict[str, float]:
    el = ET.fromstring(text).find(f"link[@name='{link}']/inertial/inertia")
    return {k: float(v) for k, v in el.attrib.items()}


def test_a_rank_one_inertia_is_corrected_and_said_once_per_link(tmp_path, caplog):
    """example-robot-data's HyQ, ANYmal B and Go1 carry 1e-6 in all six entries: eigenvalues
    0, 0, 3e-6, which MuJoCo refuses ('inertia must have positive eigenvalues')."""
    import mujoco
    urdf = _urdf(tmp_path, (1e-6,) * 6, robot="rank_one")
    with pytest.raises(ValueError, match="positive eigenvalues"):
        mujoco.MjSpec.from_string(open(urdf).read()).compile()
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf)
        mujoco_urdf_text(urdf)
    m = _compile(text)
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "foot")
    assert m.body_inertia[foot] == pytest.approx([1e-6] * 3, rel=1e-5)  # balanced: the mean
    new = _inertia(text, "foot")
    assert new["ixy"] == new["ixz"] == new["iyz"] == 0.0
    lines = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert len(lines) == 1 and lines[0].levelname == "INFO"     # 1e-6 kg: a placeholder
    msg = lines[0].getMessage()
    assert "rank_one" in msg and "MuJoCo" in msg and "negligible against" in msg
    assert "'base'" not in caplog.text


def test_a_correction_the_motion_can_show_is_a_warning(tmp_path, caplog):
    """A link of real mass whose inertia MuJoCo refuses (rank one, 0.01 in all six entries:
    as large as the base's) is corrected with a WARNING giving the principal moments; the
    1e-6 kg placeholder feet of example-robot-data's HyQ were a WARNING per foot on every run
    for a change of 1e-6 kg·m² against a 0.05 kg·m² base, and are INFO (above)."""
    urdf = _urdf(tmp_path, (0.01,) * 6, robot="heavy_foot", foot_mass=1.0)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        _compile(mujoco_urdf_text(urdf))
    (rec,) = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert rec.levelname == "WARNING"
    assert "principal moments" in rec.getMessage() and "changed by" in rec.getMessage()


def test_a_triangle_violation_is_balanced_as_mujoco_would_and_logged(tmp_path, caplog):
    urdf = _urdf(tmp_path, (0.001, 0, 0, 0.001, 0, 0.0030000001), robot="triangle", foot_mass=0.1)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf)
    new = _inertia(text, "foot")
    assert new["ixx"] == new["iyy"] == new["izz"] == pytest.approx(0.0050000001 / 3)
    (rec,) = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert rec.levelname == "WARNING" and "A + B < C" in rec.getMessage()
    _compile(text)


def test_a_rounding_off_the_triangle_is_info_not_warning(tmp_path, caplog):
    urdf = _urdf(tmp_path, (0.001, 0, 0, 0.001, 0, 0.002 * (1 + 1e-12)), robot="rounding", foot_mass=0.1)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf)
    (rec,) = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert rec.levelname == "INFO"
    new = _inertia(text, "foot")
    assert (new["ixx"], new["iyy"], new["izz"]) == pytest.approx((0.001, 0.001, 0.002), rel=1e-7)
    import mujoco
    m = _compile(text)
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "foot")
    assert sorted(m.body_inertia[foot]) == pytest.approx([0.001, 0.001, 0.002], rel=1e-7)  # not averaged


def test_valid_inertias_are_left_as_written(tmp_path, caplog):
    urdf = _urdf(tmp_path, (0.001, 0.0002, -0.0001, 0.002, 0.0001, 0.0025), robot="valid", foot_mass=0.1)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf)
    assert _inertia(text, "foot") == {"ixx": 0.001, "ixy": 0.0002, "ixz": -0.0001, "iyy": 0.002,
                                      "iyz": 0.0001, "izz": 0.0025}
    assert not caplog.records
    _compile(text)


@pytest.mark.parametrize("robot", ["a1", "b1", "solo12"])
def test_the_built_in_robots_need_no_correction(robot, caplog):
    """Their MuJoCo models stay the URDFs' (the B1 and Go1 root with the bad inertia is stripped)."""
    from latentune.robots import get_robot, prepared_urdf
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        mujoco_urdf_text(prepared_urdf(get_robot(robot)))
    assert not caplog.records


def test_a_link_without_inertial_gets_no_mass_from_its_collision_shapes(tmp_path):
    """URDF: no ``<inertial>`` is a massless link (pinocchio's reading; ANYmal C's root). MuJoCo
    by default gave it its collision box's volume × 1000 kg/m³ (29 kg on ANYmal C's base)."""
    import mujoco
    path = tmp_path / "bare.urdf"
    path.write_text(
        '<robot name="bare"><link name="base"><collision><geometry><box size="0.5 0.2 0.2"/>'
        '</geometry></collision></link>'
        + _LINK.format(name="body", mass=3.0, i=(0.02, 0, 0, 0.03, 0, 0.04))
        + '<joint name="j" type="fixed"><parent link="base"/><child link="body"/></joint></robot>')
    m = _compile(mujoco_urdf_text(str(path)))
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
    assert m.body_mass[base] == 0.0
    assert m.body_subtreemass[0] == pytest.approx(3.0)


def test_the_correction_names_the_specs_robot_not_the_urdfs(tmp_path, caplog):
    """ANYmal B's and C's URDFs are both <robot name="anymal">: the line names the spec."""
    urdf = _urdf(tmp_path, (1e-6,) * 6, robot="anymal")
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        mujoco_urdf_text(urdf, "anymal_c")
    (rec,) = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert rec.getMessage().startswith("robot 'anymal_c', link 'foot'")


@pytest.mark.parametrize("mass, inertia", [(0.0, 0.0), (0.0, 0.001), (0.1, 0.0)])
def test_a_moving_link_without_mass_or_inertia_gets_a_negligible_one(tmp_path, caplog, mass, inertia):
    """MuJoCo refuses a moving body of zero mass or inertia ('mass and inertia of moving bodies
    must be larger than mjMINVAL'; PyBullet runs it): it gets the prepared URDF's negligible
    1e-6 kg / 1e-9 kg·m² where it lacks them, with one warning per link."""
    import mujoco
    urdf = _urdf(tmp_path, (inertia, 0, 0, inertia, 0, inertia), robot="zero", foot_mass=mass)
    with pytest.raises(ValueError, match="mjMINVAL"):
        mujoco.MjSpec.from_string(open(urdf).read()).compile()
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf, f"zero_{mass}_{inertia}")
        mujoco_urdf_text(urdf, f"zero_{mass}_{inertia}")
    m = _compile(text)
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "foot")
    assert m.body_mass[foot] == pytest.approx(mass or 1e-6)
    assert m.body_inertia[foot] == pytest.approx([inertia or 1e-9] * 3)
    (rec,) = [r for r in caplog.records if "'foot'" in r.getMessage()]
    assert rec.levelname == "WARNING" and "moving" in rec.getMessage()


def test_a_massless_link_welded_to_a_massive_one_is_left_alone(tmp_path, caplog):
    """MuJoCo counts the bodies fixed to a moving one with it: a massless link on a revolute
    joint carrying a massive link on a fixed joint compiles as written."""
    path = tmp_path / "welded.urdf"
    path.write_text(
        '<robot name="welded">' + _LINK.format(name="base", mass=2.0, i=(0.02, 0, 0, 0.03, 0, 0.04))
        + _LINK.format(name="hip", mass=0.0, i=(0,) * 6)
        + _LINK.format(name="thigh", mass=1.0, i=(0.01, 0, 0, 0.01, 0, 0.01))
        + '<joint name="j" type="revolute"><parent link="base"/><child link="hip"/>'
          '<axis xyz="0 1 0"/><limit effort="10" lower="-1" upper="1" velocity="10"/></joint>'
          '<joint name="f" type="fixed"><parent link="hip"/><child link="thigh"/></joint></robot>')
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(str(path))
    assert not caplog.records
    assert _inertia(text, "hip") == {k: 0.0 for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    _compile(text)


def test_two_robots_of_one_name_each_say_their_corrections(tmp_path, caplog):
    """The once-per-link line was keyed on (robot name, link): a second robot of the same name
    (another URDF) said nothing of its own corrections."""
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    first = _urdf(tmp_path / "a", (1e-6,) * 6, robot="same_name")
    second = _urdf(tmp_path / "b", (0.001, 0, 0, 0.001, 0, 0.0030000001), robot="same_name", foot_mass=0.1)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        for urdf in (first, second, first, second):
            mujoco_urdf_text(urdf)
    lines = [r.getMessage() for r in caplog.records if "'foot'" in r.getMessage()]
    assert len(lines) == 2 and "A + B < C" in lines[1]


def test_a_massless_link_with_a_refused_inertia_says_both_corrections(tmp_path, caplog):
    """A moving link whose inertia MuJoCo refuses and that has no mass gets two corrections,
    each logged: the inertia's log line once said it, and the mass it is given was silent."""
    urdf = _urdf(tmp_path, (0.01, 0, 0, 0.01, 0, 0.05), robot="massless_bad", foot_mass=0.0)
    with caplog.at_level(logging.INFO, logger="latentune.sim.mujoco_world"):
        text = mujoco_urdf_text(urdf)
    _compile(text)
    lines = [r.getMessage() for r in caplog.records if "'foot'" in r.getMessage()]
    assert len(lines) == 2, lines
    assert any("A + B < C" in m for m in lines)
    assert any("without mass" in m for m in lines)
