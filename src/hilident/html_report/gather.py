"""What a report is made of, read from an output folder: the summary, the config text, plots, recordings.

The one part of :mod:`hilident.html_report` that reads files. A folder is
whatever ``run``, ``identify`` or ``upload`` left: ``summary.json`` (needed),
PNG plots, HDF5 recordings (their root attributes carry the run's config
text, device identity and library versions). Anything else missing only
leaves its part of the report empty.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from hilident.errors import DataError, UsageError

__all__ = ["Recording", "ReportInputs", "gather"]

#: Root attributes of a hilident recording the report uses (JSON ones under their plain name).
_ATTRS = (
    "experiment",
    "mode",
    "created_utc",
    "closed_utc",
    "status",
    "reason",
    "n_samples",
    "flushed_samples",
    "sample_rate_hz",
    "config_toml",
    "config_source",
    "versions",
    "device",
    "channel_names",
    "channel_units",
)

#: A plot older than summary.json by more than this is an earlier command's (plots are drawn after the summary), s.
STALE_PLOT_S = 10.0

#: Largest config file read for the report (a path that is not a config must not fill the page), bytes.
_MAX_CONFIG_BYTES = 256 * 1024


@dataclass
class Recording:
    """One HDF5 recording: its file name (relative to the folder, or a path elsewhere) and root attributes."""

    name: str
    attrs: dict[str, Any]
    size_bytes: int
    in_folder: bool = True
    error: str = ""


@dataclass
class ReportInputs:
    """Everything :func:`hilident.html_report.page.render` draws from.

    Attributes
    ----------
    folder : pathlib.Path
        The output folder.
    summary : dict
        ``summary.json`` as read.
    summary_time_utc : str
        When ``summary.json`` was written (its modification time), ISO 8601 UTC.
    config_text, config_origin : str
        The configuration's TOML text and where it was read from (empty when not found).
    images : list of (str, bytes)
        Every PNG of the folder, by file name, with its bytes.
    stale_images : list of str
        PNGs left out: older than ``summary.json`` (an earlier command's, e.g. before a ``--no-plots`` run).
    recordings : list of Recording
        The folder's ``.h5`` files (and, for ``identify``, the data file when it is a hilident recording).
    report_versions : dict of str to str
        hilident, numpy and scipy as installed where the report is written.
    response_units : tuple of (str, str), optional
        Units of the measured response's output and input (``("m/s", "N*m")``), when the data say them.
    """

    folder: Path
    summary: dict[str, Any]
    summary_time_utc: str = ""
    config_text: str = ""
    config_origin: str = ""
    images: list[tuple[str, bytes]] = field(default_factory=list)
    stale_images: list[str] = field(default_factory=list)
    recordings: list[Recording] = field(default_factory=list)
    report_versions: dict[str, str] = field(default_factory=dict)
    response_units: tuple[str, str] | None = None

    @property
    def kind(self) -> str:
        """``run``, ``identify`` or ``upload`` (from the summary's keys)."""
        s = self.summary
        if s.get("command") == "upload" or "source" in s:
            return "upload"
        if "data" in s:
            return "identify"
        return "run"

    def first_attrs(self, key: str) -> Any:
        """``key`` from the first recording that has it (identification first), else None."""
        ordered = sorted(self.recordings, key=lambda r: r.attrs.get("experiment") != "identification")
        for rec in ordered:
            if rec.attrs.get(key) not in (None, "", {}):
                return rec.attrs[key]
        return None


def read_summary(folder: Path) -> dict[str, Any]:
    """``folder/summary.json`` as a dict.

    Raises
    ------
    UsageError
        ``folder`` is not a folder or holds no ``summary.json``.
    DataError
        ``summary.json`` is not a JSON object.
    """
    path = folder / "summary.json"
    if not folder.is_dir():
        raise UsageError(f"{folder}: not a folder (give the output folder of a run, identify or upload)")
    if not path.is_file():
        raise UsageError(f"{folder}: no summary.json in it (give the output folder of a run, identify or upload)")
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: cannot be read as JSON: {exc}") from None
    if not isinstance(summary, dict):
        raise DataError(f"{path}: expected a JSON object (a hilident summary), got {type(summary).__name__}")
    return summary


def _plain(value: Any) -> Any:
    import numpy as np

    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_recording_attrs(path: Path) -> dict[str, Any]:
    """The root attributes of a hilident recording the report uses (``*_json`` decoded); samples are not read."""
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        for key in _ATTRS:
            for stored in (key, f"{key}_json"):
                if stored in f.attrs:
                    value = _plain(f.attrs[stored])
                    if stored.endswith("_json") and isinstance(value, str):
                        try:
                            value = json.loads(value)
                        except json.JSONDecodeError:
                            continue
                    out[key] = value
        out["events"] = int(f["events"].shape[0]) if "events" in f and hasattr(f["events"], "shape") else 0
    return out


def _recording(path: Path, name: str, in_folder: bool) -> Recording:
    try:
        size = path.stat().st_size
        return Recording(name, read_recording_attrs(path), size, in_folder)
    except Exception as exc:  # a damaged or foreign file is listed, with why it says nothing more
        size = path.stat().st_size if path.exists() else 0
        return Recording(name, {}, size, in_folder, str(exc) or type(exc).__name__)


def _stored_config(recordings: list[Recording]) -> tuple[str, str]:
    for rec in sorted(recordings, key=lambda r: r.attrs.get("experiment") != "identification"):
        text = rec.attrs.get("config_toml")
        if isinstance(text, str) and text:
            return text, f"stored in {rec.name}"
    return "", ""


def _config(summary: dict[str, Any], folder: Path, recordings: list[Recording]) -> tuple[str, str]:
    """The config text and where it came from.

    What a recording of this folder stores comes first (it is what ran; the
    file may have changed since), then the file the summary names, then what
    the data file of ``identify`` stores.
    """
    text, origin = _stored_config([r for r in recordings if r.in_folder])
    if text:
        return text, origin
    source = summary.get("config")
    if isinstance(source, str) and source and not source.endswith("(config_toml attribute)"):
        for candidate in (Path(source), folder / source):
            try:
                if candidate.is_file() and candidate.stat().st_size <= _MAX_CONFIG_BYTES:
                    return candidate.read_text(encoding="utf-8", errors="replace"), str(candidate)
            except OSError:
                continue
    return _stored_config(recordings)


def _response_units(summary: dict[str, Any], config_text: str, recordings: list[Recording]) -> tuple[str, str] | None:
    """Output and input units of the plant response: ``identify``'s data units, else the run's output channel (the
    configuration's ``[identification] output``) and torque channel as its identification recording stores them."""
    import tomllib

    units = summary.get("data", {}).get("units") if isinstance(summary.get("data"), dict) else None
    if isinstance(units, dict) and units.get("output") and units.get("torque"):
        return str(units["output"]), str(units["torque"])
    try:
        output = tomllib.loads(config_text).get("identification", {}).get("output", "velocity_mps")
    except (tomllib.TOMLDecodeError, AttributeError):
        return None
    for rec in recordings:
        if rec.in_folder and rec.attrs.get("experiment") == "identification":
            channels = dict(
                zip(rec.attrs.get("channel_names") or [], rec.attrs.get("channel_units") or [], strict=False)
            )
            if channels.get(output) and channels.get("torque_nm"):
                return str(channels[output]), str(channels["torque_nm"])
    return None


def _versions() -> dict[str, str]:
    out = {}
    for name in ("hilident", "numpy", "scipy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def gather(folder: str | os.PathLike) -> ReportInputs:
    """Read what the report of ``folder`` shows.

    Raises
    ------
    UsageError
        No ``summary.json`` in ``folder``.
    DataError
        ``summary.json`` cannot be read.
    """
    folder = Path(folder)
    summary = read_summary(folder)
    mtime = (folder / "summary.json").stat().st_mtime
    when = _dt.datetime.fromtimestamp(mtime, _dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    recordings = [_recording(p, p.name, True) for p in sorted(folder.glob("*.h5"))]
    data = summary.get("data")
    if isinstance(data, dict) and isinstance(data.get("file"), str):
        path = Path(data["file"])
        if path.suffix.lower() in (".h5", ".hdf5") and path.is_file() and path.parent.resolve() != folder.resolve():
            recordings.append(_recording(path, str(path), False))
    pngs = sorted(folder.glob("*.png"))
    stale = [p.name for p in pngs if p.stat().st_mtime < mtime - STALE_PLOT_S]
    images = [(p.name, p.read_bytes()) for p in pngs if p.name not in stale]
    text, origin = _config(summary, folder, recordings)
    return ReportInputs(
        folder,
        summary,
        when,
        text,
        origin,
        images,
        stale,
        recordings,
        _versions(),
        _response_units(summary, text, recordings),
    )
