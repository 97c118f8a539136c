"""The notches of an upload: the chain as designed and as the device stores it (read back), in dB."""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.plots.common import config_name, outside_legend, plain_number, plot_title, save

__all__ = ["notch_figure", "plot_notches", "records_chain"]

#: Points of the log frequency grid the chains are drawn on.
GRID_POINTS = 4000


def records_chain(
    records: Iterable[Mapping[str, Any]], b_key: str, a_key: str, rates: Mapping[Any, float], f: np.ndarray
) -> np.ndarray | None:
    """The biquads ``(record[b_key], record[a_key])`` in series at ``f`` (Hz); None when no record has both.

    A record's rate is ``rates[record["slot"]]``, else its own ``sample_rate_hz``; a record without one is left out.

    Raises
    ------
    DataError
        A record's coefficients are not a biquad's (three each, ``a[0] = 1``), naming its slot and keys.
    """
    from hilident.filters.biquad import Biquad

    h = np.ones(f.shape, dtype=complex)
    found = False
    for r in records:
        b, a, rate = r.get(b_key), r.get(a_key), rates.get(r.get("slot"), r.get("sample_rate_hz"))
        if b is None or a is None or not rate:
            continue
        try:
            section = Biquad.from_sequences(b, a)
        except ValueError as exc:
            raise DataError(f"slot {r.get('slot')}: {b_key} {b!r} and {a_key} {a!r}: {exc}") from None
        h = h * section.response(f, float(rate))
        found = True
    return h if found else None


def notch_figure(summary: Mapping[str, Any]):
    """The figure of :func:`plot_notches`, unsaved (what the tests inspect).

    Raises
    ------
    DataError
        The summary holds no notch with a centre and a sample rate.
    """
    from matplotlib.figure import Figure

    designs = [n for n in summary.get("notch_filters") or [] if n.get("center_hz") and n.get("sample_rate_hz")]
    if not designs:
        raise DataError("the summary holds no notch (notch_filters with center_hz and sample_rate_hz) to draw")
    centres = [float(n["center_hz"]) for n in designs]
    nyquist = min(float(n["sample_rate_hz"]) for n in designs) / 2
    f = np.geomspace(min(centres) / 5, min(max(centres) * 5, 0.99 * nyquist), GRID_POINTS)
    rates = {n.get("slot"): float(n["sample_rate_hz"]) for n in designs}
    slots = (summary.get("upload") or {}).get("slots") or []

    fig = Figure(figsize=(9.0, 4.5), layout="constrained")
    ax = fig.add_subplot()
    designed = records_chain(designs, "b", "a", rates, f)
    if designed is not None:
        ax.semilogx(
            f,
            20 * np.log10(np.abs(designed)),
            color="tab:blue",
            lw=1.5,
            ls="--",
            label=f"designed ({len(designs)} notch{'es' if len(designs) != 1 else ''})",
        )
    stored = records_chain(slots, "readback_b", "readback_a", rates, f)
    if stored is not None:
        ax.semilogx(
            f,
            20 * np.log10(np.abs(stored)),
            color="tab:red",
            lw=1.2,
            label=f"stored in the device (read back, {len(slots)} slot{'s' if len(slots) != 1 else ''})",
        )
    for n in designs:
        ax.axvline(
            float(n["center_hz"]),
            color="0.5",
            lw=0.8,
            ls=":",
            label=f"slot {n.get('slot')}: {float(n['center_hz']):.4g} Hz, {float(n['depth_db']):.3g} dB asked"
            if n.get("depth_db") is not None
            else f"slot {n.get('slot')}: {float(n['center_hz']):.4g} Hz",
        )
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("magnitude [dB re 1]")
    ax.xaxis.set_major_formatter(plain_number)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(plot_title(config_name(summary.get("config")), what="Notches designed and stored"))
    outside_legend(ax)
    return fig


def plot_notches(path: str | os.PathLike, summary: Mapping[str, Any]) -> Path:
    """``notch.png`` of ``hilident upload``: the notch chain as designed and as read back from the device.

    Parameters
    ----------
    path : path-like
        The PNG to write.
    summary : mapping
        The upload's ``summary.json``: ``notch_filters`` (``center_hz``,
        ``depth_db``, ``sample_rate_hz``, ``slot``, ``b``, ``a``) and
        ``upload.slots`` (``slot``, ``readback_b``, ``readback_a``).

    Returns
    -------
    pathlib.Path
        The written PNG.
    """
    return save(notch_figure(summary), path)
