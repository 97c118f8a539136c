"""The gain step of ``hilident run``: the proposed gains into the drive, proven by a closed-loop run, or put back.

With ``[tuning] upload = true`` on a drive whose driver describes its loop:

1. the proposal (:func:`hilident.pipeline.loop_analysis.tuning_part`) made with
   the notches when they were uploaded, else without, and the feed-forward
   terms the drive has (:func:`hilident.pipeline.feedforward.propose_feedforward`),
   as the drive will store them (:meth:`~hilident.adapters.base.AdapterBase.stored_loop`);
2. refused when it would leave either loop without a positive gain or phase
   margin on the identified plant or its variants
   (:func:`hilident.pipeline.gain_check.check_gains`), naming the margin;
3. the present gains read, the new ones written and read back; a read-back
   that differs puts the old ones back;
4. a multisine on the velocity set-point, sized from the prediction to stay
   within a share of ``[limits]``, recorded in velocity mode; the measured
   response against the prediction (:mod:`hilident.pipeline.closed_loop`);
   outside ``[tuning] tolerance_db``/``tolerance_deg`` the old gains go back;
5. small steps on the velocity set-point, their measured period against the
   predicted one (:mod:`hilident.pipeline.step_check`); beyond
   ``[tuning] step_tolerance_percent`` the old gains go back.

Whatever ends the run before the gains are proven (an error, a signal) puts
the old gains back (:meth:`GainStep.restore`, from the run's ``finally``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from hilident.errors import UsageError
from hilident.filters.biquad import Biquad
from hilident.numbers import finite_or_none
from hilident.pipeline import closed_loop, step_check
from hilident.pipeline.gain_check import check_gains
from hilident.pipeline.loop_analysis import LoopAnalysis, tuning_targets
from hilident.pipeline.responses import periods_response
from hilident.signals.excitation import build_excitation

__all__ = ["GainStep", "describe_gains", "put_back_gains", "read_gains", "uploaded_notches"]

#: The recordings of the closed-loop run: the multisine, then the steps.
RECORDING = "closed-loop"
STEP_RECORDING = "closed-loop-step"
#: Periods of the step run that are compared (after one that lets the transient from rest die out).
STEP_PERIODS = 4


def uploaded_notches(upload) -> tuple[Biquad, ...]:
    """The notches the drive holds after the run's upload, as read back (none when none was kept)."""
    if not (upload.written and upload.verified_readback):
        return ()
    return tuple(Biquad.from_sequences(s["readback_b"], s["readback_a"]) for s in upload.slots if s["matches"])


class GainStep:
    """Upload, prove and keep (or put back) the proposed gains.

    Parameters
    ----------
    adapter : AdapterBase
        The open drive.
    cfg : Config
    analysis : LoopAnalysis
        The loop step's result (its plant, cascade and proposal).
    notches : tuple of Biquad
        What the drive's filter slots hold now.
    friction : FrictionResult or None
        The friction test's fit: its part of the closed-loop response is taken out before the comparison.
    record : callable
        ``record(name, mode, samples, period_samples=...) -> Experiment`` (the session's).
    samples : callable
        ``samples(experiment, excitation) -> dict`` of whole periods (the session's selection).
    warnings : list of str
        Appended to.
    progress : Progress
    """

    def __init__(
        self,
        adapter,
        cfg,
        analysis: LoopAnalysis,
        notches: tuple[Biquad, ...],
        friction,
        record: Callable,
        samples: Callable,
        warnings: list[str],
        progress,
    ):
        self.adapter, self.cfg, self.analysis, self.notches = adapter, cfg, analysis, notches
        self.friction = friction
        self.record, self.samples, self.warnings, self.progress = record, samples, warnings, progress
        self.before: dict | None = None  # the gains the drive held, while the new ones are not proven
        self.check: closed_loop.ClosedLoopCheck | None = None
        self.step: step_check.StepCheck | None = None
        self.part: dict = {"uploaded": False, "kept": False}

    @property
    def friction_fit(self):
        """The friction test's fitted curve; None without a friction test."""
        return None if self.friction is None else self.friction.fit

    def run(self) -> dict:
        """Every step; returns ``summary.json["loop"]["upload"]``."""
        part = self.part
        tuning = self.analysis.tuning or {}
        which = "with_notch" if self.notches else "without_notch"
        proposal = tuning.get(which)
        if proposal is None:
            return self._skip(f"no gains {which.replace('_', ' ')} keep the [tuning] targets: none uploaded")
        asked = {**proposal["gains"], **(tuning.get("feedforward") or {}).get("terms", {})}
        part.update(proposal=which, asked=asked)
        try:
            expected = self.adapter.stored_loop(asked)
        except UsageError as exc:
            return self._skip(f"the gains cannot be written: {exc}")
        assert self.analysis.cascade is not None and self.analysis.seen is not None
        cascade = self.analysis.cascade.with_gains(**expected, filters=self.notches)
        present = self.analysis.cascade.with_gains(filters=self.notches)
        check = check_gains(cascade, self.analysis.seen, tuning_targets(self.cfg.tuning), present)
        part.update(expected=expected, check=check.to_dict())
        if not check.stable:
            return self._skip(
                f"refused before upload: the gains {describe_gains(expected)} would leave {check.describe()}"
            )
        if check.meets_targets is False:
            self.warnings.append(f"loop: the gains as the drive stores them miss the targets: {check.describe()}")
        self.progress.step(f"loop: uploading gains {describe_gains(expected)}")
        self.before = read_gains(self.adapter, asked)
        part["before"] = dict(self.before)
        self.adapter.write_loop(asked)
        readback = read_gains(self.adapter, asked)
        part.update(uploaded=True, readback=readback, matches=readback == expected)
        if readback != expected:
            self.restore(f"the gains read back {describe_gains(readback)}, not the {describe_gains(expected)} written")
            return part
        self._prove(cascade)
        return part

    def _skip(self, reason: str) -> dict:
        self.part["reason"] = reason
        self.warnings.append(f"loop: {reason}")
        return self.part

    def _prove(self, cascade) -> None:
        """The closed-loop run; the gains are kept when it agrees with the prediction."""
        cfg, seen = self.cfg, self.analysis.seen
        assert seen is not None
        fs = cfg.run.sample_rate_hz
        shape = replace(cfg.excitation, kind="multisine", mode="velocity", fade_s=0.0)
        unit = build_excitation(shape, fs, 1.0, seed=cfg.run.seed)
        amplitude, peaks = closed_loop.closed_loop_amplitude(unit.samples[: unit.period], fs, cascade, seen, cfg.limits)
        excitation = build_excitation(replace(shape, fade_s=cfg.excitation.fade_s), fs, amplitude, seed=cfg.run.seed)
        self.progress.step(f"loop: closed-loop run, velocity set-point multisine of {amplitude:.3g} m/s peak")
        exp = self.record(RECORDING, "velocity", excitation.samples, period_samples=excitation.period_samples)
        s = self.samples(exp, excitation)
        measured, warnings = periods_response(s, s["velocity_mps"], excitation, fs, cfg.identification)
        self.warnings += warnings
        f = measured.frequency_hz
        predicted, *variants = closed_loop.predicted_setpoint_response(cascade, seen, f, fs)
        response = measured.response
        torque = closed_loop.net_friction_torque(
            self.friction_fit, s["velocity_mps"], s["excitation"], cascade.friction_feedforward_nm
        )
        if torque is not None:  # the friction's part of the response out, as from the plant's torque
            friction, _ = periods_response(s, torque, excitation, fs, cfg.identification)
            raw = closed_loop.compare_closed_loop(
                f, response, predicted, excitation.band_hz, cfg.tuning.tolerance_db, cfg.tuning.tolerance_deg
            )
            self.part["closed_loop_with_friction"] = raw.to_dict()
            response = closed_loop.remove_friction(
                response, friction.response, closed_loop.friction_response(cascade, seen, f)
            )
        t = cfg.tuning
        scatter = closed_loop.line_scatter(measured.coherence, measured.n_averages)
        self.check = check = closed_loop.compare_closed_loop(
            f,
            response,
            predicted,
            excitation.band_hz,
            t.tolerance_db,
            t.tolerance_deg,
            scatter,
            usable=measured.coherence >= cfg.identification.coherence_threshold,
            variants=variants,
        )
        self.part["closed_loop"] = {
            **check.to_dict(),
            "recording": f"{RECORDING}.h5",
            "amplitude_mps": amplitude,
            "predicted_peaks": peaks,
            "predicted_bandwidth_hz": finite_or_none(closed_loop.bandwidth_or_nan(check.frequency_hz, check.predicted)),
            "measured_bandwidth_hz": finite_or_none(closed_loop.bandwidth_or_nan(check.frequency_hz, check.measured)),
        }
        if not check.within_tolerance:
            w = check.worst()
            self.restore(
                f"the measured closed loop differs from the prediction by up to {w['max_gain_error_db']:+.1f} dB "
                f"({w['max_gain_error_hz']:.3g} Hz) and {w['max_phase_error_deg']:+.0f} deg "
                f"({w['max_phase_error_hz']:.3g} Hz), beyond tuning.tolerance_db = {t.tolerance_db:g} / "
                f"tolerance_deg = {t.tolerance_deg:g}"
            )
            return
        step = self._step(cascade, self.part["closed_loop"]["predicted_bandwidth_hz"])
        if step is not None and not step.within_tolerance:
            self.restore(
                f"the measured velocity step differs from the prediction by {100 * step.rms_error:.1f} % rms of the "
                f"step, beyond tuning.step_tolerance_percent = {t.step_tolerance_percent:g} "
                f"(+ {100 * step.spread:.1f} % the plant's uncertainty gives)"
            )
            return
        self.part["kept"] = True
        self.before = None

    def _step(self, cascade, bandwidth_hz: float | None) -> step_check.StepCheck | None:
        """The step run (``closed-loop-step.h5``): ``+A, 0, -A, 0`` on the velocity set-point, its measured
        period against the predicted one; None (and why, in the summary) where the plant is known only on
        its measured lines."""
        cfg, seen = self.cfg, self.analysis.seen
        assert seen is not None
        if seen.mechanics is None:
            self.part["step"] = {"reason": "the plant is known only on its measured lines: no step is predicted"}
            return None
        fs = cfg.run.sample_rate_hz
        hold = step_check.hold_samples(bandwidth_hz or math.nan, fs)
        levels = step_check.step_levels(hold, step_check.ramp_samples(hold, cascade.accel_feedforward_nm_per_mps2 > 0))
        amplitude, peaks = closed_loop.closed_loop_amplitude(levels, fs, cascade, seen, cfg.limits)
        played = STEP_PERIODS + 1  # the first period lets the transient from rest die out
        self.progress.step(f"loop: closed-loop step run, velocity steps of {amplitude:.3g} m/s")
        exp = self.record(STEP_RECORDING, "velocity", np.tile(amplitude * levels, played), period_samples=levels.size)
        velocity, periods = step_check.measured_period(
            exp.samples["sample_index"], exp.samples["velocity_mps"], levels.size, played
        )
        friction = closed_loop.net_friction_torque(self.friction_fit, velocity, levels, cascade.friction_feedforward_nm)
        predictions = closed_loop.predicted_period(amplitude * levels, fs, cascade, seen, friction)
        self.step = step = step_check.compare_steps(
            amplitude * levels, velocity, predictions, fs, amplitude, cfg.tuning.step_tolerance_percent / 100, periods
        )
        self.part["step"] = {**step.to_dict(), "recording": f"{STEP_RECORDING}.h5", "predicted_peaks": peaks}
        return step

    def restore(self, reason: str = "the run ended before the gains were proven") -> None:
        """Put the gains the drive held back, when new ones are written and not proven (never raises)."""
        if self.before is None:
            return
        before, self.before = self.before, None
        self.part.update(kept=False, reason=reason)
        self.warnings.append(f"loop: {reason}: the previous gains {describe_gains(before)} were put back")
        self.part["restored"] = put_back_gains(self.adapter, before, self.warnings, "loop: ")


def read_gains(adapter, names) -> dict[str, float]:
    """The drive's present values of the parameters ``names``, SI units."""
    return {k: v for k, v in (adapter.read_loop() or {}).items() if k in names}


def put_back_gains(adapter, before: dict, warnings: list[str], prefix: str = "") -> bool:
    """Write ``before`` back and read it; whether it reads as it was. Never raises: the line may be gone, and
    what fails becomes a warning (each starting with ``prefix``)."""
    try:
        adapter.write_loop(before)
        back = read_gains(adapter, before)
    except Exception as exc:  # the ending must go on: say so
        warnings.append(f"{prefix}the previous gains could not be put back: {exc}")
        return False
    if back != before:
        warnings.append(f"{prefix}the gains put back read {describe_gains(back)}")
    return back == before


def describe_gains(values: dict) -> str:
    """``(name = value, ...)`` for messages."""
    return "(" + ", ".join(f"{k} = {v:.6g}" for k, v in values.items()) + ")"
