"""The emulated drive's own signal generator and data recorder, as its driver description declares them.

Built from ``[canopen.recorder]`` and ``[canopen.generator]``
(:mod:`hilident.protocol.canopen_recorder`) on the objects of the drive's EDS,
and run by the drive's clock like a vendor drive's firmware runs them:

* the recorder's channel-selection objects take CiA 301 mapping entries; only
  sampled signals (the objects of sensor and loop values, and the generator's
  output object) are accepted, others are refused with SDO abort 0x06040041;
* starting the recorder (its control object) checks the sample period against
  the allowed ones and the sample count against ``max_samples``; it then waits
  for its trigger (immediately, or the generator's start) and records one
  sample every ``sample_period`` loop cycles, the state at the start of that
  cycle, until it holds ``samples``;
* starting the generator (Operation Enabled only) reads its kind, target and
  parameters as stored and adds its output, tick by tick, to the set-point its
  target names (target torque, torque offset or target velocity); it stops at
  the end of its duration, when stopped, or when the power stage goes off;
* the buffer objects (one interleaved DOMAIN, or one per channel) serve the
  recorded samples by SDO (block upload), little-endian, in the channels' types.

The fault switch ``capture_stops_after_s`` ends the recording early (a short
buffer: the recorder says done with fewer samples than asked).
"""

from __future__ import annotations

import math
import time

import numpy as np
from canopen.sdo import SdoAbortedError

from hilident.emulator.canopen.host import FirmwareHost
from hilident.emulator.canopen.roles import COLUMN_OF_ROLE
from hilident.emulator.canopen.sdo import (
    ABORT_NO_DATA,
    ABORT_NOT_MAPPABLE,
    ABORT_STATE,
    ABORT_TOO_HIGH,
    ABORT_TOO_LOW,
    ABORT_VALUE,
)
from hilident.emulator.clock import SimClock, cut_at
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import (
    NUMERIC_TYPES,
    encode_si,
    parse_mapping_entry,
    record_dtype,
    type_bits,
)
from hilident.protocol.canopen_recorder import (
    GeneratorKind,
    GeneratorSpec,
    RecorderCapability,
    generator_output,
)
from hilident.protocol.canopen_types import ObjectAddress

__all__ = ["DriveRecorder"]


class DriveRecorder:
    """Generator and recorder of one emulated drive (see the module docstring).

    Parameters
    ----------
    firmware : CanopenDriveFirmware
        The drive it belongs to: its object dictionary, scales, drive loop and clock.
    cap : RecorderCapability
    """

    def __init__(self, firmware: FirmwareHost, cap: RecorderCapability):
        self.fw = firmware
        self.cap = cap
        self.rec = cap.recorder
        self.gen = cap.generator
        self.addresses = set(cap.objects().values())
        self.rec_state = self.rec.states["idle"]
        self.gen_state = self.gen.states["idle"] if self.gen else 0
        self.layout: list[tuple[ObjectAddress, int]] = []  # (object, data type) of the channels being recorded
        self.data: list[bytearray] = []
        self.count = 0
        self.period = 1
        self.samples = 0
        self.recording_from: int | None = None  # generator tick of the first recorded sample
        self.gen_tick = 0  # loop cycles the drive's clock ran since the generator (or the recording) started
        self.gen_start = 0  # the tick the generator started at
        self.gen_settings: tuple[GeneratorKind, str, dict[str, float]] | None = None  # (kind, target role, SI values)
        self.pacing = SimClock(firmware.loop_rate, firmware.time_scale)  # one generator tick per loop tick
        self.stopped_early = False

    # --- object dictionary ---------------------------------------------------------------------

    def owns(self, addr: ObjectAddress) -> bool:
        return addr in self.addresses

    def on_read(self, addr: ObjectAddress):
        """Live value of an object of the recorder or generator (None: the stored value)."""
        r, g = self.rec, self.gen
        if addr == r.state:
            return self.rec_state
        if addr == r.recorded:
            return self.count
        if addr in r.buffers:
            return self._buffer(r.buffers.index(addr))
        if g is not None and addr == g.state:
            return self.gen_state
        if g is not None and addr == g.output:
            return self._output_raw(g, addr, self._output_now())[0].item()
        return None

    def on_write(self, addr: ObjectAddress, value) -> None:
        r, g = self.rec, self.gen
        if addr == r.control:
            self._recorder_command(int(value))
        elif addr in r.channels or addr in (r.trigger, r.sample_period, r.samples):
            if self.rec_state in (r.states["waiting"], r.states["recording"]):
                raise SdoAbortedError(ABORT_STATE)  # the set-up is fixed while it records
            if addr in r.channels and int(value):
                self._channel(int(value))
            bad = {
                r.trigger: lambda v: v not in r.triggers.values(),
                r.sample_period: lambda v: v not in r.sample_periods,
                r.samples: lambda v: not 1 <= v <= r.max_samples,
            }.get(addr)
            if bad is not None and bad(int(value)):
                raise SdoAbortedError(ABORT_VALUE)
        elif g is not None and addr == g.control:
            self._generator_command(g, int(value))
        elif g is not None:
            if self.gen_state == g.states["running"]:
                raise SdoAbortedError(ABORT_STATE)  # parameters are fixed while it plays
            self._check_generator_value(g, addr, int(value))

    def _check_generator_value(self, g: GeneratorSpec, addr: ObjectAddress, value: int) -> None:
        """A kind or target code the generator does not know, or a parameter out of its range: refused."""
        if addr == g.kind and value not in {k.code for k in g.kinds.values()}:
            raise SdoAbortedError(ABORT_VALUE)
        if addr == g.target and value not in g.targets.values():
            raise SdoAbortedError(ABORT_VALUE)
        for kind in g.kinds.values():
            for name, p in kind.parameters.items():
                if p.address != addr:
                    continue
                si = value if name in ("register_length", "clock_divider") else value * self._scale(p.scale)
                tol = 1e-9 * max(1.0, abs(si))
                if (p.minimum is not None and si < p.minimum - tol) or (p.maximum is not None and si > p.maximum + tol):
                    raise SdoAbortedError(ABORT_TOO_HIGH if p.maximum is not None and si > p.maximum else ABORT_TOO_LOW)

    def _stored(self, addr) -> int:
        return int(self.fw.stored(addr.index, addr.subindex))

    def _channel(self, entry: int) -> tuple[ObjectAddress, int]:
        """The (address, data type) a mapping entry selects; SDO abort when it is not a sampled signal."""
        addr, bits = parse_mapping_entry(entry)
        obj = self.fw.od.get_variable(addr.index, addr.subindex)
        role = self.fw.role_of.get(addr)
        sampled = role in COLUMN_OF_ROLE or (self.gen is not None and addr == self.gen.output)
        if obj is None or obj.data_type not in NUMERIC_TYPES or bits != type_bits(obj.data_type) or not sampled:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        return addr, obj.data_type

    # --- recorder --------------------------------------------------------------------------------

    def _recorder_command(self, command: int) -> None:
        r = self.rec
        if command == r.commands["stop"]:
            if self.rec_state in (r.states["waiting"], r.states["recording"]):
                self.rec_state = r.states["done"]
            return
        if command != r.commands["start"]:
            raise SdoAbortedError(ABORT_VALUE)
        period, samples = self._stored(r.sample_period), self._stored(r.samples)
        trigger = self._stored(r.trigger)
        if period not in r.sample_periods or not 1 <= samples <= r.max_samples or trigger not in r.triggers.values():
            raise SdoAbortedError(ABORT_VALUE)
        layout = [self._channel(e) for e in (self._stored(a) for a in r.channels) if e]
        if not layout:
            raise SdoAbortedError(ABORT_STATE)
        immediate = trigger == r.triggers["immediate"]
        if immediate and self.fw.state is not cia402.State.OPERATION_ENABLED:
            raise SdoAbortedError(ABORT_STATE)  # the loop, and so the recorder's clock, runs when enabled
        self.layout, self.period, self.samples = layout, period, samples
        self.data = [bytearray() for _ in layout]
        self.count = 0
        self.stopped_early = False
        self.recording_from = None
        if immediate:
            if not self.active:
                self._start_clock()
            self.recording_from = self.gen_tick
            self.rec_state = r.states["recording"]
        else:
            self.rec_state = r.states["waiting"]

    def _buffer(self, i: int) -> bytes:
        if not self.count:
            raise SdoAbortedError(ABORT_NO_DATA)
        if not self.rec.interleaved:
            return bytes(self.data[i])
        records = np.empty(self.count, dtype=record_dtype([t for _, t in self.layout]))
        for j, (_, _t) in enumerate(self.layout):
            records[f"f{j}"] = np.frombuffer(bytes(self.data[j]), dtype=records.dtype[j])
        return records.tobytes()

    # --- generator -------------------------------------------------------------------------------

    def _generator_command(self, g: GeneratorSpec, command: int) -> None:
        if command == g.commands["stop"]:
            self.gen_state = g.states["idle"]  # from running or done
            return
        if command != g.commands["start"]:
            raise SdoAbortedError(ABORT_VALUE)
        if self.fw.state is not cia402.State.OPERATION_ENABLED or self.gen_state == g.states["running"]:
            raise SdoAbortedError(ABORT_STATE)
        settings = self._generator_settings(g)
        if not self.active:
            self._start_clock()
        self.gen_settings = settings
        self.gen_state = g.states["running"]
        self.gen_start = self.gen_tick
        if self.rec_state == self.rec.states["waiting"]:
            self.rec_state = self.rec.states["recording"]
            self.recording_from = self.gen_tick

    def _generator_settings(self, g: GeneratorSpec) -> tuple[GeneratorKind, str, dict[str, float]]:
        """(kind, target role, SI parameter values) as stored; SDO abort when the generator cannot play them."""
        code = self._stored(g.kind) if g.kind is not None else next(iter(g.kinds.values())).code
        kind = next((k for k in g.kinds.values() if k.code == code), None)
        target = next((role for role, c in g.targets.items() if c == self._stored(g.target)), None)
        if kind is None or target is None or not self.fw.desc.has(target):
            raise SdoAbortedError(ABORT_VALUE)
        if target != "torque_offset" and not self._mode_takes(target):
            raise SdoAbortedError(ABORT_STATE)  # a torque (velocity) set-point is the loop's input in CST (CSV) only
        values: dict[str, float] = {}
        for name, p in kind.parameters.items():
            raw = self._stored(p.address)
            values[name] = raw if name in ("register_length", "clock_divider") else raw * self._scale(p.scale)
        if kind.name == "prbs" and (values["clock_divider"] < 1 or values["register_length"] not in kind.taps):
            raise SdoAbortedError(ABORT_VALUE)  # a register this firmware has no sequence for
        return kind, target, values

    def _mode_takes(self, target: str) -> bool:
        """The selected mode of operation takes its set-point from the object of role ``target``."""
        spec = self.fw.setpoints.mode_spec
        if self.fw.desc.explicit_modes:
            return spec is not None and spec.setpoint == target
        return {"target_torque": 10, "target_velocity": 9}.get(target) == self.fw.setpoints.mode_code

    def stop_generator(self) -> None:
        if self.gen is not None and self.gen_state == self.gen.states["running"]:
            self.gen_state = self.gen.states["idle"]

    def _scale(self, scale) -> float:
        if not isinstance(scale, str):
            return float(scale)
        role = {"torque": "target_torque", "velocity": "target_velocity", "position": "target_position"}[scale]
        return self.fw.desc.scale(role, self.fw.rated_torque_nm, self.fw.rated_current_a)

    def _playing(self) -> tuple[GeneratorKind, str, dict[str, float]] | None:
        """The settings the generator plays, None while it does not."""
        g = self.gen
        if g is None or self.gen_settings is None or self.gen_state != g.states["running"]:
            return None
        return self.gen_settings

    def _output_now(self) -> float:
        settings = self._playing()
        if settings is None:
            return 0.0
        kind, _, values = settings
        return float(generator_output(kind, values, np.array([self.gen_tick - self.gen_start]), self.fw.loop_rate)[0])

    def _output_raw(self, g: GeneratorSpec, output: ObjectAddress, si) -> np.ndarray:
        """``si`` in the type and scale of the generator's output object ``output``."""
        obj = self.fw.od.get_variable(output.index, output.subindex)
        if obj is None or obj.data_type is None:  # parse_recorder checked the EDS has it
            raise RuntimeError(f"{self.cap.source}: the generator's output object {output} is not in the EDS")
        return encode_si(np.atleast_1d(si), obj.data_type, self._scale(g.output_scale))

    # --- the clock ---------------------------------------------------------------------------------

    def _start_clock(self) -> None:
        self.gen_tick = 0
        self.pacing.start_run(time.monotonic())
        self.fw.start_run()

    @property
    def active(self) -> bool:
        g_running = self.gen is not None and self.gen_state == self.gen.states["running"]
        return g_running or self.rec_state == self.rec.states["recording"]

    def tick(self, now: float) -> None:
        """Advance generator, drive loop and recorder to wall time ``now`` (at the drive's time scale).

        Called by the drive's clock while Operation Enabled; with the power
        stage off the generator stops and the recorder ends what it holds.
        """
        fw = self.fw
        if fw.state is not cia402.State.OPERATION_ENABLED:
            self.stop_generator()
            if self.rec_state == self.rec.states["recording"]:
                self.rec_state = self.rec.states["done"]
            return
        if not self.active:
            return
        due = self.pacing.samples_due(now, self.gen_tick, fw.loop_rate)
        due = cut_at(self.gen_tick, due, fw.pending_fault_times(), fw.loop_rate)  # stop where a fault is due
        if due <= 0:
            return
        ticks = self.gen_tick + np.arange(due)
        g = self._played(ticks)
        rows = self._run(g)
        self._record(ticks, rows, g)
        self.gen_tick += due
        fw.sample_index = self.gen_tick // max(1, self.period)
        fw.last_row = rows[-1]
        fw.check_faults()
        settings = self._playing()
        if settings is not None and self.gen is not None:
            _, _, values = settings
            if "duration_s" in values and self.gen_tick - self.gen_start >= round(values["duration_s"] * fw.loop_rate):
                self.gen_state = self.gen.states["done"]

    def _played(self, ticks: np.ndarray) -> np.ndarray:
        settings = self._playing()
        if settings is None:
            return np.zeros(len(ticks))
        kind, _, values = settings
        return generator_output(kind, values, ticks - self.gen_start, self.fw.loop_rate)

    def _run(self, g: np.ndarray) -> np.ndarray:
        """The drive loop over ``len(g)`` cycles with the generator's output added to its target set-point."""
        fw = self.fw
        base = fw.setpoints.drive_input()  # also loads the host's torque offset into the loop
        target = self.gen_settings[1] if self.gen_settings is not None else ""
        if target != "torque_offset":
            return fw.drive.run(base + g)
        offset = fw.drive.torque_offset_nm
        rows = []
        edges = np.flatnonzero(np.diff(g)) + 1
        try:
            for seg in np.split(np.arange(len(g)), edges):
                fw.drive.torque_offset_nm = offset + g[seg[0]]
                rows.append(fw.drive.run(np.full(len(seg), base)))
        finally:
            fw.drive.torque_offset_nm = offset
        return np.concatenate(rows)

    def _record(self, ticks: np.ndarray, rows: np.ndarray, g: np.ndarray) -> None:
        if self.rec_state != self.rec.states["recording"] or self.recording_from is None:
            return
        rel = ticks - self.recording_from
        pick = np.flatnonzero((rel >= 0) & (rel % self.period == 0))[: self.samples - self.count]
        stop_after = self.fw.faults.capture_stops_after_s
        if stop_after:
            limit = math.ceil(stop_after * self.fw.loop_rate / self.period)
            pick = pick[: max(0, limit - self.count)]
            if self.count + len(pick) >= limit:
                self.stopped_early = True
        fw = self.fw
        for j, (addr, dtype) in enumerate(self.layout):
            if self.gen is not None and addr == self.gen.output:
                raw = self._output_raw(self.gen, addr, g[pick])
            else:
                role = fw.role_of[addr]
                raw = encode_si(rows[pick, fw.columns[_column(role)]], dtype, fw.scales.get(role, 1.0))
            self.data[j] += raw.tobytes()  # little-endian, in the channel's type
        self.count += len(pick)
        if self.count >= self.samples or self.stopped_early:
            self.rec_state = self.rec.states["done"]


def _column(role: str) -> str:
    return COLUMN_OF_ROLE[role]
