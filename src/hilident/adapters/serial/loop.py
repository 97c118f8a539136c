"""The board's cascade on the host side: what its LOOP answer means and what WRITE_LOOP stores.

The board carries its loop in one message (PROTOCOL.md sections 4.15 and 4.16):
LOOP reports all six parameters as binary32 in SI units, WRITE_LOOP sets the
four gains at once. The driver's ``[loop]`` says, per parameter, whether the
board's LOOP holds it (``{ message = "LOOP" }``) or the description fixes it
(``{ value = ... }``, which wins over what the board reports).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from hilident.errors import UsageError
from hilident.protocol import serial_board as sb
from hilident.protocol.loop_parameters import LoopDescription

__all__ = ["described_values", "held_in_loop", "stored_gains", "write_message"]


def held_in_loop(loop: LoopDescription | None, name: str, port: str) -> None:
    """UsageError naming ``port`` unless ``[loop]`` keeps ``name`` in the board's LOOP message."""
    param = loop.parameters.get(name) if loop is not None else None
    if param is None or param.message is None:
        raise UsageError(
            f"{port}: {name} is not held in the board's LOOP message ([loop] of the driver gives "
            + ("no [loop]" if loop is None else "it as a fixed value")
            + ")"
        )


def described_values(loop: LoopDescription, board: Mapping[str, float]) -> dict[str, float]:
    """The six parameters, SI units: LOOP's values (``board``), a fixed value of ``[loop]`` replacing the board's."""
    return {name: float(board[name]) if p.held else float(p.value or 0.0) for name, p in loop.parameters.items()}


def stored_gains(values: Mapping[str, float], port: str) -> dict[str, float]:
    """``values`` as the board stores them: rounded to binary32 (its field's type).

    Raises
    ------
    UsageError
        A finite value beyond binary32's range (it would arrive as infinity).
    """
    out = {}
    for name, value in values.items():
        with np.errstate(over="ignore"):  # too large for binary32: refused below
            stored = sb.float32(value)
        if math.isfinite(value) and not math.isfinite(stored):
            raise UsageError(f"{port}: {name} = {value} does not fit the binary32 field of WRITE_LOOP")
        out[name] = stored
    return out


def write_message(present: Mapping[str, float], gains: Mapping[str, float]) -> sb.WriteLoop:
    """WRITE_LOOP of ``gains``, every gain it leaves out as the board reported it (``present``)."""
    return sb.WriteLoop(**{name: float(gains.get(name, present[name])) for name in sb.WRITE_LOOP_FIELDS})
