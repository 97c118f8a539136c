"""The Modbus register-map language: types, word and byte order, scale and offset, ranges, bit fields,
parameter addressing rules, capabilities, and errors that name the key and the file."""

from __future__ import annotations

import copy
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.drivers.description import find_driver
from hilident.errors import ConfigError, DataError
from hilident.protocol.modbus.codecs import decode_values, encode_values
from hilident.protocol.modbus.filter_slots import FieldSlots
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.registers import ParameterRule

STRUCT = {"u16": "H", "i16": "h", "u32": "I", "i32": "i", "f32": "f", "u64": "Q", "i64": "q", "f64": "d"}
SOURCE = "/drives/x/driver.toml"


def reference_words(type_: str, value, word_order: str, byte_order: str) -> list[int]:
    """Registers by struct: big-endian bytes, words reversed for "little", bytes swapped for "little"."""
    data = struct.pack(">" + STRUCT[type_], value)
    words = [data[i : i + 2] for i in range(0, len(data), 2)]
    if word_order == "little":
        words = words[::-1]
    return [int.from_bytes(w, "little" if byte_order == "little" else "big") for w in words]


def integers(type_: str):
    bits = int(type_[1:])
    if type_.startswith("u"):
        return st.integers(0, 2**bits - 1)
    return st.integers(-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


@settings(max_examples=150, deadline=None)
@given(
    st.data(),
    st.sampled_from(["u16", "i16", "u32", "i32", "u64", "i64"]),
    st.sampled_from(["big", "little"]),
    st.sampled_from(["big", "little"]),
)
def test_integer_types_are_laid_out_as_struct_lays_them(data, type_, word_order, byte_order):
    value = data.draw(integers(type_))
    regs = encode_values([value], type_, word_order=word_order, byte_order=byte_order)
    assert regs.tolist() == reference_words(type_, value, word_order, byte_order)
    spec = {"address": 10, "type": type_, "word_order": word_order, "byte_order": byte_order}
    register = parameter_map({"v": spec}).register("v")
    assert register.decode(regs) == value  # exact, 64-bit values included


@settings(max_examples=100, deadline=None)
@given(
    st.floats(allow_nan=False, allow_infinity=False, width=32),
    st.sampled_from(["f32", "f64"]),
    st.sampled_from(["big", "little"]),
    st.sampled_from(["big", "little"]),
)
def test_float_types_round_trip(value, type_, word_order, byte_order):
    regs = encode_values([value], type_, word_order=word_order, byte_order=byte_order)
    assert regs.tolist() == reference_words(type_, value, word_order, byte_order)
    assert decode_values(regs, type_, word_order=word_order, byte_order=byte_order)[0] == value


@settings(max_examples=100, deadline=None)
@given(st.integers(-32768, 32767), st.sampled_from([0.1, 0.01, 2.5]), st.floats(-100, 100))
def test_scale_and_offset_round_trip_on_the_grid(raw, scale, offset):
    physical = raw * scale + offset
    regs = encode_values([physical], "i16", scale, offset=offset)
    assert regs.tolist() == reference_words("i16", raw, "big", "big")
    assert decode_values(regs, "i16", scale, offset=offset)[0] == pytest.approx(physical, abs=1e-9)


def base_sections(registers: dict, **modbus) -> dict:
    """A parameter drive's map: the given registers, a rule, an identity table."""
    regs = {"model": {"parameter": "P01.00", "type": "u16"}, **registers}
    mb = {
        "parameters": {"address": "group * 0x100 + index"},
        "registers": regs,
        "identity": {"registers": ["model"]},
        **modbus,
    }
    return {"modbus": mb}


def parameter_map(registers: dict, filter_slots: int = 0, **modbus) -> RegisterMap:
    return RegisterMap.parse(base_sections(registers, **modbus), filter_slots, SOURCE)


def test_register_attributes_come_from_the_table_and_the_defaults():
    m = parameter_map(
        {
            "speed": {"parameter": "P18.01", "type": "i16", "unit": "rpm"},
            "temp": {"address": 0x2000, "type": "u16", "table": "input", "scale": 0.1, "offset": -40.0, "unit": "degC"},
            "pos": {"parameter": "P18.07", "type": "i32", "word_order": "little"},
        },
        word_order="big",
        byte_order="little",
    )
    speed, temp, pos = m.register("speed"), m.register("temp"), m.register("pos")
    assert (speed.address, speed.type, speed.access, speed.byte_order) == (0x1201, "i16", "r", "little")
    assert (temp.table, temp.writable) == ("input", False)
    assert temp.decode(temp.encode(21.5)) == pytest.approx(21.5)
    assert temp.encode(-40.0) == [0]  # raw 0 is the offset
    assert (pos.word_order, pos.byte_order, pos.count) == ("little", "little", 2)
    assert not m.excitation and m.filters is None


def test_writes_outside_the_range_are_refused_naming_the_register():
    m = parameter_map(
        {"notch": {"parameter": "P08.02", "type": "u16", "access": "rw", "unit": "Hz", "min": 10, "max": 4000}}
    )
    assert m.encode("notch", 4000) == [4000]
    with pytest.raises(DataError, match=r"0x0802 \(notch, P08.02\): 4001 Hz is outside its range 10\.\.4000 Hz"):
        m.encode("notch", 4001)
    with pytest.raises(DataError, match="outside its range"):
        m.encode("notch", 9)


def test_bit_fields_are_read_shifted_down():
    m = parameter_map({"status": {"address": 0x1200, "type": "u16", "bits": {"ready": 0x0001, "mode": 0x0030}}})
    r = m.register("status")
    assert r.bit_field("mode", [0x0021]) == 2
    assert r.bit_field("ready", [0x0021]) == 1
    assert r.bit_field("ready", [0x0020]) == 0


@pytest.mark.parametrize(
    "text,group,index,base",
    [
        ("group * 0x100 + index", 256, 1, 0),
        ("group*256 + 2*index", 256, 2, 0),
        ("0x100 * group + index * 2 + 0x4000", 256, 2, 0x4000),
        ("index + group * 100", 100, 1, 0),
    ],
)
def test_addressing_rules_are_parsed_not_evaluated(text, group, index, base):
    rule = ParameterRule.parse(text)
    assert (rule.group_factor, rule.index_factor, rule.base) == (group, index, base)
    assert rule.address_of("P2.23") == 2 * group + 23 * index + base
    assert rule.code(rule.address_of("P08.02")) == "P08.02"


@pytest.mark.parametrize(
    "text",
    [
        "group * index",
        "__import__('os').system('true')",
        "group + 1",
        "group * 0x100 - index",
        "",
        "group ** 2 + index",
    ],
)
def test_a_rule_that_is_not_a_sum_of_terms_names_the_key(text):
    sections = base_sections({})
    sections["modbus"]["parameters"]["address"] = text
    with pytest.raises(ConfigError) as err:
        RegisterMap.parse(sections, 0, SOURCE)
    assert err.value.key == "modbus.parameters.address" and err.value.file == SOURCE


def test_delta_style_rule_puts_p2_23_at_0x022e():
    rule = ParameterRule.parse("group * 0x100 + index * 2")
    assert rule.address_of("P2.23") == 0x022E
    assert rule.code(0x022F) is None  # the second word of a 32-bit parameter is no parameter of its own


def test_undeclared_parameters_resolve_through_the_rule():
    m = parameter_map({})
    r = m.parameter("P10.04")
    assert (r.address, r.type, r.writable) == (0x0A04, "u16", True)
    with pytest.raises(DataError, match="not a parameter code"):
        m.parameter("X10.04")
    assert "parameter P03.03" in m.describe(0x0303)


@pytest.mark.parametrize(
    "change,key",
    [
        (
            lambda s: s["modbus"]["registers"].update(x={"parameter": "P01.01", "type": "u16", "colour": 1}),
            "modbus.registers.x.colour",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"parameter": "P01.01", "type": "u24"}),
            "modbus.registers.x.type",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"type": "u16"}) or s["modbus"].pop("parameters"),
            "modbus.registers.model.address",
        ),
        (
            lambda s: s["modbus"]["registers"].update(
                x={"address": 5, "type": "u16", "table": "input", "access": "rw"}
            ),
            "modbus.registers.x.access",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"address": 5, "type": "u16", "min": 9, "max": 1}),
            "modbus.registers.x.min",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"address": 5, "type": "u16", "max": 10, "default": 11}),
            "modbus.registers.x.default",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"address": 5, "type": "u16", "bits": {"a": 0x10000}}),
            "modbus.registers.x.bits.a",
        ),
        (
            lambda s: s["modbus"]["registers"].update(x={"address": 5, "type": "f32", "bits": {"a": 1}}),
            "modbus.registers.x.bits",
        ),
        (lambda s: s["modbus"]["registers"].update(x={"address": 0x0100, "type": "u16"}), "modbus.registers.x"),
        (
            lambda s: s["modbus"]["registers"].update(x={"address": 0x0200, "parameter": "P02.01", "type": "u16"}),
            "modbus.registers.x.address",
        ),
        (lambda s: s["modbus"].pop("identity"), "modbus.identity"),
        (lambda s: s["modbus"]["identity"].update(registers=["nope"]), "modbus.identity.registers"),
        (lambda s: s["modbus"].update(save={"register": "model", "value": 1}), "modbus.save.register"),
        (lambda s: s["modbus"].update(stop={"model": 0}), "modbus.stop.model"),
        (lambda s: s["modbus"]["parameters"].update(prefix="P-"), "modbus.parameters.prefix"),
    ],
)
def test_invalid_parameter_maps_name_the_key_and_the_file(change, key):
    sections = base_sections({})
    change(sections)
    with pytest.raises(ConfigError) as err:
        RegisterMap.parse(sections, 0, SOURCE)
    assert err.value.key == key, err.value
    assert err.value.file == SOURCE


def notch_sections() -> dict:
    sections = base_sections(
        {
            "c": {"parameter": "P08.02", "type": "u16", "access": "rw", "min": 10, "max": 4000},
            "w": {"parameter": "P08.03", "type": "u16", "access": "rw"},
            "d": {"parameter": "P08.04", "type": "u16", "access": "rw"},
        }
    )
    sections["modbus"]["filters"] = {
        "off": {"center": 4000},
        "slots": [{"center": "c", "width": "w", "depth": "P08.04"}],
    }
    sections["filters"] = {
        "encoding": "notch_parameters",
        "center_scale": 1.0,
        "depth_scale": 1.0,
        "width_unit": "index",
        "depth_unit": "percent",
        "width_table": [0.5, 1.0, 2.0],
    }
    return sections


def test_filter_slots_of_named_registers_and_parameter_codes():
    m = RegisterMap.parse(notch_sections(), 1, SOURCE)
    assert isinstance(m.filters, FieldSlots) and not m.filters.has_enable
    assert {f: r.address for f, r in m.filters.fields(0).items()} == {"center": 0x802, "width": 0x803, "depth": 0x804}
    assert m.filters.slot_at(0x803) == 0 and m.filters.slot_at(0x805) is None
    assert "filter slot 0" in m.describe(0x802, 3)


@pytest.mark.parametrize(
    "change,key",
    [
        (lambda s: s["modbus"]["filters"].pop("off"), "modbus.filters.off"),
        (lambda s: s["modbus"]["filters"]["slots"][0].pop("width"), "modbus.filters.slots[0]"),
        (lambda s: s["modbus"]["filters"]["slots"][0].update(width="model"), "modbus.filters.slots[0].width"),
        (
            lambda s: s["modbus"]["filters"]["slots"].append(dict(s["modbus"]["filters"]["slots"][0])),
            "modbus.filters.slots",
        ),
        (lambda s: s["filters"].update(width_table=[]), "filters.width_table"),
    ],
)
def test_invalid_filter_slots_name_the_key(change, key):
    sections = notch_sections()
    change(sections)
    with pytest.raises(ConfigError) as err:
        RegisterMap.parse(sections, 1, SOURCE)
    assert err.value.key == key, err.value


def test_the_table_and_capture_map_loads_unchanged_with_its_capability():
    m = RegisterMap.from_driver(find_driver("modbus-servo"))
    assert m.excitation and m.rule is None and m.save is None
    assert m.register("fault_value").decode(m.encode("fault_value", 1.5)) == 1.5
    assert m.describe(100) == "register 100 (control_word)"


def test_requests_never_mix_holding_and_input_registers():
    m = parameter_map(
        {
            "a": {"address": 0x10, "type": "u16"},
            "b": {"address": 0x11, "type": "u16"},
            "c": {"address": 0x12, "type": "u16", "table": "input"},
            "d": {"address": 0x13, "type": "u16", "table": "input"},
        }
    )
    assert m.request_groups(["a", "b", "c", "d"]) == [("holding", 0x10, 2), ("input", 0x12, 2)]
    assert "input register" in m.describe(0x12, table="input")


def test_hostile_register_tables_are_refused_with_the_key():
    sections = base_sections({})
    for bad, key in (("x", "modbus.registers.bad"), (3, "modbus.registers.bad")):
        s = copy.deepcopy(sections)
        s["modbus"]["registers"]["bad"] = bad
        with pytest.raises(ConfigError) as err:
            RegisterMap.parse(s, 0, SOURCE)
        assert err.value.key == key
    s = copy.deepcopy(sections)
    s["modbus"]["registers"]["big"] = {"address": 65535, "type": "u64"}
    with pytest.raises(ConfigError, match="16-bit address space"):
        RegisterMap.parse(s, 0, SOURCE)
    assert np.iinfo(np.uint16).max == 65535
