"""A drive's filter slots as an adapter reaches them (read, save, disable, restore), without a device."""

from __future__ import annotations

from types import SimpleNamespace

from hilident.filters.biquad import Biquad


class FakeSlots:
    """Filter slots ``0 .. count - 1``; ``enabled`` maps the slots that filter to their section.

    ``node_id`` and ``identity`` (``filter_slots``, ``loop_rate_hz``) are what a session reads of an adapter.
    """

    def __init__(self, enabled: dict[int, Biquad], count: int = 2, node_id: int = 1):
        self.node_id = node_id
        self.identity = SimpleNamespace(filter_slots=count, loop_rate_hz=4000.0)
        self.slots = {k: (enabled.get(k, Biquad.identity()), k in enabled) for k in range(count)}

    def read_filter(self, slot):
        return self.slots[slot]

    def save_filter(self, slot):
        return self.slots[slot]

    def disable_filter(self, slot):
        self.slots[slot] = (self.slots[slot][0], False)

    def restore_filter(self, slot, saved):
        self.slots[slot] = saved
