"""The Modbus twin's cascade is its [loop] registers: the host reads the gains the drive runs, a write retunes it,
a fixed part is refused, and a value the loop cannot run is refused with the register named."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver, load_driver
from hilident.emulator.factory import build_drive
from hilident.emulator.modbus.parameter_firmware import ParameterDriveFirmware
from hilident.emulator.modbus.server import start
from hilident.errors import DeviceError, UsageError
from hilident.protocol.loop_parameters import FEEDFORWARD, PARAMETERS
from hilident.protocol.modbus.register_map import RegisterMap

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-modbus-gantry.toml"
DRIVER = find_driver("modbus-servo")


def serve(driver):
    """The gantry's twin behind ``driver``, and the adapter connected to it."""
    cfg = load_config(CONFIG)
    emulated = start(replace(cfg.emulator, time_scale=10.0), driver, cfg.device)
    try:
        adapter = ModbusDriveAdapter.open_device(replace(emulated.device, timeout_s=0.5), driver)
    except BaseException:
        emulated.close()
        raise
    return cfg, emulated, adapter


@pytest.fixture
def twin():
    cfg, emulated, adapter = serve(DRIVER)
    yield cfg, emulated, adapter
    adapter.close()
    emulated.close()


def test_the_host_reads_the_gains_the_drive_runs(twin):
    cfg, emulated, adapter = twin
    tuning = emulated.drive.tuning
    values = adapter.read_loop()
    assert set(values) == set(PARAMETERS) | set(FEEDFORWARD)
    assert values["kv_nm_per_mps"] == cfg.emulator.drive.kv_nm_per_mps == tuning.kv_nm_per_mps
    assert values["ti_s"] != tuning.ti_s and values["ti_s"] == pytest.approx(tuning.ti_s, rel=1e-7)  # f32
    assert values["current_loop_hz"] == tuning.current_loop_hz and values["delay_ticks"] == tuning.delay_ticks
    emulated.drive.retune(kp_pos_per_s=33.0)  # the registers are the running tuning, whoever changed it
    assert adapter.read_loop()["kp_pos_per_s"] == 33.0


def test_a_write_is_read_back_as_stored_and_retunes_the_running_loop(twin):
    _, emulated, adapter = twin
    asked = {"kv_nm_per_mps": 123.456789, "ti_s": 0.0123456789, "velocity_filter_hz": 321.123456789}
    expected = adapter.stored_loop(asked)
    assert all(expected[k] != asked[k] and expected[k] == pytest.approx(asked[k], rel=1e-7) for k in asked)
    adapter.write_loop(asked)
    back = adapter.read_loop()
    assert {k: back[k] for k in asked} == expected
    tuning = emulated.drive.tuning
    assert {k: getattr(tuning, k) for k in asked} == expected


def test_the_current_loop_and_the_delay_are_refused(twin):
    _, emulated, adapter = twin
    before = emulated.drive.tuning
    with pytest.raises(UsageError, match="current_loop_hz"):
        adapter.write_loop({"current_loop_hz": 900.0})
    r = adapter.map.register("current_loop_bw")
    with pytest.raises(DeviceError, match=r"registers 138\.\.139 \(current_loop_bw\): Modbus exception 2"):
        adapter.registers.write(r.address, r.encode(900.0))  # past the host's own check: the drive refuses it
    d = adapter.map.register("loop_delay")
    with pytest.raises(DeviceError, match=r"register 140 \(loop_delay\): Modbus exception 2"):
        adapter.registers.write(d.address, d.encode(3))
    assert emulated.drive.tuning == before


@pytest.mark.parametrize(
    ("name", "value", "register"),
    [
        ("ti_s", 0.0, r"registers 132\.\.133 \(velocity_integral\)"),
        ("kv_nm_per_mps", -5.0, r"registers 130\.\.131 \(velocity_gain\)"),
        ("kp_pos_per_s", math.nan, r"registers 134\.\.135 \(position_gain\)"),
        ("velocity_filter_hz", math.inf, r"registers 136\.\.137 \(velocity_filter\)"),
    ],
)
def test_a_value_the_loop_cannot_run_is_refused_naming_the_register(twin, name, value, register):
    _, emulated, adapter = twin
    before, read_before = emulated.drive.tuning, adapter.read_loop()
    with pytest.raises(DeviceError, match=register + r": Modbus exception 3") as err:
        adapter.write_loop({name: value})
    assert adapter.port in str(err.value)
    assert emulated.drive.tuning == before and adapter.read_loop() == read_before


def test_an_integer_register_rounds_to_its_scale_and_a_fixed_gain_is_never_written(tmp_path):
    """Another drive of the same family: the integral time in 10 us steps, the velocity filter fixed by the manual."""
    text = DRIVER.text.replace(
        'velocity_integral  = { address = 132, type = "f32", access = "rw", unit = "s" }',
        'velocity_integral  = { address = 132, type = "u32", access = "rw", unit = "s", scale = 1e-5 }',
    ).replace('velocity_filter_hz = { register = "velocity_filter" }', "velocity_filter_hz = { value = 400.0 }")
    assert text.count("scale = 1e-5") == 1 and text.count("value = 400.0") == 1
    (tmp_path / "driver.toml").write_text(text)
    cfg, emulated, adapter = serve(load_driver(tmp_path))
    try:
        assert adapter.read_loop()["velocity_filter_hz"] == 400.0 == cfg.emulator.drive.velocity_filter_hz
        expected = adapter.stored_loop({"ti_s": 0.0123456789})
        assert expected["ti_s"] == pytest.approx(0.01235, abs=1e-12)  # 1235 steps of 10 us
        adapter.write_loop({"ti_s": 0.0123456789})
        assert adapter.read_loop()["ti_s"] == expected["ti_s"] == emulated.drive.tuning.ti_s
        with pytest.raises(UsageError, match="velocity_filter_hz"):
            adapter.write_loop({"velocity_filter_hz": 300.0})
        with pytest.raises(UsageError, match="velocity_filter_hz"):
            adapter.stored_loop({"velocity_filter_hz": 300.0})
    finally:
        adapter.close()
        emulated.close()


def test_a_drive_keeping_the_integral_as_a_gain_in_a_register_is_tuned_in_the_integral_time(tmp_path):
    """Another drive of the family: the integral as a gain, ki = kv / ti, in whole N*m per m (u32)."""
    text = DRIVER.text.replace(
        'velocity_integral  = { address = 132, type = "f32", access = "rw", unit = "s" }',
        'velocity_integral  = { address = 132, type = "u32", access = "rw", unit = "N*m/m" }',
    ).replace('ti_s = { register = "velocity_integral" }', 'ki_nm_per_m = { register = "velocity_integral" }')
    assert text.count('ki_nm_per_m = { register = "velocity_integral" }') == 1
    (tmp_path / "driver.toml").write_text(text)
    cfg, emulated, adapter = serve(load_driver(tmp_path))
    try:
        tuning = emulated.drive.tuning
        r = adapter.map.register("velocity_integral")
        assert adapter.registers.read_names(r.name)[r.name] == round(tuning.kv_nm_per_mps / tuning.ti_s)
        assert adapter.read_loop()["ti_s"] == pytest.approx(tuning.ti_s, rel=1e-3)
        expected = adapter.stored_loop({"ti_s": 0.0123456789})
        assert expected["ti_s"] == tuning.kv_nm_per_mps / round(tuning.kv_nm_per_mps / 0.0123456789)
        adapter.write_loop({"ti_s": 0.0123456789})
        assert emulated.drive.tuning.ti_s == pytest.approx(expected["ti_s"], rel=1e-12)
        adapter.registers.write_names(velocity_gain=2 * tuning.kv_nm_per_mps)  # kv alone, past the host: ki stays
        assert emulated.drive.tuning.ti_s == pytest.approx(2 * expected["ti_s"], rel=1e-12)
    finally:
        adapter.close()
        emulated.close()


def test_a_parameter_drive_keeps_its_gains_in_scaled_parameters():
    """A vendor's parameter list (gains in 0.1 steps, the integral time in 0.01 ms): the twin shows and takes them."""
    sections = {
        "modbus": {
            "parameters": {"address": "group * 0x100 + index"},
            "registers": {
                "model": {"parameter": "P01.00", "type": "u16", "default": 101},
                "position_gain": {"parameter": "P07.00", "type": "u16", "access": "rw", "scale": 0.1},
                "speed_gain": {"parameter": "P07.01", "type": "u16", "access": "rw", "scale": 0.1},
                "speed_integral": {"parameter": "P07.02", "type": "u16", "access": "rw", "scale": 1e-5},
                "speed_filter": {"parameter": "P07.03", "type": "u16", "access": "rw"},
            },
            "identity": {"registers": ["model"]},
        },
        "loop": {
            "kv_nm_per_mps": {"register": "speed_gain"},
            "ti_s": {"register": "speed_integral"},
            "kp_pos_per_s": {"register": "position_gain"},
            "velocity_filter_hz": {"register": "speed_filter"},
            "current_loop_hz": {"value": math.inf},
            "delay_ticks": {"value": 0},
        },
    }
    regmap = RegisterMap.parse(sections, 0, "synthetic")
    dsy = find_driver("dsy-rs")
    driver = replace(dsy, filter_slots=0, sections=sections)
    cfg = load_config(CONFIG)
    drive = build_drive(cfg.emulator, driver)
    fw = ParameterDriveFirmware(drive, regmap, driver)
    t = drive.tuning
    assert fw.read(0x0700, 4) == [round(t.kp_pos_per_s * 10), round(t.kv_nm_per_mps * 10), round(t.ti_s * 1e5), 400]
    assert fw.write(0x0701, [1234]) is None and drive.tuning.kv_nm_per_mps == pytest.approx(123.4)
    assert fw.write(0x0702, [0]) == 3 and drive.tuning.ti_s == t.ti_s  # no integral time of zero
    assert fw.write(0x0700, [150, 1000, 2000]) is None
    assert (drive.tuning.kp_pos_per_s, drive.tuning.kv_nm_per_mps, drive.tuning.ti_s) == pytest.approx((15, 100, 0.02))
    assert np.all(np.asarray(fw.read(0x0700, 3)) == [150, 1000, 2000])
