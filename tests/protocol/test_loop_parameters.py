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


GAIN_FORM = {
    **{n: {"object": f"0x2400:{i}"} for i, n in enumerate(PARAMETERS, start=1) if n != "ti_s"},
    "ki_nm_per_m": {"object": "0x2400:9", "scale": 0.1},
}


def test_the_integral_may_be_given_as_a_gain_but_not_both_nor_neither():
    loop = parse_loop(GAIN_FORM, "drive.toml")
    assert loop.integral_as_gain and "ti_s" not in loop.parameters
    with pytest.raises(ConfigError, match=r"loop\.ki_nm_per_m.*loop\.ti_s.*one of them"):
        parse_loop({**GAIN_FORM, "ti_s": {"object": "0x2400:2"}}, "drive.toml")
    with pytest.raises(ConfigError, match=r"loop\.ti_s.*or ki_nm_per_m"):
        parse_loop({k: v for k, v in GAIN_FORM.items() if k != "ki_nm_per_m"}, "drive.toml")
    with pytest.raises(ConfigError, match=r"loop\.ki_nm_per_m\.message.*carries ti_s"):
        parse_loop(
            {**{n: {"message": "LOOP"} for n in PARAMETERS if n != "ti_s"}, "ki_nm_per_m": {"message": "LOOP"}},
            "b.toml",
            kinds=("message",),
        )


def test_the_integral_gain_converts_to_and_from_the_integral_time():
    loop = parse_loop(GAIN_FORM, "drive.toml")
    present = {"kv_nm_per_mps": 100.0, "ti_s": 0.05}
    assert loop.to_cascade({"kv_nm_per_mps": 200.0, "ki_nm_per_m": 1000.0}) == {"kv_nm_per_mps": 200.0, "ti_s": 0.2}
    assert loop.to_cascade({"ki_nm_per_m": 0.0}, lambda: present) == {"ti_s": math.inf}
    assert loop.to_cascade({"ki_nm_per_m": -10.0}, lambda: present)["ti_s"] < 0  # refused as a time, not a P loop
    # a drive keeps ki when kv alone is written: its integral time moves with kv
    assert loop.to_cascade({"kv_nm_per_mps": 300.0}, lambda: present) == {"kv_nm_per_mps": 300.0, "ti_s": 0.15}
    assert loop.to_device({"kv_nm_per_mps": 300.0, "ti_s": math.inf}) == {"kv_nm_per_mps": 300.0, "ki_nm_per_m": 0.0}
    # the host writing kv alone writes ki with it, so the integral time stays
    assert loop.to_device({"kv_nm_per_mps": 300.0}, lambda: present) == {"kv_nm_per_mps": 300.0, "ki_nm_per_m": 6000.0}
    assert loop.to_device({"ti_s": 0.1, "kp_pos_per_s": 5.0}, lambda: present) == {
        "kp_pos_per_s": 5.0,
        "ki_nm_per_m": 1000.0,
    }
    with pytest.raises(ValueError, match="present"):
        loop.to_device({"ti_s": 0.1})
    time_form = parse_loop({n: {"object": f"0x2400:{i}"} for i, n in enumerate(PARAMETERS, start=1)}, "d.toml")
    assert time_form.to_device({"ti_s": 0.1}) == {"ti_s": 0.1} and time_form.to_cascade({"ti_s": 0.1}) == {"ti_s": 0.1}
