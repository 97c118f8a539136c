"""MATLAB ``.mat`` files: v4 and v5 listed from their headers before any variable is loaded, v7.3 through HDF5."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilident.datafile.raw import (
    RawColumns,
    check_fits,
    check_stored,
    exception_text,
    open_h5,
)
from hilident.errors import DataError

_NUMERIC_MAT_CLASSES = frozenset(
    ("double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
)


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


_MAT_CLASSES = {
    1: "cell",
    2: "struct",
    3: "object",
    4: "char",
    5: "sparse",
    6: "double",
    7: "single",
    8: "int8",
    9: "uint8",
    10: "int16",
    11: "uint16",
    12: "int32",
    13: "uint32",
    14: "int64",
    15: "uint64",
    16: "function",
    17: "opaque",
}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
#: The element types a real numeric array's data may have (miINT8 .. miUINT32, miSINGLE, miDOUBLE, miINT64,
#: miUINT64). scipy's reader indexes a table with the type it finds and does not check it first: an unknown
#: type crashes the process, so a variable whose headers name one is refused before scipy sees it.
_MI_NUMERIC = frozenset((1, 2, 3, 4, 5, 6, 7, 9, 12, 13))
#: The element types of a matrix's array flags, dimensions and name (miUINT32, miINT32, miINT8).
_MI_FLAGS, _MI_DIMS, _MI_NAME = 6, 5, 1
_MAT_HEADER_BYTES = 8192  # enough for flags, up to 32 dimensions, a long name and the data tag


def read_mat(path: Path, names, check=lambda available: None) -> RawColumns:
    from scipy.io import loadmat
    from scipy.io.matlab import matfile_version

    try:
        major, _ = matfile_version(path)
    except Exception as exc:  # a damaged header can fail in several ways
        raise DataError(f"{path}: not a readable MATLAB file ({exception_text(exc)})") from None
    if major == 2:
        return _read_mat73(path, names, check)
    if major == 0:
        listing, header = _mat4_listing(path), b""
    else:
        listing, header = _mat5_listing(path)
    variables: dict[str, _MatVariable] = {}
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
            raise DataError(
                f"{path}: variable {name!r} declares {var.data_bytes} bytes of data for shape "
                f"{var.shape}: damaged or hostile file"
            )
        total += n
        check_fits(path, n, 1, f"variable {name!r}")
        check_fits(path, total, 1, "the mapped variables together")
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
        raise DataError(f"{path}: variable {var.name!r} cannot be read ({exception_text(exc)})") from None
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
                raise DataError(
                    f"{path}: truncated MATLAB v4 file: the variable at byte {pos} declares "
                    f"{stop - pos} bytes, the file ends {size - pos} bytes later"
                )
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
                raise DataError(
                    f"{path}: truncated MATLAB file: the variable at byte {pos} declares {nbytes} bytes, "
                    f"the file ends {size - pos - 8} bytes later"
                )
            if mdtype == _MI_COMPRESSED:
                try:
                    head = zlib.decompressobj().decompress(fh.read(min(nbytes, 1 << 16)), _MAT_HEADER_BYTES)
                except zlib.error as exc:
                    raise DataError(
                        f"{path}: damaged compressed variable at byte {pos} ({exception_text(exc)})"
                    ) from None
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
        mdtype, nbytes = struct.unpack(order + "II", head[p : p + 8])
        if mdtype >> 16:  # small element: up to 4 bytes of data inside the tag
            return mdtype & 0xFFFF, head[p + 4 : p + 4 + (mdtype >> 16)], p + 8
        body = head[p + 8 : p + 8 + nbytes]
        return mdtype, body, p + 8 + nbytes + (-nbytes % 8)

    try:
        mdtype, _ = struct.unpack(order + "II", head[:8])
        if mdtype != _MI_MATRIX:
            raise DataError(f"{path}: damaged variable at byte {start} (element type {mdtype}, expected a matrix)")
        flags_type, flags, p = element(8)
        dims_type, dims, p = element(p)
        name_type, name, p = element(p)
        if len(flags) < 8 or len(dims) < 8 or len(dims) % 4:
            raise DataError(f"{path}: damaged variable header at byte {start}")
        if (flags_type, dims_type, name_type) != (_MI_FLAGS, _MI_DIMS, _MI_NAME):
            raise DataError(f"{path}: damaged variable header at byte {start} (element types of flags, dims, name)")
        flag = struct.unpack(order + "I", flags[:4])[0]
        shape = tuple(struct.unpack(order + f"{len(dims) // 4}i", dims))
        cls = _MAT_CLASSES.get(flag & 0xFF, "unknown")
        data_bytes = 0
        if cls in _NUMERIC_MAT_CLASSES and math.prod(max(d, 0) for d in shape):
            if p + 8 > len(head):
                raise DataError(f"{path}: damaged variable header at byte {start}")
            mdtype, nbytes = struct.unpack(order + "II", head[p : p + 8])
            data_bytes = mdtype >> 16 if mdtype >> 16 else nbytes
            if (mdtype & 0xFFFF if mdtype >> 16 else mdtype) not in _MI_NUMERIC:
                raise DataError(
                    f"{path}: variable {name.decode('latin-1')!r} at byte {start} declares data of element type "
                    f"{mdtype & 0xFFFF if mdtype >> 16 else mdtype}, not a number: damaged file"
                )
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
        raise DataError(
            f"{path}: variable {name!r} is not a real numeric vector (dtype {arr.dtype}, shape {arr.shape})"
        )
    return arr.astype(np.float64, copy=False).ravel()


def _read_mat73(path: Path, names, check=lambda available: None) -> RawColumns:
    import h5py

    with open_h5(path) as f:
        try:
            available = [
                k
                for k in f
                if isinstance(f.get(k, getclass=True), type) and issubclass(f.get(k, getclass=True), h5py.Dataset)
            ]
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
                check_fits(path, n, 1, f"variable {name!r}")
                check_fits(path, total, 1, "the mapped variables together")
                check_stored(path, ds, ds.shape[0] if ds.ndim else 1, f"variable {name!r}")
                columns[name] = _as_vector(path, name, ds[()])
        except DataError:
            raise
        except Exception as exc:  # HDF5 reports damaged structures as many types
            raise DataError(f"{path}: damaged MATLAB v7.3 file ({exception_text(exc)})") from None
    return RawColumns(columns, available)
