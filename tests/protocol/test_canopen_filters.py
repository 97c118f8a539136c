"""Where a CANopen drive keeps its filter slots: records, word blocks and field-major layouts, and bypassing
a slot that has no enable."""

from __future__ import annotations

import pathlib
import re
import tomllib

import pytest

from hilident.errors import ConfigError, DataError
from hilident.protocol.canopen_filters import ENABLED, parse_filter_objects
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.filter_encoding import FilterEncoding

DOC = pathlib.Path(__file__).parents[2] / "docs" / "filter_encodings.md"
RATE = 16000.0


def _documented() -> list[dict]:
    tables = [tomllib.loads(b)["filters"] for b in re.findall(r"```toml\n(.*?)```", DOC.read_text(), re.DOTALL)]
    return [t for t in tables if "objects" in t or isinstance(t.get("fields"), dict)]


def test_every_documented_slot_layout_parses_and_names_every_field_of_its_encoding():
    tables = _documented()
    assert len(tables) >= 4
    for table in tables:
        fo = parse_filter_objects(table, "docs/filter_encodings.md")
        encoding = FilterEncoding.from_table(table)
        assert fo is not None and set(fo.slots[0]) == set(encoding.fields)
        assert fo.in_block == (encoding.kind == "word_block")
        assert fo.has_enable or fo.in_block or encoding.bypassable


def test_record_block_and_field_major_layouts():
    record = parse_filter_objects({"objects": ["0x2300", "0x2301"], "fields": {"b0": 2, "a1": 5}})
    assert record.address(1, "a1") == ObjectAddress(0x2301, 5) and record.address(1, ENABLED) == ObjectAddress(
        0x2301, 1
    )
    block = parse_filter_objects({"encoding": "word_block", "objects": ["0x2106"]})
    assert block.in_block and not block.has_enable and block.where(0) == "object 0x2106"
    with pytest.raises(ConfigError, match="filters.enable"):
        block.address(0, ENABLED)
    beckhoff_like = parse_filter_objects(
        {
            "fields": {"center": ["0x3664"], "width": ["0x3665"]},
            "enable": ["0x3666"],
            "enable_values": {"on": 2, "off": 0},
        }
    )
    assert (beckhoff_like.enable_on, beckhoff_like.enable_off) == (2, 0)
    assert beckhoff_like.owner(ObjectAddress(0x3666)) == (0, ENABLED)
    assert beckhoff_like.owner(ObjectAddress(0x3667)) is None


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"objects": ["0x2023"], "fields": {"center": 1, "band": 3}}, "filters.enable_subindex"),
        ({"fields": {"a": ["0x3406:5", "0x3406:6"], "b": ["0x3406:9"]}, "enable": "none"}, "filters.fields"),
        ({"fields": {"a": ["0x3406:5"]}}, "filters.enable"),
        ({"fields": {"a": ["0x3406:5"]}, "enable": ["0x3406:5"]}, "filters.enable"),
        (
            {"fields": {"a": ["0x3406:5"]}, "enable": ["0x3406:6"], "enable_values": {"on": 1, "off": 1}},
            "filters.enable_values",
        ),
        ({"fields": {"a": ["0x3406:5"], "b": 2}, "enable": "none"}, "filters.fields.b"),  # a sub-index of what?
    ],
)
def test_a_malformed_layout_is_refused_naming_its_key(table, key):
    with pytest.raises(ConfigError) as err:
        parse_filter_objects(table, "driver.toml")
    assert err.value.key == key


def test_a_pole_zero_slot_without_an_enable_is_bypassed_by_its_zeros_on_its_poles():
    table = {
        "encoding": "pole_zero_q",
        "scales": {"pole_hz": 0.001, "pole_q": 0.001, "zero_hz": 0.001, "zero_q": 0.001},
        "ranges": {"pole_hz": [5, 5000], "zero_hz": [5, 5000], "pole_q": [0.2, 20], "zero_q": [0.1, 5]},
    }
    enc = FilterEncoding.from_table(table)
    notch = {"pole_hz": 300_000, "pole_q": 12_000, "zero_hz": 310_000, "zero_q": 150}
    neutral = enc.neutral(notch)
    assert neutral["pole_hz"] == neutral["zero_hz"] == 300_000
    assert neutral["pole_q"] == neutral["zero_q"] == 5_000  # 12 is beyond the zero's range: the shared end
    section = enc.applied(neutral, RATE)
    assert section.b == section.a  # the identity
    with pytest.raises(DataError, match="needs an enable"):
        FilterEncoding.from_table({"encoding": "center_band"}).neutral({"center": 100, "band": 2})
