"""A grey-box model against the measurement: simulated output (as SITB's ``compare``) and residual tests (``resid``).

The grey-box fit (:mod:`hilident.ident.greybox`) is an equation-error fit of
the inverse dynamics (force from the filtered position and its
derivatives). Its figure here is the forward simulation a person checks a
model with: the measured force drives the model and its output is laid on
the measured one, fit % (NRMSE, as ``compare``) in the legend:

* ``mass_spring_damper`` (``m``, ``b``, ``k``): the position, m; the two
  initial states are estimated by least squares, as ``compare`` does;
* ``rigid_axis`` (``M``, ``Fv``, ``Fc``, ``offset`` or the per-direction
  ``Fv+``, ``Fv-``, ``Fc+``, ``Fc-``): the velocity, m/s (its position is a
  free integrator: any force bias makes it drift), force and measured
  velocity through the fit's low-pass alike.

Beside each record, the residuals of the fitted equation: their
autocorrelation and their cross-correlation with the first regressor (the
tests ``summary.json`` reports as ``residuals_white`` and
``independent_of_input``), with the 99 % band.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.plots.common import save, vector

__all__ = ["Simulation", "simulate_greybox", "greybox_figure", "plot_greybox"]

#: Longest stretch simulated and drawn per record, samples (a rigid axis is stepped in Python).
MAX_SIMULATED = 200_000


@dataclass(frozen=True)
class Simulation:
    """A grey-box model's simulated output next to the measured one.

    Attributes
    ----------
    time_s : ndarray
        Time of each sample from the record's start, s.
    measured, simulated : ndarray
        The output (``name`` in ``unit``).
    name, unit : str
        ``"position"``, ``"m"`` or ``"velocity"``, ``"m/s"``.
    fit_percent : float
        NRMSE fit of the simulation, % (100: perfect).
    note : str
        What was left out (filter settling, a cut to :data:`MAX_SIMULATED`).
    """

    time_s: np.ndarray
    measured: np.ndarray
    simulated: np.ndarray
    name: str
    unit: str
    fit_percent: float
    note: str = ""


def simulate_greybox(
    kind: str, params: Mapping[str, float], force_n: Any, position_m: Any, sample_rate_hz: float, cutoff_hz: float
) -> Simulation:
    """Simulate a fitted grey-box model from the measured force and compare it with the measured output.

    Parameters
    ----------
    kind : {"mass_spring_damper", "rigid_axis"}
    params : mapping
        The fit's parameters (SI: kg, N·s/m, N/m, N).
    force_n, position_m : array_like
        Measured force, N (``c`` times the torque), and position, m.
    sample_rate_hz : float
    cutoff_hz : float
        The fit's state-variable-filter corner, Hz (rigid axis: the velocity
        is the filter's derivative).

    Raises
    ------
    DataError
        An unknown kind, a parameter missing, too few samples.
    """
    from hilident.ident.validation import fit_percent

    u = vector(force_n, "force")
    y = vector(position_m, "position")
    if u.shape != y.shape:
        raise DataError(f"force has {u.size} samples but position has {y.size}")
    note = ""
    if u.size > MAX_SIMULATED:
        note = f"first {MAX_SIMULATED} of {u.size} samples"
        u, y = u[:MAX_SIMULATED], y[:MAX_SIMULATED]
    fs = float(sample_rate_hz)
    try:
        if kind == "mass_spring_damper":
            measured, simulated, skip = y, _simulate_msd(params, u, y, fs), 0
            name, unit = "position", "m"
        elif kind == "rigid_axis":
            measured, simulated, skip = _simulate_rigid(params, u, y, fs, cutoff_hz)
            name, unit = "velocity", "m/s"
            note = "; ".join(n for n in (note, f"first {skip} samples: filter settling") if n)
        else:
            raise DataError(f"no simulation for a grey-box model of kind {kind!r}")
    except KeyError as exc:
        raise DataError(f"{kind}: parameter {exc} missing from the fit") from None
    t = np.arange(skip, skip + measured.size) / fs
    with np.errstate(all="ignore"):
        fit = float(fit_percent(measured, simulated)) if np.all(np.isfinite(simulated)) else float("-inf")
    return Simulation(t, measured, simulated, name, unit, fit, note)


def _simulate_msd(params: Mapping[str, float], u: np.ndarray, y: np.ndarray, fs: float) -> np.ndarray:
    """Position of ``m y'' + b y' + k y = F`` (ZOH), initial state by least squares on the measured position."""
    from scipy import signal

    m, b, k = float(params["m"]), float(params["b"]), float(params["k"])
    bd, ad, _ = signal.cont2discrete(([1.0], [m, b, k]), 1.0 / fs, method="zoh")
    bd = np.atleast_1d(np.squeeze(bd))
    forced = signal.lfilter(bd, ad, u)
    zeros = np.zeros_like(u)
    order = len(ad) - 1
    basis = np.column_stack([signal.lfilter(bd, ad, zeros, zi=np.eye(order)[i])[0] for i in range(order)])
    with np.errstate(all="ignore"):
        x0, *_ = np.linalg.lstsq(basis, y - forced, rcond=None)
    return forced + basis @ x0


def _simulate_rigid(
    params: Mapping[str, float], u: np.ndarray, q: np.ndarray, fs: float, cutoff_hz: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Velocity of ``M v' = F - friction(v) - offset`` stepped from the measured start, and the measured velocity."""
    from hilident.ident.derivatives import settling_samples, state_variable_filter

    Q = state_variable_filter(q, fs, cutoff_hz, 1, order=3)  # the fit's filter (order 3, zero phase)
    F = state_variable_filter(u, fs, cutoff_hz, 0, order=3)[0]
    edge = settling_samples(fs, cutoff_hz, 3)
    if q.size <= 2 * edge + 2:
        raise DataError(f"{q.size} samples are too few to simulate after {edge} samples of filter settling")
    v_meas, force = Q[1][edge:], F[edge:]
    M = float(params["M"])
    if "Fv" in params:
        fv_pos = fv_neg = float(params["Fv"])
        fc_pos = fc_neg = float(params["Fc"])
        offset = float(params.get("offset", 0.0))
    else:
        fv_pos, fv_neg = float(params["Fv+"]), float(params["Fv-"])
        fc_pos, fc_neg = float(params["Fc+"]), float(params["Fc-"])
        offset = 0.0
    h = 1.0 / fs
    steps = int(np.clip(np.ceil(abs(h * max(fv_pos, fv_neg) / M) / 0.2), 1, 50)) if M > 0 else 1
    dt = h / steps
    sim = np.empty_like(v_meas)
    v = float(v_meas[0])
    for i, f in enumerate(force.tolist()):
        sim[i] = v
        for _ in range(steps):
            fr = (fv_pos * v + fc_pos) if v > 0 else (fv_neg * v - fc_neg) if v < 0 else 0.0
            v += dt * (f - fr - offset) / M
        if not np.isfinite(v) or abs(v) > 1e6:
            sim[i + 1 :] = np.nan
            break
    return v_meas, sim, edge


def greybox_figure(
    kind: str,
    fit: Any,
    simulations: Mapping[str, Simulation | str],
    residuals: Mapping[str, tuple[Any, Any]],
    *,
    title: str | None = None,
    regression_fit_percent: Mapping[str, float] | None = None,
    max_lag: int = 25,
):
    """The figure of :func:`plot_greybox`, not saved.

    One row per record: simulated against measured, the residuals'
    autocorrelation and their cross-correlation with the first regressor
    (``residuals[name] = (residual, regressor)``, in the fit's target unit, N).
    A simulation given as a string (why there is none) is written in its place.
    """
    from matplotlib.figure import Figure

    from hilident.ident.validation import residual_analysis

    names = list(simulations)
    if not names:
        raise DataError("plot_greybox: no record to compare the model with")
    fig = Figure(figsize=(13.0, 1.0 + 3.0 * len(names)), dpi=100, layout="constrained")
    grid = fig.subplots(len(names), 3, squeeze=False, gridspec_kw={"width_ratios": [3.0, 1.2, 1.6]})
    params = ", ".join(f"{n} = {v:.4g}" for n, v in fit.params.items())
    for row, name in zip(grid, names, strict=True):
        sim = simulations[name]
        ax, ax_auto, ax_cross = row
        if isinstance(sim, str):
            ax.text(0.5, 0.5, sim, transform=ax.transAxes, ha="center", va="center", color="0.3", wrap=True)
            ax.set_title(name, fontsize=9)
        else:
            _compare_axis(ax, kind, name, sim, regression_fit_percent)
        e, regressor = residuals.get(name, (None, None))
        if e is None:
            for a in (ax_auto, ax_cross):
                a.text(0.5, 0.5, "no residuals", transform=a.transAxes, ha="center", va="center", color="0.4")
            continue
        e = vector(e, f"residuals[{name!r}]")
        lag = int(min(max_lag, max(1, e.size // 4 - 1)))
        try:
            ra = residual_analysis(e, regressor, max_lag=lag)
        except (DataError, ConfigError) as exc:
            ax_auto.text(
                0.5,
                0.5,
                f"no residual test:\n{exc}",
                transform=ax_auto.transAxes,
                ha="center",
                va="center",
                color="0.4",
                fontsize=8,
                wrap=True,
            )
            continue
        _correlation_axis(
            ax_auto,
            ra.lags,
            ra.autocorr,
            ra.bound,
            "autocorrelation of residuals",
            f"white: {'yes' if ra.white else 'no'}, Ljung-Box p = {ra.ljung_box_p:.2g}",
        )
        if ra.cross_lags.size:
            _correlation_axis(
                ax_cross,
                ra.cross_lags,
                ra.crosscorr,
                ra.bound,
                f"cross-corr. residual / {fit.names[0]} regressor",
                f"independent: {'yes' if ra.independent else 'no'}",
            )
    fig.suptitle(f"{title}\n{kind}: {params}" if title else f"{kind}: {params}", fontsize=10)
    return fig


def _compare_axis(ax, kind: str, name: str, sim: Simulation, regression_fit_percent) -> None:
    """Measured and simulated output of one record, the simulation's fit % in the legend."""
    stride = max(1, sim.time_s.size // 20_000)
    ax.plot(sim.time_s[::stride], sim.measured[::stride], color="0.35", lw=0.8, label="measured")
    ax.plot(
        sim.time_s[::stride],
        sim.simulated[::stride],
        color="tab:blue",
        lw=1.0,
        ls="--",
        label=f"simulated {kind} (fit {sim.fit_percent:.1f} %)",
    )
    ax.set_ylim(*_padded(sim.measured))
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{sim.name} [{sim.unit}]")
    extra = []
    if regression_fit_percent and name in regression_fit_percent:
        extra.append(f"equation fit {regression_fit_percent[name]:.1f} %")
    if sim.note:
        extra.append(sim.note)
    ax.set_title(f"{name}: simulated vs measured {sim.name}" + (f" ({'; '.join(extra)})" if extra else ""), fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)


def _padded(y: np.ndarray) -> tuple[float, float]:
    finite = y[np.isfinite(y)]
    if finite.size == 0:
        return -1.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    span = max(hi - lo, 1e-12)
    return lo - 0.15 * span, hi + 0.15 * span


def _correlation_axis(ax, lags: np.ndarray, values: np.ndarray, bound: float, what: str, verdict: str) -> None:
    """Stems of a normalised correlation, the 99 % band shaded, the verdict in the title."""
    inside = np.abs(values) < bound
    ax.vlines(lags, 0.0, values, color=np.where(inside, "tab:blue", "tab:red").tolist(), lw=1.2)
    ax.plot(lags, values, "o", ms=2.5, color="tab:blue")
    ax.axhspan(-bound, bound, color="tab:green", alpha=0.2, lw=0, label=f"99 % band (±{bound:.2g})")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_xlabel("lag [samples]")
    ax.set_ylabel("correlation [-]")
    ax.set_title(f"{what}\n{verdict}", fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=7, framealpha=0.9)


def plot_greybox(
    path: str | os.PathLike,
    kind: str,
    fit: Any,
    simulations: Mapping[str, Simulation | str],
    residuals: Mapping[str, tuple[Any, Any]],
    **kwargs: Any,
) -> Path:
    """The grey-box model against each record, written as PNG.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    kind : str
        ``[model].kind``.
    fit : LinearFit
        :class:`hilident.ident.greybox.LinearFit` (``params``, ``names``).
    simulations : mapping of str to Simulation
        :func:`simulate_greybox` of each record, by name (``"estimation data"``, ``"holdout"``, a file name).
    residuals : mapping of str to (residual, regressor)
        The equation's residual (target minus prediction, N) and the first
        regressor, per record, for the correlation tests.
    **kwargs
        ``title``, ``regression_fit_percent`` (name to the equation's fit %,
        as ``summary.json`` reports), ``max_lag``.

    Returns
    -------
    pathlib.Path
    """
    return save(greybox_figure(kind, fit, simulations, residuals, **kwargs), path)
