"""Time from a signal to a stopped axis, on each transport's twin.

For every transport a twin is served in this process on a real transport
(serial: a pseudo-terminal and a raw TCP line; Modbus TCP and RTU; CANopen
behind socketcand) and ``hilident run --yes`` runs against it in another
process, as on the bench. Once the identification run is moving the axis the
host gets SIGTERM; the script polls the twin's own drive state every 0.2 ms and
reports how long the axis stayed enabled after the signal (target: 100 ms).
It also SIGKILLs the host, which cannot clean up, and reports how long the
device took to stop on its own (its net: the board watchdog, the CANopen
heartbeat consumer, the Modbus communication timeout).

Usage::

    python bench/stop_latency.py [--repeats 5] [--only serial-pty,modbus-tcp]

Needs ``tomli-w`` (installed with ``.[test]``).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import tomli_w

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import host_device_table, start_standalone

ROOT = Path(__file__).resolve().parents[1]
SETUPS = {
    "serial-pty": ("pty", "emulated-gantry.toml"),
    "serial-tcp": ("tcp", "emulated-gantry.toml"),
    "modbus-tcp": ("tcp", "emulated-modbus-gantry.toml"),
    "modbus-rtu": ("rtu", "emulated-modbus-gantry.toml"),
    "canopen-socketcand": ("socketcand", "emulated-canopen-gantry.toml"),
}


def _settings(config: str) -> dict:
    raw = tomllib.loads((ROOT / "configs" / config).read_text())
    raw["friction_test"] = {"enabled": False}
    raw["excitation"].update(period_s=4.0, duration_s=40.0)  # long enough to be stopped mid-run
    raw["notch"]["verify"] = False
    if raw["device"]["driver"].startswith("modbus"):
        raw["device"]["baudrate"] = 921600
    return raw


def _until(condition, timeout_s: float, step_s: float = 0.0002) -> float | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return time.monotonic()
        time.sleep(step_s)
    return None


def one_ending(name: str, how: int, folder: Path) -> tuple[float | None, float]:
    """Start a twin and a host, end the host with signal ``how``; returns (seconds to a stopped axis, timeout)."""
    link, config = SETUPS[name]
    raw = _settings(config)
    cfg = parse_config(tomli_w.dumps(raw), config)
    emu = start_standalone(cfg.emulator, find_driver(cfg.device.driver), cfg.device, link)
    try:
        raw["device"] = host_device_table(replace(emu.device, driver=cfg.device.driver))
        path = folder / f"{name}.toml"
        path.write_text(tomli_w.dumps(raw))
        env = dict(os.environ, HILIDENT_LOCK_DIR=str(folder / "locks"))
        host = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hilident.cli",
                "run",
                str(path),
                "--yes",
                "-q",
                "--out",
                str(folder / name),
                "--clear-fault",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
        )
        if _until(lambda: emu.drive.enabled, 60, 0.001) is None:
            host.kill()
            raise RuntimeError(f"{name}: the host never enabled the drive: {host.communicate()[1][-500:]}")
        time.sleep(1.0)
        sent = time.monotonic()
        host.send_signal(how)
        stopped = _until(lambda: not emu.drive.enabled, 10)
        host.wait(30)
        net = 1.0 if name.startswith("serial") else cfg.device.host_timeout_s
        return (None if stopped is None else stopped - sent), net
    finally:
        emu.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", default="", help="comma-separated setups (default: all): " + ", ".join(SETUPS))
    args = ap.parse_args()
    names = [n for n in SETUPS if not args.only or n in args.only.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            term = [one_ending(name, signal.SIGTERM, Path(tmp))[0] for _ in range(args.repeats)]
            kills = [one_ending(name, signal.SIGKILL, Path(tmp)) for _ in range(args.repeats)]
            rows.append((name, term, [k for k, _ in kills], kills[0][1]))
    print(
        f"{'setup':<20} {'SIGTERM -> stopped, ms (median / max)':>38} {'SIGKILL -> device stops itself, ms':>36}"
        f" {'net timeout, ms':>16}"
    )
    for name, term, kill, net in rows:
        ok_t = [t for t in term if t is not None]
        ok_k = [t for t in kill if t is not None]
        t_txt = f"{1e3 * statistics.median(ok_t):.1f} / {1e3 * max(ok_t):.1f}" if ok_t else "never"
        k_txt = f"{1e3 * statistics.median(ok_k):.0f} / {1e3 * max(ok_k):.0f}" if ok_k else "never"
        missed = f" ({len(term) - len(ok_t)} never stopped)" if len(ok_t) < len(term) else ""
        print(f"{name:<20} {t_txt + missed:>38} {k_txt:>36} {1e3 * net:>16.0f}")
    print(json.dumps({n: {"sigterm_s": t, "sigkill_s": k} for n, t, k, _ in rows}), file=sys.stderr)


if __name__ == "__main__":
    main()
