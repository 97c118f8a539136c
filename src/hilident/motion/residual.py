"""Residual vibration after a move, from a recorded load signal, and its reduction between two moves.

The signal is whatever shows the load ringing: the laser's load position
(m), an accelerometer (m/s^2), or -- on a device without a load sensor -- the
cart's following error (m). Over the dwell, the window from the move's end
to ``dwell_s`` later:

* the **final value** is the mean over the last :data:`FINAL_FRACTION` of the
  dwell, and the deviation is the signal minus it (``detrend="final"``, the
  default: a load that settles at an offset, such as a laser reading a
  deflected beam, is measured around where it settles); ``detrend="linear"``
  removes a least-squares line over the dwell instead (a slow creep, such as
  an integrator unwinding, is then not counted as vibration);
* **peak-to-peak** is ``max - min`` of the deviation, **RMS** its root mean square;
* the **first peak** is the largest ``|deviation|`` over the dwell (for a
  decaying vibration, its first swing);
* the **settling time** is the time from the move's end until the deviation
  stays within ``band`` for the rest of the dwell (0 when it never leaves it,
  None when it is still outside at the dwell's end). ``band`` is absolute, in
  the signal's unit; by default ``band_fraction`` of the first peak.

:func:`compare_moves` measures two moves with the same band (the first
move's, by default), so their settling times compare, and gives the reduction
``20 log10(without / with)`` of RMS and peak-to-peak in dB.

Examples
--------
>>> t = np.arange(0.0, 2.0, 1e-3)
>>> ring = np.where(t >= 0.5, 1e-3 * np.exp(-3.0 * (t - 0.5)) * np.cos(2 * np.pi * 20.0 * (t - 0.5)), 0.0)
>>> r = residual_vibration(t, 0.2 + ring, move_end_s=0.5, dwell_s=1.5)
>>> round(r.first_peak * 1e3, 3), round(r.settling_time_s, 2)
(1.0, 0.98)
>>> sorted(r.as_dict())[:3]
['band_m', 'detrend', 'dwell_s']
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.numbers import number

__all__ = [
    "FINAL_FRACTION",
    "MoveComparison",
    "ResidualVibration",
    "compare_moves",
    "reduction_db",
    "residual_vibration",
]

#: Part of the dwell, at its end, averaged for the final value.
FINAL_FRACTION = 0.1
#: Fewest samples a dwell must hold to be measured.
MIN_SAMPLES = 8
DETRENDS = ("final", "linear")


@dataclass(frozen=True)
class ResidualVibration:
    """Residual vibration over one move's dwell.

    Attributes
    ----------
    unit : str
        Suffix of the signal's unit in :meth:`as_dict` keys (``"m"``, ``"mps2"``, ...).
    peak_to_peak : float
        ``max - min`` of the deviation over the dwell, in the signal's unit.
    rms : float
        Root mean square of the deviation over the dwell, in the signal's unit.
    first_peak : float
        Largest ``|deviation|`` over the dwell, in the signal's unit.
    band : float
        Half-width of the settling band, in the signal's unit.
    settling_time_s : float or None
        From the move's end until the deviation stays within ``band``, s; None when it does not within the dwell.
    final_value : float
        Value the deviation is taken from (``detrend="final"``) or the fitted line's value at the dwell's end.
    move_end_s : float
        Time the dwell starts, s (on the signal's time axis).
    dwell_s : float
        Length of the window measured, s.
    detrend : str
        ``"final"`` or ``"linear"``.
    """

    unit: str
    peak_to_peak: float
    rms: float
    first_peak: float
    band: float
    settling_time_s: float | None
    final_value: float
    move_end_s: float
    dwell_s: float
    detrend: str

    def as_dict(self) -> dict[str, float | str | None]:
        """The figures under unit-suffixed keys (``rms_m``, ``settling_time_s``, ...), JSON-ready."""
        u = self.unit
        return {
            f"peak_to_peak_{u}": self.peak_to_peak,
            f"rms_{u}": self.rms,
            f"first_peak_{u}": self.first_peak,
            f"band_{u}": self.band,
            "settling_time_s": self.settling_time_s,
            f"final_value_{u}": self.final_value,
            "move_end_s": self.move_end_s,
            "dwell_s": self.dwell_s,
            "detrend": self.detrend,
        }


@dataclass(frozen=True)
class MoveComparison:
    """The same move without and with the notch, measured with one band.

    Attributes
    ----------
    without, with_notch : ResidualVibration
    rms_reduction_db : float
        ``20 log10(rms_without / rms_with)``, dB (positive: less vibration with the notch; inf when it is 0).
    peak_to_peak_reduction_db : float
        ``20 log10(p2p_without / p2p_with)``, dB.
    """

    without: ResidualVibration
    with_notch: ResidualVibration
    rms_reduction_db: float
    peak_to_peak_reduction_db: float

    def as_dict(self) -> dict:
        """``{"without": {...}, "with_notch": {...}, "rms_reduction_db", "peak_to_peak_reduction_db"}``; an
        infinite reduction is None."""

        def finite(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {
            "without": self.without.as_dict(),
            "with_notch": self.with_notch.as_dict(),
            "rms_reduction_db": finite(self.rms_reduction_db),
            "peak_to_peak_reduction_db": finite(self.peak_to_peak_reduction_db),
        }


def _number(key: str, value, *, positive: bool = False) -> float:
    return number(key, value, minimum=0.0 if positive else -math.inf, strict=positive)


def residual_vibration(
    time_s,
    signal,
    move_end_s: float,
    dwell_s: float,
    *,
    unit: str = "m",
    band: float | None = None,
    band_fraction: float = 0.05,
    detrend: str = "final",
) -> ResidualVibration:
    """Peak-to-peak, RMS and settling time of ``signal`` over the dwell after a move.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Sample times, s, increasing.
    signal : array_like, shape (n,)
        The load signal (laser position, acceleration, following error).
    move_end_s : float
        When the move's set-point reached its end, s (on ``time_s``'s axis).
    dwell_s : float
        Length of the window after ``move_end_s`` that is measured, s (> 0).
    unit : str
        The signal's unit as a key suffix (lower-case letters and digits: ``"m"``, ``"mps2"``).
    band : float, optional
        Half-width of the settling band, in the signal's unit (> 0); default
        ``band_fraction`` times the first peak.
    band_fraction : float
        Fraction of the first peak used when ``band`` is not given (> 0).
    detrend : {"final", "linear"}
        Remove the final value or a least-squares line (see the module docstring).

    Returns
    -------
    ResidualVibration

    Raises
    ------
    DataError
        Arrays of different lengths, not 1-D, times not increasing, NaN in the
        dwell, or fewer than :data:`MIN_SAMPLES` samples in it.
    ConfigError
        A non-positive or non-finite dwell, band or fraction, an unknown detrend, a bad unit (names the key).
    """
    if not isinstance(unit, str) or not re.fullmatch(r"[a-z][a-z0-9]*", unit):
        raise ConfigError("unit", f"must be a unit suffix of lower-case letters and digits (m, mps2), got {unit!r}")
    if detrend not in DETRENDS:
        raise ConfigError("detrend", f"must be one of {DETRENDS}, got {detrend!r}")
    t0 = _number("move_end_s", move_end_s)
    dwell = _number("dwell_s", dwell_s, positive=True)
    fraction = _number("band_fraction", band_fraction, positive=True)
    fixed_band = None if band is None else _number("band", band, positive=True)
    t = np.asarray(time_s, dtype=float)
    y = np.asarray(signal, dtype=float)
    if t.ndim != 1 or y.ndim != 1 or t.shape != y.shape:
        raise DataError(f"time_s and signal must be 1-D of one length, got shapes {t.shape} and {y.shape}")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise DataError("time_s must be strictly increasing")
    # A hair of slack so a dwell of exactly n samples (t0 + dwell landing on a sample) keeps its last one.
    slack = 1e-9 * max(1.0, abs(t0) + dwell)
    inside = (t >= t0 - slack) & (t <= t0 + dwell + slack)
    tw, yw = t[inside], y[inside]
    if tw.size < MIN_SAMPLES:
        raise DataError(
            f"the dwell from {t0:g} s for {dwell:g} s holds {tw.size} samples; at least {MIN_SAMPLES} are needed"
        )
    bad = int(np.count_nonzero(~np.isfinite(yw)))
    if bad:
        raise DataError(
            f"the signal has {bad} NaN or infinite samples in the dwell from {t0:g} s (a laser out of range?)"
        )
    if detrend == "final":
        tail = tw >= tw[-1] - FINAL_FRACTION * (tw[-1] - tw[0])
        final = float(np.mean(yw[tail]))
        dev = yw - final
    else:
        slope, offset = np.polyfit(tw - tw[0], yw, 1)
        dev = yw - (offset + slope * (tw - tw[0]))
        final = float(offset + slope * (tw[-1] - tw[0]))
    first_peak = float(np.max(np.abs(dev)))
    half_width = fixed_band if fixed_band is not None else fraction * first_peak
    outside = np.flatnonzero(np.abs(dev) > half_width)
    if outside.size == 0:
        settling: float | None = 0.0
    elif outside[-1] == dev.size - 1:
        settling = None
    else:
        settling = float(tw[outside[-1] + 1] - t0)
    return ResidualVibration(
        unit=unit,
        peak_to_peak=float(np.max(dev) - np.min(dev)),
        rms=float(np.sqrt(np.mean(dev * dev))),
        first_peak=first_peak,
        band=float(half_width),
        settling_time_s=settling,
        final_value=final,
        move_end_s=t0,
        dwell_s=dwell,
        detrend=detrend,
    )


def reduction_db(without: float, with_notch: float) -> float:
    """``20 log10(without / with_notch)`` in dB: positive when ``with_notch`` is smaller; inf when it is 0.

    Raises
    ------
    DataError
        A negative or non-finite amplitude, or ``without`` 0 (nothing to reduce).

    Examples
    --------
    >>> round(reduction_db(1e-3, 1e-4), 6)
    20.0
    """
    a, b = float(without), float(with_notch)
    if not (math.isfinite(a) and math.isfinite(b)) or a < 0 or b < 0:
        raise DataError(f"amplitudes must be finite and >= 0, got {a!r} and {b!r}")
    if a == 0.0:
        raise DataError("the move without the notch shows no vibration; there is nothing to reduce")
    return math.inf if b == 0.0 else 20.0 * math.log10(a / b)


def compare_moves(
    without: tuple,
    with_notch: tuple,
    dwell_s: float,
    *,
    unit: str = "m",
    band: float | None = None,
    band_fraction: float = 0.05,
    detrend: str = "final",
) -> MoveComparison:
    """Residual vibration of the same move without and with the notch, and the reduction in dB.

    Parameters
    ----------
    without, with_notch : tuple
        ``(time_s, signal, move_end_s)`` of each move.
    dwell_s : float
        Window measured after each move's end, s.
    unit, detrend, band_fraction : see :func:`residual_vibration`.
    band : float, optional
        Settling band for both moves, in the signal's unit; default ``band_fraction``
        of the first peak of the move without the notch.

    Returns
    -------
    MoveComparison

    Raises
    ------
    DataError, ConfigError
        As :func:`residual_vibration`; a move without vibration.
    """
    t_a, y_a, end_a = without
    t_b, y_b, end_b = with_notch
    first = residual_vibration(
        t_a, y_a, end_a, dwell_s, unit=unit, band=band, band_fraction=band_fraction, detrend=detrend
    )
    second = residual_vibration(t_b, y_b, end_b, dwell_s, unit=unit, band=first.band, detrend=detrend)
    return MoveComparison(
        first, second, reduction_db(first.rms, second.rms), reduction_db(first.peak_to_peak, second.peak_to_peak)
    )
