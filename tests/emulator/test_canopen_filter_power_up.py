"""A CANopen twin powers up running what its filter objects hold, as a drive does.

A drive keeps its filter parameters in non-volatile memory: at power-up a slot
without an enable object runs whatever its fields hold, and a slot with one runs
when the enable reads "on". The twin takes those values from the EDS defaults or
from the ``[emulator] values`` a driver folder gives it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from hilident.config.tables import CanopenDeviceConfig, DeviceConfig, load_config
from hilident.drivers.description import load_driver
from hilident.emulator.canopen.server import start
from support.filter_families import family_folder, kollmorgen_akd, synapticon

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"


def _powered_slots(folder: Path, values: str):
    """The twin's filter chain at power-up, the driver folder holding ``values`` in ``[emulator.values]``."""
    (folder / "driver.toml").write_text((folder / "driver.toml").read_text() + f"\n[emulator.values]\n{values}\n")
    driver = load_driver(folder)
    emu = replace(load_config(CONFIG).emulator, time_scale=10.0)
    emulated = start(emu, driver, DeviceConfig(driver=str(folder), canopen=CanopenDeviceConfig(node_id=5)))
    try:
        return emulated.drive.filters, driver.loop_rate_hz
    finally:
        emulated.close()


def _attenuation_db(filters, slot: int, frequency_hz: float, rate_hz: float) -> float:
    section, _ = filters.read(slot)
    gain = abs(section.response(np.array([frequency_hz]), rate_hz)[0])
    return float(-20 * np.log10(max(gain, 1e-12)))  # a zero on the unit circle: 240 dB


def test_a_slot_without_an_enable_runs_its_stored_fields(tmp_path):
    # AR1 with its zero damped ten times less than its pole at 500 Hz: a 20 dB notch the drive runs as it holds it
    filters, rate = _powered_slots(family_folder(tmp_path, kollmorgen_akd()), '"0x3406:0xD" = 5000')
    assert filters.read(0)[1]
    assert abs(_attenuation_db(filters, 0, 500.0, rate) - 20.0) < 0.5
    assert filters.read(1)[1] and _attenuation_db(filters, 1, 500.0, rate) < 0.01  # AR2 at its identity defaults


def test_a_slot_with_an_enable_runs_only_while_it_reads_on(tmp_path):
    on = family_folder(tmp_path / "on", synapticon())
    filters, rate = _powered_slots(on, '"0x2023:1" = 1\n"0x2023:2" = 300\n"0x2023:3" = 20')
    assert filters.read(0)[1] and _attenuation_db(filters, 0, 300.0, rate) > 40.0
    off = family_folder(tmp_path / "off", synapticon())
    filters, _ = _powered_slots(off, '"0x2023:1" = 0\n"0x2023:2" = 300\n"0x2023:3" = 20')
    assert not filters.read(0)[1]
