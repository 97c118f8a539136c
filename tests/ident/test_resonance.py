import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError
from hilident.ident.frequency import FrequencyResponse, h1_estimate
from hilident.ident.resonance import Resonance, find_resonances, fit_local_mode

FS = 1000.0


def two_mass(m1=40.0, m2=10.0, f0_hz=20.0, zeta=0.02):
    """Continuous torque -> motor velocity of the two-mass axis (c = 1), with the
    rigid-body integrator: (m2 s^2 + d s + k) / (s (m1 m2 s^2 + d (m1+m2) s + k (m1+m2)))."""
    w0 = 2 * np.pi * f0_hz
    k = w0**2 * m1 * m2 / (m1 + m2)  # coupled mode sqrt(k (m1+m2) / (m1 m2)) = w0
    d = 2 * zeta * w0 * m1 * m2 / (m1 + m2)
    num = [m2, d, k]
    den = np.polymul([1.0, 0.0], [m1 * m2, d * (m1 + m2), k * (m1 + m2)])
    return num, den


def mode_of(den):
    """Natural frequency (Hz) and damping of the complex pole pair of den."""
    p = [r for r in np.roots(den) if r.imag > 0][0]
    return abs(p) / (2 * np.pi), -p.real / abs(p)


def simulate_h1(num, den, seconds, noise_rel, seed, segment_length, fs=FS):
    rng = np.random.default_rng(seed)
    b, a, _ = signal.cont2discrete((num, den), 1.0 / fs, method="zoh")
    u = rng.standard_normal(int(seconds * fs))
    y = signal.lfilter(np.ravel(b), a, u)
    y = y + noise_rel * np.std(y) * rng.standard_normal(u.size)
    return h1_estimate(u, y, fs, segment_length)


def analytic_frf(num, den, f_hz, coherence=1.0):
    h = signal.freqs(num, den, worN=2 * np.pi * f_hz)[1]
    return FrequencyResponse(f_hz, h, np.full(f_hz.size, coherence), 50, "h1")


# --- acceptance: gantry and lecture examples ---------------------------------


@pytest.mark.parametrize("zeta", [0.02, 0.05])
@pytest.mark.parametrize("seed", [0, 1])
def test_gantry_resonance_from_noisy_h1(zeta, seed):
    num, den = two_mass(zeta=zeta)
    f_true, z_true = mode_of(den)
    assert f_true == pytest.approx(20.0, rel=1e-9) and z_true == pytest.approx(zeta, rel=1e-9)
    frf = simulate_h1(num, den, seconds=120, noise_rel=0.02, seed=seed, segment_length=8192)
    found = find_resonances(frf)
    assert len(found) == 1
    res = found[0]
    assert res.method == "fit"
    assert res.frequency_hz == pytest.approx(f_true, rel=0.005)
    assert res.damping_ratio == pytest.approx(z_true, rel=0.15)
    assert res.coherence > 0.9
    true_peak = 20 * np.log10(np.max(np.abs(signal.freqs(num, den, 2 * np.pi * np.linspace(15, 25, 4001))[1])))
    assert res.peak_magnitude_db == pytest.approx(true_peak, abs=1.0)


def test_lecture_mass_spring_damper():
    m, b, k = 5.0, 1.0, 10.0
    f_true = np.sqrt(k / m) / (2 * np.pi)  # 0.225 Hz
    z_true = b / (2 * np.sqrt(k * m))  # 0.0707
    # 1 kHz as in the lecture; 1000 s so that 0.0076 Hz bins resolve the
    # 0.032 Hz half-power bandwidth
    frf = simulate_h1([1.0], [m, b, k], 1000, 0.02, seed=3, segment_length=2**17)
    found = find_resonances(frf)
    assert len(found) == 1
    assert found[0].frequency_hz == pytest.approx(f_true, rel=0.01)
    assert found[0].damping_ratio == pytest.approx(z_true, rel=0.15)


def test_no_resonance_when_coherence_is_low_everywhere():
    num, den = two_mass()
    rng = np.random.default_rng(4)
    b, a, _ = signal.cont2discrete((num, den), 1.0 / FS, method="zoh")
    u = rng.standard_normal(60_000)
    y = signal.lfilter(np.ravel(b), a, u)
    y = signal.detrend(y) + 20 * np.std(y) * rng.standard_normal(u.size)
    frf = h1_estimate(u, y, FS, 4096)
    assert np.max(frf.coherence) < 0.8
    assert find_resonances(frf) == []
    # the same data, taken at face value, would give (noise) peaks
    assert len(find_resonances(frf, coherence_threshold=None)) > 0


# --- the local fit -----------------------------------------------------------


def test_exact_on_analytic_response_with_antiresonance():
    num, den = two_mass(zeta=0.05)
    f = np.arange(0.25, 200, 0.25)
    res = find_resonances(analytic_frf(num, den, f))
    assert len(res) == 1
    assert res[0].frequency_hz == pytest.approx(20.0, rel=1e-6)
    assert res[0].damping_ratio == pytest.approx(0.05, rel=1e-5)
    true_peak = 20 * np.log10(np.max(np.abs(signal.freqs(num, den, 2 * np.pi * np.linspace(18, 22, 20001))[1])))
    assert res[0].peak_magnitude_db == pytest.approx(true_peak, abs=0.01)


def test_fit_local_mode_returns_model():
    num, den = two_mass(zeta=0.03)
    f = np.linspace(12, 28, 80)
    h = signal.freqs(num, den, 2 * np.pi * f)[1]
    fn, zeta, model = fit_local_mode(f, h)
    assert fn == pytest.approx(20.0, rel=1e-6) and zeta == pytest.approx(0.03, rel=1e-5)
    assert np.allclose(model(f), h, rtol=1e-5)
    assert fit_local_mode(f[:3], h[:3]) is None


def test_two_modes_sorted_and_most_prominent_first():
    # Two separate modes, 12 Hz lightly and 60 Hz more damped, of opposite
    # sign so that no anti-resonance lies between them: the 12 Hz peak is then
    # the more prominent one.
    def mode(f0, z, gain):
        w = 2 * np.pi * f0
        return [gain * w**2], [1, 2 * z * w, w**2]

    (n1, d1), (n2, d2) = mode(12, 0.01, 1.0), mode(60, 0.04, -0.5)
    num = np.polyadd(np.polymul(n1, d2), np.polymul(n2, d1))
    den = np.polymul(d1, d2)
    f = np.arange(0.5, 150, 0.1)
    both = find_resonances(analytic_frf(num, den, f))
    assert [r.method for r in both] == ["fit", "fit"]
    assert [r.frequency_hz for r in both] == pytest.approx([12.0, 60.0], rel=2e-3)
    assert [r.damping_ratio for r in both] == pytest.approx([0.01, 0.04], rel=0.05)
    (top,) = find_resonances(analytic_frf(num, den, f), max_count=1)
    assert top.frequency_hz == pytest.approx(12.0, rel=2e-3)
    (upper,) = find_resonances(analytic_frf(num, den, f), band_hz=(30.0, 100.0))
    assert upper.frequency_hz == pytest.approx(60.0, rel=2e-3)


def test_falls_back_to_half_power_when_no_stable_pole_fits():
    # The mirror image of a mode (anti-causal phase) has a textbook magnitude
    # peak but no stable pole pair: the result must say it is a fallback.
    w0, z = 2 * np.pi * 30.0, 0.04
    f = np.arange(1.0, 100.0, 0.05)
    s = 2j * np.pi * f
    h = np.conj(w0**2 / (s**2 + 2 * z * w0 * s + w0**2))
    (res,) = find_resonances(FrequencyResponse(f, h, np.ones(f.size), 10, "h1"))
    assert res.method == "half_power"
    assert res.frequency_hz == pytest.approx(30.0, abs=0.05)
    assert res.damping_ratio == pytest.approx(z, rel=0.05)


def test_coherence_none_accepts_estimates_without_coherence():
    num, den = two_mass(zeta=0.05)
    frf = analytic_frf(num, den, np.arange(0.25, 100, 0.25), coherence=np.nan)
    assert find_resonances(frf) == []
    (res,) = find_resonances(frf, coherence_threshold=None)
    assert res.frequency_hz == pytest.approx(20.0, rel=1e-6)


def test_argument_checks_and_dict():
    frf = analytic_frf(*two_mass(), np.arange(1.0, 50.0, 0.5))
    with pytest.raises(ConfigError, match="coherence_threshold"):
        find_resonances(frf, coherence_threshold=1.5)
    with pytest.raises(ConfigError, match="max_count"):
        find_resonances(frf, max_count=0)
    with pytest.raises(ConfigError, match="band_hz"):
        find_resonances(frf, band_hz=(40.0, 10.0))
    d = Resonance(20.0, 0.02, -60.0, 0.99).to_dict()
    assert {k: d[k] for k in ("frequency_hz", "damping_ratio", "peak_magnitude_db", "coherence", "method")} == {
        "frequency_hz": 20.0,
        "damping_ratio": 0.02,
        "peak_magnitude_db": -60.0,
        "coherence": 0.99,
        "method": "fit",
    }
    # without a fit the uncertainty is unknown, never 0
    assert all(np.isnan(d[k]) for k in ("frequency_ci95_hz", "damping_ci95", "local_fit_db_rms"))
