"""The emulated Modbus drive's cascade parameters: the registers of its ``[loop]`` table.

The drive loop (:class:`~hilident.emulator.drive.DriveLoop`) runs with its
:class:`~hilident.emulator.drive.DriveTuning`; these registers are that tuning,
read as it is (in each register's type and scale) and written into it. A write
of a tunable parameter (:data:`~hilident.protocol.loop_parameters.TUNABLE`)
retunes the running loop at once, as a drive takes a new parameter. The current
loop and the delay are the power stage's and the firmware's: a write of either
is answered with exception 2, as a read-only register's is. A value the loop
cannot run (a gain that is not positive, a zero integral time, NaN) is answered
with exception 3 and the loop keeps its gains.

The firmwares call :meth:`LoopRegisters.show` before a read or a write touches
the registers, check a write with :meth:`LoopRegisters.refusal` and carry it out
with :meth:`LoopRegisters.take`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from hilident.emulator.drive import DriveLoop
from hilident.errors import ConfigError, DataError
from hilident.protocol.loop_parameters import TUNABLE
from hilident.protocol.modbus.register_map import RegisterMap

__all__ = ["LoopRegisters"]

ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3


class LoopRegisters:
    """Reads and writes of the registers that hold the drive's cascade parameters.

    Parameters
    ----------
    drive : DriveLoop
        The loop whose tuning the registers show.
    regmap : RegisterMap
        The drive's map (its ``loop``; without one there are no loop registers).
    source : str
        The driver file, for messages.

    Raises
    ------
    ConfigError
        A gain the twin starts with (``[emulator.drive]``) does not fit the register that holds it
        (an infinite integral time in an integer register, say); the message names the key and the register.
    """

    def __init__(self, drive: DriveLoop, regmap: RegisterMap, source: str = ""):
        self.drive = drive
        self.by_parameter = regmap.loop_registers()
        self._parameter_of = {r.name: n for n, r in self.by_parameter.items()}
        for name, r in self.by_parameter.items():
            try:
                r.encode(getattr(drive.tuning, name))
            except DataError as exc:
                where = f"register {r.label} of {source or 'the driver'}"
                raise ConfigError(f"emulator.drive.{name}", f"cannot be shown in {where}: {exc}") from None

    def __contains__(self, register: str) -> bool:
        return register in self._parameter_of

    def show(self, image: np.ndarray, first: int, end: int, table: str = "holding") -> None:
        """Put the running tuning into the loop registers of ``table`` that overlap ``first .. end - 1``."""
        tuning = self.drive.tuning
        for name, r in self.by_parameter.items():
            if r.table == table and r.address < end and r.end > first:
                image[r.address : r.end] = r.encode(getattr(tuning, name))

    def refusal(self, written: dict[str, float]) -> int | None:
        """The exception code that refuses the loop registers ``written`` (register -> physical value, as the
        write leaves them); None when the loop can run them."""
        if any(self._parameter_of[n] not in TUNABLE for n in written):
            return ILLEGAL_ADDRESS
        try:
            replace(self.drive.tuning, **self._gains(written))  # what DriveTuning accepts, nothing changed yet
        except ConfigError:
            return ILLEGAL_VALUE
        return None

    def take(self, written: dict[str, float]) -> None:
        """Retune the running loop with the loop registers ``written`` (checked by :meth:`refusal`)."""
        if written:
            self.drive.retune(**self._gains(written))

    def _gains(self, written: dict[str, float]) -> dict[str, Any]:
        return {self._parameter_of[n]: float(v) for n, v in written.items()}
