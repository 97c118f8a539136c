"""The emulated Modbus drive on a real wire: Modbus TCP on 127.0.0.1, or Modbus RTU on a pseudo-terminal.

:class:`ModbusDriveServer` serves a
:class:`~hilident.emulator.modbus.firmware.ModbusDriveFirmware` in a
background asyncio loop and advances its drive in simulated time
(``time_scale`` simulated seconds per wall second) in a second thread. The
wire follows the MODBUS Application Protocol V1.1b3 (requests answered by
:func:`hilident.emulator.modbus.pdu.handle`), the MODBUS Messaging on TCP/IP
Implementation Guide V1.0b (MBAP header) and MODBUS over Serial Line V1.02
(RTU frames), so any master, not only pymodbus, sees what a specification
reader expects:

* a function code the drive does not declare (``firmware.functions``) gets
  exception 01; a quantity out of range or a byte count that does not match it
  exception 03; an address the map does not hold (or a write into a read-only
  register) exception 02; 04 only when the drive itself fails;
* Modbus TCP: several connections, the transaction id echoed; requests to the
  configured unit id and to 255 are answered, others ignored (or answered with
  exception 11 with ``[emulator.faults.modbus] unknown_unit_id = "gateway_exception"``);
* Modbus RTU: only frames to its own address are answered; a broadcast
  (address 0) write is carried out without an answer, a broadcast read
  ignored; a frame with a bad CRC is dropped in silence. A frame ends where its
  function code says (its length, or its byte count), else at 3.5 characters
  of silence (1.75 ms above 19200 baud).

Modbus RTU runs over two pseudo-terminals joined like a null-modem cable
(:class:`PtyBridge`): the server opens one end like a serial port, the
host opens the other (``/dev/pts/N``), and the bridge carries the bytes at the
line rate (start bit, 8 data bits, parity bit unless ``N``, stop bits). A
pseudo-terminal carries no parity bit, and some kernels refuse to set one, so
both ends open it with parity ``N``; the host's ``[device.modbus].parity`` must be
``"N"`` for an emulated RTU line.

``[emulator].link`` chooses the transport: ``"tcp"`` and ``"pipe"`` give Modbus
TCP (there is no in-memory Modbus line; TCP on loopback is the fast one),
``"pty"`` gives Modbus RTU over a pseudo-terminal.

Fault switches (``[emulator.faults.modbus]``): ``exception_register`` /
``exception_code`` (every request touching that register is answered with
that exception), ``response_delay_s`` (every answer comes this late),
``missing_response_rate`` (answers lost; the request itself was carried out),
``unknown_unit_id`` (see above); in ``[emulator.faults]``,
``capture_stops_after_s`` and ``drive_fault_after_s`` (see the firmware).

The drive's communication timeout (register ``comm_timeout_ms``) is watched on
the wall clock by the clock thread, whatever ``time_scale`` is: a host that
falls silent while the drive is enabled finds it stopped, disabled and
latched in fault ``comm_timeout``. A real drive listens in real time; this
twin is a process that a loaded machine can leave unscheduled, so the time
its server loop could not run is not counted as the host's silence.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import threading
import time
from dataclasses import replace
from typing import Protocol

import numpy as np

from hilident.config.tables import DeviceConfig, EmulatorConfig, FaultsConfig
from hilident.drivers.description import DriverDescription
from hilident.emulator.clock import PacedFirmware, SimClock
from hilident.emulator.device import EmulatedDevice, build_drive
from hilident.emulator.drive import DriveLoop
from hilident.emulator.modbus.firmware import ModbusDriveFirmware
from hilident.emulator.modbus.parameter_firmware import ParameterDriveFirmware
from hilident.emulator.modbus.pdu import (
    GATEWAY_TARGET_FAILED,
    ILLEGAL_DATA_ADDRESS,
    SERVER_DEVICE_FAILURE,
    WRITE_FUNCTIONS,
    BitFirmware,
    exception_response,
    handle,
)
from hilident.emulator.modbus.rtu import PtyBridge, RtuLine
from hilident.errors import ConfigError
from hilident.protocol.modbus.exception_codes import EXCEPTION_MEANINGS
from hilident.protocol.modbus.filter_slots import FourRegisterSlots
from hilident.protocol.modbus.register_map import RegisterMap
from hilident.protocol.modbus.rtu import rtu_crc

log = logging.getLogger(__name__)

_BEAT_S = 0.005  # the server loop notes every so often that it is free to hear requests
_STALL_S = 0.02  # a longer gap between two notes: this process was not scheduled (a loaded machine)
_TCP_UNIT_ANY = 0xFF  # the unit id of a directly addressed Modbus TCP device
_MBAP_MAX_LENGTH = 1 + 253 + 16  # unit id + the longest PDU, with room to answer an oversized request with 03
_BROADCAST = 0


class ServedDrive(PacedFirmware, Protocol):
    """What the server needs of a drive's firmware: its registers, its clock and its host watch.

    :class:`~hilident.emulator.modbus.firmware.ModbusDriveFirmware` and
    :class:`~hilident.emulator.modbus.parameter_firmware.ParameterDriveFirmware`
    offer it (the register requests :func:`~hilident.emulator.modbus.pdu.handle`
    makes, and :class:`~hilident.emulator.clock.PacedFirmware`'s methods).
    """

    @property
    def drive(self) -> DriveLoop: ...

    @property
    def functions(self) -> frozenset[int]: ...

    @property
    def loop_rate_hz(self) -> float: ...

    @property
    def runs(self) -> int: ...

    def read(self, address: int, count: int, input_registers: bool = False) -> list[int] | int: ...

    def write(self, address: int, values) -> int | None: ...

    def heard_from_host(self, now: float) -> None: ...

    def excuse_silence(self, seconds: float) -> None: ...

    def watch_host(self, now: float) -> bool: ...


def _address_tables(regmap: RegisterMap | None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Which addresses read as holding registers, take writes, and read as input registers.

    The map's registers (read-only where it says so), the excitation table
    window, the capture window (read-only) and the filter slots, when the map
    has them. None without a map: the firmware then decides alone.
    """
    if regmap is None:
        return None
    readable, writable, inputs = (np.zeros(1 << 16, dtype=bool) for _ in range(3))
    for r in regmap.registers.values():
        if getattr(r, "table", "holding") == "input":
            inputs[r.address : r.end] = True
            continue
        readable[r.address : r.end] = True
        writable[r.address : r.end] = r.writable
    for name, writes in (("table", True), ("capture", False)):
        if (w := getattr(regmap, name, None)) is not None:
            readable[w.base : w.end] = True
            writable[w.base : w.end] = writes
    if isinstance(f := getattr(regmap, "filters", None), FourRegisterSlots):  # FieldSlots are map registers
        for i in range(f.slots):
            readable[f.address(i) : f.address(i) + f.span] = True
            writable[f.address(i) : f.address(i) + f.span] = True
    return readable, writable, inputs


class _ServedFirmware:
    """The firmware as the wire reaches it: addresses outside the map refused (02), and the fault switch."""

    def __init__(self, firmware: ServedDrive, server: ModbusDriveServer):
        self.firmware = firmware
        self.functions = frozenset(firmware.functions)
        self.server = server  # its fault switches, as they are now
        self._tables = _address_tables(getattr(firmware, "map", None))

    def _refusal(self, table: int, address: int, count: int) -> int | None:
        if self._tables is not None and not self._tables[table][address : address + count].all():
            return ILLEGAL_DATA_ADDRESS
        f = self.server.faults.modbus
        if f.exception_register >= 0 and address <= f.exception_register < address + count:
            return f.exception_code
        return None

    def read(self, address: int, count: int, input_registers: bool = False):
        refused = self._refusal(2 if input_registers else 0, address, count)
        if refused is None:
            return self.firmware.read(address, count, input_registers=input_registers)
        return refused

    def write(self, address: int, values):
        refused = self._refusal(1, address, len(values))
        return self.firmware.write(address, values) if refused is None else refused

    def _bits(self) -> BitFirmware:
        """The firmware's coils and discrete inputs (asked only for the function codes it declares)."""
        if not isinstance(self.firmware, BitFirmware):
            raise NotImplementedError(
                f"the drive declares functions {sorted(self.functions)} but has no coils or discrete inputs"
            )
        return self.firmware

    def read_bits(self, address: int, count: int, discrete: bool = False) -> list[bool] | int:
        return self._bits().read_bits(address, count, discrete=discrete)

    def write_bits(self, address: int, values) -> int | None:
        return self._bits().write_bits(address, values)


class ModbusDriveServer:
    """Serve a :class:`ModbusDriveFirmware` over Modbus TCP or RTU and run its clock.

    Parameters
    ----------
    firmware : ServedDrive
        A :class:`ModbusDriveFirmware`, a :class:`ParameterDriveFirmware`, or
        any drive with ``functions``, ``read`` and ``write`` (see
        :mod:`hilident.emulator.modbus.pdu`) and the clock's methods.
    device_id : int
        Modbus device (unit) id it answers (0: any).
    rtu : bool
        Modbus RTU over a pseudo-terminal instead of Modbus TCP on 127.0.0.1.
    baudrate, parity, stopbits
        RTU line settings (the bridge carries bytes at this rate).
    time_scale : float
        Simulated seconds per wall-clock second.
    faults : FaultsConfig, optional
        Its ``modbus`` sub-table (``[emulator.faults.modbus]``) is what the wire does.
    seed : int
        Seed of the missing-response draws.

    Attributes
    ----------
    port : str
        What a host puts in ``[device].port``: ``tcp://127.0.0.1:PORT`` or the pty path.
    error : BaseException or None
        What stopped the server, if anything did.
    lock : threading.Lock
        Held while the firmware is read, written or advanced.
    requests : int
        Requests addressed to this drive (broadcasts included).
    dropped_responses : int
        Answers lost on purpose (``missing_response_rate``).
    device_failures : int
        Requests answered with exception 04 because the firmware failed
        (``last_failure`` holds the latest cause).
    """

    def __init__(
        self,
        firmware: ServedDrive,
        *,
        device_id: int = 1,
        rtu: bool = False,
        baudrate: int = 115200,
        parity: str = "E",
        stopbits: int = 1,
        time_scale: float = 1.0,
        faults: FaultsConfig | None = None,
        seed: int = 0,
    ):
        self.firmware = firmware
        self.device_id = device_id
        self.rtu = rtu
        self.baudrate = baudrate
        self.parity = parity
        self.stopbits = stopbits
        self.time_scale = time_scale
        self.faults = faults or FaultsConfig()
        wire = self.faults.modbus
        if wire.exception_register >= 0 and wire.exception_code not in EXCEPTION_MEANINGS:
            raise ConfigError(
                "emulator.faults.modbus.exception_code",
                f"{wire.exception_code} is not a Modbus exception code "
                f"({', '.join(str(c) for c in EXCEPTION_MEANINGS)})",
            )
        self._rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        self.error: BaseException | None = None
        self.port = ""
        self.requests = 0
        self.dropped_responses = 0
        self.device_failures = 0
        self.last_failure: BaseException | None = None
        self._served = _ServedFirmware(firmware, self)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: threading.Thread | None = None
        self._clock_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._server: asyncio.AbstractServer | None = None
        self._connections: set[asyncio.StreamWriter] = set()
        self._bridge: PtyBridge | None = None
        self._rtu = RtuLine(self) if rtu else None
        self._beat_at = time.monotonic()
        self._beat_task: asyncio.Task | None = None

    # --- lifecycle -------------------------------------------------------------------------

    def start(self) -> ModbusDriveServer:
        if self.rtu:
            self._bridge = PtyBridge(self.baudrate, self.bits_per_char).start()
        self._loop = asyncio.new_event_loop()
        self._loop_thread = threading.Thread(target=self._loop.run_forever, name="modbus-server", daemon=True)
        self._loop_thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._serve(), self._loop).result(timeout=10)
        except BaseException:
            self.close()
            raise
        self._clock_thread = threading.Thread(target=self._clock, name="modbus-drive-clock", daemon=True)
        self._clock_thread.start()
        return self

    @property
    def bits_per_char(self) -> int:
        """Start bit, 8 data bits, parity bit (unless ``N``) and stop bits of one RTU character."""
        return 1 + 8 + (0 if self.parity == "N" else 1) + self.stopbits

    async def _serve(self) -> None:
        if self.rtu:
            if self._rtu is None or self._bridge is None:
                raise RuntimeError("an RTU server is served on its bridge: start() makes it")
            self._rtu.open(self._bridge.device_path, asyncio.get_running_loop())
            self.port = self._bridge.host_path
        else:
            self._server = await asyncio.start_server(self._tcp_connection, "127.0.0.1", 0)
            self.port = f"tcp://127.0.0.1:{self._server.sockets[0].getsockname()[1]}"
        self._beat_at = time.monotonic()
        self._beat_task = asyncio.ensure_future(self._beat())

    async def _beat(self) -> None:
        """Note how long the server loop could not run; that time is not the host's silence."""
        while True:
            await asyncio.sleep(_BEAT_S)
            now = time.monotonic()
            stalled = now - self._beat_at - _BEAT_S
            self._beat_at = now
            if stalled > _STALL_S:
                with self.lock:
                    self.firmware.excuse_silence(stalled)

    async def _shutdown(self) -> None:
        if self._beat_task is not None:
            self._beat_task.cancel()
        if self._server is not None:
            self._server.close()
        for writer in list(self._connections):
            writer.close()
        if self._rtu is not None:
            self._rtu.close()

    def close(self) -> None:
        """Stop the axis, the clock and the server; release the port."""
        self._stop.set()
        if self._clock_thread is not None:
            self._clock_thread.join(timeout=2.0)
        with self.lock:
            self.firmware.drive.disable()
        if self._loop is not None and self._loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop).result(timeout=2.0)
            except Exception:
                pass
            self._loop.call_soon_threadsafe(self._loop.stop)
            if self._loop_thread is not None:
                self._loop_thread.join(timeout=2.0)
        if self._loop is not None and not self._loop.is_running():
            self._loop.close()
        if self._bridge is not None:
            self._bridge.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    # --- requests ---------------------------------------------------------------------------

    def _answer(self, pdu: bytes) -> bytes | None:
        """Carry out one request addressed to this drive; its response PDU (None: nothing to answer)."""
        self.requests += 1
        with self.lock:
            self.firmware.heard_from_host(time.monotonic())
            try:
                return handle(self._served, pdu)
            except Exception as exc:  # the drive itself failed: exception 04, and the server goes on
                self.device_failures += 1
                self.last_failure = exc
                log.warning("emulated Modbus drive failed on request %s: %r", pdu.hex(), exc)
                return exception_response(pdu[0], SERVER_DEVICE_FAILURE)

    def _deliver(self) -> bool:
        """Whether an answer leaves now: the place for slow and missing answers."""
        wire = self.faults.modbus
        if wire.response_delay_s:
            # a slow drive answers one request after the other: block this server's loop, so a
            # late answer never overtakes (or takes the transaction id of) the next request
            time.sleep(wire.response_delay_s)
        rate = wire.missing_response_rate
        if rate and self._rng.random() < rate:
            self.dropped_responses += 1
            return False  # carried out, never answered
        return True

    def _answers_unit(self, unit: int) -> bool:
        return self.device_id == 0 or unit == self.device_id

    # --- Modbus TCP ---------------------------------------------------------------------------

    async def _tcp_connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One client connection: MBAP header, PDU, answer with the same transaction id."""
        self._connections.add(writer)
        try:
            while True:
                transaction, protocol, length, unit = struct.unpack(">HHHB", await reader.readexactly(7))
                if not 2 <= length <= _MBAP_MAX_LENGTH:
                    break  # not a Modbus frame: the stream cannot be resynchronised, close it
                pdu = await reader.readexactly(length - 1)
                if protocol != 0:
                    continue  # another protocol multiplexed on the port: not ours
                answer = self._tcp_answer(unit, pdu)
                if answer is None or not self._deliver():
                    continue
                writer.write(struct.pack(">HHHB", transaction, 0, len(answer) + 1, unit) + answer)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        finally:
            self._connections.discard(writer)
            writer.close()

    def _tcp_answer(self, unit: int, pdu: bytes) -> bytes | None:
        if unit == _TCP_UNIT_ANY or self._answers_unit(unit):
            return self._answer(pdu)
        if self.faults.modbus.unknown_unit_id == "gateway_exception" and pdu:
            return exception_response(pdu[0], GATEWAY_TARGET_FAILED)
        return None  # another unit behind this address: not ours to answer

    # --- Modbus RTU ---------------------------------------------------------------------------

    def rtu_frame(self, frame: bytes) -> bytes | None:
        """The RTU answer frame to a request frame whose CRC is good (None: stay silent)."""
        address, pdu = frame[0], frame[1:-2]
        if address == _BROADCAST:
            if pdu and pdu[0] in WRITE_FUNCTIONS:
                self._answer(pdu)  # carried out, never answered
            return None
        if not self._answers_unit(address):
            return None
        answer = self._answer(pdu)
        if answer is None or not self._deliver():
            return None
        body = bytes([address]) + answer
        crc = rtu_crc(body)
        return body + bytes([crc & 0xFF, crc >> 8])

    # --- the drive's clock --------------------------------------------------------------------

    def _clock(self) -> None:
        fw = self.firmware
        # at most 20 ms of samples per step: the lock is held while they play, and requests wait for it
        clock = SimClock(fw.loop_rate_hz, self.time_scale, max_catch_up_s=0.02)
        runs_seen = fw.runs
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                with self.lock:
                    listening = now - self._beat_at < _STALL_S + _BEAT_S  # else the silence may be ours
                    if listening and fw.watch_host(now):  # the host went silent: the drive stopped on its own
                        clock.start_coast(now)
                    if fw.runs != runs_seen:  # a run was triggered since the last look
                        runs_seen = fw.runs
                        clock.start_run(now)
                    clock.step(fw, now)
                time.sleep(0.002)
        except BaseException as exc:  # keep the failure for the owner to see
            self.error = exc
            with self.lock:
                fw.drive.disable()


def start(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig, link: str | None = None
) -> EmulatedDevice:
    """Start an emulated Modbus drive for a session configured with ``device``.

    Parameters
    ----------
    cfg : EmulatorConfig
        Plant, friction, drive, sensors, faults, time scale; ``cfg.link``:
        ``"tcp"``/``"pipe"`` Modbus TCP, ``"pty"`` Modbus RTU.
    driver : DriverDescription
        A ``transport = "modbus"`` driver (its register map).
    device : DeviceConfig
        ``device_id`` and the RTU line settings (``baudrate`` 0: the driver's default).
    link : {"tcp", "pty"}, optional
        Overrides ``cfg.link``.

    Returns
    -------
    EmulatedDevice
        ``device.port`` is ``tcp://127.0.0.1:PORT`` or the pseudo-terminal path.
    """
    rtu = (link or cfg.link) == "pty"
    regmap = RegisterMap.from_driver(driver)
    drive = build_drive(cfg, driver)
    firmware: ServedDrive
    if regmap.excitation:
        firmware = ModbusDriveFirmware(
            drive, regmap, driver, cfg.faults.drive_fault_after_s, cfg.faults.capture_stops_after_s
        )
    else:  # a real drive's parameter list: no table, no capture
        firmware = ParameterDriveFirmware(drive, regmap, driver)
    baudrate = device.baudrate or driver.default_baudrate
    line = device.modbus
    server = ModbusDriveServer(
        firmware,
        device_id=line.device_id,
        rtu=rtu,
        baudrate=baudrate,
        parity=line.parity,
        stopbits=line.stopbits,
        time_scale=cfg.time_scale,
        faults=cfg.faults,
        seed=cfg.seed + 1,
    ).start()
    # a pseudo-terminal carries no parity bit (some kernels refuse the setting): both ends open it
    # without one, while the bridge still times each character with the configured parity bit
    host = (
        replace(device, port=server.port, baudrate=baudrate, modbus=replace(line, parity="N"))
        if rtu
        else replace(device, port=server.port)
    )
    return EmulatedDevice(server=server, device=host, drive=drive)
