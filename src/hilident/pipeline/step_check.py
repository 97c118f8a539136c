"""A small velocity step, measured and predicted: the closed loop's proof in the time domain.

After the closed-loop multisine, the gain step plays steps on the velocity
set-point: one period holds ``+A``, ``0``, ``-A``, ``0`` for ``hold`` each (zero
mean, so the axis comes back to where it started; every step starts from rest
or ends at it), repeated; with acceleration feed-forward each level is reached
by a short ramp, as a drive's profile generator does. The set-point is
periodic, so its response is exactly the set-point's lines times the predicted
set-point response, summed back into one period, with the part of the friction
the axis meets (:func:`hilident.pipeline.closed_loop.predicted_period`).

The measured period is the mean over the played periods (the first one, the
transient from rest, left out). The comparison gives the rms difference over
the period relative to ``A`` and, for the step from rest to ``+A``, the
overshoot, the 10-90 % rise time and the 2 % settling time of both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "StepCheck",
    "compare_steps",
    "hold_samples",
    "measured_period",
    "ramp_samples",
    "step_levels",
]

#: The settling band of the settling time: a share of the step.
SETTLING_BAND = 0.02


def step_levels(hold_samples: int, ramp_samples: int = 1) -> np.ndarray:
    """One period of the step set-point at ``A = 1``: ``+1, 0, -1, 0``, each for ``hold_samples`` samples, each
    reached by a straight ramp over ``ramp_samples`` samples (1: a step).

    A drive with acceleration feed-forward turns a step of the velocity set-point into a torque impulse; a
    ramp bounds it, as a drive's own profile generator does.
    """
    n, r = int(hold_samples), int(ramp_samples)
    if n < 2 or not 1 <= r <= n // 2:
        raise ValueError(f"a step level must last 2 samples or more and twice its ramp, got {n} and {r}")
    rise = np.minimum(np.arange(1, n + 1) / r, 1.0)
    return np.concatenate([rise, 1.0 - rise, -rise, rise - 1.0])


def measured_period(
    sample_index: np.ndarray, values: np.ndarray, period_samples: int, periods_played: int
) -> tuple[np.ndarray, int]:
    """The mean of ``values`` over the periods played, by each row's place in its period; the first period
    (the transient from rest), missing samples (NaN) and rows after the last period left out.

    Returns
    -------
    (mean, periods) : (ndarray, int)
        One period (NaN at a place no period holds) and the number of periods that contributed.
    """
    n = int(period_samples)
    index = np.asarray(sample_index, dtype=np.int64)
    v = np.asarray(values, dtype=float)
    keep = (index >= n) & (index < n * int(periods_played)) & np.isfinite(v)
    place = index[keep] % n
    total = np.bincount(place, weights=v[keep], minlength=n)
    count = np.bincount(place, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    periods = int(np.unique(index[keep] // n).size)
    return mean, periods


@dataclass(frozen=True)
class StepCheck:
    """A measured step period against its prediction.

    Attributes
    ----------
    time_s : ndarray
        Time in the period, s.
    setpoint, measured, predicted : ndarray
        One period of the set-point and of the velocity, m/s.
    amplitude_mps : float
        ``A``, m/s.
    spread : float
        The largest rms distance of the prediction on the plant's variants from the nominal one, relative
        to ``A``.
    tolerance : float
        The rms difference allowed, relative to ``A``, besides the spread.
    periods : int
        Periods averaged.
    """

    time_s: np.ndarray
    setpoint: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    amplitude_mps: float
    spread: float
    tolerance: float
    periods: int

    @property
    def rms_error(self) -> float:
        """The rms of measured minus predicted over the period, relative to ``A``."""
        d = self.measured - self.predicted
        return float(np.sqrt(np.nanmean(d**2)) / self.amplitude_mps)

    @property
    def within_tolerance(self) -> bool:
        return self.rms_error <= self.tolerance + self.spread

    def to_dict(self) -> dict:
        hold = self.setpoint.size // 4
        measured, predicted = (
            _step_figures(x[:hold], self.amplitude_mps, self.time_s[1]) for x in (self.measured, self.predicted)
        )
        return {
            "amplitude_mps": self.amplitude_mps,
            "hold_s": hold * float(self.time_s[1]),
            "periods": self.periods,
            "rms_error_percent": 100.0 * self.rms_error,
            "prediction_spread_percent": 100.0 * self.spread,
            "tolerance_percent": 100.0 * self.tolerance,
            "within_tolerance": self.within_tolerance,
            "measured": measured,
            "predicted": predicted,
        }


def compare_steps(
    setpoint: np.ndarray,
    measured: np.ndarray,
    predictions: list[np.ndarray],
    sample_rate_hz: float,
    amplitude_mps: float,
    tolerance: float,
    periods: int,
) -> StepCheck:
    """The measured period against the prediction (``predictions``: the plant's first, then its variants')."""
    predicted, *variants = predictions
    spread = max((float(np.sqrt(np.mean((v - predicted) ** 2))) for v in variants), default=0.0)
    return StepCheck(
        np.arange(np.asarray(setpoint).size) / sample_rate_hz,
        np.asarray(setpoint, dtype=float),
        np.asarray(measured, dtype=float),
        np.asarray(predicted, dtype=float),
        float(amplitude_mps),
        spread / amplitude_mps,
        float(tolerance),
        int(periods),
    )


def _step_figures(response: np.ndarray, amplitude: float, dt_s: float) -> dict:
    """Overshoot (%), 10-90 % rise time (s) and 2 % settling time (s) of a step from 0 to ``amplitude``
    (None where the response does not reach the level)."""
    y = np.asarray(response, dtype=float) / amplitude
    final = float(np.nanmean(y[-max(2, y.size // 10) :]))

    def first(condition: np.ndarray) -> float | None:
        hits = np.flatnonzero(condition)
        return float(hits[0] * dt_s) if hits.size else None

    t10, t90 = first(y >= 0.1 * final), first(y >= 0.9 * final)
    outside = np.flatnonzero(np.abs(y - final) > SETTLING_BAND * abs(final))
    settle = float((outside[-1] + 1) * dt_s) if outside.size and outside[-1] + 1 < y.size else None
    return {
        "final": final,
        "overshoot_percent": max(0.0, 100.0 * (float(np.nanmax(y)) / final - 1.0)) if final > 0 else None,
        "rise_time_s": t90 - t10 if t10 is not None and t90 is not None else None,
        "settling_time_s": settle if outside.size else 0.0,
    }


#: The ramp to each level, as a share of the level's hold.
RAMP_SHARE = 0.1


def hold_samples(bandwidth_hz: float, sample_rate_hz: float, least_s: float = 0.1) -> int:
    """Samples each level holds: ten time constants of the closed loop's bandwidth, at least ``least_s``."""
    if not math.isfinite(bandwidth_hz) or bandwidth_hz <= 0:
        return int(round(least_s * sample_rate_hz))
    return int(round(max(least_s, 10.0 / (2.0 * math.pi * bandwidth_hz)) * sample_rate_hz))


def ramp_samples(hold: int, feedforward: bool) -> int:
    """The ramp to each level: a step (1 sample) for a loop without acceleration feed-forward, else
    :data:`RAMP_SHARE` of the hold (its torque impulse bounded, so the levels can be large enough to leave
    the friction's slow region)."""
    return max(1, int(round(RAMP_SHARE * hold))) if feedforward else 1
