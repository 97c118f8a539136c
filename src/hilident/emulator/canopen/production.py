"""The emulated CANopen drive as SYNC producer (CiA 301 0x1005 bit 30, period 0x1006).

A host writing 0x1005 with bit 30 set makes the drive produce SYNC, if its
driver's ``[canopen.sync]`` says it can (else SDO abort 0x06090030, value
range). While 0x1006 is 0 the drive waits; then it sends a SYNC every period
until bit 30 is cleared, whatever its CiA 402 state, unless NMT Stopped.

At each SYNC instant (:meth:`SyncProducer.instant`, called on a deadline
schedule by :class:`~hilident.emulator.canopen.server.CanopenDriveServer`)
the drive:

1. sends the SYNC that starts the next cycle (with the 0x1019 counter when
   ``sync_overflow > 1``), stamped with its instant on the drive's clock: the
   emulator's own lag in reaching an instant is delivery latency, never the
   device's clock (a drive's timer does not stall);
2. in a SYNC-driven run (NMT Operational, Operation Enabled), latches the
   set-points received before the previous SYNC (the newest RPDO set-point
   whose bus timestamp is earlier than that SYNC's; an RPDO that came after
   it waits for the next one) and runs the cycle that previous SYNC started,
   counting an underrun when it had no fresh set-point;
3. sends that cycle's TPDOs (the state at the start of the cycle and its
   sample index), the same frames the drive sends when it consumes SYNC.

A cycle is run once it has passed, so every RPDO stamped before its SYNC has
been read whatever the emulator's lag; its TPDOs therefore follow the next
SYNC (a host matches them by the sample counter, or by order: the n-th set of
TPDOs answers the n-th SYNC). The first SYNC of a run starts cycle 0.
A schedule that wakes late catches up cycle by cycle, each overdue cycle with
its SYNC and TPDOs in order, and counts ``late`` (the emulator's lag, not
the device's).
"""

from __future__ import annotations

import time

from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.pdo import PdoExchange
from hilident.emulator.canopen.sdo import ABORT_VALUE
from hilident.emulator.canopen.sync import SYNC_COB_ID_INDEX
from hilident.protocol.canopen_sync import SYNC_GEN_BIT

__all__ = ["SyncProducer"]


class SyncProducer:
    """SYNC production of one drive: 0x1005 as written, and what happens at each SYNC instant.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
    pdo : PdoExchange
        The drive's PDOs: its cycles and TPDOs, and its ``producing`` flag.

    Attributes
    ----------
    cob_id : int
        COB-ID of the SYNC (0x1005 bits 0-10).
    changes : int
        Counts writes of 0x1005: a schedule started before a change starts anew.
    produced : int
        SYNCs sent.
    late : int
        SYNCs sent more than the driver's window (a quarter period without one) after their instant.
    """

    def __init__(self, firmware: FirmwareHost, pdo: PdoExchange):
        self.fw = firmware
        self.pdo = pdo
        self.changes = 0
        self.produced = 0
        self.late = 0
        self.counter = 0  # the last SYNC counter sent (0x1019)
        self.sent_at: float | None = None  # bus time of the last SYNC sent
        self.cycle_open = False  # the last SYNC sent started a cycle of a SYNC-driven run
        value = int(firmware.stored(SYNC_COB_ID_INDEX, 0)) if SYNC_COB_ID_INDEX in firmware.od else 0x80
        self.cob_id = value & 0x7FF
        pdo.producing = bool(value & SYNC_GEN_BIT) and firmware.desc.sync.producer

    def write(self, value: int) -> None:
        """0x1005 written: the COB-ID, and bit 30, production on or off."""
        produce = bool(value & SYNC_GEN_BIT)
        if produce and not self.fw.desc.sync.producer:
            raise SdoAbortedError(ABORT_VALUE)  # this drive cannot produce SYNC
        if not produce and self.pdo.producing:
            self.fw.setpoints.latch()  # set-points waiting for a SYNC apply at once
        if produce and not self.pdo.producing:
            self.counter, self.sent_at, self.cycle_open = 0, None, False
        self.cob_id = value & 0x7FF
        self.pdo.producing = produce
        self.changes += 1

    def schedule(self) -> tuple[int, float]:
        """(changes, period in s) of the production as it stands; period 0: no SYNC to send."""
        with self.fw.lock:
            period_us = self.pdo.cycle_period_us if self.pdo.producing else 0
            return self.changes, period_us / 1e6

    def restart(self) -> None:
        """A run starts: the next SYNC starts its cycle 0."""
        self.cycle_open = False

    def instant(self, late_s: float, due_wall_s: float | None = None) -> None:
        """One SYNC instant, reached ``late_s`` seconds after it was due (see the module docstring).

        ``due_wall_s`` is the instant on the wall clock (``time.time()``): the
        SYNC frame carries it as its bus timestamp, as the drive's own timer
        would put it on the wire; the emulator's lag in getting here is
        delivery, not the device's clock (None: the time it is sent).
        """
        fw, pdo = self.fw, self.pdo
        with fw.lock:
            state = fw.node.nmt.state
            if not pdo.producing or state == "STOPPED":
                return
            previous = self.sent_at
            period_s = pdo.cycle_period_us / 1e6
            if late_s > (pdo.sync.window_us * 1e-6 or 0.25 * period_s):
                self.late += 1
            self.sent_at = time.time() if due_wall_s is None else due_wall_s  # the SYNC frame's bus timestamp
            fw.send_stamped(self.cob_id, self._payload(pdo.sync_overflow), self.sent_at)  # the timer first
            self.produced += 1
            if previous is not None:
                fw.setpoints.latch(previous)
            running = state == "OPERATIONAL" and pdo.running()
            if running and self.cycle_open:
                k = fw.sample_index
                pdo.send_tpdos(pdo.cycle(fresh=True)[0], k)
                fw.check_faults()
                running = pdo.running()
            self.cycle_open = running

    def _payload(self, overflow: int) -> bytes:
        """SYNC data: the counter 1..``overflow`` when 0x1019 is above 1 (CiA 301), else none."""
        if overflow <= 1:
            return b""
        self.counter = self.counter % overflow + 1
        return bytes([self.counter])
