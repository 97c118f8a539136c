"""The session's device connection: the device of ``[device]`` opened (or the embedded emulator started and
opened like one), with its lock, as ``hilident run`` and ``hilident upload`` share it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hilident import endings
from hilident.adapters.backends import adapter_class
from hilident.config.tables import Config, node_ids
from hilident.drivers.description import DriverDescription, find_driver
from hilident.progress import Progress
from hilident.session.devicelock import DeviceLock, DeviceLocks, device_key

if TYPE_CHECKING:
    from hilident.adapters.base import DeviceAdapter


@dataclass(frozen=True)
class ConnectedDevice:
    """An open device, complete: its driver, the adapter talking to it, and what was started or taken to reach
    it (the embedded emulator, the device lock). Made by :func:`connect_device`."""

    driver: DriverDescription
    adapter: DeviceAdapter
    emulator: Any = None
    lock: DeviceLock | DeviceLocks | None = None

    def safe_stop(self) -> None:
        """Command the axis safe now (first thing on every ending). Never raises."""
        try:
            self.adapter.safe_stop()
        except Exception:
            pass

    def close(self) -> None:
        """Stop the axis and release the device (and the emulator, and the device lock)."""
        try:
            self.adapter.close()
        finally:
            try:
                if self.emulator is not None:
                    self.emulator.close()
            finally:
                if self.lock is not None:
                    self.lock.release()


def connect_device(cfg: Config, driver: DriverDescription, progress: Progress) -> ConnectedDevice:
    """Open the device of ``[device]`` (taking its lock), or start the embedded emulator and open it like one.

    The adapter brings the device to a known state as it opens (stale frames
    discarded, axis stopped, latched faults reported and cleared only when
    allowed). The lock and the emulator are released again when opening fails.
    """
    cls = adapter_class(driver.transport)
    nodes = node_ids(cfg.device) if driver.transport == "canopen" else [cfg.device.canopen.node_id]
    device, link, emulator, lock = cfg.device, None, None, None
    if cfg.uses_emulator:
        from hilident.emulator.factory import start_emulator

        emulator = start_emulator(cfg.emulator, driver, cfg.device)
        device, link = emulator.device, emulator.link
    else:
        d = cfg.device
        lock = DeviceLocks(
            [
                device_key(
                    driver.transport,
                    d.port,
                    node_id=node,
                    device_id=d.modbus.device_id,
                    can_interface=d.canopen.can_interface,
                )
                for node in nodes
            ]
        ).acquire()
        if lock.recovered_from:
            progress.step(f"device lock of pid {lock.recovered_from} recovered (that session died)")
    adapter: Any  # a NodeGroup stands for the adapter where it records (hilident.session.nodes_run)
    try:
        if len(nodes) > 1:
            from hilident.adapters.canopen.group import NodeGroup

            adapter = NodeGroup.open(device, driver)
        else:
            adapter = cls.open_device(device, driver, link=link)
    except BaseException:
        with endings.shielded():
            _release(emulator, lock)
        raise
    return ConnectedDevice(driver, adapter, emulator, lock)


def _release(emulator, lock: DeviceLock | DeviceLocks | None) -> None:
    """Stop an emulator and release a lock of a device that did not open."""
    try:
        if emulator is not None:
            emulator.close()
    finally:
        if lock is not None:
            lock.release()


def connect_warnings(report_) -> list[str]:
    """What :attr:`AdapterBase.connect_report` found, as the session's warnings."""
    out = []
    if report_.discarded_frames:
        out.append(f"connect: {report_.discarded_frames} frame(s) left over from an earlier session were discarded")
    if report_.faults:
        out.append(
            f"connect: the device had latched fault(s): {'; '.join(report_.faults)}"
            + ("; cleared (allow_fault_reset)" if report_.faults_cleared else "")
        )
    return out + [f"connect: {w}" for w in report_.warnings]


class DeviceConnection:
    """A device opened as ``[device]`` says (or the embedded emulator), one session per device.

    What ``hilident run`` and ``hilident upload`` share: the subclass sets
    ``cfg``, ``progress`` and ``warnings`` and may set ``driver``;
    :meth:`open_device` makes :attr:`device` (a :class:`ConnectedDevice`);
    ``adapter``, ``emulator`` and ``lock`` are its parts (None until then).
    """

    cfg: Config
    progress: Progress
    warnings: list[str]
    driver: DriverDescription | None = None
    device: ConnectedDevice | None = None

    @property
    def found_driver(self) -> DriverDescription:
        """The driver description, once :meth:`open_device` (or :meth:`Session.prepare`) found it.

        Raises
        ------
        RuntimeError
            Asked before the driver was looked up (a caller's mistake).
        """
        if self.driver is None:
            raise RuntimeError("the driver is looked up by open_device() or prepare() first")
        return self.driver

    @property
    def adapter(self):
        """The open device's adapter (None before :meth:`open_device`)."""
        return self.device.adapter if self.device is not None else None

    @property
    def emulator(self):
        """The embedded emulator (None on a real port, or before :meth:`open_device`)."""
        return self.device.emulator if self.device is not None else None

    @property
    def lock(self) -> DeviceLock | DeviceLocks | None:
        """The device lock (None for the emulator, or before :meth:`open_device`)."""
        return self.device.lock if self.device is not None else None

    def open_device(self) -> ConnectedDevice:
        """Open the device (taking its lock), or start the embedded emulator and open it like a device.

        What the adapter found as it brought the device to a known state goes to ``warnings``.
        """
        driver = self.driver = self.driver or find_driver(self.cfg.device.driver, self.cfg.device.driver_paths)
        self.device = connect_device(self.cfg, driver, self.progress)
        where = "emulated" if self.cfg.uses_emulator else "connected to"
        self.progress.step(f"{where} {self.adapter.identity.name} on {self.adapter.port}")
        report_ = getattr(self.adapter, "connect_report", None)
        if report_ is not None:
            self.warnings += connect_warnings(report_)
        return self.device

    def safe_stop(self) -> None:
        """Command the axis safe now (first thing on every ending). Never raises."""
        if self.device is not None:
            self.device.safe_stop()

    def close(self) -> None:
        """Stop the axis and release the device (and the emulator, and the device lock)."""
        if self.device is not None:
            self.device.close()
