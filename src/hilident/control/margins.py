"""Stability margins and bandwidths of a loop from its frequency response.

The open loop ``L(f)`` on a grid of frequencies is all this module needs: it may
come from a model (a dense grid) or from a measurement (the lines of an
excitation). Every figure is interpolated between grid points, so a sparse grid
gives approximate figures and the caller chooses the grid.

* **Gain margin**: where ``L`` crosses the negative real axis with ``|L| < 1``,
  ``-20 log10 |L|``; the smallest over every such crossing (``inf``: none).
* **Phase margin**: where ``|L|`` crosses 1, the angle from ``L`` to the
  negative real axis, positive when ``L`` lies below it (phase above -180 deg);
  of every crossing, the one where ``L`` lies nearest -1 (the smallest in size: a
  loop around a lightly damped mode may cross 1 again far from -1, where the
  signed angle reads near -180 deg without the loop being near instability).
* **Sensitivity peak** ``Ms``: the largest ``|1 / (1 + L)|``; ``1 / Ms`` is the
  distance from ``L`` to -1 (the modulus margin).
* **Bandwidth**: the first frequency where a closed-loop response falls 3 dB (half its power)
  below its value at the grid's lowest frequency.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["HALF_POWER_DB", "LoopMargins", "bandwidth_hz", "loop_margins"]

#: The "-3 dB" of a bandwidth: half the power, dB.
HALF_POWER_DB = 10.0 * math.log10(2.0)


@dataclass(frozen=True)
class LoopMargins:
    """The margins of one open loop.

    Attributes
    ----------
    gain_margin_db : float
        Smallest gain margin, dB (``inf``: the loop never crosses the negative
        real axis inside the unit circle on the grid).
    gain_margin_hz : float
        Where it is, Hz (NaN when infinite).
    phase_margin_deg : float
        The phase margin of the gain crossover where ``L`` lies nearest -1, degrees (``inf``: ``|L|`` never
        crosses 1).
    crossover_hz : float
        The gain crossover of that phase margin, Hz (NaN when none).
    sensitivity_peak : float
        ``Ms``, the largest ``|1 / (1 + L)|`` on the grid, 1.
    sensitivity_peak_hz : float
        Where it is, Hz.
    """

    gain_margin_db: float
    gain_margin_hz: float
    phase_margin_deg: float
    crossover_hz: float
    sensitivity_peak: float
    sensitivity_peak_hz: float

    @property
    def sensitivity_peak_db(self) -> float:
        """``Ms`` in dB."""
        return 20.0 * math.log10(self.sensitivity_peak)

    def to_dict(self) -> dict:
        """The figures for ``summary.json`` (non-finite values as None)."""
        return {k: (float(v) if math.isfinite(v) else None) for k, v in asdict(self).items()}


def _grid(frequency_hz, response) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(frequency_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    if f.ndim != 1 or f.shape != h.shape or f.size < 2:
        raise ValueError("frequency_hz and the response must be 1-D and of one length >= 2")
    if not (np.all(np.diff(f) > 0) and f[0] > 0):
        raise ValueError("frequency_hz must be positive and increasing")
    keep = np.isfinite(h)
    return f[keep], h[keep]


def _log_interpolate(f0: float, f1: float, t: float) -> float:
    """The frequency a fraction ``t`` of the way from ``f0`` to ``f1`` on a log axis."""
    return float(f0 * (f1 / f0) ** t)


def _phase_crossings(f: np.ndarray, L: np.ndarray) -> list[tuple[float, float]]:
    """``(frequency, |L|)`` where ``L`` crosses the negative real axis."""
    out = []
    im = L.imag
    for i in np.flatnonzero(np.signbit(im[:-1]) != np.signbit(im[1:])):
        t = im[i] / (im[i] - im[i + 1]) if im[i] != im[i + 1] else 0.0
        re = L.real[i] + t * (L.real[i + 1] - L.real[i])
        if re < 0:
            out.append((_log_interpolate(f[i], f[i + 1], t), -re))
    return out


def _gain_crossings(f: np.ndarray, L: np.ndarray) -> list[tuple[float, complex]]:
    """``(frequency, L)`` where ``|L|`` crosses 1, interpolated on log axes."""
    out = []
    logmag = np.log(np.abs(L))
    for i in np.flatnonzero(np.signbit(logmag[:-1]) != np.signbit(logmag[1:])):
        t = logmag[i] / (logmag[i] - logmag[i + 1]) if logmag[i] != logmag[i + 1] else 0.0
        point = L[i] + t * (L[i + 1] - L[i])
        out.append((_log_interpolate(f[i], f[i + 1], t), complex(point / abs(point))))
    return out


def _phase_margin_deg(point: complex) -> float:
    """The signed angle from ``point`` (on the unit circle) to -1: positive below the real axis."""
    angle = math.degrees(math.atan2(point.imag, point.real))
    return 180.0 + angle if angle <= 0 else angle - 180.0


def loop_margins(frequency_hz, open_loop) -> LoopMargins:
    """Gain and phase margins and the sensitivity peak of ``open_loop`` on its grid.

    Parameters
    ----------
    frequency_hz : array_like
        Increasing positive frequencies, Hz.
    open_loop : array_like of complex
        ``L`` at those frequencies; non-finite values are left out.

    Returns
    -------
    LoopMargins

    Examples
    --------
    >>> import numpy as np
    >>> f = np.geomspace(0.1, 100, 4000)
    >>> s = 2j * np.pi * f
    >>> m = loop_margins(f, 20 / (s * (1 + s / 10) * (1 + s / 100)))  # an integrator and two lags
    >>> round(m.crossover_hz, 1), round(m.phase_margin_deg), round(m.gain_margin_db, 1)
    (2.0, 32, 14.8)
    """
    f, L = _grid(frequency_hz, open_loop)
    phase = [(hz, -20.0 * math.log10(mag)) for hz, mag in _phase_crossings(f, L) if mag < 1.0]
    gain = [(hz, _phase_margin_deg(point)) for hz, point in _gain_crossings(f, L)]
    gm_hz, gm = min(phase, key=lambda x: x[1], default=(math.nan, math.inf))
    pm_hz, pm = min(gain, key=lambda x: abs(x[1]), default=(math.nan, math.inf))
    sensitivity = np.abs(1.0 / (1.0 + L))
    peak = int(np.argmax(sensitivity))
    return LoopMargins(gm, gm_hz, pm, pm_hz, float(sensitivity[peak]), float(f[peak]))


def bandwidth_hz(frequency_hz, closed_loop, drop_db: float = HALF_POWER_DB) -> float:
    """The first frequency where ``|closed_loop|`` falls ``drop_db`` (default: to half its power) below its value
    at the lowest frequency.

    Returns
    -------
    float
        Hz, interpolated on log axes; NaN when it never falls that far on the grid.
    """
    f, T = _grid(frequency_hz, closed_loop)
    level = 20.0 * np.log10(np.abs(T) / abs(T[0])) + drop_db
    below = np.flatnonzero(level < 0)
    if below.size == 0:
        return math.nan
    i = int(below[0])
    if i == 0:
        return float(f[0])
    t = level[i - 1] / (level[i - 1] - level[i])
    return _log_interpolate(f[i - 1], f[i], t)
