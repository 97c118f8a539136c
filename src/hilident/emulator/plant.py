"""Plant physics of an emulated servo axis.

Two linear plants and one friction law, integrated on a simulated clock:

* :class:`TwoMass` -- the thesis's gantry (eqs. 2.1-2.2): a driven mass ``m1`` (the
  cart, position ``p1``) coupled by a spring ``k`` and a damper ``d`` to a load mass
  ``m2`` (position ``p2``). The motor torque ``tau`` acts on ``m1`` as the force
  ``c * (tau - tau_friction)`` (thesis eq. 3.3)::

      m1 p1'' = c (tau - tau_fr) - k (p1 - p2) - d (p1' - p2')
      m2 p2'' =                    k (p1 - p2) - d (p2' - p1')

* :class:`ThreeMass` -- the same chain with a third mass ``m3`` hung from the load
  by ``k2``, ``d2``: a second, higher mode, as a real gantry's tool or beam has.

* :class:`MassSpringDamper` -- the lecture's ``m y'' + b y' + k y = F`` with
  ``F = c * (tau - tau_fr)``.

* :class:`StribeckFriction` -- thesis eq. 2.13 as a torque at the motor, a function of
  the driven mass's velocity, with stiction (breakaway at ``Fs``) handled by
  :class:`Plant`.

:class:`Plant` holds the state ``(p1, v1, p2, v2)`` and advances it exactly (matrix
exponential, zero-order hold on the input) over each substep. :func:`modes` and
:func:`frf` give the frictionless truth that tests and examples compare against.

The cart-to-load coupling's ``k`` and ``d`` may vary with the cart position ``p1``
(thesis eqs. 2.3-2.4, a :class:`~hilident.emulator.coupling.PositionCurve` each):
:class:`Plant` then steps with them taken at ``p1``, and :func:`modes_at` gives the
truth at a position.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.linalg import expm

from hilident.emulator.coupling import PositionCurve, model_at
from hilident.errors import ConfigError

__all__ = [
    "TwoMass",
    "ThreeMass",
    "MassSpringDamper",
    "StribeckFriction",
    "Plant",
    "COUPLING_TOLERANCE",
    "DAMPING_TOLERANCE",
    "modes",
    "modes_at",
    "frf",
    "state_matrices",
]


def _check_fields(obj, positive: tuple[str, ...], nonnegative: tuple[str, ...]) -> None:
    """Coerce every field of a frozen dataclass to float and check its range."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, bool):
            raise ConfigError(f.name, f"must be a number, got {value!r}")
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f.name, f"must be a number, got {value!r}") from None
        if not math.isfinite(x):
            raise ConfigError(f.name, f"must be finite, got {value!r}")
        if f.name in positive and not x > 0.0:
            raise ConfigError(f.name, f"must be > 0, got {value!r}")
        if f.name in nonnegative and not x >= 0.0:
            raise ConfigError(f.name, f"must be >= 0, got {value!r}")
        object.__setattr__(obj, f.name, x)


@dataclass(frozen=True)
class TwoMass:
    """Two masses coupled by a spring and a damper (thesis eqs. 2.1-2.2).

    Parameters
    ----------
    m1 : float
        Driven mass (cart, motor side), kg.
    m2 : float
        Load mass (tool), kg.
    k : float
        Coupling stiffness, N/m.
    d : float
        Coupling damping, N·s/m.
    c : float
        Torque-to-force constant of thesis eq. 3.3, N/(N·m): the force on ``m1``
        is ``c * (tau - tau_friction)``.

    Examples
    --------
    >>> TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0)  # doctest: +ELLIPSIS
    TwoMass(m1=8.0, m2=2.0, k=80000.0, d=20.0, c=10.0)
    """

    m1: float
    m2: float
    k: float
    d: float
    c: float = 1.0

    def __post_init__(self):
        _check_fields(self, positive=("m1", "m2", "k", "c"), nonnegative=("d",))


@dataclass(frozen=True)
class ThreeMass:
    """Three masses in a chain: the two-mass axis with a third mass on the load.

    ``m1`` (cart, driven) --``k``, ``d``-- ``m2`` (load, seen by the laser)
    --``k2``, ``d2``-- ``m3``. Two modes; the drive's torque acts on ``m1`` as
    the force ``c * (tau - tau_friction)``.

    Parameters
    ----------
    m1, m2, m3 : float
        Masses, kg.
    k, k2 : float
        Stiffness between m1 and m2, and between m2 and m3, N/m.
    d, d2 : float
        Damping of those couplings, N·s/m.
    c : float
        Torque-to-force constant, N/(N·m).

    Examples
    --------
    >>> [round(f, 2) for f, _ in modes(ThreeMass(40.0, 10.0, 2.0, 1.5e5, 40.0, 2e5, 10.0, c=10.0))]
    [20.05, 55.79]
    """

    m1: float
    m2: float
    m3: float
    k: float
    d: float
    k2: float
    d2: float
    c: float = 1.0

    def __post_init__(self):
        _check_fields(self, positive=("m1", "m2", "m3", "k", "k2", "c"), nonnegative=("d", "d2"))


@dataclass(frozen=True)
class MassSpringDamper:
    """The lecture's single mass ``m y'' + b y' + k y = F`` with ``F = c (tau - tau_fr)``.

    Parameters
    ----------
    m : float
        Mass, kg.
    b : float
        Viscous damping to ground, N·s/m.
    k : float
        Stiffness to ground, N/m (0 gives a free mass with damping).
    c : float
        Torque-to-force constant, N/(N·m).
    """

    m: float
    b: float
    k: float
    c: float = 1.0

    def __post_init__(self):
        _check_fields(self, positive=("m", "c"), nonnegative=("b", "k"))


@dataclass(frozen=True)
class StribeckFriction:
    """Stribeck friction, thesis eq. 2.13, as a torque at the motor.

    ``tau_fr(v) = (Fc + (Fs - Fc) exp(-|v/vs|**delta_s) + Fv |v|**delta_v) sgn(v)``

    where ``v`` is the velocity of the driven mass (m/s). At ``v = 0`` the curve is 0;
    a stopped mass is held by stiction up to the breakaway torque ``Fs``, which
    :class:`Plant` applies.

    Parameters
    ----------
    Fc : float
        Coulomb friction torque, N·m.
    Fs : float
        Static (breakaway) friction torque, N·m.
    Fv : float
        Viscous coefficient, N·m / (m/s)**delta_v.
    vs : float
        Stribeck velocity, m/s.
    delta_v : float
        Viscous exponent (1 gives linear viscous friction).
    delta_s : float
        Stribeck shape exponent.

    Examples
    --------
    >>> f = StribeckFriction(Fc=0.5, Fs=0.8, Fv=2.0, vs=0.01)
    >>> round(float(f(0.1)), 6), round(float(f(-0.1)), 6)
    (0.7, -0.7)
    """

    Fc: float
    Fs: float
    Fv: float
    vs: float
    delta_v: float = 1.0
    delta_s: float = 2.0

    def __post_init__(self):
        _check_fields(
            self,
            positive=("vs", "delta_v", "delta_s"),
            nonnegative=("Fc", "Fs", "Fv"),
        )

    def __call__(self, velocity_mps):
        """Kinetic friction torque (N·m) at ``velocity_mps``; array in, array out."""
        v = np.asarray(velocity_mps, dtype=float)
        a = np.abs(v)
        mag = self.Fc + (self.Fs - self.Fc) * np.exp(-((a / self.vs) ** self.delta_s)) + self.Fv * a**self.delta_v
        return np.sign(v) * mag

    torque = __call__


Model = TwoMass | ThreeMass | MassSpringDamper


def state_matrices(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """State matrix ``A`` and force input vector ``B`` of the frictionless plant.

    The input is the force on the driven mass, ``F = c * tau``.

    Returns
    -------
    A : ndarray, shape (4, 4) for :class:`TwoMass`, (2, 2) for :class:`MassSpringDamper`
        States ``(p1, v1, p2, v2)`` resp. ``(y, y')`` (thesis eq. 2.6).
    B : ndarray, shape (4,) or (2,)
    """
    if isinstance(model, TwoMass):
        m1, m2, k, d = model.m1, model.m2, model.k, model.d
        A = np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / m1, -d / m1, k / m1, d / m1],
                [0.0, 0.0, 0.0, 1.0],
                [k / m2, d / m2, -k / m2, -d / m2],
            ]
        )
        B = np.array([0.0, 1.0 / m1, 0.0, 0.0])
        return A, B
    if isinstance(model, ThreeMass):
        M, D, K = _chain(model)
        Minv = np.diag(1.0 / np.diag(M))
        A = np.zeros((6, 6))
        A[0::2, 1::2] = np.eye(3)
        A[1::2, 0::2] = -Minv @ K
        A[1::2, 1::2] = -Minv @ D
        B = np.zeros(6)
        B[1] = 1.0 / model.m1
        return A, B
    if isinstance(model, MassSpringDamper):
        A = np.array([[0.0, 1.0], [-model.k / model.m, -model.b / model.m]])
        B = np.array([0.0, 1.0 / model.m])
        return A, B
    raise TypeError(f"unknown plant model {type(model).__name__}")


def _chain(model: ThreeMass) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass, damping and stiffness matrices of the three-mass chain (positions p1, p2, p3)."""
    k, k2, d, d2 = model.k, model.k2, model.d, model.d2
    M = np.diag([model.m1, model.m2, model.m3])
    K = np.array([[k, -k, 0.0], [-k, k + k2, -k2], [0.0, -k2, k2]])
    D = np.array([[d, -d, 0.0], [-d, d + d2, -d2], [0.0, -d2, d2]])
    return M, D, K


def _flexible_matrix(model: Model) -> np.ndarray | None:
    """State matrix of the plant with the rigid-body motion removed (None if none left).

    For the two-mass plant this is the relative motion ``e = p1 - p2`` with the reduced
    mass ``mu = m1 m2 / (m1 + m2)``: its eigenvalues are exactly the non-zero
    eigenvalues of the full 4x4 state matrix, which has a double zero eigenvalue for
    the free rigid-body motion. Computing them this way avoids the poor conditioning
    of that defective zero eigenvalue.
    """
    if isinstance(model, TwoMass):
        mu = model.m1 * model.m2 / (model.m1 + model.m2)
        return np.array([[0.0, 1.0], [-model.k / mu, -model.d / mu]])
    if isinstance(model, ThreeMass):
        # Relative coordinates e1 = p1 - p2, e2 = p2 - p3: the rigid-body motion drops out of
        # M q'' + D q' + K q = 0 (q = T e + 1 p3) once p3'' is eliminated through the
        # momentum balance 1' M q'' = 0.
        M, D, K = _chain(model)
        T = np.array([[1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
        ones = np.ones(3)
        # p3'' = -(1' M T e'') / (1' M 1): q'' = (T - 1 (1' M T) / (1' M 1)) e'' = P e''
        P = T - np.outer(ones, ones @ M @ T) / (ones @ M @ ones)
        Me = P.T @ M @ P
        Ke = P.T @ K @ T
        De = P.T @ D @ T
        A = np.zeros((4, 4))
        A[0::2, 1::2] = np.eye(2)
        Mi = np.linalg.inv(Me)
        A[1::2, 0::2] = -Mi @ Ke
        A[1::2, 1::2] = -Mi @ De
        return A
    if isinstance(model, MassSpringDamper):
        if model.k == 0.0:
            return None
        return state_matrices(model)[0]
    raise TypeError(f"unknown plant model {type(model).__name__}")


def _pairs(lam: np.ndarray) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the eigenvalue pairs of a flexible state matrix, slowest first."""
    lam = np.asarray(lam)
    complex_ = sorted(lam[np.imag(lam) > 0], key=abs)
    real = sorted(np.real(lam[np.imag(lam) == 0]), key=abs)
    out = [(abs(z), -z.real / abs(z)) for z in complex_]
    out += [
        (math.sqrt(a * b), -(a + b) / (2.0 * math.sqrt(a * b)))
        for a, b in zip(real[0::2], real[1::2], strict=False)
        if a * b > 0
    ]
    return sorted(((float(w) / (2.0 * math.pi), float(z) + 0.0) for w, z in out if w > 0.0), key=lambda m: m[0])


def modes(model: Model) -> list[tuple[float, float]]:
    """Vibration modes of the frictionless plant.

    Parameters
    ----------
    model : TwoMass or MassSpringDamper

    Returns
    -------
    list of (frequency_hz, damping_ratio)
        ``frequency_hz`` is the undamped natural frequency ``|lambda| / (2 pi)`` of an
        eigenvalue pair ``lambda`` of the state matrix, ``damping_ratio`` is
        ``-Re(lambda) / |lambda|`` (for an overdamped pair of real eigenvalues
        ``l1, l2``: ``sqrt(l1 l2)`` and ``-(l1 + l2) / (2 sqrt(l1 l2))``). Rigid-body
        (zero) eigenvalues are excluded; a free mass with damping has no mode.
        A free vibration oscillates at ``frequency_hz * sqrt(1 - damping_ratio**2)``.

    Examples
    --------
    >>> import math
    >>> f, z = modes(TwoMass(m1=1.0, m2=1.0, k=2.0, d=0.0))[0]
    >>> round(f * 2 * math.pi, 9), z
    (2.0, 0.0)
    """
    A = _flexible_matrix(model)
    if A is None:
        return []
    if isinstance(model, ThreeMass):
        return _pairs(np.linalg.eigvals(A))
    lam = np.linalg.eigvals(A)
    omega = math.sqrt(max(float(np.real(lam[0] * lam[1])), 0.0))
    if omega == 0.0:
        return []
    zeta = -float(np.real(lam[0] + lam[1])) / (2.0 * omega) + 0.0  # no -0.0
    return [(omega / (2.0 * math.pi), zeta)]


def modes_at(
    model, position_m: float, stiffness: PositionCurve | None = None, damping: PositionCurve | None = None
) -> list[tuple[float, float]]:
    """(frequency_hz, damping_ratio) of the frictionless plant with the cart held at ``position_m`` (m).

    :func:`~hilident.emulator.plant.modes` of :func:`model_at`.

    Examples
    --------
    >>> k = PositionCurve(poly=[1.0e5, 0.0, 2.0e5], span_m=(-0.5, 0.5))
    >>> [round(f, 3) for f, _ in modes_at(TwoMass(40.0, 10.0, 1.0e5, 0.0), 0.5, k)]
    [21.793]
    """
    return modes(model_at(model, position_m, stiffness, damping))


_OUTPUTS = ("velocity", "position", "load_position")


def frf(model: Model, frequency_hz, output: str = "velocity") -> np.ndarray:
    """Analytic frequency response of the frictionless plant from motor torque.

    Parameters
    ----------
    model : TwoMass or MassSpringDamper
    frequency_hz : array_like
        Frequencies, Hz. The two-mass plant (and a mass-spring-damper with ``k = 0``)
        has a rigid-body pole at 0 Hz, where the response is infinite.
    output : {"velocity", "position", "load_position"}
        ``"velocity"`` is ``v1`` in (m/s)/(N·m), ``"position"`` is ``p1`` in m/(N·m),
        ``"load_position"`` is ``p2`` in m/(N·m) (equal to ``p1`` for a
        mass-spring-damper).

    Returns
    -------
    ndarray of complex
    """
    if output not in _OUTPUTS:
        raise ValueError(f"output must be one of {_OUTPUTS}, got {output!r}")
    s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if isinstance(model, TwoMass):
            m1, m2, k, d = model.m1, model.m2, model.k, model.d
            den = s * s * (m1 * m2 * s * s + (m1 + m2) * (d * s + k))
            if output == "load_position":
                h = (d * s + k) / den
            else:
                h = (m2 * s * s + d * s + k) / den
        elif isinstance(model, ThreeMass):
            M, D, K = _chain(model)
            s1 = np.atleast_1d(s)
            moving = s1 != 0  # the rigid-body pole: infinite at 0 Hz
            Z = M * (s1[moving] ** 2)[:, None, None] + D * s1[moving][:, None, None] + K
            force = np.zeros((Z.shape[0], 3, 1), dtype=complex)
            force[:, 0, 0] = 1.0
            x = np.linalg.solve(Z, force)[:, :, 0]
            h1 = np.full(s1.shape, np.inf + 0j)
            h1[moving] = x[:, 1] if output == "load_position" else x[:, 0]
            h = h1.reshape(np.shape(s))
        elif isinstance(model, MassSpringDamper):
            h = 1.0 / (model.m * s * s + model.b * s + model.k)
        else:
            raise TypeError(f"unknown plant model {type(model).__name__}")
        if output == "velocity":
            h = s * h
    return model.c * h


def _tolerance(name: str, value) -> float:
    try:
        tol = float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be a number, got {value!r}") from None
    if not (math.isfinite(tol) and 0.0 < tol < 0.1):
        raise ConfigError(name, f"must lie in (0, 0.1), got {value!r}")
    return tol


def _snap(x: float, anchor: float, log_ratio: float) -> float:
    """``x`` > 0 rounded to the nearest ``anchor * exp(n * log_ratio)`` (``anchor`` itself at ``n == 0``); 0 stays 0."""
    if x == anchor or x <= 0.0:
        return anchor if x == anchor else 0.0
    n = round(math.log(x / anchor) / log_ratio)
    return anchor if n == 0 else anchor * math.exp(n * log_ratio)


# Substep coefficient caches are keyed by dt; more distinct dts than this is a caller
# sweeping dt, and the cache starts over rather than growing without bound.
_CACHE_LIMIT = 64

#: Relative step of the grid a position-dependent coupling's ``k`` is snapped to before the
#: step matrices are built (see :class:`Plant`): a mode frequency within 5e-5 of itself.
COUPLING_TOLERANCE = 1e-4
#: The same for ``d``: it moves a mode's frequency only through ``zeta**2``, and a damping
#: ratio by this share of itself (0.018 by 1.8e-5).
DAMPING_TOLERANCE = 1e-3
# Couplings whose step matrices are kept; a cart crossing the shipped map gantry's travel
# passes about 5000 of them; each costs about 1.5 kB.
_COUPLING_CACHE_LIMIT = 8192


class Plant:
    """A plant with optional Stribeck friction and stiction, stepped on a simulated clock.

    Parameters
    ----------
    model : TwoMass or MassSpringDamper
    friction : StribeckFriction, optional
        Friction torque acting against the driven mass's motion; frictionless if None.
    max_substep_s : float
        Longest integration substep, s. :meth:`step` splits ``dt_s`` into equal
        substeps no longer than this.
    backlash_m : float
        Total play in the first coupling (cart to load), m: inside it the spring and
        damper carry no force. :func:`modes` and :func:`frf` describe the coupling
        in contact.
    stiffness, damping : PositionCurve, optional
        The first coupling's ``k`` (N/m) and ``d`` (N·s/m) as functions of the cart
        position ``p1`` (thesis eqs. 2.3-2.4), for a two- or three-mass model; None
        keeps the model's number. ``model.k`` and ``model.d`` are then only the
        nominal values.
    coupling_tolerance, damping_tolerance : float
        Relative resolution of position-dependent ``k`` and ``d``, see Notes.

    Attributes
    ----------
    p1, v1 : float
        Position (m) and velocity (m/s) of the driven mass.
    p2, v2 : float
        Position and velocity of the load mass. For a :class:`MassSpringDamper` the
        single mass is the load too: ``p2``/``v2`` mirror ``p1``/``v1`` exactly.

    Notes
    -----
    The linear part is integrated exactly per substep, ``x+ = Phi x + Gamma u`` with
    ``Phi = expm(A h)``, ``Gamma = int_0^h expm(A s) B ds`` and the force
    ``u = c (tau - tau_fr)`` held over the substep (torque and friction are both
    held). Friction is Karnopp-style:

    * a stopped driven mass (``v1 == 0.0``) stays exactly stopped while the net
      non-friction force on it, ``c tau - k (p1 - p2) + d v2`` (``c tau - k p1`` for
      a mass-spring-damper), has magnitude ``<= c Fs``; the load mass meanwhile keeps
      moving, integrated exactly with ``p1`` fixed;
    * above ``c Fs`` it breaks away against a friction of ``Fs``;
    * a moving mass whose velocity would reach or cross zero within a substep stops
      at ``v1 = 0.0`` if the net non-friction force at the end of the substep is
      within breakaway, so it never chatters around zero. The stop position is the
      end of that substep (error of order ``h**2`` times the deceleration).

    With a position-dependent coupling, :meth:`step` takes ``k`` and ``d`` at ``p1``
    at the start of the step, snapped to geometric grids of ratio
    ``1 + coupling_tolerance`` (``1 + damping_tolerance``) anchored at their values
    at ``p1 = 0`` (so a constant curve gives its value exactly), and keeps the step
    matrices of each grid point it has met. It looks again only once ``p1`` has
    moved far enough for ``k`` or ``d`` to change by half its tolerance
    (:meth:`PositionCurve.still_radius_m`), so a cart held at one position costs
    what a constant coupling costs. The ``k`` in use is then within
    ``coupling_tolerance`` of ``k(p1)`` (a mode frequency within half of it), the
    ``d`` within ``damping_tolerance`` of ``d(p1)``.

    Examples
    --------
    >>> p = Plant(TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0))
    >>> p.step(1.0, 1e-3)     # 1 N·m for 1 ms: 20 substeps of 50 us
    >>> p.v1 > 0.0
    True
    """

    def __init__(
        self,
        model: Model,
        friction: StribeckFriction | None = None,
        max_substep_s: float = 1.0 / 20000.0,
        backlash_m: float = 0.0,
        stiffness: PositionCurve | None = None,
        damping: PositionCurve | None = None,
        coupling_tolerance: float = COUPLING_TOLERANCE,
        damping_tolerance: float = DAMPING_TOLERANCE,
    ):
        if not isinstance(model, (TwoMass, ThreeMass, MassSpringDamper)):
            raise TypeError(f"model must be TwoMass, ThreeMass or MassSpringDamper, got {type(model).__name__}")
        if friction is not None and not isinstance(friction, StribeckFriction):
            raise TypeError(f"friction must be StribeckFriction or None, got {type(friction).__name__}")
        try:
            h = float(max_substep_s)
        except (TypeError, ValueError):
            raise ConfigError("max_substep_s", f"must be a number, got {max_substep_s!r}") from None
        if not (math.isfinite(h) and h > 0.0):
            raise ConfigError("max_substep_s", f"must be > 0 and finite, got {max_substep_s!r}")
        try:
            gap = float(backlash_m)
        except (TypeError, ValueError):
            raise ConfigError("backlash_m", f"must be a number, got {backlash_m!r}") from None
        if not (math.isfinite(gap) and gap >= 0.0):
            raise ConfigError("backlash_m", f"must be >= 0 and finite, got {backlash_m!r}")
        if gap and isinstance(model, MassSpringDamper):
            raise ConfigError("backlash_m", "needs a coupling between two masses (two_mass or three_mass)")
        self.model = model
        self.friction = friction
        self.max_substep_s = h
        self.backlash_m = gap
        self._c = model.c
        self._mirror = isinstance(model, MassSpringDamper)
        self._chain = isinstance(model, ThreeMass)
        self._general = self._chain or gap > 0.0
        # The first coupling (cart to load) of a two- or three-mass chain; None for a single mass.
        self._coupling: TwoMass | ThreeMass | None
        if isinstance(model, MassSpringDamper):
            # Embed y'' into the 4-state form with a frozen second half; p2/v2 are
            # copied from p1/v1 after every step.
            a, b = state_matrices(model)
            A = np.zeros((4, 4))
            A[:2, :2] = a
            B = np.zeros(4)
            B[:2] = b
            mass = load_mass = model.m
            self._coupling = None
        else:
            A, B = state_matrices(model)
            mass, load_mass = model.m1, model.m2
            self._coupling = model
        self._driven_mass = mass  # kg, the mass the drive pushes and friction holds
        self._load_mass = load_mass  # kg, the mass a load disturbance pushes
        self._A = A
        self._B = B
        # Net non-friction force on the stopped driven mass (v1 = 0), besides c*tau:
        # f0*p1 + f2*p2 + f3*v2 (the third mass, if any, does not touch the first).
        self._fstick = (mass * A[1, 0], mass * A[1, 2], mass * A[1, 3])
        self._x3 = np.zeros(2)  # p3, v3 of a ThreeMass
        if friction is None:
            self._fr = None
        else:
            self._fr = (friction.Fc, friction.Fs, friction.Fv, friction.vs, friction.delta_v, friction.delta_s)
        self._cache: dict[float, tuple] = {}
        self._laws = self._position_laws(stiffness, damping, coupling_tolerance, damping_tolerance)
        self.reset()

    # -- position-dependent coupling ---------------------------------------------

    def _position_laws(self, stiffness, damping, k_tolerance, d_tolerance) -> tuple | None:
        """``(k curve, d curve, k anchor, d anchor, k log grid ratio, d log grid ratio)``, or None for a
        constant coupling."""
        if stiffness is None and damping is None:
            return None
        for name, curve in (("stiffness", stiffness), ("damping", damping)):
            if curve is not None and not isinstance(curve, PositionCurve):
                raise TypeError(f"{name} must be a PositionCurve or None, got {type(curve).__name__}")
        model = self._coupling
        if model is None:
            raise ConfigError(
                "k", "a function of the cart position needs a coupling between two masses (two_mass or three_mass)"
            )
        k_tol = _tolerance("coupling_tolerance", k_tolerance)
        d_tol = _tolerance("damping_tolerance", d_tolerance)
        k_of = stiffness if stiffness is not None else PositionCurve.constant(model.k)
        d_of = damping if damping is not None else PositionCurve.constant(model.d)
        k_ref, d_ref = k_of(0.0), d_of(0.0)
        if not (k_ref > 0.0 and d_ref >= 0.0):
            raise ConfigError(
                "k", f"the coupling at p1 = 0 must have k > 0 and d >= 0, got k = {k_ref!r}, d = {d_ref!r}"
            )
        self._coupling_radius_m = min(k_of.still_radius_m(k_tol), d_of.still_radius_m(d_tol))
        self._couplings: dict[tuple[float, float], tuple] = {}
        self._coupling_key: tuple[float, float] | None = None
        self._coupling_at_m = math.nan
        return (k_of, d_of, k_ref, d_ref if d_ref > 0.0 else 1.0, math.log1p(k_tol), math.log1p(d_tol))

    def coupling_at(self, position_m: float) -> tuple[float, float]:
        """The first coupling's exact ``(k, d)`` (N/m, N·s/m) with the cart at ``position_m``."""
        if self._laws is None:
            m = self._coupling
            if m is None:
                raise ValueError("a mass-spring-damper has no coupling")
            return m.k, m.d
        return self._laws[0](float(position_m)), self._laws[1](float(position_m))

    def modes_at(self, position_m: float) -> list[tuple[float, float]]:
        """:func:`modes` of the frictionless plant with the cart held at ``position_m`` (m): the truth."""
        if self._laws is None:
            return modes(self.model)
        k, d = self.coupling_at(position_m)
        return modes(dataclasses.replace(self.model, k=k, d=d))  # type: ignore[arg-type]  # never a single mass

    @property
    def coupling(self) -> tuple[float, float] | None:
        """The ``(k, d)`` the step matrices use now (snapped to the grid), None for a single mass."""
        m = self._coupling
        return None if m is None else (m.k, m.d)

    def _follow_position(self, p1: float) -> None:
        """Take the coupling at ``p1``, snapped to its grids; switch step matrices if that changed it."""
        k_of, d_of, k_ref, d_ref, k_ratio, d_ratio = self._laws  # type: ignore[misc]
        self._coupling_at_m = p1
        key = (_snap(k_of(p1), k_ref, k_ratio), _snap(d_of(p1), d_ref, d_ratio))
        if key == self._coupling_key:
            return
        self._coupling_key = key
        found = self._couplings.get(key)
        if found is None:
            if len(self._couplings) >= _COUPLING_CACHE_LIMIT:
                self._couplings.clear()
            coupling = dataclasses.replace(self.model, k=key[0], d=key[1])  # type: ignore[arg-type]
            A, _ = state_matrices(coupling)
            mass = self._driven_mass
            found = (coupling, A, (mass * A[1, 0], mass * A[1, 2], mass * A[1, 3]), {})
            self._couplings[key] = found
        self._coupling, self._A, self._fstick, self._cache = found

    # -- state ------------------------------------------------------------------

    def reset(self, p1: float = 0.0, v1: float = 0.0, p2: float | None = None, v2: float | None = None) -> None:
        """Set the state; ``p2``/``v2`` default to ``p1``/``v1`` (undeflected coupling).

        For a mass-spring-damper ``p2``/``v2`` are ignored and mirror ``p1``/``v1``.
        """
        vals = [p1, v1, p1 if p2 is None else p2, v1 if v2 is None else v2]
        for name, v in zip(("p1", "v1", "p2", "v2"), vals, strict=True):
            if not math.isfinite(float(v)):
                raise ValueError(f"{name} must be finite, got {v!r}")
        self.p1, self.v1, self.p2, self.v2 = (float(v) for v in vals)
        if self._mirror:
            self.p2, self.v2 = self.p1, self.v1
        self._x3 = np.array([self.p2, self.v2])  # a third mass starts undeflected from the load
        if self._laws is not None:
            self._follow_position(self.p1)

    @property
    def state(self) -> tuple[float, float, float, float]:
        """The exact state ``(p1, v1, p2, v2)``."""
        return (self.p1, self.v1, self.p2, self.v2)

    @property
    def stuck(self) -> bool:
        """True while friction holds the driven mass (``v1 == 0.0`` with friction)."""
        return self._fr is not None and self.v1 == 0.0

    def push_load(self, force_n: float, dt_s: float) -> None:
        """Apply ``force_n`` on the load mass for ``dt_s`` as one impulse (a disturbance, not a drive input).

        The load's velocity jumps by ``force_n * dt_s / m2`` (the single mass's,
        by ``/ m``, for a mass-spring-damper). Exact enough for noise whose
        spectrum lies far below ``1 / dt_s``.
        """
        if self._mirror:
            self.v1 += force_n * dt_s / self._load_mass
            self.v2 = self.v1
        else:
            self.v2 += force_n * dt_s / self._load_mass

    # -- integration -------------------------------------------------------------

    def substeps(self, dt_s: float) -> int:
        """Number of equal substeps :meth:`step` uses for ``dt_s``."""
        return max(1, math.ceil(dt_s / self.max_substep_s * (1.0 - 1e-12)))

    def _prepare(self, dt_s: float) -> tuple:
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s must be > 0 and finite, got {dt_s!r}")
        n = self.substeps(dt_s)
        h = dt_s / n
        M = np.zeros((5, 5))
        M[:4, :4] = self._A
        M[:4, 4] = self._B
        E = expm(M * h)
        phi = E[:4, :4]
        gam = E[:4, 4]
        # Load mass alone with p1 fixed and v1 = 0: [p2, v2]' = A22 [p2, v2] + A[2:, 0] p1.
        M3 = np.zeros((3, 3))
        M3[:2, :2] = self._A[2:, 2:]
        M3[:2, 2] = self._A[2:, 0]
        E3 = expm(M3 * h)
        entry = (n, *phi.ravel().tolist(), *gam.tolist(), *E3[:2, :2].ravel().tolist(), *E3[:2, 2].tolist())
        if len(self._cache) >= _CACHE_LIMIT:
            self._cache.clear()
        self._cache[dt_s] = entry
        return entry

    def _regime_matrices(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(A, w)`` per coupling regime: ``x' = A x + B u + w``.

        Without backlash one regime. With it three: the first coupling in contact on
        the positive side (its spring force is ``k (e - g)``, ``e = p1 - p2``, ``g`` half
        the gap: the linear ``A`` plus a constant ``w``), in the gap (no spring or
        damper force), in contact on the negative side.
        """
        A = self._A
        if self.backlash_m == 0.0:
            return [(A, np.zeros(A.shape[0]))]
        m = self._coupling
        assert m is not None, "the constructor refuses backlash without a coupling"
        k, d, g = m.k, m.d, 0.5 * self.backlash_m
        coupling = np.zeros_like(A)  # the first spring and damper's part of A (p1, v1, p2, v2 are states 0-3)
        coupling[1, :4] = [-k / m.m1, -d / m.m1, k / m.m1, d / m.m1]
        coupling[3, :4] = [k / m.m2, d / m.m2, -k / m.m2, -d / m.m2]
        w = np.zeros(A.shape[0])
        w[1], w[3] = k * g / m.m1, -k * g / m.m2
        return [(A, w), (A - coupling, np.zeros(A.shape[0])), (A, -w)]

    def _prepare_general(self, dt_s: float) -> tuple:
        """Substep matrices per regime: the whole state, and the state with the cart held."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s must be > 0 and finite, got {dt_s!r}")
        n = self.substeps(dt_s)
        h = dt_s / n
        nx = self._A.shape[0]
        mass = self._driven_mass
        regimes = []
        for A, w in self._regime_matrices():
            M = np.zeros((nx + 2, nx + 2))
            M[:nx, :nx] = A
            M[:nx, nx] = self._B
            M[:nx, nx + 1] = w
            E = expm(M * h)
            # States 2.. with p1 fixed and v1 = 0: x_r' = A_rr x_r + A[2:, 0] p1 + w[2:].
            Ms = np.zeros((nx, nx))
            Ms[: nx - 2, : nx - 2] = A[2:, 2:]
            Ms[: nx - 2, nx - 2] = A[2:, 0]
            Ms[: nx - 2, nx - 1] = w[2:]
            Es = expm(Ms * h)
            regimes.append(
                (
                    E[:nx, :nx],
                    E[:nx, nx],
                    E[:nx, nx + 1],
                    Es[: nx - 2, : nx - 2],
                    Es[: nx - 2, nx - 2],
                    Es[: nx - 2, nx - 1],
                    mass * A[1],
                    mass * w[1],
                )
            )
        entry = (n, regimes)
        if len(self._cache) >= _CACHE_LIMIT:
            self._cache.clear()
        self._cache[dt_s] = entry
        return entry

    def _step_general(self, tau: float, dt_s: float) -> None:
        """:meth:`step` with matrix products: a ThreeMass, or backlash in the first coupling.

        The same Karnopp friction on the cart; with backlash the regime (contact on
        either side, or in the gap) is taken at each substep's start.
        """
        entry = self._cache.get(dt_s)
        if entry is None:
            entry = self._prepare_general(dt_s)
        n, regimes = entry
        if not math.isfinite(tau):
            raise ValueError(f"torque_nm must be finite, got {tau!r}")
        ctau = self._c * tau
        x = np.array([self.p1, self.v1, self.p2, self.v2, *(self._x3 if self._chain else ())])
        half_gap = 0.5 * self.backlash_m
        fr = self._fr
        for _ in range(n):
            if len(regimes) == 1:
                r = regimes[0]
            else:
                e = x[0] - x[2]
                r = regimes[0] if e > half_gap else (regimes[2] if e < -half_gap else regimes[1])
            phi, gam, off, stuck_phi, stuck_gam, stuck_off, force_row, force_off = r
            if fr is None:
                x = phi @ x + gam * ctau + off
                continue
            Fc, Fs, Fv, vs, dv, ds = fr
            brk = self._c * Fs
            v1 = x[1]
            if v1 == 0.0:
                fnet = ctau + float(force_row @ x) + force_off
                if -brk <= fnet <= brk:
                    x[2:] = stuck_phi @ x[2:] + stuck_gam * x[0] + stuck_off
                    continue
                x = phi @ x + gam * (ctau - brk if fnet > 0.0 else ctau + brk) + off
                continue
            a = abs(v1)
            ffr = self._c * (Fc + (Fs - Fc) * math.exp(-((a / vs) ** ds)) + Fv * a**dv)
            nxt = phi @ x + gam * (ctau - ffr if v1 > 0.0 else ctau + ffr) + off
            if nxt[1] == 0.0 or (nxt[1] > 0.0) != (v1 > 0.0):
                held = np.concatenate(([nxt[0], 0.0], nxt[2:]))
                if -brk <= ctau + float(force_row @ held) + force_off <= brk:
                    nxt[1] = 0.0
            x = nxt
        self.p1, self.v1, self.p2, self.v2 = (float(v) for v in x[:4])
        if self._chain:
            self._x3 = x[4:].copy()

    def step(self, torque_nm: float, dt_s: float) -> None:
        """Advance the state by ``dt_s`` seconds with ``torque_nm`` held constant.

        Parameters
        ----------
        torque_nm : float
            Motor torque, N·m.
        dt_s : float
            Time to advance, s; split into ``substeps(dt_s)`` equal substeps.
        """
        if (
            self._laws is not None
            and not -self._coupling_radius_m <= self.p1 - self._coupling_at_m <= self._coupling_radius_m
        ):
            self._follow_position(self.p1)
        if self._general:
            self._step_general(float(torque_nm), dt_s)
            return
        entry = self._cache.get(dt_s)
        if entry is None:
            entry = self._prepare(dt_s)
        (
            n,
            a00,
            a01,
            a02,
            a03,
            a10,
            a11,
            a12,
            a13,
            a20,
            a21,
            a22,
            a23,
            a30,
            a31,
            a32,
            a33,
            g0,
            g1,
            g2,
            g3,
            s00,
            s01,
            s10,
            s11,
            sg0,
            sg1,
        ) = entry
        tau = float(torque_nm)
        if not math.isfinite(tau):
            raise ValueError(f"torque_nm must be finite, got {torque_nm!r}")
        ctau = self._c * tau
        p1, v1, p2, v2 = self.p1, self.v1, self.p2, self.v2
        fr = self._fr
        if fr is None:
            for _ in range(n):
                p1, v1, p2, v2 = (
                    a00 * p1 + a01 * v1 + a02 * p2 + a03 * v2 + g0 * ctau,
                    a10 * p1 + a11 * v1 + a12 * p2 + a13 * v2 + g1 * ctau,
                    a20 * p1 + a21 * v1 + a22 * p2 + a23 * v2 + g2 * ctau,
                    a30 * p1 + a31 * v1 + a32 * p2 + a33 * v2 + g3 * ctau,
                )
        else:
            exp = math.exp
            c = self._c
            Fc, Fs, Fv, vs, dv, ds = fr
            cdF = c * (Fs - Fc)
            cFc = c * Fc
            cFv = c * Fv
            inv_vs = 1.0 / vs
            brk = c * Fs
            f0, f2, f3 = self._fstick
            for _ in range(n):
                if v1 == 0.0:
                    fnet = ctau + f0 * p1 + f2 * p2 + f3 * v2
                    if -brk <= fnet <= brk:
                        # Stuck: friction balances fnet exactly; only the load moves.
                        p2, v2 = (s00 * p2 + s01 * v2 + sg0 * p1, s10 * p2 + s11 * v2 + sg1 * p1)
                        continue
                    u = ctau - brk if fnet > 0.0 else ctau + brk
                    q1 = a00 * p1 + a02 * p2 + a03 * v2 + g0 * u
                    w1 = a10 * p1 + a12 * p2 + a13 * v2 + g1 * u
                    q2 = a20 * p1 + a22 * p2 + a23 * v2 + g2 * u
                    w2 = a30 * p1 + a32 * p2 + a33 * v2 + g3 * u
                    p1, v1, p2, v2 = q1, w1, q2, w2
                    continue
                a = -v1 if v1 < 0.0 else v1
                ffr = cFc + cdF * exp(-((a * inv_vs) ** ds)) + cFv * a**dv
                u = ctau - ffr if v1 > 0.0 else ctau + ffr
                q1 = a00 * p1 + a01 * v1 + a02 * p2 + a03 * v2 + g0 * u
                w1 = a10 * p1 + a11 * v1 + a12 * p2 + a13 * v2 + g1 * u
                q2 = a20 * p1 + a21 * v1 + a22 * p2 + a23 * v2 + g2 * u
                w2 = a30 * p1 + a31 * v1 + a32 * p2 + a33 * v2 + g3 * u
                if w1 == 0.0 or (w1 > 0.0) != (v1 > 0.0):
                    # Velocity reached zero inside the substep: stop unless the
                    # driving force is beyond breakaway.
                    fnet = ctau + f0 * q1 + f2 * q2 + f3 * w2
                    if -brk <= fnet <= brk:
                        w1 = 0.0
                p1, v1, p2, v2 = q1, w1, q2, w2
        if self._mirror:
            p2, v2 = p1, v1
        self.p1, self.v1, self.p2, self.v2 = p1, v1, p2, v2
