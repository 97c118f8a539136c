"""JSON Schemas shipped with hilident: ``summary.schema.json`` (draft 2020-12) describes ``summary.json``.

Examples
--------
>>> summary_schema()["$schema"]
'https://json-schema.org/draft/2020-12/schema'

Data only; imports nothing of hilident.
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

__all__ = ["summary_schema"]


def summary_schema() -> dict[str, Any]:
    """The JSON Schema of ``summary.json`` of ``run``, ``identify`` and ``upload``, units in each description."""
    return json.loads(resources.files(__name__).joinpath("summary.schema.json").read_text(encoding="utf-8"))
