"""Friction from the friction test: steady constant-velocity windows in, a fitted friction curve out.

A recording gives its steady windows (:class:`RecordedPoints`); the fit pools the
points of every recording of the test (the first round and the rounds that
extend it, :mod:`hilident.session.friction_test`). The curve is fitted to the
folded points, one per pair of opposite legs, so a load torque that does not
change with the direction cancels instead of counting as scatter, and the
intervals rest on as many independent points as there are pairs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from hilident.errors import DataError
from hilident.ident import friction as fr
from hilident.ident.preprocess import check_signals

#: The levels whose 95 % intervals the friction test is judged by: Coulomb (N·m) and viscous (N·m/(m/s)).
LEVELS = ("Fc", "Fv")
#: Significance at which the first round's points are taken to disagree with the rounds after it.
FIRST_ROUND_ALPHA = 0.01
_WINDOW_KEYS = fr.SteadyStatePoints._fields
_FOLDED_KEYS = fr.FoldedPoints._fields


@dataclass(frozen=True)
class RecordedPoints:
    """The steady windows of one friction recording: each window's means and the folded points."""

    windows: fr.SteadyStatePoints
    folded: fr.FoldedPoints


@dataclass
class FrictionResult:
    """Friction identified from constant-velocity windows.

    ``extension``: what the test did to narrow its intervals (rounds, target, why it
    stopped; :class:`hilident.session.friction_test.FrictionTest`), None for a fixed test.
    ``first_round_left_out``: the configured round's points disagreed with the later rounds'
    and the fit rests on those (:func:`fit_recorded`).
    """

    fit: fr.FrictionFit
    points: fr.SteadyStatePoints
    model: str
    warnings: list[str] = field(default_factory=list)
    folded: fr.FoldedPoints | None = None
    extension: dict | None = None
    first_round_left_out: bool = False

    @property
    def slowest_mps(self) -> float:
        """The slowest steady speed the friction was measured at, m/s: the curve is not extrapolated below it."""
        speeds = np.abs(np.asarray(self.points.v_mean, dtype=float))
        speeds = speeds[speeds > 0.0]
        return float(speeds.min()) if speeds.size else 0.0

    def half_width_percent(self, name: str) -> float:
        """The 95 % interval's half-width of parameter ``name`` as a share of its value, % (inf at 0)."""
        value = abs(getattr(self.fit.params, name))
        width = self.fit.half_width(name)
        return 100.0 * width / value if value > 0.0 else float("inf")

    def intervals(self) -> dict[str, float]:
        """Half-width of the 95 % interval of each fitted parameter, in its unit."""
        return {name: self.fit.half_width(name) for name in fr.free_parameters(self.fit)}


def recorded_points(velocity, torque, windows) -> RecordedPoints:
    """The steady windows of one recording of the friction test, as means and as folded points.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and measured torque (N·m).
    windows : sequence of (start, stop, nominal_velocity_mps)
        Sample ranges at constant velocity, in the order they were run.
    """
    checked = check_signals({"velocity": velocity, "torque": torque})
    return RecordedPoints(
        fr.steady_state_points(checked["velocity"], checked["torque"], windows),
        fr.folded_points(checked["velocity"], checked["torque"], windows),
    )


def fit_recorded(recorded: Sequence[RecordedPoints], model: str = "stribeck") -> FrictionResult:
    """The friction curve fitted to the points of every recording of the test, pooled.

    The first recording is the configured round; the rounds after it hold each leg longer
    and let the axis settle longer after its ramp. When the first round's points disagree
    with the curve the others follow (:func:`first_round_differs`), its windows were averaged
    before the axis had settled and are left out (``first_round_left_out``).

    Parameters
    ----------
    recorded : sequence of RecordedPoints
        One per recording (the test's first round and its extensions).
    model : {"stribeck", "coulomb_viscous"}
        ``"stribeck"``: the Stribeck structure the points support (Coulomb + viscous,
        fixed exponents or all six parameters, by AICc; :func:`~hilident.ident.friction.fit_friction`).
        Each point is weighted by the windows averaged into it.
    """
    pooled = _fit(recorded, model)
    if len(recorded) < 2 or not first_round_differs(pooled, len(recorded[0].folded.speed)):
        return pooled
    try:
        later = _fit(recorded[1:], model)
    except DataError:  # too few points without the first round: keep them all
        return pooled
    later.first_round_left_out = True
    return later


def first_round_differs(result: FrictionResult, n_first: int, alpha: float = FIRST_ROUND_ALPHA) -> bool:
    """Whether the first ``n_first`` folded points lie off the pooled curve by more than its scatter explains.

    The residuals of the pooled fit are regressed on an offset and a slope (in speed) that only the
    first points carry; an F test at level ``alpha`` decides. A first round whose windows began
    before the axis had settled after its ramps (``settle_s`` too short for the plant) rings into
    its means more at higher speeds, and shows as such an offset and slope.
    """
    folded = result.folded
    if folded is None:
        return False
    n, k = len(folded.speed), result.fit.n_points - result.fit.dof
    dof = n - k - 2
    if n_first < 3 or n - n_first < k + 1 or dof < 3:
        return False
    w = np.sqrt(np.asarray(folded.windows, dtype=float))
    resid = (folded.friction - result.fit.predict(folded.speed)) * w
    first = np.arange(n) < n_first
    speed = folded.speed - folded.speed[first].mean()
    X = np.column_stack([first, first * speed]) * w[:, None]
    coef, *_ = np.linalg.lstsq(X, resid, rcond=None)
    rss0, rss1 = float(resid @ resid), float(np.sum((resid - X @ coef) ** 2))
    if rss1 <= 0.0:
        return rss0 > 0.0
    f = (rss0 - rss1) / 2.0 / (rss1 / dof)
    return bool(stats.f.sf(f, 2, dof) < alpha)


def _fit(recorded: Sequence[RecordedPoints], model: str) -> FrictionResult:
    """:func:`fit_recorded` of all of ``recorded``."""
    points = fr.SteadyStatePoints(*(np.concatenate([getattr(r.windows, k) for r in recorded]) for k in _WINDOW_KEYS))
    folded = fr.FoldedPoints(*(np.concatenate([getattr(r.folded, k) for r in recorded]) for k in _FOLDED_KEYS))
    if len(points.v_mean) < 4 or np.unique(folded.speed).size < 3:
        raise DataError(
            f"only {len(points.v_mean)} steady constant-velocity windows at {np.unique(folded.speed).size} "
            "speeds; a friction fit needs at least 4 windows at 3 speeds (longer friction_test.hold_s, or slower "
            "accelerations)"
        )
    sigma = 1.0 / np.sqrt(folded.windows)
    fit = (
        fr.fit_friction(folded.speed, folded.friction, sigma)
        if model == "stribeck"
        else fr.fit_coulomb_viscous(folded.speed, folded.friction, sigma)
    )
    loose = fr.undetermined(fit)
    warnings = []
    if loose:
        se = ", ".join(f"{n} {getattr(fit.params, n):.3g} +- {fit.stderr[n]:.2g}" for n in loose)
        warnings.append(
            f"friction: {se}: not determined by the {fit.n_points} points (standard error above the "
            "value); measure more speeds around where the torque bends (friction_test.speeds_mps) or "
            "hold each longer (friction_test.hold_s) before trusting them"
        )
    return FrictionResult(fit=fit, points=points, model=model, warnings=warnings, folded=folded)


def identify_friction(velocity, torque, windows, model: str = "stribeck") -> FrictionResult:
    """Steady-state friction points of one recording and the fitted friction curve.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and measured torque (N·m) of the friction test.
    windows : sequence of (start, stop, nominal_velocity_mps)
        Sample ranges at constant velocity.
    model : {"stribeck", "coulomb_viscous"}
        As :func:`fit_recorded`.
    """
    return fit_recorded([recorded_points(velocity, torque, windows)], model)
