"""One list of resonances, notches only where the evidence allows, and the verification's band figure."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from hilident.config.tables import IdentificationConfig, NotchConfig
from hilident.filters.notch import NotchSpec, design_notch
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.resonance import RejectedPeak, Resonance
from hilident.pipeline.eligibility import coherence_amplitude_factor, notch_eligibility
from hilident.pipeline.findings import grouped
from hilident.pipeline.measurement import measurement_quality
from hilident.pipeline.notches import design_notches
from hilident.pipeline.plant import identify_plant
from hilident.pipeline.plant_model import fit_plant_model, model_warnings, reconcile_resonances
from hilident.pipeline.records import resonance_records
from hilident.pipeline.verification import peak_reductions

FS = 1000.0
FILTER_RATE = 4000.0


def mode_frf(f0=22.0, zeta=0.018, df=0.5, top=80.0):
    """Torque to velocity of a free two-mass axis (mode f0, anti-resonance 0.9 f0) on a line grid."""
    f = np.arange(df, top, df)
    s = 2j * np.pi * f
    wa, w0 = 2 * np.pi * 0.9 * f0, 2 * np.pi * f0
    h = (s**2 + 2 * zeta * wa * s + wa**2) / (s * (s**2 + 2 * zeta * w0 * s + w0**2)) * (w0 / wa) ** 2 * 0.02
    return FrequencyResponse(f, h, np.full(f.size, 0.99), 8, "h1")


def resonance(f0=22.0, zeta=0.018, ci=0.01, fit_db=0.1, noise_db=0.3, ratio=0.5):
    return Resonance(f0, zeta, -40.0, 0.99, "fit", ci, 0.001, fit_db, noise_db, 20.0, ratio)


def notched(frf, biquad):
    return FrequencyResponse(
        frf.frequency_hz,
        frf.response * biquad.response(frf.frequency_hz, FILTER_RATE),
        frf.coherence,
        frf.n_averages,
        frf.method,
    )


# --- the band figure ------------------------------------------------------------------------


def test_band_figure_counts_the_skirts_a_narrow_notch_leaves():
    before = mode_frf()
    narrow = design_notch(NotchSpec(22.0, 1.0, 40.0), FILTER_RATE)
    (row,) = peak_reductions(before, notched(before, narrow), [resonance()], band_bandwidths=2.0)
    assert row["reduction_db"] > 30.0  # at the resonance line the notch is deep
    assert row["band_reduction_db"] < row["reduction_db"] - 10.0  # beside it, the response is barely touched
    lo, hi = row["band_hz"]
    assert lo == pytest.approx(22.0 - 2 * 2 * 0.018 * 22.0) and hi == pytest.approx(22.0 + 2 * 2 * 0.018 * 22.0)
    band = (before.frequency_hz >= lo) & (before.frequency_hz <= hi)
    after = np.abs(notched(before, narrow).response)
    want = 20 * np.log10(np.abs(before.response[band]).max() / after[band].max())
    assert row["band_reduction_db"] == pytest.approx(want)


def test_width_search_reaches_the_band_target_on_the_measured_response():
    before = mode_frf()
    cfg = NotchConfig(depth_db=30.0, width_factor=1.0, min_width_ratio=0.05, min_reduction_db=20.0)
    (d,) = design_notches([resonance()], cfg, FILTER_RATE, [0], before)
    assert d.spec.width_hz > 0.05 * 22.0 and not d.warning  # widened from the starting width
    (row,) = peak_reductions(before, notched(before, d.biquad), [resonance()], 2.0)
    assert row["band_reduction_db"] >= 20.0
    assert row["band_reduction_db"] == pytest.approx(d.predicted_band_reduction_db, abs=0.5)
    # the narrower notch the old rule gave falls short of the band figure
    start = design_notch(NotchSpec(22.0, 0.05 * 22.0, 30.0), FILTER_RATE)
    (old,) = peak_reductions(before, notched(before, start), [resonance()], 2.0)
    assert old["band_reduction_db"] < 20.0


def test_unreachable_band_target_is_an_honest_warning_with_the_figure():
    before = mode_frf()
    cfg = NotchConfig(min_width_ratio=0.02, width_factor=1.0, max_width_ratio=0.05, min_reduction_db=20.0)
    (d,) = design_notches([resonance()], cfg, FILTER_RATE, [0], before)
    assert d.spec.width_hz == pytest.approx(0.05 * 22.0)
    assert d.predicted_band_reduction_db < 20.0
    assert f"{d.predicted_band_reduction_db:.1f} dB" in d.warning and "max_width_ratio" in d.warning


def test_model_prediction_without_a_measured_response():
    cfg = NotchConfig(min_width_ratio=0.02, width_factor=1.0, min_reduction_db=20.0)
    (d,) = design_notches([resonance()], cfg, FILTER_RATE, [0])
    assert d.predicted_band_reduction_db >= 20.0


# --- notch only with evidence ---------------------------------------------------------------


def test_notch_eligibility_reasons():
    assert notch_eligibility(resonance())["notchable"]
    wide = notch_eligibility(resonance(ci=0.6))  # 1.2 Hz interval, 0.78 Hz bandwidth
    assert not wide["notchable"] and "95 % interval" in wide["reason"]
    assert wide["amplitude_factor"] == pytest.approx(2 * 1.2 / (2 * 0.018 * 22.0))
    bad = notch_eligibility(resonance(fit_db=4.0, noise_db=0.5, ratio=5.0))
    assert not bad["notchable"] and "local fit" in bad["reason"] and "5.0 times" in bad["reason"]
    # a peak fitted as well as its noisy bins allow is fine however large its dB error
    assert notch_eligibility(resonance(fit_db=2.5, noise_db=2.0, ratio=1.2))["notchable"]
    # without coherence the dB error alone decides
    blind = notch_eligibility(resonance(fit_db=4.0, ratio=float("nan")))
    assert not blind["notchable"] and "without a coherence" in blind["reason"]
    grid = notch_eligibility(dataclasses.replace(resonance(), method="half_power", frequency_ci95_hz=float("nan")))
    assert not grid["notchable"] and "no local fit" in grid["reason"]
    records = resonance_records([resonance(), resonance(ci=0.6)])
    assert [r["notchable"] for r in records] == [True, False] and "not_notchable" in records[1]


def test_coherence_amplitude_factor():
    # SNR grows with the amplitude squared: coherence 0.5 (SNR 1) to 0.9 (SNR 9) needs 3 times the amplitude
    assert coherence_amplitude_factor(0.5, 0.9) == pytest.approx(3.0)
    assert coherence_amplitude_factor(0.95, 0.9) < 1.0
    assert np.isnan(coherence_amplitude_factor(0.0, 0.9))


# --- one source of truth for resonances -----------------------------------------------------


def simulate(amplitude, noise, seconds=40.0, seed=0):
    """Two-mass axis (mode 21.8 Hz) driven by band-limited noise torque; velocity with sensor noise."""
    rng = np.random.default_rng(seed)
    w0, wa, zeta = 2 * np.pi * 21.8, 2 * np.pi * 19.5, 0.018
    num = np.array([1.0, 2 * zeta * wa, wa**2]) * 0.02 * (w0 / wa) ** 2
    den = np.polymul([1.0, 0.5], [1.0, 2 * zeta * w0, w0**2])  # a slightly leaky integrator
    b, a, _ = signal.cont2discrete((num, den), 1 / FS, method="zoh")
    u = amplitude * rng.standard_normal(int(seconds * FS))
    y = signal.lfilter(np.ravel(b), a, u) + noise * rng.standard_normal(u.size)
    return u, y


def test_reported_resonances_and_model_modes_agree():
    u, y = simulate(amplitude=1.0, noise=1e-5)
    cfg = IdentificationConfig(max_resonances=4)
    plant = identify_plant(u, u, y, y, FS, cfg, (2.0, 80.0))
    (res,) = plant.resonances
    assert res.frequency_hz == pytest.approx(21.8, rel=0.005)
    notes = plant.model.mode_notes
    reported = [n for n in notes if n["reported"]]
    assert [n["resonance_hz"] for n in reported] == [res.frequency_hz]
    assert all(n["reason"] for n in notes if not n["reported"])
    model = plant.model.to_dict()
    assert model["resonances"] == notes and "rhp_zeros" in model and "flagged_poles" in model
    assert all(-z["real_part_rad_s"] < 0 for z in model["rhp_zeros"])  # only right-half-plane zeros there
    assert all(f > 0 for f in model["real_zeros_hz"])


def test_peak_without_a_model_mode_is_rejected_with_the_reason():
    frf = mode_frf()
    peak = resonance(f0=50.0, zeta=0.01)
    model = fit_plant_model(frf, (1.0, 79.0), 4)
    found, rejected, warnings = reconcile_resonances([resonance(), peak], [], model, 6, 0.5)
    assert [r.frequency_hz for r in found] == [22.0]
    (rej,) = rejected
    assert rej.frequency_hz == 50.0 and "not confirmed by the fitted model" in rej.reason
    assert not warnings
    # with every pole the order limit allows already used, the peak stays and a warning says why
    found, rejected, warnings = reconcile_resonances(
        [resonance(), peak], [], model, model.fit.n_den + model.fit.integrators, 0.5
    )
    assert len(found) == 2 and "model_max_order" in warnings[0]


def test_model_mode_without_a_peak_is_noted_not_reported():
    frf = mode_frf()
    model = fit_plant_model(frf, (1.0, 79.0), 4)
    rejected = [RejectedPeak(21.75, -40.0, 0.5, "coherence 0.500 around the peak is under ...")]
    found, _, _ = reconcile_resonances([], rejected, model, 4, 0.5)
    assert found == []
    (note,) = model.mode_notes
    assert not note["reported"] and "coherence 0.500" in note["reason"]


def test_weak_excitation_reports_no_resonance_and_says_why():
    u, y = simulate(amplitude=1.0, noise=2e-2, seconds=20.0, seed=3)  # coherence far under 0.8 at the mode
    plant = identify_plant(u, u, y, y, FS, IdentificationConfig(), (2.0, 80.0))
    assert plant.resonances == []
    assert plant.rejected and all(p.reason for p in plant.rejected)
    assert any("no resonance" in w for w in plant.warnings)


def test_sampling_rule_violation_is_a_note_with_the_decimation_that_meets_it():
    # hilident fits no discrete-time model: the omega0 h rule asks nothing of the run, so it is a note
    frf = mode_frf()
    quality, warnings, notes = measurement_quality(
        frf, [resonance(), resonance(f0=25.0)], np.random.default_rng(0).standard_normal(4000), FS, (1.0, 79.0), None
    )
    assert [r["within_rule"] for r in quality["sampling"]["resonances"]] == [False, False]
    assert not [w for w in warnings if w.startswith("sampling")]
    (line,) = grouped(notes)  # one cause: one line naming both resonances
    assert "decimate them by 2" in line and "within_rule" in line and "22 Hz, 25 Hz" in line


def test_a_rate_below_the_sampling_rule_says_what_it_limits_not_to_sample_faster():
    frf = mode_frf()
    fast_mode = resonance(f0=300.0)
    excitation = np.random.default_rng(5).standard_normal(4000)  # a spectrum over the band, as a run plays
    _, warnings, notes = measurement_quality(frf, [fast_mode], excitation, FS, (1.0, 79.0), None)
    (note,) = notes
    assert "300 Hz" in note and "500 Hz (Nyquist)" in note
    assert "or faster" not in " ".join(warnings + notes) and "run.sample_rate_hz" not in note


def test_a_misfitting_model_confirms_nothing_and_says_so():
    frf = mode_frf()
    model = fit_plant_model(frf, (1.0, 79.0), 4)
    # misses the data by 10 times the scatter, and by 3 dB; even at the order limit it confirms nothing
    model.fit = dataclasses.replace(model.fit, weighted_cost=100.0, fit_db_rms=3.0)
    clean, vague = resonance(f0=50.0), resonance(ci=0.6)  # the second's frequency interval is too wide
    found, rejected, warnings = reconcile_resonances([clean, vague], [], model, 1, 0.5)
    assert found == [clean] and "local fit alone" in warnings[0]  # stands on its own evidence
    (rej,) = rejected
    assert rej.frequency_hz == 22.0 and "misses the measured response as a whole" in rej.reason
    assert "95 % interval" in rej.reason
    assert not any(n["reported"] for n in model.mode_notes)
    assert any("not that of a linear plant" in w for w in model_warnings(model))


def test_a_count_key_takes_a_number_or_its_text(tmp_path):
    from hilident.config.tables import load_config
    from hilident.errors import ConfigError

    base = (Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml").read_text()
    for value, expected in (("3", "3"), ('"3"', "3"), ('"auto"', "auto")):
        path = tmp_path / "c.toml"
        path.write_text(base.replace("[identification]\n", f"[identification]\nmodel_order = {value}\n", 1))
        assert load_config(path).identification.model_order == expected
    path.write_text(base.replace("[identification]\n", "[identification]\nmodel_order = 13\n", 1))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert err.value.key == "identification.model_order"
