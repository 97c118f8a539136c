"""The figures of a run and of ``identify``, drawn as a set.

Pure output helpers: arrays in, files out. The figures themselves live in
:mod:`hilident.plots` (Bode, friction, grey-box); this module draws a run's
and an identification's set (:func:`plot_run`, :func:`plot_identify`). Plots are drawn with matplotlib's
object API (:class:`matplotlib.figure.Figure`, rendered by Agg), so nothing
here touches pyplot's global state or the process-wide backend, and
matplotlib is only imported when a plot is drawn.

Every writer creates the parent folder if needed and writes atomically (a
temporary file in the same folder, then :func:`os.replace`), so a reader never
sees half a PNG. JSON is :mod:`hilident.io.serialise`'s job.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.plots.bode import PER_CURVE, plot_bode
from hilident.plots.common import channel_unit, config_name, plot_title, ratio_unit
from hilident.plots.common import same_length as _same_length
from hilident.plots.common import save as _save
from hilident.plots.common import vector as _vector
from hilident.plots.friction import plot_friction
from hilident.plots.greybox import Simulation, plot_greybox, simulate_greybox

__all__ = ["plot_run", "plot_identify", "plot_model", "plot_timeseries"]

# Above this many samples a time-series trace is reduced to a min/max envelope
# (peaks survive, the PNG renders in well under a second for hour-long runs).
_MAX_PLOT_POINTS = 20_000


# --------------------------------------------------------------------------- JSON


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
        Events as returned in :attr:`hilident.io.recording.RunData.events` (dicts
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
            axes[0].annotate(
                kind,
                xy=(t_ev, 1.0),
                xycoords=("data", "axes fraction"),
                xytext=(2, -2),
                textcoords="offset points",
                ha="left",
                va="top",
                fontsize=7,
                color="tab:red",
                rotation=90,
            )
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


# --------------------------------------------------------------------------- a run's plots

#: Points of the fine grid the notch curves are drawn on: log-spaced over the view, dense around each notch.
_FINE_POINTS = 3000
_NOTCH_POINTS = 801


def model_label(model) -> str:
    """What a fitted plant model is: ``"fitted TF, 3 zeros / 4 poles (1 integrator), MDL"``."""
    fit = model.fit
    poles = fit.n_den + fit.integrators
    integ = f" ({fit.integrators} integrator{'s' if fit.integrators != 1 else ''})" if fit.integrators else ""
    return (
        f"fitted TF, {fit.n_num} zero{'s' if fit.n_num != 1 else ''} / {poles} pole{'s' if poles != 1 else ''}"
        f"{integ}, {str(model.criterion).upper()}"
    )


def _fine_grid(f: np.ndarray, band_hz: tuple[float, float] | None, designs: list) -> np.ndarray:
    """Frequencies for the notch curves, Hz: the view of the Bode plot, and +-3 widths around every notch."""
    f = f[f > 0]
    lo, hi = (float(f.min()), float(f.max())) if f.size else (1.0, 1000.0)
    if band_hz is not None:
        lo, hi = max(lo, band_hz[0] / 2.0), min(hi, band_hz[1] * 2.0)
    parts = [np.geomspace(max(lo, 1e-6), max(hi, 2 * lo), _FINE_POINTS)]
    for d in designs:
        c, w = d.spec.center_hz, d.spec.width_hz
        parts.append(np.linspace(max(c - 3 * w, 1e-6), c + 3 * w, _NOTCH_POINTS))
    return np.unique(np.concatenate(parts))


def stored_notch_response(summary: Mapping[str, Any] | None, frequency_hz) -> tuple[np.ndarray, np.ndarray] | None:
    """The chain the device stores, from ``summary["upload"]["slots"]`` read back, at ``frequency_hz``.

    The rate of each slot is its design's (``notch_filters[].sample_rate_hz``,
    same ``slot``). None when nothing was read back.
    """
    if not summary:
        return None
    from hilident.plots.notches import records_chain

    rates = {n.get("slot"): n.get("sample_rate_hz") for n in summary.get("notch_filters") or []}
    f = np.asarray(frequency_hz, dtype=float)
    h = records_chain((summary.get("upload") or {}).get("slots") or [], "readback_b", "readback_a", rates, f)
    return (f, h) if h is not None else None


def _bode_args(plant, designs: list, summary, band_hz, coherence_threshold) -> dict:
    """The keyword arguments of :func:`plot_bode` shared by a run and ``identify``."""
    from hilident.pipeline.plant import bode_extras
    from hilident.pipeline.records import notch_chain_response

    fine = _fine_grid(plant.plant.frequency_hz, band_hz, designs)
    extras = bode_extras(plant)
    if "model" in extras and plant.model is not None:
        extras["model"] = (model_label(plant.model), *extras["model"][1:])
    stored = stored_notch_response(summary, fine)
    uploaded = bool(((summary or {}).get("upload") or {}).get("slots"))
    return dict(
        resonances=plant.resonances,
        notch_response=notch_chain_response(designs, fine),
        coherence_threshold=coherence_threshold,
        band_hz=band_hz,
        stored_notch=stored,
        notch_label="designed notch [dB re 1]" + ("" if uploaded or not designs else ", not uploaded"),
        **extras,
    )


def _friction_png(path: Path, friction, title: str) -> None:
    from hilident.ident.friction import stribeck

    pts = friction.points
    vmax = float(np.max(np.abs(pts.v_mean)))
    v = np.linspace(-vmax, vmax, 801)
    p = friction.fit.params
    params = {n: getattr(p, n) for n in ("Fc", "Fs", "Fv", "vs", "delta_v", "delta_s")}
    plot_friction(
        path,
        pts.v_mean,
        pts.tau_mean,
        v,
        stribeck(v, p),
        label=title,
        structure=friction.fit.structure or friction.model,
        params=params,
        stderr=friction.fit.stderr,
    )


def plot_run(
    out: str | os.PathLike,
    friction,
    plant,
    designs: list,
    loop_after=None,
    coherence_threshold: float | None = None,
    *,
    summary: Mapping[str, Any] | None = None,
    band_hz: tuple[float, float] | None = None,
    output: str | None = None,
) -> None:
    """``friction.png`` (with a friction test) and ``bode.png`` of a run into the folder ``out``.

    Parameters
    ----------
    out : path-like
        The run's folder.
    friction, plant, designs, loop_after
        The friction test's result (or None), the identification's
        :class:`~hilident.pipeline.plant.PlantResult`, the notch designs, the
        verification run's response (None without one).
    coherence_threshold : float, optional
    summary : mapping, optional
        The run's ``summary.json``: its ``config`` names the plots, its
        ``excitation.unit`` gives the loop's input unit, its
        ``upload.slots`` (read back) the stored notch.
    band_hz : (float, float), optional
        The analysis band, Hz.
    output : str, optional
        The output channel (``velocity_mps``): its unit is the responses' numerator.
    """
    out = Path(out)
    summary = summary or {}
    config = config_name(summary.get("config"))
    if friction is not None:
        _friction_png(out / "friction.png", friction, plot_title(config))
    out_unit = channel_unit(output)
    plant_unit = ratio_unit(out_unit, "N*m")
    loop_unit = ratio_unit(out_unit, (summary.get("excitation") or {}).get("unit"))
    same = plant_unit == loop_unit or not loop_unit
    responses = [
        ("plant (net torque to output)" + ("" if same else f" [{plant_unit}]"), plant.plant),
        ("excitation to output, before notch" + ("" if same else f" [{loop_unit}]"), plant.loop),
    ]
    if loop_after is not None:
        responses.append(("excitation to output, after notch" + ("" if same else f" [{loop_unit}]"), loop_after))
    unit = plant_unit if same else PER_CURVE
    plot_bode(
        out / "bode.png",
        responses,
        title=plot_title(config, what="Bode"),
        magnitude_unit=unit or None,
        **_bode_args(plant, designs, summary, band_hz, coherence_threshold),
    )


# --------------------------------------------------------------------------- identify's plots


def greybox_records(
    holdout: float, estimation: tuple[Any, Any], validation: Mapping[str, tuple[Any, Any]] | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``(torque, position)`` of the records a grey-box fit was estimated and validated on, by name.

    As :func:`hilident.pipeline.greybox.fit_greybox` splits them: the validation
    records by their names when there are any; without, the last
    ``holdout`` of the estimation data (``"holdout"``).
    """
    torque, position = (np.asarray(x, dtype=float) for x in estimation)
    others = {
        name: (np.asarray(t, dtype=float), np.asarray(q, dtype=float)) for name, (t, q) in (validation or {}).items()
    }
    if others:
        return {"estimation data": (torque, position), **others}
    if holdout > 0:
        cut = int(round(len(torque) * (1.0 - holdout)))
        return {"estimation data": (torque[:cut], position[:cut]), "holdout": (torque[cut:], position[cut:])}
    return {"estimation data": (torque, position)}


def plot_model(
    path: str | os.PathLike,
    model_cfg,
    result,
    records: Mapping[str, tuple[Any, Any]],
    sample_rate_hz: float,
    title: str | None = None,
) -> Path:
    """``model.png``: the grey-box ``result`` simulated against each record, with its residual tests.

    ``records`` are ``(torque N·m, position m)`` by name (:func:`greybox_records`);
    the force is ``model_cfg.c`` times the torque, the residuals are those of
    the fitted equation on each record's regression.
    """
    from hilident.pipeline.greybox import greybox_regression

    cutoff = model_cfg.cutoff_hz or sample_rate_hz / 10.0
    sims: dict[str, Simulation | str] = {}
    residuals: dict[str, tuple[Any, Any]] = {}
    fits: dict[str, float] = {}
    for name, (torque, position) in records.items():
        try:
            sims[name] = simulate_greybox(
                model_cfg.kind,
                result.fit.params,
                model_cfg.c * np.asarray(torque, dtype=float),
                position,
                sample_rate_hz,
                cutoff,
            )
        except DataError as exc:  # the figure says why, the command goes on
            sims[name] = f"no simulation: {exc}"
        try:
            reg = greybox_regression(model_cfg, torque, position, sample_rate_hz)
        except DataError:
            continue
        residuals[name] = (
            np.asarray(reg.target) - result.fit.predict(reg.regressors),
            reg.regressors[result.fit.names[0]],
        )
        check = result.estimation if name == "estimation data" else result.validation.get(name, {})
        if check.get("fit_percent") is not None:
            fits[name] = check["fit_percent"]
    return plot_greybox(path, model_cfg.kind, result.fit, sims, residuals, title=title, regression_fit_percent=fits)


def plot_identify(
    out: str | os.PathLike,
    summary: Mapping[str, Any],
    plant,
    designs: list,
    *,
    band_hz: tuple[float, float] | None = None,
    coherence_threshold: float | None = None,
    friction=None,
    model=None,
    model_cfg=None,
    data=None,
    validation=None,
) -> list[Path]:
    """``bode.png``, and ``friction.png`` and ``model.png`` when there is one, of ``hilident identify``.

    Parameters
    ----------
    out : path-like
        The output folder.
    summary : mapping
        ``identify``'s ``summary.json``: ``config``, ``data.file``,
        ``data.units`` and ``data.mapping`` (units of the responses).
    plant, designs
        The :class:`~hilident.pipeline.plant.PlantResult` and the notch designs.
    band_hz, coherence_threshold
        The analysis band (Hz) and the coherence threshold.
    friction : FrictionResult, optional
    model : GreyBoxResult, optional
        With ``model_cfg`` (``[model]``) and ``data`` (the dataset it was
        fitted to, ``validation`` the other record): ``model.png``.

    Returns
    -------
    list of pathlib.Path
        The PNGs written.
    """
    out = Path(out)
    info = summary.get("data") or {}
    source = Path(str(info.get("file") or "recording")).name
    config = str(summary.get("config") or "")
    # a hilident recording's own configuration is named after the recording
    name = source if not config or config.startswith(str(info.get("file"))) else f"{source} ({config_name(config)})"
    title = plot_title(f"identify {name}")
    units, mapping = info.get("units") or {}, info.get("mapping") or {}

    def unit_of(key: str) -> str:
        return units.get(key) or channel_unit(mapping.get(key))

    unit = ratio_unit(unit_of("output") or unit_of("velocity"), unit_of("torque") or unit_of("excitation"))
    written = [
        plot_bode(
            out / "bode.png",
            [("plant (input to output)", plant.plant)],
            title=title.replace("identify", "Bode: identify", 1),
            magnitude_unit=unit or None,
            **_bode_args(plant, designs, summary, band_hz, coherence_threshold),
        )
    ]
    if friction is not None:
        _friction_png(out / "friction.png", friction, title)
        written.append(out / "friction.png")
    if model is not None and model_cfg is not None and data is not None:
        others = (
            None
            if validation is None
            else {Path(validation.source).name: (validation.signals["torque"], validation.signals["position"])}
        )
        records = greybox_records(model_cfg.holdout, (data.signals["torque"], data.signals["position"]), others)
        written.append(plot_model(out / "model.png", model_cfg, model, records, data.sample_rate_hz, title))
    return written
