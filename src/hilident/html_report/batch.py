"""``report.html`` of ``hilident batch``: what was run, the drift verdict of every axis, the drift view,
the failures and every recording's row.

Built from the same pieces as a run's report (:func:`hilident.html_report.page.page`, the tables and
figures of :mod:`hilident.html_report.markup`): one self-contained page, no JavaScript, plots as
``data:`` URIs. Flagged axes come first in the verdict table and in the figures.
"""

from __future__ import annotations

import datetime as dt
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hilident.html_report import REPORT_NAME
from hilident.html_report.markup import MISSING, esc, figure, key_values, note, num, pm, section, table
from hilident.io.serialise import atomic_write

if TYPE_CHECKING:
    from hilident.ident.drift import DriftTrend

__all__ = ["BATCH_SECTIONS", "write_batch_report", "render_batch"]

#: The sections of a batch report in page order: (anchor, heading).
BATCH_SECTIONS = (
    ("run", "What was run"),
    ("drift", "Drift verdicts"),
    ("drift-plots", "Drift plots"),
    ("failures", "Failures"),
    ("recordings", "Recordings"),
)

#: ``meta`` keys shown under their own label, in this order; any other key is shown as it is named.
_META_LABELS = {
    "command": "command",
    "inputs": "inputs",
    "config": "configuration",
    "out": "output folder",
    "scheduler": "scheduler",
    "workers": "workers",
    "started_utc": "started",
    "wall_time_s": "wall time",
    "skipped": "skipped (already done)",
}


#: Recordings up to which the per-recording table is shown unfolded.
_OPEN_UP_TO = 200


def _float(value: Any) -> float | None:
    """A finite number, or None (shown as the missing mark)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _meta_value(key: str, value: Any) -> str:
    if key == "wall_time_s":
        return num(_float(value), "s", 3)
    if isinstance(value, (list, tuple)):
        return "<br>".join(esc(v) for v in value) or MISSING
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return MISSING if value in (None, "") else esc(value)
    return num(value)


def _run(rows: Sequence[Mapping[str, Any]], drifts: Mapping[str, DriftTrend], meta: Mapping[str, Any]) -> str:
    pairs = [(_META_LABELS[k], _meta_value(k, meta[k])) for k in _META_LABELS if k in meta]
    pairs += [(str(k), _meta_value(str(k), v)) for k, v in meta.items() if k not in _META_LABELS]
    ok = sum(1 for r in rows if r.get("status") == "ok")
    flagged = sum(1 for t in drifts.values() if t.flagged)
    pairs.append(("recordings", esc(f"{len(rows)}: {ok} identified, {len(rows) - ok} failed")))
    pairs.append(("axes", esc(f"{len(drifts)}, {flagged} flagged")))
    settings = next(iter(drifts.values()), None)
    if settings is not None:
        freq = settings.frequency
        pairs.append(
            (
                "drift flagged above",
                esc(f"{freq.threshold_percent_per_day:g} %/day, trend significant at {100 * freq.confidence:g} %"),
            )
        )
    return section("run", "What was run", key_values(pairs))


def _when(text: str) -> str:
    return esc(text[:16].replace("T", " ")) if text else MISSING


def _verdict_cell(trend: DriftTrend) -> str:
    text = esc(trend.verdict)
    return f'<strong class="flagged">{text}</strong>' if trend.flagged else text


def _drift(drifts: Mapping[str, DriftTrend]) -> str:
    from hilident.plots.drift import ordered

    if not drifts:
        return section("drift", "Drift verdicts", note("No axis in this batch."))
    rows = []
    for t in ordered(drifts):
        left_out = t.n_failed + t.n_unusable
        rows.append(
            [
                esc(t.axis),
                esc(f"{t.n} / {left_out}"),
                f"{_when(t.first_utc)} .. {_when(t.last_utc)}",
                num(_float(t.reference_hz), "Hz"),
                pm(_float(t.rate_percent_per_day), _float(t.rate_ci95_percent_per_day), "%/day", 3),
                num(_float(t.p_value), "", 2),
                pm(_float(t.damping_rate_percent_per_day), _float(t.damping_rate_ci95_percent_per_day), "%/day", 3),
                _verdict_cell(t),
            ]
        )
    body = table(
        [
            "axis",
            "recordings ok / left out",
            "first .. last (UTC)",
            "resonance at first",
            "drift rate (95 %)",
            "p",
            "damping drift (95 %)",
            "verdict",
        ],
        rows,
    )
    explain = (
        "The drift rate is the slope of a least-squares line through each axis's resonance over the days, "
        "as a percentage of the line's value at the first recording per day; its interval comes from the "
        "scatter of the recordings around the line (Student t), not from each recording's own interval. "
        "An axis is flagged when the trend is significant and steeper than the threshold; with too few "
        "recordings it is not judged. Left out: recordings that failed or gave no resonance."
    )
    outliers = [(t.axis, o) for t in ordered(drifts) for o in t.outliers]
    if outliers:
        body += table(
            ["axis", "quantity", "time (UTC)", "value", "residual", "file"],
            [
                [
                    esc(axis),
                    esc(o.quantity),
                    _when(o.time_utc),
                    num(o.value, "Hz" if o.quantity == "frequency" else ""),
                    esc(f"{o.robust_sigmas:+.1f} robust σ"),
                    esc(o.path),
                ]
                for axis, o in outliers
            ],
            caption="Recordings far from their axis's line (kept in the fit; worth a look)",
        )
    return section("drift", "Drift verdicts", body + note(explain))


def _plots(images: Sequence[tuple[str, bytes]]) -> str:
    if not images:
        return section("drift-plots", "Drift plots", note("No drift plots (no axis, or plots were not drawn)."))
    caption = (
        "Resonance of each recording over the days with its 95 % interval, the fitted trend and its 95 % "
        "band, the damping ratio on the right axis; flagged axes first, titled in red."
    )
    return section("drift-plots", "Drift plots", "".join(figure(name, png, caption) for name, png in images))


def _failures(rows: Sequence[Mapping[str, Any]]) -> str:
    failed = [r for r in rows if r.get("status") != "ok"]
    if not failed:
        return section("failures", "Failures", note("No recording failed."))
    body = table(
        ["file", "axis", "error"],
        [[esc(r.get("path", MISSING)), esc(r.get("axis") or MISSING), esc(r.get("error") or MISSING)] for r in failed],
    )
    return section("failures", "Failures", body)


def _recordings(rows: Sequence[Mapping[str, Any]]) -> str:
    if not rows:
        return section("recordings", "Recordings", note("No recording."))
    ordered_rows = sorted(rows, key=lambda r: (str(r.get("axis") or ""), str(r.get("time_utc") or "")))
    cells = [
        [
            esc(r.get("axis") or MISSING),
            _when(str(r.get("time_utc") or "")),
            esc(r.get("status", MISSING)),
            pm(_float(r.get("frequency_hz")), _float(r.get("frequency_ci95_hz")), "Hz"),
            pm(_float(r.get("damping_ratio")), _float(r.get("damping_ci95")), "", 3),
            esc(Path(str(r.get("path", ""))).name or MISSING),
        ]
        for r in ordered_rows
    ]
    body = table(["axis", "time (UTC)", "status", "resonance (95 %)", "damping ratio (95 %)", "file"], cells)
    # a year of nightly recordings of fifty axes is a long table: folded until asked for (a short one is open)
    state = " open" if len(rows) <= _OPEN_UP_TO else ""
    return section(
        "recordings",
        "Recordings",
        f"<details{state}><summary>{esc(len(rows))} recordings, by axis and time</summary>{body}</details>",
    )


def render_batch(
    rows: Sequence[Mapping[str, Any]],
    drifts: Mapping[str, DriftTrend],
    meta: Mapping[str, Any],
    images: Sequence[tuple[str, bytes]] = (),
    *,
    subtitle: str = "",
) -> str:
    """The batch report's HTML (pure): see :func:`write_batch_report`; ``images`` are ``(file name, PNG bytes)``."""
    from hilident.html_report.page import page

    subject = meta.get("config") or meta.get("out") or "fleet"
    parts = {
        "run": _run(rows, drifts, meta),
        "drift": _drift(drifts),
        "drift-plots": _plots(images),
        "failures": _failures(rows),
        "recordings": _recordings(rows),
    }
    return page(
        f"hilident batch: {subject}",
        subtitle,
        [(a, h, parts[a]) for a, h in BATCH_SECTIONS],
        "Written by hilident batch from the table of its recordings.",
    )


def write_batch_report(
    out_dir: str | os.PathLike,
    rows: Iterable[Mapping[str, Any]],
    drifts: Mapping[str, DriftTrend],
    meta: Mapping[str, Any],
    *,
    plots: bool = True,
) -> Path:
    """Write ``out_dir/report.html`` of a batch (and its drift figures, ``drift.png``, ... beside it).

    Parameters
    ----------
    out_dir : path-like
        The batch's output folder (exists).
    rows : iterable of mapping
        One per recording, the keys :func:`hilident.ident.drift.axis_drifts` reads.
    drifts : mapping of str to DriftTrend
        :func:`~hilident.ident.drift.axis_drifts`'s verdicts.
    meta : mapping
        What was run: ``inputs`` (list of str), ``config``, ``scheduler``, ``workers``, ``wall_time_s``,
        ``started_utc``, ``skipped``...; any other key is listed under its name.
    plots : bool
        Draw the drift figures (``False``: the section says they were not drawn).

    Returns
    -------
    pathlib.Path
        The report.
    """
    out = Path(out_dir)
    rows = list(rows)
    images: list[tuple[str, bytes]] = []
    if plots and drifts:
        from hilident.plots.drift import plot_drift

        title = str(meta.get("config") or "")
        images = [(p.name, p.read_bytes()) for p in plot_drift(out, drifts, title=Path(title).name if title else "")]
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    text = render_batch(rows, drifts, meta, images, subtitle=f"{out.name}, written {stamp}")
    path = out / REPORT_NAME
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))
    return path
