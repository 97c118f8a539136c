"""The house keeps its shape: no import cycle, a short top level, and every package says its job.

The layering itself (pure layers, adapters apart from the emulator, nothing importing the command line) is
checked by import-linter's contracts in pyproject.toml (``lint-imports`` in .ci/run); the complexity limit by
xenon. These tests hold what those tools do not.
"""

from __future__ import annotations

import ast
from pathlib import Path

import grimp
import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "hilident"

#: The top level holds the package's entry points and the small pure helpers every layer shares; a module that
#: has a job of its own belongs to a package. Raise it only with a reason.
MAX_TOP_LEVEL_MODULES = 12


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one node of a directed graph (Tarjan, iterative).

    >>> sorted(map(sorted, strongly_connected({"a": {"b"}, "b": {"a", "c"}, "c": set()})))
    [['a', 'b']]
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(component)
    return found


@pytest.fixture(scope="module")
def imports() -> dict[str, set[str]]:
    """Module -> the hilident modules it imports at run time (imports for annotations only left out)."""
    graph = grimp.build_graph("hilident", exclude_type_checking_imports=True)
    return {module: set(graph.find_modules_directly_imported_by(module)) for module in graph.modules}


def test_the_cycle_finder_finds_a_cycle_through_three_modules():
    graph = {"p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a", "p.d"}, "p.d": set(), "p.e": {"p.d"}}
    assert strongly_connected(graph) == [{"p.a", "p.b", "p.c"}]


def test_no_module_of_hilident_takes_part_in_an_import_cycle(imports):
    cycles = [sorted(component) for component in strongly_connected(imports)]
    assert cycles == [], f"import cycles: {cycles}"


def test_the_top_level_holds_at_most_a_dozen_modules():
    top = sorted(p.name for p in SRC.glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, f"{len(top)} modules at the top of src/hilident: {top}"


@pytest.mark.parametrize(
    "package", sorted(str(p.parent.relative_to(SRC.parent)) for p in SRC.rglob("__init__.py")), ids=str
)
def test_every_package_says_its_job(package):
    init = SRC.parent / package / "__init__.py"
    docstring = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
    assert docstring and len(docstring.split()) >= 8, f"{package}/__init__.py has no docstring saying its job"
    if package.count("/") == 1:  # a room of the top level says what it may import, as the contracts hold it
        assert "may import" in docstring.lower() or "imports nothing" in docstring.lower(), (
            f"{package}/__init__.py does not say what the package may import"
        )
