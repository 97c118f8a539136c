"""Argument checks shared by the signal generators.

Every check raises :class:`hilident.errors.ConfigError` whose key is the name of
the offending argument, so a caller that forwards a config value can re-key it.
"""

from __future__ import annotations

import math

from hilident.errors import ConfigError


def finite(key: str, value) -> float:
    """``value`` as a float; it must be finite."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ConfigError(key, f"must be finite, got {value!r}")
    return x


def positive(key: str, value) -> float:
    """``value`` as a float; it must be finite and > 0."""
    x = finite(key, value)
    if x <= 0.0:
        raise ConfigError(key, f"must be positive, got {value!r}")
    return x


def non_negative(key: str, value) -> float:
    """``value`` as a float; it must be finite and >= 0."""
    x = finite(key, value)
    if x < 0.0:
        raise ConfigError(key, f"must not be negative, got {value!r}")
    return x


def integer(key: str, value, low: int, high: int | None = None) -> int:
    """``value`` as an int in ``low..high`` (inclusive); bools and fractions are rejected."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if isinstance(value, bool) or not x.is_integer():
        raise ConfigError(key, f"must be an integer, got {value!r}")
    n = int(x)
    if n < low or (high is not None and n > high):
        span = f"{low}..{high}" if high is not None else f">= {low}"
        raise ConfigError(key, f"must be in {span}, got {n}")
    return n


def below_nyquist(key: str, frequency_hz: float, sample_rate_hz: float) -> float:
    """Check ``frequency_hz`` lies strictly below half of ``sample_rate_hz``."""
    nyquist = 0.5 * sample_rate_hz
    if frequency_hz >= nyquist:
        raise ConfigError(
            key,
            f"must be below the Nyquist frequency {nyquist:g} Hz, got {frequency_hz:g}",
        )
    return frequency_hz


def n_samples(key: str, duration_s: float, sample_rate_hz: float) -> int:
    """Number of samples in ``duration_s`` (rounded); at least one."""
    n = int(round(duration_s * sample_rate_hz))
    if n < 1:
        raise ConfigError(
            key, f"{duration_s:g} s is shorter than one sample at {sample_rate_hz:g} Hz"
        )
    return n
