"""The frequency response of a system with several inputs and outputs, and the checks of its signals.

:class:`MimoResponse` is what every estimator of :mod:`hilident.ident.mimo` returns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import ConfigError, DataError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.preprocess import check_signals

__all__ = ["MimoResponse"]


@dataclass(frozen=True, eq=False)
class MimoResponse:
    """A measured frequency response of a system with ``n_in`` inputs and ``n_out`` outputs.

    Attributes
    ----------
    frequency_hz : ndarray, shape (F,)
        Frequencies, Hz, ascending.
    response : ndarray of complex, shape (F, n_out, n_in)
        ``response[f, j, i]``: output ``j`` per unit of input ``i``.
    multiple_coherence : ndarray, shape (F, n_out)
        Fraction of each output's power at each frequency that the inputs
        explain linearly, all of them together, in [0, 1]; NaN where it cannot
        be told (a singular input matrix, one period only).
    std : ndarray, shape (F, n_out, n_in)
        Standard deviation of the real part of each response element's
        estimate, equal to that of its imaginary part: the error is taken as
        circular complex Gaussian, so ``std = sqrt(E|H_est - H|^2 / 2)`` and
        ``Re H +- 2 std`` and ``Im H +- 2 std`` are each about a 95 %
        interval (the circle ``|H_est - H| <= 2.45 std`` holds 95 % of the
        complex error). Random error only: the leakage bias of a window near a
        sharp resonance is not included. NaN where not available.
    input_condition : ndarray, shape (F,)
        Condition number of the inputs' cross-spectral matrix scaled to unit
        diagonal (their coherence matrix): 1 for uncorrelated inputs, large
        when some inputs move together, ``inf`` where singular. Scaling makes
        it independent of the inputs' units and levels. For an orthogonal
        periodic estimate the matrix is ``U U^H`` over the blocks; NaN for a
        zippered one, in which no matrix is inverted.
    n_averages : int
        Segments (Welch) or periods averaged.
    method : str
        ``"h1"``, ``"hv"``, ``"periodic"`` (zippered) or ``"orthogonal"``.
    warnings : tuple of str
        What makes the estimate doubtful (correlated inputs, ...).
    measured : ndarray of bool, shape (F, n_in)
        ``measured[f, i]``: the responses to input ``i`` at frequency ``f``
        were measured there; False where they were interpolated from the
        neighbouring measured lines (zippered periodic estimate). Default
        all True.
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    multiple_coherence: np.ndarray
    std: np.ndarray
    input_condition: np.ndarray
    n_averages: int
    method: str
    warnings: tuple[str, ...] = ()
    measured: np.ndarray | None = None

    def __post_init__(self):
        f = np.asarray(self.frequency_hz, dtype=np.float64)
        h = np.asarray(self.response, dtype=np.complex128)
        if f.ndim != 1 or h.ndim != 3 or h.shape[0] != f.size:
            raise DataError(f"frequency_hz must be (F,) and response (F, n_out, n_in), got {f.shape} and {h.shape}")
        n_f, n_out, n_in = h.shape
        arrays = {
            "multiple_coherence": (np.float64, (n_f, n_out)),
            "std": (np.float64, (n_f, n_out, n_in)),
            "input_condition": (np.float64, (n_f,)),
            "measured": (np.bool_, (n_f, n_in)),
        }
        for name, (dtype, shape) in arrays.items():
            value = getattr(self, name)
            value = np.ones(shape, dtype=bool) if value is None else np.asarray(value, dtype=dtype)
            if value.shape != shape:
                raise DataError(f"{name} must have shape {shape} to match response {h.shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        coherence = self.multiple_coherence[np.isfinite(self.multiple_coherence)]
        if coherence.size and (coherence.min() < 0.0 or coherence.max() > 1.0):
            raise DataError("multiple_coherence must lie in [0, 1] (or be NaN)")
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "response", h)
        object.__setattr__(self, "n_averages", int(self.n_averages))
        object.__setattr__(self, "warnings", tuple(str(w) for w in self.warnings))

    def __len__(self) -> int:
        return self.frequency_hz.size

    @property
    def n_outputs(self) -> int:
        return self.response.shape[1]

    @property
    def n_inputs(self) -> int:
        return self.response.shape[2]

    def element(self, j: int, i: int) -> FrequencyResponse:
        """The response of output `j` to input `i` as a single-input :class:`FrequencyResponse`.

        Its coherence is the multiple coherence of output `j` (how well all
        the inputs together explain that output), so tools written for one
        input (resonance search, transfer-function fits, plots) read one
        element as they read a single-input measurement.
        """
        if int(j) != j or not 0 <= j < self.n_outputs:
            raise ConfigError("j", f"must be an output index in 0..{self.n_outputs - 1}, got {j!r}")
        if int(i) != i or not 0 <= i < self.n_inputs:
            raise ConfigError("i", f"must be an input index in 0..{self.n_inputs - 1}, got {i!r}")
        return FrequencyResponse(
            frequency_hz=self.frequency_hz.copy(),
            response=self.response[:, int(j), int(i)].copy(),
            coherence=self.multiple_coherence[:, int(j)].copy(),
            n_averages=self.n_averages,
            method=self.method,
        )


# --- signals -------------------------------------------------------------------------------------------------


def _as_columns(x: ArrayLike, what: str) -> np.ndarray:
    """`x` as a float64 array of shape (samples, channels); a 1-D array is one channel."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{what} is not numeric: {exc}") from None
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[1] == 0:
        raise DataError(f"{what} must have shape (samples,) or (samples, channels), got {a.shape}")
    if a.shape[0] < a.shape[1]:
        raise DataError(f"{what} has shape {a.shape}: fewer samples than channels (transposed?)")
    return a


def _checked_channels(inputs: ArrayLike, outputs: ArrayLike) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each input and output column, validated (finite, not constant, all the same length)."""
    u, y = _as_columns(inputs, "inputs"), _as_columns(outputs, "outputs")
    if u.shape[0] != y.shape[0]:
        raise DataError(f"inputs have {u.shape[0]} samples but outputs have {y.shape[0]}")
    columns = {f"input {i}": u[:, i] for i in range(u.shape[1])}
    columns.update({f"output {j}": y[:, j] for j in range(y.shape[1])})
    sig = check_signals(columns, copy=False)
    return [sig[f"input {i}"] for i in range(u.shape[1])], [sig[f"output {j}"] for j in range(y.shape[1])]


def _positive_int(value, key: str, least: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < least:
        raise ConfigError(key, f"must be an integer >= {least}, got {value!r}")
    return int(value)
