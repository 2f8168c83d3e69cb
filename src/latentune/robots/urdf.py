"""URDF files: where installed robot packages keep them, their link/joint tree, and the copy
PyBullet and pinocchio load.

:func:`package_dir` locates an installed package's files (``example-robot-data`` ships URDFs
only, under ``site-packages/cmeel.prefix/share/example-robot-data/robots``; any other name is an
importable Python package such as ``pybullet_data``). :func:`read_urdf` parses a URDF into a
:class:`UrdfTree` (links with mass and collision shapes, joints with type, axis and limits) and
raises a one-line :class:`~latentune.errors.RobotSpecError` for a file that is not XML or not a
tree of links and joints. :func:`prepared_urdf` rewrites a spec's URDF for simulation:
``package://`` mesh URIs become absolute paths, a massless dummy root link is removed
(``strip_root``), ``continuous`` joints become ``revolute`` without limits (one configuration
value each, as the leg kinematics expect), a link without ``<inertial>`` gets a negligible one
(:data:`NO_INERTIAL`), ``.dae`` collision meshes are dropped (PyBullet ignores them), and with
``primitive_collisions`` each link's collision shapes (none, one or several, ``.dae`` or not) are
replaced by one: the spec's :class:`CollisionShape` for that link, if any (lengths in metres).
"""
from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import importlib.util
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Protocol

from latentune.atomicfile import write_atomic
from latentune.errors import RobotSpecError

ERD = "example-robot-data"


@dataclass(frozen=True)
class CollisionShape:
    """The collision shape that replaces a link's collision meshes (``primitive_collisions``).

    Attributes:
        kind: ``"box"`` or ``"sphere"``.
        size: box edge lengths (x, y, z) [m]; sphere ``(radius,)`` [m], or ``()`` for a sphere
            of the spec's ``foot_radius``.
        xyz: shape origin in the link frame [m].
    """

    kind: str
    size: tuple[float, ...]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        size: Any = list(self.size) if self.kind == "box" else (self.size[0] if self.size else "foot_radius")
        return {self.kind: size, "xyz": list(self.xyz)}


class UrdfFields(Protocol):
    """The fields of a :class:`~latentune.robots.spec.RobotSpec` that :func:`prepared_urdf`
    reads (read-only: the spec is frozen)."""

    @property
    def name(self) -> str: ...
    @property
    def urdf(self) -> str: ...
    @property
    def strip_root(self) -> bool: ...
    @property
    def primitive_collisions(self) -> bool: ...
    @property
    def collision_primitives(self) -> Mapping[str, CollisionShape]: ...
    @property
    def foot_radius(self) -> float: ...


def erd_robots_dir() -> Path:
    """Directory of example-robot-data's robot descriptions (URDFs ship there, no Python module).

    Raises:
        RobotSpecError: example-robot-data is not installed.
    """
    try:
        dist = importlib.metadata.distribution(ERD)
    except importlib.metadata.PackageNotFoundError:
        raise RobotSpecError(f"package {ERD!r} is not installed") from None
    return Path(dist.locate_file(f"cmeel.prefix/share/{ERD}/robots")).resolve()


def package_dir(package: str) -> Path:
    """Root directory of an installed package's files: example-robot-data's ``robots``
    directory, or the directory of an importable Python package (e.g. ``pybullet_data``).

    Raises:
        RobotSpecError: no such package is installed.
    """
    if package == ERD:
        return erd_robots_dir()
    try:
        found = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        found = None
    if found is None or not found.submodule_search_locations:
        raise RobotSpecError(f"package {package!r} is not installed (give {ERD!r} or an "
                             "importable Python package such as 'pybullet_data')")
    return Path(next(iter(found.submodule_search_locations))).resolve()


MASSLESS = 1e-4
"""A link lighter than this [kg] (or without ``<inertial>``) counts as massless."""

_REWRITE_VERSION = "rewrite-6"  # in the prepared-URDF cache key: bump when the rewrite changes


@dataclass(frozen=True)
class UrdfLink:
    """A ``<link>``: ``mass`` [kg] (None without ``<inertial>``); ``collisions``: one
    ``(geometry tag, attributes)`` per ``<collision>``, e.g. ``("sphere", {"radius": "0.02"})``;
    ``moments``: the ``<inertia>``'s ``ixx``, ``iyy``, ``izz`` [kg·m²] (None without one)."""

    name: str
    mass: float | None
    collisions: tuple[tuple[str, dict[str, str]], ...]
    moments: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class UrdfJoint:
    """A ``<joint>``: type, parent and child link, axis (joint frame), origin xyz [m] and the
    ``<limit>`` attributes as floats (None where absent): effort [N·m], lower/upper [rad]."""

    name: str
    type: str
    parent: str
    child: str
    axis: tuple[float, float, float]
    xyz: tuple[float, float, float]
    effort: float | None
    lower: float | None
    upper: float | None

    @property
    def movable(self) -> bool:
        return self.type in ("revolute", "continuous", "prismatic", "planar", "floating")


@dataclass(frozen=True)
class UrdfTree:
    """The link/joint tree of a URDF file (:func:`read_urdf`).

    Attributes:
        path: the file.
        name: the ``<robot name>``.
        links, joints: by name, in file order.
        root: the one link that is no joint's child.
    """

    path: str
    name: str
    links: dict[str, UrdfLink]
    joints: dict[str, UrdfJoint]
    root: str

    def child_joints(self, link: str) -> list[UrdfJoint]:
        return [j for j in self.joints.values() if j.parent == link]

    def parent_joint(self, link: str) -> UrdfJoint | None:
        return next((j for j in self.joints.values() if j.child == link), None)

    def joints_above(self, link: str) -> list[str]:
        """Names of the joints from the root down to ``link`` (root first)."""
        out = []
        j = self.parent_joint(link)
        while j is not None:
            out.append(j.name)
            j = self.parent_joint(j.parent)
        return out[::-1]

    def links_below(self, link: str) -> list[str]:
        """``link`` and every link under it."""
        out, todo = [], [link]
        while todo:
            name = todo.pop(0)
            out.append(name)
            todo += [j.child for j in self.child_joints(name)]
        return out

    def total_mass(self) -> float:
        return float(sum(link.mass or 0.0 for link in self.links.values()))

    def massless_root(self) -> bool:
        """The root link is a massless dummy fixed to the real base (``strip_root``)."""
        mass = self.links[self.root].mass
        kids = self.child_joints(self.root)
        return (mass is None or mass < MASSLESS) and len(kids) == 1 and kids[0].type == "fixed"

    def base(self, strip_root: bool) -> str:
        """The base link: the root, or its child once a massless root is stripped."""
        if strip_root and self.massless_root():
            return self.child_joints(self.root)[0].child
        return self.root


def _floats(text: str | None, n: int, what: str) -> tuple[float, ...]:
    vals = tuple(float(v) for v in (text or "").split())
    if len(vals) != n:
        raise ValueError(f"{what} needs {n} numbers, got {text!r}")
    return vals


INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
"""The attributes of a URDF ``<inertia>``, all six required by the format (urdfdom)."""


def _check_inertia(el: ET.Element | None, link: str) -> tuple[float, float, float] | None:
    """The moments ``(ixx, iyy, izz)`` of the ``<inertia>`` element (None without one). Raise
    ValueError unless it has all of :data:`INERTIA_KEYS` (PyBullet would take a missing one as
    0, MuJoCo and pinocchio refuse it), as finite numbers, with moments ``ixx``, ``iyy``,
    ``izz`` >= 0 (up to rounding; the products of inertia are not checked further: real URDFs
    carry rounded ones)."""
    if el is None:
        return None
    missing = [k for k in INERTIA_KEYS if el.get(k) is None]
    if missing:
        raise ValueError(f"link {link!r}: <inertia> lacks {', '.join(missing)} (the URDF format "
                         f"requires all six of {', '.join(INERTIA_KEYS)}; write 0 for a product "
                         "of inertia that is zero)")
    v = {k: _number(el.get(k, ""), f"link {link!r}: inertia {k}") for k in INERTIA_KEYS}
    if not all(math.isfinite(x) for x in v.values()):
        raise ValueError(f"link {link!r}: inertia must be finite numbers, got "
                         + ", ".join(f"{k}={x:g}" for k, x in v.items() if not math.isfinite(x)))
    negative = [f"{k}={v[k]:g}" for k in ("ixx", "iyy", "izz") if v[k] < -1e-9]  # -5e-20: rounding
    if negative:
        raise ValueError(f"link {link!r}: inertia moments ixx, iyy, izz must be >= 0 [kg·m²], "
                         f"got {', '.join(negative)}")
    return v["ixx"], v["iyy"], v["izz"]


def _number(text: str, what: str) -> float:
    """``float(text)``, or a ValueError that says ``what`` is not a number."""
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{what} is not a number: {text!r}") from None


def _opt_float(el: ET.Element | None, key: str) -> float | None:
    v = None if el is None else el.get(key)
    return None if v is None else float(v)


def read_urdf(path: str | os.PathLike) -> UrdfTree:
    """The link/joint tree of a URDF file (cached per file path, size and modification time).

    Raises:
        RobotSpecError: one line naming the file: unreadable, empty, not XML, no ``<robot>``,
            no links or joints, a joint naming an undefined link, not one tree, a link's mass
            negative or not finite, an inertia lacking one of its six attributes, not finite or
            with a negative moment.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise RobotSpecError(f"URDF {p}: cannot read ({exc.strerror})") from None
    return _read_urdf(str(p), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _read_urdf(path: str, size: int, mtime_ns: int) -> UrdfTree:
    where = f"URDF {path}"
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise RobotSpecError(f"{where}: cannot read ({exc.strerror})") from None
    if not data.strip():
        raise RobotSpecError(f"{where}: the file is empty")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise RobotSpecError(f"{where}: not XML ({exc})") from None
    if root.tag != "robot":
        raise RobotSpecError(f"{where}: the top element is <{root.tag}>, not <robot>")
    links: dict[str, UrdfLink] = {}
    joints: dict[str, UrdfJoint] = {}
    try:
        for el in root.findall("link"):
            name = el.get("name")
            if not name:
                raise ValueError("a <link> has no name")
            if name in links:
                raise ValueError(f"link {name!r} is defined twice")
            mass_el = el.find("inertial/mass")
            mass = None if mass_el is None else _number(mass_el.get("value", "nan"), f"link {name!r}: mass")
            if mass is not None and not (math.isfinite(mass) and mass >= 0):
                raise ValueError(f"link {name!r}: mass must be a finite number >= 0 [kg], "
                                 f"got {mass_el.get('value')}")
            moments = _check_inertia(el.find("inertial/inertia"), name)
            geoms = (c.find("geometry") for c in el.findall("collision"))
            cols = tuple((g[0].tag, dict(g[0].attrib)) for g in geoms if g is not None and len(g))
            links[name] = UrdfLink(name, mass, cols, moments)
        for el in root.findall("joint"):
            name, typ = el.get("name"), el.get("type")
            if not name or not typ:
                raise ValueError("a <joint> has no name or type")
            if name in joints:
                raise ValueError(f"joint {name!r} is defined twice")
            parent, child = el.find("parent"), el.find("child")
            if parent is None or child is None or not parent.get("link") or not child.get("link"):
                raise ValueError(f"joint {name!r} needs <parent link> and <child link>")
            for end in (parent.get("link"), child.get("link")):
                if end not in links:
                    raise ValueError(f"joint {name!r} names the undefined link {end!r}")
            axis_el, origin_el, lim = el.find("axis"), el.find("origin"), el.find("limit")
            axis = (1.0, 0.0, 0.0) if axis_el is None else _floats(axis_el.get("xyz"), 3, f"joint {name!r} axis")
            xyz = (0.0, 0.0, 0.0) if origin_el is None else \
                _floats(origin_el.get("xyz", "0 0 0"), 3, f"joint {name!r} origin")
            joints[name] = UrdfJoint(name, typ, parent.get("link"), child.get("link"), axis, xyz,
                                     _opt_float(lim, "effort"), _opt_float(lim, "lower"),
                                     _opt_float(lim, "upper"))
    except ValueError as exc:
        raise RobotSpecError(f"{where}: {exc}") from None
    if not links:
        raise RobotSpecError(f"{where}: no <link> elements")
    if not joints:
        raise RobotSpecError(f"{where}: no <joint> elements (a quadruped needs 12 actuated joints)")
    children = [j.child for j in joints.values()]
    twice = sorted({c for c in children if children.count(c) > 1})
    if twice:
        raise RobotSpecError(f"{where}: link {twice[0]!r} is the child of more than one joint")
    roots = [n for n in links if n not in set(children)]
    if len(roots) != 1:
        raise RobotSpecError(f"{where}: the links do not form one tree (root links: "
                             f"{', '.join(roots) if roots else 'none, a joint loop'})")
    tree = UrdfTree(path, root.get("name", ""), links, joints, roots[0])
    unreached = set(links) - set(tree.links_below(tree.root))
    if unreached:
        raise RobotSpecError(f"{where}: the links do not form one tree (a joint loop through "
                             f"{', '.join(sorted(unreached)[:3])})")
    return tree


def _uri_roots(src: Path) -> list[tuple[Path, bool]]:
    """Where ``package://`` URIs of the URDF ``src`` are looked for: (directory, drop the URI's
    package component)."""
    roots: list[tuple[Path, bool]] = []
    try:
        robots = erd_robots_dir()
        roots += [(robots.parent.parent, False), (robots, False)]
    except RobotSpecError:
        pass
    roots.append((src.parent.parent, True))
    return roots


def resolve_mesh(filename: str, src: str | os.PathLike,
                 roots: list[tuple[Path, bool]] | None = None) -> Path | None:
    """The file a mesh ``filename`` of the URDF ``src`` refers to (a ``package://`` URI, a path
    relative to the URDF's directory, or absolute), or None when it does not exist."""
    src = Path(src)
    if filename.startswith("package://"):
        rel = filename[len("package://"):]
        for root, drop_package in (roots if roots is not None else _uri_roots(src)):
            cand = root / (rel.split("/", 1)[-1] if drop_package else rel)
            if cand.is_file():
                return cand
        return None
    cand = Path(filename[len("file://"):] if filename.startswith("file://") else filename)
    cand = cand if cand.is_absolute() else src.parent / cand
    return cand if cand.is_file() else None


def _fix_uris(text: str, src: Path) -> str:
    """Replace ``package://`` mesh URIs, ``file://`` URIs and paths relative to the URDF's
    directory by absolute paths where the file is found (a rewritten copy lives elsewhere)."""
    roots = _uri_roots(src)

    def fix(m: re.Match) -> str:
        if Path(m.group(1)).is_absolute():
            return m.group(0)
        found = resolve_mesh(m.group(1), src, roots)
        return f'filename="{found}"' if found is not None else m.group(0)

    return re.sub(r'filename="([^"]+)"', fix, text)


def _strip_root(text: str, root: str | None = None) -> str:
    """Remove the link ``root`` (default: the first link) if it is (nearly) massless, and the
    fixed joint to the real base (callers check :meth:`UrdfTree.massless_root` first)."""
    name = r"[^\"]+" if root is None else re.escape(root)
    m = re.search(r'<link\s+name="(%s)"\s*(?:/>|>.*?</link>)' % name, text, flags=re.S)
    mass = re.search(r'<mass\s+value="([^"]+)"', m.group(0)) if m else None
    if m and (mass is None or float(mass.group(1)) < MASSLESS):
        root = m.group(1)
        text = text.replace(m.group(0), "", 1)
        text = re.sub(r'<joint[^>]*type="fixed"[^>]*>(?:(?!</joint>).)*?<parent\s+link="%s"\s*/>.*?</joint>'
                      % re.escape(root), "", text, count=1, flags=re.S)
    return text


def _continuous_to_revolute(text: str) -> str:
    """``continuous`` joints as ``revolute`` ones with limits that are never reached (pinocchio
    gives a continuous joint two configuration values; the leg kinematics expect one)."""
    def repl(m: re.Match) -> str:
        body = m.group(0).replace('type="continuous"', 'type="revolute"', 1)
        limit = re.search(r"<limit\b[^>]*?/>", body)
        effort = re.search(r'effort="([^"]*)"', limit.group(0)) if limit else None
        velocity = re.search(r'velocity="([^"]*)"', limit.group(0)) if limit else None
        new = (f'<limit lower="-1e4" upper="1e4" effort="{effort.group(1) if effort else 0}" '
               f'velocity="{velocity.group(1) if velocity else 0}"/>')
        if limit:
            return body.replace(limit.group(0), new, 1)
        return body.replace("</joint>", new + "</joint>", 1)

    return re.sub(r'<joint\b[^>]*type="continuous"[^>]*>.*?</joint>', repl, text, flags=re.S)


NO_INERTIAL_MASS, NO_INERTIAL_MOMENT = 1e-6, 1e-9
"""The mass [kg] and the moment about each axis [kg·m²] of :data:`NO_INERTIAL`."""
NO_INERTIAL = (f'<inertial><mass value="{NO_INERTIAL_MASS!r}"/><inertia ixx="{NO_INERTIAL_MOMENT!r}" '
               f'ixy="0" ixz="0" iyy="{NO_INERTIAL_MOMENT!r}" iyz="0" izz="{NO_INERTIAL_MOMENT!r}"/>'
               '</inertial>')
"""The ``<inertial>`` :func:`prepared_urdf` gives a link without one: negligible (PyBullet gives
such a link 1 kg and 1 kg·m² about each axis; pinocchio and the URDF mean none; a root of mass
0 would be fixed in space in PyBullet)."""

_BARE_LINK = re.compile(r'<link(?=[\s/>])[^>]*?/>|<link(?=[\s>])[^>]*>(?:(?!</link>).)*?</link>',
                        re.S)
"""A ``<link>`` element, empty or not, whatever its attributes and their quotes."""


def _has_bare_link(text: str) -> bool:
    """Whether a ``<link>`` of the URDF text has no ``<inertial>``."""
    return any("<inertial" not in m.group(0) for m in _BARE_LINK.finditer(text))


def _add_inertials(text: str) -> str:
    """Give every ``<link>`` without ``<inertial>`` :data:`NO_INERTIAL`."""
    def repl(m: re.Match) -> str:
        link = m.group(0)
        if "<inertial" in link:
            return link
        if link.endswith("/>"):
            return link[:-2].rstrip() + f">{NO_INERTIAL}</link>"
        return link.replace(">", f">{NO_INERTIAL}", 1)

    return _BARE_LINK.sub(repl, text)


def kinematic_urdf_text(spec_urdf: str | os.PathLike, strip_root: bool) -> str:
    """The URDF text whose kinematics pinocchio and PyBullet see after :func:`prepared_urdf`
    (root stripped, continuous joints revolute); collision and mesh rewrites left out."""
    text = Path(spec_urdf).read_text()
    if strip_root and read_urdf(spec_urdf).massless_root():
        text = _strip_root(text, read_urdf(spec_urdf).root)
    if 'type="continuous"' in text:
        text = _continuous_to_revolute(text)
    return text


def _num(v: float) -> str:
    return f"{v:g}"


def _collision_xml(shape: CollisionShape, foot_radius: float) -> str:
    if shape.kind == "box":
        geom = f'<box size="{" ".join(map(_num, shape.size))}"/>'
    else:
        geom = f'<sphere radius="{_num(shape.size[0] if shape.size else foot_radius)}"/>'
    origin = f'<origin xyz="{" ".join(map(_num, shape.xyz))}" rpy="0 0 0"/>' if any(shape.xyz) else ""
    return f"<collision>{origin}<geometry>{geom}</geometry></collision>"


def _primitive_collisions(text: str, spec: UrdfFields) -> str:
    """Give every link exactly one collision, the shape whose key ends the link's name (also
    where its own were ``.dae`` meshes, already dropped), or none when no key matches."""
    def repl_link(m: re.Match) -> str:
        body, name = m.group(0), m.group(1)
        shape = next((s for suffix, s in spec.collision_primitives.items() if name.endswith(suffix)), None)
        col = "" if shape is None else _collision_xml(shape, spec.foot_radius)
        # in place of the first collision (the others dropped), else before </link>
        body, n = re.subn(r"<collision>.*?</collision>", lambda _: "\0", body, flags=re.S)
        if n:
            return body.replace("\0", col, 1).replace("\0", "")
        return body[:-len("</link>")] + col + "</link>"

    return re.sub(r'<link\s+name="([^"]+)"\s*>.*?</link>', repl_link, text, flags=re.S)


def prepared_urdf(spec: UrdfFields) -> str:
    """Path of a URDF PyBullet and pinocchio can both load, derived from ``spec.urdf``.

    ``spec.urdf`` itself when it needs no change; otherwise a rewritten copy (see the module
    docstring), cached in the temp directory under a hash of the URDF text, the spec fields the
    rewrite uses and the rewrite's version.
    """
    src = Path(spec.urdf)
    text = src.read_text()
    continuous = 'type="continuous"' in text
    bare = _has_bare_link(text)
    if not (spec.strip_root or spec.primitive_collisions or continuous or bare
            or "package://" in text):
        return str(src)
    prims = spec.collision_primitives if spec.primitive_collisions else {}
    # the key hashes the text with its mesh URIs resolved: the same URDF in another place (e.g.
    # another venv's example-robot-data) refers to other mesh files, so it gets its own copy
    text = _fix_uris(text, src)
    key = hashlib.sha1((text + repr((spec.strip_root, spec.primitive_collisions, spec.foot_radius,
                                     sorted(prims.items()))) + _REWRITE_VERSION).encode()).hexdigest()[:12]
    stem = re.sub(r"[^\w-]", "_", spec.name)     # a name is a label: '../x' or 'a/b' no path
    out = Path(tempfile.gettempdir()) / "latentune_urdf" / f"{stem}_{key}.urdf"
    if out.is_file():
        return str(out)

    if spec.strip_root and read_urdf(src).massless_root():  # a massless dummy fixed to the base
        text = _strip_root(text, read_urdf(src).root)
    if continuous:
        text = _continuous_to_revolute(text)
    if bare:
        text = _add_inertials(text)
    # PyBullet does not collide with .dae meshes: drop those collision shapes
    text = re.sub(r'<collision>(?:(?!</collision>).)*?\.dae"(?:(?!</collision>).)*?</collision>', "", text, flags=re.S)
    if spec.primitive_collisions:
        text = _primitive_collisions(text, spec)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, text)
    return str(out)
