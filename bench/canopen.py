"""CANopen transport benchmarks against emulated CiA 402 drives. Run by hand, never by the tests::

    python bench/canopen.py                      # 60 s per search trial: about an hour
    python bench/canopen.py --duration 5         # quick search; the 1 kHz / 60 s trial stays in full
    python bench/canopen.py --parts fixed        # only the 1 kHz / 60 s trial over socketcand

Two setups, each measured the same way:

``virtual``
    the drive runs in this process on python-can's ``virtual`` bus (one
    interpreter: host, drive and both bus threads share the GIL);
``socketcand``
    the drive runs in another process (``hilident emulate canopen``) behind its
    socketcand server on 127.0.0.1; the host uses python-can's ``socketcand``
    interface, as it would a socketcand daemon in front of a real bus.

Two drivers: ``--driver`` (default ``cia402-standard``: a drive described by
its EDS alone, standard objects only, TPDOs matched to SYNCs by bus order) and
the ones of ``--search-drivers`` (default: ``canopen-servo``, whose TPDOs carry
the hilident sample counter, and ``--driver``). Every criterion below comes
from the run's own ``RunResult`` (its stats and events), never from objects a
standard drive lacks.

1. **Fixed-rate trial** (``--driver``, socketcand). ``--fixed-rate`` SYNC/s
   (1000) for ``--fixed-duration`` seconds (60) in real time: the sample rate
   is the SYNC rate (``sync_rate_hz`` None) and the drive runs at
   ``time_scale`` 1 in its own process. Printed: samples received of those
   asked, lost samples and frames, late and corrupt frames, SYNCs sent more
   than one period late and the worst lateness, SYNCs unanswered; PASS when
   nothing was lost and every sample arrived.
2. **Host-streamed SYNC rate** (every search driver, every setup). The adapter
   streams a small torque sine with one RPDO and one SYNC per sample, at the
   drive's fastest sample rate (``--sample-rate``, one loop tick per SYNC),
   and the TPDOs come back per SYNC. The SYNC rate is the adapter's
   ``sync_rate_hz``: the emulated drive's clock follows SYNC, so it may run
   faster than real time. A trial of ``--duration`` seconds is clean when no
   PDO was lost or late, no SYNC went unanswered, the drive reported no
   set-point underrun or SYNC counter jump (drives with the hilident counters
   only), every sample arrived, and the SYNCs kept 98 % of the asked rate. The
   rate doubles from 500/s until a trial fails, then is bisected to
   ``--resolution``.
3. **SDO throughput** (``--driver``, drives with an excitation table only).
   Download and upload of the excitation-table DOMAIN (0x2200), by block
   transfer and by segmented transfer, in kB/s (1 kB = 1000 bytes of payload).
4. **Drive-buffered capture** (``--driver``, drives with an excitation table
   only). 10 s at the drive's fastest sample rate in real time
   (``time_scale`` 1): table download, then play and capture while the host
   reads the capture back in chunks; printed are the table download time, the
   whole run, and how long after the table's end the last sample was home.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.emulator.canopen.server import start
from hilident.errors import HilidentError

# the gantry of the shipped configs; the bench picks the driver, the plant is the same for all
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-cia402-gantry.toml"
LIMITS = (50.0, 10.0, -10.0, 10.0)  # wide: the bench measures the bus, not the axis
SETUPS = ("virtual", "socketcand")


@dataclass
class Trial:
    """One host-streamed run and what its RunResult says about it."""

    rate: float  # SYNC/s asked
    achieved: float  # samples received per wall-clock second
    asked: int  # samples played
    samples: int  # samples received
    lost_frames: int
    lost_samples: int
    late: int  # TPDOs that came after their sample was given up
    corrupt: int
    underruns: int  # set-point underruns the drive reported (drives with the hilident counters only)
    sync_errors: int  # SYNC counter jumps the drive reported (idem)
    late_syncs: int  # SYNCs sent more than one period after their due time
    worst_late_ms: float
    unanswered: int  # SYNCs that got no TPDO at all (drives matched by bus order)
    clean: bool
    note: str = ""


class Setup:
    """An emulated drive and an adapter on it.

    Parameters
    ----------
    kind : {"virtual", "socketcand"}
        The drive in this process on a virtual bus, or in a ``hilident emulate
        canopen`` process behind socketcand on 127.0.0.1.
    driver_name : str
        Driver name or folder, for the drive and the host alike.
    """

    def __init__(self, kind: str, driver_name: str):
        cfg = load_config(CONFIG)
        self.kind = kind
        self.driver = find_driver(driver_name, cfg.device.driver_paths)
        self.proc = None
        self.emulated = None
        device = replace(cfg.device, driver=driver_name, acquisition="streamed")
        emu = replace(cfg.emulator, time_scale=1.0)
        if kind == "virtual":
            self.emulated = start(emu, self.driver, device)
            device = self.emulated.device
        else:
            self.proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "hilident.cli",
                    "emulate",
                    "canopen",
                    "--config",
                    str(CONFIG),
                    "--driver",
                    driver_name,
                    "--time-scale",
                    "1",
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            port = self.proc.stdout.readline().strip()
            if not port:
                self.proc.wait(timeout=10)
                raise HilidentError(
                    f"hilident emulate canopen --driver {driver_name} exited ({self.proc.returncode}) without serving"
                )
            device = replace(device, can_interface="socketcand", port=port)
        self.device = device
        try:
            self.adapter = CanopenDriveAdapter.open_device(device, self.driver)
            self.adapter.set_limits(*LIMITS)
        except BaseException:
            self._stop_drive()
            raise

    @property
    def has_table(self) -> bool:
        """The drive has the excitation table (and capture) objects of drive-buffered runs."""
        try:
            self.adapter.desc.require_buffered()
        except HilidentError:
            return False
        return True

    def close(self) -> None:
        self.adapter.close()
        self._stop_drive()

    def _stop_drive(self) -> None:
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
            ad.sdo.read("statusword")
            return
        except HilidentError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def _event_value(events, kind: str) -> int:
    return sum(int(e.get("value", 0)) for e in events if e["kind"] == kind)


def _worst_late_ms(events) -> float:
    """The worst SYNC lateness, ms, as the run's ``sync_late`` event states it."""
    worst = 0.0
    for e in events:
        m = re.search(r"worst ([0-9.]+) ms", e.get("message", "")) if e["kind"] == "sync_late" else None
        if m:
            worst = max(worst, float(m.group(1)))
    return worst


def streaming_trial(setup: Setup, rate: float | None, duration: float, sample_rate: float) -> Trial:
    """Stream a 0.5 N*m, 3 Hz torque sine for ``duration`` s of SYNCs at ``rate`` (None: the sample rate)."""
    ad = setup.adapter
    wait_until_answering(ad)
    ad.acquisition = "streamed"
    ad.configure(sample_rate, "torque")
    ad.sync_rate_hz = rate
    rate = rate or ad.sample_rate_hz
    n = round(rate * duration)
    x = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / ad.sample_rate_hz)
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
    if result is None:  # broke off before the run began
        return Trial(rate, 0.0, n, 0, 0, 0, 0, 0, 0, 0, 0, 0.0, 0, False, note)
    s, ev = result.stats, result.events
    sync_errors = _event_value(ev, "sync_errors")
    unanswered = _event_value(ev, "sync_unanswered")
    achieved = count[0] / wall  # samples that arrived per second (all of them in a clean trial)
    clean = (
        not note
        and s.lost_frames == 0
        and s.lost_samples == 0
        and s.out_of_order == 0
        and s.corrupt_frames == 0
        and s.underruns == 0
        and sync_errors == 0
        and unanswered == 0
        and count[0] == n
        and achieved >= 0.98 * rate
    )
    return Trial(
        rate,
        achieved,
        n,
        count[0],
        s.lost_frames,
        s.lost_samples,
        s.out_of_order,
        s.corrupt_frames,
        s.underruns,
        sync_errors,
        _event_value(ev, "sync_late"),
        _worst_late_ms(ev),
        unanswered,
        clean,
        note,
    )


def find_sync_rate(setup: Setup, duration: float, sample_rate: float, resolution: float) -> tuple[float, list[Trial]]:
    """The highest clean SYNC rate (0: not even 500/s) and every trial run to find it."""
    trials = []
    name = setup.driver.name

    def run(rate):
        t = streaming_trial(setup, rate, duration, sample_rate)
        trials.append(t)
        verdict = "clean" if t.clean else "LOSS"
        print(
            f"  {name:16s} {setup.kind:10s} {rate:8.0f}/s asked {t.achieved:8.0f}/s received  "
            f"lost frames {t.lost_frames:5d}  lost samples {t.lost_samples:5d}  late {t.late:4d}  "
            f"unanswered {t.unanswered:4d}  underruns {t.underruns:4d}  late SYNCs {t.late_syncs:5d} "
            f"(worst {t.worst_late_ms:.1f} ms)  {verdict} {t.note[:80]}",
            flush=True,
        )
        return t.clean

    good, bad = 0.0, None
    rate = 500.0
    while bad is None and rate <= 64000:
        if run(rate):
            good, rate = rate, rate * 2
        else:
            bad = rate
    while bad is not None and good and bad - good > max(resolution, 0.05 * good):
        mid = round((good + bad) / 2 / 50) * 50
        if run(mid):
            good = mid
        else:
            bad = mid
    return good, trials


def machine_load() -> str:
    """The load average over 1 and 5 minutes and the CPU count: the trials share the machine."""
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs"


def fixed_rate_trial(driver: str, rate: float, duration: float) -> Trial:
    """``rate`` SYNC/s in real time for ``duration`` s, the drive in its own process behind socketcand."""
    setup = Setup("socketcand", driver)
    print(f"  before: {machine_load()}", flush=True)
    try:
        return streaming_trial(setup, None, duration, rate)
    finally:
        print(f"  after:  {machine_load()}", flush=True)
        setup.close()


def passed(t: Trial) -> bool:
    """The fixed-rate criterion: nothing lost, every sample home, the run not broken off."""
    return t.lost_samples == 0 and t.lost_frames == 0 and t.samples == t.asked and not t.note


def print_fixed(driver: str, t: Trial, duration: float) -> None:
    verdict = "PASS" if passed(t) else "FAIL"
    print(
        f"{driver}, socketcand, {t.rate:g} SYNC/s for {duration:g} s (real time, drive in its own process):\n"
        f"  samples {t.samples} of {t.asked}, lost samples {t.lost_samples}, lost frames {t.lost_frames}, "
        f"late frames {t.late}, corrupt frames {t.corrupt}\n"
        f"  SYNCs more than one period late {t.late_syncs} (worst {t.worst_late_ms:.2f} ms), "
        f"SYNCs unanswered {t.unanswered}, received {t.achieved:.1f} samples/s\n"
        f"  {verdict}{': ' + t.note if t.note else ''}",
        flush=True,
    )


def sdo_throughput(setup: Setup, block_bytes: int, segmented_bytes: int) -> dict:
    ad = setup.adapter
    wait_until_answering(ad)
    table = ad.desc.address("table")
    original = ad.sdo.block_transfer
    out = {}
    try:
        for label, block, size in (("block", True, block_bytes), ("segmented", False, segmented_bytes)):
            ad.sdo.block_transfer = block
            data = np.random.default_rng(1).standard_normal(size // 4).astype("<f4").tobytes()
            t0 = time.perf_counter()
            ad.sdo.write_domain(table, data)
            down = time.perf_counter() - t0
            t0 = time.perf_counter()
            back = ad.sdo.read_domain(table)
            up = time.perf_counter() - t0
            assert back == data, "upload differs from download"
            out[label] = (len(data) / down / 1e3, len(data) / up / 1e3, len(data))
    finally:
        ad.sdo.block_transfer = original
    return out


def buffered_capture(setup: Setup, seconds: float, sample_rate: float) -> dict:
    ad = setup.adapter
    ad.acquisition = "buffered"
    ad.configure(sample_rate, "torque")
    n = int(seconds * sample_rate)
    x = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / sample_rate)
    marks = {}
    write = ad.sdo.write

    def timed_write(role, value):
        write(role, value)
        if role == "table_command":
            marks["started"] = time.perf_counter()

    last = [0.0]

    def sink(index, rows):
        last[0] = time.perf_counter()

    ad.sdo.write = timed_write
    t0 = time.perf_counter()
    try:
        result = ad.stream(x, sink)
    finally:
        del ad.sdo.write
    total = time.perf_counter() - t0
    return {
        "samples": result.stats.samples,
        "record_bytes": sum(c.bits for c in ad.layout.channels) // 8,
        "download_s": marks["started"] - t0,
        "total_s": total,
        "lag_s": last[0] - marks["started"] - seconds,
    }


def table_parts(setup: Setup, args) -> tuple[str, str]:
    """SDO throughput and the drive-buffered capture on ``setup``, as two summary cells."""
    name = setup.driver.name
    if not setup.has_table:
        print(f"SDO throughput: skipped: {name} has no excitation table", flush=True)
        print(f"buffered capture: skipped: {name} has no excitation table", flush=True)
        return "no table", "no table"
    sdo = sdo_throughput(setup, 256_000, 64_000)
    for label, (down, up, size) in sdo.items():
        print(
            f"SDO {label:9s} transfer of {size / 1e3:.0f} kB: download {down:7.1f} kB/s, upload {up:7.1f} kB/s",
            flush=True,
        )
    cap = buffered_capture(setup, args.capture_s, args.sample_rate)
    print(
        f"buffered: {cap['samples']} samples ({args.capture_s:g} s at {args.sample_rate:g} Hz, "
        f"{cap['record_bytes']} B a sample): table download {cap['download_s']:.2f} s, whole run "
        f"{cap['total_s']:.2f} s, last sample home {cap['lag_s']:.2f} s after the table ended",
        flush=True,
    )
    return (
        f"{sdo['block'][0]:.1f}/{sdo['block'][1]:.1f} seg {sdo['segmented'][0]:.1f}/{sdo['segmented'][1]:.1f}",
        f"{cap['total_s']:.2f} s, lag {cap['lag_s']:.2f} s",
    )


def _names(text: str) -> list[str]:
    return list(dict.fromkeys(s.strip() for s in text.split(",") if s.strip()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--driver",
        default="cia402-standard",
        help="driver of the fixed-rate trial, the SDO and the buffered parts (default cia402-standard)",
    )
    p.add_argument(
        "--search-drivers",
        default="canopen-servo",
        help="drivers of the SYNC-rate search besides --driver (default canopen-servo)",
    )
    p.add_argument(
        "--parts",
        default="fixed,search,table",
        help="what to run: fixed (the fixed-rate trial), search (the SYNC-rate search), "
        "table (SDO throughput and buffered capture); default all",
    )
    p.add_argument("--fixed-rate", type=float, default=1000.0, help="SYNC/s of the fixed-rate trial (default 1000)")
    p.add_argument("--fixed-duration", type=float, default=60.0, help="seconds of the fixed-rate trial (default 60)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per search trial (default 60)")
    p.add_argument("--sample-rate", type=float, default=4000.0, help="drive sample rate of the search (default 4000)")
    p.add_argument("--resolution", type=float, default=250.0, help="SYNC-rate resolution of the search, 1/s")
    p.add_argument("--setups", default="virtual,socketcand")
    p.add_argument("--capture-s", type=float, default=10.0, help="length of the buffered capture (default 10 s)")
    args = p.parse_args(argv)
    parts = set(_names(args.parts))
    unknown = parts - {"fixed", "search", "table"}
    setups = _names(args.setups)
    if unknown or any(s not in SETUPS for s in setups):
        p.error(f"unknown part or setup: {', '.join(sorted(unknown) + [s for s in setups if s not in SETUPS])}")
    fixed = None
    if "fixed" in parts:
        print(f"\n== fixed rate: {args.driver} ==", flush=True)
        fixed = fixed_rate_trial(args.driver, args.fixed_rate, args.fixed_duration)
        print_fixed(args.driver, fixed, args.fixed_duration)
    if "search" in parts:
        print(f"\nsearch starts at {machine_load()}", flush=True)
    rows = {}  # (driver, setup) -> [SYNC/s held, trials, SDO, buffered, TPDO matching]
    drivers = _names(args.search_drivers) + [args.driver]
    drivers = list(dict.fromkeys(drivers))
    for kind in setups:
        for driver in drivers:
            wanted = ("search" in parts) or ("table" in parts and driver == args.driver)
            if not wanted:
                continue
            print(f"\n== {driver}, {kind} ({machine_load()}) ==", flush=True)
            setup = Setup(kind, driver)
            row = rows.setdefault((driver, kind), ["-", "-", "-", "-", "-"])
            row[4] = "counter" if setup.adapter.desc.counted else "order"
            try:
                if "search" in parts:
                    print(
                        f"host-streamed, {args.duration:g} s per trial, {args.sample_rate:g} Hz samples, "
                        "RPDO + SYNC out, TPDOs back per sample:",
                        flush=True,
                    )
                    best, trials = find_sync_rate(setup, args.duration, args.sample_rate, args.resolution)
                    print(f"  highest lossless SYNC rate: {best:.0f}/s", flush=True)
                    row[0], row[1] = f"{best:.0f}", str(len(trials))
                if "table" in parts and driver == args.driver:
                    row[2], row[3] = table_parts(setup, args)
            finally:
                setup.close()
    print("\n== summary ==")
    if fixed is not None:
        verdict = "PASS" if passed(fixed) else "FAIL"
        print(
            f"fixed rate, {args.driver}, socketcand, {fixed.rate:g} SYNC/s x {args.fixed_duration:g} s: "
            f"{fixed.samples}/{fixed.asked} samples, lost {fixed.lost_samples} samples / {fixed.lost_frames} frames, "
            f"sync_late {fixed.late_syncs} (worst {fixed.worst_late_ms:.2f} ms), "
            f"sync_unanswered {fixed.unanswered}: {verdict}"
        )
    if rows:
        print(
            f"{'driver':16s} {'matching':8s} {'setup':10s} {'SYNC/s held':>11s} {'trials':>6s}   "
            f"{'SDO block down/up, segmented down/up kB/s':42s} buffered {args.capture_s:g} s: run, lag"
        )
        for (driver, kind), (best, n, sdo, cap, matching) in rows.items():
            print(f"{driver:16s} {matching:8s} {kind:10s} {best:>11s} {n:>6s}   {sdo:42s} {cap}")
    return 1 if fixed is not None and not passed(fixed) else 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except HilidentError as exc:  # a driver that is not there, a drive that does not answer: one line
        print(f"bench/canopen.py: {exc}", file=sys.stderr)
        sys.exit(1)
