"""Host side of the serial board protocol, over pyserial.

Opens a device path (``/dev/ttyUSB0``), a Windows port (``COM3``) or any
pyserial URL (``socket://host:port``, ``rfc2217://host:port``), streams the
excitation with flow control, receives sample blocks, counts every lost,
corrupt or out-of-order frame, and stops the axis (zero torque) on every exit
path: normal end, error, limit trip, Ctrl-C.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import serial

from hilident.adapters.base import AdapterBase, RunResult, StreamStats
from hilident.config import DeviceConfig
from hilident.drivers import DriverDescription
from hilident.errors import DeviceError, LimitTrip, ProtocolError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec
from hilident.links import LinkClosed
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame

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
    """

    transport = "serial"

    def __init__(self, link, driver: DriverDescription, port: str, timeout_s: float = 2.0):
        self.link = link
        self.driver = driver
        self.port = port
        self.timeout_s = timeout_s
        self.decoder = FrameDecoder()
        self.identity: sb.Identity | None = None
        self.channels: tuple[sb.ChannelSelection, ...] = ()
        self.channel_names: list[str] = []
        self.channel_units: list[str] = []
        self.sample_rate_hz = 0.0
        self._seq = 0
        self._rx_seq: int | None = None
        self.lost_frames = 0
        self.events: list[dict] = []
        self.last_result: RunResult | None = None
        self._backlog: list = []  # messages that arrived while waiting for an answer
        if hasattr(link, "timeout"):
            link.timeout = _READ_TIMEOUT_S  # short reads: the adapter polls and keeps the line busy

    # --- opening --------------------------------------------------------------------

    @classmethod
    def open_device(cls, device: DeviceConfig, driver: DriverDescription, link=None) -> "SerialBoardAdapter":
        """Connect as ``[device]`` says, or over an already open ``link``; identifies the board."""
        if link is None:
            return cls.open(device.port, driver, device.baudrate, device.timeout_s)
        return cls._identified(cls(link, driver, device.port, device.timeout_s))

    @classmethod
    def open(cls, port: str, driver: DriverDescription, baudrate: int = 0, timeout_s: float = 2.0):
        """Open ``port`` (device path, ``COMx`` or pyserial URL) and identify the board."""
        try:
            link = serial.serial_for_url(port, baudrate=baudrate or driver.default_baudrate, timeout=_READ_TIMEOUT_S)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise DeviceError(f"{port}: cannot open: {exc}") from None
        return cls._identified(cls(link, driver, port, timeout_s))

    def close(self) -> None:
        """Stop the axis and close the line."""
        try:
            self.stop()
        finally:
            try:
                self.link.close()
            except Exception:
                pass

    # --- low-level exchange ---------------------------------------------------------------

    def _send(self, msg) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        exc = (sb.Format.F32, 1.0)
        try:
            self.link.write(encode_frame(sb.encode(msg, self._seq, excitation=exc)))
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
                data = self.link.read(max(1, self.link.in_waiting))
            except (serial.SerialException, OSError, LinkClosed) as e:
                raise DeviceError(f"{self.port}: line lost: {e}") from None
            messages = []
            for payload in self.decoder.feed(data):
                try:
                    header, msg = sb.decode(payload, sample_channels=self.channels)
                except ProtocolError as e:
                    self.events.append({"kind": "protocol_error", "message": str(e), "sample_index": -1})
                    continue
                self._track_seq(header.seq)
                messages.append(msg)
            if messages or time.monotonic() >= deadline:
                return messages

    def _track_seq(self, seq: int) -> None:
        if self._rx_seq is not None:
            gap = (seq - self._rx_seq - 1) & 0xFFFF
            if gap < 0x8000:
                self.lost_frames += gap
        self._rx_seq = seq

    def _request(self, msg, answer_type=None):
        """Send ``msg`` and wait for its ACK (or ``answer_type``); NAK raises DeviceError."""
        seq = self._send(msg)
        deadline = time.monotonic() + self.timeout_s
        keep = []  # data and events that arrive while waiting are kept for the stream
        answer = refusal = None
        try:
            while answer is None and refusal is None and time.monotonic() < deadline:
                for reply in self._read_messages(0.05):
                    if answer is None and refusal is None:
                        if isinstance(reply, sb.Nak) and reply.acked_seq == seq:
                            refusal = reply
                            continue
                        if (answer_type is None and isinstance(reply, sb.Ack) and reply.acked_seq == seq) or (
                            answer_type is not None and isinstance(reply, answer_type)
                        ):
                            answer = reply
                            continue
                    if isinstance(reply, (sb.Samples, sb.Event)):
                        keep.append(reply)
        finally:
            self._backlog = keep + self._backlog
        if refusal is not None:
            raise DeviceError(
                f"{self.port}: board refused {type(msg).__name__}: {refusal.error.name} ({refusal.detail})"
            )
        if answer is not None:
            return answer
        raise DeviceError(
            f"{self.port}: no answer to {type(msg).__name__} within {self.timeout_s:g} s "
            "(is the board powered, and the baud rate right?)"
        )

    def _note_event(self, ev: sb.Event) -> dict:
        entry = {"kind": ev.code.name.lower(), "message": ev.message, "sample_index": ev.sample_index, "value": ev.value}
        self.events.append(entry)
        return entry

    # --- device operations ------------------------------------------------------------------

    def identify(self) -> sb.Identity:
        """Ask the board who it is and check it matches the driver description."""
        try:
            self.link.reset_input_buffer()
        except Exception:
            pass
        ident = self._request(sb.Identify(), sb.Identity)
        if ident.protocol_version != self.driver.protocol_version:
            raise DeviceError(
                f"{self.port}: board speaks protocol {ident.protocol_version}, "
                f"driver {self.driver.name!r} expects {self.driver.protocol_version}"
            )
        offered = [c.name for c in ident.channels]
        missing = [c.name for c in self.driver.channels if c.name not in offered]
        if missing:
            raise DeviceError(f"{self.port}: board {ident.name!r} lacks channels {missing} of driver {self.driver.name!r}")
        self.identity = ident
        return ident

    def configure(self, sample_rate_hz: float, mode: str, channels: list[str] | None = None) -> list[str]:
        """Choose rate, excitation mode and streamed channels; returns the channel names."""
        ident = self.identity
        divider = ident.loop_rate_hz / sample_rate_hz
        if abs(divider - round(divider)) > 1e-9 or round(divider) < 1:
            raise DeviceError(
                f"{self.port}: sample rate {sample_rate_hz:g} Hz does not divide the board's loop rate "
                f"{ident.loop_rate_hz:g} Hz"
            )
        specs = self.driver.streamed_channels if not channels else [
            self.driver.channels[self.driver.channel_index(n)] for n in channels
        ]
        offered = [c.name for c in ident.channels]
        selection = tuple(
            sb.ChannelSelection(offered.index(c.name), _FORMATS[c.format], c.scale) for c in specs
        )
        # block_samples is given per 1 kHz; slower rates keep at least 32 samples per frame
        block = max(32, int(round(self.driver.block_samples * sample_rate_hz / 1000.0)))
        self._request(sb.Configure(int(round(divider)), _MODES[mode], min(block, 4096), selection))
        self.channels = selection
        self.channel_names = [c.name for c in specs]
        self.channel_units = [c.unit for c in specs]
        self.sample_rate_hz = ident.loop_rate_hz / round(divider)
        return self.channel_names

    def set_limits(self, torque_nm: float, velocity_mps: float, position_min_m: float, position_max_m: float) -> None:
        """Load the safety limits the board enforces on its own."""
        self._request(sb.Limits(torque_nm, velocity_mps, position_min_m, position_max_m))

    def status(self) -> sb.Status:
        """Board state and counters."""
        return self._request(sb.StatusRequest(), sb.Status)

    def clear_fault(self) -> None:
        self._request(sb.ClearFault())

    def stop(self) -> None:
        """Send STOP (zero torque). Never raises: it runs on every exit path."""
        try:
            if getattr(self.link, "is_open", True):
                self._send(sb.Stop())
        except Exception:
            pass

    def write_filter(self, slot: int, biquad: Biquad, spec: NotchSpec | None = None, *, enabled: bool) -> None:
        """Store a biquad in a filter slot (the board takes coefficients; ``spec`` is not used)."""
        self._request(sb.WriteFilter(sb.FilterCoefficients(slot, enabled, biquad.b, biquad.a)))

    def save_filter(self, slot: int) -> tuple[Biquad, bool]:
        """The slot's present contents, for :meth:`restore_filter`."""
        return self.read_filter(slot)

    def restore_filter(self, slot: int, saved: tuple[Biquad, bool]) -> None:
        """Put back what :meth:`save_filter` returned."""
        biquad, enabled = saved
        self.write_filter(slot, biquad, enabled=enabled)

    def read_filter(self, slot: int) -> tuple[Biquad, bool]:
        """Read a filter slot back (coefficients as the board stores them, REAL32)."""
        self._send(sb.ReadFilter(slot))
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            for reply in self._read_messages(0.05):
                if isinstance(reply, sb.FilterCoefficients) and reply.slot == slot:
                    return Biquad(reply.b, reply.a), reply.enabled
                if isinstance(reply, sb.Nak):
                    raise DeviceError(f"{self.port}: filter slot {slot}: {reply.error.name} ({reply.detail})")
        raise DeviceError(f"{self.port}: no answer reading filter slot {slot}")

    @staticmethod
    def stored_form(biquad: Biquad, spec: NotchSpec | None = None) -> Biquad:
        """The coefficients as this board stores them (REAL32), for read-back comparison."""
        return Biquad(tuple(sb.float32(x) for x in biquad.b), (1.0, sb.float32(biquad.a[1]), sb.float32(biquad.a[2])))

    # --- streaming ----------------------------------------------------------------------------

    def stream(
        self,
        excitation: np.ndarray,
        sink: Callable[[np.ndarray, np.ndarray], None],
        progress: Callable[[float], None] | None = None,
    ) -> RunResult:
        """Play ``excitation`` (one value per sample) and hand every received block to ``sink``.

        ``sink(sample_index, rows)`` gets the absolute sample indices and an
        ``(n, n_channels)`` array. Missing blocks are counted, never filled.
        The axis is stopped on every exit path.

        Raises
        ------
        LimitTrip
            The board tripped a safety limit (the samples up to then were delivered).
        DeviceError
            The line was lost, the board went silent, or its watchdog stopped the axis.
        """
        excitation = np.asarray(excitation, dtype=float)
        n = len(excitation)
        capacity = self.identity.excitation_buffer_samples
        window = max(_EXCITATION_CHUNK, capacity - _EXCITATION_CHUNK)
        self.events = []
        stats = StreamStats()
        result = RunResult(requested_samples=n, stats=stats)
        corrupt_before = self.decoder.stats.corrupt
        lost_before = self.lost_frames
        sent = consumed = 0
        expected_block = None
        expected_sample = 0
        done = False
        end_seen = None  # when the board announced the end of the run
        fault_code = None
        def send_excitation() -> int:
            count = 0
            while sent + count < n and sent + count - consumed + _EXCITATION_CHUNK <= window:
                chunk = excitation[sent + count : sent + count + _EXCITATION_CHUNK]
                self._send(sb.Excitation(sent + count, chunk))
                count += len(chunk)
            return count

        try:
            sent += send_excitation()  # pre-fill the board's buffer so the run starts without underruns
            self._request(sb.Start(n))
            last_data = time.monotonic()
            last_tx = time.monotonic()
            while not done:
                count = send_excitation()
                sent += count
                if count:
                    last_tx = time.monotonic()
                elif time.monotonic() - last_tx > _KEEPALIVE_S:
                    self._send(sb.Ping())  # the board's watchdog stops the axis if the host goes silent
                    last_tx = time.monotonic()
                messages = self._read_messages(0.01)
                now = time.monotonic()
                if any(isinstance(m, (sb.Samples, sb.Event)) for m in messages):
                    last_data = now
                elif now - last_data > self.timeout_s:
                    raise DeviceError(f"{self.port}: no data from the board for {self.timeout_s:g} s")
                if end_seen is not None and now - end_seen > _END_GRACE_S:
                    break  # the run's last block was lost on the line
                for msg in messages:
                    if isinstance(msg, sb.Samples):
                        if expected_block is not None and msg.block_index < expected_block:
                            stats.out_of_order += 1
                            continue
                        if expected_block is not None and msg.block_index > expected_block:
                            gap = msg.block_index - expected_block
                            stats.lost_blocks += gap
                            stats.lost_samples += msg.first_sample - expected_sample
                            self.events.append({
                                "kind": "lost_blocks", "sample_index": expected_sample,
                                "message": f"{gap} sample block(s) lost: samples {expected_sample}..{msg.first_sample - 1}",
                                "value": float(gap),
                            })
                        expected_block = msg.block_index + 1
                        expected_sample = msg.first_sample + len(msg.data)
                        consumed = max(consumed, msg.excitation_consumed)
                        stats.underruns = msg.underruns
                        if msg.flags & sb.FLAG_CLIPPED:
                            stats.clipped_blocks += 1
                        if len(msg.data):
                            sink(msg.first_sample + np.arange(len(msg.data)), msg.data)
                            stats.samples += len(msg.data)
                        if progress:
                            progress(min(1.0, expected_sample / max(n, 1)))
                        if msg.flags & sb.FLAG_LAST:
                            done = True
                    elif isinstance(msg, sb.Event):
                        entry = self._note_event(msg)
                        if msg.code in (sb.EventCode.LIMIT_TRIP, sb.EventCode.WATCHDOG, sb.EventCode.FAULT):
                            result.fault = entry["message"]
                            fault_code = msg.code
                        if msg.code in _END_EVENTS and end_seen is None:
                            end_seen = now
                    elif isinstance(msg, sb.Nak):
                        raise DeviceError(f"{self.port}: board refused a frame during the run: {msg.error.name} ({msg.detail})")
            end = max(expected_sample, 0)
            if result.fault is None and end < n:
                stats.lost_samples += n - end
                self.events.append({"kind": "lost_blocks", "sample_index": end, "value": 0.0,
                                    "message": f"end of run lost on the line: samples {end}..{n - 1}"})
            # Late events (FINISHED after the last block) and the board's own counters.
            for msg in self._read_messages(0.02):
                if isinstance(msg, sb.Event):
                    self._note_event(msg)
            status = self.status()
            stats.underruns = status.underruns
            stats.board_dropped_blocks = status.dropped_blocks
            result.completed = result.fault is None
        finally:
            if not result.completed:
                self.stop()
            stats.corrupt_frames = self.decoder.stats.corrupt - corrupt_before
            stats.lost_frames = self.lost_frames - lost_before
            result.events = list(self.events)
            self.last_result = result
        if result.fault:
            error = LimitTrip if fault_code == sb.EventCode.LIMIT_TRIP else DeviceError
            raise error(f"{self.port}: {result.fault}") from None
        return result
