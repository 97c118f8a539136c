"""An input shaper scheduled by position: its impulses follow a mode that moves along the travel.

Where a mode's frequency depends on where the axis is (a beam stiffer near its supports, a load that
changes with the stroke), a shaper designed for one position leaves vibration at the others, and one
designed for the whole range (:func:`fixed_for_range`) pays for its robustness with a longer, smoother
move. :class:`ScheduledShaper` designs the shaper again at every sample, for the mode at the position the
set-point commands then: ``y[n] = sum_i A_i(p_n) x(t_n - t_i(p_n))`` with ``p_n = x[n]``.

The set-point commands position ``x[n]`` now; the shaped set-point follows it by at most the shaper's
duration, and the tail that decides the residual vibration of a point-to-point move is shaped with the mode
where the move ends. The shaped set-point ends exactly where the unshaped one does: once ``x`` has been at
rest for the longest shaper's duration every delayed copy equals its end, and the amplitudes sum to 1.

Examples
--------
>>> schedule = ScheduledShaper("zv", [0.0, 1.0], [20.0, 30.0], [0.02, 0.02])
>>> round(schedule.at(0.5).frequency_hz, 6)
25.0
>>> y = schedule.apply(np.linspace(0.0, 1.0, 101), 1000.0)
>>> float(y[-1]), y.size > 101
(1.0, True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError
from hilident.motion.input_shapers import (
    MIN_RELATIVE_INTERVAL,
    TARGET_VIBRATION,
    Shaper,
    ShaperChoice,
    add_delayed_copies,
    choose_shaper,
    design_shaper,
    held_setpoint,
    residual_vibration,
)
from hilident.numbers import number

__all__ = ["RangeShaper", "ScheduleChoice", "ScheduledShaper", "fixed_for_range", "schedule_shaper"]


@dataclass(frozen=True)
class ScheduledShaper:
    """A shaper of one kind whose frequency and damping ratio follow a table over position.

    Attributes
    ----------
    kind : str
        The design (a key of :data:`hilident.motion.input_shapers.DESIGNS`).
    positions_m : ndarray
        Where the mode is known, m, strictly increasing.
    frequencies_hz : ndarray
        The mode's undamped natural frequency there, Hz; linear in between, held beyond the ends.
    damping_ratios : ndarray
        Its damping ratio there; likewise.

    Raises
    ------
    ConfigError
        Tables of different or zero length, positions not increasing, a frequency not above 0 or a damping
        ratio outside [0, 1), or one the kind is not designed for.
    """

    kind: str
    positions_m: np.ndarray
    frequencies_hz: np.ndarray
    damping_ratios: np.ndarray

    def __post_init__(self):
        p, f, z = (
            np.array(v, dtype=float).ravel() for v in (self.positions_m, self.frequencies_hz, self.damping_ratios)
        )
        if p.size == 0 or not (p.size == f.size == z.size):
            raise ConfigError("positions_m", "positions, frequencies and damping ratios must be tables of one length")
        if not (np.all(np.isfinite(p)) and np.all(np.diff(p) > 0)):
            raise ConfigError("positions_m", f"must be finite and strictly increasing, got {p.tolist()}")
        if not (np.all(np.isfinite(f)) and np.all(f > 0)):
            raise ConfigError("frequencies_hz", f"must be finite and > 0, got {f.tolist()}")
        if not (np.all(np.isfinite(z)) and np.all((z >= 0) & (z < 1))):
            raise ConfigError("damping_ratios", f"must lie in [0, 1), got {z.tolist()}")
        for v in (p, f, z):
            v.setflags(write=False)
        object.__setattr__(self, "positions_m", p)
        object.__setattr__(self, "frequencies_hz", f)
        object.__setattr__(self, "damping_ratios", z)
        for fi, zi in zip(f, z, strict=True):
            design_shaper(self.kind, float(fi), float(zi))  # the kind covers every damping ratio of the table

    def mode_at(self, position_m) -> tuple[np.ndarray, np.ndarray]:
        """``(frequency_hz, damping_ratio)`` at ``position_m`` (scalar or array), interpolated linearly."""
        p = np.asarray(position_m, dtype=float)
        return np.interp(p, self.positions_m, self.frequencies_hz), np.interp(p, self.positions_m, self.damping_ratios)

    def at(self, position_m: float) -> Shaper:
        """The shaper for the mode at ``position_m``, m."""
        f, z = self.mode_at(float(position_m))
        return design_shaper(self.kind, float(f), float(z))

    def relative_to(self, origin_m: float) -> ScheduledShaper:
        """The same schedule for a set-point given relative to ``origin_m`` (m): a move that starts at
        ``origin_m`` and is streamed from 0, as position set-points relative to where the axis stands are."""
        return ScheduledShaper(self.kind, self.positions_m - float(origin_m), self.frequencies_hz, self.damping_ratios)

    @property
    def longest_duration_s(self) -> float:
        """The longest of the table's shapers, s: how much later a shaped move ends at most."""
        return max(self.at(float(p)).duration_s for p in self.positions_m)

    def apply(self, x, sample_rate_hz: float) -> np.ndarray:
        """The set-point ``x`` (m) shaped with the shaper for the position it commands at each sample.

        Delays between samples interpolate linearly, as
        :meth:`~hilident.motion.input_shapers.Shaper.apply`; before its first sample the set-point is held
        at ``x[0]``, after its last at ``x[-1]``. The output is longer than ``x`` by the longest shaper's
        duration (whole samples, rounded up), and ends at ``x[-1]``.

        Parameters
        ----------
        x : array_like, shape (n,)
            Position set-point, m, at ``sample_rate_hz``.
        sample_rate_hz : float
            Hz (> 0).

        Returns
        -------
        ndarray
        """
        fs = number("sample_rate_hz", sample_rate_hz, strict=True)
        held = held_setpoint(x, self.longest_duration_s, fs)
        frequency, damping = self.mode_at(held)
        shaped = held.copy()
        # one design per distinct mode: a move has few (its rests), and every sample of one shares the impulses
        modes, which = np.unique(np.column_stack([frequency, damping]), axis=0, return_inverse=True)
        which = which.ravel()
        for k, (f, z) in enumerate(modes):
            shaper = design_shaper(self.kind, float(f), float(z))
            add_delayed_copies(shaped, held, np.flatnonzero(which == k), shaper.times_s, shaper.amplitudes, fs)
        return shaped

    def residual_at(self, positions_m) -> np.ndarray:
        """The residual vibration the scheduled shaper leaves at each position, a fraction of a unit impulse's:
        the shaper for that position against the mode there (the design's own, 0 for the zero-vibration kinds)."""
        out = []
        for p in np.atleast_1d(np.asarray(positions_m, dtype=float)):
            f, z = self.mode_at(p)
            out.append(float(residual_vibration(self.at(p), float(f), float(z))))
        return np.array(out)

    def table(self) -> list[dict]:
        """``[{"position_m", "frequency_hz", "damping_ratio"}, ...]``: the schedule, JSON-ready."""
        return [
            {"position_m": float(p), "frequency_hz": float(f), "damping_ratio": float(z)}
            for p, f, z in zip(self.positions_m, self.frequencies_hz, self.damping_ratios, strict=True)
        ]


def _table(modes: Sequence[dict]) -> tuple[np.ndarray, ...]:
    """Positions, frequencies, damping ratios and frequency half-widths (NaN: unknown) of ``modes``, sorted by
    position, duplicates of one position dropped."""
    rows = sorted(
        (
            float(m["position_m"]),
            float(m["frequency_hz"]),
            float(m["damping_ratio"]),
            float(m["frequency_ci95_hz"]) if m.get("frequency_ci95_hz") is not None else math.nan,
        )
        for m in modes
    )
    unique = [r for i, r in enumerate(rows) if i == 0 or r[0] > rows[i - 1][0]]
    if not unique:
        raise ConfigError("modes", "no mode over position to schedule a shaper with")
    return tuple(np.array(c) for c in zip(*unique, strict=True))


@dataclass(frozen=True)
class RangeShaper:
    """A shaper designed once for a mode over a range of positions, with what it leaves at each.

    Attributes
    ----------
    choice : ShaperChoice
        Every kind scored over the whole range of the mode's frequency and damping; the chosen first.
    positions_m : ndarray
        The positions it was checked at, m.
    residuals : ndarray
        Its residual vibration at each, for the mode there, a fraction.
    """

    choice: ShaperChoice
    positions_m: np.ndarray
    residuals: np.ndarray

    @property
    def shaper(self) -> Shaper:
        return self.choice.shaper

    @property
    def worst_residual(self) -> float:
        """The largest residual over the positions, a fraction."""
        return float(np.max(self.residuals))


def fixed_for_range(modes: Sequence[dict], target_vibration: float = TARGET_VIBRATION) -> RangeShaper:
    """The one shaper for a mode that moves over the travel: every kind designed at the middle of the range of
    the mode's frequency and scored over all of it (and over the range of its damping ratio), chosen as
    :func:`~hilident.motion.input_shapers.choose_shaper` does.

    Parameters
    ----------
    modes : sequence of dict
        ``position_m``, ``frequency_hz``, ``damping_ratio`` and optionally ``frequency_ci95_hz``: the mode
        along the travel (the map's joint model, or the mapped points).
    target_vibration : float
        Worst-case residual a shaper must stay at or below, a fraction.

    Returns
    -------
    RangeShaper
    """
    p, f, z, ci = _table(modes)
    ci = np.nan_to_num(ci, nan=0.0)
    lo, hi = float(np.min(f - ci)), float(np.max(f + ci))
    z_lo, z_hi = float(np.min(z)), float(np.max(z))
    middle = 0.5 * (lo + hi)
    choice = choose_shaper(
        [(middle, 0.5 * (z_lo + z_hi), 0.5 * (hi - lo), 0.5 * (z_hi - z_lo))], target_vibration=target_vibration
    )
    residuals = np.array([float(residual_vibration(choice.shaper, fi, zi)) for fi, zi in zip(f, z, strict=True)])
    return RangeShaper(choice, p, residuals)


@dataclass(frozen=True)
class ScheduleChoice:
    """The kind a scheduled shaper uses, and why.

    Attributes
    ----------
    schedule : ScheduledShaper
    worst_vibration : float
        The chosen kind's worst-case residual over each position's own 95 % band, a fraction.
    reason : str
    """

    schedule: ScheduledShaper
    worst_vibration: float
    reason: str


def schedule_shaper(modes: Sequence[dict], target_vibration: float = TARGET_VIBRATION) -> ScheduleChoice:
    """A shaper scheduled over the table ``modes`` (as :func:`fixed_for_range` takes), of the kind that, scored
    at each position over that position's own 95 % band (at least +-:data:`MIN_RELATIVE_INTERVAL`), keeps its
    worst case at or below ``target_vibration`` with the least smoothing; when none does, the one with the
    lowest worst case.

    The band at each position is what is not known about the mode there, not how far it moves: the schedule
    follows the move, so a shorter kind than :func:`fixed_for_range`'s usually does.
    """
    p, f, z, ci = _table(modes)
    worst: dict[str, float] = {}
    smoothing: dict[str, float] = {}
    for fi, zi, cii in zip(f, z, ci, strict=True):
        local = choose_shaper(
            [(float(fi), float(zi), None if math.isnan(cii) else float(cii), None)],
            target_vibration=target_vibration,
            min_relative_interval=MIN_RELATIVE_INTERVAL,
        )
        for score in local.candidates:
            worst[score.kind] = max(worst.get(score.kind, 0.0), score.worst_vibration)
            smoothing[score.kind] = max(smoothing.get(score.kind, 0.0), score.smoothing)
    usable = [k for k in worst if k in smoothing]
    passing = sorted((k for k in usable if worst[k] <= target_vibration), key=lambda k: smoothing[k])
    if passing:
        kind = passing[0]
        reason = (
            f"{kind}: the least smoothing of the {len(passing)} kinds whose worst case over each position's own "
            f"band stays at or below {100 * target_vibration:.0f} % ({100 * worst[kind]:.1f} %)"
        )
    else:
        kind = min(usable, key=lambda k: worst[k])
        reason = (
            f"{kind}: no kind stays at or below {100 * target_vibration:.0f} % over each position's own band; "
            f"this one leaves the least ({100 * worst[kind]:.1f} %)"
        )
    return ScheduleChoice(ScheduledShaper(kind, p, f, z), worst[kind], reason)
