"""A starting robot spec for a quadruped URDF: :func:`init_spec`.

The legs are the four chains of three revolute joints (abduction about x, hip and knee about y
in the base frame) from the base to a leaf link; their order FR, FL, RR, RL comes from the hip
positions at q = 0 (front x > 0, right y < 0), or from the joint names (FR/RF/…, HR/RH = rear)
where the geometry does not decide. Each leg's foot is the leaf link below its knee farthest from
the knee. The stance ``nominal_q`` is a crouch: abduction 0, hip and knee chosen (planar
two-link inverse kinematics, within the URDF's joint limits when possible, knee behind the foot
otherwise) so that the foot is :data:`CROUCH` × the leg length below the hip flexion joint,
straight under it. Gains and gait timing scale with the robot (numbers chosen so that the rules
give A1's hand-tuned values on A1's URDF):

* ``kp = min(8 m, 4 τ_knee)`` [N·m/rad] (m: total mass [kg]), ``kd = (0.01, 0.02, 0.02) kp``;
* trot period ``0.6 √L`` [s] (L: leg length [m]), duty 0.6; jump 1.12 × that, duty 0.7; swing
  apex ``0.2 L``;
* ``torque_limits``: the URDF's ``<limit effort>``, or ``(0.3, 0.3, 0.45) m g L`` where it has
  none or one above 5 m g L (a placeholder);
* ``foot_radius``: the foot's collision sphere, else half the mean extent of its STL mesh, else
  0.05 L.
"""
from __future__ import annotations

import cmath
import json
import math
import os
import re
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from latentune.constants import G
from latentune.errors import RobotSpecError, RobotSpecWarning
from latentune.robots.check import CLEARANCE, check_spec, round_sig
from latentune.robots.inspection import (LEG_SIGNS, LEGS, PLACEHOLDER_EFFORT, joint_position,
                                         link_position, pin_model, placements, usable_collision)
from latentune.robots.spec import BUILTIN
from latentune.robots.urdf import ERD, UrdfTree, package_dir, read_urdf, resolve_mesh
from latentune.wording import option

CROUCH = 0.75
"""Hip-flexion-joint-to-foot distance at the stance, as a fraction of the leg length."""

_NAME_TAGS = {"FR": "FR", "RF": "FR", "FL": "FL", "LF": "FL",
              "RR": "RR", "HR": "RR", "RH": "RR", "BR": "RR",
              "RL": "RL", "HL": "RL", "LH": "RL", "BL": "RL"}


def _leg_from_name(name: str) -> str | None:
    """FR/FL/RR/RL from a joint name (``FR_hip_joint``, ``LF_HAA``, ``front_left_…``)."""
    low = name.lower()
    words = re.split(r"[^a-z]+", low)
    if ("front" in words or "rear" in words or "hind" in words or "back" in words) and \
            ("left" in words or "right" in words):
        return ("F" if "front" in words else "R") + ("L" if "left" in words else "R")
    for tok in re.split(r"[^A-Za-z]+", name):
        if tok.upper() in _NAME_TAGS and len(tok) == 2:
            return _NAME_TAGS[tok.upper()]
    return None


def _legs(tree: UrdfTree) -> list[tuple[list[str], list[str]]]:
    """The four (three joint names, leaf links below the knee) chains of the URDF."""
    revolute = ("revolute", "continuous")
    chains: dict[tuple[str, ...], list[str]] = {}
    for leaf in (n for n in tree.links if not tree.child_joints(n)):
        chain = tuple(j for j in tree.joints_above(leaf) if tree.joints[j].type in revolute)
        if chain:
            chains.setdefault(chain, []).append(leaf)
    # keep the maximal chains (a rotor hanging off the thigh gives a chain that is a prefix)
    maximal = {c: leaves for c, leaves in chains.items()
               if not any(len(o) > len(c) and o[:len(c)] == c for o in chains)}
    legs = [(list(c), leaves) for c, leaves in maximal.items() if len(c) == 3]
    if len(legs) > 4:  # extra 3-joint chains (an arm, a head): keep those with leg names
        named = [leg for leg in legs if _leg_from_name(leg[0][0])]
        legs = named if len(named) == 4 else legs
    if len(legs) != 4:
        found = ", ".join(f"{c[0]}…({len(c)} joints)" for c in maximal) or "none"
        raise RobotSpecError(f"URDF {tree.path}: init needs 4 legs of 3 revolute joints (abduction, "
                             f"hip, knee) from the base to a foot; found chains: {found}")
    return legs


def _stl_extent(path: Path) -> np.ndarray | None:
    """(3,) size of a binary or ASCII STL mesh's bounding box [mesh units], or None."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * n == len(data) and n > 0:
            rec = np.frombuffer(data[84:], dtype=np.dtype([("n", "<3f4"), ("v", "<9f4"), ("a", "<u2")]))
            v = rec["v"].reshape(-1, 3)
            return v.max(0) - v.min(0)
    vals = re.findall(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", data)
    if vals:
        v = np.array(vals, dtype=float)
        return v.max(0) - v.min(0)
    return None


def _foot_radius(tree: UrdfTree, foot: str, leg_length: float) -> tuple[float, str]:
    for tag, attrib in tree.links[foot].collisions:
        if tag == "sphere" and "radius" in attrib:
            return float(attrib["radius"]), "the foot's collision sphere"
    for tag, attrib in tree.links[foot].collisions:
        if tag == "mesh" and attrib.get("filename", "").lower().endswith(".stl"):
            mesh = resolve_mesh(attrib["filename"], tree.path)
            ext = _stl_extent(mesh) if mesh is not None else None
            if ext is not None:
                scale = [float(v) for v in attrib.get("scale", "1 1 1").split()] or [1.0]
                r = float(np.mean(ext * np.array(scale if len(scale) == 3 else scale * 3))) / 2
                if 0 < r < leg_length:
                    return round(r, 4), "half the mean extent of the foot's collision mesh"
    return round(0.05 * leg_length, 4), "0.05 × leg length (the foot has no sphere or STL collision)"


def _axis(model: Any, data: Any, joint: str) -> np.ndarray:
    """Rotation axis of a joint in the base frame (after forward kinematics)."""
    import pinocchio as pin

    jid = model.getJointId(joint)
    pin.computeJointJacobians(model, data, np.zeros(model.nq))
    J = pin.getJointJacobian(model, data, jid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return J[3:6, model.joints[jid].idx_v].copy()


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _crouch(p1: np.ndarray, p2: np.ndarray, pf: np.ndarray, s_hip: float, s_knee: float,
            lim_hip: tuple, lim_knee: tuple, ratio: float) -> tuple[float, float]:
    """Hip and knee angles putting the foot ``ratio`` × leg length straight below the hip
    flexion joint (planar, x-z; rotating by φ about +y multiplies x + iz by e^{-iφ})."""
    a = complex(p2[0] - p1[0], p2[2] - p1[2])
    b = complex(pf[0] - p2[0], pf[2] - p2[2])
    la, lb = abs(a), abs(b)
    d = ratio * (la + lb)
    target = complex(0.0, -d)
    c = max(-1.0, min(1.0, (d * d - la * la - lb * lb) / (2 * la * lb)))
    beta = cmath.phase(b) - cmath.phase(a)
    best = None
    for sign in (1.0, -1.0):
        gamma = beta - sign * math.acos(c)
        q_knee = _wrap(gamma) / s_knee
        w = a + cmath.exp(-1j * gamma) * b
        q_hip = _wrap(cmath.phase(w) - cmath.phase(target)) / s_hip
        within = all(lo is None or hi is None or lo >= hi or lo <= v <= hi
                     for v, (lo, hi) in ((q_hip, lim_hip), (q_knee, lim_knee)))
        behind = (cmath.exp(-1j * s_hip * q_hip) * a).real < 0
        score = (within, behind)
        if best is None or score > best[0]:
            best = (score, q_hip, q_knee)
    return best[1], best[2]


def _urdf_field(path: Path) -> str:
    """The YAML ``urdf`` value: ``{package, path}`` inside example-robot-data or pybullet_data."""
    for pkg in (ERD, "pybullet_data"):
        try:
            root = package_dir(pkg)
        except RobotSpecError:
            continue
        if path.is_relative_to(root):
            return f"{{package: {pkg}, path: {path.relative_to(root).as_posix()}}}"
    return json.dumps(str(path))  # a JSON string is a YAML string


def _str(v: str) -> str:
    """A YAML scalar for a name: as is when plain, else JSON-quoted."""
    return v if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", v) else json.dumps(v)


def _num(v: float, digits: int = 4) -> str:
    r = round(float(v), digits)
    return repr(0.0 if r == 0 else r)


def _list(vals, digits: int = 4) -> str:
    return "[" + ", ".join(_num(v, digits) for v in vals) + "]"


def _urdf_robot_name(urdf_name: str, path: Path) -> str:
    """The spec name from the URDF's ``<robot name>`` (without ``_description``; else the file
    stem), or the file stem when it extends that name (``solo12.urdf`` of ``<robot name="solo">``,
    as Solo8's ``solo.urdf`` is); a robot name that is a built-in robot's
    (:data:`~latentune.robots.spec.BUILTIN`) becomes the file stem when that is none, else
    ``my_<name>``, with a warning, and a file stem that extends the name and is a built-in
    robot's becomes ``my_<stem>``, with a warning."""
    def clean(s: str) -> str:
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", s)

    robot, stem = clean(urdf_name.removesuffix("_description")) or clean(path.stem), clean(path.stem)
    if robot not in BUILTIN:
        if not (stem != robot and stem.startswith(robot)):
            return robot
        if stem not in BUILTIN:
            return stem
        warnings.warn(f"the URDF file's name {stem!r} is the built-in robot's: the spec is named "
                      f"'my_{stem}' (give {option('name', 'NAME')} for another)", RobotSpecWarning,
                      stacklevel=3)
        return f"my_{stem}"
    other = stem if stem and stem not in BUILTIN else f"my_{robot}"
    warnings.warn(f"the URDF's robot name {robot!r} is the built-in robot's: the spec is named "
                  f"{other!r} (give {option('name', 'NAME')} for another)", RobotSpecWarning,
                  stacklevel=3)
    return other


def init_spec(urdf_path: str | os.PathLike, name: str | None = None) -> str:
    """YAML text of a starting spec for a quadruped URDF (see the module docstring).

    Args:
        urdf_path: the URDF file.
        name: the robot's name (default: the URDF's ``<robot name>`` without ``_description``,
            or the file stem when it extends that name, another when that is a built-in
            robot's, with a warning; a built-in robot's name
            given here is kept, with a warning).

    Returns:
        The spec as YAML with comments; it loads (:func:`~latentune.robots.spec.load_spec_file`)
        and is written for the legs, feet and stance found, so check the comments.

    Raises:
        RobotSpecError: an empty ``name``; the URDF cannot be read, or has no four 3-joint
            legs with the axes of a quadruped's abduction (x), hip (y) and knee (y) joints.
    """
    if name is not None and not str(name).strip():
        raise RobotSpecError(f"the robot name must not be empty, got {name!r} (leave it out for "
                             "the URDF's)")
    if not str(urdf_path).strip():
        raise RobotSpecError("the URDF path is empty: give the quadruped's .urdf file")
    if name is not None and name in BUILTIN:
        warnings.warn(f"{name!r} is the name of a built-in robot: runs and reports show this "
                      f"robot under the same name (choose another {option('name')} to tell them "
                      "apart)",
                      RobotSpecWarning, stacklevel=2)
    path = Path(urdf_path).expanduser().resolve()
    if path.is_dir():
        raise RobotSpecError(f"URDF {path}: is a directory, not a URDF file")
    tree = read_urdf(path)
    strip = tree.massless_root()
    model = pin_model(str(path), strip)
    _, d0 = placements(model, {})
    legs = _legs(tree)

    # ---- leg order: geometry (hip position at q = 0), else names
    notes: list[str] = []
    by_geom: dict[str, tuple[list[str], list[str]]] = {}
    for chain, leaves in legs:
        h = joint_position(model, d0, chain[0])
        tag = next((n for n, (sx, sy) in LEG_SIGNS.items() if sx * h[0] > 1e-6 and sy * h[1] > 1e-6), None)
        if tag is not None:
            by_geom.setdefault(tag, (chain, leaves))
    by_name = {_leg_from_name(c[0]): (c, lv) for c, lv in legs}
    if len(by_geom) == 4:
        order = by_geom
        clash = [n for n in LEGS if _leg_from_name(order[n][0][0]) not in (None, n)]
        if clash:
            notes.append(f"leg order from the hip positions; the joint names suggest another order "
                         f"for {', '.join(clash)}")
    elif set(by_name) == set(LEGS):
        order = by_name
        notes.append("leg order from the joint names (the hip positions at q = 0 do not decide it)")
    else:
        raise RobotSpecError(f"URDF {path}: cannot tell the legs FR, FL, RR, RL apart (hips at q = 0 "
                             "not one per quadrant of the base frame, names without FR/FL/RR/RL)")

    # ---- joints, feet, geometry per leg
    joint_names: list[str] = []
    feet: list[str] = []
    q_nom: list[float] = []
    lengths = []
    for leg in LEGS:
        chain, leaves = order[leg]
        p1, p2 = joint_position(model, d0, chain[1]), joint_position(model, d0, chain[2])
        foot = max(leaves, key=lambda f: float(np.linalg.norm(link_position(model, d0, f) - p2)))
        pf = link_position(model, d0, foot)
        if np.linalg.norm(pf - p2) < 0.2 * np.linalg.norm(p2 - p1):
            raise RobotSpecError(f"URDF {path}: leg {leg} has no foot link below its knee joint "
                                 f"{chain[2]} (the leaf {foot} is at the knee): add a fixed foot link")
        axes = [_axis(model, d0, j) for j in chain]
        for j, ax, i in zip(chain, axes, (0, 1, 1)):  # abduction about x, hip and knee about y
            if abs(ax[i]) < 0.9:
                axis = ", ".join(f"{v:+.2f}" for v in ax)
                raise RobotSpecError(f"URDF {path}: joint {j} turns about ({axis}) in the base frame; init "
                                     "expects abduction about x, hip and knee about y")
        lim = [(tree.joints[j].lower, tree.joints[j].upper) if tree.joints[j].type == "revolute"
               else (None, None) for j in chain]
        q_hip, q_knee = _crouch(p1, p2, pf, math.copysign(1, axes[1][1]), math.copysign(1, axes[2][1]),
                                lim[1], lim[2], CROUCH)
        joint_names += chain
        feet.append(foot)
        q_nom += [0.0, q_hip, q_knee]
        lengths.append(float(np.linalg.norm(p2 - p1) + np.linalg.norm(pf - p2)))
    L = float(np.mean(lengths))
    mass = tree.total_mass()
    radius, radius_src = _foot_radius(tree, feet[0], L)
    _, dn = placements(model, dict(zip(joint_names, q_nom)))
    height = radius - float(np.mean([link_position(model, dn, f)[2] for f in feet]))

    # ---- torque limits, gains, gaits
    scale = mass * G * L
    est = (0.3 * scale, 0.3 * scale, 0.45 * scale)
    torque, torque_src = [], "the URDF's <limit effort> (smallest of the four legs)"
    for r in range(3):
        eff = [tree.joints[joint_names[3 * k + r]].effort for k in range(4)]
        if all(e is not None and 0 < e <= PLACEHOLDER_EFFORT * scale for e in eff):
            torque.append(min(eff))
        else:
            torque.append(round_sig(est[r], 2))
            torque_src = ("ESTIMATES (0.3, 0.3, 0.45) m·g·leg length where the URDF has no usable "
                          "<limit effort>: give your actuators' limits")
    kp = round_sig(min(8.0 * mass, 4.0 * torque[2]), 2)
    kd = [round_sig(0.01 * kp, 2), round_sig(0.02 * kp, 2), round_sig(0.02 * kp, 2)]
    period = round(0.6 * math.sqrt(L), 3)
    step = round(0.2 * L, 3)
    robot = name or _urdf_robot_name(tree.name, path)

    # ---- collisions: the URDF's, unless a foot has none PyBullet uses or another link of the
    # leg reaches the ground at the stance; then a base box and foot spheres only
    def primitives(why: str) -> list[str]:
        suffix = os.path.commonprefix([f[::-1] for f in feet])[::-1]
        hips = np.array([joint_position(model, d0, joint_names[3 * k]) for k in range(4)])
        box = [2 * np.abs(hips[:, 0]).max(), 2 * np.abs(hips[:, 1]).max(), 0.25 * L]
        return [f"primitive_collisions: true       # {why}",
                "collision_primitives:            # link-name suffix -> shape [m]; other links: none",
                f"  {_str(tree.base(strip))}: {{box: {_list(box, 3)}}}"] + \
            [f"  {_str(f)}: {{sphere: foot_radius}}" for f in ([suffix] if suffix else feet)]

    def compose(prim_lines: list[str], warnings: list[str]) -> str:
        legs_txt = ",\n              ".join(", ".join(map(_str, joint_names[3 * k:3 * k + 3]))
                                             for k in range(4))
        lines = [f"# {robot}: starting spec written by latentune init_spec from {path.name}. "
                 "Units: m, s, rad, N·m.",
                 "# Leg order FR, FL, RR, RL; check the stance, gains and limits, then "
                 "`latentune robot check`."]
        lines += [f"# note: {n}" for n in notes] + [f"# warning: {w}" for w in warnings]
        lines += [
            f"name: {_str(robot)}",
            f"urdf: {_urdf_field(path)}",
            f"joint_names: [{legs_txt}]",
            f"foot_links: [{', '.join(map(_str, feet))}]",
            f"nominal_q: {_list(q_nom)}   # crouch: foot {CROUCH:g} × leg length below the hip",
            f"nominal_height: {_num(height)}           # from forward kinematics at nominal_q [m]",
            f"torque_limits: {_list(torque, 6)}   # abduction, hip, knee [N·m]: {torque_src}",
            f"kp: {_list([kp] * 3, 3)}   # swing-leg joint PD [N·m/rad]: "
            f"min(8 × mass {mass:.1f} kg, 4 × knee torque)",
            f"kd: {_list(kd, 3)}   # [N·m·s/rad]: (0.01, 0.02, 0.02) × kp",
            f"foot_radius: {_num(radius)}              # {radius_src} [m]",
            f"gaits:                           # leg length L = {L:.3f} m: period 0.6·sqrt(L), apex 0.2·L",
            f"  trot: {{period: {_num(period, 3)}, duty: 0.6, step_height: {_num(step, 3)}}}",
            f"  jump: {{period: {_num(round(1.12 * period, 3), 3)}, duty: 0.7, "
            f"step_height: {_num(step, 3)}}}",
        ]
        if strip:
            lines.append(f"strip_root: true                 # the root link {tree.root!r}: a massless dummy")
        lines += prim_lines
        lines += ["raibert_gain: 0.03               # swing foot placement gain on the velocity error [s]",
                  "mu: 0.45                         # MPC friction coefficient",
                  "max_tilt_deg: 60.0               # fallen beyond this base tilt [deg]"]
        return "\n".join(lines) + "\n"

    prims = [] if all(usable_collision(tree, f) for f in feet) else \
        primitives("the feet have no collision shape PyBullet uses")
    report = _self_check(compose(prims, []), path)
    if not prims and report.body_clearance is not None and report.body_clearance < CLEARANCE:
        prims = primitives(f"the URDF's {report.closest_link} is {1000 * report.body_clearance:.1f} mm "
                           "from the ground at the stance")
        report = _self_check(compose(prims, []), path)
    return compose(prims, report.warnings)


def _self_check(text: str, path: Path) -> Any:
    """:func:`~latentune.robots.check.check_spec` of the written spec, standing in PyBullet; the
    spec must load (else a bug of init_spec)."""
    from latentune import yamltext

    report = check_spec(yamltext.load(text))
    if report.errors:
        raise RobotSpecError(f"URDF {path}: init_spec wrote a spec that does not load "
                             f"({'; '.join(report.errors)})")
    return report
