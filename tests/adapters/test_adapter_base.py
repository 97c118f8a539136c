"""The adapter template (AdapterBase) and the run event vocabulary, on a transport made of hooks only."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.adapters.backends import BACKENDS, adapter_class
from hilident.adapters.base import AdapterBase, RunStrategy
from hilident.errors import DataError, DeviceError, LimitTrip
from hilident.events import Kind, RunEvent
from hilident.filters.biquad import Biquad
from hilident.protocol import serial_board as sb


class _Transport(AdapterBase):
    """A device that plays ``x`` back as its only channel, in blocks of 10; hooks record what was called."""

    def __init__(self, script=None, limits=None):
        self.port = "fake:0"
        self.events = []
        self.channel_names = ["torque_nm"]
        self.calls = []
        self.script = script or (lambda ad, k: None)
        self.limits = limits or []
        self.slot = (Biquad.identity(), False)
        self.rounding = 0.0

    def _play(self, x, deliver, result):
        self.calls.append("play")
        for k in range(0, len(x), 10):
            self.script(self, k)
            deliver(np.arange(k, min(k + 10, len(x))), x[k : k + 10, None])
            result.stats.samples += min(10, len(x) - k)
        result.completed = self.run_fault is None

    def _host_limit_columns(self):
        return self.limits

    def _command_safe(self):
        self.calls.append("safe")
        if "unplugged" in self.calls:
            raise OSError("gone")

    # filter slot: stores a biquad with its own rounding
    def _write_filter(self, slot, biquad, spec, enabled):
        self.calls.append(("write", enabled))
        self.slot = (Biquad(tuple(b + self.rounding for b in biquad.b), biquad.a), enabled)

    def _read_filter(self, slot):
        return self.slot

    def _stored_form(self, biquad, spec):
        return biquad

    def _read_raw_slot(self, slot):
        return self.slot

    def _write_raw_slot(self, slot, saved):
        self.calls.append("restore")
        self.slot = saved


class _Rows:
    def __init__(self):
        self.index = []

    def __call__(self, index, rows):
        self.index += list(index)


def test_a_run_delivers_every_sample_and_ends_with_the_axis_commanded_safe():
    ad, sink = _Transport(), _Rows()
    ad.events = [{"kind": "stale"}]
    result = ad.stream(np.linspace(0, 1, 35), sink)
    assert sink.index == list(range(35))
    assert result.completed and result.stats.samples == 35 and ad.last_result is result
    assert ad.events == [] and ad.calls == ["play", "safe"]


@pytest.mark.parametrize("bad", [np.array([0.0, np.nan]), np.zeros((3, 2)), [0.0, np.inf]])
def test_a_bad_excitation_is_refused_before_anything_moves(bad):
    ad = _Transport()
    with pytest.raises(DataError, match="finite one-dimensional"):
        ad.stream(bad, _Rows())
    assert ad.calls == []


def test_the_sinks_own_error_propagates_after_the_safe_stop_and_last_result_is_set():
    class DiskFull(Exception):
        pass

    def sink(index, rows):
        if index[0] >= 20:
            raise DiskFull

    ad = _Transport()
    ad.log_event(RunEvent(Kind.LIMIT_TRIP, "tripped before", 0))  # an earlier run's: emptied
    with pytest.raises(DiskFull):
        ad.stream(np.zeros(50), sink)
    assert ad.calls[-1] == "safe" and ad.last_result is not None and not ad.last_result.completed
    assert ad.last_result.stats.samples == 20 and ad.events == []


def test_the_first_cause_wins_a_limit_trip_then_a_device_error():
    def script(ad, k):
        if k == 10:
            ad.note_fault(ad.log_event(RunEvent(Kind.LIMIT_TRIP, "torque_limit: axis stopped", 12, value=3.0)))
        if k == 20:
            raise DeviceError("fake:0: line lost")

    ad = _Transport(script)
    with pytest.raises(LimitTrip, match=r"^fake:0: torque_limit: axis stopped \(then: fake:0: line lost\)$"):
        ad.stream(np.zeros(50), _Rows())
    assert ad.last_result.fault == "torque_limit: axis stopped"
    assert ad.last_result.events == [
        {"kind": "limit_trip", "message": "torque_limit: axis stopped", "sample_index": 12, "value": 3.0}
    ]


def test_a_fault_noted_during_a_run_that_returns_ends_it_with_a_device_error():
    def script(ad, k):
        if k == 0:
            ad.note_fault(ad.log_event(RunEvent(Kind.FAULT, "drive fault 7", 3)))

    ad = _Transport(script)
    with pytest.raises(DeviceError, match="drive fault 7") as err:
        ad.stream(np.zeros(20), _Rows())
    assert not isinstance(err.value, LimitTrip)
    assert ad.calls[-1] == "safe"


def test_the_host_limit_check_cuts_the_block_at_the_first_sample_outside_and_stops_the_axis():
    ad, sink = _Transport(limits=[(0, -1.0, 1.0, "torque_limit")]), _Rows()
    x = np.zeros(40)
    x[23] = 1.5
    with pytest.raises(LimitTrip, match="torque_limit: torque_nm = 1.5 outside"):
        ad.stream(x, sink)
    assert sink.index == list(range(24))  # nothing after the sample the host stopped the axis at
    (event,) = ad.events
    assert event["kind"] == "limit_trip" and event["sample_index"] == 23 and event["host_check"] is True
    assert ad.calls.count("safe") == 2  # at the trip, and again at the end of the run


def test_safe_stop_never_raises():
    ad = _Transport()
    ad.calls.append("unplugged")
    ad.safe_stop()
    assert ad.calls[-1] == "safe"


def test_upload_filter_enables_what_read_back_as_written_and_restores_what_did_not():
    notch = Biquad((0.9, -1.5, 0.9), (1.0, -1.5, 0.8))
    ad = _Transport()
    up = ad.upload_filter(0, notch)
    assert up.matches and ad.slot == (notch, True)
    assert ad.calls == [("write", False), ("write", True)]

    ad = _Transport()
    ad.rounding = 1e-3  # the device stores something else than it was given
    before = ad.slot
    up = ad.upload_filter(0, notch)
    assert not up.matches and ad.slot == before and ad.calls[-1] == "restore"
    assert up.stored.b[0] == pytest.approx(0.901)


def test_disable_filter_keeps_the_coefficients():
    notch = Biquad((0.9, -1.5, 0.9), (1.0, -1.5, 0.8))
    ad = _Transport()
    ad.slot = (notch, True)
    ad.disable_filter(0)
    assert ad.slot == (notch, False)


def test_a_strategy_owns_its_run():
    class Twice(RunStrategy):
        def run(self):
            self.deliver(np.arange(self.n), 2 * self.x[:, None])
            self.stats.samples = self.n
            self.result.completed = True

    class Strategic(_Transport):
        def _play(self, x, deliver, result):
            Twice.play(self, x, deliver, result)

    rows = []
    result = Strategic().stream(np.ones(5), lambda i, r: rows.append(r))
    assert result.completed and np.array_equal(rows[0][:, 0], 2 * np.ones(5))


# --- the event vocabulary ---------------------------------------------------------------------------


def test_run_events_give_the_dicts_the_recordings_hold():
    assert RunEvent(Kind.SYNC_LATE, "3 SYNC(s) late", 0, value=3, worst_s=0.0021).to_dict() == {
        "kind": "sync_late",
        "message": "3 SYNC(s) late",
        "sample_index": 0,
        "value": 3.0,
        "worst_s": 0.0021,
    }
    emcy = RunEvent(Kind.EMERGENCY, "EMCY 0x4310", 7, code=0x4310, register=0x09, data="0100000000").to_dict()
    assert emcy == {
        "kind": "emergency",
        "message": "EMCY 0x4310",
        "sample_index": 7,
        "code": 0x4310,
        "register": 9,
        "data": "0100000000",
    }
    assert list(emcy)[3:] == ["code", "register", "data"]  # the recording's data column keeps this order
    assert "value" not in emcy and "host_check" not in emcy
    trip = RunEvent(Kind.LIMIT_TRIP, "x", np.int64(4), value=np.float32(1.5), host_check=True).to_dict()
    assert list(trip) == ["kind", "message", "sample_index", "value", "host_check"]
    assert type(trip["sample_index"]) is int and type(trip["value"]) is float


def test_every_serial_board_event_has_a_kind():
    for code in sb.EventCode:
        assert Kind(code.name.lower()).value == code.name.lower()


def test_fault_kinds_end_a_run():
    assert RunEvent(Kind.EMERGENCY, "x").is_fault and RunEvent(Kind.WATCHDOG, "x").is_fault
    assert not RunEvent(Kind.EMERGENCY_RESET, "x").is_fault and not RunEvent(Kind.LOST_BLOCKS, "x").is_fault


def test_canopen_acquisitions_are_one_table():
    from hilident.adapters.canopen.buffered import BufferedRun
    from hilident.adapters.canopen.drive import ACQUISITIONS
    from hilident.adapters.canopen.streamed import StreamedRun

    assert ACQUISITIONS["streamed"] == StreamedRun.play and ACQUISITIONS["buffered"] == BufferedRun.play


# --- the template is never overridden ---------------------------------------------------------------


def _public_methods(cls: type) -> set[str]:
    """The public callables a class defines itself (methods, class and static methods, properties aside)."""
    return {
        name
        for name, value in vars(cls).items()
        if not name.startswith("_") and (callable(value) or isinstance(value, (classmethod, staticmethod)))
    }


@pytest.mark.parametrize("transport", sorted(BACKENDS))
def test_no_adapter_overrides_a_public_method_of_the_template(transport):
    # the public run, upload and stop logic lives once, in AdapterBase; a transport supplies protected hooks
    cls = adapter_class(transport)
    template = _public_methods(AdapterBase)
    assert template >= {"close", "safe_stop", "stream", "upload_filter", "save_filter", "restore_filter"}
    below = cls.__mro__[: cls.__mro__.index(AdapterBase)]
    overridden = {f"{klass.__name__}.{name}" for klass in below for name in template & set(vars(klass))}
    assert overridden == set(), f"{cls.__name__} overrides the template's public methods: {sorted(overridden)}"


def test_a_transport_made_of_hooks_only_overrides_nothing_public():
    below = _Transport.__mro__[: _Transport.__mro__.index(AdapterBase)]
    assert all(not (_public_methods(AdapterBase) & set(vars(klass))) for klass in below)
