import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.greybox import (
    LinearFit,
    check_excitation,
    fit_dc_motor_speed,
    fit_linear,
    fit_mass_spring_damper,
    fit_rigid_axis,
    fit_torque_constant,
)

FS = 1000.0
T = 1.0 / FS
# lecture's mass-spring-damper
MSD = {"m": 5.0, "b": 1.0, "k": 10.0}


def band_limited_noise(n, bandwidth_hz, rms, seed):
    """The lecture's band-limited white noise: white noise through a 4th-order low-pass."""
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, bandwidth_hz, fs=FS, output="sos")
    u = signal.sosfilt(sos, rng.standard_normal(n))
    return u * rms / np.std(u), rng


def simulate_tf(num, den, u, hold="foh"):
    """Exact response of num/den to u: piecewise-linear ('foh') or held ('zoh') input."""
    numd, dend, _ = signal.cont2discrete((num, den), T, method=hold)
    return signal.lfilter(np.ravel(numd), dend, u)


def rel_err(fit, truth):
    return {n: abs(fit.params[n] / v - 1.0) for n, v in truth.items()}


@pytest.fixture(scope="module")
def msd_data():
    """300 s of the lecture's MSD at T = 1 ms, force band-limited to 2 Hz."""
    force, rng = band_limited_noise(300_000, 2.0, 10.0, seed=1)
    y = simulate_tf([1.0], [MSD["m"], MSD["b"], MSD["k"]], force)
    y_noisy = y + 0.01 * np.std(y) * rng.standard_normal(y.size)  # 1 % of rms
    return force, y, y_noisy


# --- fit_linear --------------------------------------------------------------


def test_fit_linear_recovers_exact_parameters_and_reports_quality():
    rng = np.random.default_rng(0)
    x1, x2 = rng.standard_normal((2, 500))
    y = 2.0 * x1 - 0.5 * x2 + 3.0
    fit = fit_linear({"a": x1, "b": x2, "c": np.ones(500)}, y)
    assert isinstance(fit, LinearFit)
    assert fit.names == ("a", "b", "c")
    np.testing.assert_allclose(fit.theta, [2.0, -0.5, 3.0], atol=1e-12)
    assert fit.fit_percent == pytest.approx(100.0, abs=1e-8)
    assert fit.cost_V < 1e-20
    assert fit.warnings == ()
    np.testing.assert_allclose(fit.predict({"a": x1, "b": x2, "c": np.ones(500)}), y, atol=1e-12)
    # names select and order the columns
    sub = fit_linear({"a": x1, "b": x2, "c": np.ones(500)}, y, names=["c", "a"])
    assert sub.names == ("c", "a")
    assert sub.params["a"] == pytest.approx(2.0, abs=0.1)


def test_fit_linear_cost_and_fit_percent_definitions():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(1000)
    y = 1.5 * x + 0.3 * rng.standard_normal(1000)
    fit = fit_linear({"g": x}, y)
    e = y - fit.params["g"] * x
    assert fit.cost_V == pytest.approx(0.5 * np.sum(e**2))
    assert fit.residual_rms == pytest.approx(np.sqrt(np.mean(e**2)))
    assert fit.fit_percent == pytest.approx(100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean())))
    # contribution of the single term: rms(g x) / rms(y)
    assert fit.contribution["g"] == pytest.approx(np.std(fit.params["g"] * x) / np.sqrt(np.mean(y**2)), rel=0.02)


def test_stderr_matches_the_scatter_of_repeated_experiments():
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.standard_normal(200), np.linspace(-1, 1, 200)])
    estimates, reported = [], []
    for _ in range(400):
        y = x @ [1.0, -2.0] + 0.5 * rng.standard_normal(200)
        fit = fit_linear({"p": x[:, 0], "q": x[:, 1]}, y)
        estimates.append(fit.theta)
        reported.append([fit.stderr["p"], fit.stderr["q"]])
    np.testing.assert_allclose(np.std(estimates, axis=0), np.mean(reported, axis=0), rtol=0.15)
    np.testing.assert_allclose(np.mean(estimates, axis=0), [1.0, -2.0], atol=0.02)


def test_n_effective_scales_the_covariance():
    rng = np.random.default_rng(3)
    x = rng.standard_normal(1000)
    y = x + 0.1 * rng.standard_normal(1000)
    full = fit_linear({"g": x}, y)
    quarter = fit_linear({"g": x}, y, n_effective=250)
    assert quarter.stderr["g"] == pytest.approx(2.0 * full.stderr["g"])
    assert quarter.params == full.params
    with pytest.raises(DataError, match="n_effective"):
        fit_linear({"g": x}, y, n_effective=1)


def test_condition_number_does_not_depend_on_units():
    rng = np.random.default_rng(4)
    x1, x2 = rng.standard_normal((2, 300))
    y = x1 + x2
    a = fit_linear({"a": x1, "b": x2}, y)
    b = fit_linear({"a": 1e6 * x1, "b": 1e-6 * x2}, y)
    assert b.condition_number == pytest.approx(a.condition_number, rel=1e-9)
    assert b.params["a"] == pytest.approx(1e-6, rel=1e-9)


# --- excitation --------------------------------------------------------------


def test_collinear_regressors_name_the_parameters():
    rng = np.random.default_rng(5)
    x = rng.standard_normal(400)
    z = rng.standard_normal(400)
    with pytest.raises(DataError, match="'b'.*'k'|'k'.*'b'") as info:
        fit_linear({"m": z, "b": x, "k": -2.0 * x}, z + x)
    assert "'m'" not in str(info.value)


def test_zero_and_near_collinear_columns():
    rng = np.random.default_rng(6)
    x, z = rng.standard_normal((2, 1000))
    with pytest.raises(DataError, match="'Fc'"):
        check_excitation(np.column_stack([x, np.zeros(1000)]), ["Fv", "Fc"])
    # almost the same column: usable, but warned about
    near = x + 3e-3 * z
    warnings = check_excitation(np.column_stack([x, near]), ["p", "q"])
    assert len(warnings) == 1 and "'p'" in warnings[0] and "'q'" in warnings[0]
    # closer still: refused
    with pytest.raises(DataError, match="not identifiable"):
        check_excitation(np.column_stack([x, x + 1e-5 * z]), ["p", "q"])
    assert check_excitation(np.column_stack([x, z]), ["p", "q"]) == []


def test_constant_input_is_refused():
    # system at rest under a constant force: nothing to identify
    rng = np.random.default_rng(7)
    force = np.full(20_000, 10.0)
    position = 1.0 + 1e-4 * rng.standard_normal(20_000)
    with pytest.raises(DataError, match="'force'"):
        fit_mass_spring_damper(force, position, FS, cutoff_hz=2.0)
    # an offset regressor and a constant input are the same column
    with pytest.raises(DataError, match="'b0'.*'offset'|'offset'.*'b0'"):
        fit_linear({"b0": force, "offset": np.ones_like(force)}, position)


# --- mass-spring-damper (lecture) ---------------------------------------------


def test_msd_svf_recovers_lecture_parameters_from_noisy_data(msd_data):
    force, _, y_noisy = msd_data
    fit = fit_mass_spring_damper(force, y_noisy, FS, cutoff_hz=2.0)
    errors = rel_err(fit, MSD)
    assert max(errors.values()) < 0.005, fit.params
    assert fit.fit_percent > 90.0
    assert all(fit.relative_stderr_percent[n] < 1.0 for n in MSD)
    # truth within a few standard errors
    for n, v in MSD.items():
        assert abs(fit.params[n] - v) < 5 * fit.stderr[n] + 1e-3 * v


def test_msd_naive_differences_fail_on_noisy_data(msd_data):
    force, y, y_noisy = msd_data
    # without noise even central differences work...
    clean = fit_mass_spring_damper(force, y, FS, method="difference")
    assert max(rel_err(clean, MSD).values()) < 0.001
    # ...with 1 % noise the differentiated noise swamps y'' (lecture, "Signal Filtering")
    noisy = fit_mass_spring_damper(force, y_noisy, FS, method="difference")
    assert max(rel_err(noisy, MSD).values()) > 0.1, noisy.params
    assert noisy.fit_percent < 50.0


def test_msd_decimation_keeps_the_estimate(msd_data):
    force, _, y_noisy = msd_data
    full = fit_mass_spring_damper(force, y_noisy, FS, cutoff_hz=2.0)
    dec = fit_mass_spring_damper(force, y_noisy, FS, cutoff_hz=2.0, decimate=10)
    for n in MSD:
        assert dec.params[n] == pytest.approx(full.params[n], rel=2e-3)
        # n_effective depends on the bandwidth, not on the decimation
        assert dec.stderr[n] == pytest.approx(full.stderr[n], rel=0.1)


def test_zoh_input_removes_the_half_sample_damping_bias():
    force, _ = band_limited_noise(120_000, 2.0, 10.0, seed=8)
    y = simulate_tf([1.0], [MSD["m"], MSD["b"], MSD["k"]], force, hold="zoh")
    as_sampled = fit_mass_spring_damper(force, y, FS, cutoff_hz=2.0)
    as_held = fit_mass_spring_damper(force, y, FS, cutoff_hz=2.0, input_hold="zoh")
    # a held force leads the model by T/2; read as samples, b is off by
    # about (T/2)(k - m w^2) -- of order 1e-3 here, far above the noise-free error
    assert abs(as_sampled.params["b"] - MSD["b"]) > 1e-3
    assert max(rel_err(as_held, MSD).values()) < 2e-4, as_held.params


def test_dc_motor_combined_parameters():
    J, b, kt, ke, R, L = 0.01, 0.1, 0.01, 0.01, 1.0, 0.5
    den = [J * L, J * R + b * L, b * R + kt * ke]
    voltage, rng = band_limited_noise(120_000, 5.0, 5.0, seed=9)
    speed = simulate_tf([kt], den, voltage)
    speed = speed + 0.01 * np.std(speed) * rng.standard_normal(speed.size)
    fit = fit_dc_motor_speed(voltage, speed, FS, cutoff_hz=3.0)
    truth = {"JL/kt": den[0] / kt, "(JR+bL)/kt": den[1] / kt, "(bR+kt*ke)/kt": den[2] / kt}
    assert max(rel_err(fit, truth).values()) < 0.005, fit.params


def test_msd_argument_errors(msd_data):
    force, y, _ = msd_data
    with pytest.raises(ConfigError, match="cutoff_hz"):
        fit_mass_spring_damper(force, y, FS)
    with pytest.raises(ConfigError, match="method"):
        fit_mass_spring_damper(force, y, FS, cutoff_hz=2.0, method="euler")
    with pytest.raises(ConfigError, match="input_hold"):
        fit_mass_spring_damper(force, y, FS, cutoff_hz=2.0, input_hold="foh")
    with pytest.raises(ConfigError, match="decimate"):
        fit_mass_spring_damper(force, y, FS, cutoff_hz=2.0, decimate=0)
    with pytest.raises(DataError, match="'position'"):
        fit_mass_spring_damper(force, y[:-1], FS, cutoff_hz=2.0)


# --- rigid axis with friction ---------------------------------------------------

AXIS = {"M": 50.0, "Fv": 20.0, "Fc": 5.0}


def simulate_axis(force, M, Fv, Fc, offset=0.0, sub=4):
    """M v' + Fv v + Fc sign(v) + offset = force, sampled position.

    Exact exponential update over sub-steps with the force linearly
    interpolated between samples; the axis stops at a zero crossing and
    sticks while |force - offset| <= Fc.
    """
    h = T / sub
    decay = np.exp(-h * Fv / M)
    f = force.tolist() + [force[-1]]
    q = np.empty(force.size)
    x = v = 0.0
    for i in range(force.size):
        q[i] = x
        for j in range(sub):
            fj = f[i] + (f[i + 1] - f[i]) * (j + 0.5) / sub - offset
            if v == 0.0:
                if abs(fj) <= Fc:
                    continue
                s = 1.0 if fj > 0 else -1.0
            else:
                s = 1.0 if v > 0 else -1.0
            v_end = (fj - Fc * s) / Fv
            v_new = v_end + (v - v_end) * decay
            if v_new * s < 0.0:  # would reverse: stop at zero within this sub-step
                tz = -M / Fv * np.log(-v_end / (v - v_end))
                x += v_end * tz + (v - v_end) * M / Fv * (1.0 - np.exp(-tz * Fv / M))
                v = 0.0
                continue
            x += v_end * h + (v - v_end) * M / Fv * (1.0 - decay)
            v = v_new
    return q


@pytest.fixture(scope="module")
def axis_data():
    """60 s, band-limited force (3 Hz, 60 N rms), 3 N constant load, 0.1 mm position noise."""
    force, rng = band_limited_noise(60_000, 3.0, 60.0, seed=3)
    q = simulate_axis(force, **AXIS, offset=3.0)
    return force, q + 1e-4 * rng.standard_normal(q.size)


def test_rigid_axis_parameters_within_3_percent(axis_data):
    force, q = axis_data
    fit = fit_rigid_axis(q, force, FS, cutoff_hz=5.0)
    assert fit.names == ("M", "Fv", "Fc", "offset")
    assert max(rel_err(fit, AXIS).values()) < 0.03, fit.params
    assert fit.params["offset"] == pytest.approx(3.0, rel=0.03)


def test_rigid_axis_stable_against_decimation_and_cutoff(axis_data):
    force, q = axis_data
    base = fit_rigid_axis(q, force, FS, cutoff_hz=5.0)
    decimated = fit_rigid_axis(q, force, FS, cutoff_hz=5.0, decimate=4)
    other_cutoff = fit_rigid_axis(q, force, FS, cutoff_hz=10.0)
    assert decimated.n_samples < base.n_samples / 3.5
    for n in AXIS:
        assert decimated.params[n] == pytest.approx(base.params[n], rel=0.02)
        assert other_cutoff.params[n] == pytest.approx(base.params[n], rel=0.02)
    assert max(rel_err(other_cutoff, AXIS).values()) < 0.03


def test_rigid_axis_asymmetric_friction_absorbs_the_load(axis_data):
    # a constant load looks like direction-dependent Coulomb friction
    force, q = axis_data
    fit = fit_rigid_axis(q, force, FS, cutoff_hz=5.0, asymmetric=True)
    assert fit.names == ("M", "Fv+", "Fv-", "Fc+", "Fc-")
    truth = {"M": 50.0, "Fv+": 20.0, "Fv-": 20.0, "Fc+": 5.0 + 3.0, "Fc-": 5.0 - 3.0}
    errors = rel_err(fit, truth)
    assert max(errors.values()) < 0.05, fit.params


def test_rigid_axis_moving_one_way_cannot_separate_coulomb_from_offset():
    drive, rng = band_limited_noise(20_000, 3.0, 5.0, seed=4)
    force = 30.0 + drive  # always pushes forward: the axis never reverses
    q = simulate_axis(force, **AXIS)
    q = q + 1e-5 * rng.standard_normal(q.size)
    with pytest.raises(DataError, match="'Fc'") as info:
        fit_rigid_axis(q, force, FS, cutoff_hz=5.0)
    assert "'offset'" in str(info.value)
    with pytest.raises(DataError, match="'Fc-'"):
        fit_rigid_axis(q, force, FS, cutoff_hz=5.0, asymmetric=True)


def test_rigid_axis_argument_errors(axis_data):
    force, q = axis_data
    with pytest.raises(ConfigError, match="min_speed"):
        fit_rigid_axis(q, force, FS, cutoff_hz=5.0, min_speed=-1.0)
    with pytest.raises(ConfigError, match="cutoff_hz"):
        fit_rigid_axis(q, force, FS, cutoff_hz=800.0)
    with pytest.raises(DataError, match="usable samples"):
        fit_rigid_axis(q, force, FS, cutoff_hz=5.0, min_speed=1e6)


# --- torque constant (thesis eqs. 3.3-3.4) -----------------------------------


def test_torque_constant():
    rng = np.random.default_rng(10)
    mass, c = 473.0, 1.7
    torque = 50.0 * rng.standard_normal(5000)
    friction = 3.0 * np.sign(torque) + 0.5 * torque / 50.0
    acceleration = c * (torque - friction) / mass + 0.01 * rng.standard_normal(5000)
    fit = fit_torque_constant(torque, friction, mass, acceleration)
    assert fit.names == ("c",)
    assert fit.params["c"] == pytest.approx(c, rel=0.01)
    assert abs(fit.params["c"] - c) < 4 * fit.stderr["c"]
    # a constant friction torque (one direction) is fine as a regressor part
    fit_torque_constant(torque, np.full(5000, 3.0), mass, acceleration)
    with pytest.raises(ConfigError, match="mass"):
        fit_torque_constant(torque, friction, 0.0, acceleration)
    with pytest.raises(DataError, match="friction_torque"):
        fit_torque_constant(torque, friction[:-1], mass, acceleration)
