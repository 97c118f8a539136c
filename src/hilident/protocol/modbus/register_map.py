"""The register map of a Modbus drive: what the host adapter and the emulated drive both read the wire by.

A :class:`RegisterMap` is built from a driver description's ``[modbus]``
tables (:mod:`~hilident.protocol.modbus.map_parser`) and converts between
physical values and 16-bit registers: single registers by name
(:mod:`~hilident.protocol.modbus.registers`), the excitation table and capture
records through their paged windows (:mod:`~hilident.protocol.modbus.paging`),
and filter slots (:mod:`~hilident.protocol.modbus.filter_slots`). The host
adapter and the emulated drive both use it, so they agree on the wire by
construction.

All pure: values in, values out.

Examples
--------
>>> from hilident.drivers.description import find_driver
>>> regmap = RegisterMap.from_driver(find_driver("modbus-servo"))
>>> regmap.excitation, regmap.decode("mode", regmap.encode("mode", 2))
(True, 2)
"""

from __future__ import annotations

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.loop_parameters import LoopDescription
from hilident.protocol.modbus.codecs import TYPES, decode_values, encode_values
from hilident.protocol.modbus.filter_slots import FieldSlots, FourRegisterSlots
from hilident.protocol.modbus.map_parser import parse_map_tables
from hilident.protocol.modbus.paging import STAMP_MODULUS, CaptureChannel, Window
from hilident.protocol.modbus.registers import ParameterRule, Register

__all__ = ["RegisterMap"]


class RegisterMap:
    """A parsed Modbus register map (see the module docstring and ``drivers/modbus-servo/README.md``).

    Build it with :meth:`from_driver` or :meth:`parse`. Its ``loop`` is the driver's ``[loop]``
    (:class:`~hilident.protocol.loop_parameters.LoopDescription`; None when the driver describes no loop).
    """

    def __init__(
        self,
        *,
        map_version: int,
        device_type: int,
        word_order: str,
        max_read: int,
        max_write: int,
        registers: dict[str, Register],
        control: dict[str, int],
        status: dict[str, int],
        fault_codes: dict[str, int],
        modes: dict[str, int],
        table: Window | None,
        table_type: str,
        table_scale: float,
        capture: Window | None,
        capture_channels: tuple[CaptureChannel, ...],
        filters: FourRegisterSlots | FieldSlots | None,
        filter_encoding: FilterEncoding | None,
        byte_order: str = "big",
        rule: ParameterRule | None = None,
        identity: tuple[str, ...] = (),
        expect: dict | None = None,
        save: tuple[str, float] | None = None,
        stop: dict | None = None,
        loop: LoopDescription | None = None,
    ):
        self.loop = loop
        self.byte_order = byte_order
        self.rule = rule
        self.identity = identity
        self.expect = dict(expect or {})
        self.save = save
        self.stop = dict(stop or {})
        self.map_version = map_version
        self.device_type = device_type
        self.word_order = word_order
        self.max_read = max_read
        self.max_write = max_write
        self.registers = registers
        self.control = control
        self.status = status
        self.fault_codes = fault_codes
        self.modes = modes
        self.table = table
        self.table_type = table_type
        self.table_scale = table_scale
        self.capture = capture
        self.capture_channels = capture_channels
        self.filters = filters
        self.filter_encoding = filter_encoding

    # --- parsing -----------------------------------------------------------------------

    @classmethod
    def from_driver(cls, driver) -> RegisterMap:
        """The map of a :class:`~hilident.drivers.description.DriverDescription` (its ``sections``)."""
        return cls.parse(driver.sections, driver.filter_slots, str(driver.folder / "driver.toml"))

    @classmethod
    def parse(cls, sections: dict, filter_slots: int, source: str = "") -> RegisterMap:
        """The map the ``[modbus]`` tables of a parsed driver description give, validated
        (:func:`~hilident.protocol.modbus.map_parser.parse_map_tables`).

        Raises
        ------
        ConfigError
            A table or key is missing, has the wrong type, or registers overlap;
            the message names the dotted key and ``source``.
        """
        tables = parse_map_tables(sections, filter_slots, source)
        protocol = tables.protocol
        return cls(
            map_version=tables.map_version,
            device_type=tables.device_type,
            word_order=tables.word_order,
            max_read=tables.max_read,
            max_write=tables.max_write,
            registers=tables.registers,
            control=protocol.control,
            status=protocol.status,
            fault_codes=protocol.fault_codes,
            modes=protocol.modes,
            table=protocol.table,
            table_type=protocol.table_type,
            table_scale=protocol.table_scale,
            capture=protocol.capture,
            capture_channels=protocol.capture_channels,
            filters=tables.filters,
            filter_encoding=tables.filter_encoding,
            byte_order=tables.byte_order,
            rule=tables.rule,
            identity=tables.identity,
            expect=tables.expect,
            save=tables.save,
            stop=tables.stop,
            loop=tables.loop,
        )

    @property
    def excitation(self) -> bool:
        """Whether the drive offers hilident's excitation-table and capture capability."""
        return self.table is not None

    def parameter(self, code: str) -> Register:
        """The register of vendor parameter ``code`` (``"P08.02"``): the map's own entry, else a ``u16``
        holding register at the rule's address.

        Raises
        ------
        DataError
            The map has no parameter rule, or ``code`` is not a parameter code.
        """
        for r in self.registers.values():
            if r.parameter == code or r.name == code:
                return r
        if self.rule is None:
            raise DataError(f"the map has no [modbus.parameters] rule to find parameter {code!r}")
        return Register(code, self.rule.address_of(code), "u16", "rw", parameter=code)

    def loop_registers(self) -> dict[str, Register]:
        """The registers that hold the drive's cascade parameters: parameter -> register (empty without
        ``[loop]``; a parameter the description fixes as a value has none)."""
        if self.loop is None:
            return {}
        return {n: self.registers[p.register] for n, p in self.loop.parameters.items() if p.register is not None}

    # --- single registers ----------------------------------------------------------------

    def register(self, name: str) -> Register:
        return self.registers[name]

    def encode(self, name: str, value) -> list[int]:
        """Registers holding ``value`` in register ``name`` (DataError naming the register when it does not fit
        or lies outside the register's range)."""
        return self.registers[name].encode(value)

    def decode(self, name: str, registers) -> float | int | str:
        """The value ``registers`` hold in register ``name`` (ints for unscaled integer types)."""
        return self.registers[name].decode(registers)

    def span(self, *names: str) -> tuple[int, int]:
        """``(address, count)`` of one request covering registers ``names``."""
        regs = [self.registers[n] for n in names]
        first = min(r.address for r in regs)
        return first, max(r.end for r in regs) - first

    def read_groups(self, names) -> list[tuple[int, int]]:
        """``(address, count)`` read requests covering registers ``names``.

        Neighbouring registers without a gap between them share a request (a
        drive answers a read across a gap with exception 2); each request holds
        at most ``max_read`` registers.
        """
        return [(a, n) for _, a, n in self.request_groups(names)]

    def request_groups(self, names) -> list[tuple[str, int, int]]:
        """``(table, address, count)`` read requests covering registers ``names``: as :meth:`read_groups`,
        holding and input registers apart."""
        regs = sorted((self.registers[n] for n in names), key=lambda r: (r.table, r.address))
        groups: list[list] = []
        for r in regs:
            if (
                groups
                and r.table == groups[-1][0]
                and r.address == groups[-1][2]
                and r.end - groups[-1][1] <= self.max_read
            ):
                groups[-1][2] = r.end
            else:
                groups.append([r.table, r.address, r.end])
        return [(t, a, b - a) for t, a, b in groups]

    def decode_span(self, names, address: int, registers) -> dict:
        """Values of ``names`` from ``registers`` read starting at ``address``."""
        out = {}
        for n in names:
            r = self.registers[n]
            out[n] = self.decode(n, registers[r.address - address : r.end - address])
        return out

    def describe(self, address: int, count: int = 1, page: int | None = None, table: str = "holding") -> str:
        """Human-readable name of registers ``address .. address + count - 1`` (for messages)."""
        last = address + max(count, 1) - 1
        fmt = "#06x" if self.rule is not None else "d"
        where = f"register {address:{fmt}}" if last == address else f"registers {address:{fmt}}..{last:{fmt}}"
        names = [
            r.label
            for r in sorted(self.registers.values(), key=lambda r: r.address)
            if r.address <= last and r.end > address and r.table == table
        ]
        if table == "holding":
            names += self._holding_names(address, last, page, bool(names))
        if table == "input":
            where = "input " + where
        return f"{where} ({', '.join(names) or 'not in the driver map'})"

    def _holding_names(self, address: int, last: int, page: int | None, named: bool) -> list[str]:
        """What else holding registers ``address..last`` are: windows, filter slots, else a parameter code."""
        names = [
            label + (f", page {page}" if page is not None else "")
            for w, label in ((self.table, "excitation table window"), (self.capture, "capture window"))
            if w is not None and w.base <= last and w.end > address
        ]
        if self.filters is not None:
            slots = sorted({s for a in range(address, last + 1) if (s := self.filters.slot_at(a)) is not None})
            names += [f"filter slot {s}" for s in slots]
        if not names and not named and self.rule is not None and (code := self.rule.code(address)):
            names.append(f"parameter {code}")
        return names

    # --- codes and bits --------------------------------------------------------------------

    def status_flags(self, word: int) -> frozenset[str]:
        """Names of the bits set in a status word."""
        return frozenset(n for n, bit in self.status.items() if word & bit)

    def fault_name(self, code: int) -> str:
        for name, value in self.fault_codes.items():
            if value == code:
                return name
        return f"fault {code}"

    # --- excitation table ------------------------------------------------------------------

    @property
    def table_registers_per_sample(self) -> int:
        return TYPES[self.table_type][0]

    def encode_table(self, values) -> np.ndarray:
        """Registers of the excitation table (DataError when a value does not fit)."""
        return encode_values(values, self.table_type, self.table_scale, self.word_order)

    def decode_table(self, registers) -> np.ndarray:
        return decode_values(registers, self.table_type, self.table_scale, self.word_order)

    # --- capture records ----------------------------------------------------------------------

    def capture_channel_names(self) -> list[str]:
        return [c.name for c in self.capture_channels]

    def mask_of(self, names) -> int:
        """``capture_mask`` selecting channels ``names`` (ConfigError naming an unknown one)."""
        known = {c.name: c for c in self.capture_channels}
        mask = 0
        for n in names:
            if n not in known:
                raise ConfigError("run.channels", f"the drive captures no channel {n!r} (it has: {', '.join(known)})")
            mask |= 1 << known[n].bit
        return mask

    def selected(self, mask: int) -> tuple[CaptureChannel, ...]:
        """Channels selected by ``mask``, in record order."""
        return tuple(c for c in self.capture_channels if mask >> c.bit & 1)

    def record_registers(self, mask: int) -> int:
        """Registers per capture record: the stamp plus the selected channels."""
        return 1 + sum(c.count for c in self.selected(mask))

    def encode_records(self, stamps, rows, mask: int) -> np.ndarray:
        """Registers of capture records (integer channels saturate, as a drive's would).

        Parameters
        ----------
        stamps : array_like of int, shape (n,)
        rows : array_like, shape (n, channels selected by ``mask``)
        """
        chans = self.selected(mask)
        stamps = np.asarray(stamps, dtype=np.int64) % STAMP_MODULUS
        rows = np.asarray(rows, dtype=float).reshape(len(stamps), len(chans))
        columns = [stamps.astype(np.uint16).reshape(-1, 1)]
        for j, c in enumerate(chans):
            regs = encode_values(rows[:, j], c.type, c.scale, self.word_order, saturate=True)
            columns.append(regs.reshape(len(stamps), c.count))
        return np.hstack(columns).ravel()

    def decode_records(self, registers, mask: int) -> tuple[np.ndarray, np.ndarray]:
        """``(stamps, rows)`` of whole capture records read back.

        Raises
        ------
        DataError
            The registers do not hold whole records.
        """
        chans = self.selected(mask)
        width = self.record_registers(mask)
        r = np.asarray(registers, dtype=np.int64)
        if len(r) % width:
            raise DataError(f"{len(r)} registers are not whole capture records of {width}")
        r = r.reshape(-1, width)
        rows = np.empty((len(r), len(chans)))
        col = 1
        for j, c in enumerate(chans):
            rows[:, j] = decode_values(r[:, col : col + c.count], c.type, c.scale, self.word_order)
            col += c.count
        return r[:, 0].copy(), rows

    # --- filter slots ---------------------------------------------------------------------

    def _four_register_slots(self) -> FourRegisterSlots:
        """The map's filter slots when they are hilident's four-register slots (DataError otherwise)."""
        if not isinstance(self.filters, FourRegisterSlots):
            held = "no filter slots" if self.filters is None else "filter slots of named registers"
            raise DataError(f"the map has {held}, not hilident's four-register slots ([modbus.filters] base)")
        return self.filters

    def encode_filter(self, values: dict, enabled: bool) -> list[int]:
        """The four registers of a filter slot, in address order."""
        slots = self._four_register_slots()
        fields = {**{k: int(values[k]) for k in ("center", "width", "depth")}, "enable": int(bool(enabled))}
        for k, v in fields.items():
            if not 0 <= v <= 0xFFFF:
                raise DataError(f"filter field {k} = {v} does not fit a 16-bit register")
        out = [0] * slots.span
        for k, v in fields.items():
            out[slots.offsets[k]] = v
        return out

    def decode_filter(self, registers) -> tuple[dict, bool]:
        """``({center, width, depth}, enabled)`` from a slot's four registers."""
        offsets = self._four_register_slots().offsets
        regs = [int(x) for x in registers]
        values = {k: regs[offsets[k]] for k in ("center", "width", "depth")}
        return values, bool(regs[offsets["enable"]])
