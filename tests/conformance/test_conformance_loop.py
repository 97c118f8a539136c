"""Conformance of a board's loop messages: READ_LOOP, LOOP and WRITE_LOOP (PROTOCOL.md sections 4.15, 4.16).

Checked on the wire against a freshly powered-up board (conftest.py's ``board``). The boards power up with
gains of their own (the twin its ``[emulator.drive]``, the C board ``board_config.h``'s), so no check assumes
a value: each reads what the board runs and works from there.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from conformance.boards import DRIVER
from conformance.wire import header
from hilident.protocol import serial_board as sb

LIMITS = sb.Limits(5.0, 5.0, -1000.0, 1000.0)
HOLD = sb.Configure(4, sb.Mode.TORQUE_INJECTION, 40, (sb.ChannelSelection(DRIVER.channel_index("velocity_mps")),))
#: Gains every loop can run, none of them a board's default: each is a binary32 value, sent and read back exact.
GAINS = sb.WriteLoop(kv_nm_per_mps=87.5, ti_s=0.0390625, kp_pos_per_s=17.25, velocity_filter_hz=312.5)


def gains_of(loop: sb.LoopParameters) -> tuple[float, ...]:
    return tuple(getattr(loop, name) for name in sb.WRITE_LOOP_FIELDS)


def test_read_loop_reports_a_cascade_the_loop_can_run(wire):
    """Sections 4.1 and 4.15: READ_LOOP (no body) is answered by LOOP, 24 bytes of six binary32 fields in SI
    units: the gains finite and > 0 (the integral time > 0, +inf for P only), a current loop bandwidth > 0
    (+inf: ideal) and a whole number of delay ticks >= 0; asked again, the same bytes."""
    loop, body = wire.read_loop()
    assert len(body) == 24, body.hex(" ")
    assert struct.unpack("<6f", body) == tuple(loop.values().values())
    assert all(math.isfinite(v) and v > 0 for v in (loop.kv_nm_per_mps, loop.kp_pos_per_s, loop.velocity_filter_hz))
    assert loop.ti_s > 0 and loop.current_loop_hz > 0
    assert loop.delay_ticks >= 0 and loop.delay_ticks == int(loop.delay_ticks)
    assert wire.read_loop()[1] == body


def test_written_gains_read_back_bit_exact_and_outlive_a_run(wire):
    """Sections 4.15 and 4.16: an accepted WRITE_LOOP is ACKed and LOOP then reports the four binary32 values
    bit for bit (LOOP's first 16 bytes are WRITE_LOOP's body), the current loop and the delay as before; a
    WRITE_LOOP while RUNNING is ACKed and runs at once; the gains outlive STOP, CONFIGURE and CLEAR_FAULT."""
    _, before = wire.read_loop()
    written = wire.payload(GAINS)
    wire.send_payload(written)
    assert isinstance(wire.answer_to(written), sb.Ack)
    loop, body = wire.read_loop()
    assert body[:16] == written[4:], (body.hex(" "), written[4:].hex(" "))
    assert body[16:] == before[16:], "WRITE_LOOP changed the current loop or the delay"
    assert gains_of(loop) == gains_of(GAINS)

    wire.configure(HOLD)
    wire.ok(LIMITS)
    wire.excite(0, np.zeros(2000))
    wire.ok(sb.Start(0))
    assert wire.status().state == sb.State.RUNNING
    running = sb.WriteLoop(120.0, math.inf, 12.0, 500.0)  # a P controller: ti_s = +inf
    wire.ok(running)
    assert gains_of(wire.read_loop()[0]) == gains_of(running)
    assert wire.status().state == sb.State.RUNNING, "taking new gains ended the run"
    wire.ok(sb.Stop())
    wire.configure(HOLD)
    wire.ok(sb.ClearFault())
    assert gains_of(wire.read_loop()[0]) == gains_of(running)


@pytest.mark.parametrize(
    "gains",
    [
        sb.WriteLoop(-1.0, 0.05, 20.0, 400.0),
        sb.WriteLoop(0.0, 0.05, 20.0, 400.0),
        sb.WriteLoop(math.nan, 0.05, 20.0, 400.0),
        sb.WriteLoop(math.inf, 0.05, 20.0, 400.0),
        sb.WriteLoop(100.0, 0.0, 20.0, 400.0),
        sb.WriteLoop(100.0, -0.05, 20.0, 400.0),
        sb.WriteLoop(100.0, math.nan, 20.0, 400.0),
        sb.WriteLoop(100.0, 0.05, -20.0, 400.0),
        sb.WriteLoop(100.0, 0.05, 20.0, 0.0),
        sb.WriteLoop(100.0, 0.05, 20.0, math.inf),
    ],
    ids=[
        "kv-negative",
        "kv-0",
        "kv-nan",
        "kv-inf",
        "ti-0",
        "ti-negative",
        "ti-nan",
        "kp-negative",
        "filter-0",
        "filter-inf",
    ],
)
def test_gains_the_loop_cannot_run_are_refused_whole(wire, gains):
    """Section 4.16: NAK BAD_ARGUMENT for a NaN, a gain or cut-off that is not finite and > 0, an integral time
    that is not > 0; LOOP then reads back exactly what it did before (the other three gains of the refused
    frame, valid on their own, are not taken either)."""
    wire.ok(GAINS)
    _, before = wire.read_loop()
    wire.refused(gains, sb.ErrorCode.BAD_ARGUMENT)
    assert wire.read_loop()[1] == before


def test_the_current_loop_and_the_delay_cannot_be_written(wire):
    """Sections 3 and 4.16: WRITE_LOOP has no field for ``current_loop_hz`` and ``delay_ticks``. A frame that
    appends them to the four gains is a version-1 body with bytes after its last field, which the board
    ignores: the gains are taken, the current loop and the delay stay the board's. A body shorter than the
    four gains is refused BAD_LENGTH and changes nothing; LOOP is no request (UNKNOWN_TYPE)."""
    _, before = wire.read_loop()
    board_parts = struct.unpack("<2f", before[16:])
    other = tuple(2.0 * v + 1.0 if math.isfinite(v) else 1000.0 for v in board_parts)
    body = struct.pack("<4f", *gains_of(GAINS)) + struct.pack("<2f", *other)
    payload = header(sb.PROTOCOL_VERSION, sb.MsgType.WRITE_LOOP, wire.next_seq()) + body
    wire.send_payload(payload)
    assert isinstance(wire.answer_to(payload), sb.Ack)
    loop, after = wire.read_loop()
    assert after[16:] == before[16:] and gains_of(loop) == gains_of(GAINS)

    short = header(sb.PROTOCOL_VERSION, sb.MsgType.WRITE_LOOP, wire.next_seq()) + body[:12]
    wire.refused_payload(short, sb.ErrorCode.BAD_LENGTH)
    assert wire.read_loop()[1] == after
    loop_as_request = header(sb.PROTOCOL_VERSION, sb.MsgType.LOOP, wire.next_seq()) + after
    wire.refused_payload(loop_as_request, sb.ErrorCode.UNKNOWN_TYPE)
    assert wire.read_loop()[1] == after
