"""The DSY-RS driver folder and its twin: parameters by code, the notch written over Modbus TCP, read back,
its attenuation from the stored integers, the twin's physics, the save parameter and the run refusal."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.emulator.drive import DriveLoop
from hilident.emulator.factory import build_drive, start_emulator
from hilident.emulator.modbus.parameter_firmware import ParameterDriveFirmware
from hilident.errors import ConfigError, DeviceError
from hilident.filters.notch import NotchSpec, design_notch
from hilident.io.summary import UploadOutcome
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.session.connection import ConnectedDevice
from hilident.session.run import Session

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-dsy-rs.toml"
DRIVER = find_driver("dsy-rs")
MAP = RegisterMap.from_driver(DRIVER)
#: Panasonic width table the driver assumes: -3 dB bandwidth / centre of width index 0..8
WIDTH_RATIO = [0.50, 0.59, 0.71, 0.84, 1.00, 1.19, 1.41, 1.68, 2.00]
RESONANCE_HZ = 21.79  # the gantry's mode


def clean_config():
    cfg = load_config(CONFIG)
    return replace(cfg, emulator=replace(cfg.emulator, preset="clean", time_scale=1.0))


def panasonic_attenuation_db(center: int, width: int, depth: int, at_hz: float, rate_hz: float) -> float:
    """The vendor family's notch from its stored integers, written out independently of hilident:
    H(s) = (s^2 + 2 d zeta w0 s + w0^2) / (s^2 + 2 zeta w0 s + w0^2), 2 zeta = width ratio, d = depth / 100,
    bilinear transform pre-warped at the centre."""
    w0 = 2 * math.pi * center
    zeta = WIDTH_RATIO[width] / 2
    d = depth / 100
    b, a = [1, 2 * d * zeta * w0, w0**2], [1, 2 * zeta * w0, w0**2]
    fs_warp = w0 / (2 * math.tan(w0 / (2 * rate_hz)))
    bz, az = scipy.signal.bilinear(b, a, fs=fs_warp)
    _, h = scipy.signal.freqz(bz, az, worN=[at_hz], fs=rate_hz)
    return -20 * math.log10(abs(h[0]))


def sine_amplitude(x: np.ndarray, t: np.ndarray) -> float:
    """Amplitude of the component at the resonance (least squares on sine, cosine and a constant): the
    torque sensor's noise stays out of it."""
    w = 2 * math.pi * RESONANCE_HZ
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    (s, c, _), *_ = np.linalg.lstsq(basis, x, rcond=None)
    return math.hypot(s, c)


def test_the_map_resolves_parameter_codes_by_the_vendor_rule():
    assert not MAP.excitation
    assert MAP.register("notch1_center_hz").address == 0x0802 == MAP.parameter("P08.02").address
    assert MAP.register("speed_feedback_rpm").address == 0x1201  # the vendor's own example
    assert MAP.parameter("P10.04").address == 0x0A04 and MAP.save == ("save_to_eeprom", 1)
    pos = MAP.register("absolute_position")
    assert (pos.type, pos.count, pos.word_order) == ("i32", 2, "little")
    assert pos.encode(-70000) == [(-70000) & 0xFFFF, 0xFFFE]  # low word first
    fields = {f: r.parameter for f, r in MAP.filters.fields(0).items()}
    assert fields == {"center": "P08.02", "width": "P08.03", "depth": "P08.04"}


def test_the_twin_answers_as_the_map_says():
    drive = build_drive(clean_config().emulator, DRIVER)
    fw = ParameterDriveFirmware(drive, MAP, DRIVER)
    assert fw.functions == frozenset({3, 6, 16})
    assert fw.read(0x0802, 3) == [4000, 8, 50]  # the vendor's defaults: the notch is off
    assert drive.filters.read(0) == (drive.filters.read(0)[0], False)
    assert fw.read(0x0805, 1) == 2  # P08.05 is not in the map
    assert fw.write(0x0802, [5000]) == 3 and fw.read(0x0802, 1) == [4000]  # beyond P08.02's range
    assert fw.write(0x0100, [7]) == 2  # P01.00, motor model: read only
    assert fw.write(0x1207, [1]) == 2  # half of the 32-bit position
    assert fw.write(0x0802, [22]) is None
    section, enabled = drive.filters.read(0)
    assert enabled
    assert -20 * math.log10(abs(section.response(np.array([22.0]), 8000.0)[0])) == pytest.approx(
        panasonic_attenuation_db(22, 8, 50, 22.0, 8000.0), abs=0.01
    )


@pytest.fixture
def dsy():
    cfg = clean_config()
    emu = start_emulator(cfg.emulator, DRIVER, cfg.device)
    try:
        adapter = ModbusDriveAdapter.open_device(emu.device, DRIVER)
        try:
            yield adapter, emu
        finally:
            adapter.close()
    finally:
        emu.close()


def test_a_notch_is_written_read_back_and_attenuates_on_the_twin(dsy):
    adapter, emu = dsy
    ident = adapter.identify()
    assert ident.filter_slots == 1 and ident.registers["motor_model"] == 101
    spec = NotchSpec(RESONANCE_HZ, 0.3 * RESONANCE_HZ, 40.0)
    realised = MAP.filter_encoding.realise(spec, DRIVER.loop_rate_hz)
    up = adapter.upload_filter(0, design_notch(spec, DRIVER.loop_rate_hz), spec)
    assert up.matches and up.stored == up.expected
    # the integers on the wire, read with a plain request: what was realised
    center, width, depth = adapter.registers.read(0x0802, 3)
    assert {"center": center, "width": width, "depth": depth} == realised.fields
    assert 10 <= center <= 3999 and 0 <= width <= 8 and 0 <= depth <= 100
    # the attenuation at the resonance from the stored integers, by the vendor family's equation
    achieved = panasonic_attenuation_db(center, width, depth, RESONANCE_HZ, DRIVER.loop_rate_hz)
    assert achieved == pytest.approx(realised.attenuation_db, abs=0.05)
    assert achieved >= min(spec.depth_db, realised.attenuation_db) - 1.0
    assert achieved > 20.0
    report = adapter.filter_parameters(0)
    assert report["enabled"] and report["fields"]["center"] == {
        "register": "notch1_center_hz",
        "parameter": "P08.02",
        "address": 0x0802,
        "value": center,
    }
    assert report["notch"]["center_hz"] == center
    assert report["notch"]["width_hz"] == pytest.approx(WIDTH_RATIO[width] * center)
    # the twin's physics: a torque sine at the resonance through the drive's filter chain
    with emu.server.lock:
        drive = emu.drive
        drive.set_mode("torque")
        drive.enable()
        n = int(DRIVER.loop_rate_hz)
        t = np.arange(n) / DRIVER.loop_rate_hz
        rows = drive.run(np.sin(2 * math.pi * RESONANCE_HZ * t))
        drive.disable()
    cmd = rows[n // 2 :, DriveLoop.CHANNELS.index("torque_cmd_nm")]
    out = rows[n // 2 :, DriveLoop.CHANNELS.index("torque_nm")]
    measured = 20 * math.log10(sine_amplitude(cmd, t[n // 2 :]) / sine_amplitude(out, t[n // 2 :]))
    assert measured == pytest.approx(achieved, abs=1.0)


def test_a_write_outside_a_parameter_range_is_refused_before_it_is_sent(dsy):
    adapter, emu = dsy
    with pytest.raises(DeviceError, match=r"P08\.02.*outside its range 10\.\.4000 Hz"):
        adapter.write_parameter("P08.02", 5000)
    with pytest.raises(DeviceError, match="read-only"):
        adapter.write_parameter("P01.00", 3)
    assert adapter.read_parameter("P08.02") == 4000
    adapter.write_parameter("P08.02", 100)
    assert emu.server.firmware.value("notch1_center_hz") == 100


def test_save_is_written_only_after_a_verified_upload(dsy, tmp_path):
    adapter, emu = dsy
    fw = emu.server.firmware
    spec = NotchSpec(RESONANCE_HZ, 6.5, 30.0)
    assert adapter.upload_filter(0, design_notch(spec, DRIVER.loop_rate_hz), spec).matches
    assert fw.saves == 0  # an upload alone stores nothing
    session = Session(clean_config(), tmp_path, save=True)
    session.driver, session.device = DRIVER, ConnectedDevice(DRIVER, adapter)
    unverified = UploadOutcome(written=True, verified_readback=True)
    session._save_step(unverified, verification=None)
    assert fw.saves == 0 and not unverified.saved
    verified = UploadOutcome(written=True, verified_readback=True)
    session._save_step(verified, verification={"band_reduction_db": 25.0})
    assert fw.saves == 1 and verified.saved and "P10.04" in verified.saved_with
    assert fw.eeprom[0x0802] == adapter.registers.read(0x0802, 1)[0] != 4000  # the notch is what was stored
    assert adapter.read_parameter("P10.04") == 0  # the drive acknowledges the store


def test_feedback_registers_show_the_axis_in_si_units(dsy):
    adapter, emu = dsy
    with emu.server.lock:
        emu.server.firmware.idle(80)
    feedback = adapter.read_feedback()
    assert set(feedback) == {"velocity_mps", "torque_nm", "position_m"}
    position = emu.drive.sensors.encoder(emu.drive.plant.p1)
    assert feedback["position_m"] == pytest.approx(position, abs=1e-6)
    assert feedback["torque_nm"] == pytest.approx(0.0, abs=0.02)  # disabled: sensor noise, 0.1 % steps


def test_experiments_are_refused_at_the_adapter_too(dsy):
    adapter, _ = dsy
    adapter.set_limits(19.0, 0.4, -0.6, 0.6)  # nothing to load, nothing moves: connecting stays possible
    with pytest.raises(ConfigError, match="excitation capability"):
        adapter.configure(1000.0, "torque")
    with pytest.raises(ConfigError, match="hilident upload --from"):
        adapter.stream(np.zeros(10), lambda index, rows: None)


def test_run_refuses_a_drive_without_an_excitation_capability(tmp_path):
    with pytest.raises(ConfigError) as err:
        Session(load_config(CONFIG), tmp_path).prepare()
    assert err.value.key == "device.driver" and err.value.file == str(CONFIG)
    text = str(err.value)
    assert "no excitation capability" in text.replace("without an excitation capability", "no excitation capability")
    assert "hilident identify" in text and "hilident upload --from" in text


def test_a_notch_that_does_not_read_back_is_never_enabled_and_the_slot_is_put_back(dsy):
    adapter, emu = dsy
    fw = emu.server.firmware
    honest = fw.write

    def widening(address, values):  # a drive that stores another width than it was sent
        values = list(values)
        if address <= 0x0803 < address + len(values):
            values[0x0803 - address] = min(values[0x0803 - address] + 1, 8)
        return honest(address, values)

    fw.write = widening
    spec = NotchSpec(RESONANCE_HZ, 6.5, 30.0)
    up = adapter.upload_filter(0, design_notch(spec, DRIVER.loop_rate_hz), spec)
    fw.write = honest
    assert not up.matches
    assert adapter.registers.read(0x0802, 3) == [4000, 8, 50]  # never enabled, and the previous values put back
    assert emu.drive.filters.read(0)[1] is False


def test_the_notch_goes_over_modbus_rtu_too():
    cfg = clean_config()
    cfg = replace(cfg, emulator=replace(cfg.emulator, link="pty"), device=replace(cfg.device, parity="N"))
    emu = start_emulator(cfg.emulator, DRIVER, cfg.device)
    try:
        adapter = ModbusDriveAdapter.open_device(emu.device, DRIVER)
        try:
            spec = NotchSpec(RESONANCE_HZ, 6.5, 30.0)
            assert adapter.upload_filter(0, design_notch(spec, DRIVER.loop_rate_hz), spec).matches
            assert adapter.registers.read(0x0802, 3) == list(
                MAP.filter_encoding.realise(spec, DRIVER.loop_rate_hz).fields.values()
            )
        finally:
            adapter.close()
    finally:
        emu.close()


def test_a_parameter_twin_with_input_registers_and_an_enable_register():
    """The twin follows any parameter map: input registers behind function 4, a slot with its own enable."""
    sections = {
        "modbus": {
            "parameters": {"address": "group * 0x100 + 2 * index"},
            "registers": {
                "model": {"parameter": "P0.01", "type": "u16", "default": 7},
                "temperature": {"address": 0x0010, "type": "i16", "table": "input", "scale": 0.1, "default": 25.0},
                "c": {"parameter": "P2.23", "type": "u32", "access": "rw", "word_order": "little", "default": 1000},
                "q": {"parameter": "P2.24", "type": "u16", "access": "rw", "default": 100},
                "d": {"parameter": "P2.25", "type": "u16", "access": "rw", "default": 10},
                "on": {"parameter": "P2.26", "type": "u16", "access": "rw", "min": 0, "max": 1, "default": 0},
            },
            "identity": {"registers": ["model"]},
            "filters": {"slots": [{"center": "c", "width": "q", "depth": "d", "enable": "on"}]},
        },
        "filters": {
            "encoding": "notch_parameters",
            "width_unit": "q",
            "depth_unit": "percent",
            "scales": {"center": 0.1, "width": 0.01, "depth": 1.0},
        },
    }
    regmap = RegisterMap.parse(sections, 1, "synthetic")
    driver = replace(DRIVER, filter_slots=1, sections=sections)
    drive = build_drive(clean_config().emulator, driver)
    fw = ParameterDriveFirmware(drive, regmap, driver)
    assert fw.functions == frozenset({3, 4, 6, 16})
    assert fw.read(0x0010, 1, input_registers=True) == [250]
    assert fw.read(0x0010, 1) == 2  # not a holding register
    assert regmap.register("c").address == 0x022E  # P2.23 by the Delta-style rule
    assert fw.read(0x022E, 2) == [1000, 0]  # low word first
    assert drive.filters.read(0)[1] is False
    assert fw.write(0x0234, [1]) is None  # P2.26: enable
    section, enabled = drive.filters.read(0)
    assert enabled
    gain = abs(section.response(np.array([100.0]), DRIVER.loop_rate_hz)[0])
    assert gain == pytest.approx(0.1, rel=0.01)  # depth 10 % at the 100.0 Hz centre
    assert fw.write(0x0234, [2]) == 3  # beyond the enable's range


def test_drivers_v_says_what_the_parameter_drive_offers():
    from hilident.drivers.tools import describe_driver

    caps = next(line for line in describe_driver(DRIVER.folder).splitlines() if "capabilities:" in line)
    assert "parameters PXX.YY at group * 0x100 + index" in caps
    assert "no excitation" in caps and "upload" in caps
    assert "save (save_to_eeprom = 1, with --save)" in caps
