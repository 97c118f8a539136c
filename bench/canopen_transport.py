"""CANopen transport benchmarks against the emulated CiA 402 drive. Run by hand, never by the tests::

    python bench/canopen_transport.py                   # 60 s per streaming trial: about half an hour
    python bench/canopen_transport.py --duration 5      # quick look, a few minutes

Two setups, each measured the same way:

``virtual``
    the drive runs in this process on python-can's ``virtual`` bus (one
    interpreter: host, drive and both bus threads share the GIL);
``socketcand``
    the drive runs in another process (``hilident emulate canopen``) behind its
    socketcand server on 127.0.0.1; the host uses python-can's ``socketcand``
    interface, as it would a socketcand daemon in front of a real bus.

1. **Host-streamed SYNC rate.** The adapter streams a small torque sine with
   one RPDO and one SYNC per sample, at the drive's fastest sample rate
   (``--sample-rate``, one loop tick per SYNC), and three TPDOs come back per
   SYNC. The SYNC rate is the adapter's ``sync_rate_hz``: the emulated drive's
   clock follows SYNC, so it may run faster than real time. A trial of
   ``--duration`` seconds is clean when no PDO was lost or late, the drive saw
   no set-point underrun and no SYNC counter jump, every sample arrived, and
   the SYNCs kept 98 % of the asked rate. The rate doubles from 500/s until a
   trial fails, then is bisected to ``--resolution``.
2. **SDO throughput.** Download and upload of the excitation-table DOMAIN
   (0x2200), by block transfer and by segmented transfer, in kB/s (1 kB = 1000
   bytes of payload).
3. **Drive-buffered capture.** 10 s at the drive's fastest sample rate in real
   time (``time_scale`` 1): table download, then play and capture while the
   host reads the capture back in chunks; printed are the table download
   time, the whole run, and how long after the table's end the last sample
   was home.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hilident.adapters.canopen_drive import CanopenDriveAdapter
from hilident.config import load_config
from hilident.drivers import find_driver
from hilident.emulator.canopen_drive import start
from hilident.errors import HilidentError

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-canopen-gantry.toml"
LIMITS = (50.0, 10.0, -10.0, 10.0)  # wide: the bench measures the bus, not the axis


@dataclass
class Trial:
    rate: float
    achieved: float
    samples: int
    lost_frames: int
    lost_samples: int
    late: int
    underruns: int
    late_syncs: int
    clean: bool
    note: str = ""


class Setup:
    """An emulated drive and an adapter on it."""

    def __init__(self, kind: str, driver_name: str):
        cfg = load_config(CONFIG)
        self.kind = kind
        self.driver = find_driver(driver_name)
        self.proc = None
        self.emulated = None
        emu = replace(cfg.emulator, time_scale=1.0)
        if kind == "virtual":
            self.emulated = start(emu, self.driver, cfg.device)
            device = self.emulated.device
        else:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "hilident.cli", "emulate", "canopen", "--config", str(CONFIG),
                 "--driver", driver_name, "--time-scale", "1"],
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            port = self.proc.stdout.readline().strip()
            device = replace(cfg.device, can_interface="socketcand", port=port)
        self.device = device
        self.adapter = CanopenDriveAdapter.open_device(device, self.driver)
        self.adapter.set_limits(*LIMITS)

    def close(self) -> None:
        self.adapter.close()
        if self.emulated is not None:
            self.emulated.close()
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)


def wait_until_answering(ad, limit_s: float = 120.0) -> None:
    """After an overload the drive may still be working off queued frames: wait for an SDO answer."""
    deadline = time.monotonic() + limit_s
    while True:
        try:
            ad.read("statusword")
            return
        except HilidentError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def streaming_trial(setup: Setup, rate: float, duration: float, sample_rate: float) -> Trial:
    ad = setup.adapter
    wait_until_answering(ad)
    ad.acquisition = "streamed"
    ad.configure(sample_rate, "torque")
    ad.sync_rate_hz = rate
    n = int(rate * duration)
    x = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / sample_rate)
    count = [0]

    def sink(index, rows):
        count[0] += len(index)

    t0 = time.perf_counter()
    note = ""
    try:
        result = ad.stream(x, sink)
    except HilidentError as exc:
        result, note = ad.last_result, str(exc)
    wall = time.perf_counter() - t0
    s = result.stats
    late_syncs = sum(int(e.get("value", 0)) for e in result.events if e["kind"] == "sync_late")
    achieved = count[0] / wall  # samples that arrived per second (all of them in a clean trial)
    clean = (not note and s.lost_frames == 0 and s.lost_samples == 0 and s.out_of_order == 0 and s.underruns == 0
             and count[0] == n and not any(e["kind"] == "sync_errors" for e in result.events)
             and achieved >= 0.98 * rate)
    return Trial(rate, achieved, count[0], s.lost_frames, s.lost_samples, s.out_of_order, s.underruns, late_syncs,
                 clean, note)


def find_sync_rate(setup: Setup, duration: float, sample_rate: float, resolution: float) -> list[Trial]:
    trials = []

    def run(rate):
        t = streaming_trial(setup, rate, duration, sample_rate)
        trials.append(t)
        verdict = "clean" if t.clean else "LOSS"
        print(f"  {setup.kind:10s} {rate:8.0f}/s asked {t.achieved:8.0f}/s received  lost frames {t.lost_frames:5d}  "
              f"lost samples {t.lost_samples:5d}  late {t.late:4d}  underruns {t.underruns:4d}  "
              f"late SYNCs {t.late_syncs:5d}  {verdict} {t.note[:60]}", flush=True)
        return t.clean

    good, bad = 0.0, None
    rate = 500.0
    while bad is None and rate <= 64000:
        if run(rate):
            good, rate = rate, rate * 2
        else:
            bad = rate
    while bad is not None and bad - good > max(resolution, 0.05 * good):
        mid = round((good + bad) / 2 / 50) * 50
        if run(mid):
            good = mid
        else:
            bad = mid
    trials.append(Trial(good, 0, 0, 0, 0, 0, 0, 0, True, "best"))
    return trials


def sdo_throughput(setup: Setup, block_bytes: int, segmented_bytes: int) -> dict:
    ad = setup.adapter
    wait_until_answering(ad)
    table = ad.desc.address("table")
    original = ad.desc
    out = {}
    try:
        for label, block, size in (("block", True, block_bytes), ("segmented", False, segmented_bytes)):
            ad.desc = replace(original, block_transfer=block)
            data = np.random.default_rng(1).standard_normal(size // 4).astype("<f4").tobytes()
            t0 = time.perf_counter()
            ad.write_domain(table, data)
            down = time.perf_counter() - t0
            t0 = time.perf_counter()
            back = ad.read_domain(table)
            up = time.perf_counter() - t0
            assert back == data, "upload differs from download"
            out[label] = (len(data) / down / 1e3, len(data) / up / 1e3, len(data))
    finally:
        ad.desc = original
    return out


def buffered_capture(setup: Setup, seconds: float, sample_rate: float) -> dict:
    ad = setup.adapter
    ad.acquisition = "buffered"
    ad.configure(sample_rate, "torque")
    n = int(seconds * sample_rate)
    x = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / sample_rate)
    marks = {}
    write = ad.write

    def timed_write(role, value):
        write(role, value)
        if role == "table_command":
            marks["started"] = time.perf_counter()

    last = [0.0]

    def sink(index, rows):
        last[0] = time.perf_counter()

    ad.write = timed_write
    t0 = time.perf_counter()
    try:
        result = ad.stream(x, sink)
    finally:
        del ad.write
    total = time.perf_counter() - t0
    return {"samples": result.stats.samples, "record_bytes": sum(c.bits for c in ad.channels) // 8,
            "download_s": marks["started"] - t0, "total_s": total,
            "lag_s": last[0] - marks["started"] - seconds}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--duration", type=float, default=60.0, help="seconds per streaming trial (default 60)")
    p.add_argument("--sample-rate", type=float, default=4000.0, help="drive sample rate of the runs (default 4000)")
    p.add_argument("--resolution", type=float, default=250.0, help="SYNC-rate resolution of the search, 1/s")
    p.add_argument("--driver", default="canopen-servo")
    p.add_argument("--setups", default="virtual,socketcand")
    p.add_argument("--capture-s", type=float, default=10.0, help="length of the buffered capture (default 10 s)")
    args = p.parse_args(argv)
    summary = []
    for kind in [s.strip() for s in args.setups.split(",") if s.strip()]:
        print(f"\n== {kind} ==", flush=True)
        setup = Setup(kind, args.driver)
        try:
            print(f"host-streamed, {args.duration:g} s per trial, {args.sample_rate:g} Hz samples, 3 TPDOs + "
                  "RPDO + SYNC per sample:")
            trials = find_sync_rate(setup, args.duration, args.sample_rate, args.resolution)
            best = trials[-1].rate
            sdo = sdo_throughput(setup, 256_000, 64_000)
            for label, (down, up, size) in sdo.items():
                print(f"SDO {label:9s} transfer of {size / 1e3:.0f} kB: download {down:7.1f} kB/s, "
                      f"upload {up:7.1f} kB/s", flush=True)
            cap = buffered_capture(setup, args.capture_s, args.sample_rate)
            print(f"buffered: {cap['samples']} samples ({args.capture_s:g} s at {args.sample_rate:g} Hz, "
                  f"{cap['record_bytes']} B a sample): table download {cap['download_s']:.2f} s, whole run "
                  f"{cap['total_s']:.2f} s, last sample home {cap['lag_s']:.2f} s after the table ended", flush=True)
            summary.append((kind, best, sdo, cap))
        finally:
            setup.close()
    print("\n== summary ==")
    print("setup       SYNC/s held   block down/up kB/s   segmented down/up kB/s   buffered 10 s: run, lag")
    for kind, best, sdo, cap in summary:
        print(f"{kind:10s} {best:10.0f}   {sdo['block'][0]:7.1f} / {sdo['block'][1]:7.1f}      "
              f"{sdo['segmented'][0]:7.1f} / {sdo['segmented'][1]:7.1f}          "
              f"{cap['total_s']:.2f} s, {cap['lag_s']:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
