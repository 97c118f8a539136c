"""Plots of a run (and ``summary.json`` by its old name: :func:`write_summary`).

Pure output helpers: arrays in, files out. Plots are drawn with matplotlib's
object API (:class:`matplotlib.figure.Figure`, rendered by Agg), so nothing
here touches pyplot's global state or the process-wide backend, and
matplotlib is only imported when a plot is drawn.

Every writer creates the parent folder if needed and writes atomically (a
temporary file in the same folder, then :func:`os.replace`), so a reader never
sees half a PNG or half a JSON file. JSON is :mod:`hilident.serialise`'s job;
``to_jsonable`` is re-exported here for older imports.

Example
-------
>>> import numpy as np
>>> to_jsonable({"gain": np.float64(2.0), "pole": 1 + 2j, "bad": float("nan")})
{'gain': 2.0, 'pole': {'re': 1.0, 'im': 2.0}, 'bad': None}
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.serialise import atomic_write, to_jsonable, write_json

__all__ = [
    "plot_run",
    "plot_bode",
    "plot_friction",
    "plot_timeseries",
    "to_jsonable",
    "write_summary",
]

# Above this many samples a time-series trace is reduced to a min/max envelope
# (peaks survive, the PNG renders in well under a second for hour-long runs).
_MAX_PLOT_POINTS = 20_000


# --------------------------------------------------------------------------- JSON


def write_summary(path: str | os.PathLike, summary: Mapping[str, Any]) -> Path:
    """Write ``summary`` as ``summary.json`` (:func:`hilident.serialise.write_json`, kept here by name)."""
    return write_json(path, summary)


# --------------------------------------------------------------------------- validation


def _vector(value: Any, name: str, *, dtype=float) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name}: expected a 1-D numeric array ({exc})") from None
    if arr.ndim != 1:
        raise DataError(f"{name}: expected a 1-D array, got shape {arr.shape}")
    if arr.size == 0:
        raise DataError(f"{name}: array is empty")
    return arr


def _same_length(a: np.ndarray, a_name: str, b: np.ndarray, b_name: str) -> None:
    if a.shape != b.shape:
        raise DataError(f"{b_name} has {b.size} values but {a_name} has {a.size}; lengths must match")


def _save(fig, path: str | os.PathLike) -> Path:
    path = Path(path)
    atomic_write(path, lambda fh: fig.savefig(fh, format="png"))
    return path


# --------------------------------------------------------------------------- Bode


def _unwrapped_phase_deg(h: np.ndarray) -> np.ndarray:
    """Unwrapped phase, shifted by whole turns so it starts in (-315, 45] deg.

    Curves of the same plant (before/after a notch) then start on the same
    branch instead of 360 deg apart when their first bin sits near +-180 deg.
    """
    phase = np.degrees(np.unwrap(np.angle(h)))
    return phase - 360.0 * np.ceil((phase[0] - 45.0) / 360.0)


def _positive_curve(frequency_hz, response, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A checked ``(frequency_hz, complex response)`` pair without its non-positive frequencies (log axis)."""
    f = _vector(frequency_hz, f"{name} frequency_hz")
    h = _vector(response, f"{name} response", dtype=complex)
    _same_length(f, f"{name} frequency_hz", h, f"{name} response")
    keep = f > 0
    return f[keep], h[keep]


def _phase_near(f: np.ndarray, phase_deg: np.ndarray, reference: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """``phase_deg`` moved bin by bin by whole turns to within 180 deg of a reference curve.

    A notch's near-zero makes ``unwrap`` pick a branch at random; measured
    before/after curves of one plant are compared on the same branch.
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


def _magnitude_limits_db(mag_db: np.ndarray) -> tuple[float, float]:
    """Y limits that show the curves but not a notch's one-bin dive to -300 dB."""
    finite = mag_db[np.isfinite(mag_db)]
    if finite.size == 0:
        return -1.0, 1.0
    top = float(finite.max())
    bottom = max(float(finite.min()), float(np.percentile(finite, 0.5)) - 20.0)
    span = max(top - bottom, 1.0)
    return bottom - 0.05 * span, top + 0.05 * span


def plot_bode(
    path: str | os.PathLike,
    responses: Sequence[tuple[str, Any]],
    resonances: Iterable[Any] = (),
    notch_response: tuple[Any, Any] | None = None,
    coherence_threshold: float | None = None,
    model: tuple[str, Any, Any] | None = None,
    bounds_db: tuple[Any, Any] | None = None,
) -> Path:
    """Bode plot (magnitude, phase, coherence) of one or more measured responses.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    responses : sequence of (label, frf)
        ``frf`` has attributes ``frequency_hz`` (1-D, Hz), ``response`` (complex
        1-D, same length) and ``coherence`` (1-D in 0..1, same length, or
        ``None``). Labels go into the legend, e.g. ``"before notch"``.
        Non-positive frequencies (the DC bin) are not drawn on the log axis.
    resonances : iterable
        Objects with a ``frequency_hz`` attribute; each gets a dotted vertical
        marker on all three axes and its frequency written at the top.
    notch_response : (frequency_hz, response), optional
        Magnitude of the designed notch chain, drawn dashed on the magnitude axis.
    coherence_threshold : float, optional
        Drawn as a horizontal line on the coherence axis (e.g. 0.8).
    model : (label, frequency_hz, response), optional
        A fitted model's complex response, drawn thin and black on magnitude and phase.
    bounds_db : (lower_db, upper_db), optional
        Confidence band of the first response relative to itself (dB, one value
        per bin of that response), shaded around its magnitude.

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        If there is no response, lengths of one response's arrays differ, or a
        response has no positive frequency.
    """
    from matplotlib.figure import Figure

    curves = _bode_curves(responses)
    notch = None if notch_response is None else _positive_curve(*notch_response, "notch_response")

    fig = Figure(figsize=(8.0, 9.0), dpi=110, layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    ax_mag, ax_phase, ax_coh = axes
    with np.errstate(divide="ignore", invalid="ignore"):
        magnitudes_db = _draw_responses(axes, curves, responses, bounds_db)
        if notch is not None and notch[0].size:
            mag_db = 20 * np.log10(np.abs(notch[1]))
            magnitudes_db.append(mag_db)
            ax_mag.semilogx(notch[0], mag_db, "k--", lw=1.2, label="notch chain")
        if model is not None:
            m_label = model[0]
            mf, mh = _positive_curve(model[1], model[2], "model")
            ax_mag.semilogx(mf, 20 * np.log10(np.abs(mh)), color="k", lw=0.8, label=m_label)
            ax_phase.semilogx(mf, _unwrapped_phase_deg(mh), color="k", lw=0.8, label=m_label)
    ax_mag.set_ylim(*_magnitude_limits_db(np.concatenate(magnitudes_db)))

    has_coherence = any(c[3] is not None for c in curves)
    if coherence_threshold is not None:
        ax_coh.axhline(float(coherence_threshold), color="0.3", ls="--", lw=1.0,
                       label=f"threshold {float(coherence_threshold):g}")
    if not has_coherence:
        ax_coh.text(0.5, 0.5, "no coherence", transform=ax_coh.transAxes, ha="center", va="center", color="0.4")
    _mark_resonances(axes, resonances)
    _bode_axes(axes)
    ax_mag.legend(loc="best", fontsize=8)
    if coherence_threshold is not None or has_coherence:
        ax_coh.legend(loc="lower left", fontsize=8)
    return _save(fig, path)


def _bode_curves(responses: Sequence[tuple[str, Any]]) -> list[tuple[str, np.ndarray, np.ndarray, Any]]:
    """``(label, f, h, coherence or None)`` of each response, checked, at positive frequencies only."""
    if len(responses) == 0:
        raise DataError("plot_bode: responses is empty; pass at least one (label, frf)")
    curves = []
    for label, frf in responses:
        f = _vector(getattr(frf, "frequency_hz", None), f"responses[{label!r}].frequency_hz")
        h = _vector(getattr(frf, "response", None), f"responses[{label!r}].response", dtype=complex)
        _same_length(f, f"responses[{label!r}].frequency_hz", h, f"responses[{label!r}].response")
        coh_raw = getattr(frf, "coherence", None)
        coh = None
        if coh_raw is not None:
            coh = _vector(coh_raw, f"responses[{label!r}].coherence")
            _same_length(f, f"responses[{label!r}].frequency_hz", coh, f"responses[{label!r}].coherence")
        keep = f > 0
        if not np.any(keep):
            raise DataError(f"responses[{label!r}].frequency_hz: no positive frequency to plot")
        curves.append((str(label), f[keep], h[keep], None if coh is None else coh[keep]))
    return curves


def _draw_responses(axes, curves: list, responses: Sequence[tuple[str, Any]], bounds_db) -> list[np.ndarray]:
    """Magnitude, phase (near the first curve's) and coherence of every curve; their magnitudes, dB."""
    ax_mag, ax_phase, ax_coh = axes
    magnitudes_db = []
    reference_phase = None
    for i, (label, f, h, coh) in enumerate(curves):
        mag_db = 20 * np.log10(np.abs(h))
        magnitudes_db.append(mag_db)
        line = ax_mag.semilogx(f, mag_db, label=label)[0]
        if i == 0 and bounds_db is not None:
            _confidence_band(ax_mag, f, mag_db, responses[0][1], bounds_db, line.get_color())
        phase = _phase_near(f, _unwrapped_phase_deg(h), reference_phase)
        if reference_phase is None:
            reference_phase = (f, phase)
        ax_phase.semilogx(f, phase, color=line.get_color(), label=label)
        if coh is not None:
            ax_coh.semilogx(f, coh, color=line.get_color(), label=label)
    return magnitudes_db


def _confidence_band(ax_mag, f: np.ndarray, mag_db: np.ndarray, frf, bounds_db, color) -> None:
    """The first response's 95 % band (``bounds_db``, dB relative to it, one value per bin), shaded."""
    f_all = _vector(frf.frequency_hz, "responses[0].frequency_hz")
    lo = _vector(bounds_db[0], "bounds_db lower")
    hi = _vector(bounds_db[1], "bounds_db upper")
    _same_length(f_all, "responses[0].frequency_hz", lo, "bounds_db lower")
    _same_length(f_all, "responses[0].frequency_hz", hi, "bounds_db upper")
    k = f_all > 0
    lo_db = np.maximum(mag_db + lo[k], mag_db - 40.0)  # a bin with no coherence: cap the band
    ax_mag.fill_between(f, lo_db, mag_db + hi[k], color=color, alpha=0.25, lw=0, label="95 % confidence")


def _mark_resonances(axes, resonances: Iterable[Any]) -> None:
    """A dotted red line at each resonance on every axis, its frequency written at the top."""
    ax_mag = axes[0]
    for i, res in enumerate(resonances):
        f_res = float(res.frequency_hz)
        for ax in axes:
            ax.axvline(f_res, color="tab:red", ls=":", lw=1.0, label="resonance" if (i == 0 and ax is ax_mag) else None)
        ax_mag.annotate(f"{f_res:.4g} Hz", xy=(f_res, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(3, -3), textcoords="offset points", ha="left", va="top",
                        fontsize=8, color="tab:red")


def _bode_axes(axes) -> None:
    """Labels, limits, grid and 1-2-5 frequency ticks of the three axes."""
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    ax_mag, ax_phase, ax_coh = axes
    ax_mag.set_ylabel("magnitude [dB]")
    ax_phase.set_ylabel("phase [deg]")
    ax_coh.set_ylabel("coherence [-]")
    ax_coh.set_ylim(0.0, 1.05)
    ax_coh.set_xlabel("frequency [Hz]")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        # plain numbers at 1-2-5 steps read better than 10^x labels crowding each other
        ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())


# --------------------------------------------------------------------------- friction


def plot_friction(
    path: str | os.PathLike,
    velocity_mps: Any,
    torque_nm: Any,
    fit_velocity_mps: Any = None,
    fit_torque_nm: Any = None,
    label: str = "",
) -> Path:
    """Friction torque against velocity: measured steady-state points and the fit.

    Measured points are drawn as markers, the fitted curve as a line. The fit
    is split at zero velocity into its negative and positive branch, so the
    Coulomb/stiction step at ``v = 0`` is not bridged by a sloped segment.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    velocity_mps, torque_nm : array_like
        Steady-state points, m/s and N·m, same length.
    fit_velocity_mps, fit_torque_nm : array_like, optional
        The fitted model evaluated on a grid (give both or neither), normally
        over both velocity signs.
    label : str
        Title, e.g. the axis name.

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        On empty or mismatched arrays, or only one of the fit arrays.
    """
    from matplotlib.figure import Figure

    v = _vector(velocity_mps, "velocity_mps")
    tau = _vector(torque_nm, "torque_nm")
    _same_length(v, "velocity_mps", tau, "torque_nm")
    if (fit_velocity_mps is None) != (fit_torque_nm is None):
        raise DataError("plot_friction: give both fit_velocity_mps and fit_torque_nm, or neither")
    fit = None
    if fit_velocity_mps is not None:
        fv = _vector(fit_velocity_mps, "fit_velocity_mps")
        ft = _vector(fit_torque_nm, "fit_torque_nm")
        _same_length(fv, "fit_velocity_mps", ft, "fit_torque_nm")
        order = np.argsort(fv, kind="stable")
        fit = (fv[order], ft[order])

    fig = Figure(figsize=(7.0, 4.5), dpi=110, layout="constrained")
    ax = fig.subplots()
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.plot(v, tau, "o", ms=4, color="tab:blue", label="measured")
    if fit is not None:
        fv, ft = fit
        first = True
        for branch in (fv < 0, fv > 0):
            if np.any(branch):
                ax.plot(fv[branch], ft[branch], "-", color="tab:orange", lw=1.6, label="fit" if first else None)
                first = False
    ax.set_xlabel("velocity [m/s]")
    ax.set_ylabel("torque [N·m]")
    if label:
        ax.set_title(label)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


# --------------------------------------------------------------------------- time series


def _minmax_envelope(t: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Reduce a long trace to min and max per bucket, keeping every peak visible."""
    n_buckets = max(1, max_points // 2)
    starts = np.linspace(0, t.size, n_buckets + 1, dtype=np.int64)[:-1]
    starts = np.unique(starts)
    lo = np.fmin.reduceat(y, starts)  # fmin/fmax skip NaN unless a whole bucket is NaN
    hi = np.fmax.reduceat(y, starts)
    tb = t[starts]
    return np.repeat(tb, 2), np.column_stack([lo, hi]).ravel()


def _event_time_and_label(event: Any) -> tuple[float, str]:
    if isinstance(event, Mapping):
        return float(event["time_s"]), str(event.get("kind", ""))
    if hasattr(event, "time_s"):
        return float(event.time_s), str(getattr(event, "kind", ""))
    return float(event), ""


def plot_timeseries(
    path: str | os.PathLike,
    time_s: Any,
    channels: Mapping[str, Any],
    units: Mapping[str, str],
    events: Iterable[Any] = (),
) -> Path:
    """One stacked axis per channel against time, with event markers.

    Traces longer than 20 000 points are drawn as a min/max envelope, so
    peaks stay visible and hour-long recordings plot quickly.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    time_s : array_like
        Time of each sample, s.
    channels : mapping of str to array_like
        Channel name to samples, each the length of ``time_s``.
    units : mapping of str to str
        Channel name to unit for the axis label; a missing unit leaves it off.
    events : iterable
        Events as returned in :attr:`hilident.recording.RunData.events` (dicts
        with ``time_s`` and ``kind``), objects with a ``time_s`` attribute, or
        plain times in s. Each becomes a vertical line on every axis.

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        If there is no channel or a channel's length differs from ``time_s``.
    """
    from matplotlib.figure import Figure

    t = _vector(time_s, "time_s")
    if len(channels) == 0:
        raise DataError("plot_timeseries: channels is empty; pass at least one channel")
    traces = []
    for name, values in channels.items():
        y = _vector(values, f"channels[{name!r}]")
        _same_length(t, "time_s", y, f"channels[{name!r}]")
        if t.size > _MAX_PLOT_POINTS:
            traces.append((name, *_minmax_envelope(t, y, _MAX_PLOT_POINTS)))
        else:
            traces.append((name, t, y))
    marks = [_event_time_and_label(e) for e in events]

    fig = Figure(figsize=(9.0, 1.2 + 1.8 * len(traces)), dpi=100, layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(traces), 1, sharex=True, squeeze=False)[:, 0])
    for ax, (name, tt, yy) in zip(axes, traces, strict=False):
        ax.plot(tt, yy, lw=0.8)
        unit = units.get(name, "")
        ax.set_ylabel(f"{name} [{unit}]" if unit else name)
        ax.grid(True, alpha=0.3)
        for t_ev, _ in marks:
            ax.axvline(t_ev, color="tab:red", lw=0.8, ls="--", alpha=0.8)
    for t_ev, kind in marks:
        if kind:
            axes[0].annotate(kind, xy=(t_ev, 1.0), xycoords=("data", "axes fraction"), xytext=(2, -2),
                             textcoords="offset points", ha="left", va="top", fontsize=7,
                             color="tab:red", rotation=90)
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


# --------------------------------------------------------------------------- a run's plots


def plot_run(out: str | os.PathLike, friction, plant, designs: list, loop_after=None,
             coherence_threshold: float | None = None) -> None:
    """``friction.png`` (with a friction test) and ``bode.png`` of a run into the folder ``out``.

    ``friction`` is the friction test's result (or None), ``plant`` the
    identification's, ``designs`` the notch designs, ``loop_after`` the
    verification run's response (None without one).
    """
    from hilident import pipeline

    out = Path(out)
    if friction is not None:
        from hilident.ident.friction import stribeck

        pts = friction.points
        vmax = float(np.max(np.abs(pts.v_mean)))
        v = np.linspace(-vmax, vmax, 801)
        plot_friction(out / "friction.png", pts.v_mean, pts.tau_mean, v, stribeck(v, friction.fit.params),
                      label=friction.model)
    responses = [("plant (net torque to output)", plant.plant), ("excitation to output, before notch", plant.loop)]
    if loop_after is not None:
        responses.append(("excitation to output, after notch", loop_after))
    notch = pipeline.notch_chain_response(designs, plant.plant.frequency_hz)
    plot_bode(out / "bode.png", responses, resonances=plant.resonances, notch_response=notch,
              coherence_threshold=coherence_threshold, **pipeline.bode_extras(plant))
