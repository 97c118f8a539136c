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

Example
-------
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
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hilident.errors import ConfigError
from hilident.ident.frequency import FrequencyResponse

__all__ = ["Resonance", "find_resonances", "fit_local_mode"]

# Least height of a peak over its local background, in standard deviations of
# |H| in dB implied by the coherence.
_NOISE_SIGMAS = 5.0


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
    """

    frequency_hz: float
    damping_ratio: float
    peak_magnitude_db: float
    coherence: float
    method: str = "fit"

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _weights(H: np.ndarray, coh: np.ndarray) -> np.ndarray:
    """Inverse standard deviation of H implied by the coherence (up to a factor)."""
    if not np.all(np.isfinite(coh)):
        return np.ones(H.size)
    c = np.clip(coh, 1e-3, 0.999)
    return np.sqrt(c / (1.0 - c)) / np.maximum(np.abs(H), np.finfo(float).tiny)


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
    x = 1j * f / fc
    scale = float(np.max(np.abs(H)))
    Hn = H / scale
    xp = x[:, None] ** np.arange(5)  # 1, x, ..., x^4 for N(x)
    # Unknowns: a1, a0, n0..n4.  Hn x D(x) - N(x) = 0 with D = x^2 + a1 x + a0.
    A = np.column_stack([Hn * x**2, Hn * x, -xp])
    b = -Hn * x**3
    a_prev = None
    sk = np.ones(f.size)
    theta = None
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

    def model(f_hz):
        xx = 1j * np.asarray(f_hz, dtype=np.float64) / fc
        return scale * np.polyval(num, xx) / (xx * (xx**2 + a1 * xx + a0))

    return float(wn * fc), float(zeta), model


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


def _refine(f, H, coh, i, df):
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
        fit = fit_local_mode(f[sel], H[sel], _weights(H[sel], coh[sel]), center_hz=fp)
    if fit is not None:
        fn, zeta, model = fit
        if fp - reach < fn < fp + reach and 0.0 < zeta < 1.0:
            grid = np.linspace(fp - reach, fp + reach, 1024)
            peak_db = float(20.0 * np.log10(np.max(np.abs(model(grid)))))
            return Resonance(fn, zeta, peak_db, float(coh[i]), "fit")
    peak_db = float(10.0 * np.log10(mag2[i]))
    if half_width is not None:
        return Resonance(float(fp), float(half_width / fp), peak_db, float(coh[i]), "half_power")
    return Resonance(float(fp), float("nan"), peak_db, float(coh[i]), "peak")


def _stands_out(mag_db: np.ndarray, i: int, coh: float, n_averages: int) -> bool:
    """Whether peak bin i rises clearly above the scatter of its surroundings.

    The surroundings are about four half-power widths either side (at least
    10 bins); their median level is the background, insensitive to the deep
    dips that low-coherence bins show in dB. The peak must exceed it by
    `_NOISE_SIGMAS` standard deviations of ``|H|`` in dB implied by the
    coherence, ``std(|H|) / |H| = sqrt((1 - coh) / (2 n coh))``. Random
    scatter forms local maxima a few deviations high, resonances far more.
    """
    below = np.flatnonzero(mag_db[:i] <= mag_db[i] - 3.0)
    above = np.flatnonzero(mag_db[i + 1:] <= mag_db[i] - 3.0)
    left = i - below[-1] if below.size else i
    right = above[0] + 1 if above.size else mag_db.size - 1 - i
    reach = max(10, 2 * (left + right))
    window = mag_db[max(0, i - reach): i + reach + 1]
    background = np.median(window[np.isfinite(window)])
    c = min(max(coh, 1e-6), 1.0)
    sigma_db = 20.0 / np.log(10.0) * np.sqrt((1.0 - c) / (2.0 * max(n_averages, 1) * c))
    return bool(mag_db[i] - background >= _NOISE_SIGMAS * sigma_db)


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
    if coherence_threshold is not None and not 0.0 <= coherence_threshold <= 1.0:
        raise ConfigError(
            "coherence_threshold", f"must lie in [0, 1] or be None, got {coherence_threshold!r}"
        )
    if not min_prominence_db >= 0.0:
        raise ConfigError("min_prominence_db", f"must be >= 0 dB, got {min_prominence_db!r}")
    if int(max_count) != max_count or max_count < 1:
        raise ConfigError("max_count", f"must be a positive integer, got {max_count!r}")

    f, H, coh = frf.frequency_hz, frf.response, frf.coherence
    valid = (f > 0.0) & np.isfinite(H) & (H != 0.0)
    if band_hz is not None:
        f_lo, f_hi = band_hz
        if not f_lo < f_hi:
            raise ConfigError("band_hz", f"must be (f_lo, f_hi) with f_lo < f_hi, got {band_hz!r}")
        valid &= (f >= f_lo) & (f <= f_hi)
    idx = np.flatnonzero(valid)
    if idx.size < 3:
        return []
    f, H, coh = f[idx], H[idx], coh[idx]
    df = float(np.median(np.diff(f)))

    mag_db = 20.0 * np.log10(np.abs(H))
    peaks, props = signal.find_peaks(mag_db, prominence=min_prominence_db)
    prominence = props["prominences"]
    if coherence_threshold is not None:
        # A resonance spans several bins: judge the coherence around the
        # peak, not at one bin that noise may have lifted over the threshold.
        near = np.clip(peaks[:, None] + np.arange(-2, 3), 0, f.size - 1)
        coh_near = np.nan_to_num(coh[near], nan=0.0).mean(axis=1)
        ok = coh_near >= coherence_threshold
        peaks, prominence, coh_near = peaks[ok], prominence[ok], coh_near[ok]
        ok = [_stands_out(mag_db, i, c, frf.n_averages) for i, c in zip(peaks, coh_near)]
        peaks, prominence = peaks[ok], prominence[ok]
    order = np.argsort(prominence)[::-1]

    found: list[Resonance] = []
    for i in peaks[order]:
        if len(found) == max_count:
            break
        res = _refine(f, H, coh, int(i), df)
        width = res.damping_ratio * res.frequency_hz if np.isfinite(res.damping_ratio) else df
        if any(abs(res.frequency_hz - r.frequency_hz) <= max(width, df) for r in found):
            continue
        found.append(res)
    return sorted(found, key=lambda r: r.frequency_hz)
