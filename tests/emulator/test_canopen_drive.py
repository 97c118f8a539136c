"""The emulated CiA 402 drive, seen from a plain canopen host over the virtual bus (no hilident adapter)."""

from __future__ import annotations

import struct
import time
from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest
from canopen.sdo import SdoAbortedError

import canopen
from hilident.config.tables import CanopenDeviceConfig, DeviceConfig, load_config
from hilident.drivers.description import find_driver
from hilident.emulator.canopen.server import start, start_socketcand
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import TableState, mapping_entry
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.filter_encoding import FilterEncoding
from support.canopen_cycles import CycleClock

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"
NODE = 3
BUS = CanopenDeviceConfig(node_id=NODE)  # [device.canopen] of the twins under test


def emulator_config(**canopen_faults):
    """The shipped CANopen twin, ten times faster, with ``canopen_faults`` set in [emulator.faults.canopen]."""
    emu = load_config(CONFIG).emulator
    faults = replace(emu.faults, canopen=replace(emu.faults.canopen, **canopen_faults))
    return replace(emu, time_scale=10.0, faults=faults)


class Host:
    """A bare canopen master on the drive's bus."""

    def __init__(self, emulated, driver):
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        self.network.connect(interface=emulated.device.canopen.can_interface, channel=emulated.device.port)
        self.node = self.network.add_node(NODE, str(driver.folder / f"{driver.name}.eds"))
        self.emcy = []
        self.node.emcy.add_callback(self.emcy.append)

    def sdo(self, index, sub=0):
        return self.node.sdo[index] if sub is None else self.node.sdo[index][sub] if sub else self.node.sdo[index]

    def write(self, index, sub, value):
        var = (
            self.node.sdo[index][sub]
            if isinstance(self.node.sdo[index], (canopen.sdo.SdoRecord, canopen.sdo.SdoArray))
            else self.node.sdo[index]
        )
        var.raw = value

    def read(self, index, sub=0):
        var = (
            self.node.sdo[index][sub]
            if isinstance(self.node.sdo[index], (canopen.sdo.SdoRecord, canopen.sdo.SdoArray))
            else self.node.sdo[index]
        )
        return var.raw

    def state(self):
        return cia402.decode_statusword(self.read(0x6041))

    def limits(self, torque=19.0, velocity=0.4, lo=-0.6, hi=0.6):
        self.write(0x6072, 0, int(torque / 1e-3))
        self.write(0x6080, 0, int(velocity / 1e-6))
        self.write(0x607D, 1, int(lo / 1e-7))
        self.write(0x607D, 2, int(hi / 1e-7))

    def enable(self, mode=10):
        self.write(0x6060, 0, mode)
        for cw in cia402.path_to_operation_enabled(self.state()):
            self.write(0x6040, 0, cw)
        assert self.state() is cia402.State.OPERATION_ENABLED

    def close(self):
        self.network.disconnect()


@pytest.fixture
def drive_host():
    started = []

    def make(driver_name="canopen-servo", **faults):
        driver = find_driver(driver_name)
        emulated = start(emulator_config(**faults), driver, DeviceConfig(driver=driver_name, canopen=BUS))
        host = Host(emulated, driver)
        started.append((host, emulated))
        return host, emulated, driver

    yield make
    for host, emulated in started:
        host.close()
        emulated.close()


def test_identity_heartbeat_and_the_eds_objects(drive_host):
    host, emulated, driver = drive_host()
    assert emulated.device.canopen.can_interface == "virtual" and emulated.device.port.startswith("hilident-canopen")
    assert host.read(0x1018, 1) == 0x0F1D and host.read(0x1018, 2) == 0x00040201
    assert host.read(0x1008) == "hilident CiA 402 servo"
    assert host.read(0x2000) == driver.loop_rate_hz
    assert host.read(0x1000) & 0xFFFF == 402  # device profile
    assert host.read(0x6502) & (1 << 7 | 1 << 8 | 1 << 9) == (1 << 7 | 1 << 8 | 1 << 9)  # CSP, CSV, CST
    host.write(0x1017, 0, 20)
    assert host.node.nmt.wait_for_heartbeat(1.0) == "PRE-OPERATIONAL"
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x1018, 1, 5)  # read-only identity
    assert err.value.code == 0x06010002


def test_a_value_outside_the_eds_limits_is_refused_as_a_drive_refuses_it(drive_host):
    host, _, _ = drive_host()
    od = host.node.object_dictionary[0x1016][1]  # consumer heartbeat time 1: LowLimit 0, HighLimit 0x007FFFFF
    assert (od.min, od.max) == (0, 0x007FFFFF)
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x1016, 1, 0x00800000)
    assert err.value.code == 0x06090031  # CiA 301: value of parameter written too high
    assert host.read(0x1016, 1) == 0  # the refused value is not kept
    host.write(0x1016, 1, 0x007FFFFF)  # the limit itself is a value the drive takes
    assert host.read(0x1016, 1) == 0x007FFFFF


def test_state_machine_needs_limits_and_drives_the_loop(drive_host):
    host, emulated, _ = drive_host()
    assert host.state() is cia402.State.SWITCH_ON_DISABLED
    host.write(0x6060, 0, 10)
    host.write(0x6040, 0, 0x06)
    host.write(0x6040, 0, 0x07)
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x6040, 0, 0x0F)  # no trip limits loaded yet
    assert err.value.code == 0x08000022 and host.state() is cia402.State.SWITCHED_ON
    host.limits()
    assert emulated.drive.torque_limit_nm == pytest.approx(19.0) and emulated.drive.position_max_m == pytest.approx(0.6)
    host.write(0x6040, 0, 0x0F)
    assert host.state() is cia402.State.OPERATION_ENABLED and emulated.drive.enabled and emulated.drive.mode == "torque"
    host.write(0x6040, 0, 0x00)  # disable voltage
    assert host.state() is cia402.State.SWITCH_ON_DISABLED and not emulated.drive.enabled
    with pytest.raises(SdoAbortedError):
        host.write(0x6060, 0, 4)  # profile torque: not offered
    host.enable(mode=-3)
    assert emulated.drive.mode == "torque_injection"


def test_block_and_segmented_transfer_of_the_table(drive_host):
    host, _, _ = drive_host()
    sdo = host.node.sdo
    table = np.linspace(-1, 1, 3001).astype("<f4").tobytes()  # 12004 bytes: last segment partly filled
    with sdo.open(0x2200, 0, "wb", size=len(table), block_transfer=True, buffering=0) as f:
        pos = 0
        while pos < len(table):
            pos += f.write(table[pos : pos + 7])
    assert host.read(0x2201, 1) == 3001
    with sdo.open(0x2200, 0, "rb", block_transfer=True, buffering=0) as f:
        assert f.readall() == table
    assert sdo.upload(0x2200, 0) == table  # segmented
    sdo.download(0x2200, 0, table[:400], force_segment=True)
    assert host.read(0x2201, 1) == 100
    with pytest.raises(SdoAbortedError) as err:
        sdo.download(0x2200, 0, np.array([1.0, np.nan], "<f4").tobytes())
    assert err.value.code == 0x06090030 and host.read(0x2201, 1) == 100
    too_big = b"\0" * 4 * (host.read(0x2201, 6) + 1)
    for block in (False, True):  # refused at the start, from the announced size
        with pytest.raises(SdoAbortedError) as err:
            with sdo.open(0x2200, 0, "wb", size=len(too_big), block_transfer=block, buffering=0) as f:
                f.write(too_big[:7])
        assert err.value.code == 0x06070012


def _map(host, comm, mapping, cob, entries):
    host.write(comm, 1, cob | 0x80000000)
    host.write(mapping, 0, 0)
    for i, e in enumerate(entries, 1):
        host.write(mapping, i, e)
    host.write(mapping, 0, len(entries))
    host.write(comm, 1, cob)


def test_one_sync_is_one_sample_period_with_the_latest_setpoint(drive_host):
    host, emulated, _ = drive_host()
    counter, demand, excitation = ObjectAddress(0x2100), ObjectAddress(0x6074), ObjectAddress(0x2102)
    _map(
        host,
        0x1800,
        0x1A00,
        0x180 + NODE,
        [mapping_entry(counter, 16), mapping_entry(excitation, 32), mapping_entry(demand, 16)],
    )
    _map(
        host,
        0x1400,
        0x1600,
        0x200 + NODE,
        [mapping_entry(ObjectAddress(0x2101), 16), mapping_entry(ObjectAddress(0x6071), 16)],
    )
    with pytest.raises(SdoAbortedError):  # the mapping of a valid PDO is locked
        host.write(0x1A00, 1, 0)
    host.write(0x1006, 0, 1000)  # 1 ms SYNC: 4 loop ticks at 4 kHz
    host.node.nmt.state = "OPERATIONAL"
    host.limits()
    host.enable(mode=10)
    got = []

    def on_tpdo(can_id, data, ts):
        got.append(struct.unpack("<Hfh", bytes(data)))

    host.network.subscribe(0x180 + NODE, on_tpdo)
    tick0 = emulated.drive.tick
    setpoints = [0.5, -1.25, 2.0, 0.0, 3.5]
    clock = CycleClock(1e-3)  # at the period, as a real host sends (a late cycle is skipped, never sent late)
    syncs = []

    def send(k):
        host.network.send_message(0x200 + NODE, struct.pack("<Hh", k, int(round(setpoints[k] / 1e-3))))
        host.network.send_message(0x80, bytes([len(syncs) + 1]))
        syncs.append(k)

    clock.at(range(5), send)
    sent = clock.sent
    deadline = time.monotonic() + 2.0
    while len(got) < len(sent) and time.monotonic() < deadline:
        time.sleep(0.001)
    assert [g[0] for g in got] == sent  # sample counter: the cycle of each SYNC
    want = [setpoints[k] for k in sent]
    assert [g[1] for g in got] == pytest.approx(want)  # the set-point applied in that period
    assert [g[2] * 1e-3 for g in got] == pytest.approx(want)  # CST: torque demand = set-point (no filter)
    assert emulated.drive.tick - tick0 == (sent[-1] + 1) * 4  # one period per cycle
    assert host.read(0x2110, 1) == 0 and host.read(0x2110, 2) == 0  # no underrun, SYNC counter continuous
    jumped = []

    def jump(k):  # one SYNC at a later cycle's instant, its counter jumping, no fresh set-point
        if not jumped:
            host.network.send_message(0x80, b"\x09")
            jumped.append(k)

    clock.at(range(sent[-1] + 30, sent[-1] + 90), jump)
    time.sleep(0.05)
    assert host.read(0x2110, 1) == 1 and host.read(0x2110, 2) == 1


def test_table_plays_at_time_scale_and_captures(drive_host):
    host, emulated, _ = drive_host()
    fs, n = 1000.0, 1500
    x = 0.4 * np.sin(2 * np.pi * 3.0 * np.arange(n) / fs)
    host.node.sdo.download(0x2200, 0, x.astype("<f4").tobytes())
    host.write(0x2201, 2, 4)
    host.write(0x2202, 0, 0)
    for i, (addr, bits) in enumerate([(0x2102, 32), (0x6064, 32), (0x2100, 16)], 1):
        host.write(0x2202, i, mapping_entry(ObjectAddress(addr), bits))
    host.write(0x2202, 0, 3)
    host.limits()
    host.enable(mode=10)
    t0 = time.monotonic()
    host.write(0x2201, 3, 1)
    while host.read(0x2201, 4) == TableState.PLAYING:
        time.sleep(0.01)
    wall = time.monotonic() - t0
    assert host.read(0x2201, 4) == TableState.DONE and host.read(0x2201, 5) == n
    assert 0.6 * n / fs / 10.0 < wall < 3 * n / fs / 10.0 + 0.1  # 1.5 s simulated at time_scale 10
    assert host.state() is cia402.State.SWITCHED_ON and not emulated.drive.enabled  # end of table: torque off
    chunks, offset = [], 0
    while offset < n:
        host.write(0x2201, 7, offset)
        data = host.node.sdo.upload(0x2203, 0)
        chunks.append(data)
        offset += len(data) // 10
    rec = np.frombuffer(b"".join(chunks), np.dtype([("x", "<f4"), ("p", "<i4"), ("k", "<u2")]))
    assert np.array_equal(rec["x"], x.astype("<f4"))
    assert np.array_equal(rec["k"], np.arange(n) & 0xFFFF)
    assert np.ptp(rec["p"]) > 100  # the cart moved (units of 1e-7 m)


@pytest.mark.parametrize("driver_name", ["canopen-servo", "canopen-servo-fixed"])
def test_filter_slot_is_what_the_plant_sees(drive_host, driver_name):
    host, emulated, driver = drive_host(driver_name)
    encoding = FilterEncoding.from_table(driver.sections["filters"])
    spec = NotchSpec(center_hz=21.8, width_hz=6.5, depth_db=40.0)
    values = encoding.encode(design_notch(spec, driver.loop_rate_hz), spec)
    for sub, name in enumerate(encoding.fields, start=2):
        host.write(0x2301, sub, values[name])
    assert emulated.drive.filters.read(1) == (Biquad.identity(), False)  # fields alone change nothing
    host.write(0x2301, 1, 1)  # enable: the slot takes its fields
    biquad, enabled = emulated.drive.filters.read(1)
    assert enabled and biquad == encoding.applied(values, driver.loop_rate_hz)
    read_back = {name: host.read(0x2301, sub) for sub, name in enumerate(encoding.fields, start=2)}
    assert read_back == values
    # an unstable section is refused and never switched in
    host.write(0x2302, 6, 1.5 if encoding.kind == "real32" else int(1.5 * 2**29))
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x2302, 1, 1)
    assert err.value.code == 0x06090030 and emulated.drive.filters.read(2)[1] is False


def test_limit_trip_sends_emcy_with_the_sample_and_faults(drive_host):
    host, emulated, _ = drive_host()
    _map(
        host,
        0x1400,
        0x1600,
        0x200 + NODE,
        [mapping_entry(ObjectAddress(0x2101), 16), mapping_entry(ObjectAddress(0x6071), 16)],
    )
    host.write(0x1006, 0, 1000)
    host.node.nmt.state = "OPERATIONAL"
    host.limits(torque=2.0)
    host.enable(mode=10)

    def send(k):
        tq = 1.0 if k < 6 else 3.0  # beyond the 2 N*m limit from sample 6 on
        host.network.send_message(0x200 + NODE, struct.pack("<Hh", k, int(tq / 1e-3)))
        host.network.send_message(0x80, b"")

    clock = CycleClock(1e-3)
    clock.at(range(10), send)
    deadline = time.monotonic() + 2
    while not host.emcy and time.monotonic() < deadline:
        time.sleep(0.01)
    (emcy,) = host.emcy
    assert emcy.code == 0x8311 and int.from_bytes(emcy.data[:4], "little") == min(k for k in clock.sent if k >= 6)
    assert host.state() is cia402.State.FAULT and not emulated.drive.enabled
    assert host.read(0x603F) == 0x8311 and host.read(0x1003, 0) == 1 and host.read(0x1003, 1) == 0x8311
    host.write(0x6040, 0, 0x0F)
    assert host.state() is cia402.State.FAULT  # only a fault reset leaves Fault
    host.write(0x6040, 0, 0x00)
    host.write(0x6040, 0, 0x80)
    assert host.state() is cia402.State.SWITCH_ON_DISABLED and emulated.drive.fault is None


def test_abort_object_fault(drive_host):
    host, _, _ = drive_host(abort_object="0x607D:2")
    host.write(0x607D, 1, -100)  # another sub-index of the same object still works
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x607D, 2, 100)
    assert err.value.code == 0x06060000
    with pytest.raises(SdoAbortedError):
        host.read(0x607D, 2)


def test_socketcand_bridge_serves_the_bus(tmp_path):
    driver = find_driver("canopen-servo")
    emulated = start_socketcand(emulator_config(), driver, DeviceConfig(driver="canopen-servo", canopen=BUS))
    try:
        assert emulated.device.canopen.can_interface == "socketcand"
        host_port, _, channel = emulated.device.port.partition("/")
        host, port = host_port.split(":")
        assert host == "127.0.0.1" and channel == "can0"
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.05
        network.connect(interface="socketcand", host=host, port=int(port), channel=channel)
        try:
            node = network.add_node(NODE, str(driver.folder / "canopen-servo.eds"))
            assert node.sdo[0x1008].raw == "hilident CiA 402 servo"
            table = np.arange(700, dtype="<f4").tobytes()
            with node.sdo.open(0x2200, 0, "wb", size=len(table), block_transfer=True, buffering=0) as f:
                pos = 0
                while pos < len(table):
                    pos += f.write(table[pos : pos + 7])
            assert node.sdo[0x2201][1].raw == 700
        finally:
            network.disconnect()
        with pytest.raises(can.CanError):  # a bus the server does not have
            can.Bus(interface="socketcand", host=host, port=int(port), channel="can9")
    finally:
        emulated.close()


def _beat(host, node, period_s):
    """A heartbeat producer for ``node`` on the host's bus (what a master sends)."""
    return host.network.send_periodic(0x700 + node, b"\x05", period_s)


@pytest.mark.parametrize(
    "option, after",
    [
        (0, cia402.State.OPERATION_ENABLED),
        (1, cia402.State.FAULT),
        (2, cia402.State.SWITCH_ON_DISABLED),
        (3, cia402.State.SWITCH_ON_DISABLED),
    ],
)
def test_heartbeat_consumer_fires_emcy_8130_and_the_abort_option(drive_host, option, after):
    host, emulated, _ = drive_host()
    host.limits()
    host.write(0x1016, 1, (100 << 16) | 150)  # watch node 100, 150 ms
    host.write(0x6007, 0, option)
    assert host.read(0x1016, 1) == (100 << 16) | 150 and host.read(0x6007) == option
    host.enable()
    time.sleep(0.4)  # no heartbeat yet: monitoring has not started (CiA 301)
    assert host.state() is cia402.State.OPERATION_ENABLED and host.emcy == []
    beat = _beat(host, 100, 0.03)
    time.sleep(0.3)
    assert host.state() is cia402.State.OPERATION_ENABLED  # heard in time
    beat.stop()
    stopped = time.monotonic()
    deadline = stopped + 1.0
    while not host.emcy and time.monotonic() < deadline:
        time.sleep(0.002)
    took = time.monotonic() - stopped
    assert 0.15 - 0.03 - 0.01 <= took <= 0.15 + 0.1
    assert [e.code for e in host.emcy] == [0x8130]
    assert host.state() is after
    assert emulated.drive.enabled == (option == 0)


def test_heartbeat_consumer_entries_follow_cia301(drive_host):
    host, emulated, _ = drive_host()
    host.write(0x1016, 1, (100 << 16) | 150)
    with pytest.raises(SdoAbortedError) as err:
        host.write(0x1016, 2, (100 << 16) | 300)  # one producer, one entry
    assert err.value.code == 0x06040043
    host.write(0x1016, 2, (101 << 16) | 300)
    host.write(0x1016, 1, 0)  # off
    beat = _beat(host, 100, 0.03)
    time.sleep(0.3)
    beat.stop()
    time.sleep(0.3)
    assert host.emcy == []  # node 100 is no longer watched
    for bad in (4, -1):
        with pytest.raises(SdoAbortedError):
            host.write(0x6007, 0, bad)


def test_socketcand_frames_flow_only_after_the_rawmode_ok():
    # python-can's client reads exactly "< ok >" after "< open >" and "< rawmode >": a frame in between
    # (the drive's heartbeat is always on the bus) breaks its handshake
    import socket

    driver = find_driver("canopen-servo")
    emulated = start_socketcand(emulator_config(), driver, DeviceConfig(driver="canopen-servo", canopen=BUS))
    try:
        emulated.server.firmware.node.sdo[0x1017].raw = 5  # a heartbeat every 5 ms
        port = int(emulated.device.port.split(":")[1].split("/")[0])
        with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:

            def received(wait_s):
                """Everything that arrives within ``wait_s``."""
                deadline = time.monotonic() + wait_s
                data = b""
                while (left := deadline - time.monotonic()) > 0:
                    sock.settimeout(left)
                    try:
                        chunk = sock.recv(65536)
                    except TimeoutError:
                        break
                    if not chunk:
                        break
                    data += chunk
                return data

            assert received(0.1) == b"< hi >"
            sock.sendall(b"< open can0 >")
            assert received(0.2) == b"< ok >"
            sock.sendall(b"< rawmode >")
            data = received(0.5)
            assert data.startswith(b"< ok >< frame 703 ")
    finally:
        emulated.close()
