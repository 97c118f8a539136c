"""Messages of the serial board protocol: layouts, round trips, sample formats, errors."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ProtocolError
from hilident.protocol import serial_board as sb

# --- strategies -----------------------------------------------------------------------------

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFF_FFFF)
# float32 fields round-trip exactly when the value is a float32 to begin with
f32 = st.floats(width=32, allow_nan=False)
short_text = st.text(max_size=40)
formats = st.sampled_from(list(sb.Format))


@st.composite
def channel_selections(draw, min_size=1, max_size=6):
    n = draw(st.integers(min_size, max_size))
    return tuple(
        sb.ChannelSelection(draw(u8), draw(formats), draw(st.floats(2.0**-30, 1024.0, width=32))) for _ in range(n)
    )


@st.composite
def sample_blocks(draw):
    """A channel selection and rows every value of which is exactly representable in it."""
    channels = draw(channel_selections(max_size=4))
    n_rows = draw(st.integers(0, 20))
    rows = np.empty((n_rows, len(channels)))
    for i, c in enumerate(channels):
        if c.format == sb.Format.F32:
            rows[:, i] = draw(st.lists(f32, min_size=n_rows, max_size=n_rows))
        else:
            info = np.iinfo(np.int16 if c.format == sb.Format.I16 else np.int32)
            counts = draw(st.lists(st.integers(int(info.min), int(info.max)), min_size=n_rows, max_size=n_rows))
            rows[:, i] = np.asarray(counts, dtype=float) * c.scale
    return channels, rows


def request_messages():
    return st.one_of(
        st.builds(sb.Identify),
        st.builds(sb.StatusRequest),
        st.builds(sb.ClearFault),
        st.builds(sb.Ping),
        st.builds(sb.Configure, u16, st.sampled_from(list(sb.Mode)), u16, channel_selections(0, 8), formats, f32),
        st.builds(sb.Limits, f32, f32, f32, f32),
        st.builds(sb.Start, u32),
        st.builds(sb.Stop, u8),
        st.builds(sb.ReadFilter, u8),
        st.builds(sb.WriteFilter, filter_coefficients()),
    )


def filter_coefficients():
    return st.builds(
        sb.FilterCoefficients, u8, st.booleans(), st.tuples(f32, f32, f32), st.tuples(st.just(1.0), f32, f32)
    )


def answer_messages():
    return st.one_of(
        st.builds(
            sb.Identity,
            u8,
            short_text,
            short_text,
            f32,
            f32,
            u8,
            u32,
            st.lists(st.builds(sb.ChannelInfo, short_text, short_text), max_size=8).map(tuple),
        ),
        st.builds(sb.Ack, u16, u8),
        st.builds(sb.Nak, u16, u8, st.sampled_from(list(sb.ErrorCode)), short_text),
        st.builds(
            sb.Status,
            st.sampled_from(list(sb.State)),
            st.sampled_from(list(sb.FaultCode)),
            u32,
            u32,
            u32,
            u32,
            u32,
            u32,
            u32,
        ),
        filter_coefficients(),
        st.builds(sb.Event, st.sampled_from(list(sb.EventCode)), u32, f32, short_text),
    )


# --- round trips ----------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(st.one_of(request_messages(), answer_messages()), st.integers(0, 3 * 0xFFFF))
def test_every_fixed_layout_message_round_trips(msg, seq):
    header, back = sb.decode(sb.encode(msg, seq))
    assert back == msg
    assert header.version == sb.PROTOCOL_VERSION
    assert header.seq == seq % 0x10000  # sequence numbers wrap modulo 2**16
    assert sb.MsgType(header.type).name  # a known type


@settings(max_examples=100, deadline=None)
@given(sample_blocks(), u32, u32, u16, u32, u32, u32)
def test_samples_round_trip_in_every_format(block, index, first, flags, consumed, level, underruns):
    channels, rows = block
    msg = sb.Samples(index, first, flags, consumed, level, underruns, rows)
    _, back = sb.decode(sb.encode(msg, 1, sample_channels=channels), sample_channels=channels)
    assert (back.block_index, back.first_sample, back.flags) == (index, first, flags)
    assert (back.excitation_consumed, back.excitation_level, back.underruns) == (consumed, level, underruns)
    assert back.data.shape == rows.shape
    # Integer columns carry counts * scale: exact up to the product's rounding.
    np.testing.assert_allclose(back.data, rows, rtol=1e-12, atol=0)


@settings(deadline=None)
@given(st.lists(f32, max_size=300), u32)
def test_excitation_round_trips_in_f32(values, first):
    msg = sb.Excitation(first, np.asarray(values, dtype=float))
    _, back = sb.decode(sb.encode(msg, 9))
    assert back.first_index == first
    np.testing.assert_array_equal(back.values, msg.values)


@settings(deadline=None)
@given(st.lists(st.integers(-32768, 32767), max_size=100), st.sampled_from([0.5, 0.001, 2.0**-12]))
def test_excitation_round_trips_in_scaled_i16(counts, scale):
    values = np.asarray(counts, dtype=float) * scale
    exc = (sb.Format.I16, scale)
    payload = sb.encode(sb.Excitation(0, values), 1, excitation=exc)
    assert len(payload) == 4 + 6 + 2 * len(values)
    _, back = sb.decode(payload, excitation=exc)
    np.testing.assert_allclose(back.values, values, rtol=1e-12, atol=0)


def test_message_types_split_by_direction():
    requests = {
        sb.MsgType.IDENTIFY,
        sb.MsgType.CONFIGURE,
        sb.MsgType.SET_LIMITS,
        sb.MsgType.START,
        sb.MsgType.STOP,
        sb.MsgType.EXCITATION,
        sb.MsgType.STATUS_REQUEST,
        sb.MsgType.WRITE_FILTER,
        sb.MsgType.READ_FILTER,
        sb.MsgType.CLEAR_FAULT,
        sb.MsgType.PING,
        sb.MsgType.READ_LOOP,
        sb.MsgType.WRITE_LOOP,
    }
    for t in sb.MsgType:
        assert (t < 0x80) == (t in requests), t.name


# --- byte layouts, assembled by hand from PROTOCOL.md ---------------------------------------------


def test_start_payload_layout():
    assert sb.encode(sb.Start(4000), 7) == bytes([0x01, 0x04, 0x07, 0x00, 0xA0, 0x0F, 0x00, 0x00])


def test_configure_layout_by_offsets():
    msg = sb.Configure(
        4, sb.Mode.TORQUE_INJECTION, 40, (sb.ChannelSelection(1), sb.ChannelSelection(4, sb.Format.I32, 1e-7))
    )
    p = sb.encode(msg, 0x1234)
    assert p[:4] == bytes([1, 0x02, 0x34, 0x12])
    body = p[4:]
    assert len(body) == 11 + 6 * 2
    assert int.from_bytes(body[0:2], "little") == 4  # sample_divider
    assert body[2] == 1  # mode
    assert int.from_bytes(body[3:5], "little") == 40  # block_samples
    assert body[5] == 0  # excitation_format F32
    assert struct.unpack_from("<f", body, 6)[0] == 1.0  # excitation_scale
    assert body[10] == 2  # channel count
    assert body[11:13] == bytes([1, 0]) and struct.unpack_from("<f", body, 13)[0] == 1.0
    assert body[17:19] == bytes([4, 2]) and struct.unpack_from("<f", body, 19)[0] == np.float32(1e-7)


def test_samples_header_layout_by_offsets():
    channels = (sb.ChannelSelection(0), sb.ChannelSelection(1, sb.Format.I16, 0.5))
    rows = np.array([[1.5, 2.0], [-0.25, -3.5]])
    msg = sb.Samples(0x01020304, 77, sb.FLAG_LAST | sb.FLAG_UNDERRUN, 500, 12, 3, rows)
    p = sb.encode(msg, 2, sample_channels=channels)
    body = p[4:]
    head = struct.unpack_from("<IIHHIII", body)
    assert head == (0x01020304, 77, 2, 0x000A, 500, 12, 3)
    assert len(body) == 24 + 2 * 6
    # row-major, channels in selection order: f32 then i16 counts
    assert struct.unpack_from("<fh", body, 24) == (1.5, 4)
    assert struct.unpack_from("<fh", body, 30) == (-0.25, -7)


def test_status_decodes_from_hand_assembled_bytes():
    body = struct.pack("<BHIIIIIII", 3, 1, 10, 4096, 5, 6, 7000, 1, 2)
    _, msg = sb.decode(bytes([1, 0x85, 9, 0]) + body)
    assert msg == sb.Status(sb.State.FAULT, sb.FaultCode.TORQUE_LIMIT, 10, 4096, 5, 6, 7000, 1, 2)
    assert len(body) == 31


def test_identity_and_strings_are_length_prefixed_utf8():
    ident = sb.Identity(1, "bänk", "fw 1", 4000.0, 2000.0, 4, 4096, (sb.ChannelInfo("x", "m"),))
    body = sb.encode(ident, 1)[4:]
    assert body[0] == 1 and struct.unpack_from("<ffBI", body, 1) == (4000.0, 2000.0, 4, 4096)
    assert body[14] == len("bänk".encode()) == 5 and body[15:20] == "bänk".encode()
    assert body[20:25] == b"\x04fw 1" and body[25] == 1 and body[26:30] == b"\x01x\x01m"


def test_long_strings_are_cut_at_255_bytes():
    _, msg = sb.decode(sb.encode(sb.Event(sb.EventCode.FAULT, 0, 0.0, "x" * 400), 1))
    assert msg.message == "x" * 255


def test_filter_body_carries_a1_a2_only():
    c = sb.FilterCoefficients(2, True, (0.5, -1.0, 0.25), (1.0, -0.5, 0.125))
    body = sb.encode(sb.WriteFilter(c), 1)[4:]
    assert body == struct.pack("<BB5f", 2, 1, 0.5, -1.0, 0.25, -0.5, 0.125)
    _, back = sb.decode(bytes([1, 0x86, 0, 0]) + body)
    assert back == c and back.a[0] == 1.0


# --- scaled integer formats ----------------------------------------------------------------------


@settings(deadline=None)
@given(st.floats(-1e3, 1e3), st.sampled_from([1e-3, 0.5, 1e-7]), st.sampled_from([sb.Format.I16, sb.Format.I32]))
def test_scaled_integers_quantise_to_the_nearest_count(x, scale, fmt):
    raw, clipped = sb.pack_values(np.array([x]), fmt, scale)
    back = sb.unpack_values(raw, fmt, scale)[0]
    info = np.iinfo(np.int16 if fmt == sb.Format.I16 else np.int32)
    if info.min <= round(x / scale) <= info.max:
        assert not clipped
        assert abs(back - x) <= scale / 2 * (1 + 1e-9)
    else:
        assert clipped
        assert back == pytest.approx((info.max if x > 0 else info.min) * scale)


def test_quantisation_rounds_half_to_even():
    raw, clipped = sb.pack_values(np.array([0.5, 1.5, 2.5, -0.5, -1.5]) * 0.25, sb.Format.I16, 0.25)
    assert np.frombuffer(raw, "<i2").tolist() == [0, 2, 2, 0, -2]
    assert not clipped


@pytest.mark.parametrize("fmt, lo, hi", [(sb.Format.I16, -32768, 32767), (sb.Format.I32, -(2**31), 2**31 - 1)])
def test_overflow_saturates_and_sets_the_clipped_flag(fmt, lo, hi):
    scale = 0.01
    # the extremes themselves fit
    raw, clipped = sb.pack_values(np.array([lo, hi]) * scale, fmt, scale)
    assert not clipped
    # one count beyond either end does not
    for beyond, edge in ((hi + 1, hi), (lo - 1, lo)):
        raw, clipped = sb.pack_values(np.array([0.0, beyond * scale]), fmt, scale)
        assert clipped
        assert sb.unpack_values(raw, fmt, scale)[1] == pytest.approx(edge * scale)
    raw, clipped = sb.pack_values(np.array([math.inf]), fmt, scale)
    assert clipped and sb.unpack_values(raw, fmt, scale)[0] == pytest.approx(hi * scale)


def test_clipped_sample_block_is_flagged_by_pack_rows_per_channel():
    channels = (sb.ChannelSelection(0, sb.Format.F32), sb.ChannelSelection(1, sb.Format.I16, 1e-3))
    _, clipped = sb.pack_rows(np.array([[1e30, 1.0]]), channels)  # huge f32 is not "clipped"
    assert not clipped
    _, clipped = sb.pack_rows(np.array([[0.0, 40.0]]), channels)  # 40000 counts > 32767
    assert clipped


def test_nan_survives_f32_and_becomes_zero_in_integer_formats():
    channels = (sb.ChannelSelection(0, sb.Format.F32), sb.ChannelSelection(1, sb.Format.I32, 1e-6))
    rows = np.array([[math.nan, math.nan], [1.0, 1.0]])
    msg = sb.Samples(0, 0, 0, 0, 0, 0, rows)
    _, back = sb.decode(sb.encode(msg, 1, sample_channels=channels), sample_channels=channels)
    assert math.isnan(back.data[0, 0]) and back.data[1, 0] == 1.0
    assert back.data[0, 1] == 0.0  # an integer has no NaN: sent as 0 counts
    assert back.data[1, 1] == pytest.approx(1.0)


def test_f32_channels_ignore_their_scale():
    channels = (sb.ChannelSelection(0, sb.Format.F32, 1e-3),)
    raw, _ = sb.pack_rows(np.array([[2.5]]), channels)
    assert struct.unpack("<f", raw) == (2.5,)
    assert sb.unpack_rows(raw, channels)[0, 0] == 2.5


# --- errors ------------------------------------------------------------------------------------------


def test_bad_version_raises():
    payload = bytearray(sb.encode(sb.Ping(), 1))
    payload[0] = 2
    with pytest.raises(ProtocolError, match="version 2"):
        sb.decode(bytes(payload))


@pytest.mark.parametrize("kind", [0x00, 0x0E, 0x7F, 0x80, 0x89, 0xFF])
def test_unknown_type_raises(kind):
    with pytest.raises(ProtocolError, match=f"0x{kind:02x}"):
        sb.decode(bytes([1, kind, 0, 0]))


def test_payload_shorter_than_the_header_raises():
    with pytest.raises(ProtocolError, match="shorter than the header"):
        sb.decode(b"\x01\x04\x00")


@pytest.mark.parametrize(
    "msg",
    [
        sb.Start(5),
        sb.Stop(1),
        sb.ReadFilter(0),
        sb.Limits(1.0, 1.0, -1.0, 1.0),
        sb.Ack(1, 2),
        sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(1),)),
        sb.Status(sb.State.IDLE, sb.FaultCode.NONE, 0, 0, 0, 0, 0, 0, 0),
        sb.WriteFilter(sb.FilterCoefficients(0, True, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))),
        sb.Event(sb.EventCode.FINISHED, 0, 0.0, "done"),
        sb.Identity(1, "b", "f", 1.0, 1.0, 1, 1, (sb.ChannelInfo("x", "m"),)),
    ],
)
def test_every_truncation_of_a_body_raises(msg):
    payload = sb.encode(msg, 3)
    for cut in range(4, len(payload)):
        with pytest.raises(ProtocolError):
            sb.decode(payload[:cut])


def test_samples_with_the_wrong_row_count_raise():
    channels = (sb.ChannelSelection(0),)
    payload = sb.encode(sb.Samples(0, 0, 0, 0, 0, 0, np.ones((3, 1))), 1, sample_channels=channels)
    with pytest.raises(ProtocolError, match="announces 3 rows but carries 2"):
        sb.decode(payload[:-4], sample_channels=channels)
    with pytest.raises(ProtocolError, match="whole number"):
        sb.decode(payload[:-1], sample_channels=channels)


def test_excitation_with_the_wrong_value_count_raises():
    payload = sb.encode(sb.Excitation(0, np.ones(5)), 1)
    with pytest.raises(ProtocolError, match="announces 5 values but carries 4"):
        sb.decode(payload[:-4])


@pytest.mark.parametrize("field, offset", [("mode", 2), ("excitation_format", 5), ("channel format", 12)])
def test_out_of_range_enum_fields_raise(field, offset):
    payload = bytearray(sb.encode(sb.Configure(4, sb.Mode.TORQUE, 40, (sb.ChannelSelection(1),)), 1))
    payload[4 + offset] = 0x7E
    with pytest.raises(ProtocolError, match="unknown"):
        sb.decode(bytes(payload))


def test_unknown_event_state_and_error_codes_raise():
    with pytest.raises(ProtocolError, match="event code"):
        sb.decode(bytes([1, 0x87, 0, 0]) + struct.pack("<BIf", 99, 0, 0.0) + b"\x00")
    with pytest.raises(ProtocolError, match="state"):
        sb.decode(bytes([1, 0x85, 0, 0]) + struct.pack("<BHIIIIIII", 9, 0, 0, 0, 0, 0, 0, 0, 0))
    with pytest.raises(ProtocolError, match="error code"):
        sb.decode(bytes([1, 0x83, 0, 0]) + struct.pack("<HBB", 1, 1, 99) + b"\x00")


def test_encode_rejects_non_messages():
    with pytest.raises(TypeError):
        sb.encode(object(), 1)


def test_samples_before_any_channel_selection_raise_a_protocol_error():
    # What a host sees when it connects to a board still streaming a killed session's run.
    channels = (sb.ChannelSelection(0), sb.ChannelSelection(1, sb.Format.I16, 0.5))
    payload = sb.encode(sb.Samples(9, 40, 0, 0, 0, 0, np.ones((4, 2))), 3, sample_channels=channels)
    with pytest.raises(ProtocolError, match="SAMPLES block 9 arrived before any channel selection"):
        sb.decode(payload)
    with pytest.raises(ProtocolError, match="without a channel selection"):
        sb.unpack_rows(b"\x00" * 8, ())


_SELECTIONS = st.lists(
    st.builds(sb.ChannelSelection, st.integers(0, 6), st.sampled_from(list(sb.Format)), st.floats(1e-6, 1.0)),
    max_size=4,
).map(tuple)


@settings(max_examples=400, deadline=None)
@given(kind=st.sampled_from([int(t) for t in sb.MsgType]), body=st.binary(max_size=80), channels=_SELECTIONS)
def test_any_payload_of_a_known_type_decodes_or_raises_a_protocol_error(kind, body, channels):
    # what a host may receive from a board it does not know, a damaged line or an earlier session
    payload = bytes([sb.PROTOCOL_VERSION, kind, 1, 0]) + body
    try:
        sb.decode(payload, sample_channels=channels)
    except ProtocolError:
        pass
