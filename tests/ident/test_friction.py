import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError, DataError
from hilident.ident.friction import (
    FrictionFit,
    StribeckParams,
    compensate,
    fit_coulomb_viscous,
    fit_stribeck,
    steady_state_points,
    stribeck,
)

# Thesis Table 3.1 and a gantry-like set.
THESIS = StribeckParams(Fc=0.606, Fs=1.43, Fv=2.21, vs=6.224e-5, delta_v=0.4994, delta_s=0.4962)
GANTRY = StribeckParams(Fc=2.0, Fs=3.0, Fv=10.0, vs=0.01, delta_v=1.0, delta_s=2.0)


def both_signs(speeds):
    return np.concatenate([-speeds[::-1], speeds])


def noisy(v, params, rel_noise, seed):
    rng = np.random.default_rng(seed)
    tau = stribeck(v, params)
    return tau * (1.0 + rel_noise * rng.standard_normal(v.size))


def rel_err(fit, true, name):
    return abs(getattr(fit.params, name) / getattr(true, name) - 1.0)


# --- the model ---------------------------------------------------------------


def test_stribeck_characteristic_values():
    p = GANTRY
    assert stribeck(0.0, p) == 0.0
    # just above standstill the breakaway torque Fs is needed
    assert stribeck(1e-9, p) == pytest.approx(p.Fs, rel=1e-6)
    assert stribeck(-1e-9, p) == pytest.approx(-p.Fs, rel=1e-6)
    # at v = vs the Stribeck excess has fallen to 1/e
    assert stribeck(p.vs, p) == pytest.approx(p.Fc + (p.Fs - p.Fc) / np.e + p.Fv * p.vs)
    # far beyond vs only Coulomb + viscous remain
    assert stribeck(0.5, p) == pytest.approx(p.Fc + p.Fv * 0.5, rel=1e-12)
    # thesis exponents: viscous term grows like sqrt(v)
    t = THESIS
    assert stribeck(1.0, t) - stribeck(0.25, t) == pytest.approx(t.Fv * (1.0 - 0.25**t.delta_v), rel=1e-6)


@settings(max_examples=50, deadline=None)
@given(v=st.floats(-5.0, 5.0, allow_nan=False))
def test_stribeck_is_odd(v):
    assert stribeck(-v, THESIS) == pytest.approx(-stribeck(v, THESIS), abs=1e-12)


def test_params_validation_and_dict():
    d = GANTRY.to_dict()
    assert d == {"Fc": 2.0, "Fs": 3.0, "Fv": 10.0, "vs": 0.01, "delta_v": 1.0, "delta_s": 2.0}
    assert StribeckParams(**d) == GANTRY
    with pytest.raises(ConfigError, match="vs"):
        StribeckParams(Fc=1, Fs=2, Fv=1, vs=0.0)
    with pytest.raises(ConfigError, match="delta_s"):
        StribeckParams(Fc=1, Fs=2, Fv=1, vs=0.1, delta_s=-1.0)
    with pytest.raises(ConfigError, match="Fc"):
        StribeckParams(Fc=np.nan, Fs=2, Fv=1, vs=0.1)


# --- fitting -----------------------------------------------------------------


def test_fit_exact_data_recovers_all_parameters():
    v = both_signs(np.geomspace(1e-6, 0.5, 30))
    fit = fit_stribeck(v, stribeck(v, THESIS))
    for name in ("Fc", "Fs", "Fv", "vs", "delta_v", "delta_s"):
        assert rel_err(fit, THESIS, name) < 1e-4, name
    assert fit.rms_residual < 1e-6
    assert fit.n_points == v.size and fit.model == "stribeck"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_thesis_table_3_1_with_one_percent_noise(seed):
    # Speeds dense near zero, coarse at high speed, both directions (as in the thesis).
    v = both_signs(np.geomspace(1e-6, 0.5, 30))
    fit = fit_stribeck(v, noisy(v, THESIS, 0.01, seed))
    for name in ("Fc", "Fs", "Fv"):
        assert rel_err(fit, THESIS, name) < 0.05, (name, fit.params)
    # the shape parameters come out too, with looser accuracy
    assert rel_err(fit, THESIS, "vs") < 0.3
    assert abs(fit.params.delta_s - THESIS.delta_s) < 0.1
    assert abs(fit.params.delta_v - THESIS.delta_v) < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_fit_gantry_set(seed):
    v = both_signs(np.geomspace(0.002, 0.3, 25))
    tau = noisy(v, GANTRY, 0.01, seed)
    fit = fit_stribeck(v, tau, fix_delta_v=1.0, fix_delta_s=2.0)
    for name in ("Fc", "Fs", "Fv", "vs"):
        assert rel_err(fit, GANTRY, name) < 0.05, (name, fit.params)
    assert fit.params.delta_v == 1.0 and fit.params.delta_s == 2.0
    assert fit.stderr["delta_v"] == 0.0 and fit.stderr["delta_s"] == 0.0
    # the reported standard errors cover the truth
    for name in ("Fc", "Fs", "Fv"):
        assert abs(getattr(fit.params, name) - getattr(GANTRY, name)) < 4 * fit.stderr[name]

    # With free exponents Fv (the torque at 1 m/s, outside the 0.3 m/s range)
    # trades off against delta_v; Fc, Fs and the curve itself stay accurate.
    free = fit_stribeck(v, tau)
    assert rel_err(free, GANTRY, "Fc") < 0.05 and rel_err(free, GANTRY, "Fs") < 0.05
    grid = np.linspace(0.002, 0.3, 200)
    assert np.max(np.abs(free.predict(grid) / stribeck(grid, GANTRY) - 1.0)) < 0.02


def test_stderr_shrinks_with_noise():
    v = both_signs(np.geomspace(0.002, 0.3, 25))
    small = fit_stribeck(v, noisy(v, GANTRY, 0.001, 5), fix_delta_v=1, fix_delta_s=2)
    large = fit_stribeck(v, noisy(v, GANTRY, 0.01, 5), fix_delta_v=1, fix_delta_s=2)
    for name in ("Fc", "Fs", "Fv", "vs"):
        assert 5 < large.stderr[name] / small.stderr[name] < 20


def test_fit_one_direction_and_zero_velocity_points():
    v = np.concatenate([[0.0, 0.0], np.geomspace(0.002, 0.3, 25)])
    tau = np.concatenate([[0.7, -0.3], stribeck(v[2:], GANTRY)])
    fit = fit_stribeck(v, tau, fix_delta_v=1, fix_delta_s=2)
    assert fit.n_points == 25
    assert rel_err(fit, GANTRY, "Fs") < 1e-6


def test_sigma_weights_down_outliers():
    v = both_signs(np.geomspace(0.002, 0.3, 25))
    tau = stribeck(v, GANTRY)
    tau[3] += 5.0  # one corrupted point ...
    sigma = np.full(v.size, 0.01)
    sigma[3] = 100.0  # ... known to be unreliable
    plain = fit_stribeck(v, tau, fix_delta_v=1, fix_delta_s=2)
    weighted = fit_stribeck(v, tau, fix_delta_v=1, fix_delta_s=2, sigma=sigma)
    assert rel_err(weighted, GANTRY, "Fc") < 1e-3
    assert rel_err(plain, GANTRY, "Fc") > 10 * rel_err(weighted, GANTRY, "Fc")


def test_fit_input_errors():
    with pytest.raises(DataError, match="at least 7"):
        fit_stribeck([0.1, 0.2, 0.3, 0.4], [1, 2, 3, 4])
    with pytest.raises(DataError, match="equal length"):
        fit_stribeck(np.arange(1, 10.0), np.arange(1, 9.0))
    with pytest.raises(DataError, match="finite"):
        fit_stribeck([0.1, np.nan] * 5, [1.0] * 10)
    with pytest.raises(ConfigError, match="fix_delta_s"):
        fit_stribeck(np.arange(1, 10.0), np.arange(1, 10.0), fix_delta_s=0.0)


def test_coulomb_viscous_fit():
    v = both_signs(np.linspace(0.01, 0.3, 15))
    tau = 1.5 * np.sign(v) + 4.0 * v
    fit = fit_coulomb_viscous(v, tau)
    assert fit.model == "coulomb_viscous"
    assert fit.params.Fc == pytest.approx(1.5) and fit.params.Fv == pytest.approx(4.0)
    assert np.allclose(fit.predict(v), tau)
    # On Stribeck data the straight line misses the low-speed hump.
    v = both_signs(np.geomspace(0.002, 0.3, 25))
    tau = stribeck(v, GANTRY)
    line = fit_coulomb_viscous(v, tau)
    curve = fit_stribeck(v, tau, fix_delta_v=1, fix_delta_s=2)
    assert line.rms_residual > 0.1 > 1e-3 > curve.rms_residual
    assert isinstance(curve, FrictionFit) and set(curve.to_dict()) >= {"params", "stderr"}


# --- steady-state points from constant-velocity tests ------------------------


def constant_velocity_record(speeds, seed, n_per=2000, fs=1000.0):
    """Velocity steps with 1 s transitions; torque = friction + inertia."""
    rng = np.random.default_rng(seed)
    J = 0.5
    v, windows = [], []
    level = 0.0
    for s in speeds:
        ramp = np.linspace(level, s, n_per // 2)
        start = sum(len(x) for x in v) + ramp.size
        v += [ramp, np.full(n_per, s)]
        windows.append((start + 100, start + n_per, s))  # skip the settling
        level = s
    v = np.concatenate(v)
    v_meas = v * (1.0 + 0.01 * rng.standard_normal(v.size)) + 1e-5 * rng.standard_normal(v.size)
    tau = stribeck(v, GANTRY) + J * np.gradient(v, 1 / fs) + 0.02 * rng.standard_normal(v.size)
    return v_meas, tau, windows


def test_steady_state_points_average_and_skip():
    speeds = [0.005, 0.02, 0.1, -0.05]
    v, tau, windows = constant_velocity_record(speeds, seed=3)
    # a window over a ramp (not steady) and one where the axis stuck
    ramp_window = (windows[1][0] - 900, windows[1][0] - 100, 0.0125)
    stuck = (0, 50, 0.01)  # velocity there is ~0, far from nominal
    points = steady_state_points(v, tau, windows + [ramp_window, stuck])
    assert points.v_mean.size == 4
    assert np.allclose(points.v_mean, speeds, rtol=0.01)
    assert np.allclose(points.tau_mean, stribeck(np.array(speeds), GANTRY), atol=0.005)
    assert np.allclose(points.tau_std, 0.02, rtol=0.2)
    v_mean, tau_mean, tau_std = points  # plain tuple unpacking works


def test_steady_state_points_errors():
    v, tau, windows = constant_velocity_record([0.01, 0.02], seed=0)
    with pytest.raises(ConfigError, match=r"windows\[1\]"):
        steady_state_points(v, tau, [windows[0], (10, v.size + 5, 0.02)])
    with pytest.raises(ConfigError, match=r"windows\[0\]"):
        steady_state_points(v, tau, [(1, 2)])
    with pytest.raises(DataError, match="no constant-velocity window was steady"):
        steady_state_points(v, tau, [(0, 400, 0.02)])
    with pytest.raises(DataError, match="equal length"):
        steady_state_points(v[:-1], tau, windows)


# --- compensation ------------------------------------------------------------


def test_compensate_removes_friction_outside_deadband():
    rng = np.random.default_rng(1)
    v = 0.2 * np.sin(np.linspace(0, 20, 5000))
    inertia_torque = rng.standard_normal(v.size)
    measured = inertia_torque + stribeck(v, GANTRY)
    out = compensate(measured, v, GANTRY, velocity_deadband_mps=0.001)
    moving = np.abs(v) > 0.001
    assert np.allclose(out[moving], inertia_torque[moving])
    assert np.array_equal(out[~moving], measured[~moving])
    assert (~moving).any()
    with pytest.raises(ConfigError, match="velocity_deadband_mps"):
        compensate(measured, v, GANTRY, velocity_deadband_mps=-1.0)
    with pytest.raises(DataError, match="shapes differ"):
        compensate(measured[:-1], v, GANTRY)


def test_compensate_does_not_extrapolate_the_curve_below_the_slowest_measured_speed():
    """A hump fitted to points above its peak (Fs 7 N*m, seen on a twin whose true Fs is 0.35) stays out of the
    torque near standstill: below the slowest measured speed the friction is the curve's value there."""
    hump = StribeckParams(Fc=0.2, Fs=7.0, Fv=2.0, vs=0.0067, delta_v=1.0, delta_s=5.0)
    slowest = 0.01
    v = np.linspace(-0.05, 0.05, 2001)
    out = compensate(np.zeros_like(v), v, hump, slowest_mps=slowest)
    fast = np.abs(v) >= slowest
    assert np.array_equal(out[fast], -stribeck(v[fast], hump))
    slow = ~fast & (v != 0.0)
    np.testing.assert_allclose(out[slow], -np.sign(v[slow]) * stribeck(np.array([slowest]), hump)[0])
    assert np.abs(out[slow]).max() < 0.25  # the extrapolated curve would subtract up to 7 N*m
    assert np.abs(compensate(np.zeros_like(v), v, hump)).max() > 5.0
    with pytest.raises(ConfigError, match="slowest_mps"):
        compensate(np.zeros_like(v), v, hump, slowest_mps=float("nan"))


@settings(max_examples=40, deadline=None)
@given(
    v=st.floats(-1.0, 1.0, allow_nan=False),
    extra=st.floats(-10.0, 10.0, allow_nan=False),
    band=st.floats(0.0, 0.1),
)
def test_compensate_inverts_friction(v, extra, band):
    out = compensate(np.array([extra + stribeck(v, THESIS)]), np.array([v]), THESIS, band)
    expected = extra if abs(v) > band else extra + stribeck(v, THESIS)
    assert out[0] == pytest.approx(expected, abs=1e-9)
