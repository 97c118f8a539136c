"""Conformance of a board's runs: the excitation buffer, sample blocks, value encodings and underruns.

Sections 4.4-4.6, 4.12, 6, 7 and 11.5 of ``drivers/myrio-board/PROTOCOL.md``, on the wire, in real time.
The runs are short and gentle (tenths of a N·m, open loop, for tenths of a second; wide position and
velocity limits), so they hold on any plant behind the board.
"""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from conformance.boards import DRIVER
from conformance.wire import Run, Wire, header
from hilident.protocol import serial_board as sb

LIMITS = sb.Limits(5.0, 5.0, -1000.0, 1000.0)
NAMES = [c.name for c in DRIVER.channels]
CAPACITY = DRIVER.excitation_buffer_samples
TIME, EXC, CMD = NAMES.index("time_s"), NAMES.index("excitation"), NAMES.index("torque_cmd_nm")


def f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float32).astype(float)


def driver_channels() -> tuple[sb.ChannelSelection, ...]:
    """Every channel of the board in the format and scale driver.toml gives it."""
    formats = {"f32": sb.Format.F32, "i16": sb.Format.I16, "i32": sb.Format.I32}
    return tuple(sb.ChannelSelection(i, formats[c.format], c.scale) for i, c in enumerate(DRIVER.channels))


def check_blocks(run: Run, n_samples: int, block_samples: int) -> None:
    """Section 7 for one run: block indices one apart, rows contiguous from sample 0, every block but the
    last full, exactly one FLAG_LAST block holding the remaining 0 ... block_samples - 1 rows, and
    ``n_samples`` rows in all; START's ACK came before the first block (section 4.4)."""
    samples = run.samples
    assert len(samples) == len(run.blocks), "a block of this run was not decoded"
    indices = [s.block_index for s in samples]
    assert indices == list(range(indices[0], indices[0] + len(indices))), f"block indices {indices}"
    firsts = [s.first_sample for s in samples]
    rows = [len(s.data) for s in samples]
    assert firsts == list(np.cumsum([0, *rows[:-1]])), f"first_sample {firsts} for rows {rows}"
    assert rows[:-1] == [block_samples] * (len(rows) - 1), f"rows per block {rows}"
    assert rows[-1] == n_samples % block_samples and sum(rows) == n_samples, f"rows per block {rows}"
    assert [bool(s.flags & sb.FLAG_LAST) for s in samples] == [False] * (len(samples) - 1) + [True]
    assert run.start_ack.order < run.blocks[0].order, "a block came before START's ACK"


def test_runs_deliver_contiguous_blocks_the_sample_instant_and_a_finished_event(wire):
    """Sections 4.4, 5, 6 (sample instant, buffer reset), 7 and 11.2: a run of 130 samples at a divider of
    4 arrives as blocks of 40, 40, 40 and a FLAG_LAST block of 10, then EVENT FINISHED with sample_index
    130; ``time_s`` steps by divider / loop rate; the excitation and, in TORQUE mode, the torque command
    (the mean over each period's ticks, section 7) equal the values sent row for row, so value ``i`` acts
    from the first tick of period ``i`` (a board that applied it a tick late, or sampled at another tick,
    would show means between the steps of this square wave). Values left in the buffer are discarded at
    the end of the run: the next run starts again from index 0, its blocks' ``block_index`` going on where
    the last run's stopped while ``first_sample`` restarts at 0, and a run as long as a whole number of
    blocks ends with an empty FLAG_LAST block."""
    divider, block = 4, 40
    channels = tuple(sb.ChannelSelection(i) for i in (TIME, EXC, CMD))
    wire.ok(LIMITS)
    wire.configure(sb.Configure(divider, sb.Mode.TORQUE, block, channels))
    square = f32(0.2 * np.sign(np.sin(2 * np.pi * (np.arange(200) + 0.5) / 10)))
    wire.excite(0, square)  # 200 values, 130 played
    first = wire.play([], n_samples=130)
    check_blocks(first, 130, block)
    assert [(e.code, e.sample_index) for e in first.events] == [(sb.EventCode.FINISHED, 130)]
    assert first.events and _event_order(wire, first, sb.EventCode.FINISHED) > first.last.order
    rows = first.rows()
    period = divider / DRIVER.loop_rate_hz
    tolerance = 4 * np.spacing(np.float32(rows[-1, 0])) + 1e-9
    np.testing.assert_allclose(np.diff(rows[:, 0]), period, rtol=0, atol=tolerance)
    np.testing.assert_array_equal(rows[:, 1], square[:130])
    np.testing.assert_allclose(rows[:, 2], square[:130], rtol=1e-6, atol=1e-9)
    status = wire.status()
    assert (status.state, status.samples_produced, status.excitation_level) == (sb.State.CONFIGURED, 130, 0)

    ramp = f32(np.linspace(-0.1, 0.1, 80))
    second = wire.play(ramp)
    check_blocks(second, 80, block)
    assert second.samples[0].block_index == first.samples[-1].block_index + 1
    assert len(second.samples[-1].data) == 0
    np.testing.assert_array_equal(second.rows()[:, 1], ramp)


def _event_order(wire: Wire, run: Run, code: sb.EventCode) -> int:
    return next(f.order for f in wire.stream if f.order >= run.since and getattr(f.msg, "code", None) == code)


def test_the_excitation_buffer_takes_exactly_its_capacity_in_order(wire):
    """Sections 4.6 and 6: EXCITATION is not acknowledged (the next answer is the next request's); a frame
    that does not start at ``written`` is refused BAD_ARGUMENT naming the expected index; the buffer takes
    exactly ``excitation_buffer_samples`` values and refuses a frame that would overflow it whole with
    BUFFER_OVERFLOW; a value count that is not ``n`` is BAD_LENGTH; NaN or infinity refuses the whole
    frame with BAD_ARGUMENT; nothing refused is stored (STATUS ``excitation_level``). CONFIGURE empties the
    buffer and the stream starts again at index 0."""
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(EXC),)))
    wire.excite(0, np.zeros(1000))
    wire.ok(sb.Ping())
    assert wire.status().excitation_level == 1000
    nak = wire.refused(sb.Excitation(999, np.zeros(4)), sb.ErrorCode.BAD_ARGUMENT)
    assert "1000" in nak.detail, f"the detail {nak.detail!r} does not name the expected index 1000"
    wire.refused(sb.Excitation(1000, np.array([0.1, np.nan])), sb.ErrorCode.BAD_ARGUMENT)
    wire.refused(sb.Excitation(1000, np.array([-np.inf])), sb.ErrorCode.BAD_ARGUMENT)
    for announced in (4, 2):  # three values carried: n (body offset 4, payload offset 8) says otherwise
        payload = wire.payload(sb.Excitation(1000, np.zeros(3)))
        wire.refused_payload(payload[:8] + struct.pack("<H", announced) + payload[10:], sb.ErrorCode.BAD_LENGTH)
    assert wire.status().excitation_level == 1000
    for first in range(1000, CAPACITY, 1024):
        wire.excite(first, np.full(min(1024, CAPACITY - first), 0.01))
    assert wire.status().excitation_level == CAPACITY
    wire.refused(sb.Excitation(CAPACITY, np.zeros(1)), sb.ErrorCode.BUFFER_OVERFLOW)
    assert wire.status().excitation_level == CAPACITY
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(EXC),)))
    assert wire.status().excitation_level == 0
    wire.refused(sb.Excitation(CAPACITY, np.zeros(1)), sb.ErrorCode.BAD_ARGUMENT)
    wire.excite(0, np.zeros(CAPACITY))
    assert wire.status().excitation_level == CAPACITY


def test_a_stream_longer_than_the_buffer_plays_in_real_time_without_a_gap(wire):
    """Sections 4.12, 6 (flow control), 7 and 8 (keep-alive): 5 000 values, more than the 4 096-value
    buffer, streamed at 2 kHz with every channel in its driver.toml format (``position_m`` as I32), the
    host topping the buffer up from the blocks' ``excitation_consumed`` and pinging when it has nothing to
    send. Every value is played, in order, with no underrun, no NAK and no block dropped (``block_index``,
    ``first_sample`` and the board's message numbers have no gap; STATUS ``dropped_blocks`` is 0); each
    block's row bytes are its rows in the configured formats; ``excitation_consumed`` never decreases and
    covers the block's rows, ``consumed + level`` never exceeds what was sent; no flag but FLAG_LAST on the
    last block; and the blocks arrive at the sample rate (the run lasts its 2.5 s, the arrival times go up
    by one sample period per sample)."""
    divider, n = 2, 5000
    rate = DRIVER.loop_rate_hz / divider
    block = DRIVER.block_samples * int(rate) // 1000  # as the reference host (section 13): 40 per 1000 Hz
    channels = driver_channels()
    wire.ok(LIMITS)
    wire.configure(sb.Configure(divider, sb.Mode.TORQUE, block, channels))
    t = np.arange(n) / rate
    x = f32(0.05 * np.sin(2 * np.pi * 37.0 * t) * np.minimum(1.0, 20 * t))
    run = wire.play(x)
    check_blocks(run, n, block)
    assert run.sent == n and run.max_outstanding <= CAPACITY
    row_bytes = sum({sb.Format.F32: 4, sb.Format.I16: 2, sb.Format.I32: 4}[c.format] for c in channels)
    for frame, samples in zip(run.blocks, run.samples, strict=True):
        assert len(frame.payload) == 4 + 24 + len(samples.data) * row_bytes
    samples = run.samples
    assert all(s.flags == 0 for s in samples[:-1]) and samples[-1].flags == sb.FLAG_LAST
    assert all(s.underruns == 0 for s in samples)
    consumed = np.array([s.excitation_consumed for s in samples])
    ends = np.array([s.first_sample + len(s.data) for s in samples])
    assert np.all(np.diff(consumed) >= 0) and np.all(consumed >= ends) and np.all(consumed <= n)
    assert all(s.excitation_consumed + s.excitation_level <= n for s in samples)
    assert [(e.code, e.sample_index) for e in run.events] == [(sb.EventCode.FINISHED, n)]
    assert wire.seq_gaps == 0 and wire.stale == 0
    status = wire.status()
    assert (status.state, status.underruns, status.dropped_blocks) == (sb.State.CONFIGURED, 0, 0)
    assert (status.samples_produced, status.excitation_level) == (n, 0)

    rows = run.rows()
    np.testing.assert_array_equal(rows[:, EXC], x)
    np.testing.assert_allclose(rows[:, CMD], x, rtol=1e-6, atol=1e-9)
    resolution = np.spacing(np.float32(np.abs(rows[:, TIME]).max()))
    np.testing.assert_allclose(np.diff(rows[:, TIME]), 1 / rate, rtol=0, atol=4 * resolution + 1e-9)
    assert np.all(np.isfinite(rows[:, :-1])), "a channel other than the load sensor is not finite"

    arrivals = np.array([f.at for f in run.blocks])
    duration = arrivals[-1] - run.started
    assert 0.8 * n / rate <= duration <= 2.0 * n / rate + 1.0, f"{n} samples at {rate:g} Hz took {duration:.2f} s"
    seconds_per_sample = np.polyfit(ends[:-1], arrivals[:-1], 1)[0]
    assert 0.8 <= seconds_per_sample * rate <= 1.5, f"blocks arrive at {1 / seconds_per_sample:.0f} samples/s"


def test_values_are_encoded_as_the_configured_formats_say(wire):
    """Sections 4.6, 7 (value encoding) and 11.5: an I32 excitation is ``count × excitation_scale``;
    an I16 channel of scale 0.5 sends ``round(value / scale)`` rounded half to even (1.25 → 2, 1.75 → 4,
    -1.25 → -2, -1.75 → -4); an I16 channel of scale 1e-5 saturates at 32767 and -32768 and sets
    FLAG_CLIPPED on that block only; an I32 channel carries the same values exactly; the F32 channel is the
    value itself."""
    counts = np.array([5, 7, -5, -7, 0, 1, 0, -1], dtype=np.int32)
    values = counts * 0.25
    exc = sb.ChannelSelection(EXC)
    channels = (
        exc,
        sb.ChannelSelection(EXC, sb.Format.I16, 0.5),
        sb.ChannelSelection(EXC, sb.Format.I16, 1e-5),
        sb.ChannelSelection(EXC, sb.Format.I32, 0.25),
    )
    wire.ok(LIMITS)
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 4, channels, sb.Format.I32, 0.25))
    body = struct.pack("<IH", 0, len(counts)) + counts.astype("<i4").tobytes()  # I32 counts from index 0
    wire.send_payload(header(1, sb.MsgType.EXCITATION, wire.next_seq()) + body)
    run = wire.play([], n_samples=len(counts))
    rows = run.rows()
    np.testing.assert_array_equal(rows[:, 0], values)
    np.testing.assert_array_equal(rows[:, 1], np.array([2, 4, -2, -4, 0, 0, 0, 0]) * 0.5)
    np.testing.assert_array_equal(np.round(rows[:, 2] / 1e-5), [32767, 32767, -32768, -32768, 0, 25000, 0, -25000])
    np.testing.assert_array_equal(rows[:, 3], values)
    assert [s.flags & sb.FLAG_CLIPPED for s in run.samples] == [sb.FLAG_CLIPPED, 0, 0]


UNDERRUNS = {
    sb.Mode.TORQUE: (0.1, False),
    sb.Mode.TORQUE_INJECTION: (0.1, False),
    sb.Mode.VELOCITY: (0.002, True),
    sb.Mode.POSITION: (1e-5, True),
}


@pytest.mark.parametrize("mode", list(UNDERRUNS), ids=[m.name.lower() for m in UNDERRUNS])
def test_an_underrun_holds_the_documented_value(wire, mode):
    """Section 6 (underrun): when the buffer runs dry the board plays the last value in VELOCITY and
    POSITION mode, 0 in TORQUE and TORQUE_INJECTION mode; it counts every such sample (``underruns`` of
    the last block and of STATUS), sets FLAG_UNDERRUN on the block that holds the first held sample, sends
    one EVENT UNDERRUN with that sample's index and the held value, and still produces exactly
    ``n_samples`` samples."""
    last, holds = UNDERRUNS[mode]
    wire.ok(LIMITS)
    wire.configure(sb.Configure(4, mode, 20, (sb.ChannelSelection(EXC),)))
    x = f32(np.linspace(last / 40, last, 40))
    wire.excite(0, x)
    run = wire.play([], n_samples=100)
    check_blocks(run, 100, 20)
    held = x[-1] if holds else 0.0
    rows = run.rows()[:, 0]
    np.testing.assert_array_equal(rows[:40], x)
    np.testing.assert_array_equal(rows[40:], held)
    underruns = [e for e in run.events if e.code == sb.EventCode.UNDERRUN]
    assert [(e.sample_index, e.value) for e in underruns] == [(40, held)]
    assert run.events[-1].code == sb.EventCode.FINISHED and run.events[-1].sample_index == 100
    first_held = next(s for s in run.samples if s.first_sample + len(s.data) > 40)
    assert first_held.flags & sb.FLAG_UNDERRUN, "the block holding sample 40 lacks FLAG_UNDERRUN"
    assert run.samples[-1].underruns == 60 and wire.status().underruns == 60


def test_the_watchdog_is_not_armed_outside_a_run(wire):
    """Section 8: "The watchdog is not armed outside RUNNING": a configured board left silent for 1.3 s is
    still CONFIGURED without a fault, and a run started after it plays."""
    wire.ok(LIMITS)
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 20, (sb.ChannelSelection(EXC),)))
    time.sleep(1.3)
    status = wire.status()
    assert (status.state, status.fault) == (sb.State.CONFIGURED, sb.FaultCode.NONE)
    assert not wire.events()
    run = wire.play(np.zeros(20))
    assert [e.code for e in run.events] == [sb.EventCode.FINISHED]
