"""Causal smoothing and rate reduction of recorded signals.

- :func:`rc_lowpass`: the first-order RC low-pass of thesis section 2.8 (eqs.
  2.64-2.67) and of the lecture ("Filter is a First Order System",
  ``1 / (RC s + 1)``), discretised by the backward difference of eq. 2.65.
- :func:`moving_average`: the lecture's FIR low-pass, the mean of the last
  ``n_taps`` samples.
- :func:`decimate`: reduce the sample rate by an integer factor behind a
  linear-phase anti-aliasing FIR (Kaiser window), zero-phase aligned.

The first two run forward only (causal, as a drive or a DAQ would run them)
and so delay the signal; the zero-phase Butterworth filters of
:mod:`hilident.ident.preprocess` are the choice before identification.
All functions work along the last axis and return float64 arrays.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.filtering import rc_lowpass, moving_average, decimate
>>> fs = 1000.0
>>> t = np.arange(4000) / fs
>>> x = np.sin(2 * np.pi * 2.0 * t) + 0.1 * np.sin(2 * np.pi * 200.0 * t)
>>> smooth = rc_lowpass(x, cutoff_hz=20.0, sample_rate_hz=fs)
>>> no_200 = moving_average(x, n_taps=5)          # zeros at 200, 400 Hz
>>> y, fs_new = decimate(x, 10, fs)
>>> y.shape, fs_new
((400,), 100.0)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

from hilident.errors import ConfigError, DataError

__all__ = ["rc_alpha", "rc_lowpass", "moving_average", "decimation_filter", "decimate"]

_INITIAL = ("first", "zero")


def _rate(sample_rate_hz: float) -> float:
    try:
        fs = float(sample_rate_hz)
    except (TypeError, ValueError):
        fs = math.nan
    if isinstance(sample_rate_hz, bool) or not math.isfinite(fs) or fs <= 0.0:
        raise ConfigError("sample_rate_hz", f"must be a positive number, got {sample_rate_hz!r}")
    return fs


def _integer(key: str, value, low: int) -> int:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if isinstance(value, bool) or not x.is_integer() or x < low:
        raise ConfigError(key, f"must be an integer >= {low}, got {value!r}")
    return int(x)


def _signal(x: ArrayLike, min_samples: int = 1) -> np.ndarray:
    try:
        a = np.array(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"x is not numeric: {exc}") from None
    if a.ndim == 0:
        raise DataError("x must be an array of samples, got a scalar")
    if a.shape[-1] < min_samples:
        raise DataError(f"x has {a.shape[-1]} samples along the last axis, at least {min_samples} needed")
    if not np.all(np.isfinite(a)):
        raise DataError(f"x has {int(np.sum(~np.isfinite(a)))} non-finite samples; filters would spread them")
    return a


def _initial(initial: str) -> str:
    if initial not in _INITIAL:
        raise ConfigError("initial", f"must be one of {_INITIAL}, got {initial!r}")
    return initial


def _run(b: np.ndarray, a: np.ndarray, x: np.ndarray, initial: str) -> np.ndarray:
    if b.size == 1 and a.size == 1:  # a pure gain has no memory
        return x * (b[0] / a[0])
    if initial == "zero":
        return signal.lfilter(b, a, x, axis=-1)
    # Start as if x[0] had been applied forever: a constant passes unchanged.
    zi = signal.lfilter_zi(b, a)
    zi = zi * x[..., :1]
    y, _ = signal.lfilter(b, a, x, axis=-1, zi=zi)
    return y


def rc_alpha(cutoff_hz: float, sample_rate_hz: float) -> float:
    """Smoothing factor ``alpha = dt / (RC + dt)`` of thesis eq. 2.66 with ``RC = 1 / (2 pi fc)``.

    Parameters
    ----------
    cutoff_hz : float
        Cut-off ``fc`` of the continuous RC filter, Hz, below Nyquist.
    sample_rate_hz : float
        Sample rate ``1 / dt``, Hz.
    """
    fs = _rate(sample_rate_hz)
    try:
        fc = float(cutoff_hz)
    except (TypeError, ValueError):
        fc = math.nan
    if isinstance(cutoff_hz, bool) or not math.isfinite(fc) or not 0.0 < fc < fs / 2.0:
        raise ConfigError("cutoff_hz", f"must lie in (0, {fs / 2.0:g}) Hz (below Nyquist), got {cutoff_hz!r}")
    rc = 1.0 / (2.0 * math.pi * fc)
    dt = 1.0 / fs
    return dt / (rc + dt)


def rc_lowpass(x: ArrayLike, cutoff_hz: float, sample_rate_hz: float, initial: str = "first") -> np.ndarray:
    """First-order RC low-pass, ``y[i] = alpha x[i] + (1 - alpha) y[i-1]`` (thesis eq. 2.66).

    The continuous filter ``RC v_out' = v_in - v_out`` (eq. 2.64,
    ``1 / (RC s + 1)``) is discretised by the backward difference of eq. 2.65,
    giving ``alpha = dt / (RC + dt)`` with ``RC = 1 / (2 pi fc)`` (eq. 2.67).
    Run causally by ``scipy.signal.lfilter`` with ``b = (alpha,)``,
    ``a = (1, alpha - 1)``.

    Gain at ``fc``: with ``w = 2 pi fc dt`` the discrete filter has
    ``|H(e^jw)|^2 = w^2 / (w^2 + 4 (1 + w) sin^2(w/2))``. Since
    ``(w/2)^2 (1 - w^2/24)^2 <= sin^2(w/2) <= (w/2)^2`` the gain at ``fc`` lies
    between ``-10 log10(2 + w)`` and ``-10 log10(2 + w - w^2 (1 + w) / 12)`` dB:
    the continuous filter's -3.01 dB, lowered by about ``10 log10(1 + w/2)``
    (roughly ``2.2 w`` dB, 0.14 dB at ``fc = fs / 100``). The backward
    difference makes the discrete filter slightly slower than the RC circuit.

    Parameters
    ----------
    x : array_like
        Samples along the last axis, finite.
    cutoff_hz : float
        Cut-off frequency ``fc``, Hz, below Nyquist.
    sample_rate_hz : float
        Sample rate, Hz.
    initial : {"first", "zero"}
        ``"first"``: the filter starts settled on ``x[0]`` (``y[-1] = x[0]``,
        no start-up transient on an offset); ``"zero"``: starts from rest
        (``y[-1] = 0``).

    Returns
    -------
    ndarray
        Filtered samples, same shape as `x`.

    Examples
    --------
    >>> import numpy as np
    >>> y = rc_lowpass(np.ones(5), cutoff_hz=10.0, sample_rate_hz=1000.0, initial="zero")
    >>> bool(np.all(np.diff(y) > 0)) and bool(y[-1] < 1.0)
    True
    """
    alpha = rc_alpha(cutoff_hz, sample_rate_hz)
    init = _initial(initial)
    a = _signal(x)
    return _run(np.array([alpha]), np.array([1.0, alpha - 1.0]), a, init)


def moving_average(x: ArrayLike, n_taps: int, initial: str = "first") -> np.ndarray:
    """Causal moving average (FIR low-pass), ``y[i] = mean(x[i - n_taps + 1 .. i])``.

    ``H(e^jw) = e^(-jw (n-1)/2) sin(n w / 2) / (n sin(w / 2))``: a linear-phase
    filter delaying by ``(n_taps - 1) / 2`` samples whose zeros sit at every
    multiple ``k fs / n_taps`` below Nyquist -- a tone at one of them (e.g.
    mains hum with ``n_taps = fs / 50``) is removed exactly. The first side
    lobe is only -13 dB down; it is a smoother, not a sharp low-pass.

    Parameters
    ----------
    x : array_like
        Samples along the last axis, finite.
    n_taps : int
        Window length, >= 1 (1 returns a copy).
    initial : {"first", "zero"}
        Samples before ``x[0]`` are taken equal to ``x[0]`` (``"first"``) or 0.

    Examples
    --------
    >>> moving_average([0.0, 3.0, 6.0, 9.0], n_taps=3, initial="zero")
    array([0., 1., 3., 6.])
    """
    n = _integer("n_taps", n_taps, 1)
    init = _initial(initial)
    a = _signal(x)
    return _run(np.full(n, 1.0 / n), np.array([1.0]), a, init)


def decimation_filter(factor: int, attenuation_db: float = 80.0, passband_fraction: float = 0.8) -> np.ndarray:
    """Anti-aliasing FIR for :func:`decimate` (Kaiser window, odd length, linear phase).

    The passband ends at ``passband_fraction`` of the new Nyquist frequency
    ``fs / (2 factor)``; the stopband starts at the new Nyquist, so nothing that
    folds into ``[0, fs / (2 factor)]`` passes with more than
    ``-attenuation_db``. Passband ripple is ``20 log10(1 + 10^(-A/20))`` dB
    (below 0.001 dB at 80 dB).

    Parameters
    ----------
    factor : int
        Decimation factor, >= 2.
    attenuation_db : float
        Stopband attenuation, dB, in [20, 200].
    passband_fraction : float
        Passband edge as a fraction of the new Nyquist, in (0, 1).

    Returns
    -------
    ndarray
        Taps at the original rate, unit DC gain.
    """
    q = _integer("factor", factor, 2)
    try:
        att = float(attenuation_db)
    except (TypeError, ValueError):
        att = math.nan
    if not 20.0 <= att <= 200.0:
        raise ConfigError("attenuation_db", f"must lie in [20, 200] dB, got {attenuation_db!r}")
    try:
        frac = float(passband_fraction)
    except (TypeError, ValueError):
        frac = math.nan
    if not 0.0 < frac < 1.0:
        raise ConfigError("passband_fraction", f"must lie in (0, 1), got {passband_fraction!r}")
    # Frequencies normalised to the original Nyquist (= 1).
    stop = 1.0 / q
    passb = frac / q
    numtaps, beta = signal.kaiserord(att, stop - passb)
    numtaps |= 1  # odd: an integer delay that resample_poly removes exactly
    taps = signal.firwin(numtaps, (stop + passb) / 2.0, window=("kaiser", beta))
    return taps / taps.sum()


def decimate(
    x: ArrayLike,
    factor: int,
    sample_rate_hz: float,
    attenuation_db: float = 80.0,
    passband_fraction: float = 0.8,
) -> tuple[np.ndarray, float]:
    """Keep every `factor`-th sample after an anti-aliasing low-pass.

    The FIR of :func:`decimation_filter` is applied by
    ``scipy.signal.resample_poly`` (polyphase, only the kept outputs are
    computed), its delay removed, so the result is aligned with the input:
    sample ``j`` of the result belongs to time ``j * factor / fs``. The ends
    are padded by extending a line through the edge samples, which keeps a
    slow trend (a position drifting with the axis) free of edge steps.

    Parameters
    ----------
    x : array_like
        Samples along the last axis, finite, at least `factor` of them.
    factor : int
        Decimation factor, >= 1 (1 returns a copy).
    sample_rate_hz : float
        Sample rate of `x`, Hz.
    attenuation_db, passband_fraction : float
        See :func:`decimation_filter`.

    Returns
    -------
    y : ndarray
        ``ceil(n / factor)`` samples along the last axis.
    new_rate_hz : float
        ``sample_rate_hz / factor``.

    Examples
    --------
    >>> import numpy as np
    >>> fs = 4000.0
    >>> t = np.arange(8000) / fs
    >>> y, fs2 = decimate(np.sin(2 * np.pi * 10.0 * t), 8, fs)
    >>> fs2, y.shape
    (500.0, (1000,))
    """
    fs = _rate(sample_rate_hz)
    q = _integer("factor", factor, 1)
    a = _signal(x, min_samples=q)
    if q == 1:
        return a.copy(), fs
    taps = decimation_filter(q, attenuation_db, passband_fraction)
    y = signal.resample_poly(a, 1, q, axis=-1, window=taps, padtype="line")
    return y, fs / q
