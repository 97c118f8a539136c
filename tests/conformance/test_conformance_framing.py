"""Conformance of a board's byte layer: framing, payload header and malformed requests.

Sections 2, 3, 4.11, 11.1 and 12 of ``drivers/myrio-board/PROTOCOL.md``. The frames these checks get
wrong on purpose are built here byte by byte (:mod:`conformance.wire`), not with the host's codec, and
every frame the board sends is unpacked by the same independent code, so a framing bug the host and a
board share cannot pass. The last check proves it: a twin that sends its CRC in the other byte order, or
that delivers frames whose CRC does not match, fails these checks.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from cobs import cobs

from conformance.boards import python_twin
from conformance.wire import (
    MAX_FRAME_BYTES,
    cobs_stuff,
    cobs_unstuff,
    crc32_ieee,
    crc_le,
    hand_frame,
    header,
    unframe,
)
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame

PING = sb.MsgType.PING
#: The worked example of PROTOCOL.md section 12: the host's START of 4000 samples, message 7 ...
EXAMPLE_START_PAYLOAD = bytes.fromhex("01 04 07 00 A0 0F 00 00")
EXAMPLE_START_FRAME = bytes.fromhex("04 01 04 07 03 A0 0F 01 05 64 95 F5 06 00")
#: ... and the board's ACK of it, its own message 3.
EXAMPLE_ACK_PAYLOAD = bytes.fromhex("01 82 03 00 07 00 04")
EXAMPLE_ACK_FRAME = bytes.fromhex("04 01 82 03 02 07 06 04 55 C9 E1 2D 00")

LIMITS = sb.Limits(5.0, 5.0, -1000.0, 1000.0)
EXCITATION_ONLY = sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(1),))


def ping(seq: int) -> bytes:
    return header(1, PING, seq)


# --- the hand-built framing is PROTOCOL.md's (no board) --------------------------------------------------


def test_the_hand_built_framing_reproduces_protocol_md():
    """Section 2's check value and section 12's frames come out of :mod:`conformance.wire` byte for byte,
    and its stuffing agrees with the host's on payloads around the 254-byte run boundary: the frames the
    checks below build by hand are the protocol's."""
    assert crc32_ieee(b"123456789") == 0xCBF43926
    assert crc_le(b"123456789") == bytes.fromhex("26 39 F4 CB")
    assert hand_frame(EXAMPLE_START_PAYLOAD) == EXAMPLE_START_FRAME
    assert hand_frame(EXAMPLE_ACK_PAYLOAD) == EXAMPLE_ACK_FRAME
    assert unframe(EXAMPLE_ACK_FRAME[:-1]) == EXAMPLE_ACK_PAYLOAD
    rng = np.random.default_rng(31)
    for n in (1, 4, 253, 254, 255, 507, 508, 509, 1000):
        for zeros in (0.0, 0.01, 0.5):
            data = rng.integers(1, 256, n, dtype=np.uint8)
            data[rng.random(n) < zeros] = 0
            payload = bytes(data)
            assert hand_frame(payload) == encode_frame(payload), (n, zeros)
            assert cobs_stuff(payload) == cobs.encode(payload)
            assert cobs_unstuff(cobs_stuff(payload)) == payload
    with pytest.raises(AssertionError, match="CRC"):
        unframe(hand_frame(EXAMPLE_ACK_PAYLOAD, crc=crc_le(EXAMPLE_ACK_PAYLOAD)[::-1])[:-1])


# --- framing, section 2 -------------------------------------------------------------------------------------


def test_the_boards_frames_are_cobs_of_payload_and_little_endian_crc(board):
    """Section 2 (framing), 3 (header), 4.9-4.13 (layouts): each answer to a hand-built request is exactly
    ``COBS(payload ‖ CRC32_LE(payload)) ‖ 0x00`` as section 2 stuffs it, its header is version 1 with a
    board -> host type, its fixed-layout body has no byte more than its layout, and the board numbers its
    messages one apart."""
    wire = board.connect()
    requests = [
        (ping(0x1234), sb.MsgType.ACK, 3),
        (header(1, sb.MsgType.STATUS_REQUEST, 0x1235), sb.MsgType.STATUS, 31),
        (header(1, sb.MsgType.READ_FILTER, 0x1236) + b"\x00", sb.MsgType.FILTER, 22),
        (header(1, sb.MsgType.START, 0x1237) + struct.pack("<I", 10), sb.MsgType.NAK, None),
        (header(1, sb.MsgType.IDENTIFY, 0x1238), sb.MsgType.IDENTITY, None),
    ]
    for payload, _, _ in requests:
        wire.send_raw(hand_frame(payload))
    answers = [wire.reply() for _ in requests]
    for (request, kind, body), frame in zip(requests, answers, strict=True):
        assert hand_frame(frame.payload) == frame.raw + b"\x00", f"{frame.raw.hex(' ')} is not stuffed as section 2"
        assert frame.payload[0] == 1 and frame.type == kind, (request.hex(" "), frame.payload.hex(" "))
        if body is not None:
            assert len(frame.payload) == 4 + body, f"{sb.MsgType(kind).name} body of {len(frame.payload) - 4} bytes"
    assert answers[0].payload[4:] == bytes.fromhex("34 12") + bytes([PING])  # acked_seq, acked_type
    nak = answers[3].msg
    assert isinstance(nak, sb.Nak) and (nak.acked_seq, nak.acked_type, nak.error) == (
        0x1237,
        sb.MsgType.START,
        sb.ErrorCode.BAD_STATE,
    )
    seqs = [frame.seq for frame in answers]
    assert [(b - a) & 0xFFFF for a, b in zip(seqs, seqs[1:], strict=False)] == [1] * (len(seqs) - 1), seqs


def test_the_worked_example_bytes_are_understood(board):
    """Section 12: the document's own START frame (message 7, 4000 samples) is refused in IDLE with a NAK
    BAD_STATE naming (7, START) (section 5), and accepted once configured and limited, with an ACK of
    (7, START) framed exactly as the document frames the ACK of its example."""
    wire = board.connect()
    wire.send_raw(EXAMPLE_START_FRAME)
    nak = wire.reply().msg
    assert isinstance(nak, sb.Nak) and (nak.acked_seq, nak.acked_type, nak.error) == (7, 4, sb.ErrorCode.BAD_STATE)
    wire.ok(LIMITS)
    wire.configure(EXCITATION_ONLY)
    wire.send_raw(EXAMPLE_START_FRAME)
    ack = wire.reply()
    assert ack.msg == sb.Ack(7, sb.MsgType.START)
    expected = bytes([1, 0x82]) + struct.pack("<H", ack.seq) + bytes.fromhex("07 00 04")
    assert ack.payload == expected and ack.raw + b"\x00" == hand_frame(expected)
    if ack.seq == 3:
        assert ack.raw + b"\x00" == EXAMPLE_ACK_FRAME
    wire.ok(sb.Stop())
    assert wire.status().state == sb.State.CONFIGURED


def test_garbage_before_the_first_frame_costs_one_corrupt_frame(board):
    """Sections 2 (receiving, items 1-3) and 5.1: a board that hears a line mid-stream (the tail of a frame,
    then idle 0x00 filler) drops the damaged candidate, counts it once in STATUS ``rx_corrupt`` and answers
    the next frame. Garbage that runs into a frame without a delimiter loses that frame with it, as one
    corrupt candidate (no answer), and the frame after it is answered; so does a frame whose own delimiter
    was lost, with the frame after it. Idle filler is never counted."""
    wire = board.connect()
    cut = hand_frame(header(1, sb.MsgType.STATUS_REQUEST, 0x4444) + bytes(range(1, 40)))[7:]  # ends in its 0x00
    wire.send_raw(cut + b"\x00\x00\x00" + hand_frame(header(1, sb.MsgType.IDENTIFY, 0x5000)))
    assert isinstance(wire.reply().msg, sb.Identity)
    assert wire.status().rx_corrupt == 1, "a fresh board counts the damaged candidate, and only it"
    wire.send_raw(b"\x13\x37\xc0\xff\xee" + hand_frame(ping(0x5001)) + hand_frame(ping(0x5002)))
    assert wire.reply().msg == sb.Ack(0x5002, PING), "the PING merged with the garbage must be lost unanswered"
    wire.send_raw(hand_frame(ping(0x5003))[:-1] + hand_frame(ping(0x5004)) + hand_frame(ping(0x5005)))
    assert wire.reply().msg == sb.Ack(0x5005, PING), "a frame that lost its delimiter takes the next one with it"
    wire.send_raw(b"\x00" * 8 + hand_frame(ping(0x5006)) + b"\x00" * 3 + hand_frame(ping(0x5007)))
    assert wire.reply().msg == sb.Ack(0x5006, PING)
    assert wire.reply().msg == sb.Ack(0x5007, PING)
    assert wire.status().rx_corrupt == 3


def test_a_frame_with_a_bad_crc_is_dropped_and_counted(board):
    """Section 2 (receiving, item 2): a candidate whose CRC does not match (one bit off, the CRC sent
    big-endian, the CRC of another payload), that is not COBS, or whose body is 4 bytes or shorter is
    rejected: never answered, not even with a NAK (the PING after them gets the next answer), and counted
    in STATUS ``rx_corrupt``. The same PING with its CRC little-endian is answered."""
    wire = board.connect()
    before = wire.status().rx_corrupt
    payload = ping(0x2001)
    good = crc_le(payload)
    assert good != good[::-1]
    rejected = [
        hand_frame(payload, crc=bytes([good[0] ^ 0x01]) + good[1:]),
        hand_frame(payload, crc=good[::-1]),  # big-endian
        hand_frame(payload, crc=crc_le(ping(0x2002))),
        b"\x05\x01\x04\x00",  # a code byte that runs past the candidate
        cobs_stuff(crc_le(b"")) + b"\x00",  # a 4-byte body: the CRC of an empty payload, and no payload
        cobs_stuff(b"\x01\x0b") + b"\x00",  # shorter still
    ]
    wire.send_raw(b"".join(rejected))
    wire.send_raw(hand_frame(ping(0x2003)))
    assert wire.reply().msg == sb.Ack(0x2003, PING), "a rejected frame was answered"
    assert wire.status().rx_corrupt == before + len(rejected)


def test_frames_up_to_the_size_limit_are_taken_and_longer_runs_dropped(board):
    """Section 2 (size; receiving, items 2 and 4) and 3 (bytes after the last field are ignored): a PING
    padded to a stuffed frame of exactly 65 536 bytes is answered; one stuffed byte more and it is
    rejected unanswered; 150 000 bytes without a delimiter are discarded (the board lives on and answers
    the next frame). ``rx_corrupt`` counts the rejected frame."""
    wire = board.connect()
    before = wire.status().rx_corrupt
    fits = _padded_ping(0x3001, MAX_FRAME_BYTES)
    too_long = _padded_ping(0x3002, MAX_FRAME_BYTES + 1)
    assert len(fits) == MAX_FRAME_BYTES + 1 and len(too_long) == MAX_FRAME_BYTES + 2
    wire.send_raw(fits)
    assert wire.reply(timeout=5.0).msg == sb.Ack(0x3001, PING)
    wire.send_raw(too_long)
    for offset in range(0, 150_000, 8192):
        wire.send_raw(b"\xa5" * min(8192, 150_000 - offset))
    wire.send_raw(b"\x00" + hand_frame(ping(0x3003)))
    assert wire.reply(timeout=5.0).msg == sb.Ack(0x3003, PING)
    # the frame one byte too long counts once; the 150 000-byte run is one oversize event per 65 536 bytes,
    # and its remainder one corrupt candidate unless an oversize event took its last byte (section 2, item 4)
    counted = wire.status().rx_corrupt - before
    assert 1 <= counted <= 2 + 3, f"{counted} corrupt frames counted for 2 rejected runs of bytes"


def _padded_ping(seq: int, stuffed_length: int) -> bytes:
    """A PING with non-zero bytes after its header, stuffed to exactly ``stuffed_length`` bytes (the length
    is searched with the ``cobs`` package and zlib for speed; the frame is then built by hand)."""
    for pad in range(stuffed_length - 300, stuffed_length):
        for split in (b"", b"\x00"):  # a zero in the padding moves the 254-byte block boundaries
            payload = ping(seq) + bytes([0x5A]) * (pad // 2) + split + bytes([0x5A]) * (pad - pad // 2)
            if len(cobs.encode(payload + zlib.crc32(payload).to_bytes(4, "little"))) == stuffed_length:
                return hand_frame(payload)
    raise AssertionError(f"no padding gives a {stuffed_length}-byte frame")


# --- payload header and malformed requests, sections 3, 4.11 and 11.1 ------------------------------------------


def test_undecodable_payloads_are_refused_with_their_code_and_counted(board):
    """Sections 3, 4.11 and 11.1: a wrong version is NAKed BAD_VERSION, an unknown type code UNKNOWN_TYPE,
    a payload shorter than the header or a body shorter than its layout BAD_LENGTH; each NAK names the
    request's ``seq`` and ``type`` (0 where the payload is too short to hold them), each such payload counts
    in STATUS ``rx_corrupt``, and none changes the state."""
    wire = board.connect()
    before = wire.status().rx_corrupt
    cases = [
        (header(2, PING, 0x0101), sb.ErrorCode.BAD_VERSION, (0x0101, PING)),
        (header(0, sb.MsgType.IDENTIFY, 0x0102), sb.ErrorCode.BAD_VERSION, (0x0102, sb.MsgType.IDENTIFY)),
        (header(1, 0x0E, 0x0103), sb.ErrorCode.UNKNOWN_TYPE, (0x0103, 0x0E)),
        (header(1, 0x42, 0x0104), sb.ErrorCode.UNKNOWN_TYPE, (0x0104, 0x42)),
        (header(1, 0x00, 0x0105), sb.ErrorCode.UNKNOWN_TYPE, (0x0105, 0x00)),
        (header(1, 0xFF, 0x0106), sb.ErrorCode.UNKNOWN_TYPE, (0x0106, 0xFF)),
        (b"\x01", sb.ErrorCode.BAD_LENGTH, (0, 0)),
        (bytes([1, PING, 0x07]), sb.ErrorCode.BAD_LENGTH, (0, PING)),
        (header(1, sb.MsgType.STOP, 0x0109), sb.ErrorCode.BAD_LENGTH, (0x0109, 5)),
        (header(1, sb.MsgType.SET_LIMITS, 0x010A) + bytes(15), sb.ErrorCode.BAD_LENGTH, (0x010A, 3)),
        (header(1, sb.MsgType.READ_FILTER, 0x010B), sb.ErrorCode.BAD_LENGTH, (0x010B, 9)),
        (header(1, sb.MsgType.WRITE_FILTER, 0x010C) + bytes(21), sb.ErrorCode.BAD_LENGTH, (0x010C, 8)),
        (sb.encode(EXCITATION_ONLY, 0x010D)[:-1], sb.ErrorCode.BAD_LENGTH, (0x010D, 2)),
        (sb.encode(EXCITATION_ONLY, 0x010E)[:-6], sb.ErrorCode.BAD_LENGTH, (0x010E, 2)),  # 1 channel announced, none
    ]
    for payload, error, (seq, kind) in cases:
        wire.send_raw(hand_frame(payload))
        nak = wire.reply().msg
        assert isinstance(nak, sb.Nak), f"{payload.hex(' ')} was answered with {nak}"
        assert (nak.error, nak.acked_seq, nak.acked_type) == (error, seq, kind), f"{payload.hex(' ')}: {nak}"
    status = wire.status()
    assert status.rx_corrupt == before + len(cases)
    assert (status.state, status.fault) == (sb.State.IDLE, sb.FaultCode.NONE)


def test_board_to_host_types_sent_to_the_board_are_unknown_types(board):
    """Section 11.1 (UNKNOWN_TYPE: "a board → host type sent to the board"): every type from 0x81 to 0x88
    sent to the board is refused with UNKNOWN_TYPE, whatever its body: empty, or a well-formed ACK."""
    wire = board.connect()
    well_formed_ack = header(1, sb.MsgType.ACK, 0x0200) + b"\x01\x00\x0b"
    empty_bodies = [header(1, kind, 0x0200 + kind) for kind in range(0x81, 0x89)]
    for payload in [well_formed_ack, *empty_bodies]:
        wire.send_raw(hand_frame(payload))
        nak = wire.reply().msg
        seq, kind = struct.unpack_from("<H", payload, 2)[0], payload[1]
        assert isinstance(nak, sb.Nak) and (nak.acked_seq, nak.acked_type) == (seq, kind), nak
        assert nak.error == sb.ErrorCode.UNKNOWN_TYPE, f"{payload.hex(' ')}: {nak}"


def test_an_unknown_mode_or_format_is_refused_as_undecodable(board):
    """Sections 4.2 ("refused like any undecodable payload") and 11.1 (BAD_LENGTH: "any other undecodable
    field such as an unknown mode or format"): a CONFIGURE with mode 4, an excitation format 3 or a channel
    format 3 is refused with BAD_LENGTH and leaves the board IDLE."""
    wire = board.connect()
    for offset, value in ((2, 4), (5, 3), (12, 3)):  # mode, excitation_format, channel 0's format
        payload = bytearray(wire.payload(EXCITATION_ONLY))
        payload[4 + offset] = value
        nak = wire.refused_payload(bytes(payload), sb.ErrorCode.BAD_LENGTH)
        assert nak.acked_type == sb.MsgType.CONFIGURE
    assert wire.status().state == sb.State.IDLE


def test_bytes_after_the_last_field_are_ignored(board):
    """Section 3: "Bytes after the last field of a fixed-layout body are ignored by version-1 receivers":
    IDENTIFY, PING, READ_FILTER and STOP with bytes appended are carried out as without them."""
    wire = board.connect()
    wire.send_raw(hand_frame(header(1, sb.MsgType.IDENTIFY, 0x0300) + b"\x01\x02\x03"))
    assert isinstance(wire.reply().msg, sb.Identity)
    wire.send_raw(hand_frame(ping(0x0301) + b"\x00\xff"))
    assert wire.reply().msg == sb.Ack(0x0301, PING)
    wire.send_raw(hand_frame(header(1, sb.MsgType.READ_FILTER, 0x0302) + b"\x01\x07\x07"))
    answer = wire.reply().msg
    assert isinstance(answer, sb.FilterCoefficients) and answer.slot == 1
    wire.send_raw(hand_frame(header(1, sb.MsgType.STOP, 0x0303) + b"\x00\x09"))
    assert wire.reply().msg == sb.Ack(0x0303, sb.MsgType.STOP)


def test_the_hosts_numbers_are_echoed_whatever_they_are(board):
    """Section 3 (sequence numbers): the board does not check the host's numbers and echoes them in ACK and
    NAK, across the wrap from 65535 to 0, repeated and out of order; its own numbers go up by one per
    message, modulo 2^16, whatever the host's do."""
    wire = board.connect()
    for seq in (0xFFFE, 0xFFFF, 0x0000, 0x0000, 0x8000, 0x0001):
        assert wire.ok(sb.Ping(), seq=seq) == sb.Ack(seq, PING)
    wire.send_raw(hand_frame(header(9, PING, 0xFFFF)))
    assert wire.reply().msg.acked_seq == 0xFFFF
    seqs = [frame.seq for frame in wire.frames]
    assert all((b - a) & 0xFFFF == 1 for a, b in zip(seqs, seqs[1:], strict=False)), seqs
    assert wire.seq_gaps == 0


# --- the checks bite -------------------------------------------------------------------------------------------


class _BigEndianCrcDecoder(FrameDecoder):
    """A board receiver that expects the CRC big-endian."""

    @staticmethod
    def _check(raw: bytes) -> bytes | None:
        try:
            body = cobs.decode(raw)
        except cobs.DecodeError:
            return None
        if len(body) <= 4 or body[-4:] != crc32_ieee(body[:-4]).to_bytes(4, "big"):
            return None
        return body[:-4]


class _UncheckedCrcDecoder(FrameDecoder):
    """A board receiver that delivers every COBS candidate without looking at its CRC."""

    @staticmethod
    def _check(raw: bytes) -> bytes | None:
        try:
            body = cobs.decode(raw)
        except cobs.DecodeError:
            return None
        return body[:-4] if len(body) > 4 else None


def _big_endian_crc_frame(payload: bytes) -> bytes:
    return cobs.encode(payload + crc32_ieee(payload).to_bytes(4, "big")) + b"\x00"


#: A drift of the twin's framing: the names of :mod:`hilident.emulator.serial.server` replaced, how many of
#: the checks below must notice it (in order), and what their failure says.
DRIFTS = {
    "crc-big-endian-both-ways": (
        {"encode_frame": _big_endian_crc_frame, "FrameDecoder": _BigEndianCrcDecoder},
        4,
        "no reply",  # it takes none of the protocol's frames
    ),
    "crc-sent-big-endian": ({"encode_frame": _big_endian_crc_frame}, 4, "CRC bytes .* are not CRC32_LE"),
    "crc-not-checked": ({"FrameDecoder": _UncheckedCrcDecoder}, 1, "a rejected frame was answered"),
}


@pytest.mark.parametrize("drift", list(DRIFTS))
def test_the_framing_checks_fail_against_a_drifted_board(drift, monkeypatch):
    """A board that drifts from section 2 fails the checks above: the Python twin with its CRC big-endian
    both ways (the drift issue 31 names), big-endian only in what it sends, or with a receiver that ignores
    the CRC, served in this process on TCP. Each check is called directly and must raise the
    AssertionError that names the drift."""
    from hilident.emulator.serial import server

    patches, n, failure = DRIFTS[drift]
    for name, replacement in patches.items():
        monkeypatch.setattr(server, name, replacement)
    checks = [
        test_a_frame_with_a_bad_crc_is_dropped_and_counted,
        test_the_boards_frames_are_cobs_of_payload_and_little_endian_crc,
        test_the_worked_example_bytes_are_understood,
        test_garbage_before_the_first_frame_costs_one_corrupt_frame,
    ][:n]
    for check in checks:
        with python_twin(timeout_s=0.5) as drifted, pytest.raises(AssertionError, match=failure):
            check(drifted)
