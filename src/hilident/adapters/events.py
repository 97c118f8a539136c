"""The run-event vocabulary, kept importable here: it lives in :mod:`hilident.events` (pure, shared with the
recording)."""

from hilident.events import FAULT_KINDS, Kind, RunEvent

__all__ = ["FAULT_KINDS", "Kind", "RunEvent"]
