"""Transfer-function model structures: the fitted zero-pole-gain form, the modal form and its factors.

:class:`TfFit` is what :func:`~hilident.ident.tffit.fit_transfer_function`
returns; :class:`ModalModel` writes a transfer function as the lecture's
building blocks (resonances, anti-resonances, first-order factors,
integrators, delay) and :func:`modal_form` converts the one into the other.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError

__all__ = ["ModalModel", "TfFit", "TfOrderCandidate", "modal_form"]

TWO_PI = 2.0 * np.pi
#: Poles with ``|Im p|`` below this fraction of ``|p|`` count as real.
REAL_TOL = 1e-9


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
        return zpk_response(frequency_hz, self.gain, self.zeros, self.poles, self.reference_hz, self.delay_s)


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

    Examples
    --------
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
                    raise ConfigError(key, f"entries must be (frequency_hz, damping_ratio), got {item!r}") from None
                if not (np.isfinite(f_hz) and f_hz > 0.0 and np.isfinite(zeta)):
                    raise ConfigError(key, f"needs frequency_hz > 0 and a finite damping ratio, got {item!r}")
                pairs.append((f_hz, zeta))
            object.__setattr__(self, key, tuple(sorted(pairs)))
        for key in ("real_poles_hz", "real_zeros_hz"):
            corners = tuple(sorted(float(v) for v in getattr(self, key)))
            if not all(np.isfinite(c) and c != 0.0 for c in corners):
                raise ConfigError(key, f"corner frequencies must be finite and non-zero, got {corners!r}")
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
            h /= (1j * TWO_PI * f) ** self.integrators
        return h * np.exp(-1j * TWO_PI * f * self.delay_s)

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
            w = TWO_PI * f0
            num = np.polymul(num, [1.0 / w**2, 2.0 * z / w, 1.0])
        for f0, z in self.resonances:
            w = TWO_PI * f0
            den = np.polymul(den, [1.0 / w**2, 2.0 * z / w, 1.0])
        for fc in self.real_zeros_hz:
            num = np.polymul(num, [1.0 / (TWO_PI * fc), 1.0])
        for fc in self.real_poles_hz:
            den = np.polymul(den, [1.0 / (TWO_PI * fc), 1.0])
        den = np.polymul(den, np.r_[1.0, np.zeros(self.integrators)])
        return num, den


def _roots_of(quadratics, corners_hz, n_zero) -> np.ndarray:
    roots: list[complex] = []
    for f0, z in quadratics:
        w = TWO_PI * f0
        roots.extend(np.roots([1.0, 2.0 * z * w, w * w]).astype(np.complex128))
    roots.extend(-TWO_PI * np.asarray(corners_hz, dtype=np.float64) + 0j)
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

    @property
    def weighted_cost(self) -> float:
        """The fit's weighted cost (:attr:`TfFit.weighted_cost`); infinite when the fit could not be made."""
        return self.fit.weighted_cost if self.fit is not None else float("inf")


def zpk_response(frequency_hz, gain, zeros, poles, reference_hz, delay_s) -> np.ndarray:
    """``gain prod(s - z) / prod(s - p) exp(-s delay)`` at ``s = j 2 pi f``, in normalised ``s``."""
    f = np.asarray(frequency_hz, dtype=np.float64)
    w_ref = TWO_PI * reference_hz
    x = 1j * f / reference_hz
    k = gain * w_ref ** (len(zeros) - len(poles))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = k * _zpk_eval(x, np.asarray(zeros) / w_ref, np.asarray(poles) / w_ref)
    return h * np.exp(-1j * TWO_PI * f * delay_s)


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


def _factor(roots: np.ndarray) -> tuple[list[tuple[float, float]], list[float]]:
    """Quadratic factors ``(frequency_hz, zeta)`` and real corners (Hz) of `roots` (rad/s)."""
    quads, corners = [], []
    for r in roots:
        if abs(r.imag) > REAL_TOL * abs(r):
            if r.imag > 0.0:
                w = abs(r)
                quads.append((w / TWO_PI, -r.real / w))
        else:
            corners.append(-r.real / TWO_PI)
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
