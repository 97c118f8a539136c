"""Firmware of the emulated serial board: protocol state machine around one drive loop.

:class:`BoardFirmware` is what runs on the board, minus the clock and the UART:
it takes request payloads, answers them, and, asked to advance by some number
of samples, steps the drive loop, fills sample blocks and watches the safety
limits. :mod:`hilident.emulator.serial.server` gives it a clock and a line.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from hilident.emulator.clock import TablePlayer
from hilident.emulator.drive import DriveLoop
from hilident.emulator.serial.loop import loop_parameters, loop_refusal
from hilident.errors import HilidentError, ProtocolError
from hilident.filters.biquad import Biquad
from hilident.protocol import serial_board as sb

_MODE_NAMES = {
    sb.Mode.TORQUE: "torque",
    sb.Mode.TORQUE_INJECTION: "torque_injection",
    sb.Mode.VELOCITY: "velocity",
    sb.Mode.POSITION: "position",
}
_FAULTS = {
    "torque_limit": sb.FaultCode.TORQUE_LIMIT,
    "velocity_limit": sb.FaultCode.VELOCITY_LIMIT,
    "position_limit": sb.FaultCode.POSITION_LIMIT,
}


@dataclass
class BoardCounters:
    """What the board counts (reported in STATUS)."""

    underruns: int = 0
    dropped_blocks: int = 0
    limit_trips: int = 0
    rx_corrupt: int = 0


class BoardFirmware:
    """Protocol logic of the board.

    Parameters
    ----------
    drive : hilident.emulator.drive.DriveLoop
        The drive loop and plant the board controls.
    identity : hilident.protocol.serial_board.Identity
        What the board answers to IDENTIFY; its channel names must be columns of
        ``drive.CHANNELS``.
    averaged : iterable of str
        Channels the board records as the mean over each sample period's loop ticks
        (PROTOCOL.md section 7; the driver's ``sampling = "mean"``).
    """

    def __init__(self, drive: DriveLoop, identity: sb.Identity, averaged: Iterable[str] = ()):
        self.drive = drive
        self.identity = identity
        self._column = drive.columns_of([c.name for c in identity.channels], "board channel")
        self.state = sb.State.IDLE
        self.fault = sb.FaultCode.NONE
        self.counters = BoardCounters()
        self.config: sb.Configure | None = None
        self._seq = 0
        capacity = identity.excitation_buffer_samples
        self._fifo = np.zeros(capacity)
        self._fifo_written = 0  # absolute index of the next excitation sample expected
        self._fifo_read = 0  # absolute index of the next excitation sample to play
        self._run_samples = 0
        self._produced = 0
        self._block_index = 0
        self._pending: list[np.ndarray] = []
        self._pending_rows = 0
        self._pending_flags = 0
        self._in_underrun = False
        self._last_value = 0.0  # the excitation value played last in this run
        self.outbox: list[bytes] = []  # encoded payloads waiting for the line
        self.limits_loaded = False  # a board never moves the axis before it was told its limits
        self.line_corrupt = 0  # frames the line layer rejected (set by the server)
        self._player = TablePlayer(drive, 1, identity.loop_rate_hz, averaged)
        self.sample_blocks_out = 0

    # --- messages ---------------------------------------------------------------

    def next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        return self._seq

    def send(self, msg) -> None:
        """Queue a message for the host."""
        channels = self.config.channels if self.config else ()
        self.outbox.append(sb.encode(msg, self.next_seq(), sample_channels=channels))

    def receive(self, payload: bytes) -> None:
        """Handle one request payload from the host (answers go to :attr:`outbox`)."""
        excitation = (
            (self.config.excitation_format, self.config.excitation_scale) if self.config else (sb.Format.F32, 1.0)
        )
        kind = payload[1] if len(payload) > 1 else 0
        seq = int.from_bytes(payload[2:4], "little") if len(payload) >= 4 else 0
        if len(payload) >= 4 and payload[0] == sb.PROTOCOL_VERSION and kind >= sb.BOARD_TO_HOST:
            # a board -> host type is no request, whatever its body (PROTOCOL.md section 11.1)
            self.counters.rx_corrupt += 1
            self.send(sb.Nak(seq, kind, sb.ErrorCode.UNKNOWN_TYPE, "not a request"))
            return
        try:
            header, msg = sb.decode(payload, excitation=excitation)
        except ProtocolError as exc:
            self.counters.rx_corrupt += 1
            text = str(exc)
            if "protocol version" in text:
                code = sb.ErrorCode.BAD_VERSION
            elif "unknown message type" in text:
                code = sb.ErrorCode.UNKNOWN_TYPE
            else:  # a short body, or (version 1) an unknown mode or format: undecodable (section 11.1)
                code = sb.ErrorCode.BAD_LENGTH
            self.send(sb.Nak(seq, kind, code, text))
            return
        handler = getattr(self, "_on_" + type(msg).__name__.lower(), None)
        if handler is None:
            self.send(sb.Nak(header.seq, header.type, sb.ErrorCode.UNKNOWN_TYPE, "not a request"))
            return
        try:
            error = handler(msg)
        except (ValueError, HilidentError) as exc:  # e.g. a value the drive refuses
            error = sb.ErrorCode.BAD_ARGUMENT, str(exc)
        if error is None:
            if not isinstance(msg, (sb.Identify, sb.StatusRequest, sb.ReadFilter, sb.ReadLoop, sb.Excitation)):
                self.send(sb.Ack(header.seq, header.type))
        else:
            self.send(sb.Nak(header.seq, header.type, error[0], error[1]))

    def _on_identify(self, msg):
        self.send(self.identity)

    def _on_statusrequest(self, msg):
        self.send(self.status())

    def status(self) -> sb.Status:
        c = self.counters
        return sb.Status(
            self.state,
            self.fault,
            self._fifo_written - self._fifo_read,
            len(self._fifo),
            c.underruns,
            c.dropped_blocks,
            self._produced,
            c.limit_trips,
            c.rx_corrupt + self.line_corrupt,
        )

    def _on_configure(self, msg: sb.Configure):
        if self.state == sb.State.RUNNING:
            return sb.ErrorCode.BAD_STATE, "cannot configure while running"
        rate = self.identity.loop_rate_hz / max(msg.sample_divider, 1)
        if msg.sample_divider < 1 or rate > self.identity.max_sample_rate_hz:
            return sb.ErrorCode.BAD_ARGUMENT, f"sample divider {msg.sample_divider} gives {rate:g} Hz"
        if not 1 <= msg.block_samples <= 4096:
            return sb.ErrorCode.BAD_ARGUMENT, f"block of {msg.block_samples} samples"
        if not msg.channels or any(c.channel >= len(self.identity.channels) for c in msg.channels):
            return sb.ErrorCode.BAD_ARGUMENT, "channel index out of range"
        if any(c.format != sb.Format.F32 and not c.scale > 0 for c in msg.channels):
            return sb.ErrorCode.BAD_ARGUMENT, "integer channel needs a positive scale"
        self.config = msg
        self._fifo_read = self._fifo_written = 0  # a new configuration starts an empty excitation buffer
        if self.state != sb.State.FAULT:
            self.state = sb.State.CONFIGURED
        return None

    def _on_limits(self, msg: sb.Limits):
        values = (msg.torque_nm, msg.velocity_mps, msg.position_min_m, msg.position_max_m)
        if not all(np.isfinite(values)):
            return sb.ErrorCode.BAD_ARGUMENT, "limits must be finite numbers"
        if not (msg.torque_nm > 0 and msg.velocity_mps > 0 and msg.position_min_m < msg.position_max_m):
            return sb.ErrorCode.BAD_ARGUMENT, "limits must be positive and the window non-empty"
        self.drive.set_limits(*values)
        self.limits_loaded = True
        return None

    def _on_start(self, msg: sb.Start):
        if self.state == sb.State.FAULT:
            return sb.ErrorCode.FAULT_ACTIVE, f"fault {self.fault.name} active; send CLEAR_FAULT"
        if self.state != sb.State.CONFIGURED or self.config is None:
            return sb.ErrorCode.BAD_STATE, f"cannot start in state {self.state.name}"
        if not self.limits_loaded:
            return sb.ErrorCode.BAD_STATE, "no safety limits loaded (send SET_LIMITS first)"
        self.drive.set_mode(_MODE_NAMES[self.config.mode])
        self.drive.enable()
        self._run_samples = msg.n_samples
        self._produced = 0
        self._player.restart(self.config.sample_divider)
        self.counters.underruns = 0  # per-run counters; limit trips and corrupt frames count since power-up
        self.counters.dropped_blocks = 0
        self._pending, self._pending_rows, self._pending_flags = [], 0, 0
        self._in_underrun = False
        self._last_value = 0.0
        self.state = sb.State.RUNNING
        return None

    def _on_stop(self, msg):
        if self.state == sb.State.RUNNING:
            self._finish(sb.EventCode.STOPPED, "stopped by host")
        self.drive.disable()
        return None

    def _on_clearfault(self, msg):
        if self.state == sb.State.RUNNING:
            return sb.ErrorCode.BAD_STATE, "running"
        self.drive.clear_fault()
        self.fault = sb.FaultCode.NONE
        self.state = sb.State.CONFIGURED if self.config else sb.State.IDLE
        return None

    def _on_ping(self, msg):
        return None

    def _on_excitation(self, msg: sb.Excitation):
        if self.state not in (sb.State.RUNNING, sb.State.CONFIGURED):
            return sb.ErrorCode.BAD_STATE, f"excitation while {self.state.name}"
        if msg.first_index != self._fifo_written:
            return sb.ErrorCode.BAD_ARGUMENT, f"excitation starts at {msg.first_index}, expected {self._fifo_written}"
        if not np.all(np.isfinite(msg.values)):
            return sb.ErrorCode.BAD_ARGUMENT, f"excitation from {msg.first_index} holds NaN or inf"
        n = len(msg.values)
        capacity = len(self._fifo)
        if self._fifo_written + n - self._fifo_read > capacity:
            return sb.ErrorCode.BUFFER_OVERFLOW, f"{n} samples do not fit the {capacity}-sample buffer"
        idx = (self._fifo_written + np.arange(n)) % capacity
        self._fifo[idx] = msg.values
        self._fifo_written += n
        return None

    def _on_writefilter(self, msg: sb.WriteFilter):
        c = msg.coefficients
        if not 0 <= c.slot < len(self.drive.filters):
            return sb.ErrorCode.BAD_ARGUMENT, f"filter slot {c.slot} (board has {len(self.drive.filters)})"
        if not all(np.isfinite(c.b + c.a)):
            return sb.ErrorCode.BAD_ARGUMENT, f"slot {c.slot}: coefficients must be finite"
        # The board stores REAL32 coefficients: what the host reads back is what runs.
        b0, b1, b2 = c.b
        stored = Biquad((sb.float32(b0), sb.float32(b1), sb.float32(b2)), (1.0, sb.float32(c.a[1]), sb.float32(c.a[2])))
        if c.enabled and not stored.is_stable():
            return sb.ErrorCode.BAD_ARGUMENT, f"slot {c.slot}: unstable coefficients refused"
        self.drive.filters.write(c.slot, stored, c.enabled)
        return None

    def _on_readfilter(self, msg: sb.ReadFilter):
        if not 0 <= msg.slot < len(self.drive.filters):
            return sb.ErrorCode.BAD_ARGUMENT, f"filter slot {msg.slot} (board has {len(self.drive.filters)})"
        coefficients, enabled = self.drive.filters.read(msg.slot)
        self.send(sb.FilterCoefficients(msg.slot, enabled, coefficients.b, coefficients.a))
        return None

    def _on_readloop(self, msg: sb.ReadLoop):
        self.send(loop_parameters(self.drive.tuning))
        return None

    def _on_writeloop(self, msg: sb.WriteLoop):
        refusal = loop_refusal(msg)
        if refusal is not None:
            return sb.ErrorCode.BAD_ARGUMENT, refusal
        # all four at once between two processing steps: the next tick runs the new gains, the loop's state on
        self.drive.retune(**{name: float(getattr(msg, name)) for name in sb.WRITE_LOOP_FIELDS})
        return None

    # --- running --------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self.state == sb.State.RUNNING

    @property
    def produced(self) -> int:
        """Samples played in this run."""
        return self._produced

    @property
    def _run_config(self) -> sb.Configure:
        """The CONFIGURE in force: a run and the sample blocks it sends are shaped by it.

        Raises
        ------
        RuntimeError
            The host has not configured the board (START refuses to run without it).
        """
        if self.config is None:
            raise RuntimeError("the board has no configuration: send CONFIGURE before a run")
        return self.config

    @property
    def sample_rate_hz(self) -> float:
        return self.identity.loop_rate_hz / self._run_config.sample_divider

    def advance(self, n_samples: int) -> None:
        """Play ``n_samples`` excitation samples through the drive and record them."""
        if not self.running or n_samples <= 0:
            return
        if self._run_samples:
            n_samples = min(n_samples, self._run_samples - self._produced)
        available = self._fifo_written - self._fifo_read
        k = min(n_samples, available)
        values = np.zeros(n_samples)
        if k:
            values[:k] = self._fifo[(self._fifo_read + np.arange(k)) % len(self._fifo)]
            self._fifo_read += k
            self._last_value = float(values[k - 1])
        if k < n_samples:
            # Nothing to play: hold (PROTOCOL.md section 6) and tell the host.
            held = self.underrun_value()
            values[k:] = held
            self.counters.underruns += n_samples - k
            self._pending_flags |= sb.FLAG_UNDERRUN
            if not self._in_underrun:
                self.send(
                    sb.Event(
                        sb.EventCode.UNDERRUN, self._produced + k, held, f"excitation buffer empty: holding {held:g}"
                    )
                )
            self._in_underrun = True
        elif k:
            self._in_underrun = False
        # sample, then update: a row holds the state at the start of its period, when its excitation begins
        first = self._produced
        played = self._player.play(values, first)
        self._produced += n_samples
        self._append(played.rows[:, self._selected_columns()])
        fault = self.drive.fault
        if fault:
            self._trip(first, fault)
        elif self._run_samples and self._produced >= self._run_samples:
            self._finish(sb.EventCode.FINISHED, "run complete")

    def underrun_value(self) -> float:
        """What the board plays when its excitation buffer is empty.

        A set-point (velocity, position) holds its last value: dropping it to
        zero would be a step the loops answer with a torque jump. An injected or
        open-loop torque drops to zero, the no-torque hold (holding a torque
        would keep accelerating the axis).
        """
        if self._run_config.mode in (sb.Mode.VELOCITY, sb.Mode.POSITION):
            return self._last_value
        return 0.0

    def idle(self, n_ticks: int) -> None:
        """Let the physics go on with the drive disabled (the axis coasts to rest)."""
        if not self.running and n_ticks > 0:
            self.drive.run(np.zeros(n_ticks))

    def _selected_columns(self) -> list[int]:
        return [self._column[c.channel] for c in self._run_config.channels]

    def _append(self, rows: np.ndarray) -> None:
        self._pending.append(rows)
        self._pending_rows += len(rows)
        block = self._run_config.block_samples
        while self._pending_rows >= block:
            data = np.concatenate(self._pending)
            self._emit(data[:block])
            rest = data[block:]
            self._pending = [rest] if len(rest) else []
            self._pending_rows = len(rest)

    def _emit(self, data: np.ndarray, extra_flags: int = 0) -> None:
        first = self._produced - self._pending_rows
        flags = self._pending_flags | extra_flags
        if self.fault != sb.FaultCode.NONE:
            flags |= sb.FLAG_FAULT
        _, clipped = sb.pack_rows(data, self._run_config.channels)
        if clipped:
            flags |= sb.FLAG_CLIPPED
        self.send(
            sb.Samples(
                self._block_index,
                first,
                flags,
                self._fifo_read,
                self._fifo_written - self._fifo_read,
                self.counters.underruns,
                data,
            )
        )
        self._block_index += 1
        self.sample_blocks_out += 1
        self._pending_flags = 0

    def _flush_last(self) -> None:
        """Send what is pending (possibly nothing) as the run's last block."""
        data = np.concatenate(self._pending) if self._pending else np.zeros((0, len(self._run_config.channels)))
        self._emit(data, sb.FLAG_LAST)
        self._pending, self._pending_rows = [], 0

    def _trip(self, first_sample: int, fault: str) -> None:
        """The drive tripped ``fault`` (a :data:`~hilident.emulator.drive.FAULTS` name) in this step."""
        self.fault = _FAULTS.get(fault, sb.FaultCode.TORQUE_LIMIT)
        self.counters.limit_trips += 1
        fault_sample = self._player.fault_sample()
        index = first_sample if fault_sample is None else fault_sample
        value = float(getattr(self.drive, "fault_value", 0.0) or 0.0)
        self.send(sb.Event(sb.EventCode.LIMIT_TRIP, index, value, f"{fault}: axis stopped, torque zero"))
        self._flush_last()
        self.state = sb.State.FAULT
        self._end_run()

    def _end_run(self) -> None:
        """Torque off; excitation left in the buffer is discarded, never replayed."""
        self.drive.disable()
        self._fifo_read = self._fifo_written = 0

    def _finish(self, code: sb.EventCode, message: str) -> None:
        self._flush_last()
        self.send(sb.Event(code, self._produced, 0.0, message))
        self._end_run()
        self.state = sb.State.CONFIGURED

    def watchdog_expired(self) -> None:
        """The host went silent while running: stop the axis."""
        if self.running:
            self.fault = sb.FaultCode.WATCHDOG
            self.send(sb.Event(sb.EventCode.WATCHDOG, self._produced, 0.0, "host silent: axis stopped"))
            self._flush_last()
            self._end_run()
            self.state = sb.State.FAULT

    def drop_block(self) -> None:
        """Record that the line could not take a sample block (the TX buffer was full)."""
        self.counters.dropped_blocks += 1
