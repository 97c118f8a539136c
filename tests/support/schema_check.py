"""summary.json against the JSON Schema shipped in the package."""

from __future__ import annotations

import jsonschema

from hilident.schemas import summary_schema


def schema_errors(summary: dict) -> list[str]:
    """Where ``summary`` breaks ``hilident/schemas/summary.schema.json`` (path: message), empty when it holds."""
    validator = jsonschema.Draft202012Validator(summary_schema())
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message[:200]}" for e in validator.iter_errors(summary)]
