"""Host side of a CiA 402 servo drive on CANopen (python-can + canopen).

The adapter opens the bus ``[device]`` names (:mod:`hilident.adapters.canopen_link`),
loads the drive's EDS from its driver folder, checks the identity object against
the driver description, asks for a heartbeat and listens to it and to the
drive's emergencies, drives the CiA 402 state machine
(:mod:`hilident.protocol.cia402`) to Operation Enabled for each run and back
to a safe state (Disable Voltage: zero torque) on every exit path.

Each run is played one of three ways (``device.acquisition``; ``"auto"`` takes the
driver's ``default_acquisition``):

``"streamed"`` (:mod:`hilident.adapters.canopen_streamed`)
    the host sends an RPDO set-point and a SYNC every sample period and
    receives TPDOs carrying a sample counter: lost and late frames are counted;
``"buffered"`` (:mod:`hilident.adapters.canopen_buffered`)
    the excitation table goes to the drive by SDO (block transfer), the drive
    plays it at its own rate and captures; the host reads the capture back in
    chunks while it runs;
``"recorder"`` (:mod:`hilident.adapters.canopen_recorder`)
    the drive's own generator plays the excitation (a PRBS, a sweep, a sine,
    set up from its parameters) and its recorder records; the host reads the
    recorder's buffers by SDO once it is done.

Connecting brings the drive to a known state whatever the previous session left
(it may have been killed): the drive is told NMT Pre-operational (no PDOs from
before), frames that arrived before that are discarded and counted, the power
stage is switched off (Disable Voltage: Switch On Disabled), and a drive in
Fault is reported with its error code (0x603F) and reset only with
``device.allow_fault_reset``; otherwise the connection is refused.

The device-side net for a host that dies hard (SIGKILL, power cut, cable
pulled): the host produces a heartbeat (COB-ID 0x700 + ``[canopen]
host_node_id``, state Operational) every third of ``device.host_timeout_s``
from a background thread, and arms the drive's heartbeat consumer (0x1016) to
watch it with ``host_timeout_s``; where the EDS has the abort connection option
code (0x6007) it is set to ``[canopen] abort_connection_option`` (2, Disable
Voltage, by default). A drive whose EDS lacks 0x1016 gets no net, and
``connect_report.device_net`` says so.

SDO aborts become :class:`~hilident.errors.DeviceError` naming the object
(``0x6072:0 (Max torque)``) and the abort's meaning. canopen's ``BaseNode402``
is not used: the state machine and the PDO set-up live here and in
:mod:`hilident.protocol`.
"""

from __future__ import annotations

import collections
import contextlib
import io
import math
import time
from struct import error as struct_error
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hilident.adapters.base import AdapterBase, ConnectReport, RunResult, refuse_latched_faults
from hilident.adapters.canopen_buffered import BufferedRun
from hilident.adapters.canopen_link import open_network
from hilident.adapters.canopen_recorder import RecorderRun, configure_recorder
from hilident.adapters.canopen_streamed import StreamedRun
from hilident.events import Kind, RunEvent
from hilident.config import DeviceConfig
from hilident.drivers import DriverDescription, load_object_dictionary
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    ABORT_CONNECTION_INDEX, ABORT_CONNECTION_OPTIONS, HEARTBEAT_CONSUMER_INDEX, CanopenDescription, ObjectAddress,
    REAL32, consumer_entry, encode_si, mapping_entry, numpy_type, pack_frames, parse_address, parse_consumer_entry,
    type_bits,
)
from hilident.protocol.canopen_profile import decode_supported_modes, mapping_capacity, period_fields
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["CanopenDriveAdapter", "DriveIdentity", "ChannelCodec", "LIMIT_TRIP_CODES"]

#: How a run is played, by acquisition name (``device.acquisition``): a strategy ``(adapter, x, deliver,
#: result)`` (:class:`~hilident.adapters.base.RunStrategy`). A new acquisition strategy joins with one line.
ACQUISITIONS = {
    "streamed": StreamedRun.play,
    "buffered": BufferedRun.play,
    "recorder": RecorderRun.play,
}

#: Emergency codes that mean a safety limit tripped (they raise LimitTrip).
LIMIT_TRIP_CODES = {0x8311: "torque_limit", 0x8400: "velocity_limit", 0x8612: "position_limit"}
_NMT_OPERATIONAL = 5
_TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
_ABORT_GENERAL = 0x08000000  # SDO abort code: general error (a transfer the host broke off)
_TRANSFER_ERRORS = (SdoAbortedError, SdoCommunicationError, can.CanError, OSError)
_STATE_POLL_S = 0.002
#: CiA 301 store parameters (0x1010): writing "save" (ASCII, little-endian) stores them in non-volatile memory.
STORE_SIGNATURE = 0x65766173
_GUARD_TIME, _LIFE_TIME_FACTOR = 0x100C, 0x100D  # CiA 301 node guarding


def _transfer_error(exc: BaseException) -> BaseException | None:
    """The SDO or bus error behind ``exc``, or None when ``exc`` is something else.

    canopen 2.4.1's ``BlockUploadStream._end_upload`` calls a method it does not
    have (``self.abort``) when the end-of-upload response times out, so a drive
    that vanishes at the end of a capture surfaces as an ``AttributeError``
    raised while handling the ``SdoCommunicationError``: that one is the cause.
    """
    while exc is not None:
        if isinstance(exc, _TRANSFER_ERRORS):
            return exc
        if not isinstance(exc, AttributeError):
            return None
        exc = exc.__context__
    return None


@dataclass(frozen=True)
class DriveIdentity:
    """What the drive reported (0x1008, 0x100A, 0x1018) and what its driver description adds."""

    name: str
    firmware: str
    loop_rate_hz: float
    filter_slots: int
    vendor_id: int
    product_code: int


@dataclass(frozen=True)
class ChannelCodec:
    """A recorded channel: the object carrying it, its CANopen data type and SI value per unit.

    ``role`` and ``address`` are None for a channel the host records itself
    (the set-point it sent, on a drive that does not report the one it applied).
    """

    name: str
    unit: str
    role: str | None
    address: ObjectAddress | None
    datatype: int
    scale: float

    @property
    def bits(self) -> int:
        return type_bits(self.datatype)

    @property
    def on_host(self) -> bool:
        return self.address is None


@dataclass(frozen=True)
class PdoSlot:
    """One PDO the drive's EDS declares: its number, how many objects it maps at most, its COB-ID."""

    number: int
    max_entries: int
    cob_id: int


@dataclass
class Emergency:
    """One EMCY message as received."""

    code: int
    register: int
    data: bytes
    received_s: float


class CanopenDriveAdapter(AdapterBase):
    """A CiA 402 drive on a CAN bus.

    Open it with :meth:`open_device`. Attributes follow
    :class:`~hilident.adapters.base.DeviceAdapter`; beyond them:

    Attributes
    ----------
    acquisition : {"streamed", "buffered", "recorder"}
        How :meth:`stream` plays a run.
    sync_rate_hz : float or None
        SYNC frames per second in streamed runs; None: the sample rate (real
        time). Only an emulated drive, whose clock follows SYNC, may run faster.
    """

    transport = "canopen"

    def __init__(self, network, node: canopen.RemoteNode, driver: DriverDescription, desc: CanopenDescription,
                 device: DeviceConfig, label: str):
        self.network = network
        self.node = node
        self.driver = driver
        self.desc = desc
        self.device = device
        self.port = label
        self.timeout_s = device.timeout_s
        self.encoding = FilterEncoding.from_table(driver.sections["filters"], str(driver.folder)) \
            if desc.filters is not None else None
        self.acquisition = desc.default_acquisition if device.acquisition == "auto" else device.acquisition
        self.identity: DriveIdentity | None = None
        self.sample_rate_hz = 0.0
        self.divider = 0
        self.mode = ""
        self.channels: list[ChannelCodec] = []
        self.channel_names: list[str] = []
        self.channel_units: list[str] = []
        self.sync_rate_hz: float | None = None
        self.sync_overflow = 0
        self.rated_torque_nm = 0.0
        self.rated_current_a = 0.0
        self.torque_problem = ""  # why torque objects cannot be scaled, when they cannot
        self.supported_modes: tuple[str, ...] | None = None  # read from 0x6502 at connect
        self.tpdo_layout: list[tuple[int, list[int]]] = []  # (COB-ID, channel indices after the counter)
        self.rpdo: tuple | None = None  # (COB-ID, counter type, set-point type, set-point role)
        self._configured_for = ""  # the acquisition configure() mapped the objects for
        self.excitation_recipe: dict | None = None  # what a drive's own generator plays (recorder runs)
        self.last_result: RunResult | None = None
        self.events: list[dict] = []
        self.connect_report = ConnectReport()
        self.run_fault: dict | None = None  # the first fault event of the current run (the first cause)
        self._host_heartbeat = None  # the periodic task producing the host's heartbeat
        self._guarding = False  # the host guards the drive (no 0x1017): node guarding requests go out
        self._consumer: ObjectAddress | None = None  # the 0x1016 entry watching the host
        self._in_block_transfer = False  # a block transfer is under way (safe_stop must abort it first)
        self.answered = True  # the drive answered the last safe_stop()
        self._beat: tuple[int, float] = (0, 0.0)  # (COB-ID, period s) of the host's heartbeat
        self._beat_s = 0.0  # when the host's heartbeat last went out (monotonic s)
        self.emergencies: collections.deque[Emergency] = collections.deque()
        self.heartbeat_s: float | None = None
        self.heartbeat_state: int | None = None
        self._trace_path: Path | None = None
        self._limits: tuple | None = None
        self._host_checks: list = []
        self.device_limits: tuple[str, ...] = ()  # the limit objects the drive holds (the rest: host-checked only)
        self._nmt_settled_s = 0.0  # heartbeats before this may still carry the NMT state before our last command
        node.sdo.RESPONSE_TIMEOUT = max(0.05, min(self.timeout_s, 1.0))
        node.nmt.add_heartbeat_callback(self._on_heartbeat)
        node.emcy.add_callback(self._on_emcy)

    # --- opening and closing --------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> "CanopenDriveAdapter":
        """Open the bus, load the EDS, check the identity, bring the drive to a known state, arm the net.

        See the module docstring: NMT Pre-operational, frames from before
        counted in ``connect_report.discarded_frames``, Disable Voltage, a
        latched fault reported (reset only with ``device.allow_fault_reset``),
        then the host's heartbeat and the drive's heartbeat consumer.

        Raises
        ------
        DeviceError
            The bus cannot be opened, the node does not answer, it is not the
            drive the description expects (the message names the object), or it
            has a latched fault and resetting it is not allowed.
        ConfigError
            ``[canopen] host_node_id`` is the drive's own node id.
        """
        source = str(driver.folder / "driver.toml")
        eds_warnings: list[str] = []
        od = load_object_dictionary(driver, device.node_id, eds_warnings)
        desc = CanopenDescription.from_sections(driver.sections, source, od)
        if device.acquisition == "buffered" or (device.acquisition == "auto" and desc.default_acquisition == "buffered"):
            desc.require_buffered(source)
        label = f"{device.can_interface}:{device.port} node {device.node_id}"
        if desc.host_node_id == device.node_id:
            raise ConfigError("canopen.host_node_id",
                              f"{desc.host_node_id} is also the drive's node id (device.node_id): the host's "
                              "heartbeat needs a node id of its own", source)
        network = open_network(device, driver.default_baudrate, label)
        adapter = None
        try:
            node = canopen.RemoteNode(device.node_id, od)
            network.add_node(node)
            adapter = cls(network, node, driver, desc, device, label)
            adapter.connect_report.warnings += eds_warnings
            early = adapter._count_early_frames()
            try:
                adapter._identify()
                adapter._to_known_state()
            finally:
                early.stop()
            adapter.connect_report.discarded_frames += early.frames
            adapter._arm_device_net()
        except BaseException:
            if adapter is not None:
                adapter._stop_host_heartbeat()
            try:
                network.disconnect()
            except Exception:
                pass
            raise
        return adapter

    def close(self) -> None:
        """Zero torque, drive in a safe state, its heartbeat consumer off, host heartbeat off, bus released.

        Never raises. The consumer entry is cleared before the host's heartbeat
        stops, so a clean close does not look like a dead host to the drive.
        """
        try:
            self.safe_stop()
            if self.answered:
                with contextlib.suppress(Exception):
                    self._disarm_device_net()
            with contextlib.suppress(Exception):
                self.nmt("PRE-OPERATIONAL")  # no PDOs from here on
        finally:
            self._stop_host_heartbeat()
            with contextlib.suppress(Exception):
                self.network.stop_trace()
            with contextlib.suppress(Exception):
                self.network.disconnect()

    # --- known state at connect, device-side net -------------------------------------------------

    def _count_early_frames(self) -> "_FrameCounter":
        """Count the TPDOs and emergencies that arrive while the host has configured nothing."""
        cobs = [base + self.node.id for base in _TPDO_BASES]
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
                raise DeviceError(f"{self.port}: the drive does not switch its power stage off: it stays in "
                                  f"{state.value} after Disable Voltage "
                                  f"({self.describe(self.desc.address('controlword'))})")
        self.connect_report.discarded_frames += len(self.emergencies)
        self.emergencies.clear()  # emergencies of an earlier session: their fault is handled above

    def _reset_fault(self, state: cia402.State) -> None:
        """Fault reset (a rising edge of controlword bit 7) to Switch On Disabled."""
        previous = 0
        for cw in (int(cia402.Command.DISABLE_VOLTAGE), int(cia402.Command.FAULT_RESET)):
            state = self._command(state, cw, previous)
            previous = cw
        if state is not cia402.State.SWITCH_ON_DISABLED:
            raise DeviceError(f"{self.port}: the fault did not clear: the drive is in {state.value} "
                              f"({self.last_error_text()})")

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
            self.connect_report.device_net = (f"none: {self.desc.eds} has no heartbeat consumer (0x1016); the drive "
                                              "does not stop on its own when the host dies")
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
        net = (f"{guarding}heartbeat consumer {entry}: host node {host}, {time_ms} ms "
               f"(host heartbeat every {period_s * 1e3:.0f} ms)")
        if ABORT_CONNECTION_INDEX in od:
            option = self.desc.abort_connection_option
            self.write_object(ObjectAddress(ABORT_CONNECTION_INDEX, 0), option)
            net += f"; 0x6007 = {option} ({ABORT_CONNECTION_OPTIONS[option]})"
        else:
            net += "; no 0x6007: the drive's own reaction to a lost heartbeat"
        self.connect_report.device_net = net

    def _consumer_entry_for(self, host: int) -> ObjectAddress:
        """The 0x1016 entry already watching ``host``, else the first unused one."""
        var = self.node.object_dictionary[HEARTBEAT_CONSUMER_INDEX]
        count = int(self.read_object(ObjectAddress(HEARTBEAT_CONSUMER_INDEX, 0)))
        free, others = None, []
        for sub in range(1, count + 1):
            if var.get(sub) is None:
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
            raise DeviceError(f"{self.port}: every heartbeat consumer entry of 0x1016 watches another node "
                              f"({', '.join(others)}); free one for the host (node {host}, [canopen] host_node_id)")
        return free

    def _start_host_heartbeat(self, host: int, period_s: float) -> None:
        """python-can's cyclic sender in a daemon thread: it dies with the process, which is the point."""
        msg = can.Message(arbitration_id=0x700 + host, data=[_NMT_OPERATIONAL], is_extended_id=False)
        self._beat = (msg.arbitration_id, period_s)
        self._beat_s = time.monotonic()
        self._host_heartbeat = can.broadcastmanager.ThreadBasedCyclicSendTask(
            self.network.bus, self.network.send_lock, msg, period_s, on_error=lambda exc: False,
            modifier_callback=self._on_beat)

    def _on_beat(self, msg) -> None:
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

    # --- object access ----------------------------------------------------------------------

    def describe(self, addr: ObjectAddress) -> str:
        """``0x6072:0 (Max torque)``: an object as messages name it."""
        var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
        name = var.name if var is not None else "not in the EDS"
        if var is not None and var.parent is not None and not isinstance(var.parent, canopen.ObjectDictionary):
            name = f"{var.parent.name}: {var.name}"
        return f"{addr} ({name})"

    def _sdo_error(self, exc: Exception, addr: ObjectAddress, action: str) -> DeviceError:
        if isinstance(exc, SdoAbortedError):
            meaning = SdoAbortedError.CODES.get(exc.code, "unknown abort code")
            return DeviceError(f"{self.port}: SDO abort {action} {self.describe(addr)}: 0x{exc.code:08X} {meaning}")
        if isinstance(exc, SdoCommunicationError):
            return DeviceError(f"{self.port}: no valid SDO answer {action} {self.describe(addr)}: {exc} "
                               "(is the drive powered, on this bus, with this node id?)")
        return DeviceError(f"{self.port}: bus failure {action} {self.describe(addr)}: {exc}")

    def read_object(self, addr: ObjectAddress):
        """Upload one object and decode it by its EDS data type."""
        var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
        if var is None:
            raise DeviceError(f"{self.port}: object {addr} is not in the EDS {self.desc.eds}")
        self.beat_if_due()
        try:
            return var.decode_raw(self.node.sdo.upload(addr.index, addr.subindex))
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, "reading") from None

    def write_object(self, addr: ObjectAddress, value) -> None:
        """Download one object, encoded by its EDS data type."""
        var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
        if var is None:
            raise DeviceError(f"{self.port}: object {addr} is not in the EDS {self.desc.eds}")
        try:
            data = var.encode_raw(value)
        except (ValueError, TypeError, struct_error) as exc:
            raise DataError(f"{self.port}: value {value!r} does not fit {self.describe(addr)}: {exc}") from None
        self.beat_if_due()
        try:
            self.node.sdo.download(addr.index, addr.subindex, data)
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, "writing") from None

    def read(self, role: str):
        return self.read_object(self.desc.address(role))

    def write(self, role: str, value) -> None:
        self.write_object(self.desc.address(role), value)

    def read_domain(self, addr: ObjectAddress) -> bytes:
        """Upload a DOMAIN object (block transfer when the description says so)."""
        if not self.desc.block_transfer:
            try:
                return bytes(self.node.sdo.upload(addr.index, addr.subindex))
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                raise self._sdo_error(exc, addr, "reading") from None

        def upload(f):
            return bytes(f.readall())

        return self._block_transfer(addr, "rb", upload, {})

    def write_domain(self, addr: ObjectAddress, data: bytes) -> None:
        """Download a DOMAIN object (block transfer when the description says so)."""
        if not self.desc.block_transfer:
            try:
                self.node.sdo.download(addr.index, addr.subindex, data, force_segment=True)
            except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
                raise self._sdo_error(exc, addr, "writing") from None
            return

        def download(f):
            view = memoryview(data)
            pos = 0
            while pos < len(data):
                pos += f.write(view[pos:pos + 7])

        self._block_transfer(addr, "wb", download, {"size": len(data)})

    def _block_transfer(self, addr: ObjectAddress, mode: str, body, options: dict):
        """Run ``body(stream)`` on an SDO block transfer stream; an interrupted transfer is aborted.

        A signal (or any exception not from the transfer itself) in the middle
        of a block download leaves the drive's SDO server reading sub-block
        segments, where every frame but an abort counts as data: the next
        request (the Disable Voltage of ``safe_stop``) would be swallowed. So
        the transfer is ended with an SDO abort, never with canopen's normal
        close, which would send the end-of-transfer request and wait for it.
        """
        action = "reading" if mode == "rb" else "writing"
        try:
            stream = self.node.sdo.open(addr.index, addr.subindex, mode, block_transfer=True, buffering=0,
                                        **options)
        except (SdoAbortedError, SdoCommunicationError, can.CanError, OSError) as exc:
            raise self._sdo_error(exc, addr, action) from None
        self._in_block_transfer = True
        try:
            result = body(stream)
        except BaseException as exc:
            self._in_block_transfer = False
            io.RawIOBase.close(stream)  # closed without the end-of-transfer exchange
            cause = _transfer_error(exc)
            if not isinstance(cause, SdoAbortedError):  # the drive aborted: its server is idle already
                with contextlib.suppress(Exception):
                    self.node.sdo.abort(_ABORT_GENERAL)
            if cause is not None:
                raise self._sdo_error(cause, addr, action) from None
            raise
        self._in_block_transfer = False
        try:
            stream.close()
        except Exception as exc:
            cause = _transfer_error(exc)
            if cause is None:
                raise
            raise self._sdo_error(cause, addr, action) from None
        return result

    # --- identity, heartbeat, emergencies ------------------------------------------------------

    def _identify(self) -> None:
        """Identity, rated torque and current, supported modes; then the drive's heartbeat.

        Only objects the EDS has are read; the identity is checked when the
        driver description gives one.
        """
        d = self.desc
        vendor = int(self.read("vendor_id")) if d.has("vendor_id") else 0
        product = int(self.read("product_code")) if d.has("product_code") else 0
        for key, expected, got in (("vendor_id", d.vendor_id, vendor), ("product_code", d.product_code, product)):
            if expected is not None and got != expected:
                raise DeviceError(
                    f"{self.port}: the node reports {key.replace('_', ' ')} 0x{got:08X} "
                    f"({self.describe(d.address(key))}); driver {self.driver.name!r} expects 0x{expected:08X}")
        if d.has("loop_rate"):
            rate = float(self.read("loop_rate"))
            if abs(rate - self.driver.loop_rate_hz) > 1e-6 * self.driver.loop_rate_hz:
                raise DeviceError(f"{self.port}: the drive's loop runs at {rate:g} Hz "
                                  f"({self.describe(d.address('loop_rate'))}); driver {self.driver.name!r} says "
                                  f"{self.driver.loop_rate_hz:g} Hz")
        name = str(self.read("device_name")) if d.has("device_name") else self.driver.name
        version = str(self.read("software_version")) if d.has("software_version") else ""
        self.identity = DriveIdentity(name, version, float(self.driver.loop_rate_hz), int(self.driver.filter_slots),
                                      vendor, product)
        try:
            self.rated_torque_nm = d.rated_torque(float(self.read("rated_torque")) if d.has("rated_torque") else None)
        except DataError as exc:
            self.rated_torque_nm = 0.0  # an experiment that needs torque objects says so
            self.torque_problem = str(exc)
        self.rated_current_a = d.rated_current(float(self.read("rated_current")) if d.has("rated_current") else None)
        if d.has("supported_modes"):
            self.supported_modes = decode_supported_modes(int(self.read("supported_modes")))
            self.desc = d = d.with_supported_modes(self.supported_modes)
        if d.has("sync_overflow"):
            self.sync_overflow = int(self.read("sync_overflow"))
        od = self.node.object_dictionary
        if d.has("heartbeat_time"):
            self.write("heartbeat_time", d.heartbeat_ms)
            how = f"setting {self.describe(d.address('heartbeat_time'))} to {d.heartbeat_ms} ms"
        elif _GUARD_TIME in od and _LIFE_TIME_FACTOR in od:
            self._start_node_guarding()
            how = f"starting node guarding every {d.heartbeat_ms} ms (the EDS has no 0x1017)"
        else:
            raise DeviceError(f"{self.port}: the EDS {d.eds} has neither a producer heartbeat time (0x1017) nor "
                              "node guarding (0x100C, 0x100D): hilident watches the drive by one of them")
        deadline = time.monotonic() + max(self.timeout_s, 3 * d.heartbeat_ms / 1000.0)
        while self.heartbeat_s is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if self.heartbeat_s is None:
            raise DeviceError(f"{self.port}: no heartbeat within {self.timeout_s:g} s after {how}")

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

    def _on_emcy(self, error) -> None:
        self.emergencies.append(Emergency(error.code, error.register, bytes(error.data), time.monotonic()))

    def check_link(self) -> None:
        """Raise DeviceError when the heartbeat stopped or the drive left NMT Operational."""
        gap = time.monotonic() - (self.heartbeat_s or 0.0)
        limit = self.desc.heartbeat_timeout_ms / 1000.0
        if gap > limit:
            raise DeviceError(f"{self.port}: heartbeat lost: nothing for {gap:.2f} s "
                              f"(limit {limit:g} s, producer {self.desc.heartbeat_ms} ms)")
        if (self.heartbeat_state is not None and self.heartbeat_state != _NMT_OPERATIONAL
                and time.monotonic() > self._nmt_settled_s):
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

    # --- CiA 402 state machine ----------------------------------------------------------------

    def drive_state(self) -> cia402.State:
        sw = int(self.read("statusword"))
        try:
            return cia402.decode_statusword(sw)
        except ValueError as exc:
            raise DeviceError(f"{self.port}: {self.describe(self.desc.address('statusword'))}: {exc}") from None

    def _command(self, state: cia402.State, cw: int, previous: int) -> cia402.State:
        """Write ``cw`` and wait until the statusword shows the state it leads to."""
        expected, _ = cia402.transition(state, cw, previous)
        self.write("controlword", cw)
        deadline = time.monotonic() + self.timeout_s
        while True:
            now_state = self.drive_state()
            if now_state is expected or now_state is cia402.State.FAULT or time.monotonic() > deadline:
                return now_state
            time.sleep(_STATE_POLL_S)

    def enable(self) -> None:
        """Drive the state machine to Operation Enabled (fault reset only if allowed).

        Raises
        ------
        DeviceError
            The drive is in Fault and ``device.allow_fault_reset`` is false, or it
            does not follow the commands.
        """
        state = self.drive_state()
        if state is cia402.State.OPERATION_ENABLED:
            return
        try:
            path = cia402.path_to_operation_enabled(state, self.device.allow_fault_reset)
        except ValueError:
            raise DeviceError(f"{self.port}: the drive is in {state.value} ({self.last_error_text()}); set "
                              "device.allow_fault_reset = true to let hilident reset it") from None
        previous = 0
        for cw in path:
            state = self._command(state, cw, previous)
            previous = cw
        if state is not cia402.State.OPERATION_ENABLED:
            raise DeviceError(f"{self.port}: the drive did not reach Operation Enabled: it is in {state.value} "
                              f"({self.last_error_text()})")

    def last_error_text(self) -> str:
        if not self.desc.has("error_code"):
            return "no error code object"
        try:
            code = int(self.read("error_code"))
        except DeviceError:
            return "error code unreadable"
        return f"error code 0x{code:04X}: {cia402.emcy_meaning(code)}" if code else "no error code"

    def safe_stop(self) -> None:
        """Power stage off now: Disable Voltage (transitions 7, 9, 10, 12 to Switch On Disabled).

        One SDO write, whatever the state (a drive in Fault keeps its fault and
        its power stage stays off). The bus and the host's heartbeat stay up.
        Never raises; a drive that does not answer costs one SDO timeout. Safe
        to call from a signal handler that interrupted a block transfer: that
        transfer is aborted first, or the drive would take the request for a
        data segment.
        """
        try:
            if self._in_block_transfer:
                self.node.sdo.abort(_ABORT_GENERAL)
            self.write("controlword", int(cia402.Command.DISABLE_VOLTAGE))
            self.answered = True
        except Exception:
            self.answered = False  # gone or not listening: close() does not wait for it again

    # --- configuration ---------------------------------------------------------------------------

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the trip limits into the drive where it has them, and read each back.

        Max torque 0x6072, max motor speed 0x6080, software position limits
        0x607D. Whatever the drive has, the host also checks every sample it
        receives against the limits (see :meth:`stream`).

        Raises
        ------
        ConfigError
            A limit does not fit its object's type.
        DeviceError
            The drive stores another value than the one written.
        """
        d = self.desc
        wanted = {
            "max_torque": lambda: math.floor(torque_nm / self.scale("max_torque")),
            "max_velocity": lambda: math.floor(velocity_mps / self.scale("max_velocity")),
            "position_limit_min": lambda: math.ceil(position_min_m / self.scale("position_limit_min")),
            "position_limit_max": lambda: math.floor(position_max_m / self.scale("position_limit_max")),
        }
        values = {}
        for role, raw in wanted.items():
            if not d.has(role) or (role == "max_torque" and not self.rated_torque_nm > 0):
                continue
            values[role] = raw()
            var = self.node.object_dictionary.get_variable(d.address(role).index, d.address(role).subindex)
            info = np.iinfo(numpy_type(var.data_type))
            if not info.min <= values[role] <= info.max:
                raise ConfigError(f"limits ({role})", f"{values[role]} units do not fit {self.describe(d.address(role))}")
        for role, raw in values.items():
            self.write(role, raw)
            back = int(self.read(role))
            if back != raw:
                raise DeviceError(f"{self.port}: wrote {raw} to {self.describe(d.address(role))}, the drive holds {back}")
        self.device_limits = tuple(values)
        self._limits = (torque_nm, velocity_mps, position_min_m, position_max_m)

    def scale(self, role: str) -> float:
        """SI value of one raw unit of the object of ``role``; DeviceError when it cannot be scaled."""
        try:
            return self.desc.scale(role, self.rated_torque_nm, self.rated_current_a)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {self.describe(self.desc.address(role))}: "
                              f"{self.torque_problem or exc}") from None

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Mode of operation, sample period and the PDO (or capture) mapping of the channels.

        The period goes to whichever of 0x1006 (us) and 0x60C2 (value and
        exponent) the drive has.
        """
        ident = self.identity
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the drive's loop rate "
                              f"{ident.loop_rate_hz:g} Hz")
        divider = int(round(divider))
        rate = ident.loop_rate_hz / divider
        if rate > self.driver.max_sample_rate_hz * (1 + 1e-9):
            raise DeviceError(f"{self.port}: sample rate {rate:g} Hz exceeds the drive's {self.driver.max_sample_rate_hz:g} Hz")
        if mode not in self.desc.modes:
            supported = f"; 0x6502 says it supports {', '.join(self.supported_modes) or 'no mode'}" \
                if self.supported_modes is not None else ""
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} has no mode for {mode!r} "
                              f"(it has {', '.join(self.desc.modes) or 'none'}{supported})")
        names = channels or [c.name for c in self.driver.streamed_channels]
        units = {c.name: c.unit for c in self.driver.channels}
        codecs = []
        for name in names:
            if name not in self.desc.channels or name not in units:
                raise DeviceError(f"{self.port}: driver {self.driver.name!r} has no channel {name!r} "
                                  f"(it has {', '.join(self.desc.channels)})")
            role = self.desc.channels[name]
            if role is None:
                codecs.append(ChannelCodec(name, units[name], None, None, REAL32, 1.0))
                continue
            addr = self.desc.address(role)
            var = self.node.object_dictionary.get_variable(addr.index, addr.subindex)
            codecs.append(ChannelCodec(name, units[name], role, addr, var.data_type, self.scale(role)))
        if self.acquisition == "recorder":
            configure_recorder(self, codecs)
        elif self.acquisition == "buffered" and any(c.on_host for c in codecs):
            raise DeviceError(f"{self.port}: a drive-buffered run records only drive objects; channel "
                              f"{next(c.name for c in codecs if c.on_host)!r} has none")
        spec = self.desc.modes[mode]
        for role in (spec.setpoint, spec.hold):
            if role:
                self.scale(role)  # a set-point that cannot be scaled stops here, before anything moves
        self.safe_stop()
        self.write("modes_of_operation", spec.code)
        period_s = divider / ident.loop_rate_hz
        if self.desc.has("cycle_period"):
            self.write("cycle_period", int(round(1e6 * period_s)))
        if self.desc.has("interpolation_period"):
            try:
                value, exponent = period_fields(period_s)
            except ValueError as exc:
                raise DeviceError(f"{self.port}: {self.describe(self.desc.address('interpolation_period'))}: "
                                  f"{exc}") from None
            self.write("interpolation_period", value)
            if self.desc.has("interpolation_exponent"):
                self.write("interpolation_exponent", exponent)
        if self.desc.has("table_divider"):
            self.write("table_divider", divider)
        if self.acquisition == "streamed":
            self._map_pdos(codecs, mode)
        elif self.acquisition == "buffered":
            self._map_capture(codecs)
        self.divider, self.sample_rate_hz, self.mode = divider, rate, mode
        self._configured_for = self.acquisition
        self.channels = codecs
        self.channel_names = [c.name for c in codecs]
        self.channel_units = [c.unit for c in codecs]
        return self.channel_names

    def _write_mapping(self, comm_index: int | None, map_index: int, entries: list[int], cob_id: int | None) -> None:
        """CiA 301 order: invalidate, clear the count, write entries, set the count, validate."""
        if comm_index is not None:
            self.write_object(ObjectAddress(comm_index, 1), (cob_id or 0) | 0x80000000)
        self.write_object(ObjectAddress(map_index, 0), 0)
        for i, entry in enumerate(entries, start=1):
            self.write_object(ObjectAddress(map_index, i), entry)
        self.write_object(ObjectAddress(map_index, 0), len(entries))
        if comm_index is not None and entries:
            self.write_object(ObjectAddress(comm_index, 2), 1)  # synchronous, every SYNC
            self.write_object(ObjectAddress(comm_index, 1), cob_id)

    def pdo_slots(self, kind: str) -> list[PdoSlot]:
        """The RPDOs (``kind = "rpdo"``) or TPDOs the EDS declares, with their mapping capacity.

        A PDO counts when both its communication and its mapping object exist;
        its capacity is :func:`~hilident.protocol.canopen_profile.mapping_capacity`.
        The COB-ID is the predefined connection set's for PDOs 1-4 and the
        EDS default for the others.
        """
        od = self.node.object_dictionary
        comm_base, map_base, cob_base = (0x1400, 0x1600, 0x200) if kind == "rpdo" else (0x1800, 0x1A00, 0x180)
        slots = []
        for n in range(512):
            if comm_base + n not in od or map_base + n not in od:
                continue
            capacity = mapping_capacity(od[map_base + n])
            if n < 4:
                cob = cob_base + 0x100 * n + self.node.id
            else:
                var = od.get_variable(comm_base + n, 1)
                cob = int(var.default or 0) & 0x7FF if var is not None else 0
            if capacity and cob:
                slots.append(PdoSlot(n, capacity, cob))
        return slots

    def _map_pdos(self, codecs: list[ChannelCodec], mode: str) -> None:
        """Map the channels into TPDOs and the set-point into an RPDO, within what the EDS allows.

        On a drive with the hilident counters every PDO is headed by one (the
        sample counter, the set-point counter); otherwise the TPDOs carry the
        channels only and the host matches them to SYNCs by their order.
        """
        od = self.node.object_dictionary
        counted = self.desc.counted
        mapped = [c for c in codecs if not c.on_host]
        tpdos, rpdos = self.pdo_slots("tpdo"), self.pdo_slots("rpdo")
        header = []
        if counted:
            counter = self.desc.address("sample_counter")
            header = [(counter, type_bits(od.get_variable(counter.index, counter.subindex).data_type))]
        per_frame = min((s.max_entries for s in tpdos[:4]), default=0) - len(header)
        try:
            frames = pack_frames([(c.name, c.bits) for c in mapped], header_bits=sum(b for _, b in header),
                                 max_frames=len(tpdos), max_entries=per_frame)
        except DataError as exc:
            raise DeviceError(f"{self.port}: {exc} ({self.desc.eds}: {len(tpdos)} TPDOs of "
                              f"{', '.join(str(s.max_entries) for s in tpdos)} entries)") from None
        self.nmt("PRE-OPERATIONAL")
        layout = []
        for i, slot in enumerate(tpdos):
            members = frames[i] if i < len(frames) else []
            idx = [self.channel_index(codecs, m) for m in members]
            entries = ([mapping_entry(a, b) for a, b in header] +
                       [mapping_entry(codecs[j].address, codecs[j].bits) for j in idx]) if members else []
            self._write_mapping(0x1800 + slot.number, 0x1A00 + slot.number, entries, slot.cob_id)
            if members:
                layout.append((slot.cob_id, idx))
        spec = self.desc.modes[mode]
        sp = self.desc.address(spec.setpoint)
        sp_var = od.get_variable(sp.index, sp.subindex)
        if not rpdos:
            raise DeviceError(f"{self.port}: the EDS {self.desc.eds} declares no RPDO: set-points cannot be streamed")
        rx_type = None
        entries = []
        if counted:
            rx_counter = self.desc.address("setpoint_counter")
            rx_type = od.get_variable(rx_counter.index, rx_counter.subindex).data_type
            entries.append(mapping_entry(rx_counter, type_bits(rx_type)))
        entries.append(mapping_entry(sp, type_bits(sp_var.data_type)))
        self._write_mapping(0x1400 + rpdos[0].number, 0x1600 + rpdos[0].number, entries, rpdos[0].cob_id)
        for slot in rpdos[1:4]:
            self._write_mapping(0x1400 + slot.number, 0x1600 + slot.number, [], slot.cob_id)
        self.tpdo_layout = layout
        self.rpdo = (rpdos[0].cob_id, rx_type, sp_var.data_type, spec.setpoint)
        self.nmt("OPERATIONAL")

    def nmt(self, state: str) -> None:
        """Send an NMT command to the drive ("OPERATIONAL", "PRE-OPERATIONAL", ...)."""
        try:
            self.node.nmt.state = state
        except Exception as exc:
            raise DeviceError(f"{self.port}: NMT command {state} failed: {exc}") from None
        # heartbeats sent before the drive took the command may still be on their way (a loaded bus reader)
        self._nmt_settled_s = time.monotonic() + self.desc.heartbeat_timeout_ms / 1000.0

    @staticmethod
    def channel_index(codecs, name: str) -> int:
        return [c.name for c in codecs].index(name)

    def _map_capture(self, codecs: list[ChannelCodec]) -> None:
        index = self.desc.address("capture_mapping").index
        self._write_mapping(None, index, [mapping_entry(c.address, c.bits) for c in codecs], None)
        self.nmt("OPERATIONAL")  # for the heartbeat's NMT check; no PDOs are mapped
        for slot in self.pdo_slots("tpdo"):  # no stale TPDOs beside the capture
            self.write_object(ObjectAddress(0x1800 + slot.number, 1), slot.cob_id | 0x80000000)

    # --- runs --------------------------------------------------------------------------------------

    def set_trace(self, path) -> None:
        """Write a CAN trace (``.asc`` or ``.blf``) of the next run to ``path``."""
        self._trace_path = Path(path)

    def _prepare_run(self, x: np.ndarray) -> None:
        """Configured for this acquisition; emergencies from before dropped; the CAN trace started."""
        if not self.channels or self._configured_for != self.acquisition:
            raise DeviceError(f"{self.port}: configure() for {self.acquisition} acquisition before stream()")
        self.emergencies.clear()
        trace_path, self._trace_path = self._trace_path, None
        if trace_path is not None:
            try:
                self.network.start_trace(trace_path)
            except (OSError, ValueError) as exc:
                raise DeviceError(f"{self.port}: cannot write the CAN trace {trace_path}: {exc}") from None

    def _play(self, x: np.ndarray, deliver, result: RunResult) -> None:
        """Play ``x`` (one value per sample, in the mode's SI unit) with the strategy of :attr:`acquisition`."""
        ACQUISITIONS[self.acquisition](self, x, deliver, result)

    def _end_run(self, result: RunResult) -> None:
        """Power stage off, CAN trace closed."""
        self.safe_stop()
        with contextlib.suppress(Exception):
            self.network.stop_trace()

    def _fault_text(self, event: dict) -> str:
        return f"{event['message']} at sample {event['sample_index']}"

    def _collect_faults(self) -> None:
        """Emergencies still queued: an SDO abort or a lost link is often the consequence of one."""
        if self.run_fault is None:
            self.take_emergency_fault(self.last_result.stats.samples if self.last_result is not None else 0)

    def _as_device_error(self, exc: BaseException) -> BaseException:
        if isinstance(exc, (can.CanError, OSError)):  # the bus itself failed (e.g. a send)
            return DeviceError(f"{self.port}: bus failure during the run: {exc}")
        return exc

    def set_excitation_recipe(self, recipe: dict | None) -> None:
        """The excitation of the next :meth:`stream` as parameters (``kind``, ``amplitude``, band, ...).

        A recorder run has the drive's generator play it (see
        :mod:`hilident.adapters.canopen_recorder`); the other runs play the samples.
        """
        self.excitation_recipe = dict(recipe) if recipe is not None else None

    def _host_limit_columns(self) -> list[tuple[int, float, float, str]]:
        """(channel column, low, high, limit name) of the limits the host checks on every sample.

        Speed and position always; torque when the drive holds no torque limit
        of its own (0x6072): its loop trips on the filtered command, which the
        host does not see, while the measured torque carries sensor noise.
        """
        if self._limits is None:
            return []
        torque, velocity, pmin, pmax = self._limits
        bounds = {"velocity_mps": (-velocity, velocity, "velocity_limit"),
                  "position_m": (pmin, pmax, "position_limit")}
        if "max_torque" not in self.device_limits:
            bounds["torque_nm"] = (-torque, torque, "torque_limit")
        return [(j, *bounds[c.name]) for j, c in enumerate(self.channels) if c.name in bounds]

    def decode_rows(self, raw_columns: list[np.ndarray], first_index: int = 0) -> np.ndarray:
        """Raw channel columns -> SI rows (values at their integer type's limit counted, see :meth:`count_saturated`)."""
        raw = np.column_stack([c.astype(float) for c in raw_columns])
        self.count_saturated(raw, first_index)
        return raw * np.array([codec.scale for codec in self.channels])

    def count_saturated(self, raw: np.ndarray, first_index: int) -> None:
        """Count the rows of ``raw`` (raw values, one column per channel) in which a drive-reported integer sits at
        its type's limit: the drive's value is saturated there, not measured (kept, counted as clipped).

        The first such sample of a run gets a ``clipped`` event naming the channel and its object.
        """
        hit = np.zeros(len(raw), dtype=bool)
        first = None
        for j, c in enumerate(self.channels):
            kind = numpy_type(c.datatype) if not c.on_host else None
            if kind is None or kind.kind not in "iu":
                continue
            info = np.iinfo(kind)
            at = (raw[:, j] >= info.max) | (raw[:, j] <= info.min)
            if at.any() and first is None:
                first = (c, int(np.argmax(at)))
            hit |= at
        if not hit.any() or self.last_result is None:
            return
        stats = self.last_result.stats
        if first is not None and not stats.clipped_blocks:
            c, row = first
            self.log_event(RunEvent(
                Kind.CLIPPED, f"{c.name} reached the range of {self.describe(c.address)} ({numpy_type(c.datatype)}): "
                f"the drive's value is saturated there; its scaling ([canopen.scaling]) or the excitation is too large",
                first_index + row))
        stats.clipped_blocks += int(hit.sum())

    def encode_setpoints(self, x: np.ndarray, datatype: int, role: str, origin_raw: int = 0) -> np.ndarray:
        """Excitation in SI units -> raw set-point values of the object of ``role``."""
        raw = encode_si(x, datatype, self.scale(role))
        if origin_raw:
            raw = (raw.astype(np.int64) + origin_raw).astype(raw.dtype)
        return raw

    # --- filter slots -----------------------------------------------------------------------------

    def _filter_slot(self, slot: int):
        fo = self.desc.filters
        if fo is None or self.encoding is None:
            raise DeviceError(f"{self.port}: driver {self.driver.name!r} describes no filter objects")
        if not 0 <= slot < len(fo.indices) or slot >= self.identity.filter_slots:
            raise DeviceError(f"{self.port}: filter slot {slot} (the drive has {self.identity.filter_slots})")
        return fo

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a notch in a slot, fitted to what the drive's encoding can hold; it takes effect when enabled.

        With ``spec`` the notch is realised in the encoding (the stored values
        closest to it, :meth:`FilterEncoding.realise`); without, ``biquad`` is
        rounded to the encoding.
        """
        fo = self._filter_slot(slot)
        values = self._realise(biquad, spec).fields if spec is not None else self.encoding.encode(biquad, spec)
        self._write_slot(fo, slot, values, enabled)

    def _realise(self, biquad: Biquad, spec: NotchSpec | None):
        try:
            return self.encoding.realise(spec, self.identity.loop_rate_hz)
        except DataError as exc:
            raise DeviceError(f"{self.port}: the drive's {self.encoding.kind} filter slots cannot hold the "
                              f"{spec.center_hz:.4g} Hz notch: {exc}") from None

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why the drive's encoding cannot meet ``spec`` exactly (depth or width out of reach), if it cannot."""
        return self._realise(None, spec).notes

    def _write_slot(self, fo, slot: int, values: dict, enabled: bool) -> None:
        if fo.enable_subindex is None:  # the enable lives inside the one block
            block = values if enabled else self.encoding.disabled(values)
            self.write_object(fo.address(slot, "block"), block["block"])
            return
        for name, value in values.items():
            self.write_object(fo.address(slot, name), value)
        self.write_object(fo.address(slot, "enabled"), int(bool(enabled)))

    def _read_slot(self, fo, slot: int) -> tuple[dict, bool]:
        values = {name: self.read_object(fo.address(slot, name)) for name in self.encoding.fields}
        if fo.enable_subindex is None:
            try:
                return values, bool(self.encoding.slot_enabled(values))
            except DataError as exc:
                raise DeviceError(f"{self.port}: filter slot {slot} (object 0x{fo.indices[slot]:04X}): {exc}") from None
        return values, bool(self.read_object(fo.address(slot, "enabled")))

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The biquad the slot applies, rebuilt from the values read from the drive."""
        fo = self._filter_slot(slot)
        values, enabled = self._read_slot(fo, slot)
        try:
            if fo.enable_subindex is None:  # a block read back disabled: what it holds, as it would run
                values = self.encoding.enabled(values)
            return self.encoding.applied(values, self.identity.loop_rate_hz), enabled
        except DataError as exc:
            raise DeviceError(f"{self.port}: filter slot {slot} (object 0x{fo.indices[slot]:04X}): {exc}") from None

    def stored_form(self, biquad: Biquad, spec: NotchSpec | None = None) -> Biquad:
        """What the drive will run once :meth:`write_filter` stored ``biquad``/``spec``."""
        if spec is not None:
            return self._realise(biquad, spec).section
        return self.encoding.stored_form(biquad, spec, self.identity.loop_rate_hz)

    def save_filter(self, slot: int) -> tuple[dict, bool]:
        """The slot's raw field values and enable flag."""
        return self._read_slot(self._filter_slot(slot), slot)

    def disable_filter(self, slot: int) -> None:
        """Bypass a slot: its enable to 0 (or its block's state word to bypass); the coefficients stay stored."""
        fo = self._filter_slot(slot)
        if fo.enable_subindex is None:
            values, _ = self._read_slot(fo, slot)
            self._write_slot(fo, slot, values, False)
            return
        self.write_object(fo.address(slot, "enabled"), 0)

    def save_parameters(self) -> str:
        """Have the drive store its parameters in non-volatile memory (CiA 301 0x1010:1, signature "save").

        ``[canopen.save]`` in the driver description may name another object
        and value (``object = "0x2F00"``, ``value = 1``) for drives that store
        by a vendor command.

        Returns
        -------
        str
            What was written, e.g. ``"0x1010:1 (Save all parameters) = 0x65766173"``.

        Raises
        ------
        DeviceError
            The drive has no store object, or refuses the command.
        """
        table = self.driver.sections.get("canopen", {}).get("save")
        if isinstance(table, dict) and "object" in table:
            addr = parse_address(table["object"], "canopen.save.object", str(self.driver.folder / "driver.toml"))
            value = table.get("value", STORE_SIGNATURE)
        elif self.desc.has("store_parameters"):
            addr, value = self.desc.address("store_parameters"), STORE_SIGNATURE
        else:
            raise DeviceError(f"{self.port}: the EDS {self.desc.eds} has no store parameters object (0x1010) and the "
                              "driver names none ([canopen.save] object): the drive cannot be asked to save")
        self.write_object(addr, value)
        return f"{self.describe(addr)} = 0x{int(value):08X}"

    def restore_filter(self, slot: int, saved: tuple[dict, bool]) -> None:
        values, enabled = saved
        fo = self._filter_slot(slot)
        if fo.enable_subindex is None:
            self.write_object(fo.address(slot, "block"), values["block"])  # the block as found, enable and all
            return
        self._write_slot(fo, slot, values, False)
        if enabled:
            self.write_object(fo.address(slot, "enabled"), 1)


class _FrameCounter:
    """Counts frames on some COB-IDs until stopped (PDOs left over from an earlier session)."""

    def __init__(self, network, cobs: list[int]):
        self.network = network
        self.cobs = cobs
        self.frames = 0
        for cob in cobs:
            network.subscribe(cob, self._on_frame)

    def _on_frame(self, can_id, data, timestamp) -> None:
        self.frames += 1

    def stop(self) -> None:
        for cob in self.cobs:
            with contextlib.suppress(KeyError, ValueError):
                self.network.unsubscribe(cob, self._on_frame)
