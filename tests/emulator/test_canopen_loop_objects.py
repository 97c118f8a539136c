"""The twin's cascade is its [loop] objects: the host reads the gains the drive runs, and a write retunes it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

import canopen
from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.emulator.canopen.server import start
from hilident.errors import DeviceError, UsageError

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"


@pytest.fixture
def twin():
    cfg = load_config(CONFIG)
    driver = find_driver("canopen-servo")
    emulated = start(replace(cfg.emulator, time_scale=10.0), driver, cfg.device)
    yield cfg, driver, emulated
    emulated.close()


def test_the_host_reads_the_gains_the_drive_runs(twin):
    cfg, driver, emulated = twin
    adapter = CanopenDriveAdapter.open_device(replace(emulated.device, timeout_s=0.5), driver)
    try:
        values = adapter.read_loop()
    finally:
        adapter.close()
    tuning = emulated.drive.tuning
    assert values["kv_nm_per_mps"] == cfg.emulator.drive.kv_nm_per_mps == tuning.kv_nm_per_mps
    assert values["ti_s"] == pytest.approx(tuning.ti_s, rel=1e-7)  # REAL32
    assert values["current_loop_hz"] == tuning.current_loop_hz and values["delay_ticks"] == tuning.delay_ticks


def test_a_write_retunes_the_running_loop_and_a_wrong_one_is_refused(twin):
    _, driver, emulated = twin
    network = canopen.Network()
    network.connect(interface="virtual", channel=emulated.device.port)
    try:
        node = network.add_node(emulated.device.canopen.node_id, str(driver.folder / "canopen-servo.eds"))
        node.sdo[0x2400][1].raw = 150.0
        assert emulated.drive.tuning.kv_nm_per_mps == 150.0
        with pytest.raises(SdoAbortedError) as err:
            node.sdo[0x2400][2].raw = 0.0  # no integral time of zero
        assert err.value.code == 0x06090030 and emulated.drive.tuning.ti_s > 0
        with pytest.raises(SdoAbortedError) as err:
            node.sdo[0x2400][5].raw = 5000.0  # the current loop is the power stage's
        assert err.value.code == 0x06010002
    finally:
        network.disconnect()


def test_the_host_writes_gains_reads_them_back_as_stored_and_refuses_a_fixed_part(twin):
    _, driver, emulated = twin
    adapter = CanopenDriveAdapter.open_device(replace(emulated.device, timeout_s=0.5), driver)
    try:
        asked = {"kv_nm_per_mps": 123.456789, "ti_s": 0.0123456789, "kp_pos_per_s": 31.0}
        expected = adapter.stored_loop(asked)
        assert expected["ti_s"] != asked["ti_s"] and expected["ti_s"] == pytest.approx(asked["ti_s"], rel=1e-7)
        adapter.write_loop(asked)
        back = adapter.read_loop()
        assert {k: back[k] for k in asked} == expected
        assert emulated.drive.tuning.kp_pos_per_s == pytest.approx(31.0)
        with pytest.raises(UsageError, match="current_loop_hz"):
            adapter.write_loop({"current_loop_hz": 900.0})
        with pytest.raises(DeviceError, match="0x2400"):
            adapter.write_loop({"ti_s": 0.0})  # the drive refuses it, and the error names the object
        assert adapter.read_loop()["ti_s"] == expected["ti_s"]
    finally:
        adapter.close()


@pytest.fixture
def gain_form_twin():
    """The fixed-point servo: its 0x2400:2 holds the velocity integral as a gain (0.1 N*m per m, UNSIGNED32)."""
    cfg = load_config(CONFIG)
    driver = find_driver("canopen-servo-fixed")
    emulated = start(replace(cfg.emulator, time_scale=10.0), driver, cfg.device)
    yield driver, emulated
    emulated.close()


def test_a_drive_keeping_the_integral_as_a_gain_keeps_it_when_kv_alone_is_written(gain_form_twin):
    driver, emulated = gain_form_twin
    network = canopen.Network()
    network.connect(interface="virtual", channel=emulated.device.port)
    try:
        node = network.add_node(emulated.device.canopen.node_id, str(driver.folder / "canopen-servo-fixed.eds"))
        tuning = emulated.drive.tuning
        ki = tuning.kv_nm_per_mps / tuning.ti_s
        assert node.sdo[0x2400][2].raw == round(ki / 0.1)
        node.sdo[0x2400][1].raw = 2.0 * tuning.kv_nm_per_mps  # kv alone: ki stays, so the integral time doubles
        assert emulated.drive.tuning.ti_s == pytest.approx(2.0 * tuning.ti_s)
        node.sdo[0x2400][2].raw = 0  # ki = 0: a P controller
        assert emulated.drive.tuning.ti_s == float("inf")
    finally:
        network.disconnect()


def test_the_host_speaks_the_integral_time_to_a_drive_that_keeps_a_gain(gain_form_twin):
    driver, emulated = gain_form_twin
    adapter = CanopenDriveAdapter.open_device(replace(emulated.device, timeout_s=0.5), driver)
    try:
        tuning = emulated.drive.tuning
        assert adapter.read_loop()["ti_s"] == pytest.approx(tuning.ti_s, rel=1e-4)  # within ki's 0.1 step
        asked = {"kv_nm_per_mps": 321.0, "ti_s": 0.0777}
        expected = adapter.stored_loop(asked)
        assert set(expected) == set(asked) and expected["ti_s"] != asked["ti_s"]
        assert expected["ti_s"] == pytest.approx(asked["ti_s"], rel=1e-4)
        adapter.write_loop(asked)
        assert {k: adapter.read_loop()[k] for k in asked} == expected
        assert emulated.drive.tuning.ti_s == pytest.approx(expected["ti_s"], rel=1e-12)
        adapter.write_loop({"kv_nm_per_mps": 160.5})  # kv alone: the host writes ki with it, the time stays
        assert emulated.drive.tuning.kv_nm_per_mps == 160.5
        assert emulated.drive.tuning.ti_s == pytest.approx(expected["ti_s"], rel=1e-3)
        with pytest.raises(UsageError, match=r"ki_nm_per_m.*does not fit 0x2400:2"):
            adapter.write_loop({"ti_s": 1e-9})  # ki beyond UNSIGNED32: refused before a byte goes out
        assert emulated.drive.tuning.kv_nm_per_mps == 160.5
    finally:
        adapter.close()
