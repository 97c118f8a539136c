"""Whole sessions against the emulated Modbus drive: where its exceptions and timeouts strike, and the standalone
emulator. The fault switches every transport shares (drive fault, limit trip, lost answers, a capture that stops
early) are scenarios of ``test_scenarios.py``."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import DeviceConfig, load_config
from hilident.drivers.description import find_driver
from hilident.emulator.modbus import server as modbus_server
from hilident.errors import DataError, DeviceError
from hilident.io.recording import read_run
from hilident.session.run import Session

pytestmark = pytest.mark.twin  # sessions on the Modbus twin, in this process or another

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CONFIG = CONFIGS / "emulated-modbus-gantry.toml"


def short_config(duration_s: float = 8.0, friction: bool = False, timeout_s: float = 0.5, **faults):
    """The shipped Modbus gantry, shorter and faster, with fault switches."""
    cfg = load_config(CONFIG)
    emu = replace(cfg.emulator, time_scale=10.0, faults=replace(cfg.emulator.faults, **faults))
    # a loaded test machine can stall a host for half a second: the drive's communication timeout is 2 s here
    return replace(
        cfg,
        emulator=emu,
        device=replace(cfg.device, timeout_s=timeout_s, host_timeout_s=2.0),
        friction_test=replace(cfg.friction_test, enabled=friction),
        excitation=replace(cfg.excitation, duration_s=duration_s, amplitude_nm=8.0),
    )


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


@pytest.mark.parametrize(
    "register,named",
    [
        (100, "register 100 (control_word)"),
        (4096 + 400, "capture window, page 0"),
    ],
)
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
    with pytest.raises(
        DeviceError, match=r"reading registers 0\.\.6 \(device_type.*no answer within 0\.05 s \(4 attempts\)"
    ):
        Session(cfg, tmp_path).run()
    assert drive_at_shutdown["enabled"] is False


def test_a_capture_too_short_for_the_analysis_is_a_data_error(tmp_path):
    cfg = short_config(capture_stops_after_s=9.0)  # 1 whole period of 2
    with pytest.raises(DataError, match="only 1 complete excitation period"):
        Session(cfg, tmp_path).run()
    assert read_run(tmp_path / "identification.h5").n_samples == 9000


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
        capture_output=True,
        text=True,
        timeout=120,
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
