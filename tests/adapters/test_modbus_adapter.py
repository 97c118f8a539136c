"""Host adapter against the emulated Modbus drive, over Modbus TCP and Modbus RTU on a pseudo-terminal."""

from __future__ import annotations

import contextlib
import shutil
import socket
import struct
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import serial
from pymodbus.exceptions import ModbusIOException

from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import DeviceConfig, parse_config
from hilident.drivers.description import find_driver, load_driver
from hilident.emulator.factory import build_drive
from hilident.emulator.modbus.server import start
from hilident.errors import ConfigError, DeviceError, LimitTrip
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.rtu import rtu_crc

DRIVER = find_driver("modbus-servo")
MAP = RegisterMap.from_driver(DRIVER)
LINKS = ["tcp", "pty"]


def emulator_config(time_scale: float = 10.0):
    return parse_config(f"""
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0

[emulator]
time_scale = {time_scale}
seed = 11

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
""").emulator


def host(emu, **settings) -> DeviceConfig:
    """The ``[device]`` a host uses for ``emu``; a loaded test machine can stall a host for half a second,
    so the communication timeout is 2 s unless a test is about it."""
    return replace(emu.device, **{"host_timeout_s": 2.0, **settings})


@contextlib.contextmanager
def drive(link: str = "tcp", time_scale: float = 10.0, driver=DRIVER, emulated=DRIVER, **settings):
    cfg = emulator_config(time_scale)
    emu = start(cfg, emulated, DeviceConfig(baudrate=921600, timeout_s=0.5), link=link)
    adapter = None
    try:
        adapter = ModbusDriveAdapter.open_device(host(emu, **settings), driver)
        adapter.set_limits(5.0, 1.0, -1.0, 1.0)
        yield emu, adapter, cfg
    finally:
        if adapter is not None:
            adapter.close()
        emu.close()


class Recorder:
    def __init__(self):
        self.index, self.rows = [], []

    def __call__(self, index, rows):
        self.index.append(index.copy())
        self.rows.append(rows.copy())

    def arrays(self):
        return np.concatenate(self.index), np.concatenate(self.rows)


def truth(cfg, x, divider, mode="torque"):
    """What the drive loop does with this table: the state at the start of each sample period."""
    twin = build_drive(cfg, DRIVER)
    twin.set_limits(5.0, 1.0, -1.0, 1.0)
    twin.set_mode(mode)
    twin.enable()
    return twin, twin.run(np.repeat(x.astype(np.float32).astype(float), divider))[::divider]


@pytest.mark.parametrize("link", LINKS)
def test_identifies_the_drive(link):
    with drive(link) as (emu, ad, _):
        assert ad.port == emu.port
        assert ad.identity.name == DRIVER.name and ad.identity.firmware == DRIVER.firmware
        assert ad.identity.loop_rate_hz == 4000.0 and ad.identity.filter_slots == 4
        assert emu.drive.torque_limit_nm == 5.0 and emu.drive.position_min_m == -1.0  # loaded into the drive


@pytest.mark.parametrize("link", LINKS)
def test_every_sample_arrives_as_the_drive_loop_produced_it(link):
    with drive(link) as (emu, ad, cfg):
        names = ["velocity_mps", "excitation", "torque_nm", "position_m"]
        assert ad.configure(1000.0, "torque", names) == names
        assert ad.channel_units == ["m/s", "N*m", "N*m", "m"] and ad.sample_rate_hz == 1000.0
        n = 2300  # the capture crosses two page boundaries
        x = 3.0 * np.sin(2 * np.pi * 9.0 * np.arange(n) / 1000.0)
        rec = Recorder()
        result = ad.stream(x, rec)
        index, rows = rec.arrays()
        assert np.array_equal(index, np.arange(n))
        s = result.stats
        assert (s.samples, s.lost_blocks, s.lost_samples, s.lost_frames, s.corrupt_frames, s.out_of_order) == (
            n,
            0,
            0,
            0,
            0,
            0,
        )
        assert result.completed and result.events[-1]["kind"] == "finished"
        assert not emu.drive.enabled
        twin, want = truth(cfg, x, 4)
        for j, name in enumerate(names):
            col = want[:, twin.CHANNELS.index(name)]
            if name == "position_m":
                assert np.max(np.abs(rows[:, j] - col)) <= 0.5e-7 + 1e-15
            else:
                assert np.array_equal(rows[:, j], col.astype(np.float32).astype(float)), name
        assert np.ptp(rows[:, 3]) > 1e-4


def test_filters_are_read_back_from_the_drive_registers():
    with drive() as (emu, ad, _):
        spec = NotchSpec(center_hz=123.456, width_hz=30.04, depth_db=25.0)
        designed = design_notch(spec, 4000.0)
        empty = ad.save_filter(2)
        assert ad.read_filter(2) == (Biquad.identity(), False)
        ad.write_filter(2, designed, spec, enabled=False)
        stored, enabled = ad.read_filter(2)
        assert not enabled and stored == ad.stored_form(designed, spec)
        assert stored != designed  # 0.1 Hz / 0.1 dB steps: centre 123.5 Hz, width 30.0 Hz
        assert emu.drive.filters.read(2) == (stored, False)
        ad.write_filter(2, designed, spec, enabled=True)
        assert ad.read_filter(2) == (stored, True) and emu.drive.filters.read(2) == (stored, True)
        # what another master writes is what read_filter sees: nothing is cached on the host
        other = ModbusDriveAdapter.open_device(DeviceConfig(port=emu.port, timeout_s=0.5), DRIVER)
        other.registers.write(
            MAP.filters.address(2), MAP.encode_filter({"center": 500, "width": 100, "depth": 200}, True)
        )
        other.client.close()
        got, _ = ad.read_filter(2)
        assert got == MAP.filter_encoding.applied({"center": 500, "width": 100, "depth": 200}, 4000.0)
        ad.restore_filter(2, empty)
        assert ad.read_filter(2) == (Biquad.identity(), False)
        assert emu.drive.filters.read(2) == (Biquad.identity(), False)


def test_limit_trip_after_delivering_the_samples_up_to_it():
    with drive() as (emu, ad, _):
        ad.configure(1000.0, "torque", ["excitation", "torque_nm", "velocity_mps", "position_m"])
        x = np.linspace(0.0, 8.0, 1500)  # through the 5 N*m limit
        rec = Recorder()
        with pytest.raises(LimitTrip) as err:
            ad.stream(x, rec)
        assert "torque_limit" in str(err.value) and "fault_code" in str(err.value)
        index, rows = rec.arrays()
        trip = int(np.argmax(x.astype(np.float32) > 5.0))
        assert np.array_equal(index, np.arange(trip + 1))
        assert not emu.drive.enabled and emu.drive.fault == "torque_limit"
        events = ad.last_result.events
        assert events[-1]["kind"] == "limit_trip" and events[-1]["sample_index"] == trip
        with pytest.raises(DeviceError, match="torque_limit.*clear the fault"):
            ad.stream(np.zeros(10), rec)
        ad.clear_fault()
        assert ad.stream(np.zeros(10), Recorder()).completed


def test_configuration_errors_name_the_cause():
    with drive() as (_, ad, _):
        with pytest.raises(DeviceError, match="does not divide"):
            ad.configure(3000.0, "torque")
        with pytest.raises(ConfigError, match="run.channels.*time_s"):
            ad.configure(1000.0, "torque", ["excitation", "time_s"])
        ad.configure(1000.0, "torque")
        with pytest.raises(DeviceError, match=r"8 \(table_capacity"):
            ad.stream(np.zeros(MAP.table.capacity_samples + 1), Recorder())


def test_an_adapter_that_never_identified_the_drive_says_so_before_asking_it_anything():
    from pymodbus.client import ModbusTcpClient

    ad = ModbusDriveAdapter(ModbusTcpClient("127.0.0.1", port=9, retries=0), DRIVER, MAP, "tcp://127.0.0.1:9")
    with pytest.raises(DeviceError, match=r"tcp://127.0.0.1:9: the drive has not been identified"):
        ad.configure(1000.0, "torque")
    with pytest.raises(DeviceError, match="not been identified"):
        ad.stored_form(Biquad.identity(), NotchSpec(center_hz=80.0, width_hz=20.0, depth_db=30.0))


def test_a_gateway_exception_names_the_device_id_key_where_it_now_lives():
    from hilident.adapters.modbus.common import _exception_text

    assert "check [device.modbus] device_id" in _exception_text(10, 3, 7)
    assert "with id 7" in _exception_text(11, 3, 7) and "[device.modbus] device_id" in _exception_text(11, 3, 7)


def test_a_different_device_is_refused(tmp_path):
    folder = tmp_path / "other-servo"
    shutil.copytree(DRIVER.folder, folder)
    text = (folder / "driver.toml").read_text().replace("device_type = 0x4D53", "device_type = 0x1234")
    (folder / "driver.toml").write_text(text)
    with pytest.raises(DeviceError, match=r"register 0 \(device_type\) holds 0x4d53.*expects 0x1234"):
        with drive(driver=load_driver(folder)):
            pass


def test_nobody_listening_names_the_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    s.close()
    with pytest.raises(DeviceError, match=port):
        ModbusDriveAdapter.open_device(DeviceConfig(port=port, timeout_s=0.2), DRIVER)


def test_ctrl_c_in_the_middle_of_a_run_leaves_the_drive_disabled():
    with drive(time_scale=1.0) as (emu, ad, _):
        ad.configure(1000.0, "torque")

        def sink(index, rows):
            raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            ad.stream(np.full(5000, 0.5), sink)
        assert not emu.drive.enabled
        assert ad.last_result is not None and not ad.last_result.completed


def test_the_start_command_is_never_sent_twice():
    with drive() as (emu, ad, _):
        ad.configure(1000.0, "torque")
        sent = []
        real = ad.client.write_register

        def answer_lost(*args, **kwargs):  # the drive gets the command, its answer is lost
            sent.append(args)
            real(*args, **kwargs)
            raise ModbusIOException("no response")

        ad.client.write_register = answer_lost
        result = ad.stream(np.zeros(300), Recorder())
        assert len(sent) == 1 and result.completed and result.stats.samples == 300
        assert any(e["kind"] == "missing_response" for e in result.events)

        def request_lost(*args, **kwargs):  # the command never reaches the drive
            sent.append(args)
            raise ModbusIOException("no response")

        ad.client.write_register = request_lost
        sent.clear()
        with pytest.raises(DeviceError, match=r"register 100 \(control_word\).*not running.*never sent twice"):
            ad.stream(np.zeros(300), Recorder())
        assert len(sent) == 1 and not emu.drive.enabled


def test_records_that_are_not_the_ones_asked_for_are_read_again_or_counted_lost():
    with drive() as (_, ad, _):
        ad.configure(1000.0, "torque")  # 9-register records: stamp, 4 channels
        real = ad.client.read_holding_registers
        capture = MAP.capture
        state = {"stale": 1}

        def damaged(address, count=1, device_id=1):
            r = real(address, count=count, device_id=device_id)
            if capture.base <= address < capture.end:
                regs = list(r.registers)
                if state["stale"]:  # one answer with the records of another chunk
                    state["stale"] -= 1
                    regs = [(v + 13) % 65536 if i % 9 == 0 else v for i, v in enumerate(regs)]
                elif any(39 <= regs[i] <= 51 for i in range(0, len(regs), 9)):  # damaged every time
                    regs[0] ^= 0x4000
                r.registers = regs
            return r

        ad.client.read_holding_registers = damaged
        rec = Recorder()
        n = 600
        result = ad.stream(np.zeros(n), rec)
        index, _ = rec.arrays()
        s = result.stats
        missing = np.setdiff1d(np.arange(n), index)
        assert set(range(39, 52)) <= set(missing.tolist())  # the hole stays a hole
        assert s.lost_blocks >= 1 and s.lost_samples == len(missing)
        # every wrong answer was counted: the stale one, and each of the 4 reads of every damaged chunk
        assert s.out_of_order >= 1 and s.out_of_order + s.corrupt_frames == 1 + 4 * s.lost_blocks
        assert len(index) == s.samples == n - len(missing) and np.all(np.diff(index) > 0)
        lost = [e for e in result.events if e["kind"] == "lost_blocks"]
        assert len(lost) == s.lost_blocks and lost[0]["sample_index"] == missing[0]


def test_a_drive_with_the_low_word_first(tmp_path):
    folder = tmp_path / "little-servo"
    shutil.copytree(DRIVER.folder, folder)
    text = (folder / "driver.toml").read_text().replace('word_order = "big"', 'word_order = "little"')
    (folder / "driver.toml").write_text(text)
    little = load_driver(folder)
    with drive(driver=little, emulated=little) as (emu, ad, cfg):
        ad.configure(1000.0, "torque", ["excitation", "position_m"])
        n = 1500
        x = 3.0 * np.sin(2 * np.pi * 9.0 * np.arange(n) / 1000.0)
        rec = Recorder()
        ad.stream(x, rec)
        index, rows = rec.arrays()
        assert np.array_equal(index, np.arange(n))
        assert np.array_equal(rows[:, 0], x.astype(np.float32).astype(float))
        twin, want = truth(cfg, x, 4)
        assert np.max(np.abs(rows[:, 1] - want[:, twin.CHANNELS.index("position_m")])) <= 0.5e-7 + 1e-15
        length = MAP.register("table_length").address
        assert ad.registers.read(length, 2) == [n % 65536, n // 65536]  # low word at the lower address, on the wire


# --- connect, stop, and what is left behind ---------------------------------------------------


def wait_until(condition, within_s: float) -> float:
    """Seconds until ``condition()`` held (``within_s`` + 1 when it never did)."""
    t = time.monotonic()
    while not condition():
        if time.monotonic() - t > within_s:
            return within_s + 1.0
        time.sleep(0.002)
    return time.monotonic() - t


def start_run_and_vanish(ad, n: int = 3000) -> None:
    """Enable the drive through the adapter, then die hard: drop the connection without a word."""
    ad.configure(1000.0, "torque")
    ad.capture.load_table(np.zeros(n))
    ad.capture.trigger()
    ad.client.socket.close()  # no stop, no goodbye: as SIGKILL or a pulled cable leaves it


@pytest.mark.parametrize("link", LINKS)
def test_a_host_that_dies_leaves_the_drive_stopped_by_its_communication_timeout(link):
    with drive(link, time_scale=1.0, host_timeout_s=0.3) as (emu, ad, _):
        assert ad.connect_report.device_net == "communication timeout register 128 (comm_timeout_ms): 300 ms"
        assert emu.server.firmware.comm_timeout_s == 0.3
        start_run_and_vanish(ad)
        assert emu.drive.enabled
        stopped = wait_until(lambda: not emu.drive.enabled, 2.0)
        assert stopped <= 0.3 + 0.15
        assert emu.server.firmware.fault_code == MAP.fault_codes["comm_timeout"]


def test_a_latched_fault_is_reported_and_cleared_only_when_allowed():
    with drive(time_scale=1.0, host_timeout_s=0.2) as (emu, ad, _):
        start_run_and_vanish(ad)
        wait_until(lambda: not emu.drive.enabled, 2.0)
        with pytest.raises(DeviceError) as err:
            ModbusDriveAdapter.open_device(host(emu), DRIVER)
        text = str(err.value)
        assert emu.port in text and "comm_timeout" in text and "register 102 (fault_code) = 5" in text
        assert "allow_fault_reset = true" in text and "--clear-fault" in text
        assert emu.server.firmware.fault_code == 5  # refused: nothing was cleared
        again = ModbusDriveAdapter.open_device(host(emu, allow_fault_reset=True), DRIVER)
        try:
            report = again.connect_report
            assert report.faults_cleared and len(report.faults) == 1 and "comm_timeout" in report.faults[0]
            assert emu.server.firmware.fault_code == 0
            again.set_limits(5.0, 1.0, -1.0, 1.0)
            again.configure(1000.0, "torque")
            assert again.stream(np.full(200, 0.2), Recorder()).completed
        finally:
            again.close()


def test_a_limit_trip_left_latched_refuses_the_next_session_until_reset():
    with drive() as (emu, ad, _):
        ad.configure(1000.0, "torque")
        with pytest.raises(LimitTrip):
            ad.stream(np.linspace(0.0, 8.0, 1500), Recorder())
        with pytest.raises(
            DeviceError, match=r"torque_limit \(register 102 \(fault_code\) = 1, at sample \d+, value 5\.0"
        ):
            ModbusDriveAdapter.open_device(host(emu), DRIVER)
        clean = ModbusDriveAdapter.open_device(host(emu, allow_fault_reset=True), DRIVER)
        clean.close()
        assert clean.connect_report.faults_cleared and emu.drive.fault is None
        fresh = ModbusDriveAdapter.open_device(host(emu), DRIVER)
        fresh.close()
        assert fresh.connect_report.faults == [] and not fresh.connect_report.faults_cleared


def test_answers_left_on_an_rtu_line_by_a_dead_host_are_dropped_and_counted():
    cfg = emulator_config()
    cfg = replace(cfg, faults=replace(cfg.faults, response_delay_s=0.1))
    emu = start(cfg, DRIVER, DeviceConfig(baudrate=921600, timeout_s=0.5), link="pty")
    try:
        # the earlier host sent a read of the status registers and died before the (slow) answer came
        dead = serial.Serial(emu.port, baudrate=921600, timeout=0)
        body = bytes([1, 3]) + MAP.register("status_word").address.to_bytes(2, "big") + (8).to_bytes(2, "big")
        crc = rtu_crc(body)
        dead.write(body + bytes([crc & 0xFF, crc >> 8]))
        dead.flush()
        dead.close()
        ad = ModbusDriveAdapter.open_device(host(emu), DRIVER)
        try:
            assert ad.connect_report.discarded_frames == 1
            assert ad.identity.name == DRIVER.name and ad.registers.bad_responses == 0
        finally:
            ad.close()
    finally:
        emu.close()


def test_safe_stop_is_quick_keeps_the_connection_and_the_sink_error_propagates():
    with drive(time_scale=1.0) as (emu, ad, _):
        ad.configure(1000.0, "torque")
        seen = {}

        def sink(index, rows):
            assert emu.drive.enabled
            t = time.monotonic()
            ad.safe_stop()
            seen["stop_s"] = time.monotonic() - t
            seen["enabled"] = emu.drive.enabled
            raise OSError(28, "No space left on device")

        with pytest.raises(OSError, match="No space left"):
            ad.stream(np.full(5000, 0.3), sink)
        assert seen["enabled"] is False and seen["stop_s"] < 0.1
        assert not emu.drive.enabled and not ad.last_result.completed
        assert ad.read_filter(0) == (Biquad.identity(), False)  # still connected


def test_safe_stop_never_raises_when_the_drive_is_gone():
    with drive() as (emu, ad, _):
        emu.close()
        t = time.monotonic()
        ad.safe_stop()
        assert time.monotonic() - t < 0.5


def test_disable_filter_keeps_the_slot_contents():
    with drive() as (emu, ad, _):
        spec = NotchSpec(center_hz=80.0, width_hz=20.0, depth_db=30.0)
        ad.write_filter(1, design_notch(spec, 4000.0), spec, enabled=True)
        saved = ad.save_filter(1)
        stored, enabled = ad.read_filter(1)
        assert enabled and emu.drive.filters.read(1) == (stored, True)
        ad.disable_filter(1)
        assert ad.read_filter(1) == (stored, False) and emu.drive.filters.read(1) == (stored, False)
        ad.restore_filter(1, saved)
        assert ad.read_filter(1) == (stored, True)


def test_events_are_live_and_start_empty_with_each_stream():
    with drive() as (_, ad, _):
        ad.configure(1000.0, "torque")
        with pytest.raises(LimitTrip):
            ad.stream(np.linspace(0.0, 8.0, 1500), Recorder())
        assert ad.events[-1]["kind"] == "limit_trip"
        seen = []
        ad.clear_fault()
        ad.stream(np.zeros(300), lambda index, rows: seen.append(list(ad.events)))
        assert seen[0] == []  # the last stream's events are gone
        assert ad.last_result.events == ad.events and ad.last_result.events is not ad.events


def test_the_first_cause_wins_a_limit_trip_then_a_failed_read():
    with drive() as (emu, ad, _):
        ad.configure(1000.0, "torque")
        read = ad.registers.read

        def broken_after_the_trip(*args, **kwargs):
            if any(e["kind"] == "limit_trip" for e in ad.events):
                raise DeviceError(f"{ad.port}: reading capture: no answer")
            return read(*args, **kwargs)

        ad.registers.read = broken_after_the_trip
        with pytest.raises(LimitTrip, match="torque_limit.*then: .*no answer"):
            ad.stream(np.linspace(0.0, 8.0, 1500), Recorder())
        assert not emu.drive.enabled


def test_a_drive_vanishing_mid_run_is_a_device_error_naming_the_port():
    with drive(time_scale=1.0) as (emu, ad, _):
        ad.configure(1000.0, "torque")
        rec = Recorder()

        def sink(index, rows):
            rec(index, rows)
            if len(rec.index) == 1:
                emu.close()  # power-cycled under the host's feet

        with pytest.raises(DeviceError, match=f"{emu.port}: .*connection to the drive was lost") as err:
            ad.stream(np.full(5000, 0.3), sink)
        assert type(err.value) is DeviceError and not ad.last_result.completed


@contextlib.contextmanager
def hostile_server(reset: bool):
    """A TCP server on 127.0.0.1 that accepts and closes each connection (``reset``: with a TCP RST)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    srv.settimeout(0.1)
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                continue
            if reset:
                conn.recv(260)  # take the request, then reset
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        thread.join()
        srv.close()


@pytest.mark.parametrize("reset", [False, True])
def test_a_server_that_accepts_and_closes_is_a_device_error_naming_the_port(reset):
    with hostile_server(reset) as port:
        with pytest.raises(
            DeviceError, match=f"{port}: reading registers 0\\.\\.6 \\(device_type.*connection to the drive was lost"
        ):
            ModbusDriveAdapter.open_device(DeviceConfig(port=port, timeout_s=0.3), DRIVER)


@pytest.mark.parametrize("link", LINKS)
def test_a_signal_in_the_middle_of_a_request_stops_the_drive_and_the_line_stays_usable(link):
    import signal

    with drive(link, time_scale=1.0) as (emu, ad, _):
        ad.configure(1000.0, "torque")
        # Ctrl-C as at a terminal, also when the suite was started with SIGINT ignored (a background job)
        previous = signal.signal(signal.SIGINT, signal.default_int_handler)
        timer = threading.Timer(0.4, signal.pthread_kill, (threading.main_thread().ident, signal.SIGINT))
        timer.start()
        try:
            with pytest.raises(KeyboardInterrupt):
                ad.stream(np.full(3000, 0.3), Recorder())  # mostly waiting for answers when the signal comes
        finally:
            timer.cancel()
            signal.signal(signal.SIGINT, previous)
        assert not emu.drive.enabled and not emu.server.firmware.running
        # the answer the interrupted request never read is not taken for another one
        rec = Recorder()
        result = ad.stream(np.full(300, 0.1), rec)
        assert result.completed and np.array_equal(rec.arrays()[0], np.arange(300))


def test_a_run_left_playing_by_a_dead_host_is_stopped_at_connect():
    with drive(time_scale=1.0, host_timeout_s=10.0) as (emu, ad, _):
        start_run_and_vanish(ad)
        assert emu.drive.enabled and emu.server.firmware.running
        nxt = ModbusDriveAdapter.open_device(host(emu), DRIVER)
        try:
            assert not emu.drive.enabled and not emu.server.firmware.running  # before anything else happens
            assert nxt.connect_report.faults == []  # a stop is no fault
            assert nxt.connect_report.device_net.endswith(": 2000 ms") and emu.server.firmware.comm_timeout_s == 2.0
        finally:
            nxt.close()
