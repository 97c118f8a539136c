"""What the drive's loop makes of the identified plant: margins and bandwidths, without and with the notches.

The identified plant (net torque to velocity, recorded every ``D`` loop ticks)
becomes the plant the loop sees tick by tick (:func:`hilident.control.loop_plant`);
the drive's cascade, read from the drive (``[loop]``), closes the loop around
it (:class:`hilident.control.Cascade`). For the velocity loop (the position loop
open, as in velocity mode) and the position loop (both closed): the gain and
phase margins, the sensitivity peak and the bandwidth of the set-point's
response, with the drive's present gains, without the notches and with the ones
designed -- what a notch buys, in the figures a servo engineer tunes by.

The margins' crossings often lie above the measured band. There the loop sees
the plant's mechanics (its integrators and the modes found in the band) through
the drive's own filters and timing, which the loop description gives: the
measured lines, brought to the tick rate and divided by the velocity estimate's
filter, fix the mechanics' gain and timing, and the figures are computed on a
dense grid up to 0.45 of the loop rate (a note names what lies beyond the
measured band). Without a fitted model only the measured lines count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from hilident.control import Cascade, LoopMargins, bandwidth_hz, loop_margins, loop_plant
from hilident.errors import DataError
from hilident.filters.biquad import Biquad

__all__ = ["LoopAnalysis", "LoopFigures", "analyse_loop"]

#: Highest frequency of the dense grid, as a fraction of the loop rate.
GRID_TOP = 0.45
GRID_POINTS = 4000
LOOPS = ("velocity", "position")


@dataclass(frozen=True)
class LoopFigures:
    """One loop's figures.

    Attributes
    ----------
    margins : LoopMargins
    bandwidth_hz : float
        Where the set-point's response falls to half its power, Hz (NaN: not on the grid).
    """

    margins: LoopMargins
    bandwidth_hz: float

    def to_dict(self) -> dict:
        out = self.margins.to_dict()
        out["sensitivity_peak_db"] = self.margins.sensitivity_peak_db
        out["bandwidth_hz"] = self.bandwidth_hz if math.isfinite(self.bandwidth_hz) else None
        return out


@dataclass
class LoopAnalysis:
    """The loop's figures for ``summary.json["loop"]``.

    Attributes
    ----------
    parameters : dict
        The cascade's parameters as read from the drive, SI units.
    grid_hz : (float, float)
        The frequencies the figures were computed over, Hz.
    measured_band_hz : (float, float)
        The band the plant was measured in, Hz.
    source : str
        ``"model"`` (the fitted transfer function on a dense grid) or ``"lines"`` (the measured lines only).
    figures : dict
        ``{loop: {"without_notch": LoopFigures, "with_notch": LoopFigures or None}}`` for ``"velocity"`` and
        ``"position"``.
    notes : list of str
    mechanics_fit : dict or None
        ``{gain_db_rms, phase_rms_deg}``: how far the measured lines lie from the mechanics the dense grid
        rests on (None: the lines themselves were used).
    """

    parameters: dict
    grid_hz: tuple[float, float]
    measured_band_hz: tuple[float, float]
    source: str
    figures: dict
    notes: list[str] = field(default_factory=list)
    mechanics_fit: dict | None = None

    def to_dict(self) -> dict:
        return {
            "parameters": dict(self.parameters),
            "grid_hz": list(self.grid_hz),
            "measured_band_hz": list(self.measured_band_hz),
            "source": self.source,
            "mechanics_fit": self.mechanics_fit,
            **{
                loop: {k: (None if v is None else v.to_dict()) for k, v in parts.items()}
                for loop, parts in self.figures.items()
            },
            "notes": list(self.notes),
        }


def _mechanics_to_position(model, band_hz: tuple[float, float], output_is_velocity: bool):
    """The fitted model's mechanics from torque to position: its integrators (one more for a velocity
    output), the modes and the corners inside the measured band, no delay (what lies beyond the band is the
    drive's filters and timing, which the loop description gives)."""
    m = model.modal
    inside = lambda hz: band_hz[0] <= abs(hz) <= band_hz[1]  # noqa: E731
    return replace(
        m,
        resonances=tuple(r for r in m.resonances if inside(r[0])),
        antiresonances=tuple(r for r in m.antiresonances if inside(r[0])),
        real_poles_hz=tuple(c for c in m.real_poles_hz if inside(c)),
        real_zeros_hz=tuple(c for c in m.real_zeros_hz if inside(c)),
        integrators=m.integrators + (1 if output_is_velocity else 0),
        delay_s=0.0,
    )


def _fit_mechanics(mechanics, f: np.ndarray, measured: np.ndarray, loop_rate_hz: float):
    """``(mechanics, gain, residual)``: the number of integrators (0 to 3) and the real gain (of either sign)
    that bring ``mechanics``, held over a tick (half a tick late), closest to the ``measured`` lines (least
    squares on the log of their ratio); ``residual`` is ``(rms dB, rms degrees)`` of what is left.

    The fitted model's own integrators and sign may trade with corners outside the band (a low-frequency
    slope bent by friction, a zero near 0 Hz); the lines brought to the tick rate decide. The timing is the
    loop's own (the torque held over a tick, the position read at its start), not fitted: a delay fitted to
    noisy lines in a low band would move the crossings far above it.
    """
    held = np.exp(-1j * np.pi * f / loop_rate_hz)
    best = None
    for n in range(4):
        candidate = replace(mechanics, integrators=n)
        log_ratio = np.log(measured / (candidate.response(f) * held))
        log_gain = float(np.mean(log_ratio.real))
        phase = np.unwrap(log_ratio.imag)
        turns = round(float(np.mean(phase)) / math.pi)  # a real gain's phase is a whole number of half turns
        phase -= turns * math.pi
        cost = float(np.mean((log_ratio.real - log_gain) ** 2 + phase**2))
        if best is None or cost < best[0]:
            residual = (
                float(20 / math.log(10) * np.sqrt(np.mean((log_ratio.real - log_gain) ** 2))),
                float(np.degrees(np.sqrt(np.mean(phase**2)))),
            )
            best = (cost, candidate, (-1) ** turns * math.exp(log_gain), residual)
    assert best is not None
    return best[1], best[2], best[3]


def _position_plant(plant, cascade: Cascade, rates: tuple[float, float], torque_sampling: str, output: str):
    """``(f, H, source, band, residual)``: the plant the loop sees tick by tick, motor torque to encoder position.

    The recorded response (torque to ``output``: the velocity estimate or the position) is brought to the
    tick rate (:func:`~hilident.control.loop_plant`) and, for a velocity, divided by the velocity estimate.
    With a fitted model, those lines inside the fitted band fix the gain and the timing of the model's
    mechanics, which give ``H`` on a dense grid (``residual``: what the lines differ from it, rms dB and
    degrees); without one, the measured lines are ``H`` (``residual`` None).
    """
    loop_rate_hz, sample_rate_hz = rates
    frf = plant.plant
    f_all = np.asarray(frf.frequency_hz, dtype=float)
    ok = (f_all > 0) & np.isfinite(frf.response)
    velocity = output == "velocity_mps"

    def measured(f: np.ndarray, recorded: np.ndarray) -> np.ndarray:
        seen = loop_plant(
            f, recorded, loop_rate_hz, sample_rate_hz, cascade.current_loop_hz, cascade.delay_ticks, torque_sampling
        )
        return seen / cascade.velocity_estimate(f) if velocity else seen

    if plant.model is None:
        f = f_all[ok]
        return f, measured(f, np.asarray(frf.response)[ok]), "lines", (float(f[0]), float(f[-1])), None
    lo, hi = plant.model.fit.band_hz
    band = (float(lo), float(hi))
    lines = ok & (f_all >= band[0]) & (f_all <= band[1])
    f_m = f_all[lines]
    mechanics, gain, residual = _fit_mechanics(
        _mechanics_to_position(plant.model, band, velocity),
        f_m,
        measured(f_m, np.asarray(frf.response)[lines]),
        loop_rate_hz,
    )
    f = np.geomspace(max(band[0] / 2, 0.1), GRID_TOP * loop_rate_hz, GRID_POINTS)
    held = np.exp(-1j * np.pi * f / loop_rate_hz)
    return f, gain * mechanics.response(f) * held, "model", band, residual


def _figures(cascade: Cascade, f: np.ndarray, position_plant: np.ndarray, loop: str) -> LoopFigures:
    margins = loop_margins(f, cascade.open_loop(f, position_plant, loop))
    return LoopFigures(margins, bandwidth_hz(f, cascade.closed_loop(f, position_plant, loop)))


def _beyond_band_notes(figures: dict, band: tuple[float, float]) -> list[str]:
    """One note naming the figures whose frequency lies beyond the measured band."""
    beyond = [
        (what, hz)
        for parts in figures.values()
        for part in parts.values()
        if part is not None
        for what, hz in (("gain margins", part.margins.gain_margin_hz), ("crossovers", part.margins.crossover_hz))
        if math.isfinite(hz) and not band[0] <= hz <= band[1]
    ]
    if not beyond:
        return []
    whats = " and ".join(sorted({w for w, _ in beyond}))
    low, high = min(hz for _, hz in beyond), max(hz for _, hz in beyond)
    return [
        f"loop: the {whats} ({low:.0f}-{high:.0f} Hz) lie beyond the measured band {band[0]:g}-{band[1]:g} Hz: "
        "there the figures rest on the mechanics found in the band seen through the drive's described filters "
        "and timing"
    ]


def analyse_loop(
    plant,
    parameters: dict,
    loop_rate_hz: float,
    sample_rate_hz: float,
    notches: list[Biquad],
    torque_sampling: str = "instant",
    output: str = "velocity_mps",
) -> LoopAnalysis:
    """Margins and bandwidths of the drive's loops around the identified plant, without and with ``notches``.

    Parameters
    ----------
    plant : PlantResult
        The identification's result (net torque to velocity, its fitted model when there is one).
    parameters : dict
        The drive's cascade parameters, SI units (:meth:`read_loop` of the adapter).
    loop_rate_hz, sample_rate_hz : float
        The drive's loop rate and the recording's sample rate, Hz.
    notches : list of Biquad
        The designed notches as the drive stores them, at the loop rate (empty: none designed).
    torque_sampling : {"instant", "mean"}
        How the recording's torque was sampled (the driver's ``sampling`` of ``torque_nm``).
    output : {"velocity_mps", "position_m"}
        The identified response's output: the drive's velocity estimate or the encoder position.
    """
    if output not in ("velocity_mps", "position_m"):
        raise DataError(f"the loop is analysed from a response to velocity_mps or position_m, not {output!r}")
    without = Cascade.from_parameters(parameters, loop_rate_hz)
    rates = (loop_rate_hz, sample_rate_hz)
    f, seen, source, band, residual = _position_plant(plant, without, rates, torque_sampling, output)
    with_notch = without.with_gains(filters=tuple(notches)) if notches else None
    figures = {
        loop: {
            "without_notch": _figures(without, f, seen, loop),
            "with_notch": _figures(with_notch, f, seen, loop) if with_notch is not None else None,
        }
        for loop in LOOPS
    }
    notes = _beyond_band_notes(figures, band) if source == "model" else []
    fit = None if residual is None else {"gain_db_rms": residual[0], "phase_rms_deg": residual[1]}
    return LoopAnalysis(dict(parameters), (float(f[0]), float(f[-1])), band, source, figures, notes, fit)
