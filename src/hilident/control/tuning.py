"""Gains proposed against stability targets: the widest loop the plant allows at the margins asked.

Drive tuners (Kollmorgen's Performance Servo Tuner, Beckhoff's TE5960, Siemens'
One Button Tuning) search the gains that give the highest bandwidth while the
loop keeps its gain margin, phase margin and sensitivity peak. This module does
that on the plant the loop sees (:class:`~hilident.control.Cascade` and its
``H``), one loop after the other as a drive is tuned: the velocity PI first
(``K_v`` and ``T_i`` over a grid, the position loop open), then the position
gain ``K_p`` with the velocity loop as chosen.

The targets hold on every plant given: the identified one and, for a robust
proposal, the same plant with its modes moved to the ends of their 95 %
intervals. A loop that meets the targets on all of them and has the highest
bandwidth of its set-point's response on the worst of them is proposed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hilident.control.cascade import Cascade
from hilident.control.margins import LoopMargins, bandwidth_hz, loop_margins

__all__ = ["PRESETS", "Proposal", "Targets", "propose_gains"]


@dataclass(frozen=True)
class Targets:
    """What a proposed loop must keep.

    Attributes
    ----------
    gain_margin_db : float
        Smallest gain margin, dB.
    phase_margin_deg : float
        Smallest phase margin, degrees.
    sensitivity_peak : float
        Largest ``Ms`` (1).
    """

    gain_margin_db: float
    phase_margin_deg: float
    sensitivity_peak: float

    def met_by(self, m: LoopMargins) -> bool:
        """Whether margins ``m`` keep every target (a loop without a crossover keeps no phase margin)."""
        return (
            m.gain_margin_db >= self.gain_margin_db
            and math.isfinite(m.phase_margin_deg)
            and m.phase_margin_deg >= self.phase_margin_deg
            and m.sensitivity_peak <= self.sensitivity_peak
        )

    def to_dict(self) -> dict:
        return {
            "gain_margin_db": self.gain_margin_db,
            "phase_margin_deg": self.phase_margin_deg,
            "sensitivity_peak": self.sensitivity_peak,
        }


#: The presets of ``[tuning] preset``: the stiffest loop first.
PRESETS = {
    "stiff": Targets(8.0, 45.0, 2.0),
    "medium": Targets(10.0, 50.0, 1.7),
    "soft": Targets(12.0, 60.0, 1.4),
}


@dataclass(frozen=True)
class Proposal:
    """The gains proposed for one cascade, and what they give on the worst plant.

    Attributes
    ----------
    cascade : Cascade
        The cascade with the proposed ``kv_nm_per_mps``, ``ti_s`` and ``kp_pos_per_s``.
    velocity, position : LoopMargins
        The loops' margins on the worst plant.
    velocity_bandwidth_hz, position_bandwidth_hz : float
        The set-point responses' half-power bandwidths on the worst plant, Hz.
    """

    cascade: Cascade
    velocity: LoopMargins
    position: LoopMargins
    velocity_bandwidth_hz: float
    position_bandwidth_hz: float

    def gains(self) -> dict:
        c = self.cascade
        return {"kv_nm_per_mps": c.kv_nm_per_mps, "ti_s": c.ti_s, "kp_pos_per_s": c.kp_pos_per_s}


def _worst(
    cascade: Cascade,
    f: np.ndarray,
    plants: Sequence[np.ndarray],
    loop: str,
    targets: Targets,
    max_crossover_hz: float = math.inf,
):
    """``(margins, bandwidth)`` on the worst of ``plants`` when all keep ``targets`` with their crossover at or
    below ``max_crossover_hz``; None otherwise."""
    worst = None
    for h in plants:
        m = loop_margins(f, cascade.open_loop(f, h, loop))
        if not targets.met_by(m) or m.crossover_hz > max_crossover_hz:
            return None
        bw = bandwidth_hz(f, cascade.closed_loop(f, h, loop))
        if not math.isfinite(bw):
            return None
        if worst is None or bw < worst[1]:
            worst = (m, bw)
    return worst


def propose_gains(
    cascade: Cascade,
    frequency_hz,
    plants: Sequence[np.ndarray],
    targets: Targets,
    kv_range: tuple[float, float] | None = None,
    points: int = 36,
    max_crossover_hz: float = math.inf,
) -> Proposal | None:
    """The gains with the widest loops that keep ``targets`` on every plant.

    Parameters
    ----------
    cascade : Cascade
        The drive's cascade as it is (its filters, rates, delay and current loop stay).
    frequency_hz : array_like
        A dense grid, Hz, up to near half the loop rate.
    plants : sequence of ndarray
        ``H`` (motor torque to encoder position, tick by tick) at ``frequency_hz``: the identified plant and
        its variants.
    targets : Targets
    kv_range : (float, float), optional
        The velocity gains searched, N·m per (m/s); default a hundredth to a hundred times the present one.
    points : int
        Grid points of each gain.
    max_crossover_hz : float
        The highest gain crossover a loop may have, Hz: the top of the band the plant was measured in (beyond it
        the plant is an extrapolation a proposal must not rest on); ``inf``: none.

    Returns
    -------
    Proposal or None
        None when no gain on the grid keeps the targets.
    """
    f = np.asarray(frequency_hz, dtype=float)
    hs = [np.asarray(h) for h in plants]
    kv0 = cascade.kv_nm_per_mps if cascade.kv_nm_per_mps > 0 else 1.0
    low, high = kv_range or (kv0 / 100.0, kv0 * 100.0)

    def velocity(kv: float, ti: float):
        trial = cascade.with_gains(kv_nm_per_mps=kv, ti_s=ti)
        worst = _worst(trial, f, hs, "velocity", targets, max_crossover_hz)
        return None if worst is None else (worst[1], trial, worst[0])

    # integral corners from 0.8 Hz to 0.8 kHz
    grid = [
        (float(kv), float(ti)) for kv in np.geomspace(low, high, points) for ti in np.geomspace(2e-4, 0.2, points // 2)
    ]
    best_velocity = _refined(velocity, grid, steps=(high / low) ** (1 / (points - 1)))
    if best_velocity is None:
        return None
    velocity_bw, velocity_cascade, velocity_margins = best_velocity

    def position(kp: float, _: float):
        trial = velocity_cascade.with_gains(kp_pos_per_s=kp)
        worst = _worst(trial, f, hs, "position", targets, max_crossover_hz)
        return None if worst is None else (worst[1], trial, worst[0])

    top = velocity_bw * 2 * math.pi
    kps = [(float(kp), 0.0) for kp in np.geomspace(top / 100, top, points)]
    best_position = _refined(position, kps, steps=100 ** (1 / (points - 1)), second=False)
    if best_position is None:
        return None
    position_bw, position_cascade, position_margins = best_position
    return Proposal(position_cascade, velocity_margins, position_margins, velocity_bw, position_bw)


def _refined(score, grid: list[tuple[float, float]], steps: float, second: bool = True, rounds: int = 5):
    """The best ``score(a, b)`` (a tuple whose first item is maximised; None: infeasible) over ``grid``, then
    refined around it by halving log steps in both (or only the first) coordinates."""
    best, where = None, None
    for a, b in grid:
        got = score(a, b)
        if got is not None and (best is None or got[0] > best[0]):
            best, where = got, (a, b)
    if best is None or where is None:
        return best
    step = steps
    for _ in range(rounds):
        step = math.sqrt(step)
        a0, b0 = where
        for a, b in [(a0 * step, b0), (a0 / step, b0)] + ([(a0, b0 * step), (a0, b0 / step)] if second else []):
            got = score(a, b)
            if got is not None and got[0] > best[0]:
                best, where = got, (a, b)
    return best
