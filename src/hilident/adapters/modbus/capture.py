"""Drive-buffered runs of the Modbus adapter: the excitation table written through its page window,
the run triggered, the capture read back.

:class:`TableCapture` is a part :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` owns (its
``capture``); its requests go through the request part
(:class:`~hilident.adapters.modbus.requests.RegisterAccess`). The adapter's run follows the drive's status
and reads the capture through it as it fills.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hilident.adapters.base import Deliver
from hilident.adapters.modbus.common import (
    _RETRIES,
    CaptureLayout,
    ModbusIdentity,
    NoResponse,
)
from hilident.adapters.modbus.requests import RegisterAccess
from hilident.errors import DataError, DeviceError
from hilident.events import Kind, RunEvent, StreamStats
from hilident.protocol.modbus.paging import STAMP_MODULUS, Chunk, Window, plan_chunks, table_crc


class TableCapture:
    """The table and capture part of :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` (its ``capture``).

    The table goes to the drive in pages and is checked by its CRC; the run is triggered
    and the capture read back in chunks while the drive plays, a record that is not the
    one asked for read again and a chunk that cannot be read counted lost.

    Parameters
    ----------
    registers : RegisterAccess
        The requests (and the map, port and driver they name).
    identity : callable
        The drive's identity as read at connect (its table and capture capacities); DeviceError before.
    log_event : callable
        Where a run event goes as soon as it is known (the adapter's ``log_event``).

    Attributes
    ----------
    layout : CaptureLayout
        The channels ``configure()`` chose and their columns in a record.
    """

    def __init__(
        self,
        registers: RegisterAccess,
        identity: Callable[[], ModbusIdentity],
        log_event: Callable[[RunEvent], dict],
    ):
        self.registers = registers
        self.map = registers.map
        self.port = registers.port
        self.driver = registers.driver
        self.identity = identity
        self.log_event = log_event
        self.layout = CaptureLayout()
        self._pages: dict[str, int | None] = {"table": None, "capture": None}  # page selected; None: unknown

    def _window(self, name: str) -> Window:
        """The drive's ``"table"`` or ``"capture"`` window; DeviceError when its map has no excitation capability."""
        window = self.map.table if name == "table" else self.map.capture
        if window is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no [modbus.{name}] window")
        return window

    def _select_page(self, window: Window, page: int) -> None:
        if self._pages[window.name] != page:
            self._pages[window.name] = None  # unknown until the drive confirms
            self.registers.write_names(**{window.page_register: page})
            self._pages[window.name] = page

    def _upload(self, table: np.ndarray, n: int) -> None:
        """Write the table's registers through the table window, a page at a time."""
        rps = self.map.table_registers_per_sample
        w = self._window("table")
        for c in plan_chunks(0, n, rps, w.page_samples, self.map.max_write):
            self._select_page(w, c.page)
            try:
                self.registers.write(
                    w.base + c.offset,
                    table[c.first_sample * rps : (c.first_sample + c.samples) * rps],
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
                regs = self.registers.read(
                    w.base + c.offset,
                    c.count,
                    f"reading capture samples {c.first_sample}..{c.first_sample + c.samples - 1}",
                    retry=False,
                    page=c.page,
                )
            except NoResponse:
                self._pages["capture"] = None
                continue
            stamps, rows = self.map.decode_records(regs, self.layout.mask)
            if np.array_equal(stamps, expected):
                sink(c.first_sample + np.arange(c.samples, dtype=np.int64), rows[:, list(self.layout.columns)])
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

    def trigger(self) -> None:
        """Start the run: one write of the run bit, never repeated."""
        r = self.map.register("control_word")
        run = self.map.control["run"]
        try:
            self.registers.request(
                "starting the run",
                r.address,
                1,
                lambda: self.registers.client.write_register(r.address, run, device_id=self.registers.device_id),
                lambda resp: resp.address == r.address,
                retry=False,
            )
        except NoResponse as exc:
            # the command may have arrived: ask the drive instead of sending it again
            after = self.registers.status()
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
        ident = self.identity()
        for cap, name in ((ident.table_capacity, "table_capacity"), (ident.capture_capacity, "capture_capacity")):
            if n > cap:
                raise DeviceError(
                    f"{self.port}: {n} samples exceed the drive's {cap} "
                    f"({self.map.describe(self.map.register(name).address)}); shorten the excitation "
                    "or lower run.sample_rate_hz"
                )
        table = self.map.encode_table(x)
        self.registers.write_names(control_word=0)  # stopped, and ready for a fresh 0 -> 1 edge
        before = self.registers.status()
        if "fault" in before.flags:
            raise DeviceError(
                f"{self.port}: the drive reports {self.map.fault_name(before.fault_code)} in "
                f"{self.map.describe(self.map.register('fault_code').address)}; clear the fault before a run"
            )
        self.registers.write_names(table_length=n)
        self._upload(table, n)
        crc = self.registers.read_names("table_crc")["table_crc"]
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
        width = self.map.record_registers(self.layout.mask)
        chunks = plan_chunks(first, count, width, self._window("capture").page_samples, self.map.max_read)
        end = first
        for c in chunks[:max_chunks]:
            self._read_chunk(c, stats, sink)
            end = c.first_sample + c.samples
        return end
