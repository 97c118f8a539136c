"""The drive's control loop as numbers: its cascade, the open and closed loops it makes with the
identified plant, and their margins (pure: no I/O).

* :mod:`.cascade`: :class:`Cascade`, a drive's cascade as discrete transfer functions;
* :mod:`.margins`: :func:`loop_margins` and :func:`bandwidth_hz` of a loop's frequency response.

May import ``filters`` and ``errors`` only (pure).
"""

from hilident.control.cascade import Cascade
from hilident.control.margins import LoopMargins, bandwidth_hz, loop_margins

__all__ = ["Cascade", "LoopMargins", "bandwidth_hz", "loop_margins"]
