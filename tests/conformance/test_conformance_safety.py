"""Conformance of a board's safety nets: limits, the fault latch, the watchdog and hosts that die.

Sections 5, 5.1, 8, 9 and 10 ("slots outlive sessions") of ``drivers/myrio-board/PROTOCOL.md``, on the
wire, in real time. Each trip is provoked so that it does not depend on the plant behind the board: a
torque command beyond the limit in TORQUE mode (open loop: the command is the excitation), a position
window that excludes where the axis stands.
"""

from __future__ import annotations

import time

import numpy as np

from conformance.boards import DRIVER
from conformance.wire import hand_frame, header
from hilident.protocol import serial_board as sb

NAMES = [c.name for c in DRIVER.channels]
EXC, CMD, TRQ, POS = (NAMES.index(n) for n in ("excitation", "torque_cmd_nm", "torque_nm", "position_m"))
TORQUES = tuple(sb.ChannelSelection(i) for i in (EXC, CMD, TRQ))
#: The watchdog's timeout (section 8) and how much later than it a loaded machine may see its EVENT.
WATCHDOG_S = 1.0
WATCHDOG_LATE_S = 0.75
#: A bypassed slot's contents as a write: what the checks leave in a slot to see it survive a trip.
KEPT = sb.FilterCoefficients(2, False, (0.5, -0.25, 0.125), (1.0, -0.5, 0.0625))


def limits(torque_nm: float = 5.0, position_m: tuple[float, float] = (-1000.0, 1000.0)) -> sb.Limits:
    return sb.Limits(torque_nm, 5.0, *position_m)


def test_a_torque_beyond_the_limit_trips_stops_and_latches(wire):
    """Sections 9, 5 (FAULT row of the table), 11.2 and 11.6: 50 samples at 0.5 N·m, then 1.5 N·m against a
    1 N·m limit. The board trips at sample 50: EVENT LIMIT_TRIP (sample_index 50, value 1.5 N·m) before the
    run's last block (FLAG_FAULT | FLAG_LAST); the trip sample is delivered and from it on the measured
    torque is (near) zero, so 1.5 N·m never reached the axis; STATUS says FAULT TORQUE_LIMIT, one limit
    trip, the buffer emptied. Latched: START is refused FAULT_ACTIVE, EXCITATION BAD_STATE; STOP, SET_LIMITS
    and CONFIGURE are accepted and leave it in FAULT; a filter slot is as it was and can be written.
    CLEAR_FAULT brings it to CONFIGURED and a run plays again, while ``limit_trips`` keeps counting since
    power-up."""
    wire.ok(limits(torque_nm=1.0))
    wire.ok(sb.WriteFilter(KEPT))
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, TORQUES))
    x = np.r_[np.full(50, 0.5), np.full(50, 1.5)]
    run = wire.play(x)
    codes = [e.code for e in run.events]
    assert codes == [sb.EventCode.LIMIT_TRIP], f"events {codes}"
    trip = run.events[0]
    assert trip.sample_index == 50 and trip.value == 1.5, trip
    trip_frame = next(f for f in wire.stream if f.order >= run.since and f.msg == trip)
    assert trip_frame.order < run.last.order, "LIMIT_TRIP must precede the last block (section 5)"
    assert run.last.flags & (sb.FLAG_FAULT | sb.FLAG_LAST) == sb.FLAG_FAULT | sb.FLAG_LAST
    rows = run.rows()
    assert 51 <= len(rows) <= 100, f"{len(rows)} rows: the trip sample must be delivered"
    np.testing.assert_array_equal(rows[:50, 1], 0.5)
    assert np.all(np.abs(rows[50:, 2]) < 0.25), f"torque after the trip: {rows[50:, 2]}"
    assert np.all(np.abs(rows[:, 2]) < 1.0), "a torque beyond the limit reached the axis"
    status = wire.status()
    assert (status.state, status.fault, status.limit_trips) == (sb.State.FAULT, sb.FaultCode.TORQUE_LIMIT, 1)
    assert (status.samples_produced, status.excitation_level) == (len(rows), 0)

    wire.refused(sb.Start(10), sb.ErrorCode.FAULT_ACTIVE)
    wire.refused(sb.Excitation(0, np.zeros(2)), sb.ErrorCode.BAD_STATE)
    wire.ok(sb.Stop())
    wire.ok(limits(torque_nm=1.0))
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, TORQUES))
    assert (wire.status().state, wire.status().fault) == (sb.State.FAULT, sb.FaultCode.TORQUE_LIMIT)
    assert wire.read_filter(2)[0] == KEPT, "the trip changed a filter slot"
    wire.ok(sb.WriteFilter(KEPT))
    wire.ok(sb.ClearFault())
    status = wire.status()
    assert (status.state, status.fault, status.limit_trips) == (sb.State.CONFIGURED, sb.FaultCode.NONE, 1)
    again = wire.play(np.full(40, 0.5))
    assert [e.code for e in again.events] == [sb.EventCode.FINISHED]
    np.testing.assert_array_equal(again.rows()[:, 1], 0.5)


def test_a_position_outside_the_window_trips_at_the_first_tick(wire):
    """Section 9: the position limit is checked every loop tick while the drive is enabled. With a window
    that starts 0.5 m beyond where the axis stands, a run trips at once: EVENT LIMIT_TRIP at sample 0 with
    the encoder position as its value, STATUS FAULT POSITION_LIMIT."""
    wire.ok(limits())
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 10, (sb.ChannelSelection(POS),)))
    where = float(np.mean(wire.play(np.zeros(10)).rows()[:, 0]))
    wire.ok(limits(position_m=(where + 0.5, where + 1.0)))
    run = wire.play(np.zeros(10))
    assert [(e.code, e.sample_index) for e in run.events] == [(sb.EventCode.LIMIT_TRIP, 0)]
    assert abs(run.events[0].value - where) < 1e-3, (run.events[0].value, where)
    assert run.last.flags & sb.FLAG_FAULT
    status = wire.status()
    assert (status.state, status.fault, status.limit_trips) == (sb.State.FAULT, sb.FaultCode.POSITION_LIMIT, 1)


def test_the_torque_limit_applies_after_the_filter_slots(wire):
    """Sections 9 ("torque command after the filter slots") and 10 (slots in series on the torque command,
    READ_FILTER answers exactly what runs): through an enabled slot of gain 0.5, a 1.5 N·m command runs
    against a 1 N·m limit without a trip, ``torque_cmd_nm`` (before the slots) reads 1.5 and the measured
    torque about 0.75 N·m; with the slot bypassed the same command trips at once."""
    wire.ok(limits(torque_nm=1.0))
    wire.ok(sb.WriteFilter(sb.FilterCoefficients(1, True, (0.5, 0.0, 0.0), (1.0, 0.0, 0.0))))
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, TORQUES))
    run = wire.play(np.full(200, 1.5))
    assert [e.code for e in run.events] == [sb.EventCode.FINISHED], run.events
    rows = run.rows()
    np.testing.assert_allclose(rows[:, 1], 1.5, rtol=1e-6)
    assert abs(np.mean(rows[100:, 2]) - 0.75) < 0.1, f"measured torque {np.mean(rows[100:, 2]):.3f} N·m"
    wire.ok(sb.WriteFilter(sb.FilterCoefficients(1, False, (0.5, 0.0, 0.0), (1.0, 0.0, 0.0))))
    tripped = wire.play(np.full(40, 1.5))
    assert [(e.code, e.sample_index, e.value) for e in tripped.events] == [(sb.EventCode.LIMIT_TRIP, 0, 1.5)]
    assert wire.status().fault == sb.FaultCode.TORQUE_LIMIT


def test_the_watchdog_stops_a_run_whose_host_went_silent(wire):
    """Section 8: while RUNNING any byte feeds the watchdog: PINGs, then corrupt frames alone for longer than
    1 s keep the run going. Once the host sends nothing at all, the board stops the axis within 1 s plus a
    processing step of the host's last byte: EVENT WATCHDOG (sample_index = samples produced) before the
    run's last block with FLAG_LAST and FLAG_FAULT; STATUS FAULT WATCHDOG, the buffer emptied; START is
    refused FAULT_ACTIVE until CLEAR_FAULT, after which a run plays again; filter slots are untouched."""
    wire.ok(limits())
    wire.ok(sb.WriteFilter(KEPT))
    wire.configure(sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(EXC),)))
    wire.excite(0, np.zeros(100))
    corrupt_before = wire.status().rx_corrupt
    since = len(wire.frames)
    wire.ok(sb.Start(0))
    for _ in range(3):
        time.sleep(0.25)
        wire.ok(sb.Ping())
    corrupt = hand_frame(header(1, sb.MsgType.PING, 0x6666), crc=b"\x01\x02\x03\x04")
    for _ in range(6):  # 1.5 s without a frame the board takes, bytes every 0.25 s
        time.sleep(0.25)
        wire.send_raw(corrupt)
        wire.listen(0.0)
    silent_from = time.monotonic()
    assert not [e for e in wire.events(since) if e.code == sb.EventCode.WATCHDOG], "a fed watchdog fired"
    wire.wait_for(
        lambda: any(e.code == sb.EventCode.WATCHDOG for e in wire.events(since)),
        "EVENT WATCHDOG",
        timeout=WATCHDOG_S + WATCHDOG_LATE_S + 1.0,
    )
    fired = next(f for f in wire.stream if f.order >= since and getattr(f.msg, "code", None) == sb.EventCode.WATCHDOG)
    late = fired.at - silent_from
    assert WATCHDOG_S - 0.05 <= late <= WATCHDOG_S + WATCHDOG_LATE_S, f"EVENT WATCHDOG {late:.3f} s after the last byte"
    last = wire.wait_for_last_block(since)
    assert fired.order < last.order and last.flags & (sb.FLAG_LAST | sb.FLAG_FAULT) == sb.FLAG_LAST | sb.FLAG_FAULT
    block = last.msg
    assert isinstance(block, sb.Samples) and fired.msg.sample_index == block.first_sample + len(block.data)
    status = wire.status()
    assert (status.state, status.fault, status.excitation_level) == (sb.State.FAULT, sb.FaultCode.WATCHDOG, 0)
    assert status.samples_produced == fired.msg.sample_index
    assert status.rx_corrupt == corrupt_before + 6
    wire.refused(sb.Start(0), sb.ErrorCode.FAULT_ACTIVE)
    assert wire.read_filter(2)[0] == KEPT
    wire.ok(sb.ClearFault())
    assert (wire.status().state, wire.status().fault) == (sb.State.CONFIGURED, sb.FaultCode.NONE)
    assert [e.code for e in wire.play(np.zeros(20)).events] == [sb.EventCode.FINISHED]


def test_the_board_is_found_as_a_host_that_died_left_it(board):
    """Sections 5.1, 8 and 10: the board's state belongs to the board, not to a connection. A host that
    starts a run and disappears without STOP leaves it RUNNING: the next host, sending STATUS_REQUEST and
    STOP back to back, finds RUNNING, gets the run's last block (undecodable to it, not decoded) and EVENT
    STOPPED before STOP's ACK, and the board CONFIGURED with the earlier host's configuration. A host that
    died 1 s or more ago leaves it in FAULT WATCHDOG: STOP is ACKed and leaves the fault latched, START is
    refused FAULT_ACTIVE, CLEAR_FAULT clears it. Filter slots written by the first host survive all of it."""
    first = board.connect(first_seq=0x1000)
    first.ok(sb.WriteFilter(KEPT))
    first.ok(limits())
    first.configure(sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(EXC),)))
    first.excite(0, np.zeros(2000))
    first.ok(sb.Start(0))
    first.wait_for(lambda: bool(first.blocks()), "sample block")
    first.close()
    time.sleep(0.2)

    second = board.connect(first_seq=0x9000)
    status_request, stop = second.payload(sb.StatusRequest()), second.payload(sb.Stop())
    second.send_raw(hand_frame(status_request) + hand_frame(stop))
    found = second.reply().msg
    assert isinstance(found, sb.Status) and found.state == sb.State.RUNNING, found
    ack = second.reply()
    assert ack.msg == sb.Ack(0x9002, sb.MsgType.STOP)
    last = second.last_block()
    assert last is not None and last.msg is None and second.stale >= 1, "the earlier run's last block"
    stopped = [f for f in second.stream if getattr(f.msg, "code", None) == sb.EventCode.STOPPED]
    assert len(stopped) == 1 and last.order < stopped[0].order < ack.order
    status = second.status()
    assert (status.state, status.fault) == (sb.State.CONFIGURED, sb.FaultCode.NONE)

    second.excite(0, np.zeros(2000))  # the earlier host's configuration is the board's
    second.ok(sb.Start(0))
    second.close()
    time.sleep(WATCHDOG_S + 0.4)

    third = board.connect(first_seq=0x0000)
    status = third.status()
    assert (status.state, status.fault) == (sb.State.FAULT, sb.FaultCode.WATCHDOG), status
    third.ok(sb.Stop())
    assert third.status().state == sb.State.FAULT, "STOP must leave a latched fault latched"
    third.refused(sb.Start(0), sb.ErrorCode.FAULT_ACTIVE)
    third.ok(sb.ClearFault())
    assert third.status().state == sb.State.CONFIGURED
    assert third.read_filter(2)[0] == KEPT
