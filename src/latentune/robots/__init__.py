"""Quadruped robots: specs (:mod:`.spec`), their checks against the URDF (:mod:`.check`), a
starting spec for a URDF (:mod:`.template`), URDF reading and preparation (:mod:`.urdf`) and the
quantities measured from the URDF with pinocchio (:mod:`.model`).

The built-in robots ``a1``, ``b1`` and ``solo12`` are the spec files ``specs/*.yaml`` of this
package, read by the same :func:`load_spec_file` as a user's ``--robot my_robot.yaml``.
"""
from __future__ import annotations

from latentune.errors import RobotSpecError
from latentune.robots.check import CheckReport, check_spec
from latentune.robots.model import RobotModel
from latentune.robots.spec import (
    BUILTIN,
    LEGS,
    SPECS_DIR,
    CollisionShape,
    GaitParams,
    RobotSpec,
    get_robot,
    is_builtin,
    load_spec_file,
    spec_from_dict,
)
from latentune.robots.template import init_spec
from latentune.robots.urdf import erd_robots_dir, package_dir, prepared_urdf, read_urdf

__all__ = [
    "BUILTIN", "LEGS", "SPECS_DIR", "CheckReport", "CollisionShape", "GaitParams", "RobotModel",
    "RobotSpec", "RobotSpecError", "check_spec", "erd_robots_dir", "get_robot", "init_spec",
    "is_builtin", "load_spec_file", "package_dir", "prepared_urdf", "read_urdf", "spec_from_dict",
]
