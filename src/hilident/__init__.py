"""hilident: hardware-in-the-loop DAQ and drive bridge for the lab bench.

The names a script or a notebook needs are here, each loaded on first use
(PEP 562), so ``import hilident`` stays light::

    import hilident

    cfg = hilident.load_config("configs/emulated-gantry.toml")
    summary = hilident.Session(cfg, "runs/gantry").run()
    run = hilident.read_run("runs/gantry/identification.h5")
    again = hilident.identify(None, "runs/gantry/identification.h5", "runs/gantry-offline")

See the documentation's Python API page (docs/api/index.md).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

TYPE_CHECKING = False  # as typing.TYPE_CHECKING (type checkers take it so) without importing typing at every start
if TYPE_CHECKING:
    from typing import Any

    from hilident.config.tables import Config, load_config, parse_config
    from hilident.datafile import Dataset, load_dataset
    from hilident.errors import ConfigError, DataError, DeviceError, HilidentError, UsageError
    from hilident.io.recording import RunData, RunWriter, read_run
    from hilident.progress import Progress
    from hilident.session.offline import identify_recording
    from hilident.session.offline import identify_recording as identify
    from hilident.session.run import Session

#: Public name -> (module, attribute) it is loaded from.
_PUBLIC: dict[str, tuple[str, str]] = {
    "Config": ("hilident.config.tables", "Config"),
    "load_config": ("hilident.config.tables", "load_config"),
    "parse_config": ("hilident.config.tables", "parse_config"),
    "Session": ("hilident.session.run", "Session"),
    "Progress": ("hilident.progress", "Progress"),
    "identify": ("hilident.session.offline", "identify_recording"),
    "identify_recording": ("hilident.session.offline", "identify_recording"),
    "read_run": ("hilident.io.recording", "read_run"),
    "RunData": ("hilident.io.recording", "RunData"),
    "RunWriter": ("hilident.io.recording", "RunWriter"),
    "load_dataset": ("hilident.datafile", "load_dataset"),
    "Dataset": ("hilident.datafile", "Dataset"),
    "HilidentError": ("hilident.errors", "HilidentError"),
    "ConfigError": ("hilident.errors", "ConfigError"),
    "DataError": ("hilident.errors", "DataError"),
    "DeviceError": ("hilident.errors", "DeviceError"),
    "UsageError": ("hilident.errors", "UsageError"),
}

__all__ = [
    "Config",
    "ConfigError",
    "DataError",
    "Dataset",
    "DeviceError",
    "HilidentError",
    "Progress",
    "RunData",
    "RunWriter",
    "Session",
    "UsageError",
    "__version__",
    "identify",
    "identify_recording",
    "load_config",
    "load_dataset",
    "parse_config",
    "read_run",
]


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first access (PEP 562); later accesses find it in the package."""
    try:
        module, attribute = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names (loaded or not) and the module's dunders, without the modules imported for the lazy loading."""
    dunders = {name for name in globals() if name.startswith("__") and name.endswith("__")}
    return sorted(dunders | set(__all__))
