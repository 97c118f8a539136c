"""The emulated drive's plant exactly, as its loop sees it tick by tick: the truth for loop predictions."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from hilident.emulator.plant import state_matrices


def plant_position(model, frequency_hz, rate_hz: float) -> np.ndarray:
    """Motor torque held over a tick to the encoder position read at the tick's start, m per N·m (exact ZOH)."""
    A, B = state_matrices(model)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, B * model.c
    E = expm(M / rate_hz)
    phi, gamma = E[:n, :n], E[:n, n]
    z = np.exp(2j * np.pi * np.asarray(frequency_hz, dtype=float) / rate_hz)
    return np.array([np.linalg.solve(zk * np.eye(n) - phi, gamma)[0] for zk in np.atleast_1d(z)])
