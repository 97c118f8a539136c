"""The emulated board on a line: a pseudo-terminal, a raw TCP line or an in-memory pipe.

:class:`BoardServer` runs :class:`~hilident.emulator.serial.firmware.BoardFirmware` in a
background thread. It steps the physics in real time (times ``time_scale``, on
:class:`~hilident.emulator.clock.SimClock`), and
writes its frames at the configured baud rate, so a host sees the same
throughput limits as on a real UART: when the host asks for more samples than
the line carries, the board's transmit buffer fills and sample blocks are
dropped (and counted), exactly as on the bench.

The pseudo-terminal is a real serial device path (``/dev/pts/N``) that pyserial
opens like a USB serial board.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import replace

from hilident.config.tables import DeviceConfig, EmulatorConfig
from hilident.drivers.description import DriverDescription
from hilident.emulator.clock import SimClock
from hilident.emulator.device import EmulatedDevice, build_drive
from hilident.emulator.serial.firmware import BoardFirmware
from hilident.emulator.serial.links import BoardLink, LineFaults, PipeLink, PtyLink, TcpLink
from hilident.errors import ConfigError
from hilident.links import LinkClosed, pipe_pair
from hilident.protocol import serial_board as sb
from hilident.protocol.framing import FrameDecoder, encode_frame

__all__ = ["BITS_PER_BYTE", "BoardServer", "identity_from_driver", "start", "start_serial_board"]

#: Bits on the line per byte: start + 8 data + stop (8N1).
BITS_PER_BYTE = 10


class BoardServer:
    """Serve :class:`BoardFirmware` on a link in a background thread.

    Parameters
    ----------
    firmware : BoardFirmware
    link : BoardLink
        A :class:`PtyLink`, :class:`TcpLink` or :class:`PipeLink`.
    baudrate : int
        Line rate; frames leave no faster than ``baudrate / 10`` bytes per second.
        0 disables pacing (fast unit tests).
    time_scale : float
        Simulated seconds per wall-clock second.
    tx_buffer_bytes : int
        Board transmit buffer. Sample blocks that do not fit are dropped.
    watchdog_s : float
        A running board stops the axis when the host is silent this long (wall time).
    faults : LineFaults, optional
    close_after_s : float
        Close the line this long (wall time) after a run starts; 0 never.
    """

    def __init__(
        self,
        firmware: BoardFirmware,
        link: BoardLink,
        baudrate: int,
        time_scale: float = 1.0,
        tx_buffer_bytes: int = 65536,
        watchdog_s: float = 1.0,
        faults: LineFaults | None = None,
        close_after_s: float = 0.0,
    ):
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ConfigError("emulator.time_scale", f"must be a finite number > 0, got {time_scale!r}")
        if not (isinstance(baudrate, int) and baudrate >= 0):
            raise ConfigError("device.baudrate", f"must be a whole number >= 0, got {baudrate!r}")
        self.firmware = firmware
        self.link = link
        self.baudrate = baudrate
        self.time_scale = time_scale
        self.tx_buffer_bytes = tx_buffer_bytes
        self._sent_seq = 0  # message numbers of the frames put on the line (PROTOCOL.md section 3)
        self.watchdog_s = watchdog_s
        self.faults = faults or LineFaults()
        self.close_after_s = close_after_s
        self.decoder = FrameDecoder()
        self._tx: deque[bytes] = deque()
        self._tx_bytes = 0
        self._tx_cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.error: BaseException | None = None
        self.bytes_sent = 0
        self._last_rx = 0.0  # wall time (s) the host was last heard
        self._run_started: float | None = None  # wall time (s) the latest run started

    @property
    def path(self) -> str:
        return self.link.path

    def start(self) -> BoardServer:
        for target in (self._board_loop, self._tx_loop):
            t = threading.Thread(target=target, name=f"board-{target.__name__}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def close(self) -> None:
        """Stop the axis, stop the threads and close the line."""
        self._stop.set()
        with self._tx_cond:
            self._tx_cond.notify_all()
        for t in self._threads:
            t.join(timeout=2.0)
        self.firmware.drive.disable()
        self.link.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    # --- board thread ------------------------------------------------------------

    def _board_loop(self) -> None:
        fw = self.firmware
        clock = SimClock(fw.identity.loop_rate_hz, self.time_scale)
        self._last_rx = time.monotonic()
        try:
            while not self._stop.is_set():
                data = self.link.read_some(0.002)
                now = time.monotonic()
                if data:
                    self._receive(data, now, clock)
                was_running = fw.running
                clock.step(fw, now)
                if was_running and self._run_checks(now, clock):
                    return
                self._flush_outbox()
        except LinkClosed:
            pass
        except BaseException as exc:  # keep the failure for the owner to see
            self.error = exc
        finally:
            fw.drive.disable()
            self._stop.set()
            with self._tx_cond:
                self._tx_cond.notify_all()

    def _receive(self, data: bytes, now: float, clock: SimClock) -> None:
        """Hand the host's frames to the firmware; a run that starts starts the clock's pacing."""
        fw = self.firmware
        self._last_rx = now
        for payload in self.decoder.feed(data):
            was_running = fw.running
            fw.receive(payload)
            if fw.running and not was_running:
                self._run_started = now
                clock.start_run(now, fw.produced)
        fw.line_corrupt = self.decoder.stats.corrupt

    def _run_checks(self, now: float, clock: SimClock) -> bool:
        """During a run: the host watchdog, and the line that closes on purpose; True when the line closed."""
        fw = self.firmware
        if fw.running and now - self._last_rx > self.watchdog_s:
            fw.watchdog_expired()
            clock.start_coast(now)  # let the axis coast to rest
        if self.close_after_s and self._run_started and now - self._run_started > self.close_after_s:
            self._flush_outbox()
            self.link.close()
            fw.drive.disable()
            return True
        return False

    def _flush_outbox(self) -> None:
        fw = self.firmware
        if not fw.outbox:
            return
        with self._tx_cond:
            for payload in fw.outbox:
                is_samples = payload[1] == sb.MsgType.SAMPLES
                if is_samples and self._tx_bytes + len(encode_frame(payload)) > self.tx_buffer_bytes:
                    fw.drop_block()  # counted by block_index; it takes no message number (section 3)
                    continue
                self._sent_seq = (self._sent_seq + 1) & 0xFFFF
                frame = encode_frame(payload[:2] + self._sent_seq.to_bytes(2, "little") + payload[4:])
                self._tx.append(frame)
                self._tx_bytes += len(frame)
            fw.outbox.clear()
            self._tx_cond.notify_all()

    # --- transmit thread (the UART) -------------------------------------------------

    def _tx_loop(self) -> None:
        rate = self.baudrate / BITS_PER_BYTE if self.baudrate else 0.0
        t0 = time.monotonic()
        credit_origin = t0
        sent_since_origin = 0
        try:
            while not self._stop.is_set():
                with self._tx_cond:
                    idle = not self._tx  # did the line run dry?
                    while not self._tx and not self._stop.is_set():
                        self._tx_cond.wait(0.05)
                    if self._stop.is_set():
                        return
                    frame = self._tx.popleft()
                    self._tx_bytes -= len(frame)
                if rate:
                    now = time.monotonic()
                    if idle and sent_since_origin / rate < now - credit_origin:
                        # the line ran dry: unused bandwidth is not saved up. A sender that woke
                        # late with frames waiting catches up instead (a UART fed from its
                        # transmit buffer never pauses).
                        credit_origin, sent_since_origin = now, 0
                    ahead = (sent_since_origin + len(frame)) / rate - (now - credit_origin)
                    if ahead > 0:
                        time.sleep(ahead)
                    sent_since_origin += len(frame)
                self.link.write(self.faults.apply(frame))
                self.bytes_sent += len(frame)
        except (LinkClosed, OSError):
            pass


def identity_from_driver(driver: DriverDescription) -> sb.Identity:
    """What the emulated board answers to IDENTIFY: the driver description's board."""
    return sb.Identity(
        protocol_version=sb.PROTOCOL_VERSION,
        name=driver.name,
        firmware=driver.firmware,
        loop_rate_hz=driver.loop_rate_hz,
        max_sample_rate_hz=driver.max_sample_rate_hz,
        filter_slots=driver.filter_slots,
        excitation_buffer_samples=driver.excitation_buffer_samples,
        channels=tuple(sb.ChannelInfo(c.name, c.unit) for c in driver.channels),
    )


def start(cfg: EmulatorConfig, driver: DriverDescription, device: DeviceConfig) -> EmulatedDevice:
    """Start the emulated board for a session configured with ``device`` (its baud rate, else the driver's)."""
    return start_serial_board(cfg, driver, device.baudrate or driver.default_baudrate)


def start_serial_board(
    cfg: EmulatorConfig, driver: DriverDescription, baudrate: int, link: str | None = None
) -> EmulatedDevice:
    """Start an emulated serial board on a pseudo-terminal or an in-memory pipe.

    Parameters
    ----------
    cfg : EmulatorConfig
        Plant, friction, drive, sensors, faults, time scale.
    driver : DriverDescription
        The board to emulate.
    baudrate : int
        Line rate the board paces its output to (0: unpaced).
    link : {"pty", "tcp", "pipe"}, optional
        Overrides ``cfg.link``: a pseudo-terminal, a raw TCP line on 127.0.0.1
        (``socket://`` for pyserial), or an in-memory pipe.
    """
    kind = link or cfg.link
    firmware = BoardFirmware(build_drive(cfg, driver), identity_from_driver(driver), driver.averaged_channels)
    line = cfg.faults.serial
    faults = LineFaults(line.corrupt_frame_rate, line.drop_frame_rate, seed=cfg.seed + 1)
    device_link: BoardLink
    if kind == "pty":
        device_link, host_link = PtyLink(), None
    elif kind == "tcp":
        device_link, host_link = TcpLink(), None
    else:
        host_link, device_end = pipe_pair()
        device_link = PipeLink(device_end)
    server = BoardServer(
        firmware,
        device_link,
        baudrate=baudrate,
        time_scale=cfg.time_scale,
        faults=faults,
        close_after_s=line.close_after_s,
    ).start()
    device = replace(DeviceConfig(), driver=str(driver.folder), port=device_link.path, baudrate=baudrate)
    return EmulatedDevice(server=server, device=device, drive=firmware.drive, link=host_link)
