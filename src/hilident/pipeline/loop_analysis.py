"""What the drive's loop makes of the identified plant: margins and bandwidths, without and with the notches.

The identified plant (net torque to velocity, recorded every ``D`` loop ticks)
becomes the plant the loop sees tick by tick (:func:`hilident.control.loop_plant`);
the drive's cascade, read from the drive (``[loop]``), closes the loop around
it (:class:`hilident.control.Cascade`). For the velocity loop (broken at the
torque, the position loop open, as in velocity mode) and the position loop
(broken at the velocity set-point, the velocity loop closed): the gain and
phase margins, the sensitivity peak and the bandwidth of the set-point's
response, with the drive's present gains, without the notches and with the ones
designed -- what a notch buys, in the figures a servo engineer tunes by.

The plant the loop sees is :func:`hilident.pipeline.loop_plant.seen_plant`'s.
With ``[tuning]`` targets, the gains that give the widest loops within them
are proposed (:func:`hilident.control.tuning.propose_gains`), without and with
the notches, robust to the modes' 95 % intervals: what the notch buys is then
the bandwidth it allows at the same margins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hilident.control import Cascade, LoopMargins, bandwidth_hz, loop_margins
from hilident.control.tuning import PRESETS, Proposal, Targets, propose_gains
from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.pipeline.loop_plant import SeenPlant, seen_plant

__all__ = ["LoopAnalysis", "LoopFigures", "analyse_loop"]

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
        ``"model"`` (the mechanics found in the band, on a dense grid) or ``"lines"`` (the measured lines only).
    figures : dict
        ``{loop: {"without_notch": LoopFigures, "with_notch": LoopFigures or None}}`` for ``"velocity"`` and
        ``"position"``.
    notes : list of str
    mechanics_fit : dict or None
        ``{gain_db_rms, phase_rms_deg}``: how far the measured lines lie from the mechanics the dense grid
        rests on (None: the lines themselves were used).
    tuning : dict or None
        The gains proposed against the ``[tuning]`` targets (:func:`tuning_part`); None: none asked for.
    seen : SeenPlant or None
        The plant the loop sees (not in ``summary.json``: the gain step and ``loop_plant.npz`` use it).
    cascade : Cascade or None
        The drive's cascade as read, without the notches.
    notches : tuple of Biquad
        The designed notches the figures "with_notch" use.
    upload : dict or None
        The gain step's outcome (:class:`hilident.session.gain_step.GainStep`); None: no gains uploaded.
    measured : dict or None
        The loop measured by torque injection (:func:`hilident.pipeline.measured_loop.measured_loop_part`);
        None: the run did not break the loop.
    """

    parameters: dict
    grid_hz: tuple[float, float]
    measured_band_hz: tuple[float, float]
    source: str
    figures: dict
    notes: list[str] = field(default_factory=list)
    mechanics_fit: dict | None = None
    tuning: dict | None = None
    seen: SeenPlant | None = field(default=None, repr=False)
    cascade: Cascade | None = None
    notches: tuple = ()
    upload: dict | None = None
    measured: dict | None = None

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
            "tuning": self.tuning,
            "upload": self.upload,
            "measured": self.measured,
            "notes": list(self.notes),
        }


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
    targets: Targets | None = None,
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
    targets : Targets, optional
        ``[tuning]``'s: gains are proposed against them (None: none proposed).
    """
    if output not in ("velocity_mps", "position_m"):
        raise DataError(f"the loop is analysed from a response to velocity_mps or position_m, not {output!r}")
    without = Cascade.from_parameters(parameters, loop_rate_hz)
    seen = seen_plant(plant, without, (loop_rate_hz, sample_rate_hz), torque_sampling, output, _mode_shift(plant))
    f, h = seen.frequency_hz, seen.response
    with_notch = without.with_gains(filters=tuple(notches)) if notches else None
    figures = {
        loop: {
            "without_notch": _figures(without, f, h, loop),
            "with_notch": _figures(with_notch, f, h, loop) if with_notch is not None else None,
        }
        for loop in LOOPS
    }
    notes = _beyond_band_notes(figures, seen.band_hz) if seen.source == "model" else []
    fit = None if seen.residual is None else {"gain_db_rms": seen.residual[0], "phase_rms_deg": seen.residual[1]}
    part = None if targets is None else tuning_part(targets, without, with_notch, seen)
    return LoopAnalysis(
        dict(parameters),
        (float(f[0]), float(f[-1])),
        seen.band_hz,
        seen.source,
        figures,
        notes,
        fit,
        part,
        seen,
        without,
        tuple(notches),
    )


def tuning_targets(tuning) -> Targets | None:
    """The targets of a ``[tuning]`` table (:class:`~hilident.config.tables.TuningConfig`): its preset's, each
    replaced by the key given; None when tuning is off."""
    if not tuning.enabled:
        return None
    preset = PRESETS[tuning.preset]
    return Targets(
        tuning.gain_margin_db if tuning.gain_margin_db is not None else preset.gain_margin_db,
        tuning.phase_margin_deg if tuning.phase_margin_deg is not None else preset.phase_margin_deg,
        tuning.sensitivity_peak if tuning.sensitivity_peak is not None else preset.sensitivity_peak,
    )


def _mode_shift(plant) -> float:
    """The widest 95 % interval of the reported resonances, as a fraction of their frequency (0: none)."""
    shifts = [
        r.frequency_ci95_hz / r.frequency_hz
        for r in plant.resonances
        if math.isfinite(getattr(r, "frequency_ci95_hz", math.nan)) and r.frequency_hz > 0
    ]
    return max(shifts, default=0.0)


def _proposed(proposal: Proposal | None) -> dict | None:
    if proposal is None:
        return None
    return {
        "gains": proposal.gains(),
        "velocity": LoopFigures(proposal.velocity, proposal.velocity_bandwidth_hz).to_dict(),
        "position": LoopFigures(proposal.position, proposal.position_bandwidth_hz).to_dict(),
    }


def tuning_part(targets: Targets, without: Cascade, with_notch: Cascade | None, seen: SeenPlant) -> dict:
    """The gains proposed against ``targets`` on the plant and its variants, without and with the notches, their
    crossovers within the band the plant was measured in, and one line saying what the notch buys."""
    plants = [seen.response, *seen.variants]
    f = seen.frequency_hz
    top = float(seen.band_hz[1])  # no loop is proposed to cross over where the plant was not measured
    bare = propose_gains(without, f, plants, targets, max_crossover_hz=top)
    notched = propose_gains(with_notch, f, plants, targets, max_crossover_hz=top) if with_notch is not None else None
    return {
        "targets": targets.to_dict(),
        "max_crossover_hz": top,
        "plants": len(plants),
        "without_notch": _proposed(bare),
        "with_notch": _proposed(notched),
        "verdict": _verdict(bare, notched, with_notch is not None),
    }


def _verdict(bare: Proposal | None, notched: Proposal | None, has_notch: bool) -> str:
    """What the notch buys, in the velocity loop's bandwidth at the same targets."""
    if not has_notch:
        return "no notch designed: the proposal is the bare loop's"
    if bare is None and notched is None:
        return "no gains on the search grid keep the targets, with or without the notch"
    if bare is None:
        assert notched is not None
        return (
            f"only with the notch do gains keep the targets: velocity bandwidth {notched.velocity_bandwidth_hz:.1f} Hz"
        )
    if notched is None:
        return f"the notch leaves no gains that keep the targets; without it: {bare.velocity_bandwidth_hz:.1f} Hz"
    word = "buys" if notched.velocity_bandwidth_hz > bare.velocity_bandwidth_hz else "costs"
    return (
        f"the notch {word} velocity bandwidth at the same targets: {bare.velocity_bandwidth_hz:.1f} -> "
        f"{notched.velocity_bandwidth_hz:.1f} Hz (position {bare.position_bandwidth_hz:.1f} -> "
        f"{notched.position_bandwidth_hz:.1f} Hz)"
    )
