"""The keys of ``summary.json`` (a documented interface, docs/results.md) checked against a recorded layout.

The layouts in ``tests/data/summary_keys/`` were recorded from the summaries
``hilident run``, ``hilident identify`` and ``hilident upload`` wrote before
the summary became typed: the top-level keys in their order, and the keys of
each section whose layout does not depend on the data; ``notes`` (beside
``warnings`` in a run's and an identify's) was added since, a documented change. Set
``HILIDENT_RECORD_SUMMARY_KEYS=1`` to record a layout again (after a
documented change of the interface only).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

LAYOUTS = Path(__file__).resolve().parents[1] / "data" / "summary_keys"

#: Sections whose own keys are fixed by the command (fitted models and measurements vary with the data).
FIXED_SECTIONS = (
    "device",
    "excitation",
    "upload",
    "verification",
    "stream",
    "connect",
    "source",
    "data",
    "friction",
    "command",
)


def layout(summary: dict) -> dict:
    """The top-level keys in order, and the sorted keys of every fixed section that is a table."""
    sections = {name: sorted(summary[name]) for name in FIXED_SECTIONS if isinstance(summary.get(name), dict)}
    return {"keys": list(summary), "sections": sections}


def assert_layout(name: str, summary: dict) -> None:
    """``summary`` has the keys recorded as ``name`` (a run, an identify or an upload of one kind)."""
    path = LAYOUTS / f"{name}.json"
    found = layout(json.loads(json.dumps(summary)))
    if os.environ.get("HILIDENT_RECORD_SUMMARY_KEYS"):
        path.write_text(json.dumps(found, indent=1) + "\n")
    assert found == json.loads(path.read_text()), f"summary.json layout differs from {path.name}"
