"""The batch table: ``batch.parquet`` and ``batch.csv`` beside it, one row per recording, written atomically."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from hilident.batch.task import FRICTION_COLUMNS
from hilident.errors import DataError

#: Every column of the table, in order, with its Arrow type (``string``, ``float64``, ``int64``).
COLUMNS: dict[str, str] = {
    "path": "string",
    "content_sha256": "string",
    "config_sha256": "string",
    "status": "string",
    "error": "string",
    "error_type": "string",
    "failed_step": "string",
    "axis": "string",
    "device_name": "string",
    "device_serial": "string",
    "time_utc": "string",
    "time_source": "string",
    "sample_rate_hz": "float64",
    "duration_s": "float64",
    "n_resonances": "int64",
    "frequency_hz": "float64",
    "frequency_ci95_hz": "float64",
    "damping_ratio": "float64",
    "damping_ci95": "float64",
    "resonances_json": "string",
    "friction_model": "string",
    **dict.fromkeys(FRICTION_COLUMNS, "float64"),
    "model_fit_percent": "float64",
    "warnings": "string",
    "n_warnings": "int64",
    "hilident_version": "string",
    "elapsed_s": "float64",
    "worker": "string",
    "worker_peak_rss_mib": "float64",
}
TABLE_NAME = "batch.parquet"
CSV_NAME = "batch.csv"
_EMPTY = {"string": "", "float64": math.nan, "int64": 0}


def _schema():
    import pyarrow as pa

    return pa.schema([(name, getattr(pa, kind)()) for name, kind in COLUMNS.items()])


def _complete(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` with exactly the table's columns (one written by another version may lack some)."""
    out = {}
    for name, kind in COLUMNS.items():
        value = row.get(name)
        out[name] = _EMPTY[kind] if value is None else value
    return out


def read_rows(folder: str | Path) -> list[dict[str, Any]]:
    """The rows of ``folder/batch.parquet`` (none when there is no table yet).

    Raises
    ------
    DataError
        The table is there but cannot be read (the message names it).
    """
    path = Path(folder) / TABLE_NAME
    if not path.exists():
        return []
    import pyarrow.parquet as pq

    try:
        return [_complete(r) for r in pq.read_table(path).to_pylist()]
    except Exception as exc:  # Arrow reports a damaged file as several types
        raise DataError(
            f"{path}: the earlier batch table cannot be read ({type(exc).__name__}: {exc}); move it "
            "away to start a new table"
        ) from None


def _replace(path: Path, write) -> None:
    """Write ``path`` through a temporary file beside it, renamed over it once complete."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_rows(folder: str | Path, rows: list[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``rows`` as ``folder/batch.parquet`` and ``folder/batch.csv``; each file is replaced atomically.

    Returns
    -------
    (Path, Path)
        The Parquet table and the CSV beside it.
    """
    import pyarrow as pa
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pylist([_complete(r) for r in rows], schema=_schema())
    parquet, csv = folder / TABLE_NAME, folder / CSV_NAME
    _replace(parquet, lambda tmp: pq.write_table(table, tmp))
    _replace(csv, lambda tmp: pcsv.write_csv(table, tmp))
    return parquet, csv
