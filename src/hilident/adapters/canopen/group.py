"""The CiA 402 drives of one session on one CANopen bus: one bus opened once, every node's adapter on it, the
nodes armed and stopped together.

``[device.canopen] node_ids`` lists the nodes (``node_id`` first). :meth:`NodeGroup.open` opens the bus once and
each node's :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` on it (identity checked, known state,
the node's heartbeat consumer armed, all watching the one host heartbeat the nodes share), so every node gets
the same checks a session of one node makes;
:meth:`NodeGroup.safe_stop` switches every node's power stage off, each whatever the others did; and
:meth:`NodeGroup.close` closes every node and then the bus. A node that fails to open closes the ones opened
before it and the bus.

:meth:`NodeGroup.configure` and :meth:`NodeGroup.stream` play one run on every node at once, each node's
set-points a column of the excitation, on one SYNC (:mod:`~hilident.adapters.canopen.group_stream`); the
recording's channels are every node's, named ``<channel>_node<id>`` (:func:`node_channel`). So a group stands
where a session's one adapter stands for recording: ``configure``, ``stream``, ``sample_rate_hz``,
``channel_units``, ``identity``, ``port``, ``events``, ``last_result``, ``safe_stop`` and ``close``.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from hilident.adapters.base import Deliver, RunResult
from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.adapters.canopen.group_stream import GroupStreamedRun
from hilident.adapters.canopen.link import open_network
from hilident.adapters.canopen.net import HostHeartbeat
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.adapters.host_timing import timely_host
from hilident.config.tables import DeviceConfig, node_ids
from hilident.drivers.description import DriverDescription
from hilident.errors import DataError, DeviceError

__all__ = ["NodeGroup", "node_channel"]


def node_channel(name: str, node_id: int) -> str:
    """The recording's name of node ``node_id``'s channel ``name`` (``torque_nm`` of node 2:
    ``torque_nm_node2``)."""
    return f"{name}_node{node_id}"


class _NodeEvents(list):
    """A node's events of one run, each also appended to the group's (in the order they happened, the message
    naming the node)."""

    def __init__(self, shared: list[dict], node_id: int):
        super().__init__()
        self.shared = shared
        self.node_id = node_id

    def append(self, entry: dict) -> None:
        super().append(entry)
        self.shared.append({**entry, "message": f"node {self.node_id}: {entry['message']}"})


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
    events : list of dict
        The last run's events of every node, in the order they happened, each message naming its node.
    last_result : RunResult or None
        The last run's: the joint rows as its samples, every node's counters added, the first node's clock.
    """

    def __init__(self, network: TracingNetwork, adapters: list[CanopenDriveAdapter]):
        self.network = network
        self.adapters = adapters
        self.last_stop_s: float | None = None
        self.events: list[dict] = []
        self.last_result: RunResult | None = None
        first = adapters[0] if adapters else None
        self.port = first.port.rsplit(" node ", 1)[0] if first is not None else ""

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
        heartbeat = HostHeartbeat(network, label)  # one host on the bus: one heartbeat every node's consumer watches
        adapters: list[CanopenDriveAdapter] = []
        try:
            for node in node_ids(device):
                one = replace(device, canopen=replace(device.canopen, node_id=node))
                adapters.append(CanopenDriveAdapter.open_device(one, driver, network=network, heartbeat=heartbeat))
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

    @property
    def identity(self):
        """The first node's identity, named for the group (``<name> x2 (nodes 1, 2)``)."""
        first = self.adapters[0].drive_identity()
        return replace(first, name=f"{first.name} x{len(self.adapters)} (nodes {', '.join(map(str, self.node_ids))})")

    @property
    def sample_rate_hz(self) -> float:
        """The run's sample rate (every node's), Hz."""
        return self.adapters[0].sample_rate_hz

    @property
    def channel_units(self) -> list[str]:
        """Every node's channel units, in the order of :meth:`configure`'s names."""
        return [unit for adapter in self.adapters for unit in adapter.channel_units]

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Every node configured for a host-streamed run (:meth:`CanopenDriveAdapter.configure`); the run's
        channels, every node's in node order, named by :func:`node_channel`. With ``device.acquisition = "auto"``
        the nodes stream whatever their driver's default.

        Raises
        ------
        DeviceError
            A node plays runs another way than host-streamed (``device.acquisition``, or its driver's default):
            one SYNC for every node is the host's or the first node's.
        """
        names = []
        for adapter in self.adapters:
            if adapter.device.acquisition == "auto":
                adapter.acquisition = "streamed"  # the driver's default may be its own buffer, one clock per node
            if adapter.acquisition != "streamed":
                raise DeviceError(
                    f"{adapter.port}: plays runs {adapter.acquisition!r} (device.acquisition or its driver's "
                    'default); several nodes run host-streamed, on one SYNC: set device.acquisition = "streamed"'
                )
            names += [node_channel(c, adapter.node_id) for c in adapter.configure(sample_rate_hz, mode, channels)]
        return names

    def set_trace(self, path) -> None:
        """A CAN trace of the next run (the bus's, every node's frames) to ``path``."""
        self.adapters[0].set_trace(path)

    def set_excitation_recipe(self, recipe: dict | None) -> None:
        """Nothing to keep: every node plays the samples it is sent."""

    def stream(
        self,
        excitation: np.ndarray,
        sink: Deliver,
        progress: Callable[[float], None] | None = None,
    ) -> RunResult:
        """Play every node's column of ``excitation`` on one SYNC; pass the joint ``(sample_index, rows)`` to
        ``sink`` (every node's channels side by side). Every node is switched off on every ending.

        Raises
        ------
        DataError
            ``excitation`` is not a finite array with one column per node.
        LimitTrip, DeviceError
            A node's fault (the first), after every node was switched off; its message names the node.
        Exception
            Whatever ``sink`` raised, after every node was switched off.
        """
        x = np.asarray(excitation, dtype=float)
        if x.ndim != 2 or x.shape[1] != len(self.adapters) or not np.all(np.isfinite(x)):
            raise DataError(f"the excitation of {len(self.adapters)} nodes must be a finite array of as many columns")
        self.events = []
        self.last_result = None
        for adapter, column in zip(self.adapters, x.T, strict=True):
            adapter.open_run(np.ascontiguousarray(column))
            adapter.events = _NodeEvents(self.events, adapter.node_id)
        from_sink: list[BaseException] = []
        run = GroupStreamedRun(self.adapters, x, sink, from_sink, progress)
        try:
            with timely_host():
                run.run()
        except BaseException as exc:
            if any(exc is e for e in from_sink):
                raise
            raise self._first_cause(exc) from None
        finally:
            self.safe_stop()
            for adapter in self.adapters:
                if adapter.last_result is not None:
                    with contextlib.suppress(Exception):
                        adapter.close_run(adapter.last_result)
            self.last_result = self._result(run, len(x))
        for adapter in self.adapters:
            if adapter.run_fault is not None:
                raise adapter.fault_error(adapter.run_fault) from None
        return self.last_result

    def _first_cause(self, exc: BaseException) -> BaseException:
        """The error a run of the group that raised ``exc`` ends with: a node's first fault, else ``exc`` as the
        node that raised it would name it."""
        for adapter in self.adapters:
            first = adapter.first_cause(exc)
            if first is not exc:
                return first
        return exc

    def _result(self, run: GroupStreamedRun, n: int) -> RunResult:
        """The group's result of ``run``: every node's counters added, the first node's clock with the nodes."""
        results = [a.last_result for a in self.adapters]
        lead = results[0]
        clock = dict(lead.clock, nodes=self.node_ids) if lead is not None and lead.clock is not None else None
        faults = [r.fault for r in results if r is not None and r.fault]
        return RunResult(
            requested_samples=n,
            stats=run.stats(),
            events=list(self.events),
            fault=faults[0] if faults else None,
            completed=all(r is not None and r.completed for r in results),
            clock=clock,
        )

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
