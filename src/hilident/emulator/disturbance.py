"""Process disturbances of an emulated axis: torques that act on it but no sensor measures.

A real axis is pushed by more than its motor: cable chains and air currents
(broadband, mostly slow), the motor's own cogging and ripple (periodic in
position) and the load changing under it (steps). :class:`ProcessDisturbance`
adds all three to the torque the drive applies, tick by tick:

* coloured noise: white Gaussian noise through a first-order low-pass at
  ``noise_corner_hz``, scaled so its standard deviation is ``noise_nm``;
* cogging: ``cogging_nm * sin(2 pi p1 / cogging_period_m)``, a function of the
  cart's true position ``p1``;
* load steps: at random instants (a Poisson process of ``load_step_rate_hz``)
  the load torque jumps to a new level drawn uniformly from
  ``[-load_step_nm, load_step_nm]``;
* load-side force noise (:meth:`load_force`): coloured noise like the torque
  noise, but acting on the load mass (floor vibration, the process the tool
  touches). It excites the mode from the far side of the spring, so near the
  anti-resonance, where the motor barely moves in answer to its own torque, it
  is what the encoder sees: the coherence there drops as on a real bench.

The drive reports the torque it applies (its current), not this one: the
disturbance is what makes a measured response differ from the plant's.
"""

from __future__ import annotations

import math

import numpy as np

from hilident.errors import ConfigError
from hilident.numbers import number

__all__ = ["ProcessDisturbance"]

_BLOCK = 4096


class ProcessDisturbance:
    """Unmeasured torque on the axis: coloured noise, cogging and load steps.

    Parameters
    ----------
    period_s : float
        Drive tick, s; :meth:`torque` is called once per tick.
    noise_nm : float
        Standard deviation of the coloured torque noise, N·m (0: none).
    noise_corner_hz : float
        Corner of the first-order low-pass that colours it, Hz.
    cogging_nm : float
        Amplitude of the position-periodic ripple, N·m (0: none).
    cogging_period_m : float
        Its period in cart position, m.
    load_step_nm : float
        Largest load-torque level a step jumps to, N·m (0: no steps).
    load_step_rate_hz : float
        Mean number of load steps per second.
    load_noise_n : float
        Standard deviation of the coloured force noise on the load, N (0: none).
    seed : int or numpy.random.SeedSequence
        Seed of the noise and the step times; the same seed gives the same torque.

    Examples
    --------
    >>> d = ProcessDisturbance(period_s=1e-3, noise_nm=0.1, noise_corner_hz=20.0, seed=1)
    >>> x = [d.torque(0.0) for _ in range(20000)]
    >>> 0.08 < float(np.std(x)) < 0.12
    True
    >>> ProcessDisturbance(period_s=1e-3, cogging_nm=0.5, cogging_period_m=0.01, seed=1).torque(0.0025)
    0.5
    """

    def __init__(
        self,
        *,
        period_s: float,
        noise_nm: float = 0.0,
        noise_corner_hz: float = 20.0,
        cogging_nm: float = 0.0,
        cogging_period_m: float = 0.01,
        load_step_nm: float = 0.0,
        load_step_rate_hz: float = 0.0,
        load_noise_n: float = 0.0,
        seed,
    ):
        self.period_s = number("period_s", period_s)
        if self.period_s == 0.0:
            raise ConfigError("period_s", "must be > 0")
        self.noise_nm = number("noise_nm", noise_nm)
        self.noise_corner_hz = number("noise_corner_hz", noise_corner_hz)
        self.cogging_nm = number("cogging_nm", cogging_nm)
        self.cogging_period_m = number("cogging_period_m", cogging_period_m)
        self.load_step_nm = number("load_step_nm", load_step_nm)
        self.load_step_rate_hz = number("load_step_rate_hz", load_step_rate_hz)
        self.load_noise_n = number("load_noise_n", load_noise_n)
        if (self.noise_nm or self.load_noise_n) and self.noise_corner_hz == 0.0:
            raise ConfigError("noise_corner_hz", "must be > 0 when there is torque noise")
        if self.cogging_nm and self.cogging_period_m == 0.0:
            raise ConfigError("cogging_period_m", "must be > 0 when there is cogging")
        if seed is None or isinstance(seed, bool):
            raise ConfigError("seed", f"must be an int or SeedSequence, got {seed!r}")
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        self._rng = np.random.Generator(np.random.PCG64(ss))
        # AR(1) low-pass: n+ = a n + b w keeps the stationary std at noise_nm.
        self._a = math.exp(-2.0 * math.pi * self.noise_corner_hz * self.period_s)
        self._b = math.sqrt(1.0 - self._a * self._a)
        self._noise = self.noise_nm * float(self._rng.standard_normal()) if self.noise_nm else 0.0
        self._load_noise = self.load_noise_n * float(self._rng.standard_normal()) if self.load_noise_n else 0.0
        self._white: list[float] = []
        self._white_i = 0
        self._step_probability = -math.expm1(-self.load_step_rate_hz * self.period_s)
        self._load = 0.0
        self._k_cog = 2.0 * math.pi / self.cogging_period_m if self.cogging_nm else 0.0

    @property
    def active(self) -> bool:
        """True when any part of the disturbance is non-zero."""
        return bool(
            self.noise_nm or self.cogging_nm or (self.load_step_nm and self.load_step_rate_hz) or self.load_noise_n
        )

    def _next_white(self) -> float:
        i = self._white_i
        if i >= len(self._white):
            self._white = self._rng.standard_normal(_BLOCK).tolist()
            i = 0
        self._white_i = i + 1
        return self._white[i]

    def torque(self, p1: float) -> float:
        """Disturbance torque (N·m) over the next tick, the cart being at ``p1`` (m)."""
        tau = 0.0
        if self.noise_nm:
            self._noise = self._a * self._noise + self._b * self.noise_nm * self._next_white()
            tau += self._noise
        if self.cogging_nm:
            tau += self.cogging_nm * math.sin(self._k_cog * p1)
        if self.load_step_nm and self._step_probability:
            if self._rng.random() < self._step_probability:
                self._load = float(self._rng.uniform(-self.load_step_nm, self.load_step_nm))
            tau += self._load
        return tau

    def load_force(self) -> float:
        """Force (N) on the load mass over the next tick."""
        if not self.load_noise_n:
            return 0.0
        self._load_noise = self._a * self._load_noise + self._b * self.load_noise_n * self._next_white()
        return self._load_noise
