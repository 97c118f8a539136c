"""READ_LOOP, WRITE_LOOP and LOOP: byte layouts assembled by hand from PROTOCOL.md sections 4.15 and 4.16."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ProtocolError
from hilident.protocol import serial_board as sb
from hilident.protocol.loop_parameters import GAINS, PARAMETERS

f32 = st.floats(width=32)  # NaN and the infinities included: the codec carries what the board judges


def test_the_fields_are_the_cascades_parameters_in_the_documents_order():
    assert sb.LOOP_FIELDS == tuple(PARAMETERS)
    assert sb.WRITE_LOOP_FIELDS == GAINS  # the board has no feed-forward terms


def test_read_loop_is_an_empty_request():
    assert sb.encode(sb.ReadLoop(), 0x1234) == bytes([0x01, 0x0C, 0x34, 0x12])
    assert sb.decode(bytes([0x01, 0x0C, 0x34, 0x12]))[1] == sb.ReadLoop()


def test_write_loop_is_four_binary32_gains():
    payload = sb.encode(sb.WriteLoop(100.0, math.inf, 20.0, 400.0), 5)
    assert payload == bytes([0x01, 0x0D, 0x05, 0x00]) + struct.pack("<4f", 100.0, math.inf, 20.0, 400.0)
    assert len(payload) == 4 + 16


def test_loop_is_six_binary32_parameters_in_order():
    loop = sb.LoopParameters(100.0, 0.05, 20.0, 400.0, math.inf, 1.0)
    payload = sb.encode(loop, 9)
    assert payload[:4] == bytes([0x01, 0x88, 0x09, 0x00])
    assert struct.unpack("<6f", payload[4:]) == (100.0, sb.float32(0.05), 20.0, 400.0, math.inf, 1.0)
    assert list(sb.decode(payload)[1].values()) == list(PARAMETERS)


@settings(max_examples=100, deadline=None)
@given(st.tuples(f32, f32, f32, f32), st.tuples(f32, f32), st.integers(0, 0xFFFF))
def test_the_loop_messages_round_trip_bit_for_bit(gains, board, seq):
    for msg in (sb.WriteLoop(*gains), sb.LoopParameters(*gains, *board)):
        payload = sb.encode(msg, seq)
        again = sb.encode(sb.decode(payload)[1], seq)
        assert again == payload  # NaN != NaN: compared as bytes


@pytest.mark.parametrize("kind, size", [(sb.MsgType.WRITE_LOOP, 16), (sb.MsgType.LOOP, 24)])
def test_a_short_body_is_refused(kind, size):
    with pytest.raises(ProtocolError, match="body too short"):
        sb.decode(bytes([0x01, kind, 1, 0]) + bytes(size - 1))
