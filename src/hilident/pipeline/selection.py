"""Which rows of a gappy recording may be analysed as one record: nothing is ever filled in or spliced."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.errors import DataError

#: Gaps listed one by one in a :class:`GapFreeSelection` (the count is always exact).
MAX_LISTED_GAPS = 100


def contiguous_runs(sample_index) -> list[tuple[int, int]]:
    """``(start, stop)`` row ranges over which ``sample_index`` increases by exactly 1."""
    index = np.asarray(sample_index, dtype=np.int64)
    if len(index) == 0:
        return []
    breaks = np.flatnonzero(np.diff(index) != 1) + 1
    edges = np.concatenate(([0], breaks, [len(index)]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


@dataclass
class GapFreeSelection:
    """The rows of a gappy recording that may be analysed as one record.

    Attributes
    ----------
    keep : ndarray of bool
        One flag per row: True for the rows analysed.
    segments : list of (int, int)
        ``(start, stop)`` row ranges of the kept rows, each gap-free (a
        segment ends where a kept row does not follow its predecessor on
        the sample clock).
    gaps : list of dict
        Up to :data:`MAX_LISTED_GAPS` breaks of the recording: ``row`` (first
        row after the break), ``sample_index`` (its index) and
        ``missing_samples`` (negative or zero: out of order or repeated).
    n_gaps : int
        All breaks, listed or not.
    missing_samples : int
        Samples absent between the first and the last row.
    period_samples : int or None
        Period used (whole periods mode), else None (longest stretch mode).
    warnings : list of str
    """

    keep: np.ndarray
    segments: list[tuple[int, int]]
    gaps: list[dict]
    n_gaps: int
    missing_samples: int
    period_samples: int | None
    warnings: list[str] = field(default_factory=list)

    @property
    def used_rows(self) -> int:
        return int(self.keep.sum())

    def to_dict(self) -> dict:
        return {
            "rows": int(len(self.keep)),
            "used_rows": self.used_rows,
            "segments": len(self.segments),
            "gaps": self.gaps,
            "n_gaps": self.n_gaps,
            "missing_samples": self.missing_samples,
            "period_samples": self.period_samples,
        }


def select_gap_free(sample_index, period_samples: int | None = None, name: str = "recording") -> GapFreeSelection:
    """Rows to analyse: whole gap-free periods of a periodic excitation, else the longest gap-free stretch.

    Nothing is ever filled in or spliced mid-period: periods of a periodic
    excitation in steady state can be joined end to end, so a lost block costs
    only the period it fell in. Period 0 (``sample_index < period_samples``) is
    the lead-in that lets the transient die out and is never used. Without a
    period only the longest stretch without a break is kept.

    Parameters
    ----------
    sample_index : array_like of int
        Index of each recorded row on the device's sample clock (0 = first
        excitation sample); a step other than +1 is a break.
    period_samples : int, optional
        Period of the excitation, samples.
    name : str
        Names the recording in warnings and errors.

    Raises
    ------
    DataError
        No rows, or fewer than two whole gap-free periods.
    """
    index = np.asarray(sample_index, dtype=np.int64)
    runs = contiguous_runs(index)
    if not runs:
        raise DataError(f"{name}: no samples were recorded")
    step = np.diff(index)
    breaks = np.flatnonzero(step != 1)
    gaps = [
        {"row": int(b + 1), "sample_index": int(index[b + 1]), "missing_samples": int(step[b] - 1)}
        for b in breaks[:MAX_LISTED_GAPS]
    ]
    missing = int(np.clip(step[breaks] - 1, 0, None).sum()) if len(breaks) else 0
    if period_samples:
        keep, warnings = _whole_periods(index, runs, int(period_samples), name)
    else:
        keep, warnings = _longest_run(len(index), runs, name)
    segments = _kept_segments(keep, step)
    return GapFreeSelection(
        keep, segments, gaps, len(breaks), missing, int(period_samples) if period_samples else None, warnings
    )


def _kept_segments(keep: np.ndarray, step: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` ranges of kept rows that follow each other on the sample clock."""
    joined = np.concatenate(([False], (step == 1) & keep[:-1] & keep[1:]))  # row r continues row r - 1
    starts = np.flatnonzero(keep & ~joined)
    stops = np.flatnonzero(keep & ~np.concatenate((joined[1:], [False]))) + 1
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=False)]


def _longest_run(n: int, runs, name: str) -> tuple[np.ndarray, list[str]]:
    a, b = max(runs, key=lambda r: r[1] - r[0])
    keep = np.zeros(n, dtype=bool)
    keep[a:b] = True
    warnings = []
    if len(runs) > 1:
        warnings.append(
            f"{name}: recording has {len(runs) - 1} gap(s); the longest contiguous stretch "
            f"({b - a} samples) was analysed"
        )
    return keep, warnings


def _whole_periods(index: np.ndarray, runs, period: int, name: str) -> tuple[np.ndarray, list[str]]:
    keep = np.zeros(len(index), dtype=bool)
    taken: set[int] = set()
    for a, b in runs:
        first = max(1, -(-int(index[a]) // period))  # first period starting inside the run (period 0 is the lead-in)
        last = (int(index[b - 1]) + 1) // period  # periods ending inside the run: < last
        for p in range(first, last):
            if p in taken:  # a repeated stretch of samples never counts twice
                continue
            taken.add(p)
            start = a + p * period - int(index[a])
            keep[start : start + period] = True
    n_complete = len(taken)
    total = max(int(index.max()) // period, 0)
    warnings = []
    if n_complete < total:
        warnings.append(
            f"{name}: {total - n_complete} of {total} excitation periods had lost samples and were left out"
        )
    if n_complete < 2:
        raise DataError(
            f"{name}: only {n_complete} complete excitation period(s) recorded; at least 2 are needed "
            "(check the line: lost or corrupt frames)"
        )
    return keep, warnings


def excitation_period_samples(excitation, sample_rate_hz: float) -> int | None:
    """Period in samples of the excitation ``[excitation]`` describes, None when it is not periodic.

    Mirrors how the session builds the excitation: a multisine is periodic,
    a PRBS is when at least three of its sequences are played.

    Parameters
    ----------
    excitation : ExcitationConfig
    sample_rate_hz : float
    """
    fs = float(sample_rate_hz)
    if excitation.kind == "multisine":
        period = int(round(excitation.period_s * fs))
        return period if period >= 1 else None
    if excitation.kind == "prbs":
        length = (2 ** int(excitation.register_length) - 1) * int(excitation.clock_divider)
        periods = max(1, int(round(excitation.duration_s * fs / length)))
        return length if periods >= 3 else None
    return None


#: Largest share of a period's samples that may be missing for the period to be read around them.
MAX_MISSING_SHARE = 0.2


@dataclass
class GappedPeriods:
    """Whole periods of a periodic excitation, some of whose samples do not exist.

    Attributes
    ----------
    rows : ndarray of int
        The recorded rows used, in order.
    positions : ndarray of int
        Where each of those rows sits in the selected periods laid end to end.
    present : ndarray of bool
        One flag per sample of the selected periods: True where a row exists.
    periods : list of int
        The periods selected (period 0 is the lead-in and never is one).
    warnings : list of str
    """

    rows: np.ndarray
    positions: np.ndarray
    present: np.ndarray
    periods: list[int]
    warnings: list[str] = field(default_factory=list)

    def spread(self, values: np.ndarray) -> np.ndarray:
        """``values`` (one per recorded row) laid on the selected periods, NaN where a sample is missing."""
        out = np.full(self.present.size, np.nan)
        out[self.positions] = np.asarray(values, dtype=np.float64)[self.rows]
        return out


def select_gapped_periods(
    sample_index, period_samples: int, name: str = "recording", max_missing_share: float = MAX_MISSING_SHARE
) -> GappedPeriods:
    """Periods after the lead-in that miss at most ``max_missing_share`` of their samples, for
    :func:`~hilident.ident.frequency.periodic_frf` with ``present``.

    Raises
    ------
    DataError
        Fewer than two such periods.
    """
    index = np.asarray(sample_index, dtype=np.int64)
    period = int(period_samples)
    if len(index) and np.any(np.diff(index) <= 0):
        order = np.unique(index, return_index=True)[1]  # a repeated or out-of-order row counts once
    else:
        order = np.arange(len(index))
    index_used = index[order]
    which = index_used // period
    counts = np.bincount(which[which >= 1], minlength=int(which.max(initial=0)) + 1)
    periods = [p for p in range(1, len(counts)) if counts[p] >= (1.0 - max_missing_share) * period]
    if len(periods) < 2:
        raise DataError(
            f"{name}: only {len(periods)} excitation period(s) miss less than {100 * max_missing_share:g} % of their "
            "samples; at least 2 are needed (check the line: lost or corrupt frames, skipped cycles)"
        )
    slot = {p: i for i, p in enumerate(periods)}
    take = np.isin(which, periods)
    rows = order[take]
    positions = np.array([slot[int(p)] for p in which[take]], dtype=np.int64) * period + index_used[take] % period
    present = np.zeros(len(periods) * period, dtype=bool)
    present[positions] = True
    warnings = []  # how many samples are missing, the analysis that reads around them says
    total = max(int(index.max(initial=0)) // period, 0)
    if len(periods) < total:
        warnings.append(f"{name}: {total - len(periods)} of {total} excitation periods missed too many samples")
    return GappedPeriods(rows, positions, present, periods, warnings)
