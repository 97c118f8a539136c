"""The ``[loop]`` table of a Modbus drive: each cascade parameter it holds in a register of its map.

A Modbus drive keeps its gains in registers of ``[modbus.registers]``
(``kv_nm_per_mps = { register = "velocity_gain" }``); the register's own
type, scale and offset say how the value is stored, so a gain kept in 0.1 Hz
steps or an integral time kept in 0.01 ms steps is that register's ``scale``.
A parameter the drive does not show is a fixed ``value``
(:mod:`hilident.protocol.loop_parameters`). The host adapter and the twin both
convert through :func:`stored_value`, so what the host predicts a write leaves
in the drive is what the drive holds.

All pure: tables in, values out.
"""

from __future__ import annotations

from hilident.errors import ConfigError
from hilident.protocol.loop_parameters import WRITABLE, LoopDescription, parse_loop
from hilident.protocol.modbus.registers import Register

__all__ = ["parse_loop_registers", "stored_value"]


def parse_loop_registers(table, registers: dict[str, Register], source: str = "") -> LoopDescription | None:
    """The ``[loop]`` table of a Modbus driver, each register it names checked against the map.

    Parameters
    ----------
    table : dict or None
        The ``[loop]`` table (None: the driver describes no loop).
    registers : dict
        ``[modbus.registers]``: name -> :class:`~hilident.protocol.modbus.registers.Register`.
    source : str
        The driver file, for messages.

    Raises
    ------
    ConfigError
        The table is malformed (:func:`~hilident.protocol.loop_parameters.parse_loop`), or a register it
        names is not in the map, holds text, or is not a read-write holding register while it keeps a
        parameter the host writes (:data:`~hilident.protocol.loop_parameters.WRITABLE`); the message names
        ``loop.<parameter>.register`` and ``source``.
    """
    loop = parse_loop(table, source, kinds=("register",))
    if loop is None:
        return None
    for name, parameter in loop.held.items():
        key = f"loop.{name}.register"
        register = registers.get(parameter.register or "")
        if register is None:
            raise ConfigError(key, f"{parameter.register!r} is no register of [modbus.registers]", source or None)
        if register.type == "str":
            raise ConfigError(key, f"register {register.label} holds text; {name} needs a numeric type", source or None)
        if name in WRITABLE and not register.writable:
            raise ConfigError(
                key,
                f'register {register.label} must be a holding register with access = "rw": the host writes {name}',
                source or None,
            )
    return loop


def stored_value(register: Register, value: float) -> float:
    """What ``register`` holds for the physical ``value``, physical units: a float register keeps its
    precision (float32 for ``f32``), an integer one the nearest whole step of its ``scale``.

    Raises
    ------
    DataError
        ``value`` does not fit the register (beyond its type or its ``min``/``max``, or not finite in an
        integer register); the message names the register.
    """
    return float(register.decode(register.encode(float(value))))
