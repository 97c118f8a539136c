"""How much a measured frequency response can be trusted, and whether the test could resolve it.

Three questions a controls engineer asks of an FRF before using it:

* **How uncertain is each bin?** For an averaged estimate (H1 over ``n``
  Welch segments, or ``n`` multisine periods) with coherence ``g2`` the
  normalised random error of ``|H|`` is (Bendat & Piersol, eq. 9.90)::

      eps = sqrt((1 - g2) / (2 n g2))

  and the standard deviation of the phase is ``eps`` radians. A bin with
  coherence 0.9 over 8 averages has ``eps = 0.083``: about +-0.7 dB (1 sigma).
  :func:`frf_uncertainty` turns that into confidence bounds in dB and degrees.
  With overlapped Hann segments the averages are not independent and the true
  error is a few percent larger than the formula says.

* **Was the frequency resolution fine enough?** A lightly damped mode has a
  half-power bandwidth of ``2 zeta f``; with fewer than about two bins across
  it the peak is clipped and the damping over-estimated. The lowest
  anti-resonance must be separated from its neighbouring resonance by several
  bins, or the pair smears into one feature. :func:`check_resolution` counts
  the bins and says which segment or period length would be enough.

* **Did the input excite the band?** :func:`input_spectrum` reports the
  spectrum level of the excitation over the band of interest, its spread in
  dB and the fraction of the band it covers.

Pure functions on arrays; no files.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.frequency import FrequencyResponse
>>> frf = FrequencyResponse(np.array([10.0]), np.array([1.0 + 0j]), np.array([0.9]), 8, "h1")
>>> u = frf_uncertainty(frf)
>>> print(f"{u.magnitude_rel_std[0]:.3f}, +{u.upper_db[0]:.2f} dB")
0.083, +1.31 dB
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse, welch_psd


@dataclass(frozen=True)
class FrfUncertainty:
    """Random error of each bin of an averaged frequency response.

    Attributes
    ----------
    frequency_hz : ndarray
        The response's frequencies, Hz.
    magnitude_rel_std : ndarray
        Standard deviation of ``|H|`` relative to ``|H|`` (``eps``); inf where
        the coherence is 0, NaN where the estimator has no coherence.
    phase_std_deg : ndarray
        Standard deviation of the phase, degrees.
    lower_db, upper_db : ndarray
        ``20 log10(1 -+ z eps)``: the confidence band of the magnitude relative
        to the estimate, dB (``lower_db`` is ``-inf`` where ``z eps >= 1``).
    phase_bound_deg : ndarray
        ``z`` times the phase standard deviation, degrees.
    confidence : float
        Two-sided level of the bounds (``z`` from the normal distribution).
    n_averages : int
    """

    frequency_hz: np.ndarray
    magnitude_rel_std: np.ndarray
    phase_std_deg: np.ndarray
    lower_db: np.ndarray
    upper_db: np.ndarray
    phase_bound_deg: np.ndarray
    confidence: float
    n_averages: int


def frf_uncertainty(frf: FrequencyResponse, confidence: float = 0.95) -> FrfUncertainty:
    """Confidence bounds of an averaged FRF from its coherence and number of averages.

    Parameters
    ----------
    frf : FrequencyResponse
        H1, reference or periodic estimate (``n_averages >= 2``).
    confidence : float
        Two-sided confidence level in (0, 1).

    Returns
    -------
    FrfUncertainty

    Raises
    ------
    DataError
        Fewer than two averages: a single segment has coherence 1 by
        construction and says nothing about the error.
    """
    if not 0.0 < confidence < 1.0:
        raise ConfigError("confidence", f"must lie in (0, 1), got {confidence!r}")
    n = frf.n_averages
    if n < 2:
        raise DataError(f"{frf.method} estimate has {n} average(s); an uncertainty needs at least 2")
    g2 = np.clip(frf.coherence, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        eps = np.sqrt((1.0 - g2) / (2.0 * n * g2))
    z = float(stats.norm.ppf(0.5 + confidence / 2.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lower = np.where(z * eps < 1.0, 20.0 * np.log10(np.clip(1.0 - z * eps, 1e-300, None)), -np.inf)
        upper = 20.0 * np.log10(1.0 + z * eps)
    phase_std = np.degrees(np.arcsin(np.clip(eps, 0.0, 1.0)))
    phase_std = np.where(np.isnan(eps), np.nan, phase_std)
    return FrfUncertainty(
        frequency_hz=frf.frequency_hz.copy(),
        magnitude_rel_std=eps,
        phase_std_deg=phase_std,
        lower_db=lower,
        upper_db=upper,
        phase_bound_deg=np.minimum(z * phase_std, 180.0),
        confidence=float(confidence),
        n_averages=n,
    )


@dataclass(frozen=True)
class ResolutionCheck:
    """Frequency resolution of a test against the features it had to resolve.

    Attributes
    ----------
    resolution_hz : float
        Spacing of the response's bins, Hz.
    bins_per_bandwidth : list of dict
        Per resonance: ``frequency_hz``, ``damping_ratio``, ``bandwidth_hz``
        (``2 zeta f``) and ``bins`` across it.
    antiresonance : dict or None
        For the lowest anti-resonance: ``frequency_hz``, the nearest resonance
        ``resonance_hz`` and the ``bins`` between them.
    required_record_s : float
        Shortest segment or period length that meets every requirement, s
        (0 when there was nothing to resolve).
    warnings : list of str
    """

    resolution_hz: float
    bins_per_bandwidth: list
    antiresonance: dict | None
    required_record_s: float
    warnings: list


def estimate_error_std(frf: FrequencyResponse) -> np.ndarray:
    """Standard deviation of the random error of each line's complex estimate, in the unit of the response.

    The output noise the excitation does not explain, seen through the
    estimate: ``|H| sqrt((1 - g) / (g d))`` with ``g`` the coherence and ``d``
    the degrees of freedom. A periodic estimate's coherence uses the spread of
    its ``M`` periods around their mean (divided by ``M``), so ``d = M - 1``;
    an averaged (H1, reference) estimate has ``d = n_averages`` (Bendat &
    Piersol). Unlike :func:`frf_uncertainty` it is absolute, not relative: a
    response a notch took down is still measured through the same noise.

    Returns
    -------
    ndarray
        One value per line; NaN where the estimator has no coherence, inf
        where the coherence is 0 or there is a single average.
    """
    dof = frf.n_averages - 1 if frf.method == "periodic" else frf.n_averages
    g = np.clip(frf.coherence, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(frf.response) * np.sqrt((1.0 - g) / (g * dof)) if dof >= 1 else np.full(g.shape, np.inf)


def check_resolution(
    frf: FrequencyResponse,
    resonances: ArrayLike,
    antiresonances_hz: ArrayLike = (),
    min_bins_per_bandwidth: float = 2.0,
    min_bins_to_antiresonance: float = 5.0,
) -> ResolutionCheck:
    """Is the bin spacing fine enough for the resonances and the lowest anti-resonance?

    Parameters
    ----------
    frf : FrequencyResponse
        The measured response (its bin spacing is the resolution).
    resonances : array_like, shape (r, 2)
        ``(frequency_hz, damping_ratio)`` of the resonances found.
    antiresonances_hz : array_like
        Anti-resonance frequencies, Hz (e.g. from a fitted transfer function).
    min_bins_per_bandwidth : float
        Fewest bins across a half-power bandwidth ``2 zeta f`` accepted.
    min_bins_to_antiresonance : float
        Fewest bins between the lowest anti-resonance and the nearest resonance.

    Returns
    -------
    ResolutionCheck
    """
    f = frf.frequency_hz
    if f.size < 2:
        raise DataError("a resolution check needs at least two frequency bins")
    df = float(np.median(np.diff(f)))
    if not df > 0:
        raise DataError("frequency bins must increase")
    res = np.asarray(resonances, dtype=float).reshape(-1, 2)
    warnings: list[str] = []
    needed_df = np.inf
    per_mode = []
    for f0, zeta in res:
        bandwidth = 2.0 * zeta * f0 if np.isfinite(zeta) and zeta > 0 else np.nan
        bins = bandwidth / df
        per_mode.append(
            {
                "frequency_hz": float(f0),
                "damping_ratio": float(zeta),
                "bandwidth_hz": float(bandwidth),
                "bins": float(bins),
            }
        )
        if np.isfinite(bins):
            needed_df = min(needed_df, bandwidth / min_bins_per_bandwidth)
            if bins < min_bins_per_bandwidth:
                warnings.append(
                    f"resolution {df:.3g} Hz gives {bins:.1f} bins across the {bandwidth:.3g} Hz half-power "
                    f"bandwidth of the {f0:.4g} Hz resonance: its damping is over-estimated; a segment or period "
                    f"of at least {min_bins_per_bandwidth / bandwidth:.3g} s resolves it"
                )
    anti = None
    ar = np.sort(np.asarray(antiresonances_hz, dtype=float).ravel())
    ar = ar[np.isfinite(ar) & (ar > 0)]
    if ar.size and res.size:
        lowest = float(ar[0])
        nearest = float(res[np.argmin(np.abs(res[:, 0] - lowest)), 0])
        gap = abs(nearest - lowest)
        bins = gap / df
        anti = {"frequency_hz": lowest, "resonance_hz": nearest, "bins": float(bins)}
        if gap > 0:
            needed_df = min(needed_df, gap / min_bins_to_antiresonance)
        if bins < min_bins_to_antiresonance:
            warnings.append(
                f"resolution {df:.3g} Hz leaves {bins:.1f} bins between the lowest anti-resonance "
                f"({lowest:.4g} Hz) and the resonance at {nearest:.4g} Hz; a segment or period of at least "
                f"{min_bins_to_antiresonance / gap if gap else np.inf:.3g} s separates them"
            )
    return ResolutionCheck(df, per_mode, anti, float(1.0 / needed_df), warnings)  # 0: nothing to resolve


@dataclass(frozen=True)
class InputSpectrum:
    """Spectrum of an excitation over a band of interest.

    Attributes
    ----------
    band_hz : (float, float)
    rms : float
        Root mean square of the excitation (its unit).
    crest_factor : float
        Peak over rms.
    level_min_db, level_max_db : float
        Lowest and highest power spectral density in the band, dB re 1 unit^2/Hz.
    spread_db : float
        ``level_max_db - level_min_db``.
    coverage : float
        Fraction of the band's bins within ``floor_db`` of the highest level.
    frequency_hz, psd : ndarray
        The Welch spectrum over the band (one-sided, unit^2/Hz).
    """

    band_hz: tuple[float, float]
    rms: float
    crest_factor: float
    level_min_db: float
    level_max_db: float
    spread_db: float
    coverage: float
    frequency_hz: np.ndarray
    psd: np.ndarray

    def to_dict(self) -> dict:
        return {
            "band_hz": list(self.band_hz),
            "rms": self.rms,
            "crest_factor": self.crest_factor,
            "level_min_db": self.level_min_db,
            "level_max_db": self.level_max_db,
            "spread_db": self.spread_db,
            "coverage": self.coverage,
        }


def input_spectrum(
    u: ArrayLike,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    segment_length: int | None = None,
    floor_db: float = 20.0,
    periodic: bool = False,
) -> InputSpectrum:
    """Power spectral density of the excitation over ``band_hz`` (Welch, Hann).

    Parameters
    ----------
    u : array_like
        Excitation samples.
    sample_rate_hz : float
    band_hz : (float, float)
        Band of interest, Hz.
    segment_length : int, optional
        Welch segment, samples. Give the period of a periodic excitation (every
        bin is then one of its lines); default an eighth of the record, at
        least 256 samples and at most 2**14.
    floor_db : float
        Bins within this many dB of the highest level count as covered.
    periodic : bool
        The record holds whole periods of ``segment_length`` samples: no window
        (a periodic signal does not leak), so each bin is exactly one line.
    """
    x = np.asarray(u, dtype=float)
    if x.ndim != 1 or x.size < 16 or not np.all(np.isfinite(x)):
        raise DataError("the excitation must be a finite 1-D record of at least 16 samples")
    lo, hi = (float(b) for b in band_hz)
    if not 0 <= lo < hi <= sample_rate_hz / 2:
        raise ConfigError("band_hz", f"must satisfy 0 <= low < high <= Nyquist, got {band_hz!r}")
    nper = int(min(segment_length or min(max(x.size // 8, 256), 2**14), x.size))
    window = "boxcar" if periodic and segment_length else "hann"
    mean = x.mean()
    f, p = welch_psd(
        x, sample_rate_hz, nper, noverlap=0 if periodic else None, window=window, detrend=False, subtract=mean
    )
    keep = (f >= lo) & (f <= hi)
    if not np.any(keep):
        raise DataError(f"no spectrum bin between {lo:g} and {hi:g} Hz; record too short")
    fb, pb = f[keep], p[keep]
    with np.errstate(divide="ignore"):
        level = 10.0 * np.log10(pb)
    top = float(np.max(level))
    rms, peak = _rms_and_peak(x, mean)
    return InputSpectrum(
        band_hz=(lo, hi),
        rms=rms,
        crest_factor=peak / rms if rms else np.inf,
        level_min_db=float(np.min(level)),
        level_max_db=top,
        spread_db=float(top - np.min(level)),
        coverage=float(np.mean(level >= top - floor_db)),
        frequency_hz=fb,
        psd=pb,
    )


def _rms_and_peak(x: np.ndarray, mean: float, block: int = 1 << 18) -> tuple[float, float]:
    """Root mean square and largest magnitude of ``x - mean``, a block at a time (no record-sized temporaries)."""
    squares = 0.0
    peak = 0.0
    for start in range(0, x.size, block):
        d = x[start : start + block] - mean
        squares += float(d @ d)
        peak = max(peak, float(np.max(np.abs(d))))
    return float(np.sqrt(squares / x.size)), peak


def excited_band(
    u: ArrayLike, sample_rate_hz: float, segment_length: int, floor_db: float = 20.0
) -> tuple[float, float]:
    """Lowest and highest frequency where the input's spectrum is within ``floor_db`` of its peak, Hz.

    For records from elsewhere, whose excitation band nobody wrote down. The
    DC bin is ignored.

    Raises
    ------
    DataError
        The record is shorter than one segment, or the input has no power.
    """
    x = np.asarray(u, dtype=float)
    if x.ndim != 1 or x.size < max(int(segment_length), 16) or not np.all(np.isfinite(x)):
        raise DataError(f"the input needs at least {segment_length} finite samples to find its excited band")
    f, p = welch_psd(x, sample_rate_hz, int(segment_length), subtract=x.mean())
    f, p = f[1:], p[1:]
    if not np.any(p > 0):
        raise DataError("the input has no power at any frequency")
    level = 10 * np.log10(np.maximum(p, np.max(p) * 1e-30))
    on = np.flatnonzero(level >= level.max() - floor_db)
    return float(f[on[0]]), float(f[on[-1]])
