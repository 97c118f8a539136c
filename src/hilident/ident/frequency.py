"""Nonparametric frequency-response estimates with coherence.

* :func:`h1_estimate` -- open loop, random excitation: ``H1 = S_uy / S_uu``
  from Welch-averaged spectra, with the magnitude-squared coherence of thesis
  eq. 2.46, ``|S_uy|^2 / (S_uu S_yy)``.
* :func:`frf_from_reference` -- closed loop: the drive injects an excitation
  ``r`` into the torque command of its velocity loop; ``u`` (total torque) is
  then correlated with the output noise through the controller and H1 is
  biased towards ``-1/C``. ``S_ry / S_ru`` uses only what is correlated with
  ``r`` and is unbiased.
* :func:`periodic_frf` -- periodic excitation (multisine): DFT of whole
  periods, averaged, read at the excited bins; no leakage, no window.
* :func:`etfe` -- the empirical transfer function estimate: DFT of the output
  over DFT of the input over the whole record.
* :func:`welch_psd` -- power spectral density as ``scipy.signal.welch``.

The Welch and periodic estimates transform a block of segments (or periods)
at a time and sum the products, so their memory does not grow with the
record: a long recording needs little beyond its own samples.

Spectra are one-sided; frequencies in Hz. ``u`` and ``y`` are in whatever units
were recorded (N·m and m/s for a velocity FRF), the response in units of
``y / u``.

Examples
--------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.frequency import h1_estimate
>>> rng = np.random.default_rng(0)
>>> u = rng.standard_normal(100_000)
>>> y = signal.lfilter([0.2], [1.0, -0.8], u)
>>> frf = h1_estimate(u, y, sample_rate_hz=1000.0, segment_length=1024)
>>> bool(abs(abs(frf.response[0]) - 1.0) < 0.05)
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.gapped_periods import line_spectra, mean_period
from hilident.ident.preprocess import check_signals

__all__ = [
    "FrequencyResponse",
    "h1_estimate",
    "frf_from_reference",
    "periodic_frf",
    "etfe",
    "welch_psd",
]


@dataclass(frozen=True, eq=False)
class FrequencyResponse:
    """A measured frequency response.

    Attributes
    ----------
    frequency_hz : ndarray
        Frequencies, Hz, ascending.
    response : ndarray of complex
        ``y / u`` at those frequencies.
    coherence : ndarray
        Quality per frequency in [0, 1] (1 = output fully explained by a linear
        response to the input); NaN where an estimator has none (ETFE).
    n_averages : int
        Segments or periods averaged.
    method : str
        ``"h1"``, ``"reference"``, ``"periodic"`` or ``"etfe"``.
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    n_averages: int
    method: str

    def __post_init__(self):
        f = np.asarray(self.frequency_hz, dtype=np.float64)
        h = np.asarray(self.response, dtype=np.complex128)
        c = np.asarray(self.coherence, dtype=np.float64)
        if not (f.ndim == h.ndim == c.ndim == 1 and f.size == h.size == c.size):
            raise DataError(
                f"frequency_hz, response and coherence must be 1-D of equal length, got {f.shape}, {h.shape}, {c.shape}"
            )
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "response", h)
        object.__setattr__(self, "coherence", c)
        object.__setattr__(self, "n_averages", int(self.n_averages))

    def __len__(self) -> int:
        return self.frequency_hz.size

    def magnitude_db(self) -> np.ndarray:
        """``20 log10 |H|`` (``-inf`` where the response is 0)."""
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(np.abs(self.response))

    def phase_deg(self, unwrap: bool = False) -> np.ndarray:
        """Phase in degrees, in (-180, 180] or unwrapped along frequency."""
        phase = np.angle(self.response)
        if unwrap:
            phase = np.unwrap(phase)
        return np.degrees(phase)

    def band(self, f_lo: float, f_hi: float) -> FrequencyResponse:
        """Copy restricted to ``f_lo <= f <= f_hi`` (Hz)."""
        if not f_lo <= f_hi:
            raise ConfigError("f_lo", f"must not exceed f_hi={f_hi!r}, got {f_lo!r}")
        keep = (self.frequency_hz >= f_lo) & (self.frequency_hz <= f_hi)
        return FrequencyResponse(
            self.frequency_hz[keep].copy(),
            self.response[keep].copy(),
            self.coherence[keep].copy(),
            self.n_averages,
            self.method,
        )


def _check_rate(sample_rate_hz: float) -> float:
    fs = float(sample_rate_hz)
    if not np.isfinite(fs) or fs <= 0.0:
        raise ConfigError("sample_rate_hz", f"must be a positive number, got {sample_rate_hz!r}")
    return fs


def _welch_setup(n: int, segment_length: int, overlap: float) -> tuple[int, int, int]:
    if int(segment_length) != segment_length or segment_length < 8:
        raise ConfigError("segment_length", f"must be an integer >= 8, got {segment_length!r}")
    nperseg = int(segment_length)
    if nperseg > n:
        raise ConfigError("segment_length", f"{nperseg} exceeds the record length of {n} samples")
    if not 0.0 <= overlap < 1.0:
        raise ConfigError("overlap", f"must lie in [0, 1), got {overlap!r}")
    noverlap = int(round(overlap * nperseg))
    noverlap = min(noverlap, nperseg - 1)
    n_avg = 1 + (n - nperseg) // (nperseg - noverlap)
    return nperseg, noverlap, n_avg


#: Samples per signal transformed at once by :func:`_cross_spectra`: bounds its working memory
#: (about 15 MB for three signals) whatever the record length.
BLOCK_SAMPLES = 1 << 18


def _segment_blocks(
    signals: dict[str, np.ndarray],
    nperseg,
    noverlap,
    window,
    detrend,
    block_samples=None,
    offsets: dict[str, float] | None = None,
):
    """Windowed FFTs of the Welch segments, a block of segments at a time.

    Yields ``(count, ffts)`` with ``ffts[name]`` of shape ``(count, nperseg // 2 + 1)``.
    Only one block of segments (``block_samples`` samples per signal, at least
    one segment) is ever held: a long record needs no memory beyond its own.
    ``offsets[name]`` is subtracted from every sample of that signal first.
    """
    win = signal.get_window(window, nperseg)
    step = nperseg - noverlap
    views = {name: np.lib.stride_tricks.sliding_window_view(x, nperseg)[::step] for name, x in signals.items()}
    n_seg = len(next(iter(views.values())))
    per_block = max(1, int(block_samples or BLOCK_SAMPLES) // nperseg)
    for start in range(0, n_seg, per_block):
        ffts = {}
        for name, view in views.items():
            seg = view[start : start + per_block]
            if offsets and name in offsets:
                seg = seg - offsets[name]
            if detrend:
                seg = signal.detrend(seg, axis=-1, type=detrend)
            if seg.flags.writeable:  # a copy already: window it in place
                seg *= win
            else:  # the read-only view of the signal
                seg = seg * win
            ffts[name] = np.fft.rfft(seg, axis=-1)
        yield len(seg), ffts


def _cross_spectra(
    signals: dict[str, np.ndarray],
    pairs,
    nperseg,
    noverlap,
    window,
    detrend,
    block_samples=None,
    offsets: dict[str, float] | None = None,
):
    """Welch cross spectra ``S_ab = E[conj(A) B]`` for the requested pairs.

    Each signal is segmented, windowed and transformed once; every spectrum is
    then an average of products, so many pairs cost little more than one. The
    products are summed block by block (:func:`_segment_blocks`), so the memory
    needed does not grow with the record; auto spectra (``a == b``) come out
    real. ``offsets`` as for :func:`_segment_blocks`.
    """
    sums: dict = {}
    total = 0
    for count, ffts in _segment_blocks(signals, nperseg, noverlap, window, detrend, block_samples, offsets):
        total += count
        for a, b in pairs:
            if a == b:
                x = ffts[a]
                part = np.add.reduce(x.real * x.real + x.imag * x.imag, axis=0)
            else:
                part = np.add.reduce(np.conj(ffts[a]) * ffts[b], axis=0)
            if (a, b) in sums:
                sums[a, b] += part
            else:
                sums[a, b] = part
    # Density scaling and the one-sided factor cancel in every ratio used here.
    return {pair: s / total for pair, s in sums.items()}


def welch_psd(
    x: np.ndarray,
    sample_rate_hz: float,
    nperseg: int,
    noverlap: int | None = None,
    window: str = "hann",
    detrend: str | bool = "constant",
    subtract: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density by Welch's method, as ``scipy.signal.welch`` with its defaults.

    The same estimate (density scaling, unit^2/Hz, mean over segments) with
    the segments transformed a block at a time, so a long record needs no
    memory beyond its own (scipy holds every segment and its transform).

    Parameters
    ----------
    x : ndarray
        1-D float64 record.
    sample_rate_hz : float
        Sample rate, Hz.
    nperseg : int
        Samples per segment.
    noverlap : int, optional
        Samples shared by neighbouring segments; default ``nperseg // 2``.
    window : str
        Window name for ``scipy.signal.get_window``.
    detrend : {"constant", "linear", False}
        Per-segment detrending.
    subtract : float
        Taken off every sample first (e.g. the record's mean), a block at a
        time: the spectrum of ``x - subtract`` without a copy of the record.

    Returns
    -------
    frequency_hz, psd : ndarray
    """
    nperseg = int(nperseg)
    noverlap = nperseg // 2 if noverlap is None else int(noverlap)
    win = signal.get_window(window, nperseg)
    offsets = {"x": float(subtract)} if subtract else None
    p = _cross_spectra({"x": x}, [("x", "x")], nperseg, noverlap, window, detrend, offsets=offsets)["x", "x"]
    p = p / (sample_rate_hz * (win * win).sum())
    p[1 : None if nperseg % 2 else -1] *= 2.0  # one-sided: every bin but DC and Nyquist counts twice
    return np.fft.rfftfreq(nperseg, 1.0 / sample_rate_hz), p


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num / den
    return np.where(np.isfinite(out), out, np.nan)


def _coherence(s_ab: np.ndarray, s_aa: np.ndarray, s_bb: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.abs(s_ab) ** 2 / (np.real(s_aa) * np.real(s_bb))
    return np.clip(np.nan_to_num(c, nan=0.0, posinf=0.0), 0.0, 1.0)


def h1_estimate(
    u: ArrayLike,
    y: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    overlap: float = 0.5,
    window: str = "hann",
    detrend: str | bool = "constant",
) -> FrequencyResponse:
    """H1 frequency response ``S_uy / S_uu`` with magnitude-squared coherence.

    Welch averaging: the record is cut into segments of `segment_length`
    samples overlapping by `overlap`, each is detrended and windowed, and the
    auto and cross spectra are averaged. H1 is unbiased by noise on ``y`` (not
    by noise on ``u``, nor under feedback: see :func:`frf_from_reference`).
    The coherence ``|S_uy|^2 / (S_uu S_yy)`` (thesis eq. 2.46) is the fraction
    of the output power explained linearly by the input.

    Parameters
    ----------
    u, y : array_like
        Input (e.g. torque, N·m) and output (e.g. velocity, m/s), same length.
    sample_rate_hz : float
        Sample rate, Hz.
    segment_length : int
        Samples per segment; the frequency resolution is
        ``sample_rate_hz / segment_length``.
    overlap : float
        Fraction of a segment shared with the next one, in [0, 1).
    window : str
        Window name for ``scipy.signal.get_window``.
    detrend : {"constant", "linear", False}
        Per-segment detrending.

    Returns
    -------
    FrequencyResponse
        ``method="h1"``, ``n_averages`` = number of segments.
    """
    fs = _check_rate(sample_rate_hz)
    sig = check_signals({"u": u, "y": y}, copy=False)
    nperseg, noverlap, n_avg = _welch_setup(sig["u"].size, segment_length, overlap)
    S = _cross_spectra(sig, [("u", "u"), ("y", "y"), ("u", "y")], nperseg, noverlap, window, detrend)
    return FrequencyResponse(
        frequency_hz=np.fft.rfftfreq(nperseg, 1.0 / fs),
        response=_ratio(S["u", "y"], S["u", "u"]),
        coherence=_coherence(S["u", "y"], S["u", "u"], S["y", "y"]),
        n_averages=n_avg,
        method="h1",
    )


def frf_from_reference(
    r: ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    sample_rate_hz: float,
    segment_length: int,
    overlap: float = 0.5,
    window: str = "hann",
    detrend: str | bool = "constant",
) -> FrequencyResponse:
    """Closed-loop plant estimate ``G = S_ry / S_ru`` using the excitation `r`.

    In a velocity loop with excitation `r` added to the torque command, both
    ``u`` and ``y`` respond to ``r`` through the closed loop
    (``y = G S r + ...``, ``u = S r + ...``) while the noise reaches ``u``
    through the controller. Correlating both with the external `r` removes
    the noise: ``S_ry / S_ru = G S / S = G``, unbiased under feedback
    (the indirect or "joint input-output" method).

    The returned coherence is the product ``gamma2_ry * gamma2_ru``. Both
    spectra of the ratio carry noise, and for high coherence
    ``(1 - g_ry g_ru) / (g_ry g_ru)`` is close to the sum of the two
    noise-to-signal ratios that set the variance of ``G``, so the product reads
    like an ordinary coherence: near 1 where ``G`` is well determined.

    Parameters
    ----------
    r : array_like
        Injected excitation, same units as `u` (N·m).
    u : array_like
        Total plant input (torque command incl. excitation), N·m.
    y : array_like
        Plant output (velocity), m/s.
    sample_rate_hz, segment_length, overlap, window, detrend
        As for :func:`h1_estimate`.

    Returns
    -------
    FrequencyResponse
        ``method="reference"``.
    """
    fs = _check_rate(sample_rate_hz)
    sig = check_signals({"r": r, "u": u, "y": y}, copy=False)
    nperseg, noverlap, n_avg = _welch_setup(sig["r"].size, segment_length, overlap)
    pairs = [("r", "r"), ("u", "u"), ("y", "y"), ("r", "u"), ("r", "y")]
    S = _cross_spectra(sig, pairs, nperseg, noverlap, window, detrend)
    coh = _coherence(S["r", "y"], S["r", "r"], S["y", "y"]) * _coherence(S["r", "u"], S["r", "r"], S["u", "u"])
    return FrequencyResponse(
        frequency_hz=np.fft.rfftfreq(nperseg, 1.0 / fs),
        response=_ratio(S["r", "y"], S["r", "u"]),
        coherence=coh,
        n_averages=n_avg,
        method="reference",
    )


def _period_sums(
    u: np.ndarray, y: np.ndarray, period: int, skip: int, n_periods: int, block_samples: int | None = None
) -> dict[str, np.ndarray]:
    """Sums over whole periods of the DFTs ``U_m``, ``Y_m`` and of ``conj(U_m) Y_m``, ``|U_m|^2``, ``|Y_m|^2``.

    Every bin of one period, periods ``skip .. skip + n_periods - 1``,
    transformed a block of periods at a time (at least one; about
    ``block_samples`` samples), so the memory needed does not grow with the
    record.
    """
    per_block = max(1, int(block_samples or BLOCK_SAMPLES) // period)
    sums: dict[str, np.ndarray] = {}
    for first in range(skip, skip + n_periods, per_block):
        last = min(first + per_block, skip + n_periods)
        U = np.fft.rfft(u[first * period : last * period].reshape(last - first, period), axis=-1)
        Y = np.fft.rfft(y[first * period : last * period].reshape(last - first, period), axis=-1)
        parts = {
            "u": U,
            "y": Y,
            "uy": np.conj(U) * Y,
            "uu": U.real * U.real + U.imag * U.imag,
            "yy": Y.real * Y.real + Y.imag * Y.imag,
        }
        for name, part in parts.items():
            total = np.add.reduce(part, axis=0)
            if name in sums:
                sums[name] += total
            else:
                sums[name] = total
    return sums


def periodic_frf(
    u: ArrayLike,
    y: ArrayLike,
    period_samples: int,
    sample_rate_hz: float,
    skip_periods: int = 1,
    bins: ArrayLike | None = None,
    excitation_threshold_db: float = -40.0,
    present: ArrayLike | None = None,
) -> FrequencyResponse:
    """FRF from a periodic excitation (multisine, periodic chirp or PRBS).

    The first `skip_periods` periods (transient) are dropped, the rest are cut
    into whole periods ``m = 1..M`` and transformed without a window (periodic
    signals do not leak). Then ``G(k) = mean_m Y_m(k) / mean_m U_m(k)`` at the
    excited bins ``k`` (frequency ``k * sample_rate_hz / period_samples``).

    The quality is the coherence over periods,
    ``|sum U_m* Y_m|^2 / (sum |U_m|^2 sum |Y_m|^2)``. For an input repeated
    exactly it equals ``|mean Y|^2 / (|mean Y|^2 + var Y)`` with the
    period-to-period variance of ``Y``: 1 when the periods agree, falling as
    noise scatters them.

    Parameters
    ----------
    u, y : array_like
        Input and output, same length.
    period_samples : int
        Samples per excitation period.
    sample_rate_hz : float
        Sample rate, Hz.
    skip_periods : int
        Leading periods to drop.
    bins : array_like of int, optional
        DFT bin indices (1 .. period_samples // 2) to report. Default: every
        bin except DC whose mean input power lies within
        `excitation_threshold_db` of the strongest bin.
    excitation_threshold_db : float
        See `bins`.
    present : array_like of bool, optional
        Which samples exist (default: all). A period missing some is read at
        the excited bins by least squares on the samples it has
        (:func:`~hilident.ident.gapped_periods.line_spectra`; nothing is filled
        in), and left out when those cannot tell its lines apart. The values of
        ``u`` and ``y`` where a sample is missing are ignored.

    Returns
    -------
    FrequencyResponse
        ``method="periodic"``, ``n_averages`` = periods used (at least 2).
    """
    fs = _check_rate(sample_rate_hz)
    if present is not None:  # what is missing is not looked at
        present = np.asarray(present, dtype=bool)
        if present.shape != np.shape(u):
            raise DataError(f"present has {present.size} flags for {np.size(u)} samples")
        u, y = np.where(present, u, 0.0), np.where(present, y, 0.0)
    sig = check_signals({"u": u, "y": y}, copy=False)
    if int(period_samples) != period_samples or period_samples < 4:
        raise ConfigError("period_samples", f"must be an integer >= 4, got {period_samples!r}")
    if int(skip_periods) != skip_periods or skip_periods < 0:
        raise ConfigError("skip_periods", f"must be an integer >= 0, got {skip_periods!r}")
    P, skip = int(period_samples), int(skip_periods)
    n_periods = sig["u"].size // P - skip
    if n_periods < 2:
        raise DataError(
            f"{sig['u'].size} samples hold {sig['u'].size // P} periods of {P}; "
            f"after skipping {skip} at least 2 are needed"
        )
    if present is not None and not present.all():
        return _gapped_periodic_frf(sig["u"], sig["y"], present, P, fs, skip, bins, excitation_threshold_db)
    sums = _period_sums(sig["u"], sig["y"], P, skip, n_periods)
    u_mean = sums["u"] / n_periods
    if bins is None:
        power = np.abs(u_mean) ** 2
        power[0] = 0.0
        limit = power.max() * 10.0 ** (excitation_threshold_db / 10.0)
        k = np.flatnonzero(power > limit)
        if k.size == 0:
            raise DataError("input u excites no frequency bin (periodic part is zero)")
    else:
        k = np.unique(np.asarray(bins, dtype=np.int64))
        if k.size == 0 or k.min() < 1 or k.max() > P // 2:
            raise ConfigError("bins", f"must be indices in 1..{P // 2}, got {bins!r}")
    return FrequencyResponse(
        frequency_hz=k * fs / P,
        response=_ratio(sums["y"][k] / n_periods, u_mean[k]),
        coherence=_coherence(sums["uy"][k], sums["uu"][k], sums["yy"][k]),
        n_averages=n_periods,
        method="periodic",
    )


def _gapped_periodic_frf(
    u: np.ndarray,
    y: np.ndarray,
    present: np.ndarray,
    period: int,
    fs: float,
    skip: int,
    bins: ArrayLike | None,
    excitation_threshold_db: float,
) -> FrequencyResponse:
    """:func:`periodic_frf` of a record some of whose samples do not exist: each period's lines by least squares."""
    n_periods = u.size // period - skip
    cut = slice(skip * period, (skip + n_periods) * period)
    shape = (n_periods, period)
    u_p, y_p, ok = u[cut].reshape(shape), y[cut].reshape(shape), present[cut].reshape(shape)
    if bins is None:  # the excited bins, from the mean period (each sample over the periods that have it)
        power = np.abs(np.fft.rfft(mean_period(u_p, ok))) ** 2
        power[0] = 0.0
        if period % 2 == 0:
            power[-1] = 0.0  # the Nyquist line cannot be read around missing samples
        k = np.flatnonzero(power > power.max() * 10.0 ** (excitation_threshold_db / 10.0))
    else:
        k = np.unique(np.asarray(bins, dtype=np.int64))
    if k.size == 0 or k.min() < 1 or 2 * k.max() >= period:
        raise DataError(f"a record with missing samples is read at bins 1..{(period - 1) // 2} only, got {k!r}")
    U, used_u = line_spectra(u_p, ok, k)
    Y, used_y = line_spectra(y_p, ok, k)
    used = used_u & used_y
    if used.sum() < 2:
        raise DataError(
            f"only {int(used.sum())} of {n_periods} periods have samples enough to read their lines; at least 2 "
            "are needed"
        )
    U, Y = U[used], Y[used]
    m = len(U)
    return FrequencyResponse(
        frequency_hz=k * fs / period,
        response=_ratio(Y.mean(axis=0), U.mean(axis=0)),
        coherence=_coherence((np.conj(U) * Y).sum(axis=0), (np.abs(U) ** 2).sum(axis=0), (np.abs(Y) ** 2).sum(axis=0)),
        n_averages=m,
        method="periodic",
    )


def etfe(u: ArrayLike, y: ArrayLike, sample_rate_hz: float) -> FrequencyResponse:
    """Empirical transfer function estimate: ``DFT(y) / DFT(u)`` over the record.

    The raw ratio of the lecture: full resolution ``sample_rate_hz / N``, no
    averaging, so its variance does not shrink with record length. Bins where
    ``DFT(u)`` is zero give NaN. Coherence is undefined for a single record and
    returned as NaN.
    """
    fs = _check_rate(sample_rate_hz)
    sig = check_signals({"u": u, "y": y}, copy=False)
    n = sig["u"].size
    return FrequencyResponse(
        frequency_hz=np.fft.rfftfreq(n, 1.0 / fs),
        response=_ratio(np.fft.rfft(sig["y"]), np.fft.rfft(sig["u"])),
        coherence=np.full(n // 2 + 1, np.nan),
        n_averages=1,
        method="etfe",
    )
