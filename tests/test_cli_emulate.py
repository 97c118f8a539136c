"""`hilident emulate serial` runs a board another process reaches like hardware."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("extra", [("--tcp",)], ids=["socket-url"])  # the pty: tests/test_serial_endings.py
def test_standalone_emulator_runs_a_session_like_hardware(tmp_path, extra, standalone_emulator):
    port = standalone_emulator("serial", CONFIGS / "emulated-gantry.toml", "--time-scale", "8", *extra)
    assert port.startswith("/dev/") or port.startswith("socket://127.0.0.1:")
    text = (CONFIGS / "emulated-gantry.toml").read_text().replace('port = "emulator"', f'port = "{port}"')
    text = text.replace("[friction_test]", "[friction_test]\nenabled = false")
    text = text.replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")  # the line and the process, not the trials
    cfg = tmp_path / "bench.toml"
    cfg.write_text(text)
    out = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o"), "-q", "--yes"],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert out.returncode == 0, out.stderr
    assert "resonances: 21." in out.stdout
    assert (tmp_path / "o" / "summary.json").is_file()


def test_ctrl_c_mid_run_stops_and_keeps_the_recording(tmp_path):
    cfg = tmp_path / "slow.toml"
    cfg.write_text((CONFIGS / "emulated-gantry.toml").read_text().replace("time_scale = 4.0", "time_scale = 1.0"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as at a terminal, also in a background job
    )
    try:
        for line in proc.stderr:  # progress lines: wait until the friction test is streaming
            if "friction:  25 %" in line:
                break
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    from hilident.io.recording import read_run

    run = read_run(tmp_path / "o" / "friction.h5")
    assert run.status == "aborted" and run.n_samples > 0


@pytest.mark.parametrize(
    "flags",
    [("--time-scale", "nan"), ("--time-scale", "-1"), ("--time-scale", "inf"), ("--baudrate", "-5")],
    ids=["nan", "negative", "inf", "baud"],
)
def test_emulate_flags_are_checked(flags):
    done = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "emulate", "serial", *flags], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2
    assert done.stderr.startswith(f"hilident: error: {flags[0]}") and "Traceback" not in done.stderr


def test_emulate_canopen_port_out_of_range():
    done = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "emulate", "canopen", "--port", "70000"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and "--port 70000" in done.stderr and "Traceback" not in done.stderr


def test_a_closed_output_pipe_does_not_end_the_run(tmp_path):
    """Whoever read the progress went away (`| head`, a closed pipe): the run goes on and completes."""
    import tomllib

    import tomli_w

    raw = tomllib.loads((CONFIGS / "emulated-gantry.toml").read_text())
    raw["friction_test"] = {"enabled": False}
    raw["excitation"].update(period_s=2.0, duration_s=4.0, amplitude_nm=8.0)
    raw["emulator"]["time_scale"] = 8.0
    cfg = tmp_path / "quick.toml"
    cfg.write_text(tomli_w.dumps(raw))
    read_end, write_end = os.pipe()
    os.close(read_end)  # nobody will ever read the output
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o")],
            stdout=write_end,
            stderr=write_end,
            timeout=240,
        )
    finally:
        os.close(write_end)
    assert proc.returncode == 0
    assert (tmp_path / "o" / "summary.json").is_file()
    from hilident.io.recording import read_run

    assert read_run(tmp_path / "o" / "identification.h5").status == "complete"
