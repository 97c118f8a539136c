"""Conformance of a board's requests and answers: identity, state machine, argument checks, filter slots.

Sections 4, 5, 9 (limits before START) and 10 of ``drivers/myrio-board/PROTOCOL.md``, checked on the
wire against a freshly powered-up board (conftest.py's ``board``).
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.signal import iirnotch

from conformance.boards import DRIVER
from conformance.wire import hand_frame, header
from hilident.protocol import serial_board as sb

LIMITS = sb.Limits(5.0, 5.0, -1000.0, 1000.0)
EXCITATION = DRIVER.channel_index("excitation")
EXCITATION_ONLY = sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(EXCITATION),))
#: A bypassed slot at power-up: enabled 0, b = (1, 0, 0), a1 = a2 = 0 (section 5, section 10).
IDENTITY_SLOT = struct.pack("<5f", 1.0, 0.0, 0.0, 0.0, 0.0)


def test_identity_is_the_driver_description(board, wire):
    """Section 4.9: IDENTITY reports protocol version 1 and the myrio-board driver's board: loop and
    maximum sample rates, filter slots, excitation buffer and the channels' names and units in board
    order, as ``drivers/myrio-board/driver.toml`` gives them; STATUS reports the same buffer capacity
    (section 4.13)."""
    ident, expected = wire.identify(), board.identity
    assert ident.protocol_version == 1 == expected.protocol_version
    assert (ident.loop_rate_hz, ident.max_sample_rate_hz) == (expected.loop_rate_hz, expected.max_sample_rate_hz)
    assert (ident.filter_slots, ident.excitation_buffer_samples) == (
        expected.filter_slots,
        expected.excitation_buffer_samples,
    )
    assert ident.channels == expected.channels
    assert wire.status().excitation_capacity == expected.excitation_buffer_samples


def test_name_and_firmware_text_are_the_driver_descriptions(board, wire):
    """Section 4.9 (``name``, ``firmware``) and driver.toml (``[driver] name``, ``[board] firmware``): the
    board names itself as the driver it answers for. PROTOCOL.md lists the figures and channels of the
    myrio-board's IDENTITY but not these two texts; driver.toml is the reference here."""
    ident = wire.identify()
    assert (ident.name, ident.firmware) == (board.identity.name, board.identity.firmware)


def test_a_board_powers_up_idle_without_limits_and_with_bypassed_slots(wire):
    """Section 5 (power-up: IDLE, no configuration, no limits, every slot bypassed with identity
    coefficients), 4.13 (counters since power-up), 10: STATUS is IDLE with no fault and zero counters,
    every slot reads back bypassed and b = (1, 0, 0), a = (1, 0, 0); START and EXCITATION are refused with
    BAD_STATE, and a slot past the last is refused with BAD_ARGUMENT."""
    status = wire.status()
    assert (status.state, status.fault) == (sb.State.IDLE, sb.FaultCode.NONE)
    assert (status.excitation_level, status.underruns, status.dropped_blocks) == (0, 0, 0)
    assert (status.samples_produced, status.limit_trips, status.rx_corrupt) == (0, 0, 0)
    for slot in range(DRIVER.filter_slots):
        _, body = wire.read_filter(slot)
        assert body == bytes([slot, 0]) + IDENTITY_SLOT, f"slot {slot} powers up as {body.hex(' ')}"
    wire.refused(sb.ReadFilter(DRIVER.filter_slots), sb.ErrorCode.BAD_ARGUMENT)
    wire.refused(sb.Start(10), sb.ErrorCode.BAD_STATE)
    wire.refused(sb.Excitation(0, np.zeros(4)), sb.ErrorCode.BAD_STATE)
    assert wire.status().state == sb.State.IDLE


def test_requests_are_answered_one_by_one_in_arrival_order(wire):
    """Section 4: "The board handles requests one at a time in arrival order and queues its answers in that
    order": six requests sent in one write get IDENTITY, STATUS, ACK, FILTER, NAK, ACK in that order, the
    ACKs and the NAK naming their own requests."""
    payloads = [
        wire.payload(sb.Identify()),
        wire.payload(sb.StatusRequest()),
        wire.payload(sb.Ping()),
        wire.payload(sb.ReadFilter(2)),
        header(7, sb.MsgType.PING, 0x0A0A),
        wire.payload(sb.Ping()),
    ]
    wire.send_raw(b"".join(hand_frame(p) for p in payloads))
    answers = [wire.reply().msg for _ in payloads]
    assert [type(a) for a in answers] == [sb.Identity, sb.Status, sb.Ack, sb.FilterCoefficients, sb.Nak, sb.Ack]
    assert answers[2] == sb.Ack(struct.unpack_from("<H", payloads[2], 2)[0], sb.MsgType.PING)
    assert answers[3].slot == 2
    assert (answers[4].acked_seq, answers[4].error) == (0x0A0A, sb.ErrorCode.BAD_VERSION)
    assert answers[5] == sb.Ack(struct.unpack_from("<H", payloads[5], 2)[0], sb.MsgType.PING)


def test_the_state_machine_from_idle_through_a_run_and_back(wire):
    """Section 5's table, 4.4, 4.5 and 9 ("START is refused until SET_LIMITS was accepted"), request by
    request: in IDLE, CLEAR_FAULT and STOP (any reason byte) are ACKed and leave it IDLE; CONFIGURE moves to
    CONFIGURED; START is refused BAD_STATE while no limits were loaded; SET_LIMITS, CLEAR_FAULT and STOP are
    ACKed in CONFIGURED; START moves to RUNNING, its ACK before the run's first SAMPLES block; while
    RUNNING, CONFIGURE, START and CLEAR_FAULT are refused BAD_STATE while SET_LIMITS, EXCITATION, the filter
    requests, IDENTIFY, STATUS_REQUEST and PING are carried out; STOP ends the run with the last block
    (FLAG_LAST), EVENT STOPPED (sample_index = samples produced) and the ACK, in that order, and the board
    is CONFIGURED with an empty excitation buffer (section 6)."""
    wire.ok(sb.ClearFault())
    wire.ok(sb.Stop(reason=0xAB))
    assert wire.status().state == sb.State.IDLE
    wire.configure(EXCITATION_ONLY)
    assert wire.status().state == sb.State.CONFIGURED
    nak = wire.refused(sb.Start(0), sb.ErrorCode.BAD_STATE)
    assert wire.status().state == sb.State.CONFIGURED, f"START without limits ({nak.detail!r})"
    wire.ok(LIMITS)
    wire.ok(sb.ClearFault())
    wire.ok(sb.Stop())
    assert wire.status().state == sb.State.CONFIGURED

    wire.excite(0, np.full(2000, 0.01))
    since = len(wire.frames)
    wire.ok(sb.Start(0))
    start_ack = wire.last_reply
    assert wire.status().state == sb.State.RUNNING
    wire.wait_for(lambda: bool(wire.blocks(since)), "sample block")
    assert start_ack is not None and start_ack.order < wire.blocks(since)[0].order, "a block came before START's ACK"
    wire.refused(EXCITATION_ONLY, sb.ErrorCode.BAD_STATE)
    wire.refused(sb.Start(0), sb.ErrorCode.BAD_STATE)
    wire.refused(sb.ClearFault(), sb.ErrorCode.BAD_STATE)
    wire.ok(LIMITS)
    wire.excite(2000, np.full(100, 0.01))
    coefficients = sb.FilterCoefficients(3, False, (0.5, 0.25, 0.125), (1.0, -0.5, 0.25))
    wire.ok(sb.WriteFilter(coefficients))
    assert wire.read_filter(3)[0] == coefficients
    assert isinstance(wire.identify(), sb.Identity)
    wire.ok(sb.Ping())
    assert wire.status().state == sb.State.RUNNING

    before_stop = len(wire.frames)
    wire.ok(sb.Stop())
    ack_order = wire.last_reply.order
    last = wire.last_block(since)
    assert last is not None and last.order < ack_order, "STOP's ACK came before the run's last block"
    stopped = [f for f in wire.stream if f.order >= before_stop and f.type == sb.MsgType.EVENT]
    assert [f.msg.code for f in stopped] == [sb.EventCode.STOPPED]
    assert last.order < stopped[0].order < ack_order, "order: last block, EVENT STOPPED, ACK (section 4.5)"
    assert [b.flags & sb.FLAG_LAST for b in wire.blocks(since)].count(sb.FLAG_LAST) == 1
    samples = [b.msg for b in wire.blocks(since)]
    produced = samples[-1].first_sample + len(samples[-1].data)
    assert stopped[0].msg.sample_index == produced
    status = wire.status()
    assert (status.state, status.fault, status.excitation_level) == (sb.State.CONFIGURED, sb.FaultCode.NONE, 0)
    assert status.samples_produced == produced


@pytest.mark.parametrize(
    "config",
    [
        sb.Configure(0, sb.Mode.TORQUE, 40, (sb.ChannelSelection(1),)),
        sb.Configure(4, sb.Mode.TORQUE, 0, (sb.ChannelSelection(1),)),
        sb.Configure(4, sb.Mode.TORQUE, 4097, (sb.ChannelSelection(1),)),
        sb.Configure(4, sb.Mode.TORQUE, 40, ()),
        sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(1), sb.ChannelSelection(len(DRIVER.channels)))),
        sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(4, sb.Format.I16, 0.0),)),
        sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(4, sb.Format.I32, -1e-7),)),
        sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(4, sb.Format.I32, float("nan")),)),
    ],
    ids=[
        "divider-0",
        "block-0",
        "block-4097",
        "no-channels",
        "channel-past-the-last",
        "i16-scale-0",
        "i32-negative",
        "i32-nan",
    ],
)
def test_configure_arguments_out_of_range_are_refused(wire, config):
    """Section 4.2: NAK BAD_ARGUMENT for a divider of 0, ``block_samples`` outside 1-4096, no channels, a
    channel index past IDENTITY's list, an integer format whose scale is not > 0; the board stays IDLE.
    Values at the bounds are accepted: divider 1 (the loop rate, the maximum sample rate), blocks of 1 and
    4096 samples, an F32 channel with scale 0 (its scale is ignored)."""
    wire.refused(config, sb.ErrorCode.BAD_ARGUMENT)
    assert wire.status().state == sb.State.IDLE
    for fine in (
        sb.Configure(1, sb.Mode.TORQUE, 1, (sb.ChannelSelection(1),)),
        sb.Configure(4, sb.Mode.POSITION, 4096, (sb.ChannelSelection(len(DRIVER.channels) - 1, sb.Format.F32, 0.0),)),
    ):
        wire.ok(fine)
    assert wire.status().state == sb.State.CONFIGURED


def test_limits_must_be_finite_positive_and_a_window(wire):
    """Section 4.3 and 9: SET_LIMITS is NAKed BAD_ARGUMENT unless every value is finite, the torque and
    velocity limits > 0 and ``position_min_m < position_max_m``; a refused SET_LIMITS loads nothing (START
    is still refused BAD_STATE); an accepted one lets START run."""
    nan, inf = float("nan"), float("inf")
    wire.configure(EXCITATION_ONLY)
    for limits in (
        sb.Limits(0.0, 1.0, -1.0, 1.0),
        sb.Limits(-1.0, 1.0, -1.0, 1.0),
        sb.Limits(1.0, 0.0, -1.0, 1.0),
        sb.Limits(1.0, 1.0, 1.0, 1.0),
        sb.Limits(1.0, 1.0, 1.0, -1.0),
        sb.Limits(nan, 1.0, -1.0, 1.0),
        sb.Limits(1.0, inf, -1.0, 1.0),
        sb.Limits(1.0, 1.0, -inf, 1.0),
    ):
        wire.refused(limits, sb.ErrorCode.BAD_ARGUMENT)
    wire.refused(sb.Start(10), sb.ErrorCode.BAD_STATE)
    wire.ok(LIMITS)
    run = wire.play(np.zeros(10))
    assert [e.code for e in run.events] == [sb.EventCode.FINISHED]


# --- filter slots, sections 4.7, 4.8 and 10 --------------------------------------------------------------


def _notch() -> sb.FilterCoefficients:
    b, a = iirnotch(120.0, 4.0, fs=DRIVER.loop_rate_hz)  # designed in float64: the board stores binary32
    return sb.FilterCoefficients(1, True, tuple(b), tuple(a))


def test_a_binary32_biquad_reads_back_bit_exact_enabled_and_bypassed(wire):
    """Sections 4.7, 4.8 and 10: a notch designed in float64 is written as binary32 and read back bit for
    bit (the FILTER body is the WRITE_FILTER body), enabled; written again with ``enabled`` 0 it reads back
    bypassed with the same coefficients; any non-zero ``enabled`` reads back as enabled; the other slots
    keep their power-up contents."""
    notch = _notch()
    written = wire.payload(sb.WriteFilter(notch))
    wire.send_payload(written)
    assert isinstance(wire.answer_to(written), sb.Ack)
    decoded, body = wire.read_filter(1)
    assert body[0] == 1 and body[1] != 0 and body[2:] == written[6:], (body.hex(" "), written[4:].hex(" "))
    assert decoded.b == tuple(sb.float32(x) for x in notch.b)

    bypassed = wire.payload(sb.WriteFilter(sb.FilterCoefficients(1, False, notch.b, notch.a)))
    wire.send_payload(bypassed)
    assert isinstance(wire.answer_to(bypassed), sb.Ack)
    _, body = wire.read_filter(1)
    assert body == bypassed[4:], (body.hex(" "), bypassed[4:].hex(" "))

    flagged = bytearray(written)
    flagged[5] = 7
    wire.send_payload(bytes(flagged))
    assert isinstance(wire.answer_to(bytes(flagged)), sb.Ack)
    decoded, body = wire.read_filter(1)
    assert decoded.enabled and body[2:] == written[6:]
    for slot in set(range(DRIVER.filter_slots)) - {1}:
        assert wire.read_filter(slot)[1] == bytes([slot, 0]) + IDENTITY_SLOT


@pytest.mark.parametrize(
    "a, why",
    [
        ((1.0, 0.0, 1.5), "complex poles outside the unit circle"),
        ((1.0, -1.9, 0.8), "a real pole at 1.27 with |a2| < 1"),
        ((1.0, -2.0, 1.0), "a double pole on the unit circle"),
        ((1.0, 0.0, 1.0 - 1e-9), "stable in float64, a2 = 1 after binary32 rounding"),
    ],
    ids=["outside", "real-pole", "on-the-circle", "rounds-onto-the-circle"],
)
def test_unstable_enabled_coefficients_are_refused_and_the_slot_kept(wire, a, why):
    """Section 10: with ``enabled`` set the board checks the stored binary32 coefficients and refuses with
    NAK BAD_ARGUMENT unless both poles lie strictly inside the unit circle, keeping the slot's previous
    contents; the same coefficients bypassed are stored without the check and read back in binary32."""
    notch = _notch()
    wire.ok(sb.WriteFilter(notch))
    _, kept = wire.read_filter(1)
    wire.refused(sb.WriteFilter(sb.FilterCoefficients(1, True, (1.0, 0.0, 0.0), a)), sb.ErrorCode.BAD_ARGUMENT)
    assert wire.read_filter(1)[1] == kept, f"a refused write ({why}) changed the slot"
    wire.ok(sb.WriteFilter(sb.FilterCoefficients(1, False, (1.0, 0.0, 0.0), a)))
    decoded, _ = wire.read_filter(1)
    assert not decoded.enabled and decoded.a == (1.0, sb.float32(a[1]), sb.float32(a[2]))


def test_filter_slots_out_of_range_or_not_finite_are_refused(wire):
    """Sections 4.7, 4.8 and 10: slot ``filter_slots`` is refused BAD_ARGUMENT for writing and reading;
    NaN or infinite coefficients are refused BAD_ARGUMENT, enabled or not, and leave the slot as it was."""
    slots = DRIVER.filter_slots
    wire.refused(
        sb.WriteFilter(sb.FilterCoefficients(slots, False, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))), sb.ErrorCode.BAD_ARGUMENT
    )
    wire.refused(sb.ReadFilter(slots), sb.ErrorCode.BAD_ARGUMENT)
    wire.refused(sb.ReadFilter(255), sb.ErrorCode.BAD_ARGUMENT)
    for enabled in (True, False):
        for b, a in (((1.0, float("nan"), 0.0), (1.0, 0.0, 0.0)), ((1.0, 0.0, 0.0), (1.0, float("inf"), 0.0))):
            wire.refused(sb.WriteFilter(sb.FilterCoefficients(0, enabled, b, a)), sb.ErrorCode.BAD_ARGUMENT)
    assert wire.read_filter(0)[1] == bytes([0, 0]) + IDENTITY_SLOT
