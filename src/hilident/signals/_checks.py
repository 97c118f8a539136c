"""Argument checks shared by the signal generators.

Every check raises :class:`hilident.errors.ConfigError` whose key is the name of
the offending argument, so a caller that forwards a config value can re-key it.
"""

from __future__ import annotations

import math
import numbers

from hilident.errors import ConfigError

#: Largest number of samples one generated signal (one experiment) may hold:
#: 2**25 samples are 256 MiB of float64, 2.3 h at 4 kHz. Checked before allocating.
MAX_SAMPLES = 2**25


def show(value) -> str:
    """``value`` as a user reads it: ``nan``, ``1e+308``, ``'text'``, never ``np.float64(nan)``."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, numbers.Integral):
        text = str(int(value))
        return text if len(text) <= 24 else f"an integer of {len(text)} digits"
    if isinstance(value, numbers.Real):
        return repr(float(value))
    if isinstance(value, str):
        return repr(value) if len(value) <= 60 else repr(value[:57]) + f"... ({len(value)} characters)"
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)} items" if len(value) > 8 else "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return f"a table of {len(value)} keys"
    return type(value).__name__


def finite(key: str, value) -> float:
    """``value`` as a float; it must be finite."""
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(key, f"must be a number, got {show(value)}") from None
    if not math.isfinite(x):
        raise ConfigError(key, f"must be finite, got {show(value)}")
    return x


def positive(key: str, value) -> float:
    """``value`` as a float; it must be finite and > 0."""
    x = finite(key, value)
    if x <= 0.0:
        raise ConfigError(key, f"must be positive, got {show(value)}")
    return x


def non_negative(key: str, value) -> float:
    """``value`` as a float; it must be finite and >= 0."""
    x = finite(key, value)
    if x < 0.0:
        raise ConfigError(key, f"must not be negative, got {show(value)}")
    return x


def integer(key: str, value, low: int, high: int | None = None) -> int:
    """``value`` as an int in ``low..high`` (inclusive); bools and fractions are rejected."""
    if isinstance(value, numbers.Integral):
        n = int(value)  # exact, however large
    else:
        try:
            x = float(value)
        except (TypeError, ValueError, OverflowError):
            x = math.nan
        if isinstance(value, bool) or not x.is_integer():
            raise ConfigError(key, f"must be an integer, got {show(value)}")
        n = int(x)
    if isinstance(value, bool):
        raise ConfigError(key, f"must be an integer, got {show(value)}")
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
    """Number of samples in ``duration_s`` (rounded); at least one, at most :data:`MAX_SAMPLES`."""
    exact = duration_s * sample_rate_hz
    if not exact < MAX_SAMPLES + 0.5:  # also inf and nan, before any allocation
        raise ConfigError(key, f"{duration_s:g} s at {sample_rate_hz:g} Hz {too_many(exact)}")
    n = int(round(exact))
    if n < 1:
        raise ConfigError(key, f"{duration_s:g} s is shorter than one sample at {sample_rate_hz:g} Hz")
    return n


def too_many(n: float) -> str:
    """The end of a message refusing ``n`` samples."""
    return f"would take {n:.4g} samples, more than the {MAX_SAMPLES} (2**25) one experiment may hold"


def at_most(key: str, n: float) -> int:
    """``n`` samples as an int; ConfigError keyed ``key`` when above :data:`MAX_SAMPLES`."""
    if not n <= MAX_SAMPLES:
        raise ConfigError(key, too_many(n))
    return int(n)
