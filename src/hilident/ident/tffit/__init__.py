"""Continuous-time transfer functions fitted to a measured frequency response.

The lecture ("Frequency Response Model", Q3) fits ``G^(s) = N(s) / D(s)`` to
a measured Bode plot by minimising::

    C = 1/(n+1) sum_i |G(j w_i) - G^(j w_i)|^2

:func:`fit_transfer_function` does this in three stages:

1. **Levy**: multiplying out the denominator, ``G D - N = 0`` is linear in the
   coefficients and is solved by least squares. It over-weights the bins
   where ``|D|`` is large (high frequencies, poles far away).
2. **Sanathanan-Koerner**: the Levy problem re-solved with each bin divided by
   ``|D(j w)|`` of the previous iterate, so that at convergence the error
   minimised is the error in ``G`` itself. Unstable poles of an iterate are
   reflected into the left half plane (``p -> -conj(p)``, same ``|D(j w)|``)
   before it is used again.
3. **Levenberg-Marquardt** (``scipy.optimize.least_squares``) on the true
   complex error. The denominator is a product of quadratics
   ``x^2 + a1 x + a0`` (and one ``x + c`` for odd order) with ``a1, a0, c``
   stored as logarithms, so every iterate is stable; the numerator is
   optimal for each denominator (linear least squares, "variable
   projection").

``s`` is normalised by a reference frequency (default the geometric mean of
the band), ``x = s / (2 pi reference_hz)``, and the weighted response by its rms, so
that polynomial coefficients stay near 1 and high orders stay well
conditioned.

Weights
-------
``weights=None`` minimises the lecture's ``C`` as written (absolute error:
bins where ``|G|`` is large dominate). ``weights="coherence"`` weights every
bin by the inverse standard deviation of an averaged estimate implied by its
coherence ``coh`` (thesis eq. 2.46) over ``n = frf.n_averages`` averages::

    w = sqrt(n coh / (1 - coh)) / |G|

since ``E|G^ - G|^2 ~ |G|^2 (1 - coh) / (n coh)`` for H1. This is maximum
likelihood for Gaussian errors, fits low- and high-gain regions alike
(relative error), and makes ``weighted_cost`` about 1 when the model explains
the data to within its noise. An array gives the weights directly (inverse
standard deviation per bin).

Rigid-body modes and delay
--------------------------
``integrators=k`` fixes ``k`` poles at ``s = 0`` (a velocity response of a
free axis has one): ``s^k G`` is fitted with weights ``w / |s|^k``, which is
the same error in ``G``. ``delay_s`` is a known pure delay
``exp(-s delay_s)``, removed from the data before fitting and put back by
:meth:`TfFit.response`; it is not part of ``num`` / ``den``.

Examples
--------
>>> import numpy as np
>>> from scipy import signal
>>> from hilident.ident.frequency import FrequencyResponse
>>> from hilident.ident.tffit import fit_transfer_function, modal_form
>>> w0, zeta = 2 * np.pi * 50.0, 0.02
>>> f = np.geomspace(5.0, 500.0, 200)
>>> h = signal.freqs([w0**2], [1.0, 2 * zeta * w0, w0**2], 2 * np.pi * f)[1]
>>> fit = fit_transfer_function(FrequencyResponse(f, h, np.ones(f.size), 10, "h1"), 0, 2)
>>> ((f_hz, z),) = modal_form(fit).resonances
>>> print(f"{f_hz:.3f} Hz, zeta {z:.4f}, gain {modal_form(fit).gain:.4f}")
50.000 Hz, zeta 0.0200, gain 1.0000

Layout
------
- :mod:`~hilident.ident.tffit.model`: :class:`TfFit`, :class:`ModalModel`, :func:`modal_form`
- :mod:`~hilident.ident.tffit.fit`: :func:`fit_transfer_function`
- :mod:`~hilident.ident.tffit.order`: :func:`select_order`, :func:`select_structure`
- :mod:`~hilident.ident.tffit.roots`: :class:`RootReport`, :func:`classify_roots`
"""

from hilident.ident.tffit.fit import fit_transfer_function
from hilident.ident.tffit.model import ModalModel, TfFit, TfOrderCandidate, modal_form
from hilident.ident.tffit.order import select_order, select_structure
from hilident.ident.tffit.roots import RootReport, classify_roots

__all__ = [
    "ModalModel",
    "RootReport",
    "TfFit",
    "TfOrderCandidate",
    "classify_roots",
    "fit_transfer_function",
    "modal_form",
    "select_order",
    "select_structure",
]
