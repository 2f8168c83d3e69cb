"""Reality profiles: how the simulated robot differs from the one the controller was tuned on.

A :class:`Reality` lists perturbations of the simulated robot and its surroundings; every field
defaults to "no change", so ``Reality()`` is the nominal simulator. The worlds
(:class:`~latentune.sim.world.World`, :class:`~latentune.sim.mujoco_world.MujocoWorld`) apply it:

* **body**: every link's mass × ``mass_scale``, every link's rotational inertia ×
  ``mass_scale · inertia_scale``; a ``payload_mass`` [kg] (a 0.1 m cube's inertia) rigidly
  fixed at ``payload_offset`` (3,) [m] in the base link frame — both written into a copy of the
  URDF (:func:`perturbed_urdf`), so both engines load the same bodies;
* **ground**: the foot–ground Coulomb coefficient × ``friction_scale`` (nominal 1.0), or set to
  ``friction``; the contact ``restitution`` (0 = no bounce, the nominal);
* **motors**: the commanded torque × ``torque_scale``, then clipped to ``torque_limits``
  (abduction, hip, knee) [N·m] when given; the command takes effect ``latency_steps`` physics
  steps (of 1 ms) after it is sent;
* **joints**: viscous ``joint_damping`` [N·m·s/rad] and Coulomb ``joint_friction`` [N·m];
* **sensors**: white Gaussian noise of standard deviation ``noise_pos`` [m], ``noise_rpy``
  [rad] (a random rotation vector), ``noise_vel`` [m/s], ``noise_omega`` [rad/s], ``noise_q``
  [rad], ``noise_dq`` [rad/s] on the state the controller sees (the cost and the fall detector
  use the true state);
* **pushes**: horizontal forces of ``push_force`` [N] on the base's centre of mass, each lasting
  ``push_duration`` [s], in a uniformly random direction, separated by exponential waiting
  times of mean ``push_interval`` [s].

**Relative to the robot.** A payload, a push or a joint friction that is modest for a 12 kg A1
is beyond a 2.5 kg Solo12, so three fields have relative twins, resolved for each robot by the
worlds (:meth:`Reality.for_robot`) and added to the absolute ones: ``payload_fraction`` (of the
robot's nominal total mass), ``push_fraction`` (of its nominal weight ``m·g``) and
``joint_friction_fraction`` (of its largest joint torque limit). The presets use them.

The random parts (sensor noise, pushes) draw from generators seeded from the world's seed (the
Task's seed) and re-seeded at every ``reset()``: a rollout is reproducible for a seed, and two
seeds give two different noise and push sequences.

YAML form (a file, or a preset under ``latentune/sim/presets``; the keys are the field names,
all optional; ``base`` names presets or files merged first, in order, the file's own keys last)::

    name: my-robot
    base: [heavy]            # start from the heavy preset
    torque_scale: 0.85
    latency_steps: 5
    noise_vel: 0.02
    push_fraction: 0.16      # pushes of 16 % of the robot's weight

:meth:`Reality.load` takes a preset name, a file, a dict or a Reality; a bad profile raises one
:class:`~latentune.errors.UsageError` line.
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import tempfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.constants import G
from latentune.errors import UsageError
from latentune.sim.state import RobotState

__all__ = ["Reality", "RealityRuntime", "PRESETS", "preset_names", "perturbed_urdf"]

PRESET_DIR = Path(__file__).resolve().parent / "presets"
_URDF_VERSION = "reality-1"  # in the perturbed-URDF cache key: bump when the rewrite changes
PAYLOAD_LINK = "latentune_payload"
"""Name of the payload link :func:`perturbed_urdf` adds."""


def preset_names() -> tuple[str, ...]:
    """Names of the built-in presets (the YAML files under ``latentune/sim/presets``)."""
    return tuple(sorted(p.stem for p in PRESET_DIR.glob("*.yaml")))


PRESETS = preset_names()

_POS, _NONNEG, _UNIT, _ANY = "> 0", ">= 0", "in [0, 1]", "finite"  # the value rules


@dataclass(frozen=True)
class Reality:
    """A reality profile (see the module docstring); all fields default to "no change".

    Attributes:
        name: a label, recorded with the run.
        mass_scale: factor on every link's mass (> 0).
        inertia_scale: extra factor on every link's rotational inertia (> 0; the inertia is
            scaled by ``mass_scale · inertia_scale``).
        payload_mass: extra mass rigidly fixed to the base [kg] (≥ 0).
        payload_offset: (3,) the payload's centre in the base link frame [m].
        friction_scale: factor on the foot–ground friction coefficient (> 0; nominal 1.0).
        friction: the foot–ground friction coefficient itself (> 0), overriding the scale.
        restitution: contact restitution coefficient in [0, 1] (0: no bounce, the nominal).
        torque_scale: factor on every commanded joint torque (> 0).
        torque_limits: (3,) saturation of the abduction, hip and knee torques after the scale
            [N·m] (> 0), or None.
        latency_steps: physics steps (1 ms each) between a torque command and its effect (≥ 0).
        joint_damping: viscous joint damping [N·m·s/rad] (≥ 0).
        joint_friction: Coulomb joint friction [N·m] (≥ 0).
        noise_pos, noise_rpy, noise_vel, noise_omega, noise_q, noise_dq: standard deviations of
            the sensor noise on base position [m], orientation [rad], linear velocity [m/s],
            angular velocity [rad/s], joint positions [rad] and joint velocities [rad/s] (≥ 0).
        push_force: magnitude of the random horizontal pushes [N] (≥ 0; 0: no pushes).
        push_duration: duration of one push [s] (> 0).
        push_interval: mean time between pushes [s] (> 0).
        payload_fraction: extra payload as a fraction of the robot's nominal total mass (≥ 0;
            added to ``payload_mass`` by :meth:`for_robot`).
        push_fraction: extra push magnitude as a fraction of the robot's nominal weight (≥ 0;
            added to ``push_force``).
        joint_friction_fraction: extra Coulomb joint friction as a fraction of the robot's
            largest joint torque limit (≥ 0; added to ``joint_friction``).
    """

    name: str = "nominal"
    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    payload_mass: float = 0.0
    payload_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    friction_scale: float = 1.0
    friction: float | None = None
    restitution: float = 0.0
    torque_scale: float = 1.0
    torque_limits: tuple[float, float, float] | None = None
    latency_steps: int = 0
    joint_damping: float = 0.0
    joint_friction: float = 0.0
    noise_pos: float = 0.0
    noise_rpy: float = 0.0
    noise_vel: float = 0.0
    noise_omega: float = 0.0
    noise_q: float = 0.0
    noise_dq: float = 0.0
    push_force: float = 0.0
    push_duration: float = 0.1
    push_interval: float = 2.0
    payload_fraction: float = 0.0
    push_fraction: float = 0.0
    joint_friction_fraction: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _check(f.name, getattr(self, f.name), "reality"))

    # ------------------------------------------------------------------ views
    def changes(self) -> dict[str, Any]:
        """The fields that differ from the nominal simulator (``name`` left out), JSON-able."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name != "name" and v != f.default:
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @property
    def relative(self) -> bool:
        """Some field is relative to the robot (resolve it with :meth:`for_robot`)."""
        return bool(self.payload_fraction or self.push_fraction or self.joint_friction_fraction)

    def for_robot(self, mass: float, torque_limit: float) -> "Reality":
        """This profile in absolute units for a robot of nominal total ``mass`` [kg] and
        largest joint torque limit ``torque_limit`` [N·m]: the relative fields added to
        ``payload_mass``, ``push_force`` and ``joint_friction`` and set to 0 (the same
        Reality when none is set)."""
        if not self.relative:
            return self
        return dataclasses.replace(
            self, payload_mass=self.payload_mass + self.payload_fraction * float(mass),
            push_force=self.push_force + self.push_fraction * float(mass) * G,
            joint_friction=self.joint_friction + self.joint_friction_fraction * float(torque_limit),
            payload_fraction=0.0, push_fraction=0.0, joint_friction_fraction=0.0)

    @property
    def is_nominal(self) -> bool:
        """No field differs from the nominal simulator."""
        return not self.changes()

    @property
    def changes_body(self) -> bool:
        """Masses, inertias or a payload differ (the URDF is rewritten)."""
        return (self.mass_scale != 1.0 or self.inertia_scale != 1.0 or self.payload_mass > 0.0)

    @property
    def has_noise(self) -> bool:
        return any(getattr(self, k) > 0 for k in _NOISE)

    @property
    def is_random(self) -> bool:
        """Sensor noise or pushes: a part drawn from the seeded generators."""
        return self.has_noise or self.push_force > 0 or self.push_fraction > 0

    @property
    def foot_friction(self) -> float:
        """The foot–ground Coulomb friction coefficient (nominal 1.0)."""
        return self.friction if self.friction is not None else self.friction_scale

    def to_dict(self) -> dict[str, Any]:
        """``{"name": …}`` plus the changed fields (lists for vectors); :meth:`from_dict`
        rebuilds an equal Reality."""
        return {"name": self.name, **self.changes()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "reality", *,
                  also_known: tuple[str, ...] = ()) -> "Reality":
        """The Reality of a dict of fields (:meth:`to_dict`, or a YAML profile's keys without
        ``base``). ``also_known``: keys the caller took out of ``d`` (a file's ``base``), listed
        among the known ones when a key is unknown.

        Raises:
            UsageError: not a mapping, an unknown key or a bad value (one line).
        """
        if not isinstance(d, Mapping):
            raise UsageError(f"{where}: a reality profile must be a mapping of fields, "
                             f"got {type(d).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        for k in d:
            if k not in known:
                raise UsageError(f"{where}: unknown key {k!r} "
                                 f"(known: {', '.join(sorted(known | set(also_known)))})")
        return cls(**{k: _check(k, v, where) for k, v in d.items()})

    @classmethod
    def load(cls, source: "str | os.PathLike | Mapping[str, Any] | Reality | None") -> "Reality":
        """A Reality from a preset name (:data:`PRESETS`), a YAML file, a dict or a Reality
        (None: the nominal simulator).

        Raises:
            UsageError: unknown preset and no such file, bad YAML, an unknown key, a bad value.
        """
        if source is None:
            return cls()
        if isinstance(source, Reality):
            return source
        if isinstance(source, Mapping):
            return cls.from_dict(source)
        if not isinstance(source, (str, os.PathLike)):
            raise UsageError(f"reality must be a preset name, a YAML file or a dict, got {source!r}")
        return cls.from_dict(_resolve(source, ()), where=f"reality {os.fspath(source)}")


_NOISE = ("noise_pos", "noise_rpy", "noise_vel", "noise_omega", "noise_q", "noise_dq")
# field -> (kind, rule); kinds: "f" float, "i" int, "f?" float or None, "v3" 3 floats,
# "v3?" 3 floats or None; the rule applies to every number
_RULES: dict[str, tuple[str, str]] = {
    "mass_scale": ("f", _POS), "inertia_scale": ("f", _POS), "payload_mass": ("f", _NONNEG),
    "payload_offset": ("v3", _ANY), "friction_scale": ("f", _POS), "friction": ("f?", _POS),
    "restitution": ("f", _UNIT), "torque_scale": ("f", _POS), "torque_limits": ("v3?", _POS),
    "latency_steps": ("i", _NONNEG), "joint_damping": ("f", _NONNEG),
    "joint_friction": ("f", _NONNEG), **{k: ("f", _NONNEG) for k in _NOISE},
    "push_force": ("f", _NONNEG), "push_duration": ("f", _POS), "push_interval": ("f", _POS),
    "payload_fraction": ("f", _NONNEG), "push_fraction": ("f", _NONNEG),
    "joint_friction_fraction": ("f", _NONNEG),
}


def _number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _check(key: str, v: Any, where: str) -> Any:
    """``v`` as the type of field ``key`` (float, int, 3-tuple, None), or a one-line UsageError."""
    if key == "name":
        if not isinstance(v, str) or not v.strip():
            raise UsageError(f"{where}: name must be a non-empty string, got {v!r}")
        return v
    from latentune.yamltext import exponent_float  # PyYAML only when a Reality is made

    kind, rule = _RULES[key]
    if v is None and kind.endswith("?"):
        return None
    v = [exponent_float(x) for x in v] if isinstance(v, (list, tuple)) else exponent_float(v)
    if kind.startswith("v3"):
        if isinstance(v, (str, bytes)) or not hasattr(v, "__len__") or len(v) != 3 \
                or not all(_number(x) for x in v):
            raise UsageError(f"{where}: {key} must be 3 numbers, got {v!r}")
        vals = tuple(float(x) for x in v)
    else:
        if not _number(v):
            raise UsageError(f"{where}: {key} must be a number, got {v!r}")
        if kind == "i":
            if not math.isfinite(float(v)) or float(v) != math.floor(float(v)):
                raise UsageError(f"{where}: {key} must be a whole number of steps, got {v!r}")
            v = int(v)
        vals = (float(v),)
    for x in vals:
        ok = math.isfinite(x) and {_POS: x > 0, _NONNEG: x >= 0, _UNIT: 0 <= x <= 1, _ANY: True}[rule]
        if not ok:
            raise UsageError(f"{where}: {key} must be finite and {rule}, got {v!r}"
                             if rule != _ANY else f"{where}: {key} must be finite, got {v!r}")
    if kind.startswith("v3"):
        return vals
    return int(v) if kind == "i" else float(v)


def profile_file(source: Any) -> str | None:
    """The absolute path of the YAML file a reality ``source`` names (the path as given,
    made absolute; symlinks kept), or None: a preset name, a dict, a Reality, None."""
    if not isinstance(source, (str, os.PathLike)):
        return None
    text = os.fspath(source)
    if text in preset_names() and os.sep not in text and not Path(text).suffix:
        return None
    return os.path.abspath(text)


def _resolve(source: str | os.PathLike, seen: tuple[str, ...]) -> dict[str, Any]:
    """The merged field dict of a preset or file, its ``base`` profiles first."""
    text = os.fspath(source)
    path = Path(text)
    is_preset = text in preset_names() and os.sep not in text and not path.suffix
    if is_preset:
        path = PRESET_DIR / f"{text}.yaml"
    elif not path.is_file():
        raise UsageError(f"unknown reality {text!r}: not a preset ({', '.join(preset_names())}) "
                         "and no such file")
    where = f"reality {text}"
    key = str(path.resolve())
    if key in seen:
        raise UsageError(f"{where}: its base profiles include itself")
    import yaml

    from latentune import yamltext

    try:
        raw = yamltext.load(path.read_text())
    except OSError as exc:
        raise UsageError(f"{where}: cannot read ({exc.strerror})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise UsageError(f"{where}: malformed YAML ({yamltext.problem(exc)})") from None
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise UsageError(f"{where}: a reality profile must be a mapping of fields, "
                         f"got {type(raw).__name__}")
    raw = dict(raw)
    bases = raw.pop("base", [])
    bases = [bases] if isinstance(bases, str) else bases
    if not isinstance(bases, list) or not all(isinstance(b, str) for b in bases):
        raise UsageError(f"{where}: base must be a preset name or file, or a list of them")
    if not is_preset and not bases and not set(raw) - {"name"}:   # a user's file: a change
        known = {f.name for f in dataclasses.fields(Reality)} | {"base"}
        raise UsageError(f"{where}: the file sets no field, so it would change nothing "
                         f"(known: {', '.join(sorted(known))}); for the unchanged simulator, "
                         "leave the reality out or name the preset nominal")
    merged: dict[str, Any] = {}
    for b in bases:
        bpath = b if b in preset_names() or os.path.isabs(b) else str(path.parent / b)
        if b not in preset_names() and not Path(bpath).is_file():
            raise UsageError(f"{where}: base {b!r} is neither a preset "
                             f"({', '.join(preset_names())}) nor a file")
        merged.update(_resolve(bpath, seen + (key,)))
    merged.pop("name", None)
    Reality.from_dict(raw, where, also_known=("base",))  # the file's own keys, with its name
    merged.update(raw)
    merged.setdefault("name", path.stem)
    return merged


# ---------------------------------------------------------------------------- URDF
def perturbed_urdf(urdf: str, reality: Reality) -> str:
    """Path of a copy of ``urdf`` with the body perturbations of ``reality``: every
    ``<mass>`` × ``mass_scale``, every ``<inertia>`` × ``mass_scale · inertia_scale``, and a
    ``payload_mass`` link (a 0.1 m cube's inertia, no collision) fixed to the root link at
    ``payload_offset`` [m]. Relative mesh paths become absolute. ``urdf`` itself when the body
    is unchanged. Cached in the temp directory under a hash of the text and the perturbation.
    """
    if not reality.changes_body:
        return urdf
    import xml.etree.ElementTree as ET

    src = Path(urdf)
    text = src.read_text()
    body = (reality.mass_scale, reality.inertia_scale, reality.payload_mass, reality.payload_offset)
    key = hashlib.sha1((text + repr(body) + str(src.parent) + _URDF_VERSION).encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / "latentune_urdf" / f"{src.stem}_reality_{key}.urdf"
    if out.is_file():
        return str(out)
    from latentune.robots.urdf import read_urdf

    root_link = read_urdf(urdf).root
    tree = ET.ElementTree(ET.fromstring(text))
    robot = tree.getroot()
    for el in robot.iter():
        fn = el.get("filename")
        if fn and not fn.startswith(("package://", "/", "file://")):
            el.set("filename", str((src.parent / fn).resolve()))
    ms, ins = reality.mass_scale, reality.mass_scale * reality.inertia_scale
    for link in robot.findall("link"):
        mass = link.find("inertial/mass")
        if mass is not None:
            mass.set("value", repr(float(mass.get("value", "0")) * ms))
        inertia = link.find("inertial/inertia")
        if inertia is not None:
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                if inertia.get(k) is not None:
                    inertia.set(k, repr(float(inertia.get(k)) * ins))
    if reality.payload_mass > 0:
        m = reality.payload_mass
        i = repr(m * (0.1 ** 2 + 0.1 ** 2) / 12.0)
        xyz = " ".join(repr(x) for x in reality.payload_offset)
        link = ET.SubElement(robot, "link", name=PAYLOAD_LINK)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz=xyz, rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=repr(m))
        ET.SubElement(inertial, "inertia", ixx=i, iyy=i, izz=i, ixy="0", ixz="0", iyz="0")
        joint = ET.SubElement(robot, "joint", name=PAYLOAD_LINK + "_joint", type="fixed")
        ET.SubElement(joint, "parent", link=root_link)
        ET.SubElement(joint, "child", link=PAYLOAD_LINK)
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, ET.tostring(tree.getroot(), encoding="unicode"))
    return str(out)


# ---------------------------------------------------------------------------- runtime
class RealityRuntime:
    """The engine-independent, per-step part of a reality: the motor (latency, torque scale,
    limits), the sensor noise and the push schedule, with their seeded generators.

    Args:
        reality: the profile.
        seed: the world's seed; the noise and push generators restart from it at :meth:`reset`.
        dt: physics step [s].
    """

    def __init__(self, reality: Reality, seed: int, dt: float):
        self.reality = reality
        self.seed = int(seed)
        self.dt = dt
        r = reality
        self.limits = None if r.torque_limits is None else np.tile(r.torque_limits, 4)
        self.noise = np.array([r.noise_pos, r.noise_rpy, r.noise_vel, r.noise_omega,
                               r.noise_q, r.noise_dq])
        self.push_steps = max(1, int(round(r.push_duration / dt)))
        self.reset()

    def reset(self) -> None:
        """Restart the generators from the seed, empty the latency queue, no push under way."""
        self.rng_noise = np.random.default_rng([self.seed, 1])
        self.rng_push = np.random.default_rng([self.seed, 2])
        self.queue: deque[np.ndarray] = deque()    # the commands sent, at most latency + 1
        self.step_no = 0
        self.push_start = self._next_push(0)
        self.push_dir = np.zeros(3)

    @property
    def passthrough(self) -> bool:
        """The motor changes nothing (no latency, scale or limits)."""
        r = self.reality
        return r.latency_steps == 0 and r.torque_scale == 1.0 and r.torque_limits is None

    def motor(self, tau: np.ndarray) -> np.ndarray:
        """The (12,) torques [N·m] acting this step for the command ``tau`` sent now: the
        command of ``latency_steps`` steps ago (the first command stands in for the ones before
        it), × ``torque_scale``, clipped to ``torque_limits``."""
        r = self.reality
        tau = np.asarray(tau, dtype=float)
        if r.latency_steps:      # no copies of the first command: a latency may exceed the run
            self.queue.append(tau.copy())
            tau = self.queue.popleft() if len(self.queue) > r.latency_steps else self.queue[0]
        if r.torque_scale != 1.0:
            tau = tau * r.torque_scale
        if self.limits is not None:
            tau = np.clip(tau, -self.limits, self.limits)
        return tau

    def observe(self, s: Any) -> Any:
        """The controller's view of the true state ``s`` (a RobotState): ``s`` itself without
        noise, else a noisy copy (orientation: ``s``'s rotation turned by a random rotation
        vector of std ``noise_rpy`` [rad], world frame)."""
        if not np.any(self.noise):
            return s
        sd = self.noise
        g = self.rng_noise
        pos = s.pos + g.normal(0.0, sd[0], 3)
        quat = _rotate_quat(s.quat, g.normal(0.0, sd[1], 3))
        vel = s.vel + g.normal(0.0, sd[2], 3)
        omega = s.omega + g.normal(0.0, sd[3], 3)
        q = s.q + g.normal(0.0, sd[4], len(s.q))
        dq = s.dq + g.normal(0.0, sd[5], len(s.dq))
        out = RobotState(pos, quat, vel, omega, q, dq, s.up_z, s.finite, s._RT)
        out.up_z = float(out.R[2, 2])
        return out

    def _next_push(self, after: int) -> int | None:
        r = self.reality
        if r.push_force <= 0:
            return None
        return after + max(1, int(round(self.rng_push.exponential(r.push_interval) / self.dt)))

    def push(self) -> np.ndarray | None:
        """The (3,) world-frame push force [N] on the base's centre of mass for the coming
        step, or None; advances the step counter."""
        n = self.step_no
        self.step_no += 1
        start = self.push_start
        if start is None or n < start:
            return None
        if n == start:
            a = self.rng_push.uniform(0.0, 2.0 * np.pi)
            self.push_dir = np.array([math.cos(a), math.sin(a), 0.0])
        if n >= start + self.push_steps - 1:
            self.push_start = self._next_push(start + self.push_steps)
        return self.reality.push_force * self.push_dir


def _rotate_quat(quat: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of the rotation ``exp(rotvec) · quat`` (rotvec: world frame [rad])."""
    ang = float(np.linalg.norm(rotvec))
    if ang < 1e-15:
        return np.array(quat, dtype=float)
    ax = rotvec / ang
    s = math.sin(0.5 * ang)
    bx, by, bz, bw = ax[0] * s, ax[1] * s, ax[2] * s, math.cos(0.5 * ang)
    x, y, z, w = quat
    return np.array([bw * x + bx * w + by * z - bz * y,
                     bw * y - bx * z + by * w + bz * x,
                     bw * z + bx * y - by * x + bz * w,
                     bw * w - bx * x - by * y - bz * z])
