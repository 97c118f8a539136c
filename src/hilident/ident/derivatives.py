"""Time derivatives of sampled signals for continuous-time identification.

Differentiating a measured signal amplifies its noise (lecture, "Signal
Filtering"). The state-variable filter (SVF) instead passes the signal through
a low-pass ``F(s)`` of order ``n`` and reads the derivatives of the *filtered*
signal as the outputs of ``s^k F(s)``, ``k = 0..n_derivatives``. When the same
filter is applied to the input and the output of a linear ODE, the ODE holds
for the filtered signals with the same coefficients::

    m y'' + b y' + k y = F   =>   m y_f'' + b y_f' + k y_f = F_f

so ``[y_f'', y_f', y_f]`` and ``F_f`` can go straight into least squares.

Discretisation
--------------
Each ``s^k F(s)`` is discretised with the bilinear (Tustin) transform, the
corner prewarped to `cutoff_hz`. All rows then share one digital low-pass
``F(z)`` and one digital differentiator ``S(z) = 2 fs (z - 1) / (z + 1)``: row
``k`` is exactly ``S(z)^k`` times row 0, so the relations between the rows are
consistent. ``S`` has the exact 90-degree phase of ``d/dt``; its gain is
``2 fs tan(pi f / fs)`` instead of ``2 pi f``, a relative error of about
``(2 pi f / fs)^2 / 12`` (0.013 % at ``f = fs / 250``). Keep `cutoff_hz` well
below Nyquist.

Zero phase (default): the forward pass runs ``s^k F(z)``, then ``F(z)`` runs
once more backwards over every row (as in ``sosfiltfilt``). The result has no
phase lag, magnitude ``|F|^2`` (a Butterworth is then -6 dB at `cutoff_hz`)
and the same consistency between rows. ``zero_phase=False`` gives the causal
SVF (forward pass only), for on-line use.

The samples are assumed to be samples of continuous signals (an encoder
position, a measured current). A force held constant from one sample to the
next (zero-order hold) acts half a sample later than such a sample says; read
as samples, it shifts a damping estimate by roughly ``(T/2)(k - m w^2)`` (``w``
a typical frequency of the motion). The grey-box functions correct for it with
``input_hold="zoh"``.

Edges: the signal is extended by odd reflection before filtering; the first
and last :func:`settling_samples` samples still carry the start-up transient
and should not enter a regression.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.derivatives import state_variable_filter
>>> fs = 1000.0
>>> t = np.arange(20000) / fs
>>> d = state_variable_filter(np.sin(2 * np.pi * t), fs, cutoff_hz=20.0, n_derivatives=2)
>>> mid = slice(5000, 15000)
>>> bool(np.allclose(d[2, mid], -(2 * np.pi) ** 2 * d[0, mid], rtol=0, atol=1e-3))
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.ident.preprocess import central_difference, check_signals

__all__ = [
    "state_variable_filter",
    "finite_difference_derivatives",
    "svf_sections",
    "settling_samples",
]

_KINDS = ("butterworth", "repeated_pole")


def _check_rate(sample_rate_hz: float) -> float:
    fs = float(sample_rate_hz)
    if not np.isfinite(fs) or fs <= 0.0:
        raise ConfigError("sample_rate_hz", f"must be a positive number, got {sample_rate_hz!r}")
    return fs


def _check_cutoff(cutoff_hz: float, fs: float) -> float:
    fc = float(cutoff_hz)
    if not np.isfinite(fc) or fc <= 0.0 or fc >= fs / 2.0:
        raise ConfigError("cutoff_hz", f"must lie in (0, {fs / 2.0:g}) Hz (below Nyquist), got {cutoff_hz!r}")
    return fc


def _check_counts(n_derivatives: int, order: int | None) -> tuple[int, int]:
    if int(n_derivatives) != n_derivatives or n_derivatives < 0:
        raise ConfigError("n_derivatives", f"must be an integer >= 0, got {n_derivatives!r}")
    n_derivatives = int(n_derivatives)
    if order is None:
        return n_derivatives, n_derivatives + 1
    if int(order) != order or order < n_derivatives + 1:
        raise ConfigError(
            "order",
            f"must be an integer >= n_derivatives + 1 = {n_derivatives + 1} so that every "
            f"s^k F(s) is strictly proper, got {order!r}",
        )
    return n_derivatives, int(order)


def _analog_poles(fs: float, fc: float, n: int, kind: str) -> tuple[np.ndarray, float]:
    """Poles (rad/s) and gain of ``F(s)`` with unit DC gain, corner prewarped."""
    if kind not in _KINDS:
        raise ConfigError("kind", f"must be one of {_KINDS}, got {kind!r}")
    wf = 2.0 * fs * np.tan(np.pi * fc / fs)
    if kind == "butterworth":
        p = signal.buttap(n)[1] * wf
    else:
        p = np.full(n, -wf, dtype=complex)
    return p, wf**n


def svf_sections(
    sample_rate_hz: float,
    cutoff_hz: float,
    n_derivatives: int,
    order: int | None = None,
    kind: str = "butterworth",
) -> list[np.ndarray]:
    """Digital second-order sections of ``s^k F(s)`` for ``k = 0..n_derivatives``.

    Parameters
    ----------
    sample_rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float
        Corner of ``F``, Hz (prewarped, so the digital filter has it exactly):
        the -3 dB point of a Butterworth, the pole frequency of the
        repeated-pole filter ``wf^n / (s + wf)^n``.
    n_derivatives : int
        Highest derivative.
    order : int, optional
        Order ``n`` of ``F``; at least ``n_derivatives + 1`` (default).
    kind : {"butterworth", "repeated_pole"}
        Butterworth (flat pass band, sharp roll-off) or the classic SVF
        ``wf^n / (s + wf)^n``.

    Returns
    -------
    list of ndarray
        ``sos`` arrays (scipy layout, ``a0 = 1``), element ``k`` for ``s^k F(s)``.
    """
    fs = _check_rate(sample_rate_hz)
    fc = _check_cutoff(cutoff_hz, fs)
    n_derivatives, n = _check_counts(n_derivatives, order)
    p, gain = _analog_poles(fs, fc, n, kind)
    sections = []
    for k in range(n_derivatives + 1):
        zd, pd, kd = signal.bilinear_zpk(np.zeros(k), p, gain, fs)
        sections.append(signal.zpk2sos(zd, pd, kd))
    return sections


def settling_samples(
    sample_rate_hz: float,
    cutoff_hz: float,
    order: int,
    kind: str = "butterworth",
    tol: float = 1e-5,
) -> int:
    """Samples after which the low-pass ``F`` has settled to `tol` of its peak response.

    The first and last this many samples of :func:`state_variable_filter`
    output depend on how the signal was extended beyond its ends; regressions
    should drop them.
    """
    fs = _check_rate(sample_rate_hz)
    fc = _check_cutoff(cutoff_hz, fs)
    if not 0.0 < tol < 1.0:
        raise ConfigError("tol", f"must lie in (0, 1), got {tol!r}")
    sos = svf_sections(fs, fc, 0, order=order, kind=kind)[0]
    p, _ = _analog_poles(fs, fc, int(order), kind)
    poles = (1.0 + p / (2.0 * fs)) / (1.0 - p / (2.0 * fs))  # bilinear map
    # samples for the slowest pole to decay to tol; more for the t^(n-1) growth
    # of repeated poles, doubled until the response has really settled
    length = int(4.0 * np.log(tol) / np.log(np.abs(poles).max())) + 64
    while True:
        impulse = np.zeros(length)
        impulse[0] = 1.0
        h = np.abs(signal.sosfilt(sos, impulse))
        last = int(np.flatnonzero(h > tol * h.max())[-1]) + 1
        if last < length // 2:
            return last
        length *= 2


def state_variable_filter(
    x: ArrayLike,
    sample_rate_hz: float,
    cutoff_hz: float,
    n_derivatives: int,
    order: int | None = None,
    kind: str = "butterworth",
    zero_phase: bool = True,
) -> np.ndarray:
    """Low-pass filtered signal and its derivatives (state-variable filter).

    Parameters
    ----------
    x : array_like
        1-D samples, e.g. position in m.
    sample_rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float
        Corner of the low-pass, Hz; well above the dynamics to be identified,
        well below Nyquist.
    n_derivatives : int
        Highest derivative returned.
    order : int, optional
        Filter order, ``>= n_derivatives + 1`` (default). Use the same order
        (and cutoff, kind, zero_phase) for every signal of one regression.
    kind : {"butterworth", "repeated_pole"}
        See :func:`svf_sections`.
    zero_phase : bool
        Forward ``s^k F`` then backward ``F`` (default), or causal forward only.

    Returns
    -------
    ndarray, shape (n_derivatives + 1, N)
        Row ``k`` is the ``k``-th time derivative of the filtered signal, in
        units of x per s^k.

    Raises
    ------
    DataError
        `x` is not 1-D, non-finite, constant or shorter than 16 samples.
    ConfigError
        Bad rate, cutoff, order or kind.
    """
    x = check_signals({"x": x})["x"]
    fs = _check_rate(sample_rate_hz)
    n_derivatives, n = _check_counts(n_derivatives, order)
    sections = svf_sections(fs, cutoff_hz, n_derivatives, order=n, kind=kind)
    N = x.size
    if not zero_phase:
        out = np.empty((n_derivatives + 1, N))
        for k, sos in enumerate(sections):
            # steady state for a signal that was x[0] forever: zero derivatives
            zi = signal.sosfilt_zi(sos) * x[0]
            out[k], _ = signal.sosfilt(sos, x, zi=zi)
        return out

    pad = min(settling_samples(fs, cutoff_hz, n, kind=kind), N - 1)
    # odd extension keeps value and slope continuous at the ends
    ext = np.concatenate([2.0 * x[0] - x[pad:0:-1], x, 2.0 * x[-1] - x[-2 : -pad - 2 : -1]])
    forward = np.empty((n_derivatives + 1, ext.size))
    for k, sos in enumerate(sections):
        forward[k], _ = signal.sosfilt(sos, ext, zi=signal.sosfilt_zi(sos) * ext[0])
    back = sections[0]
    zi = signal.sosfilt_zi(back)[:, None, :] * forward[None, :, -1, None]
    rev, _ = signal.sosfilt(back, forward[:, ::-1], axis=-1, zi=zi)
    return np.ascontiguousarray(rev[:, ::-1][:, pad : pad + N])


def finite_difference_derivatives(x: ArrayLike, sample_rate_hz: float, n: int) -> np.ndarray:
    """Unfiltered derivatives by repeated central differences, for comparison.

    Row ``k`` is :func:`hilident.ident.preprocess.central_difference` applied
    ``k`` times (stencil ``2k + 1`` samples wide, one-sided at the ends). Noise
    is not suppressed: white noise of std ``s`` on `x` gives roughly
    ``s * fs^k`` on row ``k``.

    Returns
    -------
    ndarray, shape (n + 1, N)
    """
    x = check_signals({"x": x})["x"]
    if int(n) != n or n < 0:
        raise ConfigError("n", f"must be an integer >= 0, got {n!r}")
    if x.size < 2 * int(n) + 1:
        raise DataError(f"{x.size} samples are too few for derivative {n}")
    rows = [x]
    for _ in range(int(n)):
        rows.append(central_difference(rows[-1], sample_rate_hz))
    return np.vstack(rows)
