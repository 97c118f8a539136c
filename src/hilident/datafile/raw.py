"""Columns as a reader returns them, and what every reader shares: the memory bound and one-line messages.

Every size a file declares is checked against :data:`MAX_DATA_BYTES` (at
most half the physical memory) and, for HDF5 datasets, against the bytes
the file really stores, before a byte of data is read.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hilident.errors import DataError

#: Most bytes of float64 samples read from one file (further capped at half the physical memory).
MAX_DATA_BYTES = 2 * 1024**3

#: Largest ratio of declared to stored bytes accepted from a compressed HDF5 dataset.
MAX_COMPRESSION_RATIO = 1000

#: Column names quoted in an error message before the list is cut short.
_LISTED_NAMES = 20

#: Formats ``[data] format = "auto"`` tells from the extension.
FORMAT_OF_SUFFIX = {
    ".h5": "hilident",
    ".hdf5": "hilident",
    ".csv": "csv",
    ".txt": "csv",
    ".dat": "csv",
    ".tsv": "csv",
    ".mat": "mat",
}


@dataclass
class RawColumns:
    """Columns read from a file before they are mapped.

    Attributes
    ----------
    columns : dict of str to ndarray
        The requested columns the file has (float64, 1-D).
    available : list of str
        Every column (or variable) name in the file.
    sample_rate_hz : float or None
        Rate the file records (hilident files).
    status, reason : str or None
        How a hilident recording was closed.
    period_samples : int or None
        Excitation period of a hilident recording, when its configuration says.
    notes : list of str
    """

    columns: dict[str, np.ndarray]
    available: list[str]
    sample_rate_hz: float | None = None
    status: str | None = None
    reason: str = ""
    period_samples: int | None = None
    flushed_samples: int | None = None
    notes: list[str] = field(default_factory=list)
    underruns: int = 0

    @property
    def indexed(self) -> bool:
        """True when the rows carry their own ``sample_index``."""
        return "sample_index" in self.columns


def memory_limit_bytes() -> int:
    """Bytes of samples one file may bring into memory: :data:`MAX_DATA_BYTES`, at most half the RAM."""
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        physical = 0
    return int(min(MAX_DATA_BYTES, physical // 2)) if physical > 0 else int(MAX_DATA_BYTES)


def _gib(n: float) -> str:
    return f"{n / 1024**3:.3g} GiB"


def check_fits(path: Path, rows: int, columns: int, what: str, verb: str = "declares") -> None:
    """Refuse before allocating ``rows`` x ``columns`` float64 samples beyond the memory bound."""
    need = int(rows) * int(columns) * 8
    limit = memory_limit_bytes()
    if need > limit:
        raise DataError(
            f"{path}: {what} {verb} {rows} rows of {columns} column(s) ({_gib(need)} as float64), "
            f"more than the {_gib(limit)} hilident reads into memory"
        )


def listed_names(names) -> str:
    """Names read from a file, for a one-line message: few, short, and control characters escaped."""
    names = sorted(str(n) for n in names)
    if not names:
        return "none"
    more = len(names) - _LISTED_NAMES
    shown = [n if n.isprintable() and len(n) <= 40 else short(n) for n in names[:_LISTED_NAMES]]
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def exception_text(exc: BaseException, limit: int = 200) -> str:
    """A library's exception as part of one line: type, message, no line breaks, bounded length."""
    text = " ".join(str(exc).split())
    if len(text) > limit:
        text = text[:limit] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def short(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[:limit] + "...")


def open_h5(path: Path):
    import h5py

    try:
        # locking=False: a writer in another process may hold the file while streaming.
        return h5py.File(path, "r", locking=False)
    except OSError:
        try:
            return h5py.File(path, "r")
        except OSError as exc:
            raise DataError(f"{path}: not a readable HDF5 file ({exception_text(exc)})") from None


def check_stored(path: Path, ds, rows: int, what: str) -> None:
    """Refuse a dataset whose first ``rows`` rows its file cannot hold (they would read back as zeros)."""
    cols = math.prod(ds.shape[1:]) if ds.ndim > 1 else 1
    need = int(rows) * int(cols) * ds.dtype.itemsize
    if need == 0:
        return
    stored = ds.id.get_storage_size()
    size = path.stat().st_size
    if ds.compression is None and (need > stored or need > size):
        raise DataError(
            f"{path}: {what} declares {rows} rows ({need} bytes) but the file holds only "
            f"{min(stored, size)} bytes of them: damaged or truncated"
        )
    if ds.compression is not None and need > MAX_COMPRESSION_RATIO * max(stored, 1):
        raise DataError(
            f"{path}: {what} declares {rows} rows ({need} bytes) from {stored} stored bytes: damaged or hostile file"
        )
