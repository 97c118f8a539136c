"""CAN traces of a run (``.asc``, ``.blf``) that a vendor tool reads cleanly.

:class:`TracingNetwork` is a :class:`canopen.Network` that can also hand every
frame it sends and receives to a :class:`FrameTrace`, which writes it with
python-can's :class:`can.ASCWriter` or :class:`can.BLFWriter` (chosen by the
file's suffix, see :func:`can.Logger`).

Two choices make the file read as one bus in one time line:

**One channel.** python-can's writers derive the channel number from
``msg.channel`` (``"can0"`` -> 1, ``"vcan1"`` -> 2, via
:func:`can.util.channel2int`), and use their default channel when a message
has none. Received frames carry the interface's channel name, frames built for
sending carry none, so a channel name ending in a digit other than 0 put Tx
and Rx on two channels. Every frame written here carries no channel and the
writer's default is :data:`TRACE_CHANNEL`: the whole trace is channel 1.

**One clock, in the order hilident saw the frames.** A received frame's own
timestamp is bus time (kernel, adapter or daemon clock), and it reaches the
host later, by up to hundreds of milliseconds under load; a sent frame has only
host time. Mixing the two made the trace go backwards. Here every frame is
stamped with :class:`TraceClock` (wall-clock time at the start of the trace,
advanced by :func:`time.monotonic`, so it never steps back with NTP) at the
moment it is written, under one lock. The trace therefore holds frames in the
order hilident handled them, with non-decreasing times: a sent frame is written
while the send holds the trace lock, so an answer to it is always written
after it; a received frame is written before canopen's own listener handles it
(the trace is the first listener of the notifier), so a frame the host sends
in reaction is written after it. The price is that the timestamps are the
host's view (arrival after the bus, transmission as handed to the interface),
not the bus's own; for latencies on the wire use the interface's tools. The
frames canopen delivers to the rest of hilident keep their bus timestamps: the
trace writes copies.

Examples
--------
>>> network = TracingNetwork()                           # doctest: +SKIP
>>> network.connect(interface="virtual", channel="vcan1")  # doctest: +SKIP
>>> network.start_trace("run.asc")                       # doctest: +SKIP
>>> network.stop_trace()                                 # doctest: +SKIP
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can

import canopen

__all__ = ["FLUSH_INTERVAL_S", "TRACE_CHANNEL", "FrameTrace", "TraceClock", "TracingNetwork"]

#: The channel number every frame has in a trace file (python-can readers give it back as ``channel == 0``).
TRACE_CHANNEL = 1

#: At most this long (s) between a frame and the moment the written file holds it (the writer's buffer aside).
FLUSH_INTERVAL_S = 0.5


class TraceClock:
    """Wall-clock seconds that never go backwards: :func:`time.time` at creation plus monotonic time since.

    The writers need absolute (epoch) times: the BLF header stores the start
    as a calendar date, and the ASC header the date of the first frame.
    """

    def __init__(self) -> None:
        self._epoch_s = time.time()
        self._start_s = time.monotonic()

    def now(self) -> float:
        """Seconds since the epoch, non-decreasing across calls and threads."""
        return self._epoch_s + (time.monotonic() - self._start_s)


class FrameTrace(can.Listener):
    """A python-can writer fed from two threads: the notifier (received frames) and the senders.

    Parameters
    ----------
    path : str or Path
        The trace file; its suffix picks the writer (``.asc`` or ``.blf``; any
        suffix :func:`can.Logger` knows works the same way).
    clock : TraceClock, optional
        The clock every written frame is stamped with (a new one by default).

    Raises
    ------
    OSError
        The file cannot be created.
    ValueError
        python-can knows no writer for the suffix.
    """

    def __init__(self, path: str | Path, clock: TraceClock | None = None) -> None:
        self.path = Path(path)
        self.clock = clock or TraceClock()
        self.writer = can.Logger(str(self.path), channel=TRACE_CHANNEL)
        self.lock = threading.RLock()
        self.frames = 0
        self._closed = False
        self._flushed_s = time.monotonic()

    def on_message_received(self, msg: can.Message) -> None:
        """A frame from the bus (the notifier's thread): written as received."""
        with self.lock:
            self._write(msg, is_rx=True)

    def write_sent(self, msg: can.Message) -> None:
        """A frame the host has just handed to the interface: written as sent (Tx)."""
        with self.lock:
            self._write(msg, is_rx=False)

    def _write(self, msg: can.Message, is_rx: bool) -> None:
        if self._closed:
            return  # a frame that was on its way while the trace stopped
        self.writer.on_message_received(self._stamped(msg, is_rx))
        self.frames += 1
        if time.monotonic() - self._flushed_s > FLUSH_INTERVAL_S:
            self._flush()

    def _stamped(self, msg: can.Message, is_rx: bool) -> can.Message:
        """A copy of ``msg`` on the trace's channel and clock (the original keeps its bus timestamp)."""
        return can.Message(
            timestamp=self.clock.now(),
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            channel=None,
            dlc=msg.dlc,
            data=msg.data,
            is_fd=msg.is_fd,
            is_rx=is_rx,
            bitrate_switch=msg.bitrate_switch,
            error_state_indicator=msg.error_state_indicator,
            check=False,
        )

    def _flush(self) -> None:
        """Push what the writer has written so far to the file (a crashed run keeps most of its trace)."""
        self._flushed_s = time.monotonic()
        file = getattr(self.writer, "file", None)
        if file is not None and not file.closed:
            file.flush()

    def stop(self) -> None:
        """Finish the file (headers, the last container); later frames are ignored. Idempotent."""
        with self.lock:
            if self._closed:
                return
            self._closed = True
            self.writer.stop()


class TracingNetwork(canopen.Network):
    """A canopen Network whose frames can also go to a :class:`FrameTrace`."""

    NOTIFIER_CYCLE = 0.1  # a short receive timeout: disconnect() returns promptly

    def __init__(self, bus: can.BusABC | None = None) -> None:
        super().__init__(bus)
        self.trace: FrameTrace | None = None

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        """Send a frame; while a trace runs, write it there once the interface has taken it."""
        trace = self.trace
        if trace is None:
            super().send_message(can_id, data, remote)
            return
        # The trace lock is held across the send so that no answer to this frame can be written before it.
        with trace.lock:
            super().send_message(can_id, data, remote)
            trace.write_sent(
                can.Message(
                    arbitration_id=can_id,
                    data=bytes(data),
                    is_extended_id=can_id > 0x7FF,
                    is_remote_frame=remote,
                    check=False,
                )
            )

    def start_trace(self, path: str | Path, clock: TraceClock | None = None) -> FrameTrace:
        """Start writing every frame to ``path`` (see :class:`FrameTrace` for what it raises)."""
        self.stop_trace()
        trace = FrameTrace(path, clock)
        notifier = self.notifier
        if notifier is not None:
            # First in line, so a received frame is written before canopen reacts to it. A new list, not an
            # insert: the notifier thread may be iterating over the old one right now.
            notifier.listeners = [trace, *notifier.listeners]
        self.trace = trace
        return trace

    def stop_trace(self) -> None:
        """Stop the trace, if one runs, and finish its file."""
        trace, self.trace = self.trace, None
        if trace is None:
            return
        notifier = self.notifier
        if notifier is not None:
            notifier.listeners = [listener for listener in notifier.listeners if listener is not trace]
        trace.stop()
