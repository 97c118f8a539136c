"""The [loop] table: every cascade parameter where the drive keeps it, or its value; a wrong table names its key."""

from __future__ import annotations

import math

import pytest

from hilident.drivers.description import find_driver, load_object_dictionary
from hilident.errors import ConfigError
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.loop_parameters import PARAMETERS, parse_loop

FULL = {
    "kv_nm_per_mps": {"object": "0x2400:1"},
    "ti_s": {"object": "0x2400:2", "scale": 0.001},
    "kp_pos_per_s": 20.0,
    "velocity_filter_hz": {"value": math.inf},
    "current_loop_hz": {"value": 1000.0},
    "delay_ticks": {"value": 1},
}


def test_objects_scales_and_values():
    loop = parse_loop(FULL, "d.toml")
    assert set(loop.parameters) == set(PARAMETERS)
    assert loop.objects == {"kv_nm_per_mps": ObjectAddress(0x2400, 1), "ti_s": ObjectAddress(0x2400, 2)}
    assert loop.parameters["ti_s"].physical(50) == pytest.approx(0.05)
    assert loop.parameters["ti_s"].stored(0.05) == pytest.approx(50)
    assert loop.parameters["kp_pos_per_s"].value == 20.0 and loop.parameters["velocity_filter_hz"].value == math.inf
    assert loop.owner(ObjectAddress(0x2400, 2)) == "ti_s" and loop.owner(ObjectAddress(0x2400, 3)) is None
    assert parse_loop(None) is None


@pytest.mark.parametrize(
    "edit,key",
    [
        ({"ti_s": None}, "loop.ti_s"),  # missing
        ({"kv_gain": 1.0}, "loop.kv_gain"),  # unknown
        ({"kp_pos_per_s": {"object": "0x2400:3", "value": 2.0}}, "loop.kp_pos_per_s"),  # both
        ({"kp_pos_per_s": {"object": "0x2400:3", "scale": 0}}, "loop.kp_pos_per_s.scale"),
        ({"kp_pos_per_s": {"object": "0x2400:3", "unit": "1/s"}}, "loop.kp_pos_per_s.unit"),
        ({"current_loop_hz": {"value": -5.0}}, "loop.current_loop_hz.value"),
        ({"current_loop_hz": {"value": math.nan}}, "loop.current_loop_hz.value"),
        ({"kv_nm_per_mps": {"object": "0x24XX"}}, "loop.kv_nm_per_mps.object"),
        ({"kv_nm_per_mps": {"register": "velocity_gain"}}, "loop.kv_nm_per_mps.register"),  # not a CANopen kind
    ],
)
def test_a_wrong_table_names_its_key(edit, key):
    table = {**FULL, **edit}
    table = {k: v for k, v in table.items() if v is not None}
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")) as err:
        parse_loop(table, "d.toml")
    assert "d.toml" in str(err.value)


def test_an_object_the_eds_does_not_have_is_refused_naming_it():
    driver = find_driver("canopen-servo")
    sections = {**driver.sections, "loop": {**driver.sections["loop"], "ti_s": {"object": "0x2400:20"}}}
    with pytest.raises(ConfigError, match=r"loop\.ti_s\.object.*0x2400:20"):
        CanopenDescription.from_sections(sections, "driver.toml", load_object_dictionary(driver))


def test_each_transport_takes_its_own_kind_of_location():
    modbus = {n: {"register": f"loop_{n}"} for n in PARAMETERS} | {"delay_ticks": 1}
    loop = parse_loop(modbus, "m.toml", kinds=("register",))
    assert loop.parameters["ti_s"].register == "loop_ti_s" and loop.parameters["ti_s"].held
    assert loop.fixed() == {"delay_ticks": 1.0} and "delay_ticks" not in loop.held
    with pytest.raises(ConfigError, match=r"loop\.ti_s\.scale"):  # a register's scale is the map's
        parse_loop({**modbus, "ti_s": {"register": "x", "scale": 2.0}}, "m.toml", kinds=("register",))
    serial = {n: {"message": "LOOP"} for n in PARAMETERS}
    assert parse_loop(serial, "s.toml", kinds=("message",)).parameters["kp_pos_per_s"].message == "LOOP"
    with pytest.raises(ConfigError, match=r"loop\.ti_s\.message"):
        parse_loop({**serial, "ti_s": {"message": "GAINS"}}, "s.toml", kinds=("message",))
