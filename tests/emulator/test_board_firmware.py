"""Board firmware driven directly with encoded payloads: the protocol state machine."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import iirnotch, lfilter

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.device import build_drive
from hilident.emulator.serial.firmware import BoardFirmware
from hilident.emulator.serial.server import identity_from_driver
from hilident.protocol import serial_board as sb

CONFIG = """
[limits]
torque_nm = 5.0
velocity_mps = 1.0
position_min_m = -1.0
position_max_m = 1.0

[emulator]
preset = "clean"

[emulator.sensors]
torque_noise_nm = 0.0
"""
FRICTIONLESS = CONFIG + '\n[emulator.friction]\nmodel = "none"\n'

DRIVER = find_driver("myrio-board")
NAMES = [c.name for c in DRIVER.channels]
# excitation, torque command and measured torque, in that order
TORQUE_CHANNELS = tuple(sb.ChannelSelection(NAMES.index(n)) for n in ("excitation", "torque_cmd_nm", "torque_nm"))
EXC, CMD, TRQ = 0, 1, 2
DEFAULT_LIMITS = sb.Limits(5.0, 1.0, -1.0, 1.0)


class Bench:
    """A firmware instance, a host-side sequence counter and the decoded answers."""

    def __init__(
        self, config: str = CONFIG, identity: sb.Identity | None = None, limits: sb.Limits | None = DEFAULT_LIMITS
    ):
        self.drive = build_drive(parse_config(config).emulator, DRIVER)
        self.fw = BoardFirmware(self.drive, identity or identity_from_driver(DRIVER))
        self.seq = 0
        self.channels: tuple[sb.ChannelSelection, ...] = ()
        self.headers: list[sb.Header] = []
        if limits is not None:  # the board refuses to start before it knows its limits
            self.ok(limits)
            self.headers.clear()

    def request(self, msg) -> list:
        """Send one request; return the board's answers (decoded)."""
        self.seq += 1
        return self.raw(sb.encode(msg, self.seq))

    def raw(self, payload: bytes) -> list:
        self.fw.receive(payload)
        return self.drain()

    def drain(self) -> list:
        out = []
        for payload in self.fw.outbox:
            header, msg = sb.decode(payload, sample_channels=self.channels)
            self.headers.append(header)
            out.append(msg)
        self.fw.outbox.clear()
        return out

    def advance(self, n: int) -> list:
        self.fw.advance(n)
        return self.drain()

    def ok(self, msg) -> None:
        answers = self.request(msg)
        assert answers == [sb.Ack(self.seq, sb.encode(msg, 0)[1])], answers

    def refused(self, msg, error: sb.ErrorCode) -> sb.Nak:
        answers = self.request(msg)
        assert len(answers) == 1 and isinstance(answers[0], sb.Nak), answers
        nak = answers[0]
        assert (nak.acked_seq, nak.acked_type, nak.error) == (self.seq, sb.encode(msg, 0)[1], error), nak
        return nak

    def configure(self, divider=4, mode=sb.Mode.TORQUE, block=10, channels=TORQUE_CHANNELS) -> None:
        self.ok(sb.Configure(divider, mode, block, channels))
        self.channels = channels

    def excite(self, first: int, values) -> list:
        return self.request(sb.Excitation(first, np.asarray(values, dtype=float)))

    def status(self) -> sb.Status:
        (answer,) = self.request(sb.StatusRequest())
        return answer


def blocks_of(messages) -> list[sb.Samples]:
    return [m for m in messages if isinstance(m, sb.Samples)]


def events_of(messages) -> list[sb.Event]:
    return [m for m in messages if isinstance(m, sb.Event)]


def rows_of(messages) -> np.ndarray:
    return np.concatenate([b.data for b in blocks_of(messages)])


def f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float32).astype(float)


# --- identify, configure, start ---------------------------------------------------------


def test_identify_answers_what_the_driver_description_says():
    bench = Bench()
    (ident,) = bench.request(sb.Identify())
    assert ident.protocol_version == 1 == DRIVER.protocol_version
    assert (ident.name, ident.firmware) == (DRIVER.name, DRIVER.firmware)
    assert (ident.loop_rate_hz, ident.max_sample_rate_hz) == (DRIVER.loop_rate_hz, DRIVER.max_sample_rate_hz)
    assert (ident.filter_slots, ident.excitation_buffer_samples) == (
        DRIVER.filter_slots,
        DRIVER.excitation_buffer_samples,
    )
    assert [(c.name, c.unit) for c in ident.channels] == [(c.name, c.unit) for c in DRIVER.channels]
    assert bench.fw.state == sb.State.IDLE


def test_board_numbers_its_messages_consecutively():
    bench = Bench()
    for _ in range(5):
        bench.ok(sb.Ping())
    seqs = [h.seq for h in bench.headers]
    assert np.all(np.diff(seqs) == 1)
    assert all(h.version == sb.PROTOCOL_VERSION for h in bench.headers)


def _bad_configures():
    ch = TORQUE_CHANNELS
    return {
        "divider 0": sb.Configure(0, sb.Mode.TORQUE, 10, ch),
        "block 0": sb.Configure(4, sb.Mode.TORQUE, 0, ch),
        "block 4097": sb.Configure(4, sb.Mode.TORQUE, 4097, ch),
        "no channels": sb.Configure(4, sb.Mode.TORQUE, 10, ()),
        "channel out of range": sb.Configure(4, sb.Mode.TORQUE, 10, (sb.ChannelSelection(len(NAMES)),)),
        "i16 without scale": sb.Configure(4, sb.Mode.TORQUE, 10, (sb.ChannelSelection(4, sb.Format.I16, 0.0),)),
        "i32 negative scale": sb.Configure(4, sb.Mode.TORQUE, 10, (sb.ChannelSelection(4, sb.Format.I32, -1e-7),)),
    }


@pytest.mark.parametrize("name", list(_bad_configures()))
def test_configure_validation_naks_and_leaves_the_board_idle(name):
    bench = Bench()
    bench.refused(_bad_configures()[name], sb.ErrorCode.BAD_ARGUMENT)
    assert bench.fw.state == sb.State.IDLE
    bench.refused(sb.Start(10), sb.ErrorCode.BAD_STATE)
    bench.configure()  # the same board accepts a valid one
    assert bench.fw.state == sb.State.CONFIGURED


def test_configure_refuses_a_rate_above_the_boards_maximum():
    ident = dataclasses.replace(identity_from_driver(DRIVER), max_sample_rate_hz=1000.0)
    bench = Bench(identity=ident)
    nak = bench.refused(sb.Configure(2, sb.Mode.TORQUE, 10, TORQUE_CHANNELS), sb.ErrorCode.BAD_ARGUMENT)
    assert "2000" in nak.detail
    bench.configure(divider=4)
    assert bench.fw.sample_rate_hz == 1000.0


def test_undecodable_configure_is_refused():
    bench = Bench()
    payload = bytearray(sb.encode(sb.Configure(4, sb.Mode.TORQUE, 10, TORQUE_CHANNELS), 42))
    payload[4 + 2] = 9  # mode 9 does not exist
    (nak,) = bench.raw(bytes(payload))
    assert isinstance(nak, sb.Nak) and (nak.acked_seq, nak.acked_type) == (42, sb.MsgType.CONFIGURE)
    assert bench.fw.state == sb.State.IDLE and bench.fw.config is None


def test_start_is_refused_before_configure():
    bench = Bench()
    bench.refused(sb.Start(100), sb.ErrorCode.BAD_STATE)
    bench.refused(sb.Excitation(0, np.zeros(4)), sb.ErrorCode.BAD_STATE)
    assert bench.fw.state == sb.State.IDLE
    assert not bench.drive.enabled
    assert bench.advance(10) == []  # nothing runs


def test_configure_start_and_clear_fault_are_refused_while_running():
    bench = Bench()
    bench.configure()
    bench.ok(sb.Start(0))
    assert bench.fw.state == sb.State.RUNNING and bench.drive.enabled
    bench.refused(sb.Configure(4, sb.Mode.TORQUE, 10, TORQUE_CHANNELS), sb.ErrorCode.BAD_STATE)
    bench.refused(sb.Start(0), sb.ErrorCode.BAD_STATE)
    bench.refused(sb.ClearFault(), sb.ErrorCode.BAD_STATE)


@pytest.mark.parametrize(
    "limits",
    [
        sb.Limits(0.0, 1.0, -1.0, 1.0),
        sb.Limits(1.0, -1.0, -1.0, 1.0),
        sb.Limits(1.0, 1.0, 1.0, 1.0),
        sb.Limits(float("nan"), 1.0, -1.0, 1.0),
    ],
)
def test_set_limits_refuses_non_positive_limits_and_empty_windows(limits):
    bench = Bench(limits=None)
    bench.refused(limits, sb.ErrorCode.BAD_ARGUMENT)
    assert bench.drive.torque_limit_nm == np.inf  # unchanged


def test_set_limits_reaches_the_drive():
    bench = Bench()
    bench.ok(sb.Limits(2.5, 0.5, -0.25, 0.75))
    d = bench.drive
    assert (d.torque_limit_nm, d.velocity_limit_mps, d.position_min_m, d.position_max_m) == (2.5, 0.5, -0.25, 0.75)


# --- excitation FIFO ------------------------------------------------------------------------


def test_prefilled_excitation_is_played_sample_by_sample():
    bench = Bench()
    bench.configure(divider=4, block=10)
    x = np.sin(np.arange(50) * 0.3) * 0.8 + 0.1
    assert bench.excite(0, x) == []  # EXCITATION is not acknowledged
    bench.ok(sb.Start(len(x)))
    out = []
    for n in (7, 13, 1, 29, 40):  # the board's clock advances in uneven steps
        out += bench.advance(n)
    blocks = blocks_of(out)
    rows = rows_of(out)
    assert len(rows) == len(x)
    np.testing.assert_array_equal(rows[:, EXC], f32(x))
    # torque mode: the excitation is the torque command, applied as is (no noise, no limit hit)
    np.testing.assert_array_equal(rows[:, CMD], f32(x))
    np.testing.assert_array_equal(rows[:, TRQ], f32(x))
    assert [b.block_index for b in blocks] == list(range(len(blocks)))
    assert [b.first_sample for b in blocks] == [10 * i for i in range(len(blocks))]
    assert all(b.flags == 0 for b in blocks[:-1]) and blocks[-1].flags == sb.FLAG_LAST
    assert (blocks[-1].excitation_consumed, blocks[-1].excitation_level) == (50, 0)
    (finished,) = events_of(out)
    assert (finished.code, finished.sample_index) == (sb.EventCode.FINISHED, 50)
    # every sample is held for `divider` loop ticks
    assert bench.drive.tick == 4 * len(x)
    assert bench.fw.state == sb.State.CONFIGURED and not bench.drive.enabled
    assert bench.advance(10) == []


def test_underrun_plays_zero_is_counted_and_reported_once_per_episode():
    bench = Bench()
    bench.configure(divider=4, block=10)
    x = np.full(25, 0.5)
    bench.excite(0, x)
    bench.ok(sb.Start(0))
    out = bench.advance(20) + bench.advance(15) + bench.advance(5)
    rows = rows_of(out)
    np.testing.assert_array_equal(rows[:25, EXC], 0.5)
    np.testing.assert_array_equal(rows[25:40, EXC], 0.0)
    np.testing.assert_array_equal(rows[25:40, TRQ], 0.0)
    (ev,) = events_of(out)
    assert (ev.code, ev.sample_index) == (sb.EventCode.UNDERRUN, 25)
    blocks = blocks_of(out)
    assert blocks[2].first_sample == 20 and blocks[2].flags & sb.FLAG_UNDERRUN
    assert not blocks[0].flags & sb.FLAG_UNDERRUN and not blocks[1].flags & sb.FLAG_UNDERRUN
    assert blocks[-1].underruns == 15
    assert bench.status().underruns == 15
    # refilled, played without starving, then dry again: a second episode
    bench.excite(25, np.full(20, 0.25))
    out = bench.advance(20) + bench.advance(10)
    (ev,) = events_of(out)
    assert (ev.code, ev.sample_index) == (sb.EventCode.UNDERRUN, 60)
    assert bench.status().underruns == 25


def test_out_of_order_excitation_index_is_refused_and_nothing_stored():
    bench = Bench()
    bench.configure()
    assert bench.excite(0, np.ones(10)) == []
    for wrong in (0, 5, 11, 1000):
        nak = bench.refused(sb.Excitation(wrong, np.ones(3)), sb.ErrorCode.BAD_ARGUMENT)
        assert "expected 10" in nak.detail
    assert bench.status().excitation_level == 10
    assert bench.excite(10, np.ones(3)) == []
    assert bench.status().excitation_level == 13


def test_overflow_is_refused_whole_and_the_ring_wraps_in_order():
    bench = Bench()
    bench.configure(divider=1, block=256)
    capacity = DRIVER.excitation_buffer_samples
    x = np.arange(capacity + 300) * 1e-4  # distinct values, inside the torque limit
    for first in range(0, capacity, 1024):
        assert bench.excite(first, x[first : first + 1024]) == []
    st = bench.status()
    assert (st.excitation_level, st.excitation_capacity) == (capacity, capacity)
    bench.refused(sb.Excitation(capacity, x[capacity : capacity + 1]), sb.ErrorCode.BUFFER_OVERFLOW)
    assert bench.status().excitation_level == capacity
    bench.ok(sb.Start(len(x)))
    out = bench.advance(200)
    # 200 played: 300 do not fit yet (refused whole), 200 do
    bench.refused(sb.Excitation(capacity, x[capacity:]), sb.ErrorCode.BUFFER_OVERFLOW)
    assert bench.excite(capacity, x[capacity : capacity + 200]) == []
    out += bench.advance(100)
    assert bench.excite(capacity + 200, x[capacity + 200 :]) == []
    out += bench.advance(len(x))
    rows = rows_of(out)
    np.testing.assert_array_equal(rows[:, EXC], f32(x))
    assert bench.status().underruns == 0


def test_new_configuration_empties_the_excitation_buffer():
    bench = Bench()
    bench.configure()
    bench.excite(0, np.ones(100))
    bench.configure()
    assert bench.status().excitation_level == 0
    assert bench.excite(0, np.ones(5)) == []


# --- filter slots ---------------------------------------------------------------------------


def test_filter_write_read_back_is_real32_and_is_what_runs():
    bench = Bench()
    b, a = iirnotch(70.0, 3.0, fs=DRIVER.loop_rate_hz)
    bench.ok(sb.WriteFilter(sb.FilterCoefficients(1, True, tuple(b), tuple(a))))
    (read,) = bench.request(sb.ReadFilter(1))
    assert isinstance(read, sb.FilterCoefficients)
    assert read.slot == 1 and read.enabled
    np.testing.assert_array_equal(read.b, f32(b))
    np.testing.assert_array_equal(read.a, f32(a))
    assert not np.array_equal(read.b, b)  # the notch's coefficients are not REAL32 numbers
    stored, enabled = bench.drive.filters.read(1)
    assert enabled and stored.b == read.b and stored.a == read.a

    # The torque the drive applies is the excitation through exactly those coefficients.
    bench.configure(divider=2, block=50)
    n = 400
    x = 0.5 * np.sin(2 * np.pi * 70.0 * np.arange(n) * 2 / DRIVER.loop_rate_hz)
    bench.excite(0, x)
    bench.ok(sb.Start(n))
    rows = rows_of(bench.advance(n))
    held = np.repeat(f32(x), 2)
    expected = lfilter(read.b, read.a, held)[::2]  # a sample is the first loop tick of its period
    np.testing.assert_allclose(rows[:, TRQ], expected, rtol=0, atol=1e-6)
    assert np.abs(rows[-100:, TRQ]).max() < 0.1 * np.abs(x).max()  # the notch works


@pytest.mark.parametrize("a", [(1.0, 0.0, 1.2), (1.0, -2.5, 1.0), (1.0, 0.0, 1.0 - 1e-9)])
def test_unstable_enabled_coefficients_are_refused(a):
    # The last one is stable in float64 but has poles on the unit circle in REAL32.
    bench = Bench()
    good = sb.FilterCoefficients(0, True, (0.5, 0.0, 0.0), (1.0, -0.5, 0.0))
    bench.ok(sb.WriteFilter(good))
    bench.refused(sb.WriteFilter(sb.FilterCoefficients(0, True, (1.0, 0.0, 0.0), a)), sb.ErrorCode.BAD_ARGUMENT)
    (read,) = bench.request(sb.ReadFilter(0))
    assert read == good  # the slot kept its previous contents
    # stored but disabled, it is harmless and accepted
    bench.ok(sb.WriteFilter(sb.FilterCoefficients(0, False, (1.0, 0.0, 0.0), a)))
    assert bench.drive.filters.read(0)[1] is False


def test_filter_slot_out_of_range_is_refused():
    bench = Bench()
    slot = DRIVER.filter_slots
    bench.refused(
        sb.WriteFilter(sb.FilterCoefficients(slot, True, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))), sb.ErrorCode.BAD_ARGUMENT
    )
    bench.refused(sb.ReadFilter(slot), sb.ErrorCode.BAD_ARGUMENT)


# --- safety ---------------------------------------------------------------------------------


def test_limit_trip_stops_the_axis_reports_and_latches_fault():
    bench = Bench(FRICTIONLESS)
    bench.ok(sb.Limits(2.0, 1.0, -1.0, 1.0))
    bench.configure(divider=4, block=10)
    x = np.concatenate([np.full(23, 1.5), np.full(12, 3.0)])
    bench.excite(0, x)
    bench.ok(sb.Start(len(x)))
    out = bench.advance(len(x))
    (trip,) = events_of(out)
    assert (trip.code, trip.sample_index) == (sb.EventCode.LIMIT_TRIP, 23)
    assert trip.value == 3.0  # the offending filtered torque command
    rows = rows_of(out)
    np.testing.assert_array_equal(rows[:23, TRQ], 1.5)
    np.testing.assert_array_equal(rows[23:, TRQ], 0.0)  # torque zero from the trip on
    assert rows[-1, TRQ] == 0.0 and rows[-1, CMD] == 0.0
    last = blocks_of(out)[-1]
    assert last.flags & sb.FLAG_LAST and last.flags & sb.FLAG_FAULT
    assert bench.fw.state == sb.State.FAULT and not bench.drive.enabled
    st = bench.status()
    assert (st.state, st.fault, st.limit_trips) == (sb.State.FAULT, sb.FaultCode.TORQUE_LIMIT, 1)

    # No torque after the trip: frictionless, the total momentum stays what it was.
    m1, m2 = 40.0, 10.0  # the configured plant (defaults)
    p1, v1, p2, v2 = bench.drive.true_state()
    assert v1 > 0  # it was pushed
    bench.fw.idle(2000)
    _, w1, _, w2 = bench.drive.true_state()
    assert m1 * w1 + m2 * w2 == pytest.approx(m1 * v1 + m2 * v2, rel=1e-9)
    assert np.all(bench.drive.run(np.full(8, 1.0))[:, DRIVER.channel_index("torque_nm")] == 0.0)

    # Latched: no START until CLEAR_FAULT; a new configuration does not clear it.
    bench.refused(sb.Start(10), sb.ErrorCode.FAULT_ACTIVE)
    bench.refused(sb.Excitation(len(x), np.ones(2)), sb.ErrorCode.BAD_STATE)
    bench.configure()
    assert bench.fw.state == sb.State.FAULT
    bench.ok(sb.ClearFault())
    st = bench.status()
    assert (st.state, st.fault) == (sb.State.CONFIGURED, sb.FaultCode.NONE)
    assert bench.drive.fault is None
    bench.excite(0, np.full(10, 1.0))
    bench.ok(sb.Start(10))
    rows = rows_of(bench.advance(10))
    np.testing.assert_array_equal(rows[:, TRQ], 1.0)  # torque flows again


def test_velocity_limit_trip_is_reported_as_such():
    bench = Bench(FRICTIONLESS)
    bench.ok(sb.Limits(5.0, 0.001, -1.0, 1.0))
    bench.configure(divider=4, block=10)
    bench.excite(0, np.full(400, 4.0))
    bench.ok(sb.Start(400))
    out = bench.advance(400)
    (trip,) = events_of(out)
    assert trip.code == sb.EventCode.LIMIT_TRIP and abs(trip.value) > 0.001
    assert bench.status().fault == sb.FaultCode.VELOCITY_LIMIT
    assert len(rows_of(out)) == 400  # every produced sample is still delivered


def test_stop_ends_the_run_with_a_last_block_an_event_and_an_ack():
    bench = Bench()
    bench.configure(divider=4, block=10)
    bench.excite(0, np.full(100, 0.5))
    bench.ok(sb.Start(0))
    out = bench.advance(34)
    answers = bench.request(sb.Stop())
    kinds = [type(m).__name__ for m in answers]
    assert kinds == ["Samples", "Event", "Ack"]
    last, stopped, _ = answers
    assert last.flags & sb.FLAG_LAST and last.first_sample == 30 and len(last.data) == 4
    assert (stopped.code, stopped.sample_index) == (sb.EventCode.STOPPED, 34)
    assert bench.fw.state == sb.State.CONFIGURED and not bench.drive.enabled
    assert bench.advance(50) == []
    assert len(rows_of(out + answers)) == 34
    bench.ok(sb.Stop())  # STOP is always accepted


def test_watchdog_stops_a_running_axis():
    bench = Bench()
    bench.configure()
    bench.ok(sb.Start(0))
    bench.advance(15)
    bench.fw.watchdog_expired()
    out = bench.drain()
    (ev,) = events_of(out)
    assert (ev.code, ev.sample_index) == (sb.EventCode.WATCHDOG, 15)
    (last,) = blocks_of(out)
    assert last.flags & sb.FLAG_LAST and last.flags & sb.FLAG_FAULT
    st = bench.status()
    assert (st.state, st.fault) == (sb.State.FAULT, sb.FaultCode.WATCHDOG)
    assert not bench.drive.enabled
    bench.ok(sb.ClearFault())
    assert bench.fw.state == sb.State.CONFIGURED


def test_block_index_runs_on_across_runs_while_first_sample_restarts():
    bench = Bench()
    bench.configure(block=10)
    out = []
    for _ in range(2):
        bench.ok(sb.Start(25))
        out += bench.advance(25)
    blocks = blocks_of(out)
    assert [b.block_index for b in blocks] == list(range(len(blocks)))
    assert [b.first_sample for b in blocks] == [0, 10, 20, 0, 10, 20]


# --- malformed requests ------------------------------------------------------------------------


def test_malformed_payloads_are_refused_with_the_matching_code():
    bench = Bench()
    (nak,) = bench.raw(bytes([2, sb.MsgType.PING, 5, 0]))
    assert (nak.error, nak.acked_seq, nak.acked_type) == (sb.ErrorCode.BAD_VERSION, 5, sb.MsgType.PING)
    (nak,) = bench.raw(bytes([1, 0x42, 6, 0]))
    assert (nak.error, nak.acked_seq, nak.acked_type) == (sb.ErrorCode.UNKNOWN_TYPE, 6, 0x42)
    (nak,) = bench.raw(bytes([1, sb.MsgType.START, 7, 0, 1]))
    assert (nak.error, nak.acked_seq, nak.acked_type) == (sb.ErrorCode.BAD_LENGTH, 7, sb.MsgType.START)
    (nak,) = bench.raw(b"\x01")
    assert (nak.error, nak.acked_seq, nak.acked_type) == (sb.ErrorCode.BAD_LENGTH, 0, 0)
    assert bench.fw.counters.rx_corrupt == 4
    # A well-formed board->host message is not a request.
    (nak,) = bench.raw(sb.encode(sb.Ack(1, 1), 8))
    assert (nak.error, nak.acked_seq, nak.acked_type) == (sb.ErrorCode.UNKNOWN_TYPE, 8, sb.MsgType.ACK)
    assert bench.fw.state == sb.State.IDLE


def test_start_is_refused_until_limits_are_loaded():
    bench = Bench(limits=None)
    bench.configure()
    nak = bench.refused(sb.Start(10), sb.ErrorCode.BAD_STATE)
    assert "SET_LIMITS" in nak.detail
    assert not bench.drive.enabled
    bench.ok(sb.Limits(5.0, 1.0, -1.0, 1.0))
    bench.ok(sb.Start(10))
    assert bench.fw.state == sb.State.RUNNING


@pytest.mark.parametrize("values", [(np.nan,), (np.inf,)])
def test_non_finite_values_are_refused_not_crashed_on(values):
    bench = Bench()
    bench.configure()
    bench.refused(sb.Limits(5.0, 1.0, -np.inf, 1.0), sb.ErrorCode.BAD_ARGUMENT)
    coeffs = sb.FilterCoefficients(0, True, (1.0, values[0], 0.0), (1.0, 0.0, 0.0))
    bench.refused(sb.WriteFilter(coeffs), sb.ErrorCode.BAD_ARGUMENT)
    assert not bench.drive.filters.read(0)[1]
    (nak,) = bench.excite(0, [0.0, values[0]])
    assert isinstance(nak, sb.Nak) and nak.error == sb.ErrorCode.BAD_ARGUMENT


def test_excitation_left_over_from_a_stopped_run_is_never_replayed():
    bench = Bench(FRICTIONLESS)
    bench.configure()
    bench.excite(0, np.full(100, 0.5))
    bench.ok(sb.Start(0))
    bench.advance(10)
    assert any(isinstance(m, sb.Ack) for m in bench.request(sb.Stop()))
    assert bench.status().excitation_level == 0
    bench.ok(sb.Start(20))
    rows = rows_of(bench.advance(20))
    assert np.all(rows[:, EXC] == 0.0)  # nothing queued: zeros, counted as underrun
    assert bench.status().underruns == 20


# --- the sample instant and underruns (PROTOCOL.md section 6) ------------------------------------


def test_a_sample_is_taken_at_the_first_loop_tick_of_its_period():
    bench = Bench(FRICTIONLESS)
    channels = tuple(sb.ChannelSelection(NAMES.index(n)) for n in ("time_s", "excitation", "torque_nm"))
    divider = 4
    bench.configure(divider=divider, block=8, channels=channels)
    bench.fw.idle(7)  # the run starts at an arbitrary loop tick, not a multiple of the divider
    tick0 = bench.drive.tick
    assert tick0 == 7
    x = np.r_[np.zeros(10), np.full(10, 2.0)]
    bench.excite(0, x)
    bench.ok(sb.Start(len(x)))
    rows = rows_of(bench.advance(len(x)))
    period = 1.0 / bench.fw.identity.loop_rate_hz
    # sample i is read at loop tick tick0 + divider * i: the first tick of its period (a board that
    # sampled at the last tick would report (divider - 1) ticks later, a phase lag of 0.75 ms at 1 kHz)
    np.testing.assert_array_equal(rows[:, 0], f32((tick0 + divider * np.arange(len(x))) * period))
    # and excitation value i acts from that very tick: the step shows in the same row, not one later
    np.testing.assert_array_equal(rows[:, 1], x)
    np.testing.assert_array_equal(rows[:, 2], x)


@pytest.mark.parametrize("mode, last", [(sb.Mode.VELOCITY, 2e-3), (sb.Mode.POSITION, 2e-5)])
def test_underrun_holds_the_last_set_point_in_velocity_and_position_mode(mode, last):
    bench = Bench(FRICTIONLESS)
    bench.configure(divider=4, block=10, mode=mode)
    x = np.linspace(0.0, last, 25)  # a ramp of set-points (m/s or m), then nothing more
    bench.excite(0, x)
    bench.ok(sb.Start(0))
    out = bench.advance(20) + bench.advance(20)
    rows = rows_of(out)
    np.testing.assert_array_equal(rows[:25, EXC], f32(x))
    np.testing.assert_array_equal(rows[25:, EXC], f32(x[-1]))  # held, never a jump to 0
    (ev,) = events_of(out)
    assert (ev.code, ev.sample_index) == (sb.EventCode.UNDERRUN, 25)
    assert ev.value == pytest.approx(x[-1])
    assert bench.status().underruns == 15
    # the loop sees no step: the torque command moves on smoothly across the underrun
    steps = np.abs(np.diff(rows[20:30, CMD]))
    assert steps[4] <= 2 * max(steps[:4].max(), steps[5:].max())


@pytest.mark.parametrize("mode", [sb.Mode.TORQUE, sb.Mode.TORQUE_INJECTION])
def test_underrun_drops_an_injected_torque_to_zero(mode):
    bench = Bench(FRICTIONLESS)
    bench.configure(divider=4, block=10, mode=mode)
    bench.excite(0, np.full(25, 0.3))
    bench.ok(sb.Start(0))
    out = bench.advance(40)
    rows = rows_of(out)
    np.testing.assert_array_equal(rows[25:, EXC], 0.0)
    (ev,) = events_of(out)
    assert (ev.sample_index, ev.value) == (25, 0.0)


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from([int(t) for t in sb.MsgType]), body=st.binary(max_size=64))
def test_the_board_survives_any_request_payload(kind, body):
    # a host written from the document, a damaged line or a confused earlier session
    bench = Bench()
    bench.configure()
    fw = bench.fw
    fw.receive(bytes([sb.PROTOCOL_VERSION, kind, 9, 0]) + body)
    assert fw.outbox or kind == sb.MsgType.EXCITATION  # every request but EXCITATION is answered
    fw.advance(5)
    fw.outbox.clear()
    assert fw.status().state in tuple(sb.State)
