"""Standalone twins served in the test process, and `hilident run` hosts in other processes, as on a bench."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import tomli_w

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import host_device_table, start_standalone, true_modes

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

#: (transport, link, shipped config the twin and the host take their settings from)
TRANSPORTS = [
    ("serial", "pty", "emulated-gantry.toml"),
    ("serial", "tcp", "emulated-gantry.toml"),
    ("modbus", "tcp", "emulated-modbus-gantry.toml"),
    ("modbus", "rtu", "emulated-modbus-gantry.toml"),
    ("canopen", "socketcand", "emulated-canopen-gantry.toml"),
]

#: The device-side net's timeout in these tests, s: long enough that a loaded test machine's stalls are not a
#: dead host, short enough to watch a real one fire.
HOST_TIMEOUT_S = 1.0


def quick(raw: dict, transport: str) -> dict:
    """The shipped config made quick: no friction test, two 2 s multisine periods at a fixed amplitude, fast
    simulated time, the clean twin."""
    raw = json.loads(json.dumps(raw))
    raw["friction_test"] = {"enabled": False}
    raw["excitation"].update(period_s=2.0, duration_s=4.0, amplitude_nm=8.0)  # no auto trials before the run
    raw["emulator"]["time_scale"] = 8.0
    raw["emulator"]["preset"] = "clean"  # these twins test endings and protocol, not the bench's noise
    raw["notch"]["verify"] = False
    raw["device"]["host_timeout_s"] = HOST_TIMEOUT_S
    if transport == "modbus":
        raw["device"]["baudrate"] = 921600  # an RTU line reads the capture back: keep it quick
        raw["run"]["sample_rate_hz"] = 500.0  # and half the registers to read (the multisine ends at 80 Hz)
    return raw


class Twin:
    """A standalone twin in this process, and host configs that reach it."""

    def __init__(self, transport: str, link: str, config: str, tmp_path: Path):
        self.transport, self.link, self.tmp = transport, link, tmp_path
        self.raw = quick(tomllib.loads((CONFIGS / config).read_text()), transport)
        cfg = parse_config(tomli_w.dumps(self.raw), str(CONFIGS / config))
        self.cfg = cfg
        self.driver = find_driver(cfg.device.driver, cfg.device.driver_paths)
        self.emu = start_standalone(cfg.emulator, self.driver, cfg.device, link)
        self.truth_hz = true_modes(cfg.emulator)[0][0]

    @property
    def enabled(self) -> bool:
        return bool(self.emu.drive.enabled)

    def host_config(self, name: str, **sections) -> Path:
        raw = json.loads(json.dumps(self.raw))
        raw["device"] = host_device_table(replace(self.emu.device, driver=self.cfg.device.driver))
        for section, values in sections.items():
            raw.setdefault(section, {}).update(values)
        path = self.tmp / f"{name}.toml"
        path.write_text(tomli_w.dumps(raw))
        return path

    def close(self) -> None:
        self.emu.close()


def host(config: Path, out: Path, *extra: str, fsize_limit: int | None = None) -> subprocess.Popen:
    # PYTHONFAULTHANDLER: a host that hangs dumps every thread's stack on SIGABRT (see finish())
    env = dict(os.environ, HILIDENT_LOCK_DIR=str(out.parent / "locks"), PYTHONFAULTHANDLER="1")

    def limit_file_size():
        # Ctrl-C and a closed terminal reach the host as at a terminal, also when this suite runs as a
        # background job (SIGINT ignored) or under nohup (SIGHUP ignored): ignored signals stay ignored in hilident
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        if fsize_limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) as on a full disk
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_limit, fsize_limit))

    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hilident.cli",
            "run",
            str(config),
            "--out",
            str(out),
            "--yes",
            "-q",
            "--no-plots",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=limit_file_size,
    )


def finish(proc: subprocess.Popen, timeout: float = 60) -> tuple[int, str]:
    """Wait for a host to exit; returns (exit code, stderr).

    A host still running after ``timeout`` s is sent SIGABRT first, so its
    stderr ends with the stack of every thread (faulthandler), then killed.
    """
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        try:
            _, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        err = f"host still running after {timeout:g} s; its threads:\n{err}"
    return proc.returncode, err


def wait_until(condition, timeout_s: float, proc: subprocess.Popen | None = None) -> float:
    """Poll ``condition`` every millisecond; returns when it became true (monotonic s)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return time.monotonic()
        if proc is not None and proc.poll() is not None:
            out, err = proc.communicate()
            raise AssertionError(f"host ended early (rc {proc.returncode}): {err[-2000:]}")
        time.sleep(0.001)
    raise AssertionError("timed out")


def assert_friction_matches(friction: dict, truth) -> None:
    """Fc and Fv agree with the twin's within what the fit says it knows (3 standard errors, at least 5 %),
    and the fit claims to know them to 25 %: a bench-like twin's disturbances scatter the friction points, and
    the configured legs alone (the suite's sessions play no added rounds, tests/conftest.py) give a few
    direction pairs, whose standard error is that of few degrees of freedom."""
    got, stderr = friction["params"], friction["stderr"]
    for name in ("Fc", "Fv"):
        want = getattr(truth, name)
        assert stderr[name] < 0.25 * want, (name, got[name], stderr[name])
        assert abs(got[name] - want) < max(0.05 * want, 3 * stderr[name]), (name, got[name], stderr[name], want)
