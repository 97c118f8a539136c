"""Register logic of an emulated parameter drive: a Modbus drive described by its parameter list.

A real servo drive with a Modbus interface is a list of parameters (``PXX.YY``
at ``group * 0x100 + index`` on the DSY-RS): identification, commands,
feedback, filter parameters and a save-to-EEPROM parameter, and no excitation
table. :class:`ParameterDriveFirmware` is such a drive minus the clock and the
wire, built from the driver's register map
(:class:`~hilident.protocol.modbus.register_map.RegisterMap` without the
excitation capability) around the same
:class:`~hilident.emulator.drive.DriveLoop` as every other twin:

* every register of the map holds its ``default`` at power-up;
* a read or write of an address the map does not declare, a write of a
  read-only or input register, or a write of part of a multi-register value
  is answered with exception 2; a value outside the register's ``min``/``max``
  with exception 3 (nothing of the request is written);
* the filter slots' parameters feed the drive's biquad chain through the
  drive's notch equation (the map's filter encoding at the loop rate): a slot
  whose ``off`` field holds its off value is bypassed; parameters that make no
  notch leave the slot bypassed, as a drive ignores a setting it cannot run;
* registers with a ``channel`` show the drive's latest state (speed, torque,
  position), converted by ``channel_scale``;
* the ``[loop]`` registers show the running loop's gains, and a write of a gain
  retunes it (:class:`~hilident.emulator.modbus.loop.LoopRegisters`: a value
  the loop cannot run is answered with exception 3);
* writing the ``[modbus.save]`` value stores every holding register in
  :attr:`ParameterDriveFirmware.eeprom` and the save register reads 0 again,
  as a drive acknowledges a completed store.

The axis is never moved by this twin: with no excitation capability hilident
runs no experiment on it, and the drive stays disabled (it coasts when idle).

Same contract as :class:`~hilident.emulator.modbus.firmware.ModbusDriveFirmware`
for a server: ``read``, ``write``, ``functions``, ``advance``, ``idle``,
``heard_from_host``, ``watch_host``, ``excuse_silence``.
"""

from __future__ import annotations

import math

import numpy as np

from hilident.drivers.description import DriverDescription
from hilident.emulator.drive import DriveLoop
from hilident.emulator.modbus.loop import LoopRegisters
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.modbus.codecs import encode_values
from hilident.protocol.modbus.filter_slots import FieldSlots
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.registers import Register

ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3


class ParameterDriveFirmware:
    """The emulated parameter drive's registers around one :class:`~hilident.emulator.drive.DriveLoop`.

    Parameters
    ----------
    drive : DriveLoop
    regmap : RegisterMap
        A map without the excitation capability (``regmap.excitation`` false).
    driver : DriverDescription
        Loop rate and name.

    Attributes
    ----------
    eeprom : dict or None
        Register address to value of the last save (None before the first).
    saves : int
        Stores carried out since power-up.

    Not thread-safe: the server serialises calls.

    Raises
    ------
    ConfigError
        The map's filter slots are register blocks (``[modbus.filters]`` base
        and stride): this twin runs a parameter drive's slots as named
        parameters (``[[modbus.filters.slots]]``) only.
    """

    def __init__(self, drive: DriveLoop, regmap: RegisterMap, driver: DriverDescription):
        if regmap.excitation:
            raise ValueError("a map with the excitation capability is served by ModbusDriveFirmware")
        if regmap.filters is not None and not isinstance(regmap.filters, FieldSlots):
            raise ConfigError(
                "modbus.filters",
                "the twin of a drive without an excitation table runs filter slots "
                "of named parameters ([[modbus.filters.slots]]), not register blocks (base, stride)",
                str(driver.folder / "driver.toml"),
            )
        self.drive = drive
        self.map = regmap
        self.loop_rate_hz = float(driver.loop_rate_hz)
        self.max_sample_rate_hz = float(driver.max_sample_rate_hz)
        self._loop = LoopRegisters(drive, regmap, str(driver.folder / "driver.toml"))
        self.images = {"holding": np.zeros(65536, dtype=np.uint16), "input": np.zeros(65536, dtype=np.uint16)}
        self._owner: dict[str, dict[int, Register]] = {"holding": {}, "input": {}}
        for r in regmap.registers.values():
            for a in range(r.address, r.end):
                self._owner[r.table][a] = r
            if r.default is not None:
                self._store(r, r.default)
        self.eeprom: dict[int, int] | None = None
        self.saves = 0
        # the session-facing state a server's clock asks about: this drive never runs a table
        self.running = False
        self.runs = 0
        self.produced = 0
        self.sample_rate_hz = self.loop_rate_hz
        self.last_heard: float | None = None
        self._latest = self._state_now()
        for slot in range(self.slot_count):
            self._apply_slot(slot)

    # --- what the drive offers ---------------------------------------------------------

    @property
    def functions(self) -> frozenset[int]:
        """Modbus function codes the drive answers: 3, 6, 16, and 4 when the map declares input registers."""
        codes = {3, 6, 16}
        if self._owner["input"]:
            codes.add(4)
        return frozenset(codes)

    @property
    def slot_count(self) -> int:
        return self.map.filters.slots if self.map.filters is not None else 0

    # --- register image -----------------------------------------------------------------

    def _store(self, r: Register, value) -> None:
        self.images[r.table][r.address : r.end] = r.encode(value)

    def value(self, name: str):
        """The physical value register ``name`` holds now (for tests and the server)."""
        r = self.map.register(name)
        self._refresh(r.table, r.address, r.end)
        return r.decode(self.images[r.table][r.address : r.end])

    def _covered(self, table: str, address: int, count: int) -> bool:
        """Every address declared, and no register cut by the request's ends."""
        owner = self._owner[table]
        if any(a not in owner for a in range(address, address + count)):
            return False
        first, last = owner[address], owner[address + count - 1]
        return first.address >= address and last.end <= address + count

    def _state_now(self) -> dict[str, float]:
        d = self.drive
        return {"velocity_mps": 0.0, "torque_nm": 0.0, "torque_cmd_nm": 0.0, "position_m": d.hold_position_m}

    def _refresh(self, table: str, first: int, end: int) -> None:
        """Feedback and loop registers in ``first .. end - 1`` from the drive's latest state and tuning."""
        self._loop.show(self.images[table], first, end, table)
        for r in self.map.registers.values():
            if r.channel and r.table == table and r.address < end and r.end > first:
                x = self._latest.get(r.channel, 0.0) / r.channel_scale
                words = _saturated(r, x)
                self.images[table][r.address : r.end] = words

    # --- requests -------------------------------------------------------------------------

    def read(self, address: int, count: int, input_registers: bool = False) -> list[int] | int:
        """Registers ``address .. address + count - 1`` of the holding (or input) table, or an exception code."""
        table = "input" if input_registers else "holding"
        if count < 1 or not self._covered(table, address, count):
            return ILLEGAL_ADDRESS
        self._refresh(table, address, address + count)
        return self.images[table][address : address + count].tolist()

    def write(self, address: int, values) -> int | None:
        """Write holding registers from ``address``; returns an exception code when the drive refuses."""
        values = np.asarray(values, dtype=np.int64)
        count = len(values)
        if count < 1 or not self._covered("holding", address, count):
            return ILLEGAL_ADDRESS
        if np.any((values < 0) | (values > 0xFFFF)):
            return ILLEGAL_VALUE
        touched = sorted(
            {id(r): r for a in range(address, address + count) for r in [self._owner["holding"][a]]}.values(),
            key=lambda r: r.address,
        )
        if any(not r.writable for r in touched):
            return ILLEGAL_ADDRESS
        for r in touched:
            words = values[r.address - address : r.end - address]
            try:
                r.check_range(r.decode(words))
            except DataError:
                return ILLEGAL_VALUE
        written = {r.name: values[r.address - address : r.end - address] for r in touched if r.name in self._loop}
        loop = {name: float(self.map.decode(name, words)) for name, words in written.items()}
        if loop and (refused := self._loop.refusal(loop)) is not None:
            return refused
        self.images["holding"][address : address + count] = values.astype(np.uint16)
        self._loop.take(loop)
        for r in touched:
            self._apply(r)
        return None

    def _apply(self, r: Register) -> None:
        if (
            self.map.save is not None
            and r.name == self.map.save[0]
            and r.decode(self.images["holding"][r.address : r.end]) == self.map.save[1]
        ):
            self.eeprom = {a: int(v) for a, v in enumerate(self.images["holding"]) if a in self._owner["holding"]}
            self.saves += 1
            self._store(r, 0)
        filters = self.map.filters
        if isinstance(filters, FieldSlots):
            slot = filters.slot_at(r.address)
            if slot is not None:
                self._apply_slot(slot)

    def _filter_parameters(self) -> tuple[FieldSlots, FilterEncoding]:
        """The map's filter slots (named parameters) and the notch equation the drive applies to them.

        Raises
        ------
        ValueError
            The map has no filter slots (the constructor refuses slots of another kind).
        """
        slots, encoding = self.map.filters, self.map.filter_encoding
        if not isinstance(slots, FieldSlots) or encoding is None:
            raise ValueError("the drive's map has no filter slots")
        return slots, encoding

    def slot_values(self, slot: int) -> tuple[dict, bool]:
        """``({field: stored integer}, enabled)`` of filter slot ``slot``."""
        slots, _ = self._filter_parameters()
        regs = slots.fields(slot)
        raw = {name: int(r.decode(self.images["holding"][r.address : r.end])) for name, r in regs.items()}
        enabled = bool(raw.pop("enable")) if "enable" in raw else not all(raw[k] == v for k, v in slots.off.items())
        return raw, enabled

    def _apply_slot(self, slot: int) -> None:
        """The drive's notch equation at its loop rate, from what the slot's parameters hold now."""
        _, encoding = self._filter_parameters()
        values, enabled = self.slot_values(slot)
        section = Biquad.identity()
        if enabled:
            try:
                section = encoding.applied(values, self.loop_rate_hz)
            except DataError:
                enabled = False  # a setting that is no notch: the drive does not run it
        self.drive.filters.write(slot, section, enabled)

    # --- the clock --------------------------------------------------------------------------

    def advance(self, n_samples: int) -> None:
        """No table to play (the drive has no excitation capability)."""

    def idle(self, n_ticks: int) -> None:
        """Let the physics go on with the drive disabled; the feedback registers follow."""
        if n_ticks > 0:
            rows = self.drive.run(np.zeros(n_ticks))
            last = rows[-1]
            cols = self.drive.CHANNELS
            self._latest = {c: float(last[cols.index(c)]) for c in cols if c != "time_s"}

    # --- communication -----------------------------------------------------------------------

    def heard_from_host(self, now: float) -> None:
        self.last_heard = now

    def excuse_silence(self, seconds: float) -> None:
        if self.last_heard is not None:
            self.last_heard += seconds

    def watch_host(self, now: float) -> bool:
        """This drive has no communication timeout in its map: it never trips on silence."""
        return False


def _saturated(r: Register, x: float) -> list[int]:
    """Registers of ``x`` in ``r``, clipped to the register's range and type (a display saturates)."""
    if not math.isfinite(x):
        x = 0.0
    if r.minimum is not None:
        x = max(x, r.minimum)
    if r.maximum is not None:
        x = min(x, r.maximum)
    return encode_values(
        [x], r.type, r.scale, r.word_order, saturate=True, byte_order=r.byte_order, offset=r.offset
    ).tolist()
