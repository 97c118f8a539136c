"""Modules loaded on first use, so a command starts without what it may never need.

``hilident run`` needs the analysis (scipy's signal and statistics modules,
about two seconds to import) only once an experiment is recorded; a run that
is refused, interrupted or stopped by the device ends without ever paying
for it.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_module(name: str) -> ModuleType:
    """The module ``name``, executed on its first attribute access (:class:`importlib.util.LazyLoader`).

    A module already imported is returned as it is.
    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ImportError(f"no module named {name!r}")
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module
