"""Drive-buffered runs of the emulated CANopen drive: the excitation table, its playback, the capture buffer.

The host downloads an excitation table, maps the objects to capture, starts
the table, and the drive plays it at its own rate through
:class:`~hilident.emulator.clock.TablePlayer` (paced by the drive's
:class:`~hilident.emulator.clock.SimClock`), recording each sample period's
mapped objects into its capture buffer, which the host uploads in chunks.
"""

from __future__ import annotations

import time

import numpy as np
from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.roles import COLUMN_OF_ROLE
from hilident.emulator.canopen.sdo import (
    ABORT_LENGTH,
    ABORT_LENGTH_HIGH,
    ABORT_NO_DATA,
    ABORT_NOT_MAPPABLE,
    ABORT_STATE,
    ABORT_TOO_HIGH,
    ABORT_VALUE,
)
from hilident.emulator.clock import Played, TablePlayer
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    NUMERIC_TYPES,
    TABLE_START,
    TABLE_STOP,
    TableState,
    encode_si,
    parse_mapping_entry,
    record_dtype,
    type_bits,
)
from hilident.protocol.canopen_types import ObjectAddress

__all__ = ["CAPTURE_CHUNK_RECORDS", "TablePlayback"]

#: Most capture records one upload of the capture-data object returns.
CAPTURE_CHUNK_RECORDS = 4096
#: Roles a capture may hold besides the sampled signals.
_CAPTURED_STATES = ("sample_counter", "statusword", "modes_display")


class TablePlayback:
    """Table, divider, capture mapping and capture buffer of one drive, and their playback.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
        The drive it belongs to: object dictionary, CiA 402 state, drive loop, faults.

    Attributes
    ----------
    state : TableState
    produced : int
        Samples of the table played in this run.
    """

    def __init__(self, firmware: FirmwareHost):
        self.fw = firmware
        desc = firmware.desc
        buffered = all(desc.has(r) for r in ("table", "table_divider", "table_capacity"))
        self.table = np.zeros(0, dtype=np.float32)
        self.divider = int(firmware.default(desc.address("table_divider"))) if buffered else 1
        self.capacity = int(firmware.default(desc.address("table_capacity"))) if buffered else 0
        self.state = TableState.IDLE
        self.produced = 0
        self.layout: list[tuple[str, int]] = []  # (role, data type) of each captured object
        self.record_size = 0
        self.capture = bytearray()
        self.count = 0
        self.offset = 0
        self.stopped = False
        self.player = TablePlayer(firmware.drive, self.divider, firmware.loop_rate, firmware.driver.averaged_channels)

    # --- the clock's view (hilident.emulator.clock.PacedFirmware) ----------------------------------

    @property
    def playing(self) -> bool:
        return self.state == TableState.PLAYING

    @property
    def running(self) -> bool:
        return self.playing and self.fw.state is cia402.State.OPERATION_ENABLED

    @property
    def sample_rate_hz(self) -> float:
        return self.fw.loop_rate / self.divider

    def idle(self, n_ticks: int) -> None:
        """Coast: the physics goes on with the power stage off."""
        self.fw.last_row = self.fw.drive.run(np.zeros(n_ticks))[-1]

    # --- objects --------------------------------------------------------------------------------

    def size_limit(self, index: int, subindex: int) -> int | None:
        """Most bytes the table object takes (None: another object, no limit of ours)."""
        desc = self.fw.desc
        if desc.has("table") and ObjectAddress(index, subindex) == desc.address("table"):
            return 4 * self.capacity
        return None

    def read(self, role: str | None):
        """Live value of a playback object (None: not one of them)."""
        return (
            {
                "table_length": len(self.table),
                "table_state": self.state,
                "capture_count": self.count,
                "capture_offset": self.offset,
                "table_divider": self.divider,
            }.get(role)
            if role is not None
            else None
        )

    def write_table(self, data: bytes) -> None:
        if self.playing:
            raise SdoAbortedError(ABORT_STATE)
        if len(data) % 4:
            raise SdoAbortedError(ABORT_LENGTH)
        if len(data) // 4 > self.capacity:
            raise SdoAbortedError(ABORT_LENGTH_HIGH)
        values = np.frombuffer(data, dtype="<f4")
        if not np.all(np.isfinite(values)):
            raise SdoAbortedError(ABORT_VALUE)
        self.table = values.copy()
        self.state = TableState.IDLE

    def write_divider(self, divider: int) -> None:
        if self.playing:
            raise SdoAbortedError(ABORT_STATE)
        if not 1 <= divider or self.fw.loop_rate / divider > self.fw.driver.max_sample_rate_hz:
            raise SdoAbortedError(ABORT_VALUE)
        self.divider = divider

    def write_capture_mapping(self, sub: int, value: int) -> None:
        if self.playing:
            raise SdoAbortedError(ABORT_STATE)
        if sub != 0:
            return
        fw = self.fw
        index = fw.desc.address("capture_mapping").index
        layout: list[tuple[str, int]] = []
        size = 0
        for s in range(1, value + 1):
            addr, width = parse_mapping_entry(int(fw.stored(index, s)))
            obj = fw.od.get_variable(addr.index, addr.subindex)
            role = fw.role_of.get(addr)
            if (
                obj is None
                or role is None
                or obj.data_type not in NUMERIC_TYPES
                or width != type_bits(obj.data_type)
                or not (role in COLUMN_OF_ROLE or role in _CAPTURED_STATES)
            ):
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)  # only sampled signals can be captured
            layout.append((role, obj.data_type))
            size += width // 8
        self.layout = layout
        self.record_size = size

    def write_capture_offset(self, offset: int) -> None:
        if offset > self.count:
            raise SdoAbortedError(ABORT_TOO_HIGH)
        self.offset = offset

    def write_command(self, command: int) -> None:
        if command == TABLE_STOP:
            if self.playing:
                self.state = TableState.STOPPED
            return
        if command != TABLE_START:
            raise SdoAbortedError(ABORT_VALUE)
        fw = self.fw
        if fw.state is not cia402.State.OPERATION_ENABLED or self.playing or not len(self.table) or not self.layout:
            raise SdoAbortedError(ABORT_STATE)
        fw.start_run()
        self.player.restart(self.divider)
        fw.clock.start_run(time.monotonic())
        self.state = TableState.PLAYING
        self.produced = 0
        self.capture = bytearray()
        self.count = 0
        self.offset = 0
        self.stopped = False

    def capture_chunk(self) -> bytes:
        """The next upload of the capture-data object: records from the capture offset on."""
        start = self.offset
        stop = min(self.count, start + CAPTURE_CHUNK_RECORDS)
        if stop <= start:
            raise SdoAbortedError(ABORT_NO_DATA)
        size = self.record_size
        return bytes(self.capture[start * size : stop * size])

    # --- playing ------------------------------------------------------------------------------------

    def advance(self, n_samples: int) -> None:
        """Play up to ``n_samples`` samples of the table and capture them."""
        fw, first = self.fw, self.produced
        n = min(n_samples, len(self.table) - first)
        n = self.player.cut_at(first, n, fw.pending_fault_times())  # stop exactly where an injected fault is due
        if n <= 0:
            return
        played = self.player.play(self.table[first : first + n], first)
        self.produced = fw.sample_index = first + n
        fw.last_row = played.rows[-1]
        self._capture(played)
        fw.check_faults()
        if self.playing and self.produced >= len(self.table):
            self.state = TableState.DONE
            fw.power_off()  # end of table: disable operation (transition 5), torque off
            fw.state = cia402.State.SWITCHED_ON

    def _capture(self, played: Played) -> None:
        keep = played.kept
        stop_after = self.fw.faults.capture_stops_after_s
        if stop_after:
            keep = min(keep, self.player.samples_before(stop_after) - played.first)
        if keep > 0 and not self.stopped:
            self.capture += self._records(played.rows[:keep], played.first).tobytes()
            self.count += keep
        if keep < len(played.rows):
            self.stopped = True

    def _records(self, rows: np.ndarray, first: int) -> np.ndarray:
        """Capture records of ``rows`` (samples ``first`` ...) as a packed structured array."""
        fw = self.fw
        out = np.empty(len(rows), dtype=record_dtype([t for _, t in self.layout]))
        for i, (role, dtype) in enumerate(self.layout):
            if role in COLUMN_OF_ROLE:
                out[f"f{i}"] = encode_si(rows[:, fw.columns[COLUMN_OF_ROLE[role]]], dtype, fw.scales[role])
            elif role == "sample_counter":
                out[f"f{i}"] = (first + np.arange(len(rows))) & 0xFFFF
            else:  # statusword, mode display: constant over a chunk
                out[f"f{i}"] = fw.live(role, fw.desc.address(role), rows[0], first)
        return out
