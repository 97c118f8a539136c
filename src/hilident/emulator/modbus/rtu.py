"""Modbus RTU on pseudo-terminals: the null-modem bridge and the drive's end of the line.

:class:`PtyBridge` joins two pseudo-terminals like a null-modem cable and
carries the bytes at the line rate; :class:`RtuLine` finds request frames in
the bytes the drive receives (by length where the function code gives it, else
at 3.5 characters of silence, MODBUS over Serial Line V1.02 2.5.1.1) and sends
the answers its server gives.
"""

from __future__ import annotations

import asyncio
import os
import select
import threading
import time
import tty
from typing import Protocol

from hilident.emulator.modbus.pdu import request_length
from hilident.protocol.modbus.rtu import rtu_crc

__all__ = ["PtyBridge", "RtuLine", "crc_ok"]

_RTU_STALL_S = 0.1  # a frame whose length is known waits this long for its missing bytes (a loaded machine)


class RtuServer(Protocol):
    """What the line needs of its server: the line settings (read only) and the answer to a frame."""

    @property
    def baudrate(self) -> int: ...

    @property
    def bits_per_char(self) -> int: ...

    def rtu_frame(self, frame: bytes) -> bytes | None: ...


class PtyBridge:
    """Two pseudo-terminals joined like a null-modem cable, carrying bytes at a line rate.

    Parameters
    ----------
    baudrate : int
        Line rate; 0 carries bytes as fast as they come.
    bits_per_char : int
        Start bit, data bits, parity bit and stop bits of one character.

    Attributes
    ----------
    device_path, host_path : str
        The two serial device paths (``/dev/pts/N``).
    """

    def __init__(self, baudrate: int, bits_per_char: int = 11):
        self._device_master, self._device_slave = os.openpty()
        self._host_master, self._host_slave = os.openpty()
        for fd in (self._device_slave, self._host_slave):
            tty.setraw(fd)
        self.device_path = os.ttyname(self._device_slave)
        self.host_path = os.ttyname(self._host_slave)
        self.char_time_s = bits_per_char / baudrate if baudrate else 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.bytes_carried = 0

    def start(self) -> PtyBridge:
        self._thread = threading.Thread(target=self._run, name="modbus-pty-bridge", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        other = {self._device_master: self._host_master, self._host_master: self._device_master}
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select(list(other), [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    time.sleep(0.01)
                    continue
                if self.char_time_s:
                    time.sleep(len(data) * self.char_time_s)  # the characters take this long on the line
                self._write(other[fd], data)
                self.bytes_carried += len(data)

    def _write(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + 0.5
        while view and not self._stop.is_set() and time.monotonic() < deadline:
            try:
                _, ready, _ = select.select([], [fd], [], 0.05)
                if ready:
                    view = view[os.write(fd, view) :]
            except OSError:
                return  # nobody at the other end: the bytes are lost, as on an open line

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self._device_master, self._device_slave, self._host_master, self._host_slave):
            try:
                os.close(fd)
            except OSError:
                pass


class RtuLine:
    """The drive's end of an RTU line: finds request frames in the bytes, answers through the server."""

    def __init__(self, server: RtuServer):
        self.server = server
        self.fd: int | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.buffer = b""
        self.garbled = False  # a bad frame was seen: drop everything until the line is silent
        self.last_byte = 0.0
        self.timer: asyncio.TimerHandle | None = None
        self.silence_s = 0.0

    def open(self, path: str, loop: asyncio.AbstractEventLoop) -> None:
        server = self.server
        char_s = server.bits_per_char / (server.baudrate or 115200)
        # t3.5 (Modbus over serial line V1.02, 2.5.1.1): 3.5 characters, fixed at 1.75 ms above 19200 baud
        self.silence_s = 3.5 * char_s if (server.baudrate or 115200) <= 19200 else 0.00175
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        self.loop = loop
        loop.add_reader(self.fd, self._readable)

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
        if self.fd is not None and self.loop is not None:
            self.loop.remove_reader(self.fd)
            os.close(self.fd)
            self.fd = None

    def _opened(self) -> tuple[int, asyncio.AbstractEventLoop]:
        """The line's descriptor and event loop; only an open line reads, waits for silence and answers."""
        if self.fd is None or self.loop is None:
            raise RuntimeError("the RTU line is not open")
        return self.fd, self.loop

    def _readable(self) -> None:
        fd, _ = self._opened()
        try:
            data = os.read(fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            time.sleep(0.005)  # the other end is not open yet (or no longer): nothing to read
            return
        if not data:
            return
        self.buffer += data
        self.last_byte = time.monotonic()
        if not self.garbled:
            self._frames()
        self._arm(self.silence_s)

    def _arm(self, delay: float) -> None:
        if self.timer is not None:
            self.timer.cancel()
        _, loop = self._opened()
        self.timer = loop.call_later(delay, self._silence) if self.buffer or self.garbled else None

    def _frames(self) -> None:
        """Answer every complete frame at the front of the buffer whose length the function code gives."""
        while self.buffer:
            n = request_length(self.buffer)
            if n is None or len(self.buffer) < n:
                return
            frame, self.buffer = self.buffer[:n], self.buffer[n:]
            if not crc_ok(frame):
                self.garbled = True  # where the next frame starts is unknown: wait for the silence
                return
            self._send(self.server.rtu_frame(frame))

    def _silence(self) -> None:
        """3.5 characters without a byte: whatever is in the buffer is one frame (or the rest of a bad one)."""
        self.timer = None
        n = request_length(self.buffer)
        waited = time.monotonic() - self.last_byte
        if not self.garbled and n is not None and len(self.buffer) < n and waited < _RTU_STALL_S:
            # a frame of known length is still short: on a loaded machine the rest can come late
            self._arm(_RTU_STALL_S - waited)
            return
        frame, self.buffer = self.buffer, b""
        garbled, self.garbled = self.garbled, False
        if not garbled and n is None and len(frame) >= 4 and crc_ok(frame):
            self._send(self.server.rtu_frame(frame))  # a function whose length is unknown ends here

    def _send(self, frame: bytes | None) -> None:
        fd, _ = self._opened()
        view = memoryview(frame or b"")
        deadline = time.monotonic() + 0.5
        while view and time.monotonic() < deadline:
            try:
                view = view[os.write(fd, view) :]
            except (BlockingIOError, InterruptedError):
                select.select([], [fd], [], 0.05)
            except OSError:
                return  # nobody at the other end: the answer is lost, as on an open line


def crc_ok(frame: bytes) -> bool:
    return len(frame) >= 4 and rtu_crc(frame[:-2]) == frame[-2] | frame[-1] << 8
