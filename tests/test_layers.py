"""The package is a stack of layers: imports go down the data path, never up, never in a circle.

Every ``import``/``from ... import`` of an ``edofproj`` module anywhere in a source file (function
bodies included) is read with :mod:`ast`. A module may import modules of its own layer or of a
lower one (:data:`LAYERS`, lowest first); no module may reach itself through imports (a cycle),
within a layer or across layers.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[1] / "src" / "edofproj"

#: Layers, lowest first: each entry is a layer's top-level modules and packages of ``edofproj``.
LAYERS = [
    {
        "errors",
        "fileio",
        "outputs",
        "config",
        "net_config",
        "presets",
        "locking",
        "limits",
        "progress",
        "builtin_runs",
        "machine",
        "cpu_tasks",
    },  # foundation
    {"optics"},
    {"doe"},
    {"imaging"},
    {"scenes"},
    {"compensation"},
    {"perceptual"},
    {"metrics"},
    {"fabrication"},
    {"data"},
    {"procams"},
    {"runs"},
    {"training"},
    {"methods"},
    {"evaluation"},
    {"reporting"},
    {"application"},
    {"commands", "cli", "__init__", "__main__"},
]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SOURCE.parent).with_suffix("").parts)
    if parts[-1] == "__init__" and len(parts) > 1:
        parts = parts[:-1]
    return ".".join(parts)


def imported_modules(path: Path) -> set[str]:
    """The ``edofproj`` modules ``path`` imports (a ``from package import name`` that names a
    submodule counts as that submodule)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("edofproj"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("edofproj"):
                continue
            for alias in node.names:
                candidate = f"{target}.{alias.name}"
                relative = Path(*candidate.split("."))
                is_module = (SOURCE.parent / relative).with_suffix(".py").is_file() or (
                    SOURCE.parent / relative
                ).is_dir()
                found.add(candidate if is_module else target)
    found.discard(name)
    return found


def import_graph() -> dict[str, set[str]]:
    return {module_name(path): imported_modules(path) for path in sorted(SOURCE.rglob("*.py"))}


def layer_of(module: str) -> int:
    top = module.split(".")[1] if "." in module else "__init__"
    for index, layer in enumerate(LAYERS):
        if top in layer:
            return index
    raise AssertionError(f"{module}: its top-level name '{top}' is in no layer of LAYERS")


def test_every_module_has_a_layer():
    for module in import_graph():
        layer_of(module)


def test_no_import_goes_up_a_layer():
    upward = [
        f"{a} -> {b}" for a, targets in import_graph().items() for b in sorted(targets) if layer_of(b) > layer_of(a)
    ]
    assert not upward, "imports that go up a layer:\n" + "\n".join(upward)


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in graph:
                continue
            if state.get(target) == 1:
                return stack[stack.index(target) :] + [target]
            if target not in state:
                cycle = visit(target)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_no_circular_imports():
    graph = import_graph()
    # a package's __init__ re-exporting its own submodules is not a loop of meaning
    for module, targets in graph.items():
        graph[module] = {t for t in targets if not module.startswith(t + ".")}
    cycle = find_cycle(graph)
    assert cycle is None, "circular import: " + " -> ".join(cycle)


@pytest.mark.parametrize(
    "graph,expected",
    [
        ({"a": {"b"}, "b": {"c"}, "c": set()}, None),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a", "b", "c", "a"]),
    ],
)
def test_the_cycle_finder_finds_cycles(graph, expected):
    assert find_cycle(graph) == expected
