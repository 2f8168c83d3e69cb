"""The MuJoCo world: the same robot, ground and interface as the PyBullet one, another engine.

:class:`MujocoWorld` implements :class:`~latentune.sim.world.SimWorld`. The robot is the
spec's prepared URDF (:func:`~latentune.robots.urdf.prepared_urdf`: a massless root stripped,
primitive collisions where the spec asks for them), with the reality's body perturbations
(:func:`~latentune.sim.reality.perturbed_urdf`), loaded by MuJoCo's URDF importer with
visual geoms discarded and fixed links kept as their own bodies (so the feet keep their names);
a link inertia MuJoCo refuses is corrected and logged (:func:`mujoco_inertia`), as is a moving
link without mass or inertia (negligible ones, :data:`MOVING_MASS`), and a link
without ``<inertial>`` is massless (MuJoCo's default would give it its collision shapes' mass).
It gets a free joint for the base, a torque actuator (motor, gear 1, no control limits) per
joint in the spec's order (a URDF joint outside the spec's, e.g. an arm's, is made fixed: its
link stays at the joint's zero position, as PyBullet's default motors hold it and the MPC's
model has it), gravity 9.81 m/s² and a 1 ms step; the ground is a plane or the
same Perlin hills as PyBullet (a MuJoCo heightfield of the same 100 × 100 heights, 0.05 m
apart). The robot's geoms collide with the ground only (PyBullet does not collide a robot with
itself either). Contacts use MuJoCo's soft model with a 0.005 s time constant and damping
ratio 1 (:data:`CONTACT_TIMECONST`; an A1 foot sinks ≈ 0.3 mm standing), a pyramidal friction
cone and the foot–ground coefficient of the reality (nominal 1.0, as PyBullet's product of
1.0 × 1.0); the contact models differ between the engines, and that is the point: it is the
kind of gap a real robot has.

Units SI. The state is that of the base link: ``RobotState.pos``/``vel`` are the base's centre
of mass position and velocity in the world frame (as PyBullet's), ``quat`` the base link's
orientation (x, y, z, w), so ``R`` is the trunk link rotation directly.
"""
from __future__ import annotations

import logging
import math
import os
import sys
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Collection
from pathlib import Path

import numpy as np

from latentune.constants import G
from latentune.errors import UsageError
from latentune.robots import RobotSpec
from latentune.robots.urdf import INERTIA_KEYS, NO_INERTIAL_MASS, NO_INERTIAL_MOMENT, read_urdf
from latentune.sim.reality import Reality, perturbed_urdf
from latentune.sim.state import RobotState
from latentune.sim.world import HILLS_CELL, HILLS_CELLS, WorldBase

logger = logging.getLogger(__name__)

__all__ = ["MujocoWorld", "require_mujoco", "contact_solref", "mujoco_urdf_text", "mujoco_inertia",
           "MAX_RESTITUTION"]

_ROBOT_CONTYPE, _GROUND_CONTYPE = 2, 1   # robot geoms touch the ground, not each other
CONTACT_TIMECONST = 0.005
"""Time constant of the contacts [s] (MuJoCo's default 0.02 lets an A1 foot sink 3 mm standing
and 14 mm at a hard touchdown, deep enough for the shank to touch the ground; ≥ 2 steps)."""
MIN_DAMPING_RATIO = 0.05
"""Least contact damping ratio (restitution ≤ 0.85): below it MuJoCo's contacts blow up."""
MAX_RESTITUTION = math.exp(-math.pi * MIN_DAMPING_RATIO / math.sqrt(1.0 - MIN_DAMPING_RATIO ** 2))
"""The largest restitution the MuJoCo world takes (that of :data:`MIN_DAMPING_RATIO`)."""


GROUND_RGBA = (0.62, 0.66, 0.7, 1.0)
"""The colour of the ground in MuJoCo's frames (RGBA): a light grey against the background."""


def contact_solref(restitution: float) -> tuple[float, float]:
    """MuJoCo ``solref`` (time constant [s], damping ratio) of the contacts for a restitution
    coefficient e: ratio 1 and :data:`CONTACT_TIMECONST` for e = 0; otherwise the ratio ζ of
    a mass-spring-damper that rebounds with e = exp(−πζ/√(1−ζ²)), at least
    :data:`MIN_DAMPING_RATIO` (so e ≤ 0.85), and a 0.01 s time constant (stiffer, lightly
    damped contacts blow up at a 1 ms step)."""
    if restitution <= 0:
        return CONTACT_TIMECONST, 1.0
    le = math.log(restitution) if restitution < 1 else 0.0
    return 0.01, max(-le / math.sqrt(math.pi ** 2 + le ** 2), MIN_DAMPING_RATIO)


def headless_gl() -> str | None:
    """The ``MUJOCO_GL`` backend to draw with when none is set on a Linux machine without a
    display (no ``DISPLAY`` nor ``WAYLAND_DISPLAY``), where mujoco's default, GLFW, cannot
    open a window: ``PYOPENGL_PLATFORM``'s when it names egl or osmesa, else egl where libEGL
    is found, else osmesa where libOSMesa is; None otherwise (a ``MUJOCO_GL`` is set, a display
    is there, or neither library is found: rendering then says which ``MUJOCO_GL`` to set)."""
    env = os.environ
    if env.get("MUJOCO_GL") or not sys.platform.startswith("linux") \
            or env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"):
        return None
    platform = env.get("PYOPENGL_PLATFORM", "").strip().lower()
    if platform in ("egl", "osmesa"):
        return platform
    import ctypes.util

    return next((gl for gl, lib in (("egl", "EGL"), ("osmesa", "OSMesa"))
                 if ctypes.util.find_library(lib)), None)


def require_mujoco():
    """The ``mujoco`` module (its warnings sent to this module's logger, not to a MUJOCO_LOG.TXT).

    Before mujoco's first import, which loads the OpenGL backend ``MUJOCO_GL`` names, an unset
    ``MUJOCO_GL`` on a machine without a display is set to a headless backend
    (:func:`headless_gl`), so that ``--gif`` draws there.

    Raises:
        UsageError: mujoco is not installed, or its import fails (it loads the OpenGL backend
            ``MUJOCO_GL`` names: ``osmesa`` without libOSMesa, an unknown name).
    """
    gl = None if "mujoco" in sys.modules else headless_gl()
    if gl is not None:
        os.environ["MUJOCO_GL"] = gl
        logger.info("no display and MUJOCO_GL unset: MuJoCo draws with MUJOCO_GL=%s", gl)
    try:
        import mujoco
    except ImportError:
        raise UsageError("engine 'mujoco' needs the mujoco package (pip install mujoco==4.0.0)") from None
    except Exception as exc:  # noqa: BLE001 - mujoco's import sets up MUJOCO_GL's backend
        gl = os.environ.get("MUJOCO_GL")
        why = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        raise UsageError(f"mujoco cannot be imported ({why})"
                         + (f"; MUJOCO_GL={gl} is not usable here: unset it or set it to egl"
                            if gl else "")) from None
    if mujoco.get_mju_user_warning() is None:  # not MuJoCo's default: a MUJOCO_LOG.TXT in the cwd
        mujoco.set_mju_user_warning(_warn)
    return mujoco


def _warn(msg: str) -> None:
    """MuJoCo's warnings (e.g. an unstable simulation, which MuJoCo resets) as a WARNING of this
    module's logger (instead of MuJoCo's default, a MUJOCO_LOG.TXT in the working directory)."""
    logger.warning("MuJoCo warning: %s", msg.strip())


INERTIA_EPS = 1e-14
"""Least principal moment [kg·m²] MuJoCo takes of an inertia with products of inertia (its
``mjEPS``: below it, 'inertia must have positive eigenvalues')."""
INERTIA_FLOOR = 1e-6
"""Least principal moment of a corrected inertia, as a fraction of its largest."""
INERTIA_TINY = 1e-4
"""A correction that changes an inertia by at most this fraction (Frobenius norm) is logged at
INFO (rounding); a larger one is a WARNING that says how much."""

_inertia_said: set[tuple[str, str, str, str]] = set()
"""(URDF file, robot, link, ``"inertia"`` or ``"moving"``) whose correction was logged."""


def _sym(v: tuple[float, ...]) -> np.ndarray:
    """The 3 × 3 inertia matrix of a URDF ``<inertia>`` (ixx, ixy, ixz, iyy, iyz, izz)."""
    return np.array([[v[0], v[1], v[2]], [v[1], v[3], v[4]], [v[2], v[4], v[5]]])


def _six(m: np.ndarray) -> tuple[float, ...]:
    """The six values (ixx, ixy, ixz, iyy, iyz, izz) of a 3 × 3 inertia matrix: :func:`_sym`'s
    inverse."""
    return tuple(float(x) for x in (m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]))


def _inertia_values(el: ET.Element | None) -> tuple[float, ...]:
    """The six values of a URDF ``<inertia>`` element (an absent attribute or element: 0)."""
    return tuple(float(el.get(k, "0")) for k in INERTIA_KEYS) if el is not None else (0.0,) * 6


def _set_inertia(el: ET.Element, values: tuple[float, ...]) -> None:
    """Write the six values (ixx, ixy, ixz, iyy, iyz, izz) into a URDF ``<inertia>``."""
    for k, v in zip(INERTIA_KEYS, values):
        el.set(k, repr(v))


def mujoco_inertia(values: tuple[float, ...]) -> tuple[tuple[float, ...], str] | None:
    """The inertia MuJoCo can take for a URDF ``<inertia>`` (ixx, ixy, ixz, iyy, iyz, izz
    [kg·m²]) it refuses, and why (e.g. ``"not positive definite, A + B < C"``), or None when
    it takes it as written.

    MuJoCo refuses a full inertia (products of inertia not all zero) with a principal moment
    below :data:`INERTIA_EPS`, and principal moments A, B, C with A + B < C (its compiler
    option ``balanceinertia`` sets such moments to their mean). The correction: principal
    moments raised to :data:`INERTIA_FLOOR` × the largest (where one is below
    :data:`INERTIA_EPS` or negative), then, if A + B < C, A and B raised by a fraction
    2 × :data:`INERTIA_TINY`² where C exceeds A + B by at most :data:`INERTIA_TINY`² of it
    (rounding), else all three set to their mean as ``balanceinertia`` does; the principal
    axes are kept. An all-zero inertia (a massless or static link) is left as written.
    """
    full = _sym(values)
    if not full.any():
        return None
    lam, axes = np.linalg.eigh(full)         # ascending
    products = bool(values[1] or values[2] or values[4])
    why = []
    if lam[0] < 0 or (products and lam[0] < INERTIA_EPS):
        why.append("not positive definite")
        lam = np.maximum(lam, INERTIA_FLOOR * max(lam[2], INERTIA_EPS))
    if lam[0] + lam[1] < lam[2]:
        why.append("A + B < C")
        nudged = lam * [1 + 2 * INERTIA_TINY ** 2, 1 + 2 * INERTIA_TINY ** 2, 1.0]
        if lam[2] - lam[0] - lam[1] <= INERTIA_TINY ** 2 * lam[2] and nudged[0] + nudged[1] >= nudged[2]:
            lam = nudged                      # off by rounding: A and B raised as little
        else:
            lam = np.full(3, lam.mean())      # what balanceinertia does
    if not why:
        return None
    if lam[0] == lam[2]:                      # balanced: the same about every axis
        new = (float(lam[0]), 0.0, 0.0, float(lam[0]), 0.0, float(lam[0]))
    else:
        new = _six(axes @ np.diag(lam) @ axes.T)
    return new, ", ".join(why)


def _correct_inertias(robot: ET.Element, name: str, where_from: str) -> None:
    """Replace in place each ``<inertia>`` MuJoCo refuses by :func:`mujoco_inertia`'s, logged
    once per URDF file ``where_from``, robot ``name`` and link (two robots of one name are
    two): INFO for a change within :data:`INERTIA_TINY` of the link's inertia, or within
    :data:`INERTIA_TINY` of the robot's largest link inertia (a placeholder link of negligible
    mass, as example-robot-data's feet of 1e-6 kg: no change the motion can show), else a
    WARNING with the principal moments before and after and the relative change."""
    scale = max((float(np.linalg.norm(_sym(_inertia_values(el)))) for el in robot.iter("inertia")),
                default=0.0)
    for link in robot.iter("link"):
        el = link.find("inertial/inertia")
        if el is None:
            continue
        old = _inertia_values(el)
        fixed = mujoco_inertia(old)
        if fixed is None:
            continue
        new, why = fixed
        _set_inertia(el, new)
        said = (where_from, name, link.get("name", ""), "inertia")
        if said in _inertia_said:
            continue
        _inertia_said.add(said)
        moved = float(np.linalg.norm(_sym(new) - _sym(old)))
        change = moved / float(np.linalg.norm(_sym(old)))
        mass = link.find("inertial/mass")
        where = (f"robot {name!r}, link {said[2]!r}"
                 + (f" ({float(mass.get('value', 'nan')):g} kg)" if mass is not None else ""))
        if change <= INERTIA_TINY:
            logger.info("%s: MuJoCo refuses its inertia (%s by rounding) and gets it corrected "
                        "(changed by %.1g %%)", where, why, 100 * change)
        elif moved <= INERTIA_TINY * scale:
            logger.info("%s: MuJoCo refuses its inertia (%s) and gets it corrected by %.3g "
                        "kg·m², negligible against the robot's largest link inertia (%.3g "
                        "kg·m²)", where, why, moved, scale)
        else:
            before = ", ".join(f"{x:.3g}" for x in np.linalg.eigvalsh(_sym(old)))
            after = ", ".join(f"{x:.3g}" for x in np.linalg.eigvalsh(_sym(new)))
            logger.warning("%s: MuJoCo refuses its inertia (principal moments %s kg·m²: %s) "
                           "and gets %s instead (changed by %.3g %%)", where, before, why, after,
                           100 * change)


MOVING_MIN_VALUE = 1e-15
"""Least mass [kg] and principal moment [kg·m²] MuJoCo takes of a moving body with the bodies
fixed to it (its ``mjMINVAL``: below it, 'mass and inertia of moving bodies must be larger than
mjMINVAL')."""
MOVING_MASS, MOVING_INERTIA = NO_INERTIAL_MASS, NO_INERTIAL_MOMENT
"""The mass [kg] and the moment about each axis [kg·m²] a moving link without them gets for
MuJoCo: negligible, the prepared URDF's for a link without ``<inertial>``
(:data:`~latentune.robots.urdf.NO_INERTIAL`)."""


def _bound_moving_links(robot: ET.Element, name: str, where_from: str) -> None:
    """Give each moving link (the root, or the child of a joint that is not fixed) whose mass or
    smallest principal moment, with those of the links fixed to it, is below
    :data:`MOVING_MIN_VALUE` the missing :data:`MOVING_MASS` or :data:`MOVING_INERTIA` (added
    to each principal moment), in place; a WARNING once per URDF file ``where_from``, robot
    ``name`` and link."""
    links = {link.get("name", ""): link for link in robot.findall("link")}
    fixed: dict[str, list[str]] = {}
    joint_type: dict[str, str] = {}       # link -> type of the joint it is the child of
    for j in robot.findall("joint"):
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            continue
        joint_type[c.get("link", "")] = j.get("type", "")
        if j.get("type") == "fixed":
            fixed.setdefault(p.get("link", ""), []).append(c.get("link", ""))

    def mass_inertia(link: ET.Element) -> tuple[float, np.ndarray]:
        mass, inertia = link.find("inertial/mass"), link.find("inertial/inertia")
        m = float(mass.get("value", "0")) if mass is not None else 0.0
        return m, _sym(_inertia_values(inertia))

    for lname, link in links.items():
        if joint_type.get(lname) == "fixed":
            continue
        group, todo = [], [lname]
        while todo:
            n = todo.pop()
            if n in links:
                group.append(mass_inertia(links[n]))
            todo.extend(fixed.get(n, []))
        light = sum(m for m, _ in group) < MOVING_MIN_VALUE
        flat = sum(float(np.linalg.eigvalsh(i)[0]) for _, i in group) < MOVING_MIN_VALUE
        if not (light or flat):
            continue
        m, inertia = mass_inertia(link)
        inertial = link.find("inertial")
        if inertial is None:
            inertial = ET.SubElement(link, "inertial")
        mel = inertial.find("mass")
        if mel is None:
            mel = ET.SubElement(inertial, "mass")
        iel = inertial.find("inertia")
        if iel is None:
            iel = ET.SubElement(inertial, "inertia")
        new_m = max(m, MOVING_MASS) if light else m
        new_i = inertia + np.eye(3) * max(MOVING_INERTIA - float(np.linalg.eigvalsh(inertia)[0]), 0.0) \
            if flat else inertia
        mel.set("value", repr(new_m))
        _set_inertia(iel, _six(new_i))
        said = (where_from, name, lname, "moving")   # said apart from an inertia correction
        if said in _inertia_said:
            continue
        _inertia_said.add(said)
        moments = ", ".join(f"{x:.3g}" for x in np.linalg.eigvalsh(inertia))
        after = ", ".join(f"{x:.3g}" for x in np.linalg.eigvalsh(new_i))
        logger.warning("robot %r, link %r: MuJoCo refuses a moving link without %s (%g kg, "
                       "principal moments %s kg·m², nor any from the links fixed to it) and gets %g kg "
                       "and %s kg·m² instead", name, lname,
                       "mass or inertia" if light and flat else "mass" if light else "inertia",
                       m, moments, new_m, after)


def mujoco_urdf_text(urdf: str, name: str | None = None,
                     driven: Collection[str] | None = None) -> str:
    """The URDF text MuJoCo's importer loads: the file with a ``<mujoco><compiler>`` element
    (mesh directory = the URDF's, visual geoms discarded, static bodies not fused, inertias
    balanced, a link without ``<inertial>`` massless as the URDF means it, not given its collision
    shapes' mass, angles in radians), and the inertias MuJoCo refuses corrected
    (:func:`mujoco_inertia`; a moving link without mass or inertia given negligible ones,
    :func:`_bound_moving_links`; each correction logged with the robot ``name``, default the
    URDF's ``<robot name>``). With ``driven`` (the spec's joint names), every other joint is
    made fixed: its link stays at the joint's zero position, as PyBullet's default motors hold
    it and the MPC's model has it (MuJoCo would let an arm's joints swing free)."""
    src = Path(urdf)
    robot = ET.fromstring(src.read_text())
    if driven is not None:
        for j in robot.findall("joint"):
            if j.get("type") != "fixed" and j.get("name") not in driven:
                j.set("type", "fixed")
    name = robot.get("name", "") if name is None else name
    where_from = str(src.resolve())
    _correct_inertias(robot, name, where_from)
    _bound_moving_links(robot, name, where_from)
    for el in robot.findall("mujoco"):
        robot.remove(el)
    ext = ET.Element("mujoco")
    ET.SubElement(ext, "compiler", meshdir=str(src.parent.resolve()), discardvisual="true",
                  fusestatic="false", balanceinertia="true", inertiafromgeom="false",
                  angle="radian")
    robot.insert(0, ext)
    for vis in list(robot.iter("link")):
        for v in vis.findall("visual"):
            vis.remove(v)
    return ET.tostring(robot, encoding="unicode")


class MujocoWorld(WorldBase):
    """A MuJoCo model and data with ground and robot, reset cheaply between rollouts
    (implements :class:`~latentune.sim.world.SimWorld`; see the module docstring).

    Args:
        spec: the robot.
        terrain: ``"flat"`` or ``"hills"`` (the PyBullet world's heights).
        seed: terrain seed, and the seed of the reality's noise and pushes.
        dt: physics step [s].
        reality: a :class:`~latentune.sim.reality.Reality` (None: nominal). In MuJoCo: masses,
            inertias and the payload through the URDF; friction (every geom's sliding
            coefficient, MuJoCo takes the larger of the pair), restitution (the contacts'
            ``solref``, :func:`contact_solref`), joint damping (``dof_damping``) and joint
            friction (``dof_frictionloss``, time constant 0.005 s) in the model; latency,
            torque scale and limits in :meth:`apply`; sensor noise in :meth:`state`; pushes
            through ``xfrc_applied`` on the base in :meth:`step`.

    Raises:
        UsageError: mujoco is not installed, or cannot load the robot's URDF.
    """

    engine = "mujoco"

    def __init__(self, spec: RobotSpec, terrain: str = "flat", seed: int = 0, dt: float = 0.001,
                 reality: Reality | None = None):
        self.mj = require_mujoco()
        self._data = None
        self._pushed = False
        self._init_common(spec, terrain, seed, dt, reality)
        self._build()

    def _build(self) -> None:
        mujoco, spec, real = self.mj, self.spec, self.reality
        urdf = perturbed_urdf(self.model.urdf, real)
        try:
            ms = mujoco.MjSpec.from_string(mujoco_urdf_text(urdf, spec.name, spec.joint_names))
        except ValueError as exc:
            raise UsageError(f"MuJoCo cannot load the URDF of {spec.name} ({urdf}): "
                             f"{str(exc).splitlines()[0]}") from None
        ms.option.timestep = self.dt
        ms.option.gravity = [0.0, 0.0, -G]
        root = read_urdf(urdf).root
        base = ms.body(root)
        base.add_freejoint()
        mu = real.foot_friction
        timeconst, ratio = contact_solref(real.restitution)
        for g in ms.geoms:
            g.contype, g.conaffinity = _ROBOT_CONTYPE, _GROUND_CONTYPE
            g.friction = [mu, 0.005, 0.0001]
            g.solref = [timeconst, ratio]
        if self.heights is None:
            ground = ms.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
        else:
            n = HILLS_CELLS
            half = 0.5 * (n - 1) * HILLS_CELL
            hf = ms.add_hfield(name="hills", nrow=n, ncol=n,
                               size=[half, half, max(self.ground_z, 1e-6), 0.1])
            # row r runs along y, column c along x: data[r * n + c] = heights[c, r]
            hf.userdata = self.heights.T.reshape(-1).tolist()
            ground = ms.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="hills")
        ground.name = "ground"
        # what a GIF sees, nothing the physics reads: a lighter ground than the background and
        # a light from above (MuJoCo's dim headlight alone drew a dark robot on a dark floor)
        ground.rgba = GROUND_RGBA
        sun = ms.worldbody.add_light(pos=[0.0, 0.0, 5.0], dir=[0.0, 0.0, -1.0],
                                     diffuse=[0.7, 0.7, 0.7], specular=[0.2, 0.2, 0.2])
        sun.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
        ms.visual.headlight.ambient = [0.3, 0.3, 0.3]
        ground.contype, ground.conaffinity = _GROUND_CONTYPE, _ROBOT_CONTYPE
        ground.friction = [mu, 0.005, 0.0001]
        ground.solref = [timeconst, ratio]
        for name in spec.joint_names:
            j = ms.joint(name)
            if j is None:
                raise UsageError(f"MuJoCo model of {spec.name}: no joint {name!r}")
            j.damping = [real.joint_damping, 0.0, 0.0]
            j.frictionloss = real.joint_friction
            j.solref_friction = [CONTACT_TIMECONST, 1.0]  # the default 0.02 s lets a joint creep
            act = ms.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_motor()
            act.gear = [1.0, 0, 0, 0, 0, 0]
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        try:
            m = ms.compile()
        except ValueError as exc:
            raise UsageError(f"MuJoCo cannot compile the model of {spec.name} ({urdf}): "
                             f"{str(exc).splitlines()[0]}") from None
        d = mujoco.MjData(m)
        self.mjmodel, self._data = m, d
        obj = mujoco.mjtObj
        self.base_id = mujoco.mj_name2id(m, obj.mjOBJ_BODY, root)
        self.ground_geom = mujoco.mj_name2id(m, obj.mjOBJ_GEOM, "ground")
        jids = [mujoco.mj_name2id(m, obj.mjOBJ_JOINT, n) for n in spec.joint_names]
        self.qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self.dadr = np.array([m.jnt_dofadr[j] for j in jids])
        self.foot_bodies = []
        for f in spec.foot_links:
            b = mujoco.mj_name2id(m, obj.mjOBJ_BODY, f)
            if b < 0:
                raise UsageError(f"MuJoCo model of {spec.name}: no foot body {f!r}")
            self.foot_bodies.append(b)
        self.body_names = {b: mujoco.mj_id2name(m, obj.mjOBJ_BODY, b) for b in range(m.nbody)}
        self.base_com_local = m.body_ipos[self.base_id].copy()
        z0 = spec.nominal_height + self.ground_z + 0.01
        d.qpos[:7] = [self.start_x, 0.0, z0, 1.0, 0.0, 0.0, 0.0]
        d.qpos[self.qadr] = spec.nominal_q
        mujoco.mj_forward(m, d)
        w = mujoco.mjtWarning
        self._bad_kinds = tuple(int(k) for k in (w.mjWARN_BADQACC, w.mjWARN_BADQVEL,
                                                 w.mjWARN_BADQPOS, w.mjWARN_BADCTRL))
        self._bad, self._blown = self._bad_count(), False
        self._settle()
        self._kind = mujoco.mjtState.mjSTATE_INTEGRATION
        self._saved = np.empty(mujoco.mj_stateSize(m, self._kind))
        mujoco.mj_getState(m, d, self._saved, self._kind)

    # ------------------------------------------------------------------ engine hooks
    def _zero_base_velocity(self) -> None:
        self._data.qvel[:6] = 0.0
        self.mj.mj_forward(self.mjmodel, self._data)

    def _restore(self) -> None:
        self.mj.mj_setState(self.mjmodel, self._data, self._saved, self._kind)
        self._data.xfrc_applied[:] = 0.0
        self.mj.mj_forward(self.mjmodel, self._data)
        self._bad, self._blown = self._bad_count(), False

    def _bad_count(self) -> int:
        """How often MuJoCo found a non-finite or huge qacc, qvel or qpos (and reset the data)
        or control (and zeroed it)."""
        return sum(self._data.warning[k].number for k in self._bad_kinds)

    def _drive(self, tau: np.ndarray) -> None:
        self._data.ctrl[:] = tau

    def _push(self, f: np.ndarray) -> None:
        self._data.xfrc_applied[self.base_id, :3] = f
        self._pushed = True

    def _raw_step(self) -> None:
        self.mj.mj_step(self.mjmodel, self._data)
        if self._bad_count() != self._bad:
            self._blown = True  # MuJoCo reset the state after a blow-up: report it as non-finite
        if self._pushed:
            self._data.xfrc_applied[self.base_id, :3] = 0.0
            self._pushed = False

    # ------------------------------------------------------------------ interface
    def true_state(self) -> RobotState:
        """The exact state: base centre of mass position/velocity, base link orientation,
        world angular velocity, joint angles and velocities (from ``qpos``/``qvel``, so current
        after ``mj_step``)."""
        d = self._data
        qp, qv = d.qpos, d.qvel
        w, x, y, z = qp[3:7]
        quat = np.array([x, y, z, w])
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        r = R @ self.base_com_local
        omega = R @ qv[3:6]                  # MuJoCo: free-joint angular velocity, body frame
        pos = qp[0:3] + r
        vel = qv[0:3] + np.cross(omega, r)   # linear velocity of the body origin, world frame
        finite = math.isfinite(pos.sum() + vel.sum()) and not self._blown
        st = RobotState(pos, quat, vel, omega, qp[self.qadr].copy(), qv[self.dadr].copy(),
                        float(R[2, 2]), finite)
        st._R = R
        return st

    def _ground_contacts(self) -> list[int]:
        """Bodies in contact with the ground (from the last step's collision detection)."""
        d, m, g = self._data, self.mjmodel, self.ground_geom
        out = []
        for k in range(d.ncon):
            c = d.contact[k]
            if c.geom1 == g:
                out.append(int(m.geom_bodyid[c.geom2]))
            elif c.geom2 == g:
                out.append(int(m.geom_bodyid[c.geom1]))
        return out

    def body_ground_contact(self) -> str | None:
        """Name of the first body other than the feet (the trunk included) that touches the
        ground, or None."""
        feet = set(self.foot_bodies)
        b = next((b for b in self._ground_contacts() if b not in feet), None)
        return None if b is None else self.body_names.get(b, f"#{b}")

    def foot_contacts(self) -> np.ndarray:
        """(4,) bool: which feet touch the ground."""
        bodies = set(self._ground_contacts())
        return np.array([f in bodies for f in self.foot_bodies])

    def foot_positions(self) -> np.ndarray:
        """(4, 3) world positions of the foot bodies' frames [m] (true, no noise; the
        kinematics are recomputed for the current ``qpos``)."""
        self.mj.mj_kinematics(self.mjmodel, self._data)
        return self._data.xpos[self.foot_bodies].copy()

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame from a camera following the robot (needs an OpenGL
        context, e.g. ``MUJOCO_GL=egl`` or ``osmesa``, which :func:`require_mujoco` sets when
        there is no display; the collision geoms are drawn). A context that cannot be made is a
        UsageError naming the ``MUJOCO_GL`` in use, the one to try and the PyBullet engine, as
        the reader sets it (:func:`latentune.wording.option`)."""
        mujoco = self.mj
        try:
            if getattr(self, "_renderer", None) is None:
                with warnings.catch_warnings():     # GLFW's, before the error below says it all
                    warnings.simplefilter("ignore")
                    self._renderer = mujoco.Renderer(self.mjmodel, height, width)
            cam = mujoco.MjvCamera()
            cam.lookat[:] = self._data.qpos[:3]
            cam.distance = 1.0 + 1.5 * self.spec.nominal_height
            cam.azimuth, cam.elevation = 140.0, -25.0
            self._renderer.update_scene(self._data, cam)
            return self._renderer.render()
        except Exception as exc:  # no OpenGL context on this machine
            from latentune.wording import option

            gl = os.environ.get("MUJOCO_GL", "").strip().lower()
            other = {"egl": "osmesa", "osmesa": "egl"}.get(gl, "egl (or osmesa)")
            why = str(exc).splitlines()[0] if str(exc) else exc
            raise UsageError(f"MuJoCo cannot render here{f' with MUJOCO_GL={gl}' if gl else ''} "
                             f"({why}); set MUJOCO_GL={other}, or use "
                             f"{option('engine', 'pybullet')}") from None

    def close(self) -> None:
        r = getattr(self, "_renderer", None)
        if r is not None:
            try:
                r.close()
            except Exception as exc:  # noqa: BLE001 - best effort: the renderer's GL context
                logger.debug("closing the MuJoCo renderer failed: %s", exc)
            self._renderer = None
        self._data = None
