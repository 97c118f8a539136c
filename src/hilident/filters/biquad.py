"""Second-order IIR sections ("biquads") as a drive runs them.

A biquad is ``b = (b0, b1, b2)``, ``a = (1, a1, a2)`` in scipy's sign convention::

    y[n] = b0 x[n] + b1 x[n-1] + b2 x[n-2] - a1 y[n-1] - a2 y[n-2]

:class:`Biquad` holds coefficients; :class:`BiquadSection` and :class:`BiquadChain`
hold the state of a running filter and are stepped one sample at a time in
transposed direct form II, the structure most servo drives use.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Biquad", "BiquadChain", "BiquadSection"]


@dataclass(frozen=True)
class Biquad:
    """Coefficients of one second-order section.

    Parameters
    ----------
    b : tuple of float
        Numerator ``(b0, b1, b2)``.
    a : tuple of float
        Denominator ``(1, a1, a2)``; ``a[0]`` must be 1.
    """

    b: tuple[float, float, float]
    a: tuple[float, float, float]

    def __post_init__(self):
        b = tuple(float(x) for x in self.b)
        a = tuple(float(x) for x in self.a)
        if len(b) != 3 or len(a) != 3:
            raise ValueError("a biquad needs three b and three a coefficients")
        if a[0] != 1.0:
            raise ValueError(f"a[0] must be 1, got {a[0]!r}")
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "a", a)

    @classmethod
    def from_sequences(cls, b: Sequence[float], a: Sequence[float]) -> Biquad:
        """A section from two sequences of three numbers each (lists read from JSON, arrays).

        Raises
        ------
        ValueError
            Not three coefficients each, or ``a[0] != 1``.
        """
        if len(b) != 3 or len(a) != 3:
            raise ValueError("a biquad needs three b and three a coefficients")
        return cls((float(b[0]), float(b[1]), float(b[2])), (float(a[0]), float(a[1]), float(a[2])))

    @classmethod
    def identity(cls) -> Biquad:
        """The pass-through section ``H(z) = 1``."""
        return cls((1.0, 0.0, 0.0), (1.0, 0.0, 0.0))

    def poles(self) -> np.ndarray:
        """Poles in the z-plane."""
        return np.roots(self.a) if self.a[2] != 0.0 or self.a[1] != 0.0 else np.zeros(0)

    def is_stable(self, margin: float = 0.0) -> bool:
        """True when every pole lies strictly inside the circle of radius ``1 - margin``."""
        poles = self.poles()
        return bool(np.all(np.abs(poles) < 1.0 - margin))

    def dc_gain(self) -> float:
        """Gain at 0 Hz, ``H(z=1)``."""
        return sum(self.b) / sum(self.a)

    def response(self, frequency_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """Complex frequency response at ``frequency_hz`` for a filter run at ``sample_rate_hz``."""
        z = np.exp(1j * 2.0 * np.pi * np.asarray(frequency_hz, dtype=float) / sample_rate_hz)
        zi = 1.0 / z
        num = self.b[0] + self.b[1] * zi + self.b[2] * zi * zi
        den = 1.0 + self.a[1] * zi + self.a[2] * zi * zi
        return num / den


class BiquadSection:
    """A running biquad (transposed direct form II), stepped one sample at a time.

    Parameters
    ----------
    coefficients : Biquad, optional
        Initial coefficients; the identity section when omitted.
    """

    __slots__ = ("b0", "b1", "b2", "a1", "a2", "s1", "s2")

    def __init__(self, coefficients: Biquad | None = None):
        self.s1 = 0.0
        self.s2 = 0.0
        self.load(coefficients or Biquad.identity())

    def load(self, coefficients: Biquad) -> None:
        """Replace the coefficients and clear the state (no bumpless transfer)."""
        self.b0, self.b1, self.b2 = coefficients.b
        _, self.a1, self.a2 = coefficients.a
        self.s1 = 0.0
        self.s2 = 0.0

    def step(self, x: float) -> float:
        """Filter one sample."""
        y = self.b0 * x + self.s1
        self.s1 = self.b1 * x - self.a1 * y + self.s2
        self.s2 = self.b2 * x - self.a2 * y
        return y


class BiquadChain:
    """A fixed number of biquad slots in series, each enabled or bypassed.

    Parameters
    ----------
    n_slots : int
        Number of filter slots the device offers.
    """

    def __init__(self, n_slots: int):
        self.sections = [BiquadSection() for _ in range(n_slots)]
        self.coefficients = [Biquad.identity() for _ in range(n_slots)]
        self.enabled = [False] * n_slots
        self._active: list[BiquadSection] = []

    def __len__(self) -> int:
        return len(self.sections)

    def write(self, slot: int, coefficients: Biquad, enabled: bool) -> None:
        """Store ``coefficients`` in ``slot`` and enable or bypass it."""
        self.coefficients[slot] = coefficients
        self.enabled[slot] = bool(enabled)
        self.sections[slot].load(coefficients)
        self._active = [s for s, on in zip(self.sections, self.enabled, strict=False) if on]

    def read(self, slot: int) -> tuple[Biquad, bool]:
        """Coefficients and enable flag of ``slot``."""
        return self.coefficients[slot], self.enabled[slot]

    def reset(self) -> None:
        """Clear the state of every section."""
        for s in self.sections:
            s.s1 = s.s2 = 0.0

    def step(self, x: float) -> float:
        """Pass one sample through every enabled slot in order."""
        for section in self._active:
            x = section.step(x)
        return x

    def response(self, frequency_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """Complex response of the enabled slots in series."""
        h = np.ones(np.shape(frequency_hz), dtype=complex)
        for c, on in zip(self.coefficients, self.enabled, strict=False):
            if on:
                h = h * c.response(frequency_hz, sample_rate_hz)
        return h
