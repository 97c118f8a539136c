"""Friction identification from constant-velocity tests (Stribeck model).

When the axis runs at constant velocity, the acceleration term vanishes and the
motor torque only overcomes friction (thesis eq. 3.1). Each steady window of
such a test gives one point (velocity, torque); the points are fitted with the
Stribeck curve, thesis eq. 2.13::

    tau_f(v) = (Fc + (Fs - Fc) exp(-|v / vs|^delta_s) + Fv |v|^delta_v) sign(v)

Units: torque at the motor in N·m against the velocity of the driven mass in
m/s; hence ``Fc, Fs`` in N·m, ``vs`` in m/s, ``Fv`` in N·m/(m/s)^delta_v.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.friction import StribeckParams, stribeck, fit_stribeck
>>> true = StribeckParams(Fc=2.0, Fs=3.0, Fv=10.0, vs=0.01)
>>> v = np.concatenate([-np.geomspace(0.002, 0.3, 20), np.geomspace(0.002, 0.3, 20)])
>>> fit = fit_stribeck(v, stribeck(v, true), fix_delta_v=1.0, fix_delta_s=2.0)
>>> round(fit.params.Fc, 3)
2.0
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize, stats

from hilident.errors import ConfigError, DataError

__all__ = [
    "StribeckParams",
    "FrictionFit",
    "SteadyStatePoints",
    "FoldedPoints",
    "stribeck",
    "steady_state_points",
    "folded_points",
    "fit_stribeck",
    "fit_coulomb_viscous",
    "fit_friction",
    "undetermined",
    "free_parameters",
    "sensitivity",
    "compensate",
]

_NAMES = ("Fc", "Fs", "Fv", "vs", "delta_v", "delta_s")


@dataclass(frozen=True)
class StribeckParams:
    """Parameters of the Stribeck friction curve (thesis eq. 2.13).

    Parameters
    ----------
    Fc : float
        Coulomb friction torque, N·m.
    Fs : float
        Static (breakaway) friction torque, N·m.
    Fv : float
        Viscous coefficient, N·m/(m/s)^delta_v.
    vs : float
        Stribeck velocity, m/s (> 0).
    delta_v : float
        Exponent of the viscous term (1 = linear viscous friction).
    delta_s : float
        Shape exponent of the Stribeck decay (2 = Gaussian).
    """

    Fc: float
    Fs: float
    Fv: float
    vs: float
    delta_v: float = 1.0
    delta_s: float = 2.0

    def __post_init__(self):
        for name in _NAMES:
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ConfigError(name, f"must be finite, got {value!r}")
            object.__setattr__(self, name, value)
        if self.vs <= 0.0:
            raise ConfigError("vs", f"Stribeck velocity must be > 0 m/s, got {self.vs!r}")
        if self.delta_v <= 0.0 or self.delta_s <= 0.0:
            raise ConfigError(
                "delta_v" if self.delta_v <= 0.0 else "delta_s",
                f"exponents must be > 0, got delta_v={self.delta_v}, delta_s={self.delta_s}",
            )

    def to_dict(self) -> dict[str, float]:
        """Plain dict ``{"Fc": ..., "Fs": ..., ...}`` (e.g. for summary.json)."""
        return dataclasses.asdict(self)


def _magnitude(a: np.ndarray, p: StribeckParams) -> np.ndarray:
    """Friction magnitude for speeds ``a = |v| >= 0``."""
    return p.Fc + (p.Fs - p.Fc) * np.exp(-((a / p.vs) ** p.delta_s)) + p.Fv * a**p.delta_v


def stribeck(v: ArrayLike, params: StribeckParams) -> np.ndarray:
    """Friction torque (N·m) at velocity `v` (m/s), thesis eq. 2.13.

    Zero at ``v == 0``: standing still, friction balances whatever torque is
    applied up to ``Fs``, which a function of velocity alone cannot express.
    """
    v = np.asarray(v, dtype=np.float64)
    return _magnitude(np.abs(v), params) * np.sign(v)


class SteadyStatePoints(NamedTuple):
    """One point per steady constant-velocity window."""

    v_mean: np.ndarray
    """Mean velocity of the window, m/s."""
    tau_mean: np.ndarray
    """Mean torque of the window, N·m."""
    tau_std: np.ndarray
    """Standard deviation of the torque inside the window, N·m."""


class FoldedPoints(NamedTuple):
    """Friction points folded onto positive speeds, one per pair of opposite legs (or per unpaired window).

    A pair of legs run back to back at ``+v`` and ``-v`` is one point: the mean of
    ``tau sign(v)`` over both windows. A torque that does not change sign with the
    direction (a load, gravity, a cable chain) and lasts over the pair cancels in it,
    so the pair, not the window, is the independent measurement.
    """

    speed: np.ndarray
    """Mean speed ``|v|`` of the window(s), m/s."""
    friction: np.ndarray
    """Mean of ``tau sign(v)`` over the window(s), N·m."""
    windows: np.ndarray
    """Windows averaged into the point: 2 for a pair, 1 for a window without its opposite."""


def _steady_rows(
    velocity: ArrayLike, torque: ArrayLike, windows, max_relative_std: float, max_velocity_error: float
) -> list[tuple[int, float, float, float, float]]:
    """``(window index, nominal, mean v, mean tau, std tau)`` of each steady window (:func:`steady_state_points`)."""
    v = np.asarray(velocity, dtype=np.float64)
    tau = np.asarray(torque, dtype=np.float64)
    if v.ndim != 1 or tau.ndim != 1 or v.size != tau.size:
        raise DataError(f"velocity and torque must be 1-D of equal length, got shapes {v.shape} and {tau.shape}")
    rows = []
    worst = []
    for i, window in enumerate(windows):
        try:
            start, stop, nominal = window
        except (TypeError, ValueError):
            raise ConfigError(
                f"windows[{i}]", f"must be (start_index, stop_index, nominal_velocity), got {window!r}"
            ) from None
        start, stop, nominal = int(start), int(stop), float(nominal)
        if not 0 <= start < stop <= v.size or stop - start < 2:
            raise ConfigError(
                f"windows[{i}]",
                f"indices ({start}, {stop}) must satisfy 0 <= start < stop - 1 < {v.size}",
            )
        if nominal == 0.0:
            continue
        vw, tw = v[start:stop], tau[start:stop]
        if not (np.all(np.isfinite(vw)) and np.all(np.isfinite(tw))):
            continue
        vm = vw.mean()
        rel_std = vw.std() / abs(vm) if vm != 0.0 else np.inf
        rel_err = abs(vm - nominal) / abs(nominal)
        worst.append((i, rel_std, rel_err))
        if rel_std <= max_relative_std and rel_err <= max_velocity_error:
            rows.append((i, nominal, *_over_distance(vw, tw)))
    if not rows:
        detail = ", ".join(f"#{i}: std/mean={s:.3g}, error={e:.3g}" for i, s, e in worst[:5])
        raise DataError(
            "no constant-velocity window was steady "
            f"(max_relative_std={max_relative_std}, max_velocity_error={max_velocity_error}"
            + (f"; {detail}" if detail else "")
            + ")"
        )
    return rows


def _over_distance(v: np.ndarray, tau: np.ndarray) -> tuple[float, float, float]:
    """Mean velocity and torque of a steady window over the distance travelled, and the torque's spread.

    Each sample counts by the distance it covers (``|v| dt``): the torque's mean is the work
    per metre. A torque that repeats with the position (cogging, the ripple of a motor's
    poles) does no work over its periods, but it slows the axis where it holds it back, so a
    mean over time counts those stretches longer and reads it as friction that grows as the
    speed falls.
    """
    w = np.abs(v)
    total = float(w.sum())
    if not total > 0.0:
        return float(v.mean()), float(tau.mean()), float(tau.std())
    return float(w @ v) / total, float(w @ tau) / total, float(tau.std())


def steady_state_points(
    velocity: ArrayLike,
    torque: ArrayLike,
    windows,
    max_relative_std: float = 0.1,
    max_velocity_error: float = 0.25,
) -> SteadyStatePoints:
    """Average torque and velocity over constant-velocity windows, each over the distance travelled.

    The means weight each sample by the distance it covers (:func:`_over_distance`): a
    torque that repeats with the position then adds nothing. A window counts as steady
    when both hold:

    * ``std(v) <= max_relative_std * |mean(v)|`` -- the velocity did not
      oscillate, creep or still accelerate (any trend raises the std too);
    * ``|mean(v) - nominal| <= max_velocity_error * |nominal|`` -- the axis
      really ran at the commanded speed (not stuck in stiction, not the wrong
      direction).

    Windows failing either test, and windows with nominal velocity 0, are
    skipped.

    Parameters
    ----------
    velocity, torque : array_like
        Recorded velocity (m/s) and motor torque (N·m), same length.
    windows : iterable of (int, int, float)
        ``(start_index, stop_index, nominal_velocity)`` per constant-velocity
        segment, Python slice convention, nominal velocity in m/s.
    max_relative_std : float
        Largest accepted ratio std(v)/|mean(v)| inside a window.
    max_velocity_error : float
        Largest accepted relative deviation of mean(v) from the nominal velocity.

    Returns
    -------
    SteadyStatePoints
        ``(v_mean, tau_mean, tau_std)`` arrays, one entry per kept window, in
        window order.

    Raises
    ------
    ConfigError
        A window is malformed or outside the recording.
    DataError
        The signals differ in length or no window was steady.
    """
    rows = _steady_rows(velocity, torque, windows, max_relative_std, max_velocity_error)
    arr = np.array([r[2:] for r in rows])
    return SteadyStatePoints(arr[:, 0], arr[:, 1], arr[:, 2])


def folded_points(
    velocity: ArrayLike,
    torque: ArrayLike,
    windows,
    max_relative_std: float = 0.1,
    max_velocity_error: float = 0.25,
) -> FoldedPoints:
    """The steady windows of :func:`steady_state_points`, each pair of opposite legs averaged into one point.

    Two windows pair when they follow each other in ``windows`` and their nominal
    velocities are opposite (``+v`` then ``-v`` or the reverse), as the friction
    test runs its legs; a steady window whose neighbour is missing or not steady
    stays a point of its own.

    Parameters
    ----------
    velocity, torque, windows, max_relative_std, max_velocity_error
        As :func:`steady_state_points`.

    Returns
    -------
    FoldedPoints
        One entry per pair or unpaired window, in window order.

    Examples
    --------
    >>> v = np.r_[np.full(10, 0.1), np.full(10, -0.1), np.full(10, 0.2)]
    >>> tau = np.r_[np.full(10, 0.5), np.full(10, -0.3), np.full(10, 0.8)]  # 0.1 N*m of load on both
    >>> p = folded_points(v, tau, [(0, 10, 0.1), (10, 20, -0.1), (20, 30, 0.2)])
    >>> p.friction.round(3).tolist(), p.windows.tolist()
    ([0.4, 0.8], [2, 1])
    """
    rows = _steady_rows(velocity, torque, windows, max_relative_std, max_velocity_error)
    points = []
    k = 0
    while k < len(rows):
        i, nominal, vm, tm, _ = rows[k]
        following = rows[k + 1] if k + 1 < len(rows) else None
        if following is not None and following[0] == i + 1 and following[1] == -nominal:
            _, _, vm2, tm2, _ = following
            points.append(((abs(vm) + abs(vm2)) / 2, (tm * np.sign(vm) + tm2 * np.sign(vm2)) / 2, 2))
            k += 2
        else:
            points.append((abs(vm), tm * np.sign(vm), 1))
            k += 1
    arr = np.array(points, dtype=np.float64)
    return FoldedPoints(arr[:, 0], arr[:, 1], arr[:, 2].astype(np.int64))


@dataclass(frozen=True)
class FrictionFit:
    """Result of a friction fit.

    Attributes
    ----------
    params : StribeckParams
        Fitted parameters. A Coulomb + viscous fit is stored as a Stribeck
        curve with ``Fs == Fc`` and ``delta_v == 1`` (``vs`` then has no effect).
    stderr : dict of str to float
        Standard error per parameter from the Jacobian at the optimum
        (``sqrt(diag((J^T J)^-1) * s^2)``); 0 for fixed parameters, inf when
        the parameter is not identifiable from the data.
    rms_residual : float
        RMS of ``tau - model`` over the points, N·m.
    n_points : int
        Number of points used (zero-velocity points are dropped).
    model : str
        ``"stribeck"`` or ``"coulomb_viscous"``.
    structure : str
        The fitted structure: ``"coulomb_viscous"``, ``"stribeck_fixed_exponents"``
        (``delta_v = 1``, ``delta_s = 2``) or ``"stribeck"`` (all six free).
    criterion : dict of str to float
        AICc of each structure tried by :func:`fit_friction` (empty otherwise).
    """

    params: StribeckParams
    stderr: dict[str, float] = field(default_factory=dict)
    rms_residual: float = 0.0
    n_points: int = 0
    model: str = "stribeck"
    structure: str = ""
    criterion: dict[str, float] = field(default_factory=dict)

    @property
    def dof(self) -> int:
        """Residual degrees of freedom, points minus fitted parameters (:func:`free_parameters`).

        The standard errors rest on the scatter of the points about the curve, so an
        interval takes Student's t with this many degrees (:meth:`half_width`).
        """
        return self.n_points - len(free_parameters(self))

    def predict(self, v: ArrayLike) -> np.ndarray:
        """Friction torque (N·m) at velocity `v` (m/s)."""
        return stribeck(v, self.params)

    def half_width(self, name: str, level: float = 0.95) -> float:
        """Half-width of the two-sided ``level`` interval of parameter ``name``, in its unit.

        ``t(dof) * stderr``: the residual scale is estimated from as few points as
        the fit has, which Student's t accounts for (1.96 would claim more with
        three degrees of freedom than the points know). Infinite without a
        degree of freedom; 0 for a fixed parameter.
        """
        se = self.stderr.get(name, float("inf"))
        if se == 0.0:
            return 0.0
        if self.dof < 1 or not np.isfinite(se):
            return float("inf")
        return float(stats.t.ppf(0.5 + level / 2.0, self.dof) * se)

    def to_dict(self) -> dict:
        out = {
            "model": self.model,
            "params": self.params.to_dict(),
            "stderr": dict(self.stderr),
            "rms_residual": self.rms_residual,
            "n_points": self.n_points,
        }
        if self.structure:
            out["structure"] = self.structure
        if self.criterion:
            out["aicc"] = dict(self.criterion)
        return out


def _fold(v: ArrayLike, tau: ArrayLike, sigma: ArrayLike | None):
    v = np.asarray(v, dtype=np.float64).ravel()
    tau = np.asarray(tau, dtype=np.float64).ravel()
    if v.size != tau.size:
        raise DataError(f"v and tau must have equal length, got {v.size} and {tau.size}")
    if sigma is None:
        s = np.ones_like(v)
    else:
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), v.shape).astype(np.float64)
        if np.any(~np.isfinite(s)) or np.any(s <= 0.0):
            raise DataError("sigma must be finite and > 0 for every point")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(tau))):
        raise DataError("v and tau must be finite")
    ok = v != 0.0
    # The model is odd in v: fold the negative branch onto the positive one.
    a = np.abs(v[ok])
    t = tau[ok] * np.sign(v[ok])
    return a, t, s[ok]


def _line(a: np.ndarray, t: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Weighted LS line ``t = c0 + c1 a``."""
    A = np.column_stack([np.ones_like(a), a]) * w[:, None]
    (c0, c1), *_ = np.linalg.lstsq(A, t * w, rcond=None)
    return float(c0), float(c1)


def _initial_guess(a: np.ndarray, t: np.ndarray) -> dict[str, float]:
    order = np.argsort(a)
    a, t = a[order], t[order]
    n = a.size
    # High-speed line from the fastest third of the points: Fc is its
    # intercept, Fv its slope (exact when delta_v == 1 and the Stribeck term
    # has died out).
    hi = slice(max(0, n - max(3, n // 3)), n)
    c0, c1 = _line(a[hi], t[hi], np.ones(a[hi].size))
    span = float(np.ptp(t)) or float(np.abs(t).max()) or 1.0
    Fc = max(c0, 0.05 * span)
    Fv = max(c1, 1e-6 * span / a[-1])
    # Static friction from the slowest points.
    Fs = max(float(np.median(t[: max(2, n // 10)])), Fc)
    # vs where the excess over the line has fallen to 1/e of its size.
    excess = t - (c0 + c1 * a)
    top = excess[: max(2, n // 10)].mean()
    vs = float(np.sqrt(a[0] * a[-1]))
    if top > 0:
        below = np.flatnonzero(excess < top / np.e)
        if below.size:
            vs = float(a[below[0]])
    return {"Fc": Fc, "Fs": Fs, "Fv": Fv, "vs": max(vs, a[0])}


def _residual_and_jac(a, t, w, names, fixed):
    """Weighted residual and analytic Jacobian in the fitted parameter vector.

    The fitted vector holds the free parameters among ``_NAMES``; ``vs`` is
    fitted as ``log(vs)`` because plausible values span decades.
    """
    la = np.log(a)

    def unpack(x):
        p = dict(fixed)
        p.update(zip(names, x, strict=False))
        return p

    def model(x):
        p = unpack(x)
        vs = np.exp(p["vs"])
        r = (a / vs) ** p["delta_s"]
        e = np.exp(-r)
        av = a ** p["delta_v"]
        return p, vs, r, e, av

    def fun(x):
        p, vs, r, e, av = model(x)
        return w * (p["Fc"] + (p["Fs"] - p["Fc"]) * e + p["Fv"] * av - t)

    def jac(x):
        p, vs, r, e, av = model(x)
        dfs = p["Fs"] - p["Fc"]
        cols = {
            "Fc": 1.0 - e,
            "Fs": e,
            "Fv": av,
            # d/d log vs of exp(-(a/vs)^ds) = e * r * ds
            "vs": dfs * e * r * p["delta_s"],
            "delta_v": p["Fv"] * av * la,
            # d/d ds of exp(-(a/vs)^ds) = -e * r * log(a/vs)
            "delta_s": -dfs * e * r * (la - p["vs"]),
        }
        return np.column_stack([cols[n] for n in names]) * w[:, None]

    return fun, jac, unpack


def fit_stribeck(
    v: ArrayLike,
    tau: ArrayLike,
    fix_delta_v: float | None = None,
    fix_delta_s: float | None = None,
    sigma: ArrayLike | None = None,
) -> FrictionFit:
    """Fit the Stribeck curve to steady-state friction points.

    Points of both velocity signs are folded onto ``|v|`` (torque times
    ``sign(v)``), so one symmetric curve is fitted; points at ``v == 0`` are
    dropped. Bounded nonlinear least squares (trust-region reflective) runs
    from several starts: ``Fc`` and ``Fv`` from the intercept and slope of a
    line through the fastest third of the points, ``Fs`` from the slowest
    points, ``vs`` where the torque excess over that line has decayed to 1/e,
    times 0.1, 1 and 10, and a few values of the exponents. The best start wins.
    Bounds: ``0 <= Fc, Fs <= 10 max|tau|``, ``Fv >= 0``,
    ``min|v| / 3 <= vs <= 10 max|v|``, ``0.05 <= delta_v <= 3``,
    ``0.1 <= delta_s <= 5``.

    ``Fs`` and ``vs`` are only determined by points below and around ``vs``:
    measure densely near zero speed (log-spaced speeds work well). A Stribeck
    velocity far below the slowest measured speed cannot be told from Coulomb
    friction (``Fs`` then takes any value), hence the lower bound on ``vs``. ``Fv`` is
    the viscous torque at 1 m/s; with ``delta_v`` free and data well below
    1 m/s it trades off against ``delta_v`` (see its stderr).

    Parameters
    ----------
    v : array_like
        Steady velocities, m/s.
    tau : array_like
        Friction torques at those velocities, N·m.
    fix_delta_v, fix_delta_s : float, optional
        Hold an exponent fixed instead of fitting it (e.g. 1 and 2 for the
        classic viscous + Gaussian Stribeck curve).
    sigma : array_like, optional
        Standard deviation of each torque point (N·m), e.g. ``tau_std /
        sqrt(n_samples)``; points are weighted by ``1/sigma``. Default: equal.

    Returns
    -------
    FrictionFit

    Raises
    ------
    DataError
        Fewer non-zero-velocity points than free parameters + 1, or
        non-finite data.
    """
    a, t, s = _fold(v, tau, sigma)
    fixed = _fixed_exponents(fix_delta_v, fix_delta_s)
    names = [n for n in _NAMES if n not in fixed]
    if a.size < len(names) + 1:
        raise DataError(
            f"{a.size} friction points with v != 0; at least {len(names) + 1} needed to fit {len(names)} parameters"
        )
    if np.unique(a).size < 3:
        raise DataError("friction points need at least 3 distinct speeds |v|")
    w = 1.0 / s
    fun, jac, unpack = _residual_and_jac(a, t, w, names, fixed)
    lower, upper = _bounds(a, t, names)
    best = _best_fit(fun, jac, _starts(a, t, names, fixed, lower, upper), lower, upper)

    p = unpack(best.x)
    params = StribeckParams(
        Fc=p["Fc"],
        Fs=p["Fs"],
        Fv=p["Fv"],
        vs=float(np.exp(p["vs"])),
        delta_v=p["delta_v"],
        delta_s=p["delta_s"],
    )
    stderr = _stderr(best.jac, best.fun, names, params)
    for n in fixed:
        stderr[n] = 0.0
    resid = stribeck(a, params) - t
    return FrictionFit(
        params=params,
        stderr={n: stderr[n] for n in _NAMES},
        rms_residual=float(np.sqrt(np.mean(resid**2))),
        n_points=int(a.size),
        model="stribeck",
    )


def _fixed_exponents(fix_delta_v: float | None, fix_delta_s: float | None) -> dict[str, float]:
    """The exponents held fixed, checked (> 0)."""
    fixed: dict[str, float] = {}
    if fix_delta_v is not None:
        fixed["delta_v"] = float(fix_delta_v)
    if fix_delta_s is not None:
        fixed["delta_s"] = float(fix_delta_s)
    for key, value in fixed.items():
        if not np.isfinite(value) or value <= 0.0:
            raise ConfigError(f"fix_{key}", f"must be > 0, got {value!r}")
    return fixed


def _bounds(a: np.ndarray, t: np.ndarray, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of the free parameters (``vs`` as its logarithm), see :func:`fit_stribeck`."""
    tmax = float(np.abs(t).max())
    log_lo, log_hi = np.log(a.min() / 3.0), np.log(a.max() * 10.0)
    bounds_by_name = {
        "Fc": (0.0, 10.0 * tmax),
        "Fs": (0.0, 10.0 * tmax),
        "Fv": (0.0, np.inf),
        "vs": (log_lo, log_hi),
        "delta_v": (0.05, 3.0),
        "delta_s": (0.1, 5.0),
    }
    lower = np.array([bounds_by_name[n][0] for n in names])
    upper = np.array([bounds_by_name[n][1] for n in names])
    return lower, upper


def _starts(a, t, names: list[str], fixed: dict[str, float], lower: np.ndarray, upper: np.ndarray) -> list[np.ndarray]:
    """Starting points: the initial guess with ``vs`` times 0.1, 1, 10 and a few exponents."""
    guess = _initial_guess(a, t)
    # starts strictly inside the box, as the trust-region method requires
    width = np.where(np.isfinite(upper - lower), upper - lower, 1.0)
    inner_lo, inner_hi = lower + 1e-6 * width, upper - 1e-6 * width
    starts = []
    dv_starts = [fixed["delta_v"]] if "delta_v" in fixed else [1.0, 0.5]
    ds_starts = [fixed["delta_s"]] if "delta_s" in fixed else [2.0, 1.0, 0.5]
    for vs_mul, dv, ds in itertools.product((0.1, 1.0, 10.0), dv_starts, ds_starts):
        p0 = {
            "Fc": guess["Fc"],
            "Fs": guess["Fs"],
            "Fv": guess["Fv"],
            "vs": np.log(guess["vs"] * vs_mul),
            "delta_v": dv,
            "delta_s": ds,
        }
        if dv != 1.0 and "delta_v" not in fixed:
            # keep the viscous torque at the fastest point unchanged
            p0["Fv"] = guess["Fv"] * a.max() ** (1.0 - dv)
        starts.append(np.clip([p0[n] for n in names], inner_lo, inner_hi))
    return starts


def _best_fit(fun, jac, starts: list[np.ndarray], lower: np.ndarray, upper: np.ndarray):
    """The least-squares result of lowest cost over `starts`."""
    best = None
    for x0 in starts:
        try:
            res = optimize.least_squares(
                fun,
                x0,
                jac=jac,
                bounds=(lower, upper),
                method="trf",
                x_scale="jac",
                max_nfev=400,
            )
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        raise DataError("friction fit failed from every start")
    return best


def _stderr(J: np.ndarray, r: np.ndarray, names, params: StribeckParams) -> dict[str, float]:
    n, m = J.shape
    dof = max(n - m, 1)
    s2 = float(r @ r) / dof
    try:
        cov = np.linalg.pinv(J.T @ J) * s2
        var = np.diag(cov)
    except np.linalg.LinAlgError:
        var = np.full(m, np.inf)
    out = {}
    for name, vi in zip(names, var, strict=False):
        se = float(np.sqrt(vi)) if vi >= 0 and np.isfinite(vi) else float("inf")
        if name == "vs":  # fitted as log(vs): d vs = vs * d log(vs)
            se *= params.vs
        out[name] = se
    return out


def fit_coulomb_viscous(v: ArrayLike, tau: ArrayLike, sigma: ArrayLike | None = None) -> FrictionFit:
    """Linear least squares ``tau = Fc sign(v) + Fv v``, for comparison.

    Returns a :class:`FrictionFit` with ``model="coulomb_viscous"`` whose
    params have ``Fs = Fc``, ``delta_v = 1`` and ``vs`` set to the largest speed
    (irrelevant since ``Fs == Fc``); stderr is given for ``Fc`` and ``Fv``.
    ``sigma``: the relative standard deviation of each point (N·m), as
    :func:`fit_stribeck` takes it; default equal.
    """
    a, t, s = _fold(v, tau, sigma)
    if a.size < 3:
        raise DataError(f"{a.size} friction points with v != 0; at least 3 needed")
    w = 1.0 / s
    A = np.column_stack([np.ones_like(a), a]) * w[:, None]
    coef, *_ = np.linalg.lstsq(A, t * w, rcond=None)
    Fc, Fv = (float(c) for c in coef)
    r = A @ coef - t * w
    s2 = float(r @ r) / max(a.size - 2, 1)
    cov = np.linalg.pinv(A.T @ A) * s2
    r = np.column_stack([np.ones_like(a), a]) @ coef - t
    params = StribeckParams(Fc=Fc, Fs=Fc, Fv=Fv, vs=float(a.max()), delta_v=1.0, delta_s=2.0)
    stderr = {n: 0.0 for n in _NAMES}
    stderr["Fc"], stderr["Fv"] = (float(x) for x in np.sqrt(np.diag(cov)))
    return FrictionFit(
        params=params,
        stderr=stderr,
        rms_residual=float(np.sqrt(np.mean(r**2))),
        n_points=int(a.size),
        model="coulomb_viscous",
    )


def _aicc(rss: float, n: int, k: int, floor: float) -> float:
    """Corrected Akaike criterion of a least-squares fit with Gaussian residuals (``rss`` at least ``floor``)."""
    rss = max(rss, floor, 1e-300)
    penalty = 2.0 * k + (2.0 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else np.inf)
    return n * float(np.log(rss / n)) + penalty


#: Share of the Stribeck excess ``Fs - Fc`` still left at the fastest speed measured, above which the
#: Coulomb level of a fit lies beyond the measured speeds.
_STRIBECK_LEFT = 0.05


def _stribeck_shaped(p: StribeckParams, fastest_mps: float) -> bool:
    """Whether a Stribeck fit is the structure: ``Fs >= Fc``, and its excess has died out by ``fastest_mps``."""
    return p.Fs >= p.Fc and float(np.exp(-((fastest_mps / p.vs) ** p.delta_s))) <= _STRIBECK_LEFT


def fit_friction(v: ArrayLike, tau: ArrayLike, sigma: ArrayLike | None = None) -> FrictionFit:
    """The friction structure the points support, chosen by AICc.

    Fits Coulomb + viscous (2 parameters), Stribeck with the classic exponents
    ``delta_v = 1``, ``delta_s = 2`` (4) and the full Stribeck curve (6), and
    keeps the one with the smallest corrected Akaike criterion. Steady-state
    points on a real axis scatter (cogging, load changes, noise); six free
    parameters then fit the scatter and return a Stribeck part of any size.
    The criterion keeps only what the scatter cannot explain. A Stribeck fit
    competes only as that structure: friction falling from a breakaway level
    ``Fs`` above ``Fc`` to the Coulomb level within the speeds measured
    (:func:`_stribeck_shaped`); otherwise it bends the curve to the scatter.

    Parameters
    ----------
    v : array_like
        Steady velocities, m/s.
    tau : array_like
        Friction torques at those velocities, N·m.
    sigma : array_like, optional
        Relative standard deviation of each point, N·m (e.g. ``1 / sqrt(windows)`` of
        :class:`FoldedPoints`); the criterion then compares weighted residuals.

    Returns
    -------
    FrictionFit
        ``structure`` names the winner, ``criterion`` holds every AICc.

    Examples
    --------
    >>> true = StribeckParams(Fc=0.2, Fs=0.35, Fv=2.0, vs=0.005)
    >>> v = np.concatenate([-np.geomspace(0.002, 0.3, 8), np.geomspace(0.002, 0.3, 8)])
    >>> fit_friction(v, stribeck(v, true)).structure
    'stribeck_fixed_exponents'
    >>> fit_friction(v, 0.2 * np.sign(v) + 2.0 * v).structure
    'coulomb_viscous'
    """
    a, t, s = _fold(v, tau, sigma)
    n = a.size
    candidates = {"coulomb_viscous": (2, lambda: fit_coulomb_viscous(v, tau, sigma))}
    if n >= 6:
        candidates["stribeck_fixed_exponents"] = (
            4,
            lambda: fit_stribeck(v, tau, fix_delta_v=1.0, fix_delta_s=2.0, sigma=sigma),
        )
    if n >= 8:
        candidates["stribeck"] = (6, lambda: fit_stribeck(v, tau, sigma=sigma))
    # Residuals below a part in 1e9 of the torque are rounding: exact data ties, and the penalty decides.
    floor = n * (1e-9 * float(np.abs(t / s).max())) ** 2
    fits: dict[str, FrictionFit] = {}
    scores: dict[str, float] = {}
    for name, (k, fit) in candidates.items():
        try:
            result = fit()
        except DataError:
            continue
        if name != "coulomb_viscous" and not _stribeck_shaped(result.params, float(a.max())):
            continue
        fits[name] = result
        weighted = (stribeck(a, result.params) - t) / s
        scores[name] = _aicc(float(weighted @ weighted), n, k, floor)
    if not fits:
        raise DataError(f"{n} friction points with v != 0 fit no friction structure")
    best = min(scores, key=scores.__getitem__)
    return dataclasses.replace(fits[best], structure=best, criterion=scores)


#: The parameters each structure fits (the others are fixed by it).
_FREE = {
    "coulomb_viscous": ("Fc", "Fv"),
    "stribeck_fixed_exponents": ("Fc", "Fs", "Fv", "vs"),
    "stribeck": _NAMES,
}


def free_parameters(fit: FrictionFit) -> tuple[str, ...]:
    """The parameters ``fit`` determined from its points, in the order of :data:`_NAMES`."""
    if fit.structure in _FREE:
        return _FREE[fit.structure]
    if fit.model == "coulomb_viscous":
        return _FREE["coulomb_viscous"]
    return tuple(n for n in _NAMES if fit.stderr.get(n, 0.0) != 0.0)  # a fixed parameter's is 0


def sensitivity(fit: FrictionFit, speeds: ArrayLike) -> np.ndarray:
    """How the fitted friction magnitude at each speed moves with each free parameter.

    Row ``i`` is the gradient of ``|tau_f|(speeds[i])`` with respect to
    :func:`free_parameters` (``vs`` as ``log(vs)``, as the fit takes it): with
    the points' weights it gives the information a point at that speed would
    add, and so which speeds would narrow an interval most.

    Parameters
    ----------
    fit : FrictionFit
    speeds : array_like
        Speeds ``|v| > 0``, m/s.

    Returns
    -------
    ndarray, shape (len(speeds), len(free_parameters(fit)))
        In N·m per unit of each parameter (per unit of ``log(vs)`` for ``vs``).
    """
    a = np.abs(np.asarray(speeds, dtype=np.float64).ravel())
    names = list(free_parameters(fit))
    if "Fs" not in names:  # Coulomb + viscous: Fs is Fc, no Stribeck term
        return np.column_stack([np.ones_like(a) if n == "Fc" else a for n in names])
    p = fit.params.to_dict()
    fixed = {n: v for n, v in p.items() if n not in names}
    fixed_log = dict(fixed)
    if "vs" in fixed_log:
        fixed_log["vs"] = float(np.log(p["vs"]))
    x = np.array([np.log(p[n]) if n == "vs" else p[n] for n in names])
    _, jac, _ = _residual_and_jac(a, np.zeros_like(a), np.ones_like(a), names, fixed_log)
    return jac(x)


def undetermined(fit: FrictionFit) -> list[str]:
    """Names of the fitted parameters whose standard error exceeds their value (not determined by the data)."""
    params = fit.params.to_dict()
    return [name for name, se in fit.stderr.items() if se > 0.0 and not se < abs(params[name])]


def compensate(
    torque: ArrayLike,
    velocity: ArrayLike,
    params: StribeckParams,
    velocity_deadband_mps: float = 0.0,
    slowest_mps: float = 0.0,
) -> np.ndarray:
    """Measured torque minus the predicted friction torque, N·m.

    Inside ``|v| <= velocity_deadband_mps`` the torque is returned unchanged:
    near standstill stiction makes the friction torque anything between
    ``-Fs`` and ``Fs``, and subtracting a guess would add error, not remove it.

    Parameters
    ----------
    torque : array_like
        Measured motor torque, N·m.
    velocity : array_like
        Velocity of the driven mass at the same samples, m/s.
    params : StribeckParams
        Friction model.
    velocity_deadband_mps : float
        Speeds up to this value (m/s) are left uncompensated.
    slowest_mps : float
        The slowest speed the friction was measured at, m/s (0: the model holds down to
        standstill). Below it the curve is not extrapolated: the friction there is the curve's
        value at this speed. A Stribeck hump fitted to points above its peak can rise to any
        height below them (7 N·m against a measured 0.2 has been seen), and subtracting it
        from a torque that crosses zero velocity would swamp the response.
    """
    tau = np.asarray(torque, dtype=np.float64)
    v = np.asarray(velocity, dtype=np.float64)
    if tau.shape != v.shape:
        raise DataError(f"torque and velocity shapes differ: {tau.shape} vs {v.shape}")
    if not velocity_deadband_mps >= 0.0:
        raise ConfigError("velocity_deadband_mps", f"must be >= 0 m/s, got {velocity_deadband_mps!r}")
    if not slowest_mps >= 0.0:
        raise ConfigError("slowest_mps", f"must be >= 0 m/s, got {slowest_mps!r}")
    speed = np.abs(v)
    friction = stribeck(np.where(speed < slowest_mps, np.sign(v) * slowest_mps, v), params)
    return np.where(speed > velocity_deadband_mps, tau - friction, tau)
