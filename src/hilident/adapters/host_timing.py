"""The host's side of a timed run: what keeps the interpreter from holding up the threads that meet a clock.

A streamed run has threads that must act within a fraction of a sample
period: the one that sends SYNC on the host's clock, the ones that receive
frames and answer the device's clock. Two things in CPython hold every thread
up at once: a full garbage collection, which walks every object the process
holds (on a session that has recorded for a while, tens to over a hundred
milliseconds, longer than a CANopen drive's SYNC loss timeout), and the
interval at which a thread waiting for the interpreter lock is let in (5 ms
by default). :func:`timely_host` collects once before the run, freezes what
exists then (:func:`gc.freeze`: later collections walk only the run's own
objects) and shortens the switch interval, and undoes both when the run ends.
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["SWITCH_INTERVAL_S", "timely_host"]

#: Interpreter switch interval during a timed run, s: a thread waiting for the lock gets it within about this.
SWITCH_INTERVAL_S = 1e-4


@contextmanager
def timely_host() -> Iterator[None]:
    """Within the block: no full collection walks the objects made before it, and threads switch every 0.1 ms."""
    switch = sys.getswitchinterval()
    gc.collect()
    gc.freeze()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(switch)
        gc.unfreeze()
