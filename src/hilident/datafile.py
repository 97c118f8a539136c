"""Recordings made elsewhere: hilident HDF5, CSV or MATLAB ``.mat``, mapped onto named signals.

The ``[data]`` table of a configuration says which column (or variable) holds
the torque, velocity, position, output and excitation, how to scale each to SI
units, and the sample rate or the time column. Everything is checked here, so
the numerics downstream only see finite, equally long, gap-free, uniformly
sampled arrays; anything else is a :class:`~hilident.errors.DataError` naming
the file and the column.

Reading is bounded: only the mapped columns are read, CSV in chunks into
arrays sized from the file before anything is allocated, and the sizes an
HDF5 or ``.mat`` file declares are checked against the file and against
:data:`MAX_DATA_BYTES` before a byte of data is read. A hostile or damaged
file is one :class:`DataError`, never a traceback.

Gaps are found, never spliced over: a hilident recording numbers its rows
(``sample_index``), a time column shows a gap as a step of a whole number of
sample periods. :func:`hilident.pipeline.select_gap_free` then keeps whole
gap-free excitation periods (when the recording says its excitation was
periodic) or the longest gap-free stretch.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hilident.config import DataConfig
from hilident.errors import ConfigError, DataError, HilidentError

#: Fewest samples an identification is attempted on.
MIN_SAMPLES = 64

#: Most bytes of float64 samples read from one file (further capped at half the physical memory).
MAX_DATA_BYTES = 2 * 1024**3

#: Lines parsed per CSV chunk.
CSV_CHUNK_LINES = 1 << 16

#: Largest ratio of declared to stored bytes accepted from a compressed HDF5 dataset.
MAX_COMPRESSION_RATIO = 1000

#: Time stamps checked per chunk.
_TIME_CHUNK = 1 << 20

#: Longest header line accepted, characters.
_MAX_HEADER_CHARS = 1 << 20

#: Column names quoted in an error message before the list is cut short.
_LISTED_NAMES = 20

_NUMERIC_MAT_CLASSES = frozenset(
    ("double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
)

_SIGNAL_KEYS = ("torque", "velocity", "position", "output", "excitation")

#: Formats ``[data] format = "auto"`` tells from the extension.
_FORMAT_OF_SUFFIX = {".h5": "hilident", ".hdf5": "hilident", ".csv": "csv", ".txt": "csv", ".dat": "csv",
                     ".tsv": "csv", ".mat": "mat"}

#: Largest relative difference between two sample rates of one record (or of two records) accepted as one
#: clock: a crystal is good to 1e-4 and time stamps rounded to microseconds add a little.
RATE_TOLERANCE = 1e-4


@dataclass
class Dataset:
    """Named signals in SI units at one sample rate.

    Attributes
    ----------
    signals : dict of str to ndarray
        Any of ``torque`` (N·m), ``velocity`` (m/s), ``position`` (m),
        ``output``, ``excitation``, all the same length: the rows analysed.
    sample_rate_hz : float
    source : str
        The file they were read from.
    notes : list of str
        What was derived, assumed or left out (e.g. velocity from position,
        periods with lost samples, a recording that did not complete).
    info : dict
        What the file held and what was used: ``rows``, ``used_rows``,
        ``segments``, ``gaps``, ``n_gaps``, ``missing_samples``,
        ``period_samples``, ``status`` (hilident files; None otherwise),
        ``reason``, ``flushed_samples``.
    period_samples : int or None
        Period of the excitation when the analysed rows are whole periods.
    segments : list of (int, int)
        ``(start, stop)`` ranges of the signals recorded without a break
        (whole periods of one stretch join seamlessly; across two stretches
        the signals jump).
    """

    signals: dict[str, np.ndarray]
    sample_rate_hz: float
    source: str
    notes: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    period_samples: int | None = None
    segments: list[tuple[int, int]] = field(default_factory=list)

    def longest_segment(self) -> "Dataset":
        """The longest stretch recorded without a break (this dataset when it has one segment)."""
        if len(self.segments) <= 1:
            return self
        a, b = max(self.segments, key=lambda r: r[1] - r[0])
        return Dataset({k: v[a:b] for k, v in self.signals.items()}, self.sample_rate_hz, self.source,
                       list(self.notes), dict(self.info), None, [(0, b - a)])

    def __len__(self) -> int:
        return len(next(iter(self.signals.values())))


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


# ---------------------------------------------------------------------- bounds and messages


def memory_limit_bytes() -> int:
    """Bytes of samples one file may bring into memory: :data:`MAX_DATA_BYTES`, at most half the RAM."""
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        physical = 0
    return int(min(MAX_DATA_BYTES, physical // 2)) if physical > 0 else int(MAX_DATA_BYTES)


def _gib(n: float) -> str:
    return f"{n / 1024**3:.3g} GiB"


def _check_fits(path: Path, rows: int, columns: int, what: str, verb: str = "declares") -> None:
    """Refuse before allocating ``rows`` x ``columns`` float64 samples beyond the memory bound."""
    need = int(rows) * int(columns) * 8
    limit = memory_limit_bytes()
    if need > limit:
        raise DataError(f"{path}: {what} {verb} {rows} rows of {columns} column(s) ({_gib(need)} as float64), "
                        f"more than the {_gib(limit)} hilident reads into memory")


def _names(names) -> str:
    """Names read from a file, for a one-line message: few, short, and control characters escaped."""
    names = sorted(str(n) for n in names)
    if not names:
        return "none"
    more = len(names) - _LISTED_NAMES
    shown = [n if n.isprintable() and len(n) <= 40 else _short(n) for n in names[:_LISTED_NAMES]]
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def _why(exc: BaseException, limit: int = 200) -> str:
    """A library's exception as part of one line: type, message, no line breaks, bounded length."""
    text = " ".join(str(exc).split())
    if len(text) > limit:
        text = text[:limit] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _short(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[:limit] + "...")


# ---------------------------------------------------------------------- reading


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
    kind = fmt if fmt != "auto" else _FORMAT_OF_SUFFIX.get(path.suffix.lower())
    if kind is None:
        raise ConfigError("data.format", f"cannot tell the format of {path.name} from its extension; set "
                                         "[data] format = \"csv\" (numeric text, with or without a header row), "
                                         "\"mat\" or \"hilident\"", str(path))
    labels = names if isinstance(names, dict) else {}
    wanted = None if names is None else list(dict.fromkeys(names))

    def check(available) -> None:
        for name, label in labels.items():
            if name not in available:
                raise DataError(f"{path}: no column {name!r} ({label}); the file has: {_names(available)}")

    try:
        if kind == "hilident":
            return _read_hilident(path, wanted, check)
        if kind == "csv":
            return _read_csv(path, wanted, check, tuple(column_names))
        return _read_mat(path, wanted, check)
    except MemoryError:
        raise DataError(f"{path}: not enough memory to read the data") from None
    except PermissionError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror}") from None


# --- CSV


def _detect_encoding(head: bytes) -> tuple[str, int]:
    """Text encoding of a file that starts with ``head``, and the length of its byte-order mark."""
    for bom, name in ((b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"),
                      (b"\xef\xbb\xbf", "utf-8"), (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16")):
        if head.startswith(bom):
            return name, (len(bom) if name == "utf-8" else 0)  # the utf-16/32 codecs consume their own mark
    return "", 0


def _line_bound(path: Path) -> int:
    """An upper bound of the lines of a text file (one pass over its bytes, no decoding)."""
    lf = cr = 0
    with path.open("rb") as fb:
        while block := fb.read(1 << 20):
            lf += block.count(b"\n")
            cr += block.count(b"\r")
    return max(lf, cr) + 1


def _open_text(path: Path) -> tuple[io.TextIOWrapper, str]:
    """The file as text lines (after any UTF-8 byte-order mark) and the encoding they are read in.

    Without a UTF-16/32 byte-order mark the file is read as Latin-1, which
    maps every byte to a character and so never fails: numbers are ASCII,
    and a stray byte in a cell is then reported as "not a number" at its
    line. The header is re-decoded as UTF-8 by the caller.
    """
    raw = path.open("rb")
    encoding, skip = _detect_encoding(raw.read(4))
    raw.seek(skip)
    if encoding in ("utf-16", "utf-32"):
        return io.TextIOWrapper(raw, encoding=encoding, errors="strict", newline=None), encoding
    if b"\x00" in raw.read(1 << 16):
        raw.close()
        raise DataError(f"{path}: holds NUL bytes: not a text CSV (UTF-16 without byte-order mark, or binary); "
                        "save it as UTF-8 CSV")
    raw.seek(skip)
    return io.TextIOWrapper(raw, encoding="latin-1", newline=None), "latin-1"


def _cells(line: str, delimiter: str | None) -> list[str]:
    """Cells of one line: split at ``delimiter`` with CSV quoting, or at any whitespace (None)."""
    return line.split() if delimiter is None else next(csv.reader([line], delimiter=delimiter), [])


def _split_header(line: str, delimiter: str | None) -> list[str]:
    cells = _cells(line, delimiter)
    return [c.strip().lstrip("\ufeff").strip() for c in cells]


def _read_header(path: Path) -> tuple[list[str], int, str, str | None, list[str]]:
    """Column names, lines up to and including the header, encoding, delimiter and notes."""
    notes: list[str] = []
    text, encoding = _open_text(path)
    with text:
        line_no, header = 0, ""
        while line := text.readline(_MAX_HEADER_CHARS + 1):
            line_no += 1
            if len(line) > _MAX_HEADER_CHARS:
                raise DataError(f"{path}: line {line_no} is longer than {_MAX_HEADER_CHARS} characters: "
                                "not a CSV header")
            if line.strip():
                header = line
                break
        if not header.strip():
            raise DataError(f"{path}: empty file")
        if encoding == "latin-1":  # most likely UTF-8 after all
            try:
                header = header.encode("latin-1").decode("utf-8")
            except UnicodeDecodeError:
                notes.append(f"{path.name}: the header is not UTF-8; read as Latin-1")
        sample = [header] + [line for line in itertools.islice(text, 20) if line.strip()]
    delimiter = _sniff(sample)
    return _split_header(header, delimiter), line_no, encoding, delimiter, notes


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return "_" not in cell


def _headerless(path: Path, cells: list[str], column_names: tuple[str, ...], notes: list[str]) -> list[str]:
    """Column names of a file whose first line is data: ``column_names``, else the positions."""
    if not column_names:
        notes.append(f"{path.name}: no header row (the first line is numbers): columns are named by position, "
                     f"0 to {len(cells) - 1}")
        return [str(i) for i in range(len(cells))]
    if len(column_names) != len(cells):
        raise ConfigError("data.column_names", f"names {len(column_names)} column(s); {path.name} has "
                                               f"{len(cells)} per line", str(path))
    return list(column_names)


def _by_position(names, columns: list[str]) -> dict[str, str]:
    """Requested names that are positions (``"2"``) of columns not named so, mapped to the column's name."""
    return {n: columns[int(n)] for n in (names or ()) if n not in columns and n.isdigit() and int(n) < len(columns)}


def _read_csv(path: Path, names, check=lambda available: None, column_names: tuple[str, ...] = ()) -> RawColumns:
    encoding = "text"
    try:
        columns, header_lines, encoding, delimiter, notes = _read_header(path)
        if all(_is_number(c) for c in columns if c) and any(columns):
            columns = _headerless(path, columns, column_names, notes)
            header_lines -= 1  # the first line is data
        elif column_names:
            raise ConfigError("data.column_names", f"is for files without a header row; {path.name} has one: "
                                                   "map its names, or remove data.column_names", str(path))
        aliases = _by_position(names, columns)
        check(list(columns) + list(aliases))
        wanted = columns if names is None else [n for n in names if n in columns or n in aliases]
        for n in wanted:
            n = aliases.get(n, n)
            if columns.count(n) > 1:
                raise DataError(f"{path}: column {n!r} appears {columns.count(n)} times in the header")
        usecols = [columns.index(aliases.get(n, n)) for n in wanted]
        bound = _line_bound(path)
        _check_fits(path, bound, len(usecols), "the CSV file", "has up to")
        text, encoding = _open_text(path)
        with text:
            for _ in range(header_lines):
                text.readline()
            data = _parse_body(path, text, header_lines, bound, usecols, wanted, delimiter)
    except UnicodeError as exc:
        raise DataError(f"{path}: not valid {encoding.upper()} text ({_why(exc)}); save it as UTF-8 CSV") from None
    except csv.Error as exc:
        raise DataError(f"{path}: not a readable CSV file: {_why(exc)}") from None
    return RawColumns(dict(zip(wanted, data)), columns, notes=notes)


def _sniff(lines: list[str]) -> str | None:
    """The delimiter of a CSV file from its header and first lines (None: any whitespace).

    The first of ``,``, ``;`` and tab that splits the header into several
    columns and every line into as many; failing that, the first that splits
    the header; failing that, whitespace when it splits the header, else
    ``,`` (one column). Plain counting: no regular expression a hostile
    line could make slow.
    """
    candidates = (",", ";", "\t")
    counts = {d: [len(_cells(line, d)) for line in lines] for d in candidates}
    for d in candidates:
        if counts[d][0] > 1 and all(c == counts[d][0] for c in counts[d]):
            return d
    for d in candidates:
        if counts[d][0] > 1:
            return d
    return None if len(lines[0].split()) > 1 else ","


def _parse_body(path: Path, text, header_lines: int, bound: int, usecols: list[int], names: list[str],
                delimiter) -> list[np.ndarray]:
    """Data rows of the mapped columns, one preallocated float64 array per column.

    A chunk goes through :func:`numpy.loadtxt` (fast); a chunk it refuses
    (empty or missing cells, junk) is parsed cell by cell, which turns
    empty and missing cells into NaN and names the first cell that is not
    a number.
    """
    out = np.empty((len(usecols), max(bound, 1)))  # one row per column: each column contiguous, no copy at the end
    filled = 0
    line_no = header_lines
    while True:
        lines = list(itertools.islice(text, CSV_CHUNK_LINES))
        if not lines:
            break
        block = _fast_chunk(lines, usecols, delimiter) if usecols else None
        if block is None:
            block = _slow_chunk(path, lines, line_no, usecols, names, delimiter)
        if filled + len(block) > out.shape[1]:  # mixed line endings can beat the bound
            _check_fits(path, 2 * out.shape[1], len(usecols), "the CSV file", "has more than")
            grown = np.empty((len(usecols), 2 * out.shape[1]))
            grown[:, :filled] = out[:, :filled]
            out = grown
        out[:, filled:filled + len(block)] = block.T
        filled += len(block)
        line_no += len(lines)
    if filled < 0.9 * out.shape[1]:
        return [out[j, :filled].copy() for j in range(len(usecols))]
    return [out[j, :filled] for j in range(len(usecols))]


def _fast_chunk(lines: list[str], usecols: list[int], delimiter) -> np.ndarray | None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # a chunk of blank lines holds no data: not news
            block = np.loadtxt(lines, delimiter=delimiter, usecols=usecols, ndmin=2, dtype=np.float64, comments=None,
                               quotechar='"')
    except ValueError:
        return None
    return block.reshape(-1, len(usecols))


def _slow_chunk(path: Path, lines: list[str], first_line: int, usecols: list[int], names: list[str],
                delimiter) -> np.ndarray:
    rows = []
    reader = (line.split() for line in lines) if delimiter is None else csv.reader(lines, delimiter=delimiter)
    for k, cells in enumerate(reader):
        if not any(c.strip() for c in cells):
            continue
        row = []
        for j, name in zip(usecols, names):
            cell = cells[j].strip() if j < len(cells) else ""
            row.append(_number(cell, path, first_line + k + 1, name))
        rows.append(row)
    return np.array(rows, dtype=np.float64).reshape(-1, len(usecols))


def _number(cell: str, path: Path, line: int, column: str) -> float:
    if not cell:
        return math.nan
    try:
        if "_" in cell:
            raise ValueError
        return float(cell)
    except ValueError:
        raise DataError(f"{path}: line {line}, column {column!r}: {_short(cell)} is not a number") from None


# --- MATLAB


@dataclass
class _MatVariable:
    """One top-level variable of a MATLAB v5 file, as its headers declare it."""

    name: str
    shape: tuple[int, ...]
    cls: str
    complex: bool
    data_bytes: int
    start: int
    stop: int


_MAT_CLASSES = {1: "cell", 2: "struct", 3: "object", 4: "char", 5: "sparse", 6: "double", 7: "single", 8: "int8",
                9: "uint8", 10: "int16", 11: "uint16", 12: "int32", 13: "uint32", 14: "int64", 15: "uint64",
                16: "function", 17: "opaque"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MAT_HEADER_BYTES = 8192  # enough for flags, up to 32 dimensions, a long name and the data tag


def _read_mat(path: Path, names, check=lambda available: None) -> RawColumns:
    from scipy.io import loadmat
    from scipy.io.matlab import matfile_version

    try:
        major, _ = matfile_version(path)
    except Exception as exc:  # a damaged header can fail in several ways
        raise DataError(f"{path}: not a readable MATLAB file ({_why(exc)})") from None
    if major == 2:
        return _read_mat73(path, names, check)
    if major == 0:
        listing, header = _mat4_listing(path), b""
    else:
        listing, header = _mat5_listing(path)
    variables = {}
    for var in listing:
        variables.setdefault(var.name, var)
    check(variables)
    wanted = [n for n in (names if names is not None else variables) if n in variables]
    total = 0
    for name in list(wanted):
        var = variables[name]
        if var.cls not in _NUMERIC_MAT_CLASSES or var.complex:
            wanted.remove(name)
            if names is None:
                continue
            kind = "complex" if var.complex else f"a MATLAB {var.cls}"
            raise DataError(f"{path}: variable {name!r} is {kind}, not a real numeric vector")
        n = _vector_length(path, name, var.shape)
        if var.data_bytes > 8 * n + 8:
            raise DataError(f"{path}: variable {name!r} declares {var.data_bytes} bytes of data for shape "
                            f"{var.shape}: damaged or hostile file")
        total += n
        _check_fits(path, n, 1, f"variable {name!r}")
        _check_fits(path, total, 1, "the mapped variables together")
    columns = {}
    for name in wanted:
        columns[name] = _as_vector(path, name, _load_mat_variable(path, variables[name], header, loadmat))
    return RawColumns(columns, list(variables))


def _load_mat_variable(path: Path, var: _MatVariable, header: bytes, loadmat) -> np.ndarray:
    """One variable, read alone: its bytes behind the file header (none in v4), so nothing else is parsed."""
    try:
        with path.open("rb") as fh:
            fh.seek(var.start)
            blob = io.BytesIO(header + fh.read(var.stop - var.start))
        raw = loadmat(blob, squeeze_me=True)
    except Exception as exc:  # truncated or corrupted data behind valid headers
        raise DataError(f"{path}: variable {var.name!r} cannot be read ({_why(exc)})") from None
    if var.name not in raw:
        raise DataError(f"{path}: variable {var.name!r} cannot be read")
    return raw[var.name]


def _mat4_listing(path: Path) -> list[_MatVariable]:
    """Every variable of a MATLAB v4 file from its 20-byte headers, each size checked against the file."""
    import struct

    size = path.stat().st_size
    out = []
    with path.open("rb") as fh:
        pos = 0
        while pos < size:
            fh.seek(pos)
            head = fh.read(20)
            if len(head) < 20:
                raise DataError(f"{path}: truncated MATLAB v4 file: a variable header at byte {pos} is cut short")
            for order in "<>":
                mopt, rows, cols, imag, namelen = struct.unpack(order + "5i", head)
                if 0 <= mopt < 2000:  # M (thousands digit) 0: little-endian, 1: big-endian IEEE
                    break
            else:
                raise DataError(f"{path}: not a readable MATLAB file (damaged v4 header at byte {pos})")
            precision, kind = (mopt // 10) % 10, mopt % 10
            item = {0: 8, 1: 4, 2: 4, 3: 2, 4: 2, 5: 1}.get(precision)
            if item is None or (mopt // 100) % 10 or kind > 2 or rows < 0 or cols < 0 or not 0 < namelen <= 4096:
                raise DataError(f"{path}: not a readable MATLAB file (damaged v4 header at byte {pos})")
            data = rows * cols * item
            stop = pos + 20 + namelen + data * (2 if imag else 1)
            if stop > size:
                raise DataError(f"{path}: truncated MATLAB v4 file: the variable at byte {pos} declares "
                                f"{stop - pos} bytes, the file ends {size - pos} bytes later")
            name = fh.read(namelen).split(b"\0")[0].decode("latin-1")
            cls = ("double" if item == 8 else "single") if kind == 0 else ("char" if kind == 1 else "sparse")
            out.append(_MatVariable(name, (rows, cols), cls, bool(imag), data, pos, stop))
            pos = stop
    return out


def _mat5_listing(path: Path) -> tuple[list[_MatVariable], bytes]:
    """Every top-level variable of a MATLAB v5 file from its headers, and the 128-byte file header.

    Reads at most a few KiB per variable: a compressed variable is inflated
    only as far as its headers, so a file whose data would inflate to
    gigabytes costs nothing here.
    """
    import struct
    import zlib

    size = path.stat().st_size
    out = []
    with path.open("rb") as fh:
        header = fh.read(128)
        order = {b"IM": "<", b"MI": ">"}.get(header[126:128])
        if len(header) < 128 or order is None:
            raise DataError(f"{path}: not a readable MATLAB file (damaged file header)")
        pos = 128
        while pos + 8 <= size:
            fh.seek(pos)
            mdtype, nbytes = struct.unpack(order + "II", fh.read(8))
            if mdtype >> 16:  # a small data element: not a variable
                pos += 8
                continue
            stop = pos + 8 + nbytes
            if stop > size:
                raise DataError(f"{path}: truncated MATLAB file: the variable at byte {pos} declares {nbytes} bytes, "
                                f"the file ends {size - pos - 8} bytes later")
            if mdtype == _MI_COMPRESSED:
                try:
                    head = zlib.decompressobj().decompress(fh.read(min(nbytes, 1 << 16)), _MAT_HEADER_BYTES)
                except zlib.error as exc:
                    raise DataError(f"{path}: damaged compressed variable at byte {pos} ({_why(exc)})") from None
            elif mdtype == _MI_MATRIX:
                head = struct.pack(order + "II", mdtype, nbytes) + fh.read(min(nbytes, _MAT_HEADER_BYTES))
            else:
                pos = stop
                continue
            out.append(_mat5_matrix_header(path, head, order, pos, stop))
            pos = stop
    return out, header


def _mat5_matrix_header(path: Path, head: bytes, order: str, start: int, stop: int) -> _MatVariable:
    """Name, shape, class and data size from the first bytes of a miMATRIX element."""
    import struct

    def element(p: int) -> tuple[int, bytes, int]:
        if p + 8 > len(head):
            raise DataError(f"{path}: damaged variable header at byte {start}")
        mdtype, nbytes = struct.unpack(order + "II", head[p:p + 8])
        if mdtype >> 16:  # small element: up to 4 bytes of data inside the tag
            return mdtype & 0xFFFF, head[p + 4:p + 4 + (mdtype >> 16)], p + 8
        body = head[p + 8:p + 8 + nbytes]
        return mdtype, body, p + 8 + nbytes + (-nbytes % 8)

    try:
        mdtype, _ = struct.unpack(order + "II", head[:8])
        if mdtype != _MI_MATRIX:
            raise DataError(f"{path}: damaged variable at byte {start} (element type {mdtype}, expected a matrix)")
        _, flags, p = element(8)
        _, dims, p = element(p)
        _, name, p = element(p)
        if len(flags) < 8 or len(dims) < 8 or len(dims) % 4:
            raise DataError(f"{path}: damaged variable header at byte {start}")
        flag = struct.unpack(order + "I", flags[:4])[0]
        shape = tuple(struct.unpack(order + f"{len(dims) // 4}i", dims))
        cls = _MAT_CLASSES.get(flag & 0xFF, "unknown")
        data_bytes = 0
        if cls in _NUMERIC_MAT_CLASSES and math.prod(max(d, 0) for d in shape):
            if p + 8 > len(head):
                raise DataError(f"{path}: damaged variable header at byte {start}")
            mdtype, nbytes = struct.unpack(order + "II", head[p:p + 8])
            data_bytes = mdtype >> 16 if mdtype >> 16 else nbytes
    except struct.error:
        raise DataError(f"{path}: damaged variable header at byte {start}") from None
    if any(d < 0 for d in shape):
        raise DataError(f"{path}: variable {name.decode('latin-1')!r} declares a negative dimension {shape}")
    return _MatVariable(name.decode("latin-1"), shape, cls, bool(flag & 0x800), data_bytes, start, stop)


def _vector_length(path: Path, name: str, shape: tuple[int, ...]) -> int:
    long = [d for d in shape if d != 1]
    if len(long) > 1:
        raise DataError(f"{path}: variable {name!r} has shape {shape}; a vector is needed")
    return long[0] if long else (0 if 0 in shape else 1)


def _as_vector(path: Path, name: str, value) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub" or arr.squeeze().ndim > 1:
        raise DataError(f"{path}: variable {name!r} is not a real numeric vector (dtype {arr.dtype}, "
                        f"shape {arr.shape})")
    return arr.astype(np.float64, copy=False).ravel()


def _open_h5(path: Path):
    import h5py

    try:
        # locking=False: a writer in another process may hold the file while streaming.
        return h5py.File(path, "r", locking=False)
    except OSError:
        try:
            return h5py.File(path, "r")
        except OSError as exc:
            raise DataError(f"{path}: not a readable HDF5 file ({_why(exc)})") from None


def _check_stored(path: Path, ds, rows: int, what: str) -> None:
    """Refuse a dataset whose first ``rows`` rows its file cannot hold (they would read back as zeros)."""
    cols = math.prod(ds.shape[1:]) if ds.ndim > 1 else 1
    need = int(rows) * int(cols) * ds.dtype.itemsize
    if need == 0:
        return
    stored = ds.id.get_storage_size()
    size = path.stat().st_size
    if ds.compression is None and (need > stored or need > size):
        raise DataError(f"{path}: {what} declares {rows} rows ({need} bytes) but the file holds only "
                        f"{min(stored, size)} bytes of them: damaged or truncated")
    if ds.compression is not None and need > MAX_COMPRESSION_RATIO * max(stored, 1):
        raise DataError(f"{path}: {what} declares {rows} rows ({need} bytes) from {stored} stored bytes: "
                        "damaged or hostile file")


def _read_mat73(path: Path, names, check=lambda available: None) -> RawColumns:
    import h5py

    with _open_h5(path) as f:
        try:
            available = [k for k in f if isinstance(f.get(k, getclass=True), type) and
                         issubclass(f.get(k, getclass=True), h5py.Dataset)]
            check(available)
            wanted = [n for n in (names if names is not None else available) if n in available]
            columns = {}
            total = 0
            for name in wanted:
                ds = f[name]
                if ds.dtype.kind not in "fiub":
                    if names is None:
                        continue
                    raise DataError(f"{path}: variable {name!r} is not numeric (dtype {ds.dtype})")
                n = _vector_length(path, name, tuple(int(d) for d in ds.shape))
                total += n
                _check_fits(path, n, 1, f"variable {name!r}")
                _check_fits(path, total, 1, "the mapped variables together")
                _check_stored(path, ds, ds.shape[0] if ds.ndim else 1, f"variable {name!r}")
                columns[name] = _as_vector(path, name, ds[()])
        except DataError:
            raise
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged MATLAB v7.3 file ({_why(exc)})") from None
    return RawColumns(columns, available)


# --- hilident HDF5


def _attr_text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.generic):
        return str(value.item())
    return str(value)


def _read_hilident(path: Path, names, check=lambda available: None) -> RawColumns:
    import h5py

    from hilident.recording import FORMAT, FORMAT_VERSION

    if not h5py.is_hdf5(path):
        raise DataError(f"{path}: not an HDF5 file, so not a hilident run file")
    with _open_h5(path) as f:
        try:
            return _read_hilident_open(path, f, names, FORMAT, FORMAT_VERSION, check)
        except (DataError, ConfigError):
            raise
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged hilident run file ({_why(exc)})") from None


def _read_hilident_open(path: Path, f, names, fmt: str, version: int, check) -> RawColumns:
    import h5py

    attrs = f.attrs
    if _attr_text(attrs.get("format", "")) != fmt:
        raise DataError(f"{path}: not a hilident run file (root attribute format != {fmt!r})")
    if _attr_text(attrs.get("format_version", "")) != str(version):
        raise DataError(f"{path}: unsupported hilident run format_version "
                        f"{_attr_text(attrs.get('format_version', ''))!r} (this reader: {version})")
    channels = [_attr_text(c) for c in np.atleast_1d(attrs.get("channel_names", []))]
    ds = f.get("samples")
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 2 or ds.shape[1] != len(channels) or ds.dtype.kind != "f":
        raise DataError(f"{path}: damaged run file: /samples does not match channel_names")
    check(channels)
    rows = int(ds.shape[0])
    notes: list[str] = []
    flushed = None
    if "flushed_samples" in attrs:
        flushed = int(attrs["flushed_samples"])
        if flushed < 0:
            raise DataError(f"{path}: damaged run file: flushed_samples = {flushed}")
        if flushed < rows:
            notes.append(f"{path.name}: {rows - flushed} rows after the last flushed sample ({flushed}) "
                         "were not counted as recorded")
        rows = min(rows, flushed)
    wanted = [n for n in (names if names is not None else channels) if n in channels]
    for extra in ("sample_index", "excitation"):  # row numbers; the played excitation proves the period
        if extra in channels and extra not in wanted:
            wanted.append(extra)
    _check_fits(path, rows, len(wanted), "/samples")
    _check_stored(path, ds, rows, "/samples")
    rate = float(attrs.get("sample_rate_hz", math.nan))
    if not math.isfinite(rate) or rate <= 0:
        raise DataError(f"{path}: sample_rate_hz attribute is {rate!r}; it must be a positive finite number")
    columns = _read_rows(ds, rows, [channels.index(n) for n in wanted])
    status = _attr_text(attrs.get("status", "running"))
    reason = _attr_text(attrs.get("reason", ""))
    period, why = _recorded_period(attrs, rate)
    if why:
        notes.append(f"{path.name}: {why}")
    return RawColumns(dict(zip(wanted, columns)), channels, rate, status, reason, period, flushed, notes,
                      _recorded_underruns(attrs))


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
        for arr, j in zip(out, cols):
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
    from hilident.config import parse_config
    from hilident.pipeline import excitation_period_samples

    try:
        return excitation_period_samples(parse_config(text, "config_toml attribute").excitation, rate), ""
    except HilidentError as exc:
        return None, f"the stored configuration cannot be read ({_why(exc)}); the excitation period is unknown"


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
    kind = fmt if fmt != "auto" else _FORMAT_OF_SUFFIX.get(path.suffix.lower())
    if kind != "hilident" or not path.is_file() or not h5py.is_hdf5(path):
        return None
    from hilident.recording import FORMAT

    with _open_h5(path) as f:
        try:
            a = f.attrs
            if _attr_text(a.get("format", "")) != FORMAT:
                return None
            channels = [_attr_text(c) for c in np.atleast_1d(a.get("channel_names", []))]
            units = [_attr_text(c) for c in np.atleast_1d(a.get("channel_units", []))]
            period = int(a["period_samples"]) if "period_samples" in a else None
            return RunInfo(_attr_text(a.get("config_toml", "")), _attr_text(a.get("config_source", "")),
                           _attr_text(a.get("experiment", "")), _attr_text(a.get("mode", "")), channels, units,
                           period if period and period > 0 else None, float(a.get("sample_rate_hz", math.nan)))
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged hilident run file ({_why(exc)})") from None


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
    raw = read_columns(path, "hilident", {"sample_index": "sample_index", "velocity_mps": "velocity_mps",
                                          "torque_nm": "torque_nm"})
    with _open_h5(path) as f:
        try:
            table = f["tables/windows"]
            windows = np.column_stack([np.asarray(table[c][()], float) for c in ("start", "stop", "velocity_mps")])
        except Exception as exc:  # HDF5 reports a missing or damaged table as many types
            raise DataError(f"{path}: no friction-test windows table ({_why(exc)})") from None
    if windows.ndim != 2 or windows.shape[1] != 3 or len(windows) > raw.columns["sample_index"].size:
        raise DataError(f"{path}: damaged friction-test windows table")
    rows = {int(i): r for r, i in enumerate(raw.columns["sample_index"].astype(np.int64))}
    kept = []
    for a, b, v in windows:
        a, b = int(a), int(b)
        if a in rows and b - 1 in rows and rows[b - 1] - rows[a] == b - 1 - a:
            kept.append((rows[a], rows[b - 1] + 1, float(v)))
    return raw.columns["velocity_mps"], raw.columns["torque_nm"], kept


# ---------------------------------------------------------------------- mapping


def load_dataset(path: str | Path, cfg: DataConfig, config_source: str = "") -> Dataset:
    """Read ``path``, map its columns as ``cfg`` says, and keep the gap-free rows.

    Raises
    ------
    DataError
        Unknown column, NaN or infinite values, mismatched lengths, too few
        samples, irregular time stamps, a sample rate that disagrees with
        them, too few whole gap-free periods, or a damaged or oversized file.
    ConfigError
        No sample rate anywhere, or no torque column configured.
    """
    path = Path(path)
    wanted = {key: (getattr(cfg, key), getattr(cfg, f"{key}_scale")) for key in _SIGNAL_KEYS if getattr(cfg, key)}
    if "torque" not in wanted:
        raise ConfigError("data.torque", "names no column", config_source)
    _check_config_rate(cfg, config_source)
    labels = {name: f"data.{key}" for key, (name, _) in wanted.items()}
    if cfg.time:
        labels.setdefault(cfg.time, "data.time")
    raw = read_columns(path, cfg.format, labels, cfg.column_names)
    signals = _mapped(path, raw, wanted)
    n = len(next(iter(signals.values())))
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: {n} samples; at least {MIN_SAMPLES} are needed")
    index, time_rate = _row_index(path, cfg, raw, n)
    rate, rates = _sample_rate(path, cfg, time_rate, raw.sample_rate_hz, config_source)
    notes = list(raw.notes) + _status_notes(path, raw)
    configured = _configured_period(cfg, rate, config_source)
    period = raw.period_samples if raw.indexed and not configured else None
    if period:
        stored = period
        period, why = _confirmed_period(index, raw.columns.get("excitation"), period)
        if why and raw.underruns:
            why = (f"the run had {raw.underruns} underrun samples (the device ran out of excitation and played "
                   f"zeros), so the recorded excitation does not repeat every {stored} samples: whole periods are "
                   "not used, and the run's own result, which averaged them, is not to be trusted")
        notes += [f"{path.name}: {why}"] if why else []
    raw.columns.clear()  # the mapped signals hold what is still needed
    used, segments, info = _gap_free(path, signals, index, period)
    notes += info.pop("warnings")
    if configured:
        used, segments = _whole_periods_of(path, used, segments, configured, info, notes)
    info["sample_rates_hz"] = rates
    info["sample_rate_spread"] = (max(rates.values()) - min(rates.values())) / rate
    if info["used_rows"] < MIN_SAMPLES:
        raise DataError(f"{path}: {info['used_rows']} gap-free samples; at least {MIN_SAMPLES} are needed")
    for key, values in used.items():
        if np.ptp(values) == 0.0:
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) is constant ({values[0]:g}): it excites nothing"
            )
    if "velocity" not in used and "position" in used:
        used["velocity"] = _derivative(used["position"], segments, rate)
        notes.append("velocity derived from position by central differences (within each gap-free segment)")
    if "output" not in used:
        if "velocity" not in used:
            raise ConfigError("data.output", "names no column, and neither data.velocity nor data.position does: "
                                             "give the response column (a torque-to-output response needs no "
                                             "velocity)", config_source)
        used["output"] = used["velocity"]
    info.update(status=raw.status, reason=raw.reason, flushed_samples=raw.flushed_samples)
    return Dataset(used, rate, str(path), notes, info, info["period_samples"], segments)


def _gap_free(path: Path, signals: dict[str, np.ndarray], index: np.ndarray | None, period: int | None):
    """The rows to analyse, their gap-free segments (in the returned arrays) and what was used.

    Without an index (no ``sample_index``, no time column) every row is
    taken as one gap-free record, without copying.
    """
    n = len(next(iter(signals.values())))
    if index is None:
        info = {"rows": n, "used_rows": n, "segments": 1, "gaps": [], "n_gaps": 0, "missing_samples": 0,
                "period_samples": None, "warnings": []}
        return signals, [(0, n)], info
    from hilident.pipeline import select_gap_free

    try:
        selection = select_gap_free(index, period, path.name)
        notes = []
    except DataError:
        if not period:
            raise
        # too few whole periods: a stretch without a break can still be analysed (Welch averaging)
        selection = select_gap_free(index, None, path.name)
        notes = [f"{path.name}: fewer than two whole gap-free excitation periods of {period} samples; "
                 "the longest gap-free stretch is analysed instead"]
    info = dict(selection.to_dict(), warnings=notes + selection.warnings)
    if selection.used_rows == n:
        return signals, selection.segments, info
    used = {key: v[selection.keep] for key, v in signals.items()}
    edges = np.cumsum([0] + [b - a for a, b in selection.segments])
    return used, [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])], info


def _confirmed_period(index: np.ndarray, excitation: np.ndarray | None, period: int) -> tuple[int | None, str]:
    """``period`` if the recorded excitation repeats with it (or was not recorded), else None and why.

    A stored configuration can describe another run than the one recorded
    (edited, or replaced in a script); joining "periods" that are not would
    splice. Of the first three pairs of consecutive whole periods recorded
    without a break (the lead-in counts: it is the first period played
    again), one must repeat to 10⁻⁶ of the peak; an underrun may have
    changed another. With no such pair the period is kept unconfirmed.
    """
    if excitation is None:
        return period, ""
    from hilident.pipeline import contiguous_runs

    pairs = 0
    for a, b in contiguous_runs(index):
        first = -(-int(index[a]) // period)
        start = a + first * period - int(index[a])
        while start + 2 * period <= b and pairs < 3:
            one, two = excitation[start:start + period], excitation[start + period:start + 2 * period]
            scale = float(np.max(np.abs(one))) or 1.0
            if np.max(np.abs(one - two)) <= 1e-6 * scale:
                return period, ""
            pairs += 1
            start += period
        if pairs == 3:
            break
    if not pairs:
        return period, ""
    return None, (f"the recorded excitation does not repeat every {period} samples as the stored configuration "
                  "says: whole periods are not used")


def _check_config_rate(cfg: DataConfig, source: str) -> None:
    rate = cfg.sample_rate_hz
    if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate < 0:
        raise ConfigError("data.sample_rate_hz", f"must be a finite number >= 0, got {rate!r}", source)


def _mapped(path: Path, raw: RawColumns, wanted: dict) -> dict[str, np.ndarray]:
    """Scaled signals of the mapped columns, all finite and equally long."""
    signals = {}
    uses = {}
    for name, _ in wanted.values():
        uses[name] = uses.get(name, 0) + 1
    for key, (name, scale) in wanted.items():
        if name not in raw.columns:
            if name in raw.available:
                raise DataError(f"{path}: column {name!r} (data.{key}) is not numeric")
            raise DataError(f"{path}: no column {name!r} (data.{key}); the file has: {_names(raw.available)}")
        values = np.asarray(raw.columns[name], dtype=float)
        if scale != 1.0:
            # the column is ours: scale it in place unless another signal maps it too
            values = values * scale if uses[name] > 1 else np.multiply(values, scale, out=values)
        signals[key] = values
    lengths = {key: len(v) for key, v in signals.items()}
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: columns of different lengths: {lengths}")
    for key, values in signals.items():
        if np.isfinite(values).all():
            continue
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) has {len(bad)} NaN or infinite values, "
                f"the first at row {bad[0]}"
            )
    return signals


def _status_notes(path: Path, raw: RawColumns) -> list[str]:
    if raw.status in (None, "complete"):
        return []
    if raw.status == "running":
        why = "the recording process ended without closing it, or is still writing"
    elif raw.status == "aborted":
        why = f"aborted: {raw.reason or 'no reason recorded'}"
    else:
        why = f"status {raw.status!r}"
    return [f"{path.name}: the recording did not complete ({why}); it may end early"]


def _row_index(path: Path, cfg: DataConfig, raw: RawColumns, n: int) -> tuple[np.ndarray | None, float | None]:
    """Index of each row on the sample clock (None: no way to tell), and the rate the time column gives."""
    index = None
    if "sample_index" in raw.columns:
        si = raw.columns["sample_index"][:n]
        if len(si) != n or not np.all(np.isfinite(si)) or np.any(si != np.round(si)) or np.any(np.abs(si) > 2**53):
            raise DataError(f"{path}: sample_index column is not whole numbers")
        index = si.astype(np.int64)
    time_rate = None
    if cfg.time:
        t_index, time_rate = _time_index(path, cfg.time, raw, n)
        if index is None:
            index = t_index
    return index, time_rate


def _time_index(path: Path, name: str, raw: RawColumns, n: int) -> tuple[np.ndarray | None, float]:
    """Sample numbers from a time column whose steps are whole multiples of one sample period.

    A step of two periods or more is a gap; a step that is no whole
    multiple (within 0.1 % of a period) is an irregular time stamp. The
    column is checked a chunk at a time (bounded temporaries); without a
    gap no index is built at all (None: every row follows the one before).
    The period is the median step of the first chunk.
    """
    if name not in raw.columns:
        raise DataError(f"{path}: no time column {name!r} (data.time); the file has: {_names(raw.available)}")
    t = np.asarray(raw.columns[name], dtype=float)
    if len(t) != n or not np.isfinite(t).all():
        raise DataError(f"{path}: time column {name!r} is not finite or not as long as the data")
    step = float(np.median(np.diff(t[:_TIME_CHUNK + 1])))
    rows, lengths = [], []
    for a in range(0, n - 1, _TIME_CHUNK):
        dt = np.diff(t[a:a + _TIME_CHUNK + 1])
        back = np.flatnonzero(dt <= 0)
        if len(back):
            i = a + int(back[0])
            raise DataError(f"{path}: time column {name!r} does not increase at row {i + 1} "
                            f"(step {dt[i - a]:.6g} s); sort the data first")
        steps = dt / step
        whole = np.rint(steps)
        off = np.flatnonzero(np.abs(steps - whole) > 1e-3)
        if len(off):
            i = a + int(off[0])
            raise DataError(
                f"{path}: time stamps are not uniform (step {dt[i - a]:.6g} s at row {i + 1}, median {step:.6g} s, "
                "not a whole number of sample periods); resample the data first"
            )
        jumps = np.flatnonzero(whole != 1)
        rows.append(a + 1 + jumps)
        lengths.append(whole[jumps].astype(np.int64) - 1)
    rows_after = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    missing = np.concatenate(lengths) if lengths else np.zeros(0, np.int64)
    rate = float((n - 1 + int(missing.sum())) / (t[-1] - t[0]))
    if not len(rows_after):
        return None, rate
    skip = np.zeros(n, dtype=np.int64)
    skip[rows_after] = missing
    return np.arange(n, dtype=np.int64) + np.cumsum(skip), rate


def _sample_rate(path, cfg: DataConfig, from_time, file_rate, source) -> tuple[float, dict]:
    """The sample rate, Hz, and where it came from (``{source: rate}``, for ``summary.json``).

    ``data.sample_rate_hz`` wins when it is set; else the file's recorded
    rate, else the time column's. Rates from several sources must agree to
    :data:`RATE_TOLERANCE` (relative): the message names the keys the user
    can change, never one that was not set.
    """
    rates = {}
    if cfg.sample_rate_hz:
        rates["data.sample_rate_hz"] = float(cfg.sample_rate_hz)
    if file_rate:
        rates["recorded sample_rate_hz attribute"] = float(file_rate)
    if from_time:
        rates[f"time column {cfg.time!r} (data.time)"] = float(from_time)
    if not rates:
        raise ConfigError("data.sample_rate_hz", "is needed: the data have no time column (data.time) and no "
                                                 "recorded rate", source)
    if any(not math.isfinite(r) or r <= 0 for r in rates.values()):
        raise DataError(f"{path}: sample rate {list(rates.values())} is not a positive finite number")
    (first, rate), *others = rates.items()
    for what, r in others:
        spread = abs(r - rate) / rate
        if spread > RATE_TOLERANCE:
            fix = ("correct data.sample_rate_hz or leave it out" if first == "data.sample_rate_hz" else
                   "check the time unit of data.time (seconds), or leave data.time out")
            raise DataError(f"{path}: {first} gives {rate:.9g} Hz, the {what} {r:.9g} Hz: they differ by "
                            f"{spread:.2g} (relative; {RATE_TOLERANCE:g} is accepted): {fix}")
    return float(rate), rates


def _configured_period(cfg: DataConfig, rate: float, source: str) -> int | None:
    """``data.period_samples``, or ``data.period_s`` in whole samples at ``rate`` (None: not set)."""
    if cfg.period_samples:
        return int(cfg.period_samples)
    if not cfg.period_s:
        return None
    exact = cfg.period_s * rate
    period = int(round(exact))
    if period < 4 or abs(exact - period) > 1e-3:
        raise ConfigError("data.period_s", f"{cfg.period_s:g} s is {exact:.6g} samples at {rate:.9g} Hz, not a whole "
                                           "number (>= 4): give data.period_samples", source)
    return period


def _whole_periods_of(path: Path, used: dict, segments, period: int, info: dict, notes: list[str]):
    """The whole periods of the longest gap-free stretch (a periodic signal's periods can start anywhere)."""
    a, b = max(segments, key=lambda r: r[1] - r[0])
    count = (b - a) // period
    if count < 1:
        raise DataError(f"{path}: {b - a} gap-free samples are less than one excitation period of {period} "
                        "samples (data.period_s / data.period_samples)")
    stop = a + count * period
    if (a, stop) != (0, len(next(iter(used.values())))):
        used = {k: v[a:stop] for k, v in used.items()}
        notes.append(f"{path.name}: {count} whole period(s) of {period} samples analysed"
                     + (f"; {b - stop} samples after the last whole period left out" if b > stop else ""))
    info.update(used_rows=count * period, segments=1, period_samples=period)
    return used, [(0, count * period)]


def _derivative(x: np.ndarray, segments: list[tuple[int, int]], rate: float) -> np.ndarray:
    """Central differences within each gap-free segment (never across a join)."""
    from hilident.ident.preprocess import central_difference

    out = np.empty_like(x)
    for a, b in segments:
        out[a:b] = central_difference(x[a:b], rate) if b - a >= 2 else 0.0
    return out
