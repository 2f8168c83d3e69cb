"""``check_spec``: every finding about a robot spec, its URDF measurements and, optionally, how
it stands in PyBullet (:class:`CheckReport`).

The field checks against the URDF are :func:`~latentune.robots.inspection.inspect_fields` (run
whenever a spec is loaded); :func:`check_spec` adds the settled height and the body clearance of
the robot stood up in the :class:`~latentune.sim.world.World` every rollout starts from.
"""
from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from latentune.errors import RobotSpecError
from latentune.robots import spec as S
from latentune.robots.inspection import LEGS, Findings, inspect_fields


# --------------------------------------------------------------------------- check_spec

@dataclass
class CheckReport(Findings):
    """Findings of :func:`check_spec` (messages without the file prefix): the
    :class:`Findings` fields (errors, warnings, filled, mass, base_link, fk_height,
    foot_positions and hip_positions in the order FR, FL, RR, RL, leg_length,
    urdf_torque_limits) and

    Attributes:
        source: the spec file (or the robot name of a :class:`RobotSpec`).
        name, urdf: the robot's name and URDF path ('' when the spec did not get that far).
        nominal_height: the spec's (or the computed) value [m].
        torque_limits: the spec's (or the computed) (3,) [N·m].
        settled_height: base (CoM) height after standing 0.3 s in PyBullet [m] (``simulate``).
        body_clearance, closest_link: distance [m] of the nearest non-foot link to the ground
            at the settled stance, and its name (``simulate``; None if none within 0.1 m).

    The spec loads iff there are no errors (:attr:`ok`).
    """

    source: str = ""
    name: str = ""
    urdf: str = ""
    nominal_height: float | None = None
    torque_limits: list[float] | None = None
    settled_height: float | None = None
    body_clearance: float | None = None
    closest_link: str | None = None

    @property
    def ok(self) -> bool:
        return not self.errors

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ok"] = self.ok
        d["filled"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.filled.items()}
        return d

    def format(self) -> str:
        """Human-readable lines: the verdict, measured values, then errors and warnings."""
        robot = f" (robot {self.name})" if self.name else ""
        lines = [f"{self.source}: {'OK' if self.ok else 'INVALID'}{robot}"]
        if self.urdf:
            lines.append(f"  urdf: {self.urdf}")
        if self.mass is not None:
            lines.append(f"  mass {self.mass:.3f} kg, base link {self.base_link}"
                         + (f", leg length {self.leg_length:.3f} m" if self.leg_length else ""))
        if self.fk_height is not None:
            h = "" if self.nominal_height is None else f"nominal_height {self.nominal_height:.3f} m, "
            lines.append(f"  {h}height from forward kinematics {self.fk_height:.3f} m")
        if self.foot_positions:
            feet = (f"{leg} ({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f})" for leg, p in zip(LEGS, self.foot_positions))
            lines.append("  feet at nominal_q (base frame, m): " + ", ".join(feet))
        if self.torque_limits is not None:
            u = "" if self.urdf_torque_limits is None else " (URDF effort: " + ", ".join(
                "-" if v is None else f"{v:g}" for v in self.urdf_torque_limits) + ")"
            lines.append(f"  torque_limits {', '.join(f'{v:g}' for v in self.torque_limits)} N·m{u}")
        if self.settled_height is not None:
            near = "" if self.closest_link is None else (
                f", nearest body link {self.closest_link} {1000 * self.body_clearance:.1f} mm above "
                "the ground")
            lines.append(f"  standing in PyBullet: base (CoM) height {self.settled_height:.3f} m{near}")
        for k, v in self.filled.items():
            lines.append(f"  computed {k}: {list(v) if isinstance(v, tuple) else v}")
        lines += [f"  error: {e}" for e in self.errors] + [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def check_spec(spec: str | os.PathLike | Any, simulate: bool = True) -> CheckReport:
    """All findings for a robot: a built-in name, a spec ``.yaml`` path, a
    :class:`~latentune.robots.spec.RobotSpec` or a dict of fields. Never raises for a bad spec
    (its problems are ``errors``); prints nothing.

    With ``simulate`` (and no errors), the robot is also stood up in PyBullet (the
    :class:`~latentune.sim.world.World` every rollout starts from: 0.3 s of joint PD at
    ``nominal_q``) to measure the settled base (CoM) height and the clearance of the nearest
    non-foot link; below :data:`CLEARANCE` a warning says the robot will count as fallen (body
    contact) as soon as that link touches."""
    path: Path | None = None
    if isinstance(spec, S.RobotSpec):
        source, fields = spec.name, dict(spec.__dict__)
    else:
        if isinstance(spec, Mapping):
            source, raw, base_dir, stem = f"robot spec {spec.get('name', '?')!r}", spec, Path.cwd(), None
        else:
            try:
                path = S.spec_path(spec)
            except RobotSpecError as exc:
                return CheckReport(source=os.fspath(spec), errors=[str(exc)])
            source = str(path)
            try:
                raw, base_dir, stem = S.read_yaml(path), path.parent, path.stem
            except RobotSpecError as exc:
                return CheckReport(source=source, errors=[_strip_prefix(str(exc), path)])
        try:
            fields = S.validated_fields(raw, "", base_dir, stem)
        except RobotSpecError as exc:
            return CheckReport(source=source, errors=[str(exc).removeprefix(": ")])
    found = inspect_fields(fields)
    fields = {**fields, **found.filled}
    tl = fields.get("torque_limits")
    report = CheckReport(**found.__dict__, source=source, name=str(fields.get("name", "")),
                         urdf=str(fields.get("urdf", "")), nominal_height=fields.get("nominal_height"),
                         torque_limits=None if tl is None else [float(v) for v in tl])
    clash = S.builtin_name_clash(S.RobotSpec(**fields), path) if report.ok and path else None
    if clash is not None:
        report.warnings.append(clash)
    if simulate and report.ok:
        _stand(S.RobotSpec(**fields), report)
    return report


CLEARANCE = 0.005
"""A non-foot link closer than this to the ground at the settled stance [m] warns."""


def _stand(spec: Any, report: CheckReport) -> None:
    """Settle the robot in PyBullet; fill the settled height and the nearest body link."""
    from latentune.sim.bullet import p, stdout_to_stderr
    from latentune.sim.world import World

    try:
        world = World(spec)
    except Exception as exc:  # noqa: BLE001 - PyBullet's errors are plain exceptions
        report.errors.append(f"PyBullet cannot build the robot ({type(exc).__name__}: {exc})")
        return
    try:
        world.reset()
        report.settled_height = float(world.state().pos[2])
        with stdout_to_stderr():
            pts = p.getClosestPoints(world.robot, world.ground, 0.1, physicsClientId=world.cid)
        feet = set(world.foot_ids)
        body = sorted((pt[8], world.link_names.get(pt[3], f"#{pt[3]}")) for pt in pts if pt[3] not in feet)
        if body:
            report.body_clearance, report.closest_link = float(body[0][0]), body[0][1]
            if body[0][0] < CLEARANCE:
                report.warnings.append(
                    f"at the settled stance the link {body[0][1]} is {1000 * body[0][0]:.1f} mm from the "
                    f"ground: the robot counts as fallen (body contact) as soon as it touches; lower "
                    "nominal_q's crouch or give collision_primitives")
        if not (0.5 * spec.nominal_height <= report.settled_height <= 2.5 * spec.nominal_height):
            report.warnings.append(f"the robot settles at a base height of {report.settled_height:.3f} "
                                   "m, outside the standing band [0.5, 2.5] × nominal_height: it falls "
                                   "at once")
    finally:
        world.close()


def _strip_prefix(msg: str, path: Path) -> str:
    return msg.removeprefix(f"robot spec {path}: ")


def round_sig(v: float, digits: int = 2) -> float:
    """``v`` rounded to ``digits`` significant digits."""
    if v == 0 or not math.isfinite(v):
        return v
    return round(v, digits - 1 - int(math.floor(math.log10(abs(v)))))
