"""The report's section on the drive's loop: margins with the present gains and the gains proposed.

It shows ``summary.json["loop"]`` (:mod:`hilident.pipeline.loop_analysis`): for the velocity and
the position loop, without and with the notch, the gain and phase margins, the sensitivity peak and the
bandwidth; then the ``[tuning]`` targets, the gains proposed and what the notch buys at the same targets; then,
with ``[tuning] upload``, the gains written, kept or put back, and the closed loop measured against its
prediction (:mod:`hilident.session.gain_step`).
"""

from __future__ import annotations

from typing import Any

from hilident.html_report.gather import ReportInputs
from hilident.html_report.markup import MISSING, esc, key_values, note, num, section, table

__all__ = ["loop"]

_LOOPS = (("velocity", "velocity (position loop open)"), ("position", "position (velocity loop closed)"))
_PARTS = (("without_notch", "without the notch"), ("with_notch", "with the notch"))


def _figure_cells(figures: dict) -> list[str]:
    return [
        num(figures.get("gain_margin_db"), "dB", 3),
        num(figures.get("gain_margin_hz"), "Hz", 3),
        num(figures.get("phase_margin_deg"), "deg", 3),
        num(figures.get("crossover_hz"), "Hz", 3),
        num(figures.get("sensitivity_peak"), "", 3),
        num(figures.get("bandwidth_hz"), "Hz", 3),
    ]


_HEADER = ["gain margin", "at", "phase margin", "crossover", "Ms", "bandwidth"]


def _present(part: dict) -> str:
    rows = [
        [esc(loop_name), esc(part_name), *_figure_cells(part[loop][key])]
        for loop, loop_name in _LOOPS
        for key, part_name in _PARTS
        if isinstance(part.get(loop), dict) and isinstance(part[loop].get(key), dict)
    ]
    return table(["loop", "", *_HEADER], rows, "The drive's present gains around the identified plant")


#: The gains and feed-forward terms shown, with their units (a position I or D term or a feed-forward term only
#: where the drive has it).
_GAIN_UNITS = (
    ("kv_nm_per_mps", "N*m/(m/s)"),
    ("ti_s", "s"),
    ("kp_pos_per_s", "1/s"),
    ("ki_pos_per_s2", "1/s^2"),
    ("kd_pos", ""),
    ("velocity_feedforward", ""),
    ("accel_feedforward_nm_per_mps2", "N*m/(m/s^2)"),
    ("viscous_feedforward_nm_per_mps", "N*m/(m/s)"),
    ("friction_feedforward_nm", "N*m"),
)


def _gains(gains: dict) -> str:
    return ", ".join(
        f"{esc(name)} {num(gains.get(name), unit, 4)}"
        for name, unit in _GAIN_UNITS
        if name in gains or name in ("kv_nm_per_mps", "ti_s", "kp_pos_per_s")
    )


def _feedforward(part: Any) -> list[tuple[str, str]]:
    if not isinstance(part, dict):
        return []
    pairs = [("feed-forward proposed", _gains(part.get("terms") or {}) or MISSING)]
    pairs += [(f"{name} left out", esc(str(why))) for name, why in (part.get("left_out") or {}).items()]
    return pairs


def _tuning(tuning: Any) -> str:
    if not isinstance(tuning, dict):
        return note("No gains proposed ([tuning] off).")
    targets = tuning.get("targets") or {}
    rows = []
    for key, part_name in _PARTS:
        proposed = tuning.get(key)
        if not isinstance(proposed, dict):
            rows.append([esc(part_name), MISSING, *([MISSING] * len(_HEADER))])
            continue
        for loop, loop_name in _LOOPS:
            rows.append([esc(part_name), esc(loop_name), *_figure_cells(proposed.get(loop) or {})])
    gains = [
        (f"gains {name}", _gains(tuning[key]["gains"])) for key, name in _PARTS if isinstance(tuning.get(key), dict)
    ]
    return key_values(
        [
            (
                "targets",
                f"gain margin {num(targets.get('gain_margin_db'), 'dB', 3)}, phase margin "
                f"{num(targets.get('phase_margin_deg'), 'deg', 3)}, Ms {num(targets.get('sensitivity_peak'), '', 3)}",
            ),
            ("plants the targets hold on", num(tuning.get("plants"))),
            *gains,
            *_feedforward(tuning.get("feedforward")),
            ("verdict", esc(str(tuning.get("verdict", "")))),
        ]
    ) + table(["proposed", "loop", *_HEADER], rows, "The proposed gains on the worst of the plants")


def _check_pairs(check: dict, label: str) -> list[tuple[str, str]]:
    return [
        (
            label,
            f"{num(check.get('lines'))} lines of {num(check.get('band_hz', [None])[0], 'Hz')} to "
            f"{num(check.get('band_hz', [None, None])[-1], 'Hz')} ({num(check.get('lines_left_out'))} below the "
            f"coherence threshold left out): largest difference {num(check.get('max_gain_error_db'), 'dB', 3)} at "
            f"{num(check.get('max_gain_error_hz'), 'Hz', 3)}, {num(check.get('max_phase_error_deg'), 'deg', 3)} at "
            f"{num(check.get('max_phase_error_hz'), 'Hz', 3)}; rms {num(check.get('rms_gain_error_db'), 'dB', 3)}, "
            f"{num(check.get('rms_phase_error_deg'), 'deg', 3)}; {num(check.get('lines_outside'))} line(s) beyond "
            f"{num(check.get('tolerance_db'), 'dB')} / {num(check.get('tolerance_deg'), 'deg')} and their own scatter",
        )
    ]


def _upload(upload: Any) -> str:
    if not isinstance(upload, dict):
        return ""
    outcome = "kept" if upload.get("kept") else ("written, then put back" if upload.get("uploaded") else "not written")
    pairs = [("gains", esc(outcome))]
    for key, label in (("before", "before"), ("readback", "read back"), ("asked", "asked")):
        if isinstance(upload.get(key), dict):
            pairs.append((label, _gains(upload[key])))
    if isinstance(upload.get("check"), dict):
        worst = upload["check"].get("worst") or {}
        pairs.append(
            (
                "smallest margins they leave",
                f"{esc(str(worst.get('loop', '')))} loop: gain margin {num(worst.get('gain_margin_db'), 'dB', 3)}, "
                f"phase margin {num(worst.get('phase_margin_deg'), 'deg', 3)}, "
                f"Ms {num(worst.get('sensitivity_peak'), '', 3)}",
            )
        )
    closed = upload.get("closed_loop")
    if isinstance(closed, dict):
        pairs.append(
            (
                "closed-loop run",
                f"velocity set-point multisine of {num(closed.get('amplitude_mps'), 'm/s', 3)} peak; bandwidth "
                f"measured {num(closed.get('measured_bandwidth_hz'), 'Hz', 3)}, predicted "
                f"{num(closed.get('predicted_bandwidth_hz'), 'Hz', 3)}",
            )
        )
        pairs += _check_pairs(closed, "measured against predicted")
    if isinstance(upload.get("closed_loop_with_friction"), dict):
        pairs += _check_pairs(upload["closed_loop_with_friction"], "before friction's part was taken out")
    if isinstance(upload.get("step"), dict):
        pairs.append(("velocity steps", _step(upload["step"])))
    if upload.get("reason"):
        pairs.append(("why", esc(str(upload["reason"]))))
    return key_values(pairs)


def _step_figures(figures: Any) -> str:
    figures = figures if isinstance(figures, dict) else {}
    return (
        f"overshoot {num(figures.get('overshoot_percent'), '%', 3)}, rise {num(figures.get('rise_time_s'), 's', 3)}, "
        f"settled {num(figures.get('settling_time_s'), 's', 3)}"
    )


def _step(step: dict) -> str:
    if step.get("reason"):
        return esc(str(step["reason"]))
    return (
        f"+/-{num(step.get('amplitude_mps'), 'm/s', 3)} for {num(step.get('hold_s'), 's', 3)} each, mean of "
        f"{num(step.get('periods'))} periods: rms difference {num(step.get('rms_error_percent'), '%', 3)} of the "
        f"step (allowed {num(step.get('tolerance_percent'), '%', 3)} + "
        f"{num(step.get('prediction_spread_percent'), '%', 3)}); measured {_step_figures(step.get('measured'))}; "
        f"predicted {_step_figures(step.get('predicted'))}"
    )


def _measured(measured: Any) -> str:
    """The loop measured by torque injection beside the one predicted."""
    if not isinstance(measured, dict) or not isinstance(measured.get("predicted"), dict):
        return ""
    rows = [
        [esc(label), *_figure_cells(measured[key])]
        for key, label in (("measured", "measured (torque injection)"), ("predicted", "predicted"))
        if isinstance(measured.get(key), dict)
    ]
    caption = (
        f"Both loops closed, broken at the torque command: measured on {measured.get('measured_lines')} lines, "
        f"rms difference {num(measured.get('rms_gain_difference_db'), 'dB', 3)}, "
        f"{num(measured.get('rms_phase_difference_deg'), 'deg', 3)}"
    )
    return table(["", *_HEADER], rows, caption) + note(str(measured.get("note", "")))


def loop(inputs: ReportInputs) -> str:
    """``summary.json["loop"]``: the drive's loop around the plant, and the gains proposed."""
    part = inputs.summary.get("loop")
    if not isinstance(part, dict):
        return section("loop", "The drive's loop", note("The driver describes no loop ([loop]): no margins."))
    params = part.get("parameters") or {}
    band = part.get("measured_band_hz") or [None, None]
    fit = part.get("mechanics_fit") or {}
    pairs = [
        ("parameters read", ", ".join(f"{esc(k)} {num(v)}" for k, v in params.items()) or MISSING),
        ("measured band", f"{num(band[0], 'Hz')} to {num(band[-1], 'Hz')}"),
        ("plant beyond the band", esc(str(part.get("source", "")))),
        (
            "measured lines against it",
            f"{num(fit.get('gain_db_rms'), 'dB', 3)} rms, {num(fit.get('phase_rms_deg'), 'deg', 3)} rms"
            if fit
            else MISSING,
        ),
    ]
    notes = "".join(note(str(n)) for n in part.get("notes") or [])
    body = key_values(pairs) + _present(part) + _measured(part.get("measured"))
    body += _tuning(part.get("tuning")) + _upload(part.get("upload"))
    return section("loop", "The drive's loop", body + notes)
