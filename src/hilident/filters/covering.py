"""One notch for a mode that moves over the workspace, or a position-scheduled set when one cannot hold.

A map of the resonance over the travel gives, per position, the mode's
frequency ``f`` and the half-width ``ci`` of its 95 % interval.  The mode can
then lie anywhere in ``[min(f - ci), max(f + ci)]``.  :func:`covering_notch`
designs one notch for that whole range:

* centre at the geometric mean of the range's ends (where an analog notch
  attenuates both ends equally);
* depth ``target_attenuation_db + depth_margin_db``: a notch only reaches the
  target off-centre when it is deeper than the target at its centre, and 20 dB
  more leaves the width within 0.5 % of that of an infinitely deep notch;
* width from the closed form :func:`~hilident.filters.notch.width_for_attenuation_hz`,
  then checked on the section the device will run (``realise``, by default the
  pre-warped Tustin design) on a grid over the range, and widened by a
  bracketing search when that section falls short (quantisation).

The worst case over the range, not the best, is what is reported.  A notch
wider than ``max_width_ratio`` times its centre eats the phase margin, so when
the range needs more, the result says so and offers a position-scheduled set:
the modes in frequency order split into as few consecutive groups as there must
be for each group's notch to meet the target, for devices with several filter
slots or switchable filter sets.

How wide is wide: an attenuation of 20 dB over +-8 % needs a notch whose -3 dB
width is about 1.7 times its centre (``|H| ~ delta / sqrt(delta^2 + zeta_p^2)``
off the centre by the fraction ``delta``, so ``zeta_p ~ 10 delta``).

Examples
--------
>>> modes = [{"position_m": p, "frequency_hz": f, "frequency_ci95_hz": 0.05}
...          for p, f in [(0.1, 20.0), (0.5, 21.0), (0.9, 22.0)]]
>>> result = covering_notch(modes, 4000.0, max_width_ratio=1.5)
>>> result.kind, result.groups[0].worst_attenuation_db >= 20.0
('single', True)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch, width_for_attenuation_hz
from hilident.numbers import number

__all__ = ["CoveringResult", "MappedMode", "NotchGroup", "covering_notch", "mapped_modes"]

#: Steps of the bisection on the width when the realised section falls short of the closed form.
_BISECTION_STEPS = 30


@dataclass(frozen=True)
class MappedMode:
    """The mode at one position of the map.

    Attributes
    ----------
    frequency_hz : float
        Identified frequency, Hz.
    frequency_ci95_hz : float
        Half-width of its 95 % interval, Hz (0 when exactly known).
    position_m : float or None
        Where it was measured, m (or rad); ``None`` when the map does not say.
    """

    frequency_hz: float
    frequency_ci95_hz: float
    position_m: float | None = None

    @property
    def low_hz(self) -> float:
        """Lower end of the 95 % interval, Hz."""
        return self.frequency_hz - self.frequency_ci95_hz

    @property
    def high_hz(self) -> float:
        """Upper end of the 95 % interval, Hz."""
        return self.frequency_hz + self.frequency_ci95_hz


def _field(entry: Any, name: str, where: str, required: bool = True) -> Any:
    if isinstance(entry, Mapping):
        if name in entry:
            return entry[name]
    elif hasattr(entry, name):
        return getattr(entry, name)
    if required:
        raise DataError(f"{where}: has no {name}")
    return None


def _finite(value: Any, name: str, where: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise DataError(f"{where}.{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise DataError(f"{where}.{name} must be finite, got {value!r}")
    return x


def mapped_modes(entries: Iterable[Any]) -> list[MappedMode]:
    """Check a map of modes and return it as :class:`MappedMode` records.

    Parameters
    ----------
    entries : iterable
        Mappings (the ``map`` entries of ``summary.json``) or objects with
        ``frequency_hz`` and ``frequency_ci95_hz`` (Hz) and optionally
        ``position_m``.

    Raises
    ------
    DataError
        An empty map, a missing field, a frequency that is not positive and
        finite, or an interval that is NaN, negative or reaches 0 Hz; the
        message names the entry (``map[i]``) and its position.
    """
    modes = []
    for i, entry in enumerate(entries):
        where = f"map[{i}]"
        raw_position = _field(entry, "position_m", where, required=False)
        position = None if raw_position is None else _finite(raw_position, "position_m", where)
        if position is not None:
            where += f" (position_m = {position:g})"
        f = _finite(_field(entry, "frequency_hz", where), "frequency_hz", where)
        ci = _finite(_field(entry, "frequency_ci95_hz", where), "frequency_ci95_hz", where)
        if f <= 0.0:
            raise DataError(f"{where}.frequency_hz must be positive, got {f!r}")
        if not 0.0 <= ci < f:
            raise DataError(f"{where}.frequency_ci95_hz must lie in [0, frequency_hz = {f:g}) Hz, got {ci!r}")
        modes.append(MappedMode(f, ci, position))
    if not modes:
        raise DataError("the map of modes is empty: no position to design a notch for")
    return modes


@dataclass(frozen=True)
class NotchGroup:
    """One notch and the modes it covers, evaluated on the section the device runs.

    Attributes
    ----------
    spec : NotchSpec
        Centre, width and depth asked for.
    biquad : Biquad
        The section evaluated: ``realise(spec)`` (what the device stores).
    modes : tuple of MappedMode
        The mapped modes this notch is for.
    range_hz : tuple of float
        ``(min(f - ci), max(f + ci))`` over ``modes``, Hz.
    worst_attenuation_db : float
        Least attenuation of ``biquad`` over ``range_hz`` on the grid, dB.
    worst_frequency_hz : float
        Where it occurs, Hz.
    mode_attenuation_db : tuple of float
        Attenuation at each mode's frequency, dB, in the order of ``modes``.
    meets_target : bool
        ``worst_attenuation_db >= target``.
    """

    spec: NotchSpec
    biquad: Biquad
    modes: tuple[MappedMode, ...]
    range_hz: tuple[float, float]
    worst_attenuation_db: float
    worst_frequency_hz: float
    mode_attenuation_db: tuple[float, ...]
    meets_target: bool

    def as_dict(self) -> dict:
        """Plain record, unit-suffixed keys (biquad ``b``, ``a`` in scipy convention, dimensionless)."""
        return {
            "center_hz": self.spec.center_hz,
            "width_hz": self.spec.width_hz,
            "depth_db": self.spec.depth_db,
            "width_ratio": self.spec.width_hz / self.spec.center_hz,
            "b": list(self.biquad.b),
            "a": list(self.biquad.a),
            "range_hz": list(self.range_hz),
            "worst_attenuation_db": self.worst_attenuation_db,
            "worst_frequency_hz": self.worst_frequency_hz,
            "meets_target": self.meets_target,
            "positions_m": [m.position_m for m in self.modes],
            "modes": [
                {
                    "position_m": m.position_m,
                    "frequency_hz": m.frequency_hz,
                    "frequency_ci95_hz": m.frequency_ci95_hz,
                    "attenuation_db": a,
                }
                for m, a in zip(self.modes, self.mode_attenuation_db, strict=True)
            ],
        }


@dataclass(frozen=True)
class CoveringResult:
    """What :func:`covering_notch` found.

    Attributes
    ----------
    kind : str
        ``"single"``: one notch covers the whole range (``groups`` holds it);
        ``"scheduled"``: it cannot within ``max_width_ratio``, and ``groups``
        holds a position-scheduled set instead.
    single : NotchGroup
        The one notch over the whole range: the narrowest that meets the
        target, or, when none within ``max_width_ratio`` does, the widest
        allowed, with its (short) worst case.
    groups : tuple of NotchGroup
        The notch(es) to use: the one notch, or the position-scheduled set (each switched in where its
        modes were mapped).
    staggered : tuple of NotchGroup
        ``"scheduled"`` only: notches for a device that enables several at once instead of switching, their
        ranges tiling the whole range without gaps (a mode between two mapped positions lies between their
        groups' ranges), each meeting the target over its piece (:func:`staggered_notches`).
    range_hz : tuple of float
        The whole range, ``(min(f - ci), max(f + ci))``, Hz.
    target_attenuation_db, max_width_ratio, sample_rate_hz : float
        The design's parameters.
    message : str
        One sentence on the outcome, with the numbers.
    """

    kind: str
    single: NotchGroup
    groups: tuple[NotchGroup, ...]
    range_hz: tuple[float, float]
    target_attenuation_db: float
    max_width_ratio: float
    sample_rate_hz: float
    message: str
    staggered: tuple[NotchGroup, ...] = ()

    @property
    def meets_target(self) -> bool:
        """Every notch to use meets the target over its range."""
        return all(g.meets_target for g in self.groups)

    @property
    def worst_attenuation_db(self) -> float:
        """Least attenuation over the ranges of the notches to use, dB."""
        return min(g.worst_attenuation_db for g in self.groups)

    def as_dict(self) -> dict:
        """Plain record for ``summary.json``: unit-suffixed keys, the one-notch attempt and the notches to use."""
        worst = min(self.groups, key=lambda g: g.worst_attenuation_db)
        return {
            "kind": self.kind,
            "meets_target": self.meets_target,
            "message": self.message,
            "range_hz": list(self.range_hz),
            "target_attenuation_db": self.target_attenuation_db,
            "max_width_ratio": self.max_width_ratio,
            "sample_rate_hz": self.sample_rate_hz,
            "worst_attenuation_db": worst.worst_attenuation_db,
            "worst_frequency_hz": worst.worst_frequency_hz,
            "single": self.single.as_dict(),
            "groups": [g.as_dict() for g in self.groups],
            "staggered": [g.as_dict() for g in self.staggered],
        }


def _parameter(key: str, value: Any, *, minimum: float = 0.0) -> float:
    return number(key, value, minimum=minimum, strict=True)


class _Designer:
    """Designs and evaluates the notch for one frequency range."""

    def __init__(
        self,
        sample_rate_hz: float,
        target_db: float,
        depth_db: float,
        max_width_ratio: float,
        grid_points: int,
        realise: Callable[[NotchSpec], Biquad],
    ):
        self.fs, self.target, self.depth = sample_rate_hz, target_db, depth_db
        self.max_ratio, self.points, self.realise = max_width_ratio, grid_points, realise

    def evaluate(self, spec: NotchSpec, modes: tuple[MappedMode, ...], lo: float, hi: float) -> NotchGroup:
        try:
            section = self.realise(spec)
        except (ConfigError, DataError):
            raise
        except Exception as exc:  # a caller's realisation: say which notch it failed on
            raise DataError(f"realise({spec}) failed: {exc}") from exc
        grid = np.linspace(lo, hi, self.points)
        with np.errstate(divide="ignore"):
            att = -20.0 * np.log10(np.abs(section.response(grid, self.fs)))
        i = int(np.argmin(att))
        with np.errstate(divide="ignore"):
            at_modes = -20.0 * np.log10(np.abs(section.response(np.array([m.frequency_hz for m in modes]), self.fs)))
        worst = float(att[i])
        return NotchGroup(
            spec,
            section,
            modes,
            (lo, hi),
            worst,
            float(grid[i]),
            tuple(float(a) for a in at_modes),
            bool(worst >= self.target),
        )

    def design(self, modes: tuple[MappedMode, ...]) -> NotchGroup:
        """The narrowest notch meeting the target over the modes' range, else the widest allowed."""
        lo, hi = min(m.low_hz for m in modes), max(m.high_hz for m in modes)
        if not hi < 0.5 * self.fs:
            raise DataError(f"the mapped range reaches {hi:g} Hz, not below half the {self.fs:g} Hz filter rate")
        center = math.sqrt(lo * hi)
        widest = self.max_ratio * center
        spec_of = lambda w: NotchSpec(center, w, self.depth)  # noqa: E731
        closed = width_for_attenuation_hz(center, [lo, hi], self.target, self.depth, self.fs)
        # the closed form is exact for the ideal section; nudge above rounding, never to zero width
        width = max(closed * (1.0 + 1e-9), 1e-6 * center)
        if width > widest:
            return self.evaluate(spec_of(widest), modes, lo, hi)
        best = self.evaluate(spec_of(width), modes, lo, hi)
        if best.meets_target:
            return best
        # the stored section falls short: bracket between the closed form (short) and the widest allowed
        top = self.evaluate(spec_of(widest), modes, lo, hi)
        if not top.meets_target:
            return top
        short, enough = width, top
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (short + enough.spec.width_hz)
            trial = self.evaluate(spec_of(mid), modes, lo, hi)
            if trial.meets_target:
                enough = trial
            else:
                short = mid
            if enough.spec.width_hz - short <= 1e-4 * enough.spec.width_hz:
                break
        return enough

    def feasible_by_closed_form(self, modes: tuple[MappedMode, ...]) -> bool:
        lo, hi = min(m.low_hz for m in modes), max(m.high_hz for m in modes)
        center = math.sqrt(lo * hi)
        return width_for_attenuation_hz(center, [lo, hi], self.target, self.depth, self.fs) <= self.max_ratio * center


def _schedule(designer: _Designer, modes: list[MappedMode]) -> list[NotchGroup]:
    """Fewest consecutive groups (in frequency order) whose notches each meet the target.

    Greedy: a group grows by the next mode while its notch still meets the
    target. For the exact design a sub-range of a range one notch covers is
    covered too, so greedy growth gives the fewest groups of consecutive modes
    (a device's rounding can break that monotony by a fraction of a dB).
    """
    ordered = sorted(modes, key=lambda m: (m.frequency_hz, m.frequency_ci95_hz))
    groups: list[NotchGroup] = []
    current = [ordered[0]]
    current_design = designer.design(tuple(current))
    for mode in ordered[1:]:
        trial_modes = (*current, mode)
        trial = designer.design(trial_modes) if designer.feasible_by_closed_form(trial_modes) else None
        if trial is not None and trial.meets_target and current_design.meets_target:
            current, current_design = list(trial_modes), trial
            continue
        groups.append(current_design)
        current = [mode]
        current_design = designer.design((mode,))
    groups.append(current_design)
    return groups


def covering_notch(
    modes: Iterable[Any],
    sample_rate_hz: float,
    target_attenuation_db: float = 20.0,
    max_width_ratio: float = 1.0,
    *,
    depth_margin_db: float = 20.0,
    grid_points: int = 2000,
    realise: Callable[[NotchSpec], Biquad] | None = None,
) -> CoveringResult:
    """One notch over the whole mapped range of a moving mode, or a position-scheduled set.

    Parameters
    ----------
    modes : iterable
        The map: per position ``frequency_hz`` and ``frequency_ci95_hz`` (Hz),
        optionally ``position_m`` (:func:`mapped_modes`).
    sample_rate_hz : float
        Rate the drive runs its filters at, Hz.
    target_attenuation_db : float
        Least attenuation wanted everywhere in the range, dB.
    max_width_ratio : float
        Widest notch allowed, as a fraction of its centre (``width_hz /
        center_hz``; ``[notch] max_width_ratio`` of a run): a wider notch costs
        too much phase below its centre.
    depth_margin_db : float
        Depth above the target at the centre, dB.
    grid_points : int
        Points of the grid over each range the worst case is taken on (the
        range's ends included).
    realise : callable, optional
        ``realise(spec) -> Biquad``: the section a device stores for a notch,
        e.g. ``lambda s: encoding.realise(s, rate).section`` of a
        :class:`~hilident.protocol.filter_encoding.FilterEncoding`; default
        the exact pre-warped Tustin design (:func:`design_notch`).

    Returns
    -------
    CoveringResult
        ``kind`` "single" or "scheduled", the notches, their worst case over
        their ranges and where it lies, the attenuation at each mapped mode.

    Raises
    ------
    DataError
        A bad map (:func:`mapped_modes`), a range reaching Nyquist, or a
        ``realise`` that fails.
    ConfigError
        A parameter out of range.
    """
    fs = _parameter("sample_rate_hz", sample_rate_hz)
    target = _parameter("target_attenuation_db", target_attenuation_db)
    ratio = _parameter("max_width_ratio", max_width_ratio)
    margin = _parameter("depth_margin_db", depth_margin_db)
    if isinstance(grid_points, bool) or not isinstance(grid_points, int | np.integer) or grid_points < 2:
        raise ConfigError("grid_points", f"must be an integer of at least 2, got {grid_points!r}")
    checked = mapped_modes(modes)
    designer = _Designer(
        fs,
        target,
        target + margin,
        ratio,
        int(grid_points),
        realise if realise is not None else (lambda spec: design_notch(spec, fs)),
    )
    single = designer.design(tuple(checked))
    lo, hi = single.range_hz
    span = f"{lo:.4g}-{hi:.4g} Hz"
    if single.meets_target:
        message = (
            f"one notch at {single.spec.center_hz:.4g} Hz, {single.spec.width_hz:.3g} Hz wide "
            f"({single.spec.width_hz / single.spec.center_hz:.2f} of its centre), attenuates at least "
            f"{single.worst_attenuation_db:.1f} dB over {span} (target {target:g} dB)"
        )
        return CoveringResult("single", single, (single,), (lo, hi), target, ratio, fs, message)
    groups = _schedule(designer, checked)
    short = [g for g in groups if not g.meets_target]
    message = (
        f"no single notch within max_width_ratio = {ratio:g} reaches {target:g} dB over {span}: the widest "
        f"gives {single.worst_attenuation_db:.1f} dB at {single.worst_frequency_hz:.4g} Hz; a "
        f"position-scheduled set needs {len(groups)} notches"
    )
    if short:
        message += (
            f", and {len(short)} of them still fall short (worst "
            f"{min(g.worst_attenuation_db for g in short):.1f} dB): a mode's own 95 % interval is too wide"
        )
    return CoveringResult(
        "scheduled", single, tuple(groups), (lo, hi), target, ratio, fs, message, staggered_notches(designer, lo, hi)
    )


def staggered_notches(designer: _Designer, lo: float, hi: float, max_notches: int = 8) -> tuple[NotchGroup, ...]:
    """The fewest notches whose ranges tile ``[lo, hi]`` Hz, each meeting the target over its piece.

    The range is cut into ``n`` pieces of equal frequency ratio (``n`` = 2, 3, ...) until every piece's notch
    meets the target; enabled together, the chain attenuates at least as much as any one of them. Empty when
    ``max_notches`` are not enough (a device's rounding that no width overcomes).
    """
    for n in range(2, max_notches + 1):
        edges = lo * (hi / lo) ** (np.arange(n + 1) / n)
        pieces = tuple(
            designer.design((MappedMode(float(a), 0.0), MappedMode(float(b), 0.0)))
            for a, b in zip(edges[:-1], edges[1:], strict=True)
        )
        if all(p.meets_target for p in pieces):
            return pieces
    return ()
