"""The house: no import circle; model, world, collision and its fast layer stand on each other in that order; the core
free of the simulator, the benches and plotting; nobody asks which checker it holds or reads another object's private
attributes; tests through public APIs only. Read from the sources' own code (ast), as a reviewer would."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import ROOT

PACKAGES = {"replanner": ROOT / "replanner", "replanner_services": ROOT / "services"}
NOT_CORE = ("replanner.sim", "replanner.bench", "replanner.apps")
FLOORS = ("replanner.model", "replanner.world", "replanner.collision", "replanner.collision.fast")  # ground floor first
CHECKERS = {"CollisionChecker", "FastChecker"}
STDLIB_PRIVATE = {"os._exit", "sys._current_frames"}  # documented names of the standard library
FORBIDDEN_IN_CORE = ("pybullet", "matplotlib", *NOT_CORE, "replanner_services")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg, root in PACKAGES.items():
        for path in root.rglob("*.py"):
            parts = [pkg, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Modules (of `known`, or external top-level names) that `name` imports anywhere in its source."""
    found = set()
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            found.add(target)
            found.update(f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in known)
    return found


def _graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    mods = _modules()
    known = set(mods)
    internal, everything = {}, {}
    for name, path in mods.items():
        imported = _imports(name, path, known)
        everything[name] = imported
        internal[name] = {m for m in imported if m in known and m != name}
    return internal, everything


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def _is_package_face(name: str) -> bool:
    """A package's __init__ re-exports its modules: importing it is importing them, not a loop."""
    return _modules()[name].name == "__init__.py"


def test_no_import_circle():
    graph, _ = _graph()
    # a package's face imports its own modules; a module importing a sibling through the face is the same arrow
    faceless = {
        m: {d for d in deps if not (_is_package_face(d) and m.startswith(d + "."))} for m, deps in graph.items()
    }
    assert _cycles(faceless) == []


def _floor(module: str) -> int | None:
    """The highest of FLOORS that holds `module` (None: another room)."""
    found = None
    for i, room in enumerate(FLOORS):
        if module == room or module.startswith(room + "."):
            found = i
    return found


def test_model_world_collision_and_fast_import_downward_only():
    graph, _ = _graph()
    floors = {m: f for m in graph if (f := _floor(m)) is not None}
    up = sorted(f"{m} -> {d}" for m, f in floors.items() for d in graph[m] if (g := _floor(d)) is not None and g > f)
    assert up == []
    assert set(floors.values()) == set(range(len(FLOORS)))  # every floor has modules: the check saw them


def _library_trees():
    for root in PACKAGES.values():
        for path in sorted(root.rglob("*.py")):
            yield path, ast.parse(path.read_text())


def test_the_library_reads_no_private_attribute_of_another_object():
    private = []
    for path, tree in _library_trees():
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                if not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
                    if ast.unparse(node) not in STDLIB_PRIVATE:
                        private.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    assert private == []


def test_no_code_asks_which_checker_it_holds():
    """The exact and the fast checker answer one protocol (collision/checker.py): only the checkers know their kind."""
    asked = []
    for path, tree in _library_trees():
        if path.is_relative_to(ROOT / "replanner" / "collision"):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance":
                names = {n.id if isinstance(n, ast.Name) else getattr(n, "attr", "") for n in ast.walk(node.args[1])}
                if names & CHECKERS:
                    asked.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    assert asked == []


def test_the_core_imports_neither_the_sim_nor_the_benches_nor_plotting():
    _, imports = _graph()
    core = [m for m in imports if m.startswith("replanner") and not m.startswith((*NOT_CORE, "replanner_services"))]
    bad = {
        m: sorted(i for i in imports[m] if any(i == f or i.startswith(f + ".") for f in FORBIDDEN_IN_CORE))
        for m in core
    }
    assert {m: b for m, b in bad.items() if b} == {}
    assert len(core) > 30  # the check saw the core


def test_tests_use_public_apis_only():
    private = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                if not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
                    private.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("replanner"):
                private += [f"{path.name}:{node.lineno}: import {a.name}" for a in node.names if a.name.startswith("_")]
    assert private == []
