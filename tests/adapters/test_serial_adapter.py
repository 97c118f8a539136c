"""Host adapter against an emulated board: in-memory pipe and a real pseudo-terminal."""

from __future__ import annotations

import contextlib
import os
import struct
import time

import numpy as np
import pytest
from cobs import cobs
from scipy.signal import iirnotch

from hilident.adapters.serial.board import SerialBoardAdapter, board_stored_form
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.serial.server import start_serial_board
from hilident.errors import DeviceError, LimitTrip
from hilident.filters.biquad import Biquad
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame

DRIVER = find_driver("myrio-board")
RATE_HZ = 1000.0
# Few channels keep every burst of sample blocks well inside the board's transmit
# buffer, so the board itself never has to drop a block in these tests.
CHANNELS = ["excitation", "torque_nm"]


class OneFrameReads:
    """A byte link whose reads stop after the first frame delimiter.

    The slowest way a line can deliver frames: the adapter sees one frame per
    read. ``test_blocks_arriving_with_the_start_ack_are_kept`` covers the other
    extreme, several frames (an answer and sample blocks) in one read.
    """

    def __init__(self, link):
        self.link = link
        self._buffer = bytearray()

    @property
    def is_open(self) -> bool:
        return getattr(self.link, "is_open", True)

    @property
    def in_waiting(self) -> int:
        return len(self._buffer) + self.link.in_waiting

    def read(self, size: int = 1) -> bytes:
        if 0 not in self._buffer:
            self._buffer += self.link.read(max(1, self.link.in_waiting))
        end = self._buffer.find(0)
        n = min(size, len(self._buffer) if end < 0 else end + 1)
        data = bytes(self._buffer[:n])
        del self._buffer[:n]
        return data

    def write(self, data: bytes) -> int:
        return self.link.write(data)

    def reset_input_buffer(self) -> None:
        self._buffer.clear()
        self.link.reset_input_buffer()

    def close(self) -> None:
        self.link.close()


def make_config(time_scale: float = 10.0, faults: str = "", limits=(5.0, 1.0, -1.0, 1.0)):
    torque, velocity, lo, hi = limits
    return parse_config(f"""
[limits]
torque_nm = {torque}
velocity_mps = {velocity}
position_min_m = {lo}
position_max_m = {hi}

[emulator]
preset = "clean"
time_scale = {time_scale}
seed = 7

[emulator.sensors]
torque_noise_nm = 0.0

[emulator.faults]
{faults}
""")


@contextlib.contextmanager
def pipe_board(cfg, spy=None, link=OneFrameReads):
    device = start_serial_board(cfg.emulator, DRIVER, baudrate=0, link="pipe")
    if spy is not None:
        device.server.faults = spy(device.server.faults)
    device.link.timeout = 0.02  # as SerialBoardAdapter.open sets for a serial port
    adapter = SerialBoardAdapter(link(device.link), DRIVER, device.port)
    try:
        adapter.identify()
        lim = cfg.limits
        adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        yield device, adapter
    finally:
        adapter.close()
        device.close()


class Recorder:
    """A sink that keeps what it is given."""

    def __init__(self):
        self.blocks: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, index, rows):
        self.blocks.append((index.copy(), rows.copy()))

    @property
    def index(self) -> np.ndarray:
        return np.concatenate([i for i, _ in self.blocks]) if self.blocks else np.zeros(0, int)

    @property
    def rows(self) -> np.ndarray:
        return np.concatenate([r for _, r in self.blocks]) if self.blocks else np.zeros((0, len(CHANNELS)))


def f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float32).astype(float)


def wait_until(condition, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def excitation(n: int, amplitude: float = 0.8) -> np.ndarray:
    """Distinct torque values (below the static friction: the axis stays put)."""
    k = np.arange(n)
    return amplitude * np.sin(2 * np.pi * k / 97.0) * np.cos(2 * np.pi * k / 1013.0)


def assert_clean(stats, n):
    assert stats.samples == n
    for field in (
        "lost_frames",
        "lost_blocks",
        "lost_samples",
        "corrupt_frames",
        "out_of_order",
        "underruns",
        "board_dropped_blocks",
        "clipped_blocks",
    ):
        assert getattr(stats, field) == 0, field


# --- clean runs ------------------------------------------------------------------------------


def test_stream_over_pipe_delivers_every_sample_once_in_order():
    cfg = make_config()
    with pipe_board(cfg) as (device, adapter):
        assert adapter.configure(RATE_HZ, "torque", CHANNELS) == CHANNELS
        n = 6000  # longer than the board's excitation buffer: flow control during the run
        assert n > DRIVER.excitation_buffer_samples
        x = excitation(n)
        rec = Recorder()
        result = adapter.stream(x, rec)
        assert result.completed and result.fault is None
        assert_clean(result.stats, n)
        np.testing.assert_array_equal(rec.index, np.arange(n))
        # The board played exactly what was sent, in order (torque mode: torque = excitation).
        np.testing.assert_array_equal(rec.rows[:, 0], f32(x))
        np.testing.assert_array_equal(rec.rows[:, 1], f32(x))
        assert "finished" in [e["kind"] for e in result.events]
        st = adapter.status()
        assert (st.state, st.samples_produced, st.excitation_level) == (sb.State.CONFIGURED, n, 0)


def test_blocks_a_slow_line_cannot_carry_are_dropped_by_the_board_and_take_no_message_number():
    # every channel at 4 kHz over 115 200 baud: far more than the line carries, so the board's transmit
    # buffer fills and it drops whole blocks; it counts them, block_index tells the host how many, and the
    # frames that were sent are numbered without a gap (PROTOCOL.md sections 3 and 7)
    cfg = make_config()
    device = start_serial_board(cfg.emulator, DRIVER, baudrate=115200, link="pty")
    try:
        with SerialBoardAdapter.open(device.port, DRIVER, 115200) as adapter:
            adapter.set_limits(5.0, 1.0, -1.0, 1.0)
            channels = [c.name for c in DRIVER.channels if c.stream]
            adapter.configure(4000.0, "torque", channels)
            result = adapter.stream(excitation(4000, 0.3), Recorder())
            stats = result.stats
            assert stats.board_dropped_blocks > 0
            assert stats.lost_blocks == stats.board_dropped_blocks and stats.lost_frames == 0
            assert stats.samples + stats.lost_samples == 4000
    finally:
        device.close()


def test_stream_over_a_pseudo_terminal():
    cfg = make_config()
    device = start_serial_board(cfg.emulator, DRIVER, baudrate=DRIVER.default_baudrate, link="pty")
    try:
        assert device.port.startswith("/dev/")
        with SerialBoardAdapter.open(device.port, DRIVER, DRIVER.default_baudrate) as adapter:
            assert adapter.identity.name == DRIVER.name
            adapter.link = OneFrameReads(adapter.link)
            adapter.set_limits(5.0, 1.0, -1.0, 1.0)
            adapter.configure(RATE_HZ, "torque", CHANNELS + ["position_m"])  # position_m: scaled i32
            n = 2500
            x = 2.0 + excitation(n, 0.3)  # above the static friction: the axis moves
            rec = Recorder()
            result = adapter.stream(x, rec)
            assert_clean(result.stats, n)
            np.testing.assert_array_equal(rec.index, np.arange(n))
            np.testing.assert_array_equal(rec.rows[:, 0], f32(x))
            # the scaled integer channel arrives as whole counts of its scale
            position = rec.rows[:, 2]
            counts = position / DRIVER.channels[DRIVER.channel_index("position_m")].scale
            np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
            assert position[-1] - position[0] > 1e-3
    finally:
        device.close()


def test_host_keep_alive_holds_off_the_watchdog_during_a_long_quiet_run():
    # The whole excitation fits the board's buffer, so after START the host sends no
    # EXCITATION; the run lasts longer than the board's 1 s watchdog in wall time.
    cfg = make_config(time_scale=2.0)
    with pipe_board(cfg) as (device, adapter):
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        n = 3000
        rec = Recorder()
        result = adapter.stream(excitation(n), rec)
        assert result.completed
        assert_clean(result.stats, n)
        assert "watchdog" not in [e["kind"] for e in result.events]


def test_filter_upload_reads_back_the_real32_coefficients():
    cfg = make_config()
    with pipe_board(cfg) as (device, adapter):
        b, a = iirnotch(120.0, 4.0, fs=DRIVER.loop_rate_hz)
        notch = Biquad(tuple(b), tuple(a))
        adapter.write_filter(2, notch, enabled=True)
        back, enabled = adapter.read_filter(2)
        assert enabled
        assert back == board_stored_form(notch)
        assert back.b == tuple(f32(b)) and back.a == tuple(f32(a))
        assert device.drive.filters.read(2) == (back, True)
        with pytest.raises(DeviceError, match="BAD_ARGUMENT"):
            adapter.write_filter(0, Biquad((1.0, 0.0, 0.0), (1.0, 0.0, 1.5)), enabled=True)


class BatchAfterStart(OneFrameReads):
    """After START is written, hold the board's answers until its ACK and two more frames are in."""

    def __init__(self, link):
        super().__init__(link)
        self.holding = False

    @property
    def in_waiting(self) -> int:
        return 0 if self.holding else super().in_waiting

    def write(self, data: bytes) -> int:
        if any(p[1] == sb.MsgType.START for p in FrameDecoder().feed(data)):
            self.holding = True
        return super().write(data)

    def read(self, size: int = 1) -> bytes:
        if self.holding:
            self._buffer += self.link.read(max(1, self.link.in_waiting))
            if self._buffer.count(0) < 3:
                return b""
            self.holding = False
        data = bytes(self._buffer) or self.link.read(size)
        self._buffer.clear()
        return data


def test_blocks_arriving_with_the_start_ack_are_kept():
    with pipe_board(make_config(), link=BatchAfterStart) as (device, adapter):
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        n = 1000
        rec = Recorder()
        stats = adapter.stream(excitation(n), rec).stats
        # every sample is either recorded or counted as lost: none vanish unnoticed
        assert stats.samples + stats.lost_samples == n


# --- a damaged line ---------------------------------------------------------------------------


class SampleBlockFaults:
    """Let the configured :class:`LineFaults` damage only sample blocks, and record which.

    Requests and their answers, and the run's last block, pass untouched: the
    stream's bookkeeping is under test here, not the adapter's request retries.
    Restricting the damage also makes it deterministic: the seeded generator sees
    the same sequence of frames on every run, however the threads interleave.
    """

    def __init__(self, faults):
        self.faults = faults
        self.damaged: list[tuple[int, int, int]] = []  # block_index, first_sample, rows

    def apply(self, frame: bytes) -> bytes:
        payload = cobs.decode(frame[:-1])[:-4]
        if payload[1] != sb.MsgType.SAMPLES:
            return frame
        block, first, rows, flags = struct.unpack_from("<IIHH", payload, 4)
        if flags & sb.FLAG_LAST:
            return frame
        out = self.faults.apply(frame)
        if out != frame:
            self.damaged.append((block, first, rows))
        return out


@pytest.mark.parametrize("corrupt, drop", [(0.15, 0.0), (0.0, 0.15), (0.1, 0.1)])
def test_damaged_frames_are_counted_and_leave_holes_never_filled(corrupt, drop):
    cfg = make_config(faults=f"[emulator.faults.serial]\ncorrupt_frame_rate = {corrupt}\ndrop_frame_rate = {drop}")
    with pipe_board(cfg, spy=SampleBlockFaults) as (device, adapter):
        spy = device.server.faults
        assert (spy.faults.corrupt, spy.faults.drop) == (corrupt, drop)  # the configured line
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        n = 4000
        x = excitation(n)
        rec = Recorder()
        result = adapter.stream(x, rec)
        stats = result.stats
        damaged = spy.damaged
        assert len(damaged) > 0

        # What the line did, the host counted.
        assert stats.corrupt_frames == len(damaged)
        assert stats.lost_frames == len(damaged)
        assert stats.lost_blocks == len(damaged)
        assert stats.lost_samples == sum(rows for _, _, rows in damaged)
        assert stats.board_dropped_blocks == 0 and stats.out_of_order == 0
        injected = spy.faults.corrupted + spy.faults.dropped
        if corrupt and drop:
            assert len(damaged) <= injected  # one frame can be hit both ways
        else:
            assert len(damaged) == injected

        # Holes exactly where blocks were lost; every other sample present once, unshifted.
        missing = set()
        for _, first, rows in damaged:
            missing.update(range(first, first + rows))
        expected = np.array(sorted(set(range(n)) - missing))
        np.testing.assert_array_equal(rec.index, expected)
        assert stats.samples == len(expected) == n - stats.lost_samples
        np.testing.assert_array_equal(rec.rows[:, 0], f32(x[expected]))
        gaps = [e for e in result.events if e["kind"] == "lost_blocks"]
        assert sum(e["value"] for e in gaps) == len(damaged)
        assert {e["sample_index"] for e in gaps} <= {first for _, first, _ in damaged}


# --- faults on the axis and the line ------------------------------------------------------------


def test_limit_trip_raises_and_keeps_the_samples_up_to_the_trip():
    cfg = make_config(limits=(2.0, 1.0, -1.0, 1.0))
    with pipe_board(cfg) as (device, adapter):
        adapter.configure(RATE_HZ, "torque", CHANNELS)
        trip_at = 1500
        x = np.concatenate([np.full(trip_at, 1.0), np.full(1500, 3.0)])
        rec = Recorder()
        with pytest.raises(LimitTrip, match=device.port):
            adapter.stream(x, rec)
        result = adapter.last_result
        assert result is not None and not result.completed and "torque_limit" in result.fault
        assert result.stats.samples == len(rec.index) > trip_at
        np.testing.assert_array_equal(rec.index, np.arange(len(rec.index)))
        torque = rec.rows[:, 1]
        np.testing.assert_array_equal(torque[:trip_at], 1.0)
        np.testing.assert_array_equal(torque[trip_at:], 0.0)
        (trip,) = [e for e in result.events if e["kind"] == "limit_trip"]
        assert trip["sample_index"] == trip_at and trip["value"] == 3.0
        assert adapter.status().state == sb.State.FAULT
        assert not device.drive.enabled


@pytest.mark.parametrize("link", ["pipe", "pty"])
def test_line_closed_mid_run_raises_device_error_and_the_axis_stops(link):
    cfg = make_config(faults="[emulator.faults.serial]\nclose_after_s = 0.3")
    device = start_serial_board(cfg.emulator, DRIVER, baudrate=DRIVER.default_baudrate, link=link)
    try:
        if link == "pipe":
            device.link.timeout = 0.02
            adapter = SerialBoardAdapter(OneFrameReads(device.link), DRIVER, device.port)
            adapter.identify()
        else:
            adapter = SerialBoardAdapter.open(device.port, DRIVER, DRIVER.default_baudrate)
            adapter.link = OneFrameReads(adapter.link)
        adapter.set_limits(5.0, 1.0, -1.0, 1.0)
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        rec = Recorder()
        with pytest.raises(DeviceError) as info:
            adapter.stream(np.zeros(60_000), rec)  # a minute of simulated time: far longer than 0.3 s
        assert not isinstance(info.value, LimitTrip)
        assert device.port in str(info.value)
        assert not adapter.last_result.completed
        assert len(rec.index) > 0
        np.testing.assert_array_equal(rec.index, np.arange(len(rec.index)))
        # the board stopped the axis on its own when the line went away
        assert wait_until(lambda: not device.drive.enabled)
        adapter.close()  # closing after a lost line must not raise
    finally:
        device.close()


def test_silent_host_trips_the_board_watchdog():
    cfg = make_config(time_scale=5.0)
    with pipe_board(cfg) as (device, adapter):
        adapter.configure(RATE_HZ, "torque_injection", CHANNELS)
        # START by hand, then send nothing more: the host only listens.
        t0 = time.monotonic()
        adapter.link.write(encode_frame(sb.encode(sb.Start(0), 1000)))
        decoder = FrameDecoder()
        seen: list = []

        def finished() -> bool:
            return any(isinstance(m, sb.Samples) and m.flags & sb.FLAG_LAST for m in seen)

        while not finished() and time.monotonic() < t0 + 10.0:
            for payload in decoder.feed(adapter.link.read(max(1, adapter.link.in_waiting))):
                seen.append(sb.decode(payload, sample_channels=adapter.channels)[1])
        waited = time.monotonic() - t0
        (watchdog,) = [m for m in seen if isinstance(m, sb.Event) and m.code == sb.EventCode.WATCHDOG]
        assert waited >= 1.0  # the board's watchdog is 1 s of host silence
        assert watchdog.sample_index > 0  # it had been running
        last = [m for m in seen if isinstance(m, sb.Samples)][-1]
        assert last.flags & sb.FLAG_LAST and last.flags & sb.FLAG_FAULT
        assert not device.drive.enabled
        st = adapter.status()
        assert (st.state, st.fault) == (sb.State.FAULT, sb.FaultCode.WATCHDOG)
        adapter.clear_fault()
        assert adapter.status().state == sb.State.CONFIGURED


# --- opening ---------------------------------------------------------------------------------


def test_unknown_port_raises_device_error_naming_it():
    port = "/dev/ttyHILIDENT-no-such-port"
    with pytest.raises(DeviceError, match=port):
        SerialBoardAdapter.open(port, DRIVER)


def test_port_without_a_board_raises_device_error_naming_it():
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        with pytest.raises(DeviceError, match=f"{port}: no answer to Identify"):
            SerialBoardAdapter.open(port, DRIVER, timeout_s=0.3)
    finally:
        os.close(master)
        os.close(slave)


def test_a_tcp_line_is_read_in_whole_chunks_and_without_nagle():
    """pyserial's socket:// says 0 or 1 for in_waiting; the adapter asks the socket for the real count."""
    import socket as socketlib
    import time as timelib

    import serial as pyserial

    from hilident.adapters.serial.board import _bytes_waiting, _no_nagle

    server = socketlib.create_server(("127.0.0.1", 0))
    link = pyserial.serial_for_url(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.02)
    conn, _ = server.accept()
    try:
        _no_nagle(link)
        assert link._socket.getsockopt(socketlib.IPPROTO_TCP, socketlib.TCP_NODELAY)
        conn.sendall(bytes(1000))
        deadline = timelib.monotonic() + 2.0
        while _bytes_waiting(link) < 1000 and timelib.monotonic() < deadline:
            timelib.sleep(0.01)
        assert _bytes_waiting(link) == 1000
        assert len(link.read(_bytes_waiting(link))) == 1000
    finally:
        link.close()
        conn.close()
        server.close()


def test_a_board_that_was_never_identified_is_refused_with_its_port_named():
    import serial

    link = serial.serial_for_url("loop://", timeout=0.01)
    try:
        ad = SerialBoardAdapter(link, DRIVER, "loop://")
        with pytest.raises(DeviceError, match=r"loop://: the board has not been identified"):
            ad.configure(RATE_HZ, "torque", CHANNELS)
    finally:
        link.close()
