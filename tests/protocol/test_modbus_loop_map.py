"""A Modbus driver's [loop] table names registers of its map; the field slots take the center/ratio bi-quad."""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import build_drive
from hilident.emulator.modbus.parameter_firmware import ParameterDriveFirmware
from hilident.errors import ConfigError, DataError
from hilident.filters.notch import NotchSpec
from hilident.protocol.loop_parameters import FEEDFORWARD, PARAMETERS, TUNABLE
from hilident.protocol.modbus.filter_slots import FieldSlots
from hilident.protocol.modbus.loop_registers import stored_value
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.registers import Register

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-modbus-gantry.toml"
DRIVER = find_driver("modbus-servo")
SOURCE = "drivers/x/driver.toml"


def sections() -> dict:
    return copy.deepcopy(tomllib.loads(DRIVER.text))


def test_the_shipped_map_keeps_the_four_gains_writable_and_the_rest_read_only():
    m = RegisterMap.from_driver(DRIVER)
    regs = m.loop_registers()
    assert set(regs) == set(PARAMETERS) | set(FEEDFORWARD)  # the shipped drive has every feed-forward term
    assert all(regs[n].writable == (n in TUNABLE) for n in regs)
    assert all(r.type != "str" for r in regs.values())
    assert m.describe(regs["ti_s"].address, regs["ti_s"].count) == "registers 132..133 (velocity_integral)"


def test_a_map_without_a_loop_has_no_loop_registers():
    s = sections()
    del s["loop"]
    m = RegisterMap.parse(s, 4, SOURCE)
    assert m.loop is None and m.loop_registers() == {}


def test_a_fixed_value_needs_no_register():
    s = sections()
    s["loop"]["current_loop_hz"] = {"value": math.inf}
    m = RegisterMap.parse(s, 4, SOURCE)
    assert m.loop.fixed() == {"current_loop_hz": math.inf} and "current_loop_hz" not in m.loop_registers()


@pytest.mark.parametrize(
    ("change", "key", "words"),
    [
        (lambda s: s["loop"].update(ti_s={"register": "integral"}), "loop.ti_s.register", "no register"),
        (lambda s: s["loop"].update(ti_s={"register": "firmware"}), "loop.ti_s.register", "holds text"),
        (lambda s: s["loop"].update(kv_nm_per_mps={"register": "fault_value"}), "loop.kv_nm_per_mps.register", "rw"),
        (lambda s: s["loop"].update(ti_s={"object": "0x2400:2"}), "loop.ti_s.object", "not a key"),
        (lambda s: s["loop"].pop("delay_ticks"), "loop.delay_ticks", "missing"),
        (lambda s: s["loop"].update(ti_s={"register": "velocity_integral", "scale": 2.0}), "loop.ti_s.scale", ""),
    ],
)
def test_a_wrong_loop_table_names_the_key_and_the_file(change, key, words):
    s = sections()
    change(s)
    with pytest.raises(ConfigError) as err:
        RegisterMap.parse(s, 4, SOURCE)
    assert err.value.key == key and words in err.value.message
    assert SOURCE in str(err.value)


def test_a_read_only_register_may_hold_a_fixed_part():
    s = sections()
    s["loop"]["current_loop_hz"] = {"register": "fault_value"}  # read-only f32: the host only reads it
    assert RegisterMap.parse(s, 4, SOURCE).loop_registers()["current_loop_hz"].name == "fault_value"


def test_stored_values_are_what_the_register_holds():
    f32 = Register("g", 0, "f32", "rw", count=2)
    assert stored_value(f32, 0.1) == pytest.approx(0.1, rel=1e-7) and stored_value(f32, 0.1) != 0.1
    steps = Register("t", 0, "u16", "rw", scale=1e-5)
    assert stored_value(steps, 0.0123456) == pytest.approx(0.01235, abs=1e-15)
    with pytest.raises(DataError, match=r"register 0 \(t\)"):
        stored_value(steps, math.inf)


# --- the center/ratio bi-quad in a parameter drive's named registers -------------------------------------


def ax2000_sections() -> dict:
    """A parameter drive whose one filter slot is BQFC, BQFR, BQDC, BQDR (0.001 per step), off at BQDR = 1."""
    registers = {
        "model": {"parameter": "P01.00", "type": "u16", "default": 1},
        "bqfc": {"parameter": "P08.10", "type": "u32", "access": "rw", "default": 200_000},
        "bqfr": {"parameter": "P08.12", "type": "u16", "access": "rw", "default": 1000},
        "bqdc": {"parameter": "P08.13", "type": "u16", "access": "rw", "default": 300},
        "bqdr": {"parameter": "P08.14", "type": "u16", "access": "rw", "default": 1000},
    }
    slot = {"center_hz": "bqfc", "ratio": "bqfr", "center_damping": "bqdc", "damping_ratio": "bqdr"}
    return {
        "modbus": {
            "parameters": {"address": "group * 0x100 + index"},
            "registers": registers,
            "identity": {"registers": ["model"]},
            "filters": {"off": {"damping_ratio": 1000}, "slots": [slot]},
        },
        "filters": {
            "encoding": "center_ratio_damping",
            "scales": {"center_hz": 0.001, "ratio": 0.001, "center_damping": 0.001, "damping_ratio": 0.001},
            "ranges": {
                "center_hz": [20, 1000],
                "ratio": [0.1, 10],
                "center_damping": [0.2, 1],
                "damping_ratio": [0.25, 5],
            },
        },
    }


def test_field_slots_take_the_center_ratio_damping_encoding():
    m = RegisterMap.parse(ax2000_sections(), 1, SOURCE)
    assert isinstance(m.filters, FieldSlots) and m.filter_encoding.kind == "center_ratio_damping"
    assert set(m.filters.fields(0)) == {"center_hz", "ratio", "center_damping", "damping_ratio"}


def test_the_twin_runs_the_center_ratio_notch_it_is_given():
    sections = ax2000_sections()
    m = RegisterMap.parse(sections, 1, SOURCE)
    driver = replace(find_driver("dsy-rs"), filter_slots=1, sections=sections)
    drive = build_drive(load_config(CONFIG).emulator, driver)
    fw = ParameterDriveFirmware(drive, m, driver)
    assert drive.filters.read(0)[1] is False  # BQFR = BQDR = 1: the identity, bypassed
    realised = m.filter_encoding.realise(NotchSpec(300.0, 300.0, 12.0), driver.loop_rate_hz)
    fields = m.filters.fields(0)
    words = [
        w
        for f in ("center_hz", "ratio", "center_damping", "damping_ratio")
        for w in fields[f].encode(realised.fields[f])
    ]
    assert fw.write(fields["center_hz"].address, words) is None
    section, enabled = drive.filters.read(0)
    assert enabled and section == realised.section
    assert fw.write(fields["damping_ratio"].address, [1000]) is None  # the off value
    assert drive.filters.read(0)[1] is False
