"""The stabilisation diagram of a modal estimate from several inputs and outputs (``stabilisation.png``).

Every physical pole of every model order of the polyreference LSCF estimate at its frequency (x) and order
(y), marked by how it compares with the poles of the order below (``summary.json["mimo"]["stabilisation"]``,
:func:`hilident.ident.mimo.modal.stabilisation`); the first singular value of the measured response over
the band on a second axis (the mode indicator: where the modes every output sees stand out); the orders the
modes were selected over shaded, and the selected modes as vertical lines.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.plots.common import save

__all__ = ["STABILISATION_PNG", "first_singular_db", "plot_stabilisation", "stabilisation_figure"]

#: The figure's file name in the output folder.
STABILISATION_PNG = "stabilisation.png"

#: Marker, colour, filled, legend of each label, from least to most stable.
_STYLES = {
    "new": ("o", "0.6", False, "new (lowest order)"),
    "unstable": ("x", "0.6", True, "unstable"),
    "frequency": ("^", "tab:orange", False, "stable in frequency"),
    "damping": ("s", "tab:purple", False, "stable in frequency and damping"),
    "vector": ("D", "tab:blue", False, "stable in frequency and vector"),
    "stable": ("o", "tab:green", True, "stable (frequency, damping, vector)"),
}


def first_singular_db(frequency_hz: Any, response: Any, band_hz: Sequence[float] | None = None):
    """The first singular value of ``response`` (F, n_out, n_in) at each finite line in the band, dB.

    Returns
    -------
    (ndarray, ndarray)
        The lines' frequencies (Hz) and ``20 log10`` of the first singular value, in the response's units.
    """
    f = np.asarray(frequency_hz, dtype=float)
    h = np.asarray(response, dtype=complex)
    if h.ndim != 3 or h.shape[0] != f.size:
        raise DataError(f"response must be (F, n_out, n_in) over the {f.size} frequencies, got {h.shape}")
    keep = np.all(np.isfinite(h), axis=(1, 2))
    if band_hz is not None:
        keep &= (f >= band_hz[0]) & (f <= band_hz[1])
    if not keep.any():
        return f[:0], f[:0]
    singular = np.linalg.svd(h[keep], compute_uv=False)[:, 0]
    return f[keep], 20.0 * np.log10(np.maximum(singular, np.finfo(float).tiny))


def stabilisation_figure(
    mimo: Mapping[str, Any],
    frequency_hz: Any = None,
    response: Any = None,
    *,
    title: str = "",
):
    """The figure of :func:`plot_stabilisation`, not saved.

    Parameters
    ----------
    mimo : mapping
        ``summary.json["mimo"]``: ``stabilisation`` ({order, frequency_hz, damping_ratio, label, orders_used}),
        ``modes`` (each with ``frequency_hz``) and ``band_hz``.
    frequency_hz, response : array_like, optional
        The measured response (Hz; (F, n_out, n_in)) for the mode indicator; left out when None.
    title : str
        The figure's title (:func:`hilident.plots.common.plot_title`).

    Raises
    ------
    DataError
        ``mimo`` holds no stabilisation diagram.
    """
    from matplotlib.figure import Figure

    diagram = mimo.get("stabilisation")
    if not isinstance(diagram, Mapping) or not diagram.get("order"):
        raise DataError("stabilisation plot: the summary holds no stabilisation diagram (no modal estimate)")
    order = np.asarray(diagram["order"], dtype=float)
    freq = np.asarray(diagram["frequency_hz"], dtype=float)
    label = np.asarray(diagram["label"], dtype=object)
    fig = Figure(figsize=(10.0, 5.6), dpi=110, layout="constrained")
    ax = fig.subplots()
    window = diagram.get("orders_used") or []
    if window:
        ax.axhspan(min(window) - 0.5, max(window) + 0.5, color="tab:green", alpha=0.08, label="orders selected over")
    for name, (marker, colour, filled, legend) in _STYLES.items():
        at = label == name
        if not at.any():
            continue
        if marker == "x":  # an unfilled marker: drawn in its face colour
            ax.scatter(freq[at], order[at], s=16, marker=marker, c=colour, label=legend)
        else:
            face = colour if filled else "none"
            ax.scatter(freq[at], order[at], s=16, marker=marker, facecolors=face, edgecolors=colour, label=legend)
    _modes(ax, mimo.get("modes") or [])
    band = mimo.get("band_hz")
    if isinstance(band, Sequence) and len(band) == 2:
        ax.set_xlim(float(band[0]), float(band[1]))
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("model order")
    ax.grid(True, alpha=0.3)
    if frequency_hz is not None and response is not None:
        _indicator(ax, frequency_hz, response, band if isinstance(band, Sequence) and len(band) == 2 else None)
    if title:
        ax.set_title(title, fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, fontsize=8, frameon=False)
    return fig


def _modes(ax, modes: Sequence[Any]) -> None:
    """Each selected mode as a vertical line, numbered as in the report's tables."""
    for k, mode in enumerate(m for m in modes if isinstance(m, Mapping) and m.get("frequency_hz") is not None):
        f = float(mode["frequency_hz"])
        ax.axvline(f, color="tab:red", ls="--", lw=1.0, alpha=0.7, zorder=1, label="selected mode" if k == 0 else None)
        ax.annotate(
            str(k + 1),
            xy=(f, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(2, -2),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize=8,
            color="tab:red",
        )


def _indicator(ax, frequency_hz: Any, response: Any, band: Sequence[float] | None) -> None:
    """The first singular value of the response on a second y axis, its legend entry on ``ax``'s."""
    f, db = first_singular_db(frequency_hz, response, band)
    if not f.size:
        return
    right = ax.twinx()
    right.plot(f, db, color="0.25", lw=0.9, alpha=0.8)
    right.set_ylabel("first singular value of H [dB]")
    ax.set_zorder(right.get_zorder() + 1)  # the poles over the curve
    ax.patch.set_visible(False)
    ax.plot([], [], color="0.25", lw=0.9, label="first singular value of H (right axis)")


def plot_stabilisation(
    path: str | os.PathLike, mimo: Mapping[str, Any], frequency_hz: Any = None, response: Any = None, **kwargs
) -> Path:
    """Draw :func:`stabilisation_figure` to ``path`` (PNG)."""
    return save(stabilisation_figure(mimo, frequency_hz, response, **kwargs), path)
