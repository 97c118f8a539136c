"""Nothing moves on a real port without a go-ahead; one session per device; the next session measures the bare plant."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilident.errors import DeviceError
from hilident.session.devicelock import DeviceLock, device_key
from support.twins import Twin, host, wait_until


@pytest.fixture
def serial_twin(tmp_path):
    t = Twin("serial", "pty", "emulated-gantry.toml", tmp_path)
    yield t
    t.close()


def _run(config: Path, out: Path, *extra: str, stdin=subprocess.DEVNULL, timeout=120):
    env = dict(os.environ, HILIDENT_LOCK_DIR=str(out.parent / "locks"))
    return subprocess.run(
        [sys.executable, "-m", "hilident.cli", "run", str(config), "--out", str(out), "--no-plots", *extra],
        capture_output=True,
        text=True,
        stdin=stdin,
        env=env,
        timeout=timeout,
    )


def _watch_enabled(twin: Twin) -> list[bool]:
    """Start noting whether the twin's drive is ever enabled (a background poll)."""
    import threading

    seen = [False]

    def poll():
        while not done[0]:
            seen[0] = seen[0] or twin.enabled
            time.sleep(0.001)

    done = [False]
    threading.Thread(target=poll, daemon=True).start()
    return seen, done


def test_a_real_port_without_yes_and_without_a_terminal_is_refused_and_nothing_moves(serial_twin, tmp_path):
    seen, done = _watch_enabled(serial_twin)
    result = _run(serial_twin.host_config("bench"), tmp_path / "o")
    done[0] = True
    assert result.returncode == 2
    assert "--yes" in result.stderr and "Traceback" not in result.stderr
    assert "identification: multisine" in result.stderr  # the plan was shown
    assert not seen[0]
    assert not list((tmp_path / "o").glob("*.h5"))


def test_dry_run_connects_checks_and_prints_the_plan_without_moving(serial_twin, tmp_path):
    seen, done = _watch_enabled(serial_twin)
    result = _run(serial_twin.host_config("bench"), tmp_path / "o", "--dry-run")
    done[0] = True
    assert result.returncode == 0, result.stderr
    assert "plan for myrio-board" in result.stdout and "peak torque 8 N*m" in result.stdout
    assert "nothing moved" in result.stdout
    assert not seen[0]
    assert not list((tmp_path / "o").glob("*.h5"))


def test_a_config_error_found_before_motion_names_the_key(serial_twin, tmp_path):
    config = serial_twin.host_config(
        "bench",
        excitation={"period_s": 4.0, "duration_s": 8.0},
        friction_test={"enabled": True, "speeds_mps": [0.3], "hold_s": 3.0},
    )
    result = _run(config, tmp_path / "o", "--yes")
    assert result.returncode == 2
    assert "[friction_test.speeds_mps]" in result.stderr
    assert not serial_twin.enabled and not list((tmp_path / "o").glob("*.h5"))


def test_an_unwritable_out_is_one_line_before_anything_moves(serial_twin, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    result = _run(serial_twin.host_config("bench"), blocker / "o", "--yes")
    assert result.returncode == 2
    assert result.stderr.strip().startswith("hilident: error: --out") and "Traceback" not in result.stderr


def test_a_second_session_on_the_same_device_is_refused_naming_the_holder(serial_twin, tmp_path):
    lock_dir = tmp_path / "locks"
    key = device_key("serial", serial_twin.emu.port)
    with DeviceLock(key, lock_dir):
        result = _run(serial_twin.host_config("bench"), tmp_path / "o", "--yes")
    assert result.returncode == 4
    assert f"pid {os.getpid()}" in result.stderr and "one session per device" in result.stderr


def test_a_lock_left_by_a_killed_session_is_recovered(tmp_path):
    key = device_key("serial", "/dev/ttyUSB-test")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from pathlib import Path;"
            "from hilident.session.devicelock import DeviceLock;"
            f"DeviceLock({key!r}, Path({str(tmp_path)!r})).acquire(); print('held', flush=True);"
            "time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(DeviceError, match=f"pid {holder.pid}"):
        DeviceLock(key, tmp_path).acquire()
    holder.kill()
    holder.wait()
    lock = DeviceLock(key, tmp_path).acquire()
    assert lock.recovered_from == holder.pid
    lock.release()


def test_two_sessions_back_to_back_the_second_measures_the_bare_plant(serial_twin, tmp_path):
    """The first session leaves its notch in the board; the second bypasses it, measures the plant without it,
    finds the same resonance and notches it again."""
    config = serial_twin.host_config("bench", notch={"verify": True})
    first = _run(config, tmp_path / "one", "--yes", "-q")
    assert first.returncode == 0, first.stderr
    second = _run(config, tmp_path / "two", "--yes", "-q")
    assert second.returncode == 0, second.stderr
    summary = json.loads((tmp_path / "two" / "summary.json").read_text())
    found = summary["resonances"][0]["frequency_hz"]
    assert abs(found - serial_twin.truth_hz) / serial_twin.truth_hz < 0.005
    assert summary["verification"]["peak_reduction_db"] >= 20.0
    before = [f for f in summary["filters_found"] if f["enabled"]]
    assert before and before[0]["bypassed"]  # the first session's notch was there, and out of the way


def test_a_session_ended_before_its_upload_puts_the_filters_back(serial_twin, tmp_path):
    config = serial_twin.host_config("bench", notch={"verify": False})
    assert _run(config, tmp_path / "one", "--yes", "-q").returncode == 0
    stored_before = json.loads((tmp_path / "one" / "summary.json").read_text())["upload"]["slots"][0]
    proc = host(config, tmp_path / "two")
    wait_until(lambda: serial_twin.enabled, 60, proc)
    proc.terminate()
    assert proc.wait(30) == 143
    third = _run(config, tmp_path / "three", "--dry-run")
    assert third.returncode == 0, third.stderr
    assert f"filter slots [{stored_before['slot']}] hold filters" in third.stdout


def test_a_session_with_nothing_to_upload_leaves_the_filters_as_it_found_them(serial_twin, tmp_path):
    config = serial_twin.host_config("bench", notch={"verify": False})
    assert _run(config, tmp_path / "one", "--yes", "-q").returncode == 0
    measuring_only = serial_twin.host_config("measure", notch={"enabled": False})
    second = _run(measuring_only, tmp_path / "two", "--yes", "-q")
    assert second.returncode == 0, second.stderr
    found = json.loads((tmp_path / "two" / "summary.json").read_text())["filters_found"]
    enabled = [f for f in found if f["enabled"]]
    assert enabled and enabled[0]["bypassed"] and enabled[0]["restored"]
    third = _run(config, tmp_path / "three", "--dry-run")
    assert f"filter slots [{enabled[0]['slot']}] hold filters" in third.stdout
