"""What a session will do, in numbers, before it does it: shown for the go-ahead and by ``--dry-run``.

A bench user confirms motion only when they know what will move: each
experiment's kind, length, peak torque and speed, the travel it needs, the
limits the device will enforce, and which filter slots will change.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from hilident.config.tables import Config, amplitude_ceiling_nm, auto_coherence_target
from hilident.signals.generators import position_of


@dataclass
class PlannedExperiment:
    """One experiment of the plan.

    Attributes
    ----------
    name : str
        ``friction``, ``identification`` or ``verification``.
    description : str
        What is played, e.g. ``"multisine 1-100 Hz"``.
    mode : str
        Where the set-point enters (``torque``, ``torque_injection``, ``velocity``, ``position``).
    duration_s : float
    samples : int
    peak_torque_nm : float or None
        Largest excitation torque (``None`` when the drive's loop chooses the torque); with
        ``amplitude_nm = "auto"`` the ceiling the trials may reach.
    peak_speed_mps : float or None
        Largest commanded speed (``None`` when not commanded).
    travel_m : float or None
        Largest excursion from the start position the profile commands.
    """

    name: str
    description: str
    mode: str
    duration_s: float
    samples: int
    peak_torque_nm: float | None = None
    peak_speed_mps: float | None = None
    travel_m: float | None = None
    amplitude: str = ""


@dataclass
class RunPlan:
    """The whole session: device, limits, experiments and filter-slot changes."""

    device: str
    port: str
    limits: dict
    experiments: list[PlannedExperiment] = field(default_factory=list)
    filters_enabled: list[int] = field(default_factory=list)
    filter_slots: int = 0
    notch_slots: int = 0
    clock: dict | None = None  # CANopen: who produces SYNC ({"source", "why"})

    def to_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        """The plan as a few lines of text for a terminal."""
        lim = self.limits
        lines = [
            f"plan for {self.device} on {self.port}:",
            f"  limits enforced by the device: torque {lim['torque_nm']:g} N*m, speed {lim['velocity_mps']:g} m/s, "
            f"position [{lim['position_min_m']:g}, {lim['position_max_m']:g}] m",
        ]
        if self.clock is not None:
            lines.append(f"  bus clock: SYNC from the {self.clock['source']}: {self.clock['why']}")
        for i, e in enumerate(self.experiments, 1):
            peaks = []
            if e.peak_torque_nm is not None:
                peaks.append(f"peak torque {e.peak_torque_nm:.3g} N*m")
            if e.peak_speed_mps is not None:
                peaks.append(f"peak speed {e.peak_speed_mps:.3g} m/s")
            if e.travel_m is not None:
                peaks.append(f"travel up to {e.travel_m:.3g} m each way")
            if e.amplitude:
                peaks.insert(0, f"amplitude {e.amplitude}")
            lines.append(
                f"  {i}. {e.name}: {e.description}, {e.mode} mode, "
                + ("up to " if e.name == "auto amplitude" else "")
                + f"{e.duration_s:.1f} s"
                + (", " + ", ".join(peaks) if peaks else "")
            )
        if self.filters_enabled:
            lines.append(
                f"  filter slots {self.filters_enabled} hold filters: bypassed while the plant is measured, "
                "put back if the session ends before its upload"
            )
        if self.notch_slots:
            lines.append(
                f"  filter slots 0..{self.notch_slots - 1} (of {self.filter_slots}) may be rewritten with "
                "the new notches"
            )
        return "\n".join(lines)


def make_plan(
    cfg: Config, excitation, friction_profile, adapter, filters_found: list[dict], friction_mode: str = "velocity"
) -> RunPlan:
    """The plan of a session from its config, its built signals and the device it reached.

    Parameters
    ----------
    cfg : Config
    excitation : session.Excitation
        The identification excitation as it will be played (torque, N·m).
    friction_profile : signals.generators.RampProfile or None
        The friction test's velocity set-points (m/s), when enabled.
    adapter
        The open device (``identity``, ``port``, ``sample_rate_hz``).
    filters_found : list of dict
        ``{slot, enabled, ...}`` per filter slot, as read from the device.
    friction_mode : str
        ``velocity``, or ``position`` when the friction legs run as a position profile.
    """
    fs = cfg.run.sample_rate_hz
    lim = cfg.bench_limits
    plan = RunPlan(
        device=f"{adapter.identity.name} (firmware {adapter.identity.firmware})",
        port=adapter.port,
        limits={
            "torque_nm": lim.torque_nm,
            "velocity_mps": lim.velocity_mps,
            "position_min_m": lim.position_min_m,
            "position_max_m": lim.position_max_m,
        },
        filters_enabled=[f["slot"] for f in filters_found if f["enabled"]],
        filter_slots=adapter.identity.filter_slots,
    )
    clock_plan = getattr(adapter, "clock_plan", None)
    if clock_plan is not None:
        plan.clock = clock_plan(fs)
    if friction_profile is not None:
        sp = np.asarray(friction_profile.setpoint_mps)
        speeds = cfg.friction_test.speeds_mps
        plan.experiments.append(
            PlannedExperiment(
                "friction",
                f"constant-velocity legs both ways at {min(speeds):g}..{max(speeds):g} m/s"
                + (
                    f", then further rounds within the same speeds and travel until Fc and Fv are known to "
                    f"{cfg.friction_test.target_ci_percent:g} %, {cfg.friction_test.max_duration_s:g} s in all at most"
                    if cfg.friction_test.target_ci_percent > 0
                    else ""
                ),
                friction_mode,
                len(sp) / fs,
                len(sp),
                peak_speed_mps=float(np.max(np.abs(sp))) if len(sp) else 0.0,
                travel_m=float(friction_profile.max_excursion_m),
            )
        )
    e = cfg.excitation
    x = np.asarray(excitation.samples)
    what = (
        e.kind
        if e.kind in ("sine", "square", "step")
        else f"{e.kind} {excitation.band_hz[0]:g}-{excitation.band_hz[1]:g} Hz"
    )
    if e.closed_loop:
        what += f" {e.mode} set-point perturbation, closed loop"
    peaks = _excitation_peaks(e.mode, x, fs)
    if e.amplitude_auto:
        ceiling = amplitude_ceiling_nm(cfg)
        peaks["amplitude"] = f"auto (at most {ceiling:g} N*m)"
        plan.experiments.append(_auto_trials(cfg, excitation, ceiling))
    plan.experiments.append(PlannedExperiment("identification", what, e.mode, len(x) / fs, len(x), **peaks))
    if cfg.notch.enabled and cfg.identification.max_resonances:
        plan.notch_slots = min(cfg.identification.max_resonances, adapter.identity.filter_slots)
        if cfg.notch.verify and plan.notch_slots:
            plan.experiments.append(
                PlannedExperiment(
                    "verification", "the same excitation with the new notches", e.mode, len(x) / fs, len(x), **peaks
                )
            )
    return plan


def _auto_trials(cfg: Config, excitation, ceiling_nm: float) -> PlannedExperiment:
    """The records ``amplitude_nm = "auto"`` makes before the run: standstill, then at most ``auto_max_trials``."""
    e, fs = cfg.excitation, cfg.run.sample_rate_hz
    period = excitation.period_samples
    n = period + period // 4 + e.auto_max_trials * (e.auto_trial_periods + 1) * period
    return PlannedExperiment(
        "auto amplitude",
        f"standstill noise record, then up to {e.auto_max_trials} trials of "
        f"{e.auto_trial_periods} multisine periods (+1 lead-in) until coherence "
        f"{auto_coherence_target(cfg):.2f} is predicted",
        e.mode,
        n / fs,
        n,
        peak_torque_nm=ceiling_nm,
    )


def _excitation_peaks(mode: str, x: np.ndarray, sample_rate_hz: float) -> dict:
    """What the excitation commands: its peak torque, or its peak speed and travel for a set-point perturbation."""
    peak = float(np.max(np.abs(x))) if len(x) else 0.0
    if mode == "velocity":
        return {"peak_speed_mps": peak, "travel_m": excitation_travel_m(mode, x, sample_rate_hz)}
    if mode == "position":
        return {"travel_m": peak}
    return {"peak_torque_nm": peak}


def excitation_travel_m(mode: str, setpoints: np.ndarray, sample_rate_hz: float) -> float:
    """Largest distance from the held position a set-point perturbation commands, m (0 for torque modes)."""
    x = np.asarray(setpoints, dtype=float)
    if mode == "velocity":
        x = position_of(x, sample_rate_hz)
    elif mode != "position":
        return 0.0
    return float(np.max(np.abs(x))) if len(x) else 0.0
