"""The emulated CANopen drive on a bus: its network, its clock and SYNC producer threads, and how a session
starts it.

:func:`start` runs the drive in-process on python-can's ``virtual`` bus;
:func:`start_socketcand` also serves that bus over the socketcand protocol on
127.0.0.1, for a host in another process (``hilident emulate canopen``).

**Several nodes on one mechanism** (``[device.canopen] node_ids`` and
``[emulator.mechanism]``): one :class:`~hilident.emulator.coupled_plant.CoupledPlant`,
one drive and one :class:`CanopenDriveServer` per node, all on one virtual
channel (one bus for the host), run by a :class:`CanopenBusServer`. The nodes'
loops step the mechanism in lockstep, and every node keeps stepping while the
server runs, as a drive's loop reads its encoder whether enabled or not.
:mod:`~hilident.emulator.canopen.mechanism` keeps their steps on the same
ticks of the mechanism. On :meth:`CanopenBusServer.close` every node is
switched off (Switch On Disabled, torque 0) and its port detached.
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
from hilident.config.tables import DeviceConfig, EmulatorConfig, node_ids
from hilident.drivers.description import DriverDescription
from hilident.emulator.canopen.firmware import CanopenDriveFirmware
from hilident.emulator.canopen.mechanism import LockstepDrive, MechanismGroup, NodeOnMechanism
from hilident.emulator.canopen.production import SyncProducer
from hilident.emulator.canopen.socketcand import SocketcandServer
from hilident.emulator.coupled_plant import CoupledPlant, PlantPort
from hilident.emulator.device import EmulatedDevice, build_drive, build_port_drive, mechanism_model
from hilident.errors import ConfigError
from hilident.protocol import cia402

__all__ = ["CanopenBusServer", "CanopenDriveServer", "start", "start_socketcand"]

_channel_numbers = itertools.count(1)
_IDLE_S = 0.01  # how often a drive that produces no SYNC looks whether it should
_SLEEP_MAX_S = 0.05  # waits longer than this are cut so that close() is heard promptly


#: The tag of a run that belongs to no SYNC (idling on the wall clock, a table): before every SYNC.
class CanopenDriveServer:
    """Runs a :class:`CanopenDriveFirmware` on a python-can bus: its network, its clock thread and its SYNC
    producer thread.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
    interface, channel : str
        python-can bus the node joins (``"virtual"`` and a channel name unique to it, or shared by the nodes of
        one bus).
    mechanism : NodeOnMechanism, optional
        For a node on a mechanism (:class:`MechanismGroup`): its steps at SYNCs and on the wall clock.
    """

    def __init__(
        self,
        firmware: CanopenDriveFirmware,
        interface: str = "virtual",
        channel: str = "",
        mechanism: NodeOnMechanism | None = None,
    ):
        self.firmware = firmware
        self.mechanism = mechanism
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
        if self.mechanism is not None:  # every SYNC steps the node, cycles or not
            network.unsubscribe(0x80)
            network.subscribe(0x80, self.firmware.guarded(self.mechanism.on_sync))
        self._thread = threading.Thread(target=self._clock, name="canopen-drive-clock", daemon=True)
        self._thread.start()
        self._producer = threading.Thread(target=self._produce, name="canopen-sync-producer", daemon=True)
        self._producer.start()
        return self

    def _clock(self) -> None:
        fw, mechanism = self.firmware, self.mechanism
        try:
            while not self._stop.wait(0.004):
                now = time.monotonic()
                fw.tick(now)
                if mechanism is not None:
                    mechanism.idle(now)
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
                if self.mechanism is not None:
                    self.mechanism.instant(producer, time.perf_counter() - due, start_wall + j * period)
                else:
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


def _check_transport(driver: DriverDescription) -> None:
    if driver.transport != "canopen":
        raise ConfigError(
            "device.driver", f"driver {driver.name!r} is not a CANopen drive (transport {driver.transport!r})"
        )


def _firmware(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> CanopenDriveFirmware:
    _check_transport(driver)
    return CanopenDriveFirmware(
        build_drive(cfg, driver), driver, device.canopen.node_id, cfg.faults, cfg.time_scale, cfg.seed
    )


def _nodes_on_mechanism(cfg: EmulatorConfig, device: DeviceConfig) -> list[int]:
    """The node ids the mechanism's motors belong to, in order; refused where they do not match."""
    nodes = node_ids(device)
    if not cfg.mechanism.defined:
        raise ConfigError("emulator.mechanism", f"is required for the twin of {len(nodes)} nodes {nodes}")
    if len(cfg.mechanism.motors) != len(nodes):
        raise ConfigError(
            "emulator.mechanism.motors",
            f"has {len(cfg.mechanism.motors)} motors for {len(nodes)} nodes {nodes}: one per node, in node order",
        )
    return nodes


def _servers_on_mechanism(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig
) -> tuple[list[CanopenDriveServer], MechanismGroup]:
    """One drive, firmware and server per node, on the ports of one mechanism (servers not started yet).

    Each firmware powers up on its port alone (its port then leaves the lockstep until its server runs it): a
    node that has not started does not hold the others.
    """
    _check_transport(driver)
    nodes = _nodes_on_mechanism(cfg, device)
    plant = CoupledPlant(mechanism_model(cfg))
    channel = f"hilident-canopen-{os.getpid()}-{next(_channel_numbers)}"
    firmwares: list[CanopenDriveFirmware] = []
    drives: list[LockstepDrive] = []
    for i, node in enumerate(nodes):
        drive = build_port_drive(cfg, driver, plant.port(i), loop=LockstepDrive)
        firmwares.append(CanopenDriveFirmware(drive, driver, node, cfg.faults, cfg.time_scale, cfg.seed + i))
        plant.port(i).detach()
        drives.append(drive)
    group = MechanismGroup(plant, driver.loop_rate_hz, cfg.time_scale)
    group.members = firmwares
    servers = []
    for fw, drive in zip(firmwares, drives, strict=True):
        drive.group = group
        servers.append(CanopenDriveServer(fw, channel=channel, mechanism=NodeOnMechanism(fw, drive, group)))
    return servers, group


def _start_bus(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> CanopenBusServer:
    servers, group = _servers_on_mechanism(cfg, driver, device)
    return CanopenBusServer(servers, group).start()


def _emulated(server: CanopenDriveServer | CanopenBusServer, reach: DeviceConfig) -> EmulatedDevice:
    if isinstance(server, CanopenBusServer):
        drives = tuple(s.firmware.drive for s in server.servers)
        return EmulatedDevice(server=server, device=reach, drive=drives[0], drives=drives, mechanism=server.plant)
    return EmulatedDevice(server=server, device=reach, drive=server.firmware.drive)


def _start_server(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig
) -> CanopenDriveServer | CanopenBusServer:
    """The drive's server, started: one node, or every node of ``node_ids`` on its mechanism."""
    if cfg.mechanism.defined or len(node_ids(device)) > 1:
        return _start_bus(cfg, driver, device)
    return CanopenDriveServer(_firmware(cfg, driver, device)).start()


def start(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    """Start the emulated drive in-process on a virtual CAN bus of its own.

    With ``[emulator.mechanism]`` (and ``[device.canopen] node_ids``), every node of the session on that bus,
    driving the mechanism together (:class:`CanopenBusServer`).

    Returns an :class:`~hilident.emulator.device.EmulatedDevice` whose ``device``
    reaches it: ``can_interface = "virtual"``, ``port`` = the channel name.
    """
    server = _start_server(cfg, driver, device)
    reach = replace(device, port=server.channel, canopen=replace(device.canopen, can_interface="virtual"))
    return _emulated(server, reach)


def start_socketcand(
    cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig, port: int = 0, bus_name: str = "can0"
) -> EmulatedDevice:
    """Start the emulated drive (or every node on its mechanism) and serve its bus over socketcand on 127.0.0.1.

    The host reaches it with ``can_interface = "socketcand"`` and ``port =
    "127.0.0.1:PORT/can0"`` (``EmulatedDevice.device`` holds exactly that).
    """
    server = _start_server(cfg, driver, device)
    try:
        bridge = SocketcandServer(server.channel, bus_name=bus_name, port=port).start()
    except BaseException:
        server.close()
        raise
    server.extra.append(bridge)
    reach = replace(device, port=bridge.address, canopen=replace(device.canopen, can_interface="socketcand"))
    return _emulated(server, reach)


class CanopenBusServer:
    """The nodes of one mechanism on one virtual bus: a :class:`CanopenDriveServer` each, run and closed together.

    Parameters
    ----------
    servers : list of CanopenDriveServer
        One per node, in node order, all on one channel.
    group : MechanismGroup

    Attributes
    ----------
    plant : CoupledPlant
        The mechanism.
    extra : list
        Services sharing the bus's lifetime (a socketcand server).
    """

    def __init__(self, servers: list[CanopenDriveServer], group: MechanismGroup):
        self.servers = servers
        self.group = group
        self.plant = group.plant
        self.extra: list = []

    @property
    def channel(self) -> str:
        return self.servers[0].channel

    @property
    def path(self) -> str:
        return self.channel

    @property
    def firmware(self) -> CanopenDriveFirmware:
        """The first node's firmware."""
        return self.servers[0].firmware

    @property
    def firmwares(self) -> list[CanopenDriveFirmware]:
        return [s.firmware for s in self.servers]

    @property
    def error(self) -> BaseException | None:
        return next((s.error for s in self.servers if s.error is not None), None)

    def start(self) -> CanopenBusServer:
        try:
            for server in self.servers:
                server.start()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Every node switched off (Switch On Disabled, torque 0) and out of the lockstep, threads stopped, bus
        released."""
        self.group.closing = True
        ports = [s.firmware.drive.plant for s in self.servers]
        for port in ports:
            if isinstance(port, PlantPort):
                port.detach()  # a run under way ends alone (LockstepDrive.run detaches it again)
        for server in self.servers:
            server._stop.set()
        for server in self.servers:
            server.close()
            fw = server.firmware
            with fw.lock:
                fw.power_off()
                fw.state = cia402.State.SWITCH_ON_DISABLED
        for port in ports:
            if isinstance(port, PlantPort):
                port.detach()
        for service in self.extra:
            try:
                service.close()
            except Exception:
                pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()


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
