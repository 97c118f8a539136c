"""The joint two-mass fit over the workspace: exact data, data simulated on the emulator's plant, refusals."""

import json
import math

import numpy as np
import pytest
from scipy import signal

from hilident.emulator.plant import Plant, StribeckFriction, TwoMass, modes
from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import periodic_frf
from hilident.ident.map_fit import (
    WorkspaceMode,
    compare_modes,
    fit_workspace_responses,
    fit_workspace_two_mass,
    two_mass_velocity_response,
)
from hilident.ident.resonance import find_resonances
from hilident.io.serialise import to_jsonable
from hilident.signals.generators import multisine

M1, M2, C, B, D = 8.0, 2.0, 10.0, 20.0, 25.0
# k(p) = 2e5 (1 - 1.5 p + 1.5 p^2) N/m: the mode moves by about +-8 % over 0.1 .. 0.9 m
K = np.array([2e5, -3e5, 3e5])
POSITIONS = np.linspace(0.1, 0.9, 6)


def k_true(p):
    return float(np.polynomial.polynomial.polyval(p, K))


def true_mode_hz(p, b=B):
    """Undamped frequency of the complex pair of the 4-state model with the cart's viscous term."""
    k = k_true(p)
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / M1, -(D + b) / M1, k / M1, D / M1],
            [0.0, 0.0, 0.0, 1.0],
            [k / M2, D / M2, -k / M2, -D / M2],
        ]
    )
    lam = np.linalg.eigvals(A)
    return abs(lam[np.imag(lam) > 0][0]) / (2.0 * np.pi)


def test_the_mode_moves_about_eight_percent_over_the_positions():
    f = [true_mode_hz(p) for p in POSITIONS]
    spread = (max(f) - min(f)) / (max(f) + min(f))
    assert 0.07 < spread < 0.09


# -- exact data ---------------------------------------------------------------------------------


def exact_responses(positions, b=B, d=D, sample_rate_hz=None):
    grids, frf, coh = [], [], []
    for i, p in enumerate(positions):
        f = np.linspace(2.0 + 0.3 * i, 140.0, 250 + 10 * i)  # each position on its own grid
        grids.append(f)
        frf.append(
            two_mass_velocity_response(
                f,
                m1=M1,
                m2=M2,
                k=k_true(p),
                d=d(p) if callable(d) else d,
                b=b,
                torque_constant=C,
                sample_rate_hz=sample_rate_hz,
            )
        )
        coh.append(np.ones(f.size))
    return grids, frf, coh


def test_noise_free_responses_give_the_coefficients_to_1e_6():
    positions = np.linspace(0.1, 0.9, 7)
    fit = fit_workspace_two_mass(positions, *exact_responses(positions), torque_constant=C)
    assert fit.converged, fit.message
    np.testing.assert_allclose(fit.k_coefficients, K, rtol=1e-6)
    np.testing.assert_allclose([fit.m1, fit.m2, fit.b], [M1, M2, B], rtol=1e-6)
    np.testing.assert_allclose(fit.d_coefficients, [D], rtol=1e-6)
    assert fit.parameter_names == ("m1", "m2", "b", "k0", "k1", "k2", "d0")
    assert all(p.fit_percent > 99.999 and p.relative_error_rms < 1e-6 for p in fit.positions)
    assert fit.k_of(0.5) == pytest.approx(k_true(0.5), rel=1e-6)
    assert fit.d_of(0.2) == pytest.approx(D, rel=1e-6)
    np.testing.assert_allclose(fit.k_of(positions), [k_true(p) for p in positions], rtol=1e-6)


def test_a_position_dependent_damping_is_recovered():
    grids, frf, coh = exact_responses(POSITIONS, d=lambda p: 20.0 + 15.0 * p)
    fit = fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C, d_degree=1)
    np.testing.assert_allclose(fit.d_coefficients, [20.0, 15.0], rtol=1e-6)
    assert fit.parameter_names[-2:] == ("d0", "d1")
    assert fit.as_dict()["d_ns_per_m"]["units"] == ["N*s/m", "N*s/m^2"]


def test_noise_free_sampled_responses_need_the_sampled_model():
    fs = 500.0
    grids, frf, coh = exact_responses(POSITIONS, sample_rate_hz=fs)
    sampled = fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C, sample_rate_hz=fs)
    np.testing.assert_allclose(sampled.k_coefficients, K, rtol=1e-6)
    np.testing.assert_allclose([sampled.m1, sampled.m2, sampled.b], [M1, M2, B], rtol=1e-6)
    # the continuous model misreads the same data by far more than the sampled one
    continuous = fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C)
    assert abs(continuous.m1 / M1 - 1.0) > 1e-3


def test_the_sampled_response_is_scipys_zero_order_hold_discretisation():
    fs, k = 1000.0, k_true(0.4)
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / M1, -(D + B) / M1, k / M1, D / M1],
            [0.0, 0.0, 0.0, 1.0],
            [k / M2, D / M2, -k / M2, -D / M2],
        ]
    )
    Bm = np.array([[0.0], [C / M1], [0.0], [0.0]])
    Cm = np.array([[0.0, 1.0, 0.0, 0.0]])
    Ad, Bd, Cd, _, _ = signal.cont2discrete((A, Bm, Cm, np.zeros((1, 1))), 1.0 / fs, method="zoh")
    f = np.array([0.5, 10.0, 35.0, 42.0, 120.0, 400.0, 490.0])
    exact = [(Cd @ np.linalg.solve(np.exp(2j * np.pi * x / fs) * np.eye(4) - Ad, Bd))[0, 0] for x in f]
    ours = two_mass_velocity_response(f, m1=M1, m2=M2, k=k, d=D, b=B, torque_constant=C, sample_rate_hz=fs)
    np.testing.assert_allclose(ours, exact, rtol=1e-5)


def test_the_mode_is_the_emulators_mode_without_cart_damping():
    grids, frf, coh = exact_responses(POSITIONS, b=0.0)
    fit = fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C, estimate_cart_damping=False)
    assert "b" not in fit.parameter_names and fit.b == 0.0
    for p in (0.1, 0.35, 0.9):
        (
            f_hz,
            zeta,
            ci,
        ) = fit.mode_at(p)[1:]
        ((f_true, z_true),) = modes(TwoMass(M1, M2, k_true(p), D, C))
        assert f_hz == pytest.approx(f_true, rel=1e-6)
        assert zeta == pytest.approx(z_true, rel=1e-5)
        assert 0.0 <= ci < 1e-3


def test_as_dict_is_json_with_unit_suffixed_keys():
    fit = fit_workspace_two_mass(POSITIONS, *exact_responses(POSITIONS), torque_constant=C)
    doc = fit.as_dict()
    json.dumps(to_jsonable(doc), allow_nan=False)
    assert doc["m1_kg"] == pytest.approx(M1) and doc["b_ns_per_m"] == pytest.approx(B)
    assert doc["torque_constant_n_per_nm"] == C
    assert doc["k_n_per_m"]["units"] == ["N/m", "N/m^2", "N/m^3"]
    np.testing.assert_allclose(doc["k_n_per_m"]["coefficients"], K, rtol=1e-6)
    assert len(doc["k_n_per_m"]["std"]) == 3 and len(doc["d_ns_per_m"]["coefficients"]) == 1
    assert np.array(doc["correlation"]).shape == (7, 7)
    assert [row["position_m"] for row in doc["positions"]] == pytest.approx(list(POSITIONS))
    row = doc["positions"][2]
    assert row["frequency_hz"] == pytest.approx(true_mode_hz(POSITIONS[2]), rel=1e-6)
    assert set(row) >= {"frequency_ci95_hz", "damping_ratio", "k_n_per_m", "d_ns_per_m", "fit_percent", "bins"}
    assert doc["position_range_m"] == pytest.approx([0.1, 0.9]) and doc["converged"] is True


def test_frequencies_in_any_order_give_the_same_fit():
    grids, frf, coh = exact_responses(POSITIONS)
    ordered = fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C)
    flipped = fit_workspace_two_mass(
        POSITIONS, [g[::-1] for g in grids], [h[::-1] for h in frf], coh, torque_constant=C
    )
    np.testing.assert_allclose(flipped.k_coefficients, ordered.k_coefficients, rtol=1e-9)


def test_the_solver_reports_when_it_stops_short():
    fit = fit_workspace_two_mass(POSITIONS, *exact_responses(POSITIONS), torque_constant=C, max_evaluations=1)
    assert not fit.converged
    assert any("before converging" in w for w in fit.warnings)


# -- data simulated on the emulator's plant, estimated as the pipeline does -----------------------

FS = 1000.0


def simulated_response(p, seed, noise_mps=5e-4):
    """A multisine torque on the plant at a fixed k(p); velocity with noise; periodic FRF as the pipeline."""
    # Viscous friction as the cart's b; 8 substeps per sample keep its explicit hold from acting as a mass.
    plant = Plant(
        TwoMass(M1, M2, k_true(p), D, C), StribeckFriction(Fc=0.0, Fs=0.0, Fv=B / C, vs=1.0), max_substep_s=1.0 / FS / 8
    )
    excitation = multisine(2.0, 2.0, 150.0, 1.0, 11, FS)
    torque = np.asarray(excitation.samples)
    velocity = np.empty(torque.size)
    for i, tau in enumerate(torque):
        velocity[i] = plant.v1
        plant.step(tau, 1.0 / FS)
    velocity += noise_mps * np.random.default_rng(seed).standard_normal(velocity.size)
    # three periods let the rigid-body transient (M / b = 0.5 s) die out
    return periodic_frf(torque, velocity, excitation.period_samples, FS, skip_periods=3, bins=excitation.excited_bins)


@pytest.fixture(scope="module")
def simulated():
    frfs = [simulated_response(p, seed) for seed, p in enumerate(POSITIONS)]
    fit = fit_workspace_responses(POSITIONS, frfs, torque_constant=C, sample_rate_hz=FS)
    return frfs, fit


def test_simulated_k_coefficients_within_two_percent_and_three_sigma(simulated):
    _, fit = simulated
    assert fit.converged, fit.message
    np.testing.assert_allclose(fit.k_coefficients, K, rtol=0.02)
    truth = {"m1": M1, "m2": M2, "b": B, "k0": K[0], "k1": K[1], "k2": K[2], "d0": D}
    sd = fit.std
    for name, value in fit.values.items():
        assert abs(value - truth[name]) < 3.5 * sd[name], (name, value, truth[name], sd[name])
        assert 0.0 < sd[name] < 0.05 * abs(truth[name]), name
    assert all(p.fit_percent > 95.0 for p in fit.positions)
    # the coherence weights are right up to a common factor; the residual variance supplies it
    assert 0.05 < fit.residual_rms < 5.0
    assert np.all(np.abs(fit.correlation) <= 1.0 + 1e-12)


def test_simulated_modes_beside_the_per_position_estimates(simulated):
    frfs, fit = simulated
    local = [max(find_resonances(r), key=lambda m: m.peak_magnitude_db) for r in frfs]
    rows = compare_modes(fit, POSITIONS, [m.frequency_hz for m in local], [m.frequency_ci95_hz for m in local])
    assert [r.position_m for r in rows] == pytest.approx(list(POSITIONS))
    for p, row in zip(POSITIONS, rows, strict=True):
        mode = fit.mode_at(p)
        assert isinstance(mode, WorkspaceMode)
        assert mode.frequency_hz == pytest.approx(true_mode_hz(p), rel=0.005)
        assert abs(mode.frequency_hz - true_mode_hz(p)) < 2.0 * mode.frequency_ci95_hz + 1e-3
        assert abs(row.difference_percent) < 1.0
        assert row.combined_ci95_hz >= row.joint_ci95_hz > 0.0
        assert row.within_interval == (abs(row.joint_frequency_hz - row.local_frequency_hz) <= row.combined_ci95_hz)


# -- comparison ---------------------------------------------------------------------------------


def test_compare_modes_difference_and_interval():
    fit = fit_workspace_two_mass(POSITIONS, *exact_responses(POSITIONS), torque_constant=C)
    f0 = fit.mode_at(0.5).frequency_hz
    inside, outside, unknown = compare_modes(
        fit, [0.5, 0.5, 0.5], [f0 * 1.01, f0 * 1.01, f0 * 0.98], [0.05 * f0, 0.001 * f0, math.nan]
    )
    assert inside.difference_percent == pytest.approx(100.0 * (1.0 / 1.01 - 1.0))
    assert inside.within_interval and not outside.within_interval
    assert unknown.difference_percent == pytest.approx(100.0 * (1.0 / 0.98 - 1.0))
    assert not unknown.within_interval  # an exact model's interval is ~0 wide; unknown local interval counts 0
    assert set(inside.as_dict()) >= {
        "joint_frequency_hz",
        "local_frequency_ci95_hz",
        "difference_percent",
        "within_interval",
    }
    with pytest.raises(DataError, match="differ in length"):
        compare_modes(fit, [0.5, 0.6], [f0])


# -- refusals -----------------------------------------------------------------------------------


def test_fewer_positions_than_coefficients_is_refused():
    grids, frf, coh = exact_responses(POSITIONS[:2])
    with pytest.raises(DataError, match="2 positions cannot determine the 3 coefficients of k"):
        fit_workspace_two_mass(POSITIONS[:2], grids, frf, coh, torque_constant=C)
    grids, frf, coh = exact_responses(POSITIONS[:3])
    with pytest.raises(DataError, match="coefficients of d"):
        fit_workspace_two_mass(POSITIONS[:3], grids, frf, coh, torque_constant=C, k_degree=1, d_degree=3)


def test_non_positive_stiffness_in_the_mapped_range_is_refused():
    positions = [0.0, 0.3, 0.7, 1.0]
    grids, frf, coh = exact_responses(positions)
    with pytest.raises(
        DataError,
        match=r"at the start values.*k\(p\) is not positive everywhere in the mapped "
        r"range 0\.\.1 m",
    ):
        fit_workspace_two_mass(positions, grids, frf, coh, torque_constant=C, resonance_hz=[60, 10, 10, 60])


def test_no_usable_frequencies_is_refused():
    grids, frf, coh = exact_responses(POSITIONS)
    with pytest.raises(DataError, match="position 0.1 m: no usable frequency"):
        fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C, band_hz=(500.0, 600.0))
    coh[3] = np.zeros_like(coh[3])
    with pytest.raises(DataError, match="no usable frequency"):
        fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C)


@pytest.mark.parametrize(
    ("change", "error", "match"),
    [
        ({"torque_constant": 0.0}, ConfigError, "torque_constant"),
        ({"torque_constant": -3.0}, ConfigError, "torque_constant"),
        ({"k_degree": -1}, ConfigError, "k_degree"),
        ({"d_degree": 1.5}, ConfigError, "d_degree"),
        ({"band_hz": (50.0, 10.0)}, ConfigError, "band_hz"),
        ({"sample_rate_hz": 200.0}, DataError, "Nyquist"),
        ({"delay_s": -1e-3}, ConfigError, "delay_s"),
        ({"resonance_hz": [40.0]}, DataError, "resonance_hz"),
    ],
)
def test_bad_arguments_are_typed_errors(change, error, match):
    kwargs = {"torque_constant": C, **change}
    with pytest.raises(error, match=match):
        fit_workspace_two_mass(POSITIONS, *exact_responses(POSITIONS), **kwargs)


def test_mismatched_inputs_are_refused():
    grids, frf, coh = exact_responses(POSITIONS)
    with pytest.raises(DataError, match="one frequency grid, response and coherence per position"):
        fit_workspace_two_mass(POSITIONS, grids[:-1], frf, coh, torque_constant=C)
    frf[1] = frf[1][:-3]
    with pytest.raises(DataError, match="differ in length"):
        fit_workspace_two_mass(POSITIONS, grids, frf, coh, torque_constant=C)
    with pytest.raises(DataError, match="distinct"):
        fit_workspace_two_mass([0.1, 0.1, 0.5, 0.6, 0.7, 0.8], *exact_responses(POSITIONS), torque_constant=C)


# -- the measured velocity's lag ----------------------------------------------------------------


def lagged(frf, grids, lag_s):
    """Each response through a first-order lag of time constant ``lag_s``: a drive's filtered velocity estimate."""
    return [h / (1.0 + 2j * np.pi * f * lag_s) for f, h in zip(grids, frf, strict=True)]


def test_a_lag_of_the_velocity_estimate_is_estimated_and_leaves_k_exact():
    positions = np.linspace(0.1, 0.9, 7)
    grids, frf, coh = exact_responses(positions, sample_rate_hz=1000.0)
    lag = 1.0 / (2.0 * np.pi * 400.0)  # a 400 Hz velocity filter
    fit = fit_workspace_two_mass(
        positions, grids, lagged(frf, grids, lag), coh, torque_constant=C, sample_rate_hz=1000.0, estimate_lag=True
    )
    assert fit.converged, fit.message
    assert fit.lag_estimated and fit.parameter_names[-1] == "lag"
    assert fit.lag_s == pytest.approx(lag, rel=1e-6)
    np.testing.assert_allclose(fit.k_coefficients, K, rtol=1e-6)
    np.testing.assert_allclose([fit.m1, fit.m2, fit.b], [M1, M2, B], rtol=1e-6)
    # the response the fit reports is the measured one, lag included
    np.testing.assert_allclose(fit.response(positions[2], grids[2]), lagged(frf, grids, lag)[2], rtol=1e-6)
    out = fit.as_dict()
    assert out["lag_estimated"] and out["velocity_lag_s"] == pytest.approx(lag, rel=1e-6)
    assert out["velocity_lag_std_s"] >= 0.0
    assert fit.mode_at(0.5).frequency_hz == pytest.approx(true_mode_hz(0.5), rel=1e-6)


def test_without_the_lag_the_same_data_bias_the_cart_and_its_damping():
    """Why the map estimates it: left out, the filter's phase reads as cart damping (negative here) and its droop
    as mass; both move well beyond the exact fit's 1e-6."""
    positions = np.linspace(0.1, 0.9, 7)
    grids, frf, coh = exact_responses(positions, sample_rate_hz=1000.0)
    fit = fit_workspace_two_mass(
        positions, grids, lagged(frf, grids, 1.0 / (2.0 * np.pi * 400.0)), coh, torque_constant=C, sample_rate_hz=1000.0
    )
    assert not fit.lag_estimated and fit.lag_s == 0.0
    assert fit.b < 0.9 * B
    assert abs(fit.m1 / M1 - 1.0) > 0.002
