"""The floors of README.md's Layout: imports point down, never round, never private.

Parsed from the source, so imports inside functions count as much as those at the
top of a module: a lazy import is still a dependency.

- No import circle between project modules.
- No module reaches into another's ``_private`` names (``from m import _x`` or
  ``m._x`` on an imported module).
- No arrow from a lower floor to a higher one: fitting does not import export, the
  library does not import its shells.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.contract

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("brdffit", "api")

#: Floors, top to bottom; a module is on the floor of the first prefix it matches.
#: ``brdffit`` itself (the package's lazy facade) is on no floor.
FLOORS = (
    (7, ("brdffit.cli", "brdffit.client", "brdffit.build_programs", "api.routes",
         "api.services", "api.main", "api.deps", "api.errors", "api.limits")),
    (6, ("brdffit.batch", "api")),
    (5, ("brdffit.export", "brdffit.view")),
    (4, ("brdffit.request", "brdffit.selection")),
    (3, ("brdffit.fitting",)),
    (2, ("brdffit.models",)),
    (1, ("brdffit.io", "brdffit.errors", "brdffit.jsonout", "brdffit.runtime",
         "brdffit.extras", "brdffit.executables", "brdffit.exported", "brdffit.outcome",
         "brdffit.child_process", "brdffit.heap")),
)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str, path: Path) -> tuple[set[str], list[str]]:
    """The project modules ``module`` imports, and the private names it reaches."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    targets, private, bound = set(), [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if (t := _resolve(a.name)) is not None:
                    targets.add(t)
                    if a.name in MODULES:
                        bound[a.asname or a.name] = a.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            for a in node.names:
                full = f"{base}.{a.name}"
                t = full if full in MODULES else _resolve(base)
                if t is None:
                    continue
                targets.add(t)
                if full in MODULES:
                    bound[a.asname or a.name] = full
                elif a.name.startswith("_") and not a.name.startswith("__") and t != module:
                    private.append(f"from {base} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in bound and node.attr.startswith("_")
                and not node.attr.startswith("__") and bound[node.value.id] != module):
            private.append(f"{bound[node.value.id]}.{node.attr}")
    targets.discard(module)
    return targets, private


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def floor(module: str) -> int | None:
    for level, prefixes in FLOORS:
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return level
    return None


def test_every_module_has_a_floor():
    assert [m for m in MODULES if floor(m) is None] == ["brdffit"]


def test_no_module_reaches_into_another_modules_private_names():
    reaching = {m: private for m, (_, private) in GRAPH.items() if private}
    assert reaching == {}


def test_imports_point_down_never_up():
    up = sorted(f"{a} (floor {floor(a)}) imports {b} (floor {floor(b)})"
                for a, (targets, _) in GRAPH.items() if floor(a) is not None
                for b in targets if floor(b) is not None and floor(b) > floor(a))
    assert up == []


def test_no_import_circle():
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v][0]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert circles == []


def test_the_checks_see_lazy_imports_and_private_names(tmp_path):
    """The parser sees what the checks are about: an import inside a function, a
    private name taken by ``from``, and one reached through a module."""
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n"
                     "    from brdffit.export import energy\n"
                     "    from brdffit.fitting.pipeline import _secret\n"
                     "    from brdffit.fitting import pipeline\n"
                     "    return pipeline._hidden\n", encoding="utf-8")
    targets, private = _imports("brdffit.fitting.probe", probe)
    assert {"brdffit.export.energy", "brdffit.fitting.pipeline"} <= targets
    assert private == ["from brdffit.fitting.pipeline import _secret",
                       "brdffit.fitting.pipeline._hidden"]
    assert floor("brdffit.fitting.probe") < floor("brdffit.export.energy")
