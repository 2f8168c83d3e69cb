"""Quadruped robots: specs (:mod:`.spec`), their checks against the URDF (:mod:`.inspection`, run
at every load; :mod:`.check`, the full report), a starting spec for a URDF (:mod:`.template`),
URDF reading and preparation (:mod:`.urdf`) and the quantities measured from the URDF with
pinocchio (:mod:`.model`).

:func:`check_spec`, :class:`CheckReport` and :func:`init_spec` stand the robot up in the
simulator (:mod:`latentune.sim`), which is built on this package's specs: they are loaded on
first use, so importing a spec never imports the simulator.

The built-in robots ``a1``, ``b1`` and ``solo12`` are the spec files ``specs/*.yaml`` of this
package, read by the same :func:`load_spec_file` as a user's ``--robot my_robot.yaml``.
"""
from __future__ import annotations

import importlib
from typing import Any

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
from latentune.robots.urdf import erd_robots_dir, package_dir, prepared_urdf, read_urdf

_ON_SIMULATOR = {"CheckReport": "latentune.robots.check", "check_spec": "latentune.robots.check",
                 "init_spec": "latentune.robots.template"}
"""The names of this package that need the simulator, and the module that defines each."""


def __getattr__(name: str) -> Any:
    if name in _ON_SIMULATOR:
        return getattr(importlib.import_module(_ON_SIMULATOR[name]), name)
    raise AttributeError(f"module 'latentune.robots' has no attribute {name!r}")


__all__ = [
    "BUILTIN", "LEGS", "SPECS_DIR", "CheckReport", "CollisionShape", "GaitParams", "RobotModel",
    "RobotSpec", "RobotSpecError", "check_spec", "erd_robots_dir", "get_robot", "init_spec",
    "is_builtin", "load_spec_file", "package_dir", "prepared_urdf", "read_urdf", "spec_from_dict",
]
