"""Sustained streaming throughput of the serial board over a pseudo-terminal.

For each baud rate this finds the highest sample rate the emulated board streams
to the host with zero losses (no lost or corrupt frames, no lost or board-dropped
blocks, no excitation underruns) for a sustained time, and states it as a
fraction of the line's payload capacity. Run by hand, never by the test suite::

    python bench/streaming.py                   # 60 s per trial, several minutes
    python bench/streaming.py --duration 5      # quick look, about a minute
    python bench/streaming.py --compact --baud 3000000
    python bench/streaming.py --board-command drivers/myrio-board/firmware/build/posix-sim   # the C board

Method
------
The board runs in its own process (as a real board is separate hardware) and
opens a pseudo-terminal; the host opens it with
:meth:`hilident.adapters.serial.board.SerialBoardAdapter.open`, exactly as a
USB serial board. The board paces its output at ``baud / 10`` bytes per second
and drops sample blocks when its transmit buffer is full.

The board offers the sample rates ``loop_rate / d`` (4000, 2000, 1333.3, ... Hz).
That ladder is too coarse to find a limit, so the emulator's ``time_scale`` s is
used as a fine knob: at nominal rate f the board delivers s * f rows per wall
second (the *effective* sample rate) with unchanged physics and unchanged frame
layout. Per baud rate the divider d is fixed (the one whose nominal rate is the
highest supported rate at or below the target load), which fixes the block size;
then s is bisected over payload fractions on a grid of ``--resolution``,
starting at the target fraction. Finally the highest board-supported rate is
run in real time (s = 1) to confirm what a real board at that baud rate can do.

``--board-command`` runs another board program instead of the emulated board:
the reference C firmware's ``posix-sim`` (``make -C drivers/myrio-board/firmware
posix-sim``), started as ``COMMAND --pty --baud B --time-scale s --quiet``, which
prints its terminal's path first and paces its own line. Its side of the
figures (bytes written, buffer peak, rows produced) is not visible from here:
the host's side stands for both, and its CPU is read from ``/proc``.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.adapters.serial.board import SerialBoardAdapter
from hilident.config.tables import parse_config
from hilident.drivers.description import ChannelSpec, DriverDescription, find_driver
from hilident.errors import HilidentError
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import encode_frame

BITS_PER_BYTE = 10  # 8N1
TARGET_FRACTION = 0.9
DEFAULT_BAUDS = (921600, 3000000)
COMPACT_CHANNELS = ("torque_nm", "position_m", "velocity_mps")
_BYTES = {"f32": 4, "i32": 4, "i16": 2}
_FORMATS = {"f32": sb.Format.F32, "i32": sb.Format.I32, "i16": sb.Format.I16}
_LIMITS = "[limits]\ntorque_nm = 100.0\nvelocity_mps = 10.0\nposition_min_m = -10.0\nposition_max_m = 10.0\n"
_EXCITATION_RMS_NM = 0.05  # small torque injection noise: keeps the axis near its hold point


def _machine_cpu() -> tuple[float, float] | None:
    """(busy, steal) CPU seconds of the whole machine since boot, from /proc/stat (Linux); None elsewhere."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
        tick = os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        return None
    user, nice, system, idle, iowait, irq, softirq, steal = (fields + [0] * 8)[:8]
    return (user + nice + system + irq + softirq) / tick, steal / tick


# --- the board process ------------------------------------------------------------------------


class _BoardMonitor:
    """Samples the board's transmit-buffer fill and its produced-sample count every ``period_s``."""

    def __init__(self, server, period_s: float = 0.002):
        self.server = server
        self.period_s = period_s
        self._stop = threading.Event()
        self.reset()

    def reset(self) -> None:
        self.peak = 0
        self.first: tuple[float, int] | None = None  # (time, samples) when production was first seen
        self.last: tuple[float, int] | None = None  # (time, samples) of the latest change

    @property
    def produced_hz(self) -> float:
        """Samples the board produced per wall second while it ran (0 if unknown)."""
        if self.first is None or self.last is None or self.last[0] <= self.first[0]:
            return 0.0
        return (self.last[1] - self.first[1]) / (self.last[0] - self.first[0])

    def start(self) -> _BoardMonitor:
        threading.Thread(target=self._run, name="tx-monitor", daemon=True).start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        firmware = self.server.firmware
        while not self._stop.wait(self.period_s):
            self.peak = max(self.peak, self.server._tx_bytes)
            produced = firmware._produced if firmware.running else None
            if produced:
                now = time.perf_counter()
                if self.first is None:
                    self.first = (now, produced)
                if self.last is None or produced != self.last[1]:
                    self.last = (now, produced)


def _serve_board(conn, config_toml: str, driver_name: str, baudrate: int) -> None:
    """Child process: one emulated board on a pseudo-terminal, answering stats requests on ``conn``."""
    from hilident.emulator.serial.server import start_serial_board

    cfg = parse_config(config_toml, "<bench>")
    device = start_serial_board(cfg.emulator, find_driver(driver_name), baudrate, link="pty")
    server = device.server
    monitor = _BoardMonitor(server).start()
    conn.send(device.port)
    try:
        while True:
            command = conn.recv()
            if command == "mark":
                monitor.reset()
            elif command != "stats":
                break
            conn.send(
                {
                    "cpu_s": time.process_time(),
                    "wall_s": time.perf_counter(),
                    "bytes_sent": server.bytes_sent,
                    "dropped_blocks": server.firmware.counters.dropped_blocks,
                    "tx_peak": monitor.peak,
                    "produced_hz": monitor.produced_hz,
                    "tx_capacity": server.tx_buffer_bytes,
                    "error": repr(server.error) if server.error else None,
                }
            )
    except EOFError:
        pass
    finally:
        monitor.stop()
        device.close()


def _process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) process ``pid`` has used, from ``/proc`` (0 where there is none)."""
    try:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def _serve_external(conn, command: str, baudrate: int, time_scale: float) -> None:
    """Child process: a board program on a pseudo-terminal (``--board-command``), answering stats requests."""
    proc = subprocess.Popen(
        [command, "--pty", "--baud", str(baudrate), "--time-scale", repr(float(time_scale)), "--quiet"],
        stdout=subprocess.PIPE,
        text=True,
    )
    conn.send(proc.stdout.readline().strip())
    try:
        while conn.recv() in ("mark", "stats"):
            rc = proc.poll()
            conn.send(
                {
                    "cpu_s": _process_cpu_s(proc.pid),
                    "wall_s": time.perf_counter(),
                    "bytes_sent": 0,
                    "dropped_blocks": 0,
                    "tx_peak": 0,
                    "produced_hz": 0.0,
                    "tx_capacity": 0,
                    "error": None if rc is None else f"the board program exited with {rc}",
                }
            )
    except EOFError:
        pass
    finally:
        proc.terminate()
        proc.wait(timeout=5.0)


#: The board program of ``--board-command`` (None: the emulated board in a child process).
BOARD_COMMAND: str | None = None


# --- one trial ------------------------------------------------------------------------------------


@dataclass
class Trial:
    """Outcome of streaming at one effective sample rate."""

    baudrate: int
    nominal_hz: float
    time_scale: float
    requested_hz: float  # nominal * time_scale
    row_bytes: int
    achieved_hz: float = 0.0  # rows per wall second, first to last block
    produced_hz: float = 0.0  # rows the board produced per wall second while running
    wire_bytes_per_s: float = 0.0  # host-side, every byte received
    board_bytes_per_s: float = 0.0  # board-side, every byte written
    block_rows: int = 0
    samples: int = 0
    requested_samples: int = 0
    lost_frames: int = 0
    lost_blocks: int = 0
    corrupt_frames: int = 0
    out_of_order: int = 0
    board_dropped_blocks: int = 0
    underruns: int = 0
    host_us_per_block: float = 0.0
    host_cpu_fraction: float = 0.0
    board_cpu_fraction: float = 0.0
    tx_peak: int = 0
    tx_capacity: int = 0
    other_cpu: float | None = None  # cores busy with other processes during the trial
    steal: float | None = None  # cores taken by the hypervisor
    attempt: int = 1
    error: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def capacity(self) -> float:
        return self.baudrate / BITS_PER_BYTE

    @property
    def payload_fraction(self) -> float:
        return self.achieved_hz * self.row_bytes / self.capacity

    @property
    def requested_fraction(self) -> float:
        return self.requested_hz * self.row_bytes / self.capacity

    @property
    def kept_rate(self) -> bool:
        """Rows arrived as fast as asked (0.5 % tolerance: block arrival jitter over a short run)."""
        return self.achieved_hz >= 0.995 * self.requested_hz

    @property
    def losses(self) -> int:
        return (
            self.lost_frames
            + self.lost_blocks
            + self.corrupt_frames
            + self.out_of_order
            + self.board_dropped_blocks
            + self.underruns
        )

    @property
    def clean(self) -> bool:
        return self.error is None and self.losses == 0 and self.samples == self.requested_samples and self.kept_rate

    def verdict(self) -> str:
        if self.error:
            return "error"
        if self.losses or self.samples != self.requested_samples:
            return "LOSS"
        if not self.kept_rate:
            if self.produced_hz and self.produced_hz < 0.995 * self.requested_hz:
                return "slow"  # the board process could not keep time: the load was lower than asked
            return "backlog"  # the line carried less than the board produced: its TX buffer fills
        return "clean" if self.attempt == 1 else f"clean (attempt {self.attempt})"


def _board_config(time_scale: float, seed: int) -> str:
    return _LIMITS + f'[emulator]\nlink = "pty"\ntime_scale = {float(time_scale)!r}\nseed = {seed}\n'


def run_trial(
    driver: DriverDescription,
    specs: tuple[ChannelSpec, ...],
    baudrate: int,
    divider: int,
    time_scale: float,
    duration_s: float,
    seed: int,
) -> Trial:
    """Stream ``duration_s`` wall seconds at nominal rate ``loop_rate / divider`` times ``time_scale``."""
    nominal = driver.loop_rate_hz / divider
    row_bytes = sum(_BYTES[c.format] for c in specs)
    trial = Trial(baudrate, nominal, time_scale, nominal * time_scale, row_bytes)
    config = _board_config(time_scale, seed)
    try:
        parse_config(config, "<bench>")  # a time_scale out of range fails here, not in the child
    except HilidentError as exc:
        trial.error = str(exc)
        return trial
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    conn, child_conn = ctx.Pipe()
    if BOARD_COMMAND is None:
        board = ctx.Process(target=_serve_board, args=(child_conn, config, driver.name, baudrate), daemon=True)
    else:
        board = ctx.Process(target=_serve_external, args=(child_conn, BOARD_COMMAND, baudrate, time_scale), daemon=True)
    board.start()
    adapter = None
    try:
        if not conn.poll(30.0):
            raise HilidentError("emulated board did not start within 30 s")
        port = conn.recv()
        adapter = SerialBoardAdapter.open(port, driver, baudrate, timeout_s=5.0)
        adapter.set_limits(100.0, 10.0, -10.0, 10.0)
        adapter.configure(nominal, "torque_injection", [c.name for c in specs])
        n = int(round(duration_s * trial.requested_hz))
        trial.requested_samples = n
        excitation = np.random.default_rng(seed).normal(0.0, _EXCITATION_RMS_NM, n)
        arrivals: list[tuple[float, int, int]] = []  # (time, samples so far, host bytes so far)
        decoder_stats = adapter.decoder.stats

        def sink(index: np.ndarray, rows: np.ndarray) -> None:
            arrivals.append((time.perf_counter(), int(index[-1]) + 1, decoder_stats.bytes_in))
            if not trial.block_rows:
                trial.block_rows = len(rows)

        conn.send("mark")
        board_before = conn.recv()
        machine0 = _machine_cpu()
        cpu0 = time.process_time()
        result = adapter.stream(excitation, sink)
        host_cpu = time.process_time() - cpu0
        machine1 = _machine_cpu()
        conn.send("stats")
        board_after = conn.recv()
        st = result.stats
        trial.samples = st.samples
        trial.lost_frames, trial.lost_blocks = st.lost_frames, st.lost_blocks
        trial.corrupt_frames, trial.out_of_order = st.corrupt_frames, st.out_of_order
        trial.board_dropped_blocks, trial.underruns = st.board_dropped_blocks, st.underruns
        if result.fault:
            trial.error = result.fault
        if len(arrivals) >= 2:
            (t0, s0, b0), (t1, s1, b1) = arrivals[0], arrivals[-1]
            trial.achieved_hz = (s1 - s0) / (t1 - t0)
            trial.wire_bytes_per_s = (b1 - b0) / (t1 - t0)
            trial.host_us_per_block = 1e6 * host_cpu / len(arrivals)
            trial.host_cpu_fraction = host_cpu / (t1 - t0)
        wall = board_after["wall_s"] - board_before["wall_s"]
        trial.board_bytes_per_s = (board_after["bytes_sent"] - board_before["bytes_sent"]) / wall
        board_cpu = board_after["cpu_s"] - board_before["cpu_s"]
        trial.board_cpu_fraction = board_cpu / wall
        if machine0 and machine1:
            trial.other_cpu = max(0.0, (machine1[0] - machine0[0] - host_cpu - board_cpu) / wall)
            trial.steal = (machine1[1] - machine0[1]) / wall
        trial.tx_peak = board_after["tx_peak"]
        trial.produced_hz = board_after["produced_hz"]
        trial.tx_capacity = board_after["tx_capacity"]
        trial.error = trial.error or board_after["error"]
    except HilidentError as exc:
        trial.error = str(exc)
    finally:
        if adapter is not None:
            adapter.close()
        try:
            conn.send("close")
        except (OSError, BrokenPipeError):
            pass
        board.join(timeout=5.0)
        if board.is_alive():
            board.terminate()
            board.join(timeout=2.0)
    return trial


# --- search ----------------------------------------------------------------------------------------


def frame_efficiency(specs: tuple[ChannelSpec, ...], block_rows: int) -> tuple[int, int]:
    """(payload bytes, wire bytes) of one full SAMPLES frame with ``block_rows`` rows."""
    selection = tuple(sb.ChannelSelection(i, _FORMATS[c.format], c.scale) for i, c in enumerate(specs))
    rows = np.random.default_rng(0).normal(0.0, 1e-3, (block_rows, len(specs)))
    msg = sb.Samples(1234, 56789, 0, 56789, 3000, 0, rows)
    frame = encode_frame(sb.encode(msg, 4321, sample_channels=selection))
    return block_rows * sum(_BYTES[c.format] for c in specs), len(frame)


def block_rows_for(driver: DriverDescription, nominal_hz: float) -> int:
    """Rows per SAMPLES block the host asks for at ``nominal_hz``.

    Mirrors :meth:`SerialBoardAdapter.configure`; every trial checks it against
    the blocks actually received.
    """
    return min(4096, max(32, int(round(driver.block_samples * nominal_hz / 1000.0))))


@dataclass
class BaudResult:
    baudrate: int
    divider: int
    efficiency: float
    trials: list[Trial]
    best: Trial | None
    real_time: Trial | None


def _print_trial_header() -> None:
    print(
        f"  {'nominal':>8} {'s':>7} {'eff.':>8} {'asked':>6} {'got':>6} {'wire':>6} {'lost':>5} "
        f"{'crpt':>4} {'drop':>4} {'undr':>5} {'host':>6} {'host':>5} {'board':>5} {'other':>5} "
        f"{'steal':>5} {'TX buf peak':>13}  result"
    )
    print(
        f"  {'Hz':>8} {'':>7} {'Hz':>8} {'frac':>6} {'frac':>6} {'frac':>6} {'blk':>5} "
        f"{'':>4} {'blk':>4} {'':>5} {'us/blk':>6} {'cpu':>5} {'cpu':>5} {'cpu':>5} {'':>5} {'/size, kB':>13}"
    )


def _opt(x: float | None) -> str:
    return f"{x:5.2f}" if x is not None else f"{'-':>5}"


def _print_trial(t: Trial) -> None:
    wire = t.wire_bytes_per_s / t.capacity
    tx = f"{t.tx_peak / 1024:.1f}/{t.tx_capacity / 1024:.0f}" if t.tx_capacity else "-"
    extra = f" ({t.error})" if t.error else ""
    if t.lost_frames != t.lost_blocks + t.board_dropped_blocks:
        extra += f", {t.lost_frames} lost frames"
    if t.out_of_order:
        extra += f", {t.out_of_order} out of order"
    if t.notes:
        extra += "; " + "; ".join(t.notes)
    print(
        f"  {t.nominal_hz:8.1f} {t.time_scale:7.4f} {t.requested_hz:8.1f} {t.requested_fraction:6.3f} "
        f"{t.payload_fraction:6.3f} {wire:6.3f} {t.lost_blocks:5d} {t.corrupt_frames:4d} "
        f"{t.board_dropped_blocks:4d} {t.underruns:5d} {t.host_us_per_block:6.0f} {t.host_cpu_fraction:5.2f} "
        f"{t.board_cpu_fraction:5.2f} {_opt(t.other_cpu)} {_opt(t.steal)} {tx:>13}  {t.verdict()}{extra}",
        flush=True,
    )


def probe_baud(
    driver: DriverDescription,
    specs,
    baudrate: int,
    duration_s: float,
    resolution: float,
    seed: int,
    divider: int | None = None,
    retries: int = 1,
) -> BaudResult:
    """Bisect the effective rate at ``baudrate``, then confirm the best board-supported rate in real time."""
    row_bytes = sum(_BYTES[c.format] for c in specs)
    capacity = baudrate / BITS_PER_BYTE
    capacity_rows = capacity / row_bytes
    loop = driver.loop_rate_hz
    if divider is None:
        divider = max(1, math.ceil(loop / (TARGET_FRACTION * capacity_rows)))
    nominal = loop / divider
    block = block_rows_for(driver, nominal)
    payload, wire = frame_efficiency(specs, block)
    efficiency = payload / wire
    print(f"\n{baudrate} baud: capacity C = {capacity:,.0f} B/s = {capacity_rows:,.1f} rows/s of {row_bytes} B")
    print(
        f"  frame layout: nominal {nominal:g} Hz (divider {divider}), {block} rows/block: "
        f"{payload} B of samples in a {wire} B frame -> at most {efficiency:.3f} of C is payload"
    )
    _print_trial_header()
    trials: list[Trial] = []

    def attempt(d: int, s: float) -> Trial:
        # A failed attempt is repeated (up to `retries` times) and stays in the log: on a shared
        # machine another process can stall the board or the host for longer than the buffers cover.
        for k in range(1, retries + 2):
            t = run_trial(driver, specs, baudrate, d, s, duration_s, seed)
            t.attempt = k
            if t.block_rows and t.block_rows != block_rows_for(driver, driver.loop_rate_hz / d):
                t.notes.append(f"blocks of {t.block_rows} rows, expected {block_rows_for(driver, loop / d)}")
            trials.append(t)
            _print_trial(t)
            if t.clean:
                break
        return t

    def trial_at(fraction: float) -> Trial:
        return attempt(divider, fraction * capacity_rows / nominal)

    def grid(f: float) -> float:
        return round(round(f / resolution) * resolution, 10)

    # Bisection on a grid: clean_lo is assumed clean until tested; fail_hi (all of the
    # line's bytes carrying samples and frames, no slack) is assumed to fail.
    clean_lo, fail_hi = grid(0.2), grid(math.ceil(efficiency / resolution) * resolution)
    best: Trial | None = None
    f = grid(TARGET_FRACTION)
    while True:
        t = trial_at(f)
        if t.clean:
            clean_lo, best = f, t
        else:
            fail_hi = f
        if fail_hi - clean_lo <= resolution * 1.0001:
            break
        f = grid((clean_lo + fail_hi) / 2)
        if not clean_lo < f < fail_hi:
            f = grid(clean_lo + resolution)
    if best is None and clean_lo < fail_hi:
        t = trial_at(clean_lo)
        best = t if t.clean else None

    # Real time: the highest rate the board supports whose load fits what streamed cleanly.
    real_time = None
    if best is not None:
        d = 1
        while loop / d * row_bytes / capacity > best.requested_fraction:
            d += 1
        above = (
            f"; the next one up, {loop / (d - 1):g} Hz, would need {loop / (d - 1) * row_bytes / capacity:.3f} of C"
            if d > 1
            else "; it is the board's maximum"
        )
        print(f"  real time (s = 1): highest supported rate within the clean load is {loop / d:g} Hz{above}")
        d_start = d
        for d in range(d_start, d_start + 4):  # step down the ladder a few rates if needed
            t = attempt(d, 1.0)
            if t.clean:
                real_time = t
                break
    return BaudResult(baudrate, divider, efficiency, trials, best, real_time)


# --- report ------------------------------------------------------------------------------------------


def _print_preamble(driver: DriverDescription, specs, duration_s: float, resolution: float) -> None:
    loop = driver.loop_rate_hz
    ladder = ", ".join(f"{loop / d:.6g}" for d in range(1, 7))
    row_bytes = sum(_BYTES[c.format] for c in specs)
    print("hilident serial streaming benchmark: emulated board (own process) on a pseudo-terminal,")
    print("host through SerialBoardAdapter.open, as with a USB serial board")
    print(f"driver {driver.name}: loop rate {loop:g} Hz, supported sample rates {loop:g}/d Hz = {ladder}, ...")
    print(
        f"channels ({len(specs)}): "
        + ", ".join(f"{c.name} {c.format}" for c in specs)
        + f" -> {row_bytes} bytes per row"
    )
    print("definitions:")
    print(f"  capacity C     = baud / {BITS_PER_BYTE} bytes/s (8N1: start bit + 8 data bits + stop bit)")
    print("  payload        = sample bytes per second = rows/s x bytes per row (block headers, message")
    print("                   header, CRC-32, COBS and delimiters excluded); payload fraction = payload / C")
    print("  wire           = every byte received per second, framing and other frames included")
    print("  time_scale s   = simulated seconds per wall second; at nominal sample rate f the board delivers")
    print("                   s x f rows per wall second (effective sample rate). The physics is unchanged;")
    print("                   s only sets the load on the line, so it probes rates between the board's")
    print("                   supported rates and above the board's maximum")
    print(f"  clean          = a sustained {duration_s:g} s (wall) run with zero lost frames, lost or board-dropped")
    print("                   blocks, corrupt frames and excitation underruns, every sample received, and the")
    print("                   rows arriving as fast as asked (>= 0.995 x); otherwise the result is LOSS,")
    print("                   backlog (the line carried less than asked and the board's TX buffer grew: a")
    print("                   longer run would drop blocks) or slow (the board process fell behind real time)")
    print("  columns        = asked/got frac: payload fraction asked and measured (first to last block);")
    print("                   wire frac: wire bytes/s over C (same interval); lost blk, crpt, drop blk, undr:")
    print("                   lost blocks, corrupt frames, blocks the board dropped, underrun samples;")
    print("                   host us/blk: host CPU per received block; cpu: CPU seconds per wall second of")
    print("                   the host, the board process and all other processes; steal: cores taken by")
    print("                   the hypervisor; TX buf: peak fill of the board's transmit buffer and its size")
    print(
        f"search: bisection of the payload fraction on a {resolution:g} grid, starting at the target "
        f"{TARGET_FRACTION:g}"
    )


def _print_summary(results: list[BaudResult], row_bytes: int) -> None:
    print("\nsummary (target: payload >= 0.9 of C at every baud rate)")
    print(
        f"  {'baud':>8} {'C B/s':>8} {'best effective rate':>30} {'payload B/s':>11} {'frac':>6} "
        f"{'wire B/s':>9} {'wire frac':>9} {'max frac':>8} {'target':>6} {'real time (s=1)':>22}"
    )
    for r in results:
        cap = r.baudrate / BITS_PER_BYTE
        if r.best:
            b = r.best
            rate = f"{b.achieved_hz:,.0f} Hz = {b.nominal_hz:g} x {b.time_scale:.4f}"
            payload = f"{b.achieved_hz * row_bytes:11,.0f} {b.payload_fraction:6.3f} "
            wire = f"{b.wire_bytes_per_s:9,.0f} {b.wire_bytes_per_s / cap:9.3f}"
            met = "met" if b.payload_fraction >= TARGET_FRACTION else "NOT met"
        else:
            rate, payload, wire, met = "none clean", f"{'-':>11} {'-':>6} ", f"{'-':>9} {'-':>9}", "NOT met"
        rt = r.real_time
        real = f"{rt.nominal_hz:g} Hz ({rt.payload_fraction:.3f} of C)" if rt else "none clean"
        print(f"  {r.baudrate:>8} {cap:8,.0f} {rate:>30} {payload}{wire} {r.efficiency:8.3f} {met:>6} {real:>22}")
    print("  max frac: payload fraction when every byte of the line carries full SAMPLES frames")


# --- command line ------------------------------------------------------------------------------------


def _parse_args(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--duration", type=float, default=60.0, help="wall seconds per trial (default 60)")
    p.add_argument(
        "--baud", default=",".join(map(str, DEFAULT_BAUDS)), help="comma-separated baud rates (default 921600,3000000)"
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument("--channels", default="", help="comma-separated channel names (default: all streamed)")
    group.add_argument(
        "--compact",
        action="store_true",
        help=f"stream only {', '.join(COMPACT_CHANNELS)} (the excitation is known to the host)",
    )
    p.add_argument("--resolution", type=float, default=0.01, help="payload fraction grid step (default 0.01)")
    p.add_argument(
        "--divider",
        type=int,
        default=0,
        help="nominal sample-rate divider for the search (default: chosen per baud rate)",
    )
    p.add_argument(
        "--retries",
        type=int,
        default=1,
        help="repeat a failed trial this many times before taking it as failed (default 1)",
    )
    p.add_argument("--driver", default="myrio-board")
    p.add_argument(
        "--board-command",
        default="",
        help="a board program to stream from instead of the emulated board (the C firmware's posix-sim)",
    )
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    if args.duration <= 0:
        p.error(f"--duration must be > 0, got {args.duration}")
    if not 0 < args.resolution < 0.5:
        p.error(f"--resolution must be in (0, 0.5), got {args.resolution}")
    if args.retries < 0:
        p.error(f"--retries must be >= 0, got {args.retries}")
    if args.divider < 0:
        p.error(f"--divider must be >= 1, got {args.divider}")
    try:
        args.bauds = [int(b) for b in args.baud.split(",") if b.strip()]
    except ValueError:
        p.error(f"--baud must be comma-separated integers, got {args.baud!r}")
    if not args.bauds or min(args.bauds) <= 0:
        p.error(f"--baud needs positive baud rates, got {args.baud!r}")
    return args


def main(argv=None) -> int:
    global BOARD_COMMAND
    args = _parse_args(argv)
    BOARD_COMMAND = os.path.abspath(args.board_command) if args.board_command else None
    try:
        driver = find_driver(args.driver)
        names = COMPACT_CHANNELS if args.compact else [n.strip() for n in args.channels.split(",") if n.strip()]
        specs = tuple(driver.channels[driver.channel_index(n)] for n in names) if names else driver.streamed_channels
    except HilidentError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _print_preamble(driver, specs, args.duration, args.resolution)
    started = time.monotonic()
    results = [
        probe_baud(driver, specs, b, args.duration, args.resolution, args.seed, args.divider or None, args.retries)
        for b in args.bauds
    ]
    _print_summary(results, sum(_BYTES[c.format] for c in specs))
    print(f"\n{sum(len(r.trials) for r in results)} trials in {time.monotonic() - started:.0f} s")
    return 0 if all(r.best and r.best.payload_fraction >= TARGET_FRACTION for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
