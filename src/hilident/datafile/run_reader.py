"""hilident run files (HDF5): the recorded channels, how the run ended, its excitation period and its attributes."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilident.datafile.raw import (
    FORMAT_OF_SUFFIX,
    RawColumns,
    check_fits,
    check_stored,
    exception_text,
    open_h5,
)
from hilident.errors import ConfigError, DataError, HilidentError


def _attr_text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.generic):
        return str(value.item())
    return str(value)


def read_hilident(path: Path, names, check=lambda available: None) -> RawColumns:
    import h5py

    from hilident.io.recording import FORMAT, FORMAT_VERSION

    if not h5py.is_hdf5(path):
        raise DataError(f"{path}: not an HDF5 file, so not a hilident run file")
    with open_h5(path) as f:
        try:
            return _read_hilident_open(path, f, names, FORMAT, FORMAT_VERSION, check)
        except (DataError, ConfigError):
            raise
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged hilident run file ({exception_text(exc)})") from None


def _read_hilident_open(path: Path, f, names, fmt: str, version: int, check) -> RawColumns:
    attrs = f.attrs
    _check_format(path, attrs, fmt, version)
    channels = [_attr_text(c) for c in np.atleast_1d(attrs.get("channel_names", []))]
    ds = _samples(path, f, channels)
    check(channels)
    notes: list[str] = []
    rows, flushed = _counted_rows(path, attrs, int(ds.shape[0]), notes)
    wanted = [n for n in (names if names is not None else channels) if n in channels]
    for extra in ("sample_index", "excitation"):  # row numbers; the played excitation proves the period
        if extra in channels and extra not in wanted:
            wanted.append(extra)
    check_fits(path, rows, len(wanted), "/samples")
    check_stored(path, ds, rows, "/samples")
    rate = float(attrs.get("sample_rate_hz", math.nan))
    if not math.isfinite(rate) or rate <= 0:
        raise DataError(f"{path}: sample_rate_hz attribute is {rate!r}; it must be a positive finite number")
    columns = _read_rows(ds, rows, [channels.index(n) for n in wanted])
    status = _attr_text(attrs.get("status", "running"))
    reason = _attr_text(attrs.get("reason", ""))
    period, why = _recorded_period(attrs, rate)
    if why:
        notes.append(f"{path.name}: {why}")
    return RawColumns(
        dict(zip(wanted, columns, strict=False)),
        channels,
        rate,
        status,
        reason,
        period,
        flushed,
        notes,
        _recorded_underruns(attrs),
    )


def _check_format(path: Path, attrs, fmt: str, version: int) -> None:
    """Refuse a file whose root attributes do not name this format and version."""
    if _attr_text(attrs.get("format", "")) != fmt:
        raise DataError(f"{path}: not a hilident run file (root attribute format != {fmt!r})")
    if _attr_text(attrs.get("format_version", "")) != str(version):
        raise DataError(
            f"{path}: unsupported hilident run format_version "
            f"{_attr_text(attrs.get('format_version', ''))!r} (this reader: {version})"
        )


def _samples(path: Path, f, channels: list[str]):
    """The ``/samples`` dataset: two-dimensional floats with one column per channel."""
    import h5py

    ds = f.get("samples")
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 2 or ds.shape[1] != len(channels) or ds.dtype.kind != "f":
        raise DataError(f"{path}: damaged run file: /samples does not match channel_names")
    return ds


def _counted_rows(path: Path, attrs, rows: int, notes: list[str]) -> tuple[int, int | None]:
    """Rows counted as recorded (none after the last flushed sample) and ``flushed_samples`` when recorded."""
    if "flushed_samples" not in attrs:
        return rows, None
    flushed = int(attrs["flushed_samples"])
    if flushed < 0:
        raise DataError(f"{path}: damaged run file: flushed_samples = {flushed}")
    if flushed < rows:
        notes.append(
            f"{path.name}: {rows - flushed} rows after the last flushed sample ({flushed}) were not counted as recorded"
        )
    return min(rows, flushed), flushed


def _recorded_underruns(attrs) -> int:
    """Samples the device played with no excitation left (``stream_json`` ``underruns``; 0 when not recorded)."""
    import json

    try:
        value = json.loads(_attr_text(attrs.get("stream_json", "{}"))).get("underruns", 0)
        return int(value) if isinstance(value, (int, float)) and value > 0 else 0
    except (ValueError, AttributeError, OverflowError):
        return 0


def _read_rows(ds, rows: int, cols: list[int], block: int = 1 << 16) -> list[np.ndarray]:
    """Columns ``cols`` of the first ``rows`` rows, read a block of rows at a time."""
    out = [np.empty(rows) for _ in cols]
    for a in range(0, rows, block):
        b = min(a + block, rows)
        part = ds[a:b, :]
        for arr, j in zip(out, cols, strict=False):
            arr[a:b] = part[:, j]
    return out


def _recorded_period(attrs, rate: float) -> tuple[int | None, str]:
    """Excitation period of a hilident recording, and a note when it cannot be told.

    A ``period_samples`` root attribute wins; else the period follows from
    the configuration the run stored (``config_toml``) for the
    identification and verification runs, which play the excitation.
    """
    if "period_samples" in attrs:
        period = int(attrs["period_samples"])
        return (period, "") if period > 0 else (None, "")
    experiment = _attr_text(attrs.get("experiment", ""))
    if experiment not in ("identification", "verification"):
        return None, ""
    text = _attr_text(attrs.get("config_toml", ""))
    if not text.strip():
        return None, "no stored configuration: the excitation period is unknown"
    from hilident.config.tables import parse_config
    from hilident.pipeline.selection import excitation_period_samples

    try:
        return excitation_period_samples(parse_config(text, "config_toml attribute").excitation, rate), ""
    except HilidentError as exc:
        return None, (
            f"the stored configuration cannot be read ({exception_text(exc)}); the excitation period is unknown"
        )


@dataclass
class RunInfo:
    """What a hilident run file says about the run that recorded it.

    Attributes
    ----------
    config_toml : str
        The run's configuration (TOML text; empty when not stored).
    config_source : str
        Where that configuration was loaded from.
    experiment : str
        ``identification``, ``verification``, ``friction``, ...
    mode : str
        Where the excitation entered (``torque``, ``torque_injection``, ``velocity``, ``position``).
    channels, units : list of str
        Recorded channels and their units.
    period_samples : int or None
        Excitation period recorded with the run.
    sample_rate_hz : float
    """

    config_toml: str
    config_source: str
    experiment: str
    mode: str
    channels: list[str]
    units: list[str]
    period_samples: int | None
    sample_rate_hz: float


def read_run_info(path: str | Path, fmt: str = "auto") -> RunInfo | None:
    """The run attributes of a hilident run file; None when ``path`` is not one (CSV, MATLAB, other HDF5).

    Raises
    ------
    DataError
        The file says it is a hilident run file but cannot be read.
    """
    import h5py

    path = Path(path)
    kind = fmt if fmt != "auto" else FORMAT_OF_SUFFIX.get(path.suffix.lower())
    if kind != "hilident" or not path.is_file() or not h5py.is_hdf5(path):
        return None
    from hilident.io.recording import FORMAT

    with open_h5(path) as f:
        try:
            a = f.attrs
            if _attr_text(a.get("format", "")) != FORMAT:
                return None
            channels = [_attr_text(c) for c in np.atleast_1d(a.get("channel_names", []))]
            units = [_attr_text(c) for c in np.atleast_1d(a.get("channel_units", []))]
            period = int(a["period_samples"]) if "period_samples" in a else None
            return RunInfo(
                _attr_text(a.get("config_toml", "")),
                _attr_text(a.get("config_source", "")),
                _attr_text(a.get("experiment", "")),
                _attr_text(a.get("mode", "")),
                channels,
                units,
                period if period and period > 0 else None,
                float(a.get("sample_rate_hz", math.nan)),
            )
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged hilident run file ({exception_text(exc)})") from None
