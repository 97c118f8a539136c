"""Drive-buffered runs of the Modbus adapter: the excitation table written through its page window,
the capture read back.

One part of :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter`, which composes the parts
(see that module); it builds on the request part (:class:`~hilident.adapters.modbus.requests.RegisterAccess`).
"""

from __future__ import annotations

import time

import numpy as np

from hilident.adapters.base import Deliver, RunResult
from hilident.adapters.modbus.common import (
    _CHUNKS_PER_POLL,
    _LIMIT_FAULTS,
    _POLL_S,
    _RETRIES,
    DriveStatus,
    NoResponse,
)
from hilident.adapters.modbus.requests import RegisterAccess
from hilident.errors import DataError, DeviceError
from hilident.events import Kind, RunEvent, StreamStats
from hilident.protocol.modbus_registers import (
    STAMP_MODULUS,
    Chunk,
    Window,
    plan_chunks,
    table_crc,
)


class TableCapture(RegisterAccess):
    """The table and capture part of :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter`.

    The table goes to the drive in pages and is checked by its CRC; the run is triggered
    and the capture read back in chunks while the drive plays, a record that is not the
    one asked for read again and a chunk that cannot be read counted lost.
    """

    # --- buffered runs ------------------------------------------------------------------------

    def _window(self, name: str) -> Window:
        """The drive's ``"table"`` or ``"capture"`` window; DeviceError when its map has no excitation capability."""
        window = self.map.table if name == "table" else self.map.capture
        if window is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no [modbus.{name}] window")
        return window

    def _select_page(self, window: Window, page: int) -> None:
        if self._pages[window.name] != page:
            self._pages[window.name] = None  # unknown until the drive confirms
            self.write_names(**{window.page_register: page})
            self._pages[window.name] = page

    def _upload(self, registers: np.ndarray, n: int) -> None:
        rps = self.map.table_registers_per_sample
        w = self._window("table")
        for c in plan_chunks(0, n, rps, w.page_samples, self.map.max_write):
            self._select_page(w, c.page)
            try:
                self.write(
                    w.base + c.offset,
                    registers[c.first_sample * rps : (c.first_sample + c.samples) * rps],
                    f"writing excitation samples {c.first_sample}..{c.first_sample + c.samples - 1}",
                    c.page,
                )
            except DeviceError:
                self._pages["table"] = None
                raise

    def _read_chunk(self, c: Chunk, stats: StreamStats, sink: Deliver) -> None:
        """Read one chunk of capture records; deliver it, or count it lost."""
        w = self._window("capture")
        expected = (c.first_sample + np.arange(c.samples)) % STAMP_MODULUS
        for _ in range(1 + _RETRIES):
            try:
                self._select_page(w, c.page)
                regs = self.read(
                    w.base + c.offset,
                    c.count,
                    f"reading capture samples {c.first_sample}..{c.first_sample + c.samples - 1}",
                    retry=False,
                    page=c.page,
                )
            except NoResponse:
                self._pages["capture"] = None
                continue
            stamps, rows = self.map.decode_records(regs, self._mask)
            if np.array_equal(stamps, expected):
                sink(c.first_sample + np.arange(c.samples, dtype=np.int64), rows[:, self._order])
                stats.samples += c.samples
                return
            # not the records asked for: a repeated or misplaced chunk, or damaged data; read it again
            if np.all((np.diff(stamps) % STAMP_MODULUS) == 1):
                stats.out_of_order += 1
            else:
                stats.corrupt_frames += 1
            self._pages["capture"] = None
        stats.lost_blocks += 1
        stats.lost_samples += c.samples
        self.log_event(
            RunEvent(
                Kind.LOST_BLOCKS,
                f"capture samples {c.first_sample}..{c.first_sample + c.samples - 1} "
                f"could not be read ({1 + _RETRIES} attempts); not filled",
                c.first_sample,
                value=1.0,
            )
        )

    def _trigger(self) -> None:
        """Start the run: one write of the run bit, never repeated."""
        r = self.map.register("control_word")
        run = self.map.control["run"]
        try:
            self._request(
                "starting the run",
                r.address,
                1,
                lambda: self.client.write_register(r.address, run, device_id=self.device_id),
                lambda resp: resp.address == r.address,
                retry=False,
            )
        except NoResponse as exc:
            # the command may have arrived: ask the drive instead of sending it again
            after = self.status()
            if not after.flags & {"running", "done"}:
                raise DeviceError(
                    f"{exc}; the drive is not running (not repeated: a start is never sent twice)"
                ) from None
            self.log_event(
                RunEvent(
                    Kind.MISSING_RESPONSE,
                    "the answer to the start command was lost; the drive reports the run started",
                    0,
                    value=0.0,
                )
            )

    def load_table(self, excitation: np.ndarray) -> np.ndarray:
        """Stop the drive, arm a run of ``len(excitation)`` samples and write the table; returns its registers.

        The drive's CRC of the table is compared with the CRC of what was sent.

        Raises
        ------
        DeviceError
            The excitation exceeds the table or capture, a fault is latched, a
            request was refused or went unanswered, or the CRC differs.
        DataError
            The excitation is empty or a value does not fit the table's type.
        """
        x = np.asarray(excitation, dtype=float)
        n = len(x)
        if n < 1:
            raise DataError("the excitation is empty")
        ident = self._known_identity()
        for cap, name in ((ident.table_capacity, "table_capacity"), (ident.capture_capacity, "capture_capacity")):
            if n > cap:
                raise DeviceError(
                    f"{self.port}: {n} samples exceed the drive's {cap} "
                    f"({self.map.describe(self.map.register(name).address)}); shorten the excitation "
                    "or lower run.sample_rate_hz"
                )
        table = self.map.encode_table(x)
        self.write_names(control_word=0)  # stopped, and ready for a fresh 0 -> 1 edge
        before = self.status()
        if "fault" in before.flags:
            raise DeviceError(
                f"{self.port}: the drive reports {self.map.fault_name(before.fault_code)} in "
                f"{self.map.describe(self.map.register('fault_code').address)}; clear the fault before a run"
            )
        self.write_names(table_length=n)
        self._upload(table, n)
        crc = self.read_names("table_crc")["table_crc"]
        if crc != table_crc(table):
            raise DeviceError(
                f"{self.port}: {self.map.describe(self.map.register('table_crc').address)} is "
                f"{crc:#06x}, the table sent has {table_crc(table):#06x}: the excitation table did "
                "not arrive intact"
            )
        return table

    def read_capture(
        self, first: int, count: int, sink: Deliver, stats: StreamStats, max_chunks: int | None = None
    ) -> int:
        """Read capture records ``first .. first + count - 1`` (or the first ``max_chunks`` requests of them).

        Each chunk is delivered to ``sink(sample_index, rows)`` or counted lost
        in ``stats``. Returns the index after the last record read.
        """
        width = self.map.record_registers(self._mask)
        chunks = plan_chunks(first, count, width, self._window("capture").page_samples, self.map.max_read)
        end = first
        for c in chunks[:max_chunks]:
            self._read_chunk(c, stats, sink)
            end = c.first_sample + c.samples
        return end

    def _play(self, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
        """Play ``x`` from the drive's table and hand the captured samples to ``deliver``.

        ``x[k]`` is held over sample period ``k``; row ``k`` is the drive's
        state at the start of that period. Samples the capture lacks (chunks
        that could not be read, a capture that stopped early) are counted in
        the result's stats, never filled. A fault is logged as soon as a status
        read shows it. While the drive is enabled each answer is waited for at
        most 40 % of the communication timeout.

        Raises
        ------
        DeviceError
            The drive refused a request (the message names the register),
            stopped answering, lost the connection, or did not finish in time.
        DataError
            The excitation is empty or a value does not fit the table's type.
        """
        self._run_counts = (self.missing_responses, self.bad_responses)
        self.load_table(x)
        with self._answers_within(self._enabled_wait_s):
            self._trigger()
            self._capture(len(x), result.stats, deliver)
        result.completed = self.run_fault is None

    def _end_run(self, result: RunResult) -> None:
        """The drive stopped and disabled; the run's unanswered and bad answers counted."""
        self.safe_stop()
        missing_before, bad_before = self._run_counts
        result.stats.lost_frames = self.missing_responses - missing_before
        result.stats.corrupt_frames += self.bad_responses - bad_before

    def _capture(self, n: int, stats: StreamStats, deliver: Deliver) -> None:
        """Poll the status and read the capture as it fills, until the run has ended and all is read."""
        started = time.monotonic()
        deadline = started + 1.2 * n / self.sample_rate_hz + 2.0 + 2 * self.timeout_s
        read_to = 0
        while True:
            st = self.status()
            if "fault" in st.flags and self.run_fault is None:
                self._note_fault(st)  # known now: the first cause, whatever fails after it
            available = min(st.sample_count, n)
            before = read_to
            read_to = self.read_capture(read_to, available - read_to, deliver, stats, _CHUNKS_PER_POLL)
            ended = "running" not in st.flags
            if ended and read_to >= available:
                break
            if ended and not st.flags & {"done", "fault"}:
                raise DeviceError(
                    f"{self.port}: the run ended without the drive reporting it done "
                    f"({self.map.describe(self.map.register('status_word').address)} = {st.word:#06x})"
                )
            if read_to == before:
                if time.monotonic() > deadline:
                    raise DeviceError(
                        f"{self.port}: the run did not end within {deadline - started:.1f} s "
                        f"({self.map.describe(self.map.register('status_word').address)} still shows "
                        "running); stopped"
                    )
                time.sleep(_POLL_S)
        if self.run_fault is not None:
            return
        if available < n:
            stats.lost_samples += n - available
            self.log_event(
                RunEvent(
                    Kind.CAPTURE_STOPPED,
                    f"the drive's capture stopped at sample {available} of {n}; "
                    f"samples {available}..{n - 1} were not recorded "
                    "(not filled)",
                    available,
                    value=float(n - available),
                )
            )
        else:
            self.log_event(RunEvent(Kind.FINISHED, "run complete", n, value=0.0))

    def _describe_fault(self, st: DriveStatus) -> str:
        """A latched fault in words: name, register, sample and value."""
        name = self.map.fault_name(st.fault_code)
        where = self.map.describe(self.map.register("fault_code").address)
        if name == "comm_timeout":
            return (
                f"comm_timeout: the drive heard nothing from the host for {st.fault_value:.3g} s and stopped "
                f"on its own ({where} = {st.fault_code}, at sample {st.fault_sample})"
            )
        return f"{name} ({where} = {st.fault_code}, at sample {st.fault_sample}, value {st.fault_value:g})"

    def _note_fault(self, st: DriveStatus) -> None:
        """Log a fault the status shows as an event, at once, and note it as the run's cause."""
        name = self.map.fault_name(st.fault_code)
        message = self._describe_fault(st)
        if name != "comm_timeout":
            message = message.replace(" (", ": axis stopped, torque zero (", 1)
        kind = Kind.LIMIT_TRIP if name in _LIMIT_FAULTS else Kind.FAULT
        self.note_fault(self.log_event(RunEvent(kind, message, st.fault_sample, value=st.fault_value)))
