"""The same move without and with the notch: the load signal after each set-point's end, overlaid.

Both moves are drawn against the time after their own set-point's end (a
shaped move ends later; the delay is in the legend), as the deviation from
the final value the residual was measured around. The measured dwell is
shaded, the settling band drawn, and each move's RMS, peak-to-peak and
settling time are in its legend entry; the reduction in dB is in the title.
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.motion.residual import MoveComparison, ResidualVibration
from hilident.plots.common import channel_unit, config_name, outside_legend, plot_title, same_length, save, vector

__all__ = ["moves_figure", "plot_moves", "signal_scale"]

#: Display unit of a residual's key suffix where the channel-name rule does not know it.
_SUFFIX_UNITS = {"mps2": "m/s²", "g": "g"}
#: Smaller units a metre signal is drawn in, largest first: (unit, metres per unit).
_METRE_SCALES = (("m", 1.0), ("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9))


def signal_scale(unit_suffix: str, magnitude: float) -> tuple[str, float]:
    """Display unit and divisor for a signal: metres go to mm, µm or nm so ``magnitude`` reads as 1 to 1000.

    Examples
    --------
    >>> signal_scale("m", 3.5e-5)
    ('µm', 1e-06)
    >>> signal_scale("mps2", 0.2)
    ('m/s²', 1.0)
    """
    unit = _SUFFIX_UNITS.get(unit_suffix) or channel_unit(f"x_{unit_suffix}") or unit_suffix
    if unit != "m" or not np.isfinite(magnitude) or magnitude <= 0:
        return unit, 1.0
    for name, size in _METRE_SCALES:
        if magnitude >= size:
            return name, size
    return _METRE_SCALES[-1]


def _number(x: float, unit: str) -> str:
    return f"{x:.3g} {unit}"


def _entry(name: str, r: ResidualVibration, unit: str, scale: float, delay_s: float | None) -> str:
    settles = (
        "settles in " + _number(r.settling_time_s, "s") if r.settling_time_s is not None else "not settled in the dwell"
    )
    delay = f"\nends {delay_s:.3g} s later" if delay_s else ""
    return (
        f"{name}:\nRMS {_number(r.rms / scale, unit)}, peak-to-peak {_number(r.peak_to_peak / scale, unit)}"
        f"\n{settles}{delay}"
    )


def moves_figure(
    comparison: MoveComparison,
    without_time_s: Any,
    without_signal: Any,
    with_time_s: Any,
    with_signal: Any,
    *,
    signal_name: str = "load",
    subject: str | None = None,
    when: dt.datetime | None = None,
    added_delay_s: float | None = None,
    before_s: float = 0.25,
    shaped: tuple = (),
):
    """The figure of :func:`plot_moves`, unsaved (what the tests inspect).

    ``shaped``: ``(name, time_s, signal, residual, added_delay_s)`` of each move made with an input shaper,
    drawn beside the two (its residual measured with the same band).

    Raises
    ------
    DataError
        Empty or mismatched arrays.
    """
    from matplotlib.figure import Figure

    curves = []
    delays = {"with notch": added_delay_s} | {str(m[0]): m[4] for m in shaped}
    for name, t, y, r in (
        ("without notch", without_time_s, without_signal, comparison.without),
        ("with notch", with_time_s, with_signal, comparison.with_notch),
        *((str(m[0]), m[1], m[2], m[3]) for m in shaped),
    ):
        tv = vector(t, f"{name} time_s")
        yv = vector(y, f"{name} signal")
        same_length(tv, f"{name} time_s", yv, f"{name} signal")
        x = tv - r.move_end_s
        keep = (x >= -before_s) & (x <= r.dwell_s)
        if not np.any(keep):
            raise DataError(f"{name}: no samples from {before_s:g} s before the move's end to the dwell's end")
        curves.append((name, x[keep], yv[keep] - r.final_value, r))
    before, after = comparison.without, comparison.with_notch
    magnitude = max(before.first_peak, after.first_peak, before.band, *(c[3].first_peak for c in curves))
    unit, scale = signal_scale(before.unit, magnitude)

    fig = Figure(figsize=(10.0, 4.8), dpi=110, layout="constrained")
    ax = fig.subplots()
    ax.axvspan(0.0, max(c[3].dwell_s for c in curves), color="0.92", zorder=0, label="dwell (measured)")
    band = before.band / scale
    ax.axhline(band, color="tab:green", ls="--", lw=0.9, label=f"settling band ±{band:.3g} {unit}")
    ax.axhline(-band, color="tab:green", ls="--", lw=0.9)
    ax.axvline(0.0, color="0.5", lw=0.8)
    colours = ("tab:red", "tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink")
    for (name, x, y, r), colour in zip(curves, colours, strict=False):
        delay = delays.get(name)
        ax.plot(x, y / scale, color=colour, lw=1.0, label=_entry(name, r, unit, scale, delay))
        if r.settling_time_s is not None and r.settling_time_s > 0:
            ax.axvline(r.settling_time_s, color=colour, ls=":", lw=0.9)
    ax.set_xlabel("time after the set-point's end [s]")
    ax.set_ylabel(f"{signal_name}, deviation from its final value [{unit}]")
    ax.grid(True, alpha=0.3)
    reduction = (
        f"residual vibration reduced by {comparison.rms_reduction_db:.1f} dB (RMS), "
        f"{comparison.peak_to_peak_reduction_db:.1f} dB (peak-to-peak) with the notch"
    )
    shaped_reductions = [
        f"{20.0 * np.log10(before.rms / r.rms):.1f} dB (RMS) with the {name}"
        for name, _, _, r in curves[2:]
        if r.rms > 0
    ]
    if shaped_reductions:
        reduction += "\n" + "; ".join(shaped_reductions)
    ax.set_title(f"{plot_title(config_name(subject), when, 'Move')}\n{reduction}", fontsize=10)
    outside_legend(ax)
    return fig


def plot_moves(
    path: str | os.PathLike,
    comparison: MoveComparison,
    without_time_s: Any,
    without_signal: Any,
    with_time_s: Any,
    with_signal: Any,
    **kwargs: Any,
) -> Path:
    """Both moves' load signal after the move, overlaid, with the dwell, the settling band and the figures.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    comparison : MoveComparison
        From :func:`hilident.motion.residual.compare_moves` on the same signals.
    without_time_s, without_signal : array_like
        The move without the notch: times (s, the axis ``comparison.without.move_end_s`` is on) and signal.
    with_time_s, with_signal : array_like
        The move with the notch.
    **kwargs
        ``signal_name`` (y-axis label, e.g. ``"load deflection (laser)"``), ``subject`` (the
        config's file, for the title), ``when`` (the title's date, default now),
        ``added_delay_s`` (how much later the shaped move ends, s), ``before_s``
        (time drawn before the move's end, s), ``shaped`` (the moves with input shapers, as
        :func:`moves_figure` takes them).

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        Empty or mismatched arrays, or no samples near the moves' ends.
    """
    return save(moves_figure(comparison, without_time_s, without_signal, with_time_s, with_signal, **kwargs), path)
