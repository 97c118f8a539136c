"""Records that miss samples: the drift, the trials' line spectra and the standstill period read around them."""

from __future__ import annotations

import numpy as np

from hilident.ident.preprocess import remove_drift
from hilident.session.auto_amplitude import _last_period, period_spectra

P = 200


def test_the_drift_of_a_record_missing_samples_is_removed_as_from_the_whole_record():
    rng = np.random.default_rng(2)
    t = np.arange(6 * P)
    x = np.sin(2 * np.pi * 3 * t / P) + 0.5 * np.cos(2 * np.pi * 7 * t / P) + 1e-6 * (t - 300.0) ** 2 + 0.2
    present = np.ones(t.size, dtype=bool)
    present[rng.choice(t.size, 12, replace=False)] = False
    whole = remove_drift(x, P)
    gapped = remove_drift(np.where(present, x, np.nan), P, present=present)
    assert np.isnan(gapped[~present]).all()
    np.testing.assert_allclose(gapped[present], whole[present], atol=1e-6)


def test_trial_spectra_read_a_period_missing_samples_at_its_lines():
    t = np.arange(3 * P)
    x = np.cos(2 * np.pi * 5 * t / P) + 0.3 * np.sin(2 * np.pi * 9 * t / P)
    present = np.ones(t.size, dtype=bool)
    present[[P + 3, P + 150, 2 * P + 77]] = False
    lines = np.array([5, 9])
    expected = period_spectra(x, P, lines)
    got = period_spectra(np.where(present, x, np.nan), P, lines, present)
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_the_standstill_records_last_period_with_a_few_samples_missing_and_with_too_many():
    index = np.delete(np.arange(P + P // 4), [P // 4 + 10, P // 4 + 11])
    samples = {"sample_index": index, "torque_nm": index * 1.0}
    last, present = _last_period(samples, P)
    assert present is not None and (~present).sum() == 2 and np.flatnonzero(~present).tolist() == [10, 11]
    np.testing.assert_array_equal(last["torque_nm"][present], index[index >= P // 4] * 1.0)
    sparse = {"sample_index": np.delete(np.arange(P + P // 4), np.arange(P // 2, P // 2 + 50))}
    assert _last_period(sparse, P) == (None, None)
    whole, none = _last_period({"sample_index": np.arange(P + 5)}, P)
    assert none is None and whole["sample_index"].tolist() == list(range(5, P + 5))


def test_a_loop_response_of_a_record_missing_samples_matches_the_whole_records():
    from scipy import signal

    from hilident.config.tables import IdentificationConfig
    from hilident.pipeline.responses import loop_response

    rng = np.random.default_rng(5)
    bins = np.arange(2, 40)
    t = np.arange(8 * P)
    r = sum(np.cos(2 * np.pi * k * t / P + rng.uniform(0, 6)) for k in bins)
    b, a = signal.cheby1(2, 1, 0.15)
    y = signal.lfilter(b, a, r) + 1e-4 * t + 0.01 * rng.standard_normal(t.size)  # a drift and some noise
    r, y = r[P:], y[P:]  # the lead-in dropped
    present = np.ones(r.size, dtype=bool)
    present[rng.choice(r.size, 30, replace=False)] = False
    present[33::P] = False  # and one place of the period in every period: a host late there each time
    cfg = IdentificationConfig()
    whole, _ = loop_response(r, y, 1000.0, cfg, P, bins)
    gapped, notes = loop_response(
        np.where(present, r, np.nan), np.where(present, y, np.nan), 1000.0, cfg, P, bins, present=present
    )
    assert gapped.n_averages == whole.n_averages == 7
    np.testing.assert_allclose(gapped.response, whole.response, rtol=0.01)
    assert any(f"{(~present).sum()} of 1400 samples missing" in n for n in notes)


def test_a_trial_missing_samples_is_read_in_the_periods_that_have_enough():
    from pathlib import Path

    import pytest

    from hilident.config.tables import load_config
    from hilident.errors import DataError
    from hilident.session.auto_amplitude import AutoAmplitude

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml")
    t = np.arange(4 * P)
    lines = np.array([4, 6, 11])
    torque = sum(np.cos(2 * np.pi * k * t / P + k) for k in lines)
    velocity = 0.1 * sum(np.sin(2 * np.pi * k * t / P + k) for k in lines)
    present = np.ones(t.size, dtype=bool)
    present[[10, 250, 260]] = False  # periods 0 and 1 miss a few samples
    present[2 * P : 2 * P + 190] = False  # period 2 too many to read its lines
    samples = {
        "torque_nm": np.where(present, torque, np.nan),
        "velocity_mps": np.where(present, velocity, np.nan),
        "sample_index": t,
        "present": present,
    }
    chooser = AutoAmplitude(cfg, None, lambda exp, x, gapped: samples, [], None)
    s, spectra = chooser._trial_spectra(None, None, P, lines, None)
    assert len(spectra["torque"]) == 3  # periods 0, 1 and 3
    expected = np.fft.rfft(torque[:P])[lines]
    np.testing.assert_allclose(spectra["torque"], np.tile(expected, (3, 1)), atol=1e-8)
    assert len(s["torque_nm"]) == present.sum() and np.isfinite(s["torque_nm"]).all()
    samples["present"] = present & (t >= 3 * P)
    with pytest.raises(DataError, match="fewer than two periods"):
        chooser._trial_spectra(None, None, P, lines, None)


def test_a_sample_of_the_period_missing_from_every_period_is_left_unknown_and_the_drift_still_removed():
    """A host late at the same place of every period (cycle 7 of each) leaves that sample unknown; the drift
    is told from the response by the samples the periods share, and the response is given back where it exists."""
    t = np.arange(3 * P)
    tone = np.sin(2 * np.pi * 3 * t / P)
    drift = 2e-6 * (t - 400.0) ** 2
    present = np.ones(t.size, dtype=bool)
    present[[7, P + 7, 2 * P + 7, P + 40]] = False
    y = remove_drift(np.where(present, tone + drift, np.nan), P, present=present)
    assert np.isnan(y[~present]).all()
    np.testing.assert_allclose(y[present], tone[present] - tone[present].mean(), atol=0.005)


def test_periods_sharing_too_few_samples_cannot_tell_a_drift_and_say_so():
    import pytest

    from hilident.errors import DataError

    x = np.sin(2 * np.pi * 3 * np.arange(3 * P) / P)
    present = np.zeros(x.size, dtype=bool)
    present[:P] = True  # the first period whole, the others hold one sample of the period each
    present[[P + 5, 2 * P + 9]] = True
    with pytest.raises(DataError, match=r"only 4 samples of .* share their place in the .*-sample period"):
        remove_drift(np.where(present, x, np.nan), P, present=present)
