"""Transfer-function structure chosen by a criterion that penalises order, and roots the data do not support."""

import dataclasses

import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.tffit import classify_roots, fit_transfer_function, select_order, select_structure

TWO_PI = 2 * np.pi


def noisy_frf(num, den, f, coherence, n_averages=8, seed=0):
    """Analytic response plus complex noise of the size an H1 estimate with this coherence has."""
    rng = np.random.default_rng(seed)
    h = signal.freqs(num, den, TWO_PI * f)[1]
    eps = np.sqrt((1 - coherence) / (2 * n_averages * coherence))
    h = h + eps * np.abs(h) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    return FrequencyResponse(f, h, np.full(f.size, coherence), n_averages, "h1")


def msd_velocity(f0=3.0, zeta=0.02, m=2.0):
    """Force to velocity of a mass-spring-damper, s / (m s^2 + b s + k): second order, relative degree 1."""
    w0 = TWO_PI * f0
    return [1.0, 0.0], [m, 2 * zeta * w0 * m, w0**2 * m]


def two_mass_velocity(f0=20.0, zeta=0.02):
    """Torque to motor velocity of a free two-mass axis: one integrator, a zero pair, a pole pair."""
    m1, m2 = 40.0, 10.0
    w0 = TWO_PI * f0
    k = w0**2 * m1 * m2 / (m1 + m2)
    d = 2 * zeta * w0 * m1 * m2 / (m1 + m2)
    return [m2, d, k], np.polymul([1.0, 0.0], [m1 * m2, d * (m1 + m2), k * (m1 + m2)])


F = np.arange(0.5, 100.0, 0.5)


@pytest.mark.parametrize("criterion", ["mdl", "validation"])
@pytest.mark.parametrize("coherence", [0.8, 0.99])
def test_second_order_system_gets_a_second_order_model(criterion, coherence):
    frf = noisy_frf(*msd_velocity(), F, coherence, seed=1)
    fit, table = select_structure(frf, 4, criterion=criterion)
    assert (fit.n_num, fit.n_den, fit.integrators) == (1, 2, 0)
    assert sum(r.selected for r in table) == 1 and len(table) > 20  # degrees, integrators and relative degree tried
    (mode,) = classify_roots(fit).modes
    assert mode[0] == pytest.approx(3.0, rel=0.005) and mode[1] == pytest.approx(0.02, rel=0.15)


def test_aic_keeps_extra_order_where_mdl_does_not():
    # AIC's penalty (2 per parameter) lets a pole pair fitted to noise through
    frf = noisy_frf(*msd_velocity(), F, 0.8, seed=1)
    aic_fit, _ = select_order(frf, max_order=4, criterion="aic", weights="coherence")
    mdl_fit, _ = select_structure(frf, 4)
    assert aic_fit.n_params > mdl_fit.n_params


def test_two_mass_axis_gets_its_integrator_and_mode():
    frf = noisy_frf(*two_mass_velocity(), F, 0.9, seed=2)
    fit, _ = select_structure(frf, 4)
    assert (fit.n_num, fit.n_den, fit.integrators) == (2, 2, 1)
    roots = classify_roots(fit)
    (mode,) = roots.modes
    assert mode[0] == pytest.approx(20.0, rel=0.005)
    (anti,) = roots.antiresonances  # sqrt(k / m2) of the load on its spring
    assert anti[0] == pytest.approx(20.0 * np.sqrt(40.0 / 50.0), rel=0.01)
    assert roots.stable and roots.rhp_zeros == []


def test_each_part_of_the_structure_can_be_fixed():
    frf = noisy_frf(*two_mass_velocity(), F, 0.9, seed=2)
    fit, table = select_structure(frf, 6, order=5, relative_degree=2, integrators=1)
    assert (fit.n_den + fit.integrators, fit.n_den + fit.integrators - fit.n_num, fit.integrators) == (5, 2, 1)
    assert len(table) == 1
    fit, table = select_structure(frf, 4, integrators=0)
    assert fit.integrators == 0 and all(r.integrators == 0 for r in table)
    with pytest.raises(ConfigError, match="criterion"):
        select_structure(frf, 4, criterion="eyeball")
    with pytest.raises(ConfigError, match="model_relative_degree"):
        select_structure(frf, 4, order=2, relative_degree=3)


def test_right_half_plane_zero_is_reported_as_such():
    # (1 - s/z) / (s^2 + 2 zeta w s + w^2): a non-minimum-phase zero at 40 Hz
    w0, z = TWO_PI * 10.0, TWO_PI * 40.0
    num, den = [-1.0 / z, 1.0], [1.0, 2 * 0.05 * w0, w0**2]
    fit = fit_transfer_function(noisy_frf(num, den, F, 0.99), 1, 2, weights="coherence")
    roots = classify_roots(fit)
    (rhp,) = roots.rhp_zeros
    assert rhp["frequency_hz"] == pytest.approx(40.0, rel=0.02) and rhp["kind"] == "real"
    assert rhp["equivalent_delay_s"] == pytest.approx(1 / z, rel=0.02)
    assert "right-half-plane" in rhp["explanation"] and "no anti-resonance" in rhp["explanation"]
    assert roots.antiresonances == [] and roots.real_zeros_hz == []  # never a negative corner frequency


def test_unsupported_poles_are_flagged_and_stability_is_honest():
    fit = fit_transfer_function(noisy_frf(*msd_velocity(), F, 0.99), 1, 2, weights="coherence")
    assert classify_roots(fit).stable
    w = TWO_PI * 7.0
    near_axis = np.array([-1e-12 * w + 1j * w, -1e-12 * w - 1j * w])
    far = np.array([-6.8e7 + 0j])
    odd = dataclasses.replace(fit, poles=np.concatenate([fit.poles, near_axis, far]))
    roots = classify_roots(odd)
    assert [m[0] for m in roots.modes] == pytest.approx([3.0], rel=0.01)
    reasons = {round(p["frequency_hz"], 1): p["reason"] for p in roots.flagged_poles}
    assert "imaginary axis" in reasons[7.0]
    assert "far outside" in reasons[round(6.8e7 / TWO_PI, 1)]
    assert not roots.stable and roots.stability.startswith("marginal")


def test_mode_narrower_than_the_line_spacing_is_flagged():
    fit = fit_transfer_function(noisy_frf(*msd_velocity(zeta=0.02), F, 0.99), 1, 2, weights="coherence")
    # 2 zeta f = 0.12 Hz: resolved by 0.5 Hz lines only to a tenth of a line, but not by 5 Hz lines
    assert classify_roots(fit, resolution_hz=0.5).modes
    roots = classify_roots(fit, resolution_hz=5.0)
    assert roots.modes == [] and "line spacing" in roots.flagged_poles[0]["reason"]


def test_identification_keys_fix_the_structure_of_the_plant_model():
    from hilident.config.tables import parse_config
    from hilident.pipeline.plant_model import fit_plant_model

    limits = "[limits]\ntorque_nm = 10\nvelocity_mps = 1\nposition_min_m = -1\nposition_max_m = 1\n"
    cfg = parse_config(
        limits + '[identification]\nmodel_order = "4"\nmodel_integrators = "1"\n'
        'model_relative_degree = "1"\nmodel_criterion = "validation"\n'
    ).identification
    frf = noisy_frf(*two_mass_velocity(), F, 0.9, seed=2)
    model = fit_plant_model(
        frf,
        (0.5, 99.0),
        cfg.model_max_order,
        0.0,
        cfg.model_order,
        cfg.model_relative_degree,
        cfg.model_integrators,
        cfg.model_criterion,
    )
    d = model.to_dict()
    assert (d["n_den"] + d["integrators"], d["integrators"], d["relative_degree"]) == (4, 1, 1)
    assert d["criterion"] == "validation"
    assert parse_config(limits + "[identification]\nmodel_order = 3\n").identification.model_order == "3"
    with pytest.raises(ConfigError, match="identification.model_order"):
        parse_config(limits + "[identification]\nmodel_order = 0\n")  # not a choice
