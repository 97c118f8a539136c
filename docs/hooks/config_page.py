"""The configuration reference pages, written from the schema's own field specs at build time.

Every TOML table hilident reads is a frozen dataclass whose fields carry their
spec (``hilident.config.schema.spec``: default, bounds, choices, list length,
``"auto"``, help). The run configuration is walked from
``hilident.config.tables.Config``; the tables of a ``driver.toml`` are found in
the modules of ``hilident.drivers`` and ``hilident.protocol`` that declare them.
Each table becomes a section with one row per key: its type, default, unit,
allowed values and help.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re
import types
import typing
from dataclasses import dataclass

from markdown_text import cell, rst_to_markdown, sentence

#: Unit of a key by the end of its name (DESIGN.md: names carry the unit), longest ending first.
UNIT_OF_SUFFIX = (
    ("_nm_per_mps2", "N·m/(m/s²)"),
    ("_nm_per_mps", "N·m/(m/s)"),
    ("_nm_per_a", "N·m/A"),
    ("_pos_per_s", "1/s"),
    ("_percent_per_day", "%/day"),
    ("_mps3", "m/s³"),
    ("_mps2", "m/s²"),
    ("_mps", "m/s"),
    ("_nm", "N·m"),
    ("_hz", "Hz"),
    ("_ms", "ms"),
    ("_db", "dB"),
    ("_kg", "kg"),
    ("_s", "s"),
    ("_m", "m"),
    ("_n", "N"),
    ("_a", "A"),
)

#: Packages whose modules declare the tables of a ``driver.toml``.
DRIVER_TABLE_PACKAGES = ("hilident.drivers", "hilident.protocol")


@dataclass(frozen=True)
class Key:
    """One key of a table as the reference shows it: plain text, except ``default``, a Markdown cell."""

    name: str
    type: str  # as TOML writes it: float, list of string, table, ...
    default: str  # the value as code, or *required*, *unset*
    unit: str  # from the key's name ("" when it carries none)
    allowed: str  # bounds, choices, list length, "auto"
    help: str


@dataclass(frozen=True)
class Table:
    """One TOML table: its title (``[device.canopen]``), what it is, where it is declared, its keys."""

    title: str
    summary: str
    declared_in: str
    keys: tuple[Key, ...]
    notes: tuple[str, ...] = ()


# --- the run configuration -------------------------------------------------------------------------------------


def run_config_tables() -> list[Table]:
    """Every table of a run configuration, in the order ``Config`` declares them, sub-tables after their parent."""
    from hilident.config.tables import Config

    tables: list[Table] = []
    hints = typing.get_type_hints(Config)
    for field in public_fields(Config):
        for table_class, title in nested_tables(hints[field.name], field.name):
            walk_table(table_class, field.name, title, tables)
    return tables


def walk_table(cls: type, path: str, title: str, tables: list[Table]) -> None:
    """Append the table ``cls`` (at dotted ``path``) and, after it, every table nested in it."""
    hints = typing.get_type_hints(cls)
    fields = public_fields(cls)
    keys = []
    for field in fields:
        hint, key = hints[field.name], dotted(path, field.name)
        see = [child_title for _, child_title in nested_tables(hint, key)]
        keys.append(key_row(field, hint, see))
    tables.append(Table(title, class_summary(cls), qualified_name(cls), tuple(keys), moved_key_notes(cls, title)))
    for field in fields:
        for table_class, child_title in nested_tables(hints[field.name], dotted(path, field.name)):
            walk_table(table_class, dotted(path, field.name), child_title, tables)


def dotted(path: str, name: str) -> str:
    """The dotted key ``name`` below the table at ``path`` (the file's top level when ``path`` is empty)."""
    return f"{path}.{name}" if path else name


def nested_tables(hint: object, path: str) -> list[tuple[type, str]]:
    """The table classes a field of type ``hint`` holds, each with the title of its table at ``path``."""
    if dataclasses.is_dataclass(hint):
        return [(typing.cast(type, hint), f"[{path}]")]
    if typing.get_origin(hint) is list:
        return [(item, f"[[{path}]]") for item in typing.get_args(hint) if dataclasses.is_dataclass(item)]
    if isinstance(hint, types.UnionType):
        return [(option, f"[{path}]") for option in typing.get_args(hint) if dataclasses.is_dataclass(option)]
    return []


def moved_key_notes(cls: type, title: str) -> tuple[str, ...]:
    """A note naming the flat keys of an earlier release that ``cls`` still reads, and where each lives now."""
    moved = getattr(cls, "moved_keys", {})
    if not moved:
        return ()
    table = title.strip("[]")
    places = ", ".join(f"`{name}` → `[{table}.{sub}]`" for name, sub in moved.items())
    return (
        f"Flat keys of the previous release, still read with a `DeprecationWarning` that names the new place: "
        f"{places}. A key given both flat and in its sub-table is an error.",
    )


# --- the tables of a driver.toml ---------------------------------------------------------------------------------


def driver_file_tables() -> list[Table]:
    """Every table of a ``driver.toml`` that the typed schema declares, module by module."""
    classes = [cls for module in driver_table_modules() for cls in spec_classes(module)]
    nested = {child for cls in classes for child, _ in children(cls)}
    tables: list[Table] = []
    for cls in classes:
        if cls not in nested:
            path, title = root_title(cls)
            walk_table(cls, path, title, tables)
    return tables


def driver_table_modules() -> list[types.ModuleType]:
    """The modules of :data:`DRIVER_TABLE_PACKAGES`, imported, in name order."""
    modules = []
    for package_name in DRIVER_TABLE_PACKAGES:
        package = importlib.import_module(package_name)
        names = sorted(info.name for info in pkgutil.walk_packages(package.__path__, package_name + "."))
        modules += [package, *(importlib.import_module(name) for name in names)]
    return modules


def spec_classes(module: types.ModuleType) -> list[type]:
    """The dataclasses ``module`` defines whose fields are all declared with ``spec`` (its typed tables)."""
    found = []
    for value in vars(module).values():
        if inspect.isclass(value) and dataclasses.is_dataclass(value) and value.__module__ == module.__name__:
            fields = public_fields(value)
            if fields and all("doc" in field.metadata for field in fields):
                found.append(value)
    return found


def children(cls: type) -> list[tuple[type, str]]:
    """The tables nested in ``cls``, each with its field name."""
    hints = typing.get_type_hints(cls)
    return [(child, field.name) for field in public_fields(cls) for child, _ in nested_tables(hints[field.name], "")]


def root_title(cls: type) -> tuple[str, str]:
    """The dotted path and the title of a table no other table nests, from its docstring (``[modbus.table]``)."""
    first_line = (inspect.getdoc(cls) or cls.__name__).splitlines()[0]
    spans = re.findall(r"``(\[\[?[^`]+?\]\]?)``", first_line)
    if spans:
        return spans[0].strip("[]"), " and ".join(spans)
    clause = re.split(r"[:;]", first_line, maxsplit=1)[0].rstrip(".")
    return "", rst_to_markdown(clause).replace("`", "")


# --- one table, one key ----------------------------------------------------------------------------------------


def public_fields(cls: type) -> list[dataclasses.Field]:
    """The fields of ``cls`` a file may set (not the ``internal`` ones the loader fills in)."""
    return [field for field in dataclasses.fields(cls) if not field.metadata.get("internal")]


def class_summary(cls: type) -> str:
    """The first line of the class's docstring in Markdown (dataclasses without one get a generated signature)."""
    doc = cls.__doc__ or ""
    if not doc or doc.startswith(f"{cls.__name__}("):
        return ""
    return rst_to_markdown(sentence(inspect.cleandoc(doc).split("\n\n")[0]))


def qualified_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def key_row(field: dataclasses.Field, hint: object, see: list[str]) -> Key:
    """The reference row of one field: type, default, unit, allowed values, help (and the tables it holds)."""
    meta = field.metadata
    help_text = sentence(meta.get("doc", ""))
    if see:
        keys_in = "its keys: " + " and ".join(see)
        help_text = f"{help_text}; {keys_in}" if help_text else keys_in
    return Key(
        name=field.name,
        type=type_text(hint, meta),
        default=default_text(field),
        unit=unit_of(field.name),
        allowed=allowed_text(meta),
        help=help_text,
    )


def type_text(hint: object, meta: typing.Mapping) -> str:
    """How a value of ``hint`` is written in TOML: ``float``, ``list of string``, ``float or table``, ..."""
    if isinstance(hint, types.UnionType):
        options = [option for option in typing.get_args(hint) if option is not type(None)]
        words = [type_text(option, {}) for option in options]
        if "float" in words and "string" in words and meta.get("auto") is True:
            return 'float or "auto"'
        return " or ".join(words)
    if dataclasses.is_dataclass(hint):
        return "table"
    if typing.get_origin(hint) is list:
        (item,) = typing.get_args(hint) or (None,)
        if item is None:
            return "list"
        return "array of tables" if dataclasses.is_dataclass(item) else f"list of {type_text(item, {})}"
    if typing.get_origin(hint) is tuple:
        return "list of " + " and ".join(type_text(item, {}) for item in typing.get_args(hint))
    names = {bool: "bool", int: "integer", float: "float", str: "string", dict: "table", list: "list"}
    return names.get(typing.cast(type, hint), "any")


def default_text(field: dataclasses.Field) -> str:
    """The default as a Markdown cell: the TOML value as code, or *required*, *unset*, *its keys' defaults*."""
    if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
        return "*required*"
    value = field.default if field.default is not dataclasses.MISSING else field.default_factory()
    if value is None:
        return "*unset*"
    if dataclasses.is_dataclass(value):
        return "*its keys' defaults*"
    return code(toml_value(value))


def toml_value(value: object) -> str:
    """``value`` as TOML writes it (a nested table as ``table``)."""
    if value is None:
        return "unset"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{key} = {toml_value(item)}" for key, item in value.items()) + "}"
    if dataclasses.is_dataclass(value):
        return "table"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def unit_of(name: str) -> str:
    """The unit a key's name carries (``hold_s`` -> ``s``), or ``""``."""
    return next((unit for suffix, unit in UNIT_OF_SUFFIX if name.endswith(suffix)), "")


def allowed_text(meta: typing.Mapping) -> str:
    """The bounds, choices, list length and ``"auto"`` of a field's spec, as a reader writes them."""
    parts = []
    if meta.get("choices"):
        parts.append("one of " + ", ".join(toml_value(choice) for choice in meta["choices"]))
    bounds = [(meta.get(name), sign) for name, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"))]
    parts += [f"{sign} {toml_value(bound)}" for bound, sign in bounds if bound is not None]
    if meta.get("max_items"):
        parts.append(f"at most {meta['max_items']} items")
    if meta.get("auto") is True:
        parts.append('or "auto"')
    return ", ".join(parts)


# --- the pages ---------------------------------------------------------------------------------------------------


def config_reference() -> str:
    """The Markdown of the run-configuration reference: every table and key of a config file."""
    intro = (
        "# Configuration keys\n\n"
        "Generated from the typed tables of `hilident.config.tables` when the site is built: every key a run "
        "configuration may hold, with its type, default, unit, allowed values and help. Every key is validated "
        "when the file is loaded; an unknown key, a wrong type or a value out of range is an error naming "
        "`[table.key]` and the file (exit 2). The [configuration guide](../configuration.md) explains how the "
        "keys work together.\n\n"
    )
    return intro + "\n".join(table_section(table) for table in run_config_tables())


def driver_keys_reference() -> str:
    """The Markdown of the ``driver.toml`` reference: every table the typed schema declares for a driver."""
    intro = (
        "# Driver file keys\n\n"
        "Generated from the typed tables the modules of `hilident.drivers` and `hilident.protocol` declare, "
        "when the site is built. Tables whose keys are names the driver chooses (`[canopen.objects]`, "
        "`[canopen.modes]`, `[modbus.control]`, ...) are read by small functions next to these classes; "
        "[one schema for every TOML file](../schema.md) and [drivers and protocols](../drivers.md) describe "
        "them.\n\n"
    )
    return intro + "\n".join(table_section(table) for table in driver_file_tables())


def table_section(table: Table) -> str:
    """One table: heading, what it is, where it is declared, its keys."""
    lines = [f"## `{table.title}`\n" if table.title.startswith("[") else f"## {table.title}\n"]
    if table.summary:
        lines.append(table.summary + "\n")
    lines.append(f"Declared by `{table.declared_in}`.\n")
    lines += [note + "\n" for note in table.notes]
    lines += ["| key | type | default | unit | allowed | help |", "|---|---|---|---|---|---|"]
    lines += [key_line(key) for key in table.keys]
    return "\n".join(lines) + "\n"


def key_line(key: Key) -> str:
    """One key as a table row; code-like cells in code spans, prose escaped."""
    cells = [f"`{key.name}`", key.type, key.default, key.unit, cell(key.allowed), cell(key.help)]
    return "| " + " | ".join(cells) + " |"


def code(text: str) -> str:
    """``text`` as a code span that survives a table cell (a backtick inside it is doubled around)."""
    return f"`` {text} ``" if "`" in text else f"`{text}`"
