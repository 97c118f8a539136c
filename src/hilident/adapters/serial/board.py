"""Host side of the serial board protocol, over pyserial.

Opens a device path (``/dev/ttyUSB0``), a Windows port (``COM3``) or any
pyserial URL (``socket://host:port``, ``rfc2217://host:port``), streams the
excitation with flow control, receives sample blocks, counts every lost,
corrupt or out-of-order frame, and stops the axis (zero torque) on every exit
path: normal end, error, limit trip, Ctrl-C.

Connecting brings the board to a known state whatever the previous session
left behind (it may have been killed mid-run): frames of the old run are
decoded and discarded, STOP is sent, a latched fault is reported and cleared
only when allowed. Only the messages of PROTOCOL.md are used, so any board
built to it is handled the same way.
"""

from __future__ import annotations

import logging
import secrets
import socket
import struct
import time
from typing import Protocol

import numpy as np
import serial

try:  # POSIX: the exact byte count of a TCP line
    import fcntl
    import termios
except ImportError:  # pragma: no cover
    pass

from hilident.adapters.base import AdapterBase, ConnectReport, Deliver, RunResult, RunStrategy
from hilident.adapters.ports import open_failure
from hilident.adapters.serial import loop as board_loop
from hilident.config.tables import DeviceConfig
from hilident.drivers.description import DriverDescription, serial_loop
from hilident.errors import DeviceError, ProtocolError
from hilident.events import Kind, RunEvent
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.links import LinkClosed
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame
from hilident.units import units_in_mode

log = logging.getLogger(__name__)

_END_EVENTS = (sb.EventCode.FINISHED, sb.EventCode.STOPPED, sb.EventCode.LIMIT_TRIP, sb.EventCode.WATCHDOG)

_MODES = {
    "torque": sb.Mode.TORQUE,
    "torque_injection": sb.Mode.TORQUE_INJECTION,
    "velocity": sb.Mode.VELOCITY,
    "position": sb.Mode.POSITION,
}
_FORMATS = {"f32": sb.Format.F32, "i16": sb.Format.I16, "i32": sb.Format.I32}
_EXCITATION_CHUNK = 256  # samples per EXCITATION frame
_KEEPALIVE_S = 0.2  # longest host silence while streaming (the board's watchdog is longer)
_READ_TIMEOUT_S = 0.02
_END_GRACE_S = 0.3  # after the board announced the end of a run, wait this long for its last block
_DRAIN_TIMEOUTS = 5  # while connecting, an answer behind a stream of stale frames may take this many timeouts
_MAX_TRACKED_GAPS = 4096  # lost blocks / frame numbers remembered, so a late arrival can be recognised

#: The device-side stop of this transport (PROTOCOL.md section 8); the board fixes it, the host cannot arm it.
WATCHDOG_NET = "board watchdog: a running board stops the axis (zero torque) after 1 s without a byte from the host"

_LIMIT_FAULTS = (sb.FaultCode.TORQUE_LIMIT, sb.FaultCode.VELOCITY_LIMIT, sb.FaultCode.POSITION_LIMIT)

_FAULT_MEANING = {
    sb.FaultCode.TORQUE_LIMIT: "a torque limit tripped",
    sb.FaultCode.VELOCITY_LIMIT: "a velocity limit tripped",
    sb.FaultCode.POSITION_LIMIT: "a position limit tripped",
    sb.FaultCode.WATCHDOG: "the board's watchdog stopped a run whose host went silent",
    sb.FaultCode.NONE: "no fault code given",
}


class BoardRefusal(DeviceError):
    """The board answered a request with a NAK; :attr:`nak` is that answer (its code and detail)."""

    def __init__(self, message: str, nak: sb.Nak):
        super().__init__(message)
        self.nak = nak


def board_stored_form(biquad: Biquad) -> Biquad:
    """The coefficients of ``biquad`` as the board stores them (REAL32: PROTOCOL.md's filter frames)."""
    b0, b1, b2 = biquad.b
    return Biquad(
        (sb.float32(b0), sb.float32(b1), sb.float32(b2)), (1.0, sb.float32(biquad.a[1]), sb.float32(biquad.a[2]))
    )


class ByteLink(Protocol):
    """What the adapter needs of a line: pyserial's ``Serial`` (any URL), a :class:`~hilident.links.PipeEnd`, ...

    ``timeout``, ``write_timeout``, ``is_open`` and ``flush`` are used when the
    line has them.
    """

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def close(self) -> None: ...


def _no_nagle(link: ByteLink) -> None:
    """Send small frames at once on a TCP line (``socket://``, a serial-to-Ethernet converter).

    pyserial leaves Nagle's algorithm on; with the peer's delayed ACKs it holds
    back the small excitation and PING frames for tens of milliseconds, long
    enough for the board's buffer to run dry at high sample rates.
    """
    sock = getattr(link, "_socket", None)  # pyserial's socket:// and rfc2217:// keep their socket here
    if sock is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass


def _bytes_waiting(link: ByteLink) -> int:
    """Bytes ready to read without waiting.

    pyserial's ``socket://`` reports ``in_waiting`` as 0 or 1 (readable or
    not), which would make the host read a TCP line one byte per call and fall
    behind the board; the socket itself knows the real count (FIONREAD).
    """
    sock = getattr(link, "_socket", None)
    if sock is not None:
        try:
            return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]
        except (OSError, ValueError, NameError):
            pass
    return link.in_waiting


class SerialBoardAdapter(AdapterBase):
    """A board speaking the hilident serial protocol.

    Parameters
    ----------
    link : serial.Serial or compatible
        An open byte link (``read``, ``write``, ``in_waiting``, ``close``).
    driver : DriverDescription
        What the board is expected to be.
    port : str
        Port name used in error messages.
    timeout_s : float
        Longest wait for an answer or for sample data.
    allow_fault_reset : bool
        Clear a fault the board latched before this session (CLEAR_FAULT) when
        connecting; without it such a board is refused.

    Attributes
    ----------
    connect_report : ConnectReport
        What :meth:`connect` found and did.
    found_state : str
        The board's state when this host connected (``"RUNNING"`` after a
        killed session), or ``""`` before :meth:`connect`.
    """

    transport = "serial"

    def __init__(
        self,
        link: ByteLink,
        driver: DriverDescription,
        port: str,
        timeout_s: float = 2.0,
        allow_fault_reset: bool = False,
    ):
        self.link = link
        self.driver = driver
        self.port = port
        self.timeout_s = timeout_s
        self.allow_fault_reset = allow_fault_reset
        self.connect_report = ConnectReport(device_net=WATCHDOG_NET)
        self.found_state = ""
        self._connecting = False
        self.decoder = FrameDecoder()
        self.identity: sb.Identity | None = None
        self.channels: tuple[sb.ChannelSelection, ...] = ()
        self.channel_names: list[str] = []
        self.channel_units: list[str] = []
        self.sample_rate_hz = 0.0
        # A fresh random start: an answer a killed host's request left on the line never matches ours.
        self._seq = secrets.randbelow(0x10000)
        # The board may hold the remains of a frame an earlier host was cut off in: a 0x00 before our first
        # frame ends them there, or they would swallow it (PROTOCOL.md section 2).
        self._line_opened = True
        self._rx_seq: int | None = None
        self._missing_seqs: set[int] = set()
        self.lost_frames = 0
        self.events: list[dict] = []
        self.last_result: RunResult | None = None
        self._run_counts = (0, 0)  # the decoder's corrupt frames and the lost frames when the run started
        self._backlog: list = []  # messages that arrived while waiting for an answer
        if hasattr(link, "timeout"):
            link.timeout = _READ_TIMEOUT_S  # short reads: the adapter polls and keeps the line busy
        if hasattr(link, "write_timeout"):
            link.write_timeout = timeout_s  # a line that takes no bytes is an error, never a hang (STOP included)

    # --- opening --------------------------------------------------------------------

    @classmethod
    def open_device(
        cls, device: DeviceConfig, driver: DriverDescription, link: ByteLink | None = None
    ) -> SerialBoardAdapter:
        """Connect as ``[device]`` says, or over an already open ``link``, and bring the board to a known state.

        See :meth:`connect`; ``device.allow_fault_reset`` decides whether a latched fault is cleared.
        """
        if link is None:
            return cls.open(
                device.port, driver, device.baudrate, device.timeout_s, allow_fault_reset=device.allow_fault_reset
            )
        return cls._connected(
            cls(link, driver, device.port, device.timeout_s, allow_fault_reset=device.allow_fault_reset)
        )

    @classmethod
    def open(
        cls,
        port: str,
        driver: DriverDescription,
        baudrate: int = 0,
        timeout_s: float = 2.0,
        allow_fault_reset: bool = False,
    ):
        """Open ``port`` (device path, ``COMx`` or pyserial URL) and connect (:meth:`connect`)."""
        log.debug("opening %s at %d baud", port, baudrate or driver.default_baudrate)
        try:
            link = serial.serial_for_url(port, baudrate=baudrate or driver.default_baudrate, timeout=_READ_TIMEOUT_S)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise open_failure(port, exc) from None
        _no_nagle(link)
        return cls._connected(cls(link, driver, port, timeout_s, allow_fault_reset=allow_fault_reset))

    @classmethod
    def _connected(cls, adapter: SerialBoardAdapter) -> SerialBoardAdapter:
        """``adapter`` after a successful :meth:`connect`; the line is closed again when that fails."""
        return cls._or_closed(adapter, adapter.connect)

    def connect(self) -> ConnectReport:
        """Identify the board and bring it to a known state, whatever the last session left.

        Frames that are not the answer waited for (sample blocks and events of
        a run a killed host left going, stale answers) are decoded or not,
        and counted in ``connect_report.discarded_frames``; never used. Then
        STATUS_REQUEST and STOP (zero torque) go out together: the board's
        state before the STOP is :attr:`found_state`. A board in FAULT is
        reported in ``connect_report.faults`` and cleared with CLEAR_FAULT only
        when ``allow_fault_reset`` is true.

        Raises
        ------
        DeviceError
            The board does not answer or does not match the driver, or it has
            a latched fault and ``allow_fault_reset`` is false (the message names
            the port, the fault and how to clear it).
        """
        report = self.connect_report
        corrupt_before = self.decoder.stats.corrupt
        self._connecting = True
        try:
            self.identify()
            found = self._stop_reporting_state()
            self.found_state = report.found_state = found.state.name
            status = self.status()
            if status.state == sb.State.FAULT:

                def clear() -> None:
                    self.clear_fault()
                    if self.status().state == sb.State.FAULT:
                        raise DeviceError(
                            f"{self.port}: the board stays in FAULT {status.fault.name} after CLEAR_FAULT"
                        )

                meaning = _FAULT_MEANING.get(status.fault, "unknown fault")
                self._clear_latched_fault(
                    f"board in FAULT {status.fault.name} ({meaning})", self.allow_fault_reset, clear
                )
        finally:
            self._connecting = False
            report.discarded_frames += self.decoder.stats.corrupt - corrupt_before
        return report

    def _stop_reporting_state(self) -> sb.Status:
        """Send STATUS_REQUEST and STOP back to back; the board's status from just before the STOP.

        The board answers in order, so the last STATUS before the STOP's ACK
        is the answer to this request, whatever stale STATUS frames came first.
        """
        self._send(sb.StatusRequest())
        seq = self._send(sb.Stop())
        started = time.monotonic()
        deadline = started + self.timeout_s
        found = None
        while time.monotonic() < deadline:
            bytes_before = self.decoder.stats.bytes_in
            replies = self._read_messages(0.05)
            deadline = self._drain_deadline(started, deadline, self.decoder.stats.bytes_in > bytes_before)
            for reply in replies:
                if isinstance(reply, sb.Ack) and (reply.acked_seq, reply.acked_type) == (seq, sb.MsgType.STOP):
                    if found is None:
                        raise DeviceError(f"{self.port}: the board acknowledged STOP but sent no STATUS")
                    self.connect_report.discarded_frames -= 1  # ``found`` was counted with the stale frames
                    return found
                if isinstance(reply, sb.Status):
                    found = reply
                self.connect_report.discarded_frames += 1
        raise DeviceError(f"{self.port}: no answer to Stop within {self.timeout_s:g} s")

    def _release(self) -> None:
        self.link.close()

    # --- low-level exchange ---------------------------------------------------------------

    def _send(self, msg) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        exc = (sb.Format.F32, 1.0)
        lead, self._line_opened = (b"\x00" if self._line_opened else b""), False
        try:
            self.link.write(lead + encode_frame(sb.encode(msg, self._seq, excitation=exc)))
        except (serial.SerialException, OSError, LinkClosed) as e:
            raise DeviceError(f"{self.port}: write failed: {e}") from None
        return self._seq

    def _read_messages(self, timeout: float) -> list:
        """Messages kept from earlier reads, else those arriving within ``timeout`` seconds."""
        if self._backlog:
            messages, self._backlog = self._backlog, []
            return messages
        deadline = time.monotonic() + timeout
        while True:
            try:
                data = self.link.read(max(1, _bytes_waiting(self.link)))
            except (serial.SerialException, OSError, LinkClosed) as e:
                raise DeviceError(f"{self.port}: line lost: {e}") from None
            messages = []
            for payload in self.decoder.feed(data):
                msg = self._decode(payload)
                if msg is not None:
                    messages.append(msg)
            if messages or time.monotonic() >= deadline:
                return messages

    def _drain_deadline(self, started: float, deadline: float, traffic: bool) -> float:
        """While connecting, a board still sending an earlier run's frames gets more time to answer.

        Its answer queues behind those frames, which may take longer than
        ``timeout_s`` to drain on a slow line; at most ``_DRAIN_TIMEOUTS`` times
        ``timeout_s`` in all.
        """
        if not (self._connecting and traffic):
            return deadline
        return min(max(deadline, time.monotonic() + self.timeout_s), started + _DRAIN_TIMEOUTS * self.timeout_s)

    def _decode(self, payload: bytes):
        """The message in ``payload``, or None when it is counted and dropped.

        Sample blocks that arrive before this host chose its channels belong
        to an earlier session (a run a killed host left going): they cannot
        even be decoded, so they are counted as discarded, never a crash.
        """
        if not self.channels and len(payload) > 1 and payload[1] == sb.MsgType.SAMPLES:
            self.connect_report.discarded_frames += 1
            return None
        try:
            header, msg = sb.decode(payload, sample_channels=self.channels)
        except ProtocolError as e:
            if self._connecting:
                self.connect_report.discarded_frames += 1
            else:
                self.log_event(RunEvent(Kind.PROTOCOL_ERROR, str(e), -1))
            return None
        self._track_seq(header.seq)
        return msg

    def _track_seq(self, seq: int) -> None:
        """Count frames missing from the board's numbering; a late one is taken back, not counted twice."""
        if self._rx_seq is None:
            self._rx_seq = seq
            return
        ahead = (seq - self._rx_seq) & 0xFFFF
        if 0 < ahead < 0x8000:
            gap = ahead - 1
            self.lost_frames += gap
            if len(self._missing_seqs) + gap > _MAX_TRACKED_GAPS:
                self._missing_seqs.clear()
            if gap <= _MAX_TRACKED_GAPS:
                self._missing_seqs.update((self._rx_seq + k) & 0xFFFF for k in range(1, gap + 1))
            self._rx_seq = seq
        elif seq in self._missing_seqs:  # arrived after a later frame: reordered, not lost
            self._missing_seqs.discard(seq)
            self.lost_frames -= 1

    def _request(self, msg, answer_type=None):
        """Send ``msg`` and wait for its ACK (or ``answer_type``); NAK raises DeviceError."""
        seq = self._send(msg)
        kind = sb.encode(msg, 0)[1]
        started = time.monotonic()
        deadline = started + self.timeout_s
        keep = []  # data and events that arrive while waiting are kept for the stream
        answer = refusal = None
        try:
            while answer is None and refusal is None and time.monotonic() < deadline:
                bytes_before = self.decoder.stats.bytes_in
                replies = self._read_messages(0.05)
                deadline = self._drain_deadline(started, deadline, self.decoder.stats.bytes_in > bytes_before)
                for reply in replies:
                    if answer is None and refusal is None:
                        if isinstance(reply, sb.Nak) and (reply.acked_seq, reply.acked_type) == (seq, kind):
                            refusal = reply
                            continue
                        if (
                            answer_type is None
                            and isinstance(reply, sb.Ack)
                            and (reply.acked_seq, reply.acked_type) == (seq, kind)
                        ) or (answer_type is not None and isinstance(reply, answer_type)):
                            answer = reply
                            continue
                    if self._connecting:
                        self.connect_report.discarded_frames += 1  # left over from an earlier session
                    elif isinstance(reply, (sb.Samples, sb.Event)):
                        keep.append(reply)
        finally:
            self._backlog = keep + self._backlog
        if refusal is not None:
            raise BoardRefusal(
                f"{self.port}: board refused {sb.MsgType(kind).name}: {refusal.error.name} ({refusal.detail})",
                refusal,
            )
        if answer is not None:
            return answer
        raise DeviceError(
            f"{self.port}: no answer to {type(msg).__name__} within {self.timeout_s:g} s "
            "(is the board powered, and the baud rate right?)"
        )

    def _note_event(self, ev: sb.Event) -> dict:
        return self.log_event(RunEvent(Kind(ev.code.name.lower()), ev.message, ev.sample_index, value=ev.value))

    # --- device operations ------------------------------------------------------------------

    def identify(self) -> sb.Identity:
        """Ask the board who it is and check it matches the driver description.

        Stale input is read and dropped frame by frame (see :meth:`connect`),
        not flushed unseen, so what a previous session left is counted.
        """
        ident = self._request(sb.Identify(), sb.Identity)
        if ident.protocol_version != self.driver.protocol_version:
            raise DeviceError(
                f"{self.port}: board speaks protocol {ident.protocol_version}, "
                f"driver {self.driver.name!r} expects {self.driver.protocol_version}"
            )
        offered = [c.name for c in ident.channels]
        missing = [c.name for c in self.driver.channels if c.name not in offered]
        if missing:
            raise DeviceError(
                f"{self.port}: board {ident.name!r} lacks channels {missing} of driver {self.driver.name!r}"
            )
        self.identity = ident
        return ident

    def _known_identity(self) -> sb.Identity:
        """What :meth:`identify` read; DeviceError when the board was not identified (never connected)."""
        if self.identity is None:
            raise DeviceError(f"{self.port}: the board has not been identified (connect to it first)")
        return self.identity

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose rate, excitation mode and streamed channels; returns the channel names."""
        ident = self._known_identity()
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the board's loop rate "
                f"{ident.loop_rate_hz:g} Hz"
            )
        specs = (
            self.driver.streamed_channels
            if not channels
            else [self.driver.channels[self.driver.channel_index(n)] for n in channels]
        )
        offered = [c.name for c in ident.channels]
        selection = tuple(sb.ChannelSelection(offered.index(c.name), _FORMATS[c.format], c.scale) for c in specs)
        # block_samples is given per 1 kHz; slower rates keep at least 32 samples per frame
        block = max(32, int(round(self.driver.block_samples * sample_rate_hz / 1000.0)))
        self._request(sb.Configure(int(round(divider)), _MODES[mode], min(block, 4096), selection))
        self.channels = selection
        self.channel_names = [c.name for c in specs]
        self.channel_units = units_in_mode(self.channel_names, [c.unit for c in specs], mode)
        self.sample_rate_hz = ident.loop_rate_hz / round(divider)
        return self.channel_names

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the safety limits the board enforces on its own."""
        self._request(sb.Limits(torque_nm, velocity_mps, position_min_m, position_max_m))

    def status(self) -> sb.Status:
        """Board state and counters."""
        return self._request(sb.StatusRequest(), sb.Status)

    def clear_fault(self) -> None:
        """Send CLEAR_FAULT (the board leaves FAULT; it does not re-enable the drive)."""
        self._request(sb.ClearFault())

    def _command_safe(self) -> None:
        """Send STOP (zero torque) now, without waiting for its ACK (:meth:`safe_stop` never raises).

        A 0x00 goes first: if an exception (a signal) cut the previous frame
        short, its remains end there as one corrupt frame at the board instead
        of swallowing the STOP (PROTOCOL.md section 2).
        """
        if not getattr(self.link, "is_open", True):
            return
        self._seq = (self._seq + 1) & 0xFFFF
        self.link.write(b"\x00" + encode_frame(sb.encode(sb.Stop(), self._seq)))
        flush = getattr(self.link, "flush", None)
        if flush is not None:
            flush()

    def stop(self) -> None:
        """Send STOP now (as :meth:`safe_stop`)."""
        self.safe_stop()

    def _write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None, enabled: bool) -> None:
        """Store a biquad in a filter slot (the board takes coefficients; ``spec`` is not used)."""
        self._request(sb.WriteFilter(sb.FilterCoefficients(slot, enabled, biquad.b, biquad.a)))

    def _read_raw_slot(self, slot: int) -> tuple[Biquad, bool]:
        """The slot's present contents (the board stores what it is sent, REAL32)."""
        return self.read_filter(slot)

    def _write_raw_slot(self, slot: int, saved: tuple[Biquad, bool]) -> None:
        biquad, enabled = saved
        self.write_filter(slot, biquad, enabled=enabled)

    def _read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """Read a filter slot back (coefficients as the board stores them, REAL32)."""
        seq = self._send(sb.ReadFilter(slot))
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            for reply in self._read_messages(0.05):
                if isinstance(reply, sb.FilterCoefficients) and reply.slot == slot:
                    return Biquad(reply.b, reply.a), reply.enabled
                # a NAK of a frame sent before (an ended run's in-flight EXCITATION) is not this answer
                if isinstance(reply, sb.Nak) and (reply.acked_seq, reply.acked_type) == (seq, sb.MsgType.READ_FILTER):
                    raise DeviceError(f"{self.port}: filter slot {slot}: {reply.error.name} ({reply.detail})")
        raise DeviceError(f"{self.port}: no answer reading filter slot {slot}")

    def _stored_form(self, biquad: Biquad, spec: NotchSpec | None) -> Biquad:
        """The coefficients as this board stores them (REAL32), for read-back comparison (``spec`` is not used)."""
        return board_stored_form(biquad)

    # --- the loop (PROTOCOL.md sections 4.15, 4.16) ----------------------------------------------

    def _loop_description(self):
        return serial_loop(self.driver)

    def _read_loop(self) -> dict[str, float] | None:
        """The cascade's six parameters, SI units: LOOP's, a fixed value of ``[loop]`` replacing the board's.
        None when the driver has no ``[loop]`` or the board has no READ_LOOP (NAK UNKNOWN_TYPE: older firmware).
        """
        loop = serial_loop(self.driver)
        if loop is None:
            return None
        board = self._board_loop() if loop.held else {}
        return None if board is None else board_loop.described_values(loop, board)

    def _board_loop(self) -> dict[str, float] | None:
        """LOOP's six values; None when the board refuses READ_LOOP as an unknown type (it has no loop messages)."""
        try:
            return self._request(sb.ReadLoop(), sb.LoopParameters).values()
        except BoardRefusal as exc:
            if exc.nak.error != sb.ErrorCode.UNKNOWN_TYPE:
                raise
            log.info("%s: the board has no READ_LOOP (%s): its loop is not known", self.port, exc.nak.detail)
            return None

    def _write_loop(self, values: dict[str, float]) -> None:
        """WRITE_LOOP with ``values`` (binary32) and the other gains as the board reports them.

        Raises
        ------
        DeviceError
            The board refused WRITE_LOOP (the message names the port, WRITE_LOOP and the NAK's code) or has no
            loop messages.
        UsageError
            ``[loop]`` does not keep a parameter of ``values`` in the LOOP message.
        """
        gains = self._stored_loop(values)
        present = self._board_loop()
        if present is None:
            raise DeviceError(f"{self.port}: the board has no loop messages (READ_LOOP: NAK UNKNOWN_TYPE)")
        self._request(board_loop.write_message(present, gains))

    def _stored_loop(self, values: dict[str, float]) -> dict[str, float]:
        """``values`` as the board stores them (binary32); UsageError for one ``[loop]`` does not keep in LOOP."""
        loop = serial_loop(self.driver)
        for name in values:
            board_loop.held_in_loop(loop, name, self.port)
        return board_loop.stored_gains(values, self.port)

    # --- streaming ----------------------------------------------------------------------------

    def _play(self, x: np.ndarray, deliver: Deliver, result: RunResult) -> None:
        """Play ``x`` (one value per sample) with flow control and hand every received block to ``deliver``.

        Missing blocks are counted, never filled; a block that arrives after a
        later one is discarded and counted as out of order, not as lost.

        The first cause wins: after the board reported a limit trip, a frame it
        refuses is no error of its own; after a run the board finished, a
        refused in-flight frame is no error at all.

        Raises
        ------
        DeviceError
            The line was lost, the board went silent, or refused a frame while
            it was running the host's run.
        """
        self._missing_seqs.clear()
        self._backlog = []  # blocks and events kept from before this run belong to an earlier one
        self._run_counts = (self.decoder.stats.corrupt, self.lost_frames)
        run = _Run(self, x, deliver, result)
        run.run()
        self._finish_run(run)

    def _end_run(self, result: RunResult) -> None:
        """STOP unless the board finished the run; the line's counters of the run."""
        if not result.completed:
            self.safe_stop()
        corrupt_before, lost_before = self._run_counts
        result.stats.corrupt_frames = self.decoder.stats.corrupt - corrupt_before
        result.stats.lost_frames = self.lost_frames - lost_before

    def _finish_run(self, run: _Run) -> None:
        """Take late events and the board's own counters, and count what never arrived.

        A board found in FAULT after a run whose fault event was lost on the
        line still ends the run with that fault (a limit trip stays a trip).
        """
        result, stats, n = run.result, run.result.stats, run.n
        try:
            for msg in self._read_messages(0.02):  # late events (FINISHED after the last block)
                if isinstance(msg, sb.Event):
                    run.take(msg, time.monotonic())
            status = self.status()
        except DeviceError:
            if self.run_fault is None:
                raise
            return  # the fault the board reported is the cause; the line failing after it is not
        end = max(run.expected_sample, 0)
        if self.run_fault is None and status.state == sb.State.FAULT:
            kind = Kind.LIMIT_TRIP if status.fault in _LIMIT_FAULTS else Kind.FAULT
            self.note_fault(
                RunEvent(
                    kind, f"board in FAULT {status.fault.name} after the run (its event was lost on the line)", end
                ).to_dict()
            )  # the run's cause; no event was logged
        if self.run_fault is None and end < n:
            stats.lost_samples += n - end
            self.log_event(
                RunEvent(Kind.LOST_BLOCKS, f"end of run lost on the line: samples {end}..{n - 1}", end, value=0.0)
            )
        stats.underruns = status.underruns
        stats.board_dropped_blocks = status.dropped_blocks
        result.completed = self.run_fault is None


class _Run(RunStrategy[SerialBoardAdapter]):
    """Bookkeeping of one run on the board: what was sent, received, lost and refused."""

    def __init__(self, adapter: SerialBoardAdapter, x: np.ndarray, deliver: Deliver, result: RunResult):
        super().__init__(adapter, x, deliver, result)
        capacity = adapter._known_identity().excitation_buffer_samples
        self.window = max(_EXCITATION_CHUNK, capacity - _EXCITATION_CHUNK)
        self.sent = self.consumed = 0
        self.expected_block: int | None = None
        self.expected_sample = 0
        self.lost: dict[int, None] = {}  # block indices counted as lost (a late one is taken back)
        self.done = False
        self.end_seen: float | None = None  # when the board announced the end of the run
        self.refusal: sb.Nak | None = None  # a NAK waiting for the board's reason
        self.refused_at = 0.0

    def send_excitation(self) -> int:
        """Top the board's buffer up within the window; the number of values sent."""
        if self.refusal is not None:
            return 0  # the board left the run or lost the stream's index: sending more cannot help
        count = 0
        while self.sent + count < self.n and self.sent + count - self.consumed + _EXCITATION_CHUNK <= self.window:
            chunk = self.x[self.sent + count : self.sent + count + _EXCITATION_CHUNK]
            self.ad._send(sb.Excitation(self.sent + count, chunk))
            count += len(chunk)
        self.sent += count
        return count

    def run(self) -> None:
        """Pre-fill, START, then top up, keep the line alive and take blocks until the run ends."""
        ad = self.ad
        self.send_excitation()  # pre-fill the board's buffer so the run starts without underruns
        ad._request(sb.Start(self.n))
        last_data = last_tx = time.monotonic()
        while not self.done:
            if self.send_excitation():
                last_tx = time.monotonic()
            elif time.monotonic() - last_tx > _KEEPALIVE_S:
                ad._send(sb.Ping())  # the board's watchdog stops the axis if the host goes silent
                last_tx = time.monotonic()
            messages = ad._read_messages(0.01)
            now = time.monotonic()
            if any(isinstance(m, (sb.Samples, sb.Event)) for m in messages):
                last_data = now
            elif now - last_data > ad.timeout_s:
                raise DeviceError(f"{ad.port}: no data from the board for {ad.timeout_s:g} s")
            if self.end_seen is not None and now - self.end_seen > _END_GRACE_S:
                break  # the run's last block was lost on the line
            for msg in messages:
                self.take(msg, now)
            if (
                self.refusal is not None
                and self.end_seen is None
                and not self.done
                and now - self.refused_at > _END_GRACE_S
            ):
                nak = self.refusal
                raise DeviceError(f"{ad.port}: board refused a frame during the run: {nak.error.name} ({nak.detail})")

    def take(self, msg, now: float) -> None:
        if isinstance(msg, sb.Samples):
            self.take_block(msg)
        elif isinstance(msg, sb.Event):
            entry = self.ad._note_event(msg)
            if msg.code in (sb.EventCode.LIMIT_TRIP, sb.EventCode.WATCHDOG, sb.EventCode.FAULT):
                self.ad.note_fault(entry)  # the first cause wins
            if msg.code in _END_EVENTS and self.end_seen is None:
                self.end_seen = now
        elif isinstance(msg, sb.Nak):
            self.take_refusal(msg, now)

    def take_refusal(self, nak: sb.Nak, now: float) -> None:
        """A NAK is an error only while the board is still running this run.

        A board that tripped, finished or was stopped refuses frames that were
        already on their way (BAD_STATE, or a stream index it has reset): that
        is the consequence of the end it announced, which wins. Its
        announcement may still be on the line, so a refusal waits for it.
        """
        try:
            what = sb.MsgType(nak.acked_type).name
        except ValueError:
            what = f"type 0x{nak.acked_type:02x}"
        self.ad.log_event(
            RunEvent(
                Kind.REFUSED,
                f"board refused a frame ({what}): {nak.error.name} ({nak.detail})",
                self.expected_sample,
                value=float(nak.error),
            )
        )
        if self.done or self.end_seen is not None or self.refusal is not None:
            return
        self.refusal, self.refused_at = nak, now

    def take_block(self, msg: sb.Samples) -> None:
        stats, ad = self.result.stats, self.ad
        if self.expected_block is not None and msg.block_index < self.expected_block:
            self.take_late_block(msg)
            return
        if self.expected_block is not None and msg.block_index > self.expected_block:
            gap = msg.block_index - self.expected_block
            stats.lost_blocks += gap
            stats.lost_samples += msg.first_sample - self.expected_sample
            if gap <= _MAX_TRACKED_GAPS:
                self.lost.update(dict.fromkeys(range(self.expected_block, msg.block_index)))
            ad.log_event(
                RunEvent(
                    Kind.LOST_BLOCKS,
                    f"{gap} sample block(s) lost: samples {self.expected_sample}..{msg.first_sample - 1}",
                    self.expected_sample,
                    value=float(gap),
                )
            )
        self.expected_block = msg.block_index + 1
        self.expected_sample = msg.first_sample + len(msg.data)
        self.consumed = max(self.consumed, msg.excitation_consumed)
        stats.underruns = msg.underruns
        if msg.flags & sb.FLAG_CLIPPED:
            stats.clipped_blocks += 1
        if len(msg.data):
            self.deliver(msg.first_sample + np.arange(len(msg.data)), msg.data)
            stats.samples += len(msg.data)
        if msg.flags & sb.FLAG_LAST:
            self.done = True

    def take_late_block(self, msg: sb.Samples) -> None:
        """A block older than one already taken: out of order, discarded, never spliced in.

        When it had been counted as lost, it is taken back out of the lost
        counts: the line reordered it, it did not lose it. Its samples stay
        missing from the recording, and the event log says so.
        """
        stats = self.result.stats
        stats.out_of_order += 1
        rows = len(msg.data)
        span = f"samples {msg.first_sample}..{msg.first_sample + rows - 1}" if rows else "no samples"
        if msg.block_index in self.lost:
            del self.lost[msg.block_index]
            stats.lost_blocks -= 1
            stats.lost_samples -= rows
        self.ad.log_event(
            RunEvent(
                Kind.OUT_OF_ORDER,
                f"sample block {msg.block_index} arrived after a later one and was discarded: "
                f"{span} are missing from the recording",
                msg.first_sample,
                value=float(rows),
            )
        )
