"""The emulated CANopen drive on a bus: its network, its clock and SYNC producer threads, and how a session
starts it.

:func:`start` runs the drive in-process on python-can's ``virtual`` bus;
:func:`start_socketcand` also serves that bus over the socketcand protocol on
127.0.0.1, for a host in another process (``hilident emulate canopen``).
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from dataclasses import replace

import can
from can.interfaces.virtual import VirtualBus, channels_lock

import canopen
from hilident.config.tables import DeviceConfig, EmulatorConfig
from hilident.drivers.description import DriverDescription
from hilident.emulator.canopen.firmware import CanopenDriveFirmware
from hilident.emulator.canopen.production import SyncProducer
from hilident.emulator.canopen.socketcand import SocketcandServer
from hilident.emulator.device import EmulatedDevice, build_drive
from hilident.errors import ConfigError

__all__ = ["CanopenDriveServer", "start", "start_socketcand"]

_channel_numbers = itertools.count(1)
_IDLE_S = 0.01  # how often a drive that produces no SYNC looks whether it should
_SLEEP_MAX_S = 0.05  # waits longer than this are cut so that close() is heard promptly


class CanopenDriveServer:
    """Runs a :class:`CanopenDriveFirmware` on a python-can bus: its network, its clock thread and its SYNC
    producer thread.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
    interface, channel : str
        python-can bus the node joins (``"virtual"`` and a channel name unique to it).
    """

    def __init__(self, firmware: CanopenDriveFirmware, interface: str = "virtual", channel: str = ""):
        self.firmware = firmware
        self.interface = interface
        self.channel = channel or f"hilident-canopen-{os.getpid()}-{next(_channel_numbers)}"
        self.network: canopen.Network | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._producer: threading.Thread | None = None
        self._error: BaseException | None = None
        self.extra: list = []  # other services sharing this drive's lifetime (a socketcand server)

    @property
    def error(self) -> BaseException | None:
        return self._error or self.firmware.error

    @property
    def path(self) -> str:
        return self.channel

    def start(self) -> CanopenDriveServer:
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1  # a short receive timeout: close() returns promptly
        network.connect(interface=self.interface, channel=self.channel, receive_own_messages=False)
        self.network = network
        self.firmware.attach(network)
        if network.notifier is None:
            raise RuntimeError(f"CAN network on {self.channel!r} connected without a notifier")
        network.notifier.add_listener(self.firmware.on_frame)
        self._thread = threading.Thread(target=self._clock, name="canopen-drive-clock", daemon=True)
        self._thread.start()
        self._producer = threading.Thread(target=self._produce, name="canopen-sync-producer", daemon=True)
        self._producer.start()
        return self

    def _clock(self) -> None:
        try:
            while not self._stop.wait(0.004):
                self.firmware.tick(time.monotonic())
        except BaseException as exc:
            self._error = exc
            self.firmware.drive.disable()

    def _produce(self) -> None:
        """The drive's SYNC production (:class:`~hilident.emulator.canopen.production.SyncProducer`) while 0x1005
        bit 30 and 0x1006 ask for it."""
        producer = self.firmware.producer
        try:
            while not self._stop.is_set():
                schedule = producer.schedule()
                if schedule[1]:
                    self._run_schedule(producer, schedule)
                else:
                    self._stop.wait(_IDLE_S)
        except BaseException as exc:
            self._error = exc
            self.firmware.drive.disable()

    def _run_schedule(self, producer: SyncProducer, schedule: tuple[int, float]) -> None:
        """SYNC instants ``t_j = t_start + j * period`` until production or its period changes: a deadline
        schedule (never drifts); an instant reached late is still produced, the next ones follow at once."""
        period = schedule[1]
        stamped = self._open_stamped()
        start, start_wall = time.perf_counter(), time.time()
        j = 0
        try:
            while not self._stop.is_set() and producer.schedule() == schedule:
                due = start + j * period
                wait = due - time.perf_counter()
                if wait > _SLEEP_MAX_S:
                    self._stop.wait(_SLEEP_MAX_S)
                    continue
                if wait > 0:
                    time.sleep(wait)
                producer.instant(time.perf_counter() - due, start_wall + j * period)
                j += 1
        finally:
            self.firmware.stamped_bus = None
            if stamped is not None:
                stamped.shutdown()

    def _open_stamped(self) -> can.BusABC | None:
        """On a virtual channel, a bus that sends with the timestamp given: the producer's SYNCs carry their
        instant on the drive's clock (on another interface the interface stamps them)."""
        if self.interface != "virtual":
            return None
        bus = TransmitOnlyVirtualBus(self.channel)
        self.firmware.stamped_bus = bus
        return bus

    def close(self) -> None:
        """Power stage off, threads stopped, bus released."""
        self._stop.set()
        for thread in (self._thread, self._producer):
            if thread is not None:
                thread.join(timeout=2.0)
        fw = self.firmware
        with fw.lock:
            fw.drive.disable()
        for service in self.extra:
            try:
                service.close()
            except Exception:
                pass
        try:
            fw.node.nmt.stop_heartbeat()
        except Exception:
            pass
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception:
                pass
            self.network = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()


def _firmware(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> CanopenDriveFirmware:
    if driver.transport != "canopen":
        raise ConfigError(
            "device.driver", f"driver {driver.name!r} is not a CANopen drive (transport {driver.transport!r})"
        )
    return CanopenDriveFirmware(
        build_drive(cfg, driver), driver, device.canopen.node_id, cfg.faults, cfg.time_scale, cfg.seed
    )


def start(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    """Start the emulated drive in-process on a virtual CAN bus of its own.

    Returns an :class:`~hilident.emulator.device.EmulatedDevice` whose ``device``
    reaches it: ``can_interface = "virtual"``, ``port`` = the channel name.
    """
    firmware = _firmware(cfg, driver, device)
    server = CanopenDriveServer(firmware).start()
    reach = replace(device, port=server.channel, canopen=replace(device.canopen, can_interface="virtual"))
    return EmulatedDevice(server=server, device=reach, drive=firmware.drive)


def start_socketcand(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig, port: int = 0, bus_name: str = "can0"
) -> EmulatedDevice:
    """Start the emulated drive and serve its bus over socketcand on 127.0.0.1.

    The host reaches it with ``can_interface = "socketcand"`` and ``port =
    "127.0.0.1:PORT/can0"`` (``EmulatedDevice.device`` holds exactly that).
    """
    firmware = _firmware(cfg, driver, device)
    server = CanopenDriveServer(firmware).start()
    try:
        bridge = SocketcandServer(server.channel, bus_name=bus_name, port=port).start()
    except BaseException:
        server.close()
        raise
    server.extra.append(bridge)
    reach = replace(device, port=bridge.address, canopen=replace(device.canopen, can_interface="socketcand"))
    return EmulatedDevice(server=server, device=reach, drive=firmware.drive)


class TransmitOnlyVirtualBus(VirtualBus):
    """A python-can virtual bus that sends with the timestamp each message carries and receives nothing.

    Every virtual bus of a channel gets a copy of every frame sent on it; one that never reads would keep them
    all (and copying them costs the interpreter's time at every frame), so this one takes itself off the
    channel's receivers while it is open.
    """

    def __init__(self, channel: str):
        super().__init__(channel=channel, preserve_timestamps=True)
        with channels_lock:
            self.channel.remove(self.queue)

    def shutdown(self) -> None:
        with channels_lock:
            self.channel.append(self.queue)  # VirtualBus.shutdown takes it off the channel
        super().shutdown()
