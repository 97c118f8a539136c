"""The order search's shared-factor solution against a plain per-candidate least squares.

The reference below builds every candidate's regressor matrix sample by sample
and solves it with ``numpy.linalg.lstsq`` (an SVD): nothing of the production
code path (no QR factor, no column selection) is used.
"""

from itertools import product

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import DataError
from hilident.ident import arx
from hilident.ident.arx import arx_order_search, fit_arx

EPS = np.finfo(float).eps
RSS_FLOOR = 1e-24  # as documented in arx.py: losses below this fraction of the output energy tie


def reference_grid(u, y, nas, nbs, nks):
    """Per candidate: orders, lstsq parameters (None when rank deficient), RSS, rank margin.

    The rank margin is the smallest singular value of the column-normalised
    regressor over the largest one, divided by the documented tolerance
    ``max(m, p) * eps``: below 1 means linearly dependent.
    """
    grid = [(na, nb, nk) for na, nb, nk in product(nas, nbs, nks) if na + nb]
    n0 = max(max(na for na, _, _ in grid), max(nk + nb - 1 for _, nb, nk in grid))
    ks = np.arange(n0, y.size)
    out = []
    for na, nb, nk in grid:
        phi = np.array(
            [[y[k - i] for i in range(1, na + 1)] + [u[k - j] for j in range(nk, nk + nb)] for k in ks]
        ).reshape(ks.size, na + nb)
        target = y[ks]
        m, p = phi.shape
        norms = np.linalg.norm(phi, axis=0)
        if m <= p or np.any(norms == 0):
            out.append(((na, nb, nk), None, np.nan, 0.0))
            continue
        sv = np.linalg.svd(phi / norms, compute_uv=False)
        margin = sv[-1] / (sv[0] * max(m, p) * EPS)
        theta = np.linalg.lstsq(phi, target, rcond=None)[0] if margin > 1 else None
        rss = float(np.sum((target - phi @ theta) ** 2)) if theta is not None else np.nan
        out.append(((na, nb, nk), theta, rss, margin))
    return out, y[n0:]


def reference_scores(rss, p, y_rows):
    n = y_rows.size
    floored = max(rss, RSS_FLOOR * float(y_rows @ y_rows))
    base = n * np.log(floored / n)
    fit = 100.0 * (1.0 - np.sqrt(rss) / np.linalg.norm(y_rows - y_rows.mean()))
    return base + 2 * p, base + p * np.log(n), fit


def assert_matches_reference(u, y, nas, nbs, nks, rtol=1e-10):
    ref, y_rows = reference_grid(u, y, nas, nbs, nks)
    search = arx_order_search(u, y, nas, nbs, nks)
    _, fits = arx._fit_grid(np.asarray(u, float), np.asarray(y, float), [r[0] for r in ref])
    energy = float(y_rows @ y_rows)
    assert [(c.na, c.nb, c.nk) for c in search.candidates] == [r[0] for r in ref]
    for (orders, theta, rss, _), cand, fit in zip(ref, search.candidates, fits, strict=True):
        p = orders[0] + orders[1]
        assert cand.n_params == p
        if theta is None:
            assert fit is None, orders
            assert np.isnan(cand.V) and np.isnan(cand.fit_percent)
            assert cand.aic == np.inf and cand.bic == np.inf
            assert cand.fit_validation_percent == -np.inf
            continue
        assert fit is not None, orders
        scale = np.max(np.abs(theta))
        np.testing.assert_allclose(fit.params, theta, rtol=rtol, atol=rtol * scale, err_msg=str(orders))
        # a loss at rounding level (an exact model) is compared on the output's energy scale
        assert cand.V == pytest.approx(0.5 * rss, rel=rtol, abs=1e-20 * energy), orders
        aic, bic, fit_pct = reference_scores(rss, p, y_rows)
        assert cand.aic == pytest.approx(aic, rel=rtol, abs=1e-9), orders
        assert cand.bic == pytest.approx(bic, rel=rtol, abs=1e-9), orders
        assert cand.fit_percent == pytest.approx(fit_pct, rel=rtol, abs=1e-8), orders
        assert np.isnan(cand.fit_validation_percent)
    return search, ref


def zoh_data(n, noise, seed, kind="equation"):
    """The 5 Hz, zeta 0.1 plant sampled at 100 Hz (na = 2, nb = 2, nk = 1) under white input."""
    w0 = 2 * np.pi * 5.0
    bd, ad, _ = signal.cont2discrete(([w0**2], [1.0, 2 * 0.1 * w0, w0**2]), 0.01, "zoh")
    bd, ad = np.ravel(bd), ad
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    y0 = signal.lfilter(bd, ad, u)
    white = noise * np.std(y0) * rng.standard_normal(n)
    return u, y0 + (signal.lfilter([1.0], ad, white) if kind == "equation" else white)


def test_noisy_candidates_match_lstsq_and_the_choice_is_the_same():
    u, y = zoh_data(6000, 0.05, seed=1)  # longer than one block of rows
    search, ref = assert_matches_reference(u, y, range(1, 5), range(1, 4), range(0, 3))
    assert all(r[1] is not None for r in ref)  # noise: every candidate determined
    # the choice by the documented rule, from the reference's own scores
    y_rows = y[max(4, 2 + 3 - 1) :]
    aic = np.array([reference_scores(r[2], sum(r[0][:2]), y_rows)[0] for r in ref])
    adequate = [i for i in range(len(ref)) if aic[i] <= aic.min() + 2.0]
    best = min(adequate, key=lambda i: (sum(ref[i][0][:2]), aic[i]))
    assert (search.model.na, search.model.nb, search.model.nk) == ref[best][0]


def test_noise_free_overparametrised_candidates_are_marked_like_the_reference():
    u, y = zoh_data(800, 0.0, seed=2)
    search, ref = assert_matches_reference(u, y, range(1, 5), range(1, 4), range(0, 3))
    deficient = [r[0] for r in ref if r[1] is None]
    assert (3, 3, 1) in deficient and (4, 3, 2) in deficient  # the plant and a shifted copy of it
    assert (2, 2, 1) not in deficient
    # no candidate near the rank tolerance: the verdict does not hang on rounding
    assert all(r[3] < 1e-3 or r[3] > 1e3 for r in ref)
    assert (search.model.na, search.model.nb, search.model.nk) == (2, 2, 1)


def test_chosen_model_is_fit_arx_on_its_own_record():
    u, y = zoh_data(5000, 0.05, seed=3)
    search = arx_order_search(u, y, range(1, 5), range(1, 4), range(1, 3), criterion="bic")
    m = search.model
    own = fit_arx(u, y, m.na, m.nb, m.nk)
    assert m.n_equations == own.n_equations == u.size - max(m.na, m.nk + m.nb - 1)
    np.testing.assert_allclose(m.params, own.params, rtol=1e-10)
    np.testing.assert_allclose(m.stderr, own.stderr, rtol=1e-8)
    np.testing.assert_allclose(m.covariance, own.covariance, rtol=1e-8, atol=1e-8 * np.abs(own.covariance).max())
    assert m.V == pytest.approx(own.V, rel=1e-10)
    assert m.noise_variance == pytest.approx(own.noise_variance, rel=1e-10)
    assert m.fit_percent == pytest.approx(own.fit_percent, rel=1e-10)


def test_validation_fits_are_free_run_simulations_of_the_reference_parameters():
    u, y = zoh_data(3000, 0.01, seed=4, kind="output")
    uv, yv = zoh_data(2000, 0.01, seed=5, kind="output")
    nas, nbs, nks = range(1, 4), range(1, 3), (1, 2)
    ref, _ = reference_grid(u, y, nas, nbs, nks)
    search = arx_order_search(u, y, nas, nbs, nks, criterion="validation", u_val=uv, y_val=yv)
    n0 = 3
    for (orders, theta, _, _), cand in zip(ref, search.candidates, strict=True):
        na, nb, nk = orders
        b = np.r_[np.zeros(nk), theta[na:]]
        a = np.r_[1.0, -theta[:na]]
        y_sim = np.empty_like(yv)
        y_sim[:n0] = yv[:n0]
        zi = signal.lfiltic(b, a, yv[:n0][::-1], uv[:n0][::-1])
        y_sim[n0:] = signal.lfilter(b, a, uv[n0:], zi=zi)[0]
        expected = 100 * (1 - np.linalg.norm(yv[n0:] - y_sim[n0:]) / np.linalg.norm(yv[n0:] - yv[n0:].mean()))
        assert cand.fit_validation_percent == pytest.approx(expected, rel=1e-9, abs=1e-9), orders
    assert search.model.na == 2


@pytest.mark.parametrize("block_elements", [1, 50, 640])  # 1, 7 and 91 rows of 7 columns
def test_factor_streamed_in_small_blocks_is_the_same(monkeypatch, block_elements):
    u, y = zoh_data(300, 0.05, seed=6)
    monkeypatch.setattr(arx, "_BLOCK_ELEMENTS", block_elements)
    assert_matches_reference(u, y, range(0, 3), range(0, 3), (0, 2))


def test_record_shorter_than_the_grid_needs_is_a_data_error():
    u, y = zoh_data(40, 0.05, seed=7)
    with pytest.raises(DataError, match="no candidate"):
        arx_order_search(u[:8], y[:8], [4], [4], [1])  # 4 rows for 8 parameters
    with pytest.raises(DataError, match="no candidate"):
        arx_order_search(u[:6], y[:6], [8], [1], [1])  # the lags reach past the record


@settings(max_examples=30, deadline=None)
@given(
    nas=st.sets(st.integers(0, 3), min_size=1, max_size=3),
    nbs=st.sets(st.integers(0, 3), min_size=1, max_size=3),
    nks=st.sets(st.integers(0, 2), min_size=1, max_size=2),
    n=st.integers(20, 200),
    noise=st.sampled_from([0.0, 1e-3, 0.1]),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_grids_match_lstsq(nas, nbs, nks, n, noise, seed):
    assume(any(na + nb for na, nb in product(nas, nbs)))
    u, y = zoh_data(n, noise, seed)
    ref, _ = reference_grid(u, y, sorted(nas), sorted(nbs), sorted(nks))
    assume(any(r[1] is not None for r in ref))
    assume(all(r[3] < 1e-2 or r[3] > 1e2 for r in ref if r[3] > 0))  # clear rank verdicts only
    assert_matches_reference(u, y, sorted(nas), sorted(nbs), sorted(nks))
