"""Plain JSON out of hilident's results: the one serialiser of ``summary.json`` and recording attributes.

:func:`to_jsonable` turns a result (typed parts of a
:class:`~hilident.io.summary.Summary`, numpy values, dataclasses, nested
mappings) into JSON types; :func:`write_json` writes it atomically. No
plotting, no HDF5: ``report`` (plots) and ``recording`` (HDF5 files) both
use this module, neither imports the other.

Examples
--------
>>> import numpy as np
>>> to_jsonable({"gain": np.float64(2.0), "pole": 1 + 2j, "bad": float("nan")})
{'gain': 2.0, 'pole': {'re': 1.0, 'im': 2.0}, 'bad': None}
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError

__all__ = ["to_jsonable", "write_json", "atomic_write"]

#: Returned by the converters below for an object of a type they do not handle.
_UNHANDLED = object()


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` recursively into plain JSON types.

    Handles numpy scalars and arrays, dataclass instances (as dicts of their
    fields), named tuples
    (as dicts), other tuples/lists/sets (as lists), mappings (keys become
    ``str``), complex numbers (as ``{"re": .., "im": ..}``),
    :class:`~pathlib.Path` (as ``str``), dates and times (ISO 8601), enums (their
    value) and ``bytes`` (UTF-8 text). NaN and infinities become ``None``,
    because JSON has no spelling for them.

    Parameters
    ----------
    obj : Any
        The object to convert.

    Returns
    -------
    Any
        ``None``, ``bool``, ``int``, ``float``, ``str``, ``list`` or ``dict``,
        nested.

    Raises
    ------
    TypeError
        For an object of a type not listed above.

    Examples
    --------
    >>> import numpy as np
    >>> to_jsonable({"f_hz": np.array([1.0, np.inf]), "n": np.int64(3)})
    {'f_hz': [1.0, None], 'n': 3}
    """
    for convert in _CONVERTERS:
        out = convert(obj)
        if out is not _UNHANDLED:
            return out
    raise TypeError(f"to_jsonable: cannot convert object of type {type(obj).__name__}: {obj!r:.80}")


def _number(obj: Any) -> Any:
    """None, bools, numbers and numpy scalars (a numpy scalar first: np.float64 subclasses float)."""
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if obj is None or isinstance(obj, bool):
        return obj
    if isinstance(obj, str):
        return _UNHANDLED  # text, a str-valued enum included, as str() spells it
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, complex):
        return {"re": to_jsonable(obj.real), "im": to_jsonable(obj.imag)}
    return _UNHANDLED


def _text(obj: Any) -> Any:
    """Strings, paths, dates and times, bytes."""
    if isinstance(obj, str):
        return str(obj)
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (_dt.datetime, _dt.date, _dt.time)):
        return obj.isoformat()
    if isinstance(obj, (bytes, bytearray)):
        return bytes(obj).decode("utf-8", errors="replace")
    return _UNHANDLED


def _record(obj: Any) -> Any:
    """Typed records: a dataclass's fields, a named tuple's fields."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple) and hasattr(obj, "_asdict"):
        return {str(k): to_jsonable(v) for k, v in obj._asdict().items()}
    return _UNHANDLED


def _collection(obj: Any) -> Any:
    """Arrays, mappings, lists and tuples, sets (sorted when their items compare)."""
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, Mapping):
        return {_json_key(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        items = [to_jsonable(v) for v in obj]
        try:
            return sorted(items)
        except TypeError:
            return items
    return _UNHANDLED


_CONVERTERS: tuple[Callable[[Any], Any], ...] = (_number, _text, _record, _collection)


def _json_key(key: Any) -> str:
    if isinstance(key, str):
        return key
    converted = to_jsonable(key)
    return converted if isinstance(converted, str) else json.dumps(converted)


def write_json(path: str | os.PathLike, document: Any) -> Path:
    """Write ``document`` as pretty JSON (indent 2, key order kept), atomically.

    Parameters
    ----------
    path : str or path-like
        Destination, e.g. ``out/summary.json``; the parent folder is created.
    document : Any
        Anything :func:`to_jsonable` accepts (a :class:`~hilident.io.summary.Summary`, a mapping).

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    DataError
        If ``document`` holds an object that cannot be converted to JSON, or
        the file cannot be written (the previous file, if any, is kept).
    """
    path = Path(path)
    try:
        plain = to_jsonable(document)
    except TypeError as exc:
        raise DataError(f"{path}: summary cannot be written as JSON: {exc}") from None
    text = json.dumps(plain, indent=2, sort_keys=False, allow_nan=False, ensure_ascii=False) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))
    return path


def atomic_write(path: Path, write: Callable[[Any], Any]) -> None:
    """Call ``write(binary_file)`` on a temporary file next to ``path``, then rename it.

    The file gets the permissions a plain ``open()`` would give (0644 under
    the usual umask). A full disk or an unwritable folder is a
    :class:`DataError` naming the file; the previous file, if any, is kept.
    """
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)  # mkstemp creates 0600
        os.replace(tmp, path)
    except OSError as exc:
        _discard(tmp)
        raise DataError(f"{path}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        _discard(tmp)
        raise


def _discard(tmp: str | None) -> None:
    if tmp is not None:
        try:
            os.unlink(tmp)
        except OSError:
            pass
