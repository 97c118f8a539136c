"""CANopen object roles, mapping entries, value coding and the driver descriptions that use them."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilident.drivers.description import find_driver, load_object_dictionary
from hilident.errors import ConfigError, DataError
from hilident.protocol import canopen_objects as co
from hilident.protocol import canopen_types as ct


def test_addresses_parse_and_print():
    assert ct.parse_address("0x6064") == ct.ObjectAddress(0x6064, 0)
    assert ct.parse_address("0x607D:2") == ct.ObjectAddress(0x607D, 2)
    assert ct.parse_address("607d:0x2") == ct.ObjectAddress(0x607D, 2)
    assert str(ct.ObjectAddress(0x2201, 7)) == "0x2201:7"
    with pytest.raises(ConfigError, match="canopen.objects.x"):
        ct.parse_address("sixty", "canopen.objects.x")
    with pytest.raises(ConfigError):
        ct.parse_address("0x12345")


@given(st.integers(0, 0xFFFF), st.integers(0, 0xFF), st.sampled_from([8, 16, 32, 64]))
def test_mapping_entries_round_trip(index, sub, bits):
    addr = ct.ObjectAddress(index, sub)
    entry = co.mapping_entry(addr, bits)
    assert 0 <= entry < 2**32 and co.parse_mapping_entry(entry) == (addr, bits)


def test_mapping_entry_is_the_cia301_layout():
    assert co.mapping_entry(ct.ObjectAddress(0x6041, 0), 16) == 0x60410010  # statusword, 16 bits
    assert co.mapping_entry(ct.ObjectAddress(0x607D, 2), 32) == 0x607D0220


@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=50))
def test_integer_coding_is_within_half_a_unit(values):
    x = np.array(values)
    raw = co.encode_si(x, co.INTEGER32, 1e-6)
    assert raw.dtype == np.dtype("<i4")
    assert np.all(np.abs(co.decode_raw(raw, 1e-6) - x) <= 0.5e-6 + 1e-15)


def test_coding_clips_to_the_type_and_keeps_nan_out_of_integers():
    raw = co.encode_si(np.array([100.0, -100.0, np.nan]), co.INTEGER16, 1e-3)
    assert raw.tolist() == [32767, -32768, 0]
    real = co.encode_si(np.array([0.1, np.nan]), co.REAL32, 1.0)
    assert real.dtype == np.dtype("<f4") and real[0] == np.float32(0.1) and np.isnan(real[1])


def test_records_pack_like_the_wire():
    dt = co.record_dtype([co.UNSIGNED16, co.INTEGER32, co.REAL32])
    assert dt.itemsize == 10
    rec = np.zeros(1, dt)
    rec["f0"], rec["f1"], rec["f2"] = 0x1234, -2, 1.5
    assert rec.tobytes() == bytes.fromhex("3412") + (-2).to_bytes(4, "little", signed=True) + bytes.fromhex("0000c03f")


def test_pdo_packing_first_fit_behind_the_counter():
    frames = co.pack_frames([("exc", 32), ("cmd", 16), ("tq", 16), ("pos", 32), ("vel", 32)])
    assert frames == [["exc", "cmd"], ["tq", "pos"], ["vel"]]
    assert all(16 + sum({"exc": 32, "cmd": 16, "tq": 16, "pos": 32, "vel": 32}[n] for n in f) <= 64 for f in frames)
    with pytest.raises(DataError, match="PDOs"):
        co.pack_frames([(str(i), 32) for i in range(5)], max_frames=4)
    with pytest.raises(DataError, match="does not fit"):
        co.pack_frames([("big", 64)])


#: The object dictionary of the shipped drive's EDS.
SERVO_OD = load_object_dictionary(find_driver("canopen-servo"))


@pytest.mark.parametrize("name", ["canopen-servo", "canopen-servo-fixed"])
def test_shipped_descriptions_are_complete(name):
    driver = find_driver(name)
    desc = co.CanopenDescription.from_sections(driver.sections, "x", load_object_dictionary(driver))
    assert driver.transport == "canopen" and (driver.folder / desc.eds).is_file()
    assert {m.code for m in desc.modes.values()} == {10, -3, 9, 8}
    assert desc.modes["torque"].setpoint == "target_torque" and desc.modes["velocity"].setpoint == "target_velocity"
    assert set(c.name for c in driver.channels) == set(desc.channels)
    assert desc.scale("torque_actual", 1.0) == pytest.approx(1e-3)  # per mille of 1 N*m
    assert desc.scale("position_actual", 1.0) == 1e-7
    assert desc.filters.address(2, "a1") == ct.ObjectAddress(0x2302, 5)
    desc.require_buffered()


def test_description_errors_name_the_key():
    driver = find_driver("canopen-servo")
    od = load_object_dictionary(driver)
    del od[0x6041]  # an EDS without the statusword is no CiA 402 drive
    with pytest.raises(ConfigError, match="the EDS has no statusword") as err:
        co.CanopenDescription.from_sections(driver.sections, "drv.toml", od)
    assert "drv.toml" in str(err.value)
    sections = copy.deepcopy(driver.sections)
    sections["canopen"]["objects"]["load_position"] = "0x2999"
    with pytest.raises(ConfigError, match=r"canopen\.objects\.load_position.*0x2999:0 is not in the EDS"):
        co.CanopenDescription.from_sections(sections, "drv.toml", load_object_dictionary(driver))
    sections = copy.deepcopy(find_driver("canopen-servo").sections)
    sections["canopen"]["modes"]["torque"]["setpoint"] = "no_such_role"
    with pytest.raises(ConfigError, match="canopen.modes.torque.setpoint"):
        co.CanopenDescription.from_sections(sections, "", SERVO_OD)
    sections = copy.deepcopy(find_driver("canopen-servo").sections)
    sections["canopen"]["scaling"]["position_unit_m"] = 0
    with pytest.raises(ConfigError, match="position_unit_m"):
        co.CanopenDescription.from_sections(sections, "", SERVO_OD)
    sections = copy.deepcopy(find_driver("canopen-servo").sections)
    del sections["canopen"]["objects"]["capture_data"]
    with pytest.raises(ConfigError, match="capture_data"):  # buffered is this drive's default
        co.CanopenDescription.from_sections(sections, "", SERVO_OD)


@given(st.integers(0, 127), st.integers(0, 0xFFFF))
def test_heartbeat_consumer_entries_round_trip(node, time_ms):
    entry = co.consumer_entry(node, time_ms)
    assert 0 <= entry < 2**24 and co.parse_consumer_entry(entry) == (node, time_ms)


def test_heartbeat_consumer_entry_is_the_cia301_layout():
    assert co.consumer_entry(127, 500) == 0x007F01F4
    with pytest.raises(DataError, match="node 128"):
        co.consumer_entry(128, 500)


def test_device_net_keys_of_the_description():
    sections = find_driver("canopen-servo").sections
    desc = co.CanopenDescription.from_sections(sections, "", SERVO_OD)
    assert (desc.host_node_id, desc.abort_connection_option) == (127, 2)
    for key, value, match in [
        ("host_node_id", 0, "1..127"),
        ("host_node_id", 200, "1..127"),
        ("abort_connection_option", 0, r"\[1, 2, 3\]"),
        ("abort_connection_option", -1, "quick stop"),
        ("host_node_id", "x", "must be int"),
    ]:
        broken = copy.deepcopy(sections)
        broken["canopen"][key] = value
        with pytest.raises(ConfigError, match=rf"canopen\.{key}.*{match}"):
            co.CanopenDescription.from_sections(broken, "driver.toml", SERVO_OD)
    bare = copy.deepcopy(sections)
    del bare["canopen"]["host_node_id"], bare["canopen"]["abort_connection_option"]
    assert co.CanopenDescription.from_sections(bare, "", SERVO_OD).host_node_id == 127
