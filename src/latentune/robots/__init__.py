"""Quadruped robots: specs (:mod:`.spec`), URDF preparation (:mod:`.urdf`) and the quantities
measured from the URDF with pinocchio (:mod:`.model`).

The built-in robots ``a1``, ``b1`` and ``solo12`` are the spec files ``specs/*.yaml`` of this
package, read by the same :func:`load_spec_file` as a user's ``--robot my_robot.yaml``.
"""
from __future__ import annotations

from latentune.errors import RobotSpecError
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
from latentune.robots.urdf import erd_robots_dir, package_dir, prepared_urdf

__all__ = [
    "BUILTIN", "LEGS", "SPECS_DIR", "CollisionShape", "GaitParams", "RobotModel", "RobotSpec",
    "RobotSpecError", "erd_robots_dir", "get_robot", "is_builtin", "load_spec_file",
    "package_dir", "prepared_urdf", "spec_from_dict",
]
