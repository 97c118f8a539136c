"""Drift of an axis's resonance over days: a straight-line trend with its uncertainty, and a verdict.

A fleet records each axis now and then and identifies it; this module turns
those identifications (one row per recording, as ``hilident batch`` writes
them) into one verdict per axis: is its resonance moving, how fast, and is
that faster than the lab accepts.

The definition (kept exactly; a fleet's truth is stated in it):

- per axis, an ordinary least-squares line ``f(t) = a + b*t`` through the
  usable recordings, ``t`` in days since the axis's first usable recording;
- ``rate_percent_per_day = 100 * b / a`` (the slope relative to the line's
  value at the first recording);
- its uncertainty is the slope's standard error from the residual scatter
  around the line (Student t, ``n - 2`` degrees of freedom). The 95 %
  intervals the recordings report are *not* used to weight the fit nor to
  size its uncertainty: a per-recording interval describes one recording's
  noise and usually understates the day-to-day scatter (temperature, payload,
  where the axis stood), so a tiny reported interval cannot make a trend
  falsely significant. ``a`` is treated as known when the slope's interval is
  turned into a rate's (its relative error is small beside the slope's), so
  the rate's interval excludes 0 exactly when the slope's test rejects;
- an axis is **flagged** when the trend is significant at ``confidence``
  (``p < 1 - confidence``) *and* ``|rate| > drift_percent_per_day``; with
  fewer than ``min_recordings`` usable recordings its verdict is
  "insufficient data" and it is not flagged.

The damping ratio's trend is fitted the same way; it is reported, never
flagged. Outliers are listed, not dropped: a recording whose residual is more
than :data:`OUTLIER_SIGMAS` robust standard deviations (1.4826 times the
median absolute residual) from the line is named in
:attr:`DriftTrend.outliers`; the line is fitted through it all the same.

Pure: mappings and arrays in, dataclasses out; no files.

Examples
--------
>>> import numpy as np
>>> days = np.arange(10.0)
>>> t = drift_trend(days, 50.0 * (1 - 0.01 * days), drift_percent_per_day=0.5)
>>> round(t.rate_percent_per_day, 6), t.flagged
(-1.0, True)
>>> t.verdict.split(":")[0]
'flagged'
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hilident.errors import DataError

__all__ = [
    "OUTLIER_SIGMAS",
    "DriftOutlier",
    "SeriesTrend",
    "DriftTrend",
    "drift_trend",
    "axis_drifts",
    "parse_time_utc",
]

#: A residual beyond this many robust standard deviations makes a recording an outlier (listed, kept).
OUTLIER_SIGMAS = 4.0

#: 1 / Phi^-1(3/4): the median absolute deviation of normal data times this is its standard deviation.
_MAD_TO_SIGMA = 1.482602218505602

_SECONDS_PER_DAY = 86400.0


@dataclass(frozen=True)
class SeriesTrend:
    """A straight line ``a + b*t`` through one quantity of one axis, with its uncertainty and verdict.

    Attributes
    ----------
    n : int
        Points in the fit.
    days : tuple of float
        The points' times, days since the origin (the axis's first recording), sorted.
    values : tuple of float
        The points' values (Hz for a frequency, 1 for a damping ratio).
    ci95 : tuple of float
        Each point's reported 95 % half-width (NaN when unknown); shown, not used by the fit.
    reference : float
        ``a``, the line at ``t = 0`` (the unit of ``values``); NaN when there is no line.
    slope_per_day : float
        ``b``, unit of ``values`` per day.
    slope_stderr_per_day : float
        Standard error of ``b`` from the residual scatter.
    residual_std : float
        Residual standard deviation ``sqrt(SSR / (n - 2))``.
    rate_percent_per_day : float
        ``100 * b / a``, %/day.
    rate_ci95_percent_per_day : float
        Half-width of the rate's 95 % interval, %/day (``100 * t_0.975(n-2) * se(b) / |a|``).
    p_value : float
        Two-sided p of the t test ``b = 0`` (NaN without a line).
    confidence : float
        Confidence the verdict used (``p < 1 - confidence`` is significant).
    threshold_percent_per_day : float
        ``|rate|`` beyond which a significant trend is flagged (``inf``: never flagged).
    flagged : bool
        Significant and steeper than the threshold, with enough points.
    verdict : str
        One line: ``"flagged: ..."``, ``"significant ... below ..."``, ``"no significant trend ..."``
        or ``"insufficient data: ..."``.
    outliers : tuple of int
        Indices into ``days``/``values`` whose residual exceeds :data:`OUTLIER_SIGMAS` robust sigmas.
    outlier_sigmas : tuple of float
        Their residuals in robust sigmas (signed).
    insufficient : bool
        Too few points (or all at one time) for a verdict: the verdict says ``"insufficient data"``.
    """

    n: int
    days: tuple[float, ...]
    values: tuple[float, ...]
    ci95: tuple[float, ...]
    reference: float
    slope_per_day: float
    slope_stderr_per_day: float
    residual_std: float
    rate_percent_per_day: float
    rate_ci95_percent_per_day: float
    p_value: float
    confidence: float
    threshold_percent_per_day: float
    flagged: bool
    verdict: str
    outliers: tuple[int, ...] = ()
    outlier_sigmas: tuple[float, ...] = ()
    insufficient: bool = False

    @property
    def has_line(self) -> bool:
        """Whether a line with an uncertainty was fitted (at least 3 points at 2 or more times)."""
        return math.isfinite(self.reference) and math.isfinite(self.slope_stderr_per_day)

    def line(self, days: Any) -> np.ndarray:
        """The fitted line at ``days`` (unit of :attr:`values`)."""
        return self.reference + self.slope_per_day * np.asarray(days, dtype=float)

    def band(self, days: Any, confidence: float = 0.95) -> np.ndarray:
        """Half-width of the line's confidence band at ``days`` (where the mean lies, not a new point)."""
        from scipy import stats

        t_days = np.asarray(days, dtype=float)
        if not self.has_line:
            return np.full(t_days.shape, np.nan)
        d = np.asarray(self.days)
        sxx = float(np.sum((d - d.mean()) ** 2))
        q = float(stats.t.ppf(0.5 + confidence / 2.0, self.n - 2))
        return q * self.residual_std * np.sqrt(1.0 / self.n + (t_days - d.mean()) ** 2 / sxx)


@dataclass(frozen=True)
class DriftOutlier:
    """A recording far from its axis's line: listed for a person to look at, never dropped.

    Attributes
    ----------
    quantity : str
        ``"frequency"`` or ``"damping"``.
    time_utc : str
        The recording's time stamp as given.
    path : str
        The recording.
    value : float
        Its value (Hz, or 1 for damping).
    robust_sigmas : float
        Its residual in robust standard deviations (signed).
    """

    quantity: str
    time_utc: str
    path: str
    value: float
    robust_sigmas: float


@dataclass(frozen=True)
class DriftTrend:
    """The drift verdict of one axis: its resonance's trend (flagged or not) and its damping's (reported).

    Attributes
    ----------
    axis : str
        The axis.
    n : int
        Recordings in the frequency fit (status ok, finite frequency and time).
    n_failed : int
        Rows of the axis whose status is not ``"ok"``.
    n_unusable : int
        Ok rows left out of the fit: no finite frequency or no readable time.
    first_utc, last_utc : str
        Time stamps of the first and last fitted recording (``""`` when none).
    span_days : float
        Days between them.
    reference_hz : float
        ``a``: the line's frequency at the first recording, Hz.
    rate_percent_per_day : float
        ``100 * b / a``, %/day (negative: the resonance falls).
    rate_ci95_percent_per_day : float
        Half-width of its 95 % interval, %/day.
    p_value : float
        Two-sided p of the slope's t test.
    flagged : bool
        Significant at the confidence asked and steeper than the threshold.
    verdict : str
        One line saying so, with the figures.
    damping_rate_percent_per_day, damping_rate_ci95_percent_per_day, damping_p_value : float
        The damping ratio's trend the same way (%/day), reported, not flagged.
    outliers : tuple of DriftOutlier
        Recordings far from either line.
    frequency, damping : SeriesTrend
        The two fits in full (points, line, band) for plots.
    """

    axis: str
    n: int
    n_failed: int
    n_unusable: int
    first_utc: str
    last_utc: str
    span_days: float
    reference_hz: float
    rate_percent_per_day: float
    rate_ci95_percent_per_day: float
    p_value: float
    flagged: bool
    verdict: str
    damping_rate_percent_per_day: float
    damping_rate_ci95_percent_per_day: float
    damping_p_value: float
    outliers: tuple[DriftOutlier, ...]
    frequency: SeriesTrend
    damping: SeriesTrend

    @property
    def insufficient(self) -> bool:
        """Too few usable recordings for a verdict on the resonance."""
        return self.frequency.insufficient


def _check_settings(drift_percent_per_day: float, min_recordings: int, confidence: float) -> None:
    if not (isinstance(drift_percent_per_day, (int, float)) and drift_percent_per_day >= 0):
        raise DataError(f"drift_percent_per_day must be a number >= 0, got {drift_percent_per_day!r}")
    if isinstance(min_recordings, bool) or not isinstance(min_recordings, int) or min_recordings < 3:
        raise DataError(f"min_recordings must be an integer >= 3 (a line and its scatter), got {min_recordings!r}")
    if not (isinstance(confidence, (int, float)) and 0.0 < confidence < 1.0):
        raise DataError(f"confidence must be between 0 and 1, got {confidence!r}")


def _fmt(x: float) -> str:
    return f"{x:.2g}" if math.isfinite(x) else "—"


def _outliers(residuals: np.ndarray, scale: float) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Indices and robust sigmas of residuals beyond :data:`OUTLIER_SIGMAS` robust standard deviations."""
    sigma = _MAD_TO_SIGMA * float(np.median(np.abs(residuals - np.median(residuals))))
    floor = 1e-12 * max(scale, 1e-300)  # an exact line: only a real departure from it counts
    if sigma <= floor:
        far = np.flatnonzero(np.abs(residuals) > 1e3 * floor)
        return tuple(int(i) for i in far), tuple(math.copysign(math.inf, residuals[i]) for i in far)
    z = residuals / sigma
    far = np.flatnonzero(np.abs(z) > OUTLIER_SIGMAS)
    return tuple(int(i) for i in far), tuple(float(z[i]) for i in far)


def drift_trend(
    days: Any,
    values: Any,
    *,
    drift_percent_per_day: float = math.inf,
    min_recordings: int = 5,
    confidence: float = 0.95,
    ci95: Any = None,
) -> SeriesTrend:
    """The ordinary least-squares trend of one series and its verdict (see the module docstring).

    Parameters
    ----------
    days : array_like
        Times of the points, days since the series' origin (the axis's first recording): the line's
        ``a`` is its value at ``days = 0``. Non-finite points (in ``days`` or ``values``) are left out.
    values : array_like
        The quantity, same length (Hz for a frequency).
    drift_percent_per_day : float
        ``|rate|`` above which a significant trend is flagged, %/day; ``inf`` (default): never flagged.
    min_recordings : int
        Fewer points than this: "insufficient data", not flagged (at least 3).
    confidence : float
        Significance level of the verdict is ``1 - confidence``.
    ci95 : array_like, optional
        Each point's reported 95 % half-width, kept for plots only.

    Returns
    -------
    SeriesTrend

    Raises
    ------
    DataError
        Mismatched lengths or settings out of range.

    Examples
    --------
    >>> t = drift_trend([0, 1, 2], [10.0, 10.1, 10.2], drift_percent_per_day=0.1)
    >>> t.verdict
    'insufficient data: 3 recordings, 5 needed'
    >>> round(t.rate_percent_per_day, 6)
    1.0
    """
    from scipy import stats

    _check_settings(drift_percent_per_day, min_recordings, confidence)
    d = np.asarray(days, dtype=float).ravel()
    v = np.asarray(values, dtype=float).ravel()
    c = np.full(d.shape, np.nan) if ci95 is None else np.asarray(ci95, dtype=float).ravel()
    if not d.shape == v.shape == c.shape:
        raise DataError(f"drift_trend: days ({d.size}), values ({v.size}) and ci95 ({c.size}) differ in length")
    keep = np.isfinite(d) & np.isfinite(v)
    order = np.argsort(d[keep], kind="stable")
    d, v, c = d[keep][order], v[keep][order], c[keep][order]
    n = int(d.size)
    nan = math.nan
    base: dict[str, Any] = dict(
        n=n,
        days=tuple(map(float, d)),
        values=tuple(map(float, v)),
        ci95=tuple(map(float, c)),
        confidence=float(confidence),
        threshold_percent_per_day=float(drift_percent_per_day),
        flagged=False,
    )
    sxx = float(np.sum((d - d.mean()) ** 2)) if n else 0.0
    if n < 3 or sxx <= 0.0:
        why = (
            f"{n} recording{'s' if n != 1 else ''}, {min_recordings} needed"
            if n < 3
            else "every recording at the same time"
        )
        return SeriesTrend(
            **base,
            reference=nan,
            slope_per_day=nan,
            slope_stderr_per_day=nan,
            residual_std=nan,
            rate_percent_per_day=nan,
            rate_ci95_percent_per_day=nan,
            p_value=nan,
            verdict=f"insufficient data: {why}",
            insufficient=True,
        )
    slope = float(np.sum((d - d.mean()) * (v - v.mean())) / sxx)
    intercept = float(v.mean() - slope * d.mean())
    residuals = v - (intercept + slope * d)
    dof = n - 2
    s = math.sqrt(float(np.sum(residuals**2)) / dof)
    se = s / math.sqrt(sxx)
    if se > 0:
        p = float(2.0 * stats.t.sf(abs(slope) / se, dof))
    else:
        p = 1.0 if slope == 0 else 0.0
    rate = 100.0 * slope / intercept if intercept != 0 else nan
    rate_ci = 100.0 * float(stats.t.ppf(0.975, dof)) * se / abs(intercept) if intercept != 0 else nan
    significant = p < 1.0 - confidence
    steep = math.isfinite(rate) and abs(rate) > drift_percent_per_day
    figures = f"{_fmt(rate)} ± {_fmt(rate_ci)} %/day (p = {p:.2g})"
    threshold = f"{drift_percent_per_day:g} %/day"
    if n < min_recordings:
        verdict, flagged = f"insufficient data: {n} recordings, {min_recordings} needed", False
    elif significant and steep:
        verdict, flagged = f"flagged: {figures}, steeper than {threshold}", True
    elif significant:
        verdict, flagged = f"significant trend {figures}, below the {threshold} threshold", False
    else:
        verdict, flagged = f"no significant trend: {figures}", False
    far, sigmas = _outliers(residuals, float(np.max(np.abs(v))))
    base["flagged"] = flagged
    return SeriesTrend(
        **base,
        reference=intercept,
        slope_per_day=slope,
        slope_stderr_per_day=se,
        residual_std=s,
        rate_percent_per_day=rate,
        rate_ci95_percent_per_day=rate_ci,
        p_value=p,
        verdict=verdict,
        outliers=far,
        outlier_sigmas=sigmas,
        insufficient=n < min_recordings,
    )


def parse_time_utc(text: Any) -> dt.datetime | None:
    """An ISO 8601 time stamp as an aware UTC datetime (one without a zone is taken as UTC); None if unreadable.

    >>> parse_time_utc("2026-11-23T19:40:00Z").isoformat()
    '2026-11-23T19:40:00+00:00'
    >>> parse_time_utc("yesterday") is None
    True
    """
    if isinstance(text, dt.datetime):
        when = text
    else:
        try:
            when = dt.datetime.fromisoformat(str(text).strip())
        except ValueError:
            return None
    return when.replace(tzinfo=dt.UTC) if when.tzinfo is None else when.astimezone(dt.UTC)


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _named_outliers(
    quantity: str, trend: SeriesTrend, items: Sequence[tuple[dt.datetime, Mapping[str, Any]]]
) -> list[DriftOutlier]:
    """The outliers of ``trend`` named by their rows (``items`` in the fit's time order)."""
    return [
        DriftOutlier(
            quantity, str(items[i][1].get("time_utc")), str(items[i][1].get("path", "")), float(trend.values[i]), z
        )
        for i, z in zip(trend.outliers, trend.outlier_sigmas, strict=True)
    ]


def _axis_trend(
    axis: str, rows: Sequence[Mapping[str, Any]], drift_percent_per_day: float, min_recordings: int, confidence: float
) -> DriftTrend:
    ok = [r for r in rows if r.get("status") == "ok"]
    timed = [(when, r) for r in ok if (when := parse_time_utc(r.get("time_utc"))) is not None]
    used = sorted(((w, r) for w, r in timed if math.isfinite(_float(r.get("frequency_hz")))), key=lambda x: x[0])
    start = used[0][0] if used else None

    def days(items: Iterable[tuple[dt.datetime, Mapping[str, Any]]]) -> np.ndarray:
        return np.array([(w - start).total_seconds() / _SECONDS_PER_DAY for w, _ in items]) if start else np.zeros(0)

    def column(items: Sequence[tuple[dt.datetime, Mapping[str, Any]]], key: str) -> np.ndarray:
        return np.array([_float(r.get(key)) for _, r in items])

    freq = drift_trend(
        days(used),
        column(used, "frequency_hz"),
        drift_percent_per_day=drift_percent_per_day,
        min_recordings=min_recordings,
        confidence=confidence,
        ci95=column(used, "frequency_ci95_hz"),
    )
    damped = [(w, r) for w, r in used if math.isfinite(_float(r.get("damping_ratio")))]
    # the damping's days keep the axis's origin: its first point need not be the first recording
    damp = drift_trend(
        days(damped),
        column(damped, "damping_ratio"),
        min_recordings=min_recordings,
        confidence=confidence,
        ci95=column(damped, "damping_ci95"),
    )
    outliers = _named_outliers("frequency", freq, used) + _named_outliers("damping", damp, damped)
    return DriftTrend(
        axis=axis,
        n=freq.n,
        n_failed=len(rows) - len(ok),
        n_unusable=len(ok) - len(used),
        first_utc=str(used[0][1].get("time_utc")) if used else "",
        last_utc=str(used[-1][1].get("time_utc")) if used else "",
        span_days=float(freq.days[-1]) if freq.days else 0.0,
        reference_hz=freq.reference,
        rate_percent_per_day=freq.rate_percent_per_day,
        rate_ci95_percent_per_day=freq.rate_ci95_percent_per_day,
        p_value=freq.p_value,
        flagged=freq.flagged,
        verdict=freq.verdict,
        damping_rate_percent_per_day=damp.rate_percent_per_day,
        damping_rate_ci95_percent_per_day=damp.rate_ci95_percent_per_day,
        damping_p_value=damp.p_value,
        outliers=tuple(outliers),
        frequency=freq,
        damping=damp,
    )


def axis_drifts(
    rows: Iterable[Mapping[str, Any]], drift_percent_per_day: float, min_recordings: int = 5, confidence: float = 0.95
) -> dict[str, DriftTrend]:
    """The drift verdict of every axis in a batch's rows, sorted by axis.

    Parameters
    ----------
    rows : iterable of mapping
        One per recording, with at least ``axis`` (str), ``time_utc`` (ISO 8601, UTC), ``status``
        (``"ok"`` or ``"failed"``), ``frequency_hz``, ``frequency_ci95_hz`` (Hz), ``damping_ratio``,
        ``damping_ci95`` (NaN or None when unknown), ``path``, ``error``. Rows that failed, or have no
        finite frequency or readable time, are counted per axis and left out of the fits; a failed row
        without an axis (a file too damaged to say) belongs to no axis.
    drift_percent_per_day : float
        ``[batch] drift_percent_per_day``: a significant trend steeper than this (either sign) is flagged, %/day.
    min_recordings : int
        Fewer usable recordings: verdict "insufficient data", not flagged.
    confidence : float
        The trend is significant when ``p < 1 - confidence``.

    Returns
    -------
    dict of str to DriftTrend
        Keyed by axis, in sorted order.

    Raises
    ------
    DataError
        An ok row without an ``axis``, or settings out of range.

    Examples
    --------
    >>> rows = [{"axis": "x", "time_utc": f"2026-11-{d:02d}T02:00:00Z", "status": "ok",
    ...          "frequency_hz": 40.0 - 0.4 * d, "damping_ratio": 0.02} for d in range(1, 8)]
    >>> rows.append({"axis": "x", "time_utc": "2026-11-08T02:00:00Z", "status": "failed", "error": "truncated"})
    >>> x = axis_drifts(rows, drift_percent_per_day=0.5)["x"]
    >>> x.n, x.n_failed, x.flagged, round(x.rate_percent_per_day, 4)
    (7, 1, True, -1.0101)
    """
    _check_settings(drift_percent_per_day, min_recordings, confidence)
    by_axis: dict[str, list[Mapping[str, Any]]] = {}
    for i, row in enumerate(rows):
        axis = row.get("axis")
        if axis is None or axis == "" or (isinstance(axis, float) and math.isnan(axis)):
            if row.get("status") != "ok":
                continue  # a file too damaged to name its axis: the batch's failures list it
            raise DataError(f"batch row {i} ({row.get('path', 'no path')}): identified, but no axis")
        by_axis.setdefault(str(axis), []).append(row)
    return {
        axis: _axis_trend(axis, by_axis[axis], drift_percent_per_day, min_recordings, confidence)
        for axis in sorted(by_axis)
    }
