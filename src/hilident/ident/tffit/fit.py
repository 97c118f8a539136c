"""Transfer functions fitted to a frequency response: Levy, Sanathanan-Koerner, Levenberg-Marquardt.

The stages and the weighting are described in :mod:`hilident.ident.tffit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.tffit.model import REAL_TOL, TWO_PI, TfFit, zpk_response

__all__ = ["fit_transfer_function"]

# Bound on the log-coefficients of the stable factors (normalised s): keeps
# a pole that drifts off towards 0 or infinity from overflowing.
_LOG_LIMIT = 40.0


def check_order(key: str, value, low: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < low:
        raise ConfigError(key, f"must be an integer >= {low}, got {value!r}")
    return int(value)


def _reflect(roots: np.ndarray) -> tuple[np.ndarray, int]:
    """Mirror right-half-plane roots into the left half plane; returns the count."""
    bad = roots.real > 0.0
    out = np.where(bad, -roots.real + 1j * roots.imag, roots)
    return out, int(np.count_nonzero(bad))


def _lstsq_complex(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Real solution of ``A theta ~ b`` (complex rows), columns scaled to unit norm."""
    Ar = np.vstack([A.real, A.imag])
    br = np.concatenate([b.real, b.imag])
    col = np.linalg.norm(Ar, axis=0)
    col[col == 0.0] = 1.0
    sol = np.linalg.lstsq(Ar / col, br, rcond=None)[0]
    return sol / col


def _numerator_for(x, H, w, Dx, n_num):
    """Best numerator (normalised x, highest first) for a fixed denominator value."""
    A = (w / Dx)[:, None] * x[:, None] ** np.arange(n_num + 1)
    return _lstsq_complex(A, w * H)[::-1]


def frf_weights(frf: FrequencyResponse, H: np.ndarray, weights) -> tuple[np.ndarray, str]:
    n = H.size
    if weights is None:
        return np.ones(n), "none"
    if isinstance(weights, str):
        if weights != "coherence":
            raise ConfigError("weights", f"must be None, 'coherence' or an array, got {weights!r}")
        coh = frf.coherence
        if not np.all(np.isfinite(coh)):
            raise DataError(
                f"weights='coherence' needs a coherence at every bin, but the '{frf.method}' "
                "estimate has NaN coherence; pass weights=None or an array"
            )
        c = np.clip(coh, 1e-6, 1.0 - 1e-9)
        mag = np.maximum(np.abs(H), np.finfo(float).tiny)
        return np.sqrt(max(frf.n_averages, 1) * c / (1.0 - c)) / mag, "coherence"
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0.0) or not np.any(w > 0.0):
        raise ConfigError(
            "weights",
            f"an array must hold {n} finite non-negative values, not all 0, got shape {w.shape}",
        )
    return w, "array"


# --- the fit ------------------------------------------------------------------


def _factors(theta: np.ndarray, n_den: int) -> tuple[list[tuple[float, float]], float | None]:
    """Stable factors ``x^2 + a1 x + a0`` (and ``x + c``) from log-parameters."""
    e = np.exp(np.clip(theta, -_LOG_LIMIT, _LOG_LIMIT))
    quads = [(e[2 * i], e[2 * i + 1]) for i in range(n_den // 2)]
    return quads, (e[-1] if n_den % 2 else None)


def _poles_from_params(theta: np.ndarray, n_den: int) -> np.ndarray:
    """Roots of the stable factors, each quadratic solved on its own (no expansion)."""
    quads, c = _factors(theta, n_den)
    poles = []
    for a1, a0 in quads:
        disc = a1 * a1 - 4.0 * a0
        if disc < 0.0:
            im = 0.5 * np.sqrt(-disc)
            poles += [complex(-0.5 * a1, im), complex(-0.5 * a1, -im)]
        else:
            q = -0.5 * (a1 + np.sqrt(disc))  # avoids cancellation for the small root
            poles += [complex(q), complex(a0 / q)]
    if c is not None:
        poles.append(complex(-c))
    return np.array(poles, dtype=np.complex128)


def _params_from_poles(poles: np.ndarray, n_den: int) -> np.ndarray:
    """Log-parameters of quadratic (and one linear) stable factors holding `poles`."""
    poles = np.asarray(poles, dtype=np.complex128)
    tiny = np.exp(-_LOG_LIMIT)
    is_real = np.abs(poles.imag) <= REAL_TOL * np.abs(poles)
    quads = [(-2.0 * p.real, abs(p) ** 2) for p in poles[~is_real & (poles.imag > 0.0)]]
    # Pair the real poles neighbour by neighbour; an odd one out is the linear factor.
    real = np.sort(poles[is_real].real)
    lin = None
    if real.size % 2:
        lin, real = real[-1], real[:-1]
    quads += [(-(a + b), a * b) for a, b in zip(real[0::2], real[1::2], strict=False)]
    theta = []
    for a1, a0 in quads:
        theta += [np.log(max(a1, tiny)), np.log(max(a0, tiny))]
    if lin is not None:
        theta.append(np.log(max(-lin, tiny)))
    if len(theta) != n_den:  # complex roots without their conjugate
        raise DataError(f"could not factor {n_den} poles into real stable sections")
    return np.array(theta)


@dataclass(frozen=True)
class _Normalised:
    """Fitting data in normalised frequency: ``x = j f / reference_hz``, response `H`, weights `w`."""

    x: np.ndarray
    H: np.ndarray
    w: np.ndarray
    n_num: int
    n_den: int

    def d_of(self, poles: np.ndarray) -> np.ndarray:
        """The monic denominator with roots `poles`, evaluated at every ``x``."""
        return np.prod(self.x[:, None] - poles[None, :], axis=1)

    def cost_of(self, poles: np.ndarray) -> tuple[float, np.ndarray]:
        """Weighted mean squared error with the best numerator for these poles, and that numerator."""
        Dx = self.d_of(poles)
        num = _numerator_for(self.x, self.H, self.w, Dx, self.n_num)
        r = self.w * (self.H - np.polyval(num, self.x) / Dx)
        return float(np.mean(np.abs(r) ** 2)), num


def _fit_normalised(x, H, w, n_num, n_den, iterations, tol, refine, max_nfev):
    """Levy, SK and LM on normalised data.

    Returns ``(num_x, poles_x, sk_iterations, reflections)`` with the numerator
    highest power first and the poles of the monic denominator.
    """
    data = _Normalised(x, H, w, n_num, n_den)
    if n_den == 0:
        none = np.array([], dtype=np.complex128)
        return data.cost_of(none)[1], none, 0, 0
    best, first, last, its, reflected = _levy_sk(data, iterations, tol)
    if not refine:
        return best[1], best[2], its, reflected
    # Started from the best, the last and the Levy iterate: when the order is
    # higher than the data support, they can lie in different basins.
    starts = [best]
    for cand in (last, first):
        if not any(np.array_equal(cand[2], s_[2]) for s_ in starts):
            starts.append(cand)
    best = _levenberg_marquardt(data, starts, best, max_nfev)
    return best[1], best[2], its, reflected


def _levy_sk(data: _Normalised, iterations: int, tol: float):
    """Levy start and Sanathanan-Koerner iterations.

    Returns ``(best, first, last, iterations_run, reflections)``; each of the
    first three is ``(cost, numerator, poles)``.
    """
    x, H, w, n_den = data.x, data.H, data.w, data.n_den
    # H (x^n + a_{n-1} x^{n-1} + ... + a0) - N(x) = 0.
    A = np.hstack([H[:, None] * x[:, None] ** np.arange(n_den), -(x[:, None] ** np.arange(data.n_num + 1))])
    b = -H * x**n_den
    sk = np.ones(x.size)
    best = first = last = None
    den_prev = None
    its = reflected = 0
    for its in range(iterations + 1):  # noqa: B007 - its is returned: the iterations run
        ww = w * sk
        theta = _lstsq_complex(ww[:, None] * A, ww * b)
        den = np.r_[1.0, theta[:n_den][::-1]]
        if not np.all(np.isfinite(den)):
            break
        poles, n_bad = _reflect(np.roots(den))
        reflected += n_bad
        c, num = data.cost_of(poles)
        last = (c, num, poles)
        first = first or last
        if best is None or c < best[0]:
            best = last
        Dx = data.d_of(poles)
        if np.any(Dx == 0.0):
            break
        sk = 1.0 / np.abs(Dx)
        den = np.real(np.poly(poles))
        if den_prev is not None and np.max(np.abs(den - den_prev) / (1.0 + np.abs(den))) < tol:
            break
        den_prev = den
    if best is None:
        raise DataError("the Levy start failed (non-finite denominator); check the data for NaN/Inf")
    return best, first, last, its, reflected


def _projected_problem(data: _Normalised):
    """Residual and Jacobian of the variable-projection problem, as one memoised function of theta.

    Levenberg-Marquardt runs over stable factors; the numerator is the linear
    least-squares optimum for each denominator (variable projection) and the
    Jacobian is Kaufman's: ``J_j = P_perp (dD/dtheta_j / D) (w N / D)``, with
    ``P_perp`` the projection off the numerator's column space.
    """
    x, w, n_den = data.x, data.w, data.n_den
    Xn = x[:, None] ** np.arange(data.n_num + 1)
    yr = np.concatenate([(w * data.H).real, (w * data.H).imag])
    memo: dict[bytes, tuple] = {}

    def evaluate(theta):
        key = theta.tobytes()
        if key not in memo:
            memo.clear()
            quads, c = _factors(theta, n_den)
            factors = [x**2 + a1 * x + a0 for a1, a0 in quads]
            dlog = []  # dD/dtheta_j / D
            for (a1, a0), q in zip(quads, factors, strict=True):
                dlog += [a1 * x / q, a0 / q]
            if c is not None:
                factors.append(x + c)
                dlog.append(c / factors[-1])
            Dx = np.prod(factors, axis=0)
            Ar = (w / Dx)[:, None] * Xn
            Ar = np.vstack([Ar.real, Ar.imag])
            Q, _ = np.linalg.qr(Ar / np.maximum(np.linalg.norm(Ar, axis=0), np.finfo(float).tiny))
            r = yr - Q @ (Q.T @ yr)
            model = yr - r  # w N / D, real-stacked
            G = np.array(dlog).T * (model[: x.size] + 1j * model[x.size :])[:, None]
            Gr = np.vstack([G.real, G.imag])
            memo[key] = (r, Gr - Q @ (Q.T @ Gr))
        return memo[key]

    return evaluate


def _levenberg_marquardt(data: _Normalised, starts, best, max_nfev):
    """The best of `best` and a Levenberg-Marquardt refinement from each start's poles."""
    evaluate = _projected_problem(data)
    for _, _, poles0 in starts:
        try:
            theta0 = _params_from_poles(poles0, data.n_den)
        except DataError:
            continue
        res = optimize.least_squares(
            lambda t: evaluate(t)[0],
            theta0,
            jac=lambda t: evaluate(t)[1],
            method="lm",
            max_nfev=max_nfev,
            x_scale="jac",
        )
        poles = _poles_from_params(res.x, data.n_den)
        c, num = data.cost_of(poles)
        if np.isfinite(c) and c <= best[0]:
            best = (c, num, poles)
    return best


def fit_transfer_function(
    frf: FrequencyResponse,
    n_num: int,
    n_den: int,
    weights: str | ArrayLike | None = None,
    delay_s: float = 0.0,
    integrators: int = 0,
    iterations: int = 30,
    refine: bool = True,
    reference_hz: float | None = None,
    band_hz: tuple[float, float] | None = None,
    tol: float = 1e-8,
    max_nfev: int | None = None,
) -> TfFit:
    """Fit ``G^(s) = N(s) / (s^integrators D(s)) exp(-s delay_s)`` to a measured FRF.

    Levy start, Sanathanan-Koerner iterations, then Levenberg-Marquardt on
    the complex error (see the module docstring). Every pole of the result
    (except the fixed integrators) lies in the open left half plane.

    Parameters
    ----------
    frf : FrequencyResponse
        Measured response; bins at ``f <= 0`` or with non-finite response are
        skipped.
    n_num, n_den : int
        Degrees of ``N`` and ``D`` (``n_den`` counts only the free poles).
    weights : None, "coherence" or array_like
        None: the lecture's unweighted cost. ``"coherence"``: inverse
        standard deviation ``sqrt(n coh / (1 - coh)) / |G|``. Array: one
        non-negative weight per bin of `frf`.
    delay_s : float
        Known pure delay, s (>= 0).
    integrators : int
        Poles fixed at ``s = 0``.
    iterations : int
        Most Sanathanan-Koerner iterations after the Levy start.
    refine : bool
        Run the Levenberg-Marquardt stage.
    reference_hz : float, optional
        Frequency normalising ``s``; default the geometric mean of the band.
    band_hz : (float, float), optional
        Fit only ``f_lo <= f <= f_hi`` (Hz).
    tol : float
        Relative change of the denominator coefficients that ends the
        Sanathanan-Koerner iterations.
    max_nfev : int, optional
        Most residual evaluations per Levenberg-Marquardt start; default
        ``50 (n_den + 1)``.

    Returns
    -------
    TfFit

    Raises
    ------
    ConfigError
        Orders, weights, delay or band out of range.
    DataError
        Too few usable bins for the number of parameters, or NaN coherence
        with ``weights="coherence"``.
    """
    n_num = check_order("n_num", n_num, 0)
    n_den = check_order("n_den", n_den, 0)
    integrators = check_order("integrators", integrators, 0)
    iterations = check_order("iterations", iterations, 0)
    delay_s = float(delay_s)
    if not (np.isfinite(delay_s) and delay_s >= 0.0):
        raise ConfigError("delay_s", f"must be a finite number >= 0 s, got {delay_s!r}")

    w_all, weighting = frf_weights(frf, frf.response, weights)
    f, H = frf.frequency_hz, frf.response
    keep = (f > 0.0) & np.isfinite(H) & (w_all > 0.0)
    if band_hz is not None:
        f_lo, f_hi = band_hz
        if not 0.0 <= f_lo < f_hi:
            raise ConfigError("band_hz", f"must be (f_lo, f_hi) with 0 <= f_lo < f_hi, got {band_hz!r}")
        keep &= (f >= f_lo) & (f <= f_hi)
    f, H, w = f[keep], H[keep], w_all[keep]
    n_params = n_num + 1 + n_den
    if 2 * f.size < n_params + 1:
        raise DataError(
            f"{f.size} usable bins give {2 * f.size} real equations, too few for "
            f"n_num={n_num}, n_den={n_den} ({n_params} parameters)"
        )
    if reference_hz is None:
        ref = float(np.sqrt(f.min() * f.max()))
    else:
        ref = float(reference_hz)
        if not (np.isfinite(ref) and ref > 0.0):
            raise ConfigError("reference_hz", f"must be a positive frequency in Hz, got {reference_hz!r}")

    # Fit s^k G e^{s tau} with weights w / |x|^k: the same error in G.
    x = 1j * f / ref
    Hk = H * x**integrators * np.exp(1j * TWO_PI * f * delay_s)
    wk = w / np.abs(x) ** integrators
    scale = float(np.sqrt(np.mean(np.abs(wk * Hk) ** 2)))
    if not scale > 0.0:
        raise DataError("the response is zero at every weighted bin")
    wk = wk / scale
    if max_nfev is None:
        max_nfev = 50 * (n_den + 1)
    num_x, poles_x, sk_its, reflected = _fit_normalised(x, Hk, wk, n_num, n_den, iterations, tol, refine, max_nfev)

    # Normalised zpk -> s domain.
    w_ref = TWO_PI * ref
    lead = np.flatnonzero(num_x != 0.0)
    num_x = num_x[lead[0] :] if lead.size else np.array([0.0])
    zeros_x = np.roots(num_x) if num_x.size > 1 else np.array([], dtype=np.complex128)
    poles_x, n_bad = _reflect(poles_x)
    reflected += n_bad
    k_x = float(num_x[0])
    zeros = zeros_x.astype(np.complex128) * w_ref
    poles = np.r_[poles_x.astype(np.complex128) * w_ref, np.zeros(integrators, dtype=np.complex128)]
    gain = k_x * w_ref ** (poles_x.size + integrators - zeros_x.size)
    num = gain * np.real(np.poly(zeros)) if zeros.size else np.array([gain])
    den = np.real(np.poly(poles)) if poles.size else np.array([1.0])

    Hhat = zpk_response(f, gain, zeros, poles, ref, delay_s)
    err = H - Hhat
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = Hhat / H
    return TfFit(
        num=num,
        den=den,
        poles=poles,
        zeros=zeros,
        gain=gain,
        n_num=n_num,
        n_den=n_den,
        integrators=integrators,
        delay_s=delay_s,
        cost=float(np.mean(np.abs(err) ** 2)),
        weighted_cost=float(np.mean(np.abs(w * err) ** 2)),
        fit_db_rms=float(np.sqrt(np.mean((20.0 * np.log10(np.abs(ratio))) ** 2))),
        phase_rms_deg=float(np.degrees(np.sqrt(np.mean(np.angle(ratio) ** 2)))),
        reflected_poles=reflected,
        stable=bool(np.all(poles_x.real < 0.0)),
        sk_iterations=sk_its,
        reference_hz=ref,
        band_hz=(float(f.min()), float(f.max())),
        n_bins=int(f.size),
        weighting=weighting,
    )
