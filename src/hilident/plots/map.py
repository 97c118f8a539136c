"""The mode over the workspace: each mapped position's frequency with its 95 % interval, the joint model's
prediction with its band, and the range a covering notch must hold."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from hilident.errors import DataError
from hilident.plots.common import outside_legend, save

__all__ = ["map_figure", "plot_map"]


def map_figure(
    points: Sequence[dict],
    *,
    title: str = "",
    model: Callable[[np.ndarray], tuple] | None = None,
    model_label: str = "joint model",
    covered_hz: tuple[float, float] | None = None,
):
    """The figure of :func:`plot_map`, not saved.

    Parameters
    ----------
    points : sequence of dict
        ``summary.json["map"]``: ``position_m``, ``frequency_hz`` (None: no mode found there),
        ``frequency_ci95_hz`` (None: no interval).
    title : str
        The figure's title (config and date, :func:`hilident.plots.common.plot_title`).
    model : callable, optional
        ``model(positions_m) -> (frequency_hz, ci95_hz)``, arrays: the joint fit's mode over position.
    model_label : str
        Legend of the model's curve.
    covered_hz : (float, float), optional
        The frequency range a covering notch holds to its target, Hz (drawn as a band).
    """
    from matplotlib.figure import Figure

    found = [p for p in points if p.get("frequency_hz") is not None]
    if not found:
        raise DataError("map plot: no mapped position has a mode")
    x = np.array([p["position_m"] for p in found], dtype=float)
    f = np.array([p["frequency_hz"] for p in found], dtype=float)
    ci = np.array([p.get("frequency_ci95_hz") or 0.0 for p in found], dtype=float)
    fig = Figure(figsize=(8.5, 4.8), dpi=110, layout="constrained")
    ax = fig.subplots()
    if covered_hz is not None:
        ax.axhspan(
            covered_hz[0],
            covered_hz[1],
            color="tab:green",
            alpha=0.12,
            label=f"notch covers {covered_hz[0]:.2f}-{covered_hz[1]:.2f} Hz",
        )
    ax.errorbar(
        x, f, yerr=ci, fmt="o", ms=5, capsize=4, color="tab:blue", label="identified at each position (95 % interval)"
    )
    if model is not None:
        grid = np.linspace(x.min(), x.max(), 200) if x.size > 1 else x
        fm, fm_ci = (np.asarray(v, dtype=float) for v in model(grid))
        ax.plot(grid, fm, color="tab:orange", lw=1.6, label=model_label)
        ax.fill_between(
            grid, fm - fm_ci, fm + fm_ci, color="tab:orange", alpha=0.2, label=f"{model_label}, 95 % interval"
        )
    missing = [p["position_m"] for p in points if p.get("frequency_hz") is None]
    for i, position in enumerate(missing):
        ax.axvline(position, color="0.5", ls=":", lw=1.0, label="no mode found" if i == 0 else None)
    ax.set_xlabel("cart position [m]")
    ax.set_ylabel("mode frequency [Hz]")
    ax.grid(True, alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)
    outside_legend(ax)
    return fig


def plot_map(path: str | os.PathLike, points: Sequence[dict], **kwargs) -> Path:
    """Draw :func:`map_figure` to ``path`` (PNG)."""
    return save(map_figure(points, **kwargs), path)
