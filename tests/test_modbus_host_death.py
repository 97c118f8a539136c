"""A host killed hard (SIGKILL) in the middle of a Modbus run: the drive stops itself by its communication timeout."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.adapters.modbus_drive import ModbusDriveAdapter
from hilident.config import load_config
from hilident.drivers import find_driver
from hilident.emulator.modbus_drive import start
from hilident.errors import DeviceError

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-modbus-gantry.toml"
HOST_TIMEOUT_S = 0.5
TOLERANCE_S = 0.15  # the twin's clock looks every 2 ms; a loaded machine delays it a little more


def bench_config(tmp_path: Path, port: str) -> Path:
    """The shipped Modbus gantry pointed at ``port`` like a bench drive, friction test off."""
    text = CONFIG.read_text().replace('port = "emulator"', f'port = "{port}"\nhost_timeout_s = {HOST_TIMEOUT_S}')
    text = text.replace("[friction_test]", "[friction_test]\nenabled = false")
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("link", ["tcp", "pty"])
def test_sigkill_of_the_host_mid_run_leaves_the_drive_stopped_within_its_timeout(tmp_path, link):
    cfg = load_config(CONFIG)
    driver = find_driver("modbus-servo")
    emu = start(replace(cfg.emulator, time_scale=1.0), driver, replace(cfg.device, baudrate=921600), link=link)
    host = None
    try:
        config = bench_config(tmp_path, emu.port)
        if link == "pty":
            text = config.read_text().replace("timeout_s = 1.0", 'timeout_s = 1.0\nparity = "N"\nbaudrate = 921600')
            config.write_text(text)
        host = subprocess.Popen(
            [sys.executable, "-m", "hilident.cli", "run", str(config), "--out", str(tmp_path / "o"), "-q",
             "--yes"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        deadline = time.monotonic() + 60
        while not emu.drive.enabled:
            assert host.poll() is None, host.stderr.read()
            assert time.monotonic() < deadline, "the run never enabled the drive"
            time.sleep(0.005)
        time.sleep(0.3)  # well into the run: the host polls the drive
        assert emu.drive.enabled
        os.kill(host.pid, signal.SIGKILL)
        killed = time.monotonic()
        while emu.drive.enabled and time.monotonic() - killed < 5.0:
            time.sleep(0.002)
        stopped_s = time.monotonic() - killed
        host.wait(timeout=10)
        print(f"{link}: stopped {stopped_s * 1e3:.0f} ms after SIGKILL")
        assert HOST_TIMEOUT_S - 0.05 <= stopped_s <= HOST_TIMEOUT_S + TOLERANCE_S  # the drive's own timeout did it
        fw = emu.server.firmware
        assert fw.fault_code == fw.map.fault_codes["comm_timeout"] and not fw.running

        # the next session finds the fault latched: refused unless it may clear it
        device = replace(emu.device, host_timeout_s=2.0)
        with pytest.raises(DeviceError, match="comm_timeout.*allow_fault_reset"):
            ModbusDriveAdapter.open_device(device, driver)
        with ModbusDriveAdapter.open_device(replace(device, allow_fault_reset=True), driver) as ad:
            assert ad.connect_report.faults_cleared and fw.fault_code == 0
    finally:
        if host is not None and host.poll() is None:
            host.kill()
        emu.close()
