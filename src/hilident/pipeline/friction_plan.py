"""Which legs extend the friction test: where one more pair of legs narrows the Coulomb and viscous intervals most.

After a round of the friction test the fit knows its points and its scatter.
:func:`plan_round` chooses the next round's legs from candidate speeds (those
measured and the midpoints between them): each pair of legs adds a point whose
information follows from the fitted curve's sensitivity at that speed
(:func:`hilident.ident.friction.sensitivity`), so the leg that narrows the 95 %
intervals of ``Fc`` and ``Fv`` most per second of test is taken first, until
the intervals are predicted within the target or the round's time is used.
A slow speed pins the Coulomb level (and the Stribeck hump, when the fit has
one), the fastest speeds the viscous slope; their legs are only as long as the
travel allows.

A leg already played is never played again: it would cover the same stretch
of the axis, and a disturbance periodic in position (cogging, a waviness of the
rail) would repeat in it instead of averaging out, so its points would not be
independent. A leg the travel cuts short is played once; the next rounds use
the speeds beside it.

Pure: no device, no recording (the session plays the legs,
:mod:`hilident.session.friction_test`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy import stats

from hilident.ident import friction as fr
from hilident.signals.ramp_legs import ramp_extent

__all__ = ["Leg", "LegRules", "RoundPlan", "candidate_speeds", "plan_round"]

#: A round aims below the target by this factor: the scatter was estimated from few points.
AIM = 0.85
#: How far (share of the speed) a steady point's mean speed may lie from its leg's (it lies within a few %).
STEADY_TOLERANCE = 0.1
#: Significant digits of a candidate speed (a speed measured at 0.24995 m/s is the leg played at 0.25).
_DIGITS = 3


@dataclass(frozen=True)
class Leg:
    """A pair of legs: ``speed_mps`` one way, then the other, each held ``hold_s`` at speed.

    Attributes
    ----------
    speed_mps : float
        Speed of the pair, m/s (> 0).
    hold_s : float
        Time at constant speed of each leg, s.
    """

    speed_mps: float
    hold_s: float


@dataclass(frozen=True)
class LegRules:
    """How an extension's legs are shaped and what bounds them.

    Attributes
    ----------
    accel_mps2 : float
        Acceleration of the ramps, m/s^2 (``friction_test.accel_mps2``).
    settle_s : float
        Start of each hold of the configured length left out of its window, s; a longer hold leaves out the
        same share of itself (:meth:`settle_for`).
    sample_rate_hz : float
        Set-point rate, Hz.
    travel_m : float
        Largest distance a leg may take the axis from where it starts, m.
    max_speed_mps : float
        Fastest speed a leg may run, m/s.
    min_hold_s : float
        Shortest hold of a leg, s (the configured ``hold_s``).
    """

    accel_mps2: float
    settle_s: float
    sample_rate_hz: float
    travel_m: float
    max_speed_mps: float
    min_hold_s: float

    def settle_for(self, hold_s: float) -> float:
        """Start of a hold of ``hold_s`` left out of its window, s: at least ``settle_s``, and the configured
        share of the hold.

        How long the axis takes to settle after a ramp depends on the plant (a heavier one rings
        longer); the longer legs of the later rounds let it settle longer instead of averaging its ringing.
        """
        return max(self.settle_s, self.settle_s / self.min_hold_s * hold_s)

    def extent(self, leg: Leg) -> tuple[int, float]:
        """Samples of the pair of legs and the largest excursion from its start, m."""
        return ramp_extent(
            [leg.speed_mps], leg.hold_s, self.accel_mps2, self.sample_rate_hz, self.settle_for(leg.hold_s)
        )

    def duration_s(self, leg: Leg) -> float:
        """Time the pair of legs takes, ramps included, s."""
        return self.extent(leg)[0] / self.sample_rate_hz

    def longest_hold_s(self, speed_mps: float, hold_s: float) -> float:
        """``hold_s``, or the longest hold below it (whole samples) whose leg keeps within ``travel_m``; 0: none.

        The travel of a leg is ``v (ramp + hold)``; the hold is shortened until it fits.
        """
        fs = self.sample_rate_hz
        n_hold = int(round(hold_s * fs))
        n_ramp = max(1, math.ceil(speed_mps / self.accel_mps2 * fs - 1e-9))
        fits = int(math.floor(self.travel_m * fs / speed_mps)) - n_ramp  # (n_ramp - 1 + n_hold) v / fs < travel
        n_hold = min(n_hold, fits)
        while (
            n_hold > int(round(self.settle_s * fs)) + 1 and self.extent(Leg(speed_mps, n_hold / fs))[1] >= self.travel_m
        ):
            n_hold -= 1
        hold = n_hold / fs
        return hold if hold >= self.min_hold_s - 0.5 / fs else 0.0


@dataclass(frozen=True)
class RoundPlan:
    """The legs of the next round and what they are predicted to achieve.

    Attributes
    ----------
    legs : tuple of Leg
        In the order they are played (empty: nothing useful fits).
    duration_s : float
        Time the legs take, s.
    predicted_percent : dict of str to float
        Predicted half-width of the 95 % interval of ``Fc`` and ``Fv`` after the round, % of the value.
    limited_by : str
        Why no leg was planned: ``"time"`` (none fits the time left), ``"travel"`` (no new
        leg fits the travel, or none would narrow the intervals); ``""`` when there are legs.
    shortened : tuple of float
        Speeds whose legs the travel held below the round's hold, m/s.
    """

    legs: tuple[Leg, ...]
    duration_s: float
    predicted_percent: dict[str, float]
    limited_by: str = ""
    shortened: tuple[float, ...] = ()


def _round_speed(v: float) -> float:
    return float(f"{v:.{_DIGITS}g}")


def candidate_speeds(played: Iterable[float], measured: Iterable[float], max_speed_mps: float) -> list[float]:
    """The speeds a round may run, m/s: those played that gave a steady point, and the midpoints between them.

    A played speed counts when a steady point was measured within
    :data:`STEADY_TOLERANCE` of it (slower legs that were not steady are not tried
    again); the midpoints are geometric, rounded to three digits. None is faster
    than ``max_speed_mps``.

    Examples
    --------
    >>> candidate_speeds([0.01, 0.02, 0.04, 0.08], [0.0199, 0.0401, 0.0799, 0.0802], 0.08)
    [0.02, 0.0283, 0.04, 0.0566, 0.08]
    """
    seen = np.asarray([abs(v) for v in measured], dtype=float)
    speeds = sorted(
        {
            v
            for v in (abs(float(u)) for u in played)
            if 0.0 < v <= max_speed_mps and np.any(np.abs(seen - v) <= STEADY_TOLERANCE * v)
        }
    )
    middles = {_round_speed(math.sqrt(a * b)) for a, b in zip(speeds, speeds[1:], strict=False)}
    return sorted(set(speeds) | {m for m in middles if speeds[0] < m < speeds[-1]})


class _Information:
    """The information matrix of the pooled points in the fit's free parameters, and the predicted intervals."""

    def __init__(self, fit: fr.FrictionFit, folded: fr.FoldedPoints, target_percent: float):
        self.fit = fit
        self.names = list(fr.free_parameters(fit))
        self.level_names = [n for n in ("Fc", "Fv") if n in self.names]
        self.levels = [self.names.index(n) for n in self.level_names]
        weights = np.asarray(folded.windows, dtype=float)
        jac = fr.sensitivity(fit, folded.speed)
        self.matrix = (jac * weights[:, None]).T @ jac
        resid = fit.predict(folded.speed) - folded.friction
        self.dof = fit.dof
        self.scale2 = float(weights @ resid**2) / max(fit.dof, 1)  # residual variance of a one-window point
        values = fit.params.to_dict()
        self.wanted = [target_percent / 100.0 * abs(values[self.names[j]]) for j in self.levels]

    def add(self, matrix: np.ndarray, speed: float) -> np.ndarray:
        """``matrix`` with one more pair of legs (two windows) at ``speed``."""
        g = fr.sensitivity(self.fit, [speed])[0]
        return matrix + 2.0 * np.outer(g, g)

    def ratios(self, matrix: np.ndarray, dof: int) -> list[float]:
        """Predicted half-width / wanted half-width of each level (inf without a degree of freedom)."""
        cov = np.linalg.pinv(matrix) * self.scale2
        t = float(stats.t.ppf(0.975, dof)) if dof >= 1 else math.inf
        out = []
        for j, wanted in zip(self.levels, self.wanted, strict=True):
            width = t * math.sqrt(max(cov[j, j], 0.0))
            out.append(width / wanted if wanted > 0 else math.inf)
        return out

    def cost(self, matrix: np.ndarray, dof: int, floor: float = AIM**2) -> float:
        """What is left to narrow: the squared ratios of :meth:`ratios`, none counted below ``floor``."""
        return sum(max(r * r, floor) for r in self.ratios(matrix, dof))


def plan_round(
    fit: fr.FrictionFit,
    folded: fr.FoldedPoints,
    played: set[Leg],
    rules: LegRules,
    hold_s: float,
    budget_s: float,
    target_percent: float,
    min_dof: int = 0,
) -> RoundPlan:
    """The legs of the next round of the friction test.

    Parameters
    ----------
    fit : FrictionFit
        The fit of every point so far (its structure decides which speeds inform which parameter).
    folded : FoldedPoints
        Those points, one per pair of legs or unpaired window.
    played : set of Leg
        Every leg played so far (none is played twice).
    rules : LegRules
        Shape of the legs, the travel and the fastest speed allowed.
    hold_s : float
        The round's hold, s: the travel may shorten it for the fastest speeds.
    budget_s : float
        Time the round may take, s.
    target_percent : float
        Wanted half-width of the 95 % intervals of ``Fc`` and ``Fv``, % of their values.
    min_dof : int
        Fewest residual degrees of freedom the intervals are to rest on after the round.

    Returns
    -------
    RoundPlan
    """
    info = _Information(fit, folded, target_percent)
    candidates = _candidates(folded, played, rules, hold_s)
    legs, matrix, dof = _choose(info, list(candidates.items()), budget_s, min_dof)
    limited = ""
    if not legs:  # nothing fits the time left, or no new leg within the travel narrows them
        limited = "time" if candidates and all(seconds > budget_s for seconds in candidates.values()) else "travel"
    ratios = info.ratios(matrix, dof)
    return RoundPlan(
        legs=tuple(sorted(legs, key=lambda leg: leg.speed_mps)),
        duration_s=sum(candidates[leg] for leg in legs),
        predicted_percent={name: r * target_percent for name, r in zip(info.level_names, ratios, strict=True)},
        limited_by=limited,
        shortened=tuple(sorted(leg.speed_mps for leg in legs if leg.hold_s < hold_s)),
    )


def _candidates(folded: fr.FoldedPoints, played: set[Leg], rules: LegRules, hold_s: float) -> dict[Leg, float]:
    """Each leg a round may play (not played before, its hold cut to the travel) and the time it takes, s."""
    out = {}
    for speed in candidate_speeds([leg.speed_mps for leg in played], folded.speed, rules.max_speed_mps):
        leg = Leg(speed, rules.longest_hold_s(speed, hold_s))
        if leg.hold_s > 0.0 and leg not in played:
            out[leg] = rules.duration_s(leg)
    return out


def _choose(info: _Information, candidates: list[tuple[Leg, float]], budget_s: float, min_dof: int):
    """The slowest and the fastest leg, then greedily the leg that lowers :meth:`_Information.cost` most per
    second, while the levels are not predicted within :data:`AIM` of the target (or rest on fewer than
    ``min_dof`` degrees of freedom) and a leg fits the time left; returns the legs, the information matrix
    and the degrees of freedom after them.

    Both ends are measured again each round, longer and settled longer than before: the ends are where
    Fc and Fv are decided, and the earlier rounds' points there are checked against them
    (:func:`hilident.pipeline.friction.first_round_differs`).
    """
    matrix, dof, left, legs = info.matrix, info.dof, budget_s, []
    ends = sorted(candidates, key=lambda c: c[0].speed_mps)
    for leg, seconds in {c[0]: c for c in (ends[:1] + ends[-1:])}.values():
        if seconds <= left:
            candidates.remove((leg, seconds))
            legs.append(leg)
            matrix, dof, left = info.add(matrix, leg.speed_mps), dof + 1, left - seconds
    while max(info.ratios(matrix, dof), default=0.0) > AIM or dof < min_dof:
        floor = AIM**2 if dof + 1 >= min_dof else 0.0  # short of points, every leg still counts
        cost = info.cost(matrix, dof + 1, floor)
        gains = [
            ((cost - info.cost(info.add(matrix, leg.speed_mps), dof + 1, floor)) / seconds, k)
            for k, (leg, seconds) in enumerate(candidates)
            if seconds <= left
        ]
        gain, best = max(gains, default=(0.0, -1))
        if gain <= 0.0:
            break
        leg, seconds = candidates.pop(best)
        legs.append(leg)
        matrix, dof, left = info.add(matrix, leg.speed_mps), dof + 1, left - seconds
    return legs, matrix, dof
