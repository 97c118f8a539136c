"""Friction plot: steady-state points, the fitted curve, and the model named with its parameters and units."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.plots.common import outside_legend, same_length, save, vector

__all__ = ["FRICTION_UNITS", "friction_figure", "plot_friction", "friction_title", "friction_parameter_lines"]

#: Unit of each friction parameter (:class:`hilident.ident.friction.StribeckParams`).
FRICTION_UNITS = {"Fc": "N·m", "Fs": "N·m", "Fv": "N·m/(m/s)", "vs": "m/s", "delta_v": "", "delta_s": ""}

#: The parameters each fitted structure has (the others are fixed by it).
_STRUCTURES = {
    "coulomb_viscous": ("Coulomb + viscous friction", ("Fc", "Fv")),
    "stribeck_fixed_exponents": ("Stribeck friction (delta_v = 1, delta_s = 2)", ("Fc", "Fs", "Fv", "vs")),
    "stribeck": ("Stribeck friction", ("Fc", "Fs", "Fv", "vs", "delta_v", "delta_s")),
}


def friction_title(structure: str) -> str:
    """``"stribeck"`` -> ``"Stribeck friction"``; an unknown name is shown as given."""
    return _STRUCTURES.get(structure, (f"{structure} friction", ()))[0]


def friction_parameter_lines(
    structure: str, params: Mapping[str, float], stderr: Mapping[str, float] | None = None
) -> list[str]:
    """One ``"Fv = 2.01 ± 0.03 N·m/(m/s)"`` line per parameter the structure fits (all given ones if unknown)."""
    names = _STRUCTURES.get(structure, ("", tuple(params)))[1]
    lines = []
    for name in names:
        if name not in params:
            continue
        unit = FRICTION_UNITS.get(name, "")
        se = (stderr or {}).get(name)
        pm = f" ± {se:.2g}" if se is not None and np.isfinite(se) and se > 0 else ""
        lines.append(f"{name} = {float(params[name]):.4g}{pm}{' ' + unit if unit else ''}")
    return lines


def friction_figure(
    velocity_mps: Any,
    torque_nm: Any,
    fit_velocity_mps: Any = None,
    fit_torque_nm: Any = None,
    label: str = "",
    *,
    structure: str | None = None,
    params: Mapping[str, float] | None = None,
    stderr: Mapping[str, float] | None = None,
):
    """The figure of :func:`plot_friction`, not saved."""
    from matplotlib.figure import Figure

    v = vector(velocity_mps, "velocity_mps")
    tau = vector(torque_nm, "torque_nm")
    same_length(v, "velocity_mps", tau, "torque_nm")
    if (fit_velocity_mps is None) != (fit_torque_nm is None):
        raise DataError("plot_friction: give both fit_velocity_mps and fit_torque_nm, or neither")
    fit = None
    if fit_velocity_mps is not None:
        fv = vector(fit_velocity_mps, "fit_velocity_mps")
        ft = vector(fit_torque_nm, "fit_torque_nm")
        same_length(fv, "fit_velocity_mps", ft, "fit_torque_nm")
        order = np.argsort(fv, kind="stable")
        fit = (fv[order], ft[order])

    fig = Figure(figsize=(8.5, 4.8), dpi=110, layout="constrained")
    ax = fig.subplots()
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.plot(v, tau, "o", ms=4, color="tab:blue", label="measured (steady state)")
    name = friction_title(structure) if structure else ""
    if fit is not None:
        fv, ft = fit
        first = True
        for branch in (fv < 0, fv > 0):  # the step at v = 0 is not bridged by a sloped segment
            if np.any(branch):
                ax.plot(
                    fv[branch],
                    ft[branch],
                    "-",
                    color="tab:orange",
                    lw=1.6,
                    label=(f"fit: {name}" if name else "fit") if first else None,
                )
                first = False
    ax.set_xlabel("velocity [m/s]")
    ax.set_ylabel("friction torque [N·m]")
    ax.set_title(" — ".join(p for p in (name, label) if p) or "friction")
    ax.grid(True, alpha=0.3)
    outside_legend(ax)
    if params:
        text = "\n".join(friction_parameter_lines(structure or "", params, stderr))
        if text:
            ax.annotate(
                text,
                xy=(1.01, 0.0),
                xycoords="axes fraction",
                ha="left",
                va="bottom",
                fontsize=8,
                family="monospace",
                bbox=dict(boxstyle="round", fc="white", ec="0.7"),
            )
    return fig


def plot_friction(
    path: str | os.PathLike,
    velocity_mps: Any,
    torque_nm: Any,
    fit_velocity_mps: Any = None,
    fit_torque_nm: Any = None,
    label: str = "",
    **kwargs: Any,
) -> Path:
    """Friction torque against velocity: measured steady-state points and the fit, written as PNG.

    The fit is split at zero velocity into its negative and positive branch,
    so the Coulomb/stiction step at ``v = 0`` is not bridged. The title names
    the model; its parameters with units (and standard errors) are written
    beside the axes.

    Parameters
    ----------
    path : str or path-like
        PNG to write.
    velocity_mps, torque_nm : array_like
        Steady-state points, m/s and N·m, same length.
    fit_velocity_mps, fit_torque_nm : array_like, optional
        The fitted model on a grid (both or neither).
    label : str
        Added to the title, e.g. the config and date.
    **kwargs
        ``structure`` (``"coulomb_viscous"``, ``"stribeck_fixed_exponents"``,
        ``"stribeck"``: the title's model name), ``params`` (name to value,
        SI: ``Fc``, ``Fs`` N·m, ``Fv`` N·m/(m/s), ``vs`` m/s, exponents),
        ``stderr`` (name to standard error).

    Returns
    -------
    pathlib.Path
        The written PNG.

    Raises
    ------
    DataError
        On empty or mismatched arrays, or only one of the fit arrays.
    """
    return save(friction_figure(velocity_mps, torque_nm, fit_velocity_mps, fit_torque_nm, label, **kwargs), path)
