"""Who and when a recording is: its axis, its device and its time stamp, from the file or what surrounds it."""

from __future__ import annotations

import datetime as _dt
import json
import re
from pathlib import Path
from typing import Any

#: An ISO-like stamp in a file name: ``20261124T010203Z``, ``2026-11-24T01-02-03``, ``2026-11-24_01:02:03``.
_NAME_STAMP = re.compile(r"(?<!\d)(\d{4})-?(\d{2})-?(\d{2})[T_ -]?(\d{2})[:-]?(\d{2})[:-]?(\d{2})(?!\d)")


def iso_utc(when: _dt.datetime) -> str:
    """``when`` as an ISO 8601 UTC string with milliseconds (a naive time is taken as UTC)."""
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.UTC)
    return when.astimezone(_dt.UTC).isoformat(timespec="milliseconds")


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if hasattr(value, "item"):  # a numpy scalar
        value = value.item()
    return "" if value is None else str(value)


def _file_attrs(path: Path) -> dict[str, Any]:
    """The root attributes of an HDF5 file (empty for any other file, or one that cannot be read)."""
    if path.suffix.lower() not in (".h5", ".hdf5"):
        return {}
    try:
        import h5py

        with h5py.File(path, "r", locking=False) as f:
            return {key: f.attrs[key] for key in ("axis", "device_json", "device", "created_utc") if key in f.attrs}
    except Exception:  # a damaged file: its identity comes from its name and folder; the analysis says what is wrong
        return {}


def _device(attrs: dict[str, Any]) -> dict[str, Any]:
    for key in ("device_json", "device"):
        try:
            value = json.loads(_text(attrs[key])) if key in attrs else None
        except ValueError:
            value = None
        if isinstance(value, dict):
            return value
    return {}


def _file_time(attrs: dict[str, Any]) -> str:
    try:
        return iso_utc(_dt.datetime.fromisoformat(_text(attrs["created_utc"]).replace("Z", "+00:00")))
    except (KeyError, ValueError):
        return ""


def name_time(name: str) -> str:
    """The time stamp a file name carries (its last ISO-like one, taken as UTC), else ``""``.

    >>> name_time("axis03_20261124T010203Z.h5")
    '2026-11-24T01:02:03.000+00:00'
    """
    for match in reversed(list(_NAME_STAMP.finditer(name))):
        try:
            year, month, day, hour, minute, second = map(int, match.groups())
            return iso_utc(_dt.datetime(year, month, day, hour, minute, second, tzinfo=_dt.UTC))
        except ValueError:  # not a date after all (month 13)
            continue
    return ""


def recording_identity(path: str | Path) -> dict[str, str]:
    """``axis``, ``device_name``, ``device_serial``, ``time_utc`` and ``time_source`` of a recording.

    The axis is the file's ``axis`` attribute, else its device's serial
    number, else its device's name and port as ``NAME@PORT`` (``device_json``
    attribute), else the name of the folder holding it. The time is the file's ``created_utc`` (``time_source``
    ``"file"``), else a stamp in its name (``"name"``), else its modification
    time (``"mtime"``; ``""`` when even that cannot be read).
    """
    path = Path(path)
    attrs = _file_attrs(path)
    device = _device(attrs)
    name, serial = _text(device.get("name")), _text(device.get("serial"))
    port = _text(device.get("port"))
    # a device model alone names no axis (two axes may run the same drive): with its port it does
    connection = f"{name}@{port}" if name and port else ""
    axis = _text(attrs.get("axis")) or serial or connection or path.parent.name or str(path.parent)
    time_utc, source = _file_time(attrs), "file"
    if not time_utc:
        time_utc, source = name_time(path.name), "name"
    if not time_utc:
        try:
            time_utc, source = iso_utc(_dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.UTC)), "mtime"
        except OSError:
            time_utc, source = "", ""
    return {"axis": axis, "device_name": name, "device_serial": serial, "time_utc": time_utc, "time_source": source}
