"""The emulated board's cascade in its LOOP and WRITE_LOOP messages (PROTOCOL.md sections 4.15 and 4.16).

The drive loop (:class:`~hilident.emulator.drive.DriveLoop`) runs with its
:class:`~hilident.emulator.drive.DriveTuning`; LOOP is that tuning as it runs,
and an accepted WRITE_LOOP retunes it, all four gains at once. A gain the loop
cannot run (a NaN, a gain that is not > 0, an integral time that is not > 0, a
cut-off that is not finite) is refused whole, and the loop keeps its gains.
The current loop and the delay are the board's: LOOP reports them, no message
writes them.
"""

from __future__ import annotations

import math

from hilident.emulator.drive import DriveTuning
from hilident.protocol import serial_board as sb

__all__ = ["loop_parameters", "loop_refusal"]


def loop_parameters(tuning: DriveTuning) -> sb.LoopParameters:
    """LOOP: the six parameters of the cascade ``tuning`` runs, SI units."""
    return sb.LoopParameters(**{name: float(getattr(tuning, name)) for name in sb.LOOP_FIELDS})


def loop_refusal(msg: sb.WriteLoop) -> str | None:
    """Why the loop cannot run the gains of ``msg`` (the NAK's detail); None when it can."""
    for name in sb.WRITE_LOOP_FIELDS:
        value = float(getattr(msg, name))
        may_be_infinite = name == "ti_s"  # an infinite integral time is a P controller
        if not (value > 0.0 and (may_be_infinite or math.isfinite(value))):
            return f"{name} = {value!r} must be {'' if may_be_infinite else 'finite and '}> 0"
    return None
