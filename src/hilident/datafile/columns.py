"""Columns read from any supported file by name, and the constant-velocity windows of a friction test."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilident.datafile.csv_reader import read_csv
from hilident.datafile.mat_reader import read_mat
from hilident.datafile.raw import (
    FORMAT_OF_SUFFIX,
    RawColumns,
    exception_text,
    listed_names,
    open_h5,
)
from hilident.datafile.run_reader import read_hilident
from hilident.errors import ConfigError, DataError


def read_columns(path: str | Path, fmt: str = "auto", names=None, column_names=()) -> RawColumns:
    """The columns ``names`` of a file (all numeric ones when None), and what the file says about itself.

    Parameters
    ----------
    path : str or path-like
    fmt : {"auto", "hilident", "csv", "mat"}
        ``auto`` goes by the extension.
    names : iterable of str or dict of str to str, optional
        Columns (or variables) to read. A dict maps each name to the
        configuration key that asked for it: then a name the file lacks is a
        :class:`DataError` naming that key, raised before any data is read;
        otherwise names the file lacks are left out. In a CSV file a name
        that is a whole number (``"2"``) is the column at that position,
        counting from 0, unless the file has a column of that name.
    column_names : sequence of str
        Names of the columns of a headerless CSV file (default: their
        positions ``"0"``, ``"1"``, ...). A CSV file is headerless when every
        cell of its first line is a number.

    Raises
    ------
    DataError
        Missing, unreadable, damaged or oversized file.
    ConfigError
        The format cannot be told from the name.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    kind = fmt if fmt != "auto" else FORMAT_OF_SUFFIX.get(path.suffix.lower())
    if kind is None:
        raise ConfigError(
            "data.format",
            f"cannot tell the format of {path.name} from its extension; set "
            '[data] format = "csv" (numeric text, with or without a header row), '
            '"mat" or "hilident"',
            str(path),
        )
    labels = names if isinstance(names, dict) else {}
    wanted = None if names is None else list(dict.fromkeys(names))

    def check(available) -> None:
        for name, label in labels.items():
            if name not in available:
                raise DataError(f"{path}: no column {name!r} ({label}); the file has: {listed_names(available)}")

    try:
        if kind == "hilident":
            return read_hilident(path, wanted, check)
        if kind == "csv":
            return read_csv(path, wanted, check, tuple(column_names))
        return read_mat(path, wanted, check)
    except MemoryError:
        raise DataError(f"{path}: not enough memory to read the data") from None
    except PermissionError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror}") from None


def read_friction_test(path: str | Path) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, float]]]:
    """Velocity (m/s), torque (N·m) and the constant-velocity windows of a hilident friction-test recording.

    The windows (``/tables/windows``: ``start``, ``stop`` on the sample
    clock and the set-point ``velocity_mps``) are turned into row ranges;
    a window with a lost sample is left out, as the run does.

    Raises
    ------
    DataError
        Not a friction-test recording, or a damaged one.
    """
    path = Path(path)
    raw = read_columns(
        path, "hilident", {"sample_index": "sample_index", "velocity_mps": "velocity_mps", "torque_nm": "torque_nm"}
    )
    with open_h5(path) as f:
        try:
            table = f["tables/windows"]
            windows = np.column_stack([np.asarray(table[c][()], float) for c in ("start", "stop", "velocity_mps")])
        except Exception as exc:  # HDF5 reports a missing or damaged table as many types
            raise DataError(f"{path}: no friction-test windows table ({exception_text(exc)})") from None
    if windows.ndim != 2 or windows.shape[1] != 3 or len(windows) > raw.columns["sample_index"].size:
        raise DataError(f"{path}: damaged friction-test windows table")
    rows = {int(i): r for r, i in enumerate(raw.columns["sample_index"].astype(np.int64))}
    kept = []
    for a, b, v in windows:
        a, b = int(a), int(b)
        if a in rows and b - 1 in rows and rows[b - 1] - rows[a] == b - 1 - a:
            kept.append((rows[a], rows[b - 1] + 1, float(v)))
    return raw.columns["velocity_mps"], raw.columns["torque_nm"], kept
