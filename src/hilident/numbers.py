"""Checks of the numbers a configuration or a pure function is built from, with errors that name the key."""

from __future__ import annotations

import math

from hilident.errors import ConfigError

__all__ = ["finite_or_none", "number"]


def number(key: str, value, *, minimum: float = 0.0, strict: bool = False) -> float:
    """``value`` as a finite float at or above ``minimum`` (above it when ``strict``).

    Raises
    ------
    ConfigError
        Naming ``key``, for a bool, a non-number, a non-finite value or one out of range.
    """
    if isinstance(value, bool):
        raise ConfigError(key, f"must be a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a number, got {value!r}") from None
    if not math.isfinite(x) or (x <= minimum if strict else x < minimum):
        raise ConfigError(key, f"must be {'>' if strict else '>='} {minimum:g} and finite, got {value!r}")
    return x


def finite_or_none(value) -> float | None:
    """``value`` as a float, None when it is missing or not finite: a figure ``summary.json`` gives as null.

    Examples
    --------
    >>> finite_or_none(2), finite_or_none(float("nan")), finite_or_none(None)
    (2.0, None, None)
    """
    return None if value is None or not math.isfinite(float(value)) else float(value)
