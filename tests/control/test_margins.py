"""Margins and bandwidths against loops whose figures are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.control import bandwidth_hz, loop_margins

F = np.geomspace(0.1, 1000.0, 20000)
S = 2j * np.pi * F


@pytest.mark.parametrize("gain_rad_s,delay_s", [(50.0, 0.004), (200.0, 0.001), (20.0, 0.02)])
def test_an_integrator_with_a_delay(gain_rad_s, delay_s):
    # L = K e^(-s tau) / s: crossover at w = K, phase margin 90 deg - K tau, phase crossover at pi / (2 tau)
    m = loop_margins(F, gain_rad_s * np.exp(-S * delay_s) / S)
    assert m.crossover_hz == pytest.approx(gain_rad_s / (2 * math.pi), rel=1e-4)
    assert m.phase_margin_deg == pytest.approx(90.0 - math.degrees(gain_rad_s * delay_s), abs=0.01)
    phase_crossover = math.pi / (2 * delay_s)
    assert m.gain_margin_hz == pytest.approx(phase_crossover / (2 * math.pi), rel=1e-4)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(phase_crossover / gain_rad_s), abs=0.01)


def test_the_sensitivity_peak_is_the_inverse_distance_to_minus_one():
    loop = 100.0 * np.exp(-S * 0.008) / S
    m = loop_margins(F, loop)
    assert m.sensitivity_peak == pytest.approx(1.0 / np.min(np.abs(1.0 + loop)), rel=1e-9)
    assert m.sensitivity_peak > 1.0 and m.sensitivity_peak_db == pytest.approx(20 * math.log10(m.sensitivity_peak))


def test_an_unstable_loop_has_negative_margins():
    m = loop_margins(F, 400.0 * np.exp(-S * 0.005) / S)  # K tau = 2 rad > pi / 2
    assert m.phase_margin_deg == pytest.approx(90.0 - math.degrees(2.0), abs=0.01)
    # the first crossing of the negative real axis lies outside the unit circle; the gain margin is the
    # next one's, inside it (5 pi / (2 tau)): a negative phase margin is what says the loop is unstable
    assert m.gain_margin_hz == pytest.approx(250.0, rel=1e-4)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(5 * math.pi / 2 / 0.005 / 400.0), abs=0.01)


def test_a_loop_that_never_crosses_has_infinite_margins_and_none_for_json():
    m = loop_margins(F, 0.1 / (1 + S / 10))
    assert m.phase_margin_deg == math.inf and m.gain_margin_db == math.inf
    assert m.to_dict()["phase_margin_deg"] is None and math.isnan(m.crossover_hz)


def test_the_bandwidth_of_a_first_order_loop_is_its_corner():
    assert bandwidth_hz(F, 1.0 / (1.0 + S / (2 * math.pi * 37.0))) == pytest.approx(37.0, rel=1e-3)
    assert math.isnan(bandwidth_hz(F, np.ones_like(S)))


def test_a_grid_that_is_not_increasing_is_refused():
    with pytest.raises(ValueError, match="increasing"):
        loop_margins(F[::-1], 1.0 / S[::-1])


def test_the_margins_agree_with_python_control_on_a_drive_like_loop():
    control = pytest.importorskip("control")
    loop = 100 * (1 + 1 / (0.05 * S)) * 10 / (10 * S) * np.exp(-S * 0.0005) / (1 + S / (2 * np.pi * 500))
    gm, pm, _, wpc, wgc, _ = control.stability_margins(control.frd(loop, 2 * np.pi * F))
    m = loop_margins(F, loop)
    assert m.gain_margin_db == pytest.approx(20 * np.log10(gm), abs=1e-3)
    assert m.phase_margin_deg == pytest.approx(pm, abs=1e-3)
    assert (m.gain_margin_hz, m.crossover_hz) == pytest.approx((wpc / (2 * np.pi), wgc / (2 * np.pi)), rel=1e-4)
