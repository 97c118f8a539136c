"""Numeric text files (CSV, TSV, whitespace-separated; with or without a header row), read in bounded chunks.

Only the requested columns are parsed, into arrays sized from a bound of the
file's lines before anything is allocated.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import warnings
from pathlib import Path

import numpy as np

from hilident.datafile.raw import RawColumns, check_fits, exception_text, short
from hilident.errors import ConfigError, DataError

#: Lines parsed per CSV chunk.
CSV_CHUNK_LINES = 1 << 16

#: Longest header line accepted, characters.
_MAX_HEADER_CHARS = 1 << 20


def _detect_encoding(head: bytes) -> tuple[str, int]:
    """Text encoding of a file that starts with ``head``, and the length of its byte-order mark."""
    for bom, name in (
        (b"\xff\xfe\x00\x00", "utf-32"),
        (b"\x00\x00\xfe\xff", "utf-32"),
        (b"\xef\xbb\xbf", "utf-8"),
        (b"\xff\xfe", "utf-16"),
        (b"\xfe\xff", "utf-16"),
    ):
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
        raise DataError(
            f"{path}: holds NUL bytes: not a text CSV (UTF-16 without byte-order mark, or binary); save it as UTF-8 CSV"
        )
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
                raise DataError(
                    f"{path}: line {line_no} is longer than {_MAX_HEADER_CHARS} characters: not a CSV header"
                )
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
        notes.append(
            f"{path.name}: no header row (the first line is numbers): columns are named by position, "
            f"0 to {len(cells) - 1}"
        )
        return [str(i) for i in range(len(cells))]
    if len(column_names) != len(cells):
        raise ConfigError(
            "data.column_names",
            f"names {len(column_names)} column(s); {path.name} has {len(cells)} per line",
            str(path),
        )
    return list(column_names)


def _by_position(names, columns: list[str]) -> dict[str, str]:
    """Requested names that are positions (``"2"``) of columns not named so, mapped to the column's name."""
    return {n: columns[int(n)] for n in (names or ()) if n not in columns and n.isdigit() and int(n) < len(columns)}


def read_csv(path: Path, names, check=lambda available: None, column_names: tuple[str, ...] = ()) -> RawColumns:
    encoding = "text"
    try:
        columns, header_lines, encoding, delimiter, notes = _read_header(path)
        if all(_is_number(c) for c in columns if c) and any(columns):
            columns = _headerless(path, columns, column_names, notes)
            header_lines -= 1  # the first line is data
        elif column_names:
            raise ConfigError(
                "data.column_names",
                f"is for files without a header row; {path.name} has one: map its names, or remove data.column_names",
                str(path),
            )
        aliases = _by_position(names, columns)
        check(list(columns) + list(aliases))
        wanted = columns if names is None else [n for n in names if n in columns or n in aliases]
        for n in wanted:
            n = aliases.get(n, n)
            if columns.count(n) > 1:
                raise DataError(f"{path}: column {n!r} appears {columns.count(n)} times in the header")
        usecols = [columns.index(aliases.get(n, n)) for n in wanted]
        bound = _line_bound(path)
        check_fits(path, bound, len(usecols), "the CSV file", "has up to")
        text, encoding = _open_text(path)
        with text:
            for _ in range(header_lines):
                text.readline()
            data = _parse_body(path, text, header_lines, bound, usecols, wanted, delimiter)
    except UnicodeError as exc:
        raise DataError(
            f"{path}: not valid {encoding.upper()} text ({exception_text(exc)}); save it as UTF-8 CSV"
        ) from None
    except csv.Error as exc:
        raise DataError(f"{path}: not a readable CSV file: {exception_text(exc)}") from None
    return RawColumns(dict(zip(wanted, data, strict=False)), columns, notes=notes)


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


def _parse_body(
    path: Path, text, header_lines: int, bound: int, usecols: list[int], names: list[str], delimiter
) -> list[np.ndarray]:
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
            check_fits(path, 2 * out.shape[1], len(usecols), "the CSV file", "has more than")
            grown = np.empty((len(usecols), 2 * out.shape[1]))
            grown[:, :filled] = out[:, :filled]
            out = grown
        out[:, filled : filled + len(block)] = block.T
        filled += len(block)
        line_no += len(lines)
    if filled < 0.9 * out.shape[1]:
        return [out[j, :filled].copy() for j in range(len(usecols))]
    return [out[j, :filled] for j in range(len(usecols))]


def _fast_chunk(lines: list[str], usecols: list[int], delimiter) -> np.ndarray | None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # a chunk of blank lines holds no data: not news
            block = np.loadtxt(
                lines, delimiter=delimiter, usecols=usecols, ndmin=2, dtype=np.float64, comments=None, quotechar='"'
            )
    except ValueError:
        return None
    return block.reshape(-1, len(usecols))


def _slow_chunk(
    path: Path, lines: list[str], first_line: int, usecols: list[int], names: list[str], delimiter
) -> np.ndarray:
    rows = []
    reader = (line.split() for line in lines) if delimiter is None else csv.reader(lines, delimiter=delimiter)
    for k, cells in enumerate(reader):
        if not any(c.strip() for c in cells):
            continue
        row = []
        for j, name in zip(usecols, names, strict=False):
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
        raise DataError(f"{path}: line {line}, column {column!r}: {short(cell)} is not a number") from None
