"""The emulated board's server refuses a clock or a line rate it cannot run with."""

from __future__ import annotations

import math

import pytest

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.device import build_drive
from hilident.emulator.serial.firmware import BoardFirmware
from hilident.emulator.serial.links import PipeLink
from hilident.emulator.serial.server import BoardServer, identity_from_driver
from hilident.errors import ConfigError
from hilident.links import pipe_pair

DRIVER = find_driver("myrio-board")
CONFIG = """
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0
"""


def firmware() -> BoardFirmware:
    return BoardFirmware(build_drive(parse_config(CONFIG).emulator, DRIVER), identity_from_driver(DRIVER))


@pytest.mark.parametrize("time_scale", [math.nan, math.inf, -1.0, 0.0])
def test_a_time_scale_that_serves_no_data_or_crashes_is_a_config_error(time_scale):
    _, device_end = pipe_pair()
    with pytest.raises(ConfigError, match=r"\[emulator.time_scale\] must be a finite number > 0"):
        BoardServer(firmware(), PipeLink(device_end), baudrate=0, time_scale=time_scale)


def test_a_negative_line_rate_is_a_config_error():
    _, device_end = pipe_pair()
    with pytest.raises(ConfigError, match=r"\[device.baudrate\]"):
        BoardServer(firmware(), PipeLink(device_end), baudrate=-9600)


def test_a_valid_server_starts_and_stops():
    _, device_end = pipe_pair()
    with BoardServer(firmware(), PipeLink(device_end), baudrate=0, time_scale=2.5) as server:
        assert server.time_scale == 2.5
    assert server.error is None
