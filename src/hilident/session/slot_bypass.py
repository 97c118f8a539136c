"""The device's filter slots while a session measures the bare plant: read, bypassed, put back.

Identification measures the plant without the filters the device already
runs: every enabled slot is bypassed first (its contents saved), and put
back when the session ends before its own upload.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["BypassedSlots"]


@dataclass
class BypassedSlots:
    """What the slots held when the session began (``found``) and what is bypassed until the upload.

    Attributes
    ----------
    found : list of dict
        Per slot ``{slot, enabled, b, a}`` (and ``bypassed``, ``restored`` once
        that happened), for the plan and ``summary.json["filters_found"]``.
    bypassed : dict
        Slot -> its saved contents (the adapter's ``save_filter``), until put back.
    """

    found: list[dict] = field(default_factory=list)
    bypassed: dict[int, object] = field(default_factory=dict)

    def read(self, adapter) -> None:
        """What every filter slot holds before the session changes anything."""
        self.found = []
        for slot in range(adapter.identity.filter_slots):
            biquad, enabled = adapter.read_filter(slot)
            self.found.append(
                {
                    "slot": slot,
                    "enabled": bool(enabled),
                    "b": [float(x) for x in biquad.b],
                    "a": [float(x) for x in biquad.a],
                }
            )

    def bypass(self, adapter, progress) -> None:
        """Bypass every slot that filters now, so identification measures the bare plant."""
        for found in self.found:
            if found["enabled"]:
                slot = found["slot"]
                saved = adapter.save_filter(slot)
                adapter.disable_filter(slot)
                self.bypassed[slot] = saved
                found["bypassed"] = True
        if self.bypassed:
            progress.step(f"filter slot(s) {sorted(self.bypassed)} bypassed while the plant is measured")

    def restore(self, adapter, warnings: list[str]) -> None:
        """Put back what the bypassed slots held; a slot that fails becomes a warning. Never raises."""
        for slot, saved in sorted(self.bypassed.items()):
            try:
                adapter.restore_filter(slot, saved)
                for found in self.found:
                    if found["slot"] == slot:
                        found["restored"] = True
            except Exception as exc:
                warnings.append(f"filter slot {slot}: could not restore its previous contents: {exc}")
        self.bypassed.clear()
