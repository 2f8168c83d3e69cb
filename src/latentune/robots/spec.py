"""Robot specifications: what the actors and the simulator need to know about a quadruped.

A :class:`RobotSpec` names a URDF, the 12 actuated joints in leg order FR, FL, RR, RL (hip
abduction, hip flexion, knee per leg), the four foot links, the nominal stance and per-gait
fixed timing. Mass, inertia, hip offsets and foot positions are measured from the URDF
(:class:`~latentune.robots.model.RobotModel`), so they are not spec fields.

A spec is a YAML file read by :func:`load_spec_file`; the built-in robots (:data:`BUILTIN`) are
the files ``specs/<name>.yaml`` of this package. The ``urdf`` field is a path (absolute, or
relative to the YAML file) or ``{package: <name>, path: <path inside the package>}`` for a URDF
shipped by an installed package (``pybullet_data``, ``example-robot-data``). ``base: <built-in
name>`` starts from a built-in robot and overrides only the fields given (in ``gaits``, only
the gaits and gait fields given); without ``name:`` it is named by its file's stem, never as its
base. Units: SI (m, s, rad,
N·m); angles of ``max_tilt_deg`` in degrees.

Every load checks the spec against its URDF (:mod:`latentune.robots.inspection`: joint and foot names,
leg order against the geometry, collision shapes of the feet) and fills ``nominal_height``,
``torque_limits`` and ``strip_root`` when they are omitted; a problem is a one-line
:class:`~latentune.errors.RobotSpecError` naming the file.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import math
import os
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from latentune.errors import RobotSpecError
from latentune.robots.inspection import LEGS  # noqa: F401 - the leg order, re-exported
from latentune.robots.urdf import CollisionShape, package_dir

TROT_OFFSETS = (0.0, 0.5, 0.5, 0.0)
JUMP_OFFSETS = (0.0, 0.0, 0.0, 0.0)


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
        nominal_height: base link height when standing at ``nominal_q`` on flat ground [m]
            (default: from forward kinematics, ``foot_radius`` − mean foot z).
        torque_limits: (3,) max |τ| for (abduction, hip, knee) [N·m] (default: the URDF's
            ``<limit effort>``, the smallest of the four legs).
        kp, kd: (3,) joint PD gains for swing legs [N·m/rad, N·m·s/rad].
        foot_radius: contact sphere radius [m].
        gaits: gait name -> :class:`GaitParams`.
        strip_root: remove the URDF's root link, a massless dummy fixed to the real base
            (PyBullet would zero its inertia and warn); default: true iff the root is one.
        primitive_collisions: replace collision meshes by ``collision_primitives`` (faster
            stepping).
        raibert_gain: swing foot placement gain on the velocity error [s].
        mu: friction coefficient used by the MPC friction pyramid.
        max_tilt_deg: base tilt beyond which the robot counts as fallen [deg].
        collision_primitives: link-name suffix -> :class:`CollisionShape`; a link whose name
            ends with no key loses its collision shapes (used with ``primitive_collisions``).
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
    collision_primitives: dict[str, CollisionShape] = field(default_factory=dict)

    def gait(self, name: str) -> GaitParams:
        if name not in self.gaits:
            raise RobotSpecError(f"robot {self.name!r} has no gait {name!r} (has: {', '.join(self.gaits)})")
        return self.gaits[name]

    def to_dict(self) -> dict[str, Any]:
        """Every field as JSON-able values (lists for tuples, ``urdf`` as an absolute path);
        :func:`spec_from_dict` is the inverse."""
        d: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            d[f.name] = list(v) if isinstance(v, tuple) else v
        d["urdf"] = str(Path(self.urdf).resolve())
        d["gaits"] = {k: {"period": g.period, "duty": g.duty, "step_height": g.step_height,
                          "offsets": list(g.offsets)} for k, g in self.gaits.items()}
        d["collision_primitives"] = {k: s.to_dict() for k, s in self.collision_primitives.items()}
        return d


# --------------------------------------------------------------------------- built-in robots

SPECS_DIR = Path(str(importlib.resources.files(__package__).joinpath("specs")))
"""Directory of the built-in spec files, inside the installed package."""

BUILTIN: tuple[str, ...] = tuple(sorted(p.stem for p in SPECS_DIR.glob("*.yaml")))
"""Names of the built-in robots (``a1``, ``b1``, ``solo12``)."""


@functools.lru_cache(maxsize=None)
def _builtin(name: str) -> RobotSpec:
    return load_spec_file(SPECS_DIR / f"{name}.yaml")


def _copy(spec: RobotSpec) -> RobotSpec:
    """A spec with its own dicts (a cached spec is never shared mutably)."""
    return dataclasses.replace(spec, gaits=dict(spec.gaits),
                               collision_primitives=dict(spec.collision_primitives))


def get_robot(robot: str | os.PathLike | RobotSpec | Mapping[str, Any]) -> RobotSpec:
    """A robot spec from a built-in name (``a1``, ``b1``, ``solo12``), a spec ``.yaml`` path, a
    :class:`RobotSpec` (returned as is) or a dict of fields (:func:`spec_from_dict`).

    Raises:
        RobotSpecError: unknown name, or a file or dict that is not a valid spec.
    """
    if isinstance(robot, RobotSpec):
        return robot
    if isinstance(robot, Mapping):
        return spec_from_dict(robot)
    if isinstance(robot, str) and robot in BUILTIN:
        return _copy(_builtin(robot))
    return load_spec_file(spec_path(robot))


def spec_path(robot: str | os.PathLike) -> Path:
    """The spec file of a robot argument: a built-in name's own spec, else ``robot`` when it
    names a file (ends in ``.yaml``/``.yml`` or holds a path separator).

    Raises:
        RobotSpecError: any other name (``unknown robot ...``, naming the choices).
    """
    if isinstance(robot, str) and robot in BUILTIN:
        return SPECS_DIR / f"{robot}.yaml"
    path = os.fspath(robot)
    if path.endswith((".yaml", ".yml")) or os.path.sep in path:
        return Path(path)
    raise RobotSpecError(f"unknown robot {path!r} (choose from {', '.join(BUILTIN)} or a spec .yaml)")


def is_builtin(spec: RobotSpec) -> bool:
    """True iff ``spec`` equals (in every field) the built-in robot of the same name."""
    return spec.name in BUILTIN and spec == _builtin(spec.name)


# --------------------------------------------------------------------------- loading and validation

def load_spec_file(path: str | os.PathLike) -> RobotSpec:
    """Read a robot spec from a YAML file (see the module docstring; README, "Custom robots").
    One named as a built-in robot but differing from it warns (it would pass as that robot).

    Raises:
        RobotSpecError: missing file, bad YAML, missing/unknown/ill-typed field, URDF not found,
            a spec that does not fit its URDF (:mod:`latentune.robots.inspection`).
    """
    from latentune.robots.inspection import emit_warning

    p = Path(path)
    where = f"robot spec {p}"
    spec = _build(read_yaml(p), where, p.parent, p.stem)
    clash = builtin_name_clash(spec, p)
    if clash is not None:
        emit_warning(f"{where}: {clash}")
    return spec


def builtin_name_clash(spec: RobotSpec, path: Path) -> str | None:
    """What is wrong with the spec read from the file ``path`` when it gives a built-in
    robot's name but is not that robot (its θ files and results would pass as the built-in's),
    else None (the built-in spec files themselves included)."""
    if spec.name not in BUILTIN or path.resolve().parent == SPECS_DIR.resolve():
        return None
    other = [k for k, v in spec.__dict__.items() if v != getattr(_builtin(spec.name), k)]
    if not other:
        return None
    differ = "differs" if len(other) == 1 else "differ"
    return (f"named {spec.name}, as a built-in robot, but not that robot ({', '.join(other[:4])}"
            f"{', …' if len(other) > 4 else ''} {differ}): its θ files and results pass as the "
            f"built-in {spec.name}'s; give it a name of its own")


def read_yaml(path: Path) -> Any:
    """The parsed YAML of a spec file (numbers in exponent form, ``1e-3``, are floats).

    Raises:
        RobotSpecError: missing file, bad YAML or an empty file.
    """
    import yaml

    from latentune import yamltext

    if not path.is_file():
        raise RobotSpecError(f"robot spec file not found: {path}")
    try:
        raw = yamltext.load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"robot spec {path}: malformed YAML ({yamltext.problem(exc)})") from None
    if raw is None:                 # an empty file (or one of comments only)
        raise RobotSpecError(f"robot spec {path}: the file is empty: it needs the spec's fields "
                             "(README, \"Custom robots\")")
    return raw


def spec_from_dict(d: Mapping[str, Any], base_dir: str | os.PathLike | None = None) -> RobotSpec:
    """The spec of a dict of fields (:meth:`RobotSpec.to_dict`, or the keys of a YAML spec),
    validated like :func:`load_spec_file`. A relative ``urdf`` path is taken relative to
    ``base_dir`` (default: the working directory).

    Raises:
        RobotSpecError: missing/unknown/ill-typed field, URDF not found, a spec that does not
            fit its URDF.
    """
    name = d.get("name", "?") if isinstance(d, Mapping) else "?"
    return _build(d, f"robot spec {name!r}", Path(base_dir) if base_dir is not None else Path.cwd())


_REQUIRED = ("name", "urdf", "joint_names", "foot_links", "nominal_q", "kp", "kd", "foot_radius",
             "gaits")  # nominal_height, torque_limits, strip_root: computed from the URDF if omitted
_FIELDS = frozenset(f.name for f in dataclasses.fields(RobotSpec))
_TUPLES = {"joint_names": (12, str), "foot_links": (4, str), "nominal_q": (12, float),
           "torque_limits": (3, float), "kp": (3, float), "kd": (3, float)}
_POSITIVE_TUPLES = ("torque_limits", "kp", "kd")  # limits and gains: a sign flip or 0 is no robot
_POSITIVE = ("nominal_height", "foot_radius", "raibert_gain", "mu", "max_tilt_deg")
_BOOLS = ("strip_root", "primitive_collisions")
_GAIT_KEYS = {"period", "duty", "step_height", "offsets"}


def _build(raw: Any, where: str, base_dir: Path, stem: str | None = None) -> RobotSpec:
    """Validate a mapping of spec fields and check them against the URDF (``where`` prefixes
    every error and warning message; ``stem``: the spec file's, see :func:`validated_fields`)."""
    from latentune.robots.inspection import emit_warning, inspect_fields

    fields = validated_fields(raw, where, base_dir, stem)
    found = inspect_fields(fields)
    if found.errors:
        raise RobotSpecError(f"{where}: {'; '.join(found.errors)}")
    spec = RobotSpec(**{**fields, **found.filled})
    for w in found.warnings:
        emit_warning(f"{where}: {w}")
    return spec


def validated_fields(raw: Any, where: str, base_dir: Path, stem: str | None = None) -> dict[str, Any]:
    """The fields of a spec mapping, typed and checked on their own (not yet against the URDF);
    ``nominal_height``, ``torque_limits`` and ``strip_root`` may be absent.

    A ``base:`` spec without ``name:`` is named by ``stem`` (its file's stem, ``heavy_a1`` for
    ``heavy_a1.yaml``), never by its base: a changed A1 named ``a1`` would pass as the built-in
    A1 (its θ files, its outputs). Without a stem, or with a built-in robot's, it is refused.

    Raises:
        RobotSpecError: ``where: <problem>``.
    """
    if not isinstance(raw, Mapping):
        raise RobotSpecError(f"{where}: expected a mapping of fields")
    fields = dict(raw)
    if "base" in fields:  # start from a built-in robot and override fields
        base = fields.pop("base")
        if not isinstance(base, str) or base not in BUILTIN:
            raise RobotSpecError(f"{where}: unknown base robot {base!r} (choose from {', '.join(BUILTIN)})")
        if "name" not in fields:
            if stem is None or stem in BUILTIN:
                why = "" if stem is None else f"; its file's stem {stem!r} is a built-in robot's"
                raise RobotSpecError(f"{where}: a spec with base: {base} needs a name of its own "
                                     f"(e.g. name: my_{base}){why}")
            fields["name"] = stem
        start = _builtin(base).to_dict()
        fields = {**start, **fields, "gaits": _over_gaits(start["gaits"], fields.get("gaits"))}
    missing = [k for k in _REQUIRED if k not in fields]
    if missing:
        raise RobotSpecError(f"{where}: missing field(s) {', '.join(missing)}")
    unknown = set(fields) - _FIELDS
    if unknown:
        raise RobotSpecError(f"{where}: unknown field(s) {', '.join(sorted(unknown))} "
                             f"({_meant(sorted(unknown))})")
    fields["urdf"] = _urdf_path(fields["urdf"], where, base_dir)
    try:
        if not isinstance(fields["name"], str) or not fields["name"]:
            raise RobotSpecError(f"{where}: name must be a non-empty string")
        for key, (n, typ) in _TUPLES.items():
            if fields.get(key) is None and key not in _REQUIRED:
                fields.pop(key, None)
                continue
            vals = _sequence(fields[key], key, where)
            if len(vals) != n:
                raise RobotSpecError(f"{where}: {key} needs {n} entries, got {len(vals)}")
            try:
                fields[key] = tuple(typ(v) for v in vals)
            except (TypeError, ValueError):
                raise RobotSpecError(f"{where}: {key} must be a list of {n} numbers, got "
                                     f"{list(vals)}") from None
            if typ is float:
                bad = [v for v in fields[key] if not math.isfinite(v) or (key in _POSITIVE_TUPLES and v <= 0)]
                if bad:
                    kind = "positive finite" if key in _POSITIVE_TUPLES else "finite"
                    raise RobotSpecError(f"{where}: {key} must be {kind} numbers, got {bad[0]:g}")
        if fields.get("nominal_height", 0) is None:
            del fields["nominal_height"]
        for key in _POSITIVE:
            if key in fields:
                v = fields[key]
                try:
                    fields[key] = float(v) if not isinstance(v, bool) else math.nan
                except (TypeError, ValueError):
                    fields[key] = math.nan
                if not math.isfinite(fields[key]) or fields[key] <= 0:
                    raise RobotSpecError(f"{where}: {key} must be a positive number, got {v!r}")
        if fields.get("max_tilt_deg", 0) >= 90:  # up_z < cos(tilt): a robot on its side never fell
            raise RobotSpecError(f"{where}: max_tilt_deg must be below 90 (beyond it a robot on its "
                                 f"side or back does not count as fallen), got {fields['max_tilt_deg']:g}")
        for key in _BOOLS:
            if key in fields and not isinstance(fields[key], bool):
                raise RobotSpecError(f"{where}: {key} must be true or false")
        fields["gaits"] = _gaits(fields["gaits"], where)
        fields["collision_primitives"] = _collision_primitives(fields.get("collision_primitives", {}), where)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, RobotSpecError):
            raise
        raise RobotSpecError(f"{where}: bad value ({exc})") from None
    if fields.get("primitive_collisions") and not fields["collision_primitives"]:
        raise RobotSpecError(f"{where}: primitive_collisions needs collision_primitives "
                             "(link-name suffix -> {box: [x, y, z]} or {sphere: radius})")
    return fields


def _meant(unknown: list[str], names: Collection[str] = _FIELDS) -> str:
    """What unknown spec (or gait) fields were meant to be: 'did you mean X?' for those close
    to one of ``names``, else where the fields are listed."""
    import difflib

    close = [m[0] for k in unknown if (m := difflib.get_close_matches(str(k).lower(), names, n=1))]
    return (f"did you mean {', '.join(close)}?" if close
            else 'the fields: README, "Custom robots"')


def _sequence(v: Any, key: str, where: str) -> tuple:
    if isinstance(v, (str, bytes, Mapping)) or not hasattr(v, "__iter__"):
        raise RobotSpecError(f"{where}: {key} must be a list")
    return tuple(v)


def _urdf_path(urdf: Any, where: str, base_dir: Path) -> str:
    """Absolute path of the ``urdf`` field: a path string, or ``{package, path}``."""
    if isinstance(urdf, Mapping):
        if set(urdf) != {"package", "path"} or not all(isinstance(v, str) for v in urdf.values()):
            raise RobotSpecError(f"{where}: urdf must be a path or {{package: <name>, path: <path>}}")
        try:
            path = package_dir(urdf["package"]) / urdf["path"]
        except RobotSpecError as exc:
            raise RobotSpecError(f"{where}: urdf: {exc}") from None
    elif isinstance(urdf, (str, os.PathLike)):
        path = Path(urdf)
        if not path.is_absolute():
            path = (base_dir / path).resolve()
    else:
        raise RobotSpecError(f"{where}: urdf must be a path or {{package: <name>, path: <path>}}")
    if not path.is_file():
        raise RobotSpecError(f"{where}: URDF not found: {path}")
    return str(path)


def _over_gaits(base: Mapping[str, Any], given: Any) -> Any:
    """A ``base:`` spec's gaits: the base robot's, with the gaits (and, in a gait the base has,
    the gait fields) that ``given`` names overriding them; ``given`` as it is if not a mapping
    (:func:`_gaits` refuses it)."""
    if given is None:
        return dict(base)
    if not isinstance(given, Mapping):
        return given
    out = dict(base)
    for name, g in given.items():
        out[name] = {**base[name], **g} if isinstance(g, Mapping) and name in base else g
    return out


def _gaits(raw: Any, where: str) -> dict[str, GaitParams]:
    if not isinstance(raw, Mapping) or not raw:
        raise RobotSpecError(f"{where}: gaits must map gait names to {{period, duty, step_height}}")
    gaits = {}
    for name, g in raw.items():
        needs = f"{where}: gait {name!r} needs period, duty, step_height (and optional offsets)"
        if not isinstance(g, Mapping):
            raise RobotSpecError(needs)
        unknown = sorted(map(str, set(g) - _GAIT_KEYS))
        if unknown:
            raise RobotSpecError(f"{where}: gait {name!r}: unknown field(s) {', '.join(unknown)} "
                                 f"({_meant(unknown, _GAIT_KEYS)})")
        missing = [k for k in ("period", "duty", "step_height") if k not in g]
        if missing:
            raise RobotSpecError(f"{needs}; missing: {', '.join(missing)}")
        offsets = _sequence(g.get("offsets", TROT_OFFSETS if name == "trot" else JUMP_OFFSETS), "offsets", where)
        nums = {}
        for key in ("period", "duty", "step_height"):
            try:
                if isinstance(g[key], bool):     # float(True) is 1.0: a typo, not a period
                    raise TypeError
                nums[key] = float(g[key])
            except (TypeError, ValueError):
                raise RobotSpecError(f"{where}: gait {name!r}: {key} must be a number, "
                                     f"got {g[key]!r}") from None
        try:
            offs = tuple(float(o) for o in offsets)
        except (TypeError, ValueError):
            raise RobotSpecError(f"{where}: gait {name!r}: offsets must be 4 numbers, "
                                 f"got {list(offsets)}") from None
        gp = GaitParams(nums["period"], nums["duty"], nums["step_height"], offs)
        # offsets are phases in cycles (taken mod 1 by the schedulers): one cycle is [0, 1)
        for key, value, ok, rule in (
                ("period", gp.period, math.isfinite(gp.period) and gp.period > 0, "a positive finite number [s]"),
                ("duty", gp.duty, 0 < gp.duty < 1, "in 0 < duty < 1"),
                ("step_height", gp.step_height, math.isfinite(gp.step_height) and gp.step_height >= 0,
                 "a finite number >= 0 [m]")):
            if not ok:
                raise RobotSpecError(f"{where}: gait {name!r}: {key} must be {rule}, got {value:g}")
        if len(gp.offsets) != 4:
            raise RobotSpecError(f"{where}: gait {name!r}: offsets needs 4 entries (FR, FL, RR, RL), "
                                 f"got {len(gp.offsets)}")
        bad = [o for o in gp.offsets if not 0 <= o < 1]
        if bad:
            raise RobotSpecError(f"{where}: gait {name!r}: offsets must be phases in [0, 1) cycles, "
                                 f"got {bad[0]:g}")
        gaits[str(name)] = gp
    return gaits


def _collision_primitives(raw: Any, where: str) -> dict[str, CollisionShape]:
    if not isinstance(raw, Mapping):
        raise RobotSpecError(f"{where}: collision_primitives must map link-name suffixes to shapes")
    shapes = {}
    for suffix, s in raw.items():
        kinds = [k for k in ("box", "sphere") if isinstance(s, Mapping) and k in s]
        if len(kinds) != 1 or set(s) - {kinds[0], "xyz"}:
            raise RobotSpecError(f"{where}: collision primitive {suffix!r} needs one of box: [x, y, z] "
                                 "or sphere: <radius | foot_radius> (and optional xyz)")
        kind, size = kinds[0], s[kinds[0]]
        if kind == "box":
            size = tuple(float(v) for v in _sequence(size, f"{suffix}.box", where))
        else:
            size = () if size == "foot_radius" else (float(size),)
        xyz = tuple(float(v) for v in _sequence(s.get("xyz", (0.0, 0.0, 0.0)), f"{suffix}.xyz", where))
        if (kind == "box" and len(size) != 3) or len(xyz) != 3 or not all(
                math.isfinite(v) and v > 0 for v in size) or not all(math.isfinite(v) for v in xyz):
            raise RobotSpecError(f"{where}: collision primitive {suffix!r}: box needs 3 positive "
                                 "lengths, sphere a positive radius, xyz 3 finite numbers")
        shapes[str(suffix)] = CollisionShape(kind, size, xyz)
    return shapes
