"""Every way a serial session ends, and the next session after it.

A killed host (its line closed without STOP), a board left in FAULT, a line
that reorders frames, a board that refuses frames already in flight when it
ended the run, a sink that fails (a full disk), a line that vanishes, an
interrupted frame: the axis stops, the first cause wins, and the next host
connects and runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cobs import cobs
from scipy.signal import iirnotch
from test_serial_adapter import (
    CHANNELS,
    DRIVER,
    RATE_HZ,
    OneFrameReads,
    Recorder,
    assert_clean,
    excitation,
    make_config,
    pipe_board,
    wait_until,
)

from hilident.adapters.serial.board import WATCHDOG_NET, SerialBoardAdapter
from hilident.config.tables import DeviceConfig
from hilident.emulator.serial.server import start_serial_board
from hilident.errors import DeviceError, LimitTrip
from hilident.filters.biquad import Biquad
from hilident.links import pipe_pair
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame

REPO = Path(__file__).resolve().parents[2]


def device_config(port: str, allow_fault_reset: bool = False, timeout_s: float = 2.0) -> DeviceConfig:
    return dataclasses.replace(DeviceConfig(), port=port, allow_fault_reset=allow_fault_reset, timeout_s=timeout_s)


@contextlib.contextmanager
def pty_board(time_scale: float = 10.0):
    device = start_serial_board(make_config(time_scale).emulator, DRIVER, baudrate=DRIVER.default_baudrate, link="pty")
    try:
        yield device
    finally:
        device.close()


def abandon_a_run(port: str, firmware) -> None:
    """What a host killed mid-run leaves: a running board, and its line closed without STOP."""
    host = SerialBoardAdapter.open(port, DRIVER)
    host.set_limits(5.0, 1.0, -1.0, 1.0)
    host.configure(RATE_HZ, "torque_injection", CHANNELS)
    host._send(sb.Excitation(0, np.zeros(2000)))
    host._request(sb.Start(0))
    assert wait_until(lambda: firmware.sample_blocks_out >= 5)
    host.link.close()  # as the operating system does for a SIGKILLed process: no STOP
    assert firmware.running


def run_ok(adapter: SerialBoardAdapter, n: int = 1500) -> None:
    adapter.set_limits(5.0, 1.0, -1.0, 1.0)
    adapter.configure(RATE_HZ, "torque", CHANNELS)
    rec = Recorder()
    result = adapter.stream(excitation(n), rec)
    assert result.completed
    assert_clean(result.stats, n)
    np.testing.assert_array_equal(rec.index, np.arange(n))


# --- restart after a killed session ------------------------------------------------------------


def test_the_next_host_drains_a_killed_hosts_run_stops_it_and_runs():
    with pty_board() as device:
        fw = device.server.firmware
        abandon_a_run(device.port, fw)
        with SerialBoardAdapter.open_device(device_config(device.port), DRIVER) as adapter:
            report = adapter.connect_report
            assert report.discarded_frames > 0  # the old run's blocks: counted, never decoded as ours
            assert adapter.found_state == "RUNNING"
            assert report.faults == [] and not report.faults_cleared
            assert report.device_net == WATCHDOG_NET
            # stopped by the new host's STOP, long before the board's own watchdog
            assert fw.state == sb.State.CONFIGURED and not device.drive.enabled
            assert fw.status().limit_trips == 0
            run_ok(adapter)


def test_a_board_left_in_fault_is_refused_unless_clearing_is_allowed():
    with pty_board() as device:
        fw = device.server.firmware
        abandon_a_run(device.port, fw)
        assert wait_until(lambda: fw.state == sb.State.FAULT, 3.0)  # the board's watchdog stopped the axis
        assert not device.drive.enabled

        with pytest.raises(DeviceError) as info:
            SerialBoardAdapter.open_device(device_config(device.port), DRIVER)
        message = str(info.value)
        assert device.port in message and "WATCHDOG" in message and "allow_fault_reset = true" in message
        assert (fw.state, fw.fault) == (sb.State.FAULT, sb.FaultCode.WATCHDOG)  # not cleared behind the user's back

        with SerialBoardAdapter.open_device(device_config(device.port, allow_fault_reset=True), DRIVER) as adapter:
            report = adapter.connect_report
            assert adapter.found_state == "FAULT"
            assert len(report.faults) == 1 and "WATCHDOG" in report.faults[0]
            assert report.faults_cleared
            assert fw.state == sb.State.CONFIGURED and fw.fault == sb.FaultCode.NONE
            run_ok(adapter)


class IndependentBoard:
    """A board written from PROTOCOL.md alone, latched in FAULT and still streaming an old run's blocks.

    It knows nothing of the emulator: it answers IDENTIFY, STATUS_REQUEST,
    STOP and CLEAR_FAULT as sections 4 and 5 say, and records what it was sent.
    """

    OLD_CHANNELS = tuple(sb.ChannelSelection(i) for i in range(6))

    def __init__(self, link, stale_blocks: int = 7, stale_spacing_s: float = 0.0):
        self.link = link
        self.stale_spacing_s = stale_spacing_s
        self.received: list[str] = []
        self.state, self.fault = sb.State.FAULT, sb.FaultCode.WATCHDOG
        self.stale_blocks = stale_blocks
        self._seq = 100
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def send(self, msg) -> None:
        self._seq += 1
        self.link.write(encode_frame(sb.encode(msg, self._seq, sample_channels=self.OLD_CHANNELS)))

    def _serve(self) -> None:
        decoder = FrameDecoder()
        ident = sb.Identity(
            1,
            DRIVER.name,
            "independent 0.1",
            4000.0,
            4000.0,
            4,
            4096,
            tuple(sb.ChannelInfo(c.name, c.unit) for c in DRIVER.channels),
        )
        try:
            while True:
                for payload in decoder.feed(self.link.read(max(1, self.link.in_waiting))):
                    header, msg = sb.decode(payload)
                    self.received.append(sb.MsgType(header.type).name)
                    if isinstance(msg, sb.Identify):
                        for k in range(self.stale_blocks):  # the old run's blocks, still on their way
                            self.send(sb.Samples(k, 40 * k, 0, 0, 0, 0, np.zeros((40, 6))))
                            time.sleep(self.stale_spacing_s)
                        self.send(ident)
                    elif isinstance(msg, sb.StatusRequest):
                        self.send(sb.Status(self.state, self.fault, 0, 4096, 0, 0, 0, 0, 0))
                    elif isinstance(msg, sb.Stop):
                        self.send(sb.Ack(header.seq, header.type))
                    elif isinstance(msg, sb.ClearFault):
                        self.state, self.fault = sb.State.IDLE, sb.FaultCode.NONE
                        self.send(sb.Ack(header.seq, header.type))
        except OSError:  # the host closed the line
            pass

    def start(self) -> IndependentBoard:
        self._thread.start()
        return self


def test_connecting_uses_only_protocol_messages_and_stops_before_clearing():
    host_end, board_end = pipe_pair("pipe://independent", timeout=0.02)
    board = IndependentBoard(board_end).start()
    adapter = SerialBoardAdapter.open_device(
        device_config("pipe://independent", allow_fault_reset=True), DRIVER, link=host_end
    )
    try:
        report = adapter.connect_report
        assert report.discarded_frames == board.stale_blocks
        assert report.faults_cleared and "WATCHDOG" in report.faults[0]
        # STOP goes out before anything is cleared; the fault is cleared only after it was read
        assert board.received == [
            "IDENTIFY",
            "STATUS_REQUEST",
            "STOP",
            "STATUS_REQUEST",
            "CLEAR_FAULT",
            "STATUS_REQUEST",
        ]
        assert board.state == sb.State.IDLE
    finally:
        adapter.close()
    assert wait_until(lambda: board.received[-1] == "STOP", 1.0)  # and on closing


def test_an_answer_queued_behind_a_long_drain_is_waited_for():
    # a slow line still carrying the old run's blocks for longer than the answer timeout
    host_end, board_end = pipe_pair("pipe://independent", timeout=0.02)
    _board = IndependentBoard(board_end, stale_blocks=20, stale_spacing_s=0.03).start()
    adapter = SerialBoardAdapter.open_device(
        device_config("pipe://independent", allow_fault_reset=True, timeout_s=0.25), DRIVER, link=host_end
    )
    try:
        assert adapter.connect_report.discarded_frames == 20
        assert adapter.identity.firmware == "independent 0.1"
    finally:
        adapter.close()


def test_without_permission_the_independent_board_is_refused_and_the_line_closed():
    host_end, board_end = pipe_pair("pipe://independent", timeout=0.02)
    board = IndependentBoard(board_end).start()
    with pytest.raises(
        DeviceError, match="pipe://independent: the device has a latched fault: board in FAULT WATCHDOG"
    ):
        SerialBoardAdapter.open_device(device_config("pipe://independent"), DRIVER, link=host_end)
    assert "CLEAR_FAULT" not in board.received and board.state == sb.State.FAULT
    assert not host_end.is_open


# --- filter slots --------------------------------------------------------------------------------


def test_disable_filter_bypasses_a_slot_and_keeps_its_coefficients():
    with pipe_board(make_config()) as (device, adapter):
        b, a = iirnotch(40.0, 5.0, fs=DRIVER.loop_rate_hz)
        notch = Biquad(tuple(b), tuple(a))
        adapter.write_filter(1, notch, enabled=True)
        saved = adapter.save_filter(1)
        adapter.disable_filter(1)
        stored, enabled = adapter.read_filter(1)
        assert not enabled and not device.drive.filters.read(1)[1]
        assert stored == adapter.stored_form(notch)  # the contents stay
        adapter.restore_filter(1, saved)
        assert adapter.read_filter(1) == (adapter.stored_form(notch), True)


# --- reordered frames ----------------------------------------------------------------------------


class RoutedFrames(OneFrameReads):
    """A line that passes every whole frame the board sends through ``_route`` (to hold, reorder or add frames)."""

    def __init__(self, link):
        super().__init__(link)
        self._frames = bytearray()

    def _route_arrived_frames(self) -> None:
        self._frames += self.link.read(max(1, self.link.in_waiting))
        while 0 in self._frames:
            end = self._frames.index(0) + 1
            frame = bytes(self._frames[:end])
            del self._frames[:end]
            self._buffer += self._route(frame)

    def _route(self, frame: bytes) -> bytes:
        return frame


class SwapOneBlockPair(RoutedFrames):
    """A line that delivers one sample block after the block that follows it."""

    def __init__(self, link, block_index: int = 6):
        super().__init__(link)
        self.block_index = block_index
        self.held: bytes | None = None
        self.swapped: tuple[int, int] | None = None  # first_sample, rows of the late block

    def read(self, size: int = 1) -> bytes:
        self._route_arrived_frames()
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def _route(self, frame: bytes) -> bytes:
        payload = cobs.decode(frame[:-1])[:-4]
        if payload[1] != sb.MsgType.SAMPLES:
            return frame
        block, first, rows = np.frombuffer(payload[4:14], dtype="<u4,<u4,<u2")[0]
        if block == self.block_index and self.held is None:
            self.held, self.swapped = frame, (int(first), int(rows))
            return b""
        if self.held is not None and block == self.block_index + 1:
            late, self.held = self.held, b""
            return frame + late
        return frame


def test_a_reordered_block_is_out_of_order_not_lost_and_never_spliced_in():
    with pipe_board(make_config(), link=SwapOneBlockPair) as (device, adapter):
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        n = 2000
        rec = Recorder()
        result = adapter.stream(excitation(n), rec)
        stats = result.stats
        first, rows = adapter.link.swapped
        assert rows > 0
        assert (stats.out_of_order, stats.lost_blocks, stats.lost_samples, stats.lost_frames) == (1, 0, 0, 0)
        # discarded: its samples are missing from the recording, the rest is in order and unshifted
        expected = np.setdiff1d(np.arange(n), np.arange(first, first + rows))
        np.testing.assert_array_equal(rec.index, expected)
        assert stats.samples == n - rows
        (late,) = [e for e in result.events if e["kind"] == "out_of_order"]
        assert late["sample_index"] == first and "missing from the recording" in late["message"]


# --- the first cause wins -----------------------------------------------------------------------


class InjectNak(RoutedFrames):
    """A line on which the board's refusal of an in-flight EXCITATION appears next to ``trigger``.

    ``trigger(msg)`` picks the board frame the NAK travels with; ``before``
    puts the NAK ahead of it (a board that answers the frame before it
    announces why it left the run), else behind it.
    """

    def __init__(self, link, trigger=None, before: bool = False, error=sb.ErrorCode.BAD_STATE):
        super().__init__(link)
        self.trigger = trigger or (lambda msg: False)
        self.before = before
        self.error = error
        self.injected = False
        self.channels: tuple = ()  # the host's channel selection, to read the blocks

    def read(self, size: int = 1) -> bytes:
        self._route_arrived_frames()
        data = bytes(self._buffer)  # the NAK arrives in the same read as the frame it travels with
        self._buffer.clear()
        return data

    def _route(self, frame: bytes) -> bytes:
        payload = cobs.decode(frame[:-1])[:-4]
        if self.injected or payload[1] not in (sb.MsgType.EVENT, sb.MsgType.SAMPLES):
            return frame
        header, msg = sb.decode(payload, sample_channels=self.channels)
        if not self.trigger(msg):
            return frame
        self.injected = True
        # same seq as the frame it travels with: the host's frame numbering sees no gap
        nak = encode_frame(
            sb.encode(sb.Nak(0, sb.MsgType.EXCITATION, self.error, "excitation while FAULT"), header.seq)
        )
        return nak + frame if self.before else frame + nak


def is_event(code):
    return lambda msg: isinstance(msg, sb.Event) and msg.code == code


@pytest.mark.parametrize("before", [False, True], ids=["nak-after-trip", "nak-before-trip"])
def test_a_limit_trip_stays_the_cause_when_an_in_flight_frame_is_refused(before):
    cfg = make_config(limits=(2.0, 1.0, -1.0, 1.0))
    with pipe_board(cfg) as (device, adapter):
        adapter.link = InjectNak(adapter.link, is_event(sb.EventCode.LIMIT_TRIP), before=before)
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        adapter.link.channels = adapter.channels
        x = np.concatenate([np.full(1500, 1.0), np.full(1500, 3.0)])
        with pytest.raises(LimitTrip, match="torque_limit"):
            adapter.stream(x, Recorder())
        assert adapter.link.injected
        kinds = [e["kind"] for e in adapter.last_result.events]
        assert "limit_trip" in kinds and "refused" in kinds


def test_a_refused_in_flight_frame_after_a_finished_run_is_no_error():
    with pipe_board(make_config()) as (device, adapter):
        # the refusal of a frame that reached the board after its run ended (its stream index reset)
        adapter.link = InjectNak(
            adapter.link,
            lambda m: isinstance(m, sb.Samples) and m.flags & sb.FLAG_LAST,
            error=sb.ErrorCode.BAD_ARGUMENT,
        )
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        adapter.link.channels = adapter.channels
        n = 1500
        result = adapter.stream(excitation(n), Recorder())
        assert adapter.link.injected and result.completed
        assert_clean(result.stats, n)


def test_a_refusal_while_the_board_runs_the_hosts_run_is_a_device_error():
    with pipe_board(make_config()) as (device, adapter):
        adapter.link = InjectNak(
            adapter.link, lambda m: isinstance(m, sb.Samples) and m.block_index >= 5, error=sb.ErrorCode.BUFFER_OVERFLOW
        )
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        adapter.link.channels = adapter.channels
        with pytest.raises(DeviceError, match=f"{device.port}: board refused a frame during the run: BUFFER_OVERFLOW"):
            adapter.stream(excitation(20_000), Recorder())
        assert adapter.last_result is not None and not adapter.last_result.completed
        assert wait_until(lambda: not device.drive.enabled)  # and the axis was stopped


# --- the host fails, the line fails ----------------------------------------------------------------


def test_a_failing_sink_propagates_after_the_axis_was_stopped():
    with pipe_board(make_config()) as (device, adapter):
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        fw = device.server.firmware
        seen = []

        def sink(index, rows):
            seen.append(len(rows))
            if sum(seen) >= 500:
                raise OSError(28, "No space left on device")

        with pytest.raises(OSError, match="No space left"):
            adapter.stream(np.zeros(20_000), sink)
        assert wait_until(lambda: not fw.running, 1.0)
        assert fw.state == sb.State.CONFIGURED and not device.drive.enabled  # stopped by STOP, not by a watchdog
        assert fw.fault == sb.FaultCode.NONE


def test_stop_after_an_interrupted_frame_still_reaches_the_board():
    with pipe_board(make_config()) as (device, adapter):
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        fw = device.server.firmware
        adapter._send(sb.Excitation(0, np.zeros(1000)))
        adapter._request(sb.Start(0))
        assert fw.running
        frame = encode_frame(sb.encode(sb.Excitation(1000, np.zeros(200)), 1))
        adapter.link.write(frame[: len(frame) // 2])  # a signal cut this write short
        corrupt_before = fw.status().rx_corrupt
        t0 = time.monotonic()
        adapter.safe_stop()
        assert wait_until(lambda: not fw.running, 0.5)
        assert time.monotonic() - t0 < 0.5  # long before the board's 1 s watchdog
        assert fw.fault == sb.FaultCode.NONE and not device.drive.enabled
        assert fw.status().rx_corrupt == corrupt_before + 1  # the cut frame, and only it


@pytest.mark.parametrize("tcp", [False, True], ids=["pty", "tcp"])
def test_a_board_process_that_dies_mid_run_is_a_device_error_naming_the_port(tcp):
    cmd = [
        sys.executable,
        "-m",
        "hilident.cli",
        "emulate",
        "serial",
        "--config",
        str(REPO / "configs" / "emulated-gantry.toml"),
        "--time-scale",
        "5",
        *(["--tcp"] if tcp else []),
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().strip()
        assert port, proc.stderr.read()
        adapter = SerialBoardAdapter.open_device(device_config(port, timeout_s=1.0), DRIVER)
        adapter.set_limits(19.0, 0.4, -0.6, 0.6)
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        killer = threading.Timer(0.5, proc.kill)
        killer.start()
        t0 = time.monotonic()
        rec = Recorder()
        with pytest.raises(DeviceError) as info:
            adapter.stream(np.zeros(120_000), rec)
        assert port in str(info.value)
        assert time.monotonic() - t0 < 3.0
        assert len(rec.index) > 0 and not adapter.last_result.completed
        adapter.close()  # closing a dead line never raises
    finally:
        proc.kill()
        proc.wait(timeout=5)


def test_filter_slots_outlive_a_session_so_the_next_host_must_not_assume_them_bypassed():
    with pty_board() as device:
        b, a = iirnotch(30.0, 4.0, fs=DRIVER.loop_rate_hz)
        notch = Biquad(tuple(b), tuple(a))
        with SerialBoardAdapter.open_device(device_config(device.port), DRIVER) as first:
            first.write_filter(2, notch, enabled=True)
        with SerialBoardAdapter.open_device(device_config(device.port), DRIVER) as second:
            assert second.read_filter(2) == (second.stored_form(notch), True)
            second.disable_filter(2)  # what a host does before it identifies the bare plant
        with SerialBoardAdapter.open_device(device_config(device.port), DRIVER) as third:
            assert third.read_filter(2) == (third.stored_form(notch), False)


class DropTripEvent(InjectNak):
    """A line that loses the board's LIMIT_TRIP event (the last block with FLAG_FAULT still arrives)."""

    def _route(self, frame: bytes) -> bytes:
        payload = cobs.decode(frame[:-1])[:-4]
        if payload[1] == sb.MsgType.EVENT and payload[4] == sb.EventCode.LIMIT_TRIP:
            self.injected = True
            return b""
        return frame


def test_a_limit_trip_whose_event_was_lost_is_still_a_limit_trip():
    cfg = make_config(limits=(2.0, 1.0, -1.0, 1.0))
    with pipe_board(cfg) as (device, adapter):
        adapter.link = DropTripEvent(adapter.link)
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        x = np.concatenate([np.full(1500, 1.0), np.full(1500, 3.0)])
        with pytest.raises(LimitTrip, match="FAULT TORQUE_LIMIT"):
            adapter.stream(x, Recorder())
        assert adapter.link.injected and not adapter.last_result.completed
        assert "limit_trip" not in [e["kind"] for e in adapter.last_result.events]


def test_a_sigkilled_session_is_stopped_by_the_board_watchdog_and_the_next_host_clears_it(tmp_path, tcp=False):
    """(tests/test_endings.py runs the same ending over the TCP line too.)"""
    config = (REPO / "configs" / "emulated-gantry.toml").read_text()
    emulator = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hilident.cli",
            "emulate",
            "serial",
            "--config",
            str(REPO / "configs" / "emulated-gantry.toml"),
            "--time-scale",
            "2",
            *(["--tcp"] if tcp else []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    host = None
    try:
        port = emulator.stdout.readline().strip()
        assert port, emulator.stderr.read()
        bench = tmp_path / "bench.toml"
        bench.write_text(
            config.replace('port = "emulator"', f'port = "{port}"')
            .replace("[friction_test]", "[friction_test]\nenabled = false")
            .replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")
        )
        out = tmp_path / "out"
        host = subprocess.Popen(
            [sys.executable, "-m", "hilident.cli", "run", str(bench), "--out", str(out), "-q", "--yes", "--no-plots"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        assert wait_until(lambda: (out / "identification.h5").exists(), 30.0)
        time.sleep(0.5)  # streaming now
        host.kill()
        host.wait(timeout=5)
        time.sleep(1.5)  # longer than the board's 1 s watchdog
        with pytest.raises(DeviceError, match="WATCHDOG"):
            SerialBoardAdapter.open_device(device_config(port), DRIVER)
        with SerialBoardAdapter.open_device(device_config(port, allow_fault_reset=True), DRIVER) as adapter:
            assert adapter.found_state == "FAULT" and adapter.connect_report.faults_cleared
            adapter.set_limits(19.0, 0.4, -0.6, 0.6)
            adapter.configure(RATE_HZ, "torque", CHANNELS)
            n = 1000
            result = adapter.stream(excitation(n, 0.5), Recorder())
            assert result.completed and result.stats.samples == n
    finally:
        for proc in (host, emulator):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(timeout=5)


def test_after_an_interrupted_run_the_axis_is_stopped_and_the_slots_can_be_restored():
    with pipe_board(make_config()) as (device, adapter):
        fw = device.server.firmware
        b, a = iirnotch(25.0, 3.0, fs=DRIVER.loop_rate_hz)
        notch = Biquad(tuple(b), tuple(a))
        adapter.write_filter(0, notch, enabled=True)
        saved = adapter.save_filter(0)
        adapter.disable_filter(0)  # bypassed for the identification run
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        received = []

        def sink(index, rows):
            received.append(len(rows))
            if sum(received) >= 300:
                raise KeyboardInterrupt  # Ctrl-C while the samples are handled

        with pytest.raises(KeyboardInterrupt):
            adapter.stream(np.zeros(20_000), sink)
        adapter.safe_stop()  # what the session does first on every ending
        assert wait_until(lambda: not fw.running, 0.5) and not device.drive.enabled
        # the ended run's last block, its STOPPED event and the ACKs are still on the line
        adapter.restore_filter(0, saved)
        assert adapter.read_filter(0) == (adapter.stored_form(notch), True)
        with pytest.raises(DeviceError, match=f"{device.port}: filter slot 9: BAD_ARGUMENT"):
            adapter.read_filter(9)
