"""Drive-buffered runs on a CANopen drive: excitation table in, capture out, both over SDO.

1. The excitation (REAL32, the mode's SI unit; positions relative to the
   position at enable) is downloaded into the table object, by SDO block
   transfer when the driver description allows it, and its length read back.
2. The drive is enabled and the table started; it plays the table at its own
   sample rate, recording the mapped channels into its capture buffer.
3. While it plays, the host polls the table state and the capture count, sets
   the capture read offset and uploads the new records (block transfer), so
   the capture is home shortly after the table ends.
4. A capture shorter than the table (the drive's buffer ended early) is
   reported: the missing samples are counted, a ``capture_short`` event is
   logged, and the run ends with DeviceError after the captured samples were
   delivered. An emergency ends it with LimitTrip or DeviceError the same way.
"""

from __future__ import annotations

import time

import numpy as np

from hilident.adapters.base import RunResult, StreamStats
from hilident.errors import DeviceError
from hilident.protocol.canopen_objects import TABLE_START, TABLE_STOP, TableState, record_dtype

__all__ = ["run_buffered"]

_POLL_S = 0.05
_EMCY_WAIT_S = 0.3  # a table that stopped early: wait this long for the emergency that says why


def run_buffered(ad, x: np.ndarray, sink, progress=None) -> RunResult:
    """Play ``x`` from the drive's table behind adapter ``ad``; see the module docstring."""
    n = len(x)
    stats = StreamStats()
    result = RunResult(requested_samples=n, stats=stats)
    ad.last_result = result
    events = ad.events  # live: the session writes them to the recording while the run goes on
    d = ad.desc
    capacity = int(ad.read("table_capacity"))
    if n > capacity:
        raise DeviceError(
            f"{ad.port}: the excitation has {n} samples; the drive's table holds {capacity} "
            f"({ad.describe(d.address('table_capacity'))}); use device.acquisition = \"streamed\" or a shorter run")
    ad.write_domain(d.address("table"), np.asarray(x, dtype="<f4").tobytes())
    length = int(ad.read("table_length"))
    if length != n:
        raise DeviceError(f"{ad.port}: wrote {n} table samples, the drive holds {length} "
                          f"({ad.describe(d.address('table_length'))})")
    dtype = record_dtype([c.datatype for c in ad.channels])
    size = dtype.itemsize
    ad.enable()
    ad.write("table_command", TABLE_START)
    captured = 0
    last_change = time.monotonic()
    stall_limit = max(2.0, 2 * ad.timeout_s)
    fault = None
    state = TableState.PLAYING
    while True:
        while ad.emergencies and fault is None:
            event = ad.emergency_event(ad.emergencies.popleft(), captured)
            events.append(event)
            if event["kind"] != "emergency_reset":
                fault = event
                ad.note_fault(event)
                _stop_table(ad)  # an emergency stops the excitation, whatever the drive does on its own
        ad.check_link()
        state = int(ad.read("table_state"))
        count = int(ad.read("capture_count"))
        if count > captured:
            last_change = time.monotonic()
        while captured < count:
            ad.write("capture_offset", captured)
            data = ad.read_domain(d.address("capture_data"))
            m = len(data) // size
            if m == 0 or len(data) % size:
                raise DeviceError(f"{ad.port}: a capture chunk of {len(data)} bytes from "
                                  f"{ad.describe(d.address('capture_data'))} is not whole {size}-byte records")
            records = np.frombuffer(data, dtype=dtype)
            rows = ad.decode_rows([records[f"f{i}"] for i in range(len(ad.channels))])
            sink(np.arange(captured, captured + m, dtype=np.int64), rows)
            captured += m
            stats.samples += m
            if progress is not None:
                progress(min(1.0, captured / max(n, 1)))
        if state != TableState.PLAYING:
            break
        if time.monotonic() - last_change > stall_limit:
            raise DeviceError(f"{ad.port}: the capture stalled at {captured} of {n} samples for "
                              f"{stall_limit:g} s ({ad.describe(d.address('capture_count'))})")
        time.sleep(_POLL_S)
    if state == TableState.STOPPED and fault is None:
        deadline = time.monotonic() + _EMCY_WAIT_S
        while not ad.emergencies and time.monotonic() < deadline:
            time.sleep(0.01)
        while ad.emergencies and fault is None:
            event = ad.emergency_event(ad.emergencies.popleft(), captured)
            events.append(event)
            if event["kind"] != "emergency_reset":
                fault = event
                ad.note_fault(event)
    if fault is not None:
        raise ad.fault_error(fault)
    if state == TableState.STOPPED:
        result.fault = f"the drive stopped the table at sample {captured} without an emergency"
        raise DeviceError(f"{ad.port}: {result.fault} ({ad.describe(d.address('table_state'))})")
    if captured < n:
        stats.lost_samples += n - captured
        stats.lost_blocks += 1
        message = (f"the drive captured only {captured} of {n} samples "
                   f"({ad.describe(d.address('capture_count'))}): its capture ended early")
        events.append({"kind": "capture_short", "sample_index": captured, "value": float(n - captured),
                       "message": message})
        result.fault = message
        raise DeviceError(f"{ad.port}: {message}")
    events.append({"kind": "capture_end", "sample_index": n, "value": float(n),
                   "message": f"table played and {n} samples captured"})
    result.completed = True
    return result


def _stop_table(ad) -> None:
    try:
        ad.write("table_command", TABLE_STOP)
    except DeviceError:
        pass  # a drive in Fault may refuse; its power stage is off anyway
