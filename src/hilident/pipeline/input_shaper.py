"""The input shaper the measured resonances favour, and whether the measurement favours it, a notch, or both
(``summary.json["input_shaper"]``).

Every kind of shaper (:mod:`hilident.motion.input_shapers`) is designed for the resonances and scored over
their 95 % intervals (:func:`~hilident.motion.input_shapers.choose_shaper`). A notch and a shaper act on
different things: the notch on everything the drive's loop feeds the mode (disturbances, the loop's own
excitation), the shaper on the commanded moves only, at the price of its duration on every move. Which the
measurement favours follows from what the notch costs the drive's loop, where the drive describes it
(``summary.json["loop"]``), and where the strongest mode lies against the velocity loop's crossover:

* where the loop's figures with the notch are known and a loop (velocity or position) keeps less than
  ``MIN_PHASE_MARGIN_DEG`` of phase margin with it, having lost more than ``PHASE_LOST_DEG``: the shaper,
  which leaves the loop alone;
* else, below ``NOTCH_COSTS_PHASE_BELOW`` times the velocity loop's crossover, a notch takes phase where the
  loop needs it: the shaper;
* above, the notch costs the loop little: both, the notch for the loop and the shaper for the moves;
* no loop described: both, the measurement alone does not tell which matters more.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from hilident.errors import ConfigError
from hilident.motion.input_shapers import choose_shaper, max_acceleration
from hilident.motion.scheduled_shaper import RangeShaper, ScheduleChoice, fixed_for_range, schedule_shaper
from hilident.numbers import finite_or_none

__all__ = [
    "MIN_PHASE_MARGIN_DEG",
    "NOTCH_COSTS_PHASE_BELOW",
    "PHASE_LOST_DEG",
    "MoveShaper",
    "MoveShapers",
    "input_shaper_part",
    "measured_modes",
    "move_shapers",
]

#: A notch centred below this multiple of the velocity loop's crossover costs the loop phase margin it needs
#: (a notch's phase lag reaches about an octave beyond its centre).
NOTCH_COSTS_PHASE_BELOW = 2.0
#: A loop left with less phase margin than this with the notch, deg ...
MIN_PHASE_MARGIN_DEG = 30.0
#: ... having lost more than this to it, deg, is one the notch costs too much.
PHASE_LOST_DEG = 5.0

Mode = tuple[float, float, float | None, float | None]


def measured_modes(records: list[dict]) -> list[Mode]:
    """``(frequency_hz, damping_ratio, frequency_ci95_hz, damping_ci95)`` of resonance or mode records (as
    ``summary.json`` lists them), strongest first (largest ``peak_magnitude_db`` where given); records without
    a frequency or with a damping ratio outside [0, 1) are left out."""
    modes = [
        (
            float(r["frequency_hz"]),
            float(r["damping_ratio"]),
            finite_or_none(r.get("frequency_ci95_hz")),
            finite_or_none(r.get("damping_ci95")),
            float(r.get("peak_magnitude_db") or 0.0),
        )
        for r in records
        if r.get("frequency_hz") and r.get("damping_ratio") is not None and 0.0 <= float(r["damping_ratio"]) < 1.0
    ]
    modes.sort(key=lambda m: -m[4])
    return [m[:4] for m in modes]


def _crossover_hz(loop: dict | None) -> float | None:
    """The velocity loop's gain crossover without a notch, Hz, where the summary's loop part gives one."""
    figures = ((loop or {}).get("velocity") or {}).get("without_notch") or {}
    value = figures.get("crossover_hz")
    return float(value) if value is not None and math.isfinite(float(value)) else None


def _margin_lost(loop: dict | None) -> str | None:
    """The loop the notch leaves with too little phase margin, as a phrase; None when none (or not known)."""
    for name in ("velocity", "position"):
        parts = (loop or {}).get(name) or {}
        before = (parts.get("without_notch") or {}).get("phase_margin_deg")
        after = (parts.get("with_notch") or {}).get("phase_margin_deg")
        if before is None or after is None or not (math.isfinite(before) and math.isfinite(after)):
            continue
        if after < MIN_PHASE_MARGIN_DEG and before - after > PHASE_LOST_DEG:
            return f"the {name} loop's phase margin falls from {before:.0f} to {after:.0f} deg with the notch"
    return None


def _versus_notch(f_hz: float, duration_s: float, loop: dict | None) -> tuple[str, str]:
    """``(favoured, why)``: ``"shaper"`` or ``"both"``, and one sentence."""
    cost = f"{1e3 * duration_s:.1f} ms on every move"
    lost = _margin_lost(loop)
    if lost is not None:
        return "shaper", f"{lost}: the shaper leaves the loop alone ({cost}), the notch costs it the margin it needs"
    crossover_hz = _crossover_hz(loop)
    if crossover_hz is None:
        return "both", (
            "no loop described: the notch acts on everything the drive's loop feeds the mode, the shaper on the "
            f"commanded moves only ({cost}); the measurement alone does not tell which matters more"
        )
    if f_hz < NOTCH_COSTS_PHASE_BELOW * crossover_hz:
        return "shaper", (
            f"the mode at {f_hz:.2f} Hz lies within {NOTCH_COSTS_PHASE_BELOW:g} times the velocity loop's crossover "
            f"({crossover_hz:.1f} Hz), where a notch costs the loop phase margin: the shaper leaves the loop alone "
            f"({cost})"
        )
    return "both", (
        f"the mode at {f_hz:.2f} Hz lies above {NOTCH_COSTS_PHASE_BELOW:g} times the velocity loop's crossover "
        f"({crossover_hz:.1f} Hz): the notch costs the loop little and keeps it from ringing the mode; the shaper "
        f"keeps the commanded moves from exciting it ({cost})"
    )


def input_shaper_part(resonances: list[dict], loop: dict | None = None) -> dict | None:
    """``summary.json["input_shaper"]`` for the ``resonances`` (records as the summary lists them); None when
    there is none to shape.

    Returns
    -------
    dict or None
        ``modes``; ``chosen`` (its ``kind``, ``times_s``, ``amplitudes``, ``duration_s``,
        ``worst_vibration``, ``smoothing_m``, ``max_accel_mps2``), ``reason``, ``target_vibration``; every
        ``candidates`` kind's figures; ``favoured`` (``"shaper"`` or ``"both"``) and ``versus_notch`` (why).
    """
    modes = measured_modes(resonances)
    if not modes:
        return None
    try:
        choice = choose_shaper(modes)
    except ConfigError as exc:  # no kind covers the modes' damping (a very damped mode needs no shaper)
        return {"modes": _mode_records(modes), "chosen": None, "reason": str(exc), "candidates": []}
    chosen = choice.chosen.as_dict()
    favoured, why = _versus_notch(modes[0][0], chosen["duration_s"], loop)
    return {
        "modes": _mode_records(modes),
        "chosen": chosen,
        "reason": choice.reason,
        "target_vibration": choice.target_vibration,
        "candidates": [
            {k: v for k, v in c.as_dict().items() if k not in ("times_s", "amplitudes")} for c in choice.candidates
        ],
        "favoured": favoured,
        "versus_notch": why,
    }


def _mode_records(modes: list[Mode]) -> list[dict]:
    return [
        {"frequency_hz": f, "damping_ratio": z, "frequency_ci95_hz": fci, "damping_ci95": zci}
        for f, z, fci, zci in modes
    ]


@dataclass(frozen=True)
class MoveShaper:
    """An input shaper the move test makes the same move with.

    Attributes
    ----------
    name : str
        ``"fixed shaper"`` (one shaper for the whole travel), ``"scheduled shaper"`` (following the map), or
        either followed by ``" and notch"``.
    shaper : Shaper or ScheduledShaper
        Anything with ``apply(x, sample_rate_hz)`` and ``at(position_m)`` or a ``kind``.
    max_accel_mps2 : float or None
        The largest acceleration whose smoothing stays within Klipper's target, m/s^2 (None: unlimited).
    with_notch : bool
        The notch acts as well, where the move test puts it (the set-point, or the drive's filter slots);
        else the drive's notch is out of the way.
    """

    name: str
    shaper: object
    max_accel_mps2: float | None
    with_notch: bool = False

    @property
    def tag(self) -> str:
        """The word the recordings are named with: ``fixed``, ``scheduled`` or ``both``."""
        return "both" if self.with_notch else self.name.split()[0]

    def for_move_from(self, start_m: float):
        """The shaper for a set-point that starts at ``start_m`` (m) and is given relative to it: a scheduled one
        moved into the move's coordinates, a fixed one as it is."""
        relative_to = getattr(self.shaper, "relative_to", None)
        return relative_to(start_m) if callable(relative_to) else self.shaper

    def design_at(self, position_m: float):
        """The shaper that acts where a move ends at ``position_m`` (the schedule's there, else the one)."""
        at = getattr(self.shaper, "at", None)
        return at(position_m) if callable(at) else self.shaper


def _accel_limit(value: float) -> float | None:
    return None if math.isinf(value) else float(value)


@dataclass(frozen=True)
class MoveShapers:
    """The shapers the move test makes its moves with, and what they are predicted to leave along the travel.

    Attributes
    ----------
    fixed : MoveShaper or None
        One shaper for every move: designed for the mapped range of the mode (``ranged``), else chosen for the
        run's resonances. None: no kind covers the modes' damping.
    scheduled : MoveShaper or None
        The shaper following the map's mode along the travel (None without a map).
    ranged : RangeShaper or None
        The fixed shaper's design over the mapped range, with its residual at every position of the table.
    schedule : ScheduleChoice or None
        The scheduled shaper's kind and why.
    """

    fixed: MoveShaper | None
    scheduled: MoveShaper | None
    ranged: RangeShaper | None = None
    schedule: ScheduleChoice | None = None

    def wanted(self, names: Sequence[str]) -> list[MoveShaper]:
        """The shapers among ``names`` (``"fixed"``, ``"scheduled"``, ``"both"``: the scheduled one, else the fixed
        one, with the notch) that could be designed, in that order."""
        best = self.scheduled or self.fixed
        found = {
            "fixed": self.fixed,
            "scheduled": self.scheduled,
            "both": None if best is None else replace(best, name=f"{best.name} and notch", with_notch=True),
        }
        return [s for name in ("fixed", "scheduled", "both") if name in names and (s := found[name]) is not None]

    def over_travel(self) -> dict | None:
        """``summary.json["input_shaper"]["over_travel"]``: the fixed and the scheduled shaper along the mapped
        travel (None without a map)."""
        if self.ranged is None or self.schedule is None:
            return None
        ranged, schedule = self.ranged, self.schedule.schedule
        scheduled_residuals = schedule.residual_at(ranged.positions_m)
        chosen = ranged.choice.chosen
        return {
            "frequency_range_hz": [float(np.min(schedule.frequencies_hz)), float(np.max(schedule.frequencies_hz))],
            "fixed": {
                "kind": chosen.kind,
                "frequency_hz": float(np.atleast_1d(chosen.shaper.frequency_hz)[0]),
                "damping_ratio": float(np.atleast_1d(chosen.shaper.damping_ratio)[0]),
                "duration_s": chosen.shaper.duration_s,
                "max_accel_mps2": _accel_limit(chosen.max_accel_mps2),
                "worst_residual": ranged.worst_residual,
                "reason": ranged.choice.reason,
            },
            "scheduled": {
                "kind": schedule.kind,
                "longest_duration_s": schedule.longest_duration_s,
                "max_accel_mps2": self.scheduled.max_accel_mps2 if self.scheduled is not None else None,
                "worst_residual": float(np.max(scheduled_residuals)),
                "worst_vibration": self.schedule.worst_vibration,
                "reason": self.schedule.reason,
                "table": schedule.table(),
            },
            "residuals": [
                {"position_m": float(p), "fixed": float(a), "scheduled": float(b)}
                for p, a, b in zip(ranged.positions_m, ranged.residuals, scheduled_residuals, strict=True)
            ],
        }


def move_shapers(resonances: list[dict], mapped: list[dict]) -> MoveShapers:
    """The fixed and the scheduled shaper for the move test.

    Parameters
    ----------
    resonances : list of dict
        The run's resonances (as :func:`measured_modes` reads them): the fixed shaper's modes without a map.
    mapped : list of dict
        The mode along the travel (``position_m``, ``frequency_hz``, ``damping_ratio``, optionally
        ``frequency_ci95_hz``), from the map's joint model; fewer than two positions: no map, no schedule.

    Returns
    -------
    MoveShapers
    """
    usable = [m for m in mapped if m.get("frequency_hz") and m.get("damping_ratio") is not None]
    if len({m["position_m"] for m in usable}) >= 2:
        try:
            ranged, schedule = fixed_for_range(usable), schedule_shaper(usable)
        except ConfigError:  # no kind covers the mode's damping along the travel
            return MoveShapers(None, None)
        plan = schedule.schedule
        limits = [max_acceleration(plan.at(float(p))) for p in plan.positions_m]
        return MoveShapers(
            MoveShaper("fixed shaper", ranged.shaper, _accel_limit(ranged.choice.chosen.max_accel_mps2)),
            MoveShaper("scheduled shaper", plan, _accel_limit(min(limits))),
            ranged,
            schedule,
        )
    modes = measured_modes(resonances)
    if not modes:
        return MoveShapers(None, None)
    try:
        chosen = choose_shaper(modes).chosen
    except ConfigError:
        return MoveShapers(None, None)
    return MoveShapers(MoveShaper("fixed shaper", chosen.shaper, _accel_limit(chosen.max_accel_mps2)), None)
