"""State estimation for a discrete linear plant: Kalman filters and pole-placement observers.

The plant is thesis eq. 2.50 with noise,
``x(k+1) = A x(k) + B u(k) + w(k)``, ``y(k) = C x(k) + v(k)``, where
``cov w = Q``, ``cov v = R`` and ``(A, B, C)`` is a sampled model, e.g. from
:func:`two_mass_discrete` (thesis eq. 2.6, sampled by
:func:`hilident.ident.discretize.zoh`). Sample ``k`` pairs the output measured
at ``t_k`` with the input held from ``t_k`` to ``t_(k+1)`` -- the layout of a
drive recording, where row ``k`` holds the encoder position at the tick's
start and the torque applied during the tick.

Estimates:

- :class:`KalmanFilter`: the time-varying filter of thesis eqs. 2.55-2.62,
  with the Joseph-form covariance update
  ``P(k|k) = (I - K C) P(k|k-1) (I - K C)^T + K R K^T`` (eq. 2.61 as it
  should read; the printed ``^-1`` is a typo). Measurements that are NaN
  (a laser out of range) are skipped.
- :func:`steady_state_kalman`: the constant gain the filter converges to,
  from the discrete algebraic Riccati equation.
- :func:`observer_gain_by_pole_placement` and :func:`run_observer`: a
  fixed-gain observer (thesis eqs. 2.51-2.54, section 3.4), with the
  estimation error's poles chosen by hand.

Two observer forms appear throughout (argument ``form``):

``"predictor"`` (thesis eq. 2.53)
    ``xp(k+1) = A xp(k) + B u(k) + L (y(k) - C xp(k))``; the estimate of
    ``x(k)`` uses the outputs up to ``k - 1``. Error dynamics ``A - L C``.
``"filter"`` (current estimate, eqs. 2.55-2.60 with a constant gain)
    ``x(k|k) = xp(k) + M (y(k) - C xp(k))``, ``xp(k+1) = A x(k|k) + B u(k)``;
    the estimate of ``x(k)`` already uses ``y(k)``. Error dynamics
    ``A - M C A`` (same eigenvalues as ``A - A M C``): the predictor gain of
    the same observer is ``L = A M``.

Observability is checked first (thesis eq. 2.32): a ``C`` from which some
state direction cannot be reconstructed -- the two-mass axis with only its
velocity measured cannot know where it is -- is refused with
:class:`~hilident.errors.DataError` naming that direction.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.kalman import two_mass_discrete, steady_state_kalman, process_noise_from_input
>>> sys = two_mass_discrete(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0, dt=2.5e-4)
>>> Q = process_noise_from_input(sys.Gamma, 0.01) + 1e-18 * np.eye(4)
>>> K, P = steady_state_kalman(sys.Phi, sys.Gamma, sys.C, Q, R=(1e-7) ** 2 / 12)
>>> K.shape, P.shape
((4, 1), (4, 4))
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg, signal

from hilident.errors import ConfigError, DataError
from hilident.ident.discretize import (
    DiscreteStateSpace,
    StateSpace,
    is_observable,
    observability_matrix,
    zoh,
)

__all__ = [
    "TWO_MASS_STATES",
    "two_mass_model",
    "two_mass_discrete",
    "check_observable",
    "process_noise_from_input",
    "SteadyStateGain",
    "steady_state_kalman",
    "KalmanRun",
    "KalmanFilter",
    "observer_gain_by_pole_placement",
    "run_observer",
]

#: State order of the two-mass model (thesis eq. 2.6).
TWO_MASS_STATES = ("p1", "v1", "p2", "v2")

_FORMS = ("predictor", "filter")


# --- the two-mass plant ----------------------------------------------------------


def _param(key: str, value, *, positive: bool) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = np.nan
    if isinstance(value, bool) or not np.isfinite(x) or (x <= 0.0 if positive else x < 0.0):
        raise ConfigError(key, f"must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")
    return x


def two_mass_model(
    m1: float,
    m2: float,
    k: float,
    d: float,
    c: float = 1.0,
    Fv: float = 0.0,
    outputs: tuple[str, ...] = ("p1",),
) -> StateSpace:
    """Continuous two-mass model of thesis eq. 2.6 with constant ``k``, ``d``, torque input.

    States ``(p1, v1, p2, v2)`` (:data:`TWO_MASS_STATES`); the input is the
    motor torque ``tau`` (N·m), acting on ``m1`` as the force ``c tau``
    (thesis eq. 3.3). Optional viscous friction on ``m1``, a torque ``Fv v1``
    at the motor like :class:`hilident.emulator.plant.StribeckFriction` with
    ``Fc = Fs = 0``, ``delta_v = 1``::

        m1 p1'' = c (tau - Fv p1') - k (p1 - p2) - d (p1' - p2')
        m2 p2'' =                    k (p1 - p2) - d (p2' - p1')

    Parameters
    ----------
    m1, m2 : float
        Driven (cart) and load mass, kg.
    k : float
        Coupling stiffness, N/m.
    d : float
        Coupling damping, N·s/m.
    c : float
        Torque-to-force constant, N/(N·m).
    Fv : float
        Viscous friction of the driven mass as a motor torque, N·m/(m/s).
    outputs : tuple of str
        Measured states, names from :data:`TWO_MASS_STATES`, one row of ``C``
        each; thesis eq. 2.7 is ``("p1", "v1")``.

    Returns
    -------
    StateSpace
        ``A`` (4, 4), ``B`` (4, 1), ``C`` (len(outputs), 4), ``D`` zeros.
    """
    m1 = _param("m1", m1, positive=True)
    m2 = _param("m2", m2, positive=True)
    k = _param("k", k, positive=True)
    d = _param("d", d, positive=False)
    c = _param("c", c, positive=True)
    Fv = _param("Fv", Fv, positive=False)
    if isinstance(outputs, str):
        outputs = (outputs,)
    outputs = tuple(outputs)
    unknown = [o for o in outputs if o not in TWO_MASS_STATES]
    if not outputs or unknown:
        raise ConfigError("outputs", f"must name one or more of {TWO_MASS_STATES}, got {outputs!r}")
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / m1, -(d + c * Fv) / m1, k / m1, d / m1],
            [0.0, 0.0, 0.0, 1.0],
            [k / m2, d / m2, -k / m2, -d / m2],
        ]
    )
    B = np.array([[0.0], [c / m1], [0.0], [0.0]])
    C = np.zeros((len(outputs), 4))
    for row, name in enumerate(outputs):
        C[row, TWO_MASS_STATES.index(name)] = 1.0
    return StateSpace(A, B, C, np.zeros((len(outputs), 1)))


def two_mass_discrete(
    m1: float,
    m2: float,
    k: float,
    d: float,
    dt: float,
    c: float = 1.0,
    Fv: float = 0.0,
    outputs: tuple[str, ...] = ("p1",),
) -> DiscreteStateSpace:
    """:func:`two_mass_model` sampled with zero-order hold on the torque (period `dt`, s).

    The zero-order hold is exact for a drive that holds each torque for one
    loop tick.
    """
    return zoh(*two_mass_model(m1, m2, k, d, c, Fv, outputs), dt)


# --- argument handling -----------------------------------------------------------


def _system(A: ArrayLike, B: ArrayLike, C: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a = np.atleast_2d(np.asarray(A, dtype=np.float64))
    n = a.shape[0]
    if a.ndim != 2 or a.shape != (n, n):
        raise DataError(f"A must be a square matrix, got shape {np.shape(A)}")
    b = np.asarray(B, dtype=np.float64)
    if b.ndim == 1:
        b = b[:, None]
    if b.ndim != 2 or b.shape[0] != n:
        raise DataError(f"B must have {n} rows (one per state), got shape {np.shape(B)}")
    c = np.asarray(C, dtype=np.float64)
    if c.ndim == 1:
        c = c[None, :]
    if c.ndim != 2 or c.shape[1] != n or c.shape[0] == 0:
        raise DataError(f"C must have {n} columns (one per state), got shape {np.shape(C)}")
    for name, m in (("A", a), ("B", b), ("C", c)):
        if not np.all(np.isfinite(m)):
            raise DataError(f"matrix {name} has non-finite entries")
    return a, b, c


def _covariance(key: str, value: ArrayLike, size: int, definite: bool) -> np.ndarray:
    """A symmetric covariance; a scalar or 1-D value is taken as its diagonal."""
    m = np.asarray(value, dtype=np.float64)
    if m.ndim == 0:
        m = np.full(size, float(m))
    if m.ndim == 1:
        if m.size != size:
            raise ConfigError(key, f"diagonal must have {size} entries, got {m.size}")
        m = np.diag(m)
    if m.shape != (size, size):
        raise ConfigError(key, f"must be {size}x{size}, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ConfigError(key, "has non-finite entries")
    scale = max(float(np.max(np.abs(m))), np.finfo(float).tiny)
    if np.max(np.abs(m - m.T)) > 1e-9 * scale:
        raise ConfigError(key, "must be symmetric")
    m = 0.5 * (m + m.T)
    lam = np.linalg.eigvalsh(m)
    if definite and not lam[0] > 0.0:
        raise ConfigError(key, f"must be positive definite, smallest eigenvalue {lam[0]:.3g}")
    if lam[0] < -1e-12 * scale:
        raise ConfigError(key, f"must be positive semi-definite, smallest eigenvalue {lam[0]:.3g}")
    return m


def _form(form: str) -> str:
    if form not in _FORMS:
        raise ConfigError("form", f"must be one of {_FORMS}, got {form!r}")
    return form


def check_observable(A: ArrayLike, C: ArrayLike) -> None:
    """Raise unless every state can be reconstructed from the outputs ``y = C x`` (thesis eq. 2.32).

    Raises
    ------
    DataError
        When ``rank W_o < n``; the message gives the rank and a state
        direction that leaves no trace in the outputs (e.g. for the two-mass
        axis with only ``v1`` measured: ``p1`` and ``p2`` moved together, the
        axis' absolute position).
    """
    a, _, c = _system(A, np.zeros((np.shape(A)[0], 1)), C)
    if is_observable(a, c):
        return
    w = observability_matrix(a, c)
    norms = np.linalg.norm(w, axis=0)
    norms[norms == 0.0] = 1.0
    _, s, vt = linalg.svd(w / norms)
    rtol = 1e3 * max(w.shape) * np.finfo(float).eps
    rank = int(np.sum(s > rtol * s[0])) if s.size and s[0] > 0 else 0
    direction = vt[-1] / norms
    direction /= direction[np.argmax(np.abs(direction))]
    direction[np.abs(direction) < 1e-9] = 0.0  # rounding residue, not a component
    shown = ", ".join(f"{v:.3g}" for v in direction)
    raise DataError(
        f"C: the state is not observable from these outputs (observability matrix rank "
        f"{rank} < {a.shape[0]}); the state direction [{shown}] (in the state order of A) "
        "leaves no trace in y = C x. "
        "Measure a quantity that sees it (e.g. a position, not only a velocity)."
    )


def process_noise_from_input(Gamma: ArrayLike, input_std: ArrayLike) -> np.ndarray:
    """Process noise ``Q = Gamma diag(sigma^2) Gamma^T`` of a noisy measured input.

    When the measured torque drives the model, its measurement noise (standard
    deviation `input_std`, N·m, held over each sample) enters the state exactly
    like process noise through ``Gamma``. Add a small diagonal for what the
    model misses.

    Parameters
    ----------
    Gamma : array_like, shape (n,) or (n, m)
        Input matrix of the sampled model.
    input_std : float or array_like, shape (m,)
        Standard deviation of each input's noise.
    """
    g = np.asarray(Gamma, dtype=np.float64)
    if g.ndim == 1:
        g = g[:, None]
    s = np.broadcast_to(np.asarray(input_std, dtype=np.float64), (g.shape[1],))
    if not np.all(np.isfinite(s)) or np.any(s < 0.0):
        raise ConfigError("input_std", f"must be finite and >= 0, got {input_std!r}")
    return (g * s**2) @ g.T


# --- steady-state Kalman gain ------------------------------------------------------


class SteadyStateGain(NamedTuple):
    """Constant Kalman gain and the covariance it settles at.

    Attributes
    ----------
    K : ndarray, shape (n, p)
        Filter (measurement-update) gain: ``x(k|k) = x(k|k-1) + K (y(k) - C x(k|k-1))``.
        The predictor gain of thesis eq. 2.51 is ``A K``.
    P : ndarray, shape (n, n)
        Steady a-priori error covariance ``P(k|k-1)``; the a-posteriori one is
        ``(I - K C) P``.
    """

    K: np.ndarray
    P: np.ndarray


def steady_state_kalman(A: ArrayLike, B: ArrayLike, C: ArrayLike, Q: ArrayLike, R: ArrayLike) -> SteadyStateGain:
    """Steady-state Kalman gain of ``x(k+1) = A x + B u + w``, ``y = C x + v``.

    ``P`` solves the filter Riccati equation
    ``P = A P A^T - A P C^T (C P C^T + R)^-1 C P A^T + Q``
    (``scipy.linalg.solve_discrete_are`` on the dual system ``(A^T, C^T)``), and
    ``K = P C^T (C P C^T + R)^-1`` -- the limit of eq. 2.59 of the
    time-varying :class:`KalmanFilter`. Use it with
    ``run_observer(A, B, C, K, u, y, x0, form="filter")``.

    Parameters
    ----------
    A, B, C : array_like
        Sampled model (``B`` only checked for shape; the gain does not depend on it).
    Q : array_like
        Process noise covariance, (n, n) or its diagonal; positive semi-definite.
    R : array_like
        Measurement noise covariance, (p, p) or its diagonal; positive definite.

    Returns
    -------
    SteadyStateGain
        ``(K, P)``.

    Raises
    ------
    DataError
        When ``(A, C)`` is not observable, or the Riccati equation has no
        stabilising solution (e.g. ``Q`` leaves an unstable or marginal mode
        undriven).
    """
    a, _, c = _system(A, B, C)
    n, p = a.shape[0], c.shape[0]
    q = _covariance("Q", Q, n, definite=False)
    r = _covariance("R", R, p, definite=True)
    check_observable(a, c)
    # Scale states and outputs to comparable size: positions in m next to
    # velocities in m/s and covariances of 1e-15 otherwise strain the solver.
    t = _state_scale(q, a)
    ri = 1.0 / np.sqrt(np.diag(r))
    a_s = a * t[:, None] / t[None, :]
    c_s = c * ri[:, None] / t[None, :]
    q_s = q * t[:, None] * t[None, :]
    r_s = r * ri[:, None] * ri[None, :]
    try:
        p_s = linalg.solve_discrete_are(a_s.T, c_s.T, q_s, r_s)
    except (linalg.LinAlgError, ValueError) as exc:
        raise DataError(
            f"no stabilising steady-state Kalman gain: {exc}; check that Q drives every "
            "mode on or outside the unit circle"
        ) from None
    P = p_s / t[:, None] / t[None, :]
    P = 0.5 * (P + P.T)
    S = c @ P @ c.T + r
    K = linalg.solve(S, c @ P, assume_a="pos").T
    return SteadyStateGain(K, P)


def _state_scale(q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Per-state factors ``t`` making ``t_i^2 Q_ii`` about 1 (1 where ``Q_ii`` is 0)."""
    diag = np.diag(q)
    t = np.ones(a.shape[0])
    pos = diag > 0.0
    t[pos] = 1.0 / np.sqrt(diag[pos])
    return t


# --- time-varying Kalman filter ------------------------------------------------------


class KalmanRun(NamedTuple):
    """Result of :meth:`KalmanFilter.run`, one row per sample.

    Attributes
    ----------
    x : ndarray, shape (N, n)
        Filtered estimates ``x(k|k)`` (eq. 2.60).
    P : ndarray, shape (N, n, n)
        Their error covariances ``P(k|k)`` (eq. 2.61, Joseph form).
    innovation : ndarray, shape (N, p)
        ``y(k) - C x(k|k-1)`` (eq. 2.57); NaN where ``y`` was missing.
    residual : ndarray, shape (N, p)
        ``y(k) - C x(k|k)`` (eq. 2.62).
    """

    x: np.ndarray
    P: np.ndarray
    innovation: np.ndarray
    residual: np.ndarray


class KalmanFilter:
    """Time-varying Kalman filter, thesis eqs. 2.55-2.62.

    Per sample ``k`` (:meth:`step`), first the measurement update with
    ``y(k)``::

        y~   = y(k) - C x(k|k-1)                               (2.57)
        S    = R + C P(k|k-1) C^T                              (2.58)
        K    = P(k|k-1) C^T S^-1                               (2.59)
        x(k|k) = x(k|k-1) + K y~                               (2.60)
        P(k|k) = (I - K C) P(k|k-1) (I - K C)^T + K R K^T      (2.61, Joseph form)

    then the time update with the input ``u(k)`` held until ``k + 1``::

        x(k+1|k) = A x(k|k) + B u(k)                           (2.55)
        P(k+1|k) = A P(k|k) A^T + Q                            (2.56)

    The Joseph form keeps ``P`` symmetric positive semi-definite under
    rounding, and stays right for a gain that is not exactly optimal.
    Outputs that are NaN at a sample are left out of that sample's update
    (their rows of ``C`` and ``R`` are dropped); with all of them missing only
    the time update runs.

    Parameters
    ----------
    A, B, C : array_like
        Sampled model, shapes (n, n), (n, m) or (n,), (p, n) or (n,).
    Q : array_like
        Process noise covariance (n, n) or its diagonal.
    R : array_like
        Measurement noise covariance (p, p) or its diagonal; positive definite.
    x0 : array_like, shape (n,)
        Prior estimate of the state at the first sample, ``x(0|-1)``.
    P0 : array_like
        Its error covariance (n, n) or diagonal.

    Attributes
    ----------
    x, P : ndarray
        Current prior ``x(k|k-1)``, ``P(k|k-1)`` for the next sample.
    K : ndarray or None
        Gain of the last full update (all outputs present).

    Examples
    --------
    >>> import numpy as np
    >>> kf = KalmanFilter(A=[[1.0]], B=[[0.0]], C=[[1.0]], Q=[[0.0]], R=[[1.0]],
    ...                   x0=[0.0], P0=[[1e6]])
    >>> est = kf.run(np.zeros(4), np.array([1.0, 3.0, 2.0, 2.0]))
    >>> round(float(est.x[-1, 0]), 3)        # constant in noise: the running mean
    2.0
    """

    def __init__(self, A, B, C, Q, R, x0, P0):
        a, b, c = _system(A, B, C)
        n, p = a.shape[0], c.shape[0]
        self.A, self.B, self.C = a, b, c
        self.Q = _covariance("Q", Q, n, definite=False)
        self.R = _covariance("R", R, p, definite=True)
        check_observable(a, c)
        self._x0 = self._state(x0)
        self._P0 = _covariance("P0", P0, n, definite=False)
        self.reset()

    def _state(self, x0) -> np.ndarray:
        x = np.asarray(x0, dtype=np.float64).reshape(-1)
        if x.shape != (self.A.shape[0],) or not np.all(np.isfinite(x)):
            raise ConfigError("x0", f"must be {self.A.shape[0]} finite values, got {x0!r}")
        return x

    def reset(self, x0: ArrayLike | None = None, P0: ArrayLike | None = None) -> None:
        """Restart from `x0`, `P0` (default: the ones given to the constructor)."""
        self.x = self._x0.copy() if x0 is None else self._state(x0)
        n = self.A.shape[0]
        self.P = self._P0.copy() if P0 is None else _covariance("P0", P0, n, definite=False)
        self.K: np.ndarray | None = None

    def _input(self, u) -> np.ndarray:
        v = np.asarray(u, dtype=np.float64).reshape(-1)
        if v.shape != (self.B.shape[1],) or not np.all(np.isfinite(v)):
            raise DataError(f"u must be {self.B.shape[1]} finite values per sample, got {u!r}")
        return v

    def _update(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measurement update; returns x(k|k), P(k|k), innovation (NaN where y is missing)."""
        x, P, C = self.x, self.P, self.C
        innovation = y - C @ x
        have = np.isfinite(y)
        if not have.any():
            return x.copy(), P.copy(), innovation
        if have.all():
            Cm, Rm, e = C, self.R, innovation
        else:
            Cm, Rm, e = C[have], self.R[np.ix_(have, have)], innovation[have]
        S = Rm + Cm @ P @ Cm.T
        K = linalg.solve(S, Cm @ P, assume_a="pos").T
        x_post = x + K @ e
        ikc = np.eye(x.size) - K @ Cm
        P_post = ikc @ P @ ikc.T + K @ Rm @ K.T
        P_post = 0.5 * (P_post + P_post.T)
        if have.all():
            self.K = K
        return x_post, P_post, innovation

    def _predict(self, x_post: np.ndarray, P_post: np.ndarray, u: np.ndarray) -> None:
        self.x = self.A @ x_post + self.B @ u
        P = self.A @ P_post @ self.A.T + self.Q
        self.P = 0.5 * (P + P.T)

    def step(self, u: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Process one sample: update with ``y(k)``, then predict with ``u(k)``.

        Parameters
        ----------
        u : float or array_like, shape (m,)
            Input held from this sample to the next.
        y : float or array_like, shape (p,)
            Outputs measured at this sample; NaN entries are missing.

        Returns
        -------
        ndarray, shape (n,)
            The filtered estimate ``x(k|k)``.
        """
        uk = self._input(u)
        yk = np.asarray(y, dtype=np.float64).reshape(-1)
        if yk.shape != (self.C.shape[0],):
            raise DataError(f"y must have {self.C.shape[0]} values per sample, got {y!r}")
        x_post, P_post, _ = self._update(yk)
        self._predict(x_post, P_post, uk)
        return x_post

    def run(self, u: ArrayLike, y: ArrayLike) -> KalmanRun:
        """Filter a whole record, continuing from the current state.

        Parameters
        ----------
        u : array_like, shape (N,) or (N, m)
            Inputs, one row per sample.
        y : array_like, shape (N,) or (N, p)
            Outputs, one row per sample; NaN where missing.

        Returns
        -------
        KalmanRun
        """
        uu, yy = _records(u, y, self.B.shape[1], self.C.shape[0])
        N, n, p = yy.shape[0], self.A.shape[0], self.C.shape[0]
        xs = np.empty((N, n))
        Ps = np.empty((N, n, n))
        innov = np.empty((N, p))
        for k in range(N):
            x_post, P_post, e = self._update(yy[k])
            self._predict(x_post, P_post, uu[k])
            xs[k], Ps[k], innov[k] = x_post, P_post, e
        innov[~np.isfinite(yy)] = np.nan
        return KalmanRun(xs, Ps, innov, yy - xs @ self.C.T)


def _records(u, y, m: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    uu = np.asarray(u, dtype=np.float64)
    yy = np.asarray(y, dtype=np.float64)
    if uu.ndim == 1:
        uu = uu[:, None]
    if yy.ndim == 1:
        yy = yy[:, None]
    if uu.ndim != 2 or uu.shape[1] != m:
        raise DataError(f"u must have shape (N, {m}) (or (N,) for one input), got {np.shape(u)}")
    if yy.ndim != 2 or yy.shape[1] != p:
        raise DataError(f"y must have shape (N, {p}) with {p} output(s), got {np.shape(y)}")
    if uu.shape[0] != yy.shape[0]:
        raise DataError(f"u has {uu.shape[0]} samples but y has {yy.shape[0]}")
    if not np.all(np.isfinite(uu)):
        raise DataError(f"u has {int(np.sum(~np.isfinite(uu)))} non-finite samples")
    if np.any(np.isinf(yy)):
        raise DataError("y has infinite samples (NaN marks a missing measurement, inf is not allowed)")
    return uu, yy


# --- fixed-gain observers ------------------------------------------------------------


def observer_gain_by_pole_placement(
    A: ArrayLike, C: ArrayLike, poles: ArrayLike, form: str = "predictor"
) -> np.ndarray:
    """Observer gain placing the estimation error's poles (thesis section 3.4).

    Pole placement on the dual system by ``scipy.signal.place_poles``
    (``A^T``, ``C^T``), which with several outputs picks the gain whose
    closed-loop eigenvectors are best conditioned.

    Parameters
    ----------
    A, C : array_like
        Sampled model.
    poles : array_like of complex, shape (n,)
        Desired error poles in the z-plane, inside the unit circle, complex
        ones in conjugate pairs. A continuous-time choice ``s`` maps to
        ``exp(s dt)``; poles well faster than the modes to be seen, yet slow
        enough not to amplify the measurement noise.
    form : {"predictor", "filter"}
        ``"predictor"``: ``L`` with ``eig(A - L C) = poles``;
        ``"filter"``: ``M`` with ``eig(A - M C A) = poles`` (see the module
        docstring).

    Returns
    -------
    ndarray, shape (n, p)

    Raises
    ------
    DataError
        When ``(A, C)`` is not observable.
    ConfigError
        When `poles` has the wrong count, is not closed under conjugation, lies
        on or outside the unit circle, or repeats a pole more often than there
        are outputs (key ``"poles"``).
    """
    a, _, c = _system(A, np.zeros((np.shape(A)[0], 1)), C)
    _form(form)
    n = a.shape[0]
    z = np.atleast_1d(np.asarray(poles, dtype=complex))
    if z.ndim != 1 or z.size != n:
        raise ConfigError("poles", f"need {n} poles (one per state), got {z.size}")
    if not np.all(np.isfinite(z)):
        raise ConfigError("poles", "must be finite")
    if np.any(np.abs(z) >= 1.0):
        raise ConfigError("poles", f"must lie inside the unit circle for a converging observer, got {z}")
    if not np.allclose(np.sort_complex(z), np.sort_complex(z.conj()), rtol=0.0, atol=1e-12):
        raise ConfigError("poles", "complex poles must come in conjugate pairs")
    check_observable(a, c)
    c_eff = c if form == "predictor" else c @ a
    try:
        res = signal.place_poles(a.T, c_eff.T, z)
    except ValueError as exc:
        raise ConfigError("poles", f"cannot be placed: {exc}") from None
    gain = res.gain_matrix.T
    achieved = np.linalg.eigvals(a - gain @ c_eff)
    # place_poles can fall short for ill-conditioned placements; say so instead of returning a wrong gain.
    worst = _pole_mismatch(achieved, z)
    if worst > 1e-6:
        raise DataError(
            f"pole placement missed the requested poles by up to {worst:.2g} "
            f"(achieved {np.sort_complex(achieved)}); choose poles further apart or slower"
        )
    return gain


def _pole_mismatch(achieved: np.ndarray, wanted: np.ndarray) -> float:
    left = list(achieved)
    worst = 0.0
    for w in wanted:
        i = int(np.argmin([abs(a - w) for a in left]))
        worst = max(worst, abs(left.pop(i) - w))
    return worst


def run_observer(
    A: ArrayLike,
    B: ArrayLike,
    C: ArrayLike,
    L: ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    x0: ArrayLike,
    form: str = "predictor",
) -> np.ndarray:
    """Run a fixed-gain observer over a record.

    ``"predictor"`` (thesis eq. 2.53): ``x^(k+1) = (A - L C) x^(k) + B u(k) + L y(k)``,
    returns ``x^(k)`` (from outputs up to ``k - 1``), ``x^(0) = x0``.

    ``"filter"``: ``x(k|k) = xp + L (y(k) - C xp)``, ``xp <- A x(k|k) + B u(k)``,
    returns ``x(k|k)``, starting from ``xp = x0``; with ``L`` the ``K`` of
    :func:`steady_state_kalman` this is the steady-state Kalman filter.

    Outputs that are NaN at a sample add no correction there (their innovation
    is taken as 0).

    Parameters
    ----------
    A, B, C : array_like
        Sampled model.
    L : array_like, shape (n, p) or (n,)
        Observer gain of the chosen `form`.
    u : array_like, shape (N,) or (N, m)
    y : array_like, shape (N,) or (N, p)
    x0 : array_like, shape (n,)
        Initial estimate (prior of the first sample).
    form : {"predictor", "filter"}

    Returns
    -------
    ndarray, shape (N, n)
    """
    a, b, c = _system(A, B, C)
    _form(form)
    n, p = a.shape[0], c.shape[0]
    g = np.asarray(L, dtype=np.float64)
    if g.ndim == 1:
        g = g[:, None]
    if g.shape != (n, p) or not np.all(np.isfinite(g)):
        raise DataError(f"L must be a finite {n}x{p} gain, got shape {np.shape(L)}")
    x = np.asarray(x0, dtype=np.float64).reshape(-1)
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise ConfigError("x0", f"must be {n} finite values, got {x0!r}")
    uu, yy = _records(u, y, b.shape[1], p)
    missing = ~np.isfinite(yy)
    yz = np.where(missing, 0.0, yy)
    N = yy.shape[0]
    out = np.empty((N, n))
    bu = uu @ b.T  # input term of every sample at once
    if form == "predictor":
        f = a - g @ c
        gy = yz @ g.T
        if missing.any():
            # a missing output contributes no correction: drop L y and L C x for it
            for k in range(N):
                out[k] = x
                if missing[k].any():
                    keep = ~missing[k]
                    x = a @ x + bu[k] + g[:, keep] @ (yz[k, keep] - c[keep] @ x)
                else:
                    x = f @ x + bu[k] + gy[k]
            return out
        for k in range(N):
            out[k] = x
            x = f @ x + bu[k] + gy[k]
        return out
    eye_gc = np.eye(n) - g @ c
    gy = yz @ g.T
    for k in range(N):
        if missing[k].any():
            keep = ~missing[k]
            xk = x + g[:, keep] @ (yz[k, keep] - c[keep] @ x)
        else:
            xk = eye_gc @ x + gy[k]
        out[k] = xk
        x = a @ xk + bu[k]
    return out
