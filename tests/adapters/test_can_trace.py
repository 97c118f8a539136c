"""CAN traces read back with python-can's own readers: one channel, time never going back, every frame there."""

from __future__ import annotations

import random
import threading
import time
import uuid
from collections import Counter
from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest

from hilident.adapters.canopen.trace import TRACE_CHANNEL, FrameTrace, TraceClock, TracingNetwork

FORMATS = ("asc", "blf")
READERS = {"asc": can.ASCReader, "blf": can.BLFReader}
LAG_S = 0.314  # how far a received frame's bus time lagged the host's clock in the run that showed the bug


def _read(path: Path) -> list[can.Message]:
    reader = READERS[path.suffix[1:]](str(path))
    try:
        return list(reader)
    finally:
        reader.stop()


def _key(msg: can.Message) -> tuple:
    """What must survive the trace: identifier, payload, direction and frame kind."""
    return msg.arbitration_id, bytes(msg.data), msg.is_rx, msg.is_extended_id, msg.is_remote_frame


def _assert_clean(frames: list[can.Message], expected: list[tuple]) -> None:
    assert frames, "the trace is empty"
    assert {m.channel for m in frames} == {TRACE_CHANNEL - 1}  # readers count channels from 0
    stamps = np.array([m.timestamp for m in frames])
    assert np.all(np.diff(stamps) >= 0), f"timestamps go back {int(np.sum(np.diff(stamps) < 0))} times"
    assert Counter(_key(m) for m in frames) == Counter(expected)


def _unique_channel() -> str:
    """A virtual bus name of its own that ends in a digit other than 0 (the case python-can numbered apart)."""
    return f"trace-{uuid.uuid4().hex[:8]}-vcan1"


# --- the trace on its own: two threads, bus timestamps out of order ---------------------------------------------


def _received(i: int, channel: str, rng: random.Random) -> can.Message:
    extended = i % 7 == 3
    return can.Message(
        timestamp=time.time() - rng.uniform(0.0, LAG_S),
        channel=channel,
        is_rx=True,
        arbitration_id=(0x1ABC000 + i) if extended else 0x181 + i % 4,
        is_extended_id=extended,
        data=i.to_bytes(4, "little") + bytes([i % 256] * (i % 5)),
    )


def _sent(i: int) -> can.Message:
    if i % 11 == 5:  # a remote request
        return can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_rx=False)
    return can.Message(arbitration_id=0x80 if i % 3 == 0 else 0x601, data=(1000 + i).to_bytes(4, "little"), is_rx=False)


@pytest.mark.parametrize("channel", ["can0", "vcan1"])
@pytest.mark.parametrize("fmt", FORMATS)
def test_a_run_of_sent_and_received_frames_reads_back_as_one_channel_in_time_order(tmp_path, fmt, channel):
    path = tmp_path / f"run.{fmt}"
    trace = FrameTrace(path)
    rng = random.Random(3)
    rx = [_received(i, channel, rng) for i in range(600)]
    tx = [_sent(i) for i in range(600)]
    bus_times = [m.timestamp for m in rx]
    assert any(np.diff(bus_times) < 0)  # really out of order

    def notifier():  # the bus delivers late, with its own (older, jittered) timestamps
        for msg in rx:
            trace.on_message_received(msg)

    listener = threading.Thread(target=notifier)
    listener.start()
    for msg in tx:
        trace.write_sent(msg)
    listener.join()
    trace.stop()

    expected = [_key(m) for m in rx] + [_key(m) for m in tx]
    _assert_clean(_read(path), expected)
    assert trace.frames == len(expected)
    # the frames handed in (shared with canopen's listener) keep their channel and bus time
    assert [m.timestamp for m in rx] == bus_times and {m.channel for m in rx} == {channel}


@pytest.mark.parametrize("fmt", FORMATS)
def test_trace_times_are_the_hosts_clock_not_the_frames(tmp_path, fmt):
    clock = TraceClock()
    path = tmp_path / f"clock.{fmt}"
    trace = FrameTrace(path, clock)
    before = clock.now()
    trace.on_message_received(can.Message(timestamp=12.5, arbitration_id=0x181, data=b"\x01", channel="can3"))
    trace.write_sent(can.Message(arbitration_id=0x201, data=b"\x02"))
    after = clock.now()
    trace.stop()
    frames = _read(path)
    assert [m.arbitration_id for m in frames] == [0x181, 0x201]
    assert [m.is_rx for m in frames] == [True, False]
    # both are host times of the moment they were written (the ASC file keeps them relative to the first frame)
    span = frames[-1].timestamp - frames[0].timestamp
    assert 0.0 <= span <= after - before + 1e-3
    if fmt == "blf":  # absolute: the first frame's second, not the bus's 12.5 s
        assert before - 1e-3 <= frames[0].timestamp <= after + 1e-3


def test_frames_after_stop_are_dropped_and_stop_is_idempotent(tmp_path):
    path = tmp_path / "late.asc"
    trace = FrameTrace(path)
    trace.write_sent(can.Message(arbitration_id=0x80, data=b""))
    trace.stop()
    trace.on_message_received(can.Message(arbitration_id=0x181, data=b"\x05"))
    trace.write_sent(can.Message(arbitration_id=0x201, data=b"\x06"))
    trace.stop()
    assert [m.arbitration_id for m in _read(path)] == [0x80] and trace.frames == 1


def test_an_unknown_suffix_is_refused_before_anything_is_written(tmp_path):
    network = TracingNetwork()
    with pytest.raises(ValueError):
        network.start_trace(tmp_path / "run.nosuchformat")
    assert network.trace is None


# --- through the Network: a peer on a virtual bus answers from its own clock ------------------------------------


class Peer:
    """The far end of a virtual bus: answers each host request (0x600+n) with 0x580+n, bus time lagging.

    It also produces a TPDO (0x181) every few answers, to which the host reacts
    from canopen's receive thread with an RPDO (0x201).
    """

    def __init__(self, channel: str, rng: random.Random):
        self.bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True, receive_own_messages=False)
        self.rng = rng
        self.sent: list[can.Message] = []
        self.received: list[can.Message] = []
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _send(self, arbitration_id: int, data: bytes) -> None:
        msg = can.Message(
            timestamp=time.time() - self.rng.uniform(0.0, LAG_S),
            arbitration_id=arbitration_id,
            is_extended_id=False,
            data=data,
        )
        self.bus.send(msg)
        self.sent.append(msg)

    def _serve(self) -> None:
        while not self.stopping.is_set():
            msg = self.bus.recv(0.05)
            if msg is None:
                continue
            self.received.append(msg)
            if 0x600 <= msg.arbitration_id < 0x680:
                self._send(msg.arbitration_id - 0x80, bytes(msg.data))
                if len(self.sent) % 4 == 0:
                    self._send(0x181, bytes(msg.data[:2]))

    def close(self) -> None:
        self.stopping.set()
        self.thread.join(2.0)
        self.bus.shutdown()


def _wait_for(predicate, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "frames did not arrive"
        time.sleep(0.01)


@pytest.fixture
def bus_pair():
    channel = _unique_channel()
    network = TracingNetwork()
    network.connect(interface="virtual", channel=channel, receive_own_messages=False)
    peer = Peer(channel, random.Random(7))
    yield network, peer
    network.stop_trace()
    network.disconnect()
    peer.close()


def _slow_send(bus: can.BusABC, after_s: float = 0.001) -> None:
    """Make ``bus.send`` return only a moment after the frame went out, as an interface that waits for the
    transmission (or a TCP write to socketcand) does: the answer can arrive before the send returns."""
    send = bus.send

    def slow(msg, timeout=None):
        send(msg, timeout)
        time.sleep(after_s)

    bus.send = slow


@pytest.mark.parametrize("fmt", FORMATS)
def test_network_trace_of_requests_answers_and_reactions_reads_back_clean(tmp_path, fmt, bus_pair):
    network, peer = bus_pair
    _slow_send(network.bus)
    seen_by_canopen: list[tuple[int, bytes, float]] = []

    def on_tpdo(can_id, data, timestamp):  # the host reacts inside canopen's receive thread
        seen_by_canopen.append((can_id, bytes(data), timestamp))
        network.send_message(0x201, bytes(data))

    network.subscribe(0x181, on_tpdo)
    path = tmp_path / f"bus.{fmt}"
    trace = network.start_trace(path)
    beating = threading.Event()

    def heartbeat():  # a second sending thread, as the host's heartbeat
        while not beating.is_set():
            network.send_message(0x77F, b"\x05")
            time.sleep(0.002)

    beat = threading.Thread(target=heartbeat)
    beat.start()
    try:
        for i in range(300):
            network.send_message(0x601, i.to_bytes(4, "little"))
            if i % 50 == 0:
                time.sleep(0.01)  # let the answers catch up now and then
    finally:
        beating.set()
        beat.join()
    _wait_for(lambda: sum(m.arbitration_id == 0x581 for m in peer.sent) == 300)
    tpdos = sum(m.arbitration_id == 0x181 for m in peer.sent)
    _wait_for(lambda: len(seen_by_canopen) == tpdos)
    _wait_for(lambda: trace.frames == len(peer.received) + len(peer.sent))
    network.stop_trace()

    frames = _read(path)
    # what the peer received the host sent (Tx), what the peer sent the host received (Rx)
    expected = [_key(m)[:2] + (False,) + _key(m)[3:] for m in peer.received]
    expected += [_key(m)[:2] + (True,) + _key(m)[3:] for m in peer.sent]
    _assert_clean(frames, expected)
    # causal order: each answer after its request, each reaction after the TPDO that caused it
    position = {}
    for n, m in enumerate(frames):
        position.setdefault((m.arbitration_id, bytes(m.data)), n)
    for i in range(300):
        data = i.to_bytes(4, "little")
        assert position[(0x601, data)] < position[(0x581, data)]
    for _can_id, data, _ in seen_by_canopen:
        assert position[(0x181, data)] < position[(0x201, data)]
    # canopen still gets the bus's own timestamps: the trace stamped copies
    bus_times = {bytes(m.data): m.timestamp for m in peer.sent if m.arbitration_id == 0x181}
    assert [t for _, _, t in seen_by_canopen] == [bus_times[d] for _, d, _ in seen_by_canopen]


def test_stopping_the_trace_leaves_canopen_listening(tmp_path, bus_pair):
    network, _ = bus_pair
    listeners = list(network.notifier.listeners)
    network.start_trace(tmp_path / "a.asc")
    assert network.notifier.listeners[0] is network.trace and network.notifier.listeners[1:] == listeners
    network.start_trace(tmp_path / "b.blf")  # a new trace ends the old one
    assert sum(isinstance(x, FrameTrace) for x in network.notifier.listeners) == 1
    network.stop_trace()
    network.stop_trace()
    assert network.notifier.listeners == listeners and network.trace is None
    assert (tmp_path / "a.asc").read_text().rstrip().endswith("End TriggerBlock")
    got = []
    network.subscribe(0x581, lambda can_id, data, ts: got.append(bytes(data)))
    network.send_message(0x601, b"\x09")
    _wait_for(lambda: got == [b"\x09"])


# --- a whole adapter run on the emulated drive ------------------------------------------------------------------


CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_emulated_run_writes_a_clean_trace(tmp_path, fmt):
    from hilident.adapters.canopen.drive import CanopenDriveAdapter
    from hilident.config.tables import load_config
    from hilident.drivers.description import find_driver
    from hilident.emulator.canopen.server import start

    cfg = load_config(CONFIG)
    driver = find_driver(cfg.device.driver, cfg.device.driver_paths)
    emulated = start(replace(cfg.emulator, time_scale=20.0), driver, cfg.device)
    adapter = None
    path = tmp_path / f"run.{fmt}"
    try:
        adapter = CanopenDriveAdapter.open_device(replace(emulated.device, acquisition="streamed"), driver)
        lim = cfg.limits
        adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        adapter.configure(1000.0, "torque", None)
        adapter.set_trace(path)
        result = adapter.stream(0.05 * np.sin(np.linspace(0.0, 20.0, 400)), lambda index, rows: None)
    finally:
        if adapter is not None:
            adapter.close()
        emulated.close()
    frames = _read(path)
    assert {m.channel for m in frames} == {TRACE_CHANNEL - 1}
    assert np.all(np.diff([m.timestamp for m in frames]) >= 0)
    directions = Counter(m.is_rx for m in frames)
    # the drive's SYNC and a TPDO per cycle come in; an RPDO per set-point sent goes out
    assert directions[True] >= 2 * 400 and directions[False] >= 400 - result.stats.setpoints_skipped
