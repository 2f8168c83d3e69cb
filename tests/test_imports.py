"""The import graph of ``src/latentune`` has no cycle, function-level imports included.

Every module is parsed with :mod:`ast`; every ``import`` / ``from … import`` of the package
anywhere in it (module level, inside functions, under ``if TYPE_CHECKING``) is an edge, with
relative names resolved. Importing ``a.b.c`` runs the ``__init__`` of ``a.b`` first, so an edge
to ``a.b.c`` also goes to the packages above it, except those above the importer itself (they
are already being imported when the importer runs). A name read from a package (``from a.b
import X``, ``X`` not a submodule) is an edge to ``a.b``'s ``__init__`` even from inside ``a.b``.
A package attribute loaded on first use through ``importlib.import_module`` of a name from a
table (``latentune`` itself; ``latentune.robots``'s ``check_spec``/``CheckReport``/``init_spec``,
which stand the robot up in :mod:`latentune.sim`) is not an import statement and not an edge;
that loading a robot spec does not import the simulator is checked on its own.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import latentune

PACKAGE_DIR = Path(latentune.__file__).resolve().parent


@dataclass(frozen=True)
class Edge:
    """``source`` imports ``target`` at ``line`` of ``path``."""

    source: str
    target: str
    path: Path
    line: int


def module_names(package_dir: Path) -> dict[str, Path]:
    """Dotted module name → file, for every ``.py`` file under ``package_dir`` (a package's
    ``__init__.py`` is named by the package)."""
    out = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _ancestors(name: str) -> list[str]:
    """``a.b.c`` → ``[a, a.b]``."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def _existing(name: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of ``name`` that is a module (``a.b.X`` with ``X`` a class → ``a.b``)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_edges(package_dir: Path) -> list[Edge]:
    """Every import edge between the modules of the package at ``package_dir``."""
    modules = module_names(package_dir)
    root = package_dir.name
    edges = []
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        own_package = name if is_package else name.rpartition(".")[0]
        own_ancestors = set(_ancestors(name))
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            explicit: list[str] = []
            if isinstance(node, ast.Import):
                explicit = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = own_package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                subs = [f"{module}.{a.name}" for a in node.names if f"{module}.{a.name}" in modules]
                # names that are not submodules are read from the module (a package's __init__)
                explicit = subs + ([module] if len(subs) < len(node.names) else [])
            for target in explicit:
                if target != root and not target.startswith(root + "."):
                    continue
                found = _existing(target, modules)
                if found is None:
                    continue
                implicit = [a for a in _ancestors(found) if a not in own_ancestors]
                for t in [found] + implicit:
                    if t != name:
                        edges.append(Edge(name, t, path, node.lineno))
    return edges


def import_cycles(edges: list[Edge]) -> list[list[Edge]]:
    """The cycles of the graph, as their edges: in each strongly connected component (Tarjan), the
    shortest cycle through each of its modules (each cycle once)."""
    graph: dict[str, dict[str, Edge]] = {}
    for e in edges:
        graph.setdefault(e.source, {}).setdefault(e.target, e)
        graph.setdefault(e.target, {})
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    components.append(sorted(comp))
    cycles: list[list[Edge]] = []
    seen: set[frozenset[Edge]] = set()
    for comp in components:
        members = set(comp)
        for first in comp:  # the shortest cycle through each module of the component
            prev: dict[str, Edge] = {}
            frontier = [first]
            while frontier and first not in prev:
                nxt = []
                for v in frontier:
                    for w, e in sorted(graph[v].items()):
                        if w in members and w not in prev:
                            prev[w] = e
                            nxt.append(w)
                frontier = nxt
            path, v = [], first
            while True:
                e = prev[v]
                path.append(e)
                v = e.source
                if v == first:
                    break
            if frozenset(path) not in seen:
                seen.add(frozenset(path))
                cycles.append(path[::-1])
    return cycles


def describe(cycle: list[Edge], base: Path) -> str:
    """``a → b → a`` with where each import is."""
    names = " → ".join([e.source for e in cycle] + [cycle[0].source])
    where = "; ".join(f"{e.source} imports {e.target} ({e.path.relative_to(base)}:{e.line})"
                      for e in cycle)
    return f"{names}  [{where}]"


def test_latentune_has_no_import_cycle():
    edges = import_edges(PACKAGE_DIR)
    assert len({e.source for e in edges}) > 30  # the parse saw the package
    cycles = import_cycles(edges)
    assert not cycles, "import cycles:\n" + "\n".join(describe(c, PACKAGE_DIR.parent) for c in cycles)


def test_no_module_imports_a_private_name_of_another():
    bad = []
    modules = module_names(PACKAGE_DIR)
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and \
                    (node.module or "").split(".")[0] == "latentune":
                bad += [f"{name} imports {node.module}.{a.name} (line {node.lineno})" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, "\n".join(bad)


def test_robot_specs_load_without_the_simulator():
    """``latentune.sim`` builds on ``latentune.robots``: a spec (and its checks against the URDF)
    loads without importing the simulator; ``check_spec`` loads on first use."""
    code = ("import sys, latentune.robots as r\n"
            "r.get_robot('a1')\n"
            "print(sorted(m for m in sys.modules if m.startswith('latentune.sim')))\n"
            "r.check_spec('a1', simulate=False)\n"
            "print('latentune.robots.check' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[:2] == ["[]", "True"], out.stdout + out.stderr


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root / "latentune"


def test_cycle_finder_sees_function_level_relative_and_package_init_imports(tmp_path):
    """The shape of the robots ↔ sim cycle: a package ``__init__`` re-exports a module whose
    function imports a world, whose module imports the first package (through its ``__init__``)."""
    files = {
        "latentune/__init__.py": "",
        "latentune/robots/__init__.py": "from latentune.robots.check import check\n",
        "latentune/robots/spec.py": "SPEC = 1\n",
        "latentune/robots/check.py": "from . import spec\n\ndef check():\n    from ..sim.world import World\n",
        "latentune/sim/__init__.py": "",
        "latentune/sim/world.py": "from latentune.robots.spec import SPEC\n",
    }
    cycles = import_cycles(import_edges(_write(tmp_path / "a", files)))
    assert [sorted(e.source for e in c) for c in cycles] == \
        [["latentune.robots", "latentune.robots.check", "latentune.sim.world"]]  # once, not thrice
    assert "latentune.robots.check imports latentune.sim.world (latentune/robots/check.py:4)" in \
        describe(cycles[0], tmp_path / "a")

    # the same modules without the function-level import: no cycle
    files["latentune/robots/check.py"] = "from . import spec\n\ndef check():\n    return spec.SPEC\n"
    assert import_cycles(import_edges(_write(tmp_path / "b", files))) == []

    # a name read from the importer's own package __init__, which imports the importer
    files["latentune/robots/spec.py"] = "def spec():\n    from latentune.robots import check_spec\n"
    cycles = import_cycles(import_edges(_write(tmp_path / "c", files)))
    assert {e.source for e in cycles[0]} == {"latentune.robots", "latentune.robots.check",
                                            "latentune.robots.spec"}
