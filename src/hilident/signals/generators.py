"""Excitation signals for system identification and friction tests.

Every generator returns float64 samples at ``sample_rate_hz``; sample ``i`` is at
``t = i / sample_rate_hz``.  A duration becomes ``round(duration_s * sample_rate_hz)``
samples.  Bad arguments raise :class:`hilident.errors.ConfigError` keyed by the
argument name, and so does a signal longer than
:data:`hilident.signals._checks.MAX_SAMPLES` (2**25 samples), refused before
anything is allocated.

Examples
--------
>>> from hilident.signals import multisine, fade
>>> ms = multisine(0.5, 2.0, 200.0, period_s=1.0, n_periods=4, sample_rate_hz=1000.0)
>>> ms.samples.shape, float(abs(ms.samples).max())
((4000,), 0.5)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.signals import _checks as chk
from hilident.signals.ramp_legs import _ramp_legs, ramp_extent

__all__ = [
    "Multisine",
    "RampProfile",
    "band_limited_noise",
    "chirp",
    "crest_factor",
    "fade",
    "multisine",
    "prbs",
    "ramp_extent",
    "sine",
    "square",
    "step",
    "velocity_ramps",
]


def _time(duration_s, sample_rate_hz) -> np.ndarray:
    fs = chk.positive("sample_rate_hz", sample_rate_hz)
    duration = chk.positive("duration_s", duration_s)
    return np.arange(chk.n_samples("duration_s", duration, fs)) / fs


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------- periodic


def sine(amplitude, frequency_hz, duration_s, sample_rate_hz, phase_rad=0.0) -> np.ndarray:
    """Sinusoid ``amplitude * sin(2 pi f t + phase_rad)``.

    Parameters
    ----------
    amplitude : float
        Peak value (any unit: N·m, N, m/s).
    frequency_hz : float
        Frequency, ``0 < f < sample_rate_hz / 2``.
    duration_s, sample_rate_hz : float
        Length of the signal and sample rate.
    phase_rad : float
        Phase at ``t = 0`` in rad.
    """
    t = _time(duration_s, sample_rate_hz)
    a = chk.positive("amplitude", amplitude)
    f = chk.positive("frequency_hz", frequency_hz)
    chk.below_nyquist("frequency_hz", f, sample_rate_hz)
    phase = chk.finite("phase_rad", phase_rad)
    return a * np.sin(2.0 * np.pi * f * t + phase)


def square(amplitude, frequency_hz, duration_s, sample_rate_hz, duty=0.5) -> np.ndarray:
    """Square wave between ``+amplitude`` and ``-amplitude`` (scipy.signal.square).

    ``duty`` is the fraction of each period spent at ``+amplitude``, ``0 < duty < 1``.
    The wave starts at ``+amplitude`` at ``t = 0``.
    """
    t = _time(duration_s, sample_rate_hz)
    a = chk.positive("amplitude", amplitude)
    f = chk.positive("frequency_hz", frequency_hz)
    chk.below_nyquist("frequency_hz", f, sample_rate_hz)
    d = chk.finite("duty", duty)
    if not 0.0 < d < 1.0:
        raise ConfigError("duty", f"must lie strictly between 0 and 1, got {chk.show(duty)}")
    import scipy.signal  # here, not at import: a host that never builds this signal starts faster

    return a * scipy.signal.square(2.0 * np.pi * f * t, duty=d)


def chirp(amplitude, f0_hz, f1_hz, duration_s, sample_rate_hz, method="linear") -> np.ndarray:
    """Swept sine from ``f0_hz`` at ``t = 0`` to ``f1_hz`` at ``t = duration_s``.

    Wraps :func:`scipy.signal.chirp` with ``phi = -90`` so the sweep is a sine that
    starts at 0 (no torque step).  ``method`` is ``"linear"`` (frequency linear in
    time) or ``"logarithmic"`` (frequency exponential in time, equal time per
    decade; both frequencies must then be positive).  Sweeping down is allowed.
    """
    t = _time(duration_s, sample_rate_hz)
    a = chk.positive("amplitude", amplitude)
    if method not in ("linear", "logarithmic"):
        raise ConfigError("method", f"must be 'linear' or 'logarithmic', got {chk.show(method)}")
    check = chk.positive if method == "logarithmic" else chk.non_negative
    f0 = chk.below_nyquist("f0_hz", check("f0_hz", f0_hz), sample_rate_hz)
    f1 = chk.below_nyquist("f1_hz", check("f1_hz", f1_hz), sample_rate_hz)
    if f0 == f1:
        raise ConfigError("f1_hz", f"must differ from f0_hz, both are {f0:g} Hz")
    import scipy.signal

    return a * scipy.signal.chirp(t, f0, float(duration_s), f1, method=method, phi=-90.0)


def step(amplitude, duration_s, sample_rate_hz, step_time_s=0.0) -> np.ndarray:
    """0 before ``step_time_s``, ``amplitude`` from the first sample at or after it."""
    t = _time(duration_s, sample_rate_hz)
    a = chk.finite("amplitude", amplitude)
    t_step = chk.non_negative("step_time_s", step_time_s)
    if t_step >= float(duration_s):
        raise ConfigError("step_time_s", f"must be before the end {float(duration_s):g} s, got {t_step:g}")
    i = int(math.ceil(t_step * float(sample_rate_hz) - 1e-9))
    x = np.zeros_like(t)
    x[i:] = a
    return x


# --------------------------------------------------------------------------- broadband


def _band_mask(n: int, sample_rate_hz: float, f_min_hz: float, f_max_hz: float) -> np.ndarray:
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    return (f >= f_min_hz) & (f <= f_max_hz)


def _band_limit(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    spectrum = np.fft.rfft(x)
    spectrum[~mask] = 0.0
    return np.fft.irfft(spectrum, n=x.size)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def band_limited_noise(rms, f_min_hz, f_max_hz, duration_s, sample_rate_hz, seed, peak=None) -> np.ndarray:
    """Gaussian noise whose spectrum is flat in ``[f_min_hz, f_max_hz]`` and zero outside.

    White noise from ``numpy.random.default_rng(seed)`` is band-limited by zeroing
    every FFT bin outside the band (the signal is therefore periodic in its own
    length) and scaled to ``rms``.

    Peak limit: when ``peak`` is given, ``|x| <= peak`` is guaranteed.  The signal
    is first clipped at ``peak`` and band-limited again, a few times over, each
    time rescaled to ``rms`` (this lowers the crest factor while the spectrum
    stays inside the band).  If a sample still exceeds ``peak`` after that, the
    whole signal is scaled down, so its rms is then somewhat below ``rms``.

    Parameters
    ----------
    rms : float
        Root-mean-square value of the result (same unit as the signal).
    f_min_hz, f_max_hz : float
        Band edges, ``0 <= f_min_hz < f_max_hz < sample_rate_hz / 2``.
    duration_s, sample_rate_hz : float
        Length and sample rate.
    seed : int or numpy.random.SeedSequence
        Seed; the same seed gives the same samples.
    peak : float, optional
        Largest allowed absolute value, ``peak >= rms``.
    """
    t = _time(duration_s, sample_rate_hz)
    fs = float(sample_rate_hz)
    target = chk.positive("rms", rms)
    f_min = chk.non_negative("f_min_hz", f_min_hz)
    f_max = chk.below_nyquist("f_max_hz", chk.positive("f_max_hz", f_max_hz), fs)
    if f_min >= f_max:
        raise ConfigError("f_min_hz", f"must be below f_max_hz {f_max:g} Hz, got {f_min:g}")
    limit = None
    if peak is not None:
        limit = chk.positive("peak", peak)
        if limit < target:
            raise ConfigError("peak", f"must be at least rms {target:g}, got {limit:g}")
    if seed is None:
        raise ConfigError("seed", "an explicit seed is required for reproducible noise")

    mask = _band_mask(t.size, fs, f_min, f_max)
    if not mask.any():
        raise ConfigError(
            "duration_s",
            f"too short: no FFT bin (spacing {fs / t.size:g} Hz) lies in [{f_min:g}, {f_max:g}] Hz",
        )
    rng = np.random.default_rng(seed)
    x = _band_limit(rng.standard_normal(t.size), mask)
    if not np.any(x):
        raise ConfigError("f_min_hz", "the band only holds the DC bin; raise f_max_hz")
    x *= target / _rms(x)
    if limit is not None:
        for _ in range(30):
            if np.max(np.abs(x)) <= limit:
                break
            x = _band_limit(np.clip(x, -limit, limit), mask)
            x *= target / _rms(x)
        largest = float(np.max(np.abs(x)))
        if largest > limit:
            # the clip only removes rounding of the scale (a few ulp)
            x = np.clip(x * (limit / largest), -limit, limit)
    return x


def prbs(amplitude, register_length, clock_divider, sample_rate_hz, periods=1) -> np.ndarray:
    """Maximum-length pseudo-random binary sequence of ``+-amplitude``.

    One period is the ``2**register_length - 1`` bits of
    :func:`scipy.signal.max_len_seq` (all-ones initial state), each bit held for
    ``clock_divider`` samples, so a period lasts
    ``(2**register_length - 1) * clock_divider`` samples.  Bit 1 maps to
    ``+amplitude``, bit 0 to ``-amplitude``; a period has one more ``+`` bit
    than ``-`` bits.  Its spectrum is flat to about ``0.44 * sample_rate_hz /
    clock_divider`` (the -3 dB point of the hold).

    ``sample_rate_hz`` only validates the call; the result is a sample sequence.
    """
    a = chk.positive("amplitude", amplitude)
    chk.positive("sample_rate_hz", sample_rate_hz)
    nbits = chk.integer("register_length", register_length, 2, 32)
    hold = chk.integer("clock_divider", clock_divider, 1)
    n_periods = chk.integer("periods", periods, 1)
    period_samples = (2**nbits - 1) * hold
    chk.at_most("clock_divider" if hold > 1 else "register_length", period_samples)
    chk.at_most("periods", period_samples * n_periods)
    import scipy.signal

    bits, _ = scipy.signal.max_len_seq(nbits)
    one_period = np.repeat(np.where(bits == 1, a, -a).astype(np.float64), hold)
    return np.tile(one_period, n_periods)


@dataclass(frozen=True, eq=False)
class Multisine:
    """A periodic multisine and its frequency lines.

    Attributes
    ----------
    samples : ndarray
        ``n_periods * period_samples`` samples, read-only.
    period_samples : int
        Samples in one period.
    excited_bins : ndarray of int
        DFT bins ``k`` of one period that carry a line (frequency ``k * fs / period_samples``).
    frequency_hz : ndarray
        Frequencies of the excited lines in Hz.
    """

    samples: np.ndarray
    period_samples: int
    excited_bins: np.ndarray
    frequency_hz: np.ndarray


def _log_bins(k_min: int, k_max: int, lines_per_decade: float) -> np.ndarray:
    decades = math.log10(k_max / k_min)
    count = max(2, int(math.ceil(lines_per_decade * decades)) + 1)
    return np.unique(np.round(np.geomspace(k_min, k_max, count)).astype(np.int64))


def _schroeder_phases(bins: np.ndarray) -> np.ndarray:
    """Schroeder phases for equal-power lines on any set of bins.

    The group delay of line ``i`` is ``i / K`` of a period (the signal sweeps
    through its lines once per period, like a chirp) and the phase is its
    integral over frequency.  For consecutive bins this is Schroeder's
    ``phi_i = -pi * i * (i + 1) / K`` (``i`` counted from 0).
    """
    n_lines = bins.size
    steps = np.diff(bins) * np.arange(1, n_lines) / n_lines
    return -2.0 * np.pi * np.concatenate(([0.0], np.cumsum(steps)))


def multisine(
    amplitude,
    f_min_hz,
    f_max_hz,
    period_s,
    n_periods,
    sample_rate_hz,
    phases="schroeder",
    spacing="linear",
    *,
    seed=None,
    lines_per_decade=20.0,
) -> Multisine:
    """Periodic sum of equal-amplitude cosines on exact DFT bins of one period.

    The period is ``round(period_s * sample_rate_hz)`` samples, so line ``k`` sits at
    exactly ``k / period``: averaging whole periods gives no leakage.

    Parameters
    ----------
    amplitude : float
        Peak of the result (the signal is scaled after the phases are chosen).
    f_min_hz, f_max_hz : float
        Band; lines are the bins with ``f_min_hz <= k / period <= f_max_hz``,
        ``k >= 1`` and below Nyquist.
    period_s : float
        Period length in s (sets the line spacing ``1 / period_s``).
    n_periods : int
        Number of periods returned.
    sample_rate_hz : float
        Sample rate.
    phases : {"schroeder", "random"} or array_like
        ``"schroeder"``: low crest factor on a linear grid (about 1.7 for 100
        consecutive lines, see :func:`_schroeder_phases`; on a sparse log grid
        the gain over random phases mostly vanishes, crest factor about 3.5-4);
        ``"random"``: uniform phases from ``default_rng(seed)``; or one phase in
        rad per excited line.
    spacing : {"linear", "log"}
        ``"linear"``: every bin in the band.  ``"log"``: about
        ``lines_per_decade`` bins per decade, geometrically spaced and rounded
        to unique bins (so the lowest lines may be denser than log spacing).
    seed : int, optional
        Seed for ``phases="random"``.
    lines_per_decade : float
        Density of the log grid.

    Returns
    -------
    Multisine
    """
    fs = chk.positive("sample_rate_hz", sample_rate_hz)
    a = chk.positive("amplitude", amplitude)
    f_min = chk.non_negative("f_min_hz", f_min_hz)
    f_max = chk.below_nyquist("f_max_hz", chk.positive("f_max_hz", f_max_hz), fs)
    if f_min >= f_max:
        raise ConfigError("f_min_hz", f"must be below f_max_hz {f_max:g} Hz, got {f_min:g}")
    period = chk.n_samples("period_s", chk.positive("period_s", period_s), fs)
    count = chk.integer("n_periods", n_periods, 1)
    chk.at_most("n_periods", period * count)
    if spacing not in ("linear", "log"):
        raise ConfigError("spacing", f"must be 'linear' or 'log', got {chk.show(spacing)}")

    df = fs / period
    k_min = max(1, int(math.ceil(f_min / df - 1e-9)))
    k_max = min((period - 1) // 2, int(math.floor(f_max / df + 1e-9)))
    if k_max < k_min:
        raise ConfigError(
            "period_s",
            f"no frequency line (spacing {df:g} Hz) lies in [{f_min:g}, {f_max:g}] Hz; "
            "lengthen the period or widen the band",
        )
    if spacing == "linear":
        bins = np.arange(k_min, k_max + 1, dtype=np.int64)
    else:
        lpd = chk.positive("lines_per_decade", lines_per_decade)
        bins = _log_bins(k_min, k_max, lpd) if k_max > k_min else np.array([k_min])

    if isinstance(phases, str):
        if phases == "schroeder":
            phi = _schroeder_phases(bins)
        elif phases == "random":
            if seed is None:
                raise ConfigError("seed", "phases='random' needs an explicit seed")
            phi = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, bins.size)
        else:
            raise ConfigError("phases", f"must be 'schroeder', 'random' or an array, got {chk.show(phases)}")
    else:
        phi = np.asarray(phases, dtype=float).ravel()
        if phi.size != bins.size or not np.all(np.isfinite(phi)):
            raise ConfigError("phases", f"needs {bins.size} finite phases (one per line), got {phi.size}")

    spectrum = np.zeros(period // 2 + 1, dtype=complex)
    spectrum[bins] = np.exp(1j * phi)
    one_period = np.fft.irfft(spectrum, n=period)
    i_peak = int(np.argmax(np.abs(one_period)))
    one_period *= a / abs(one_period[i_peak])
    one_period[i_peak] = math.copysign(a, one_period[i_peak])  # exact peak despite rounding
    return Multisine(
        samples=_frozen(np.tile(one_period, count)),
        period_samples=period,
        excited_bins=_frozen(bins),
        frequency_hz=_frozen(bins * df),
    )


# --------------------------------------------------------------------------- friction runs


@dataclass(frozen=True, eq=False)
class RampProfile:
    """Velocity setpoint for constant-velocity friction tests.

    Attributes
    ----------
    setpoint_mps : ndarray
        Velocity setpoint per sample in m/s, read-only; starts and ends at 0.
    windows : tuple of (int, int, float)
        ``(start_index, stop_index, velocity_mps)`` of every constant-velocity
        stretch after settling; ``setpoint_mps[start:stop] == velocity_mps``.
    speeds_mps : tuple of float
        The requested speeds, as passed.
    excursion_m : (float, float)
        Lowest and highest position reached, in m relative to the start
        (trapezoidal integral of the setpoint), for checking a travel window.
    """

    setpoint_mps: np.ndarray
    windows: tuple[tuple[int, int, float], ...]
    speeds_mps: tuple[float, ...]
    excursion_m: tuple[float, float]

    @property
    def max_excursion_m(self) -> float:
        """Largest distance from the start position in m."""
        return max(abs(self.excursion_m[0]), abs(self.excursion_m[1]))


def velocity_ramps(speeds_mps, hold_s, accel_mps2, sample_rate_hz, settle_s, alternate=True) -> RampProfile:
    """Trapezoidal velocity legs, one per speed, for steady-state friction tests.

    Each leg starts at rest, ramps to ``v`` at (at most) ``accel_mps2``, holds
    ``v`` for ``hold_s`` and ramps back to 0.  With ``alternate`` every leg is
    followed by its mirror image at ``-v``, so the axis returns to its start
    position (the net displacement is 0 up to rounding) and friction is measured
    in both directions.  The first ``settle_s`` of every hold is left out of the
    measurement windows so the velocity loop can settle.

    Parameters
    ----------
    speeds_mps : sequence of float
        Non-zero speeds in m/s (sign sets the direction of the first leg).
    hold_s : float
        Constant-velocity time per leg in s.
    accel_mps2 : float
        Largest acceleration in m/s^2; ramps take ``ceil(|v| / accel * fs)`` samples.
    sample_rate_hz : float
        Setpoint rate.
    settle_s : float
        Time in s at the start of each hold excluded from its window, ``0 <= settle_s < hold_s``.
    alternate : bool
        Follow every leg by the same leg at ``-v``.

    Examples
    --------
    >>> p = velocity_ramps([0.01, 0.05], hold_s=2.0, accel_mps2=0.5,
    ...                    sample_rate_hz=1000.0, settle_s=0.5)
    >>> [w[2] for w in p.windows]
    [0.01, -0.01, 0.05, -0.05]
    """
    fs, legs, ramps, n_hold, n_settle = _ramp_legs(speeds_mps, hold_s, accel_mps2, sample_rate_hz, settle_s, alternate)
    speeds = tuple(legs[::2] if alternate else legs)
    pieces: list[np.ndarray] = []
    windows: list[tuple[int, int, float]] = []
    position = 0
    for v, n_ramp in zip(legs, ramps, strict=False):
        up = v * np.arange(n_ramp) / n_ramp  # 0 .. v (exclusive)
        hold_start = position + n_ramp
        windows.append((hold_start + n_settle, hold_start + n_hold, float(v)))
        pieces += [up, np.full(n_hold, v), up[::-1]]
        position = hold_start + n_hold + n_ramp
    setpoint = np.concatenate(pieces)
    travel = position_of(setpoint, fs)
    return RampProfile(
        setpoint_mps=_frozen(setpoint),
        windows=tuple(windows),
        speeds_mps=speeds,
        excursion_m=(float(travel.min()), float(travel.max())),
    )


def position_of(velocity_mps, sample_rate_hz) -> np.ndarray:
    """The position a velocity set-point leads to, relative to the start (trapezoidal integral), m.

    A position-controlled axis follows this profile to run a velocity profile
    (e.g. the friction test on a drive that has no velocity mode).

    Examples
    --------
    >>> position_of([0.0, 1.0, 1.0, 0.0], sample_rate_hz=10.0).round(3).tolist()
    [0.0, 0.05, 0.15, 0.2]
    """
    fs = chk.positive("sample_rate_hz", sample_rate_hz)
    import scipy.integrate

    return scipy.integrate.cumulative_trapezoid(np.asarray(velocity_mps, dtype=float), dx=1.0 / fs, initial=0.0)


# --------------------------------------------------------------------------- helpers


def fade(x, ramp_s, sample_rate_hz) -> np.ndarray:
    """Raised-cosine fade-in over the first and fade-out over the last ``ramp_s``.

    The first and last samples become exactly 0, so a torque excitation starts
    and ends without a step.  Returns a new array; ``ramp_s = 0`` returns a copy.
    """
    y = np.array(x, dtype=np.float64)
    if y.ndim != 1:
        raise DataError(f"x must be one-dimensional, got shape {y.shape}")
    fs = chk.positive("sample_rate_hz", sample_rate_hz)
    n_ramp = int(round(chk.non_negative("ramp_s", ramp_s) * fs))
    if 2 * n_ramp > y.size:
        raise ConfigError("ramp_s", f"two ramps of {n_ramp} samples do not fit into {y.size} samples")
    if n_ramp:
        w = 0.5 - 0.5 * np.cos(np.pi * np.arange(n_ramp) / n_ramp)
        y[:n_ramp] *= w
        y[y.size - n_ramp :] *= w[::-1]
    return y


def crest_factor(x) -> float:
    """Peak over rms, ``max|x| / sqrt(mean(x**2))``; sqrt(2) for a sine."""
    y = np.asarray(x, dtype=np.float64)
    if y.size == 0 or not np.all(np.isfinite(y)):
        raise DataError("x must be a non-empty array of finite samples")
    rms = _rms(y)
    if rms == 0.0:
        raise DataError("crest factor of an all-zero signal is undefined")
    return float(np.max(np.abs(y)) / rms)
