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

The adapter owns its parts and hands each its share of the work, so a call
site says where the code lives: ``sdo`` (:class:`~hilident.adapters.canopen.sdo.SdoAccess`,
every object read and write), ``net`` (:class:`~hilident.adapters.canopen.net.NetWatch`:
NMT, the host's heartbeat and the drive's consumer watching it, the drive's
heartbeat, emergencies), ``mapping`` (:class:`~hilident.adapters.canopen.mapping.ChannelMapping`:
limits, sample period, channel codecs and the PDO or capture mapping, which
returns the run's :class:`~hilident.adapters.canopen.common.RunLayout`, kept
as ``layout``) and ``slots`` (:class:`~hilident.adapters.canopen.slots.CanopenFilterSlots`).
Each part gets what it needs in its constructor; none of them sees the
adapter. This module keeps opening and the known state at connect, identity
and ratings, the CiA 402 state machine, the hooks of
:class:`~hilident.adapters.base.AdapterBase` (it overrides none of its public
methods) and the set-point and channel codecs. The acquisition strategies are
separate objects: they see the adapter through the protocol
:class:`~hilident.adapters.canopen.streamed.DriveHost`, and :data:`ACQUISITIONS`
is typed with it, so the checker verifies that this class provides everything
a strategy uses.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
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
from hilident.adapters.canopen.common import (
    _STATE_POLL_S,
    DriveIdentity,
    DriveRatings,
    RunLayout,
)
from hilident.adapters.canopen.link import open_network
from hilident.adapters.canopen.mapping import ChannelMapping
from hilident.adapters.canopen.net import HostHeartbeat, NetWatch
from hilident.adapters.canopen.recorder import RecorderRun
from hilident.adapters.canopen.sdo import SdoAccess
from hilident.adapters.canopen.slots import CanopenFilterSlots
from hilident.adapters.canopen.streamed import POSITION_SETPOINTS, Deliver, DriveHost, StreamedRun, choose_clock
from hilident.adapters.canopen.trace import TracingNetwork
from hilident.config.tables import DeviceConfig
from hilident.drivers.description import DriverDescription, load_object_dictionary
from hilident.errors import ConfigError, DataError, DeviceError, UsageError
from hilident.events import Kind, RunEvent
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    CanopenDescription,
    encode_si,
    numpy_type,
)
from hilident.protocol.canopen_profile import (
    decode_supported_modes,
)
from hilident.protocol.canopen_types import ModeSpec
from hilident.protocol.filter_encoding import FilterEncoding
from hilident.units import units_in_mode

__all__ = ["ACQUISITIONS", "CanopenDriveAdapter"]

#: How a run is played, by acquisition name (``device.acquisition``): a strategy ``(adapter, x, deliver,
#: result)`` (:class:`~hilident.adapters.base.RunStrategy`). A new acquisition strategy joins with one line.
ACQUISITIONS: dict[str, Callable[[DriveHost, np.ndarray, Deliver, RunResult], None]] = {
    "streamed": StreamedRun.play,
    "buffered": BufferedRun.play,
    "recorder": RecorderRun.play,
}


#: What canopen says when an SDO request got no answer within the timeout
_NO_ANSWER = "No SDO response received"


class CanopenDriveAdapter(AdapterBase):
    """A CiA 402 drive on a CAN bus.

    Open it with :meth:`open_device`. Attributes follow
    :class:`~hilident.adapters.base.DeviceAdapter`; beyond them:

    Attributes
    ----------
    acquisition : {"streamed", "buffered", "recorder"}
        How :meth:`stream` plays a run.
    sdo, net, mapping, slots
        The parts (see the module docstring).
    layout : RunLayout
        What :meth:`configure` set the drive up for (the default value before).
    ratings : DriveRatings
        Rated torque and current, read at connect.
    supported_modes : tuple of str or None
        What 0x6502 says the drive supports, when it has 0x6502.
    device_limits : tuple of str
        The limit objects the drive holds (the rest are checked by the host only).
    answered : bool
        The drive answered the last :meth:`safe_stop` (else :meth:`close` does not wait for it again).
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
        heartbeat: HostHeartbeat | None = None,
    ):
        encoding = (
            FilterEncoding.from_table(driver.sections["filters"], str(driver.folder))
            if desc.filters is not None
            else None
        )
        self.network = network
        self.owns_network = True  # False: a bus shared with other nodes of the session, released by their group
        self.node = node
        self.driver = driver
        self.desc = desc
        self.device = device
        self.port = label
        self.node_id = device.canopen.node_id  # the drive's node id ([device.canopen] node_id)
        self.timeout_s = device.timeout_s
        self.acquisition = desc.default_acquisition if device.acquisition == "auto" else device.acquisition
        node.sdo.RESPONSE_TIMEOUT = max(0.05, min(self.timeout_s, 1.0))
        heartbeat = heartbeat or HostHeartbeat(network, label)
        self.sdo = SdoAccess(node, desc, label, heartbeat.beat_if_due)
        self.net = NetWatch(network, self.sdo, heartbeat, desc, label, device.host_timeout_s)
        self.mapping = ChannelMapping(self.sdo, self.net, desc, driver, self.node_id, label)
        self.slots = CanopenFilterSlots(self.sdo, desc, driver, encoding, self.drive_identity, label)
        self.identity: DriveIdentity | None = None
        self.ratings = DriveRatings()
        self.supported_modes: tuple[str, ...] | None = None  # read from 0x6502 at connect
        self.sync_overflow = 0
        self.layout = RunLayout()
        self.sample_rate_hz = 0.0
        self.channel_names: list[str] = []
        self.channel_units: list[str] = []
        self.excitation_recipe: dict | None = None  # what a drive's own generator plays (recorder runs)
        self.last_result: RunResult | None = None
        self.events: list[dict] = []
        self.connect_report = ConnectReport()
        self.run_fault: dict | None = None  # the first fault event of the current run (the first cause)
        self.answered = True
        self._trace_path: Path | None = None
        self._limits: tuple[float, float, float, float] | None = None  # torque N·m, velocity m/s, position m
        self._host_checks: list = []
        self.device_limits: tuple[str, ...] = ()

    # --- opening --------------------------------------------------------------------------

    @classmethod
    def open_device(
        cls,
        device: DeviceConfig,
        driver: DriverDescription,
        link=None,
        network: TracingNetwork | None = None,
        heartbeat: HostHeartbeat | None = None,
    ) -> CanopenDriveAdapter:
        """Open the bus, load the EDS, check the identity, bring the drive to a known state, arm the net.

        ``network``: a bus already open that the drive shares with other nodes of the session
        (:mod:`hilident.adapters.canopen.group`); the adapter then never disconnects it. ``heartbeat``: the
        host's heartbeat those nodes share (one host, one heartbeat on the bus), else the adapter's own.

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
        owns_network = network is None
        network = open_network(device, driver.default_baudrate, label) if network is None else network
        adapter = None
        try:
            node = canopen.RemoteNode(node_id, od)
            network.add_node(node)
            adapter = cls(network, node, driver, desc, device, label, heartbeat)
            adapter.owns_network = owns_network
            adapter.connect_report.warnings += eds_warnings
            early = adapter.net.count_early_frames(node_id)
            try:
                adapter._identify()
                adapter._to_known_state()
            finally:
                early.stop()
            adapter.connect_report.discarded_frames += early.frames
            adapter.connect_report.device_net = adapter.net.arm_device_net()
        except BaseException:
            if adapter is not None:
                adapter.net.stop_heartbeats()
            if owns_network:
                with contextlib.suppress(Exception):
                    network.disconnect()
            raise
        return adapter

    # --- identity, ratings, the known state at connect --------------------------------------------

    def _identify(self) -> None:
        """Identity, rated torque and current, supported modes; then the drive's heartbeat.

        Only objects the EDS has are read; the identity is checked when the
        driver description gives one.
        """
        d, sdo = self.desc, self.sdo
        vendor = int(sdo.read("vendor_id")) if d.has("vendor_id") else 0
        product = int(sdo.read("product_code")) if d.has("product_code") else 0
        self._check_identity(vendor, product)
        name = str(sdo.read("device_name")) if d.has("device_name") else self.driver.name
        version = str(sdo.read("software_version")) if d.has("software_version") else ""
        self.identity = DriveIdentity(
            name, version, float(self.driver.loop_rate_hz), int(self.driver.filter_slots), vendor, product
        )
        self.ratings = self._read_ratings()
        if d.has("supported_modes"):
            self.supported_modes = decode_supported_modes(int(sdo.read("supported_modes")))
            # the modes only: the parts keep the description they were given, whose objects stay the same
            self.desc = d = d.with_supported_modes(self.supported_modes)
        if d.has("sync_overflow"):
            self.sync_overflow = int(sdo.read("sync_overflow"))
        self.net.watch_drive_heartbeat(self.timeout_s)

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
                    f"({self.sdo.describe(d.address(key))}); driver {self.driver.name!r} expects 0x{expected:08X}"
                )
        if d.has("loop_rate"):
            rate = float(self.sdo.read("loop_rate"))
            if abs(rate - self.driver.loop_rate_hz) > 1e-6 * self.driver.loop_rate_hz:
                raise DeviceError(
                    f"{self.port}: the drive's loop runs at {rate:g} Hz "
                    f"({self.sdo.describe(d.address('loop_rate'))}); driver {self.driver.name!r} says "
                    f"{self.driver.loop_rate_hz:g} Hz"
                )

    def _read_ratings(self) -> DriveRatings:
        """Rated torque (N·m; 0 with the reason kept when it cannot be scaled) and rated current (A)."""
        d, sdo = self.desc, self.sdo
        problem = ""
        try:
            torque_nm = d.rated_torque(float(sdo.read("rated_torque")) if d.has("rated_torque") else None)
        except DataError as exc:
            torque_nm = 0.0  # an experiment that needs torque objects says so
            problem = str(exc)
        current_a = d.rated_current(float(sdo.read("rated_current")) if d.has("rated_current") else None)
        return DriveRatings(torque_nm, current_a, problem)

    def _to_known_state(self) -> None:
        """NMT Pre-operational, power stage off, latched faults reported (reset only when allowed).

        Raises
        ------
        DeviceError
            The drive is in Fault and ``device.allow_fault_reset`` is false (the
            message names the fault and how to clear it), or it does not leave Fault.
        """
        self.net.nmt("PRE-OPERATIONAL")  # PDOs of an earlier session stop here
        state = self.drive_state()
        if state in (cia402.State.FAULT, cia402.State.FAULT_REACTION_ACTIVE):
            self._clear_latched_fault(
                f"{state.value}, {self.last_error_text()}",
                self.device.allow_fault_reset,
                lambda: self._reset_fault(state),
            )
        elif cia402.path_to_safe_state(state):
            self.safe_stop()  # left switched on by someone else: off before anything moves
            state = self.drive_state()
            if state is not cia402.State.SWITCH_ON_DISABLED:
                raise DeviceError(
                    f"{self.port}: the drive does not switch its power stage off: it stays in "
                    f"{state.value} after Disable Voltage "
                    f"({self.sdo.describe(self.desc.address('controlword'))})"
                )
        self.connect_report.discarded_frames += len(self.net.emergencies)
        self.net.emergencies.clear()  # emergencies of an earlier session: their fault is handled above

    def _reset_fault(self, state: cia402.State) -> None:
        """Fault reset (a rising edge of controlword bit 7) to Switch On Disabled."""
        state = self._follow(state, (int(cia402.Command.DISABLE_VOLTAGE), int(cia402.Command.FAULT_RESET)))
        if state is not cia402.State.SWITCH_ON_DISABLED:
            raise DeviceError(
                f"{self.port}: the fault did not clear: the drive is in {state.value} ({self.last_error_text()})"
            )

    # --- CiA 402 state machine ----------------------------------------------------------------

    def drive_state(self) -> cia402.State:
        sw = int(self.sdo.read("statusword"))
        try:
            return cia402.decode_statusword(sw)
        except ValueError as exc:
            raise DeviceError(f"{self.port}: {self.sdo.describe(self.desc.address('statusword'))}: {exc}") from None

    def _command(self, state: cia402.State, cw: int, previous: int) -> cia402.State:
        """Write ``cw`` and wait until the statusword shows the state it leads to."""
        expected, _ = cia402.transition(state, cw, previous)
        self.sdo.write("controlword", cw)
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
            code = int(self.sdo.read("error_code"))
        except DeviceError:
            return "error code unreadable"
        return f"error code 0x{code:04X}: {cia402.emcy_meaning(code)}" if code else "no error code"

    # --- stopping and closing (hooks of AdapterBase.safe_stop and close) -------------------------

    def _command_safe(self) -> None:
        """Power stage off now: Disable Voltage (transitions 7, 9, 10, 12 to Switch On Disabled).

        One SDO write, whatever the state (a drive in Fault keeps its fault and
        its power stage stays off). The bus and the host's heartbeat stay up;
        a drive that does not answer costs one SDO timeout. Safe to call from
        a signal handler that interrupted a block transfer: that transfer is
        aborted first, or the drive would take the request for a data segment.
        An answer of that transfer arriving late can be taken for this write's
        answer (SDO has no request id): the write is then repeated once.
        """
        try:
            self.sdo.abort_interrupted_transfer()
            self.answered = self._disable_voltage()
        except Exception:
            self.answered = False  # gone or not listening: close() does not wait for it again
            raise

    def _disable_voltage(self) -> bool:
        """Write Disable Voltage; once more when the answer read was not this write's (a stale one)."""
        for attempt in (1, 2):
            try:
                self.sdo.write("controlword", int(cia402.Command.DISABLE_VOLTAGE))
                return True
            except DeviceError as exc:
                if attempt == 2 or _NO_ANSWER in str(exc):  # silence is not retried: it costs a timeout
                    return False
        return False

    def _stop_for_close(self) -> None:
        """Power stage off; the drive's heartbeat consumer off (when it answered) before the host's heartbeat
        stops, so a clean close does not look like a dead host; NMT Pre-operational (no PDOs from here on)."""
        self.safe_stop()
        if self.answered:
            with contextlib.suppress(Exception):
                self.net.disarm_device_net()
        with contextlib.suppress(Exception):
            self.net.nmt("PRE-OPERATIONAL")

    def _release(self) -> None:
        """Host heartbeat off, CAN trace closed, bus released (unless shared with other nodes: their group
        releases it); each step whatever the others did."""
        self.net.stop_heartbeats()
        if not self.owns_network:
            return
        with contextlib.suppress(Exception):
            self.network.stop_trace()
        with contextlib.suppress(Exception):
            self.network.disconnect()

    # --- configuration ---------------------------------------------------------------------------

    def scale(self, role: str) -> float:
        """SI value of one raw unit of the object of ``role``; DeviceError when it cannot be scaled."""
        try:
            return self.desc.scale(role, self.ratings.torque_nm, self.ratings.current_a)
        except DataError as exc:
            raise DeviceError(
                f"{self.port}: {self.sdo.describe(self.desc.address(role))}: {self.ratings.torque_problem or exc}"
            ) from None

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
        limits = (torque_nm, velocity_mps, position_min_m, position_max_m)
        self.device_limits = self.mapping.load_limits(limits, self.scale, self.ratings.torque_nm > 0)
        self._limits = limits

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Mode of operation, sample period and the PDO (or capture) mapping of the channels.

        The period goes to whichever of 0x1006 (us) and 0x60C2 (value and
        exponent) the drive has. Everything is checked before the drive is
        stopped and anything is written (a recorder run's channels aside).
        """
        loop_rate_hz = self.drive_identity().loop_rate_hz
        divider, rate = self.mapping.divider_for(sample_rate_hz, loop_rate_hz)
        spec = self._mode_spec(mode)
        codecs = self.mapping.channel_codecs(channels, self.scale)
        if self.acquisition == "recorder":
            self.mapping.prepare_recorder(codecs)
        elif self.acquisition == "buffered" and any(c.on_host for c in codecs):
            raise DeviceError(
                f"{self.port}: a drive-buffered run records only drive objects; channel "
                f"{next(c.name for c in codecs if c.on_host)!r} has none"
            )
        for role in (spec.setpoint, spec.hold):
            if role:
                self.scale(role)  # a set-point that cannot be scaled stops here, before anything moves
        self._check_following_error(spec)
        self.safe_stop()
        self.sdo.write("modes_of_operation", spec.code)
        self.mapping.write_period(divider, loop_rate_hz)
        planned = RunLayout(self.acquisition, mode, divider, rate, tuple(codecs))
        self.layout = self.mapping.map_run(planned, spec)
        self.sample_rate_hz = rate
        self.channel_names = [c.name for c in codecs]
        self.channel_units = units_in_mode(self.channel_names, [c.unit for c in codecs], mode)
        return self.channel_names

    def _check_following_error(self, spec) -> None:
        """A position mode on a drive whose following error window (0x6065) is 0 faults on its first sample
        (CiA 402: any distance from the set-point is a following error): refused before anything moves."""
        position = spec.setpoint in POSITION_SETPOINTS or spec.hold in POSITION_SETPOINTS  # the drive's position loop
        if not position or not self.desc.has("following_error_window"):
            return
        if int(self.sdo.read("following_error_window")) == 0:
            where = self.sdo.describe(self.desc.address("following_error_window"))
            raise DeviceError(
                f"{self.port}: {where} is 0: with its position loop closed the drive would fault (following error) "
                "on the first sample; set it in the drive to the largest distance from the set-point it may tolerate, "
                "in position units (0xFFFFFFFF switches the monitor off)"
            )

    def clock_plan(self, sample_rate_hz: float) -> dict:
        """Who will keep the bus clock of a run at ``sample_rate_hz``: ``{"source", "why"}``.

        Raises
        ------
        ConfigError
            ``device.canopen.sync_source`` asks for a source the drive or the interface does not offer.
        """
        if self.acquisition != "streamed":
            return {"source": "drive", "why": f"the drive plays the run itself ({self.acquisition} acquisition)"}
        choice, task = choose_clock(self, 1.0 / sample_rate_hz)
        if task is not None:
            task.stop()
        return {"source": choice.source, "why": choice.why}

    def _mode_spec(self, mode: str) -> ModeSpec:
        """The driver's mode for ``mode``; DeviceError naming the modes it has (and 0x6502's) when it has none."""
        if mode not in self.desc.modes:
            supported = (
                f"; 0x6502 says it supports {', '.join(self.supported_modes) or 'no mode'}"
                if self.supported_modes is not None
                else ""
            )
            raise DeviceError(
                f"{self.port}: driver {self.driver.name!r} has no mode for {mode!r} "
                f"(it has {', '.join(self.desc.modes) or 'none'}{supported})"
            )
        return self.desc.modes[mode]

    # --- runs (hooks of AdapterBase.stream) ---------------------------------------------------------

    def _set_trace(self, path: str | os.PathLike[str]) -> None:
        """Write a CAN trace (``.asc`` or ``.blf``) of the next run to ``path``."""
        self._trace_path = Path(path)

    def _set_excitation_recipe(self, recipe: dict | None) -> None:
        """The excitation of the next :meth:`stream` as parameters (``kind``, ``amplitude``, band, ...).

        A recorder run has the drive's generator play it (see
        :mod:`hilident.adapters.canopen.recorder`); the other runs play the samples.
        """
        self.excitation_recipe = dict(recipe) if recipe is not None else None

    def _prepare_run(self, x: np.ndarray) -> None:
        """Configured for this acquisition; emergencies from before dropped; the CAN trace started."""
        if not self.layout.channels or self.layout.acquisition != self.acquisition:
            raise DeviceError(f"{self.port}: configure() for {self.acquisition} acquisition before stream()")
        self.net.emergencies.clear()
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

    def take_emergency_fault(self, sample_index: int) -> dict | None:
        """Log the queued emergencies up to the first fault, note that as the run's fault and return it.

        ``sample_index`` is where the host is, for drives whose EMCY does not
        name the sample. Emergencies after the fault stay queued; None when
        no fault was queued.
        """
        queue = self.net.emergencies
        while queue:
            event = self.log_event(self.net.emergency_event(queue.popleft(), sample_index))
            if event["kind"] != Kind.EMERGENCY_RESET.value:
                self.note_fault(event)
                return event
        return None

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
        return [(j, *bounds[c.name]) for j, c in enumerate(self.layout.channels) if c.name in bounds]

    # --- filter slots (hooks of AdapterBase's filter-slot methods) ----------------------------------

    def _write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        self.slots.write_filter(slot, biquad, spec, enabled)

    def _read_filter(self, slot: int) -> tuple[Biquad, bool]:
        return self.slots.read_filter(slot)

    def _stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        return self.slots.stored_form(biquad, spec)

    def _read_raw_slot(self, slot: int) -> tuple[dict, bool]:
        return self.slots.read_raw(slot)

    def _write_raw_slot(self, slot: int, saved: tuple[dict, bool]) -> None:
        self.slots.write_raw(slot, saved)

    def _bypass_slot(self, slot: int) -> None:
        self.slots.bypass(slot)

    def filter_notes(self, spec: NotchSpec) -> tuple[str, ...]:
        """Why the drive's encoding cannot meet ``spec`` exactly (depth or width out of reach), if it cannot."""
        return self.slots.filter_notes(spec)

    def _loop_description(self):
        return self.desc.loop

    def _read_loop(self) -> dict[str, float] | None:
        """The drive's cascade parameters in SI units (``[loop]``: the objects read, the fixed values as given);
        None when the driver description has no ``[loop]``. DeviceError naming the object when one cannot be
        read."""
        loop = self.desc.loop
        if loop is None:
            return None
        return {
            name: p.physical(self.sdo.read_object(p.address)) if p.address is not None else float(p.value or 0.0)
            for name, p in loop.parameters.items()
        }

    def _write_loop(self, values: dict[str, float]) -> None:
        """Each tunable parameter into its object, in the object's unit (rounded to its type); DeviceError naming
        the object when the drive refuses it, UsageError when the description keeps it as a fixed value."""
        params = [self._loop_object(name) for name in values]
        stored = [self._loop_stored_value(p, v) for p, v in zip(params, values.values(), strict=True)]  # all first
        for param, value in zip(params, stored, strict=True):
            assert param.address is not None
            self.sdo.write_object(param.address, value)

    def _stored_loop(self, values: dict[str, float]) -> dict[str, float]:
        """``values`` as the objects will hold them: an integer object keeps the nearest whole unit."""
        return {
            name: self._loop_object(name).physical(self._loop_stored_value(self._loop_object(name), v))
            for name, v in values.items()
        }

    def _loop_object(self, name: str):
        loop = self.desc.loop
        param = loop.parameters.get(name) if loop is not None else None
        if param is None or param.address is None:
            raise UsageError(
                f"{self.port}: {name} is not held in an object of the drive ([loop] of the driver gives "
                + ("no [loop]" if loop is None else "it as a fixed value")
                + ")"
            )
        return param

    def _loop_stored_value(self, param, value: float):
        """What the object of ``param`` is written for the SI ``value``: REAL types as given, integers rounded."""
        assert param.address is not None
        stored = param.stored(float(value))
        data_type = self.sdo.data_type(param.address)
        if data_type == 0x0008:  # REAL32
            return float(np.float32(stored))
        if data_type == 0x0011:  # REAL64
            return stored
        if not math.isfinite(stored):
            raise UsageError(
                f"{self.port}: {param.name} = {value} cannot be held in the integer object {param.address}"
            )
        whole = int(round(stored))
        try:
            self.sdo.eds_variable(param.address).encode_raw(whole)
        except (ValueError, TypeError, struct.error):
            raise UsageError(
                f"{self.port}: {param.name} = {value} ({whole} units) does not fit {self.sdo.describe(param.address)}"
            ) from None
        return whole

    def save_parameters(self) -> str:
        """Have the drive store its parameters in non-volatile memory (0x1010, or the object ``[canopen.save]``
        names); what was written, e.g. ``"0x1010:1 (Save all parameters) = 0x65766173"``. DeviceError when the
        drive has no store object or refuses the command."""
        return self.slots.save_parameters()

    # --- set-point and channel codecs ------------------------------------------------------------

    def decode_rows(self, raw_columns: list[np.ndarray], first_index: int = 0) -> np.ndarray:
        """Raw channel columns -> SI rows (values at their integer type's limit counted, see
        :meth:`count_saturated`)."""
        raw = np.column_stack([c.astype(float) for c in raw_columns])
        self.count_saturated(raw, first_index)
        return raw * np.array([codec.scale for codec in self.layout.channels])

    def count_saturated(self, raw: np.ndarray, first_index: int) -> None:
        """Count the rows of ``raw`` (raw values, one column per channel) in which a drive-reported integer sits at
        its type's limit: the drive's value is saturated there, not measured (kept, counted as clipped).

        The first such sample of a run gets a ``clipped`` event naming the channel and its object.
        """
        hit = np.zeros(len(raw), dtype=bool)
        first = None
        for j, c in enumerate(self.layout.channels):
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
                    f"{c.name} reached the range of {self.sdo.describe(address)} ({numpy_type(c.datatype)}): "
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
