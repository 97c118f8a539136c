"""Modbus transport throughput: table writes, capture reads and a whole buffered experiment.

Run by hand (never by the test suite)::

    python bench/modbus.py                       # TCP and RTU at 115200 baud, 10 s at 1 kHz
    python bench/modbus.py --links rtu --baud 921600
    python bench/modbus.py --duration 20 --channels excitation,torque_nm,velocity_mps

For each link (Modbus TCP on 127.0.0.1, Modbus RTU over a pseudo-terminal
whose bridge carries characters at the line rate) it starts the emulated
``modbus-servo`` drive, opens it with :class:`ModbusDriveAdapter` exactly as a
session does, and measures:

1. **table write**: ``load_table`` of a ``duration`` s excitation (stop, arm,
   paged write-multiple requests of 61 float32 samples, CRC check);
2. **whole experiment**: ``stream`` of the same excitation with the drive
   playing it in real time (``--time-scale``, default 1), capture read while
   the drive plays; the wall time from the first request to the last sample;
3. **capture read**: reading the whole capture of that run again
   (``read_capture``: paged reads of 125 registers at most, whole records).

Registers/s counts payload registers (table samples or capture records,
stamps included), not request headers.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.adapters.modbus.drive import ModbusDriveAdapter
from hilident.config.tables import DeviceConfig, load_config
from hilident.drivers.description import find_driver
from hilident.emulator.modbus.server import start
from hilident.events import StreamStats

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-modbus-gantry.toml"


def measure(link: str, args, driver) -> dict:
    cfg = load_config(CONFIG)
    emu_cfg = replace(cfg.emulator, time_scale=args.time_scale)
    emu = start(emu_cfg, driver, DeviceConfig(baudrate=args.baud, timeout_s=2.0), link=link)
    ad = ModbusDriveAdapter.open_device(emu.device, driver)
    try:
        lim = cfg.limits
        ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        channels = args.channels.split(",") if args.channels else None
        ad.configure(args.rate, "torque", channels)
        n = int(round(args.duration * args.rate))
        t = np.arange(n) / args.rate
        x = 2.0 * np.sin(2 * np.pi * 5.0 * t) * np.hanning(n)
        rps = ad.map.table_registers_per_sample
        width = ad.map.record_registers(ad.map.mask_of(ad.channel_names))

        t0 = time.perf_counter()
        ad.capture.load_table(x)
        table_s = time.perf_counter() - t0

        got = [0]

        def sink(index, rows):
            got[0] += len(index)

        t0 = time.perf_counter()
        result = ad.stream(x, sink)
        run_s = time.perf_counter() - t0

        stats = StreamStats()
        t0 = time.perf_counter()
        ad.capture.read_capture(0, n, lambda i, r: None, stats)
        read_s = time.perf_counter() - t0
        return {
            "link": "TCP" if link == "tcp" else f"RTU {args.baud}",
            "port": emu.port,
            "samples": n,
            "record": width,
            "table_regs_s": n * rps / table_s,
            "table_samples_s": n / table_s,
            "table_s": table_s,
            "read_regs_s": n * width / read_s,
            "read_samples_s": n / read_s,
            "read_s": read_s,
            "run_s": run_s,
            "delivered": got[0],
            "lost": result.stats.lost_samples + stats.lost_samples,
            "missing": result.stats.lost_frames,
        }
    finally:
        ad.close()
        emu.close()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--links", default="tcp,rtu", help="tcp, rtu or both")
    p.add_argument("--baud", type=int, default=115200, help="RTU line rate")
    p.add_argument("--duration", type=float, default=10.0, help="experiment length, s")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate, Hz")
    p.add_argument("--channels", default="", help="captured channels (default: the driver's)")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated s per wall s during the run")
    args = p.parse_args(argv)
    driver = find_driver("modbus-servo")
    rows = []
    for link in args.links.split(","):
        link = {"rtu": "pty", "tcp": "tcp"}[link.strip()]
        r = measure(link, args, driver)
        rows.append(r)
        print(f"{r['link']:>11}  ({r['port']}): {r['samples']} samples, {r['record']} registers a record", flush=True)
    print()
    print(
        f"{'link':>11} | {'table write':>28} | {'capture read':>28} | "
        f"{'whole ' + format(args.duration, 'g') + ' s experiment':>26}"
    )
    print(
        f"{'':>11} | {'registers/s':>13} {'samples/s':>14} | {'registers/s':>13} {'samples/s':>14} | "
        f"{'wall s':>8} {'lost':>6} {'no answer':>10}"
    )
    for r in rows:
        print(
            f"{r['link']:>11} | {r['table_regs_s']:13.0f} {r['table_samples_s']:14.0f} | {r['read_regs_s']:13.0f} "
            f"{r['read_samples_s']:14.0f} | {r['run_s']:8.2f} {r['lost']:6d} {r['missing']:10d}"
        )
    return 0 if all(r["lost"] == 0 and r["delivered"] == r["samples"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
