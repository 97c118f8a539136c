"""The batch's drift verdicts: every row of the table, grouped by axis, judged, drawn and written.

After a batch, the whole table (this batch's rows and those of earlier runs)
goes through :func:`hilident.ident.drift.axis_drifts` with the ``[batch]``
settings; ``drift.json`` (:mod:`hilident.io.drift_json`) and ``report.html``
with the drift view (:mod:`hilident.html_report.batch`) are written beside the
table, so a nightly run keeps one up-to-date picture of the fleet.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hilident.config.tables import BatchConfig
    from hilident.ident.drift import DriftTrend


def judge_fleet(
    out: str | Path,
    rows: Sequence[Mapping[str, Any]],
    settings: BatchConfig,
    meta: Mapping[str, Any],
    *,
    plots: bool = True,
) -> dict[str, DriftTrend]:
    """Each axis's drift verdict from ``rows``; ``drift.json`` and ``report.html`` written into ``out``.

    Parameters
    ----------
    out : path
        The batch's folder (it holds the table).
    rows : sequence of mapping
        Every row of the table.
    settings : BatchConfig
        ``[batch]``: ``drift_percent_per_day`` (%/day), ``min_recordings``, ``confidence``.
    meta : mapping
        What was run, for the report's first section (see
        :func:`hilident.html_report.batch.write_batch_report`).
    plots : bool
        Draw the drift figures (``drift.png``, ...).

    Returns
    -------
    dict of str to DriftTrend
        The verdicts, by axis.
    """
    from hilident.html_report.batch import write_batch_report
    from hilident.ident.drift import axis_drifts
    from hilident.io.drift_json import write_drift_json

    drifts = axis_drifts(rows, settings.drift_percent_per_day, settings.min_recordings, settings.confidence)
    write_drift_json(out, drifts)
    write_batch_report(out, rows, drifts, meta, plots=plots)
    return drifts


def verdict_lines(drifts: Mapping[str, DriftTrend]) -> list[str]:
    """One line per flagged axis, then one counting the others: what the command prints."""
    flagged = [d for d in drifts.values() if d.flagged]
    lines = [f"drift: {d.axis}: {d.verdict}" for d in flagged]
    short = sum(1 for d in drifts.values() if d.insufficient)
    lines.append(
        f"drift: {len(flagged)} of {len(drifts)} axes flagged"
        + (f", {short} with too few recordings for a verdict" if short else "")
    )
    return lines
