"""Hostile driver descriptions: mutated copies of the shipped ``driver.toml`` files.

Whatever a driver folder holds, loading it and parsing its transport tables ends
in a :class:`~hilident.errors.ConfigError` naming the file and a key, or in a
valid description; never in another exception.
"""

from __future__ import annotations

import copy
import shutil
import tempfile
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilident.drivers.description import find_driver, load_driver, load_object_dictionary
from hilident.errors import ConfigError
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.modbus.register_map import RegisterMap
from support.hostile_toml import toml_string, toml_value

SHIPPED = ("myrio-board", "canopen-servo", "canopen-servo-fixed", "modbus-servo")
ORIGINALS = {name: tomllib.loads(find_driver(name).text) for name in SHIPPED}


def toml_text(data: dict) -> str:
    """A TOML document holding ``data`` (every top-level key as one inline value)."""
    return "\n".join(f"{toml_string(k)} = {toml_value(v)}" for k, v in data.items()) + "\n"


hostile_values = st.one_of(
    st.none(),  # delete the key
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, -1, 1, 2**31, 2**64, 65536, 0x10000]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e308, -1e308, 1e-308, 0.0]),
    st.text(max_size=12),
    st.sampled_from(["0x6064", "0x607D:2", "0xFFFFF", "i24", "real32", "fixed", "", "torque", "serial"]),
    st.lists(st.integers(-3, 70000), max_size=4),
    st.lists(st.text(max_size=4), max_size=3),
    st.dictionaries(st.text(max_size=6), st.integers(-2, 300), max_size=3),
)


def _paths(node, prefix=()):
    """Every key path into ``node`` (tables and list items)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield prefix + (i,)
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated_descriptions(draw):
    """A shipped description with a few values replaced, deleted or added."""
    name = draw(st.sampled_from(SHIPPED))
    data = copy.deepcopy(ORIGINALS[name])
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(data))
        path = draw(st.sampled_from(paths))
        parent = data
        for step in path[:-1]:
            parent = parent[step]
        value = draw(hostile_values)
        if draw(st.booleans()) and isinstance(parent, dict):
            parent[draw(st.sampled_from(["extra", "name", "type", "encoding", "objects"]))] = value or 1
        elif value is None:
            del parent[path[-1]]
        else:
            parent[path[-1]] = value
    return name, data


#: The EDS files of the shipped CANopen drivers: every hostile folder has them, as a real driver folder does.
EDS_FILES = [f for name in SHIPPED for f in find_driver(name).folder.glob("*.eds")]


def _parse_transport(driver) -> None:
    source = str(driver.folder / "driver.toml")
    if driver.transport == "canopen":
        CanopenDescription.from_sections(driver.sections, source, load_object_dictionary(driver))
    elif driver.transport == "modbus":
        RegisterMap.parse(driver.sections, driver.filter_slots, source)
    if isinstance(driver.sections.get("filters"), dict) and "encoding" in driver.sections["filters"]:
        FilterEncoding.from_table(driver.sections["filters"], source)


def _load(text: bytes):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "hostile"
        folder.mkdir()
        (folder / "driver.toml").write_bytes(text)
        for eds in EDS_FILES:
            shutil.copyfile(eds, folder / eds.name)
        try:
            driver = load_driver(folder)
            _parse_transport(driver)
        except ConfigError as exc:
            assert "driver.toml" in str(exc) and exc.key, exc
            assert len(str(exc)) < 2000
            return exc
        return driver


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_descriptions_survive_the_round_trip_of_this_test(name):
    driver = _load(toml_text(ORIGINALS[name]).encode())
    assert not isinstance(driver, ConfigError) and driver.name == name


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_descriptions())
def test_mutated_description_is_valid_or_a_config_error(case):
    _, data = case
    _load(toml_text(data).encode())


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(SHIPPED), st.integers(0, 10_000), st.binary(min_size=1, max_size=6))
def test_corrupted_bytes_are_valid_or_a_config_error(name, at, garbage):
    raw = find_driver(name).text.encode()
    at = at % len(raw)
    _load(raw[:at] + garbage + raw[at:])


@settings(max_examples=150, deadline=None)
@given(mutated_descriptions())
def test_transport_parsers_take_any_sections(case):
    """The parsers alone, fed the mutated tables directly (as an adapter or a twin would)."""
    _, data = case
    for parse in (
        lambda: CanopenDescription.from_sections(data, "d.toml"),
        lambda: RegisterMap.parse(data, 4, "d.toml"),
        lambda: FilterEncoding.from_table(data.get("filters", {}), "d.toml"),
    ):
        try:
            parse()
        except ConfigError as exc:
            assert exc.file == "d.toml" and exc.key, exc


def test_a_non_utf8_description_names_file_and_offset(tmp_path):
    (tmp_path / "driver.toml").write_bytes(b'[driver]\nname = "caf\xe9"\n')
    with pytest.raises(ConfigError, match=r"driver.toml.*not UTF-8.*0xe9 at offset 20"):
        load_driver(tmp_path)


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda d: d["board"].pop("loop_rate_hz"), "board.loop_rate_hz"),
        (lambda d: d["board"].update(loop_rate_hz=float("nan")), "board.loop_rate_hz"),
        (lambda d: d["board"].update(filter_slots=10**12), "board.filter_slots"),
        (lambda d: d["channels"][1].update(name=3), "channels[1].name"),
        (lambda d: d["channels"][1].update(colour="red"), "channels[1].colour"),
        (lambda d: d["channels"][4].update(scale=0.0), "channels[4].scale"),
        (lambda d: d["channels"][4].update(scale=float("inf")), "channels[4].scale"),
        (lambda d: d.update(channels=[{"name": "x"}] * 65), "channels"),
        (lambda d: d.update(board="fast"), "board"),
        (lambda d: d["driver"].pop("block_samples", None) or d["board"].pop("block_samples"), "board.block_samples"),
        (lambda d: d["channels"].append(dict(d["channels"][1])), "channels"),
    ],
)
def test_broken_serial_description_names_the_key(edit, key):
    data = copy.deepcopy(ORIGINALS["myrio-board"])
    edit(data)
    err = _load(toml_text(data).encode())
    assert isinstance(err, ConfigError) and err.key == key, err


@settings(max_examples=150, deadline=None)
@given(
    st.one_of(
        st.text(max_size=20),
        st.text(min_size=250, max_size=600),
        st.sampled_from(["a\x00b", "~nosuchuser/x", "./" + "x" * 300, "..", ".", "~", "myrio-board", "/", "drivers/"]),
    ),
    st.lists(st.sampled_from(["~nosuchuser", "y" * 300, "", "/nonexistent"]), max_size=2),
)
def test_any_driver_value_finds_a_driver_or_is_a_config_error(value, paths):
    try:
        driver = find_driver(value, paths)
    except ConfigError as exc:
        assert exc.key == "device.driver", exc
    else:
        assert driver.name in SHIPPED


@pytest.mark.parametrize("table, key", [("driver", "protocol_versoin"), ("board", "loop_rate")])
def test_a_misspelt_key_is_named_with_the_known_ones(table, key):
    data = copy.deepcopy(ORIGINALS["myrio-board"])
    data[table][key] = 1
    err = _load(toml_text(data).encode())
    assert isinstance(err, ConfigError) and err.key == f"{table}.{key}" and "known here" in err.message
