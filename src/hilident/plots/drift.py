"""The drift view of a batch: one panel per axis, its resonance and damping over the days, and the trend.

Each panel shows the identified resonance of every usable recording with its
95 % interval, the fitted straight line with the line's 95 % confidence band,
recordings far from the line ringed, and the damping ratio on a second y axis
(its own line, dashed). A flagged axis has a red title saying so with its rate;
an axis without enough data says that in grey. Flagged axes come first, then
the others by name; a figure holds :data:`PANELS_PER_FIGURE` panels (four
rows of three), so 50 axes make five figures, each readable on a page.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilident.plots.common import save

if TYPE_CHECKING:
    from hilident.ident.drift import DriftTrend

__all__ = [
    "PANELS_PER_FIGURE",
    "COLUMNS",
    "FLAGGED_COLOUR",
    "panel_title",
    "ordered",
    "drift_figures",
    "plot_drift",
    "drift_file_names",
]

#: Axes drawn in one figure (rows of :data:`COLUMNS`).
PANELS_PER_FIGURE = 12
#: Panels side by side.
COLUMNS = 3
#: Title colour of a flagged axis.
FLAGGED_COLOUR = "#c62828"


def _pm(value: float, half: float) -> str:
    if not math.isfinite(value):
        return "—"
    return f"{value:+.3g} ± {half:.2g}" if math.isfinite(half) else f"{value:+.3g}"


def panel_title(trend: DriftTrend) -> tuple[str, str]:
    """The title of an axis's panel and its colour: ``("x3: FLAGGED -0.52 ± 0.05 %/day", FLAGGED_COLOUR)``."""
    rate = f"{_pm(trend.rate_percent_per_day, trend.rate_ci95_percent_per_day)} %/day"
    if trend.flagged:
        return f"{trend.axis}: FLAGGED {rate}", FLAGGED_COLOUR
    if trend.insufficient:
        return f"{trend.axis}: insufficient data (n = {trend.n})", "0.45"
    return f"{trend.axis}: {rate}", "black"


def ordered(drifts: Mapping[str, DriftTrend] | Iterable[DriftTrend]) -> list[DriftTrend]:
    """Flagged axes first, then the others; by axis name within each."""
    trends = list(drifts.values()) if isinstance(drifts, Mapping) else list(drifts)
    return sorted(trends, key=lambda t: (not t.flagged, t.axis))


def _errors(ci95: tuple[float, ...]) -> np.ndarray | None:
    half = np.asarray(ci95, dtype=float)
    if not np.any(np.isfinite(half)):
        return None
    return np.where(np.isfinite(half), half, 0.0)


def _panel(ax, trend: DriftTrend):
    """Draw one axis's panel on ``ax``; returns the damping's twin axes (None without damping)."""
    freq, damp = trend.frequency, trend.damping
    days = np.asarray(freq.days)
    ax.errorbar(
        days,
        freq.values,
        yerr=_errors(freq.ci95),
        fmt="o",
        ms=3.5,
        color="tab:blue",
        ecolor="0.55",
        elinewidth=0.8,
        capsize=2,
        label="resonance (95 % interval)",
    )
    if freq.has_line and days.size:
        grid = np.linspace(0.0, float(days.max()), 100)
        line, band = freq.line(grid), freq.band(grid)
        ax.fill_between(grid, line - band, line + band, color="tab:blue", alpha=0.18, label="trend's 95 % band")
        ax.plot(grid, line, "-", color="tab:blue", lw=1.5, label="trend (least squares)")
    if freq.outliers:
        idx = list(freq.outliers)
        ax.plot(
            days[idx],
            np.asarray(freq.values)[idx],
            "o",
            ms=9,
            mfc="none",
            mec=FLAGGED_COLOUR,
            mew=1.3,
            label="outlier (listed, kept)",
        )
    ax.set_xlabel("days since first recording [d]")
    ax.set_ylabel("resonance [Hz]", color="tab:blue")
    ax.grid(True, alpha=0.3)
    text, colour = panel_title(trend)
    ax.set_title(text, color=colour, fontsize=10, fontweight="bold" if trend.flagged else "normal")
    twin = None
    if damp.n:
        twin = ax.twinx()
        dd = np.asarray(damp.days)
        twin.errorbar(
            dd,
            damp.values,
            yerr=_errors(damp.ci95),
            fmt="s",
            ms=3,
            color="tab:orange",
            ecolor="tab:orange",
            elinewidth=0.6,
            alpha=0.8,
            capsize=0,
            label="damping ratio (95 % interval)",
        )
        if damp.has_line:
            grid = np.linspace(0.0, float(dd.max()), 50)
            twin.plot(grid, damp.line(grid), "--", color="tab:orange", lw=1.2, label="damping trend")
        if damp.outliers:
            idx = list(damp.outliers)
            twin.plot(
                dd[idx],
                np.asarray(damp.values)[idx],
                "s",
                ms=9,
                mfc="none",
                mec=FLAGGED_COLOUR,
                mew=1.3,
                label="outlier (listed, kept)",
            )
        twin.set_ylabel("damping ratio [1]", color="tab:orange")
    return twin


def drift_figures(
    drifts: Mapping[str, DriftTrend] | Iterable[DriftTrend], *, title: str = "", per_figure: int = PANELS_PER_FIGURE
) -> list:
    """The drift view as matplotlib figures (not saved), :data:`PANELS_PER_FIGURE` axes each.

    Parameters
    ----------
    drifts : mapping of str to DriftTrend, or iterable of DriftTrend
        :func:`hilident.ident.drift.axis_drifts`'s result.
    title : str
        What the batch was (config, date), added to each figure's title.
    per_figure : int
        Panels per figure.

    Returns
    -------
    list of matplotlib.figure.Figure
        Empty when there is no axis.
    """
    from matplotlib.figure import Figure

    trends = ordered(drifts)
    per_figure = max(1, int(per_figure))
    pages = [trends[i : i + per_figure] for i in range(0, len(trends), per_figure)]
    figures = []
    for number, page in enumerate(pages, start=1):
        rows = math.ceil(len(page) / COLUMNS)
        columns = min(COLUMNS, len(page))
        fig = Figure(figsize=(4.6 * columns + 0.6, 3.3 * rows + 0.9), dpi=90, layout="constrained")
        axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False)).ravel()
        twins = [_panel(ax, trend) for ax, trend in zip(axes, page, strict=False)]
        for ax in axes[len(page) :]:
            ax.set_visible(False)
        flagged = sum(t.flagged for t in trends)
        head = f"Resonance drift per axis ({flagged} of {len(trends)} flagged)"
        more = f", figure {number} of {len(pages)}" if len(pages) > 1 else ""
        fig.suptitle(f"{head}{more}" + (f" — {title}" if title else ""), fontsize=11)
        handles: dict[str, Any] = {}
        for ax in [*axes[: len(page)], *(t for t in twins if t is not None)]:
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
                handles.setdefault(label, handle)
        fig.legend(
            list(handles.values()), list(handles), loc="outside lower center", ncols=min(len(handles), 4), fontsize=8
        )
        figures.append(fig)
    return figures


def drift_file_names(count: int) -> list[str]:
    """``drift.png``, ``drift_2.png``, ...: the files of ``count`` drift figures."""
    return ["drift.png" if i == 1 else f"drift_{i}.png" for i in range(1, count + 1)]


def plot_drift(
    out_dir: str | os.PathLike, drifts: Mapping[str, DriftTrend] | Iterable[DriftTrend], **kwargs: Any
) -> list[Path]:
    """Write the drift view as ``drift.png`` (and ``drift_2.png``, ... for more than one figure) in ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Folder to write into (exists).
    drifts : mapping of str to DriftTrend, or iterable of DriftTrend
        The verdicts per axis.
    **kwargs
        ``title``, ``per_figure``: as :func:`drift_figures`.

    Returns
    -------
    list of pathlib.Path
        The PNGs written, in order (none without axes).
    """
    figures = drift_figures(drifts, **kwargs)
    return [save(fig, Path(out_dir) / name) for fig, name in zip(figures, drift_file_names(len(figures)), strict=True)]
