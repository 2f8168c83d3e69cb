"""Checks of a robot spec's fields against its URDF, run whenever a spec is loaded.

:func:`inspect_fields` compares the spec fields with the URDF (:func:`~latentune.robots.urdf.read_urdf`
tree and pinocchio forward kinematics at ``nominal_q``, in the base link frame: x forward, y left,
z up) and fills the fields a spec may omit:

* errors: the URDF is not XML or has no links/joints, or a link's mass or inertia is impossible;
  a root link of mass 0 carries the legs (PyBullet holds it in space); a ``joint_names`` entry is missing or not
  ``revolute``/``continuous``; a foot link is missing; a leg's three joints are not one chain or
  its foot is not below its knee; a foot is not where its leg's name says (FR: x > 0, y < 0;
  FL: x > 0, y > 0; RR: x < 0, y < 0; RL: x < 0, y > 0) or not below the base; a foot has no
  collision shape PyBullet uses; a mesh file the URDF names is missing (a visual one, or a
  collision one without ``primitive_collisions``); a spec joint's URDF ``<limit>`` has lower > upper; ``foot_radius``
  is the leg length or more.
* filled when omitted: ``nominal_height`` (the base height that ``nominal_q`` gives with the feet
  on the ground: ``foot_radius`` − mean foot z), ``torque_limits`` (the URDF's
  ``<limit effort>``, the smallest of the four legs per joint role), ``strip_root`` (true iff the
  root link is a massless dummy fixed to the real base).
* warnings: ``nominal_height`` more than :data:`HEIGHT_TOLERANCE` from the forward-kinematics
  height, feet not level at ``nominal_q``, ``nominal_q`` outside the URDF's joint limits,
  ``torque_limits`` above the URDF's effort limits, an effort limit that looks like a placeholder,
  ``strip_root`` that strips nothing or is off with a massless root, a ``collision_primitives``
  key that matches no link, ``foot_radius`` above :data:`LARGE_FOOT` of the leg length, a link
  with mass and a zero moment of inertia. A root
  without ``<inertial>`` that carries movable joints is not stripped and not warned about (the
  prepared URDF gives it a negligible mass); one whose ``<inertial>`` gives mass 0 is an error
  (PyBullet would hold it fixed in space).

The loader (:mod:`latentune.robots.spec`) raises :class:`~latentune.errors.RobotSpecError` with
every error in one line and warns (:func:`emit_warning`) once per process about each warning;
:func:`~latentune.robots.check.check_spec` reports them all. :data:`LEGS` is the leg order of
every spec field (FR, FL, RR, RL).
"""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from latentune.constants import G
from latentune.errors import RobotSpecError, RobotSpecWarning
from latentune.robots.urdf import MASSLESS, UrdfTree, kinematic_urdf_text, read_urdf, resolve_mesh

LEGS = ("FR", "FL", "RR", "RL")
"""The leg order of every per-leg spec field: front right, front left, rear right, rear left."""
LEG_SIGNS = {"FR": (1, -1), "FL": (1, 1), "RR": (-1, -1), "RL": (-1, 1)}
"""Sign of a leg's foot (x, y) in the base frame: front x > 0, right y < 0."""
ROLES = ("abduction", "hip", "knee")
HEIGHT_TOLERANCE = 0.10
"""Relative gap between ``nominal_height`` and the forward-kinematics height that warns (the
built-in robots agree within 0.5 %)."""
LEVEL_TOLERANCE = 0.05
"""Spread of the foot heights at ``nominal_q``, relative to the height, that warns."""
PLACEHOLDER_EFFORT = 5.0
"""An effort limit above this × m·g·leg length looks like a placeholder (A1's URDF: 1000 N·m)."""
LARGE_FOOT = 0.25
"""A ``foot_radius`` above this share of the leg length warns (a ball foot, a wheel; the built-in
robots' are 5–6 %); one of the leg length or more is refused."""


@dataclass
class Findings:
    """What :func:`inspect_fields` found (errors and warnings without the file prefix).

    Attributes:
        filled: values of omitted fields (``nominal_height``, ``torque_limits``, ``strip_root``).
        mass: total URDF mass [kg]; base_link: the base link after stripping.
        fk_height: base height from forward kinematics at ``nominal_q``, feet on the ground [m].
        foot_positions, hip_positions: (4, 3) at ``nominal_q``, base link frame [m].
        leg_length: mean hip-flexion-joint → knee → foot length at q = 0 [m].
        urdf_torque_limits: (3,) smallest URDF effort per role (None where a joint has none).
    """

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    filled: dict[str, Any] = field(default_factory=dict)
    mass: float | None = None
    base_link: str | None = None
    fk_height: float | None = None
    foot_positions: list[list[float]] | None = None
    hip_positions: list[list[float]] | None = None
    leg_length: float | None = None
    urdf_torque_limits: list[float | None] | None = None


_EMITTED: set[str] = set()


def emit_warning(message: str) -> None:
    """Warn (:class:`~latentune.errors.RobotSpecWarning`) about something the user should change
    in a robot spec, once per process and message."""
    if message not in _EMITTED:
        _EMITTED.add(message)
        warnings.warn(message, RobotSpecWarning, stacklevel=3)


# --------------------------------------------------------------------------- kinematics

def pin_model(urdf: str, strip_root: bool) -> Any:
    """Fixed-base pinocchio model of the URDF as simulated (root stripped, continuous joints
    revolute).

    Raises:
        RobotSpecError: pinocchio cannot build it.
    """
    import pinocchio as pin

    try:
        return pin.buildModelFromXML(kinematic_urdf_text(urdf, strip_root))
    except Exception as exc:  # noqa: BLE001 - pinocchio raises RuntimeError/ValueError
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RobotSpecError(f"URDF {urdf}: pinocchio cannot build the model ({msg})") from None


def placements(model: Any, q_by_joint: Mapping[str, float]) -> tuple[Any, Any]:
    """(model, data) after forward kinematics with the given joint angles (others 0)."""
    import pinocchio as pin

    q = np.zeros(model.nq)
    for name, v in q_by_joint.items():
        q[model.joints[model.getJointId(name)].idx_q] = v
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    return model, data


def joint_position(model: Any, data: Any, joint: str) -> np.ndarray:
    return data.oMi[model.getJointId(joint)].translation.copy()


def link_position(model: Any, data: Any, link: str) -> np.ndarray:
    import pinocchio as pin

    return data.oMf[model.getFrameId(link, pin.FrameType.BODY)].translation.copy()


# --------------------------------------------------------------------------- the checks

def _fmt(v: float) -> str:
    return f"{v:+.3f}"


def missing_meshes(tree: UrdfTree, collisions: bool = True) -> list[tuple[str, str, str]]:
    """(link, "visual" or "collision", filename) of each mesh file the URDF names that is not
    there (PyBullet refuses to load such a URDF, visual shapes ignored or not); collision
    ``.dae`` meshes (dropped for PyBullet) are not looked for, nor any collision mesh without
    ``collisions`` (``primitive_collisions`` replaces them)."""
    import xml.etree.ElementTree as ET

    out = []
    for link in ET.parse(tree.path).getroot().iter("link"):
        for kind in ("visual", "collision") if collisions else ("visual",):
            for mesh in link.findall(f"{kind}/geometry/mesh"):
                fn = mesh.get("filename", "")
                if not fn or (kind == "collision" and fn.lower().endswith(".dae")):
                    continue
                if resolve_mesh(fn, tree.path) is None:
                    out.append((link.get("name", "?"), kind, fn))
    return out


def usable_collision(tree: UrdfTree, link: str) -> bool:
    """The link keeps a collision shape PyBullet uses (.dae meshes are dropped; a mesh file
    must exist)."""
    for tag, attrib in tree.links[link].collisions:
        if tag != "mesh":
            return True
        fn = attrib.get("filename", "")
        if not fn.lower().endswith(".dae") and resolve_mesh(fn, tree.path) is not None:
            return True
    return False


def inspect_fields(fields: Mapping[str, Any]) -> Findings:
    """Check validated spec fields against the URDF (see the module docstring).

    ``fields`` holds at least ``urdf`` (absolute path), ``joint_names`` (12), ``foot_links`` (4),
    ``nominal_q`` (12) and ``foot_radius``; ``nominal_height``, ``torque_limits`` and
    ``strip_root`` are filled when absent. Never raises for a bad URDF: the problem is an error.
    """
    out = Findings()
    err, warn = out.errors.append, out.warnings.append
    try:
        tree = read_urdf(fields["urdf"])
    except RobotSpecError as exc:
        err(str(exc))
        return out

    # ---- root link
    root_mass = tree.links[tree.root].mass
    if "strip_root" in fields:
        strip = bool(fields["strip_root"])
        if strip and not tree.massless_root():
            warn(f"strip_root: the root link {tree.root!r} is not a massless dummy fixed to the "
                 "base; nothing is stripped")
        elif not strip and tree.massless_root():
            warn(f"strip_root is false but the root link {tree.root!r} is massless (PyBullet "
                 "zeroes its inertia and prints a warning); omit strip_root to strip it")
    else:
        strip = tree.massless_root()
        out.filled["strip_root"] = strip
    # a root without <inertial> gets a negligible mass in the prepared URDF and floats; one of
    # mass 0 given in its <inertial> would be held fixed in space by PyBullet
    if root_mass == 0 and not tree.massless_root():
        err(f"the root link {tree.root!r} has mass 0 and carries movable joints: PyBullet would "
            "hold it fixed in space; give it its mass")
    for link in tree.links.values():      # a limit, not a body: the engines need moments > 0
        # ... in a body that moves: a link on a fixed joint (HyQ's trunk_imu) is welded into
        # its parent's body, its moments added to the parent's (PyBullet, MuJoCo, pinocchio)
        welded = (j := tree.parent_joint(link.name)) is not None and j.type == "fixed"
        if (link.moments is not None and (link.mass or 0.0) >= MASSLESS and not welded
                and min(link.moments) <= 0):
            k = ("ixx", "iyy", "izz")[int(np.argmin(link.moments))]
            warn(f"link {link.name!r} has mass {link.mass:g} kg and the moment of inertia {k} = 0 "
                 "kg·m² (a point mass or a thin rod, not a body): give its moments (the engines "
                 "need them > 0)")
    out.base_link = tree.base(strip)
    out.mass = tree.total_mass()
    if out.mass <= 0:
        err("the URDF's links have no mass")

    # ---- names
    jn, feet = list(fields["joint_names"]), list(fields["foot_links"])
    movable = [j.name for j in tree.joints.values() if j.type in ("revolute", "continuous")]
    for what, names in (("joint_names", jn), ("foot_links", feet)):
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            err(f"{what}: {', '.join(twice)} given twice")
    missing = [j for j in jn if j not in tree.joints]
    if missing:
        err(f"joint_names: not in the URDF: {', '.join(missing)} (its revolute joints: "
            f"{', '.join(movable[:16]) or 'none'})")
    wrong = [f"{j} is {tree.joints[j].type}" for j in jn if j in tree.joints
             and tree.joints[j].type not in ("revolute", "continuous")]
    if wrong:
        err(f"joint_names: {', '.join(wrong)}, not revolute or continuous")
    missing = [f for f in feet if f not in tree.links]
    if missing:
        leaves = [n for n in tree.links if not tree.child_joints(n)]
        err(f"foot_links: not links of the URDF: {', '.join(missing)} (its leaf links: "
            f"{', '.join(leaves[:16])})")
    if out.errors:
        return out

    # ---- joint limits: a <limit> with lower > upper is no range (PyBullet reads it as none)
    for j in jn:
        lo, hi = tree.joints[j].lower, tree.joints[j].upper
        if tree.joints[j].type == "revolute" and lo is not None and hi is not None and lo > hi:
            err(f"joint_names: {j}'s URDF <limit> lower must be at most its upper {hi:.4g} rad, "
                f"got {lo:.4g}")
    if out.errors:
        return out

    # ---- leg chains: abduction -> hip -> knee -> foot
    for k, leg in enumerate(LEGS):
        j0, j1, j2 = jn[3 * k:3 * k + 3]
        above = tree.joints_above(feet[k])
        chain = tree.joints_above(tree.joints[j2].child)
        if not (j0 in chain and j1 in chain and chain.index(j0) < chain.index(j1) < chain.index(j2)):
            err(f"joint_names: leg {leg} ({j0}, {j1}, {j2}) is not one chain abduction -> hip -> knee")
        elif j2 not in above:
            err(f"foot_links: {feet[k]} (leg {leg}) is not below that leg's knee joint {j2}")
    if out.errors:
        return out

    # ---- forward kinematics at nominal_q, base frame
    try:
        model = pin_model(fields["urdf"], strip)
    except RobotSpecError as exc:
        err(str(exc))
        return out
    q_nom = dict(zip(jn, fields["nominal_q"]))
    _, data = placements(model, q_nom)
    foot_pos = np.array([link_position(model, data, f) for f in feet])
    hip_pos = np.array([joint_position(model, data, jn[3 * k]) for k in range(4)])
    out.foot_positions, out.hip_positions = foot_pos.tolist(), hip_pos.tolist()
    _, data0 = placements(model, {})  # q = 0: hip flexion joint, knee joint, foot per leg
    hip0, knee0 = ([joint_position(model, data0, jn[3 * k + r]) for k in range(4)] for r in (1, 2))
    foot0 = [link_position(model, data0, f) for f in feet]
    thigh = [float(np.linalg.norm(knee0[k] - hip0[k])) for k in range(4)]
    shank = [float(np.linalg.norm(foot0[k] - knee0[k])) for k in range(4)]
    out.leg_length = leg_length = float(np.mean(np.add(thigh, shank)))
    at_knee = [feet[k] for k in range(4) if shank[k] < 0.2 * thigh[k]]
    if at_knee:
        err(f"foot_links: {', '.join(at_knee)} at the knee joint, not at the foot: a foot link's "
            "origin must be the contact point (add fixed foot links)")
    for k, leg in enumerate(LEGS):
        sx, sy = LEG_SIGNS[leg]
        x, y = foot_pos[k, 0], foot_pos[k, 1]
        if not (sx * x > 0 and sy * y > 0):
            at = next(n for n, (a, b) in LEG_SIGNS.items() if a * x > 0 and b * y > 0) \
                if x != 0 and y != 0 else "on an axis"
            err(f"foot_links/joint_names: leg {leg}'s foot {feet[k]} is at x={_fmt(x)}, y={_fmt(y)} m "
                f"in the base frame at nominal_q ({at}); {leg} needs x {'>' if sx > 0 else '<'} 0, "
                f"y {'>' if sy > 0 else '<'} 0 (order FR, FL, RR, RL; base x forward, y left)")
    low = [f"{feet[k]} (z={_fmt(foot_pos[k, 2])})" for k in range(4) if foot_pos[k, 2] >= 0]
    if low:
        err(f"nominal_q: feet not below the base: {', '.join(low)}")
    if out.errors:
        return out
    radius = float(fields["foot_radius"])
    if radius >= leg_length:
        err(f"foot_radius must be in (0, {leg_length:.3g}) m, below the leg length (hip -> knee "
            f"-> foot at q = 0), got {radius:g}")
        return out
    if radius > LARGE_FOOT * leg_length:
        warn(f"foot_radius {radius:g} m is {100 * radius / leg_length:.0f}% of the leg length "
             f"{leg_length:.3g} m (more than {100 * LARGE_FOOT:.0f}%): a ball foot or a wheel?")
    fk_height = radius - float(foot_pos[:, 2].mean())
    out.fk_height = fk_height
    spread = float(np.ptp(foot_pos[:, 2]))
    if spread > LEVEL_TOLERANCE * fk_height:
        warn(f"nominal_q does not put the feet level: foot z from {foot_pos[:, 2].min():.3f} to "
             f"{foot_pos[:, 2].max():.3f} m")
    if fields.get("nominal_height") is None:
        out.filled["nominal_height"] = round(fk_height, 4)
    else:
        h = float(fields["nominal_height"])
        if abs(h - fk_height) > HEIGHT_TOLERANCE * fk_height:
            warn(f"nominal_height {h:.3f} m is {100 * (h / fk_height - 1):+.0f}% off the height "
                 f"{fk_height:.3f} m that nominal_q gives with the feet on the ground (forward "
                 "kinematics); omit nominal_height to use that")

    # ---- joint limits and torque limits
    for j, v in q_nom.items():
        lo, hi = tree.joints[j].lower, tree.joints[j].upper
        if tree.joints[j].type == "revolute" and lo is not None and hi is not None and lo < hi \
                and not lo - 1e-9 <= v <= hi + 1e-9:
            warn(f"nominal_q: {j} = {v:g} rad is outside its URDF limits [{lo:g}, {hi:g}]")
    efforts = [[tree.joints[jn[3 * k + r]].effort for k in range(4)] for r in range(3)]
    urdf_lim = [min(e) if all(x is not None and x > 0 for x in e) else None for e in efforts]
    out.urdf_torque_limits = urdf_lim
    scale = out.mass * G * leg_length
    if fields.get("torque_limits") is None:
        none = [jn[3 * k + r] for r in range(3) for k in range(4) if not (efforts[r][k] or 0) > 0]
        if none:
            err(f"torque_limits omitted and the URDF gives no <limit effort> for {', '.join(none[:4])}"
                f"{' …' if len(none) > 4 else ''}: give torque_limits [abduction, hip, knee] in N·m")
        else:
            out.filled["torque_limits"] = tuple(float(v) for v in urdf_lim)
            big = [f"{ROLES[r]} {urdf_lim[r]:g}" for r in range(3)
                   if urdf_lim[r] > PLACEHOLDER_EFFORT * scale]
            if big:
                warn(f"torque_limits from the URDF's effort limits ({', '.join(big)} N·m) exceed "
                     f"{PLACEHOLDER_EFFORT:g} × m·g·leg length = {PLACEHOLDER_EFFORT * scale:.0f} N·m: "
                     "placeholders? give torque_limits")
    else:
        over = [f"{ROLES[r]} {fields['torque_limits'][r]:g} > {urdf_lim[r]:g}" for r in range(3)
                if urdf_lim[r] is not None and fields["torque_limits"][r] > urdf_lim[r] * (1 + 1e-9)]
        if over:
            warn(f"torque_limits above the URDF's effort limits ({', '.join(over)} N·m)")

    # ---- collisions
    prims = fields.get("collision_primitives") or {}
    missing = missing_meshes(tree, collisions=not fields.get("primitive_collisions"))
    if missing:                 # the first by name, then how many more (a URDF without meshes/)
        link, kind, fn = missing[0]
        more = f" and {len(missing) - 1} more mesh file(s)" if len(missing) > 1 else ""
        err(f"link {link!r}: {kind} mesh {fn} not found{more} (a path is relative to the "
            "URDF's directory): add " + ("them" if more else "the file") + (", or give primitive_collisions" if any(
                k == "collision" for _, k, _ in missing) else ""))
    if fields.get("primitive_collisions"):
        nofoot = [f for f in feet if not any(f.endswith(s) for s in prims)]
        if nofoot:
            err(f"collision_primitives: no key ends the foot link name(s) {', '.join(nofoot)}, "
                "so they would not touch the ground")
    else:
        nofoot = [f for f in feet if not usable_collision(tree, f)]
        if nofoot:
            err(f"foot link(s) {', '.join(nofoot)} have no collision shape PyBullet uses (none, a "
                "missing mesh or a .dae mesh): give primitive_collisions: true and "
                "collision_primitives with a foot sphere")
    unused = [s for s in prims if not any(n.endswith(s) for n in tree.links)]
    if unused:
        warn(f"collision_primitives: {', '.join(unused)} ends no link name")
    return out
