"""The CiA 402 drives of one session on one CANopen bus: one bus opened once, every node's adapter on it, the
nodes armed and stopped together.

``[device.canopen] node_ids`` lists the nodes (``node_id`` first). :meth:`NodeGroup.open` opens the bus once and
each node's :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` on it (identity checked, known state,
the node's heartbeat consumer armed), so every node gets the same checks a session of one node makes;
:meth:`NodeGroup.safe_stop` switches every node's power stage off, each whatever the others did; and
:meth:`NodeGroup.close` closes every node and then the bus. A node that fails to open closes the ones opened
before it and the bus.

What is not here yet: a run that streams every node's set-points on one SYNC (the session refuses several
nodes until it has one, :mod:`hilident.session.connection`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.adapters.canopen.link import open_network
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.config.tables import DeviceConfig, node_ids
from hilident.drivers.description import DriverDescription
from hilident.errors import DeviceError

__all__ = ["NodeGroup"]


class NodeGroup:
    """Several nodes of one driver on one bus, each with its adapter.

    Parameters
    ----------
    network : TracingNetwork
        The bus, opened once; the group releases it.
    adapters : list of CanopenDriveAdapter
        One per node, in the order of ``node_ids``, each on ``network``.

    Attributes
    ----------
    last_stop_s : float or None
        Wall time the last :meth:`safe_stop` took to switch every node off, s.
    """

    def __init__(self, network: TracingNetwork, adapters: list[CanopenDriveAdapter]):
        self.network = network
        self.adapters = adapters
        self.last_stop_s: float | None = None

    @classmethod
    def open(cls, device: DeviceConfig, driver: DriverDescription) -> NodeGroup:
        """Open the bus of ``device`` once and every node of ``node_ids`` on it.

        Raises
        ------
        DeviceError, ConfigError
            As :meth:`CanopenDriveAdapter.open_device` for the node that failed (its message names it); the
            nodes opened before it are closed and the bus released.
        """
        label = f"{device.canopen.can_interface}:{device.port}"
        network = open_network(device, driver.default_baudrate, label)
        adapters: list[CanopenDriveAdapter] = []
        try:
            for node in node_ids(device):
                one = replace(device, canopen=replace(device.canopen, node_id=node))
                adapters.append(CanopenDriveAdapter.open_device(one, driver, network=network))
        except BaseException:
            cls(network, adapters).close()
            raise
        return cls(network, adapters)

    @property
    def node_ids(self) -> list[int]:
        return [a.node_id for a in self.adapters]

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """The same ``[limits]`` on every node (:meth:`CanopenDriveAdapter.set_limits`)."""
        for adapter in self.adapters:
            adapter.set_limits(torque_nm, velocity_mps, position_min_m, position_max_m)

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[list[str]]:
        """Every node configured for a run (:meth:`CanopenDriveAdapter.configure`); each node's channels."""
        return [adapter.configure(sample_rate_hz, mode, channels) for adapter in self.adapters]

    def enable(self) -> None:
        """Every node to Operation Enabled, in order; if one fails, every node is switched off again.

        Raises
        ------
        DeviceError
            The node that did not reach Operation Enabled (its message names it).
        """
        try:
            for adapter in self.adapters:
                adapter.enable()
        except BaseException:
            self.safe_stop()
            raise

    def safe_stop(self) -> None:
        """Every node's power stage off now (Disable Voltage), each whatever the others did. Never raises."""
        started = time.perf_counter()
        for adapter in self.adapters:
            with contextlib.suppress(Exception):
                adapter.safe_stop()
        self.last_stop_s = time.perf_counter() - started

    def close(self) -> None:
        """Every node stopped and closed (its heartbeat consumer off, NMT Pre-operational), then the bus
        released. Never raises."""
        self.safe_stop()  # every node off first: closing one node (its SDO writes, NMT) would delay the next's stop
        for adapter in self.adapters:
            with contextlib.suppress(Exception):
                adapter.close()
        with contextlib.suppress(Exception):
            self.network.stop_trace()
        with contextlib.suppress(Exception):
            self.network.disconnect()

    def states(self) -> dict[int, str]:
        """Each node's CiA 402 state, by node id (``"unreadable"`` where the node does not answer)."""
        out = {}
        for adapter in self.adapters:
            try:
                out[adapter.node_id] = adapter.drive_state().value
            except DeviceError:
                out[adapter.node_id] = "unreadable"
        return out
