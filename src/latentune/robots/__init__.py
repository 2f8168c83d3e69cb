"""Robot specifications: what the actors and the simulator need to know about a quadruped.

A :class:`RobotSpec` names a URDF from an installed package (``pybullet_data`` or
``example-robot-data``), the 12 actuated joints in leg order FR, FL, RR, RL (hip abduction,
hip flexion, knee per leg), the four foot links, the nominal stance and per-gait fixed gains.
Mass, centroidal inertia at the stance, hip offsets and link lengths are *measured* from the URDF
with pinocchio when the robot is loaded (:func:`RobotModel`), so a custom robot needs only the
fields below. A custom robot is a YAML file with the same keys as :data:`BUILTIN` entries plus
``urdf`` (a path, absolute or relative to the YAML file).
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

LEGS = ("FR", "FL", "RR", "RL")


class RobotSpecError(ValueError):
    """A robot name or spec file that cannot be used."""


def _site_packages_path(*parts: str) -> Path:
    import pybullet_data  # noqa: F401  (any package in site-packages to locate it)

    base = Path(pybullet_data.__file__).resolve().parent.parent
    return base.joinpath(*parts)


def erd_robots_dir() -> Path:
    """Directory of example-robot-data's robot descriptions (URDFs ship there, no Python module)."""
    return _site_packages_path("cmeel.prefix", "share", "example-robot-data", "robots")


@dataclass(frozen=True)
class GaitParams:
    """Fixed (not tuned) gait timing per robot × gait. Times in seconds, heights in metres."""

    period: float        # full gait cycle [s]
    duty: float          # stance fraction of the cycle
    step_height: float   # swing apex above the ground [m]
    offsets: tuple[float, float, float, float]  # phase offset per leg FR, FL, RR, RL, in cycles


@dataclass(frozen=True)
class RobotSpec:
    """Static description of a quadruped. Leg order is always FR, FL, RR, RL.

    Attributes:
        name: short name.
        urdf: absolute path of the URDF file loaded by PyBullet and pinocchio.
        joint_names: 12 actuated joint names, per leg (abduction, hip, knee).
        foot_links: 4 foot link names.
        nominal_q: (12,) joint angles of the standing pose [rad].
        nominal_height: base height when standing at ``nominal_q`` on flat ground [m].
        torque_limits: (3,) max |τ| for (abduction, hip, knee) [N·m].
        kp, kd: (3,) joint PD gains for swing legs [N·m/rad, N·m·s/rad].
        foot_radius: contact sphere radius [m].
        gaits: gait name -> :class:`GaitParams`.
        strip_root: the URDF has a massless dummy root link to remove (B1).
        primitive_collisions: replace mesh collision shapes by boxes/spheres (faster stepping).
        raibert_gain: swing foot placement gain on the velocity error [s].
        mu: friction coefficient used by the MPC friction pyramid.
    """

    name: str
    urdf: str
    joint_names: tuple[str, ...]
    foot_links: tuple[str, ...]
    nominal_q: tuple[float, ...]
    nominal_height: float
    torque_limits: tuple[float, float, float]
    kp: tuple[float, float, float]
    kd: tuple[float, float, float]
    foot_radius: float
    gaits: dict[str, GaitParams] = field(default_factory=dict)
    strip_root: bool = False
    primitive_collisions: bool = False
    raibert_gain: float = 0.03
    mu: float = 0.45
    max_tilt_deg: float = 60.0

    def gait(self, name: str) -> GaitParams:
        if name not in self.gaits:
            raise RobotSpecError(f"robot {self.name!r} has no gait {name!r} (has: {', '.join(self.gaits)})")
        return self.gaits[name]


TROT_OFFSETS = (0.0, 0.5, 0.5, 0.0)
JUMP_OFFSETS = (0.0, 0.0, 0.0, 0.0)


def _unitree_joints(hip: str, thigh: str, calf: str) -> tuple[str, ...]:
    return tuple(f"{leg}_{j}" for leg in LEGS for j in (hip, thigh, calf))


def _a1() -> RobotSpec:
    import pybullet_data

    return RobotSpec(
        name="a1",
        urdf=str(Path(pybullet_data.getDataPath()) / "a1" / "a1.urdf"),
        joint_names=_unitree_joints("hip_joint", "upper_joint", "lower_joint"),
        foot_links=tuple(f"{leg}_toe" for leg in LEGS),
        nominal_q=(0.0, 0.8, -1.6) * 4,
        nominal_height=0.30,
        torque_limits=(20.0, 55.0, 55.0),
        kp=(100.0, 100.0, 100.0),
        kd=(1.0, 2.0, 2.0),
        foot_radius=0.02,
        gaits={
            "trot": GaitParams(period=0.3833, duty=0.6, step_height=0.08, offsets=TROT_OFFSETS),
            "jump": GaitParams(period=0.4286, duty=0.7, step_height=0.08, offsets=JUMP_OFFSETS),
        },
    )


def _b1() -> RobotSpec:
    return RobotSpec(
        name="b1",
        urdf=str(erd_robots_dir() / "b1_description" / "urdf" / "b1.urdf"),
        joint_names=_unitree_joints("hip_joint", "thigh_joint", "calf_joint"),
        foot_links=tuple(f"{leg}_foot" for leg in LEGS),
        nominal_q=(0.0, 0.8, -1.5) * 4,
        nominal_height=0.55,
        torque_limits=(91.0, 93.0, 140.0),
        kp=(300.0, 300.0, 300.0),
        kd=(5.0, 8.0, 8.0),
        foot_radius=0.04,
        gaits={
            "trot": GaitParams(period=0.45, duty=0.6, step_height=0.10, offsets=TROT_OFFSETS),
            "jump": GaitParams(period=0.5, duty=0.7, step_height=0.10, offsets=JUMP_OFFSETS),
        },
        strip_root=True,
        raibert_gain=0.04,
    )


def _solo12() -> RobotSpec:
    legs_solo = ("FR", "FL", "HR", "HL")
    return RobotSpec(
        name="solo12",
        urdf=str(erd_robots_dir() / "solo_description" / "robots" / "solo12.urdf"),
        joint_names=tuple(f"{leg}_{j}" for leg in legs_solo for j in ("HAA", "HFE", "KFE")),
        foot_links=tuple(f"{leg}_FOOT" for leg in legs_solo),
        nominal_q=(0.0, 0.8, -1.6, 0.0, 0.8, -1.6, 0.0, -0.8, 1.6, 0.0, -0.8, 1.6),
        nominal_height=0.24,
        torque_limits=(2.7, 2.7, 2.7),  # 0.025 N·m/A × 12 A × gear 9 (Solo12 actuator)
        kp=(6.0, 6.0, 6.0),
        kd=(0.15, 0.15, 0.15),
        foot_radius=0.0175,
        gaits={
            "trot": GaitParams(period=0.5, duty=0.6, step_height=0.05, offsets=TROT_OFFSETS),
            "jump": GaitParams(period=0.5, duty=0.7, step_height=0.05, offsets=JUMP_OFFSETS),
        },
        primitive_collisions=True,
        raibert_gain=0.03,
        mu=0.6,
    )


BUILTIN = {"a1": _a1, "b1": _b1, "solo12": _solo12}


_GAIT_KEYS = {"period", "duty", "step_height", "offsets"}


def load_spec_file(path: str | os.PathLike) -> RobotSpec:
    """Read a custom robot from a YAML file (see README, "Custom robots").

    Raises:
        RobotSpecError: missing file, bad YAML, missing/ill-typed field, URDF not found.
    """
    import yaml

    p = Path(path)
    if not p.is_file():
        raise RobotSpecError(f"robot spec file not found: {p}")
    try:
        raw = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise RobotSpecError(f"robot spec {p}: malformed YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise RobotSpecError(f"robot spec {p}: expected a mapping of fields")
    raw = dict(raw)
    if "base" in raw:  # start from a built-in robot and override fields
        base = raw.pop("base")
        if base not in BUILTIN:
            raise RobotSpecError(f"robot spec {p}: unknown base robot {base!r}")
        fields = dataclasses.asdict(BUILTIN[base]())
        fields["gaits"] = BUILTIN[base]().gaits
    else:
        fields = {}
    fields.update(raw)
    required = ["name", "urdf", "joint_names", "foot_links", "nominal_q", "nominal_height",
                "torque_limits", "kp", "kd", "foot_radius", "gaits"]
    missing = [k for k in required if k not in fields]
    if missing:
        raise RobotSpecError(f"robot spec {p}: missing field(s) {', '.join(missing)}")
    known = {f.name for f in dataclasses.fields(RobotSpec)}
    unknown = set(fields) - known
    if unknown:
        raise RobotSpecError(f"robot spec {p}: unknown field(s) {', '.join(sorted(unknown))}")
    urdf = Path(str(fields["urdf"]))
    if not urdf.is_absolute():
        urdf = (p.parent / urdf).resolve()
    if not urdf.is_file():
        raise RobotSpecError(f"robot spec {p}: URDF not found: {urdf}")
    fields["urdf"] = str(urdf)
    try:
        gaits = {}
        for gname, g in dict(fields["gaits"]).items():
            if isinstance(g, GaitParams):
                gaits[gname] = g
                continue
            if set(g) - _GAIT_KEYS or not {"period", "duty", "step_height"} <= set(g):
                raise RobotSpecError(f"robot spec {p}: gait {gname!r} needs period, duty, step_height")
            offs = g.get("offsets", TROT_OFFSETS if gname == "trot" else JUMP_OFFSETS)
            gaits[gname] = GaitParams(float(g["period"]), float(g["duty"]), float(g["step_height"]),
                                      tuple(float(o) for o in offs))
        fields["gaits"] = gaits
        for key, n in (("joint_names", 12), ("foot_links", 4), ("nominal_q", 12),
                       ("torque_limits", 3), ("kp", 3), ("kd", 3)):
            vals = tuple(fields[key])
            if len(vals) != n:
                raise RobotSpecError(f"robot spec {p}: {key} needs {n} entries, got {len(vals)}")
            fields[key] = tuple(str(v) for v in vals) if key in ("joint_names", "foot_links") \
                else tuple(float(v) for v in vals)
        for key in ("nominal_height", "foot_radius", "raibert_gain", "mu", "max_tilt_deg"):
            if key in fields:
                fields[key] = float(fields[key])
                if not np.isfinite(fields[key]) or fields[key] <= 0:
                    raise RobotSpecError(f"robot spec {p}: {key} must be a positive number")
        for g in gaits.values():
            if not (g.period > 0 and 0 < g.duty < 1 and g.step_height >= 0 and len(g.offsets) == 4):
                raise RobotSpecError(f"robot spec {p}: gait needs period > 0, 0 < duty < 1, 4 offsets")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, RobotSpecError):
            raise
        raise RobotSpecError(f"robot spec {p}: bad value ({exc})") from None
    return RobotSpec(**fields)


def get_robot(name: str | RobotSpec) -> RobotSpec:
    """A built-in robot by name (``a1``, ``b1``, ``solo12``) or a custom one from a YAML path."""
    if isinstance(name, RobotSpec):
        return name
    if name in BUILTIN:
        return BUILTIN[name]()
    if name.endswith((".yaml", ".yml")) or os.path.sep in name:
        return load_spec_file(name)
    raise RobotSpecError(f"unknown robot {name!r} (choose from {', '.join(BUILTIN)} or a spec .yaml)")


# --------------------------------------------------------------------------- URDF preparation

_SOLO_PRIMITIVES = {
    "base_link": '<box size="0.38 0.20 0.05"/>',
    "UPPER_LEG": '<box size="0.03 0.03 0.16"/>',
    "LOWER_LEG": '<box size="0.02 0.02 0.16"/>',
    "FOOT": None,  # sphere of foot_radius
}


def prepared_urdf(spec: RobotSpec) -> str:
    """Path of a URDF PyBullet and pinocchio can both load, derived from ``spec.urdf``.

    Rewrites ``package://`` mesh URIs to absolute paths, strips a massless dummy root link
    (``strip_root``), drops mesh collision shapes that duplicate primitives, and with
    ``primitive_collisions`` replaces mesh collisions by boxes and foot spheres. The result is
    cached in the temp directory under a hash of the inputs.
    """
    src = Path(spec.urdf)
    text = src.read_text()
    if not (spec.strip_root or spec.primitive_collisions or "package://" in text):
        return str(src)
    key = hashlib.sha1((text + repr((spec.strip_root, spec.primitive_collisions, spec.foot_radius))).encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / "latentune_urdf" / f"{spec.name}_{key}.urdf"
    if out.is_file():
        return str(out)

    robots = erd_robots_dir()

    def fix_uri(m: re.Match) -> str:
        uri = m.group(1)
        rel = uri[len("package://"):]
        for cand in (robots.parent.parent / rel, robots / rel, src.parent.parent / rel.split("/", 1)[-1]):
            if cand.is_file():
                return f'filename="{cand}"'
        return f'filename="{uri}"'

    text = re.sub(r'filename="(package://[^"]+)"', fix_uri, text)
    if spec.strip_root:
        # remove the first link if it is (nearly) massless and fixed to the real base
        m = re.search(r'<link\s+name="([^"]+)"\s*(?:/>|>.*?</link>)', text, flags=re.S)
        mass = re.search(r'<mass\s+value="([^"]+)"', m.group(0)) if m else None
        if m and (mass is None or float(mass.group(1)) < 1e-4):
            root = m.group(1)
            text = text.replace(m.group(0), "", 1)
            text = re.sub(r'<joint[^>]*type="fixed"[^>]*>(?:(?!</joint>).)*?<parent\s+link="%s"\s*/>.*?</joint>'
                          % re.escape(root), "", text, count=1, flags=re.S)
    # collision meshes in .dae are not used by PyBullet for collision; drop them
    text = re.sub(r'<collision>(?:(?!</collision>).)*?\.dae"(?:(?!</collision>).)*?</collision>', "", text, flags=re.S)
    if spec.primitive_collisions:
        def repl_link(m: re.Match) -> str:
            body, name = m.group(0), m.group(1)
            prim = None
            for suffix, shape in _SOLO_PRIMITIVES.items():
                if name.endswith(suffix):
                    prim = shape if shape is not None else f'<sphere radius="{spec.foot_radius}"/>'
            def repl_col(c: re.Match) -> str:
                if prim is None:
                    return ""
                origin = ""
                if "LEG" in name:
                    origin = '<origin xyz="0 0 -0.08" rpy="0 0 0"/>'
                return f"<collision>{origin}<geometry>{prim}</geometry></collision>"
            return re.sub(r"<collision>.*?</collision>", repl_col, body, flags=re.S)
        text = re.sub(r'<link\s+name="([^"]+)"\s*>.*?</link>', repl_link, text, flags=re.S)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    return str(out)


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
    q_index: np.ndarray | None = None  # pinocchio q index of each of our 12 joints

    @classmethod
    def load(cls, spec: RobotSpec) -> "RobotModel":
        key = repr(spec)
        if key not in _MODEL_CACHE:
            _MODEL_CACHE[key] = _load_model(spec)
        return _MODEL_CACHE[key]


_MODEL_CACHE: dict[str, RobotModel] = {}


def _load_model(spec: RobotSpec) -> RobotModel:
    import pinocchio as pin

    urdf = prepared_urdf(spec)
    try:
        model = pin.buildModelFromUrdf(urdf)  # fixed base: kinematics in the base link frame
    except Exception as exc:  # pinocchio raises RuntimeError/ValueError with long messages
        raise RobotSpecError(f"cannot parse URDF {urdf}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    names = [model.names[i] for i in range(model.njoints)]
    try:
        q_index = np.array([model.joints[names.index(j)].idx_q for j in spec.joint_names])
    except ValueError:
        missing = [j for j in spec.joint_names if j not in names]
        raise RobotSpecError(f"robot {spec.name}: joints not in URDF: {', '.join(missing)}") from None
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
    # whole-body CoM and centroidal inertia need the trunk too: use a free-flyer model at identity
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
    # (The whole-body centroidal inertia at the stance, pin.ccrba, is ~3x larger on A1 because it
    # counts the legs swinging with the trunk; with stance feet planted the body turns far more
    # easily, and the MPC built on the whole-body value over-corrects and oscillates.)
    trunk = ff.inertias[1]
    inertia = trunk.inertia.copy() * (mass / trunk.mass)
    return RobotModel(spec=spec, urdf=urdf, mass=mass, inertia=inertia, hip_offsets=hips,
                      foot_stance=feet, com_offset=com, pin_model=model, foot_frame_ids=tuple(fids),
                      q_index=q_index)
