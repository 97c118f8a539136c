import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse, h1_estimate
from hilident.ident.tffit import ModalModel, fit_transfer_function, modal_form, select_order


def hz(w_rad_s):
    return np.asarray(w_rad_s) / (2 * np.pi)


# The lecture's hand-fitted piezo actuator model (frequencies in rad/s there).
PIEZO_RES = [(2450, 0.1), (4860, 0.05), (4860, 0.7), (4860, 0.8), (9800, 0.02)]
PIEZO_ANTI = [(2875, 0.01), (9540, 0.01)]
LIGHT_RES = [2450, 4860, 9800]  # zeta <= 0.1
N_AVG = 20


def piezo():
    return ModalModel(
        0.673,
        resonances=[(hz(w), z) for w, z in PIEZO_RES],
        antiresonances=[(hz(w), z) for w, z in PIEZO_ANTI],
    )


def noisy_frf(f_hz, h, rel, seed, n_avg=N_AVG):
    """Complex Gaussian error of rms `rel * |h|` per bin and the H1 coherence that
    goes with it: E|dH|^2 / |H|^2 = (1 - coh) / (n coh)  =>  coh = 1 / (1 + n rel^2)."""
    rng = np.random.default_rng(seed)
    e = (rng.standard_normal(f_hz.size) + 1j * rng.standard_normal(f_hz.size)) / np.sqrt(2)
    coh = np.full(f_hz.size, 1.0 / (1.0 + n_avg * rel**2))
    return FrequencyResponse(f_hz, h * (1 + rel * e), coh, n_avg, "h1")


def nearest(pairs, f_hz):
    return min(pairs, key=lambda p: abs(p[0] - f_hz))


@pytest.fixture(scope="module")
def piezo_grid():
    f = hz(np.geomspace(100.0, 20000.0, 400))
    return f, piezo().response(f)


# --- lecture's piezo model -----------------------------------------------------


def test_modal_model_writes_down_the_lecture_model():
    m = piezo()
    # DC gain read off the Bode plot: -3.44 dB.
    assert 20 * np.log10(abs(m.response(0.0))) == pytest.approx(-3.44, abs=0.005)
    # Each factor is the lecture's w^2 / (s^2 + 2 zeta w s + w^2): at s = j w it is 1 / (2 j zeta).
    single = ModalModel(1.0, resonances=[(hz(2450), 0.1)])
    assert single.response(hz(2450)) == pytest.approx(1 / (0.2j))
    anti = ModalModel(1.0, antiresonances=[(hz(2875), 0.01)])
    assert anti.response(hz(2875)) == pytest.approx(0.02j)
    # Rational form agrees with the factored one; roots are where the factors say.
    num, den = m.to_tf()
    f = hz(np.geomspace(100, 20000, 50))
    np.testing.assert_allclose(signal.freqs(num, den, 2 * np.pi * f)[1], m.response(f), rtol=1e-9)
    p = m.poles()
    assert len(p) == 10 and np.all(p.real < 0)
    np.testing.assert_allclose(sorted(np.abs(m.zeros())), [2875, 2875, 9540, 9540], rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_piezo_fit_from_noisy_frf(piezo_grid, seed):
    f, G = piezo_grid
    rel = 0.015
    frf = noisy_frf(f, G, rel, seed)
    fit = fit_transfer_function(frf, 4, 10, weights="coherence")
    assert fit.stable and fit.n_params == 15
    modal = modal_form(fit)
    for w in LIGHT_RES:
        f_fit, z_fit = nearest(modal.resonances, hz(w))
        assert f_fit == pytest.approx(hz(w), rel=0.01)
    # damping of the lightly damped modes as well
    assert nearest(modal.resonances, hz(2450))[1] == pytest.approx(0.1, rel=0.05)
    assert nearest(modal.resonances, hz(9800))[1] == pytest.approx(0.02, rel=0.1)
    for w, _ in PIEZO_ANTI:
        assert nearest(modal.antiresonances, hz(w))[0] == pytest.approx(hz(w), rel=0.01)
    assert modal.gain == pytest.approx(0.673, rel=0.01)
    # Within 1 dB (and a few degrees) of the noise-free truth over the whole band.
    ratio = fit.response(f) / G
    assert np.max(np.abs(20 * np.log10(np.abs(ratio)))) < 1.0
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 3.0
    # With inverse-std weights the minimised cost is chi-square per bin: ~ 1 - p / (2 N).
    assert 0.85 < fit.weighted_cost < 1.1
    # Lecture's C is the noise power left: mean |rel G e|^2 ~ rel^2 mean |G|^2.
    assert fit.cost == pytest.approx(rel**2 * np.mean(np.abs(G) ** 2), rel=0.2)
    # The fit's dB error against the noisy data is the noise: ~ 8.686 * rel / sqrt(2).
    assert fit.fit_db_rms == pytest.approx(20 / np.log(10) * rel / np.sqrt(2), rel=0.2)


@pytest.mark.parametrize("weights", [None, "coherence"])
def test_piezo_noise_free_is_recovered_exactly(piezo_grid, weights):
    f, G = piezo_grid
    frf = FrequencyResponse(f, G, np.ones(f.size), N_AVG, "h1")
    fit = fit_transfer_function(frf, 4, 10, weights=weights)
    assert fit.reflected_poles == 0 and fit.stable
    np.testing.assert_allclose(fit.response(f), G, rtol=1e-8)
    want = sorted(np.abs(piezo().poles()))
    np.testing.assert_allclose(sorted(np.abs(fit.poles)), want, rtol=1e-7)
    modal = modal_form(fit)
    assert modal.gain == pytest.approx(0.673, rel=1e-9)
    np.testing.assert_allclose(modal.response(f), G, rtol=1e-8)
    for (fa, za), (w, z) in zip(modal.antiresonances, PIEZO_ANTI, strict=False):
        assert fa == pytest.approx(hz(w), rel=1e-8) and za == pytest.approx(z, rel=1e-6)
    # The scipy polynomials describe the same system.
    np.testing.assert_allclose(signal.freqs(fit.num, fit.den, 2 * np.pi * f)[1], G, rtol=1e-8)
    assert fit.cost < 1e-20


def test_coherence_weights_are_relative_weights_for_constant_coherence(piezo_grid):
    f, G = piezo_grid
    frf = noisy_frf(f, G, 0.02, seed=3)
    a = fit_transfer_function(frf, 4, 10, weights="coherence")
    b = fit_transfer_function(frf, 4, 10, weights=7.0 / np.abs(frf.response))
    np.testing.assert_allclose(a.response(f), b.response(f), rtol=1e-6)
    assert a.weighting == "coherence" and b.weighting == "array"


def test_select_order_piezo(piezo_grid):
    f, G = piezo_grid
    frf = noisy_frf(f, G, 0.015, seed=0)
    orders = [(2, 6), (2, 8), (4, 8), (4, 10), (6, 10), (6, 12)]
    best, table = select_order(frf, orders=orders, weights="coherence")
    assert (best.n_num, best.n_den) == (4, 10)
    assert [r.selected for r in table].count(True) == 1
    assert [r.n_params for r in table] == sorted(r.n_params for r in table)
    too_small = {(r.n_num, r.n_den): r.fit.weighted_cost for r in table}
    assert too_small[(4, 8)] > 10 * best.weighted_cost
    best_bic, _ = select_order(frf, orders=orders, weights="coherence", criterion="bic")
    assert (best_bic.n_num, best_bic.n_den) == (4, 10)


# --- two-mass axis: rigid-body integrator -----------------------------------------


def two_mass(m1=40.0, m2=10.0, f0_hz=20.0, zeta=0.02):
    """Torque -> motor velocity of the two-mass axis (thesis eqs. 2.1-2.2):
    (m2 s^2 + d s + k) / (s (m1 m2 s^2 + d (m1 + m2) s + k (m1 + m2)))."""
    w0 = 2 * np.pi * f0_hz
    k = w0**2 * m1 * m2 / (m1 + m2)
    d = 2 * zeta * w0 * m1 * m2 / (m1 + m2)
    num = [m2, d, k]
    den = np.polymul([1.0, 0.0], [m1 * m2, d * (m1 + m2), k * (m1 + m2)])
    f_anti = np.sqrt(k / m2) / (2 * np.pi)
    return num, den, f_anti


def test_two_mass_with_fixed_integrator():
    num, den, f_anti = two_mass()
    f = np.geomspace(1.0, 200.0, 300)
    frf = noisy_frf(f, signal.freqs(num, den, 2 * np.pi * f)[1], 0.02, seed=5)
    fit = fit_transfer_function(frf, 2, 2, weights="coherence", integrators=1)
    assert fit.integrators == 1 and fit.stable
    assert np.count_nonzero(fit.poles == 0) == 1 and len(fit.den) == 4
    modal = modal_form(fit)
    assert modal.integrators == 1
    ((f_res, z_res),) = modal.resonances
    ((f_ar, z_ar),) = modal.antiresonances
    assert f_res == pytest.approx(20.0, rel=0.005) and z_res == pytest.approx(0.02, rel=0.1)
    assert f_ar == pytest.approx(f_anti, rel=0.005)
    # Below the mode the axis is one rigid mass: G ~ 1 / ((m1 + m2) s).
    assert modal.gain == pytest.approx(1 / 50.0, rel=0.01)


def test_two_mass_free_denominator_finds_the_pole_at_zero():
    num, den, _ = two_mass()
    f = np.geomspace(1.0, 200.0, 300)
    h = signal.freqs(num, den, 2 * np.pi * f)[1]
    fit = fit_transfer_function(noisy_frf(f, h, 0.02, seed=6), 2, 3, weights="coherence")
    assert fit.stable and fit.integrators == 0
    real = [p for p in fit.poles if abs(p.imag) < 1e-9 * abs(p)]
    assert len(real) == 1 and abs(real[0]) < 1e-3 * 2 * np.pi * 1.0  # far below the band
    ((f_res, _),) = modal_form(fit).resonances
    assert f_res == pytest.approx(20.0, rel=0.005)
    assert np.max(np.abs(20 * np.log10(np.abs(fit.response(f) / h)))) < 0.5


def test_two_mass_from_simulated_h1_with_zoh_delay():
    fs = 1000.0
    num, den, _ = two_mass()
    rng = np.random.default_rng(7)
    b, a, _ = signal.cont2discrete((num, den), 1 / fs, method="zoh")
    u = rng.standard_normal(60_000)
    y = signal.lfilter(np.ravel(b), a, u)
    y += 0.02 * np.std(y) * rng.standard_normal(y.size)
    frf = h1_estimate(u, y, fs, segment_length=4096)
    # A zero-order hold looks like half a sample of delay.
    fit = fit_transfer_function(frf, 2, 2, weights="coherence", integrators=1, delay_s=0.5 / fs, band_hz=(2.0, 100.0))
    ((f_res, z_res),) = modal_form(fit).resonances
    assert f_res == pytest.approx(20.0, rel=0.005) and z_res == pytest.approx(0.02, rel=0.2)
    assert fit.band_hz[0] >= 2.0 and fit.band_hz[1] <= 100.0
    assert modal_form(fit).gain == pytest.approx(1 / 50.0, rel=0.02)
    f = frf.band(2.0, 100.0).frequency_hz
    truth = signal.freqs(num, den, 2 * np.pi * f)[1]
    # the fit (without its delay) against the continuous plant
    fit_no_delay = fit.response(f) * np.exp(2j * np.pi * f * 0.5 / fs)
    assert np.max(np.abs(20 * np.log10(np.abs(fit_no_delay / truth)))) < 0.5


def test_select_order_two_mass_max_order():
    num, den, _ = two_mass()
    f = np.geomspace(1.0, 200.0, 300)
    frf = noisy_frf(f, signal.freqs(num, den, 2 * np.pi * f)[1], 0.02, seed=8)
    best, table = select_order(frf, max_order=4, relative_degree=0, weights="coherence", integrators=1)
    assert [(r.n_num, r.n_den) for r in table] == [(1, 1), (2, 2), (3, 3), (4, 4)]
    assert (best.n_num, best.n_den) == (2, 2) and best.integrators == 1


# --- stability ---------------------------------------------------------------


def test_unstable_poles_are_reflected():
    # The data of an unstable mode: Levy and SK propose right-half-plane poles.
    w0, zeta = 2 * np.pi * 20.0, 0.05
    f = np.geomspace(1.0, 100.0, 200)
    h = signal.freqs([w0**2], [1.0, -2 * zeta * w0, w0**2], 2 * np.pi * f)[1]
    frf = FrequencyResponse(f, h, np.ones(f.size), 10, "h1")
    # Without the final refinement the result is the reflected Levy/SK iterate:
    # the mirror image of the unstable pair, same frequency and |damping|.
    sk = fit_transfer_function(frf, 0, 2, refine=False)
    assert sk.reflected_poles >= 2 and sk.stable
    ((f_res, z_res),) = modal_form(sk).resonances
    assert f_res == pytest.approx(20.0, rel=1e-6) and z_res == pytest.approx(zeta, rel=1e-6)
    assert np.all(sk.poles.real < 0)
    for weights in (None, "coherence"):
        fit = fit_transfer_function(frf, 0, 2, weights=weights)
        assert fit.reflected_poles >= 2
        assert fit.stable and np.all(fit.poles.real < 0)


def test_overfitted_noise_stays_stable(piezo_grid):
    f, G = piezo_grid
    frf = noisy_frf(f, G, 0.05, seed=11)
    fit = fit_transfer_function(frf, 8, 14, weights="coherence", iterations=10)
    assert fit.stable and np.all(fit.poles.real < 0)
    assert np.max(np.abs(20 * np.log10(np.abs(fit.response(f) / G)))) < 1.5


# --- properties -----------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(
    f1=st.floats(5.0, 50.0),
    ratio=st.floats(2.0, 5.0),
    z1=st.floats(0.01, 0.3),
    z2=st.floats(0.01, 0.3),
    za=st.floats(0.005, 0.2),
    gain=st.floats(0.01, 100.0),
    corner=st.floats(0.3, 3.0),
)
def test_modal_round_trip(f1, ratio, z1, z2, za, gain, corner):
    f2 = f1 * ratio
    truth = ModalModel(
        gain,
        resonances=[(f1, z1), (f2, z2)],
        antiresonances=[(np.sqrt(f1 * f2), za)],
        real_poles_hz=[corner * f1],
    )
    f = np.geomspace(f1 / 10, f2 * 5, 300)
    frf = FrequencyResponse(f, truth.response(f), np.ones(f.size), 1, "h1")
    fit = fit_transfer_function(frf, 2, 5)
    m = modal_form(fit)
    assert m.gain == pytest.approx(gain, rel=1e-6)
    for got, want in zip(m.resonances, truth.resonances, strict=False):
        assert got == pytest.approx(want, rel=1e-5)
    assert m.antiresonances[0] == pytest.approx(truth.antiresonances[0], rel=1e-5)
    assert m.real_poles_hz[0] == pytest.approx(corner * f1, rel=1e-5)


def test_delay_is_removed_and_put_back():
    w0 = 2 * np.pi * 30.0
    f = np.linspace(1.0, 150.0, 200)
    tau = 2e-3
    h = signal.freqs([w0**2], [1.0, 0.1 * w0, w0**2], 2 * np.pi * f)[1]
    h = h * np.exp(-2j * np.pi * f * tau)
    frf = FrequencyResponse(f, h, np.ones(f.size), 1, "h1")
    fit = fit_transfer_function(frf, 0, 2, delay_s=tau)
    np.testing.assert_allclose(fit.response(f), h, rtol=1e-9)
    assert modal_form(fit).delay_s == tau
    np.testing.assert_allclose(modal_form(fit).response(f), h, rtol=1e-9)


# --- errors --------------------------------------------------------------------


def test_errors():
    f = np.linspace(1.0, 100.0, 10)
    frf = FrequencyResponse(f, 1 / (1 + 1j * f), np.ones(10), 1, "h1")
    with pytest.raises(ConfigError, match="n_den"):
        fit_transfer_function(frf, 1, -1)
    with pytest.raises(ConfigError, match="weights"):
        fit_transfer_function(frf, 0, 1, weights="magic")
    with pytest.raises(ConfigError, match="weights"):
        fit_transfer_function(frf, 0, 1, weights=np.ones(3))
    with pytest.raises(ConfigError, match="delay_s"):
        fit_transfer_function(frf, 0, 1, delay_s=-1.0)
    with pytest.raises(DataError, match="too few"):
        fit_transfer_function(frf, 10, 12)
    nan_coh = FrequencyResponse(f, frf.response, np.full(10, np.nan), 1, "etfe")
    with pytest.raises(DataError, match="coherence"):
        fit_transfer_function(nan_coh, 0, 1, weights="coherence")
    with pytest.raises(ConfigError, match="criterion"):
        select_order(frf, orders=[(0, 1)], criterion="best")
    with pytest.raises(ConfigError, match="orders"):
        select_order(frf)
    with pytest.raises(ConfigError, match="resonances"):
        ModalModel(1.0, resonances=[(-5.0, 0.1)])
    with pytest.raises(ConfigError, match="real_poles_hz"):
        ModalModel(1.0, real_poles_hz=[0.0])
