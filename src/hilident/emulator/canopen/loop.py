"""The emulated CANopen drive's cascade parameters: the objects of its ``[loop]`` table.

The drive loop (:class:`~hilident.emulator.drive.DriveLoop`) runs with its
:class:`~hilident.emulator.drive.DriveTuning`; these objects are that tuning,
read as it is and written into it. A write of a tunable parameter
(:data:`~hilident.protocol.loop_parameters.TUNABLE`) retunes the running loop
at once, as a drive takes a new parameter; the current loop and the delay are
the power stage's and the firmware's, read-only. A value the loop cannot run
(a negative gain, a zero integral time) is refused with the SDO abort a drive
gives for a value out of range, and the loop keeps its gains. A drive that keeps
the velocity integral as a gain (``ki_nm_per_m``) keeps that gain when ``kv``
is written: its integral time moves with ``kv``, as a real one's does.
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.sdo import ABORT_VALUE
from hilident.errors import ConfigError
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.loop_parameters import WRITABLE

__all__ = ["LoopObjects"]

_ABORT_READ_ONLY = 0x06010002  # attempt to write a read-only object (CiA 301)
_REAL_TYPES = (0x0008, 0x0011)  # REAL32, REAL64


class LoopObjects:
    """Reads and writes of the objects that hold the drive's cascade parameters."""

    def __init__(self, firmware: FirmwareHost):
        self.fw = firmware
        self.loop = firmware.desc.loop

    def owner(self, addr: ObjectAddress) -> str | None:
        """The parameter the object ``addr`` holds; None when it is no loop object."""
        return self.loop.owner(addr) if self.loop is not None else None

    def read(self, name: str, addr: ObjectAddress):
        """What the object of parameter ``name`` answers: the running tuning, in the object's unit."""
        assert self.loop is not None
        shown = self.loop.to_device(self.fw.drive.tuning.cascade_values())
        stored = self.loop.parameters[name].stored(float(shown[name]))
        var = self.fw.od.get_variable(addr.index, addr.subindex)
        return stored if var is not None and var.data_type in _REAL_TYPES else int(round(stored))

    def write(self, name: str, value) -> None:
        """The host wrote parameter ``name``: the running loop takes it, or the write is refused."""
        assert self.loop is not None
        if name not in WRITABLE:
            raise SdoAbortedError(_ABORT_READ_ONLY)
        written = {name: self.loop.parameters[name].physical(value)}
        try:
            self.fw.drive.retune(**self.loop.to_cascade(written, self.fw.drive.tuning.cascade_values))
        except ConfigError:
            raise SdoAbortedError(ABORT_VALUE) from None
