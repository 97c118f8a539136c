"""Serial framing: COBS + CRC-32 + zero delimiter, and the incremental decoder."""

from __future__ import annotations

import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.protocol.framing import CRC_BYTES, MAX_FRAME_BYTES, FrameDecoder, encode_frame

payloads = st.binary(min_size=1, max_size=300)


def reference_cobs(data: bytes) -> bytes:
    """Consistent-overhead byte stuffing written out from its definition (no delimiter).

    Each run of non-zero bytes is sent behind a code byte of its length + 1; a run
    of 254 bytes is cut with code 0xFF and continues without an implied zero. Data
    that ends right after such a full run needs no further (empty) block.
    """
    out = bytearray()
    block = bytearray()
    after_full_run = False
    for byte in data:
        after_full_run = False
        if byte == 0:
            out += bytes([len(block) + 1]) + block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:
                out += b"\xff" + block
                block.clear()
                after_full_run = True
    if not after_full_run:
        out += bytes([len(block) + 1]) + block
    return bytes(out)


def split_at(data: bytes, cuts: list[int]) -> list[bytes]:
    edges = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    return [data[a:b] for a, b in zip(edges[:-1], edges[1:], strict=True)]


def feed_all(decoder: FrameDecoder, chunks) -> list[bytes]:
    out = []
    for chunk in chunks:
        out += decoder.feed(chunk)
    return out


def test_crc_is_ieee_crc32_little_endian_behind_the_payload():
    # "123456789" is the standard check string of CRC-32/IEEE: check value 0xCBF43926.
    payload = b"123456789"
    frame = encode_frame(payload)
    assert frame == reference_cobs(payload + bytes([0x26, 0x39, 0xF4, 0xCB])) + b"\x00"


@pytest.mark.parametrize(
    "payload, frame",
    [
        # PROTOCOL.md section 12: START n_samples=4000, host seq 7, and the board's ACK.
        ("01 04 07 00 A0 0F 00 00", "04 01 04 07 03 A0 0F 01 05 64 95 F5 06 00"),
        ("01 82 03 00 07 00 04", "04 01 82 03 02 07 06 04 55 C9 E1 2D 00"),
    ],
)
def test_worked_examples_of_the_specification(payload, frame):
    payload, frame = bytes.fromhex(payload), bytes.fromhex(frame)
    assert encode_frame(payload) == frame
    assert FrameDecoder().feed(frame) == [payload]


@pytest.mark.parametrize(
    "data, encoded",
    [
        # the textbook examples of COBS (Cheshire and Baker)
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255))),
        (bytes(range(0, 255)), b"\x01\xff" + bytes(range(1, 255))),
        (bytes(range(1, 256)), b"\xff" + bytes(range(1, 255)) + b"\x02\xff"),
    ],
)
def test_reference_cobs_matches_the_textbook(data, encoded):
    assert reference_cobs(data) == encoded


def test_frame_ending_in_a_full_run_gets_no_empty_block():
    # 250 payload bytes + 4 CRC bytes, all non-zero: exactly one full 254-byte run.
    for seed in range(100):
        payload = bytes((seed + 7 * i) % 255 + 1 for i in range(250))
        crc = zlib.crc32(payload).to_bytes(4, "little")
        if 0 not in crc:
            break
    assert encode_frame(payload) == b"\xff" + payload + crc + b"\x00"


@settings(deadline=None)
@given(payloads)
def test_frame_matches_reference_cobs_and_has_a_single_zero_at_the_end(payload):
    frame = encode_frame(payload)
    assert frame[-1:] == b"\x00"
    assert 0 not in frame[:-1]
    crc = zlib.crc32(payload).to_bytes(4, "little")
    assert frame == reference_cobs(payload + crc) + b"\x00"


@settings(max_examples=150, deadline=None)
@given(st.lists(payloads, min_size=1, max_size=8), st.lists(st.integers(0, 10_000), max_size=30))
def test_round_trip_through_arbitrary_chunking(messages, cuts):
    wire = b"".join(encode_frame(m) for m in messages)
    dec = FrameDecoder()
    assert feed_all(dec, split_at(wire, cuts)) == messages
    assert dec.stats.frames == len(messages)
    assert dec.stats.corrupt == 0 and dec.stats.oversize == 0
    assert dec.stats.bytes_in == len(wire)


def test_byte_by_byte_feeding():
    messages = [b"\x00\x00\x00", b"abc", bytes(range(256))]
    wire = b"".join(encode_frame(m) for m in messages)
    dec = FrameDecoder()
    assert feed_all(dec, [wire[i : i + 1] for i in range(len(wire))]) == messages


def test_back_to_back_delimiters_are_idle_filler_not_errors():
    dec = FrameDecoder()
    wire = b"\x00\x00" + encode_frame(b"one") + b"\x00\x00\x00" + encode_frame(b"two")
    assert dec.feed(wire) == [b"one", b"two"]
    assert dec.stats.corrupt == 0


@settings(deadline=None)
@given(st.binary(min_size=1, max_size=200), payloads, st.lists(st.integers(0, 1000), max_size=10))
def test_resynchronises_at_the_next_delimiter_after_garbage(garbage, payload, cuts):
    # Garbage (possibly containing zeros) then a delimiter: everything after it decodes.
    wire = garbage + b"\x00" + encode_frame(payload) + encode_frame(payload[::-1])
    dec = FrameDecoder()
    got = feed_all(dec, split_at(wire, cuts))
    assert got[-2:] == [payload, payload[::-1]]
    # Garbage can only produce rejected frames (a valid CRC by chance is not expected here).
    assert dec.stats.frames == 2
    assert dec.stats.corrupt == sum(1 for run in garbage.split(b"\x00") if run)


@settings(deadline=None)
@given(st.lists(payloads, min_size=3, max_size=3), st.integers(0, 10_000), st.integers(0, 7))
def test_corrupted_byte_is_counted_and_the_next_frame_still_decodes(messages, where, bit):
    frames = [bytearray(encode_frame(m)) for m in messages]
    victim = frames[1]
    i = where % (len(victim) - 1)  # any byte but the delimiter
    victim[i] ^= 1 << bit
    if victim[i] == 0:
        victim[i] = 0x55  # keep the frame in one piece: damage, not a split
    dec = FrameDecoder()
    got = dec.feed(b"".join(bytes(f) for f in frames))
    assert got == [messages[0], messages[2]]
    assert dec.stats.corrupt == 1
    assert dec.stats.frames == 2


@settings(deadline=None)
@given(payloads, payloads, st.integers(1, 10_000))
def test_truncated_frame_is_rejected_and_later_frames_decode(first, second, cut):
    frame = encode_frame(first)
    keep = cut % (len(frame) - 1)  # lose at least one byte before the delimiter
    dec = FrameDecoder()
    # Truncated but delimited (bytes lost in the middle of the line): one corrupt frame.
    assert dec.feed(frame[:keep] + b"\x00" + encode_frame(second)) == [second]
    assert dec.stats.corrupt == (1 if keep else 0)
    # Truncated without its delimiter: it swallows the next frame; the one after decodes.
    dec = FrameDecoder()
    got = dec.feed(frame[:keep] + encode_frame(second) + encode_frame(first))
    assert got[-1] == first
    assert dec.stats.frames + dec.stats.corrupt == 2


def test_frame_shorter_than_its_crc_is_corrupt():
    dec = FrameDecoder()
    assert dec.feed(b"\x01\x00" + b"\x03ab\x00") == []
    assert dec.stats.corrupt == 2
    # An empty payload cannot be told from line noise: it is rejected too.
    assert dec.feed(encode_frame(b"")) == []
    assert dec.stats.corrupt == 3


def _payload_with_encoded_length(n_encoded: int) -> bytes:
    # COBS adds about one byte per 254; a zero byte here and there shifts its block
    # boundaries, so search a few nearby lengths and zero positions for an exact fit.
    estimate = n_encoded * 254 // 255 - CRC_BYTES
    for n in range(estimate - 8, estimate + 8):
        for zero_at in (None, 0, 100, 200):
            payload = bytearray(b"\x01" * n)
            if zero_at is not None:
                payload[zero_at] = 0
            if len(encode_frame(bytes(payload))) - 1 == n_encoded:
                return bytes(payload)
    raise AssertionError(f"no payload encodes to {n_encoded} bytes")


def test_frame_of_exactly_the_maximum_length_is_accepted():
    payload = _payload_with_encoded_length(MAX_FRAME_BYTES)
    frame = encode_frame(payload)
    dec = FrameDecoder()
    chunks = [frame[i : i + 4096] for i in range(0, len(frame), 4096)]
    assert feed_all(dec, chunks) == [payload]
    assert dec.stats.oversize == 0


def test_oversize_run_is_discarded_counted_and_the_decoder_recovers():
    dec = FrameDecoder()
    noise = b"\x01" * 4096
    for _ in range(MAX_FRAME_BYTES // len(noise) + 2):
        assert dec.feed(noise) == []
    assert dec.stats.oversize >= 1
    assert len(dec._buffer) <= MAX_FRAME_BYTES  # memory stays bounded without a delimiter
    # The tail of the overlong run ends at the next delimiter (one more rejected frame),
    # and the frame after it decodes.
    assert dec.feed(b"\x00" + encode_frame(b"after")) == [b"after"]
    assert dec.stats.frames == 1


def test_overlong_frame_inside_one_chunk_is_rejected():
    payload = _payload_with_encoded_length(MAX_FRAME_BYTES + 1)
    frame = encode_frame(payload)
    dec = FrameDecoder()
    assert dec.feed(frame + encode_frame(b"next")) == [b"next"]
    assert dec.stats.corrupt == 1
