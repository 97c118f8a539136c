"""Model order and structure chosen for a transfer-function fit by a criterion that penalises order."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.tffit.fit import check_order, fit_transfer_function, frf_weights
from hilident.ident.tffit.model import REAL_TOL, TWO_PI, TfFit, TfOrderCandidate
from hilident.ident.tffit.roots import AXIS_TOL

__all__ = ["select_order", "select_structure"]

_CRITERIA = ("threshold", "aic", "bic")
_STRUCTURE_CRITERIA = ("mdl", "aic", "validation")
#: Most lines the screening fits of :func:`select_structure` use.
_SCREEN_BINS = 200


def select_order(
    frf: FrequencyResponse,
    orders: Sequence[tuple[int, int]] | None = None,
    max_order: int | None = None,
    criterion: str = "threshold",
    threshold: float = 0.1,
    relative_degree: int | None = None,
    **fit_options,
) -> tuple[TfFit, list[TfOrderCandidate]]:
    """Fit several orders and return the smallest adequate one.

    Candidates are `orders` (``[(n_num, n_den), ...]``) or, with
    `max_order`, every ``n_den = 1 .. max_order`` with
    ``n_num = n_den - relative_degree`` (all ``0 <= n_num <= n_den`` when
    `relative_degree` is None). The lecture guesses the relative degree from
    the roll-off (-20 dB/decade or -90 degrees per order) above the last
    resonance.

    Criteria, on the weighted cost ``V`` each fit minimised:

    * ``"threshold"`` (default): the candidate with the fewest parameters
      that no larger candidate improves on by more than `threshold`
      (relative), i.e. ``V_i <= (1 + threshold) V_j`` for every ``j`` with
      more parameters. Once the model explains the data to within its noise,
      more parameters only lower ``V`` by about ``p / (2 bins)``.
    * ``"aic"`` / ``"bic"``: lowest ``N ln(V_sum / N) + 2 p`` (or ``p ln N``)
      with ``N = 2 * bins`` real residuals.

    Only stable fits are eligible (they always are, the fit reflects unstable
    poles); ties go to fewer parameters.

    Parameters
    ----------
    frf : FrequencyResponse
    orders : sequence of (int, int), optional
    max_order : int, optional
        Exactly one of `orders` and `max_order` must be given.
    criterion : {"threshold", "aic", "bic"}
    threshold : float
        Relative cost improvement that justifies more parameters (> 0).
    relative_degree : int, optional
        See above; only with `max_order`.
    **fit_options
        Passed to :func:`fit_transfer_function` (weights, integrators, ...).

    Returns
    -------
    (TfFit, list of TfOrderCandidate)
        The chosen fit and one row per candidate (``selected`` marks it),
        sorted by parameter count.
    """
    if criterion not in _CRITERIA:
        raise ConfigError("criterion", f"must be one of {_CRITERIA}, got {criterion!r}")
    if not (np.isfinite(threshold) and threshold > 0.0):
        raise ConfigError("threshold", f"must be a positive number, got {threshold!r}")
    if (orders is None) == (max_order is None):
        raise ConfigError("orders", "give exactly one of orders=[(n_num, n_den), ...] and max_order")
    if orders is None:
        orders = _orders_up_to(max_order, relative_degree)
    else:
        orders = _checked_orders(orders)
    orders = sorted(orders, key=lambda mn: (mn[0] + 1 + mn[1], mn[1], mn[0]))

    rows = [_order_candidate(frf, m, n, fit_options) for m, n in orders]
    ok = [r for r in rows if r.fit is not None and r.fit.stable]
    if not ok:
        why = "; ".join(r.error for r in rows if r.error)
        raise DataError(f"no candidate order gave a stable fit: {why}")

    if criterion == "threshold":
        chosen = _smallest_adequate(ok, threshold)
    else:
        chosen = min(ok, key=lambda r: (getattr(r, criterion), r.n_params))
    table = [TfOrderCandidate(r.n_num, r.n_den, r.fit, r.aic, r.bic, r is chosen, r.error) for r in rows]
    assert chosen.fit is not None  # ok holds the candidates with a fit
    return chosen.fit, table


def _orders_up_to(max_order, relative_degree) -> list[tuple[int, int]]:
    """``(n_num, n_den)`` for ``n_den = 1 .. max_order``: every numerator degree, or ``n_den - relative_degree``."""
    max_order = check_order("max_order", max_order, 1)
    if relative_degree is None:
        orders = [(m, n) for n in range(1, max_order + 1) for m in range(n + 1)]
    else:
        rd = check_order("relative_degree", relative_degree, 0)
        orders = [(n - rd, n) for n in range(max(1, rd), max_order + 1)]
    if not orders:
        raise ConfigError("max_order", f"{max_order} leaves no order with relative_degree={relative_degree}")
    return orders


def _checked_orders(orders) -> list[tuple[int, int]]:
    """The given ``(n_num, n_den)`` pairs, checked, without repeats, in their order."""
    checked = []
    for item in orders:
        try:
            m, n = item
        except (TypeError, ValueError):
            raise ConfigError("orders", f"entries must be (n_num, n_den), got {item!r}") from None
        checked.append((check_order("orders.n_num", m, 0), check_order("orders.n_den", n, 0)))
    if not checked:
        raise ConfigError("orders", "must not be empty")
    return list(dict.fromkeys(checked))


def _order_candidate(frf: FrequencyResponse, m: int, n: int, fit_options: dict) -> TfOrderCandidate:
    """One row of :func:`select_order`: the fit of ``(m, n)`` and its AIC and BIC, or why it failed."""
    try:
        fit = fit_transfer_function(frf, m, n, **fit_options)
    except DataError as exc:
        return TfOrderCandidate(m, n, None, np.inf, np.inf, error=str(exc))
    N = 2 * fit.n_bins
    v = max(fit.weighted_cost * N / 2.0, np.finfo(float).tiny)  # sum of squares
    p = fit.n_params
    return TfOrderCandidate(m, n, fit, N * np.log(v / N) + 2 * p, N * np.log(v / N) + p * np.log(N))


def _smallest_adequate(ok: list[TfOrderCandidate], threshold: float) -> TfOrderCandidate:
    """The first candidate (fewest parameters) that no larger one improves on by more than `threshold`."""
    # Tiny absolute slack so that noise-free data (costs near rounding) does not
    # force the largest model.
    slack = 1e-12 * max(r.weighted_cost for r in ok)
    for i, r in enumerate(ok):
        larger = [q for q in ok[i + 1 :] if q.n_params > r.n_params]
        limit = [(1.0 + threshold) * q.weighted_cost + slack for q in larger]
        if all(r.weighted_cost <= lim for lim in limit):
            return r
    return ok[-1]


def _structures(max_order, order, relative_degree, integrators):
    """``(n_num, n_den_free, integrators)`` candidates; `order` counts every pole (integrators included)."""
    orders = [order] if order is not None else range(1, max_order + 1)
    ints = [integrators] if integrators is not None else range(3)
    out = []
    for k in ints:
        for n in orders:
            if n < k:
                continue
            rds = [relative_degree] if relative_degree is not None else range(min(n, 3) + 1)
            out += [(n - rd, n - k, k) for rd in rds if 0 <= n - rd]
    return sorted(set(out), key=lambda c: (c[0] + 1 + c[1], c[1] + c[2], c[2], c[0]))


def select_structure(
    frf: FrequencyResponse,
    max_order: int = 4,
    order: int | None = None,
    relative_degree: int | None = None,
    integrators: int | None = None,
    criterion: str = "mdl",
    weights: str | ArrayLike | None = "coherence",
    holdout_every: int = 4,
    **fit_options,
) -> tuple[TfFit, list[TfOrderCandidate]]:
    """Degrees, integrators and relative degree of a transfer function, chosen by a criterion that penalises order.

    Every structure within the limits is fitted (:func:`fit_transfer_function`)
    and scored on the weighted complex error ``V`` (sum of squares over
    ``N = 2 * bins`` real residuals) with ``p = n_num + 1 + n_den`` free
    parameters:

    * ``"mdl"`` (default): ``N ln(V / N) + p ln N`` (Rissanen's minimum
      description length, the same as BIC): an extra pole pair must lower
      ``V`` by more than a factor ``N^(-4 / N)`` to be kept, which noise alone
      does not do.
    * ``"aic"``: ``N ln(V / N) + 2 p`` (penalises less; keeps more structure).
    * ``"validation"``: every `holdout_every`-th line is left out of the fit
      and the weighted cost on those lines decides; a structure that fits the
      noise of the fitted lines does worse on lines it has not seen. Ties
      within the held-out cost's own scatter go to fewer parameters.

    Unlike the lecture's rule of thumb (relative degree from the roll-off
    above the last resonance, integrators from the slope at the bottom of the
    band), no part of the band decides alone. A structure with a pole or
    zero more than a decade above the band (in the band a constant) or, with
    free integrators, below it (in the band an integrator or its inverse),
    with a complex pole or zero pair outside the band (a mode the data do
    not show), or with a pole on the imaginary axis ranks after those
    without.

    Parameters
    ----------
    frf : FrequencyResponse
    max_order : int
        Highest denominator degree tried, integrators included (>= 1).
    order, relative_degree, integrators : int, optional
        Fix the denominator degree (integrators included), ``deg D - deg N``
        and the poles at ``s = 0``; None lets the criterion choose
        (integrators 0 to 2, relative degree 0 to 3).
    criterion : {"mdl", "aic", "validation"}
    weights : None, "coherence" or array_like
        As for :func:`fit_transfer_function`.
    holdout_every : int
        Line spacing of the held-out lines for ``"validation"`` (>= 2).
    **fit_options
        Passed to :func:`fit_transfer_function` (delay_s, band_hz, ...).

    Every structure is first fitted without the Levenberg-Marquardt stage
    (on at most 200 evenly picked lines); the three best are refitted with it
    on every line and ranked again.

    Returns
    -------
    (TfFit, list of TfOrderCandidate)
        The chosen fit (refitted on every line for ``"validation"``) and one
        row per structure, sorted by parameter count; ``selected`` marks the
        choice.

    Raises
    ------
    ConfigError
        Limits or criterion out of range, or no structure satisfies them.
    DataError
        No structure gave a fit.
    """
    if criterion not in _STRUCTURE_CRITERIA:
        raise ConfigError("criterion", f"must be one of {_STRUCTURE_CRITERIA}, got {criterion!r}")
    max_order = check_order("max_order", max_order, 1)
    if order is not None:
        order = check_order("model_order", order, 1)
    if relative_degree is not None:
        relative_degree = check_order("model_relative_degree", relative_degree, 0)
    if integrators is not None:
        integrators = check_order("model_integrators", integrators, 0)
    holdout_every = check_order("holdout_every", holdout_every, 2)
    cands = _structures(max_order, order, relative_degree, integrators)
    if not cands:
        raise ConfigError(
            "model_relative_degree",
            f"no structure with order {order if order is not None else f'<= {max_order}'}, relative degree "
            f"{relative_degree} and {integrators} integrator(s)",
        )
    w_all, weighting = frf_weights(frf, frf.response, weights)
    train_w = w_all
    hold = np.zeros(len(frf), dtype=bool)
    if criterion == "validation":
        usable = np.flatnonzero((frf.frequency_hz > 0.0) & np.isfinite(frf.response) & (w_all > 0.0))
        hold[usable[holdout_every // 2 :: holdout_every]] = True
        train_w = np.where(hold, 0.0, w_all)

    # The screening fits use at most _SCREEN_BINS lines (every k-th): their ranking
    # changes little, their cost a lot; the final ranking uses every line.
    iterations = fit_options.pop("iterations", 30)
    usable = np.flatnonzero(train_w > 0.0)
    step = max(1, -(-usable.size // _SCREEN_BINS))
    screen_w = train_w
    if step > 1:
        screen_w = np.zeros_like(train_w)
        screen_w[usable[::step]] = train_w[usable[::step]]

    def score(m, n, k, refine):
        try:
            fit = fit_transfer_function(
                frf,
                m,
                n,
                weights=train_w if refine else screen_w,
                integrators=k,
                refine=refine,
                iterations=iterations if refine else min(iterations, 15),
                **fit_options,
            )
        except DataError as exc:
            return TfOrderCandidate(m, n, None, np.inf, np.inf, error=str(exc), integrators=k)
        N = 2 * fit.n_bins
        v = max(fit.weighted_cost * N / 2.0, np.finfo(float).tiny)
        p = fit.n_params
        val = float("nan")
        if criterion == "validation":
            e = w_all[hold] * (frf.response[hold] - fit.response(frf.frequency_hz[hold]))
            val = float(np.mean(np.abs(e) ** 2))
        return TfOrderCandidate(
            m, n, fit, N * np.log(v / N) + 2 * p, N * np.log(v / N) + p * np.log(N), integrators=k, validation=val
        )

    def slow(r):
        # A free pole or zero more than a decade outside the band is not a feature the
        # data show: below the band a pole acts as an integrator (with a slight leak,
        # e.g. uncompensated viscous friction) and a zero cancels one (without
        # integrators a zero at 0 is a real differentiator), above it either acts as
        # a constant; a complex pair outside the band bends only its edge. A
        # structure without such roots ranks first.
        poles = r.fit.poles[: len(r.fit.poles) - r.fit.integrators]
        zeros = r.fit.zeros
        lo, hi = r.fit.band_hz
        low = TWO_PI * lo / 10.0
        below = integrators is None and (
            np.any(np.abs(poles) < low) or (r.integrators > 0 and np.any(np.abs(zeros) < low))
        )
        roots = np.r_[poles, zeros]
        # a complex pair outside the band is a resonance or anti-resonance the data do not show
        pair = np.abs(roots.imag) > REAL_TOL * np.abs(roots)
        outside = (np.abs(roots) < TWO_PI * lo) | (np.abs(roots) > TWO_PI * hi)
        # a pole on the imaginary axis (a fit that ran off to an undamped mode)
        undamped = np.any(-poles.real <= AXIS_TOL * np.abs(poles))
        return bool(below or undamped or np.any(np.abs(roots) > TWO_PI * hi * 10.0) or np.any(pair & outside))

    def rank(rows):
        ok = [r for r in rows if r.fit is not None]
        if not ok:
            raise DataError("no structure could be fitted: " + "; ".join(r.error for r in rows if r.error))
        if criterion == "validation":
            best = min(r.validation for r in ok)
            # the held-out cost of n lines scatters by about sqrt(2 / n) of itself
            slack = best * np.sqrt(2.0 / max(int(hold.sum()), 1))
            return sorted(ok, key=lambda r: (slow(r), r.validation > best + slack, r.n_params, r.validation))
        key = "bic" if criterion == "mdl" else "aic"
        return sorted(ok, key=lambda r: (slow(r), getattr(r, key), r.n_params))

    # Screen every structure with the linear (Levy + Sanathanan-Koerner) fit,
    # then refine the few best with Levenberg-Marquardt and rank again.
    refine = fit_options.pop("refine", True)
    rows = [score(m, n, k, False) for m, n, k in cands]
    if refine:
        short = rank(rows)[:3]
        refined = {id(r): score(r.n_num, r.n_den, r.integrators, True) for r in short}
        rows = [refined.get(id(r), r) for r in rows]
        chosen = rank([refined[id(r)] for r in short])[0]
    else:
        chosen = rank(rows)[0]
    fit = chosen.fit
    if criterion == "validation":
        fit = fit_transfer_function(
            frf, chosen.n_num, chosen.n_den, weights=w_all, integrators=chosen.integrators, refine=refine, **fit_options
        )
    table = [dataclasses.replace(r, selected=r is chosen) for r in rows]
    return dataclasses.replace(fit, weighting=weighting), table
