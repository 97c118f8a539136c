"""The emulated Modbus drive on a real wire: Modbus TCP on 127.0.0.1, or Modbus RTU on a pseudo-terminal.

:class:`ModbusDriveServer` serves a
:class:`~hilident.emulator.modbus_firmware.ModbusDriveFirmware` with pymodbus
(``ModbusTcpServer``, or ``ModbusSerialServer`` with the RTU framer) in a
background asyncio loop, and advances its drive in simulated time
(``time_scale`` simulated seconds per wall second) in a second thread. Its
registers are a pymodbus ``SimDevice`` built from the driver's register map;
every request goes through the firmware, so the host sees exactly what the map
describes.

Modbus RTU runs over two pseudo-terminals joined like a null-modem cable
(:class:`PtyBridge`): the pymodbus server opens one end like a serial port, the
host opens the other (``/dev/pts/N``), and the bridge carries the bytes at the
line rate (start bit, 8 data bits, parity bit unless ``N``, stop bits). A
pseudo-terminal carries no parity bit, and some kernels refuse to set one, so
both ends open it with parity ``N``; the host's ``[device].parity`` must be
``"N"`` for an emulated RTU line.

``[emulator].link`` chooses the transport: ``"tcp"`` and ``"pipe"`` give Modbus
TCP (there is no in-memory Modbus line; TCP on loopback is the fast one),
``"pty"`` gives Modbus RTU over a pseudo-terminal.

Fault switches (``[emulator.faults]``): ``exception_register`` /
``exception_code`` (every request touching that register is answered with
that exception), ``response_delay_s`` (every answer comes this late),
``missing_response_rate`` (answers lost; the request itself was carried out),
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
import os
import select
import threading
import time
import tty
from dataclasses import replace

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from hilident.config import DeviceConfig, EmulatorConfig, FaultsConfig
from hilident.drivers import DriverDescription
from hilident.emulator.factory import EmulatedDevice, build_drive
from hilident.emulator.modbus_firmware import ModbusDriveFirmware
from hilident.errors import ConfigError
from hilident.protocol.modbus_registers import RegisterMap

logging.getLogger("pymodbus").addHandler(logging.NullHandler())  # no library chatter on stderr

_COAST_S = 2.0  # simulated seconds the axis coasts, drive disabled, after a run
_BEAT_S = 0.005  # the server loop notes every so often that it is free to hear requests
_STALL_S = 0.02  # a longer gap between two notes: this process was not scheduled (a loaded machine)


class PtyBridge:
    """Two pseudo-terminals joined like a null-modem cable, carrying bytes at a line rate.

    Parameters
    ----------
    baudrate : int
        Line rate; 0 carries bytes as fast as they come.
    bits_per_char : int
        Start bit, data bits, parity bit and stop bits of one character.

    Attributes
    ----------
    device_path, host_path : str
        The two serial device paths (``/dev/pts/N``).
    """

    def __init__(self, baudrate: int, bits_per_char: int = 11):
        self._device_master, self._device_slave = os.openpty()
        self._host_master, self._host_slave = os.openpty()
        for fd in (self._device_slave, self._host_slave):
            tty.setraw(fd)
        self.device_path = os.ttyname(self._device_slave)
        self.host_path = os.ttyname(self._host_slave)
        self.char_time_s = bits_per_char / baudrate if baudrate else 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.bytes_carried = 0

    def start(self) -> "PtyBridge":
        self._thread = threading.Thread(target=self._run, name="modbus-pty-bridge", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        other = {self._device_master: self._host_master, self._host_master: self._device_master}
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select(list(other), [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    time.sleep(0.01)
                    continue
                if self.char_time_s:
                    time.sleep(len(data) * self.char_time_s)  # the characters take this long on the line
                self._write(other[fd], data)
                self.bytes_carried += len(data)

    def _write(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + 0.5
        while view and not self._stop.is_set() and time.monotonic() < deadline:
            try:
                _, ready, _ = select.select([], [fd], [], 0.05)
                if ready:
                    view = view[os.write(fd, view):]
            except OSError:
                return  # nobody at the other end: the bytes are lost, as on an open line

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self._device_master, self._device_slave, self._host_master, self._host_slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _simdata(regmap: RegisterMap) -> list[SimData]:
    """The addresses the drive answers, read-only where the map says so (writes there get exception 2)."""
    blocks = [(r.address, r.count, not r.writable) for r in regmap.registers.values()]
    blocks.append((regmap.table.base, regmap.table.registers, False))
    blocks.append((regmap.capture.base, regmap.capture.registers, True))
    f = regmap.filters
    blocks += [(f.address(i), f.span, False) for i in range(f.slots)]
    return [SimData(a, count=n, values=0, datatype=DataType.REGISTERS, readonly=ro) for a, n, ro in sorted(blocks)]


class ModbusDriveServer:
    """Serve a :class:`ModbusDriveFirmware` over Modbus TCP or RTU and run its clock.

    Parameters
    ----------
    firmware : ModbusDriveFirmware
    device_id : int
        Modbus device (unit) id it answers (0: any).
    rtu : bool
        Modbus RTU over a pseudo-terminal instead of Modbus TCP on 127.0.0.1.
    baudrate, parity, stopbits
        RTU line settings (the bridge carries bytes at this rate).
    time_scale : float
        Simulated seconds per wall-clock second.
    faults : FaultsConfig, optional
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
    """

    def __init__(self, firmware: ModbusDriveFirmware, *, device_id: int = 1, rtu: bool = False,
                 baudrate: int = 115200, parity: str = "E", stopbits: int = 1, time_scale: float = 1.0,
                 faults: FaultsConfig | None = None, seed: int = 0):
        self.firmware = firmware
        self.device_id = device_id
        self.rtu = rtu
        self.baudrate = baudrate
        self.parity = parity
        self.stopbits = stopbits
        self.time_scale = time_scale
        self.faults = faults or FaultsConfig()
        if self.faults.exception_register >= 0 and self.faults.exception_code not in set(ExcCodes):
            raise ConfigError("emulator.faults.exception_code",
                              f"{self.faults.exception_code} is not a Modbus exception code "
                              f"({', '.join(str(int(c)) for c in ExcCodes)})")
        self._rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        self.error: BaseException | None = None
        self.port = ""
        self.requests = 0
        self.dropped_responses = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: threading.Thread | None = None
        self._clock_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._server = None
        self._bridge: PtyBridge | None = None
        self._beat_at = time.monotonic()
        self._beat_task: asyncio.Task | None = None

    # --- lifecycle -------------------------------------------------------------------------

    def start(self) -> "ModbusDriveServer":
        if self.rtu:
            bits = 1 + 8 + (0 if self.parity == "N" else 1) + self.stopbits
            self._bridge = PtyBridge(self.baudrate, bits).start()
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

    async def _serve(self) -> None:
        device = SimDevice(id=self.device_id, simdata=_simdata(self.firmware.map), action=self._action)
        if self.rtu:
            self._server = ModbusSerialServer(
                device, framer=FramerType.RTU, port=self._bridge.device_path, baudrate=self.baudrate or 115200,
                parity="N", stopbits=self.stopbits, trace_packet=self._trace_packet,
            )
            await self._server.serve_forever(background=True)
            self.port = self._bridge.host_path
        else:
            self._server = ModbusTcpServer(device, address=("127.0.0.1", 0), trace_packet=self._trace_packet)
            await self._server.serve_forever(background=True)
            self.port = f"tcp://127.0.0.1:{self._server.transport.sockets[0].getsockname()[1]}"
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

    def close(self) -> None:
        """Stop the axis, the clock and the server; release the port."""
        self._stop.set()
        if self._clock_thread is not None:
            self._clock_thread.join(timeout=2.0)
        with self.lock:
            self.firmware.drive.disable()
        if self._loop is not None and self._loop.is_running():
            if self._beat_task is not None:
                self._loop.call_soon_threadsafe(self._beat_task.cancel)
            if self._server is not None:
                try:
                    asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(timeout=2.0)
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

    async def _action(self, function_code, start_address, address, count, registers, set_values):
        """Every request that passed pymodbus's address checks lands here."""
        self.requests += 1
        with self.lock:
            self.firmware.heard_from_host(time.monotonic())
        f = self.faults
        if f.exception_register >= 0 and address <= f.exception_register < address + count:
            return ExcCodes(f.exception_code)
        with self.lock:
            if set_values is None:
                result = self.firmware.read(address, count)
                if not isinstance(result, int):
                    registers[address - start_address : address - start_address + count] = result
                    result = None
            else:
                result = self.firmware.write(address, list(set_values))
        return ExcCodes(result) if result else None

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """Every frame in and out passes here: the place for slow and missing answers."""
        if not sending:
            return data
        if self.faults.response_delay_s:
            # a slow drive answers one request after the other: block this server's loop, so a
            # late answer never overtakes (or takes the transaction id of) the next request
            time.sleep(self.faults.response_delay_s)
        rate = self.faults.missing_response_rate
        if rate and self._rng.random() < rate:
            self.dropped_responses += 1
            return b""  # carried out, never answered
        return data

    # --- the drive's clock --------------------------------------------------------------------

    def _clock(self) -> None:
        fw = self.firmware
        loop_rate = fw.loop_rate_hz
        runs_seen = fw.runs
        origin = time.monotonic()
        at_origin = 0
        coast_left = 0
        coast_clock = origin
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                with self.lock:
                    listening = now - self._beat_at < _STALL_S + _BEAT_S  # else the silence may be ours
                    if listening and fw.watch_host(now):  # the host went silent: the drive stopped on its own
                        coast_left, coast_clock = int(_COAST_S * loop_rate), now
                    if fw.runs != runs_seen:  # a run was triggered since the last look
                        runs_seen = fw.runs
                        origin, at_origin = now, 0
                    if fw.running:
                        rate = fw.sample_rate_hz * self.time_scale
                        due = int((now - origin) * rate) - (fw.produced - at_origin)
                        cap = max(1, int(0.02 * rate))
                        if due > cap:  # fell behind (slow machine): resume from now, never burst
                            origin, at_origin, due = now, fw.produced, cap
                        fw.advance(due)
                        if not fw.running:
                            coast_left, coast_clock = int(_COAST_S * loop_rate), now
                    elif coast_left > 0:
                        n = min(coast_left, int((now - coast_clock) * loop_rate * self.time_scale))
                        if n > 0:
                            fw.idle(n)
                            coast_left -= n
                            coast_clock = now
                time.sleep(0.002)
        except BaseException as exc:  # keep the failure for the owner to see
            self.error = exc
            with self.lock:
                fw.drive.disable()


def start(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig,
          link: str | None = None) -> EmulatedDevice:
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
    firmware = ModbusDriveFirmware(drive, regmap, driver, cfg.faults.drive_fault_after_s,
                                   cfg.faults.capture_stops_after_s)
    baudrate = device.baudrate or driver.default_baudrate
    server = ModbusDriveServer(
        firmware, device_id=device.device_id, rtu=rtu, baudrate=baudrate, parity=device.parity,
        stopbits=device.stopbits, time_scale=cfg.time_scale, faults=cfg.faults, seed=cfg.seed + 1,
    ).start()
    # a pseudo-terminal carries no parity bit (some kernels refuse the setting): both ends open it
    # without one, while the bridge still times each character with the configured parity bit
    host = replace(device, port=server.port, baudrate=baudrate, parity="N") if rtu else replace(device, port=server.port)
    return EmulatedDevice(server=server, device=host, drive=drive)
