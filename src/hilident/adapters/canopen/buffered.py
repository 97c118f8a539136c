"""Drive-buffered runs on a CANopen drive: excitation table in, capture out, both over SDO.

1. The excitation (REAL32, the mode's SI unit; positions relative to the
   position at enable) is downloaded into the table object, by SDO block
   transfer when the driver description allows it, and its length read back.
2. The drive is enabled and the table started; it plays the table at its own
   sample rate, recording the mapped channels into its capture buffer.
3. While it plays, the host polls the table state and the capture count, sets
   the capture read offset and uploads the new records (block transfer), so
   the capture is home shortly after the table ends.
4. A capture shorter than the table (the drive's buffer ended early) is
   reported: the missing samples are counted, a ``capture_short`` event is
   logged, and the run ends with DeviceError after the captured samples were
   delivered. An emergency ends it with LimitTrip or DeviceError the same way.
"""

from __future__ import annotations

import time

import numpy as np

from hilident.adapters.base import RunResult, RunStrategy
from hilident.adapters.canopen.streamed import Deliver, DriveHost
from hilident.errors import DeviceError
from hilident.protocol.canopen_objects import TABLE_START, TABLE_STOP, TableState, record_dtype

__all__ = ["BufferedRun"]

_POLL_S = 0.05
_EMCY_WAIT_S = 0.3  # a table that stopped early: wait this long for the emergency that says why


class BufferedRun(RunStrategy):
    """One drive-buffered run: the table downloaded, played, and its capture read back as it fills.

    State: the samples captured so far, when the capture last grew, the
    table's state. The adapter is used through
    :class:`~hilident.adapters.canopen.streamed.DriveHost`.
    """

    ad: DriveHost

    def __init__(self, adapter: DriveHost, x: np.ndarray, deliver: Deliver, result: RunResult):
        super().__init__(adapter, x, deliver, result)
        self.captured = 0
        self.state = TableState.PLAYING
        self.dtype = record_dtype([c.datatype for c in adapter.layout.channels])  # one capture record

    def where(self, role: str) -> str:
        """The object of ``role``, for messages."""
        return self.ad.sdo.describe(self.ad.desc.address(role))

    def load(self) -> None:
        """Download the excitation into the table and check the length the drive holds."""
        ad, n = self.ad, self.n
        capacity = int(ad.sdo.read("table_capacity"))
        if n > capacity:
            raise DeviceError(
                f"{ad.port}: the excitation has {n} samples; the drive's table holds {capacity} "
                f'({self.where("table_capacity")}); use device.acquisition = "streamed" '
                "or a shorter run"
            )
        ad.sdo.write_domain(ad.desc.address("table"), np.asarray(self.x, dtype="<f4").tobytes())
        length = int(ad.sdo.read("table_length"))
        if length != n:
            raise DeviceError(
                f"{ad.port}: wrote {n} table samples, the drive holds {length} ({self.where('table_length')})"
            )

    def read_capture(self, count: int) -> None:
        """Upload and deliver the records from :attr:`captured` up to ``count``."""
        ad, size = self.ad, self.dtype.itemsize
        while self.captured < count:
            ad.sdo.write("capture_offset", self.captured)
            data = ad.sdo.read_domain(ad.desc.address("capture_data"))
            m = len(data) // size
            if m == 0 or len(data) % size:
                raise DeviceError(
                    f"{ad.port}: a capture chunk of {len(data)} bytes from "
                    f"{self.where('capture_data')} is not whole {size}-byte records"
                )
            records = np.frombuffer(data, dtype=self.dtype)
            rows = ad.decode_rows([records[f"f{i}"] for i in range(len(ad.layout.channels))], self.captured)
            self.deliver(np.arange(self.captured, self.captured + m, dtype=np.int64), rows)
            self.captured += m
            self.stats.samples += m

    def take_emergencies(self) -> None:
        """Emergencies queued so far; the first fault stops the table."""
        if self.ad.run_fault is None and self.ad.take_emergency_fault(self.captured) is not None:
            self.stop_table()  # an emergency stops the excitation, whatever the drive does on its own

    def run(self) -> None:
        """Play the table and capture; see the module docstring."""
        ad, n = self.ad, self.n
        self.load()
        ad.enable()
        ad.sdo.write("table_command", TABLE_START)
        last_change = time.monotonic()
        stall_limit = max(2.0, 2 * ad.timeout_s)
        while True:
            self.take_emergencies()
            ad.net.check_link()
            self.state = int(ad.sdo.read("table_state"))
            count = int(ad.sdo.read("capture_count"))
            if count > self.captured:
                last_change = time.monotonic()
            self.read_capture(count)
            if self.state != TableState.PLAYING:
                break
            if time.monotonic() - last_change > stall_limit:
                raise DeviceError(
                    f"{ad.port}: the capture stalled at {self.captured} of {n} samples for "
                    f"{stall_limit:g} s ({self.where('capture_count')})"
                )
            time.sleep(_POLL_S)
        if self.state == TableState.STOPPED and ad.run_fault is None:
            deadline = time.monotonic() + _EMCY_WAIT_S
            while not ad.net.emergencies and time.monotonic() < deadline:
                time.sleep(0.01)
            ad.take_emergency_fault(self.captured)
        if ad.run_fault is not None:
            return
        self.check_complete()

    def check_complete(self) -> None:
        """DeviceError when the table stopped early or the capture is short; else the ``capture_end`` event."""
        ad, n, captured = self.ad, self.n, self.captured
        if self.state == TableState.STOPPED:
            self.result.fault = f"the drive stopped the table at sample {captured} without an emergency"
            raise DeviceError(f"{ad.port}: {self.result.fault} ({self.where('table_state')})")
        self.finish_capture(
            captured,
            f"the drive captured only {captured} of {n} samples "
            f"({self.where('capture_count')}): its capture ended early",
            f"table played and {n} samples captured",
        )

    def stop_table(self) -> None:
        try:
            self.ad.sdo.write("table_command", TABLE_STOP)
        except DeviceError:
            pass  # a drive in Fault may refuse; its power stage is off anyway
