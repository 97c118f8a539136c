"""Point-to-point moves that do not ring: pure numerics, no devices.

- ``profiles``: trapezoidal and jerk-limited set-point trajectories, sampled at a rate, with a dwell
- ``shaping``: a notch chain applied by the host to a position set-point, extended until it has settled
- ``residual``: residual vibration after a move (peak-to-peak, RMS, settling time) and its reduction in dB
- ``input_shapers``: impulse-train shapers (ZV, MZV, ZVD, EI, 2- and 3-hump EI), their residual vibration and choice

May import ``filters``, ``errors`` and ``numbers`` only (pure).
"""
