"""PDOs and SYNC of the emulated CANopen drive: mapping, transmission, and synchronous runs.

PDO communication and mapping objects are honoured as the host writes them.
In a SYNC-driven run (Operation Enabled, no table playing) each cycle is
``loop_rate / sample_rate`` ticks of the drive loop (the SYNC period, 0x1006
or 0x60C2). The drive keeps its own clock (:class:`~.sync.SyncMonitor`, by
the SYNC frames' bus timestamps): a SYNC on time starts a cycle with the
latest RPDO set-point and the drive sends its TPDOs with the state at the
start of that cycle; cycles that passed without a SYNC run with the held
set-point and send nothing (``sync_missed``); a SYNC off the drive's clock (a
burst, or outside the window) is a sync error (``sync_window_errors``), and
too many of them fault the drive (EMCY 0x8700). When the drive itself
produces SYNC (:mod:`.production`) it runs the same cycles at its SYNC
instants. In a position mode the following error is watched (0x6065, 0x6066).
The :class:`~hilident.emulator.clock.SimClock` paces table playback only.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np
from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.following import FOLLOWING_ERROR_OFF, FollowingErrorMonitor
from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.roles import EMCY_FOLLOWING_ERROR, EMCY_SYNC_ERROR, EMCY_SYNC_TIMEOUT
from hilident.emulator.canopen.sdo import (
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_STATE,
    ABORT_VALUE,
)
from hilident.emulator.canopen.sync import SyncMonitor
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    NUMERIC_TYPES,
    numpy_type,
    parse_mapping_entry,
    type_bits,
)
from hilident.protocol.canopen_profile import mapping_capacity, period_from_fields

__all__ = ["PDO_KINDS", "PdoConfig", "PdoExchange"]

#: Base index of each PDO object range: (rpdo or tpdo, communication or mapping).
PDO_KINDS = {0x1400: ("rpdo", "comm"), 0x1600: ("rpdo", "map"), 0x1800: ("tpdo", "comm"), 0x1A00: ("tpdo", "map")}
_MAX_TICKS = 65535  # most loop ticks one SYNC period may span
#: The highest transmission type of a synchronous PDO (CiA 301: 0-240; 254 and 255 are event-driven).
_LAST_SYNCHRONOUS = 240


@dataclass
class PdoConfig:
    """One PDO as the host configured it."""

    cob_id: int
    valid: bool
    trans_type: int
    entries: list = field(default_factory=list)  # (ObjectAddress, datatype)
    packer: struct.Struct | None = None


def _whole_ticks(seconds: float, loop_rate: float) -> int | None:
    """``seconds`` in loop ticks, when it is a whole number of them that one SYNC period may span."""
    ticks = seconds * loop_rate
    if abs(ticks - round(ticks)) > 1e-6 or not 1 <= round(ticks) <= _MAX_TICKS:
        return None
    return int(round(ticks))


class PdoExchange:
    """The PDOs of one drive and its synchronous runs.

    Parameters
    ----------
    firmware : CanopenDriveFirmware
        The drive it belongs to: object dictionary, CiA 402 state, set-points, drive loop.
    seed : int
        Seed of the PDO-drop fault.

    Attributes
    ----------
    pdos : dict
        (``"rpdo"`` or ``"tpdo"``, number) -> :class:`PdoConfig`.
    sync_divider : int
        Loop ticks per SYNC period (0: not set).
    cycle_period_us : int
        0x1006 as last written, µs (0: not set).
    producing : bool
        The drive produces SYNC itself (:mod:`.production`): received SYNCs are ignored, RPDO set-points wait
        for the SYNC that latches them.
    underruns, sync_errors, tpdos_dropped : int
        Samples without a fresh set-point, SYNC counter jumps, TPDOs the drop fault swallowed.
    sync_missed, sync_window_errors : int
        In the run: cycles the drive's own clock ran without a SYNC it answered (held set-point, no TPDOs);
        SYNCs off its clock (a second one in a cycle, or outside the window).
    dropped : list
        (sample index, COB-ID) of each TPDO the drop fault swallowed.
    """

    def __init__(self, firmware: FirmwareHost, seed: int = 0):
        self.fw = firmware
        od = firmware.od
        self.rng = np.random.default_rng(seed + 2)
        self.interpolation_period = [0, -3]  # 0x60C2 value and exponent as last written
        self.sync_divider = 0
        self.cycle_period_us = 0
        self.producing = False
        self.sync = firmware.desc.sync
        self.monitor = SyncMonitor(self.sync)
        self.following = FollowingErrorMonitor()
        self.sync_overflow = (
            int(firmware.default(firmware.desc.address("sync_overflow"))) if firmware.desc.has("sync_overflow") else 0
        )
        self.tpdos_dropped = 0
        self.dropped: list[tuple[int, int]] = []
        self.restart()
        self.pdos = {("tpdo", n): self._load("tpdo", n) for n in range(512) if 0x1800 + n in od and 0x1A00 + n in od}
        self.pdos.update(
            {("rpdo", n): self._load("rpdo", n) for n in range(512) if 0x1400 + n in od and 0x1600 + n in od}
        )

    def restart(self) -> None:
        """A run starts: counters cleared, not yet driven by SYNC."""
        self.underruns = 0
        self.sync_errors = 0
        self.sync_missed = 0
        self.sync_window_errors = 0
        self.last_sync_counter: int | None = None
        self.last_sync_stamp: float | None = None  # bus time of the run's last SYNC received
        self.held_input: float | None = None  # the drive loop's input (SI) in the last cycle
        self.input_before: float | None = None  # ... and in the cycle before it (a position's extrapolation)
        self.position_setpoint_m: float | None = None  # last position set-point, the start of the next ramp
        self.monitor.restart()
        self.following.restart()

    # --- configuration -----------------------------------------------------------------------

    def _load(self, kind: str, n: int) -> PdoConfig:
        fw = self.fw
        comm = (0x1400 if kind == "rpdo" else 0x1800) + n
        cob = int(fw.stored(comm, 1))
        cfg = PdoConfig(cob & 0x7FF, not cob & 0x80000000, int(fw.stored(comm, 2)))
        self._set_mapping(kind, n, cfg, int(fw.stored(comm + 0x200, 0)))
        return cfg

    def _set_mapping(self, kind: str, n: int, cfg: PdoConfig, count: int) -> None:
        od = self.fw.od
        mapping = (0x1600 if kind == "rpdo" else 0x1A00) + n
        if count > mapping_capacity(od[mapping]):
            raise SdoAbortedError(ABORT_PDO_LENGTH)
        entries, bits = [], 0
        for sub in range(1, count + 1):
            addr, width = parse_mapping_entry(int(self.fw.stored(mapping, sub)))
            obj = od.get_variable(addr.index, addr.subindex)
            if obj is None or not obj.pdo_mappable or obj.data_type not in NUMERIC_TYPES:
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)
            if width != type_bits(obj.data_type) or not (obj.writable if kind == "rpdo" else obj.readable):
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)
            entries.append((addr, obj.data_type))
            bits += width
        if bits > 64:
            raise SdoAbortedError(ABORT_PDO_LENGTH)
        cfg.entries = entries
        cfg.packer = struct.Struct("<" + "".join(numpy_type(t).char for _, t in entries)) if entries else None

    def owns(self, index: int) -> bool:
        base = index & 0xFE00
        return base in PDO_KINDS and (PDO_KINDS[base][0], index - base) in self.pdos

    def write(self, index: int, sub: int, value: int) -> None:
        """The host wrote a PDO communication or mapping object (:meth:`owns` ``index``)."""
        base = index & 0xFE00
        kind, part = PDO_KINDS[base]
        n = index - base
        cfg = self.pdos[(kind, n)]
        if part == "comm":
            self._write_comm(kind, n, cfg, sub, value)
            return
        if cfg.valid:
            raise SdoAbortedError(ABORT_STATE)  # mapping changes need the PDO invalid
        if sub == 0:
            self._set_mapping(kind, n, cfg, value)  # entries 1..value were stored before

    def _write_comm(self, kind: str, n: int, cfg: PdoConfig, sub: int, value: int) -> None:
        if sub == 1:
            valid = not value & 0x80000000
            if valid and cfg.valid and (value & 0x7FF) != cfg.cob_id:
                raise SdoAbortedError(ABORT_VALUE)  # CiA 301: invalidate a PDO before moving it
            network = self.fw.network
            if kind == "rpdo" and network is not None:
                if cfg.valid:
                    network.unsubscribe(cfg.cob_id)
                if valid:
                    network.subscribe(value & 0x7FF, self.fw.guarded(self._rpdo_handler(n)))
            cfg.cob_id, cfg.valid = value & 0x7FF, valid
        elif sub == 2:
            if kind == "tpdo" and not 1 <= value <= 240:
                raise SdoAbortedError(ABORT_VALUE)  # this drive sends TPDOs on SYNC only
            cfg.trans_type = value

    def write_cycle_period(self, period_us: int) -> None:
        """0x1006: the SYNC period, µs; it must be whole loop ticks (0: not set)."""
        if period_us == 0:
            self.sync_divider = self.cycle_period_us = 0
            return
        ticks = _whole_ticks(period_us / 1e6, self.fw.loop_rate)
        if ticks is None:
            raise SdoAbortedError(ABORT_VALUE)
        self.sync_divider = ticks
        self.cycle_period_us = period_us

    def write_interpolation_period(self, value: int | None, exponent: int | None) -> None:
        """0x60C2: the sample period is ``value * 10**exponent`` s; it must be whole loop ticks."""
        period = list(self.interpolation_period)
        if value is not None:
            period[0] = value
        if exponent is not None:
            period[1] = exponent
        seconds = period_from_fields(*period)
        ticks = _whole_ticks(seconds, self.fw.loop_rate) if seconds else None
        if seconds and ticks is None and value is not None:
            raise SdoAbortedError(ABORT_VALUE)  # the exponent may come second: only a value that fits no exponent
        self.interpolation_period = period
        if ticks is not None:
            self.sync_divider = ticks

    def subscribe(self, network) -> None:
        for (kind, n), cfg in self.pdos.items():
            if kind == "rpdo" and cfg.valid:
                network.subscribe(cfg.cob_id, self.fw.guarded(self._rpdo_handler(n)))

    # --- receiving ---------------------------------------------------------------------------------

    def _rpdo_handler(self, n: int):
        def on_rpdo(can_id, data, timestamp):
            fw = self.fw
            with fw.lock:
                cfg = self.pdos[("rpdo", n)]
                if fw.node.nmt.state != "OPERATIONAL" or not cfg.valid or cfg.packer is None:
                    return
                if len(data) < cfg.packer.size:
                    return  # CiA 301: a too-short PDO is not processed
                for (addr, _), value in zip(cfg.entries, cfg.packer.unpack_from(bytes(data)), strict=False):
                    role = fw.role_of.get(addr)
                    if role is not None and fw.setpoints.queued(role) and cfg.trans_type <= _LAST_SYNCHRONOUS:
                        fw.setpoints.receive_synchronous(role, value)  # into the buffer at the next SYNC
                    elif (
                        self.producing
                        and role is not None
                        and fw.setpoints.holds(role)
                        and not fw.setpoints.queued(role)
                    ):
                        fw.setpoints.defer(role, value, timestamp)  # latched by the SYNC after it
                    else:
                        fw.receive_setpoint(role, value)

        on_rpdo.__name__ = f"on_rpdo{n + 1}"
        return on_rpdo

    # --- SYNC ----------------------------------------------------------------------------------------

    def on_sync(self, can_id, data, timestamp) -> None:
        """A SYNC received at bus time ``timestamp`` (s): judged against the drive's clock in a SYNC-driven run."""
        fw = self.fw
        with fw.lock:
            if fw.node.nmt.state != "OPERATIONAL" or self.producing:
                return
            self._count_sync(data)
            if not self.running():
                return
            last, self.last_sync_stamp = self.last_sync_stamp, timestamp
            if last is not None and timestamp - last > self.loss_timeout_s:
                fw.fault(EMCY_SYNC_TIMEOUT, fw.sample_index)  # the drive faulted before this SYNC came
                return
            verdict = self.monitor.observe(timestamp, fw.divider() / fw.loop_rate)
            for _ in range(verdict.held):
                if not self.running():
                    break
                self.cycle(fresh=False)
                self.sync_missed += 1
            self.sync_window_errors += verdict.error
            if self.running() and verdict.fault:
                # Every fault reaction option (0x605E) ends in Fault with the power stage off; the ramps of
                # options 1-4 are not modelled, so with or without 0x605E the drive faults at once.
                fw.fault(EMCY_SYNC_ERROR, fw.sample_index)
            elif self.running() and verdict.answer:
                k = fw.sample_index
                self.send_tpdos(self.cycle(fresh=True)[0], k)
            fw.check_faults()

    @property
    def loss_timeout_s(self) -> float:
        """How long a SYNC may be missing in a SYNC-driven run before the drive faults (0x8250), s."""
        return self.sync.loss_timeout_ms / 1000.0

    def running(self) -> bool:
        """A SYNC-driven run: Operation Enabled, no table playing, no limit trip waiting to be reported."""
        fw = self.fw
        return fw.state is cia402.State.OPERATION_ENABLED and not fw.playback.playing and fw.drive.fault is None

    def cycle(self, fresh: bool) -> np.ndarray:
        """One cycle of the drive loop: with the latest set-point (``fresh``) or the one held from the last cycle.

        Returns the loop's rows; the first is the state at the start of the cycle (what its TPDOs carry).
        """
        fw = self.fw
        k = fw.sample_index
        new = fw.setpoints.take_new(fresh)
        last = self.held_input
        position = fw.drive.mode == "position"
        if fresh or last is None:
            if fw.setpoints.rx_counter != k & 0xFFFF:
                self.underruns += 1  # no fresh set-point for this sample: the last one is held
            if new or last is None or not position:
                self.held_input = fw.setpoints.drive_input()
        if not new and position and last is not None and self.input_before is not None:
            # no new position set-point this cycle: extrapolated at the last set-point velocity, as CSP and IP
            # drives do (a held position followed by the next one would jolt the axis at twice the speed)
            self.held_input = last + (last - self.input_before)
        self.input_before = last
        rows = fw.drive.run(
            self._setpoint_ticks(fw.setpoints.drive_input() if self.held_input is None else self.held_input)
        )
        fw.sample_index = k + 1
        fw.last_row = rows[-1]
        self._watch_following_error(rows, k)
        return rows

    def _watch_following_error(self, rows: np.ndarray, k: int) -> None:
        """CiA 402 following error in a position mode, where the EDS has 0x6065 (EMCY 0x8611 and Fault)."""
        fw, desc = self.fw, self.fw.desc
        if fw.drive.mode != "position" or not desc.has("following_error_window"):
            return
        window = int(self._stored_role("following_error_window"))
        if window == FOLLOWING_ERROR_OFF:
            return
        timeout_s = self._stored_role("following_error_timeout") / 1000.0 if desc.has("following_error_timeout") else 0
        error = rows[:, fw.columns["excitation"]] + fw.drive.hold_position_m - rows[:, fw.columns["position_m"]]
        if self.following.exceeded(error, window * desc.position_unit_m, timeout_s, 1.0 / fw.loop_rate):
            fw.fault(EMCY_FOLLOWING_ERROR, k)

    def _stored_role(self, role: str) -> float:
        addr = self.fw.desc.address(role)
        return float(self.fw.stored(addr.index, addr.subindex))

    def sync_deadline(self) -> float | None:
        """Bus time (s) by which the next SYNC must come in this run (None: the drive expects none)."""
        if self.producing or self.last_sync_stamp is None:
            return None
        return self.last_sync_stamp + self.loss_timeout_s

    def _count_sync(self, data) -> None:
        """SYNC counter (CiA 301): a counter that does not follow the last one is a lost or extra SYNC."""
        if len(data) >= 1 and self.sync_overflow > 1:
            counter = data[0]
            if self.last_sync_counter is not None and counter != self.last_sync_counter % self.sync_overflow + 1:
                self.sync_errors += 1
            self.last_sync_counter = counter

    def send_tpdos(self, row, k: int) -> None:
        rate = self.fw.faults.canopen.drop_pdo_rate
        for cob_id, payload in self._tpdo_frames(row, k):
            if rate and self.rng.random() < rate:
                self.tpdos_dropped += 1
                self.dropped.append((k, cob_id))
                continue
            self.fw.send(cob_id, payload)

    def _tpdo_frames(self, row, k: int) -> list[tuple[int, bytes]]:
        fw, frames = self.fw, []
        for (kind, _), cfg in self.pdos.items():
            if kind != "tpdo" or not cfg.valid or cfg.packer is None:
                continue
            if cfg.trans_type > 1 and (k % cfg.trans_type):
                continue
            values = [fw.live(fw.role_of.get(addr), addr, row, k) for addr, _ in cfg.entries]
            frames.append((cfg.cob_id, cfg.packer.pack(*values)))
        return frames

    def _setpoint_ticks(self, target: float) -> np.ndarray:
        """The loop's input for each tick of one SYNC period.

        A position set-point (CSP, IP) is interpolated linearly from the last
        one over the period (CiA 402 linear interpolation, 0x60C0 = 0): a step
        every period would jolt the position loop at the SYNC rate. Other
        set-points are held.
        """
        n = self.fw.divider()
        self.fw.drive.setpoint_ticks = n
        if self.fw.drive.mode != "position":
            return np.full(n, target)
        start = target if self.position_setpoint_m is None else self.position_setpoint_m
        self.position_setpoint_m = target
        return start + (target - start) * np.arange(1, n + 1) / n
