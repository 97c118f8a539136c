"""CANopen transport benchmarks against emulated CiA 402 drives. Run by hand, never by the tests::

    python bench/canopen.py                      # 60 s per search trial: about half an hour
    python bench/canopen.py --duration 5         # quick search; the 1 kHz / 60 s trial stays in full
    python bench/canopen.py --parts fixed        # only the 1 kHz / 60 s trial over socketcand
    python bench/canopen.py --parts search --duration 5 --setups virtual   # a quick look at the search

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
from the run's own ``RunResult`` (its stats, events and clock report), never
from objects a standard drive lacks. Every run is in real time (the drive at
``time_scale`` 1; its clock does not follow SYNC), one SYNC per sample, from the
source the adapter chooses (``sync_source = "auto"``: the drive's own clock
where its driver says it can produce SYNC, as both shipped twins do).

1. **Fixed-rate trial** (``--driver``, socketcand). ``--fixed-rate`` samples
   (and SYNCs) per second (1000) for ``--fixed-duration`` seconds (60), the
   drive in its own process. Printed: samples received of those asked, lost
   samples and frames, late and corrupt frames, SYNCs unanswered, and the
   clock: its source, the SYNCs outside the drive's window, the worst jitter
   and the set-points skipped; PASS when nothing was lost and every sample
   arrived.
2. **Host-streamed sample rate** (every search driver, every setup). The
   adapter streams a small torque sine with one RPDO and one SYNC per sample,
   and the TPDOs come back per SYNC. The sample rate is the drive's loop rate
   over a divider d (4000, 2000, 1333.3, 1000, 800, ... Hz for a 4 kHz loop),
   at most the driver's ``max_sample_rate_hz``. A trial of ``--duration``
   seconds is clean when no PDO was lost or late, no SYNC went unanswered, the
   drive reported no set-point underrun or SYNC counter jump (drives with the
   hilident counters only), every sample arrived, and the samples arrived at
   98 % of the sample rate (the slope of the sample index over the time it
   came home). The set-points the host skipped are printed, not a criterion:
   a drive with the hilident counters counts every cycle without a fresh
   set-point as an underrun (a criterion), a standard drive holds the last
   set-point without a word.
   The search starts at d = loop rate / 500 Hz, halves d (doubling the rate)
   while trials are clean, then bisects d between the last clean and the
   first failed divider.
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
import math
import os
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

    rate: float  # samples (and SYNCs) per second asked
    achieved: float  # samples received per wall-clock second (slope of the sample index over arrival time)
    asked: int  # samples played
    samples: int  # samples received
    lost_frames: int
    lost_samples: int
    late: int  # TPDOs that came after their sample was given up
    corrupt: int
    underruns: int  # set-point underruns the drive reported (drives with the hilident counters only)
    sync_errors: int  # SYNC counter jumps the drive reported (idem)
    unanswered: int  # SYNCs that got no TPDO at all (drives matched by bus order)
    clean: bool
    note: str = ""
    source: str = "-"  # who kept the bus clock (RunResult.clock)
    outside_window: int = 0  # SYNCs further from their cycle's instant than the drive's window
    jitter_max_ms: float = 0.0  # the largest SYNC jitter about the fitted clock
    skipped: int = 0  # set-points (drive clock) or cycles (host clock) skipped


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


class Arrivals:
    """A run's sink: counts the samples home, and when each block came with the index of its last sample."""

    def __init__(self):
        self.count = 0
        self.last_index: list[int] = []
        self.at_s: list[float] = []

    def __call__(self, index, rows) -> None:
        self.at_s.append(time.perf_counter())
        self.last_index.append(int(index[-1]))
        self.count += len(index)

    @property
    def rate(self) -> float:
        """Samples per second home: the slope of each block's last sample index over its arrival (0: too few)."""
        if len(self.at_s) < 3 or self.at_s[-1] <= self.at_s[0]:
            return 0.0
        return float(np.polyfit(np.array(self.at_s) - self.at_s[0], self.last_index, 1)[0])


def _clock_fields(clock: dict | None) -> dict:
    """The Trial fields of a run's clock report (``RunResult.clock``)."""
    clock = clock or {}
    return {
        "source": clock.get("source", "-"),
        "outside_window": int(clock.get("outside_window", 0)),
        "jitter_max_ms": 1e3 * float(clock.get("jitter_max_s") or 0.0),
        "skipped": int(clock.get("setpoints_skipped") or 0),
    }


def streaming_trial(setup: Setup, sample_rate: float, duration: float) -> Trial:
    """Stream a 0.5 N*m, 3 Hz torque sine for ``duration`` s at ``sample_rate`` (one SYNC per sample)."""
    ad = setup.adapter
    wait_until_answering(ad)
    ad.acquisition = "streamed"
    ad.configure(sample_rate, "torque")
    rate = ad.sample_rate_hz
    n = round(rate * duration)
    x = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / rate)
    home = Arrivals()
    note = ""
    try:
        result = ad.stream(x, home)
    except HilidentError as exc:
        result, note = ad.last_result, str(exc)
    if result is None:  # broke off before the run began
        return Trial(rate, 0.0, n, 0, 0, 0, 0, 0, 0, 0, 0, False, note)
    s, ev = result.stats, result.events
    sync_errors = _event_value(ev, "sync_errors")
    unanswered = _event_value(ev, "sync_unanswered")
    achieved = home.rate  # samples that arrived per second (all of them in a clean trial)
    clean = (
        not note
        and s.lost_frames == 0
        and s.lost_samples == 0
        and s.out_of_order == 0
        and s.corrupt_frames == 0
        and s.underruns == 0
        and sync_errors == 0
        and unanswered == 0
        and home.count == n
        and achieved >= 0.98 * rate
    )
    return Trial(
        rate,
        achieved,
        n,
        home.count,
        s.lost_frames,
        s.lost_samples,
        s.out_of_order,
        s.corrupt_frames,
        s.underruns,
        sync_errors,
        unanswered,
        clean,
        note,
        **_clock_fields(result.clock),
    )


def bisect_divider(clean, first: int, smallest: int) -> tuple[int | None, int]:
    """The smallest divider ``d >= smallest`` for which ``clean(d)`` holds, searched from ``first``.

    ``d`` halves while ``clean(d)`` holds (the rate doubles), then is bisected
    between the last clean and the first failed divider. Returns (that divider,
    or None when ``first`` already failed; the number of trials).
    """
    trials = 1
    if not clean(first):
        return None, trials
    good, bad = first, smallest - 1  # bad: the largest divider known to fail (none below smallest)
    while good > smallest:
        d = max(smallest, good // 2)
        trials += 1
        if clean(d):
            good = d
        else:
            bad = d
            break
    while good - bad > 1 and bad >= smallest:
        mid = (good + bad) // 2
        trials += 1
        if clean(mid):
            good = mid
        else:
            bad = mid
    return good, trials


def find_sample_rate(setup: Setup, duration: float) -> tuple[float, list[Trial]]:
    """The highest clean sample rate, loop rate / d (0: not even about 500 Hz), and every trial run to find it."""
    trials = []
    name = setup.driver.name
    loop_hz = setup.adapter.drive_identity().loop_rate_hz
    smallest = max(1, math.ceil(loop_hz / setup.driver.max_sample_rate_hz - 1e-9))

    def run(d):
        t = streaming_trial(setup, loop_hz / d, duration)
        trials.append(t)
        verdict = "clean" if t.clean else "LOSS"
        print(
            f"  {name:16s} {setup.kind:10s} d {d:3d} {t.rate:7.1f} Hz asked {t.achieved:7.1f}/s received  "
            f"lost frames {t.lost_frames:5d}  lost samples {t.lost_samples:5d}  late {t.late:4d}  "
            f"unanswered {t.unanswered:4d}  underruns {t.underruns:4d}  SYNC {t.source}: outside window "
            f"{t.outside_window:5d} (worst jitter {t.jitter_max_ms:.2f} ms), skipped {t.skipped:5d} "
            f"({100 * t.skipped / max(t.asked, 1):4.1f} %)  "
            f"{verdict} {t.note[:80]}",
            flush=True,
        )
        return t.clean

    first = max(smallest, round(loop_hz / 500.0))
    best, _ = bisect_divider(run, first, smallest)
    return (0.0 if best is None else loop_hz / best), trials


def machine_load() -> str:
    """The load average over 1 and 5 minutes and the CPU count: the trials share the machine."""
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs"


def fixed_rate_trial(driver: str, rate: float, duration: float) -> Trial:
    """``rate`` samples (and SYNCs) per second for ``duration`` s, the drive in its own process behind socketcand."""
    setup = Setup("socketcand", driver)
    print(f"  before: {machine_load()}", flush=True)
    try:
        return streaming_trial(setup, rate, duration)
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
        f"  SYNC from the {t.source}: {t.outside_window} outside the drive's window (worst jitter "
        f"{t.jitter_max_ms:.2f} ms), set-points skipped {t.skipped}, SYNCs unanswered {t.unanswered}, "
        f"received {t.achieved:.1f} samples/s\n"
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
        help="drivers of the sample-rate search besides --driver (default canopen-servo)",
    )
    p.add_argument(
        "--parts",
        default="fixed,search,table",
        help="what to run: fixed (the fixed-rate trial), search (the sample-rate search), "
        "table (SDO throughput and buffered capture); default all",
    )
    p.add_argument("--fixed-rate", type=float, default=1000.0, help="SYNC/s of the fixed-rate trial (default 1000)")
    p.add_argument("--fixed-duration", type=float, default=60.0, help="seconds of the fixed-rate trial (default 60)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per search trial (default 60)")
    p.add_argument(
        "--sample-rate", type=float, default=4000.0, help="drive sample rate of the buffered capture (default 4000)"
    )
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
    rows = {}  # (driver, setup) -> [sample rate held, trials, SDO, buffered, TPDO matching]
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
                        f"host-streamed in real time, {args.duration:g} s per trial, one RPDO + SYNC out and the "
                        "TPDOs back per sample:",
                        flush=True,
                    )
                    best, trials = find_sample_rate(setup, args.duration)
                    print(f"  highest lossless sample rate: {best:.1f} Hz", flush=True)
                    row[0], row[1] = f"{best:.1f}", str(len(trials))
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
            f"SYNC from the {fixed.source}, {fixed.outside_window} outside the window (worst jitter "
            f"{fixed.jitter_max_ms:.2f} ms), set-points skipped {fixed.skipped}, "
            f"sync_unanswered {fixed.unanswered}: {verdict}"
        )
    if rows:
        print(
            f"{'driver':16s} {'matching':8s} {'setup':10s} {'Hz held':>11s} {'trials':>6s}   "
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
