"""Which modes of a fit over several drives each drive notches (hilident.pipeline.node_notches), on exact
responses of a two-mode mechanism whose residues are known."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.ident.frequency import FrequencyResponse
from hilident.pipeline.node_notches import node_reductions, node_resonances

F = np.arange(1.0, 60.0, 0.25)
#: Two modes: (f Hz, zeta, residue matrix R[output][input] of the term R / (s - lambda) + conj)
MODES = [
    (20.0, 0.02, np.array([[0.0 - 2.0j, 0.0 - 1.5j], [0.0 - 1.5j, 0.0 - 1.2j]])),
    # the second mode barely in drive 0's own element, strongly in drive 1's
    (35.0, 0.01, np.array([[0.0 - 0.01j, 0.0 + 0.3j], [0.0 + 0.3j, 0.0 - 3.0j]])),
]


def _pole(f: float, zeta: float) -> complex:
    w = 2 * np.pi * f
    return complex(-zeta * w, w * np.sqrt(1 - zeta**2))


def _element(j: int, i: int) -> np.ndarray:
    s = 2j * np.pi * F
    h = np.zeros(F.size, dtype=complex)
    for f, zeta, r in MODES:
        lam = _pole(f, zeta)
        h += r[j, i] / (s - lam) + np.conj(r[j, i]) / (s - np.conj(lam))
    return h


def _summary_modes(ci_hz=(0.02, 0.02)) -> list[dict]:
    out = []
    for (f, zeta, r), ci in zip(MODES, ci_hz, strict=True):
        lam = _pole(f, zeta)
        out.append(
            {
                "frequency_hz": f,
                "damping_ratio": zeta,
                "pole_rad_per_s": [lam.real, lam.imag],
                "residue_real": r.real.tolist(),
                "residue_imag": r.imag.tolist(),
                "frequency_ci95_hz": ci,
                "damping_ci95": 0.1 * zeta,
            }
        )
    return out


def _own(k: int) -> FrequencyResponse:
    return FrequencyResponse(F, _element(k, k), np.ones(F.size), 4, "periodic")


def test_a_drive_notches_the_modes_it_drives_and_sees_not_one_that_barely_moves_it():
    first = node_resonances(_own(0), _summary_modes(), 0, 0, node_id=1, max_count=4)
    assert [r.frequency_hz for r in first.resonances] == [20.0]
    assert any("35 Hz" in n and "neither drives nor sees" in n for n in first.notes), first.notes
    second = node_resonances(_own(1), _summary_modes(), 1, 1, node_id=2, max_count=4)
    assert sorted(r.frequency_hz for r in second.resonances) == [20.0, 35.0]
    res = {r.frequency_hz: r for r in second.resonances}[35.0]
    assert res.damping_ratio == 0.01 and res.frequency_ci95_hz == 0.02 and res.method == "fit"
    line = int(np.argmin(np.abs(F - 35.0)))
    assert res.peak_magnitude_db == pytest.approx(20 * np.log10(abs(_element(1, 1)[line])))


def test_the_count_keeps_the_largest_in_the_drives_own_response_and_an_uncertain_mode_is_refused():
    kept = node_resonances(_own(1), _summary_modes(), 1, 1, node_id=2, max_count=1)
    assert [r.frequency_hz for r in kept.resonances] == [35.0]  # 35 Hz rings more in drive 1's own element
    assert any("beyond identification.max_resonances = 1" in n for n in kept.notes)
    doubtful = node_resonances(_own(1), _summary_modes(ci_hz=(0.02, 0.5)), 1, 1, node_id=2, max_count=4)
    assert [r.frequency_hz for r in doubtful.resonances] == [20.0]
    (warning,) = doubtful.warnings
    assert warning.startswith("node 2: no notch at 35 Hz: the 95 % interval of its frequency")


def test_the_verification_compares_each_drives_own_response_before_and_after_its_notch():
    from hilident.filters.notch import NotchSpec, design_notch

    before = _own(0)
    notch = design_notch(NotchSpec(20.0, 4.0, 40.0), 4000.0)
    after = FrequencyResponse(F, before.response * notch.response(F, 4000.0), np.ones(F.size), 4, "periodic")
    (res,) = node_resonances(before, _summary_modes(), 0, 0, node_id=1, max_count=4).resonances
    (row,) = node_reductions(before, after, [res], 2.0, node=1)
    assert row["node"] == 1 and row["frequency_hz"] == 20.0
    assert row["reduction_db"] == pytest.approx(-20 * np.log10(abs(notch.response(np.array([20.0]), 4000.0)[0])))
    assert row["band_reduction_db"] > 15.0 and row["floor_db"] == np.inf and not row["floor_limited"]


def test_a_periodic_elements_spread_gives_the_error_the_noise_floor_reads_even_where_a_notch_took_it_down():
    from hilident.ident.frfquality import estimate_error_std
    from hilident.pipeline.node_notches import coherence_of_spread

    h = np.array([1e-3, 1e-6, 1e-12, 2e-4])  # the last ones far below their error: a notch's centre
    std = np.array([1e-5, 2e-6, 3e-6, np.nan])
    for averages, method in ((2, "periodic"), (5, "periodic"), (8, "h1")):
        g = coherence_of_spread(h, std, averages, method)
        frf = FrequencyResponse(np.arange(1.0, 5.0), h, g, averages, method)
        np.testing.assert_allclose(estimate_error_std(frf)[:3], np.sqrt(2) * std[:3], rtol=1e-9)
        assert np.isnan(g[3])
    assert np.isnan(coherence_of_spread(h, std, 1, "periodic")).all()  # one period: no spread
