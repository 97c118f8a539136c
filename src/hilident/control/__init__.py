"""The drive's control loop as numbers: its cascade, the open and closed loops it makes with the
identified plant, and their margins (pure: no I/O).

* :mod:`.cascade`: :class:`Cascade`, a drive's cascade as discrete transfer functions;
* :mod:`.sampled`: :func:`loop_plant`, the plant the loop sees tick by tick from a response recorded at the
  sample rate;
* :mod:`.tuning`: :func:`~hilident.control.tuning.propose_gains`, the widest loops that keep stability targets;
* :mod:`.margins`: :func:`loop_margins` and :func:`bandwidth_hz` of a loop's frequency response.

May import ``filters`` and ``errors`` only (pure).
"""

from hilident.control.cascade import Cascade
from hilident.control.margins import LoopMargins, bandwidth_hz, loop_margins
from hilident.control.sampled import loop_plant

__all__ = ["Cascade", "LoopMargins", "bandwidth_hz", "loop_margins", "loop_plant"]
