"""The small values every CANopen module of hilident shares: an object's address, and how a mode runs.

:class:`ObjectAddress` (index and sub-index of an object dictionary entry) and
its text form (:func:`parse_address`), and :class:`ModeSpec` (the CiA 402 mode
of operation and set-point object serving one hilident mode). The modules
that describe a drive build on them: :mod:`~hilident.protocol.canopen_profile`
(the standard objects and modes), :mod:`~hilident.protocol.canopen_recorder`
(a drive's generator and recorder) and :mod:`~hilident.protocol.canopen_objects`
(the ``[canopen]`` tables of a driver description). This module imports none
of them.

All pure: text in, frozen dataclasses out.

Examples
--------
>>> parse_address("0x607D:2")
ObjectAddress(index=24701, subindex=2)
>>> str(ObjectAddress(0x6064))
'0x6064:0'
"""

from __future__ import annotations

from dataclasses import dataclass

from hilident.errors import ConfigError

__all__ = ["ModeSpec", "ObjectAddress", "parse_address"]


@dataclass(frozen=True, order=True)
class ObjectAddress:
    """Index and sub-index of one object dictionary entry."""

    index: int
    subindex: int = 0

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex}"


def parse_address(text, key: str = "", source: str = "") -> ObjectAddress:
    """``"0x6064"`` or ``"0x607D:2"`` (hex index, decimal or hex sub-index) -> ObjectAddress.

    Raises
    ------
    ConfigError
        The text is not an address; the message names ``key``.
    """
    if isinstance(text, ObjectAddress):
        return text
    if not isinstance(text, str):
        raise ConfigError(
            key or "address", f'must be an object address like "0x6064" or "0x607D:2", got {text!r}', source
        )
    try:
        head, _, tail = str(text).strip().partition(":")
        index = int(head, 16)
        sub = int(tail, 0) if tail else 0
    except ValueError:
        raise ConfigError(
            key or "address", f'must be an object address like "0x6064" or "0x607D:2", got {text!r}', source
        ) from None
    if not (0 <= index <= 0xFFFF and 0 <= sub <= 0xFF):
        raise ConfigError(key or "address", f"index or sub-index out of range in {text!r}", source)
    return ObjectAddress(index, sub)


@dataclass(frozen=True)
class ModeSpec:
    """How one hilident mode runs on the drive.

    Attributes
    ----------
    name : str
        hilident mode (``"torque"``, ``"torque_injection"``, ``"velocity"``, ``"position"``).
    code : int
        Mode of operation written to 0x6060 (CST 10, CSV 9, CSP 8; negative: manufacturer mode).
    setpoint : str
        Role of the object the excitation is written to each cycle.
    hold : str
        Role of the set-point that holds the axis while the excitation goes to
        ``setpoint`` (a torque offset injected in CSP or CSV: "target_position",
        written with the present position, or "target_velocity", written 0);
        empty when nothing needs holding.
    """

    name: str
    code: int
    setpoint: str
    hold: str = ""
