"""The board implementations the conformance checks run against, each served on a TCP line of 127.0.0.1.

* ``python-twin``: the emulated board (:mod:`hilident.emulator.serial`), served in this process as
  ``hilident emulate serial --tcp`` serves it, in real time (time scale 1).
* ``c-board``: the reference C firmware's ``posix-sim`` target, built for the test run with the
  firmware's Makefile (:func:`support.c_board.build`: skipped without ``cc`` and ``make``) and started
  as a process; it serves a TCP line on 127.0.0.1 and prints the line's ``socket://127.0.0.1:PORT`` URL
  as the first line of its standard output.

Every board starts powered up afresh for each check (PROTOCOL.md section 5: IDLE, no configuration, no
limits, every filter slot bypassed), and every check ends with the board still alive.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

from conformance.wire import Wire
from hilident.config.tables import parse_config
from hilident.drivers.description import DriverDescription, find_driver
from hilident.emulator.factory import start_standalone
from hilident.protocol import serial_board as sb

REPO = Path(__file__).resolve().parents[2]
#: The driver description the boards answer for (PROTOCOL.md section 4.9).
DRIVER: DriverDescription = find_driver(str(REPO / "drivers" / "myrio-board"))

#: The C board's command line after the executable: the board on a free TCP port of 127.0.0.1, in real time,
#: ``socket://127.0.0.1:PORT`` its first line of standard output (as ``hilident emulate serial --tcp``).
C_BOARD_ARGS = ["--tcp", "0"]
#: How long the C board may take to print its URL, s.
C_BOARD_START_S = 10.0

#: The twin's configuration: the defaults ``hilident emulate serial`` serves, in real time.
TWIN_CONFIG = "[emulator]\ntime_scale = 1.0\n"


@dataclass
class Board:
    """A board on a line: its implementation's name, the ``socket://`` URL a host opens and the identity
    it must report."""

    implementation: str
    url: str
    driver: DriverDescription = DRIVER
    timeout_s: float = 2.0  #: how long a check waits for an answer
    wires: list[Wire] = field(default_factory=list)

    @property
    def identity(self) -> sb.Identity:
        """What the board must answer to IDENTIFY: the driver description's board (PROTOCOL.md section 4.9)."""
        d = self.driver
        return sb.Identity(
            protocol_version=d.protocol_version,
            name=d.name,
            firmware=d.firmware,
            loop_rate_hz=d.loop_rate_hz,
            max_sample_rate_hz=d.max_sample_rate_hz,
            filter_slots=d.filter_slots,
            excitation_buffer_samples=d.excitation_buffer_samples,
            channels=tuple(sb.ChannelInfo(c.name, c.unit) for c in d.channels),
        )

    def connect(self, first_seq: int = 0x7FF0) -> Wire:
        """A new host connection to the board (closed when the check ends)."""
        wire = Wire(
            self.url, self.timeout_s, first_seq, self.driver.loop_rate_hz, self.driver.excitation_buffer_samples
        )
        self.wires.append(wire)
        return wire

    def close_wires(self) -> None:
        for wire in self.wires:
            wire.close()


@contextmanager
def python_twin(timeout_s: float = 2.0) -> Iterator[Board]:
    """The emulated board on a fresh TCP line, powered up for one check."""
    cfg = parse_config(TWIN_CONFIG, "<conformance twin>")
    emu = start_standalone(replace(cfg.emulator, time_scale=1.0), DRIVER, cfg.device, "tcp")
    board = Board("python-twin", emu.device.port, timeout_s=timeout_s)
    try:
        yield board
        assert emu.server.error is None, f"the twin's board thread failed: {emu.server.error!r}"
    finally:
        board.close_wires()
        emu.close()


@contextmanager
def c_board(executable: Path, folder: Path, timeout_s: float = 2.0) -> Iterator[Board]:
    """The C board's ``posix-sim`` process, started for one check; its output goes to files in ``folder``."""
    out, err = folder / "c-board.stdout", folder / "c-board.stderr"
    with out.open("wb") as stdout, err.open("wb") as stderr:
        proc = subprocess.Popen(
            [str(executable), *C_BOARD_ARGS], stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr
        )
    board = None
    try:
        url = _first_line(out, proc, err)
        assert url.startswith("socket://127.0.0.1:"), f"the C board printed {url!r}, not socket://127.0.0.1:PORT"
        board = Board("c-board", url, timeout_s=timeout_s)
        yield board
        assert proc.poll() is None, f"the C board exited with {proc.returncode} during the check: {_tail(err)}"
    finally:
        if board is not None:
            board.close_wires()
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _first_line(path: Path, proc: subprocess.Popen, err: Path) -> str:
    deadline = time.monotonic() + C_BOARD_START_S
    while time.monotonic() < deadline:
        text = path.read_text(errors="replace")
        if "\n" in text:
            return text.split("\n", 1)[0].strip()
        assert proc.poll() is None, f"the C board exited with {proc.returncode} before printing its URL: {_tail(err)}"
        time.sleep(0.02)
    raise AssertionError(f"the C board printed no URL within {C_BOARD_START_S:g} s: {_tail(err)}")


def _tail(path: Path) -> str:
    return path.read_text(errors="replace")[-2000:] or "(nothing on stderr)"
