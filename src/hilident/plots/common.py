"""Checks, units, titles and file writing shared by the figures.

Examples
--------
>>> ratio_unit(channel_unit("velocity_mps"), "N*m")
'(m/s)/(N·m)'
>>> plain_number(0.05), plain_number(1000.0)
('0.05', '1000')
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError
from hilident.io.serialise import atomic_write

#: Unit of a channel from its name's suffix (hilident's channel names carry their unit).
_SUFFIX_UNITS = {"_mps": "m/s", "_m": "m", "_nm": "N·m", "_rad": "rad", "_rads": "rad/s", "_a": "A", "_v": "V"}


def vector(value: Any, name: str, *, dtype=float) -> np.ndarray:
    """``value`` as a non-empty 1-D array, or a :class:`DataError` naming it."""
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name}: expected a 1-D numeric array ({exc})") from None
    if arr.ndim != 1:
        raise DataError(f"{name}: expected a 1-D array, got shape {arr.shape}")
    if arr.size == 0:
        raise DataError(f"{name}: array is empty")
    return arr


def same_length(a: np.ndarray, a_name: str, b: np.ndarray, b_name: str) -> None:
    """A :class:`DataError` naming both arrays when their shapes differ."""
    if a.shape != b.shape:
        raise DataError(f"{b_name} has {b.size} values but {a_name} has {a.size}; lengths must match")


def save(fig, path: str | os.PathLike) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically (a reader never sees half a file)."""
    path = Path(path)
    atomic_write(path, lambda fh: fig.savefig(fh, format="png"))
    return path


def pretty_unit(unit: str | None) -> str:
    """``"N*m"`` -> ``"N·m"``; None or ``"1"`` (no unit recorded) -> ``""``."""
    if not unit or unit.strip() in ("1", "-"):
        return ""
    return unit.strip().replace("*", "·")


def channel_unit(channel: str | None) -> str:
    """Unit a hilident channel name carries (``velocity_mps`` -> ``"m/s"``), ``""`` when it carries none."""
    if not channel:
        return ""
    for suffix in sorted(_SUFFIX_UNITS, key=len, reverse=True):
        if channel.lower().endswith(suffix):
            return _SUFFIX_UNITS[suffix]
    return ""


def ratio_unit(output_unit: str | None, input_unit: str | None) -> str:
    """Unit of a response ``output / input``: ``("m/s", "N*m")`` -> ``"(m/s)/(N·m)"``; ``""`` if either is unknown."""
    out, inp = pretty_unit(output_unit), pretty_unit(input_unit)
    if not out or not inp:
        return ""

    def group(u: str) -> str:
        return f"({u})" if any(c in u for c in "/·* ") else u

    return f"{group(out)}/{group(inp)}"


def config_name(source: str | None) -> str:
    """The file name of a config source: ``"configs/msd.toml"`` -> ``"msd.toml"``, ``"run.h5 (config_toml
    attribute)"`` -> ``"run.h5"``; ``""`` for none."""
    if not source:
        return ""
    return Path(str(source).split(" (")[0]).name


def plot_title(subject: str | None, when: dt.datetime | None = None, what: str = "") -> str:
    """``"Bode: emulated-gantry.toml, 2026-11-23 19:40 UTC"``: what is drawn, of what (a config's name), and when."""
    when = when or dt.datetime.now(dt.UTC)
    stamp = when.astimezone(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"{what + ': ' if what else ''}{subject or 'no config'}, {stamp}"


def plain_number(x: float, _pos: Any = None) -> str:
    """Tick label of a log axis: the shortest plain form (``0.05``, ``2``, ``1000``), never rounded to a duplicate."""
    if x == 0 or not np.isfinite(x):
        return "0"
    return f"{x:.6g}"


def outside_legend(ax, **kwargs):
    """A legend to the right of ``ax``, outside the data."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    return ax.legend(
        handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8, **kwargs
    )
