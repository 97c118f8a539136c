"""The velocity loop closed with new gains: its response predicted from the identified plant, measured, compared.

After gains are uploaded, a run in velocity mode plays a multisine on the
velocity set-point and records the drive's velocity estimate. The same
response is predicted from the plant the loop sees
(:class:`~hilident.pipeline.loop_plant.SeenPlant`) and the cascade as the drive
now holds it (:class:`~hilident.control.Cascade`, its notches and feed-forward included), as
the recording sees it: the set-point held over the ``D`` ticks of each sample,
the velocity read at a sample's first tick, so the response at ``f`` folds the
tick-level ``T`` of its images,

``T_rec(f) = 1/D sum_{k<D} T(f + k f_s) Hold(f + k f_s)``, ``Hold = sum_{i<D} z^-i``.

The multisine's amplitude is chosen from the same prediction: the largest whose
predicted velocity, motor torque and travel stay within a share of
``[limits]`` (:func:`closed_loop_amplitude`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hilident.control import Cascade
from hilident.control.sampled import ticks_per_sample
from hilident.pipeline.loop_plant import SeenPlant

__all__ = [
    "ClosedLoopCheck",
    "LIMIT_SHARE",
    "POOLED_LINES",
    "closed_loop_amplitude",
    "compare_closed_loop",
    "friction_response",
    "net_friction_torque",
    "predicted_period",
    "remove_friction",
    "line_scatter",
    "predicted_setpoint_response",
]

#: Share of each of [limits] (velocity, torque, half the position window) the check's predicted peaks may use.
LIMIT_SHARE = 0.5


def _tick_response(cascade: Cascade, seen: SeenPlant, f: np.ndarray, what: str, d: int) -> list[np.ndarray]:
    """Set-point to ``what`` at the tick rate, on the plant and its variants: ``"velocity"`` (the estimate,
    ``(C + F_v) N z^-d G V H / (1 + L)``) or ``"torque"`` (the motor torque, ``(C + F_v) N z^-d G / (1 + L)``),
    the set-point held over ``d`` ticks for the feed-forward's differences."""
    part = "output" if what == "velocity" else "torque"
    return [cascade.setpoint_response(f, h, "velocity", d, part) for h in seen.at(f)]


def predicted_setpoint_response(
    cascade: Cascade, seen: SeenPlant, frequency_hz, sample_rate_hz: float, what: str = "velocity"
) -> list[np.ndarray]:
    """The velocity set-point's response as recorded every ``D`` ticks, on the plant and on its variants.

    Parameters
    ----------
    cascade : Cascade
        The drive's cascade as it now holds it (gains and notches).
    seen : SeenPlant
        The plant the loop sees, tick by tick.
    frequency_hz : array_like
        Frequencies, Hz, below half the sample rate.
    sample_rate_hz : float
        The recording's sample rate, Hz (it divides the loop rate).
    what : {"velocity", "torque"}
        The recorded velocity estimate ((m/s) per (m/s)) or the motor torque (N·m per (m/s)).

    Returns
    -------
    list of ndarray of complex
        The plant's first, then its variants'.
    """
    f = np.asarray(frequency_hz, dtype=float)
    d = ticks_per_sample(cascade.loop_rate_hz, sample_rate_hz)
    total: list[np.ndarray] | None = None
    for k in range(d):
        fk = f + k * sample_rate_hz
        zi = np.exp(-2j * np.pi * fk / cascade.loop_rate_hz)
        hold = sum(zi**i for i in range(d))
        terms = [t * hold / d for t in _tick_response(cascade, seen, fk, what, d)]
        if k > 0:  # an image beyond a measured plant's lines is left out (the mechanics fall off up there)
            terms = [np.nan_to_num(t) for t in terms]
        total = terms if total is None else [a + b for a, b in zip(total, terms, strict=True)]
    assert total is not None
    return total


def friction_response(cascade: Cascade, seen: SeenPlant, frequency_hz) -> np.ndarray:
    """Friction torque to the velocity estimate in the closed velocity loop, ``-V H / (1 + L)``, (m/s) per N·m.

    The recorded set-point response holds, besides ``T r``, the response to the friction torque ``F(v)`` the
    axis meets; with the identified friction curve, ``F`` of the recorded velocity gives that part, and
    :func:`remove_friction` takes it out, as the identification takes friction out of the torque.
    """
    f = np.asarray(frequency_hz, dtype=float)
    h = seen.at(f)[0]
    return -cascade.velocity_estimate(f) * h / (1.0 + cascade.open_loop(f, h, "velocity"))


def net_friction_torque(fit, velocity_mps, setpoint_mps, coulomb_feedforward_nm: float) -> np.ndarray | None:
    """The friction torque the loop meets, N·m: the identified curve ``fit`` (None: none identified) at the
    velocity, less the Coulomb feed-forward the drive adds with the set-point's sign (outside the linear
    model, so taken with the friction it cancels). None when there is neither."""
    if fit is None and not coulomb_feedforward_nm:
        return None
    v = np.nan_to_num(np.asarray(velocity_mps, dtype=float))
    torque = np.zeros_like(v) if fit is None else np.asarray(fit.predict(v), dtype=float)
    return torque - coulomb_feedforward_nm * np.sign(np.nan_to_num(np.asarray(setpoint_mps, dtype=float)))


def remove_friction(measured, friction_over_setpoint, response_to_friction) -> np.ndarray:
    """The set-point response with the friction's part taken out: ``T = v / r - (-V H / (1 + L)) F / r``.

    Parameters
    ----------
    measured : ndarray of complex
        ``v / r`` per line as recorded.
    friction_over_setpoint : ndarray of complex
        ``F / r`` per line: the identified friction of the recorded velocity over the set-point.
    response_to_friction : ndarray of complex
        :func:`friction_response` at the lines.
    """
    return np.asarray(measured) - np.asarray(response_to_friction) * np.asarray(friction_over_setpoint)


def predicted_period(
    period: np.ndarray,
    sample_rate_hz: float,
    cascade: Cascade,
    seen: SeenPlant,
    friction_torque_nm: np.ndarray | None = None,
    what: str = "velocity",
) -> list[np.ndarray]:
    """The response to a periodic set-point over one of its periods, on the plant and on its variants.

    Each line of the period below half the sample rate that the set-point (or the friction) excites is
    multiplied by :func:`predicted_setpoint_response` and the lines summed back into one period.

    Parameters
    ----------
    period : ndarray
        One period of the velocity set-point, m/s, zero mean.
    sample_rate_hz : float
        The recording's sample rate, Hz.
    cascade, seen
        The drive's cascade as it holds it, and the plant its loop sees.
    friction_torque_nm : ndarray or None
        The friction torque over the same period (the identified curve at the measured velocity), N·m; its
        part of the velocity is added (``what = "velocity"`` only).
    what : {"velocity", "torque"}
        The velocity estimate (m/s) or the motor torque (N·m).

    Returns
    -------
    list of ndarray
        One period each: the plant's first, then its variants'. NaN where the plant is not known at every
        line used (measured lines without a model).
    """
    p = np.asarray(period, dtype=float)
    spectrum = np.fft.rfft(p)
    f = np.fft.rfftfreq(p.size, 1.0 / sample_rate_hz)
    with_friction = friction_torque_nm is not None and what == "velocity"
    excited = np.abs(spectrum) > 1e-9 * np.abs(spectrum).max()
    lines = np.flatnonzero((f > 0) & (f < sample_rate_hz / 2) & (excited | with_friction))
    extra = np.zeros_like(spectrum)
    if with_friction:
        torque = np.fft.rfft(np.asarray(friction_torque_nm, dtype=float))
        extra[lines] = torque[lines] * friction_response(cascade, seen, f[lines])
    out = []
    for response in predicted_setpoint_response(cascade, seen, f[lines], sample_rate_hz, what):
        shaped = np.zeros_like(spectrum)
        shaped[lines] = spectrum[lines] * response + extra[lines]
        out.append(np.fft.irfft(shaped, p.size) if np.all(np.isfinite(shaped)) else np.full(p.size, np.nan))
    return out


def _period_peaks(period: np.ndarray, sample_rate_hz: float, cascade: Cascade, seen: SeenPlant) -> dict:
    """The predicted peaks of velocity (m/s), motor torque (N·m) and travel (m) over one period of the set-point."""
    f = np.fft.rfftfreq(period.size, 1.0 / sample_rate_hz)
    peaks = {"velocity_mps": 0.0, "torque_nm": 0.0, "travel_m": 0.0}
    for which, key in (("velocity", "velocity_mps"), ("torque", "torque_nm")):
        for response in predicted_period(period, sample_rate_hz, cascade, seen, what=which):
            peaks[key] = max(peaks[key], float(np.abs(response).max()))
            if which == "velocity":  # the travel: the velocity integrated line by line (zero mean)
                travel = np.fft.rfft(response)
                travel[1:] /= 2j * np.pi * f[1:]
                travel[0] = 0.0
                swing = np.fft.irfft(travel, period.size)
                peaks["travel_m"] = max(peaks["travel_m"], float(swing.max() - swing.min()))
    return peaks


def closed_loop_amplitude(
    unit_period: np.ndarray,
    sample_rate_hz: float,
    cascade: Cascade,
    seen: SeenPlant,
    limits,
    share: float = LIMIT_SHARE,
) -> tuple[float, dict]:
    """The multisine's peak velocity set-point, m/s, whose predicted response keeps within ``share`` of ``limits``.

    Parameters
    ----------
    unit_period : ndarray
        One period of the set-point at a peak of 1 m/s.
    limits : LimitsConfig
        ``torque_nm``, ``velocity_mps``, ``position_min_m``, ``position_max_m``.

    Returns
    -------
    (amplitude_mps, peaks) : (float, dict)
        The amplitude, and the predicted peaks at it (``velocity_mps``, ``torque_nm``, ``travel_m``).
    """
    unit = _period_peaks(unit_period, sample_rate_hz, cascade, seen)
    room = {
        "velocity_mps": share * limits.velocity_mps,
        "torque_nm": share * limits.torque_nm,
        "travel_m": share * (limits.position_max_m - limits.position_min_m) / 2,
    }
    scale = min(room[k] / unit[k] for k in room if unit[k] > 0)
    return float(scale), {k: v * scale for k, v in unit.items()}


@dataclass(frozen=True)
class ClosedLoopCheck:
    """A measured closed-loop response against its prediction.

    Attributes
    ----------
    frequency_hz : ndarray
        The excited lines compared, Hz.
    measured, predicted : ndarray of complex
        Velocity set-point to velocity estimate, as recorded.
    gain_error_db, phase_error_deg : ndarray
        ``measured / predicted`` per line, dB and degrees (wrapped to +-180).
    tolerance_db, tolerance_deg : float
        What the comparison allows.
    scatter : ndarray
        The measured line's own 95 % scatter relative to its value (:func:`line_scatter`), 1; each line is
        allowed the tolerance plus that scatter.
    left_out : int
        Lines of the band not compared: their measurement is not trusted (below the coherence threshold).
    spread_db, spread_deg : ndarray or float
        Per line, how far the prediction on the plant's variants (its modes at the ends of their 95 %
        intervals) lies from the nominal one, dB and degrees; added to what each line is allowed.
    """

    frequency_hz: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    gain_error_db: np.ndarray
    phase_error_deg: np.ndarray
    tolerance_db: float
    tolerance_deg: float
    scatter: np.ndarray
    left_out: int = 0
    spread_db: np.ndarray | float = 0.0
    spread_deg: np.ndarray | float = 0.0

    @property
    def allowed_db(self) -> np.ndarray:
        """Per line: the tolerance plus the measurement's scatter and the prediction's spread, dB."""
        return self.tolerance_db + 20.0 * np.log10(1.0 + self.scatter) + self.spread_db

    @property
    def allowed_deg(self) -> np.ndarray:
        """Per line: the tolerance plus the measurement's scatter and the prediction's spread, degrees."""
        scatter_deg = np.degrees(np.arcsin(np.minimum(self.scatter, 1.0)))
        return np.where(self.scatter >= 1.0, 180.0, self.tolerance_deg + scatter_deg + self.spread_deg)

    @property
    def outside(self) -> np.ndarray:
        """The lines whose difference exceeds what they are allowed."""
        return (np.abs(self.gain_error_db) > self.allowed_db) | (np.abs(self.phase_error_deg) > self.allowed_deg)

    @property
    def within_tolerance(self) -> bool:
        """Whether every line lies within its tolerance."""
        return not bool(self.outside.any())

    def worst(self) -> dict:
        """The largest differences and where they are."""
        g, p = int(np.argmax(np.abs(self.gain_error_db))), int(np.argmax(np.abs(self.phase_error_deg)))
        return {
            "max_gain_error_db": float(self.gain_error_db[g]),
            "max_gain_error_hz": float(self.frequency_hz[g]),
            "max_phase_error_deg": float(self.phase_error_deg[p]),
            "max_phase_error_hz": float(self.frequency_hz[p]),
        }

    def to_dict(self) -> dict:
        return {
            "band_hz": [float(self.frequency_hz[0]), float(self.frequency_hz[-1])],
            "lines": int(self.frequency_hz.size),
            "lines_left_out": self.left_out,
            **self.worst(),
            "rms_gain_error_db": float(np.sqrt(np.mean(self.gain_error_db**2))),
            "rms_phase_error_deg": float(np.sqrt(np.mean(self.phase_error_deg**2))),
            "tolerance_db": self.tolerance_db,
            "tolerance_deg": self.tolerance_deg,
            "median_scatter": float(np.median(self.scatter)),
            "largest_prediction_spread_db": float(np.max(self.spread_db, initial=0.0)),
            "lines_outside": int(self.outside.sum()),
            "within_tolerance": self.within_tolerance,
        }


#: Neighbouring lines whose period-to-period variance is pooled for each line's.
POOLED_LINES = 9


def line_scatter(coherence, periods: int, pooled: int = POOLED_LINES) -> np.ndarray:
    """How far each periodic line's mean may lie from its true value, relative to it, with 95 % confidence for
    all the lines together.

    The relative variance of a line's mean over ``periods`` periods follows from its coherence
    (:func:`hilident.ident.periodic_frf`: ``var / |mean|^2 = (1 - g) / g``, over ``periods``). A variance from
    a few periods is itself uncertain, so each line's is pooled with its ``pooled`` neighbours' (the noise
    changes slowly with frequency), and the quantile is Student's t of the pooled degrees of freedom at
    ``1 - 0.025 / N`` for ``N`` lines (Bonferroni): every line of a good measurement lies inside with 95 %
    probability, not 95 % of them.
    """
    from scipy.ndimage import uniform_filter1d
    from scipy.stats import t

    g = np.clip(np.nan_to_num(np.asarray(coherence, dtype=float), nan=0.0), 1e-12, 1.0)
    m = max(int(periods), 2)
    relative_variance = uniform_filter1d((1.0 - g) / g / m, size=max(int(pooled), 1), mode="nearest")
    n = max(relative_variance.size, 1)
    return float(t.ppf(1.0 - 0.025 / n, pooled * (m - 1))) * np.sqrt(relative_variance)


def compare_closed_loop(
    frequency_hz,
    measured,
    predicted,
    band_hz: tuple[float, float],
    tolerance_db: float,
    tolerance_deg: float,
    scatter=None,
    usable=None,
    variants=(),
) -> ClosedLoopCheck:
    """The measured response against the prediction on the lines inside ``band_hz`` where both are finite.

    ``scatter`` (:func:`line_scatter`, per line of ``frequency_hz``) widens each line's tolerance by the
    measurement's own uncertainty (default none); ``usable`` (bool per line, e.g. the coherence threshold
    met) leaves the others out, as the identification leaves out lines it cannot trust; ``variants`` (the
    prediction on the plant's variants, per line) widen each line by the prediction's own spread.

    Raises
    ------
    ValueError
        No line to compare.
    """
    f = np.asarray(frequency_hz, dtype=float)
    m, p = np.asarray(measured, dtype=complex), np.asarray(predicted, dtype=complex)
    keep = (f >= band_hz[0]) & (f <= band_hz[1]) & np.isfinite(m) & np.isfinite(p) & (np.abs(p) > 0)
    in_band = int(keep.sum())
    if usable is not None:
        keep &= np.asarray(usable, dtype=bool)
    if not keep.any():
        raise ValueError(f"no measured line in {band_hz[0]:g}-{band_hz[1]:g} Hz to compare with the prediction")
    ratio = m[keep] / p[keep]
    spread = np.zeros(f.shape) if scatter is None else np.nan_to_num(np.asarray(scatter, dtype=float), nan=np.inf)
    spread_db, spread_deg = np.zeros(int(keep.sum())), np.zeros(int(keep.sum()))
    for v in variants:
        off = np.asarray(v, dtype=complex)[keep] / p[keep]
        spread_db = np.maximum(spread_db, np.nan_to_num(np.abs(20.0 * np.log10(np.abs(off)))))
        spread_deg = np.maximum(spread_deg, np.nan_to_num(np.abs(np.degrees(np.angle(off)))))
    return ClosedLoopCheck(
        f[keep],
        m[keep],
        p[keep],
        20.0 * np.log10(np.abs(ratio)),
        np.degrees(np.angle(ratio)),
        float(tolerance_db),
        float(tolerance_deg),
        spread[keep],
        in_band - int(keep.sum()),
        spread_db,
        spread_deg,
    )


def bandwidth_or_nan(frequency_hz, response) -> float:
    """The half-power bandwidth of a set-point response on its lines, Hz (NaN where it is not reached)."""
    from hilident.control import bandwidth_hz

    try:
        return bandwidth_hz(frequency_hz, response)
    except ValueError:
        return math.nan
