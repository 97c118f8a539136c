"""``drift.json``: the drift verdict of every axis of a batch, for a script or a nightly job to read.

One object: the settings the verdicts used, the flagged axes by name, and per
axis its counts, time span, resonance at the first recording, rate with its
95 % half-width and p, verdict, damping trend and outliers. The points
themselves are in the batch's table; unknown figures are ``null``.

Examples
--------
>>> from hilident.ident.drift import axis_drifts
>>> rows = [{"axis": "x", "time_utc": f"2026-11-{d:02d}T02:00:00Z", "status": "ok",
...          "frequency_hz": 40.0 - 0.4 * d} for d in range(1, 8)]
>>> doc = drift_document(axis_drifts(rows, drift_percent_per_day=0.5))
>>> doc["flagged"], doc["axes"]["x"]["n"], doc["drift_percent_per_day"]
(['x'], 7, 0.5)
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hilident.io.serialise import to_jsonable, write_json

if TYPE_CHECKING:
    from hilident.ident.drift import DriftTrend, SeriesTrend

__all__ = ["DRIFT_JSON", "drift_document", "write_drift_json"]

#: The file's name in a batch's output folder.
DRIFT_JSON = "drift.json"


def _line(trend: SeriesTrend) -> dict[str, Any]:
    return {
        "n": trend.n,
        "reference": trend.reference,
        "slope_per_day": trend.slope_per_day,
        "slope_stderr_per_day": trend.slope_stderr_per_day,
        "residual_std": trend.residual_std,
        "rate_percent_per_day": trend.rate_percent_per_day,
        "rate_ci95_percent_per_day": trend.rate_ci95_percent_per_day,
        "p_value": trend.p_value,
    }


def _axis(t: DriftTrend) -> dict[str, Any]:
    return {
        "n": t.n,
        "n_failed": t.n_failed,
        "n_unusable": t.n_unusable,
        "first_utc": t.first_utc,
        "last_utc": t.last_utc,
        "span_days": t.span_days,
        "reference_hz": t.reference_hz,
        "rate_percent_per_day": t.rate_percent_per_day,
        "rate_ci95_percent_per_day": t.rate_ci95_percent_per_day,
        "p_value": t.p_value,
        "flagged": t.flagged,
        "verdict": t.verdict,
        "damping": _line(t.damping),
        "outliers": [
            {
                "quantity": o.quantity,
                "time_utc": o.time_utc,
                "path": o.path,
                "value": o.value,
                "robust_sigmas": o.robust_sigmas,
            }
            for o in t.outliers
        ],
    }


def drift_document(drifts: Mapping[str, DriftTrend]) -> dict[str, Any]:
    """``drift.json``'s content as plain JSON types (NaN as None).

    Parameters
    ----------
    drifts : mapping of str to DriftTrend
        :func:`hilident.ident.drift.axis_drifts`'s verdicts.
    """
    first = next(iter(drifts.values()), None)
    settings = first.frequency if first is not None else None
    doc = {
        "drift_percent_per_day": settings.threshold_percent_per_day if settings else None,
        "confidence": settings.confidence if settings else None,
        "flagged": [axis for axis, t in drifts.items() if t.flagged],
        "axes": {axis: _axis(t) for axis, t in drifts.items()},
    }
    return to_jsonable(doc)


def write_drift_json(out_dir: str | os.PathLike, drifts: Mapping[str, DriftTrend]) -> Path:
    """Write ``out_dir/drift.json`` (atomically); returns its path.

    Raises
    ------
    DataError
        The file cannot be written.
    """
    return write_json(Path(out_dir) / DRIFT_JSON, drift_document(drifts))
