"""Bode plot a controls engineer can read: units, the analysis band, coherence, model, designed and stored notch.

Every response is drawn over the whole frequency range it was measured on;
the lines outside the analysis band or under the coherence threshold are
drawn grey (still visible, not trusted), the others in colour. The phase is
unwrapped and put on the branch where the band's first line lies in
(-180, 180] deg. The magnitude axis says its reference unit
(``dB re 1 (m/s)/(N·m)``), legends sit beside the axes, not on the data.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.plots.common import outside_legend, plain_number, same_length, save, vector

__all__ = ["PER_CURVE", "bode_figure", "plot_bode", "branch_phase_deg"]

#: ``magnitude_unit`` when the curves have different units, each given in its label.
PER_CURVE = "per curve"

#: Colour and line style of each response in turn: told apart in colour and in black and white.
_STYLES = (("tab:blue", "-"), ("tab:orange", "--"), ("tab:green", "-."), ("tab:purple", ":"))
_GREY = "0.72"
#: The view reaches this factor beyond the analysis band on either side.
_VIEW_MARGIN = 2.0


def branch_phase_deg(h: np.ndarray, in_band: np.ndarray) -> np.ndarray:
    """Unwrapped phase, deg, on the branch where the first in-band line lies in (-180, 180].

    Outside the band (noise, where ``unwrap`` wanders off by turns) each line
    is put within 180 deg of the nearest band edge, so it stays in view.

    Parameters
    ----------
    h : ndarray of complex
        Response at increasing frequencies.
    in_band : ndarray of bool
        Lines inside the analysis band (all False: the first line decides).
    """
    phase = np.degrees(np.unwrap(np.angle(h)))
    idx = np.flatnonzero(in_band)
    first = int(idx[0]) if idx.size else 0
    phase = phase - 360.0 * np.ceil((phase[first] - 180.0) / 360.0)
    if idx.size:
        last = int(idx[-1])
        for sl, ref in ((slice(0, first), phase[first]), (slice(last + 1, None), phase[last])):
            phase[sl] -= 360.0 * np.round((phase[sl] - ref) / 360.0)
    return phase


def _positive_curve(frequency_hz, response, name: str) -> tuple[np.ndarray, np.ndarray]:
    f = vector(frequency_hz, f"{name} frequency_hz")
    h = vector(response, f"{name} response", dtype=complex)
    same_length(f, f"{name} frequency_hz", h, f"{name} response")
    keep = f > 0
    return f[keep], h[keep]


def _phase_near(f: np.ndarray, phase_deg: np.ndarray, reference: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """``phase_deg`` moved line by line by whole turns to within 180 deg of a reference curve.

    A notch's near-zero makes ``unwrap`` pick a branch at random; curves of
    one plant (before/after a notch, the model) are compared on one branch.
    """
    if reference is None:
        return phase_deg
    f_ref, p_ref = reference
    inside = (f >= f_ref[0]) & (f <= f_ref[-1])
    if not np.any(inside):
        return phase_deg
    ref = np.interp(f, f_ref, p_ref)
    out = phase_deg.copy()
    out[inside] -= 360.0 * np.round((phase_deg[inside] - ref[inside]) / 360.0)
    return out


def _bode_curves(responses: Sequence[tuple[str, Any]]) -> list[tuple[str, np.ndarray, np.ndarray, Any]]:
    """``(label, f, h, coherence or None)`` of each response, checked, at positive frequencies only."""
    if len(responses) == 0:
        raise DataError("plot_bode: responses is empty; pass at least one (label, frf)")
    curves = []
    for label, frf in responses:
        f = vector(getattr(frf, "frequency_hz", None), f"responses[{label!r}].frequency_hz")
        h = vector(getattr(frf, "response", None), f"responses[{label!r}].response", dtype=complex)
        same_length(f, f"responses[{label!r}].frequency_hz", h, f"responses[{label!r}].response")
        coh_raw = getattr(frf, "coherence", None)
        coh = None
        if coh_raw is not None:
            coh = vector(coh_raw, f"responses[{label!r}].coherence")
            same_length(f, f"responses[{label!r}].frequency_hz", coh, f"responses[{label!r}].coherence")
        keep = f > 0
        if not np.any(keep):
            raise DataError(f"responses[{label!r}].frequency_hz: no positive frequency to plot")
        curves.append((str(label), f[keep], h[keep], None if coh is None else coh[keep]))
    return curves


def _limits(values: list[np.ndarray], floor_span: float) -> tuple[float, float] | None:
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.empty(0)
    if finite.size == 0:
        return None
    top = float(finite.max())
    # a notch's one-line dive to -300 dB does not squash the curves
    bottom = max(float(finite.min()), float(np.percentile(finite, 0.5)) - 20.0)
    span = max(top - bottom, floor_span)
    return bottom - 0.05 * span, top + 0.05 * span


def bode_figure(
    responses: Sequence[tuple[str, Any]],
    resonances: Iterable[Any] = (),
    notch_response: tuple[Any, Any] | None = None,
    coherence_threshold: float | None = None,
    model: tuple[str, Any, Any] | None = None,
    bounds_db: tuple[Any, Any] | None = None,
    *,
    title: str | None = None,
    magnitude_unit: str | None = None,
    band_hz: tuple[float, float] | None = None,
    stored_notch: tuple[Any, Any] | None = None,
    notch_label: str = "designed notch [dB re 1]",
):
    """The Bode figure (magnitude, phase, coherence) of :func:`plot_bode`, not saved.

    Returns
    -------
    matplotlib.figure.Figure
        Axes 0, 1, 2: magnitude, phase, coherence.
    """
    from matplotlib.figure import Figure

    curves = _bode_curves(responses)
    notch = None if notch_response is None else _positive_curve(*notch_response, "notch_response")
    stored = None if stored_notch is None else _positive_curve(*stored_notch, "stored_notch")
    span = _frequency_span(curves)
    band = _analysis_band(band_hz, span)
    threshold = None if coherence_threshold is None else float(coherence_threshold)

    fig = Figure(figsize=(10.0, 9.0), dpi=110, layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    ax_mag, ax_phase, ax_coh = axes
    with np.errstate(divide="ignore", invalid="ignore"):
        first_bounds = None if bounds_db is None else (responses[0][1], bounds_db)
        mags, phases, reference = _draw_responses(axes, curves, band, threshold, first_bounds)
        if model is not None:
            _draw_model(ax_mag, ax_phase, model, band, reference)
        mags += _draw_notches(ax_mag, notch, stored, notch_label, band)
    _magnitude_limits(ax_mag, mags)
    _phase_axis(ax_phase, phases)
    view = _view(band, span)
    if view[1] > view[0]:
        ax_mag.set_xlim(*view)
    _shade_outside_band(axes, view, band)
    _coherence_notes(ax_coh, threshold, curves)
    _mark_resonances(axes, resonances)
    _axes_labels(axes, magnitude_unit)
    if title:
        fig.suptitle(title, fontsize=11)
    outside_legend(ax_mag)
    outside_legend(ax_coh)
    return fig


def _frequency_span(curves: list[tuple[str, np.ndarray, np.ndarray, Any]]) -> tuple[float, float]:
    """Lowest and highest positive frequency of all the curves, Hz."""
    return min(float(c[1][0]) for c in curves), max(float(c[1][-1]) for c in curves)


def _analysis_band(band_hz: tuple[float, float] | None, span: tuple[float, float]) -> tuple[float, float]:
    """The analysis band, Hz: ``band_hz`` clipped to the measured ``span``; the whole span when none or disjoint.

    Raises
    ------
    DataError
        ``band_hz`` is not ``(low, high)`` with ``0 <= low < high``, both finite.
    """
    f_lo, f_hi = span
    if band_hz is None:
        return span
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise DataError(f"plot_bode: band_hz must be (low, high) with 0 <= low < high, got {band_hz!r}")
    return (max(lo, f_lo), min(hi, f_hi)) if lo < f_hi and hi > f_lo else span


def _view(band: tuple[float, float], span: tuple[float, float]) -> tuple[float, float]:
    """Frequency view, Hz: :data:`_VIEW_MARGIN` beyond the band on either side, within the measured ``span``."""
    return max(band[0] / _VIEW_MARGIN, span[0]), min(band[1] * _VIEW_MARGIN, span[1])


def _in_band(f: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """Lines of ``f`` (Hz) inside the analysis ``band`` (Hz), its edges included."""
    return (f >= band[0]) & (f <= band[1])


def _trusted_lines(in_band: np.ndarray, coh: np.ndarray | None, threshold: float | None) -> np.ndarray:
    """Lines drawn in colour: inside the band and not under the coherence threshold."""
    trusted = in_band.copy()
    if coh is not None and threshold is not None:
        # an undefined coherence (NaN: one period, no averages) is unknown, not low: not greyed
        trusted &= ~(coh < threshold)
    return trusted


def _grey_label(threshold: float | None) -> str:
    """Legend entry of the greyed lines."""
    return "outside band" + (f" or coherence < {threshold:g}" if threshold is not None else "")


def _draw_responses(
    axes,
    curves: list[tuple[str, np.ndarray, np.ndarray, Any]],
    band: tuple[float, float],
    threshold: float | None,
    first_bounds: tuple[Any, tuple[Any, Any]] | None,
) -> tuple[list[np.ndarray], list[np.ndarray], tuple[np.ndarray, np.ndarray] | None]:
    """Draw each measured response on the three axes, the first on top with its 95 % band.

    ``first_bounds`` is ``(frf, bounds_db)`` of the first response (None: no band drawn).

    Returns
    -------
    mags : list of ndarray
        Each response's magnitude inside the band, dB (all of it when no line is in the band).
    phases : list of ndarray
        Each response's phase on its trusted lines, deg.
    reference : (ndarray, ndarray) or None
        Frequency (Hz) and phase (deg) in band of the first response with a line in band: the branch the
        others are put on.
    """
    mags: list[np.ndarray] = []
    phases: list[np.ndarray] = []
    reference = None
    for i, (label, f, h, coh) in enumerate(curves):
        in_band = _in_band(f, band)
        trusted = _trusted_lines(in_band, coh, threshold)
        color, ls = _STYLES[i % len(_STYLES)]
        # the first response (the plant) on top, and thicker
        style = dict(color=color, ls=ls, lw=1.8 if i == 0 else 1.3, zorder=3 + len(curves) - i)
        mag_db = 20 * np.log10(np.abs(h))
        phase = _phase_near(f, branch_phase_deg(h, in_band), reference)
        if reference is None and np.any(in_band):
            reference = (f[in_band], phase[in_band])
        grey_label = _grey_label(threshold) if i == 0 else None
        _draw_magnitude_and_phase(axes, f, mag_db, phase, trusted, label, style, grey_label)
        mags.append(mag_db[in_band] if np.any(in_band) else mag_db)
        phases.append(phase[trusted])
        if coh is not None:
            _draw_coherence(axes[2], f, coh, in_band, label, style, "os^v"[i % 4])
        if i == 0 and first_bounds is not None:
            _confidence_band(axes[0], f, mag_db, in_band, *first_bounds, color)
    return mags, phases, reference


def _draw_magnitude_and_phase(
    axes,
    f: np.ndarray,
    mag_db: np.ndarray,
    phase: np.ndarray,
    trusted: np.ndarray,
    label: str,
    style: dict,
    grey_label: str | None,
) -> None:
    """One response's magnitude (dB) and phase (deg): every line grey underneath, the trusted ones in colour."""
    ax_mag, ax_phase = axes[0], axes[1]
    ax_mag.semilogx(f, mag_db, color=_GREY, lw=0.7, zorder=1, label=grey_label)
    ax_phase.semilogx(f, phase, color=_GREY, lw=0.7, zorder=1)
    ax_mag.semilogx(f, np.where(trusted, mag_db, np.nan), label=label, **style)
    ax_phase.semilogx(f, np.where(trusted, phase, np.nan), label=label, **style)


def _draw_coherence(
    ax_coh, f: np.ndarray, coh: np.ndarray, in_band: np.ndarray, label: str, style: dict, marker: str
) -> None:
    """One response's coherence: grey outside the band, in colour with about ten markers inside.

    ``style`` is the response's magnitude line style; its width is replaced by one for every coherence.
    """
    ax_coh.semilogx(f, np.where(in_band, np.nan, coh), color=_GREY, lw=0.7, zorder=1)
    inside = np.flatnonzero(in_band)
    marks = slice(int(inside[0]), int(inside[-1]) + 1, max(1, inside.size // 10)) if inside.size else None
    line = {**style, "lw": 1.5}
    ax_coh.semilogx(f, np.where(in_band, coh, np.nan), marker=marker, markevery=marks, ms=4, label=f"{label}", **line)


def _draw_model(
    ax_mag,
    ax_phase,
    model: tuple[str, Any, Any],
    band: tuple[float, float],
    reference: tuple[np.ndarray, np.ndarray] | None,
) -> None:
    """The fitted model's magnitude (dB) and phase (deg) inside the band, on the first response's phase branch."""
    mf, mh = _positive_curve(model[1], model[2], "model")
    m_in = _in_band(mf, band)
    m_phase = _phase_near(mf, branch_phase_deg(mh, m_in), reference)
    # dashed: the measured curve under it stays visible
    style = dict(color="k", lw=0.9, ls=(0, (4, 2)), zorder=10, label=str(model[0]))
    ax_mag.semilogx(mf[m_in], 20 * np.log10(np.abs(mh[m_in])), **style)
    ax_phase.semilogx(mf[m_in], m_phase[m_in], **style)


def _draw_notches(
    ax_mag,
    notch: tuple[np.ndarray, np.ndarray] | None,
    stored: tuple[np.ndarray, np.ndarray] | None,
    notch_label: str,
    band: tuple[float, float],
) -> list[np.ndarray]:
    """The designed and the stored notch chain's magnitude (dB); returns each drawn one's magnitude in band, dB."""
    mags = []
    # the designed notch dashed over the stored one: both visible where the device holds the design
    for curve, style, label in (
        (notch, dict(color="tab:brown", ls=(0, (5, 2)), lw=1.3, zorder=9), notch_label),
        (stored, dict(color="tab:red", ls="-", lw=2.0, alpha=0.8, zorder=8), "stored notch, read back [dB re 1]"),
    ):
        if curve is not None and curve[0].size:
            n_db = 20 * np.log10(np.abs(curve[1]))
            ax_mag.semilogx(curve[0], n_db, label=label, **style)
            mags.append(n_db[_in_band(curve[0], band)])
    return mags


def _magnitude_limits(ax_mag, mags: list[np.ndarray]) -> None:
    """Limits around the magnitudes (dB) in band, when any is finite."""
    mag_limits = _limits(mags, 1.0)
    if mag_limits:
        ax_mag.set_ylim(*mag_limits)


def _shade_outside_band(axes, view: tuple[float, float], band: tuple[float, float]) -> None:
    """Light grey on every axis between the view's edges and the band's, Hz."""
    ax_mag = axes[0]
    for ax in axes:
        for lo, hi in ((view[0], band[0]), (band[1], view[1])):
            if hi > lo:
                ax.axvspan(
                    lo,
                    hi,
                    color="0.9",
                    zorder=0,
                    lw=0,
                    label="outside analysis band" if ax is ax_mag and lo == view[0] else None,
                )


def _coherence_notes(ax_coh, threshold: float | None, curves: list[tuple[str, np.ndarray, np.ndarray, Any]]) -> None:
    """The coherence threshold as a dashed line, or a note that no response has a coherence."""
    if threshold is not None:
        ax_coh.axhline(threshold, color="0.3", ls="--", lw=1.0, label=f"threshold {threshold:g}")
    if not any(c[3] is not None for c in curves):
        ax_coh.text(0.5, 0.5, "no coherence", transform=ax_coh.transAxes, ha="center", va="center", color="0.4")


def plot_bode(
    path: str | os.PathLike,
    responses: Sequence[tuple[str, Any]],
    resonances: Iterable[Any] = (),
    notch_response: tuple[Any, Any] | None = None,
    coherence_threshold: float | None = None,
    model: tuple[str, Any, Any] | None = None,
    bounds_db: tuple[Any, Any] | None = None,
    **kwargs: Any,
) -> Path:
    """Bode plot (magnitude, phase, coherence) of one or more measured responses, written as PNG.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    responses : sequence of (label, frf)
        ``frf`` has attributes ``frequency_hz`` (1-D, Hz), ``response`` (complex
        1-D, same length) and ``coherence`` (1-D in 0..1, same length, or
        ``None``). The first is drawn on top, solid; each has its own colour,
        line style and (coherence) marker. The DC line is not drawn.
    resonances : iterable
        Objects with a ``frequency_hz`` attribute; a dotted red marker on all
        axes, the frequency written at the top.
    notch_response : (frequency_hz, response), optional
        The designed notch chain (dimensionless gain), dashed, best on a fine grid.
    coherence_threshold : float, optional
        Drawn on the coherence axis; lines under it are greyed.
    model : (label, frequency_hz, response), optional
        A fitted model's response, thin black, drawn inside the band only
        (say what it is: ``"fitted TF, 3 zeros / 4 poles"``).
    bounds_db : (lower_db, upper_db), optional
        95 % band of the first response relative to itself (dB, one value per
        line of that response), shaded inside the analysis band.
    **kwargs
        ``title`` (str: config and date), ``magnitude_unit`` (str, e.g.
        ``"(m/s)/(N·m)"``: the axis reads ``dB re 1 (m/s)/(N·m)``;
        :data:`PER_CURVE` when each label gives its curve's unit),
        ``band_hz`` ((low, high) Hz: the analysis band; lines outside are
        greyed and the view reaches a factor 2 beyond it), ``stored_notch``
        ((frequency_hz, response): the chain the device stores, read back),
        ``notch_label``.

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        No response, a response's arrays of different lengths, no positive
        frequency, a malformed notch, model or band.
    """
    return save(
        bode_figure(responses, resonances, notch_response, coherence_threshold, model, bounds_db, **kwargs), path
    )


def _confidence_band(ax_mag, f: np.ndarray, mag_db: np.ndarray, in_band: np.ndarray, frf, bounds_db, color) -> None:
    """The first response's 95 % band (``bounds_db``, dB relative to it, one value per line), shaded in band."""
    f_all = vector(frf.frequency_hz, "responses[0].frequency_hz")
    lo = vector(bounds_db[0], "bounds_db lower")
    hi = vector(bounds_db[1], "bounds_db upper")
    same_length(f_all, "responses[0].frequency_hz", lo, "bounds_db lower")
    same_length(f_all, "responses[0].frequency_hz", hi, "bounds_db upper")
    k = f_all > 0
    lo, hi = lo[k], hi[k]
    if not np.any(in_band):
        return
    lo_db = np.maximum(mag_db + lo, mag_db - 40.0)  # a line with no coherence: cap the band
    width = np.nanmedian((hi - np.maximum(lo, -40.0))[in_band]) / 2.0
    ax_mag.fill_between(
        f,
        np.where(in_band, lo_db, np.nan),
        np.where(in_band, mag_db + hi, np.nan),
        color=color,
        alpha=0.3,
        lw=0.6,
        edgecolor=color,
        zorder=2,
        label=f"95 % confidence (median ±{width:.2g} dB)",
    )


def _phase_axis(ax_phase, phases: list[np.ndarray]) -> None:
    """Limits around the trusted lines' phase, ticks at 45, 90 or 180 deg."""
    from matplotlib.ticker import MultipleLocator

    lim = _limits(phases, 90.0)
    if lim is None:
        return
    ax_phase.set_ylim(*lim)
    span = lim[1] - lim[0]
    ax_phase.yaxis.set_major_locator(MultipleLocator(45.0 if span <= 360 else 90.0 if span <= 900 else 180.0))


def _mark_resonances(axes, resonances: Iterable[Any]) -> None:
    """A dotted red line at each resonance on every axis, its frequency written at the top."""
    ax_mag = axes[0]
    for i, res in enumerate(resonances):
        f_res = float(res.frequency_hz)
        for ax in axes:
            ax.axvline(f_res, color="tab:red", ls=":", lw=1.0, label="resonance" if (i == 0 and ax is ax_mag) else None)
        ax_mag.annotate(
            f"{f_res:.4g} Hz",
            xy=(f_res, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -3),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize=8,
            color="tab:red",
        )


def _axes_labels(axes, magnitude_unit: str | None) -> None:
    """Labels with units, limits, grid and plain 1-2-5 frequency ticks."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    ax_mag, ax_phase, ax_coh = axes
    if magnitude_unit == PER_CURVE:
        ax_mag.set_ylabel("magnitude [dB re 1, units in legend]")
    else:
        ax_mag.set_ylabel(
            f"magnitude [dB re 1 {magnitude_unit}]" if magnitude_unit else "magnitude [dB re 1, unit not recorded]"
        )
    ax_phase.set_ylabel("phase [deg]")
    ax_coh.set_ylabel("coherence [-]")
    ax_coh.set_ylim(0.0, 1.05)
    ax_coh.set_xlabel("frequency [Hz]")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(plain_number))
        ax.xaxis.set_minor_formatter(NullFormatter())
