"""The emulated CiA 402 servo drive: a CANopen node around the shared drive loop.

:class:`CanopenDriveFirmware` is the drive's application on a
:class:`canopen.LocalNode` built from the EDS in the driver folder. Everything it
does goes through its object dictionary and the bus:

* the CiA 402 state machine runs in the controlword's write callback
  (:func:`hilident.protocol.cia402.transition`); Operation Enabled closes the
  :class:`~hilident.emulator.drive.DriveLoop`, every other state opens it;
* PDO communication and mapping objects are honoured as the host writes them;
  on each SYNC (while Operation Enabled) the drive runs ``loop_rate /
  sample_rate`` ticks of the drive loop with the latest RPDO set-point and
  sends its TPDOs with the state at the start of that sample period. In these
  synchronous runs the drive's clock *is* SYNC: one SYNC, one sample period;
* drive-buffered runs: the host downloads an excitation table, starts it, and
  the drive plays it at its own rate (``time_scale`` simulated seconds per wall
  second), recording the mapped objects into its capture buffer, which the host
  uploads in chunks;
* writing a filter slot's enable sub-index rebuilds the slot's biquad from its
  stored fields with :meth:`FilterEncoding.applied` and loads it into
  ``drive.filters``: the same chain the plant sees;
* heartbeat producer (0x1017), EMCY on every fault (limit trips too; the first
  four manufacturer bytes carry the sample index of the fault);
* heartbeat consumer (0x1016, when the EDS has it), as CiA 301 describes it:
  each entry ``node << 16 | time_ms`` watches the heartbeat of one producer
  (the host); monitoring starts with the first heartbeat received after the
  entry was written. When one stays away longer than its time the drive sends
  EMCY 0x8130 (life guard or heartbeat error) and does what the abort
  connection option code (0x6007, CiA 402) says: 0 nothing, 1 Fault, 2 Disable
  Voltage, 3 Quick Stop (both end in Switch On Disabled, power stage off).
  A drive with 0x1016 but no 0x6007 goes to Fault (the CiA 402 default).

Fault switches (``[emulator.faults]``): ``drive_fault_after_s`` (EMCY 0x4310 and
Fault), ``heartbeat_stops_after_s``, ``abort_object`` (SDO abort on every
access), ``drop_pdo_rate`` (TPDOs not sent), ``capture_stops_after_s``.

:func:`start` runs it in-process on python-can's ``virtual`` bus;
:func:`start_socketcand` also serves that bus over the socketcand protocol on
127.0.0.1, for a host in another process (``hilident emulate canopen``).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from dataclasses import dataclass, field

import canopen
import numpy as np
from canopen.sdo import SdoAbortedError

from hilident.config import FaultsConfig
from hilident.drivers import DriverDescription, load_object_dictionary
from hilident.emulator.canopen.recorder import DriveRecorder
from hilident.emulator.canopen.roles import (
    COLUMN_OF_ROLE,
    EMCY_DRIVE_FAULT,
    EMCY_HEARTBEAT,
    EMCY_INTERNAL,
    EMCY_OF_TRIP,
    EMCY_SYNC_TIMEOUT,
    LIMIT_ROLES,
    TARGET_ROLES,
    error_register,
)
from hilident.emulator.canopen.sdo import (
    ABORT_INCOMPATIBLE,
    ABORT_LENGTH,
    ABORT_LENGTH_HIGH,
    ABORT_NO_DATA,
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_STATE,
    ABORT_TOO_HIGH,
    ABORT_TOO_LOW,
    ABORT_VALUE,
    BlockSdoServer,
    parse_fault_object,
)
from hilident.emulator.drive import DriveLoop
from hilident.errors import ConfigError, DataError
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    ABORT_CONNECTION_INDEX,
    DOMAIN,
    HEARTBEAT_CONSUMER_INDEX,
    NUMERIC_TYPES,
    REAL32,
    TABLE_START,
    TABLE_STOP,
    CanopenDescription,
    ObjectAddress,
    TableState,
    default_supported_modes,
    encode_si,
    numpy_type,
    parse_consumer_entry,
    parse_mapping_entry,
    record_dtype,
    type_bits,
)
from hilident.protocol.canopen_profile import (
    CYCLIC_MODES,
    MODE_CODES,
    SETPOINT_OF_MODE,
    encode_supported_modes,
    mapping_capacity,
    mode_name_of_code,
    period_from_fields,
)
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["CAPTURE_CHUNK_RECORDS", "CanopenDriveFirmware"]

#: Most capture records one upload of the capture-data object returns.
CAPTURE_CHUNK_RECORDS = 4096
#: A drive that saw SYNC and then none for this long (wall time) while enabled faults (0x8250).
SYNC_WATCHDOG_S = 1.0
IDLE_S = 0.02  # a bus reader this long without a frame has nothing queued (heartbeat consumer)
STALL_S = 0.1  # the clock thread ran this late: the whole process stood still (heartbeat consumer)
COAST_S = 2.0  # simulated time the axis is left to coast after the power stage is switched off


_PDO_KINDS = {0x1400: ("rpdo", "comm"), 0x1600: ("rpdo", "map"), 0x1800: ("tpdo", "comm"), 0x1A00: ("tpdo", "map")}
#: CiA 402 modes of operation and the drive loop mode that runs them (torque offsets are added in each).
_LOOP_MODE_OF_CODE = {10: "torque", 9: "velocity", 8: "position", 7: "position"}

_STRING_TYPES = (0x09, 0x0A, 0x0B)  # VISIBLE_STRING, OCTET_STRING, UNICODE_STRING


@dataclass
class PdoConfig:
    """One PDO as the host configured it."""

    cob_id: int
    valid: bool
    trans_type: int
    entries: list = field(default_factory=list)  # (ObjectAddress, datatype)
    packer: struct.Struct | None = None


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


class CanopenDriveFirmware:
    """The drive application: object dictionary callbacks, CiA 402 states, PDOs, table, capture, filters.

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

    def __init__(self, drive: DriveLoop, driver: DriverDescription, node_id: int, faults: FaultsConfig | None = None,
                 time_scale: float = 1.0, seed: int = 0):
        self.drive = drive
        self.driver = driver
        source = str(driver.folder / "driver.toml")
        od = load_object_dictionary(driver, node_id)
        desc = CanopenDescription.from_sections(driver.sections, source, od)
        self.supported = _supported_modes(desc, od, driver.sections.get("emulator", {}))
        self.desc = desc = desc.with_supported_modes(self.supported)
        self.encoding = (FilterEncoding.from_table(driver.sections["filters"], source)
                         if self.desc.filters is not None else None)
        self.faults = faults or FaultsConfig()
        self.time_scale = float(time_scale)
        self.loop_rate = float(driver.loop_rate_hz)
        node = canopen.LocalNode(node_id, od)
        node.sdo = BlockSdoServer(0x600 + node_id, 0x580 + node_id, node, parse_fault_object(self.faults.abort_object))
        node.sdo.size_limit = self._size_limit
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        self.node = node
        self.od = od
        self.lock = threading.RLock()
        self.role_of = {addr: role for role, addr in self.desc.objects.items()}
        try:
            self.rated_torque_nm = desc.rated_torque(
                float(self._default(desc.address("rated_torque"))) if desc.has("rated_torque") else None)
        except DataError:
            self.rated_torque_nm = 0.0  # no torque objects to scale
        self.rated_current_a = desc.rated_current(
            float(self._default(desc.address("rated_current"))) if desc.has("rated_current") else None)
        self.scales = {}
        for role in desc.objects:
            try:
                self.scales[role] = desc.scale(role, self.rated_torque_nm, self.rated_current_a)
            except DataError:
                pass  # a torque or current object without its reference: the drive cannot be asked for it
        self.columns = {name: i for i, name in enumerate(DriveLoop.CHANNELS)}
        self._codecs: dict = {}
        self.network = None
        self.error: BaseException | None = None
        self.rng = np.random.default_rng(seed + 2)

        self.state = cia402.State.SWITCH_ON_DISABLED
        self.cw = 0
        self.mode_code = int(self._default(self.desc.address("modes_of_operation")))
        self.targets = {role: 0 for role in TARGET_ROLES if self.desc.has(role)}
        self.rx_counter = 0
        self.limits_raw: dict[str, int] = {}
        # a drive with no limit object of its own can be enabled without any (the host checks the limits)
        self.limits_loaded = not any(desc.has(r) and r in self.scales for r in LIMIT_ROLES)
        self.interpolation_period = [0, -3]  # 0x60C2 value and exponent as last written
        self.sync_divider = 0
        self.sync_overflow = int(self._default(self.desc.address("sync_overflow"))) if self.desc.has("sync_overflow") else 0
        self.last_sync_counter: int | None = None
        self.last_sync_wall: float | None = None
        self.sync_driven = False
        self.position_setpoint_m = None
        self.sample_index = 0
        self.underruns = 0
        self.sync_errors = 0
        self.tpdos_dropped = 0
        self.saves = 0  # times the host had the parameters stored (0x1010:1 "save")
        self.stored_parameters: dict = {}  # the filter slots as they were when last stored
        self.dropped: list[tuple[int, int]] = []  # (sample index, COB-ID) of each TPDO the drop fault swallowed
        self.run_start_tick = drive.tick
        self.injected: set[str] = set()
        self.heartbeat_stopped = False
        self.error_code = 0
        self.error_history: list[int] = []
        self.coast_ticks = 0
        self.coast_clock = time.monotonic()

        buffered = all(self.desc.has(r) for r in ("table", "table_divider", "table_capacity"))
        self.table = np.zeros(0, dtype=np.float32)
        self.table_divider = int(self._default(self.desc.address("table_divider"))) if buffered else 1
        self.table_capacity = int(self._default(self.desc.address("table_capacity"))) if buffered else 0
        self.table_state = TableState.IDLE
        self.play_pos = 0
        self.play_origin = 0.0
        self.play_origin_pos = 0
        self.capture_layout: list[tuple[str | ObjectAddress, int]] = []
        self.capture = bytearray()
        self.capture_count = 0
        self.capture_offset = 0
        self.capture_stopped = False
        self.capture_record_size = 0

        self.consumers: dict[int, tuple[int, int]] = {}  # 0x1016 sub-index -> (producer node, time ms)
        self.heard: dict[int, float] = {}  # producer node -> bus timestamp (s) of its last heartbeat (monitoring on)
        self.last_frame = (0.0, 0.0)  # (bus timestamp, monotonic time it was handled) of the last frame received
        self.last_tick = 0.0
        self.resumed = 0.0  # monotonic time the clock thread ran again after a stall of the process
        self.host_lost: set[int] = set()  # producers whose heartbeat event fired and that stayed silent since
        self.guard_toggle = 0  # node guarding: the toggle bit of the next answer
        self.guard_heard: float | None = None  # bus timestamp of the last guard request (life guarding on)
        self.guard_lost = False
        self.heartbeat_events = 0
        self.heartbeat_event_wall: float | None = None  # wall time (s) the last heartbeat event fired
        self._on_producer = self._guard(self._on_producer_heartbeat)
        if HEARTBEAT_CONSUMER_INDEX in od:
            for sub in range(1, int(self._stored(HEARTBEAT_CONSUMER_INDEX, 0)) + 1):
                node_id, time_ms = parse_consumer_entry(int(self._stored(HEARTBEAT_CONSUMER_INDEX, sub)))
                if node_id and time_ms:
                    self.consumers[sub] = (node_id, time_ms)
        self.pdos = {("tpdo", n): self._load_pdo("tpdo", n) for n in range(512) if 0x1800 + n in od and 0x1A00 + n in od}
        self.pdos.update({("rpdo", n): self._load_pdo("rpdo", n) for n in range(512)
                          if 0x1400 + n in od and 0x1600 + n in od})
        self.last_row = drive.run(np.zeros(1))[0]
        drive.disable()
        self.recorder = DriveRecorder(self, desc.recorder) if desc.recorder is not None else None

    # --- object dictionary helpers --------------------------------------------------------

    def _default(self, addr: ObjectAddress):
        return self._stored(addr.index, addr.subindex)

    def _variable(self, addr: ObjectAddress):
        obj = self.od.get_variable(addr.index, addr.subindex)
        if obj is None:
            raise SdoAbortedError(0x06020000)
        return obj

    def _stored(self, index: int, sub: int):
        """Value of an object as stored (written or EDS default), without live callbacks."""
        obj = self._variable(ObjectAddress(index, sub))
        try:
            raw = self.node.data_store[index][sub]
        except KeyError:
            value = obj.value if obj.value is not None else obj.default
            return 0 if value is None else value
        return obj.decode_raw(raw)

    def _load_pdo(self, kind: str, n: int) -> PdoConfig:
        comm = (0x1400 if kind == "rpdo" else 0x1800) + n
        cob = int(self._stored(comm, 1))
        cfg = PdoConfig(cob & 0x7FF, not cob & 0x80000000, int(self._stored(comm, 2)))
        self._set_mapping(kind, n, cfg, int(self._stored(comm + 0x200, 0)))
        return cfg

    def _set_mapping(self, kind: str, n: int, cfg: PdoConfig, count: int) -> None:
        mapping = (0x1600 if kind == "rpdo" else 0x1A00) + n
        if count > mapping_capacity(self.od[mapping]):
            raise SdoAbortedError(ABORT_PDO_LENGTH)
        entries, bits = [], 0
        for sub in range(1, count + 1):
            addr, width = parse_mapping_entry(int(self._stored(mapping, sub)))
            obj = self.od.get_variable(addr.index, addr.subindex)
            if obj is None or not obj.pdo_mappable or obj.data_type not in NUMERIC_TYPES:
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)
            if width != type_bits(obj.data_type) or (kind == "rpdo" and not obj.writable) or (
                    kind == "tpdo" and not obj.readable):
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)
            entries.append((addr, obj.data_type))
            bits += width
        if bits > 64:
            raise SdoAbortedError(ABORT_PDO_LENGTH)
        cfg.entries = entries
        cfg.packer = struct.Struct("<" + "".join(numpy_type(t).char for _, t in entries)) if entries else None

    # --- network ---------------------------------------------------------------------------

    def attach(self, network: canopen.Network) -> None:
        """Join ``network``, send the boot-up message and enter Pre-operational."""
        self.network = network
        network[self.node.id] = self.node
        network.subscribe(0x80, self._guard(self._on_sync))
        network.subscribe(0, self._guard(self._on_nmt))
        for node_id, _ in self.consumers.values():
            network.subscribe(0x700 + node_id, self._on_producer)
        for (kind, n), cfg in self.pdos.items():
            if kind == "rpdo" and cfg.valid:
                network.subscribe(cfg.cob_id, self._guard(self._rpdo_handler(n)))
        self.node.nmt.state = "INITIALISING"  # boot-up message
        if 0x1017 in self.od:
            self.node.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat if 0x1017 is set
        else:
            self.node.nmt._state = 127  # Pre-operational, no heartbeat to start (canopen would look up 0x1017)

    def _guard(self, callback):
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

    def _send(self, cob_id: int, payload: bytes) -> None:
        if self.network is not None:
            self.network.send_message(cob_id, payload)

    # --- CiA 402 -------------------------------------------------------------------------------

    @property
    def mode_spec(self):
        return self.desc.mode_by_code(self.mode_code)

    def loop_mode(self) -> str | None:
        """The drive loop mode of the selected mode of operation (None: not one this drive runs)."""
        spec = self.mode_spec
        if self.desc.explicit_modes:
            return spec.name if spec is not None else None
        name = mode_name_of_code(self.mode_code)
        return _LOOP_MODE_OF_CODE.get(self.mode_code) if name in self.supported else None

    def statusword(self) -> int:
        internal_limit = self.drive.fault is not None
        return cia402.statusword(self.state, target_reached=self.table_state == TableState.DONE,
                                 internal_limit=internal_limit)

    def apply_controlword(self, cw: int) -> None:
        new, number = cia402.transition(self.state, cw, self.cw)
        if new is self.state:
            self.cw = cw
            return
        if new is cia402.State.OPERATION_ENABLED:
            loop_mode = self.loop_mode()
            if not self.limits_loaded or loop_mode is None:
                raise SdoAbortedError(ABORT_STATE)  # no limits loaded, or no supported mode selected
            self.drive.set_mode(loop_mode)
            self.drive.enable()
            self._start_run()
        elif self.state is cia402.State.OPERATION_ENABLED:
            self._power_off()
        if number == 15:  # fault reset
            self.drive.clear_fault()
            self.error_code = 0
            self._send(0x80 + self.node.id, struct.pack("<HB5s", 0, 0, b""))  # EMCY error reset
        self.cw = cw
        self.state = new

    def _start_run(self) -> None:
        self.sample_index = 0
        self.underruns = 0
        self.sync_errors = 0
        self.last_sync_counter = None
        self.sync_driven = False
        self.position_setpoint_m: float | None = None  # last position set-point, the start of the next ramp
        self.run_start_tick = self.drive.tick
        self.injected = set()
        self.coast_ticks = 0

    def _power_off(self) -> None:
        self.drive.disable()
        if self.table_state == TableState.PLAYING:
            self.table_state = TableState.STOPPED
        self.coast_ticks = int(COAST_S * self.loop_rate)
        self.coast_clock = time.monotonic()

    def fault(self, code: int, sample_index: int) -> None:
        """Enter Fault: power stage off, EMCY with ``code`` and the run's sample index."""
        if self.state is cia402.State.FAULT:
            return
        self._power_off()
        self.state = cia402.State.FAULT
        self.error_code = code
        self.error_history = [code, *self.error_history][:8]
        data = struct.pack("<I", max(0, int(sample_index)) & 0xFFFFFFFF) + b"\0"
        self._send(0x80 + self.node.id, struct.pack("<HB5s", code, error_register(code), data))

    def _check_faults(self) -> None:
        """After the physics advanced: limit trips and the injected faults."""
        drive = self.drive
        divider = self._divider()
        if drive.fault is not None and self.state is cia402.State.OPERATION_ENABLED:
            index = (int(drive.fault_tick) - self.run_start_tick) // divider
            self.fault(EMCY_OF_TRIP.get(drive.fault, 0x8311), index)
        elapsed = (drive.tick - self.run_start_tick) / self.loop_rate
        f = self.faults
        if (f.drive_fault_after_s and elapsed >= f.drive_fault_after_s and "drive" not in self.injected
                and self.state is cia402.State.OPERATION_ENABLED):
            self.injected.add("drive")
            self.fault(EMCY_DRIVE_FAULT, (drive.tick - self.run_start_tick) // divider)
        if f.heartbeat_stops_after_s and elapsed >= f.heartbeat_stops_after_s and not self.heartbeat_stopped:
            self.heartbeat_stopped = True
            self.node.nmt.stop_heartbeat()

    def _pending_fault_times(self) -> list[float]:
        """Run times (s) of the injected faults still to come in this run."""
        f, times = self.faults, []
        if f.drive_fault_after_s and "drive" not in self.injected:
            times.append(f.drive_fault_after_s)
        if f.heartbeat_stops_after_s and not self.heartbeat_stopped:
            times.append(f.heartbeat_stops_after_s)
        return times

    def _divider(self) -> int:
        if self.table_state == TableState.PLAYING or not self.sync_divider:
            return self.table_divider
        return self.sync_divider

    # --- live values -----------------------------------------------------------------------------

    def _live(self, role: str | None, addr: ObjectAddress, row, k: int):
        """Raw value of a readable object for the sample in ``row`` (SDO reads and TPDOs)."""
        if role in COLUMN_OF_ROLE:
            column, scale, lo, hi = self._scalar_codec(role, addr)
            x = float(row[column])
            if scale is None:
                return x  # REAL32
            v = x / scale
            if not math.isfinite(v):
                return 0
            return min(max(round(v), lo), hi)  # as encode_si: half to even, clipped to the type
        if role == "sample_counter":
            return k & 0xFFFF
        if role == "statusword":
            return self.statusword()
        if role in ("modes_display", "modes_of_operation"):
            return self.mode_code
        if role in self.targets:
            return self.targets[role]
        if role == "setpoint_counter":
            return self.rx_counter
        if role == "controlword":
            return self.cw
        if role == "error_code":
            return self.error_code
        if role == "error_register":
            return error_register(self.error_code) if self.error_code else 0
        return self._stored(addr.index, addr.subindex)

    def _scalar_codec(self, role: str, addr: ObjectAddress):
        """(row column, SI per unit or None for REAL32, type minimum, type maximum) of a sampled object."""
        codec = self._codecs.get(addr)
        if codec is None:
            obj = self._variable(addr)
            column = self.columns[COLUMN_OF_ROLE[role]]
            if obj.data_type == REAL32:
                codec = (column, None, 0, 0)
            else:
                info = np.iinfo(numpy_type(obj.data_type))
                codec = (column, self.scales[role], int(info.min), int(info.max))
            self._codecs[addr] = codec
        return codec

    def _capture_columns(self, rows: np.ndarray, first: int) -> np.ndarray:
        """Capture records of ``rows`` (samples ``first`` ...) as a packed structured array."""
        out = np.empty(len(rows), dtype=record_dtype([t for _, t in self.capture_layout]))
        for i, (role, dtype) in enumerate(self.capture_layout):
            if role in COLUMN_OF_ROLE:
                out[f"f{i}"] = encode_si(rows[:, self.columns[COLUMN_OF_ROLE[role]]], dtype, self.scales[role])
            elif role == "sample_counter":
                out[f"f{i}"] = (first + np.arange(len(rows))) & 0xFFFF
            else:  # statusword, mode display: constant over a chunk
                out[f"f{i}"] = self._live(role, self.desc.address(role), rows[0], first)
        return out

    def _tpdo_frames(self, row, k: int) -> list[tuple[int, bytes]]:
        frames = []
        for (kind, n), cfg in self.pdos.items():
            if kind != "tpdo" or not cfg.valid or cfg.packer is None:
                continue
            if cfg.trans_type > 1 and (k % cfg.trans_type):
                continue
            values = [self._live(self.role_of.get(addr), addr, row, k) for addr, _ in cfg.entries]
            frames.append((cfg.cob_id, cfg.packer.pack(*values)))
        return frames

    # --- SYNC and PDOs -----------------------------------------------------------------------

    def _on_sync(self, can_id, data, timestamp) -> None:
        frames = []
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL":
                return
            if len(data) >= 1 and self.sync_overflow > 1:
                counter = data[0]
                if self.last_sync_counter is not None and counter != self.last_sync_counter % self.sync_overflow + 1:
                    self.sync_errors += 1
                self.last_sync_counter = counter
            if self.state is not cia402.State.OPERATION_ENABLED or self.table_state == TableState.PLAYING:
                return
            self.sync_driven = True
            self.last_sync_wall = time.monotonic()
            k = self.sample_index
            if self.rx_counter != k & 0xFFFF:
                self.underruns += 1  # no fresh set-point for this sample: the last one is held
            rows = self.drive.run(self._setpoint_ticks(self._setpoint_si()))
            self.sample_index = k + 1
            self.last_row = rows[-1]
            frames = self._tpdo_frames(rows[0], k)
            rate = self.faults.drop_pdo_rate
            for cob_id, payload in frames:
                if rate and self.rng.random() < rate:
                    self.tpdos_dropped += 1
                    self.dropped.append((k, cob_id))
                    continue
                self._send(cob_id, payload)
            self._check_faults()

    def _si(self, role: str) -> float:
        return self.targets.get(role, 0) * self.scales.get(role, 1.0)

    def _setpoint_ticks(self, target: float) -> np.ndarray:
        """The loop's input for each tick of one SYNC period.

        A position set-point (CSP, IP) is interpolated linearly from the last
        one over the period (CiA 402 linear interpolation, 0x60C0 = 0): a step
        every period would jolt the position loop at the SYNC rate. Other
        set-points are held.
        """
        n = self._divider()
        if self.drive.mode != "position":
            return np.full(n, target)
        start = target if self.position_setpoint_m is None else self.position_setpoint_m
        self.position_setpoint_m = target
        return start + (target - start) * np.arange(1, n + 1) / n

    def _setpoint_si(self) -> float:
        """The drive loop's input for the next ticks; the torque offset (0x60B2) goes to the loop on its own."""
        if self.desc.explicit_modes:
            spec = self.mode_spec
            x = self._si(spec.setpoint)
            if spec.name == "position":
                x -= self.drive.hold_position_m  # CSP targets are absolute; the drive loop takes them relative
            return x
        self.drive.torque_offset_nm = self._si("torque_offset")
        if self.mode_code == 10:
            return self._si("target_torque")
        if self.mode_code == 9:
            return self._si("target_velocity")
        target = "target_position" if self.mode_code == 8 else "interpolation_data"
        return self._si(target) - self.drive.hold_position_m

    def _rpdo_handler(self, n: int):
        def on_rpdo(can_id, data, timestamp):
            with self.lock:
                cfg = self.pdos[("rpdo", n)]
                if self.node.nmt.state != "OPERATIONAL" or not cfg.valid or cfg.packer is None:
                    return
                if len(data) < cfg.packer.size:
                    return  # CiA 301: a too-short PDO is not processed
                for (addr, _), value in zip(cfg.entries, cfg.packer.unpack_from(bytes(data))):
                    role = self.role_of.get(addr)
                    if role in self.targets:
                        self.targets[role] = value
                    elif role == "setpoint_counter":
                        self.rx_counter = value
                    elif role == "controlword":
                        try:
                            self.apply_controlword(value)
                        except SdoAbortedError:
                            pass
        on_rpdo.__name__ = f"on_rpdo{n + 1}"
        return on_rpdo

    def _on_nmt(self, can_id, data, timestamp) -> None:
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL" and self.state is cia402.State.OPERATION_ENABLED:
                self._power_off()  # communication lost its operational state: switch off
                self.state = cia402.State.SWITCH_ON_DISABLED

    # --- heartbeat consumer (0x1016) and abort connection option (0x6007) -------------------------

    def _write_consumer(self, sub: int, value: int) -> None:
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
            if self.network is not None:
                self.network.subscribe(0x700 + node_id, self._on_producer)

    def _on_producer_heartbeat(self, can_id, data, timestamp) -> None:
        node_id = can_id - 0x700
        with self.lock:
            if any(n == node_id for n, _ in self.consumers.values()):
                self.heard[node_id] = timestamp
                self.host_lost.discard(node_id)

    def on_frame(self, msg) -> None:
        """Every received frame, after its handlers ran: how far the drive has read the bus.

        Also node guarding (CiA 301), for a drive that has a guard time
        (0x100C): a remote frame on 0x700 + node id is answered with the NMT
        state and the toggle bit, and restarts the life guarding.
        """
        if msg.is_remote_frame and msg.arbitration_id == 0x700 + self.node.id and 0x100C in self.od:
            with self.lock:
                self._answer_guarding(msg.timestamp)
        self.last_frame = (msg.timestamp, time.monotonic())

    def _answer_guarding(self, timestamp: float) -> None:
        state = {"OPERATIONAL": 5, "STOPPED": 4, "PRE-OPERATIONAL": 127}.get(self.node.nmt.state, 127)
        self._send(0x700 + self.node.id, bytes([state | self.guard_toggle]))
        self.guard_toggle ^= 0x80
        self.guard_heard = timestamp
        self.guard_lost = False

    def _check_life_guarding(self, now: float) -> None:
        """Life guarding: no guard request for guard time x life time factor (0x100C x 0x100D) -> the
        drive has lost its host (EMCY 0x8130, then what 0x6007 says)."""
        if self.guard_heard is None or self.guard_lost or 0x100D not in self.od:
            return
        lifetime_s = int(self._stored(0x100C, 0)) * int(self._stored(0x100D, 0)) / 1000.0
        if lifetime_s <= 0:
            return
        deadline = self.guard_heard + lifetime_s
        last_stamp, last_handled = self.last_frame
        idle = now - max(last_handled, self.resumed) > IDLE_S
        if last_stamp > deadline or (time.time() > deadline and idle):
            self.guard_lost = True
            self.heartbeat_events += 1
            self.heartbeat_event_wall = time.time()
            self._abort_connection()

    def _check_consumers(self, now: float) -> None:
        """The heartbeat event: a watched producer silent for longer than its consumer time.

        A real drive handles each frame as it arrives. This one reads the bus in
        a thread that may lag behind a flood of SYNCs, so silence is judged by
        bus timestamps: the event fires when a frame stamped after the deadline
        was read with no heartbeat before it, or when the deadline passed and
        nothing is left to read (``IDLE_S`` without a frame, counted from when the
        twin's own clock ran again after a stall of ``STALL_S``: a process that
        was not scheduled has frames waiting that its reader threads have not
        had the chance to read).
        """
        wall = time.time()
        last_stamp, last_handled = self.last_frame
        for node_id, time_ms in self.consumers.values():
            seen = self.heard.get(node_id)
            if seen is None or node_id in self.host_lost:
                continue
            deadline = seen + time_ms / 1000.0
            idle = now - max(last_handled, self.resumed) > IDLE_S
            if not (last_stamp > deadline or (wall > deadline and idle)):
                continue
            self.host_lost.add(node_id)
            self.heartbeat_events += 1
            self.heartbeat_event_wall = wall
            self._abort_connection()

    def _abort_connection(self) -> None:
        """EMCY 0x8130, then the action of the abort connection option code (0x6007)."""
        option = int(self._stored(ABORT_CONNECTION_INDEX, 0)) if ABORT_CONNECTION_INDEX in self.od else 1
        if option == 1:
            self.fault(EMCY_HEARTBEAT, self.sample_index)
            return
        self.error_history = [EMCY_HEARTBEAT, *self.error_history][:8]
        data = struct.pack("<I", max(0, int(self.sample_index)) & 0xFFFFFFFF) + b"\0"
        self._send(0x80 + self.node.id, struct.pack("<HB5s", EMCY_HEARTBEAT, error_register(EMCY_HEARTBEAT), data))
        if option in (2, 3) and self.state in (cia402.State.OPERATION_ENABLED, cia402.State.SWITCHED_ON,
                                               cia402.State.READY_TO_SWITCH_ON, cia402.State.QUICK_STOP_ACTIVE):
            if self.state is cia402.State.OPERATION_ENABLED:
                self._power_off()  # quick stop in a torque mode: the torque ramps to zero; here at once
            self.state = cia402.State.SWITCH_ON_DISABLED

    def _write_abort_option(self, value: int) -> None:
        if not 0 <= value <= 3:
            raise SdoAbortedError(ABORT_VALUE)  # negative (manufacturer) codes: none on this drive

    # --- SDO callbacks ----------------------------------------------------------------------------

    def _on_read(self, index: int, subindex: int, od):
        addr = ObjectAddress(index, subindex)
        role = self.role_of.get(addr)
        with self.lock:
            if self.recorder is not None and self.recorder.owns(addr) and (live := self.recorder.on_read(addr)) is not None:
                return live
            if role == "capture_data":
                return self._capture_chunk()
            if role in COLUMN_OF_ROLE or role in ("sample_counter", "statusword", "modes_display", "error_code",
                                                   "error_register", "modes_of_operation", "controlword",
                                                   "setpoint_counter") or role in self.targets:
                row = self.last_row
                if role == "position_actual":  # the encoder now, as the loop would sample it (the hold at enable)
                    row = row.copy()
                    row[self.columns["position_m"]] = self.drive.sensors.encoder(self.drive.plant.p1)
                return self._live(role, addr, row, self.sample_index)
            values = {
                "supported_modes": encode_supported_modes(self.supported),
                "setpoint_underruns": self.underruns, "sync_errors": self.sync_errors,
                "table_length": len(self.table), "table_state": self.table_state,
                "capture_count": self.capture_count, "capture_offset": self.capture_offset,
                "table_divider": self.table_divider,
            }
            if role in values:
                return values[role]
            if self.desc.has("error_history") and index == self.desc.address("error_history").index:
                if subindex == 0:
                    return len(self.error_history)
                return self.error_history[subindex - 1] if subindex <= len(self.error_history) else 0
        return self._unset_value(index, subindex, od)

    def _unset_value(self, index: int, subindex: int, od):
        """The answer for an object never written whose EDS entry has no default (None: canopen serves it).

        A drive answers every readable object: the identity from the EDS's
        [DeviceInfo], an empty string, or 0.
        """
        string = od.data_type in _STRING_TYPES
        if subindex in self.node.data_store.get(index, {}) or (
                (od.default is not None or od.value is not None) and not (string and not (od.value or od.default))):
            return None
        info = self.od.device_information
        if (index, subindex) == (0x1018, 1) and info.vendor_number:
            return int(info.vendor_number)
        if (index, subindex) == (0x1018, 2) and info.product_number:
            return int(info.product_number)
        if (index, subindex) == (0x1008, 0):
            return info.product_name or self.driver.name
        if string:
            return "n/a"  # an empty string cannot be uploaded (SDO abort 0x08000024); a drive says something
        return b"\0" if od.data_type == DOMAIN else 0

    def _capture_chunk(self) -> bytes:
        start = self.capture_offset
        stop = min(self.capture_count, start + CAPTURE_CHUNK_RECORDS)
        if stop <= start:
            raise SdoAbortedError(ABORT_NO_DATA)
        size = self.capture_record_size
        return bytes(self.capture[start * size:stop * size])

    def _on_write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = od.decode_raw(data) if od.data_type in NUMERIC_TYPES else bytes(data)
        addr = ObjectAddress(index, subindex)
        role = self.role_of.get(addr)
        with self.lock:
            if self.recorder is not None and self.recorder.owns(addr):
                return self.recorder.on_write(addr, value)
            base = index & 0xFE00
            if base in _PDO_KINDS and (("rpdo" if base < 0x1800 else "tpdo"), index - base) in self.pdos:
                self._write_pdo(base, index - base, subindex, int(value))
                return
            if index == HEARTBEAT_CONSUMER_INDEX and subindex > 0:
                self._write_consumer(subindex, int(value))
                return
            if index == ABORT_CONNECTION_INDEX:
                self._write_abort_option(int(value))
                return
            if self.desc.filters is not None and index in self.desc.filters.indices:
                slot = self.desc.filters.indices.index(index)
                if self.desc.filters.enable_subindex is None:  # one block, its enable inside
                    if subindex == self.desc.filters.fields["block"]:
                        self._apply_filter(slot, None, {"block": bytes(value)})
                elif subindex == self.desc.filters.enable_subindex:
                    self._apply_filter(slot, bool(value))
                return
            if self.desc.has("capture_mapping") and index == self.desc.address("capture_mapping").index:
                self._write_capture_mapping(subindex, int(value))
                return
            if self.desc.has("error_history") and index == self.desc.address("error_history").index:
                if value != 0:
                    raise SdoAbortedError(ABORT_VALUE)
                self.error_history = []
                return
            handler = {
                "store_parameters": lambda: self._store_parameters(int(value)),
                "controlword": lambda: self.apply_controlword(int(value)),
                "modes_of_operation": lambda: self._write_mode(int(value)),
                "cycle_period": lambda: self._write_cycle_period(int(value)),
                "interpolation_period": lambda: self._write_interpolation_period(int(value), None),
                "interpolation_exponent": lambda: self._write_interpolation_period(None, int(value)),
                "setpoint_counter": lambda: setattr(self, "rx_counter", int(value)),
                "table": lambda: self._write_table(value),
                "table_divider": lambda: self._write_table_divider(int(value)),
                "table_command": lambda: self._write_table_command(int(value)),
                "capture_offset": lambda: self._write_capture_offset(int(value)),
                "sync_overflow": lambda: setattr(self, "sync_overflow", int(value)),
            }.get(role)
            if handler is not None:
                handler()
            elif role in self.targets:
                self.targets[role] = int(value)
            elif role in LIMIT_ROLES:
                self._write_limit(role, int(value))

    def _write_pdo(self, base: int, n: int, sub: int, value: int) -> None:
        kind, part = _PDO_KINDS[base]
        cfg = self.pdos[(kind, n)]
        if part == "comm":
            if sub == 1:
                valid = not value & 0x80000000
                if valid and cfg.valid and (value & 0x7FF) != cfg.cob_id:
                    raise SdoAbortedError(ABORT_VALUE)  # CiA 301: invalidate a PDO before moving it
                if kind == "rpdo" and self.network is not None:
                    if cfg.valid:
                        self.network.unsubscribe(cfg.cob_id)
                    if valid:
                        self.network.subscribe(value & 0x7FF, self._guard(self._rpdo_handler(n)))
                cfg.cob_id, cfg.valid = value & 0x7FF, valid
            elif sub == 2:
                if kind == "tpdo" and not 1 <= value <= 240:
                    raise SdoAbortedError(ABORT_VALUE)  # this drive sends TPDOs on SYNC only
                cfg.trans_type = value
            return
        if cfg.valid:
            raise SdoAbortedError(ABORT_STATE)  # mapping changes need the PDO invalid
        if sub == 0:
            self._set_mapping(kind, n, cfg, value)  # entries 1..value were stored before

    def _write_mode(self, code: int) -> None:
        previous, self.mode_code = self.mode_code, code
        loop_mode = self.loop_mode()
        if loop_mode is None:
            self.mode_code = previous
            raise SdoAbortedError(ABORT_VALUE)
        if self.state is cia402.State.OPERATION_ENABLED:
            self.drive.set_mode(loop_mode)
            self.position_setpoint_m = None

    def _write_cycle_period(self, period_us: int) -> None:
        if period_us == 0:
            self.sync_divider = 0
            return
        ticks = period_us * self.loop_rate / 1e6
        if abs(ticks - round(ticks)) > 1e-6 or not 1 <= round(ticks) <= 65535:
            raise SdoAbortedError(ABORT_VALUE)  # the SYNC period must be whole loop ticks
        self.sync_divider = int(round(ticks))

    def _store_parameters(self, value: int) -> None:
        """0x1010:1: with the signature "save" the drive keeps its parameters (here: the filter slots) as stored."""
        if value != 0x65766173:
            raise SdoAbortedError(0x08000020)  # data cannot be transferred or stored (CiA 301)
        self.stored_parameters = {slot: self.drive.filters.read(slot) for slot in range(len(self.drive.filters.enabled))}
        self.saves += 1

    def _write_interpolation_period(self, value: int | None, exponent: int | None) -> None:
        """0x60C2: the sample period is ``value * 10**exponent`` s; it must be whole loop ticks."""
        period = list(self.interpolation_period)
        if value is not None:
            period[0] = value
        if exponent is not None:
            period[1] = exponent
        seconds = period_from_fields(*period)
        ticks = seconds * self.loop_rate
        if seconds and (abs(ticks - round(ticks)) > 1e-6 or not 1 <= round(ticks) <= 65535):
            if value is not None:  # the exponent may come second: only a value that fits no exponent is refused
                raise SdoAbortedError(ABORT_VALUE)
        self.interpolation_period = period
        if seconds and abs(ticks - round(ticks)) <= 1e-6 and 1 <= round(ticks) <= 65535:
            self.sync_divider = int(round(ticks))

    def _write_limit(self, role: str, raw: int) -> None:
        if role in ("max_torque", "max_velocity") and raw <= 0:
            raise SdoAbortedError(ABORT_TOO_LOW)
        self.limits_raw[role] = raw
        held = [r for r in LIMIT_ROLES if self.desc.has(r) and r in self.scales]
        if not all(r in self.limits_raw for r in held):
            return
        si = {r: self.limits_raw[r] * self.scales[r] if r in held else None for r in LIMIT_ROLES}
        if (si["position_limit_min"] is not None and si["position_limit_max"] is not None
                and si["position_limit_min"] >= si["position_limit_max"]):
            self.limits_loaded = False  # one end written, the other still to come
            return
        try:
            self.drive.set_limits(si["max_torque"], si["max_velocity"], si["position_limit_min"],
                                  si["position_limit_max"])
        except (ConfigError, ValueError):
            raise SdoAbortedError(ABORT_VALUE) from None
        self.limits_loaded = True

    def _apply_filter(self, slot: int, enabled: bool | None, values: dict | None = None) -> None:
        """Load a slot's section into the drive loop: from its stored fields when its enable is written, or
        from the block being written (``values``; its state word says ``enabled``)."""
        fo = self.desc.filters
        if values is None:
            values = {name: self._stored(fo.indices[slot], sub) for name, sub in fo.fields.items()}
        try:
            if enabled is None:
                enabled = bool(self.encoding.slot_enabled(values))
            biquad = self.encoding.applied(values, self.loop_rate)
        except (DataError, ConfigError):
            raise SdoAbortedError(ABORT_VALUE) from None
        if enabled and not biquad.is_stable():
            raise SdoAbortedError(ABORT_VALUE)  # an unstable section is never switched in
        self.drive.filters.write(slot, biquad, enabled)

    # --- drive-buffered runs -----------------------------------------------------------------

    def _size_limit(self, index: int, subindex: int) -> int | None:
        if self.desc.has("table") and ObjectAddress(index, subindex) == self.desc.address("table"):
            return 4 * self.table_capacity
        return None

    def _write_table(self, data: bytes) -> None:
        if self.table_state == TableState.PLAYING:
            raise SdoAbortedError(ABORT_STATE)
        if len(data) % 4:
            raise SdoAbortedError(ABORT_LENGTH)
        if len(data) // 4 > self.table_capacity:
            raise SdoAbortedError(ABORT_LENGTH_HIGH)
        values = np.frombuffer(data, dtype="<f4")
        if not np.all(np.isfinite(values)):
            raise SdoAbortedError(ABORT_VALUE)
        self.table = values.copy()
        self.table_state = TableState.IDLE

    def _write_table_divider(self, divider: int) -> None:
        if self.table_state == TableState.PLAYING:
            raise SdoAbortedError(ABORT_STATE)
        if not 1 <= divider or self.loop_rate / divider > self.driver.max_sample_rate_hz:
            raise SdoAbortedError(ABORT_VALUE)
        self.table_divider = divider

    def _write_capture_mapping(self, sub: int, value: int) -> None:
        if self.table_state == TableState.PLAYING:
            raise SdoAbortedError(ABORT_STATE)
        if sub != 0:
            return
        index = self.desc.address("capture_mapping").index
        layout, size = [], 0
        for s in range(1, value + 1):
            addr, width = parse_mapping_entry(int(self._stored(index, s)))
            obj = self.od.get_variable(addr.index, addr.subindex)
            role = self.role_of.get(addr)
            if obj is None or obj.data_type not in NUMERIC_TYPES or width != type_bits(obj.data_type) or not (
                    role in COLUMN_OF_ROLE or role in ("sample_counter", "statusword", "modes_display")):
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)  # only sampled signals can be captured
            layout.append((role, obj.data_type))
            size += width // 8
        self.capture_layout = layout
        self.capture_record_size = size

    def _write_capture_offset(self, offset: int) -> None:
        if offset > self.capture_count:
            raise SdoAbortedError(ABORT_TOO_HIGH)
        self.capture_offset = offset

    def _write_table_command(self, command: int) -> None:
        if command == TABLE_STOP:
            if self.table_state == TableState.PLAYING:
                self.table_state = TableState.STOPPED
            return
        if command != TABLE_START:
            raise SdoAbortedError(ABORT_VALUE)
        if (self.state is not cia402.State.OPERATION_ENABLED or self.table_state == TableState.PLAYING
                or not len(self.table) or not self.capture_layout):
            raise SdoAbortedError(ABORT_STATE)
        self._start_run()
        self.table_state = TableState.PLAYING
        self.play_pos = 0
        self.play_origin = time.monotonic()
        self.play_origin_pos = 0
        self.capture = bytearray()
        self.capture_count = 0
        self.capture_offset = 0
        self.capture_stopped = False

    def advance_table(self, now: float) -> None:
        """Play the excitation table up to wall time ``now`` (at ``time_scale``) and capture."""
        rate = self.loop_rate / self.table_divider
        due = int((now - self.play_origin) * rate * self.time_scale) - (self.play_pos - self.play_origin_pos)
        cap = max(1, int(0.05 * rate * self.time_scale))
        if due > cap:  # fell behind (a slow machine): resume from now, never burst
            self.play_origin, self.play_origin_pos, due = now, self.play_pos, cap
        n = min(due, len(self.table) - self.play_pos)
        first = self.play_pos
        for t in self._pending_fault_times():  # stop exactly where an injected fault is due
            k = math.ceil(t * rate - 1e-9)
            if first < k < first + n:
                n = k - first
        if n <= 0:
            return
        divider = self.table_divider
        rows = self.drive.run(np.repeat(self.table[first:first + n].astype(float), divider))[::divider]
        self.play_pos = self.sample_index = first + n
        self.last_row = rows[-1]
        keep = n
        stop_after = self.faults.capture_stops_after_s
        if stop_after:
            keep = min(keep, max(0, math.ceil(stop_after * rate) - first))
        if self.drive.fault is not None and self.drive.fault_tick is not None:
            keep = min(keep, (int(self.drive.fault_tick) - self.run_start_tick) // divider - first + 1)
        if keep > 0 and not self.capture_stopped:
            self.capture += self._capture_columns(rows[:keep], first).tobytes()
            self.capture_count += keep
        if keep < n:
            self.capture_stopped = True
        self._check_faults()
        if self.table_state == TableState.PLAYING and self.play_pos >= len(self.table):
            self.table_state = TableState.DONE
            self._power_off()  # end of table: disable operation (transition 5), torque off
            self.state = cia402.State.SWITCHED_ON

    def tick(self, now: float) -> None:
        """Clock work: the heartbeat consumer, table playback, coasting with the power stage off, the SYNC watchdog."""
        with self.lock:
            if now - self.last_tick > STALL_S:
                self.resumed = now
            self.last_tick = now
            if self.consumers:
                self._check_consumers(now)
            self._check_life_guarding(now)
            if self.recorder is not None:
                self.recorder.tick(now)
            if self.state is cia402.State.OPERATION_ENABLED:
                if self.table_state == TableState.PLAYING:
                    self.advance_table(now)
                elif (self.sync_driven and self.last_sync_wall is not None
                      and now - self.last_sync_wall > SYNC_WATCHDOG_S):
                    self.fault(EMCY_SYNC_TIMEOUT, self.sample_index)
            elif self.coast_ticks > 0:
                n = min(self.coast_ticks, int((now - self.coast_clock) * self.loop_rate * self.time_scale))
                if n > 0:
                    self.last_row = self.drive.run(np.zeros(n))[-1]
                    self.coast_ticks -= n
                    self.coast_clock = now
