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
from hilident.protocol.loop_parameters import ALTERNATIVES, WRITABLE
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
        self.loop = regmap.loop
        self.by_parameter = regmap.loop_registers()
        self._parameter_of = {r.name: n for n, r in self.by_parameter.items()}
        shown = self._shown()
        for name, r in self.by_parameter.items():
            try:
                r.encode(shown[name])
            except DataError as exc:
                where = f"register {r.label} of {source or 'the driver'}"
                key = ALTERNATIVES.get(name, (name,))[0]  # the twin's tuning is in the cascade's form
                raise ConfigError(f"emulator.drive.{key}", f"cannot be shown in {where} as {name}: {exc}") from None

    def __contains__(self, register: str) -> bool:
        return register in self._parameter_of

    def show(self, image: np.ndarray, first: int, end: int, table: str = "holding") -> None:
        """Put the running tuning into the loop registers of ``table`` that overlap ``first .. end - 1``."""
        shown = self._shown()
        for name, r in self.by_parameter.items():
            if r.table == table and r.address < end and r.end > first:
                image[r.address : r.end] = r.encode(shown[name])

    def refusal(self, written: dict[str, float]) -> int | None:
        """The exception code that refuses the loop registers ``written`` (register -> physical value, as the
        write leaves them); None when the loop can run them."""
        if any(self._parameter_of[n] not in WRITABLE for n in written):
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

    def _shown(self) -> dict[str, float]:
        """The running tuning in the drive's form (its integral as a gain where ``[loop]`` keeps it so)."""
        values = self.drive.tuning.cascade_values()
        return values if self.loop is None else self.loop.to_device(values)

    def _gains(self, written: dict[str, float]) -> dict[str, Any]:
        """The registers ``written`` (register -> physical value) as cascade settings for the running tuning."""
        values = {self._parameter_of[n]: float(v) for n, v in written.items()}
        return values if self.loop is None else self.loop.to_cascade(values, self.drive.tuning.cascade_values)
