"""Host-streamed runs on a CANopen drive: an RPDO set-point and a SYNC every sample period.

For sample ``k`` the host sends the RPDO with the set-point and then SYNC; the
drive applies the set-point for the sample period that SYNC starts and answers
with its TPDOs (transmission type 1), carrying the state at the start of that
period. Which sample a TPDO belongs to is known in one of two ways:

* **counted**: on a drive with the hilident counters every TPDO is headed by
  the sample counter ``k`` (and the RPDO by the set-point counter), so each
  frame names its sample;
* **ordered** (every other CiA 402 drive, standard objects only): CAN keeps
  the order of frames, and a drive answers each SYNC with its TPDOs in PDO
  number order, so the answers form consecutive sets; a frame whose PDO
  number is not above the previous frame's starts the next set, and the
  ``n``-th set answers the ``n``-th SYNC. A set with a frame missing is a lost
  sample at a known index. A SYNC the drive did not answer at all (a whole set
  missing) shows only in the count: the samples after it shift by one, which the
  run reports (``sync_unanswered``) with the number of unanswered SYNCs; such
  samples are never filled in. Channels the drive does not report (the
  set-point, on drives without an applied-set-point object) are the host's own.

The host assembles a sample from its TPDOs:

* a sample whose TPDOs did not all arrive within ``window`` sample periods
  after its SYNC (at the end of the run: ``_GRACE_S`` after the last SYNC or
  the last new sample, whichever is later) is lost: counted (``lost_samples``, ``lost_blocks``, and
  ``lost_frames`` for the missing TPDOs), logged as a ``lost_blocks`` event,
  never filled in;
* a TPDO arriving after its sample was given up is late: counted as
  ``out_of_order`` and discarded;
* a SYNC the host sent more than one period late is counted in a
  ``sync_late`` event; set-points that reached the drive after their SYNC are
  the drive's ``underruns`` (read from its diagnostics at the end).

An emergency stops the SYNCs at once (the drive already switched its power
stage off); the samples up to the fault are delivered, then the run ends with
LimitTrip (a limit) or DeviceError. A lost heartbeat ends it with DeviceError,
and so do TPDOs lagging more than a second behind the SYNCs (the drive does not
keep up; flooding it further would only queue frames).
"""

from __future__ import annotations

import collections
import struct
import time

import numpy as np

from hilident.adapters.base import RunResult, StreamStats
from hilident.errors import DeviceError
from hilident.protocol.canopen_objects import numpy_type, type_bits

__all__ = ["run_streamed", "POSITION_SETPOINTS"]

#: Set-point roles that are positions (targets relative to where the axis holds at enable).
POSITION_SETPOINTS = ("target_position", "interpolation_data")

_GRACE_S = 0.25  # after the last SYNC (or an emergency), wait this long for the TPDOs in flight


def run_streamed(ad, x: np.ndarray, sink, progress=None) -> RunResult:
    """Play ``x`` on the drive behind adapter ``ad``, one SYNC per sample; see the module docstring."""
    n = len(x)
    stats = StreamStats()
    result = RunResult(requested_samples=n, stats=stats)
    ad.last_result = result
    events = ad.events  # live: the session writes them to the recording while the run goes on
    od = ad.node.object_dictionary
    counted = ad.desc.counted
    counter_char, counter_mod = "", 0
    if counted:
        counter_addr = ad.desc.address("sample_counter")
        counter_type = od.get_variable(counter_addr.index, counter_addr.subindex).data_type
        counter_char, counter_mod = numpy_type(counter_type).char, 1 << type_bits(counter_type)
    n_ch = len(ad.channels)
    frames = {}
    for rank, (cob, idx) in enumerate(ad.tpdo_layout):
        fmt = "<" + counter_char + "".join(numpy_type(ad.channels[i].datatype).char for i in idx)
        frames[cob] = (1 << rank, struct.Struct(fmt), np.asarray(idx, dtype=np.intp), rank)
    full = (1 << len(frames)) - 1
    scales = np.array([c.scale for c in ad.channels])
    raw = np.zeros((n, n_ch))
    for j, c in enumerate(ad.channels):
        if c.on_host:
            raw[:, j] = x  # the set-point the host sends, in SI units (scale 1)
    mask = np.zeros(n, dtype=np.uint32)
    answered = {"set": -1, "rank": len(frames)}  # ordered matching: the set being received, its last PDO

    rx = collections.deque()

    def on_tpdo(can_id, data, timestamp):
        rx.append((can_id, bytes(data)))

    rpdo_cob, rx_type, sp_type, sp_role = ad.rpdo
    if rx_type is not None:
        rx_mod = 1 << type_bits(rx_type)
        rpdo_struct = struct.Struct("<" + numpy_type(rx_type).char + numpy_type(sp_type).char)

        def rpdo_pack(k, value):
            return rpdo_struct.pack(k % rx_mod, value)
    else:
        rpdo_struct = struct.Struct("<" + numpy_type(sp_type).char)

        def rpdo_pack(k, value):
            return rpdo_struct.pack(value)
    period = 1.0 / (ad.sync_rate_hz or ad.sample_rate_hz)
    window = max(16, int(round(0.1 / period)))
    lag_limit = max(10 * window, int(round(1.0 / period)))  # the drive is not keeping up: stop flooding it
    overflow = ad.sync_overflow
    send = ad.network.send_message

    state = {"final": 0, "last_progress": 0.0}

    def finalize(limit: int, count_lost: bool = True) -> None:
        """Deliver complete samples below ``limit``; count the others as lost (or drop them silently)."""
        a = state["final"]
        if limit <= a:
            return
        seg = mask[a:limit]
        complete = seg == full
        idx = np.flatnonzero(complete) + a
        if len(idx):
            sink(idx.astype(np.int64), raw[idx] * scales)
            stats.samples += len(idx)
        if count_lost and not complete.all():
            missing = np.flatnonzero(~complete) + a
            stats.lost_samples += len(missing)
            stats.lost_blocks += len(missing)
            stats.lost_frames += int(sum(bin(full & ~int(m)).count("1") for m in mask[missing]))
            breaks = np.flatnonzero(np.diff(missing) != 1) + 1
            for run in np.split(missing, breaks):
                events.append({"kind": "lost_blocks", "sample_index": int(run[0]), "value": float(len(run)),
                               "message": f"{len(run)} sample(s) lost on the bus: samples {run[0]}..{run[-1]}"})
        state["final"] = limit
        if progress is not None and (limit == n or time.monotonic() - state["last_progress"] > 0.1):
            state["last_progress"] = time.monotonic()
            progress(min(1.0, limit / max(n, 1)))

    def drain(sent: int) -> int:
        """Sort received TPDOs into samples; returns the highest sample index seen."""
        top = -1
        ref = sent - 1
        final = state["final"]
        while rx:
            cob, data = rx.popleft()
            spec = frames.get(cob)
            if spec is None:
                continue
            bit, packer, idx, rank = spec
            if not counted:  # a PDO number not above the last one's starts the answer to the next SYNC
                if rank <= answered["rank"]:
                    answered["set"] += 1
                answered["rank"] = rank
            if len(data) < packer.size:
                stats.corrupt_frames += 1
                continue
            values = packer.unpack_from(data)
            if counted:
                k = ref - ((ref - values[0]) % counter_mod)
                values = values[1:]
            else:
                k = answered["set"]
                if k >= sent:
                    stats.corrupt_frames += 1  # an answer to a SYNC the host never sent: not this run's
                    continue
            if k < final or k < 0:
                stats.out_of_order += 1  # arrived after its sample was given up: late
                continue
            raw[k, idx] = values
            mask[k] |= bit
            top = max(top, k)
        return top

    def note_late_syncs() -> None:
        """The ``sync_late`` event (once): how many SYNCs went out more than a period late, the worst in s."""
        if late_syncs and not any(e["kind"] == "sync_late" for e in events):
            events.append({"kind": "sync_late", "sample_index": 0, "value": float(late_syncs),
                           "worst_s": float(worst_late),
                           "message": f"{late_syncs} SYNC(s) sent more than one period late "
                                      f"(worst {worst_late * 1e3:.2f} ms)"})

    for cob in frames:
        ad.network.subscribe(cob, on_tpdo)
    late_syncs, worst_late = 0, 0.0
    fault = None
    sent = 0
    try:
        # start from a harmless set-point: zero torque/speed/offset, or the present position in CSP and IP;
        # a torque offset injected in CSP or CSV is held by the present position or zero speed
        position = sp_role in POSITION_SETPOINTS
        ad.write(sp_role, int(ad.read("position_actual")) if position else 0)
        hold = ad.desc.modes[ad.mode].hold
        if hold:
            ad.write(hold, int(ad.read("position_actual")) if hold in POSITION_SETPOINTS else 0)
        ad.enable()
        origin = int(ad.read("position_actual")) if position else 0  # CSP targets: relative to where it holds
        setpoints = ad.encode_setpoints(x, sp_type, sp_role, origin).tolist()
        t0 = time.perf_counter() + 0.001
        ended = None
        top = -1
        heard_s = 0.0  # when the newest sample so far arrived
        while True:
            now = time.perf_counter()
            if fault is None:
                while sent < n and now >= t0 + sent * period:
                    late = now - (t0 + sent * period)
                    if late > period:
                        late_syncs += 1
                        worst_late = max(worst_late, late)
                    send(rpdo_cob, rpdo_pack(sent, setpoints[sent]))
                    send(0x80, bytes([sent % overflow + 1]) if overflow > 1 else b"")
                    sent += 1
            ad.beat_if_due()
            newest = drain(sent)
            if newest > top:
                top, heard_s = newest, now
            while ad.emergencies and fault is None:
                event = ad.emergency_event(ad.emergencies.popleft(), max(top, 0))
                events.append(event)
                if event["kind"] != "emergency_reset":
                    fault = event
                    ad.note_fault(event)
                    ended = now
            if fault is not None:
                last = min(sent, fault["sample_index"] + 1)
                if now - ended > _GRACE_S or mask[state["final"]:last].min(initial=full) == full:
                    finalize(last)
                    finalize(min(sent, top + 1), count_lost=False)
                    break
            else:
                ad.check_link()
                if sent - 1 - top > lag_limit:
                    raise DeviceError(f"{ad.port}: the drive's TPDOs lag {sent - 1 - top} samples behind the SYNCs "
                                      f"(more than {lag_limit * period:.2g} s): it does not keep up with "
                                      f"{1 / period:g} SYNC/s")
                if sent == n:
                    ended = ended or now
                    # the grace runs from the last SYNC or the last new sample, whichever is later: a drive
                    # still answering the last SYNCs is slow, not silent
                    if now - max(ended, heard_s) > _GRACE_S or mask[state["final"]:].min(initial=full) == full:
                        finalize(n)
                        break
                else:
                    finalize(sent - window)
            wait = t0 + sent * period - time.perf_counter()
            time.sleep(min(max(wait, 0.0), 0.005) if sent < n and fault is None else 0.002)
        note_late_syncs()
        if fault is None and not counted:
            unanswered = sent - 1 - answered["set"]
            if unanswered > 0:
                events.append({"kind": "sync_unanswered", "sample_index": int(answered["set"] + 1),
                               "value": float(unanswered),
                               "message": f"{unanswered} SYNC(s) got no TPDO at all: the drive skipped them or "
                                          "their answers were lost; matched by order, the samples after such a SYNC "
                                          "are shifted, so the run's last samples are counted lost"})
        if fault is None and counted:
            stats.underruns = int(ad.read("setpoint_underruns"))
            sync_errors = int(ad.read("sync_errors"))
            if sync_errors:
                events.append({"kind": "sync_errors", "sample_index": 0, "value": float(sync_errors),
                               "message": f"the drive saw {sync_errors} SYNC counter jump(s)"})
        result.completed = fault is None
    except BaseException:
        note_late_syncs()  # a run that broke off says how late its SYNCs went out too
        try:
            drain(sent)
            finalize(sent - window)  # long overdue: lost
            finalize(sent, count_lost=False)  # still in flight when the run broke off
        except Exception:
            pass
        raise
    finally:
        for cob in frames:
            try:
                ad.network.unsubscribe(cob, on_tpdo)
            except (KeyError, ValueError):
                pass
    if fault is not None:
        raise ad.fault_error(fault)
    return result
