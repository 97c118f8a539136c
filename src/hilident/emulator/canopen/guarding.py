"""How the emulated CANopen drive watches its host: heartbeat consumer (0x1016) and node/life guarding.

Heartbeat consumer, as CiA 301 describes it: each entry ``node << 16 |
time_ms`` watches the heartbeat of one producer (the host); monitoring starts
with the first heartbeat received after the entry was written. Node guarding:
a remote frame on 0x700 + node id is answered with the NMT state and the
toggle bit; life guarding fires when no guard request came for guard time x
life time factor (0x100C x 0x100D). Either event makes the drive send EMCY
0x8130 and do what the abort connection option code (0x6007, CiA 402) says.

A real drive handles each frame as it arrives. This one reads the bus in a
thread that may lag behind a flood of SYNCs, so silence is judged by bus
timestamps: the event fires when a frame stamped after the deadline was read
with no heartbeat before it, or when the deadline passed and nothing is left to
read (``IDLE_S`` without a frame, counted from when the twin's own clock ran
again after a stall of ``STALL_S``: a process that was not scheduled has frames
waiting that its reader threads have not had the chance to read).
"""

from __future__ import annotations

import time

from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.sdo import ABORT_INCOMPATIBLE
from hilident.protocol.canopen_objects import (
    HEARTBEAT_CONSUMER_INDEX,
    parse_consumer_entry,
)

__all__ = ["IDLE_S", "STALL_S", "HostWatch"]

IDLE_S = 0.02  # a bus reader this long without a frame has nothing queued (heartbeat consumer)
STALL_S = 0.1  # the clock thread ran this late: the whole process stood still (heartbeat consumer)
_NMT_STATE_CODES = {"OPERATIONAL": 5, "STOPPED": 4, "PRE-OPERATIONAL": 127}


class HostWatch:
    """Heartbeat consumer and node/life guarding of one drive.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
        The drive it belongs to: object dictionary, network, and what it does when the host is lost
        (``abort_connection``).

    Attributes
    ----------
    consumers : dict
        0x1016 sub-index -> (producer node, time ms).
    heard : dict
        Producer node -> bus timestamp (s) of its last heartbeat (monitoring on).
    heartbeat_events : int
        Times the host was found lost.
    heartbeat_event_wall : float or None
        Wall time (s) the last event fired.
    """

    def __init__(self, firmware: FirmwareHost):
        self.fw = firmware
        self.consumers: dict[int, tuple[int, int]] = {}
        self.heard: dict[int, float] = {}
        self.last_frame = (0.0, 0.0)  # (bus timestamp, monotonic time it was handled) of the last frame received
        self.last_tick = 0.0
        self.resumed = 0.0  # monotonic time the clock thread ran again after a stall of the process
        self.host_lost: set[int] = set()  # producers whose heartbeat event fired and that stayed silent since
        self.guard_toggle = 0  # node guarding: the toggle bit of the next answer
        self.guard_heard: float | None = None  # bus timestamp of the last guard request (life guarding on)
        self.guard_lost = False
        self.heartbeat_events = 0
        self.heartbeat_event_wall: float | None = None
        self.on_producer = firmware.guarded(self._on_producer_heartbeat)
        if HEARTBEAT_CONSUMER_INDEX in firmware.od:
            for sub in range(1, int(firmware.stored(HEARTBEAT_CONSUMER_INDEX, 0)) + 1):
                node_id, time_ms = parse_consumer_entry(int(firmware.stored(HEARTBEAT_CONSUMER_INDEX, sub)))
                if node_id and time_ms:
                    self.consumers[sub] = (node_id, time_ms)

    def subscribe(self, network) -> None:
        for node_id, _ in self.consumers.values():
            network.subscribe(0x700 + node_id, self.on_producer)

    # --- heartbeat consumer -------------------------------------------------------------------

    def write_consumer(self, sub: int, value: int) -> None:
        """CiA 301: one producer per entry; node 0 or time 0 switches the entry off."""
        node_id, time_ms = parse_consumer_entry(value)
        active = bool(node_id and time_ms)
        if active and any(n == node_id for s, (n, _) in self.consumers.items() if s != sub):
            raise SdoAbortedError(ABORT_INCOMPATIBLE)
        old = self.consumers.pop(sub, None)
        if old is not None:
            self.heard.pop(old[0], None)
            self.host_lost.discard(old[0])
        if active:
            self.consumers[sub] = (node_id, time_ms)
            self.heard.pop(node_id, None)  # monitoring starts with the next heartbeat
            self.host_lost.discard(node_id)
            if self.fw.network is not None:
                self.fw.network.subscribe(0x700 + node_id, self.on_producer)

    def _on_producer_heartbeat(self, can_id, data, timestamp) -> None:
        node_id = can_id - 0x700
        with self.fw.lock:
            if any(n == node_id for n, _ in self.consumers.values()):
                self.heard[node_id] = timestamp
                self.host_lost.discard(node_id)

    # --- node guarding --------------------------------------------------------------------------

    def on_frame(self, msg) -> None:
        """Every received frame, after its handlers ran: how far the drive has read the bus; node guarding."""
        fw = self.fw
        if msg.is_remote_frame and msg.arbitration_id == 0x700 + fw.node_id and 0x100C in fw.od:
            with fw.lock:
                self._answer_guarding(msg.timestamp)
        self.last_frame = (msg.timestamp, time.monotonic())

    def _answer_guarding(self, timestamp: float) -> None:
        fw = self.fw
        state = _NMT_STATE_CODES.get(fw.node.nmt.state, 127)
        fw.send(0x700 + fw.node_id, bytes([state | self.guard_toggle]))
        self.guard_toggle ^= 0x80
        self.guard_heard = timestamp
        self.guard_lost = False

    # --- the clock's look --------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """At monotonic time ``now`` (s): note a stall of the process, then look for a lost host."""
        if now - self.last_tick > STALL_S:
            self.resumed = now
        self.last_tick = now
        if self.consumers:
            self._check_consumers(now)
        self._check_life_guarding(now)

    def silent_past(self, deadline: float, now: float, wall: float) -> bool:
        """Whether the bus shows no frame from the host up to ``deadline`` (bus time, s), judged at monotonic
        time ``now`` and wall time ``wall`` (s); also how the drive finds a SYNC missing."""
        last_stamp, last_handled = self.last_frame
        idle = now - max(last_handled, self.resumed) > IDLE_S
        return last_stamp > deadline or (wall > deadline and idle)

    def _check_life_guarding(self, now: float) -> None:
        """Life guarding: no guard request for guard time x life time factor (0x100C x 0x100D)."""
        fw = self.fw
        if self.guard_heard is None or self.guard_lost or 0x100D not in fw.od:
            return
        lifetime_s = int(fw.stored(0x100C, 0)) * int(fw.stored(0x100D, 0)) / 1000.0
        if lifetime_s <= 0:
            return
        if self.silent_past(self.guard_heard + lifetime_s, now, time.time()):
            self.guard_lost = True
            self._host_lost(time.time())

    def _check_consumers(self, now: float) -> None:
        """The heartbeat event: a watched producer silent for longer than its consumer time."""
        wall = time.time()
        for node_id, time_ms in self.consumers.values():
            seen = self.heard.get(node_id)
            if seen is None or node_id in self.host_lost:
                continue
            if self.silent_past(seen + time_ms / 1000.0, now, wall):
                self.host_lost.add(node_id)
                self._host_lost(wall)

    def _host_lost(self, wall: float) -> None:
        self.heartbeat_events += 1
        self.heartbeat_event_wall = wall
        self.fw.abort_connection()
