"""The automatic excitation amplitude (``amplitude_nm = "auto"``): short trials, and what they predict.

The numbers are pure functions (coherence predicted per excited line, the
amplitude a coherence target needs, the nonlinear share from friction or
from two trials' responses); :class:`AutoAmplitude` plays the trials through
the session's recorder and chooses.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from hilident.config.tables import (
    AUTO_BAND_SHARE,
    AUTO_START_SHARE,
    Config,
    amplitude_ceiling_nm,
    auto_coherence_target,
)
from hilident.errors import DataError
from hilident.pipeline.selection import MAX_MISSING_SHARE, GappedPeriods
from hilident.session.excitation import Excitation, build_excitation, excitation_recipe

__all__ = [
    "AutoAmplitude",
    "band_coherence",
    "coherence_factor",
    "friction_share",
    "period_spectra",
    "predicted_coherence",
    "response_change",
    "smooth_lines",
]

#: Share of the speed limit and of the room to the position window a trial's prediction may use.
AUTO_LIMIT_MARGIN = 0.8
#: Share of the torque limit a trial's amplitude may reach.
AUTO_TORQUE_MARGIN = 0.95
#: Share of the torque limit the run's predicted peak measured torque may reach: the loop adds to the excitation,
#: and over a run several times a trial's length it adds more than linear scaling of the trial's peak predicts (a
#: position loop's response to the drift, friction).
AUTO_PEAK_TORQUE_MARGIN = 0.8
#: Below this share of the Stribeck velocity the axis counts as sticking.
AUTO_STUCK_SHARE = 0.1
#: Factor to the next trial when a trial's response does not rise above the noise (nothing to scale from).
AUTO_NO_RESPONSE_STEP = 4.0
#: Without a friction test, the factor from a first trial to the second (the response change between two
#: amplitudes is what bounds the distortion then).
AUTO_LINEARITY_STEP = 2.0
#: Smallest factor between two trials (a smaller step tells nothing new).
AUTO_MIN_STEP = 1.1
#: Neighbouring excited lines a noise estimate is averaged over (a single period's line has two degrees of freedom).
AUTO_NOISE_LINES = 5


def period_spectra(x: np.ndarray, period_samples: int, lines: np.ndarray, present=None) -> np.ndarray:
    """DFT of each whole period of ``x`` at the DFT bins ``lines``, shape (periods, lines).

    With ``present`` (bool per sample), a period that misses samples is read by least squares on those it has
    (:func:`~hilident.ident.gapped_periods.line_spectra`), and is a row of NaN when they cannot tell its lines
    apart.
    """
    n = len(x) // period_samples
    periods = np.asarray(x[: n * period_samples], dtype=float).reshape(n, period_samples)
    if present is None:
        return np.fft.rfft(periods, axis=1)[:, lines]
    from hilident.ident.gapped_periods import line_spectra

    spectra, _ = line_spectra(periods, np.asarray(present[: n * period_samples]).reshape(n, period_samples), lines)
    return spectra


def smooth_lines(power: np.ndarray) -> np.ndarray:
    """A per-line noise power averaged over :data:`AUTO_NOISE_LINES` neighbouring lines."""
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(np.asarray(power, dtype=float), AUTO_NOISE_LINES, mode="nearest")


def predicted_coherence(signal: dict, noise: dict, factor: float, periods: int) -> np.ndarray:
    """Coherence per line of a periodic run of ``periods`` periods at ``factor`` times the trial's amplitude.

    Each channel's coherence over periods is ``(S r^2 + N / M) / (S r^2 + N)``
    (``|mean|^2 / (|mean|^2 + variance)`` with the mean's own noise ``N / M``),
    the signal power ``S`` growing with the amplitude squared and the noise
    power per period ``N`` staying as measured; the input's and the output's
    multiply.
    """
    out = 1.0
    for key in signal:
        s, n = signal[key] * factor**2, noise[key]
        out = out * (s + n / periods) / np.maximum(s + n, 1e-300)
    return np.clip(out, 0.0, 1.0)


def band_coherence(coherence: np.ndarray) -> float:
    """The coherence :data:`AUTO_BAND_SHARE` of the band's lines reach or exceed."""
    return float(np.quantile(coherence, 1.0 - AUTO_BAND_SHARE))


def coherence_factor(signal: dict, noise: dict, periods: int, target: float) -> float:
    """Smallest factor on the trial's amplitude whose predicted band coherence reaches ``target`` (inf: none)."""
    from scipy.optimize import brentq

    def gap(log_r: float) -> float:
        return band_coherence(predicted_coherence(signal, noise, float(np.exp(log_r)), periods)) - target

    lo, hi = np.log(1e-3), np.log(1e4)
    if gap(hi) < 0:
        return float("inf")
    if gap(lo) >= 0:
        return 1e-3
    return float(np.exp(brentq(gap, lo, hi, xtol=1e-4)))


def response_change(low: dict, high: dict) -> float:
    """Nonlinear distortion at the higher of two trials' amplitudes, from how much the response changed.

    For a linear plant the responses ``G = mean Y / mean U`` of two trials
    agree within their noise. Friction-like distortion ``D`` falls as
    ``1 / A``: with ``G(A) = G0 (1 + D0 / A)`` the relative change
    ``x = |G_low - G_high| / |G_high|`` is ``D (r - 1) / (1 + D)`` for the
    share ``D`` left at ``A_high`` and ``r = A_high / A_low``, so
    ``D = x / (r - 1 - x)``. ``x`` is the median over the lines, their noise
    (``var G / |G|^2`` of both) taken out. ``low`` and ``high``:
    ``{amplitude_nm, frf, relative_variance}``; inf when the change is too large to say.
    """
    change = np.abs(high["frf"] - low["frf"]) ** 2 / np.maximum(np.abs(high["frf"]) ** 2, 1e-300)
    x = float(np.sqrt(max(np.median(change - low["relative_variance"] - high["relative_variance"]), 0.0)))
    room = high["amplitude_nm"] / low["amplitude_nm"] - 1.0 - x
    return x / room if room > 0 else float("inf")


def friction_share(velocity: np.ndarray, excitation: np.ndarray, friction, stuck_mps: float) -> float:
    """Rms of the fitted friction's nonlinear part (Coulomb and Stribeck) over the rms excitation.

    Stick-slip repeats every period, so coherence does not see the distortion
    it brings; its share falls as the excitation grows (the viscous part is
    linear and left out). While the axis sticks (``|v| <= stuck_mps``)
    friction holds whatever torque is applied, up to ``Fs``.
    """
    from hilident.ident.friction import stribeck

    velocity, excitation = np.asarray(velocity, dtype=float), np.asarray(excitation, dtype=float)
    nonlinear = stribeck(velocity, dataclasses.replace(friction, Fv=0.0))
    stuck = np.abs(velocity) <= stuck_mps
    nonlinear[stuck] = np.clip(excitation[stuck], -friction.Fs, friction.Fs)
    rms_x = float(np.sqrt(np.mean(np.square(excitation))))
    return float(np.sqrt(np.mean(np.square(nonlinear)))) / rms_x if rms_x > 0 else float("inf")


def _last_period(samples: dict, period: int) -> tuple[dict | None, np.ndarray | None]:
    """The last whole period of a record (NaN where a sample is missing) and which of its samples exist
    (None: all); (None, None) when it misses more than :data:`~hilident.pipeline.selection.MAX_MISSING_SHARE`."""
    index = np.asarray(samples["sample_index"], dtype=np.int64)
    if len(index) == 0:
        return None, None
    first = int(index[-1]) - period + 1
    rows = np.flatnonzero(index >= first)
    if first < 0 or len(rows) < (1.0 - MAX_MISSING_SHARE) * period or np.any(np.diff(index[rows]) <= 0):
        return None, None
    if len(rows) == period:
        return {k: v[rows] for k, v in samples.items()}, None
    at = index[rows] - first
    present = np.zeros(period, dtype=bool)
    present[at] = True
    laid = GappedPeriods(rows, at, present, [0])
    return {k: laid.spread(v) for k, v in samples.items()}, present


class AutoAmplitude:
    """Choose the torque amplitude of a run by short trials.

    Parameters
    ----------
    cfg : Config
        The run's configuration (``amplitude_nm = "auto"``).
    record : callable
        ``record(name, mode, samples, period_samples=, recipe=)`` plays and records a trial
        (:meth:`hilident.session.run.Session.record`), returning its :class:`~hilident.session.run.Experiment`.
    analysis_samples : callable
        ``analysis_samples(experiment, excitation)``: a trial's whole gap-free periods.
    warnings : list of str
        Appended to.
    progress : Progress
    """

    def __init__(self, cfg: Config, record: Callable, analysis_samples: Callable, warnings: list[str], progress):
        self.cfg = cfg
        self.record = record
        self._analysis_samples = analysis_samples
        self.warnings = warnings
        self.progress = progress
        self._friction_slowest_mps = 0.0  # set by choose() from its friction result

    def choose(self, friction) -> tuple[Config, dict]:
        """Choose the torque amplitude by short trials; returns the config playing it and the choice's record.

        A record at standstill gives the noise floor per excited line; trials
        of a few periods of the same multisine, from the friction test's Fs
        up, predict the coherence the run would reach and the amplitude the
        target needs, and the friction's share the run would carry. Each
        next trial is that amplitude times ``auto_safety``, capped at the
        ceiling and at what the trial's measured peak speed, travel and torque,
        scaled linearly, leave within ``[limits]``. The choice and the reason
        go to ``summary.json["excitation"]["auto"]``.
        """
        cfg = self.cfg
        e = cfg.excitation
        probe = build_excitation(cfg, amplitude=1.0)
        period = probe.period
        band = self._band(probe)
        fs = cfg.run.sample_rate_hz
        bins = np.asarray(probe.excited_bins)
        lines = bins[(bins * fs / period >= band[0]) & (bins * fs / period <= band[1])]
        if lines.size < AUTO_NOISE_LINES:
            lines = bins
        run_periods = len(probe.samples) // period - 1
        fit = friction.fit.params if friction is not None else None
        self._friction_slowest_mps = friction.slowest_mps if friction is not None else 0.0
        ceiling, target = amplitude_ceiling_nm(cfg), auto_coherence_target(cfg)
        # a trial's peak stays off the trip level
        highest = min(ceiling, AUTO_TORQUE_MARGIN * cfg.bench_limits.torque_nm)
        self.progress.step(
            f"excitation: choosing the amplitude (coherence target {target:.2f} over "
            f"{band[0]:g}-{band[1]:g} Hz, ceiling {ceiling:g} N*m)"
        )
        noise = self._auto_noise(period, lines, fit)
        amplitude = min(e.auto_start_nm or self._auto_start(probe, fit, ceiling), highest)
        trials: list[dict] = []
        chosen: float | None = None
        reason, needed = "", None
        for i in range(e.auto_max_trials):
            t = self._auto_trial(
                i + 1, amplitude, period, lines, run_periods, noise, fit, target, trials[-1] if trials else None
            )
            if t is None:
                continue
            trials.append(t)
            cap, cap_by = min(
                (highest, "the ceiling" if highest == ceiling else "limits.torque_nm (with its margin)"),
                (t["cap_nm"], t["cap_by"]),
            )
            needed = t["needed_nm"]
            enough = needed <= amplitude * (1 + 1e-9)
            close = amplitude * AUTO_MIN_STEP >= cap  # no room left for a trial that would tell more
            if enough or (close and needed <= cap):
                chosen = min(cap, max(amplitude, needed * e.auto_safety))
                reason = self._auto_met(t, cap, band, run_periods, fit, tried=enough)
                break
            if close:
                chosen = cap
                reason = self._auto_capped(t, cap, cap_by, target)
                break
            amplitude = min(cap, max(needed * e.auto_safety, 1.5 * amplitude))
        else:
            chosen, reason = self._auto_out_of_trials(trials, amplitude, needed)
        auto = {
            "chosen_nm": float(chosen),
            "reason": reason,
            "target_coherence": target,
            "band_share": AUTO_BAND_SHARE,
            "band_hz": [float(band[0]), float(band[1])],
            "ceiling_nm": float(ceiling),
            "safety": e.auto_safety,
            "run_periods": run_periods,
            "noise_floor": noise["report"],
            "trials": [t["report"] for t in trials],
        }
        if reason.startswith("target met"):
            why = f"coherence >= {target:.2f} over {band[0]:g}-{band[1]:g} Hz predicted"
        elif reason.startswith("capped"):
            why = reason.split(":")[0] + f" (coherence {target:.2f}): the notch decision rests on the evidence gates"
        else:
            why = f"target not reached in excitation.auto_max_trials = {e.auto_max_trials}"
        auto["line"] = (
            f"excitation: auto amplitude {chosen:.3g} N*m ({why}; {len(trials)} trial{'s' if len(trials) != 1 else ''})"
        )
        self.progress.step(auto["line"])
        return dataclasses.replace(cfg, excitation=dataclasses.replace(e, amplitude_nm=float(chosen))), auto

    def _auto_met(self, trial: dict, cap: float, band, run_periods: int, fit, tried: bool) -> str:
        """The reason when the target is met (by the last trial, or as it predicts when the cap is that close)."""
        e = self.cfg.excitation
        how = "target met" if tried else "target met as predicted (the cap leaves no room for another trial)"
        source = "friction" if fit is not None else "response change between trials"
        return (
            f"{how}: {trial['needed_nm']:.3g} N*m needed (set by {trial['report']['needed_by']}) times "
            f"excitation.auto_safety = {e.auto_safety:g}, at least the trial's, at most {cap:.3g} N*m; "
            f"coherence >= {auto_coherence_target(self.cfg):.2f} at {AUTO_BAND_SHARE:.0%} of the excited lines "
            f"over {band[0]:g}-{band[1]:g} Hz predicted for the run's {run_periods} periods; nonlinear "
            f"distortion ({source}) within excitation.auto_nonlinear_share = {e.auto_nonlinear_share:g}"
        )

    def _auto_out_of_trials(self, trials: list, amplitude: float, needed: float | None) -> tuple[float, str]:
        """``auto_max_trials`` made before the target: the last prediction (not tried), or an error without any."""
        e = self.cfg.excitation
        if not trials:
            raise DataError(
                f'excitation.amplitude_nm = "auto": none of the {e.auto_max_trials} trials could be '
                "analysed (lost samples, see the warnings); check the line, or give the amplitude as "
                "a number"
            )
        reason = (
            f"excitation.auto_max_trials = {e.auto_max_trials} trials made before the target was met: the run "
            f"uses the amplitude the last trial predicts ({amplitude:.3g} N*m, within its caps)"
        )
        if needed is not None and needed > amplitude:
            self.warnings.append(
                f"excitation: auto amplitude {amplitude:.3g} N*m is below the {needed:.3g} N*m the "
                "last trial predicts the target needs; the notch decision will rest on the evidence "
                "gates"
            )
        return amplitude, reason

    def _auto_start(self, probe: Excitation, fit, ceiling: float) -> float:
        """First trial's amplitude, N·m: the multisine whose rms is the friction test's ``Fs / auto_nonlinear_share``.

        Friction torque is at most Fs (breakaway) and about Fc while sliding, so
        below that rms its nonlinear part would exceed its allowed share for
        sure. Without a friction test, :data:`AUTO_START_SHARE` of the ceiling.
        """
        if fit is None or not fit.Fs > 0:
            return AUTO_START_SHARE * ceiling
        x = probe.samples[probe.period :]  # amplitude 1: peak over rms is the crest factor
        crest = float(np.max(np.abs(x)) / np.sqrt(np.mean(np.square(x))))
        return crest * fit.Fs / self.cfg.excitation.auto_nonlinear_share

    def _auto_capped(self, trial: dict, cap: float, cap_by: str, target: float) -> str:
        """The reason (and a warning) when the cap stops the amplitude before the target."""
        band = trial["report"]["predicted_coherence_band"]
        reason = (
            f"capped at {cap:.3g} N*m by {cap_by} before the target: coherence {band:.2f} "
            f"predicted at {AUTO_BAND_SHARE:.0%} of the lines (target {target:.2f}), "
            f"{trial['needed_nm']:.3g} N*m would be needed (set by {trial['report']['needed_by']})"
        )
        self.warnings.append(
            f"excitation: auto amplitude {reason}; the notch decision will then rest on the evidence gates"
        )
        return reason

    def _band(self, excitation: Excitation) -> tuple[float, float]:
        """The band searched for resonances: ``[identification]`` f_min_hz/f_max_hz, else the excitation's."""
        ic = self.cfg.identification
        return ic.f_min_hz or excitation.band_hz[0], ic.f_max_hz or excitation.band_hz[1]

    def _plant_input(self, s: dict, fit) -> np.ndarray:
        """The torque as the identification sees it: the friction fit removed when there is one."""
        if fit is None:
            return s["torque_nm"]
        from hilident.ident.friction import compensate

        return compensate(
            s["torque_nm"],
            s["velocity_mps"],
            fit,
            self.cfg.friction_test.velocity_deadband_mps,
            self._friction_slowest_mps,
        )

    def _auto_noise(self, period: int, lines: np.ndarray, fit) -> dict:
        """Noise power per excited line and period, output and torque, from a record with zero excitation."""
        mode = self.cfg.excitation.mode
        recipe = excitation_recipe(self.cfg, amplitude=0.0, duration_s=1.25 * self.cfg.excitation.period_s)
        exp = self.record("auto_noise", mode, np.zeros(period + period // 4), period_samples=period, recipe=recipe)
        s = exp.samples
        out: dict[str, Any] = {"output": np.zeros(len(lines)), "torque": np.zeros(len(lines))}
        last, present = _last_period(s, period)
        spectra = {}
        if last is not None:
            for key, x in (("output", last[self.cfg.identification.output]), ("torque", self._plant_input(last, fit))):
                spectra[key] = period_spectra(x, period, lines, present)[0]
        if last is None or not all(np.isfinite(v).all() for v in spectra.values()):
            self.warnings.append(
                "excitation: the standstill record lost samples; the noise floor comes from the "
                "trials' period-to-period scatter alone"
            )
            out["report"] = None
            return out
        for key, spec in spectra.items():
            out[key] = smooth_lines(np.abs(spec) ** 2)
        # as the amplitude of a sine on one line (peak), the unit of the channel
        out["report"] = {
            "output_median": float(np.median(2 * np.sqrt(out["output"]) / period)),
            "torque_nm_median": float(np.median(2 * np.sqrt(out["torque"]) / period)),
            "output_channel": self.cfg.identification.output,
            "per": "excited line, peak",
        }
        return out

    def _trial_spectra(self, exp, x, period: int, lines: np.ndarray, fit) -> tuple[dict, dict]:
        """A trial's samples that exist and its output's and torque's line spectra, one row a period.

        Whole gap-free periods, or periods that miss a few samples, each read by least squares on those it has
        (then only the periods whose lines both channels could be read at).

        Raises
        ------
        DataError
            Fewer than two periods to read.
        """
        s = self._analysis_samples(exp, x, gapped=True)
        present = s.get("present")
        spectra = {
            "output": period_spectra(s[self.cfg.identification.output], period, lines, present),
            "torque": period_spectra(self._plant_input(s, fit), period, lines, present),
        }
        if present is None:
            return s, spectra
        used = np.isfinite(spectra["output"]).all(axis=1) & np.isfinite(spectra["torque"]).all(axis=1)
        if used.sum() < 2:
            raise DataError("fewer than two periods with samples enough to read their lines")
        spectra = {key: spec[used] for key, spec in spectra.items()}
        return {key: v[present] for key, v in s.items() if key != "present"}, spectra

    def _auto_trial(
        self,
        number: int,
        amplitude: float,
        period: int,
        lines: np.ndarray,
        run_periods: int,
        noise: dict,
        fit,
        target: float,
        previous: dict | None,
    ) -> dict | None:
        """One trial: the multisine at ``amplitude`` for a few periods, and what it predicts for the run."""
        cfg = self.cfg
        e = cfg.excitation
        duration = e.auto_trial_periods * e.period_s
        trial_cfg = dataclasses.replace(cfg, excitation=dataclasses.replace(e, duration_s=duration))
        x = build_excitation(trial_cfg, amplitude=amplitude)
        exp = self.record(
            f"auto_trial_{number}",
            e.mode,
            x.samples,
            period_samples=period,
            recipe=excitation_recipe(cfg, amplitude=amplitude, duration_s=duration),
        )
        try:
            s, spectra = self._trial_spectra(exp, x, period, lines, fit)
        except DataError as exc:  # lost samples: nothing to predict from, the next trial repeats it
            self.warnings.append(f"excitation: auto trial {number} at {amplitude:.3g} N*m could not be analysed: {exc}")
            return None
        m = len(spectra["output"])
        signal, scatter = {}, {}
        for key, spec in spectra.items():
            scatter[key] = np.maximum(smooth_lines(np.var(spec, axis=0, ddof=1)), noise[key])
            # the periodic part less the mean's own noise; a line lost in the noise keeps a small signal (a tenth
            # of what the mean's noise could hide), so what it needs stays finite, and large
            signal[key] = np.maximum(np.abs(spec.mean(axis=0)) ** 2 - scatter[key] / m, 0.1 * scatter[key] / m)
            # no noise at all (a quantised sensor at rest): a floor far below the signal keeps the ratios finite
            scatter[key] = np.maximum(scatter[key], 1e-12 * max(float(np.max(signal[key])), 1e-300))
        coh = predicted_coherence(signal, scatter, 1.0, run_periods)
        factor = coherence_factor(signal, scatter, run_periods, target)
        means = {key: spec.mean(axis=0) for key, spec in spectra.items()}
        torque_mean = np.where(means["torque"] == 0, 1e-300, means["torque"])
        this = {
            "amplitude_nm": amplitude,
            "frf": means["output"] / torque_mean,
            "relative_variance": sum(scatter[k] / np.maximum(signal[k], 1e-300) for k in spectra) / m,
        }
        share, share_by = None, "nonlinear distortion unknown until a second trial"
        if fit is not None:
            stuck = max(cfg.friction_test.velocity_deadband_mps, AUTO_STUCK_SHARE * fit.vs)
            share, share_by = friction_share(s["velocity_mps"], s["excitation"], fit, stuck), "friction's share"
        elif previous is not None and amplitude >= AUTO_MIN_STEP * previous["frf"]["amplitude_nm"]:
            share, share_by = response_change(previous["frf"], this), "response change between trials"
        elif previous is not None and previous["share"] is not None:  # as 1 / A from the last estimate
            share = previous["share"] * previous["frf"]["amplitude_nm"] / amplitude
            share_by = "response change between trials"
        nonlinear = share / e.auto_nonlinear_share if share is not None else AUTO_LINEARITY_STEP / e.auto_safety
        moved = np.median(signal["output"]) > np.median(scatter["output"]) and np.ptp(s[cfg.identification.output]) > 0
        if not moved:  # nothing above the noise: the prediction is weak, step at least this far
            factor, nonlinear = max(min(factor, 1e3), AUTO_NO_RESPONSE_STEP / e.auto_safety), 0.0
        needed = amplitude * max(factor, nonlinear)
        needed_by = "no response above the noise" if not moved else share_by if nonlinear > factor else "coherence"
        limits = self._auto_caps(exp.samples, amplitude, period, run_periods)
        speed, torque, travel, cap, cap_by = (limits[k] for k in ("speed", "torque", "travel", "cap", "cap_by"))
        report_ = {
            "amplitude_nm": float(amplitude),
            "predicted_coherence_min": float(np.min(coh)),
            "predicted_coherence_median": float(np.median(coh)),
            "predicted_coherence_band": band_coherence(coh),
            "coherence_factor": float(factor),
            "nonlinear_share": float(share) if share is not None else None,
            "nonlinear_share_from": "friction fit" if fit is not None else "response change between trials",
            "responded": bool(moved),
            "needed_nm": float(needed),
            "needed_by": needed_by,
            "peak_speed_mps": speed,
            "peak_torque_nm": torque,
            "travel_m": float(travel) if travel is not None else None,
            "cap_nm": float(cap),
            "cap_by": cap_by,
        }
        self.progress.step(
            f"  trial {number}: {amplitude:.3g} N*m -> coherence "
            f"{report_['predicted_coherence_band']:.2f} predicted, {needed:.3g} N*m needed"
        )
        return {
            "report": report_,
            "needed_nm": float(needed),
            "cap_nm": float(cap),
            "cap_by": cap_by,
            "frf": this,
            "share": share,
        }

    def _auto_caps(self, full: dict, amplitude: float, period: int, run_periods: int) -> dict:
        """What a trial's measurements allow: the run's peak torque, speed and travel, scaled linearly, in ``[limits]``.

        The travel adds the trial's drift per period (an open-loop axis creeps)
        over the run's extra periods; the room is to the nearer end of the
        position window from where the trial started or ended.
        """
        e, lim = self.cfg.excitation, self.cfg.bench_limits
        speed = float(np.max(np.abs(full["velocity_mps"])))
        torque = float(np.max(np.abs(full["torque_nm"])))
        caps = [
            (
                amplitude * AUTO_PEAK_TORQUE_MARGIN * lim.torque_nm / torque if torque > 0 else np.inf,
                "limits.torque_nm (the trial's measured peak torque, scaled)",
            ),
            (
                amplitude * AUTO_LIMIT_MARGIN * lim.velocity_mps / speed if speed > 0 else np.inf,
                "limits.velocity_mps (the trial's measured peak speed, scaled)",
            ),
        ]
        travel = None
        if "position_m" in full:
            pos = full["position_m"]
            start, end = float(pos[0]), float(pos[-1])
            excursion = float(np.max(np.abs(pos - start)))
            drift = abs(end - float(pos[min(period, len(pos) - 1)])) / e.auto_trial_periods
            travel = excursion + drift * max(run_periods - e.auto_trial_periods, 0)
            room = min(lim.position_max_m - max(start, end), min(start, end) - lim.position_min_m)
            caps.append(
                (
                    amplitude * AUTO_LIMIT_MARGIN * max(room, 0.0) / travel if travel > 0 else np.inf,
                    "the position window (the trial's travel and drift, scaled)",
                )
            )
        cap, cap_by = min(caps)
        return {"speed": speed, "torque": torque, "travel": travel, "cap": float(cap), "cap_by": cap_by}
