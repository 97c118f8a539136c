"""The one schema mechanism of every TOML file hilident reads: run configurations and driver files.

A table is a frozen dataclass whose fields are declared with :func:`spec`
(bounds, choices, list length, ``"auto"``, a custom ``check``);
:func:`build_table` validates a parsed TOML table into it. Unknown keys, wrong
types and out-of-range values raise :class:`~hilident.errors.ConfigError`
naming the dotted ``[table.key]`` and the file. A nested dataclass field is a
sub-table, a ``list[Dataclass]`` field an array of tables, a ``float |
Dataclass`` field either a number or a (usually inline) table.

Why this and not msgspec or pydantic: it already gives typed, declarative
tables with errors naming ``[table.key]`` and the file, numbers and strings
bounded against hostile input (:data:`FLOAT_MAX`, :data:`INT_RANGE`,
:data:`MAX_STRING_CHARS`, :data:`MAX_LIST_ITEMS`), and every driver file can
use it without a new dependency.

Keys that moved to a sub-table (``[device] node_id`` to
``[device.canopen] node_id``) are listed in the class attribute
``moved_keys``; :func:`moved_keys_readable` keeps their flat attributes and
constructor keywords, and :func:`build_table` still reads the flat keys, with a
:class:`ConfigKeyDeprecationWarning` naming the key, the file and the new place.

Pure: no files, no clocks; :mod:`hilident.config.tables` reads the files.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
import types
import typing
import warnings
from dataclasses import field

from hilident.errors import ConfigError
from hilident.signals._checks import show

_Table = typing.TypeVar("_Table")

#: Largest configuration or driver description file read, bytes.
MAX_FILE_BYTES = 1 << 20
#: Most items a list in a configuration may hold (unless its key says fewer).
MAX_LIST_ITEMS = 1024
#: Longest string value, characters.
MAX_STRING_CHARS = 4096
#: Integers without their own bounds must fit a signed 32-bit C integer.
INT_RANGE = (-(2**31), 2**31 - 1)
#: Every number must be finite and within +-FLOAT_MAX (a REAL32 object holds 3.4e38).
FLOAT_MAX = 1e30


def spec(
    default=dataclasses.MISSING,
    *,
    gt=None,
    ge=None,
    le=None,
    lt=None,
    choices=None,
    max_items=None,
    doc="",
    auto=None,
    check=None,
):
    """A dataclass field with validation metadata (bounds, choices, list length).

    ``auto``: the string ``"auto"`` is accepted besides a number (``True``), or
    refused with this message (a str) where it cannot apply. ``check``: a
    callable ``check(value, key, source)`` run on a value (a list: the whole
    list) that passed the other checks; it raises :class:`ConfigError` naming
    ``key``.
    """
    meta = {
        "gt": gt,
        "ge": ge,
        "le": le,
        "lt": lt,
        "choices": choices,
        "max_items": max_items,
        "doc": doc,
        "auto": auto,
        "check": check,
    }
    if isinstance(default, (list, dict)):  # each instance gets its own copy of a mutable default
        return field(default_factory=functools.partial(type(default), default), metadata=meta)
    return field(default=default, metadata=meta)


class ConfigKeyDeprecationWarning(DeprecationWarning):
    """A key of an earlier release was read; the message names it, the file and where it lives now."""


if not sys.warnoptions:  # shown once per key and file, unless the user chose what to do with warnings
    warnings.filterwarnings("default", category=ConfigKeyDeprecationWarning)


def moved_keys_readable(cls):
    """Keep the flat attributes of the keys ``cls.moved_keys`` moved into sub-tables.

    Each moved key stays a read-only attribute of ``cls`` (``device.node_id``
    reads ``device.canopen.node_id``) and a keyword of the constructor and of
    :func:`dataclasses.replace`, which set it in its sub-table. Readers should
    move to the sub-table attribute; the aliases go with the flat keys.
    """
    init = cls.__init__

    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        flat = {name: kwargs.pop(name) for name in list(kwargs) if name in cls.moved_keys}
        init(self, *args, **kwargs)
        for sub in dict.fromkeys(cls.moved_keys[name] for name in flat):
            given = {name: value for name, value in flat.items() if cls.moved_keys[name] == sub}
            object.__setattr__(self, sub, dataclasses.replace(getattr(self, sub), **given))

    cls.__init__ = __init__
    for name, sub in cls.moved_keys.items():
        setattr(cls, name, _moved_alias(name, sub))
    return cls


def _moved_alias(name: str, sub: str) -> property:
    """A read-only attribute ``name`` that reads ``self.<sub>.<name>``."""

    def read(self: object) -> object:
        return getattr(getattr(self, sub), name)

    return property(read, doc=f"Deprecated alias of ``{sub}.{name}``.")


def build_table(cls: type[_Table], table: object, prefix: str, source: str) -> _Table:
    """Validate TOML ``table`` into the dataclass ``cls`` (fields declared with ``_spec``).

    Unknown keys are refused unless ``cls`` sets ``open_table = True`` (a class
    attribute): such a table also holds keys other readers validate.

    Raises
    ------
    ConfigError
        Naming ``source`` and the dotted key below ``prefix``.
    """
    return _build(cls, table, prefix, source)


def _name(key: str) -> str:
    """A key as printed in a message (a hostile key may be huge or hold control characters)."""
    text = key if key.isprintable() else repr(key)
    return text if len(text) <= 60 else text[:57] + "..."


def _build(cls, table, prefix: str, source: str):
    if not isinstance(table, dict):
        raise ConfigError(prefix.rstrip(".") or "(file)", f"must be a table, got {show(table)}", source)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    moved = _moved_values(cls, table, prefix, source)
    unknown = sorted(set(table) - set(fields) - set(moved))
    if unknown and not getattr(cls, "open_table", False):
        raise ConfigError(prefix + _name(unknown[0]), f"unknown key (known here: {', '.join(sorted(fields))})", source)
    values = {}
    for name, f in fields.items():
        key = prefix + name
        if name not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(key, "is required", source)
            continue
        values[name] = _convert(hints[name], table[name], f.metadata, key, source)
    return cls(**values, **moved)


def _moved_values(cls, table: dict, prefix: str, source: str) -> dict:
    """The flat keys of an earlier release in ``table``, validated, each with a deprecation warning.

    Raises
    ------
    ConfigError
        A value is invalid, or the key is given both flat and in its sub-table.
    """
    values = {}
    for name, sub in getattr(cls, "moved_keys", {}).items():
        if name not in table:
            continue
        new_key = f"{prefix}{sub}.{name}"
        if isinstance(table.get(sub), dict) and name in table[sub]:
            raise ConfigError(prefix + name, f"is given twice: here and as [{new_key}]; keep the latter", source)
        sub_cls = typing.get_type_hints(cls)[sub]
        sub_field = next(f for f in dataclasses.fields(sub_cls) if f.name == name)
        values[name] = _convert(
            typing.get_type_hints(sub_cls)[name], table[name], sub_field.metadata, prefix + name, source
        )
        # explicit: the place worth naming is the file and key, not this line of hilident
        warnings.warn_explicit(
            f"{source}: [{prefix}{name}] is deprecated: write it as {name} in "
            f"[{prefix}{sub}] ([{new_key}]); the flat key is read until the next release",
            ConfigKeyDeprecationWarning,
            "hilident.config.tables",
            0,
            module="hilident.config.tables",
        )
    return values


def _convert(hint, value, meta, key: str, source: str):
    if isinstance(hint, types.UnionType):
        options = [h for h in typing.get_args(hint) if h is not type(None)]
        tables = [h for h in options if dataclasses.is_dataclass(h)]
        if tables and len(options) > 1:  # "float | Table": a number, or an inline table ("k = { poly = [...] }")
            return _number_or_table(options, tables[0], value, meta, key, source)
        hint = options[0]  # "X | None": the table, when given
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, key + ".", source)
    if typing.get_origin(hint) is list:
        return _list(typing.get_args(hint)[0], value, meta, key, source)
    return _scalar(hint, value, meta, key, source)


def _number_or_table(options, table_cls, value, meta, key: str, source: str):
    """A field declared ``float | Table``: a dict is built as the table, anything else as the scalar.

    The field's bounds and choices apply to the scalar; its ``check`` sees whichever was given (the
    number, or the built table) and may refuse either.
    """
    if isinstance(value, dict):
        table = _build(table_cls, value, key + ".", source)
        if meta.get("check"):
            meta["check"](table, key, source)
        return table
    scalar = next(h for h in options if not dataclasses.is_dataclass(h))
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if scalar in (int, float) and not number or scalar not in (int, float) and not isinstance(value, scalar):
        what = "a number" if scalar in (int, float) else scalar.__name__
        raise ConfigError(key, f"must be {what} or a table, got {show(value)}", source)
    return _scalar(scalar, value, meta, key, source)


def _list(item, value, meta, key: str, source: str) -> list:
    """A list of ``item`` (tables, scalars or lists of scalars, each checked as the field says); ``check`` sees the
    whole list."""
    if not isinstance(value, list):
        raise ConfigError(key, f"must be a list, got {show(value)}", source)
    limit = meta.get("max_items") or MAX_LIST_ITEMS
    if len(value) > limit:
        raise ConfigError(key, f"may hold at most {limit} items, got {len(value)}", source)
    if dataclasses.is_dataclass(item):
        return [_build(item, v, f"{key}[{i}].", source) for i, v in enumerate(value)]
    item_meta = {**meta, "check": None}
    convert = _list if typing.get_origin(item) is list else _scalar  # list[list[float]]: each row as list[float]
    inner = typing.get_args(item)[0] if convert is _list else item
    items = [convert(inner, v, item_meta, f"{key}[{i}]", source) for i, v in enumerate(value)]
    if meta.get("check"):
        meta["check"](items, key, source)
    return items


_BOUNDS = (
    ("gt", lambda v, b: v > b, ">"),
    ("ge", lambda v, b: v >= b, ">="),
    ("le", lambda v, b: v <= b, "<="),
    ("lt", lambda v, b: v < b, "<"),
)


def _scalar(hint, value, meta, key, source):
    """One scalar value of type ``hint`` under the field metadata ``meta``, validated."""
    auto = meta.get("auto")
    if auto and isinstance(value, str) and value == "auto":
        if auto is True:
            return value
        raise ConfigError(key, auto, source)
    if auto is True and isinstance(value, str):
        raise ConfigError(key, f'must be a number or "auto", got {show(value)}', source)
    value = _coerce(hint, value, meta, key, source)
    _check_type(hint, value, key, source)
    if meta.get("choices") and value not in meta["choices"]:
        raise ConfigError(key, f"must be one of {', '.join(map(repr, meta['choices']))}, got {show(value)}", source)
    _check_bounds(hint, value, meta, key, source)
    if meta.get("check"):
        meta["check"](value, key, source)
    return value


def _coerce(hint, value, meta, key, source):
    """An integer where a float is declared as a float; a count where a string choice is declared as its string."""
    is_int = isinstance(value, int) and not isinstance(value, bool)
    if hint is str and is_int and str(value) in (meta.get("choices") or ()):
        return str(value)  # a choice of "auto" or a count: model_order = 3 as well as "3"
    if hint is float and is_int:
        if not abs(value) <= 1e300:
            raise ConfigError(key, f"must be a finite number, got {show(value)}", source)
        return float(value)
    return value


def _check_type(hint, value, key, source) -> None:
    """``value`` is of type ``hint`` (a bool is no number), a finite float within FLOAT_MAX, a printable string."""
    if hint is not bool and isinstance(value, bool) or not isinstance(value, hint):
        raise ConfigError(key, f"must be {hint.__name__}, got {show(value)}", source)
    if hint is float and not math.isfinite(value):
        raise ConfigError(key, f"must be a finite number, got {show(value)}", source)
    if hint is float and abs(value) > FLOAT_MAX:
        raise ConfigError(key, f"must lie within +-{FLOAT_MAX:g}, got {show(value)}", source)
    if hint is str:
        _check_string(value, key, source)


def _check_bounds(hint, value, meta, key, source) -> None:
    """The field's bounds; an integer without bounds of its own must fit :data:`INT_RANGE`."""
    bounds = dict(meta)
    if hint is int:  # what a device register, a C int or a numpy seed can hold
        bounds["ge"] = INT_RANGE[0] if bounds.get("ge") is None and bounds.get("gt") is None else bounds.get("ge")
        bounds["le"] = INT_RANGE[1] if bounds.get("le") is None and bounds.get("lt") is None else bounds.get("le")
    for bound, ok, text in _BOUNDS:
        b = bounds.get(bound)
        if b is not None and not ok(value, b):
            raise ConfigError(key, f"must be {text} {show(b)}, got {show(value)}", source)


def _check_string(value: str, key: str, source: str) -> None:
    if len(value) > MAX_STRING_CHARS:
        raise ConfigError(key, f"may be at most {MAX_STRING_CHARS} characters long, got {len(value)}", source)
    if not value.isprintable() and any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise ConfigError(key, f"must not contain control characters, got {show(value)}", source)
