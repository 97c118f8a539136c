"""Whether gains keep the loop stable on the identified plant and on its uncertainty, before they are written.

A closed loop changes from stable to unstable only where a pole crosses the
unit circle, that is where ``1 + L`` passes through zero. The drive runs its
present gains stably; on the way from them to the new ones (each gain moved
geometrically, in :data:`PATH_STEPS` steps) the loops (the velocity loop broken
at the torque, the position loop at the velocity set-point) must keep ``L``
away from -1 (``|1 + L| > 1 / MS_LIMIT``) on the plant the loop sees and on
its variants (the modes at the ends of their 95 % intervals). Margins read
from a Bode plot alone cannot say this for a loop that crosses 0 dB more than
once, as one around a lightly damped mode does. A change that fails is
refused with the margins it would leave; one that is stable but misses the
``[tuning]`` targets is allowed with a warning, as a tuner's manual override
is. Without the present gains the margins decide (both positive).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hilident.control import Cascade, loop_margins
from hilident.control.tuning import Targets
from hilident.pipeline.loop_plant import SeenPlant

__all__ = ["GainCheck", "check_gains"]

LOOPS = ("velocity", "position")
#: Steps from the present gains to the new ones.
PATH_STEPS = 40
#: A loop whose sensitivity exceeds this anywhere on the way is taken as crossing into instability.
MS_LIMIT = 20.0


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
    closest: float = math.nan

    @property
    def stable(self) -> bool:
        """Whether the loops stay stable: ``|1 + L|`` kept above ``1 / MS_LIMIT`` from the present gains to
        these (without the present gains: every loop keeps positive margins on every plant)."""
        if math.isfinite(self.closest):
            return self.closest > 1.0 / MS_LIMIT
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
        way = (
            f"; on the way from the present gains the loops come within {self.closest:.3g} of -1"
            if math.isfinite(self.closest)
            else ""
        )
        return f"the {w['loop']} loop with {gm}, {pm}, Ms {w['sensitivity_peak']:.2f} on {plant}{way}"

    def to_dict(self) -> dict:
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {
            "gains": dict(self.gains),
            "stable": self.stable,
            "closest_to_minus_one": clean(self.closest),
            "meets_targets": self.meets_targets,
            "worst": {k: clean(v) for k, v in self.worst().items()},
            "rows": [{k: clean(v) for k, v in r.items()} for r in self.rows],
        }


def check_gains(
    cascade: Cascade, seen: SeenPlant, targets: Targets | None = None, present: Cascade | None = None
) -> GainCheck:
    """The margins of ``cascade`` (the gains and filters the drive would hold) on ``seen`` and its variants, and
    how close the loops come to -1 on the way from ``present`` (the gains the drive runs) to them."""
    below_nyquist = seen.frequency_hz < cascade.loop_rate_hz / 2
    f = seen.frequency_hz[below_nyquist]
    plants = [np.asarray(h)[below_nyquist] for h in [seen.response, *seen.variants]]
    rows = []
    for i, h in enumerate(plants):
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
    closest = math.nan if present is None else _closest_on_the_way(present, cascade, f, plants)
    return GainCheck(gains, rows, targets, closest)


def _between(a: float, b: float, t: float) -> float:
    """A fraction ``t`` of the way from ``a`` to ``b``: geometric for two positive values, else linear (an
    infinite integral time moves in its reciprocal)."""
    if math.isinf(a) or math.isinf(b):
        ra, rb = (0.0 if math.isinf(x) else 1.0 / x for x in (a, b))
        r = ra + t * (rb - ra)
        return math.inf if r == 0 else 1.0 / r
    if a > 0 and b > 0:
        return a * (b / a) ** t
    return a + t * (b - a)


def _closest_on_the_way(present: Cascade, new: Cascade, f: np.ndarray, plants: list[np.ndarray]) -> float:
    """The smallest ``|1 + L|`` of either loop, on any plant, from ``present``'s gains to ``new``'s."""
    closest = math.inf
    for t in np.linspace(0.0, 1.0, PATH_STEPS + 1):
        step = new.with_gains(
            **{
                k: _between(getattr(present, k), getattr(new, k), float(t))
                for k in ("kv_nm_per_mps", "ti_s", "kp_pos_per_s")
            }
        )
        for h in plants:
            for loop in LOOPS:
                distance = np.abs(1.0 + step.open_loop(f, h, loop))
                closest = min(closest, float(np.nanmin(distance)))
    return closest
