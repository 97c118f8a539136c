"""NMT, heartbeats and emergencies for the CANopen adapter: the device-side net and the drive watched.

Two parts :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` owns: :class:`NetWatch` (its
``net``): NMT commands, the drive's heartbeat consumer armed to watch the host (the device-side net), the
drive's heartbeat or node guarding watched by the host, and emergencies queued as they arrive; and
:class:`HostHeartbeat` (``net.heartbeat``), the host's heartbeat, which the object access
(:class:`~hilident.adapters.canopen.sdo.SdoAccess`) also sends when it is due.
"""

from __future__ import annotations

import collections
import contextlib
import math
import time

import can
from canopen.emcy import EmcyError

import canopen
from hilident.adapters.canopen.common import (
    _GUARD_TIME,
    _LIFE_TIME_FACTOR,
    _NMT_OPERATIONAL,
    _TPDO_BASES,
    LIMIT_TRIP_CODES,
    Emergency,
)
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.errors import DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    ABORT_CONNECTION_INDEX,
    ABORT_CONNECTION_OPTIONS,
    HEARTBEAT_CONSUMER_INDEX,
    CanopenDescription,
    consumer_entry,
    parse_consumer_entry,
)
from hilident.protocol.canopen_types import ObjectAddress


class HostHeartbeat:
    """The host's heartbeat: COB-ID 0x700 + host node id, state Operational, once a period.

    python-can's cyclic sender produces it from a daemon thread: it dies with
    the process, which is the point. On a loaded machine that thread can wait
    for the interpreter longer than the drive's consumer time while the thread
    talking to the drive keeps running; :meth:`beat_if_due` sends the heartbeat
    from there, which is just as true.

    Parameters
    ----------
    network : TracingNetwork
        The bus the heartbeat goes out on.
    port : str
        Where the drive is; used in messages.

    Attributes
    ----------
    task : can.broadcastmanager.ThreadBasedCyclicSendTask or None
        The cyclic sender while the heartbeat is produced, else None.
    """

    def __init__(self, network: TracingNetwork, port: str):
        self.network = network
        self.port = port
        self.task: can.broadcastmanager.ThreadBasedCyclicSendTask | None = None
        self._frame = (0, 0.0)  # (COB-ID, period s)
        self._sent_s = 0.0  # when the heartbeat last went out (monotonic s)

    def start(self, host: int, period_s: float) -> None:
        """Produce the heartbeat of node ``host`` every ``period_s`` seconds; the first frame goes out at once.

        Already produced at that period (the heartbeat several nodes of one bus share): nothing changes, as the
        host is one node whatever the number of drives watching it.
        """
        if self.task is not None and self._frame == (0x700 + host, period_s):
            return
        self.stop()
        bus = self.network.bus
        if bus is None:
            raise DeviceError(f"{self.port}: the CAN bus is not open: the host's heartbeat cannot be sent")
        msg = can.Message(arbitration_id=0x700 + host, data=[_NMT_OPERATIONAL], is_extended_id=False)
        self._frame = (msg.arbitration_id, period_s)
        self._sent_s = time.monotonic()
        self.task = can.broadcastmanager.ThreadBasedCyclicSendTask(
            bus, self.network.send_lock, msg, period_s, on_error=lambda exc: False, modifier_callback=self._on_beat
        )

    def _on_beat(self, msg: can.Message) -> None:
        self._sent_s = time.monotonic()

    def beat_if_due(self) -> None:
        """Send the heartbeat from this thread when the cyclic sender is a period late."""
        if self.task is None or time.monotonic() - self._sent_s < self._frame[1]:
            return
        self._sent_s = time.monotonic()
        with contextlib.suppress(can.CanError, OSError):
            self.network.send_message(self._frame[0], bytes([_NMT_OPERATIONAL]))

    def stop(self) -> None:
        """No more heartbeats (the drive's consumer, if still armed, takes the host for dead)."""
        task, self.task = self.task, None
        if task is not None:
            with contextlib.suppress(Exception):
                task.stop()


class NetWatch:
    """The NMT and heartbeat part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` (its ``net``).

    The host heartbeat and the drive's consumer watching it, the drive's heartbeat or
    node guarding watched by the host, NMT commands, and emergencies as run events.

    Parameters
    ----------
    network : TracingNetwork
        The bus (frames counted at connect).
    sdo : SdoAccess
        The drive's objects (heartbeat, guarding, consumer and abort option objects).
    heartbeat : HostHeartbeat
        The host's heartbeat, started when the device-side net is armed.
    desc : CanopenDescription
        The drive's objects, its EDS file name and its heartbeat, host node and abort option settings.
    port : str
        Where the drive is; used in messages.
    host_timeout_s : float
        How long the drive waits for the host's heartbeat before it stops on its own
        (``[device] host_timeout_s``), s.

    Attributes
    ----------
    emergencies : collections.deque of Emergency
        Emergencies as received, oldest first, until the adapter takes them.
    heartbeat_s : float or None
        When the drive's last heartbeat (or node guarding answer) arrived (monotonic s); None: none yet.
    heartbeat_state : int or None
        The NMT state that heartbeat carried.
    guarding : bool
        The host guards the drive (its EDS has no 0x1017): node guarding requests go out.
    """

    def __init__(
        self,
        network: TracingNetwork,
        sdo: SdoAccess,
        heartbeat: HostHeartbeat,
        desc: CanopenDescription,
        port: str,
        host_timeout_s: float,
    ):
        self.network = network
        self.sdo = sdo
        self.node = sdo.node
        self.heartbeat = heartbeat
        self.desc = desc
        self.port = port
        self.host_timeout_s = host_timeout_s
        self.emergencies: collections.deque[Emergency] = collections.deque()
        self.heartbeat_s: float | None = None
        self.heartbeat_state: int | None = None
        self.guarding = False
        self._consumer: ObjectAddress | None = None  # the 0x1016 entry watching the host
        self._nmt_settled_s = 0.0  # heartbeats before this may still carry the NMT state before our last command
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)

    # --- the known state at connect, the device-side net ---------------------------------------------

    def count_early_frames(self, node_id: int) -> _FrameCounter:
        """Count the TPDOs of node ``node_id`` that arrive while the host has configured nothing."""
        return _FrameCounter(self.network, [base + node_id for base in _TPDO_BASES])

    def watch_drive_heartbeat(self, timeout_s: float) -> None:
        """Ask for the drive's heartbeat (0x1017) or start node guarding, then wait for the first beat.

        Raises
        ------
        DeviceError
            The EDS has neither, or no beat comes within ``timeout_s`` (or three heartbeat periods).
        """
        d = self.desc
        od = self.node.object_dictionary
        if d.has("heartbeat_time"):
            self.sdo.write("heartbeat_time", d.heartbeat_ms)
            how = f"setting {self.sdo.describe(d.address('heartbeat_time'))} to {d.heartbeat_ms} ms"
        elif _GUARD_TIME in od and _LIFE_TIME_FACTOR in od:
            self._start_node_guarding()
            how = f"starting node guarding every {d.heartbeat_ms} ms (the EDS has no 0x1017)"
        else:
            raise DeviceError(
                f"{self.port}: the EDS {d.eds} has neither a producer heartbeat time (0x1017) nor "
                "node guarding (0x100C, 0x100D): hilident watches the drive by one of them"
            )
        deadline = time.monotonic() + max(timeout_s, 3 * d.heartbeat_ms / 1000.0)
        while self.heartbeat_s is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if self.heartbeat_s is None:
            raise DeviceError(f"{self.port}: no heartbeat within {timeout_s:g} s after {how}")

    def arm_device_net(self) -> str:
        """Produce the host's heartbeat and have the drive watch it (0x1016, 0x6007 when the EDS has them).

        Returns
        -------
        str
            The net as ``connect_report.device_net`` states it (what watches the host, and what the drive
            does when the host goes silent), or why there is none.
        """
        od = self.node.object_dictionary
        guarding = ""
        if self.guarding:
            guard = int(self.sdo.read_object(ObjectAddress(_GUARD_TIME, 0)))
            factor = int(self.sdo.read_object(ObjectAddress(_LIFE_TIME_FACTOR, 0)))
            guarding = f"life guarding 0x100C x 0x100D: {guard} ms x {factor}; "
        if HEARTBEAT_CONSUMER_INDEX not in od and guarding:
            net = guarding.rstrip("; ")
            if ABORT_CONNECTION_INDEX in od:
                option = self.desc.abort_connection_option
                self.sdo.write_object(ObjectAddress(ABORT_CONNECTION_INDEX, 0), option)
                net += f"; 0x6007 = {option} ({ABORT_CONNECTION_OPTIONS[option]})"
            return net
        if HEARTBEAT_CONSUMER_INDEX not in od:
            return (
                f"none: {self.desc.eds} has no heartbeat consumer (0x1016); the drive "
                "does not stop on its own when the host dies"
            )
        host = self.desc.host_node_id
        time_ms = max(1, min(0xFFFF, round(self.host_timeout_s * 1000)))
        period_s = time_ms / 3000.0
        entry = self._consumer_entry_for(host)
        self.sdo.write_object(entry, consumer_entry(host, time_ms))
        self._consumer = entry
        # after the entry: the task's first frame goes out at once and starts the drive's monitoring
        # (CiA 301: a consumer watches from the first heartbeat it receives)
        self.heartbeat.start(host, period_s)
        net = (
            f"{guarding}heartbeat consumer {entry}: host node {host}, {time_ms} ms "
            f"(host heartbeat every {period_s * 1e3:.0f} ms)"
        )
        if ABORT_CONNECTION_INDEX in od:
            option = self.desc.abort_connection_option
            self.sdo.write_object(ObjectAddress(ABORT_CONNECTION_INDEX, 0), option)
            net += f"; 0x6007 = {option} ({ABORT_CONNECTION_OPTIONS[option]})"
        else:
            net += "; no 0x6007: the drive's own reaction to a lost heartbeat"
        return net

    def _consumer_entry_for(self, host: int) -> ObjectAddress:
        """The 0x1016 entry already watching ``host``, else the first unused one."""
        od = self.node.object_dictionary
        count = int(self.sdo.read_object(ObjectAddress(HEARTBEAT_CONSUMER_INDEX, 0)))
        free: ObjectAddress | None = None
        others: list[str] = []
        for sub in range(1, count + 1):
            if od.get_variable(HEARTBEAT_CONSUMER_INDEX, sub) is None:
                continue
            addr = ObjectAddress(HEARTBEAT_CONSUMER_INDEX, sub)
            node, time_ms = parse_consumer_entry(int(self.sdo.read_object(addr)))
            if node == host:
                return addr
            if node == 0 or time_ms == 0:
                free = free or addr
            else:
                others.append(f"{addr}: node {node}")
        if free is None:
            raise DeviceError(
                f"{self.port}: every heartbeat consumer entry of 0x1016 watches another node "
                f"({', '.join(others)}); free one for the host (node {host}, [canopen] host_node_id)"
            )
        return free

    def stop_heartbeats(self) -> None:
        """The host's heartbeat and its node guarding requests off. Never raises."""
        self.heartbeat.stop()
        if self.guarding:
            with contextlib.suppress(Exception):
                self.node.nmt.stop_node_guarding()

    def disarm_device_net(self) -> None:
        """The drive's consumer entry cleared and its life guarding off, so a clean close is no dead host."""
        entry, self._consumer = self._consumer, None
        if entry is not None:
            self.sdo.write_object(entry, 0)
        if self.guarding:  # life time factor 0: the drive stops life guarding before the requests stop
            self.sdo.write_object(ObjectAddress(_LIFE_TIME_FACTOR, 0), 0)

    # --- drive heartbeat, node guarding, emergencies ----------------------------------------------

    def _start_node_guarding(self) -> None:
        """CiA 301 node guarding for a drive without a heartbeat producer: the host asks for the drive's
        state every guard time (its answers are watched like heartbeats), and the drive's life guarding
        (guard time x life time factor) is its net for a host that dies."""
        guard_ms = self.desc.heartbeat_ms
        factor = max(2, math.ceil(self.host_timeout_s * 1000 / guard_ms))
        self.sdo.write_object(ObjectAddress(_GUARD_TIME, 0), guard_ms)
        self.sdo.write_object(ObjectAddress(_LIFE_TIME_FACTOR, 0), min(255, factor))
        self.guarding = True
        self.node.nmt.start_node_guarding(guard_ms / 1000.0)

    def _on_heartbeat(self, state: int) -> None:
        self.heartbeat_s = time.monotonic()
        self.heartbeat_state = state

    def _on_emcy(self, error: EmcyError) -> None:
        self.emergencies.append(Emergency(error.code, error.register, bytes(error.data), time.monotonic()))

    def check_link(self) -> None:
        """Raise DeviceError when the heartbeat stopped or the drive left NMT Operational."""
        gap = time.monotonic() - (self.heartbeat_s or 0.0)
        limit = self.desc.heartbeat_timeout_ms / 1000.0
        if gap > limit:
            raise DeviceError(
                f"{self.port}: heartbeat lost: nothing for {gap:.2f} s "
                f"(limit {limit:g} s, producer {self.desc.heartbeat_ms} ms)"
            )
        if (
            self.heartbeat_state is not None
            and self.heartbeat_state != _NMT_OPERATIONAL
            and time.monotonic() > self._nmt_settled_s
        ):
            state = canopen.nmt.NMT_STATES.get(self.heartbeat_state, str(self.heartbeat_state))
            raise DeviceError(f"{self.port}: the drive left NMT Operational (heartbeat says {state})")

    def emergency_event(self, e: Emergency, fallback_index: int) -> RunEvent:
        """The run event of an emergency (a limit trip names its limit)."""
        index = fallback_index
        if self.desc.emcy_sample_index and len(e.data) >= 4:
            value = int.from_bytes(e.data[:4], "little")
            if value != 0xFFFFFFFF:
                index = value
        meaning = cia402.emcy_meaning(e.code)
        if e.code in LIMIT_TRIP_CODES:
            kind = Kind.LIMIT_TRIP
            message = f"{LIMIT_TRIP_CODES[e.code]}: axis stopped, torque zero (EMCY 0x{e.code:04X} {meaning})"
        elif e.code & 0xFF00 == 0:
            kind, message = Kind.EMERGENCY_RESET, "EMCY 0x0000: error reset"
        else:
            kind, message = Kind.EMERGENCY, f"EMCY 0x{e.code:04X} {meaning}, error register 0x{e.register:02X}"
        return RunEvent(kind, message, int(index), code=e.code, register=e.register, data=e.data.hex())

    def nmt(self, state: str) -> None:
        """Send an NMT command to the drive ("OPERATIONAL", "PRE-OPERATIONAL", ...)."""
        try:
            self.node.nmt.state = state
        except Exception as exc:
            raise DeviceError(f"{self.port}: NMT command {state} failed: {exc}") from None
        # heartbeats sent before the drive took the command may still be on their way (a loaded bus reader)
        self._nmt_settled_s = time.monotonic() + self.desc.heartbeat_timeout_ms / 1000.0


class _FrameCounter:
    """Counts frames on some COB-IDs until stopped (PDOs left over from an earlier session)."""

    def __init__(self, network: canopen.Network, cobs: list[int]) -> None:
        self.network = network
        self.cobs = cobs
        self.frames = 0
        for cob in cobs:
            network.subscribe(cob, self._on_frame)

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.frames += 1

    def stop(self) -> None:
        for cob in self.cobs:
            with contextlib.suppress(KeyError, ValueError):
                self.network.unsubscribe(cob, self._on_frame)
