"""The board's cascade over the serial line: the host reads the gains the twin runs, writes them as the board
stores them (binary32), and a refusal or an older board are told apart (PROTOCOL.md sections 4.15, 4.16)."""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace

import pytest

from hilident.adapters.serial.board import SerialBoardAdapter
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.serial.server import start_serial_board
from hilident.errors import ConfigError, DeviceError, UsageError
from hilident.protocol import serial_board as sb

DRIVER = find_driver("myrio-board")
#: A twin whose current loop and delay are not the defaults, so the host cannot get them right by chance.
CONFIG = parse_config("""
[emulator]
time_scale = 10.0

[emulator.drive]
kv_nm_per_mps = 80.0
ti_s = 0.04
kp_pos_per_s = 15.0
velocity_filter_hz = 300.0
current_loop_hz = 1500.0
delay_s = 0.0005
""")


@contextlib.contextmanager
def pipe_board(driver=DRIVER, cfg=CONFIG):
    device = start_serial_board(cfg.emulator, driver, baudrate=0, link="pipe")
    device.link.timeout = 0.02
    adapter = SerialBoardAdapter(device.link, driver, device.port, timeout_s=1.0)
    try:
        adapter.identify()
        yield device, adapter
    finally:
        adapter.close()
        device.close()


def test_the_host_reads_the_cascade_the_twin_runs():
    with pipe_board() as (device, adapter):
        values = adapter.read_loop()
        tuning = device.drive.tuning
    assert values is not None and set(values) == set(sb.LOOP_FIELDS)
    for name in sb.LOOP_FIELDS:  # each parameter as the board runs it, rounded to its binary32 field
        assert values[name] == sb.float32(getattr(tuning, name)), name
    assert (values["current_loop_hz"], values["delay_ticks"]) == (1500.0, 2.0)


def test_a_write_reads_back_as_stored_and_retunes_the_running_loop():
    asked = {"kv_nm_per_mps": 123.456789, "ti_s": 0.0123456789, "velocity_filter_hz": 250.1}
    with pipe_board() as (device, adapter):
        before = adapter.read_loop()
        expected = adapter.stored_loop(asked)
        assert expected["ti_s"] != asked["ti_s"] and expected["ti_s"] == pytest.approx(asked["ti_s"], rel=1e-7)
        adapter.write_loop(asked)
        back = adapter.read_loop()
        tuning = device.drive.tuning
        assert {k: back[k] for k in asked} == expected
        assert back["kp_pos_per_s"] == before["kp_pos_per_s"]  # a gain left out keeps its value
        assert tuning.kv_nm_per_mps == expected["kv_nm_per_mps"] and tuning.ti_s == expected["ti_s"]
        adapter.write_loop({"ti_s": math.inf})  # a P controller
        assert adapter.read_loop()["ti_s"] == math.inf


def test_a_refused_gain_names_the_port_the_message_and_the_code_and_changes_nothing():
    with pipe_board() as (device, adapter):
        before = adapter.read_loop()
        for bad in ({"ti_s": 0.0}, {"kv_nm_per_mps": -1.0}, {"velocity_filter_hz": math.nan}):
            with pytest.raises(DeviceError) as err:
                adapter.write_loop(bad)
            assert device.port in str(err.value) and "WRITE_LOOP" in str(err.value), err.value
            assert "BAD_ARGUMENT" in str(err.value) and next(iter(bad)) in str(err.value), err.value
            assert adapter.read_loop() == before
        with pytest.raises(UsageError, match="current_loop_hz"):
            adapter.write_loop({"current_loop_hz": 900.0})  # the board's, not a tuner's
        with pytest.raises(UsageError, match="binary32"):
            adapter.write_loop({"kv_nm_per_mps": 1e39})


def test_a_fixed_value_of_the_description_wins_and_is_never_written(tmp_path):
    folder = tmp_path / "board"
    folder.mkdir()
    text = (DRIVER.folder / "driver.toml").read_text()
    (folder / "driver.toml").write_text(text.replace('delay_ticks = { message = "LOOP" }', "delay_ticks = 3"))
    driver = find_driver(str(folder))
    with pipe_board(driver) as (_, adapter):
        assert adapter.read_loop()["delay_ticks"] == 3.0
        with pytest.raises(UsageError, match="fixed value"):
            adapter.stored_loop({"delay_ticks": 1.0})


def test_an_older_board_without_the_loop_messages_gives_no_loop_and_keeps_working(monkeypatch):
    with pipe_board() as (device, adapter):
        firmware = device.server.firmware
        monkeypatch.delattr(type(firmware), "_on_readloop")  # a board that does not know READ_LOOP
        monkeypatch.delattr(type(firmware), "_on_writeloop")
        assert adapter.read_loop() is None
        with pytest.raises(DeviceError, match="no loop messages"):
            adapter.write_loop({"kv_nm_per_mps": 90.0})
        assert adapter.status().state == sb.State.IDLE  # the line and the board carry on


def test_a_driver_without_loop_asks_the_board_nothing(tmp_path):
    folder = tmp_path / "board"
    folder.mkdir()
    text = (DRIVER.folder / "driver.toml").read_text()
    (folder / "driver.toml").write_text(text.split("\n[loop]")[0])
    driver = find_driver(str(folder))
    with pipe_board(replace(driver)) as (_, adapter):
        sent = adapter._seq
        assert adapter.read_loop() is None
        assert adapter._seq == sent


def test_a_serial_driver_keeps_its_loop_in_the_loop_message_only(tmp_path):
    folder = tmp_path / "board"
    folder.mkdir()
    text = (DRIVER.folder / "driver.toml").read_text()
    (folder / "driver.toml").write_text(
        text.replace('kv_nm_per_mps = { message = "LOOP" }', 'kv_nm_per_mps = { object = "0x2400:1" }')
    )
    with pytest.raises(ConfigError) as err:
        find_driver(str(folder))
    assert err.value.key == "loop.kv_nm_per_mps.object" and str(folder / "driver.toml") in str(err.value)
