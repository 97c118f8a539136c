"""Host side of a CiA 402 servo drive on CANopen (python-can + canopen).

The adapter opens the bus ``[device]`` names (:mod:`hilident.adapters.canopen.link`),
loads the drive's EDS from its driver folder, checks the identity object against
the driver description, asks for a heartbeat and listens to it and to the
drive's emergencies, drives the CiA 402 state machine
(:mod:`hilident.protocol.cia402`) to Operation Enabled for each run and back
to a safe state (Disable Voltage: zero torque) on every exit path.

Each run is played one of three ways (``device.acquisition``; ``"auto"`` takes the
driver's ``default_acquisition``):

``"streamed"`` (:mod:`hilident.adapters.canopen.streamed`)
    the host sends an RPDO set-point and a SYNC every sample period and
    receives TPDOs carrying a sample counter: lost and late frames are counted;
``"buffered"`` (:mod:`hilident.adapters.canopen.buffered`)
    the excitation table goes to the drive by SDO (block transfer), the drive
    plays it at its own rate and captures; the host reads the capture back in
    chunks while it runs;
``"recorder"`` (:mod:`hilident.adapters.canopen.recorder`)
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

The adapter class is composed of parts along its seams (see :mod:`hilident.adapters`):
object access (:mod:`~hilident.adapters.canopen.sdo`), NMT, heartbeats and
emergencies (:mod:`~hilident.adapters.canopen.net`), configuration and PDO mapping
(:mod:`~hilident.adapters.canopen.mapping`) and filter slots
(:mod:`~hilident.adapters.canopen.slots`); this module keeps opening, closing,
identity, the CiA 402 state machine and the run hooks.

How the parts are typed: every part derives from
:class:`~hilident.adapters.canopen.common.CanopenState`, which declares the
attributes this class sets in ``__init__`` (bare annotations: nothing changes
at run time) and, under ``TYPE_CHECKING`` only, the signatures of the methods
one part calls that another part, this class or
:class:`~hilident.adapters.base.AdapterBase` defines. The type checker holds
each definition to its declaration; a part uses nothing CanopenState does not
declare, and a new cross-part call or shared attribute is declared there first.
The acquisition strategies are separate objects: they see the adapter through
the protocol :class:`~hilident.adapters.canopen.streamed.DriveHost`, and
:data:`ACQUISITIONS` is typed with it, so the checker verifies that this class
provides everything a strategy uses.
"""

from __future__ import annotations

import collections
import contextlib
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import can
import numpy as np

import canopen
from hilident.adapters.base import (
    AdapterBase,
    ConnectReport,
    RunResult,
)
from hilident.adapters.canopen.buffered import BufferedRun
from hilident.adapters.canopen.common import (  # noqa: F401  (re-exported)
    _ABORT_GENERAL,
    _GUARD_TIME,
    _LIFE_TIME_FACTOR,
    _NMT_OPERATIONAL,
    _STATE_POLL_S,
    _TPDO_BASES,
    _TRANSFER_ERRORS,
    LIMIT_TRIP_CODES,
    STORE_SIGNATURE,
    ChannelCodec,
    DriveIdentity,
    Emergency,
    PdoSlot,
    _transfer_error,
)
from hilident.adapters.canopen.link import open_network
from hilident.adapters.canopen.mapping import ChannelMapping
from hilident.adapters.canopen.net import NetWatch
from hilident.adapters.canopen.recorder import RecorderRun
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.adapters.canopen.slots import FilterSlots
from hilident.adapters.canopen.streamed import Deliver, DriveHost, StreamedRun
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.config.tables import DeviceConfig
from hilident.drivers.description import DriverDescription, load_object_dictionary
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.events import Kind, RunEvent
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    CanopenDescription,
    encode_si,
    numpy_type,
)
from hilident.protocol.canopen_profile import (
    decode_supported_modes,
)
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["CanopenDriveAdapter", "DriveIdentity", "ChannelCodec", "LIMIT_TRIP_CODES"]

#: How a run is played, by acquisition name (``device.acquisition``): a strategy ``(adapter, x, deliver,
#: result)`` (:class:`~hilident.adapters.base.RunStrategy`). A new acquisition strategy joins with one line.
ACQUISITIONS: dict[str, Callable[[DriveHost, np.ndarray, Deliver, RunResult], None]] = {
    "streamed": StreamedRun.play,
    "buffered": BufferedRun.play,
    "recorder": RecorderRun.play,
}


#: What canopen says when an SDO request got no answer within the timeout
_NO_ANSWER = "No SDO response received"


class CanopenDriveAdapter(SdoAccess, NetWatch, ChannelMapping, FilterSlots, AdapterBase):
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

    def __init__(
        self,
        network: TracingNetwork,
        node: canopen.RemoteNode,
        driver: DriverDescription,
        desc: CanopenDescription,
        device: DeviceConfig,
        label: str,
    ):
        self.network = network
        self.node = node
        self.driver = driver
        self.desc = desc
        self.device = device
        self.port = label
        self.node_id = device.canopen.node_id
        self.timeout_s = device.timeout_s
        self.encoding = (
            FilterEncoding.from_table(driver.sections["filters"], str(driver.folder))
            if desc.filters is not None
            else None
        )
        self.acquisition = desc.default_acquisition if device.acquisition == "auto" else device.acquisition
        self.identity = None
        self.sample_rate_hz = 0.0
        self.divider = 0
        self.mode = ""
        self.channels = []
        self.channel_names = []
        self.channel_units = []
        self.sync_rate_hz = None
        self.sync_overflow = 0
        self.rated_torque_nm = 0.0
        self.rated_current_a = 0.0
        self.torque_problem = ""  # why torque objects cannot be scaled, when they cannot
        self.supported_modes = None  # read from 0x6502 at connect
        self.tpdo_layout = []  # (COB-ID, channel indices after the counter)
        self.rpdo = None  # (COB-ID, counter type, set-point type, set-point role)
        self._configured_for = ""  # the acquisition configure() mapped the objects for
        self.excitation_recipe = None  # what a drive's own generator plays (recorder runs)
        self.last_result = None
        self.events = []
        self.connect_report = ConnectReport()
        self.run_fault = None  # the first fault event of the current run (the first cause)
        self._host_heartbeat = None  # the periodic task producing the host's heartbeat
        self._guarding = False  # the host guards the drive (no 0x1017): node guarding requests go out
        self._consumer = None  # the 0x1016 entry watching the host
        self._in_block_transfer = False  # a block transfer is under way (safe_stop must abort it first)
        self.answered = True  # the drive answered the last safe_stop()
        self._beat = (0, 0.0)  # (COB-ID, period s) of the host's heartbeat
        self._beat_s = 0.0  # when the host's heartbeat last went out (monotonic s)
        self.emergencies = collections.deque()
        self.heartbeat_s = None
        self.heartbeat_state = None
        self._trace_path = None
        self._limits = None
        self._host_checks: list = []
        self.device_limits = ()  # the limit objects the drive holds (the rest: host-checked only)
        self._nmt_settled_s = 0.0  # heartbeats before this may still carry the NMT state before our last command
        node.sdo.RESPONSE_TIMEOUT = max(0.05, min(self.timeout_s, 1.0))
        node.nmt.add_heartbeat_callback(self._on_heartbeat)
        node.emcy.add_callback(self._on_emcy)

    # --- opening and closing --------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> CanopenDriveAdapter:
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
        node_id = device.canopen.node_id
        eds_warnings: list[str] = []
        od = load_object_dictionary(driver, node_id, eds_warnings)
        desc = CanopenDescription.from_sections(driver.sections, source, od)
        if device.acquisition == "buffered" or (
            device.acquisition == "auto" and desc.default_acquisition == "buffered"
        ):
            desc.require_buffered(source)
        label = f"{device.canopen.can_interface}:{device.port} node {node_id}"
        if desc.host_node_id == node_id:
            raise ConfigError(
                "canopen.host_node_id",
                f"{desc.host_node_id} is also the drive's node id (device.canopen.node_id): the "
                "host's heartbeat needs a node id of its own",
                source,
            )
        network = open_network(device, driver.default_baudrate, label)
        adapter = None
        try:
            node = canopen.RemoteNode(node_id, od)
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

    # --- identity, heartbeat, emergencies ------------------------------------------------------

    def _identify(self) -> None:
        """Identity, rated torque and current, supported modes; then the drive's heartbeat.

        Only objects the EDS has are read; the identity is checked when the
        driver description gives one.
        """
        d = self.desc
        vendor = int(self.read("vendor_id")) if d.has("vendor_id") else 0
        product = int(self.read("product_code")) if d.has("product_code") else 0
        self._check_identity(vendor, product)
        name = str(self.read("device_name")) if d.has("device_name") else self.driver.name
        version = str(self.read("software_version")) if d.has("software_version") else ""
        self.identity = DriveIdentity(
            name, version, float(self.driver.loop_rate_hz), int(self.driver.filter_slots), vendor, product
        )
        self._read_ratings()
        if d.has("supported_modes"):
            self.supported_modes = decode_supported_modes(int(self.read("supported_modes")))
            self.desc = d = d.with_supported_modes(self.supported_modes)
        if d.has("sync_overflow"):
            self.sync_overflow = int(self.read("sync_overflow"))
        self._watch_drive_heartbeat()

    def drive_identity(self) -> DriveIdentity:
        """:attr:`identity`, which :meth:`open_device` reads; DeviceError on an adapter it has not identified."""
        if self.identity is None:
            raise DeviceError(f"{self.port}: the drive has not been identified (open it with open_device)")
        return self.identity

    def _check_identity(self, vendor: int, product: int) -> None:
        """DeviceError when the vendor id, product code or loop rate is not the driver description's."""
        d = self.desc
        for key, expected, got in (("vendor_id", d.vendor_id, vendor), ("product_code", d.product_code, product)):
            if expected is not None and got != expected:
                raise DeviceError(
                    f"{self.port}: the node reports {key.replace('_', ' ')} 0x{got:08X} "
                    f"({self.describe(d.address(key))}); driver {self.driver.name!r} expects 0x{expected:08X}"
                )
        if d.has("loop_rate"):
            rate = float(self.read("loop_rate"))
            if abs(rate - self.driver.loop_rate_hz) > 1e-6 * self.driver.loop_rate_hz:
                raise DeviceError(
                    f"{self.port}: the drive's loop runs at {rate:g} Hz "
                    f"({self.describe(d.address('loop_rate'))}); driver {self.driver.name!r} says "
                    f"{self.driver.loop_rate_hz:g} Hz"
                )

    def _read_ratings(self) -> None:
        """Rated torque (N·m; 0 with the reason kept when it cannot be scaled) and rated current (A)."""
        d = self.desc
        try:
            self.rated_torque_nm = d.rated_torque(float(self.read("rated_torque")) if d.has("rated_torque") else None)
        except DataError as exc:
            self.rated_torque_nm = 0.0  # an experiment that needs torque objects says so
            self.torque_problem = str(exc)
        self.rated_current_a = d.rated_current(float(self.read("rated_current")) if d.has("rated_current") else None)

    def _watch_drive_heartbeat(self) -> None:
        """Ask for the drive's heartbeat (0x1017) or start node guarding, then wait for the first beat."""
        d = self.desc
        od = self.node.object_dictionary
        if d.has("heartbeat_time"):
            self.write("heartbeat_time", d.heartbeat_ms)
            how = f"setting {self.describe(d.address('heartbeat_time'))} to {d.heartbeat_ms} ms"
        elif _GUARD_TIME in od and _LIFE_TIME_FACTOR in od:
            self._start_node_guarding()
            how = f"starting node guarding every {d.heartbeat_ms} ms (the EDS has no 0x1017)"
        else:
            raise DeviceError(
                f"{self.port}: the EDS {d.eds} has neither a producer heartbeat time (0x1017) nor "
                "node guarding (0x100C, 0x100D): hilident watches the drive by one of them"
            )
        deadline = time.monotonic() + max(self.timeout_s, 3 * d.heartbeat_ms / 1000.0)
        while self.heartbeat_s is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if self.heartbeat_s is None:
            raise DeviceError(f"{self.port}: no heartbeat within {self.timeout_s:g} s after {how}")

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

    def _follow(self, state: cia402.State, commands: Iterable[int]) -> cia402.State:
        """Write ``commands`` (controlwords) one after another, each once the drive shows the state the last
        one led to; the state the drive ends in."""
        previous = 0
        for cw in commands:
            state = self._command(state, cw, previous)
            previous = cw
        return state

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
            raise DeviceError(
                f"{self.port}: the drive is in {state.value} ({self.last_error_text()}); set "
                "device.allow_fault_reset = true to let hilident reset it"
            ) from None
        state = self._follow(state, path)
        if state is not cia402.State.OPERATION_ENABLED:
            raise DeviceError(
                f"{self.port}: the drive did not reach Operation Enabled: it is in {state.value} "
                f"({self.last_error_text()})"
            )

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
        data segment. An answer of that transfer arriving late can be taken
        for this write's answer (SDO has no request id): the write is then
        repeated once.
        """
        try:
            if self._in_block_transfer:
                self.node.sdo.abort(_ABORT_GENERAL)
            self.answered = self._disable_voltage()
        except Exception:
            self.answered = False  # gone or not listening: close() does not wait for it again

    def _disable_voltage(self) -> bool:
        """Write Disable Voltage; once more when the answer read was not this write's (a stale one)."""
        for attempt in (1, 2):
            try:
                self.write("controlword", int(cia402.Command.DISABLE_VOLTAGE))
                return True
            except DeviceError as exc:
                if attempt == 2 or _NO_ANSWER in str(exc):  # silence is not retried: it costs a timeout
                    return False
        return False

    # --- runs --------------------------------------------------------------------------------------

    def set_trace(self, path: str | os.PathLike[str]) -> None:
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

    def _play(self, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
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
        :mod:`hilident.adapters.canopen.recorder`); the other runs play the samples.
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
        bounds = {"velocity_mps": (-velocity, velocity, "velocity_limit"), "position_m": (pmin, pmax, "position_limit")}
        if "max_torque" not in self.device_limits:
            bounds["torque_nm"] = (-torque, torque, "torque_limit")
        return [(j, *bounds[c.name]) for j, c in enumerate(self.channels) if c.name in bounds]

    def decode_rows(self, raw_columns: list[np.ndarray], first_index: int = 0) -> np.ndarray:
        """Raw channel columns -> SI rows (values at their integer type's limit counted, see
        :meth:`count_saturated`)."""
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
            if c.address is None:  # the host's own column (the set-point it sent)
                continue
            kind = numpy_type(c.datatype)
            if kind.kind not in "iu":
                continue
            info = np.iinfo(kind)
            at = (raw[:, j] >= info.max) | (raw[:, j] <= info.min)
            if at.any() and first is None:
                first = (c, c.address, int(np.argmax(at)))
            hit |= at
        if not hit.any() or self.last_result is None:
            return
        stats = self.last_result.stats
        if first is not None and not stats.clipped_blocks:
            c, address, row = first
            self.log_event(
                RunEvent(
                    Kind.CLIPPED,
                    f"{c.name} reached the range of {self.describe(address)} ({numpy_type(c.datatype)}): "
                    "the drive's value is saturated there; its scaling ([canopen.scaling]) or the excitation is "
                    "too large",
                    first_index + row,
                )
            )
        stats.clipped_blocks += int(hit.sum())

    def encode_setpoints(self, x: np.ndarray, datatype: int, role: str, origin_raw: int = 0) -> np.ndarray:
        """Excitation in SI units -> raw set-point values of the object of ``role``."""
        raw = encode_si(x, datatype, self.scale(role))
        if origin_raw:
            raw = (raw.astype(np.int64) + origin_raw).astype(raw.dtype)
        return raw
