import numpy as np
import pytest
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import (
    FrequencyResponse,
    etfe,
    frf_from_reference,
    h1_estimate,
    periodic_frf,
)

FS = 1000.0


def two_mass_velocity(m1=40.0, m2=10.0, f0_hz=20.0, zeta=0.03, b1=20.0):
    """Torque -> motor velocity of the two-mass axis (thesis eqs. 2.1-2.2, c = 1).

    A small viscous term b1 (N·s/m) from the motor mass to ground makes the
    rigid-body pole stable; the coupled mode has frequency f0_hz and damping zeta.
    Returns the ZOH-discretised (b, a) at FS.
    """
    w0 = 2 * np.pi * f0_hz
    k = w0**2 * m1 * m2 / (m1 + m2)
    d = 2 * zeta * w0 * m1 * m2 / (m1 + m2)
    num = [m2, d, k]
    # (m1 s + b1)(m2 s^2 + d s + k) + (d s + k) m2 s
    den = np.polyadd(np.polymul([m1, b1], [m2, d, k]), [m2 * d, m2 * k, 0.0])
    b, a, _ = signal.cont2discrete((num, den), 1.0 / FS, method="zoh")
    return np.ravel(b), a


def truth(b, a, f_hz):
    return signal.freqz(b, a, worN=f_hz, fs=FS)[1]


# --- container ---------------------------------------------------------------


def test_frequency_response_helpers():
    f = np.array([0.0, 1.0, 2.0, 3.0])
    h = np.array([1.0, 10j, -100.0, 0.0])
    frf = FrequencyResponse(f, h, [1.0, 0.9, 0.5, 0.1], 7, "h1")
    assert np.allclose(frf.magnitude_db()[:3], [0.0, 20.0, 40.0])
    assert frf.magnitude_db()[3] == -np.inf
    assert np.allclose(frf.phase_deg()[:3], [0.0, 90.0, 180.0])
    part = frf.band(1.0, 2.0)
    assert np.array_equal(part.frequency_hz, [1.0, 2.0])
    assert np.array_equal(part.coherence, [0.9, 0.5])
    assert part.n_averages == 7 and part.method == "h1" and len(part) == 2
    part.response[0] = 0.0
    assert frf.response[1] == 10j  # band() returned a copy
    with pytest.raises(DataError, match="equal length"):
        FrequencyResponse(f, h[:3], np.ones(4), 1, "h1")
    with pytest.raises(ConfigError, match="f_lo"):
        frf.band(3.0, 1.0)


def test_unwrapped_phase_of_a_delay():
    f = np.linspace(0, 100, 101)
    frf = FrequencyResponse(f, np.exp(-2j * np.pi * f * 0.01), np.ones(101), 1, "h1")
    assert np.allclose(frf.phase_deg(unwrap=True), -360.0 * f * 0.01)


# --- H1 ----------------------------------------------------------------------


def test_h1_equals_scipy_welch_csd_coherence():
    rng = np.random.default_rng(0)
    u = rng.standard_normal(20_000)
    y = signal.lfilter([0.1, 0.05], [1.0, -1.5, 0.7], u) + 0.1 * rng.standard_normal(u.size)
    frf = h1_estimate(u, y, FS, 1024, overlap=0.5)
    f, s_uy = signal.csd(u, y, fs=FS, nperseg=1024)
    _, s_uu = signal.welch(u, fs=FS, nperseg=1024)
    _, coh = signal.coherence(u, y, fs=FS, nperseg=1024)
    assert np.allclose(frf.frequency_hz, f)
    assert np.allclose(frf.response, s_uy / s_uu, rtol=1e-10)
    assert np.allclose(frf.coherence, coh, atol=1e-10)
    assert frf.n_averages == 1 + (20_000 - 1024) // 512
    assert frf.method == "h1"


def test_h1_two_mass_against_analytic_response():
    b, a = two_mass_velocity()
    rng = np.random.default_rng(1)
    u = rng.standard_normal(120_000)  # torque, N·m
    y_clean = signal.lfilter(b, a, u)
    y = y_clean + 0.02 * np.std(y_clean) * rng.standard_normal(u.size)
    frf = h1_estimate(u, y, FS, 4096)
    G = truth(b, a, frf.frequency_hz)
    good = (frf.coherence >= 0.9) & (frf.frequency_hz > 0)
    assert good.sum() > 300  # bins up to where the response meets the noise floor
    err_db = frf.magnitude_db()[good] - 20 * np.log10(np.abs(G[good]))
    assert np.max(np.abs(err_db)) < 1.0
    err_deg = np.degrees(np.angle(frf.response[good] / G[good]))
    assert np.max(np.abs(err_deg)) < 6.0
    # coherence follows the output signal-to-noise ratio: |G|^2 / (|G|^2 + S_nn/S_uu)
    noise = (0.02 * np.std(y_clean)) ** 2
    expected = np.abs(G) ** 2 / (np.abs(G) ** 2 + noise)
    band = (frf.frequency_hz > 1) & (frf.frequency_hz < 400)
    assert np.median(np.abs(frf.coherence[band] - expected[band])) < 0.03
    # at the anti-resonance (about 17.9 Hz) the output drowns in noise
    anti = np.argmin(np.abs(G[band]))
    assert frf.coherence[band][anti] < 0.5


def test_h1_coherence_low_for_unrelated_signals():
    rng = np.random.default_rng(2)
    frf = h1_estimate(rng.standard_normal(50_000), rng.standard_normal(50_000), FS, 1024)
    # unbiased value is 0; estimate ~ 1/n_averages
    assert np.mean(frf.coherence) < 3.0 / frf.n_averages
    assert np.max(frf.coherence) < 0.2


def test_h1_full_record_of_1e6_samples():
    """A record of 10**6 samples is estimated (its speed is bench/ident.py's to measure, not a timed test's)."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal(1_000_000)
    y = signal.lfilter([0.2], [1.0, -0.8], u)
    frf = h1_estimate(u, y, FS, 8192)
    assert abs(frf.response[0] - 1.0) < 0.02  # DC gain 0.2 / (1 - 0.8)


def test_h1_argument_errors():
    u = np.random.default_rng(0).standard_normal(1000)
    with pytest.raises(ConfigError, match="segment_length"):
        h1_estimate(u, u, FS, 2000)
    with pytest.raises(ConfigError, match="segment_length"):
        h1_estimate(u, u, FS, 100.5)
    with pytest.raises(ConfigError, match="overlap"):
        h1_estimate(u, u, FS, 100, overlap=1.0)
    with pytest.raises(ConfigError, match="sample_rate_hz"):
        h1_estimate(u, u, -1.0, 100)
    with pytest.raises(DataError, match="'y'"):
        h1_estimate(u, u[:-1], FS, 100)
    with pytest.raises(DataError, match="'u'"):
        h1_estimate(np.where(u > 2, np.nan, u), u, FS, 100)


# --- closed loop -------------------------------------------------------------


def _poly_add(p, q):
    n = max(len(p), len(q))
    return np.pad(p, (0, n - len(p))) + np.pad(q, (0, n - len(q)))


def closed_loop_record(seed, n=300_000):
    """Velocity loop: PI on the velocity error, one sample of computation delay,
    excitation r added to the torque command, input disturbance d (load torque
    ripple) and velocity measurement noise v. Returns r, u, y and the plant."""
    bg, ag = two_mass_velocity()
    m = 50.0
    kp = m * 2 * np.pi * 5.0  # ~5 Hz velocity bandwidth
    ki = kp * 2 * np.pi * 1.0
    bc = np.array([0.0, kp + ki / FS, -kp])  # (kp + ki T / (1 - z^-1)) z^-1
    ac = np.array([1.0, -1.0])
    den = _poly_add(np.convolve(ag, ac), np.convolve(bg, bc))
    assert np.max(np.abs(np.roots(den))) < 1.0
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(n)
    d = 0.5 * rng.standard_normal(n)
    v = 0.02 / kp * rng.standard_normal(n)
    lf = signal.lfilter
    # u = S r - C G S d - C S v,  y = G S (r + d) + S v
    u = lf(np.convolve(ag, ac), den, r) - lf(np.convolve(bc, bg), den, d) - lf(np.convolve(bc, ag), den, v)
    y = lf(np.convolve(bg, ac), den, r + d) + lf(np.convolve(ag, ac), den, v)
    return r, u, y, (bg, ag)


def test_reference_estimate_unbiased_in_closed_loop_where_h1_is_not():
    r, u, y, (bg, ag) = closed_loop_record(seed=4)
    h1 = h1_estimate(u, y, FS, 2048)
    ref = frf_from_reference(r, u, y, FS, 2048)
    assert ref.method == "reference" and ref.n_averages == h1.n_averages
    true_db = 20 * np.log10(np.abs(truth(bg, ag, ref.frequency_hz[1:])))
    h1_err = h1.magnitude_db()[1:] - true_db
    ref_err = ref.magnitude_db()[1:] - true_db
    f = ref.frequency_hz[1:]
    band = (f >= 2) & (f <= 100) & (ref.coherence[1:] >= 0.25)
    assert band.sum() > 150  # of 200 bins
    assert np.max(np.abs(ref_err[band])) < 1.5
    assert abs(np.median(ref_err[band])) < 0.1
    # H1 drifts towards -1/C where the loop feeds the disturbance back into u:
    # it flattens the resonance at 20 Hz and is far off at low frequency.
    at = lambda hz: np.argmin(np.abs(f - hz))  # noqa: E731
    assert h1_err[at(20.0)] < -4.0
    assert abs(h1_err[at(2.0)]) > 4.0
    # (the reference estimate's small deficit at the peak is window smoothing
    # at 0.5 Hz resolution, which H1 shares)
    assert abs(ref_err[at(20.0)]) < 1.5 and abs(ref_err[at(2.0)]) < 1.5
    # coherence is the product of the r->y and r->u coherences
    _, c_ry = signal.coherence(r, y, fs=FS, nperseg=2048)
    _, c_ru = signal.coherence(r, u, fs=FS, nperseg=2048)
    assert np.allclose(ref.coherence, c_ry * c_ru, atol=1e-9)


# --- periodic excitation and ETFE --------------------------------------------


def multisine(period, bins, seed):
    rng = np.random.default_rng(seed)
    spec = np.zeros(period // 2 + 1, complex)
    spec[bins] = np.exp(2j * np.pi * rng.random(len(bins)))  # Schroeder-free random phases
    return np.fft.irfft(spec, n=period)


def test_periodic_frf_exact_without_noise():
    b, a = two_mass_velocity(b1=200.0)  # rigid-body transient gone in ~1 s
    P = 2000  # 2 s period -> 0.5 Hz lines
    bins = np.arange(1, 400)
    x = multisine(P, bins, seed=5)
    u = np.tile(x, 6)
    y = signal.lfilter(b, a, u)
    frf = periodic_frf(u, y, P, FS, skip_periods=2)  # transient gone after 4 s
    assert frf.n_averages == 4 and frf.method == "periodic"
    assert np.array_equal(frf.frequency_hz, bins * FS / P)
    G = truth(b, a, frf.frequency_hz)
    assert np.allclose(frf.response, G, rtol=1e-4)
    assert np.all(frf.coherence > 0.999999)


def test_periodic_frf_with_noise_and_chosen_bins():
    b, a = two_mass_velocity(b1=200.0)
    P = 1000
    x = multisine(P, np.arange(2, 200, 2), seed=6)  # even bins only
    u = np.tile(x, 22)
    rng = np.random.default_rng(6)
    y_clean = signal.lfilter(b, a, u)
    y = y_clean + 0.05 * np.std(y_clean) * rng.standard_normal(u.size)
    auto = periodic_frf(u, y, P, FS, skip_periods=2)
    assert np.array_equal(auto.frequency_hz, np.arange(2, 200, 2) * FS / P)  # odd bins not excited
    G = truth(b, a, auto.frequency_hz)
    good = auto.coherence > 0.9
    assert good.sum() > 60
    assert np.max(np.abs(auto.magnitude_db()[good] - 20 * np.log10(np.abs(G[good])))) < 1.0
    # low output SNR at the anti-resonance shows up as low quality
    assert auto.coherence[np.argmin(np.abs(G))] < auto.coherence[np.argmax(np.abs(G))]
    chosen = periodic_frf(u, y, P, FS, skip_periods=2, bins=[20, 40])
    assert np.allclose(chosen.frequency_hz, [20.0, 40.0])
    assert np.allclose(chosen.response, auto.response[[9, 19]])
    with pytest.raises(ConfigError, match="bins"):
        periodic_frf(u, y, P, FS, bins=[0, 3])
    with pytest.raises(DataError, match="at least 2"):
        periodic_frf(u[: 3 * P], y[: 3 * P], P, FS, skip_periods=2)


def test_etfe_matches_truth_for_steady_periodic_record():
    # The lecture's DFT ratio is exact when the record holds whole periods of a
    # steady-state response to a periodic input.
    b, a = two_mass_velocity(b1=200.0)
    P = 4000
    bins = np.arange(1, 1000)
    x = multisine(P, bins, seed=7)
    y = signal.lfilter(b, a, np.tile(x, 5))[-P:]
    frf = etfe(x, y, FS)
    assert frf.n_averages == 1 and frf.method == "etfe"
    assert frf.frequency_hz.size == P // 2 + 1 and np.all(np.isnan(frf.coherence))
    assert np.allclose(frf.response[bins], truth(b, a, frf.frequency_hz[bins]), rtol=1e-4)


def test_etfe_gives_nan_where_input_has_no_energy():
    u = np.zeros(64)
    u[0] = 1.0
    u[1] = 1.0  # DFT 1 + exp(-j w): exactly zero at Nyquist
    frf = etfe(u, np.roll(u, 1) + 0.5 * u, FS)
    assert np.isnan(frf.response[-1])
    assert np.allclose(frf.response[:-1], np.exp(-2j * np.pi * frf.frequency_hz[:-1] / FS) + 0.5)
