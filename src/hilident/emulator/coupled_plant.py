"""One mechanism, several drives: lumped masses on springs and dampers, driven through ports.

:class:`CoupledModel` describes a linear mechanism of ``n`` lumped masses (positions
``q``, m) joined by springs and dampers to each other or to ground::

    M q'' + D q' + K q = F(tau),    F_i = sum over the ports p driving mass i of c_p tau_p

with ``M`` diagonal (kg) and ``K`` (N/m), ``D`` (N·s/m) symmetric, assembled from the
links. Each *port* is one drive: its motor pushes one mass with the force ``c * tau``
(``tau`` its torque, N·m; ``c`` in N/(N·m), as in :class:`~hilident.emulator.plant.TwoMass`),
and its load sensor (the laser) watches one mass. :func:`dual_motor_gantry` builds the
common case, a beam carried on two driven carriages with a load between them;
:func:`single_axis` gives the one-port mechanism of a
:class:`~hilident.emulator.plant.TwoMass` or :class:`~hilident.emulator.plant.ThreeMass`.

The truth: :func:`coupled_modes` (frequency and damping ratio of each non-rigid mode),
:func:`mode_shapes` (each mode's complex shape at the measured masses) and
:func:`coupled_frf` (the exact matrix of responses from every port's torque to the
positions or velocities of the chosen masses).

:class:`CoupledPlant` simulates the mechanism: exact zero-order-hold steps of the
linear system (``scipy.linalg.expm`` of the augmented matrix, cached per step length).
The mechanism is linear: no friction, no backlash and no position-dependent coupling
(those stay with the single-axis :class:`~hilident.emulator.plant.Plant`).
:meth:`CoupledPlant.port` gives each drive a :class:`PlantPort`, which a
:class:`~hilident.emulator.drive.DriveLoop` takes in place of its ``Plant``. Each drive
runs in its own thread; the mechanism advances a tick once every port in the lockstep
has submitted its torque for that tick, so two drives on one mechanism give the same
numbers on every run. A port whose drive stops stepping holds its last torque after
``wait_s`` of wall time and is counted in :attr:`CoupledPlant.held_steps`;
:meth:`PlantPort.detach` takes a port out of the lockstep (its torque is then 0).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, null_space

from hilident.emulator.plant import ThreeMass, TwoMass
from hilident.errors import ConfigError
from hilident.numbers import number

__all__ = [
    "GROUND",
    "WAIT_S",
    "CoupledModel",
    "CoupledPlant",
    "PlantPort",
    "dual_motor_gantry",
    "single_axis",
    "coupled_matrices",
    "coupled_state_matrices",
    "coupled_modes",
    "mode_shapes",
    "coupled_frf",
]

#: The index a link uses for ground (a spring or damper to the frame).
GROUND = -1
#: Default wall time, s, a port waits for its partners before the mechanism advances without them.
WAIT_S = 0.05
# Step matrices kept per step length; more distinct lengths than this is a caller sweeping dt.
_CACHE_LIMIT = 64


# -- the model ---------------------------------------------------------------------------


def _index(key: str, value, n: int, ground: bool = False) -> int:
    """``value`` as a mass index below ``n`` (or :data:`GROUND` when ``ground``)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ConfigError(key, f"must be a mass index (int), got {value!r}")
    i = int(value)
    if not (0 <= i < n or (ground and i == GROUND)):
        where = f"0..{n - 1}" + (f" or {GROUND} (ground)" if ground else "")
        raise ConfigError(key, f"must be {where}, got {value!r}")
    return i


def _entries(key: str, value, size: int) -> list:
    """``value`` as a list of sequences of ``size`` items each."""
    if isinstance(value, str | bytes) or not isinstance(value, Sequence):
        raise ConfigError(key, f"must be a list, got {value!r}")
    for j, entry in enumerate(value):
        if isinstance(entry, str | bytes) or not isinstance(entry, Sequence) or len(entry) != size:
            raise ConfigError(f"{key}[{j}]", f"must be a sequence of {size} items, got {entry!r}")
    return list(value)


def _masses(value) -> tuple[float, ...]:
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) == 0:
        raise ConfigError("masses", f"must be a non-empty list of masses (kg), got {value!r}")
    return tuple(number(f"masses[{i}]", m, strict=True) for i, m in enumerate(value))


def _links(value, n: int) -> tuple[tuple[int, int, float, float], ...]:
    out = []
    for j, (a, b, k, d) in enumerate(_entries("links", value, 4)):
        key = f"links[{j}]"
        i1, i2 = _index(f"{key}.i", a, n), _index(f"{key}.j", b, n, ground=True)
        if i1 == i2:
            raise ConfigError(f"{key}.j", f"must differ from i (a link joins two masses), got {b!r}")
        kk, dd = number(f"{key}.k", k), number(f"{key}.d", d)
        if kk == 0.0 and dd == 0.0:
            raise ConfigError(key, "has k = 0 and d = 0: it joins nothing")
        out.append((i1, i2, kk, dd))
    return tuple(out)


def _motors(value, n: int) -> tuple[tuple[int, float], ...]:
    entries = _entries("motors", value, 2)
    if not entries:
        raise ConfigError("motors", "must name at least one motor (one per drive port)")
    return tuple(
        (_index(f"motors[{p}].mass", i, n), number(f"motors[{p}].c", c, strict=True))
        for p, (i, c) in enumerate(entries)
    )


def _sensors(value, n: int, n_ports: int) -> tuple[int, ...]:
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) != n_ports:
        raise ConfigError("sensors", f"must name one mass per port ({n_ports}), got {value!r}")
    return tuple(_index(f"sensors[{p}]", i, n) for p, i in enumerate(value))


@dataclass(frozen=True)
class CoupledModel:
    """A linear mechanism of lumped masses driven through one or more ports.

    Parameters
    ----------
    masses : sequence of float
        Mass of each lumped body, kg (> 0). Body ``i`` has position ``q[i]``, m.
    links : sequence of (i, j, k, d)
        Springs and dampers: ``k`` (N/m, >= 0) and ``d`` (N·s/m, >= 0) between mass ``i``
        and mass ``j``, or ground for ``j == GROUND`` (-1). Not both 0.
    motors : sequence of (mass, c)
        One per drive port, in port order: the mass the motor pushes and its
        torque-to-force constant ``c``, N/(N·m) (> 0); the force is ``c * tau``.
    sensors : sequence of int
        One per port: the mass that port's load sensor (laser) watches (its ``p2``).

    Raises
    ------
    ConfigError
        Naming the field (``masses[1]``, ``links[0].k``, ``motors[1].mass``, ...).

    Examples
    --------
    >>> m = CoupledModel(masses=[8.0, 2.0], links=[(0, 1, 8e4, 20.0)], motors=[(0, 10.0)], sensors=[1])
    >>> m.n_masses, m.n_ports, m.motor_masses, m.sensor_masses
    (2, 1, (0,), (1,))
    """

    masses: tuple[float, ...]
    links: tuple[tuple[int, int, float, float], ...]
    motors: tuple[tuple[int, float], ...]
    sensors: tuple[int, ...]

    def __post_init__(self):
        masses = _masses(self.masses)
        n = len(masses)
        motors = _motors(self.motors, n)
        object.__setattr__(self, "masses", masses)
        object.__setattr__(self, "links", _links(self.links, n))
        object.__setattr__(self, "motors", motors)
        object.__setattr__(self, "sensors", _sensors(self.sensors, n, len(motors)))

    @property
    def n_masses(self) -> int:
        """Number of lumped masses."""
        return len(self.masses)

    @property
    def n_ports(self) -> int:
        """Number of drive ports (motors)."""
        return len(self.motors)

    @property
    def motor_masses(self) -> tuple[int, ...]:
        """The mass each port's motor pushes (its ``p1``), in port order."""
        return tuple(i for i, _ in self.motors)

    @property
    def sensor_masses(self) -> tuple[int, ...]:
        """The mass each port's load sensor watches (its ``p2``), in port order."""
        return self.sensors


def dual_motor_gantry(
    m_left: float,
    m_right: float,
    m_load: float,
    k_left: float,
    k_right: float,
    d_left: float,
    d_right: float,
    c: float = 1.0,
    *,
    k_beam: float = 0.0,
    d_beam: float = 0.0,
) -> CoupledModel:
    """A gantry whose beam is driven at both ends: two carriages, one motor each, the load between them.

    Masses: 0 the left carriage (port 0's motor), 1 the right carriage (port 1's
    motor), 2 the load (beam and tool, watched by both ports' lasers). The load hangs
    between the carriages on the beam's two halves, ``k_left``/``d_left`` and
    ``k_right``/``d_right``; ``k_beam``/``d_beam`` optionally join the two carriages
    directly (the beam's own stiffness between its ends). No link to
    ground: the whole gantry moves freely along its rails (one rigid-body motion).

    With equal sides (``m``, ``k``, ``d``; no beam link) the two modes are the
    racking mode, carriages opposite and the load still, at ``sqrt(k / m) / (2 pi)``,
    and the load swinging against both carriages at ``sqrt(k / m + 2 k / m_load) / (2 pi)``.

    Parameters
    ----------
    m_left, m_right, m_load : float
        Masses, kg.
    k_left, k_right : float
        Stiffness between each carriage and the load, N/m.
    d_left, d_right : float
        Damping of those couplings, N·s/m.
    c : float
        Torque-to-force constant of both motors, N/(N·m).
    k_beam, d_beam : float
        Stiffness (N/m) and damping (N·s/m) directly between the carriages; 0 for none.

    Returns
    -------
    CoupledModel
        Two ports: 0 drives the left carriage, 1 the right one; both lasers watch the load.

    Examples
    --------
    >>> g = dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 2e5, 40.0, 40.0, c=10.0)
    >>> [(round(f, 2), round(z, 4)) for f, z in coupled_modes(g)]
    [(15.92, 0.01), (35.59, 0.0224)]
    """
    values = {
        "m_left": number("m_left", m_left, strict=True),
        "m_right": number("m_right", m_right, strict=True),
        "m_load": number("m_load", m_load, strict=True),
        "k_left": number("k_left", k_left, strict=True),
        "k_right": number("k_right", k_right, strict=True),
        "d_left": number("d_left", d_left),
        "d_right": number("d_right", d_right),
        "c": number("c", c, strict=True),
        "k_beam": number("k_beam", k_beam),
        "d_beam": number("d_beam", d_beam),
    }
    v = values
    links = [(0, 2, v["k_left"], v["d_left"]), (1, 2, v["k_right"], v["d_right"])]
    if v["k_beam"] or v["d_beam"]:
        links.append((0, 1, v["k_beam"], v["d_beam"]))
    return CoupledModel(
        masses=(v["m_left"], v["m_right"], v["m_load"]),
        links=tuple(links),
        motors=((0, v["c"]), (1, v["c"])),
        sensors=(2, 2),
    )


def single_axis(model: TwoMass | ThreeMass) -> CoupledModel:
    """The one-port mechanism of a two- or three-mass axis (its motor on ``m1``, its laser on ``m2``).

    Parameters
    ----------
    model : TwoMass or ThreeMass

    Returns
    -------
    CoupledModel
        Masses in the chain's order; :func:`coupled_modes` equals
        :func:`~hilident.emulator.plant.modes` of ``model``.
    """
    if isinstance(model, TwoMass):
        return CoupledModel((model.m1, model.m2), ((0, 1, model.k, model.d),), ((0, model.c),), (1,))
    if isinstance(model, ThreeMass):
        links = ((0, 1, model.k, model.d), (1, 2, model.k2, model.d2))
        return CoupledModel((model.m1, model.m2, model.m3), links, ((0, model.c),), (1,))
    raise TypeError(f"model must be a TwoMass or ThreeMass, got {type(model).__name__}")


# -- the truth ---------------------------------------------------------------------------


def coupled_matrices(model: CoupledModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mass, damping, stiffness and force-input matrices of the mechanism.

    Returns
    -------
    M : ndarray, shape (n, n)
        Diagonal mass matrix, kg.
    D : ndarray, shape (n, n)
        Damping matrix, N·s/m (symmetric).
    K : ndarray, shape (n, n)
        Stiffness matrix, N/m (symmetric).
    F : ndarray, shape (n, n_ports)
        Force on each mass per N·m of each port's torque, N/(N·m).
    """
    n = model.n_masses
    K = np.zeros((n, n))
    D = np.zeros((n, n))
    for i, j, k, d in model.links:
        for mat, value in ((K, k), (D, d)):
            mat[i, i] += value
            if j != GROUND:
                mat[j, j] += value
                mat[i, j] -= value
                mat[j, i] -= value
    F = np.zeros((n, model.n_ports))
    for p, (i, c) in enumerate(model.motors):
        F[i, p] = c
    return np.diag(model.masses), D, K, F


def coupled_state_matrices(model: CoupledModel) -> tuple[np.ndarray, np.ndarray]:
    """State matrix ``A`` and torque input matrix ``B`` of the mechanism: ``x' = A x + B tau``.

    Returns
    -------
    A : ndarray, shape (2 n, 2 n)
        States interleaved as :func:`~hilident.emulator.plant.state_matrices` orders a
        chain: ``(q0, v0, q1, v1, ...)``, positions m, velocities m/s.
    B : ndarray, shape (2 n, n_ports)
        Per N·m of each port's torque, (m/s^2)/(N·m) on the velocity rows.
    """
    M, D, K, F = coupled_matrices(model)
    n = model.n_masses
    inv_m = 1.0 / np.diag(M)
    A = np.zeros((2 * n, 2 * n))
    A[0::2, 1::2] = np.eye(n)
    A[1::2, 0::2] = -inv_m[:, None] * K
    A[1::2, 1::2] = -inv_m[:, None] * D
    B = np.zeros((2 * n, model.n_ports))
    B[1::2, :] = inv_m[:, None] * F
    return A, B


def _flexible(model: CoupledModel) -> tuple[np.ndarray, np.ndarray]:
    """``(T, A_e)``: the mechanism with its rigid-body motions removed.

    The rigid-body motions are the displacements ``u`` with ``K u = 0`` and ``D u = 0``
    (basis ``R``). The flexible coordinates ``e`` span the mass-orthogonal complement,
    ``q = T e`` with ``T' M R = 0``: then ``T' M T e'' + T' D T e' + T' K T e = T' F``
    decouples exactly from the rigid motion, and the eigenvalues of its state matrix
    ``A_e`` (states ``(e, e')``) are the non-zero eigenvalues of the full one without
    the ill-conditioned defective zeros of the free motion.
    """
    M, D, K, _ = coupled_matrices(model)
    n = model.n_masses
    scaled = [X / np.abs(X).max() for X in (K, D) if np.any(X)]
    R = null_space(np.vstack(scaled)) if scaled else np.eye(n)
    T = null_space(R.T @ M) if R.shape[1] else np.eye(n)
    m = T.shape[1]
    Me_inv = np.linalg.inv(T.T @ M @ T)
    A = np.zeros((2 * m, 2 * m))
    A[:m, m:] = np.eye(m)
    A[m:, :m] = -Me_inv @ (T.T @ K @ T)
    A[m:, m:] = -Me_inv @ (T.T @ D @ T)
    return T, A


def _modal(model: CoupledModel) -> list[tuple[float, float, np.ndarray]]:
    """``(frequency_hz, damping_ratio, shape over all masses)`` of each non-rigid mode, slowest first."""
    T, A = _flexible(model)
    m = T.shape[1]
    if m == 0:
        return []
    lam, V = np.linalg.eig(A)
    floor = 1e-9 * float(np.abs(lam).max())  # the zeros of masses held only by dampers
    found = []
    for z, v in zip(lam, V.T, strict=True):
        if z.imag > 0.0 and abs(z) > floor:
            found.append((abs(z), -z.real / abs(z), T @ v[:m]))
    real = sorted(
        (k for k in range(lam.size) if lam[k].imag == 0.0 and abs(lam[k]) > floor), key=lambda k: -lam[k].real
    )
    for a, b in zip(real[0::2], real[1::2], strict=False):  # an overdamped pair: the slower one's shape
        la, lb = lam[a].real, lam[b].real
        w = math.sqrt(la * lb)
        found.append((w, -(la + lb) / (2.0 * w), T @ V[:m, a]))
    out = []
    for w, zeta, q in sorted(found, key=lambda mode: mode[0]):
        q = np.asarray(q, dtype=complex)
        size = np.abs(q)
        first = int(np.argmax(size >= (1.0 - 1e-9) * size.max()))  # of entries equal but for rounding, the first
        out.append((float(w) / (2.0 * math.pi), float(zeta) + 0.0, q / q[first]))
    return out


def coupled_modes(model: CoupledModel) -> list[tuple[float, float]]:
    """Vibration modes of the mechanism.

    Parameters
    ----------
    model : CoupledModel

    Returns
    -------
    list of (frequency_hz, damping_ratio)
        Slowest first. ``frequency_hz`` is ``|lambda| / (2 pi)`` of an eigenvalue pair
        ``lambda`` of the state matrix, ``damping_ratio`` is ``-Re(lambda) / |lambda|``
        (an overdamped pair of real eigenvalues ``l1, l2``, paired in order of size,
        gives ``sqrt(l1 l2)`` and ``-(l1 + l2) / (2 sqrt(l1 l2))``), as
        :func:`~hilident.emulator.plant.modes` reports them. Rigid-body motions (zero
        eigenvalues) are left out, as is the single real eigenvalue of a mass held
        only by a damper.

    Examples
    --------
    >>> g = dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 2e5, 0.0, 0.0)
    >>> [(round(f, 3), round(z, 9)) for f, z in coupled_modes(g)]
    [(15.915, 0.0), (35.588, 0.0)]
    """
    return [(f, z) for f, z, _ in _modal(model)]


def _output_masses(model: CoupledModel, outputs) -> tuple[int, ...]:
    """The mass indices ``outputs`` names: "motor", "load", "both" (motors, then loads) or indices."""
    named = {
        "motor": model.motor_masses,
        "load": model.sensor_masses,
        "both": model.motor_masses + model.sensor_masses,
    }
    if isinstance(outputs, str):
        if outputs not in named:
            raise ValueError(f"outputs must be one of {tuple(named)} or mass indices, got {outputs!r}")
        return named[outputs]
    try:
        return tuple(_index("outputs", i, model.n_masses) for i in outputs)
    except ConfigError as exc:
        raise ValueError(str(exc)) from None


def mode_shapes(model: CoupledModel, outputs: str | Sequence[int] = "both") -> np.ndarray:
    """Complex shape of each mode at the measured masses.

    Parameters
    ----------
    model : CoupledModel
    outputs : {"both", "motor", "load"} or sequence of int
        The masses: each port's motor mass (``"motor"``), each port's laser mass
        (``"load"``), both (motors first, then loads, in port order), or mass indices.

    Returns
    -------
    ndarray of complex, shape (n_modes, n_outputs)
        Row ``r`` belongs to mode ``r`` of :func:`coupled_modes`: the position
        eigenvector of the state matrix (m per unit of modal amplitude), scaled so that
        its largest entry over all masses is exactly 1. Entries in phase (or opposite)
        move together (against each other); a lightly damped mode's shape is nearly
        real. The shape of an overdamped pair is the slower eigenvalue's; modes of
        equal frequency have shapes fixed only up to their common subspace.

    Examples
    --------
    >>> g = dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 2e5, 40.0, 40.0)
    >>> np.round(mode_shapes(g).real, 3) + 0.0  # racking, then the load against both carriages
    array([[ 1.  , -1.  ,  0.  ,  0.  ],
           [-0.25, -0.25,  1.  ,  1.  ]])
    """
    idx = list(_output_masses(model, outputs))
    modal = _modal(model)
    out = np.zeros((len(modal), len(idx)), dtype=complex)
    for r, (_, _, q) in enumerate(modal):
        out[r] = q[idx]
    return out


_FRF_OUTPUTS = ("position", "velocity")


def coupled_frf(
    model: CoupledModel, frequency_hz, output: str = "position", outputs: str | Sequence[int] = "motor"
) -> np.ndarray:
    """Exact frequency response from every port's motor torque to the chosen positions or velocities.

    Parameters
    ----------
    model : CoupledModel
    frequency_hz : array_like
        Frequencies, Hz. A mechanism free to move as a whole (or a mass held only by
        a damper) responds infinitely at 0 Hz.
    output : {"position", "velocity"}
        Position in m/(N·m) or velocity in (m/s)/(N·m).
    outputs : {"motor", "load", "both"} or sequence of int
        The rows, as :func:`mode_shapes` takes them: by default each port's motor
        mass (its ``p1``), giving the square ``n_ports x n_ports`` matrix.

    Returns
    -------
    ndarray of complex, shape ``np.shape(frequency_hz) + (n_outputs, n_ports)``
        Entry ``[..., r, p]`` is the response of output ``r`` to port ``p``'s torque.

    Examples
    --------
    >>> g = dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 2e5, 40.0, 40.0, c=10.0)
    >>> coupled_frf(g, [5.0, 50.0]).shape
    (2, 2, 2)
    """
    if output not in _FRF_OUTPUTS:
        raise ValueError(f"output must be one of {_FRF_OUTPUTS}, got {output!r}")
    idx = list(_output_masses(model, outputs))
    M, D, K, F = coupled_matrices(model)
    f = np.asarray(frequency_hz, dtype=float)
    s = (2j * np.pi * f).ravel()
    h = np.full((s.size, len(idx), model.n_ports), np.inf + 0j)
    finite = s != 0.0
    if np.linalg.matrix_rank(K) == model.n_masses:
        finite[:] = True
    Z = M * (s[finite] ** 2)[:, None, None] + D * s[finite][:, None, None] + K
    x = np.linalg.solve(Z, np.broadcast_to(F.astype(complex), (Z.shape[0], *F.shape)))
    h[finite] = x[:, idx, :]
    if output == "velocity":
        with np.errstate(invalid="ignore"):
            h = h * s[:, None, None]
    return h.reshape(f.shape + h.shape[1:])


# -- the simulated mechanism -----------------------------------------------------------------


class CoupledPlant:
    """The mechanism of a :class:`CoupledModel`, stepped exactly, shared by the drives on its ports.

    Parameters
    ----------
    model : CoupledModel
    wait_s : float
        Wall time, s, a port's :meth:`PlantPort.step` waits for the other ports in the
        lockstep before the mechanism advances without them (their last torque held).

    Attributes
    ----------
    held_steps : list of int
        Per port: ticks the mechanism advanced with that port's torque held because it
        was in the lockstep but did not submit one in time.
    ticks : int
        Ticks the mechanism has advanced.
    time_s : float
        Simulated time, s: the sum of the ticks' lengths.

    Notes
    -----
    Each tick is exact for torques held over it (zero-order hold):
    ``x+ = Phi x + Gamma tau`` with ``Phi = expm(A dt)`` and
    ``Gamma = int_0^dt expm(A s) B ds`` from one matrix exponential of the augmented
    matrix, kept per ``dt``. No substeps: the mechanism is linear (no friction).

    **Lockstep.** A port joins the lockstep when :meth:`port` hands it out (or, after
    :meth:`PlantPort.detach`, at its next step). Its :meth:`PlantPort.step` submits the
    torque for the current tick and returns once the mechanism has advanced by that
    tick: as soon as every port in the lockstep has submitted, the last one to submit
    advances it. So each drive's next reading sees the state after the tick all drives
    acted in, and the result does not depend on the threads' timing. A port that has
    not submitted ``wait_s`` after another one did is *held*: the tick runs with its
    last torque, :attr:`held_steps` counts it, and later ticks no longer wait for it
    until it submits again (it rejoins with the tick then pending). A held port makes a
    run depend on timing; ``wait_s`` should be far above the scheduling delays of the
    machine. :meth:`PlantPort.detach` leaves the lockstep at once: the port's torque is
    0 and nothing waits for it or counts it. All ports of one tick must step by the
    same ``dt_s``.

    A load push (:meth:`PlantPort.push_load`) is kept until the tick it belongs to and
    applied at that tick's start, the ports' pushes in port order.

    Examples
    --------
    >>> plant = CoupledPlant(dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 2e5, 40.0, 40.0, c=10.0))
    >>> plant.step([1.0, 1.0], 1e-3)  # the whole mechanism, from one thread
    >>> bool(plant.velocities[0] > 0.0), plant.ticks
    (True, 1)
    """

    def __init__(self, model: CoupledModel, wait_s: float = WAIT_S):
        if not isinstance(model, CoupledModel):
            raise TypeError(f"model must be a CoupledModel, got {type(model).__name__}")
        self.model = model
        self.wait_s = number("wait_s", wait_s, strict=True)
        self._A, self._B = coupled_state_matrices(model)
        n_ports = model.n_ports
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._cond = threading.Condition(threading.Lock())
        self._ports: list[PlantPort | None] = [None] * n_ports
        self._attached = [False] * n_ports  # in the lockstep
        self._held = [False] * n_ports  # in it, but not waited for until it submits again
        self._submitted = [False] * n_ports  # torque in for the pending tick
        self._torque = [0.0] * n_ports  # N·m, the last submitted
        self._kicks = [0.0] * n_ports  # m/s, the pending load pushes' velocity jumps
        self._tick_dt: float | None = None  # the pending tick's length, set by its first submission
        self.held_steps = [0] * n_ports
        self.ticks = 0
        self.time_s = 0.0
        self.reset()

    # -- state ---------------------------------------------------------------------------

    def reset(self, positions: Sequence[float] | None = None, velocities: Sequence[float] | None = None) -> None:
        """Set the state: each mass's position (m) and velocity (m/s); None for zeros."""
        n = self.model.n_masses
        x = np.zeros(2 * n)
        for offset, name, values in ((0, "positions", positions), (1, "velocities", velocities)):
            if values is None:
                continue
            v = np.asarray(values, dtype=float)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be {n} finite numbers, got {values!r}")
            x[offset::2] = v
        with self._cond:
            self._set_state(x)

    def _set_state(self, x: np.ndarray) -> None:
        """Take ``x`` as the state (never changed in place afterwards: readers need no lock)."""
        self._x = x
        self._xs = tuple(x.tolist())

    @property
    def positions(self) -> np.ndarray:
        """Position of each mass, m."""
        return self._x[0::2].copy()

    @property
    def velocities(self) -> np.ndarray:
        """Velocity of each mass, m/s."""
        return self._x[1::2].copy()

    @property
    def state(self) -> tuple[float, ...]:
        """The exact state ``(q0, v0, q1, v1, ...)``, m and m/s."""
        return self._xs

    def port(self, index: int) -> PlantPort:
        """The port ``index`` (a drive's view of the mechanism); it joins the lockstep."""
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < self.model.n_ports:
            raise ValueError(f"port index must be an int in [0, {self.model.n_ports}), got {index!r}")
        with self._cond:
            found = self._ports[index]
            if found is None:
                found = self._ports[index] = PlantPort(self, index)
            self._attached[index] = True
            return found

    # -- integration ---------------------------------------------------------------------

    def _matrices(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Gamma)`` of one tick of ``dt_s`` seconds, cached."""
        found = self._cache.get(dt_s)
        if found is not None:
            return found
        if not (isinstance(dt_s, float | int) and math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s must be > 0 and finite, got {dt_s!r}")
        nx, nu = self._B.shape
        aug = np.zeros((nx + nu, nx + nu))
        aug[:nx, :nx] = self._A
        aug[:nx, nx:] = self._B
        E = expm(aug * dt_s)
        if len(self._cache) >= _CACHE_LIMIT:
            self._cache.clear()
        found = self._cache[dt_s] = (E[:nx, :nx].copy(), E[:nx, nx:].copy())
        return found

    def _advance(self, torques: list[float], dt_s: float) -> None:
        """Advance by one tick of ``dt_s`` seconds with ``torques`` (N·m per port); called holding the lock."""
        phi, gam = self._matrices(dt_s)
        x = self._x
        if any(self._kicks):
            x = x.copy()
            for p, dv in enumerate(self._kicks):
                x[2 * self.model.sensors[p] + 1] += dv
            self._kicks = [0.0] * len(self._kicks)
        self._set_state(phi.dot(x) + gam.dot(torques))  # ndarray.dot: a quarter of the cost of @ here
        self._submitted = [False] * len(self._submitted)
        self._tick_dt = None
        self.ticks += 1
        self.time_s += dt_s
        self._cond.notify_all()

    def step(self, torques_nm: Sequence[float], dt_s: float) -> None:
        """Advance the whole mechanism by ``dt_s`` seconds with one torque per port, from one thread.

        The reference a lockstepped run equals; not to be mixed with ports stepping at
        the same time.

        Parameters
        ----------
        torques_nm : sequence of float
            Each port's motor torque, N·m, held over the tick.
        dt_s : float
            Tick length, s.
        """
        u = [float(t) for t in torques_nm]
        if len(u) != self.model.n_ports or not all(math.isfinite(t) for t in u):
            raise ValueError(f"torques_nm must be {self.model.n_ports} finite numbers, got {torques_nm!r}")
        with self._cond:
            self._advance(u, dt_s)

    # -- the lockstep --------------------------------------------------------------------

    def _ready(self) -> bool:
        """Whether every port in the lockstep that is waited for has submitted the pending tick's torque."""
        return all(s or h or not a for s, h, a in zip(self._submitted, self._held, self._attached, strict=True))

    def _advance_tick(self) -> None:
        """Advance the pending tick; ports in the lockstep without a torque for it are held. Holding the lock."""
        torques = []
        for p, attached in enumerate(self._attached):
            if attached and not self._submitted[p]:
                self.held_steps[p] += 1
                self._held[p] = True
            torques.append(self._torque[p] if attached else 0.0)
        self._advance(torques, self._tick_dt)  # type: ignore[arg-type]  # set by the submission that got here

    def _submit(self, index: int, torque_nm: float, dt_s: float) -> None:
        """Port ``index``'s torque for the pending tick; return once the mechanism has advanced by it."""
        if not math.isfinite(torque_nm):
            raise ValueError(f"torque_nm must be finite, got {torque_nm!r}")
        with self._cond:
            if self._tick_dt is None:
                self._matrices(dt_s)  # refuses a bad dt_s before anything changes
                self._tick_dt = dt_s
            elif dt_s != self._tick_dt:
                raise ValueError(f"dt_s {dt_s!r} differs from the pending tick's {self._tick_dt!r}")
            self._attached[index] = True
            self._held[index] = False
            self._submitted[index] = True
            self._torque[index] = torque_nm
            target = self.ticks + 1
            if self._ready():
                self._advance_tick()
                return
            deadline = time.monotonic() + self.wait_s
            while self.ticks < target:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    self._advance_tick()
                    return
                self._cond.wait(left)

    def _detach(self, index: int) -> None:
        """Take port ``index`` out of the lockstep; a tick that waited only for it advances now."""
        with self._cond:
            self._attached[index] = False
            self._held[index] = False
            self._submitted[index] = False
            self._torque[index] = 0.0
            if any(self._submitted) and self._ready():
                self._advance_tick()

    def _push(self, index: int, dv_mps: float) -> None:
        with self._cond:
            self._kicks[index] += dv_mps


class PlantPort:
    """One drive's view of a :class:`CoupledPlant`: what a :class:`~hilident.emulator.drive.DriveLoop` steps.

    It offers what the drive, its sensors and the firmwares read of a
    :class:`~hilident.emulator.plant.Plant`: ``p1``, ``v1`` (the port's motor mass),
    ``p2``, ``v2`` (the mass its laser watches), ``state``, ``stuck``,
    :meth:`push_load` and :meth:`step`. Get it from :meth:`CoupledPlant.port`.

    Attributes
    ----------
    plant : CoupledPlant
    index : int
        The port's number (its motor in :attr:`CoupledModel.motors`).
    stuck : bool
        Always False: the mechanism has no friction.
    """

    stuck = False

    def __init__(self, plant: CoupledPlant, index: int):
        self.plant = plant
        self.index = index
        model = plant.model
        self._k1 = 2 * model.motor_masses[index]
        self._k2 = 2 * model.sensor_masses[index]
        self._load_mass = model.masses[model.sensor_masses[index]]

    @property
    def p1(self) -> float:
        """Position of the port's motor mass, m."""
        return self.plant._xs[self._k1]

    @property
    def v1(self) -> float:
        """Velocity of the port's motor mass, m/s."""
        return self.plant._xs[self._k1 + 1]

    @property
    def p2(self) -> float:
        """Position of the mass the port's laser watches, m."""
        return self.plant._xs[self._k2]

    @property
    def v2(self) -> float:
        """Velocity of the mass the port's laser watches, m/s."""
        return self.plant._xs[self._k2 + 1]

    @property
    def state(self) -> tuple[float, float, float, float]:
        """``(p1, v1, p2, v2)`` of one tick (m, m/s)."""
        xs, k1, k2 = self.plant._xs, self._k1, self._k2
        return (xs[k1], xs[k1 + 1], xs[k2], xs[k2 + 1])

    @property
    def attached(self) -> bool:
        """Whether the port is in the lockstep."""
        return self.plant._attached[self.index]

    def step(self, torque_nm: float, dt_s: float) -> None:
        """Submit the motor torque (N·m) for the pending tick of ``dt_s`` s; return once the mechanism advanced.

        A detached port rejoins the lockstep with it.
        """
        self.plant._submit(self.index, float(torque_nm), dt_s)

    def push_load(self, force_n: float, dt_s: float) -> None:
        """Push the watched mass with ``force_n`` (N) for ``dt_s`` (s) as one impulse at the pending tick's start.

        Its velocity jumps by ``force_n * dt_s / m`` (a disturbance, not a drive input),
        as :meth:`~hilident.emulator.plant.Plant.push_load` does.
        """
        self.plant._push(self.index, float(force_n) * float(dt_s) / self._load_mass)

    def detach(self) -> None:
        """Leave the lockstep: the port's torque is 0 and no tick waits for it (until it steps again)."""
        self.plant._detach(self.index)
