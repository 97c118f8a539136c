"""``hilident show``: a recording's channels over time, its events and the run's metadata in one figure.

Channels that share a unit share an axis (labelled with the quantity and its
unit); the recording's events are vertical lines on every axis, styled by
what they mean (faults red, lost or mangled data orange, the rest grey) and
counted in the legend; the title names the file, the experiment, the mode,
the configuration, the device, the sample rate, the date and the status.
Rows are placed at their own ``time_s`` (or ``sample_index``), so samples a
run lost leave a gap in the trace instead of a line drawn across it.

matplotlib is imported only when a figure is drawn; the figure is built with
the object API, so a PNG is written without touching pyplot's global state.

Examples
--------
>>> parse_channel_list("excitation, torque_nm,,")
['excitation', 'torque_nm']
>>> axis_label(["torque_cmd_nm", "torque_nm"], "N*m")
'torque [N·m]'
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilident.errors import UsageError
from hilident.events import FAULT_KINDS, Kind
from hilident.units import DIMENSIONLESS, display_unit, recorded_units

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from hilident.io.recording import RunData

__all__ = [
    "TIME_COLUMNS",
    "ShowResult",
    "axis_label",
    "draw_recording",
    "load_recording",
    "parse_channel_list",
    "recording_figure",
    "select_channels",
    "show_recording",
    "title_lines",
]

#: Columns that give each row's place in time; drawn as the time axis, not as channels.
TIME_COLUMNS = ("sample_index", "time_s")

#: Above this many rows a trace is drawn as a min/max envelope per bucket (every peak stays visible).
MAX_PLOT_POINTS = 20_000

#: What the quantity of a unit is called on an axis shared by several channels.
QUANTITY_OF_UNIT = {
    "N*m": "torque",
    "N": "force",
    "m": "position",
    "m/s": "velocity",
    "m/s^2": "acceleration",
    "rad": "angle",
    "rad/s": "angular velocity",
    "A": "current",
    "V": "voltage",
    "s": "time",
}

#: Event kinds that mean data were lost, mangled or not measured.
LOSS_KINDS = frozenset(
    {
        Kind.LOST_BLOCKS,
        Kind.OUT_OF_ORDER,
        Kind.PROTOCOL_ERROR,
        Kind.REFUSED,
        Kind.MISSING_RESPONSE,
        Kind.UNDERRUN,
        Kind.CLIPPED,
        Kind.SYNC_LATE,
        Kind.SYNC_UNANSWERED,
        Kind.SYNC_ERRORS,
        Kind.CAPTURE_SHORT,
        Kind.CAPTURE_STOPPED,
        Kind.EXCITATION_DIFFERS,
    }
)

#: (colour, line width) of an event line by what the event means; kinds of one meaning differ in line style.
_FAULT_STYLE = ("tab:red", 1.4)
_LOSS_STYLE = ("tab:orange", 1.0)
_OTHER_STYLE = ("0.45", 1.0)
_LINE_STYLES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)))


@dataclass(frozen=True)
class ShowResult:
    """What :func:`show_recording` did.

    Attributes
    ----------
    png : pathlib.Path or None
        The PNG written, or None when the figure was shown in a window.
    note : str
        Why a PNG was written instead of a window (empty when ``--out`` asked for it).
    """

    png: Path | None
    note: str = ""


# --------------------------------------------------------------------------- input


def load_recording(path: str | os.PathLike) -> RunData:
    """The recording at ``path``, read with :func:`hilident.io.recording.read_run`.

    Raises
    ------
    UsageError
        When ``path`` is missing, a folder, or not a hilident recording (the
        argument cannot be used; exit 2).
    DataError
        When it is a hilident recording that cannot be read (damaged; exit 3).
    """
    import h5py

    from hilident.io.recording import FORMAT, read_run

    p = Path(path)
    if p.is_dir():
        inside = sorted(q.name for q in p.glob("*.h5"))
        hint = f"; its recordings: {', '.join(inside)}" if inside else " and holds no recording (.h5)"
        raise UsageError(f"{p}: is a folder, not a recording{hint}")
    if not p.is_file():
        raise UsageError(f"{p}: no such file; hilident show takes a recording (.h5) written by hilident run")
    if not h5py.is_hdf5(p):
        raise UsageError(
            f"{p}: not a hilident recording (not an HDF5 file); hilident show takes the .h5 files "
            "hilident run writes (CSV and .mat files go to hilident identify)"
        )
    try:
        with h5py.File(p, "r", locking=False) as f:
            found = f.attrs.get("format")
    except OSError:
        found = FORMAT  # open elsewhere in this process: read_run copes, or says what is wrong
    if isinstance(found, bytes):
        found = found.decode("utf-8", errors="replace")
    if found != FORMAT:
        raise UsageError(
            f"{p}: not a hilident recording (an HDF5 file without format = {FORMAT!r}); hilident show "
            "takes the .h5 files hilident run writes"
        )
    return read_run(p)


def parse_channel_list(text: str) -> list[str]:
    """``"a, b,,c"`` -> ``["a", "b", "c"]``: the names of a ``--channels`` option, empty parts dropped."""
    return [part.strip() for part in text.split(",") if part.strip()]


def select_channels(run: RunData, names: Sequence[str] | None = None) -> list[str]:
    """The channels to draw: ``names`` in their order (each once), or every channel but the time columns.

    Raises
    ------
    UsageError
        For a name the recording does not have; the message lists the ones it has.
    """
    if not names:
        picked = [n for n in run.channel_names if n not in TIME_COLUMNS]
        return picked or list(run.channel_names)
    unknown = [n for n in names if n not in run.samples]
    if unknown:
        raise UsageError(
            f"--channels: {run.path} has no channel {', '.join(map(repr, unknown))}; its channels: "
            f"{', '.join(run.channel_names)}"
        )
    return list(dict.fromkeys(names))


def sample_times_s(run: RunData) -> np.ndarray:
    """Time of each row, s: the ``time_s`` column (else ``sample_index / rate``, else ``row / rate``).

    A run that lost samples has no rows for them, so the row number is not
    the time; the recorded columns are.
    """
    rate = run.sample_rate_hz
    for name, scale in (("time_s", 1.0), ("sample_index", 1.0 / rate)):
        column = run.samples.get(name)
        if column is not None and column.size and np.all(np.isfinite(column)) and np.all(np.diff(column) > 0):
            return column * scale
    return run.time_s


# --------------------------------------------------------------------------- drawing


def axis_label(names: Sequence[str], unit: str) -> str:
    """Y label of an axis holding ``names``, all in ``unit``: the channel (or the quantity) and the unit.

    A dimensionless channel is labelled ``[-]``; a channel without a unit has
    only its name.
    """
    shown = "-" if unit == DIMENSIONLESS else display_unit(unit)
    what = names[0] if len(names) == 1 else QUANTITY_OF_UNIT.get(unit, ", ".join(names))
    return f"{what} [{shown}]" if unit else what


def _axis_groups(names: Sequence[str], units: Mapping[str, str]) -> list[tuple[str, list[str]]]:
    """``(unit, channels)`` per axis: channels of one unit together, in order of first appearance; a
    channel without a unit alone."""
    groups: dict[str, list[str]] = {}
    for name in names:
        unit = units.get(name, "")
        groups.setdefault(unit if unit else f"\0{name}", []).append(name)
    return [("" if key.startswith("\0") else key, members) for key, members in groups.items()]


def _with_gaps(t: np.ndarray, y: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` with a NaN after every row followed by a gap (lost samples), so no line bridges it."""
    gaps = np.flatnonzero(np.diff(t) > 1.5 * period_s) + 1
    if gaps.size == 0:
        return t, y
    return np.insert(t, gaps, t[gaps - 1] + period_s), np.insert(y.astype(float), gaps, np.nan)


def _envelope(t: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """A long trace as min and max per bucket (peaks survive); a bucket holding a gap ends its line."""
    n_buckets = max(1, max_points // 3)
    starts = np.unique(np.linspace(0, t.size, n_buckets + 1, dtype=np.int64)[:-1])
    nan = np.isnan(y)
    with np.errstate(invalid="ignore"):
        lo = np.fmin.reduceat(y, starts)  # fmin/fmax skip NaN unless a whole bucket is NaN
        hi = np.fmax.reduceat(y, starts)
    gap = np.add.reduceat(nan.astype(np.int64), starts) > 0
    tb = t[starts]
    return np.repeat(tb, 3), np.column_stack([lo, hi, np.where(gap, np.nan, hi)]).ravel()


def _event_style(kind: str) -> tuple[str, float]:
    if kind in FAULT_KINDS:
        return _FAULT_STYLE
    if kind in LOSS_KINDS:
        return _LOSS_STYLE
    return _OTHER_STYLE


def _events_by_kind(events: Iterable[Mapping[str, Any]]) -> dict[str, list[float]]:
    """Times of the events of each kind, s, kinds in order of first appearance."""
    out: dict[str, list[float]] = {}
    for ev in events:
        out.setdefault(str(ev.get("kind", "")), []).append(float(ev["time_s"]))
    return out


def title_lines(run: RunData) -> list[str]:
    """The run's metadata as the figure's title says it: what, where, when, how it ended, what happened."""
    lines = [_what_line(run), _where_line(run.attrs), f"{_when_text(run)} · {_status_text(run)}"]
    lines += _event_lines(run.events)
    return [line for line in lines if line]


def _what_line(run: RunData) -> str:
    """The file, the experiment and the mode."""
    a = run.attrs
    what = f"{run.path.name}: {a.get('experiment', 'run')}"
    if a.get("mode"):
        what += f", mode {a['mode']}"
    return what


def _where_line(attrs: Mapping[str, Any]) -> str:
    """The configuration, the device and the hilident version that made the recording (each when known)."""
    device = attrs.get("device") if isinstance(attrs.get("device"), Mapping) else {}
    where = [f"config {attrs['config_source']}"] if attrs.get("config_source") else []
    if device:
        where.append(_device_text(device))
    versions = attrs.get("versions")
    version = (versions or {}).get("hilident") if isinstance(versions, Mapping) else None
    if version:
        where.append(f"hilident {version}")
    return " · ".join(where)


def _device_text(device: Mapping[str, Any]) -> str:
    """The device's name and firmware, and the port it was on."""
    name = " ".join(str(device[k]) for k in ("name", "firmware") if device.get(k))
    return f"device {name}" + (f" on {device['port']}" if device.get("port") else "")


def _when_text(run: RunData) -> str:
    """The sample rate (Hz), the samples over the span they cover (s), those not recorded, and the date (UTC)."""
    t = sample_times_s(run)
    span = int(round((float(t[-1]) - float(t[0])) * run.sample_rate_hz)) + 1 if t.size else 0
    when = f"{run.sample_rate_hz:g} Hz, {run.n_samples} samples over {span / run.sample_rate_hz:.4g} s"
    if span > run.n_samples:
        when += f" ({span - run.n_samples} not recorded)"
    created = run.attrs.get("created_utc")
    if created:
        when += f", recorded {str(created)[:19].replace('T', ' ')} UTC"
    return when


def _status_text(run: RunData) -> str:
    """How the recording ended: its status, and why (or that it was never closed)."""
    status = f"status {run.status}"
    if run.status == "running":
        status += " (the recording process ended without closing the file, or is still writing)"
    elif run.reason:
        status += f": {_shorten(run.reason, 90)}"
    return status


def _event_lines(events: Sequence[Mapping[str, Any]]) -> list[str]:
    """How many events of each kind the recording holds, and the first fault with its time (s) and message."""
    counts = _events_by_kind(events)
    if not counts:
        return []
    lines = ["events: " + ", ".join(f"{kind} × {len(times)}" for kind, times in counts.items())]
    first_fault = next((ev for ev in events if ev.get("kind") in FAULT_KINDS), None)
    if first_fault is not None:
        lines.append(
            f"{first_fault['kind']} at {first_fault['time_s']:.4g} s: "
            f"{_shorten(str(first_fault.get('message', '')), 100)}"
        )
    return lines


def _shorten(text: str, length: int) -> str:
    text = " ".join(text.split())
    return text if len(text) <= length else text[: length - 1] + "…"


def draw_recording(fig: Figure, run: RunData, channels: Sequence[str] | None = None) -> None:
    """Draw ``run`` into ``fig``: one axis per unit, the events on every axis, the metadata as the title.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        An empty figure (from :class:`~matplotlib.figure.Figure` or pyplot).
    run : RunData
        The recording (:func:`load_recording`).
    channels : sequence of str, optional
        Channels to draw (default: all but ``sample_index`` and ``time_s``).

    Raises
    ------
    UsageError
        For a channel the recording does not have.
    """
    names = select_channels(run, channels)
    units = recorded_units(run.units, run.attrs)
    groups = _axis_groups(names, units)
    t = sample_times_s(run)
    period_s = 1.0 / run.sample_rate_hz
    axes = fig.subplots(len(groups), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (unit, members) in zip(axes, groups, strict=True):
        for name in members:
            tt, yy = _with_gaps(t, run.samples[name], period_s)
            if tt.size > MAX_PLOT_POINTS:
                tt, yy = _envelope(tt, yy, MAX_PLOT_POINTS)
            ax.plot(tt, yy, lw=0.8, label=name, alpha=0.8 if len(members) > 1 else 1.0)  # overlaps stay visible
        ax.set_ylabel(axis_label(members, unit))
        ax.grid(True, alpha=0.3)
        if len(members) > 1:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    if t.size:  # the run's span, and the events logged at its end (a run's "finished" is one past the last row)
        end = max([float(t[-1]) + period_s, *(float(ev["time_s"]) for ev in run.events)])
        axes[-1].set_xlim(float(t[0]), min(end, float(t[-1]) + 0.05 * (float(t[-1]) - float(t[0])) + period_s))
    axes[-1].set_xlabel("time [s]")
    _draw_events(fig, axes, run.events)
    fig.suptitle("\n".join(title_lines(run)), fontsize=9, x=0.01, ha="left")


def _draw_events(fig: Figure, axes, events: Sequence[Mapping[str, Any]]) -> None:
    """A vertical line per event on every axis, one legend entry per kind (with its count) below the axes."""
    handles = []
    kinds_of_style: dict[tuple[str, float], int] = {}
    for kind, times in _events_by_kind(events).items():
        color, width = _event_style(kind)
        n = kinds_of_style[color, width] = kinds_of_style.get((color, width), -1) + 1
        style = _LINE_STYLES[n % len(_LINE_STYLES)]
        for i, ax in enumerate(axes):
            lines = ax.vlines(
                times,
                0.0,
                1.0,
                transform=ax.get_xaxis_transform(),
                colors=color,
                linestyles=style,
                linewidths=width,
                alpha=0.85,
                zorder=3,
                label=f"{kind} ({len(times)})" if i == 0 else None,
            )
            if i == 0:
                handles.append(lines)
    if handles:
        fig.legend(
            handles=handles,
            loc="outside lower center",
            ncols=min(4, len(handles)),
            fontsize=8,
            frameon=False,
            title="events",
            title_fontsize=8,
        )


def recording_figure(run: RunData, channels: Sequence[str] | None = None) -> Figure:
    """A new (pyplot-free) figure of ``run``, drawn by :func:`draw_recording`."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=_figure_size(run, channels), dpi=100, layout="constrained")
    draw_recording(fig, run, channels)
    return fig


def _figure_size(run: RunData, channels: Sequence[str] | None) -> tuple[float, float]:
    names = select_channels(run, channels)
    n_axes = len(_axis_groups(names, recorded_units(run.units, run.attrs)))
    return 10.0, 2.2 + 2.0 * n_axes + (0.5 if run.events else 0.0)


# --------------------------------------------------------------------------- window or file


def display_available(environ: Mapping[str, str] | None = None, platform: str | None = None) -> bool:
    """Whether a window can be opened: always on Windows and macOS, with ``DISPLAY`` or
    ``WAYLAND_DISPLAY`` set elsewhere."""
    environ = os.environ if environ is None else environ
    platform = sys.platform if platform is None else platform
    if platform.startswith(("win", "darwin")):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def _interactive_pyplot():
    """pyplot on an interactive backend, or None when only a file backend can be had."""
    import matplotlib

    try:
        from matplotlib.backends import BackendFilter, backend_registry

        interactive = set(backend_registry.list_builtin(BackendFilter.INTERACTIVE))
    except ImportError:  # matplotlib 3.8
        from matplotlib import rcsetup

        interactive = set(getattr(rcsetup, "interactive_bk", ()))
    try:
        import matplotlib.pyplot as plt

        backend = matplotlib.get_backend()  # resolves the automatic choice: a GUI toolkit if one imports
    except (ImportError, RuntimeError):
        return None
    return plt if backend.lower() in {b.lower() for b in interactive} else None


def beside(path: Path) -> Path:
    """``<recording>.png`` in the recording's folder."""
    return path.with_suffix(".png")


def save_png(fig: Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` atomically; an unwritable place is a UsageError naming it."""
    from hilident.io.serialise import atomic_write

    try:
        atomic_write(path, lambda fh: fig.savefig(fh, format="png"))
    except OSError as exc:
        raise UsageError(f"cannot write {path}: {exc.strerror or exc}; give another place with --out") from None
    return path


def show_recording(
    path: str | os.PathLike,
    channels: Sequence[str] | None = None,
    out: str | os.PathLike | None = None,
    *,
    window: bool | None = None,
) -> ShowResult:
    """Draw a recording: into ``out``, else in a window when a display exists, else into ``<recording>.png``.

    Parameters
    ----------
    path : str or path-like
        The recording (``.h5``).
    channels : sequence of str, optional
        Channels to draw (default: all but the time columns).
    out : str or path-like, optional
        PNG to write; no window then.
    window : bool, optional
        Whether to try a window when ``out`` is not given (default: when
        :func:`display_available`).

    Returns
    -------
    ShowResult
        The PNG written (None when a window showed the figure) and why a file was written instead of a window.

    Raises
    ------
    UsageError
        A missing file, a file that is not a recording, an unknown channel, an unwritable PNG.
    DataError
        A damaged recording.
    """
    run = load_recording(path)
    select_channels(run, channels)  # an unknown channel is refused before a window opens
    if out is not None:
        return ShowResult(save_png(recording_figure(run, channels), Path(out)))
    if window is None:
        window = display_available()
    plt = _interactive_pyplot() if window else None
    if plt is not None:
        fig = plt.figure(figsize=_figure_size(run, channels), layout="constrained")
        draw_recording(fig, run, channels)
        plt.show()
        return ShowResult(None)
    note = "no display" if not window else "no interactive matplotlib backend"
    return ShowResult(save_png(recording_figure(run, channels), beside(run.path)), note)
