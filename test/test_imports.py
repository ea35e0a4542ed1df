"""The package's import graph: no module imports another that (directly or not) imports it back.

Every ``import`` and ``from ... import`` of ``moseg_ros`` counts, those inside functions and under
``TYPE_CHECKING`` too: an import held apart by being local is still a cycle a reader has to follow.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "moseg_ros"


def module_name(path: Path) -> str:
    """``moseg_ros.a.b`` of ``moseg_ros/a/b.py`` (``moseg_ros.a`` of its ``__init__.py``)."""
    parts = ("moseg_ros",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, modules: set[str]) -> set[str]:
    """The package's modules that the file at ``path`` imports (a name imported from a module counts as that
    module, or as the submodule of that name)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    paths = {module_name(path): path for path in PACKAGE.rglob("*.py")}
    return {name: imported_modules(path, set(paths)) for name, path in paths.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module, or of one that imports itself."""
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        order[node] = low[node] = len(order)
        stack.append(node)
        for target in graph[node]:
            if target not in order:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], order[target])
        if low[node] == order[node]:
            component = []
            while not component or component[-1] != node:
                component.append(stack.pop())
            if len(component) > 1 or node in graph[node]:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in order:
            visit(node)
    return found


class TestCycles:
    def test_finds_a_cycle_through_three_modules_and_none_in_a_chain(self):
        assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
        assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []

    def test_the_package_has_none(self):
        graph = import_graph()
        assert "moseg_ros.pipeline" in graph["moseg_ros.tools.bag_masks"]  # the graph sees the imports
        assert "moseg_ros.config" in graph["moseg_ros.methods.base"]  # TYPE_CHECKING imports count too
        assert cycles(graph) == []

    def test_the_core_imports_nothing_above_it(self):
        graph = import_graph()
        core = {name for name in graph if name.startswith("moseg_ros.core")}
        assert all(target in core for name in core for target in graph[name]), {
            name: graph[name] - core for name in core if graph[name] - core}
