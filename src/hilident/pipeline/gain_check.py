"""Whether gains keep the loop stable on the identified plant and on its uncertainty, before they are written.

A gain change goes to a drive only when both loops it closes (the velocity
loop broken at the torque, the position loop at the velocity set-point) keep
a positive gain and phase margin on the plant the loop sees and on its
variants (the modes at the ends of their 95 % intervals). A change that does
not is refused with the margin it would leave; one that is stable but misses
the ``[tuning]`` targets is allowed with a warning, as a tuner's manual
override is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hilident.control import Cascade, loop_margins
from hilident.control.tuning import Targets
from hilident.pipeline.loop_plant import SeenPlant

__all__ = ["GainCheck", "check_gains"]

LOOPS = ("velocity", "position")


@dataclass(frozen=True)
class GainCheck:
    """The margins a cascade's gains leave on every plant.

    Attributes
    ----------
    gains : dict
        The gains checked, SI units.
    rows : list of dict
        One per plant and loop: ``plant`` (0: the identified one, then its variants), ``loop``,
        ``gain_margin_db``, ``phase_margin_deg``, ``sensitivity_peak``, ``stable``.
    targets : Targets or None
    """

    gains: dict
    rows: list[dict]
    targets: Targets | None

    @property
    def stable(self) -> bool:
        """Whether every loop keeps positive margins on every plant."""
        return all(r["stable"] for r in self.rows)

    @property
    def meets_targets(self) -> bool | None:
        """Whether every loop keeps the targets on every plant (None: no targets)."""
        if self.targets is None:
            return None
        t = self.targets
        return all(
            r["gain_margin_db"] >= t.gain_margin_db
            and r["phase_margin_deg"] >= t.phase_margin_deg
            and r["sensitivity_peak"] <= t.sensitivity_peak
            for r in self.rows
        )

    def worst(self) -> dict:
        """The row with the smallest margin (gain margin in dB against phase margin in tens of degrees)."""
        return min(self.rows, key=lambda r: min(r["gain_margin_db"], r["phase_margin_deg"] / 10.0))

    def describe(self) -> str:
        """One line: the smallest margins the gains leave, and on which plant."""
        w = self.worst()
        plant = "the identified plant" if w["plant"] == 0 else "the plant with its modes at an end of their interval"
        gm = "no gain margin limit" if math.isinf(w["gain_margin_db"]) else f"gain margin {w['gain_margin_db']:.1f} dB"
        pm = "no crossover" if math.isinf(w["phase_margin_deg"]) else f"phase margin {w['phase_margin_deg']:.1f} deg"
        return f"the {w['loop']} loop keeps {gm}, {pm}, Ms {w['sensitivity_peak']:.2f} on {plant}"

    def to_dict(self) -> dict:
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {
            "gains": dict(self.gains),
            "stable": self.stable,
            "meets_targets": self.meets_targets,
            "worst": {k: clean(v) for k, v in self.worst().items()},
            "rows": [{k: clean(v) for k, v in r.items()} for r in self.rows],
        }


def check_gains(cascade: Cascade, seen: SeenPlant, targets: Targets | None = None) -> GainCheck:
    """The margins of ``cascade`` (the gains and filters the drive would hold) on ``seen`` and its variants."""
    f = seen.frequency_hz
    rows = []
    for i, h in enumerate([seen.response, *seen.variants]):
        for loop in LOOPS:
            m = loop_margins(f, cascade.open_loop(f, h, loop))
            rows.append(
                {
                    "plant": i,
                    "loop": loop,
                    "gain_margin_db": m.gain_margin_db,
                    "phase_margin_deg": m.phase_margin_deg,
                    "sensitivity_peak": m.sensitivity_peak,
                    "stable": m.gain_margin_db > 0 and m.phase_margin_deg > 0,
                }
            )
    gains = {"kv_nm_per_mps": cascade.kv_nm_per_mps, "ti_s": cascade.ti_s, "kp_pos_per_s": cascade.kp_pos_per_s}
    return GainCheck(gains, rows, targets)
