"""Nonparametric frequency responses of systems with several inputs and outputs.

With two or more inputs acting at once (two axes of a gantry, a motor and a
load torque, an actuator and a disturbance that is measured), the single-input
estimate of :mod:`hilident.ident.frequency` sees the other inputs as noise: its
coherence drops and, when the inputs are correlated, its response is biased.
The estimates here take every input into account at once.

* :func:`mimo_h1` -- random excitation, noise on the outputs:
  ``H1 = S_yu S_uu^-1`` per frequency from Welch-averaged cross-spectral
  matrices, with multiple coherence and standard deviations.
* :func:`mimo_hv` -- random excitation, noise on inputs and outputs alike:
  the total-least-squares (errors-in-variables) estimate per output.
* :func:`zippered_multisine` and :func:`periodic_mimo_frf` -- periodic
  excitation in which every input excites its own DFT bins: each response
  element is a plain ratio at its input's bins, no matrix to invert, no window.
* :func:`modal_analysis` (:mod:`hilident.ident.mimo.modal`) -- modal parameters
  from all outputs and inputs at once: polyreference LSCF poles, a
  stabilisation diagram, LSFD shapes and their MAC; :func:`modal_intervals`,
  95 % intervals of each mode's frequency and damping from independent groups
  of the record and a maximum-likelihood refinement (:func:`refine_poles`).
* :func:`orthogonal_multisine` and :func:`orthogonal_mimo_frf` -- ``n_in``
  periodic experiments in which every input excites every bin, in orthogonal
  phase patterns: every element measured at every bin.

Conventions. ``H[f, j, i]`` is the response of output ``j`` to input ``i``
(units of output ``j`` per unit of input ``i``). Spectra are cross products of
windowed segment transforms averaged over the segments, as in
:mod:`hilident.ident.frequency`; their scaling cancels in every ratio used.
Frequencies in Hz.

Sources: J. S. Bendat, A. G. Piersol, *Random Data*, 4th ed., Wiley 2010,
ch. 7 (multiple-input systems, multiple coherence) and ch. 9 (random errors);
R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
Approach*, 2nd ed., Wiley-IEEE 2012 (FRF measurement of multiple-input
systems, Hv, zippered and orthogonal multisines).

Examples
--------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.mimo import mimo_h1
>>> rng = np.random.default_rng(0)
>>> u = rng.standard_normal((100_000, 2))
>>> y = signal.lfilter([0.2], [1.0, -0.8], u[:, 0]) + 0.5 * u[:, 1]
>>> frf = mimo_h1(u, y, sample_rate_hz=1000.0, segment_length=1024)
>>> frf.response.shape
(513, 1, 2)
>>> bool(abs(frf.response[10, 0, 1] - 0.5) < 0.02)
True
"""

from hilident.ident.mimo.modal import ModalResult, Mode, mac, mac_matrix, modal_analysis, modal_intervals, refine_poles
from hilident.ident.mimo.periodic import (
    ZIPPER_LEAKAGE,
    orthogonal_mimo_frf,
    orthogonal_multisine,
    periodic_mimo_frf,
    zippered_lines,
    zippered_multisine,
)
from hilident.ident.mimo.response import MimoResponse
from hilident.ident.mimo.spectral import (
    CORRELATED_FRACTION,
    POWER_FLOOR,
    SINGULAR_CONDITION,
    leave_one_out_h1,
    mimo_h1,
    mimo_hv,
)

__all__ = [
    "CORRELATED_FRACTION",
    "POWER_FLOOR",
    "SINGULAR_CONDITION",
    "ZIPPER_LEAKAGE",
    "MimoResponse",
    "ModalResult",
    "Mode",
    "mac",
    "mac_matrix",
    "modal_analysis",
    "modal_intervals",
    "refine_poles",
    "leave_one_out_h1",
    "mimo_h1",
    "mimo_hv",
    "zippered_lines",
    "zippered_multisine",
    "periodic_mimo_frf",
    "orthogonal_multisine",
    "orthogonal_mimo_frf",
]
