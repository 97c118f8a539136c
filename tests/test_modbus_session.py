"""Whole sessions against the emulated Modbus drive with its fault switches, and the standalone emulator."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.adapters.modbus_drive import ModbusDriveAdapter
from hilident.cli import main
from hilident.config import DeviceConfig, load_config
from hilident.drivers import find_driver
from hilident.emulator.modbus import server as modbus_server
from hilident.emulator.factory import true_modes
from hilident.errors import DataError, DeviceError
from hilident.recording import read_run
from hilident.session import Session

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CONFIG = CONFIGS / "emulated-modbus-gantry.toml"


def short_config(duration_s: float = 8.0, friction: bool = False, timeout_s: float = 0.5, **faults):
    """The shipped Modbus gantry, shorter and faster, with fault switches."""
    cfg = load_config(CONFIG)
    emu = replace(cfg.emulator, time_scale=10.0, faults=replace(cfg.emulator.faults, **faults))
    # a loaded test machine can stall a host for half a second: the drive's communication timeout is 2 s here
    return replace(cfg, emulator=emu, device=replace(cfg.device, timeout_s=timeout_s, host_timeout_s=2.0),
                   friction_test=replace(cfg.friction_test, enabled=friction),
                   excitation=replace(cfg.excitation, duration_s=duration_s, amplitude_nm=8.0))


@pytest.fixture
def drive_at_shutdown(monkeypatch):
    """The emulated drive's state when its server shuts down (after the host closed the adapter)."""
    seen = {}
    close = modbus_server.ModbusDriveServer.close

    def watched(self):
        seen.setdefault("enabled", self.firmware.drive.enabled)
        seen.setdefault("running", self.firmware.running)
        close(self)

    monkeypatch.setattr(modbus_server.ModbusDriveServer, "close", watched)
    return seen


def resonance_error(cfg, summary) -> float:
    (true_f, _), = true_modes(cfg.emulator)
    return min(abs(r["frequency_hz"] - true_f) / true_f for r in summary["resonances"])


@pytest.mark.parametrize("register,named", [
    (117, "register 117 (table_crc)"),
    (100, "register 100 (control_word)"),
    (4096 + 400, "capture window, page 0"),
])
def test_an_exception_stops_the_run_cleanly_and_names_the_register(tmp_path, drive_at_shutdown, register, named):
    cfg = short_config(exception_register=register, exception_code=4)
    session = Session(cfg, tmp_path)
    with pytest.raises(DeviceError) as err:
        session.run()
    assert named in str(err.value) and "Modbus exception 4 (server device failure" in str(err.value)
    assert drive_at_shutdown == {"enabled": False, "running": False}
    if register == 100:  # the stop at connect is refused: nothing is recorded, nothing moved
        assert not (tmp_path / "identification.h5").exists()
        return
    run = read_run(tmp_path / "identification.h5")
    assert run.status == "aborted" and named in run.reason
    if register > 4096:  # it struck while reading the capture: what came before is kept
        assert 0 < run.n_samples and np.all(np.diff(run.samples["sample_index"]) == 1)


def test_slow_answers_beyond_the_timeout_name_the_register(tmp_path, drive_at_shutdown):
    cfg = short_config(timeout_s=0.05, response_delay_s=0.15)
    with pytest.raises(DeviceError, match=r"reading registers 0\.\.6 \(device_type.*no answer within 0\.05 s \(4 attempts\)"):
        Session(cfg, tmp_path).run()
    assert drive_at_shutdown["enabled"] is False


def test_missing_answers_are_retried_and_counted(tmp_path, drive_at_shutdown):
    cfg = short_config(timeout_s=0.03, missing_response_rate=0.03)
    summary = Session(cfg, tmp_path).run()
    s = summary["stream"]
    assert s["lost_frames"] > 20 and s["lost_blocks"] == 0 and s["lost_samples"] == 0
    assert resonance_error(cfg, summary) < 0.01
    assert summary["upload"]["verified_readback"] and summary["verification"]["peak_reduction_db"] >= 20.0
    for name in ("identification.h5", "verification.h5"):
        run = read_run(tmp_path / name)
        assert run.complete and np.array_equal(run.samples["sample_index"], np.arange(run.n_samples))
    assert drive_at_shutdown == {"enabled": False, "running": False}


def test_a_capture_that_stops_early_is_counted_and_the_complete_periods_analysed(tmp_path, drive_at_shutdown):
    # 16 s of multisine after a 4 s lead-in; the capture ends at 13 s: periods 1 and 2 remain whole
    cfg = short_config(duration_s=16.0, capture_stops_after_s=13.0)
    summary = Session(cfg, tmp_path).run()
    assert summary["stream"]["lost_samples"] == 2 * 7000
    assert any("periods had lost samples" in w for w in summary["warnings"])
    assert resonance_error(cfg, summary) < 0.01
    run = read_run(tmp_path / "identification.h5")
    assert run.n_samples == 13000 and run.samples["sample_index"][-1] == 12999
    stopped = [e for e in run.events if e["kind"] == "capture_stopped"]
    assert stopped and stopped[0]["sample_index"] == 13000
    assert drive_at_shutdown == {"enabled": False, "running": False}


def test_a_capture_too_short_for_the_analysis_is_a_data_error(tmp_path):
    cfg = short_config(capture_stops_after_s=9.0)  # 1 whole period of 2
    with pytest.raises(DataError, match="only 1 complete excitation period"):
        Session(cfg, tmp_path).run()
    assert read_run(tmp_path / "identification.h5").n_samples == 9000


def test_a_drive_fault_stops_the_run(tmp_path, drive_at_shutdown):
    cfg = short_config(drive_fault_after_s=2.0)
    with pytest.raises(DeviceError, match=r"drive_fault: axis stopped.*register 102 \(fault_code\) = 4, at sample 2000"):
        Session(cfg, tmp_path).run()
    run = read_run(tmp_path / "identification.h5")
    assert run.status == "aborted" and run.n_samples == 2000
    assert [e["kind"] for e in run.events] == ["fault"]
    assert drive_at_shutdown["enabled"] is False


def test_a_limit_trip_is_a_clean_stop(tmp_path):
    text = CONFIG.read_text().replace("accel_mps2 = 0.5", "accel_mps2 = 5.0").replace("time_scale = 4.0", "time_scale = 10.0")
    path = tmp_path / "trip.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "-q"]) == 5
    run = read_run(tmp_path / "out" / "friction.h5")
    assert run.status == "aborted" and run.n_samples > 0
    trips = [e for e in run.events if e["kind"] == "limit_trip"]
    assert trips and "torque_limit" in trips[0]["message"]
    assert run.samples["sample_index"][-1] == trips[0]["sample_index"]
    assert not (tmp_path / "out" / "summary.json").exists()


# --- standalone --------------------------------------------------------------------------


def test_standalone_modbus_tcp_emulator_runs_a_session_like_hardware(tmp_path, standalone_emulator):
    port = standalone_emulator("modbus", CONFIG, "--time-scale", "8")
    assert port.startswith("tcp://127.0.0.1:")
    text = CONFIG.read_text().replace('port = "emulator"', f'port = "{port}"\nhost_timeout_s = 2.0')
    text = text.replace("[friction_test]", "[friction_test]\nenabled = false")
    text = text.replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")  # the session, not the trials, is the point
    cfg = tmp_path / "bench.toml"
    cfg.write_text(text)
    out = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o"), "-q", "--yes"],
        capture_output=True, text=True, timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "resonances: 21." in out.stdout and "0 lost blocks" in out.stdout


def test_standalone_modbus_rtu_emulator_on_a_pty(standalone_emulator):
    port = standalone_emulator("modbus", CONFIG, "--time-scale", "8", "--rtu")
    assert port.startswith("/dev/")
    driver = find_driver("modbus-servo")
    adapter = ModbusDriveAdapter.open_device(DeviceConfig(port=port, parity="N", timeout_s=1.0), driver)
    try:
        assert adapter.identity.name == "modbus-servo" and adapter.rtu
    finally:
        adapter.close()
