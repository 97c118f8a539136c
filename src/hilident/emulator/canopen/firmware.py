"""The emulated CiA 402 servo drive: a CANopen node around the shared drive loop.

:class:`CanopenDriveFirmware` is the drive's application on a
:class:`canopen.LocalNode` built from the EDS in the driver folder. Everything it
does goes through its object dictionary and the bus:

* the CiA 402 state machine runs in the controlword's write callback
  (:func:`hilident.protocol.cia402.transition`); Operation Enabled closes the
  :class:`~hilident.emulator.drive.DriveLoop`, every other state opens it;
* SDO reads and writes are dispatched to the firmware's parts: stored values
  and scalings (:mod:`.objects`), modes and set-points (:mod:`.setpoints`),
  limits and filter slots (:mod:`.parameters`), PDOs and SYNC-driven runs
  (:mod:`.pdo`, SYNC judged by :mod:`.sync`, the following error by
  :mod:`.following`), SYNC production (:mod:`.production`), heartbeat
  consumer and node guarding (:mod:`.guarding`),
  drive-buffered table runs and the capture (:mod:`.playback`), a vendor
  drive's recorder and generator (:mod:`.recorder`);
* heartbeat producer (0x1017), EMCY on every fault (limit trips too; the first
  four manufacturer bytes carry the sample index of the fault);
* when the host is lost (heartbeat consumer or life guarding) the drive sends
  EMCY 0x8130 (life guard or heartbeat error) and does what the abort
  connection option code (0x6007, CiA 402) says: 0 nothing, 1 Fault, 2 Disable
  Voltage, 3 Quick Stop (both end in Switch On Disabled, power stage off).
  A drive with 0x1016 but no 0x6007 goes to Fault (the CiA 402 default).

The parts are composed, not mixed in: each is made with the firmware and
reaches it through :class:`~hilident.emulator.canopen.host.FirmwareHost`, a
protocol that declares the firmware state and calls the parts share. A type
checker holds the firmware to it where it makes its parts, and the parts never
import this module (no import cycle).

Its clock (:meth:`CanopenDriveFirmware.tick`, called by
:class:`~hilident.emulator.canopen.server.CanopenDriveServer`) runs the host
watch, the recorder, table playback and coasting on the twins' one
:class:`~hilident.emulator.clock.SimClock`, and the SYNC watchdog (EMCY 0x8250 when a SYNC-driven run
sees no SYNC for the driver's ``[canopen.sync] loss_timeout_ms``).

Fault switches (``[emulator.faults]``): ``drive_fault_after_s`` (EMCY 0x4310 and
Fault), ``capture_stops_after_s``; in ``[emulator.faults.canopen]``,
``heartbeat_stops_after_s``, ``abort_object`` (SDO abort on every access),
``drop_pdo_rate`` (TPDOs not sent).
"""

from __future__ import annotations

import struct
import threading
import time

import can
import numpy as np
from canopen.sdo import SdoAbortedError

import canopen
from hilident.config.tables import FaultsConfig
from hilident.drivers.description import DriverDescription, load_object_dictionary
from hilident.emulator.canopen.guarding import HostWatch
from hilident.emulator.canopen.loop import LoopObjects
from hilident.emulator.canopen.objects import ObjectStore, hold_values
from hilident.emulator.canopen.parameters import DriveParameters
from hilident.emulator.canopen.pdo import PdoExchange
from hilident.emulator.canopen.playback import CAPTURE_CHUNK_RECORDS, TablePlayback
from hilident.emulator.canopen.production import SyncProducer
from hilident.emulator.canopen.recorder import DriveRecorder
from hilident.emulator.canopen.roles import (
    COLUMN_OF_ROLE,
    EMCY_DRIVE_FAULT,
    EMCY_HEARTBEAT,
    EMCY_INTERNAL,
    EMCY_OF_TRIP,
    EMCY_SYNC_TIMEOUT,
    LIMIT_ROLES,
    error_register,
)
from hilident.emulator.canopen.sdo import (
    ABORT_STATE,
    ABORT_TOO_HIGH,
    ABORT_TOO_LOW,
    ABORT_VALUE,
    BlockSdoServer,
    parse_fault_object,
)
from hilident.emulator.canopen.setpoints import SetPoints
from hilident.emulator.canopen.sync import SYNC_COB_ID_INDEX
from hilident.emulator.clock import SimClock
from hilident.emulator.drive import DriveLoop
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    ABORT_CONNECTION_INDEX,
    HEARTBEAT_CONSUMER_INDEX,
    NUMERIC_TYPES,
    CanopenDescription,
    TableState,
    default_supported_modes,
)
from hilident.protocol.canopen_profile import (
    CYCLIC_MODES,
    MODE_CODES,
    SETPOINT_OF_MODE,
    encode_supported_modes,
)
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["CAPTURE_CHUNK_RECORDS", "EMCY_HEARTBEAT", "CanopenDriveFirmware"]

#: Roles whose value is the drive's state now, not what was stored: ``value(firmware, sample index)``.
_LIVE_VALUES = {
    "sample_counter": lambda fw, k: k & 0xFFFF,
    "statusword": lambda fw, k: fw.statusword(),
    "modes_display": lambda fw, k: fw.setpoints.mode_code,
    "modes_of_operation": lambda fw, k: fw.setpoints.mode_code,
    "setpoint_counter": lambda fw, k: fw.setpoints.rx_counter,
    "controlword": lambda fw, k: fw.cw,
    "error_code": lambda fw, k: fw.error_code,
    "error_register": lambda fw, k: error_register(fw.error_code) if fw.error_code else 0,
}
#: Abort connection options (0x6007) that end in Switch On Disabled, and the states they leave.
_SWITCHED_OFF_BY_ABORT = (
    cia402.State.OPERATION_ENABLED,
    cia402.State.SWITCHED_ON,
    cia402.State.READY_TO_SWITCH_ON,
    cia402.State.QUICK_STOP_ACTIVE,
)


def _supported_modes(desc: CanopenDescription, od, emulator: dict) -> tuple[str, ...]:
    """The modes this drive runs: 0x6502's EDS default, else the driver's ``[emulator] supported_modes``,
    else every cyclic mode whose set-point object the EDS has."""
    declared = default_supported_modes(od, desc.objects)
    if declared is not None:
        return declared
    listed = emulator.get("supported_modes") if isinstance(emulator, dict) else None
    if isinstance(listed, list) and all(m in MODE_CODES for m in listed):
        return tuple(listed)
    if desc.explicit_modes:
        return tuple(m for m in MODE_CODES if MODE_CODES[m] in {spec.code for spec in desc.modes.values()})
    return tuple(m for m in CYCLIC_MODES if SETPOINT_OF_MODE[m] in desc.objects)


def _part(part: str, name: str) -> property:
    """An attribute of one of the firmware's parts, read through the firmware."""
    return property(lambda self: getattr(getattr(self, part), name))


class CanopenDriveFirmware:
    """The drive application: CiA 402 states and the object dictionary callbacks, around its parts.

    The parts: :class:`~hilident.emulator.canopen.objects.ObjectStore` (stored
    values and scalings), :class:`~hilident.emulator.canopen.pdo.PdoExchange`
    (PDOs and SYNC), :class:`~hilident.emulator.canopen.guarding.HostWatch`
    (heartbeat consumer, guarding), :class:`~hilident.emulator.canopen.playback.TablePlayback`
    (table and capture) and, when the driver has one, the
    :class:`~hilident.emulator.canopen.recorder.DriveRecorder`.

    Parameters
    ----------
    drive : DriveLoop
        The physics (plant, sensors, drive loop).
    driver : DriverDescription
        A ``transport = "canopen"`` description; its EDS is the object dictionary.
    node_id : int
    faults : FaultsConfig
    time_scale : float
        Simulated seconds per wall second for table playback and coasting.
    seed : int
        Seed of the PDO-drop fault.
    """

    pdos = _part("pdo", "pdos")
    sync_divider = _part("pdo", "sync_divider")
    interpolation_period = _part("pdo", "interpolation_period")
    tpdos_dropped = _part("pdo", "tpdos_dropped")
    dropped = _part("pdo", "dropped")
    saves = _part("parameters", "saves")
    stored_parameters = _part("parameters", "stored_parameters")
    consumers = _part("watch", "consumers")
    heard = _part("watch", "heard")
    heartbeat_events = _part("watch", "heartbeat_events")
    heartbeat_event_wall = _part("watch", "heartbeat_event_wall")

    def __init__(
        self,
        drive: DriveLoop,
        driver: DriverDescription,
        node_id: int,
        faults: FaultsConfig | None = None,
        time_scale: float = 1.0,
        seed: int = 0,
    ):
        self.drive = drive
        self.driver = driver
        self.faults = faults or FaultsConfig()
        self.time_scale = float(time_scale)
        self.loop_rate = float(driver.loop_rate_hz)
        self.lock = threading.RLock()
        self.network: canopen.Network | None = None
        self.stamped_bus: can.BusABC | None = None  # sends with a given bus timestamp (the SYNC producer's)
        self.error: BaseException | None = None
        self.clock = SimClock(self.loop_rate, self.time_scale)
        self._describe(driver, node_id)
        self._power_up_state()
        self.parameters = DriveParameters(self)
        self.parameters.power_up_slots()
        self.loop_objects = LoopObjects(self)
        self.watch = HostWatch(self)
        self.pdo = PdoExchange(self, seed)
        self.producer = SyncProducer(self, self.pdo)
        self.playback = TablePlayback(self)
        self.last_row: np.ndarray = drive.run(np.zeros(1))[0]
        drive.disable()
        self.recorder = DriveRecorder(self, self.desc.recorder) if self.desc.recorder is not None else None

    def _describe(self, driver: DriverDescription, node_id: int) -> None:
        """The object dictionary from the EDS, the roles from the driver description, the node on it."""
        source = str(driver.folder / "driver.toml")
        od = load_object_dictionary(driver, node_id)
        desc = CanopenDescription.from_sections(driver.sections, source, od)
        self.supported = _supported_modes(desc, od, driver.sections.get("emulator", {}))
        self.desc = desc = desc.with_supported_modes(self.supported)
        self.encoding = (
            FilterEncoding.from_table(driver.sections["filters"], source) if desc.filters is not None else None
        )
        node = canopen.LocalNode(node_id, od)
        node.sdo = BlockSdoServer(
            0x600 + node_id, 0x580 + node_id, node, parse_fault_object(self.faults.canopen.abort_object)
        )
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        self.node = node
        self.node_id = node_id
        self.od = od
        self.role_of = {addr: role for role, addr in desc.objects.items()}
        self.columns = {name: i for i, name in enumerate(DriveLoop.CHANNELS)}
        emulator = driver.sections.get("emulator")
        hold_values(node, od, emulator.get("values") if isinstance(emulator, dict) else None, source)
        self.objects = ObjectStore(node, desc, driver.name, self.columns)
        self.stored, self.default = self.objects.stored, self.objects.default
        self.scales = self.objects.scales
        self.rated_torque_nm, self.rated_current_a = self.objects.rated_torque_nm, self.objects.rated_current_a
        node.sdo.size_limit = lambda index, subindex: self.playback.size_limit(index, subindex)

    def _power_up_state(self) -> None:
        """CiA 402 state, set-points and limits as the drive powers up."""
        desc = self.desc
        self.state = cia402.State.SWITCH_ON_DISABLED
        self.cw = 0
        self.setpoints = SetPoints(
            desc,
            self.scales,
            self.supported,
            int(self.default(desc.address("modes_of_operation"))),
            self.drive,
            int(self.default(desc.address("ip_buffer_max"))) if desc.has("ip_buffer_max") else 1,
        )
        self.sample_index = 0
        self.run_start_tick = self.drive.tick
        self.injected: set[str] = set()
        self.heartbeat_stopped = False
        self.error_code = 0
        self.error_history: list[int] = []

    # --- network ---------------------------------------------------------------------------

    def attach(self, network: canopen.Network) -> None:
        """Join ``network``, send the boot-up message and enter Pre-operational."""
        self.network = network
        network[self.node_id] = self.node
        network.subscribe(0x80, self.guarded(self.pdo.on_sync))
        network.subscribe(0, self.guarded(self._on_nmt))
        self.watch.subscribe(network)
        self.pdo.subscribe(network)
        self.node.nmt.state = "INITIALISING"  # boot-up message
        if 0x1017 in self.od:
            self.node.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat if 0x1017 is set
        else:
            self.node.nmt._state = 127  # Pre-operational, no heartbeat to start (canopen would look up 0x1017)

    def on_frame(self, msg) -> None:
        """Every received frame, after its handlers ran (see :meth:`HostWatch.on_frame`)."""
        self.watch.on_frame(msg)

    def guarded(self, callback):
        """``callback`` as a bus handler: a failure in it faults the drive and is kept for the owner."""

        def guarded(can_id, data, timestamp):
            try:
                callback(can_id, data, timestamp)
            except Exception as exc:  # a bug in the drive: keep it for the owner, fault, power off
                self.error = self.error or exc
                try:
                    with self.lock:
                        self.fault(EMCY_INTERNAL, self.sample_index)
                except Exception:
                    self.drive.disable()

        guarded.__name__ = callback.__name__
        return guarded

    def send(self, cob_id: int, payload: bytes) -> None:
        if self.network is not None:
            self.network.send_message(cob_id, payload)

    def send_stamped(self, cob_id: int, payload: bytes, stamp: float) -> None:
        """A frame whose bus timestamp is ``stamp`` (wall s): the instant the drive's clock put it on the wire."""
        if self.stamped_bus is None:
            self.send(cob_id, payload)
            return
        self.stamped_bus.send(can.Message(arbitration_id=cob_id, data=payload, is_extended_id=False, timestamp=stamp))

    def _on_nmt(self, can_id, data, timestamp) -> None:
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL" and self.state is cia402.State.OPERATION_ENABLED:
                self.power_off()  # communication lost its operational state: switch off
                self.state = cia402.State.SWITCH_ON_DISABLED

    # --- CiA 402 -------------------------------------------------------------------------------

    def statusword(self) -> int:
        internal_limit = self.drive.fault is not None
        return cia402.statusword(
            self.state, target_reached=self.playback.state == TableState.DONE, internal_limit=internal_limit
        )

    def apply_controlword(self, cw: int) -> None:
        new, number = cia402.transition(self.state, cw, self.cw)
        if new is self.state:
            self.cw = cw
            return
        if new is cia402.State.OPERATION_ENABLED:
            loop_mode = self.setpoints.loop_mode()
            if not self.parameters.limits_loaded or loop_mode is None:
                raise SdoAbortedError(ABORT_STATE)  # no limits loaded, or no supported mode selected
            self.drive.set_mode(loop_mode)
            self.drive.enable()
            self.start_run()
        elif self.state is cia402.State.OPERATION_ENABLED:
            self.power_off()
        if number == 15:  # fault reset
            self.drive.clear_fault()
            self.error_code = 0
            self.send(0x80 + self.node_id, struct.pack("<HB5s", 0, 0, b""))  # EMCY error reset
        self.cw = cw
        self.state = new

    def start_run(self) -> None:
        """A run starts at the drive's present tick: sample index, counters and injected faults anew."""
        self.sample_index = 0
        self.pdo.restart()
        self.producer.restart()
        self.run_start_tick = self.drive.tick
        self.injected = set()
        self.clock.stop_coast()

    def power_off(self) -> None:
        """Power stage off: a playing table stops, the axis coasts."""
        self.drive.disable()
        if self.playback.playing:
            self.playback.state = TableState.STOPPED
        self.clock.start_coast(time.monotonic())

    def fault(self, code: int, sample_index: int) -> None:
        """Enter Fault: power stage off, EMCY with ``code`` and the run's sample index."""
        if self.state is cia402.State.FAULT:
            return
        self.power_off()
        self.state = cia402.State.FAULT
        self.error_code = code
        self._emergency(code, sample_index)

    def _emergency(self, code: int, sample_index: int) -> None:
        """EMCY ``code``, the run's sample index in its first manufacturer bytes; noted in the history."""
        self.error_history = [code, *self.error_history][:8]
        data = struct.pack("<I", max(0, int(sample_index)) & 0xFFFFFFFF) + b"\0"
        self.send(0x80 + self.node_id, struct.pack("<HB5s", code, error_register(code), data))

    def check_faults(self) -> None:
        """After the physics advanced: limit trips and the injected faults."""
        drive = self.drive
        divider = self.divider()
        if drive.fault is not None and drive.fault_tick is not None and self.state is cia402.State.OPERATION_ENABLED:
            index = (int(drive.fault_tick) - self.run_start_tick) // divider
            self.fault(EMCY_OF_TRIP.get(drive.fault, 0x8311), index)
        elapsed = (drive.tick - self.run_start_tick) / self.loop_rate
        f, bus = self.faults, self.faults.canopen
        if (
            f.drive_fault_after_s
            and elapsed >= f.drive_fault_after_s
            and "drive" not in self.injected
            and self.state is cia402.State.OPERATION_ENABLED
        ):
            self.injected.add("drive")
            self.fault(EMCY_DRIVE_FAULT, (drive.tick - self.run_start_tick) // divider)
        if bus.heartbeat_stops_after_s and elapsed >= bus.heartbeat_stops_after_s and not self.heartbeat_stopped:
            self.heartbeat_stopped = True
            self.node.nmt.stop_heartbeat()

    def pending_fault_times(self) -> list[float]:
        """Run times (s) of the injected faults still to come in this run."""
        f, times = self.faults, []
        if f.drive_fault_after_s and "drive" not in self.injected:
            times.append(f.drive_fault_after_s)
        if f.canopen.heartbeat_stops_after_s and not self.heartbeat_stopped:
            times.append(f.canopen.heartbeat_stops_after_s)
        return times

    def divider(self) -> int:
        """Loop ticks per sample of the present run: the table's, else the SYNC period's."""
        if self.playback.playing or not self.pdo.sync_divider:
            return self.playback.divider
        return self.pdo.sync_divider

    def abort_connection(self) -> None:
        """The host is lost: EMCY 0x8130, then the action of the abort connection option code (0x6007)."""
        option = int(self.stored(ABORT_CONNECTION_INDEX, 0)) if ABORT_CONNECTION_INDEX in self.od else 1
        if option == 1:
            self.fault(EMCY_HEARTBEAT, self.sample_index)
            return
        self._emergency(EMCY_HEARTBEAT, self.sample_index)
        if option in (2, 3) and self.state in _SWITCHED_OFF_BY_ABORT:
            if self.state is cia402.State.OPERATION_ENABLED:
                self.power_off()  # quick stop in a torque mode: the torque ramps to zero; here at once
            self.state = cia402.State.SWITCH_ON_DISABLED

    # --- set-points and live values ------------------------------------------------------------------

    def receive_setpoint(self, role: str | None, value: int) -> None:
        """A set-point, set-point counter or controlword the host sent in an RPDO."""
        if not self.setpoints.receive(role, value) and role == "controlword":
            try:
                self.apply_controlword(value)
            except SdoAbortedError:
                pass

    def live(self, role: str | None, addr: ObjectAddress, row, k: int):
        """Raw value of a readable object for the sample in ``row`` (SDO reads, TPDOs, captures)."""
        if role in COLUMN_OF_ROLE:
            return self.objects.sampled(role, addr, row)
        targets = self.setpoints.targets
        if role in targets:
            return targets[role]
        value = _LIVE_VALUES.get(role) if role is not None else None
        return value(self, k) if value is not None else self.stored(addr.index, addr.subindex)

    # --- SDO reads ------------------------------------------------------------------------------------

    def _on_read(self, index: int, subindex: int, od):
        addr = ObjectAddress(index, subindex)
        role = self.role_of.get(addr)
        with self.lock:
            if (
                self.recorder is not None
                and self.recorder.owns(addr)
                and (live := self.recorder.on_read(addr)) is not None
            ):
                return live
            value = self._read_live(role, addr)
            if value is not None:
                return value
            if (parameter := self.loop_objects.owner(addr)) is not None:
                return self.loop_objects.read(parameter, addr)
        return self.objects.unset_value(index, subindex, od)

    def _read_live(self, role: str | None, addr: ObjectAddress):
        """What the drive answers for an object whose value it keeps itself (None: the stored value)."""
        if role == "capture_data":
            return self.playback.capture_chunk()
        if role in COLUMN_OF_ROLE or role in _LIVE_VALUES or role in self.setpoints.targets:
            row = self.last_row
            if role == "position_actual":  # the encoder now, as the loop would sample it (the hold at enable)
                row = row.copy()
                row[self.columns["position_m"]] = self.drive.sensors.encoder(self.drive.plant.p1)
            return self.live(role, addr, row, self.sample_index)
        counters = {
            "supported_modes": lambda: encode_supported_modes(self.supported),
            "setpoint_underruns": lambda: self.pdo.underruns,
            "sync_errors": lambda: self.pdo.sync_errors,
            "sync_missed": lambda: self.pdo.sync_missed,
            "sync_window_errors": lambda: self.pdo.sync_window_errors,
        }
        if role in counters:
            return counters[role]()
        played = self.playback.read(role)
        if played is not None:
            return played
        if self._is_error_history(addr.index):
            history = self.error_history
            if addr.subindex == 0:
                return len(history)
            return history[addr.subindex - 1] if addr.subindex <= len(history) else 0
        return None

    def _is_error_history(self, index: int) -> bool:
        return self.desc.has("error_history") and index == self.desc.address("error_history").index

    # --- SDO writes ------------------------------------------------------------------------------------

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = od.decode_raw(data) if od.data_type in NUMERIC_TYPES else bytes(data)
        _check_eds_range(od, value)
        addr = ObjectAddress(index, subindex)
        with self.lock:
            if self.recorder is not None and self.recorder.owns(addr):
                self.recorder.on_write(addr, value)
            elif not self._write_indexed(index, subindex, value):
                self._write_role(self.role_of.get(addr), value)

    def _write_indexed(self, index: int, subindex: int, value) -> bool:
        """Writes to objects known by their index (PDOs, 0x1005, 0x1016, 0x6007, filter slots, capture mapping,
        error history); False when ``index`` is none of them."""
        if self.pdo.owns(index):
            self.pdo.write(index, subindex, int(value))
        elif index == SYNC_COB_ID_INDEX:
            self.producer.write(int(value))
        elif index == HEARTBEAT_CONSUMER_INDEX and subindex > 0:
            self.watch.write_consumer(subindex, int(value))
        elif index == ABORT_CONNECTION_INDEX:
            if not 0 <= int(value) <= 3:
                raise SdoAbortedError(ABORT_VALUE)  # negative (manufacturer) codes: none on this drive
        elif self.desc.filters is not None and (slot := self.desc.filters.owner(ObjectAddress(index, subindex))):
            self.parameters.write_filter(*slot, value)
        elif self.desc.has("capture_mapping") and index == self.desc.address("capture_mapping").index:
            self.playback.write_capture_mapping(subindex, int(value))
        elif (parameter := self.loop_objects.owner(ObjectAddress(index, subindex))) is not None:
            self.loop_objects.write(parameter, value)
        elif self._is_error_history(index):
            if value != 0:
                raise SdoAbortedError(ABORT_VALUE)
            self.error_history = []
        else:
            return False
        return True

    def _write_role(self, role: str | None, value) -> None:
        """Writes to objects known by their role (an object without one keeps what was written)."""
        if role is None:
            return
        handler = {
            "store_parameters": self.parameters.store,
            "controlword": self.apply_controlword,
            "modes_of_operation": self._write_mode,
            "cycle_period": self.pdo.write_cycle_period,
            "interpolation_period": lambda v: self.pdo.write_interpolation_period(v, None),
            "interpolation_exponent": lambda v: self.pdo.write_interpolation_period(None, v),
            "table_divider": self.playback.write_divider,
            "table_command": self.playback.write_command,
            "capture_offset": self.playback.write_capture_offset,
            "sync_overflow": lambda v: setattr(self.pdo, "sync_overflow", v),
            "ip_buffer_size": self.setpoints.buffer.write_size,
            "ip_buffer_organization": self.setpoints.buffer.write_organization,
            "ip_buffer_clear": self.setpoints.buffer.write_clear,
        }.get(role)
        if role == "table":
            self.playback.write_table(value)
        elif handler is not None:
            handler(int(value))
        elif role in self.setpoints.targets or role == "setpoint_counter":
            self.setpoints.receive(role, int(value))
        elif role in LIMIT_ROLES:
            self.parameters.write_limit(role, int(value))

    def _write_mode(self, code: int) -> None:
        loop_mode = self.setpoints.loop_mode(code)
        if loop_mode is None:
            raise SdoAbortedError(ABORT_VALUE)
        self.setpoints.mode_code = code
        if self.state is cia402.State.OPERATION_ENABLED:
            self.drive.set_mode(loop_mode)
            self.pdo.position_setpoint_m = None

    # --- the clock ------------------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """Clock work at monotonic time ``now`` (s): the host watch, the recorder, table playback or coasting,
        the SYNC watchdog."""
        with self.lock:
            self.watch.tick(now)
            if self.recorder is not None:
                self.recorder.tick(now)
            deadline = self.pdo.sync_deadline()
            if deadline is not None and self.pdo.running() and self.watch.silent_past(deadline, now, time.time()):
                self.fault(EMCY_SYNC_TIMEOUT, self.sample_index)
                return
            self.clock.step(self.playback, now)


def _check_eds_range(od, value) -> None:
    """A drive refuses a value outside its EDS's LowLimit/HighLimit (CiA 301 aborts 0x06090032/0x06090031)."""
    if isinstance(value, bytes | bytearray) or isinstance(value, float) and value != value:
        return
    if od.min is not None and value < od.min:
        raise SdoAbortedError(ABORT_TOO_LOW)
    if od.max is not None and value > od.max:
        raise SdoAbortedError(ABORT_TOO_HIGH)
