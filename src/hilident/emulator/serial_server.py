"""The emulated board on a line: a pseudo-terminal or an in-memory pipe.

:class:`BoardServer` runs :class:`~hilident.emulator.board.BoardFirmware` in a
background thread. It steps the physics in real time (times ``time_scale``), and
writes its frames at the configured baud rate, so a host sees the same
throughput limits as on a real UART: when the host asks for more samples than
the line carries, the board's transmit buffer fills and sample blocks are
dropped (and counted), exactly as on the bench.

The pseudo-terminal is a real serial device path (``/dev/pts/N``) that pyserial
opens like a USB serial board.
"""

from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
import tty
from collections import deque

import numpy as np

from hilident.errors import ConfigError
from hilident.links import LinkClosed, PipeEnd
from hilident.protocol.framing import FrameDecoder, encode_frame

#: Bits on the line per byte: start + 8 data + stop (8N1).
BITS_PER_BYTE = 10


class PtyLink:
    """Device side of a pseudo-terminal; :attr:`path` is what the host opens."""

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: a raw 8-bit line
        self.path = os.ttyname(self._slave)
        self._closed = False

    def read_some(self, timeout: float) -> bytes:
        if self._closed:
            raise LinkClosed(f"{self.path}: closed")
        ready, _, _ = select.select([self.master], [], [], timeout)
        if not ready:
            return b""
        try:
            return os.read(self.master, 65536)
        except OSError as exc:
            raise LinkClosed(f"{self.path}: {exc}") from None

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            if self._closed:
                raise LinkClosed(f"{self.path}: closed")
            _, ready, _ = select.select([], [self.master], [], 0.05)
            if ready:
                n = os.write(self.master, view)
                view = view[n:]

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for fd in (self.master, self._slave):
                try:
                    os.close(fd)
                except OSError:
                    pass


class TcpLink:
    """Device side of a raw TCP line on 127.0.0.1, reached as ``socket://127.0.0.1:PORT``.

    This is what a serial-to-Ethernet converter looks like to pyserial. One host
    at a time; a new connection replaces the old one.
    """

    def __init__(self, port: int = 0):
        self._listener = socket.create_server(("127.0.0.1", port))
        self._listener.setblocking(False)
        self.port = self._listener.getsockname()[1]
        self.path = f"socket://127.0.0.1:{self.port}"
        self._conn: socket.socket | None = None
        self._closed = False

    def _accept(self, timeout: float) -> bool:
        ready, _, _ = select.select([self._listener], [], [], timeout)
        if ready:
            conn, _ = self._listener.accept()
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if self._conn is not None:
                self._conn.close()
            self._conn = conn
        return self._conn is not None

    def read_some(self, timeout: float) -> bytes:
        if self._closed:
            raise LinkClosed(f"{self.path}: closed")
        conn = self._conn  # the transmit thread may drop it meanwhile
        if conn is None:
            self._accept(timeout)
            return b""
        try:
            ready, _, _ = select.select([conn, self._listener], [], [], timeout)
        except (OSError, ValueError):  # closed by the transmit thread
            return b""
        if self._listener in ready:
            self._accept(0)
            return b""
        if not ready:
            return b""
        try:
            data = conn.recv(65536)
        except OSError:  # reset by a host that died: the line is free for the next one
            data = b""
        if not data:  # the host hung up: wait for the next one
            self._drop(conn)
        return data

    def write(self, data: bytes) -> None:
        if self._closed:
            raise LinkClosed(f"{self.path}: closed")
        conn = self._conn
        if conn is None:
            return  # nobody listening: bytes on an unconnected line are lost
        try:
            conn.sendall(data)
        except OSError:  # the host went away; what it did not take is lost, as on a real line
            self._drop(conn)

    def _drop(self, conn: socket.socket) -> None:
        conn.close()
        if self._conn is conn:
            self._conn = None

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for s in (self._conn, self._listener):
                if s is not None:
                    s.close()


class PipeLink:
    """Device side of an in-memory pipe (see :func:`hilident.links.pipe_pair`)."""

    def __init__(self, end: PipeEnd):
        self.end = end
        self.path = end.port

    def read_some(self, timeout: float) -> bytes:
        self.end.timeout = timeout
        return self.end.read(max(1, self.end.in_waiting))

    def write(self, data: bytes) -> None:
        self.end.write(data)

    def close(self) -> None:
        self.end.close()


class LineFaults:
    """Seeded damage to board->host frames, for fault tests.

    Parameters
    ----------
    corrupt_frame_rate : float
        Probability that one byte of a frame is flipped.
    drop_frame_rate : float
        Probability that a run of bytes of a frame is lost.
    seed : int
    """

    def __init__(self, corrupt_frame_rate=0.0, drop_frame_rate=0.0, seed=0):
        self.corrupt = corrupt_frame_rate
        self.drop = drop_frame_rate
        self.rng = np.random.default_rng(seed)
        self.corrupted = 0
        self.dropped = 0

    def apply(self, frame: bytes) -> bytes:
        if not (self.corrupt or self.drop) or len(frame) < 4:
            return frame
        data = bytearray(frame)
        if self.corrupt and self.rng.random() < self.corrupt:
            i = int(self.rng.integers(0, len(data) - 1))
            data[i] ^= 1 << int(self.rng.integers(0, 8))
            if data[i] == 0:
                data[i] = 0x55  # a new zero would split the frame: still corrupt, just differently
            self.corrupted += 1
        if self.drop and self.rng.random() < self.drop:
            i = int(self.rng.integers(0, len(data) - 1))
            n = int(self.rng.integers(1, 9))
            del data[i : min(i + n, len(data) - 1)]
            self.dropped += 1
        return bytes(data)


class BoardServer:
    """Serve :class:`BoardFirmware` on a link in a background thread.

    Parameters
    ----------
    firmware : BoardFirmware
    link : PtyLink or PipeLink
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

    def __init__(self, firmware, link, baudrate: int, time_scale: float = 1.0,
                 tx_buffer_bytes: int = 65536, watchdog_s: float = 1.0,
                 faults: LineFaults | None = None, close_after_s: float = 0.0):
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ConfigError("emulator.time_scale", f"must be a finite number > 0, got {time_scale!r}")
        if not (isinstance(baudrate, int) and baudrate >= 0):
            raise ConfigError("device.baudrate", f"must be a whole number >= 0, got {baudrate!r}")
        self.firmware = firmware
        self.link = link
        self.baudrate = baudrate
        self.time_scale = time_scale
        self.tx_buffer_bytes = tx_buffer_bytes
        self.watchdog_s = watchdog_s
        self.faults = faults or LineFaults()
        self.close_after_s = close_after_s
        self.decoder = FrameDecoder()
        self._tx = deque()
        self._tx_bytes = 0
        self._tx_cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.error: BaseException | None = None
        self.bytes_sent = 0

    @property
    def path(self) -> str:
        return self.link.path

    def start(self) -> "BoardServer":
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
        loop_rate = fw.identity.loop_rate_hz
        last_rx = time.monotonic()
        run_started = None
        run_origin = 0.0
        samples_at_origin = 0
        idle_clock = time.monotonic()
        idle_ticks_left = 0
        try:
            while not self._stop.is_set():
                data = self.link.read_some(0.002)
                now = time.monotonic()
                if data:
                    last_rx = now
                    for payload in self.decoder.feed(data):
                        was_running = fw.running
                        fw.receive(payload)
                        if fw.running and not was_running:
                            run_started = run_origin = now
                            samples_at_origin = 0
                    fw.line_corrupt = self.decoder.stats.corrupt
                if fw.running:
                    due = int((now - run_origin) * fw.sample_rate_hz * self.time_scale) - (
                        fw._produced - samples_at_origin
                    )
                    cap = max(1, int(0.05 * fw.sample_rate_hz * self.time_scale))
                    if due > cap:  # fell behind (slow machine): resume from now, never burst
                        run_origin = now
                        samples_at_origin = fw._produced
                        due = cap
                    fw.advance(due)
                    if fw.running and now - last_rx > self.watchdog_s:
                        fw.watchdog_expired()
                    if self.close_after_s and run_started and now - run_started > self.close_after_s:
                        self._flush_outbox()
                        self.link.close()
                        self.firmware.drive.disable()
                        return
                    if not fw.running:
                        idle_clock = now
                        idle_ticks_left = int(2.0 * loop_rate)  # let the axis coast to rest
                elif idle_ticks_left > 0:
                    n = min(idle_ticks_left, int((now - idle_clock) * loop_rate * self.time_scale))
                    if n > 0:
                        fw.idle(n)
                        idle_ticks_left -= n
                        idle_clock = now
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

    def _flush_outbox(self) -> None:
        fw = self.firmware
        if not fw.outbox:
            return
        with self._tx_cond:
            for payload in fw.outbox:
                frame = encode_frame(payload)
                is_samples = payload[1] == 0x84
                if is_samples and self._tx_bytes + len(frame) > self.tx_buffer_bytes:
                    fw.drop_block()
                    continue
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
