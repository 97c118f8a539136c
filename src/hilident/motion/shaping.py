"""A notch chain applied by the host to a move's set-point, as the thesis did on its robot.

A drive without filter slots (or one that is streamed positions) still gets a
move that does not excite the resonance when the set-point itself carries no
energy at the mode's frequency. :func:`shape_move` runs the move's position,
velocity and acceleration set-points through a chain of biquads at the
set-point rate:

* causal, from rest: the filter's state is zero at the start of the move
  (the set-point is filtered relative to its start value), so nothing moves
  before the move is commanded;
* unity DC gain, checked: otherwise the filtered move would end elsewhere;
* the input is held at the end position until the filtered set-point has
  settled to it within ``tolerance_m``, and from that sample on the set-point
  is exactly the end position with zero velocity -- the move still ends exactly
  where asked, later by :attr:`ShapedMove.added_delay_s`;
* the dwell of the original move follows the new end.

The shaped velocity and acceleration are the profile's through the same
chain; a notch's small overshoot can take them a little (about 1 %) beyond the
profile's limits.

Examples
--------
>>> from hilident.filters.notch import NotchSpec, design_notch
>>> from hilident.motion.profiles import trapezoid
>>> move = trapezoid(0.2, 0.3, 2.0, 1000.0, dwell_s=0.5)
>>> notch = design_notch(NotchSpec(center_hz=21.8, width_hz=10.0, depth_db=40.0), 1000.0)
>>> shaped = shape_move(move, [notch])
>>> float(shaped.profile.position_m[-1]), round(shaped.profile.dwell_s, 3)
(0.2, 0.5)
>>> 0.0 < shaped.added_delay_s < 0.5
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad
from hilident.motion.profiles import MoveProfile

__all__ = ["ShapedMove", "chain_dc_gain", "filter_setpoint", "shape_move"]

#: Default settling tolerance relative to the move's distance (0.2 m: 2 um).
RELATIVE_TOLERANCE = 1e-5


@dataclass(frozen=True, eq=False)
class ShapedMove:
    """A move whose set-point went through a notch chain on the host.

    Attributes
    ----------
    profile : MoveProfile
        The shaped set-point; its ``move_end_index`` is the first sample at the
        exact end position (the filtered set-point settled there), and its dwell
        is the original move's. ``plan`` is None.
    original : MoveProfile
        The move before shaping.
    added_delay_s : float
        How much later the shaped move reaches its end than the original, s.
    dc_gain : float
        DC gain of the chain (1 within the checked tolerance).
    tolerance_m : float
        Band around the end position the filtered set-point settled into, m.
    """

    profile: MoveProfile
    original: MoveProfile
    added_delay_s: float
    dc_gain: float
    tolerance_m: float


def _checked_sections(sections: Sequence[Biquad]) -> list[Biquad]:
    checked = []
    for i, section in enumerate(sections):
        if not isinstance(section, Biquad):
            raise DataError(f"notch chain section {i}: expected a Biquad, got {type(section).__name__}")
        if not all(math.isfinite(x) for x in (*section.b, *section.a)):
            raise DataError(f"notch chain section {i}: coefficients must be finite, got b={section.b}, a={section.a}")
        if not section.is_stable():
            raise DataError(
                f"notch chain section {i}: unstable (poles {np.round(section.poles(), 6).tolist()}); "
                "a set-point filter needs every pole inside the unit circle"
            )
        checked.append(section)
    return checked


def chain_dc_gain(sections: Sequence[Biquad]) -> float:
    """DC gain of biquads in series, the product of ``H_i(z = 1)``; 1 for an empty chain."""
    gain = 1.0
    for section in sections:
        gain *= section.dc_gain()
    return gain


def filter_setpoint(values, sections: Sequence[Biquad]) -> np.ndarray:
    """Filter a set-point through ``sections`` in series, causally, starting at rest at its first value.

    The chain sees ``values - values[0]`` from zero state and the first value is
    added back, so a trajectory starting anywhere starts without a transient.

    Parameters
    ----------
    values : array_like, shape (n,)
        Set-point samples (any unit) at the rate the sections were designed for.
    sections : sequence of Biquad

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    DataError
        Non-finite samples, an empty array, or an unstable or non-finite section.
    """
    from scipy.signal import sosfilt

    x = np.asarray(values, dtype=float)
    if x.ndim != 1 or x.size == 0:
        raise DataError(f"set-point: expected a non-empty 1-D array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DataError("set-point contains NaN or infinite values")
    chain = _checked_sections(sections)
    if not chain:
        return x.copy()
    sos = np.array([[*s.b, *s.a] for s in chain])
    return sosfilt(sos, x - x[0]) + x[0]


def _decay_samples(sections: Sequence[Biquad]) -> int:
    """Samples over which the slowest pole's free response decays by a factor of 10 (at least 1)."""
    radius = max((float(np.max(np.abs(s.poles()))) for s in sections if s.poles().size), default=0.0)
    if radius <= 0.0:
        return 1
    return max(1, math.ceil(math.log(0.1) / math.log(radius)))


def shape_move(
    profile: MoveProfile,
    sections: Sequence[Biquad],
    *,
    tolerance_m: float | None = None,
    dc_gain_tolerance: float = 1e-6,
    max_extension_s: float = 10.0,
) -> ShapedMove:
    """Apply a notch chain to a move's set-point on the host; the shaped move ends exactly at the same place.

    Parameters
    ----------
    profile : MoveProfile
        The move (e.g. from :func:`~hilident.motion.profiles.trapezoid`); the
        sections run at its ``sample_rate_hz``.
    sections : sequence of Biquad
        The chain, ``b = (b0, b1, b2)``, ``a = (1, a1, a2)``, designed for the set-point rate.
    tolerance_m : float, optional
        The filtered set-point counts as settled once it stays within this of the
        end position, m; default ``1e-5 * |distance_m|``.
    dc_gain_tolerance : float
        Largest accepted ``|DC gain - 1|`` of the chain.
    max_extension_s : float
        Longest the move may be extended while the set-point settles, s.

    Returns
    -------
    ShapedMove

    Raises
    ------
    DataError
        A section that is not a stable, finite biquad; a chain whose DC gain is
        not 1; a set-point that does not settle within ``max_extension_s``.
    ConfigError
        A tolerance or extension that is not positive and finite (names the key).
    """
    if not isinstance(profile, MoveProfile):
        raise TypeError(f"profile must be a MoveProfile, got {type(profile).__name__}")
    chain = _checked_sections(sections)
    dc = chain_dc_gain(chain)
    if not abs(dc - 1.0) <= dc_gain_tolerance:
        raise DataError(
            f"notch chain has DC gain {dc:.9g}, not 1 (within {dc_gain_tolerance:g}); "
            "a shaped move would end at the wrong position"
        )
    end = float(profile.position_m[profile.move_end_index])
    start = float(profile.position_m[0])
    tol = RELATIVE_TOLERANCE * abs(end - start) if tolerance_m is None else tolerance_m
    for key, value in (("tolerance_m", tol), ("max_extension_s", max_extension_s)):
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ConfigError(key, f"must be > 0 and finite, got {value!r}")
    fs = profile.sample_rate_hz
    i_end = profile.move_end_index
    dwell_samples = profile.position_m.size - 1 - i_end
    guard = _decay_samples(chain)
    limit = i_end + 1 + math.ceil(max_extension_s * fs)
    n = min(limit, i_end + 1 + max(guard * 10, profile.position_m.size))
    while True:
        hold = n - (i_end + 1)
        x = np.concatenate([profile.position_m[: i_end + 1], np.full(hold, end)])
        y = filter_setpoint(x, chain)
        outside = np.flatnonzero(np.abs(y - end) > tol)
        settle = int(outside[-1]) + 1 if outside.size else 0
        if n - settle >= guard:
            break
        if n >= limit:
            raise DataError(
                f"the shaped set-point did not settle within {tol:g} m of the end position "
                f"in {max_extension_s:g} s; widen the tolerance or check the notch chain"
            )
        n = min(limit, 2 * n)
    settle = max(settle, i_end)
    size = settle + 1 + dwell_samples
    position = np.full(size, end)
    position[:settle] = y[:settle]
    # Velocity and acceleration are zero before the move (a trapezoid's acceleration steps at its first
    # sample): filtered from zero state, not relative to their first value.
    velocity = np.zeros(size)
    accel = np.zeros(size)
    for src, dst in ((profile.velocity_mps, velocity), (profile.accel_mps2, accel)):
        padded = np.concatenate([[0.0], src[: i_end + 1], np.zeros(max(0, settle - i_end))])
        dst[:settle] = filter_setpoint(padded, chain)[1 : settle + 1]
    shaped = MoveProfile(np.arange(size) / fs, position, velocity, accel, settle, fs, profile.distance_m, None)
    return ShapedMove(shaped, profile, (settle - i_end) / fs, dc, float(tol))


def impulse_shaped_move(profile: MoveProfile, shaper) -> ShapedMove:
    """``profile`` shaped by an input shaper (a train of impulses, fixed or scheduled by position).

    The motion (up to ``move_end_index``) goes through ``shaper.apply``; the shaped set-point reaches the end
    position exactly, ``shaper``'s duration later at most, and the original dwell follows. Velocity and
    acceleration are the shaped position's central differences (the move test streams the position).

    Parameters
    ----------
    profile : MoveProfile
    shaper : Shaper or ScheduledShaper
        Anything with ``apply(x, sample_rate_hz)`` (:mod:`hilident.motion.input_shapers`,
        :mod:`hilident.motion.scheduled_shaper`).

    Returns
    -------
    ShapedMove
        ``dc_gain`` 1 and ``tolerance_m`` 0: an impulse train's amplitudes sum to 1, so it ends where asked.
    """
    if not isinstance(profile, MoveProfile):
        raise TypeError(f"profile must be a MoveProfile, got {type(profile).__name__}")
    fs, i_end = profile.sample_rate_hz, profile.move_end_index
    end = float(profile.position_m[i_end])
    y = np.asarray(shaper.apply(profile.position_m[: i_end + 1], fs), dtype=float)
    moving = np.flatnonzero(y != end)
    settle = max(int(moving[-1]) + 1 if moving.size else 0, i_end)
    dwell_samples = profile.position_m.size - 1 - i_end
    position = np.full(settle + 1 + dwell_samples, end)
    position[:settle] = y[:settle]
    velocity = np.gradient(position) * fs
    accel = np.gradient(velocity) * fs
    shaped = MoveProfile(np.arange(position.size) / fs, position, velocity, accel, settle, fs, profile.distance_m, None)
    return ShapedMove(shaped, profile, (settle - i_end) / fs, 1.0, 0.0)
