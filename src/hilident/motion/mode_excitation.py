"""How strongly a move's set-point leaves a flexible mode ringing: known before the axis moves.

A stiff servo makes the cart follow its set-point, so the load on a spring behind it sees the set-point's
acceleration as a base excitation. The load's deflection ``x`` then obeys
``x'' + 2 zeta w x' + w^2 x = -a(t)``, and what rings after the move is the free vibration left when
the set-point comes to rest. Its amplitude, divided by ``a_max / w^2`` (the deflection the move's peak
acceleration would hold the load at), is the **mode excitation** ``V``:

* ``V = 1`` for a single step of acceleration;
* a trapezoid's two acceleration steps and two deceleration steps add up to ``V`` between 0 and 4: it is
  ``4 |sin(pi f T_a)| |sin(pi f (T - T_a))|`` undamped (``T_a`` the acceleration time, ``T`` the move's),
  so a move whose acceleration lasts a whole number of the mode's periods hardly excites it at all;
* a notch on the set-point lowers ``V``; ``20 log10`` of the ratio is what it takes off the ringing the
  set-point causes.

The move test (:mod:`hilident.session.move_test`) reports ``V`` with and without the notch at the mode where each
move ends: a move with ``V`` well below 1 rings little more than the axis does at rest, and its "reduction"
then measures the rest vibration and the friction at the stop, not the notch. :func:`exciting_move` finds
the velocity and acceleration nearest the configured ones that excite every mode of a set of moves.

This is the residual-vibration measure of input shaping (Singer and Seering, 1990), normalised to a
step of the move's peak acceleration.

Examples
--------
>>> from hilident.motion.profiles import trapezoid
>>> move = trapezoid(0.2, 0.3, 2.0, 1000.0, dwell_s=0.2)   # accelerates for 0.15 s
>>> round(mode_excitation(move.position_m, 1000.0, move.move_end_index, 20.0), 2)   # 3 periods: hardly
0.06
>>> round(mode_excitation(move.position_m, 1000.0, move.move_end_index, 23.3), 2)   # 3.5 periods: fully
3.98
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from hilident.errors import DataError

__all__ = [
    "GOOD_EXCITATION",
    "WEAK_EXCITATION",
    "ExcitingMove",
    "exciting_move",
    "mode_excitation",
    "peak_acceleration",
]

#: Below this ``V`` a move excites the mode less than one step of its acceleration would: weakly.
WEAK_EXCITATION = 1.0
#: The ``V`` a suggested move reaches at every mode, where it can: half again a step, some way from the zeros.
GOOD_EXCITATION = 1.5


def _acceleration(position_m, sample_rate_hz: float) -> np.ndarray:
    """The set-point's acceleration by central differences, m/s^2 (sample ``i`` of ``i = 1 .. n - 2``)."""
    x = np.asarray(position_m, dtype=float)
    if x.ndim != 1 or x.size < 3 or not np.all(np.isfinite(x)):
        raise DataError(f"set-point: expected a finite 1-D array of at least 3 samples, got shape {x.shape}")
    if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise DataError(f"set-point: sample rate must be > 0, got {sample_rate_hz!r}")
    return np.diff(x, 2) * sample_rate_hz * sample_rate_hz


def peak_acceleration(position_m, sample_rate_hz: float) -> float:
    """The largest ``|acceleration|`` of a sampled set-point, m/s^2."""
    return float(np.max(np.abs(_acceleration(position_m, sample_rate_hz))))


def mode_excitation(
    position_m,
    sample_rate_hz: float,
    end_index: int,
    frequency_hz: float,
    damping_ratio: float = 0.0,
    *,
    reference_accel_mps2: float | None = None,
) -> float:
    """The mode excitation ``V`` of a sampled set-point: the free vibration it leaves at ``end_index``.

    Parameters
    ----------
    position_m : array_like, shape (n,)
        The set-point, m, at ``sample_rate_hz``.
    sample_rate_hz : float
    end_index : int
        Sample at which the move counts as ended (its ``move_end_index``); the ringing is taken there, what
        acceleration the set-point still has after it (a shaped set-point's tail) is left out.
    frequency_hz : float
        The mode's natural frequency, Hz.
    damping_ratio : float
        The mode's damping ratio, in [0, 1): the ringing from the start of a long move has partly died out
        by its end. The loop holding the cart damps the mode more than the plant alone does (about twice, on
        the gantry twin); with the plant's damping, ``V`` comes out a little deeper at its zeros and higher at
        its peaks than the move will ring.
    reference_accel_mps2 : float, optional
        Acceleration of the reference step, m/s^2; default the set-point's own peak. Give the unshaped move's
        peak when comparing a shaped set-point with it.

    Returns
    -------
    float
        The ringing's amplitude in units of ``reference_accel / w^2``; 0 for a set-point that never
        accelerates.
    """
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        raise DataError(f"mode excitation: frequency must be > 0 Hz, got {frequency_hz!r}")
    if not (math.isfinite(damping_ratio) and 0 <= damping_ratio < 1):
        raise DataError(f"mode excitation: damping ratio must be in [0, 1), got {damping_ratio!r}")
    accel = _acceleration(position_m, sample_rate_hz)
    reference = float(np.max(np.abs(accel))) if reference_accel_mps2 is None else float(reference_accel_mps2)
    if reference <= 0:
        return 0.0
    last = min(max(int(end_index), 1), accel.size)  # acceleration sample i sits at set-point sample i + 1
    t = np.arange(1, last + 1) / sample_rate_hz
    w = 2.0 * math.pi * frequency_hz
    wd = w * math.sqrt(1.0 - damping_ratio * damping_ratio)
    t_end = last / sample_rate_hz
    # Duhamel's integral of the oscillator's impulse response, as a complex amplitude at t_end
    kernel = np.exp(-damping_ratio * w * (t_end - t) + 1j * wd * t)
    amplitude = abs(np.sum(accel[:last] * kernel)) / sample_rate_hz / wd
    return float(amplitude * w * w / reference)


@dataclass(frozen=True)
class ExcitingMove:
    """The move :func:`exciting_move` found.

    Attributes
    ----------
    max_velocity_mps, max_accel_mps2 : float
        Its limits, m/s and m/s^2.
    min_excitation : float
        Its smallest ``V`` over the moves and modes it was asked for.
    """

    max_velocity_mps: float
    max_accel_mps2: float
    min_excitation: float


def exciting_move(
    profile: Callable[[float, float, float], tuple[np.ndarray, int]],
    distances_m: Sequence[float],
    modes: Sequence[Sequence[tuple[float, float]]],
    sample_rate_hz: float,
    velocities_mps: Iterable[float],
    accels_mps2: Iterable[float],
    configured: tuple[float, float],
    target: float = GOOD_EXCITATION,
) -> ExcitingMove | None:
    """Of the candidate velocity and acceleration limits, the nearest to the configured ones whose moves
    excite every mode at ``V >= target``; else those that excite the least excited mode most.

    Parameters
    ----------
    profile : callable
        ``profile(distance_m, max_velocity_mps, max_accel_mps2) -> (position_m, end_index)``: the move's
        set-point at ``sample_rate_hz`` (the same profile kind and dwell as the configured move).
    distances_m : sequence of float
        One signed distance per move.
    modes : sequence of sequences of (frequency_hz, damping_ratio)
        The modes at each move's end, aligned with ``distances_m``.
    sample_rate_hz : float
    velocities_mps, accels_mps2 : iterable of float
        The candidates, m/s and m/s^2, tried in every combination.
    configured : (float, float)
        The configured velocity and acceleration limits; nearness is the larger of the two ratios to them.
    target : float
        The ``V`` every mode should reach.

    Returns
    -------
    ExcitingMove or None
        None without candidates or modes.
    """
    v0, a0 = configured
    accels = [float(a) for a in accels_mps2]  # walked once per velocity
    found = []
    for v in velocities_mps:
        for a in accels:
            worst = math.inf
            for distance, here in zip(distances_m, modes, strict=True):
                position, end = profile(distance, v, a)
                for f, zeta in here:
                    worst = min(worst, mode_excitation(position, sample_rate_hz, end, f, zeta))
            if math.isfinite(worst):
                found.append(ExcitingMove(float(v), float(a), float(worst)))
    if not found:
        return None
    reaching = [m for m in found if m.min_excitation >= target]
    if not reaching:
        return max(found, key=lambda m: m.min_excitation)
    return min(
        reaching,
        key=lambda m: (
            max(abs(math.log(m.max_velocity_mps / v0)), abs(math.log(m.max_accel_mps2 / a0))),
            -m.min_excitation,
        ),
    )
