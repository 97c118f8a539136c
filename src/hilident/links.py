"""An in-memory byte link with the subset of pyserial's ``Serial`` API hilident uses.

:func:`pipe_pair` returns two connected ends, like the two ends of a null-modem
cable: what one end writes the other reads. The host adapter uses one end
exactly as it would use ``serial.Serial``; an emulated device uses the other.
Tests use it to run the full protocol without a pseudo-terminal.
"""

from __future__ import annotations

import threading
import time


class LinkClosed(OSError):
    """The other end of the link was closed."""


class _Channel:
    """One direction of the pipe: a byte buffer guarded by a condition."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.cond = threading.Condition()
        self.closed = False


class PipeEnd:
    """One end of an in-memory link (pyserial-like).

    Parameters
    ----------
    rx, tx : _Channel
        Receive and transmit directions.
    port : str
        Name reported in errors.
    timeout : float or None
        Read timeout in seconds, as ``serial.Serial.timeout``.
    """

    def __init__(self, rx: _Channel, tx: _Channel, port: str, timeout: float | None = 1.0):
        self._rx = rx
        self._tx = tx
        self.port = port
        self.timeout = timeout
        self.is_open = True

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        return len(self._rx.buffer)

    def read(self, size: int = 1) -> bytes:
        """Read up to ``size`` bytes, waiting at most ``timeout`` for all of them."""
        self._check_open()
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        with self._rx.cond:
            while len(self._rx.buffer) < size and not self._rx.closed:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                self._rx.cond.wait(remaining)
            if self._rx.closed and not self._rx.buffer:
                raise LinkClosed(f"{self.port}: the other end closed the link")
            data = bytes(self._rx.buffer[:size])
            del self._rx.buffer[:size]
            return data

    def write(self, data: bytes) -> int:
        """Queue ``data`` for the other end."""
        self._check_open()
        with self._tx.cond:
            if self._tx.closed:
                raise LinkClosed(f"{self.port}: the other end closed the link")
            self._tx.buffer += data
            self._tx.cond.notify_all()
        return len(data)

    def flush(self) -> None:
        """Nothing to do: writes are delivered at once."""

    def reset_input_buffer(self) -> None:
        """Discard received, unread bytes."""
        with self._rx.cond:
            self._rx.buffer.clear()

    def close(self) -> None:
        """Close this end; the other end sees :class:`LinkClosed` once drained."""
        if not self.is_open:
            return
        self.is_open = False
        for ch in (self._rx, self._tx):
            with ch.cond:
                ch.closed = True
                ch.cond.notify_all()

    def _check_open(self) -> None:
        if not self.is_open:
            raise LinkClosed(f"{self.port}: link is closed")


def pipe_pair(name: str = "pipe://emulator", timeout: float | None = 1.0) -> tuple[PipeEnd, PipeEnd]:
    """Two connected ends: ``(host_end, device_end)``."""
    a_to_b, b_to_a = _Channel(), _Channel()
    return PipeEnd(b_to_a, a_to_b, name, timeout), PipeEnd(a_to_b, b_to_a, name, timeout)
