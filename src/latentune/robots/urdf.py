"""URDF files: where installed robot packages keep them, and the copy PyBullet and pinocchio load.

:func:`package_dir` locates an installed package's files (``example-robot-data`` ships URDFs
only, under ``site-packages/cmeel.prefix/share/example-robot-data/robots``; any other name is an
importable Python package such as ``pybullet_data``). :func:`prepared_urdf` rewrites a spec's URDF
for simulation: ``package://`` mesh URIs become absolute paths, a massless dummy root link is
removed (``strip_root``), ``.dae`` collision meshes are dropped, and with
``primitive_collisions`` each link's collision shapes are replaced by the spec's
:class:`~latentune.robots.spec.CollisionShape` for that link (lengths in metres).
"""
from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from latentune.errors import RobotSpecError

if TYPE_CHECKING:
    from latentune.robots.spec import CollisionShape, RobotSpec

ERD = "example-robot-data"


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


def _fix_uris(text: str, src: Path) -> str:
    """Replace ``package://`` mesh URIs by absolute paths where the file is found."""
    roots: list[tuple[Path, bool]] = []  # (directory, drop the URI's package component)
    try:
        robots = erd_robots_dir()
        roots += [(robots.parent.parent, False), (robots, False)]
    except RobotSpecError:
        pass
    roots.append((src.parent.parent, True))

    def fix(m: re.Match) -> str:
        rel = m.group(1)[len("package://"):]
        for root, drop_package in roots:
            cand = root / (rel.split("/", 1)[-1] if drop_package else rel)
            if cand.is_file():
                return f'filename="{cand}"'
        return m.group(0)

    return re.sub(r'filename="(package://[^"]+)"', fix, text)


def _strip_root(text: str) -> str:
    """Remove the first link if it is (nearly) massless, and the fixed joint to the real base."""
    m = re.search(r'<link\s+name="([^"]+)"\s*(?:/>|>.*?</link>)', text, flags=re.S)
    mass = re.search(r'<mass\s+value="([^"]+)"', m.group(0)) if m else None
    if m and (mass is None or float(mass.group(1)) < 1e-4):
        root = m.group(1)
        text = text.replace(m.group(0), "", 1)
        text = re.sub(r'<joint[^>]*type="fixed"[^>]*>(?:(?!</joint>).)*?<parent\s+link="%s"\s*/>.*?</joint>'
                      % re.escape(root), "", text, count=1, flags=re.S)
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


def _primitive_collisions(text: str, spec: RobotSpec) -> str:
    """In every link, replace each collision by the shape whose key ends the link's name, or
    drop it when no key matches."""
    def repl_link(m: re.Match) -> str:
        body, name = m.group(0), m.group(1)
        shape = next((s for suffix, s in spec.collision_primitives.items() if name.endswith(suffix)), None)
        col = "" if shape is None else _collision_xml(shape, spec.foot_radius)
        return re.sub(r"<collision>.*?</collision>", lambda _: col, body, flags=re.S)

    return re.sub(r'<link\s+name="([^"]+)"\s*>.*?</link>', repl_link, text, flags=re.S)


def prepared_urdf(spec: RobotSpec) -> str:
    """Path of a URDF PyBullet and pinocchio can both load, derived from ``spec.urdf``.

    ``spec.urdf`` itself when it needs no change; otherwise a rewritten copy (see the module
    docstring), cached in the temp directory under a hash of the URDF text and the spec fields
    the rewrite uses.
    """
    src = Path(spec.urdf)
    text = src.read_text()
    if not (spec.strip_root or spec.primitive_collisions or "package://" in text):
        return str(src)
    prims = spec.collision_primitives if spec.primitive_collisions else {}
    key = hashlib.sha1((text + repr((spec.strip_root, spec.primitive_collisions, spec.foot_radius,
                                     sorted(prims.items())))).encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / "latentune_urdf" / f"{spec.name}_{key}.urdf"
    if out.is_file():
        return str(out)

    text = _fix_uris(text, src)
    if spec.strip_root:
        text = _strip_root(text)
    # PyBullet does not collide with .dae meshes: drop those collision shapes
    text = re.sub(r'<collision>(?:(?!</collision>).)*?\.dae"(?:(?!</collision>).)*?</collision>', "", text, flags=re.S)
    if spec.primitive_collisions:
        text = _primitive_collisions(text, spec)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    return str(out)
