"""The SI unit of each recorded channel, where it depends on how the run was made (pure: no I/O).

A device's driver description gives every channel a fixed unit, but the
``excitation`` column holds the set-point the excitation was played into,
so its unit is the unit of the run's mode: N·m for ``torque`` and
``torque_injection``, m/s for ``velocity`` (and the friction test's legs),
m for ``position``. Adapters report it so in ``channel_units``; recordings
made before they did store ``"1"``, which :func:`recorded_units` reads as the
mode's unit.

Examples
--------
>>> excitation_unit("velocity")
'm/s'
>>> units_in_mode(["excitation", "torque_nm"], ["1", "N*m"], "torque_injection")
['N*m', 'N*m']
>>> display_unit("N*m/(m/s)")
'N·m/(m/s)'
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "DIMENSIONLESS",
    "EXCITATION_CHANNEL",
    "EXCITATION_UNIT_OF_MODE",
    "display_unit",
    "excitation_unit",
    "recorded_units",
    "units_in_mode",
]

#: The channel that holds the set-point the excitation was played into.
EXCITATION_CHANNEL = "excitation"

#: Unit of the excitation set-point in each hilident mode.
EXCITATION_UNIT_OF_MODE = {"torque": "N*m", "torque_injection": "N*m", "velocity": "m/s", "position": "m"}

#: What a channel without a physical unit was stored with (a count, or an excitation before units were honest).
DIMENSIONLESS = "1"


def excitation_unit(mode: str) -> str | None:
    """The unit of the excitation set-point in ``mode``, or None for a mode hilident does not know."""
    return EXCITATION_UNIT_OF_MODE.get(mode)


def units_in_mode(names: Sequence[str], units: Sequence[str], mode: str) -> list[str]:
    """``units`` (one per channel of ``names``) with the excitation's replaced by the unit of ``mode``.

    Parameters
    ----------
    names : sequence of str
        Channel names, in column order.
    units : sequence of str
        The driver's unit of each channel, same order.
    mode : str
        The run's mode (``torque``, ``torque_injection``, ``velocity``, ``position``).

    Returns
    -------
    list of str
        One unit per channel; unchanged where the channel is not the excitation or the mode is unknown.
    """
    unit = excitation_unit(mode)
    return [unit if name == EXCITATION_CHANNEL and unit else u for name, u in zip(names, units, strict=True)]


def recorded_units(units: Mapping[str, str], attrs: Mapping[str, Any]) -> dict[str, str]:
    """The units of a recording's channels, with an older recording's excitation ``"1"`` read as its mode's unit.

    Parameters
    ----------
    units : mapping of str to str
        Channel name to the unit stored in the file (:attr:`hilident.io.recording.RunData.units`).
    attrs : mapping
        The recording's root attributes; ``mode`` says what the excitation was played into.

    Returns
    -------
    dict of str to str
        Channel name to unit.
    """
    out = dict(units)
    unit = excitation_unit(str(attrs.get("mode", "")))
    if unit and out.get(EXCITATION_CHANNEL) in (DIMENSIONLESS, ""):
        out[EXCITATION_CHANNEL] = unit
    return out


def display_unit(unit: str) -> str:
    """``unit`` as a plot label shows it: ``N*m`` as ``N·m``."""
    return unit.replace("*", "·")
