"""The filter slots and the plant together, measured in closed loop (``pipeline.responses.filtered_plant_response``).

A map's verification excites the held axis ahead of the filter slots: the loop response ``y/r`` then carries the
loop's sensitivity, and only the ratio ``(y/r) / (u/r)`` with ``u`` the command entering the slots is the filtered
plant ``N G`` an open-loop torque run would measure.
"""

from __future__ import annotations

from functools import reduce
from pathlib import Path

import numpy as np
from scipy import signal

from hilident.config.tables import load_config
from hilident.pipeline.responses import filtered_plant_response, loop_response

FS = 1000.0
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml"


def _conv(*polys):
    return reduce(np.convolve, polys)


def _add(p, q):
    """Sum of two polynomials in z^-1 (aligned at their first coefficient)."""
    out = np.zeros(max(len(p), len(q)))
    out[: len(p)] += p
    out[: len(q)] += q
    return out


def _closed_loop(period: int, periods: int):
    """A two-mass axis (velocity out) held by a PI velocity loop with one sample of delay, a 20 Hz notch in the
    loop after the injection point, excited by a periodic multisine: ``r``, ``u`` (controller output plus
    injection, the notch's input), ``y``, and the truth ``N G`` as polynomials."""
    m1, m2, w0, zeta = 40.0, 10.0, 2 * np.pi * 20.0, 0.02
    k = w0**2 * m1 * m2 / (m1 + m2)
    d = 2 * zeta * w0 * m1 * m2 / (m1 + m2)
    num, den = [m2, d, k], np.polyadd(np.polymul([m1, 20.0], [m2, d, k]), [m2 * d, m2 * k, 0.0])
    bg, ag, _ = signal.cont2discrete((num, den), 1.0 / FS, method="zoh")
    bg = np.ravel(bg)
    kp = 50.0 * 2 * np.pi * 5.0
    ki = kp * 2 * np.pi * 1.0
    bc, ac = np.array([0.0, kp + ki / FS, -kp]), np.array([1.0, -1.0])
    bn, an = signal.iirnotch(20.0, 20.0 / 6.0, fs=FS)
    closed = _add(_conv(ac, ag, an), _conv(bc, bg, bn))
    assert np.max(np.abs(np.roots(closed))) < 1.0
    rng = np.random.default_rng(7)
    spec = np.zeros(period // 2 + 1, complex)
    bins = np.arange(2, 200)
    spec[bins] = np.exp(2j * np.pi * rng.random(bins.size))
    r = np.tile(np.fft.irfft(spec, n=period), periods)
    r *= 5.0 / np.abs(r).max()
    u = signal.lfilter(_conv(ac, ag, an), closed, r)  # u = S r
    y = signal.lfilter(_conv(bg, bn, ac), closed, r)  # y = G N S r
    skip = 3 * period  # the transient
    return r[skip:], u[skip:], y[skip:], (_conv(bg, bn), _conv(ag, an))


def test_the_ratio_of_the_two_responses_is_the_filtered_plant_where_the_loop_response_is_not():
    period = 2000
    r, u, y, (b_true, a_true) = _closed_loop(period, 8)
    cfg = load_config(CONFIG).identification
    loop, _ = loop_response(r, y, FS, cfg, period_samples=period)
    command, _ = loop_response(r, u, FS, cfg, period_samples=period)
    plant = filtered_plant_response(loop, command)
    f = plant.frequency_hz
    lines = (f >= 2.0) & (f <= 90.0) & (plant.coherence > 0.9)
    assert lines.sum() > 150
    true_db = 20 * np.log10(np.abs(signal.freqz(b_true, a_true, worN=f[lines], fs=FS)[1]))
    assert np.max(np.abs(20 * np.log10(np.abs(plant.response[lines])) - true_db)) < 0.05
    # the loop response is another thing: near the crossover and the notch it is several dB off N G
    loop_db = 20 * np.log10(np.abs(loop.response[lines]))
    assert np.max(np.abs(loop_db - true_db)) > 6.0
