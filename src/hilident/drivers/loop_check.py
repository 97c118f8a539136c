"""``drivers check`` of a CANopen driver's ``[loop]`` table: every object of the cascade against the EDS.

The table is read as ``hilident run`` reads it
(:func:`~hilident.protocol.loop_parameters.parse_loop`); then each object is
looked up in the EDS: it exists, holds a number, the host may read it, and the
host may write it when it holds a gain or a feed-forward term
(:data:`~hilident.protocol.loop_parameters.WRITABLE`). A refusal names the
``[loop]`` key and the object.
"""

from __future__ import annotations

from hilident.errors import ConfigError
from hilident.protocol import eds as E
from hilident.protocol.canopen_objects import NUMERIC_TYPES
from hilident.protocol.loop_parameters import WRITABLE, parse_loop

__all__ = ["loop_problems"]


def loop_problems(data: dict, od, source: str = "") -> list[tuple[str, str]]:
    """The errors of ``data``'s ``[loop]`` (a parsed ``driver.toml``) against the object dictionary ``od``:
    ``(key, text)`` pairs, none when it has no ``[loop]``."""
    try:
        loop = parse_loop(data.get("loop"), source)
    except ConfigError as exc:
        return [(exc.key, exc.message)]
    if loop is None:
        return []
    problems = []
    for name, address in loop.objects.items():
        key = f"loop.{name}.object"
        info = E.object_info(od, address.index, address.subindex)
        if info is None:
            problems.append((key, f"{address} is not in the EDS"))
            continue
        if info.data_type not in NUMERIC_TYPES:
            problems.append((key, f"{address} is {E.type_name(info.data_type)} in the EDS; {name} needs a number"))
        if not E.readable(info.access):
            problems.append((key, f"{address} is {info.access!r} in the EDS; the host reads {name}"))
        if name in WRITABLE and not E.writable(info.access):
            problems.append((key, f"{address} is {info.access!r} in the EDS; the host writes {name}"))
    return problems
