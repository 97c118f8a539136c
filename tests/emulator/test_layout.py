"""The emulator package's layout: no module imports another that imports it back, and no adapter is imported."""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import hilident.emulator

PACKAGE = "hilident.emulator"
ROOT = Path(hilident.emulator.__file__).parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join((PACKAGE, *parts))


@cache
def _imports(path: Path, name: str) -> frozenset[str]:
    """Every module ``path`` imports, at any depth of the file (function-level imports too)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)  # ``from package import module``
    return frozenset(found)


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in ROOT.rglob("*.py")}
    return {name: {m for m in _imports(path, name) if m in modules and m != name} for name, path in modules.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` (its modules in order), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)) is not None:
                return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)) is not None:
            return found
    return None


def test_the_emulator_package_has_no_import_cycle():
    graph = _graph()
    assert f"{PACKAGE}.canopen.firmware" in graph and f"{PACKAGE}.factory" in graph  # the walk sees the package
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_only_the_factory_imports_the_transports_servers_and_nothing_imports_the_factory():
    graph = _graph()
    for name, imported in graph.items():
        assert f"{PACKAGE}.factory" not in imported, name
        servers = {m for m in imported if m.endswith(".server")}
        transport = name.rsplit(".", 1)[0]
        assert all(name == f"{PACKAGE}.factory" or m.startswith(transport + ".") for m in servers), (name, servers)


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_the_emulator_never_imports_an_adapter():
    for path in ROOT.rglob("*.py"):
        assert not any(m.startswith("hilident.adapters") for m in _imports(path, _module_name(path))), path
