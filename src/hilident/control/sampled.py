"""From a response recorded at the sample rate to the plant the drive's loop sees at its own rate.

A drive runs its loop every tick (``1 / loop_rate_hz``) but records one sample
every ``D`` ticks. In a run of torque mode each sample's set-point is held over
its ``D`` ticks from the first, passes the drive's delay (``z^-d``) and current
loop (``G``) and drives the plant; each sample records the torque (at the
period's first tick, or its mean over the period's ticks: the driver's
``sampling``) and the velocity estimate at the first tick. With the hold
``Hold(f) = sum_{i<D} z^-i`` and the torque's sampling kernel ``A(f)`` (1, or
``sum_{i<D} z^i / D`` for the mean), both at the tick rate, the response
recorded from torque to velocity is

``P(f) = HV(f) G(f) z^-d Hold(f) / sum_{k<D} [A G z^-d Hold](f + k f_s)``

where ``HV`` is the loop's own plant (motor torque to velocity estimate, tick by
tick) and the sum runs over the images of the sample rate ``f_s`` that fold
onto ``f``. The velocity's images are left out: above the first image the
mechanics fall off and the hold's images are small, so they add well under 1 %
below a tenth of the sample rate. :func:`loop_plant` inverts it.
"""

from __future__ import annotations

import math

import numpy as np

from hilident.errors import ConfigError

__all__ = ["loop_plant", "ticks_per_sample"]


def ticks_per_sample(loop_rate_hz: float, sample_rate_hz: float) -> int:
    """``D``: loop ticks per recorded sample.

    Raises
    ------
    ConfigError
        The sample rate does not divide the loop rate.
    """
    ratio = loop_rate_hz / sample_rate_hz
    d = int(round(ratio))
    if d < 1 or abs(ratio - d) > 1e-9 * ratio:
        raise ConfigError(
            "run.sample_rate_hz", f"{sample_rate_hz:g} Hz does not divide the loop rate {loop_rate_hz:g} Hz"
        )
    return d


def _tick_path(frequency_hz: np.ndarray, loop_rate_hz: float, current_loop_hz: float, delay_ticks: int, d: int):
    """``G z^-d Hold`` at the tick rate: the set-point held over ``d`` ticks, delayed, through the current loop."""
    zi = np.exp(-2j * np.pi * frequency_hz / loop_rate_hz)
    b = -math.expm1(-2.0 * math.pi * current_loop_hz / loop_rate_hz) if math.isfinite(current_loop_hz) else 1.0
    hold = sum(zi**i for i in range(d))
    return b / (1.0 - (1.0 - b) * zi) * zi**delay_ticks * hold, zi


def loop_plant(
    frequency_hz,
    recorded,
    loop_rate_hz: float,
    sample_rate_hz: float,
    current_loop_hz: float,
    delay_ticks: int,
    torque_sampling: str = "instant",
) -> np.ndarray:
    """The plant the loop sees tick by tick (motor torque to velocity estimate) from the recorded response.

    Parameters
    ----------
    frequency_hz : array_like
        Frequencies of ``recorded``, Hz, below half the sample rate.
    recorded : array_like of complex
        Recorded torque-to-velocity response at those frequencies, (m/s) per N·m.
    loop_rate_hz, sample_rate_hz : float
        The drive's loop rate and the recording's sample rate, Hz.
    current_loop_hz : float
        The current loop's bandwidth, Hz (``inf``: ideal).
    delay_ticks : int
        The drive's delay from its torque command to the current loop, ticks.
    torque_sampling : {"instant", "mean"}
        How each sample records the torque: at the period's first tick, or
        the mean over the period's ticks.

    Returns
    -------
    ndarray of complex
        ``HV`` at ``frequency_hz``, (m/s) per N·m.
    """
    if torque_sampling not in ("instant", "mean"):
        raise ValueError(f"torque_sampling must be 'instant' or 'mean', got {torque_sampling!r}")
    f = np.asarray(frequency_hz, dtype=float)
    d = ticks_per_sample(loop_rate_hz, sample_rate_hz)
    path, _ = _tick_path(f, loop_rate_hz, current_loop_hz, delay_ticks, d)
    folded = np.zeros_like(path)
    for k in range(d):
        image, zi = _tick_path(f + k * sample_rate_hz, loop_rate_hz, current_loop_hz, delay_ticks, d)
        kernel = sum(zi ** (-i) for i in range(d)) / d if torque_sampling == "mean" else 1.0
        folded = folded + kernel * image
    return np.asarray(recorded) * folded / path
