"""Input shapers for point-to-point moves: impulse trains that cancel a mode's residual vibration.

An input shaper is a train of impulses ``A_i`` at times ``t_i`` (``t_0 = 0``,
``sum A_i = 1``); a set-point convolved with it reaches the same end position
``t_N`` later, and the vibration each impulse starts in a lightly damped mode
cancels the others' (Singer & Seering 1990). The designs are the family 3D
printer firmwares tune (Klipper's ``SHAPER_CALIBRATE``, Marlin's ``M593``),
with the same impulse times and amplitudes as the Klipper firmware's
definitions, so a shaper tuned here can be entered there and the other way round:

* ``zv`` -- zero vibration: two impulses half a damped period apart (Singer & Seering 1990);
* ``mzv`` -- three impulses 3/8 of a damped period apart, zero vibration at the design
  frequency and at 5/3 of it: shorter than ZVD, more robust than ZV (the Klipper firmware's design);
* ``zvd`` -- zero vibration and derivative: three impulses half a period apart (Singer & Seering 1990);
* ``ei`` -- extra-insensitive: residual vibration ``VIBRATION_TOLERANCE`` at the design frequency,
  zero either side of it, from the damped curve fit of Singhose, Derezinski & Singer (1996);
* ``2hump_ei``, ``3hump_ei`` -- two- and three-hump EI: four and five impulses, a band of
  at most 5 % vibration 1.8 and 2.4 times as wide as EI's, undamped (curve fits of Singhose,
  Porter, Tuttle & Singer 1997, for a tolerance of 5 %).

Every design takes the mode's undamped natural frequency (Hz) and damping ratio.
The curve-fitted designs (EI and the multi-hump EI) are valid up to the
damping ratios in :data:`MAX_DAMPING_RATIOS`, and their residual vibration at
the design point is the fit's: within 0.35 percentage points of the exact
shaper's (EI and 3-hump EI: 5 %, 2-hump EI: 0), not the tolerance exactly.

:func:`residual_vibration` is the closed-form residual vibration of a mode
excited by a shaper (a fraction of one unit impulse's); :func:`score_shaper`
scores a shaper as the firmware's calibration does (worst-case vibration over a
frequency band and a set of damping ratios, smoothing, largest acceleration),
and :func:`choose_shaper` designs each kind for measured modes and picks one.

Examples
--------
>>> zv = zv_shaper(40.0, 0.1)
>>> np.round(zv.times_s, 6).tolist(), np.round(zv.amplitudes, 4).tolist()
([0.0, 0.012563], [0.5783, 0.4217])
>>> round(residual_vibration(zv, 40.0, 0.1), 12), round(residual_vibration(zv, 44.0, 0.1), 3)
(0.0, 0.131)
>>> ei = DESIGNS["ei"](40.0, 0.1)
>>> score = score_shaper(ei, (36.0, 44.0))
>>> round(score.worst_vibration, 3), round(score.smoothing * 1e3, 3), round(score.max_accel_mps2, 2)
(0.056, 0.206, 2.91)
>>> shaped = zv.apply(np.linspace(0.0, 1.0, 11), 1000.0)
>>> shaped.size, float(shaped[-1])
(24, 1.0)

References
----------
N. C. Singer, W. P. Seering, "Preshaping command inputs to reduce system vibration",
J. Dyn. Sys., Meas., Control 112(1), 76-82, 1990.
W. Singhose, S. Derezinski, N. Singer, "Extra-insensitive input shapers for controlling
flexible spacecraft", J. Guidance, Control, and Dynamics 19(2), 385-391, 1996.
W. Singhose, L. Porter, T. Tuttle, N. Singer, "Vibration reduction using multi-hump input
shapers", J. Dyn. Sys., Meas., Control 119(2), 320-326, 1997.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.numbers import number

__all__ = [
    "DEFAULT_DAMPING_RATIO",
    "DESIGNS",
    "MAX_DAMPING_RATIOS",
    "MAX_TESTED_DAMPING_RATIO",
    "MIN_RELATIVE_INTERVAL",
    "SCORE_POINTS",
    "SMOOTHING_ACCEL_MPS2",
    "SQUARE_CORNER_VELOCITY_MPS",
    "TARGET_SMOOTHING_M",
    "TARGET_VIBRATION",
    "TEST_DAMPING_RATIOS",
    "VIBRATION_TOLERANCE",
    "Shaper",
    "ShaperChoice",
    "ShaperScore",
    "choose_shaper",
    "design_shaper",
    "ei_shaper",
    "max_acceleration",
    "mzv_shaper",
    "residual_vibration",
    "score_shaper",
    "shaper_smoothing",
    "three_hump_ei_shaper",
    "two_hump_ei_shaper",
    "zv_shaper",
    "zvd_shaper",
]

#: Damping ratio a shaper is designed for when the mode's is not known (the firmware's default).
DEFAULT_DAMPING_RATIO = 0.1
#: Residual vibration the EI family allows at the design point, a fraction (5 %: a reduction by 20).
VIBRATION_TOLERANCE = 0.05
#: Damping ratios the firmware's calibration scores a shaper at, not knowing the mode's: :func:`score_shaper`'s
#: default; about :data:`DEFAULT_DAMPING_RATIO`, the spread :func:`choose_shaper` gives a mode without an interval.
TEST_DAMPING_RATIOS = (0.075, 0.1, 0.15)
#: Acceleration the smoothing is reported at, m/s^2 (the firmware's 5000 mm/s^2).
SMOOTHING_ACCEL_MPS2 = 5.0
#: Velocity kept through a square corner, m/s (the firmware's default square_corner_velocity, 5 mm/s).
SQUARE_CORNER_VELOCITY_MPS = 0.005
#: Smoothing the largest acceleration is found for, m (the firmware's target of 0.12 mm).
TARGET_SMOOTHING_M = 0.12e-3
#: Worst-case residual vibration below which :func:`choose_shaper` takes the least-smoothing shaper, a fraction.
TARGET_VIBRATION = 0.05
#: Half-width of the frequency band a mode is scored over, at least, relative to its frequency (+-5 %).
MIN_RELATIVE_INTERVAL = 0.05
#: Largest damping ratio a mode is scored at (the ends of a wide damping interval are cut here).
MAX_TESTED_DAMPING_RATIO = 0.99
#: Frequencies per band at which the worst-case vibration is evaluated.
SCORE_POINTS = 201
#: Largest damping ratio each design accepts (the firmware's limits; for the EI family, the curve fits' range).
MAX_DAMPING_RATIOS = {"zv": 0.99, "mzv": 0.99, "zvd": 0.99, "ei": 0.4, "2hump_ei": 0.3, "3hump_ei": 0.2}

# Two-hump EI (5 % tolerance), Singhose et al. 1997: per impulse, t_i * f and A_i as cubics in the
# damping ratio, coefficients of 1, z, z^2, z^3.
_TWO_HUMP_TIMES = (
    (0.0, 0.0, 0.0, 0.0),
    (0.49890, 0.16270, -0.54262, 6.16180),
    (0.99748, 0.18382, -1.58270, 8.17120),
    (1.49920, -0.09297, -0.28338, 1.85710),
)
_TWO_HUMP_AMPLITUDES = (
    (0.16054, 0.76699, 2.26560, -1.22750),
    (0.33911, 0.45081, -2.58080, 1.73650),
    (0.34089, -0.61533, -0.68765, 0.42261),
    (0.15997, -0.60246, 1.00280, -0.93145),
)
# Three-hump EI (5 % tolerance), Singhose et al. 1997, laid out as the two-hump's.
_THREE_HUMP_TIMES = (
    (0.0, 0.0, 0.0, 0.0),
    (0.49974, 0.23834, 0.44559, 12.4720),
    (0.99849, 0.29808, -2.36460, 23.3990),
    (1.49870, 0.10306, -2.01390, 17.0320),
    (1.99960, -0.28231, 0.61536, 5.40450),
)
_THREE_HUMP_AMPLITUDES = (
    (0.11275, 0.76632, 3.29160, -1.44380),
    (0.23698, 0.61164, -2.57850, 4.85220),
    (0.30008, -0.19062, -2.14560, 0.13744),
    (0.23775, -0.73297, 0.46885, -2.08650),
    (0.11244, -0.45439, 0.96382, -1.46000),
)


def _modes(value) -> tuple[float, ...]:
    return tuple(float(v) for v in value) if isinstance(value, (tuple, list)) else (float(value),)


@dataclass(frozen=True, eq=False)
class Shaper:
    """A train of impulses, to be convolved with a set-point.

    Attributes
    ----------
    kind : str
        The design (a key of :data:`DESIGNS`), or ``"a*b"`` for the convolution of two shapers.
    times_s : ndarray
        Impulse times, s: the first 0, strictly increasing (read-only).
    amplitudes : ndarray
        Impulse amplitudes, each > 0, summing to 1 (read-only).
    frequency_hz : float or tuple of float
        The undamped natural frequency the shaper was designed for, Hz; for a
        convolution the modes' frequencies, in order.
    damping_ratio : float or tuple of float
        The damping ratio it was designed for; for a convolution the modes', in order.

    Raises
    ------
    DataError
        Times and amplitudes not 1-D of one non-zero length, non-finite, a first
        time not 0, times not increasing, an amplitude not above 0, or amplitudes
        not summing to 1 (within 1e-9).
    """

    kind: str
    times_s: np.ndarray
    amplitudes: np.ndarray
    frequency_hz: float | tuple[float, ...]
    damping_ratio: float | tuple[float, ...]

    def __post_init__(self):
        t = np.array(self.times_s, dtype=float)
        a = np.array(self.amplitudes, dtype=float)
        if t.ndim != 1 or t.shape != a.shape or t.size == 0:
            raise DataError(f"shaper {self.kind!r}: times and amplitudes must be 1-D of one non-zero length")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
            raise DataError(f"shaper {self.kind!r}: times and amplitudes must be finite")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0.0):
            raise DataError(f"shaper {self.kind!r}: times must start at 0 and increase, got {t.tolist()}")
        if np.any(a <= 0.0) or abs(float(a.sum()) - 1.0) > 1e-9:
            raise DataError(f"shaper {self.kind!r}: amplitudes must be > 0 and sum to 1, got {a.tolist()}")
        t.setflags(write=False)
        a.setflags(write=False)
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "amplitudes", a)

    @property
    def duration_s(self) -> float:
        """Time of the last impulse, s: how much later a shaped move ends."""
        return float(self.times_s[-1])

    def convolve(self, other: Shaper) -> Shaper:
        """The shaper that is this one followed by ``other``: zero vibration at both shapers' modes.

        The impulses are all pairwise sums of times with the products of their
        amplitudes; impulses closer than ``1e-9`` of the duration are merged.

        Parameters
        ----------
        other : Shaper

        Returns
        -------
        Shaper
            Kind ``"<self.kind>*<other.kind>"``, the modes of both, in order.
        """
        if not isinstance(other, Shaper):
            raise TypeError(f"other must be a Shaper, got {type(other).__name__}")
        times = np.add.outer(self.times_s, other.times_s).ravel()
        amplitudes = np.multiply.outer(self.amplitudes, other.amplitudes).ravel()
        order = np.argsort(times, kind="stable")
        times, amplitudes = times[order], amplitudes[order]
        tolerance = 1e-9 * max(float(times[-1]), 1e-12)
        starts = np.concatenate([[True], np.diff(times) > tolerance])
        merged_amplitudes = np.add.reduceat(amplitudes, np.flatnonzero(starts))
        merged_amplitudes /= merged_amplitudes.sum()
        return Shaper(
            f"{self.kind}*{other.kind}",
            times[starts],
            merged_amplitudes,
            _modes(self.frequency_hz) + _modes(other.frequency_hz),
            _modes(self.damping_ratio) + _modes(other.damping_ratio),
        )

    def apply(self, x, sample_rate_hz: float) -> np.ndarray:
        """The set-point ``x`` shaped: ``y(t) = sum_i A_i x(t - t_i)``, extended by the shaper's duration.

        Each impulse delays the set-point by its time, interpolating linearly
        between samples for a delay that is not a whole number of samples;
        before its first sample the set-point is held at ``x[0]``, after its
        last at ``x[-1]``. The output is ``ceil(duration_s * sample_rate_hz)``
        samples longer than ``x``, so a move that ends at rest ends at rest at
        the same place.

        Parameters
        ----------
        x : array_like, shape (n,)
            Set-point samples (any unit), at ``sample_rate_hz``.
        sample_rate_hz : float
            Rate of the samples, Hz (> 0).

        Returns
        -------
        ndarray, shape (n + ceil(duration_s * sample_rate_hz),)

        Raises
        ------
        DataError
            ``x`` not a non-empty 1-D array, or not finite.
        ConfigError
            A rate that is not > 0 and finite.
        """
        fs = number("sample_rate_hz", sample_rate_hz, strict=True)
        held = held_setpoint(x, self.duration_s, fs)
        shaped = held.copy()
        add_delayed_copies(shaped, held, np.arange(held.size), self.times_s, self.amplitudes, fs)
        return shaped


def held_setpoint(x, duration_s: float, sample_rate_hz: float) -> np.ndarray:
    """The set-point ``x`` checked and held at its last value for ``duration_s`` more (whole samples, rounded up).

    Raises
    ------
    DataError
        ``x`` not a non-empty 1-D array, or not finite.
    """
    values = np.asarray(x, dtype=float)
    if values.ndim != 1 or values.size == 0:
        raise DataError(f"set-point: expected a non-empty 1-D array, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise DataError("set-point contains NaN or infinite values")
    return np.concatenate([values, np.full(math.ceil(duration_s * sample_rate_hz - 1e-9), values[-1])])


def add_delayed_copies(
    shaped: np.ndarray, held: np.ndarray, rows: np.ndarray, times_s, amplitudes, sample_rate_hz: float
) -> None:
    """Add to ``shaped[rows]`` the impulses' delayed copies of ``held``, as corrections to ``held[rows]``.

    A delay between samples interpolates linearly; before its first sample the set-point is ``held[0]``.
    Summed as corrections to the held set-point, so where every delayed copy equals it (before the move, and
    from the end of the last copy on) the output is exactly the set-point, not within rounding.
    """
    for time_s, amplitude in zip(times_s, amplitudes, strict=True):
        delay = time_s * sample_rate_hz
        whole = math.floor(delay)
        fraction = delay - whole
        later = held[np.clip(rows - whole, 0, None)]
        earlier = held[np.clip(rows - whole - 1, 0, None)]
        shaped[rows] += amplitude * ((1.0 - fraction) * (later - held[rows]) + fraction * (earlier - held[rows]))


def _design_point(kind: str, frequency_hz, damping_ratio) -> tuple[float, float]:
    f = number("frequency_hz", frequency_hz, strict=True)
    z = number("damping_ratio", damping_ratio)
    limit = MAX_DAMPING_RATIOS[kind]
    if z > limit:
        raise ConfigError("damping_ratio", f"must be <= {limit:g} for a {kind} shaper, got {damping_ratio!r}")
    return f, z


def _normalised(kind: str, times_s, amplitudes, frequency_hz: float, damping_ratio: float) -> Shaper:
    a = np.asarray(amplitudes, dtype=float)
    return Shaper(kind, np.asarray(times_s, dtype=float), a / a.sum(), frequency_hz, damping_ratio)


def _damped_period_s(frequency_hz: float, damping_ratio: float) -> float:
    return 1.0 / (frequency_hz * math.sqrt(1.0 - damping_ratio**2))


def _half_period_decay(damping_ratio: float) -> float:
    """Decay of a mode's free vibration over half a damped period, ``exp(-z pi / sqrt(1 - z^2))``."""
    return math.exp(-damping_ratio * math.pi / math.sqrt(1.0 - damping_ratio**2))


def zv_shaper(frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """Zero-vibration shaper: two impulses half a damped period apart (Singer & Seering 1990).

    Parameters
    ----------
    frequency_hz : float
        Undamped natural frequency of the mode, Hz (> 0).
    damping_ratio : float
        Damping ratio of the mode, ``0 <= z <= 0.99``.

    Returns
    -------
    Shaper
        ``A = [1, K] / (1 + K)`` at ``t = [0, T_d / 2]``, ``K = exp(-z pi / sqrt(1 - z^2))``,
        ``T_d = 1 / (f sqrt(1 - z^2))``.

    Raises
    ------
    ConfigError
        A frequency not above 0 or a damping ratio out of range (names the argument).
    """
    f, z = _design_point("zv", frequency_hz, damping_ratio)
    k = _half_period_decay(z)
    return _normalised("zv", [0.0, 0.5 * _damped_period_s(f, z)], [1.0, k], f, z)


def zvd_shaper(frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """Zero-vibration-and-derivative shaper: the ZV shaper convolved with itself (Singer & Seering 1990).

    Parameters
    ----------
    frequency_hz, damping_ratio : see :func:`zv_shaper`.

    Returns
    -------
    Shaper
        ``A = [1, 2K, K^2] / (1 + K)^2`` at ``t = [0, T_d / 2, T_d]``.
    """
    f, z = _design_point("zvd", frequency_hz, damping_ratio)
    k = _half_period_decay(z)
    period = _damped_period_s(f, z)
    return _normalised("zvd", [0.0, 0.5 * period, period], [1.0, 2.0 * k, k * k], f, z)


def mzv_shaper(frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """Three impulses 3/8 of a damped period apart, zero vibration at ``f`` and ``5 f / 3`` (undamped).

    Undamped, the amplitudes ``[1 - 1/sqrt(2), sqrt(2) - 1, 1 - 1/sqrt(2)]`` put
    the impulses' vectors at 0, 135 and 270 degrees of the design frequency's
    cycle into balance; each impulse is then scaled by the mode's decay since
    the first, ``K = exp(-0.75 z pi / sqrt(1 - z^2))`` per impulse, so the
    balance holds for the damped mode. This is the Klipper firmware's MZV.

    Parameters
    ----------
    frequency_hz, damping_ratio : see :func:`zv_shaper`.

    Returns
    -------
    Shaper
        ``t = [0, 0.375, 0.75] T_d``, 0.75 of ZVD's duration.
    """
    f, z = _design_point("mzv", frequency_hz, damping_ratio)
    k = math.exp(-0.75 * z * math.pi / math.sqrt(1.0 - z * z))
    outer = 1.0 - 1.0 / math.sqrt(2.0)
    period = _damped_period_s(f, z)
    return _normalised(
        "mzv", [0.0, 0.375 * period, 0.75 * period], [outer, (math.sqrt(2.0) - 1.0) * k, outer * k * k], f, z
    )


def ei_shaper(
    frequency_hz: float,
    damping_ratio: float = DEFAULT_DAMPING_RATIO,
    vibration_tolerance: float = VIBRATION_TOLERANCE,
) -> Shaper:
    """Extra-insensitive shaper: three impulses over one damped period (Singhose, Derezinski & Singer 1996).

    The curve fit of the paper in the tolerance ``V`` and damping ratio ``z``::

        A_1 = 0.24968 + 0.24961 V + (0.80008 + 1.23328 V) z + (0.49599 + 3.17316 V) z^2
        A_3 = 0.25149 + 0.21474 V + (-0.83249 + 1.41498 V) z + (0.85181 - 4.90094 V) z^2
        A_2 = 1 - A_1 - A_3
        t_2 / T_d = 0.4999 + (0.46159 + 8.57843 V) V z + (4.26169 - 108.644 V) V z^2 + (1.75601 + 336.989 V) V z^3
        t_3 = T_d = 1 / (f sqrt(1 - z^2))

    The exact undamped shaper, ``A = [(1 + V) / 4, (1 - V) / 2, (1 + V) / 4]`` at
    ``[0, T / 2, T]``, leaves exactly ``V`` at the design frequency; the fit leaves
    ``V`` within about 0.15 % (4.88 % undamped, 5.06 % at ``z = 0.1`` for ``V = 5 %``).

    Parameters
    ----------
    frequency_hz, damping_ratio : see :func:`zv_shaper`; ``damping_ratio <= 0.4`` (the fit's range).
    vibration_tolerance : float
        ``V``, the residual vibration allowed at the design point, a fraction (> 0).

    Returns
    -------
    Shaper
    """
    f, z = _design_point("ei", frequency_hz, damping_ratio)
    v = number("vibration_tolerance", vibration_tolerance, strict=True)
    a1 = 0.24968 + 0.24961 * v + (0.80008 + 1.23328 * v) * z + (0.49599 + 3.17316 * v) * z * z
    a3 = 0.25149 + 0.21474 * v + (-0.83249 + 1.41498 * v) * z + (0.85181 - 4.90094 * v) * z * z
    middle = (
        0.4999
        + (0.46159 + 8.57843 * v) * v * z
        + (4.26169 - 108.644 * v) * v * z**2
        + (1.75601 + 336.989 * v) * v * z**3
    )
    period = _damped_period_s(f, z)
    return _normalised("ei", [0.0, middle * period, period], [a1, 1.0 - a1 - a3, a3], f, z)


def _from_cubic_fits(kind: str, frequency_hz, damping_ratio, time_fits, amplitude_fits) -> Shaper:
    f, z = _design_point(kind, frequency_hz, damping_ratio)
    powers = np.array([1.0, z, z * z, z**3])
    times = np.asarray(time_fits) @ powers / f
    amplitudes = np.asarray(amplitude_fits) @ powers
    return _normalised(kind, times, amplitudes, f, z)


def two_hump_ei_shaper(frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """Two-hump extra-insensitive shaper (5 % tolerance): four impulses over 1.5 periods (Singhose et al. 1997).

    Each impulse's time (in undamped periods ``1 / f``) and amplitude is a cubic
    in the damping ratio, the paper's fit; the amplitudes are normalised to sum
    to 1 (the fit's sum to 1.0005). The vibration has two humps of 5 % either side of
    the design frequency and (nearly) none at it: exact undamped, it is 0 there; the
    fit leaves 0.3 % undamped, 0.05 % at ``z = 0.1``.

    Parameters
    ----------
    frequency_hz, damping_ratio : see :func:`zv_shaper`; ``damping_ratio <= 0.3`` (the fit's range).

    Returns
    -------
    Shaper
    """
    return _from_cubic_fits("2hump_ei", frequency_hz, damping_ratio, _TWO_HUMP_TIMES, _TWO_HUMP_AMPLITUDES)


def three_hump_ei_shaper(frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """Three-hump extra-insensitive shaper (5 % tolerance): five impulses over two periods (Singhose et al. 1997).

    Built as :func:`two_hump_ei_shaper` from the paper's cubic fits. The middle
    of the three 5 % humps is at the design frequency: exact undamped, the
    vibration there is the tolerance; the fit leaves 5.05 % undamped, 4.92 % at ``z = 0.1``.

    Parameters
    ----------
    frequency_hz, damping_ratio : see :func:`zv_shaper`; ``damping_ratio <= 0.2`` (the fit's range).

    Returns
    -------
    Shaper
    """
    return _from_cubic_fits("3hump_ei", frequency_hz, damping_ratio, _THREE_HUMP_TIMES, _THREE_HUMP_AMPLITUDES)


#: Each kind's design, ``(frequency_hz, damping_ratio) -> Shaper``, shortest to most robust.
DESIGNS: dict[str, Callable[[float, float], Shaper]] = {
    "zv": zv_shaper,
    "mzv": mzv_shaper,
    "zvd": zvd_shaper,
    "ei": ei_shaper,
    "2hump_ei": two_hump_ei_shaper,
    "3hump_ei": three_hump_ei_shaper,
}


def design_shaper(kind: str, frequency_hz: float, damping_ratio: float = DEFAULT_DAMPING_RATIO) -> Shaper:
    """The shaper of ``kind`` (a key of :data:`DESIGNS`) for one mode.

    Raises
    ------
    ConfigError
        An unknown kind (key ``"kind"``), a bad frequency or damping ratio.
    """
    if kind not in DESIGNS:
        raise ConfigError("kind", f"must be one of {sorted(DESIGNS)}, got {kind!r}")
    return DESIGNS[kind](frequency_hz, damping_ratio)


def _frequencies(frequency_hz) -> np.ndarray:
    try:
        f = np.asarray(frequency_hz, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError("frequency_hz", f"must be a number or an array of numbers, got {frequency_hz!r}") from None
    if not np.all(np.isfinite(f) & (f > 0.0)):
        raise ConfigError("frequency_hz", f"must be > 0 and finite, got {frequency_hz!r}")
    return f


def _damping_ratios(damping_ratio, key: str = "damping_ratio") -> np.ndarray:
    try:
        z = np.asarray(damping_ratio, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a number or an array of numbers, got {damping_ratio!r}") from None
    if not np.all(np.isfinite(z) & (z >= 0.0) & (z < 1.0)):
        raise ConfigError(key, f"must be in [0, 1), got {damping_ratio!r}")
    return z


def residual_vibration(shaper: Shaper, frequency_hz, damping_ratio) -> float | np.ndarray:
    """Residual vibration of a second-order mode excited by the shaper, a fraction of one unit impulse's.

    With ``w = 2 pi f``, ``w_d = w sqrt(1 - z^2)`` and the last impulse at ``t_N``
    (Singer & Seering 1990)::

        V = sqrt(C^2 + S^2),   C = sum_i A_i exp(-z w (t_N - t_i)) cos(w_d t_i),
                               S = sum_i A_i exp(-z w (t_N - t_i)) sin(w_d t_i)

    the amplitude of the free vibration after the last impulse, at ``t_N``,
    relative to that of a unit impulse just after it is applied. It is the
    same expression as the Klipper firmware's shaper estimate (which divides by
    the amplitudes' sum, 1 here); the decay is written relative to ``t_N`` so it
    never overflows. Since each impulse's vibration decays at the same rate, ``V``
    is also the ratio of a shaped move's residual vibration, measured from its
    end, to the unshaped move's measured from its own end.

    Parameters
    ----------
    shaper : Shaper
    frequency_hz : float or array_like
        Undamped natural frequency of the mode, Hz (> 0).
    damping_ratio : float or array_like
        Its damping ratio, in [0, 1); broadcast against ``frequency_hz``.

    Returns
    -------
    float or ndarray
        ``V`` (0: no vibration, 1: as much as without a shaper); an array of
        the broadcast shape when either argument is an array.

    Raises
    ------
    ConfigError
        A frequency not above 0 or a damping ratio outside [0, 1) (names the argument).
    """
    f = _frequencies(frequency_hz)
    z = _damping_ratios(damping_ratio)
    omega = 2.0 * math.pi * f[..., np.newaxis]
    zeta = z[..., np.newaxis]
    t = shaper.times_s
    weight = shaper.amplitudes * np.exp(-zeta * omega * (t[-1] - t))
    phase = omega * np.sqrt(1.0 - zeta * zeta) * t
    v = np.hypot(np.sum(weight * np.cos(phase), axis=-1), np.sum(weight * np.sin(phase), axis=-1))
    return float(v) if v.ndim == 0 else v


def _smoothing_terms(shaper: Shaper) -> tuple[float, float, float]:
    """``(P1, P2, Q)``: sums of ``A_i (t_i - t_s)`` and ``A_i (t_i - t_s)^2`` over impulses at or after the
    centroid ``t_s``, and of ``A_i (t_i - t_s)^2`` over all."""
    t, a = shaper.times_s, shaper.amplitudes
    lag = t - float(np.dot(a, t))
    late = lag >= 0.0
    return float(np.dot(a[late], lag[late])), float(np.dot(a[late], lag[late] ** 2)), float(np.dot(a, lag**2))


def shaper_smoothing(
    shaper: Shaper,
    accel_mps2: float = SMOOTHING_ACCEL_MPS2,
    square_corner_velocity_mps: float = SQUARE_CORNER_VELOCITY_MPS,
) -> float:
    """How far the shaped path cuts a corner, m: the Klipper firmware's smoothing estimate, in SI units.

    Relative to the amplitude-weighted centroid ``t_s`` of the impulses, with
    ``a`` the acceleration and ``v`` the square-corner velocity::

        offset_90  = sqrt(2) * sum_{t_i >= t_s} A_i (v + a (t_i - t_s) / 2) (t_i - t_s)
        offset_180 = sum_i A_i a (t_i - t_s)^2 / 2
        smoothing  = max(offset_90, offset_180)

    The firmware computes it in mm with 5000 mm/s^2 and 5 mm/s; it is linear in
    the units, so with 5 m/s^2 and 0.005 m/s this gives its number in m (times 1e-3).

    Parameters
    ----------
    shaper : Shaper
    accel_mps2 : float
        Acceleration of the move, m/s^2 (>= 0).
    square_corner_velocity_mps : float
        Velocity kept through a 90-degree corner, m/s (>= 0).

    Returns
    -------
    float
        Smoothing, m.
    """
    a = number("accel_mps2", accel_mps2)
    v = number("square_corner_velocity_mps", square_corner_velocity_mps)
    late_lag, late_lag2, lag2 = _smoothing_terms(shaper)
    return max(math.sqrt(2.0) * (v * late_lag + 0.5 * a * late_lag2), 0.5 * a * lag2)


def max_acceleration(
    shaper: Shaper,
    square_corner_velocity_mps: float = SQUARE_CORNER_VELOCITY_MPS,
    target_smoothing_m: float = TARGET_SMOOTHING_M,
) -> float:
    """Largest acceleration whose :func:`shaper_smoothing` stays at or below ``target_smoothing_m``, m/s^2.

    Both offsets grow linearly with the acceleration, so the limit is solved in
    closed form (the firmware bisects for the same number, in mm/s^2, with a
    target of 0.12 mm: :data:`TARGET_SMOOTHING_M`). 0 when the square-corner
    velocity alone smooths more than the target; inf for a single impulse.

    Parameters
    ----------
    shaper : Shaper
    square_corner_velocity_mps : float
        m/s (>= 0).
    target_smoothing_m : float
        m (> 0).

    Returns
    -------
    float
        m/s^2.
    """
    v = number("square_corner_velocity_mps", square_corner_velocity_mps)
    target = number("target_smoothing_m", target_smoothing_m, strict=True)
    late_lag, late_lag2, lag2 = _smoothing_terms(shaper)
    room = target / math.sqrt(2.0) - v * late_lag
    if room < 0.0:
        return 0.0
    by_corner = 2.0 * room / late_lag2 if late_lag2 > 0.0 else math.inf
    by_reversal = 2.0 * target / lag2 if lag2 > 0.0 else math.inf
    return min(by_corner, by_reversal)


@dataclass(frozen=True, eq=False)
class ShaperScore:
    """A shaper's worst-case residual vibration over frequency bands and damping ratios, and its smoothing.

    Attributes
    ----------
    shaper : Shaper
    worst_vibration : float
        Largest :func:`residual_vibration` over the bands and damping ratios, a fraction.
    worst_frequency_hz : float
        Frequency where it was found, Hz.
    worst_damping_ratio : float
        Damping ratio where it was found.
    smoothing : float
        :func:`shaper_smoothing` at :attr:`accel_mps2`, m.
    max_accel_mps2 : float
        :func:`max_acceleration` for the target smoothing, m/s^2.
    accel_mps2 : float
        Acceleration the smoothing is given at, m/s^2.
    frequency_intervals_hz : tuple of (float, float)
        The bands scored, Hz, one per mode.
    damping_ratios : tuple of tuple of float
        The damping ratios scored in each band.
    """

    shaper: Shaper
    worst_vibration: float
    worst_frequency_hz: float
    worst_damping_ratio: float
    smoothing: float
    max_accel_mps2: float
    accel_mps2: float
    frequency_intervals_hz: tuple[tuple[float, float], ...]
    damping_ratios: tuple[tuple[float, ...], ...]

    @property
    def kind(self) -> str:
        """The shaper's kind."""
        return self.shaper.kind

    def as_dict(self) -> dict:
        """The figures under unit-suffixed keys, JSON-ready (the shaper as its times and amplitudes)."""
        return {
            "kind": self.kind,
            "times_s": self.shaper.times_s.tolist(),
            "amplitudes": self.shaper.amplitudes.tolist(),
            "worst_vibration": self.worst_vibration,
            "worst_frequency_hz": self.worst_frequency_hz,
            "worst_damping_ratio": self.worst_damping_ratio,
            "smoothing_m": self.smoothing,
            "max_accel_mps2": None if math.isinf(self.max_accel_mps2) else self.max_accel_mps2,
            "accel_mps2": self.accel_mps2,
            "duration_s": self.shaper.duration_s,
        }


def _interval(value, key: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a pair (f_lo, f_hi) in Hz, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
        raise ConfigError(key, f"must satisfy 0 < f_lo <= f_hi (finite), got {value!r}")
    return lo, hi


def _score(
    shaper: Shaper,
    bands: Sequence[tuple[tuple[float, float], tuple[float, ...]]],
    n: int,
    accel_mps2: float,
    square_corner_velocity_mps: float,
    target_smoothing_m: float,
) -> ShaperScore:
    worst = (-1.0, math.nan, math.nan)
    for (lo, hi), dampings in bands:
        f = np.linspace(lo, hi, n)
        for z in dampings:
            v = np.asarray(residual_vibration(shaper, f, z))
            i = int(np.argmax(v))
            if v[i] > worst[0]:
                worst = (float(v[i]), float(f[i]), float(z))
    return ShaperScore(
        shaper,
        *worst,
        smoothing=shaper_smoothing(shaper, accel_mps2, square_corner_velocity_mps),
        max_accel_mps2=max_acceleration(shaper, square_corner_velocity_mps, target_smoothing_m),
        accel_mps2=float(accel_mps2),
        frequency_intervals_hz=tuple(band for band, _ in bands),
        damping_ratios=tuple(tuple(d) for _, d in bands),
    )


def _points(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ConfigError("n", f"must be an integer >= 2, got {n!r}")
    return int(n)


def score_shaper(
    shaper: Shaper,
    frequency_hz_interval: tuple[float, float],
    damping_ratios: Sequence[float] = TEST_DAMPING_RATIOS,
    n: int = SCORE_POINTS,
    *,
    accel_mps2: float = SMOOTHING_ACCEL_MPS2,
    square_corner_velocity_mps: float = SQUARE_CORNER_VELOCITY_MPS,
    target_smoothing_m: float = TARGET_SMOOTHING_M,
) -> ShaperScore:
    """Score a shaper as the firmware's calibration does: worst-case vibration, smoothing, largest acceleration.

    Parameters
    ----------
    shaper : Shaper
    frequency_hz_interval : (float, float)
        The band the mode's frequency may lie in, Hz, ``0 < f_lo <= f_hi``.
    damping_ratios : sequence of float
        Damping ratios the mode may have, each in [0, 1); default the firmware's
        :data:`TEST_DAMPING_RATIOS`.
    n : int
        Frequencies, evenly spaced over the band, at which the vibration is evaluated (>= 2).
    accel_mps2 : float
        Acceleration the smoothing is given at, m/s^2 (the firmware's 5000 mm/s^2).
    square_corner_velocity_mps : float
        m/s (the firmware's default 5 mm/s).
    target_smoothing_m : float
        Smoothing the largest acceleration is found for, m (the firmware's 0.12 mm).

    Returns
    -------
    ShaperScore

    Raises
    ------
    ConfigError
        A band, damping ratio, count, acceleration or velocity out of range (names the argument).
    """
    band = _interval(frequency_hz_interval, "frequency_hz_interval")
    dampings = tuple(float(z) for z in _damping_ratios(list(damping_ratios), "damping_ratios").ravel())
    if not dampings:
        raise ConfigError("damping_ratios", "must hold at least one damping ratio")
    return _score(shaper, [(band, dampings)], _points(n), accel_mps2, square_corner_velocity_mps, target_smoothing_m)


@dataclass(frozen=True, eq=False)
class ShaperChoice:
    """Every kind of shaper designed for the modes and scored, the chosen one first.

    Attributes
    ----------
    candidates : tuple of ShaperScore
        Ranked: the shapers whose worst-case vibration is at most the target, least
        smoothing first; then the others, lowest worst-case vibration first.
    reason : str
        One sentence on why the first was chosen.
    target_vibration : float
        The worst-case vibration a shaper had to stay at or below, a fraction.
    """

    candidates: tuple[ShaperScore, ...]
    reason: str
    target_vibration: float

    @property
    def chosen(self) -> ShaperScore:
        """The first candidate."""
        return self.candidates[0]

    @property
    def shaper(self) -> Shaper:
        """The chosen shaper."""
        return self.candidates[0].shaper


def _mode(i: int, mode) -> tuple[float, float, float | None, float | None]:
    key = f"modes[{i}]"
    try:
        frequency, damping, frequency_ci, damping_ci = mode
    except (TypeError, ValueError):
        raise ConfigError(
            key, f"must be (frequency_hz, damping_ratio, frequency_ci95_hz or None, damping_ci95 or None), got {mode!r}"
        ) from None
    f = number(f"{key}.frequency_hz", frequency, strict=True)
    z = number(f"{key}.damping_ratio", damping)
    if z >= 1.0:
        raise ConfigError(f"{key}.damping_ratio", f"must be in [0, 1), got {damping!r}")
    f_ci = None if frequency_ci is None else number(f"{key}.frequency_ci95_hz", frequency_ci)
    z_ci = None if damping_ci is None else number(f"{key}.damping_ci95", damping_ci)
    return f, z, f_ci, z_ci


def _band(
    f: float, z: float, f_ci: float | None, z_ci: float | None, extra: Sequence[float], min_relative: float
) -> tuple[tuple[float, float], tuple[float, ...]]:
    half = max(f_ci or 0.0, min_relative * f)
    # A band reaching 0 Hz is cut at 1e-3 f: the vibration there is ~1 for any shaper.
    band = (max(f - half, 1e-3 * f), f + half)
    if z_ci is None:
        spread = [z * r / DEFAULT_DAMPING_RATIO for r in TEST_DAMPING_RATIOS]
    else:
        spread = [z - z_ci, z, z + z_ci]
    measured = [min(max(x, 0.0), MAX_TESTED_DAMPING_RATIO) for x in spread]
    return band, tuple(sorted({*extra, *measured}))


def _percent(x: float) -> str:
    return f"{100.0 * x:.1f} %"


def _reason(choice: ShaperScore, passing: int, target: float) -> str:
    worst = (
        f"{_percent(choice.worst_vibration)} at {choice.worst_frequency_hz:.4g} Hz, "
        f"damping ratio {choice.worst_damping_ratio:.3g}"
    )
    smoothing = f"{choice.smoothing * 1e3:.3g} mm at {choice.accel_mps2:g} m/s^2"
    if passing:
        return (
            f"{choice.kind} smooths least ({smoothing}) of the {passing} shaper(s) whose worst-case residual "
            f"vibration stays at or below {_percent(target)} ({worst})."
        )
    return (
        f"no shaper keeps the worst-case residual vibration at or below {_percent(target)}; "
        f"{choice.kind} leaves the least ({worst})."
    )


def choose_shaper(
    modes: Sequence[tuple[float, float, float | None, float | None]],
    *,
    kinds: Sequence[str] | None = None,
    target_vibration: float = TARGET_VIBRATION,
    damping_ratios: Sequence[float] = (),
    min_relative_interval: float = MIN_RELATIVE_INTERVAL,
    n: int = SCORE_POINTS,
    accel_mps2: float = SMOOTHING_ACCEL_MPS2,
    square_corner_velocity_mps: float = SQUARE_CORNER_VELOCITY_MPS,
    target_smoothing_m: float = TARGET_SMOOTHING_M,
) -> ShaperChoice:
    """Design each kind of shaper for the measured modes, score it over their uncertainty, and choose one.

    For each kind, a shaper is designed at each mode's frequency and damping
    ratio and, for several modes, the shapers are convolved. It is scored over
    each mode's band, ``f +- max(frequency_ci95_hz, min_relative_interval * f)``
    (at least +-5 %; +-5 % when no interval is given), at damping ratios that
    cover the mode's: the measured one and the ends of its 95 % interval; without
    an interval, the measured one times 0.75, 1 and 1.5 (the firmware's spread,
    :data:`TEST_DAMPING_RATIOS` about :data:`DEFAULT_DAMPING_RATIO`); and any of
    ``damping_ratios`` (pass :data:`TEST_DAMPING_RATIOS` to score as pessimistically
    as the firmware, which does not measure the damping).

    The rule, as the firmware's calibration aims: among the shapers whose
    worst-case vibration is at most ``target_vibration``, the one that smooths
    least (the shortest, in effect); when none is, the one with the lowest
    worst-case vibration. A kind whose design does not cover a mode's damping
    ratio (:data:`MAX_DAMPING_RATIOS`) is left out. The EI family leaves about
    :data:`VIBRATION_TOLERANCE` at its humps by design, so against the default
    5 % target it passes only where its curve fit leaves a little less; a target
    of 6 % lets it compete on smoothing.

    Parameters
    ----------
    modes : sequence of (float, float, float or None, float or None)
        Per mode ``(frequency_hz, damping_ratio, frequency_ci95_hz, damping_ci95)``: the
        undamped natural frequency (Hz), the damping ratio, and the half-widths of their
        95 % confidence intervals (Hz; a ratio), None when not known.
    kinds : sequence of str, optional
        The kinds to consider (keys of :data:`DESIGNS`); default all.
    target_vibration : float
        The worst-case residual vibration a shaper must stay at or below, a fraction (> 0).
    damping_ratios : sequence of float
        Damping ratios scored for every mode besides its own, each in [0, 1).
    min_relative_interval : float
        Smallest half-width of a mode's band, relative to its frequency (>= 0).
    n, accel_mps2, square_corner_velocity_mps, target_smoothing_m :
        See :func:`score_shaper`.

    Returns
    -------
    ShaperChoice

    Raises
    ------
    ConfigError
        No modes, a mode out of range (names ``modes[i]`` and the field), an unknown
        kind, no kind valid for the modes' damping ratios, a bad target or count.

    Examples
    --------
    >>> narrow = choose_shaper([(25.0, 0.03, 0.2, 0.005)])    # +-5 %
    >>> wide = choose_shaper([(25.0, 0.03, 3.75, 0.005)])     # +-15 %
    >>> narrow.chosen.kind, wide.chosen.kind
    ('mzv', '2hump_ei')
    >>> round(wide.chosen.worst_vibration, 3), round(wide.chosen.max_accel_mps2, 2)
    (0.049, 0.48)
    """
    if isinstance(modes, (str, bytes)) or not isinstance(modes, Sequence) or not modes:
        raise ConfigError("modes", f"must be a non-empty sequence of modes, got {modes!r}")
    measured = [_mode(i, mode) for i, mode in enumerate(modes)]
    wanted = list(DESIGNS) if kinds is None else list(kinds)
    for kind in wanted:
        if kind not in DESIGNS:
            raise ConfigError("kinds", f"each must be one of {sorted(DESIGNS)}, got {kind!r}")
    target = number("target_vibration", target_vibration, strict=True)
    min_relative = number("min_relative_interval", min_relative_interval)
    extra = tuple(float(z) for z in _damping_ratios(list(damping_ratios), "damping_ratios").ravel())
    points = _points(n)
    bands = [_band(f, z, f_ci, z_ci, extra, min_relative) for f, z, f_ci, z_ci in measured]
    scores = []
    for kind in wanted:
        if any(z > MAX_DAMPING_RATIOS[kind] for _, z, _, _ in measured):
            continue
        shapers = [DESIGNS[kind](f, z) for f, z, _, _ in measured]
        shaper = shapers[0]
        for other in shapers[1:]:
            shaper = shaper.convolve(other)
        scores.append(_score(shaper, bands, points, accel_mps2, square_corner_velocity_mps, target_smoothing_m))
    if not scores:
        raise ConfigError("kinds", f"no kind of {wanted} is designed for the modes' damping ratios")
    passing = sorted(
        (s for s in scores if s.worst_vibration <= target), key=lambda s: (s.smoothing, s.shaper.duration_s)
    )
    failing = sorted((s for s in scores if s.worst_vibration > target), key=lambda s: s.worst_vibration)
    ranked = tuple(passing + failing)
    return ShaperChoice(ranked, _reason(ranked[0], len(passing), target), target)
