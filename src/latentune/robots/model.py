"""Quantities measured from a robot's URDF with pinocchio at its nominal stance.

:meth:`RobotModel.load` builds the prepared URDF (:func:`~latentune.robots.urdf.prepared_urdf`)
and measures total mass [kg], the single-rigid-body inertia [kg·m²], hip and stance-foot
positions and the whole-body CoM [m] in the base link frame. Results are cached per process,
keyed by the spec.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from latentune.errors import RobotSpecError
from latentune.robots.spec import RobotSpec
from latentune.robots.urdf import prepared_urdf


@dataclass
class RobotModel:
    """Quantities measured from the URDF with pinocchio at the nominal stance.

    Attributes:
        spec: the :class:`RobotSpec`.
        urdf: prepared URDF path.
        mass: total mass [kg].
        inertia: (3, 3) rotational inertia for the single-rigid-body model, base frame [kg·m²]
            (trunk inertia × total mass / trunk mass).
        hip_offsets: (4, 3) hip (abduction joint) positions in the base *link* frame [m].
        foot_stance: (4, 3) foot positions at ``nominal_q`` in the base link frame [m].
        com_offset: (3,) whole-body CoM at the stance in the base link frame [m].
        pin_model: fixed-base pinocchio model of the prepared URDF.
        foot_frame_ids: pinocchio frame id of each foot link.
        q_index: (12,) pinocchio configuration index of each of the spec's joints.
    """

    spec: RobotSpec
    urdf: str
    mass: float
    inertia: np.ndarray
    hip_offsets: np.ndarray
    foot_stance: np.ndarray
    com_offset: np.ndarray
    pin_model: Any = None
    foot_frame_ids: tuple[int, ...] = ()
    q_index: np.ndarray | None = None

    @classmethod
    def load(cls, spec: RobotSpec) -> "RobotModel":
        """The measured model of ``spec`` (built once per process and spec).

        Raises:
            RobotSpecError: the URDF does not parse, or lacks a joint or foot link of the spec.
        """
        key = repr(spec)
        if key not in _MODEL_CACHE:
            _MODEL_CACHE[key] = _measure(spec)
        return _MODEL_CACHE[key]


_MODEL_CACHE: dict[str, RobotModel] = {}


def _measure(spec: RobotSpec) -> RobotModel:
    import pinocchio as pin

    urdf = prepared_urdf(spec)
    try:
        model = pin.buildModelFromUrdf(urdf)  # fixed base: kinematics in the base link frame
    except Exception as exc:  # pinocchio raises RuntimeError/ValueError with long messages
        raise RobotSpecError(f"cannot parse URDF {urdf}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    names = [model.names[i] for i in range(model.njoints)]
    missing = [j for j in spec.joint_names if j not in names]
    if missing:
        raise RobotSpecError(f"robot {spec.name}: joints not in URDF: {', '.join(missing)}")
    q_index = np.array([model.joints[names.index(j)].idx_q for j in spec.joint_names])
    fids = []
    for f in spec.foot_links:
        if not model.existFrame(f):
            raise RobotSpecError(f"robot {spec.name}: foot link {f!r} not in URDF")
        fids.append(model.getFrameId(f))
    data = model.createData()
    q = np.zeros(model.nq)
    q[q_index] = spec.nominal_q
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    feet = np.array([data.oMf[i].translation.copy() for i in fids])
    hips = np.array([data.oMi[names.index(spec.joint_names[3 * k])].translation.copy() for k in range(4)])
    # whole-body CoM and mass need the trunk too: use a free-flyer model at identity
    ff = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    ffd = ff.createData()
    qf = pin.neutral(ff)
    ff_names = [ff.names[i] for i in range(ff.njoints)]
    for k, j in enumerate(spec.joint_names):
        qf[ff.joints[ff_names.index(j)].idx_q] = spec.nominal_q[k]
    pin.ccrba(ff, ffd, qf, np.zeros(ff.nv))
    com = ffd.com[0].copy()
    mass = float(pin.computeTotalMass(ff))
    # Rotational inertia for a single-rigid-body MPC: the trunk's, scaled by total/trunk mass.
    # The whole-body centroidal inertia at the stance (pin.ccrba; 2.4-3.5x larger per axis on
    # A1) counts the legs turning rigidly with the trunk; with stance feet planted the body turns
    # far more easily, and an MPC built on it over-corrects and oscillates.
    trunk = ff.inertias[1]
    inertia = trunk.inertia.copy() * (mass / trunk.mass)
    return RobotModel(spec=spec, urdf=urdf, mass=mass, inertia=inertia, hip_offsets=hips,
                      foot_stance=feet, com_offset=com, pin_model=model, foot_frame_ids=tuple(fids),
                      q_index=q_index)
