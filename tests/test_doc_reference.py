"""The configuration reference of the site covers every key: the generator (``docs/hooks/config_page.py``) is
called directly, no site is built. A key added to a table without its spec or its help fails here."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re
import typing

import pytest

from hilident.config.tables import Config
from support.doc_blocks import hook_module

#: A row of a generated key table: the key, then type, default, unit, allowed values and help.
ROW = re.compile(r"^\| `(\w+)` \| (.*) \|$", re.M)


def public_fields(cls: type) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if not f.metadata.get("internal")]


def tables_below(cls: type, path: str) -> list[tuple[str, type]]:
    """``(dotted path, table class)`` of every table nested in ``cls`` at any depth, ``cls`` itself left out."""
    found = []
    hints = typing.get_type_hints(cls)
    for field in public_fields(cls):
        key = f"{path}.{field.name}" if path else field.name
        for option in typing.get_args(hints[field.name]) or (hints[field.name],):
            if dataclasses.is_dataclass(option):
                found += [(key, typing.cast(type, option)), *tables_below(typing.cast(type, option), key)]
    return found


def sections(page: str) -> dict[str, dict[str, list[str]]]:
    """Section title -> {key: its cells (type, default, unit, allowed, help)} of a generated reference page."""
    parts = re.split(r"^## `?(.+?)`?\n", page, flags=re.M)
    return {
        title: {key: re.split(r"(?<!\\) \| ", cells) for key, cells in ROW.findall(text)}
        for title, text in zip(parts[1::2], parts[2::2], strict=True)
    }


@pytest.fixture(scope="module")
def config_page():
    return hook_module("config_page")


def test_every_key_of_every_config_table_has_a_row_with_its_type_default_and_help(config_page):
    shown = sections(config_page.config_reference())
    tables = tables_below(Config, "")
    assert len(tables) >= 20
    for path, cls in tables:
        rows = shown.get(f"[{path}]")
        assert rows is not None, f"[{path}] ({cls.__name__}) has no section in the configuration reference"
        for field in public_fields(cls):
            key = f"{path}.{field.name}"
            assert "doc" in field.metadata, f"[{key}] is not declared with spec(): the schema cannot validate it"
            assert field.name in rows, f"[{key}] is missing from the configuration reference"
            type_, default, _unit, _allowed, help_ = rows[field.name]
            assert type_ and default, f"[{key}]: no type or default shown"
            assert help_, f"[{key}] has no help: give its spec a doc=... (hilident.config.tables)"


def test_the_reference_shows_bounds_choices_and_units(config_page):
    rows = sections(config_page.config_reference())
    node_id = rows["[device.canopen]"]["node_id"]
    assert node_id[:2] == ["integer", "`1`"] and node_id[3] == "≥ 1, ≤ 127"
    hold = rows["[friction_test]"]["hold_s"]
    assert hold[2] == "s" and hold[3] == "&gt; 0"
    amplitude = rows["[excitation]"]["amplitude_nm"]
    assert amplitude[0] == 'float or "auto"' and amplitude[2] == "N·m"
    assert rows["[limits]"]["torque_nm"][1] == "*required*"
    assert rows["[device]"]["canopen"][0] == "table"


def driver_table_classes() -> list[type]:
    """The dataclasses of ``hilident.drivers`` and ``hilident.protocol`` whose every field is a spec: the tables
    of a ``driver.toml``."""
    found = []
    for package_name in ("hilident.drivers", "hilident.protocol"):
        package = importlib.import_module(package_name)
        for info in pkgutil.walk_packages(package.__path__, package_name + "."):
            module = importlib.import_module(info.name)
            for value in vars(module).values():
                if inspect.isclass(value) and dataclasses.is_dataclass(value) and value.__module__ == info.name:
                    fields = public_fields(value)
                    if fields and all("doc" in f.metadata for f in fields):
                        found.append(value)
    return found


def test_every_table_of_a_driver_file_has_a_section_with_every_key(config_page):
    page = config_page.driver_keys_reference()
    classes = driver_table_classes()
    assert len(classes) >= 15
    blocks = page.split("\n## ")
    for cls in classes:
        declared = f"Declared by `{cls.__module__}.{cls.__qualname__}`."
        shown = [b for b in blocks if declared in b]  # a table nested in two others has a section under each
        assert shown, f"{cls.__qualname__} ({cls.__module__}) has no section in the driver file reference"
        for block in shown:
            assert {key for key, _ in ROW.findall(block)} == {f.name for f in public_fields(cls)}, cls.__qualname__
