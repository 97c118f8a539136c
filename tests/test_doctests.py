"""Every docstring example in ``src/hilident`` runs and prints what it says."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import hilident

#: Docstrings with examples in ``hilident.ident``, and their examples, when this test was written: fewer means
#: some stopped being collected.
MIN_IDENT_DOCSTRINGS = 22
MIN_IDENT_EXAMPLES = 137


def _module_names() -> list[str]:
    names = [hilident.__name__]
    for info in pkgutil.walk_packages(hilident.__path__, prefix=f"{hilident.__name__}."):
        if not info.name.endswith(".__main__"):  # running it is the command itself
            names.append(info.name)
    return sorted(names)


MODULES = _module_names()


def _docstrings(name: str) -> list[doctest.DocTest]:
    """The docstrings with examples written in module `name` (not those of names it imports)."""
    module = importlib.import_module(name)
    found = doctest.DocTestFinder(exclude_empty=True).find(module, name, globs=vars(module).copy())
    return [test for test in found if test.examples]


@pytest.mark.parametrize("name", MODULES)
def test_examples_in_module_pass(name):
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in _docstrings(name):
        runner.run(test)
    failed, _ = runner.summarize(verbose=False)
    assert failed == 0, f"{failed} docstring example(s) of {name} failed (output above)"


def test_identification_examples_are_collected():
    tests = [test for name in MODULES if name.startswith("hilident.ident.") for test in _docstrings(name)]
    assert len(tests) >= MIN_IDENT_DOCSTRINGS
    assert sum(len(test.examples) for test in tests) >= MIN_IDENT_EXAMPLES
