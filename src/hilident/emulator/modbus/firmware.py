"""Register logic of the emulated Modbus drive: what it does on each read and write.

:class:`ModbusDriveFirmware` is the drive minus the clock and the wire. It
holds the register image described by the driver's map
(:class:`~hilident.protocol.modbus.register_map.RegisterMap`), the excitation
table and the capture buffer behind their paged windows, and the drive loop.
:mod:`hilident.emulator.modbus.server` serves it on a Modbus wire and advances
it in (scaled) real time; ``functions`` says which Modbus function codes it
declares (read/write holding registers: 3, 6, 16; 4 when the map has input
registers), and every other one is refused by the server with exception 1.

Reads and writes return a Modbus exception code (int) when the drive refuses,
as a real one would:

* 2 -- a write into the capture window (read-only), or of the current loop or
  the delay (:mod:`~hilident.emulator.modbus.loop`);
* 3 -- a value out of range (mode, divider, mask, length, page, limits, filter
  parameters, a gain the loop cannot run) or a command not allowed in the
  present state (run without limits, with a fault latched, with an empty or
  non-finite table);
* 6 -- configuration, limits or table written while a run is in progress.

Writing ``table_length`` arms a new run: ``done``, ``capture_stopped`` and
``sample_count`` clear. The ``[loop]`` registers show the running loop's
gains, and a write of one retunes it at once, during a run too
(:class:`~hilident.emulator.modbus.loop.LoopRegisters`). A buffered run: a
0 -> 1 edge of the ``run`` bit enables the drive in the selected mode and plays
the table, one sample per ``sample_divider`` loop ticks; record ``k`` of the
capture holds the drive's state at the start of sample period ``k``, while
``table[k]`` is held over that period. The run ends at the end of the table
(drive disabled), on a 1 -> 0 edge or a write of 0 (stop: disabled, zero
torque), or on a fault: a tripped limit, or the configured
``drive_fault_after_s``. The capture then holds the samples up to and
including the one in which the fault happened.

Communication timeout (when the map names ``comm_timeout_ms``): while the
drive is enabled and no request addressed to it has arrived for longer than
``comm_timeout_ms`` (0: off), it stops the run, disables itself and latches
fault ``comm_timeout`` (``fault_value``: the silence, s), as a servo drive's
communication-loss detection does. The server reports every request with
:meth:`ModbusDriveFirmware.heard_from_host` and asks
:meth:`ModbusDriveFirmware.watch_host` on its clock; the timeout runs on the
wall clock, because it watches the real link, not the simulated physics.
"""

from __future__ import annotations

import math

import numpy as np

from hilident.drivers.description import DriverDescription
from hilident.emulator.clock import Played, TablePlayer
from hilident.emulator.drive import DriveLoop
from hilident.emulator.modbus.loop import LoopRegisters
from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.protocol.modbus.filter_slots import FourRegisterSlots
from hilident.protocol.modbus.paging import STAMP_MODULUS, Window, table_crc
from hilident.protocol.modbus.register_map import RegisterMap

ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3
DEVICE_BUSY = 6

_HOLDING_FUNCTIONS = frozenset({3, 6, 16})  # read holding registers, write single, write multiple
_INPUT_FUNCTION = 4  # read input registers


def _input_registers(regmap: RegisterMap) -> list:
    """The map's input registers (function 4), none on a map that has only holding registers."""
    return [r for r in regmap.registers.values() if getattr(r, "table", "holding") == "input"]


def _declared_functions(regmap: RegisterMap) -> frozenset:
    """The Modbus function codes a drive with this map answers."""
    return _HOLDING_FUNCTIONS | ({_INPUT_FUNCTION} if _input_registers(regmap) else frozenset())


def _all_input(regmap: RegisterMap, address: int, count: int) -> bool:
    """Whether every address of ``address .. address + count - 1`` belongs to an input register."""
    inputs = _input_registers(regmap)
    return all(any(r.address <= a < r.end for r in inputs) for a in range(address, address + count))


_CONFIG = ("mode", "sample_divider", "capture_mask", "table_length")  # fixed while a run is in progress
_LIMITS = ("torque_limit_nm", "velocity_limit_mps", "position_min_m", "position_max_m")


class ModbusDriveFirmware:
    """The emulated drive's registers around one :class:`~hilident.emulator.drive.DriveLoop`.

    Parameters
    ----------
    drive : DriveLoop
    regmap : RegisterMap
        A map with the excitation capability (table, capture and filter slots).
    driver : DriverDescription
        Identity figures (name, firmware, loop rate, filter slots).
    drive_fault_after_s, capture_stops_after_s : float
        Fault switches (simulated seconds after a run starts; 0: never).

    Not thread-safe: the server serialises calls.

    Raises
    ------
    ValueError
        The map lacks the excitation capability (a parameter drive's map is
        served by :class:`~hilident.emulator.modbus.parameter_firmware.ParameterDriveFirmware`).
    ConfigError
        The map's filter slots are named parameters (``[[modbus.filters.slots]]``):
        beside an excitation table this twin runs hilident's four-register slots only.
    """

    def __init__(
        self,
        drive: DriveLoop,
        regmap: RegisterMap,
        driver: DriverDescription,
        drive_fault_after_s: float = 0.0,
        capture_stops_after_s: float = 0.0,
    ):
        if regmap.table is None or regmap.capture is None or regmap.filters is None or regmap.filter_encoding is None:
            raise ValueError("a map without the excitation capability is served by ParameterDriveFirmware")
        if not isinstance(regmap.filters, FourRegisterSlots):
            raise ConfigError(
                "modbus.filters",
                "the twin of a drive with an excitation table runs hilident's "
                "four-register filter slots (base, stride), not named parameters "
                "([[modbus.filters.slots]])",
                str(driver.folder / "driver.toml"),
            )
        self.drive = drive
        self.map = regmap
        self._table_window: Window = regmap.table
        self._capture_window: Window = regmap.capture
        self._slots: FourRegisterSlots = regmap.filters
        self._encoding: FilterEncoding = regmap.filter_encoding
        self.loop_rate_hz = float(driver.loop_rate_hz)
        self.max_sample_rate_hz = float(driver.max_sample_rate_hz)
        self.drive_fault_after_s = drive_fault_after_s
        self.capture_stops_after_s = capture_stops_after_s
        self._columns = drive.columns_of([c.name for c in regmap.capture_channels], "capture channel")
        self.image = np.zeros(65536, dtype=np.uint16)
        rps = regmap.table_registers_per_sample
        self.table = np.zeros(self._table_window.capacity_samples * rps, dtype=np.uint16)
        self.capture = np.zeros((self._capture_window.capacity_samples, len(regmap.capture_channels)))
        self.stamps = self._invalid_stamps(0, self._capture_window.capacity_samples)
        self.running = False
        self.done = False
        self.fault_code = 0
        self.fault_sample = 0
        self.fault_value = 0.0
        self.captured = 0
        self.produced = 0
        self.capture_stopped = False
        self.limits_loaded = False
        self.runs = 0  # runs started since power-up (the server's clock watches it)
        self.functions = _declared_functions(regmap)
        self.last_heard: float | None = None  # wall-clock time of the last request addressed to the drive, s
        self._crc: int | None = None
        self._values = np.zeros(0)
        self._run_mask = 0
        self._player = TablePlayer(drive, 1, self.loop_rate_hz, driver.averaged_channels)
        self._loop = LoopRegisters(drive, regmap, str(driver.folder / "driver.toml"))
        self._set("device_type", regmap.device_type)
        self._set("map_version", regmap.map_version)
        self._set("loop_rate_hz", driver.loop_rate_hz)
        self._set("max_sample_rate_hz", driver.max_sample_rate_hz)
        self._set("filter_slots", driver.filter_slots)
        self._set("table_capacity", self._table_window.capacity_samples)
        self._set("capture_capacity", self._capture_window.capacity_samples)
        self._set("device_name", driver.name)
        self._set("firmware", driver.firmware)
        self._set("mode", regmap.modes["torque"])
        self._set("sample_divider", 1)
        self._set("capture_mask", regmap.mask_of(regmap.capture_channel_names()))

    # --- the register image -------------------------------------------------------------

    def _set(self, name: str, value) -> None:
        r = self.map.register(name)
        self.image[r.address : r.end] = self.map.encode(name, value)

    def _get(self, name: str):
        r = self.map.register(name)
        return self.map.decode(name, self.image[r.address : r.end])

    @staticmethod
    def _invalid_stamps(first: int, n: int) -> np.ndarray:
        # a stamp that cannot match its own sample index: stale records never pass for new ones
        return ((np.arange(first, first + n) ^ 0x8000) % STAMP_MODULUS).astype(np.uint16)

    @property
    def table_length(self) -> int:
        return int(self._get("table_length"))

    @property
    def sample_rate_hz(self) -> float:
        return self._player.sample_rate_hz

    def status_word(self) -> int:
        s = self.map.status
        word = 0
        for on, name in (
            (self.drive.enabled, "enabled"),
            (self.running, "running"),
            (self.done, "done"),
            (self.fault_code != 0, "fault"),
            (self.capture_stopped, "capture_stopped"),
            (self.limits_loaded, "limits_loaded"),
        ):
            if on:
                word |= s[name]
        return word

    def _refresh(self, first: int, end: int) -> None:
        """Bring the computed registers in ``first .. end - 1`` up to date."""

        def touched(name):
            r = self.map.register(name)
            return r.address < end and r.end > first

        self._set("status_word", self.status_word())
        self._set("fault_code", self.fault_code)
        self._set("sample_count", self.captured)
        self._set("fault_sample", self.fault_sample)
        self._set("fault_value", self.fault_value)
        self._loop.show(self.image, first, end)
        if touched("table_crc"):
            if self._crc is None:
                n = min(self.table_length, self._table_window.capacity_samples) * self.map.table_registers_per_sample
                self._crc = table_crc(self.table[:n])
            self._set("table_crc", self._crc)

    # --- reads ----------------------------------------------------------------------------

    def read(self, address: int, count: int, input_registers: bool = False) -> list[int] | int:
        """Registers ``address .. address + count - 1``, or an exception code.

        ``input_registers``: read the input registers (function 4) instead of
        the holding registers; exception 2 unless every address is an input
        register of the map.
        """
        if input_registers and not _all_input(self.map, address, count):
            return ILLEGAL_ADDRESS
        end = address + count
        self._refresh(address, end)
        out = self.image[address:end].copy()
        w = self._table_window
        lo, hi = max(address, w.base), min(end, w.end)
        if lo < hi:
            start = int(self._get("table_page")) * w.page_samples * self.map.table_registers_per_sample
            a, b = start + lo - w.base, start + hi - w.base
            part = np.zeros(hi - lo, dtype=np.uint16)
            avail = max(0, min(b, len(self.table)) - a)
            part[:avail] = self.table[a : a + avail]
            out[lo - address : hi - address] = part
        w = self._capture_window
        lo, hi = max(address, w.base), min(end, w.end)
        if lo < hi:
            out[lo - address : hi - address] = self._capture_registers(lo - w.base, hi - w.base)
        return out.tolist()

    def _capture_registers(self, first: int, end: int) -> np.ndarray:
        """Window registers ``first .. end - 1`` (offsets) of the selected capture page."""
        mask = self._run_mask or int(self._get("capture_mask"))
        width = self.map.record_registers(mask)
        w = self._capture_window
        page0 = int(self._get("capture_page")) * w.page_samples
        r0, r1 = first // width, -(-end // width)  # records touched, relative to the page
        r1 = min(r1, w.page_samples)
        out = np.zeros(end - first, dtype=np.uint16)
        k0, k1 = page0 + r0, min(page0 + r1, w.capacity_samples)
        if k1 <= k0:
            return out
        selected = [i for i, c in enumerate(self.map.capture_channels) if mask >> c.bit & 1]
        regs = self.map.encode_records(self.stamps[k0:k1], self.capture[k0:k1][:, selected], mask)
        skip = first - r0 * width
        n = min(len(regs) - skip, end - first)
        out[:n] = regs[skip : skip + n]
        return out

    # --- writes ---------------------------------------------------------------------------

    def write(self, address: int, values) -> int | None:
        """Write registers from ``address``; returns an exception code when the drive refuses."""
        values = np.asarray(values, dtype=np.int64)
        end = address + len(values)
        if np.any((values < 0) | (values > 0xFFFF)):
            return ILLEGAL_VALUE
        values = values.astype(np.uint16)
        w = self._capture_window
        if address < w.end and end > w.base:
            return ILLEGAL_ADDRESS
        w = self._table_window
        lo, hi = max(address, w.base), min(end, w.end)
        if lo < hi:
            if self.running:
                return DEVICE_BUSY
            start = int(self._get("table_page")) * w.page_samples * self.map.table_registers_per_sample
            a = start + lo - w.base
            if a + (hi - lo) > len(self.table):
                return ILLEGAL_ADDRESS  # beyond the table's capacity
            self.table[a : a + hi - lo] = values[lo - address : hi - address]
            self._crc = None
        self._loop.show(self.image, address, end)  # a loop register written in part keeps its other words
        old = self.image[address:end].copy()
        self.image[address:end] = values
        if address < w.end and end > w.base:
            self.image[max(address, w.base) : min(end, w.end)] = 0  # the window is not image memory
        touched = [r.name for r in self.map.registers.values() if r.address < end and r.end > address]
        slots = sorted({s for a in range(address, end) if (s := self._slots.slot_at(a)) is not None})
        loop = {n: float(self._get(n)) for n in touched if n in self._loop}
        error = self._check(
            touched,
            slots,
            loop,
            old_control=int(old[self.map.register("control_word").address - address])
            if "control_word" in touched
            else None,
        )
        if error:
            self.image[address:end] = old
            return error
        self._apply(
            touched,
            slots,
            loop,
            int(old[self.map.register("control_word").address - address]) if "control_word" in touched else 0,
        )
        return None

    def _check(
        self, touched: list[str], slots: list[int], loop: dict[str, float], old_control: int | None
    ) -> int | None:
        """The exception code that refuses a write of the ``touched`` registers, ``slots`` and ``loop`` registers
        (register -> value written; None: accepted)."""
        if self.running and any(n in touched for n in (*_CONFIG, *_LIMITS)):
            return DEVICE_BUSY
        if not self._values_valid(touched):
            return ILLEGAL_VALUE
        if loop and (refused := self._loop.refusal(loop)) is not None:
            return refused
        if any(n in touched for n in _LIMITS) and self._limits() is None:
            return ILLEGAL_VALUE
        if any(self._slot_filter(slot) is None for slot in slots):
            return ILLEGAL_VALUE
        if old_control is not None:
            run = self.map.control["run"]
            if int(self._get("control_word")) & run and not old_control & run and not self.running:
                return self._start_refusal()
        return None

    def _values_valid(self, touched: list[str]) -> bool:
        """Whether every touched configuration register holds a value the drive takes."""
        m = self.map
        checks = {
            "mode": lambda: int(self._get("mode")) in m.modes.values(),
            "sample_divider": lambda: self._divider_valid(int(self._get("sample_divider"))),
            "capture_mask": lambda: self._mask_valid(int(self._get("capture_mask"))),
            "table_length": lambda: (
                self.table_length <= min(self._table_window.capacity_samples, self._capture_window.capacity_samples)
            ),
            "table_page": lambda: int(self._get("table_page")) < self._table_window.pages,
            "capture_page": lambda: int(self._get("capture_page")) < self._capture_window.pages,
        }
        return all(check() for name, check in checks.items() if name in touched)

    def _divider_valid(self, divider: int) -> bool:
        return divider >= 1 and self.loop_rate_hz / divider <= self.max_sample_rate_hz * (1 + 1e-9)

    def _mask_valid(self, mask: int) -> bool:
        return mask != 0 and not mask >> len(self.map.capture_channels)

    def _apply(self, touched: list[str], slots: list[int], loop: dict[str, float], old_control: int) -> None:
        self._loop.take(loop)
        if "table_length" in touched:  # a new table re-arms the capture: the last run's records are gone
            self._crc = None
            self.done = self.capture_stopped = False
            self.captured = self.produced = 0
        if any(n in touched for n in _LIMITS):
            limits = self._limits()
            assert limits is not None, "_check refuses a write that leaves the limits invalid"
            self.drive.set_limits(*limits)
            self.limits_loaded = True
        for slot in slots:
            section = self._slot_filter(slot)
            assert section is not None, "_check refuses a write that leaves a slot without a valid notch"
            biquad, enabled = section
            self.drive.filters.write(slot, biquad, enabled)
        if "control_word" in touched:
            self._control(old_control, int(self._get("control_word")))

    def _limits(self) -> tuple[float, float, float, float] | None:
        t, v, lo, hi = (float(self._get(n)) for n in _LIMITS)
        if not all(math.isfinite(x) for x in (t, v, lo, hi)) or not (t > 0 and v > 0 and lo < hi):
            return None
        return t, v, lo, hi

    def _slot_filter(self, slot: int) -> tuple[Biquad, bool] | None:
        """What slot ``slot``'s registers ask for, or None when the values are not a valid notch."""
        a = self._slots.address(slot)
        values, enabled = self.map.decode_filter(self.image[a : a + self._slots.span])
        if not any(values.values()):  # an empty slot passes the torque through; it cannot be enabled
            return None if enabled else (Biquad.identity(), False)
        try:
            return self._encoding.applied(values, self.loop_rate_hz), enabled
        except DataError:
            return None

    # --- commands -------------------------------------------------------------------------

    def _start_refusal(self) -> int | None:
        n = self.table_length
        if self.fault_code or self.drive.fault is not None:
            return ILLEGAL_VALUE  # clear the fault first (fault_reset)
        if not self.limits_loaded or n < 1:
            return ILLEGAL_VALUE
        values = self.map.decode_table(self.table[: n * self.map.table_registers_per_sample])
        if not np.all(np.isfinite(values)):
            return ILLEGAL_VALUE
        self._values = values
        return None

    def _control(self, old: int, new: int) -> None:
        c = self.map.control
        run, reset = c["run"], c["fault_reset"]
        if new & reset and not old & reset and not self.running:
            self.drive.clear_fault()
            self.fault_code = self.fault_sample = 0
            self.fault_value = 0.0
        if new & run and not old & run and not self.running:
            self._start()
        elif not new & run:
            if self.running:
                self._end()
            self.drive.disable()  # writing 0 always leaves the axis at zero torque

    def _start(self) -> None:
        n = self.table_length
        mode = {v: k for k, v in self.map.modes.items()}[int(self._get("mode"))]
        self._run_mask = int(self._get("capture_mask"))
        self.stamps[:n] = self._invalid_stamps(0, n)
        self.drive.set_mode(mode)
        self.drive.enable()
        self._player.restart(int(self._get("sample_divider")))
        self.produced = self.captured = 0
        self.capture_stopped = False
        self.running = True
        self.done = False
        self.runs += 1

    def _end(self) -> None:
        self.running = False
        self.done = True
        self.drive.disable()
        if self.produced < self.table_length and self.captured < self.produced:
            self.capture_stopped = True

    # --- the run --------------------------------------------------------------------------

    def advance(self, n_samples: int) -> None:
        """Play up to ``n_samples`` samples of the table through the drive and capture them."""
        if not self.running or n_samples <= 0:
            return
        player, k0 = self._player, self.produced
        n = min(int(n_samples), self.table_length - k0)
        if self.drive_fault_after_s:
            if k0 >= player.samples_before(self.drive_fault_after_s):
                self._fault(self.map.fault_codes["drive_fault"], k0, 0.0)
                return
            n = player.cut_at(k0, n, (self.drive_fault_after_s,))
        played = player.play(self._values[k0 : k0 + n], k0)
        self._capture(played)
        self.produced = played.end
        if self.captured < self.produced:
            self.capture_stopped = True
        if played.faulted:
            fault, unknown = self.drive.fault, self.map.fault_codes["drive_fault"]
            code = self.map.fault_codes.get(fault, unknown) if fault is not None else unknown
            self._fault(code, played.end - 1, float(self.drive.fault_value or 0.0))
        elif self.produced >= self.table_length:
            self._end()

    def _capture(self, played: Played) -> None:
        """Record the kept samples, up to ``capture_stops_after_s`` when that fault is switched on."""
        k0, stop = played.first, played.end
        if self.capture_stops_after_s:
            stop = min(stop, max(k0, self._player.samples_before(self.capture_stops_after_s)))
        if stop > k0:
            self.capture[k0:stop] = played.rows[: stop - k0][:, self._columns]
            self.stamps[k0:stop] = np.arange(k0, stop) % STAMP_MODULUS
            self.captured = stop

    def _fault(self, code: int, sample: int, value: float) -> None:
        self.fault_code = code
        self.fault_sample = sample
        self.fault_value = value
        self.running = False
        self.done = True
        self.drive.disable()

    # --- communication timeout ------------------------------------------------------------

    def heard_from_host(self, now: float) -> None:
        """A request addressed to this drive arrived at wall-clock time ``now`` (s, monotonic)."""
        self.last_heard = now

    def excuse_silence(self, seconds: float) -> None:
        """``seconds`` during which the server could not hear requests do not count as the host's silence."""
        if self.last_heard is not None:
            self.last_heard += seconds

    @property
    def comm_timeout_s(self) -> float:
        """The communication timeout the host set, s (0: off, or the map has no such register)."""
        if "comm_timeout_ms" not in self.map.registers:
            return 0.0
        return float(self._get("comm_timeout_ms")) / 1000.0

    def watch_host(self, now: float) -> bool:
        """Stop, disable and latch ``comm_timeout`` when enabled and silent too long; True when it tripped."""
        timeout = self.comm_timeout_s
        if not timeout or not self.drive.enabled or self.last_heard is None:
            return False
        silence = now - self.last_heard
        if silence <= timeout:
            return False
        self._fault(self.map.fault_codes["comm_timeout"], self.produced, silence)
        return True

    def idle(self, n_ticks: int) -> None:
        """Let the physics go on with the drive disabled (the axis coasts to rest)."""
        if not self.running and n_ticks > 0:
            self.drive.run(np.zeros(n_ticks))
