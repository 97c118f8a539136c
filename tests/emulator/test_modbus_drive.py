"""The emulated Modbus drive: register logic against the drive loop's truth, and its MBAP/RTU server reached by
pymodbus clients (tests/test_modbus_conformance.py probes it with raw frames)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from hilident.config.tables import DeviceConfig, ModbusDeviceConfig, parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import build_drive
from hilident.emulator.modbus.firmware import ModbusDriveFirmware
from hilident.emulator.modbus.server import start
from hilident.filters.biquad import Biquad
from hilident.protocol.modbus.paging import plan_chunks, table_crc
from hilident.protocol.modbus.register_map import RegisterMap

DRIVER = find_driver("modbus-servo")
MAP = RegisterMap.from_driver(DRIVER)
REG = MAP.registers


def emulator_config(faults: str = "", time_scale: float = 10.0):
    return parse_config(f"""
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0

[emulator]
time_scale = {time_scale}
seed = 5

[emulator.plant]
model = "two_mass"
m1 = 8.0
m2 = 2.0
k = 8e4
d = 20.0
c = 10.0

[emulator.sensors]
encoder_resolution_m = 1e-7
torque_noise_nm = 0.01

[emulator.faults]
{faults}
""").emulator


class Drive:
    """A firmware with helpers that speak registers, as the server does."""

    def __init__(self, cfg=None, **faults):
        self.cfg = cfg or emulator_config()
        self.fw = ModbusDriveFirmware(build_drive(self.cfg, DRIVER), MAP, DRIVER, **faults)

    def set(self, **values):
        for name, value in values.items():
            code = self.fw.write(REG[name].address, MAP.encode(name, value))
            if code:
                return code
        return None

    def get(self, name):
        r = REG[name]
        return MAP.decode(name, self.fw.read(r.address, r.count))

    def flags(self):
        return MAP.status_flags(self.get("status_word"))

    def load_table(self, x):
        regs = MAP.encode_table(x)
        assert self.set(table_length=len(x)) is None
        for c in plan_chunks(0, len(x), 2, MAP.table.page_samples, MAP.max_write):
            assert self.set(table_page=c.page) is None
            assert (
                self.fw.write(MAP.table.base + c.offset, regs[2 * c.first_sample : 2 * (c.first_sample + c.samples)])
                is None
            )
        return regs

    def capture(self, n, mask):
        width = MAP.record_registers(mask)
        stamps, rows = [], []
        for c in plan_chunks(0, n, width, MAP.capture.page_samples, MAP.max_read):
            assert self.set(capture_page=c.page) is None
            s, r = MAP.decode_records(self.fw.read(MAP.capture.base + c.offset, c.count), mask)
            stamps.append(s)
            rows.append(r)
        return np.concatenate(stamps), np.concatenate(rows)

    def limits(self, torque=5.0, velocity=1.0, lo=-1.0, hi=1.0):
        return self.fw.write(
            REG["torque_limit_nm"].address,
            [
                r
                for name, v in (
                    ("torque_limit_nm", torque),
                    ("velocity_limit_mps", velocity),
                    ("position_min_m", lo),
                    ("position_max_m", hi),
                )
                for r in MAP.encode(name, v)
            ],
        )


def test_identity_registers_follow_the_driver():
    d = Drive()
    assert d.get("device_type") == MAP.device_type and d.get("map_version") == MAP.map_version
    assert d.get("loop_rate_hz") == DRIVER.loop_rate_hz and d.get("filter_slots") == DRIVER.filter_slots
    assert d.get("device_name") == DRIVER.name and d.get("firmware") == DRIVER.firmware
    assert d.get("table_capacity") == MAP.table.capacity_samples


def test_table_pages_hold_what_was_written_and_the_crc_covers_it():
    d = Drive()
    x = np.random.default_rng(0).normal(size=2500)  # three pages
    regs = d.load_table(x)
    assert d.get("table_crc") == table_crc(regs)
    assert d.set(table_page=2) is None
    got = d.fw.read(MAP.table.base, 2 * (2500 - 2048))
    assert np.array_equal(MAP.decode_table(got), x[2048:].astype(np.float32))
    assert d.set(table_length=2499) is None  # the CRC covers table_length samples only
    assert d.get("table_crc") == table_crc(regs[:-2])
    assert d.set(table_page=MAP.table.pages) == 3


def test_run_captures_the_drive_state_at_the_start_of_each_sample_period():
    d = Drive()
    divider, n = 4, 700
    x = 3.0 * np.sin(2 * np.pi * 7.0 * np.arange(n) / 1000.0)
    assert d.limits() is None
    mask = MAP.mask_of(MAP.capture_channel_names())
    assert d.set(mode=MAP.modes["torque"], sample_divider=divider, capture_mask=mask) is None
    d.load_table(x)
    assert d.set(control_word=MAP.control["run"]) is None
    assert {"running", "enabled", "limits_loaded"} <= d.flags()
    for step in (1, 250, 3, 1000):  # uneven chunks, as the clock delivers them
        d.fw.advance(step)
    assert d.flags() & {"running", "enabled", "fault"} == set() and "done" in d.flags()
    assert d.get("sample_count") == n and not d.fw.drive.enabled
    stamps, rows = d.capture(n, mask)
    assert stamps.tolist() == list(range(n))
    # the truth: the same drive loop fed the same float32 table, sampled at the start of each period
    twin = build_drive(d.cfg, DRIVER)
    twin.set_limits(5.0, 1.0, -1.0, 1.0)
    twin.set_mode("torque")
    twin.enable()
    truth = twin.run(np.repeat(x.astype(np.float32).astype(float), divider))[::divider]
    columns = [twin.CHANNELS.index(c) for c in MAP.capture_channel_names()]
    for j, c in enumerate(MAP.capture_channels):
        want = truth[:, columns[j]]
        if c.type == "f32":
            assert np.array_equal(rows[:, j], want.astype(np.float32).astype(float), equal_nan=True), c.name
        else:
            assert np.max(np.abs(rows[:, j] - want)) <= c.scale / 2 + 1e-15, c.name
    assert np.ptp(rows[:, MAP.capture_channel_names().index("position_m")]) > 1e-5  # the axis moved


def test_commands_refused_in_the_wrong_state():
    d = Drive()
    run = MAP.control["run"]
    d.load_table(np.zeros(10))
    assert d.set(control_word=run) == 3  # no limits loaded
    assert d.limits(torque=-1.0) == 3 and "limits_loaded" not in d.flags()
    assert d.limits() is None and "limits_loaded" in d.flags()
    assert d.fw.drive.torque_limit_nm == 5.0 and d.fw.drive.position_max_m == 1.0
    assert d.set(control_word=0) is None
    d.set(table_length=0)
    assert d.set(control_word=run) == 3  # empty table
    d.load_table(np.zeros(100))
    assert d.set(control_word=0) is None and d.set(control_word=run) is None
    assert d.set(mode=MAP.modes["velocity"]) == 6 and d.set(table_length=5) == 6  # locked while running
    assert d.fw.write(MAP.table.base, [0, 0]) == 6
    assert d.fw.write(MAP.capture.base, [0]) == 2  # the capture window is read-only
    assert d.set(control_word=0) is None  # stop: disabled, done
    assert not d.fw.drive.enabled and "done" in d.flags()
    assert d.set(mode=99) == 3 and d.set(sample_divider=0) == 3 and d.set(capture_mask=1 << 9) == 3


def test_filter_registers_feed_the_drive_filters():
    d = Drive()
    enc = MAP.filter_encoding
    base = MAP.filters.address(1)
    values = {"center": 218, "width": 65, "depth": 400}
    assert d.fw.write(base, MAP.encode_filter(values, enabled=False)) is None
    assert d.fw.drive.filters.read(1) == (enc.applied(values, 4000.0), False)
    assert d.fw.write(base, MAP.encode_filter(values, enabled=True)) is None
    biquad, enabled = d.fw.drive.filters.read(1)
    assert enabled and biquad == enc.applied(values, 4000.0)
    assert abs(biquad.response(np.array([21.8]), 4000.0)[0]) < 0.011  # -40 dB at 21.8 Hz: it really filters
    assert d.fw.write(base, MAP.encode_filter({"center": 20000, "width": 65, "depth": 400}, True)) == 3  # >= Nyquist
    assert d.fw.write(base, MAP.encode_filter({"center": 0, "width": 0, "depth": 0}, True)) == 3  # empty, enabled
    assert d.fw.drive.filters.read(1) == (biquad, True)  # refused writes change nothing
    assert d.fw.write(base, MAP.encode_filter({"center": 0, "width": 0, "depth": 0}, False)) is None
    assert d.fw.drive.filters.read(1) == (Biquad.identity(), False)


def test_limit_trip_ends_the_capture_at_the_trip():
    d = Drive()
    n = 400
    x = np.linspace(0.0, 8.0, n)  # torque ramp through the 5 N*m limit
    d.limits()
    mask = MAP.mask_of(["excitation", "torque_nm"])
    d.set(mode=MAP.modes["torque"], sample_divider=4, capture_mask=mask)
    d.load_table(x)
    d.set(control_word=MAP.control["run"])
    d.fw.advance(n)
    trip = int(np.argmax(x.astype(np.float32) > 5.0))
    assert "fault" in d.flags() and not d.fw.drive.enabled
    assert d.get("fault_code") == MAP.fault_codes["torque_limit"]
    assert d.get("fault_sample") == trip and d.get("sample_count") == trip + 1
    assert d.get("fault_value") > 5.0
    stamps, rows = d.capture(trip + 1, mask)
    assert stamps.tolist() == list(range(trip + 1))
    assert rows[-1, 1] == pytest.approx(0.0, abs=0.05)  # zero torque in the sample period of the trip
    d.set(control_word=0)
    assert d.set(control_word=MAP.control["run"]) == 3  # fault latched
    d.set(control_word=MAP.control["fault_reset"])
    assert d.get("fault_code") == 0 and d.fw.drive.fault is None


def test_capture_that_stops_early_and_a_drive_fault():
    d = Drive(capture_stops_after_s=0.1)
    d.limits()
    d.set(mode=MAP.modes["torque"], sample_divider=4)
    d.load_table(np.zeros(300))
    d.set(control_word=MAP.control["run"])
    d.fw.advance(300)
    assert d.get("sample_count") == 100 and d.fw.produced == 300  # the table played on
    assert {"done", "capture_stopped"} <= d.flags() and "fault" not in d.flags()

    d = Drive(drive_fault_after_s=0.05)
    d.limits()
    d.set(mode=MAP.modes["torque"], sample_divider=4)
    d.load_table(np.zeros(300))
    d.set(control_word=MAP.control["run"])
    for _ in range(5):
        d.fw.advance(40)
    assert d.get("fault_code") == MAP.fault_codes["drive_fault"] and d.get("fault_sample") == 50
    assert d.get("sample_count") == 50 and not d.fw.drive.enabled


# --- the server -----------------------------------------------------------------------------


def tcp_client(port: str, timeout: float = 1.0) -> ModbusTcpClient:
    host, number = port[len("tcp://") :].rsplit(":", 1)
    client = ModbusTcpClient(host, port=int(number), timeout=timeout, retries=0)
    assert client.connect()
    return client


def test_tcp_server_on_loopback_answers_as_the_map_says():
    emu = start(emulator_config(), DRIVER, DeviceConfig(modbus=ModbusDeviceConfig(device_id=3)), link="tcp")
    try:
        assert emu.port.startswith("tcp://127.0.0.1:") and int(emu.port.rsplit(":", 1)[1]) > 0
        client = tcp_client(emu.port)
        r = client.read_holding_registers(REG["device_name"].address, count=16, device_id=3)
        assert MAP.decode("device_name", r.registers) == DRIVER.name
        assert client.read_holding_registers(5, count=4, device_id=3).exception_code == 2  # crosses the gap at 7
        assert client.write_register(REG["status_word"].address, 1, device_id=3).exception_code == 2  # read-only
        assert client.write_registers(REG["mode"].address, [77], device_id=3).exception_code == 3
        client.close()
    finally:
        emu.close()
    assert not emu.drive.enabled


def test_rtu_over_a_pseudo_terminal():
    emu = start(emulator_config(), DRIVER, DeviceConfig(baudrate=230400), link="pty")
    try:
        assert emu.port.startswith("/dev/") and emu.device.modbus.parity == "N" and emu.device.baudrate == 230400
        client = ModbusSerialClient(emu.port, baudrate=230400, parity="N", timeout=1.0, retries=0)
        assert client.connect()
        t = time.monotonic()
        r = client.read_holding_registers(REG["device_name"].address, count=16, device_id=1)
        elapsed = time.monotonic() - t
        assert MAP.decode("device_name", r.registers) == DRIVER.name
        # 8 request + 37 answer characters of 11 bits at 230400 baud: the line takes its time
        assert elapsed >= 45 * 11 / 230400
        client.close()
    finally:
        emu.close()


def test_a_buffered_run_takes_its_duration_over_the_time_scale():
    emu = start(emulator_config(time_scale=5.0), DRIVER, DeviceConfig(), link="tcp")
    client = tcp_client(emu.port)
    try:

        def write(name, value):
            assert not client.write_registers(REG[name].address, MAP.encode(name, value), device_id=1).isError()

        limits = [
            r
            for name, v in (
                ("torque_limit_nm", 5.0),
                ("velocity_limit_mps", 1.0),
                ("position_min_m", -1.0),
                ("position_max_m", 1.0),
            )
            for r in MAP.encode(name, v)
        ]
        assert not client.write_registers(REG["torque_limit_nm"].address, limits, device_id=1).isError()
        for name, value in (("mode", MAP.modes["torque"]), ("sample_divider", 4), ("table_length", 2000)):
            write(name, value)
        regs = MAP.encode_table(np.zeros(2000))
        for c in plan_chunks(0, 2000, 2, MAP.table.page_samples, MAP.max_write):
            write("table_page", c.page)
            client.write_registers(
                MAP.table.base + c.offset,
                regs[2 * c.first_sample : 2 * (c.first_sample + c.samples)].tolist(),
                device_id=1,
            )
        t = time.monotonic()
        write("control_word", MAP.control["run"])
        status = REG["status_word"].address
        while MAP.status_flags(client.read_holding_registers(status, count=1, device_id=1).registers[0]) & {"running"}:
            time.sleep(0.01)
        elapsed = time.monotonic() - t
        assert 0.3 <= elapsed <= 0.9  # 2 s simulated at 5x
    finally:
        client.close()
        emu.close()


def test_fault_switches_of_the_server():
    faults = (
        "[emulator.faults.modbus]\nexception_register = 117\nexception_code = 4\nresponse_delay_s = 0.05\n"
        "missing_response_rate = 0.3"
    )
    emu = start(emulator_config(faults), DRIVER, DeviceConfig(), link="tcp")
    client = tcp_client(emu.port, timeout=0.2)
    try:
        answered = missing = 0
        t = time.monotonic()
        for _ in range(20):
            try:
                r = client.read_holding_registers(REG["table_crc"].address, count=1, device_id=1)
                assert r.exception_code == 4
                answered += 1
            except ModbusException:
                missing += 1
        assert missing >= 1 and answered >= 1
        assert missing == emu.server.dropped_responses
        assert time.monotonic() - t >= 20 * 0.05  # every answer waits
        r = None
        while r is None:
            try:
                r = client.read_holding_registers(REG["device_type"].address, count=1, device_id=1)
            except ModbusException:
                pass
        assert r.registers == [MAP.device_type]  # other registers answer normally
    finally:
        client.close()
        emu.close()


def test_exception_code_must_be_a_modbus_code():
    from hilident.errors import ConfigError

    with pytest.raises(ConfigError, match="exception_code"):
        faults = "[emulator.faults.modbus]\nexception_register = 100\nexception_code = 9"
        start(emulator_config(faults), DRIVER, DeviceConfig(), link="tcp")


def test_a_parameter_drive_with_register_block_slots_is_a_config_error_naming_the_table():
    """A map without an excitation table whose slots are register blocks: the twin cannot run them, and says so
    (it used to fail with an AttributeError while building the drive)."""
    from dataclasses import replace

    from hilident.errors import ConfigError

    sections = {
        "modbus": {
            "registers": {"model": {"address": 0, "type": "u16", "default": 7}},
            "identity": {"registers": ["model"]},
            "filters": {"base": 0x100, "stride": 4, "center": 0, "width": 1, "depth": 2, "enable": 3},
        },
        "filters": {
            "encoding": "notch_parameters",
            "width_unit": "q",
            "depth_unit": "percent",
            "scales": {"center": 0.1, "width": 0.01, "depth": 1.0},
        },
    }
    driver = replace(find_driver("dsy-rs"), filter_slots=1, sections=sections)
    assert not RegisterMap.from_driver(driver).excitation  # a parameter drive's map, slots and all, parses
    with pytest.raises(ConfigError) as info:
        start(emulator_config(), driver, DeviceConfig(), link="tcp")
    assert info.value.key == "modbus.filters" and "driver.toml" in str(info.value)


def test_a_table_drive_with_named_parameter_slots_is_a_config_error_naming_the_table():
    """The other way round: an excitation map whose slots are named parameters; the twin's filter writes would
    all fail (exception 04), so it is refused when it is built."""
    import copy
    from dataclasses import replace

    from hilident.errors import ConfigError

    sections = copy.deepcopy(DRIVER.sections)
    sections["modbus"]["registers"].update(
        {name: {"address": 900 + i, "type": "u16", "access": "rw"} for i, name in enumerate(("c", "w", "d", "on"))}
    )
    sections["modbus"]["filters"] = {"slots": [{"center": "c", "width": "w", "depth": "d", "enable": "on"}]}
    driver = replace(DRIVER, filter_slots=1, sections=sections)
    assert RegisterMap.from_driver(driver).excitation  # the map itself is valid
    with pytest.raises(ConfigError) as info:
        start(emulator_config(), driver, DeviceConfig(), link="tcp")
    assert info.value.key == "modbus.filters" and "driver.toml" in str(info.value)


# --- communication timeout ------------------------------------------------------------------


def test_communication_timeout_stops_an_enabled_drive_that_hears_nothing():
    d = Drive()
    run = MAP.control["run"]
    d.limits()
    d.load_table(np.full(4000, 0.5))
    assert d.set(comm_timeout_ms=300) is None and d.fw.comm_timeout_s == 0.3
    d.fw.heard_from_host(100.0)
    assert not d.fw.watch_host(101.0)  # disabled: nothing to watch
    assert d.set(control_word=run) is None
    d.fw.heard_from_host(200.0)
    d.fw.advance(50)
    assert not d.fw.watch_host(200.29) and d.fw.drive.enabled
    assert d.fw.watch_host(200.31)
    assert not d.fw.drive.enabled and not d.fw.running
    assert "fault" in d.flags() and d.get("fault_code") == MAP.fault_codes["comm_timeout"] == 5
    assert d.get("fault_sample") == 50 and abs(d.get("fault_value") - 0.31) < 1e-6
    assert d.set(control_word=0) is None
    assert d.set(control_word=run) == 3  # latched until a fault reset
    assert d.set(control_word=MAP.control["fault_reset"]) is None and "fault" not in d.flags()


def test_time_the_drive_could_not_listen_is_not_the_hosts_silence():
    d = Drive()
    d.limits()
    d.load_table(np.full(4000, 0.5))
    assert d.set(comm_timeout_ms=300, control_word=MAP.control["run"]) is None
    d.fw.heard_from_host(10.0)
    d.fw.excuse_silence(0.2)  # the twin's own process was not scheduled for 0.2 s
    assert not d.fw.watch_host(10.45) and d.fw.drive.enabled
    assert d.fw.watch_host(10.51) and not d.fw.drive.enabled


def test_communication_timeout_zero_is_off():
    d = Drive()
    d.limits()
    d.load_table(np.full(4000, 0.5))
    assert d.set(comm_timeout_ms=0) is None
    d.fw.heard_from_host(0.0)
    assert d.set(control_word=MAP.control["run"]) is None
    assert not d.fw.watch_host(1e6) and d.fw.drive.enabled


@pytest.mark.parametrize("link", ["tcp", "pty"])
def test_the_served_drive_stops_itself_when_the_host_goes_silent(link):
    emu = start(emulator_config(time_scale=1.0), DRIVER, DeviceConfig(baudrate=921600), link=link)
    client = (
        tcp_client(emu.port, timeout=0.5)
        if link == "tcp"
        else ModbusSerialClient(emu.port, baudrate=921600, parity="N", timeout=0.5, retries=0)
    )
    assert client.connect()
    fw = emu.server.firmware

    def write(name, value):
        assert not client.write_registers(REG[name].address, MAP.encode(name, value), device_id=1).isError()

    try:
        limits = [
            r
            for name, v in (
                ("torque_limit_nm", 5.0),
                ("velocity_limit_mps", 1.0),
                ("position_min_m", -1.0),
                ("position_max_m", 1.0),
            )
            for r in MAP.encode(name, v)
        ]
        assert not client.write_registers(REG["torque_limit_nm"].address, limits, device_id=1).isError()
        write("comm_timeout_ms", 200)
        write("table_length", 20000)  # a 5 s table of zeros: only the timeout can end this run early
        write("control_word", MAP.control["run"])
        assert fw.drive.enabled
        t = time.monotonic()
        for _ in range(30):  # talks for 0.3 s, more often than the timeout
            client.read_holding_registers(REG["status_word"].address, count=1, device_id=1)
            time.sleep(0.01)
        assert fw.drive.enabled and time.monotonic() - t > 0.2
        silent = time.monotonic()
        while fw.drive.enabled and time.monotonic() - silent < 2.0:
            time.sleep(0.002)
        stopped = time.monotonic() - silent
        assert 0.15 <= stopped <= 0.2 + 0.2
        assert fw.fault_code == MAP.fault_codes["comm_timeout"] and not fw.running
    finally:
        client.close()
        emu.close()
