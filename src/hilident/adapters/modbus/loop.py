"""The drive's cascade parameters in its registers: read, written, and what the drive will hold.

:class:`ModbusLoop` is a part :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` owns (its ``cascade``);
its requests go through the request part (:class:`~hilident.adapters.modbus.requests.RegisterAccess`). The
driver's ``[loop]`` says which register holds each parameter
(:mod:`hilident.protocol.modbus.loop_registers`); a parameter it fixes as a value is reported as given and
never written.
"""

from __future__ import annotations

from hilident.adapters.modbus.requests import RegisterAccess
from hilident.errors import DataError, UsageError
from hilident.protocol.modbus.loop_registers import stored_value
from hilident.protocol.modbus.registers import Register

__all__ = ["ModbusLoop"]


class ModbusLoop:
    """The cascade parameters of a Modbus drive (the ``cascade`` of
    :class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter`).

    Parameters
    ----------
    registers : RegisterAccess
        The requests (and the map, port and driver they name).
    """

    def __init__(self, registers: RegisterAccess):
        self.registers = registers
        self.map = registers.map
        self.port = registers.port

    def read(self) -> dict[str, float] | None:
        """The six parameters in SI units: the registers read (neighbours in one request), the fixed values as
        the driver gives them; None when the driver has no ``[loop]``.

        Raises
        ------
        DeviceError
            A register cannot be read; the message names the port and the register.
        """
        loop = self.map.loop
        if loop is None:
            return None
        held = self.map.loop_registers()
        values = self.registers.read_names(*(r.name for r in held.values())) if held else {}
        fixed = loop.fixed()
        return {n: float(values[held[n].name]) if n in held else fixed[n] for n in loop.parameters}

    def write(self, values: dict[str, float]) -> None:
        """Each parameter of ``values`` (SI units) into its register, neighbours in one request.

        Raises
        ------
        UsageError
            The driver fixes a parameter as a value (or describes no loop): there is no register to write.
        DeviceError
            A value does not fit its register, or the drive refuses it (exception 3: a value its loop cannot
            run); the message names the port and the register (name and address).
        """
        regs = {n: self._register(n) for n in values}
        self.registers.write_names(**{regs[n].name: float(v) for n, v in values.items()})

    def stored(self, values: dict[str, float]) -> dict[str, float]:
        """``values`` as the registers will hold them, SI units: float32 for an ``f32`` register, the nearest
        whole step of its scale for an integer one (what :meth:`read` reads back after :meth:`write`).

        Raises
        ------
        UsageError
            The driver fixes a parameter as a value, or a value cannot be held by its register.
        """
        out = {}
        for name, value in values.items():
            r = self._register(name)
            try:
                out[name] = stored_value(r, value)
            except DataError as exc:
                raise UsageError(f"{self.port}: {name} = {value!r} cannot be held: {exc}") from None
        return out

    def _register(self, name: str) -> Register:
        """The register of parameter ``name``; UsageError when the driver keeps it as a fixed value."""
        loop = self.map.loop
        register = self.map.loop_registers().get(name)
        if register is None:
            how = "gives no [loop]" if loop is None else "fixes it as a value in [loop]"
            raise UsageError(f"{self.port}: {name} is in no register of the drive (the driver {how})")
        return register
