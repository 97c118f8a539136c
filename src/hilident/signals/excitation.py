"""The identification excitation described by an ``[excitation]`` table, as played.

Pure: the table's fields in (any object with them, e.g.
:class:`hilident.config.tables.ExcitationConfig`), samples out. The amplitude is
given by the caller (a configured number, or what ``amplitude_nm = "auto"``
chose).

Examples
--------
>>> from types import SimpleNamespace as T
>>> e = T(kind="sine", frequency_hz=5.0, duration_s=1.0, f_min_hz=1.0, f_max_hz=50.0, fade_s=0.0)
>>> x = build_excitation(e, 1000.0, amplitude=2.0)
>>> x.samples.shape, x.period_samples, x.band_hz
((1000,), None, (5.0, 5.0))
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hilident.signals import generators as sig

__all__ = ["Excitation", "build_excitation"]


@dataclass
class Excitation:
    """An excitation as played: samples, and the period when it is periodic.

    Attributes
    ----------
    samples : ndarray
        The set-points, in the unit of the excitation's mode (N·m, m/s or m).
    period_samples : int or None
        Samples per period of a periodic excitation (multisine, PRBS of three periods or more).
    band_hz : (float, float)
        The band it excites, Hz.
    excited_bins : ndarray or None
        A multisine's excited DFT bins of one period.
    """

    samples: np.ndarray
    period_samples: int | None
    band_hz: tuple[float, float]
    excited_bins: np.ndarray | None = None

    @property
    def period(self) -> int:
        """Samples per period of an excitation that must be periodic.

        Raises
        ------
        ValueError
            The excitation is not periodic (a caller's mistake: the config checks rule that out).
        """
        if self.period_samples is None:
            raise ValueError("a periodic excitation was expected")
        return self.period_samples


def build_excitation(e: Any, sample_rate_hz: float, amplitude: float, seed: int | None = None) -> Excitation:
    """The excitation ``e`` (an ``[excitation]`` table) at ``amplitude``, sampled at ``sample_rate_hz``, Hz.

    A multisine plays one extra period first (it lets the transient die out
    and is skipped by the analysis); a PRBS plays one extra period; a fade
    (``fade_s``) is applied to a non-periodic excitation. ``seed`` drives
    band-limited noise.
    """
    fs = sample_rate_hz
    if e.kind == "multisine":
        n_periods = max(1, int(round(e.duration_s / e.period_s)))
        ms = sig.multisine(amplitude, e.f_min_hz, e.f_max_hz, e.period_s, n_periods, fs)
        x = np.concatenate([ms.samples[: ms.period_samples], ms.samples])
        return Excitation(x, ms.period_samples, (e.f_min_hz, e.f_max_hz), ms.excited_bins)
    if e.kind == "prbs":
        return _prbs(e, fs, amplitude)
    x, band = _aperiodic(e, fs, amplitude, seed)
    if e.fade_s:
        x = sig.fade(x, e.fade_s, fs)
    return Excitation(np.asarray(x, dtype=float), None, band)


def _prbs(e: Any, fs: float, amplitude: float) -> Excitation:
    """A PRBS of whole sequences, one more than ``duration_s`` holds; periodic from three sequences on."""
    length = (2**e.register_length - 1) * e.clock_divider
    periods = max(1, int(round(e.duration_s * fs / length)))
    x = sig.prbs(amplitude, e.register_length, e.clock_divider, fs, periods=periods + 1)
    period = length if periods >= 3 else None
    band = (fs / length, min(e.f_max_hz, fs / (2 * e.clock_divider)))
    if e.fade_s and period is None:
        x = sig.fade(x, e.fade_s, fs)
    return Excitation(np.asarray(x, dtype=float), period, band)


def _aperiodic(e: Any, fs: float, amplitude: float, seed: int | None) -> tuple[np.ndarray, tuple[float, float]]:
    """Samples and band of a sine, square, chirp, band-limited noise or step."""
    band = (e.f_min_hz, e.f_max_hz)
    if e.kind == "sine":
        return sig.sine(amplitude, e.frequency_hz, e.duration_s, fs), (e.frequency_hz, e.frequency_hz)
    if e.kind == "square":
        return sig.square(amplitude, e.frequency_hz, e.duration_s, fs), (e.frequency_hz, e.f_max_hz)
    if e.kind == "chirp":
        return sig.chirp(amplitude, e.f_min_hz, e.f_max_hz, e.duration_s, fs, method=e.chirp_method), band
    if e.kind == "noise":
        return sig.band_limited_noise(
            amplitude / 3.0, e.f_min_hz, e.f_max_hz, e.duration_s, fs, seed=seed, peak=amplitude
        ), band
    return sig.step(amplitude, e.duration_s, fs, step_time_s=0.1 * e.duration_s), band
