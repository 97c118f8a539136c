"""Fault switches, limit trips and lost data: one scenario suite over every transport.

One test class, parametrised over the transports (python-can's back-to-back
style): each scenario states once what any transport must do (the exit code
of the bench guide's table, a stopped drive, a recording marked aborted whose
sample indices never invent a sample) and takes what differs per transport
(the shipped config, the fault switch that provokes the scenario, the words
the error names) from one small :class:`Transport` record. A transport that
cannot have a scenario says why in its ``skip`` table.

The endings that need a host in another process (signals, SIGKILL, a device
that vanishes, a full disk) are the ending matrix of ``test_endings.py``,
one class over every transport and link too.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from hilident.cli.main import main
from hilident.config.tables import load_config
from hilident.emulator.factory import true_modes
from hilident.errors import DeviceError
from hilident.io.recording import read_run
from hilident.session.run import Session

pytestmark = pytest.mark.twin  # every scenario is a session on a twin

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

#: The exit-code table of docs/bench-guide.md ("Safety, endings and exit codes").
EXIT_LIMIT_TRIP = 5


# --- what differs per transport ------------------------------------------------------------


def _serial_config(**faults):
    """The shipped gantry over the in-memory line, quick, at a fixed amplitude."""
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    emu = replace(cfg.emulator, link="pipe", time_scale=8.0, faults=replace(cfg.emulator.faults, **faults))
    return replace(
        cfg,
        emulator=emu,
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, amplitude_nm=8.0),
    )


def _modbus_config(duration_s: float = 8.0, timeout_s: float = 0.5, **faults):
    """The shipped Modbus gantry, shorter and faster."""
    cfg = load_config(CONFIGS / "emulated-modbus-gantry.toml")
    emu = replace(cfg.emulator, time_scale=10.0, faults=replace(cfg.emulator.faults, **faults))
    # a loaded test machine can stall a host for half a second: the drive's communication timeout is 2 s here
    return replace(
        cfg,
        emulator=emu,
        device=replace(cfg.device, timeout_s=timeout_s, host_timeout_s=2.0),
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, duration_s=duration_s, amplitude_nm=8.0),
    )


def _canopen_config(acquisition="buffered", time_scale=20.0, period_s=1.0, duration_s=2.0, **faults):
    """The shipped CANopen gantry with a short multisine."""
    cfg = load_config(CONFIGS / "emulated-canopen-gantry.toml")
    emu = replace(cfg.emulator, time_scale=time_scale, faults=replace(cfg.emulator.faults, **faults))
    return replace(
        cfg,
        device=replace(cfg.device, acquisition=acquisition),
        emulator=emu,
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, period_s=period_s, duration_s=duration_s, amplitude_nm=8.0),
    )


def _serial_line_closing_config():
    """The board closes its line 0.8 s into the run (on a pseudo-terminal: a real serial path)."""
    cfg = _serial_config(close_after_s=0.8)
    return replace(cfg, emulator=replace(cfg.emulator, link="pty"))


def _serial_lost_config():
    cfg = _serial_config(corrupt_frame_rate=0.02, drop_frame_rate=0.02)
    return replace(cfg, excitation=replace(cfg.excitation, kind="noise"))


def _canopen_lost_config():
    cfg = _canopen_config("streamed", drop_pdo_rate=0.002)
    return replace(
        cfg,
        excitation=replace(cfg.excitation, kind="noise", duration_s=3.0, amplitude_nm=4.0),
        identification=replace(cfg.identification, segment_s=0.5),
        notch=replace(cfg.notch, enabled=False),
    )


def _serial_lost_extra(cfg, summary, run):
    s = summary["stream"]
    assert s["corrupt_frames"] > 0 and s["lost_blocks"] > 0
    assert run.n_samples < int(run.samples["sample_index"][-1]) + 1


def _canopen_lost_extra(cfg, summary, run):
    s = summary["stream"]
    assert s["lost_frames"] >= s["lost_samples"] and s["samples"] + s["lost_samples"] == 3000
    assert any("gap" in w for w in summary["warnings"]) and run.n_samples < 3000


def _modbus_lost_extra(cfg, summary, run):
    # a request without an answer is asked again: frames are lost, samples never
    s = summary["stream"]
    assert s["lost_frames"] > 20 and s["lost_blocks"] == 0
    ((true_f, _),) = true_modes(cfg.emulator)
    assert min(abs(r["frequency_hz"] - true_f) / true_f for r in summary["resonances"]) < 0.01
    assert summary["upload"]["verified_readback"] and summary["verification"]["peak_reduction_db"] >= 20.0
    assert run.complete


@dataclass(frozen=True)
class Fault:
    """A fault switch that ends a run with a DeviceError, and what the error and the recording then say."""

    config: Callable[[], object]
    match: str  # regular expression the DeviceError matches
    also: tuple[str, ...] = ()  # further words the message contains
    n_samples: int | None = None  # samples recorded, when the switch fixes it
    events: tuple[str, ...] | None = None  # the recording's event kinds, when the switch fixes them
    names_port: bool = True  # the message and the recording's reason name the port


@dataclass(frozen=True)
class ShortCapture:
    """A capture that stops early: the error (if the transport makes one) and what the recording keeps."""

    config: Callable[[], object]
    n_samples: int
    event: str
    error: tuple[type, str] | None = None
    lost_samples: int | None = None
    event_index: int | None = None  # where the event says the capture ended, when the transport records it


@dataclass(frozen=True)
class Transport:
    """What differs per transport in the scenario suite."""

    name: str
    config_file: str
    trip_overrides: dict  # TOML tables changed for the limit trip run (a fast twin, a quick line)
    lost_config: Callable[[], object]
    lost_extra: Callable
    drive_fault: Fault | None = None
    falls_silent: Fault | None = None
    refused_access: Fault | None = None
    short_capture: ShortCapture | None = None
    running: Callable = lambda emulated: emulated.drive.enabled  # the twin still moves or plays (after a run: never)
    trip_ends_the_recording: bool = True  # the last recorded sample is the trip's (a drive's capture ends there)
    skip: dict[str, str] = field(default_factory=dict)

    def needs(self, scenario: str):
        """The scenario's per-transport settings, or a skip with the reason this transport cannot have it."""
        if scenario in self.skip:
            pytest.skip(f"{self.name}: {self.skip[scenario]}")
        return getattr(self, scenario)


SERIAL = Transport(
    name="serial",
    config_file="emulated-gantry.toml",
    trip_overrides={"emulator": {"link": "pipe", "time_scale": 8.0}},
    lost_config=_serial_lost_config,
    lost_extra=_serial_lost_extra,
    trip_ends_the_recording=False,  # the board's blocks already on the line after the trip are recorded too
    falls_silent=Fault(_serial_line_closing_config, match="line lost|write failed|no data from the board"),
    skip={
        "drive_fault": "the board's firmware has no drive-fault switch (drive_fault_after_s is a CANopen/Modbus "
        "drive's); its latched faults come from limit trips and the watchdog, tested by "
        "test_limit_trip and test_endings.py",
        "refused_access": "the board has no objects or registers to refuse; a refused frame (NAK) is injected at "
        "the adapter in tests/adapters/test_serial_endings.py",
        "short_capture": "the board streams every sample as it is measured: there is no drive-side capture to stop",
    },
)

MODBUS = Transport(
    name="modbus",
    config_file="emulated-modbus-gantry.toml",
    running=lambda emulated: emulated.drive.enabled or emulated.server.firmware.running,
    trip_overrides={"emulator": {"time_scale": 10.0}},
    lost_config=lambda: _modbus_config(timeout_s=0.03, missing_response_rate=0.03),
    lost_extra=_modbus_lost_extra,
    drive_fault=Fault(
        lambda: _modbus_config(drive_fault_after_s=2.0),
        match=r"drive_fault: axis stopped.*register 102 \(fault_code\) = 4, at sample 2000",
        n_samples=2000,
        events=("fault",),
    ),
    refused_access=Fault(
        lambda: _modbus_config(exception_register=117, exception_code=4),
        match=re.escape("register 117 (table_crc)"),
        also=("Modbus exception 4 (server device failure",),
    ),
    short_capture=ShortCapture(
        lambda: _modbus_config(duration_s=16.0, capture_stops_after_s=13.0),
        # 16 s of multisine after a 4 s lead-in; the capture ends at 13 s: periods 1 and 2
        # remain whole and are analysed, the rest is counted lost
        n_samples=13000,
        event="capture_stopped",
        lost_samples=2 * 7000,
        event_index=13000,
    ),
    skip={
        "falls_silent": "the Modbus twin has no switch that silences it mid-run (its server answers every "
        "request it gets); a twin closed mid-run is test_endings.py's test_device_vanishes",
    },
)

CANOPEN = Transport(
    name="canopen",
    config_file="emulated-canopen-gantry.toml",
    trip_overrides={"emulator": {"time_scale": 20.0}},
    lost_config=_canopen_lost_config,
    lost_extra=_canopen_lost_extra,
    drive_fault=Fault(
        lambda: _canopen_config(drive_fault_after_s=1.5),
        match="EMCY 0x4310",
        also=("temperature",),
        n_samples=1500,
        events=("emergency",),
    ),
    # the heartbeat is watched in wall time: 3 s of table at time scale 2 outlast the 0.5 s consumer timeout
    falls_silent=Fault(lambda: _canopen_config(time_scale=2.0, heartbeat_stops_after_s=0.5), match="heartbeat lost"),
    refused_access=Fault(
        lambda: _canopen_config(abort_object="0x2201:3"),
        match="0x2201:3",
        also=("Command", "hardware error"),
        n_samples=0,
    ),
    short_capture=ShortCapture(
        lambda: _canopen_config(capture_stops_after_s=2.0),
        n_samples=2000,
        event="capture_short",
        error=(DeviceError, "captured only 2000 of 3000"),
    ),
)

TRANSPORTS = [SERIAL, MODBUS, CANOPEN]


@pytest.fixture(params=TRANSPORTS, ids=[t.name for t in TRANSPORTS])
def transport(request) -> Transport:
    return request.param


# --- the scenarios ---------------------------------------------------------------------------


def _contiguous(run) -> bool:
    return bool(np.array_equal(run.samples["sample_index"], np.arange(run.n_samples)))


def _aborted_by(transport: Transport, fault: Fault, tmp_path, error=DeviceError):
    """Run ``fault``'s session; it raises ``error``, leaves the drive off and the recording aborted."""
    session = Session(fault.config(), tmp_path)
    with pytest.raises(error, match=fault.match) as err:
        session.run()
    assert not transport.running(session.emulator)  # torque zero, power stage off, nothing playing
    message = str(err.value)
    assert all(word in message for word in fault.also), message
    run = read_run(tmp_path / "identification.h5")
    assert run.status == "aborted" and re.search(fault.match, run.reason), run.reason
    if fault.names_port:
        assert session.emulator.port in message and session.emulator.port in run.reason
    return run


class TestScenarios:
    """One class over every transport: each scenario ends the same documented way."""

    def test_limit_trip_is_a_clean_stop_with_exit_code_5(self, transport, tmp_path):
        # accelerating at 5 m/s^2 in the friction test needs about 25 N*m, beyond limits.torque_nm: the device trips
        raw = tomllib.loads((CONFIGS / transport.config_file).read_text())
        raw["friction_test"]["accel_mps2"] = 5.0
        for table, values in transport.trip_overrides.items():
            raw[table].update(values)
        path = tmp_path / "trip.toml"
        path.write_text(tomli_w.dumps(raw))
        assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == EXIT_LIMIT_TRIP
        run = read_run(tmp_path / "out" / "friction.h5")
        assert run.status == "aborted" and run.n_samples > 0
        trips = [e for e in run.events if e["kind"] == "limit_trip"]
        assert trips and "torque_limit" in trips[0]["message"]
        last = run.samples["sample_index"][-1]
        if transport.trip_ends_the_recording:
            assert last == trips[0]["sample_index"]
        else:
            assert last >= trips[0]["sample_index"]
        assert not (tmp_path / "out" / "summary.json").exists()

    def test_a_drive_fault_stops_the_run(self, transport, tmp_path):
        fault = transport.needs("drive_fault")
        run = _aborted_by(transport, fault, tmp_path)
        assert run.n_samples == fault.n_samples and _contiguous(run)
        assert tuple(e["kind"] for e in run.events) == fault.events
        assert run.events[0]["sample_index"] == fault.n_samples

    def test_a_device_that_falls_silent_mid_run_is_a_device_error(self, transport, tmp_path):
        fault = transport.needs("falls_silent")
        run = _aborted_by(transport, fault, tmp_path)
        assert run.n_samples > 0

    def test_a_refused_object_or_register_is_named_and_stops_the_run(self, transport, tmp_path):
        fault = transport.needs("refused_access")
        run = _aborted_by(transport, fault, tmp_path)
        if fault.n_samples is not None:
            assert run.n_samples == fault.n_samples

    def test_a_capture_that_stops_early_keeps_what_was_captured(self, transport, tmp_path):
        short = transport.needs("short_capture")
        cfg = short.config()
        session = Session(cfg, tmp_path)
        if short.error:
            error, match = short.error
            with pytest.raises(error, match=match):
                session.run()
        else:
            summary = session.run()
            assert summary["stream"]["lost_samples"] == short.lost_samples
            assert any("periods had lost samples" in w for w in summary["warnings"])
            ((true_f, _),) = true_modes(cfg.emulator)
            assert min(abs(r["frequency_hz"] - true_f) / true_f for r in summary["resonances"]) < 0.01
        assert not transport.running(session.emulator)
        run = read_run(tmp_path / "identification.h5")
        assert run.n_samples == short.n_samples and _contiguous(run)
        events = [e for e in run.events if e["kind"] == short.event]
        assert events
        if short.event_index is not None:
            assert events[0]["sample_index"] == short.event_index

    def test_lost_data_is_counted_and_never_filled_in(self, transport, tmp_path):
        cfg = transport.lost_config()
        session = Session(cfg, tmp_path)
        summary = session.run()
        s = summary["stream"]
        assert s["lost_frames"] > 0 or s["corrupt_frames"] > 0
        run = read_run(tmp_path / "identification.h5")
        index = run.samples["sample_index"]
        assert np.all(np.diff(index) >= 1)  # never reordered, never a sample twice
        if s["lost_samples"]:
            assert np.any(np.diff(index) > 1)  # holes stay holes
            assert any("lost" in w for w in summary["warnings"])
            assert any(e["kind"] == "lost_blocks" for e in run.events)
        else:
            assert _contiguous(run)
        transport.lost_extra(cfg, summary, run)
        assert not transport.running(session.emulator)
