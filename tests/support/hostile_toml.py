"""TOML text for any value, NaN, infinities and control characters included (hostile-input tests write what a
well-behaved writer would refuse)."""

from __future__ import annotations

import math


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string (control characters escaped, as TOML requires)."""

    def char(c):
        return "\\" + c if c in '"\\' else f"\\u{ord(c):04x}" if ord(c) < 32 or ord(c) == 127 else c

    return '"' + "".join(map(char, text)) + '"'


def toml_value(v) -> str:
    """``v`` as an inline TOML value."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{toml_string(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
