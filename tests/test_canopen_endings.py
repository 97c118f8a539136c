"""How a CANopen session ends and how the next one starts, against the emulated drive.

The device-side net (the drive's heartbeat consumer 0x1016 watching the host,
the abort connection option 0x6007), the known state at connect (latched
faults, a drive left switched on), a fast ``safe_stop``, live events, the first
cause winning, and a bus that vanishes mid-run.
"""

from __future__ import annotations

import os
import shutil
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from canopen.sdo import SdoCommunicationError

from hilident import endings
from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver, load_driver
from hilident.emulator.canopen.roles import EMCY_HEARTBEAT
from hilident.emulator.canopen.server import start, start_socketcand
from hilident.errors import ConfigError, DeviceError, Interrupted, LimitTrip
from hilident.protocol import cia402

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CONFIG = CONFIGS / "emulated-canopen-gantry.toml"
FS = 1000.0
HOST_TIMEOUT_S = 0.3
TOLERANCE_S = 0.25  # the twin checks every 4 ms; the rest is thread scheduling on a busy (CI) machine


class Twin:
    """An emulated drive (virtual bus, or socketcand) and the adapters opened on it."""

    def __init__(self, driver="canopen-servo", socketcand=False, time_scale=20.0, **faults):
        cfg = load_config(CONFIG)
        self.cfg = cfg
        emu = replace(cfg.emulator, time_scale=time_scale, faults=replace(cfg.emulator.faults, **faults))
        self.driver = driver if not isinstance(driver, str) else find_driver(driver)
        self.emulated = (start_socketcand if socketcand else start)(emu, self.driver, cfg.device)
        self.fw = self.emulated.server.firmware
        self.adapters: list[CanopenDriveAdapter] = []

    def open(self, acquisition="buffered", **device) -> CanopenDriveAdapter:
        dev = replace(
            self.emulated.device, acquisition=acquisition, timeout_s=0.5, host_timeout_s=HOST_TIMEOUT_S, **device
        )
        ad = CanopenDriveAdapter.open_device(dev, self.driver)
        self.adapters.append(ad)
        lim = self.cfg.limits
        ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        return ad

    def close(self):
        for ad in self.adapters:
            ad.close()
        self.emulated.close()


@pytest.fixture
def twin():
    made = []

    def make(*args, **kwargs):
        t = Twin(*args, **kwargs)
        made.append(t)
        return t

    yield make
    for t in made:
        t.close()


def die_hard(ad: CanopenDriveAdapter) -> None:
    """What SIGKILL does to the host: its heartbeat and every frame stop, nothing is sent on the way out."""
    ad.net.heartbeat.task.stop()
    ad.network.disconnect()
    ad.close = lambda: None  # the process is gone: no orderly close either


def wait_until(predicate, timeout_s: float) -> float:
    """Seconds until ``predicate()`` held; ``inf`` when it did not within ``timeout_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if predicate():
            return time.monotonic() - t0
        time.sleep(0.002)
    return float("inf")


def driver_copy(tmp_path, name="canopen-servo", toml=(), eds=None):
    """A copy of a shipped driver folder with text replacements in driver.toml (and a new EDS text)."""
    folder = tmp_path / name
    shutil.copytree(find_driver(name).folder, folder)
    text = (folder / "driver.toml").read_text()
    for old, new in toml:
        assert old in text
        text = text.replace(old, new)
    (folder / "driver.toml").write_text(text)
    if eds is not None:
        path = folder / f"{name}.eds"
        path.write_text(eds(path.read_text()))
    return load_driver(folder)


def without_consumer(eds: str) -> str:
    """The EDS with the heartbeat consumer object (0x1016) taken out."""
    start = eds.index("[1016]")
    return eds[:start] + eds[eds.index("[1017]") :].replace("=0x1016\n", "=0x1000\n")


# --- the device-side net ----------------------------------------------------------------------------


def test_the_drive_watches_the_host_heartbeat_once_connected(twin):
    t = twin()
    ad = t.open()
    assert ad.connect_report.device_net == (
        "heartbeat consumer 0x1016:1: host node 127, 300 ms (host heartbeat every 100 ms); 0x6007 = 2 (disable voltage)"
    )
    assert t.fw.consumers == {1: (127, 300)}
    assert wait_until(lambda: 127 in t.fw.heard, 1.0) < 1.0  # the host's heartbeat reaches the drive
    time.sleep(3 * HOST_TIMEOUT_S)  # a host alive: no heartbeat event
    assert t.fw.heartbeat_events == 0


@pytest.mark.parametrize("acquisition", ["buffered", "streamed"])
def test_a_host_that_dies_hard_leaves_the_drive_switched_off_within_the_consumer_time(twin, acquisition):
    t = twin()
    ad = t.open(acquisition)
    ad.configure(FS, "torque")
    ad.enable()
    assert t.fw.state is cia402.State.OPERATION_ENABLED and t.emulated.drive.enabled
    time.sleep(0.1)
    die_hard(ad)
    took = wait_until(lambda: not t.emulated.drive.enabled, HOST_TIMEOUT_S + 1.0)
    assert took <= HOST_TIMEOUT_S + TOLERANCE_S
    # a real timeout: not before the consumer time after the last heartbeat the drive heard
    assert t.fw.heartbeat_event_wall - t.fw.heard[127] >= HOST_TIMEOUT_S
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED  # 0x6007 = 2: Disable Voltage
    assert t.fw.heartbeat_events == 1 and t.fw.error_history[0] == EMCY_HEARTBEAT
    # the next session starts cleanly and finds the drive off
    ad2 = t.open(acquisition)
    assert ad2.connect_report.faults == [] and ad2.drive_state() is cia402.State.SWITCH_ON_DISABLED


def test_a_host_whose_heartbeat_thread_starves_keeps_the_drive_while_it_talks_to_it(twin):
    # the cyclic sender waits for the interpreter; the thread polling the drive sends the heartbeat instead
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    ad.enable()
    ad.net.heartbeat.task.stop()
    end = time.monotonic() + 3 * HOST_TIMEOUT_S
    while time.monotonic() < end:
        ad.drive_state()
        time.sleep(0.02)
    assert t.fw.heartbeat_events == 0 and t.fw.state is cia402.State.OPERATION_ENABLED
    assert wait_until(lambda: not t.emulated.drive.enabled, HOST_TIMEOUT_S + 1.0) <= HOST_TIMEOUT_S + TOLERANCE_S


def test_abort_option_fault_latches_and_the_next_session_needs_the_reset(twin, tmp_path):
    driver = driver_copy(tmp_path, toml=[("abort_connection_option = 2", "abort_connection_option = 1")])
    t = twin(driver)
    ad = t.open()
    assert "0x6007 = 1 (fault)" in ad.connect_report.device_net
    ad.configure(FS, "torque")
    ad.enable()
    die_hard(ad)
    assert wait_until(lambda: t.fw.state is cia402.State.FAULT, HOST_TIMEOUT_S + 1.0) <= HOST_TIMEOUT_S + TOLERANCE_S
    assert not t.emulated.drive.enabled
    with pytest.raises(
        DeviceError,
        match=r"latched fault: Fault, error code 0x8130: life guard or heartbeat error"
        r".*allow_fault_reset = true or hilident run --clear-fault",
    ):
        t.open()
    ad3 = t.open(allow_fault_reset=True)
    assert ad3.connect_report.faults == ["Fault, error code 0x8130: life guard or heartbeat error"]
    assert ad3.connect_report.faults_cleared and t.fw.state is cia402.State.SWITCH_ON_DISABLED


def test_a_clean_close_disarms_the_consumer(twin):
    t = twin()
    ad = t.open()
    ad.close()
    assert t.fw.consumers == {}
    time.sleep(2 * HOST_TIMEOUT_S)
    assert t.fw.heartbeat_events == 0  # no EMCY 0x8130 for a host that said goodbye


def test_a_drive_without_a_heartbeat_consumer_gets_no_net_and_says_so(twin, tmp_path):
    t = twin(driver_copy(tmp_path, eds=without_consumer))
    ad = t.open()
    assert ad.connect_report.device_net.startswith("none: canopen-servo.eds has no heartbeat consumer (0x1016)")
    assert ad.net.heartbeat.task is None and t.fw.consumers == {}


def test_the_host_node_id_must_differ_from_the_drive(twin, tmp_path):
    t = twin(driver_copy(tmp_path, toml=[("host_node_id = 127", "host_node_id = 1")]))
    with pytest.raises(ConfigError, match=r"canopen\.host_node_id.*also the drive's node id"):
        t.open()


def test_a_consumer_entry_watching_another_node_is_left_alone(twin):
    t = twin()
    t.fw.node.sdo[0x1016][1].raw = (5 << 16) | 1000  # another master's entry, set on the drive's side
    t.fw.consumers[1] = (5, 1000)
    ad = t.open()
    assert ad.connect_report.device_net.startswith("heartbeat consumer 0x1016:2: host node 127")
    assert t.fw.consumers == {1: (5, 1000), 2: (127, 300)}


# --- known state at connect ---------------------------------------------------------------------------


def test_a_drive_found_in_fault_is_refused_then_reset_only_when_allowed(twin):
    t = twin()
    with t.fw.lock:
        t.fw.fault(0x4310, 0)  # a fault latched before this session
    with pytest.raises(DeviceError, match=r"node 1: the device has a latched fault: Fault, error code 0x4310"):
        t.open()
    assert t.fw.state is cia402.State.FAULT  # refused: nothing was reset
    ad = t.open(allow_fault_reset=True)
    assert ad.connect_report.faults_cleared and "0x4310" in ad.connect_report.faults[0]
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and t.fw.error_code == 0


def test_a_drive_left_enabled_by_a_killed_session_is_switched_off_at_connect(twin):
    t = twin()
    first = t.open()
    first.configure(FS, "torque")
    first.enable()
    first.net.heartbeat.task.stop()  # killed, but the consumer has not noticed yet: the next host is quicker
    first.network.disconnect()
    first.close = lambda: None
    second = t.open()
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled
    assert t.fw.node.nmt.state == "PRE-OPERATIONAL"
    assert second.connect_report.faults == []


def test_pdos_and_emergencies_from_before_the_configuration_are_counted_and_dropped(twin):
    # a drive left Operational by another master keeps sending its TPDOs on that master's SYNCs, and an
    # old emergency is repeated; here a second bus member plays that part while the host connects
    import can

    t = twin()
    other = can.Bus(interface="virtual", channel=t.emulated.device.port, receive_own_messages=False)
    stale = [
        can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False),
        can.Message(arbitration_id=0x81, data=bytes.fromhex("1183110000000000"), is_extended_id=False),
    ]
    try:
        tasks = [other.send_periodic(msg, 0.002) for msg in stale]
        ad = t.open()
        for task in tasks:
            task.stop()
    finally:
        other.shutdown()
    # at least one stale frame arrived while the host connected (a loaded machine may starve the 2 ms sender),
    # and none of them, the old emergency included, became a fault of this session
    assert ad.connect_report.discarded_frames >= 1 and ad.connect_report.faults == []
    ad.configure(FS, "torque")
    result = ad.stream(np.zeros(500), lambda i, rows: None)
    assert result.completed and result.events[-1]["kind"] == "capture_end"


# --- safe_stop, events, first cause ---------------------------------------------------------------------


def test_safe_stop_reaches_switch_on_disabled_fast_and_keeps_the_link(twin):
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    times = []
    for _ in range(5):
        ad.enable()
        t0 = time.perf_counter()
        ad.safe_stop()
        times.append(time.perf_counter() - t0)
        assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled
    assert np.median(times) < 0.1
    time.sleep(2 * HOST_TIMEOUT_S)
    assert t.fw.heartbeat_events == 0  # the host's heartbeat goes on after safe_stop
    ad.net.check_link()


def test_safe_stop_never_raises_when_the_drive_is_gone(twin):
    t = twin()
    ad = t.open()
    t.emulated.close()
    t0 = time.perf_counter()
    ad.safe_stop()
    assert time.perf_counter() - t0 < 0.5 + 0.2  # one SDO timeout, no more
    assert not ad.answered
    t0 = time.perf_counter()
    ad.close()
    assert time.perf_counter() - t0 < 0.5 + 0.2  # one more Disable Voltage, then no other request waits


def test_events_reach_the_adapter_while_the_run_goes_on(twin):
    t = twin(drop_pdo_rate=0.02)
    ad = t.open("streamed")
    ad.configure(4 * FS, "torque")  # the drive's fastest cycle: a second of it is enough
    seen = []
    result = ad.stream(np.zeros(4000), lambda i, rows: seen.append(len(ad.events)))
    lost = [e for e in result.events if e["kind"] == "lost_blocks"]
    assert len(lost) >= 5 and result.stats.lost_blocks > 0
    assert 0 < seen[len(seen) // 2] < len(lost)  # half way through, some of them were already there
    assert result.events == ad.events and result.events is not ad.events

    def refused():
        raise DeviceError("refused")

    ad.enable = refused
    with pytest.raises(DeviceError, match="refused"):
        ad.stream(np.zeros(100), lambda i, rows: None)
    assert ad.events == [] and len(result.events) == len(lost) + sum(e["kind"] != "lost_blocks" for e in result.events)


def test_a_limit_trip_stays_the_cause_whatever_fails_after_it(twin):
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    read = ad.sdo.read

    def read_failing_after_the_trip(role):
        if ad.net.emergencies and role in ("table_state", "capture_count"):
            raise DeviceError(f"{ad.port}: SDO abort reading {role}: 0x08000022 (state)")
        return read(role)

    ad.sdo.read = read_failing_after_the_trip
    x = np.full(3000, 60.0)  # far beyond the 19 N·m torque limit
    with pytest.raises(LimitTrip, match="torque_limit"):
        ad.stream(x, lambda i, rows: None)
    assert ad.run_fault["kind"] == "limit_trip" and ad.last_result.fault == ad.run_fault["message"]
    assert not t.emulated.drive.enabled


def test_an_exception_from_the_sink_propagates_after_the_drive_is_off(twin):
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")

    def full_disk(i, rows):
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        ad.stream(np.zeros(3000), full_disk)
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled


@pytest.mark.parametrize("acquisition", ["buffered", "streamed"])
def test_the_socketcand_server_vanishing_mid_run_is_a_device_error(twin, acquisition):
    t = twin(socketcand=True, time_scale=1.0)
    ad = t.open(acquisition)
    ad.configure(FS, "torque")
    bridge = t.emulated.server.extra[0]
    calls = []

    def sink(i, rows):
        calls.append(len(i))
        if len(calls) == 2:
            bridge.close()

    with pytest.raises(DeviceError, match=r"socketcand:127\.0\.0\.1:\d+/can0 node 1: ") as info:
        ad.stream(np.zeros(6000), sink)
    assert type(info.value) is DeviceError
    # the drive that lost its host stops on its own
    assert wait_until(lambda: not t.emulated.drive.enabled, HOST_TIMEOUT_S + 1.0) <= HOST_TIMEOUT_S + TOLERANCE_S


@pytest.mark.parametrize("direction", ["wb", "rb"])
def test_a_signal_in_the_middle_of_a_block_transfer_still_stops_the_drive(twin, direction, caplog):
    # Ctrl-C lands while a table goes down or a capture comes up: the interrupted block transfer is
    # aborted, so the drive's SDO server takes the Disable Voltage that follows, and the next run works
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    real_open = ad.node.sdo.open

    def open_interrupted(index, subindex=0, mode="rb", **options):
        stream = real_open(index, subindex, mode, **options)
        if mode == direction:
            name = "write" if mode == "wb" else "read"
            real = getattr(stream, name)
            calls = []

            def interrupted(*args):
                calls.append(1)
                if len(calls) == 20:
                    raise KeyboardInterrupt
                return real(*args)

            setattr(stream, name, interrupted)
        return stream

    ad.node.sdo.open = open_interrupted
    with pytest.raises(KeyboardInterrupt), caplog.at_level("INFO", logger="canopen"):
        ad.stream(np.zeros(3000), lambda i, rows: None)
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled
    assert not [r for r in caplog.records if r.levelname in ("WARNING", "ERROR")]  # the interruption says it all
    ad.node.sdo.open = real_open
    result = ad.stream(np.zeros(1000), lambda i, rows: None)
    assert result.completed and result.stats.samples == 1000


@pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(), reason="signal handlers need the main thread"
)
@pytest.mark.parametrize("direction", ["wb", "rb"])
def test_a_signal_during_a_segment_is_raised_between_segments(twin, direction):
    # canopen's SDO client holds its response queue's lock while a segment is exchanged; a signal's exception
    # landing there left the lock taken, and the stop's Disable Voltage waited on it for good (a CI run hung)
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    real_open = ad.node.sdo.open
    steps = []

    def open_signalled(index, subindex=0, mode="rb", **options):
        stream = real_open(index, subindex, mode, **options)
        if mode == direction and options.get("block_transfer"):  # the table or the capture, not the stop's write
            name = "write" if mode == "wb" else "read"
            real = getattr(stream, name)

            def segment(*args):
                steps.append("segment")
                if len(steps) == 20:
                    os.kill(os.getpid(), signal.SIGINT)
                    steps.append("segment ended")  # what the library does after the signal, under its lock
                return real(*args)

            setattr(stream, name, segment)
        return stream

    ad.node.sdo.open = open_signalled
    with endings.signals_end_the_session(), pytest.raises(Interrupted):
        ad.stream(np.zeros(3000), lambda i, rows: None)
    assert steps[19:21] == ["segment", "segment ended"] and len(steps) == 21  # raised after it, before the next
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled
    assert not ad.node.sdo.responses.mutex.locked()
    ad.node.sdo.open = real_open
    result = ad.stream(np.zeros(1000), lambda i, rows: None)
    assert result.completed and result.stats.samples == 1000


def test_a_drive_silent_at_the_end_of_a_capture_upload_is_a_device_error(twin):
    # the drive answers every segment of the capture, then not the end of the transfer (it vanished):
    # canopen 2.4.1 turns that timeout into an AttributeError of its own; the host names the object
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    real_open = ad.node.sdo.open
    real_read_response = ad.node.sdo.read_response
    last_segment_seen = []

    def silent_after_last_segment():
        if last_segment_seen:
            ad.node.sdo.read_response = real_read_response  # silent once: the end-of-upload answer
            raise SdoCommunicationError("No SDO response received")
        response = real_read_response()
        if response[0] & 0x80:  # a block upload segment with the "no more segments" bit
            last_segment_seen.append(1)
        return response

    def open_going_silent(index, subindex=0, mode="rb", **options):
        stream = real_open(index, subindex, mode, **options)
        if mode == "rb" and options.get("block_transfer"):  # the capture upload
            ad.node.sdo.read_response = silent_after_last_segment
        return stream

    ad.node.sdo.open = open_going_silent
    with pytest.raises(DeviceError, match=r"no valid SDO answer reading 0x2203:0 \(Capture data\)") as info:
        ad.stream(np.zeros(1000), lambda i, rows: None)
    assert type(info.value) is DeviceError and last_segment_seen
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED and not t.emulated.drive.enabled


def test_safe_stop_from_a_handler_that_interrupted_a_table_download(twin):
    # a signal handler that calls safe_stop() at once runs in the middle of whatever the main thread did
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    ad.enable()
    real_open = ad.node.sdo.open
    states = []

    def open_with_handler(index, subindex=0, mode="rb", **options):
        stream = real_open(index, subindex, mode, **options)
        real_write = stream.write
        calls = []

        def write(b):
            calls.append(1)
            if len(calls) == 20:  # the "handler": stop now, then end the run
                ad.safe_stop()
                states.append(t.fw.state)
                raise KeyboardInterrupt
            return real_write(b)

        stream.write = write
        return stream

    ad.node.sdo.open = open_with_handler
    with pytest.raises(KeyboardInterrupt):
        ad.sdo.write_domain(ad.desc.address("table"), np.zeros(3000, "<f4").tobytes())
    assert states == [cia402.State.SWITCH_ON_DISABLED]
    ad.node.sdo.open = real_open
    ad.enable()
    ad.safe_stop()
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED


def test_safe_stop_takes_a_stale_sdo_answer_for_what_it_is_and_writes_again(twin):
    # the answer of a transfer the host gave up on arrives after safe_stop's request went out: canopen reads it as
    # the answer to the controlword write ("Unexpected response"); the drive must still end up without power
    t = twin()
    ad = t.open()
    ad.configure(FS, "torque")
    t.fw.state = cia402.State.OPERATION_ENABLED
    real_read_response = ad.node.sdo.read_response
    stale = []

    def stale_answer_first():
        if not stale:
            stale.append(real_read_response())  # the write's own answer, consumed
            return bytes([0xC1, 0, 0, 0, 0, 0, 0, 0])  # ... and in its place a block upload's end
        return real_read_response()

    ad.node.sdo.read_response = stale_answer_first
    ad.safe_stop()
    ad.node.sdo.read_response = real_read_response
    assert stale and ad.answered
    assert t.fw.state is cia402.State.SWITCH_ON_DISABLED
