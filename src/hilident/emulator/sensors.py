"""Sensors of the emulated axis: what a drive and a load laser report of the true state.

* Encoder on the driven mass: position (plus interpolation noise, if any) floored
  to whole counts.
* Torque: the applied torque plus white Gaussian noise.
* Laser on the load (the thesis's Baumer sensor, mounted on the cart): the load
  position ``p2`` with noise and a finite resolution, NaN while the load's
  deflection from the cart ``p2 - p1`` is outside the sensor's window.

Noise comes from a seeded numpy Generator, drawn in blocks for speed. Torque,
laser and encoder noise use independent streams (children of one
``SeedSequence``), so enabling one does not shift the others.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hilident.errors import ConfigError
from hilident.numbers import number

__all__ = ["SensorModel"]

_BLOCK = 4096


class SensorModel:
    """Turns the true plant state into measured values.

    Parameters
    ----------
    encoder_resolution_m : float
        One encoder count, m; 0 gives an ideal (unquantised) position.
    encoder_noise_m : float
        Standard deviation of the encoder's interpolation noise, added to the
        position before it is floored to counts, m.
    torque_noise_nm : float
        Standard deviation of the torque measurement noise, N·m.
    laser_range_m : sequence of two floats
        Window ``(min, max)`` of the load deflection ``p2 - p1`` (m) inside which
        the laser reads; outside it returns NaN. The default spans 104 mm like the
        thesis's 16-120 mm sensor, centred on the undeflected load.
    laser_noise_m : float
        Standard deviation of the laser noise, m.
    laser_resolution_m : float
        Laser output step, m (the thesis's sensor: about 0.12e-3); 0 for none.
    seed : int or numpy.random.SeedSequence
        Seed of the noise streams; the same seed gives the same noise.

    Examples
    --------
    >>> s = SensorModel(encoder_resolution_m=1e-6, seed=1)
    >>> round(s.encoder(2.5e-6) / 1e-6)
    2
    >>> s.laser(0.0, 1.0)
    nan
    """

    def __init__(
        self,
        *,
        encoder_resolution_m: float = 1e-6,
        torque_noise_nm: float = 0.0,
        laser_range_m: Sequence[float] = (-0.052, 0.052),
        laser_noise_m: float = 0.0,
        laser_resolution_m: float = 0.0,
        encoder_noise_m: float = 0.0,
        seed,
    ):
        self.encoder_resolution_m = number("encoder_resolution_m", encoder_resolution_m)
        self.encoder_noise_m = number("encoder_noise_m", encoder_noise_m)
        self.torque_noise_nm = number("torque_noise_nm", torque_noise_nm)
        self.laser_noise_m = number("laser_noise_m", laser_noise_m)
        self.laser_resolution_m = number("laser_resolution_m", laser_resolution_m)
        try:
            lo, hi = (float(x) for x in laser_range_m)
        except (TypeError, ValueError):
            raise ConfigError("laser_range_m", f"must be a pair (min, max) in m, got {laser_range_m!r}") from None
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise ConfigError("laser_range_m", f"needs min < max, got {laser_range_m!r}")
        self.laser_range_m = (lo, hi)
        if seed is None or isinstance(seed, bool):
            raise ConfigError("seed", f"must be an int or SeedSequence, got {seed!r}")
        self.seed = seed
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        # spawn(3)'s first two children are spawn(2)'s: adding the encoder stream kept the others.
        torque_ss, laser_ss, encoder_ss = ss.spawn(3)
        self._torque_rng = np.random.Generator(np.random.PCG64(torque_ss))
        self._laser_rng = np.random.Generator(np.random.PCG64(laser_ss))
        self._encoder_rng = np.random.Generator(np.random.PCG64(encoder_ss))
        self._encoder_buf: list[float] = []
        self._encoder_i = 0
        self._torque_buf: list[float] = []
        self._torque_i = 0
        self._laser_buf: list[float] = []
        self._laser_i = 0

    def encoder(self, p1: float) -> float:
        """Encoder position (m) of the driven mass at true position ``p1``: floor to counts."""
        if self.encoder_noise_m != 0.0:
            i = self._encoder_i
            if i >= len(self._encoder_buf):
                self._encoder_buf = self._encoder_rng.standard_normal(_BLOCK).tolist()
                i = 0
            self._encoder_i = i + 1
            p1 = p1 + self.encoder_noise_m * self._encoder_buf[i]
        r = self.encoder_resolution_m
        if r == 0.0:
            return p1
        return math.floor(p1 / r) * r

    def torque(self, applied_nm: float) -> float:
        """Measured torque (N·m): ``applied_nm`` plus Gaussian noise."""
        sigma = self.torque_noise_nm
        if sigma == 0.0:
            return applied_nm
        i = self._torque_i
        if i >= len(self._torque_buf):
            self._torque_buf = self._torque_rng.standard_normal(_BLOCK).tolist()
            i = 0
        self._torque_i = i + 1
        return applied_nm + sigma * self._torque_buf[i]

    def laser(self, p1: float, p2: float) -> float:
        """Laser reading of the load position (m), NaN when ``p2 - p1`` is out of range.

        The reading is the load position ``p2`` on the encoder's axis plus noise,
        rounded to ``laser_resolution_m``.
        """
        lo, hi = self.laser_range_m
        deflection = p2 - p1
        if not lo <= deflection <= hi:
            return math.nan
        y = p2
        sigma = self.laser_noise_m
        if sigma != 0.0:
            i = self._laser_i
            if i >= len(self._laser_buf):
                self._laser_buf = self._laser_rng.standard_normal(_BLOCK).tolist()
                i = 0
            self._laser_i = i + 1
            y += sigma * self._laser_buf[i]
        r = self.laser_resolution_m
        if r != 0.0:
            y = math.floor(y / r + 0.5) * r
        return y
