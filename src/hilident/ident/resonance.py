"""Resonances (frequency, damping) picked from a measured frequency response.

Peaks of ``|H|`` are searched among the bins whose coherence is high enough,
then each is refined by a local rational fit, so that frequency and damping
come from a fitted pole pair rather than from the grid of the FFT. The local
model around a peak at ``w_p`` is, with ``x = s / w_p``::

    H(x) = N(x) / (x (x^2 + a1 x + a0)),     deg N = 4

which is exactly one mode plus a rigid-body term ``c/s`` plus ``c0 + c1 s``
(partial fractions: ``(b1 x + b0)/D(x) + c_-1/x + c0 + c1 x``). The two-mass
velocity response of thesis eqs. 2.1-2.2 has this form exactly; the
anti-resonance next to its peak is the zero of ``N`` and needs no special
treatment. The fit is linear after multiplying out the denominator (Levy),
then re-weighted by ``1 / |x D(x)|`` of the previous iterate
(Sanathanan-Koerner) until the denominator settles, so the error minimised
is the error in ``H`` itself. Each bin is weighted by the inverse of the
standard deviation of an H1 estimate implied by its coherence,
``|H| sqrt((1 - coh) / coh)``.

Examples
--------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.frequency import FrequencyResponse
>>> from hilident.ident.resonance import find_resonances
>>> w0, zeta = 2 * np.pi * 30.0, 0.05
>>> f = np.arange(0.5, 100.0, 0.5)
>>> h = signal.freqs([w0**2], [1.0, 2 * zeta * w0, w0**2], 2 * np.pi * f)[1]
>>> (r,) = find_resonances(FrequencyResponse(f, h, np.ones(f.size), 20, "h1"))
>>> print(f"{r.frequency_hz:.3f} Hz, zeta {r.damping_ratio:.4f}, {r.method}")
30.000 Hz, zeta 0.0500, fit
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hilident.errors import ConfigError
from hilident.ident.frequency import FrequencyResponse

__all__ = ["Resonance", "RejectedPeak", "find_resonances", "screen_resonances", "fit_local_mode"]

# Least height of a peak over its local background, in standard deviations of
# |H| in dB implied by the coherence.
_NOISE_SIGMAS = 5.0
# Two-sided 95 % quantile of the normal distribution.
_Z95 = 1.959963984540054
_DB = 20.0 / np.log(10.0)
# Least scatter (dB) a bin is judged against in Resonance.local_fit_ratio: the
# model error a single mode plus background may leave on real data.
_MODEL_FLOOR_DB = 0.25


@dataclass(frozen=True)
class Resonance:
    """One resonance of a measured frequency response.

    Attributes
    ----------
    frequency_hz : float
        Undamped natural frequency ``w_n / 2 pi`` of the fitted pole pair, Hz
        (the peak frequency for the fallbacks).
    damping_ratio : float
        Damping ratio zeta of the pole pair (NaN if unknown).
    peak_magnitude_db : float
        Largest ``|H|`` of the local model in the fitted band, dB; for the
        fallbacks the largest measured bin.
    coherence : float
        Coherence at the peak bin.
    method : str
        ``"fit"`` (local rational fit), ``"half_power"`` (fit failed; zeta from
        the -3 dB bandwidth, frequency from the peak bin) or ``"peak"``
        (neither worked; damping unknown).
    frequency_ci95_hz : float
        Half-width of the 95 % confidence interval of `frequency_hz`, Hz,
        from the local fit's covariance (residual variance times the inverse
        normal matrix of the last Sanathanan-Koerner step); NaN without a fit.
        Neighbouring bins of a Welch estimate are correlated, so the true
        interval is somewhat wider.
    damping_ci95 : float
        The same for `damping_ratio`.
    local_fit_db_rms : float
        rms of ``20 log10 |model / H|`` over the bins of the local fit, dB
        (NaN without a fit).
    local_noise_db_rms : float
        rms over the same bins of the standard deviation of ``|H|`` in dB that
        the coherence and the number of averages imply: what a perfect model
        would leave (NaN without coherence).
    prominence_db : float
        Prominence of the peak bin (``scipy.signal.find_peaks``), dB; NaN when
        not set.
    local_fit_ratio : float
        rms over the bins of the local fit of ``20 log10 |model / H|`` divided
        by each bin's own standard deviation in dB (at least 0.25 dB, for model
        error): about 1 when the model explains the peak to within the noise
        (NaN without a fit or coherence).
    """

    frequency_hz: float
    damping_ratio: float
    peak_magnitude_db: float
    coherence: float
    method: str = "fit"
    frequency_ci95_hz: float = float("nan")
    damping_ci95: float = float("nan")
    local_fit_db_rms: float = float("nan")
    local_noise_db_rms: float = float("nan")
    prominence_db: float = float("nan")
    local_fit_ratio: float = float("nan")

    @property
    def bandwidth_hz(self) -> float:
        """Half-power bandwidth ``2 zeta f``, Hz (NaN when the damping is unknown)."""
        return 2.0 * self.damping_ratio * self.frequency_hz

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class RejectedPeak:
    """A peak of ``|H|`` that is not reported as a resonance, and why.

    Attributes
    ----------
    frequency_hz : float
        Frequency of the peak bin, Hz.
    peak_magnitude_db : float
        ``|H|`` at the peak bin, dB.
    coherence : float
        Mean coherence of the peak bin and two neighbours either side.
    reason : str
        What failed, with the numbers (coherence, height over the scatter,
        count limit, duplicate).
    """

    frequency_hz: float
    peak_magnitude_db: float
    coherence: float
    reason: str

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _weights(H: np.ndarray, coh: np.ndarray) -> np.ndarray:
    """Inverse standard deviation of H implied by the coherence (up to a factor)."""
    if not np.all(np.isfinite(coh)):
        return np.ones(H.size)
    c = np.clip(coh, 1e-3, 0.999)
    return np.sqrt(c / (1.0 - c)) / np.maximum(np.abs(H), np.finfo(float).tiny)


@dataclass(frozen=True)
class _LocalFit:
    frequency_hz: float
    damping_ratio: float
    model: Callable[[np.ndarray], np.ndarray]  # the fitted FRF at frequencies in Hz
    frequency_std_hz: float
    damping_std: float


def _fit_local(f, H, w, fc, iterations) -> _LocalFit | None:
    """Levy + Sanathanan-Koerner fit of ``N(x) / (x D(x))``; see :func:`fit_local_mode`."""
    x = 1j * f / fc
    scale = float(np.max(np.abs(H)))
    Hn = H / scale
    xp = x[:, None] ** np.arange(5)  # 1, x, ..., x^4 for N(x)
    # Unknowns: a1, a0, n0..n4.  Hn x D(x) - N(x) = 0 with D = x^2 + a1 x + a0.
    A = np.column_stack([Hn * x**2, Hn * x, -xp])
    b = -Hn * x**3
    a_prev = None
    sk = np.ones(f.size)
    theta = np.zeros(A.shape[1])
    for _ in range(iterations + 1):
        ww = w * sk
        Ar = np.vstack([(A * ww[:, None]).real, (A * ww[:, None]).imag])
        br = np.concatenate([(b * ww).real, (b * ww).imag])
        col = np.linalg.norm(Ar, axis=0)
        col[col == 0.0] = 1.0
        try:
            sol, *_ = np.linalg.lstsq(Ar / col, br, rcond=None)
        except np.linalg.LinAlgError:
            return None
        theta = sol / col
        a1, a0 = theta[0], theta[1]
        D = x * (x**2 + a1 * x + a0)
        if not np.all(np.isfinite(D)) or np.any(D == 0):
            return None
        sk = 1.0 / np.abs(D)
        if a_prev is not None and np.allclose((a1, a0), a_prev, rtol=1e-10, atol=1e-12):
            break
        a_prev = (a1, a0)
    a1, a0 = theta[0], theta[1]
    # Stable complex pair: a1 > 0 and a1^2 < 4 a0.
    if not (a0 > 0.0 and 0.0 < a1 < 2.0 * np.sqrt(a0)):
        return None
    wn = np.sqrt(a0)
    zeta = a1 / (2.0 * wn)
    num = theta[2:][::-1]

    # Covariance of (a1, a0) of the last (linear) step: residual variance
    # times the inverse normal matrix, then first-order propagation.
    dof = br.size - theta.size
    f_std = z_std = float("nan")
    if dof > 0:
        An = Ar / col
        resid = br - An @ sol
        sigma2 = float(resid @ resid) / dof
        try:
            cov = sigma2 * np.linalg.pinv(An.T @ An)[:2, :2] / np.outer(col[:2], col[:2])
        except np.linalg.LinAlgError:
            cov = None
        if cov is not None and np.all(np.isfinite(cov)):
            # fn = fc sqrt(a0); zeta = a1 / (2 sqrt(a0))
            g_f = np.array([0.0, fc / (2.0 * wn)])
            g_z = np.array([1.0 / (2.0 * wn), -a1 / (4.0 * wn**3)])
            f_std = float(np.sqrt(max(g_f @ cov @ g_f, 0.0)))
            z_std = float(np.sqrt(max(g_z @ cov @ g_z, 0.0)))

    def model(f_hz):
        xx = 1j * np.asarray(f_hz, dtype=np.float64) / fc
        return scale * np.polyval(num, xx) / (xx * (xx**2 + a1 * xx + a0))

    return _LocalFit(float(wn * fc), float(zeta), model, f_std, z_std)


def fit_local_mode(
    frequency_hz: np.ndarray,
    response: np.ndarray,
    weights: np.ndarray | None = None,
    center_hz: float | None = None,
    iterations: int = 30,
):
    """Fit one pole pair plus background ``N(s) / (s D(s))`` to FRF points.

    Parameters
    ----------
    frequency_hz : ndarray
        Frequencies of the points, Hz (> 0), at least 4.
    response : ndarray of complex
        Measured response at those frequencies.
    weights : ndarray, optional
        Weight per point (inverse standard deviation of `response`).
    center_hz : float, optional
        Frequency used to normalise ``s``; default the mean of `frequency_hz`.
    iterations : int
        Most Sanathanan-Koerner iterations after the Levy start.

    Returns
    -------
    (frequency_hz, damping_ratio, model) or None
        Natural frequency (Hz) and damping ratio of the pole pair, and a
        callable ``model(f_hz) -> complex response``; None when the points do
        not yield a stable, complex pole pair.
    """
    f = np.asarray(frequency_hz, dtype=np.float64)
    H = np.asarray(response, dtype=np.complex128)
    if f.size < 4:
        return None
    w = np.ones(f.size) if weights is None else np.asarray(weights, dtype=np.float64)
    fc = float(np.mean(f)) if center_hz is None else float(center_hz)
    fit = _fit_local(f, H, w, fc, iterations)
    return None if fit is None else (fit.frequency_hz, fit.damping_ratio, fit.model)


def _half_power(f: np.ndarray, mag2: np.ndarray, i: int):
    """Half-power (-3 dB) crossings either side of bin i, linearly interpolated.

    Returns ``(f_left, f_right)``; an entry is None when ``|H|^2`` does not
    fall to half its peak value on that side.
    """
    half = mag2[i] / 2.0
    below = np.flatnonzero(mag2 <= half)
    left, right = below[below < i], below[below > i]

    def cross(j, k):  # j inside the peak, k the first bin below half power
        t = (mag2[j] - half) / (mag2[j] - mag2[k])
        return float(f[j] + t * (f[k] - f[j]))

    f_left = cross(left[-1] + 1, left[-1]) if left.size else None
    f_right = cross(right[0] - 1, right[0]) if right.size else None
    return f_left, f_right


def _noise_db(coh: np.ndarray, n_averages: int) -> np.ndarray:
    """Standard deviation of ``|H|`` in dB implied by the coherence, ``sqrt((1 - coh) / (2 n coh))``."""
    c = np.clip(coh, 1e-6, 1.0)
    return _DB * np.sqrt((1.0 - c) / (2.0 * max(n_averages, 1) * c))


def _refine(f, H, coh, i, df, n_averages=1):
    """Resonance at peak bin i: local fit, else half-power, else the peak."""
    mag2 = np.abs(H) ** 2
    fp = f[i]
    lo, hi = _half_power(f, mag2, i)
    if lo is not None and hi is not None:
        half_width = (hi - lo) / 2.0
    elif lo is not None or hi is not None:
        half_width = abs(fp - (lo if lo is not None else hi))
    else:
        half_width = None

    # Fit band: a few half-power widths either side, at least 8 bins, at most
    # +-50 % of the peak frequency.
    reach = 4.0 * half_width if half_width is not None else 0.2 * fp
    reach = min(max(reach, 8.0 * df), 0.5 * fp)
    sel = (f >= fp - reach) & (f <= fp + reach)
    fit = None
    if np.count_nonzero(sel) >= 8:
        fit = _fit_local(f[sel], H[sel], _weights(H[sel], coh[sel]), fp, 30)
    if fit is not None:
        fn, zeta = fit.frequency_hz, fit.damping_ratio
        if fp - reach < fn < fp + reach and 0.0 < zeta < 1.0:
            grid = np.linspace(fp - reach, fp + reach, 1024)
            peak_db = float(20.0 * np.log10(np.max(np.abs(fit.model(grid)))))
            with np.errstate(divide="ignore", invalid="ignore"):
                err_db = 20.0 * np.log10(np.abs(fit.model(f[sel]) / H[sel]))
            fit_db = float(np.sqrt(np.mean(err_db**2)))
            noise_db, ratio = float("nan"), float("nan")
            if np.all(np.isfinite(coh[sel])):
                sigma = _noise_db(coh[sel], n_averages)
                noise_db = float(np.sqrt(np.mean(sigma**2)))
                # each bin against its own scatter: the low-coherence bins of a nearby
                # anti-resonance count little; the floor stands for model error
                ratio = float(np.sqrt(np.mean((err_db / np.maximum(sigma, _MODEL_FLOOR_DB)) ** 2)))
            return Resonance(
                fn,
                zeta,
                peak_db,
                float(coh[i]),
                "fit",
                _Z95 * fit.frequency_std_hz,
                _Z95 * fit.damping_std,
                fit_db,
                noise_db,
                local_fit_ratio=ratio,
            )
    peak_db = float(10.0 * np.log10(mag2[i]))
    if half_width is not None:
        return Resonance(float(fp), float(half_width / fp), peak_db, float(coh[i]), "half_power")
    return Resonance(float(fp), float("nan"), peak_db, float(coh[i]), "peak")


def _stands_out(mag_db: np.ndarray, i: int, coh: float, n_averages: int) -> tuple[float, float]:
    """How far peak bin i rises above its surroundings, and how far it must (both dB).

    The surroundings are about four half-power widths either side (at least
    10 bins); their median level is the background, insensitive to the deep
    dips that low-coherence bins show in dB. The peak must exceed it by
    `_NOISE_SIGMAS` standard deviations of ``|H|`` in dB implied by the
    coherence, ``std(|H|) / |H| = sqrt((1 - coh) / (2 n coh))``. Random
    scatter forms local maxima a few deviations high, resonances far more.
    """
    below = np.flatnonzero(mag_db[:i] <= mag_db[i] - 3.0)
    above = np.flatnonzero(mag_db[i + 1 :] <= mag_db[i] - 3.0)
    left = i - below[-1] if below.size else i
    right = above[0] + 1 if above.size else mag_db.size - 1 - i
    reach = max(10, 2 * (left + right))
    window = mag_db[max(0, i - reach) : i + reach + 1]
    background = np.median(window[np.isfinite(window)])
    sigma_db = float(_noise_db(np.array([coh]), n_averages)[0])
    return float(mag_db[i] - background), _NOISE_SIGMAS * sigma_db


def find_resonances(
    frf: FrequencyResponse,
    coherence_threshold: float | None = 0.8,
    min_prominence_db: float = 3.0,
    max_count: int = 4,
    band_hz: tuple[float, float] | None = None,
) -> list[Resonance]:
    """Resonances of a measured frequency response, sorted by frequency.

    Local maxima of ``|H|`` in dB with at least `min_prominence_db` of
    prominence (``scipy.signal.find_peaks``) are candidates. With a coherence
    threshold, a candidate is kept when

    * the mean coherence of the peak bin and two neighbours either side
      reaches `coherence_threshold`, and
    * the peak stands out of its surroundings (median level over about four
      half-power half-widths either side) by five standard deviations of
      ``|H|`` in dB implied by that coherence and ``frf.n_averages``, which
      rejects the ripples of estimation noise.

    The `max_count` most prominent candidates are refined by
    :func:`fit_local_mode` over four half-power half-widths either side of the
    peak (at least 8 bins, at most +-50 % of the peak frequency). When the fit
    gives no stable complex pole pair in that band, the result falls back to
    the half-power bandwidth (``method="half_power"``). Refinements closer
    than ``zeta * f`` to an earlier one are merged.

    Parameters
    ----------
    frf : FrequencyResponse
        Measured response, e.g. from :func:`~hilident.ident.frequency.h1_estimate`.
    coherence_threshold : float or None
        Lowest coherence accepted around a peak, in [0, 1]. None skips both
        coherence tests and accepts every prominent peak (for estimates
        without coherence, such as the ETFE, or noise-free data).
    min_prominence_db : float
        Least prominence of a peak, dB.
    max_count : int
        Most resonances returned.
    band_hz : (float, float), optional
        Only search ``f_lo <= f <= f_hi`` (Hz).

    Returns
    -------
    list of Resonance
        Empty when no bin qualifies, e.g. when coherence is low everywhere.
    """
    found, _ = screen_resonances(frf, coherence_threshold, min_prominence_db, max_count, band_hz)
    return found


def screen_resonances(
    frf: FrequencyResponse,
    coherence_threshold: float | None = 0.8,
    min_prominence_db: float = 3.0,
    max_count: int = 4,
    band_hz: tuple[float, float] | None = None,
    max_rejected: int = 8,
) -> tuple[list[Resonance], list[RejectedPeak]]:
    """:func:`find_resonances`, and the prominent peaks it did not report with the reason.

    Parameters are those of :func:`find_resonances`, and

    max_rejected : int
        Most rejected peaks listed (the most prominent ones): noise makes
        many small peaks where the coherence is low.

    Returns
    -------
    (list of Resonance, list of RejectedPeak)
        Both sorted by frequency.
    """
    _check_screen_limits(coherence_threshold, min_prominence_db, max_count)
    idx = _usable_bins(frf, band_hz)
    if idx.size < 3:
        return [], []
    f, H, coh = frf.frequency_hz[idx], frf.response[idx], frf.coherence[idx]
    df = float(np.median(np.diff(f)))

    mag_db = 20.0 * np.log10(np.abs(H))
    peaks, props = signal.find_peaks(mag_db, prominence=min_prominence_db)
    prominence = props["prominences"]
    # A resonance spans several bins: judge the coherence around the peak,
    # not at one bin that noise may have lifted over the threshold.
    near = np.clip(peaks[:, None] + np.arange(-2, 3), 0, f.size - 1)
    coh_near = np.nan_to_num(coh[near], nan=0.0).mean(axis=1) if peaks.size else np.zeros(0)
    rejected: list[tuple[float, RejectedPeak]] = []  # (prominence, peak)

    def reject(i, c, reason):
        rejected.append((float(prom_of[int(i)]), RejectedPeak(float(f[i]), float(mag_db[i]), float(c), reason)))

    prom_of = dict(zip(peaks.tolist(), prominence.tolist(), strict=False))

    kept = []
    for i, p, c in zip(peaks, prominence, coh_near, strict=False):
        doubt = _doubt(mag_db, int(i), c, coherence_threshold, frf.n_averages)
        if doubt:
            reject(i, c, doubt)
        else:
            kept.append((i, p, c))
    kept.sort(key=lambda k: -k[1])

    found: list[Resonance] = []
    for i, _, c in kept:
        if len(found) == max_count:
            reject(i, c, f"beyond the {max_count} most prominent peaks (identification.max_resonances)")
            continue
        res = dataclasses.replace(_refine(f, H, coh, int(i), df, frf.n_averages), prominence_db=float(prom_of[int(i)]))
        twin = _same_mode(res, found, df)
        if twin:
            reject(i, c, f"the same mode as the resonance at {twin[0].frequency_hz:.4g} Hz")
            continue
        found.append(res)
    # noise makes many small peaks where the coherence is low: list the most prominent
    listed = [r for _, r in sorted(rejected, key=lambda pr: -pr[0])[:max_rejected]]
    return sorted(found, key=lambda r: r.frequency_hz), sorted(listed, key=lambda r: r.frequency_hz)


def _check_screen_limits(coherence_threshold: float | None, min_prominence_db: float, max_count: int) -> None:
    if coherence_threshold is not None and not 0.0 <= coherence_threshold <= 1.0:
        raise ConfigError("coherence_threshold", f"must lie in [0, 1] or be None, got {coherence_threshold!r}")
    if not min_prominence_db >= 0.0:
        raise ConfigError("min_prominence_db", f"must be >= 0 dB, got {min_prominence_db!r}")
    if int(max_count) != max_count or max_count < 1:
        raise ConfigError("max_count", f"must be a positive integer, got {max_count!r}")


def _usable_bins(frf: FrequencyResponse, band_hz: tuple[float, float] | None) -> np.ndarray:
    """Indices of the bins at ``f > 0`` with a finite non-zero response, within `band_hz` when given."""
    f, H = frf.frequency_hz, frf.response
    valid = (f > 0.0) & np.isfinite(H) & (H != 0.0)
    if band_hz is not None:
        f_lo, f_hi = band_hz
        if not f_lo < f_hi:
            raise ConfigError("band_hz", f"must be (f_lo, f_hi) with f_lo < f_hi, got {band_hz!r}")
        valid &= (f >= f_lo) & (f <= f_hi)
    return np.flatnonzero(valid)


def _doubt(mag_db: np.ndarray, i: int, c: float, coherence_threshold: float | None, n_averages: int) -> str:
    """Why the peak at bin `i` (coherence `c` around it) is not a resonance the data show ("" when it is)."""
    if coherence_threshold is None:
        return ""
    if c < coherence_threshold:
        return (
            f"coherence {c:.3f} around the peak is under identification.coherence_threshold = {coherence_threshold:g}"
        )
    height, needed = _stands_out(mag_db, i, c, n_averages)
    if height < needed:
        return (
            f"rises {height:.1f} dB over its surroundings, within the scatter of the estimate "
            f"(needs {needed:.1f} dB: {_NOISE_SIGMAS:g} standard deviations at coherence {c:.3f} "
            f"over {n_averages} averages)"
        )
    return ""


def _same_mode(res: Resonance, found: list[Resonance], df: float) -> list[Resonance]:
    """The resonances already found within ``zeta f`` (at least a line) of `res`."""
    width = res.damping_ratio * res.frequency_hz if np.isfinite(res.damping_ratio) else df
    return [r for r in found if abs(res.frequency_hz - r.frequency_hz) <= max(width, df)]
