"""Point-to-point set-point trajectories: trapezoidal and jerk-limited (S-curve) velocity profiles.

A move is a sequence of segments of constant jerk (the trapezoid: constant
acceleration, infinite jerk at the corners). Position, velocity and
acceleration are exact polynomials of time inside each segment and are sampled
at ``sample_rate_hz``; the last sample of the motion (``move_end_index``)
and every dwell sample after it hold exactly the asked distance with zero
velocity and acceleration.

* :func:`trapezoid` -- accelerate at ``max_accel_mps2``, cruise at
  ``max_velocity_mps``, decelerate; when the distance is too short to reach the
  velocity limit the cruise vanishes and the profile is triangular, peaking at
  ``sqrt(|distance| * max_accel)``.
* :func:`s_curve` -- the seven-segment jerk-limited profile: the jerk limit
  is given as ``max_jerk_mps3`` (a rate, m/s^3, not a jerk time; the time to ramp
  the acceleration up is ``max_accel / max_jerk``). Short moves lose the
  constant-acceleration phase, the cruise, or both; the peak velocity and
  acceleration are then lowered so the distance is met exactly.

Both profiles are symmetric: the deceleration mirrors the acceleration, so
``v(T - t) = v(t)`` and ``p(T - t) = distance - p(t)`` for a move of duration ``T``.

Examples
--------
>>> move = trapezoid(0.2, 0.3, 2.0, 1000.0, dwell_s=0.5)
>>> round(move.duration_s, 4), move.move_end_index, float(move.position_m[-1])
(0.8167, 817, 0.2)
>>> bool(abs(move.velocity_mps).max() <= 0.3)
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError
from hilident.numbers import number

__all__ = ["MAX_SAMPLES", "MovePlan", "MoveProfile", "s_curve", "trapezoid"]

#: Longest trajectory (move and dwell) built, in samples: a guard against a rate or dwell typed in the wrong unit.
MAX_SAMPLES = 50_000_000


@dataclass(frozen=True)
class MovePlan:
    """The continuous-time move: segments of constant jerk, for a positive distance, and the sign.

    Parameters
    ----------
    durations_s : tuple of float
        Length of each segment, s (zero-length segments are allowed).
    jerks_mps3 : tuple of float
        Jerk inside each segment, m/s^3, for the move in the positive direction.
    start_accels_mps2 : tuple of float
        Acceleration at each segment's start, m/s^2 (a trapezoid's steps live here).
    distance_m : float
        Signed distance; the segments describe ``|distance_m|`` and are mirrored for a negative one.
    """

    durations_s: tuple[float, ...]
    jerks_mps3: tuple[float, ...]
    start_accels_mps2: tuple[float, ...]
    distance_m: float

    @property
    def duration_s(self) -> float:
        """Time from the start of the motion to its end, s."""
        return float(sum(self.durations_s))

    def evaluate(self, time_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (m, from the start), velocity (m/s) and acceleration (m/s^2) at ``time_s``.

        Times before 0 give the start, times at or after :attr:`duration_s` give
        exactly ``distance_m`` at rest.
        """
        t = np.asarray(time_s, dtype=float)
        p = np.zeros(t.shape)
        v = np.zeros(t.shape)
        a = np.zeros(t.shape)
        t0, p0, v0 = 0.0, 0.0, 0.0
        for dur, j, a0 in zip(self.durations_s, self.jerks_mps3, self.start_accels_mps2, strict=True):
            inside = (t >= t0) & (t < t0 + dur)
            tau = t[inside] - t0
            p[inside] = p0 + v0 * tau + a0 * tau**2 / 2.0 + j * tau**3 / 6.0
            v[inside] = v0 + a0 * tau + j * tau**2 / 2.0
            a[inside] = a0 + j * tau
            p0 += v0 * dur + a0 * dur**2 / 2.0 + j * dur**3 / 6.0
            v0 += a0 * dur + j * dur**2 / 2.0
            t0 += dur
        done = t >= t0
        p[done], v[done], a[done] = abs(self.distance_m), 0.0, 0.0
        sign = -1.0 if self.distance_m < 0 else 1.0
        return sign * p, sign * v, sign * a


@dataclass(frozen=True, eq=False)
class MoveProfile:
    """A sampled point-to-point move followed by a dwell at the end position.

    Attributes
    ----------
    time_s : ndarray
        Sample times from the start of the motion, s (``n / sample_rate_hz``).
    position_m : ndarray
        Set-point relative to the start, m; exactly ``distance_m`` from ``move_end_index`` on.
    velocity_mps : ndarray
        Velocity set-point, m/s; exactly 0 from ``move_end_index`` on.
    accel_mps2 : ndarray
        Acceleration set-point, m/s^2; exactly 0 from ``move_end_index`` on.
    move_end_index : int
        First sample at or after the end of the motion: the dwell starts here.
    sample_rate_hz : float
        Rate of the samples, Hz.
    distance_m : float
        Signed distance of the move, m.
    plan : MovePlan or None
        The continuous-time move the samples were taken from (None for a trajectory
        that is not a polynomial, such as a notch-shaped one).
    """

    time_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    accel_mps2: np.ndarray
    move_end_index: int
    sample_rate_hz: float
    distance_m: float
    plan: MovePlan | None = None

    @property
    def move_end_s(self) -> float:
        """Time of the sample where the dwell starts, s."""
        return float(self.time_s[self.move_end_index])

    @property
    def duration_s(self) -> float:
        """Duration of the continuous motion (the plan's), else :attr:`move_end_s`, s."""
        return self.plan.duration_s if self.plan is not None else self.move_end_s

    @property
    def dwell_s(self) -> float:
        """Time from :attr:`move_end_s` to the last sample, s."""
        return float(self.time_s[-1] - self.time_s[self.move_end_index])


def _value(key: str, value, prefix: str, *, positive: bool) -> float:
    return number(f"{prefix}{key}", value, strict=positive)


def _distance(value, prefix: str) -> float:
    x = number(f"{prefix}distance_m", value, minimum=-math.inf)
    if x == 0.0:
        raise ConfigError(f"{prefix}distance_m", "must not be 0 (a move needs a distance)")
    return x


def _sample(plan: MovePlan, sample_rate_hz: float, dwell_s: float, prefix: str) -> MoveProfile:
    fs = sample_rate_hz
    # The first sample at or after the end (a hair of slack so T * fs = 817.0000000001 is sample 817).
    end = max(1, math.ceil(plan.duration_s * fs - 1e-9))
    n = end + 1 + round(dwell_s * fs)
    if n > MAX_SAMPLES:
        raise ConfigError(
            f"{prefix}sample_rate_hz",
            f"the move and dwell would take {n} samples (more than {MAX_SAMPLES}); "
            "check the rate, the dwell and the limits' units",
        )
    t = np.arange(n) / fs
    p, v, a = plan.evaluate(t)
    p[end:], v[end:], a[end:] = plan.distance_m, 0.0, 0.0
    return MoveProfile(t, p, v, a, end, fs, plan.distance_m, plan)


def trapezoid(
    distance_m: float,
    max_velocity_mps: float,
    max_accel_mps2: float,
    sample_rate_hz: float,
    dwell_s: float = 0.0,
    *,
    key_prefix: str = "",
) -> MoveProfile:
    """A trapezoidal-velocity move (triangular when the velocity limit is not reached).

    Parameters
    ----------
    distance_m : float
        Signed distance, m (non-zero).
    max_velocity_mps : float
        Velocity limit, m/s (> 0).
    max_accel_mps2 : float
        Acceleration (and deceleration) limit, m/s^2 (> 0).
    sample_rate_hz : float
        Set-point rate, Hz (> 0).
    dwell_s : float
        Time held at the end position after the motion, s (>= 0).
    key_prefix : str
        Prepended to the parameter names in errors, e.g. ``"verification.move."``.

    Returns
    -------
    MoveProfile

    Raises
    ------
    ConfigError
        A non-finite value, a limit or rate not above 0, a negative dwell, a zero
        distance, or more than :data:`MAX_SAMPLES` samples; the message names the key.

    Examples
    --------
    >>> tri = trapezoid(-0.01, 1.0, 2.0, 1000.0)    # too short to reach 1 m/s
    >>> round(float(tri.velocity_mps.min()), 3), float(tri.position_m[-1])
    (-0.141, -0.01)
    """
    d = _distance(distance_m, key_prefix)
    vmax = _value("max_velocity_mps", max_velocity_mps, key_prefix, positive=True)
    amax = _value("max_accel_mps2", max_accel_mps2, key_prefix, positive=True)
    fs = _value("sample_rate_hz", sample_rate_hz, key_prefix, positive=True)
    dwell = _value("dwell_s", dwell_s, key_prefix, positive=False)
    s = abs(d)
    if s * amax >= vmax * vmax:
        ta, tv, vpeak = vmax / amax, s / vmax - vmax / amax, vmax
    else:
        ta = math.sqrt(s / amax)
        tv, vpeak = 0.0, amax * ta
    apeak = vpeak / ta
    plan = MovePlan((ta, tv, ta), (0.0, 0.0, 0.0), (apeak, 0.0, -apeak), d)
    return _sample(plan, fs, dwell, key_prefix)


def _s_curve_plan(d: float, vmax: float, amax: float, jmax: float) -> MovePlan:
    """Segments of the seven-phase jerk-limited move over ``|d|``."""
    s = abs(d)

    def ramp_times(v: float) -> tuple[float, float]:
        """Jerk time and constant-acceleration time to reach ``v`` from rest within the limits."""
        if v * jmax <= amax * amax:
            return math.sqrt(v / jmax), 0.0
        return amax / jmax, v / amax - amax / jmax

    tj, tc = ramp_times(vmax)
    if vmax * (2.0 * tj + tc) <= s:  # the velocity limit is reached: cruise for the rest
        vpeak = vmax
    else:  # no cruise: the largest peak velocity whose ramp up and down covers exactly s
        v_knee = amax * amax / jmax  # peak velocity at which the acceleration limit is just reached
        if v_knee * 2.0 * amax / jmax >= s:
            vpeak = (s * math.sqrt(jmax) / 2.0) ** (2.0 / 3.0)  # s = 2 v sqrt(v / j)
        else:
            r = amax / jmax  # s = v^2 / a + v a / j
            vpeak = 0.5 * amax * (-r + math.sqrt(r * r + 4.0 * s / amax))
        tj, tc = ramp_times(vpeak)
    tv = max(0.0, s / vpeak - (2.0 * tj + tc))
    ap = jmax * tj
    durations = (tj, tc, tj, tv, tj, tc, tj)
    jerks = (jmax, 0.0, -jmax, 0.0, -jmax, 0.0, jmax)
    accels = (0.0, ap, ap, 0.0, 0.0, -ap, -ap)
    return MovePlan(durations, jerks, accels, d)


def s_curve(
    distance_m: float,
    max_velocity_mps: float,
    max_accel_mps2: float,
    max_jerk_mps3: float,
    sample_rate_hz: float,
    dwell_s: float = 0.0,
    *,
    key_prefix: str = "",
) -> MoveProfile:
    """A jerk-limited (seven-segment, S-curve) move.

    The acceleration ramps at ``max_jerk_mps3`` to at most ``max_accel_mps2``
    and back, so it is continuous and the velocity is smooth. When the velocity
    limit cannot be reached within the distance, or the acceleration limit
    within the velocity limit, the peak values are lowered and the
    corresponding constant phases vanish.

    Parameters
    ----------
    distance_m : float
        Signed distance, m (non-zero).
    max_velocity_mps : float
        Velocity limit, m/s (> 0).
    max_accel_mps2 : float
        Acceleration limit, m/s^2 (> 0).
    max_jerk_mps3 : float
        Jerk limit, m/s^3 (> 0); the acceleration ramps take ``max_accel_mps2 / max_jerk_mps3`` s.
    sample_rate_hz : float
        Set-point rate, Hz (> 0).
    dwell_s : float
        Time held at the end position after the motion, s (>= 0).
    key_prefix : str
        Prepended to the parameter names in errors.

    Returns
    -------
    MoveProfile

    Raises
    ------
    ConfigError
        As :func:`trapezoid`, and for a jerk limit not above 0.

    Examples
    --------
    >>> move = s_curve(0.2, 0.3, 2.0, 40.0, 1000.0)
    >>> round(move.duration_s, 4), float(move.position_m[-1])
    (0.8667, 0.2)
    >>> bool(np.abs(np.diff(move.accel_mps2)).max() * 1000.0 <= 40.0 + 1e-9)
    True
    """
    d = _distance(distance_m, key_prefix)
    vmax = _value("max_velocity_mps", max_velocity_mps, key_prefix, positive=True)
    amax = _value("max_accel_mps2", max_accel_mps2, key_prefix, positive=True)
    jmax = _value("max_jerk_mps3", max_jerk_mps3, key_prefix, positive=True)
    fs = _value("sample_rate_hz", sample_rate_hz, key_prefix, positive=True)
    dwell = _value("dwell_s", dwell_s, key_prefix, positive=False)
    return _sample(_s_curve_plan(d, vmax, amax, jmax), fs, dwell, key_prefix)
