"""Bus clock of streamed CANopen runs: SYNC source x transport x CPU load, on a twin. Run by hand, never by the tests::

    python bench/canopen_jitter.py                           # 12 sessions of about 10 s: about 2 minutes
    python bench/canopen_jitter.py --config configs/emulated-cia402-gantry.toml
    python bench/canopen_jitter.py --sources host --loads 2 --transports socketcand --out /tmp/jitter

``hilident run`` runs a whole identification session (identification, notch
upload, verification) on a CANopen twin, host-streamed
(``[device] acquisition = "streamed"``), once for every combination of:

transport
    ``socketcand``: the twin in its own process (``hilident emulate canopen``)
    behind its socketcand server on 127.0.0.1, at normal priority; ``virtual``:
    the twin in the host's process on python-can's virtual bus
    (``port = "emulator"``), sharing the host's interpreter and priority;
SYNC source
    ``[device.canopen] sync_source``: ``drive`` (the drive's own clock),
    ``host`` (the host's Python loop) and ``interface`` (the CAN interface's own
    cyclic transmit). ``interface`` is first asked for in a ``--dry-run`` on each
    transport: where the host refuses it (its cyclic transmit is a Python
    thread, not the interface's own), the reason is printed and it is left out;
load
    0, 1 or 2 busy processes (pure-Python spin loops) beside the host. The
    machine may be busy with other work too: ``other CPU`` is the cores busy
    with processes outside the bench during the run (from ``/proc/stat``, less
    the CPU time of the bench, the host, the twin and the busy processes).

The host and the busy processes run at ``nice 10``, the twin's own process at
the bench's priority: the twin stands for a drive, which no load on the host's
computer slows down. The twin runs in real time (``[emulator] time_scale = 1``).

Each run gets its config written into its own folder: ``--config`` (default
``configs/emulated-canopen-gantry.toml``, whose drive has filter slots, so the
notch is uploaded and verified) with ``acquisition = "streamed"``, the source,
the transport, the excitation shortened to ``--duration-s`` (two periods), the
friction test off (``--friction`` keeps it) and the amplitude fixed
(``--amplitude``, ``auto`` keeps the config's: its trials add about 25 s a run).

Printed per run (one row): the exit code and the error's first line when it is
not 0 (a drive that faults ends the run with exit code 4: a result, not a
failure of the bench); the SYNCs outside the drive's window (the sum of
``outside_window`` over the run's recordings) and their share; the SYNC jitter
(the largest p99 and max of the recordings, ms, about the fitted clock). Both
are measured where the host sent the SYNCs (its loop) or heard them (the
drive's clock: the host's latency and the twin's own lag included). Then the
set-points skipped; the samples lost; the resonance found against the twin's
true one (from ``[emulator.plant]``); the notch's verified band reduction or why
there is none. The clock and stream figures are ``summary.json``'s when the run
completed, else read from the recordings it left (the same ``clock`` and
``stream`` entries), so a run that faulted still shows its clock. The
machine, the date and the load average come first.

A twin that does not start, or a run that outlasts ``--timeout-s``, is a row
with the reason; the host's process group is then stopped (SIGTERM, SIGKILL).
The busy processes and the twin are stopped after every run, also on Ctrl-C.
The exit status is 0 when the matrix ran (whatever the runs' exit codes), 130
when interrupted.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.batch.fleet import toml_text
from hilident.io.recording import read_run

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "emulated-canopen-gantry.toml"
TRANSPORTS = ("socketcand", "virtual")
SOURCES = ("drive", "host", "interface")
NICE = 10  # the host and the busy processes; the twin's process keeps the bench's priority


@dataclass
class Row:
    """One run of the matrix: what was run and what its results say."""

    transport: str
    source: str
    load: int
    exit: int | None = None  # None: timed out, or the twin never served
    error: str = ""
    syncs: int = 0
    outside_window: int = 0
    jitter_p99_s: float | None = None
    jitter_max_s: float | None = None
    setpoints_skipped: int = 0
    lost_samples: int = 0
    corrupt_frames: int = 0
    underruns: int = 0
    sources_seen: list[str] = field(default_factory=list)
    resonance_hz: float | None = None
    true_hz: float = 0.0
    band_reduction_db: float | None = None
    notch: str = ""
    load_average: float = 0.0
    other_cpu: float | None = None  # cores busy with processes outside the bench during the run
    wall_s: float = 0.0
    folder: str = ""


# ---------------------------------------------------------------------------------------------- configs


def base_settings(path: Path, duration_s: float, friction: bool, amplitude: str) -> dict:
    """The tables of ``path``, host-streamed, in real time, shortened for the bench.

    Parameters
    ----------
    path : Path
        A shipped (or any) config of a CANopen twin.
    duration_s : float
        ``[excitation] duration_s``; the period is half of it (two analysed periods).
    friction : bool
        Keep the config's friction test (else ``enabled = false``).
    amplitude : str
        ``"auto"`` keeps the config's amplitude, else ``amplitude_nm`` in N*m.
    """
    raw = tomllib.loads(path.read_text())
    raw["device"]["acquisition"] = "streamed"
    raw["excitation"].update(duration_s=duration_s, period_s=duration_s / 2)
    if amplitude != "auto":
        raw["excitation"]["amplitude_nm"] = float(amplitude)
    if not friction:
        raw.setdefault("friction_test", {})["enabled"] = False
    raw.setdefault("emulator", {})["time_scale"] = 1.0
    return raw


def variant(raw: dict, source: str, port: str | None) -> dict:
    """``raw`` with ``source`` as SYNC source, on the twin at socketcand ``port`` (None: in the host's process)."""
    out = copy.deepcopy(raw)
    canopen = out["device"].setdefault("canopen", {})
    canopen["sync_source"] = source
    if port is None:
        out["device"]["port"] = "emulator"
    else:
        out["device"]["port"] = port
        canopen["can_interface"] = "socketcand"
    return out


def true_resonance_hz(raw: dict) -> float:
    """The twin's resonance from ``[emulator.plant]``: sqrt(k (m1 + m2) / (m1 m2)) / 2 pi for a two-mass plant."""
    plant = raw["emulator"]["plant"]
    if plant.get("model", "two_mass") == "two_mass":
        m1, m2, k = plant["m1"], plant["m2"], plant["k"]
        return math.sqrt(k * (m1 + m2) / (m1 * m2)) / (2 * math.pi)
    from hilident.config.tables import parse_config
    from hilident.emulator.device import true_modes

    return true_modes(parse_config(toml_text(raw), "bench").emulator)[0][0]


# ---------------------------------------------------------------------------------------------- processes


def _nice_child() -> None:
    """In a child before it runs: lower its priority, and let SIGINT end it as at a terminal."""
    os.nice(NICE)
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def stop_group(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """End ``proc`` and its process group: SIGTERM, then SIGKILL after ``grace_s``."""
    for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            continue


def _last_line(path: Path) -> str:
    lines = [s.strip() for s in path.read_text(errors="replace").splitlines() if s.strip()] if path.exists() else []
    return lines[-1] if lines else ""


class Busy:
    """``n`` pure-Python spin loops at ``nice 10``, each in its own process, for the ``with`` block."""

    def __init__(self, n: int):
        self.n = n
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> Busy:
        try:
            for _ in range(self.n):
                self.procs.append(
                    subprocess.Popen(
                        [sys.executable, "-c", "while True: pass"],
                        stdout=subprocess.DEVNULL,
                        stderr=subprocess.DEVNULL,
                        preexec_fn=_nice_child,
                        start_new_session=True,
                    )
                )
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        for proc in self.procs:
            stop_group(proc, 2.0)
        self.procs.clear()


class TwinError(RuntimeError):
    """The twin's process did not serve."""


class Twin:
    """``hilident emulate canopen`` in its own process (and process group); ``port`` once it serves.

    Parameters
    ----------
    config : Path
        The config whose ``[emulator]`` and ``[device]`` the twin takes.
    folder : Path
        Where its output goes (``twin.out``, ``twin.err``).
    start_timeout_s : float
        How long it may take to print its port.
    """

    def __init__(self, config: Path, folder: Path, start_timeout_s: float):
        self.out, self.err = folder / "twin.out", folder / "twin.err"
        command = [sys.executable, "-m", "hilident.cli", "emulate", "canopen", "--config", str(config)]
        with open(self.out, "w") as out, open(self.err, "w") as err:
            self.proc = subprocess.Popen(
                [*command, "--time-scale", "1"], stdout=out, stderr=err, start_new_session=True
            )
        try:
            self.port = self._wait_for_port(start_timeout_s)
        except BaseException:
            self.stop()
            raise

    def _wait_for_port(self, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            text = self.out.read_text()
            if "\n" in text:
                return text.split("\n", 1)[0].strip()
            if self.proc.poll() is not None:
                raise TwinError(f"the twin exited ({self.proc.returncode}) without serving: {_last_line(self.err)}")
            time.sleep(0.05)
        raise TwinError(f"the twin printed no port within {timeout_s:g} s: {_last_line(self.err)}")

    def ended_early(self) -> str:
        """Why the twin's process is no longer running, or "" while it runs."""
        if self.proc.poll() is None:
            return ""
        return f"the twin exited ({self.proc.returncode}) during the run: {_last_line(self.err)}"

    def stop(self) -> None:
        stop_group(self.proc)


def run_host(config: Path, folder: Path, timeout_s: float, *extra: str) -> tuple[int | None, str]:
    """``hilident run config`` at ``nice 10`` in its own process group; returns (exit code, error line).

    The exit code is None when the run outlasted ``timeout_s`` (its group is then stopped).
    """
    env = dict(os.environ, HILIDENT_LOCK_DIR=str(folder.parent / "locks"))
    command = [sys.executable, "-m", "hilident.cli", "run", str(config), "--out", str(folder / "session")]
    out_path, err_path = folder / "host.out", folder / "host.err"
    with open(out_path, "w") as out, open(err_path, "w") as err:
        proc = subprocess.Popen(
            [*command, "--overwrite", "--no-plots", *extra],
            stdout=out,
            stderr=err,
            env=env,
            preexec_fn=_nice_child,
            start_new_session=True,
        )
    try:
        rc = proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        stop_group(proc)
        return None, f"timed out after {timeout_s:g} s (stopped); {_last_line(err_path)}"
    finally:
        stop_group(proc)
    return rc, ("" if rc == 0 else _error_line(err_path))


def _error_line(path: Path) -> str:
    """The first ``hilident: error:`` line of a host's stderr (without the prefix), else its last line."""
    prefix = "hilident: error: "
    text = path.read_text(errors="replace") if path.exists() else ""
    for line in text.splitlines():
        if line.startswith(prefix):
            return line[len(prefix) :].strip()
    return _last_line(path)


# ---------------------------------------------------------------------------------------------- one run


def host_on_twin(raw: dict, transport: str, source: str, folder: Path, args, *extra: str) -> tuple[int | None, str]:
    """One ``hilident run`` of ``raw`` with ``source`` on a twin over ``transport``: (exit code, error line)."""
    folder.mkdir(parents=True, exist_ok=True)
    if transport == "virtual":
        config = folder / "config.toml"
        config.write_text(toml_text(variant(raw, source, None)))
        return run_host(config, folder, args.timeout_s, *extra)
    twin_config = folder / "twin.toml"
    twin_config.write_text(toml_text(variant(raw, source, None)))
    try:
        twin = Twin(twin_config, folder, args.start_timeout_s)
    except TwinError as exc:
        return None, str(exc)
    try:
        config = folder / "config.toml"
        config.write_text(toml_text(variant(raw, source, twin.port)))
        rc, error = run_host(config, folder, args.timeout_s, *extra)
        gone = twin.ended_early()
        return rc, "; ".join(s for s in (error, gone) if s)
    finally:
        twin.stop()


def interface_available(raw: dict, transport: str, folder: Path, args) -> tuple[bool, str]:
    """Whether the host takes ``sync_source = "interface"`` on ``transport`` (a ``--dry-run``), and its answer."""
    rc, error = host_on_twin(raw, transport, "interface", folder, args, "--dry-run")
    return rc == 0, error


def machine_busy_s() -> float | None:
    """CPU seconds the whole machine was busy since boot, from /proc/stat (Linux); None elsewhere."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
        tick = os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        return None
    user, nice, system, _idle, _iowait, irq, softirq = (fields + [0] * 7)[:7]
    return (user + nice + system + irq + softirq) / tick


def bench_cpu_s() -> float:
    """CPU seconds of this process and of its children that ended (the host, the twin, the busy processes)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def measure(raw: dict, transport: str, source: str, load: int, folder: Path, args) -> Row:
    """One run of the matrix with ``load`` busy processes beside it."""
    row = Row(transport, source, load, true_hz=true_resonance_hz(raw), folder=str(folder))
    started, machine0, own0 = time.monotonic(), machine_busy_s(), bench_cpu_s()
    with Busy(load):
        row.load_average = os.getloadavg()[0]
        row.exit, row.error = host_on_twin(raw, transport, source, folder, args, "--yes", "-q")
    row.wall_s = time.monotonic() - started
    machine1 = machine_busy_s()
    if machine0 is not None and machine1 is not None:
        row.other_cpu = max(0.0, (machine1 - machine0 - (bench_cpu_s() - own0)) / row.wall_s)
    read_results(row, folder / "session")
    return row


# ---------------------------------------------------------------------------------------------- results


def _recorded_clock(session: Path) -> tuple[list[dict], list[dict]]:
    """(clock, stream) entries of every recording in ``session``, also of runs that did not complete."""
    clocks, streams = [], []
    for path in sorted(session.glob("*.h5")):
        try:
            attrs = read_run(path).attrs
        except Exception as exc:  # a recording the host left half written: say so, read the others
            print(f"  (could not read {path.name}: {exc})", flush=True)
            continue
        if attrs.get("clock"):
            clocks.append(dict(attrs["clock"], run=path.stem))
        streams.append(attrs.get("stream") or {})
    return clocks, streams


def read_results(row: Row, session: Path) -> None:
    """Fill ``row`` from ``session``: its summary when the run completed, else its recordings."""
    path = session / "summary.json"
    summary = json.loads(path.read_text()) if path.is_file() else {}
    if row.exit == 0 and summary.get("clock") is not None:
        clocks, streams = summary["clock"], [summary.get("stream") or {}]
    else:
        clocks, streams = _recorded_clock(session)
    _clock_figures(row, clocks)
    row.lost_samples = sum(int(s.get("lost_samples", 0)) for s in streams)
    row.corrupt_frames = sum(int(s.get("corrupt_frames", 0)) for s in streams)
    row.underruns = sum(int(s.get("underruns", 0)) for s in streams)
    _notch_figures(row, summary)


def _clock_figures(row: Row, clocks: list[dict]) -> None:
    row.syncs = sum(int(c.get("syncs", 0)) for c in clocks)
    row.outside_window = sum(int(c.get("outside_window", 0)) for c in clocks)
    row.setpoints_skipped = sum(int(c.get("setpoints_skipped") or 0) for c in clocks)
    p99 = [c["jitter_p99_s"] for c in clocks if c.get("jitter_p99_s") is not None]
    worst = [c["jitter_max_s"] for c in clocks if c.get("jitter_max_s") is not None]
    row.jitter_p99_s = max(p99) if p99 else None
    row.jitter_max_s = max(worst) if worst else None
    row.sources_seen = sorted({c.get("source", "?") for c in clocks})


def _notch_figures(row: Row, summary: dict) -> None:
    found = summary.get("resonances") or []
    row.resonance_hz = found[0]["frequency_hz"] if found else None
    upload = summary.get("upload") or {}
    band = (summary.get("verification") or {}).get("band_reduction_db")
    failed = summary.get("failed_step")
    if not summary:
        row.notch = "none: no summary (the run failed)"
    elif upload.get("written") and band is not None:
        row.band_reduction_db = band
        row.notch = f"{band:.1f} dB"
    elif upload.get("written"):
        row.notch = "uploaded, not verified" + (f" ({failed} failed)" if failed else "")
    else:
        why = upload.get("not_uploaded") or upload.get("skipped_reason")
        row.notch = f"none: {why or (f'{failed} failed' if failed else 'no notch')}"


# ---------------------------------------------------------------------------------------------- printing


HEADER = (
    "transport",
    "source",
    "load",
    "other CPU",
    "exit",
    "SYNCs outside window",
    "jitter p99 / max, ms",
    "set-points skipped",
    "lost samples",
    "resonance, Hz (vs {true})",
    "notch band reduction",
    "note",
)


def _ms(seconds: float | None) -> str:
    return "-" if seconds is None else f"{1e3 * seconds:.2f}"


def table_header(true_hz: float) -> str:
    cells = [h.format(true=f"{true_hz:.2f}") for h in HEADER]
    return "| " + " | ".join(cells) + " |\n|" + "|".join("---" for _ in cells) + "|"


def table_row(r: Row, note_chars: int = 110) -> str:
    """The row as a Markdown table line."""
    share = f" ({100 * r.outside_window / r.syncs:.2f} %)" if r.syncs else ""
    if r.resonance_hz is None:
        resonance = "none found"
    else:
        resonance = f"{r.resonance_hz:.2f} ({100 * (r.resonance_hz - r.true_hz) / r.true_hz:+.2f} %)"
    note = r.error if len(r.error) <= note_chars else r.error[: note_chars - 3] + "..."
    cells = (
        r.transport,
        r.source,
        str(r.load),
        "-" if r.other_cpu is None else f"{r.other_cpu:.2f}",
        "-" if r.exit is None else str(r.exit),
        f"{r.outside_window} of {r.syncs}{share}",
        f"{_ms(r.jitter_p99_s)} / {_ms(r.jitter_max_s)}",
        str(r.setpoints_skipped),
        str(r.lost_samples),
        resonance,
        r.notch,
        note.replace("|", "/"),
    )
    return "| " + " | ".join(cells) + " |"


def machine() -> dict:
    """The date, CPU, Python and load average the figures were taken with."""
    model = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": model,
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }


def machine_line(m: dict) -> str:
    one, five, fifteen = m["load_average"]
    return (
        f"{m['date']}: {m['cpu']}, {m['cpus']} CPUs; Python {m['python']}; "
        f"load average {one:.2f} / {five:.2f} / {fifteen:.2f} (1 / 5 / 15 min)"
    )


# ---------------------------------------------------------------------------------------------- main


def _names(text: str, known: tuple[str, ...], what: str, p: argparse.ArgumentParser) -> list[str]:
    names = list(dict.fromkeys(s.strip() for s in text.split(",") if s.strip()))
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        p.error(f"--{what}: {', '.join(unknown) or 'none given'}; choose from {', '.join(known)}")
    return names


def _loads(text: str, p: argparse.ArgumentParser) -> list[int]:
    try:
        loads = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        loads = []
    if not loads or min(loads) < 0:
        p.error(f"--loads {text}: give busy-process counts, e.g. 0,1,2")
    return loads


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--config", type=Path, default=CONFIG, help=f"config of the twin (default {CONFIG.name})")
    p.add_argument("--transports", default=",".join(TRANSPORTS), help="socketcand,virtual (default both)")
    p.add_argument("--sources", default=",".join(SOURCES), help="drive,host,interface (default all three)")
    p.add_argument("--loads", default="0,1,2", help="busy processes beside the host (default 0,1,2)")
    p.add_argument("--duration-s", type=float, default=4.0, help="excitation duration, two periods (default 4)")
    p.add_argument("--amplitude", default="8", help="excitation amplitude, N*m, or auto (default 8)")
    p.add_argument("--friction", action="store_true", help="keep the config's friction test")
    p.add_argument("--timeout-s", type=float, default=240.0, help="a run longer than this is stopped (default 240)")
    p.add_argument("--start-timeout-s", type=float, default=30.0, help="time for the twin to serve (default 30)")
    p.add_argument("--out", type=Path, help="keep every run's folder here (default: a temporary folder, removed)")
    p.add_argument("--json", type=Path, help="write the machine and the rows to this file")
    args = p.parse_args(argv)
    args.transports = _names(args.transports, TRANSPORTS, "transports", p)
    args.sources = _names(args.sources, SOURCES, "sources", p)
    args.loads = _loads(args.loads, p)
    if args.amplitude != "auto":
        try:
            float(args.amplitude)
        except ValueError:
            p.error(f"--amplitude {args.amplitude}: a number (N*m) or auto")
    if args.duration_s <= 0:
        p.error("--duration-s must be positive")
    return args


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM: clean up as on Ctrl-C


def run_matrix(raw: dict, args, work: Path, rows: list[Row]) -> None:
    """Every transport, source and load; the rows as they come."""
    print(table_header(true_resonance_hz(raw)), flush=True)
    for transport in args.transports:
        sources = [s for s in args.sources if s != "interface"]
        if "interface" in args.sources:
            ok, why = interface_available(raw, transport, work / f"{transport}-interface-probe", args)
            if ok:
                sources.append("interface")
            else:
                print(f"(interface on {transport}: not available: {why})", flush=True)
        for source in sources:
            for load in args.loads:
                folder = work / f"{transport}-{source}-load{load}"
                rows.append(measure(raw, transport, source, load, folder, args))
                print(table_row(rows[-1]), flush=True)


def main(argv=None) -> int:
    args = parse_args(argv)
    raw = base_settings(args.config, args.duration_s, args.friction, args.amplitude)
    m = machine()
    print(machine_line(m))
    print(
        f"config {args.config.name} (acquisition streamed, {args.duration_s:g} s excitation, amplitude "
        f"{args.amplitude}{', friction test' if args.friction else ''}); host and busy processes at nice {NICE}",
        flush=True,
    )
    work = args.out or Path(tempfile.mkdtemp(prefix="hilident-canopen-jitter-"))
    work.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, signal.default_int_handler)  # also where a shell started it ignoring SIGINT
    rows: list[Row] = []
    started = time.monotonic()
    interrupted = False
    try:
        run_matrix(raw, args, work, rows)
    except KeyboardInterrupt:
        interrupted = True
        print("interrupted: the runs above are all there is", flush=True)
    finally:
        if args.json:
            m_end = dict(m, load_average_end=[round(x, 2) for x in os.getloadavg()])
            args.json.write_text(json.dumps({"machine": m_end, "rows": [asdict(r) for r in rows]}, indent=1))
        if args.out is None:
            shutil.rmtree(work, ignore_errors=True)
    one, five, _ = os.getloadavg()
    print(f"{len(rows)} runs in {time.monotonic() - started:.0f} s; load average now {one:.2f} / {five:.2f}")
    if args.out is not None:
        print(f"run folders in {work}")
    return 130 if interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
