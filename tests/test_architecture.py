"""The house: no import circle, no module over 500 lines, the core free of the simulator, the benches and plotting;
tests through public APIs only. Read from the sources' own imports (ast), as a reviewer would."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.conftest import ROOT

PACKAGES = {"replanner": ROOT / "replanner", "replanner_services": ROOT / "services"}
NOT_CORE = ("replanner.sim", "replanner.bench", "replanner.apps")
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


def test_no_module_over_500_lines():
    long = {name: n for name, path in _modules().items() if (n := len(path.read_text().splitlines())) > 500}
    assert long == {}


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
