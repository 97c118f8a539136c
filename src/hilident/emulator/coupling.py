"""Coupling coefficients that vary with the cart position (thesis eqs. 2.3-2.4).

The thesis's gantry carries its load on a bearing beam that bends more the
further the cart is from the beam's supports, so the cart-to-load stiffness
``k`` and damping ``d`` are functions of the cart position ``p1``.
:class:`PositionCurve` is one such function, a polynomial or a table;
:func:`model_at` substitutes both into a two- or three-mass model, whose
:func:`~hilident.emulator.plant.modes` (:func:`~hilident.emulator.plant.modes_at`)
are the truth a map of the resonance over the workspace is compared with.
"""

from __future__ import annotations

import bisect
import dataclasses
import math

import numpy as np

from hilident.errors import ConfigError

__all__ = ["PositionCurve", "model_at"]


def _floats(name: str, values) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be a list of numbers, got {values!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise ConfigError(name, f"must be finite, got {values!r}")
    return out


class PositionCurve:
    """A coefficient as a function of the cart position ``p`` (m): a polynomial or a table.

    Parameters
    ----------
    poly : sequence of float, optional
        ``c0 + c1 p + c2 p**2 + ...``, constant term first (unit of the
        coefficient per m**i).
    positions_m, values : sequence of float, optional
        A table instead: strictly increasing positions (m) and the coefficient
        at each; interpolated linearly, held at the end values beyond the ends.
    span_m : (float, float), optional
        Polynomial only: the window it holds over; beyond it the value at the
        nearer end is held. None: the polynomial everywhere.

    Examples
    --------
    >>> k = PositionCurve(poly=[1.0e5, 0.0, 2.0e5], span_m=(-0.5, 0.5))
    >>> k(0.25), k(2.0)
    (112500.0, 150000.0)
    >>> PositionCurve(positions_m=[0.0, 1.0], values=[10.0, 20.0])(0.25)
    12.5
    """

    def __init__(self, *, poly=(), positions_m=(), values=(), span_m: tuple[float, float] | None = None):
        self.poly = _floats("poly", poly)
        self.positions_m = _floats("positions_m", positions_m)
        self.values = _floats("values", values)
        if bool(self.poly) == bool(self.positions_m):
            raise ConfigError("poly", "give either poly or positions_m and values")
        if len(self.positions_m) != len(self.values):
            raise ConfigError("values", f"{len(self.values)} values for {len(self.positions_m)} positions_m")
        if any(b <= a for a, b in zip(self.positions_m, self.positions_m[1:], strict=False)):
            raise ConfigError("positions_m", "must increase strictly")
        if span_m is not None:
            lo, hi = (float(v) for v in span_m)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ConfigError("span_m", f"must be (lo, hi) with lo <= hi, got {span_m!r}")
            span_m = (lo, hi)
        self.span_m = span_m if self.poly else (self.positions_m[0], self.positions_m[-1])

    @classmethod
    def constant(cls, value: float) -> PositionCurve:
        """The curve that is ``value`` everywhere."""
        return cls(poly=[value])

    @classmethod
    def from_table(cls, table) -> PositionCurve:
        """A curve from a config table with ``poly``, ``positions_m``, ``values`` and ``span_m`` attributes."""
        return cls(poly=table.poly, positions_m=table.positions_m, values=table.values, span_m=table.span_m)

    def __repr__(self) -> str:
        if self.poly:
            return f"PositionCurve(poly={list(self.poly)!r}, span_m={self.span_m!r})"
        return f"PositionCurve(positions_m={list(self.positions_m)!r}, values={list(self.values)!r})"

    @property
    def is_constant(self) -> bool:
        """Whether the curve has the same value at every position."""
        if self.poly:
            return all(c == 0.0 for c in self.poly[1:])
        return all(v == self.values[0] for v in self.values)

    def __call__(self, p: float) -> float:
        """The value at the position ``p`` (m); a float in, a float out."""
        poly = self.poly
        if poly:
            span = self.span_m
            if span is not None:
                p = span[0] if p < span[0] else (span[1] if p > span[1] else p)
            y = 0.0
            for c in reversed(poly):
                y = y * p + c
            return y
        x, v = self.positions_m, self.values
        if p <= x[0]:
            return v[0]
        if p >= x[-1]:
            return v[-1]
        i = bisect.bisect_right(x, p)
        a, b = x[i - 1], x[i]
        return v[i - 1] + (v[i] - v[i - 1]) * ((p - a) / (b - a))

    def sample(self, positions_m) -> np.ndarray:
        """The values at an array of positions (m)."""
        return np.array([self(float(p)) for p in np.ravel(positions_m)]).reshape(np.shape(positions_m))

    def still_radius_m(self, tolerance: float) -> float:
        """How far the position may move before the value can have changed by ``tolerance / 2`` of itself, m.

        ``inf`` for a constant curve; 0 where the value reaches 0 or a polynomial
        has no span (every position must be evaluated).
        """
        if self.is_constant:
            return math.inf
        if self.poly:
            if self.span_m is None:
                return 0.0
            p = np.linspace(self.span_m[0], self.span_m[1], 1025)
            y = np.abs(np.polynomial.polynomial.polyval(p, self.poly))
            slope = np.abs(np.polynomial.polynomial.polyval(p, np.polynomial.polynomial.polyder(self.poly)))
            smallest, steepest = float(y.min()), float(slope.max())
        else:
            x, v = np.asarray(self.positions_m), np.asarray(self.values)
            smallest = float(np.abs(v).min())
            steepest = float(np.max(np.abs(np.diff(v) / np.diff(x))))
        if smallest <= 0.0:
            return 0.0
        # 0.4 instead of 0.5: margin for a polynomial's slope sampled between the grid points.
        return 0.4 * tolerance * smallest / steepest


def model_at(model, position_m: float, stiffness: PositionCurve | None = None, damping: PositionCurve | None = None):
    """``model`` (a TwoMass or ThreeMass) with its first coupling's ``k``, ``d`` taken at ``position_m``.

    A curve that is None leaves that coefficient as it is.
    """
    changes = {}
    if stiffness is not None:
        changes["k"] = stiffness(float(position_m))
    if damping is not None:
        changes["d"] = damping(float(position_m))
    return dataclasses.replace(model, **changes) if changes else model
