import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.discretize import (
    c2d_tf,
    controllability_matrix,
    d2c_tf,
    d2c_tustin,
    d2c_zoh,
    forward_euler,
    is_controllable,
    is_observable,
    observability_matrix,
    sampling_advice,
    second_order_poles,
    tustin,
    zoh,
)


def two_mass(m1=40.0, m2=10.0, k=1.5e5, d=40.0):
    """Thesis eq. 2.6 with constant k_s, d; force input F on m1 (eq. 2.1: 1/m1).

    States (p1, v1, p2, v2); output y = (p1, v1) as in eq. 2.7.
    """
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / m1, -d / m1, k / m1, d / m1],
            [0.0, 0.0, 0.0, 1.0],
            [k / m2, d / m2, -k / m2, -d / m2],
        ]
    )
    B = np.array([[0.0], [1.0 / m1], [0.0], [0.0]])
    C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    return A, B, C, np.zeros((2, 1))


def msd(m=5.0, b=1.0, k=10.0):
    """Lecture mass-spring-damper, states (y, y'), input force u."""
    return np.array([[0.0, 1.0], [-k / m, -b / m]]), np.array([[0.0], [1.0 / m]]), np.eye(2), np.zeros((2, 1))


SYSTEMS = {"two_mass": two_mass(), "msd": msd()}


# --- agreement with scipy.signal.cont2discrete --------------------------------


@pytest.mark.parametrize("name", sorted(SYSTEMS))
@pytest.mark.parametrize("dt", [1e-3, 2e-3, 0.01])
@pytest.mark.parametrize("ours, scipy_method", [(zoh, "zoh"), (forward_euler, "euler"), (tustin, "bilinear")])
def test_state_space_matches_scipy(name, dt, ours, scipy_method):
    A, B, C, D = SYSTEMS[name]
    got = ours(A, B, C, D, dt)
    ref = signal.cont2discrete((A, B, C, D), dt, method=scipy_method)
    for mine, theirs in zip(got[:4], ref[:4], strict=False):
        np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-12 * np.max(np.abs(theirs)))
    assert got.dt == dt


def test_zoh_gamma_is_the_integral_of_eq_2_23():
    """For invertible A: Gamma = A^-1 (e^(A h) - I) B."""
    A, B, C, D = msd()
    h = 0.05
    sys = zoh(A, B, C, D, h)
    np.testing.assert_allclose(sys.Gamma, np.linalg.solve(A, sys.Phi - np.eye(2)) @ B, rtol=1e-12)


def test_euler_and_tustin_approximate_phi_as_in_eqs_2_28_and_2_30():
    A, B, C, D = two_mass()
    h = 1e-4
    eye = np.eye(4)
    np.testing.assert_allclose(forward_euler(A, B, C, D, h).Phi, eye + A * h)
    np.testing.assert_allclose(
        tustin(A, B, C, D, h).Phi, (eye + A * h / 2) @ np.linalg.inv(eye - A * h / 2), rtol=1e-12
    )
    exact = zoh(A, B, C, D, h).Phi
    assert np.max(np.abs(tustin(A, B, C, D, h).Phi - exact)) < np.max(np.abs(forward_euler(A, B, C, D, h).Phi - exact))


@pytest.mark.parametrize("method, scipy_method", [("zoh", "zoh"), ("euler", "euler"), ("tustin", "bilinear")])
def test_tf_version_matches_scipy(method, scipy_method):
    w0, zeta = 2 * np.pi * 20.0, 0.03
    num, den = [w0**2], [1.0, 2 * zeta * w0, w0**2]
    bd, ad = c2d_tf(num, den, 1e-3, method)
    ref_b, ref_a, _ = signal.cont2discrete((num, den), 1e-3, method=scipy_method)
    np.testing.assert_allclose(ad, ref_a, rtol=1e-9)
    np.testing.assert_allclose(bd, np.ravel(ref_b), atol=1e-12)


# --- pre-warping and inverses -------------------------------------------------


def test_prewarped_tustin_is_exact_at_the_prewarp_frequency():
    w0, zeta, dt = 2 * np.pi * 150.0, 0.01, 1e-3  # resonance at 0.3 * Nyquist: plain Tustin misses it
    num, den = [w0**2], [1.0, 2 * zeta * w0, w0**2]
    f = 150.0
    h_c = signal.freqs(num, den, [2 * np.pi * f])[1][0]
    bd, ad = c2d_tf(num, den, dt, "tustin", prewarp_hz=f)
    h_d = signal.freqz(bd, ad, [f], fs=1 / dt)[1][0]
    assert h_d == pytest.approx(h_c, rel=1e-9)
    bd0, ad0 = c2d_tf(num, den, dt, "tustin")
    h_plain = signal.freqz(bd0, ad0, [f], fs=1 / dt)[1][0]
    assert abs(h_plain - h_c) > 0.1 * abs(h_c)


@pytest.mark.parametrize("name", sorted(SYSTEMS))
@pytest.mark.parametrize("dt", [1e-3, 0.01])
def test_inverse_zoh_and_tustin_round_trip(name, dt):
    A, B, C, D = SYSTEMS[name]
    for fwd, inv, kw in (
        (zoh, d2c_zoh, {}),
        (tustin, d2c_tustin, {}),
        (tustin, d2c_tustin, {"prewarp_hz": 15.0}),
    ):
        back = inv(*fwd(A, B, C, D, dt, **kw), **kw)
        for mine, truth in zip(back, (A, B, C, D), strict=False):
            np.testing.assert_allclose(mine, truth, rtol=1e-7, atol=1e-9 * max(1.0, np.max(np.abs(truth))))


@settings(max_examples=25, deadline=None)
@given(
    w0=st.floats(1.0, 500.0),
    zeta=st.floats(0.001, 2.0),
    dt=st.floats(1e-4, 1e-2),
)
def test_d2c_tf_inverts_c2d_tf(w0, zeta, dt):
    if w0 * dt > 2.5:  # keep the sampled poles away from the negative real axis
        dt = 2.5 / w0
    num, den = [w0**2], [1.0, 2 * zeta * w0, w0**2]
    for method in ("zoh", "tustin"):
        nc, dc = d2c_tf(*c2d_tf(num, den, dt, method), dt, method)
        np.testing.assert_allclose(dc, den, rtol=1e-6, atol=1e-8 * w0**2)
        np.testing.assert_allclose(np.trim_zeros(nc, "f")[-1], w0**2, rtol=1e-6)


def test_d2c_zoh_refuses_negative_real_poles():
    Phi = np.array([[-0.5, 0.0], [0.0, 0.9]])
    with pytest.raises(DataError, match="-0.5"):
        d2c_zoh(Phi, [[1.0], [1.0]], [[1.0, 0.0]], [[0.0]], 1e-3)


def test_d2c_tustin_refuses_pole_at_minus_one():
    with pytest.raises(DataError, match="-1"):
        d2c_tustin([[-1.0]], [[1.0]], [[1.0]], [[0.0]], 1e-3)


# --- controllability / observability ------------------------------------------


@pytest.mark.parametrize("dt", [1e-3, 2e-3])
def test_two_mass_controllable_and_observable_with_position_and_velocity(dt):
    A, B, C, D = two_mass()
    sys = zoh(A, B, C, D, dt)
    assert is_controllable(sys.Phi, sys.Gamma)
    assert is_observable(sys.Phi, sys.C)  # y = (p1, v1), eq. 2.7
    assert is_observable(sys.Phi, sys.C[:1])  # p1 alone also suffices


@pytest.mark.parametrize("dt", [1e-3, 2e-3])
def test_two_mass_with_velocity_only_is_not_observable(dt):
    """From v1 alone the common position (1, 0, 1, 0) never shows: A maps it
    to 0 and C v1 ignores it, so it is in the kernel of W_o."""
    A, B, C, D = two_mass()
    sys = zoh(A, B, C, D, dt)
    assert not is_observable(sys.Phi, sys.C[1:])
    wo = observability_matrix(sys.Phi, sys.C[1:])
    assert np.linalg.matrix_rank(wo / np.linalg.norm(wo, axis=0), tol=1e-8) == 3
    hidden = np.array([1.0, 0.0, 1.0, 0.0])
    assert np.max(np.abs(wo @ hidden)) < 1e-12 * np.max(np.abs(wo))


def test_force_on_mass_two_only_through_spring_is_uncontrollable_when_decoupled():
    A, B, C, D = two_mass(k=0.0, d=0.0)  # no coupling: m2 cannot be moved by F
    sys = zoh(A, B, C, D, 1e-3)
    assert not is_controllable(sys.Phi, sys.Gamma)


def test_controllability_matrix_layout():
    Phi = np.array([[1.0, 2.0], [0.0, 3.0]])
    G = np.array([1.0, 1.0])
    np.testing.assert_allclose(controllability_matrix(Phi, G), [[1.0, 3.0], [1.0, 3.0]])
    assert not is_controllable(Phi, G)
    np.testing.assert_allclose(observability_matrix(Phi, [[1.0, 0.0]]), [[1.0, 0.0], [1.0, 2.0]])


# --- thesis eqs. 2.33-2.37 ----------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(w0=st.floats(0.5, 2000.0), zeta=st.floats(0.0, 3.0), dt=st.floats(1e-4, 0.02))
def test_second_order_poles_equal_zoh_poles(w0, zeta, dt):
    A = np.array([[0.0, 1.0], [-(w0**2), -2 * zeta * w0]])
    phi = zoh(A, [[0.0], [w0**2]], [[1.0, 0.0]], [[0.0]], dt).Phi
    a1, a2 = second_order_poles(w0, zeta, dt)
    # z^2 + a1 z + a2 = z^2 - trace(Phi) z + det(Phi)
    assert a1 == pytest.approx(-np.trace(phi), rel=1e-8, abs=1e-10)
    assert a2 == pytest.approx(np.linalg.det(phi), rel=1e-8, abs=1e-12)


def test_sampling_advice_rule_and_nyquist():
    w0 = 2 * np.pi * 6.0  # the 6 Hz mode of thesis section 3.3
    adv = sampling_advice(w0)
    assert adv["h_min_s"] * w0 == pytest.approx(0.2)
    assert adv["h_max_s"] * w0 == pytest.approx(0.6)
    assert adv["sample_rate_min_hz"] == pytest.approx(1 / adv["h_max_s"])
    assert adv["nyquist_sample_rate_min_hz"] == pytest.approx(12.0)
    assert adv["h_max_s"] < adv["nyquist_h_max_s"]
    assert 10 < adv["samples_per_period_min"] < adv["samples_per_period_max"] < 32


def test_argument_errors():
    A, B, C, D = msd()
    with pytest.raises(ConfigError, match="dt"):
        zoh(A, B, C, D, 0.0)
    with pytest.raises(ConfigError, match="prewarp_hz"):
        tustin(A, B, C, D, 1e-3, prewarp_hz=600.0)
    with pytest.raises(ConfigError, match="method"):
        c2d_tf([1.0], [1.0, 1.0], 1e-3, "foh")
    with pytest.raises(DataError, match="inconsistent"):
        zoh(A, np.ones((3, 1)), C, D, 1e-3)
    with pytest.raises(ConfigError, match="omega0_rad_s"):
        sampling_advice(-1.0)
    with pytest.raises(ConfigError, match="zeta"):
        second_order_poles(10.0, -0.1, 1e-3)
