"""Residual vibration metrics on damped sines whose answers are known in closed form."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hilident.errors import ConfigError, DataError
from hilident.motion.residual import compare_moves, reduction_db, residual_vibration

FS = 10000.0
END_S = 0.4  # the move's end on the recording's time axis
DWELL_S = 2.0
F_HZ = 21.8
SIGMA = 8.0  # 1/s: the envelope is exp(-8 t), 1e-7 of the start by the end of the dwell
OFFSET_M = 0.2


def ringing(amplitude=1e-3, sigma=SIGMA, f_hz=F_HZ, offset=OFFSET_M, slope=0.0):
    """A move that ends at END_S and rings as ``A exp(-sigma tau) cos(w tau)`` around ``offset`` after it."""
    t = np.arange(0.0, END_S + DWELL_S + 0.3, 1.0 / FS)
    tau = t - END_S
    ring = np.where(tau >= 0, amplitude * np.exp(-sigma * tau) * np.cos(2 * np.pi * f_hz * tau), 0.0)
    approach = np.where(tau < 0, offset * (t / END_S) - offset, 0.0)  # a ramp up to the end, not measured
    return t, offset + approach + ring + slope * np.maximum(tau, 0.0)


def exact_rms(amplitude, sigma, f_hz, duration):
    """RMS of ``A exp(-s t) cos(w t)`` over ``[0, D]``, from the integral in closed form."""
    w = 2 * np.pi * f_hz
    mean_part = (1 - math.exp(-2 * sigma * duration)) / (2 * sigma)
    z = complex(-2 * sigma, 2 * w)
    osc_part = ((np.exp(z * duration) - 1) / z).real
    return amplitude * math.sqrt(0.5 * (mean_part + osc_part) / duration)


def exact_trough(amplitude, sigma, f_hz):
    """The first minimum of ``A exp(-s t) cos(w t)``: at ``w t = pi - atan(s / w)``."""
    w = 2 * np.pi * f_hz
    tau = (math.pi - math.atan(sigma / w)) / w
    return amplitude * math.exp(-sigma * tau) * math.cos(w * tau)


def test_peak_to_peak_rms_and_first_peak_of_a_damped_sine():
    t, y = ringing()
    r = residual_vibration(t, y, END_S, DWELL_S)
    assert r.first_peak == pytest.approx(1e-3, rel=1e-6)
    assert r.peak_to_peak == pytest.approx(1e-3 - exact_trough(1e-3, SIGMA, F_HZ), rel=1e-4)
    assert r.rms == pytest.approx(exact_rms(1e-3, SIGMA, F_HZ, DWELL_S), rel=2e-3)
    assert r.final_value == pytest.approx(OFFSET_M, abs=1e-9)


@pytest.mark.parametrize("fraction", [0.2, 0.05, 0.01])
def test_settling_time_is_where_the_envelope_enters_the_band(fraction):
    t, y = ringing()
    r = residual_vibration(t, y, END_S, DWELL_S, band_fraction=fraction)
    assert r.band == pytest.approx(fraction * 1e-3)
    envelope_s = math.log(1 / fraction) / SIGMA  # exp(-sigma t) = fraction
    half_period = 0.5 / F_HZ
    # the last excursion beyond the band is the last peak before the envelope gets there
    assert envelope_s - half_period <= r.settling_time_s <= envelope_s + 1 / FS


def test_an_absolute_band_in_the_signals_unit():
    t, y = ringing()
    r = residual_vibration(t, y, END_S, DWELL_S, band=1e-4)
    assert r.band == 1e-4
    assert r.settling_time_s == pytest.approx(math.log(10) / SIGMA, abs=0.5 / F_HZ)
    assert residual_vibration(t, y, END_S, DWELL_S, band=2e-3).settling_time_s == 0.0  # never outside
    t, y = ringing(sigma=0.0)  # no damping: still ringing when the dwell ends
    assert residual_vibration(t, y, END_S, DWELL_S, band=1e-4).settling_time_s is None


def test_linear_detrend_removes_a_creep_that_final_value_counts():
    t, y = ringing(slope=2e-4)  # 0.4 mm of creep over the dwell, on a 1 mm ring
    clean = exact_rms(1e-3, SIGMA, F_HZ, DWELL_S)
    linear = residual_vibration(t, y, END_S, DWELL_S, detrend="linear")
    final = residual_vibration(t, y, END_S, DWELL_S, detrend="final")
    assert linear.rms == pytest.approx(clean, rel=0.02)
    assert final.rms > 1.5 * clean
    assert linear.final_value == pytest.approx(OFFSET_M + 2e-4 * DWELL_S, abs=2e-6)


def test_reduction_between_two_moves_in_db_with_one_band():
    t, loud = ringing(amplitude=1e-3)
    _, quiet = ringing(amplitude=1e-4)
    c = compare_moves((t, loud, END_S), (t, quiet, END_S), DWELL_S)
    assert c.rms_reduction_db == pytest.approx(20.0, abs=1e-6)
    assert c.peak_to_peak_reduction_db == pytest.approx(20.0, abs=1e-6)
    assert c.with_notch.band == c.without.band == pytest.approx(5e-5)
    # the same band: the quieter move settles ln(10)/sigma sooner
    assert c.without.settling_time_s - c.with_notch.settling_time_s == pytest.approx(math.log(10) / SIGMA, abs=1 / F_HZ)
    # a louder second move is a negative reduction
    assert compare_moves((t, quiet, END_S), (t, loud, END_S), DWELL_S).rms_reduction_db == pytest.approx(-20.0)


def test_dicts_carry_units_in_their_keys_and_are_json():
    t, y = ringing(offset=0.0)
    acc = residual_vibration(t, 9.81 * y, END_S, DWELL_S, unit="mps2")
    d = acc.as_dict()
    assert d["rms_mps2"] == acc.rms and d["peak_to_peak_mps2"] == acc.peak_to_peak
    assert {"band_mps2", "first_peak_mps2", "settling_time_s", "move_end_s", "dwell_s"} <= set(d)
    c = compare_moves((t, y, END_S), (t, np.zeros_like(y), END_S), DWELL_S)
    out = json.loads(json.dumps(c.as_dict(), allow_nan=False))  # an infinite reduction is null, not Infinity
    assert out["rms_reduction_db"] is None and out["without"]["rms_m"] == pytest.approx(c.without.rms)


def test_reduction_db_rejects_what_cannot_be_reduced():
    assert reduction_db(2.0, 1.0) == pytest.approx(20 * math.log10(2.0))
    with pytest.raises(DataError, match="nothing to reduce"):
        reduction_db(0.0, 1.0)
    with pytest.raises(DataError):
        reduction_db(float("nan"), 1.0)


def test_bad_data_is_a_data_error():
    t, y = ringing()
    y_nan = y.copy()
    y_nan[int((END_S + 0.5) * FS)] = np.nan
    with pytest.raises(DataError, match="1 NaN"):
        residual_vibration(t, y_nan, END_S, DWELL_S)
    with pytest.raises(DataError, match="holds 0 samples"):
        residual_vibration(t, y, t[-1] + 1.0, DWELL_S)
    with pytest.raises(DataError, match="one length"):
        residual_vibration(t, y[:-1], END_S, DWELL_S)
    with pytest.raises(DataError, match="increasing"):
        residual_vibration(t[::-1], y, END_S, DWELL_S)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        (dict(dwell_s=0.0), "dwell_s"),
        (dict(band=-1.0), "band"),
        (dict(band_fraction=float("inf")), "band_fraction"),
        (dict(detrend="quadratic"), "detrend"),
        (dict(unit="m/s"), "unit"),
        (dict(move_end_s=float("nan")), "move_end_s"),
    ],
)
def test_bad_settings_are_config_errors_naming_the_key(kwargs, key):
    t, y = ringing()
    args = dict(move_end_s=END_S, dwell_s=DWELL_S)
    args.update(kwargs)
    with pytest.raises(ConfigError) as err:
        residual_vibration(t, y, **args)
    assert err.value.key == key
