"""Whole sessions on the emulated CiA 402 drive: the other acquisition mode, the fixed-point drive,
every injected fault, and the drive in another process behind a socketcand server."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.cli import main
from hilident.config import load_config
from hilident.emulator.factory import true_modes
from hilident.errors import DeviceError
from hilident.recording import read_run
from hilident.session import Session

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CONFIG = CONFIGS / "emulated-canopen-gantry.toml"


def short_config(acquisition="buffered", time_scale=20.0, period_s=1.0, duration_s=2.0, **faults):
    """The shipped CANopen gantry without the friction test and with a short multisine."""
    cfg = load_config(CONFIG)
    emu = replace(cfg.emulator, time_scale=time_scale, faults=replace(cfg.emulator.faults, **faults))
    return replace(cfg, device=replace(cfg.device, acquisition=acquisition), emulator=emu,
                   friction_test=replace(cfg.friction_test, enabled=False),
                   excitation=replace(cfg.excitation, period_s=period_s, duration_s=duration_s, amplitude_nm=8.0))


def test_streamed_session_on_the_fixed_point_drive(tmp_path):
    # the host sends every set-point and SYNC in real time; the notch goes into Q2.29 INTEGER32 slots
    cfg = short_config("streamed")
    cfg = replace(cfg, device=replace(cfg.device, driver="canopen-servo-fixed"))
    session = Session(cfg, tmp_path)
    summary = session.run()
    (true_f, true_zeta), = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.01
    assert abs(res["damping_ratio"] - true_zeta) / true_zeta < 0.3
    assert summary["upload"]["verified_readback"] and summary["upload"]["slots"][0]["matches"]
    assert summary["verification"]["peak_reduction_db"] >= 20.0
    stream = summary["stream"]
    n = read_run(tmp_path / "identification.h5").n_samples
    assert stream["samples"] == 2 * n and stream["lost_samples"] == 0 and stream["underruns"] == 0
    biquad, enabled = session.emulator.drive.filters.read(0)
    assert enabled and biquad.b == tuple(summary["upload"]["slots"][0]["readback_b"])
    assert not session.emulator.drive.enabled
    for name in summary["recordings"]:
        run = read_run(tmp_path / name)
        assert run.complete and np.array_equal(run.samples["sample_index"], np.arange(n))


def _aborted(tmp_path, cfg, match, error=DeviceError):
    session = Session(cfg, tmp_path)
    with pytest.raises(error, match=match) as err:
        session.run()
    assert not session.emulator.drive.enabled  # torque zero, power stage off
    run = read_run(tmp_path / "identification.h5")
    assert run.status == "aborted" and session.emulator.port in run.reason
    return err.value, run, session


def test_drive_fault_stops_the_run(tmp_path):
    err, run, _ = _aborted(tmp_path, short_config(drive_fault_after_s=1.5), "EMCY 0x4310")
    assert "temperature" in str(err)
    assert run.n_samples == 1500 and np.array_equal(run.samples["sample_index"], np.arange(1500))
    assert [e["kind"] for e in run.events] == ["emergency"] and run.events[0]["sample_index"] == 1500


def test_heartbeat_loss_stops_the_run(tmp_path):
    # the heartbeat is watched in wall time: 3 s of table at time scale 2 outlast the 0.5 s consumer timeout
    err, run, _ = _aborted(tmp_path, short_config(time_scale=2.0, heartbeat_stops_after_s=0.5), "heartbeat lost")
    assert 0 < run.n_samples < 3000


def test_aborted_object_is_named(tmp_path):
    err, run, _ = _aborted(tmp_path, short_config(abort_object="0x2201:3"), "0x2201:3")
    assert "Command" in str(err) and "hardware error" in str(err) and run.n_samples == 0


def test_short_capture_is_reported(tmp_path):
    err, run, _ = _aborted(tmp_path, short_config(capture_stops_after_s=2.0), "captured only 2000 of 3000")
    assert run.n_samples == 2000 and any(e["kind"] == "capture_short" for e in run.events)


def test_limit_trip_exits_with_code_5(tmp_path):
    # accelerating at 5 m/s^2 needs about 25 N*m, beyond limits.torque_nm: the drive trips
    text = CONFIG.read_text().replace("accel_mps2 = 0.5", "accel_mps2 = 5.0").replace("time_scale = 6.0",
                                                                                      "time_scale = 20.0")
    cfg = tmp_path / "trip.toml"
    cfg.write_text(text)
    assert main(["run", str(cfg), "--out", str(tmp_path / "out"), "-q"]) == 5
    run = read_run(tmp_path / "out" / "friction.h5")
    assert run.status == "aborted" and run.n_samples > 0
    trips = [e for e in run.events if e["kind"] == "limit_trip"]
    assert trips and "torque_limit" in trips[0]["message"] and trips[0]["sample_index"] == run.n_samples - 1


def test_lost_pdos_are_counted_and_left_out(tmp_path):
    cfg = short_config("streamed", drop_pdo_rate=0.002)
    cfg = replace(cfg, excitation=replace(cfg.excitation, kind="noise", duration_s=3.0, amplitude_nm=4.0),
                  identification=replace(cfg.identification, segment_s=0.5), notch=replace(cfg.notch, enabled=False))
    summary = Session(cfg, tmp_path).run()
    stream = summary["stream"]
    assert stream["lost_samples"] > 0 and stream["lost_frames"] >= stream["lost_samples"]
    assert stream["samples"] + stream["lost_samples"] == 3000
    assert any("lost" in w for w in summary["warnings"]) and any("gap" in w for w in summary["warnings"])
    run = read_run(tmp_path / "identification.h5")
    index = run.samples["sample_index"]
    assert run.n_samples < 3000 and np.all(np.diff(index) >= 1) and np.any(np.diff(index) > 1)  # holes stay holes
    assert any(e["kind"] == "lost_blocks" for e in run.events)


def _bench_config(tmp_path, port, **replacements) -> Path:
    text = CONFIG.read_text().replace('port = "emulator"', f'port = "{port}"')
    text = text.replace('can_interface = "socketcan"', 'can_interface = "socketcand"')
    text = text.replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")  # the session, not the trials, is the point
    for old, new in replacements.items():
        text = text.replace(old, new)
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


def test_standalone_drive_over_socketcand_runs_a_session_like_hardware(tmp_path, standalone_emulator):
    port = standalone_emulator("canopen", CONFIG, "--time-scale", "10")
    assert port.startswith("127.0.0.1:") and port.endswith("/can0")
    cfg = _bench_config(tmp_path, port, **{"[friction_test]": "[friction_test]\nenabled = false",
                                           "duration_s = 16.0": "duration_s = 8.0"})
    out = subprocess.run([sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o"),
                          "-q", "--yes"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "resonances: 21." in out.stdout and "0 lost blocks" in out.stdout
    assert (tmp_path / "o" / "summary.json").is_file()
