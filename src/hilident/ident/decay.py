"""Poles of a lightly damped mode from a free-vibration (decay) record.

The thesis (section 3.3) bent the IRB140 arm, let it go and read the decay and
the period of the oscillation off the accelerometer record, which gave the
pole pair it writes as ``0.2554 +- 27.1412i``. That number is the decay rate
``sigma`` and the damped frequency ``omega_d``: the stable poles themselves
are ``s = -sigma +- j omega_d = -0.2554 +- 27.1412j`` (1/s, rad/s). Here
``sigma`` is always the decay rate (positive for a decaying mode) and
:attr:`DampedMode.poles` always carries the minus sign.

Any response of the mode (position, velocity, acceleration) is

    x(t) = c + A e^(-sigma t) cos(omega_d t + phi)

so one method serves all sensors. Steps:

1. ``omega_d`` from the peak of the zero-padded FFT (parabolic interpolation);
2. ``sigma`` from the logarithmic decrement: straight-line fit of the log of
   half peak-to-peak amplitudes (offset-free) against time;
3. least-squares refinement of the model above (``scipy.optimize.least_squares``),
   optionally with further damped sinusoids for overtones (the thesis saw a
   second, weaker pole pair). The amplitudes, phases and the offset enter
   linearly and are solved for inside each residual evaluation (variable
   projection), so only ``sigma`` and ``omega_d`` of each mode are iterated.

Examples
--------
>>> import numpy as np
>>> from hilident.ident.decay import decay_poles
>>> fs = 500.0
>>> t = np.arange(int(10 * fs)) / fs
>>> x = 25e-3 * np.exp(-0.2554 * t) * np.cos(27.1412 * t)
>>> fit = decay_poles(x, fs)
>>> np.round(fit.poles, 4)
array([-0.2554+27.1412j, -0.2554-27.1412j])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize, signal

from hilident.errors import ConfigError, DataError
from hilident.ident.preprocess import check_signals, lowpass
from hilident.ident.validation import fit_percent

__all__ = ["DampedMode", "DecayFit", "decay_poles"]


@dataclass(frozen=True)
class DampedMode:
    """One decaying oscillation ``A e^(-sigma t) cos(omega_d t + phi)``.

    Attributes
    ----------
    sigma : float
        Decay rate, 1/s (> 0 for a decaying mode; the poles' real part is ``-sigma``).
    omega_d : float
        Damped angular frequency, rad/s.
    amplitude : float
        ``A`` at the first sample (units of the record).
    phase_rad : float
        ``phi`` at the first sample, rad.
    sigma_stderr, omega_d_stderr : float
        Standard errors from the least-squares Jacobian (NaN if not refined).
    """

    sigma: float
    omega_d: float
    amplitude: float
    phase_rad: float
    sigma_stderr: float = float("nan")
    omega_d_stderr: float = float("nan")

    @property
    def frequency_hz(self) -> float:
        """Damped frequency ``omega_d / 2 pi``, Hz (what a period count gives)."""
        return self.omega_d / (2.0 * np.pi)

    @property
    def natural_frequency_hz(self) -> float:
        """Undamped natural frequency ``sqrt(sigma^2 + omega_d^2) / 2 pi``, Hz."""
        return float(np.hypot(self.sigma, self.omega_d) / (2.0 * np.pi))

    @property
    def damping_ratio(self) -> float:
        """``zeta = sigma / omega_n``."""
        return float(self.sigma / np.hypot(self.sigma, self.omega_d))

    @property
    def log_decrement(self) -> float:
        """``delta = ln(x_i / x_(i+1)) = 2 pi sigma / omega_d`` per period."""
        return 2.0 * np.pi * self.sigma / self.omega_d

    @property
    def poles(self) -> np.ndarray:
        """``(-sigma + j omega_d, -sigma - j omega_d)``, 1/s."""
        return np.array([complex(-self.sigma, self.omega_d), complex(-self.sigma, -self.omega_d)])


@dataclass(frozen=True)
class DecayFit:
    """Result of :func:`decay_poles`.

    Attributes
    ----------
    modes : tuple of DampedMode
        Fitted modes, largest amplitude first.
    offset : float
        Constant ``c`` of the record.
    fit_percent : float
        NRMSE fit of the model to the record, %.
    rms_residual : float
        RMS of record minus model (units of the record).
    initial : DampedMode
        Dominant mode from FFT peak and logarithmic decrement, before refinement.
    refined : bool
        Whether the least-squares refinement ran.
    """

    modes: tuple[DampedMode, ...]
    offset: float
    fit_percent: float
    rms_residual: float
    initial: DampedMode
    refined: bool

    @property
    def sigma(self) -> float:
        """Decay rate of the dominant mode, 1/s."""
        return self.modes[0].sigma

    @property
    def omega_d(self) -> float:
        """Damped angular frequency of the dominant mode, rad/s."""
        return self.modes[0].omega_d

    @property
    def frequency_hz(self) -> float:
        return self.modes[0].frequency_hz

    @property
    def damping_ratio(self) -> float:
        return self.modes[0].damping_ratio

    @property
    def poles(self) -> np.ndarray:
        """Pole pair of the dominant mode, ``-sigma +- j omega_d``, 1/s."""
        return self.modes[0].poles


def _basis(t: np.ndarray, sigmas, omegas) -> np.ndarray:
    """Columns ``e^(-s t) cos(w t)``, ``e^(-s t) sin(w t)`` per mode, then 1."""
    cols = []
    for s, w in zip(sigmas, omegas, strict=False):
        env = np.exp(-s * t)
        cols.append(env * np.cos(w * t))
        cols.append(env * np.sin(w * t))
    cols.append(np.ones_like(t))
    return np.column_stack(cols)


def _linear_part(t, x, sigmas, omegas):
    phi = _basis(t, sigmas, omegas)
    coef, *_ = np.linalg.lstsq(phi, x, rcond=None)
    return coef, x - phi @ coef


def _spectrum_peak(x: np.ndarray, fs: float, exclude_rad_s=(), min_bin: int = 3):
    """Angular frequency of the largest zero-padded FFT peak, rad/s.

    Bins within ``min_bin`` record-resolution bins of DC or of a frequency in
    `exclude_rad_s` are skipped.
    """
    n = x.size
    nfft = 1 << int(np.ceil(np.log2(8 * n)))
    mag = np.abs(np.fft.rfft(x - x.mean(), nfft))
    w = 2.0 * np.pi * np.fft.rfftfreq(nfft, 1.0 / fs)
    resolution = 2.0 * np.pi * fs / n
    mask = w > min_bin * resolution
    for w_ex in exclude_rad_s:
        mask &= np.abs(w - w_ex) > min_bin * resolution
    mask[-1] = False
    if not mask.any():
        raise DataError("record too short to find an oscillation frequency")
    k = int(np.flatnonzero(mask)[np.argmax(mag[mask])])
    if 0 < k < mag.size - 1:  # parabola through the log magnitudes of three bins
        y0, y1, y2 = np.log(mag[k - 1 : k + 2] + 1e-300)
        den = y0 - 2.0 * y1 + y2
        shift = 0.5 * (y0 - y2) / den if den < 0 else 0.0
        return float(w[k] + shift * (w[1] - w[0]))
    return float(w[k])


def _log_decrement_sigma(x: np.ndarray, fs: float, omega: float) -> float | None:
    """Decay rate from half peak-to-peak amplitudes, or None if too few peaks.

    Each positive peak is paired with the next trough; ``(x_peak - x_trough)/2``
    does not depend on the offset. ``ln`` of these against time is a line of
    slope ``-sigma`` (the logarithmic decrement per period is ``sigma T_d``).
    """
    period = 2.0 * np.pi / omega * fs
    cutoff_hz = 2.0 * omega / (2.0 * np.pi)
    if cutoff_hz < 0.4 * fs and x.size > 30 * period / 2:
        # Zero-phase low-pass: keeps the envelope of the mode, removes noise
        # and overtones that would bias the picked peaks upwards.
        x = lowpass(x, cutoff_hz, fs)
    dist = max(1, int(0.7 * period))
    peaks, _ = signal.find_peaks(x, distance=dist)
    troughs, _ = signal.find_peaks(-x, distance=dist)
    if peaks.size < 2 or troughs.size < 2:
        return None
    nxt = np.searchsorted(troughs, peaks)
    keep = nxt < troughs.size
    peaks, tr = peaks[keep], troughs[nxt[keep]]
    keep = (tr - peaks) < period  # trough within the same period
    peaks, tr = peaks[keep], tr[keep]
    amp = 0.5 * (x[peaks] - x[tr])
    if amp.size < 3 or amp.max() <= 0:
        return None
    # Noise floor from the second difference (the mode itself barely shows
    # in it when sampled well above its frequency); drop peaks near it.
    noise = np.median(np.abs(np.diff(x, 2))) / 0.6745 / np.sqrt(6.0)
    good = amp > max(5.0 * noise, 0.02 * amp.max())
    if good.sum() < 3:
        return None
    tc = 0.5 * (peaks[good] + tr[good]) / fs
    slope = np.polyfit(tc, np.log(amp[good]), 1)[0]
    return float(-slope)


def _fit_sigma_grid(t, x, omega):
    """Best decay rate for a fixed frequency from a log-spaced grid (fallback/overtones)."""
    span = t[-1] - t[0]
    grid = np.geomspace(0.1 / span, max(omega / 2.0, 1.0 / span), 40)
    costs = [np.sum(_linear_part(t, x, [s], [omega])[1] ** 2) for s in grid]
    return float(grid[int(np.argmin(costs))])


def _mode_from(coef_ab, s, w, s_err=np.nan, w_err=np.nan) -> DampedMode:
    a, b = coef_ab
    return DampedMode(
        sigma=float(s),
        omega_d=float(w),
        amplitude=float(np.hypot(a, b)),
        phase_rad=float(np.arctan2(-b, a)),
        sigma_stderr=float(s_err),
        omega_d_stderr=float(w_err),
    )


def decay_poles(
    x: ArrayLike,
    sample_rate_hz: float,
    n_modes: int = 1,
    refine: bool = True,
) -> DecayFit:
    """Pole pair(s) of a free vibration: decay rate and damped frequency.

    Parameters
    ----------
    x : array_like
        Record starting at (or after) the release, e.g. an accelerometer in
        m/s^2 or a position in m; any offset is allowed.
    sample_rate_hz : float
        Sample rate, Hz.
    n_modes : int
        Damped sinusoids fitted together; use 2 when an overtone (a second,
        faster pole pair) is visible. Extra modes start from the largest
        remaining FFT peak of the residual.
    refine : bool
        Run the least-squares refinement; False returns the FFT + logarithmic
        decrement estimate of the dominant mode.

    Returns
    -------
    DecayFit
        ``fit.sigma``, ``fit.omega_d``, ``fit.poles`` (``-sigma +- j omega_d``),
        ``fit.damping_ratio``, ``fit.frequency_hz`` of the dominant mode;
        ``fit.modes`` for all of them.

    Raises
    ------
    DataError
        Record invalid, too short, or without a decaying oscillation.
    """
    fs = float(sample_rate_hz)
    if not np.isfinite(fs) or fs <= 0.0:
        raise ConfigError("sample_rate_hz", f"must be a positive number, got {sample_rate_hz!r}")
    if isinstance(n_modes, bool) or int(n_modes) != n_modes or n_modes < 1:
        raise ConfigError("n_modes", f"must be a positive integer, got {n_modes!r}")
    n_modes = int(n_modes)
    x = check_signals({"x": x}, min_samples=32)["x"]
    t = np.arange(x.size) / fs

    omega0 = _spectrum_peak(x, fs)
    sigma0 = _log_decrement_sigma(x, fs, omega0)
    if sigma0 is None or not np.isfinite(sigma0) or sigma0 <= 0.0:
        sigma0 = _fit_sigma_grid(t, x, omega0)
    coef, _ = _linear_part(t, x, [sigma0], [omega0])
    initial = _mode_from(coef[:2], sigma0, omega0)

    if not refine:
        model_x = _basis(t, [sigma0], [omega0]) @ coef
        return DecayFit(
            modes=(initial,),
            offset=float(coef[-1]),
            fit_percent=float(fit_percent(x, model_x)),
            rms_residual=float(np.sqrt(np.mean((x - model_x) ** 2))),
            initial=initial,
            refined=False,
        )

    def residual(p):
        k = p.size // 2
        return _linear_part(t, x, p[:k], p[k:])[1]

    w_max = np.pi * fs
    sigmas, omegas = [sigma0], [omega0]
    for _ in range(n_modes):
        p0 = np.r_[sigmas, omegas]
        k = len(sigmas)
        lower = np.r_[np.full(k, -np.inf), np.full(k, 0.0)]
        upper = np.r_[np.full(k, np.inf), np.full(k, w_max)]
        sol = optimize.least_squares(residual, p0, bounds=(lower, upper), x_scale="jac")
        sigmas, omegas = list(sol.x[:k]), list(sol.x[k:])
        if k == n_modes:
            break
        rest = residual(sol.x)
        w_new = _spectrum_peak(rest, fs, exclude_rad_s=omegas)
        sigmas.append(_fit_sigma_grid(t, rest, w_new))
        omegas.append(w_new)

    k = len(sigmas)
    coef, res = _linear_part(t, x, sigmas, omegas)
    dof = max(x.size - 3 * k - 1, 1)
    s2 = float(res @ res) / dof
    try:
        cov = s2 * np.linalg.inv(sol.jac.T @ sol.jac)
        err = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        err = np.full(2 * k, np.nan)
    modes = [_mode_from(coef[2 * i : 2 * i + 2], sigmas[i], omegas[i], err[i], err[k + i]) for i in range(k)]
    modes.sort(key=lambda m: -m.amplitude)
    if modes[0].sigma <= 0.0:
        raise DataError(
            f"the dominant oscillation ({modes[0].frequency_hz:.3g} Hz) does not decay "
            f"(sigma = {modes[0].sigma:.3g} 1/s); is this a free-vibration record?"
        )
    return DecayFit(
        modes=tuple(modes),
        offset=float(coef[-1]),
        fit_percent=float(fit_percent(x, x - res)),
        rms_residual=float(np.sqrt(np.mean(res**2))),
        initial=initial,
        refined=True,
    )
