"""The velocity-ramp profile's arguments checked and its length and travel computed, without numpy.

The config loader checks a friction test with :func:`ramp_extent` before
anything is generated; :func:`hilident.signals.velocity_ramps` builds the
profile from the same :func:`_ramp_legs`. Kept free of numpy so that a config
error appears before the numerics are imported.
"""

from __future__ import annotations

import math

from hilident.errors import ConfigError
from hilident.signals import _checks as chk


def _as_sequence(value) -> tuple:
    """``value`` as a tuple of its items, a single value (a number, a string, a table, a 0-d array) as one."""
    if isinstance(value, (str, bytes, dict)) or getattr(value, "ndim", None) == 0 or not hasattr(value, "__iter__"):
        return (value,)
    return tuple(value)


def _ramp_legs(speeds_mps, hold_s, accel_mps2, sample_rate_hz, settle_s, alternate):
    """Checked arguments of :func:`velocity_ramps`: rate, legs, ramp and hold samples; nothing allocated."""
    fs = chk.positive("sample_rate_hz", sample_rate_hz)
    hold = chk.positive("hold_s", hold_s)
    accel = chk.positive("accel_mps2", accel_mps2)
    settle = chk.non_negative("settle_s", settle_s)
    if settle >= hold:
        raise ConfigError("settle_s", f"must be shorter than hold_s {hold:g} s, got {settle:g}")
    speeds = tuple(chk.finite("speeds_mps", v) for v in _as_sequence(speeds_mps))
    if not speeds:
        raise ConfigError("speeds_mps", "needs at least one speed")
    if any(v == 0.0 for v in speeds):
        raise ConfigError("speeds_mps", f"speeds must be non-zero, got {chk.show(list(speeds))}")
    n_hold = chk.n_samples("hold_s", hold, fs)
    n_settle = int(round(settle * fs))
    if n_settle >= n_hold:
        raise ConfigError("settle_s", f"leaves no sample of the {hold:g} s hold at {fs:g} Hz")
    legs = [u for v in speeds for u in ((v, -v) if alternate else (v,))]
    ramps = [_ramp_samples(v, accel, fs) for v in legs]
    ramp_total, hold_total = 2 * sum(ramps), n_hold * len(legs)
    chk.at_most("accel_mps2" if ramp_total > hold_total else "hold_s", ramp_total + hold_total)
    return fs, legs, ramps, n_hold, n_settle


def ramp_extent(speeds_mps, hold_s, accel_mps2, sample_rate_hz, settle_s, alternate=True) -> tuple[int, float]:
    """Length and travel of :func:`velocity_ramps` with these arguments, computed without building it.

    Returns
    -------
    n_samples : int
        Samples of the set-point.
    max_excursion_m : float
        Largest distance from the start position in m (as ``RampProfile.max_excursion_m``).

    Raises
    ------
    ConfigError
        The arguments :func:`velocity_ramps` refuses, including a profile longer than
        :data:`~hilident.signals._checks.MAX_SAMPLES`.
    """
    fs, legs, ramps, n_hold, _ = _ramp_legs(speeds_mps, hold_s, accel_mps2, sample_rate_hz, settle_s, alternate)
    # a leg's samples sum to v * (n_ramp - 1 + n_hold); it starts and ends at 0, so that sum / fs is its travel
    position, extreme = 0.0, 0.0
    for v, n_ramp in zip(legs, ramps, strict=False):
        position += v * (n_ramp - 1 + n_hold) / fs
        extreme = max(extreme, abs(position))
    return sum(2 * r + n_hold for r in ramps), extreme


def _ramp_samples(v: float, accel: float, fs: float) -> int:
    """Samples of one ramp from 0 to ``v`` at ``accel`` (at least one), bounded before any allocation."""
    exact = abs(v) / accel * fs
    if not exact <= chk.MAX_SAMPLES:
        raise ConfigError("accel_mps2", f"a ramp to {v:g} m/s at {accel:g} m/s^2 {chk.too_many(exact)}")
    return max(1, int(math.ceil(exact - 1e-9)))
