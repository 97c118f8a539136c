"""Friction from the friction test: steady constant-velocity windows in, a fitted friction curve out."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilident.errors import DataError
from hilident.ident import friction as fr
from hilident.ident.preprocess import check_signals


@dataclass
class FrictionResult:
    """Friction identified from constant-velocity windows."""

    fit: fr.FrictionFit
    points: fr.SteadyStatePoints
    model: str
    warnings: list[str] = field(default_factory=list)

    @property
    def slowest_mps(self) -> float:
        """The slowest steady speed the friction was measured at, m/s: the curve is not extrapolated below it."""
        speeds = np.abs(np.asarray(self.points.v_mean, dtype=float))
        speeds = speeds[speeds > 0.0]
        return float(speeds.min()) if speeds.size else 0.0


def identify_friction(velocity, torque, windows, model: str = "stribeck") -> FrictionResult:
    """Steady-state friction points and the fitted friction curve.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and measured torque (N·m) of the friction test.
    windows : sequence of (start, stop, nominal_velocity_mps)
        Sample ranges at constant velocity.
    model : {"stribeck", "coulomb_viscous"}
        ``"stribeck"``: the Stribeck structure the points support (Coulomb + viscous,
        fixed exponents or all six parameters, by AICc; :func:`~hilident.ident.friction.fit_friction`).
    """
    checked = check_signals({"velocity": velocity, "torque": torque})
    points = fr.steady_state_points(checked["velocity"], checked["torque"], windows)
    if len(points.v_mean) < 4:
        raise DataError(
            f"only {len(points.v_mean)} steady constant-velocity windows; a friction fit needs at least 4 "
            "(longer friction_test.hold_s, or slower accelerations)"
        )
    fit = (
        fr.fit_friction(points.v_mean, points.tau_mean)
        if model == "stribeck"
        else fr.fit_coulomb_viscous(points.v_mean, points.tau_mean)
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
    return FrictionResult(fit=fit, points=points, model=model, warnings=warnings)
