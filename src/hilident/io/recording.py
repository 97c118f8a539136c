"""HDF5 run files: one file per experiment run, appended while streaming.

A :class:`RunWriter` grows the ``/samples`` dataset block by block and flushes
the file after every block and every event, so memory stays bounded whatever
the run length and a process that dies mid-run leaves a readable file with
everything appended so far (its ``status`` attribute still says
``"running"``). :func:`read_run` reads a file back into a :class:`RunData`.

The file layout is documented in ``docs/recording.md``; in short::

    /                 root attributes: format, format_version, created_utc,
                      sample_rate_hz, channel_names, channel_units, status,
                      reason, n_samples, caller metadata (dicts/lists as *_json)
    /samples          float64 (n_samples, n_channels), chunked, resizable
    /events           compound (sample_index, time_s, kind, message, data)
    /tables/<name>/   one 1-D dataset per column

Examples
--------
>>> import numpy as np
>>> with RunWriter(tmp / "run.h5", ["position", "torque"], ["m", "N*m"], 1000.0) as rec:  # doctest: +SKIP
...     rec.append(np.zeros((100, 2)))
...     rec.event("excitation_start", "chirp 1-200 Hz", sample_index=0)
>>> run = read_run(tmp / "run.h5")  # doctest: +SKIP
>>> run.channel("torque").shape, run.status  # doctest: +SKIP
((100,), 'complete')
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hilident.errors import DataError
from hilident.events import Kind, RunEvent
from hilident.io.serialise import to_jsonable

__all__ = ["FORMAT", "FORMAT_VERSION", "DiskFull", "RunData", "RunWriter", "read_run"]

FORMAT = "hilident-run"
FORMAT_VERSION = 1

#: Root attributes owned by the writer; callers cannot set these through ``attrs``.
RESERVED_ATTRS = frozenset(
    {
        "format",
        "format_version",
        "created_utc",
        "closed_utc",
        "sample_rate_hz",
        "channel_names",
        "channel_units",
        "status",
        "reason",
        "n_samples",
        "flushed_samples",
    }
)
_JSON_SUFFIX = "_json"
_STATUSES = ("running", "complete", "aborted")

_STR = h5py.string_dtype("utf-8")
_EVENT_DTYPE = np.dtype([("sample_index", "<i8"), ("time_s", "<f8"), ("kind", _STR), ("message", _STR), ("data", _STR)])


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def _utc_text(when: _dt.datetime, path: Path) -> str:
    """``when`` as :func:`_utc_now` writes a time; a naive datetime is refused (its zone is unknown)."""
    if not isinstance(when, _dt.datetime) or when.utcoffset() is None:
        raise DataError(f"{path}: created_utc must be a timezone-aware datetime, got {when!r}")
    return when.astimezone(_dt.UTC).isoformat(timespec="milliseconds")


def _to_json_text(value: Any, what: str) -> str:
    try:
        return json.dumps(to_jsonable(value), allow_nan=False, ensure_ascii=False)
    except TypeError as exc:
        raise DataError(f"{what}: cannot be stored as JSON: {exc}") from None


def _file_size_limit() -> int | None:
    """The process's file size limit (``ulimit -f``), bytes, or None when there is none."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        return None if soft == resource.RLIM_INFINITY else int(soft)
    except (ImportError, OSError, ValueError):
        return None


def _file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


_FILE_SIZE_LIMIT = _file_size_limit()


class DiskFull(DataError):
    """The recording could not be written (the disk is full, or another write error); the file keeps its good rows."""


def _chmod_like_umask(path: Path) -> None:
    """Give ``path`` the permissions a plain ``open()`` would (0644 under the usual umask 022)."""
    try:
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(path, 0o666 & ~mask)
    except OSError:
        pass


class RunWriter:
    """Write one run to an HDF5 file while it streams.

    Parameters
    ----------
    path : str or path-like
        File to create; the parent folder is created if needed.
    channels : list of str
        Channel names, one per column of every block, unique.
    units : list of str
        Unit of each channel (SI, e.g. ``"m"``, ``"N*m"``, ``"m/s"``).
    sample_rate_hz : float
        Sample rate, Hz; ``time_s = sample_index / sample_rate_hz``.
    attrs : dict, optional
        Caller metadata stored as root attributes (see :meth:`set_attrs`),
        e.g. ``experiment``, ``seed``, ``config_toml``, ``driver``,
        ``versions`` (a dict), ``device``.
    chunk_rows : int
        Rows per HDF5 chunk of ``/samples``. The default (8192) keeps a chunk
        at 64 KiB per channel.
    compression : {None, "lzf"}
        Compression of ``/samples``. Off by default: because the file is
        flushed after every block, a compressed partial chunk is recompressed
        on every append, which makes small appends about 15x slower for about
        25 % smaller files on noisy sensor data (see ``docs/recording.md``).
    overwrite : bool
        Replace an existing file instead of raising :class:`DataError`.
    created_utc : datetime.datetime, optional
        The time the recording was made, stored as ``created_utc`` in the
        writer's own format (ISO 8601, milliseconds, ``+00:00``); it must be
        timezone-aware. Default: now. For recordings made earlier or
        simulated (``hilident emulate fleet``).

    Notes
    -----
    The status attribute is ``"running"`` from creation until :meth:`close`
    sets ``"complete"`` or ``"aborted"``. Used as a context manager, an
    exception leaving the block closes the run as ``"aborted"`` with the
    exception's message as reason (the exception still propagates).

    The writer keeps no samples in memory: each block goes straight to the
    file. It is not thread-safe; call it from the thread that streams.

    Examples
    --------
    >>> with RunWriter("run.h5", ["x", "u"], ["m", "N*m"], 1000.0, attrs={"seed": 1}) as rec:  # doctest: +SKIP
    ...     for block in stream:
    ...         rec.append(block)
    """

    def __init__(
        self,
        path: str | os.PathLike,
        channels: list[str],
        units: list[str],
        sample_rate_hz: float,
        attrs: dict[str, Any] | None = None,
        chunk_rows: int = 8192,
        *,
        compression: str | None = None,
        overwrite: bool = False,
        created_utc: _dt.datetime | None = None,
    ):
        self._path = Path(path)
        created = _utc_now() if created_utc is None else _utc_text(created_utc, self._path)
        self._file: h5py.File | None = None
        channels, units, rate = self._checked_layout(channels, units, sample_rate_hz, chunk_rows, compression)
        if self._path.exists() and not overwrite:
            raise DataError(f"{self._path}: file exists; choose another path or pass overwrite=True")
        if attrs is not None:
            self._check_attr_keys(attrs)

        self._channels = channels
        self._failure: str | None = None
        self._margin_bytes = 2 * int(chunk_rows) * len(channels) * 8 + (1 << 20)
        self._rate = rate
        self._n_channels = len(channels)
        chunk_bytes = int(chunk_rows) * self._n_channels * 8
        self._path.parent.mkdir(parents=True, exist_ok=True)
        try:
            # Default (earliest) file format on purpose: a file left open by a
            # crashed process opens again with any HDF5 reader, which is not
            # true for libver="latest" (see docs/recording.md, SWMR).
            f = h5py.File(self._path, "w", rdcc_nbytes=max(1 << 20, 4 * chunk_bytes))
        except OSError as exc:
            raise DataError(f"{self._path}: cannot create run file: {exc}") from None
        self._file = f
        try:
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = np.int64(FORMAT_VERSION)
            f.attrs["created_utc"] = created
            f.attrs["sample_rate_hz"] = np.float64(rate)
            f.attrs.create("channel_names", np.array(channels, dtype=object), dtype=_STR)
            f.attrs.create("channel_units", np.array(units, dtype=object), dtype=_STR)
            f.attrs["status"] = "running"
            f.attrs["reason"] = ""
            f.attrs["flushed_samples"] = np.int64(0)
            self._samples = f.create_dataset(
                "samples",
                shape=(0, self._n_channels),
                maxshape=(None, self._n_channels),
                chunks=(int(chunk_rows), self._n_channels),
                dtype="<f8",
                compression=compression,
            )
            self._events = f.create_dataset("events", shape=(0,), maxshape=(None,), chunks=(256,), dtype=_EVENT_DTYPE)
            if attrs:
                self.set_attrs(**attrs)
            f.flush()
        except BaseException:
            f.close()
            self._file = None
            raise
        self._n_samples = 0

    def _checked_layout(
        self, channels, units, sample_rate_hz, chunk_rows, compression
    ) -> tuple[list[str], list[str], float]:
        """Channels, units and rate as lists and a float, or a :class:`DataError` naming the file and the value."""
        channels = list(channels)
        units = list(units)
        if not channels or not all(isinstance(c, str) and c for c in channels):
            raise DataError(f"{self._path}: channels must be a non-empty list of non-empty names, got {channels!r}")
        if len(set(channels)) != len(channels):
            raise DataError(f"{self._path}: channel names must be unique, got {channels!r}")
        if len(units) != len(channels) or not all(isinstance(u, str) for u in units):
            raise DataError(f"{self._path}: units must be {len(channels)} strings (one per channel), got {units!r}")
        try:
            rate = float(sample_rate_hz)
        except (TypeError, ValueError):
            rate = math.nan
        if not (math.isfinite(rate) and rate > 0):
            raise DataError(f"{self._path}: sample_rate_hz must be a positive finite number, got {sample_rate_hz!r}")
        if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, (int, np.integer)) or chunk_rows < 1:
            raise DataError(f"{self._path}: chunk_rows must be a positive integer, got {chunk_rows!r}")
        if compression not in (None, "lzf"):
            raise DataError(f"{self._path}: compression must be None or 'lzf', got {compression!r}")
        return channels, units, rate

    # ------------------------------------------------------------------ properties

    @property
    def path(self) -> Path:
        """The run file."""
        return self._path

    @property
    def n_samples(self) -> int:
        """Rows appended so far."""
        return self._n_samples

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._file is None

    def _open_file(self) -> h5py.File:
        if self._file is None:
            raise DataError(f"{self._path}: run file is closed")
        if self._failure is not None:
            raise DataError(f"{self._path}: run file can no longer be written ({self._failure})")
        return self._file

    def _check_space(self, nbytes: int) -> None:
        """Refuse a write the disk cannot take, before HDF5 half-writes it.

        HDF5 allocates whole chunks and metadata on flush; a flush that hits a
        full disk leaves the file's in-memory state unusable (and h5py may then
        crash the interpreter on exit), so the writer keeps a margin free.
        """
        need = nbytes + self._margin_bytes
        try:
            st = os.statvfs(self._path.parent)
        except (OSError, AttributeError):  # no statvfs (Windows): rely on the write error
            return
        free = st.f_bavail * st.f_frsize
        if free < need:
            self._failure = f"disk full: {free / 1e6:.1f} MB free on {self._path.parent}, {need / 1e6:.1f} MB needed"
        elif _FILE_SIZE_LIMIT is not None and _file_size(self._path) + need > _FILE_SIZE_LIMIT:
            self._failure = f"file size limit reached (ulimit -f: {_FILE_SIZE_LIMIT / 1e6:.1f} MB)"
        if self._failure is not None:
            raise DiskFull(f"{self._path}: {self._failure}; the file holds the first {self._n_samples} samples")

    def _write_failed(self, exc: BaseException) -> None:
        """A write to the file failed (full disk, I/O error): keep what is good, raise :class:`DataError`."""
        self._failure = str(exc).split("\n")[0]
        self._discard_unwritten()
        raise DiskFull(
            f"{self._path}: cannot write the recording ({self._failure}); the file holds the first "
            f"{self._n_samples} samples"
        ) from None

    def _discard_unwritten(self) -> None:
        """Shrink /samples back to the rows known good, so no unwritten row is ever read as zeros.

        Only chunks wholly below the last good flush are known to be on disk
        (appends touch the chunk holding the last row, and a failed flush may
        have lost it), so the file is cut to them; if even that cannot be
        flushed, to nothing. The first that flushes leaves a file that closes
        cleanly.
        """
        f = self._file
        if f is None:  # closed already: nothing left to cut
            return
        chunk = self._samples.chunks[0]
        boundary = self._n_samples // chunk * chunk
        # HDF5 may rewrite the chunk at the new edge from its damaged cache: keep that one out of the good rows too
        for rows, good in ((boundary, max(0, boundary - chunk)), (0, 0)):
            try:
                self._samples.resize(rows, axis=0)
                f.attrs["flushed_samples"] = np.int64(good)
                f.flush()
                self._n_samples = good
                return
            except (OSError, RuntimeError):
                continue

    # ------------------------------------------------------------------ writing

    def append(self, block: Any) -> None:
        """Append ``block`` (n_rows, n_channels) to ``/samples`` and flush.

        Parameters
        ----------
        block : array_like
            Real numbers, one column per channel in the order given at
            creation. NaN is stored as is. Zero rows is allowed (no-op).

        Raises
        ------
        DataError
            If ``block`` is not 2-D with ``n_channels`` columns of real numbers,
            or the file is closed.
        """
        f = self._open_file()
        arr = np.asarray(block)
        if arr.ndim != 2 or arr.shape[1] != self._n_channels:
            raise DataError(
                f"{self._path}: block must have shape (n_rows, {self._n_channels}) for channels "
                f"{self._channels}, got shape {arr.shape}"
            )
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer) or arr.dtype == np.bool_):
            raise DataError(f"{self._path}: block must hold real numbers, got dtype {arr.dtype}")
        n = arr.shape[0]
        if n == 0:
            return
        self._check_space(arr.shape[0] * self._n_channels * 8)
        start = self._n_samples
        try:
            self._samples.resize(start + n, axis=0)
            self._samples[start : start + n] = arr.astype("<f8", copy=False)
            f.attrs["flushed_samples"] = np.int64(start + n)
            f.flush()
        except (OSError, RuntimeError) as exc:
            self._write_failed(exc)
        self._n_samples = start + n

    def event(self, kind: str, message: str, sample_index: int = -1, **fields: Any) -> None:
        """Append an event to ``/events`` and flush.

        Parameters
        ----------
        kind : str
            Short machine-readable tag, e.g. ``"excitation_start"``, ``"limit_trip"``.
        message : str
            Human-readable text.
        sample_index : int
            Sample the event refers to. ``-1`` (default) means "now": the
            index of the next sample to be appended, i.e. :attr:`n_samples`.
        **fields
            Extra data, stored as a JSON object in the ``data`` column
            (numpy values, complex, NaN are converted as by
            :func:`hilident.io.serialise.to_jsonable`).

        Raises
        ------
        DataError
            On an empty ``kind``, a ``sample_index`` below -1, fields that
            cannot be JSON, or a closed file.
        """
        f = self._open_file()
        if not isinstance(kind, str) or not kind:
            raise DataError(f"{self._path}: event kind must be a non-empty string, got {kind!r}")
        if isinstance(sample_index, bool) or not isinstance(sample_index, (int, np.integer)) or sample_index < -1:
            raise DataError(f"{self._path}: event sample_index must be an integer >= -1, got {sample_index!r}")
        index = self._n_samples if sample_index == -1 else int(sample_index)
        data = _to_json_text(fields, f"{self._path}: event {kind!r} fields")
        row = np.array([(index, index / self._rate, kind, str(message), data)], dtype=_EVENT_DTYPE)
        self._check_space(4096)
        n = self._events.shape[0]
        try:
            self._events.resize(n + 1, axis=0)
            self._events[n : n + 1] = row
            f.flush()
        except (OSError, RuntimeError) as exc:
            self._write_failed(exc)

    def log(self, event: RunEvent) -> None:
        """Append a run event of the shared vocabulary (:class:`hilident.events.RunEvent`) to ``/events``.

        Its ``kind``, ``message`` and ``sample_index`` go to their columns, the
        other fields that are set to the ``data`` column (as :meth:`event`).
        """
        self.event(Kind(event.kind).value, event.message, int(event.sample_index), **event.extra)

    def write_table(self, name: str, **columns: Any) -> None:
        """Write a small table as ``/tables/<name>``, one 1-D dataset per column.

        For results computed during the run, e.g. friction test windows or
        steady-state points. Writing a table of the same name again replaces it.

        Parameters
        ----------
        name : str
            Table name (no ``/``).
        **columns : array_like
            Column name to 1-D values, all of one length; numbers, booleans or
            strings.

        Raises
        ------
        DataError
            On a bad name, no columns, columns that are not 1-D, of unequal
            length or of unsupported type, or a closed file.
        """
        f = self._open_file()
        if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
            raise DataError(f"{self._path}: table name must be a non-empty string without '/', got {name!r}")
        if not columns:
            raise DataError(f"{self._path}: table {name!r} has no columns")
        arrays: dict[str, np.ndarray] = {}
        for col, values in columns.items():
            arr = np.asarray(values)
            if arr.ndim != 1:
                raise DataError(f"{self._path}: table {name!r} column {col!r} must be 1-D, got shape {arr.shape}")
            if arr.dtype.kind in "US" or (arr.dtype == object and all(isinstance(v, str) for v in arr)):
                arr = np.array([str(v) for v in arr], dtype=object)
            elif arr.dtype.kind not in "biuf":
                raise DataError(
                    f"{self._path}: table {name!r} column {col!r} must hold numbers, booleans or "
                    f"strings, got dtype {arr.dtype}"
                )
            arrays[col] = arr
        lengths = {col: a.shape[0] for col, a in arrays.items()}
        if len(set(lengths.values())) > 1:
            raise DataError(f"{self._path}: table {name!r} columns differ in length: {lengths}")
        tables = f.require_group("tables")
        if name in tables:
            del tables[name]
        group = tables.create_group(name, track_order=True)
        for col, arr in arrays.items():
            if arr.dtype == object:
                group.create_dataset(col, data=arr, dtype=_STR)
            else:
                group.create_dataset(col, data=arr)
        f.flush()

    def set_attrs(self, **attrs: Any) -> None:
        """Set root attributes.

        ``str``, ``bool``, ``int`` and ``float`` (and numpy scalars) are
        stored as they are. Everything else (dicts, lists, tuples, arrays,
        ``None``) is stored as a JSON string under the key with ``_json``
        appended; :func:`read_run` decodes it back under the plain key.
        Setting a key again replaces it, whatever its previous form.

        Raises
        ------
        DataError
            For a key owned by the writer (``status``, ``n_samples``, ...), a
            key ending in ``_json``, a value that cannot be JSON, or a closed
            file.
        """
        f = self._open_file()
        self._check_attr_keys(attrs)
        for key, value in attrs.items():
            if isinstance(value, np.generic) and value.dtype.kind in "biuf":
                value = value.item()
            if isinstance(value, (str, bool, int, float)):
                plain, stored = key, value
                other = key + _JSON_SUFFIX
            else:
                plain, stored = key + _JSON_SUFFIX, _to_json_text(value, f"{self._path}: attribute {key!r}")
                other = key
            if other in f.attrs:
                del f.attrs[other]
            f.attrs[plain] = stored
        f.flush()

    def _check_attr_keys(self, attrs: dict[str, Any]) -> None:
        for key in attrs:
            if not isinstance(key, str) or not key:
                raise DataError(f"{self._path}: attribute names must be non-empty strings, got {key!r}")
            if key in RESERVED_ATTRS:
                raise DataError(f"{self._path}: attribute {key!r} is set by the writer and cannot be given")
            if key.endswith(_JSON_SUFFIX):
                raise DataError(
                    f"{self._path}: attribute {key!r} must not end in '{_JSON_SUFFIX}' "
                    "(that suffix marks JSON-encoded values; pass the plain name and a dict/list)"
                )

    # ------------------------------------------------------------------ closing

    def close(self, status: str = "complete", reason: str = "", *, closed_utc: _dt.datetime | None = None) -> None:
        """Write ``status``, ``reason`` and ``n_samples`` and close the file.

        Parameters
        ----------
        status : {"complete", "aborted"}
        reason : str
            Why the run was aborted (empty for a complete run).
        closed_utc : datetime.datetime, optional
            The time the recording ended (timezone-aware), as ``created_utc``
            at creation; default: now.

        Closing twice does nothing the second time.
        """
        if status not in ("complete", "aborted"):
            raise DataError(f"{self._path}: close status must be 'complete' or 'aborted', got {status!r}")
        f = self._file
        if f is None:
            return
        closed = _utc_now() if closed_utc is None else _utc_text(closed_utc, self._path)
        if self._failure is not None:
            status, reason = "aborted", reason or self._failure
        try:
            f.attrs["status"] = status
            f.attrs["reason"] = str(reason)
            f.attrs["n_samples"] = np.int64(self._n_samples)
            f.attrs["closed_utc"] = closed
            f.flush()
        except (OSError, RuntimeError) as exc:
            if self._failure is None:
                self._failure = str(exc).split("\n")[0]
            self._discard_unwritten()
        finally:
            self._file = None
            try:
                f.close()
            except (OSError, RuntimeError):
                pass
            _chmod_like_umask(self._path)

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.close("complete")
        else:
            self.close("aborted", str(exc) or exc_type.__name__)

    def __repr__(self) -> str:
        state = "closed" if self.closed else "open"
        return f"RunWriter({str(self._path)!r}, channels={self._channels}, n_samples={self._n_samples}, {state})"


# ---------------------------------------------------------------------- reading


@dataclass
class RunData:
    """A run read back from its HDF5 file.

    Attributes
    ----------
    path : pathlib.Path
        The file read.
    samples : dict of str to ndarray
        Channel name to its samples (float64, 1-D), in channel order.
    units : dict of str to str
        Channel name to unit.
    sample_rate_hz : float
        Sample rate, Hz.
    attrs : dict
        All root attributes, JSON attributes decoded under their plain key
        (``versions_json`` -> ``attrs["versions"]``), string arrays as lists.
    events : list of dict
        ``{"sample_index", "time_s", "kind", "message", "data"}`` per event,
        ``data`` a dict.
    tables : dict of str to dict of str to ndarray
        Table name to column name to values.
    status : str
        ``"complete"``, ``"aborted"``, or ``"running"`` when the writing
        process ended without closing the file (or is still writing).
    reason : str
        Why the run was aborted, else empty.
    """

    path: Path
    samples: dict[str, np.ndarray]
    units: dict[str, str]
    sample_rate_hz: float
    attrs: dict[str, Any] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    status: str = "complete"
    reason: str = ""

    @property
    def complete(self) -> bool:
        """True only if the writer closed the run as ``"complete"``."""
        return self.status == "complete"

    @property
    def channel_names(self) -> list[str]:
        return list(self.samples)

    @property
    def n_samples(self) -> int:
        """Rows in the file (also for a run that did not complete)."""
        return next(iter(self.samples.values())).shape[0] if self.samples else 0

    @property
    def time_s(self) -> np.ndarray:
        """Time of each sample, ``arange(n_samples) / sample_rate_hz``, s."""
        return np.arange(self.n_samples) / self.sample_rate_hz

    def channel(self, name: str) -> np.ndarray:
        """Samples of channel ``name``.

        Raises
        ------
        DataError
            If there is no such channel; the message lists the available ones.
        """
        try:
            return self.samples[name]
        except KeyError:
            raise DataError(
                f"{self.path}: no channel {name!r}; available channels: {', '.join(self.samples)}"
            ) from None


def _plain(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OS":
            return [_plain(v) for v in value.tolist()]
        return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def _decode_attrs(raw: h5py.AttributeManager, path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in raw:
        value = _plain(raw[key])
        if key.endswith(_JSON_SUFFIX) and isinstance(value, str):
            try:
                out[key[: -len(_JSON_SUFFIX)]] = json.loads(value)
                continue
            except json.JSONDecodeError as exc:
                raise DataError(f"{path}: attribute {key!r} is not valid JSON: {exc}") from None
        out[key] = value
    return out


def _read_column(ds: h5py.Dataset) -> np.ndarray:
    if h5py.check_string_dtype(ds.dtype) is not None:
        return np.array(ds.asstr()[()], dtype=str)
    return ds[()]


#: Largest /samples a reader loads (values); beyond it the file is refused rather than exhausting memory.
MAX_READ_VALUES = 1 << 28


def _check_declared_size(dataset: h5py.Dataset, rows: int, path: Path) -> None:
    """Refuse a /samples whose declared size the file cannot hold or memory cannot take."""
    values = rows * max(1, dataset.shape[1])
    if values > MAX_READ_VALUES:
        raise DataError(
            f"{path}: /samples declares {rows} rows x {dataset.shape[1]} channels, more than this "
            f"reader loads ({MAX_READ_VALUES} values); split the recording"
        )
    if dataset.compression is None:
        stored = dataset.id.get_storage_size()
        slack = dataset.chunks[0] * dataset.shape[1] * 8 if dataset.chunks else 0
        if values * 8 > stored + slack:
            raise DataError(
                f"{path}: damaged run file: /samples declares {rows} rows but the file stores "
                f"only {stored} bytes of them"
            )


def _read_open_file(f: h5py.File, path: Path) -> RunData:
    if _plain(f.attrs.get("format")) != FORMAT:
        raise DataError(f"{path}: not a hilident run file (root attribute format != {FORMAT!r})")
    version = _plain(f.attrs.get("format_version"))
    if version != FORMAT_VERSION:
        raise DataError(f"{path}: unsupported hilident run format_version {version!r} (this reader: {FORMAT_VERSION})")
    attrs = _decode_attrs(f.attrs, path)
    names = list(attrs.get("channel_names", []))
    units = list(attrs.get("channel_units", []))
    if "samples" not in f or len(names) != len(units) or f["samples"].shape[1:] != (len(names),):
        raise DataError(f"{path}: damaged run file: /samples does not match channel_names/channel_units")
    dataset = f["samples"]
    rows = dataset.shape[0]
    if "flushed_samples" in attrs:  # rows past the last good flush were never written
        rows = min(rows, max(0, int(attrs["flushed_samples"])))
    _check_declared_size(dataset, rows, path)
    data = dataset[:rows]
    samples = {name: np.ascontiguousarray(data[:, i]) for i, name in enumerate(names)}
    del data

    events = []
    if "events" in f:
        for row in f["events"][()]:
            text = _plain(row["data"])
            events.append(
                {
                    "sample_index": int(row["sample_index"]),
                    "time_s": float(row["time_s"]),
                    "kind": _plain(row["kind"]),
                    "message": _plain(row["message"]),
                    "data": json.loads(text) if text else {},
                }
            )
    tables: dict[str, dict[str, np.ndarray]] = {}
    if "tables" in f:
        for tname, group in f["tables"].items():
            tables[tname] = {col: _read_column(ds) for col, ds in group.items()}

    status = str(attrs.get("status", "running"))
    return RunData(
        path=path,
        samples=samples,
        units=dict(zip(names, units, strict=False)),
        sample_rate_hz=float(attrs["sample_rate_hz"]),
        attrs=attrs,
        events=events,
        tables=tables,
        status=status,
        reason=str(attrs.get("reason", "")),
    )


def _open_for_reading(path: Path) -> h5py.File:
    try:
        # locking=False: a writer in another process holds an exclusive lock while streaming.
        return h5py.File(path, "r", locking=False)
    except OSError:
        # The file is open in this process (HDF5 then requires the same locking
        # flag as the open handle) or the lock-free open failed otherwise.
        return h5py.File(path, "r")


def read_run(path: str | os.PathLike, *, require_complete: bool = False, retries: int = 3) -> RunData:
    """Read a run file written by :class:`RunWriter`.

    Works on a file whose writer died (``status == "running"``, all rows
    flushed before the crash are there) and, without taking a file lock, on
    a file still being written; such a read sees the rows of the last flush.

    Parameters
    ----------
    path : str or path-like
        The ``.h5`` run file.
    require_complete : bool
        Raise :class:`DataError` unless the run was closed as ``"complete"``.
    retries : int
        Attempts when reading a file that is being written fails on a
        half-written block (the writer's next flush repairs it).

    Returns
    -------
    RunData

    Raises
    ------
    DataError
        If the file is missing, not HDF5, not a hilident run, damaged, or
        (with ``require_complete``) not complete.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: run file not found")
    if not h5py.is_hdf5(path):
        raise DataError(f"{path}: not an HDF5 file, so not a hilident run file")
    attempts = max(1, int(retries))
    for attempt in range(attempts):
        try:
            with _open_for_reading(path) as f:
                run = _read_open_file(f, path)
            break
        except DataError:
            raise
        except (OSError, KeyError, ValueError, RuntimeError) as exc:
            if attempt + 1 == attempts:
                raise DataError(f"{path}: cannot read run file: {exc}") from None
            time.sleep(0.05)
    if require_complete and not run.complete:
        detail = (
            "the recording process ended without closing the file, or is still writing"
            if run.status == "running"
            else run.reason or "no reason recorded"
        )
        raise DataError(f"{path}: run did not complete (status {run.status!r}: {detail})")
    return run
