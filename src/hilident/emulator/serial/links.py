"""The device's end of a serial line: a pseudo-terminal, a raw TCP line, an in-memory pipe; and line damage.

Each link offers ``read_some(timeout)``, ``write(data)``, ``close()`` and
``path`` (what a host opens). :class:`LineFaults` damages board->host frames
for fault tests.
"""

from __future__ import annotations

import os
import select
import socket
import tty
from typing import Protocol

import numpy as np

from hilident.links import LinkClosed, PipeEnd

__all__ = ["BoardLink", "LineFaults", "PipeLink", "PtyLink", "TcpLink"]


class BoardLink(Protocol):
    """The device's end of a line, as :class:`~hilident.emulator.serial.server.BoardServer` uses it."""

    path: str

    def read_some(self, timeout: float) -> bytes: ...

    def write(self, data: bytes) -> None: ...

    def close(self) -> None: ...


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
