"""The package's import graph, read from the source with ``ast``: no import circle, no module importing another
module's private (``_name``) names, and an engine (``colonlight/``) without CLI or web code.

Every ``import``/``from ... import`` counts, also those inside functions (a lazy import is still a dependency,
and a circle through one is still a knot); ``if TYPE_CHECKING:`` blocks are skipped (they never run).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Source folder -> the name its modules are imported by (cli/ and service/ are installed under other names).
PACKAGES = {"colonlight": "colonlight", "cli": "colonlight_cli", "service": "colonlight_service"}
#: What the engine must never import: the shells and their frameworks.
SHELL_ONLY = ("typer", "click", "fastapi", "starlette", "uvicorn", "rich", "colonlight_cli", "colonlight_service")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT)
    parts = [PACKAGES[rel.parts[0]], *rel.parts[1:]]
    parts[-1] = parts[-1].removesuffix(".py")
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    found = {}
    for folder in PACKAGES:
        for path in sorted((ROOT / folder).rglob("*.py")):
            found[_module_name(path)] = path
    return found


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _walk(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """The imports of a module that can run (not those under ``if TYPE_CHECKING:``)."""
    out: list[ast.Import | ast.ImportFrom] = []
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            todo.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append(node)
        todo.extend(ast.iter_child_nodes(node))
    return out


def _absolute(module: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for _ in range(node.level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{node.module}" if node.module else package


class Graph:
    """Module -> the modules of ours it imports; and every import of a private name from another module."""

    def __init__(self) -> None:
        self.modules = _modules()
        self.edges: dict[str, set[str]] = {m: set() for m in self.modules}
        self.private: list[str] = []
        self.external: dict[str, set[str]] = {m: set() for m in self.modules}
        for module, path in self.modules.items():
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            for node in _walk(tree):
                if isinstance(node, ast.Import):
                    for alias in node.names:
                        self._add(module, alias.name)
                        if any(p.startswith("_") and not p.startswith("__") for p in alias.name.split(".")):
                            self.private.append(f"{module}: import {alias.name}")
                    continue
                target = _absolute(module, path, node)
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    if sub in self.modules:  # ``from . import video``: the submodule itself
                        self._add(module, sub)
                        continue
                    self._add(module, target)
                    name = alias.name
                    if name.startswith("_") and not name.startswith("__") and target != module:
                        self.private.append(f"{module}: from {target} import {name}")

    def _add(self, module: str, target: str) -> None:
        self.external[module].add(target.partition(".")[0])
        # the deepest module of ours that ``target`` names (``colonlight.live.reader`` -> that module)
        while target and target not in self.modules:
            target = target.rpartition(".")[0]
        if target and target != module:
            self.edges[module].add(target)

    def cycles(self) -> list[list[str]]:
        """Every strongly connected component of more than one module (Tarjan), as a sorted list."""
        index: dict[str, int] = {}
        low: dict[str, int] = {}
        stack: list[str] = []
        on_stack: set[str] = set()
        found: list[list[str]] = []

        def visit(v: str) -> None:
            index[v] = low[v] = len(index)
            stack.append(v)
            on_stack.add(v)
            for w in sorted(self.edges[v]):
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
                    found.append(sorted(component))

        for v in sorted(self.edges):
            if v not in index:
                visit(v)
        return found


@pytest.fixture(scope="module")
def graph() -> Graph:
    return Graph()


def test_the_graph_sees_the_tree(graph: Graph) -> None:
    """Guards the other tests: the walk found the packages and their imports (an empty graph has no circle)."""
    assert {"colonlight", "colonlight.pipeline", "colonlight_cli.main", "colonlight_service.app"} <= set(graph.modules)
    assert "colonlight.pipeline" in graph.edges["colonlight_cli.enhance"] | graph.edges["colonlight.batch"]
    assert "typer" in graph.external["colonlight_cli.main"]


def test_no_import_circle(graph: Graph) -> None:
    assert graph.cycles() == []


def test_no_private_name_imported_from_another_module(graph: Graph) -> None:
    assert graph.private == []


def test_the_engine_has_no_cli_or_web_code(graph: Graph) -> None:
    bad = {m: sorted(graph.external[m] & set(SHELL_ONLY)) for m in graph.modules if m.split(".")[0] == "colonlight"}
    assert {m: names for m, names in bad.items() if names} == {}


#: The engine modules a shell may import: the public API, the public modules of defaults and bounds, of the exception
#: types and of the methods' option declaration, and the subpackages' own APIs (each lazy or light).
PUBLIC_ENGINE = {
    "colonlight",
    "colonlight.limits",
    "colonlight.errors",
    "colonlight.methods.options",
    "colonlight.evaluation",
    "colonlight.synth",
    "colonlight.live",
}
#: Deep imports of the shells not yet moved to the public API (issue 15); this list may only shrink.
NOT_YET_PUBLIC: dict[str, set[str]] = {}


def test_the_shells_use_the_public_api(graph: Graph) -> None:
    """cli/ and service/ reach the engine through ``import colonlight`` (and the subpackages' APIs), so that the
    engine's modules can be split and moved without touching the shells: export what a shell needs there."""
    deep = {}
    for module in graph.modules:
        if module.split(".")[0] in ("colonlight_cli", "colonlight_service"):
            targets = {t for t in graph.edges[module] if t.split(".")[0] == "colonlight" and t not in PUBLIC_ENGINE}
            if targets - NOT_YET_PUBLIC.get(module, set()):
                deep[module] = sorted(targets - NOT_YET_PUBLIC.get(module, set()))
    assert deep == {}
