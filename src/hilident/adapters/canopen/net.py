"""NMT, heartbeats and emergencies for the CANopen adapter: the known state at connect and the device-side net.

One part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`, which composes the parts
(see that module); a part uses only the attributes and methods
:class:`~hilident.adapters.canopen.common.CanopenState` declares.
"""

from __future__ import annotations

import contextlib
import math
import time

import can
from canopen.emcy import EmcyError

import canopen
from hilident.adapters.base import (
    refuse_latched_faults,
)
from hilident.adapters.canopen.common import (
    _GUARD_TIME,
    _LIFE_TIME_FACTOR,
    _NMT_OPERATIONAL,
    _TPDO_BASES,
    LIMIT_TRIP_CODES,
    CanopenState,
    Emergency,
)
from hilident.errors import DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    ABORT_CONNECTION_INDEX,
    ABORT_CONNECTION_OPTIONS,
    HEARTBEAT_CONSUMER_INDEX,
    ObjectAddress,
    consumer_entry,
    parse_consumer_entry,
)


class NetWatch(CanopenState):
    """The NMT and heartbeat part of :class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter`.

    The known state at connect (pre-operational, early frames counted, power stage off,
    latched faults), the host heartbeat and the drive's consumer watching it, the
    drive's heartbeat or node guarding watched by the host, and emergencies as run events.
    """

    # --- known state at connect, device-side net -------------------------------------------------

    def _count_early_frames(self) -> _FrameCounter:
        """Count the TPDOs and emergencies that arrive while the host has configured nothing."""
        cobs = [base + self.node_id for base in _TPDO_BASES]
        counter = _FrameCounter(self.network, cobs)
        return counter

    def _to_known_state(self) -> None:
        """NMT Pre-operational, power stage off, latched faults reported (reset only when allowed).

        Raises
        ------
        DeviceError
            The drive is in Fault and ``device.allow_fault_reset`` is false (the
            message names the fault and how to clear it), or it does not leave Fault.
        """
        self.nmt("PRE-OPERATIONAL")  # PDOs of an earlier session stop here
        state = self.drive_state()
        if state in (cia402.State.FAULT, cia402.State.FAULT_REACTION_ACTIVE):
            self.connect_report.faults = [f"{state.value}, {self.last_error_text()}"]
            if not self.device.allow_fault_reset:
                raise refuse_latched_faults(self.port, self.connect_report.faults)
            self._reset_fault(state)
            self.connect_report.faults_cleared = True
        elif cia402.path_to_safe_state(state):
            self.safe_stop()  # left switched on by someone else: off before anything moves
            state = self.drive_state()
            if state is not cia402.State.SWITCH_ON_DISABLED:
                raise DeviceError(
                    f"{self.port}: the drive does not switch its power stage off: it stays in "
                    f"{state.value} after Disable Voltage "
                    f"({self.describe(self.desc.address('controlword'))})"
                )
        self.connect_report.discarded_frames += len(self.emergencies)
        self.emergencies.clear()  # emergencies of an earlier session: their fault is handled above

    def _reset_fault(self, state: cia402.State) -> None:
        """Fault reset (a rising edge of controlword bit 7) to Switch On Disabled."""
        state = self._follow(state, (int(cia402.Command.DISABLE_VOLTAGE), int(cia402.Command.FAULT_RESET)))
        if state is not cia402.State.SWITCH_ON_DISABLED:
            raise DeviceError(
                f"{self.port}: the fault did not clear: the drive is in {state.value} ({self.last_error_text()})"
            )

    def _arm_device_net(self) -> None:
        """Produce the host's heartbeat and have the drive watch it (0x1016, 0x6007 when the EDS has them)."""
        od = self.node.object_dictionary
        guarding = ""
        if self._guarding:
            guard = int(self.read_object(ObjectAddress(_GUARD_TIME, 0)))
            factor = int(self.read_object(ObjectAddress(_LIFE_TIME_FACTOR, 0)))
            guarding = f"life guarding 0x100C x 0x100D: {guard} ms x {factor}; "
        if HEARTBEAT_CONSUMER_INDEX not in od and guarding:
            net = guarding.rstrip("; ")
            if ABORT_CONNECTION_INDEX in od:
                option = self.desc.abort_connection_option
                self.write_object(ObjectAddress(ABORT_CONNECTION_INDEX, 0), option)
                net += f"; 0x6007 = {option} ({ABORT_CONNECTION_OPTIONS[option]})"
            self.connect_report.device_net = net
            return
        if HEARTBEAT_CONSUMER_INDEX not in od:
            self.connect_report.device_net = (
                f"none: {self.desc.eds} has no heartbeat consumer (0x1016); the drive "
                "does not stop on its own when the host dies"
            )
            return
        host = self.desc.host_node_id
        time_ms = max(1, min(0xFFFF, round(self.device.host_timeout_s * 1000)))
        period_s = time_ms / 3000.0
        entry = self._consumer_entry_for(host)
        self.write_object(entry, consumer_entry(host, time_ms))
        self._consumer = entry
        # after the entry: the task's first frame goes out at once and starts the drive's monitoring
        # (CiA 301: a consumer watches from the first heartbeat it receives)
        self._start_host_heartbeat(host, period_s)
        net = (
            f"{guarding}heartbeat consumer {entry}: host node {host}, {time_ms} ms "
            f"(host heartbeat every {period_s * 1e3:.0f} ms)"
        )
        if ABORT_CONNECTION_INDEX in od:
            option = self.desc.abort_connection_option
            self.write_object(ObjectAddress(ABORT_CONNECTION_INDEX, 0), option)
            net += f"; 0x6007 = {option} ({ABORT_CONNECTION_OPTIONS[option]})"
        else:
            net += "; no 0x6007: the drive's own reaction to a lost heartbeat"
        self.connect_report.device_net = net

    def _consumer_entry_for(self, host: int) -> ObjectAddress:
        """The 0x1016 entry already watching ``host``, else the first unused one."""
        od = self.node.object_dictionary
        count = int(self.read_object(ObjectAddress(HEARTBEAT_CONSUMER_INDEX, 0)))
        free: ObjectAddress | None = None
        others: list[str] = []
        for sub in range(1, count + 1):
            if od.get_variable(HEARTBEAT_CONSUMER_INDEX, sub) is None:
                continue
            addr = ObjectAddress(HEARTBEAT_CONSUMER_INDEX, sub)
            node, time_ms = parse_consumer_entry(int(self.read_object(addr)))
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

    def _start_host_heartbeat(self, host: int, period_s: float) -> None:
        """python-can's cyclic sender in a daemon thread: it dies with the process, which is the point."""
        bus = self.network.bus
        if bus is None:
            raise DeviceError(f"{self.port}: the CAN bus is not open: the host's heartbeat cannot be sent")
        msg = can.Message(arbitration_id=0x700 + host, data=[_NMT_OPERATIONAL], is_extended_id=False)
        self._beat = (msg.arbitration_id, period_s)
        self._beat_s = time.monotonic()
        self._host_heartbeat = can.broadcastmanager.ThreadBasedCyclicSendTask(
            bus, self.network.send_lock, msg, period_s, on_error=lambda exc: False, modifier_callback=self._on_beat
        )

    def _on_beat(self, msg: can.Message) -> None:
        self._beat_s = time.monotonic()

    def beat_if_due(self) -> None:
        """Send the host's heartbeat from this thread when the cyclic sender is a period late.

        On a loaded machine the sender thread can wait for the interpreter
        longer than the drive's consumer time while the thread talking to the
        drive keeps running; a heartbeat from that thread is just as true.
        """
        if self._host_heartbeat is None or time.monotonic() - self._beat_s < self._beat[1]:
            return
        self._beat_s = time.monotonic()
        with contextlib.suppress(can.CanError, OSError):
            self.network.send_message(self._beat[0], bytes([_NMT_OPERATIONAL]))

    def _stop_host_heartbeat(self) -> None:
        task, self._host_heartbeat = self._host_heartbeat, None
        if task is not None:
            with contextlib.suppress(Exception):
                task.stop()
        if self._guarding:
            with contextlib.suppress(Exception):
                self.node.nmt.stop_node_guarding()

    def _disarm_device_net(self) -> None:
        entry, self._consumer = self._consumer, None
        if entry is not None:
            self.write_object(entry, 0)
        if self._guarding:  # life time factor 0: the drive stops life guarding before the requests stop
            self.write_object(ObjectAddress(_LIFE_TIME_FACTOR, 0), 0)

    # --- drive heartbeat, node guarding, emergencies ----------------------------------------------

    def _start_node_guarding(self) -> None:
        """CiA 301 node guarding for a drive without a heartbeat producer: the host asks for the drive's
        state every guard time (its answers are watched like heartbeats), and the drive's life guarding
        (guard time x life time factor) is its net for a host that dies."""
        guard_ms = self.desc.heartbeat_ms
        factor = max(2, math.ceil(self.device.host_timeout_s * 1000 / guard_ms))
        self.write_object(ObjectAddress(_GUARD_TIME, 0), guard_ms)
        self.write_object(ObjectAddress(_LIFE_TIME_FACTOR, 0), min(255, factor))
        self._guarding = True
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

    def take_emergency_fault(self, sample_index: int) -> dict | None:
        """Log the queued emergencies up to the first fault, note that as the run's fault and return it.

        ``sample_index`` is where the host is, for drives whose EMCY does not
        name the sample. Emergencies after the fault stay queued; None when
        no fault was queued.
        """
        while self.emergencies:
            event = self.log_event(self.emergency_event(self.emergencies.popleft(), sample_index))
            if event["kind"] != Kind.EMERGENCY_RESET.value:
                self.note_fault(event)
                return event
        return None

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
