"""Continuous-time transfer functions fitted to a measured frequency response.

The lecture ("Frequency Response Model", Q3) fits ``G^(s) = N(s) / D(s)`` to
a measured Bode plot by minimising::

    C = 1/(n+1) sum_i |G(j w_i) - G^(j w_i)|^2

:func:`fit_transfer_function` does this in three stages:

1. **Levy**: multiplying out the denominator, ``G D - N = 0`` is linear in the
   coefficients and is solved by least squares. It over-weights the bins
   where ``|D|`` is large (high frequencies, poles far away).
2. **Sanathanan-Koerner**: the Levy problem re-solved with each bin divided by
   ``|D(j w)|`` of the previous iterate, so that at convergence the error
   minimised is the error in ``G`` itself. Unstable poles of an iterate are
   reflected into the left half plane (``p -> -conj(p)``, same ``|D(j w)|``)
   before it is used again.
3. **Levenberg-Marquardt** (``scipy.optimize.least_squares``) on the true
   complex error. The denominator is a product of quadratics
   ``x^2 + a1 x + a0`` (and one ``x + c`` for odd order) with ``a1, a0, c``
   stored as logarithms, so every iterate is stable; the numerator is
   optimal for each denominator (linear least squares, "variable
   projection").

``s`` is normalised by a reference frequency (default the geometric mean of
the band), ``x = s / (2 pi reference_hz)``, and the weighted response by its rms, so
that polynomial coefficients stay near 1 and high orders stay well
conditioned.

Weights
-------
``weights=None`` minimises the lecture's ``C`` as written (absolute error:
bins where ``|G|`` is large dominate). ``weights="coherence"`` weights every
bin by the inverse standard deviation of an averaged estimate implied by its
coherence ``coh`` (thesis eq. 2.46) over ``n = frf.n_averages`` averages::

    w = sqrt(n coh / (1 - coh)) / |G|

since ``E|G^ - G|^2 ~ |G|^2 (1 - coh) / (n coh)`` for H1. This is maximum
likelihood for Gaussian errors, fits low- and high-gain regions alike
(relative error), and makes ``weighted_cost`` about 1 when the model explains
the data to within its noise. An array gives the weights directly (inverse
standard deviation per bin).

Rigid-body modes and delay
--------------------------
``integrators=k`` fixes ``k`` poles at ``s = 0`` (a velocity response of a
free axis has one): ``s^k G`` is fitted with weights ``w / |s|^k``, which is
the same error in ``G``. ``delay_s`` is a known pure delay
``exp(-s delay_s)``, removed from the data before fitting and put back by
:meth:`TfFit.response`; it is not part of ``num`` / ``den``.

Example
-------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.frequency import FrequencyResponse
>>> from hilident.ident.tffit import fit_transfer_function, modal_form
>>> w0, zeta = 2 * np.pi * 50.0, 0.02
>>> f = np.geomspace(5.0, 500.0, 200)
>>> h = signal.freqs([w0**2], [1.0, 2 * zeta * w0, w0**2], 2 * np.pi * f)[1]
>>> fit = fit_transfer_function(FrequencyResponse(f, h, np.ones(f.size), 10, "h1"), 0, 2)
>>> ((f_hz, z),) = modal_form(fit).resonances
>>> print(f"{f_hz:.3f} Hz, zeta {z:.4f}, gain {modal_form(fit).gain:.4f}")
50.000 Hz, zeta 0.0200, gain 1.0000
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse

__all__ = [
    "TfFit",
    "ModalModel",
    "TfOrderCandidate",
    "fit_transfer_function",
    "modal_form",
    "select_order",
    "select_structure",
    "RootReport",
    "classify_roots",
]

_TWO_PI = 2.0 * np.pi
# Poles with |Im p| below this fraction of |p| count as real.
_REAL_TOL = 1e-9
_CRITERIA = ("threshold", "aic", "bic")
# Bound on the log-coefficients of the stable factors (normalised s): keeps
# a pole that drifts off towards 0 or infinity from overflowing.
_LOG_LIMIT = 40.0


# --- results ------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TfFit:
    """A continuous-time transfer function fitted to a frequency response.

    ``G^(s) = gain * prod(s - zeros) / prod(s - poles) * exp(-s delay_s)``.

    Attributes
    ----------
    num, den : ndarray
        Polynomials in ``s`` (rad/s), highest power first (scipy order), for
        ``scipy.signal.freqs`` / ``lti``. ``den`` includes the integrators;
        neither includes the delay. At high order the coefficients span many
        decades: prefer :meth:`response`, ``poles``/``zeros`` or
        :func:`modal_form`.
    poles, zeros : ndarray of complex
        rad/s; ``poles`` includes ``integrators`` poles at exactly 0.
    gain : float
        ``k`` of the zero-pole-gain form (scipy convention).
    n_num, n_den, integrators : int
        Fitted numerator and denominator degrees (``den`` has degree
        ``n_den + integrators``) and fixed poles at 0.
    delay_s : float
        Pure delay, s.
    cost : float
        The lecture's ``C = 1/(n+1) sum |G - G^|^2`` over the fitted bins
        (units of ``G`` squared), whatever the weighting.
    weighted_cost : float
        ``mean |w (G - G^)|^2``, the quantity minimised (equal to `cost` for
        ``weights=None``; about 1 for a good fit with coherence weights).
    fit_db_rms : float
        rms over the fitted bins of ``20 log10 |G^ / G|``, dB.
    phase_rms_deg : float
        rms of the phase error ``angle(G^ / G)``, degrees.
    reflected_poles : int
        Unstable poles reflected into the left half plane on the way (over
        all iterations); 0 when no iterate was unstable.
    stable : bool
        All poles except the integrators have negative real part.
    sk_iterations : int
        Sanathanan-Koerner iterations run after the Levy start.
    reference_hz : float
        Frequency that normalised ``s``, Hz.
    band_hz : (float, float)
        Lowest and highest fitted frequency, Hz.
    n_bins : int
        Bins fitted (non-zero weight, finite response, ``f > 0``, in the band).
    weighting : str
        ``"none"``, ``"coherence"`` or ``"array"``.
    """

    num: np.ndarray
    den: np.ndarray
    poles: np.ndarray
    zeros: np.ndarray
    gain: float
    n_num: int
    n_den: int
    integrators: int
    delay_s: float
    cost: float
    weighted_cost: float
    fit_db_rms: float
    phase_rms_deg: float
    reflected_poles: int
    stable: bool
    sk_iterations: int
    reference_hz: float
    band_hz: tuple[float, float]
    n_bins: int
    weighting: str

    @property
    def n_params(self) -> int:
        """Free real parameters: ``n_num + 1`` numerator, ``n_den`` denominator."""
        return self.n_num + 1 + self.n_den

    def response(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Complex response ``G^(j 2 pi f)`` at `frequency_hz` (Hz).

        Evaluated from poles and zeros in normalised frequency, so it stays
        accurate where the ``num``/``den`` coefficients would not.
        """
        return _zpk_response(
            frequency_hz, self.gain, self.zeros, self.poles, self.reference_hz, self.delay_s
        )


@dataclass(frozen=True, eq=False)
class ModalModel:
    """A transfer function as a product of the lecture's building blocks.

    ::

        G(s) = gain / s^integrators * exp(-s delay_s)
               * prod_anti (s^2/w^2 + 2 zeta s/w + 1)  * prod_zero (1 + s/w_z)
               / prod_res  (s^2/w^2 + 2 zeta s/w + 1)  / prod_pole (1 + s/w_p)

    with ``w = 2 pi frequency_hz``. Each factor is 1 at ``s = 0``, so `gain` is
    the DC gain (for ``integrators=0``). A negative ``zeta`` or corner
    frequency is a factor with its roots in the right half plane.

    Attributes
    ----------
    gain : float
        DC gain of everything but the integrators (units of ``G`` times s^integrators).
    resonances : tuple of (float, float)
        ``(frequency_hz, damping_ratio)`` of the quadratic denominator factors,
        sorted by frequency.
    antiresonances : tuple of (float, float)
        The same for the numerator.
    real_poles_hz, real_zeros_hz : tuple of float
        Corner frequencies ``w / 2 pi`` of first-order factors ``1 + s/w``, Hz.
    integrators : int
        Poles at ``s = 0``.
    delay_s : float
        Pure delay, s.

    Example
    -------
    The lecture's piezo actuator up to 8000 rad/s (frequencies given in rad/s):

    >>> import numpy as np
    >>> hz = lambda w: w / (2 * np.pi)
    >>> piezo = ModalModel(0.673,
    ...     resonances=[(hz(2450), 0.1), (hz(4860), 0.05), (hz(4860), 0.7), (hz(4860), 0.8)],
    ...     antiresonances=[(hz(2875), 0.01)])
    >>> print(f"{20 * np.log10(abs(piezo.response(0.0))):.2f} dB")
    -3.44 dB
    """

    gain: float
    resonances: Sequence[tuple[float, float]] = ()
    antiresonances: Sequence[tuple[float, float]] = ()
    real_poles_hz: Sequence[float] = ()
    real_zeros_hz: Sequence[float] = ()
    integrators: int = 0
    delay_s: float = 0.0

    def __post_init__(self):
        gain = float(self.gain)
        if not np.isfinite(gain):
            raise ConfigError("gain", f"must be a finite number, got {self.gain!r}")
        object.__setattr__(self, "gain", gain)
        for key in ("resonances", "antiresonances"):
            pairs = []
            for item in getattr(self, key):
                try:
                    f_hz, zeta = (float(v) for v in item)
                except (TypeError, ValueError):
                    raise ConfigError(
                        key, f"entries must be (frequency_hz, damping_ratio), got {item!r}"
                    ) from None
                if not (np.isfinite(f_hz) and f_hz > 0.0 and np.isfinite(zeta)):
                    raise ConfigError(
                        key, f"needs frequency_hz > 0 and a finite damping ratio, got {item!r}"
                    )
                pairs.append((f_hz, zeta))
            object.__setattr__(self, key, tuple(sorted(pairs)))
        for key in ("real_poles_hz", "real_zeros_hz"):
            corners = tuple(sorted(float(v) for v in getattr(self, key)))
            if not all(np.isfinite(c) and c != 0.0 for c in corners):
                raise ConfigError(
                    key, f"corner frequencies must be finite and non-zero, got {corners!r}"
                )
            object.__setattr__(self, key, corners)
        if int(self.integrators) != self.integrators or self.integrators < 0:
            raise ConfigError("integrators", f"must be an integer >= 0, got {self.integrators!r}")
        object.__setattr__(self, "integrators", int(self.integrators))
        object.__setattr__(self, "delay_s", float(self.delay_s))

    def response(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Complex response at `frequency_hz` (Hz)."""
        f = np.asarray(frequency_hz, dtype=np.float64)
        h = np.full(f.shape, self.gain, dtype=np.complex128)
        for f0, z in self.antiresonances:
            r = f / f0
            h *= 1.0 - r**2 + 2j * z * r
        for f0, z in self.resonances:
            r = f / f0
            h /= 1.0 - r**2 + 2j * z * r
        for fc in self.real_zeros_hz:
            h *= 1.0 + 1j * f / fc
        for fc in self.real_poles_hz:
            h /= 1.0 + 1j * f / fc
        with np.errstate(divide="ignore", invalid="ignore"):
            h /= (1j * _TWO_PI * f) ** self.integrators
        return h * np.exp(-1j * _TWO_PI * f * self.delay_s)

    def poles(self) -> np.ndarray:
        """Poles, rad/s (integrators as zeros of ``s``)."""
        return _roots_of(self.resonances, self.real_poles_hz, self.integrators)

    def zeros(self) -> np.ndarray:
        """Zeros, rad/s."""
        return _roots_of(self.antiresonances, self.real_zeros_hz, 0)

    def to_tf(self) -> tuple[np.ndarray, np.ndarray]:
        """``(num, den)`` in ``s``, highest power first; the delay is left out."""
        num = np.array([self.gain])
        den = np.array([1.0])
        for f0, z in self.antiresonances:
            w = _TWO_PI * f0
            num = np.polymul(num, [1.0 / w**2, 2.0 * z / w, 1.0])
        for f0, z in self.resonances:
            w = _TWO_PI * f0
            den = np.polymul(den, [1.0 / w**2, 2.0 * z / w, 1.0])
        for fc in self.real_zeros_hz:
            num = np.polymul(num, [1.0 / (_TWO_PI * fc), 1.0])
        for fc in self.real_poles_hz:
            den = np.polymul(den, [1.0 / (_TWO_PI * fc), 1.0])
        den = np.polymul(den, np.r_[1.0, np.zeros(self.integrators)])
        return num, den


def _roots_of(quadratics, corners_hz, n_zero) -> np.ndarray:
    roots = []
    for f0, z in quadratics:
        w = _TWO_PI * f0
        roots.extend(np.roots([1.0, 2.0 * z * w, w * w]).astype(np.complex128))
    roots.extend(-_TWO_PI * np.asarray(corners_hz, dtype=np.float64) + 0j)
    roots.extend([0j] * n_zero)
    return np.array(roots, dtype=np.complex128)


@dataclass(frozen=True, eq=False)
class TfOrderCandidate:
    """One row of :func:`select_order`.

    Attributes
    ----------
    n_num, n_den : int
        Orders tried.
    fit : TfFit or None
        The fit (None when it could not be made, see `error`).
    aic, bic : float
        ``N ln(V / N) + 2 p`` and ``N ln(V / N) + p ln N`` with ``N = 2 * bins``
        real residuals, ``V`` their weighted sum of squares, ``p`` parameters.
    selected : bool
        The chosen order.
    error : str
        Why the fit failed ("" when it did not).
    integrators : int
        Poles fixed at ``s = 0`` (:func:`select_structure`).
    validation : float
        Weighted cost on the held-out lines (:func:`select_structure` with
        ``criterion="validation"``), else NaN.
    """

    n_num: int
    n_den: int
    fit: TfFit | None
    aic: float
    bic: float
    selected: bool = False
    error: str = ""
    integrators: int = 0
    validation: float = float("nan")

    @property
    def n_params(self) -> int:
        return self.n_num + 1 + self.n_den


# --- internals ----------------------------------------------------------------


def _zpk_response(frequency_hz, gain, zeros, poles, reference_hz, delay_s) -> np.ndarray:
    """``gain prod(s - z) / prod(s - p) exp(-s delay)`` at ``s = j 2 pi f``, in normalised ``s``."""
    f = np.asarray(frequency_hz, dtype=np.float64)
    w_ref = _TWO_PI * reference_hz
    x = 1j * f / reference_hz
    k = gain * w_ref ** (len(zeros) - len(poles))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = k * _zpk_eval(x, np.asarray(zeros) / w_ref, np.asarray(poles) / w_ref)
    return h * np.exp(-1j * _TWO_PI * f * delay_s)


def _zpk_eval(x: np.ndarray, zeros: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """``prod(x - z) / prod(x - p)``, factors interleaved to stay in range."""
    h = np.ones(np.shape(x), dtype=np.complex128)
    nz, npl = len(zeros), len(poles)
    for i in range(max(nz, npl)):
        if i < nz:
            h = h * (x - zeros[i])
        if i < npl:
            h = h / (x - poles[i])
    return h


def _check_order(key: str, value, low: int) -> int:
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


def _weights(frf: FrequencyResponse, H: np.ndarray, weights) -> tuple[np.ndarray, str]:
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
    is_real = np.abs(poles.imag) <= _REAL_TOL * np.abs(poles)
    quads = [(-2.0 * p.real, abs(p) ** 2) for p in poles[~is_real & (poles.imag > 0.0)]]
    # Pair the real poles neighbour by neighbour; an odd one out is the linear factor.
    real = np.sort(poles[is_real].real)
    lin = None
    if real.size % 2:
        lin, real = real[-1], real[:-1]
    quads += [(-(a + b), a * b) for a, b in zip(real[0::2], real[1::2])]
    theta = []
    for a1, a0 in quads:
        theta += [np.log(max(a1, tiny)), np.log(max(a0, tiny))]
    if lin is not None:
        theta.append(np.log(max(-lin, tiny)))
    if len(theta) != n_den:  # complex roots without their conjugate
        raise DataError(f"could not factor {n_den} poles into real stable sections")
    return np.array(theta)


def _fit_normalised(x, H, w, n_num, n_den, iterations, tol, refine, max_nfev):
    """Levy, SK and LM on normalised data.

    Returns ``(num_x, poles_x, sk_iterations, reflections)`` with the numerator
    highest power first and the poles of the monic denominator.
    """
    reflected = 0
    Xn = x[:, None] ** np.arange(n_num + 1)

    def d_of(poles):
        return np.prod(x[:, None] - poles[None, :], axis=1)

    def cost_of(poles):
        Dx = d_of(poles)
        num = _numerator_for(x, H, w, Dx, n_num)
        r = w * (H - np.polyval(num, x) / Dx)
        return float(np.mean(np.abs(r) ** 2)), num

    if n_den == 0:
        none = np.array([], dtype=np.complex128)
        return cost_of(none)[1], none, 0, 0

    # Levy + Sanathanan-Koerner: H (x^n + a_{n-1} x^{n-1} + ... + a0) - N(x) = 0.
    A = np.hstack([H[:, None] * x[:, None] ** np.arange(n_den), -Xn])
    b = -H * x**n_den
    sk = np.ones(x.size)
    best = first = last = None
    den_prev = None
    its = 0
    for its in range(iterations + 1):
        ww = w * sk
        theta = _lstsq_complex(ww[:, None] * A, ww * b)
        den = np.r_[1.0, theta[:n_den][::-1]]
        if not np.all(np.isfinite(den)):
            break
        poles, n_bad = _reflect(np.roots(den))
        reflected += n_bad
        c, num = cost_of(poles)
        last = (c, num, poles)
        first = first or last
        if best is None or c < best[0]:
            best = last
        Dx = d_of(poles)
        if np.any(Dx == 0.0):
            break
        sk = 1.0 / np.abs(Dx)
        den = np.real(np.poly(poles))
        if den_prev is not None and np.max(np.abs(den - den_prev) / (1.0 + np.abs(den))) < tol:
            break
        den_prev = den
    if best is None:
        raise DataError(
            "the Levy start failed (non-finite denominator); check the data for NaN/Inf"
        )
    if not refine:
        return best[1], best[2], its, reflected

    # Levenberg-Marquardt over stable factors; the numerator is the linear
    # least-squares optimum for each denominator (variable projection) and the
    # Jacobian is Kaufman's: J_j = P_perp (dD/dtheta_j / D) (w N / D), with
    # P_perp the projection off the numerator's column space.
    yr = np.concatenate([(w * H).real, (w * H).imag])
    memo = {}

    def evaluate(theta):
        key = theta.tobytes()
        if key not in memo:
            memo.clear()
            quads, c = _factors(theta, n_den)
            factors = [x**2 + a1 * x + a0 for a1, a0 in quads]
            dlog = []  # dD/dtheta_j / D
            for (a1, a0), q in zip(quads, factors):
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
            G = np.array(dlog).T * (model[: x.size] + 1j * model[x.size:])[:, None]
            Gr = np.vstack([G.real, G.imag])
            memo[key] = (r, Gr - Q @ (Q.T @ Gr))
        return memo[key]

    # Started from the best, the last and the Levy iterate: when the order is
    # higher than the data support, they can lie in different basins.
    starts = [best]
    for cand in (last, first):
        if not any(np.array_equal(cand[2], s_[2]) for s_ in starts):
            starts.append(cand)
    for _, _, poles0 in starts:
        try:
            theta0 = _params_from_poles(poles0, n_den)
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
        poles = _poles_from_params(res.x, n_den)
        c, num = cost_of(poles)
        if np.isfinite(c) and c <= best[0]:
            best = (c, num, poles)
    return best[1], best[2], its, reflected


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
    n_num = _check_order("n_num", n_num, 0)
    n_den = _check_order("n_den", n_den, 0)
    integrators = _check_order("integrators", integrators, 0)
    iterations = _check_order("iterations", iterations, 0)
    delay_s = float(delay_s)
    if not (np.isfinite(delay_s) and delay_s >= 0.0):
        raise ConfigError("delay_s", f"must be a finite number >= 0 s, got {delay_s!r}")

    w_all, weighting = _weights(frf, frf.response, weights)
    f, H = frf.frequency_hz, frf.response
    keep = (f > 0.0) & np.isfinite(H) & (w_all > 0.0)
    if band_hz is not None:
        f_lo, f_hi = band_hz
        if not 0.0 <= f_lo < f_hi:
            raise ConfigError(
                "band_hz", f"must be (f_lo, f_hi) with 0 <= f_lo < f_hi, got {band_hz!r}"
            )
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
            raise ConfigError(
                "reference_hz", f"must be a positive frequency in Hz, got {reference_hz!r}"
            )

    # Fit s^k G e^{s tau} with weights w / |x|^k: the same error in G.
    x = 1j * f / ref
    Hk = H * x**integrators * np.exp(1j * _TWO_PI * f * delay_s)
    wk = w / np.abs(x) ** integrators
    scale = float(np.sqrt(np.mean(np.abs(wk * Hk) ** 2)))
    if not scale > 0.0:
        raise DataError("the response is zero at every weighted bin")
    wk = wk / scale
    if max_nfev is None:
        max_nfev = 50 * (n_den + 1)
    num_x, poles_x, sk_its, reflected = _fit_normalised(
        x, Hk, wk, n_num, n_den, iterations, tol, refine, max_nfev
    )

    # Normalised zpk -> s domain.
    w_ref = _TWO_PI * ref
    lead = np.flatnonzero(num_x != 0.0)
    num_x = num_x[lead[0]:] if lead.size else np.array([0.0])
    zeros_x = np.roots(num_x) if num_x.size > 1 else np.array([], dtype=np.complex128)
    poles_x, n_bad = _reflect(poles_x)
    reflected += n_bad
    k_x = float(num_x[0])
    zeros = zeros_x.astype(np.complex128) * w_ref
    poles = np.r_[poles_x.astype(np.complex128) * w_ref, np.zeros(integrators, dtype=np.complex128)]
    gain = k_x * w_ref ** (poles_x.size + integrators - zeros_x.size)
    num = gain * np.real(np.poly(zeros)) if zeros.size else np.array([gain])
    den = np.real(np.poly(poles)) if poles.size else np.array([1.0])

    Hhat = _zpk_response(f, gain, zeros, poles, ref, delay_s)
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


# --- modal form ---------------------------------------------------------------


def _factor(roots: np.ndarray) -> tuple[list[tuple[float, float]], list[float]]:
    """Quadratic factors ``(frequency_hz, zeta)`` and real corners (Hz) of `roots` (rad/s)."""
    quads, corners = [], []
    for r in roots:
        if abs(r.imag) > _REAL_TOL * abs(r):
            if r.imag > 0.0:
                w = abs(r)
                quads.append((w / _TWO_PI, -r.real / w))
        else:
            corners.append(-r.real / _TWO_PI)
    return quads, corners


def modal_form(fit: TfFit) -> ModalModel:
    """Factor a fitted transfer function like the lecture's piezo model.

    Complex pole pairs become resonances ``(frequency_hz, zeta)`` with
    ``frequency_hz = |p| / 2 pi`` and ``zeta = -Re p / |p|``; complex zero
    pairs become anti-resonances; real poles and zeros become first-order
    factors with corner ``-p / 2 pi``. The gain is the DC gain of what remains
    after the integrators, ``gain * prod(-z) / prod(-p)`` over the non-zero roots.

    Parameters
    ----------
    fit : TfFit

    Returns
    -------
    ModalModel
        Same response as ``fit.response`` (up to rounding).

    Raises
    ------
    DataError
        A fitted zero lies exactly at ``s = 0`` (a differentiator), which the
        modal form has no factor for.
    """
    zeros = np.asarray(fit.zeros)
    poles = np.asarray(fit.poles)[: len(fit.poles) - fit.integrators]
    if np.any(zeros == 0.0):
        raise DataError("the fit has a zero at s = 0; the modal form has no differentiator factor")
    dc = fit.gain * np.prod(-zeros) / np.prod(-poles)
    res, real_p = _factor(poles)
    anti, real_z = _factor(zeros)
    return ModalModel(
        gain=float(np.real(dc)),
        resonances=res,
        antiresonances=anti,
        real_poles_hz=real_p,
        real_zeros_hz=real_z,
        integrators=fit.integrators,
        delay_s=fit.delay_s,
    )


# --- order selection ----------------------------------------------------------


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
        raise ConfigError(
            "orders", "give exactly one of orders=[(n_num, n_den), ...] and max_order"
        )
    if orders is None:
        max_order = _check_order("max_order", max_order, 1)
        if relative_degree is None:
            orders = [(m, n) for n in range(1, max_order + 1) for m in range(n + 1)]
        else:
            rd = _check_order("relative_degree", relative_degree, 0)
            orders = [(n - rd, n) for n in range(max(1, rd), max_order + 1)]
        if not orders:
            raise ConfigError(
                "max_order", f"{max_order} leaves no order with relative_degree={relative_degree}"
            )
    else:
        checked = []
        for item in orders:
            try:
                m, n = item
            except (TypeError, ValueError):
                raise ConfigError(
                    "orders", f"entries must be (n_num, n_den), got {item!r}"
                ) from None
            checked.append((_check_order("orders.n_num", m, 0), _check_order("orders.n_den", n, 0)))
        if not checked:
            raise ConfigError("orders", "must not be empty")
        orders = list(dict.fromkeys(checked))
    orders = sorted(orders, key=lambda mn: (mn[0] + 1 + mn[1], mn[1], mn[0]))

    rows = []
    for m, n in orders:
        try:
            fit = fit_transfer_function(frf, m, n, **fit_options)
        except DataError as exc:
            rows.append(TfOrderCandidate(m, n, None, np.inf, np.inf, error=str(exc)))
            continue
        N = 2 * fit.n_bins
        v = max(fit.weighted_cost * N / 2.0, np.finfo(float).tiny)  # sum of squares
        p = fit.n_params
        rows.append(
            TfOrderCandidate(
                m, n, fit, N * np.log(v / N) + 2 * p, N * np.log(v / N) + p * np.log(N)
            )
        )
    ok = [r for r in rows if r.fit is not None and r.fit.stable]
    if not ok:
        why = "; ".join(r.error for r in rows if r.error)
        raise DataError(f"no candidate order gave a stable fit: {why}")

    if criterion == "threshold":
        # Tiny absolute slack so that noise-free data (costs near rounding) does not
        # force the largest model.
        slack = 1e-12 * max(r.fit.weighted_cost for r in ok)
        chosen = ok[-1]
        for i, r in enumerate(ok):
            larger = [q for q in ok[i + 1:] if q.n_params > r.n_params]
            limit = [(1.0 + threshold) * q.fit.weighted_cost + slack for q in larger]
            if all(r.fit.weighted_cost <= lim for lim in limit):
                chosen = r
                break
    else:
        chosen = min(ok, key=lambda r: (getattr(r, criterion), r.n_params))
    table = [
        TfOrderCandidate(r.n_num, r.n_den, r.fit, r.aic, r.bic, r is chosen, r.error) for r in rows
    ]
    return chosen.fit, table



# --- structure selection ------------------------------------------------------

_STRUCTURE_CRITERIA = ("mdl", "aic", "validation")
#: Least damping ratio of a pole counted off the imaginary axis (classify_roots' default).
_AXIS_TOL = 1e-6
#: Most lines the screening fits of :func:`select_structure` use.
_SCREEN_BINS = 200


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
    max_order = _check_order("max_order", max_order, 1)
    if order is not None:
        order = _check_order("model_order", order, 1)
    if relative_degree is not None:
        relative_degree = _check_order("model_relative_degree", relative_degree, 0)
    if integrators is not None:
        integrators = _check_order("model_integrators", integrators, 0)
    holdout_every = _check_order("holdout_every", holdout_every, 2)
    cands = _structures(max_order, order, relative_degree, integrators)
    if not cands:
        raise ConfigError(
            "model_relative_degree",
            f"no structure with order {order if order is not None else f'<= {max_order}'}, relative degree "
            f"{relative_degree} and {integrators} integrator(s)",
        )
    w_all, weighting = _weights(frf, frf.response, weights)
    train_w = w_all
    hold = np.zeros(len(frf), dtype=bool)
    if criterion == "validation":
        usable = np.flatnonzero((frf.frequency_hz > 0.0) & np.isfinite(frf.response) & (w_all > 0.0))
        hold[usable[holdout_every // 2::holdout_every]] = True
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
            fit = fit_transfer_function(frf, m, n, weights=train_w if refine else screen_w, integrators=k,
                                        refine=refine, iterations=iterations if refine else min(iterations, 15),
                                        **fit_options)
        except DataError as exc:
            return TfOrderCandidate(m, n, None, np.inf, np.inf, error=str(exc), integrators=k)
        N = 2 * fit.n_bins
        v = max(fit.weighted_cost * N / 2.0, np.finfo(float).tiny)
        p = fit.n_params
        val = float("nan")
        if criterion == "validation":
            e = w_all[hold] * (frf.response[hold] - fit.response(frf.frequency_hz[hold]))
            val = float(np.mean(np.abs(e) ** 2))
        return TfOrderCandidate(m, n, fit, N * np.log(v / N) + 2 * p, N * np.log(v / N) + p * np.log(N),
                                integrators=k, validation=val)

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
        low = _TWO_PI * lo / 10.0
        below = integrators is None and (np.any(np.abs(poles) < low)
                                         or (r.integrators > 0 and np.any(np.abs(zeros) < low)))
        roots = np.r_[poles, zeros]
        # a complex pair outside the band is a resonance or anti-resonance the data do not show
        pair = np.abs(roots.imag) > _REAL_TOL * np.abs(roots)
        outside = (np.abs(roots) < _TWO_PI * lo) | (np.abs(roots) > _TWO_PI * hi)
        # a pole on the imaginary axis (a fit that ran off to an undamped mode)
        undamped = np.any(-poles.real <= _AXIS_TOL * np.abs(poles))
        return bool(below or undamped or np.any(np.abs(roots) > _TWO_PI * hi * 10.0) or np.any(pair & outside))

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
        fit = fit_transfer_function(frf, chosen.n_num, chosen.n_den, weights=w_all,
                                    integrators=chosen.integrators, refine=refine, **fit_options)
    table = [dataclasses.replace(r, selected=r is chosen) for r in rows]
    return dataclasses.replace(fit, weighting=weighting), table


# --- which roots the data support ---------------------------------------------


@dataclass(frozen=True)
class RootReport:
    """The poles and zeros of a fit, sorted into what the data support and what they do not.

    Attributes
    ----------
    modes : list of (float, float)
        ``(frequency_hz, damping_ratio)`` of complex pole pairs inside the
        supported range: the resonances the model claims.
    flagged_poles : list of dict
        Poles that are not reported as modes: ``frequency_hz``,
        ``damping_ratio`` (NaN for a real pole), ``reason``.
    antiresonances : list of (float, float)
        Complex left-half-plane zero pairs inside the supported range.
    rhp_zeros : list of dict
        Right-half-plane zeros: ``frequency_hz`` (``|z| / 2 pi``),
        ``real_part_rad_s``, ``kind`` (``"real"`` or ``"complex pair"``),
        ``explanation`` and, for a real one, ``equivalent_delay_s`` (``1 / z``:
        the delay whose phase lag it has well below ``z``).
    flagged_zeros : list of dict
        Zeros far outside the band, either half plane, and complex zero pairs
        outside it (``frequency_hz``, ``reason``).
    real_poles_hz, real_zeros_hz : list of float
        Corner frequencies of real left-half-plane poles and zeros in range, Hz.
    stable : bool
        Every pole except the integrators lies in the left half plane by more
        than the numerical tolerance.
    stability : str
        ``"stable"``, or why not (``"marginal: ..."``).
    """

    modes: list
    flagged_poles: list
    antiresonances: list
    rhp_zeros: list
    flagged_zeros: list
    real_poles_hz: list
    real_zeros_hz: list
    stable: bool
    stability: str

    def to_dict(self) -> dict:
        return {
            "resonances": [{"frequency_hz": f, "damping_ratio": z} for f, z in self.modes],
            "flagged_poles": list(self.flagged_poles),
            "antiresonances": [{"frequency_hz": f, "damping_ratio": z} for f, z in self.antiresonances],
            "rhp_zeros": list(self.rhp_zeros),
            "flagged_zeros": list(self.flagged_zeros),
            "real_poles_hz": list(self.real_poles_hz),
            "real_zeros_hz": list(self.real_zeros_hz),
            "stable": self.stable,
            "stability": self.stability,
        }


_RHP_EXPLANATION = (
    "right-half-plane (non-minimum-phase) zero: it adds phase lag without a dip in |G|, so it is no "
    "anti-resonance; on a drive it usually stands for a delay (computation, transport, current loop) or for "
    "a sensor that is not collocated with the actuator"
)


def classify_roots(
    fit: TfFit,
    band_hz: tuple[float, float] | None = None,
    axis_tol: float = _AXIS_TOL,
    outside_factor: float = 10.0,
    resolution_hz: float | None = None,
) -> RootReport:
    """Which poles and zeros of a fit the data can support.

    A pole is flagged, not reported as a mode, when

    * its damping ratio is below `axis_tol` (within numerical noise of the
      imaginary axis; the model is then only marginally stable);
    * ``|p| / 2 pi`` lies above ``outside_factor`` times the top of the band
      or below the bottom divided by it (the fit put it there to bend the
      response at the band edge; it is not a mode the data show), or, for a
      complex pair, outside the band at all;
    * with `resolution_hz`, its half-power bandwidth ``2 zeta f`` is under a
      tenth of the line spacing (the measurement cannot resolve it).

    Zeros in the right half plane within reach of the band are listed as
    such with an explanation, never as anti-resonances; zeros far outside the
    band and complex zero pairs outside it are flagged.

    Parameters
    ----------
    fit : TfFit
    band_hz : (float, float), optional
        Band the data cover, Hz; default ``fit.band_hz``.
    axis_tol : float
        Least damping ratio of a pole (or ``|Re z| / |z|`` of a zero) counted
        off the imaginary axis.
    outside_factor : float
        How far outside the band a root may lie and still count (> 1).
    resolution_hz : float, optional
        Line spacing of the measured response, Hz.

    Returns
    -------
    RootReport
    """
    lo, hi = fit.band_hz if band_hz is None else band_hz
    poles = np.asarray(fit.poles)[: len(fit.poles) - fit.integrators]
    modes, flagged, real_p = [], [], []
    marginal = []
    for p in poles:
        if p.imag < -_REAL_TOL * abs(p):
            continue  # the conjugate speaks for the pair
        f_hz = abs(p) / _TWO_PI
        is_complex = p.imag > _REAL_TOL * abs(p)
        zeta = -p.real / abs(p) if abs(p) > 0 else float("nan")
        reason = ""
        if not zeta > axis_tol:
            reason = (f"on the imaginary axis within numerical noise (zeta {zeta:.2g}): an undamped pole the "
                      "data cannot support")
            marginal.append(f_hz)
        elif f_hz > outside_factor * hi or f_hz < lo / outside_factor:
            reason = (f"far outside the fitted band {lo:.4g}-{hi:.4g} Hz: the fit uses it to bend the response "
                      "at the band edge")
        elif is_complex and not lo <= f_hz <= hi:
            reason = f"outside the fitted band {lo:.4g}-{hi:.4g} Hz: the data show at most its skirt"
        elif is_complex and resolution_hz and 2.0 * zeta * f_hz < 0.1 * resolution_hz:
            reason = (f"half-power bandwidth {2 * zeta * f_hz:.3g} Hz is under a tenth of the "
                      f"{resolution_hz:.3g} Hz line spacing: the measurement cannot resolve it")
        if reason:
            flagged.append({"frequency_hz": float(f_hz), "damping_ratio": float(zeta) if is_complex else float("nan"),
                            "real_part_rad_s": float(p.real), "reason": reason})
        elif is_complex:
            modes.append((float(f_hz), float(zeta)))
        else:
            real_p.append(float(f_hz))
    anti, rhp, flagged_z, real_z = [], [], [], []
    for z in np.asarray(fit.zeros):
        if z.imag < -_REAL_TOL * abs(z):
            continue
        f_hz = abs(z) / _TWO_PI
        is_complex = z.imag > _REAL_TOL * abs(z)
        if f_hz > outside_factor * hi or f_hz < lo / outside_factor:
            side = "right" if z.real > axis_tol * abs(z) else "left"
            acts = "a differentiator s" if f_hz < lo else "a constant"
            flagged_z.append({"frequency_hz": float(f_hz), "real_part_rad_s": float(z.real),
                              "reason": f"{side}-half-plane zero far outside the fitted band {lo:.4g}-{hi:.4g} Hz: "
                                        f"in the band it acts as {acts}"})
        elif z.real > axis_tol * abs(z):
            entry = {"frequency_hz": float(f_hz), "real_part_rad_s": float(z.real),
                     "kind": "complex pair" if is_complex else "real", "explanation": _RHP_EXPLANATION}
            if not is_complex:
                # below it, 1 - s/z has the phase of a delay 1/z (and no effect on |G|)
                entry["equivalent_delay_s"] = float(1.0 / z.real)
            rhp.append(entry)
        elif is_complex and not lo <= f_hz <= hi:
            flagged_z.append({"frequency_hz": float(f_hz),
                              "reason": f"outside the fitted band {lo:.4g}-{hi:.4g} Hz: not an anti-resonance the data show"})
        elif is_complex:
            anti.append((float(f_hz), float(-z.real / abs(z))))
        else:
            real_z.append(float(f_hz))
    stable = not marginal and bool(np.all(poles.real < 0.0))
    stability = "stable" if stable else (
        "marginal: pole(s) at " + ", ".join(f"{f:.4g} Hz" for f in marginal) + " lie on the imaginary axis"
        if marginal else "unstable: a pole lies in the right half plane")
    return RootReport(sorted(modes), flagged, sorted(anti), rhp, flagged_z, sorted(real_p), sorted(real_z),
                      stable, stability)
